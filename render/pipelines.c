/* pipelines.c — the table of every compute pipeline of the renderer, and the one function
 * that gets a context's pipeline by id (making it on first use where the table says so). */
#include "pipelines.h"

#include <pthread.h>
#include <unistd.h>

#include "internal.h"
#include "accumulate_shared.h"
#include "pt_shared.h"
#include "scatter_shared.h"
#include "vrl_method_shared.h"
#include "vrl_shared.h"

/* The gather's binding of the table (gather.glsl). */
#define GATHER_TABLE_TEXELS (1u << 5)

/* The push-constant sizes are the sizeof of the structs the shaders declare their push
 * blocks with (each header checks its struct's size with _Static_assert), so a block that
 * grows on one side cannot leave the pipeline layout behind. */
static const ns_pipeline_row pipeline_rows[NS_PIPELINE_COUNT] = {
    [NS_PIPELINE_CAMERA] = {"camera", 9, sizeof(GpuSamplePush), NS_PIPELINE_AT_START,
                            NS_TRACE_TEXEL_BINDINGS, 0},
    /* J, read at every step of the walk (accumulate.glsl), is a texel buffer of 16-byte
     * texels: a cell's channels in one fetch (accumulate_shared.h). */
    [NS_PIPELINE_ACCUMULATE] = {"accumulate", 5, sizeof(GpuAccumulatePush), NS_PIPELINE_AT_START,
                                1u << 1, 0},
    [NS_PIPELINE_VRL] = {"vrl", 8, sizeof(GpuVrlPush), NS_PIPELINE_AT_START,
                         NS_TRACE_TEXEL_BINDINGS, 0},
    /* The table A, read at per-lane addresses four times per channel and point (gather.glsl),
     * is a texel buffer of floats in every form of the gather: on lavapipe a storage buffer's
     * per-lane read is a loop over the lanes, a texel fetch goes through the texture path
     * (1.7-1.9x shorter gather; docs/bench.md, *The gather's table as texels*). */
    [NS_PIPELINE_GATHER] = {"gather", 8, sizeof(GpuGatherPush), NS_PIPELINE_AT_START,
                            GATHER_TABLE_TEXELS, GATHER_TABLE_TEXELS},
    [NS_PIPELINE_SINGLE] = {"single", 8, sizeof(GpuSinglePush), NS_PIPELINE_AT_START,
                            NS_TRACE_TEXEL_BINDINGS, 0},
    /* Only scenes with a box of a refracting medium take it: made when one first does. */
    [NS_PIPELINE_SINGLE_BOX_FACES] = {"single_box_faces", 8, sizeof(GpuSinglePush),
                                      NS_PIPELINE_FIRST_USE, NS_TRACE_TEXEL_BINDINGS, 0},
    [NS_PIPELINE_VRL_TRACE] = {"vrl_trace", 9, sizeof(GpuVrlTracePush), NS_PIPELINE_AT_START,
                               NS_TRACE_TEXEL_BINDINGS, 0},
    [NS_PIPELINE_VRL_GATHER] = {"vrl_gather", 8, sizeof(GpuVrlGatherPush), NS_PIPELINE_AT_START,
                                NS_TRACE_TEXEL_BINDINGS, 0},
    /* Without the paper's and the dipole's branches the default gather runs 1.7x faster on
     * lavapipe (gather.glsl), so each form is its own shader and only the default one is
     * compiled at start-up; the others are warmed when made so that their render reports the
     * compile as the stage "gather_pipeline". */
    [NS_PIPELINE_GATHER_BOUNDED] = {"gather_bounded", 8, sizeof(GpuGatherPush),
                                    NS_PIPELINE_FIRST_USE_WARMED, GATHER_TABLE_TEXELS,
                                    GATHER_TABLE_TEXELS},
    [NS_PIPELINE_GATHER_PAPER] = {"gather_paper", 8, sizeof(GpuGatherPush),
                                  NS_PIPELINE_FIRST_USE_WARMED, GATHER_TABLE_TEXELS,
                                  GATHER_TABLE_TEXELS},
    [NS_PIPELINE_GATHER_PAPER_BOUNDED] = {"gather_paper_bounded", 8, sizeof(GpuGatherPush),
                                          NS_PIPELINE_FIRST_USE_WARMED, GATHER_TABLE_TEXELS,
                                          GATHER_TABLE_TEXELS},
    /* The walks' reflected beams' first order, with their tables (every render with walks
     * in a refracting medium: made at start-up, as the default form) or alone (single
     * scattering's correction, and beside the paper's accumulation: made on first use). */
    [NS_PIPELINE_GATHER_EXACT_FIRST] = {"gather_exact_first", 8, sizeof(GpuGatherPush),
                                        NS_PIPELINE_AT_START, GATHER_TABLE_TEXELS,
                                        GATHER_TABLE_TEXELS},
    [NS_PIPELINE_GATHER_FIRST] = {"gather_first", 8, sizeof(GpuGatherPush),
                                  NS_PIPELINE_FIRST_USE_WARMED, GATHER_TABLE_TEXELS,
                                  GATHER_TABLE_TEXELS},
    [NS_PIPELINE_GATHER_DIPOLE] = {"gather_dipole", 8, sizeof(GpuGatherPush),
                                   NS_PIPELINE_FIRST_USE_WARMED, GATHER_TABLE_TEXELS,
                                   GATHER_TABLE_TEXELS},
    /* The reference path tracer is not on the fast path: its compile (0.8-1.2 s on lavapipe
     * with Mesa's cache warm, 2026-11-30: NIR passes before the cache is looked up) is
     * paid once per context by the first pt render (stage "pt_pipeline" and its first
     * dispatch), never by a context that renders no pt. */
    [NS_PIPELINE_PT] = {"pt", 8, sizeof(GpuPtPush), NS_PIPELINE_FIRST_USE, NS_TRACE_TEXEL_BINDINGS,
                        0},
    /* Only the BVH tests trace rays on their own (ns_trace_rays): a service never does. */
    [NS_PIPELINE_TRACE_TEST] = {"trace_test", 5, 0, NS_PIPELINE_FIRST_USE, NS_TRACE_TEXEL_BINDINGS,
                                0},
    /* Only renders that read two order sets of one material (multiple scattering alone,
     * with walks) take it: not charged to every start-up. */
    [NS_PIPELINE_ACCUMULATE_SECOND] = {"accumulate_second", 5, sizeof(GpuAccumulatePush),
                                       NS_PIPELINE_FIRST_USE, 1u << 1, 0},
    [NS_PIPELINE_NN_RECONSTRUCT] = {"nn_reconstruct", 3, 0, NS_PIPELINE_WITH_NETWORKS, 0, 0},
    [NS_PIPELINE_NN_INTERPOLATE] = {"nn_interpolate", 3, 0, NS_PIPELINE_WITH_NETWORKS, 0, 0},
};

const ns_pipeline_row *ns_pipeline_row_of(ns_pipeline_id id)
{
    return (unsigned)id < NS_PIPELINE_COUNT ? &pipeline_rows[id] : NULL;
}

int ns_pipeline_make(gpu_device *dev, ns_pipeline_id id, gpu_pipeline *pipe, ns_error *err)
{
    const ns_pipeline_row *row = ns_pipeline_row_of(id);
    if (!row)
        return ns_fail(err, NS_ERR_INTERNAL, "pipeline id %d is not in the table", (int)id);
    return gpu_pipeline_create(dev, pipe,
                               &(gpu_pipeline_desc){.shader = row->shader,
                                                    .binding_count = row->bindings,
                                                    .push_constant_size = row->push_bytes,
                                                    .texel_bindings = row->texel_bindings,
                                                    .texel_r32_bindings = row->texel_r32_bindings},
                               err);
}

/* The start-up pipelines are made by a few threads at once: lavapipe translates and
 * optimises each shader's NIR inside vkCreateComputePipelines (single.comp about 0.45 s,
 * vrl_trace.comp 0.27 s, camera.comp 0.2 s on the 2-core machine), and the Vulkan spec
 * makes pipeline creation (and the pipeline cache) safe from several threads. Each thread
 * takes the next pipeline not yet taken, the largest shaders first (their size is the best
 * guess at their cost), so that the longest one does not start last. */
typedef struct pipeline_maker {
    ns_context *ctx;
    pthread_mutex_t lock;
    ns_pipeline_id order[NS_PIPELINE_CONTEXT_COUNT];
    int count, next;
    int status;     /* the first failure's */
    ns_error error; /* its message */
} pipeline_maker;

static void *make_start_pipelines(void *arg)
{
    pipeline_maker *m = arg;
    for (;;) {
        pthread_mutex_lock(&m->lock);
        int stop = m->status != NS_OK || m->next >= m->count;
        ns_pipeline_id id = stop ? NS_PIPELINE_CONTEXT_COUNT : m->order[m->next++];
        pthread_mutex_unlock(&m->lock);
        if (stop)
            return NULL;
        ns_error err = {0};
        int status = ns_pipeline_make(&m->ctx->dev, id, &m->ctx->pipelines[id], &err);
        if (status) {
            pthread_mutex_lock(&m->lock);
            if (m->status == NS_OK) {
                m->status = status;
                m->error = err;
            }
            pthread_mutex_unlock(&m->lock);
        }
    }
}

int ns_pipelines_create(ns_context *ctx, ns_error *err)
{
    pipeline_maker maker = {.ctx = ctx, .status = NS_OK};
    size_t spirv_bytes[NS_PIPELINE_CONTEXT_COUNT];
    for (int id = 0; id < NS_PIPELINE_CONTEXT_COUNT; id++) {
        if (pipeline_rows[id].when != NS_PIPELINE_AT_START)
            continue;
        ns_shader_code(pipeline_rows[id].shader, &spirv_bytes[id]);
        int at = maker.count++;
        for (; at > 0 && spirv_bytes[maker.order[at - 1]] < spirv_bytes[id]; at--)
            maker.order[at] = maker.order[at - 1];
        maker.order[at] = (ns_pipeline_id)id;
    }
    pthread_mutex_init(&maker.lock, NULL);
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    pthread_t helpers[3];
    int helper_count = 0;
    /* The calling thread makes pipelines too; a helper that cannot start leaves it more. */
    for (int i = 0; i < (int)(sizeof helpers / sizeof helpers[0]) && i + 1 < cores; i++)
        if (pthread_create(&helpers[helper_count], NULL, make_start_pipelines, &maker) == 0)
            helper_count++;
    make_start_pipelines(&maker);
    for (int i = 0; i < helper_count; i++)
        pthread_join(helpers[i], NULL);
    pthread_mutex_destroy(&maker.lock);
    int status = maker.status;
    if (status && err)
        *err = maker.error;
    /* All made first, then all warmed: lavapipe compiles inside the first dispatch. */
    for (int id = 0; id < NS_PIPELINE_CONTEXT_COUNT && !status; id++)
        if (pipeline_rows[id].when == NS_PIPELINE_AT_START)
            status = gpu_pipeline_warm(&ctx->dev, &ctx->pipelines[id], err);
    return status;
}

void ns_pipelines_destroy(ns_context *ctx)
{
    /* A pipeline never made is zeroed, and destroying it does nothing. */
    for (int id = 0; id < NS_PIPELINE_CONTEXT_COUNT; id++)
        gpu_pipeline_destroy(&ctx->dev, &ctx->pipelines[id]);
}

int ns_pipeline(ns_context *ctx, ns_pipeline_id id, gpu_pipeline **out, double *made_ms,
                ns_error *err)
{
    *out = NULL;
    if (made_ms)
        *made_ms = 0;
    if ((unsigned)id >= NS_PIPELINE_CONTEXT_COUNT)
        return ns_fail(err, NS_ERR_INTERNAL, "pipeline id %d is not a context's", (int)id);
    gpu_pipeline *pipe = &ctx->pipelines[id];
    if (pipe->pipeline) {
        *out = pipe;
        return NS_OK;
    }
    /* Start-up made every NS_PIPELINE_AT_START pipeline or the context does not exist. */
    if (pipeline_rows[id].when == NS_PIPELINE_AT_START)
        return ns_fail(err, NS_ERR_INTERNAL, "pipeline %s was not made at start-up",
                       pipeline_rows[id].shader);
    double t0 = ns_now_ms();
    int status = ns_pipeline_make(&ctx->dev, id, pipe, err);
    /* A failed warm-up leaves the pipeline made: the next render uses it (and its first
     * dispatch compiles it), as it would any pipeline. */
    if (!status && pipeline_rows[id].when == NS_PIPELINE_FIRST_USE_WARMED)
        status = gpu_pipeline_warm(&ctx->dev, pipe, err);
    if (made_ms)
        *made_ms = ns_now_ms() - t0;
    if (!status)
        *out = pipe;
    return status;
}
