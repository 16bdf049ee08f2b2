/* render.c — one render job: validate, build the GPU scene (BVH), upload, run the camera
 * pass, read back. The job owns every buffer it creates and frees them on every path.
 *
 * Progress (internal.h): bvh 0-1%, upload 1-2%, the camera pass and the scattering stages
 * 2-98% (shared out among the camera batches by their samples, and within a batch as
 * ns_batch_shares says), the added camera samples 98-99%, readback 99-100%. pt.c plans its
 * own stages the same way. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"
#include "pt.h"
#include "scatter.h"

/* Segment buffer: room for two stretches per camera sample by default, within 120 MiB
 * (lavapipe caps a storage buffer at 128 MiB). */
#define SEGMENTS_PER_SAMPLE 2u
#define SEGMENT_BYTES_MAX (120u << 20)

enum {
    B_PARAMS,
    B_NODES,
    B_PRIMS,
    B_MATERIALS,
    B_LIGHTS,
    B_PIXELS,
    B_SEGMENTS,
    B_COUNTERS,
    B_COUNT
};

typedef struct render_job {
    gpu_buffer buffers[B_COUNT];
    gpu_buffer added; /* render.adaptive_spp: the added samples (camera.comp's binding 8) */
    ns_gpu_scene scene;
} render_job;

static void job_free(ns_context *ctx, render_job *job)
{
    for (int i = 0; i < B_COUNT; i++)
        gpu_buffer_destroy(&ctx->dev, &job->buffers[i]);
    gpu_buffer_destroy(&ctx->dev, &job->added);
    ns_gpu_scene_free(&job->scene);
}

static void component_names(uint32_t bits, char *out, size_t size)
{
    out[0] = '\0';
    for (int i = 0; i < NS_COMPONENT_COUNT; i++)
        if (bits & (1u << i)) {
            size_t used = strlen(out);
            snprintf(out + used, size - used, "%s%s", used ? ", " : "", ns_component_name(1u << i));
        }
}

/* How many elements of `size` bytes one of the render's storage buffers may hold: within
 * SEGMENT_BYTES_MAX and the device's range. */
static uint64_t storage_capacity(const ns_context *ctx, size_t size)
{
    uint64_t cap = SEGMENT_BYTES_MAX / size;
    uint64_t device_cap = ctx->dev.properties.limits.maxStorageBufferRange / size;
    return cap < device_cap ? cap : device_cap;
}

static uint32_t segment_capacity(const ns_context *ctx, const ns_scene *scene,
                                 const ns_render_debug *debug)
{
    if (debug && debug->segment_capacity)
        return debug->segment_capacity;
    uint64_t want = (uint64_t)scene->camera.width * scene->camera.height * scene->render.spp *
                    SEGMENTS_PER_SAMPLE;
    uint64_t cap = storage_capacity(ctx, sizeof(GpuSegment));
    return (uint32_t)(want < cap ? want : cap);
}

_Static_assert(B_LIGHTS + 1 == NS_SCENE_BUFFER_COUNT, "camera.comp binds the scene buffers first");

static int upload(ns_context *ctx, render_job *job, uint32_t pixels, ns_error *err)
{
    gpu_buffer_desc descs[B_COUNT];
    ns_gpu_scene_buffer_descs(&job->scene, descs);
    /* Written whole by the first dispatch / read only up to the recorded count. */
    descs[B_PIXELS] = (gpu_buffer_desc){.size = (uint64_t)pixels * 4 * sizeof(float),
                                        .kind = GPU_BUFFER_STORAGE,
                                        .uninitialized = 1,
                                        .host_reads = 1,
                                        .label = "ns.render.pixels"};
    descs[B_SEGMENTS] =
        (gpu_buffer_desc){.size = (uint64_t)job->scene.params.counts[2] * sizeof(GpuSegment),
                          .kind = GPU_BUFFER_STORAGE,
                          .uninitialized = 1,
                          .host_reads = 1,
                          .label = "ns.render.segments"};
    descs[B_COUNTERS] = (gpu_buffer_desc){.size = NS_COUNTER_COUNT * sizeof(uint32_t),
                                          .kind = GPU_BUFFER_STORAGE,
                                          .label = "ns.render.counters"};
    return gpu_buffers_create(&ctx->dev, job->buffers, descs, B_COUNT, err);
}

/* camera.comp's buffers: the job's, then the added samples' (binding 8), which only the
 * added samples' dispatches read; the others get the counters there, unread. */
enum { CAMERA_BINDINGS = B_COUNT + 1 };

static void camera_bindings(render_job *job, gpu_buffer *added, gpu_buffer *bound[CAMERA_BINDINGS])
{
    for (int i = 0; i < B_COUNT; i++)
        bound[i] = &job->buffers[i];
    bound[B_COUNT] = added ? added : &job->buffers[B_COUNTERS];
}

static int loop_limit_check(const render_job *job, ns_error *err)
{
    const uint32_t *counters = job->buffers[B_COUNTERS].mapped;
    if (!counters[NS_COUNTER_LOOP_LIMIT])
        return NS_OK;
    return ns_fail(err, NS_ERR_LIMIT,
                   "scene too complex for this device: %u pixel(s) ran past lavapipe's loop limit "
                   "(65535 iterations per invocation); lower render.max_depth, "
                   "render.light_samples, the light count or the geometry, or pick another "
                   "device",
                   counters[NS_COUNTER_LOOP_LIMIT]);
}

/* Camera samples [first, first + count). On lavapipe every sample gets its own dispatch, so
 * that the per-invocation loop limit (shared.h) applies to one camera sample rather than to
 * all of them; elsewhere one dispatch takes them all. The pixels of a range that does not
 * start at sample 0 add to what is there. */
static int dispatch_camera(ns_context *ctx, render_job *job, const ns_scene *scene, uint32_t first,
                           uint32_t count, ns_error *err)
{
    gpu_buffer *bound[CAMERA_BINDINGS];
    camera_bindings(job, NULL, bound);
    const ns_camera *cam = &scene->camera;
    uint32_t per_dispatch = ctx->dev.loop_limited ? 1 : count;
    uint32_t dispatches = (count + per_dispatch - 1) / per_dispatch;
    gpu_pipeline *camera;
    int status = ns_pipeline(ctx, NS_PIPELINE_CAMERA, &camera, NULL, err);
    if (status)
        return status;
    GpuSamplePush *push = calloc(dispatches, sizeof *push);
    if (!push)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "camera pass: %u dispatches", dispatches);
    for (uint32_t i = 0; i < dispatches; i++) {
        uint32_t done = i * per_dispatch;
        push[i].first_sample = first + done;
        push[i].sample_count = count - done < per_dispatch ? count - done : per_dispatch;
    }
    memset(job->buffers[B_COUNTERS].mapped, 0, NS_COUNTER_COUNT * sizeof(uint32_t));
    status = gpu_dispatch_many(
        &ctx->dev,
        &(gpu_dispatch_desc){
            .pipeline = camera,
            .buffers = bound,
            .buffer_count = CAMERA_BINDINGS,
            .groups = {(cam->width + NS_CAMERA_GROUP_X - 1) / NS_CAMERA_GROUP_X,
                       (cam->height + NS_CAMERA_GROUP_Y - 1) / NS_CAMERA_GROUP_Y, 1},
            .push = push,
            .dispatch_count = dispatches,
        },
        err);
    free(push);
    return status ? status : loop_limit_check(job, err);
}

/* Added samples traced for the pixels [first, first + count) of the plan, whose entries fit
 * the buffer: camera.comp's added mode, in dispatches of at most the device's groups in one
 * dimension; then those pixels become the means of all their samples. */
static int trace_added(ns_context *ctx, render_job *job, gpu_pipeline *camera, uint32_t spp,
                       const uint32_t *counts, size_t first, size_t count, uint64_t entries,
                       ns_error *err)
{
    ns_adaptive_entries(counts + first, first, count, spp, job->added.mapped);
    const uint32_t group = NS_CAMERA_GROUP_X * NS_CAMERA_GROUP_Y;
    uint32_t max_groups = ctx->dev.properties.limits.maxComputeWorkGroupCount[0];
    uint64_t groups_needed = (entries + group - 1) / group;
    uint32_t groups = groups_needed < max_groups ? (uint32_t)groups_needed : max_groups;
    uint32_t chunk = groups * group;
    uint32_t dispatches = (uint32_t)((entries + chunk - 1) / chunk);
    GpuSamplePush *push = calloc(dispatches, sizeof *push);
    if (!push)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "adaptive samples: %u dispatches",
                       dispatches);
    for (uint32_t i = 0; i < dispatches; i++) {
        push[i].first_sample = i * chunk;
        push[i].added_count = (uint32_t)entries;
    }
    gpu_buffer *bound[CAMERA_BINDINGS];
    camera_bindings(job, &job->added, bound);
    int status = gpu_dispatch_many(&ctx->dev,
                                   &(gpu_dispatch_desc){.pipeline = camera,
                                                        .buffers = bound,
                                                        .buffer_count = CAMERA_BINDINGS,
                                                        .groups = {groups, 1, 1},
                                                        .push = push,
                                                        .dispatch_count = dispatches},
                                   err);
    free(push);
    if (!status)
        status = loop_limit_check(job, err);
    if (!status)
        ns_adaptive_merge((float *)job->buffers[B_PIXELS].mapped + 4 * first, count, spp,
                          counts + first, job->added.mapped);
    return status;
}

/* render.adaptive_spp: after the camera pass, its surface image takes added samples where its
 * pixels' neighbours spread most (render/adaptive.c says why a pixel's own samples do not
 * count). One invocation per added sample, each recording no segments; the pixels become the
 * means of all their samples. Where they outnumber one buffer (a 7.8 M-sample budget, 2048²
 * at the default), they go in passes of whole pixels. *added_total: how many were traced. */
static int add_camera_samples(ns_context *ctx, render_job *job, const ns_scene *scene,
                              const ns_render_debug *debug, uint64_t *added_total, ns_error *err)
{
    const ns_camera *cam = &scene->camera;
    uint32_t spp = scene->render.spp;
    size_t pixels = (size_t)cam->width * cam->height;
    uint64_t budget = (uint64_t)((double)scene->render.adaptive_spp * pixels + 0.5);
    uint32_t cap = NS_ADAPTIVE_PIXEL_FACTOR * spp;
    if (cap > NS_MAX_SPP - spp)
        cap = NS_MAX_SPP - spp;
    *added_total = 0;
    uint32_t *counts = malloc(pixels * sizeof *counts);
    if (!counts)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "adaptive samples: %zu pixels", pixels);
    uint64_t total = ns_adaptive_plan(job->buffers[B_PIXELS].mapped, cam->width, cam->height, spp,
                                      budget, cap, counts);
    int status = NS_OK;
    if (total == UINT64_MAX)
        status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "adaptive samples: %zu pixels", pixels);
    /* A pass holds at least one pixel's samples: cap (<= NS_MAX_SPP) is far below it. */
    uint64_t room = storage_capacity(ctx, sizeof(GpuAddedSample));
    if (debug && debug->added_capacity && debug->added_capacity < room)
        room = debug->added_capacity > cap ? debug->added_capacity : cap;
    if (!status && total > 0)
        status = gpu_buffer_create(&ctx->dev, &job->added,
                                   &(gpu_buffer_desc){.size = (total < room ? total : room) *
                                                              sizeof(GpuAddedSample),
                                                      .kind = GPU_BUFFER_STORAGE,
                                                      .uninitialized = 1,
                                                      .host_reads = 1,
                                                      .label = "ns.render.added_samples"},
                                   err);
    gpu_pipeline *camera = NULL;
    if (!status && total > 0)
        status = ns_pipeline(ctx, NS_PIPELINE_CAMERA, &camera, NULL, err);
    for (size_t first = 0; !status && total > 0 && first < pixels;) {
        size_t count = 0;
        uint64_t entries = 0;
        while (first + count < pixels && entries + counts[first + count] <= room)
            entries += counts[first + count++];
        if (entries)
            status = trace_added(ctx, job, camera, spp, counts, first, count, entries, err);
        first += count;
    }
    gpu_buffer_destroy(&ctx->dev, &job->added);
    free(counts);
    if (!status)
        *added_total = total;
    return status;
}

static int read_back(render_job *job, const ns_camera *cam, ns_image *out, ns_render_stats *stats,
                     ns_render_debug *debug, ns_error *err)
{
    size_t pixels = (size_t)cam->width * cam->height;
    out->rgb = malloc(pixels * 3 * sizeof(float));
    if (!out->rgb)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "image: %zu pixels", pixels);
    out->width = cam->width;
    out->height = cam->height;
    const float *src = job->buffers[B_PIXELS].mapped;
    for (size_t i = 0; i < pixels; i++)
        memcpy(out->rgb + 3 * i, src + 4 * i, 3 * sizeof(float));
    const uint32_t *counters = job->buffers[B_COUNTERS].mapped;
    uint32_t capacity = job->scene.params.counts[2];
    uint64_t attempted = counters[NS_COUNTER_SEGMENTS];
    uint64_t written = attempted < capacity ? attempted : capacity;
    if (stats && !stats->camera_segments) /* the batched scattering path counted them */
        stats->camera_segments = written;
    if (debug) {
        debug->segments_written = written;
        debug->segments_overflow = counters[NS_COUNTER_OVERFLOW];
        if (debug->segments) {
            uint64_t n = written < debug->segments_max ? written : debug->segments_max;
            memcpy(debug->segments, job->buffers[B_SEGMENTS].mapped, n * sizeof(GpuSegment));
        }
    }
    return NS_OK;
}

/* Replaces the segment buffer by one of `capacity` segments. */
static int resize_segments(ns_context *ctx, render_job *job, uint64_t capacity, ns_error *err)
{
    gpu_buffer_destroy(&ctx->dev, &job->buffers[B_SEGMENTS]);
    job->scene.params.counts[2] = (uint32_t)capacity;
    memcpy(job->buffers[B_PARAMS].mapped, &job->scene.params, sizeof job->scene.params);
    return gpu_buffer_create(&ctx->dev, &job->buffers[B_SEGMENTS],
                             &(gpu_buffer_desc){.size = capacity * sizeof(GpuSegment),
                                                .kind = GPU_BUFFER_STORAGE,
                                                .uninitialized = 1,
                                                .host_reads = 1,
                                                .label = "ns.render.segments"},
                             err);
}

/* Camera pass and scattering stages together. The scattering stages need every segment of
 * the samples they are given, so the samples go in batches whose segments fit the buffer:
 * all of them at first; when a batch overflows, its surface light is taken back (the pixels
 * are restored) and it is run again smaller, or with the buffer grown to what one sample
 * needs, up to the device's limit. Each batch's scattering adds into `scattered`.
 * kept: the segment count of a camera pass taken from the context (ns_camera_keep_take) and
 * already in the job's buffers, or -1. single: the single-scattering fields of the stages'
 * inputs (ns_scatter_inputs). *single_pass = 1 when the whole sample range went
 * through one camera pass with nothing retried, the only pass a later render may reuse;
 * *segment_count is then its segments'. */
static int camera_and_scattering(ns_context *ctx, render_job *job, const ns_scene *scene,
                                 int64_t kept, float *scattered, const ns_scatter_inputs *single,
                                 int *single_pass, uint32_t *segment_count, ns_render_stats *stats,
                                 ns_error *err)
{
    uint32_t spp = scene->render.spp, pixels = scene->camera.width * scene->camera.height;
    uint64_t cap = storage_capacity(ctx, sizeof(GpuSegment));
    size_t pixel_bytes = (size_t)pixels * 4 * sizeof(float);
    float *saved = malloc(pixel_bytes);
    if (!saved)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "camera pass: %u pixels", pixels);
    int status = NS_OK;
    uint32_t first = 0, batch = spp;
    double shares[2];
    ns_batch_shares(scene, shares);
    *single_pass = 1;
    while (!status && first < spp) {
        uint32_t count = spp - first < batch ? spp - first : batch;
        if (first > 0)
            memcpy(saved, job->buffers[B_PIXELS].mapped, pixel_bytes);
        /* The batch's part of the render: its share of the samples. */
        ns_span outer = ns_progress_push(ctx, (double)first / spp, (double)(first + count) / spp);
        uint64_t attempted = 0;
        int overflow = 0;
        if (kept >= 0) { /* the whole range, traced by an earlier render */
            attempted = (uint64_t)kept;
            kept = -1;
        } else {
            ns_stage stage = ns_stage_begin(ctx, "ray_pass", 0.0, shares[0]);
            status = dispatch_camera(ctx, job, scene, first, count, err);
            ns_stats_add_stage(stats, "ray_pass", ns_stage_end(ctx, &stage));
            if (status) {
                ns_progress_pop(ctx, outer);
                break;
            }
            const uint32_t *counters = job->buffers[B_COUNTERS].mapped;
            attempted = counters[NS_COUNTER_SEGMENTS];
            overflow = counters[NS_COUNTER_OVERFLOW] != 0;
        }
        if (overflow || count < spp)
            *single_pass = 0;
        if (overflow) {
            ns_progress_restore(ctx, outer); /* run again, smaller */
            if (first > 0)
                memcpy(job->buffers[B_PIXELS].mapped, saved, pixel_bytes);
            if (count > 1) {
                /* Room for the batch's share, with a margin: samples differ. */
                uint64_t fit = (uint64_t)((double)count * job->scene.params.counts[2] / attempted * 0.8);
                batch = fit >= 1 ? (uint32_t)fit : 1;
            } else if (attempted <= cap) {
                status = resize_segments(ctx, job, attempted, err);
            } else {
                status = ns_fail(err, NS_ERR_LIMIT,
                                 "camera segments: one sample of this image records %llu stretches "
                                 "inside media, more than this device's buffer holds (%llu); lower "
                                 "the image size or render.max_depth",
                                 (unsigned long long)attempted, (unsigned long long)cap);
            }
            continue;
        }
        if (stats)
            stats->camera_segments += attempted;
        ns_scatter_inputs in = {.scene = scene,
                                .gs = &job->scene,
                                .scene_buffers = job->buffers,
                                .segments = &job->buffers[B_SEGMENTS],
                                .segment_count = (uint32_t)attempted,
                                .pixels = scattered,
                                .single_materials = single->single_materials,
                                .single_reference = {single->single_reference[0],
                                                     single->single_reference[1],
                                                     single->single_reference[2]},
                                .single_image = single->single_image,
                                .single_given = single->single_given};
        status = ns_scatter_render(ctx, &in, stats, err);
        ns_progress_pop(ctx, outer);
        first += count;
        if (!status)
            *segment_count = (uint32_t)attempted;
    }
    free(saved);
    return status;
}

static int render_locked(ns_context *ctx, const ns_scene *scene, ns_image *out,
                         ns_render_stats *stats, ns_render_debug *debug, ns_error *err)
{
    render_job job;
    memset(&job, 0, sizeof job);
    /* Always a stage of its own, also when the BVH was kept from an earlier render (its time
     * is then that of converting the scene and comparing it with the kept one). */
    ns_stage stage = ns_stage_begin(ctx, "bvh", 0.0, 0.01);
    int reused = 0;
    int status = ns_gpu_scene_build_reusing(scene, &ctx->bvh, &job.scene, &reused, err);
    if (!status) {
        job.scene.params.counts[2] = job.scene.has_media ? segment_capacity(ctx, scene, debug) : 0;
        job.scene.params.limits[0] = ctx->dev.loop_limited ? NS_LAVAPIPE_LOOP_BUDGET : 0;
        if (stats) {
            stats->bvh_nodes = job.scene.node_count;
            stats->primitives = job.scene.bvh_prim_count + job.scene.plane_count;
            stats->bvh_reused = (uint32_t)reused;
        }
    }
    ns_stats_add_stage(stats, "bvh", ns_stage_end(ctx, &stage));
    if (!status)
        status = ns_run_check(ctx, err);
    stage = ns_stage_begin(ctx, "upload", 0.01, 0.02);
    if (!status)
        status = upload(ctx, &job, scene->camera.width * scene->camera.height, err);
    ns_stats_add_stage(stats, "upload", ns_stage_end(ctx, &stage));
    /* A debug caller that reads the segments back gets the camera pass alone. */
    int scattering = job.scene.has_media && !(debug && debug->segments) &&
                     (scene->render.components & ~(uint32_t)NS_COMPONENT_SURFACE);
    float *scattered = NULL;
    if (!status && scattering &&
        !(scattered = calloc((size_t)scene->camera.width * scene->camera.height * 3, sizeof(float))))
        status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "scattering image");
    /* The camera pass of the last render is taken when it is the one this render would make
     * (render/camera_keep.c); a debug caller gets a pass of its own. */
    unsigned char *signature = NULL;
    size_t signature_bytes = 0;
    int64_t kept = -1;
    int single_pass = 0;
    uint32_t segment_count = 0;
    ns_single_keep single = {0};
    if (!status && scattering && !debug &&
        (signature = ns_camera_signature(&job.scene, &signature_bytes)) &&
        ns_camera_keep_take(ctx, signature, signature_bytes, &job.buffers[B_PIXELS],
                            &job.buffers[B_SEGMENTS], &segment_count, &single)) {
        kept = segment_count;
        if (stats)
            stats->camera_reused = 1;
    }
    /* Single scattering per unit sigma_s (render/camera_keep.c): its materials, and its image,
     * the one kept with the pass when it is the one this render's stage would make, else made
     * by the stage into a buffer kept with the pass (none for a debug caller). */
    ns_scatter_inputs single_part = {0};
    GpuMaterial *unit = NULL;
    if (!status && scattering && (scene->render.components & NS_COMPONENT_SINGLE)) {
        uint32_t count = job.scene.material_count;
        if (!(unit = malloc(sizeof *unit * (count ? count : 1))))
            status =
                ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "single scattering: %u materials", count);
        else
            ns_single_unit_materials(job.scene.materials, count, unit,
                                     single_part.single_reference);
        single_part.single_materials = unit;
        if (!status && kept >= 0 && ns_single_keep_matches(&single, scene, unit, count)) {
            single_part.single_image = single.image;
            single.image = NULL;
            single_part.single_given = 1;
        } else if (!status && signature) {
            single_part.single_image =
                calloc((size_t)scene->camera.width * scene->camera.height * 3, sizeof(float));
        }
        if (stats)
            stats->single_reused = (uint32_t)single_part.single_given;
    }
    ns_single_keep_free(&single);
    if (!status && scattering) {
        ns_span outer = ns_progress_push(ctx, 0.02, 0.98);
        status = camera_and_scattering(ctx, &job, scene, kept, scattered, &single_part,
                                       &single_pass, &segment_count, stats, err);
        ns_progress_pop(ctx, outer);
    } else if (!status) {
        stage = ns_stage_begin(ctx, "ray_pass", 0.02, 0.98);
        status = dispatch_camera(ctx, &job, scene, 0, scene->render.spp, err);
        ns_stats_add_stage(stats, "ray_pass", ns_stage_end(ctx, &stage));
    }
    /* Added samples, after the scattering stages (which take only the first spp samples'
     * segments); a kept camera pass has them already. */
    if (!status && kept < 0 && !(debug && debug->segments) &&
        ns_adaptive_spp_used(&scene->render) > 0.0f) {
        uint64_t added = 0;
        stage = ns_stage_begin(ctx, "adaptive", 0.98, 0.99);
        status = add_camera_samples(ctx, &job, scene, debug, &added, err);
        ns_stats_add_stage(stats, "adaptive", ns_stage_end(ctx, &stage));
        if (stats)
            stats->adaptive_samples = added;
    }
    /* The work is done; a cancellation that comes now still cancels (no image). */
    if (!status)
        status = ns_run_check(ctx, err);
    stage = ns_stage_begin(ctx, "readback", 0.99, 1.0);
    if (!status)
        status = read_back(&job, &scene->camera, out, stats, debug, err);
    ns_stats_add_stage(stats, "readback", ns_stage_end(ctx, &stage));
    if (!status && signature && single_pass) {
        /* Out of memory the pass is kept without its single scattering. */
        if (single_part.single_image)
            ns_single_keep_set(&single, single_part.single_image, scene, unit,
                               job.scene.material_count);
        single_part.single_image = NULL;
        ns_camera_keep_put(ctx, signature, signature_bytes, &job.buffers[B_PIXELS],
                           &job.buffers[B_SEGMENTS], segment_count, &single);
        signature = NULL;
    }
    free(signature);
    free(single_part.single_image);
    free(unit);
    /* The camera pass always shades surfaces; a render without them starts from black. */
    if (!status && !(scene->render.components & NS_COMPONENT_SURFACE))
        memset(out->rgb, 0, sizeof(float) * 3 * out->width * out->height);
    if (!status && scattered)
        for (size_t i = 0; i < (size_t)out->width * out->height * 3; i++)
            out->rgb[i] += scattered[i];
    free(scattered);
    job_free(ctx, &job);
    return status;
}

static int render_run(ns_context *ctx, const ns_scene *scene, const ns_render_control *control,
                      ns_image *out, ns_render_stats *stats, ns_render_debug *debug,
                      ns_error *err)
{
    /* This render's figures alone, whatever the struct held (the counts and stages add up
     * inside a render, and a caller may hand the same struct to every render). */
    if (stats)
        memset(stats, 0, sizeof *stats);
    if (!out)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "ns_render: out is NULL");
    memset(out, 0, sizeof *out);
    if (!ctx)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "ns_render: no context");
    /* Settings left 0 take their defaults here, once: everything below reads them resolved. */
    ns_scene resolved;
    if (scene) {
        resolved = *scene;
        resolved.render = ns_render_settings_resolve(scene->render);
        scene = &resolved;
    }
    int status = ns_scene_validate(scene, err);
    if (status)
        return status;
    uint32_t missing = ns_unsupported_components(scene->render.method, scene->render.components);
    if (missing) {
        char names[64];
        component_names(missing, names, sizeof names);
        return ns_fail(err, NS_ERR_NOT_AVAILABLE,
                       "render.components: %s cannot be rendered alone with this method (the "
                       "dipole gives double and multiple scattering together)",
                       names);
    }
    pthread_mutex_lock(&ctx->lock);
    ns_run_begin(ctx, control, scene->render.deadline_ms);
    /* A flag set before the render began cancels it before any work. */
    status = ns_run_check(ctx, err);
    if (!status && scene->render.method == NS_METHOD_PT)
        status = ns_pt_render(ctx, scene, out, stats, err); /* render/pt.c */
    else if (!status)
        status = render_locked(ctx, scene, out, stats, debug, err);
    status = ns_run_end(ctx, status, err);
    pthread_mutex_unlock(&ctx->lock);
    if (status)
        ns_image_free(out);
    return status;
}

int ns_render_ex(ns_context *ctx, const ns_scene *scene, ns_image *out, ns_render_stats *stats,
                 ns_render_debug *debug, ns_error *err)
{
    return render_run(ctx, scene, NULL, out, stats, debug, err);
}

int ns_render(ns_context *ctx, const ns_scene *scene, ns_image *out, ns_render_stats *stats,
              ns_error *err)
{
    return render_run(ctx, scene, NULL, out, stats, NULL, err);
}

int ns_render_controlled(ns_context *ctx, const ns_scene *scene, const ns_render_control *control,
                         ns_image *out, ns_render_stats *stats, ns_error *err)
{
    return render_run(ctx, scene, control, out, stats, NULL, err);
}
