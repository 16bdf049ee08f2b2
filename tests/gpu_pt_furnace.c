/* gpu_pt_furnace.c — the reference path tracer (render.method "pt") in a white furnace:
 * a closed, non-absorbing medium (albedo 1) in a uniform environment must look exactly
 * like the environment, index matched or behind a dielectric boundary (ior 1.5), with
 * equal or per-channel extinction (hero-channel MIS), optically thin or 300 mean free
 * paths thick (paths resumed across dispatches), and the per-order images
 * (components surface/single/double/multiple) must add up to the full one path for path.
 * Also: the scattering-order limit, seed determinism, and the order arithmetic. */
#include "gpu_util.h"
#include "pt.h"

#define SIDE 16 /* image side: a 16x16 image all inside the sphere's silhouette */

/* Camera 4 units from a unit sphere, fov narrow enough that every pixel sees the sphere
 * (half-angle 9 deg < asin(1/4) = 14.5 deg). */
static ns_scene furnace_scene(ns_material *m, ns_object *o, ns_light *l, const double sigma_s[3],
                              double ior, double g)
{
    ns_scene s = base_scene(SIDE, SIDE, 18);
    set3(s.camera.position, 0, 0, 4);
    *m = medium(sigma_s, (double[3]){0, 0, 0}, ior);
    m->g = (float)g;
    *o = sphere(0, 0, 0, 1, 0);
    *l = light(NS_LIGHT_ENVIRONMENT, 1.0, 0.5, 0.25);
    scene_lists(&s, m, 1, o, 1, l, 1);
    s.render.method = NS_METHOD_PT;
    s.render.components = NS_COMPONENT_ALL;
    s.render.spp = 8;
    return s;
}

static const double env[3] = {1.0, 0.5, 0.25};

/* Largest |pixel / env - 1| over the image and channels. */
static double furnace_max_error(const ns_image *img)
{
    double worst = 0;
    for (size_t i = 0; i < (size_t)img->width * img->height; i++)
        for (int c = 0; c < 3; c++) {
            double e = fabs(img->rgb[3 * i + c] / env[c] - 1.0);
            if (!(e <= worst))
                worst = e; /* NaN propagates into the check */
        }
    return worst;
}

/* Equal extinction in the three channels: every path's weight stays exactly 1 (sigma_s /
 * sigma_t = 1 at each event, Fresnel choices unweighted), so every sample returns the
 * environment and the image has no noise at all. */
static void test_furnace_exact(double ior, double g)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = furnace_scene(&m, &o, &l, (double[3]){2, 2, 2}, ior, g);
    ns_image img;
    if (render_ok(&s, &img, NULL)) {
        double worst = furnace_max_error(&img);
        if (worst > 1e-4)
            fprintf(stderr, "  ior %.2f g %.2f: worst relative error %.3g\n", ior, g, worst);
        CHECK_NEAR(worst, 0.0, 1e-4);
    }
    ns_image_free(&img);
}

static void test_furnace_index_matched(void)
{
    test_furnace_exact(1.0, 0.0);
    test_furnace_exact(1.0, 0.7);
}

static void test_furnace_dielectric(void)
{
    test_furnace_exact(1.5, 0.0);
    test_furnace_exact(1.5, -0.5);
}

/* The furnace's environment replaced by a sphere light of radius 10 around everything:
 * scattering events inside a light's sphere cannot sample it, so the light must count
 * when a path hits it; every pixel is its radiance, exactly. */
static void test_furnace_inside_sphere_light(void)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = furnace_scene(&m, &o, &l, (double[3]){2, 2, 2}, 1.5, 0.5);
    l = light(NS_LIGHT_SPHERE, env[0], env[1], env[2]);
    l.radius = 10;
    ns_image img;
    if (render_ok(&s, &img, NULL))
        CHECK_NEAR(furnace_max_error(&img), 0.0, 1e-4);
    ns_image_free(&img);
}

/* An optically huge furnace (radius 300 mean free paths, albedo 1): paths take thousands
 * of scattering events, far past what one lavapipe invocation may loop, so they are
 * suspended and resumed across many dispatches. Still exactly the environment. */
static void test_dense_medium(void)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = furnace_scene(&m, &o, &l, (double[3]){300, 300, 300}, 1.5, 0.0);
    s.camera.width = s.camera.height = 8;
    s.render.spp = 2;
    ns_image img;
    if (render_ok(&s, &img, NULL))
        CHECK_NEAR(furnace_max_error(&img), 0.0, 1e-4);
    ns_image_free(&img);
}

/* Per-channel extinction (1, 1.5, 2.5): distances are sampled with one channel, weighted by
 * the balance heuristic; the image is noisy but its mean is the environment. */
static void test_furnace_chromatic(void)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = furnace_scene(&m, &o, &l, (double[3]){1, 1.5, 2.5}, 1.5, 0.3);
    s.render.spp = 256;
    ns_image img;
    if (render_ok(&s, &img, NULL)) {
        size_t n = (size_t)SIDE * SIDE;
        for (int c = 0; c < 3; c++) {
            double sum = 0, sum2 = 0;
            for (size_t i = 0; i < n; i++) {
                double v = img.rgb[3 * i + c] / env[c];
                sum += v;
                sum2 += v * v;
            }
            double mean = sum / n, sd = sqrt(fmax(0, sum2 / n - mean * mean));
            double se = sd / sqrt((double)n);
            fprintf(stderr, "  channel %d: mean %.4f, pixel sd %.4f, standard error %.4f\n", c,
                    mean, sd, se);
            CHECK(se < 0.02); /* the check below has teeth */
            CHECK(sd > 1e-4); /* the weights really vary: MIS is exercised */
            CHECK_NEAR(mean, 1.0, 4 * se + 1e-3);
        }
    }
    ns_image_free(&img);
}

/* The orders partition the paths: with the same seed every path takes the same random
 * numbers until an order's limit cuts it, so surface + single + double + multiple equals
 * the full image pixel for pixel (up to float summation). */
static void test_orders_add_up(void)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = furnace_scene(&m, &o, &l, (double[3]){1, 2, 4}, 1.5, 0.3);
    s.render.spp = 4;
    ns_image full, part[4];
    memset(part, 0, sizeof part);
    int ok = render_ok(&s, &full, NULL);
    for (int k = 0; k < 4 && ok; k++) {
        s.render.components = 1u << k;
        ok = render_ok(&s, &part[k], NULL);
    }
    if (ok) {
        double worst = 0, energy[4] = {0};
        for (size_t i = 0; i < (size_t)SIDE * SIDE * 3; i++) {
            double sum = 0;
            for (int k = 0; k < 4; k++) {
                sum += part[k].rgb[i];
                energy[k] += part[k].rgb[i];
            }
            worst = fmax(worst, fabs(sum - full.rgb[i]));
        }
        CHECK_NEAR(worst, 0.0, 1e-4);
        for (int k = 0; k < 4; k++)
            CHECK(energy[k] > 0); /* optical radius 1-4: every order carries light */
        fprintf(stderr, "  energy by order: surface %.1f single %.1f double %.1f multiple %.1f\n",
                energy[0], energy[1], energy[2], energy[3]);
    }
    ns_image_free(&full);
    for (int k = 0; k < 4; k++)
        ns_image_free(&part[k]);
}

/* max_scatter 2 with every component = surface + single + double. */
static void test_max_scatter(void)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = furnace_scene(&m, &o, &l, (double[3]){2, 2, 2}, 1.0, 0.0);
    s.render.spp = 4;
    s.render.max_scatter = 2;
    ns_image limited, orders;
    int ok = render_ok(&s, &limited, NULL);
    s.render.max_scatter = 0;
    s.render.components = NS_COMPONENT_SURFACE | NS_COMPONENT_SINGLE | NS_COMPONENT_DOUBLE;
    ok = ok && render_ok(&s, &orders, NULL);
    if (ok) {
        double worst = 0, sum = 0;
        for (size_t i = 0; i < (size_t)SIDE * SIDE * 3; i++) {
            worst = fmax(worst, fabs(limited.rgb[i] - orders.rgb[i]));
            sum += limited.rgb[i];
        }
        CHECK_NEAR(worst, 0.0, 1e-6);
        /* Optical radius 2: a good part of the light scatters 3 times or more. */
        CHECK(sum / (SIDE * SIDE * (1.0 + 0.5 + 0.25)) < 0.9);
    }
    ns_image_free(&limited);
    ns_image_free(&orders);
}

static void test_seed_determinism(void)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = furnace_scene(&m, &o, &l, (double[3]){1, 2, 4}, 1.5, 0.3);
    s.render.spp = 2;
    ns_image a, b, c;
    int ok = render_ok(&s, &a, NULL) && render_ok(&s, &b, NULL);
    s.render.seed = 8;
    ok = ok && render_ok(&s, &c, NULL);
    if (ok) {
        size_t bytes = (size_t)SIDE * SIDE * 3 * sizeof(float);
        CHECK(memcmp(a.rgb, b.rgb, bytes) == 0);
        CHECK(memcmp(a.rgb, c.rgb, bytes) != 0);
    }
    ns_image_free(&a);
    ns_image_free(&b);
    ns_image_free(&c);
}

static void test_max_events(void)
{
    const uint32_t all =
        NS_COMPONENT_ALL;
    CHECK_INT(ns_pt_max_events(all, 0), NS_NONE);
    CHECK_INT(ns_pt_max_events(all, 5), 5);
    CHECK_INT(ns_pt_max_events(NS_COMPONENT_SURFACE, 0), 0);
    CHECK_INT(ns_pt_max_events(NS_COMPONENT_SINGLE, 0), 1);
    CHECK_INT(ns_pt_max_events(NS_COMPONENT_SINGLE | NS_COMPONENT_DOUBLE, 0), 2);
    CHECK_INT(ns_pt_max_events(NS_COMPONENT_DOUBLE, 1), 1);
    CHECK_INT(ns_pt_max_events(NS_COMPONENT_MULTIPLE, 3), 3);
    CHECK_INT(ns_unsupported_components(NS_METHOD_PT, all), 0);
}

int main(void)
{
    RUN(test_max_events);
    RUN(test_furnace_index_matched);
    RUN(test_furnace_dielectric);
    RUN(test_furnace_inside_sphere_light);
    RUN(test_furnace_chromatic);
    RUN(test_dense_medium);
    RUN(test_orders_add_up);
    RUN(test_max_scatter);
    RUN(test_seed_determinism);
    ns_context_destroy(test_context());
    return harness_report();
}
