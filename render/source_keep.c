/* source_keep.c — the light's sources of the last two renders, kept for the next render that
 * would make the same ones (source_keep.h).
 *
 * The table and dipole methods gather from VRLs, and with render.boundary also from the
 * boundary sources the light's walks leave (scatter_render.c, vrl_source_init). Both come
 * from the lights, the geometry and the media, never from the camera: vrl.comp and
 * vrl_trace.comp read the five scene buffers, the path count, the chain length and the seed,
 * and the boundary sources are then filtered and grouped by the components asked for. So
 * two renders whose scene buffers agree once the camera, the image size, the samples per
 * pixel and the camera pass's light and added samples are cleared from params (and the segment
 * buffer's capacity, which follows from them), with the same VRL count, chain, seed,
 * boundary model and (with the boundary correction) components, make the same sources; the
 * second takes a copy of the first's instead of tracing them again (issue 15: "keep the
 * sources across camera changes").
 *
 * The bytes are compared whole, nothing hashed, so nothing can collide; the sources are
 * the ones a new trace would give, bit for bit (gpu_render_control checks the image). */
#include <stdlib.h>
#include <string.h>

#include "source_keep.h"

/* Kept only when the sources together are at most this big (host memory, while the service
 * idles): 4,000 VRLs and 20,000 walks' sources take about 2 MB. The context keeps two renders'
 * (the web page's preview traces a quarter of the full image's light paths, and the two
 * alternate), the least recently kept replaced. */
#define SOURCE_KEEP_BYTES_MAX (64ull << 20)

struct ns_source_keep {
    unsigned char *signature;
    size_t signature_bytes;
    ns_vrl_set set;
    ns_boundary_groups boundary;
    uint64_t kept_at; /* ns_context.sources_clock when kept or last taken: the oldest goes first */
};

/* What generates the sources besides the scene buffers. */
typedef struct source_inputs {
    uint32_t paths, chain, seed, boundary, components;
} source_inputs;

unsigned char *ns_source_signature(const ns_scene *scene, const ns_gpu_scene *gs, uint32_t chain,
                                   size_t *bytes)
{
    source_inputs inputs = {
        .paths = scene->render.vrls,
        .chain = chain,
        .seed = scene->render.seed,
        .boundary = (uint32_t)scene->render.boundary,
        /* Only the boundary's sources depend on them (ns_boundary_source_orders). */
        .components = scene->render.boundary != NS_BOUNDARY_OFF ? scene->render.components : 0,
    };
    GpuParams params = gs->params;
    memset(params.cam_position, 0, sizeof params.cam_position);
    memset(params.cam_right, 0, sizeof params.cam_right);
    memset(params.cam_up, 0, sizeof params.cam_up);
    memset(params.cam_forward, 0, sizeof params.cam_forward);
    params.image[0] = params.image[1] = params.image[2] = 0; /* width, height, spp; not the seed */
    params.counts[2] = 0;                                     /* the segment buffer's capacity */
    params.surface[0] = params.surface[1] = 0; /* the camera pass's light and added samples */
    return ns_scene_signature(gs, &params, 0, &inputs, sizeof inputs, bytes);
}

static int copy_set(ns_vrl_set *to, const ns_vrl_set *from)
{
    *to = *from;
    to->vrls = NULL;
    to->ends = NULL; /* the walks' ends are not kept: only the sources made from them */
    if (!from->count)
        return 1;
    to->vrls = malloc(sizeof *to->vrls * from->count);
    if (!to->vrls)
        return 0;
    memcpy(to->vrls, from->vrls, sizeof *to->vrls * from->count);
    return 1;
}

/* A copy of both; on failure nothing is left allocated in the copies. */
static int copy_sources(ns_vrl_set *set, ns_boundary_groups *boundary, const ns_vrl_set *from_set,
                        const ns_boundary_groups *from_boundary)
{
    memset(boundary, 0, sizeof *boundary);
    int ok = copy_set(set, from_set);
    boundary->count = from_boundary->count;
    for (uint32_t g = 0; ok && g < from_boundary->count; g++) {
        boundary->group[g] = from_boundary->group[g];
        ok = copy_set(&boundary->group[g].set, &from_boundary->group[g].set);
    }
    if (!ok) {
        ns_vrl_set_free(set);
        ns_boundary_groups_free(boundary);
    }
    return ok;
}

static uint64_t sources_bytes(const ns_vrl_set *set, const ns_boundary_groups *boundary)
{
    uint64_t n = set->count;
    for (uint32_t g = 0; g < boundary->count; g++)
        n += boundary->group[g].set.count;
    return n * sizeof(GpuVrl);
}

int ns_source_keep_take(ns_context *ctx, const unsigned char *signature, size_t bytes, ns_vrl_set *set,
                        ns_boundary_groups *boundary)
{
    for (int i = 0; signature && i < NS_CAMERA_KEEP_ENTRIES; i++) {
        struct ns_source_keep *keep = ctx->sources[i];
        if (keep && keep->signature_bytes == bytes &&
            memcmp(keep->signature, signature, bytes) == 0) {
            keep->kept_at = ++ctx->sources_clock; /* used: the other goes first */
            return copy_sources(set, boundary, &keep->set, &keep->boundary);
        }
    }
    return 0;
}

static void free_keep(struct ns_source_keep **slot)
{
    struct ns_source_keep *keep = *slot;
    if (!keep)
        return;
    free(keep->signature);
    ns_vrl_set_free(&keep->set);
    ns_boundary_groups_free(&keep->boundary);
    free(keep);
    *slot = NULL;
}

void ns_source_keep_put(ns_context *ctx, unsigned char *signature, size_t bytes, const ns_vrl_set *set,
                        const ns_boundary_groups *boundary)
{
    if (!signature || sources_bytes(set, boundary) > SOURCE_KEEP_BYTES_MAX) {
        free(signature); /* nothing kept, nothing pushed out */
        return;
    }
    /* The slot: the one that holds these sources already, an empty one, or the oldest. */
    struct ns_source_keep **slot = &ctx->sources[0];
    for (int i = 0; i < NS_CAMERA_KEEP_ENTRIES; i++) {
        struct ns_source_keep **s = &ctx->sources[i];
        if (*s && (*s)->signature_bytes == bytes &&
            memcmp((*s)->signature, signature, bytes) == 0) {
            slot = s;
            break;
        }
        if (*slot && (!*s || (*s)->kept_at < (*slot)->kept_at))
            slot = s;
    }
    free_keep(slot);
    struct ns_source_keep *keep = calloc(1, sizeof *keep);
    if (keep && copy_sources(&keep->set, &keep->boundary, set, boundary)) {
        keep->signature = signature;
        keep->signature_bytes = bytes;
        keep->kept_at = ++ctx->sources_clock;
        *slot = keep;
        return;
    }
    free(keep);
    free(signature);
}

void ns_source_keep_free(ns_context *ctx)
{
    for (int i = 0; i < NS_CAMERA_KEEP_ENTRIES; i++)
        free_keep(&ctx->sources[i]);
}
