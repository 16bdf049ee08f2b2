/* internal.h — what the render library's modules share with each other and with the GPU
 * tests, but not with the server (which sees render/include/nscatter.h only). */
#ifndef NS_RENDER_INTERNAL_H
#define NS_RENDER_INTERNAL_H

#include <pthread.h>

#include "gpu.h"
#include "nscatter.h"
#include "pipelines.h"
#include "shared.h"

/* ---------------------------------------------------------------------------------------
 * Progress reports and cancellation of the render in progress (render/progress.c).
 *
 * The fraction of the whole render done is planned top down: the code running now stands for
 * a span [lo, hi] of it; a stage or a part of one takes a part [a, b] of the span it runs in
 * (ns_progress_push, ns_stage_begin) and gives it back when done (ns_progress_pop,
 * ns_stage_end), which moves the fraction to the end of that part. A TICK reports a part of
 * the current span done. The fraction reported never decreases: a part that is run again (a
 * camera batch that overflowed, a pass restarted with a smaller budget) waits until it has
 * passed where it was. Every stage that ns_render_stats lists is timed with ns_stage_begin /
 * ns_stage_end, so that its reports and its time come from the same two calls.
 * ------------------------------------------------------------------------------------- */
typedef struct ns_span {
    double lo, hi;
} ns_span;

typedef struct ns_run {
    const ns_render_control *control; /* NULL: no render, or one without control */
    uint64_t serial;                  /* counts renders (the table cache's counts per render) */
    double done;                      /* reported so far, or due at the next report */
    ns_span span;                     /* what the code running now stands for */
    const char *stage;                /* the stage open now; NULL between stages */
    const char *last;                 /* the stage that ended last */
    char where[64];                   /* where a cancellation was noticed: "during pt_pass" */
    uint32_t deadline_ms;             /* render.deadline_ms, for its message */
    /* Work that nobody waits for (ns_context_idle_work): long submissions are split, so that
     * a cancellation stops it sooner, at the cost of a little time. */
    int preemptible;
} ns_run;

typedef struct ns_stage {
    const char *name;
    double t0;
    ns_span outer;
    int reported; /* its START was reported: its END is too */
} ns_stage;

/* Begins and ends a render's run (render.c, with the context's lock held): the cancellation
 * flag goes to the device for the render's duration and is cleared on every path. ns_run_end
 * returns the render's status, NS_ERR_CANCELLED when the render was cancelled, with the
 * message naming the stage ("cancelled during pt_pass"). */
void ns_run_begin(ns_context *ctx, const ns_render_control *control, uint32_t deadline_ms);
int ns_run_end(ns_context *ctx, int status, ns_error *err);
/* A cancellation point between stages (a device submission is one by itself). */
int ns_run_check(ns_context *ctx, ns_error *err);
/* Narrows the current span to its part [a, b] (0 <= a <= b <= 1) and returns the span to
 * give back to ns_progress_pop, which restores it with the part done. */
ns_span ns_progress_push(ns_context *ctx, double a, double b);
void ns_progress_pop(ns_context *ctx, ns_span outer);
/* Restores outer without marking the part done: it will be run again (a camera batch whose
 * segments overflowed). */
void ns_progress_restore(ns_context *ctx, ns_span outer);
/* Whether TICKs are wanted now: a progress callback, and no cancellation seen. A caller
 * whose estimate costs something (pt's sum over pixels) asks first. */
int ns_progress_wanted(ns_context *ctx);
/* A TICK: `part` (clamped to [0, 1]) of the current span is done. */
void ns_progress_tick(ns_context *ctx, double part);
/* A stage that takes the part [a, b] of the current span: a START now, and at ns_stage_end an
 * END with its time, which ns_stage_end returns for ns_render_stats. Stages do not nest. */
ns_stage ns_stage_begin(ns_context *ctx, const char *name, double a, double b);
double ns_stage_end(ns_context *ctx, const ns_stage *stage);

/* ---------------------------------------------------------------------------------------
 * The last BVH (render/scene_gpu.c): one entry, the scene's BVH primitives in tree order,
 * its nodes and the permutation from the scene's order, so that a render of the same
 * geometry with other materials, lights or camera skips the build.
 * ------------------------------------------------------------------------------------- */
typedef struct ns_bvh_keep {
    GpuNode *nodes;
    uint32_t node_count;
    GpuPrim *prims;  /* tree order; only kind and numbers are compared (info.y/z: the
                        building render's material and object) */
    uint32_t *order; /* prims[i] is the scene's BVH primitive order[i] */
    uint32_t count;
} ns_bvh_keep;

/* Single scattering's image per unit sigma_s made from a kept camera pass, for a render that
 * would make the same (render/camera_keep.c says when). */
typedef struct ns_single_keep {
    float *image;           /* 3 floats per pixel, before the reference's product; NULL: none */
    GpuMaterial *materials; /* the materials per unit sigma_s it was made with */
    uint32_t material_count;
    uint32_t settings[4]; /* the render settings it was made with (ns_single_keep_settings) */
} ns_single_keep;

/* The surface image and segments of a recent render's camera pass (render/camera_keep.c),
 * kept with the bytes they were made from: the scene buffers with every material's sigma_s
 * cleared, which camera.comp never reads. */
typedef struct ns_camera_keep {
    unsigned char *signature; /* NULL: nothing kept */
    size_t signature_bytes;
    gpu_buffer pixels, segments;
    uint32_t segment_count;
    ns_single_keep single; /* made from this pass, or none */
    uint64_t kept_at;      /* ns_context.camera_clock when kept: the oldest goes first */
} ns_camera_keep;

/* The camera passes a context keeps (render/camera_keep.c): two, so that the web page's
 * quarter-size preview and the full image it renders next do not push each other out. */
#define NS_CAMERA_KEEP_ENTRIES 2

/* A BVH above this many bytes (nodes, primitives and order together) is not kept. */
#define NS_BVH_KEEP_BYTES_MAX (256ull << 20)

void ns_bvh_keep_free(ns_bvh_keep *keep);

/* The context: made once, used by one render at a time (lock serialises them anyway). */
struct ns_table_cache; /* render/scatter_tables.c */
struct ns_source_keep; /* render/source_keep.c */
struct ns_nn_state;    /* render/scatter_tables.c: the networks and their pipeline */

struct ns_context {
    gpu_device dev;
    /* Every pipeline of the renderer but the networks', by ns_pipeline_id: made at start-up
     * or on first use as render/pipelines.c's table says; get one with ns_pipeline. */
    gpu_pipeline pipelines[NS_PIPELINE_CONTEXT_COUNT];
    struct ns_table_cache *tables;
    struct ns_nn_state *nn;
    ns_mc_tables_fn mc_tables;
    void *mc_user;
    uint64_t table_cache_bytes;
    pthread_mutex_t lock;
    char *pipeline_cache_path;
    char *table_node_dir;     /* ns_context_desc.table_node_dir, or NULL */
    uint64_t table_dir_bytes; /* its bound (2 GiB when the desc gives 0) */
    ns_run run;          /* the render in progress: its control, its progress */
    ns_bvh_keep bvh;     /* the last BVH built, for the next render of the same geometry */
    /* The last camera passes, for the next render that makes one of them. */
    ns_camera_keep camera[NS_CAMERA_KEEP_ENTRIES];
    uint64_t camera_clock;
    /* The last two renders' sources, for the next render that makes the same
     * (render/source_keep.h); NULL: none. Two, as the camera passes. */
    struct ns_source_keep *sources[NS_CAMERA_KEEP_ENTRIES];
    uint64_t sources_clock;
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
/* The same, taking the BVH from keep when it holds the same BVH primitives (compared whole,
 * bit for bit, in scene order: kind, centre and radius, corners, vertices; not materials or
 * objects, which the BVH does not depend on), and keeping the BVH it built otherwise. keep
 * NULL: no reuse. *reused (may be NULL) = 1 when the BVH was taken from keep. The result is
 * the same, bit for bit, either way. */
int ns_gpu_scene_build_reusing(const ns_scene *scene, ns_bvh_keep *keep, ns_gpu_scene *out,
                               int *reused, ns_error *err);
void ns_gpu_scene_free(ns_gpu_scene *gs);

/* The scene buffers as bytes to compare whole (render/scene_gpu.c): prefix (the caller's
 * other inputs), the counts, params (the caller's copy, with what does not matter cleared),
 * BVH nodes, primitives, materials (sigma_s and g cleared when clear_sigma_s), lights. NULL
 * when out of memory: then nothing is reused. */
unsigned char *ns_scene_signature(const ns_gpu_scene *gs, const GpuParams *params, int clear_sigma_s,
                                  const void *prefix, size_t prefix_bytes, size_t *bytes);
/* The bytes the camera pass depends on (NULL when out of memory: then nothing is reused). */
unsigned char *ns_camera_signature(const ns_gpu_scene *gs, size_t *bytes);
/* When a kept pass has this signature: replaces *pixels and *segments (destroyed) by its
 * buffers, which the caller then owns (the pass leaves the keep), moves the single
 * scattering made from them into *single (else leaves it empty), sets *segment_count and
 * returns 1; else 0. */
int ns_camera_keep_take(ns_context *ctx, const unsigned char *signature, size_t bytes,
                        gpu_buffer *pixels, gpu_buffer *segments, uint32_t *segment_count,
                        ns_single_keep *single);
/* Keeps the buffers (zeroed in the caller), the signature and *single (both owned from now
 * on; single may be empty) beside the other kept pass or in place of the least recently kept,
 * within the bounds (camera_keep.c); otherwise keeps nothing, frees the signature and
 * *single, leaving the buffers with the caller. */
void ns_camera_keep_put(ns_context *ctx, unsigned char *signature, size_t bytes, gpu_buffer *pixels,
                        gpu_buffer *segments, uint32_t segment_count, ns_single_keep *single);
void ns_camera_keep_free(gpu_device *dev, ns_camera_keep *keep);
/* Frees every kept pass (ns_context_destroy; tests that need a render to trace). */
void ns_camera_keep_clear(ns_context *ctx);
/* The render settings a kept single-scattering image must match: those the stage reads beyond
 * the camera pass's, and the method. */
void ns_single_keep_settings(const ns_render_settings *render, uint32_t settings[4]);
/* 1 when the kept image is the one this render's stage would make from the same camera pass:
 * the same settings and the same `count` materials per unit sigma_s (ns_single_unit_materials),
 * bit for bit; else 0. */
int ns_single_keep_matches(const ns_single_keep *keep, const ns_scene *scene,
                           const GpuMaterial *unit, uint32_t count);
/* Makes keep hold image (owned from now on) with a copy of the materials per unit; 0, or -1
 * out of memory (then image is freed and keep left empty). */
int ns_single_keep_set(ns_single_keep *keep, float *image, const ns_scene *scene,
                       const GpuMaterial *unit, uint32_t count);
void ns_single_keep_free(ns_single_keep *keep);

/* render.adaptive_spp (render/adaptive.c). counts[p] (width x height of them) := the camera
 * samples added to pixel p, from the camera pass's pixels (4 floats each: the mean of spp
 * samples' radiance, and the mean of their squared lengths): in proportion to the spread of
 * p's neighbours' samples (the 24 within 2 pixels; never p's own), at most cap to a pixel,
 * budget in all.
 * Returns how many were given (<= budget; 0 with spp < 2 or where no pixel spreads), or
 * UINT64_MAX when out of memory (counts then all 0). */
uint64_t ns_adaptive_plan(const float *pixels, uint32_t width, uint32_t height, uint32_t spp,
                          uint64_t budget, uint32_t cap, uint32_t *counts);
/* The added samples' entries for camera.comp, pixel by pixel, for the pixels first ..
 * first + pixels - 1 (counts[0] is pixel first's): a pixel's counts samples take the sample
 * indices spp, spp + 1, ... */
void ns_adaptive_entries(const uint32_t *counts, size_t first, size_t pixels, uint32_t spp,
                         GpuAddedSample *entries);
/* Each pixel with added samples becomes the mean of its spp first samples and its added
 * ones (the entries as camera.comp returned them, in ns_adaptive_entries' order). */
void ns_adaptive_merge(float *pixels, size_t count, uint32_t spp, const uint32_t *counts,
                       const GpuAddedSample *entries);

/* Every scene pass (camera.comp, pt.comp) binds the same five scene buffers first, in this
 * order: params (uniform), BVH nodes, primitives, materials, lights. */
enum { NS_SCENE_BUFFER_COUNT = 5, NS_SCENE_BUFFER_MATERIALS = 3 };
/* Fills descs[0..NS_SCENE_BUFFER_COUNT) for gs; the descriptors point into gs, which must
 * outlive the buffer creation. */
void ns_gpu_scene_buffer_descs(const ns_gpu_scene *gs, gpu_buffer_desc descs[NS_SCENE_BUFFER_COUNT]);

/* ns_render with access to the segment buffer (tests). segment_capacity 0 = the default
 * capacity; when segments is not NULL the first min(written, segments_max) are copied. */
typedef struct ns_render_debug {
    uint32_t segment_capacity;
    uint32_t added_capacity; /* 0: as many added samples a pass as one buffer holds */
    GpuSegment *segments;
    uint32_t segments_max;
    uint64_t segments_written;  /* out: recorded (at most the capacity) */
    uint64_t segments_overflow; /* out: dropped because the buffer was full */
} ns_render_debug;

int ns_render_ex(ns_context *ctx, const ns_scene *scene, ns_image *out, ns_render_stats *stats,
                 ns_render_debug *debug, ns_error *err);

/* ---------------------------------------------------------------------------------------
 * Resumed dispatches (render/resume.c). lavapipe stops every shader invocation after 65535
 * loop iterations in all, silently (shared.h), so the long passes (pt.c, single.c and the
 * vrl method's two, vrl_method.c) are cut into many dispatches: an invocation counts its
 * loop iterations, yields after a budget with its state saved in a buffer and resumes in
 * the next dispatch, or each dispatch takes its own share of the work. The shaders count,
 * in a counter buffer, the work left (only in a dispatch that reports, so that the count is
 * that of one dispatch) and the invocations lavapipe cut short anyway. One round runs
 * submissions until the work-left counter reads 0 after one.
 * ------------------------------------------------------------------------------------- */
typedef struct ns_resume_desc {
    const gpu_pipeline *pipeline;
    gpu_buffer *const *buffers; /* pipeline->binding_count of them, in binding order */
    uint32_t groups[3];
    /* Push blocks of pipeline->push_constant_size bytes. With a report field
     * (report_offset != NS_NONE: the byte offset of a uint in the block) push is one block
     * (push_count 1) and each submission dispatches copies of it, the report field 1 in the
     * last copy and 0 in the others. Without one, push holds push_count different blocks,
     * the round's dispatches known in advance, dispatched in one submission. */
    const void *push;
    uint32_t push_count;
    uint32_t report_offset;
    uint32_t *counters;       /* the shader's counter buffer, mapped */
    uint32_t unfinished;      /* counter of the work left after a reporting dispatch; NS_NONE: one
                                 submission finishes the round */
    uint32_t cut;             /* counter of the invocations cut short; NS_NONE: check sees to it */
    uint32_t first_batch;     /* dispatches in the first submission (0: 1), with a report field */
    uint32_t max_batch;       /* each next submission doubles the last, up to this many */
    uint32_t max_submissions; /* gives up before the submission after this many (0: never) */
    uint64_t max_dispatches;  /* or once this many dispatches ran (0: never) */
    /* Called after every submission (may be NULL) with the counters: a nonzero return ends
     * the round with that status (a pass's own counters, such as pt's truncated paths). */
    int (*check)(const uint32_t *counters, void *user, ns_error *err);
    void *user;
    /* Progress: after every submission the round reports a TICK (ns_progress_tick) with the
     * part of the round done: done(done_user) when given (pt: its samples finished), else
     * dispatches run / expected_dispatches when that is known, else 1 - 1 / (1 + submissions)
     * (each submission is twice as long as the last); 1 after a round without a work-left
     * counter, which one submission finishes. Asked only when a progress callback wants it. */
    double (*done)(void *done_user);
    void *done_user;
    uint64_t expected_dispatches;
} ns_resume_desc;

/* ns_resume_dispatch's answers besides NS_OK and the (negative) ns_status errors; err is
 * left untouched, because what they mean (start again with a smaller budget, or fail with
 * the pass's own message) is the caller's to say. */
enum {
    NS_RESUME_CUT = 1,     /* the cut counter was not 0 after a submission: the work done is
                              wrong and the round stopped there */
    NS_RESUME_GAVE_UP = 2, /* max_submissions or max_dispatches reached, work still left */
};

/* Runs one round as desc says. Zeroes the work-left and cut counters before each
 * submission. dispatches (may be NULL) is added the number of dispatches made. */
int ns_resume_dispatch(ns_context *ctx, const ns_resume_desc *desc, uint32_t *dispatches,
                       ns_error *err);

/* Traces rays against prims (spheres, boxes, triangles; built into a BVH here) and planes
 * with shaders/trace_test.comp (render/trace_rays.c; tests only: the pipeline is made by the
 * first call and kept, never at start-up). hits[i].prim is an index into prims, or prim_count + j
 * for planes[j], or NS_NONE. */
int ns_trace_rays(ns_context *ctx, const GpuPrim *prims, uint32_t prim_count, const GpuPrim *planes,
                  uint32_t plane_count, const GpuRay *rays, uint32_t ray_count, GpuHit *hits,
                  ns_error *err);
/* The same, with the dispatch made timing->repeats times (0: once) on one BVH and one set of
 * buffers (the ray benchmark, bench/rays.c): device_ms[r] (NULL: not asked) is dispatch r's
 * device time from two timestamp queries around it, -1 where the queue has no timestamps;
 * wall_ms[r] (NULL: not asked) its host time from recording to the fence. Neither includes
 * the BVH build, the uploads or the readback. `between` (NULL: none) is called after
 * dispatch r with (user, r), so that a benchmark can interleave the runs it compares under
 * the same load; the context's lock is held meanwhile. hits are the last dispatch's. */
typedef struct ns_trace_timing {
    uint32_t repeats;
    uint32_t max_depth; /* where the BVH's surface-area splits stop (0: NS_BVH_MAX_DEPTH), so
                           that tests reach the leaves built past it */
    double *device_ms;
    double *wall_ms;
    void (*between)(void *user, uint32_t r);
    void *user;
} ns_trace_timing;

int ns_trace_rays_timed(ns_context *ctx, const GpuPrim *prims, uint32_t prim_count,
                        const GpuPrim *planes, uint32_t plane_count, const GpuRay *rays,
                        uint32_t ray_count, GpuHit *hits, const ns_trace_timing *timing,
                        ns_error *err);

#endif
