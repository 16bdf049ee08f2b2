/* pipelines.h — (private to render/) every compute pipeline of the renderer, named by id.
 * One table (pipelines.c) gives each its shader, its binding count, its push-constant size
 * (the sizeof of the push struct the shader shares with C) and when it is made, so that a
 * pipeline's layout is written in one place and the start-up cost of a context is visible in
 * one list. */
#ifndef NS_RENDER_PIPELINES_H
#define NS_RENDER_PIPELINES_H

#include "gpu.h"

typedef enum ns_pipeline_id {
    NS_PIPELINE_CAMERA,     /* shaders/camera.comp */
    NS_PIPELINE_ACCUMULATE, /* shaders/accumulate.comp */
    NS_PIPELINE_VRL,        /* shaders/vrl.comp */
    NS_PIPELINE_GATHER,     /* shaders/gather.comp: the default form (exact, endless beams) */
    NS_PIPELINE_SINGLE,     /* shaders/single.comp */
    /* shaders/single_box_faces.comp: scenes with a box of a refracting medium (single.c) */
    NS_PIPELINE_SINGLE_BOX_FACES,
    NS_PIPELINE_VRL_TRACE,  /* shaders/vrl_trace.comp (method vrl) */
    NS_PIPELINE_VRL_GATHER, /* shaders/vrl_gather.comp (method vrl) */
    /* The gather's other forms (render/gather.c ns_gather_pipeline), one shader each. */
    NS_PIPELINE_GATHER_BOUNDED,
    NS_PIPELINE_GATHER_PAPER,
    NS_PIPELINE_GATHER_PAPER_BOUNDED,
    NS_PIPELINE_GATHER_DIPOLE,
    NS_PIPELINE_GATHER_FIRST,
    NS_PIPELINE_GATHER_EXACT_FIRST,
    NS_PIPELINE_PT,         /* shaders/pt.comp (method pt) */
    NS_PIPELINE_TRACE_TEST, /* shaders/trace_test.comp (tests: render/trace_rays.c) */
    /* shaders/accumulate_second.comp: two tables of one material on one walk
     * (scatter_tables.c, ns_tables_expect_orders) */
    NS_PIPELINE_ACCUMULATE_SECOND,
    /* The pipelines above are kept in ns_context.pipelines; the networks' below are kept in
     * ns_nn_gpu (render/nn_reconstruct.h), which an nn session uses without a context. */
    NS_PIPELINE_CONTEXT_COUNT,
    NS_PIPELINE_NN_RECONSTRUCT = NS_PIPELINE_CONTEXT_COUNT, /* shaders/nn_reconstruct.comp */
    NS_PIPELINE_NN_INTERPOLATE,                             /* shaders/nn_interpolate.comp */
    NS_PIPELINE_COUNT
} ns_pipeline_id;

typedef enum ns_pipeline_when {
    /* Made and warmed by ns_context_create: no request pays for its compile (lavapipe
     * compiles inside the first dispatch, 1-2 s each). */
    NS_PIPELINE_AT_START,
    /* Made and warmed by the first render that needs it, then kept: a pipeline most renders
     * never use is not charged to every start-up, and the render that makes it reports the
     * time as a stage of its own. */
    NS_PIPELINE_FIRST_USE_WARMED,
    /* Made by the first call that needs it, then kept; its first dispatch compiles it. */
    NS_PIPELINE_FIRST_USE,
    /* Made and warmed by ns_nn_gpu_create with the networks (a dispatch of its own: the
     * generic warm-up's uniform buffer is smaller than GpuNnParams). */
    NS_PIPELINE_WITH_NETWORKS,
} ns_pipeline_when;

typedef struct ns_pipeline_row {
    const char *shader;  /* name in the shader registry: shaders/<shader>.comp */
    uint32_t bindings;   /* binding 0 is a uniform buffer, the rest storage buffers... */
    uint32_t push_bytes; /* sizeof the shader's push struct; 0 = no push constants */
    ns_pipeline_when when;
    uint32_t texel_bindings; /* ...except these (bit i: binding i), texel buffers */
    uint32_t texel_r32_bindings; /* of those, the ones of 4-byte texels (gpu_pipeline_desc) */
} ns_pipeline_row;

/* The bindings of the BVH's nodes (1) and primitives (2), which every shader that traces
 * reads as texel buffers (shaders/trace.glsl). */
#define NS_TRACE_TEXEL_BINDINGS ((1u << 1) | (1u << 2))

/* The table's row of id (NULL if id is out of range). */
const ns_pipeline_row *ns_pipeline_row_of(ns_pipeline_id id);

/* Creates the pipeline of id's row on dev into *pipe, without warming it. Destroy it with
 * gpu_pipeline_destroy. */
int ns_pipeline_make(gpu_device *dev, ns_pipeline_id id, gpu_pipeline *pipe, ns_error *err);

/* Makes and warms every NS_PIPELINE_AT_START pipeline of ctx (ns_context_create). On failure
 * the ones made stay: ns_pipelines_destroy frees them. */
int ns_pipelines_create(ns_context *ctx, ns_error *err);
/* Destroys every pipeline ctx holds, whenever it was made; safe twice. */
void ns_pipelines_destroy(ns_context *ctx);

/* Points *out at ctx's pipeline id (id < NS_PIPELINE_CONTEXT_COUNT), making it now if its
 * row says first use and no call made it before. The caller holds ctx->lock, as every
 * render does, so that two threads never make the same pipeline. made_ms (may be NULL): the
 * milliseconds spent making it now (also when that failed), 0 when it was there. */
int ns_pipeline(ns_context *ctx, ns_pipeline_id id, gpu_pipeline **out, double *made_ms,
                ns_error *err);

#endif
