/* cmd_table.c — `nscatter table`: a scattering table from the networks (GPU reconstruction)
 * or from Monte Carlo, in the format `nscatter mc` writes; `--report`: accuracy of the
 * networks against exact energies and Monte Carlo tables; `--benchmark`: reconstruction
 * speed against a CPU evaluation of the same network (docs/network.md). */
#include <cblas.h>
#include <errno.h>
#include <pthread.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "args.h"
#include "mc.h"
#include "nn_train.h"
#include "table_io.h"
#include "nn.h"
#include "commands.h"

static const char usage_text[] =
    "usage: nscatter table --source nn|mc --order double|multiple --g G --albedo A --out PREFIX\n"
    "                      [--no-renormalise] [--photons N (mc, default 5e7 collisions)]\n"
    "                      [--seed S] [--weights-double F] [--weights-multiple F] [--device D]\n"
    "       nscatter table --report [--mc-dir DIR] [--materials G:A,G:A,...]\n"
    "                      [--mc-collisions C (5e7)] [common options]\n"
    "       nscatter table --benchmark [--runs N (5)] [common options]\n"
    "       nscatter table --compare PREFIX_A PREFIX_B\n"
    "common: [--stride Z,R,T,P (4,4,1,2)] [--full-radius MFP (2)] [--every-cell]\n"
    "\n"
    "--source nn reconstructs the table on the GPU from the networks (built in, or --weights-*)\n"
    "on the Monte Carlo table's bins and, unless --no-renormalise, rescales it to the exact\n"
    "energy (a^2 or a^3/(1-a)). The networks are evaluated at every --stride-th bin of each\n"
    "axis (and every z and rho bin within --full-radius mfp of the source), the cells between\n"
    "interpolated; --every-cell evaluates them at every cell. --report compares the networks\n"
    "with the exact energies and with Monte Carlo tables of materials off the training grid\n"
    "(cached in --mc-dir, default data/report) and, unless --every-cell, with the every-cell\n"
    "evaluation. --benchmark times the reconstruction of both tables of an RGB material,\n"
    "sampled and every cell, and a plain C OpenBLAS evaluation of the same network on 2\n"
    "threads.\n"
    "--compare prints the energies of two tables and their energy-weighted L1 distance\n"
    "(relative to B), e.g. two Monte Carlo seeds: the noise floor of the report's L1.\n";

typedef struct {
    const char *source, *out, *weights[2], *device, *mc_dir, *materials, *compare[2];
    ns_order order;
    int have_order, have_g, have_albedo, renormalise, report, benchmark, runs;
    double g, albedo, mc_collisions;
    uint64_t photons, seed;
    ns_nn_sampling sampling;
} table_options;

#define usage_error(...) cli_usage_error("nscatter table", __VA_ARGS__)

static double now_s(void)
{
    return ns_now_ms() * 1e-3;
}

static int parse_num(const char *name, const char *text, double lo, double hi, double *out)
{
    return cli_parse_number("nscatter table", name, text, lo, hi, out);
}

static int parse_uint(const char *name, const char *text, uint64_t lo, uint64_t hi, uint64_t *out)
{
    return cli_parse_uint("nscatter table", name, text, lo, hi, out);
}

static int parse_stride(const char *text, ns_nn_sampling *s)
{
    uint64_t v[4];
    size_t count = 0;
    if (cli_parse_uint_list("nscatter table", "--stride", text, 1, 16, v, 4, &count))
        return 2;
    if (count != 4)
        return usage_error("--stride: '%s' is not Z,R,T,P (four integers, 1 to 16)", text);
    for (int a = 0; a < 4; a++)
        s->stride[a] = (uint32_t)v[a];
    return 0;
}

static int parse_value(table_options *o, const char *arg, const char *val)
{
    uint64_t u = 0;
    if (!strcmp(arg, "--source")) {
        if (strcmp(val, "nn") && strcmp(val, "mc"))
            return usage_error("--source: '%s' is not nn or mc", val);
        o->source = val;
    } else if (!strcmp(arg, "--order")) {
        if (ns_order_parse(val, &o->order))
            return usage_error("--order: '%s' is not double or multiple", val);
        o->have_order = 1;
    } else if (!strcmp(arg, "--g")) {
        o->have_g = 1;
        return parse_num(arg, val, 0, 0.999999, &o->g);
    } else if (!strcmp(arg, "--albedo")) {
        o->have_albedo = 1;
        return parse_num(arg, val, 0, 0.999999, &o->albedo);
    } else if (!strcmp(arg, "--out"))
        o->out = val;
    else if (!strcmp(arg, "--weights-double"))
        o->weights[0] = val;
    else if (!strcmp(arg, "--weights-multiple"))
        o->weights[1] = val;
    else if (!strcmp(arg, "--device"))
        o->device = val;
    else if (!strcmp(arg, "--mc-dir"))
        o->mc_dir = val;
    else if (!strcmp(arg, "--materials"))
        o->materials = val;
    else if (!strcmp(arg, "--photons"))
        return parse_uint(arg, val, 1, (uint64_t)1e13, &o->photons);
    else if (!strcmp(arg, "--mc-collisions"))
        return parse_num(arg, val, 1e4, 1e12, &o->mc_collisions);
    else if (!strcmp(arg, "--seed"))
        return parse_uint(arg, val, 0, 9007199254740992ull, &o->seed);
    else if (!strcmp(arg, "--stride")) {
        return parse_stride(val, &o->sampling);
    } else if (!strcmp(arg, "--full-radius"))
        return parse_num(arg, val, 0, 1e6, &o->sampling.full_radius);
    else if (!strcmp(arg, "--runs")) {
        if (parse_uint(arg, val, 1, 100, &u))
            return 2;
        o->runs = (int)u;
    } else
        return usage_error("unknown option '%s' (see nscatter table --help)", arg);
    return 0;
}

static int parse_options(int argc, char **argv, table_options *o)
{
    memset(o, 0, sizeof *o);
    o->renormalise = 1;
    o->seed = 1;
    o->runs = 5;
    o->mc_collisions = 5e7;
    o->mc_dir = "data/report";
    o->sampling = ns_nn_sampling_default();
    for (int i = 1; i < argc; i++) {
        const char *arg = argv[i];
        if (!strcmp(arg, "--help") || !strcmp(arg, "-h")) {
            fputs(usage_text, stdout);
            return -1;
        }
        if (!strcmp(arg, "--no-renormalise"))
            o->renormalise = 0;
        else if (!strcmp(arg, "--every-cell"))
            o->sampling = ns_nn_sampling_every_cell();
        else if (!strcmp(arg, "--report"))
            o->report = 1;
        else if (!strcmp(arg, "--benchmark"))
            o->benchmark = 1;
        else if (!strcmp(arg, "--compare")) {
            if (i + 2 >= argc)
                return usage_error("--compare: needs two table prefixes");
            o->compare[0] = argv[++i];
            o->compare[1] = argv[++i];
        } else if (strncmp(arg, "--", 2) != 0)
            return usage_error("unexpected argument '%s' (see nscatter table --help)", arg);
        else if (i + 1 >= argc)
            return usage_error("%s: missing value", arg);
        else if (parse_value(o, arg, argv[++i]))
            return 2;
    }
    return 0;
}

/* =======================================================================================
 * GPU and weights
 * ===================================================================================== */

typedef struct {
    ns_nn_session *session;
    const ns_nn_weights *nets[2];
} nn_session;

static int session_open(const table_options *o, nn_session *s)
{
    memset(s, 0, sizeof *s);
    ns_error err = {0};
    const char *validation = getenv("NSCATTER_VALIDATION");
    int rc =
        ns_nn_session_create(&(ns_nn_session_desc){.device = o->device,
                                                   .validation = validation && *validation == '1',
                                                   .weights = {o->weights[0], o->weights[1]}},
                             &s->session, &err);
    if (rc) {
        fprintf(stderr, "nscatter table: %s\n", err.message);
        /* A bad weights file is bad input (2); a device failure is a failure (1). */
        return rc == NS_ERR_INVALID_ARGUMENT || rc == NS_ERR_IO || rc == NS_ERR_NOT_AVAILABLE ? 2
                                                                                              : 1;
    }
    s->nets[0] = ns_nn_session_net(s->session, 0);
    s->nets[1] = ns_nn_session_net(s->session, 1);
    return 0;
}

static void session_close(nn_session *s)
{
    ns_nn_session_destroy(s->session);
    s->session = NULL;
}

static int default_table(ns_table *t, ns_order order, double g, double albedo)
{
    const uint32_t n[4] = {NS_TABLE_NZ, NS_TABLE_NRHO, NS_TABLE_NTHETA, NS_TABLE_NPHI};
    ns_error err = {0};
    if (ns_table_create(t, n, &err)) {
        fprintf(stderr, "nscatter table: %s\n", err.message);
        return 1;
    }
    ns_mc_default_edges(t);
    t->order = order;
    t->g = g;
    t->albedo = albedo;
    t->energy_expected = ns_mc_expected_energy(order, albedo);
    return 0;
}

static ns_nn_grid grid_of(const ns_table *t)
{
    ns_nn_grid g;
    for (int a = 0; a < 4; a++)
        g.n[a] = t->n[a], g.edges[a] = t->edges[a];
    return g;
}

/* Both orders, three channels; *out is malloc'ed [2][3][cells]. */
static int reconstruct(nn_session *s, const ns_table *shape, double g, const double albedo[3],
                       uint32_t channels, int renormalise, const ns_nn_sampling *sampling,
                       float **out, ns_nn_reconstruct_stats *stats)
{
    size_t cells = ns_table_size(shape);
    *out = malloc(cells * 6 * sizeof(float));
    if (!*out)
        return usage_error("out of memory");
    ns_error err = {0};
    ns_nn_reconstruct_desc d = {.nets = {s->nets[0], s->nets[1]},
                                .grid = grid_of(shape),
                                .g = g,
                                .albedo = {albedo[0], albedo[1], albedo[2]},
                                .renormalise = renormalise,
                                .channels = channels,
                                .out = *out,
                                .sampling = sampling};
    if (ns_nn_session_reconstruct(s->session, &d, stats, &err)) {
        fprintf(stderr, "nscatter table: %s\n", err.message);
        free(*out);
        *out = NULL;
        return 1;
    }
    return 0;
}

/* =======================================================================================
 * One table
 * ===================================================================================== */

static int run_mc_table(const table_options *o, ns_table *t)
{
    uint64_t photons =
        o->photons
            ? o->photons
            : (uint64_t)fmax(1000, o->mc_collisions /
                                       ns_mc_collisions_per_photon(1u << o->order, o->albedo));
    ns_mc_desc desc = {.g = o->g,
                       .albedo = o->albedo,
                       .photons = photons,
                       .seed = o->seed,
                       .orders = 1u << o->order};
    ns_error err = {0};
    ns_mc_result r;
    if (ns_mc_run(&desc, &r, &err)) {
        fprintf(stderr, "nscatter table: %s\n", err.message);
        return 1;
    }
    *t = r.table[o->order];
    memset(&r.table[o->order], 0, sizeof r.table[o->order]); /* ownership moves to *t */
    ns_mc_result_free(&r);
    return 0;
}

static int run_one(const table_options *o)
{
    if (!o->source)
        return usage_error("--source: missing (nn or mc)");
    if (!o->have_order || !o->have_g || !o->have_albedo || !o->out)
        return usage_error("%s: missing", !o->have_order    ? "--order"
                                          : !o->have_g      ? "--g"
                                          : !o->have_albedo ? "--albedo"
                                                            : "--out");
    ns_error err = {0};
    if (ns_table_check_writable(o->out, &err))
        return usage_error("--out: %s", err.message);
    ns_table t;
    memset(&t, 0, sizeof t);
    int rc;
    if (!strcmp(o->source, "mc")) {
        rc = run_mc_table(o, &t);
    } else {
        nn_session s;
        rc = session_open(o, &s);
        if (!rc)
            rc = default_table(&t, o->order, o->g, o->albedo);
        float *all = NULL;
        ns_nn_reconstruct_stats st;
        double albedo[3] = {o->albedo, o->albedo, o->albedo};
        if (!rc)
            rc = reconstruct(&s, &t, o->g, albedo, 1, o->renormalise, &o->sampling, &all, &st);
        if (!rc) {
            memcpy(t.data, all + (size_t)o->order * 3 * ns_table_size(&t),
                   ns_table_size(&t) * sizeof(float));
            snprintf(t.source, sizeof t.source, "nn");
            fprintf(stderr,
                    "nscatter table: reconstructed in %.3f s (GPU %.3f s, %s), raw "
                    "energy %.6g of %.6g\n",
                    st.total_seconds, st.gpu_seconds, ns_nn_session_device(s.session),
                    st.energy_raw[o->order][0], st.energy_exact[o->order][0]);
        } else if (t.data) {
            ns_table_free(&t);
        }
        free(all);
        session_close(&s);
    }
    if (rc)
        return rc;
    t.energy_captured = ns_table_energy(&t);
    rc = ns_table_write(&t, o->out, &err);
    if (rc)
        fprintf(stderr, "nscatter table: %s\n", err.message);
    else
        printf("%s: %s %s g=%g albedo=%g energy %.6g of %.6g\n", o->out, t.source,
               ns_order_name(t.order), t.g, t.albedo, t.energy_captured, t.energy_expected);
    ns_table_free(&t);
    return rc ? 1 : 0;
}

/* =======================================================================================
 * Accuracy report
 * ===================================================================================== */

static const double report_default[][2] = {
    {0.45, 0.87}, {0.75, 0.97}, {0.15, 0.5}, {0.92, 0.995}, {0.3, 0.1},
};

/* Energy-weighted L1 distance (the paper's Fig. 18): sum |J_nn - J_mc| dV dOmega over the
 * energy of the MC table. */
static double weighted_l1_to(const ns_table *shape, const float *ref_j, const float *j)
{
    double diff = 0.0, ref = 0.0;
    size_t c = 0;
    for (uint32_t iz = 0; iz < shape->n[0]; iz++)
        for (uint32_t ir = 0; ir < shape->n[1]; ir++) {
            double vol = ns_table_bin_volume(shape, iz, ir);
            for (uint32_t it = 0; it < shape->n[2]; it++)
                for (uint32_t ip = 0; ip < shape->n[3]; ip++, c++) {
                    double w = vol * ns_table_bin_solid_angle(shape, it, ip);
                    diff += fabs((double)j[c] - ref_j[c]) * w;
                    ref += ref_j[c] * w;
                }
        }
    return ref > 0 ? diff / ref : NAN;
}

static double weighted_l1(const ns_table *mc, const float *nn)
{
    return weighted_l1_to(mc, mc->data, nn);
}

static int samples_every_cell(const ns_nn_sampling *s)
{
    return s->stride[0] == 1 && s->stride[1] == 1 && s->stride[2] == 1 && s->stride[3] == 1;
}

static int reference_table(const table_options *o, double g, double a, ns_order order, ns_table *t)
{
    char prefix[4096];
    snprintf(prefix, sizeof prefix, "%s/g%.2f_a%.3f_%s", o->mc_dir, g, a, ns_order_name(order));
    ns_error err = {0};
    if (ns_table_is_complete(prefix) && !ns_table_read(prefix, t, &err))
        return 0;
    mkdir(o->mc_dir, 0755);
    table_options m = *o;
    m.g = g, m.albedo = a, m.order = order, m.photons = 0, m.seed = 12345;
    fprintf(stderr, "nscatter table: Monte Carlo reference %s (%.0e collisions)...\n", prefix,
            o->mc_collisions);
    if (run_mc_table(&m, t))
        return 1;
    if (ns_table_write(t, prefix, &err))
        fprintf(stderr, "nscatter table: warning: cannot cache %s: %s\n", prefix, err.message);
    return 0;
}

static int parse_materials(const char *text, double (*m)[2], int cap, int *count)
{
    if (!*text)
        return usage_error("--materials: empty list");
    const char *cursor = text;
    char item[64];
    int r;
    *count = 0;
    while ((r = cli_list_next(&cursor, item, sizeof item)) != 0) {
        if (r < 0)
            return usage_error("--materials: '%s' has an empty or overlong item", text);
        if (*count >= cap)
            return usage_error("--materials: '%s' has more than %d materials", text, cap);
        double *g = &m[*count][0], *a = &m[*count][1];
        if (cli_number_pair(item, ':', g, a) || !(*g >= 0 && *g < 1 && *a >= 0 && *a < 1))
            return usage_error("--materials: '%s' is not G:A with G, A in [0, 1)", item);
        (*count)++;
    }
    return 0;
}

static int report_material(const table_options *o, nn_session *s, double g, double a)
{
    ns_table mc[2];
    if (reference_table(o, g, a, NS_ORDER_DOUBLE, &mc[0]))
        return 1;
    if (reference_table(o, g, a, NS_ORDER_MULTIPLE, &mc[1])) {
        ns_table_free(&mc[0]);
        return 1;
    }
    double albedo[3] = {a, a, a};
    float *raw = NULL, *every = NULL;
    ns_nn_reconstruct_stats st, st_every;
    int rc = reconstruct(s, &mc[0], g, albedo, 1, 0, &o->sampling, &raw, &st);
    ns_nn_sampling all = ns_nn_sampling_every_cell();
    if (!rc && !samples_every_cell(&o->sampling))
        rc = reconstruct(s, &mc[0], g, albedo, 1, 0, &all, &every, &st_every);
    for (int k = 0; k < 2 && !rc; k++) {
        size_t cells = ns_table_size(&mc[k]);
        float *j = raw + (size_t)k * 3 * cells;
        /* The interpolation's own error: sampled against every cell, both raw. */
        double l1_every = every ? weighted_l1_to(&mc[k], every + (size_t)k * 3 * cells, j) : 0.0;
        double exact = ns_mc_expected_energy((ns_order)k, a);
        double e_raw = st.energy_raw[k][0];
        double l1_raw = weighted_l1(&mc[k], j);
        for (size_t i = 0; i < cells; i++)
            j[i] = (float)(j[i] * (exact / e_raw));
        double l1_norm = weighted_l1(&mc[k], j);
        double mc_energy = ns_table_energy(&mc[k]);
        printf("%5.2f %6.3f %-8s %+9.2f%% %+9.2f%% %9.2f%% %9.2f%%  %7.2f%% %9.3f%%\n", g, a,
               ns_order_name((ns_order)k), 100 * (e_raw / exact - 1), 100 * (e_raw / mc_energy - 1),
               100 * l1_raw, 100 * l1_norm, 100 * mc_energy / exact, 100 * l1_every);
        fflush(stdout);
    }
    free(raw);
    free(every);
    ns_table_free(&mc[0]);
    ns_table_free(&mc[1]);
    return rc;
}

static int run_report(const table_options *o)
{
    double mats[32][2];
    int count = (int)(sizeof report_default / sizeof report_default[0]);
    memcpy(mats, report_default, sizeof report_default);
    if (o->materials && parse_materials(o->materials, mats, 32, &count))
        return 2;
    nn_session s;
    int rc = session_open(o, &s);
    if (rc)
        return rc;
    printf("device: %s; weights: %s, %s\n", ns_nn_session_device(s.session),
           o->weights[0] ? o->weights[0] : "built-in", o->weights[1] ? o->weights[1] : "built-in");
    printf("energy error: NN table (no renormalisation) vs exact a^k and vs the MC table; L1: "
           "energy-weighted |NN - MC| / MC energy, raw and renormalised; MC captured: MC "
           "table energy / exact; L1 sampled: L1 of the sampled NN table against the NN evaluated "
           "at every cell (raw)\n");
    printf("sampling: stride %u,%u,%u,%u, every z and rho bin within %g mfp\n",
           o->sampling.stride[0], o->sampling.stride[1], o->sampling.stride[2],
           o->sampling.stride[3], o->sampling.full_radius);
    printf("%5s %6s %-8s %10s %10s %10s %10s %9s %10s\n", "g", "albedo", "order", "E vs exact",
           "E vs MC", "L1 raw", "L1 renorm", "MC capt.", "L1 sampled");
    for (int i = 0; i < count && !rc; i++)
        rc = report_material(o, &s, mats[i][0], mats[i][1]);
    session_close(&s);
    return rc;
}

/* =======================================================================================
 * Benchmark
 * ===================================================================================== */

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* CPU seconds of this process, all threads. On a shared machine wall time stretches with
 * the other processes' load, CPU time much less: CPU time / cores estimates the wall time
 * on the idle machine. */
static double process_cpu_seconds(void)
{
    struct rusage u;
    getrusage(RUSAGE_SELF, &u);
    return (double)u.ru_utime.tv_sec + 1e-6 * (double)u.ru_utime.tv_usec +
           (double)u.ru_stime.tv_sec + 1e-6 * (double)u.ru_stime.tv_usec;
}

/* Random normalised inputs in [0, 1). */
static void random_inputs(float *x, size_t n)
{
    uint64_t s = 42;
    for (size_t i = 0; i < n * NS_NN_INPUTS; i++) {
        s = s * 6364136223846793005ull + 1442695040888963407ull;
        x[i] = (float)((s >> 40) * 0x1.0p-24);
    }
}

/* Plain scalar forward pass, one thread: evaluations per second. */
static double cpu_scalar_rate(const ns_nn_weights *w, const float *x, uint32_t n)
{
    volatile float sink = 0;
    double t0 = now_s();
    for (uint32_t i = 0; i < n; i++)
        sink += ns_nn_forward(w, x + (size_t)i * NS_NN_INPUTS);
    (void)sink;
    return n / (now_s() - t0);
}

typedef struct {
    const ns_nn_weights *w;
    const float *x;
    uint32_t n;
    int status;
} blas_chunk;

enum { BLAS_BATCH = 8192, BLAS_THREADS = 2 };

/* One thread's chunk through the trainer's OpenBLAS forward pass (single-threaded BLAS). */
static void *blas_chunk_run(void *arg)
{
    blas_chunk *c = arg;
    ns_nn_trainer tr;
    c->status = ns_nn_trainer_init(&tr, BLAS_BATCH);
    if (c->status)
        return NULL;
    for (uint32_t i = 0; i < c->n; i += BLAS_BATCH)
        ns_nn_batch_forward(&tr, c->w->p, c->x + (size_t)i * NS_NN_INPUTS,
                            c->n - i < BLAS_BATCH ? c->n - i : BLAS_BATCH, NULL);
    ns_nn_trainer_free(&tr);
    return NULL;
}

/* OpenBLAS forward on BLAS_THREADS threads, each its own chunk with single-threaded BLAS
 * (DESIGN.md section 6: faster than letting OpenBLAS thread each call). NAN on failure. */
static double cpu_blas_rate(const ns_nn_weights *w, const float *x, uint32_t n, double *cpu_rate)
{
    openblas_set_num_threads(1);
    blas_chunk chunk[BLAS_THREADS];
    pthread_t thread[BLAS_THREADS];
    uint32_t per = n / BLAS_THREADS;
    int started = 0;
    double t0 = now_s(), c0 = process_cpu_seconds();
    for (int t = 0; t < BLAS_THREADS; t++) {
        chunk[t] = (blas_chunk){.w = w, .x = x + (size_t)t * per * NS_NN_INPUTS, .n = per};
        if (pthread_create(&thread[t], NULL, blas_chunk_run, &chunk[t]) == 0)
            started++;
        else
            break;
    }
    int ok = started == BLAS_THREADS;
    for (int t = 0; t < started; t++) {
        pthread_join(thread[t], NULL);
        ok = ok && !chunk[t].status;
    }
    double evals = per * (double)BLAS_THREADS;
    *cpu_rate = ok ? evals / (process_cpu_seconds() - c0) : NAN;
    return ok ? evals / (now_s() - t0) : NAN;
}

static double median(double *v, int n)
{
    qsort(v, (size_t)n, sizeof(double), cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

typedef struct {
    double gpu, total; /* medians, s */
    double cpu;        /* process CPU time per reconstruction (all threads, lavapipe's too) */
    ns_nn_reconstruct_stats last;
} timing;

static int time_reconstruction(nn_session *s, const ns_table *shape, const table_options *o,
                               const ns_nn_sampling *sampling, timing *t)
{
    const double albedo[3] = {0.97, 0.95, 0.9};
    double gpu[100], total[100], cpu0 = process_cpu_seconds();
    for (int r = 0; r < o->runs; r++) {
        float *out = NULL;
        int rc = reconstruct(s, shape, 0.75, albedo, 3, o->renormalise, sampling, &out, &t->last);
        free(out);
        if (rc)
            return rc;
        gpu[r] = t->last.gpu_seconds, total[r] = t->last.total_seconds;
    }
    t->cpu = (process_cpu_seconds() - cpu0) / o->runs;
    t->gpu = median(gpu, o->runs);
    t->total = median(total, o->runs);
    return 0;
}

static void print_timing(const char *label, const timing *t, double flops)
{
    double rate = t->last.evaluations / t->gpu;
    printf("%s: %llu network evaluations for %llu cells; median %.3f s on the GPU queue, "
           "%.3f s in all; %.3g evaluations/s (%.1f GFLOP/s), %.3g cells/s; process CPU "
           "time %.3f s per reconstruction (/ %ld cores = %.3f s)\n",
           label, (unsigned long long)t->last.evaluations, (unsigned long long)t->last.cells,
           t->gpu, t->total, rate, rate * flops * 1e-9, t->last.cells / t->total, t->cpu,
           sysconf(_SC_NPROCESSORS_ONLN), t->cpu / (double)sysconf(_SC_NPROCESSORS_ONLN));
}

static int run_benchmark(const table_options *o)
{
    nn_session s;
    double t0 = now_s();
    int rc = session_open(o, &s);
    if (rc)
        return rc;
    double startup = now_s() - t0;
    ns_table shape;
    if (default_table(&shape, NS_ORDER_DOUBLE, 0.75, 0.97)) {
        session_close(&s);
        return 1;
    }
    ns_nn_sampling every = ns_nn_sampling_every_cell();
    timing sampled = {0}, full = {0};
    double load[2][3] = {{0}};
    getloadavg(load[0], 3);
    rc = time_reconstruction(&s, &shape, o, &o->sampling, &sampled);
    if (!rc && !samples_every_cell(&o->sampling))
        rc = time_reconstruction(&s, &shape, o, &every, &full);
    const uint32_t n = 1u << 18;
    float *x = rc ? NULL : malloc((size_t)n * NS_NN_INPUTS * sizeof(float));
    if (!rc && !x)
        rc = usage_error("out of memory");
    if (!rc) {
        random_inputs(x, n);
        double scalar = cpu_scalar_rate(s.nets[0], x, n / 4);
        double blas_runs[3], blas_cpu_runs[3];
        for (int r = 0; r < 3; r++)
            blas_runs[r] = cpu_blas_rate(s.nets[0], x, n, &blas_cpu_runs[r]);
        double blas = median(blas_runs, 3);
        double blas_idle = median(blas_cpu_runs, 3) * BLAS_THREADS; /* per CPU s x threads */
        double flops = 2.0 * (NS_NN_PARAMS - 1 - 2 * NS_NN_HIDDEN); /* multiply-adds x 2 */
        getloadavg(load[1], 3);
        printf("device: %s (pipeline created and warmed in %.2f s); load average %.2f at the "
               "start, %.2f at the end (1 min)\n",
               ns_nn_session_device(s.session), startup, load[0][0], load[1][0]);
        printf("RGB material g 0.75, albedo 0.97/0.95/0.9: both orders, %u x %u x %u x %u cells "
               "x 3 channels x 2 orders; times include readback, energy sums%s\n",
               shape.n[0], shape.n[1], shape.n[2], shape.n[3],
               o->renormalise ? ", renormalisation" : "");
        char label[160];
        snprintf(label, sizeof label, "sampled (stride %u,%u,%u,%u, full radius %g mfp)",
                 o->sampling.stride[0], o->sampling.stride[1], o->sampling.stride[2],
                 o->sampling.stride[3], o->sampling.full_radius);
        print_timing(label, &sampled, flops);
        if (full.last.cells)
            print_timing("every cell", &full, flops);
        printf("CPU plain C, 1 thread: %.3g evaluations/s (%.1f GFLOP/s)\n", scalar,
               scalar * flops * 1e-9);
        printf("CPU OpenBLAS, %d threads each its own chunk, single-threaded BLAS, batch %d "
               "(median of 3): %.3g evaluations/s (%.1f GFLOP/s); from its CPU time, on %d idle "
               "cores: %.3g evaluations/s (%.1f GFLOP/s); the sampled table's evaluations "
               "would take %.2f s, every cell %.2f s\n",
               BLAS_THREADS, BLAS_BATCH, blas, blas * flops * 1e-9, BLAS_THREADS, blas_idle,
               blas_idle * flops * 1e-9, sampled.last.evaluations / blas_idle,
               sampled.last.cells / blas_idle);
    }
    free(x);
    ns_table_free(&shape);
    session_close(&s);
    return rc;
}

static int run_compare(const table_options *o)
{
    ns_table t[2];
    ns_error err = {0};
    for (int i = 0; i < 2; i++)
        if (ns_table_read(o->compare[i], &t[i], &err)) {
            if (i)
                ns_table_free(&t[0]);
            return usage_error("--compare: %s", err.message);
        }
    int rc = 0;
    for (int a = 0; a < 4 && !rc; a++)
        if (t[0].n[a] != t[1].n[a] ||
            memcmp(t[0].edges[a], t[1].edges[a], (t[0].n[a] + 1) * sizeof(double)))
            rc = usage_error("--compare: the tables' bins differ (axis %d)", a);
    if (!rc)
        printf("energy A %.6g, B %.6g (exact %.6g); energy-weighted L1 |A - B| / B: %.2f%%\n",
               ns_table_energy(&t[0]), ns_table_energy(&t[1]), t[1].energy_expected,
               100 * weighted_l1(&t[1], t[0].data));
    ns_table_free(&t[0]);
    ns_table_free(&t[1]);
    return rc;
}

int cmd_table(int argc, char **argv)
{
    table_options o;
    int rc = parse_options(argc, argv, &o);
    if (rc)
        return rc < 0 ? 0 : rc;
    if (o.report + o.benchmark + !!o.compare[0] > 1)
        return usage_error("--report, --benchmark and --compare are separate runs");
    if (o.compare[0])
        return run_compare(&o);
    if (o.report)
        return run_report(&o);
    if (o.benchmark)
        return run_benchmark(&o);
    return run_one(&o);
}
