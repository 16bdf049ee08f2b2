/* pt.c — one reference path-tracing job: build the GPU scene, upload, dispatch until every
 * pixel has finished its samples (paths suspended between dispatches because of lavapipe's
 * loop limit, docs/rendering.md), read back. Estimators: shaders/pt.comp and
 * docs/reference.md. */
#include "pt.h"

#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "pt_shared.h"

_Static_assert((int)NS_PT_SURFACE == (int)NS_COMPONENT_SURFACE &&
                   (int)NS_PT_SINGLE == (int)NS_COMPONENT_SINGLE &&
                   (int)NS_PT_DOUBLE == (int)NS_COMPONENT_DOUBLE &&
                   (int)NS_PT_MULTIPLE == (int)NS_COMPONENT_MULTIPLE,
               "pt_shared.h component bits follow nscatter.h");

enum {
    PT_PARAMS,
    PT_NODES,
    PT_PRIMS,
    PT_MATERIALS,
    PT_LIGHTS,
    PT_PIXELS,
    PT_COUNTERS,
    PT_PATHS,
    PT_COUNT
};

typedef struct pt_job {
    gpu_buffer buffers[PT_COUNT];
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

/* ---------------------------------------------------------------------------------------
 * Media behind refracting boundaries and delta lights (docs/reference.md).
 * ------------------------------------------------------------------------------------- */
static int pt_refracting_scatterer(const ns_material *mat)
{
    return mat->type == NS_MATERIAL_MEDIUM && mat->ior != 1.0f &&
           (mat->sigma_s[0] > 0 || mat->sigma_s[1] > 0 || mat->sigma_s[2] > 0);
}

static void pt_grow(float lo[3], float hi[3], const float p[3], float pad)
{
    for (int k = 0; k < 3; k++) {
        lo[k] = p[k] - pad < lo[k] ? p[k] - pad : lo[k];
        hi[k] = p[k] + pad > hi[k] ? p[k] + pad : hi[k];
    }
}

typedef struct pt_light_plan {
    uint32_t delta_lights;     /* point + directional lights; 0 = no light sub-paths */
    float target[4];           /* sphere around every refracting scattering medium */
    int unbounded;             /* such a medium on a plane: no target sphere */
    int first_delta, material; /* for the refusal message */
} pt_light_plan;

static void pt_plan_light_subpaths(const ns_scene *scene, pt_light_plan *plan)
{
    memset(plan, 0, sizeof *plan);
    plan->first_delta = plan->material = -1;
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (uint32_t o = 0; o < scene->object_count; o++) {
        const ns_object *obj = &scene->objects[o];
        if (!pt_refracting_scatterer(&scene->materials[obj->material]))
            continue;
        if (plan->material < 0)
            plan->material = (int)obj->material;
        if (obj->shape == NS_SHAPE_SPHERE) {
            pt_grow(lo, hi, obj->center, obj->radius);
        } else if (obj->shape == NS_SHAPE_BOX) {
            pt_grow(lo, hi, obj->min, 0);
            pt_grow(lo, hi, obj->max, 0);
        } else if (obj->shape == NS_SHAPE_MESH) {
            for (uint32_t t = 0; t < obj->triangle_count; t++)
                for (int v = 0; v < 3; v++)
                    pt_grow(lo, hi, scene->triangles[obj->first_triangle + t].v[v], 0);
        } else {
            plan->unbounded = 1;
        }
    }
    for (uint32_t l = 0; l < scene->light_count; l++)
        if (scene->lights[l].type == NS_LIGHT_DIRECTIONAL ||
            scene->lights[l].type == NS_LIGHT_POINT) {
            if (plan->first_delta < 0)
                plan->first_delta = (int)l;
            plan->delta_lights++;
        }
    if (plan->material < 0 || plan->unbounded || !(lo[0] <= hi[0])) {
        plan->delta_lights = 0;
        return;
    }
    float r2 = 0;
    for (int k = 0; k < 3; k++) {
        plan->target[k] = 0.5f * (lo[k] + hi[k]);
        r2 += 0.25f * (hi[k] - lo[k]) * (hi[k] - lo[k]);
    }
    plan->target[3] = sqrtf(r2) * 1.0001f + 1e-6f;
}

/* Light sub-paths give every order from 2 up, and the specular connection (manifold
 * next-event estimation, pt.comp) the single order. The sub-paths aim at a sphere around the
 * refracting media, so a render that needs them while such a medium is an unbounded plane is
 * refused rather than returned without that light. */
static int pt_check_reachable(const ns_scene *scene, const pt_light_plan *plan, ns_error *err)
{
    if (plan->first_delta < 0 || plan->material < 0 || !plan->unbounded)
        return NS_OK;
    uint32_t missing = scene->render.components & (NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE);
    if (!missing)
        return NS_OK;
    static const char *kinds[] = {"directional", "point"};
    const ns_material *mat = &scene->materials[plan->material];
    return ns_fail(err, NS_ERR_NOT_AVAILABLE,
                   "pt: lights[%d] (%s) reaches medium '%s' (materials[%d], ior %g) only "
                   "through its refracting boundary, and that medium is a plane: the light "
                   "sub-paths of its double and multiple scattering need a bounded medium; "
                   "leave out components \"double\" and \"multiple\", or use "
                   "sphere/environment lights or ior 1",
                   plan->first_delta, kinds[scene->lights[plan->first_delta].type], mat->name,
                   plan->material, (double)mat->ior);
}

_Static_assert(PT_LIGHTS + 1 == NS_SCENE_BUFFER_COUNT, "pt.comp binds the scene buffers first");

static int pt_upload(ns_context *ctx, pt_job *job, uint32_t pixels, ns_error *err)
{
    gpu_buffer_desc descs[PT_COUNT];
    ns_gpu_scene_buffer_descs(&job->scene, descs);
    /* All three start zeroed: the sums, the counters, and paths that read as "sample 0
     * next". */
    descs[PT_PIXELS] = (gpu_buffer_desc){.size = (uint64_t)pixels * 4 * sizeof(float),
                                         .kind = GPU_BUFFER_STORAGE,
                                         .host_reads = 1,
                                         .label = "ns.pt.pixels"};
    /* Progress scans every path's sample count after each submission. */
    descs[PT_PATHS] = (gpu_buffer_desc){.size = (uint64_t)pixels * sizeof(GpuPtPath),
                                        .kind = GPU_BUFFER_STORAGE,
                                        .host_reads = 1,
                                        .label = "ns.pt.paths"};
    descs[PT_COUNTERS] = (gpu_buffer_desc){.size = NS_PT_COUNTER_COUNT * sizeof(uint32_t),
                                           .kind = GPU_BUFFER_STORAGE,
                                           .label = "ns.pt.counters"};
    return gpu_buffers_create(&ctx->dev, job->buffers, descs, PT_COUNT, err);
}

/* After every submission (ns_resume_desc.check): the first problem the counters show. */
static int pt_check_counters(const uint32_t *counters, void *user, ns_error *err)
{
    (void)user;
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
    if (counters[NS_PT_COUNTER_LIGHT_TRUNCATED])
        return ns_fail(err, NS_ERR_LIMIT,
                       "pt: %u light sub-path(s) took more than %u boundary events in a row "
                       "without scattering",
                       counters[NS_PT_COUNTER_LIGHT_TRUNCATED],
                       (unsigned)NS_PT_MAX_LIGHT_BOUNDARIES);
    if (counters[NS_PT_COUNTER_NONFINITE])
        return ns_fail(err, NS_ERR_INTERNAL, "pt: %u sample(s) came out NaN or infinite",
                       counters[NS_PT_COUNTER_NONFINITE]);
    return NS_OK;
}

/* The part of the pass done, for the progress TICK after each submission: the samples
 * finished over all of them. Each pixel's saved path holds its next sample index
 * (GpuPtPath.progress.y) and whether that sample's path is still under way (progress.z). */
typedef struct pt_samples {
    const GpuPtPath *paths;
    uint32_t pixels, spp;
} pt_samples;

static double pt_samples_done(void *user)
{
    const pt_samples *p = user;
    uint64_t done = 0;
    for (uint32_t i = 0; i < p->pixels; i++)
        done += p->paths[i].progress[1] - (p->paths[i].progress[2] != 0u);
    return (double)done / ((double)p->pixels * p->spp);
}

/* Submissions of 1, 2, 4, ... 16 dispatches (ns_resume_dispatch) until the last dispatch of
 * one finds every pixel done: a pixel's samples may need many dispatches when its paths are
 * long (each dispatch yields after NS_PT_YIELD_LAVAPIPE counted iterations on lavapipe). */
static int pt_dispatch(ns_context *ctx, const gpu_pipeline *pipeline, pt_job *job,
                       const ns_scene *scene, const pt_light_plan *plan, uint32_t *dispatched,
                       ns_error *err)
{
    gpu_buffer *bound[PT_COUNT];
    for (int i = 0; i < PT_COUNT; i++)
        bound[i] = &job->buffers[i];
    const ns_camera *cam = &scene->camera;
    uint32_t *counters = job->buffers[PT_COUNTERS].mapped;
    GpuPtPush push = {
        .target = {plan->target[0], plan->target[1], plan->target[2], plan->target[3]},
        .delta_lights = plan->delta_lights,
        .components = scene->render.components,
        .max_events = ns_pt_max_events(scene->render.components, scene->render.max_scatter),
        .yield_after = ctx->dev.loop_limited ? NS_PT_YIELD_LAVAPIPE : 1u << 24,
    };
    *dispatched = 0;
    pt_samples samples = {.paths = job->buffers[PT_PATHS].mapped,
                          .pixels = cam->width * cam->height,
                          .spp = scene->render.spp};
    /* An invocation that lavapipe cut short anyway is an error here (pt_check_counters's
     * first check), not a reason to start again with a smaller budget as in the vrl method. */
    int status = ns_resume_dispatch(
        ctx,
        &(ns_resume_desc){
            .pipeline = pipeline,
            .buffers = bound,
            .groups = {(cam->width + NS_CAMERA_GROUP_X - 1) / NS_CAMERA_GROUP_X,
                       (cam->height + NS_CAMERA_GROUP_Y - 1) / NS_CAMERA_GROUP_Y, 1},
            .push = &push,
            .push_count = 1,
            .report_offset = offsetof(GpuPtPush, report),
            .counters = counters,
            .unfinished = NS_PT_COUNTER_UNFINISHED,
            .cut = NS_NONE,
            .first_batch = 1,
            .max_batch = 16,
            .max_dispatches = NS_PT_MAX_DISPATCHES,
            .check = pt_check_counters,
            .done = pt_samples_done,
            .done_user = &samples,
        },
        dispatched, err);
    if (status == NS_RESUME_GAVE_UP)
        status = ns_fail(err, NS_ERR_LIMIT,
                         "pt: not finished after %u dispatches (%u pixels left); the media "
                         "are too thick or spp too high for the reference on this device",
                         *dispatched, counters[NS_PT_COUNTER_UNFINISHED]);
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

/* Progress (internal.h): pt_pipeline 0-2% (the context's first pt render only), bvh 2-3%,
 * upload 3-4%, pt_pass 4-99% by the samples finished, readback 99-100%. */
int ns_pt_render(ns_context *ctx, const ns_scene *scene, ns_image *out, ns_render_stats *stats,
                 ns_error *err)
{
    pt_light_plan plan;
    pt_plan_light_subpaths(scene, &plan);
    int reachable = pt_check_reachable(scene, &plan, err);
    if (reachable)
        return reachable;
    pt_job job;
    memset(&job, 0, sizeof job);
    /* Made by the first pt render of this context (the caller holds its lock) and kept. */
    gpu_pipeline *pipeline = NULL;
    int status = NS_OK;
    if (ctx->pipelines[NS_PIPELINE_PT].pipeline) {
        status = ns_pipeline(ctx, NS_PIPELINE_PT, &pipeline, NULL, err);
    } else {
        ns_stage stage = ns_stage_begin(ctx, "pt_pipeline", 0.0, 0.02);
        status = ns_pipeline(ctx, NS_PIPELINE_PT, &pipeline, NULL, err);
        ns_stats_add_stage(stats, "pt_pipeline", ns_stage_end(ctx, &stage));
    }
    if (!status)
        status = ns_run_check(ctx, err);
    /* Always a stage of its own, also when the BVH was kept (render.c says the same). */
    ns_stage stage = ns_stage_begin(ctx, "bvh", 0.02, 0.03);
    int reused = 0;
    if (!status)
        status = ns_gpu_scene_build_reusing(scene, &ctx->bvh, &job.scene, &reused, err);
    if (!status) {
        /* No limit inside the traversal: pt yields between path steps instead (push). */
        job.scene.params.limits[0] = 0;
        if (stats) {
            stats->bvh_nodes = job.scene.node_count;
            stats->primitives = job.scene.bvh_prim_count + job.scene.plane_count;
            stats->bvh_reused = (uint32_t)reused;
        }
    }
    ns_stats_add_stage(stats, "bvh", ns_stage_end(ctx, &stage));
    if (!status)
        status = ns_run_check(ctx, err);
    stage = ns_stage_begin(ctx, "upload", 0.03, 0.04);
    if (!status)
        status = pt_upload(ctx, &job, scene->camera.width * scene->camera.height, err);
    ns_stats_add_stage(stats, "upload", ns_stage_end(ctx, &stage));
    uint32_t dispatched = 0;
    stage = ns_stage_begin(ctx, "pt_pass", 0.04, 0.99);
    if (!status)
        status = pt_dispatch(ctx, pipeline, &job, scene, &plan, &dispatched, err);
    ns_stats_add_stage(stats, "pt_pass", ns_stage_end(ctx, &stage));
    (void)dispatched; /* not in ns_render_stats (a shared struct); measured by the tests */
    /* The work is done; a cancellation that comes now still cancels (no image). */
    if (!status)
        status = ns_run_check(ctx, err);
    stage = ns_stage_begin(ctx, "readback", 0.99, 1.0);
    if (!status)
        status = pt_read_back(&job, &scene->camera, out, err);
    ns_stats_add_stage(stats, "readback", ns_stage_end(ctx, &stage));
    for (int i = 0; i < PT_COUNT; i++)
        gpu_buffer_destroy(&ctx->dev, &job.buffers[i]);
    ns_gpu_scene_free(&job.scene);
    return status;
}
