/* scatter_render.c — the scattering components of a render, after the camera pass (paper
 * Sections 3.8 and 4.1): single scattering at every camera segment; double and multiple
 * scattering gathered from the VRLs (tables of the network or of Monte Carlo, the dipole,
 * or the brute-force `vrl` method) for one pixel per tile, then edge-aware upsampling; and
 * the composition into pixels.
 *
 * Composition. A stage gives, per segment, the radiance L arriving at the segment's entry
 * from inside the medium. The pixel gets throughput * L / spp, times 1/ior^2: radiance
 * leaving a medium of index n into vacuum is divided by n^2 (L / n^2 is invariant along a
 * refracted ray), which the camera pass's throughput (Fresnel only) leaves out because its
 * other paths enter and leave the medium and the factors cancel. The dipole's R_d already
 * gives radiance outside, so it takes no such factor.
 *
 * Upsampling. The gathered quantity per pixel is the radiance per unit throughput,
 * Lbar = sum(throughput * L) / sum(throughput) over the pixel's segments; a pixel that is
 * not gathered takes the bilinear mix of Lbar of the gathered pixels of the four nearest
 * tiles, using only those that see the same medium at a similar distance (their first
 * segment's material and entry distance), and multiplies by its own sum of throughputs
 * (so coverage and Fresnel stay its own). A pixel that no neighbour can stand for is
 * gathered itself: light never bleeds across silhouettes or between objects.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scatter.h"

/* Two pixels see "the same surface" when their first stretches are in the same medium and
 * start at distances within this fraction of each other. */
#define SAME_SURFACE_DISTANCE 0.05f

typedef struct pixel_key {
    uint32_t material;   /* of the first participating segment; NS_NONE: none */
    uint32_t first_rank; /* (sample, depth) of that segment, to find the first */
    float distance;      /* camera to its entry point */
    float weight[3];     /* sum of throughput / spp over participating segments */
} pixel_key;

typedef struct tile_plan {
    uint32_t width, height, tile, tiles_x, tiles_y;
    pixel_key *keys;
    uint32_t *representative; /* per tile: the gathered pixel standing for it, or NS_NONE */
    uint8_t *gathered;        /* per pixel: gathered itself */
    uint32_t *segment_start;  /* pixel -> its segments [start[p], start[p + 1]) in by_pixel */
    uint32_t *by_pixel;
} tile_plan;

static void tile_plan_free(tile_plan *t)
{
    free(t->keys);
    free(t->representative);
    free(t->gathered);
    free(t->segment_start);
    free(t->by_pixel);
    memset(t, 0, sizeof *t);
}

/* The camera pass records no segment dimmer than this (shared.h); segments handed in by
 * other callers are held to the same rule. */
static int visible(const GpuSegment *s)
{
    return fmaxf(s->throughput[0], fmaxf(s->throughput[1], s->throughput[2])) >= NS_MIN_SEGMENT_THROUGHPUT;
}

static int participates(const GpuSegment *s, ns_method method)
{
    /* The dipole is a surface model: it lights the points where light leaves the medium,
     * i.e. the entries of camera paths coming from outside. */
    return visible(s) && (method != NS_METHOD_DIPOLE || (s->depth & NS_SEGMENT_ENTERED));
}

static float distance3(const float *a, const float *b)
{
    float d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
}

static int compatible(const pixel_key *a, const pixel_key *b)
{
    return a->material != NS_NONE && a->material == b->material &&
           fabsf(a->distance - b->distance) <= SAME_SURFACE_DISTANCE * fmaxf(a->distance, b->distance);
}

/* Tile (tx, ty)'s representative: its centre pixel, or the first of its pixels with a
 * participating segment when the centre has none. */
static uint32_t choose_representative(const tile_plan *t, uint32_t tx, uint32_t ty)
{
    uint32_t x0 = tx * t->tile, y0 = ty * t->tile;
    uint32_t x1 = x0 + t->tile < t->width ? x0 + t->tile : t->width;
    uint32_t y1 = y0 + t->tile < t->height ? y0 + t->tile : t->height;
    uint32_t cx = x0 + t->tile / 2 < x1 ? x0 + t->tile / 2 : x1 - 1;
    uint32_t cy = y0 + t->tile / 2 < y1 ? y0 + t->tile / 2 : y1 - 1;
    if (t->keys[cy * t->width + cx].material != NS_NONE)
        return cy * t->width + cx;
    for (uint32_t y = y0; y < y1; y++)
        for (uint32_t x = x0; x < x1; x++)
            if (t->keys[y * t->width + x].material != NS_NONE)
                return y * t->width + x;
    return NS_NONE;
}

/* Bilinear neighbours of pixel (x, y) among the tiles' representatives: up to 4 (pixel,
 * weight) pairs that see the same surface. Returns how many. */
static int upsample_sources(const tile_plan *t, uint32_t x, uint32_t y, uint32_t pixel[4], float weight[4])
{
    float fx = ((float)x + 0.5f) / (float)t->tile - 0.5f, fy = ((float)y + 0.5f) / (float)t->tile - 0.5f;
    int tx0 = (int)floorf(fx), ty0 = (int)floorf(fy);
    float ax = fx - (float)tx0, ay = fy - (float)ty0;
    const pixel_key *self = &t->keys[y * t->width + x];
    int n = 0;
    for (int j = 0; j < 2; j++)
        for (int i = 0; i < 2; i++) {
            int tx = tx0 + i, ty = ty0 + j;
            if (tx < 0 || ty < 0 || tx >= (int)t->tiles_x || ty >= (int)t->tiles_y)
                continue;
            uint32_t r = t->representative[(uint32_t)ty * t->tiles_x + (uint32_t)tx];
            if (r == NS_NONE || !compatible(self, &t->keys[r]))
                continue;
            /* A floor on the weight keeps a compatible neighbour usable at the exact
             * centre of another tile. */
            float w = (i ? ax : 1.0f - ax) * (j ? ay : 1.0f - ay);
            pixel[n] = r;
            weight[n++] = fmaxf(w, 1e-3f);
        }
    return n;
}

static int tile_plan_build(const ns_scene *scene, const GpuSegment *segs, uint32_t n, tile_plan *t)
{
    const ns_camera *cam = &scene->camera;
    uint32_t pixels = cam->width * cam->height;
    t->width = cam->width;
    t->height = cam->height;
    t->tile = scene->render.gather_tile ? scene->render.gather_tile : 1;
    t->tiles_x = (t->width + t->tile - 1) / t->tile;
    t->tiles_y = (t->height + t->tile - 1) / t->tile;
    t->keys = malloc(sizeof *t->keys * pixels);
    t->representative = malloc(sizeof *t->representative * t->tiles_x * t->tiles_y);
    t->gathered = calloc(pixels, 1);
    t->segment_start = calloc(pixels + 1, sizeof *t->segment_start);
    t->by_pixel = malloc(sizeof *t->by_pixel * (n ? n : 1));
    if (!t->keys || !t->representative || !t->gathered || !t->segment_start || !t->by_pixel)
        return -1;
    ns_method method = scene->render.method;
    float inv_spp = 1.0f / (float)scene->render.spp;
    for (uint32_t p = 0; p < pixels; p++)
        t->keys[p] = (pixel_key){.material = NS_NONE, .first_rank = UINT32_MAX};
    /* Segments by pixel (counting sort), and each pixel's key. */
    for (uint32_t i = 0; i < n; i++)
        t->segment_start[segs[i].pixel + 1]++;
    for (uint32_t p = 0; p < pixels; p++)
        t->segment_start[p + 1] += t->segment_start[p];
    uint32_t *fill = calloc(pixels, sizeof *fill);
    if (!fill)
        return -1;
    for (uint32_t i = 0; i < n; i++) {
        const GpuSegment *s = &segs[i];
        t->by_pixel[t->segment_start[s->pixel] + fill[s->pixel]++] = i;
        if (!participates(s, method))
            continue;
        pixel_key *k = &t->keys[s->pixel];
        for (int c = 0; c < 3; c++)
            k->weight[c] += s->throughput[c] * inv_spp;
        uint32_t rank = s->sample_index * 256u + (s->depth & 255u);
        if (rank < k->first_rank) {
            k->first_rank = rank;
            k->material = s->material;
            k->distance = distance3(s->entry, cam->position);
        }
    }
    free(fill);
    for (uint32_t ty = 0; ty < t->tiles_y; ty++)
        for (uint32_t tx = 0; tx < t->tiles_x; tx++) {
            uint32_t r = choose_representative(t, tx, ty);
            t->representative[ty * t->tiles_x + tx] = r;
            if (r != NS_NONE)
                t->gathered[r] = 1;
        }
    for (uint32_t y = 0; y < t->height; y++)
        for (uint32_t x = 0; x < t->width; x++) {
            uint32_t p = y * t->width + x, src[4];
            float w[4];
            if (t->keys[p].material != NS_NONE && !t->gathered[p] && upsample_sources(t, x, y, src, w) == 0)
                t->gathered[p] = 1;
        }
    return 0;
}

/* ---------------------------------------------------------------------------------------
 * Timings and counts of the stages, added to the render's stats once at the end.
 * ------------------------------------------------------------------------------------- */
typedef struct scatter_times {
    double reconstruct, accumulate, vrl, grid, gather, single, composite;
} scatter_times;

static void add_times(ns_render_stats *stats, const scatter_times *t)
{
    const struct {
        const char *name;
        double ms;
    } rows[] = {{"reconstruct", t->reconstruct}, {"accumulate", t->accumulate}, {"vrl", t->vrl},
                {"grid", t->grid},               {"gather", t->gather},         {"single", t->single},
                {"composite", t->composite}};
    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++)
        if (rows[i].ms > 0)
            ns_stats_add_stage(stats, rows[i].name, rows[i].ms);
}

/* Radiance inside a medium reaches vacuum divided by ior^2 (see the top of this file). */
static float exit_factor(const GpuMaterial *m)
{
    float ior = m->sigma_t[3];
    return 1.0f / (ior * ior);
}

/* ---------------------------------------------------------------------------------------
 * Single scattering: every segment, full resolution.
 * ------------------------------------------------------------------------------------- */
static int render_single(ns_context *ctx, const ns_scatter_inputs *in, scatter_times *times, ns_error *err)
{
    double t0 = ns_now_ms();
    const GpuSegment *all = in->segments->mapped;
    GpuSegment *kept = malloc(sizeof *kept * (in->segment_count ? in->segment_count : 1));
    if (!kept)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "single: %u segments", in->segment_count);
    uint32_t n = 0;
    for (uint32_t i = 0; i < in->segment_count; i++)
        if (visible(&all[i]))
            kept[n++] = all[i];
    gpu_buffer segments = {0}, out = {0};
    int status = NS_OK;
    if (n) {
        status = gpu_buffer_create(&ctx->dev, &segments,
                                   &(gpu_buffer_desc){.size = sizeof *kept * n,
                                                      .data = kept,
                                                      .data_size = sizeof *kept * n,
                                                      .label = "ns.single.segments"},
                                   err);
        if (!status)
            status = gpu_buffer_create(&ctx->dev, &out,
                                       &(gpu_buffer_desc){.size = 16ull * n, .label = "ns.single.radiance"},
                                       err);
        if (!status)
            status = ns_single_scatter(ctx, in->scene_buffers, &segments, n,
                                       in->scene->render.single_samples, &out, err);
    }
    if (!status && n) {
        const float(*radiance)[4] = out.mapped;
        float inv_spp = 1.0f / (float)in->scene->render.spp;
        for (uint32_t i = 0; i < n; i++) {
            float f = inv_spp * exit_factor(&in->gs->materials[kept[i].material]);
            for (int c = 0; c < 3; c++)
                in->pixels[3 * kept[i].pixel + c] += kept[i].throughput[c] * radiance[i][c] * f;
        }
    }
    gpu_buffer_destroy(&ctx->dev, &segments);
    gpu_buffer_destroy(&ctx->dev, &out);
    free(kept);
    times->single += ns_now_ms() - t0;
    return status;
}

/* ---------------------------------------------------------------------------------------
 * Double and multiple scattering.
 * ------------------------------------------------------------------------------------- */
typedef struct gather_list {
    GpuSegment *segments;   /* gathered segments, grouped by material */
    uint32_t count;
    uint32_t material_first[NS_MAX_MATERIALS + 1]; /* material m: [first[m], first[m + 1]) */
} gather_list;

/* Even bits of v packed into the low half: one coordinate of a Morton code. */
static uint32_t morton_compact(uint32_t v)
{
    v &= 0x55555555u;
    v = (v | (v >> 1)) & 0x33333333u;
    v = (v | (v >> 2)) & 0x0f0f0f0fu;
    v = (v | (v >> 4)) & 0x00ff00ffu;
    v = (v | (v >> 8)) & 0x0000ffffu;
    return v;
}

/* The gathered pixels in Morton (Z) order: consecutive segments of the list, which the
 * gather runs side by side in one SIMD group, then lie close together on the image, so
 * their walks of the VRL hierarchy take the same branches (row order put 8 of them along
 * 16 pixels of one row). Returns the count; order holds room for every pixel. */
static uint32_t gathered_in_z_order(const tile_plan *t, uint32_t *order)
{
    uint32_t side = 1, n = 0;
    while (side < t->width || side < t->height)
        side *= 2;
    for (uint64_t code = 0; code < (uint64_t)side * side; code++) {
        uint32_t x = morton_compact((uint32_t)code), y = morton_compact((uint32_t)(code >> 1));
        if (x < t->width && y < t->height && t->gathered[y * t->width + x])
            order[n++] = y * t->width + x;
    }
    return n;
}

static int gather_list_build(const tile_plan *t, const GpuSegment *segs, ns_method method, gather_list *g)
{
    memset(g->material_first, 0, sizeof g->material_first);
    uint32_t pixels = t->width * t->height, n = 0;
    uint32_t *order = malloc(sizeof *order * (pixels ? pixels : 1));
    if (!order)
        return -1;
    uint32_t gathered = gathered_in_z_order(t, order);
    for (uint32_t j = 0; j < gathered; j++)
        for (uint32_t k = t->segment_start[order[j]]; k < t->segment_start[order[j] + 1]; k++)
            if (participates(&segs[t->by_pixel[k]], method)) {
                g->material_first[segs[t->by_pixel[k]].material + 1]++;
                n++;
            }
    for (uint32_t m = 0; m < NS_MAX_MATERIALS; m++)
        g->material_first[m + 1] += g->material_first[m];
    g->count = n;
    g->segments = malloc(sizeof *g->segments * (n ? n : 1));
    uint32_t *fill = calloc(NS_MAX_MATERIALS, sizeof *fill);
    if (!g->segments || !fill) {
        free(fill);
        free(order);
        return -1;
    }
    for (uint32_t j = 0; j < gathered; j++)
        for (uint32_t k = t->segment_start[order[j]]; k < t->segment_start[order[j] + 1]; k++) {
            uint32_t i = t->by_pixel[k];
            if (!participates(&segs[i], method))
                continue;
            uint32_t at = g->material_first[segs[i].material] + fill[segs[i].material]++;
            g->segments[at] = segs[i];
        }
    free(fill);
    free(order);
    return 0;
}

static void ns_table_key_for(const GpuMaterial *m, const ns_scene *scene, uint32_t orders, ns_table_key *key)
{
    memset(key, 0, sizeof *key);
    key->source = scene->render.method;
    key->g = m->sigma_s[3];
    for (int c = 0; c < 3; c++)
        key->albedo[c] = m->sigma_t[c] > 0 ? m->sigma_s[c] / m->sigma_t[c] : 0.0f;
    key->orders = orders;
    key->accumulation = scene->render.accumulation;
}

/* Table and dipole methods: VRLs, then per medium its grid, its tables and the gather. */
static int gather_from_vrls(ns_context *ctx, const ns_scatter_inputs *in, const gather_list *list,
                            gpu_buffer *seg_buf, gpu_buffer *out, ns_render_stats *stats,
                            scatter_times *times, ns_error *err)
{
    const ns_scene *scene = in->scene;
    ns_method method = scene->render.method;
    uint32_t orders = scene->render.components & (NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE);
    ns_vrl_set set = {0};
    uint64_t table_bytes = 0; /* of this call's media; a render may call once per sample batch */
    double t0 = ns_now_ms();
    int status = ns_vrl_generate(ctx, scene, in->gs, in->scene_buffers, scene->render.vrls,
                                 scene->render.seed, &set, err);
    times->vrl += ns_now_ms() - t0;
    if (!status && stats) {
        stats->vrl_paths = set.paths;
        stats->vrl_count = set.count;
    }
    for (uint32_t m = 0; m < in->gs->material_count && !status; m++) {
        uint32_t first = list->material_first[m], count = list->material_first[m + 1] - first;
        if (!count)
            continue;
        const GpuMaterial *mat = &in->gs->materials[m];
        float s_max = fmaxf(mat->sigma_t[0], fmaxf(mat->sigma_t[1], mat->sigma_t[2]));
        ns_vrl_grid grid = {0};
        double t1 = ns_now_ms();
        /* Representatives pay off only with small leaves (docs/scattering.md). */
        uint32_t leaf_fill = scene->render.cull_solid_angle > 0 ? NS_VRL_LEAF_FILL_REPRESENTED : 0;
        status = ns_vrl_grid_build(&set, m, s_max > 0 ? 1.0f / s_max : INFINITY, leaf_fill, &grid, err);
        times->grid += ns_now_ms() - t1;
        const ns_scatter_tables *tables = NULL;
        uint32_t mode = NS_GATHER_MODE_DIPOLE;
        if (!status && method != NS_METHOD_DIPOLE) {
            ns_table_key key;
            ns_table_key_for(mat, scene, orders, &key);
            ns_table_stats ts = {0};
            status = ns_tables_get(ctx, &key, &tables, &ts, err);
            times->reconstruct += ts.reconstruct_ms;
            times->accumulate += ts.accumulate_ms;
            if (!status && stats) {
                stats->weights_bytes = ts.weights_bytes;
                table_bytes += tables->bytes;
            }
            mode = scene->render.accumulation == NS_ACCUMULATION_PAPER ? NS_GATHER_MODE_PAPER
                                                                      : NS_GATHER_MODE_EXACT;
        }
        if (!status && grid.vrl_count) {
            ns_gather_desc desc = {.segments = seg_buf,
                                   .first_segment = first,
                                   .segment_count = count,
                                   .grid = &grid,
                                   .table = tables ? &tables->a : NULL,
                                   .out = out};
            ns_gather_params(&desc.params, mat, mode, tables, scene->render.cull_solid_angle);
            ns_gather_counts counts;
            double t2 = ns_now_ms();
            status = ns_gather_run(ctx, &desc, &counts, err);
            times->gather += ns_now_ms() - t2;
            if (!status && stats) {
                stats->interactions += counts.interactions;
                stats->cells_culled += counts.cells_culled;
                stats->cells_represented += counts.cells_represented;
            }
        }
        ns_vrl_grid_free(&grid);
    }
    ns_vrl_set_free(&set);
    if (stats && table_bytes > stats->table_bytes)
        stats->table_bytes = table_bytes;
    return status;
}

/* Composes the gathered radiance into the gathered pixels, then upsamples the rest. */
static void compose_gathered(const ns_scatter_inputs *in, const tile_plan *t, const gather_list *list,
                             const float (*radiance)[4])
{
    const ns_scene *scene = in->scene;
    uint32_t pixels = t->width * t->height;
    float inv_spp = 1.0f / (float)scene->render.spp;
    float(*contribution)[3] = calloc(pixels, sizeof *contribution);
    if (!contribution)
        return;
    for (uint32_t i = 0; i < list->count; i++) {
        const GpuSegment *s = &list->segments[i];
        /* The dipole's R_d is radiance outside already. */
        float f = inv_spp * (scene->render.method == NS_METHOD_DIPOLE ? 1.0f : exit_factor(&in->gs->materials[s->material]));
        for (int c = 0; c < 3; c++)
            contribution[s->pixel][c] += s->throughput[c] * radiance[i][c] * f;
    }
    for (uint32_t y = 0; y < t->height; y++)
        for (uint32_t x = 0; x < t->width; x++) {
            uint32_t p = y * t->width + x;
            const pixel_key *k = &t->keys[p];
            if (k->material == NS_NONE)
                continue;
            if (t->gathered[p]) {
                for (int c = 0; c < 3; c++)
                    in->pixels[3 * p + c] += contribution[p][c];
                continue;
            }
            uint32_t src[4];
            float w[4], total = 0, mix[3] = {0, 0, 0};
            int n = upsample_sources(t, x, y, src, w);
            for (int i = 0; i < n; i++) {
                const pixel_key *r = &t->keys[src[i]];
                for (int c = 0; c < 3; c++)
                    if (r->weight[c] > 0)
                        mix[c] += w[i] * contribution[src[i]][c] / r->weight[c];
                total += w[i];
            }
            for (int c = 0; c < 3 && total > 0; c++)
                in->pixels[3 * p + c] += k->weight[c] * mix[c] / total;
        }
    free(contribution);
}

static int render_double_multiple(ns_context *ctx, const ns_scatter_inputs *in, ns_render_stats *stats,
                                  scatter_times *times, ns_error *err)
{
    const ns_scene *scene = in->scene;
    ns_method method = scene->render.method;
    const GpuSegment *segs = in->segments->mapped;
    double t0 = ns_now_ms();
    tile_plan plan = {0};
    gather_list list = {0};
    int status = NS_OK;
    if (tile_plan_build(scene, segs, in->segment_count, &plan) ||
        gather_list_build(&plan, segs, method, &list))
        status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "gather: %u segments", in->segment_count);
    times->composite += ns_now_ms() - t0;
    if (stats)
        stats->gather_segments += list.count;

    gpu_buffer seg_buf = {0}, out[2] = {{0}};
    if (!status && list.count) {
        status = gpu_buffer_create(&ctx->dev, &seg_buf,
                                   &(gpu_buffer_desc){.size = sizeof(GpuSegment) * list.count,
                                                      .data = list.segments,
                                                      .data_size = sizeof(GpuSegment) * list.count,
                                                      .label = "ns.gather.segments"},
                                   err);
        for (int i = 0; i < 2 && !status; i++)
            status = gpu_buffer_create(&ctx->dev, &out[i],
                                       &(gpu_buffer_desc){.size = 16ull * list.count,
                                                          .label = "ns.gather.radiance"},
                                       err);
    }
    if (!status && list.count) {
        if (method == NS_METHOD_VRL) {
            double t1 = ns_now_ms();
            status = ns_vrl_method_gather(ctx, scene, in->gs, in->scene_buffers, &seg_buf, list.count,
                                          &out[0], &out[1], stats, err);
            times->gather += ns_now_ms() - t1;
            if (!status) {
                /* Keep the orders asked for, summed into out[0]. */
                float(*d)[4] = out[0].mapped;
                const float(*mult)[4] = out[1].mapped;
                int want_double = scene->render.components & NS_COMPONENT_DOUBLE;
                int want_multiple = scene->render.components & NS_COMPONENT_MULTIPLE;
                for (uint32_t i = 0; i < list.count; i++)
                    for (int c = 0; c < 3; c++)
                        d[i][c] = (want_double ? d[i][c] : 0.0f) + (want_multiple ? mult[i][c] : 0.0f);
            }
        } else {
            status = gather_from_vrls(ctx, in, &list, &seg_buf, &out[0], stats, times, err);
        }
    }
    if (!status && list.count) {
        double t2 = ns_now_ms();
        compose_gathered(in, &plan, &list, out[0].mapped);
        times->composite += ns_now_ms() - t2;
    }
    gpu_buffer_destroy(&ctx->dev, &seg_buf);
    gpu_buffer_destroy(&ctx->dev, &out[0]);
    gpu_buffer_destroy(&ctx->dev, &out[1]);
    free(list.segments);
    tile_plan_free(&plan);
    return status;
}

int ns_scatter_render(ns_context *ctx, const ns_scatter_inputs *in, ns_render_stats *stats, ns_error *err)
{
    uint32_t components = in->scene->render.components;
    scatter_times times = {0};
    int status = NS_OK;
    if (in->segment_count && (components & NS_COMPONENT_SINGLE))
        status = render_single(ctx, in, &times, err);
    if (!status && in->segment_count && (components & (NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE)))
        status = render_double_multiple(ctx, in, stats, &times, err);
    add_times(stats, &times);
    return status;
}
