/* unit_adaptive_gather.c — the adaptive gather's rule (render.gather_levels,
 * render/scatter_render.c) against closed forms, on fields given as functions, through the
 * same rounds the render runs (ns_adaptive_tiles; tiles of one pixel but where said):
 *  - a linear field: every tile off the coarsest lattice is interpolated, and exactly;
 *  - tiles of 2, 3 and 4 pixels: a linear field upsampled from the representatives comes
 *    back exactly at every pixel between them;
 *  - a parabola in x, f = 1 + c x^2: the mean of the two neighbours h away misses by c h^2,
 *    which the second differences estimate exactly, so a tile is interpolated if and only
 *    if c h^2 <= tolerance x the mean, and then carries exactly that error;
 *  - in both, a line whose two outer samples (3h away) both leave the image (the
 *    anti-diagonal at a corner) has no second difference and must pass on the spread of its
 *    two neighbours instead;
 *  - two media side by side, or one surface at two distances: no value crosses between them;
 *  - levels 0 or tolerance 0: everything is gathered;
 *  - adaptive single scattering's curved values (a cubic through four samples, a parabola
 *    through three): the same decisions, and a parabola comes back exactly;
 *  - light the pixels show besides (the render's single scattering, `other`) counts in the
 *    mean the error is weighed against: with K beside a parabola, a tile is interpolated if
 *    and only if c h^2 <= tolerance x (the mean + K);
 *  - noisy values (adaptive single scattering's, `noise` their variance v): a second
 *    difference d has the noise v (1 + 4 + 1) of its samples, which is taken off its square,
 *    and an interpolation whose bias is within what it saves in noise (v, computed, against
 *    the cubic's 0.64 v) stands for the pixel: interpolated if and only if
 *    max(0, d^2 - 6 v) / 64 <= (tolerance x the mean)^2 + v - v_interpolated, v the outer
 *    samples' mean variance at most the inner ones' larger (the inner ones' smaller without
 *    outer ones): a large variance on one sample (an outlier's) excuses nothing;
 *  - the pixels' variance (ns_sample_moments_add, ns_ratio_variance): a camera sample's
 *    segments are summed before they are squared, whatever their order; the variance of
 *    Lbar = sum X / sum W is spp / (spp - 1) sum_j (X_j - Lbar W_j)^2 / (sum W)^2, computed
 *    here in double from the samples themselves; samples whose parts are proportional to
 *    their weights (a silhouette: some miss, X = W = 0) have none; one sample, or no
 *    weight, none.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "harness.h"
#include "scatter.h"

#define W 33
#define H 33 /* the coarsest lattice (8 apart) reaches every edge */

/* The field the rounds gather from: ns_adaptive_tiles passes it to gather() as it is. */
typedef struct ns_tile_field {
    double (*f)(const struct ns_tile_field *, double x, double y);
    double c; /* the parabola's: f'' = 2c along x, 0 along y */
    int gathered; /* calls */
} field;

static void gather(uint32_t pixel, float radiance[3], field *fd)
{
    double v = fd->f(fd, pixel % W, pixel / W);
    for (int k = 0; k < 3; k++)
        radiance[k] = (float)(v * (k + 1)); /* three channels, same shape */
    fd->gathered++;
}

static double linear(const field *fd, double x, double y)
{
    (void)fd;
    return 1 + 0.01 * x + 0.02 * y;
}

static double parabola(const field *fd, double x, double y)
{
    (void)y;
    return 1 + fd->c * x * x;
}

static double step_in_x(const field *fd, double x, double y)
{
    (void)fd;
    (void)y;
    return x < 16 ? 1 : 5;
}

static uint32_t materials[W * H];
static float distances[W * H];
static float radiance[W * H][3];
static uint8_t interpolated[W * H];
/* The light beside the gathered part, K (k + 1) in channel k as the field's own channels; 0:
 * the rounds are given none (NULL). */
static double other_k;
static float other_light[W * H][3];
/* The variance of every gathered value, v (k + 1)^2 in channel k (the field's channels are
 * (k + 1) times channel 0); 0: the rounds are given none (NULL). */
static double noise_v;
static float noise[W * H][3];
/* The variance of the pixels on the lattice 8 apart, times noise_v (1: like the others). */
static double noise_outlier = 1;

static void one_surface(void)
{
    for (int p = 0; p < W * H; p++) {
        materials[p] = 0;
        distances[p] = 10;
    }
}

/* The level of lattice that pixel (x, y) is first on, with `levels` levels. */
static int first_level(int x, int y, int levels)
{
    for (int k = levels; k > 0; k--)
        if (x % (1 << k) == 0 && y % (1 << k) == 0)
            return k;
    return 0;
}

static int in_image(int x, int y) { return x >= 0 && y >= 0 && x < W && y < H; }

/* The rule, stated on the field itself: tile (x, y), first on the lattice h = 2^level apart,
 * is interpolated when each of its lines (along x, along y, or both diagonals) has an error
 * within tolerance x the mean of its two neighbours; the error of the mean is c (dx h)^2
 * when a second difference exists (an outer sample in the image), else the neighbours'
 * spread. Returns the expected value through *value. */
static int expected_interpolated(const field *fd, int x, int y, int levels, float tolerance,
                                 double *value)
{
    int level = first_level(x, y, levels), h = 1 << level;
    if (level == levels)
        return 0;
    int odd_x = (x / h) % 2, odd_y = (y / h) % 2;
    int line_count = odd_x && odd_y ? 2 : 1;
    int lines[2][2] = {{odd_x, odd_y}, {1, -1}}; /* both odd: the two diagonals */
    double sum = 0;
    for (int i = 0; i < line_count; i++) {
        int dx = lines[i][0] * h, dy = lines[i][1] * h;
        double a = fd->f(fd, x - dx, y - dy), b = fd->f(fd, x + dx, y + dy);
        int outer = in_image(x - 3 * dx, y - 3 * dy) || in_image(x + 3 * dx, y + 3 * dy);
        double error = outer ? fd->c * dx * dx : fabs(a - b);
        if (error > tolerance * 0.5 * (a + b + 2 * other_k))
            return 0;
        sum += a + b;
    }
    *value = sum / (2 * line_count);
    return 1;
}

/* Runs the rounds; returns 1 when they ran. The status is checked here, so that a caller
 * that gives up on a failure is still counted as failed. */
static int run_as(field *fd, uint32_t levels, float tolerance, int curved)
{
    fd->gathered = 0;
    for (int p = 0; p < W * H; p++)
        for (int k = 0; k < 3; k++)
            other_light[p][k] = (float)(other_k * (k + 1));
    for (int p = 0; p < W * H; p++)
        for (int k = 0; k < 3; k++)
            noise[p][k] = (float)(noise_v * (k + 1) * (k + 1) *
                                  (p % W % 8 == 0 && p / W % 8 == 0 ? noise_outlier : 1));
    int status = ns_adaptive_tiles(W, H, 1, levels, tolerance, curved, materials, distances,
                                   other_k > 0 ? (const float(*)[3])other_light : NULL,
                                   noise_v > 0 ? (const float(*)[3])noise : NULL, gather, fd,
                                   radiance, interpolated);
    if (status)
        fprintf(stderr, "ns_adaptive_tiles: status %d (out of memory)\n", status);
    CHECK_INT(status, 0);
    return status == 0;
}

static int run(field *fd, uint32_t levels, float tolerance)
{
    return run_as(fd, levels, tolerance, 0);
}

/* Compares the rounds with the rule; returns how many tiles it interpolated. */
static int check_against_rule(const field *fd, int levels, float tolerance)
{
    int count = 0, decisions_ok = 1, values_ok = 1;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            int p = y * W + x;
            double want = fd->f(fd, x, y);
            int expected = expected_interpolated(fd, x, y, levels, tolerance, &want);
            decisions_ok &= interpolated[p] == expected;
            for (int k = 0; k < 3; k++)
                values_ok &= fabs(radiance[p][k] - want * (k + 1)) <= 2e-6 * (k + 1);
            count += interpolated[p];
        }
    CHECK(decisions_ok);
    CHECK(values_ok);
    return count;
}

static void test_linear_field_is_interpolated_exactly(void)
{
    one_surface();
    field fd = {.f = linear};
    if (!run(&fd, 3, 1e-4f))
        return;
    int count = check_against_rule(&fd, 3, 1e-4f);
    /* All but the 5 x 5 coarsest and the 12 anti-diagonals at the corners (their spread is
     * 0.01-0.16, far above 1e-4). Every interpolated value is the field's, exactly. */
    CHECK_INT(count, W * H - 25 - 12);
    CHECK_INT(fd.gathered, 25 + 12);
}

/* Tiles of several pixels (render.gather_tile): each tile's representative is gathered and
 * every other pixel is upsampled bilinearly from the representatives around it, each weighed
 * where it is (pixel tile / 2 of its tile). On a linear field every pixel between
 * representatives comes back exactly, up to the last tile's, moved onto the last pixel.
 * Weighed at their tiles' centres instead, half a pixel away for even tiles, they put the
 * field half a pixel off (0.005-0.01 here, 2e-6 allowed); weighed at its own pixel tile / 2,
 * the moved one put the pixels before it off by as much. */
static void test_tiles_upsample_a_linear_field_exactly(void)
{
    one_surface();
    for (uint32_t tile = 2; tile <= 4; tile++) {
        field fd = {.f = linear};
        int status = ns_adaptive_tiles(W, H, tile, 0, 0.0f, 0, materials, distances, NULL, NULL,
                                       gather, &fd, radiance, interpolated);
        CHECK_INT(status, 0);
        if (status)
            return;
        int tiles = (W + (int)tile - 1) / (int)tile;
        CHECK_INT(fd.gathered, tiles * tiles);
        /* The representatives' span; the last tile's is moved onto the image's last pixel
         * when its pixel tile / 2 lies outside (W = H = 33: tiles 2 and 4), and weighed
         * there. */
        int lo = (int)tile / 2, hi = lo + (tiles - 1) * (int)tile;
        if (hi > W - 1)
            hi = W - 1;
        int exact = 1, checked = 0;
        for (int y = lo; y <= hi; y++)
            for (int x = lo; x <= hi; x++, checked++)
                for (int k = 0; k < 3; k++)
                    exact &= fabs(radiance[y * W + x][k] - linear(&fd, x, y) * (k + 1)) <=
                             2e-6 * (k + 1);
        CHECK(exact);
        CHECK(checked >= 31 * 31);
    }
}

static void test_parabola_interpolated_where_its_error_is_within_tolerance(void)
{
    one_surface();
    /* h = 1: error 1e-4, within 1.5e-4 x mean (mean 1 to 1.1); h = 2: 4e-4, not. An
     * estimate off by a factor 2 either way would flip the first. */
    field fd = {.f = parabola, .c = 1e-4};
    if (!run(&fd, 3, 1.5e-4f))
        return;
    int count = check_against_rule(&fd, 3, 1.5e-4f);
    printf("parabola: %d of %d tiles interpolated\n", count, W * H);
    CHECK(count > 0 && count < W * H - 25);
}

static void test_other_light_counts_in_the_tolerance(void)
{
    one_surface();
    /* Alone, a line along x misses by c h^2 = 4e-4 at h = 1, outside 1.5e-4 x the mean (1 to
     * 1.4): only the tiles whose line runs along y, where the parabola is flat, are
     * interpolated. Beside K = 3 the h = 1 lines along x pass (4e-4 <= 1.5e-4 x (mean + 3)),
     * the h = 2 ones (1.6e-3) still do not. check_against_rule holds every decision. */
    field fd = {.f = parabola, .c = 4e-4};
    other_k = 0;
    if (!run(&fd, 3, 1.5e-4f))
        return;
    int alone = check_against_rule(&fd, 3, 1.5e-4f);
    other_k = 3;
    int beside = run(&fd, 3, 1.5e-4f) ? check_against_rule(&fd, 3, 1.5e-4f) : 0;
    other_k = 0;
    printf("parabola beside other light: %d tiles interpolated alone, %d beside K = 3\n", alone,
           beside);
    CHECK(beside > alone + W * H / 4);
}

static void test_nothing_crosses_media_or_surfaces(void)
{
    field fd = {.f = step_in_x};
    for (int pass = 0; pass < 2; pass++) {
        /* pass 0: two media meeting at x = 16; pass 1: one medium, a step in distance. */
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++) {
                materials[y * W + x] = pass == 0 && x >= 16 ? 1 : 0;
                distances[y * W + x] = pass == 1 && x >= 16 ? 12.0f : 10.0f;
            }
        if (!run(&fd, 3, 1.0f)) /* the loosest tolerance: only the keys can refuse */
            return;
        int wrong = 0, beside_step = 0;
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++) {
                wrong += radiance[y * W + x][0] != (float)step_in_x(&fd, x, y);
                beside_step += interpolated[y * W + x] && x == 15;
            }
        CHECK_INT(wrong, 0);
        /* x = 15 lies midway between x = 14 and x = 16 at the finest level: gathered. */
        CHECK_INT(beside_step, 0);
    }
    /* Nothing seen: nothing gathered, nothing interpolated. */
    for (int p = 0; p < W * H; p++)
        materials[p] = NS_NONE;
    if (run(&fd, 3, 1.0f)) {
        CHECK_INT(fd.gathered, 0);
        int any = 0;
        for (int p = 0; p < W * H; p++)
            any |= interpolated[p];
        CHECK_INT(any, 0);
    }
}

static void test_no_levels_or_no_tolerance_gathers_everything(void)
{
    one_surface();
    field fd = {.f = parabola, .c = 1e-4};
    const uint32_t levels[2] = {0, 3};
    const float tolerances[2] = {0.5f, 0.0f};
    for (int i = 0; i < 2; i++) {
        if (!run(&fd, levels[i], tolerances[i]))
            return;
        /* tolerance 0 still takes the tiles whose estimate is exactly 0: those midway in y
         * alone (the field is constant in y) */
        int expected = 0;
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++) {
                int level = first_level(x, y, (int)levels[i]), h = 1 << level;
                int midway_in_y_only = level < (int)levels[i] && (x / h) % 2 == 0;
                expected += !midway_in_y_only;
            }
        CHECK_INT(fd.gathered, expected);
    }
}

/* Curved values: where the mean of two neighbours h apart misses the parabola by c h^2, the
 * cubic through four samples and the parabola through three (at the image's edges) are
 * exact. One level, so that every value interpolated from is gathered: a diagonal with no
 * outer sample in the image (one at each corner pixel, (1 or W-2, 1 or H-2)) has only the
 * mean, which misses, and a finer round would carry that on. The decisions are the
 * mean's: the error estimate bounds the mean, which the curved value improves on. */
static void test_curved_values_are_exact_for_a_parabola(void)
{
    one_surface();
    field fd = {.f = parabola, .c = 0.002};
    if (!run_as(&fd, 1, 0.5f, 1))
        return;
    int count = 0, decisions_ok = 1, missed = 0, missed_elsewhere = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            int p = y * W + x, corner = (x == 1 || x == W - 2) && (y == 1 || y == H - 2);
            double mean, want = fd.f(&fd, x, y);
            decisions_ok &= interpolated[p] == expected_interpolated(&fd, x, y, 1, 0.5f, &mean);
            int exact = 1;
            for (int k = 0; k < 3; k++)
                exact &= fabs(radiance[p][k] - want * (k + 1)) <= 4e-6 * want * (k + 1);
            missed += !exact;
            missed_elsewhere += !exact && !corner;
            count += interpolated[p];
        }
    CHECK(decisions_ok);
    CHECK_INT(missed_elsewhere, 0);
    CHECK_INT(missed, 4);
    CHECK(count > W * H / 2);
    /* And the plain mean is not exact: the test would see the difference. */
    run(&fd, 1, 0.5f);
    double worst = 0;
    for (int p = 0; p < W * H; p++)
        worst = fmax(worst, fabs(radiance[p][0] - fd.f(&fd, p % W, p / W)));
    CHECK(worst > 0.001);
}

/* The variance run_as gives pixel (x, y) in channel 0. */
static double variance_at(int x, int y)
{
    return noise_v * (x % 8 == 0 && y % 8 == 0 ? noise_outlier : 1);
}

/* The noisy rule on one level (every value interpolated from is gathered), curved values,
 * stated on the parabola itself in channel 0 (the others scale alike): a line whose outer
 * samples exist on both sides has the cubic (noise (81 + 81 + 1 + 1) / 64 / 4 v), on one side
 * the parabola through three ((1 + 36 + 9) / 16 / 4 v), on neither the mean (v / 2), whose
 * error is the spread; v is the outer samples' mean variance at most the inner ones' larger,
 * without outer samples the inner ones' smaller. */
static int expected_noisy(const field *fd, int x, int y, float tolerance)
{
    if (x % 2 == 0 && y % 2 == 0)
        return 0;
    int odd_x = x % 2, odd_y = y % 2;
    int line_count = odd_x && odd_y ? 2 : 1;
    int lines[2][2] = {{odd_x, odd_y}, {1, -1}};
    for (int i = 0; i < line_count; i++) {
        int dx = lines[i][0], dy = lines[i][1];
        double a = fd->f(fd, x - dx, y - dy), b = fd->f(fd, x + dx, y + dy);
        int a_out = in_image(x - 3 * dx, y - 3 * dy), b_out = in_image(x + 3 * dx, y + 3 * dy);
        double va_out = a_out ? variance_at(x - 3 * dx, y - 3 * dy) : 0,
               vb_out = b_out ? variance_at(x + 3 * dx, y + 3 * dy) : 0;
        double va = variance_at(x - dx, y - dy), vb = variance_at(x + dx, y + dy);
        double v = a_out && b_out ? fmin(0.5 * (va_out + vb_out), fmax(va, vb))
                 : a_out || b_out ? fmin(a_out ? va_out : vb_out, fmax(va, vb))
                                  : fmin(va, vb);
        double d = 8 * fd->c * dx * dx; /* both second differences of the parabola */
        double bias2 = a_out || b_out ? fmax(0, (d * d - 6 * v) / 64) : fmax(0, (a - b) * (a - b) - 2 * v);
        double interpolated_v = a_out && b_out ? 164.0 / 256 * v : a_out || b_out ? 46.0 / 64 * v : 0.5 * v;
        double allowed = tolerance * 0.5 * (a + b);
        if (bias2 > allowed * allowed + fmax(0, v - interpolated_v))
            return 0;
    }
    return 1;
}

static void test_noise_lets_an_interpolation_no_worse_than_computing_through(void)
{
    one_surface();
    /* c h^2 = 1e-4 on the lines along x, far outside 1e-7 x the mean without noise. With
     * v = 4e-8 their bias^2 1e-8 (less 6 v / 64) is within the 0.36 v the cubic saves and
     * they pass too; at v = 1e-8 they do not (9.1e-9 against 3.6e-9). */
    field fd = {.f = parabola, .c = 1e-4};
    const double variances[3] = {0, 1e-8, 4e-8};
    int counts[3] = {0, 0, 0};
    for (int i = 0; i < 3; i++) {
        noise_v = variances[i];
        if (!run_as(&fd, 1, 1e-7f, 1))
            break;
        int decisions_ok = 1;
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++) {
                decisions_ok &= interpolated[y * W + x] == expected_noisy(&fd, x, y, 1e-7f);
                counts[i] += interpolated[y * W + x];
            }
        CHECK(decisions_ok);
    }
    /* A hundred times the variance on the lattice 8 apart, which is an inner sample of some
     * lines and an outer one of others: no line along x passes at v = 1e-8 (with the inner
     * samples' variance alone, or the mean of all four, those with an outlier inside would;
     * with the outer samples' alone, those with one outside). */
    noise_v = variances[1];
    noise_outlier = 100;
    if (run_as(&fd, 1, 1e-7f, 1)) {
        int decisions_ok = 1, inner_passed = 0, outer_passed = 0;
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++) {
                int p = y * W + x, along_x = x % 2 == 1 && y % 2 == 0 && y % 8 == 0;
                decisions_ok &= interpolated[p] == expected_noisy(&fd, x, y, 1e-7f);
                inner_passed += along_x && (x % 8 == 1 || x % 8 == 7) && interpolated[p];
                outer_passed += along_x && (x % 8 == 3 || x % 8 == 5) && interpolated[p];
            }
        CHECK(decisions_ok);
        CHECK_INT(inner_passed, 0);
        CHECK_INT(outer_passed, 0);
    }
    noise_outlier = 1;
    noise_v = 0;
    printf("noisy parabola: %d / %d / %d tiles interpolated at v = 0 / 1e-8 / 4e-8\n", counts[0],
           counts[1], counts[2]);
    /* The lines along y alone (a quarter of the image), then every line. */
    CHECK(counts[0] == counts[1] && counts[0] > W * H / 5);
    CHECK(counts[2] > counts[1] + W * H / 3);
}

/* A pixel's camera samples as segments: pixel 1's sample 0 is two segments (X 1 + 2, W 0.5 +
 * 0.25), its sample 2 one (X 3, W 1), in the order 0, 2, 0 to show that order does not
 * matter; sample 1 misses the medium (nothing); pixel 0 beside it is one segment. */
static void test_pixel_variance_is_the_ratio_estimators(void)
{
    const uint32_t spp = 3;
    GpuSegment segs[4];
    memset(segs, 0, sizeof segs);
    const uint32_t pixel[4] = {0, 1, 1, 1}, sample[4] = {0, 0, 2, 0};
    const float added[4][3] = {{5, 5, 5}, {1, 2, 4}, {3, 3, 3}, {2, 2, 2}};
    const float weight[4][3] = {{1, 1, 1}, {0.5f, 0.5f, 0.5f}, {1, 1, 1}, {0.25f, 0.25f, 0.25f}};
    for (int i = 0; i < 4; i++) {
        segs[i].pixel = pixel[i];
        segs[i].sample_index = sample[i];
    }
    ns_sample_moments m[2];
    memset(m, 0, sizeof m);
    CHECK_INT(ns_sample_moments_add(segs, added, weight, 4, m), 0);
    for (int c = 0; c < 3; c++) {
        /* Pixel 1's samples: X = (1 + 2, 0, 3), W = (0.75, 0, 1) in channel 0, etc. */
        double x[3] = {added[1][c] + added[3][c], 0, added[2][c]}, w[3] = {0.75, 0, 1};
        double sum_x = x[0] + x[1] + x[2], sum_w = w[0] + w[1] + w[2], lbar = sum_x / sum_w;
        double xx = 0, xw = 0, ww = 0, spread = 0;
        for (int j = 0; j < 3; j++) {
            xx += x[j] * x[j];
            xw += x[j] * w[j];
            ww += w[j] * w[j];
            spread += (x[j] - lbar * w[j]) * (x[j] - lbar * w[j]);
        }
        CHECK_NEAR(m[1].xx[c], xx, 1e-5);
        CHECK_NEAR(m[1].xw[c], xw, 1e-5);
        CHECK_NEAR(m[1].ww[c], ww, 1e-6);
        double want = spp / (spp - 1.0) * spread / (sum_w * sum_w);
        CHECK(want > 0.1);
        CHECK_NEAR(ns_ratio_variance((float)sum_x, (float)sum_w, &m[1], c, spp), want, 1e-5 * want);
        /* Pixel 0: one sample of one segment. */
        CHECK_NEAR(m[0].xx[c], 25, 0);
        CHECK_NEAR(m[0].ww[c], 1, 0);
    }
    /* Parts proportional to the weights (Lbar 2 in every sample that sees the medium, one
     * sample missing it): no noise, though the samples' sums differ. */
    const float prop_added[3][3] = {{1, 1, 1}, {4, 4, 4}, {0.5f, 0.5f, 0.5f}};
    const float prop_weight[3][3] = {{0.5f, 0.5f, 0.5f}, {2, 2, 2}, {0.25f, 0.25f, 0.25f}};
    const uint32_t prop_sample[3] = {0, 1, 3};
    GpuSegment prop[3];
    memset(prop, 0, sizeof prop);
    for (int i = 0; i < 3; i++)
        prop[i].sample_index = prop_sample[i];
    ns_sample_moments pm;
    memset(&pm, 0, sizeof pm);
    CHECK_INT(ns_sample_moments_add(prop, prop_added, prop_weight, 3, &pm), 0);
    CHECK_NEAR(ns_ratio_variance(5.5f, 2.75f, &pm, 0, 4), 0, 1e-6);
    /* One camera sample, or no weight: nothing to tell the noise from. */
    CHECK_NEAR(ns_ratio_variance(5.5f, 2.75f, &m[1], 0, 1), 0, 0);
    CHECK_NEAR(ns_ratio_variance(0.0f, 0.0f, &m[1], 0, 3), 0, 0);
}

/* ns_from_pixel_centre against the camera pass's own ray (camera.comp: d = forward +
 * right (2u - 1) tan_x + up (1 - 2v) tan_y for u = (x + jx) / width, v = (y + jy) / height):
 * a point on the ray of pixel (x, y) at jitter (jx, jy) is (jx - 0.5)^2 + (jy - 0.5)^2 pixels^2
 * from that pixel's centre, at any distance along it; behind the camera it is infinitely far. */
static void test_pixel_centre_distance_is_the_jitter(void)
{
    const uint32_t width = 40, height = 30;
    const float tan_x = 0.6f, tan_y = 0.6f * 30 / 40;
    GpuParams cam;
    memset(&cam, 0, sizeof cam);
    const float position[3] = {1, 2, 3}, forward[3] = {0, 0, -1}, right[3] = {1, 0, 0}, up[3] = {0, 1, 0};
    for (int i = 0; i < 3; i++) {
        cam.cam_position[i] = position[i];
        cam.cam_forward[i] = forward[i];
        cam.cam_right[i] = right[i];
        cam.cam_up[i] = up[i];
    }
    cam.cam_position[3] = tan_x;
    cam.cam_right[3] = tan_y;
    const uint32_t pixels[3][2] = {{0, 0}, {17, 11}, {39, 29}};
    const float jitters[3][2] = {{0.5f, 0.5f}, {0.1f, 0.8f}, {0.95f, 0.05f}};
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) {
            float u = ((float)pixels[a][0] + jitters[b][0]) / (float)width;
            float v = ((float)pixels[a][1] + jitters[b][1]) / (float)height;
            float along = 2.5f + (float)(a + b);
            float x[3];
            for (int i = 0; i < 3; i++)
                x[i] = position[i] + along * (forward[i] + right[i] * (2 * u - 1) * tan_x + up[i] * (1 - 2 * v) * tan_y);
            float jx = jitters[b][0] - 0.5f, jy = jitters[b][1] - 0.5f;
            uint32_t p = pixels[a][1] * width + pixels[a][0];
            CHECK_NEAR(ns_from_pixel_centre(&cam, width, height, p, x), jx * jx + jy * jy, 1e-4);
        }
    const float behind[3] = {1, 2, 4};
    CHECK(isinf(ns_from_pixel_centre(&cam, width, height, 0, behind)));
}

int main(void)
{
    RUN(test_linear_field_is_interpolated_exactly);
    RUN(test_tiles_upsample_a_linear_field_exactly);
    RUN(test_parabola_interpolated_where_its_error_is_within_tolerance);
    RUN(test_other_light_counts_in_the_tolerance);
    RUN(test_nothing_crosses_media_or_surfaces);
    RUN(test_no_levels_or_no_tolerance_gathers_everything);
    RUN(test_curved_values_are_exact_for_a_parabola);
    RUN(test_noise_lets_an_interpolation_no_worse_than_computing_through);
    RUN(test_pixel_variance_is_the_ratio_estimators);
    RUN(test_pixel_centre_distance_is_the_jitter);
    return harness_report();
}
