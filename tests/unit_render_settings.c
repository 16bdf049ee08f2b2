/* unit_render_settings.c — the render settings' defaults live in the library
 * (ns_render_settings_resolve, render/common.c): a field left 0 takes the default nscatter.h
 * documents for it, a field given is kept (in range or not: ns_render checks it), and seed
 * gather_tolerance and single_tolerance keep their 0, which is a value of its own there. */
#include "harness.h"
#include "nscatter.h"

static void test_zero_means_default(void)
{
    ns_render_settings r = ns_render_settings_resolve((ns_render_settings){0});
    CHECK_INT(r.method, NS_METHOD_NN);
    CHECK_INT(r.components, NS_COMPONENT_SURFACE | NS_COMPONENT_SINGLE | NS_COMPONENT_DOUBLE |
                                NS_COMPONENT_MULTIPLE);
    CHECK_INT(r.spp, 1);
    CHECK_INT(r.max_depth, 8);
    CHECK_INT(r.light_samples, 2);
    CHECK_NEAR(r.adaptive_spp, 0, 0); /* none added: the parser's default is 2 at spp >= 2 */
    CHECK_NEAR(r.exposure, 0, 0);
    CHECK_INT(r.max_scatter, 0);
    CHECK_INT(r.vrls, 10000);
    CHECK_INT(r.gather_tile, 2);
    CHECK_INT(r.gather_levels, 0);
    CHECK_INT(r.gather_camera_samples, 0); /* every sample: the parser's default is 1 */
    CHECK_INT(r.single_samples, 64);
    CHECK_INT(r.single_levels, 0);
    CHECK_INT(r.accumulation, NS_ACCUMULATION_EXACT);
    CHECK_INT(r.tables, NS_TABLES_EXACT);
    CHECK_INT(r.vrl_beams, NS_VRL_BEAMS_ENDLESS);
    CHECK_NEAR(r.cull_solid_angle, 0, 0);
    /* 0 is a seed and a tolerance like any other: kept, not replaced. */
    CHECK_INT(r.seed, 0);
    CHECK_NEAR(r.gather_tolerance, 0, 0);
    CHECK_NEAR(r.single_tolerance, 0, 0);
}

static void test_given_fields_are_kept(void)
{
    ns_render_settings given = {
        .method = NS_METHOD_VRL,
        .components = NS_COMPONENT_MULTIPLE,
        .spp = 5000, /* out of range: kept for ns_render to refuse, naming it */
        .seed = 9,
        .max_depth = 3,
        .light_samples = 5,
        .adaptive_spp = 70.0f, /* out of range: kept for ns_render to refuse */
        .exposure = -2,
        .vrls = 7,
        .gather_tile = 1,
        .gather_levels = 2,
        .gather_tolerance = 0.5f,
        .gather_camera_samples = 2,
        .single_samples = 4,
        .single_levels = 3,
        .single_tolerance = 0.25f,
        .accumulation = NS_ACCUMULATION_PAPER,
        .tables = NS_TABLES_INTERPOLATED,
        .cull_solid_angle = 0.1f,
    };
    ns_render_settings r = ns_render_settings_resolve(given);
    CHECK(memcmp(&r, &given, sizeof r) == 0);
    /* Resolving twice changes nothing. */
    ns_render_settings twice = ns_render_settings_resolve(ns_render_settings_resolve((ns_render_settings){0}));
    ns_render_settings once = ns_render_settings_resolve((ns_render_settings){0});
    CHECK(memcmp(&twice, &once, sizeof once) == 0);
}

int main(void)
{
    RUN(test_zero_means_default);
    RUN(test_given_fields_are_kept);
    return harness_report();
}
