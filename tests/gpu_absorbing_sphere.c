/* gpu_absorbing_sphere.c — Fresnel boundaries and Beer-Lambert against closed forms.
 *
 * A purely absorbing sphere (sigma_s 0, radius r, ior n) in a uniform environment L_env,
 * seen through its centre: the light reflected at the front (R) plus the light that enters,
 * crosses the sphere any odd number of times and leaves, each crossing attenuated by
 * T = exp(-2 sigma_a r) and each internal reflection by R:
 *   L = L_env (R + (1 - R)^2 T / (1 - R T)),  R = ((n - 1) / (n + 1))^2.
 * Also: total internal reflection, and index-matched spheres (no Fresnel at all). */
#include "gpu_util.h"

static const double env[3] = {1.0, 2.0, 3.0};

static ns_scene sphere_scene(ns_material *m, ns_object *o, ns_light *l, uint32_t size, double fov)
{
    ns_scene s = base_scene(size, size, fov);
    set3(s.camera.position, 0, 0, 10);
    set3(s.camera.look_at, 0, 0, 0);
    s.render.max_depth = 32;
    *o = sphere(0, 0, 0, 1.0, 0);
    *l = light(NS_LIGHT_ENVIRONMENT, env[0], env[1], env[2]);
    scene_lists(&s, m, 1, o, 1, l, 1);
    return s;
}

/* Fresnel reflectance at normal incidence. */
static double normal_reflectance(double ior)
{
    double r = (ior - 1) / (ior + 1);
    return r * r;
}

static double closed_form(double ior, double sigma_a, double r)
{
    double R = normal_reflectance(ior);
    double T = exp(-2 * sigma_a * r);
    return R + (1 - R) * (1 - R) * T / (1 - R * T);
}

static void check_centre(double ior, uint32_t max_depth, double tol)
{
    const double sigma_s[3] = {0, 0, 0}, sigma_a[3] = {0.1, 0.5, 2.0};
    ns_material m = medium(sigma_s, sigma_a, ior);
    ns_object o;
    ns_light l;
    ns_scene s = sphere_scene(&m, &o, &l, 33, 2.0);
    s.render.max_depth = max_depth;
    ns_image img = {0};
    ns_render_stats stats = {0};
    if (!render_ok(&s, &img, &stats))
        return;
    for (int k = 0; k < 3; k++)
        CHECK_REL(pixel_at(&img, 16, 16)[k], env[k] * closed_form(ior, sigma_a[k], 1.0), tol);
    /* A 2 degree view at 10 units is 0.35 units wide: every pixel sees the sphere, so every
     * sample recorded at least one stretch inside it. */
    CHECK(stats.camera_segments >= (uint64_t)33 * 33 * s.render.spp);
    ns_image_free(&img);
}

static void test_glass_1_5(void)
{
    check_centre(1.5, 32, 1e-3);
}
static void test_glass_2_4(void)
{
    check_centre(2.4, 32, 1e-3);
}

/* Weak branches (throughput below NS_MIN_SEGMENT_THROUGHPUT in every channel) play Russian
 * roulette (camera.comp): an interior so absorbing that the light crossing it once is below
 * 1e-3 in every channel keeps its part of the pixel, (1 - R)^2 T (0.1-0.8% of it), in
 * expectation. Dropping those branches fails by all of it; the roulette's noise at 4,096
 * samples is about 2.5% of it (the tolerance is 12%). */
static void test_weak_branches_keep_their_light(void)
{
    const double ior = 1.5, sigma_s[3] = {0, 0, 0}, sigma_a[3] = {4.0, 4.5, 5.0};
    ns_material m = medium(sigma_s, sigma_a, ior);
    ns_object o;
    ns_light l;
    ns_scene s = sphere_scene(&m, &o, &l, 3, 0.5);
    s.render.spp = 4096;
    ns_image img = {0};
    ns_render_stats stats = {0};
    if (!render_ok(&s, &img, &stats))
        return;
    /* The same segments as without the roulette: each sample records its entry stretch and
     * nothing after (the reflected one at the back is below 1e-3, and a branch that survives
     * the roulette must not record). */
    CHECK_INT(stats.camera_segments, 9 * 4096);
    double R = normal_reflectance(ior);
    CHECK((1 - R) * exp(-2 * sigma_a[0]) < 1e-3); /* every channel is weak when it exits */
    for (int k = 0; k < 3; k++) {
        double T = exp(-2 * sigma_a[k]), weak = env[k] * (1 - R) * (1 - R) * T;
        double got = pixel_at(&img, 1, 1)[k], want = env[k] * closed_form(ior, sigma_a[k], 1.0);
        if (k == 0)
            printf("weak branches: the pixel %.7f, closed form %.7f, of which %.7f through the "
                   "weak branches\n",
                   got, want, weak);
        CHECK_NEAR(got, want, 0.12 * weak);
    }
    ns_image_free(&img);
}

/* max_depth cuts the series: with depth 2 only the front reflection and the first exit
 * (entry = bounce 1, exit = bounce 2) count: L = R + (1 - R)^2 T. */
static void test_depth_truncates_series(void)
{
    const double ior = 2.4, sigma_s[3] = {0, 0, 0}, sigma_a[3] = {0.1, 0.5, 2.0};
    ns_material m = medium(sigma_s, sigma_a, ior);
    ns_object o;
    ns_light l;
    ns_scene s = sphere_scene(&m, &o, &l, 33, 2.0);
    s.render.max_depth = 2;
    ns_image img = {0};
    if (!render_ok(&s, &img, NULL))
        return;
    double R = normal_reflectance(ior);
    for (int k = 0; k < 3; k++) {
        double T = exp(-2 * sigma_a[k]);
        CHECK_REL(pixel_at(&img, 16, 16)[k], env[k] * (R + (1 - R) * (1 - R) * T), 1e-3);
    }
    ns_image_free(&img);
}

/* Index matched (ior 1): no reflection, just T; with sigma_t 0 the sphere is invisible. */
static void test_index_matched(void)
{
    const double sigma_s[3] = {0.3, 0.0, 0.0}, sigma_a[3] = {0.2, 0.4, 0.0};
    ns_material m = medium(sigma_s, sigma_a, 1.0);
    ns_object o;
    ns_light l;
    ns_scene s = sphere_scene(&m, &o, &l, 33, 2.0);
    ns_image img = {0};
    if (!render_ok(&s, &img, NULL))
        return;
    for (int k = 0; k < 3; k++) {
        double sigma_t = sigma_s[k] + sigma_a[k];
        CHECK_REL(pixel_at(&img, 16, 16)[k], env[k] * exp(-2 * sigma_t), 1e-3);
    }
    CHECK_NEAR(pixel_at(&img, 16, 16)[2], env[2], 1e-6); /* sigma_t 0: exactly L_env */
    ns_image_free(&img);
}

/* The sphere's silhouette region: outside the sphere the environment exactly; a wide view
 * also shows the sphere darker than the environment in every channel (absorbing). */
static void test_background_and_silhouette(void)
{
    const double sigma_s[3] = {0, 0, 0}, sigma_a[3] = {0.1, 0.5, 2.0};
    ns_material m = medium(sigma_s, sigma_a, 1.5);
    ns_object o;
    ns_light l;
    ns_scene s = sphere_scene(&m, &o, &l, 64, 30.0);
    ns_image img = {0};
    if (!render_ok(&s, &img, NULL))
        return;
    for (int k = 0; k < 3; k++) {
        CHECK_NEAR(pixel_at(&img, 0, 0)[k], env[k], 1e-6);
        CHECK_NEAR(pixel_at(&img, 63, 40)[k], env[k], 1e-6);
        CHECK(pixel_at(&img, 32, 32)[k] < env[k]);
    }
    ns_image_free(&img);
}

/* Unpolarised Fresnel reflectance from air into a dielectric of index n at incidence cos_i
 * (written from the Fresnel equations in their n1/n2 form). */
static double fresnel_air(double cos_i, double n)
{
    double sin_t = sqrt(1 - cos_i * cos_i) / n, cos_t = sqrt(1 - sin_t * sin_t);
    double rs = (cos_i - n * cos_t) / (cos_i + n * cos_t);
    double rp = (n * cos_i - cos_t) / (n * cos_i + cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

/* An (almost) black interior, sigma_a 50: every pixel shows only the reflection at the
 * front surface, L_env R(theta_i), which rises from 4% at the centre towards 1 at the rim. */
static void test_fresnel_angular(void)
{
    const double ior = 1.5, sigma_s[3] = {0, 0, 0}, sigma_a[3] = {50, 50, 50};
    ns_material m = medium(sigma_s, sigma_a, ior);
    ns_object o;
    ns_light l;
    ns_scene s = sphere_scene(&m, &o, &l, 129, 14.0);
    s.camera.height = 1; /* one row through the centre */
    s.render.spp = 64;
    ns_image img = {0};
    if (!render_ok(&s, &img, NULL))
        return;
    int checked = 0;
    double strongest = 0;
    for (uint32_t x = 64; x < 129; x++) {
        double d[3];
        camera_ray(&s.camera, (x + 0.5) / 129.0, 0.5, d);
        /* Incidence from the ray's distance to the centre: b = |o x d| = sin(theta_i) * r. */
        double cx = s.camera.position[1] * d[2] - s.camera.position[2] * d[1];
        double cy = s.camera.position[2] * d[0] - s.camera.position[0] * d[2];
        double cz = s.camera.position[0] * d[1] - s.camera.position[1] * d[0];
        double sin_i = sqrt(cx * cx + cy * cy + cz * cz);
        if (sin_i > 0.9)
            break; /* near the rim R changes too fast across one pixel for a point check */
        double want = env[0] * fresnel_air(sqrt(1 - sin_i * sin_i), ior);
        CHECK_REL(pixel_at(&img, x, 0)[0], want, 0.01);
        strongest = want;
        checked++;
    }
    CHECK(checked > 30);
    CHECK(strongest > 0.1 * env[0]); /* the check reached the steep part of R */
    ns_image_free(&img);
}

/* The 12 triangles of the cube [-h, h]^3, counter-clockwise seen from outside. */
static void cube_triangles(double h, ns_triangle tris[12])
{
    static const int faces[6][4][3] = {
        {{1, -1, -1}, {1, 1, -1}, {1, 1, 1}, {1, -1, 1}},
        {{-1, -1, -1}, {-1, -1, 1}, {-1, 1, 1}, {-1, 1, -1}},
        {{-1, 1, -1}, {-1, 1, 1}, {1, 1, 1}, {1, 1, -1}},
        {{-1, -1, -1}, {1, -1, -1}, {1, -1, 1}, {-1, -1, 1}},
        {{-1, -1, 1}, {1, -1, 1}, {1, 1, 1}, {-1, 1, 1}},
        {{-1, -1, -1}, {-1, 1, -1}, {1, 1, -1}, {1, -1, -1}},
    };
    for (int f = 0; f < 6; f++)
        for (int t = 0; t < 2; t++) {
            const int *v[3] = {faces[f][0], faces[f][1 + t], faces[f][2 + t]};
            for (int i = 0; i < 3; i++)
                set3(tris[2 * f + t].v[i], h * v[i][0], h * v[i][1], h * v[i][2]);
        }
}

/* The same series through a glass box (primitive) and a glass cube mesh (closed triangles,
 * inside known from their facing), seen face-on: chord = the box's width. */
static void test_glass_box_and_cube_mesh(void)
{
    const double ior = 1.5, h = 0.8, sigma_s[3] = {0, 0, 0}, sigma_a[3] = {0.1, 0.5, 2.0};
    ns_triangle tris[12] = {0};
    cube_triangles(h, tris);
    for (int mesh = 0; mesh < 2; mesh++) {
        ns_material m = medium(sigma_s, sigma_a, ior);
        ns_object o;
        ns_light l;
        ns_scene s = sphere_scene(&m, &o, &l, 33, 2.0);
        memset(&o, 0, sizeof o);
        if (mesh) {
            o.shape = NS_SHAPE_MESH;
            o.triangle_count = 12;
            s.triangles = tris;
            s.triangle_count = 12;
        } else {
            o.shape = NS_SHAPE_BOX;
            set3(o.min, -h, -h, -h);
            set3(o.max, h, h, h);
        }
        ns_image img = {0};
        if (!render_ok(&s, &img, NULL))
            return;
        for (int k = 0; k < 3; k++) {
            double R = 0.04, T = exp(-2 * h * sigma_a[k]);
            CHECK_REL(pixel_at(&img, 16, 16)[k], env[k] * (R + (1 - R) * (1 - R) * T / (1 - R * T)),
                      1e-3);
        }
        ns_image_free(&img);
    }
}

int main(void)
{
    RUN(test_glass_box_and_cube_mesh);
    RUN(test_glass_1_5);
    RUN(test_glass_2_4);
    RUN(test_depth_truncates_series);
    RUN(test_weak_branches_keep_their_light);
    RUN(test_index_matched);
    RUN(test_background_and_silhouette);
    RUN(test_fresnel_angular);
    ns_context_destroy(test_context());
    return harness_report();
}
