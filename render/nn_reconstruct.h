/* nn_reconstruct.h — the double and multiple scattering tables of an RGB material,
 * reconstructed from the networks by shaders/nn_reconstruct.comp (issue 4).
 *
 * One dispatch evaluates both networks at every cell centre of the table, for the three
 * channels (each channel its own albedo, g shared). Optionally each of the six tables is then
 * rescaled so that its energy equals the exact E_k (a^2, a^3/(1-a)): energy conservation,
 * which the paper lacks (docs/network.md measures whether it helps).
 */
#ifndef NS_NN_RECONSTRUCT_H
#define NS_NN_RECONSTRUCT_H

#include "gpu.h"
#include "nn_weights.h"

typedef struct ns_nn_gpu {
    gpu_pipeline pipeline;
    gpu_buffer params;  /* uniform GpuNnParams */
    gpu_buffer dummy;   /* bound to the points slot in table mode */
    int created;
} ns_nn_gpu;

/* Creates the pipeline and compiles it now (lavapipe compiles at the first dispatch). */
int ns_nn_gpu_create(gpu_device *dev, ns_nn_gpu *nn, ns_error *err);
void ns_nn_gpu_destroy(gpu_device *dev, ns_nn_gpu *nn);

/* Table geometry the reconstruction fills: bin counts and edges, in table_io's file order
 * (z, rho, theta, phi); edges[axis] holds n[axis] + 1 values (mfp or radians). */
typedef struct ns_nn_grid {
    uint32_t n[4];
    const double *edges[4];
} ns_nn_grid;

typedef struct ns_nn_reconstruct_desc {
    const ns_nn_weights *nets[2]; /* double, multiple */
    ns_nn_grid grid;
    double g;
    double albedo[3];     /* per RGB channel */
    int renormalise;      /* rescale each table to its exact energy */
    uint32_t channels;    /* 1 to 3 channels evaluated (0 means 3); out keeps room for 3 */
    float *out;           /* [2][3][cells] J values: order-major, then channel */
} ns_nn_reconstruct_desc;

typedef struct ns_nn_reconstruct_stats {
    double energy_raw[2][3];  /* energy of each table as the network gave it */
    double energy_exact[2][3];/* E_k */
    double gpu_seconds;       /* dispatch, submit and wait */
    double total_seconds;     /* including upload, readback and renormalisation */
    uint64_t evaluations;     /* network evaluations (cells x 3 channels x 2 orders) */
} ns_nn_reconstruct_stats;

int ns_nn_reconstruct(gpu_device *dev, ns_nn_gpu *nn, const ns_nn_reconstruct_desc *desc,
                      ns_nn_reconstruct_stats *stats, ns_error *err);

/* Points mode (tests): J of both networks at n explicit normalised inputs x (n x 6); energy[n]
 * is the E_k the logrel transform scales by (the same for both orders here); out[4][n]:
 * J of double, J of multiple, then the raw network outputs y of double and multiple. */
int ns_nn_eval_points(gpu_device *dev, ns_nn_gpu *nn, const ns_nn_weights *nets[2],
                      const float *x, const double *energy, uint32_t n, float *out,
                      ns_error *err);

/* Energy of one table in this grid: sum of J * ring volume * solid angle (DESIGN.md §3). */
double ns_nn_grid_energy(const ns_nn_grid *grid, const float *j);

#endif
