/* context.c — ns_context: the device, every pipeline and the pipeline cache, made once
 * and warmed at start-up so that no request ever pays for a shader compile. */
#include <stdlib.h>
#include <string.h>

#include <stddef.h>

#include "internal.h"
#include "scatter.h"
#include "accumulate_shared.h"

static int env_flag(const char *name)
{
    const char *v = getenv(name);
    return v && *v && strcmp(v, "0") != 0;
}

/* Every pipeline of the renderer: shader, bindings (binding 0 uniform, the rest storage),
 * push-constant bytes. Each is created and warmed here, once. */
typedef struct pipeline_row {
    size_t offset; /* of the gpu_pipeline in ns_context */
    const char *shader;
    uint32_t bindings;
    uint32_t push_bytes;
} pipeline_row;

static const pipeline_row pipeline_rows[] = {
    {offsetof(ns_context, camera), "camera", 8, sizeof(GpuSamplePush)},
    {offsetof(ns_context, trace_test), "trace_test", 5, 0},
    {offsetof(ns_context, accumulate), "accumulate", 4, sizeof(GpuAccumulatePush)},
    {offsetof(ns_context, vrl), "vrl", 8, 32},
    {offsetof(ns_context, gather), "gather", 8, sizeof(GpuGatherPush)},
    {offsetof(ns_context, single), "single", 8, 16},
    {offsetof(ns_context, vrl_trace), "vrl_trace", 8, 32},
    {offsetof(ns_context, vrl_gather), "vrl_gather", 8, 32},
};

static gpu_pipeline *pipeline_at(ns_context *ctx, const pipeline_row *row)
{
    return (gpu_pipeline *)((char *)ctx + row->offset);
}

static int create_pipelines(ns_context *ctx, ns_error *err)
{
    int status = NS_OK;
    size_t n = sizeof pipeline_rows / sizeof pipeline_rows[0];
    for (size_t i = 0; i < n && !status; i++)
        status = gpu_pipeline_create(&ctx->dev, pipeline_at(ctx, &pipeline_rows[i]),
                                     &(gpu_pipeline_desc){.shader = pipeline_rows[i].shader,
                                                          .binding_count = pipeline_rows[i].bindings,
                                                          .push_constant_size =
                                                              pipeline_rows[i].push_bytes},
                                     err);
    /* lavapipe compiles inside the first dispatch (1-2 s each): do it now, once. */
    for (size_t i = 0; i < n && !status; i++)
        status = gpu_pipeline_warm(&ctx->dev, pipeline_at(ctx, &pipeline_rows[i]), err);
    return status;
}

int ns_context_create(const ns_context_desc *desc, ns_context **out, ns_error *err)
{
    *out = NULL;
    ns_context_desc defaults = {0};
    if (!desc)
        desc = &defaults;
    ns_context *ctx = calloc(1, sizeof *ctx);
    if (!ctx)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "context: out of memory");
    pthread_mutex_init(&ctx->lock, NULL);
    ctx->mc_tables = desc->mc_tables;
    ctx->mc_user = desc->mc_user;
    ctx->table_cache_bytes = desc->table_cache_bytes ? desc->table_cache_bytes : (1ull << 30);
    if (desc->pipeline_cache_path &&
        !(ctx->pipeline_cache_path = strdup(desc->pipeline_cache_path))) {
        ns_context_destroy(ctx);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "context: out of memory");
    }
    gpu_device_desc device = {
        .device = desc->device ? desc->device : getenv("NSCATTER_DEVICE"),
        .validation = desc->validation || env_flag("NSCATTER_VALIDATION"),
        .pipeline_cache_path = desc->pipeline_cache_path,
    };
    int status = gpu_device_create(&ctx->dev, &device, err);
    if (!status)
        status = create_pipelines(ctx, err);
    /* The networks' pipeline (compiled now) and the table cache (render/scatter_tables.c). */
    if (!status)
        status = ns_tables_init(ctx, err);
    /* Save right after warming so a later crash still leaves a warm cache behind. */
    if (!status && ctx->pipeline_cache_path)
        status = gpu_pipeline_cache_save(&ctx->dev, ctx->pipeline_cache_path, err);
    if (!status)
        status = gpu_validation_check(&ctx->dev, 0, err);
    if (status) {
        ns_context_destroy(ctx);
        return status;
    }
    *out = ctx;
    return NS_OK;
}

void ns_context_destroy(ns_context *ctx)
{
    if (!ctx)
        return;
    if (ctx->dev.device)
        ns_tables_destroy(ctx);
    if (ctx->dev.device)
        for (size_t i = 0; i < sizeof pipeline_rows / sizeof pipeline_rows[0]; i++)
            gpu_pipeline_destroy(&ctx->dev, pipeline_at(ctx, &pipeline_rows[i]));
    if (ctx->dev.device)
        gpu_pipeline_destroy(&ctx->dev, &ctx->pt);
    if (ctx->dev.device)
        for (size_t i = 0; i < sizeof ctx->gather_forms / sizeof ctx->gather_forms[0]; i++)
            gpu_pipeline_destroy(&ctx->dev, &ctx->gather_forms[i]);
    gpu_device_destroy(&ctx->dev);
    pthread_mutex_destroy(&ctx->lock);
    free(ctx->pipeline_cache_path);
    free(ctx);
}

void ns_context_device_info(const ns_context *ctx, ns_device_info *out)
{
    if (!ctx) {
        memset(out, 0, sizeof *out);
        return;
    }
    *out = ctx->dev.info;
}

void ns_image_free(ns_image *img)
{
    if (!img)
        return;
    free(img->rgb);
    memset(img, 0, sizeof *img);
}
