/* gpu_nn_reconstruct.c — shaders/nn_reconstruct.comp against the CPU forward pass of the
 * same weights, and reconstructed tables (committed weights) against the exact energy and
 * moments of DESIGN.md section 2, for materials on and off the training grid. Validation
 * layers on (ctest sets NSCATTER_VALIDATION=1): any message fails the test. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mc.h"
#include "nn_train.h"
#include "harness.h"
#include "nn_reconstruct.h"

static gpu_device dev;
static ns_nn_gpu nn;

static void random_inputs(float *x, uint32_t n, uint64_t seed)
{
    for (size_t i = 0; i < (size_t)n * NS_NN_INPUTS; i++) {
        seed = seed * 6364136223846793005ull + 1442695040888963407ull;
        x[i] = (float)((seed >> 40) * 0x1.0p-24);
    }
}

/* GPU against the CPU forward pass for n random inputs: returns the worst relative error
 * of the network output y (relative to max(|y|, 1)) and stores that of J in *worst_j. The
 * J scale is |J| + eps E: where J is within eps E of zero (exp(t) ~ eps) the transform
 * cancels and only an absolute comparison at that scale is meaningful. J's error is y's
 * times the transform's scale (up to ~12 for the committed weights): float rounding of y
 * alone, amplified, so J gets that factor in its tolerance. */
static double compare_points(const ns_nn_weights *nets[2], uint32_t n, double *worst_j)
{
    float *x = malloc((size_t)n * NS_NN_INPUTS * sizeof(float));
    double *energy = malloc(n * sizeof(double));
    float *out = malloc((size_t)n * 4 * sizeof(float));
    random_inputs(x, n, 1234 + nets[0]->h.target);
    for (uint32_t i = 0; i < n; i++)
        energy[i] = 0.05 + 2.0 * x[(size_t)i * NS_NN_INPUTS + 5];
    ns_error err = {0};
    uint32_t before = gpu_validation_count(&dev);
    CHECK_INT(ns_nn_eval_points(&dev, &nn, nets, x, energy, n, out, &err), 0);
    CHECK_INT(gpu_validation_check(&dev, before, &err), 0);
    double worst = 0;
    *worst_j = 0;
    for (int o = 0; o < 2; o++)
        for (uint32_t i = 0; i < n; i++) {
            const ns_nn_header *h = &nets[o]->h;
            double y = ns_nn_forward(nets[o], x + (size_t)i * NS_NN_INPUTS);
            worst = fmax(worst, fabs(out[(size_t)(2 + o) * n + i] - y) / fmax(fabs(y), 1.0));
            double j = ns_nn_output_to_j(h, y, energy[i]);
            double scale =
                fabs(j) + (h->target == NS_NN_TARGET_LOGREL ? h->target_eps * energy[i] : 1e-7);
            *worst_j = fmax(*worst_j, fabs(out[(size_t)o * n + i] - j) / scale / h->target_scale);
        }
    free(x), free(energy), free(out);
    return worst;
}

static void test_shader_equals_cpu_random_weights(void)
{
    ns_nn_weights w[2];
    for (int o = 0; o < 2; o++) {
        ns_nn_header_init(&w[o].h, (uint32_t)o, NS_NN_TARGET_LOGREL);
        ns_nn_init_params(w[o].p, 100 + (uint64_t)o);
        for (int i = 0; i < NS_NN_HIDDEN; i++)
            w[o].p[NS_NN_OFF_B1 + i] = 0.05f * (i % 9) - 0.2f, w[o].p[NS_NN_OFF_B2 + i] = 0.01f * i;
        w[o].h.target_mean = -2.0f, w[o].h.target_scale = 1.5f;
    }
    const ns_nn_weights *nets[2] = {&w[0], &w[1]};
    /* 5000 points: not a multiple of the 16 points per invocation, so the tail is tested. */
    double worst_j, worst = compare_points(nets, 5000, &worst_j);
    printf("random weights: worst relative difference GPU vs CPU: y %.3g, J / scale %.3g\n", worst,
           worst_j);
    CHECK(worst <= 1e-5);
    CHECK(worst_j <= 1e-5);
    /* The paper's transform too. */
    /* (mean +1: J = exp(t) - 1 stays positive, else both sides clamp to 0 and agree
     * trivially.) */
    for (int o = 0; o < 2; o++)
        w[o].h.target = NS_NN_TARGET_PAPER, w[o].h.target_eps = 1.0f, w[o].h.target_mean = 1.0f;
    worst = compare_points(nets, 777, &worst_j);
    printf("random weights, paper transform: worst relative difference: y %.3g, J / scale "
           "%.3g\n",
           worst, worst_j);
    CHECK(worst <= 1e-5);
    CHECK(worst_j <= 1e-5);
}

/* The committed weights (weights/double.bin and multiple.bin, built in). Returns 0, or -1
 * when the build has none, which is checked here: the repository has them, so a build
 * without them fails. */
static int load_builtin(ns_nn_weights w[2])
{
    ns_error err = {0};
    int status = NS_OK;
    for (uint32_t o = 0; o < 2 && !status; o++) {
        status = ns_nn_weights_builtin(o, &w[o], &err);
        if (status)
            fprintf(stderr, "no built-in weights: %s\n", err.message);
    }
    CHECK_INT(status, NS_OK);
    return status ? -1 : 0;
}

static void test_shader_equals_cpu_committed_weights(void)
{
    ns_nn_weights w[2];
    if (load_builtin(w))
        return;
    const ns_nn_weights *nets[2] = {&w[0], &w[1]};
    double worst_j, worst = compare_points(nets, 4096, &worst_j);
    printf("committed weights: worst relative difference GPU vs CPU: y %.3g, J / scale %.3g\n",
           worst, worst_j);
    CHECK(worst <= 1e-5);
    CHECK(worst_j <= 1e-5);
}

/* Exact moments of an order (DESIGN.md section 2): double is event 2, multiple the a^k
 * weighted mixture of events 3, 4, ... */
typedef struct {
    double energy, z, cos_theta, r2;
} moments;

static moments exact_moments(int order, double g, double a)
{
    moments m = {0};
    double wsum = 0;
    for (int k = order == 0 ? 2 : 3; k <= (order == 0 ? 2 : 20000); k++) {
        double w = pow(a, k), gk = pow(g, k);
        if (w < 1e-300)
            break;
        wsum += w;
        m.z += w * (1 - gk) / (1 - g);
        m.cos_theta += w * gk;
        m.r2 += w * 2 * (k / (1 - g) - g * (1 - gk) / ((1 - g) * (1 - g)));
    }
    m.energy = wsum;
    m.z /= wsum, m.cos_theta /= wsum, m.r2 /= wsum;
    return m;
}

/* Moments of a table, with bin averages that are exact for a constant J in the bin:
 * <z> at the bin's middle, <z^2> = (z1^3 - z0^3) / 3 dz, <rho^2> = (rho1^2 + rho0^2) / 2,
 * <cos theta> = (sin^2 theta1 - sin^2 theta0) / (2 (cos theta0 - cos theta1)). */
static moments table_moments(const ns_nn_grid *g, const float *j)
{
    moments m = {0};
    const double *ez = g->edges[0], *er = g->edges[1], *et = g->edges[2], *ep = g->edges[3];
    size_t c = 0;
    for (uint32_t iz = 0; iz < g->n[0]; iz++)
        for (uint32_t ir = 0; ir < g->n[1]; ir++) {
            double vol = M_PI * (er[ir + 1] * er[ir + 1] - er[ir] * er[ir]) * (ez[iz + 1] - ez[iz]);
            double zc = 0.5 * (ez[iz] + ez[iz + 1]);
            double z2 = (pow(ez[iz + 1], 3) - pow(ez[iz], 3)) / (3 * (ez[iz + 1] - ez[iz]));
            double rho2 = 0.5 * (er[ir] * er[ir] + er[ir + 1] * er[ir + 1]);
            for (uint32_t it = 0; it < g->n[2]; it++) {
                double dcos = cos(et[it]) - cos(et[it + 1]);
                double ct = (pow(sin(et[it + 1]), 2) - pow(sin(et[it]), 2)) / (2 * dcos);
                for (uint32_t ip = 0; ip < g->n[3]; ip++, c++) {
                    double e = j[c] * vol * dcos * (ep[ip + 1] - ep[ip]) * 2;
                    m.energy += e;
                    m.z += e * zc;
                    m.cos_theta += e * ct;
                    m.r2 += e * (z2 + rho2);
                }
            }
        }
    m.z /= m.energy, m.cos_theta /= m.energy, m.r2 /= m.energy;
    return m;
}

/* The Monte Carlo tables' default grid as a table (ns_table_free it) and as the
 * reconstruction's grid, whose edges are the table's; returns its cells. */
static size_t default_grid(ns_table *shape, ns_nn_grid *grid)
{
    const uint32_t n[4] = {NS_TABLE_NZ, NS_TABLE_NRHO, NS_TABLE_NTHETA, NS_TABLE_NPHI};
    CHECK_INT(ns_table_create(shape, n, NULL), 0);
    ns_mc_default_edges(shape);
    for (int a = 0; a < 4; a++)
        grid->n[a] = shape->n[a], grid->edges[a] = shape->edges[a];
    return ns_table_size(shape);
}

/* Energy (before renormalisation), <z>, <r^2> within 5% relative; <cos theta> within 0.05
 * (5% of its range: g^k is near 0 for the multiple order of low g, where relative error
 * means nothing). */
static void check_material(const ns_nn_weights w[2], double g, const double albedo[3],
                           const char *label)
{
    ns_table shape;
    ns_nn_grid grid;
    size_t cells = default_grid(&shape, &grid);
    float *out = malloc(cells * 6 * sizeof(float));
    ns_nn_reconstruct_desc d = {.nets = {&w[0], &w[1]},
                                .grid = grid,
                                .g = g,
                                .albedo = {albedo[0], albedo[1], albedo[2]},
                                .renormalise = 1,
                                .out = out};
    ns_nn_reconstruct_stats st;
    ns_error err = {0};
    uint32_t before = gpu_validation_count(&dev);
    CHECK_INT(ns_nn_reconstruct(&dev, &nn, &d, &st, &err), 0);
    CHECK_INT(gpu_validation_check(&dev, before, &err), 0);
    for (int o = 0; o < 2; o++)
        for (int c = 0; c < 3; c++) {
            moments want = exact_moments(o, g, albedo[c]);
            moments got = table_moments(&d.grid, out + ((size_t)o * 3 + c) * cells);
            printf("%s %s a=%.3f: energy raw %.4g / %.4g, renormalised %.4g; <z> %.4g / %.4g; "
                   "<cos> %.4g / %.4g; <r2> %.4g / %.4g\n",
                   label, o ? "multiple" : "double", albedo[c], st.energy_raw[o][c], want.energy,
                   got.energy, got.z, want.z, got.cos_theta, want.cos_theta, got.r2, want.r2);
            CHECK_REL(st.energy_raw[o][c], want.energy, 0.05);
            CHECK_REL(got.energy, want.energy, 1e-4); /* renormalised */
            CHECK_REL(got.z, want.z, 0.05);
            CHECK_NEAR(got.cos_theta, want.cos_theta, 0.05);
            CHECK_REL(got.r2, want.r2, 0.05);
        }
    free(out);
    ns_table_free(&shape);
}

static void test_tables_on_grid(void)
{
    ns_nn_weights w[2];
    if (load_builtin(w))
        return;
    check_material(w, 0.5, (double[3]){0.8, 0.6, 0.4}, "on-grid g=0.5");
}

static void test_tables_off_grid(void)
{
    ns_nn_weights w[2];
    if (load_builtin(w))
        return;
    check_material(w, 0.45, (double[3]){0.87, 0.65, 0.35}, "off-grid g=0.45");
}

static void test_rejects_bad_material(void)
{
    ns_nn_weights w[2];
    for (int o = 0; o < 2; o++) {
        ns_nn_header_init(&w[o].h, (uint32_t)o, NS_NN_TARGET_LOGREL);
        ns_nn_init_params(w[o].p, 1);
    }
    double edges[2] = {0, 1};
    float out[6];
    ns_nn_reconstruct_desc d = {
        .nets = {&w[0], &w[1]}, .g = 0.5, .albedo = {0.5, 1.5, 0.5}, .out = out};
    for (int a = 0; a < 4; a++)
        d.grid.n[a] = 1, d.grid.edges[a] = edges;
    ns_error err = {0};
    CHECK_INT(ns_nn_reconstruct(&dev, &nn, &d, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "albedo[1]");
    d.albedo[1] = 0.5;
    d.nets[1] = &w[0]; /* the double network in the multiple slot */
    CHECK_INT(ns_nn_reconstruct(&dev, &nn, &d, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "multiple");
    /* The two networks feed on one input table: a multiple network of input map 2 (g through
     * ln(1 - g)) beside a double network of map 1 is refused, even with the same g range. */
    d.nets[1] = &w[1];
    w[1].h.input_map = NS_NN_INPUT_MAP_ASINH_LOGG;
    CHECK_INT(ns_nn_reconstruct(&dev, &nn, &d, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "normalise inputs differently");
}

/* One order alone (desc.orders): its tables bit for bit those of both orders evaluated
 * together, the other order's part of out untouched, fewer evaluations; a value that names
 * no order is refused, naming the field. */
static void test_one_order_alone(void)
{
    ns_nn_weights w[2];
    if (load_builtin(w))
        return;
    ns_table shape;
    ns_nn_grid grid;
    size_t cells = default_grid(&shape, &grid);
    float *both = malloc(cells * 6 * sizeof(float)), *alone = malloc(cells * 6 * sizeof(float));
    ns_nn_reconstruct_desc d = {.nets = {&w[0], &w[1]},
                                .grid = grid,
                                .g = 0.6,
                                .albedo = {0.9, 0.5, 0.99},
                                .renormalise = 1,
                                .channels = 2,
                                .out = both};
    ns_nn_reconstruct_stats st_both, st;
    ns_error err = {0};
    CHECK_INT(ns_nn_reconstruct(&dev, &nn, &d, &st_both, &err), 0);
    const uint32_t orders[2] = {NS_NN_ORDER_DOUBLE, NS_NN_ORDER_MULTIPLE};
    for (int o = 0; o < 2; o++) {
        for (size_t i = 0; i < cells * 6; i++)
            alone[i] = -1.0f;
        d.out = alone;
        d.orders = orders[o];
        CHECK_INT(ns_nn_reconstruct(&dev, &nn, &d, &st, &err), 0);
        for (int c = 0; c < 2; c++) {
            size_t at = ((size_t)o * 3 + c) * cells, other = ((size_t)(1 - o) * 3 + c) * cells;
            CHECK(memcmp(alone + at, both + at, cells * sizeof(float)) == 0);
            CHECK(alone[other] == -1.0f && alone[other + cells - 1] == -1.0f);
            CHECK(st.energy_raw[o][c] == st_both.energy_raw[o][c]);
        }
        CHECK(st.evaluations * 2 == st_both.evaluations);
    }
    d.orders = 3;
    CHECK_INT(ns_nn_reconstruct(&dev, &nn, &d, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "orders");
    free(both);
    free(alone);
    ns_table_free(&shape);
}

/* Is bin i of axis a a node of the sampling (the rule of nn_reconstruct.c's sample_axis)? */
static int is_node(const ns_nn_grid *g, int a, uint32_t i, const ns_nn_sampling *s)
{
    double centre = 0.5 * (g->edges[a][i] + g->edges[a][i + 1]);
    return i % s->stride[a] == 0 || i == g->n[a] - 1 || (a < 2 && fabs(centre) <= s->full_radius);
}

/* The default sampled reconstruction against every cell evaluated, committed weights, one
 * channel: at the nodes the two agree to float rounding (same network, same transform, the
 * interpolation weights are 0 or 1 there); between them the energy-weighted L1 stays small
 * (docs/network.md measures 0.4-2.0% over the report's materials; 3% allowed), and far
 * fewer evaluations are made. */
static void test_sampled_matches_every_cell(void)
{
    ns_nn_weights w[2];
    if (load_builtin(w))
        return;
    ns_table shape;
    ns_nn_grid grid;
    size_t cells = default_grid(&shape, &grid);
    float *out[2] = {malloc(cells * 6 * sizeof(float)), malloc(cells * 6 * sizeof(float))};
    ns_nn_sampling sampling[2] = {ns_nn_sampling_default(), ns_nn_sampling_every_cell()};
    ns_nn_reconstruct_stats st[2];
    for (int k = 0; k < 2; k++) {
        ns_nn_reconstruct_desc d = {.nets = {&w[0], &w[1]},
                                    .grid = grid,
                                    .g = 0.75,
                                    .albedo = {0.97, 0, 0},
                                    .channels = 1,
                                    .out = out[k],
                                    .sampling = &sampling[k]};
        ns_error err = {0};
        uint32_t before = gpu_validation_count(&dev);
        CHECK_INT(ns_nn_reconstruct(&dev, &nn, &d, &st[k], &err), 0);
        CHECK_INT(gpu_validation_check(&dev, before, &err), 0);
    }
    CHECK(st[0].evaluations * 4 < st[1].evaluations);
    CHECK(st[0].cells == st[1].cells && st[1].evaluations == st[1].cells);
    for (int o = 0; o < 2; o++) {
        const float *s = out[0] + (size_t)o * 3 * cells, *e = out[1] + (size_t)o * 3 * cells;
        double worst_node = 0, diff = 0, ref = 0;
        size_t c = 0, node_cells = 0;
        for (uint32_t iz = 0; iz < grid.n[0]; iz++)
            for (uint32_t ir = 0; ir < grid.n[1]; ir++) {
                double vol = ns_table_bin_volume(&shape, iz, ir);
                for (uint32_t it = 0; it < grid.n[2]; it++)
                    for (uint32_t ip = 0; ip < grid.n[3]; ip++, c++) {
                        double wgt = vol * ns_table_bin_solid_angle(&shape, it, ip);
                        diff += fabs((double)s[c] - e[c]) * wgt;
                        ref += e[c] * wgt;
                        if (is_node(&grid, 0, iz, &sampling[0]) &&
                            is_node(&grid, 1, ir, &sampling[0]) &&
                            is_node(&grid, 2, it, &sampling[0]) &&
                            is_node(&grid, 3, ip, &sampling[0])) {
                            node_cells++;
                            worst_node = fmax(worst_node, fabs(s[c] - e[c]) / fmax(e[c], 1e-30));
                        }
                    }
            }
        printf("g 0.75 a 0.97 %s: %llu of %zu evaluations; at the %zu node cells worst relative "
               "difference %.3g; L1 sampled vs every cell %.3f%%\n",
               o ? "multiple" : "double", (unsigned long long)st[0].evaluations / 2, cells,
               node_cells, worst_node, 100 * diff / ref);
        CHECK(node_cells * 2 == st[0].evaluations);
        CHECK(worst_node <= 1e-5);
        CHECK(diff / ref <= 0.03);
    }
    free(out[0]), free(out[1]);
    ns_table_free(&shape);
}

static void test_rejects_bad_sampling(void)
{
    ns_nn_weights w[2];
    for (int o = 0; o < 2; o++) {
        ns_nn_header_init(&w[o].h, (uint32_t)o, NS_NN_TARGET_LOGREL);
        ns_nn_init_params(w[o].p, 1);
    }
    double edges[2] = {0, 1};
    float out[6];
    ns_nn_sampling bad = {.stride = {2, 0, 1, 1}};
    ns_nn_reconstruct_desc d = {
        .nets = {&w[0], &w[1]}, .g = 0.5, .albedo = {0.5, 0.5, 0.5}, .out = out, .sampling = &bad};
    for (int a = 0; a < 4; a++)
        d.grid.n[a] = 1, d.grid.edges[a] = edges;
    ns_error err = {0};
    CHECK_INT(ns_nn_reconstruct(&dev, &nn, &d, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "stride[1]");
    bad.stride[1] = 1, bad.full_radius = -1;
    CHECK_INT(ns_nn_reconstruct(&dev, &nn, &d, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "full_radius");
}

int main(void)
{
    const char *v = getenv("NSCATTER_VALIDATION");
    ns_error err = {0};
    if (gpu_device_create(
            &dev,
            &(gpu_device_desc){.device = getenv("NSCATTER_DEVICE"), .validation = v && *v == '1'},
            &err) ||
        ns_nn_gpu_create(&dev, &nn, &err)) {
        fprintf(stderr, "device: %s\n", err.message);
        return 1;
    }
    RUN(test_shader_equals_cpu_random_weights);
    RUN(test_shader_equals_cpu_committed_weights);
    RUN(test_rejects_bad_material);
    RUN(test_tables_on_grid);
    RUN(test_tables_off_grid);
    RUN(test_sampled_matches_every_cell);
    RUN(test_one_order_alone);
    RUN(test_rejects_bad_sampling);
    ns_nn_gpu_destroy(&dev, &nn);
    gpu_device_destroy(&dev);
    return harness_report();
}
