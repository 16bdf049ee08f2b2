/* cmd_compare.c — `nscatter compare A B [--mask M] [--diff OUT.png]`: the paper's error
 * metrics of an image A against a reference B, as one JSON object on stdout. The metric
 * definitions live in image_metrics.h and docs/cli.md. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "args.h"
#include "commands.h"
#include "encode.h"
#include "image_metrics.h"
#include "nscatter.h"

static void compare_usage(FILE *out)
{
    fprintf(
        out,
        "usage: nscatter compare A B [--mask M.png] [--diff OUT.png] [--diff-scale S]\n"
        "\n"
        "  A, B            images (.exr linear, or .png sRGB decoded to linear); B is the\n"
        "                  reference (PSNR's peak and the relative error's denominator)\n"
        "  --mask M        PNG or EXR of the same size: pixels with any non-zero channel count\n"
        "  --diff OUT.png  write a false-colour map of |A - B| (channel mean)\n"
        "  --diff-scale S  difference shown at the top of the ramp (default: the largest)\n"
        "\n"
        "prints one JSON object: pixels, peak, rmse/psnr/relerr/mean_ratio (mean of A over\n"
        "mean of B) per channel and overall.\n"
        "exit status: 0 compared, 1 could not write the difference image, 2 bad arguments\n"
        "or unreadable/mismatched images\n");
}

typedef struct compare_args {
    const char *a_path, *b_path, *mask_path, *diff_path;
    double diff_scale;
} compare_args;

static int compare_parse_args(int argc, char **argv, compare_args *args)
{
    memset(args, 0, sizeof *args);
    for (int i = 1; i < argc; i++) {
        const char *arg = argv[i];
        if (!strcmp(arg, "--help") || !strcmp(arg, "-h")) {
            compare_usage(stdout);
            return 0;
        } else if (!strcmp(arg, "--mask") && i + 1 < argc) {
            args->mask_path = argv[++i];
        } else if (!strcmp(arg, "--diff") && i + 1 < argc) {
            args->diff_path = argv[++i];
            const char *dot = strrchr(args->diff_path, '.');
            if (!dot || strcasecmp(dot, ".png")) {
                fprintf(stderr,
                        "nscatter compare: --diff '%s': the difference image is a PNG; "
                        "use a .png name\n",
                        args->diff_path);
                return 2;
            }
        } else if (!strcmp(arg, "--diff-scale") && i + 1 < argc) {
            if (cli_number(argv[++i], &args->diff_scale) || !(args->diff_scale > 0.0)) {
                fprintf(stderr, "nscatter compare: --diff-scale '%s' is not a positive number\n",
                        argv[i]);
                return 2;
            }
        } else if (arg[0] == '-' && arg[1] != '\0') {
            fprintf(stderr, "nscatter compare: unknown or incomplete argument '%s'\n\n", arg);
            compare_usage(stderr);
            return 2;
        } else if (!args->a_path) {
            args->a_path = arg;
        } else if (!args->b_path) {
            args->b_path = arg;
        } else {
            fprintf(stderr, "nscatter compare: unexpected third image '%s'\n\n", arg);
            compare_usage(stderr);
            return 2;
        }
    }
    if (!args->a_path || !args->b_path) {
        fprintf(stderr, "nscatter compare: two images are needed (A and the reference B)\n\n");
        compare_usage(stderr);
        return 2;
    }
    return -1; /* go on */
}

/* JSON cannot hold Inf or NaN: both become null (an identical pair says so separately
 * through "identical": true). */
static json_t *compare_number(double v)
{
    return isfinite(v) ? json_real(v) : json_null();
}

static json_t *compare_channels(const double v[4])
{
    return json_pack("{s:o, s:o, s:o, s:o}", "r", compare_number(v[0]), "g", compare_number(v[1]),
                     "b", compare_number(v[2]), "all", compare_number(v[3]));
}

static int compare_print(const compare_args *args, const ns_image *a, const image_metrics *m,
                         double diff_scale)
{
    json_t *obj = json_pack(
        "{s:s, s:s, s:o, s:I, s:I, s:I, s:b, s:o, s:o, s:o, s:o, s:o, s:f, s:o, s:I}", "a", args->a_path,
        "b", args->b_path, "mask", args->mask_path ? json_string(args->mask_path) : json_null(),
        "width", (json_int_t)a->width, "height", (json_int_t)a->height, "pixels",
        (json_int_t)m->pixels, "identical", m->identical, "peak", compare_number(m->peak), "rmse",
        compare_channels(m->rmse), "psnr", compare_channels(m->psnr), "relerr",
        compare_channels(m->relerr), "mean_ratio", compare_channels(m->mean_ratio), "relerr_epsilon", IMAGE_RELERR_EPSILON, "max_abs_diff",
        compare_number(m->max_abs_diff), "nonfinite", (json_int_t)m->nonfinite);
    if (!obj)
        return 1;
    if (args->diff_path)
        json_object_set_new(obj, "diff",
                            json_pack("{s:s, s:f}", "path", args->diff_path, "scale", diff_scale));
    char *text = json_dumps(obj, JSON_COMPACT | JSON_REAL_PRECISION(9));
    json_decref(obj);
    if (!text)
        return 1;
    printf("%s\n", text);
    free(text);
    return 0;
}

static int compare_write_diff(const compare_args *args, const ns_image *a, const ns_image *b,
                              const uint8_t *mask, double *used_scale)
{
    ns_image diff = {0};
    ns_error err = {0};
    encode_buffer png = {0};
    int status = image_diff_false_colour(a, b, mask, args->diff_scale, &diff, used_scale, &err);
    if (!status)
        status = encode_png(&diff, 0.0f, NULL, 0, &png, &err);
    ns_image_free(&diff);
    if (status) {
        fprintf(stderr, "nscatter compare: difference image: %s\n", err.message);
        return 1;
    }
    FILE *f = fopen(args->diff_path, "wb");
    int ok = f && fwrite(png.data, 1, png.size, f) == png.size;
    if (f && fclose(f) != 0)
        ok = 0;
    if (!ok)
        fprintf(stderr, "nscatter compare: cannot write --diff '%s': %s\n", args->diff_path,
                strerror(errno));
    encode_buffer_free(&png);
    return ok ? 0 : 1;
}

static int compare_load(const char *path, const char *role, ns_image *img)
{
    ns_error err = {0};
    if (image_load(path, img, &err)) {
        fprintf(stderr, "nscatter compare: %s: %s\n", role, err.message);
        return 2;
    }
    return 0;
}

int cmd_compare(int argc, char **argv)
{
    compare_args args;
    int rc = compare_parse_args(argc, argv, &args);
    if (rc >= 0)
        return rc;
    ns_image a = {0}, b = {0};
    uint8_t *mask = NULL;
    rc = compare_load(args.a_path, "A", &a);
    if (!rc)
        rc = compare_load(args.b_path, "B (reference)", &b);
    if (!rc && (a.width != b.width || a.height != b.height)) {
        fprintf(stderr, "nscatter compare: sizes differ: A '%s' is %ux%u, B '%s' is %ux%u\n",
                args.a_path, a.width, a.height, args.b_path, b.width, b.height);
        rc = 2;
    }
    if (!rc && args.mask_path) {
        ns_error err = {0};
        uint32_t mw, mh;
        if (image_load_mask(args.mask_path, &mask, &mw, &mh, &err)) {
            fprintf(stderr, "nscatter compare: --mask: %s\n", err.message);
            rc = 2;
        } else if (mw != a.width || mh != a.height) {
            fprintf(stderr, "nscatter compare: --mask '%s' is %ux%u, the images are %ux%u\n",
                    args.mask_path, mw, mh, a.width, a.height);
            rc = 2;
        }
    }
    image_metrics m;
    if (!rc) {
        image_compare(&a, &b, mask, &m);
        if (m.pixels == 0) {
            fprintf(stderr, "nscatter compare: --mask '%s' selects no pixel\n", args.mask_path);
            rc = 2;
        }
    }
    double diff_scale = 0.0;
    if (!rc && args.diff_path)
        rc = compare_write_diff(&args, &a, &b, mask, &diff_scale);
    if (!rc)
        rc = compare_print(&args, &a, &m, diff_scale);
    free(mask);
    ns_image_free(&a);
    ns_image_free(&b);
    return rc;
}
