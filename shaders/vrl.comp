#version 450
// vrl.comp — Virtual Ray Light generation: one invocation per light path (render/vrl.c
// plans the paths). A path leaves its light aimed at the bounding sphere of one medium
// object (its stratum), walks in a straight line to the first medium it enters, and, when
// that is its target object, stores the first stretch inside as a GpuVrl:
//   - diffuse surfaces, refracting non-scattering boundaries (glass) and any other
//     scattering medium end the walk: no caustics through other objects (the other stages'
//     model), and light entering another scattering medium is that medium's strata's job;
//   - index-matched (ior 1) non-scattering media are crossed with their Beer-Lambert factor;
//   - at the target's boundary the refracted part is kept with weight 1 - F (deterministic,
//     power-correct); the reflected part is not followed; ior 1 enters unchanged;
//   - inside, the unscattered beam is followed through internal reflections, up to
//     push.chain stretches in all: where a stretch meets its medium's boundary, the beam is
//     reflected with the Fresnel probability F (1 on total internal reflection; Russian
//     roulette: the reflected stretch carries the beam's power as it arrives, e^{-sigma_t L}
//     P) and every reflected stretch is one more VRL with events 0. The transmitted part
//     leaves; the gather ends each stretch at its exit (gather.comp).
// Every path writes its own push.chain slots (path index * chain + stretch), VRLs or
// material = NS_NONE, so the result does not depend on the order invocations run in; the C
// side compacts the slots.
#extension GL_GOOGLE_include_directive : require
#include "shared.h"
#include "scatter_shared.h"
#include "vrl_shared.h"
#include "trace.glsl"

layout(local_size_x = NS_VRL_GROUP) in;

layout(std430, binding = 3) readonly buffer MaterialBlock { GpuMaterial materials[]; };
layout(std430, binding = 4) readonly buffer LightBlock { GpuLight lights[]; };
layout(std430, binding = 5) readonly buffer StratumBlock { GpuVrlStratum strata[]; };
layout(std430, binding = 6) writeonly buffer VrlBlock { GpuVrl vrls[]; };
layout(std430, binding = 7) buffer CounterBlock { uint counters[]; };
layout(push_constant) uniform PushBlock { GpuVrlPush ns_push[1]; };
#define push ns_push[NS_OPAQUE_ZERO] /* shared.h: NS_OPAQUE_ZERO */

#include "common.glsl"

// An index-matched medium that does not scatter: light crosses it, attenuated.
bool crossable(GpuMaterial m)
{
    return m.reflectance.w != 0.0 && m.sigma_t.w == 1.0 && !scatters(m);
}

// ---------------------------------------------------------------------------------------
// Light that comes from infinity (directional, environment) to the start point o, just
// outside the target sphere: the line behind o must be clear of everything but crossable
// media. Returns the transmittance and the crossable medium o lies in (NS_NONE: vacuum).
// ---------------------------------------------------------------------------------------
vec3 from_infinity(vec3 o, vec3 d, out uint medium_at_o)
{
    medium_at_o = NS_NONE;
    vec3 tau = vec3(0.0);
    float t_enter = 0.0, tmin = 0.0;
    bool inside = false;
    for (uint crossing = 0u; crossing < NS_VRL_MAX_CROSSINGS; crossing++) {
        if (out_of_budget())
            return vec3(0.0);
        Hit h;
        if (!trace_scene(o, -d, tmin, NS_INF, h))
            return inside ? vec3(0.0) : exp(-tau); // an unbounded medium behind: no light
        uint m = prim_at(h.prim).info.y;
        GpuMaterial mat = materials[m];
        if (!crossable(mat))
            return vec3(0.0);
        if (!h.front) { // walking backwards out of m: the stretch since t_enter was inside
            if (crossing == 0u)
                medium_at_o = m;
            tau += mat.sigma_t.xyz * (h.t - t_enter);
        }
        inside = h.front;
        t_enter = h.t;
        tmin = h.t + ray_epsilon(o + h.t * -d);
    }
    return vec3(0.0);
}

// ---------------------------------------------------------------------------------------
// The forward walk from o along d, starting in `medium` (crossable or NS_NONE), to the first
// scattering medium it enters. True when that is the target object; hit = its boundary.
// ---------------------------------------------------------------------------------------
bool walk_to_target(vec3 o, vec3 d, uint medium, uint target_object, inout vec3 beta, out Hit hit)
{
    float t_enter = 0.0, tmin = 0.0;
    for (uint crossing = 0u; crossing < NS_VRL_MAX_CROSSINGS; crossing++) {
        if (out_of_budget())
            return false;
        if (!trace_scene(o, d, tmin, NS_INF, hit))
            return false;
        if (medium != NS_NONE)
            beta *= beer_lambert(materials[medium].sigma_t.xyz, hit.t - t_enter);
        GpuPrim p = prim_at(hit.prim);
        GpuMaterial mat = materials[p.info.y];
        if (scatters(mat))
            return hit.front && p.info.z == target_object;
        if (!crossable(mat))
            return false;
        medium = hit.front ? p.info.y : NS_NONE;
        t_enter = hit.t;
        tmin = hit.t + ray_epsilon(o + hit.t * d);
    }
    return false;
}

// ---------------------------------------------------------------------------------------
// Emission: a start point o, a direction d, the medium o lies in, and beta = the flux the
// sample carries (before the stratum's weight), from the uniform numbers u (the stratum's
// stratified point for this path: common.glsl, stratified4). Each estimator is unbiased
// for the flux the light sends through the target sphere (c, r).
// ---------------------------------------------------------------------------------------
bool emit(GpuLight light, vec3 c, float r, vec4 u, out vec3 o, out vec3 d, out uint medium,
          out vec3 beta)
{
    medium = NS_NONE;
    uint kind = light.info.x;
    if (kind == NS_GPU_LIGHT_DIRECTIONAL || kind == NS_GPU_LIGHT_ENVIRONMENT) {
        // A uniform point on the disk perpendicular to d covering the target sphere, moved
        // back just outside it: E * area (directional); the environment first draws d
        // uniformly over the sphere of directions: L * 4 pi * area.
        d = kind == NS_GPU_LIGHT_DIRECTIONAL ? light.direction.xyz : uniform_sphere_at(u.z, u.w);
        float area = PI * r * r;
        beta = light.color.rgb * (kind == NS_GPU_LIGHT_DIRECTIONAL ? area : 4.0 * PI * area);
        o = disk_before_sphere_at(c, r, d, u.x, u.y);
        beta *= from_infinity(o, d, medium);
    } else if (kind == NS_GPU_LIGHT_POINT) {
        // Uniform directions in the cone subtending the sphere: I * solid angle.
        o = light.position.xyz;
        float cos_max = cone_cos(o, c, r);
        vec3 axis = cos_max > -1.0 ? normalize(c - o) : vec3(0.0, 0.0, 1.0);
        d = around(axis, 1.0 - u.x * (1.0 - cos_max), 2.0 * PI * u.y);
        beta = light.color.rgb * (2.0 * PI * (1.0 - cos_max));
    } else {
        // Sphere light of radiance L: a uniform point on its surface (pdf 1 / area), then a
        // uniform direction in the cone from there to the target (pdf 1 / solid angle):
        // L * cos * solid angle * area, zero when the direction goes into the light. From a
        // point inside the target sphere, cosine-distributed directions: L * pi * area.
        vec3 n = uniform_sphere_at(u.x, u.y);
        float radius = light.position.w;
        float area = 4.0 * PI * radius * radius;
        o = light.position.xyz + radius * n;
        float cos_max = cone_cos(o, c, r);
        if (cos_max > -1.0) {
            d = around(normalize(c - o), 1.0 - u.z * (1.0 - cos_max), 2.0 * PI * u.w);
            beta = light.color.rgb * (max(dot(n, d), 0.0) * 2.0 * PI * (1.0 - cos_max) * area);
        } else {
            d = cosine_sample_at(n, u.z, u.w);
            beta = light.color.rgb * (PI * area);
        }
        o += n * ray_epsilon(o);
    }
    return max(beta.x, max(beta.y, beta.z)) > 0.0;
}

// The stratum of path i: the last one whose first path is <= i (strata are sorted).
uint stratum_of(uint i)
{
    uint lo = 0u, hi = push.stratum_count - 1u;
    while (lo < hi) {
        out_of_budget();
        uint mid = (lo + hi + 1u) >> 1u;
        if (strata[mid].ids.x <= i)
            lo = mid;
        else
            hi = mid - 1u;
    }
    return lo;
}

// The VRL at the boundary point the path entered through: refracted direction, (1 - F),
// and the distance to the next boundary along it (exit_hit: that boundary, exit_hit.t = 0
// when there is none).
GpuVrl enter(vec3 o, vec3 d, Hit h, vec3 beta, out Hit exit_hit)
{
    vec3 p = o + h.t * d;
    uint m = prim_at(h.prim).info.y;
    float ior = materials[m].sigma_t.w;
    vec3 d_in = d;
    if (ior != 1.0) {
        float eta = 1.0 / ior;
        float cos_i = -dot(d, h.normal);
        float cos_t;
        float f = fresnel(cos_i, eta, cos_t); // from the outside: never total reflection
        d_in = refract_direction(d, h.normal, eta, cos_i, cos_t);
        beta *= 1.0 - f;
    }
    float stretch = trace_scene(p, d_in, ray_epsilon(p), NS_INF, exit_hit) ? exit_hit.t : 0.0;
    exit_hit.t = stretch;
    // A constructor: glslang reads `v.length` as the length() method.
    return GpuVrl(p, stretch, d_in, m, beta, 0u);
}

// The stretch after `v`, which ends on `exit_hit` (exit_hit.t = its length, 0 without an
// exit): its internal reflection there, taken with the Fresnel probability, or false when
// the beam leaves (or ends anywhere but on its own medium's boundary, seen from inside).
// exit_hit becomes the new stretch's end.
bool reflect_stretch(GpuVrl v, inout Hit exit_hit, out GpuVrl next)
{
    next = v;
    float len = exit_hit.t;
    if (len <= 0.0 || prim_at(exit_hit.prim).info.y != v.material || exit_hit.front)
        return false;
    GpuMaterial mat = materials[v.material];
    vec3 n = exit_hit.normal; // outward: the beam leaves along it
    float cos_t;
    float f = fresnel(dot(v.direction, n), mat.sigma_t.w, cos_t); // 1 on total reflection
    // A beam too faint to be subtracted past its exit (gather.comp) is not reflected either.
    vec3 arriving = beer_lambert(mat.sigma_t.xyz, len);
    if (mat.sigma_t.w == 1.0 || max(arriving.x, max(arriving.y, arriving.z)) <= NS_BEAM_CUTOFF ||
        rnd() >= f)
        return false;
    vec3 p = v.origin + len * v.direction;
    p -= n * ray_epsilon(p);
    vec3 d = normalize(reflect(v.direction, n));
    float stretch = trace_scene(p, d, 0.0, NS_INF, exit_hit) ? exit_hit.t : 0.0;
    exit_hit.t = stretch;
    next = GpuVrl(p, stretch, d, v.material, v.power * arriving, 0u);
    return max(next.power.x, max(next.power.y, next.power.z)) > 0.0;
}

void main()
{
    uint i = gl_GlobalInvocationID.x;
    if (i >= push.path_count || push.stratum_count == 0u)
        return;
    rng_state = pcg_hash(pcg_hash(push.seed) + i);
    GpuVrlStratum s = strata[stratum_of(i)];
    vec3 o, d, beta;
    uint medium;
    Hit h, exit_hit;
    const GpuVrl none = GpuVrl(vec3(0.0), 0.0, vec3(0.0), NS_NONE, vec3(0.0), 0u);
    GpuVrl chain[NS_VRL_MAX_CHAIN];
    uint stored = 0u;
    vec4 u = stratum_point(i, s.ids.x, s.ids.w, push.seed);
    if (emit(lights[s.ids.y], s.target.xyz, s.target.w, u, o, d, medium, beta) &&
        walk_to_target(o, d, medium, s.ids.z, beta, h)) {
        GpuVrl v = enter(o, d, h, beta * s.weight.x, exit_hit);
        if (max(v.power.x, max(v.power.y, v.power.z)) > 0.0) {
            chain[stored++] = v;
            GpuVrl next;
            while (stored < push.chain && reflect_stretch(v, exit_hit, next)) {
                chain[stored++] = next;
                v = next;
            }
        }
    }
    if (push.budget != 0u && loop_count > push.budget) {
        atomicAdd(counters[NS_VRL_COUNTER_LOOP_LIMIT], 1u);
        stored = 0u;
    }
    for (uint k = 0u; k < push.chain; k++)
        vrls[i * push.chain + k] = k < stored ? chain[k] : none;
    if (stored > 0u)
        atomicAdd(counters[NS_VRL_COUNTER_STORED], stored);
    else
        atomicAdd(counters[NS_VRL_COUNTER_LOST], 1u);
}
