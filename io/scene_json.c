/* scene_json.c — scene JSON version 1 (docs/scene.md) to ns_scene, strictly validated.
 *
 * The parser walks the document once, keeping the JSON pointer of the value it is looking
 * at, and reports every problem it can find (up to SCENE_MAX_ISSUES are stored) rather than
 * stopping at the first: a user fixing a scene should see all of its mistakes at once.
 * Nothing is defaulted silently except the documented defaults; any unknown key is an
 * error, so a typo ("radious") never renders a scene that differs from the one intended.
 */
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "gltf_shim.h"
#include "scene_json.h"

struct scene_doc {
    ns_scene scene;
    ns_material *materials;
    ns_object *objects;
    ns_triangle *triangles;
    ns_light *lights;
};

/* =======================================================================================
 * Parser state, JSON pointers and issues
 * ===================================================================================== */

typedef struct parser {
    scene_issues *issues;
    const scene_parse_options *opts;
    char ptr[1024]; /* JSON pointer of the value being looked at */
    size_t ptr_len;
    int oom;

    ns_camera camera;
    ns_material *materials;
    uint32_t material_count;
    int materials_known; /* 0: "materials" was unusable, so references cannot be checked */
    ns_object *objects;
    uint32_t object_count;
    ns_triangle *triangles;
    uint32_t triangle_count;
    size_t triangle_cap;
    ns_light *lights;
    uint32_t light_count;
    ns_render_settings render;
    int vrls_given; /* render.vrls was written (else its default applies) */
} parser;

/* A service's limit (0: none) within the hard one. */
static uint32_t limit(uint32_t service, uint32_t hard)
{
    return service && service < hard ? service : hard;
}

/* Appends "/key" (RFC 6901: '~' as "~0", '/' as "~1") and returns the previous length,
 * which pop() restores. A pointer longer than the buffer is cut, never overrun. */
static size_t push_key(parser *p, const char *key)
{
    size_t saved = p->ptr_len, n = p->ptr_len, cap = sizeof p->ptr - 1;
    if (n < cap)
        p->ptr[n++] = '/';
    for (const char *c = key; *c && n < cap; c++) {
        if (*c == '~' || *c == '/') {
            if (n + 2 > cap)
                break;
            p->ptr[n++] = '~';
            p->ptr[n++] = *c == '~' ? '0' : '1';
        } else {
            p->ptr[n++] = *c;
        }
    }
    p->ptr[n] = '\0';
    p->ptr_len = n;
    return saved;
}

static size_t push_index(parser *p, size_t index)
{
    char buf[32];
    snprintf(buf, sizeof buf, "%zu", index);
    return push_key(p, buf);
}

static void pop(parser *p, size_t saved)
{
    p->ptr_len = saved;
    p->ptr[saved] = '\0';
}

/* Copies src into dst[cap], cut to fit (pointers are built longer than an issue holds). */
static void copy_cut(char *dst, size_t cap, const char *src)
{
    size_t n = strnlen(src, cap - 1);
    memcpy(dst, src, n);
    dst[n] = '\0';
}

static void add_issue(scene_issues *issues, const char *pointer, const char *detail)
{
    issues->total++;
    if (issues->count >= SCENE_MAX_ISSUES)
        return;
    scene_issue *it = &issues->items[issues->count++];
    copy_cut(it->pointer, sizeof it->pointer, pointer);
    copy_cut(it->detail, sizeof it->detail, detail);
}

__attribute__((format(printf, 2, 3))) static void report(parser *p, const char *fmt, ...)
{
    char detail[sizeof p->issues->items[0].detail];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(detail, sizeof detail, fmt, ap);
    va_end(ap);
    add_issue(p->issues, p->ptr, detail);
}

/* Reports at the pointer of the child `key` of the current value. */
__attribute__((format(printf, 3, 4))) static void report_at(parser *p, const char *key,
                                                            const char *fmt, ...)
{
    char detail[sizeof p->issues->items[0].detail];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(detail, sizeof detail, fmt, ap);
    va_end(ap);
    size_t saved = push_key(p, key);
    add_issue(p->issues, p->ptr, detail);
    pop(p, saved);
}

static const char *json_kind(const json_t *v)
{
    switch (json_typeof(v)) {
    case JSON_OBJECT: return "an object";
    case JSON_ARRAY: return "an array";
    case JSON_STRING: return "a string";
    case JSON_INTEGER:
    case JSON_REAL: return "a number";
    case JSON_TRUE:
    case JSON_FALSE: return "a boolean";
    case JSON_NULL: return "null";
    }
    return "something else";
}

/* =======================================================================================
 * Typed values. Each as_* checks the value at the current pointer and reports what is
 * wrong with it; each field_* looks a key up in an object (reporting it missing when it is
 * required) and checks its value at the key's pointer. They return 1 when *out was set.
 * ===================================================================================== */

typedef struct range {
    double lo, hi;
    char lo_open, hi_open; /* 1: the bound itself is excluded */
} range;

static const range R_FINITE = {-FLT_MAX, FLT_MAX, 0, 0};
static const range R_POSITIVE = {0, FLT_MAX, 1, 0};
static const range R_NONNEGATIVE = {0, FLT_MAX, 0, 0};
static const range R_UNIT = {0, 1, 0, 0};
static const range R_G = {-1, 1, 1, 1};
static const range R_IOR = {1, FLT_MAX, 0, 0};
static const range R_FOV = {0, 180, 1, 1};
static const range R_EXPOSURE = {-64, 64, 0, 0};
static const range R_SOLID_ANGLE = {0, 12.57f, 0, 0};
static const range R_ADAPTIVE_SPP = {0, NS_MAX_ADAPTIVE_SPP, 0, 0};

static void describe_range(range r, char *buf, size_t cap)
{
    if (r.lo == -FLT_MAX && r.hi == FLT_MAX)
        snprintf(buf, cap, "a finite number");
    else if (r.hi == FLT_MAX)
        snprintf(buf, cap, "%s %g", r.lo_open ? ">" : ">=", r.lo);
    else
        snprintf(buf, cap, "in %c%g, %g%c", r.lo_open ? '(' : '[', r.lo, r.hi, r.hi_open ? ')' : ']');
}

static int in_range(double x, range r)
{
    return (r.lo_open ? x > r.lo : x >= r.lo) && (r.hi_open ? x < r.hi : x <= r.hi);
}

static int as_number(parser *p, const json_t *v, range r, const char *what, double *out)
{
    char allowed[64];
    describe_range(r, allowed, sizeof allowed);
    if (!json_is_number(v)) {
        report(p, "%s must be a number (%s), got %s", what, allowed, json_kind(v));
        return 0;
    }
    double x = json_number_value(v);
    if (!isfinite(x) || fabs(x) > FLT_MAX) {
        report(p, "%s is too large for a 32-bit float; must be %s", what, allowed);
        return 0;
    }
    if (!in_range(x, r)) {
        report(p, "%s must be %s, got %g", what, allowed, x);
        return 0;
    }
    *out = x;
    return 1;
}

static int as_vec3(parser *p, const json_t *v, range r, const char *what, float out[3])
{
    if (!json_is_array(v) || json_array_size(v) != 3) {
        if (json_is_array(v))
            report(p, "%s must be an array of 3 numbers, got %zu elements", what, json_array_size(v));
        else
            report(p, "%s must be an array of 3 numbers, got %s", what, json_kind(v));
        return 0;
    }
    int ok = 1;
    for (size_t i = 0; i < 3; i++) {
        size_t saved = push_index(p, i);
        double x;
        if (as_number(p, json_array_get(v, i), r, what, &x))
            out[i] = (float)x;
        else
            ok = 0;
        pop(p, saved);
    }
    return ok;
}

/* A color is [r, g, b] or one number meaning grey (the same value in all three). */
static int as_color(parser *p, const json_t *v, range r, const char *what, float out[3])
{
    if (json_is_number(v)) {
        double x;
        if (!as_number(p, v, r, what, &x))
            return 0;
        out[0] = out[1] = out[2] = (float)x;
        return 1;
    }
    if (!json_is_array(v)) {
        report(p, "%s must be [r, g, b] or one number (grey), got %s", what, json_kind(v));
        return 0;
    }
    return as_vec3(p, v, r, what, out);
}

/* An integer in [lo, hi]; a number with no fractional part (256.0) counts as one. */
static int as_uint(parser *p, const json_t *v, double lo, double hi, const char *what, uint32_t *out)
{
    if (!json_is_number(v)) {
        report(p, "%s must be an integer in [%.0f, %.0f], got %s", what, lo, hi, json_kind(v));
        return 0;
    }
    double x = json_number_value(v);
    if (!isfinite(x) || floor(x) != x) {
        report(p, "%s must be an integer in [%.0f, %.0f], got %g", what, lo, hi, x);
        return 0;
    }
    if (x < lo || x > hi) {
        report(p, "%s must be an integer in [%.0f, %.0f], got %.0f", what, lo, hi, x);
        return 0;
    }
    *out = (uint32_t)x;
    return 1;
}

/* One of `names` (count n); *out is its index. */
static int as_enum(parser *p, const json_t *v, const char *const *names, size_t n, const char *what,
                   int *out)
{
    char allowed[256] = "";
    for (size_t i = 0; i < n; i++) {
        size_t len = strlen(allowed);
        snprintf(allowed + len, sizeof allowed - len, "%s\"%s\"", i ? ", " : "", names[i]);
    }
    if (!json_is_string(v)) {
        report(p, "%s must be a string, one of %s; got %s", what, allowed, json_kind(v));
        return 0;
    }
    for (size_t i = 0; i < n; i++)
        if (strcmp(json_string_value(v), names[i]) == 0) {
            *out = (int)i;
            return 1;
        }
    report(p, "unknown %s \"%.64s\"; allowed: %s", what, json_string_value(v), allowed);
    return 0;
}

static void report_missing(parser *p, const char *key, const char *what)
{
    report_at(p, key, "missing required field \"%s\" (%s)", key, what);
}

/* The value of `key`, or NULL (reported as missing when required). */
static const json_t *field(parser *p, const json_t *obj, const char *key, int required, const char *what)
{
    const json_t *v = json_object_get(obj, key);
    if (!v && required)
        report_missing(p, key, what);
    return v;
}

static int field_number(parser *p, const json_t *obj, const char *key, int required, range r,
                        const char *what, double *out)
{
    const json_t *v = field(p, obj, key, required, what);
    if (!v)
        return 0;
    size_t saved = push_key(p, key);
    int ok = as_number(p, v, r, what, out);
    pop(p, saved);
    return ok;
}

static int field_float(parser *p, const json_t *obj, const char *key, int required, range r,
                       const char *what, float *out)
{
    double x;
    if (!field_number(p, obj, key, required, r, what, &x))
        return 0;
    *out = (float)x;
    return 1;
}

static int field_vec3(parser *p, const json_t *obj, const char *key, int required, range r,
                      const char *what, float out[3])
{
    const json_t *v = field(p, obj, key, required, what);
    if (!v)
        return 0;
    size_t saved = push_key(p, key);
    int ok = as_vec3(p, v, r, what, out);
    pop(p, saved);
    return ok;
}

static int field_color(parser *p, const json_t *obj, const char *key, int required, range r,
                       const char *what, float out[3])
{
    const json_t *v = field(p, obj, key, required, what);
    if (!v)
        return 0;
    size_t saved = push_key(p, key);
    int ok = as_color(p, v, r, what, out);
    pop(p, saved);
    return ok;
}

static int field_uint(parser *p, const json_t *obj, const char *key, int required, double lo,
                      double hi, const char *what, uint32_t *out)
{
    const json_t *v = field(p, obj, key, required, what);
    if (!v)
        return 0;
    size_t saved = push_key(p, key);
    int ok = as_uint(p, v, lo, hi, what, out);
    pop(p, saved);
    return ok;
}

static int field_enum(parser *p, const json_t *obj, const char *key, int required,
                      const char *const *names, size_t n, const char *what, int *out)
{
    const json_t *v = field(p, obj, key, required, what);
    if (!v)
        return 0;
    size_t saved = push_key(p, key);
    int ok = as_enum(p, v, names, n, what, out);
    pop(p, saved);
    return ok;
}

/* Reports every key of obj not in the NULL-terminated `allowed` list. */
static void check_keys(parser *p, const json_t *obj, const char *const *allowed)
{
    char list[256] = "";
    for (size_t i = 0; allowed[i]; i++) {
        size_t len = strlen(list);
        snprintf(list + len, sizeof list - len, "%s%s", i ? ", " : "", allowed[i]);
    }
    const char *key;
    const json_t *value;
    json_object_foreach((json_t *)obj, key, value) {
        int known = 0;
        for (size_t i = 0; allowed[i] && !known; i++)
            known = strcmp(key, allowed[i]) == 0;
        if (!known)
            report_at(p, key, "unknown key \"%.64s\"; allowed here: %s", key, list);
    }
}

static int expect_object(parser *p, const json_t *v, const char *what)
{
    if (json_is_object(v))
        return 1;
    report(p, "%s must be an object, got %s", what, json_kind(v));
    return 0;
}

static int expect_array(parser *p, const json_t *v, const char *what)
{
    if (json_is_array(v))
        return 1;
    report(p, "%s must be an array, got %s", what, json_kind(v));
    return 0;
}

/* =======================================================================================
 * Small vector helpers
 * ===================================================================================== */

static double length3(const double v[3])
{
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

/* Normalises a float vector in double precision; returns 0 when it has no direction. */
static int normalize3f(float v[3])
{
    double d[3] = {v[0], v[1], v[2]};
    double len = length3(d);
    if (!(len > 0) || !isfinite(len))
        return 0;
    for (int i = 0; i < 3; i++)
        v[i] = (float)(d[i] / len);
    return 1;
}

/* =======================================================================================
 * Camera
 * ===================================================================================== */

static void parse_camera(parser *p, const json_t *v)
{
    static const char *const keys[] = {"position", "look_at", "up", "fov", "width", "height", NULL};
    if (!expect_object(p, v, "camera"))
        return;
    check_keys(p, v, keys);
    ns_camera *c = &p->camera;
    int have_pos = field_vec3(p, v, "position", 1, R_FINITE, "camera position, scene units", c->position);
    int have_look = field_vec3(p, v, "look_at", 1, R_FINITE, "point the camera looks at", c->look_at);
    int have_up = field_vec3(p, v, "up", 1, R_FINITE, "camera up vector", c->up);
    field_float(p, v, "fov", 1, R_FOV, "fov (horizontal field of view, degrees)", &c->fov_deg);
    int have_w = field_uint(p, v, "width", 1, 1, NS_MAX_IMAGE_SIDE, "width (pixels)", &c->width);
    int have_h = field_uint(p, v, "height", 1, 1, NS_MAX_IMAGE_SIDE, "height (pixels)", &c->height);

    uint32_t max_pixels = limit(p->opts ? p->opts->max_pixels : 0, NS_MAX_PIXELS);
    if (have_w && have_h && (uint64_t)c->width * c->height > max_pixels)
        report_at(p, "height", "width x height = %llu pixels is over the limit of %u pixels",
                  (unsigned long long)c->width * c->height, (unsigned)max_pixels);

    double dir[3] = {0, 0, 0};
    int have_dir = 0;
    if (have_pos && have_look) {
        for (int i = 0; i < 3; i++)
            dir[i] = (double)c->look_at[i] - (double)c->position[i];
        have_dir = length3(dir) > 0;
        if (!have_dir)
            report_at(p, "look_at", "look_at equals position; the camera needs a direction to look in");
    }
    if (have_up) {
        if (!normalize3f(c->up)) {
            report_at(p, "up", "up must not be the zero vector");
        } else if (have_dir) {
            double len = length3(dir);
            double d[3] = {dir[0] / len, dir[1] / len, dir[2] / len};
            double cr[3] = {d[1] * c->up[2] - d[2] * c->up[1], d[2] * c->up[0] - d[0] * c->up[2],
                            d[0] * c->up[1] - d[1] * c->up[0]};
            if (length3(cr) < 1e-6)
                report_at(p, "up", "up is parallel to the view direction (look_at - position); "
                                   "it must point away from it");
        }
    }
}

/* =======================================================================================
 * Materials
 * ===================================================================================== */

/* The paper's Table 1 (Ge et al. 2021): albedo and mean free path per channel, g, eta. */
typedef struct preset {
    const char *name;
    double albedo[3], mfp[3], g, ior;
} preset;

static const preset presets[] = {
    {"bumpy_sphere", {0.955, 0.677, 0.457}, {4.55, 3.23, 2.17}, 0.9, 1.50},
    {"candle", {0.980, 0.962, 0.750}, {0.65, 0.63, 0.59}, 0.8, 1.45},
    {"dragon", {0.882, 0.938, 0.980}, {0.29, 0.18, 0.33}, 0.5, 1.50},
    {"milk", {0.999, 0.999, 0.999}, {0.84, 0.75, 0.68}, 0.7, 1.30},
    {"oil", {0.398, 0.453, 0.032}, {9.71, 11.63, 2.74}, 0.9, 1.50},
    {"lucy", {0.936, 0.939, 0.941}, {0.21, 0.20, 0.19}, 0.0, 1.50},
    {"cloud", {0.909, 0.909, 0.909}, {0.909, 0.909, 0.909}, 0.0, 1.0},
};
#define PRESET_COUNT (sizeof presets / sizeof presets[0])

uint32_t scene_preset_count(void)
{
    return (uint32_t)PRESET_COUNT;
}

int scene_preset_get(uint32_t index, scene_preset *out)
{
    if (index >= PRESET_COUNT)
        return NS_ERR_INVALID_ARGUMENT;
    const preset *p = &presets[index];
    out->name = p->name;
    memcpy(out->albedo, p->albedo, sizeof out->albedo);
    memcpy(out->mfp, p->mfp, sizeof out->mfp);
    out->g = p->g;
    out->ior = p->ior;
    return NS_OK;
}

static const preset *find_preset(parser *p, const json_t *m)
{
    const char *names[PRESET_COUNT];
    for (size_t i = 0; i < PRESET_COUNT; i++)
        names[i] = presets[i].name;
    int index;
    if (!field_enum(p, m, "preset", 0, names, PRESET_COUNT, "preset", &index))
        return NULL;
    return &presets[index];
}

/* Writes scale * coefficient into out, refusing results a float cannot hold. */
/* The floats are chosen so that sigma_s + sigma_a, added as floats (as the GPU scene does),
 * is exactly the extinction rounded to a float. Rounding each part on its own would move
 * that sum by an ulp for about one albedo in six, so a sweep of albedo at one mean free path
 * would see a different extinction, and trace the camera pass again (render/camera_keep.c),
 * for no physical reason. The smaller part carries the albedo's precision (milk's sigma_a is
 * a thousandth of sigma_t), so it is rounded as usual, or moved by a few of its own ulps
 * where the float sum would otherwise tie between two floats; the larger is the extinction
 * minus it, moved by an ulp. Should no such pair exist, the larger part rounded and the
 * smaller the exact rest (Sterbenz: the larger is at least half the extinction) always
 * sum exactly. */
static void split_extinction(double s, double a, float *sigma_s, float *sigma_a)
{
    float extinction = (float)(s + a);
    float nearest = (float)(s < a ? s : a), smaller = nearest, larger = 0.0f;
    int found = 0;
    for (int k = 0; k < 9 && !found; k++) { /* nearest, +1, -1, +2, -2 ... of its ulps */
        smaller = nearest;
        for (int j = 0; j < (k + 1) / 2; j++)
            smaller = nextafterf(smaller, k % 2 ? INFINITY : 0.0f);
        larger = extinction - smaller;
        for (int step = 0; step < 3 && !found; step++) {
            found = larger + smaller == extinction && smaller >= 0.0f && larger >= smaller;
            if (!found)
                larger = nextafterf(larger, larger + smaller < extinction ? INFINITY : 0.0f);
        }
    }
    if (!found) {
        larger = (float)(s < a ? a : s);
        smaller = extinction - larger;
    }
    *sigma_s = s < a ? smaller : larger;
    *sigma_a = s < a ? larger : smaller;
}

static int store_coefficients(parser *p, const double sigma_s[3], const double sigma_a[3], double scale,
                              ns_material *out)
{
    for (int i = 0; i < 3; i++) {
        double s = sigma_s[i] * scale, a = sigma_a[i] * scale;
        if (!(s + a <= FLT_MAX)) {
            report(p, "the resolved coefficients (sigma_s, sigma_a = %g, %g per scene unit) "
                      "overflow a 32-bit float; use a larger mfp or a smaller scale", s, a);
            return 0;
        }
        split_extinction(s, a, &out->sigma_s[i], &out->sigma_a[i]);
    }
    return 1;
}

static void parse_medium(parser *p, const json_t *m, ns_material *out)
{
    static const char *const keys[] = {"type", "preset", "sigma_s", "sigma_a", "albedo", "mfp",
                                       "scale", "g", "ior", NULL};
    check_keys(p, m, keys);
    const preset *pre = find_preset(p, m);
    int preset_bad = json_object_get(m, "preset") && !pre;

    double albedo[3] = {0, 0, 0}, mfp[3] = {1, 1, 1};
    out->g = pre ? (float)pre->g : 0.0f;
    out->ior = pre ? (float)pre->ior : 1.0f;
    if (pre)
        for (int i = 0; i < 3; i++)
            albedo[i] = pre->albedo[i], mfp[i] = pre->mfp[i];

    field_float(p, m, "g", 0, R_G, "g (Henyey-Greenstein anisotropy)", &out->g);
    field_float(p, m, "ior", 0, R_IOR, "ior (index of refraction, 1 = index matched)", &out->ior);
    double scale = 1;
    int ok = 1;
    if (json_object_get(m, "scale"))
        ok &= field_number(p, m, "scale", 1, R_POSITIVE, "scale (multiplies the coefficients)", &scale);

    const char *sigma_key = json_object_get(m, "sigma_s") ? "sigma_s"
                            : json_object_get(m, "sigma_a") ? "sigma_a"
                                                             : NULL;
    const char *amfp_key = json_object_get(m, "albedo") ? "albedo"
                           : json_object_get(m, "mfp")  ? "mfp"
                                                        : NULL;
    if (sigma_key && amfp_key) {
        report_at(p, amfp_key, "\"%s\" contradicts \"%s\": a medium is given by sigma_s+sigma_a "
                               "or by albedo+mfp, never both", amfp_key, sigma_key);
        ok = 0;
    }
    if (!sigma_key && !amfp_key && !pre) {
        if (!preset_bad)
            report(p, "a medium needs sigma_s+sigma_a (per scene unit), albedo+mfp, or a preset");
        return;
    }

    if (sigma_key) {
        /* The coefficient form replaces a preset's coefficients entirely, so both are
         * needed even with a preset (after a contradiction, only what is there is checked:
         * the user has to drop one form anyway). */
        float fs[3], fa[3], unused[3];
        int need = !amfp_key;
        if (amfp_key) {
            field_color(p, m, "albedo", 0, R_UNIT, "albedo (single-scattering albedo)", unused);
            field_color(p, m, "mfp", 0, R_POSITIVE, "mfp (mean free path, scene units)", unused);
        }
        ok &= field_color(p, m, "sigma_s", need, R_NONNEGATIVE, "sigma_s (scattering coefficient per scene unit)", fs);
        ok &= field_color(p, m, "sigma_a", need, R_NONNEGATIVE, "sigma_a (absorption coefficient per scene unit)", fa);
        if (ok && !amfp_key) {
            double s[3] = {fs[0], fs[1], fs[2]}, a[3] = {fa[0], fa[1], fa[2]};
            store_coefficients(p, s, a, scale, out);
        }
        return;
    }
    /* Albedo/mfp form: each field overrides the preset's; without a preset both are needed. */
    float fv[3];
    if (field_color(p, m, "albedo", !pre, R_UNIT, "albedo (single-scattering albedo)", fv))
        for (int i = 0; i < 3; i++)
            albedo[i] = fv[i];
    else if (json_object_get(m, "albedo") || !pre)
        ok = 0;
    if (field_color(p, m, "mfp", !pre, R_POSITIVE, "mfp (mean free path, scene units)", fv))
        for (int i = 0; i < 3; i++)
            mfp[i] = fv[i];
    else if (json_object_get(m, "mfp") || !pre)
        ok = 0;
    if (!ok || preset_bad)
        return;
    double sigma_s[3], sigma_a[3];
    for (int i = 0; i < 3; i++) {
        double sigma_t = 1.0 / mfp[i];
        sigma_s[i] = albedo[i] * sigma_t;
        sigma_a[i] = (1.0 - albedo[i]) * sigma_t;
    }
    store_coefficients(p, sigma_s, sigma_a, scale, out);
}

static void parse_material(parser *p, const json_t *m, ns_material *out)
{
    static const char *const types[] = {"diffuse", "medium"};
    static const char *const diffuse_keys[] = {"type", "reflectance", NULL};
    if (!expect_object(p, m, "a material"))
        return;
    int type;
    if (!field_enum(p, m, "type", 1, types, 2, "material type", &type))
        return;
    if (type == 0) {
        out->type = NS_MATERIAL_DIFFUSE;
        check_keys(p, m, diffuse_keys);
        field_color(p, m, "reflectance", 1, R_UNIT, "reflectance (diffuse albedo)", out->reflectance);
    } else {
        out->type = NS_MATERIAL_MEDIUM;
        parse_medium(p, m, out);
    }
}

static void parse_materials(parser *p, const json_t *v)
{
    if (!expect_object(p, v, "materials (an object keyed by material name)"))
        return;
    size_t n = json_object_size(v);
    if (n > NS_MAX_MATERIALS) {
        report(p, "%zu materials is over the limit of %d", n, NS_MAX_MATERIALS);
        return;
    }
    p->materials = calloc(n ? n : 1, sizeof *p->materials);
    if (!p->materials) {
        p->oom = 1;
        return;
    }
    p->materials_known = 1;
    const char *name;
    const json_t *m;
    json_object_foreach((json_t *)v, name, m) {
        ns_material *out = &p->materials[p->material_count++];
        size_t saved = push_key(p, name);
        size_t len = strlen(name);
        if (len == 0 || len >= NS_NAME_MAX)
            report(p, "material names must be 1 to %d bytes long, got %zu", NS_NAME_MAX - 1, len);
        /* Kept (cut) even when invalid, so that objects naming it are not reported too. */
        snprintf(out->name, sizeof out->name, "%s", name);
        parse_material(p, m, out);
        pop(p, saved);
    }
}

/* =======================================================================================
 * Mesh sources: base64, data: URIs, named assets
 * ===================================================================================== */

static int base64_value(unsigned char c)
{
    if (c >= 'A' && c <= 'Z') return c - 'A';
    if (c >= 'a' && c <= 'z') return c - 'a' + 26;
    if (c >= '0' && c <= '9') return c - '0' + 52;
    if (c == '+') return 62;
    if (c == '/') return 63;
    return -1;
}

/* Standard base64 (RFC 4648 section 4); padding optional, ASCII whitespace ignored so that
 * wrapped output of base64(1) works. Returns 0 and a malloc'd buffer, or writes why not. */
static int base64_decode(const char *s, size_t len, unsigned char **out, size_t *out_len, int *oom,
                         char *why, size_t why_len)
{
    *out = NULL;
    *out_len = 0;
    if (len / 4 * 3 > GLTF_MAX_BYTES + 3) {
        snprintf(why, why_len, "decodes to more than the %zu-byte limit for a mesh", GLTF_MAX_BYTES);
        return -1;
    }
    unsigned char *buf = malloc(len / 4 * 3 + 3);
    if (!buf) {
        *oom = 1;
        snprintf(why, why_len, "out of memory");
        return -1;
    }
    uint32_t acc = 0;
    size_t bits = 0, n = 0, pad = 0, digits = 0;
    for (size_t i = 0; i < len; i++) {
        unsigned char c = (unsigned char)s[i];
        if (c == ' ' || c == '\n' || c == '\r' || c == '\t')
            continue;
        if (c == '=') {
            pad++;
            continue;
        }
        int val = base64_value(c);
        if (val < 0 || pad) {
            if (val < 0)
                snprintf(why, why_len, "is not valid base64: character 0x%02x at offset %zu", c, i);
            else
                snprintf(why, why_len, "is not valid base64: data after '=' padding at offset %zu", i);
            free(buf);
            return -1;
        }
        digits++;
        acc = (acc << 6) | (uint32_t)val;
        bits += 6;
        if (bits >= 8) {
            bits -= 8;
            buf[n++] = (unsigned char)(acc >> bits);
            acc &= (1u << bits) - 1;
        }
    }
    if (digits % 4 == 1 || pad > 2 || (pad && (digits + pad) % 4 != 0)) {
        snprintf(why, why_len, "is not valid base64: its length does not fit whole bytes");
        free(buf);
        return -1;
    }
    *out = buf;
    *out_len = n;
    return 0;
}

static int starts_with_nocase(const char *s, const char *prefix)
{
    for (; *prefix; s++, prefix++) {
        char c = *s >= 'A' && *s <= 'Z' ? (char)(*s - 'A' + 'a') : *s;
        if (c != *prefix)
            return 0;
    }
    return 1;
}

/* data:[<mediatype>][;params];base64,<data> */
static int decode_data_uri(const char *uri, unsigned char **out, size_t *out_len, int *oom, char *why,
                           size_t why_len)
{
    *out = NULL;
    if (!starts_with_nocase(uri, "data:")) {
        snprintf(why, why_len, "only data: URIs are accepted (data:model/gltf-binary;base64,...); "
                               "use \"asset\" for a file in the server's asset folder");
        return -1;
    }
    const char *comma = strchr(uri, ',');
    if (!comma) {
        snprintf(why, why_len, "is a data: URI without the ',' before its data");
        return -1;
    }
    size_t meta_len = (size_t)(comma - uri);
    if (meta_len < 12 || !starts_with_nocase(comma - 7, ";base64")) {
        snprintf(why, why_len, "must be a base64 data: URI (data:<type>;base64,<data>)");
        return -1;
    }
    return base64_decode(comma + 1, strlen(comma + 1), out, out_len, oom, why, why_len);
}

static int asset_name_ok(const char *name, char *why, size_t why_len)
{
    size_t len = strlen(name);
    if (len == 0 || len > 255 || name[0] == '.' || strchr(name, '/') || strchr(name, '\\')) {
        snprintf(why, why_len, "\"%.64s\" is not an asset name: names are 1-255 bytes, contain no "
                               "'/' or '\\\\', and do not start with '.'", name);
        return 0;
    }
    for (const char *c = name; *c; c++)
        if ((unsigned char)*c < 0x20 || *c == 0x7f) {
            snprintf(why, why_len, "asset names may not contain control characters");
            return 0;
        }
    return 1;
}

static int read_asset(const char *dir, const char *name, unsigned char **out, size_t *out_len, int *oom,
                      char *why, size_t why_len)
{
    *out = NULL;
    char path[4096];
    if ((size_t)snprintf(path, sizeof path, "%s/%s", dir, name) >= sizeof path) {
        snprintf(why, why_len, "asset path is too long");
        return -1;
    }
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(why, why_len, "asset \"%.64s\" cannot be opened: %s", name, strerror(errno));
        return -1;
    }
    int rc = -1;
    unsigned char *buf = NULL;
    long size = -1;
    if (fseek(f, 0, SEEK_END) == 0)
        size = ftell(f);
    if (size < 0 || fseek(f, 0, SEEK_SET) != 0) {
        snprintf(why, why_len, "asset \"%.64s\" is not a regular readable file", name);
    } else if ((unsigned long)size > GLTF_MAX_BYTES) {
        snprintf(why, why_len, "asset \"%.64s\" is %ld bytes, over the %zu-byte limit", name, size, GLTF_MAX_BYTES);
    } else if (!(buf = malloc((size_t)size + 1))) {
        *oom = 1;
        snprintf(why, why_len, "out of memory");
    } else if (fread(buf, 1, (size_t)size, f) != (size_t)size) {
        snprintf(why, why_len, "asset \"%.64s\" could not be read", name);
    } else {
        *out = buf;
        *out_len = (size_t)size;
        buf = NULL;
        rc = 0;
    }
    free(buf);
    fclose(f);
    return rc;
}

/* =======================================================================================
 * Objects
 * ===================================================================================== */

/* Affine object transform p' = T + R * (S * p), R = Rz * Ry * Rx (rotate about x first). */
typedef struct xform {
    double m[3][4];
} xform;

static int parse_transform(parser *p, const json_t *t, xform *out)
{
    static const char *const keys[] = {"translate", "rotate_deg", "scale", NULL};
    if (!expect_object(p, t, "transform"))
        return 0;
    check_keys(p, t, keys);
    float tr[3] = {0, 0, 0}, rot[3] = {0, 0, 0}, sc[3] = {1, 1, 1};
    int ok = 1;
    if (json_object_get(t, "translate"))
        ok &= field_vec3(p, t, "translate", 1, R_FINITE, "translate (scene units)", tr);
    if (json_object_get(t, "rotate_deg"))
        ok &= field_vec3(p, t, "rotate_deg", 1, R_FINITE, "rotate_deg ([x, y, z] degrees)", rot);
    const json_t *s = json_object_get(t, "scale");
    if (s) {
        size_t saved = push_key(p, "scale");
        if (json_is_number(s)) {
            double x;
            if (as_number(p, s, R_POSITIVE, "scale", &x))
                sc[0] = sc[1] = sc[2] = (float)x;
            else
                ok = 0;
        } else if (json_is_array(s)) {
            ok &= as_vec3(p, s, R_POSITIVE, "scale", sc);
        } else {
            report(p, "scale must be a number > 0 or [sx, sy, sz], got %s", json_kind(s));
            ok = 0;
        }
        pop(p, saved);
    }
    if (!ok)
        return 0;
    const double to_rad = acos(-1.0) / 180.0;
    double cx = cos(rot[0] * to_rad), sx = sin(rot[0] * to_rad);
    double cy = cos(rot[1] * to_rad), sy = sin(rot[1] * to_rad);
    double cz = cos(rot[2] * to_rad), sz = sin(rot[2] * to_rad);
    double r[3][3] = {
        {cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx},
        {sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx},
        {-sy, cy * sx, cy * cx},
    };
    for (int row = 0; row < 3; row++) {
        for (int col = 0; col < 3; col++)
            out->m[row][col] = r[row][col] * sc[col];
        out->m[row][3] = tr[row];
    }
    return 1;
}

/* The inverse transpose of x's 3x3 part, up to a positive factor (its cofactor matrix: x has
 * no mirroring, its scales are positive), for carrying normals. */
static void normal_matrix(const xform *x, double out[3][3])
{
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            out[r][c] = x->m[(r + 1) % 3][(c + 1) % 3] * x->m[(r + 2) % 3][(c + 2) % 3] -
                        x->m[(r + 1) % 3][(c + 2) % 3] * x->m[(r + 2) % 3][(c + 1) % 3];
}

/* Appends count triangles (9 floats each) moved by x; normals (9 floats each, or NULL: flat)
 * moved by x's normal matrix and normalised, a triangle with all-zero normals staying flat. */
static int append_triangles(parser *p, const float *pos, const float *normals, size_t count,
                            const xform *x)
{
    if (p->triangle_count + count > p->triangle_cap) {
        size_t cap = p->triangle_cap ? p->triangle_cap : 64;
        while (cap < p->triangle_count + count)
            cap *= 2;
        ns_triangle *grown = realloc(p->triangles, cap * sizeof *grown);
        if (!grown) {
            p->oom = 1;
            return 0;
        }
        p->triangles = grown;
        p->triangle_cap = cap;
    }
    double nm[3][3];
    normal_matrix(x, nm);
    for (size_t t = 0; t < count; t++) {
        ns_triangle *tri = &p->triangles[p->triangle_count + t];
        memset(tri, 0, sizeof *tri);
        for (int v = 0; v < 3; v++) {
            const float *in = pos + t * 9 + v * 3;
            for (int a = 0; a < 3; a++) {
                double w = x->m[a][0] * in[0] + x->m[a][1] * in[1] + x->m[a][2] * in[2] + x->m[a][3];
                if (!(fabs(w) <= FLT_MAX)) {
                    report(p, "a vertex of triangle %zu is not finite after the transform", t);
                    return 0;
                }
                tri->v[v][a] = (float)w;
            }
        }
        const float *n = normals ? normals + t * 9 : NULL;
        int given = 0;
        for (int k = 0; n && k < 9; k++)
            given |= n[k] != 0.0f;
        for (int v = 0; given && v < 3; v++) {
            double w[3], len = 0;
            for (int a = 0; a < 3; a++) {
                w[a] = nm[a][0] * n[v * 3] + nm[a][1] * n[v * 3 + 1] + nm[a][2] * n[v * 3 + 2];
                len += w[a] * w[a];
            }
            len = sqrt(len);
            for (int a = 0; a < 3; a++)
                tri->n[v][a] = len > 0 ? (float)(w[a] / len) : 0.0f;
        }
    }
    p->triangle_count += (uint32_t)count;
    return 1;
}

/* ---------------------------------------------------------------------------------------
 * Generated normals ("normals": "smooth" on a mesh without NORMAL)
 * ------------------------------------------------------------------------------------- */

/* Faces that meet at more than this angle keep their shared edge sharp. */
#define SMOOTH_CREASE_COS 0.5 /* 60 degrees */

typedef struct corner_ref {
    float position[3];
    uint32_t triangle, corner;
} corner_ref;

static int compare_corners(const void *a, const void *b)
{
    const corner_ref *x = a, *y = b;
    for (int k = 0; k < 3; k++)
        if (x->position[k] != y->position[k])
            return x->position[k] < y->position[k] ? -1 : 1;
    return 0;
}

/* Unit face normal times the corner's angle (the angle-weighted vertex normal of Thürmer and
 * Wüthrich 1998, which does not depend on how a surface is split into triangles); zero for a
 * degenerate triangle. unit_face: the face normal alone. */
static void corner_weighted_normal(const ns_triangle *t, int corner, double out[3], double unit_face[3])
{
    double e1[3], e2[3], f[3];
    for (int k = 0; k < 3; k++) {
        e1[k] = (double)t->v[1][k] - t->v[0][k];
        e2[k] = (double)t->v[2][k] - t->v[0][k];
    }
    f[0] = e1[1] * e2[2] - e1[2] * e2[1];
    f[1] = e1[2] * e2[0] - e1[0] * e2[2];
    f[2] = e1[0] * e2[1] - e1[1] * e2[0];
    double len = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
    double a[3], b[3], la = 0, lb = 0, dot = 0;
    for (int k = 0; k < 3; k++) {
        a[k] = (double)t->v[(corner + 1) % 3][k] - t->v[corner][k];
        b[k] = (double)t->v[(corner + 2) % 3][k] - t->v[corner][k];
        la += a[k] * a[k];
        lb += b[k] * b[k];
        dot += a[k] * b[k];
    }
    double angle = la > 0 && lb > 0 ? acos(fmax(-1.0, fmin(1.0, dot / sqrt(la * lb)))) : 0.0;
    for (int k = 0; k < 3; k++) {
        unit_face[k] = len > 0 ? f[k] / len : 0.0;
        out[k] = unit_face[k] * angle;
    }
}

/* Shading normals for triangles [first, first + count): at each corner, the angle-weighted
 * normals of the triangles that share its position (exactly, after the transform) and whose
 * faces are within the crease angle of its own. A corner whose sum vanishes, or a degenerate
 * triangle, leaves its triangle flat. */
static int generate_normals(parser *p, uint32_t first, size_t count)
{
    size_t corners = count * 3;
    corner_ref *refs = malloc(sizeof *refs * (corners ? corners : 1));
    if (!refs) {
        p->oom = 1;
        return 0;
    }
    ns_triangle *tris = p->triangles + first;
    for (size_t i = 0; i < corners; i++) {
        refs[i].triangle = (uint32_t)(i / 3);
        refs[i].corner = (uint32_t)(i % 3);
        memcpy(refs[i].position, tris[i / 3].v[i % 3], sizeof refs[i].position);
    }
    qsort(refs, corners, sizeof *refs, compare_corners);
    for (size_t start = 0; start < corners;) {
        size_t end = start + 1;
        while (end < corners && compare_corners(&refs[start], &refs[end]) == 0)
            end++;
        for (size_t i = start; i < end; i++) {
            double own[3], own_face[3], sum[3] = {0, 0, 0};
            corner_weighted_normal(&tris[refs[i].triangle], (int)refs[i].corner, own, own_face);
            for (size_t j = start; j < end; j++) {
                double w[3], face[3];
                corner_weighted_normal(&tris[refs[j].triangle], (int)refs[j].corner, w, face);
                if (face[0] * own_face[0] + face[1] * own_face[1] + face[2] * own_face[2] >=
                    SMOOTH_CREASE_COS)
                    for (int k = 0; k < 3; k++)
                        sum[k] += w[k];
            }
            double len = sqrt(sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]);
            float *n = tris[refs[i].triangle].n[refs[i].corner];
            for (int k = 0; k < 3; k++)
                n[k] = len > 0 ? (float)(sum[k] / len) : 0.0f;
        }
        start = end;
    }
    free(refs);
    /* A triangle with a corner left without a normal stays flat as a whole. */
    for (size_t t = 0; t < count; t++) {
        int missing = 0;
        for (int v = 0; v < 3; v++)
            missing |= tris[t].n[v][0] == 0.0f && tris[t].n[v][1] == 0.0f && tris[t].n[v][2] == 0.0f;
        if (missing)
            memset(tris[t].n, 0, sizeof tris[t].n);
    }
    return 1;
}

/* Reads the one mesh source of o (its key in *source_key) into malloc'd bytes. */
static int mesh_bytes(parser *p, const json_t *o, const char *key, unsigned char **bytes, size_t *len)
{
    const json_t *v = json_object_get(o, key);
    size_t saved = push_key(p, key);
    char why[400] = "";
    int rc = -1;
    if (!json_is_string(v)) {
        report(p, "%s must be a string, got %s", key, json_kind(v));
        pop(p, saved);
        return -1;
    }
    const char *s = json_string_value(v);
    if (strcmp(key, "glb_base64") == 0) {
        rc = base64_decode(s, json_string_length(v), bytes, len, &p->oom, why, sizeof why);
        if (rc)
            report(p, "glb_base64 %s", why);
    } else if (strcmp(key, "uri") == 0) {
        rc = decode_data_uri(s, bytes, len, &p->oom, why, sizeof why);
        if (rc)
            report(p, "uri %s", why);
    } else if (!asset_name_ok(s, why, sizeof why)) {
        report(p, "%s", why);
    } else if (!p->opts || !p->opts->asset_dir) {
        report(p, "assets are not available: this server has no asset folder; "
                  "send the mesh as glb_base64 or a data: uri");
    } else {
        rc = read_asset(p->opts->asset_dir, s, bytes, len, &p->oom, why, sizeof why);
        if (rc)
            report(p, "%s", why);
    }
    pop(p, saved);
    return rc;
}

enum { MESH_AUTO, MESH_FLAT, MESH_SMOOTH };

static void parse_mesh(parser *p, const json_t *o, ns_object *out)
{
    static const char *const sources[] = {"glb_base64", "uri", "asset"};
    const char *source = NULL;
    for (size_t i = 0; i < 3; i++) {
        if (!json_object_get(o, sources[i]))
            continue;
        if (source)
            report_at(p, sources[i], "a mesh takes exactly one of glb_base64, uri, asset; "
                                     "\"%s\" is given too", source);
        else
            source = sources[i];
    }
    if (!source) {
        report(p, "missing mesh data: give exactly one of \"glb_base64\" (GLB bytes as base64), "
                  "\"uri\" (a data: URI) or \"asset\" (a file name in the server's asset folder)");
        return;
    }
    /* "normals": the file's NORMAL where given, else flat (auto); never (flat); the file's,
     * else generated (smooth). */
    static const char *const shading_names[] = {"auto", "flat", "smooth"};
    int shading = MESH_AUTO;
    if (json_object_get(o, "normals") &&
        !field_enum(p, o, "normals", 0, shading_names, 3, "shading normals", &shading))
        shading = MESH_AUTO; /* reported; the rest of the mesh is still checked */
    xform x = {{{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}}};
    const json_t *t = json_object_get(o, "transform");
    int transform_ok = 1;
    if (t) {
        size_t saved = push_key(p, "transform");
        transform_ok = parse_transform(p, t, &x);
        pop(p, saved);
    }
    unsigned char *bytes = NULL;
    size_t len = 0;
    if (mesh_bytes(p, o, source, &bytes, &len) != 0)
        return;
    float *pos = NULL, *normals = NULL;
    size_t count = 0;
    char err[400];
    uint32_t max_triangles = limit(p->opts ? p->opts->max_triangles : 0, NS_MAX_TRIANGLES);
    size_t room = p->triangle_count < max_triangles ? max_triangles - p->triangle_count : 0;
    int rc = gltf_load_shaded(bytes, len, room, &pos, shading == MESH_FLAT ? NULL : &normals,
                              &count, err, sizeof err);
    free(bytes);
    if (rc == NS_ERR_OUT_OF_HOST_MEMORY) {
        p->oom = 1;
    } else if (rc == NS_ERR_LIMIT) {
        report(p, "%s; a scene holds at most %u triangles in all", err, (unsigned)max_triangles);
    } else if (rc != 0) {
        report_at(p, source, "%s", err);
    } else if (transform_ok) {
        out->first_triangle = p->triangle_count;
        if (append_triangles(p, pos, normals, count, &x) &&
            (shading != MESH_SMOOTH || normals || generate_normals(p, out->first_triangle, count)))
            out->triangle_count = (uint32_t)count;
    }
    free(pos);
    free(normals);
}

static uint32_t find_material(const parser *p, const char *name)
{
    for (uint32_t i = 0; i < p->material_count; i++)
        if (strcmp(p->materials[i].name, name) == 0)
            return i;
    return UINT32_MAX;
}

static void parse_object_material(parser *p, const json_t *o, ns_object *out)
{
    const json_t *v = field(p, o, "material", 1, "the name of a key of \"materials\"");
    if (!v)
        return;
    size_t saved = push_key(p, "material");
    if (!json_is_string(v)) {
        report(p, "material must be a string naming a key of \"materials\", got %s", json_kind(v));
    } else if (p->materials_known) {
        out->material = find_material(p, json_string_value(v));
        if (out->material == UINT32_MAX) {
            char list[256] = "";
            for (uint32_t i = 0; i < p->material_count && strlen(list) < 200; i++) {
                size_t len = strlen(list);
                snprintf(list + len, sizeof list - len, "%s\"%s\"", i ? ", " : "", p->materials[i].name);
            }
            report(p, "unknown material \"%.64s\"; defined: %s", json_string_value(v),
                   p->material_count ? list : "none");
        }
    }
    pop(p, saved);
}

static void parse_object(parser *p, const json_t *o, ns_object *out)
{
    static const char *const shapes[] = {"sphere", "plane", "box", "mesh"};
    static const char *const sphere_keys[] = {"shape", "material", "center", "radius", NULL};
    static const char *const plane_keys[] = {"shape", "material", "point", "normal", NULL};
    static const char *const box_keys[] = {"shape", "material", "min", "max", NULL};
    static const char *const mesh_keys[] = {"shape", "material", "glb_base64", "uri", "asset", "transform", "normals", NULL};
    static const char *const *const keys[] = {sphere_keys, plane_keys, box_keys, mesh_keys};
    if (!expect_object(p, o, "an object"))
        return;
    int shape;
    int have_shape = field_enum(p, o, "shape", 1, shapes, 4, "shape", &shape);
    parse_object_material(p, o, out);
    if (!have_shape)
        return;
    out->shape = (ns_shape)shape;
    check_keys(p, o, keys[shape]);
    switch (out->shape) {
    case NS_SHAPE_SPHERE:
        field_vec3(p, o, "center", 1, R_FINITE, "sphere center, scene units", out->center);
        field_float(p, o, "radius", 1, R_POSITIVE, "sphere radius, scene units", &out->radius);
        break;
    case NS_SHAPE_PLANE:
        field_vec3(p, o, "point", 1, R_FINITE, "a point on the plane", out->point);
        if (field_vec3(p, o, "normal", 1, R_FINITE, "plane normal", out->normal) && !normalize3f(out->normal))
            report_at(p, "normal", "normal must not be the zero vector");
        break;
    case NS_SHAPE_BOX: {
        int have_min = field_vec3(p, o, "min", 1, R_FINITE, "box minimum corner", out->min);
        int have_max = field_vec3(p, o, "max", 1, R_FINITE, "box maximum corner", out->max);
        for (int a = 0; a < 3 && have_min && have_max; a++)
            if (!(out->max[a] > out->min[a])) {
                report_at(p, "max", "max must exceed min on every axis; on %c, max %g <= min %g",
                          "xyz"[a], out->max[a], out->min[a]);
                break;
            }
        break;
    }
    case NS_SHAPE_MESH:
        parse_mesh(p, o, out);
        break;
    }
}

static void parse_objects(parser *p, const json_t *v)
{
    if (!expect_array(p, v, "objects"))
        return;
    size_t n = json_array_size(v);
    if (n > NS_MAX_OBJECTS) {
        report(p, "%zu objects is over the limit of %d", n, NS_MAX_OBJECTS);
        return;
    }
    p->objects = calloc(n ? n : 1, sizeof *p->objects);
    if (!p->objects) {
        p->oom = 1;
        return;
    }
    for (size_t i = 0; i < n && !p->oom; i++) {
        size_t saved = push_index(p, i);
        parse_object(p, json_array_get(v, i), &p->objects[i]);
        pop(p, saved);
    }
    p->object_count = (uint32_t)n;
}

/* =======================================================================================
 * Lights
 * ===================================================================================== */

static void parse_light(parser *p, const json_t *l, ns_light *out, size_t *environment_at, size_t index)
{
    static const char *const types[] = {"directional", "point", "sphere", "environment"};
    static const char *const directional_keys[] = {"type", "direction", "irradiance", NULL};
    static const char *const point_keys[] = {"type", "position", "intensity", NULL};
    static const char *const sphere_keys[] = {"type", "center", "radius", "radiance", NULL};
    static const char *const environment_keys[] = {"type", "radiance", NULL};
    static const char *const *const keys[] = {directional_keys, point_keys, sphere_keys, environment_keys};
    if (!expect_object(p, l, "a light"))
        return;
    int type;
    if (!field_enum(p, l, "type", 1, types, 4, "light type", &type))
        return;
    out->type = (ns_light_type)type;
    check_keys(p, l, keys[type]);
    switch (out->type) {
    case NS_LIGHT_DIRECTIONAL:
        if (field_vec3(p, l, "direction", 1, R_FINITE, "direction the light travels", out->direction) &&
            !normalize3f(out->direction))
            report_at(p, "direction", "direction must not be the zero vector");
        field_color(p, l, "irradiance", 1, R_NONNEGATIVE, "irradiance (W/m^2 facing the light)", out->color);
        break;
    case NS_LIGHT_POINT:
        field_vec3(p, l, "position", 1, R_FINITE, "light position, scene units", out->position);
        field_color(p, l, "intensity", 1, R_NONNEGATIVE, "intensity (W/sr)", out->color);
        break;
    case NS_LIGHT_SPHERE:
        field_vec3(p, l, "center", 1, R_FINITE, "sphere light center, scene units", out->position);
        field_float(p, l, "radius", 1, R_POSITIVE, "sphere light radius, scene units", &out->radius);
        field_color(p, l, "radiance", 1, R_NONNEGATIVE, "radiance (W/(m^2 sr))", out->color);
        break;
    case NS_LIGHT_ENVIRONMENT:
        if (*environment_at != SIZE_MAX)
            report(p, "a second environment light; a scene has at most one (the first is /lights/%zu)",
                   *environment_at);
        else
            *environment_at = index;
        field_color(p, l, "radiance", 1, R_NONNEGATIVE, "radiance (W/(m^2 sr))", out->color);
        break;
    }
}

static void parse_lights(parser *p, const json_t *v)
{
    if (!expect_array(p, v, "lights"))
        return;
    size_t n = json_array_size(v);
    if (n > NS_MAX_LIGHTS) {
        report(p, "%zu lights is over the limit of %d", n, NS_MAX_LIGHTS);
        return;
    }
    p->lights = calloc(n ? n : 1, sizeof *p->lights);
    if (!p->lights) {
        p->oom = 1;
        return;
    }
    size_t environment_at = SIZE_MAX;
    for (size_t i = 0; i < n; i++) {
        size_t saved = push_index(p, i);
        parse_light(p, json_array_get(v, i), &p->lights[i], &environment_at, i);
        pop(p, saved);
    }
    p->light_count = (uint32_t)n;
}

/* =======================================================================================
 * Render settings
 * ===================================================================================== */

/* The names come from the render library's tables (nscatter.h); as_enum() takes them as an
 * array, indexed by ns_method and by component bit number, to list them in its messages. */
#define SCENE_X_NAME(code, value, name) [value] = name,
static const char *const component_names[NS_COMPONENT_COUNT] = {NS_COMPONENTS(SCENE_X_NAME)};
static const char *const method_names[NS_METHOD_COUNT] = {NS_METHODS(SCENE_X_NAME)};
#undef SCENE_X_NAME

/* Returns the component mask, 0 when the list is invalid (reported). */
static uint32_t parse_components(parser *p, const json_t *v)
{
    if (!expect_array(p, v, "components"))
        return 0;
    if (json_array_size(v) == 0) {
        report(p, "components must not be empty; list some of \"surface\", \"single\", \"double\", \"multiple\"");
        return 0;
    }
    uint32_t mask = 0;
    int ok = 1;
    size_t i;
    const json_t *c;
    json_array_foreach(v, i, c) {
        size_t saved = push_index(p, i);
        int index;
        if (as_enum(p, c, component_names, NS_COMPONENT_COUNT, "component", &index)) {
            if (mask & (1u << index)) {
                report(p, "component \"%s\" is listed twice", component_names[index]);
                ok = 0;
            }
            mask |= 1u << index;
        } else {
            ok = 0;
        }
        pop(p, saved);
    }
    return ok ? mask : 0;
}

/* A requested component the method cannot render is an error at its pointer, never
 * dropped: the picture would silently lack light the user asked for. Today that is the
 * dipole asked for double or multiple scattering alone (ns_unsupported_components). */
static void check_components_available(parser *p, const json_t *components, uint32_t mask)
{
    uint32_t missing = ns_unsupported_components(p->render.method, mask);
    if (!missing || !components)
        return;
    const char *method = ns_method_name(p->render.method);
    size_t saved = push_key(p, "components");
    size_t i;
    const json_t *c;
    json_array_foreach(components, i, c) {
        for (int bit = 0; bit < NS_COMPONENT_COUNT; bit++)
            if ((missing & (1u << bit)) && strcmp(json_string_value(c), component_names[bit]) == 0) {
                size_t inner = push_index(p, i);
                report(p, "component \"%s\" cannot be rendered alone with method \"%s\": its "
                          "diffusion profile holds double and multiple scattering together; ask "
                          "for both", component_names[bit], method);
                pop(p, inner);
            }
    }
    pop(p, saved);
}

static void parse_render(parser *p, const json_t *v)
{
    static const char *const keys[] = {"method", "components", "spp", "seed", "max_depth",
                                       "light_samples", "adaptive_spp", "exposure",
                                       "max_scatter", "vrls", "gather_tile", "gather_levels",
                                       "gather_tolerance", "gather_camera_samples", "single_samples",
                                       "single_levels", "single_tolerance", "deadline_ms",
                                       "accumulation", "tables", "vrl_beams", "boundary",
                                       "cull_solid_angle", NULL};
    static const char *const accumulation_names[] = {"exact", "paper"};
    static const char *const tables_names[] = {"exact", "interpolated", "auto"};
    static const char *const beam_names[] = {"endless", "bounded"};
    static const char *const boundary_names[] = {"off", "walks"};
    ns_render_settings *r = &p->render;
    /* An absent key is left 0, which the render library reads as its default (resolved at
     * the end). Not so for seed, gather_tolerance and single_tolerance: 0 is a value of their
     * own there, which the library keeps, so only the parser, which sees whether the key was
     * written, can give them their defaults. single_levels too: the library's 0 computes
     * every pixel, as renders built in C always did, and a scene file gets the adaptive
     * single scattering the bench measured (docs/bench.md, *Adaptive single scattering*);
     * gather_levels likewise (*The adaptive gather by default*), and gather_camera_samples
     * (*One camera sample per gathered pixel*); and tables, "auto" (docs/rendering.md,
     * *Interpolated tables*), where the library's 0 is exact. */
    *r = (ns_render_settings){.seed = NS_DEFAULT_SEED,
                              .gather_levels = NS_DEFAULT_GATHER_LEVELS,
                              .gather_tolerance = NS_DEFAULT_GATHER_TOLERANCE,
                              .gather_camera_samples = NS_DEFAULT_GATHER_CAMERA_SAMPLES,
                              .single_levels = NS_DEFAULT_SINGLE_LEVELS,
                              .single_tolerance = NS_DEFAULT_SINGLE_TOLERANCE,
                              .tables = NS_TABLES_AUTO};
    size_t saved = push_key(p, "render");
    if (v && !expect_object(p, v, "render")) {
        pop(p, saved);
        return;
    }
    int method_ok = 1, components_ok = 1, boundary_given = 0, adaptive_given = 0;
    const json_t *components = NULL;
    if (v) {
        check_keys(p, v, keys);
        int method;
        if (json_object_get(v, "method")) {
            method_ok = field_enum(p, v, "method", 1, method_names, NS_METHOD_COUNT,
                                   "render method", &method);
            if (method_ok)
                r->method = (ns_method)method;
        }
        components = json_object_get(v, "components");
        if (components) {
            size_t inner = push_key(p, "components");
            r->components = parse_components(p, components);
            components_ok = r->components != 0;
            pop(p, inner);
        }
        field_uint(p, v, "spp", 0, 1, limit(p->opts ? p->opts->max_spp : 0, NS_MAX_SPP),
                   "spp (samples per pixel)", &r->spp);
        field_uint(p, v, "seed", 0, 0, UINT32_MAX, "seed", &r->seed);
        field_uint(p, v, "max_depth", 0, 1, NS_MAX_DEPTH, "max_depth (bounces of a camera path)", &r->max_depth);
        field_uint(p, v, "light_samples", 0, 1, NS_MAX_LIGHT_SAMPLES,
                   "light_samples (shadow rays per light at a diffuse surface)", &r->light_samples);
        adaptive_given = json_object_get(v, "adaptive_spp") != NULL;
        field_float(p, v, "adaptive_spp", 0, R_ADAPTIVE_SPP,
                    "adaptive_spp (camera samples added per pixel, on average, where the "
                    "pixels spread)",
                    &r->adaptive_spp);
        field_float(p, v, "exposure", 0, R_EXPOSURE, "exposure (stops)", &r->exposure);
        p->vrls_given = json_object_get(v, "vrls") != NULL;
        field_uint(p, v, "vrls", 0, 1, limit(p->opts ? p->opts->max_vrls : 0, NS_MAX_VRLS),
                   "vrls (light paths traced towards the media)", &r->vrls);
        field_uint(p, v, "deadline_ms", 0, 1, NS_MAX_DEADLINE_MS,
                   "deadline_ms (milliseconds the render may take)", &r->deadline_ms);
        field_uint(p, v, "gather_tile", 0, 1, NS_MAX_GATHER_TILE,
                   "gather_tile (one gathered pixel per tile x tile block)", &r->gather_tile);
        field_uint(p, v, "gather_levels", 0, 0, NS_MAX_GATHER_LEVELS,
                   "gather_levels (coarser lattices of tiles; 0 = gather every tile)", &r->gather_levels);
        field_float(p, v, "gather_tolerance", 0, R_UNIT,
                    "gather_tolerance (relative spread that still interpolates)", &r->gather_tolerance);
        field_uint(p, v, "gather_camera_samples", 0, 0, NS_MAX_SPP,
                   "gather_camera_samples (camera samples a gathered pixel takes; 0 = all)",
                   &r->gather_camera_samples);
        field_uint(p, v, "single_samples", 0, 1, NS_MAX_SINGLE_SAMPLES,
                   "single_samples (samples per camera segment)", &r->single_samples);
        field_uint(p, v, "single_levels", 0, 0, NS_MAX_GATHER_LEVELS,
                   "single_levels (coarser lattices of pixels; 0 = every pixel)", &r->single_levels);
        field_float(p, v, "single_tolerance", 0, R_UNIT,
                    "single_tolerance (relative error that still interpolates)", &r->single_tolerance);
        int accumulation;
        if (json_object_get(v, "accumulation") &&
            field_enum(p, v, "accumulation", 0, accumulation_names, 2, "accumulation", &accumulation))
            r->accumulation = (ns_accumulation)accumulation;
        int tables;
        if (json_object_get(v, "tables") &&
            field_enum(p, v, "tables", 0, tables_names, 3, "tables", &tables)) {
            r->tables = (ns_tables_mode)tables;
            /* Only the networks' tables have nodes to blend (method table's Monte Carlo runs
             * per albedo): the key would be silently meaningless elsewhere. */
            if (r->tables == NS_TABLES_INTERPOLATED && method_ok && r->method != NS_METHOD_NN) {
                size_t inner = push_key(p, "tables");
                report(p, "tables \"interpolated\" applies to method \"nn\" only");
                pop(p, inner);
            }
        }
        int beams;
        if (json_object_get(v, "vrl_beams") &&
            field_enum(p, v, "vrl_beams", 0, beam_names, 2, "vrl_beams", &beams)) {
            r->vrl_beams = (ns_vrl_beams)beams;
            /* The other methods have no table VRLs: the key would be silently meaningless. */
            if (r->vrl_beams == NS_VRL_BEAMS_BOUNDED && method_ok && !ns_method_uses_tables(r->method)) {
                size_t inner = push_key(p, "vrl_beams");
                report(p, "vrl_beams \"bounded\" applies to methods \"nn\" and \"table\" only");
                pop(p, inner);
            }
        }
        int boundary;
        boundary_given = json_object_get(v, "boundary") != NULL;
        if (boundary_given &&
            field_enum(p, v, "boundary", 0, boundary_names, 2, "boundary", &boundary)) {
            r->boundary = (ns_boundary)boundary;
            /* Like vrl_beams: only the table methods gather through tables. */
            if (r->boundary != NS_BOUNDARY_OFF && method_ok && !ns_method_uses_tables(r->method)) {
                size_t inner = push_key(p, "boundary");
                report(p, "boundary \"walks\" applies to methods \"nn\" and \"table\" only");
                pop(p, inner);
            }
        }
        field_float(p, v, "cull_solid_angle", 0, R_SOLID_ANGLE,
                    "cull_solid_angle (sr; 0 = exact)", &r->cull_solid_angle);
        /* Only the path tracer can cut paths by their scattering events; the other methods
         * choose orders with "components", so the key would be silently meaningless there. */
        if (json_object_get(v, "max_scatter")) {
            if (method_ok && r->method != NS_METHOD_PT) {
                size_t inner = push_key(p, "max_scatter");
                report(p, "max_scatter applies to method \"pt\" only (other methods select "
                          "scattering orders with \"components\")");
                pop(p, inner);
            } else {
                field_uint(p, v, "max_scatter", 0, 0, NS_MAX_SCATTER,
                           "max_scatter (scattering events per path, 0 = no limit)", &r->max_scatter);
            }
        }
    }
    /* The boundary correction is the default where it applies: the bench shows every
     * scene's nn image closer to pt with it (docs/scattering.md, "The object's boundary").
     * The library keeps 0 = off, so renders built in C stay as they were; only the parser
     * sees that the key was not written (as for gather_tolerance). */
    if (!boundary_given && method_ok)
        r->boundary = ns_default_boundary(r->method);
    /* Added camera samples by default where there is a spread to place them by (spp >= 2;
     * docs/bench.md, *Adaptive camera samples*); the library's 0 adds none, as renders built
     * in C always did, and pt, which ignores it, reports none. Asked for at one sample per
     * pixel they could go nowhere: refused. */
    uint32_t spp = r->spp ? r->spp : NS_DEFAULT_SPP;
    if (!adaptive_given && method_ok && ns_adaptive_spp_applies(r->method, spp))
        r->adaptive_spp = NS_DEFAULT_ADAPTIVE_SPP;
    if (adaptive_given && method_ok && ns_adaptive_spp_refused(r->method, spp, r->adaptive_spp)) {
        size_t inner = push_key(p, "adaptive_spp");
        report(p, "adaptive_spp needs spp >= 2: the added samples go where a pixel's "
                  "neighbours' first samples spread");
        pop(p, inner);
    }
    /* The settings leave the parser resolved, as ns_render will render them: what the scene
     * reports (image metadata, --timings) is then the effective spp, max_depth and
     * components, not a 0 standing for them. */
    *r = ns_render_settings_resolve(*r);
    if (method_ok && components_ok)
        check_components_available(p, components, r->components);
    pop(p, saved);
}

/* A medium that the method cannot render (outside the network's domain, for "nn") is an
 * error at the material, before anything renders, when an object uses it and the scattering
 * components that need its tables are asked for. */
static void check_media_for_method(parser *p)
{
    ns_render_settings resolved = ns_render_settings_resolve(p->render);
    uint32_t max_vrls = limit(p->opts ? p->opts->max_vrls : 0, NS_MAX_VRLS);
    if (resolved.vrls > max_vrls && !p->vrls_given &&
        (resolved.components & (NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE)) &&
        resolved.method != NS_METHOD_PT) {
        size_t saved = push_key(p, "render");
        report_at(p, "vrls", "the default of %u VRLs is over the limit of %u; set render.vrls",
                  resolved.vrls, max_vrls);
        pop(p, saved);
    }
    uint32_t components = resolved.components;
    if (!p->materials_known ||
        !(components & (NS_COMPONENT_SINGLE | NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE)))
        return;
    for (uint32_t i = 0; i < p->material_count; i++) {
        int used = 0;
        for (uint32_t o = 0; o < p->object_count && !used; o++)
            used = p->objects[o].material == i;
        const char *field = NULL;
        ns_error err = {0};
        if (!used || !ns_material_supported(p->render.method, &p->materials[i], &field, &err))
            continue;
        size_t saved = push_key(p, "materials");
        push_key(p, p->materials[i].name);
        push_key(p, field ? field : "");
        report(p, "%s", err.message);
        pop(p, saved);
    }
}


/* =======================================================================================
 * Where jansson stopped: the JSON pointer at a byte offset
 *
 * jansson reports duplicate keys and numeric overflow by line and column only. To name the
 * field as a pointer, the text up to that offset is scanned again, tracking the open
 * containers and the key or index inside each.
 * ===================================================================================== */

typedef struct scan_frame {
    int is_array;
    int expect_key;   /* object: the next string is a key */
    size_t index;     /* array: element being read */
    size_t key_start; /* object: the last key, raw bytes between its quotes */
    size_t key_len;
    int have_key;
} scan_frame;

#define SCAN_MAX_DEPTH 64

static void pointer_at_offset(const char *text, size_t len, size_t pos, char *out, size_t cap, char *last_key,
                              size_t last_cap)
{
    scan_frame frames[SCAN_MAX_DEPTH];
    size_t depth = 0; /* may exceed SCAN_MAX_DEPTH; deeper frames are not tracked */
    if (pos > len)
        pos = len;
    for (size_t i = 0; i < pos; i++) {
        char c = text[i];
        scan_frame *top = depth && depth <= SCAN_MAX_DEPTH ? &frames[depth - 1] : NULL;
        if (c == '{' || c == '[') {
            if (depth < SCAN_MAX_DEPTH)
                frames[depth] = (scan_frame){.is_array = c == '[', .expect_key = c == '{'};
            depth++;
        } else if (c == '}' || c == ']') {
            if (depth)
                depth--;
        } else if (c == ',' && top) {
            if (top->is_array)
                top->index++;
            else
                top->expect_key = 1;
        } else if (c == '"') {
            size_t start = ++i;
            while (i < len && text[i] != '"')
                i += text[i] == '\\' ? 2 : 1;
            if (top && !top->is_array && top->expect_key) {
                top->key_start = start;
                top->key_len = (i < len ? i : len) - start;
                top->have_key = 1;
                top->expect_key = 0;
            }
        }
    }
    /* Build the pointer through a scratch parser so keys are escaped the same way. */
    parser scratch = {0};
    last_key[0] = '\0';
    for (size_t d = 0; d < depth && d < SCAN_MAX_DEPTH; d++) {
        if (frames[d].is_array) {
            push_index(&scratch, frames[d].index);
        } else if (frames[d].have_key) {
            char key[256];
            size_t n = 0;
            for (size_t k = 0; k < frames[d].key_len && n < sizeof key - 1; k++) {
                char ch = text[frames[d].key_start + k];
                if (ch == '\\' && k + 1 < frames[d].key_len)
                    ch = text[frames[d].key_start + ++k];
                key[n++] = ch;
            }
            key[n] = '\0';
            push_key(&scratch, key);
            copy_cut(last_key, last_cap, key);
        } else {
            break;
        }
    }
    copy_cut(out, cap, scratch.ptr);
}

static void report_load_error(const char *json, size_t length, const json_error_t *e, scene_issues *issues)
{
    char detail[512], pointer[256], key[96];
    issues->line = e->line > 0 ? e->line : 1;
    issues->column = e->column > 0 ? e->column : 1;
    switch (json_error_code(e)) {
    case json_error_duplicate_key:
    case json_error_numeric_overflow:
        /* Valid JSON grammar, invalid scene: name the field (422). */
        pointer_at_offset(json, length, (size_t)(e->position > 0 ? e->position : 0), pointer, sizeof pointer, key,
                          sizeof key);
        if (json_error_code(e) == json_error_duplicate_key)
            snprintf(detail, sizeof detail, "key \"%s\" is given twice (line %d, column %d); each key may appear once",
                     key, issues->line, issues->column);
        else
            snprintf(detail, sizeof detail, "%s (line %d, column %d); numbers must fit a 32-bit float", e->text,
                     issues->line, issues->column);
        add_issue(issues, pointer, detail);
        break;
    case json_error_stack_overflow:
        snprintf(detail, sizeof detail, "JSON nested too deeply (line %d, column %d): %s", issues->line,
                 issues->column, e->text);
        add_issue(issues, "", detail);
        break;
    default:
        issues->syntax_error = 1;
        snprintf(detail, sizeof detail, "JSON syntax error at line %d, column %d: %s", issues->line,
                 issues->column, e->text);
        add_issue(issues, "", detail);
        break;
    }
}

void scene_json_load_error(const char *json, size_t length, const void *e, scene_issues *issues)
{
    memset(issues, 0, sizeof *issues);
    report_load_error(json ? json : "", length, e, issues);
}

/* =======================================================================================
 * Entry points
 * ===================================================================================== */

static void parse_root(parser *p, const json_t *root)
{
    static const char *const keys[] = {"version", "camera", "materials", "objects", "lights", "render", NULL};
    if (!json_is_object(root)) {
        report(p, "the scene must be a JSON object, got %s", json_kind(root));
        return;
    }
    check_keys(p, root, keys);
    uint32_t version;
    if (json_object_get(root, "version"))
        field_uint(p, root, "version", 1, 1, 1, "version (only 1 exists)", &version);

    const json_t *v;
    if ((v = field(p, root, "camera", 1, "position, look_at, up, fov, width, height"))) {
        size_t saved = push_key(p, "camera");
        parse_camera(p, v);
        pop(p, saved);
    }
    if ((v = field(p, root, "materials", 1, "an object keyed by material name"))) {
        size_t saved = push_key(p, "materials");
        parse_materials(p, v);
        pop(p, saved);
    }
    if (!p->oom && (v = field(p, root, "objects", 1, "an array of shapes"))) {
        size_t saved = push_key(p, "objects");
        parse_objects(p, v);
        pop(p, saved);
    }
    if (!p->oom && (v = field(p, root, "lights", 1, "an array of lights"))) {
        size_t saved = push_key(p, "lights");
        parse_lights(p, v);
        pop(p, saved);
    }
    parse_render(p, json_object_get(root, "render"));
    check_media_for_method(p);
}

static void free_parser_arrays(parser *p)
{
    free(p->materials);
    free(p->objects);
    free(p->triangles);
    free(p->lights);
}

int scene_parse(const char *json, size_t length, const scene_parse_options *opts, scene_doc **out,
                scene_issues *issues)
{
    scene_issues local;
    if (!issues)
        issues = &local;
    memset(issues, 0, sizeof *issues);
    if (!out)
        return NS_ERR_INVALID_ARGUMENT;
    *out = NULL;
    if (!json && length) {
        add_issue(issues, "", "no scene text");
        return NS_ERR_INVALID_ARGUMENT;
    }

    json_error_t error;
    /* Integers are read as reals so that any out-of-range integer gets this parser's
     * message naming the allowed range, not a generic overflow. */
    json_t *root = json_loadb(json ? json : "", length, JSON_REJECT_DUPLICATES | JSON_DECODE_INT_AS_REAL, &error);
    if (!root) {
        if (json_error_code(&error) == json_error_out_of_memory)
            return NS_ERR_OUT_OF_HOST_MEMORY;
        report_load_error(json ? json : "", length, &error, issues);
        return NS_ERR_INVALID_ARGUMENT;
    }

    parser p = {.issues = issues, .opts = opts};
    parse_root(&p, root);
    json_decref(root);
    if (p.oom) {
        free_parser_arrays(&p);
        return NS_ERR_OUT_OF_HOST_MEMORY;
    }
    if (issues->total) {
        free_parser_arrays(&p);
        return NS_ERR_INVALID_ARGUMENT;
    }
    scene_doc *doc = calloc(1, sizeof *doc);
    if (!doc) {
        free_parser_arrays(&p);
        return NS_ERR_OUT_OF_HOST_MEMORY;
    }
    doc->materials = p.materials;
    doc->objects = p.objects;
    doc->triangles = p.triangles;
    doc->lights = p.lights;
    doc->scene = (ns_scene){
        .camera = p.camera,
        .materials = p.materials,
        .material_count = p.material_count,
        .objects = p.objects,
        .object_count = p.object_count,
        .triangles = p.triangles,
        .triangle_count = p.triangle_count,
        .lights = p.lights,
        .light_count = p.light_count,
        .render = p.render,
    };
    *out = doc;
    return 0;
}

const ns_scene *scene_doc_scene(const scene_doc *doc)
{
    return doc ? &doc->scene : NULL;
}

void scene_doc_free(scene_doc *doc)
{
    if (!doc)
        return;
    free(doc->materials);
    free(doc->objects);
    free(doc->triangles);
    free(doc->lights);
    free(doc);
}
