/* gpu_scatter_bench.c — timings of the scattering stages on a candle-like scene (a block of
 * the paper's candle wax lit by a flame-like point light and a dim environment), and the
 * gather's VRL-segment interactions per second against a plain C loop of the same arithmetic
 * (tests/oracles/gather_cpu.c ns_gather_cpu) on 2 threads, on the same VRLs, segments and table.
 *
 * As a test (default) it renders once, small, and checks that every scattering stage and
 * count is reported. With NSCATTER_BENCH=N it prints the medians of N runs: 256x256 and
 * 512x512, multiple only and the full solution, with render.vrls = 40000 (the issue's
 * target scene), then the solid-angle option's time and error against the exact gather, then
 * the adaptive gather's, then the interaction rates (docs/scattering.md quotes them).
 * NSCATTER_BENCH_ONLY=renders | solid_angle | adaptive | gather runs one part;
 * NSCATTER_BENCH_256_ONLY=1 skips 512x512 in the solid-angle and adaptive sweeps,
 * NSCATTER_BENCH_THRESHOLDS=0.05,0.5 sweeps those thresholds (after the
 * exact gather); NSCATTER_BENCH_POINT_ONLY=1 drops the environment light;
 * NSCATTER_BENCH_BEAMS=bounded renders with render.vrl_beams "bounded". */
#include <pthread.h>
#include <stdlib.h>

#include "gpu_util.h"
#include "image_metrics.h"
#include "oracles/gather_cpu.h"
#include "vrl_shared.h"

static ns_material materials[2];
static ns_object objects[2];
static ns_light lights[2];

static ns_scene candle_scene(uint32_t size, uint32_t components, uint32_t vrls)
{
    ns_scene s = base_scene(size, size, 30);
    set3(s.camera.position, 0, 2.5, 9);
    set3(s.camera.look_at, 0, 1.2, 0);
    s.render.spp = 1;
    s.render.components = components;
    s.render.vrls = vrls;
    const char *beams = getenv("NSCATTER_BENCH_BEAMS");
    s.render.vrl_beams = beams && !strcmp(beams, "bounded") ? NS_VRL_BEAMS_BOUNDED : NS_VRL_BEAMS_ENDLESS;
    materials[0] = diffuse(0.5, 0.45, 0.4);
    /* The paper's Table 1 candle: albedo 0.98 0.962 0.75, mfp 0.65 0.63 0.59, g 0.8. */
    const double albedo[3] = {0.98, 0.962, 0.75}, mfp[3] = {0.65, 0.63, 0.59};
    double sigma_s[3], sigma_a[3];
    for (int c = 0; c < 3; c++) {
        sigma_s[c] = albedo[c] / mfp[c];
        sigma_a[c] = (1 - albedo[c]) / mfp[c];
    }
    materials[1] = medium(sigma_s, sigma_a, 1.45);
    materials[1].g = 0.8f;
    objects[0] = plane(-0.001, 0);
    memset(&objects[1], 0, sizeof objects[1]);
    objects[1].shape = NS_SHAPE_BOX;
    objects[1].material = 1;
    set3(objects[1].min, -1, 0, -1);
    set3(objects[1].max, 1, 3, 1);
    lights[0] = light(NS_LIGHT_POINT, 6, 4.5, 2.5);
    set3(lights[0].position, 0.3, 3.6, 0.2);
    lights[1] = light(NS_LIGHT_ENVIRONMENT, 0.05, 0.06, 0.08);
    scene_lists(&s, materials, 2, objects, 2, lights, getenv("NSCATTER_BENCH_POINT_ONLY") ? 1 : 2);
    return s;
}

static double stage_ms(const ns_render_stats *stats, const char *name)
{
    double ms = -1;
    for (uint32_t i = 0; i < stats->stage_count; i++)
        if (!strcmp(stats->stages[i].name, name))
            ms = (ms < 0 ? 0 : ms) + stats->stages[i].ms;
    return ms;
}

static void test_stages_reported(void)
{
    ns_scene s = candle_scene(48, NS_COMPONENT_SURFACE | NS_COMPONENT_SINGLE | NS_COMPONENT_DOUBLE |
                                      NS_COMPONENT_MULTIPLE,
                              2000);
    ns_image img = {0};
    ns_render_stats stats = {0};
    if (!render_ok(&s, &img, &stats))
        return;
    const char *names[] = {"ray_pass", "single", "vrl", "grid", "gather", "composite"};
    for (int i = 0; i < 6; i++)
        CHECK(stage_ms(&stats, names[i]) >= 0);
    CHECK(stats.vrl_paths == 2000);
    /* Bounded beams store up to NS_VRL_MAX_CHAIN stretches per path. */
    uint32_t per_path = s.render.vrl_beams == NS_VRL_BEAMS_BOUNDED ? NS_VRL_MAX_CHAIN : 1;
    CHECK(stats.vrl_count > 500 && stats.vrl_count <= 2000 * per_path);
    CHECK(stats.gather_segments > 0 && stats.gather_segments <= stats.camera_segments);
    CHECK(stats.interactions >= stats.gather_segments);
    CHECK(stats.table_bytes == 3ull * NS_TABLE_CELLS * sizeof(float));
    ns_image_free(&img);
}

static int compare_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

static double median(double *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, compare_double);
    return v[n / 2];
}

#define MAX_RUNS 32
static void bench_renders(int runs)
{
    const char *names[] = {"ray_pass", "reconstruct", "accumulate", "vrl", "grid", "gather", "single", "composite"};
    enum { NAMES = 8 };
    const uint32_t sizes[] = {256, 512};
    const uint32_t sets[] = {NS_COMPONENT_MULTIPLE, NS_COMPONENT_SURFACE | NS_COMPONENT_SINGLE |
                                                        NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE};
    printf("candle-like scene, 40000 VRL paths, tables cached (warm), median ms of %d runs\n", runs);
    printf("%-8s %-9s", "size", "solution");
    for (int k = 0; k < NAMES; k++)
        printf(" %10s", names[k]);
    printf(" %10s %8s %12s\n", "total", "VRLs", "interactions");
    /* One untimed render first: reconstruction and accumulation of the material (cached). */
    ns_scene warm = candle_scene(32, NS_COMPONENT_MULTIPLE, 1000);
    ns_image img = {0};
    if (!render_ok(&warm, &img, NULL))
        return;
    ns_image_free(&img);
    for (int a = 0; a < 2; a++)
        for (int b = 0; b < 2; b++) {
            double t[NAMES + 1][MAX_RUNS];
            ns_render_stats stats = {0};
            for (int r = 0; r < runs; r++) {
                ns_scene s = candle_scene(sizes[a], sets[b], 40000);
                memset(&stats, 0, sizeof stats);
                double t0 = ns_now_ms();
                if (!render_ok(&s, &img, &stats))
                    return;
                t[NAMES][r] = ns_now_ms() - t0;
                for (int k = 0; k < NAMES; k++)
                    t[k][r] = stage_ms(&stats, names[k]);
                ns_image_free(&img);
            }
            printf("%3ux%-4u %-9s", sizes[a], sizes[a], b ? "full" : "multiple");
            for (int k = 0; k <= NAMES; k++)
                printf(" %10.1f", median(t[k], runs));
            printf(" %8llu %12llu\n", (unsigned long long)stats.vrl_count,
                   (unsigned long long)stats.interactions);
        }
}

/* Renders scene `runs` times: the last image and stats, the median gather and total ms.
 * Returns 0 when a render failed. */
static int timed_renders(const ns_scene *scene, int runs, ns_image *img, ns_render_stats *stats,
                         double *gather_ms, double *total_ms)
{
    double gather[MAX_RUNS], total[MAX_RUNS];
    for (int r = 0; r < runs; r++) {
        ns_scene s = *scene;
        memset(stats, 0, sizeof *stats);
        ns_image_free(img);
        double t0 = ns_now_ms();
        if (!render_ok(&s, img, stats))
            return 0;
        total[r] = ns_now_ms() - t0;
        gather[r] = stage_ms(stats, "gather");
    }
    *gather_ms = median(gather, runs);
    *total_ms = median(total, runs);
    return 1;
}

/* The solid-angle option (render.cull_solid_angle): far nodes of the hierarchy count as
 * their representative. Error against the exact gather (threshold 0) of the same scene and
 * VRLs, and the time it buys: multiple only, 256x256 and 512x512. */
static void bench_solid_angle(int runs)
{
    float thresholds[8] = {0.0f, 0.02f, 0.05f, 0.1f, 0.2f, 0.5f};
    int count = 6;
    /* NSCATTER_BENCH_THRESHOLDS=0.05,0.5: a shorter sweep (the exact gather always first). */
    const char *list = getenv("NSCATTER_BENCH_THRESHOLDS");
    if (list) {
        count = 1;
        for (char *end; count < 8; list = end + 1) {
            float t = strtof(list, &end);
            if (end == list)
                break;
            thresholds[count++] = t;
            if (*end != ',')
                break;
        }
    }
    const uint32_t sizes[] = {256, 512};
    int size_count = getenv("NSCATTER_BENCH_256_ONLY") ? 1 : 2;
    printf("\nsolid-angle threshold, multiple only, 40000 VRL paths, median ms of %d runs\n", runs);
    printf("%-8s %9s %10s %10s %12s %12s %9s %9s\n", "size", "threshold", "gather", "total",
           "interactions", "represented", "PSNR dB", "rel.err");
    for (int a = 0; a < size_count; a++) {
        ns_image exact = {0};
        for (int k = 0; k < count; k++) {
            ns_render_stats stats = {0};
            ns_image img = {0};
            ns_scene s = candle_scene(sizes[a], NS_COMPONENT_MULTIPLE, 40000);
            s.render.cull_solid_angle = thresholds[k];
            double gather, total;
            if (!timed_renders(&s, runs, &img, &stats, &gather, &total))
                return;
            image_metrics m = {0};
            if (k == 0)
                exact = img;
            else
                image_compare(&img, &exact, NULL, &m);
            printf("%3ux%-4u %9.3g %10.1f %10.1f %12llu %12llu %9.1f %8.3f%%\n", sizes[a], sizes[a],
                   (double)thresholds[k], gather, total,
                   (unsigned long long)stats.interactions, (unsigned long long)stats.cells_represented,
                   k ? m.psnr[3] : INFINITY, k ? 100 * m.relerr[3] : 0.0);
            if (k)
                ns_image_free(&img);
        }
        ns_image_free(&exact);
    }
}

/* The adaptive gather (render.gather_levels, gather_tolerance), alone and with the
 * solid-angle option: time, and error against the exact gather of every tile with the same
 * VRLs and against one with five times the light paths (nearer the converged image: the
 * adaptive gather smooths the VRL estimate's own noise, which the first comparison counts
 * as error). Multiple only, 256x256 and 512x512. */
static void bench_adaptive(int runs)
{
    const struct {
        uint32_t levels;
        float tolerance, solid_angle;
    } settings[] = {{0, 0, 0},        {0, 0, 0.05f},      {3, 0.01f, 0},     {3, 0.02f, 0},
                    {3, 0.02f, 0.05f}, {4, 0.05f, 0.05f}, {4, 0.05f, 0.5f}};
    const int count = sizeof settings / sizeof settings[0];
    const uint32_t sizes[] = {256, 512};
    int size_count = getenv("NSCATTER_BENCH_256_ONLY") ? 1 : 2;
    printf("\nadaptive gather, multiple only, 40000 VRL paths, median ms of %d runs; error against "
           "every tile gathered exactly (same VRLs) and against 200000 light paths\n", runs);
    printf("%-8s %6s %9s %6s %9s %9s %9s %12s %12s %8s %8s %8s\n", "size", "levels", "tolerance",
           "sr", "gather", "total", "segments", "interpolated", "interactions", "PSNR dB",
           "rel.err", "vs 200k");
    for (int a = 0; a < size_count; a++) {
        ns_image exact = {0}, converged = {0};
        ns_scene c = candle_scene(sizes[a], NS_COMPONENT_MULTIPLE, 200000);
        if (!render_ok(&c, &converged, NULL))
            return;
        for (int k = 0; k < count; k++) {
            ns_render_stats stats = {0};
            ns_image img = {0};
            ns_scene s = candle_scene(sizes[a], NS_COMPONENT_MULTIPLE, 40000);
            s.render.gather_levels = settings[k].levels;
            s.render.gather_tolerance = settings[k].tolerance;
            s.render.cull_solid_angle = settings[k].solid_angle;
            double gather, total;
            if (!timed_renders(&s, runs, &img, &stats, &gather, &total))
                return;
            image_metrics m = {0}, mc = {0};
            if (k > 0)
                image_compare(&img, &exact, NULL, &m);
            image_compare(&img, &converged, NULL, &mc);
            printf("%3ux%-4u %6u %9.3g %6.3g %9.1f %9.1f %9llu %12llu %12llu %8.1f %7.3f%% %7.3f%%\n",
                   sizes[a], sizes[a], settings[k].levels, (double)settings[k].tolerance,
                   (double)settings[k].solid_angle, gather, total,
                   (unsigned long long)stats.gather_segments, (unsigned long long)stats.tiles_interpolated,
                   (unsigned long long)stats.interactions, k ? m.psnr[3] : INFINITY,
                   k ? 100 * m.relerr[3] : 0.0, 100 * mc.relerr[3]);
            fflush(stdout);
            if (k == 0)
                exact = img;
            else
                ns_image_free(&img);
        }
        ns_image_free(&exact);
        ns_image_free(&converged);
    }
}

/* ---------------------------------------------------------------------------------------
 * The gather alone: GPU against ns_gather_cpu on 2 threads, same inputs.
 * ------------------------------------------------------------------------------------- */
typedef struct cpu_job {
    const GpuGatherParams *params;
    const GpuSegment *segments;
    uint32_t count;
    const ns_vrl_grid *grid;
    const float *table;
    float (*out)[4];
} cpu_job;

static void *cpu_worker(void *arg)
{
    cpu_job *j = arg;
    ns_gather_cpu(j->params, j->segments, j->count, j->grid, j->table, 1, j->out, NULL);
    return NULL;
}

static uint32_t rng_state = 99u;
static float uniform01(void)
{
    rng_state = rng_state * 1664525u + 1013904223u;
    return (float)(rng_state >> 8) * (1.0f / 16777216.0f);
}

static void bench_gather(int runs)
{
    ns_context *ctx = test_context();
    ns_error err = {0};
    const GpuMaterial *unused = NULL;
    (void)unused;
    /* The candle material's tables (exact accumulation, double + multiple). */
    ns_table_key key = {.source = NS_METHOD_NN, .g = 0.8f, .albedo = {0.98f, 0.962f, 0.75f},
                        .orders = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE};
    const ns_scatter_tables *tables = NULL;
    int status = ns_tables_get(ctx, &key, &tables, NULL, &err);
    if (status)
        fprintf(stderr, "tables: %s\n", err.message);
    CHECK_INT(status, NS_OK); /* a bench that could not run is a failure, not a quiet pass */
    if (status)
        return;
    const uint32_t vrl_count = 40000, cells = 64, segment_count = 4096;
    ns_vrl_grid grid = {0};
    grid.vrls = calloc(vrl_count, sizeof *grid.vrls);
    grid.cells = calloc(cells, sizeof *grid.cells);
    grid.representatives = calloc(cells, sizeof *grid.representatives);
    grid.vrl_count = vrl_count;
    grid.cell_count = cells;
    for (uint32_t i = 0; i < vrl_count; i++) {
        GpuVrl *v = &grid.vrls[i];
        set3(v->origin, 2 * uniform01() - 1, 3 * uniform01(), 2 * uniform01() - 1);
        float z = -uniform01(), phi = 6.2831853f * uniform01(), r = sqrtf(1 - z * z);
        set3(v->direction, r * cosf(phi), z, r * sinf(phi));
        set3(v->power, 1e-4, 1e-4, 1e-4);
    }
    for (uint32_t c = 0; c < cells; c++) {
        grid.cells[c].first = c * (vrl_count / cells);
        grid.cells[c].count = vrl_count / cells;
        set3(grid.cells[c].bmin, -1, 0, -1);
        set3(grid.cells[c].bmax, 1, 3, 1);
    }
    GpuSegment *segments = calloc(segment_count, sizeof *segments);
    for (uint32_t i = 0; i < segment_count; i++) {
        set3(segments[i].entry, 2 * uniform01() - 1, 3 * uniform01(), 1);
        set3(segments[i].direction, 0, 0, -1);
        set3(segments[i].exit, segments[i].entry[0], segments[i].entry[1], -1);
    }
    GpuMaterial m = {0};
    for (int c = 0; c < 3; c++)
        m.sigma_t[c] = 1.0f / (float)(c == 0 ? 0.65 : c == 1 ? 0.63 : 0.59);
    m.sigma_t[3] = 1.45f;
    gpu_buffer seg_buf = {0}, out = {0};
    status = gpu_buffer_create(&ctx->dev, &seg_buf,
                               &(gpu_buffer_desc){.size = sizeof *segments * segment_count, .data = segments,
                                                  .data_size = sizeof *segments * segment_count, .label = "bench"},
                               &err);
    if (!status)
        status = gpu_buffer_create(&ctx->dev, &out,
                                   &(gpu_buffer_desc){.size = 16ull * segment_count, .label = "bench"}, &err);
    ns_gather_desc desc = {.segments = &seg_buf, .segment_count = segment_count, .grid = &grid,
                           .table = &tables->a, .out = &out};
    ns_gather_params(&desc.params, &m, NS_GATHER_MODE_EXACT, tables, 0.0f, 0);
    double gpu[MAX_RUNS], cpu[MAX_RUNS];
    for (int r = 0; r < runs && !status; r++) {
        ns_gather_counts counts;
        double t0 = ns_now_ms();
        status = ns_gather_run(ctx, &desc, &counts, &err);
        gpu[r] = ns_now_ms() - t0;
    }
    if (status)
        fprintf(stderr, "gather: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    float(*host)[4] = calloc(segment_count, sizeof *host);
    GpuGatherParams params = desc.params;
    params.counts[0] = segment_count;
    for (int r = 0; r < runs; r++) {
        pthread_t threads[2];
        cpu_job jobs[2];
        double t0 = ns_now_ms();
        for (int k = 0; k < 2; k++) {
            uint32_t half = segment_count / 2;
            jobs[k] = (cpu_job){&params, segments + k * half, half, &grid, tables->a.mapped, host + k * half};
            pthread_create(&threads[k], NULL, cpu_worker, &jobs[k]);
        }
        for (int k = 0; k < 2; k++)
            pthread_join(threads[k], NULL);
        cpu[r] = ns_now_ms() - t0;
    }
    double pairs = (double)vrl_count * segment_count;
    double g = status ? NAN : median(gpu, runs), c = median(cpu, runs);
    printf("gather, %u VRLs x %u segments (%.0f M interactions), median of %d:\n", vrl_count,
           segment_count, pairs / 1e6, runs);
    printf("  GPU (%s): %8.1f ms  %7.1f M interactions/s\n", ctx->dev.info.device_name, g, pairs / g / 1e3);
    printf("  C, 2 threads:              %8.1f ms  %7.1f M interactions/s  (GPU / C = %.2f)\n", c,
           pairs / c / 1e3, c / g);
    gpu_buffer_destroy(&ctx->dev, &seg_buf);
    gpu_buffer_destroy(&ctx->dev, &out);
    free(host);
    free(segments);
    free(grid.vrls);
    free(grid.cells);
    free(grid.representatives);
}

int main(void)
{
    RUN(test_stages_reported);
    const char *runs = getenv("NSCATTER_BENCH");
    if (runs && atoi(runs) > 0) {
        int n = atoi(runs) < MAX_RUNS ? atoi(runs) : MAX_RUNS;
        if (!getenv("NSCATTER_BENCH_ONLY") || !strcmp(getenv("NSCATTER_BENCH_ONLY"), "renders"))
            bench_renders(n);
        if (!getenv("NSCATTER_BENCH_ONLY") || !strcmp(getenv("NSCATTER_BENCH_ONLY"), "solid_angle"))
            bench_solid_angle(n);
        if (!getenv("NSCATTER_BENCH_ONLY") || !strcmp(getenv("NSCATTER_BENCH_ONLY"), "adaptive"))
            bench_adaptive(n);
        if (!getenv("NSCATTER_BENCH_ONLY") || !strcmp(getenv("NSCATTER_BENCH_ONLY"), "gather"))
            bench_gather(n);
    }
    ns_context_destroy(test_context());
    return harness_report();
}
