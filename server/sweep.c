/* sweep.c — a sweep's variants: parsed, checked, ordered, and made into scenes (sweep.h). */
#include "sweep.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "problem.h"

#define SWEEP_MAX_ERRORS 32u

struct sweep {
    json_t *scene;    /* the base scene */
    json_t *variants; /* array of {"/pointer": value} */
    int grid;         /* given as a grid: where an override sits in the body differs */
    json_t *grid_pointers; /* grid: the pointers in body order (array of strings) */
    json_t *grid_values;   /* grid: the body's grid object */
    uint32_t *order;
    uint64_t pixels; /* over every variant's image */
    scene_parse_options opts;
    char *asset_dir;
};

void sweep_free(sweep *sw)
{
    if (!sw)
        return;
    json_decref(sw->scene);
    json_decref(sw->variants);
    json_decref(sw->grid_pointers);
    json_decref(sw->grid_values);
    free(sw->order);
    free(sw->asset_dir);
    free(sw);
}

uint32_t sweep_variant_count(const sweep *sw)
{
    return sw ? (uint32_t)json_array_size(sw->variants) : 0;
}

const json_t *sweep_overrides(const sweep *sw, uint32_t i)
{
    return json_array_get(sw->variants, i);
}

uint64_t sweep_pixels(const sweep *sw)
{
    return sw->pixels;
}

const uint32_t *sweep_order(const sweep *sw)
{
    return sw->order;
}

/* ---------------------------------------------------------------------------------------
 * JSON pointers (RFC 6901).
 * ------------------------------------------------------------------------------------- */
/* Appends `token` to `out` as one escaped reference token ("/" + token, ~ and / escaped). */
static void pointer_append(char *out, size_t cap, const char *token)
{
    size_t n = strlen(out);
    if (n + 1 < cap)
        out[n++] = '/';
    for (; *token && n + 2 < cap; token++) {
        if (*token == '~' || *token == '/') {
            out[n++] = '~';
            out[n++] = *token == '~' ? '0' : '1';
        } else {
            out[n++] = *token;
        }
    }
    out[n < cap ? n : cap - 1] = 0;
}

/* Sets a copy of `value` at `pointer` in `doc`: the parent must exist; an object's key is
 * replaced or added, an array's element replaced (or appended at its size or "-"). A copy,
 * because a later override may point inside this one: it must change the variant's scene,
 * never the override kept for the manifest and the labels. Returns 0, or -1 with `why`
 * filled. */
static int pointer_set(json_t *doc, const char *pointer, json_t *value, char *why, size_t cap)
{
    if (pointer[0] != '/') {
        snprintf(why, cap, "a JSON pointer starts with '/' and names a part of the scene");
        return -1;
    }
    json_t *node = doc;
    const char *p = pointer + 1;
    for (;;) {
        const char *slash = strchr(p, '/');
        size_t len = slash ? (size_t)(slash - p) : strlen(p);
        char token[256];
        size_t t = 0;
        if (len >= sizeof token) {
            snprintf(why, cap, "a key of more than %zu characters", sizeof token - 1);
            return -1;
        }
        for (size_t i = 0; i < len && t + 1 < sizeof token; i++) {
            if (p[i] == '~' && i + 1 < len && (p[i + 1] == '0' || p[i + 1] == '1')) {
                token[t++] = p[i + 1] == '0' ? '~' : '/';
                i++;
            } else if (p[i] == '~') {
                snprintf(why, cap, "'~' must be followed by 0 or 1 in a JSON pointer");
                return -1;
            } else {
                token[t++] = p[i];
            }
        }
        token[t] = 0;
        int last = slash == NULL;
        if (json_is_object(node)) {
            if (last)
                return json_object_set_new(node, token, json_deep_copy(value))
                           ? (snprintf(why, cap, "out of memory"), -1)
                           : 0;
            json_t *next = json_object_get(node, token);
            if (!next) {
                snprintf(why, cap, "the scene has no '%s' here, so nothing under it can be set",
                         token);
                return -1;
            }
            node = next;
        } else if (json_is_array(node)) {
            size_t size = json_array_size(node);
            int dash = !strcmp(token, "-");
            unsigned long index = dash ? size : strtoul(token, NULL, 10);
            /* RFC 6901: "0", or digits without a leading zero; nothing else (no sign). */
            if (!dash && (!token[0] || strspn(token, "0123456789") != strlen(token) ||
                          (token[0] == '0' && token[1]) || strlen(token) > 9)) {
                snprintf(why, cap, "'%s' is not an array index", token);
                return -1;
            }
            if (index > size || (!last && index == size)) {
                snprintf(why, cap, "index %lu is past the end of an array of %zu", index, size);
                return -1;
            }
            if (last)
                return (index == size ? json_array_append_new(node, json_deep_copy(value))
                                      : json_array_set_new(node, index, json_deep_copy(value)))
                           ? (snprintf(why, cap, "out of memory"), -1)
                           : 0;
            node = json_array_get(node, index);
        } else {
            snprintf(why, cap, "the scene holds a %s before '%s', not an object or an array",
                     json_is_string(node) ? "string" : json_is_number(node) ? "number" : "value",
                     token);
            return -1;
        }
        p = slash + 1;
    }
}

/* ---------------------------------------------------------------------------------------
 * Variants: made, checked, keyed by their tables.
 * ------------------------------------------------------------------------------------- */
/* Where override `pointer` of variant i sits in the request body: in the variants list, or
 * for a grid the value of that pointer's list that variant i took (first pointer slowest). */
static void body_pointer(const sweep *sw, uint32_t i, const char *pointer, char *out, size_t cap)
{
    if (!sw->grid) {
        snprintf(out, cap, "/variants/%u", i);
        pointer_append(out, cap, pointer);
        return;
    }
    size_t rest = i, index = 0;
    for (size_t k = json_array_size(sw->grid_pointers); k-- > 0;) {
        const char *name = json_string_value(json_array_get(sw->grid_pointers, k));
        size_t n = json_array_size(json_object_get(sw->grid_values, name));
        if (!strcmp(name, pointer))
            index = rest % n;
        rest /= n;
    }
    snprintf(out, cap, "/grid");
    pointer_append(out, cap, pointer);
    size_t len = strlen(out);
    snprintf(out + len, cap - len, "/%zu", index);
}

/* Variant i's scene: the base with its overrides set, parsed. Returns 0 and *out; or
 * NS_ERR_INVALID_ARGUMENT with *failed the override that could not be set (and why), or with
 * *failed NULL and the parser's issues; or NS_ERR_OUT_OF_HOST_MEMORY. */
static int parse_variant(const sweep *sw, uint32_t i, scene_doc **out, scene_issues *issues,
                         char *why, size_t cap, const char **failed)
{
    *out = NULL;
    *failed = NULL;
    json_t *doc = json_deep_copy(sw->scene);
    if (!doc)
        return NS_ERR_OUT_OF_HOST_MEMORY;
    const char *pointer;
    json_t *value;
    json_object_foreach((json_t *)sweep_overrides(sw, i), pointer, value)
    {
        if (pointer_set(doc, pointer, value, why, cap)) {
            json_decref(doc);
            if (!strcmp(why, "out of memory"))
                return NS_ERR_OUT_OF_HOST_MEMORY;
            *failed = pointer;
            return NS_ERR_INVALID_ARGUMENT;
        }
    }
    char *text = json_dumps(doc, JSON_COMPACT | JSON_REAL_PRECISION(17));
    json_decref(doc);
    if (!text)
        return NS_ERR_OUT_OF_HOST_MEMORY;
    int rc = scene_parse(text, strlen(text), &sw->opts, out, issues);
    free(text);
    return rc;
}

int sweep_variant_scene(const sweep *sw, uint32_t i, scene_doc **out, ns_error *err)
{
    char why[256];
    const char *failed = NULL;
    scene_issues *issues = calloc(1, sizeof *issues);
    int rc = issues ? parse_variant(sw, i, out, issues, why, sizeof why, &failed)
                    : NS_ERR_OUT_OF_HOST_MEMORY;
    if (rc == NS_ERR_OUT_OF_HOST_MEMORY)
        ns_fail(err, rc, "variant %u: out of memory", i);
    else if (rc && failed)
        ns_fail(err, rc, "variant %u: %s: %s", i, failed, why);
    else if (rc)
        ns_fail(err, rc, "variant %u: %s: %s", i, issues->count ? issues->items[0].pointer : "",
                issues->count ? issues->items[0].detail : ns_status_message(rc));
    free(issues);
    return rc;
}

/* The tables a scene needs depend on g and the single-scattering albedo of each medium
 * (DESIGN.md: tables are in mean-free-path units, so mfp, scale and ior do not enter). */
static void table_key(const ns_scene *scene, char *out, size_t cap)
{
    size_t n = 0;
    out[0] = 0;
    for (uint32_t m = 0; m < scene->material_count && n + 1 < cap; m++) {
        const ns_material *mat = &scene->materials[m];
        if (mat->type != NS_MATERIAL_MEDIUM)
            continue;
        float albedo[3];
        for (int c = 0; c < 3; c++) {
            float t = mat->sigma_s[c] + mat->sigma_a[c];
            albedo[c] = t > 0 ? mat->sigma_s[c] / t : 0;
        }
        int w = snprintf(out + n, cap - n, "%.9g,%.9g,%.9g,%.9g;", (double)mat->g,
                         (double)albedo[0], (double)albedo[1], (double)albedo[2]);
        n += w > 0 ? (size_t)w : 0;
    }
}

/* Adds one error to the problem unless the same one is there already (a fault of the base
 * scene shows in every variant: reported once). */
static void add_error(json_t *problem, const char *pointer, const char *detail)
{
    json_t *errors = json_object_get(problem, "errors");
    size_t k;
    json_t *e;
    json_array_foreach(errors, k, e)
    {
        if (!strcmp(json_string_value(json_object_get(e, "pointer")), pointer))
            return;
    }
    if (json_array_size(errors) < SWEEP_MAX_ERRORS)
        problem_add_error(problem, pointer, detail);
}

/* Checks variant i; on failure adds its errors to *problem (made on first use). Fills key. */
static int check_variant(sweep *sw, uint32_t i, json_t **problem, char *key, size_t key_cap)
{
    char why[512], at[512];
    const char *failed = NULL;
    scene_issues *issues = calloc(1, sizeof *issues);
    scene_doc *parsed = NULL;
    int rc = issues ? parse_variant(sw, i, &parsed, issues, why, sizeof why, &failed)
                    : NS_ERR_OUT_OF_HOST_MEMORY;
    if (rc == 0) {
        const ns_scene *scene = scene_doc_scene(parsed);
        table_key(scene, key, key_cap);
        sw->pixels += (uint64_t)scene->camera.width * scene->camera.height;
        scene_doc_free(parsed);
        free(issues);
        return NS_OK;
    }
    if (rc == NS_ERR_OUT_OF_HOST_MEMORY) {
        free(issues);
        return rc;
    }
    if (!*problem)
        *problem = problem_new(PROBLEM_INVALID_SWEEP, "");
    if (failed) {
        body_pointer(sw, i, failed, at, sizeof at);
        char detail[900];
        snprintf(detail, sizeof detail, "variant %u: %s: %s", i, failed, why);
        add_error(*problem, at, detail);
        free(issues);
        return NS_ERR_INVALID_ARGUMENT;
    }
    for (uint32_t k = 0; rc == NS_ERR_INVALID_ARGUMENT && k < issues->count; k++) {
        const scene_issue *is = &issues->items[k];
        /* The issue is in an override (or under one): point at the override in the body;
         * else it is in the base scene. */
        const char *pointer;
        json_t *value;
        const char *owner = NULL;
        json_object_foreach((json_t *)sweep_overrides(sw, i), pointer, value)
        {
            size_t n = strlen(pointer);
            if (!strncmp(is->pointer, pointer, n) && (is->pointer[n] == 0 || is->pointer[n] == '/'))
                owner = pointer;
        }
        char detail[900];
        if (owner) {
            body_pointer(sw, i, owner, at, sizeof at);
            strncat(at, is->pointer + strlen(owner), sizeof at - strlen(at) - 1);
            snprintf(detail, sizeof detail, "variant %u: %s: %s", i, is->pointer, is->detail);
        } else {
            snprintf(at, sizeof at, "/scene%s", is->pointer);
            snprintf(detail, sizeof detail, "variant %u: %s: %s (in the base scene)", i,
                     is->pointer, is->detail);
        }
        add_error(*problem, at, detail);
    }
    free(issues);
    return rc;
}

/* ---------------------------------------------------------------------------------------
 * The request body.
 * ------------------------------------------------------------------------------------- */
static json_t *sweep_problem(problem_kind kind, const char *pointer, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static json_t *sweep_problem(problem_kind kind, const char *pointer, const char *fmt, ...)
{
    char detail[600];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(detail, sizeof detail, fmt, ap);
    va_end(ap);
    json_t *p = problem_new(kind, detail);
    if (p && pointer)
        problem_add_error(p, pointer, detail);
    return p;
}

/* Expands {"/a": [..], "/b": [..]} into the variants, first pointer slowest. */
static json_t *expand_grid(json_t *grid, json_t *pointers, json_t **problem)
{
    size_t total = 1;
    const char *pointer;
    json_t *values;
    json_object_foreach(grid, pointer, values)
    {
        char at[300] = "/grid";
        pointer_append(at, sizeof at, pointer);
        if (!json_is_array(values) || json_array_size(values) == 0) {
            *problem = sweep_problem(PROBLEM_INVALID_SWEEP, at,
                                     "%s: a grid entry is a non-empty list of values", at);
            return NULL;
        }
        total *= json_array_size(values);
        if (total > SWEEP_MAX_VARIANTS) {
            *problem = sweep_problem(PROBLEM_INVALID_SWEEP, "/grid",
                                     "/grid: more than %u variants (the limit of a sweep)",
                                     SWEEP_MAX_VARIANTS);
            return NULL;
        }
        json_array_append_new(pointers, json_string(pointer));
    }
    if (json_array_size(pointers) == 0) {
        *problem = sweep_problem(PROBLEM_INVALID_SWEEP, "/grid", "/grid: no pointer to vary");
        return NULL;
    }
    json_t *variants = json_array();
    for (size_t v = 0; variants && v < total; v++) {
        json_t *o = json_object();
        size_t rest = v;
        /* The last pointer varies fastest. */
        for (size_t k = json_array_size(pointers); k-- > 0;) {
            const char *name = json_string_value(json_array_get(pointers, k));
            json_t *list = json_object_get(grid, name);
            size_t n = json_array_size(list);
            json_object_set(o, name, json_array_get(list, rest % n));
            rest /= n;
        }
        /* Keep the body's order of pointers in each variant's overrides. */
        json_t *ordered = json_object();
        for (size_t k = 0; k < json_array_size(pointers); k++) {
            const char *name = json_string_value(json_array_get(pointers, k));
            json_object_set(ordered, name, json_object_get(o, name));
        }
        json_decref(o);
        json_array_append_new(variants, ordered);
    }
    return variants;
}

int sweep_parse(const char *body, size_t size, const scene_parse_options *opts, sweep **out,
                json_t **problem)
{
    *out = NULL;
    *problem = NULL;
    json_error_t jerr;
    json_t *root = json_loadb(body ? body : "", size, JSON_REJECT_DUPLICATES, &jerr);
    if (!root) {
        if (json_error_code(&jerr) == json_error_out_of_memory) {
            *problem = problem_from_status(PROBLEM_STATUS_UNAVAILABLE, NS_ERR_OUT_OF_HOST_MEMORY,
                                           "out of memory");
            return NS_ERR_OUT_OF_HOST_MEMORY;
        }
        /* As a scene's: a duplicate key, a number that overflows or nesting too deep is an
         * invalid sweep at the field's pointer (422), anything else a syntax error (400). */
        scene_issues *issues = calloc(1, sizeof *issues);
        if (issues)
            scene_json_load_error(body ? body : "", size, &jerr, issues);
        if (issues && !issues->syntax_error && issues->count) {
            *problem = sweep_problem(PROBLEM_INVALID_SWEEP, issues->items[0].pointer, "%s%s%s",
                                     issues->items[0].pointer,
                                     issues->items[0].pointer[0] ? ": " : "",
                                     issues->items[0].detail);
        } else {
            *problem = sweep_problem(PROBLEM_MALFORMED_JSON, "",
                                     "JSON syntax error at line %d, column %d: %s", jerr.line,
                                     jerr.column, jerr.text);
            if (*problem) {
                json_object_set_new(*problem, "line", json_integer(jerr.line));
                json_object_set_new(*problem, "column", json_integer(jerr.column));
            }
        }
        free(issues);
        return NS_ERR_INVALID_ARGUMENT;
    }
    sweep *sw = calloc(1, sizeof *sw);
    if (!sw) {
        json_decref(root);
        *problem = problem_from_status(PROBLEM_STATUS_UNAVAILABLE, NS_ERR_OUT_OF_HOST_MEMORY,
                                       "out of memory");
        return NS_ERR_OUT_OF_HOST_MEMORY;
    }
    if (opts) {
        sw->opts = *opts; /* the service's limits too */
        sw->opts.asset_dir = NULL;
    }
    if (opts && opts->asset_dir) {
        sw->asset_dir = strdup(opts->asset_dir);
        sw->opts.asset_dir = sw->asset_dir;
    }
    int rc = NS_ERR_INVALID_ARGUMENT;
    if (!json_is_object(root)) {
        *problem = sweep_problem(PROBLEM_INVALID_SWEEP, "",
                                 "a sweep is an object: {\"scene\": {...}, \"variants\": [...]} or "
                                 "{\"scene\": {...}, \"grid\": {...}}");
        goto done;
    }
    const char *key;
    json_t *value;
    json_object_foreach(root, key, value)
    {
        if (strcmp(key, "scene") && strcmp(key, "variants") && strcmp(key, "grid")) {
            char at[300] = "";
            pointer_append(at, sizeof at, key);
            *problem = sweep_problem(PROBLEM_INVALID_SWEEP, at,
                                     "unknown key '%.200s' (a sweep has scene, and variants or grid)",
                                     key);
            goto done;
        }
    }
    json_t *scene = json_object_get(root, "scene");
    json_t *variants = json_object_get(root, "variants");
    json_t *grid = json_object_get(root, "grid");
    if (!json_is_object(scene)) {
        *problem = sweep_problem(PROBLEM_INVALID_SWEEP, "/scene",
                                 "/scene: the base scene (an object) is required");
        goto done;
    }
    if (!variants == !grid) {
        *problem = sweep_problem(PROBLEM_INVALID_SWEEP, "",
                                 "give exactly one of \"variants\" (a list) and \"grid\" (an object)");
        goto done;
    }
    sw->scene = json_incref(scene);
    if (variants) {
        if (!json_is_array(variants) || json_array_size(variants) == 0) {
            *problem = sweep_problem(PROBLEM_INVALID_SWEEP, "/variants",
                                     "/variants: a non-empty list of {\"/pointer\": value} objects");
            goto done;
        }
        if (json_array_size(variants) > SWEEP_MAX_VARIANTS) {
            *problem = sweep_problem(PROBLEM_INVALID_SWEEP, "/variants",
                                     "/variants: %zu variants, more than the limit of %u",
                                     json_array_size(variants), SWEEP_MAX_VARIANTS);
            goto done;
        }
        size_t i;
        json_t *v;
        json_array_foreach(variants, i, v)
        {
            if (!json_is_object(v)) {
                char at[32];
                snprintf(at, sizeof at, "/variants/%zu", i);
                *problem = sweep_problem(PROBLEM_INVALID_SWEEP, at,
                                         "%s: a variant is an object {\"/pointer\": value, ...}", at);
                goto done;
            }
        }
        sw->variants = json_incref(variants);
    } else {
        if (!json_is_object(grid)) {
            *problem = sweep_problem(PROBLEM_INVALID_SWEEP, "/grid",
                                     "/grid: an object {\"/pointer\": [values...], ...}");
            goto done;
        }
        sw->grid = 1;
        sw->grid_pointers = json_array();
        sw->variants = expand_grid(grid, sw->grid_pointers, problem);
        if (!sw->variants) {
            if (!*problem)
                rc = NS_ERR_OUT_OF_HOST_MEMORY;
            goto done;
        }
        sw->grid_values = json_incref(grid);
    }
    uint32_t n = sweep_variant_count(sw);
    sw->order = calloc(n, sizeof *sw->order);
    char (*keys)[512] = calloc(n, sizeof *keys);
    if (!sw->order || !keys) {
        free(keys);
        rc = NS_ERR_OUT_OF_HOST_MEMORY;
        goto done;
    }
    int invalid = 0;
    for (uint32_t i = 0; i < n; i++) {
        int status = check_variant(sw, i, problem, keys[i], sizeof keys[i]);
        if (status == NS_ERR_OUT_OF_HOST_MEMORY) {
            free(keys);
            json_decref(*problem); /* an answer about memory, not about the variants */
            *problem = NULL;
            rc = status;
            goto done;
        }
        invalid |= status != 0;
    }
    if (invalid) {
        size_t count = json_array_size(json_object_get(*problem, "errors"));
        const char *first = json_string_value(
            json_object_get(json_array_get(json_object_get(*problem, "errors"), 0), "detail"));
        char detail[800];
        snprintf(detail, sizeof detail, "the sweep has %zu problem%s; first: %s", count,
                 count == 1 ? "" : "s", first ? first : "");
        json_object_set_new(*problem, "detail", json_string(detail));
        free(keys);
        goto done;
    }
    json_decref(*problem);
    *problem = NULL;
    /* Grouped by table key, groups in order of first appearance, request order within. */
    uint32_t placed = 0;
    unsigned char *taken = calloc(n, 1);
    for (uint32_t i = 0; taken && i < n; i++) {
        if (taken[i])
            continue;
        for (uint32_t k = i; k < n; k++)
            if (!taken[k] && !strcmp(keys[k], keys[i])) {
                taken[k] = 1;
                sw->order[placed++] = k;
            }
    }
    free(taken);
    free(keys);
    if (placed != n) {
        rc = NS_ERR_OUT_OF_HOST_MEMORY;
        goto done;
    }
    rc = NS_OK;
done:
    json_decref(root);
    if (rc) {
        if (!*problem)
            *problem = problem_from_status(PROBLEM_STATUS_UNAVAILABLE, NS_ERR_OUT_OF_HOST_MEMORY,
                                           "out of memory");
        sweep_free(sw);
        return rc;
    }
    *out = sw;
    return NS_OK;
}

uint32_t sweep_label_lines(const sweep *sw, uint32_t i, char (*lines)[96], uint32_t max)
{
    const json_t *overrides = sweep_overrides(sw, i);
    uint32_t count = 0;
    const char *pointer;
    json_t *value;
    json_object_foreach((json_t *)overrides, pointer, value)
    {
        if (count == max)
            break;
        /* The last token names the parameter ("g"); the whole pointer when two overrides
         * end alike. */
        const char *name = strrchr(pointer, '/') ? strrchr(pointer, '/') + 1 : pointer;
        const char *other;
        json_t *unused;
        json_object_foreach((json_t *)overrides, other, unused)
        {
            const char *other_name = strrchr(other, '/') ? strrchr(other, '/') + 1 : other;
            if (other != pointer && strcmp(other, pointer) && !strcmp(other_name, name))
                name = pointer;
        }
        char *text = json_dumps(value, JSON_COMPACT | JSON_ENCODE_ANY | JSON_REAL_PRECISION(4));
        snprintf(lines[count++], 96, "%s=%s", name, text ? text : "?");
        free(text);
    }
    return count;
}
