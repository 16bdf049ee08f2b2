/* unit_compare.c — image comparison (io/image_metrics.c) and `nscatter compare`:
 * closed-form metrics (identical images, a constant offset, one channel, masks), PNG
 * decoding to linear, the false-colour ramp, and the CLI's JSON and exit statuses for
 * size mismatches, corrupt and missing files. */
#include <jansson.h>
#include <stdint.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

#include "encode.h"
#include "harness.h"
#include "image_metrics.h"

static char tmpdir[64];

/* ---------------------------------------------------------------------------------------
 * Helpers: images in memory and on disk, running the CLI.
 * ------------------------------------------------------------------------------------- */
static ns_image image_filled(uint32_t w, uint32_t h, float r, float g, float b)
{
    ns_image img = {w, h, malloc((size_t)w * h * 3 * sizeof(float))};
    for (size_t i = 0; i < (size_t)w * h; i++) {
        img.rgb[3 * i] = r;
        img.rgb[3 * i + 1] = g;
        img.rgb[3 * i + 2] = b;
    }
    return img;
}

/* A reference with varied, exactly representable values in [0, 2]: peak 2. */
static ns_image image_ramp(uint32_t w, uint32_t h)
{
    ns_image img = image_filled(w, h, 0, 0, 0);
    for (size_t i = 0; i < (size_t)w * h * 3; i++)
        img.rgb[i] = (float)(i % 17) / 8.0f; /* 0 .. 2 in steps of 1/8 */
    return img;
}

static ns_image image_copy(const ns_image *src)
{
    ns_image img = image_filled(src->width, src->height, 0, 0, 0);
    memcpy(img.rgb, src->rgb, (size_t)src->width * src->height * 3 * sizeof(float));
    return img;
}

static const char *tmp_path(const char *name)
{
    static char paths[16][128];
    static int next;
    char *p = paths[next++ % 16];
    snprintf(p, 128, "%s/%s", tmpdir, name);
    return p;
}

static void write_bytes(const char *path, const void *data, size_t size)
{
    FILE *f = fopen(path, "wb");
    CHECK(f != NULL);
    if (!f)
        return;
    CHECK(fwrite(data, 1, size, f) == size);
    fclose(f);
}

static void write_image(const char *path, const ns_image *img, encode_format format)
{
    encode_buffer buf = {0};
    ns_error err = {0};
    CHECK_INT(encode_image(format, img, 0.0f, NULL, 0, &buf, &err), 0);
    write_bytes(path, buf.data, buf.size);
    encode_buffer_free(&buf);
}

typedef struct cli_result {
    int status;
    json_t *json; /* stdout parsed, or NULL */
    char err[2048];
} cli_result;

static void read_text(const char *path, char *out, size_t size)
{
    out[0] = '\0';
    FILE *f = fopen(path, "rb");
    if (!f)
        return;
    size_t n = fread(out, 1, size - 1, f);
    out[n] = '\0';
    fclose(f);
}

/* Runs `nscatter compare ARGS` (ARGS already shell-safe: only our temp paths). */
static cli_result run_compare(const char *args)
{
    cli_result r = {-1, NULL, ""};
    const char *bin = getenv("NSCATTER_BIN");
    if (!bin || !*bin) {
        fprintf(stderr, "NSCATTER_BIN is not set\n");
        CHECK(bin && *bin);
        return r;
    }
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "'%s' compare %s >%s/out.txt 2>%s/err.txt", bin, args, tmpdir,
             tmpdir);
    int st = system(cmd);
    r.status = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
    char out[8192];
    read_text(tmp_path("out.txt"), out, sizeof out);
    read_text(tmp_path("err.txt"), r.err, sizeof r.err);
    r.json = json_loads(out, 0, NULL);
    return r;
}

static double json_metric(const json_t *obj, const char *group, const char *channel)
{
    json_t *v = json_object_get(json_object_get(obj, group), channel);
    return json_is_number(v) ? json_number_value(v) : NAN;
}

/* ---------------------------------------------------------------------------------------
 * Metrics with closed-form answers.
 * ------------------------------------------------------------------------------------- */
static void test_identical_images(void)
{
    ns_image b = image_ramp(16, 8), a = image_copy(&b);
    image_metrics m;
    image_compare(&a, &b, NULL, &m);
    CHECK_INT(m.pixels, 16 * 8);
    CHECK(m.identical);
    CHECK_NEAR(m.peak, 2.0, 0);
    for (int c = 0; c < 4; c++) {
        CHECK_NEAR(m.rmse[c], 0.0, 0);
        CHECK_NEAR(m.relerr[c], 0.0, 0);
        CHECK(isinf(m.psnr[c]) && m.psnr[c] > 0);
    }
    ns_image_free(&a);
    ns_image_free(&b);
}

static void test_constant_offset(void)
{
    const double d = 0.125;
    ns_image b = image_ramp(16, 8), a = image_copy(&b);
    for (size_t i = 0; i < 16 * 8 * 3; i++)
        a.rgb[i] += (float)d;
    image_metrics m;
    image_compare(&a, &b, NULL, &m);
    CHECK(!m.identical);
    CHECK_NEAR(m.peak, 2.0, 0);
    double want_rel = 0.0;
    for (size_t i = 0; i < 16 * 8 * 3; i++)
        want_rel += d / (b.rgb[i] + IMAGE_RELERR_EPSILON);
    want_rel /= 16 * 8 * 3;
    for (int c = 0; c < 4; c++) {
        CHECK_NEAR(m.rmse[c], d, 1e-12);
        CHECK_NEAR(m.psnr[c], 20.0 * log10(2.0 / d), 1e-9); /* 24.08 dB */
    }
    CHECK_NEAR(m.relerr[3], want_rel, 1e-9);
    CHECK_NEAR(m.max_abs_diff, d, 1e-12);
    ns_image_free(&a);
    ns_image_free(&b);
}

static void test_one_channel_and_relerr(void)
{
    /* Reference constant 1: relative error is d / (1 + eps) exactly where it differs. */
    const double d = 0.25;
    ns_image b = image_filled(4, 4, 1, 1, 1), a = image_filled(4, 4, 1.25f, 1, 1);
    image_metrics m;
    image_compare(&a, &b, NULL, &m);
    CHECK_NEAR(m.rmse[0], d, 1e-12);
    CHECK_NEAR(m.rmse[1], 0.0, 0);
    CHECK_NEAR(m.rmse[2], 0.0, 0);
    CHECK_NEAR(m.rmse[3], d / sqrt(3.0), 1e-12);
    CHECK_NEAR(m.psnr[0], 20.0 * log10(1.0 / d), 1e-9);
    CHECK(isinf(m.psnr[1]));
    CHECK_NEAR(m.psnr[3], 20.0 * log10(sqrt(3.0) / d), 1e-9);
    CHECK_NEAR(m.relerr[0], d / (1.0 + IMAGE_RELERR_EPSILON), 1e-12);
    CHECK_NEAR(m.relerr[3], d / (1.0 + IMAGE_RELERR_EPSILON) / 3.0, 1e-12);
    /* Means over the reference's: 1.25 in red, 1 elsewhere, 3.25 / 3 over all. */
    CHECK_NEAR(m.mean_ratio[0], 1.25, 1e-12);
    CHECK_NEAR(m.mean_ratio[1], 1.0, 0);
    CHECK_NEAR(m.mean_ratio[3], 3.25 / 3.0, 1e-12);
    ns_image_free(&a);
    ns_image_free(&b);
    /* A reference channel that is 0 everywhere has no ratio. */
    b = image_filled(4, 4, 1, 0, 1), a = image_filled(4, 4, 2, 0.5f, 1);
    image_compare(&a, &b, NULL, &m);
    CHECK_NEAR(m.mean_ratio[0], 2.0, 0);
    CHECK(isnan(m.mean_ratio[1]));
    CHECK_NEAR(m.mean_ratio[3], 3.5 / 2.0, 1e-12);
    ns_image_free(&a);
    ns_image_free(&b);
}

static void test_mask(void)
{
    /* Left half off by 0.5, right half by 0.25; the peak must come from counted pixels. */
    ns_image b = image_filled(8, 2, 1, 1, 1), a = image_filled(8, 2, 1, 1, 1);
    uint8_t mask[16];
    for (int y = 0; y < 2; y++)
        for (int x = 0; x < 8; x++) {
            int i = y * 8 + x;
            mask[i] = x < 4;
            if (x >= 4)
                b.rgb[3 * i] = b.rgb[3 * i + 1] = b.rgb[3 * i + 2] = 4.0f; /* outside mask */
            for (int c = 0; c < 3; c++)
                a.rgb[3 * i + c] = b.rgb[3 * i + c] + (x < 4 ? 0.5f : 0.25f);
        }
    image_metrics m;
    image_compare(&a, &b, mask, &m);
    CHECK_INT(m.pixels, 8);
    CHECK_NEAR(m.peak, 1.0, 0);
    CHECK_NEAR(m.rmse[3], 0.5, 1e-12);
    CHECK_NEAR(m.psnr[3], 20.0 * log10(1.0 / 0.5), 1e-9);
    image_compare(&a, &b, NULL, &m);
    CHECK_INT(m.pixels, 16);
    CHECK_NEAR(m.peak, 4.0, 0);
    CHECK_NEAR(m.rmse[3], sqrt((0.25 + 0.0625) / 2.0), 1e-12);
    memset(mask, 0, sizeof mask);
    image_compare(&a, &b, mask, &m);
    CHECK_INT(m.pixels, 0);
    CHECK(isnan(m.rmse[3]) && isnan(m.psnr[3]));
    ns_image_free(&a);
    ns_image_free(&b);
}

static void test_nonfinite_values_are_counted_apart(void)
{
    ns_image b = image_filled(2, 1, 1, 1, 1), a = image_filled(2, 1, 1, 1, 1);
    a.rgb[0] = NAN;
    a.rgb[4] = 1.5f;
    image_metrics m;
    image_compare(&a, &b, NULL, &m);
    CHECK_INT(m.nonfinite, 1);
    CHECK(!m.identical);
    CHECK_NEAR(m.rmse[3], sqrt(0.25 / 5.0), 1e-12);
    ns_image_free(&a);
    ns_image_free(&b);
}

/* ---------------------------------------------------------------------------------------
 * Loading and the false-colour image.
 * ------------------------------------------------------------------------------------- */
static void test_load_exr_and_png(void)
{
    ns_image src = image_ramp(5, 3);
    write_image(tmp_path("ramp.exr"), &src, ENCODE_EXR_FLOAT);
    ns_image got;
    ns_error err = {0};
    CHECK_INT(image_load(tmp_path("ramp.exr"), &got, &err), 0);
    CHECK_INT(got.width, 5);
    CHECK_INT(got.height, 3);
    int same = got.rgb && !memcmp(got.rgb, src.rgb, 5 * 3 * 3 * sizeof(float));
    CHECK(same);
    ns_image_free(&got);

    /* PNG: 8-bit sRGB decoded back to linear with the exact inverse transfer. */
    ns_image grey = image_filled(3, 2, 0.2f, 0.5f, 0.9f);
    write_image(tmp_path("grey.png"), &grey, ENCODE_PNG);
    CHECK_INT(image_load(tmp_path("grey.png"), &got, &err), 0);
    CHECK_INT(got.width, 3);
    for (int c = 0; c < 3; c++) {
        double v = encode_srgb8(grey.rgb[c], 1.0f) / 255.0;
        double want = v <= 0.04045 ? v / 12.92 : pow((v + 0.055) / 1.055, 2.4);
        CHECK_NEAR(got.rgb[c], want, 1e-6);
        CHECK_NEAR(got.rgb[c], grey.rgb[c], 0.01); /* 8 bits: within a step */
    }
    ns_image_free(&got);
    ns_image_free(&grey);
    ns_image_free(&src);
}

static void test_load_errors(void)
{
    ns_image got;
    ns_error err = {0};
    CHECK_INT(image_load(tmp_path("missing.exr"), &got, &err), NS_ERR_IO);
    CHECK_STR_CONTAINS(err.message, "missing.exr");
    const unsigned char bad_exr[] = {0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0, 'x', 'y'};
    write_bytes(tmp_path("corrupt.exr"), bad_exr, sizeof bad_exr);
    CHECK_INT(image_load(tmp_path("corrupt.exr"), &got, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "not a readable EXR");
    const unsigned char bad_png[] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n', 0, 0, 0};
    write_bytes(tmp_path("corrupt.png"), bad_png, sizeof bad_png);
    CHECK_INT(image_load(tmp_path("corrupt.png"), &got, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "not a readable PNG");
    write_bytes(tmp_path("text.exr"), "hello", 5);
    CHECK_INT(image_load(tmp_path("text.exr"), &got, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "neither an EXR nor a PNG");
    write_bytes(tmp_path("empty.exr"), "", 0);
    CHECK_INT(image_load(tmp_path("empty.exr"), &got, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_INT(image_load(tmpdir, &got, &err), NS_ERR_IO); /* a directory */
}

static void test_ramp_is_monotonic_in_luminance(void)
{
    double prev = -1.0;
    for (int i = 0; i <= 100; i++) {
        double rgb[3];
        image_ramp_srgb(i / 100.0, rgb);
        double y = 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
        CHECK(y > prev);
        prev = y;
    }
}

static void test_diff_image(void)
{
    ns_image b = image_filled(4, 1, 1, 1, 1), a = image_filled(4, 1, 1, 1, 1);
    for (int c = 0; c < 3; c++) {
        a.rgb[3 * 1 + c] = 1.5f;  /* diff 0.5: the largest */
        a.rgb[3 * 2 + c] = 1.25f; /* diff 0.25: half way */
    }
    ns_image diff;
    double scale = 0;
    ns_error err = {0};
    CHECK_INT(image_diff_false_colour(&a, &b, NULL, 0.0, &diff, &scale, &err), 0);
    CHECK_NEAR(scale, 0.5, 1e-12);
    double want[3][3];
    image_ramp_srgb(0.0, want[0]);
    image_ramp_srgb(1.0, want[1]);
    image_ramp_srgb(0.5, want[2]);
    for (int p = 0; p < 3; p++)
        for (int c = 0; c < 3; c++) {
            double v = diff.rgb[3 * p + c];
            double srgb = v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1 / 2.4) - 0.055;
            CHECK_NEAR(srgb, want[p][c], 1e-5);
        }
    ns_image_free(&diff);
    uint8_t mask[4] = {1, 0, 1, 1};
    CHECK_INT(image_diff_false_colour(&a, &b, mask, 0.0, &diff, &scale, &err), 0);
    CHECK_NEAR(scale, 0.25, 1e-12); /* the masked-out pixel no longer sets the scale */
    CHECK(diff.rgb[3] == 0 && diff.rgb[4] == 0 && diff.rgb[5] == 0);
    ns_image_free(&diff);
    ns_image_free(&a);
    ns_image_free(&b);
}

/* ---------------------------------------------------------------------------------------
 * The command line.
 * ------------------------------------------------------------------------------------- */
static void test_cli_identical_and_offset(void)
{
    ns_image b = image_ramp(16, 8), a = image_copy(&b);
    write_image(tmp_path("b.exr"), &b, ENCODE_EXR_FLOAT);
    write_image(tmp_path("a_same.exr"), &a, ENCODE_EXR_FLOAT);
    char args[1024];
    snprintf(args, sizeof args, "%s %s", tmp_path("a_same.exr"), tmp_path("b.exr"));
    cli_result r = run_compare(args);
    CHECK_INT(r.status, 0);
    CHECK(r.json != NULL);
    CHECK(json_is_true(json_object_get(r.json, "identical")));
    CHECK(json_is_null(json_object_get(json_object_get(r.json, "psnr"), "all")));
    CHECK_NEAR(json_metric(r.json, "rmse", "all"), 0.0, 0);
    CHECK_INT(json_integer_value(json_object_get(r.json, "pixels")), 128);
    json_decref(r.json);

    for (size_t i = 0; i < 16 * 8 * 3; i++)
        a.rgb[i] += 0.125f;
    write_image(tmp_path("a_off.exr"), &a, ENCODE_EXR_FLOAT);
    snprintf(args, sizeof args, "%s %s --diff %s", tmp_path("a_off.exr"), tmp_path("b.exr"),
             tmp_path("diff.png"));
    r = run_compare(args);
    CHECK_INT(r.status, 0);
    CHECK(json_is_false(json_object_get(r.json, "identical")));
    CHECK_NEAR(json_metric(r.json, "rmse", "all"), 0.125, 1e-7);
    CHECK_NEAR(json_metric(r.json, "rmse", "g"), 0.125, 1e-7);
    CHECK_NEAR(json_metric(r.json, "psnr", "all"), 20.0 * log10(2.0 / 0.125), 1e-6);
    /* A is B + 0.125 everywhere: its mean over B's is 1 + 0.125 / mean(B). */
    double mean_b = 0;
    for (size_t i = 0; i < 16 * 8 * 3; i++)
        mean_b += b.rgb[i] / (16.0 * 8 * 3);
    CHECK_NEAR(json_metric(r.json, "mean_ratio", "all"), 1.0 + 0.125 / mean_b, 1e-6);
    CHECK_NEAR(json_number_value(json_object_get(r.json, "peak")), 2.0, 0);
    CHECK_NEAR(json_number_value(json_object_get(json_object_get(r.json, "diff"), "scale")), 0.125,
               1e-6);
    json_decref(r.json);
    ns_image diff;
    ns_error err = {0};
    CHECK_INT(image_load(tmp_path("diff.png"), &diff, &err), 0);
    CHECK_INT(diff.width, 16);
    CHECK_INT(diff.height, 8);
    ns_image_free(&diff);
    ns_image_free(&a);
    ns_image_free(&b);
}

static void test_cli_mask_and_png(void)
{
    /* A PNG against an EXR: the PNG is decoded to linear, so a PNG of the reference's own
     * 8-bit values differs from it only by rounding. */
    ns_image b = image_filled(8, 4, 0.5f, 0.5f, 0.5f), a = image_filled(8, 4, 0.5f, 0.5f, 0.5f);
    uint8_t mask_px[8 * 4];
    for (int i = 0; i < 32; i++) {
        mask_px[i] = (i % 8) < 2;
        if (!mask_px[i])
            a.rgb[3 * i] = 3.0f;
    }
    ns_image mask = image_filled(8, 4, 0, 0, 0);
    for (int i = 0; i < 32; i++)
        mask.rgb[3 * i + 1] = mask_px[i] ? 1.0f : 0.0f; /* any non-zero channel counts */
    write_image(tmp_path("mb.exr"), &b, ENCODE_EXR_FLOAT);
    write_image(tmp_path("ma.exr"), &a, ENCODE_EXR_FLOAT);
    write_image(tmp_path("mask.png"), &mask, ENCODE_PNG);
    char args[1024];
    snprintf(args, sizeof args, "%s %s --mask %s", tmp_path("ma.exr"), tmp_path("mb.exr"),
             tmp_path("mask.png"));
    cli_result r = run_compare(args);
    CHECK_INT(r.status, 0);
    CHECK_INT(json_integer_value(json_object_get(r.json, "pixels")), 8);
    CHECK(json_is_true(json_object_get(r.json, "identical")));
    json_decref(r.json);

    write_image(tmp_path("mb.png"), &b, ENCODE_PNG);
    snprintf(args, sizeof args, "%s %s --mask %s", tmp_path("mb.png"), tmp_path("mb.exr"),
             tmp_path("mask.png"));
    r = run_compare(args);
    CHECK_INT(r.status, 0);
    CHECK(json_metric(r.json, "rmse", "all") < 0.5 * 0.01); /* one 8-bit step: < 1% */
    json_decref(r.json);

    ns_image none = image_filled(8, 4, 0, 0, 0);
    write_image(tmp_path("none.png"), &none, ENCODE_PNG);
    snprintf(args, sizeof args, "%s %s --mask %s", tmp_path("ma.exr"), tmp_path("mb.exr"),
             tmp_path("none.png"));
    r = run_compare(args);
    CHECK_INT(r.status, 2);
    CHECK_STR_CONTAINS(r.err, "selects no pixel");
    json_decref(r.json);
    ns_image_free(&none);
    ns_image_free(&mask);
    ns_image_free(&a);
    ns_image_free(&b);
}

static void test_cli_errors(void)
{
    ns_image small = image_filled(4, 4, 1, 1, 1), big = image_filled(5, 4, 1, 1, 1);
    write_image(tmp_path("s.exr"), &small, ENCODE_EXR_FLOAT);
    write_image(tmp_path("big.exr"), &big, ENCODE_EXR_HALF);
    struct {
        const char *args, *message;
    } cases[] = {
        {"s.exr big.exr", "sizes differ: A '"},
        {"s.exr missing.exr", "B (reference): cannot open '"},
        {"missing.exr s.exr", "A: cannot open '"},
        {"corrupt.exr s.exr", "not a readable EXR"},
        {"s.exr text.exr", "neither an EXR nor a PNG"},
        {"s.exr s.exr --mask big.exr", "--mask '"},
        {"s.exr s.exr --mask corrupt.png", "--mask: "},
        {"s.exr s.exr --diff d.jpg", "use a .png name"},
        {"s.exr s.exr --diff-scale -1", "--diff-scale '-1'"},
        {"s.exr", "two images are needed"},
        {"s.exr s.exr s.exr", "unexpected third image"},
        {"s.exr s.exr --frobnicate", "unknown or incomplete argument '--frobnicate'"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        /* Prefix every bare file name with the temp directory. */
        char args[1024] = "", copy[256];
        snprintf(copy, sizeof copy, "%s", cases[i].args);
        for (char *tok = strtok(copy, " "); tok; tok = strtok(NULL, " ")) {
            size_t len = strlen(args);
            if (tok[0] == '-' || (tok[0] >= '0' && tok[0] <= '9'))
                snprintf(args + len, sizeof args - len, "%s ", tok);
            else
                snprintf(args + len, sizeof args - len, "%s/%s ", tmpdir, tok);
        }
        cli_result r = run_compare(args);
        if (r.status != 2 || !strstr(r.err, cases[i].message))
            fprintf(stderr, "  case '%s': status %d, stderr: %s\n", cases[i].args, r.status, r.err);
        CHECK_INT(r.status, 2);
        CHECK_STR_CONTAINS(r.err, cases[i].message);
        CHECK(r.json == NULL); /* nothing on stdout */
        json_decref(r.json);
    }
    /* The size-mismatch message names both sizes. */
    char args[512];
    snprintf(args, sizeof args, "%s %s", tmp_path("s.exr"), tmp_path("big.exr"));
    cli_result r = run_compare(args);
    CHECK_STR_CONTAINS(r.err, "is 4x4");
    CHECK_STR_CONTAINS(r.err, "is 5x4");
    /* An unwritable difference image is a failure while working: exit 1. */
    snprintf(args, sizeof args, "%s %s --diff %s/no/such/dir/d.png", tmp_path("s.exr"),
             tmp_path("s.exr"), tmpdir);
    r = run_compare(args);
    CHECK_INT(r.status, 1);
    CHECK_STR_CONTAINS(r.err, "cannot write --diff");
    ns_image_free(&small);
    ns_image_free(&big);
}

int main(void)
{
    snprintf(tmpdir, sizeof tmpdir, "/tmp/ns_compare_XXXXXX");
    if (!mkdtemp(tmpdir)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(test_identical_images);
    RUN(test_constant_offset);
    RUN(test_one_channel_and_relerr);
    RUN(test_mask);
    RUN(test_nonfinite_values_are_counted_apart);
    RUN(test_load_exr_and_png);
    RUN(test_load_errors);
    RUN(test_ramp_is_monotonic_in_luminance);
    RUN(test_diff_image);
    RUN(test_cli_identical_and_offset);
    RUN(test_cli_mask_and_png);
    RUN(test_cli_errors);
    char cmd[128];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmpdir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", tmpdir);
    return harness_report();
}
