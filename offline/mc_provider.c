/* mc_provider.c — Monte Carlo tables for method "table", computed with offline/mc.h and kept
 * on disk (see mc_provider.h). */
#include "mc_provider.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "mc.h"
#include "table_io.h"

#define DIR_CAP 3000
#define PATH_CAP 4096
#define CELLS ((size_t)NS_TABLE_CELLS) /* floats in one table (render/include/table_grid.h) */

struct ns_mc_provider {
    char dir[DIR_CAP];
    double collisions;
    unsigned threads, lobe_in, lobe_out;
    ns_mc_provider_counts counts;
    /* The last double table seen, divided by its a^2: the double table of any albedo of
     * unit_g is this times a^2 (see mc_provider.h). */
    float *unit_double;
    double unit_g;
};

int ns_mc_provider_create(const ns_mc_provider_desc *desc, ns_mc_provider **out, ns_error *err)
{
    *out = NULL;
    ns_mc_provider_desc defaults = {0};
    if (!desc)
        desc = &defaults;
    if (!(desc->collisions >= 0) || desc->collisions > 1e15)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "Monte Carlo cache: collisions %g (0 to 1e15)",
                    desc->collisions);
    ns_mc_provider *p = calloc(1, sizeof *p);
    if (!p)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "Monte Carlo cache: out of memory");
    int status = ns_cache_dir(desc->cache_dir, "Monte Carlo cache", p->dir, sizeof p->dir, err);
    if (status) {
        free(p);
        return status;
    }
    p->collisions = desc->collisions > 0 ? desc->collisions : NS_MC_PROVIDER_COLLISIONS;
    p->threads = desc->threads;
    p->lobe_in = desc->lobe_in_samples;
    p->lobe_out = desc->lobe_out_samples;
    *out = p;
    return NS_OK;
}

void ns_mc_provider_destroy(ns_mc_provider *p)
{
    if (p)
        free(p->unit_double);
    free(p);
}

const char *ns_mc_provider_dir(const ns_mc_provider *p)
{
    return p->dir;
}

void ns_mc_provider_get_counts(const ns_mc_provider *p, ns_mc_provider_counts *out)
{
    *out = p->counts;
}

static ns_mc_provider *process_provider;

static void free_process_provider(void)
{
    ns_mc_provider_destroy(process_provider);
    process_provider = NULL;
}

void ns_mc_provider_attach(ns_context_desc *desc)
{
    if (!process_provider) {
        ns_error err = {0};
        if (ns_mc_provider_create(NULL, &process_provider, &err)) {
            fprintf(stderr, "nscatter: method \"table\" unavailable: %s\n", err.message);
            return;
        }
        atexit(free_process_provider);
    }
    desc->mc_tables = ns_mc_provider_tables;
    desc->mc_user = process_provider;
}

void ns_table_caches_attach(ns_context_desc *desc)
{
    ns_mc_provider_attach(desc);
    if (process_provider)
        desc->table_node_dir = process_provider->dir;
}

/* ---------------------------------------------------------------------------------------
 * One order's table: read and check, or simulate and write
 * ------------------------------------------------------------------------------------- */
/* Photons of one order's simulation at the budget (as `nscatter mc --grid` plans them). */
static uint64_t budget_photons(const ns_mc_provider *p, ns_order order, double albedo)
{
    double per = ns_mc_collisions_per_photon(1u << order, albedo);
    double n = floor(p->collisions / per);
    return n < 1000 ? 1000 : (uint64_t)n;
}

static void file_prefix(const ns_mc_provider *p, double g, double albedo, ns_order order,
                        char *prefix)
{
    snprintf(prefix, PATH_CAP, "%s/mc_g%.17g_a%.17g_%s", p->dir, g, albedo, ns_order_name(order));
}

static int near(double a, double b, double rel)
{
    return fabs(a - b) <= rel * fmax(fabs(a), fabs(b));
}

/* Why the table read from disk cannot be used for (g, albedo, order), or NULL. */
static const char *cache_file_problem(const ns_table *t, double g, double albedo, ns_order order,
                                      uint64_t photons)
{
    static const uint32_t n[NS_AXIS_COUNT] = {NS_TABLE_NZ, NS_TABLE_NRHO, NS_TABLE_NTHETA,
                                              NS_TABLE_NPHI};
    for (int a = 0; a < NS_AXIS_COUNT; a++)
        if (t->n[a] != n[a])
            return "its shape is not the default grid's";
    ns_table ref = {0};
    if (ns_table_create(&ref, n, NULL))
        return "out of memory while checking it";
    ns_mc_default_edges(&ref);
    const char *problem = NULL;
    for (int a = 0; a < NS_AXIS_COUNT && !problem; a++)
        for (uint32_t i = 0; i <= n[a] && !problem; i++)
            if (!near(t->edges[a][i], ref.edges[a][i], 1e-12) && fabs(ref.edges[a][i]) > 1e-300)
                problem = "its bin edges are not the default grid's";
    ns_table_free(&ref);
    if (problem)
        return problem;
    if (t->order != order || strcmp(t->source, "mc") != 0)
        return "it holds another order or source";
    if (!near(t->g, g, 1e-15) && t->g != g)
        return "it holds another g";
    if (!near(t->albedo, albedo, 1e-15) && t->albedo != albedo)
        return "it holds another albedo";
    if (t->photons != photons)
        return "it was made with another photon budget";
    for (size_t i = 0; i < CELLS; i++)
        if (!(t->data[i] >= 0.0f) || isinf(t->data[i]))
            return "it holds a negative or non-finite value";
    /* The energy recorded at write time against the data now: a changed value shows. */
    double energy = ns_table_energy(t);
    if (!near(energy, t->energy_captured, 1e-6) && !(energy == 0 && t->energy_captured == 0))
        return "its data do not match its recorded energy";
    return NULL;
}

/* Keeps the double table of (g, albedo) per unit a^2 for the other albedos of g. */
static void remember_double(ns_mc_provider *p, double g, double albedo, const float *j)
{
    if (!(albedo > 0.0))
        return;
    if (!p->unit_double && !(p->unit_double = malloc(CELLS * sizeof(float))))
        return; /* only an optimisation */
    float k = (float)(1.0 / (albedo * albedo));
    for (size_t i = 0; i < CELLS; i++)
        p->unit_double[i] = j[i] * k;
    p->unit_g = g;
}

/* The double table of (g, albedo) from the remembered one, as a table to write and serve;
 * 0 when there is none for this g. */
static int rescale_double(ns_mc_provider *p, double g, double albedo, ns_table *t)
{
    static const uint32_t n[NS_AXIS_COUNT] = {NS_TABLE_NZ, NS_TABLE_NRHO, NS_TABLE_NTHETA,
                                              NS_TABLE_NPHI};
    if (!p->unit_double || p->unit_g != g || ns_table_create(t, n, NULL))
        return 0;
    ns_mc_default_edges(t);
    t->order = NS_ORDER_DOUBLE;
    t->g = g;
    t->albedo = albedo;
    t->photons = budget_photons(p, NS_ORDER_DOUBLE, albedo);
    t->seed = NS_MC_PROVIDER_SEED;
    float k = (float)(albedo * albedo);
    for (size_t i = 0; i < CELLS; i++)
        t->data[i] = p->unit_double[i] * k;
    t->energy_expected = ns_mc_expected_energy(NS_ORDER_DOUBLE, albedo);
    t->energy_captured = ns_table_energy(t);
    return 1;
}

/* 1 and out filled when a usable cache file exists; 0 otherwise (missing or rejected). */
static int read_cached(ns_mc_provider *p, double g, double albedo, ns_order order, float *out)
{
    char prefix[PATH_CAP];
    file_prefix(p, g, albedo, order, prefix);
    char json[PATH_CAP + 8];
    snprintf(json, sizeof json, "%s.json", prefix);
    struct stat st;
    if (stat(json, &st) != 0)
        return 0;
    ns_table t = {0};
    ns_error err = {0};
    const char *problem = NULL;
    if (ns_table_read(prefix, &t, &err))
        problem = err.message;
    else
        problem = cache_file_problem(&t, g, albedo, order, budget_photons(p, order, albedo));
    if (problem) {
        fprintf(stderr, "nscatter: Monte Carlo cache file %s rejected (%s); recomputing\n", json,
                problem);
        p->counts.files_rejected++;
    } else {
        memcpy(out, t.data, CELLS * sizeof(float));
        p->counts.files_read++;
    }
    ns_table_free(&t);
    return problem == NULL;
}

static void write_cached(ns_mc_provider *p, const ns_table *t, double g, double albedo,
                         ns_order order)
{
    char prefix[PATH_CAP];
    file_prefix(p, g, albedo, order, prefix);
    ns_error err = {0};
    int status = ns_make_dirs(p->dir, "Monte Carlo cache", &err);
    if (!status)
        status = ns_table_write(t, prefix, &err);
    if (status) {
        /* The render still gets its table; only the next one pays again. */
        fprintf(stderr, "nscatter: %s\n", err.message);
        p->counts.write_failures++;
    }
}

static int simulate(ns_mc_provider *p, double g, double albedo, ns_order order, const double *lobe,
                    float *out, ns_error *err)
{
    ns_mc_desc desc = {.g = g,
                       .albedo = albedo,
                       .photons = budget_photons(p, order, albedo),
                       .seed = NS_MC_PROVIDER_SEED,
                       .orders = 1u << order,
                       .threads = p->threads,
                       .lobe_in_samples = p->lobe_in,
                       .lobe_out_samples = p->lobe_out,
                       .lobe = lobe};
    ns_mc_result r;
    int status = ns_mc_run(&desc, &r, err);
    if (status)
        return status;
    p->counts.simulations++;
    memcpy(out, r.table[order].data, CELLS * sizeof(float));
    if (order == NS_ORDER_DOUBLE)
        remember_double(p, g, albedo, out);
    write_cached(p, &r.table[order], g, albedo, order);
    ns_mc_result_free(&r);
    return NS_OK;
}

int ns_mc_provider_tables(void *user, double g, double albedo, float *j_double, float *j_multiple,
                          ns_error *err)
{
    ns_mc_provider *p = user;
    ns_mc_desc check = {.g = g, .albedo = albedo, .photons = 1, .orders = NS_MC_WANT_DOUBLE};
    int status = ns_mc_check_desc(&check, err);
    if (status)
        return status;
    float *out[2] = {j_double, j_multiple};
    int have[2];
    for (int o = 0; o < 2; o++)
        have[o] = read_cached(p, g, albedo, (ns_order)o, out[o]);
    if (have[0])
        remember_double(p, g, albedo, j_double);
    ns_table rescaled;
    if (!have[0] && rescale_double(p, g, albedo, &rescaled)) {
        memcpy(j_double, rescaled.data, CELLS * sizeof(float));
        write_cached(p, &rescaled, g, albedo, NS_ORDER_DOUBLE);
        ns_table_free(&rescaled);
        p->counts.doubles_rescaled++;
        have[0] = 1;
    }
    if (have[0] && have[1])
        return NS_OK;
    /* The lobe matrix depends on g only: one for both orders. */
    double *lobe = malloc((size_t)NS_MC_NDIR * NS_MC_NDIR * sizeof(double));
    if (!lobe)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "Monte Carlo: out of memory");
    ns_mc_lobe_matrix(g, p->lobe_in, p->lobe_out, p->threads, lobe);
    for (int o = 0; o < 2 && !status; o++)
        if (!have[o])
            status = simulate(p, g, albedo, (ns_order)o, lobe, out[o], err);
    free(lobe);
    return status;
}
