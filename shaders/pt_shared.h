/* pt_shared.h — constants and the push block of the reference path tracer (shaders/pt.comp,
 * render/pt.c), shared by C and GLSL like shared.h (which this file extends; include that
 * first). */
#ifndef NS_SHADERS_PT_SHARED_H
#define NS_SHADERS_PT_SHARED_H

/* Push block of a dispatch (render/pt.c fills it): components = NS_COMPONENT_* bits
 * (surface = paths with 0 scattering events, single = 1, double = 2, multiple = 3 or more);
 * max_events = the largest event count that can still contribute (render.max_scatter and
 * the components together; NS_NONE = no limit), so a path stops as soon as it could only
 * add to orders nobody asked for; yield_after = loop iterations after which an invocation
 * saves its path and stops; report = 1 on the last dispatch of a batch: unfinished pixels
 * count themselves (NS_PT_COUNTER_UNFINISHED); target and delta_lights drive the light
 * sub-paths that reach media behind refracting boundaries (docs/reference.md). */
struct GpuPtPush {
    ns_vec4 target; /* light sub-paths aim at this sphere (xyz centre, w radius) */
    ns_uint components;
    ns_uint max_events;
    ns_uint yield_after;
    ns_uint report;
    ns_uint delta_lights; /* point + directional lights; 0: no light sub-paths */
    ns_uint pad0;
    ns_uint pad1;
    ns_uint pad2;
};

/* A pixel's suspended path between dispatches (w components unused); the buffer starts
 * zeroed, which reads as "no path active, sample 0 next".
 * state = medium, scattering events, boundary run, nee_covered;
 * progress = rng state, next sample index, path active, unused. */
struct GpuPtPath {
    ns_vec4 origin;
    ns_vec4 direction;
    ns_vec4 weight;
    ns_vec4 radiance;
    ns_vec4 last_event;
    ns_uvec4 state;
    ns_uvec4 progress;
    ns_vec4 light_vertex; /* the sample's light sub-path vertex; w = 1 when there is one */
    ns_vec4 light_weight; /* its throughput (flux per unit pdf) */
    ns_vec4 light_dir;    /* the direction light travelled to reach it; w = its events */
};

/* Boundary (Fresnel) events a path may take between two scattering events before it is
 * counted as truncated (NS_PT_COUNTER_TRUNCATED): a path trapped by total internal
 * reflection would otherwise never end. A render with truncated paths fails rather than
 * return a biased image. */
NS_CONST(uint, NS_PT_MAX_BOUNDARY_RUN, 256);

/* Boundary events a light sub-path may take in a row before it reaches its next scattering
 * event. */
NS_CONST(uint, NS_PT_MAX_LIGHT_BOUNDARIES, 256);

/* Counters of the pt pass: [NS_COUNTER_LOOP_LIMIT] as in shared.h (lavapipe cut an
 * invocation short: the probe loop in pt.comp), samples that came out NaN or infinite
 * (dropped), truncated paths, and pixels still unfinished after a batch. */
NS_CONST(uint, NS_PT_COUNTER_NONFINITE, 0);
NS_CONST(uint, NS_PT_COUNTER_TRUNCATED, 1);
NS_CONST(uint, NS_PT_COUNTER_UNFINISHED, 3);
NS_CONST(uint, NS_PT_COUNTER_LIGHT_TRUNCATED, 4); /* light sub-paths over their boundary cap */
NS_CONST(uint, NS_PT_COUNTER_COUNT, 8);

/* Counted loop iterations after which a dispatch yields on lavapipe. Measured: 4000 was
 * too many (the probe caught cut invocations in a plain furnace), 1000 is not: the count
 * misses the traversal's leaf, plane and light-hit loops, and lavapipe's limit evidently
 * spans more than one invocation's loops (SIMD lanes, perhaps a workgroup's chunks). */
NS_CONST(uint, NS_PT_YIELD_LAVAPIPE, 1000);

/* Dispatches after which a render gives up (NS_ERR_LIMIT). Paths always progress (each
 * dispatch takes at least one step per unfinished pixel and paths end), so this only bounds
 * a runaway job: at lavapipe's 15-30 ms per dispatch it is hours. */
NS_CONST(uint, NS_PT_MAX_DISPATCHES, 1000000);

/* NS_COMPONENT_* bits of render/include/nscatter.h, for the shader (render/pt.c checks they match). */
NS_CONST(uint, NS_PT_SURFACE, 1);
NS_CONST(uint, NS_PT_SINGLE, 2);
NS_CONST(uint, NS_PT_DOUBLE, 4);
NS_CONST(uint, NS_PT_MULTIPLE, 8);

#if defined(__STDC__) || defined(__cplusplus)
typedef struct GpuPtPush GpuPtPush;
typedef struct GpuPtPath GpuPtPath;
_Static_assert(sizeof(GpuPtPush) == 48 && offsetof(GpuPtPush, components) == 16, "GpuPtPush");
_Static_assert(sizeof(GpuPtPath) == 160 && offsetof(GpuPtPath, state) == 80, "GpuPtPath layout");
#endif

#endif
