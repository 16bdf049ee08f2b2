/* vrl_method.c — the `vrl` method: Novak et al. 2012, "Virtual Ray Lights for rendering
 * scenes with participating media", brute force, no tables (the paper's equal-time
 * competitor).
 *
 *   trace   shaders/vrl_trace.comp: render.vrls light paths towards the scattering media;
 *           every stretch inside a medium (after the entry, a scattering event or an internal
 *           reflection) becomes a VRL. Two passes with the same random numbers (count, then
 *           write at prefix-summed offsets), so the VRL list is exact in size and in path
 *           order whatever the dispatch order was.
 *   gather  shaders/vrl_gather.comp: every camera segment against every VRL of its medium,
 *           one sample per pair; VRLs with events = 0 give double scattering, the others
 *           multiple.
 *
 * Light paths are spread over (light, medium object) pairs by systematic sampling in
 * proportion to an estimate of the power the light sends through the object's bounding
 * sphere: path i belongs to pair k when cdf[k-1] <= (i + xi) / N < cdf[k], and carries the
 * weight 1 / (N p_k), which is unbiased whatever the estimate is (a pair whose share rounds
 * to no path this time is covered by the others' weights in expectation).
 *
 * lavapipe's loop limit (docs/rendering.md): both shaders count their loop iterations, yield
 * after a budget and resume in the next dispatch from saved state; a probe loop catches an
 * invocation that lavapipe cut short anyway, and the call fails rather than return a wrong
 * image.
 */
#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "vrl_method.h"

/* Counted loop iterations after which an invocation yields on lavapipe. The trace's steps
 * run traversal loops that are not all counted (pt.comp measured 1000 as safe there; the
 * single stage measured 6.5-8.7 real iterations per counted one in a one-box scene); the
 * gather's loop without shadow rays has no inner loop, so it counts every iteration. When
 * the probe still finds a cut invocation (many planes: each traversal runs a loop over all
 * of them), the pass starts again from scratch with a quarter of the budget, down to
 * MIN_YIELD; the random numbers do not depend on the split, so the result is the same. */
#define TRACE_YIELD_LAVAPIPE 1000u
#define GATHER_YIELD_LAVAPIPE 16000u
#define GATHER_YIELD_VISIBILITY 1000u
#define MIN_YIELD 4u

/* VRLs a render may make (48 bytes each; lavapipe caps a storage buffer at 128 MiB). */
#define VRL_METHOD_MAX_VRLS (2u * 1024u * 1024u)

/* Submissions after which a pass gives up: every dispatch advances every unfinished path or
 * segment, so this only bounds a runaway job. */
#define MAX_BATCHES 100000u

/* Dispatches in one submission at most (the batches double up to it). */
#define MAX_PER_BATCH 4096u

/* =======================================================================================
 * Emitters: (light, target object) pairs and their share of the paths.
 * ===================================================================================== */
static void box_of(const ns_scene *scene, const ns_object *o, float lo[3], float hi[3])
{
    for (int k = 0; k < 3; k++) {
        lo[k] = INFINITY;
        hi[k] = -INFINITY;
    }
    if (o->shape == NS_SHAPE_SPHERE) {
        for (int k = 0; k < 3; k++) {
            lo[k] = o->center[k] - o->radius;
            hi[k] = o->center[k] + o->radius;
        }
    } else if (o->shape == NS_SHAPE_BOX) {
        memcpy(lo, o->min, sizeof o->min);
        memcpy(hi, o->max, sizeof o->max);
    } else if (o->shape == NS_SHAPE_MESH) {
        for (uint32_t t = 0; t < o->triangle_count; t++)
            for (int v = 0; v < 3; v++)
                for (int k = 0; k < 3; k++) {
                    float p = scene->triangles[o->first_triangle + t].v[v][k];
                    lo[k] = fminf(lo[k], p);
                    hi[k] = fmaxf(hi[k], p);
                }
    }
}

typedef struct emitter_list {
    GpuVrlEmitter *items;
    uint32_t count;
} emitter_list;

static int plan_emitters(const ns_scene *scene, const ns_gpu_scene *gs, uint32_t paths,
                         uint32_t seed, emitter_list *out, ns_error *err)
{
    memset(out, 0, sizeof *out);
    uint32_t n_obj = scene->object_count ? scene->object_count : 1;
    ns_vrl_target *targets_of = malloc(sizeof *targets_of * n_obj);
    uint32_t targets = 0;
    ns_vrl_stratum *strata = NULL;
    uint32_t count = 0;
    int status =
        targets_of ? NS_OK : ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl method: targets");
    if (!status)
        status = ns_vrl_targets(scene, "the vrl method", targets_of, &targets, err);
    /* The same systematic sampling over (light, target) pairs as the VRL stage (vrl.c). */
    if (!status)
        status = ns_vrl_stratify(gs, targets_of, targets, paths, seed, "vrl method", &strata,
                                 &count, err);
    if (!status && count && !(out->items = calloc(count, sizeof *out->items)))
        status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl method: %u emitters", count);
    for (uint32_t i = 0; !status && i < count; i++) {
        const ns_vrl_stratum *st = &strata[i];
        const GpuLight *light = &gs->lights[st->light];
        GpuVrlEmitter *e = &out->items[out->count++];
        memcpy(e->target, targets_of[st->target].sphere, sizeof e->target);
        memcpy(e->position, light->position, sizeof e->position);
        memcpy(e->direction, light->direction, sizeof e->direction);
        for (int c = 0; c < 3; c++)
            e->color[c] = (float)(light->color[c] / (st->p * paths));
        e->ids[0] = st->first_path;
        e->ids[1] = light->info[0];
        e->ids[2] = targets_of[st->target].object;
        e->ids[3] = st->path_count; /* the stratified emission's n (common.glsl) */
    }
    free(targets_of);
    free(strata);
    if (status) {
        free(out->items);
        memset(out, 0, sizeof *out);
    }
    return status;
}

/* =======================================================================================
 * Shared plumbing: the loop budget and the resumed dispatches.
 * ===================================================================================== */
static int check_scene_buffers(const ns_context *ctx, const gpu_buffer *scene_buffers,
                               const char *what, ns_error *err)
{
    if (!scene_buffers || scene_buffers[0].size < sizeof(GpuParams) || !scene_buffers[0].mapped)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "%s: scene_buffers[0] is not the scene's parameters", what);
    const GpuParams *params = scene_buffers[0].mapped;
    if (ctx->dev.loop_limited && !params->limits[0])
        return ns_fail(err, NS_ERR_INTERNAL,
                       "%s: the scene parameters carry no loop budget (limits.x) on a loop-limited "
                       "device",
                       what);
    return NS_OK;
}

/* Both passes run rounds of ns_resume_dispatch: one push block, its report field set in the
 * last dispatch of each submission, MAX_PER_BATCH dispatches per submission at most and
 * MAX_BATCHES submissions. A round that gave up becomes the pass's error here;
 * NS_RESUME_CUT (an invocation cut by the loop limit) goes back to the pass, which starts
 * again with a smaller budget. */
static int round_status(int status, const char *what, ns_error *err)
{
    if (status == NS_RESUME_GAVE_UP)
        return ns_fail(err, NS_ERR_LIMIT, "%s: still unfinished after %u submissions", what,
                       MAX_BATCHES);
    return status;
}

/* =======================================================================================
 * Trace
 * ===================================================================================== */
enum { T_EMITTERS, T_WALKS, T_VRLS, T_COUNTERS, T_ENDS, T_OWN };

static int loop_limit_error(const char *what, uint32_t yield, ns_error *err)
{
    return ns_fail(err, NS_ERR_LIMIT,
                   "%s: invocations ran past lavapipe's loop limit (65535 iterations per "
                   "invocation) even when yielding after %u counted iterations; lower the "
                   "geometry (planes, meshes) or pick another device",
                   what, yield);
}

/* offsets: NULL in the count pass; each path's first VRL slot in the write pass. */
static int trace_pass(ns_context *ctx, gpu_buffer *scene_buffers, gpu_buffer *own,
                      GpuVrlTracePush *push, const uint32_t *offsets, uint32_t *restarts,
                      ns_error *err)
{
    gpu_buffer *bound[4 + T_OWN];
    for (int i = 0; i < 3; i++)
        bound[i] = &scene_buffers[i];
    bound[3] = &scene_buffers[3]; /* materials */
    for (int i = 0; i < T_OWN; i++)
        bound[4 + i] = &own[i];
    const GpuParams *params = scene_buffers[0].mapped;
    GpuVrlWalk *walks = own[T_WALKS].mapped;
    uint32_t yield = params->limits[0] ? TRACE_YIELD_LAVAPIPE : 0;
    gpu_pipeline *pipeline;
    int status = ns_pipeline(ctx, NS_PIPELINE_VRL_TRACE, &pipeline, NULL, err);
    if (status)
        return status;
    for (;;) {
        memset(walks, 0, sizeof *walks * push->path_count);
        for (uint32_t i = 0; offsets && i < push->path_count; i++)
            walks[i].count[1] = offsets[i];
        ((uint32_t *)own[T_COUNTERS].mapped)[NS_VRL_TRACE_TRUNCATED] = 0;
        push->yield_after = yield;
        status = ns_resume_dispatch(
            ctx,
            &(ns_resume_desc){
                .pipeline = pipeline,
                .buffers = bound,
                .groups = {(push->path_count + NS_VRL_METHOD_GROUP - 1) / NS_VRL_METHOD_GROUP, 1,
                           1},
                .push = push,
                .push_count = 1,
                .report_offset = offsetof(GpuVrlTracePush, report),
                .counters = own[T_COUNTERS].mapped,
                .unfinished = NS_VRL_TRACE_ACTIVE,
                .cut = NS_VRL_TRACE_LOOP_LIMIT,
                .first_batch = yield ? 4 : 1,
                .max_batch = MAX_PER_BATCH,
                .max_submissions = MAX_BATCHES,
            },
            NULL, err);
        if (status != NS_RESUME_CUT)
            return round_status(status, "vrl method: light paths", err);
        if (!yield || yield <= MIN_YIELD)
            return loop_limit_error("vrl method: light paths", yield, err);
        yield /= 4;
        ++*restarts;
    }
}

/* After the count pass: each path's VRL count becomes its first slot. */
static int offsets_from_counts(const GpuVrlWalk *walks, uint32_t paths, uint32_t *offsets,
                               uint32_t *total, ns_error *err)
{
    uint64_t sum = 0;
    for (uint32_t i = 0; i < paths; i++) {
        offsets[i] = (uint32_t)(sum < UINT32_MAX ? sum : UINT32_MAX);
        sum += walks[i].count[0];
    }
    if (sum > VRL_METHOD_MAX_VRLS)
        return ns_fail(err, NS_ERR_LIMIT,
                       "render.vrls: %u light paths make %llu VRLs in these media, at most %u; "
                       "lower render.vrls",
                       paths, (unsigned long long)sum, VRL_METHOD_MAX_VRLS);
    *total = (uint32_t)sum;
    return NS_OK;
}

int ns_vrl_method_trace(ns_context *ctx, const ns_scene *scene, const ns_gpu_scene *gs,
                        gpu_buffer *scene_buffers, uint32_t paths, uint32_t seed, uint32_t options,
                        ns_vrl_set *out, uint32_t *restarts, ns_error *err)
{
    memset(out, 0, sizeof *out);
    uint32_t restarts_here = 0;
    if (!restarts)
        restarts = &restarts_here;
    *restarts = 0;
    if (!ctx || !scene || !gs)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "vrl method: %s is NULL",
                       !ctx     ? "ctx"
                       : !scene ? "scene"
                                : "gs");
    if (paths > NS_MAX_VRLS)
        return ns_fail(err, NS_ERR_LIMIT, "render.vrls: %u light paths, at most %u", paths,
                       NS_MAX_VRLS);
    int status = check_scene_buffers(ctx, scene_buffers, "vrl method", err);
    out->paths = paths;
    emitter_list emitters = {0};
    if (!status)
        status = plan_emitters(scene, gs, paths, seed, &emitters, err);
    if (status || !emitters.count || !paths) {
        free(emitters.items);
        return status;
    }
    gpu_buffer own[T_OWN];
    memset(own, 0, sizeof own);
    gpu_buffer_desc descs[T_OWN] = {
        {.size = sizeof(GpuVrlEmitter) * emitters.count,
         .data = emitters.items,
         .data_size = sizeof(GpuVrlEmitter) * emitters.count,
         .label = "ns.vrl_method.emitters"},
        {.size = (uint64_t)sizeof(GpuVrlWalk) * paths,
         .host_reads = 1,
         .label = "ns.vrl_method.walks"},
        {.size = sizeof(GpuVrl), .label = "ns.vrl_method.vrls"},
        {.size = NS_VRL_TRACE_COUNTER_COUNT * sizeof(uint32_t), .label = "ns.vrl_method.counters"},
        {.size = 4 * sizeof(float), .label = "ns.vrl_method.ends"},
    };
    status = gpu_buffers_create(&ctx->dev, own, descs, T_OWN, err);
    GpuVrlTracePush push = {
        .path_count = paths, .emitter_count = emitters.count, .seed = seed, .options = options};
    uint32_t *offsets = status ? NULL : malloc(sizeof *offsets * paths);
    if (!status && !offsets)
        status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl method: %u paths", paths);
    /* Progress: the count pass is the first half of the trace's part, the write pass the
     * second. */
    ns_span outer = ns_progress_push(ctx, 0.0, 0.5);
    if (!status)
        status = trace_pass(ctx, scene_buffers, own, &push, NULL, restarts, err);
    ns_progress_pop(ctx, outer);
    /* The reference path tracer refuses the same (pt.c): a trapped path's flux is lost. */
    const uint32_t *counters = own[T_COUNTERS].mapped;
    if (!status && counters[NS_VRL_TRACE_TRUNCATED])
        status = ns_fail(err, NS_ERR_LIMIT,
                         "vrl method: %u light path(s) took more than %u boundary events in a row "
                         "(trapped by total internal reflection?)",
                         counters[NS_VRL_TRACE_TRUNCATED], (unsigned)NS_VRL_MAX_BOUNDARY_RUN);
    uint32_t total = 0;
    if (!status)
        status = offsets_from_counts(own[T_WALKS].mapped, paths, offsets, &total, err);
    if (!status && total) {
        gpu_buffer_destroy(&ctx->dev, &own[T_VRLS]);
        status = gpu_buffer_create(&ctx->dev, &own[T_VRLS],
                                   &(gpu_buffer_desc){.size = (uint64_t)sizeof(GpuVrl) * total,
                                                      .uninitialized = 1,
                                                      .host_reads = 1,
                                                      .label = "ns.vrl_method.vrls"},
                                   err);
        if (!status && (options & NS_VRL_TRACE_ENDS)) {
            gpu_buffer_destroy(&ctx->dev, &own[T_ENDS]);
            status =
                gpu_buffer_create(&ctx->dev, &own[T_ENDS],
                                  &(gpu_buffer_desc){.size = (uint64_t)4 * sizeof(float) * total,
                                                     .uninitialized = 1,
                                                     .host_reads = 1,
                                                     .label = "ns.vrl_method.ends"},
                                  err);
        }
        push.write = 1;
        push.vrl_capacity = total;
        outer = ns_progress_push(ctx, 0.5, 1.0);
        if (!status)
            status = trace_pass(ctx, scene_buffers, own, &push, offsets, restarts, err);
        ns_progress_pop(ctx, outer);
    }
    /* The write pass must have made exactly the counted VRLs (same random numbers). */
    const GpuVrlWalk *walks = own[T_WALKS].mapped;
    for (uint32_t i = 0; !status && total && i < paths; i++) {
        uint32_t end = i + 1 < paths ? walks[i + 1].count[1] : total;
        if (walks[i].count[1] + walks[i].count[0] != end)
            status = ns_fail(err, NS_ERR_INTERNAL, "vrl method: path %u made %u VRLs, counted %u",
                             i, walks[i].count[0], end - walks[i].count[1]);
    }
    if (!status && total) {
        out->vrls = malloc(sizeof *out->vrls * total);
        if (!out->vrls)
            status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl method: %u VRLs", total);
        else {
            memcpy(out->vrls, own[T_VRLS].mapped, sizeof *out->vrls * total);
            out->count = total;
        }
    }
    if (!status && total && (options & NS_VRL_TRACE_ENDS)) {
        out->ends = malloc(4 * sizeof *out->ends * total);
        if (!out->ends)
            status =
                ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl method: %u stretches' ends", total);
        else
            memcpy(out->ends, own[T_ENDS].mapped, 4 * sizeof *out->ends * total);
    }
    for (int i = 0; i < T_OWN; i++)
        gpu_buffer_destroy(&ctx->dev, &own[i]);
    free(offsets);
    free(emitters.items);
    if (status)
        ns_vrl_set_free(out);
    return status;
}

/* =======================================================================================
 * Gather
 * ===================================================================================== */
int ns_vrl_method_sort(const GpuVrl *vrls, uint32_t count, uint32_t material_count, GpuVrl **sorted,
                       uint32_t *first)
{
    memset(first, 0, sizeof *first * (material_count + 1));
    *sorted = malloc(sizeof **sorted * (count ? count : 1));
    uint32_t *fill = calloc(material_count + 1, sizeof *fill);
    if (!*sorted || !fill) {
        free(*sorted);
        *sorted = NULL;
        free(fill);
        return -1;
    }
    for (uint32_t i = 0; i < count; i++)
        if (vrls[i].material < material_count)
            first[vrls[i].material + 1]++;
    for (uint32_t m = 0; m < material_count; m++)
        first[m + 1] += first[m];
    for (uint32_t i = 0; i < count; i++) {
        uint32_t m = vrls[i].material;
        if (m < material_count)
            (*sorted)[first[m] + fill[m]++] = vrls[i];
    }
    free(fill);
    return 0;
}

enum { G_VRLS, G_RESULTS, G_COUNTERS, G_OWN };

static int gather_material(ns_context *ctx, gpu_buffer **bound, gpu_buffer *counters,
                           uint32_t segment_count, uint32_t material, uint32_t first, uint32_t end,
                           uint32_t seed, int visibility, int loop_limited, uint32_t *dispatches,
                           uint32_t *restarts, ns_error *err)
{
    uint32_t yield = !loop_limited ? 0
                     : visibility  ? GATHER_YIELD_VISIBILITY
                                   : GATHER_YIELD_LAVAPIPE;
    const GpuSegment *segs = bound[4]->mapped;
    GpuVrlResult *results = bound[6]->mapped;
    gpu_pipeline *pipeline;
    int status = ns_pipeline(ctx, NS_PIPELINE_VRL_GATHER, &pipeline, NULL, err);
    if (status)
        return status;
    for (;;) {
        /* This material's segments start (again) from nothing. */
        for (uint32_t i = 0; i < segment_count; i++)
            if (segs[i].material == material)
                memset(&results[i], 0, sizeof results[i]);
        GpuVrlGatherPush push = {.first_vrl = first,
                                 .end_vrl = end,
                                 .segment_count = segment_count,
                                 .material = material,
                                 .seed = seed,
                                 .yield_after = yield,
                                 .visibility = visibility ? 1u : 0u};
        /* Without shadow rays a VRL costs one counted iteration: this many dispatches finish. */
        uint32_t per_batch = yield ? (end - first + yield - 1) / yield : 1;
        status = ns_resume_dispatch(
            ctx,
            &(ns_resume_desc){
                .pipeline = pipeline,
                .buffers = bound,
                .groups = {(segment_count + NS_VRL_METHOD_GROUP - 1) / NS_VRL_METHOD_GROUP, 1, 1},
                .push = &push,
                .push_count = 1,
                .report_offset = offsetof(GpuVrlGatherPush, report),
                .counters = counters->mapped,
                .unfinished = NS_VRL_GATHER_UNFINISHED,
                .cut = NS_VRL_GATHER_LOOP_LIMIT,
                .first_batch = per_batch,
                .max_batch = MAX_PER_BATCH,
                .max_submissions = MAX_BATCHES,
                .expected_dispatches = yield ? per_batch : 0,
            },
            dispatches, err);
        if (status != NS_RESUME_CUT)
            return round_status(status, "vrl method: gather", err);
        if (!yield || yield <= MIN_YIELD)
            return loop_limit_error("vrl method: gather", yield, err);
        yield /= 4;
        ++*restarts;
    }
}

static int check_gather_buffers(const gpu_buffer *segments, uint32_t segment_count,
                                const gpu_buffer *out_double, const gpu_buffer *out_multiple,
                                ns_error *err)
{
    if (!segments || !out_double || !out_multiple)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "vrl method: %s is NULL",
                       !segments     ? "segments"
                       : !out_double ? "out_double"
                                     : "out_multiple");
    if (segments->size < (uint64_t)segment_count * sizeof(GpuSegment))
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "vrl method: segments buffer holds %llu bytes, %u segments need %llu",
                       (unsigned long long)segments->size, segment_count,
                       (unsigned long long)segment_count * sizeof(GpuSegment));
    const gpu_buffer *outs[2] = {out_double, out_multiple};
    for (int i = 0; i < 2; i++)
        if (outs[i]->size < (uint64_t)segment_count * 16 || !outs[i]->mapped)
            return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                           "vrl method: %s holds %llu bytes, %u segments need %llu (mapped)",
                           i ? "out_multiple" : "out_double", (unsigned long long)outs[i]->size,
                           segment_count, (unsigned long long)segment_count * 16);
    return NS_OK;
}

static int run_gather(ns_context *ctx, gpu_buffer *scene_buffers, const ns_gpu_scene *gs,
                      gpu_buffer *segments, uint32_t segment_count, const GpuVrl *sorted,
                      const uint32_t *first, uint32_t vrl_count, uint32_t seed,
                      const uint8_t *visibility, gpu_buffer *own, ns_vrl_gather_counts *counts,
                      ns_error *err)
{
    gpu_buffer_desc descs[G_OWN] = {
        {.size = (uint64_t)sizeof(GpuVrl) * vrl_count,
         .data = sorted,
         .data_size = (uint64_t)sizeof(GpuVrl) * vrl_count,
         .label = "ns.vrl_method.vrls"},
        {.size = (uint64_t)sizeof(GpuVrlResult) * segment_count,
         .host_reads = 1,
         .label = "ns.vrl_method.results"},
        {.size = NS_VRL_GATHER_COUNTER_COUNT * sizeof(uint32_t), .label = "ns.vrl_method.counters"},
    };
    int status = gpu_buffers_create(&ctx->dev, own, descs, G_OWN, err);
    if (status)
        return status;
    gpu_buffer *bound[8] = {&scene_buffers[0], &scene_buffers[1], &scene_buffers[2],
                            &scene_buffers[3], segments,          &own[G_VRLS],
                            &own[G_RESULTS],   &own[G_COUNTERS]};
    /* Which materials the segments use: only those are dispatched. */
    uint8_t *used = calloc(gs->material_count ? gs->material_count : 1, 1);
    if (!used)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl method: materials");
    const GpuSegment *segs = segments->mapped;
    uint64_t *per_material =
        calloc(gs->material_count ? gs->material_count : 1, sizeof *per_material);
    for (uint32_t i = 0; per_material && i < segment_count; i++)
        if (segs[i].material < gs->material_count) {
            used[segs[i].material] = 1;
            per_material[segs[i].material]++;
        }
    if (!per_material)
        status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl method: materials");
    /* Progress: each material's part is its share of the (segment, VRL) pairs. */
    double pairs = 0.0, done = 0.0;
    for (uint32_t m = 0; !status && m < gs->material_count; m++)
        if (used[m])
            pairs += (double)per_material[m] * (first[m + 1] - first[m]);
    for (uint32_t m = 0; !status && m < gs->material_count; m++) {
        if (!used[m] || first[m + 1] == first[m])
            continue;
        double share = (double)per_material[m] * (first[m + 1] - first[m]);
        ns_span outer = ns_progress_push(ctx, done / pairs, (done + share) / pairs);
        status =
            gather_material(ctx, bound, &own[G_COUNTERS], segment_count, m, first[m], first[m + 1],
                            seed, visibility && visibility[m], ctx->dev.loop_limited,
                            &counts->dispatches, &counts->restarts, err);
        ns_progress_pop(ctx, outer);
        done += share;
        counts->interactions += per_material[m] * (first[m + 1] - first[m]);
    }
    if (!status)
        counts->nonfinite = ((const uint32_t *)own[G_COUNTERS].mapped)[NS_VRL_GATHER_NONFINITE];
    free(used);
    free(per_material);
    return status;
}

int ns_vrl_method_gather_vrls(ns_context *ctx, gpu_buffer *scene_buffers, const ns_gpu_scene *gs,
                              gpu_buffer *segments, uint32_t segment_count, const GpuVrl *vrls,
                              uint32_t vrl_count, uint32_t seed, const uint8_t *visibility,
                              gpu_buffer *out_double, gpu_buffer *out_multiple,
                              ns_vrl_gather_counts *counts, ns_error *err)
{
    memset(counts, 0, sizeof *counts);
    if (!ctx || !gs)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "vrl method: %s is NULL", !ctx ? "ctx" : "gs");
    int status = check_scene_buffers(ctx, scene_buffers, "vrl method", err);
    if (!status)
        status = check_gather_buffers(segments, segment_count, out_double, out_multiple, err);
    if (status)
        return status;
    memset(out_double->mapped, 0, (size_t)segment_count * 16);
    memset(out_multiple->mapped, 0, (size_t)segment_count * 16);
    if (!segment_count || !vrl_count)
        return NS_OK;
    GpuVrl *sorted = NULL;
    uint32_t *first = malloc(sizeof *first * (gs->material_count + 1));
    if (!first || ns_vrl_method_sort(vrls, vrl_count, gs->material_count, &sorted, first)) {
        free(first);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl method: %u VRLs", vrl_count);
    }
    gpu_buffer own[G_OWN];
    memset(own, 0, sizeof own);
    status = run_gather(ctx, scene_buffers, gs, segments, segment_count, sorted, first, vrl_count,
                        seed, visibility, own, counts, err);
    if (!status && counts->nonfinite)
        status = ns_fail(err, NS_ERR_INTERNAL, "vrl method: %llu pair estimate(s) were NaN or Inf",
                         (unsigned long long)counts->nonfinite);
    if (!status) {
        const GpuVrlResult *res = own[G_RESULTS].mapped;
        float(*dbl)[4] = out_double->mapped;
        float(*mult)[4] = out_multiple->mapped;
        for (uint32_t i = 0; i < segment_count; i++) {
            memcpy(dbl[i], res[i].double_rgb, sizeof res[i].double_rgb);
            memcpy(mult[i], res[i].multiple_rgb, sizeof res[i].multiple_rgb);
        }
    }
    for (int i = 0; i < G_OWN; i++)
        gpu_buffer_destroy(&ctx->dev, &own[i]);
    free(sorted);
    free(first);
    return status;
}

/* =======================================================================================
 * Visibility: a straight line between two points inside a convex object that nothing else
 * enters stays inside it, so shadow rays are only traced for the other media.
 * ===================================================================================== */
static int boxes_overlap(const float alo[3], const float ahi[3], const float blo[3],
                         const float bhi[3])
{
    for (int k = 0; k < 3; k++)
        if (ahi[k] < blo[k] || bhi[k] < alo[k])
            return 0;
    return 1;
}

static int plane_cuts_box(const ns_object *plane, const float lo[3], const float hi[3])
{
    int below = 0, above = 0;
    for (int corner = 0; corner < 8; corner++) {
        double s = 0;
        for (int k = 0; k < 3; k++) {
            float p = corner & (1 << k) ? hi[k] : lo[k];
            s += ((double)p - plane->point[k]) * plane->normal[k];
        }
        below |= s <= 0;
        above |= s >= 0;
    }
    return below && above;
}

static int lone_convex(const ns_scene *scene, uint32_t object)
{
    const ns_object *o = &scene->objects[object];
    if (o->shape != NS_SHAPE_SPHERE && o->shape != NS_SHAPE_BOX)
        return 0;
    float lo[3], hi[3], olo[3], ohi[3];
    box_of(scene, o, lo, hi);
    for (uint32_t j = 0; j < scene->object_count; j++) {
        if (j == object)
            continue;
        const ns_object *other = &scene->objects[j];
        if (other->shape == NS_SHAPE_PLANE) {
            if (plane_cuts_box(other, lo, hi))
                return 0;
            continue;
        }
        box_of(scene, other, olo, ohi);
        if (boxes_overlap(lo, hi, olo, ohi))
            return 0;
    }
    return 1;
}

/* visibility[m] = 1 unless material m bounds exactly one object, convex and alone. */
static void visibility_per_material(const ns_scene *scene, uint8_t *visibility)
{
    uint32_t *objects = calloc(scene->material_count ? scene->material_count : 1, sizeof *objects);
    for (uint32_t m = 0; m < scene->material_count; m++)
        visibility[m] = 1;
    if (!objects)
        return; /* shadow rays everywhere: slower, never wrong */
    for (uint32_t i = 0; i < scene->object_count; i++)
        objects[scene->objects[i].material]++;
    for (uint32_t i = 0; i < scene->object_count; i++) {
        uint32_t m = scene->objects[i].material;
        if (objects[m] == 1 && lone_convex(scene, i))
            visibility[m] = 0;
    }
    free(objects);
}

/* =======================================================================================
 * The method
 * ===================================================================================== */
int ns_vrl_method_gather(ns_context *ctx, const ns_scene *scene, const ns_gpu_scene *gs,
                         gpu_buffer *scene_buffers, gpu_buffer *segments, uint32_t segment_count,
                         gpu_buffer *out_double, gpu_buffer *out_multiple, ns_render_stats *stats,
                         ns_error *err)
{
    if (!ctx || !scene || !gs)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "vrl method: %s is NULL",
                       !ctx     ? "ctx"
                       : !scene ? "scene"
                                : "gs");
    int status = check_gather_buffers(segments, segment_count, out_double, out_multiple, err);
    if (status)
        return status;
    ns_vrl_set set = {0};
    /* Progress: the light paths are the first tenth of this stage, the gather the rest. */
    ns_span outer = ns_progress_push(ctx, 0.0, 0.1);
    status = ns_vrl_method_trace(ctx, scene, gs, scene_buffers, scene->render.vrls,
                                 scene->render.seed, 0, &set, NULL, err);
    ns_progress_pop(ctx, outer);
    uint8_t visibility[NS_MAX_MATERIALS];
    visibility_per_material(scene, visibility);
    ns_vrl_gather_counts counts = {0};
    outer = ns_progress_push(ctx, 0.1, 1.0);
    if (!status)
        status = ns_vrl_method_gather_vrls(ctx, scene_buffers, gs, segments, segment_count,
                                           set.vrls, set.count, scene->render.seed ^ 0x9e3779b9u,
                                           visibility, out_double, out_multiple, &counts, err);
    ns_progress_pop(ctx, outer);
    if (stats) {
        stats->vrl_paths = set.paths;
        stats->vrl_count = set.count;
        stats->interactions += counts.interactions;
    }
    free(set.vrls);
    return status;
}
