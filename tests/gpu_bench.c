/* gpu_bench.c — stage timings of the camera pass on a small mixed scene (spheres, a box, a
 * plane, a glass medium sphere; three kinds of light), and context creation with cold and
 * warm caches. As a test (default) it renders once, small, and checks that every stage is
 * reported and that the medium recorded segments. With NSCATTER_BENCH=N it also prints the
 * medians of N runs at 256x256 and 512x512, spp 1 and 4 (docs/rendering.md quotes them).
 * Context timing: NSCATTER_BENCH_CACHE=path/to/pipeline_cache (cold = a missing file and an
 * empty MESA_SHADER_CACHE_DIR, which the caller arranges). */
#include <stdlib.h>

#include "gpu_util.h"

static ns_material materials[4];
static ns_object objects[6];
static ns_light lights[3];

static ns_scene bench_scene(uint32_t size, uint32_t spp)
{
    ns_scene s = base_scene(size, size, 40);
    set3(s.camera.position, 0, 1.6, 6);
    set3(s.camera.look_at, 0, -0.1, 0);
    s.render.spp = spp;
    const double glass_s[3] = {0.2, 0.3, 0.4}, glass_a[3] = {0.3, 0.1, 0.05};
    materials[0] = diffuse(0.6, 0.6, 0.6);
    materials[1] = diffuse(0.7, 0.25, 0.15);
    materials[2] = diffuse(0.2, 0.4, 0.7);
    materials[3] = medium(glass_s, glass_a, 1.45);
    objects[0] = plane(-1, 0);
    objects[1] = sphere(-0.6, 0, 0, 1, 3);
    objects[2] = sphere(1.2, -0.6, 1.2, 0.4, 2);
    objects[3] = sphere(-2.0, -0.5, 1.0, 0.5, 1);
    objects[4] = sphere(0.4, -0.75, 1.8, 0.25, 0);
    memset(&objects[5], 0, sizeof objects[5]);
    objects[5].shape = NS_SHAPE_BOX;
    objects[5].material = 1;
    set3(objects[5].min, 1.0, -1, -0.6);
    set3(objects[5].max, 2.0, 0.2, 0.4);
    lights[0] = light(NS_LIGHT_DIRECTIONAL, 2.5, 2.4, 2.2);
    set3(lights[0].direction, -0.4, -1, -0.6);
    lights[1] = light(NS_LIGHT_SPHERE, 20, 20, 20);
    set3(lights[1].position, 2.5, 3.5, 2.5);
    lights[1].radius = 0.3f;
    lights[2] = light(NS_LIGHT_ENVIRONMENT, 0.25, 0.3, 0.4);
    scene_lists(&s, materials, 4, objects, 6, lights, 3);
    return s;
}

static int compare_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

static double stage_ms(const ns_render_stats *stats, const char *name)
{
    for (uint32_t i = 0; i < stats->stage_count; i++)
        if (!strcmp(stats->stages[i].name, name))
            return stats->stages[i].ms;
    return -1;
}

static void test_stages_reported(void)
{
    ns_scene s = bench_scene(32, 1);
    ns_image img = {0};
    ns_render_stats stats = {0};
    if (!render_ok(&s, &img, &stats))
        return;
    const char *names[] = {"bvh", "upload", "ray_pass", "readback"};
    for (int i = 0; i < 4; i++)
        CHECK(stage_ms(&stats, names[i]) >= 0);
    CHECK(stats.camera_segments > 0);
    CHECK_INT(stats.primitives, 6);
    CHECK(stats.bvh_nodes >= 3);
    ns_image_free(&img);
}

#define MAX_RUNS 64
static void bench(int runs)
{
    const char *names[] = {"bvh", "upload", "ray_pass", "readback"};
    const uint32_t sizes[] = {256, 512}, spps[] = {1, 4};
    printf("size     spp  %10s %10s %10s %10s %10s  (median ms of %d runs)\n", names[0], names[1],
           names[2], names[3], "total", runs);
    for (int a = 0; a < 2; a++)
        for (int b = 0; b < 2; b++) {
            double t[5][MAX_RUNS];
            for (int r = 0; r < runs; r++) {
                ns_scene s = bench_scene(sizes[a], spps[b]);
                ns_image img = {0};
                ns_render_stats stats = {0};
                double t0 = ns_now_ms();
                if (!render_ok(&s, &img, &stats))
                    return;
                t[4][r] = ns_now_ms() - t0;
                for (int k = 0; k < 4; k++)
                    t[k][r] = stage_ms(&stats, names[k]);
                ns_image_free(&img);
            }
            printf("%3ux%-4u %3u ", sizes[a], sizes[a], spps[b]);
            for (int k = 0; k < 5; k++) {
                qsort(t[k], (size_t)runs, sizeof(double), compare_double);
                printf(" %10.2f", t[k][runs / 2]);
            }
            printf("\n");
        }
}

int main(void)
{
    const char *cache = getenv("NSCATTER_BENCH_CACHE");
    if (cache) {
        ns_context *ctx = NULL;
        ns_error err = {0};
        double t0 = ns_now_ms();
        int status =
            ns_context_create(&(ns_context_desc){.pipeline_cache_path = cache}, &ctx, &err);
        printf("context create (pipelines warmed): %.1f ms, status %s\n", ns_now_ms() - t0,
               ns_status_name(status));
        ns_context_destroy(ctx);
        return status ? 1 : 0;
    }
    RUN(test_stages_reported);
    const char *runs = getenv("NSCATTER_BENCH");
    if (runs && atoi(runs) > 0)
        bench(atoi(runs) < MAX_RUNS ? atoi(runs) : MAX_RUNS);
    ns_context_destroy(test_context());
    return harness_report();
}
