/* render_job.c — ns_render, then the encoder, with the metadata and timings both carry. */
#include "render_job.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void render_components_append(json_t *array, uint32_t components)
{
    for (int bit = 0; bit < NS_COMPONENT_COUNT; bit++)
        if (components & (1u << bit))
            json_array_append_new(array, json_string(ns_component_name(1u << bit)));
}

json_t *render_stats_stages_json(const ns_render_stats *stats)
{
    json_t *stages = json_object();
    for (uint32_t i = 0; stats && i < stats->stage_count && i < NS_MAX_STAGES; i++) {
        const ns_stage_time *s = &stats->stages[i];
        json_t *earlier = json_object_get(stages, s->name);
        double ms = s->ms + (earlier ? json_real_value(earlier) : 0.0);
        json_object_set_new(stages, s->name, json_real(ms));
    }
    return stages;
}

json_t *render_stats_counts_json(const ns_render_stats *stats)
{
    const struct {
        const char *name;
        uint64_t value;
    } rows[] = {
        {"camera_segments", stats->camera_segments},
        {"bvh_nodes", stats->bvh_nodes},
        {"primitives", stats->primitives},
        {"vrl_paths", stats->vrl_paths},
        {"vrl_count", stats->vrl_count},
        {"boundary_sources", stats->boundary_sources},
        {"gather_segments", stats->gather_segments},
        {"tiles_interpolated", stats->tiles_interpolated},
        {"single_interpolated", stats->single_interpolated},
        {"corrections_interpolated", stats->corrections_interpolated},
        {"interactions", stats->interactions},
        {"cells_culled", stats->cells_culled},
        {"cells_represented", stats->cells_represented},
        {"weights_bytes", stats->weights_bytes},
        {"table_bytes", stats->table_bytes},
        {"tables_blended", stats->tables_blended},
        {"adaptive_samples", stats->adaptive_samples},
    };
    json_t *counts = json_object();
    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++)
        json_object_set_new(counts, rows[i].name, json_integer((json_int_t)rows[i].value));
    return counts;
}

double render_stats_total_ms(const ns_render_stats *stats)
{
    double total = 0.0;
    for (uint32_t i = 0; stats && i < stats->stage_count && i < NS_MAX_STAGES; i++)
        total += stats->stages[i].ms;
    return total;
}

json_t *render_settings_json(const ns_scene *scene, float exposure_stops)
{
    const ns_render_settings *r = &scene->render;
    json_t *components = json_array();
    render_components_append(components, r->components);
    /* The boundary model too: its default depends on the method, and it changes nn's and
     * table's scattering by up to 3x, so an image says which one made it. single_levels
     * and gather_camera_samples likewise: the parser's defaults (2, 1) are not the
     * library's (0); and tables, whose parser default (auto) is not the library's (exact).
     * light_samples and adaptive_spp with spp: together they set the surface's noise
     * (adaptive_spp as used: 0 where it added nothing, pt or no surface). */
    return json_pack("{s:s, s:o, s:I, s:I, s:I, s:I, s:f, s:f, s:I, s:I, s:s, s:I, s:I, s:s}",
                     "method", ns_method_name(r->method), "components", components, "spp",
                     (json_int_t)r->spp, "seed", (json_int_t)r->seed, "max_depth",
                     (json_int_t)r->max_depth, "light_samples", (json_int_t)r->light_samples,
                     "adaptive_spp", (double)ns_adaptive_spp_used(r), "exposure",
                     (double)exposure_stops, "width", (json_int_t)scene->camera.width, "height",
                     (json_int_t)scene->camera.height, "boundary", ns_boundary_name(r->boundary),
                     "single_levels", (json_int_t)r->single_levels, "gather_camera_samples",
                     (json_int_t)r->gather_camera_samples, "tables", ns_tables_name(r->tables));
}

/* Metadata strings live here while the encoder reads them. */
typedef struct render_meta {
    char software[64];
    char device[256];
    char *settings; /* json_dumps output, freed by render_meta_free */
    char *timings;
    char *counts;
    encode_text texts[5];
    size_t count;
} render_meta;

static void render_meta_free(render_meta *meta)
{
    free(meta->settings);
    free(meta->timings);
    free(meta->counts);
}

static void render_meta_build(render_meta *meta, const char *device, const ns_scene *scene,
                              float exposure_stops, const ns_render_stats *stats)
{
    memset(meta, 0, sizeof *meta);
    snprintf(meta->software, sizeof meta->software, "nscatter %s", NS_VERSION);
    snprintf(meta->device, sizeof meta->device, "%s", device ? device : "");
    json_t *settings = render_settings_json(scene, exposure_stops);
    json_t *stages = render_stats_stages_json(stats);
    json_t *counts = render_stats_counts_json(stats);
    meta->settings = json_dumps(settings, JSON_COMPACT | JSON_REAL_PRECISION(6));
    meta->timings = json_dumps(stages, JSON_COMPACT | JSON_REAL_PRECISION(6));
    meta->counts = json_dumps(counts, JSON_COMPACT);
    json_decref(settings);
    json_decref(stages);
    json_decref(counts);
    meta->texts[meta->count++] = (encode_text){"Software", meta->software};
    if (meta->device[0])
        meta->texts[meta->count++] = (encode_text){"nscatter:device", meta->device};
    if (meta->settings)
        meta->texts[meta->count++] = (encode_text){"nscatter:render", meta->settings};
    if (meta->timings)
        meta->texts[meta->count++] = (encode_text){"nscatter:timings_ms", meta->timings};
    if (meta->counts)
        meta->texts[meta->count++] = (encode_text){"nscatter:counts", meta->counts};
}

int render_job_render(ns_context *ctx, const ns_scene *scene, const ns_render_control *control,
                      ns_render_stats *stats, ns_image *image, ns_error *err)
{
    memset(image, 0, sizeof *image);
    /* The renderer fills its own stats (it may clear them first); merge them after the
     * caller's stages so "parse" stays first. */
    ns_render_stats render_stats;
    memset(&render_stats, 0, sizeof render_stats);
    int rc = ns_render_controlled(ctx, scene, control, image, &render_stats, err);
    ns_render_stats callers = *stats;
    *stats = render_stats; /* the counts */
    stats->stage_count = 0;
    for (uint32_t i = 0; i < callers.stage_count && i < NS_MAX_STAGES; i++)
        ns_stats_add_stage(stats, callers.stages[i].name, callers.stages[i].ms);
    for (uint32_t i = 0; i < render_stats.stage_count && i < NS_MAX_STAGES; i++)
        ns_stats_add_stage(stats, render_stats.stages[i].name, render_stats.stages[i].ms);
    if (!rc && (!image->rgb || image->width != scene->camera.width ||
                image->height != scene->camera.height))
        rc = ns_fail(err, NS_ERR_INTERNAL, "renderer returned a %ux%u image for a %ux%u camera",
                     image->width, image->height, scene->camera.width, scene->camera.height);
    if (rc)
        ns_image_free(image);
    return rc;
}

int render_job_encode(const char *device, const ns_scene *scene, const ns_image *image,
                      encode_format format, float exposure_stops, ns_render_stats *stats,
                      encode_buffer *out, ns_error *err)
{
    double t0 = ns_now_ms();
    render_meta meta;
    render_meta_build(&meta, device, scene, exposure_stops, stats);
    int rc = encode_image(format, image, exposure_stops, meta.texts, meta.count, out, err);
    render_meta_free(&meta);
    if (rc == 0)
        ns_stats_add_stage(stats, "encode", ns_now_ms() - t0);
    return rc;
}

int render_job_run(ns_context *ctx, const ns_scene *scene, encode_format format,
                   float exposure_stops, ns_render_stats *stats, encode_buffer *out, ns_error *err)
{
    out->data = NULL;
    out->size = 0;
    ns_image image;
    int rc = render_job_render(ctx, scene, NULL, stats, &image, err);
    if (rc)
        return rc;
    ns_device_info info;
    ns_context_device_info(ctx, &info);
    rc = render_job_encode(info.device_name, scene, &image, format, exposure_stops, stats, out,
                           err);
    ns_image_free(&image);
    return rc;
}
