/* image_metrics.h — image comparison for `nscatter compare`: loading EXR/PNG as linear
 * RGB, the paper's error metrics (PSNR, RMSE, mean relative error) over an optional mask,
 * and a false-colour difference image.
 *
 * Definitions (docs/cli.md, "nscatter compare", says the same):
 *   n      = number of pixels counted (all, or the mask's non-zero pixels)
 *   RMSE_c = sqrt( sum_p (A_c(p) - B_c(p))^2 / n )                 per channel c
 *   RMSE   = sqrt( sum_p sum_c (A_c(p) - B_c(p))^2 / (3 n) )       overall
 *   peak   = max over the counted pixels and all channels of the reference B
 *   PSNR   = 20 log10(peak / RMSE)                                 per channel and overall,
 *            with the same overall peak everywhere so the numbers compare
 *   relerr = mean over counted pixels (and channels) of |A - B| / (|B| + eps), eps = 0.01
 *            (the epsilon keeps black reference pixels from dominating; 0.01 is 1% of a
 *            unit-radiance pixel, the scale of the scenes' lights)
 * B is the reference: the second argument of `nscatter compare`.
 *
 * Ownership: image_load fills an ns_image whose rgb the caller frees with ns_image_free.
 * Results are 0 or a negative ns_status; err names the file.
 */
#ifndef NS_IMAGE_METRICS_H
#define NS_IMAGE_METRICS_H

#include <stddef.h>
#include <stdint.h>

#include "nscatter.h"

#define IMAGE_RELERR_EPSILON 0.01

/* Loads a .exr (R, G, B channels, any pixel type tinyexr reads; a single Y channel is
 * copied to all three) or a .png (8/16-bit, sRGB decoded to linear). The type is decided
 * by the file's magic bytes, not its name. Missing file: NS_ERR_IO; unreadable content:
 * NS_ERR_INVALID_ARGUMENT. */
int image_load(const char *path, ns_image *out, ns_error *err);

/* A mask: width*height bytes, 1 where a pixel counts (any non-zero channel in the file). */
int image_load_mask(const char *path, uint8_t **mask, uint32_t *width, uint32_t *height,
                    ns_error *err);

typedef struct image_metrics {
    uint64_t pixels;     /* pixels counted */
    double peak;         /* max of the reference over counted pixels, all channels */
    double rmse[4];      /* R, G, B, overall */
    double psnr[4];      /* +INFINITY when the RMSE is 0; NaN when peak is 0 */
    double relerr[4];    /* mean relative error, R, G, B, overall */
    double mean_ratio[4]; /* mean of A over mean of B, R, G, B, overall (NaN when B's is 0):
                             the bias a scattering model leaves, apart from its noise */
    double max_abs_diff; /* largest |A - B| over counted pixels and channels */
    int identical;       /* every counted value equal (bit for bit after loading) */
    uint64_t nonfinite;  /* counted values where A or B is NaN/Inf (excluded) */
} image_metrics;

/* a: the image under test, b: the reference; mask may be NULL (all pixels). Sizes must
 * match (checked by the caller, asserted here). No counted pixel gives pixels = 0 and
 * NaN metrics. */
void image_compare(const ns_image *a, const ns_image *b, const uint8_t *mask, image_metrics *m);

/* False-colour map of the per-pixel difference |A - B| averaged over channels, scaled so
 * that `scale` maps to the top of the colour ramp (values above are clamped); pixels
 * outside the mask are black. The result is linear RGB ready for encode_png at exposure
 * 0 (the ramp is defined in sRGB and linearised so that the PNG shows it exactly).
 * scale <= 0 picks the largest counted difference (returned through used_scale). */
int image_diff_false_colour(const ns_image *a, const ns_image *b, const uint8_t *mask, double scale,
                            ns_image *out, double *used_scale, ns_error *err);

/* The colour ramp, t in [0, 1] -> sRGB in [0, 1]: black-blue-magenta-orange-yellow-white
 * ("inferno"-like, monotonic in luminance so it reads in grey too). Exposed for tests. */
void image_ramp_srgb(double t, double rgb[3]);

#endif
