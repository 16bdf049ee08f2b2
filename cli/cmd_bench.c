/* cmd_bench.c — `nscatter bench`: the paper's experiments (Ge et al. 2021, Tables 2-4) on the
 * built-in scenes of scenes/bench/, each method against a path-traced reference with the
 * same scattering components. References are cached outside git, keyed by a hash of the
 * reference's scene JSON and its meshes. docs/bench.md says what every number means.
 *
 * This file: arguments, scenes and meshes, the renders, the reference cache, pt's cost of
 * quality, and the Monte Carlo table provider of method "table". bench_report.c writes the
 * report and the contact sheet.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <jansson.h>

#include "args.h"
#include "bench.h"
#include "bench_mesh.h"
#include "commands.h"
#include "encode.h"
#include "image_metrics.h"
#include "mc_provider.h"
#include "nscatter.h"
#include "scene_json.h"

#ifndef NS_SOURCE_DIR
#define NS_SOURCE_DIR "."
#endif

#define BENCH_DEFAULT_BUNNY "/usr/share/glmark2/models/bunny.obj"
#define BENCH_REF_SEED 1u
#define BENCH_LADDER_SEED 1000u /* pt ladder renders: seeds apart from the reference's */
#define BENCH_NOISE_SEED 2000u  /* the short render that measures a reference's noise */
/* Progressive references stop adding chunks here even below their target: pt's noise can
 * be heavy-tailed enough (fireflies) that the estimated ceiling falls for a while as chunks
 * come in (docs/bench.md), and a target must not mean an endless run. */
#define BENCH_REF_MAX_SPP 65536u
/* ... and a target counts as reached only from this many chunks on: with a heavy tail, the
 * spread of two or three chunks says little (the bumpy sphere's full solution: 77% of its
 * two chunks' M2 in 0.1% of the pixels). */
#define BENCH_REF_MIN_CHUNKS 8u

/* ---------------------------------------------------------------------------------------
 * Arguments.
 * ------------------------------------------------------------------------------------- */
typedef struct bench_args {
    const char *scenes, *methods, *out_dir, *cache_dir, *device, *scene_dir, *bunny, *diff;
    const char *ladder, *boundary;
    uint32_t width, height, spp, ref_spp, repeat, seeds;
    double vrl_scale, mc_collisions;
    double ref_ceiling_db, ref_budget_s; /* progressive references (0: off / no budget) */
    uint32_t ref_max_spp;                /* progressive references stop there */
    int references_only;
} bench_args;

static void bench_usage(FILE *out)
{
    fprintf(out,
            "usage: nscatter bench [options]\n"
            "\n"
            "Renders the built-in scenes (scenes/bench) with nn, table, vrl (equal time) and dipole,\n"
            "compares each with a path-traced reference of the same components, and writes\n"
            "OUT/report.md (the paper's Tables 2-4) and OUT/contact_sheet.png.\n"
            "\n"
            "  --scenes A,B       scenes to run (default: all): bumpy_sphere, candle, bunny, milk,\n"
            "                     oil, cloud\n"
            "  --methods A,B      nn_surface, nn_multiple, nn_double, nn_full, table, dipole, vrl,\n"
            "                     pt (default: all)\n"
            "  --width N, --height N   image size (default: each scene's, 128x128)\n"
            "  --spp N            camera samples per pixel of the fast methods (default: scene's, 4)\n"
            "  --ref-spp N        samples per pixel of the references (default: bench.json's, 256);\n"
            "                     with --ref-ceiling, of each of their chunks\n"
            "  --ref-ceiling DB   progressive references: chunks of --ref-spp samples on new\n"
            "                     seeds, merged, until each reference's noise ceiling (from the\n"
            "                     chunks' spread) reaches DB; cached after every chunk, resumed\n"
            "                     by the next run\n"
            "  --ref-budget S     with --ref-ceiling: at most S seconds of chunks in this run,\n"
            "                     shared equally by the references still to make (the report\n"
            "                     gives the ceilings reached)\n"
            "  --ref-max-spp N    with --ref-ceiling: no chunk beyond N spp (default 65536)\n"
            "  --pt-spp A,B,..    spp of the short pt renders (default 1,4,16)\n"
            "  --repeat N         renders per method; the time is the median after the first (2)\n"
            "  --seeds N          renders every row on N seeds (the scene's and the N - 1 after it)\n"
            "                     and reports the spread of its mean / ref and PSNR (default 1)\n"
            "  --vrl-scale F      multiplies the scenes' VRL counts (default 1)\n"
            "  --mc-collisions N  Monte Carlo collisions per order and channel, method table\n"
            "                     (default: the provider's, 8e7; tables cached per machine)\n"
            "  --out DIR          where the report goes (default: bench-out)\n"
            "  --cache DIR        reference cache (default: $NSCATTER_CACHE_DIR, else\n"
            "                     ~/.cache/nscatter/bench)\n"
            "  --references       (re)render the references of the chosen scenes, report the\n"
            "                     time, and stop (with --ref-ceiling: resume their chunks)\n"
            "  --diff METHOD      method in the contact sheet's difference column (nn_full)\n"
            "  --boundary MODEL   render.boundary of the nn and table rows: walks (the\n"
            "                     default) or off (the paper's infinite-medium model)\n"
            "  --device D         Vulkan device: index or name substring (also NSCATTER_DEVICE)\n"
            "  --scene-dir DIR    folder holding bench.json and the scenes (default: the source's)\n"
            "  --bunny OBJ        the Stanford bunny (default: glmark2-data's " BENCH_DEFAULT_BUNNY ")\n"
            "\n"
            "exit status: 0 report written (methods that cannot render are listed in it),\n"
            "1 a reference, the device or the report failed, 2 bad arguments or scene files\n");
}

static int bench_bad(const char *arg, const char *value, const char *why)
{
    fprintf(stderr, "nscatter bench: %s '%s': %s\n", arg, value, why);
    return 2;
}

static int parse_u32(const char *arg, const char *text, uint32_t lo, uint32_t hi, uint32_t *out)
{
    uint64_t v = 0;
    if (cli_parse_uint("nscatter bench", arg, text, lo, hi, &v))
        return 2;
    *out = (uint32_t)v;
    return 0;
}

static int parse_real(const char *arg, const char *text, double lo, double hi, double *out)
{
    return cli_parse_number("nscatter bench", arg, text, lo, hi, out);
}

static int bench_method_by_name(const char *name, size_t len)
{
    for (int m = 0; m < BENCH_METHOD_COUNT; m++)
        if (strlen(bench_methods[m].name) == len && !strncmp(bench_methods[m].name, name, len))
            return m;
    return -1;
}

static int parse_methods(const char *list, int selected[BENCH_METHOD_COUNT])
{
    memset(selected, 0, sizeof(int) * BENCH_METHOD_COUNT);
    for (const char *p = list; *p;) {
        size_t len = strcspn(p, ",");
        int m = bench_method_by_name(p, len);
        if (m < 0) {
            fprintf(stderr,
                    "nscatter bench: --methods: unknown method '%.*s' (nn_surface, nn_multiple, "
                    "nn_double, nn_full, table, dipole, vrl, pt)\n",
                    (int)len, p);
            return 2;
        }
        selected[m] = 1;
        p += len + (p[len] == ',');
    }
    return 0;
}

static int parse_bench_args(int argc, char **argv, bench_args *a, int *done)
{
    memset(a, 0, sizeof *a);
    a->repeat = 2;
    a->seeds = 1;
    a->vrl_scale = 1.0;
    a->out_dir = "bench-out";
    a->diff = "nn_full";
    a->ladder = "1,4,16";
    for (int i = 1; i < argc; i++) {
        const char *arg = argv[i];
        const char *val = i + 1 < argc ? argv[i + 1] : NULL;
        int rc = 0;
#define TAKES(name) (!strcmp(arg, name) && val && (++i, 1))
        if (!strcmp(arg, "-h") || !strcmp(arg, "--help")) {
            bench_usage(stdout);
            *done = 1;
            return 0;
        } else if (!strcmp(arg, "--references")) {
            a->references_only = 1;
        } else if (TAKES("--scenes")) {
            a->scenes = val;
        } else if (TAKES("--methods")) {
            a->methods = val;
        } else if (TAKES("--width")) {
            rc = parse_u32(arg, val, 1, 4096, &a->width);
        } else if (TAKES("--height")) {
            rc = parse_u32(arg, val, 1, 4096, &a->height);
        } else if (TAKES("--spp")) {
            rc = parse_u32(arg, val, 1, NS_MAX_SPP, &a->spp);
        } else if (TAKES("--ref-spp")) {
            rc = parse_u32(arg, val, 1, NS_MAX_SPP, &a->ref_spp);
        } else if (TAKES("--ref-ceiling")) {
            rc = parse_real(arg, val, 1.0, 200.0, &a->ref_ceiling_db);
        } else if (TAKES("--ref-budget")) {
            rc = parse_real(arg, val, 1.0, 1e7, &a->ref_budget_s);
        } else if (TAKES("--ref-max-spp")) {
            rc = parse_u32(arg, val, 1, UINT32_MAX / 2, &a->ref_max_spp);
        } else if (TAKES("--repeat")) {
            rc = parse_u32(arg, val, 1, 50, &a->repeat);
        } else if (TAKES("--seeds")) {
            rc = parse_u32(arg, val, 1, BENCH_MAX_SEEDS, &a->seeds);
        } else if (TAKES("--vrl-scale")) {
            rc = parse_real(arg, val, 1e-4, 1e3, &a->vrl_scale);
        } else if (TAKES("--mc-collisions")) {
            rc = parse_real(arg, val, 1e4, 1e12, &a->mc_collisions);
        } else if (TAKES("--pt-spp")) {
            a->ladder = val;
        } else if (TAKES("--boundary")) {
            a->boundary = val;
            if (strcmp(val, "off") && strcmp(val, "walks"))
                return bench_bad("--boundary", val, "neither off nor walks");
        } else if (TAKES("--out")) {
            a->out_dir = val;
        } else if (TAKES("--cache")) {
            a->cache_dir = val;
        } else if (TAKES("--device")) {
            a->device = val;
        } else if (TAKES("--scene-dir")) {
            a->scene_dir = val;
        } else if (TAKES("--bunny")) {
            a->bunny = val;
        } else if (TAKES("--diff")) {
            a->diff = val;
        } else {
            fprintf(stderr, "nscatter bench: unknown option or missing value: '%s'\n\n", arg);
            bench_usage(stderr);
            return 2;
        }
#undef TAKES
        if (rc)
            return rc;
    }
    if (bench_method_by_name(a->diff, strlen(a->diff)) < 0)
        return bench_bad("--diff", a->diff, "not a method name (see --methods)");
    if ((a->ref_budget_s > 0 || a->ref_max_spp) && !(a->ref_ceiling_db > 0)) {
        fprintf(stderr, "nscatter bench: %s: only with --ref-ceiling (a reference of fixed spp "
                        "has no chunks to bound)\n", a->ref_budget_s > 0 ? "--ref-budget" : "--ref-max-spp");
        return 2;
    }
    if (!a->ref_max_spp)
        a->ref_max_spp = BENCH_REF_MAX_SPP;
    return 0;
}

/* "1,4,16" -> ladder spp values. */
static int parse_ladder(const char *text, uint32_t *spp, uint32_t *count)
{
    uint64_t v[BENCH_MAX_LADDER];
    size_t n = 0;
    if (cli_parse_uint_list("nscatter bench", "--pt-spp", text, 1, NS_MAX_SPP, v, BENCH_MAX_LADDER,
                            &n))
        return 2;
    for (size_t i = 0; i < n; i++)
        spp[i] = (uint32_t)v[i];
    *count = (uint32_t)n;
    return 0;
}

/* ---------------------------------------------------------------------------------------
 * Small file helpers.
 * ------------------------------------------------------------------------------------- */
static int mkdir_p(const char *path)
{
    char buf[4096];
    if (snprintf(buf, sizeof buf, "%s", path) >= (int)sizeof buf)
        return -1;
    for (char *p = buf + 1; *p; p++)
        if (*p == '/') {
            *p = 0;
            if (mkdir(buf, 0755) && errno != EEXIST)
                return -1;
            *p = '/';
        }
    return mkdir(buf, 0755) && errno != EEXIST ? -1 : 0;
}

static unsigned char *read_all(const char *path, size_t *size)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    unsigned char *data = NULL;
    long n = -1;
    if (!fseek(f, 0, SEEK_END) && (n = ftell(f)) >= 0 && !fseek(f, 0, SEEK_SET)) {
        data = malloc((size_t)n + 1);
        if (data && fread(data, 1, (size_t)n, f) != (size_t)n) {
            free(data);
            data = NULL;
        }
    }
    fclose(f);
    if (data) {
        data[n] = 0;
        *size = (size_t)n;
    }
    return data;
}

static uint64_t fnv1a(uint64_t h, const void *data, size_t size)
{
    const unsigned char *p = data;
    for (size_t i = 0; i < size; i++) {
        h ^= p[i];
        h *= 0x100000001b3ull;
    }
    return h;
}

/* ---------------------------------------------------------------------------------------
 * State of one bench run.
 * ------------------------------------------------------------------------------------- */
typedef struct bench {
    bench_args args;
    bench_run run;
    ns_context *ctx;
    json_t *manifest;
    char scene_dir[4096], cache_dir[4096], asset_dir[4200];
    uint32_t ladder[BENCH_MAX_LADDER], ladder_count;
    ns_mc_provider *mc; /* method "table": the server's Monte Carlo provider (mc_provider.h) */
    double ref_chunks_ms;  /* time spent on progressive chunks in this run (--ref-budget) */
    uint32_t ref_pending; /* progressive references not yet made in this run (its share) */
} bench;

/* ---------------------------------------------------------------------------------------
 * Meshes: written into CACHE/assets when missing or different.
 * ------------------------------------------------------------------------------------- */
static int write_asset(bench *b, const char *name, const bench_mesh *mesh)
{
    ns_error err = {0};
    unsigned char *glb;
    size_t size, old_size = 0;
    if (bench_mesh_to_glb(mesh, &glb, &size, &err)) {
        fprintf(stderr, "nscatter bench: %s: %s\n", name, err.message);
        return 1;
    }
    char path[4400];
    snprintf(path, sizeof path, "%.4200s/%.100s", b->asset_dir, name);
    unsigned char *old = read_all(path, &old_size);
    int same = old && old_size == size && !memcmp(old, glb, size);
    free(old);
    int rc = 0;
    /* Atomically (ns_write_file_atomic): a cache never holds half a file. */
    if (!same && ns_write_file_atomic(path, glb, size, &err)) {
        fprintf(stderr, "nscatter bench: %s\n", err.message);
        rc = 1;
    }
    free(glb);
    return rc;
}

static int prepare_generated_assets(bench *b)
{
    ns_error err = {0};
    bench_mesh m;
    int rc = 0;
    /* 5120 triangles: bumps a tenth of the radius across, and a mesh the single-scattering
     * stage's shadow rays cross quickly on lavapipe. */
    if (bench_mesh_bumpy_sphere(4, 0.08f, &m, &err) == 0) {
        rc |= write_asset(b, "bench_bumpy_sphere.glb", &m);
        bench_mesh_free(&m);
    } else {
        rc = 1;
    }
    if (bench_mesh_cylinder(64, &m, &err) == 0) {
        rc |= write_asset(b, "bench_cylinder.glb", &m);
        bench_mesh_free(&m);
    } else {
        rc = 1;
    }
    if (rc && err.message[0])
        fprintf(stderr, "nscatter bench: meshes: %s\n", err.message);
    return rc;
}

/* The bunny, converted once; a missing glmark2-data skips the scene (reason returned). */
static int prepare_bunny(bench *b, char *why, size_t why_len)
{
    const char *obj = b->args.bunny ? b->args.bunny : getenv("NSCATTER_BUNNY_OBJ");
    if (!obj || !*obj)
        obj = BENCH_DEFAULT_BUNNY;
    ns_error err = {0};
    bench_mesh m;
    if (bench_mesh_load_obj(obj, &m, &err)) {
        snprintf(why, why_len, "%.300s (the bunny comes from Debian's glmark2-data: apt-get install "
                 "glmark2-data, or give --bunny OBJ)", err.message);
        return 1;
    }
    int rc = write_asset(b, "bench_bunny.glb", &m);
    bench_mesh_free(&m);
    if (rc)
        snprintf(why, why_len, "cannot write the bunny's GLB into %.400s", b->asset_dir);
    return rc;
}

/* ---------------------------------------------------------------------------------------
 * Scenes.
 * ------------------------------------------------------------------------------------- */
static json_t *load_json(const char *path, const char *what)
{
    json_error_t e;
    json_t *j = json_load_file(path, JSON_REJECT_DUPLICATES, &e);
    if (!j)
        fprintf(stderr, "nscatter bench: %s '%s':%d:%d: %s\n", what, path, e.line, e.column, e.text);
    return j;
}

static uint32_t manifest_vrls(const bench_scene *s, const char *key, double scale)
{
    json_t *v = json_object_get(json_object_get(s->manifest, "vrls"), key);
    double n = json_is_number(v) ? json_number_value(v) : (double)NS_DEFAULT_VRLS;
    n = round(n * scale);
    return (uint32_t)fmin(fmax(n, 1.0), (double)NS_MAX_VRLS);
}

/* Reads SCENE_DIR/<file>, applies --width/--height and checks that it parses. */
static int load_scene(bench *b, json_t *entry, bench_scene *s)
{
    const char *name = json_string_value(json_object_get(entry, "name"));
    const char *file = json_string_value(json_object_get(entry, "scene"));
    const char *figure = json_string_value(json_object_get(entry, "figure"));
    const char *row = json_string_value(json_object_get(json_object_get(entry, "paper"), "row"));
    if (!name || !file || strchr(file, '/')) {
        fprintf(stderr, "nscatter bench: %s/bench.json: a scene needs \"name\" and \"scene\" (a file "
                        "name in the same folder)\n", b->scene_dir);
        return 2;
    }
    snprintf(s->name, sizeof s->name, "%s", name);
    snprintf(s->figure, sizeof s->figure, "%s", figure ? figure : "");
    snprintf(s->paper_row, sizeof s->paper_row, "%s", row ? row : "");
    s->manifest = entry;
    char path[8300];
    snprintf(path, sizeof path, "%s/%s", b->scene_dir, file);
    s->scene = load_json(path, "scene");
    if (!s->scene)
        return 2;
    json_t *camera = json_object_get(s->scene, "camera");
    if (b->args.width)
        json_object_set_new(camera, "width", json_integer(b->args.width));
    if (b->args.height)
        json_object_set_new(camera, "height", json_integer(b->args.height));
    s->width = (uint32_t)json_integer_value(json_object_get(camera, "width"));
    s->height = (uint32_t)json_integer_value(json_object_get(camera, "height"));
    json_t *ref_spp = json_object_get(b->manifest, "reference_spp");
    s->ref_spp = b->args.ref_spp ? b->args.ref_spp
                                 : json_is_integer(ref_spp) ? (uint32_t)json_integer_value(ref_spp) : 256;
    json_t *exposure = json_object_get(json_object_get(s->scene, "render"), "exposure");
    s->exposure = json_is_number(exposure) ? (float)json_number_value(exposure) : 0.0f;
    return 0;
}

/* The scene with the render settings of one run. vrls 0: the scene's own. */
static json_t *scene_for(const bench_scene *s, ns_method method, uint32_t components, uint32_t spp,
                         uint32_t seed, uint32_t vrls)
{
    json_t *copy = json_deep_copy(s->scene);
    json_t *render = json_object_get(copy, "render");
    if (!render) {
        render = json_object();
        json_object_set_new(copy, "render", render);
    }
    json_object_set_new(render, "method", json_string(ns_method_name(method)));
    json_t *list = json_array();
    for (int c = 0; c < NS_COMPONENT_COUNT; c++)
        if (components & (1u << c))
            json_array_append_new(list, json_string(ns_component_name(1u << c)));
    json_object_set_new(render, "components", list);
    if (spp)
        json_object_set_new(render, "spp", json_integer(spp));
    if (seed)
        json_object_set_new(render, "seed", json_integer(seed));
    if (vrls)
        json_object_set_new(render, "vrls", json_integer(vrls));
    return copy;
}

/* The scene as pt renders it for a reference or its noise: without the keys pt takes no
 * part of (vrls; adaptive_spp, which it ignores), so that they do not make another reference. */
static json_t *pt_scene_for(const bench_scene *s, uint32_t components, uint32_t spp, uint32_t seed)
{
    json_t *scene_json = scene_for(s, NS_METHOD_PT, components, spp, seed, 0);
    json_t *render = json_object_get(scene_json, "render");
    json_object_del(render, "vrls");
    json_object_del(render, "adaptive_spp");
    return scene_json;
}

/* ---------------------------------------------------------------------------------------
 * One render: JSON -> parse -> ns_render, timed. error gets the first problem.
 * ------------------------------------------------------------------------------------- */
static int bench_render(bench *b, const json_t *scene_json, ns_image *img, ns_render_stats *stats,
                        double *ms, char *error, size_t error_len)
{
    memset(img, 0, sizeof *img);
    memset(stats, 0, sizeof *stats);
    char *text = json_dumps(scene_json, JSON_COMPACT | JSON_SORT_KEYS);
    scene_issues *issues = calloc(1, sizeof *issues);
    if (!text || !issues) {
        free(text);
        free(issues);
        snprintf(error, error_len, "out of host memory");
        return NS_ERR_OUT_OF_HOST_MEMORY;
    }
    scene_doc *doc = NULL;
    int rc = scene_parse(text, strlen(text), &(scene_parse_options){.asset_dir = b->asset_dir}, &doc,
                         issues);
    free(text);
    if (rc) {
        if (issues->count)
            snprintf(error, error_len, "%.120s: %.360s%s", issues->items[0].pointer, issues->items[0].detail,
                     issues->total > 1 ? " (and more)" : "");
        else
            snprintf(error, error_len, "%s", ns_status_message(rc));
        free(issues);
        return rc;
    }
    free(issues);
    ns_error err = {0};
    double t0 = ns_now_ms();
    rc = ns_render(b->ctx, scene_doc_scene(doc), img, stats, &err);
    *ms = ns_now_ms() - t0;
    scene_doc_free(doc);
    if (rc) {
        snprintf(error, error_len, "%.40s: %.440s", ns_status_name(rc), err.message);
        ns_image_free(img);
    }
    return rc;
}

static double stage_ms(const ns_render_stats *st, const char *name)
{
    double ms = 0;
    for (uint32_t i = 0; i < st->stage_count; i++)
        if (!strcmp(st->stages[i].name, name))
            ms += st->stages[i].ms;
    return ms;
}

/* The camera pass: the camera's paths and the samples render.adaptive_spp adds. */
static double camera_pass_ms(const ns_render_stats *st)
{
    return stage_ms(st, "ray_pass") + stage_ms(st, "adaptive");
}

static int compare_doubles(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The median of n >= 1 values sorted in ascending order. */
static double median_of_sorted(const double *v, uint32_t n)
{
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/* ---------------------------------------------------------------------------------------
 * References: pt with the components of the methods compared with them.
 * ------------------------------------------------------------------------------------- */
static uint64_t reference_key(bench *b, const json_t *scene_json)
{
    char *text = json_dumps(scene_json, JSON_COMPACT | JSON_SORT_KEYS);
    uint64_t h = fnv1a(0xcbf29ce484222325ull, text ? text : "", text ? strlen(text) : 0);
    free(text);
    /* A reference made by another pt (another expected image) is another reference. */
    const uint32_t estimator = NS_PT_ESTIMATOR_VERSION;
    h = fnv1a(h, &estimator, sizeof estimator);
    /* Meshes are named, not inlined: their bytes are part of the key. */
    size_t i;
    json_t *o;
    json_array_foreach(json_object_get(scene_json, "objects"), i, o)
    {
        const char *asset = json_string_value(json_object_get(o, "asset"));
        if (!asset)
            continue;
        char path[4500];
        size_t size = 0;
        snprintf(path, sizeof path, "%s/%s", b->asset_dir, asset);
        unsigned char *data = read_all(path, &size);
        if (data)
            h = fnv1a(h, data, size);
        free(data);
    }
    return h;
}

static int write_reference_meta(const char *path, const bench_reference *r, const char *scene,
                                uint32_t components);

static int write_reference(const char *path, const ns_image *img, const bench_reference *r,
                           const char *scene, uint32_t components)
{
    encode_buffer exr = {0};
    ns_error err = {0};
    if (encode_exr(img, 0, NULL, 0, &exr, &err))
        return -1;
    int rc = ns_write_file_atomic(path, exr.data, exr.size, NULL);
    encode_buffer_free(&exr);
    if (rc)
        return -1;
    return write_reference_meta(path, r, scene, components);
}

static int write_reference_meta(const char *path, const bench_reference *r, const char *scene,
                                uint32_t components)
{
    char meta_path[4200];
    snprintf(meta_path, sizeof meta_path, "%.4190s.json", path);
    json_t *meta = json_pack("{s:s, s:s, s:I, s:I, s:f, s:s, s:f}", "scene", scene, "components",
                             bench_components_name(components), "spp", (json_int_t)r->spp, "seed",
                             (json_int_t)BENCH_REF_SEED, "ms", r->ms, "device", r->device, "variance",
                             r->variance);
    char *text = meta ? json_dumps(meta, JSON_INDENT(1)) : NULL;
    json_decref(meta);
    int rc = text ? ns_write_file_atomic(meta_path, text, strlen(text), NULL) : -1;
    free(text);
    return rc;
}

static void read_reference_meta(const char *path, bench_reference *r)
{
    char meta_path[4200];
    snprintf(meta_path, sizeof meta_path, "%.4190s.json", path);
    json_t *meta = json_load_file(meta_path, 0, NULL);
    json_t *ms = json_object_get(meta, "ms");
    r->ms = json_is_number(ms) ? json_number_value(ms) : NAN;
    const char *dev = json_string_value(json_object_get(meta, "device"));
    snprintf(r->device, sizeof r->device, "%s", dev ? dev : "?");
    json_t *variance = json_object_get(meta, "variance");
    r->variance = json_is_number(variance) ? json_number_value(variance) : 0.0;
    json_decref(meta);
}

/* Renders scene_json (and releases it) and compares the image with `against` (the
 * reference: image_compare's b). 0, or bench_render's failure with error set. */
static int render_compared(bench *b, json_t *scene_json, const ns_image *against, image_metrics *m,
                           char *error, size_t error_len)
{
    ns_image img;
    ns_render_stats stats;
    double ms;
    int rc = bench_render(b, scene_json, &img, &stats, &ms, error, error_len);
    json_decref(scene_json);
    if (rc)
        return rc;
    image_compare(&img, against, NULL, m);
    ns_image_free(&img);
    return 0;
}

/* The reference's noise: one short pt render of the same components on another seed;
 * their MSE is variance (1/BENCH_NOISE_SPP + 1/spp). Kept in the reference's .json. */
static void measure_reference_noise(bench *b, bench_scene *s, bench_reference *r, uint32_t components)
{
    if (!(r->variance > 0)) {
        json_t *scene_json = pt_scene_for(s, components, BENCH_NOISE_SPP, BENCH_NOISE_SEED);
        char error[512];
        image_metrics m;
        if (render_compared(b, scene_json, &r->image, &m, error, sizeof error)) {
            fprintf(stderr, "nscatter bench: %s reference (%s): its noise: %s\n", s->name,
                    bench_components_name(components), error);
            return;
        }
        r->variance = m.rmse[3] * m.rmse[3] / (1.0 / BENCH_NOISE_SPP + 1.0 / r->spp);
        if (write_reference_meta(r->path, r, s->name, components))
            fprintf(stderr, "nscatter bench: cannot update '%s.json': %s\n", r->path, strerror(errno));
    }
    image_metrics self;
    image_compare(&r->image, &r->image, NULL, &self);
    r->noise_mse = r->variance / r->spp;
    r->ceiling_db = r->noise_mse > 0 && self.peak > 0 ? 20.0 * log10(self.peak / sqrt(r->noise_mse)) : NAN;
    fprintf(stderr, "bench: %s reference (%s): noise ceiling %.1f dB\n", s->name, bench_components_name(components),
            r->ceiling_db);
}

/* ---------------------------------------------------------------------------------------
 * Progressive references (--ref-ceiling): chunks of --ref-spp samples, chunk k on seed
 * BENCH_REF_SEED + k, merged into their mean until the reference's noise ceiling reaches the
 * target. The noise comes from the chunks' own spread: per pixel and channel, Welford's
 * running mean and M2 (the sum of squared deviations from it), so the mean's variance is
 * M2 / (K (K - 1)) after K chunks, with no extra render and no assumption about how pt's
 * noise falls with spp. Every chunk is a checkpoint: the mean and M2 are written under
 * names that hold K, then the .json that names K, and only then is the previous pair
 * removed, so an interrupted run leaves a consistent reference that the next run resumes.
 * ------------------------------------------------------------------------------------- */
typedef struct progressive_state {
    char base[4096]; /* the path without its suffix: BASE.json, BASE-kK.exr, BASE-kK.m2.exr */
    uint32_t chunks;
    double ms;
    ns_image mean, m2;
    /* The ceiling after each chunk (index k - 1), NaN where unknown (a checkpoint written
     * before they were kept, or below 2 chunks); room for `capacity`. */
    double *ceilings;
    uint32_t capacity;
} progressive_state;

/* Records the ceiling after chunk `chunks`; -1 out of memory. */
static int progressive_record(progressive_state *p, uint32_t chunks, double ceiling_db)
{
    if (chunks > p->capacity) {
        uint32_t capacity = chunks > 2 * p->capacity ? chunks : 2 * p->capacity;
        double *grown = realloc(p->ceilings, capacity * sizeof *grown);
        if (!grown)
            return -1;
        for (uint32_t i = p->capacity; i < capacity; i++)
            grown[i] = NAN;
        p->ceilings = grown;
        p->capacity = capacity;
    }
    p->ceilings[chunks - 1] = ceiling_db;
    return 0;
}

/* The ceiling's rise over the last doubling of the chunks (from chunks / 2 to chunks), and in
 * *expected what a finite variance gives; NaN below BENCH_REF_TAIL_CHUNKS or where either
 * ceiling is unknown. */
static double progressive_rise(const progressive_state *p, double *expected)
{
    uint32_t k = p->chunks, half = k / 2;
    *expected = half ? 10.0 * log10((double)k / half) : NAN;
    if (k < BENCH_REF_TAIL_CHUNKS || k > p->capacity)
        return NAN;
    double now = p->ceilings[k - 1], then = p->ceilings[half - 1];
    return isfinite(now) && isfinite(then) ? now - then : NAN;
}

static void progressive_path(const progressive_state *p, uint32_t chunks, const char *suffix, char *out,
                             size_t size)
{
    snprintf(out, size, "%.4000s-k%u%s", p->base, chunks, suffix);
}

/* The variance of the mean image (the mean over pixels and channels), NaN below 2 chunks. */
static double progressive_noise_mse(const progressive_state *p)
{
    if (p->chunks < 2)
        return NAN;
    size_t n = (size_t)p->m2.width * p->m2.height * 3;
    double sum = 0.0;
    for (size_t i = 0; i < n; i++)
        sum += p->m2.rgb[i];
    return sum / (double)n / ((double)p->chunks * (p->chunks - 1));
}

static void progressive_measure(const progressive_state *p, bench_reference *r)
{
    image_metrics self;
    image_compare(&p->mean, &p->mean, NULL, &self);
    r->noise_mse = progressive_noise_mse(p);
    r->spp = p->chunks * r->chunk_spp;
    r->variance = r->noise_mse * r->spp; /* per sample, as the fixed-spp references keep it */
    r->ceiling_db = r->noise_mse > 0 && self.peak > 0 ? 20.0 * log10(self.peak / sqrt(r->noise_mse)) : NAN;
}

/* Reads the checkpoint named by BASE.json; 0 chunks when there is none or it does not fit. */
static void progressive_load(progressive_state *p, const bench_scene *s, bench_reference *r)
{
    char meta_path[4200];
    snprintf(meta_path, sizeof meta_path, "%.4000s.json", p->base);
    json_t *meta = json_load_file(meta_path, 0, NULL);
    json_t *chunks = json_object_get(meta, "chunks"), *ms = json_object_get(meta, "ms");
    json_t *chunk_spp = json_object_get(meta, "chunk_spp");
    const char *dev = json_string_value(json_object_get(meta, "device"));
    p->chunks = 0;
    if (json_is_integer(chunks) && json_integer_value(chunks) >= 1 && json_is_integer(chunk_spp) &&
        json_integer_value(chunk_spp) == r->chunk_spp) {
        uint32_t k = (uint32_t)json_integer_value(chunks);
        char mean_path[4200], m2_path[4200];
        progressive_path(p, k, ".exr", mean_path, sizeof mean_path);
        progressive_path(p, k, ".m2.exr", m2_path, sizeof m2_path);
        ns_error err = {0};
        if (image_load(mean_path, &p->mean, &err) == 0 && image_load(m2_path, &p->m2, &err) == 0 &&
            p->mean.width == s->width && p->mean.height == s->height && p->m2.width == s->width &&
            p->m2.height == s->height) {
            p->chunks = k;
            /* The ceilings' history, as far as it was kept and is numbers. */
            json_t *ceilings = json_object_get(meta, "ceilings");
            for (uint32_t i = 0; i < k && i < json_array_size(ceilings); i++) {
                json_t *v = json_array_get(ceilings, i);
                if (json_is_number(v) && isfinite(json_number_value(v)) &&
                    progressive_record(p, i + 1, json_number_value(v)))
                    break;
            }
            /* Not a finite number (an edited file): 0, as json_pack refuses NaN and every
             * later checkpoint would fail to write. */
            p->ms = json_is_number(ms) && isfinite(json_number_value(ms)) ? json_number_value(ms) : 0.0;
            snprintf(r->device, sizeof r->device, "%s", dev ? dev : "?");
        } else {
            fprintf(stderr, "bench: %s: checkpoint of %u chunks unreadable (%s); starting again\n",
                    p->base, k, err.message);
            ns_image_free(&p->mean);
            ns_image_free(&p->m2);
        }
    }
    json_decref(meta);
}

static int progressive_save(const progressive_state *p, const bench_scene *s, const bench_reference *r,
                            uint32_t components)
{
    char mean_path[4200], m2_path[4200], meta_path[4200];
    progressive_path(p, p->chunks, ".exr", mean_path, sizeof mean_path);
    progressive_path(p, p->chunks, ".m2.exr", m2_path, sizeof m2_path);
    snprintf(meta_path, sizeof meta_path, "%.4000s.json", p->base);
    const ns_image *images[2] = {&p->mean, &p->m2};
    const char *paths[2] = {mean_path, m2_path};
    for (int i = 0; i < 2; i++) {
        encode_buffer exr = {0};
        ns_error err = {0};
        int rc = encode_exr(images[i], 0, NULL, 0, &exr, &err) ||
                 ns_write_file_atomic(paths[i], exr.data, exr.size, &err);
        encode_buffer_free(&exr);
        if (rc) {
            fprintf(stderr, "nscatter bench: cannot write '%s': %s\n", paths[i], err.message);
            return -1;
        }
    }
    json_t *meta = json_pack("{s:s, s:s, s:I, s:I, s:I, s:I, s:f, s:s, s:f, s:f, s:f}", "scene", s->name,
                             "components", bench_components_name(components), "chunk_spp",
                             (json_int_t)r->chunk_spp, "chunks", (json_int_t)p->chunks, "spp",
                             (json_int_t)r->spp, "first_seed", (json_int_t)BENCH_REF_SEED, "ms", p->ms,
                             "device", r->device, "noise_mse", isfinite(r->noise_mse) ? r->noise_mse : 0.0,
                             "ceiling_db", isfinite(r->ceiling_db) ? r->ceiling_db : 0.0, "variance",
                             isfinite(r->variance) ? r->variance : 0.0);
    json_t *ceilings = json_array();
    for (uint32_t i = 0; i < p->chunks; i++)
        json_array_append_new(ceilings, i < p->capacity && isfinite(p->ceilings[i])
                                            ? json_real(p->ceilings[i])
                                            : json_null());
    json_object_set_new(meta, "ceilings", ceilings);
    char *text = meta ? json_dumps(meta, JSON_INDENT(1)) : NULL;
    json_decref(meta);
    int rc = text ? ns_write_file_atomic(meta_path, text, strlen(text), NULL) : -1;
    free(text);
    if (rc) {
        fprintf(stderr, "nscatter bench: cannot write '%s'\n", meta_path);
        return -1;
    }
    if (p->chunks > 1) { /* the .json names the new pair now: the old one can go */
        char old[4200];
        progressive_path(p, p->chunks - 1, ".exr", old, sizeof old);
        remove(old);
        progressive_path(p, p->chunks - 1, ".m2.exr", old, sizeof old);
        remove(old);
    }
    return 0;
}

/* Welford: the chunk x joins the mean and M2 of the chunks before it. */
static int progressive_add(progressive_state *p, const ns_image *x)
{
    size_t n = (size_t)x->width * x->height * 3;
    if (!p->chunks) {
        p->mean = (ns_image){.width = x->width, .height = x->height, .rgb = malloc(n * sizeof(float))};
        p->m2 = (ns_image){.width = x->width, .height = x->height, .rgb = calloc(n, sizeof(float))};
        if (!p->mean.rgb || !p->m2.rgb)
            return -1;
        memcpy(p->mean.rgb, x->rgb, n * sizeof(float));
        p->chunks = 1;
        return 0;
    }
    double k = (double)p->chunks + 1.0;
    for (size_t i = 0; i < n; i++) {
        double value = x->rgb[i], mean = p->mean.rgb[i];
        double delta = value - mean, next = mean + delta / k;
        p->mean.rgb[i] = (float)next;
        p->m2.rgb[i] = (float)(p->m2.rgb[i] + delta * (value - next));
    }
    p->chunks++;
    return 0;
}

/* --references does not start these again: a progressive reference is hours of chunks, and a
 * references-only run is how they are made; its checkpoint is resumed. */
static int ensure_progressive_reference(bench *b, bench_scene *s, int set)
{
    bench_reference *r = &s->refs[set];
    uint32_t components = bench_ref_components[set];
    const char *set_name = bench_components_name(components);
    json_t *scene_json = pt_scene_for(s, components, s->ref_spp, BENCH_REF_SEED);
    uint64_t key = reference_key(b, scene_json);
    progressive_state p = {0};
    snprintf(p.base, sizeof p.base, "%.3900s/%.63s-%s-%ux%u-%uspp-progressive-%016llx", b->cache_dir, s->name,
             set_name, s->width, s->height, s->ref_spp, (unsigned long long)key);
    for (char *c = strrchr(p.base, '/'); c && *c; c++)
        if (*c == '+')
            *c = '_';
    r->chunk_spp = s->ref_spp;
    r->noise_mse = r->ceiling_db = r->variance = NAN;
    r->ceiling_rise_db = r->ceiling_rise_expected_db = NAN;
    progressive_load(&p, s, r);
    if (p.chunks)
        progressive_measure(&p, r);
    if (p.chunks && isfinite(r->ceiling_db))
        progressive_record(&p, p.chunks, r->ceiling_db); /* out of memory: the rise is unknown */
    /* This reference's share of what is left of the budget: a hard scene does not take the
     * time of the ones after it. */
    double target = b->args.ref_ceiling_db, budget_ms = b->args.ref_budget_s * 1000.0;
    double share_ms = budget_ms > 0 ? (budget_ms - b->ref_chunks_ms) / (b->ref_pending ? b->ref_pending : 1) : 0;
    double spent_ms = 0.0;
    uint32_t before = p.chunks;
    int failed = 0;
    if (b->ref_pending)
        b->ref_pending--;
    while (!(p.chunks >= BENCH_REF_MIN_CHUNKS && r->ceiling_db >= target)) {
        if (budget_ms > 0 && spent_ms >= share_ms) {
            fprintf(stderr, "bench: %s reference (%s): its share of --ref-budget spent at %u chunks, "
                            "ceiling %.1f dB\n", s->name, set_name, p.chunks, r->ceiling_db);
            break;
        }
        if ((uint64_t)(p.chunks + 1) * r->chunk_spp > b->args.ref_max_spp) {
            fprintf(stderr, "bench: %s reference (%s): --ref-max-spp %u reached at %u chunks, "
                            "ceiling %.1f dB\n", s->name, set_name, b->args.ref_max_spp, p.chunks,
                    r->ceiling_db);
            break;
        }
        uint32_t seed = BENCH_REF_SEED + p.chunks;
        json_object_set_new(json_object_get(scene_json, "render"), "seed", json_integer(seed));
        ns_image chunk;
        ns_render_stats stats;
        double ms;
        if (bench_render(b, scene_json, &chunk, &stats, &ms, r->error, sizeof r->error)) {
            fprintf(stderr, "nscatter bench: %s reference (%s), chunk %u: %s\n", s->name, set_name,
                    p.chunks + 1, r->error);
            failed = 1;
            break;
        }
        b->ref_chunks_ms += ms;
        spent_ms += ms;
        p.ms = (p.chunks ? p.ms : 0.0) + ms;
        int added = progressive_add(&p, &chunk);
        ns_image_free(&chunk);
        if (added) {
            snprintf(r->error, sizeof r->error, "out of host memory");
            failed = 1;
            break;
        }
        snprintf(r->device, sizeof r->device, "%s", b->run.device);
        progressive_measure(&p, r);
        if (isfinite(r->ceiling_db) && progressive_record(&p, p.chunks, r->ceiling_db)) {
            snprintf(r->error, sizeof r->error, "out of host memory");
            failed = 1;
            break;
        }
        if (progressive_save(&p, s, r, components)) {
            snprintf(r->error, sizeof r->error, "cannot write the checkpoint under %.400s", b->cache_dir);
            failed = 1;
            break;
        }
        fprintf(stderr, "bench: %s reference (%s): chunk %u, %u spp, noise ceiling %.1f dB (target %.1f), %.1f s\n",
                s->name, set_name, p.chunks, r->spp, r->ceiling_db, target, ms / 1000.0);
    }
    json_decref(scene_json);
    ns_image_free(&p.m2);
    r->ceiling_rise_db = progressive_rise(&p, &r->ceiling_rise_expected_db);
    free(p.ceilings);
    if (failed || !p.chunks) {
        ns_image_free(&p.mean);
        if (!failed)
            snprintf(r->error, sizeof r->error, "no chunk rendered within --ref-budget or --ref-max-spp");
        return 1;
    }
    r->image = p.mean;
    r->ms = p.ms;
    r->ok = 1;
    r->generated = p.chunks > before;
    progressive_path(&p, p.chunks, ".exr", r->path, sizeof r->path);
    fprintf(stderr, "bench: %s reference (%s): %u chunks of %u spp, noise ceiling %.1f dB%s\n", s->name, set_name,
            p.chunks, r->chunk_spp, r->ceiling_db, r->generated ? "" : " (cached)");
    if (r->ceiling_rise_db < 0.5 * r->ceiling_rise_expected_db)
        fprintf(stderr,
                "bench: %s reference (%s): its noise ceiling rose %.1f dB from %u to %u chunks, "
                "where a finite variance gives %.1f dB: pt's noise there may have a heavy tail, "
                "and more chunks may not reach a higher target\n",
                s->name, set_name, r->ceiling_rise_db, p.chunks / 2, p.chunks,
                r->ceiling_rise_expected_db);
    return 0;
}

static int ensure_reference(bench *b, bench_scene *s, int set, int force)
{
    if (b->args.ref_ceiling_db > 0)
        return ensure_progressive_reference(b, s, set);
    bench_reference *r = &s->refs[set];
    uint32_t components = bench_ref_components[set];
    json_t *scene_json = pt_scene_for(s, components, s->ref_spp, BENCH_REF_SEED);
    uint64_t key = reference_key(b, scene_json);
    char name[sizeof s->name];
    memcpy(name, s->name, sizeof name);
    snprintf(r->path, sizeof r->path, "%.3900s/%.63s-%s-%ux%u-%uspp-%016llx.exr", b->cache_dir, name,
             bench_components_name(components), s->width, s->height, s->ref_spp, (unsigned long long)key);
    for (char *p = strrchr(r->path, '/'); p && *p; p++)
        if (*p == '+')
            *p = '_';
    r->spp = s->ref_spp;
    ns_error err = {0};
    if (!force && access(r->path, R_OK) == 0 && image_load(r->path, &r->image, &err) == 0 &&
        r->image.width == s->width && r->image.height == s->height) {
        read_reference_meta(r->path, r);
        r->ok = 1;
        json_decref(scene_json);
        fprintf(stderr, "bench: %s reference (%s): cached %s\n", s->name, bench_components_name(components),
                r->path);
        measure_reference_noise(b, s, r, components);
        return 0;
    }
    ns_image_free(&r->image);
    fprintf(stderr, "bench: %s reference (%s): pt %u spp at %ux%u...\n", s->name,
            bench_components_name(components), s->ref_spp, s->width, s->height);
    ns_render_stats stats;
    int rc = bench_render(b, scene_json, &r->image, &stats, &r->ms, r->error, sizeof r->error);
    json_decref(scene_json);
    if (rc) {
        fprintf(stderr, "nscatter bench: %s reference (%s): %s\n", s->name,
                bench_components_name(components), r->error);
        return 1;
    }
    snprintf(r->device, sizeof r->device, "%s", b->run.device);
    r->ok = r->generated = 1;
    if (write_reference(r->path, &r->image, r, s->name, components))
        fprintf(stderr, "nscatter bench: cannot cache the reference '%s': %s\n", r->path, strerror(errno));
    fprintf(stderr, "bench: %s reference (%s): %.1f s, %s\n", s->name, bench_components_name(components),
            r->ms / 1000.0, r->path);
    measure_reference_noise(b, s, r, components);
    return 0;
}

/* ---------------------------------------------------------------------------------------
 * Methods.
 * ------------------------------------------------------------------------------------- */
static uint32_t scene_spp(const bench *b, const bench_scene *s)
{
    if (b->args.spp)
        return b->args.spp;
    json_t *spp = json_object_get(json_object_get(s->scene, "render"), "spp");
    return json_is_integer(spp) ? (uint32_t)json_integer_value(spp) : 1;
}

/* Method m's scene: its components, spp, seed (0: the scene's), render.vrls (0: the
 * scene's) and --boundary for the methods that gather through tables. nn's tables are the
 * exact ones unless the scene file asks otherwise: with the parser's default, "auto", a
 * scene would blend wherever the cache folder happens to hold its g's albedo nodes, and the
 * bench would measure what the machine did before. */
static json_t *method_scene(const bench *b, const bench_scene *s, int m, uint32_t spp, uint32_t seed,
                            uint32_t vrls)
{
    const bench_method_info *info = &bench_methods[m];
    json_t *scene_json = scene_for(s, info->method, info->components, spp, seed, vrls);
    json_t *render = json_object_get(scene_json, "render");
    if (b->args.boundary && ns_method_uses_tables(info->method))
        json_object_set_new(render, "boundary", json_string(b->args.boundary));
    if (info->method == NS_METHOD_NN && !json_object_get(render, "tables"))
        json_object_set_new(render, "tables", json_string("exact"));
    return scene_json;
}

/* Renders method m `repeat` times at `vrls`; the result keeps the last image. */
static void run_method_at(bench *b, bench_scene *s, int m, uint32_t vrls, uint32_t repeat)
{
    const bench_method_info *info = &bench_methods[m];
    bench_result *r = &s->results[m];
    ns_image_free(&r->image);
    memset(r, 0, sizeof *r);
    r->ran = 1;
    r->vrls = info->vrls_key ? vrls : 0;
    r->spp = scene_spp(b, s);
    json_t *scene_json = method_scene(b, s, m, r->spp, 0, r->vrls);
    double times[64];
    uint32_t n = 0;
    for (uint32_t i = 0; i < repeat && i < 64; i++) {
        ns_image img;
        ns_render_stats stats;
        double ms;
        if (bench_render(b, scene_json, &img, &stats, &ms, r->error, sizeof r->error)) {
            r->ok = 0;
            ns_image_free(&r->image);
            json_decref(scene_json);
            return;
        }
        if (i == 0) {
            r->cold_ms = ms;
            r->cold_stats = stats;
        }
        times[n++] = ms;
        r->stats = stats;
        ns_image_free(&r->image);
        r->image = img;
    }
    json_decref(scene_json);
    /* The first render pays for table reconstruction; the warm ones are the frame time. */
    double *warm = n > 1 ? times + 1 : times;
    uint32_t warm_n = n > 1 ? n - 1 : n;
    qsort(warm, warm_n, sizeof *warm, compare_doubles);
    r->ms = median_of_sorted(warm, warm_n);
    /* Where the warm renders kept the first one's camera pass (render/camera_keep.c), their
     * time is a frame of the same view, and a new view adds that pass as the first render
     * timed it, and its single scattering where that was kept with it. A first render that
     * itself took a pass kept by the method before (the same camera and geometry) never
     * timed one: unknown. */
    if (r->cold_stats.camera_reused)
        r->camera_ms = NAN;
    else if (n > 1 && r->stats.camera_reused)
        r->camera_ms = camera_pass_ms(&r->cold_stats) +
                       (r->stats.single_reused ? stage_ms(&r->cold_stats, "single") : 0.0);
    else
        r->camera_ms = 0.0;
    r->ok = 1;
}

static void compare_with_reference(bench_scene *s, int m)
{
    bench_result *r = &s->results[m];
    int set = bench_ref_index(bench_methods[m].components);
    if (!r->ok || set < 0 || !s->refs[set].ok)
        return;
    const bench_reference *ref = &s->refs[set];
    image_compare(&r->image, &ref->image, NULL, &r->metrics);
    /* What is left of the MSE once the reference's own noise is taken out; within 10% of
     * the measured MSE it cannot be told from 0. */
    double mse = r->metrics.rmse[3] * r->metrics.rmse[3], rest = mse - ref->noise_mse;
    r->psnr_denoised = ref->noise_mse > 0 && rest > 0.1 * mse ? 20.0 * log10(r->metrics.peak / sqrt(rest)) : NAN;
}

/* --seeds N: the row's render again on the N - 1 seeds after the scene's, each compared with
 * the reference: how far one seed's mean / ref and PSNR can be from another's (light paths
 * and camera samples both change). The row itself keeps its first seed's image and time. */
static uint32_t scene_seed(const bench_scene *s)
{
    json_t *seed = json_object_get(json_object_get(s->scene, "render"), "seed");
    return json_is_integer(seed) ? (uint32_t)json_integer_value(seed) : 1u;
}

/* The k-th seed after `first`, wrapping past UINT32_MAX but never to 0: scene_for reads a
 * seed of 0 as "the scene's own", which would render the first seed again. */
static uint32_t seed_after(uint32_t first, uint32_t k)
{
    uint32_t seed = first + k;
    return seed < first ? seed + 1 : seed;
}

static void run_seeds(bench *b, bench_scene *s, int m)
{
    bench_result *r = &s->results[m];
    int set = bench_ref_index(bench_methods[m].components);
    uint32_t n = b->args.seeds;
    if (n < 2 || !r->ok || !(r->metrics.pixels > 0) || set < 0 || !s->refs[set].ok)
        return;
    double ratio[BENCH_MAX_SEEDS][3], psnr[BENCH_MAX_SEEDS],
        mse_sum = r->metrics.rmse[3] * r->metrics.rmse[3];
    for (int c = 0; c < 3; c++)
        ratio[0][c] = r->metrics.mean_ratio[c];
    psnr[0] = r->metrics.psnr[3];
    uint32_t done = 1, first = scene_seed(s);
    for (uint32_t k = 1; k < n; k++) {
        uint32_t seed = seed_after(first, k);
        json_t *scene_json = method_scene(b, s, m, r->spp, seed, r->vrls);
        char error[512];
        image_metrics metrics;
        if (render_compared(b, scene_json, &s->refs[set].image, &metrics, error, sizeof error)) {
            fprintf(stderr, "bench: %s %s seed %u: %s\n", s->name, bench_methods[m].name, seed, error);
            continue;
        }
        if (!isfinite(metrics.rmse[3])) { /* nothing finite compared: no error to average */
            fprintf(stderr, "bench: %s %s seed %u: no finite pixel to compare\n", s->name,
                    bench_methods[m].name, seed);
            continue;
        }
        for (int c = 0; c < 3; c++)
            ratio[done][c] = metrics.mean_ratio[c];
        mse_sum += metrics.rmse[3] * metrics.rmse[3];
        psnr[done++] = metrics.psnr[3];
    }
    r->seeds = done;
    r->seed_mse_mean = mse_sum / done;
    for (int c = 0; c < 3; c++) {
        double sum = 0, sq = 0;
        for (uint32_t k = 0; k < done; k++)
            sum += ratio[k][c];
        r->seed_ratio_mean[c] = sum / done;
        for (uint32_t k = 0; k < done; k++)
            sq += (ratio[k][c] - r->seed_ratio_mean[c]) * (ratio[k][c] - r->seed_ratio_mean[c]);
        r->seed_ratio_sd[c] = done > 1 ? sqrt(sq / (done - 1)) : NAN;
    }
    qsort(psnr, done, sizeof *psnr, compare_doubles);
    r->seed_psnr_min = psnr[0];
    r->seed_psnr_max = psnr[done - 1];
    r->seed_psnr_median = median_of_sorted(psnr, done);
}

/* vrl at equal time: its cost grows linearly with render.vrls above a fixed part (the stages
 * that do not depend on it), so two renders find the count whose time matches nn full's. */
static void run_vrl_equal_time(bench *b, bench_scene *s)
{
    const bench_result *nn = &s->results[BENCH_NN_FULL];
    uint32_t vrls = manifest_vrls(s, "full", b->args.vrl_scale);
    if (!nn->ok) {
        run_method_at(b, s, BENCH_VRL, vrls, b->run.repeat);
        return; /* nothing to match: rendered at the scene's count, ratio left 0 */
    }
    double target = nn->ms;
    /* The first probe is cheap (a twentieth of nn's count): brute-force VRLs cost far more
     * each than nn's, and the probe only measures the cost per VRL. */
    vrls = vrls / 20 > 500 ? vrls / 20 : (vrls < 500 ? vrls : 500);
    /* vrl keeps no tables between renders, so a single render measures a probe's time; the
     * count that lands within 20% is rendered again with --repeat. */
    for (int attempt = 0; attempt < 4; attempt++) {
        run_method_at(b, s, BENCH_VRL, vrls, attempt == 3 ? b->run.repeat : 1);
        bench_result *r = &s->results[BENCH_VRL];
        if (!r->ok)
            return;
        r->equal_time_ratio = r->ms / target;
        if (fabs(r->equal_time_ratio - 1.0) < 0.2 || attempt == 3) {
            if (attempt < 3 && b->run.repeat > 1) {
                run_method_at(b, s, BENCH_VRL, vrls, b->run.repeat);
                r->equal_time_ratio = r->ms / target;
            }
            return;
        }
        double variable = stage_ms(&r->stats, "vrl") + stage_ms(&r->stats, "grid") +
                          stage_ms(&r->stats, "gather");
        double fixed = r->ms - variable;
        double per_vrl = variable / vrls;
        if (!(per_vrl > 0) || target <= fixed) {
            if (target <= fixed && vrls > 1) {
                vrls = vrls / 10 > 0 ? vrls / 10 : 1; /* fixed part alone exceeds the target */
                continue;
            }
            return;
        }
        double next = (target - fixed) / per_vrl;
        vrls = (uint32_t)fmin(fmax(round(next), 1.0), (double)NS_MAX_VRLS);
    }
}

/* pt at a few spp, seeds apart from the reference, and the cost-of-quality estimate. */
static void run_pt_ladder(bench *b, bench_scene *s)
{
    bench_result *res = &s->results[BENCH_PT];
    memset(res, 0, sizeof *res);
    res->ran = 1;
    const bench_reference *ref = &s->refs[bench_ref_index(BENCH_ALL)];
    s->ladder_count = 0;
    for (uint32_t i = 0; i < b->ladder_count; i++) {
        bench_pt_point *p = &s->ladder[s->ladder_count++];
        memset(p, 0, sizeof *p);
        p->spp = b->ladder[i];
        json_t *scene_json = pt_scene_for(s, BENCH_ALL, p->spp, BENCH_LADDER_SEED + i);
        ns_image img;
        ns_render_stats stats;
        int rc = bench_render(b, scene_json, &img, &stats, &p->ms, res->error, sizeof res->error);
        json_decref(scene_json);
        if (rc)
            return;
        p->pass_ms = stage_ms(&stats, "pt_pass");
        if (ref->ok) {
            image_metrics m;
            image_compare(&img, &ref->image, NULL, &m);
            p->mse = m.rmse[3] * m.rmse[3];
            p->psnr = m.psnr[3];
            res->metrics = m;
        }
        p->ok = 1;
        ns_image_free(&res->image);
        res->image = img; /* the contact sheet shows the longest */
        res->ms = p->ms;
        res->spp = p->spp;
        res->stats = stats;
        res->ok = 1;
    }
    /* variance: least squares through the origin of MSE against 1/spp + 1/ref_spp;
     * time per spp: least squares of pt_pass against spp through the origin. */
    double sxy = 0, sxx = 0, tsy = 0, tss = 0;
    for (uint32_t i = 0; ref->ok && i < s->ladder_count; i++) {
        const bench_pt_point *p = &s->ladder[i];
        double x = 1.0 / p->spp + 1.0 / ref->spp; /* a reference that is ok has spp >= 1 */
        sxy += x * p->mse, sxx += x * x;
        tsy += p->spp * p->pass_ms, tss += (double)p->spp * p->spp;
    }
    bench_pt_estimate *e = &s->pt;
    memset(e, 0, sizeof *e);
    const bench_result *nn = &s->results[BENCH_NN_FULL];
    if (!ref->ok || !res->ok || sxx <= 0 || tss <= 0)
        return;
    e->variance = sxy / sxx;
    e->pass_ms_per_spp = tsy / tss;
    if (!nn->ok || !(nn->metrics.pixels > 0))
        return;
    double nn_mse = bench_result_mse(nn);
    e->nn_mse_true = nn_mse - e->variance / ref->spp;
    /* Within the reference's own noise nn's true error cannot be told from zero: the bound
     * uses the measured error, which only flatters pt. */
    e->lower_bound = !(e->nn_mse_true > 0.1 * nn_mse);
    double mse = e->lower_bound ? nn_mse : e->nn_mse_true;
    e->pt_ms_equal = e->pass_ms_per_spp * e->variance / mse;
    e->speedup = e->pt_ms_equal / nn->ms;
    e->speedup_frame = e->pt_ms_equal / (nn->ms + nn->camera_ms);
    e->ok = isfinite(e->speedup); /* speedup_frame: NaN where the camera pass is unknown */
}

static void run_scene(bench *b, bench_scene *s)
{
    const int *sel = b->run.methods;
    for (int m = 0; m < BENCH_METHOD_COUNT; m++) {
        if (!sel[m] || m == BENCH_PT)
            continue;
        double t0 = ns_now_ms();
        if (m == BENCH_VRL)
            run_vrl_equal_time(b, s);
        else
            run_method_at(b, s, m,
                          bench_methods[m].vrls_key
                              ? manifest_vrls(s, bench_methods[m].vrls_key, b->args.vrl_scale)
                              : 0,
                          b->run.repeat);
        compare_with_reference(s, m);
        run_seeds(b, s, m);
        const bench_result *r = &s->results[m];
        if (r->ok)
            fprintf(stderr, "bench: %s %s: %.1f ms, PSNR %.2f dB (%.1f s)\n", s->name, bench_methods[m].name,
                    r->ms, r->metrics.psnr[3], (ns_now_ms() - t0) / 1000.0);
        else
            fprintf(stderr, "bench: %s %s: not rendered: %s\n", s->name, bench_methods[m].name, r->error);
    }
    if (sel[BENCH_PT]) {
        run_pt_ladder(b, s);
        if (!s->results[BENCH_PT].ok)
            fprintf(stderr, "bench: %s pt: %s\n", s->name, s->results[BENCH_PT].error);
    }
}

/* ---------------------------------------------------------------------------------------
 * Set-up: folders, manifest, scenes, device.
 * ------------------------------------------------------------------------------------- */
static int setup_dirs(bench *b)
{
    const char *cache = b->args.cache_dir ? b->args.cache_dir : getenv("NSCATTER_CACHE_DIR");
    if (cache && *cache) {
        snprintf(b->cache_dir, sizeof b->cache_dir, "%s", cache);
    } else {
        const char *home = getenv("HOME");
        snprintf(b->cache_dir, sizeof b->cache_dir, "%s/.cache/nscatter/bench", home && *home ? home : ".");
    }
    snprintf(b->asset_dir, sizeof b->asset_dir, "%s/assets", b->cache_dir);
    if (mkdir_p(b->asset_dir)) {
        fprintf(stderr, "nscatter bench: --cache '%s': cannot create it: %s\n", b->cache_dir, strerror(errno));
        return 1;
    }
    if (!b->args.references_only && mkdir_p(b->args.out_dir)) {
        fprintf(stderr, "nscatter bench: --out '%s': cannot create it: %s\n", b->args.out_dir, strerror(errno));
        return 1;
    }
    return 0;
}

static int load_scenes(bench *b)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/bench.json", b->scene_dir);
    b->manifest = load_json(path, "manifest");
    json_t *list = json_object_get(b->manifest, "scenes");
    if (!json_is_array(list) || !json_array_size(list)) {
        if (b->manifest)
            fprintf(stderr, "nscatter bench: '%s' has no \"scenes\" array\n", path);
        return 2;
    }
    if (b->args.scenes) /* every name asked for must exist */
        for (const char *p = b->args.scenes; *p;) {
            size_t len = strcspn(p, ","), i, found = 0;
            json_t *e;
            json_array_foreach(list, i, e)
            {
                const char *n = json_string_value(json_object_get(e, "name"));
                found |= n && strlen(n) == len && !strncmp(n, p, len);
            }
            if (!found) {
                fprintf(stderr, "nscatter bench: --scenes: unknown scene '%.*s' (see %s)\n", (int)len, p, path);
                return 2;
            }
            p += len + (p[len] == ',');
        }
    b->run.scenes = calloc(json_array_size(list), sizeof *b->run.scenes);
    if (!b->run.scenes)
        return 1;
    /* In the order of --scenes when given (cheap scenes first on a slow device), else the
     * manifest's. */
    const char *order = b->args.scenes;
    for (const char *p = order; p && *p;) {
        size_t len = strcspn(p, ","), i;
        json_t *e;
        json_array_foreach(list, i, e)
        {
            const char *n = json_string_value(json_object_get(e, "name"));
            if (n && strlen(n) == len && !strncmp(n, p, len) && b->run.scene_count < json_array_size(list)) {
                if (load_scene(b, e, &b->run.scenes[b->run.scene_count++]))
                    return 2;
                break;
            }
        }
        p += len + (p[len] == ',');
    }
    size_t i;
    json_t *e;
    json_array_foreach(list, i, e)
    {
        if (order)
            break;
        if (load_scene(b, e, &b->run.scenes[b->run.scene_count++]))
            return 2;
    }
    return 0;
}

static int scene_uses_asset(const bench_scene *s, const char *asset)
{
    size_t i;
    json_t *o;
    json_array_foreach(json_object_get(s->scene, "objects"), i, o)
    {
        const char *a = json_string_value(json_object_get(o, "asset"));
        if (a && !strcmp(a, asset))
            return 1;
    }
    return 0;
}

static void note_command_and_date(bench *b, int argc, char **argv)
{
    size_t at = (size_t)snprintf(b->run.command, sizeof b->run.command, "nscatter bench");
    for (int i = 1; i < argc && at < sizeof b->run.command; i++)
        at += (size_t)snprintf(b->run.command + at, sizeof b->run.command - at, " %s", argv[i]);
    time_t now = time(NULL);
    struct tm tm;
    gmtime_r(&now, &tm);
    strftime(b->run.date, sizeof b->run.date, "%Y-%m-%d %H:%M UTC", &tm);
}

static int create_context(bench *b)
{
    ns_error err = {0};
    /* The provider's own cache (shared with `render` and `serve`): a material's tables are
     * simulated once per machine, whichever command asks first. */
    int rc = ns_mc_provider_create(&(ns_mc_provider_desc){.collisions = b->args.mc_collisions}, &b->mc, &err);
    if (rc)
        fprintf(stderr, "bench: method table will be unavailable: %s\n", err.message);
    rc = ns_context_create(&(ns_context_desc){.device = b->args.device,
                                              .mc_tables = b->mc ? ns_mc_provider_tables : NULL,
                                              .mc_user = b->mc},
                           &b->ctx, &err);
    if (rc) {
        fprintf(stderr, "nscatter bench: %s: %s\n", ns_status_name(rc), err.message);
        return 1;
    }
    ns_device_info info;
    ns_context_device_info(b->ctx, &info);
    snprintf(b->run.device, sizeof b->run.device, "%s", info.device_name);
    snprintf(b->run.driver, sizeof b->run.driver, "%.120s %.120s", info.driver_name, info.driver_info);
    return 0;
}

static void bench_free(bench *b)
{
    for (uint32_t i = 0; i < b->run.scene_count; i++) {
        bench_scene *s = &b->run.scenes[i];
        for (int r = 0; r < BENCH_REF_SETS; r++)
            ns_image_free(&s->refs[r].image);
        for (int m = 0; m < BENCH_METHOD_COUNT; m++)
            ns_image_free(&s->results[m].image);
        json_decref(s->scene);
    }
    free(b->run.scenes);
    json_decref(b->manifest);
    ns_context_destroy(b->ctx);
    ns_mc_provider_destroy(b->mc);
}

/* Which reference sets the selected methods compare with. */
static void mark_wanted_references(bench *b, bench_scene *s)
{
    for (int m = 0; m < BENCH_METHOD_COUNT; m++)
        if (b->run.methods[m]) {
            int set = bench_ref_index(bench_methods[m].components);
            if (set >= 0)
                s->refs[set].wanted = 1;
        }
}

/* The references scene s's methods compare with; made counts those rendered now. */
static int scene_references(bench *b, bench_scene *s, int force, uint32_t *made)
{
    int failed = 0;
    mark_wanted_references(b, s);
    for (int set = 0; set < BENCH_REF_SETS; set++)
        if (s->refs[set].wanted) {
            failed |= ensure_reference(b, s, set, force);
            *made += s->refs[set].generated;
        }
    return failed;
}

int cmd_bench(int argc, char **argv)
{
    bench *b = calloc(1, sizeof *b);
    if (!b)
        return 1;
    int done = 0;
    int rc = parse_bench_args(argc, argv, &b->args, &done);
    if (!rc && !done && b->args.methods)
        rc = parse_methods(b->args.methods, b->run.methods);
    else if (!rc && !done)
        for (int m = 0; m < BENCH_METHOD_COUNT; m++)
            b->run.methods[m] = 1;
    if (!rc && !done)
        rc = parse_ladder(b->args.ladder, b->ladder, &b->ladder_count);
    if (rc || done) {
        free(b);
        return rc;
    }
    double t0 = ns_now_ms();
    b->run.repeat = b->args.repeat;
    b->run.seeds = b->args.seeds;
    b->run.mc_collisions = b->args.mc_collisions;
    b->run.boundary = b->args.boundary;
    b->run.diff_method = bench_method_by_name(b->args.diff, strlen(b->args.diff));
    note_command_and_date(b, argc, argv);
    snprintf(b->scene_dir, sizeof b->scene_dir, "%s",
             b->args.scene_dir ? b->args.scene_dir : NS_SOURCE_DIR "/scenes/bench");
    rc = load_scenes(b); /* bad scene names exit 2 before anything is created */
    if (!rc)
        rc = setup_dirs(b);
    if (!rc && prepare_generated_assets(b))
        rc = 1;
    for (uint32_t i = 0; !rc && i < b->run.scene_count; i++) {
        bench_scene *s = &b->run.scenes[i];
        if (scene_uses_asset(s, "bench_bunny.glb") && prepare_bunny(b, s->skip_reason, sizeof s->skip_reason)) {
            s->skipped = 1;
            fprintf(stderr, "bench: %s skipped: %s\n", s->name, s->skip_reason);
        }
    }
    if (!rc)
        rc = create_context(b);
    /* Scene by scene: references, methods, then the report again, so a long run can be read
     * as it goes and an interrupted one keeps what it measured. A reference that cannot be
     * made fails the run (exit 1) but not the other scenes: the report says what is missing. */
    int references_failed = 0, wrote = 0;
    uint32_t made = 0;
    for (uint32_t i = 0; !rc && b->args.ref_ceiling_db > 0 && i < b->run.scene_count; i++) {
        bench_scene *s = &b->run.scenes[i];
        mark_wanted_references(b, s);
        for (int set = 0; set < BENCH_REF_SETS && !s->skipped; set++)
            b->ref_pending += (uint32_t)s->refs[set].wanted;
    }
    double ref_ms = 0;
    for (uint32_t i = 0; !rc && i < b->run.scene_count; i++) {
        bench_scene *s = &b->run.scenes[i];
        if (s->skipped)
            continue;
        double t1 = ns_now_ms();
        references_failed |= scene_references(b, s, b->args.references_only, &made);
        ref_ms += ns_now_ms() - t1;
        if (b->args.references_only)
            continue;
        run_scene(b, s);
        b->run.total_s = (ns_now_ms() - t0) / 1000.0;
        rc = bench_write_report(&b->run, b->args.out_dir);
        wrote = 1;
    }
    if (!rc && !wrote && !b->args.references_only) /* every scene skipped: say so */
        rc = bench_write_report(&b->run, b->args.out_dir);
    if (b->ctx)
        fprintf(stderr, "bench: references: %u rendered in %.1f s (cache %s)\n", made, ref_ms / 1000.0,
                b->cache_dir);
    if (!rc && !b->args.references_only)
        fprintf(stderr, "bench: wrote %s/report.md and %s/contact_sheet.png in %.1f s\n", b->args.out_dir,
                b->args.out_dir, b->run.total_s);
    if (!rc && references_failed)
        rc = 1;
    bench_free(b);
    free(b);
    return rc;
}
