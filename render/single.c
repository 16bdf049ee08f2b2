/* single.c — single scattering along the camera segments (shaders/single.comp, or
 * single_box_faces.comp where a box of a refracting medium scatters): checks the
 * arguments and splits each segment's samples across dispatches so that no invocation runs
 * past lavapipe's loop limit (shared.h). The cost of a sample depends on the scene (BVH
 * depth, lights), so it is measured: a first dispatch takes sample 0 alone and reports the
 * most loop iterations any invocation counted; the remaining samples go in chunks sized
 * from that (SINGLE_COST_FACTOR). The shader detects an invocation whose loops were cut
 * short anyway; then every sample is run again in smaller chunks, and when one sample alone
 * is too much the call fails with NS_ERR_LIMIT: a wrong result is never returned. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scatter.h"

enum { SINGLE_GROUP = 64 };

/* More samples per segment than this is refused: on lavapipe each may need its own
 * dispatch, and far fewer already converge (the integrand is smooth along a segment). */
#define SINGLE_SAMPLES_MAX 65536u

enum { COUNTER_CUT_SHORT, COUNTER_MAX_LOOPS, COUNTER_COUNT };

/* lavapipe counts loop iterations that the shaders' own count (out_of_budget in trace.glsl)
 * does not see: a leaf's primitives, the planes, every loop's exit test, and a SIMD group
 * iterates as long as any of its lanes does. Measured in the one-box slab of
 * tests/gpu_single.c: 5 counted iterations per sample, but 2000 samples ran past 65535 and
 * 1500 did not, so 6.5 to 8.7 real iterations per counted one. Chunks are sized for 16; should
 * one still be cut short (the shader detects it), every sample is run again in chunks a
 * quarter the size. */
#define SINGLE_COST_FACTOR 16u

static int check_arguments(const gpu_buffer *scene_buffers, const gpu_buffer *segments,
                           uint32_t segment_count, uint32_t samples, const gpu_buffer *out,
                           ns_error *err)
{
    if (!scene_buffers || !segments || !out)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "single scattering: %s is NULL",
                       !scene_buffers ? "scene_buffers"
                       : !segments    ? "segments"
                                      : "out");
    if (samples == 0 || samples > SINGLE_SAMPLES_MAX)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "single scattering: samples %u must be in [1, %u]", samples,
                       SINGLE_SAMPLES_MAX);
    if (segments->size < (uint64_t)segment_count * sizeof(GpuSegment))
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "single scattering: segments buffer holds %llu bytes, %u segments need %llu",
                       (unsigned long long)segments->size, segment_count,
                       (unsigned long long)segment_count * sizeof(GpuSegment));
    if (out->size < (uint64_t)segment_count * 4 * sizeof(float))
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "single scattering: out buffer holds %llu bytes, %u segments need %llu",
                       (unsigned long long)out->size, segment_count,
                       (unsigned long long)segment_count * 4 * sizeof(float));
    if (scene_buffers[0].size < sizeof(GpuParams) || !scene_buffers[0].mapped)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "single scattering: scene_buffers[0] is not the scene's parameters");
    return NS_OK;
}

static uint32_t cut_short(const gpu_buffer *counters)
{
    return ((const uint32_t *)counters->mapped)[COUNTER_CUT_SHORT];
}

static int cut_short_error(const gpu_buffer *counters, ns_error *err)
{
    return ns_fail(err, NS_ERR_LIMIT,
                   "single scattering: %u segment(s) ran past lavapipe's loop limit (65535 "
                   "iterations per invocation) within one sample; lower the light count or the "
                   "geometry, or pick another device",
                   cut_short(counters));
}

/* Push blocks for samples [first, end) of `samples` in chunks of per_dispatch; returns the
 * number of blocks written. */
static uint32_t chunk_samples(uint32_t first, uint32_t end, uint32_t samples, uint32_t per_dispatch,
                              uint32_t segment_count, GpuSinglePush *push)
{
    uint32_t n = 0;
    for (uint32_t s = first; s < end; s += per_dispatch)
        push[n++] = (GpuSinglePush){.first_sample = s,
                                    .sample_count = end - s < per_dispatch ? end - s : per_dispatch,
                                    .samples = samples,
                                    .segment_count = segment_count};
    return n;
}

/* Runs samples [first, end) of `samples` in chunks of per_dispatch, in one submission: a
 * round of ns_resume_dispatch whose dispatches are all known in advance (each chunk its own
 * push block, no work-left count). NS_RESUME_CUT when an invocation was cut short. */
static int run_chunks(ns_context *ctx, const gpu_pipeline *pipeline, gpu_buffer **bound,
                      uint32_t segment_count, uint32_t first, uint32_t end, uint32_t samples,
                      uint32_t per_dispatch, GpuSinglePush *push, ns_error *err)
{
    uint32_t n = chunk_samples(first, end, samples, per_dispatch, segment_count, push);
    return ns_resume_dispatch(
        ctx,
        &(ns_resume_desc){
            .pipeline = pipeline,
            .buffers = bound,
            .groups = {(segment_count + SINGLE_GROUP - 1) / SINGLE_GROUP, 1, 1},
            .push = push,
            .push_count = n,
            .report_offset = NS_NONE,
            .counters = bound[NS_SCENE_BUFFER_COUNT + 2]->mapped,
            .unfinished = NS_NONE,
            .cut = COUNTER_CUT_SHORT,
        },
        NULL, err);
}

static int run_dispatches(ns_context *ctx, gpu_buffer **bound, uint32_t segment_count,
                          uint32_t samples, uint32_t budget, ns_error *err)
{
    const gpu_buffer *counters = bound[NS_SCENE_BUFFER_COUNT + 2];
    gpu_pipeline *pipeline;
    /* A box of a refracting medium passes light through each face that sees a light: its
     * own form of the shader (single_box_faces.comp), which other scenes do not carry. */
    const GpuParams *params = bound[0]->mapped;
    int status =
        ns_pipeline(ctx, params->surface[2] ? NS_PIPELINE_SINGLE_BOX_FACES : NS_PIPELINE_SINGLE,
                    &pipeline, NULL, err);
    if (status)
        return status;
    GpuSinglePush *push = calloc(samples, sizeof *push);
    if (!push)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "single scattering: %u dispatches", samples);
    if (!budget) {
        status = run_chunks(ctx, pipeline, bound, segment_count, 0, samples, samples, samples, push,
                            err);
        if (status == NS_RESUME_CUT)
            status = cut_short_error(counters, err);
        free(push);
        return status;
    }
    /* Sample 0 alone measures the cost of one sample (and is its share of the progress). */
    ns_span outer = ns_progress_push(ctx, 0.0, 1.0 / samples);
    status = run_chunks(ctx, pipeline, bound, segment_count, 0, 1, samples, 1, push, err);
    ns_progress_pop(ctx, outer);
    if (status == NS_RESUME_CUT)
        status = cut_short_error(counters, err);
    uint32_t cost = ((const uint32_t *)counters->mapped)[COUNTER_MAX_LOOPS];
    uint32_t per_dispatch = budget / (SINGLE_COST_FACTOR * (cost ? cost : 1));
    per_dispatch = per_dispatch ? per_dispatch : 1;
    uint32_t first = 1;
    outer = ns_progress_push(ctx, 1.0 / samples, 1.0);
    while (!status && samples > 1) {
        status = run_chunks(ctx, pipeline, bound, segment_count, first, samples, samples,
                            per_dispatch, push, err);
        if (status != NS_RESUME_CUT)
            break;
        if (per_dispatch == 1) {
            status = cut_short_error(counters, err);
            break;
        }
        /* Some chunk was cut short and its segments' sums are wrong: all samples again, in
         * smaller chunks (the chunk that starts at sample 0 overwrites the output). */
        per_dispatch = per_dispatch / 4 ? per_dispatch / 4 : 1;
        first = 0;
        status = NS_OK;
    }
    ns_progress_pop(ctx, outer);
    free(push);
    return status;
}

/* A segment's strata as single.comp's segment_strata counts them: `samples` scaled by its
 * largest throughput, at least 1. Only the order below uses it: should the two drift apart,
 * the SIMD groups are less full, the result the same. */
static uint32_t segment_strata(const GpuSegment *seg, uint32_t samples)
{
    float w = seg->throughput[0];
    w = seg->throughput[1] > w ? seg->throughput[1] : w;
    w = seg->throughput[2] > w ? seg->throughput[2] : w;
    float scaled = ceilf((float)samples * (w < 1.0f ? w : 1.0f));
    return !(scaled >= 1.0f) ? 1u : scaled > (float)samples ? samples : (uint32_t)scaled;
}

int ns_single_order(const GpuSegment *segs, uint32_t count, uint32_t samples, uint32_t *order)
{
    /* A counting sort on samples - strata: most strata first, stable. (0 samples, which
     * ns_single_scatter refuses, keeps the order.) */
    samples = samples ? samples : 1;
    uint32_t *start = calloc((size_t)samples + 1, sizeof *start);
    if (!start)
        return -1;
    for (uint32_t i = 0; i < count; i++)
        start[samples - segment_strata(&segs[i], samples) + 1]++;
    for (uint32_t k = 0; k < samples; k++)
        start[k + 1] += start[k];
    for (uint32_t i = 0; i < count; i++)
        order[start[samples - segment_strata(&segs[i], samples)]++] = i;
    free(start);
    return 0;
}

int ns_single_scatter(ns_context *ctx, gpu_buffer *scene_buffers, gpu_buffer *segments,
                      uint32_t segment_count, uint32_t samples, gpu_buffer *out, ns_error *err)
{
    if (!ctx)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "single scattering: no context");
    int status = check_arguments(scene_buffers, segments, segment_count, samples, out, err);
    if (status || !segment_count)
        return status;
    /* The shaders' loop budget travels in the scene's parameters (render.c sets it on
     * lavapipe); without it lavapipe would cut loops short silently. */
    const GpuParams *params = scene_buffers[0].mapped;
    uint32_t budget = params->limits[0];
    if (ctx->dev.loop_limited && !budget)
        return ns_fail(err, NS_ERR_INTERNAL,
                       "single scattering: the scene parameters carry no loop budget "
                       "(limits.x) on a loop-limited device");

    gpu_buffer counters = {0};
    status = gpu_buffer_create(
        &ctx->dev, &counters,
        &(gpu_buffer_desc){.size = COUNTER_COUNT * sizeof(uint32_t), .label = "ns.single.counters"},
        err);
    if (!status) {
        gpu_buffer *bound[NS_SCENE_BUFFER_COUNT + 3];
        for (int i = 0; i < NS_SCENE_BUFFER_COUNT; i++)
            bound[i] = &scene_buffers[i];
        bound[NS_SCENE_BUFFER_COUNT] = segments;
        bound[NS_SCENE_BUFFER_COUNT + 1] = out;
        bound[NS_SCENE_BUFFER_COUNT + 2] = &counters;
        status = run_dispatches(ctx, bound, segment_count, samples, budget, err);
    }
    gpu_buffer_destroy(&ctx->dev, &counters);
    return status;
}

void ns_single_unit_materials(const GpuMaterial *materials, uint32_t count, GpuMaterial *unit,
                              float reference[3])
{
    for (int c = 0; c < 3; c++) {
        reference[c] = 0.0f;
        for (uint32_t i = 0; i < count; i++)
            reference[c] = fmaxf(reference[c], materials[i].sigma_s[c]);
    }
    for (uint32_t i = 0; i < count; i++) {
        unit[i] = materials[i];
        for (int c = 0; c < 3; c++)
            unit[i].sigma_s[c] =
                reference[c] > 0.0f ? materials[i].sigma_s[c] / reference[c] : 0.0f;
    }
}
