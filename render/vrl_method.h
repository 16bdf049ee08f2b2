/* vrl_method.h — (private to render/ and the tests) the two halves of the `vrl` method
 * (render/vrl_method.c; ns_vrl_method_gather in scatter.h strings them together). The CPU
 * copy of the gather's estimator the tests compare with is tests/oracles/vrl_method_cpu.c. */
#ifndef NS_RENDER_VRL_METHOD_H
#define NS_RENDER_VRL_METHOD_H

#include "scatter.h"
#include "vrl_method_shared.h"

/* Traces `paths` light paths towards the scene's scattering media and returns every stretch
 * inside a medium as a VRL (out->vrls malloc'd, in path order; ns_vrl_set_free). options
 * (vrl_method_shared.h): NS_VRL_TRACE_MARK_LINES sets NS_VRL_LINE_RETURNS in the events of
 * each stretch whose line, past its end, meets its medium again (render.boundary's walks;
 * costs a trace per stretch); NS_VRL_TRACE_ENDS returns each stretch's end reflection in
 * out->ends (render.boundary's reflected sources in expectation); NS_VRL_TRACE_MARK_ENVIRONMENT
 * sets NS_VRL_FROM_ENVIRONMENT in the events of a path's stretches from the environment
 * before it scatters. restarts (may be NULL):
 * passes started again after lavapipe cut an invocation (tests). */
int ns_vrl_method_trace(ns_context *ctx, const ns_scene *scene, const ns_gpu_scene *gs,
                        gpu_buffer *scene_buffers, uint32_t paths, uint32_t seed, uint32_t options,
                        ns_vrl_set *out, uint32_t *restarts, ns_error *err);

typedef struct ns_vrl_gather_counts {
    uint64_t interactions; /* (segment, VRL) pairs evaluated */
    uint64_t nonfinite;    /* pair estimates dropped as NaN/Inf (0 when healthy) */
    uint32_t dispatches;
    uint32_t restarts; /* material gathers started again after lavapipe cut an invocation */
} ns_vrl_gather_counts;

/* Gathers vrls[0, vrl_count) (any materials, any order) into out_double / out_multiple (vec4
 * per segment, overwritten). visibility[m] != 0: shadow rays between the sampled points for
 * material m (NULL = none). */
int ns_vrl_method_gather_vrls(ns_context *ctx, gpu_buffer *scene_buffers, const ns_gpu_scene *gs,
                              gpu_buffer *segments, uint32_t segment_count, const GpuVrl *vrls,
                              uint32_t vrl_count, uint32_t seed, const uint8_t *visibility,
                              gpu_buffer *out_double, gpu_buffer *out_multiple,
                              ns_vrl_gather_counts *counts, ns_error *err);

/* The order the GPU gather visits VRLs in: a stable sort by material. first[m], first[m + 1]
 * bound material m's (first has material_count + 1 entries). Returns 0, or -1 when out of
 * memory. *sorted is malloc'd. */
int ns_vrl_method_sort(const GpuVrl *vrls, uint32_t count, uint32_t material_count, GpuVrl **sorted,
                       uint32_t *first);

#endif
