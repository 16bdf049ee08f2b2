/* gpu_upsample.c — edge-aware upsampling never lets gathered light cross a silhouette or
 * pass from one object to another. Two spheres side by side, one of a bright medium and one
 * of a dark one (albedo 0.95 against 0.2), in front of a diffuse wall, double + multiple
 * only, rendered with a gather tile of 4 and with every pixel gathered (tile 1):
 *  - pixels that see no medium get exactly nothing in both;
 *  - every pixel of the dark sphere stays within the dark sphere's own range at tile 1
 *    (plus a margin for interpolation within it), however close it is to the bright one;
 *  - away from edges the upsampled image follows the full one closely.
 * The adaptive gather (render.gather_levels) is held to the same rules at tile 1 with three
 * coarser lattices: it gathers far fewer segments, and with tolerance 0 it interpolates
 * nothing that is not exact, so its image is the full one.
 * One camera sample per gathered pixel (render.gather_camera_samples) at 4 spp: about a
 * quarter of the segments gathered, the same rules against gathering every sample (a pixel
 * whose samples see both spheres must gather them all), and as many samples as the pixel has
 * is every sample, bit for bit. The tolerance is of the pixel's scattered light: with single
 * scattering rendered too, the dark sphere's faint double and multiple scattering interpolates
 * where alone it would not, and the image stays within half the tolerance of every tile
 * gathered. */
#include "gpu_util.h"

#define W 96
#define H 48

/* What the two spheres' scene points into: it must outlive the scene build() returns. */
typedef struct spheres {
    ns_material mats[3];
    ns_object objs[3];
    ns_light sun;
} spheres;

static ns_scene build(spheres *k, uint32_t tile)
{
    ns_material *mats = k->mats;
    ns_object *objs = k->objs;
    ns_light *sun = &k->sun;
    ns_scene scene = base_scene(W, H, 40), *s = &scene;
    s->render.components = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE;
    s->render.spp = 1;
    s->render.vrls = 3000;
    s->render.gather_tile = tile;
    set3(s->camera.position, 0, 0, 6);
    set3(s->camera.look_at, 0, 0, 0);
    mats[0] = diffuse(0.5, 0.5, 0.5);
    double bright = 0.95, dark = 0.2, sigma_t = 6.0;
    mats[1] = medium((double[3]){bright * sigma_t, bright * sigma_t, bright * sigma_t},
                     (double[3]){(1 - bright) * sigma_t, (1 - bright) * sigma_t, (1 - bright) * sigma_t}, 1.3);
    mats[2] = medium((double[3]){dark * sigma_t, dark * sigma_t, dark * sigma_t},
                     (double[3]){(1 - dark) * sigma_t, (1 - dark) * sigma_t, (1 - dark) * sigma_t}, 1.3);
    mats[1].g = mats[2].g = 0.3f;
    /* The spheres touch at x = 0; the wall is a plane behind them. */
    objs[0] = sphere(-1, 0, 0, 1, 1);
    objs[1] = sphere(1, 0, 0, 1, 2);
    memset(&objs[2], 0, sizeof objs[2]);
    objs[2].shape = NS_SHAPE_PLANE;
    set3(objs[2].point, 0, 0, -2);
    set3(objs[2].normal, 0, 0, 1);
    objs[2].material = 0;
    *sun = light(NS_LIGHT_DIRECTIONAL, 3, 3, 3);
    set3(sun->direction, 0, -0.6, -0.8);
    scene_lists(s, mats, 3, objs, 3, sun, 1);
    return scene;
}

/* Which medium the centre of pixel (x, y) sees first: 0 wall/none, 1 bright, 2 dark (the
 * scene's spheres, intersected in double from the documented camera). */
static int seen(const ns_scene *s, uint32_t x, uint32_t y)
{
    double d[3];
    camera_ray(&s->camera, (x + 0.5) / W, (y + 0.5) / H, d);
    double best = INFINITY;
    int which = 0;
    for (uint32_t k = 0; k < s->object_count; k++) {
        const ns_object *b = &s->objects[k];
        if (b->shape != NS_SHAPE_SPHERE)
            continue;
        double o[3] = {s->camera.position[0] - b->center[0], s->camera.position[1] - b->center[1],
                       s->camera.position[2] - b->center[2]};
        double r = b->radius;
        double h = o[0] * d[0] + o[1] * d[1] + o[2] * d[2], c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - r * r;
        double disc = h * h - c;
        if (disc > 0 && -h - sqrt(disc) < best) {
            best = -h - sqrt(disc);
            which = (int)b->material;
        }
    }
    return which;
}

/* Checks `up` (a render that gathered fewer pixels) against `full` (tile 1, every pixel). */
static void check_against_full(const ns_scene *s1, const ns_image *full, const ns_image *up,
                               double max_interior_error)
{
    double dark_max = 0, bright_mean = 0;
    uint32_t bright_pixels = 0;
    uint32_t covered = 0;
    for (uint32_t y = 0; y < H; y++)
        for (uint32_t x = 0; x < W; x++) {
            int which = seen(s1, x, y);
            double g = pixel_at(full, x, y)[1];
            if (which == 2)
                dark_max = fmax(dark_max, g);
            if (which == 1) {
                bright_mean += g;
                bright_pixels++;
            }
        }
    bright_mean /= bright_pixels ? bright_pixels : 1;
    printf("tile 1: dark sphere max %.4g, bright sphere mean %.4g\n", dark_max, bright_mean);
    CHECK(dark_max > 0);
    /* The test can only see bleeding if the bright sphere is much brighter. */
    CHECK(bright_mean > 3 * dark_max);
    uint32_t dark_over = 0, lit_background = 0;
    double interior_error = 0, interior_mean = 0;
    for (uint32_t y = 0; y < H; y++)
        for (uint32_t x = 0; x < W; x++) {
            int which = seen(s1, x, y);
            /* A pixel next to a silhouette may be partly covered by its jittered sample: judge
             * background and interior only where all eight neighbours see the same thing. */
            int same = 1;
            for (int dy = -1; dy <= 1; dy++)
                for (int dx = -1; dx <= 1; dx++) {
                    int nx = (int)x + dx, ny = (int)y + dy;
                    if (nx >= 0 && ny >= 0 && nx < W && ny < H && seen(s1, (uint32_t)nx, (uint32_t)ny) != which)
                        same = 0;
                }
            const float *a = pixel_at(up, x, y), *b = pixel_at(full, x, y);
            if (which == 0 && same && (a[0] != 0 || a[1] != 0 || a[2] != 0 || b[1] != 0))
                lit_background++;
            if (which == 2 && a[1] > 1.25 * dark_max)
                dark_over++;
            if (which != 0 && same) {
                interior_error += fabs(a[1] - b[1]);
                interior_mean += b[1];
                covered++;
            }
        }
    printf("background pixels lit: %u; dark pixels above 1.25x the dark sphere's max: %u; "
           "interior mean |up - full| / mean %.4f over %u pixels\n",
           lit_background, dark_over, interior_error / fmax(interior_mean, 1e-30), covered);
    CHECK_INT(lit_background, 0);
    CHECK_INT(dark_over, 0);
    CHECK(covered > 500);
    CHECK(interior_error < max_interior_error * interior_mean);
}

static void test_no_bleeding(void)
{
    spheres k1, k4;
    ns_scene s1 = build(&k1, 1), s4 = build(&k4, 4);
    ns_image full = {0}, up = {0};
    ns_render_stats st1 = {0}, st4 = {0};
    if (!render_ok(&s1, &full, &st1) || !render_ok(&s4, &up, &st4))
        return;
    printf("gathered segments: %llu at tile 1, %llu at tile 4\n",
           (unsigned long long)st1.gather_segments, (unsigned long long)st4.gather_segments);
    CHECK(st4.gather_segments < st1.gather_segments / 4);
    check_against_full(&s1, &full, &up, 0.1);
    ns_image_free(&full);
    ns_image_free(&up);
}

/* Mean |a - b| / mean b over the pixels of the spheres away from silhouettes. */
static double interior_difference(const ns_scene *s, const ns_image *a, const ns_image *b)
{
    double difference = 0, mean = 0;
    for (uint32_t y = 1; y + 1 < H; y++)
        for (uint32_t x = 1; x + 1 < W; x++) {
            int which = seen(s, x, y), same = which != 0;
            for (int dy = -1; dy <= 1; dy++)
                for (int dx = -1; dx <= 1; dx++)
                    same = same && seen(s, x + dx, y + dy) == which;
            if (same) {
                difference += fabs(pixel_at(a, x, y)[1] - pixel_at(b, x, y)[1]);
                mean += pixel_at(b, x, y)[1];
            }
        }
    return difference / fmax(mean, 1e-30);
}

/* The judge is a render with ten times the light paths: interpolation may take the image
 * further from it than gathering every pixel does by no more than half its tolerance (the
 * bound is per tile; on average it is well inside it). (With
 * independent light paths the full gather's own VRL noise was larger than that, and the
 * test asked for no more than 5% beyond it; with stratified paths, 2026-11-29, every pixel
 * reads 1.43% from the judge and the adaptive gather 1.92%.) */
static void test_adaptive(void)
{
    spheres kr, k1, ka, k0;
    ns_scene sr = build(&kr, 1), s1 = build(&k1, 1), sa = build(&ka, 1), s0 = build(&k0, 1);
    sr.render.vrls = 30000;
    sa.render.gather_levels = s0.render.gather_levels = 3;
    sa.render.gather_tolerance = 0.02f;
    s0.render.gather_tolerance = 0.0f;
    ns_image reference = {0}, full = {0}, adaptive = {0}, strict = {0};
    ns_render_stats str = {0}, st1 = {0}, sta = {0}, st0 = {0};
    if (!render_ok(&sr, &reference, &str) || !render_ok(&s1, &full, &st1) ||
        !render_ok(&sa, &adaptive, &sta) || !render_ok(&s0, &strict, &st0))
        return;
    double e_full = interior_difference(&s1, &full, &reference);
    double e_adaptive = interior_difference(&s1, &adaptive, &reference);
    printf("adaptive: %llu segments gathered (%llu tiles interpolated) against %llu; "
           "against %u light paths: every pixel %.4f, adaptive %.4f\n",
           (unsigned long long)sta.gather_segments, (unsigned long long)sta.tiles_interpolated,
           (unsigned long long)st1.gather_segments, sr.render.vrls, e_full, e_adaptive);
    CHECK(sta.tiles_interpolated > 0);
    CHECK(sta.gather_segments < 3 * st1.gather_segments / 4);
    CHECK(st1.tiles_interpolated == 0);
    CHECK(e_adaptive < e_full + 0.5 * sa.render.gather_tolerance);
    check_against_full(&s1, &full, &adaptive, 0.05);
    /* Tolerance 0 interpolates only where the estimated error is exactly 0 (no light). */
    double worst = 0;
    for (uint32_t i = 0; i < 3u * W * H; i++)
        worst = fmax(worst, fabs(strict.rgb[i] - full.rgb[i]) / fmax(fabs(full.rgb[i]), 1e-20));
    printf("tolerance 0: %llu tiles interpolated; largest relative difference from every pixel "
           "gathered: %.3g\n", (unsigned long long)st0.tiles_interpolated, worst);
    CHECK(worst < 1e-6);
    ns_image_free(&reference);
    ns_image_free(&full);
    ns_image_free(&adaptive);
    ns_image_free(&strict);
}

/* The adaptive gather's tolerance is of the pixel's whole scattered value: where single
 * scattering outshines double and multiple (the dark sphere, albedo 0.2), the gather's noise
 * is small against what the pixel shows, and more tiles are interpolated than when double
 * and multiple scattering are rendered alone (then the tolerance is of them: the same
 * decisions as before). */
static void test_tolerance_of_the_pixel(void)
{
    spheres kd, kf;
    ns_scene sd = build(&kd, 1), sf = build(&kf, 1);
    sd.render.gather_levels = sf.render.gather_levels = 2;
    sd.render.gather_tolerance = sf.render.gather_tolerance = 0.05f;
    sf.render.components |= NS_COMPONENT_SINGLE;
    ns_image dm = {0}, full = {0};
    ns_render_stats std = {0}, stf = {0};
    if (!render_ok(&sd, &dm, &std) || !render_ok(&sf, &full, &stf))
        return;
    printf("tolerance of the pixel: %llu tiles interpolated with double and multiple alone, "
           "%llu with single scattering too (%llu / %llu segments gathered)\n",
           (unsigned long long)std.tiles_interpolated, (unsigned long long)stf.tiles_interpolated,
           (unsigned long long)std.gather_segments, (unsigned long long)stf.gather_segments);
    CHECK(stf.tiles_interpolated > std.tiles_interpolated);
    CHECK(10 * stf.gather_segments < 9 * std.gather_segments);
    /* And the pixels still show what gathering every tile shows, within the tolerance. */
    spheres k0;
    ns_scene s0 = build(&k0, 1);
    s0.render.components = sf.render.components;
    ns_image every = {0};
    if (render_ok(&s0, &every, NULL)) {
        double e = interior_difference(&sf, &full, &every);
        printf("against every tile gathered: %.4f\n", e);
        CHECK(e < 0.5 * sf.render.gather_tolerance);
    }
    ns_image_free(&every);
    ns_image_free(&dm);
    ns_image_free(&full);
}

/* Mean |a - b| / mean b over the pixels whose 3 x 3 neighbourhood sees both spheres: where
 * one sphere's silhouette crosses the other. */
static double band_difference(const ns_scene *s, const ns_image *a, const ns_image *b, uint32_t *pixels)
{
    double difference = 0, mean = 0;
    *pixels = 0;
    for (uint32_t y = 1; y + 1 < H; y++)
        for (uint32_t x = 1; x + 1 < W; x++) {
            int saw[3] = {0, 0, 0};
            for (int dy = -1; dy <= 1; dy++)
                for (int dx = -1; dx <= 1; dx++)
                    saw[seen(s, x + dx, y + dy)] = 1;
            if (saw[1] && saw[2]) {
                difference += fabs(pixel_at(a, x, y)[1] - pixel_at(b, x, y)[1]);
                mean += pixel_at(b, x, y)[1];
                ++*pixels;
            }
        }
    return difference / fmax(mean, 1e-30);
}

/* render.gather_camera_samples at 4 spp, tile 1. The gather's noise is the VRLs', and a
 * pixel's four samples average some of it (their segments lie close together, so less than
 * four independent gathers would): one sample is noisier at the same light paths, about as
 * good at the same cost (four times the light paths). The judge: 30,000 light paths on
 * another seed. It keeps the rules of check_against_full against every sample, and 4 (as
 * many as the pixel has) is 0, bit for bit. Then the dark sphere goes in front of the bright
 * one: a pixel on its silhouette, whose samples see both, must gather them all, or one
 * sphere's light goes to every sample. */
static void test_camera_samples(void)
{
    enum { JUDGE, ALL, ONE, ONE_SAME_COST, FOUR, FRONT_ALL, FRONT_ONE, RUNS };
    spheres k[RUNS];
    ns_scene s[RUNS];
    ns_image img[RUNS];
    ns_render_stats st[RUNS];
    memset(img, 0, sizeof img);
    memset(st, 0, sizeof st);
    const uint32_t samples[RUNS] = {[JUDGE] = 1, [ONE] = 1, [ONE_SAME_COST] = 1, [FOUR] = 4, [FRONT_ONE] = 1};
    for (int r = 0; r < RUNS; r++) {
        s[r] = build(&k[r], 1);
        s[r].render.spp = 4;
        s[r].render.gather_camera_samples = samples[r];
        if (r >= FRONT_ALL)
            k[r].objs[1] = sphere(-0.5, 0.2, 1.8, 0.6, 2);
    }
    s[JUDGE].render.vrls = 30000;
    s[JUDGE].render.seed = 2;
    s[ONE_SAME_COST].render.vrls = 4 * s[ALL].render.vrls;
    for (int r = 0; r < RUNS; r++)
        if (!render_ok(&s[r], &img[r], &st[r]))
            goto done;
    double e_all = interior_difference(&s[ALL], &img[ALL], &img[JUDGE]);
    double e_one = interior_difference(&s[ALL], &img[ONE], &img[JUDGE]);
    double e_same_cost = interior_difference(&s[ALL], &img[ONE_SAME_COST], &img[JUDGE]);
    printf("camera samples: %llu segments gathered with one, %llu with every sample; against "
           "the judge: every sample %.4f, one %.4f, one with %u light paths %.4f\n",
           (unsigned long long)st[ONE].gather_segments, (unsigned long long)st[ALL].gather_segments,
           e_all, e_one, s[ONE_SAME_COST].render.vrls, e_same_cost);
    CHECK(st[ONE].gather_segments < 0.3 * (double)st[ALL].gather_segments);
    /* Measured 0.0166 against 0.0104 (0.0187 against 0.0133 before the camera's samples
     * spread evenly over the pixel: every sample's image gained more). Four independent
     * gathers would be twice as far as their mean. */
    CHECK(e_one < 1.8 * e_all);
    CHECK(e_same_cost < 1.1 * e_all); /* 0.0089 */
    check_against_full(&s[ALL], &img[ALL], &img[ONE], 0.05);
    CHECK_INT(st[FOUR].gather_segments, st[ALL].gather_segments);
    CHECK(memcmp(img[FOUR].rgb, img[ALL].rgb, sizeof(float) * 3 * W * H) == 0);
    uint32_t band = 0;
    double e_band = band_difference(&s[FRONT_ALL], &img[FRONT_ONE], &img[FRONT_ALL], &band);
    double e_inside = interior_difference(&s[FRONT_ALL], &img[FRONT_ONE], &img[FRONT_ALL]);
    printf("dark sphere in front: one sample against every sample, %.4f on the %u pixels of the "
           "silhouette, %.4f inside\n", e_band, band, e_inside);
    CHECK(band > 40);
    /* 0.025 against 0.015 inside; without the rule 0.133 against 0.017 (when the first
     * sample was taken, not the nearest to the centre) */
    CHECK(e_band < 3 * e_inside);
done:
    for (int r = 0; r < RUNS; r++)
        ns_image_free(&img[r]);
}

int main(void)
{
    RUN(test_no_bleeding);
    RUN(test_adaptive);
    RUN(test_camera_samples);
    RUN(test_tolerance_of_the_pixel);
    return harness_report();
}
