/* unit_encode.c — PNG and EXR encoders: decode what they wrote and compare with closed-form
 * values (sRGB transfer, exposure), check the metadata chunks/attributes and their CRCs,
 * and feed them hostile pixels (NaN, Inf, negative) and odd sizes. */
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <tinyexr.h>
#include <zlib.h>

#include "encode.h"
#include "harness.h"

/* The decoder, compiled static from the system header so the test needs no extra link. */
#define STB_IMAGE_IMPLEMENTATION
#define STB_IMAGE_STATIC
#define STBI_ONLY_PNG
/* Unused static declarations are reported at the end of the file: keep that off for all. */
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wshadow"
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#include <stb/stb_image.h>
#pragma GCC diagnostic pop

/* sRGB transfer written independently of the encoder, in double precision. */
static double srgb_closed_form(double v)
{
    if (!(v > 0.0))
        return 0.0;
    if (v >= 1.0)
        return 1.0;
    return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1.0 / 2.4) - 0.055;
}

/* Gradient: red ramps 0..1.5 across (past 1 to exercise clamping), green ramps down the
 * rows, blue stays in the linear toe of the sRGB curve. */
static ns_image make_gradient(uint32_t w, uint32_t h)
{
    ns_image img = {w, h, malloc(sizeof(float) * 3 * w * h)};
    for (uint32_t y = 0; y < h; y++)
        for (uint32_t x = 0; x < w; x++) {
            float *px = img.rgb + 3 * (y * w + x);
            px[0] = w > 1 ? 1.5f * (float)x / (float)(w - 1) : 0.25f;
            px[1] = h > 1 ? (float)y / (float)(h - 1) : 0.5f;
            px[2] = 0.003f * (float)(x % 2);
        }
    return img;
}

static uint32_t get_be32(const unsigned char *p)
{
    return (uint32_t)p[0] << 24 | (uint32_t)p[1] << 16 | (uint32_t)p[2] << 8 | p[3];
}

/* Walks the chunk list: every CRC must be valid; returns the number of chunks or -1.
 * Looks up the value of tEXt `key` into value (NUL-terminated) when found. */
static int png_walk(const unsigned char *png, size_t size, const char *key, char *value,
                    size_t value_cap, uint32_t *ihdr_w, uint32_t *ihdr_h)
{
    static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    if (size < 8 || memcmp(png, sig, 8) != 0)
        return -1;
    size_t at = 8;
    int chunks = 0;
    if (value)
        value[0] = 0;
    while (at + 12 <= size) {
        uint32_t len = get_be32(png + at);
        if (at + 12 + len > size)
            return -1;
        const unsigned char *type = png + at + 4, *data = png + at + 8;
        uint32_t crc = (uint32_t)crc32(0L, type, 4 + len);
        if (crc != get_be32(data + len))
            return -1;
        if (!memcmp(type, "IHDR", 4) && len == 13) {
            *ihdr_w = get_be32(data);
            *ihdr_h = get_be32(data + 4);
        }
        if (!memcmp(type, "tEXt", 4) && key && len > strlen(key) &&
            !memcmp(data, key, strlen(key)) && data[strlen(key)] == 0) {
            size_t vlen = len - strlen(key) - 1;
            if (vlen >= value_cap)
                vlen = value_cap - 1;
            memcpy(value, data + strlen(key) + 1, vlen);
            value[vlen] = 0;
        }
        chunks++;
        if (!memcmp(type, "IEND", 4))
            return at + 12 + len == size ? chunks : -1;
        at += 12 + len;
    }
    return -1;
}

static const encode_text test_texts[] = {
    {"Software", "nscatter test"},
    {"nscatter:render", "{\"spp\": 4, \"method\": \"nn\"}"},
};

/* ---------------------------------------------------------------------------------------
 * PNG.
 * ------------------------------------------------------------------------------------- */
static void check_png_matches(const ns_image *img, float exposure)
{
    encode_buffer buf;
    ns_error err = {0};
    CHECK_INT(encode_png(img, exposure, test_texts, 2, &buf, &err), 0);
    if (!buf.data)
        return;
    int w = 0, h = 0, n = 0;
    unsigned char *px = stbi_load_from_memory(buf.data, (int)buf.size, &w, &h, &n, 3);
    CHECK(px != NULL);
    CHECK_INT(w, img->width);
    CHECK_INT(h, img->height);
    CHECK_INT(n, 3);
    int worst = 0;
    for (size_t i = 0; px && i < (size_t)img->width * img->height * 3; i++) {
        double want = 255.0 * srgb_closed_form(img->rgb[i] * pow(2.0, exposure));
        int diff = abs((int)px[i] - (int)lround(want));
        worst = diff > worst ? diff : worst;
    }
    /* Float vs double evaluation can only move a value sitting on a rounding boundary. */
    CHECK(worst <= 1);
    stbi_image_free(px);
    encode_buffer_free(&buf);
}

static void test_png_gradient_matches_srgb(void)
{
    ns_image img = make_gradient(64, 16);
    check_png_matches(&img, 0.0f);
    ns_image_free(&img);
}

static void test_png_exposure_scales_by_power_of_two(void)
{
    ns_image img = make_gradient(33, 7);
    check_png_matches(&img, 1.0f);
    check_png_matches(&img, -2.5f);
    /* One stop up is the same as doubling the radiance. */
    CHECK_INT(encode_srgb8(0.2f, exp2f(1.0f)), encode_srgb8(0.4f, 1.0f));
    ns_image_free(&img);
}

static void test_srgb_known_values(void)
{
    CHECK_INT(encode_srgb8(0.0f, 1.0f), 0);
    CHECK_INT(encode_srgb8(1.0f, 1.0f), 255);
    CHECK_INT(encode_srgb8(0.5f, 1.0f), 188);      /* 1.055 * 0.5^(1/2.4) - 0.055 = 0.7354 */
    CHECK_INT(encode_srgb8(0.0031308f, 1.0f), 10); /* end of the linear toe: 0.04045 */
    CHECK_INT(encode_srgb8(0.18f, 1.0f), 118);     /* mid grey: 0.4614 */
}

static void test_png_text_chunks_and_crcs(void)
{
    ns_image img = make_gradient(20, 10);
    encode_buffer buf;
    ns_error err = {0};
    CHECK_INT(encode_png(&img, 0.0f, test_texts, 2, &buf, &err), 0);
    char value[256];
    uint32_t w = 0, h = 0;
    int chunks = png_walk(buf.data, buf.size, "nscatter:render", value, sizeof value, &w, &h);
    CHECK(chunks >= 5); /* IHDR, 2 x tEXt, IDAT, IEND */
    CHECK_INT(w, 20);
    CHECK_INT(h, 10);
    CHECK(strcmp(value, test_texts[1].value) == 0);
    png_walk(buf.data, buf.size, "Software", value, sizeof value, &w, &h);
    CHECK(strcmp(value, "nscatter test") == 0);
    /* The text chunks sit right after IHDR. */
    CHECK(buf.size > 41 && memcmp(buf.data + 33 + 4, "tEXt", 4) == 0);
    encode_buffer_free(&buf);
    CHECK(buf.data == NULL && buf.size == 0);
    ns_image_free(&img);
}

static void test_png_rejects_bad_keyword(void)
{
    ns_image img = make_gradient(4, 4);
    encode_buffer buf;
    ns_error err = {0};
    encode_text bad[] = {{"", "x"}};
    CHECK_INT(encode_png(&img, 0.0f, bad, 1, &buf, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK(buf.data == NULL);
    encode_text spaced[] = {{" lead", "x"}};
    CHECK_INT(encode_png(&img, 0.0f, spaced, 1, &buf, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_INT(encode_png(&img, NAN, NULL, 0, &buf, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "exposure");
    ns_image_free(&img);
}

static void test_png_hostile_pixels_clamped(void)
{
    float rgb[6 * 3] = {NAN,  INFINITY, -INFINITY, -1.0f, -0.0f, 1e30f, 0.5f, 2.0f, 1e-30f,
                        -NAN, 0.25f,    FLT_MAX,   1.0f,  0.0f,  0.5f,  0.1f, 0.2f, 0.3f};
    ns_image img = {3, 2, rgb};
    encode_buffer buf;
    ns_error err = {0};
    CHECK_INT(encode_png(&img, 0.0f, NULL, 0, &buf, &err), 0);
    int w, h, n;
    unsigned char *px = stbi_load_from_memory(buf.data, (int)buf.size, &w, &h, &n, 3);
    CHECK(px != NULL);
    if (px) {
        CHECK_INT(px[0], 0);   /* NaN */
        CHECK_INT(px[1], 255); /* +Inf */
        CHECK_INT(px[2], 0);   /* -Inf */
        CHECK_INT(px[3], 0);   /* negative */
        CHECK_INT(px[5], 255); /* huge */
        CHECK_INT(px[7], 255); /* over 1 */
        CHECK_INT(px[9], 0);   /* -NaN */
        CHECK_INT(px[11], 255);
        CHECK_INT(px[12], 255);
        CHECK_INT(px[14], 188);
    }
    stbi_image_free(px);
    encode_buffer_free(&buf);
}

static void test_png_odd_sizes(void)
{
    static const uint32_t sizes[][2] = {{1, 1}, {1, 9}, {13, 1}, {257, 3}};
    for (size_t i = 0; i < sizeof sizes / sizeof sizes[0]; i++) {
        ns_image img = make_gradient(sizes[i][0], sizes[i][1]);
        check_png_matches(&img, 0.0f);
        ns_image_free(&img);
    }
}

static void test_encode_rejects_bad_images(void)
{
    encode_buffer buf;
    ns_error err = {0};
    float px[3] = {0};
    ns_image empty = {0, 5, px};
    CHECK_INT(encode_png(&empty, 0.0f, NULL, 0, &buf, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_INT(encode_exr(&empty, 0, NULL, 0, &buf, &err), NS_ERR_INVALID_ARGUMENT);
    ns_image no_pixels = {2, 2, NULL};
    CHECK_INT(encode_png(&no_pixels, 0.0f, NULL, 0, &buf, &err), NS_ERR_INVALID_ARGUMENT);
    ns_image huge = {NS_MAX_IMAGE_SIDE + 1, 1, px};
    CHECK_INT(encode_exr(&huge, 1, NULL, 0, &buf, &err), NS_ERR_LIMIT);
    CHECK(buf.data == NULL);
    CHECK_INT(encode_image((encode_format)7, &no_pixels, 0.0f, NULL, 0, &buf, &err),
              NS_ERR_INVALID_ARGUMENT);
}

/* ---------------------------------------------------------------------------------------
 * EXR.
 * ------------------------------------------------------------------------------------- */
static float *exr_decode(const encode_buffer *buf, int *w, int *h)
{
    float *rgba = NULL;
    const char *exr_err = NULL;
    if (LoadEXRFromMemory(&rgba, w, h, buf->data, buf->size, &exr_err) != TINYEXR_SUCCESS) {
        fprintf(stderr, "LoadEXRFromMemory: %s\n", exr_err ? exr_err : "?");
        FreeEXRErrorMessage(exr_err);
        return NULL;
    }
    return rgba;
}

static void check_exr_matches(const ns_image *img, int half)
{
    encode_buffer buf;
    ns_error err = {0};
    CHECK_INT(encode_exr(img, half, test_texts, 2, &buf, &err), 0);
    if (!buf.data)
        return;
    static const unsigned char magic[4] = {0x76, 0x2f, 0x31, 0x01};
    CHECK(buf.size > 4 && memcmp(buf.data, magic, 4) == 0);
    int w = 0, h = 0;
    float *rgba = exr_decode(&buf, &w, &h);
    CHECK(rgba != NULL);
    CHECK_INT(w, img->width);
    CHECK_INT(h, img->height);
    double worst = 0;
    for (size_t i = 0; rgba && i < (size_t)img->width * img->height; i++)
        for (int c = 0; c < 3; c++) {
            double want = img->rgb[3 * i + c], got = rgba[4 * i + c];
            /* float is exact; half keeps 11 significant bits (relative 2^-11), and values
             * below its normal range (6.1e-5) lose relative precision. */
            double tol = half ? fabs(want) / 2048.0 + 1e-7 : 0.0;
            double excess = fabs(got - want) - tol;
            worst = excess > worst ? excess : worst;
        }
    CHECK(worst <= 0.0);
    free(rgba);
    encode_buffer_free(&buf);
}

static void test_exr_float_and_half_roundtrip(void)
{
    ns_image img = make_gradient(40, 12);
    check_exr_matches(&img, 0);
    check_exr_matches(&img, 1);
    ns_image_free(&img);
    ns_image one = make_gradient(1, 1);
    check_exr_matches(&one, 0);
    check_exr_matches(&one, 1);
    ns_image_free(&one);
    ns_image tall = make_gradient(3, 70); /* more rows than one ZIP block (16) */
    check_exr_matches(&tall, 0);
    ns_image_free(&tall);
}

static void test_exr_half_is_smaller(void)
{
    ns_image img = make_gradient(64, 64);
    encode_buffer f, h;
    ns_error err = {0};
    CHECK_INT(encode_exr(&img, 0, NULL, 0, &f, &err), 0);
    CHECK_INT(encode_exr(&img, 1, NULL, 0, &h, &err), 0);
    CHECK(h.size < f.size);
    encode_buffer_free(&f);
    encode_buffer_free(&h);
    ns_image_free(&img);
}

static void test_exr_attributes_present(void)
{
    ns_image img = make_gradient(8, 8);
    encode_buffer buf;
    ns_error err = {0};
    CHECK_INT(encode_exr(&img, 0, test_texts, 2, &buf, &err), 0);
    EXRVersion version;
    EXRHeader header;
    InitEXRHeader(&header);
    const char *exr_err = NULL;
    CHECK_INT(ParseEXRVersionFromMemory(&version, buf.data, buf.size), TINYEXR_SUCCESS);
    CHECK_INT(ParseEXRHeaderFromMemory(&header, &version, buf.data, buf.size, &exr_err),
              TINYEXR_SUCCESS);
    int found = 0;
    for (int i = 0; i < header.num_custom_attributes; i++) {
        const EXRAttribute *a = &header.custom_attributes[i];
        if (!strcmp(a->name, "nscatter:render") && !strcmp(a->type, "string") &&
            a->size == (int)strlen(test_texts[1].value) &&
            !memcmp(a->value, test_texts[1].value, (size_t)a->size))
            found++;
        if (!strcmp(a->name, "Software") && a->size == 13 && !memcmp(a->value, "nscatter test", 13))
            found++;
    }
    CHECK_INT(found, 2);
    FreeEXRHeader(&header);
    encode_buffer_free(&buf);
    ns_image_free(&img);
}

static void test_exr_hostile_pixels_zeroed(void)
{
    float rgb[2 * 3] = {NAN, INFINITY, -INFINITY, -2.0f, 3.5f, 0.0f};
    ns_image img = {2, 1, rgb};
    encode_buffer buf;
    ns_error err = {0};
    CHECK_INT(encode_exr(&img, 1, NULL, 0, &buf, &err), 0);
    int w, h;
    float *rgba = exr_decode(&buf, &w, &h);
    CHECK(rgba != NULL);
    if (rgba) {
        CHECK(rgba[0] == 0.0f && rgba[1] == 0.0f && rgba[2] == 0.0f);
        CHECK(rgba[4] == -2.0f); /* linear output keeps negative values as they are */
        CHECK(rgba[5] == 3.5f);
    }
    free(rgba);
    encode_buffer_free(&buf);
}

int main(void)
{
    RUN(test_srgb_known_values);
    RUN(test_png_gradient_matches_srgb);
    RUN(test_png_exposure_scales_by_power_of_two);
    RUN(test_png_text_chunks_and_crcs);
    RUN(test_png_rejects_bad_keyword);
    RUN(test_png_hostile_pixels_clamped);
    RUN(test_png_odd_sizes);
    RUN(test_encode_rejects_bad_images);
    RUN(test_exr_float_and_half_roundtrip);
    RUN(test_exr_half_is_smaller);
    RUN(test_exr_attributes_present);
    RUN(test_exr_hostile_pixels_zeroed);
    return harness_report();
}
