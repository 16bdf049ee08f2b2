/* gpu_accumulate.c — the accumulation stage (render/scatter_tables.c, shaders/accumulate.comp)
 * against closed forms and a brute-force integration, and the table cache:
 *   (a) J(z) = e^{-kz} on z >= 0 (bin averages): A = e^{-kz} [e^{-(1-kc)u0} - e^{-(1-kc)u1}] /
 *       (1 - kc), c = cos theta, [u0, u1] the part of the line inside the support and the table;
 *       per-cell tolerance from the bin discretisation (bounded below), one k per channel;
 *   (b) the network's tables of one material: A at a cell centre equals a brute-force
 *       integral of the same nearest-bin J along the line, and the exact segment form
 *       A(entry) - e^{-L} A(exit) equals the brute-force integral over the segment;
 *   (c) paper mode: the 5-mfp integral (closed form of (a), brute force of (b));
 *   (d) the cache: a second call is a hit with no reconstruction, other components reuse J,
 *       eviction keeps the byte bound; bad keys are refused naming the field;
 *   (e) a plane of beams: A read as the gather reads it, averaged over where the beams start,
 *       equals the binned J's integral along the camera line;
 *   (f) a walk within a reach (ns_table_key.reach_bins): its cells bit for bit the whole
 *       walk's, the others 0; the reach holds every cell the gather reads up to that distance.
 * Validation layers on (NSCATTER_VALIDATION=1). */
#include "accumulate_shared.h"
#include "gpu_util.h"
#include "nn.h"
#include "scatter.h"

static ns_table_grid grid;
static const size_t cells = NS_TABLE_CELLS;

static uint32_t rng = 2024u;
static uint32_t next_random(void)
{
    rng = rng * 1664525u + 1013904223u;
    return rng >> 8;
}
static double uniform01(void)
{
    return next_random() * (1.0 / 16777216.0);
}

/* A cell's centre in its own frame: position (rho, 0, z), direction w from (theta, phi). */
typedef struct centre {
    int iz, ir, it, ip;
    double p[3], w[3];
} centre;

static centre cell_line(size_t cell, uint32_t line);

static centre cell_centre(size_t cell)
{
    return cell_line(cell, ns_accumulate_phi_lines((uint32_t)(cell % NS_TABLE_NPHI)) / 2);
}

/* The cell's line `line` of the ns_accumulate_phi_lines of its phi bin, whose mean A the
 * cell holds (accumulate_shared.h): its centre, with phi at (ip + (line + 0.5) / n) bins. With
 * an even count, cell_centre takes the line just past the bin's centre. */
static centre cell_line(size_t cell, uint32_t line)
{
    centre c;
    c.ip = (int)(cell % NS_TABLE_NPHI);
    cell /= NS_TABLE_NPHI;
    c.it = (int)(cell % NS_TABLE_NTHETA);
    cell /= NS_TABLE_NTHETA;
    c.ir = (int)(cell % NS_TABLE_NRHO);
    c.iz = (int)(cell / NS_TABLE_NRHO);
    /* The two cells beside the source's plane hold A on the plane (accumulate_shared.h). */
    int beside_plane = c.iz == NS_TABLE_NZ / 2 - 1 || c.iz == NS_TABLE_NZ / 2;
    double z = beside_plane ? 0.0 : 0.5 * (grid.z[c.iz] + grid.z[c.iz + 1]);
    double rho = 0.5 * (grid.rho[c.ir] + grid.rho[c.ir + 1]);
    double theta = 0.5 * (grid.theta[c.it] + grid.theta[c.it + 1]);
    double n = ns_accumulate_phi_lines((uint32_t)c.ip);
    double phi = grid.phi[c.ip] + (line + 0.5) / n * (grid.phi[c.ip + 1] - grid.phi[c.ip]);
    c.p[0] = rho;
    c.p[1] = 0.0;
    c.p[2] = z;
    c.w[0] = sin(theta) * cos(phi);
    c.w[1] = sin(theta) * sin(phi);
    c.w[2] = cos(theta);
    return c;
}

/* Bin of v among n bins with these edges (sinh-spaced, found by search), or -1 outside. */
static int edge_bin(const double *edges, int n, double v)
{
    if (v < edges[0] || v >= edges[n])
        return -1;
    int lo = 0, hi = n; /* edges[lo] <= v < edges[hi] */
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (v >= edges[mid])
            lo = mid;
        else
            hi = mid;
    }
    return lo;
}

static int angle_bin(double angle)
{
    int i = (int)(angle / (M_PI / NS_TABLE_NTHETA));
    return i < 0 ? 0 : i >= (int)NS_TABLE_NTHETA ? (int)NS_TABLE_NTHETA - 1 : i;
}

/* The table cell holding point p for light travelling along w (nearest bin, the gather's
 * rule written independently), or -1 outside the table. */
static long table_cell(const double p[3], const double w[3])
{
    double rho = hypot(p[0], p[1]);
    int iz = edge_bin(grid.z, NS_TABLE_NZ, p[2]);
    int ir = edge_bin(grid.rho, NS_TABLE_NRHO, rho);
    if (iz < 0 || ir < 0)
        return -1;
    int it = angle_bin(acos(fmax(-1.0, fmin(1.0, w[2]))));
    double wh = hypot(w[0], w[1]);
    double cos_phi = rho > 0 && wh > 0 ? (w[0] * p[0] + w[1] * p[1]) / (wh * rho) : 1.0;
    int ip = angle_bin(acos(fmax(-1.0, fmin(1.0, cos_phi))));
    return (((long)iz * NS_TABLE_NRHO + ir) * NS_TABLE_NTHETA + it) * NS_TABLE_NPHI + ip;
}

/* Brute force: integral over [0, length] of e^{-u} J(p - u w, w) du, J one channel, by the
 * midpoint rule on steps far finer than the finest bin (0.058 mfp). */
static double brute_force(const float *j, const double p[3], const double w[3], double length)
{
    double sum = 0.0, u = 0.0;
    while (u < length) {
        double du = u < 8.0 ? 1e-3 : 1e-2;
        if (u + du > length)
            du = length - u;
        double um = u + 0.5 * du;
        double q[3] = {p[0] - um * w[0], p[1] - um * w[1], p[2] - um * w[2]};
        long cell = table_cell(q, w);
        if (cell >= 0)
            sum += exp(-um) * j[cell] * du;
        u += du;
    }
    return sum;
}

/* u where the line p - u w leaves the table (|z| or rho reaches the extent). */
static double table_exit(const double p[3], const double w[3])
{
    double e = grid.extent;
    double uz = w[2] > 0 ? (p[2] + e) / w[2] : w[2] < 0 ? (e - p[2]) / -w[2] : INFINITY;
    double a = w[0] * w[0] + w[1] * w[1], b = p[0] * w[0] + p[1] * w[1];
    double c = p[0] * p[0] + p[1] * p[1] - e * e; /* |p_h - u w_h|^2 = e^2 */
    double ur = a > 0 ? (b + sqrt(b * b - a * c)) / a : INFINITY;
    return fmin(uz, ur);
}

/* Accumulates j into *a_out (the caller frees it). Returns the status, and checks it: a
 * caller that gives up on a failure is still counted as failed. */
static int accumulate(const float *j, ns_accumulation mode, float **a_out, uint64_t *steps)
{
    ns_scatter_tables t;
    ns_error err = {0};
    int status = ns_tables_accumulate(test_context(), j, mode, &t, steps, &err);
    if (status)
        fprintf(stderr, "ns_tables_accumulate: %s (%s)\n", err.message, ns_status_name(status));
    CHECK_INT(status, NS_OK);
    if (status)
        return status;
    *a_out = malloc(3 * cells * sizeof(float));
    memcpy(*a_out, t.a.mapped, 3 * cells * sizeof(float));
    CHECK_REL(t.scale, 0.5, 1e-7);
    CHECK_REL(t.extent, 400.0, 1e-6);
    CHECK_REL(1.0 / t.inv_step, grid.step, 1e-6);
    CHECK_INT(t.bytes, 3 * cells * sizeof(float));
    ns_scatter_tables_free(test_context(), &t);
    return 0;
}

/* ---------------------------------------------------------------------------------------
 * (a), (c): J(z) = e^{-kz} on z >= 0
 * ------------------------------------------------------------------------------------- */
static const double ks[3] = {0.01, 0.04, 0.1};

static double bin_width_at(double z)
{
    int i = edge_bin(grid.z, NS_TABLE_NZ, z);
    return i < 0 ? 0.0 : grid.z[i + 1] - grid.z[i];
}

/* The bin average of e^{-kz} over z-bin i (0 below z = 0): the synthetic J. */
static double bin_average(int i, double k)
{
    double z0 = grid.z[i], z1 = grid.z[i + 1];
    return z0 >= 0 ? (exp(-k * z0) - exp(-k * z1)) / (k * (z1 - z0)) : 0.0;
}

/* The part [u0, u1] of [0, length] where the line stays in the table and in z >= 0. */
static void support(const centre *c, double length, double *u0, double *u1)
{
    double cz = c->w[2], z0 = c->p[2];
    *u0 = 0.0;
    *u1 = fmin(length, table_exit(c->p, c->w));
    if (cz > 0) /* z falls to 0 at u = z0 / cz */
        *u1 = fmin(*u1, z0 > 0 ? z0 / cz : 0.0);
    else if (z0 < 0) /* z rises through 0 (cz < 0), or never reaches it */
        *u0 = cz < 0 ? z0 / cz : INFINITY;
}

/* Closed form for the smooth J = e^{-kz} over the support, and the bound on what bin
 * averaging changes: inside a bin of width d the average of e^{-kz} lies within a factor
 * e^{kd} of e^{-kz}, so |A_bins - A| <= integral e^{-u} e^{-kz(u)} (e^{k d(z(u))} - 1) du. */
static void smooth_case(const centre *c, double k, double length, double *a, double *bound)
{
    double u0, u1, cz = c->w[2], z0 = c->p[2];
    support(c, length, &u0, &u1);
    *a = *bound = 0.0;
    if (!(u1 > u0))
        return;
    double m = 1.0 - k * cz;
    *a = exp(-k * z0) * (exp(-m * u0) - exp(-m * u1)) / m;
    double du = 1e-3, top = fmin(u1, u0 + 40.0);
    for (double u = u0; u < top; u += du) {
        double um = u + 0.5 * du, z = z0 - um * cz;
        *bound += exp(-um - k * z) * (exp(k * bin_width_at(z)) - 1.0) * du;
    }
}

/* Closed form for the bin averages themselves (J constant on each z-bin, whatever rho and
 * phi do): the sum over the z-bins the line crosses of J_i (e^{-u_in} - e^{-u_out}). */
static double stepwise_case(const centre *c, double k, double length)
{
    double u0, u1, cz = c->w[2], z0 = c->p[2];
    support(c, length, &u0, &u1);
    if (!(u1 > u0) || cz == 0)
        return 0.0;
    double sum = 0.0;
    int step = cz > 0 ? -1 : 1;
    for (int i = c->iz; i >= 0 && i < (int)NS_TABLE_NZ; i += step) {
        double a = (z0 - grid.z[cz > 0 ? i + 1 : i]) / cz,
               b = (z0 - grid.z[cz > 0 ? i : i + 1]) / cz;
        a = fmax(a, u0);
        b = fmin(b, u1);
        if (b > a)
            sum += bin_average(i, k) * (exp(-a) - exp(-b));
    }
    return sum;
}

static float *exponential_j(void)
{
    float *j = malloc(3 * cells * sizeof(float));
    for (size_t cell = 0; cell < cells; cell++) {
        int iz = (int)(cell / (NS_TABLE_NRHO * NS_TABLE_NTHETA * NS_TABLE_NPHI));
        for (int ch = 0; ch < 3; ch++)
            j[ch * cells + cell] = (float)bin_average(iz, ks[ch]);
    }
    return j;
}

static void check_exponential(const float *a, double length, const char *what)
{
    int step_failures = 0, smooth_failures = 0, tested = 0;
    double worst_step = 0.0, sum_error = 0.0, sum_bound = 0.0, worst_smooth = 0.0;
    for (int n = 0; n < 800; n++) {
        /* Every other cell within 20 mfp of the source, where the bins are fine enough for
         * the smooth closed form to say something; the others anywhere (stepwise only). */
        size_t cell = next_random() % cells;
        centre c = cell_centre(cell);
        int near = fabs(c.p[2]) < 20 && c.p[0] < 20;
        if (n % 2 && !near) {
            n--;
            continue;
        }
        for (int ch = 0; ch < 3; ch++) {
            double got = a[ch * cells + cell];
            /* The cut leaves at most 1e-4 of A or 1e-14 J_max (J_max <= 1); float sums. */
            double stepwise = stepwise_case(&c, ks[ch], length);
            double tol = 2e-4 * stepwise + 1e-13;
            if (stepwise > 1e-10) /* below the cut's floor only the absolute error counts */
                worst_step = fmax(worst_step, fabs(got - stepwise) / stepwise);
            if (fabs(got - stepwise) > tol && step_failures++ < 5)
                fprintf(stderr,
                        "%s: cell %zu ch %d (z %.4g rho %.4g cos %.3f): A %.7g, stepwise "
                        "closed form %.7g\n",
                        what, cell, ch, c.p[2], c.p[0], c.w[2], got, stepwise);
            if (!near)
                continue;
            double smooth, bound;
            smooth_case(&c, ks[ch], length, &smooth, &bound);
            tol = bound + 2e-4 * smooth + 1e-13;
            tested++;
            if (smooth > 1e-10) {
                sum_error += fabs(got - smooth) / smooth;
                sum_bound += bound / smooth;
                worst_smooth = fmax(worst_smooth, fabs(got - smooth) / smooth);
            }
            if (fabs(got - smooth) > tol && smooth_failures++ < 5)
                fprintf(stderr,
                        "%s: cell %zu ch %d (z %.4g rho %.4g cos %.3f): A %.7g, closed "
                        "form %.7g, tolerance %.3g\n",
                        what, cell, ch, c.p[2], c.p[0], c.w[2], got, smooth, tol);
        }
    }
    CHECK_INT(step_failures, 0);
    CHECK_INT(smooth_failures, 0);
    printf("%s: stepwise J worst relative error %.2e (tolerance 2e-4); smooth e^{-kz} at %d "
           "values within 20 mfp (relative figures above 1e-10): mean relative error %.2e, mean "
           "tolerance %.2e, worst %.2e\n",
           what, worst_step, tested, sum_error / tested, sum_bound / tested, worst_smooth);
}

/* A of j walked from every cell (zero_from = NS_TABLE_NRHO) and as ns_tables_accumulate
 * does it (told where J's radial support ends, lines that stay outside it skipped): the same
 * floats, bit for bit, and the steps of both. */
static void compare_skipped(const float *j, const char *what, uint64_t *steps_all,
                            uint64_t *steps_skipped)
{
    ns_scatter_tables all, skipped;
    ns_error err = {0};
    int status = ns_tables_accumulate_within(test_context(), j, NS_ACCUMULATION_EXACT,
                                             NS_TABLE_NRHO, &all, steps_all, &err);
    CHECK_INT(status, NS_OK);
    if (status)
        return;
    status = ns_tables_accumulate(test_context(), j, NS_ACCUMULATION_EXACT, &skipped,
                                  steps_skipped, &err);
    CHECK_INT(status, NS_OK);
    if (!status) {
        CHECK(memcmp(all.a.mapped, skipped.a.mapped, 3 * cells * sizeof(float)) == 0);
        printf("%s: %llu steps walking every line, %llu skipping those outside J's support\n",
               what, (unsigned long long)*steps_all, (unsigned long long)*steps_skipped);
        ns_scatter_tables_free(test_context(), &skipped);
    }
    ns_scatter_tables_free(test_context(), &all);
    ns_error bad = {0};
    CHECK_INT(ns_tables_accumulate_within(test_context(), j, NS_ACCUMULATION_EXACT,
                                          NS_TABLE_NRHO + 1, &all, NULL, &bad),
              NS_ERR_INVALID_ARGUMENT);
}

/* One channel of J (float [cells]) near the axis only: light leaving the source along its
 * axis and scattering once within a Gaussian tube 0.1 mfp wide, e^{-z} [z > 0] K(rho), as
 * bin averages. 0 beyond about 1.5 mfp of the axis, where its Gaussian underflows. */
static void tube_j(float *j)
{
    const double two_var = 2.0 * 0.1 * 0.1;
    double along_z[NS_TABLE_NZ], across[NS_TABLE_NRHO];
    for (uint32_t i = 0; i < NS_TABLE_NZ; i++) {
        double z0 = fmax(grid.z[i], 0.0), z1 = fmax(grid.z[i + 1], 0.0);
        along_z[i] = (exp(-z0) - exp(-z1)) / (grid.z[i + 1] - grid.z[i]);
    }
    for (uint32_t i = 0; i < NS_TABLE_NRHO; i++) {
        double r0 = grid.rho[i], r1 = grid.rho[i + 1];
        across[i] = (exp(-r0 * r0 / two_var) - exp(-r1 * r1 / two_var)) / (M_PI * (r1 * r1 - r0 * r0));
    }
    size_t at = 0;
    for (uint32_t iz = 0; iz < NS_TABLE_NZ; iz++)
        for (uint32_t ir = 0; ir < NS_TABLE_NRHO; ir++)
            for (uint32_t k = 0; k < NS_TABLE_NTHETA * NS_TABLE_NPHI; k++)
                j[at++] = (float)(along_z[iz] * across[ir]);
}

/* A table that is 0 beyond ~1.5 mfp of the axis (tube_j): the lines that stay outside are
 * not walked (about 40% of the lines; their walks would stop at once on the remainder bound,
 * so this saves a step or a few each), and A is what walking them gives. A table with light
 * in its last rho bin skips nothing. */
static void test_radial_support_skips_walks(void)
{
    float *j = calloc(3 * cells, sizeof *j);
    tube_j(j); /* channel 0 */
    for (size_t i = 0; i < cells; i++)
        j[2 * cells + i] = 0.5f * j[i]; /* channel 2 too; channel 1 stays 0 */
    uint64_t all = 0, skipped = 0;
    compare_skipped(j, "a tube near the axis", &all, &skipped);
    CHECK(skipped > 0 && skipped < all * 9 / 10); /* 0.88 of them, 2026-12-02 */
    free(j);

    j = exponential_j();
    compare_skipped(j, "exponential (light in every rho bin)", &all, &skipped);
    CHECK(skipped == all);
    free(j);
}

/* The exponential J (light in every rho bin, z > 0) in the theta bins `keep` only. */
static float *exponential_j_in_theta(const int *keep, int n)
{
    float *j = exponential_j();
    for (size_t cell = 0; cell < cells; cell++) {
        int it = (int)(cell / NS_TABLE_NPHI % NS_TABLE_NTHETA), kept = 0;
        for (int k = 0; k < n; k++)
            kept = kept || it == keep[k];
        if (!kept)
            for (int ch = 0; ch < 3; ch++)
                j[ch * cells + cell] = 0.0f;
    }
    return j;
}

/* The remainder bounds (accumulate_shared.h): theta is constant along a line, so a line in a
 * theta bin without light has nothing left to gather from its start, and stops after its
 * first step. With light in theta bin 12 alone, in 13 alone, and in both, the lines of each
 * bin walk the same in the table of both as in their own (their J and their bound are the
 * same), so in steps(12) + steps(13) - steps(both) those walks cancel and what is left is
 * the dark lines' steps: the other sixteen bins' twice less once, bin 13's in the first,
 * bin 12's in the second; one step each makes that one step per line of all eighteen bins.
 * With the table's peak as the bound (no remainder bounds) they walk tens of steps each.
 * A adds up bit for bit, and is 0 exactly in the dark bins. */
static void test_remainder_bounds_stop_dark_lines(void)
{
    const int bin12[] = {12}, bin13[] = {13}, both[] = {12, 13};
    float *j12 = exponential_j_in_theta(bin12, 1), *j13 = exponential_j_in_theta(bin13, 1);
    float *j_both = exponential_j_in_theta(both, 2);
    float *a12 = NULL, *a13 = NULL, *a_both = NULL;
    uint64_t s12 = 0, s13 = 0, s_both = 0;
    if (!accumulate(j12, NS_ACCUMULATION_EXACT, &a12, &s12) &&
        !accumulate(j13, NS_ACCUMULATION_EXACT, &a13, &s13) &&
        !accumulate(j_both, NS_ACCUMULATION_EXACT, &a_both, &s_both)) {
        uint64_t lines_per_theta = 0;
        for (uint32_t ip = 0; ip < NS_TABLE_NPHI; ip++)
            lines_per_theta += ns_accumulate_phi_lines(ip);
        lines_per_theta *= (uint64_t)NS_TABLE_NZ * NS_TABLE_NRHO;
        CHECK(s12 + s13 - s_both == (uint64_t)NS_TABLE_NTHETA * lines_per_theta);
        int sums = 1, dark_zero = 1;
        for (size_t i = 0; i < 3 * cells; i++) {
            int it = (int)(i % cells / NS_TABLE_NPHI % NS_TABLE_NTHETA);
            float want = it == 12 ? a12[i] : it == 13 ? a13[i] : 0.0f;
            sums = sums && a_both[i] == want;
            dark_zero = dark_zero && (it == 12 || a12[i] == 0.0f);
        }
        CHECK(sums);
        CHECK(dark_zero);
        printf("light in one theta bin: %llu steps (12), %llu (13), %llu (both); the lines of "
               "the dark bins take one step each\n",
               (unsigned long long)s12, (unsigned long long)s13, (unsigned long long)s_both);
    }
    free(a12);
    free(a13);
    free(a_both);
    free(j12);
    free(j13);
    free(j_both);
}

static void test_closed_form_exponential(void)
{
    float *j = exponential_j(), *a = NULL, *a5 = NULL;
    uint64_t steps = 0;
    double t0 = ns_now_ms();
    if (accumulate(j, NS_ACCUMULATION_EXACT, &a, &steps) == 0) {
        double ms = ns_now_ms() - t0;
        printf("accumulate (exact): %.0f ms, %.3g steps (%.3g per cell), %.3g lookups/s "
               "(3 channels per step)\n",
               ms, (double)steps, (double)steps / cells, 3.0 * steps / (ms * 1e-3));
        CHECK(steps >= cells);
        check_exponential(a, INFINITY, "exact");
    }
    /* (c) paper mode: only the first 5 mfp. */
    if (accumulate(j, NS_ACCUMULATION_PAPER, &a5, &steps) == 0)
        check_exponential(a5, NS_PAPER_ACCUMULATION_MFP, "paper");
    free(a);
    free(a5);
    free(j);
}

/* ---------------------------------------------------------------------------------------
 * (b), (c): the network's tables of one material
 * ------------------------------------------------------------------------------------- */
static const ns_table_key nn_key = {.source = NS_METHOD_NN,
                                    .g = 0.5f,
                                    .albedo = {0.3f, 0.8f, 0.95f},
                                    .orders = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE,
                                    .accumulation = NS_ACCUMULATION_EXACT};

/* J of key's channel ch, both orders summed (from the cache the call filled). */
static float *summed_j(const ns_table_key *key, int ch)
{
    const float *jd = ns_tables_cached_j(test_context(), key->source, key->g, key->albedo[ch], 0);
    const float *jm = ns_tables_cached_j(test_context(), key->source, key->g, key->albedo[ch], 1);
    CHECK(jd && jm);
    if (!jd || !jm)
        return NULL;
    float *j = malloc(cells * sizeof(float));
    for (size_t i = 0; i < cells; i++)
        j[i] = jd[i] + jm[i];
    return j;
}

static const float *get_tables(const ns_table_key *key, ns_table_stats *stats)
{
    const ns_scatter_tables *t = NULL;
    ns_error err = {0};
    int status = ns_tables_get(test_context(), key, &t, stats, &err);
    if (status)
        fprintf(stderr, "ns_tables_get: %s (%s)\n", err.message, ns_status_name(status));
    CHECK_INT(status, NS_OK);
    return t ? t->a.mapped : NULL;
}

/* A cell near the source (|z|, rho < 8 mfp), where the light is. */
static size_t random_near_cell(void)
{
    for (;;) {
        size_t cell = next_random() % cells;
        centre c = cell_centre(cell);
        if (fabs(c.p[2]) < 8 && c.p[0] < 8)
            return cell;
    }
}

/* The A table's value at point p (nearest bin) and the spread of its neighbours in z, rho
 * and phi: where between cell centres the continuous A lies is only known to that spread. */
static double table_value(const float *a, const double p[3], const double w[3], double *spread)
{
    long cell = table_cell(p, w);
    *spread = 0.0;
    if (cell < 0)
        return 0.0;
    long ip = cell % NS_TABLE_NPHI, ir = cell / (NS_TABLE_NPHI * NS_TABLE_NTHETA) % NS_TABLE_NRHO;
    long iz = cell / ((long)NS_TABLE_NPHI * NS_TABLE_NTHETA * NS_TABLE_NRHO);
    long strides[3] = {(long)NS_TABLE_NPHI * NS_TABLE_NTHETA * NS_TABLE_NRHO,
                       (long)NS_TABLE_NPHI * NS_TABLE_NTHETA, 1};
    long index[3] = {iz, ir, ip}, count[3] = {NS_TABLE_NZ, NS_TABLE_NRHO, NS_TABLE_NPHI};
    double lo = a[cell], hi = a[cell];
    for (int axis = 0; axis < 3; axis++)
        for (int d = -1; d <= 1; d += 2) {
            long i = index[axis] + d;
            if (i < 0 || i >= count[axis])
                continue;
            double v = a[cell + d * strides[axis]];
            lo = fmin(lo, v);
            hi = fmax(hi, v);
        }
    *spread = hi - lo;
    return a[cell];
}

/* The A table's value at point p read between cell centres as the gather reads it
 * (shaders/gather.glsl table_at, written here independently in double): linear in the
 * continuous asinh index of z and rho and in theta between the centres, on Kuhn's
 * tetrahedra, held beyond the first and last centres, phi at the nearest bin. */
static double table_value_between(const float *a, const double p[3], const double w[3])
{
    double rho = hypot(p[0], p[1]);
    if (fabs(p[2]) >= grid.extent || rho >= grid.extent)
        return 0.0;
    double fz = asinh(p[2] / grid.scale) / grid.step + NS_TABLE_NZ / 2 - 0.5;
    double fr = asinh(rho / grid.scale) / grid.step - 0.5;
    fz = fmin(fmax(fz, 0.0), NS_TABLE_NZ - 1);
    fr = fmin(fmax(fr, 0.0), NS_TABLE_NRHO - 1);
    int iz = fz >= NS_TABLE_NZ - 1 ? NS_TABLE_NZ - 2 : (int)fz;
    int ir = fr >= NS_TABLE_NRHO - 1 ? NS_TABLE_NRHO - 2 : (int)fr;
    double tz = fz - iz, tr = fr - ir;
    double cos_theta = fmax(-1.0, fmin(1.0, w[2])), step = M_PI / NS_TABLE_NTHETA;
    double ft = acos(cos_theta) / step - 0.5;
    int it = ft <= 0 ? 0 : ft >= NS_TABLE_NTHETA - 2 ? NS_TABLE_NTHETA - 2 : (int)ft;
    double tt = fmin(fmax((acos(cos_theta) - (it + 0.5) * step) / step, 0.0), 1.0);
    double wh = hypot(w[0], w[1]);
    double cos_phi = rho > 0 && wh > 0 ? (w[0] * p[0] + w[1] * p[1]) / (wh * rho) : 1.0;
    int ip = angle_bin(acos(fmax(-1.0, fmin(1.0, cos_phi))));
    /* Kuhn's tetrahedron holding the point: from the lower corner step along the axes in
     * decreasing order of their fractions; the weights are the differences of the sorted
     * fractions. */
    double t[3] = {tz, tr, tt};
    int order[3] = {0, 1, 2}; /* z, rho, theta; ties keep this order */
    for (int i = 0; i < 3; i++)
        for (int k = 0; k + 1 < 3 - i; k++)
            if (t[order[k + 1]] > t[order[k]]) {
                int swap = order[k];
                order[k] = order[k + 1];
                order[k + 1] = swap;
            }
    int corner[3] = {0, 0, 0};
    double sum = 0.0, previous = 1.0;
    for (int k = 0; k <= 3; k++) {
        double next = k < 3 ? t[order[k]] : 0.0;
        long cell = (((long)(iz + corner[0]) * NS_TABLE_NRHO + ir + corner[1]) * NS_TABLE_NTHETA + it +
                     corner[2]) * NS_TABLE_NPHI + ip;
        sum += (previous - next) * a[cell];
        if (k < 3)
            corner[order[k]] = 1;
        previous = next;
    }
    return sum;
}

/* Double scattering depends on the albedo only through a^2 (scatter_tables.c, unit_double):
 * every channel's double J at one g is a^2 times one table, within float rounding, in one
 * material and in a later one, with the exact energy a^2. The networks evaluated at each
 * albedo differ in shape by 0.1-0.9% (L1), single cells by far more: this fails if each
 * albedo's double table is the network's own. */
static void test_double_from_one_table_per_g(void)
{
    const ns_table_key first = {.source = NS_METHOD_NN,
                                .g = 0.65f,
                                .albedo = {0.3f, 0.8f, 0.995f},
                                .orders = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE,
                                .accumulation = NS_ACCUMULATION_EXACT};
    ns_table_key second = first;
    second.albedo[0] = 0.6f;
    second.albedo[1] = 0.6f;
    second.albedo[2] = 0.6f;
    ns_table_stats stats;
    if (!get_tables(&first, &stats) || !get_tables(&second, &stats))
        return;
    const float albedos[4] = {0.3f, 0.8f, 0.995f, 0.6f};
    const float *unit_source =
        ns_tables_cached_j(test_context(), NS_METHOD_NN, first.g, albedos[0], 0);
    CHECK(unit_source != NULL);
    if (!unit_source)
        return;
    double worst = 0.0;
    for (int k = 1; k < 4; k++) {
        const float *j = ns_tables_cached_j(test_context(), NS_METHOD_NN, first.g, albedos[k], 0);
        CHECK(j != NULL);
        if (!j)
            continue;
        double ratio = (double)albedos[k] * albedos[k] / ((double)albedos[0] * albedos[0]);
        size_t zeros_apart = 0;
        for (size_t i = 0; i < cells; i++) {
            double want = unit_source[i] * ratio;
            if (want > 0.0)
                worst = fmax(worst, fabs(j[i] - want) / want);
            else
                zeros_apart += j[i] != 0.0f;
        }
        CHECK_INT(zeros_apart, 0);
        const ns_nn_grid energy_grid = {
            .n = {NS_TABLE_NZ, NS_TABLE_NRHO, NS_TABLE_NTHETA, NS_TABLE_NPHI},
            .edges = {grid.z, grid.rho, grid.theta, grid.phi}};
        CHECK_REL(ns_nn_grid_energy(&energy_grid, j), (double)albedos[k] * albedos[k], 1e-4);
    }
    printf("double scattering at g 0.65, albedos 0.3 / 0.8 / 0.995 / 0.6: every table a^2 times "
           "one, worst cell %.2e relative\n",
           worst);
    CHECK(worst < 1e-6);
}

static void test_network_tables_brute_force(void)
{
    ns_table_stats stats;
    double t0 = ns_now_ms();
    const float *a = get_tables(&nn_key, &stats);
    if (!a)
        return;
    printf("nn tables (g 0.5, albedo 0.3/0.8/0.95): reconstruct %.0f ms, accumulate %.0f ms, "
           "total %.0f ms, weights %llu bytes\n",
           stats.reconstruct_ms, stats.accumulate_ms, ns_now_ms() - t0,
           (unsigned long long)stats.weights_bytes);
    CHECK(stats.reconstruct_ms > 0 && stats.accumulate_ms > 0 && !stats.cache_hit);
    CHECK(stats.weights_bytes > 20000 && stats.weights_bytes < 2 * 12288);
    float *copy = malloc(3 * cells * sizeof(float)); /* the cache may evict it later */
    memcpy(copy, a, 3 * cells * sizeof(float));
    int point_failures = 0, segment_failures = 0;
    double worst_point = 0, worst_segment = 0;
    /* A at the exit point itself, nearest cell and between cells, against the brute force
     * from that point (issue 15: what reading between cells gains), and the segment form with
     * each: mean and worst relative errors. */
    double exit_err[2] = {0, 0}, exit_worst[2] = {0, 0}, seg_err[2] = {0, 0}, seg_worst[2] = {0, 0};
    int exit_n = 0, seg_n = 0;
    for (int ch = 0; ch < 3; ch++) {
        float *j = summed_j(&nn_key, ch);
        if (!j)
            continue;
        const float *ac = copy + ch * cells;
        float j_max = 0;
        for (size_t i = 0; i < cells; i++)
            j_max = fmaxf(j_max, j[i]);
        for (int n = 0; n < 40; n++) {
            /* Half of the cells in the first two phi bins, where a cell holds the mean of
             * several lines. */
            size_t cell = random_near_cell();
            if (n % 2)
                cell = cell - cell % NS_TABLE_NPHI + (size_t)(n % 4 == 1 ? 0 : 1);
            centre c = cell_centre(cell);
            uint32_t lines = ns_accumulate_phi_lines((uint32_t)c.ip);
            /* A in the cell: the mean over its lines of the whole line (40 mfp leaves e^-40
             * of J_max behind). */
            double want = 0;
            for (uint32_t k = 0; k < lines; k++) {
                centre line = cell_line(cell, k);
                want += brute_force(j, line.p, line.w, 40.0) / lines;
            }
            double tol = 3e-3 * want + 1e-13 * j_max;
            worst_point = fmax(worst_point, fabs(ac[cell] - want) / want);
            if (fabs(ac[cell] - want) > tol && point_failures++ < 5)
                fprintf(stderr, "channel %d cell %zu: A %.7g, brute force %.7g\n", ch, cell,
                        ac[cell], want);
            /* A segment of random length from the centre: the exact segment form, in the
             * mean over the cell's lines. */
            double length = 0.2 + 4.0 * uniform01();
            double a_exit = 0, spread = 0, direct = 0;
            for (uint32_t k = 0; k < lines; k++) {
                centre line = cell_line(cell, k);
                double exit_k[3] = {line.p[0] - length * line.w[0], line.p[1] - length * line.w[1],
                                    line.p[2] - length * line.w[2]};
                double spread_k;
                a_exit += table_value(ac, exit_k, line.w, &spread_k) / lines;
                spread = fmax(spread, spread_k);
                direct += brute_force(j, line.p, line.w, length) / lines;
            }
            double segment = ac[cell] - exp(-length) * a_exit;
            double seg_tol = exp(-length) * spread + 3e-3 * want + 1e-13 * j_max;
            /* Reading A at a point (the exit of a cell's one line) nearest and between cells. */
            double exit[3] = {c.p[0] - length * c.w[0], c.p[1] - length * c.w[1],
                              c.p[2] - length * c.w[2]};
            double exit_want = lines == 1 ? brute_force(j, exit, c.w, 40.0) : 0;
            double got[2] = {a_exit, table_value_between(ac, exit, c.w)};
            for (int k = 0; k < 2 && lines == 1; k++) {
                double es = fabs(ac[cell] - exp(-length) * got[k] - direct) / want;
                seg_err[k] += es;
                seg_worst[k] = fmax(seg_worst[k], es);
                seg_n += k;
                if (exit_want > 1e-6 * j_max) {
                    double e = fabs(got[k] - exit_want) / exit_want;
                    exit_err[k] += e;
                    exit_worst[k] = fmax(exit_worst[k], e);
                    exit_n += k;
                }
            }
            worst_segment = fmax(worst_segment, fabs(segment - direct) / want);
            if (fabs(segment - direct) > seg_tol && segment_failures++ < 5)
                fprintf(stderr,
                        "channel %d cell %zu L %.3f: segment form %.7g, brute force "
                        "%.7g, tolerance %.3g\n",
                        ch, cell, length, segment, direct, seg_tol);
        }
        free(j);
    }
    CHECK_INT(point_failures, 0);
    CHECK_INT(segment_failures, 0);
    printf("nn tables: A vs brute force worst %.2e relative; segment form worst error %.2e "
           "of A(entry)\n",
           worst_point, worst_segment);
    if (exit_n > 0) {
        printf("A at %d exit points against brute force, mean / worst relative error: nearest cell "
               "%.3f / %.3f, between cells %.3f / %.3f; segment form of the %d one-line cells, "
               "of A(entry): %.4f / %.3f, %.4f / %.3f\n",
               exit_n, exit_err[0] / exit_n, exit_worst[0], exit_err[1] / exit_n, exit_worst[1],
               seg_n, seg_err[0] / seg_n, seg_worst[0], seg_err[1] / seg_n, seg_worst[1]);
        /* The gather's reads between cells must do better than the nearest cell on average. */
        CHECK(exit_err[1] < exit_err[0]);
        CHECK(seg_err[1] < seg_err[0]);
    }
    free(copy);
}

/* (e) A plane of beams. Endless beams start at every point of the plane z = 0 (one per unit
 * area, all along +z), and a camera line enters at the plane at 35 degrees from it, so that
 * light reaches the camera along w at a theta bin's centre: 125 degrees from the beams when
 * the camera goes the beams' way (a face the light enters, the camera on the light's side),
 * 35 degrees when it goes against them (the beams leave through the face it enters: ghosts).
 * What the gather gives the camera, in expectation over where the beams start, is the mean
 * over the plane of A read at (z = 0, rho, phi) as the gather reads it; what it should give
 * is the binned J's own integral: the plane makes the field at depth d the sum over rho and
 * phi bins of J times the ring's area, and the line takes e^{-u} of it at |z| = u |cos
 * theta|. The two must agree. A cell holding A on its phi bin's centre line instead of the
 * bin's mean read 5.8% low going the beams' way, and the two cells beside the plane holding
 * A at their centres (the read at z = 0 interpolates across the kink A has there) read 10.5%
 * high going against them (docs/scattering.md, *The phi bins' mean*, *A on the source's
 * plane*). J_2 of the network's material (g 0.5), where J peaks beside the beams. */
static void plane_of_beams(const float *a, const ns_table_key *key, int it)
{
    double theta = (it + 0.5) * M_PI / NS_TABLE_NTHETA, c = cos(theta);
    for (int ch = 0; ch < 3; ch++) {
        const float *j = ns_tables_cached_j(test_context(), key->source, key->g, key->albedo[ch], 0);
        CHECK(j != NULL);
        if (!j)
            continue;
        double want = 0;
        for (int iz = 0; iz < NS_TABLE_NZ; iz++) {
            /* The part of the camera line in bin iz: z = -u cos theta. */
            double z0 = grid.z[iz], z1 = grid.z[iz + 1], u0, u1;
            if (c > 0 ? z0 >= 0 : z1 <= 0)
                continue;
            if (c > 0) {
                u0 = -fmin(z1, 0.0) / c;
                u1 = -z0 / c;
            } else {
                u0 = fmax(z0, 0.0) / -c;
                u1 = z1 / -c;
            }
            double field = 0; /* in bin iz, per unit source area */
            for (int ir = 0; ir < NS_TABLE_NRHO; ir++) {
                double ring = M_PI * (grid.rho[ir + 1] * grid.rho[ir + 1] - grid.rho[ir] * grid.rho[ir]);
                for (int ip = 0; ip < NS_TABLE_NPHI; ip++)
                    field += ring / NS_TABLE_NPHI *
                             j[(((size_t)iz * NS_TABLE_NRHO + ir) * NS_TABLE_NTHETA + it) * NS_TABLE_NPHI + ip];
            }
            want += field * (exp(-u0) - exp(-u1));
        }
        /* The mean over the plane: rho on a log scale from 1e-4 mfp (below it A is held at
         * its first centre and the area is 3e-8) to the extent, phi uniformly. */
        const float *ac = a + ch * cells;
        const int n_rho = 2000, n_phi = 144;
        double lo = log(1e-4), hi = log(grid.extent), got = 0;
        for (int q = 0; q < n_rho; q++) {
            double rho = exp(lo + (q + 0.5) * (hi - lo) / n_rho), d_rho = rho * (hi - lo) / n_rho;
            double p[3] = {rho, 0, 0}, mean = 0;
            for (int k = 0; k < n_phi; k++) {
                double phi = (k + 0.5) * M_PI / n_phi;
                double w[3] = {sin(theta) * cos(phi), sin(theta) * sin(phi), cos(theta)};
                mean += table_value_between(ac, p, w) / n_phi;
            }
            got += 2 * M_PI * rho * d_rho * mean;
        }
        printf("plane of beams, theta %.0f, channel %d (albedo %.2f): A read on the plane %.6g, "
               "J integrated %.6g (%+.2f%%)\n",
               theta * 180 / M_PI, ch, key->albedo[ch], got, want, 100 * (got / want - 1));
        CHECK(want > 0);
        CHECK(fabs(got / want - 1) < 0.015);
    }
}

static void test_plane_of_beams(void)
{
    ns_table_key key = nn_key;
    key.orders = NS_COMPONENT_DOUBLE;
    ns_table_stats stats;
    const float *a = get_tables(&key, &stats);
    if (!a)
        return;
    plane_of_beams(a, &key, 12); /* the camera goes the beams' way */
    plane_of_beams(a, &key, 3);  /* against them */
}

/* ---------------------------------------------------------------------------------------
 * (d) the cache
 * ------------------------------------------------------------------------------------- */
static void test_cache_hit_and_eviction(void)
{
    ns_context *ctx = test_context();
    ns_table_stats stats;
    const ns_scatter_tables *first = NULL, *second = NULL;
    ns_error err = {0};
    CHECK_INT(ns_tables_get(ctx, &nn_key, &first, &stats, &err), NS_OK);
    CHECK_INT(ns_tables_get(ctx, &nn_key, &second, &stats, &err), NS_OK);
    CHECK(first == second && stats.cache_hit == 1);
    CHECK(stats.reconstruct_ms == 0.0 && stats.accumulate_ms == 0.0);
    CHECK(stats.weights_bytes > 0);

    /* Room for the three channels' J and two A tables. Other components reuse the J (no
     * reconstruction); the third A evicts the least recently used, the first key. */
    uint64_t j_bytes = 3 * 2 * cells * sizeof(float), a_bytes = 3 * cells * sizeof(float);
    uint64_t saved = ctx->table_cache_bytes;
    ctx->table_cache_bytes = j_bytes + 2 * a_bytes;
    ns_table_key keys[3] = {nn_key, nn_key, nn_key};
    keys[0].orders = NS_COMPONENT_DOUBLE;
    keys[1].orders = NS_COMPONENT_MULTIPLE;
    float *parts[2] = {NULL, NULL};
    const float *sum = NULL;
    for (int i = 0; i < 3; i++) {
        const ns_scatter_tables *t = NULL;
        CHECK_INT(ns_tables_get(ctx, &keys[i], &t, &stats, &err), NS_OK);
        if (!t)
            break;
        CHECK(stats.cache_hit == 0 && stats.accumulate_ms > 0); /* the first key was evicted */
        CHECK(stats.reconstruct_ms == 0.0);
        uint64_t bytes;
        uint32_t entries;
        ns_tables_cache_usage(ctx, &bytes, &entries);
        CHECK(bytes <= ctx->table_cache_bytes);
        CHECK_INT(entries, 5); /* 3 J + 2 A */
        if (i < 2) {
            parts[i] = malloc(a_bytes);
            memcpy(parts[i], t->a.mapped, a_bytes);
        } else {
            sum = t->a.mapped;
        }
    }
    /* The double table plus the multiple table is the summed one. */
    if (sum && parts[0] && parts[1]) {
        /* Each table's cut leaves 1e-4 of it, or 1e-14 of its J_max (below 1e-12 of A_max). */
        int bad = 0;
        for (int c = 0; c < 3; c++) {
            float a_max = 0;
            for (size_t i = 0; i < cells; i++)
                a_max = fmaxf(a_max, sum[c * cells + i]);
            for (size_t i = c * cells; i < (c + 1) * cells; i += 97)
                bad += fabsf(parts[0][i] + parts[1][i] - sum[i]) > 3e-4f * sum[i] + 1e-12f * a_max;
        }
        CHECK_INT(bad, 0);
    }
    free(parts[0]);
    free(parts[1]);
    ctx->table_cache_bytes = saved;
    CHECK_INT(ctx->dev.live_buffers, 0); /* cached tables are the context's, not a leak */
}

/* Albedo 0 (clear glass): J and A are 0 exactly, without the network or a walk. */
static void test_zero_albedo_costs_nothing(void)
{
    ns_table_key key = nn_key;
    key.albedo[0] = key.albedo[1] = key.albedo[2] = 0.0f;
    ns_table_stats stats;
    const float *a = get_tables(&key, &stats);
    if (!a)
        return;
    CHECK(stats.reconstruct_ms == 0.0 && !stats.cache_hit);
    int nonzero = 0;
    for (size_t i = 0; i < 3 * cells; i++)
        nonzero += a[i] != 0.0f;
    CHECK_INT(nonzero, 0);
    const float *j = ns_tables_cached_j(test_context(), NS_METHOD_NN, 0.5f, 0.0f, 1);
    CHECK(j && j[0] == 0.0f && j[cells - 1] == 0.0f);
}

/* Method table through a stand-in provider (tables of zeros, so no walk is needed): channel
 * albedos equal up to float rounding are one call, a provider's failure reaches the caller
 * with its message, and a table with a NaN is refused. */
static int provider_calls;
static int stand_in_provider(void *user, double g, double albedo, float *jd, float *jm,
                             ns_error *err)
{
    provider_calls++;
    memset(jd, 0, cells * sizeof(float));
    memset(jm, 0, cells * sizeof(float));
    if (user && !strcmp(user, "nan"))
        jm[cells / 2] = NAN;
    if (user && !strcmp(user, "fail"))
        return ns_fail(err, NS_ERR_IO, "stand-in provider: disk full");
    return 0;
}

static void test_table_source_through_provider(void)
{
    ns_context *ctx = test_context();
    ns_mc_tables_fn saved_fn = ctx->mc_tables;
    void *saved_user = ctx->mc_user;
    ctx->mc_tables = stand_in_provider;
    ctx->mc_user = NULL;
    ns_table_key key = {.source = NS_METHOD_TABLE,
                        .g = -0.2f,
                        .albedo = {0.6f, 0.6f + 2e-6f, 0.7f},
                        .orders = NS_COMPONENT_MULTIPLE};
    ns_table_stats stats;
    provider_calls = 0;
    CHECK(get_tables(&key, &stats) != NULL);
    CHECK_INT(provider_calls, 2);
    CHECK_INT(stats.weights_bytes, 0);

    const ns_scatter_tables *t = NULL;
    ns_error err = {0};
    key.albedo[0] = key.albedo[1] = key.albedo[2] = 0.3f;
    ctx->mc_user = "nan";
    CHECK_INT(ns_tables_get(ctx, &key, &t, &stats, &err), NS_ERR_INTERNAL);
    CHECK_STR_CONTAINS(err.message, "provider");
    key.albedo[0] = key.albedo[1] = key.albedo[2] = 0.4f;
    ctx->mc_user = "fail";
    CHECK_INT(ns_tables_get(ctx, &key, &t, &stats, &err), NS_ERR_IO);
    CHECK_STR_CONTAINS(err.message, "disk full");
    ctx->mc_tables = saved_fn;
    ctx->mc_user = saved_user;
}

static void test_bad_keys(void)
{
    ns_context *ctx = test_context();
    const ns_scatter_tables *t = (const ns_scatter_tables *)&t;
    ns_error err = {0};
    ns_table_key key = nn_key;
    key.albedo[1] = 1.0f;
    CHECK_INT(ns_tables_get(ctx, &key, &t, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "albedo[1]");
    CHECK(t == NULL);
    key = nn_key;
    key.g = NAN;
    CHECK_INT(ns_tables_get(ctx, &key, &t, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "g");
    key = nn_key;
    key.orders = NS_COMPONENT_SINGLE;
    CHECK_INT(ns_tables_get(ctx, &key, &t, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    /* The blurred first order is computed in the gather: it has no table. */
    key = nn_key;
    key.orders |= NS_TABLE_FIRST_BLURRED;
    CHECK_INT(ns_tables_get(ctx, &key, &t, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "orders");
    key = nn_key;
    key.source = NS_METHOD_TABLE; /* test_context has no Monte Carlo provider */
    CHECK_INT(ns_tables_get(ctx, &key, &t, NULL, &err), NS_ERR_NOT_AVAILABLE);
    CHECK_STR_CONTAINS(err.message, "provider");
    key = nn_key;
    key.g = -0.3f; /* the network covers g in [0, 1) */
    CHECK_INT(ns_tables_get(ctx, &key, &t, NULL, &err), NS_ERR_INVALID_ARGUMENT);
}

/* ---------------------------------------------------------------------------------------
 * Measurement (not a test): NSCATTER_BENCH_ACCUMULATE=N runs N RGB materials (distinct
 * albedos, so every one misses the cache), N walks of the networks' J of two materials and
 * N accumulations of the synthetic J, and prints the medians. With
 * NSCATTER_BENCH_ACCUMULATE_DUMP=PREFIX it also writes the two materials' A (float
 * [3][cells]) to PREFIX_0.f32 and PREFIX_1.f32, to compare two builds' tables (how the
 * remainder bounds' A was compared with the walk before them, docs/bench.md).
 * ------------------------------------------------------------------------------------- */
static int compare_doubles(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

static double median(double *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, compare_doubles);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

static double cpu_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

static void bench(int n)
{
    double recon[64], acc[64], synth[64], rate[64], cpu[64], material_cpu[64];
    n = n > 64 ? 64 : n;
    for (int i = 0; i < n; i++) {
        ns_table_key key = nn_key;
        for (int c = 0; c < 3; c++)
            key.albedo[c] = 0.5f + 0.1f * c + 0.01f * i;
        ns_table_stats stats;
        double c0 = cpu_ms();
        get_tables(&key, &stats);
        material_cpu[i] = cpu_ms() - c0;
        recon[i] = stats.reconstruct_ms;
        acc[i] = stats.accumulate_ms;
    }
    /* The walk alone over the networks' J (both orders summed), at two ends of the albedo
     * range: its steps and time. */
    static const ns_table_key materials[] = {
        {.source = NS_METHOD_NN,
         .g = 0.5f,
         .albedo = {0.3f, 0.8f, 0.95f},
         .orders = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE,
         .accumulation = NS_ACCUMULATION_EXACT},
        {.source = NS_METHOD_NN,
         .g = 0.7f,
         .albedo = {0.999f, 0.995f, 0.98f},
         .orders = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE,
         .accumulation = NS_ACCUMULATION_EXACT},
    };
    for (size_t m = 0; m < sizeof materials / sizeof materials[0]; m++) {
        ns_table_stats made;
        float *j3 = get_tables(&materials[m], &made) ? malloc(3 * cells * sizeof(float)) : NULL;
        int have = j3 != NULL;
        for (int c = 0; c < 3 && have; c++) {
            float *jc = summed_j(&materials[m], c);
            have = jc != NULL;
            if (jc)
                memcpy(j3 + c * cells, jc, cells * sizeof(float));
            free(jc);
        }
        double walk_ms[64];
        uint64_t steps = 0;
        int walks = 0;
        for (int i = 0; i < n && have; i++) {
            float *a_walk = NULL;
            double t0 = ns_now_ms();
            if (accumulate(j3, NS_ACCUMULATION_EXACT, &a_walk, &steps))
                break;
            walk_ms[walks++] = ns_now_ms() - t0;
            const char *dump = getenv("NSCATTER_BENCH_ACCUMULATE_DUMP");
            if (dump && i == 0) {
                char path[512];
                snprintf(path, sizeof path, "%s_%zu.f32", dump, m);
                FILE *f = fopen(path, "wb");
                int written = f && fwrite(a_walk, sizeof(float), 3 * cells, f) == 3 * cells;
                if (f && fclose(f))
                    written = 0;
                if (!written)
                    fprintf(stderr, "NSCATTER_BENCH_ACCUMULATE_DUMP: cannot write %s\n", path);
            }
            free(a_walk);
        }
        if (walks)
            printf("nn J of g %.1f albedos %.3g / %.3g / %.3g: %llu steps, walk %.0f ms (median)\n",
                   (double)materials[m].g, (double)materials[m].albedo[0],
                   (double)materials[m].albedo[1], (double)materials[m].albedo[2],
                   (unsigned long long)steps, median(walk_ms, walks));
        free(j3);
    }
    float *j = exponential_j(), *a = NULL;
    for (int i = 0; i < n; i++) {
        uint64_t steps = 0;
        double t0 = ns_now_ms(), c0 = cpu_ms();
        if (accumulate(j, NS_ACCUMULATION_EXACT, &a, &steps))
            break;
        synth[i] = ns_now_ms() - t0;
        cpu[i] = cpu_ms() - c0;
        rate[i] = 3.0 * steps / (synth[i] * 1e-3);
        free(a);
    }
    free(j);
    ns_device_info info;
    ns_context_device_info(test_context(), &info);
    printf("device %s; %d runs, medians: nn RGB material reconstruct %.0f ms, accumulate %.0f ms "
           "(%.0f ms of CPU time for both, all threads); synthetic J accumulate %.0f ms (%.0f ms "
           "of CPU time), %.3g lookups/s\n",
           info.device_name, n, median(recon, n), median(acc, n), median(material_cpu, n),
           median(synth, n), median(cpu, n), median(rate, n));
}

/* ns_table_reach_bins against the gather's reads (gather.glsl, table_at, in the same float
 * arithmetic): every point up to the reach in |z| and in rho, at either side of the source's
 * plane, reads bins inside it, with at most three spare bins beyond; a reach at or past the
 * table's extent, infinite or not a number takes every cell. */
static void test_reach_bins(void)
{
    const float scale = (float)grid.scale, inv_step = (float)(1.0 / grid.step);
    const double reaches[] = {0.0, 1e-3, 0.05, 1.0, 2.86, 7.5, 17.9, 60.0, 250.0};
    for (size_t r = 0; r < sizeof reaches / sizeof reaches[0]; r++) {
        uint32_t k = ns_table_reach_bins(reaches[r]);
        CHECK(k >= 1 && k <= NS_TABLE_NRHO);
        int outside = 0, top_read = 0;
        for (int n = 0; n <= 1000; n++) {
            float d = (float)(reaches[r] * (n == 1000 ? 1.0 : uniform01()));
            float fr = asinhf(d / scale) * inv_step - 0.5f;
            fr = fr < 0.0f ? 0.0f : fr;
            int ir = (int)fr < NS_TABLE_NRHO - 2 ? (int)fr : NS_TABLE_NRHO - 2;
            top_read = ir + 1 > top_read ? ir + 1 : top_read;
            outside += (uint32_t)(ir + 1) >= k && k < NS_TABLE_NRHO;
            for (int side = -1; side <= 1; side += 2) {
                float fz = asinhf(side * d / scale) * inv_step + ((float)(NS_TABLE_NZ / 2) - 0.5f);
                fz = fz < 0.0f ? 0.0f : fz > NS_TABLE_NZ - 1 ? (float)(NS_TABLE_NZ - 1) : fz;
                int iz = (int)fz < NS_TABLE_NZ - 2 ? (int)fz : NS_TABLE_NZ - 2;
                outside += k < NS_TABLE_NRHO &&
                           (iz < (int)(NS_TABLE_NZ / 2 - k) || iz + 1 >= (int)(NS_TABLE_NZ / 2 + k));
            }
        }
        CHECK_INT(outside, 0);
        CHECK((int)k - 1 - top_read <= 3 || k == NS_TABLE_NRHO); /* spare bins beyond the reads */
        printf("reach %g mfp: %u bins (the reads' top rho bin %d)\n", reaches[r], k, top_read);
    }
    CHECK_INT(ns_table_reach_bins(grid.extent), NS_TABLE_NRHO);
    CHECK_INT(ns_table_reach_bins(INFINITY), NS_TABLE_NRHO);
    CHECK_INT(ns_table_reach_bins(NAN), NS_TABLE_NRHO);
    CHECK_INT(ns_table_reach_bins(-1.0), NS_TABLE_NRHO);
}

/* A of j and of second (3 channels each), each walked alone, against both walked together
 * (ns_tables_accumulate_parts): the same floats, bit for bit; and walked within a reach. */
static void compare_parts(const float *j, const float *second, ns_accumulation mode, const char *what)
{
    ns_context *ctx = test_context();
    ns_error err = {0};
    ns_scatter_tables table, together, second_alone = {0}, second_together = {0};
    uint64_t steps_table = 0, steps_second = 0, steps_together = 0;
    CHECK_INT(ns_tables_accumulate(ctx, j, mode, &table, &steps_table, &err), NS_OK);
    CHECK_INT(ns_tables_accumulate(ctx, second, mode, &second_alone, &steps_second, &err), NS_OK);
    int status = ns_tables_accumulate_parts(ctx, j, second, mode, NS_TABLE_NRHO, &together, &second_together,
                                            &steps_together, &err);
    CHECK_INT(status, NS_OK);
    if (!status) {
        CHECK(memcmp(table.a.mapped, together.a.mapped, 3 * cells * sizeof(float)) == 0);
        CHECK(memcmp(second_alone.a.mapped, second_together.a.mapped, 3 * cells * sizeof(float)) ==
              0);
        /* One walk covers both: at most the longer of them per line. */
        CHECK(steps_together < steps_table + steps_second);
        printf("%s (%s): %llu + %llu steps alone, %llu together; both bit for bit\n", what,
               mode == NS_ACCUMULATION_PAPER ? "paper" : "exact", (unsigned long long)steps_table,
               (unsigned long long)steps_second, (unsigned long long)steps_together);
        ns_scatter_tables_free(ctx, &together);
        ns_scatter_tables_free(ctx, &second_together);
    }
    /* Within a reach (ns_table_key.reach_bins): its cells as the whole walk makes them, bit
     * for bit, the others 0, in fewer steps. */
    const uint32_t reach = 20;
    uint64_t steps_within = 0;
    status = ns_tables_accumulate_parts(ctx, j, second, mode, reach, &together, &second_together,
                                        &steps_within, &err);
    CHECK_INT(status, NS_OK);
    if (!status) {
        size_t differ = 0, inside = 0, nonzero_outside = 0;
        for (int part = 0; part < 2; part++) {
            const float *whole = part ? second_alone.a.mapped : table.a.mapped;
            const float *within = part ? second_together.a.mapped : together.a.mapped;
            for (size_t i = 0; i < 3 * cells; i++) {
                size_t cell = i % cells, ir = cell / (NS_TABLE_NTHETA * NS_TABLE_NPHI) % NS_TABLE_NRHO;
                size_t iz = cell / ((size_t)NS_TABLE_NRHO * NS_TABLE_NTHETA * NS_TABLE_NPHI);
                if (ir < reach && iz + reach >= NS_TABLE_NZ / 2 && iz < NS_TABLE_NZ / 2 + reach) {
                    inside++;
                    differ += memcmp(&whole[i], &within[i], sizeof(float)) != 0;
                } else {
                    nonzero_outside += within[i] != 0.0f;
                }
            }
        }
        CHECK_INT(inside, 2 * 3 * (size_t)2 * reach * reach * NS_TABLE_NTHETA * NS_TABLE_NPHI);
        CHECK_INT(differ, 0);
        CHECK_INT(nonzero_outside, 0);
        CHECK(steps_within < steps_together);
        printf("  within %u bins: %zu cells as the whole walk's, the rest 0; %llu steps\n", reach,
               inside / 6, (unsigned long long)steps_within);
        ns_scatter_tables_free(ctx, &together);
        ns_scatter_tables_free(ctx, &second_together);
    }
    ns_error bad = {0};
    CHECK_INT(ns_tables_accumulate_parts(ctx, j, second, mode, 0, &together, &second_together, NULL,
                                         &bad),
              NS_ERR_INVALID_ARGUMENT);
    CHECK_INT(ns_tables_accumulate_parts(ctx, j, second, mode, NS_TABLE_NRHO + 1, &together,
                                         &second_together, NULL, &bad),
              NS_ERR_INVALID_ARGUMENT);
    ns_scatter_tables_free(ctx, &table);
    ns_scatter_tables_free(ctx, &second_alone);
}

/* The second three ride along a material's walk (accumulate_shared.h), with light
 * everywhere in the three and near the axis only in the second three (their own radius),
 * and the other way round (lines that meet the second three's light and not the three's), in
 * both modes; a J that is not finite or a missing output is refused; through the cache, a
 * render that announces two order sets gets the other set's table from the first
 * accumulation, as a walk of its own makes it. */
static void test_second_three_ride_along(void)
{
    float *j = exponential_j(), *tube3 = calloc(3 * cells, sizeof(float));
    tube_j(tube3 + 2 * cells); /* one channel near the axis, two dark */
    compare_parts(j, tube3, NS_ACCUMULATION_EXACT, "exponential J, a tube second");
    compare_parts(tube3, j, NS_ACCUMULATION_EXACT, "a tube J, exponential second");
    compare_parts(j, tube3, NS_ACCUMULATION_PAPER, "exponential J, a tube second");

    ns_context *ctx = test_context();
    ns_error err = {0};
    ns_scatter_tables t, t2;
    float *bad3 = malloc(3 * cells * sizeof(float));
    memcpy(bad3, j, 3 * cells * sizeof(float));
    bad3[2 * cells + 7] = INFINITY;
    CHECK_INT(ns_tables_accumulate_parts(ctx, j, bad3, NS_ACCUMULATION_EXACT, NS_TABLE_NRHO, &t, &t2, NULL, &err),
              NS_ERR_INVALID_ARGUMENT);
    CHECK(strstr(err.message, "J table") != NULL);
    free(bad3);
    CHECK_INT(ns_tables_accumulate_parts(ctx, j, tube3, NS_ACCUMULATION_EXACT, NS_TABLE_NRHO, &t, NULL, NULL, &err),
              NS_ERR_INVALID_ARGUMENT);
    CHECK(strstr(err.message, "second three") != NULL);
    CHECK_INT(ns_tables_accumulate(ctx, NULL, NS_ACCUMULATION_EXACT, &t, NULL, &err),
              NS_ERR_INVALID_ARGUMENT);
    CHECK(strstr(err.message, "missing") != NULL);

    /* Through the cache: a fresh context whose first accumulation (double alone) reconstructs
     * both orders' J. */
    ns_context *fresh = NULL;
    CHECK_INT(ns_context_create(&(ns_context_desc){0}, &fresh, &err), NS_OK);
    if (fresh) {
        ns_table_key double_only = nn_key;
        double_only.orders = NS_COMPONENT_DOUBLE;
        const ns_scatter_tables *first = NULL;
        CHECK_INT(ns_tables_get(fresh, &double_only, &first, NULL, &err), NS_OK);
        /* The render reads double + multiple and multiple scattering alone (a walk's sources
         * shifted by one event; the blurred first order's bit, which has no table, is
         * ignored): the second's table rides along as the second three. */
        ns_tables_expect_orders(fresh, nn_key.orders);
        ns_tables_expect_orders(fresh, NS_COMPONENT_MULTIPLE | NS_TABLE_FIRST_BLURRED);
        const ns_scatter_tables *got = NULL;
        ns_table_stats stats;
        CHECK_INT(ns_tables_get(fresh, &nn_key, &got, &stats, &err), NS_OK);
        CHECK_INT(stats.tables_made, 2); /* its A and the companion's; the J were there */
        ns_table_key multiple_only = nn_key;
        multiple_only.orders = NS_COMPONENT_MULTIPLE;
        CHECK_INT(ns_tables_get(fresh, &multiple_only, &got, &stats, &err), NS_OK);
        CHECK(stats.cache_hit && !stats.accumulated && stats.tables_made == 0);
        /* As its own walk of the channels' J of multiple scattering makes it. */
        float *j_multiple = malloc(3 * cells * sizeof(float));
        int have_j = 1;
        for (int c = 0; c < 3; c++) {
            const float *jc =
                ns_tables_cached_j(fresh, NS_METHOD_NN, nn_key.g, nn_key.albedo[c], 1);
            have_j = have_j && jc;
            if (jc)
                memcpy(j_multiple + c * cells, jc, cells * sizeof(float));
        }
        CHECK(have_j);
        ns_scatter_tables own_walk;
        int walked = have_j && got ? ns_tables_accumulate(fresh, j_multiple, NS_ACCUMULATION_EXACT,
                                                          &own_walk, NULL, &err)
                                   : NS_ERR_INTERNAL;
        CHECK_INT(walked, NS_OK);
        if (!walked) {
            CHECK(memcmp(own_walk.a.mapped, got->a.mapped, 3 * cells * sizeof(float)) == 0);
            ns_scatter_tables_free(fresh, &own_walk);
        }
        free(j_multiple);
        ns_context_destroy(fresh);
    }
    free(tube3);
    free(j);
}

int main(void)
{
    ns_table_grid_default(&grid);
    test_context();
    const char *bench_runs = getenv("NSCATTER_BENCH_ACCUMULATE");
    if (bench_runs && atoi(bench_runs) > 0) {
        bench(atoi(bench_runs));
        ns_context_destroy(test_context());
        return 0;
    }
    RUN(test_closed_form_exponential);
    RUN(test_radial_support_skips_walks);
    RUN(test_remainder_bounds_stop_dark_lines);
    RUN(test_second_three_ride_along);
    RUN(test_reach_bins);
    RUN(test_network_tables_brute_force);
    RUN(test_double_from_one_table_per_g);
    RUN(test_cache_hit_and_eviction);
    RUN(test_zero_albedo_costs_nothing);
    RUN(test_table_source_through_provider);
    RUN(test_bad_keys);
    RUN(test_plane_of_beams);
    ns_context_destroy(test_context());
    return harness_report();
}
