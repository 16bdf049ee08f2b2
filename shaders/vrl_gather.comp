#version 450
// vrl_gather.comp — ray-to-ray transport of the `vrl` method (Novak et al. 2012): every
// camera segment against every VRL of its medium, one invocation per segment, one sample
// per (segment, VRL) pair. The radiance a VRL sends to the segment's entry is
//
//   L = int_0^Lc dt int_0^l du  Phi sigma_s^2 p(w . v) p(v . -d) e^{-sigma_t (t + u + |x - y|)} / |x - y|^2
//
// with x = entry + t d on the camera segment, y = origin + u w on the VRL, v = (x - y) / |x - y|
// and Phi the VRL's power (flux at its origin). The pair is sampled as in Novak et al. 2012:
// t with density proportional to 1 / h(t), h = distance from x to the VRL's line, then u
// by equiangular sampling from x (density proportional to 1 / |x - y|^2). The two
// singular factors cancel against the densities, so the estimate stays bounded where the
// segment passes close to the VRL; transmittance and phase functions are evaluated.
// Nearly parallel lines take t uniformly instead.
//
// Random numbers come from a hash of (seed, segment, VRL), so the result does not depend on
// how the VRLs are split across dispatches (render/vrl_method.c has the same estimator on
// the CPU for the tests). A segment resumes at results[i].next_vrl after yielding
// (lavapipe's loop limit).
#extension GL_GOOGLE_include_directive : require
#include "shared.h"
#include "scatter_shared.h"
#include "vrl_method_shared.h"
#include "trace.glsl"

layout(local_size_x = NS_VRL_METHOD_GROUP) in;

layout(std430, binding = 3) readonly buffer MaterialBlock { GpuMaterial materials[]; };
layout(std430, binding = 4) readonly buffer SegmentBlock { GpuSegment segments[]; };
// GpuVrl read as three vec4 (origin + length, direction + material, power + events):
// glslang takes `vrl.length` for the length() method.
layout(std430, binding = 5) readonly buffer VrlBlock { vec4 vrl_words[]; };

struct Vrl {
    vec3 origin;
    float len;
    vec3 direction;
    vec3 power;
    uint events;
};

Vrl load_vrl(uint k)
{
    vec4 a = vrl_words[3u * k], b = vrl_words[3u * k + 1u], c = vrl_words[3u * k + 2u];
    return Vrl(a.xyz, a.w, b.xyz, c.xyz, floatBitsToUint(c.w));
}
layout(std430, binding = 6) buffer ResultBlock { GpuVrlResult results[]; };
layout(std430, binding = 7) buffer CounterBlock { uint counters[]; };
layout(push_constant) uniform PushBlock { GpuVrlGatherPush ns_push[1]; };
#define push ns_push[NS_OPAQUE_ZERO] /* shared.h: NS_OPAQUE_ZERO */

#include "common.glsl"

// Sines below this count as parallel lines (t sampled uniformly).
const float PARALLEL_SIN = 1e-3;
// Distances below this fraction of the segment's length count as touching.
const float MIN_DISTANCE = 1e-6;

// e^{asinh(x)} = x + sqrt(1 + x^2), without cancellation for negative x.
float asinh_exp(float x)
{
    float root = sqrt(1.0 + x * x);
    return x >= 0.0 ? x + root : 1.0 / (root - x);
}

// One sample of the pair's transport per unit Phi (RGB), before the VRL's power.
vec3 pair_estimate(vec3 e, vec3 dc, float lc, Vrl vrl, GpuMaterial m, float xi_t, float xi_u)
{
    vec3 w = vrl.direction;
    float l = vrl.len;
    vec3 r = e - vrl.origin;
    float b = dot(dc, w);
    float sin2 = max(0.0, 1.0 - b * b);
    float s = sqrt(sin2);
    float dd = dot(dc, r), ee = dot(w, r);
    float floor_h = MIN_DISTANCE * max(lc, l);
    float t, inv_pdf_t;
    bool parallel = s < PARALLEL_SIN;
    if (!parallel) {
        float t0 = (b * ee - dd) / sin2;
        float u0 = (ee - b * dd) / sin2;
        float h0 = max(length(r + t0 * dc - u0 * w), floor_h);
        float k = s / h0;
        // The inverse CDF t = t0 + sinh(a0 + xi (a1 - a0)) / k with a = asinh(k (t - t0)) at
        // the ends, rearranged so that nothing cancels when t0 lies far outside the segment:
        // with E = e^{xi (a1 - a0)} and q = sqrt(1/k^2 + t0^2),
        //   t0 <= 0: t = -t0 (E - 1)^2 / (2E) + q (E - 1/E) / 2
        //   t0 >  0: t = t0 (E - 1) / E + (E - 1/E) / (2 k^2 (q + t0)).
        float span = log(asinh_exp(k * (lc - t0)) / asinh_exp(-k * t0)); // a1 - a0
        float big_e = exp(xi_t * span);
        float q = sqrt(1.0 / (k * k) + t0 * t0);
        float sinh_part = 0.5 * (big_e - 1.0 / big_e);
        t = t0 <= 0.0 ? -t0 * (big_e - 1.0) * (big_e - 1.0) / (2.0 * big_e) + q * sinh_part
                      : t0 * (big_e - 1.0) / big_e + sinh_part / (k * k * (q + t0));
        t = clamp(t, 0.0, lc);
        // 1 / pdf(t) = (a1 - a0) h(t) / s; h(t) cancels against equiangular 1 / h below.
        inv_pdf_t = span / s;
    } else {
        t = xi_t * lc;
        inv_pdf_t = lc;
    }
    vec3 x = e + t * dc;
    float uc = dot(x - vrl.origin, w);
    float hx = max(length(x - vrl.origin - uc * w), floor_h);
    float th0 = atan(-uc, hx), th1 = atan(l - uc, hx);
    float u = clamp(uc + hx * tan(mix(th0, th1, xi_u)), 0.0, l);
    // 1 / (|x - y|^2 pdf(u)) = (th1 - th0) / hx; the 1 / h of pdf(t) is that same hx.
    float geometry = (th1 - th0) * inv_pdf_t / (parallel ? hx : 1.0);
    vec3 y = vrl.origin + u * w;
    vec3 v = x - y;
    float dist = length(v);
    if (!(dist > 0.0))
        return vec3(0.0);
    v /= dist;
    if (push.visibility != 0u) {
        Hit hit;
        if (trace_scene(y, v, 0.0, max(0.0, dist - ray_epsilon(x)), hit))
            return vec3(0.0);
    }
    float g = m.sigma_s.w;
    float phases = hg_phase(dot(w, v), g) * hg_phase(-dot(v, dc), g);
    vec3 tr = exp(-m.sigma_t.xyz * (t + u + dist));
    return m.sigma_s.xyz * m.sigma_s.xyz * tr * (phases * geometry);
}

void main()
{
    uint i = gl_GlobalInvocationID.x;
    if (i >= push.segment_count)
        return;
    GpuSegment seg = segments[i];
    if (seg.material != push.material)
        return;
    GpuVrlResult res = results[i];
    uint k = max(res.next_vrl, push.first_vrl);
    if (k >= push.end_vrl)
        return;
    GpuMaterial m = materials[push.material];
    vec3 dc = seg.direction;
    float lc = length(seg.exit - seg.entry);
    uint seg_seed = pcg_hash(pcg_hash(push.seed ^ 0x68e31da4u) + i);
    vec3 dbl = vec3(0.0), mult = vec3(0.0);
    uint nonfinite = 0u;
    for (; k < push.end_vrl; k++) {
        if (push.yield_after != 0u && loop_count >= push.yield_after)
            break;
        out_of_budget();
        Vrl vrl = load_vrl(k);
        uint h1 = pcg_hash(seg_seed ^ pcg_hash(k));
        uint h2 = pcg_hash(h1);
        vec3 c = vrl.power * pair_estimate(seg.entry, dc, lc, vrl, m, unit_float(h1), unit_float(h2));
        if (any(isnan(c)) || any(isinf(c))) {
            nonfinite++;
            continue;
        }
        if (vrl.events == 0u)
            dbl += c;
        else
            mult += c;
    }
    res.double_rgb += dbl;
    res.multiple_rgb += mult;
    res.next_vrl = k;
    results[i] = res;
    if (nonfinite != 0u)
        atomicAdd(counters[NS_VRL_GATHER_NONFINITE], nonfinite);
    if (push.report != 0u && k < push.end_vrl)
        atomicAdd(counters[NS_VRL_GATHER_UNFINISHED], 1u);
    uint probe_end = min(push.segment_count, 64u), probe = 0u;
    for (uint q = 0u; q <= probe_end; q++)
        probe++;
    if ((params.limits.x != 0u && loop_count > params.limits.x) || probe != probe_end + 1u)
        atomicAdd(counters[NS_VRL_GATHER_LOOP_LIMIT], 1u);
}
