/* gpu_scatter_units.c — the scattering stages keep their units straight: scaling a scene
 * by k (positions, sizes, the camera) and its coefficients by 1/k leaves the image unchanged,
 * for every component of method nn (single, double, multiple) and for the dipole, with a
 * point light whose intensity is scaled by k^2 (its irradiance falls as 1/d^2) and a
 * directional light (irradiance unchanged). The VRLs and the table bins are the same in mfp
 * units, so those images agree to float rounding; a wrong power of s anywhere (s^2 in the
 * gather, s^3 in J_world, the distance density along a segment) would change them by k^n.
 * Single scattering jitters its points along a segment from a hash of the segment's entry
 * point, which the scaling changes, so it takes the most samples there are: its jitter then
 * moves the image by about 2e-4 of its mean (measured), under the 2e-3 allowed. */
#include "gpu_util.h"

#define W 40
#define H 32

static void build(ns_scene *s, ns_material mats[2], ns_object objs[2], ns_light lights[2], double k,
                  ns_method method, uint32_t components)
{
    *s = base_scene(W, H, 35);
    s->render.method = method;
    s->render.components = components;
    s->render.spp = 1;
    s->render.vrls = 4000;
    s->render.single_samples = NS_MAX_SINGLE_SAMPLES;
    set3(s->camera.position, 0, 1.2 * k, 5 * k);
    set3(s->camera.look_at, 0, 0, 0);
    mats[0] = diffuse(0.5, 0.5, 0.5);
    double sigma_s[3] = {3.0 / k, 2.0 / k, 1.2 / k}, sigma_a[3] = {0.02 / k, 0.05 / k, 0.1 / k};
    mats[1] = medium(sigma_s, sigma_a, 1.3);
    mats[1].g = 0.3f;
    objs[0] = plane(-1.0 * k, 0);
    objs[1] = sphere(0, 0, 0, 1.0 * k, 1);
    lights[0] = light(NS_LIGHT_DIRECTIONAL, 1.5, 1.4, 1.3);
    set3(lights[0].direction, 0.3 / 1.1446, -1 / 1.1446, -0.4 / 1.1446);
    lights[1] = light(NS_LIGHT_POINT, 4 * k * k, 4 * k * k, 4 * k * k);
    set3(lights[1].position, 1.5 * k, 2.5 * k, 1.0 * k);
    scene_lists(s, mats, 2, objs, 2, lights, 2);
}

static void check_scale_invariance(ns_method method, uint32_t components, const char *what)
{
    ns_scene a, b;
    ns_material ma[2], mb[2];
    ns_object oa[2], ob[2];
    ns_light la[2], lb[2];
    build(&a, ma, oa, la, 1.0, method, components);
    build(&b, mb, ob, lb, 3.0, method, components);
    ns_image ia = {0}, ib = {0};
    ns_render_stats sa = {0}, sb = {0};
    if (!render_ok(&a, &ia, &sa) || !render_ok(&b, &ib, &sb))
        return;
    double sum = 0, diff = 0, worst = 0;
    for (size_t i = 0; i < (size_t)W * H * 3; i++) {
        sum += fabs(ia.rgb[i]);
        diff += fabs(ia.rgb[i] - ib.rgb[i]);
    }
    double mean = sum / (W * H * 3);
    for (size_t i = 0; i < (size_t)W * H * 3; i++)
        worst = fmax(worst, fabs(ia.rgb[i] - ib.rgb[i]) / fmax(fabs(ia.rgb[i]), 0.1 * mean));
    printf("%s: mean %.4g, mean |difference| / mean %.2e, worst pixel %.2e\n", what, mean,
           diff / sum, worst);
    CHECK(mean > 1e-4);
    CHECK(diff / sum < 2e-3);
    CHECK(worst < 2e-2);
    ns_image_free(&ia);
    ns_image_free(&ib);
}

static void test_single(void) { check_scale_invariance(NS_METHOD_NN, NS_COMPONENT_SINGLE, "nn single"); }
static void test_double_multiple(void)
{
    check_scale_invariance(NS_METHOD_NN, NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE, "nn double+multiple");
}
static void test_dipole(void)
{
    check_scale_invariance(NS_METHOD_DIPOLE, NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE, "dipole");
}

int main(void)
{
    RUN(test_single);
    RUN(test_double_multiple);
    RUN(test_dipole);
    return harness_report();
}
