/* gpu_render_defaults.c — ns_render gives the settings a caller left 0 their defaults
 * (ns_render_settings_resolve): a scene with every setting but the seed left 0 renders the
 * very image (every float equal) and counts of the same scene with the defaults written out,
 * for all four components of the default method. */
#include "gpu_util.h"

static ns_material mats[2];
static ns_object objs[2];
static ns_light lights[2];

static ns_scene scene_with(ns_render_settings settings)
{
    ns_scene s = base_scene(16, 12, 35);
    s.render = settings;
    lit_medium_sphere(&s, mats, objs, lights);
    return s;
}

static void test_zero_settings_render_the_defaults(void)
{
    ns_scene left = scene_with((ns_render_settings){.seed = 7});
    ns_scene written = scene_with((ns_render_settings){
        .method = NS_METHOD_NN,
        .components = NS_COMPONENT_SURFACE | NS_COMPONENT_SINGLE | NS_COMPONENT_DOUBLE |
                      NS_COMPONENT_MULTIPLE,
        .spp = 1,
        .seed = 7,
        .max_depth = 8,
        .light_samples = 2,
        .vrls = 10000,
        .gather_tile = 2,
        .single_samples = 64,
    });
    ns_image a = {0}, b = {0};
    ns_render_stats sa = {0}, sb = {0};
    if (render_ok(&left, &a, &sa) && render_ok(&written, &b, &sb)) {
        CHECK(memcmp(a.rgb, b.rgb, sizeof(float) * 3 * a.width * a.height) == 0);
        CHECK_INT(sa.camera_segments, sb.camera_segments);
        CHECK_INT(sa.vrl_paths, 10000);
        CHECK_INT(sa.vrl_count, sb.vrl_count);
        CHECK_INT(sa.gather_segments, sb.gather_segments);
        CHECK_INT(sa.interactions, sb.interactions);
        double mean[3];
        image_mean(&a, mean);
        CHECK(mean[0] > 0); /* something was rendered */
    }
    ns_image_free(&a);
    ns_image_free(&b);
}

int main(void)
{
    RUN(test_zero_settings_render_the_defaults);
    return harness_report();
}
