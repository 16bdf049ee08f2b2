/* trace_rays.c — the BVH test path (tests and the ray benchmark only): rays against
 * primitives through shaders/trace_test.comp, without a scene or a camera. Kept apart from
 * render.c so that render.c shows the render's main path alone; its pipeline is made by the
 * first call and kept (render/pipelines.c), so a service that never traces test rays never
 * compiles it. */
#include <stdlib.h>
#include <string.h>

#include "bvh.h"
#include "internal.h"

int ns_trace_rays(ns_context *ctx, const GpuPrim *prims, uint32_t prim_count, const GpuPrim *planes,
                  uint32_t plane_count, const GpuRay *rays, uint32_t ray_count, GpuHit *hits,
                  ns_error *err)
{
    return ns_trace_rays_timed(ctx, prims, prim_count, planes, plane_count, rays, ray_count, hits,
                               &(ns_trace_timing){.repeats = 1}, err);
}

int ns_trace_rays_timed(ns_context *ctx, const GpuPrim *prims, uint32_t prim_count,
                        const GpuPrim *planes, uint32_t plane_count, const GpuRay *rays,
                        uint32_t ray_count, GpuHit *hits, const ns_trace_timing *timing,
                        ns_error *err)
{
    uint32_t repeats = timing->repeats ? timing->repeats : 1;
    ns_bvh bvh;
    int status = ns_bvh_build_limited(prims, prim_count,
                                      timing->max_depth ? timing->max_depth : NS_BVH_MAX_DEPTH,
                                      &bvh, err);
    GpuPrim *all = status ? NULL : malloc(sizeof *all * ((size_t)prim_count + plane_count + 1));
    if (!status && !all)
        status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "trace: primitives");
    gpu_buffer buffers[5];
    memset(buffers, 0, sizeof buffers);
    if (!status) {
        if (prim_count)
            memcpy(all, bvh.prims, sizeof *all * prim_count);
        if (plane_count)
            memcpy(all + prim_count, planes, sizeof *all * plane_count);
        GpuParams params = {0};
        params.counts[3] = bvh.node_count;
        params.prims[0] = prim_count;
        params.prims[1] = plane_count;
        params.prims[3] = ray_count;
        const struct {
            const void *data;
            uint64_t size;
        } plan[5] = {
            {&params, sizeof params},
            {bvh.nodes, (uint64_t)bvh.node_count * sizeof(GpuNode)},
            {all, ((uint64_t)prim_count + plane_count) * sizeof(GpuPrim)},
            {rays, (uint64_t)ray_count * sizeof(GpuRay)},
            {NULL, (uint64_t)ray_count * sizeof(GpuHit)},
        };
        for (int i = 0; i < 5 && !status; i++)
            status = gpu_buffer_create(
                &ctx->dev, &buffers[i],
                &(gpu_buffer_desc){.size = plan[i].size,
                                   .kind = i ? GPU_BUFFER_STORAGE : GPU_BUFFER_UNIFORM,
                                   .data = plan[i].data,
                                   .data_size = plan[i].data ? plan[i].size : 0,
                                   .label = "ns.trace_test"},
                err);
    }
    if (!status) {
        gpu_buffer *bound[5] = {&buffers[0], &buffers[1], &buffers[2], &buffers[3], &buffers[4]};
        /* The lock covers making the pipeline (the first call) as well as the dispatch. */
        pthread_mutex_lock(&ctx->lock);
        gpu_pipeline *pipeline = NULL;
        status = ns_pipeline(ctx, NS_PIPELINE_TRACE_TEST, &pipeline, NULL, err);
        /* The same rays again on the same buffers: every dispatch writes every hit. */
        for (uint32_t r = 0; r < repeats && !status; r++) {
            double start = ns_now_ms();
            status = gpu_dispatch_many(
                &ctx->dev,
                &(gpu_dispatch_desc){
                    .pipeline = pipeline,
                    .buffers = bound,
                    .buffer_count = 5,
                    .groups = {(ray_count + NS_TRACE_GROUP - 1) / NS_TRACE_GROUP, 1, 1},
                    .device_ms = timing->device_ms ? &timing->device_ms[r] : NULL},
                err);
            if (timing->wall_ms)
                timing->wall_ms[r] = ns_now_ms() - start;
            if (!status && timing->between)
                timing->between(timing->user, r);
        }
        pthread_mutex_unlock(&ctx->lock);
    }
    if (!status) {
        memcpy(hits, buffers[4].mapped, sizeof *hits * ray_count);
        /* Back from tree order to the caller's order. */
        for (uint32_t i = 0; i < ray_count; i++)
            if (hits[i].prim != NS_NONE && hits[i].prim < prim_count)
                hits[i].prim = bvh.order[hits[i].prim];
    }
    for (int i = 0; i < 5; i++)
        gpu_buffer_destroy(&ctx->dev, &buffers[i]);
    free(all);
    ns_bvh_free(&bvh);
    return status;
}
