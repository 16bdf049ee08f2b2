/* image_metrics.c — load EXR/PNG as linear RGB, PSNR/RMSE/relative error, false colour. */
#include "image_metrics.h"

#include <assert.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include <tinyexr.h>

/* stb_image, PNG only, compiled here with its functions static so it cannot clash with
 * the copy in libstb.so (encode.c does the same with stb_image_write). */
#define STB_IMAGE_IMPLEMENTATION
#define STB_IMAGE_STATIC
#define STBI_ONLY_PNG
#define STBI_NO_STDIO
/* Static declarations of stb's unused loaders (GIF, ...) are reported at the end of the
 * file, so -Wunused-function stays off for all of it. */
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wshadow"
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Wunused-but-set-variable"
#include <stb/stb_image.h>
#pragma GCC diagnostic pop

/* Larger files than this are refused before reading: the largest image nscatter renders
 * (NS_MAX_PIXELS, 32-bit float RGB, uncompressed) is 192 MiB. */
#define IMAGE_MAX_FILE_BYTES (512u << 20)

/* ---------------------------------------------------------------------------------------
 * Loading.
 * ------------------------------------------------------------------------------------- */
static int image_read_file(const char *path, unsigned char **data, size_t *size, ns_error *err)
{
    *data = NULL;
    *size = 0;
    FILE *f = fopen(path, "rb");
    if (!f)
        return ns_fail(err, NS_ERR_IO, "cannot open '%s': %s", path, strerror(errno));
    int status = NS_OK;
    struct stat st;
    long length = -1;
    if (fstat(fileno(f), &st) == 0 && S_ISREG(st.st_mode) && fseek(f, 0, SEEK_END) == 0)
        length = ftell(f);
    if (length < 0 || fseek(f, 0, SEEK_SET) != 0) {
        status = ns_fail(err, NS_ERR_IO, "cannot read '%s': not a regular file", path);
    } else if ((unsigned long)length > IMAGE_MAX_FILE_BYTES) {
        status = ns_fail(err, NS_ERR_LIMIT, "'%s' is %ld bytes, more than the %u MiB limit",
                            path, length, IMAGE_MAX_FILE_BYTES >> 20);
    } else {
        *data = malloc(length > 0 ? (size_t)length : 1);
        if (!*data)
            status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "no memory to read '%s'", path);
        else if (fread(*data, 1, (size_t)length, f) != (size_t)length)
            status = ns_fail(err, NS_ERR_IO, "cannot read '%s': %s", path, strerror(errno));
        else
            *size = (size_t)length;
    }
    fclose(f);
    if (status) {
        free(*data);
        *data = NULL;
    }
    return status;
}

static const unsigned char image_exr_magic[4] = {0x76, 0x2f, 0x31, 0x01};
static const unsigned char image_png_magic[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};

static float image_srgb_to_linear(float v)
{
    return v <= 0.04045f ? v / 12.92f : powf((v + 0.055f) / 1.055f, 2.4f);
}

static int image_alloc(ns_image *out, uint32_t width, uint32_t height, ns_error *err,
                       const char *path)
{
    out->width = width;
    out->height = height;
    out->rgb = malloc((size_t)width * height * 3 * sizeof(float));
    if (!out->rgb) {
        memset(out, 0, sizeof *out);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "no memory for '%s'", path);
    }
    return NS_OK;
}

static int image_decode_exr(const char *path, const unsigned char *data, size_t size, ns_image *out,
                            ns_error *err)
{
    float *rgba = NULL;
    int width = 0, height = 0;
    const char *exr_err = NULL;
    int rc = LoadEXRFromMemory(&rgba, &width, &height, data, size, &exr_err);
    if (rc != TINYEXR_SUCCESS || width <= 0 || height <= 0) {
        ns_fail(err, NS_ERR_INVALID_ARGUMENT, "'%s' is not a readable EXR image: %s", path,
                   exr_err ? exr_err : "unknown tinyexr error");
        if (exr_err)
            FreeEXRErrorMessage(exr_err);
        free(rgba);
        return NS_ERR_INVALID_ARGUMENT;
    }
    int status = image_alloc(out, (uint32_t)width, (uint32_t)height, err, path);
    if (status == NS_OK) {
        size_t n = (size_t)width * (size_t)height;
        for (size_t i = 0; i < n; i++)
            for (int c = 0; c < 3; c++)
                out->rgb[3 * i + c] = rgba[4 * i + c];
    }
    free(rgba);
    return status;
}

static int image_decode_png(const char *path, const unsigned char *data, size_t size, ns_image *out,
                            ns_error *err)
{
    if (size > INT32_MAX)
        return ns_fail(err, NS_ERR_LIMIT, "'%s' is too large", path);
    int width = 0, height = 0, channels = 0;
    /* 16-bit decoding serves both depths: 8-bit values come back as v * 257, exactly
     * v / 255 after the division below. */
    stbi_us *px = stbi_load_16_from_memory(data, (int)size, &width, &height, &channels, 3);
    if (!px)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "'%s' is not a readable PNG image: %s",
                          path, stbi_failure_reason());
    int status = image_alloc(out, (uint32_t)width, (uint32_t)height, err, path);
    if (status == NS_OK) {
        size_t n = (size_t)width * (size_t)height * 3;
        for (size_t i = 0; i < n; i++)
            out->rgb[i] = image_srgb_to_linear((float)px[i] / 65535.0f);
    }
    stbi_image_free(px);
    return status;
}

int image_load(const char *path, ns_image *out, ns_error *err)
{
    memset(out, 0, sizeof *out);
    unsigned char *data;
    size_t size;
    int status = image_read_file(path, &data, &size, err);
    if (status)
        return status;
    if (size >= sizeof image_exr_magic && !memcmp(data, image_exr_magic, sizeof image_exr_magic))
        status = image_decode_exr(path, data, size, out, err);
    else if (size >= sizeof image_png_magic &&
             !memcmp(data, image_png_magic, sizeof image_png_magic))
        status = image_decode_png(path, data, size, out, err);
    else
        status = ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                            "'%s' is neither an EXR nor a PNG image (unknown magic bytes)", path);
    free(data);
    return status;
}

int image_load_mask(const char *path, uint8_t **mask, uint32_t *width, uint32_t *height,
                    ns_error *err)
{
    *mask = NULL;
    ns_image img;
    int status = image_load(path, &img, err);
    if (status)
        return status;
    size_t n = (size_t)img.width * img.height;
    *mask = malloc(n ? n : 1);
    if (!*mask) {
        ns_image_free(&img);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "no memory for mask '%s'", path);
    }
    for (size_t i = 0; i < n; i++) {
        const float *p = img.rgb + 3 * i;
        (*mask)[i] = p[0] != 0.0f || p[1] != 0.0f || p[2] != 0.0f;
    }
    *width = img.width;
    *height = img.height;
    ns_image_free(&img);
    return NS_OK;
}

/* ---------------------------------------------------------------------------------------
 * Metrics.
 * ------------------------------------------------------------------------------------- */
void image_compare(const ns_image *a, const ns_image *b, const uint8_t *mask, image_metrics *m)
{
    assert(a->width == b->width && a->height == b->height);
    memset(m, 0, sizeof *m);
    double sq[3] = {0}, rel[3] = {0}, sum_a[3] = {0}, sum_b[3] = {0};
    uint64_t counted[3] = {0};
    double peak = 0.0;
    int identical = 1;
    size_t n = (size_t)a->width * a->height;
    for (size_t i = 0; i < n; i++) {
        if (mask && !mask[i])
            continue;
        m->pixels++;
        for (int c = 0; c < 3; c++) {
            double va = a->rgb[3 * i + c], vb = b->rgb[3 * i + c];
            if (!isfinite(va) || !isfinite(vb)) {
                m->nonfinite++;
                identical = 0;
                continue;
            }
            double d = va - vb;
            if (d != 0.0)
                identical = 0;
            sq[c] += d * d;
            rel[c] += fabs(d) / (fabs(vb) + IMAGE_RELERR_EPSILON);
            sum_a[c] += va;
            sum_b[c] += vb;
            counted[c]++;
            if (vb > peak)
                peak = vb;
            if (fabs(d) > m->max_abs_diff)
                m->max_abs_diff = fabs(d);
        }
    }
    double sq_all = 0.0, rel_all = 0.0;
    uint64_t counted_all = 0;
    for (int c = 0; c < 3; c++) {
        m->rmse[c] = counted[c] ? sqrt(sq[c] / (double)counted[c]) : NAN;
        m->relerr[c] = counted[c] ? rel[c] / (double)counted[c] : NAN;
        sq_all += sq[c];
        rel_all += rel[c];
        counted_all += counted[c];
    }
    for (int c = 0; c < 3; c++)
        m->mean_ratio[c] = sum_b[c] != 0.0 ? sum_a[c] / sum_b[c] : NAN;
    double total_b = sum_b[0] + sum_b[1] + sum_b[2];
    m->mean_ratio[3] = total_b != 0.0 ? (sum_a[0] + sum_a[1] + sum_a[2]) / total_b : NAN;
    m->rmse[3] = counted_all ? sqrt(sq_all / (double)counted_all) : NAN;
    m->relerr[3] = counted_all ? rel_all / (double)counted_all : NAN;
    m->peak = counted_all ? peak : NAN;
    for (int c = 0; c < 4; c++) {
        if (!(m->peak > 0.0) || isnan(m->rmse[c]))
            m->psnr[c] = NAN;
        else if (m->rmse[c] == 0.0)
            m->psnr[c] = INFINITY;
        else
            m->psnr[c] = 20.0 * log10(m->peak / m->rmse[c]);
    }
    m->identical = identical && m->pixels > 0;
}

/* ---------------------------------------------------------------------------------------
 * False colour.
 * ------------------------------------------------------------------------------------- */
void image_ramp_srgb(double t, double rgb[3])
{
    /* Control points of an inferno-like ramp (sRGB), evenly spaced in t. */
    static const double stops[][3] = {
        {0.000, 0.000, 0.016}, {0.258, 0.039, 0.406}, {0.576, 0.149, 0.404},
        {0.865, 0.317, 0.226}, {0.988, 0.645, 0.040}, {0.988, 1.000, 0.645},
    };
    const int last = (int)(sizeof stops / sizeof stops[0]) - 1;
    if (!(t > 0.0))
        t = 0.0;
    if (t > 1.0)
        t = 1.0;
    double x = t * last;
    int i = (int)x;
    if (i >= last)
        i = last - 1;
    double f = x - i;
    for (int c = 0; c < 3; c++)
        rgb[c] = stops[i][c] + f * (stops[i + 1][c] - stops[i][c]);
}

int image_diff_false_colour(const ns_image *a, const ns_image *b, const uint8_t *mask, double scale,
                            ns_image *out, double *used_scale, ns_error *err)
{
    assert(a->width == b->width && a->height == b->height);
    size_t n = (size_t)a->width * a->height;
    int status = image_alloc(out, a->width, a->height, err, "difference image");
    if (status)
        return status;
    if (!(scale > 0.0)) {
        scale = 0.0;
        for (size_t i = 0; i < n; i++) {
            if (mask && !mask[i])
                continue;
            double d = 0.0;
            for (int c = 0; c < 3; c++)
                d += fabs((double)a->rgb[3 * i + c] - b->rgb[3 * i + c]) / 3.0;
            if (isfinite(d) && d > scale)
                scale = d;
        }
        if (!(scale > 0.0))
            scale = 1.0; /* identical images: all pixels at the bottom of the ramp */
    }
    for (size_t i = 0; i < n; i++) {
        float *o = out->rgb + 3 * i;
        if (mask && !mask[i]) {
            o[0] = o[1] = o[2] = 0.0f;
            continue;
        }
        double d = 0.0;
        for (int c = 0; c < 3; c++)
            d += fabs((double)a->rgb[3 * i + c] - b->rgb[3 * i + c]) / 3.0;
        double srgb[3];
        /* Non-finite differences show at the top of the ramp: they are the worst pixels. */
        image_ramp_srgb(isfinite(d) ? d / scale : 1.0, srgb);
        for (int c = 0; c < 3; c++)
            o[c] = image_srgb_to_linear((float)srgb[c]);
    }
    *used_scale = scale;
    return NS_OK;
}
