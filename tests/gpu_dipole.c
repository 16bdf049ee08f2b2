/* gpu_dipole.c — method "dipole" against its closed form: a thick slab (a wide box) of a
 * scattering medium under a directional light perpendicular to its top face, seen from
 * straight above. For a semi-infinite medium the dipole's R_d integrates to the total
 * diffuse reflectance (Jensen et al. 2001, eq. 6 integrated; Jensen & Buhler 2002)
 *     R = (alpha'/2) (1 + exp(-(4/3) A sqrt(3 (1 - alpha')))) exp(-sqrt(3 (1 - alpha'))),
 * so the radiance leaving the centre is L = (1 - F(0))^2 E R / pi: the light enters with
 * the Fresnel transmittance at normal incidence, and leaves towards the camera with it. */
#include "gpu_util.h"

#define W 16
#define H 16

static double fresnel_normal(double n) { return ((n - 1) / (n + 1)) * ((n - 1) / (n + 1)); }

static void test_slab_total_reflectance(void)
{
    const double ior = 1.4, sigma_s = 40.0, sigma_a = 0.4, g = 0.5, irradiance = 2.0;
    ns_scene s = base_scene(W, H, 4);
    s.render.method = NS_METHOD_DIPOLE;
    s.render.components = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE;
    s.render.spp = 1;
    s.render.gather_tile = 1;
    s.render.vrls = 200000;
    set3(s.camera.position, 0, 12, 0.001);
    set3(s.camera.look_at, 0, 0, 0);
    set3(s.camera.up, 0, 0, -1);
    ns_material mat = medium((double[3]){sigma_s, sigma_s, sigma_s}, (double[3]){sigma_a, sigma_a, sigma_a}, ior);
    mat.g = (float)g;
    ns_object box;
    memset(&box, 0, sizeof box);
    box.shape = NS_SHAPE_BOX;
    set3(box.min, -2.5, -3, -2.5);
    set3(box.max, 2.5, 0, 2.5);
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, irradiance, irradiance, irradiance);
    set3(sun.direction, 0, -1, 0);
    scene_lists(&s, &mat, 1, &box, 1, &sun, 1);
    ns_image img = {0};
    ns_render_stats stats = {0};
    if (!render_ok(&s, &img, &stats))
        return;

    double s_reduced = sigma_s * (1 - g), t_reduced = s_reduced + sigma_a, alpha = s_reduced / t_reduced;
    double f_dr = -1.440 / (ior * ior) + 0.710 / ior + 0.668 + 0.0636 * ior;
    double a = (1 + f_dr) / (1 - f_dr), root = sqrt(3 * (1 - alpha));
    double total = alpha / 2 * (1 + exp(-4.0 / 3.0 * a * root)) * exp(-root);
    double t = 1 - fresnel_normal(ior);
    double expected = t * t * irradiance * total / M_PI;
    double mean = 0;
    for (int y = 4; y < 12; y++)
        for (int x = 4; x < 12; x++)
            mean += pixel_at(&img, x, y)[1] / 64.0;
    printf("dipole slab: R = %.5f, expected L = %.6g, rendered %.6g (%+.2f%%), %llu VRLs\n", total,
           expected, mean, 100 * (mean / expected - 1), (unsigned long long)stats.vrl_count);
    CHECK(stats.vrl_count > 100000);
    CHECK_NEAR(mean / expected, 1.0, 0.03);
    ns_image_free(&img);
}

int main(void)
{
    RUN(test_slab_total_reflectance);
    return harness_report();
}
