/* cmd_info.c — `nscatter info [--device D] [--json]`: which Vulkan device nscatter would
 * render on, and its driver. It makes a full render context (device, pipelines warmed),
 * so a zero exit status also means the device can run the shaders. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "commands.h"
#include "huge_pages.h"
#include "nscatter.h"

static void info_usage(FILE *out)
{
    fprintf(out,
            "usage: nscatter info [--device D] [--json]\n"
            "\n"
            "  --device D   Vulkan device: index or case-insensitive name substring\n"
            "               (default: lavapipe if present, else the first; also NSCATTER_DEVICE)\n"
            "  --json       print one JSON object instead of text\n"
            "\n"
            "exit status: 0 device ready, 1 no usable Vulkan device, 2 bad arguments\n");
}

static void version_string(uint32_t v, char *out, size_t size)
{
    /* VK_API_VERSION_MAJOR/MINOR/PATCH without including Vulkan in server/. */
    snprintf(out, size, "%u.%u.%u", (v >> 22) & 0x7fu, (v >> 12) & 0x3ffu, v & 0xfffu);
}

/* A memory type's bits as "device-local+host-visible+..." ("none" without any). */
static void memory_type_name(uint32_t bits, char *out, size_t size)
{
    static const struct {
        uint32_t bit;
        const char *name;
    } names[] = {{NS_MEMORY_DEVICE_LOCAL, "device-local"},
                 {NS_MEMORY_HOST_VISIBLE, "host-visible"},
                 {NS_MEMORY_HOST_COHERENT, "coherent"},
                 {NS_MEMORY_HOST_CACHED, "cached"}};
    size_t used = 0;
    out[0] = '\0';
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++)
        if (bits & names[i].bit)
            used += (size_t)snprintf(out + used, used < size ? size - used : 0, "%s%s",
                                     used ? "+" : "", names[i].name);
    if (!used)
        snprintf(out, size, "none");
}

static int print_json(const ns_device_info *info, const char *api)
{
    char thp[32];
    json_t *obj = json_pack(
        "{s:s, s:s, s:s, s:s, s:b, s:I, s:I, s:I, s:I, s:b, s:b, s:s, s:b, s:s}", "device",
        info->device_name, "driver", info->driver_name, "driver_info", info->driver_info,
        "api_version", api, "is_cpu", info->is_cpu, "vendor_id", (json_int_t)info->vendor_id,
        "device_id", (json_int_t)info->device_id, "subgroup_size", (json_int_t)info->subgroup_size,
        "device_local_bytes", (json_int_t)info->device_local_bytes, "ray_query", info->ray_query,
        "ray_tracing_pipeline", info->ray_tracing_pipeline, "version", NS_VERSION,
        "malloc_huge_pages", huge_pages_on(), "kernel_huge_pages",
        huge_pages_kernel_mode(thp, sizeof thp));
    json_t *types = obj ? json_array() : NULL;
    for (uint32_t i = 0; types && i < info->memory_type_count; i++) {
        char name[96];
        memory_type_name(info->memory_types[i], name, sizeof name);
        json_array_append_new(types, json_string(name));
    }
    if (!obj || !types || json_object_set_new(obj, "memory_types", types)) {
        json_decref(obj);
        return 1;
    }
    char *text = json_dumps(obj, JSON_COMPACT);
    json_decref(obj);
    if (!text)
        return 1;
    printf("%s\n", text);
    free(text);
    return 0;
}

int cmd_info(int argc, char **argv)
{
    const char *device = NULL;
    int as_json = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--json")) {
            as_json = 1;
        } else if (!strcmp(argv[i], "--device") && i + 1 < argc) {
            device = argv[++i];
        } else if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
            info_usage(stdout);
            return 0;
        } else {
            fprintf(stderr, "nscatter info: unknown or incomplete argument '%s'\n\n", argv[i]);
            info_usage(stderr);
            return 2;
        }
    }
    ns_context *ctx = NULL;
    ns_error err = {0};
    int status = ns_context_create(&(ns_context_desc){.device = device}, &ctx, &err);
    if (status) {
        fprintf(stderr, "nscatter info: no usable Vulkan device: %s (%s)\n", err.message,
                ns_status_name(status));
        return 1;
    }
    ns_device_info info;
    ns_context_device_info(ctx, &info);
    ns_context_destroy(ctx);
    char api[32];
    version_string(info.api_version, api, sizeof api);
    if (as_json)
        return print_json(&info, api);
    printf("device:       %s\n", info.device_name);
    printf("type:         %s\n", info.is_cpu ? "cpu" : "gpu");
    printf("driver:       %s\n", info.driver_name);
    printf("driver info:  %s\n", info.driver_info);
    printf("api version:  %s\n", api);
    printf("vendor/device id: 0x%04x / 0x%04x\n", info.vendor_id, info.device_id);
    printf("subgroup size: %u\n", info.subgroup_size);
    printf("device memory: %.1f GiB (largest device-local heap)\n",
           (double)info.device_local_bytes / (1024.0 * 1024.0 * 1024.0));
    printf("memory types:");
    for (uint32_t i = 0; i < info.memory_type_count; i++) {
        char name[96];
        memory_type_name(info.memory_types[i], name, sizeof name);
        printf("%s %s", i ? "," : "", name);
    }
    printf("\n");
    /* Hardware traversal is reported so that a user can see what a GPU offers; nscatter
     * traces through its compute BVH everywhere (docs/rendering.md, *Ray tracing*). */
    printf("ray query:    %s\n", info.ray_query ? "yes (not used)" : "no");
    printf("ray tracing pipelines: %s\n", info.ray_tracing_pipeline ? "yes (not used)" : "no");
    /* cli/huge_pages.c: what a render's fresh buffers cost at their first touch. */
    char thp[32];
    printf("huge pages:   GLIBC_TUNABLES %s glibc.malloc.hugetlb=1 (kernel mode: %s)\n",
           huge_pages_on() ? "has" : "has not", huge_pages_kernel_mode(thp, sizeof thp));
    return 0;
}
