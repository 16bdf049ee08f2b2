/* gpu_batches.c — when the camera segments of all samples do not fit the segment buffer,
 * or the added samples (render.adaptive_spp) one buffer,
 * the render runs the samples in batches (render.c camera_and_scattering): the image must be
 * the one rendered in a single batch, for the surface and for every scattering component.
 * The buffer is made small on purpose (ns_render_debug.segment_capacity); with a gather tile
 * of 1 every segment is gathered either way, so only float summation order differs. */
#include "gpu_util.h"

#define W 24
#define H 20

static void build(ns_scene *s, ns_material mats[2], ns_object objs[2], ns_light lights[2])
{
    *s = base_scene(W, H, 35);
    s->render.components = NS_COMPONENT_SURFACE | NS_COMPONENT_SINGLE | NS_COMPONENT_DOUBLE |
                           NS_COMPONENT_MULTIPLE;
    s->render.spp = 8;
    s->render.vrls = 1500;
    s->render.gather_tile = 1;
    s->render.single_samples = 16;
    lit_medium_sphere(s, mats, objs, lights);
}

/* The scene rendered with `debug` (small buffers); 0 (with the error printed) if it failed. */
static int render_debugged(const ns_scene *s, ns_image *img, ns_render_stats *stats,
                           ns_render_debug *debug, const char *what)
{
    ns_error err = {0};
    int status = ns_render_ex(test_context(), s, img, stats, debug, &err);
    if (status)
        fprintf(stderr, "%s: %s\n", what, err.message);
    CHECK_INT(status, NS_OK);
    return status == NS_OK;
}

static void test_batches_equal_one_pass(void)
{
    ns_scene s;
    ns_material mats[2];
    ns_object objs[2];
    ns_light lights[2];
    build(&s, mats, objs, lights);
    ns_image one = {0}, batched = {0};
    ns_render_stats st1 = {0}, st2 = {0};
    if (!render_ok(&s, &one, &st1))
        return;
    /* Room for about a sample and a half: the eight samples need several batches. */
    ns_render_debug debug = {.segment_capacity = (uint32_t)(st1.camera_segments * 3 / 16)};
    if (!render_debugged(&s, &batched, &st2, &debug, "batched")) {
        ns_image_free(&one);
        return;
    }
    CHECK(st1.camera_segments > 100);
    CHECK_INT(st2.camera_segments, st1.camera_segments);
    CHECK_INT(st2.gather_segments, st1.gather_segments);
    double sum = 0, worst = 0;
    for (size_t i = 0; i < (size_t)W * H * 3; i++)
        sum += one.rgb[i];
    double mean = sum / (W * H * 3);
    for (size_t i = 0; i < (size_t)W * H * 3; i++)
        worst = fmax(worst, fabs(one.rgb[i] - batched.rgb[i]) / fmax(fabs(one.rgb[i]), 0.01 * mean));
    printf("%llu camera segments, capacity %u: worst relative difference %.2e\n",
           (unsigned long long)st1.camera_segments, debug.segment_capacity, worst);
    CHECK(worst < 1e-4);
    ns_image_free(&one);
    ns_image_free(&batched);
}

/* render.adaptive_spp's added samples, when they outnumber one buffer, go in passes of whole
 * pixels (render.c add_camera_samples): the image is the one a single pass gives, bit for
 * bit (the same samples, merged in the same order). The buffer is made small on purpose
 * (ns_render_debug.added_capacity: room for about a tenth of them). */
static void test_added_samples_in_passes(void)
{
    ns_scene s;
    ns_material mats[2];
    ns_object objs[2];
    ns_light lights[2];
    build(&s, mats, objs, lights);
    s.render.components = NS_COMPONENT_SURFACE;
    s.render.adaptive_spp = 4.0f;
    ns_image one = {0}, passes = {0};
    ns_render_stats st1 = {0}, st2 = {0};
    if (!render_ok(&s, &one, &st1))
        return;
    ns_render_debug debug = {.added_capacity = (uint32_t)(st1.adaptive_samples / 10)};
    if (!render_debugged(&s, &passes, &st2, &debug, "in passes")) {
        ns_image_free(&one);
        return;
    }
    printf("%llu added samples, in passes of at most %u\n",
           (unsigned long long)st1.adaptive_samples, debug.added_capacity);
    CHECK(st1.adaptive_samples > 1000);
    CHECK_INT(st2.adaptive_samples, st1.adaptive_samples);
    CHECK(memcmp(one.rgb, passes.rgb, sizeof(float) * 3 * W * H) == 0);
    ns_image_free(&one);
    ns_image_free(&passes);
}

int main(void)
{
    RUN(test_batches_equal_one_pass);
    RUN(test_added_samples_in_passes);
    return harness_report();
}
