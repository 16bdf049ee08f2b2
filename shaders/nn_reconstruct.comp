#version 450
// nn_reconstruct.comp — evaluates the scattering networks (render/include/nn_weights.h) at the
// nodes of a table (the bins GpuNnParams.interp lists per axis: every cell, or every
// stride-th bin for nn_interpolate.comp to fill in): gl_GlobalInvocationID.x picks 16
// consecutive nodes, .y the RGB channel (each its own albedo), .z the order (0 double, 1
// multiple). The output, out[(order * 3 + channel) * nodes + node], is J itself (the inverse
// target transform applied) when every cell is a node, else t (info.z: the network output
// in the target's log space, which nn_interpolate.comp interpolates).
// Points mode (tests): the inputs come from a list instead, 2 vec4 per point: (rho, z,
// theta, phi) and (g, albedo, E_k, 0) normalised; out[order * points + point] = J and
// out[(2 + order) * points + point] = the network output y.
// Shape (DESIGN.md section 6, lavapipe): many points per invocation with the weights in a
// uniform buffer, layer 1's weights fetched once for 16 points. The loops over the 16 points and
// over a row's 13 vec4s are unrolled so the activation array is indexed by constants
// (3x faster on lavapipe); the loops over hidden units stay loops (compile time: ~8 s cold,
// 32 points took 36 s). Docs: docs/network.md.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
#include "nn_shared.h"

layout(local_size_x = NS_NN_GROUP) in;

layout(std140, binding = 0) uniform NnBlock { GpuNnParams ns_nn[1]; };
#define P ns_nn[NS_OPAQUE_ZERO] /* shared.h: NS_OPAQUE_ZERO */
layout(std430, binding = 1) writeonly buffer OutBlock { float outv[]; };
layout(std430, binding = 2) readonly buffer PointBlock { vec4 points[]; };

float axis_value(uint axis, uint i)
{
    uint k = axis * NS_NN_MAX_AXIS + i;
    return P.axis[k >> 2][k & 3u];
}

uint node_bin(uint axis, uint k)
{
    return uint(P.interp[axis * NS_NN_MAX_AXIS + k].x);
}

// Normalised inputs of node or point `index`: lo = (rho, z, theta, phi), hi = (g, a, E, 0).
void inputs(uint index, uint channel, uint order, out vec4 lo, out vec4 hi)
{
    if (P.info.y == NS_NN_MODE_POINTS) {
        lo = points[2u * index];
        hi = points[2u * index + 1u];
        return;
    }
    // index runs over the nodes (the evaluated bins) of each axis.
    uint iphi = node_bin(3u, index % P.nodes.w);
    uint itheta = node_bin(2u, (index / P.nodes.w) % P.nodes.z);
    uint spatial = index / (P.nodes.w * P.nodes.z);
    uint irho = node_bin(1u, spatial % P.nodes.y);
    uint iz = node_bin(0u, spatial / P.nodes.y);
    lo = vec4(axis_value(1u, irho), axis_value(0u, iz), axis_value(2u, itheta),
              axis_value(3u, iphi));
    vec4 c = P.channel[channel];
    hi = vec4(c.x, c.y, order == 0u ? c.z : c.w, 0.0);
}

void main()
{
    // From the workgroup id, not the invocation id: the compiler then knows they are the same
    // for all lanes, so weight fetches stay scalar loads instead of per-lane gathers.
    uint order = gl_WorkGroupID.z + P.orders.x; // P.orders: nn_shared.h
    uint channel = gl_WorkGroupID.y;
    uint first = gl_GlobalInvocationID.x * NS_NN_POINTS;
    uint count = P.info.x;
    if (first >= count)
        return;

    uint net = order * NS_NN_NET_VEC4;

    vec4 h1[NS_NN_POINTS * NS_NN_H4];
    float energy[NS_NN_POINTS]; // E_k, or 0 outside the trained extent (inputs < 0)
    [[unroll]] for (uint p = 0u; p < NS_NN_POINTS; p++) {
        vec4 lo, hi;
        inputs(min(first + p, count - 1u), channel, order, lo, hi);
        energy[p] = min(lo.x, lo.y) < 0.0 ? 0.0 : hi.z;
        for (uint j4 = 0u; j4 < NS_NN_H4; j4++) {
            vec4 a = P.net[net + NS_NN_B1_OFF + j4];
            for (uint c = 0u; c < 4u; c++) {
                uint row = net + NS_NN_W1_OFF + 2u * (4u * j4 + c);
                // hi.zw carry E and 0: the padded weights 6 and 7 are zero.
                a[c] += dot(P.net[row], lo) + dot(P.net[row + 1u], vec4(hi.xy, 0.0, 0.0));
            }
            h1[j4 * NS_NN_POINTS + p] = tanh(a);
        }
    }

    // Layer 2 one point at a time: a single running sum per (unit, point) keeps the CPU's
    // vector registers free. Sixteen sums at once (all points of a unit, the weight fetched
    // once for all) spilled them to the stack on lavapipe and took 1.6x as long; a weight
    // fetched again per point is a broadcast from L1 (docs/network.md, 2026-11-29).
    float y[NS_NN_POINTS];
    [[unroll]] for (uint p = 0u; p < NS_NN_POINTS; p++)
        y[p] = P.net[net + NS_NN_B3_OFF].x;
    for (uint j = 0u; j < 50u; j++) {
        float bias = P.net[net + NS_NN_B2_OFF + (j >> 2)][j & 3u];
        float w3 = P.net[net + NS_NN_W3_OFF + (j >> 2)][j & 3u];
        [[unroll]] for (uint p = 0u; p < NS_NN_POINTS; p++) {
            float acc = bias;
            [[unroll]] for (uint k4 = 0u; k4 < NS_NN_H4; k4++)
                acc += dot(P.net[net + NS_NN_W2_OFF + j * NS_NN_H4 + k4], h1[k4 * NS_NN_POINTS + p]);
            y[p] += w3 * tanh(acc);
        }
    }

    vec4 tt = P.target[order];
    uint base = P.info.y == NS_NN_MODE_POINTS ? order * count : (order * 3u + channel) * count;
    for (uint p = 0u; p < NS_NN_POINTS && first + p < count; p++) {
        float t = y[p] * tt.w + tt.z;
        outv[base + first + p] = P.info.z != 0u ? t : nn_target_to_j(tt, t, energy[p]);
        if (P.info.y == NS_NN_MODE_POINTS) // the raw network output too, after both orders' J
            outv[(2u + order) * count + first + p] = y[p];
    }
}
