/* unit_names.c — the render library's registry of method and component names (nscatter.h):
 * the names the scene JSON, the HTTP API and the command line share, both ways, and what
 * happens to anything that is not one of them. */
#include <stdint.h>
#include <string.h>

#include "harness.h"
#include "nscatter.h"

static void test_methods(void)
{
    static const char *const want[] = {"nn", "table", "vrl", "dipole", "pt"};
    CHECK_INT(NS_METHOD_COUNT, 5);
    for (int m = 0; m < NS_METHOD_COUNT; m++) {
        CHECK(!strcmp(ns_method_name((ns_method)m), want[m]));
        ns_method parsed = (ns_method)-1;
        CHECK_INT(ns_method_parse(want[m], &parsed), NS_OK);
        CHECK_INT(parsed, m);
    }
    CHECK_INT(NS_METHOD_DIPOLE, 3); /* the values are the scene JSON's and the tables' order */
    CHECK(!strcmp(ns_method_name((ns_method)NS_METHOD_COUNT), "unknown"));
    CHECK(!strcmp(ns_method_name((ns_method)-1), "unknown"));

    /* Exact names only: case, spaces, prefixes, trailing garbage and empty are refused, and
     * the output is left alone. */
    static const char *const bad[] = {"",    "NN",     " nn",     "nn ",    "n",
                                      "nnx", "table2", "unknown", "surface"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        ns_method parsed = NS_METHOD_PT;
        CHECK_INT(ns_method_parse(bad[i], &parsed), NS_ERR_INVALID_ARGUMENT);
        CHECK_INT(parsed, NS_METHOD_PT);
    }
    ns_method parsed = NS_METHOD_PT;
    CHECK_INT(ns_method_parse(NULL, &parsed), NS_ERR_INVALID_ARGUMENT);
}

static void test_components(void)
{
    static const char *const want[] = {"surface", "single", "double", "multiple"};
    CHECK_INT(NS_COMPONENT_COUNT, 4);
    CHECK_INT(NS_COMPONENT_ALL, 0xf);
    CHECK_INT(NS_COMPONENT_MULTIPLE, 1u << 3);
    for (int bit = 0; bit < NS_COMPONENT_COUNT; bit++) {
        CHECK(!strcmp(ns_component_name(1u << bit), want[bit]));
        uint32_t parsed = 0;
        CHECK_INT(ns_component_parse(want[bit], &parsed), NS_OK);
        CHECK_INT(parsed, 1u << bit);
    }
    /* A name is one bit's: none, several or an unknown bit have none. */
    CHECK(!strcmp(ns_component_name(0), "unknown"));
    CHECK(!strcmp(ns_component_name(NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE), "unknown"));
    CHECK(!strcmp(ns_component_name(1u << 4), "unknown"));
    CHECK(!strcmp(ns_component_name(UINT32_MAX), "unknown"));
    static const char *const bad[] = {"", "Surface", "double ", "doubles", "full", "nn"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        uint32_t parsed = 77;
        CHECK_INT(ns_component_parse(bad[i], &parsed), NS_ERR_INVALID_ARGUMENT);
        CHECK_INT(parsed, 77);
    }
    uint32_t parsed = 77;
    CHECK_INT(ns_component_parse(NULL, &parsed), NS_ERR_INVALID_ARGUMENT);
}

int main(void)
{
    RUN(test_methods);
    RUN(test_components);
    return harness_report();
}
