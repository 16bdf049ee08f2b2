/* unit_adaptive.c — where render.adaptive_spp's added camera samples go (render/adaptive.c):
 * by the neighbours' spread only, in proportion to it (Neyman's allocation), within the budget
 * and the per-pixel cap; and how they join the pixels' first samples. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "harness.h"
#include "internal.h"

enum { W = 13, H = 11, PIXELS = W * H };

/* A camera-pass image (mean, mean squared length) whose pixel p has one sample's variance
 * var[p] about the mean value v in each channel: mean^2 summed + var. */
static void fill(float *pixels, const double *var, double v)
{
    for (int p = 0; p < PIXELS; p++) {
        for (int c = 0; c < 3; c++)
            pixels[4 * p + c] = (float)v;
        pixels[4 * p + 3] = (float)(3 * v * v + var[p]);
    }
}

static uint64_t sum_counts(const uint32_t *counts)
{
    uint64_t total = 0;
    for (int p = 0; p < PIXELS; p++)
        total += counts[p];
    return total;
}

/* A lone pixel whose samples spread gets none of the added samples: its count is read from
 * its neighbours, never from its own samples (its mean would lean towards what they happened
 * to be); the 24 pixels within 2 of it get them, equally, and nothing else does. */
static void test_neighbours_not_self(void)
{
    double var[PIXELS] = {0};
    const int cx = 6, cy = 5, centre = cy * W + cx;
    var[centre] = 8.0;
    float pixels[4 * PIXELS];
    fill(pixels, var, 0.5);
    uint32_t counts[PIXELS];
    const uint32_t spp = 4;
    uint64_t total = ns_adaptive_plan(pixels, W, H, spp, 48, 1000, counts);
    CHECK_INT(total, sum_counts(counts));
    CHECK_INT(counts[centre], 0);
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            int neighbour = abs(x - cx) <= 2 && abs(y - cy) <= 2 && !(x == cx && y == cy);
            if (neighbour)
                CHECK_INT(counts[y * W + x], 2); /* 48 over 24 equal pixels */
            else if (!(x == cx && y == cy))
                CHECK_INT(counts[y * W + x], 0);
        }
    CHECK_INT(total, 48);
}

/* Two halves whose samples spread with standard deviations 1 and 3: a pixel's samples in
 * all (its spp and its added ones) are in proportion to its sigma, the allocation that
 * minimises the summed variance of the means, within the rounding of one sample. */
static void test_neyman_proportions(void)
{
    double var[PIXELS];
    for (int p = 0; p < PIXELS; p++)
        var[p] = p % W < W / 2 ? 1.0 : 9.0;
    float pixels[4 * PIXELS];
    fill(pixels, var, 2.0);
    uint32_t counts[PIXELS];
    const uint32_t spp = 2;
    const uint64_t budget = 12 * PIXELS;
    uint64_t total = ns_adaptive_plan(pixels, W, H, spp, budget, 1000, counts);
    CHECK(total <= budget);
    CHECK(total + PIXELS >= budget); /* at most one sample a pixel lost to rounding */
    /* Away from the border between them (x = 4 to 7 see both halves). */
    for (int y = 0; y < H; y++) {
        double low = spp + counts[y * W + 1], high = spp + counts[y * W + 10];
        CHECK_NEAR(high / low, 3.0, 3.0 * 2.0 / low);
    }
}

/* No pixel takes more than the cap; what the cap leaves goes to the others, in proportion. */
static void test_cap(void)
{
    double var[PIXELS];
    for (int p = 0; p < PIXELS; p++)
        var[p] = p / W < 2 ? 100.0 : 1.0;
    float pixels[4 * PIXELS];
    fill(pixels, var, 1.0);
    uint32_t counts[PIXELS];
    uint64_t total = ns_adaptive_plan(pixels, W, H, 4, 30 * PIXELS, 50, counts);
    for (int p = 0; p < PIXELS; p++)
        CHECK(counts[p] <= 50);
    CHECK_INT(counts[0], 50);        /* the spread rows are capped */
    CHECK(counts[6 * W + 4] > 0);    /* and the quiet ones take the rest */
    CHECK(total <= 30 * PIXELS);
}

/* Nothing to place by: one sample per pixel has no spread, an image without spread has none,
 * and a zero budget adds nothing. */
static void test_nothing_to_add(void)
{
    double var[PIXELS];
    for (int p = 0; p < PIXELS; p++)
        var[p] = 1.0;
    float pixels[4 * PIXELS];
    fill(pixels, var, 1.0);
    uint32_t counts[PIXELS];
    CHECK_INT(ns_adaptive_plan(pixels, W, H, 1, 100, 10, counts), 0);
    CHECK_INT(sum_counts(counts), 0);
    CHECK_INT(ns_adaptive_plan(pixels, W, H, 4, 0, 10, counts), 0);
    double none[PIXELS] = {0};
    fill(pixels, none, 1.0);
    CHECK_INT(ns_adaptive_plan(pixels, W, H, 4, 100, 10, counts), 0);
    CHECK_INT(sum_counts(counts), 0);
}

/* Float rounding can leave a pixel's spread slightly below zero: it counts as none, so the
 * plan is the one where that pixel's spread is exactly zero (a negative one would lower its
 * neighbours' sigma, or make it NaN). */
static void test_negative_spread_is_none(void)
{
    double var[PIXELS];
    for (int p = 0; p < PIXELS; p++)
        var[p] = p % 3 ? 1.0 : 4.0;
    var[5 * W + 6] = 0.0;
    float pixels[4 * PIXELS];
    fill(pixels, var, 1.0);
    uint32_t exact[PIXELS], rounded[PIXELS];
    uint64_t a = ns_adaptive_plan(pixels, W, H, 4, 5 * PIXELS, 100, exact);
    pixels[4 * (5 * W + 6) + 3] -= 0.5f; /* mean square below mean squared */
    uint64_t b = ns_adaptive_plan(pixels, W, H, 4, 5 * PIXELS, 100, rounded);
    CHECK(a > 0);
    CHECK_INT(a, b);
    CHECK(memcmp(exact, rounded, sizeof exact) == 0);
}

/* The entries name each pixel's added samples by the indices after its spp, and the merge
 * makes each pixel the mean of all its samples; pixels without added samples stay as they
 * were, bit for bit. */
static void test_entries_and_merge(void)
{
    const uint32_t spp = 4;
    uint32_t counts[PIXELS] = {0};
    counts[3] = 2;
    counts[10] = 1;
    float pixels[4 * PIXELS];
    for (int i = 0; i < 4 * PIXELS; i++)
        pixels[i] = 0.25f * (float)(i % 7);
    float before[4 * PIXELS];
    memcpy(before, pixels, sizeof pixels);
    GpuAddedSample entries[3];
    ns_adaptive_entries(counts, 0, PIXELS, spp, entries);
    const uint32_t want[3][2] = {{3, 4}, {3, 5}, {10, 4}};
    for (int e = 0; e < 3; e++) {
        CHECK_INT(entries[e].words[0], want[e][0]);
        CHECK_INT(entries[e].words[1], want[e][1]);
    }
    /* A range of pixels names them by their place in the image. */
    GpuAddedSample part[3];
    ns_adaptive_entries(counts + 3, 3, 8, spp, part);
    for (int e = 0; e < 3; e++)
        CHECK(memcmp(part[e].words, entries[e].words, sizeof part[e].words) == 0);
    /* What camera.comp would return: the bits of the samples' radiance. */
    const float radiance[3][3] = {{1, 2, 3}, {3, 2, 1}, {8, 8, 8}};
    for (int e = 0; e < 3; e++)
        memcpy(entries[e].words, radiance[e], sizeof radiance[e]);
    ns_adaptive_merge(pixels, PIXELS, spp, counts, entries);
    for (int c = 0; c < 3; c++) {
        CHECK_NEAR(pixels[4 * 3 + c], (4 * before[4 * 3 + c] + radiance[0][c] + radiance[1][c]) / 6,
                   1e-6);
        CHECK_NEAR(pixels[4 * 10 + c], (4 * before[4 * 10 + c] + radiance[2][c]) / 5, 1e-6);
    }
    for (int p = 0; p < PIXELS; p++)
        if (p != 3 && p != 10)
            CHECK(memcmp(pixels + 4 * p, before + 4 * p, 4 * sizeof(float)) == 0);
}

/* The setting as the camera pass uses it: none for pt, at one sample per pixel, or without
 * the surface component (all the light they add). */
static void test_where_it_applies(void)
{
    ns_render_settings r = {.method = NS_METHOD_NN, .spp = 4, .adaptive_spp = 2.0f,
                            .components = NS_COMPONENT_ALL};
    CHECK_NEAR(ns_adaptive_spp_used(&r), 2.0, 0);
    ns_render_settings pt = r, one = r, scattering = r;
    pt.method = NS_METHOD_PT;
    one.spp = 1;
    scattering.components = NS_COMPONENT_MULTIPLE;
    CHECK_NEAR(ns_adaptive_spp_used(&pt), 0, 0);
    CHECK_NEAR(ns_adaptive_spp_used(&one), 0, 0);
    CHECK_NEAR(ns_adaptive_spp_used(&scattering), 0, 0);
}

int main(void)
{
    RUN(test_neighbours_not_self);
    RUN(test_neyman_proportions);
    RUN(test_cap);
    RUN(test_nothing_to_add);
    RUN(test_negative_spread_is_none);
    RUN(test_entries_and_merge);
    RUN(test_where_it_applies);
    return harness_report();
}
