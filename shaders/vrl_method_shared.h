/* vrl_method_shared.h — GPU structs of the `vrl` method (Novak et al. 2012, brute force):
 * shaders/vrl_trace.comp (light paths -> VRLs of every stretch) and shaders/vrl_gather.comp
 * (ray-to-ray transport by sampling), render/vrl_method.c. Include shared.h first. Sizes
 * checked at the bottom. */
#ifndef NS_SHADERS_VRL_METHOD_SHARED_H
#define NS_SHADERS_VRL_METHOD_SHARED_H

/* One (light, target) pair: paths [ids.x, next emitter's ids.x) start at this light and are
 * aimed at the bounding sphere of medium object ids.z. The light's own fields are copied in
 * (the trace binds no light buffer); color already carries 1 / (paths * probability of the
 * pair), so a path's flux is unbiased whatever share of the paths the pair got. */
struct GpuVrlEmitter {
    ns_vec4 target;    /* xyz = centre, w = radius (scene units) */
    ns_vec4 position;  /* point / sphere light: centre; w = sphere light radius */
    ns_vec4 direction; /* directional: unit travel direction */
    ns_vec4 color;     /* light colour / (N p); w unused */
    ns_uvec4 ids;      /* x = first path, y = light kind (NS_GPU_LIGHT_*), z = target object,
                          w = its paths */
};

/* A light path's state between dispatches (lavapipe's loop limit: a path yields after a
 * budget of loop iterations and resumes in the next dispatch). The buffer starts zeroed
 * except count.y (the path's first VRL in the write pass). */
struct GpuVrlWalk {
    ns_vec4 origin; /* w = the flux's largest channel at the medium entry (roulette) */
    ns_vec4 direction;
    ns_vec4 flux;   /* RGB flux carried now (W) */
    ns_uvec4 state; /* x = rng, y = scattering events, z = medium, w = phase (NS_VRL_WALK_*) */
    ns_uvec4 count; /* x = VRLs made so far, y = first VRL slot (write pass), z = boundary
                       events since the last scattering event, w = the hero channel (0-2)
                       whose extinction samples the free flights */
    ns_vec4 mis;    /* xyz = each channel's pdf of the path so far over their mean (spectral
                       MIS, vrl_trace.comp); w = 1 for a path from the environment */
};

NS_CONST(uint, NS_VRL_WALK_FRESH, 0);
NS_CONST(uint, NS_VRL_WALK_INSIDE, 1);
NS_CONST(uint, NS_VRL_WALK_DONE, 2);

/* Push block of vrl_trace.comp. write = 0 counts each path's VRLs (count.x), 1 writes them at
 * count.y. yield_after = counted loop iterations after which an invocation saves its path
 * and stops (0 = never). report: count the paths still walking (NS_VRL_TRACE_ACTIVE). */
struct GpuVrlTracePush {
    ns_uint path_count;
    ns_uint emitter_count;
    ns_uint seed;
    ns_uint yield_after;
    ns_uint write;
    ns_uint report;
    ns_uint vrl_capacity;
    ns_uint options;    /* NS_VRL_TRACE_* (below) */
};

/* GpuVrlTracePush.options. MARK_LINES: set NS_VRL_LINE_RETURNS in the stored stretches'
 * events. ENDS: write each stored stretch's end (binding 8): where the walk leaves through
 * its medium's own refracting boundary, the direction it would reflect in, scaled by the
 * chord ahead along it for a stretch of unscattered light (the distance to the boundary the
 * reflected beam meets: render/boundary.c narrows its first order's tube to it; unit length
 * after a scattering, where nothing reads it), and in w the Fresnel reflectance F (1 on
 * total internal reflection) that decides whether it does; else 0 (also where the
 * reflected beam of unscattered light would meet nothing ahead: the walk ends there). */
NS_CONST(uint, NS_VRL_TRACE_MARK_LINES, 1);
NS_CONST(uint, NS_VRL_TRACE_ENDS, 2);
/* MARK_ENVIRONMENT: set NS_VRL_FROM_ENVIRONMENT in the events of the stored stretches of a
 * path from the environment that has not scattered yet. */
NS_CONST(uint, NS_VRL_TRACE_MARK_ENVIRONMENT, 4);

/* Trace counters (binding 7). */
NS_CONST(uint, NS_VRL_TRACE_ACTIVE, 0);     /* paths not finished after a reporting dispatch */
NS_CONST(uint, NS_VRL_TRACE_LOOP_LIMIT, 1); /* invocations cut by lavapipe's limit */
NS_CONST(uint, NS_VRL_TRACE_TRUNCATED, 2);  /* paths stopped by the boundary-event cap */
NS_CONST(uint, NS_VRL_TRACE_COUNTER_COUNT, 4);

/* Boundary events (internal reflections, crossings of index-matched objects) a path may make
 * in a row without scattering; beyond it the path ends and is counted. */
NS_CONST(uint, NS_VRL_MAX_BOUNDARY_RUN, 256);

/* Surfaces a stretch's line past its end is followed through to find its medium again
 * (vrl_trace.comp, line_meets_medium); a line that crosses more is taken not to return. */
NS_CONST(uint, NS_VRL_LINE_CROSSINGS, 16);

/* Russian roulette starts after this many scattering events (the flux relative to its value
 * at the medium entry is the survival probability). */
NS_CONST(uint, NS_VRL_ROULETTE_AFTER, 3);

/* Per camera segment result of the gather: radiance of orders 2 (VRLs with events = 0) and
 * >= 3, and the next VRL this segment visits (resumed across dispatches). */
struct GpuVrlResult {
    ns_vec3 double_rgb;
    ns_uint next_vrl;
    ns_vec3 multiple_rgb;
    ns_uint pad;
};

/* Push block of vrl_gather.comp: segments [0, segment_count) of material `material` visit the
 * VRLs [first_vrl, end_vrl) (all of that material), each from its own next_vrl on, until its
 * counted loop iterations reach yield_after (0 = never). visibility = 1: a shadow ray between
 * the two sampled points (media that are not a lone convex object). */
struct GpuVrlGatherPush {
    ns_uint first_vrl;
    ns_uint end_vrl;
    ns_uint segment_count;
    ns_uint material;
    ns_uint seed;
    ns_uint yield_after;
    ns_uint visibility;
    ns_uint report;
};

NS_CONST(uint, NS_VRL_METHOD_GROUP, 64);

/* Gather counters (binding 7). */
NS_CONST(uint, NS_VRL_GATHER_UNFINISHED, 0); /* segments with VRLs left (reporting dispatch) */
NS_CONST(uint, NS_VRL_GATHER_LOOP_LIMIT, 1); /* invocations cut by lavapipe's limit */
NS_CONST(uint, NS_VRL_GATHER_NONFINITE, 2);  /* pair estimates dropped as NaN/Inf */
NS_CONST(uint, NS_VRL_GATHER_COUNTER_COUNT, 4);

#if defined(__STDC__) || defined(__cplusplus)
typedef struct GpuVrlEmitter GpuVrlEmitter;
typedef struct GpuVrlWalk GpuVrlWalk;
typedef struct GpuVrlTracePush GpuVrlTracePush;
typedef struct GpuVrlResult GpuVrlResult;
typedef struct GpuVrlGatherPush GpuVrlGatherPush;
_Static_assert(sizeof(GpuVrlEmitter) == 80 && offsetof(GpuVrlEmitter, ids) == 64, "GpuVrlEmitter");
_Static_assert(sizeof(GpuVrlWalk) == 96 && offsetof(GpuVrlWalk, mis) == 80, "GpuVrlWalk");
_Static_assert(sizeof(GpuVrlTracePush) == 32, "GpuVrlTracePush");
_Static_assert(sizeof(GpuVrlResult) == 32 && offsetof(GpuVrlResult, multiple_rgb) == 16,
               "GpuVrlResult");
_Static_assert(sizeof(GpuVrlGatherPush) == 32, "GpuVrlGatherPush");
#endif

#endif
