/* encode.c — PNG (stb_image_write + zlib) and EXR (tinyexr) encoders with metadata. */
#include "encode.h"

#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <tinyexr.h>
#include <zlib.h>

/* ---------------------------------------------------------------------------------------
 * stb_image_write, compiled here with its functions static so it cannot clash with the
 * copy in libstb.so, and with zlib doing the deflate: stb's own compressor is simple and
 * produces files 10-30% larger than zlib's.
 * ------------------------------------------------------------------------------------- */
static unsigned char *encode_zlib_compress(unsigned char *data, int data_len, int *out_len,
                                           int quality);
#define STB_IMAGE_WRITE_IMPLEMENTATION
#define STB_IMAGE_WRITE_STATIC
#define STBI_WRITE_NO_STDIO
#define STBIW_ZLIB_COMPRESS encode_zlib_compress
/* Static declarations of stb's unused writers (HDR, BMP, ...) are reported at the end of
 * the file, so -Wunused-function stays off for all of it. */
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wshadow"
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#include <stb/stb_image_write.h>
#pragma GCC diagnostic pop

/* stb asks for a buffer it releases with STBIW_FREE (free); a NULL return makes
 * stbi_write_png_to_mem fail cleanly. */
static unsigned char *encode_zlib_compress(unsigned char *data, int data_len, int *out_len,
                                           int quality)
{
    /* stb's default quality is 8; zlib level 6 is within a few percent of 9 in size at
     * a fraction of the time, which matters for large renders served over HTTP. */
    (void)quality;
    uLongf bound = compressBound((uLong)data_len);
    unsigned char *buf = malloc(bound);
    if (!buf)
        return NULL;
    if (compress2(buf, &bound, data, (uLong)data_len, 6) != Z_OK || bound > INT_MAX) {
        free(buf);
        return NULL;
    }
    *out_len = (int)bound;
    return buf;
}

/* ---------------------------------------------------------------------------------------
 * Shared helpers.
 * ------------------------------------------------------------------------------------- */
static int encode_fail(ns_error *err, int status, const char *fmt, ...)
{
    if (err) {
        va_list ap;
        va_start(ap, fmt);
        err->status = status;
        vsnprintf(err->message, sizeof err->message, fmt, ap);
        va_end(ap);
    }
    return status;
}

static int encode_check_image(const ns_image *img, ns_error *err)
{
    if (!img || !img->rgb)
        return encode_fail(err, NS_ERR_INVALID_ARGUMENT, "encode: no image");
    if (img->width == 0 || img->height == 0)
        return encode_fail(err, NS_ERR_INVALID_ARGUMENT, "encode: empty image %ux%u", img->width,
                           img->height);
    /* The renderer's own limits, which also keep stride and pixel counts far from int
     * overflow in the third-party encoders. */
    if (img->width > NS_MAX_IMAGE_SIDE || img->height > NS_MAX_IMAGE_SIDE ||
        (uint64_t)img->width * img->height > NS_MAX_PIXELS)
        return encode_fail(err, NS_ERR_LIMIT, "encode: image %ux%u over the size limits",
                           img->width, img->height);
    return 0;
}

void encode_buffer_free(encode_buffer *buf)
{
    if (!buf)
        return;
    free(buf->data);
    buf->data = NULL;
    buf->size = 0;
}

const char *encode_mime_type(encode_format format)
{
    return format == ENCODE_PNG ? "image/png" : "image/x-exr";
}

/* ---------------------------------------------------------------------------------------
 * PNG.
 * ------------------------------------------------------------------------------------- */
uint8_t encode_srgb8(float linear, float scale)
{
    float v = linear * scale;
    if (!(v > 0.0f)) /* also catches NaN */
        return 0;
    if (v >= 1.0f)
        return 255;
    float srgb = v <= 0.0031308f ? 12.92f * v : 1.055f * powf(v, 1.0f / 2.4f) - 0.055f;
    int q = (int)(srgb * 255.0f + 0.5f);
    return (uint8_t)(q < 0 ? 0 : q > 255 ? 255 : q);
}

/* PNG tEXt keywords: 1-79 printable Latin-1 characters, no leading, trailing or double
 * spaces (PNG spec 11.3.4.2). Values are Latin-1 without NUL; we write ASCII/UTF-8 JSON. */
static int png_keyword_ok(const char *key)
{
    size_t n = key ? strlen(key) : 0;
    if (n < 1 || n > 79 || key[0] == ' ' || key[n - 1] == ' ')
        return 0;
    for (size_t i = 0; i < n; i++) {
        unsigned char c = (unsigned char)key[i];
        if (c < 32 || (c > 126 && c < 161) || (c == ' ' && key[i + 1] == ' '))
            return 0;
    }
    return 1;
}

static void put_be32(unsigned char *p, uint32_t v)
{
    p[0] = (unsigned char)(v >> 24);
    p[1] = (unsigned char)(v >> 16);
    p[2] = (unsigned char)(v >> 8);
    p[3] = (unsigned char)v;
}

/* Writes one tEXt chunk at p (length, type, keyword NUL value, CRC over type and data);
 * returns the bytes written. */
static size_t png_write_text_chunk(unsigned char *p, const encode_text *t)
{
    size_t key_len = strlen(t->key), value_len = strlen(t->value);
    size_t data_len = key_len + 1 + value_len;
    put_be32(p, (uint32_t)data_len);
    memcpy(p + 4, "tEXt", 4);
    memcpy(p + 8, t->key, key_len);
    p[8 + key_len] = 0;
    memcpy(p + 9 + key_len, t->value, value_len);
    uLong crc = crc32(0L, p + 4, (uInt)(4 + data_len));
    put_be32(p + 8 + data_len, (uint32_t)crc);
    return 12 + data_len;
}

/* The 8-byte signature and the IHDR chunk (4 length + 4 type + 13 data + 4 CRC) come
 * first; ancillary text chunks may follow IHDR anywhere before IEND, and readers that show
 * metadata find them fastest right there. */
#define PNG_AFTER_IHDR (8 + 25)

static int png_insert_texts(encode_buffer *png, const encode_text *texts, size_t count,
                            ns_error *err)
{
    size_t extra = 0;
    for (size_t i = 0; i < count; i++) {
        if (!png_keyword_ok(texts[i].key) || !texts[i].value)
            return encode_fail(err, NS_ERR_INVALID_ARGUMENT, "encode: bad PNG text keyword '%s'",
                               texts[i].key ? texts[i].key : "(null)");
        size_t len = strlen(texts[i].key) + 1 + strlen(texts[i].value);
        if (len > 0x7fffffffu)
            return encode_fail(err, NS_ERR_LIMIT, "encode: PNG text '%s' too long", texts[i].key);
        extra += 12 + len;
    }
    if (png->size < PNG_AFTER_IHDR || memcmp(png->data + 12, "IHDR", 4) != 0)
        return encode_fail(err, NS_ERR_INTERNAL, "encode: PNG writer produced no IHDR first");
    unsigned char *grown = malloc(png->size + extra);
    if (!grown)
        return encode_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "encode: out of memory for PNG text");
    memcpy(grown, png->data, PNG_AFTER_IHDR);
    size_t at = PNG_AFTER_IHDR;
    for (size_t i = 0; i < count; i++)
        at += png_write_text_chunk(grown + at, &texts[i]);
    memcpy(grown + at, png->data + PNG_AFTER_IHDR, png->size - PNG_AFTER_IHDR);
    free(png->data);
    png->data = grown;
    png->size += extra;
    return 0;
}

int encode_exposure_scale(float exposure_stops, float *scale, ns_error *err)
{
    if (!isfinite(exposure_stops) || fabsf(exposure_stops) > 64.0f)
        return encode_fail(err, NS_ERR_INVALID_ARGUMENT,
                           "encode: exposure %g stops is not a finite number in [-64, 64]",
                           (double)exposure_stops);
    *scale = exp2f(exposure_stops);
    return 0;
}

int encode_png_rgb8(const uint8_t *rgb, uint32_t width, uint32_t height, const encode_text *texts,
                    size_t text_count, encode_buffer *out, ns_error *err)
{
    out->data = NULL;
    out->size = 0;
    if (!rgb || width == 0 || height == 0)
        return encode_fail(err, NS_ERR_INVALID_ARGUMENT, "encode: empty picture %ux%u", width,
                           height);
    /* These limits also keep stb's int strides and buffer sizes far from overflow. */
    if (width > ENCODE_RGB8_MAX_SIDE || height > ENCODE_RGB8_MAX_SIDE ||
        (uint64_t)width * height > ENCODE_RGB8_MAX_PIXELS)
        return encode_fail(err, NS_ERR_LIMIT, "encode: picture %ux%u over the size limits", width,
                           height);
    int len = 0;
    unsigned char *png =
        stbi_write_png_to_mem(rgb, (int)width * 3, (int)width, (int)height, 3, &len);
    if (!png || len <= 0)
        return encode_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "encode: PNG writer failed");
    out->data = png;
    out->size = (size_t)len;
    int rc = png_insert_texts(out, texts, text_count, err);
    if (rc)
        encode_buffer_free(out);
    return rc;
}

int encode_png(const ns_image *img, float exposure_stops, const encode_text *texts,
               size_t text_count, encode_buffer *out, ns_error *err)
{
    out->data = NULL;
    out->size = 0;
    int rc = encode_check_image(img, err);
    if (rc)
        return rc;
    float scale = 1.0f;
    rc = encode_exposure_scale(exposure_stops, &scale, err);
    if (rc)
        return rc;
    size_t count = (size_t)img->width * img->height;
    uint8_t *rgb8 = malloc(count * 3);
    if (!rgb8)
        return encode_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "encode: out of memory (%zu pixels)",
                           count);
    for (size_t i = 0; i < count * 3; i++)
        rgb8[i] = encode_srgb8(img->rgb[i], scale);
    rc = encode_png_rgb8(rgb8, img->width, img->height, texts, text_count, out, err);
    free(rgb8);
    return rc;
}

/* ---------------------------------------------------------------------------------------
 * EXR.
 * ------------------------------------------------------------------------------------- */
int encode_exr(const ns_image *img, int half, const encode_text *texts, size_t text_count,
               encode_buffer *out, ns_error *err)
{
    out->data = NULL;
    out->size = 0;
    int rc = encode_check_image(img, err);
    if (rc)
        return rc;
    if (text_count > ENCODE_MAX_TEXTS)
        return encode_fail(err, NS_ERR_LIMIT, "encode: %zu metadata entries, at most %d",
                           text_count, ENCODE_MAX_TEXTS);
    size_t count = (size_t)img->width * img->height;
    float *planes = malloc(count * 3 * sizeof(float));
    if (!planes)
        return encode_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "encode: out of memory (%zu pixels)",
                           count);
    /* EXR readers expect channels sorted by name: B, G, R planes. */
    float *plane_b = planes, *plane_g = planes + count, *plane_r = planes + 2 * count;
    for (size_t i = 0; i < count; i++) {
        const float *px = img->rgb + 3 * i;
        plane_r[i] = isfinite(px[0]) ? px[0] : 0.0f;
        plane_g[i] = isfinite(px[1]) ? px[1] : 0.0f;
        plane_b[i] = isfinite(px[2]) ? px[2] : 0.0f;
    }

    EXRHeader header;
    EXRImage image;
    InitEXRHeader(&header);
    InitEXRImage(&image);
    unsigned char *channel_ptrs[3] = {(unsigned char *)plane_b, (unsigned char *)plane_g,
                                      (unsigned char *)plane_r};
    image.images = channel_ptrs;
    image.width = (int)img->width;
    image.height = (int)img->height;
    image.num_channels = 3;

    EXRChannelInfo channels[3];
    memset(channels, 0, sizeof channels);
    strcpy(channels[0].name, "B");
    strcpy(channels[1].name, "G");
    strcpy(channels[2].name, "R");
    int pixel_types[3] = {TINYEXR_PIXELTYPE_FLOAT, TINYEXR_PIXELTYPE_FLOAT,
                          TINYEXR_PIXELTYPE_FLOAT};
    int stored = half ? TINYEXR_PIXELTYPE_HALF : TINYEXR_PIXELTYPE_FLOAT;
    int requested[3] = {stored, stored, stored};
    header.num_channels = 3;
    header.channels = channels;
    header.pixel_types = pixel_types;
    header.requested_pixel_types = requested;
    header.compression_type = TINYEXR_COMPRESSIONTYPE_ZIP;

    EXRAttribute attributes[ENCODE_MAX_TEXTS];
    memset(attributes, 0, sizeof attributes);
    for (size_t i = 0; i < text_count; i++) {
        size_t key_len = texts[i].key ? strlen(texts[i].key) : 0;
        if (key_len < 1 || key_len > 255 || !texts[i].value || strlen(texts[i].value) > INT_MAX) {
            free(planes);
            return encode_fail(err, NS_ERR_INVALID_ARGUMENT, "encode: bad EXR attribute '%s'",
                               texts[i].key ? texts[i].key : "(null)");
        }
        memcpy(attributes[i].name, texts[i].key, key_len + 1);
        strcpy(attributes[i].type, "string");
        /* tinyexr only reads the value; the cast drops a const it never needed. */
        attributes[i].value = (unsigned char *)(uintptr_t)texts[i].value;
        attributes[i].size = (int)strlen(texts[i].value);
    }
    header.num_custom_attributes = (int)text_count;
    header.custom_attributes = text_count ? attributes : NULL;

    unsigned char *memory = NULL;
    const char *exr_err = NULL;
    size_t size = SaveEXRImageToMemory(&image, &header, &memory, &exr_err);
    free(planes);
    if (size == 0 || !memory) {
        rc = encode_fail(err, NS_ERR_INTERNAL, "encode: EXR writer failed: %s",
                         exr_err ? exr_err : "unknown error");
        if (exr_err)
            FreeEXRErrorMessage(exr_err);
        free(memory);
        return rc;
    }
    out->data = memory;
    out->size = size;
    return 0;
}

int encode_image(encode_format format, const ns_image *img, float exposure_stops,
                 const encode_text *texts, size_t text_count, encode_buffer *out, ns_error *err)
{
    switch (format) {
    case ENCODE_PNG:
        return encode_png(img, exposure_stops, texts, text_count, out, err);
    case ENCODE_EXR_FLOAT:
        return encode_exr(img, 0, texts, text_count, out, err);
    case ENCODE_EXR_HALF:
        return encode_exr(img, 1, texts, text_count, out, err);
    }
    out->data = NULL;
    out->size = 0;
    return encode_fail(err, NS_ERR_INVALID_ARGUMENT, "encode: unknown format %d", (int)format);
}
