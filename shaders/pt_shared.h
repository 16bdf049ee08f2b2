/* pt_shared.h — constants and the push block of the reference path tracer (shaders/pt.comp,
 * render/pt.c), shared by C and GLSL like shared.h (which this file extends; include that
 * first). */
#ifndef NS_SHADERS_PT_SHARED_H
#define NS_SHADERS_PT_SHARED_H

/* Which samples a dispatch takes and which paths count (render/pt.c fills it):
 * components = NS_COMPONENT_* bits (surface = paths with 0 scattering events, single = 1,
 * double = 2, multiple = 3 or more); max_events = the largest event count that can still
 * contribute (render.max_scatter and the components together; NS_NONE = no limit), so a
 * path stops as soon as it could only add to orders nobody asked for. */
struct GpuPtPush {
    ns_uint first_sample;
    ns_uint sample_count;
    ns_uint components;
    ns_uint max_events;
};

/* Boundary (Fresnel) events a path may take between two scattering events before it is
 * counted as truncated (NS_PT_COUNTER_TRUNCATED): a path trapped by total internal
 * reflection would otherwise never end. A render with truncated paths fails rather than
 * return a biased image. */
NS_CONST(uint, NS_PT_MAX_BOUNDARY_RUN, 256);

/* Counters of the pt pass: [NS_COUNTER_LOOP_LIMIT] as in shared.h (lavapipe's loop
 * budget), samples that came out NaN or infinite (dropped), and truncated paths. */
NS_CONST(uint, NS_PT_COUNTER_NONFINITE, 0);
NS_CONST(uint, NS_PT_COUNTER_TRUNCATED, 1);

/* NS_COMPONENT_* bits of render/nscatter.h, for the shader (render/pt.c checks they match). */
NS_CONST(uint, NS_PT_SURFACE, 1);
NS_CONST(uint, NS_PT_SINGLE, 2);
NS_CONST(uint, NS_PT_DOUBLE, 4);
NS_CONST(uint, NS_PT_MULTIPLE, 8);

/* Samples per dispatch where the device has no loop limit (bounds one submission's time). */
NS_CONST(uint, NS_PT_SAMPLES_PER_DISPATCH, 16);

#if defined(__STDC__) || defined(__cplusplus)
typedef struct GpuPtPush GpuPtPush;
_Static_assert(sizeof(GpuPtPush) == 16, "GpuPtPush size");
#endif

#endif
