/* camera_keep.c — the camera passes of the last two renders, kept for the next render that
 * would make one of them again (internal.h, ns_camera_keep).
 *
 * camera.comp reads the five scene buffers (params, BVH nodes, primitives, materials,
 * lights) and its sample range, and writes the surface image and the segments. Of a
 * material it reads the reflectance, the extinction sigma_t and the ior, never sigma_s or g:
 * those are what the scattering stages read, and what a sweep of albedo and g changes. So
 * two renders whose scene buffers agree once every material's sigma_s (g in its w) is
 * cleared make the same pixels and segments when both ran the whole sample range in one
 * pass; the second takes the first's buffers instead of tracing again.
 *
 * The bytes are compared whole, nothing hashed, so nothing can collide. A sweep of albedo at
 * one mean free path keeps its extinction bit for bit because the scene parser splits it so
 * (io/scene_json.c: sigma_s + sigma_a is exactly the float extinction), and the image is the
 * one a new camera pass would give, bit for bit. The signature is ns_scene_signature's
 * (scene_gpu.c), as for the sources render/source_keep.c keeps.
 *
 * Single scattering's image goes with the pass (ns_single_keep); this is the one full
 * account of when (docs/rendering.md repeats it for users). single.comp reads sigma_s only as
 * the factor of its sum (sigma_s times the in-scattered light, which depends on the segments,
 * sigma_t, g and the ior), so the stage computes its image per unit sigma_s, each channel's
 * sigma_s divided by a reference, the largest of the scene's (ns_single_unit_materials: one
 * medium's becomes exactly 1 wherever it scatters), and multiplies by the reference last
 * (render_single). What is kept is that image before the product, with the materials per unit
 * and the settings it was made from (ns_single_keep_settings). A render that takes the same
 * camera pass and whose materials per unit and settings are the same bit for bit takes it
 * instead of computing it: the same inputs, the same image, so the render's image is bit for
 * bit the one the stage would give. A scene with one medium whose albedo changes at a fixed
 * mean free path (a sweep, a slider) qualifies as long as no channel's albedo becomes or stops
 * being 0; of several media, those whose quotients come out the same. */
#include <stdlib.h>
#include <string.h>

#include "internal.h"

/* A pass is kept only when its two buffers together are at most this big: they stay
 * allocated (host memory, being read back: gpu_buffer_desc.host_reads) while the service
 * idles. 256² at 4 samples per pixel needs 33 MiB. The context keeps NS_CAMERA_KEEP_ENTRIES
 * passes (the web page's quarter-size preview and its full image, which alternate) within
 * CAMERA_KEEP_TOTAL_MAX together: the least recently kept goes first. */
#define CAMERA_KEEP_BYTES_MAX (64ull << 20)
#define CAMERA_KEEP_TOTAL_MAX (96ull << 20)

/* The signature: the scene buffers with every material's sigma_s (and g) cleared. */
unsigned char *ns_camera_signature(const ns_gpu_scene *gs, size_t *bytes)
{
    return ns_scene_signature(gs, &gs->params, 1, NULL, 0, bytes);
}

/* A kept buffer is not counted among the live ones (ns_context_live_buffers), like the
 * table cache's: a render that leaves one behind still brings the count back. */
static void move_buffer(gpu_buffer *to, gpu_buffer *from)
{
    *to = *from;
    memset(from, 0, sizeof *from);
}

int ns_camera_keep_take(ns_context *ctx, const unsigned char *signature, size_t bytes,
                        gpu_buffer *pixels, gpu_buffer *segments, uint32_t *segment_count,
                        ns_single_keep *single)
{
    ns_camera_keep *keep = NULL;
    for (int i = 0; i < NS_CAMERA_KEEP_ENTRIES && !keep; i++) {
        ns_camera_keep *k = &ctx->camera[i];
        if (k->signature && k->signature_bytes == bytes &&
            memcmp(k->signature, signature, bytes) == 0)
            keep = k;
    }
    if (!keep)
        return 0;
    gpu_buffer_destroy(&ctx->dev, pixels);
    gpu_buffer_destroy(&ctx->dev, segments);
    move_buffer(pixels, &keep->pixels);
    move_buffer(segments, &keep->segments);
    __atomic_add_fetch(&ctx->dev.live_buffers, 2, __ATOMIC_SEQ_CST);
    *segment_count = keep->segment_count;
    *single = keep->single;
    memset(&keep->single, 0, sizeof keep->single);
    /* The buffers are the render's now; they come back with ns_camera_keep_put when it
     * succeeds, and are destroyed with the job when it does not. */
    ns_camera_keep_free(&ctx->dev, keep);
    return 1;
}

static uint64_t kept_bytes(const ns_camera_keep *keep)
{
    return keep->signature ? keep->pixels.size + keep->segments.size : 0;
}

void ns_camera_keep_put(ns_context *ctx, unsigned char *signature, size_t bytes, gpu_buffer *pixels,
                        gpu_buffer *segments, uint32_t segment_count, ns_single_keep *single)
{
    uint64_t size = pixels->size + segments->size;
    if (size > CAMERA_KEEP_BYTES_MAX) {
        free(signature);
        ns_single_keep_free(single);
        return;
    }
    /* Room: the least recently kept passes go until this one fits beside the rest, and the
     * slot is an empty one or the least recently kept. */
    for (;;) {
        uint64_t total = size;
        ns_camera_keep *oldest = NULL;
        for (int i = 0; i < NS_CAMERA_KEEP_ENTRIES; i++) {
            ns_camera_keep *k = &ctx->camera[i];
            total += kept_bytes(k);
            if (k->signature && (!oldest || k->kept_at < oldest->kept_at))
                oldest = k;
        }
        if (total <= CAMERA_KEEP_TOTAL_MAX || !oldest)
            break;
        ns_camera_keep_free(&ctx->dev, oldest);
    }
    ns_camera_keep *keep = &ctx->camera[0];
    for (int i = 1; i < NS_CAMERA_KEEP_ENTRIES; i++) {
        ns_camera_keep *k = &ctx->camera[i];
        if (keep->signature && (!k->signature || k->kept_at < keep->kept_at))
            keep = k;
    }
    ns_camera_keep_free(&ctx->dev, keep);
    keep->kept_at = ++ctx->camera_clock;
    keep->single = *single;
    memset(single, 0, sizeof *single);
    keep->signature = signature;
    keep->signature_bytes = bytes;
    move_buffer(&keep->pixels, pixels);
    move_buffer(&keep->segments, segments);
    keep->segment_count = segment_count;
    __atomic_sub_fetch(&ctx->dev.live_buffers, 2, __ATOMIC_SEQ_CST);
}

void ns_camera_keep_clear(ns_context *ctx)
{
    for (int i = 0; i < NS_CAMERA_KEEP_ENTRIES; i++)
        ns_camera_keep_free(&ctx->dev, &ctx->camera[i]);
}

void ns_camera_keep_free(gpu_device *dev, ns_camera_keep *keep)
{
    /* gpu_buffer_destroy counts a buffer out of the live ones; these were counted out
     * when they were kept. */
    uint32_t held = (keep->pixels.size != 0) + (keep->segments.size != 0);
    __atomic_add_fetch(&dev->live_buffers, held, __ATOMIC_SEQ_CST);
    gpu_buffer_destroy(dev, &keep->pixels);
    gpu_buffer_destroy(dev, &keep->segments);
    free(keep->signature);
    ns_single_keep_free(&keep->single);
    memset(keep, 0, sizeof *keep);
}

void ns_single_keep_settings(const ns_render_settings *render, uint32_t settings[4])
{
    /* The method is not read by the stage; it keeps one method's render from taking
     * another's, which nscatter bench times apart. */
    settings[0] = (uint32_t)render->method;
    settings[1] = render->single_samples;
    settings[2] = render->single_levels;
    memcpy(&settings[3], &render->single_tolerance, sizeof settings[3]);
}

int ns_single_keep_matches(const ns_single_keep *keep, const ns_scene *scene,
                           const GpuMaterial *unit, uint32_t count)
{
    uint32_t settings[4];
    ns_single_keep_settings(&scene->render, settings);
    return keep->image && keep->material_count == count &&
           memcmp(settings, keep->settings, sizeof settings) == 0 &&
           memcmp(unit, keep->materials, sizeof *unit * count) == 0;
}

int ns_single_keep_set(ns_single_keep *keep, float *image, const ns_scene *scene,
                       const GpuMaterial *unit, uint32_t count)
{
    ns_single_keep_free(keep);
    if (!image || !(keep->materials = malloc(sizeof *unit * (count ? count : 1)))) {
        free(image);
        return -1;
    }
    memcpy(keep->materials, unit, sizeof *unit * count);
    keep->material_count = count;
    keep->image = image;
    ns_single_keep_settings(&scene->render, keep->settings);
    return 0;
}

void ns_single_keep_free(ns_single_keep *keep)
{
    free(keep->image);
    free(keep->materials);
    memset(keep, 0, sizeof *keep);
}
