/* unit_pt_settings.c — the scene keys of the reference path tracer: render.max_scatter
 * (pt only, an integer in [0, NS_MAX_SCATTER], 0 = no limit, absent = 0), and every
 * scattering component accepted with method "pt". */
#include <stdlib.h>

#include "harness.h"
#include "scene_json.h"

static const char *scene_fmt =
    "{\"version\": 1, \"camera\": {\"position\": [0, 0, 4], \"look_at\": [0, 0, 0], "
    "\"up\": [0, 1, 0], \"fov\": 40, \"width\": 8, \"height\": 8}, "
    "\"materials\": {\"m\": {\"type\": \"medium\", \"sigma_s\": [1, 1, 1], "
    "\"sigma_a\": [0, 0, 0], \"ior\": 1}}, "
    "\"objects\": [{\"shape\": \"sphere\", \"center\": [0, 0, 0], \"radius\": 1, "
    "\"material\": \"m\"}], "
    "\"lights\": [{\"type\": \"environment\", \"radiance\": [1, 1, 1]}], "
    "\"render\": {%s}}";

static int parse_render(const char *render_json, scene_doc **doc, scene_issues *issues)
{
    char text[2048];
    snprintf(text, sizeof text, scene_fmt, render_json);
    return scene_parse(text, strlen(text), NULL, doc, issues);
}

static void expect_valid(const char *render_json, uint32_t max_scatter, uint32_t components)
{
    scene_doc *doc = NULL;
    scene_issues issues;
    int rc = parse_render(render_json, &doc, &issues);
    CHECK_INT(rc, 0);
    if (rc) {
        for (uint32_t i = 0; i < issues.count; i++)
            fprintf(stderr, "  %s: %s: %s\n", render_json, issues.items[i].pointer,
                    issues.items[i].detail);
    } else {
        const ns_scene *s = scene_doc_scene(doc);
        CHECK_INT(s->render.max_scatter, max_scatter);
        CHECK_INT(s->render.components, components);
    }
    scene_doc_free(doc);
}

static void expect_issue(const char *render_json, const char *pointer, const char *detail)
{
    scene_doc *doc = NULL;
    scene_issues issues;
    CHECK_INT(parse_render(render_json, &doc, &issues), NS_ERR_INVALID_ARGUMENT);
    CHECK(doc == NULL);
    int found = 0;
    for (uint32_t i = 0; i < issues.count; i++)
        if (!strcmp(issues.items[i].pointer, pointer) && strstr(issues.items[i].detail, detail))
            found = 1;
    if (!found)
        for (uint32_t i = 0; i < issues.count; i++)
            fprintf(stderr, "  %s: got %s: %s\n", render_json, issues.items[i].pointer,
                    issues.items[i].detail);
    CHECK(found);
    scene_doc_free(doc);
}

static void test_max_scatter_values(void)
{
    const uint32_t all =
        NS_COMPONENT_ALL;
    expect_valid("\"method\": \"pt\"", 0, all);
    expect_valid("\"method\": \"pt\", \"max_scatter\": 0", 0, all);
    expect_valid("\"method\": \"pt\", \"max_scatter\": 2", 2, all);
    expect_valid("\"method\": \"pt\", \"max_scatter\": 100000", 100000, all);
    expect_issue("\"method\": \"pt\", \"max_scatter\": -1", "/render/max_scatter", "max_scatter");
    expect_issue("\"method\": \"pt\", \"max_scatter\": 100001", "/render/max_scatter",
                 "max_scatter");
    expect_issue("\"method\": \"pt\", \"max_scatter\": 1.5", "/render/max_scatter", "max_scatter");
    expect_issue("\"method\": \"pt\", \"max_scatter\": \"2\"", "/render/max_scatter",
                 "max_scatter");
}

static void test_max_scatter_is_pt_only(void)
{
    expect_issue("\"max_scatter\": 2, \"components\": [\"surface\"]", "/render/max_scatter",
                 "applies to method \"pt\" only");
    expect_issue("\"method\": \"nn\", \"components\": [\"surface\"], \"max_scatter\": 1",
                 "/render/max_scatter", "applies to method \"pt\" only");
}

static void test_pt_takes_every_component(void)
{
    expect_valid("\"method\": \"pt\", \"components\": [\"single\"]", 0, NS_COMPONENT_SINGLE);
    expect_valid("\"method\": \"pt\", \"components\": [\"double\", \"multiple\"], "
                 "\"max_scatter\": 5",
                 5, NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE);
}

int main(void)
{
    RUN(test_max_scatter_values);
    RUN(test_max_scatter_is_pt_only);
    RUN(test_pt_takes_every_component);
    return harness_report();
}
