/* adaptive.c — render.adaptive_spp: which pixels the added camera samples go to, and how
 * they join each pixel's first spp samples (render.c runs them through camera.comp).
 *
 * Why: at a few samples per pixel the surface image's error sits in few pixels (a glint of a
 * light seen in a bumpy dielectric, an edge, a soft shadow's rim): on the bench's bunny 100
 * of 16,384 pixels hold 80% of the squared error at 4 spp. Samples spent there, in
 * proportion to each pixel's spread (Neyman's allocation: it minimises the summed variance
 * of the pixels' means for a given number of samples), bring the image nearer a converged
 * one than the same number spread over every pixel (docs/bench.md, *Adaptive camera
 * samples*).
 *
 * Unbiased: a pixel whose count were read from its own samples would take more samples
 * where its first ones happened to spread, and its mean would lean towards the value they
 * happened to have (a glint caught by one of four samples is kept and refined; one missed by
 * all four is kept at black). So a pixel's spread is read from its neighbours' samples,
 * which are independent of its own (each pixel has its own random streams and its own shift
 * of the low-discrepancy points): given its count, its samples are spp + count independent
 * draws of the same estimator, and their mean is unbiased. The one global number, the scale
 * that makes the counts add up to the budget, is read from every pixel, so a pixel's own
 * samples move its count through it by about one part in the image's pixel count. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

/* A pixel's spread is read from the pixels within this many of it (a 5 x 5 square but its
 * centre). With its eight nearest alone, a pixel that is the only one its feature's edge
 * crosses got nothing: the leftmost sliver of the candle's flame, 5% covered, one of its four
 * samples on the flame (60 against 0.05) and all eight neighbours pure flame or pure sky,
 * held most of the candle's error (its surface 57.0 dB at every budget; 64.5 dB with the
 * 24; radius 3: 63.8). Elsewhere radius 1 and 2 are within 0.3 dB (docs/bench.md). */
#define NEIGHBOUR_RADIUS 2

/* Total added samples of the counts that `scale` gives: round(scale x sigma) samples in
 * all for each pixel, of which spp it has, at most cap added. */
static uint64_t counts_at(const double *sigma, size_t pixels, double scale, uint32_t spp,
                          uint32_t cap, uint32_t *counts)
{
    uint64_t total = 0;
    const double most = (double)spp + cap;
    for (size_t p = 0; p < pixels; p++) {
        double want = scale * sigma[p] + 0.5; /* rounded below by the conversion */
        uint32_t n = want >= most + 1.0 ? cap : want < spp + 1.0 ? 0 : (uint32_t)want - spp;
        if (counts)
            counts[p] = n;
        total += n;
    }
    return total;
}

/* sum[p] := the sum of values over the pixels within NEIGHBOUR_RADIUS of p in x (a row's
 * window), then, applied to that, in y: a box sum in two passes of 5 reads each. */
static void window_sums(const double *values, uint32_t width, uint32_t height, int along_x,
                        double *sum)
{
    for (uint32_t y = 0; y < height; y++)
        for (uint32_t x = 0; x < width; x++) {
            long at = along_x ? x : y, size = along_x ? width : height;
            long lo = at - NEIGHBOUR_RADIUS < 0 ? 0 : at - NEIGHBOUR_RADIUS;
            long hi = at + NEIGHBOUR_RADIUS >= size ? size - 1 : at + NEIGHBOUR_RADIUS;
            double total = 0.0;
            for (long k = lo; k <= hi; k++)
                total += along_x ? values[(size_t)y * width + k] : values[(size_t)k * width + x];
            sum[(size_t)y * width + x] = total;
        }
}

static long window_size(long at, long size)
{
    long lo = at - NEIGHBOUR_RADIUS < 0 ? 0 : at - NEIGHBOUR_RADIUS;
    long hi = at + NEIGHBOUR_RADIUS >= size ? size - 1 : at + NEIGHBOUR_RADIUS;
    return hi - lo + 1;
}

uint64_t ns_adaptive_plan(const float *pixels, uint32_t width, uint32_t height, uint32_t spp,
                          uint64_t budget, uint32_t cap, uint32_t *counts)
{
    size_t n = (size_t)width * height;
    memset(counts, 0, n * sizeof *counts);
    if (spp < 2 || budget == 0 || cap == 0 || n == 0)
        return 0;
    double *spread = malloc(n * sizeof *spread), *rows = malloc(n * sizeof *rows),
           *sigma = malloc(n * sizeof *sigma);
    if (!spread || !rows || !sigma) {
        free(spread);
        free(rows);
        free(sigma);
        return UINT64_MAX;
    }
    /* Each pixel's variance of one sample (summed over r, g, b), from its samples' mean and
     * mean squared length, with Bessel's correction. */
    for (size_t p = 0; p < n; p++) {
        const float *v = pixels + 4 * p;
        double mean2 = (double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2];
        double s = ((double)v[3] - mean2) * spp / (spp - 1);
        spread[p] = s > 0.0 && isfinite(s) ? s : 0.0;
    }
    /* A pixel's own: the mean of its neighbours' (those inside the image, itself left out),
     * as sigma. */
    window_sums(spread, width, height, 1, rows);
    window_sums(rows, width, height, 0, sigma);
    double smallest = INFINITY, largest = 0.0;
    for (uint32_t y = 0; y < height; y++)
        for (uint32_t x = 0; x < width; x++) {
            size_t p = (size_t)y * width + x;
            long count = window_size(x, width) * window_size(y, height) - 1;
            double sum = sigma[p] - spread[p];
            double s = count > 0 && sum > 0.0 ? sqrt(sum / count) : 0.0;
            sigma[p] = s;
            if (s > 0.0 && s < smallest)
                smallest = s;
            if (s > largest)
                largest = s;
        }
    uint64_t total = 0;
    if (largest > 0.0) {
        /* The largest scale whose counts fit the budget, by bisection in its logarithm, to
         * within a thousandth of the budget: the total grows with the scale, from 0 below
         * spp / max(sigma) to every pixel capped above (spp + cap + 1) / min(sigma). */
        double lo = log(spp / largest), hi = log((spp + cap + 1.0) / smallest);
        if (counts_at(sigma, n, exp(hi), spp, cap, NULL) <= budget)
            lo = hi;
        else
            for (int i = 0; i < 64 && hi - lo > 1e-9; i++) {
                double mid = 0.5 * (lo + hi);
                uint64_t at = counts_at(sigma, n, exp(mid), spp, cap, NULL);
                if (at > budget) {
                    hi = mid;
                    continue;
                }
                lo = mid;
                if (budget - at <= budget / 1000)
                    break;
            }
        total = counts_at(sigma, n, exp(lo), spp, cap, counts);
    }
    free(spread);
    free(rows);
    free(sigma);
    return total;
}

void ns_adaptive_entries(const uint32_t *counts, size_t first, size_t pixels, uint32_t spp,
                         GpuAddedSample *entries)
{
    size_t e = 0;
    for (size_t p = 0; p < pixels; p++)
        for (uint32_t k = 0; k < counts[p]; k++, e++) {
            memset(&entries[e], 0, sizeof entries[e]);
            entries[e].words[0] = (uint32_t)(first + p);
            entries[e].words[1] = spp + k;
        }
}

void ns_adaptive_merge(float *pixels, size_t count, uint32_t spp, const uint32_t *counts,
                       const GpuAddedSample *entries)
{
    size_t e = 0;
    for (size_t p = 0; p < count; p++) {
        if (!counts[p])
            continue;
        double sum[3] = {0.0, 0.0, 0.0};
        for (uint32_t k = 0; k < counts[p]; k++, e++) {
            float radiance[3];
            memcpy(radiance, entries[e].words, sizeof radiance);
            for (int c = 0; c < 3; c++)
                sum[c] += radiance[c];
        }
        double all = (double)spp + counts[p];
        for (int c = 0; c < 3; c++)
            pixels[4 * p + c] = (float)(((double)pixels[4 * p + c] * spp + sum[c]) / all);
    }
}
