/* cmd_render.c — `nscatter render SCENE.json -o OUT.png|OUT.exr`: one render from the
 * command line, written atomically, with optional per-stage timings as JSON on stdout. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include <jansson.h>

#include "args.h"
#include "commands.h"
#include "encode.h"
#include "mc_provider.h"
#include "nscatter.h"
#include "render_job.h"
#include "scene_json.h"

/* Scene files are text; anything bigger than this is not a scene we can render anyway
 * (the HTTP service's default body limit is the same). */
#define RENDER_MAX_SCENE_BYTES (64u * 1024u * 1024u)

typedef struct render_args {
    const char *scene_path;
    const char *out_path;
    const char *device;
    const char *asset_dir;
    int timings;
    int half;
    int has_exposure;
    float exposure;
    encode_format format;
} render_args;

static void render_usage(FILE *out)
{
    fprintf(out,
            "usage: nscatter render SCENE.json -o OUT.png|OUT.exr [options]\n"
            "\n"
            "  -o, --output PATH   output image; the extension picks the format (.png, .exr)\n"
            "  --timings           print one JSON object with per-stage milliseconds to stdout\n"
            "  --device D          Vulkan device: index or name substring (default: lavapipe;\n"
            "                      also NSCATTER_DEVICE)\n"
            "  --half              EXR only: store 16-bit half floats instead of 32-bit\n"
            "  --exposure STOPS    scale radiance by 2^STOPS before the PNG's sRGB transfer\n"
            "                      (overrides the scene's render.exposure; EXR stays linear)\n"
            "  --assets DIR        folder holding mesh assets named by \"asset\" in the scene\n"
            "\n"
            "exit status: 0 written, 1 render or write failed, 2 bad arguments or invalid scene\n");
}

static int format_from_path(const char *path, encode_format *format)
{
    const char *dot = strrchr(path, '.');
    if (dot && !strchr(dot, '/') && !strcasecmp(dot, ".png")) {
        *format = ENCODE_PNG;
        return 0;
    }
    if (dot && !strchr(dot, '/') && !strcasecmp(dot, ".exr")) {
        *format = ENCODE_EXR_FLOAT;
        return 0;
    }
    return -1;
}

static int parse_float_arg(const char *text, float *out)
{
    double v = 0;
    if (cli_number(text, &v) || fabs(v) > 64.0)
        return -1;
    *out = (float)v;
    return 0;
}

/* Returns 0, or 2 after printing what is wrong (or 1 with *done set for --help). */
static int parse_render_args(int argc, char **argv, render_args *a, int *done)
{
    memset(a, 0, sizeof *a);
    for (int i = 1; i < argc; i++) {
        const char *arg = argv[i];
        int has_value = i + 1 < argc;
        if (!strcmp(arg, "-h") || !strcmp(arg, "--help")) {
            render_usage(stdout);
            *done = 1;
            return 0;
        } else if (!strcmp(arg, "--timings")) {
            a->timings = 1;
        } else if (!strcmp(arg, "--half")) {
            a->half = 1;
        } else if ((!strcmp(arg, "-o") || !strcmp(arg, "--output")) && has_value) {
            a->out_path = argv[++i];
        } else if (!strcmp(arg, "--device") && has_value) {
            a->device = argv[++i];
        } else if (!strcmp(arg, "--assets") && has_value) {
            a->asset_dir = argv[++i];
        } else if (!strcmp(arg, "--exposure") && has_value) {
            if (parse_float_arg(argv[++i], &a->exposure)) {
                fprintf(stderr,
                        "nscatter render: --exposure '%s' is not a number of stops in "
                        "[-64, 64]\n",
                        argv[i]);
                return 2;
            }
            a->has_exposure = 1;
        } else if (arg[0] == '-' && arg[1]) {
            fprintf(stderr, "nscatter render: unknown option or missing value: '%s'\n", arg);
            render_usage(stderr);
            return 2;
        } else if (!a->scene_path) {
            a->scene_path = arg;
        } else {
            fprintf(stderr, "nscatter render: more than one scene given ('%s' and '%s')\n",
                    a->scene_path, arg);
            return 2;
        }
    }
    if (!a->scene_path || !a->out_path) {
        fprintf(stderr, "nscatter render: %s\n",
                !a->scene_path ? "no SCENE.json given" : "no output given (-o OUT.png|OUT.exr)");
        render_usage(stderr);
        return 2;
    }
    if (format_from_path(a->out_path, &a->format)) {
        fprintf(stderr, "nscatter render: -o '%s': unknown image type; use a .png or .exr name\n",
                a->out_path);
        return 2;
    }
    if (a->half && a->format != ENCODE_EXR_FLOAT) {
        fprintf(stderr, "nscatter render: --half applies to EXR output only (-o '%s')\n",
                a->out_path);
        return 2;
    }
    if (a->half)
        a->format = ENCODE_EXR_HALF;
    return 0;
}

/* ---------------------------------------------------------------------------------------
 * Files.
 * ------------------------------------------------------------------------------------- */
static char *read_scene_file(const char *path, size_t *length)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        fprintf(stderr, "nscatter render: cannot open '%s': %s\n", path, strerror(errno));
        return NULL;
    }
    char *text = NULL;
    size_t size = 0, cap = 0;
    for (;;) {
        if (size == cap) {
            cap = cap ? cap * 2 : 64 * 1024;
            char *grown = cap <= RENDER_MAX_SCENE_BYTES + 1 ? realloc(text, cap) : NULL;
            if (!grown) {
                fprintf(stderr, "nscatter render: '%s' is larger than %u bytes\n", path,
                        RENDER_MAX_SCENE_BYTES);
                free(text);
                fclose(f);
                return NULL;
            }
            text = grown;
        }
        size_t n = fread(text + size, 1, cap - size, f);
        size += n;
        if (n == 0)
            break;
    }
    int failed = ferror(f);
    fclose(f);
    if (failed) {
        fprintf(stderr, "nscatter render: cannot read '%s'\n", path);
        free(text);
        return NULL;
    }
    *length = size;
    return text;
}

/* Writes to a temporary file beside `path`, then renames it over `path`
 * (ns_write_file_atomic), so a reader never sees a half-written image and a failed render
 * leaves an earlier image in place. */
static int write_file_atomically(const char *path, const encode_buffer *buf)
{
    ns_error err = {0};
    if (ns_write_file_atomic(path, buf->data, buf->size, &err)) {
        fprintf(stderr, "nscatter render: %s\n", err.message);
        return -1;
    }
    return 0;
}

/* ---------------------------------------------------------------------------------------
 * The command.
 * ------------------------------------------------------------------------------------- */
static void print_issues(const char *path, const scene_issues *issues)
{
    if (issues->syntax_error) {
        fprintf(stderr, "%s:%d:%d: %s\n", path, issues->line, issues->column,
                issues->count ? issues->items[0].detail : "not valid JSON");
        return;
    }
    for (uint32_t i = 0; i < issues->count && i < SCENE_MAX_ISSUES; i++)
        fprintf(stderr, "%s: %s: %s\n", path,
                issues->items[i].pointer[0] ? issues->items[i].pointer : "(document)",
                issues->items[i].detail);
    if (issues->total > issues->count)
        fprintf(stderr, "%s: ... and %u more\n", path, issues->total - issues->count);
}

static void print_timings(const render_args *a, ns_context *ctx, const ns_scene *scene,
                          const ns_render_stats *stats, double context_ms, size_t bytes)
{
    ns_device_info info;
    ns_context_device_info(ctx, &info);
    json_t *timings = json_pack(
        "{s:s, s:s, s:o, s:f, s:f, s:I, s:I, s:I, s:I, s:I, s:I, s:s, s:s, s:I}", "device",
        info.device_name, "driver", info.driver_name, "stages", render_stats_stages_json(stats),
        "total_ms", render_stats_total_ms(stats), "context_ms", context_ms, "width",
        (json_int_t)scene->camera.width, "height", (json_int_t)scene->camera.height, "spp",
        (json_int_t)scene->render.spp, "camera_segments", (json_int_t)stats->camera_segments,
        "bvh_nodes", (json_int_t)stats->bvh_nodes, "primitives", (json_int_t)stats->primitives,
        "output", a->out_path, "format", a->format == ENCODE_PNG ? "png" : "exr", "bytes",
        (json_int_t)bytes);
    if (timings)
        json_object_set_new(timings, "counts", render_stats_counts_json(stats));
    if (timings) {
        json_dumpf(timings, stdout, JSON_COMPACT | JSON_REAL_PRECISION(6));
        fputc('\n', stdout);
        fflush(stdout);
    }
    json_decref(timings);
}

static int render_scene(const render_args *a, const scene_doc *doc, ns_render_stats *stats)
{
    const ns_scene *scene = scene_doc_scene(doc);
    ns_error err = {0};
    ns_context *ctx = NULL;
    double t0 = ns_now_ms();
    ns_context_desc desc = {.device = a->device};
    /* Monte Carlo tables for method "table" and the albedo nodes of render.tables
     * "interpolated": cached on disk. */
    ns_table_caches_attach(&desc);
    int rc = ns_context_create(&desc, &ctx, &err);
    if (rc) {
        fprintf(stderr, "nscatter render: %s: %s\n", ns_status_name(rc), err.message);
        return 1;
    }
    double context_ms = ns_now_ms() - t0;
    float exposure = a->has_exposure ? a->exposure : scene->render.exposure;
    encode_buffer image = {0};
    rc = render_job_run(ctx, scene, a->format, exposure, stats, &image, &err);
    if (rc) {
        fprintf(stderr, "nscatter render: %s: %s\n", ns_status_name(rc), err.message);
        ns_context_destroy(ctx);
        return 1;
    }
    t0 = ns_now_ms();
    int written = write_file_atomically(a->out_path, &image);
    ns_stats_add_stage(stats, "write", ns_now_ms() - t0);
    if (written == 0 && a->timings)
        print_timings(a, ctx, scene, stats, context_ms, image.size);
    encode_buffer_free(&image);
    ns_context_destroy(ctx);
    return written == 0 ? 0 : 1;
}

int cmd_render(int argc, char **argv)
{
    render_args args;
    int done = 0;
    int rc = parse_render_args(argc, argv, &args, &done);
    if (rc || done)
        return rc;

    ns_render_stats stats;
    memset(&stats, 0, sizeof stats);
    double t0 = ns_now_ms();
    size_t length = 0;
    char *text = read_scene_file(args.scene_path, &length);
    if (!text)
        return 2;
    ns_stats_add_stage(&stats, "read", ns_now_ms() - t0);

    t0 = ns_now_ms();
    scene_doc *doc = NULL;
    scene_issues *issues = calloc(1, sizeof *issues); /* ~25 KB: keep it off the stack */
    if (!issues) {
        free(text);
        return 1;
    }
    rc = scene_parse(text, length, &(scene_parse_options){.asset_dir = args.asset_dir}, &doc,
                     issues);
    free(text);
    ns_stats_add_stage(&stats, "parse", ns_now_ms() - t0);
    if (rc) {
        if (rc == NS_ERR_INVALID_ARGUMENT)
            print_issues(args.scene_path, issues);
        else
            fprintf(stderr, "nscatter render: %s: %s\n", args.scene_path, ns_status_message(rc));
        free(issues);
        return rc == NS_ERR_INVALID_ARGUMENT ? 2 : 1;
    }
    free(issues);
    rc = render_scene(&args, doc, &stats);
    scene_doc_free(doc);
    return rc;
}
