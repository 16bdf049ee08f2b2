/* pt.c — one reference path-tracing job: build the GPU scene, upload, one dispatch per
 * sample on lavapipe (its loop limit, docs/rendering.md) accumulating into the pixel
 * buffer, read back. Estimators: shaders/pt.comp and docs/reference.md. */
#include "pt.h"

#include <stdlib.h>
#include <string.h>

#include "pt_shared.h"

_Static_assert((int)NS_PT_SURFACE == (int)NS_COMPONENT_SURFACE &&
                   (int)NS_PT_SINGLE == (int)NS_COMPONENT_SINGLE &&
                   (int)NS_PT_DOUBLE == (int)NS_COMPONENT_DOUBLE &&
                   (int)NS_PT_MULTIPLE == (int)NS_COMPONENT_MULTIPLE,
               "pt_shared.h component bits follow nscatter.h");

enum { PT_PARAMS, PT_NODES, PT_PRIMS, PT_MATERIALS, PT_LIGHTS, PT_PIXELS, PT_COUNTERS, PT_COUNT };

typedef struct pt_job {
    gpu_buffer buffers[PT_COUNT];
    gpu_pipeline pipeline;
    ns_gpu_scene scene;
} pt_job;

uint32_t ns_pt_max_events(uint32_t components, uint32_t max_scatter)
{
    uint32_t highest = NS_NONE;
    if (!(components & NS_COMPONENT_MULTIPLE))
        highest = (components & NS_COMPONENT_DOUBLE)   ? 2
                  : (components & NS_COMPONENT_SINGLE) ? 1
                                                       : 0;
    if (max_scatter && max_scatter < highest)
        highest = max_scatter;
    return highest;
}

static int pt_upload(ns_context *ctx, pt_job *job, uint32_t pixels, ns_error *err)
{
    ns_gpu_scene *gs = &job->scene;
    struct {
        const void *data;
        uint64_t size;
        gpu_buffer_kind kind;
        const char *label;
        int uninitialized;
    } plan[PT_COUNT] = {
        [PT_PARAMS] = {&gs->params, sizeof gs->params, GPU_BUFFER_UNIFORM, "ns.pt.params"},
        [PT_NODES] = {gs->nodes, (uint64_t)gs->node_count * sizeof(GpuNode), GPU_BUFFER_STORAGE,
                      "ns.pt.bvh_nodes"},
        [PT_PRIMS] = {gs->prims, (uint64_t)(gs->bvh_prim_count + gs->plane_count) * sizeof(GpuPrim),
                      GPU_BUFFER_STORAGE, "ns.pt.prims"},
        [PT_MATERIALS] = {gs->materials, (uint64_t)gs->material_count * sizeof(GpuMaterial),
                          GPU_BUFFER_STORAGE, "ns.pt.materials"},
        [PT_LIGHTS] = {gs->lights, (uint64_t)gs->light_count * sizeof(GpuLight), GPU_BUFFER_STORAGE,
                       "ns.pt.lights"},
        /* Written whole by the first dispatch (first_sample 0 overwrites). */
        [PT_PIXELS] = {NULL, (uint64_t)pixels * 4 * sizeof(float), GPU_BUFFER_STORAGE,
                       "ns.pt.pixels", 1},
        [PT_COUNTERS] = {NULL, NS_COUNTER_COUNT * sizeof(uint32_t), GPU_BUFFER_STORAGE,
                         "ns.pt.counters"},
    };
    for (int i = 0; i < PT_COUNT; i++) {
        int status =
            gpu_buffer_create(&ctx->dev, &job->buffers[i],
                              &(gpu_buffer_desc){.size = plan[i].size,
                                                 .kind = plan[i].kind,
                                                 .data = plan[i].data,
                                                 .data_size = plan[i].data ? plan[i].size : 0,
                                                 .uninitialized = plan[i].uninitialized,
                                                 .label = plan[i].label},
                              err);
        if (status)
            return status;
    }
    return NS_OK;
}

static int pt_check_counters(const uint32_t *counters, ns_error *err)
{
    if (counters[NS_COUNTER_LOOP_LIMIT])
        return ns_fail(err, NS_ERR_LIMIT,
                       "pt: %u pixel sample(s) ran past lavapipe's loop limit (65535 "
                       "iterations per invocation); the media are too thick (optical size) or "
                       "the scene too large for the reference on this device",
                       counters[NS_COUNTER_LOOP_LIMIT]);
    if (counters[NS_PT_COUNTER_TRUNCATED])
        return ns_fail(err, NS_ERR_LIMIT,
                       "pt: %u path(s) took more than %u boundary events in a row (trapped by "
                       "total internal reflection?)",
                       counters[NS_PT_COUNTER_TRUNCATED], (unsigned)NS_PT_MAX_BOUNDARY_RUN);
    if (counters[NS_PT_COUNTER_NONFINITE])
        return ns_fail(err, NS_ERR_INTERNAL, "pt: %u sample(s) came out NaN or infinite",
                       counters[NS_PT_COUNTER_NONFINITE]);
    return NS_OK;
}

static int pt_dispatch(ns_context *ctx, pt_job *job, const ns_scene *scene, ns_error *err)
{
    gpu_buffer *bound[PT_COUNT];
    for (int i = 0; i < PT_COUNT; i++)
        bound[i] = &job->buffers[i];
    const ns_camera *cam = &scene->camera;
    uint32_t spp = scene->render.spp;
    uint32_t per_dispatch = ctx->dev.loop_limited ? 1 : NS_PT_SAMPLES_PER_DISPATCH;
    uint32_t dispatches = (spp + per_dispatch - 1) / per_dispatch;
    GpuPtPush *push = calloc(dispatches, sizeof *push);
    if (!push)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "pt: %u dispatches", dispatches);
    uint32_t max_events = ns_pt_max_events(scene->render.components, scene->render.max_scatter);
    for (uint32_t i = 0; i < dispatches; i++) {
        push[i].first_sample = i * per_dispatch;
        push[i].sample_count =
            spp - push[i].first_sample < per_dispatch ? spp - push[i].first_sample : per_dispatch;
        push[i].components = scene->render.components;
        push[i].max_events = max_events;
    }
    int status = gpu_dispatch_many(
        &ctx->dev,
        &(gpu_dispatch_desc){
            .pipeline = &job->pipeline,
            .buffers = bound,
            .buffer_count = PT_COUNT,
            .groups = {(cam->width + NS_CAMERA_GROUP_X - 1) / NS_CAMERA_GROUP_X,
                       (cam->height + NS_CAMERA_GROUP_Y - 1) / NS_CAMERA_GROUP_Y, 1},
            .push = push,
            .dispatch_count = dispatches,
        },
        err);
    free(push);
    if (!status)
        status = pt_check_counters(job->buffers[PT_COUNTERS].mapped, err);
    return status;
}

static int pt_read_back(pt_job *job, const ns_camera *cam, ns_image *out, ns_error *err)
{
    size_t pixels = (size_t)cam->width * cam->height;
    out->rgb = malloc(pixels * 3 * sizeof(float));
    if (!out->rgb)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "image: %zu pixels", pixels);
    out->width = cam->width;
    out->height = cam->height;
    const float *src = job->buffers[PT_PIXELS].mapped;
    for (size_t i = 0; i < pixels; i++)
        memcpy(out->rgb + 3 * i, src + 4 * i, 3 * sizeof(float));
    return NS_OK;
}

int ns_pt_render(ns_context *ctx, const ns_scene *scene, ns_image *out, ns_render_stats *stats,
                 ns_error *err)
{
    pt_job job;
    memset(&job, 0, sizeof job);
    double t0 = ns_now_ms();
    int status = gpu_pipeline_create(&ctx->dev, &job.pipeline,
                                     &(gpu_pipeline_desc){.shader = "pt",
                                                          .binding_count = PT_COUNT,
                                                          .push_constant_size = sizeof(GpuPtPush)},
                                     err);
    double t1 = ns_now_ms();
    ns_stats_add_stage(stats, "pt_pipeline", t1 - t0);
    if (!status)
        status = ns_gpu_scene_build(scene, &job.scene, err);
    if (!status) {
        job.scene.params.limits[0] = ctx->dev.loop_limited ? NS_LAVAPIPE_LOOP_BUDGET : 0;
        if (stats) {
            stats->bvh_nodes = job.scene.node_count;
            stats->primitives = job.scene.bvh_prim_count + job.scene.plane_count;
        }
    }
    double t2 = ns_now_ms();
    ns_stats_add_stage(stats, "bvh", t2 - t1);
    if (!status)
        status = pt_upload(ctx, &job, scene->camera.width * scene->camera.height, err);
    double t3 = ns_now_ms();
    ns_stats_add_stage(stats, "upload", t3 - t2);
    if (!status)
        status = pt_dispatch(ctx, &job, scene, err);
    double t4 = ns_now_ms();
    ns_stats_add_stage(stats, "pt_pass", t4 - t3);
    if (!status)
        status = pt_read_back(&job, &scene->camera, out, err);
    ns_stats_add_stage(stats, "readback", ns_now_ms() - t4);
    for (int i = 0; i < PT_COUNT; i++)
        gpu_buffer_destroy(&ctx->dev, &job.buffers[i]);
    gpu_pipeline_destroy(&ctx->dev, &job.pipeline);
    ns_gpu_scene_free(&job.scene);
    return status;
}
