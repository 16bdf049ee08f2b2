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
 * nothing that is not exact, so its image is the full one. */
#include "gpu_util.h"

#define W 96
#define H 48

static void build(ns_scene *s, ns_material mats[3], ns_object objs[3], ns_light *sun, uint32_t tile)
{
    *s = base_scene(W, H, 40);
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
}

/* Which object the centre of pixel (x, y) sees first: 0 wall/none, 1 bright, 2 dark
 * (sphere intersection in double, from the documented camera). */
static int seen(const ns_scene *s, uint32_t x, uint32_t y)
{
    double d[3];
    camera_ray(&s->camera, (x + 0.5) / W, (y + 0.5) / H, d);
    const double cx[2] = {-1, 1};
    double best = INFINITY;
    int which = 0;
    for (int k = 0; k < 2; k++) {
        double o[3] = {s->camera.position[0] - cx[k], s->camera.position[1], s->camera.position[2]};
        double b = o[0] * d[0] + o[1] * d[1] + o[2] * d[2], c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - 1;
        double disc = b * b - c;
        if (disc > 0 && -b - sqrt(disc) < best) {
            best = -b - sqrt(disc);
            which = k + 1;
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
    ns_scene s1, s4;
    ns_material m1[3], m4[3];
    ns_object o1[3], o4[3];
    ns_light l1, l4;
    build(&s1, m1, o1, &l1, 1);
    build(&s4, m4, o4, &l4, 4);
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
    ns_scene sr, s1, sa, s0;
    ns_material mr[3], m1[3], ma[3], m0[3];
    ns_object orr[3], o1[3], oa[3], o0[3];
    ns_light lr, l1, la, l0;
    build(&sr, mr, orr, &lr, 1);
    build(&s1, m1, o1, &l1, 1);
    build(&sa, ma, oa, &la, 1);
    build(&s0, m0, o0, &l0, 1);
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

int main(void)
{
    RUN(test_no_bleeding);
    RUN(test_adaptive);
    return harness_report();
}
