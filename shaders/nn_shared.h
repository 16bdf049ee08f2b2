/* nn_shared.h — layout of the network reconstruction pass (shaders/nn_reconstruct.comp),
 * shared by the shader and render/nn_reconstruct.c like shared.h.
 *
 * The two networks (double, multiple) live in one uniform buffer as vec4s, each layer's
 * rows padded to whole vec4s so the inner products are vec4 dot products:
 *   W1: 52 rows (50 + 2 zero rows) x 2 vec4 (6 inputs + 2 zeros)   offset 0
 *   B1: 13 vec4 (52 biases, the last 2 zero)                       offset 104
 *   W2: 50 rows x 13 vec4 (50 inputs + 2 zeros)                    offset 117
 *   B2: 13 vec4, W3: 13 vec4, B3: 1 vec4 (.x)                      offsets 767, 780, 793
 * Zero padding keeps the padded hidden units at tanh(0) = 0, so no loop needs a branch.
 */
#ifndef NS_SHADERS_NN_SHARED_H
#define NS_SHADERS_NN_SHARED_H

#include "shared.h"

NS_CONST(uint, NS_NN_GROUP, 64);  /* invocations per workgroup */
NS_CONST(uint, NS_NN_POINTS, 16); /* table cells per invocation (DESIGN.md section 6) */
NS_CONST(uint, NS_NN_H4, 13);     /* vec4s per padded hidden layer (52 units) */
NS_CONST(uint, NS_NN_W1_OFF, 0);
NS_CONST(uint, NS_NN_B1_OFF, 104);
NS_CONST(uint, NS_NN_W2_OFF, 117);
NS_CONST(uint, NS_NN_B2_OFF, 767);
NS_CONST(uint, NS_NN_W3_OFF, 780);
NS_CONST(uint, NS_NN_B3_OFF, 793);
NS_CONST(uint, NS_NN_NET_VEC4, 794);  /* one network */
NS_CONST(uint, NS_NN_MAX_AXIS, 256);  /* bins per table axis */
NS_CONST(uint, NS_NN_MODE_TABLE, 0);  /* every cell of a table, 3 channels */
NS_CONST(uint, NS_NN_MODE_POINTS, 1); /* a list of input vectors (tests) */

/* Uniform buffer, binding 0 (std140: vec4 members only). */
struct GpuNnParams {
    ns_vec4 net[2 * 794]; /* [order][NS_NN_NET_VEC4] */
    ns_vec4 axis[256];    /* normalised bin centres: 4 axes x NS_NN_MAX_AXIS floats,
                             in table order z, rho, theta, phi */
    ns_uvec4 counts;      /* bins per axis: nz, nrho, ntheta, nphi */
    ns_uvec4 info;        /* x: items of this dispatch (nodes, cells or points), y: mode,
                             z: table mode writes t (the transformed target, for
                             interpolation) instead of J, w: nodes in all */
    ns_vec4 channel[3];   /* per RGB channel: normalised g, normalised albedo,
                             exact energy of double, of multiple */
    ns_vec4 target[2];    /* per order: transform (0 paper, 1 logrel), eps, mean, scale */
    ns_uvec4 nodes;       /* evaluated bins (nodes) per axis, table order */
    ns_vec4 interp[1024]; /* [axis][NS_NN_MAX_AXIS]: for node k of the axis .x = its bin;
                             for bin i .y = its lower node, .z = the weight of the next
                             node (interpolation in normalised input) */
    ns_uvec4 orders;      /* x: the first order a table dispatch evaluates (workgroup z is the
                             order less this: a dispatch of one order has z 0 only); yzw 0 */
};

#if !defined(__STDC__) && !defined(__cplusplus)
/* Inverse target transform (tt = GpuNnParams.target[order]): paper exp(t) - 1, logrel
 * (exp(t) - eps) E_k; J >= 0, and 0 where energy is 0 (outside the trained extent). */
float nn_target_to_j(vec4 tt, float t, float energy)
{
    float j = tt.x < 0.5 ? exp(t) - 1.0 : (exp(t) - tt.y) * energy;
    return energy == 0.0 ? 0.0 : max(j, 0.0);
}
#endif

#if defined(__STDC__) || defined(__cplusplus)
_Static_assert(sizeof(struct GpuNnParams) == (2 * 794 + 256 + 2 + 3 + 2 + 1 + 1024 + 1) * 16,
               "GpuNnParams");
_Static_assert(offsetof(struct GpuNnParams, counts) == (2 * 794 + 256) * 16, "GpuNnParams");
#endif

#endif
