/* context.c — ns_context: the device, the pipelines (render/pipelines.c's table says which
 * are made and warmed here, so that no request pays for their compile) and the pipeline
 * cache. */
#include <stdlib.h>
#include <string.h>

#include "internal.h"
#include "source_keep.h"
#include "scatter.h"

static int env_flag(const char *name)
{
    const char *v = getenv(name);
    return v && *v && strcmp(v, "0") != 0;
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
    ctx->table_dir_bytes = desc->table_dir_bytes ? desc->table_dir_bytes : (2ull << 30);
    if ((desc->pipeline_cache_path &&
         !(ctx->pipeline_cache_path = strdup(desc->pipeline_cache_path))) ||
        (desc->table_node_dir && *desc->table_node_dir &&
         !(ctx->table_node_dir = strdup(desc->table_node_dir)))) {
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
        status = ns_pipelines_create(ctx, err);
    /* The networks' pipelines (made and compiled now) and the table cache
     * (render/scatter_tables.c). */
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
    if (ctx->dev.device) {
        ns_pipelines_destroy(ctx);
        ns_camera_keep_clear(ctx);
    }
    gpu_device_destroy(&ctx->dev);
    ns_bvh_keep_free(&ctx->bvh);
    ns_source_keep_free(ctx);
    pthread_mutex_destroy(&ctx->lock);
    free(ctx->pipeline_cache_path);
    free(ctx->table_node_dir);
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

uint32_t ns_context_live_buffers(const ns_context *ctx)
{
    return ctx ? __atomic_load_n(&ctx->dev.live_buffers, __ATOMIC_SEQ_CST) : 0;
}

void ns_image_free(ns_image *img)
{
    if (!img)
        return;
    free(img->rgb);
    memset(img, 0, sizeof *img);
}
