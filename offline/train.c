/* train.c — the training behind `nscatter train` (cli/cmd_train.c): samples the Monte Carlo grid, trains one network per order with
 * Adam, checkpoints every epoch (resumable), writes weights/<order>.bin and .json. */
#include "train.h"

#include <cblas.h>
#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <jansson.h>

#include "nn_train.h"
#include "nn_weights.h"

const double ns_train_holdout_default[][2] = {
    {0.3, 0.8}, {0.5, 0.95}, {0.7, 0.5}, {0.9, 0.9}, {0.0, 0.3}, {0.95, 0.99}, {0.5, 0.2},
};
const int ns_train_holdout_default_count =
    (int)(sizeof ns_train_holdout_default / sizeof ns_train_holdout_default[0]);

/* Every failure is reported on stderr as "nscatter train: ..." and gives exit status 2 (bad
 * input: a missing table, an unwritable folder), as the command's usage errors do. */
static int usage_error(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static int usage_error(const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    fputs("nscatter train: ", stderr);
    vfprintf(stderr, fmt, args);
    fputc('\n', stderr);
    va_end(args);
    return 2;
}

static double now_seconds(void)
{
    return ns_now_ms() * 1e-3;
}

/* =======================================================================================
 * Data: a fixed sample of cells per table, half uniform over the cells (the table's shape
 * everywhere, including its faint far field) and half in proportion to the cell's energy
 * (where the light is, which is what the renderer integrates).
 * ===================================================================================== */

typedef struct {
    float *x; /* n x 6 */
    float *t; /* n targets (transformed, standardised later) */
    uint32_t n, cap;
    int materials;
} sample_set;

typedef struct {
    sample_set train, test;
    /* The first `regular` training samples alternate uniform / energy-proportional (the
     * calibration reads the odd ones); the near-field samples (--near-samples) follow them. */
    uint32_t regular;
    char names[1024]; /* summary of the materials used, for the JSON */
} dataset;

int ns_train_parse_table_name(const char *name, double *g, double *albedo, ns_order *order)
{
    char ord[16];
    int consumed = 0;
    if (sscanf(name, "g%lf_a%lf_%15[a-z].json%n", g, albedo, ord, &consumed) != 3 ||
        name[consumed] != '\0')
        return -1;
    return ns_order_parse(ord, order) ? -1 : 0;
}

static int is_holdout(double g, double albedo)
{
    for (int i = 0; i < ns_train_holdout_default_count; i++)
        if (fabs(g - ns_train_holdout_default[i][0]) < 1e-6 &&
            fabs(albedo - ns_train_holdout_default[i][1]) < 1e-6)
            return 1;
    return 0;
}

static int set_reserve(sample_set *s, uint32_t extra)
{
    if (s->n + extra <= s->cap)
        return 0;
    uint32_t cap = s->cap ? s->cap : 1u << 20;
    while (cap < s->n + extra)
        cap *= 2;
    float *x = realloc(s->x, (size_t)cap * NS_NN_INPUTS * sizeof(float));
    if (x)
        s->x = x;
    float *t = realloc(s->t, (size_t)cap * sizeof(float));
    if (t)
        s->t = t;
    if (!x || !t)
        return NS_ERR_OUT_OF_HOST_MEMORY;
    s->cap = cap;
    return 0;
}

static double uniform01(uint64_t *s)
{
    uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return (double)((z ^ (z >> 31)) >> 11) * 0x1.0p-53;
}

static size_t upper_bound(const double *cdf, size_t n, double u)
{
    size_t lo = 0, hi = n - 1;
    while (lo < hi) {
        size_t mid = (lo + hi) / 2;
        if (cdf[mid] > u)
            hi = mid;
        else
            lo = mid + 1;
    }
    return lo;
}

static void add_cell(sample_set *s, const ns_nn_header *h, const ns_table *tab, size_t cell)
{
    uint32_t iphi = (uint32_t)(cell % tab->n[3]), itheta = (uint32_t)(cell / tab->n[3] % tab->n[2]);
    uint32_t irho = (uint32_t)(cell / ((size_t)tab->n[3] * tab->n[2]) % tab->n[1]);
    uint32_t iz = (uint32_t)(cell / ((size_t)tab->n[3] * tab->n[2] * tab->n[1]));
#define MID(a, i) (0.5 * (tab->edges[a][i] + tab->edges[a][(i) + 1]))
    ns_nn_normalise(h, MID(NS_AXIS_RHO, irho), MID(NS_AXIS_Z, iz), MID(NS_AXIS_THETA, itheta),
                    MID(NS_AXIS_PHI, iphi), tab->g, tab->albedo,
                    s->x + (size_t)s->n * NS_NN_INPUTS);
#undef MID
    s->t[s->n++] = (float)ns_nn_j_to_target(h, tab->data[cell], tab->energy_expected);
}

/* Cell c's spatial bin centre lies within radius of the source. */
static int cell_is_near(const ns_table *tab, size_t c, double radius)
{
    size_t spatial = c / ((size_t)tab->n[3] * tab->n[2]);
    uint32_t iz = (uint32_t)(spatial / tab->n[1]), irho = (uint32_t)(spatial % tab->n[1]);
    double z = 0.5 * (tab->edges[NS_AXIS_Z][iz] + tab->edges[NS_AXIS_Z][iz + 1]);
    double rho = 0.5 * (tab->edges[NS_AXIS_RHO][irho] + tab->edges[NS_AXIS_RHO][irho + 1]);
    return z * z + rho * rho < radius * radius;
}

/* A cell drawn uniformly among those cell_is_near, by rejection: in the grid's tables (128 z
 * x 64 rho bins, sinh-spaced to 400 mfp) 3.3% of the cells lie within 1 mfp, 18% within 6,
 * so a draw takes 6 to 30 tries. The table's size when 10^5 tries found none. */
static size_t uniform_near_cell(const ns_table *tab, double radius, uint64_t *rng)
{
    size_t cells = ns_table_size(tab);
    for (int tries = 0; tries < 100000; tries++) {
        size_t c = (size_t)(uniform01(rng) * (double)cells);
        if (c < cells && cell_is_near(tab, c, radius))
            return c;
    }
    return cells;
}

static int sample_table(sample_set *s, sample_set *near, const ns_train_options *o,
                        const ns_nn_header *h, const ns_table *tab, uint32_t k, uint32_t k_near,
                        uint64_t *rng, double *cdf, double *cdf_near)
{
    size_t cells = ns_table_size(tab);
    int status = set_reserve(s, k);
    if (!status && k_near)
        status = set_reserve(near, k_near);
    if (status)
        return status;
    double sum = 0.0, sum_near = 0.0;
    for (size_t c = 0; c < cells; c++) {
        uint32_t iphi = (uint32_t)(c % tab->n[3]), itheta = (uint32_t)(c / tab->n[3] % tab->n[2]);
        size_t spatial = c / ((size_t)tab->n[3] * tab->n[2]);
        uint32_t iz = (uint32_t)(spatial / tab->n[1]), irho = (uint32_t)(spatial % tab->n[1]);
        double e = tab->data[c] * ns_table_bin_volume(tab, iz, irho) *
                   ns_table_bin_solid_angle(tab, itheta, iphi);
        e = e > 0 ? e : 0;
        sum += e;
        cdf[c] = sum;
        if (k_near) {
            sum_near += cell_is_near(tab, c, o->near_radius) ? e : 0;
            cdf_near[c] = sum_near;
        }
    }
    for (uint32_t i = 0; i < k; i++) {
        size_t cell = (i % 2 == 0 || !(sum > 0)) ? (size_t)(uniform01(rng) * (double)cells)
                                                 : upper_bound(cdf, cells, uniform01(rng) * sum);
        add_cell(s, h, tab, cell < cells ? cell : cells - 1);
    }
    /* The near field in proportion to its energy: what a small object integrates. At high
     * albedo it holds under 1% of the table's energy, so the energy-proportional half above
     * barely sees it, and the fit's error there (10% and more) is what such objects show.
     * A share near_uniform of them goes uniformly over the near cells instead, dim directions
     * as much as bright ones (the shape that a boundary correction's differences read).
     * Without it no number is drawn for the choice, so the draws stay those of before the
     * option (the committed weights' recorded commands). */
    for (uint32_t i = 0; i < k_near && sum_near > 0; i++) {
        size_t cell = cells;
        if (o->near_uniform > 0 && uniform01(rng) < o->near_uniform)
            cell = uniform_near_cell(tab, o->near_radius, rng);
        if (cell >= cells)
            cell = upper_bound(cdf_near, cells, uniform01(rng) * sum_near);
        add_cell(near, h, tab, cell < cells ? cell : cells - 1);
    }
    return 0;
}

static int load_dataset(const ns_train_options *o, ns_order order, ns_nn_header *h, dataset *d)
{
    DIR *dir = opendir(o->data);
    if (!dir)
        return usage_error("--data: cannot open '%s': %s", o->data, strerror(errno));
    memset(d, 0, sizeof *d);
    double *cdf = NULL, *cdf_near = NULL;
    sample_set near = {0};
    size_t first_size = 0;
    uint64_t rng = o->seed * 7919u + (uint64_t)order;
    int status = 0;
    struct dirent *e;
    size_t names_len = 0;
    while (!status && (e = readdir(dir))) {
        double g, a;
        ns_order ord;
        if (ns_train_parse_table_name(e->d_name, &g, &a, &ord) || ord != order)
            continue;
        char prefix[4096];
        snprintf(prefix, sizeof prefix, "%s/%.*s", o->data, (int)(strlen(e->d_name) - 5),
                 e->d_name);
        if (!ns_table_is_complete(prefix))
            continue;
        ns_table tab;
        ns_error err = {0};
        if (ns_table_read(prefix, &tab, &err)) {
            fprintf(stderr, "nscatter train: skipping %s: %s\n", prefix, err.message);
            continue;
        }
        /* The input map's extent comes from the tables; all must share the first one's. */
        float extent = (float)tab.edges[NS_AXIS_RHO][tab.n[NS_AXIS_RHO]];
        if (!cdf) {
            h->extent = extent;
            first_size = ns_table_size(&tab);
            cdf = malloc(first_size * sizeof(double));
            if (o->near_samples)
                cdf_near = malloc(first_size * sizeof(double));
        } else if (extent != h->extent || ns_table_size(&tab) != first_size) {
            fprintf(stderr,
                    "nscatter train: skipping %s: extent %g mfp / %zu cells, the "
                    "first table has %g / %zu\n",
                    prefix, extent, ns_table_size(&tab), h->extent, first_size);
            ns_table_free(&tab);
            continue;
        }
        int held = is_holdout(tab.g, tab.albedo);
        uint32_t samples = o->samples_per_table, samples_near = held ? 0 : o->near_samples;
        if (!held && tab.albedo >= o->oversample_albedo) {
            samples = (uint32_t)(samples * o->oversample_factor) & ~1u;
            samples_near = (uint32_t)(samples_near * o->oversample_factor);
        }
        status = cdf && (cdf_near || !o->near_samples)
                     ? sample_table(held ? &d->test : &d->train, &near, o, h, &tab, samples,
                                    samples_near, &rng, cdf, cdf_near)
                     : NS_ERR_OUT_OF_HOST_MEMORY;
        (held ? &d->test : &d->train)->materials++;
        if (held && names_len + 32 < sizeof d->names)
            names_len += (size_t)snprintf(d->names + names_len, sizeof d->names - names_len,
                                          "%s[%g, %g]", names_len ? ", " : "", tab.g, tab.albedo);
        ns_table_free(&tab);
    }
    closedir(dir);
    free(cdf);
    free(cdf_near);
    d->regular = d->train.n;
    if (!status && near.n && !(status = set_reserve(&d->train, near.n))) {
        memcpy(d->train.x + (size_t)d->train.n * NS_NN_INPUTS, near.x,
               (size_t)near.n * NS_NN_INPUTS * sizeof(float));
        memcpy(d->train.t + d->train.n, near.t, (size_t)near.n * sizeof(float));
        d->train.n += near.n;
    }
    free(near.x);
    free(near.t);
    if (status)
        return usage_error("out of memory while sampling the tables");
    if (!d->train.n)
        return usage_error("--data: no complete %s tables in '%s'", ns_order_name(order), o->data);
    return 0;
}

static void dataset_free(dataset *d)
{
    free(d->train.x);
    free(d->train.t);
    free(d->test.x);
    free(d->test.t);
}

/* Standardises the targets with the training set's mean and spread (kept in the header). */
static void standardise(dataset *d, ns_nn_header *h)
{
    double sum = 0, sum2 = 0;
    for (uint32_t i = 0; i < d->train.n; i++)
        sum += d->train.t[i], sum2 += (double)d->train.t[i] * d->train.t[i];
    double mean = sum / d->train.n, var = sum2 / d->train.n - mean * mean;
    h->target_mean = (float)mean;
    h->target_scale = (float)(var > 1e-12 ? sqrt(var) : 1.0);
    sample_set *sets[2] = {&d->train, &d->test};
    for (int s = 0; s < 2; s++)
        for (uint32_t i = 0; i < sets[s]->n; i++)
            sets[s]->t[i] = (sets[s]->t[i] - h->target_mean) / h->target_scale;
}

/* Re-expresses standardised targets with another mean and scale (a resumed checkpoint's or
 * --init's network's). */
static void restandardise(dataset *d, ns_nn_header *h, float mean, float scale)
{
    sample_set *sets[2] = {&d->train, &d->test};
    for (int s = 0; s < 2; s++)
        for (uint32_t i = 0; i < sets[s]->n; i++)
            sets[s]->t[i] = (sets[s]->t[i] * h->target_scale + h->target_mean - mean) / scale;
    h->target_mean = mean;
    h->target_scale = scale;
}

/* =======================================================================================
 * Checkpoints: parameters, Adam state and the epoch, with a CRC, written atomically.
 * ===================================================================================== */

typedef struct {
    char magic[8];
    uint32_t epoch, order, target, input_map; /* input_map 0: written before maps had numbers (1) */
    uint64_t step;
    float target_mean, target_scale;
    float p[NS_NN_PARAMS], m[NS_NN_PARAMS], v[NS_NN_PARAMS];
    double seconds;
    uint32_t crc;
} checkpoint;

static void checkpoint_path(const ns_train_options *o, ns_order order, char *out, size_t cap)
{
    snprintf(out, cap, "%s/train_%s.ckpt", o->ckpt_dir, ns_order_name(order));
}

static int checkpoint_save(const char *path, checkpoint *c)
{
    c->crc = ns_crc32(c, offsetof(checkpoint, crc));
    return ns_write_file_atomic(path, c, sizeof *c, NULL) ? -1 : 0;
}

static int checkpoint_load(const char *path, checkpoint *c)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return -1;
    int ok = fread(c, sizeof *c, 1, f) == 1;
    fclose(f);
    return ok && !memcmp(c->magic, "NSNNCKP1", 8) &&
                   c->crc == ns_crc32(c, offsetof(checkpoint, crc))
               ? 0
               : -2;
}

/* =======================================================================================
 * Training loop
 * ===================================================================================== */

static double evaluate(ns_nn_trainer *tr, const float *p, const sample_set *s)
{
    double sum = 0;
    for (uint32_t i = 0; i < s->n; i += tr->batch_cap) {
        uint32_t n = s->n - i < tr->batch_cap ? s->n - i : tr->batch_cap;
        sum += ns_nn_batch_forward(tr, p, s->x + (size_t)i * NS_NN_INPUTS, n, s->t + i) * n;
    }
    return s->n ? sum / s->n : NAN;
}

/* Learning rate: constant, then down by 10x over the last 40% of the epochs (cosine). */
static float learning_rate(const ns_train_options *o, int epoch)
{
    double f = (double)epoch / o->epochs;
    if (f < 0.6)
        return (float)o->lr;
    double u = (f - 0.6) / 0.4;
    return (float)(o->lr * (0.1 + 0.9 * 0.5 * (1 + cos(M_PI * u))));
}

typedef struct {
    int epochs_done;
    double train_loss, test_loss, seconds, calibration;
    uint64_t samples_seen;
} train_result;

static void shuffle(uint32_t *idx, uint32_t n, uint64_t *rng)
{
    for (uint32_t i = n; i > 1; i--) {
        uint32_t j = (uint32_t)(uniform01(rng) * i);
        uint32_t t = idx[i - 1];
        idx[i - 1] = idx[j < i ? j : i - 1];
        idx[j < i ? j : i - 1] = t;
    }
}

static int run_epochs(const ns_train_options *o, ns_order order, ns_nn_weights *w, const dataset *d,
                      checkpoint *ck, train_result *res)
{
    ns_nn_trainer tr;
    if (ns_nn_trainer_init(&tr, o->batch))
        return usage_error("out of memory");
    memcpy(tr.m, ck->m, sizeof tr.m);
    memcpy(tr.v, ck->v, sizeof tr.v);
    tr.step = ck->step;
    uint32_t *idx = malloc((size_t)d->train.n * sizeof *idx);
    float *bx = malloc((size_t)o->batch * NS_NN_INPUTS * sizeof(float));
    float *bt = malloc((size_t)o->batch * sizeof(float));
    if (!idx || !bx || !bt) {
        free(idx), free(bx), free(bt), ns_nn_trainer_free(&tr);
        return usage_error("out of memory");
    }
    char path[4200];
    checkpoint_path(o, order, path, sizeof path);
    const double start_seconds = ck->seconds; /* time spent before a resume */
    double start = now_seconds() - start_seconds;
    int epoch = (int)ck->epoch;
    const int first_epoch = epoch;
    uint64_t rng = o->seed * 104729u + (uint64_t)epoch;
    for (; epoch < o->epochs; epoch++) {
        for (uint32_t i = 0; i < d->train.n; i++)
            idx[i] = i;
        shuffle(idx, d->train.n, &rng);
        float lr = learning_rate(o, epoch);
        double loss_sum = 0;
        for (uint32_t b = 0; b < d->train.n; b += o->batch) {
            uint32_t n = d->train.n - b < o->batch ? d->train.n - b : o->batch;
            for (uint32_t i = 0; i < n; i++) {
                memcpy(bx + (size_t)i * NS_NN_INPUTS,
                       d->train.x + (size_t)idx[b + i] * NS_NN_INPUTS,
                       NS_NN_INPUTS * sizeof(float));
                bt[i] = d->train.t[idx[b + i]];
            }
            loss_sum += ns_nn_batch_gradient(&tr, w->p, bx, bt, n) * n;
            ns_nn_adam_step(&tr, w->p, lr);
        }
        res->train_loss = loss_sum / d->train.n;
        res->samples_seen += d->train.n;
        double elapsed = now_seconds() - start;
        int last = epoch + 1 == o->epochs || (o->time_budget > 0 && elapsed > o->time_budget);
        if (last || epoch % 5 == 4 || !o->quiet)
            res->test_loss = evaluate(&tr, w->p, &d->test);
        double eta =
            (elapsed - start_seconds) / (epoch + 1 - first_epoch) * (o->epochs - epoch - 1);
        if (!o->quiet)
            fprintf(stderr, "%s epoch %d/%d  train %.5f  test %.5f  lr %.2g  %.0f s  ETA %.0f s\n",
                    ns_order_name(order), epoch + 1, o->epochs, res->train_loss, res->test_loss, lr,
                    elapsed, eta);
        memcpy(ck->p, w->p, sizeof ck->p);
        memcpy(ck->m, tr.m, sizeof ck->m);
        memcpy(ck->v, tr.v, sizeof ck->v);
        ck->step = tr.step;
        ck->epoch = (uint32_t)epoch + 1;
        ck->seconds = elapsed;
        if (checkpoint_save(path, ck))
            fprintf(stderr, "nscatter train: warning: cannot write checkpoint %s\n", path);
        if (last) {
            epoch++;
            break;
        }
    }
    res->epochs_done = epoch;
    res->seconds = now_seconds() - start;
    if (isnan(res->test_loss) || res->test_loss == 0)
        res->test_loss = evaluate(&tr, w->p, &d->test);
    free(idx), free(bx), free(bt), ns_nn_trainer_free(&tr);
    return 0;
}

/* Energy calibration. A regression in log space is unbiased for ln J, hence biased low for J
 * (E[e^x] > e^E[x]): the raw tables came out 4% (double) and 10% (multiple) short of the
 * exact energy. The energy-sampled half of the training samples (odd indices: cells drawn in
 * proportion to their MC energy) estimates E_nn / E_mc = mean of J_nn / J_mc over them; its
 * inverse c rescales J. For logrel, c J = (exp(t + ln c) - c eps) E folds exactly into the
 * header (mean += ln c, eps *= c), so the file format needs no new field. */
static double energy_calibration(ns_nn_trainer *tr, const float *p, const sample_set *s,
                                 uint32_t regular, const ns_nn_header *h)
{
    double sum = 0;
    uint64_t count = 0;
    for (uint32_t i = 0; i < regular; i += tr->batch_cap) {
        uint32_t n = regular - i < tr->batch_cap ? regular - i : tr->batch_cap;
        ns_nn_batch_forward(tr, p, s->x + (size_t)i * NS_NN_INPUTS, n, NULL);
        for (uint32_t k = 0; k < n; k++) {
            if ((i + k) % 2 == 0)
                continue;
            double j_mc = ns_nn_output_to_j(h, s->t[i + k], 1.0);
            double j_nn = ns_nn_output_to_j(h, tr->y[k], 1.0);
            if (j_mc > 0) {
                sum += j_nn / j_mc;
                count++;
            }
        }
    }
    return count && sum > 0 ? count / sum : 1.0;
}

/* =======================================================================================
 * Output
 * ===================================================================================== */

static int write_json(const ns_train_options *o, ns_order order, const ns_nn_weights *w,
                      const dataset *d, const train_result *r, const char *initialised_from,
                      const char *path)
{
    FILE *f = fopen(path, "w");
    if (!f)
        return usage_error("%s: %s", path, strerror(errno));
    const ns_nn_header *h = &w->h;
    fprintf(f,
            "{\n  \"order\": \"%s\",\n  \"file\": \"%s.bin\",\n  \"bytes\": %u,\n"
            "  \"architecture\": {\"inputs\": [\"rho\", \"z\", \"theta\", \"phi\", \"g\", "
            "\"albedo\"], \"layers\": [6, 50, 50, 1], \"activation\": \"tanh\", "
            "\"parameters\": %d},\n",
            ns_order_name(order), ns_order_name(order),
            (unsigned)(NS_NN_HEADER_SIZE + NS_NN_PARAMS * 4), NS_NN_PARAMS);
    fprintf(f,
            "  \"input_normalisation\": {\"rho\": \"asinh(rho/%g)/asinh(%g/%g)\", "
            "\"z\": \"(asinh(z/%g)/asinh(%g/%g)+1)/2\", \"theta\": \"theta/pi\", "
            "\"phi\": \"phi/pi\", \"g\": \"%s(g-%g)/(%g-%g)%s\", \"input_map\": %u, "
            "\"albedo\": \"ln(1-albedo)/ln(1-%g)\", \"clamped_to\": [0, 1], "
            "\"points\": \"bin centres (mid-edges)\"},\n",
            h->sinh_scale, h->extent, h->sinh_scale, h->sinh_scale, h->extent, h->sinh_scale,
            h->input_map == NS_NN_INPUT_MAP_ASINH_LOGG ? "0.5*" : "", h->g_min, h->g_max, h->g_min,
            h->input_map == NS_NN_INPUT_MAP_ASINH_LOGG ? "+0.5*ln(1-g)/ln(1-g_max)" : "",
            h->input_map, h->albedo_max);
    fprintf(f,
            "  \"target_transform\": {\"name\": \"%s\", \"formula\": \"%s\", \"eps\": %.9g, "
            "\"mean\": %.9g, \"scale\": %.9g, \"energy_calibration\": %.6g, "
            "\"zero_floor\": %g, \"training_eps\": %.9g},\n",
            h->target == NS_NN_TARGET_PAPER ? "paper" : "logrel",
            h->target == NS_NN_TARGET_PAPER ? "(ln(J+1)-mean)/scale"
                                            : "(ln(J/E_k+eps)-mean)/scale, E_k=a^2 or a^3/(1-a)",
            h->target_eps, h->target_mean, h->target_scale, r->calibration,
            h->target == NS_NN_TARGET_LOGREL ? o->zero_floor : 1.0, o->eps);
    fprintf(f,
            "  \"training_set\": {\"data\": \"%s\", \"train_materials\": %d, "
            "\"test_materials\": %d, \"held_out\": [%s], \"samples_per_table\": %u, "
            "\"oversampled_albedo_from\": %g, \"oversample_factor\": %g, "
            "\"near_samples_per_table\": %u, \"near_radius\": %g, \"near_uniform\": %g, "
            "\"train_samples\": %u, \"test_samples\": %u, \"sampling\": \"half uniform over "
            "cells, half proportional to cell energy%s\"},\n",
            o->data, d->train.materials, d->test.materials, d->names, o->samples_per_table,
            o->oversample_factor > 1 ? o->oversample_albedo : 1.0, o->oversample_factor,
            o->near_samples, o->near_samples ? o->near_radius : 0.0,
            o->near_samples ? o->near_uniform : 0.0, d->train.n, d->test.n,
            !o->near_samples ? ""
            : o->near_uniform > 0
                ? "; then near_samples_per_table more within near_radius mfp of the source, "
                  "the share near_uniform uniformly over those cells, the rest proportional "
                  "to cell energy"
                : "; then near_samples_per_table more proportional to cell energy "
                  "within near_radius mfp of the source");
    fprintf(f,
            "  \"optimiser\": {\"name\": \"adam\", \"lr\": %g, \"batch\": %u, \"seed\": %llu},\n"
            "  \"epochs\": %d,\n  \"epochs_requested\": %d,\n  \"final_train_loss\": %.6g,\n"
            "  \"final_test_loss\": %.6g,\n  \"loss\": \"mean squared error of the standardised "
            "target\",\n  \"training_seconds\": %.1f,\n",
            o->lr, o->batch, (unsigned long long)o->seed, r->epochs_done, o->epochs, r->train_loss,
            r->test_loss, r->seconds);
    if (initialised_from)
        fprintf(f, "  \"initialised_from\": %s,\n", initialised_from);
    fprintf(f, "  \"command\": \"%s\"\n}\n", o->command);
    return fclose(f) ? usage_error("%s: write failed", path) : 0;
}

/* The header the options ask for, before the data gives it its extent and standardisation. */
static void header_for(const ns_train_options *o, ns_order order, ns_nn_header *h)
{
    ns_nn_header_init(h, (uint32_t)order, o->target);
    if (o->input_map == NS_NN_INPUT_MAP_ASINH_LOGG) {
        h->input_map = NS_NN_INPUT_MAP_ASINH_LOGG;
        h->g_max = 0.99f; /* the grid's largest g; ln(1 - g) needs g_max < 1 */
    }
    if (o->target == NS_NN_TARGET_LOGREL)
        h->target_eps = (float)o->eps;
}

int ns_train_samples_load(const ns_train_options *o, ns_order order, ns_train_samples *s)
{
    memset(s, 0, sizeof *s);
    header_for(o, order, &s->h);
    dataset d;
    int rc = load_dataset(o, order, &s->h, &d);
    if (rc)
        return rc;
    s->x = d.train.x, s->t = d.train.t, s->n = d.train.n, s->regular = d.regular;
    free(d.test.x);
    free(d.test.t);
    return 0;
}

void ns_train_samples_free(ns_train_samples *s)
{
    free(s->x);
    free(s->t);
    memset(s, 0, sizeof *s);
}

/* --init: one order's starting network and the mean of the standardisation it was trained
 * in. A written file has its energy calibration c folded into its transform (mean + ln c,
 * eps * c * zero_floor: train_order below), so the training's own mean is the file's less
 * ln c; c, the zero floor and the training eps are read from the JSON written beside it
 * (exact, where inferring c from the eps would take a changed --zero-floor for a
 * calibration). */
typedef struct init_weights {
    ns_nn_weights w;
    float train_mean;
    char *record; /* JSON object for the written JSON's "initialised_from" (json_dumps) */
} init_weights;

static const char *target_name(uint32_t target)
{
    return target == NS_NN_TARGET_PAPER ? "paper" : target == NS_NN_TARGET_LOGREL ? "logrel" : "?";
}

static const char *g_map_name(uint32_t map)
{
    return map == NS_NN_INPUT_MAP_ASINH_LOGG ? "log"
           : map == NS_NN_INPUT_MAP_ASINH    ? "linear"
                                             : "?";
}

static int load_init(const ns_train_options *o, ns_order order, init_weights *out)
{
    char path[4200], json_path[4200];
    snprintf(path, sizeof path, "%s/%s.bin", o->init_dir, ns_order_name(order));
    snprintf(json_path, sizeof json_path, "%s/%s.json", o->init_dir, ns_order_name(order));
    ns_error err = {0};
    if (ns_nn_weights_load(path, &out->w, &err))
        return usage_error("--init: %s", err.message);
    const ns_nn_header *h = &out->w.h;
    if (h->order != (uint32_t)order || h->target != (uint32_t)o->target ||
        h->input_map != o->input_map)
        return usage_error("--init: %s is a %s network with target %s and g map %s; this run "
                           "trains %s with target %s and g map %s",
                           path, h->order <= 1 ? ns_order_name((ns_order)h->order) : "?",
                           target_name(h->target), g_map_name(h->input_map), ns_order_name(order),
                           target_name(o->target), g_map_name(o->input_map));
    json_error_t jerr;
    json_t *root = json_load_file(json_path, 0, &jerr);
    /* What the new weights were tuned from, for the JSON written with them. */
    json_t *record =
        json_pack("{s:s, s:O*, s:O*}", "file", path, "epochs", json_object_get(root, "epochs"),
                  "command", json_object_get(root, "command"));
    out->record = record ? json_dumps(record, JSON_PRESERVE_ORDER) : NULL;
    json_decref(record);
    out->train_mean = h->target_mean;
    if (o->target != NS_NN_TARGET_LOGREL) {
        json_decref(root);
        return 0; /* paper: eps 1, no calibration, no floor */
    }
    json_t *t = json_object_get(root, "target_transform");
    json_t *c = json_object_get(t, "energy_calibration"), *f = json_object_get(t, "zero_floor"),
           *e = json_object_get(t, "training_eps");
    int ok = json_is_number(c) && json_is_number(f) && json_is_number(e);
    double calibration = ok ? json_number_value(c) : NAN, floor = ok ? json_number_value(f) : NAN,
           eps = ok ? json_number_value(e) : NAN;
    json_decref(root);
    if (!ok || !(calibration > 0) || !(floor >= 1) || !(eps > 0))
        return usage_error("--init: %s: no target_transform with energy_calibration, zero_floor "
                           "and training_eps (the JSON `nscatter train` writes beside %s)",
                           json_path, path);
    if (fabs(eps / o->eps - 1) > 1e-6)
        return usage_error("--init: %s was trained with --eps %g; this run's is %g (the targets "
                           "would mean something else)",
                           path, eps, o->eps);
    if (fabs(h->target_eps / (eps * calibration * floor) - 1) > 1e-5)
        return usage_error("--init: %s decodes with eps %g, not its JSON's training eps %g x "
                           "calibration %g x zero floor %g",
                           path, h->target_eps, eps, calibration, floor);
    out->train_mean = h->target_mean - (float)log(calibration);
    return 0;
}

/* Starts w from `from`, whose inputs must be mapped as this run's tables map them, with the
 * targets re-expressed in its standardisation. */
static int start_from(const ns_train_options *o, ns_order order, const init_weights *from,
                      ns_nn_weights *w, dataset *d)
{
    const ns_nn_header *a = &from->w.h, *b = &w->h;
    if (a->extent != b->extent || a->sinh_scale != b->sinh_scale ||
        a->albedo_max != b->albedo_max || a->g_min != b->g_min || a->g_max != b->g_max)
        return usage_error("--init: %s/%s.bin maps its inputs otherwise (extent %g, sinh scale %g, "
                           "albedo max %g, g %g to %g) than these tables (%g, %g, %g, %g to %g)",
                           o->init_dir, ns_order_name(order), a->extent, a->sinh_scale,
                           a->albedo_max, a->g_min, a->g_max, b->extent, b->sinh_scale,
                           b->albedo_max, b->g_min, b->g_max);
    memcpy(w->p, from->w.p, sizeof w->p);
    restandardise(d, &w->h, from->train_mean, a->target_scale);
    fprintf(stderr, "nscatter train: %s: starting from %s/%s.bin\n", ns_order_name(order),
            o->init_dir, ns_order_name(order));
    return 0;
}

static int train_order(const ns_train_options *o, ns_order order, const init_weights *init)
{
    ns_nn_weights w;
    header_for(o, order, &w.h);
    dataset d;
    double t0 = now_seconds();
    int rc = load_dataset(o, order, &w.h, &d);
    if (rc)
        return rc;
    standardise(&d, &w.h);
    fprintf(stderr,
            "nscatter train: %s: %u training samples from %d materials, %u test "
            "samples from %d held-out materials (%.1f s to load)\n",
            ns_order_name(order), d.train.n, d.train.materials, d.test.n, d.test.materials,
            now_seconds() - t0);
    checkpoint ck;
    memset(&ck, 0, sizeof ck);
    char path[4200];
    checkpoint_path(o, order, path, sizeof path);
    if (o->resume && checkpoint_load(path, &ck) == 0 && ck.order == (uint32_t)order &&
        ck.target == (uint32_t)o->target && (ck.input_map ? ck.input_map : 1) == o->input_map) {
        fprintf(stderr, "nscatter train: resuming %s from epoch %u (%s)%s\n", ns_order_name(order),
                ck.epoch, path, init ? "; --init is not read" : "");
        memcpy(w.p, ck.p, sizeof w.p);
        restandardise(&d, &w.h, ck.target_mean, ck.target_scale);
    } else {
        if (o->resume)
            fprintf(stderr, "nscatter train: no usable checkpoint %s, starting afresh\n", path);
        memset(&ck, 0, sizeof ck);
        memcpy(ck.magic, "NSNNCKP1", 8);
        ck.order = (uint32_t)order;
        ck.target = (uint32_t)o->target;
        ck.input_map = o->input_map;
        if (init) {
            rc = start_from(o, order, init, &w, &d);
            if (rc) {
                dataset_free(&d);
                return rc;
            }
        } else {
            ns_nn_init_params(w.p, o->seed + (uint64_t)order);
        }
        ck.target_mean = w.h.target_mean;
        ck.target_scale = w.h.target_scale;
    }
    train_result res = {.test_loss = NAN};
    rc = run_epochs(o, order, &w, &d, &ck, &res);
    double calibration = 1.0;
    if (!rc && o->target == NS_NN_TARGET_LOGREL && o->calibrate) {
        ns_nn_trainer tr;
        if (ns_nn_trainer_init(&tr, 8192) == 0) {
            if (!(res.train_loss > 0))
                res.train_loss = evaluate(&tr, w.p, &d.train);
            calibration = energy_calibration(&tr, w.p, &d.train, d.regular, &w.h);
            ns_nn_trainer_free(&tr);
        }
        w.h.target_mean += (float)log(calibration);
        w.h.target_eps *= (float)calibration;
        fprintf(stderr,
                "nscatter train: %s: energy calibration x%.4f folded into the target "
                "transform\n",
                ns_order_name(order), calibration);
    }
    res.calibration = calibration;
    /* Decode floor. Where the table is empty the network answers its floor ln(eps) with an
     * error of a few tenths either way, and (e^t - eps) E_k keeps the positive half of that
     * noise: a tiny J, but in the far cells of a 400-mfp table it lit a shell at r ~ 300 mfp
     * and doubled <r^2> of the double table (docs/network.md). Decoding with a larger eps
     * sends everything below (F - 1) eps to zero; the cells that hold the light are many
     * orders above it. The file keeps one eps, the decoding one. */
    if (o->target == NS_NN_TARGET_LOGREL)
        w.h.target_eps *= (float)o->zero_floor;
    if (!rc) {
        char bin[4200], json[4200];
        snprintf(bin, sizeof bin, "%s/%s.bin", o->out_dir, ns_order_name(order));
        snprintf(json, sizeof json, "%s/%s.json", o->out_dir, ns_order_name(order));
        ns_error err = {0};
        if (ns_nn_weights_save(&w, bin, &err))
            rc = usage_error("%s", err.message);
        else
            rc = write_json(o, order, &w, &d, &res, init ? init->record : NULL, json);
        if (!rc)
            printf("%s: %d epochs, train loss %.5f, test loss %.5f, %.0f s -> %s\n",
                   ns_order_name(order), res.epochs_done, res.train_loss, res.test_loss,
                   res.seconds, bin);
    }
    dataset_free(&d);
    return rc;
}

ns_train_options ns_train_options_default(void)
{
    return (ns_train_options){
        .out_dir = "weights",
        .orders = 3,
        .target = NS_NN_TARGET_LOGREL,
        .input_map = NS_NN_INPUT_MAP_ASINH,
        .epochs = 200,
        .batch = 8192,
        .samples_per_table = 24000,
        .lr = 0.003,
        .eps = 1e-13,
        .zero_floor = 10,
        .oversample_albedo = 2, /* none */
        .oversample_factor = 1,
        .calibrate = 1,
        .seed = 1,
    };
}

int ns_train(const ns_train_options *o)
{
    if (mkdir(o->out_dir, 0755) != 0 && errno != EEXIST)
        return usage_error("--out-dir: cannot create '%s': %s", o->out_dir, strerror(errno));
    /* A run of an hour without its checkpoints cannot be resumed: refuse at once rather
     * than warn at every epoch. */
    if (o->ckpt_dir && mkdir(o->ckpt_dir, 0755) != 0 && errno != EEXIST)
        return usage_error("--checkpoint-dir: cannot create '%s': %s", o->ckpt_dir,
                           strerror(errno));
    if (o->threads)
        openblas_set_num_threads(o->threads);
    /* Every --init file is checked before the first order trains (an hour, maybe). Static:
     * two networks are 24 KB, and no call keeps them past its return. */
    static init_weights init[2];
    memset(init, 0, sizeof init);
    int rc = 0;
    for (int k = 0; k < 2 && o->init_dir && !rc; k++)
        if (o->orders & (1u << k))
            rc = load_init(o, (ns_order)k, &init[k]);
    for (int k = 0; k < 2 && !rc; k++)
        if (o->orders & (1u << k))
            rc = train_order(o, (ns_order)k, o->init_dir ? &init[k] : NULL);
    for (int k = 0; k < 2; k++) {
        free(init[k].record);
        init[k].record = NULL;
    }
    return rc;
}
