/* camera_keep.c — the camera pass of the last render, kept for the next render that would
 * make the same one (internal.h, ns_camera_keep).
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
 * (scene_gpu.c), as for the sources render/source_keep.c keeps. */
#include <stdlib.h>
#include <string.h>

#include "internal.h"

/* Kept only when the two buffers together are at most this big: they stay allocated (host
 * memory, being read back: gpu_buffer_desc.host_reads) while the service idles. 256² at 4
 * samples per pixel needs 33 MiB. */
#define CAMERA_KEEP_BYTES_MAX (64ull << 20)

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
                        gpu_buffer *pixels, gpu_buffer *segments, uint32_t *segment_count)
{
    ns_camera_keep *keep = &ctx->camera;
    if (!keep->signature || keep->signature_bytes != bytes ||
        memcmp(keep->signature, signature, bytes) != 0)
        return 0;
    gpu_buffer_destroy(&ctx->dev, pixels);
    gpu_buffer_destroy(&ctx->dev, segments);
    move_buffer(pixels, &keep->pixels);
    move_buffer(segments, &keep->segments);
    __atomic_add_fetch(&ctx->dev.live_buffers, 2, __ATOMIC_SEQ_CST);
    *segment_count = keep->segment_count;
    /* The buffers are the render's now; they come back with ns_camera_keep_put when it
     * succeeds, and are destroyed with the job when it does not. */
    ns_camera_keep_free(&ctx->dev, keep);
    return 1;
}

void ns_camera_keep_put(ns_context *ctx, unsigned char *signature, size_t bytes, gpu_buffer *pixels,
                        gpu_buffer *segments, uint32_t segment_count)
{
    ns_camera_keep *keep = &ctx->camera;
    ns_camera_keep_free(&ctx->dev, keep);
    if (pixels->size + segments->size > CAMERA_KEEP_BYTES_MAX) {
        free(signature);
        return;
    }
    keep->signature = signature;
    keep->signature_bytes = bytes;
    move_buffer(&keep->pixels, pixels);
    move_buffer(&keep->segments, segments);
    keep->segment_count = segment_count;
    __atomic_sub_fetch(&ctx->dev.live_buffers, 2, __ATOMIC_SEQ_CST);
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
    memset(keep, 0, sizeof *keep);
}
