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
layout(push_constant) uniform PushBlock { GpuVrlPush push; };

const float PI = 3.14159265358979;

// ---------------------------------------------------------------------------------------
// Random numbers: a PCG hash chain per path (deterministic for a seed).
// ---------------------------------------------------------------------------------------
uint rng_state;

uint pcg_hash(uint v)
{
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

float rnd()
{
    rng_state = pcg_hash(rng_state);
    return float(rng_state >> 8u) * (1.0 / 16777216.0);
}

float ray_epsilon(vec3 p)
{
    return 1e-4 * max(1.0, max(abs(p.x), max(abs(p.y), abs(p.z))));
}

// Orthonormal basis around n (Duff et al. 2017).
void basis(vec3 n, out vec3 t, out vec3 b)
{
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}

vec3 around(vec3 axis, float cos_t, float phi)
{
    float sin_t = sqrt(max(0.0, 1.0 - cos_t * cos_t));
    vec3 tx, ty;
    basis(axis, tx, ty);
    return normalize(tx * (sin_t * cos(phi)) + ty * (sin_t * sin(phi)) + axis * cos_t);
}

vec3 uniform_sphere()
{
    return around(vec3(0.0, 0.0, 1.0), 1.0 - 2.0 * rnd(), 2.0 * PI * rnd());
}

// A point uniform on the disk of radius r around c perpendicular to d.
vec3 disk_point(vec3 c, vec3 d, float r)
{
    vec3 tx, ty;
    basis(d, tx, ty);
    float rho = r * sqrt(rnd()), phi = 2.0 * PI * rnd();
    return c + rho * (cos(phi) * tx + sin(phi) * ty);
}

// Cosine of the half-angle of the cone from p that holds the sphere (c, r); -1 inside it.
float cone_cos(vec3 p, vec3 c, float r)
{
    vec3 v = c - p;
    float d2 = dot(v, v);
    return d2 > r * r ? sqrt(1.0 - r * r / d2) : -1.0;
}

// Unpolarised Fresnel reflectance of a smooth dielectric (as camera.comp); eta = n_i / n_t.
float fresnel(float cos_i, float eta, out float cos_t)
{
    float sin2_t = eta * eta * max(0.0, 1.0 - cos_i * cos_i);
    cos_t = 0.0;
    if (sin2_t >= 1.0)
        return 1.0;
    cos_t = sqrt(1.0 - sin2_t);
    float rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    float rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

bool scatters(GpuMaterial m)
{
    return m.reflectance.w != 0.0 && max(m.sigma_s.x, max(m.sigma_s.y, m.sigma_s.z)) > 0.0;
}

// An index-matched medium that does not scatter: light crosses it, attenuated.
bool crossable(GpuMaterial m)
{
    return m.reflectance.w != 0.0 && m.sigma_t.w == 1.0 && !scatters(m);
}

vec3 beer_lambert(vec3 sigma_t, float distance)
{
    vec3 tau = vec3(sigma_t.x > 0.0 ? sigma_t.x * distance : 0.0,
                    sigma_t.y > 0.0 ? sigma_t.y * distance : 0.0,
                    sigma_t.z > 0.0 ? sigma_t.z * distance : 0.0);
    return exp(-tau);
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
        uint m = prims[h.prim].info.y;
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
        GpuPrim p = prims[hit.prim];
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
// sample carries (before the stratum's weight). Each estimator is unbiased for the flux the
// light sends through the target sphere (c, r).
// ---------------------------------------------------------------------------------------
bool emit(GpuLight light, vec3 c, float r, out vec3 o, out vec3 d, out uint medium, out vec3 beta)
{
    medium = NS_NONE;
    uint kind = light.info.x;
    if (kind == NS_GPU_LIGHT_DIRECTIONAL || kind == NS_GPU_LIGHT_ENVIRONMENT) {
        // A uniform point on the disk perpendicular to d covering the target sphere, moved
        // back just outside it: E * area (directional); the environment first draws d
        // uniformly over the sphere of directions: L * 4 pi * area.
        d = kind == NS_GPU_LIGHT_DIRECTIONAL ? light.direction.xyz : uniform_sphere();
        float area = PI * r * r;
        beta = light.color.rgb * (kind == NS_GPU_LIGHT_DIRECTIONAL ? area : 4.0 * PI * area);
        o = disk_point(c, d, r) - (1.001 * r + ray_epsilon(c)) * d;
        beta *= from_infinity(o, d, medium);
    } else if (kind == NS_GPU_LIGHT_POINT) {
        // Uniform directions in the cone subtending the sphere: I * solid angle.
        o = light.position.xyz;
        float cos_max = cone_cos(o, c, r);
        vec3 axis = cos_max > -1.0 ? normalize(c - o) : vec3(0.0, 0.0, 1.0);
        d = around(axis, 1.0 - rnd() * (1.0 - cos_max), 2.0 * PI * rnd());
        beta = light.color.rgb * (2.0 * PI * (1.0 - cos_max));
    } else {
        // Sphere light of radiance L: a uniform point on its surface (pdf 1 / area), then a
        // uniform direction in the cone from there to the target (pdf 1 / solid angle):
        // L * cos * solid angle * area, zero when the direction goes into the light. From a
        // point inside the target sphere, cosine-distributed directions: L * pi * area.
        vec3 n = uniform_sphere();
        float radius = light.position.w;
        float area = 4.0 * PI * radius * radius;
        o = light.position.xyz + radius * n;
        float cos_max = cone_cos(o, c, r);
        if (cos_max > -1.0) {
            d = around(normalize(c - o), 1.0 - rnd() * (1.0 - cos_max), 2.0 * PI * rnd());
            beta = light.color.rgb * (max(dot(n, d), 0.0) * 2.0 * PI * (1.0 - cos_max) * area);
        } else {
            float s = sqrt(rnd());
            d = around(n, sqrt(max(0.0, 1.0 - s * s)), 2.0 * PI * rnd());
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
    uint m = prims[h.prim].info.y;
    float ior = materials[m].sigma_t.w;
    vec3 d_in = d;
    if (ior != 1.0) {
        float eta = 1.0 / ior;
        float cos_i = -dot(d, h.normal);
        float cos_t;
        float f = fresnel(cos_i, eta, cos_t); // from the outside: never total reflection
        d_in = normalize(eta * d + (eta * cos_i - cos_t) * h.normal);
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
    if (len <= 0.0 || prims[exit_hit.prim].info.y != v.material || exit_hit.front)
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
    if (emit(lights[s.ids.y], s.target.xyz, s.target.w, o, d, medium, beta) &&
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
