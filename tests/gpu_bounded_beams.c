/* gpu_bounded_beams.c — render.vrl_beams "bounded" against the path tracer, where the
 * paper's endless beams are known to be wrong. Double scattering only: with one event on the
 * beam and one on the camera segment, both inside a convex object, the tables' infinite
 * medium is exact once the beam itself follows the object (the path between the two events
 * is a straight line inside it), so what is left between nn and pt is the tables' own
 * discretisation and the light reflected between the two events.
 *   (a) a slab half a mean free path thick, index matched, under a directional light: an
 *       endless beam keeps scattering below the slab; bounded, it ends at the far face;
 *   (b) a glass rod (ior 1.5) under a point light just above its top face: every beam meets
 *       the side walls beyond the critical angle, so the light is guided down the rod by
 *       total internal reflection, which bounded beams follow.
 * Each case checks, per channel, bounded nn within a tolerance of pt, and that endless nn is
 * off by far more (so that the scene tells the two apart). Image means over 32 x 32 pixels;
 * pt at 512 spp has a standard error near 0.5% of these means. Validation on. */
#include "gpu_util.h"

/* Mean of the double-scattering image of `s` rendered by `method` with `beams`. */
static int double_mean(ns_scene s, ns_method method, ns_vrl_beams beams, uint32_t spp,
                       double out[3])
{
    s.render.method = method;
    s.render.vrl_beams = beams;
    s.render.spp = spp;
    ns_image img = {0};
    ns_render_stats stats = {0};
    if (!render_ok(&s, &img, &stats))
        return -1;
    image_mean(&img, out);
    ns_image_free(&img);
    return 0;
}

/* bounded_tolerance: |bounded / pt - 1| allowed; endless_off: |endless / pt - 1| required.
 * nn_spp: camera paths per pixel for nn. Its gather costs in proportion to them, and where
 * the object fills the image one is enough (the image mean's noise is the VRLs'); a narrow
 * object needs more, or its edge pixels' coverage is a coin toss. */
static void compare(const char *name, ns_scene s, uint32_t nn_spp, double bounded_tolerance,
                    double endless_off)
{
    double pt[3], bounded[3], endless[3];
    if (double_mean(s, NS_METHOD_PT, NS_VRL_BEAMS_ENDLESS, 512, pt) ||
        double_mean(s, NS_METHOD_NN, NS_VRL_BEAMS_BOUNDED, nn_spp, bounded) ||
        double_mean(s, NS_METHOD_NN, NS_VRL_BEAMS_ENDLESS, nn_spp, endless))
        return;
    for (int c = 0; c < 3; c++) {
        fprintf(stderr, "  %s, channel %d: pt %.6g, nn bounded %.6g (%+.1f%%), endless %.6g (%+.1f%%)\n",
                name, c, pt[c], bounded[c], 100 * (bounded[c] / pt[c] - 1), endless[c],
                100 * (endless[c] / pt[c] - 1));
        CHECK(pt[c] > 0);
        CHECK(fabs(bounded[c] / pt[c] - 1) < bounded_tolerance);
        CHECK(fabs(endless[c] / pt[c] - 1) > endless_off);
    }
}

static ns_scene double_scene(ns_material *m, ns_object *box, ns_light *l)
{
    ns_scene s = base_scene(32, 32, 10);
    scene_lists(&s, m, 1, box, 1, l, 1);
    s.render.components = NS_COMPONENT_DOUBLE;
    s.render.vrls = 40000;
    s.render.gather_tile = 1;
    s.render.seed = 1;
    return s;
}

static void test_thin_slab(void)
{
    /* albedo 0.909 / 0.5 / 0.99 at mfp 1; the camera looks down at 30 degrees from above,
     * seeing only the slab's top face. */
    const double albedo[3] = {0.909, 0.5, 0.99};
    double sigma_s[3], sigma_a[3];
    for (int c = 0; c < 3; c++) {
        sigma_s[c] = albedo[c];
        sigma_a[c] = 1 - albedo[c];
    }
    ns_material m = medium(sigma_s, sigma_a, 1.0);
    ns_object box;
    memset(&box, 0, sizeof box);
    box.shape = NS_SHAPE_BOX;
    set3(box.min, -30, -0.5, -30);
    set3(box.max, 30, 0, 30);
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(sun.direction, 0, -1, 0);
    ns_scene s = double_scene(&m, &box, &sun);
    set3(s.camera.position, 0, 10, 17.32);
    set3(s.camera.look_at, 0, 0, 0);
    s.render.vrls = 100000; /* the slab is 60 wide: VRLs spread over all of it */
    /* The slab's image is smooth: the default adaptive gather (2 x 2 tiles) gathers about a
     * quarter of its pixels. (The rod below is 4.6 pixels wide: it gathers every one.) */
    s.render.gather_tile = 2;
    /* Measured (2026-11-29): bounded +5.5 to +5.8%, endless +33% (with the tiles +6.0 to
     * +6.2% and +34%; +2.4 to +2.7% and +27%
     * while A held each phi bin's centre line, 5% low beside a beam's start; +3.5 to +3.8%
     * before the cells beside a source's plane held A on the plane). */
    compare("slab 0.5 mfp, ior 1", s, 1, 0.08, 0.2);
}

static void test_light_guide(void)
{
    /* The glass rod (gpu_util.h), lit by a point light 0.3 above the centre of its top face:
     * the side faces are not lit, and every refracted beam meets a side wall at 52 degrees or
     * more (the critical angle is 41.8). Camera from the side. */
    ns_material m;
    ns_object box;
    glass_rod(&m, &box);
    ns_light lamp = light(NS_LIGHT_POINT, 1, 1, 1);
    set3(lamp.position, 0, 6.3, 0);
    ns_scene s = double_scene(&m, &box, &lamp);
    /* Four camera samples for the edge pixels' coverage; the gather takes one of them (the
     * coverage stays every sample's), a quarter of the gather that was most of this test. */
    s.render.gather_camera_samples = 1;
    s.camera.fov_deg = 28;
    set3(s.camera.position, 0, 3, 14);
    set3(s.camera.look_at, 0, 3, 0);
    /* Measured: bounded -6 to -8% (pt at 256 and 512 spp), endless -55%; 2026-11-29 -7.9%
     * and -54.7% (-6.5% while A held each phi bin's centre line; at 1 camera path per pixel
     * -9.1%: the rod is 4.6 pixels wide; 2026-11-30, one camera sample gathered, -8.1% and
     * -54.4%, the test 55 s to 22 s). */
    compare("glass rod, total internal reflection", s, 4, 0.12, 0.4);
}

static void test_bad_setting(void)
{
    /* Bounded beams belong to the table methods: others refuse them naming the field. */
    ns_material m = diffuse(0.5, 0.5, 0.5);
    ns_object ball = sphere(0, 0, 0, 1, 0);
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(sun.direction, 0, -1, 0);
    ns_scene s = double_scene(&m, &ball, &sun);
    set3(s.camera.position, 0, 0, 10);
    s.render.vrl_beams = NS_VRL_BEAMS_BOUNDED;
    s.render.method = NS_METHOD_DIPOLE;
    ns_error err = {0};
    CHECK_INT(ns_scene_validate(&s, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK(strstr(err.message, "render.vrl_beams") != NULL);
}

int main(void)
{
    RUN(test_thin_slab);
    RUN(test_light_guide);
    RUN(test_bad_setting);
    ns_context_destroy(test_context());
    return harness_report();
}
