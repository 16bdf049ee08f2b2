/* unit_sweep.c — sweeps (server/sweep.h): the variants of a list and of a grid (first
 * pointer slowest), overrides applied as JSON Patch "add", every variant validated before
 * anything renders with errors that point into the request body, the render order grouped
 * by scattering-table key, and the limits. tests/http_sweeps.py checks the same on the wire. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "harness.h"
#include "sweep.h"

/* A small valid scene with one medium "wax" (g 0 unless overridden). */
#define SCENE                                                                                  \
    "{\"version\": 1,"                                                                         \
    " \"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0],"       \
    "  \"fov\": 40, \"width\": 16, \"height\": 16},"                                           \
    " \"materials\": {\"wax\": {\"type\": \"medium\", \"albedo\": [0.9, 0.9, 0.9],"            \
    "  \"mfp\": [0.1, 0.1, 0.1], \"g\": 0, \"ior\": 1}},"                                      \
    " \"objects\": [{\"shape\": \"sphere\", \"center\": [0, 0, 0], \"radius\": 1,"             \
    "  \"material\": \"wax\"}],"                                                               \
    " \"lights\": [{\"type\": \"directional\", \"direction\": [0, -1, 0],"                     \
    "  \"irradiance\": [1, 1, 1]}]}"

typedef struct parsed {
    sweep *sw;
    json_t *problem;
    int rc;
} parsed;

static parsed parse(const char *body)
{
    parsed p = {0};
    p.rc = sweep_parse(body, strlen(body), NULL, &p.sw, &p.problem);
    return p;
}

static void done(parsed *p)
{
    sweep_free(p->sw);
    json_decref(p->problem);
}

/* errors[i].pointer of a problem, "" when absent. */
static const char *error_pointer(const json_t *problem, size_t i)
{
    const json_t *e = json_array_get(json_object_get(problem, "errors"), i);
    const char *s = json_string_value(json_object_get(e, "pointer"));
    return s ? s : "";
}

static const char *problem_code_of(const json_t *problem)
{
    const char *s = json_string_value(json_object_get(problem, "code"));
    return s ? s : "";
}

static float variant_g(const sweep *sw, uint32_t i)
{
    scene_doc *doc = NULL;
    ns_error err;
    if (sweep_variant_scene(sw, i, &doc, &err))
        return -99.0f;
    float g = scene_doc_scene(doc)->materials[0].g;
    scene_doc_free(doc);
    return g;
}

static float variant_ior(const sweep *sw, uint32_t i)
{
    scene_doc *doc = NULL;
    ns_error err;
    if (sweep_variant_scene(sw, i, &doc, &err))
        return -99.0f;
    float ior = scene_doc_scene(doc)->materials[0].ior;
    scene_doc_free(doc);
    return ior;
}

static void test_variant_list_and_order(void)
{
    parsed p = parse("{\"scene\": " SCENE ", \"variants\": ["
                     "{\"/materials/wax/g\": 0.5},"
                     "{\"/materials/wax/g\": 0.8},"
                     "{\"/materials/wax/g\": 0.5, \"/materials/wax/ior\": 1.3}]}");
    CHECK_INT(p.rc, 0);
    CHECK(p.problem == NULL);
    if (!p.sw)
        return;
    CHECK_INT(sweep_variant_count(p.sw), 3);
    CHECK_NEAR(variant_g(p.sw, 0), 0.5, 1e-6);
    CHECK_NEAR(variant_g(p.sw, 1), 0.8, 1e-6);
    CHECK_NEAR(variant_ior(p.sw, 2), 1.3, 1e-6);
    CHECK_NEAR(variant_ior(p.sw, 0), 1.0, 1e-6); /* the base scene's, untouched by variant 2 */
    /* ior does not change the tables: variants 0 and 2 share them and render together. */
    const uint32_t *order = sweep_order(p.sw);
    CHECK_INT(order[0], 0);
    CHECK_INT(order[1], 2);
    CHECK_INT(order[2], 1);
    char lines[4][96];
    uint32_t n = sweep_label_lines(p.sw, 2, lines, 4);
    CHECK_INT(n, 2);
    CHECK(!strcmp(lines[0], "g=0.5"));
    CHECK(!strcmp(lines[1], "ior=1.3"));
    done(&p);
}

static void test_grid_first_pointer_slowest(void)
{
    parsed p = parse("{\"scene\": " SCENE ", \"grid\": {\"/materials/wax/ior\": [1, 1.3, 1.5],"
                     " \"/materials/wax/g\": [0.2, 0.5]}}");
    CHECK_INT(p.rc, 0);
    if (!p.sw)
        return;
    CHECK_INT(sweep_variant_count(p.sw), 6);
    const float ior[6] = {1, 1, 1.3f, 1.3f, 1.5f, 1.5f}, g[6] = {0.2f, 0.5f, 0.2f, 0.5f, 0.2f, 0.5f};
    for (uint32_t i = 0; i < 6; i++) {
        CHECK_NEAR(variant_ior(p.sw, i), ior[i], 1e-6);
        CHECK_NEAR(variant_g(p.sw, i), g[i], 1e-6);
    }
    /* Grouped by g (the table key), in request order within a group. */
    const uint32_t want[6] = {0, 2, 4, 1, 3, 5};
    for (uint32_t i = 0; i < 6; i++)
        CHECK_INT(sweep_order(p.sw)[i], want[i]);
    /* Overrides keep the body's order of pointers. */
    const char *first = NULL;
    const char *key;
    json_t *value;
    json_object_foreach((json_t *)sweep_overrides(p.sw, 3), key, value)
    {
        if (!first)
            first = key;
    }
    CHECK(first && !strcmp(first, "/materials/wax/ior"));
    done(&p);
}

static void test_overrides_add_and_arrays(void)
{
    /* A key the base lacks is added (JSON Patch "add"); an array element is replaced. */
    parsed p = parse("{\"scene\": " SCENE ", \"variants\": ["
                     "{\"/render\": {\"spp\": 2}},"
                     "{\"/lights/0/irradiance\": [2, 2, 2]},"
                     "{\"/materials/wax/albedo/1\": 0.5}]}");
    CHECK_INT(p.rc, 0);
    if (!p.sw)
        return;
    scene_doc *doc = NULL;
    ns_error err;
    CHECK_INT(sweep_variant_scene(p.sw, 0, &doc, &err), 0);
    if (doc)
        CHECK_INT(scene_doc_scene(doc)->render.spp, 2);
    scene_doc_free(doc);
    doc = NULL;
    CHECK_INT(sweep_variant_scene(p.sw, 1, &doc, &err), 0);
    if (doc)
        CHECK_NEAR(scene_doc_scene(doc)->lights[0].color[0], 2.0, 1e-6);
    scene_doc_free(doc);
    doc = NULL;
    CHECK_INT(sweep_variant_scene(p.sw, 2, &doc, &err), 0);
    if (doc) {
        const ns_material *m = &scene_doc_scene(doc)->materials[0];
        float a0 = m->sigma_s[0] / (m->sigma_s[0] + m->sigma_a[0]);
        float a1 = m->sigma_s[1] / (m->sigma_s[1] + m->sigma_a[1]);
        CHECK_NEAR(a0, 0.9, 1e-5);
        CHECK_NEAR(a1, 0.5, 1e-5);
    }
    scene_doc_free(doc);
    /* Variant 2's albedo differs in one channel: its own table group, after the others. */
    CHECK_INT(sweep_order(p.sw)[2], 2);
    done(&p);
}

/* An override inside another's value changes the variant's scene, never the value kept
 * for the manifest and the labels (nor the other variants that share it). */
static void test_nested_overrides_stay_apart(void)
{
    parsed p = parse("{\"scene\": " SCENE ", \"grid\": {\"/materials/wax\": [{\"type\": "
                     "\"medium\", \"albedo\": [0.9, 0.9, 0.9], \"mfp\": [0.1, 0.1, 0.1], "
                     "\"g\": 0.1, \"ior\": 1}], \"/materials/wax/g\": [0.2, 0.8]}}");
    CHECK_INT(p.rc, 0);
    if (!p.sw)
        return;
    CHECK_NEAR(variant_g(p.sw, 0), 0.2, 1e-6);
    CHECK_NEAR(variant_g(p.sw, 1), 0.8, 1e-6);
    for (uint32_t i = 0; i < 2; i++) {
        const json_t *wax = json_object_get(sweep_overrides(p.sw, i), "/materials/wax");
        CHECK_NEAR(json_real_value(json_object_get(wax, "g")), 0.1, 1e-12);
    }
    done(&p);
}

static void test_errors_point_into_the_body(void)
{
    parsed p = parse("{\"scene\": " SCENE ", \"variants\": ["
                     "{\"/materials/wax/g\": 0.5},"
                     "{\"/materials/wax/g\": 2},"
                     "{\"/materials/nope/g\": 0.1},"
                     "{\"/lights/3/irradiance\": [1, 1, 1]},"
                     "{\"materials\": 1}]}");
    CHECK(p.rc != 0);
    CHECK(p.sw == NULL);
    CHECK(!strcmp(problem_code_of(p.problem), "invalid_sweep"));
    CHECK_INT(json_integer_value(json_object_get(p.problem, "status")), 422);
    CHECK_INT(json_array_size(json_object_get(p.problem, "errors")), 4);
    CHECK(!strcmp(error_pointer(p.problem, 0), "/variants/1/~1materials~1wax~1g"));
    CHECK(!strcmp(error_pointer(p.problem, 1), "/variants/2/~1materials~1nope~1g"));
    CHECK(!strcmp(error_pointer(p.problem, 2), "/variants/3/~1lights~13~1irradiance"));
    CHECK(!strcmp(error_pointer(p.problem, 3), "/variants/4/materials"));
    const char *detail = json_string_value(
        json_object_get(json_array_get(json_object_get(p.problem, "errors"), 0), "detail"));
    CHECK(detail && !strncmp(detail, "variant 1: ", 11));
    CHECK_STR_CONTAINS(json_string_value(json_object_get(p.problem, "detail")), "variant 1");
    done(&p);

    /* A grid's bad value: the pointer names the value in the grid's list. */
    p = parse("{\"scene\": " SCENE ", \"grid\": {\"/materials/wax/ior\": [1, 1.3],"
              " \"/materials/wax/g\": [0.2, 1.5]}}");
    CHECK(p.rc != 0);
    CHECK(!strcmp(error_pointer(p.problem, 0), "/grid/~1materials~1wax~1g/1"));
    CHECK_INT(json_array_size(json_object_get(p.problem, "errors")), 1); /* once, not twice */
    done(&p);

    /* A fault of the base scene, outside every override: once, under /scene. */
    char body[4096];
    snprintf(body, sizeof body, "{\"scene\": %s, \"variants\": [{\"/materials/wax/g\": 0.1},"
                                "{\"/materials/wax/g\": 0.2}]}",
             SCENE);
    char *fov = strstr(body, "\"fov\": 40");
    memcpy(fov, "\"fov\": -4", 9);
    p = parse(body);
    CHECK(p.rc != 0);
    CHECK(!strcmp(error_pointer(p.problem, 0), "/scene/camera/fov"));
    CHECK_INT(json_array_size(json_object_get(p.problem, "errors")), 1);
    done(&p);
}

static void test_refused_bodies(void)
{
    const struct {
        const char *body;
        const char *code;
        const char *pointer;
    } cases[] = {
        {"{\"scene\": " SCENE ", \"variants\": [", "malformed_json", ""},
        {"[]", "invalid_sweep", ""},
        {"{\"variants\": [{}]}", "invalid_sweep", "/scene"},
        {"{\"scene\": " SCENE "}", "invalid_sweep", ""},
        {"{\"scene\": " SCENE ", \"variants\": [], \"grid\": {}}", "invalid_sweep", ""},
        {"{\"scene\": " SCENE ", \"variants\": []}", "invalid_sweep", "/variants"},
        {"{\"scene\": " SCENE ", \"variants\": [1]}", "invalid_sweep", "/variants/0"},
        {"{\"scene\": " SCENE ", \"grid\": {\"/materials/wax/g\": []}}", "invalid_sweep",
         "/grid/~1materials~1wax~1g"},
        {"{\"scene\": " SCENE ", \"grid\": {}}", "invalid_sweep", "/grid"},
        {"{\"scene\": " SCENE ", \"variants\": [{}], \"colour\": 1}", "invalid_sweep", "/colour"},
        {"{\"scene\": " SCENE ", \"variants\": [{\"/materials/wax/g\": 0.1, "
         "\"/materials/wax/g\": 0.2}]}",
         "invalid_sweep", "/variants/0/~1materials~1wax~1g"},
        /* Valid grammar, invalid sweep, as in a scene: at the field's pointer (422). */
        {"{\"scene\": " SCENE ", \"scene\": " SCENE ", \"variants\": [{}]}", "invalid_sweep",
         "/scene"},
        {"{\"scene\": " SCENE ", \"variants\": [{\"/materials/wax/g\": 1e400}]}",
         "invalid_sweep", "/variants/0/~1materials~1wax~1g"},
        {"{\"scene\": " SCENE ", \"grid\": {\"/materials/wax/g\": [0.1, -1e999]}}",
         "invalid_sweep", "/grid/~1materials~1wax~1g/1"},
        {"{\"scene\": " SCENE ", \"variants\": [{\"/materials~2/g\": 0.1}]}", "invalid_sweep",
         "/variants/0/~1materials~02~1g"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        parsed p = parse(cases[i].body);
        CHECK(p.rc != 0);
        CHECK(p.sw == NULL);
        if (strcmp(problem_code_of(p.problem), cases[i].code) ||
            strcmp(error_pointer(p.problem, 0), cases[i].pointer))
            fprintf(stderr, "  case %zu: code %s pointer '%s'\n", i, problem_code_of(p.problem),
                    error_pointer(p.problem, 0));
        CHECK(!strcmp(problem_code_of(p.problem), cases[i].code));
        CHECK(!strcmp(error_pointer(p.problem, 0), cases[i].pointer));
        done(&p);
    }
}

static void test_limits(void)
{
    /* 257 variants, as a list and as a grid (17 x 17 = 289). */
    size_t cap = 1 << 16;
    char *body = malloc(cap);
    size_t n = (size_t)snprintf(body, cap, "{\"scene\": " SCENE ", \"variants\": [");
    for (uint32_t i = 0; i <= SWEEP_MAX_VARIANTS; i++)
        n += (size_t)snprintf(body + n, cap - n, "%s{\"/materials/wax/g\": 0.1}", i ? "," : "");
    snprintf(body + n, cap - n, "]}");
    parsed p = parse(body);
    CHECK(p.rc != 0);
    CHECK(!strcmp(error_pointer(p.problem, 0), "/variants"));
    done(&p);
    n = (size_t)snprintf(body, cap, "{\"scene\": " SCENE ", \"grid\": {\"/materials/wax/g\": [");
    for (int i = 0; i < 17; i++)
        n += (size_t)snprintf(body + n, cap - n, "%s0.%d", i ? "," : "", i + 1);
    n += (size_t)snprintf(body + n, cap - n, "], \"/materials/wax/ior\": [");
    for (int i = 0; i < 17; i++)
        n += (size_t)snprintf(body + n, cap - n, "%s1.%d", i ? "," : "", i + 1);
    snprintf(body + n, cap - n, "]}}");
    p = parse(body);
    CHECK(p.rc != 0);
    CHECK(!strcmp(error_pointer(p.problem, 0), "/grid"));
    done(&p);
    /* Exactly the limit is fine: 16 x 16. */
    n = (size_t)snprintf(body, cap, "{\"scene\": " SCENE ", \"grid\": {\"/materials/wax/g\": [");
    for (int i = 0; i < 16; i++)
        n += (size_t)snprintf(body + n, cap - n, "%s0.%02d", i ? "," : "", i + 1);
    n += (size_t)snprintf(body + n, cap - n, "], \"/materials/wax/ior\": [");
    for (int i = 0; i < 16; i++)
        n += (size_t)snprintf(body + n, cap - n, "%s1.%02d", i ? "," : "", i + 1);
    snprintf(body + n, cap - n, "]}}");
    p = parse(body);
    CHECK_INT(p.rc, 0);
    CHECK_INT(sweep_variant_count(p.sw), SWEEP_MAX_VARIANTS);
    done(&p);
    free(body);
}

int main(void)
{
    RUN(test_variant_list_and_order);
    RUN(test_grid_first_pointer_slowest);
    RUN(test_overrides_add_and_arrays);
    RUN(test_nested_overrides_stay_apart);
    RUN(test_errors_point_into_the_body);
    RUN(test_refused_bodies);
    RUN(test_limits);
    return harness_report();
}
