/* bench.c — what `nscatter bench` measures: its methods, the component sets of its
 * references and the paper's figures of a scene. Shared by the command (cmd_bench.c), which
 * runs the experiments, and by its report (bench_report.c), which prints them; neither of
 * those two calls the other back. */
#include <math.h>

#include "bench.h"

const bench_method_info bench_methods[BENCH_METHOD_COUNT] = {
    [BENCH_NN_SURFACE] = {"nn_surface", NS_METHOD_NN, NS_COMPONENT_SURFACE, NULL, "nn, surface only"},
    [BENCH_NN_MULTIPLE] = {"nn_multiple", NS_METHOD_NN, NS_COMPONENT_MULTIPLE, "multiple",
                           "nn, multiple only"},
    [BENCH_NN_DOUBLE] = {"nn_double", NS_METHOD_NN, NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE,
                         "double", "nn, double + multiple"},
    [BENCH_NN_FULL] = {"nn_full", NS_METHOD_NN, BENCH_ALL, "full", "nn, full solution"},
    [BENCH_TABLE] = {"table", NS_METHOD_TABLE, BENCH_ALL, "full", "table (Monte Carlo, [WH17])"},
    [BENCH_DIPOLE] = {"dipole", NS_METHOD_DIPOLE, BENCH_ALL, "full", "dipole"},
    [BENCH_VRL] = {"vrl", NS_METHOD_VRL, BENCH_ALL, "full", "vrl at equal time"},
    [BENCH_PT] = {"pt", NS_METHOD_PT, BENCH_ALL, NULL, "pt, short renders"},
};

const uint32_t bench_ref_components[BENCH_REF_SETS] = {
    BENCH_ALL, NS_COMPONENT_MULTIPLE, NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE, NS_COMPONENT_SURFACE};

int bench_ref_index(uint32_t components)
{
    for (int i = 0; i < BENCH_REF_SETS; i++)
        if (bench_ref_components[i] == components)
            return i;
    return -1;
}

const char *bench_components_name(uint32_t components)
{
    switch (components) {
    case BENCH_ALL: return "full";
    case NS_COMPONENT_MULTIPLE: return ns_component_name(components);
    case NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE: return "double+multiple";
    case NS_COMPONENT_SURFACE: return ns_component_name(components);
    default: return "other";
    }
}

double bench_paper_value(const bench_scene *s, const char *method, const char *field)
{
    json_t *v = json_object_get(json_object_get(json_object_get(s->manifest, "paper"), method), field);
    return json_is_number(v) ? json_number_value(v) : NAN;
}

double bench_result_mse(const bench_result *r)
{
    if (r->seeds >= 2)
        return r->seed_mse_mean;
    return r->metrics.rmse[3] * r->metrics.rmse[3];
}

double bench_result_psnr(const bench_result *r)
{
    if (!r->metrics.pixels)
        return NAN;
    if (r->seeds < 2)
        return r->metrics.psnr[3];
    /* The same reference, so the same peak as the row's own comparison (image_compare's
     * NaN for a peak of 0, infinity for no error). */
    if (!(r->metrics.peak > 0))
        return NAN;
    if (r->seed_mse_mean == 0)
        return INFINITY;
    return 10.0 * log10(r->metrics.peak * r->metrics.peak / r->seed_mse_mean);
}
