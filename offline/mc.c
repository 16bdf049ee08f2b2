/* mc.c — photon tracer for the J tables; see mc.h for the estimator. */
#include "mc.h"

#include <math.h>
#include <pthread.h>
#include <stddef.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#define SPATIAL_BINS (NS_TABLE_NZ * NS_TABLE_NRHO)
#define THETA_STEP (M_PI / NS_TABLE_NTHETA)
#define PHI_STEP (M_PI / NS_TABLE_NPHI)
#define LOBE_IN_DEFAULT 8
#define LOBE_OUT_DEFAULT 128
#define MAX_THREADS 256
#define LOBE_MAX_SAMPLES 256

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* CPU time of the whole process (all threads): per-core rates that a busy shared machine
 * does not distort as much as wall time. */
static double cpu_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* =======================================================================================
 * Random numbers: xoshiro256+ per batch, seeded through splitmix64 from (seed, batch).
 * ===================================================================================== */

typedef struct {
    uint64_t s[4];
} rng;

static uint64_t splitmix64(uint64_t *state)
{
    uint64_t z = (*state += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

static void rng_seed(rng *r, uint64_t seed, uint64_t stream)
{
    uint64_t state = seed ^ (stream * 0xd1342543de82ef95ull + 0x632be59bd9b4e019ull);
    for (int i = 0; i < 4; i++)
        r->s[i] = splitmix64(&state);
}

static inline uint64_t rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

/* Uniform in [0, 1). */
static inline double rng_uniform(rng *r)
{
    uint64_t *s = r->s;
    uint64_t result = s[0] + s[3];
    uint64_t t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = rotl(s[3], 45);
    return (double)(result >> 11) * 0x1.0p-53;
}

/* =======================================================================================
 * Henyey-Greenstein
 * ===================================================================================== */

double ns_mc_hg(double g, double cos_angle)
{
    double denom = 1.0 + g * g - 2.0 * g * cos_angle;
    return (1.0 - g * g) / (4.0 * M_PI * denom * sqrt(denom));
}

double ns_mc_sample_hg_cos(double g, double u)
{
    if (fabs(g) < 1e-4)
        return 2.0 * u - 1.0;
    double s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u);
    double c = (1.0 + g * g - s * s) / (2.0 * g);
    return c < -1.0 ? -1.0 : (c > 1.0 ? 1.0 : c);
}

/* Turns unit direction d by the angle whose cosine is c, around d by azimuth angle b. */
static inline void scatter_direction(double d[3], double c, double b)
{
    /* Orthonormal basis around d without branches on the pole (Duff et al. 2017). */
    double sign = copysign(1.0, d[2]);
    double a = -1.0 / (sign + d[2]);
    double bb = d[0] * d[1] * a;
    double t1[3] = {1.0 + sign * d[0] * d[0] * a, sign * bb, -sign * d[0]};
    double t2[3] = {bb, sign + d[1] * d[1] * a, -d[1]};
    double s = sqrt(fmax(0.0, 1.0 - c * c));
    double cb = cos(b) * s, sb = sin(b) * s;
    double n[3];
    for (int i = 0; i < 3; i++)
        n[i] = c * d[i] + cb * t1[i] + sb * t2[i];
    double inv = 1.0 / sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (int i = 0; i < 3; i++)
        d[i] = n[i] * inv;
}

/* =======================================================================================
 * Bins
 * ===================================================================================== */

static double sinh_step(void)
{
    return asinh(NS_TABLE_EXTENT / NS_TABLE_SINH_SCALE) / NS_TABLE_NRHO;
}

void ns_mc_default_edges(ns_table *t)
{
    double c = sinh_step();
    for (int i = 0; i <= NS_TABLE_NZ; i++)
        t->edges[NS_AXIS_Z][i] = NS_TABLE_SINH_SCALE * sinh(c * (i - NS_TABLE_NZ / 2));
    for (int i = 0; i <= NS_TABLE_NRHO; i++)
        t->edges[NS_AXIS_RHO][i] = NS_TABLE_SINH_SCALE * sinh(c * i);
    t->edges[NS_AXIS_Z][NS_TABLE_NZ / 2] = 0.0; /* exactly, not sinh(0 * c) rounding */
    t->edges[NS_AXIS_RHO][0] = 0.0;
    for (int i = 0; i <= NS_TABLE_NTHETA; i++)
        t->edges[NS_AXIS_THETA][i] = M_PI * i / NS_TABLE_NTHETA;
    for (int i = 0; i <= NS_TABLE_NPHI; i++)
        t->edges[NS_AXIS_PHI][i] = M_PI * i / NS_TABLE_NPHI;
}

/* Index of v among n bins with the given edges, or -1 outside. The sinh mapping gives the
 * index directly; one step either way repairs the rounding at an edge. */
static inline int sinh_bin(const double *edges, int n, int offset, double v, double inv_step)
{
    int i = (int)floor(asinh(v * (1.0 / NS_TABLE_SINH_SCALE)) * inv_step) + offset;
    if (i < 0 || i >= n)
        return -1;
    if (v < edges[i])
        i--;
    else if (v >= edges[i + 1])
        i++;
    return (i < 0 || i >= n) ? -1 : i;
}

static inline int angle_bin(double angle, double step, int n)
{
    int i = (int)(angle * (1.0 / step));
    return i >= n ? n - 1 : (i < 0 ? 0 : i);
}

/* Direction bin of d in the local frame (e_rho, e_phi, e_z) at position (x, y). On the
 * axis e_rho is taken as +x (e_phi = +y), the limit along the x half-plane. */
static inline int local_direction_bin(double x, double y, double rho, const double d[3])
{
    double ex = 1.0, ey = 0.0;
    if (rho > 0.0) {
        ex = x / rho;
        ey = y / rho;
    }
    double along_rho = d[0] * ex + d[1] * ey;
    double along_phi = d[1] * ex - d[0] * ey;
    double theta = acos(fmax(-1.0, fmin(1.0, d[2])));
    double phi = atan2(fabs(along_phi), along_rho); /* folded into [0, pi] */
    return angle_bin(theta, THETA_STEP, NS_TABLE_NTHETA) * NS_TABLE_NPHI +
           angle_bin(phi, PHI_STEP, NS_TABLE_NPHI);
}

/* =======================================================================================
 * Tracing
 * ===================================================================================== */

/* Per-batch sums for one order, reduced in batch order at the end (deterministic). */
typedef struct {
    double events, in_table, z, cos_theta, r2;
} order_sums;

typedef struct {
    order_sums sums[2];
    uint64_t photons;
    uint64_t collisions;
} batch_stats;

typedef struct {
    const ns_mc_desc *desc;
    const ns_table *bins; /* edges only */
    batch_stats *batches;
    uint64_t batch_size, batch_count;
    double inv_step;
    _Atomic uint64_t next_batch, done_batches;
    pthread_mutex_t flush_lock;
} trace_job;

/* One tracing thread: its own 32-bit histograms (plain adds; an atomic add waits for each
 * cache miss, and half the bytes keep more of the histogram in cache). They are added into
 * the result's 64-bit histograms before any bin can wrap (after 2^32 - 1 deposits of the
 * thread) and at the end: integer sums, so the order of threads does not matter. */
typedef struct {
    trace_job *job;
    uint32_t *counts[2];
    uint64_t *totals[2]; /* the result's histograms, shared: add under job->flush_lock */
    uint64_t deposits;   /* since the last flush */
} trace_worker_state;

static void flush_counts(trace_worker_state *w)
{
    static const size_t cells = (size_t)SPATIAL_BINS * NS_MC_NDIR;
    pthread_mutex_lock(&w->job->flush_lock);
    for (int o = 0; o < 2; o++)
        if (w->counts[o])
            for (size_t c = 0; c < cells; c++)
                w->totals[o][c] += w->counts[o][c];
    pthread_mutex_unlock(&w->job->flush_lock);
    for (int o = 0; o < 2; o++)
        if (w->counts[o])
            memset(w->counts[o], 0, cells * sizeof(uint32_t));
    w->deposits = 0;
}

static void deposit(trace_worker_state *w, int order, const double p[3], const double d[3],
                    order_sums *sums, double g)
{
    const trace_job *job = w->job;
    double rho = sqrt(p[0] * p[0] + p[1] * p[1]);
    sums->events += 1.0;
    sums->z += p[2];
    sums->r2 += rho * rho + p[2] * p[2];
    /* The emitted direction's mean cosine given the incoming one is exactly g cos (HG):
     * its expectation has less noise than one sampled direction. */
    sums->cos_theta += g * d[2];
    int iz =
        sinh_bin(job->bins->edges[NS_AXIS_Z], NS_TABLE_NZ, NS_TABLE_NZ / 2, p[2], job->inv_step);
    int ir = sinh_bin(job->bins->edges[NS_AXIS_RHO], NS_TABLE_NRHO, 0, rho, job->inv_step);
    if (iz < 0 || ir < 0)
        return;
    sums->in_table += 1.0;
    size_t cell = ((size_t)iz * NS_TABLE_NRHO + (size_t)ir) * NS_MC_NDIR +
                  (size_t)local_direction_bin(p[0], p[1], rho, d);
    w->counts[order][cell]++;
    if (++w->deposits == UINT32_MAX)
        flush_counts(w);
}

static void trace_photon(trace_worker_state *w, rng *r, batch_stats *st)
{
    const trace_job *job = w->job;
    const double g = job->desc->g, a = job->desc->albedo;
    const int want_multiple = (job->desc->orders & NS_MC_WANT_MULTIPLE) != 0;
    double p[3] = {0.0, 0.0, 0.0}, d[3] = {0.0, 0.0, 1.0};
    for (uint64_t k = 1;; k++) {
        double t = -log(1.0 - rng_uniform(r));
        for (int i = 0; i < 3; i++)
            p[i] += t * d[i];
        st->collisions++;
        if (k == 2) {
            if (job->desc->orders & NS_MC_WANT_DOUBLE)
                deposit(w, NS_ORDER_DOUBLE, p, d, &st->sums[NS_ORDER_DOUBLE], g);
            if (!want_multiple)
                return;
        } else if (k >= 3) {
            deposit(w, NS_ORDER_MULTIPLE, p, d, &st->sums[NS_ORDER_MULTIPLE], g);
            if (rng_uniform(r) >= a) /* absorbed: roulette with survival probability a */
                return;
        }
        double c = ns_mc_sample_hg_cos(g, rng_uniform(r));
        scatter_direction(d, c, 2.0 * M_PI * rng_uniform(r));
    }
}

static void trace_batch(trace_worker_state *w, uint64_t batch)
{
    trace_job *job = w->job;
    batch_stats *st = &job->batches[batch];
    memset(st, 0, sizeof *st);
    uint64_t first = batch * job->batch_size;
    uint64_t last = first + job->batch_size;
    if (last > job->desc->photons)
        last = job->desc->photons;
    rng r;
    rng_seed(&r, job->desc->seed, batch);
    for (uint64_t i = first; i < last; i++)
        trace_photon(w, &r, st);
    st->photons = last - first;
}

static void *trace_worker(void *arg)
{
    trace_worker_state *w = arg;
    trace_job *job = w->job;
    for (;;) {
        uint64_t b = atomic_fetch_add(&job->next_batch, 1);
        if (b >= job->batch_count)
            break;
        trace_batch(w, b);
        atomic_fetch_add(&job->done_batches, 1);
    }
    flush_counts(w);
    return NULL;
}

/* =======================================================================================
 * A tiny parallel-for over independent items (each item writes only its own output).
 * ===================================================================================== */

typedef struct {
    void (*fn)(void *ctx, uint64_t item);
    void *ctx;
    uint64_t count;
    _Atomic uint64_t next;
} parallel_job;

static void *parallel_worker(void *arg)
{
    parallel_job *job = arg;
    for (uint64_t i; (i = atomic_fetch_add(&job->next, 1)) < job->count;)
        job->fn(job->ctx, i);
    return NULL;
}

static int parallel_for(unsigned threads, uint64_t count, void (*fn)(void *, uint64_t), void *ctx)
{
    parallel_job job = {.fn = fn, .ctx = ctx, .count = count};
    atomic_init(&job.next, 0);
    pthread_t tid[MAX_THREADS];
    unsigned started = 0;
    for (; started < threads; started++)
        if (pthread_create(&tid[started], NULL, parallel_worker, &job) != 0)
            break;
    parallel_worker(&job); /* the caller helps, and finishes alone if no thread started */
    for (unsigned i = 0; i < started; i++)
        pthread_join(tid[i], NULL);
    return NS_OK;
}

/* =======================================================================================
 * The lobe matrix: for incoming bin i, the fraction of the scattered energy that leaves in
 * bin o, with the incoming direction uniform over bin i (and its mirror image, which folds
 * onto the same emitted bins). Each row sums to 1: energy is conserved exactly.
 *
 * Rotating about z is a symmetry before phi is folded, so on UNFOLDED 10-degree phi bins
 * the fraction depends only on the two theta bins and the phi-bin offset. We compute that
 * offset table U[theta_in][theta_out][offset] for incoming bins at phi in [0, 10) degrees
 * only (18 rows instead of 324), then fold: emitted bin phi_o stands for the unfolded bins
 * phi_o and -phi_o - 1, so M[(ti, pi)][(to, po)] = U[ti][to][po - pi] + U[ti][to][-po-1-pi].
 *
 * U is a stratified quadrature: a jittered n x n grid of incoming directions over the bin,
 * and for each, equal-probability strata of the HG scattering cosine (so narrow lobes,
 * g = 0.99, are resolved as well as broad ones), each stratum a ring of 4n azimuths with a
 * golden-ratio rotation (so the rings do not alias with the bin grid). Deterministic: the jitter
 * comes from a fixed stream per theta row.
 * ===================================================================================== */

#define PHI_UNFOLDED (2 * NS_TABLE_NPHI)

typedef struct {
    double g;
    unsigned n_in, n_out;
    double *offsets; /* [NS_TABLE_NTHETA][NS_TABLE_NTHETA][PHI_UNFOLDED] */
} lobe_job;

/* Sampling resolves the lobe's peak but leaves ~5-10% noise in small bins far from it,
 * where few rings cross. There the phase function is smooth, and a midpoint product rule
 * (n points per axis in cos theta and phi, for both bins; n = the incoming samples per
 * axis, at most QUAD_MAX_N) is accurate: we use it for every pair of bins over which the
 * phase function varies by less than a factor QUAD_MAX_RATIO. For g <= 0.5 that is every
 * pair. */
#define QUAD_MAX_N 16
#define QUAD_MAX_RATIO 8.0

static void bin_nodes(int theta_bin, double phi_offset, int n, double nodes[][3])
{
    double c0 = cos(theta_bin * THETA_STEP), c1 = cos((theta_bin + 1) * THETA_STEP);
    for (int a = 0; a < n; a++)
        for (int b = 0; b < n; b++) {
            double ct = c0 + (c1 - c0) * (a + 0.5) / n;
            double st = sqrt(fmax(0.0, 1.0 - ct * ct));
            double ph = phi_offset + (b + 0.5) / n * PHI_STEP;
            double *node = nodes[a * n + b];
            node[0] = st * cos(ph);
            node[1] = st * sin(ph);
            node[2] = ct;
        }
}

static void replace_smooth_pairs_by_quadrature(double g, int n, int theta_in, double *out)
{
    double in[QUAD_MAX_N * QUAD_MAX_N][3], on[QUAD_MAX_N * QUAD_MAX_N][3];
    n = n > QUAD_MAX_N ? QUAD_MAX_N : n;
    bin_nodes(theta_in, 0.0, n, in);
    for (int to = 0; to < NS_TABLE_NTHETA; to++) {
        double solid_angle_out = (cos(to * THETA_STEP) - cos((to + 1) * THETA_STEP)) * PHI_STEP;
        for (int u = 0; u < PHI_UNFOLDED; u++) {
            bin_nodes(to, -M_PI + u * PHI_STEP, n, on);
            double sum = 0.0, lo = INFINITY, hi = 0.0;
            for (int i = 0; i < n * n; i++)
                for (int o = 0; o < n * n; o++) {
                    double c = in[i][0] * on[o][0] + in[i][1] * on[o][1] + in[i][2] * on[o][2];
                    double p = ns_mc_hg(g, c);
                    sum += p;
                    lo = fmin(lo, p);
                    hi = fmax(hi, p);
                }
            if (hi <= QUAD_MAX_RATIO * lo)
                out[to * PHI_UNFOLDED + u] = sum / ((double)n * n * n * n) * solid_angle_out;
        }
    }
}

static void lobe_offsets_row(void *ctx, uint64_t theta_in)
{
    lobe_job *job = ctx;
    double *out = job->offsets + theta_in * NS_TABLE_NTHETA * PHI_UNFOLDED;
    memset(out, 0, NS_TABLE_NTHETA * PHI_UNFOLDED * sizeof *out);
    double c0 = cos((double)theta_in * THETA_STEP), c1 = cos((double)(theta_in + 1) * THETA_STEP);
    unsigned n_in = job->n_in, rings = job->n_out, azimuths = 4 * job->n_out;
    double w = 1.0 / ((double)n_in * n_in * rings * azimuths);
    rng r;
    rng_seed(&r, 0x6c6f6265u, theta_in);
    for (unsigned a = 0; a < n_in; a++)
        for (unsigned b = 0; b < n_in; b++) {
            double ct = c0 + (c1 - c0) * (a + rng_uniform(&r)) / n_in; /* uniform in solid angle */
            double st = sqrt(fmax(0.0, 1.0 - ct * ct));
            double ph = (b + rng_uniform(&r)) / n_in * PHI_STEP;
            double in[3] = {st * cos(ph), st * sin(ph), ct};
            double turn0 = rng_uniform(&r);
            for (unsigned j = 0; j < rings; j++) {
                double c = ns_mc_sample_hg_cos(job->g, (j + rng_uniform(&r)) / rings);
                /* Golden-ratio turns spread the rings' azimuths evenly over the sphere. */
                double turn = fmod(turn0 + 0.6180339887498949 * j, 1.0);
                for (unsigned k = 0; k < azimuths; k++) {
                    double d[3] = {in[0], in[1], in[2]};
                    scatter_direction(d, c, 2.0 * M_PI * (k + turn) / azimuths);
                    int it =
                        angle_bin(acos(fmax(-1.0, fmin(1.0, d[2]))), THETA_STEP, NS_TABLE_NTHETA);
                    /* Unfolded phi in [-pi, pi) as bins 0..35 counted from -pi. */
                    int ip = (int)floor((atan2(d[1], d[0]) + M_PI) / PHI_STEP);
                    ip = ip < 0 ? 0 : (ip >= PHI_UNFOLDED ? PHI_UNFOLDED - 1 : ip);
                    out[it * PHI_UNFOLDED + ip] += w;
                }
            }
        }
    replace_smooth_pairs_by_quadrature(job->g, (int)job->n_in, (int)theta_in, out);
    double sum = 0.0;
    for (int i = 0; i < NS_TABLE_NTHETA * PHI_UNFOLDED; i++)
        sum += out[i];
    for (int i = 0; i < NS_TABLE_NTHETA * PHI_UNFOLDED; i++)
        out[i] /= sum; /* exact energy conservation (the sum is 1 up to quadrature error) */
}

void ns_mc_lobe_matrix(double g, unsigned in_samples, unsigned out_samples, unsigned threads,
                       double *lobe)
{
    lobe_job lj = {.g = g,
                   .n_in = in_samples ? in_samples : LOBE_IN_DEFAULT,
                   .n_out = out_samples ? out_samples : LOBE_OUT_DEFAULT};
    if (lj.n_in > LOBE_MAX_SAMPLES)
        lj.n_in = LOBE_MAX_SAMPLES;
    if (lj.n_out > LOBE_MAX_SAMPLES)
        lj.n_out = LOBE_MAX_SAMPLES;
    if (threads == 0)
        threads = ns_mc_default_threads();
    double offsets[NS_TABLE_NTHETA * NS_TABLE_NTHETA * PHI_UNFOLDED];
    lj.offsets = offsets;
    parallel_for(threads - 1, NS_TABLE_NTHETA, lobe_offsets_row, &lj);
    /* Unfolded bin index u counts from -pi; the incoming bins start at phi = 0, index 18. */
    for (int ti = 0; ti < NS_TABLE_NTHETA; ti++)
        for (int pi = 0; pi < NS_TABLE_NPHI; pi++)
            for (int to = 0; to < NS_TABLE_NTHETA; to++)
                for (int po = 0; po < NS_TABLE_NPHI; po++) {
                    const double *u = offsets + (ti * NS_TABLE_NTHETA + to) * PHI_UNFOLDED;
                    int direct = ((po - pi) % PHI_UNFOLDED + PHI_UNFOLDED) % PHI_UNFOLDED;
                    int mirror = ((-po - 1 - pi) % PHI_UNFOLDED + PHI_UNFOLDED) % PHI_UNFOLDED;
                    lobe[(size_t)(ti * NS_TABLE_NPHI + pi) * NS_MC_NDIR + to * NS_TABLE_NPHI + po] =
                        u[(NS_TABLE_NPHI + direct) % PHI_UNFOLDED] +
                        u[(NS_TABLE_NPHI + mirror) % PHI_UNFOLDED];
                }
}

/* =======================================================================================
 * From counts to J: J = const * sum_i count_i lobe[i][o] / (photons * volume * solid angle)
 * ===================================================================================== */

typedef struct {
    const uint64_t *counts;
    const double *lobe;
    ns_table *table;
    double scale; /* energy per count: a^k / photons */
} convolve_job;

static void convolve_spatial_bin(void *ctx, uint64_t cell)
{
    convolve_job *job = ctx;
    const uint64_t *in = job->counts + cell * NS_MC_NDIR;
    double out[NS_MC_NDIR] = {0};
    int any = 0;
    for (int i = 0; i < NS_MC_NDIR; i++) {
        if (!in[i])
            continue;
        any = 1;
        double c = (double)in[i];
        const double *row = job->lobe + (size_t)i * NS_MC_NDIR;
        for (int o = 0; o < NS_MC_NDIR; o++)
            out[o] += c * row[o];
    }
    float *dst = job->table->data + cell * NS_MC_NDIR;
    if (!any)
        return; /* the table was zeroed at creation */
    uint32_t iz = (uint32_t)(cell / NS_TABLE_NRHO), ir = (uint32_t)(cell % NS_TABLE_NRHO);
    double per_volume = job->scale / ns_table_bin_volume(job->table, iz, ir);
    for (int o = 0; o < NS_MC_NDIR; o++)
        dst[o] = (float)(out[o] * per_volume /
                         ns_table_bin_solid_angle(job->table, (uint32_t)(o / NS_TABLE_NPHI),
                                                  (uint32_t)(o % NS_TABLE_NPHI)));
}

/* =======================================================================================
 * Statistics from the per-batch sums
 * ===================================================================================== */

/* Mean of x per photon over all photons, and its standard error from the batch spread. */
static void per_photon_mean(const batch_stats *b, uint64_t nb, uint64_t photons, int order,
                            size_t field, double *mean, double *se)
{
    double total = 0.0;
    for (uint64_t i = 0; i < nb; i++)
        total += *(const double *)((const char *)&b[i].sums[order] + field);
    *mean = total / (double)photons;
    double ss = 0.0;
    for (uint64_t i = 0; i < nb; i++) {
        double e = *(const double *)((const char *)&b[i].sums[order] + field) -
                   *mean * (double)b[i].photons;
        ss += e * e;
    }
    *se = nb > 1 ? sqrt(ss * nb / (nb - 1.0)) / (double)photons : INFINITY;
}

/* Ratio sum(x) / sum(events) and its standard error (delta method over batches). */
static void event_mean(const batch_stats *b, uint64_t nb, int order, size_t field, double *mean,
                       double *se)
{
    double num = 0.0, den = 0.0;
    for (uint64_t i = 0; i < nb; i++) {
        num += *(const double *)((const char *)&b[i].sums[order] + field);
        den += b[i].sums[order].events;
    }
    *mean = den > 0.0 ? num / den : 0.0;
    double ss = 0.0;
    for (uint64_t i = 0; i < nb; i++) {
        double e = *(const double *)((const char *)&b[i].sums[order] + field) -
                   *mean * b[i].sums[order].events;
        ss += e * e;
    }
    *se = (nb > 1 && den > 0.0) ? sqrt(ss * nb / (nb - 1.0)) / den : INFINITY;
}

static void compute_moments(const ns_mc_desc *desc, const batch_stats *b, uint64_t nb, int order,
                            ns_mc_moments *m)
{
    double per_event = ns_mc_expected_energy((ns_order)order, desc->albedo) *
                       (order == NS_ORDER_MULTIPLE ? (1.0 - desc->albedo) : 1.0);
    double events, events_se, in_table, in_table_se;
    per_photon_mean(b, nb, desc->photons, order, offsetof(order_sums, events), &events, &events_se);
    per_photon_mean(b, nb, desc->photons, order, offsetof(order_sums, in_table), &in_table,
                    &in_table_se);
    m->energy = per_event * events;
    m->energy_se = per_event * events_se;
    m->energy_in_table = per_event * in_table;
    event_mean(b, nb, order, offsetof(order_sums, z), &m->z, &m->z_se);
    event_mean(b, nb, order, offsetof(order_sums, cos_theta), &m->cos_theta, &m->cos_theta_se);
    event_mean(b, nb, order, offsetof(order_sums, r2), &m->r2, &m->r2_se);
    double total = 0.0, inside = 0.0;
    for (uint64_t i = 0; i < nb; i++) {
        total += b[i].sums[order].events;
        inside += b[i].sums[order].in_table;
    }
    m->events = (uint64_t)total;
    m->events_in_table = (uint64_t)inside;
}

/* =======================================================================================
 * Public entry points
 * ===================================================================================== */

double ns_mc_expected_energy(ns_order order, double albedo)
{
    double a2 = albedo * albedo;
    return order == NS_ORDER_DOUBLE ? a2 : a2 * albedo / (1.0 - albedo);
}

double ns_mc_collisions_per_photon(unsigned orders, double albedo)
{
    /* Two collisions always; from the third on, a geometric number with mean 1/(1-a). */
    return (orders & NS_MC_WANT_MULTIPLE) ? 2.0 + 1.0 / (1.0 - albedo) : 2.0;
}

unsigned ns_mc_default_threads(void)
{
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n < 1 ? 1u : (n > MAX_THREADS ? MAX_THREADS : (unsigned)n);
}

static int fail(ns_error *err, int status, const char *msg, double value)
{
    if (err) {
        snprintf(err->message, sizeof err->message, msg, value);
        err->status = status;
    }
    return status;
}

int ns_mc_check_desc(const ns_mc_desc *desc, ns_error *err)
{
    if (!(desc->g > -1.0 && desc->g < 1.0))
        return fail(err, NS_ERR_INVALID_ARGUMENT, "--g: %g is outside (-1, 1)", desc->g);
    if (!(desc->albedo >= 0.0 && desc->albedo < 1.0))
        return fail(err, NS_ERR_INVALID_ARGUMENT, "--albedo: %g is outside [0, 1)", desc->albedo);
    if (desc->photons < 1)
        return fail(err, NS_ERR_INVALID_ARGUMENT, "--photons: must be at least 1", 0.0);
    if (!(desc->orders & (NS_MC_WANT_DOUBLE | NS_MC_WANT_MULTIPLE)))
        return fail(err, NS_ERR_INVALID_ARGUMENT, "--order: no order asked for", 0.0);
    if (desc->threads > MAX_THREADS)
        return fail(err, NS_ERR_INVALID_ARGUMENT, "--threads: %g is more than 256",
                    (double)desc->threads);
    return NS_OK;
}

void ns_mc_result_free(ns_mc_result *r)
{
    if (!r)
        return;
    for (int o = 0; o < 2; o++) {
        ns_table_free(&r->table[o]);
        free(r->counts[o]);
        r->counts[o] = NULL;
    }
    free(r->lobe);
    r->lobe = NULL;
}

static int worker_init(trace_worker_state *w, trace_job *job, uint64_t *const totals[2])
{
    static const size_t cells = (size_t)SPATIAL_BINS * NS_MC_NDIR;
    memset(w, 0, sizeof *w);
    w->job = job;
    for (int o = 0; o < 2; o++) {
        w->totals[o] = totals[o];
        if (totals[o] && !(w->counts[o] = calloc(cells, sizeof(uint32_t)))) {
            free(w->counts[0]);
            return NS_ERR_OUT_OF_HOST_MEMORY;
        }
    }
    return NS_OK;
}

/* Traces every batch on up to `threads` threads (fewer if memory or threads run out; the
 * batches, hence the result, stay the same). */
static int trace_all(const ns_mc_desc *desc, trace_job *job, unsigned threads,
                     uint64_t *const totals[2])
{
    trace_worker_state state[MAX_THREADS];
    pthread_t tid[MAX_THREADS];
    unsigned started = 0;
    for (; started < threads; started++) {
        if (worker_init(&state[started], job, totals) != NS_OK)
            break;
        if (pthread_create(&tid[started], NULL, trace_worker, &state[started]) != 0) {
            free(state[started].counts[0]);
            free(state[started].counts[1]);
            break;
        }
    }
    if (started == 0) { /* no thread: trace on this one, or fail for lack of memory */
        if (worker_init(&state[0], job, totals) != NS_OK)
            return NS_ERR_OUT_OF_HOST_MEMORY;
        trace_worker(&state[0]);
        free(state[0].counts[0]);
        free(state[0].counts[1]);
    }
    while (desc->progress && atomic_load(&job->done_batches) < job->batch_count) {
        desc->progress(desc->progress_user, atomic_load(&job->done_batches), job->batch_count);
        struct timespec ts = {0, 250 * 1000 * 1000};
        nanosleep(&ts, NULL);
    }
    for (unsigned i = 0; i < started; i++) {
        pthread_join(tid[i], NULL);
        free(state[i].counts[0]);
        free(state[i].counts[1]);
    }
    if (desc->progress)
        desc->progress(desc->progress_user, job->batch_count, job->batch_count);
    return NS_OK;
}

static int allocate_result(const ns_mc_desc *desc, ns_mc_result *out, ns_error *err)
{
    static const uint32_t n[NS_AXIS_COUNT] = {NS_TABLE_NZ, NS_TABLE_NRHO, NS_TABLE_NTHETA,
                                              NS_TABLE_NPHI};
    for (int o = 0; o < 2; o++) {
        int rc = ns_table_create(&out->table[o], n, err);
        if (rc)
            return rc;
        ns_mc_default_edges(&out->table[o]);
        if (!(desc->orders & (1u << o)))
            continue;
        out->counts[o] = calloc((size_t)SPATIAL_BINS * NS_MC_NDIR, sizeof(uint64_t));
        if (!out->counts[o])
            return fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "mc: out of memory for the histograms",
                        0.0);
    }
    out->lobe = malloc((size_t)NS_MC_NDIR * NS_MC_NDIR * sizeof(double));
    if (!out->lobe)
        return fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "mc: out of memory for the lobe matrix", 0.0);
    return NS_OK;
}

/* Every deposit of an order carries the same energy: a^2 (double) or a^3 (multiple). */
static double energy_per_deposit(int order, double albedo)
{
    return order == NS_ORDER_DOUBLE ? albedo * albedo : albedo * albedo * albedo;
}

static void fill_table(ns_mc_result *out, int order, double albedo)
{
    ns_table *t = &out->table[order];
    t->order = (ns_order)order;
    t->albedo = albedo;
    t->energy_expected = ns_mc_expected_energy((ns_order)order, albedo);
    convolve_job cj = {.counts = out->counts[order], .lobe = out->lobe, .table = t,
                       .scale = energy_per_deposit(order, albedo) / (double)t->photons};
    parallel_for(out->threads - 1, SPATIAL_BINS, convolve_spatial_bin, &cj);
    t->energy_captured = ns_table_energy(t);
}

int ns_mc_result_set_double_albedo(ns_mc_result *r, double albedo, ns_error *err)
{
    if (!r->counts[NS_ORDER_DOUBLE])
        return fail(err, NS_ERR_INVALID_ARGUMENT, "mc: no double-scattering histogram", 0.0);
    if (!(albedo >= 0.0 && albedo < 1.0))
        return fail(err, NS_ERR_INVALID_ARGUMENT, "--albedo: %g is outside [0, 1)", albedo);
    ns_mc_moments *m = &r->moments[NS_ORDER_DOUBLE];
    double per_photon = energy_per_deposit(NS_ORDER_DOUBLE, albedo) /
                        (double)r->table[NS_ORDER_DOUBLE].photons;
    m->energy = per_photon * (double)m->events;
    m->energy_in_table = per_photon * (double)m->events_in_table;
    fill_table(r, NS_ORDER_DOUBLE, albedo);
    return NS_OK;
}

int ns_mc_run(const ns_mc_desc *desc, ns_mc_result *out, ns_error *err)
{
    memset(out, 0, sizeof *out);
    int rc = ns_mc_check_desc(desc, err);
    if (rc)
        return rc;
    double t0 = now_seconds(), cpu0 = cpu_seconds();
    unsigned threads = desc->threads ? desc->threads : ns_mc_default_threads();
    rc = allocate_result(desc, out, err);
    if (rc) {
        ns_mc_result_free(out);
        return rc;
    }

    /* Batch size depends only on the photon count, never on the threads: at most ~4096
     * batches (bounded bookkeeping), at least 256 photons each. */
    uint64_t batch_size = (desc->photons + 4095) / 4096;
    if (batch_size < 256)
        batch_size = 256;
    trace_job job = {.desc = desc, .bins = &out->table[0], .batch_size = batch_size,
                     .batch_count = (desc->photons + batch_size - 1) / batch_size,
                     .inv_step = 1.0 / sinh_step()};
    atomic_init(&job.next_batch, 0);
    atomic_init(&job.done_batches, 0);
    job.batches = calloc(job.batch_count, sizeof *job.batches);
    if (!job.batches) {
        ns_mc_result_free(out);
        return fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "mc: out of memory for batch sums", 0.0);
    }
    pthread_mutex_init(&job.flush_lock, NULL);
    rc = trace_all(desc, &job, threads, out->counts);
    pthread_mutex_destroy(&job.flush_lock);
    if (rc) {
        free(job.batches);
        ns_mc_result_free(out);
        return fail(err, rc, "mc: out of memory for the histograms", 0.0);
    }
    double t1 = now_seconds();
    out->trace_cpu_seconds = cpu_seconds() - cpu0;

    if (desc->lobe)
        memcpy(out->lobe, desc->lobe, (size_t)NS_MC_NDIR * NS_MC_NDIR * sizeof(double));
    else
        ns_mc_lobe_matrix(desc->g, desc->lobe_in_samples, desc->lobe_out_samples, threads,
                          out->lobe);
    double t2 = now_seconds();

    out->threads = threads;
    for (int o = 0; o < 2; o++) {
        if (!(desc->orders & (1u << o)))
            continue;
        compute_moments(desc, job.batches, job.batch_count, o, &out->moments[o]);
        out->table[o].g = desc->g;
        out->table[o].photons = desc->photons;
        out->table[o].seed = desc->seed;
        fill_table(out, o, desc->albedo);
    }
    for (uint64_t b = 0; b < job.batch_count; b++)
        out->collisions += job.batches[b].collisions;
    free(job.batches);
    out->batches = job.batch_count;
    out->trace_seconds = t1 - t0;
    out->lobe_seconds = t2 - t1;
    out->total_seconds = now_seconds() - t0;
    return NS_OK;
}
