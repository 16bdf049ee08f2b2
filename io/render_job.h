/* render_job.h — one render from a parsed scene to encoded image bytes, shared by the CLI
 * (`nscatter render`) and the HTTP service: ns_render, metadata, the encoder, and the
 * stage timings both report (CLI --timings JSON, HTTP Server-Timing).
 */
#ifndef NS_RENDER_JOB_H
#define NS_RENDER_JOB_H

#include <jansson.h>

#include "encode.h"
#include "nscatter.h"

/* Renders `scene` with `ctx` and encodes it as `format`. Stages the renderer reports are
 * appended to *stats after whatever the caller put there (e.g. "parse"), then "encode".
 * Metadata written into the image: software, device, render parameters, timings up to
 * the encode. On success *out holds the bytes (free with encode_buffer_free); on failure
 * it is empty and err names the failing step. The rendered pixels are freed on every path. */
int render_job_run(ns_context *ctx, const ns_scene *scene, encode_format format,
                   float exposure_stops, ns_render_stats *stats, encode_buffer *out, ns_error *err);

/* The two halves of render_job_run, for a caller that keeps the image and encodes it later
 * (the HTTP service's asynchronous jobs, once per format asked for).
 * render_job_render: ns_render_controlled (control may be NULL), its stages appended to
 * *stats after the caller's; *image holds the pixels on success (free with ns_image_free)
 * and is empty on failure. */
int render_job_render(ns_context *ctx, const ns_scene *scene, const ns_render_control *control,
                      ns_render_stats *stats, ns_image *image, ns_error *err);
/* Encodes a rendered image with the metadata render_job_run writes (render settings from
 * scene, timings from *stats), then adds an "encode" stage to *stats. device names the
 * device that rendered. */
int render_job_encode(const char *device, const ns_scene *scene, const ns_image *image,
                      encode_format format, float exposure_stops, ns_render_stats *stats,
                      encode_buffer *out, ns_error *err);

/* {"stage": ms, ...} in the order the stages ran; a repeated name adds up. New reference. */
json_t *render_stats_stages_json(const ns_render_stats *stats);

/* {"method", "components", "spp", "seed", "max_depth", "exposure", "width", "height"}. */
json_t *render_settings_json(const ns_scene *scene, float exposure_stops);

/* Appends the names (ns_component_name) of the NS_COMPONENT_* bits set in `components` to
 * `array`, in bit order. */
void render_components_append(json_t *array, uint32_t components);

/* {"camera_segments", "vrl_count", "interactions", "table_bytes", ...}: every count and
 * memory figure of ns_render_stats. New reference. */
json_t *render_stats_counts_json(const ns_render_stats *stats);

/* Sum of all stage times. */
double render_stats_total_ms(const ns_render_stats *stats);

#endif
