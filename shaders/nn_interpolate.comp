#version 450
// nn_interpolate.comp — the second pass of a sampled network reconstruction
// (render/nn_reconstruct.c): nn_reconstruct.comp evaluated the networks only at the nodes
// (docs/network.md) and wrote t, the network's output in the target's log space; this pass
// fills every cell of the table with J, multilinear in t between the nodes around it
// (lower node and weight per axis and bin from the CPU, GpuNnParams.interp).
// One invocation per row of cells along phi (gl_GlobalInvocationID.x = (z, rho, theta)
// row; .y the channel, .z the order): it interpolates z, rho and theta once per phi node
// and then only along phi, so a cell costs a few loads instead of 16. Every lane walks phi
// in step, so the "next phi node" branch is uniform.
// A separate pipeline: compiled into nn_reconstruct.comp, this code made the network
// evaluation 3x slower on lavapipe (measured).
// out[(order * 3 + channel) * cells + cell] = J; t[(order * 3 + channel) * nodes + node].
#extension GL_GOOGLE_include_directive : require
#include "nn_shared.h"

layout(local_size_x = NS_NN_GROUP) in;

layout(std140, binding = 0) uniform NnBlock { GpuNnParams ns_nn[1]; };
#define P ns_nn[NS_OPAQUE_ZERO] /* shared.h: NS_OPAQUE_ZERO */
layout(std430, binding = 1) writeonly buffer OutBlock { float outv[]; };
layout(std430, binding = 2) readonly buffer NodeBlock { float node_t[]; };

float axis_value(uint axis, uint i)
{
    uint k = axis * NS_NN_MAX_AXIS + i;
    return P.axis[k >> 2][k & 3u];
}

// Lower node and the next one's weight of bin i along an axis.
void axis_weight(uint axis, uint i, out uint lo, out float w)
{
    vec4 e = P.interp[axis * NS_NN_MAX_AXIS + i];
    lo = uint(e.y);
    w = e.z;
}

// t at phi node kp, interpolated over the 8 (z, rho, theta) nodes around the row.
float row_t(uint src, uvec3 lo, uvec3 hi, vec3 w, uvec3 stride, uint kp)
{
    float t = 0.0;
    for (uint corner = 0u; corner < 8u; corner++) {
        bvec3 up = notEqual(uvec3(corner) & uvec3(4u, 2u, 1u), uvec3(0u));
        uvec3 k = mix(lo, hi, up);
        vec3 f = mix(1.0 - w, w, up);
        float weight = f.x * f.y * f.z;
        // Rows on a node of an axis (every row along theta by default) skip its far corners:
        // half the loads or more, and the same branch for most lanes.
        if (weight != 0.0)
            t += weight * node_t[src + k.x * stride.x + k.y * stride.y + k.z * stride.z + kp];
    }
    return t;
}

void main()
{
    uint order = gl_WorkGroupID.z + P.orders.x; // P.orders: nn_shared.h
    uint channel = gl_WorkGroupID.y;
    uint row = gl_GlobalInvocationID.x;
    uint cells = P.info.x;
    uint nphi = P.counts.w;
    if (row * nphi >= cells)
        return;
    uvec3 bin = uvec3(row / (P.counts.y * P.counts.z), (row / P.counts.z) % P.counts.y,
                      row % P.counts.z);
    uvec3 lo, hi;
    vec3 w;
    for (uint a = 0u; a < 3u; a++) {
        axis_weight(a, bin[a], lo[a], w[a]);
        hi[a] = min(lo[a] + 1u, P.nodes[a] - 1u);
    }
    uvec3 stride = uvec3(P.nodes.y * P.nodes.z * P.nodes.w, P.nodes.z * P.nodes.w, P.nodes.w);
    uint src = (order * 3u + channel) * P.info.w;
    uint dst = (order * 3u + channel) * cells + row * nphi;
    vec4 tt = P.target[order];
    vec4 c = P.channel[channel];
    bool outside = min(axis_value(0u, bin.x), axis_value(1u, bin.y)) < 0.0;
    float energy = outside ? 0.0 : (order == 0u ? c.z : c.w);
    uint last_phi = P.nodes.w - 1u;
    uint cur = 0u; // phi node whose t is in t_lo
    float t_lo = row_t(src, lo, hi, w, stride, 0u);
    float t_hi = row_t(src, lo, hi, w, stride, min(1u, last_phi));
    for (uint ip = 0u; ip < nphi; ip++) {
        uint kp;
        float wp;
        axis_weight(3u, ip, kp, wp);
        if (kp != cur) { // the same for every lane: uniform
            t_lo = kp == cur + 1u ? t_hi : row_t(src, lo, hi, w, stride, kp);
            t_hi = row_t(src, lo, hi, w, stride, min(kp + 1u, last_phi));
            cur = kp;
        }
        outv[dst + ip] = nn_target_to_j(tt, mix(t_lo, t_hi, wp), energy);
    }
}
