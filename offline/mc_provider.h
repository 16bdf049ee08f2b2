/* mc_provider.h — Monte Carlo tables for method "table" (render/include/nscatter.h ns_mc_tables_fn):
 * the render library does not link the offline tracer, so the server hands it this provider.
 *
 * For one channel (g, albedo) it runs offline/mc.h's ns_mc_run at the default budget of
 * `nscatter mc --grid` (8e7 collisions per order, on all cores, fixed seed: the same table
 * for the same material on any machine) and keeps the two tables (double, multiple) on disk
 * in the table_io .npy + .json format, so a material costs its simulation once per machine.
 *
 * Double scattering depends on the albedo only through the factor a^2 (events 1 and 2 never
 * absorb in the tracer, and the budget gives every albedo the same photons), so once a g has
 * one double table the others of that g are that table times (a / a0)^2: an RGB material
 * pays one double simulation, not three.
 *
 * Cache directory: desc.cache_dir, else $NSCATTER_CACHE_DIR, else $XDG_CACHE_HOME/nscatter,
 * else $HOME/.cache/nscatter (created on first write). Files: mc_g<G>_a<A>_<order>.npy/.json
 * with G and A printed exactly (%.17g). Writes are atomic (table_io). A cache file is never
 * trusted: its shape, edges, material, order, photon budget, finiteness and recorded energy
 * are checked on every read, and a file that fails any check is recomputed and overwritten.
 *
 * Thread safety: calls are serialised by the render context's lock (one render at a time).
 */
#ifndef NS_SERVER_MC_PROVIDER_H
#define NS_SERVER_MC_PROVIDER_H

#include <stdint.h>

#include "nscatter.h"

#define NS_MC_PROVIDER_COLLISIONS 8e7 /* per order: `nscatter mc --grid`'s default budget */
#define NS_MC_PROVIDER_SEED 1u

typedef struct ns_mc_provider_desc {
    const char *cache_dir; /* NULL: the environment's (see above) */
    double collisions;     /* per order's simulation; 0: NS_MC_PROVIDER_COLLISIONS */
    unsigned threads;      /* 0: all online cores */
    unsigned lobe_in_samples, lobe_out_samples; /* lobe matrix quality; 0: defaults (tests lower) */
} ns_mc_provider_desc;

typedef struct ns_mc_provider ns_mc_provider;

/* Resolves the cache directory (no file is touched yet). NS_ERR_INVALID_ARGUMENT when none
 * can be named (no variable set and no HOME). Free with ns_mc_provider_destroy. */
int ns_mc_provider_create(const ns_mc_provider_desc *desc, ns_mc_provider **out, ns_error *err);
void ns_mc_provider_destroy(ns_mc_provider *p); /* NULL: no-op */
const char *ns_mc_provider_dir(const ns_mc_provider *p);

/* The ns_mc_tables_fn: user is the ns_mc_provider. Fills NS_TABLE_CELLS floats of each. */
int ns_mc_provider_tables(void *user, double g, double albedo, float *j_double, float *j_multiple,
                          ns_error *err);

/* Sets desc->mc_tables and desc->mc_user to the process's provider (default description,
 * made on the first call, freed at exit): what `serve` and `render` pass to
 * ns_context_create. When no cache directory can be named it prints why on stderr and leaves
 * desc alone (method "table" then answers NS_ERR_NOT_AVAILABLE). */
void ns_mc_provider_attach(ns_context_desc *desc);
/* ns_mc_provider_attach, and the same cache folder for the render library's own table files
 * (ns_context_desc.table_node_dir: the interpolated tables' albedo nodes). */
void ns_table_caches_attach(ns_context_desc *desc);

/* What the provider did so far (tests, logs). */
typedef struct ns_mc_provider_counts {
    uint32_t simulations;      /* ns_mc_run calls (one per order computed) */
    uint32_t doubles_rescaled; /* double tables made from another albedo's of the same g */
    uint32_t files_read;       /* tables served from the cache directory */
    uint32_t files_rejected;   /* cache files that failed a check and were recomputed */
    uint32_t write_failures;   /* tables computed but not saved (the render still got them) */
} ns_mc_provider_counts;
void ns_mc_provider_get_counts(const ns_mc_provider *p, ns_mc_provider_counts *out);

#endif
