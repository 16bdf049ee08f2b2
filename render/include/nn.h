/* nn.h — the scattering networks for code outside render/ (the CLI, the server): a session
 * owns a Vulkan device, the reconstruction pipeline (compiled at creation) and the two
 * validated networks, and reconstructs tables from them (render/nn_reconstruct.h does the
 * work). Types only from nscatter.h and nn_weights.h: no Vulkan here. */
#ifndef NS_NN_H
#define NS_NN_H

#include "nn_weights.h"

/* Table geometry the reconstruction fills: bin counts and edges, in table_io's file order
 * (z, rho, theta, phi); edges[axis] holds n[axis] + 1 values (mfp or radians). */
typedef struct ns_nn_grid {
    uint32_t n[4];
    const double *edges[4];
} ns_nn_grid;

/* Where the networks are evaluated: every stride[a]-th bin along each axis (z, rho, theta,
 * phi; always the first and last bin too), and every z and rho bin whose centre lies within
 * full_radius mfp of the source. The cells between are interpolated linearly in the
 * network's output (log space) over its normalised inputs: the networks are smooth there,
 * and this is what brings an RGB material under 1 s on lavapipe (docs/network.md measures
 * the time and the error it adds). */
typedef struct ns_nn_sampling {
    uint32_t stride[4]; /* 1 to 16; 1 everywhere: every cell evaluated */
    double full_radius; /* mfp, >= 0 */
} ns_nn_sampling;

/* The default (measured in docs/network.md) and the exact one, every cell evaluated. */
ns_nn_sampling ns_nn_sampling_default(void);
ns_nn_sampling ns_nn_sampling_every_cell(void);

typedef struct ns_nn_reconstruct_desc {
    const ns_nn_weights *nets[2]; /* double, multiple */
    ns_nn_grid grid;
    double g;
    double albedo[3];  /* per RGB channel */
    int renormalise;   /* rescale each table to its exact energy */
    uint32_t channels; /* 1 to 3 channels evaluated (0 means 3); out keeps room for 3 */
    float *out;        /* [2][3][cells] J values: order-major, then channel */
    const ns_nn_sampling *sampling; /* NULL: ns_nn_sampling_default() */
    /* 0: both orders; NS_NN_ORDER_DOUBLE or NS_NN_ORDER_MULTIPLE: that one alone. Only the
     * tables evaluated are written, at out + (order * 3 + channel) * cells (one channel of the
     * double order alone: out[0, cells)); the rest of out is left as it was, and the stats'
     * energies of an order not evaluated are 0. (Not a bit mask: 3 is refused.) */
    uint32_t orders;
} ns_nn_reconstruct_desc;

enum { NS_NN_ORDER_DOUBLE = 1, NS_NN_ORDER_MULTIPLE = 2 };

typedef struct ns_nn_reconstruct_stats {
    double energy_raw[2][3];   /* energy of each table as the network gave it */
    double energy_exact[2][3]; /* E_k */
    double gpu_seconds;        /* dispatch, submit and wait */
    double total_seconds;      /* including upload, readback and renormalisation */
    uint64_t evaluations;      /* network evaluations (nodes x channels x orders evaluated) */
    uint64_t cells;            /* table cells filled (cells x channels x orders evaluated) */
} ns_nn_reconstruct_stats;

/* Energy of one table in this grid: sum of J * ring volume * solid angle (DESIGN.md §3). */
double ns_nn_grid_energy(const ns_nn_grid *grid, const float *j);

typedef struct ns_nn_session ns_nn_session;

typedef struct ns_nn_session_desc {
    const char *device;     /* NULL: NSCATTER_DEVICE, else lavapipe if present, else first */
    int validation;         /* Vulkan validation layers */
    const char *weights[2]; /* files for double, multiple; NULL: the built-in weights */
} ns_nn_session_desc;

/* Loads and validates the weights first (a bad file is NS_ERR_INVALID_ARGUMENT or NS_ERR_IO
 * naming it), then makes the device and pipeline. Free with ns_nn_session_destroy. */
int ns_nn_session_create(const ns_nn_session_desc *desc, ns_nn_session **out, ns_error *err);
void ns_nn_session_destroy(ns_nn_session *s); /* NULL: no-op */
const char *ns_nn_session_device(const ns_nn_session *s);
const ns_nn_weights *ns_nn_session_net(const ns_nn_session *s, uint32_t order);

/* ns_nn_reconstruct on the session's device; desc->nets NULL means the session's networks. */
int ns_nn_session_reconstruct(ns_nn_session *s, const ns_nn_reconstruct_desc *desc,
                              ns_nn_reconstruct_stats *stats, ns_error *err);

#endif
