/* table_io.h — the scattering-table file format of DESIGN.md section 3.
 *
 * A table is J(z, rho, theta, phi) for one material (g, albedo) and one order (double or
 * multiple), stored as two files that share a prefix:
 *   PREFIX.npy   float32, C order, shape [Nz, Nrho, Ntheta, Nphi]; each value is the average
 *                of J over its bin (energy emitted in the bin / (ring volume * solid angle)).
 *   PREFIX.json  metadata: quantity, order, g, albedo, photons, seed, source, the four axes'
 *                bin edges, energy_captured, energy_expected.
 *
 * Writing is atomic (ns_write_file_atomic_parts): each file goes to a temporary file beside
 * it (PREFIX.*.tmp.XXXXXX), is fsync'ed and renamed, the .json last. A table counts as complete
 * only when its .json exists (ns_table_is_complete), so a run killed half-way never leaves
 * something that looks finished.
 *
 * Ownership: ns_table_create/ns_table_read allocate the edges and the data; ns_table_free
 * releases them (and accepts a zeroed or already freed table). Results are 0 or a negative
 * ns_status, with a one-line message in *err when err is not NULL.
 */
#ifndef NS_TABLE_IO_H
#define NS_TABLE_IO_H

#include <stddef.h>
#include <stdint.h>

#include "nscatter.h"

enum { NS_AXIS_Z = 0, NS_AXIS_RHO = 1, NS_AXIS_THETA = 2, NS_AXIS_PHI = 3, NS_AXIS_COUNT = 4 };

typedef enum { NS_ORDER_DOUBLE = 0, NS_ORDER_MULTIPLE = 1 } ns_order;

typedef struct ns_table {
    ns_order order;
    char source[8]; /* "mc" or "nn" */
    double g, albedo;
    uint64_t photons, seed;
    double energy_captured; /* energy held by the table (ns_table_energy at write time) */
    double energy_expected; /* exact energy of the order: a^2, or a^3 / (1 - a) */
    uint32_t n[NS_AXIS_COUNT];      /* bins per axis, in file order z, rho, theta, phi */
    double *edges[NS_AXIS_COUNT];   /* n[axis] + 1 increasing edges; mfp or radians */
    float *data;                    /* n[0]*n[1]*n[2]*n[3] values, C order */
} ns_table;

/* Allocates edges (uninitialised) and data (zeroed) for the given bin counts. Every count
 * must be in [1, 4096]. */
int ns_table_create(ns_table *t, const uint32_t n[NS_AXIS_COUNT], ns_error *err);
void ns_table_free(ns_table *t);

static inline size_t ns_table_size(const ns_table *t)
{
    return (size_t)t->n[0] * t->n[1] * t->n[2] * t->n[3];
}
static inline size_t ns_table_index(const ns_table *t, uint32_t iz, uint32_t irho,
                                    uint32_t itheta, uint32_t iphi)
{
    return (((size_t)iz * t->n[1] + irho) * t->n[2] + itheta) * t->n[3] + iphi;
}

/* Volume of the ring of spatial bin (iz, irho): pi (rho1^2 - rho0^2)(z1 - z0). */
double ns_table_bin_volume(const ns_table *t, uint32_t iz, uint32_t irho);
/* Solid angle of angular bin (itheta, iphi), both mirror halves of phi:
 * (cos theta0 - cos theta1)(phi1 - phi0) * 2. */
double ns_table_bin_solid_angle(const ns_table *t, uint32_t itheta, uint32_t iphi);
/* Energy held by the table: sum of J * volume * solid angle (DESIGN.md section 3); NaN
 * if out of memory. */
double ns_table_energy(const ns_table *t);

const char *ns_order_name(ns_order order); /* "double" / "multiple" */
int ns_order_parse(const char *name, ns_order *out); /* 0 or NS_ERR_INVALID_ARGUMENT */

/* Writes PREFIX.npy then PREFIX.json, each atomically (temp file, fsync, rename). Any
 * existing PREFIX.json is removed first, so an interrupted overwrite is never complete. */
int ns_table_write(const ns_table *t, const char *prefix, ns_error *err);
/* Reads PREFIX.json and PREFIX.npy into *t (which it initialises); checks that the edges
 * and the array shape agree. */
int ns_table_read(const char *prefix, ns_table *t, ns_error *err);
/* 1 when PREFIX.json exists, parses, and PREFIX.npy has the size it announces. */
int ns_table_is_complete(const char *prefix);

/* Checks that PREFIX.npy and PREFIX.json can be created, before spending minutes on a
 * simulation (leaves no file behind). */
int ns_table_check_writable(const char *prefix, ns_error *err);

#endif
