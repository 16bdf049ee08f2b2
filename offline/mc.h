/* mc.h — Monte Carlo ground truth for the double and multiple scattering tables.
 *
 * The problem (DESIGN.md section 2): a pencil beam of unit power leaves the origin along +z
 * into an infinite medium with extinction 1 (lengths in mean free paths), albedo a and a
 * Henyey-Greenstein phase function g. J_k(x, w) is the radiance the k-th scattering event
 * emits at x into w, per unit volume, solid angle and source power; the double table is
 * J_2, the multiple table the sum over k >= 3.
 *
 * The estimator. Every collision is histogrammed by its position (rho, z) and its INCOMING
 * direction, expressed in the local frame (e_rho, e_phi, e_z) of that position. The
 * emitted radiance is the incoming distribution convolved with the HG lobe; because the
 * table's angular bins live in the same local frame everywhere, the bin-to-bin lobe matrix
 * is the same for every spatial bin and is applied once at the end. Photons carry no
 * per-event weight: events 1 and 2 never absorb (implicit capture, the absorption goes into
 * a constant factor a^(k-1)), and from event 3 on the photon survives each event with
 * probability a (an unbiased Russian roulette). So every deposit of an order weighs the
 * same (a^2 for double, a^3 for multiple) and the histograms are plain integer counts:
 * their sums are exact and independent of the thread order, hence the same table for the
 * same seed whatever the number of threads.
 *
 * Threads: photons are traced in fixed batches, each with its own random stream seeded from
 * (seed, batch index); threads take batches in any order.
 */
#ifndef NS_MC_H
#define NS_MC_H

#include <stdint.h>

#include "nscatter.h"
#include "table_grid.h"
#include "table_io.h"

/* Default binning: the renderer's table grid (render/include/table_grid.h: NS_TABLE_NZ,
 * NS_TABLE_NRHO, NS_TABLE_NTHETA, NS_TABLE_NPHI, NS_TABLE_SINH_SCALE, NS_TABLE_EXTENT), so
 * that the tables made here are the ones the renderer reads. NS_MC_NDIR directions (theta x
 * phi bins) per spatial bin. */
#define NS_MC_NDIR (NS_TABLE_NTHETA * NS_TABLE_NPHI)

/* Fills the edges of a table created with the default bin counts above. */
void ns_mc_default_edges(ns_table *t);

enum { NS_MC_WANT_DOUBLE = 1u << NS_ORDER_DOUBLE, NS_MC_WANT_MULTIPLE = 1u << NS_ORDER_MULTIPLE };

typedef struct ns_mc_desc {
    double g;          /* (-1, 1) */
    double albedo;     /* [0, 1) */
    uint64_t photons;  /* >= 1 */
    uint64_t seed;
    unsigned orders;   /* NS_MC_WANT_* bits, at least one */
    unsigned threads;  /* 0: all online cores */
    /* Quality of the lobe matrix: sub-directions per axis of an incoming bin (0: 8) and
     * stratified lobe samples per axis (0: 48). Tests lower them to run fast. */
    unsigned lobe_in_samples, lobe_out_samples;
    /* Optional lobe matrix from ns_mc_lobe_matrix for this g (borrowed, copied): it depends
     * on g only, so a grid computes it once per g. NULL: computed here. */
    const double *lobe;
    /* Called from the calling thread about 4 times a second while photons are traced. */
    void (*progress)(void *user, uint64_t batches_done, uint64_t batches_total);
    void *progress_user;
} ns_mc_desc;

/* Exact per-event statistics of one order, measured by the tracer itself (not from the
 * table): a side channel to test the tracer against the closed forms of DESIGN.md
 * section 2. Each value has a standard error estimated from the spread between batches. */
typedef struct ns_mc_moments {
    double energy, energy_se;       /* energy emitted by the order, all of space */
    double energy_in_table;         /* the part emitted inside the table's bins */
    double z, z_se;                 /* energy-weighted mean depth of the events */
    double cos_theta, cos_theta_se; /* mean cosine of the emitted direction with +z */
    double r2, r2_se;               /* mean squared distance of the events */
    uint64_t events;                /* deposits traced (in and out of the table) */
    uint64_t events_in_table;       /* those inside the table's bins */
} ns_mc_moments;

typedef struct ns_mc_result {
    ns_table table[2];         /* filled for the orders asked for, indexed by ns_order */
    uint64_t *counts[2];       /* raw histograms [Nz*Nrho][NS_MC_NDIR] of incoming dirs */
    double *lobe;              /* [NS_MC_NDIR][NS_MC_NDIR]: incoming bin -> emitted bin */
    ns_mc_moments moments[2];
    uint64_t collisions;       /* all collisions traced, the unit of work */
    uint64_t batches;
    unsigned threads;
    double trace_seconds, lobe_seconds, total_seconds; /* wall clock */
    double trace_cpu_seconds; /* CPU time of all threads while tracing */
} ns_mc_result;

/* Runs the simulation. On success *out owns its tables and arrays: free them with
 * ns_mc_result_free. */
int ns_mc_run(const ns_mc_desc *desc, ns_mc_result *out, ns_error *err);
void ns_mc_result_free(ns_mc_result *r);

/* Double scattering depends on the albedo only through the factor a^2: events 1 and 2
 * never absorb (implicit capture), so the photon paths, hence the histogram, are the same
 * for every albedo. This recomputes the double table and its energies of *r for another
 * albedo, so one simulation serves every albedo of a g (the grid does this). */
int ns_mc_result_set_double_albedo(ns_mc_result *r, double albedo, ns_error *err);

/* Validates the physical parameters; the message names the argument (--g, --albedo...). */
int ns_mc_check_desc(const ns_mc_desc *desc, ns_error *err);

/* The NS_MC_NDIR x NS_MC_NDIR lobe matrix for g: row i holds the fraction of the energy
 * scattered from incoming bin i that leaves in each emitted bin (rows sum to 1). 0 samples
 * and 0 threads mean the defaults. */
void ns_mc_lobe_matrix(double g, unsigned in_samples, unsigned out_samples, unsigned threads,
                       double *lobe);

/* Exact energy of an order: a^2, or a^3 / (1 - a). */
double ns_mc_expected_energy(ns_order order, double albedo);
/* Expected collisions per photon when tracing the given orders (the cost model). */
double ns_mc_collisions_per_photon(unsigned orders, double albedo);

/* Samples the cosine of the HG scattering angle from a uniform number in [0, 1). */
double ns_mc_sample_hg_cos(double g, double u);
/* HG phase function value (per steradian) for the cosine of the scattering angle. */
double ns_mc_hg(double g, double cos_angle);

unsigned ns_mc_default_threads(void);

#endif
