/* Placeholder until the Vulkan layer lands (render/gpu.c replaces this file). */
#include <stdlib.h>
#include <string.h>
#include "nscatter.h"

int ns_context_create(const ns_context_desc *desc, ns_context **out, ns_error *err)
{
    *out = NULL;
    if (err) { err->status = NS_ERR_NOT_AVAILABLE; strcpy(err->message, "Vulkan layer not built yet"); }
    return NS_ERR_NOT_AVAILABLE;
}
void ns_context_destroy(ns_context *ctx) {}
void ns_context_device_info(const ns_context *ctx, ns_device_info *out) { memset(out, 0, sizeof *out); }
void ns_image_free(ns_image *img) { if (img) { free(img->rgb); memset(img, 0, sizeof *img); } }
int ns_render(ns_context *ctx, const ns_scene *scene, ns_image *out, ns_render_stats *stats, ns_error *err)
{
    return ns_context_create(NULL, &ctx, err);
}
