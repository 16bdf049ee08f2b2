/* internal.h — what the render library's modules share with each other and with the GPU
 * tests, but not with the server (which sees render/nscatter.h only). */
#ifndef NS_RENDER_INTERNAL_H
#define NS_RENDER_INTERNAL_H

#include <pthread.h>

#include "gpu.h"
#include "nscatter.h"
#include "shared.h"

/* The context: made once, used by one render at a time (lock serialises them anyway). */
struct ns_table_cache; /* render/scatter_tables.c */
struct ns_nn_state;    /* render/scatter_tables.c: the networks and their pipeline */

struct ns_context {
    gpu_device dev;
    gpu_pipeline camera;     /* shaders/camera.comp */
    gpu_pipeline trace_test; /* shaders/trace_test.comp */
    /* The scattering stages (render/scatter.h); made and warmed with the others. */
    gpu_pipeline accumulate; /* shaders/accumulate.comp */
    gpu_pipeline vrl;        /* shaders/vrl.comp */
    gpu_pipeline gather;     /* shaders/gather.comp */
    gpu_pipeline single;     /* shaders/single.comp */
    gpu_pipeline vrl_trace;  /* shaders/vrl_trace.comp (method vrl) */
    gpu_pipeline vrl_gather; /* shaders/vrl_gather.comp (method vrl) */
    /* shaders/pt.comp: made by the first pt render and kept. Its compile (~0.3 s on
     * lavapipe) is paid once per context, and never by a context that renders no pt. */
    gpu_pipeline pt;
    /* The gather's other forms (gather.c ns_gather_pipeline: bounded beams, the paper's
     * accumulation, the dipole), one shader each: made by the first gather that needs one
     * and kept, like pt. gather above is the default form, made with the others. */
    gpu_pipeline gather_forms[5];
    struct ns_table_cache *tables;
    struct ns_nn_state *nn;
    ns_mc_tables_fn mc_tables;
    void *mc_user;
    uint64_t table_cache_bytes;
    pthread_mutex_t lock;
    char *pipeline_cache_path;
};

/* Checks the scene's structural invariants (indices, counts, finite numbers, ranges);
 * the message names the field, e.g. "objects[3].material: 9 out of range (2 materials)".
 * Render settings left 0 are checked as their defaults (ns_render_settings_resolve). The
 * stages below ns_render read scene->render resolved: a test that calls one directly with
 * settings it left 0 resolves them first. */
int ns_scene_validate(const ns_scene *scene, ns_error *err);

/* The scene in the shaders' layout. prims = BVH primitives in tree order, then the planes. */
typedef struct ns_gpu_scene {
    GpuParams params;
    GpuNode *nodes;
    uint32_t node_count;
    GpuPrim *prims;
    uint32_t bvh_prim_count, plane_count;
    GpuMaterial *materials;
    uint32_t material_count;
    GpuLight *lights;
    uint32_t light_count;
    int has_media; /* some object bounds a medium: the segment buffer is needed */
} ns_gpu_scene;

/* Builds the GPU form of a validated scene (including the BVH). Free with
 * ns_gpu_scene_free, also after a failure. */
int ns_gpu_scene_build(const ns_scene *scene, ns_gpu_scene *out, ns_error *err);
void ns_gpu_scene_free(ns_gpu_scene *gs);

/* Every scene pass (camera.comp, pt.comp) binds the same five scene buffers first, in this
 * order: params (uniform), BVH nodes, primitives, materials, lights. */
enum { NS_SCENE_BUFFER_COUNT = 5 };
/* Fills descs[0..NS_SCENE_BUFFER_COUNT) for gs; the descriptors point into gs, which must
 * outlive the buffer creation. */
void ns_gpu_scene_buffer_descs(const ns_gpu_scene *gs, gpu_buffer_desc descs[NS_SCENE_BUFFER_COUNT]);

/* ns_render with access to the segment buffer (tests). segment_capacity 0 = the default
 * capacity; when segments is not NULL the first min(written, segments_max) are copied. */
typedef struct ns_render_debug {
    uint32_t segment_capacity;
    GpuSegment *segments;
    uint32_t segments_max;
    uint64_t segments_written;  /* out: recorded (at most the capacity) */
    uint64_t segments_overflow; /* out: dropped because the buffer was full */
} ns_render_debug;

int ns_render_ex(ns_context *ctx, const ns_scene *scene, ns_image *out, ns_render_stats *stats,
                 ns_render_debug *debug, ns_error *err);

/* Traces rays against prims (spheres, boxes, triangles; built into a BVH here) and planes
 * with shaders/trace_test.comp. hits[i].prim is an index into prims, or prim_count + j for
 * planes[j], or NS_NONE. */
int ns_trace_rays(ns_context *ctx, const GpuPrim *prims, uint32_t prim_count, const GpuPrim *planes,
                  uint32_t plane_count, const GpuRay *rays, uint32_t ray_count, GpuHit *hits,
                  ns_error *err);

#endif
