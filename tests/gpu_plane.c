/* gpu_plane.c — known answers for diffuse surfaces under each light type:
 *   directional: L = rho E cos(theta) / pi at every pixel that sees the plane, the
 *                environment radiance (or exactly 0) at every pixel that sees the sky;
 *   point:       L = rho/pi I cos / d^2 below the light;
 *   sphere:      L = rho Le (R / h)^2 below the light (E = pi Le sin^2 alpha);
 *   environment: L = rho L_env on an unoccluded plane. */
#include "gpu_util.h"

static const double rho[3] = {0.2, 0.5, 0.8};

/* Which pixels see the plane y = 0 for all four corners, and which see only sky. */
static int pixel_class(const ns_camera *c, uint32_t x, uint32_t y)
{
    int down = 0, up = 0;
    for (int corner = 0; corner < 4; corner++) {
        double d[3];
        camera_ray(c, (x + (corner & 1)) / (double)c->width,
                   (y + (corner >> 1)) / (double)c->height, d);
        if (d[1] < -1e-3)
            down++;
        else if (d[1] > 1e-3)
            up++;
    }
    return down == 4 ? 1 : up == 4 ? -1 : 0;
}

static void check_directional(double theta_deg, int with_environment)
{
    const double E[3] = {2.0, 3.0, 4.0}, env[3] = {0.3, 0.6, 0.9};
    ns_scene s = base_scene(48, 32, 90);
    set3(s.camera.position, 0, 1, 0);
    set3(s.camera.look_at, 0, 0.7, -1);
    ns_material m = diffuse(rho[0], rho[1], rho[2]);
    ns_object floor = plane(0, 0);
    ns_light lights[2] = {light(NS_LIGHT_DIRECTIONAL, E[0], E[1], E[2]),
                          light(NS_LIGHT_ENVIRONMENT, env[0], env[1], env[2])};
    double th = theta_deg * M_PI / 180;
    set3(lights[0].direction, -sin(th), -cos(th), 0); /* travels down, tilted by theta */
    scene_lists(&s, &m, 1, &floor, 1, lights, with_environment ? 2 : 1);

    ns_image img = {0};
    ns_render_stats stats = {0};
    if (!render_ok(&s, &img, &stats))
        return;
    double cos_t = cos(th) > 0 ? cos(th) : 0;
    int ground = 0, sky = 0, bad = 0;
    for (uint32_t y = 0; y < img.height; y++)
        for (uint32_t x = 0; x < img.width; x++) {
            int cls = pixel_class(&s.camera, x, y);
            const float *p = pixel_at(&img, x, y);
            for (int k = 0; k < 3 && cls; k++) {
                double L_env = with_environment ? env[k] : 0.0;
                double want = cls > 0 ? rho[k] * (E[k] * cos_t / M_PI + L_env) : L_env;
                if (!(fabs(p[k] - want) <= 2e-5 + 2e-5 * want)) {
                    if (bad++ < 5)
                        fprintf(stderr, "pixel (%u,%u)[%d] = %.7g, expected %.7g\n", x, y, k, p[k],
                                want);
                }
            }
            ground += cls > 0;
            sky += cls < 0;
        }
    CHECK_INT(bad, 0);
    CHECK(ground > 300); /* the test looked at both kinds of pixel */
    CHECK(sky > 300);
    CHECK_INT(stats.camera_segments, 0);
    ns_image_free(&img);
}

static void test_directional_45(void)
{
    check_directional(45, 0);
}
static void test_directional_70_environment(void)
{
    check_directional(70, 1);
}
static void test_directional_from_below_is_dark(void)
{
    check_directional(120, 0);
}

/* A point light of intensity I at height h above the plane, seen from the side. */
static void test_point_light(void)
{
    const double I[3] = {10, 20, 5}, h = 2.0;
    ns_scene s = base_scene(33, 33, 2);
    set3(s.camera.position, 3, 4, 0);
    set3(s.camera.look_at, 0, 0, 0);
    ns_material m = diffuse(rho[0], rho[1], rho[2]);
    ns_object floor = plane(0, 0);
    ns_light l = light(NS_LIGHT_POINT, I[0], I[1], I[2]);
    set3(l.position, 0, h, 0);
    scene_lists(&s, &m, 1, &floor, 1, &l, 1);
    ns_image img = {0};
    if (!render_ok(&s, &img, NULL))
        return;
    const float *p = pixel_at(&img, 16, 16);
    for (int k = 0; k < 3; k++)
        CHECK_REL(p[k], rho[k] / M_PI * I[k] / (h * h), 2e-3);
    /* A pixel off centre: its own cos / d^2 from the ray through its centre. */
    double d[3];
    camera_ray(&s.camera, 0.5 / 33, 0.5 / 33, d);
    double t = -s.camera.position[1] / d[1];
    double q[3] = {s.camera.position[0] + t * d[0], 0, s.camera.position[2] + t * d[2]};
    double d2 = q[0] * q[0] + h * h + q[2] * q[2];
    double cos_l = h / sqrt(d2);
    for (int k = 0; k < 3; k++)
        CHECK_REL(pixel_at(&img, 0, 0)[k], rho[k] / M_PI * I[k] * cos_l / d2, 5e-3);
    ns_image_free(&img);
}

/* A sphere light of radiance Le and radius R at height h; the camera also sees it. */
static void test_sphere_light(void)
{
    const double Le[3] = {40, 20, 10}, h = 2.0, R = 0.5;
    ns_scene s = base_scene(33, 33, 1);
    set3(s.camera.position, 3, 3, 0);
    set3(s.camera.look_at, 0, 0, 0);
    s.render.spp = 256;
    ns_material m = diffuse(rho[0], rho[1], rho[2]);
    ns_object floor = plane(0, 0);
    ns_light l = light(NS_LIGHT_SPHERE, Le[0], Le[1], Le[2]);
    set3(l.position, 0, h, 0);
    l.radius = (float)R;
    scene_lists(&s, &m, 1, &floor, 1, &l, 1);
    ns_image img = {0};
    if (!render_ok(&s, &img, NULL))
        return;
    for (int k = 0; k < 3; k++)
        CHECK_REL(pixel_at(&img, 16, 16)[k], rho[k] * Le[k] * R * R / (h * h), 5e-3);
    ns_image_free(&img);

    /* Looking straight at the light: its radiance. */
    set3(s.camera.look_at, 0, h, 0);
    s.render.spp = 4;
    if (!render_ok(&s, &img, NULL))
        return;
    for (int k = 0; k < 3; k++)
        CHECK_NEAR(pixel_at(&img, 16, 16)[k], Le[k], 1e-4 * Le[k]);
    ns_image_free(&img);
}

/* Environment only, with a unit sphere resting on the plane. A sphere wholly above a
 * point's horizon hides the cosine-weighted fraction sin^2(alpha) cos(theta_c) of its sky;
 * for the touching sphere, at horizontal distance x from the contact, that is 1 / d^3 with
 * d^2 = x^2 + 1, so L = rho L_env (1 - 1/d^3). */
static void test_environment_occlusion(void)
{
    const double env[3] = {1, 2, 3};
    const double distances[] = {0.4, 1.2, 3.0, 8.0};
    ns_material m = diffuse(rho[0], rho[1], rho[2]);
    ns_object objects[2] = {plane(0, 0), sphere(0, 1, 0, 1, 0)};
    ns_light l = light(NS_LIGHT_ENVIRONMENT, env[0], env[1], env[2]);
    for (size_t i = 0; i < sizeof distances / sizeof distances[0]; i++) {
        /* Looking at (x, 0, 0) with a tiny field of view, from the side away from the
         * sphere, low enough (direction (1, 0.3, 0)) that the view passes beside it. */
        double x = distances[i];
        ns_scene s = base_scene(3, 3, 0.2);
        set3(s.camera.position, x + 10, 3, 0);
        set3(s.camera.look_at, x, 0, 0);
        s.render.spp = 4096;
        scene_lists(&s, &m, 1, objects, 2, &l, 1);
        ns_image img = {0};
        if (!render_ok(&s, &img, NULL))
            return;
        double d = sqrt(x * x + 1.0), visible = 1.0 - 1.0 / (d * d * d);
        /* Each sample sees the sky or not: binomial noise, checked at 4.5 sigma. */
        double sigma = sqrt(visible * (1.0 - visible) / s.render.spp);
        for (int k = 0; k < 3; k++)
            CHECK_NEAR(pixel_at(&img, 1, 1)[k], rho[k] * env[k] * visible,
                       rho[k] * env[k] * (4.5 * sigma + 1e-4));
        ns_image_free(&img);
    }
}

/* render.light_samples on the occluded plane of test_environment_occlusion at x = 1.2, seen
 * through a field of view so narrow that its 32 x 32 pixels all estimate the same value:
 * with N directions a pixel, their mean is the closed form (the estimate is unbiased at any
 * spp and light_samples), and because a pixel's spp x light_samples directions are
 * low-discrepancy points, not independent draws, the pixels' spread is well below the
 * binomial sqrt(v (1 - v) / N) that independent draws would give. Reached through
 * light_samples 16 at 1 spp, through 4 x 4, and through 16 spp of one light sample each. */
static void test_light_samples(void)
{
    const double env[3] = {1, 2, 3}, x = 1.2;
    const uint32_t side = 32;
    ns_material m = diffuse(rho[0], rho[1], rho[2]);
    ns_object objects[2] = {plane(0, 0), sphere(0, 1, 0, 1, 0)};
    ns_light l = light(NS_LIGHT_ENVIRONMENT, env[0], env[1], env[2]);
    double d = sqrt(x * x + 1.0), visible = 1.0 - 1.0 / (d * d * d);
    const uint32_t spp[] = {1, 4, 16}, samples[] = {16, 4, 1};
    for (int run = 0; run < 3; run++) {
        ns_scene s = base_scene(side, side, 0.02);
        set3(s.camera.position, x + 10, 3, 0);
        set3(s.camera.look_at, x, 0, 0);
        s.render.spp = spp[run];
        s.render.light_samples = samples[run];
        scene_lists(&s, &m, 1, objects, 2, &l, 1);
        ns_image img = {0};
        if (!render_ok(&s, &img, NULL))
            return;
        double n = spp[run] * samples[run], binomial = sqrt(visible * (1.0 - visible) / n);
        for (int k = 0; k < 3; k++) {
            double sum = 0.0, sum2 = 0.0;
            for (uint32_t y = 0; y < side; y++)
                for (uint32_t xp = 0; xp < side; xp++) {
                    double v = pixel_at(&img, xp, y)[k] / (rho[k] * env[k]);
                    sum += v;
                    sum2 += v * v;
                }
            double pixels = (double)side * side, mean = sum / pixels;
            double spread = sqrt(fmax(0.0, sum2 / pixels - mean * mean));
            if (k == 0) /* the channels differ only by their scale */
                printf("light_samples: spp %u x %u: mean %.5f (closed form %.5f), spread %.4f = "
                       "%.2f of independent draws'\n",
                       spp[run], samples[run], mean, visible, spread, spread / binomial);
            CHECK_NEAR(mean, visible, 4.5 * binomial / sqrt(pixels) + 1e-4);
            CHECK(spread < 0.6 * binomial);
        }
        ns_image_free(&img);
    }
}

/* Where the camera's samples fall in a pixel: a diffuse box face lit head-on (radiance
 * rho (E / pi + L_env), exact: nothing occludes its hemisphere) whose vertical edge runs
 * through the middle of the image, against the sky (L_env), so every pixel of the middle
 * column is half face, half sky, and each sample sees one or the other. Its expected value
 * is the average of the two; with the samples at low-discrepancy points of the pixel the
 * column's pixels spread well below the binomial sqrt(1/4 / spp) of independent jitter. */
static void test_pixel_samples_spread_evenly(void)
{
    const double E[3] = {2.0, 3.0, 4.0}, env[3] = {0.3, 0.6, 0.9};
    const uint32_t side = 33, spp = 16;
    ns_scene s = base_scene(side, side, 20);
    set3(s.camera.position, 0, 0, 0);
    set3(s.camera.look_at, 0, 0, -1);
    s.render.spp = spp;
    ns_material m = diffuse(rho[0], rho[1], rho[2]);
    ns_object box;
    memset(&box, 0, sizeof box);
    box.shape = NS_SHAPE_BOX;
    set3(box.min, -50, -50, -11);
    set3(box.max, 0, 50, -10); /* its edge x = 0 is on the view axis: the middle column */
    ns_light l[2] = {light(NS_LIGHT_DIRECTIONAL, E[0], E[1], E[2]),
                     light(NS_LIGHT_ENVIRONMENT, env[0], env[1], env[2])};
    set3(l[0].direction, 0, 0, -1);
    scene_lists(&s, &m, 1, &box, 1, l, 2);
    ns_image img = {0};
    if (!render_ok(&s, &img, NULL))
        return;
    double binomial = sqrt(0.25 / spp);
    for (int k = 0; k < 3; k++) {
        double face = rho[k] * (E[k] / M_PI + env[k]), sky = env[k];
        CHECK_REL(pixel_at(&img, 5, 16)[k], face, 1e-5);
        CHECK_REL(pixel_at(&img, 27, 16)[k], sky, 1e-5);
        double sum = 0.0, sum2 = 0.0;
        for (uint32_t y = 0; y < side; y++) {
            double covered = (pixel_at(&img, side / 2, y)[k] - sky) / (face - sky);
            sum += covered;
            sum2 += covered * covered;
        }
        double mean = sum / side, spread = sqrt(fmax(0.0, sum2 / side - mean * mean));
        if (k == 0)
            printf("pixel samples: the edge's pixels cover %.4f (0.5), spread %.4f = %.2f of "
                   "independent jitter's\n",
                   mean, spread, spread / binomial);
        CHECK_NEAR(mean, 0.5, 4.5 * binomial / sqrt((double)side));
        CHECK(spread < 0.5 * binomial);
    }
    ns_image_free(&img);
}

/* render.adaptive_spp on the box edge of test_pixel_samples_spread_evenly, at 3 spp (4 R2
 * points split a half-covered pixel exactly two and two, which would leave nothing to
 * improve; 3 give a third or two thirds): only the edge's column spreads, so the added
 * samples go to it and the two columns on each side (a pixel's count is read from the
 * pixels within 2 of it: the edge's pixels from those above and below them), every other
 * pixel is the same as without them, bit for bit, the column's mean stays half covered
 * (unbiased), and its spread falls well below that of its 3 samples alone. */
static void test_adaptive_samples(void)
{
    const double E[3] = {2.0, 3.0, 4.0}, env[3] = {0.3, 0.6, 0.9};
    const uint32_t side = 33, spp = 3;
    ns_material m = diffuse(rho[0], rho[1], rho[2]);
    ns_object box;
    memset(&box, 0, sizeof box);
    box.shape = NS_SHAPE_BOX;
    set3(box.min, -50, -50, -11);
    set3(box.max, 0, 50, -10);
    ns_light l[2] = {light(NS_LIGHT_DIRECTIONAL, E[0], E[1], E[2]),
                     light(NS_LIGHT_ENVIRONMENT, env[0], env[1], env[2])};
    set3(l[0].direction, 0, 0, -1);
    ns_image img[2] = {{0}, {0}};
    ns_render_stats stats[2];
    memset(stats, 0, sizeof stats);
    const float adaptive[2] = {0.0f, 1.0f};
    for (int run = 0; run < 2; run++) {
        ns_scene s = base_scene(side, side, 20);
        set3(s.camera.position, 0, 0, 0);
        set3(s.camera.look_at, 0, 0, -1);
        s.render.spp = spp;
        s.render.adaptive_spp = adaptive[run];
        scene_lists(&s, &m, 1, &box, 1, l, 2);
        if (!render_ok(&s, &img[run], &stats[run]))
            return;
    }
    /* The budget, one per pixel, is spent but for rounding (at most one sample for each of
     * the five columns' pixels). */
    CHECK_INT(stats[0].adaptive_samples, 0);
    CHECK(stats[1].adaptive_samples <= side * side &&
          stats[1].adaptive_samples + 5 * side >= side * side);
    double spread[2];
    for (int run = 0; run < 2; run++) {
        double sum = 0.0, sum2 = 0.0;
        for (uint32_t y = 0; y < side; y++) {
            double face = rho[0] * (E[0] / M_PI + env[0]), sky = env[0];
            double covered = (pixel_at(&img[run], side / 2, y)[0] - sky) / (face - sky);
            sum += covered;
            sum2 += covered * covered;
        }
        double mean = sum / side;
        spread[run] = sqrt(fmax(0.0, sum2 / side - mean * mean));
        CHECK_NEAR(mean, 0.5, 4.5 * sqrt(0.25 / spp) / sqrt((double)side));
    }
    printf("adaptive samples: %llu added; the edge's spread %.4f at %u spp, %.4f with them\n",
           (unsigned long long)stats[1].adaptive_samples, spread[0], spp, spread[1]);
    CHECK(spread[1] < 0.5 * spread[0]);
    for (uint32_t y = 0; y < side; y++)
        for (uint32_t x = 0; x < side; x++)
            if (x + 2 < side / 2 || x > side / 2 + 2)
                for (int k = 0; k < 3; k++)
                    CHECK(pixel_at(&img[0], x, y)[k] == pixel_at(&img[1], x, y)[k]);
    ns_image_free(&img[0]);
    ns_image_free(&img[1]);
}

/* The point light's shadow ray crosses an index-matched absorbing sphere on its way down:
 * the pixel below gets rho/pi I / h^2 exp(-sigma_t 2r); a glass (ior 1.5) sphere there
 * blocks it completely (this pass does not follow caustics). */
static void test_shadow_through_index_matched_medium(void)
{
    const double I[3] = {10, 20, 5}, h = 3.0, sigma_s[3] = {0.2, 0.0, 0.0},
                 sigma_a[3] = {0.3, 0.7, 0.0};
    for (int glass = 0; glass < 2; glass++) {
        ns_scene s = base_scene(33, 33, 2);
        set3(s.camera.position, 4, 3, 0);
        set3(s.camera.look_at, 0, 0, 0);
        ns_material m[2] = {diffuse(rho[0], rho[1], rho[2]),
                            medium(sigma_s, sigma_a, glass ? 1.5 : 1.0)};
        ns_object objects[2] = {plane(0, 0), sphere(0, 1.5, 0, 0.5, 1)};
        ns_light l = light(NS_LIGHT_POINT, I[0], I[1], I[2]);
        set3(l.position, 0, h, 0);
        scene_lists(&s, m, 2, objects, 2, &l, 1);
        ns_image img = {0};
        if (!render_ok(&s, &img, NULL))
            return;
        for (int k = 0; k < 3; k++) {
            double want =
                glass ? 0.0
                      : rho[k] / M_PI * I[k] / (h * h) * exp(-(sigma_s[k] + sigma_a[k]) * 1.0);
            CHECK_NEAR(pixel_at(&img, 16, 16)[k], want, 2e-3 * rho[k] / M_PI * I[k] / (h * h));
        }
        ns_image_free(&img);
    }
}

/* The same seed gives the same image bit for bit; another seed gives other noise. */
static void test_seed_determinism(void)
{
    ns_material m = diffuse(rho[0], rho[1], rho[2]);
    ns_object objects[2] = {plane(0, 0), sphere(0, 1, 0, 1, 0)};
    ns_light l = light(NS_LIGHT_ENVIRONMENT, 1, 1, 1);
    ns_scene s = base_scene(24, 24, 60);
    set3(s.camera.position, 0, 4, 6);
    scene_lists(&s, &m, 1, objects, 2, &l, 1);
    ns_image a = {0}, b = {0}, c = {0};
    if (!render_ok(&s, &a, NULL) || !render_ok(&s, &b, NULL))
        return;
    s.render.seed++;
    if (!render_ok(&s, &c, NULL))
        return;
    size_t bytes = sizeof(float) * 3 * 24 * 24;
    CHECK(memcmp(a.rgb, b.rgb, bytes) == 0);
    CHECK(memcmp(a.rgb, c.rgb, bytes) != 0);
    ns_image_free(&a);
    ns_image_free(&b);
    ns_image_free(&c);
}

/* The default device is lavapipe, and the context says so. NSCATTER_DEVICE chooses the
 * device for the whole program, and then there is no default to check. */
static void test_device_info(void)
{
    if (getenv("NSCATTER_DEVICE"))
        SKIP("NSCATTER_DEVICE chooses the device: there is no default device to check");
    ns_device_info info;
    ns_context_device_info(test_context(), &info);
    CHECK_STR_CONTAINS(info.device_name, "llvmpipe");
    CHECK_INT(info.is_cpu, 1);
    CHECK(info.api_version >= (1u << 22 | 1u << 12)); /* Vulkan 1.1 at least */
    CHECK(info.driver_name[0] != '\0');
}

int main(void)
{
    RUN(test_device_info);
    RUN(test_directional_45);
    RUN(test_directional_70_environment);
    RUN(test_directional_from_below_is_dark);
    RUN(test_point_light);
    RUN(test_sphere_light);
    RUN(test_environment_occlusion);
    RUN(test_light_samples);
    RUN(test_pixel_samples_spread_evenly);
    RUN(test_adaptive_samples);
    RUN(test_shadow_through_index_matched_medium);
    RUN(test_seed_determinism);
    ns_context_destroy(test_context());
    return harness_report();
}
