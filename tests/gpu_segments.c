/* gpu_segments.c — the camera pass records every stretch a path travels inside a medium:
 * through an index-matched sphere each sample records exactly one segment, entering and
 * leaving on the sphere, of length 2r through the centre, with the throughput it had at
 * the entry; a full buffer counts the overflow instead of writing past its end. */
#include "gpu_util.h"

#define SPP 16

static ns_scene segment_scene(ns_material *m, ns_object *o, ns_light *l, uint32_t size)
{
    const double sigma_s[3] = {0.5, 0.25, 0.0}, sigma_a[3] = {0.1, 0.0, 0.0};
    ns_scene s = base_scene(size, size, 0.5);
    set3(s.camera.position, 0, 0, 10);
    set3(s.camera.look_at, 0, 0, 0);
    s.render.spp = SPP;
    *m = medium(sigma_s, sigma_a, 1.0);
    *o = sphere(0, 0, 0, 1.5, 0);
    *l = light(NS_LIGHT_ENVIRONMENT, 1, 1, 1);
    scene_lists(&s, m, 1, o, 1, l, 1);
    return s;
}

static double dist3(const float a[3], const float b[3])
{
    double dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
    return sqrt(dx * dx + dy * dy + dz * dz);
}

static void test_one_segment_per_sample(void)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = segment_scene(&m, &o, &l, 3);
    GpuSegment segments[1024];
    ns_render_debug debug = {.segments = segments, .segments_max = 1024};
    ns_image img = {0};
    ns_render_stats stats = {0};
    ns_error err = {0};
    int status = ns_render_ex(test_context(), &s, &img, &stats, &debug, &err);
    CHECK_INT(status, NS_OK);
    if (status)
        return;
    CHECK_INT(debug.segments_written, 3 * 3 * SPP);
    CHECK_INT(stats.camera_segments, 3 * 3 * SPP);
    CHECK_INT(debug.segments_overflow, 0);
    int per_pixel[9] = {0};
    uint32_t sample_seen[9] = {0};
    for (uint64_t i = 0; i < debug.segments_written && i < 1024; i++) {
        const GpuSegment *g = &segments[i];
        CHECK(g->pixel < 9);
        if (g->pixel >= 9)
            continue;
        per_pixel[g->pixel]++;
        sample_seen[g->pixel] |= 1u << g->sample_index;
        /* The chord at distance b from the centre is 2 sqrt(r^2 - b^2); b from the entry
         * point and the direction (|entry x direction| with the centre at the origin). */
        double bx = g->entry[1] * g->direction[2] - g->entry[2] * g->direction[1];
        double by = g->entry[2] * g->direction[0] - g->entry[0] * g->direction[2];
        double bz = g->entry[0] * g->direction[1] - g->entry[1] * g->direction[0];
        double b2 = bx * bx + by * by + bz * bz;
        CHECK_NEAR(dist3(g->entry, g->exit), 2 * sqrt(1.5 * 1.5 - b2), 5e-4);
        if (g->pixel == 4) /* the centre pixel: within 0.02 of the axis, 2r within 5e-4 */
            CHECK_NEAR(dist3(g->entry, g->exit), 3.0, 5e-4);
        CHECK_NEAR(
            sqrt(g->entry[0] * g->entry[0] + g->entry[1] * g->entry[1] + g->entry[2] * g->entry[2]),
            1.5, 1e-3);
        CHECK_NEAR(
            sqrt(g->exit[0] * g->exit[0] + g->exit[1] * g->exit[1] + g->exit[2] * g->exit[2]), 1.5,
            1e-3);
        CHECK_NEAR(g->direction[2], -1.0, 1e-4);
        CHECK(g->entry[2] > 1.49f && g->exit[2] < -1.49f);
        CHECK_NEAR(g->throughput[0], 1.0, 1e-6);
        CHECK_NEAR(g->throughput[1], 1.0, 1e-6);
        CHECK_INT(g->material, 0);
        CHECK_INT(g->depth & ~NS_SEGMENT_ENTERED, 1);
        CHECK(g->depth & NS_SEGMENT_ENTERED);
    }
    for (int p = 0; p < 9; p++) {
        CHECK_INT(per_pixel[p], SPP);
        CHECK_INT(sample_seen[p], (1u << SPP) - 1);
    }
    /* The same paths, attenuated: L_env exp(-sigma_t 2r). */
    CHECK_REL(pixel_at(&img, 1, 1)[0], exp(-0.6 * 3.0), 1e-3);
    CHECK_REL(pixel_at(&img, 1, 1)[1], exp(-0.25 * 3.0), 1e-3);
    CHECK_NEAR(pixel_at(&img, 1, 1)[2], 1.0, 1e-6);
    ns_image_free(&img);
}

static void test_overflow_is_counted(void)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = segment_scene(&m, &o, &l, 8);
    GpuSegment segments[16];
    ns_render_debug debug = {.segment_capacity = 10, .segments = segments, .segments_max = 16};
    ns_image img = {0};
    ns_render_stats stats = {0};
    ns_error err = {0};
    int status = ns_render_ex(test_context(), &s, &img, &stats, &debug, &err);
    CHECK_INT(status, NS_OK);
    CHECK_INT(debug.segments_written, 10);
    CHECK_INT(stats.camera_segments, 10);
    CHECK_INT(debug.segments_overflow, 8 * 8 * SPP - 10);
    /* The image is unaffected by the full buffer. */
    if (!status)
        CHECK_REL(pixel_at(&img, 4, 4)[0], exp(-0.6 * 3.0), 1e-3);
    ns_image_free(&img);
}

/* A diffuse floor under the sphere, seen through it: segments and the floor's direct light
 * both happen, and nothing is recorded for paths that miss the medium. */
static void test_no_segments_without_media(void)
{
    ns_material m = diffuse(0.5, 0.5, 0.5);
    ns_object o = sphere(0, 0, 0, 1, 0);
    ns_light l = light(NS_LIGHT_ENVIRONMENT, 1, 1, 1);
    ns_scene s = base_scene(16, 16, 20);
    set3(s.camera.position, 0, 0, 10);
    scene_lists(&s, &m, 1, &o, 1, &l, 1);
    ns_image img = {0};
    ns_render_stats stats = {0};
    if (render_ok(&s, &img, &stats))
        CHECK_INT(stats.camera_segments, 0);
    ns_image_free(&img);
}

int main(void)
{
    RUN(test_one_segment_per_sample);
    RUN(test_overflow_is_counted);
    RUN(test_no_segments_without_media);
    ns_context_destroy(test_context());
    return harness_report();
}
