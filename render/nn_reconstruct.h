/* nn_reconstruct.h — (private to render/) the double and multiple scattering tables of an
 * RGB material, reconstructed from the networks by shaders/nn_reconstruct.comp (issue 4);
 * render/include/nn.h wraps it for code outside render/.
 *
 * One dispatch evaluates both networks at every cell centre of the table, for the three
 * channels (each channel its own albedo, g shared). Optionally each of the six tables is then
 * rescaled so that its energy equals the exact E_k (a^2, a^3/(1-a)): energy conservation,
 * which the paper lacks (docs/network.md measures whether it helps).
 */
#ifndef NS_NN_RECONSTRUCT_H
#define NS_NN_RECONSTRUCT_H

#include "gpu.h"
#include "nn.h"

typedef struct ns_nn_gpu {
    gpu_pipeline pipeline;    /* nn_reconstruct.comp: the networks at nodes or points */
    gpu_pipeline interpolate; /* nn_interpolate.comp: every cell from the nodes */
    gpu_buffer params;        /* uniform GpuNnParams */
    gpu_buffer dummy;         /* bound to the points slot in table mode */
    int created;
} ns_nn_gpu;

/* Creates the pipelines and compiles them now (lavapipe compiles at the first dispatch). */
int ns_nn_gpu_create(gpu_device *dev, ns_nn_gpu *nn, ns_error *err);
void ns_nn_gpu_destroy(gpu_device *dev, ns_nn_gpu *nn);

/* The exact energy E_k of a table (DESIGN.md section 2): a^2 (order 0, double), a^3 / (1 - a)
 * (order 1, multiple); what renormalisation rescales each table to. */
double ns_nn_exact_energy(int order, double albedo);

int ns_nn_reconstruct(gpu_device *dev, ns_nn_gpu *nn, const ns_nn_reconstruct_desc *desc,
                      ns_nn_reconstruct_stats *stats, ns_error *err);

/* Points mode (tests): J of both networks at n explicit normalised inputs x (n x 6); energy[n]
 * is the E_k the logrel transform scales by (the same for both orders here); out[4][n]:
 * J of double, J of multiple, then the raw network outputs y of double and multiple. */
int ns_nn_eval_points(gpu_device *dev, ns_nn_gpu *nn, const ns_nn_weights *nets[2], const float *x,
                      const double *energy, uint32_t n, float *out, ns_error *err);

#endif
