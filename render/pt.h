/* pt.h — the reference volumetric path tracer (render.method "pt", shaders/pt.comp). */
#ifndef NS_RENDER_PT_H
#define NS_RENDER_PT_H

#include "internal.h"

/* Renders a validated scene with the path tracer; the caller holds ctx->lock. The pipeline
 * is made by the context's first pt render and kept (render/pipelines.c: the reference is not
 * on the fast path). Fails with NS_ERR_LIMIT, never a wrong image, when a path ran past
 * lavapipe's loop budget, was trapped at boundaries (NS_PT_MAX_BOUNDARY_RUN) or came out
 * non-finite. */
int ns_pt_render(ns_context *ctx, const ns_scene *scene, ns_image *out, ns_render_stats *stats,
                 ns_error *err);

/* The largest scattering-event count that can contribute with these settings (NS_NONE:
 * no limit): max_scatter (0 = none) and the highest requested order. Exposed for tests. */
uint32_t ns_pt_max_events(uint32_t components, uint32_t max_scatter);

#endif
