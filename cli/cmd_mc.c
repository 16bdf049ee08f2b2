/* mc_cli.c — `nscatter mc`: one material's tables, the training grid, or a benchmark. */
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "commands.h"
#include "args.h"
#include "mc.h"
#include "table_io.h"

/* The training grid: the paper's 12 x 13 materials, albedo extended to 0.999 (its Milk). */
static const double grid_g_default[] = {0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6,
                                        0.7, 0.8, 0.9, 0.95, 0.99};
static const double grid_albedo_default[] = {0.01, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6,
                                             0.7,  0.8, 0.9, 0.95, 0.99, 0.995, 0.999};
#define GRID_MAX_VALUES 64
/* Collisions traced per table in grid mode: sets the noise (docs/montecarlo.md). */
#define GRID_DEFAULT_COLLISIONS 8e7
#define PREFIX_CAP 4000

static const char usage_text[] =
    "usage: nscatter mc --order double|multiple|both --g G --albedo A --photons N\n"
    "                   [--seed S] --out PREFIX [--threads T] [--quiet]\n"
    "       nscatter mc --grid --out DIR [--collisions C] [--g-values LIST]\n"
    "                   [--albedo-values LIST] [--seed S] [--threads T] [--quiet]\n"
    "       nscatter mc --benchmark [--threads T]\n"
    "       lobe matrix quality (tests): [--lobe-in N (default 8)] [--lobe-out N (default 128)]\n"
    "\n"
    "Monte Carlo J tables (DESIGN.md sections 2-3): PREFIX.npy + PREFIX.json per order\n"
    "(--order both writes PREFIX_double.* and PREFIX_multiple.*). Grid mode writes\n"
    "DIR/g<G>_a<A>_<order>.* for every material, skips finished tables (resumable) and\n"
    "spends C collisions per simulation (default 8e7): one per multiple table,\n"
    "one per g for all the double tables (double scattering scales as a^2). LIST: comma-separated numbers.\n";

typedef struct {
    int grid, benchmark, quiet;
    unsigned orders;
    double g, albedo, collisions;
    int have_g, have_albedo;
    uint64_t photons, seed;
    int have_photons;
    unsigned threads;
    unsigned lobe_in, lobe_out; /* lobe matrix quality; 0: defaults */
    const char *out;
    double g_values[GRID_MAX_VALUES], albedo_values[GRID_MAX_VALUES];
    int g_count, albedo_count;
} mc_options;

#define usage_error(...) cli_usage_error("nscatter mc", __VA_ARGS__)

/* =======================================================================================
 * Argument parsing: every number is checked whole; errors name the argument.
 * ===================================================================================== */

/* Numbers through args.h. --g and --albedo take any finite number here: their ranges are
 * ns_mc_check_desc's, which names them; the grid's lists are checked by grid_validate. */
static int parse_double(const char *name, const char *text, double *out)
{
    return cli_parse_number("nscatter mc", name, text, -INFINITY, INFINITY, out);
}

static int parse_u64(const char *name, const char *text, uint64_t lo, uint64_t hi, uint64_t *out)
{
    return cli_parse_uint("nscatter mc", name, text, lo, hi, out);
}

static int parse_list(const char *name, const char *text, double *values, int *count)
{
    size_t n = 0;
    int rc = cli_parse_number_list("nscatter mc", name, text, -INFINITY, INFINITY, values,
                                   GRID_MAX_VALUES, &n);
    if (!rc)
        *count = (int)n;
    return rc;
}

static int parse_order(const char *text, unsigned *orders)
{
    ns_order o;
    if (!strcmp(text, "both"))
        *orders = NS_MC_WANT_DOUBLE | NS_MC_WANT_MULTIPLE;
    else if (ns_order_parse(text, &o) == 0)
        *orders = 1u << o;
    else
        return usage_error("--order: '%s' is not double, multiple or both", text);
    return 0;
}

static int parse_value_option(mc_options *o, const char *arg, const char *val)
{
    uint64_t u = 0;
    if (!strcmp(arg, "--order"))
        return parse_order(val, &o->orders);
    if (!strcmp(arg, "--g"))
        return o->have_g = 1, parse_double(arg, val, &o->g);
    if (!strcmp(arg, "--albedo"))
        return o->have_albedo = 1, parse_double(arg, val, &o->albedo);
    if (!strcmp(arg, "--photons")) {
        if (parse_u64(arg, val, 1, (uint64_t)1e15, &o->photons))
            return 2;
        o->have_photons = 1;
        return 0;
    }
    if (!strcmp(arg, "--seed"))
        return parse_u64(arg, val, 0, 9007199254740992ull, &o->seed);
    if (!strcmp(arg, "--threads")) {
        if (parse_u64(arg, val, 1, 256, &u))
            return 2;
        o->threads = (unsigned)u;
        return 0;
    }
    if (!strcmp(arg, "--out"))
        return o->out = val, 0;
    if (!strcmp(arg, "--lobe-in") || !strcmp(arg, "--lobe-out")) {
        if (parse_u64(arg, val, 1, 256, &u))
            return 2;
        *(!strcmp(arg, "--lobe-in") ? &o->lobe_in : &o->lobe_out) = (unsigned)u;
        return 0;
    }
    if (!strcmp(arg, "--collisions"))
        return cli_parse_number("nscatter mc", arg, val, 1e3, 1e13, &o->collisions);
    if (!strcmp(arg, "--g-values"))
        return parse_list(arg, val, o->g_values, &o->g_count);
    if (!strcmp(arg, "--albedo-values"))
        return parse_list(arg, val, o->albedo_values, &o->albedo_count);
    return usage_error("unknown option '%s' (see nscatter mc --help)", arg);
}

static int parse_options(int argc, char **argv, mc_options *o)
{
    memset(o, 0, sizeof *o);
    o->orders = NS_MC_WANT_DOUBLE | NS_MC_WANT_MULTIPLE;
    o->seed = 1;
    o->collisions = GRID_DEFAULT_COLLISIONS;
    for (int i = 1; i < argc; i++) {
        const char *arg = argv[i];
        if (!strcmp(arg, "--help") || !strcmp(arg, "-h")) {
            fputs(usage_text, stdout);
            return -1;
        }
        if (!strcmp(arg, "--grid") || !strcmp(arg, "--benchmark") || !strcmp(arg, "--quiet")) {
            *(!strcmp(arg, "--grid") ? &o->grid : !strcmp(arg, "--benchmark") ? &o->benchmark
                                                                              : &o->quiet) = 1;
            continue;
        }
        if (strncmp(arg, "--", 2) != 0)
            return usage_error("unexpected argument '%s' (see nscatter mc --help)", arg);
        if (i + 1 >= argc)
            return usage_error("%s: missing value", arg);
        int rc = parse_value_option(o, arg, argv[++i]);
        if (rc)
            return rc;
    }
    return 0;
}

/* =======================================================================================
 * Progress: a bar with an ETA on a terminal, nothing otherwise.
 * ===================================================================================== */

typedef struct {
    int enabled;
    double start;            /* seconds */
    double work_before;      /* grid: collisions finished before this table */
    double work_this;        /* collisions this table will take */
    double work_total;       /* collisions of everything still to do in this run */
    const char *label;
} progress_state;

static double wall_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void progress_print(void *user, uint64_t done, uint64_t total)
{
    progress_state *p = user;
    if (!p->enabled || total == 0)
        return;
    double fraction = (p->work_before + p->work_this * (double)done / (double)total) /
                      (p->work_total > 0 ? p->work_total : 1.0);
    double elapsed = wall_seconds() - p->start;
    double eta = fraction > 1e-6 ? elapsed * (1.0 - fraction) / fraction : 0.0;
    char bar[31];
    int filled = (int)(fraction * 30.0 + 0.5);
    for (int i = 0; i < 30; i++)
        bar[i] = i < filled ? '#' : '.';
    bar[30] = '\0';
    fprintf(stderr, "\r%-28s [%s] %5.1f%%  %6.0f s, ETA %6.0f s ", p->label, bar,
            100.0 * fraction, elapsed, eta);
    fflush(stderr);
}

static void progress_end(progress_state *p)
{
    if (p->enabled)
        fprintf(stderr, "\n");
}

/* =======================================================================================
 * One material
 * ===================================================================================== */

static int table_prefix(char *out, size_t cap, const char *base, unsigned orders, ns_order o)
{
    int both = orders == (NS_MC_WANT_DOUBLE | NS_MC_WANT_MULTIPLE);
    int len = both ? snprintf(out, cap, "%s_%s", base, ns_order_name(o))
                   : snprintf(out, cap, "%s", base);
    return len < 0 || (size_t)len >= cap ? usage_error("--out: path too long") : 0;
}

static void print_summary(const char *prefix, const ns_mc_result *r, ns_order o)
{
    const ns_table *t = &r->table[o];
    const ns_mc_moments *m = &r->moments[o];
    /* Inside the bins, as a share of the energy these photons emitted: the truncation of
     * the table without the photon noise of the total. */
    double inside = m->energy > 0 ? 100.0 * m->energy_in_table / m->energy : 100.0;
    printf("%s: %s g=%g albedo=%g photons=%llu energy captured %.6g of %.6g (%.2f%%; "
           "%.2f%% of the traced energy), %.1f s, %.3g collisions/s\n",
           prefix, ns_order_name(o), t->g, t->albedo, (unsigned long long)t->photons,
           t->energy_captured, t->energy_expected,
           t->energy_expected > 0 ? 100.0 * t->energy_captured / t->energy_expected : 100.0,
           inside, r->total_seconds, (double)r->collisions / fmax(r->trace_seconds, 1e-9));
    fflush(stdout); /* a grid's log shows each table as it finishes */
}

static int write_tables(const ns_mc_result *r, const char *base, unsigned orders)
{
    for (int o = 0; o < 2; o++) {
        if (!(orders & (1u << o)))
            continue;
        char prefix[PREFIX_CAP];
        if (table_prefix(prefix, sizeof prefix, base, orders, (ns_order)o))
            return 2;
        ns_error err = {0};
        if (ns_table_write(&r->table[o], prefix, &err)) {
            fprintf(stderr, "nscatter mc: %s\n", err.message);
            return 1;
        }
        print_summary(prefix, r, (ns_order)o);
    }
    return 0;
}

static int run_single(const mc_options *o)
{
    if (!o->have_g)
        return usage_error("--g: missing (see nscatter mc --help)");
    if (!o->have_albedo)
        return usage_error("--albedo: missing");
    if (!o->have_photons)
        return usage_error("--photons: missing");
    if (!o->out)
        return usage_error("--out: missing");
    ns_mc_desc desc = {.g = o->g, .albedo = o->albedo, .photons = o->photons, .seed = o->seed,
                       .orders = o->orders, .threads = o->threads,
                       .lobe_in_samples = o->lobe_in, .lobe_out_samples = o->lobe_out};
    ns_error err = {0};
    if (ns_mc_check_desc(&desc, &err))
        return usage_error("%s", err.message);
    /* Fail before the simulation if the output cannot be written. */
    for (int k = 0; k < 2; k++) {
        char prefix[PREFIX_CAP];
        if (!(o->orders & (1u << k)))
            continue;
        if (table_prefix(prefix, sizeof prefix, o->out, o->orders, (ns_order)k))
            return 2;
        if (ns_table_check_writable(prefix, &err))
            return usage_error("%s", err.message);
    }
    progress_state prog = {.enabled = !o->quiet && isatty(STDERR_FILENO),
                           .start = wall_seconds(), .work_this = 1.0, .work_total = 1.0,
                           .label = "mc"};
    desc.progress = progress_print;
    desc.progress_user = &prog;
    ns_mc_result r;
    int rc = ns_mc_run(&desc, &r, &err);
    progress_end(&prog);
    if (rc) {
        fprintf(stderr, "nscatter mc: %s\n", err.message);
        return rc == NS_ERR_INVALID_ARGUMENT ? 2 : 1;
    }
    rc = write_tables(&r, o->out, o->orders);
    ns_mc_result_free(&r);
    return rc;
}

/* =======================================================================================
 * The grid: resumable, one table at a time, overall progress by collisions.
 * ===================================================================================== */

typedef struct {
    double g, albedo;
    ns_order order;
    char prefix[PREFIX_CAP];
    uint64_t photons;
    double cost;     /* expected collisions of its simulation */
    double cost_now; /* what it costs in this run (0 if finished or shared) */
    int complete;
} grid_item;

static uint64_t grid_photons(double collisions, ns_order order, double albedo)
{
    double per = ns_mc_collisions_per_photon(1u << order, albedo);
    double n = floor(collisions / per);
    return n < 1000 ? 1000 : (uint64_t)n;
}

static int ensure_directory(const char *dir)
{
    if (mkdir(dir, 0755) != 0 && errno != EEXIST)
        return usage_error("--out: cannot create directory '%s': %s", dir, strerror(errno));
    struct stat st;
    if (stat(dir, &st) != 0 || !S_ISDIR(st.st_mode))
        return usage_error("--out: '%s' is not a directory", dir);
    char probe[PREFIX_CAP];
    snprintf(probe, sizeof probe, "%s/.probe", dir);
    ns_error err = {0};
    if (ns_table_check_writable(probe, &err))
        return usage_error("%s", err.message);
    return 0;
}

static int grid_validate(const mc_options *o)
{
    for (int i = 0; i < o->g_count; i++)
        if (!(o->g_values[i] > -1.0 && o->g_values[i] < 1.0))
            return usage_error("--g-values: %g is outside (-1, 1)", o->g_values[i]);
    for (int i = 0; i < o->albedo_count; i++)
        if (!(o->albedo_values[i] >= 0.0 && o->albedo_values[i] < 1.0))
            return usage_error("--albedo-values: %g is outside [0, 1)", o->albedo_values[i]);
    return 0;
}

/* Marks finished tables and what the rest will cost. Double scattering is traced once per
 * g (ns_mc_result_set_double_albedo makes every albedo's table from it), so only the first
 * unfinished double table of each g costs collisions. */
static double plan_grid(grid_item *items, int count, int *pending)
{
    double total = 0.0, double_g = NAN;
    *pending = 0;
    for (int i = 0; i < count; i++) {
        grid_item *it = &items[i];
        it->complete = ns_table_is_complete(it->prefix);
        it->cost_now = 0.0;
        if (it->complete)
            continue;
        (*pending)++;
        if (it->order == NS_ORDER_MULTIPLE || !(double_g == it->g))
            it->cost_now = it->cost;
        if (it->order == NS_ORDER_DOUBLE)
            double_g = it->g;
        total += it->cost_now;
    }
    return total;
}

static int run_grid_items(const mc_options *o, grid_item *items, int count)
{
    int pending = 0;
    double total = plan_grid(items, count, &pending), done = 0.0;
    fprintf(stderr, "nscatter mc: grid of %d tables, %d already complete, %d to do (%.3g collisions)\n",
            count, count - pending, pending, total);
    progress_state prog = {.enabled = !o->quiet && isatty(STDERR_FILENO),
                           .start = wall_seconds(), .work_total = total};
    double *lobe = malloc((size_t)NS_MC_NDIR * NS_MC_NDIR * sizeof(double));
    if (!lobe) {
        fprintf(stderr, "nscatter mc: out of memory\n");
        return 1;
    }
    double lobe_g = NAN, double_g = NAN;
    ns_mc_result doubles = {0}; /* the double-scattering simulation of g = double_g */
    int rc = 0;
    for (int i = 0; i < count && !rc; i++) {
        grid_item *it = &items[i];
        if (it->complete)
            continue;
        ns_error err = {0};
        if (it->order == NS_ORDER_DOUBLE && double_g == it->g) {
            rc = ns_mc_result_set_double_albedo(&doubles, it->albedo, &err);
            if (!rc)
                rc = write_tables(&doubles, it->prefix, NS_MC_WANT_DOUBLE);
            continue;
        }
        if (!(lobe_g == it->g)) { /* items are sorted by g: one lobe matrix per g */
            ns_mc_lobe_matrix(it->g, o->lobe_in, o->lobe_out, o->threads, lobe);
            lobe_g = it->g;
        }
        ns_mc_desc desc = {.g = it->g, .albedo = it->albedo, .photons = it->photons,
                           .seed = o->seed, .orders = 1u << it->order, .threads = o->threads,
                           .lobe = lobe, .lobe_in_samples = o->lobe_in,
                           .lobe_out_samples = o->lobe_out, .progress = progress_print,
                           .progress_user = &prog};
        char label[64];
        snprintf(label, sizeof label, "g=%g a=%g %s", it->g, it->albedo, ns_order_name(it->order));
        prog.label = label;
        prog.work_before = done;
        prog.work_this = it->cost_now;
        ns_mc_result r;
        rc = ns_mc_run(&desc, &r, &err);
        if (rc) {
            fprintf(stderr, "\nnscatter mc: %s: %s\n", it->prefix, err.message);
            break;
        }
        rc = write_tables(&r, it->prefix, desc.orders);
        if (it->order == NS_ORDER_DOUBLE) {
            ns_mc_result_free(&doubles);
            doubles = r; /* kept for the other albedos of this g */
            double_g = it->g;
        } else {
            ns_mc_result_free(&r);
        }
        done += it->cost_now;
    }
    progress_end(&prog);
    ns_mc_result_free(&doubles);
    free(lobe);
    return rc;
}

static int run_grid(mc_options *o)
{
    if (!o->out)
        return usage_error("--out: missing (the directory of the grid)");
    if (o->have_g || o->have_albedo || o->have_photons)
        return usage_error("--grid: use --g-values, --albedo-values and --collisions, "
                           "not --g, --albedo or --photons");
    if (!o->g_count) {
        o->g_count = (int)(sizeof grid_g_default / sizeof grid_g_default[0]);
        memcpy(o->g_values, grid_g_default, sizeof grid_g_default);
    }
    if (!o->albedo_count) {
        o->albedo_count = (int)(sizeof grid_albedo_default / sizeof grid_albedo_default[0]);
        memcpy(o->albedo_values, grid_albedo_default, sizeof grid_albedo_default);
    }
    int rc = grid_validate(o);
    if (!rc)
        rc = ensure_directory(o->out);
    if (rc)
        return rc;
    int count = o->g_count * o->albedo_count * 2;
    grid_item *items = calloc((size_t)count, sizeof *items);
    if (!items)
        return 1;
    int n = 0;
    for (int gi = 0; gi < o->g_count; gi++)
        for (int ai = 0; ai < o->albedo_count; ai++)
            for (int k = 0; k < 2; k++) {
                grid_item *it = &items[n++];
                it->g = o->g_values[gi];
                it->albedo = o->albedo_values[ai];
                it->order = (ns_order)k;
                it->photons = grid_photons(o->collisions, it->order, it->albedo);
                it->cost = (double)it->photons * ns_mc_collisions_per_photon(1u << k, it->albedo);
                snprintf(it->prefix, sizeof it->prefix, "%s/g%.2f_a%.3f_%s", o->out, it->g,
                         it->albedo, ns_order_name(it->order));
            }
    rc = run_grid_items(o, items, n);
    free(items);
    return rc;
}

/* =======================================================================================
 * Benchmark: photons and collisions per second per core, and the grid's expected time.
 * ===================================================================================== */

static int bench_one(double g, double albedo, double collisions, unsigned threads,
                     ns_mc_result *r)
{
    unsigned orders = NS_MC_WANT_DOUBLE | NS_MC_WANT_MULTIPLE;
    ns_mc_desc desc = {.g = g, .albedo = albedo, .seed = 7, .orders = orders,
                       .threads = threads, .lobe_in_samples = 2, .lobe_out_samples = 8};
    desc.photons = (uint64_t)(collisions / ns_mc_collisions_per_photon(orders, albedo));
    ns_error err = {0};
    if (ns_mc_run(&desc, r, &err)) {
        fprintf(stderr, "nscatter mc: %s\n", err.message);
        return 1;
    }
    return 0;
}

static int run_benchmark(const mc_options *o)
{
    static const double albedos[] = {0.3, 0.9, 0.99};
    const double g = 0.5, collisions = 2e7;
    unsigned threads = o->threads ? o->threads : ns_mc_default_threads();
    printf("nscatter mc benchmark: g = %g, both orders, %.0e collisions per run, %u threads\n",
           g, collisions, threads);
    printf("per core = per second of CPU time (all threads), robust to other load; "
           "wall = elapsed\n");
    printf("%-7s %16s %20s %18s\n", "albedo", "photons/s/core", "collisions/s/core",
           "collisions/s wall");
    double cpu_rate_sum = 0.0;
    for (size_t i = 0; i < sizeof albedos / sizeof albedos[0]; i++) {
        ns_mc_result r;
        if (bench_one(g, albedos[i], collisions, threads, &r))
            return 1;
        double cpu = fmax(r.trace_cpu_seconds, 1e-9), wall = fmax(r.trace_seconds, 1e-9);
        printf("%-7g %16.4g %20.4g %18.4g\n", albedos[i], (double)r.table[0].photons / cpu,
               (double)r.collisions / cpu, (double)r.collisions / wall);
        cpu_rate_sum += (double)r.collisions / cpu;
        ns_mc_result_free(&r);
    }
    double per_core = cpu_rate_sum / 3.0;
    /* The grid's cost: its collisions at the per-core rate on every core, plus one lobe
     * matrix per g and the per-table convolution and writing, measured here. */
    double t0 = wall_seconds();
    double *lobe = malloc((size_t)NS_MC_NDIR * NS_MC_NDIR * sizeof(double));
    if (!lobe)
        return 1;
    ns_mc_lobe_matrix(g, 0, 0, threads, lobe);
    double lobe_s = wall_seconds() - t0;
    ns_mc_desc desc = {.g = g, .albedo = 0.9, .photons = 100000, .orders = NS_MC_WANT_MULTIPLE,
                       .threads = threads, .lobe = lobe};
    ns_mc_result r;
    ns_error err = {0};
    int rc = ns_mc_run(&desc, &r, &err);
    free(lobe);
    if (rc)
        return 1;
    t0 = wall_seconds();
    char prefix[64];
    snprintf(prefix, sizeof prefix, "/tmp/nscatter-bench-%d", (int)getpid());
    if (ns_table_write(&r.table[NS_ORDER_MULTIPLE], prefix, &err) == 0) {
        char path[96];
        snprintf(path, sizeof path, "%s.npy", prefix);
        unlink(path);
        snprintf(path, sizeof path, "%s.json", prefix);
        unlink(path);
    }
    double overhead = r.total_seconds - r.trace_seconds + (wall_seconds() - t0);
    ns_mc_result_free(&r);
    size_t ng = sizeof grid_g_default / sizeof grid_g_default[0];
    size_t na = sizeof grid_albedo_default / sizeof grid_albedo_default[0];
    double tables = 2.0 * (double)ng * (double)na;
    double simulations = (double)ng * (double)na + (double)ng; /* one double run per g */
    unsigned cores = ns_mc_default_threads();
    double trace_s = simulations * GRID_DEFAULT_COLLISIONS / (per_core * cores);
    double grid_s = trace_s + tables * overhead + (double)ng * lobe_s;
    printf("lobe matrix (default quality): %.2f s per g; per-table convolution + write: %.2f s\n",
           lobe_s, overhead);
    printf("expected grid time (extrapolated): %.0f tables from %.0f simulations x %.3g "
           "collisions at %.4g collisions/s/core x %u cores = %.0f s tracing, %.0f s in all "
           "(%.2f h)\n",
           tables, simulations, GRID_DEFAULT_COLLISIONS, per_core, cores, trace_s, grid_s,
           grid_s / 3600.0);
    return 0;
}

int cmd_mc(int argc, char **argv)
{
    mc_options o;
    int rc = parse_options(argc, argv, &o);
    if (rc)
        return rc < 0 ? 0 : rc;
    if (o.benchmark)
        return run_benchmark(&o);
    if (o.grid)
        return run_grid(&o);
    return run_single(&o);
}
