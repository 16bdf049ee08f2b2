/* nn_weights.h — the scattering network (paper Section 3.4): its weights file, its input
 * normalisation, its target transform and a plain CPU forward pass.
 *
 * The network maps (rho, z, theta, phi, g, albedo), each normalised to [0, 1], through two
 * hidden layers of 50 tanh units to one output y; J is recovered from y by the inverse of
 * the target transform named in the file. One network per order (double, multiple).
 *
 * Weights file (little endian, self-describing so that it can be validated without JSON):
 *   ns_nn_header (NS_NN_HEADER_SIZE bytes), then param_count float32 parameters in the order
 *   W1[H1][6] b1[H1] W2[H2][H1] b2[H2] W3[H2] b3 (row-major, W[out][in]).
 *   The header's payload_crc32 is the CRC-32 (zlib polynomial) of the parameter bytes and
 *   header_crc32 that of the header bytes before it: a truncated, corrupted or foreign file
 *   is rejected with a message that says which check failed.
 */
#ifndef NS_NN_WEIGHTS_H
#define NS_NN_WEIGHTS_H

#include <stddef.h>
#include <stdint.h>

#include "nscatter.h"

#define NS_NN_MAGIC "NSNNWTS1" /* 8 bytes, no terminator in the file */
#define NS_NN_VERSION 1u
#define NS_NN_INPUTS 6
#define NS_NN_HIDDEN 50
#define NS_NN_PARAMS                                                                               \
    (NS_NN_HIDDEN * NS_NN_INPUTS + NS_NN_HIDDEN + NS_NN_HIDDEN * NS_NN_HIDDEN + NS_NN_HIDDEN +     \
     NS_NN_HIDDEN + 1)
#define NS_NN_MAX_FILE_BYTES 12288 /* issue 4: each network at most 12 KB */

/* Offsets of the parameter blocks inside the payload. */
enum {
    NS_NN_OFF_W1 = 0,
    NS_NN_OFF_B1 = NS_NN_OFF_W1 + NS_NN_HIDDEN * NS_NN_INPUTS,
    NS_NN_OFF_W2 = NS_NN_OFF_B1 + NS_NN_HIDDEN,
    NS_NN_OFF_B2 = NS_NN_OFF_W2 + NS_NN_HIDDEN * NS_NN_HIDDEN,
    NS_NN_OFF_W3 = NS_NN_OFF_B2 + NS_NN_HIDDEN,
    NS_NN_OFF_B3 = NS_NN_OFF_W3 + NS_NN_HIDDEN,
};

/* Target transforms: what the network's output y means.
 *   PAPER  (the paper's):   y = (ln(J + 1) - mean) / scale
 *   LOGREL (default here):  y = (ln(J / E_k + eps) - mean) / scale, E_k the exact energy of
 *                           the order for the material (a^2 or a^3/(1-a)): the network learns
 *                           the shape of the table, the exact energy gives its scale, so
 *                           low-albedo tables are not crushed to zero by the +1. */
typedef enum { NS_NN_TARGET_PAPER = 0, NS_NN_TARGET_LOGREL = 1 } ns_nn_target;

/* Input map version 1 (see ns_nn_normalise): spatial axes through asinh(x / sinh_scale),
 * the inverse of the Monte Carlo bins' sinh spacing, so every spatial bin is about equally
 * wide in the network's input; albedo through -ln(1 - a), which spreads the high-albedo
 * end where the tables change fastest. */
#define NS_NN_INPUT_MAP_ASINH 1u
/* Input map version 2: as version 1, but g through the mean of (g - g_min) / (g_max - g_min)
 * and ln(1 - g) / ln(1 - g_max) (g_max < 1): the forward-scattering end, where the tables
 * change with 1 / (1 - g), gets a third of the input range from g 0.9 to 0.99 instead of a
 * tenth, while low g keeps half of its linear spread. */
#define NS_NN_INPUT_MAP_ASINH_LOGG 2u

typedef struct ns_nn_header {
    char magic[8];
    uint32_t version;
    uint32_t header_size;                       /* sizeof(ns_nn_header) */
    uint32_t order;                             /* 0 double, 1 multiple (ns_order) */
    uint32_t inputs, hidden1, hidden2, outputs; /* 6, 50, 50, 1 */
    uint32_t activation;                        /* 1 = tanh */
    uint32_t target;                            /* ns_nn_target */
    uint32_t input_map;                         /* NS_NN_INPUT_MAP_* */
    uint32_t param_count;                       /* NS_NN_PARAMS */
    float target_eps, target_mean, target_scale;
    float extent;       /* spatial extent (mfp) mapped to 1 */
    float sinh_scale;   /* mfp: the asinh knee */
    float albedo_max;   /* albedo mapped to 1 */
    float g_min, g_max; /* g range mapped to [0, 1] */
    uint32_t payload_crc32;
    uint32_t header_crc32; /* CRC of all header bytes before this field */
} ns_nn_header;

#define NS_NN_HEADER_SIZE 92u

typedef struct ns_nn_weights {
    ns_nn_header h;
    float p[NS_NN_PARAMS];
} ns_nn_weights;

uint32_t ns_crc32(const void *data, size_t size);

/* Fills the header fields for the default architecture and input map (not the CRCs). */
void ns_nn_header_init(ns_nn_header *h, uint32_t order, ns_nn_target target);

/* Validates a whole file image (header, size, architecture, CRCs, finite parameters) and
 * copies it into *w. `what` names the source in messages (a path or "embedded double"). */
int ns_nn_weights_parse(const void *bytes, size_t size, const char *what, ns_nn_weights *w,
                        ns_error *err);
int ns_nn_weights_load(const char *path, ns_nn_weights *w, ns_error *err);
/* Computes the CRCs and writes atomically (temporary file, then rename). */
int ns_nn_weights_save(ns_nn_weights *w, const char *path, ns_error *err);

/* The weights built into the binary (weights/double.bin, weights/multiple.bin at build
 * time), validated; NS_ERR_NOT_FOUND-style failure (NS_ERR_INVALID_ARGUMENT) with a clear
 * message when the binary was built without them. */
int ns_nn_weights_builtin(uint32_t order, ns_nn_weights *w, ns_error *err);

/* The normalised input vector for one point; x[6] in [0, 1] for points inside the table. */
void ns_nn_normalise(const ns_nn_header *h, double rho, double z, double theta, double phi,
                     double g, double albedo, float x[NS_NN_INPUTS]);
/* Individual axis maps (also used to build the GPU's per-axis input tables). */
float ns_nn_map_rho(const ns_nn_header *h, double rho);
float ns_nn_map_z(const ns_nn_header *h, double z);
float ns_nn_map_albedo(const ns_nn_header *h, double albedo);
float ns_nn_map_g(const ns_nn_header *h, double g);

/* Forward pass in float, same operation order as shaders/nn_reconstruct.comp: returns y. */
float ns_nn_forward(const ns_nn_weights *w, const float x[NS_NN_INPUTS]);
/* From the network output to J for a material (inverse target transform, clamped >= 0). */
double ns_nn_output_to_j(const ns_nn_header *h, double y, double energy_expected);
/* And back (training targets). */
double ns_nn_j_to_target(const ns_nn_header *h, double j, double energy_expected);

#endif
