#version 450
// vrl_trace.comp — light paths for the `vrl` method (Novak et al. 2012), one invocation per
// path. A path starts at a light, aimed at the bounding sphere of one scattering medium
// object (render/vrl_method.c picks the (light, object) pair and its weight), crosses what
// lies between (index-matched objects attenuate, anything else ends the path), enters the
// target through its boundary with the Fresnel transmittance (1 - F) as a weight, then walks
// inside: free flights sampled with one hero channel's extinction, the channel picked
// uniformly per path, and the one-sample balance heuristic over the three channels' pdfs of
// the whole path (spectral MIS: unbiased per channel; mis_step), Henyey-Greenstein
// scattering, internal reflection chosen with probability F at the boundary (total internal
// reflection always reflects), Russian roulette. A path that leaves after scattering goes on
// outside, as the emitted ray does, and enters the first scattering object it meets again
// (a non-convex object's own, or another); otherwise it ends.
//
// Every stretch that starts inside the medium (at the entry, an event or an internal
// reflection) is a VRL: origin, direction, length to the boundary ahead (the full ray: the
// gather attenuates along it, so the free-flight distance that ends the stretch in the walk
// is not its length), power = the flux at the origin, events = scattering events before it.
//
// Two passes with the same random numbers: write = 0 counts each path's VRLs, the C side
// turns the counts into offsets, write = 1 stores them there. A path yields after
// push.yield_after counted loop iterations (lavapipe's limit, docs/rendering.md) and the
// next dispatch resumes it from its GpuVrlWalk.
#extension GL_GOOGLE_include_directive : require
#include "shared.h"
#include "scatter_shared.h"
#include "vrl_method_shared.h"
#include "trace.glsl"

layout(local_size_x = NS_VRL_METHOD_GROUP) in;

layout(std430, binding = 3) readonly buffer MaterialBlock { GpuMaterial materials[]; };
layout(std430, binding = 4) readonly buffer EmitterBlock { GpuVrlEmitter emitters[]; };
layout(std430, binding = 5) buffer WalkBlock { GpuVrlWalk walks[]; };
layout(std430, binding = 6) writeonly buffer VrlBlock { GpuVrl vrls[]; };
layout(std430, binding = 7) buffer CounterBlock { uint counters[]; };
// With NS_VRL_TRACE_ENDS, at each stored stretch's slot: its end's reflection (options above).
layout(std430, binding = 8) writeonly buffer EndBlock { vec4 ends[]; };
layout(push_constant) uniform PushBlock { GpuVrlTracePush ns_push[1]; };
#define push ns_push[NS_OPAQUE_ZERO] /* shared.h: NS_OPAQUE_ZERO */

#define NS_COMMON_TRACE
#include "common.glsl"

// Transmittance from o to infinity along d outside the media (the light's side of a
// directional or environment sample): blocked by diffuse surfaces and refracting
// boundaries, attenuated by index-matched media, as the camera pass's shadow rays. It is
// not common.glsl's transmittance(o, d, NS_INF, NS_NONE, 0u), which differs in two
// cases and would change this method's images: a ray that leaves the scene inside an
// index-matched medium keeps exp(-tau) here, where transmittance applies that medium's
// Beer-Lambert to infinity (0 in every channel it attenuates); and a ray that runs out of
// crossings is blocked here, where transmittance returns the attenuation so far.
vec3 transmittance_to_infinity(vec3 o, vec3 d)
{
    vec3 tau = vec3(0.0);
    float t_enter = 0.0, tmin = 0.0;
    uint medium = NS_NONE;
    for (int crossing = 0; crossing < 16; crossing++) {
        Hit h;
        if (!trace_scene(o, d, tmin, NS_INF, h))
            return exp(-tau);
        uint m = prim_at(h.prim).info.y;
        GpuMaterial mat = materials[m];
        if (mat.reflectance.w == 0.0 || mat.sigma_t.w != 1.0)
            return vec3(0.0);
        if (!h.front && medium != NS_NONE)
            tau += materials[medium].sigma_t.xyz * (h.t - t_enter);
        medium = h.front ? m : NS_NONE;
        t_enter = h.t;
        tmin = h.t + ray_epsilon(o + h.t * d);
    }
    return vec3(0.0);
}

// ---------------------------------------------------------------------------------------
// Emission: a ray from the path's light through the target sphere, with its flux.
// ---------------------------------------------------------------------------------------
uint find_emitter(uint path)
{
    // The last emitter whose first path is <= path (they are sorted by first path).
    uint lo = 0u, hi = push.emitter_count;
    while (hi - lo > 1u) {
        uint mid = (lo + hi) / 2u;
        if (emitters[mid].ids.x <= path)
            lo = mid;
        else
            hi = mid;
    }
    return lo;
}

// Direction from o uniform in the cone that the target sphere subtends (the whole sphere of
// directions when o is inside it), from the uniform numbers u and v; returns the cone's
// solid angle (1 / pdf).
float cone_towards(vec4 target, vec3 o, float u, float v, out vec3 d)
{
    vec3 to = target.xyz - o;
    float dist2 = dot(to, to);
    float r2 = target.w * target.w;
    if (dist2 <= r2) {
        d = uniform_sphere_at(u, v);
        return 4.0 * PI;
    }
    return sample_cone_at(target, o, u, v, d);
}

// Emits the ray of `path`; flux = 0 when it carries nothing (a sphere light's back side,
// a directional or environment light blocked upstream). Its numbers are the emitter's
// stratified point for the path (common.glsl, stratified4).
void emit(uint path, out vec3 o, out vec3 d, out vec3 flux, out uint target_object, out uint kind)
{
    GpuVrlEmitter e = emitters[find_emitter(path)];
    vec4 u = stratum_point(path, e.ids.x, e.ids.w, push.seed);
    target_object = e.ids.z;
    kind = e.ids.y;
    vec3 color = e.color.rgb;
    if (kind == NS_GPU_LIGHT_DIRECTIONAL || kind == NS_GPU_LIGHT_ENVIRONMENT) {
        // Flux through the target's disk: E pi r^2 for a directional light; for a uniform
        // environment L every direction (4 pi) brings L pi r^2.
        d = kind == NS_GPU_LIGHT_DIRECTIONAL ? e.direction.xyz : uniform_sphere_at(u.z, u.w);
        o = disk_before_sphere_at(e.target.xyz, e.target.w, d, u.x, u.y);
        float disk = PI * e.target.w * e.target.w;
        flux = color * disk * (kind == NS_GPU_LIGHT_DIRECTIONAL ? 1.0 : 4.0 * PI) *
               transmittance_to_infinity(o, -d);
    } else if (kind == NS_GPU_LIGHT_POINT) {
        o = e.position.xyz;
        flux = color * cone_towards(e.target, o, u.x, u.y, d);
    } else {
        // Sphere light of radiance L: a uniform point on its surface (area A), a direction in
        // the cone towards the target (solid angle W); flux = L cos A W, zero where the
        // direction points into the light.
        vec3 n = uniform_sphere_at(u.x, u.y);
        float radius = e.position.w;
        o = e.position.xyz + n * radius;
        float solid_angle = cone_towards(e.target, o, u.z, u.w, d);
        float cos_n = dot(n, d);
        o += n * ray_epsilon(o);
        flux = cos_n > 0.0 ? color * (cos_n * 4.0 * PI * radius * radius * solid_angle) : vec3(0.0);
    }
}

// Follows a ray outside the media up to a scattering object's boundary and through it.
// Returns true with the walk state set inside that medium, false when the path ends before
// (missed, blocked, reflected off, or it reached another scattering object first).
// An emitted ray enters only target_object: another object's own paths carry the light
// that enters it. A walk that has left its object (re-entry, NS_NONE) enters any
// scattering object it meets, its own included, with its events so far: that light
// reaches the object from nowhere else (docs/scattering.md, *Light that leaves and comes
// back*). roulette_ref: the flux that Russian roulette measures the walk against.
bool enter_object(inout GpuVrlWalk w, vec3 o, vec3 d, vec3 flux, uint target_object, uint events,
                  float roulette_ref)
{
    uint medium = NS_NONE;
    for (uint crossing = 0u; crossing < NS_VRL_MAX_BOUNDARY_RUN; crossing++) {
        if (!(max(flux.x, max(flux.y, flux.z)) > 0.0))
            return false;
        Hit h;
        if (!trace_scene(o, d, 0.0, NS_INF, h))
            return false;
        if (medium != NS_NONE)
            flux *= exp(-materials[medium].sigma_t.xyz * h.t);
        vec3 p = o + h.t * d;
        float eps = ray_epsilon(p);
        uint m = prim_at(h.prim).info.y;
        GpuMaterial mat = materials[m];
        if (mat.reflectance.w == 0.0)
            return false;
        if (spurious_boundary(h.front, m, medium)) {
            o = p + d * eps;
            continue;
        }
        vec3 n = h.front ? h.normal : -h.normal; // faces the incoming ray
        bool wanted = target_object == NS_NONE || prim_at(h.prim).info.z == target_object;
        if (h.front && wanted && scatters(mat)) {
            float ior = mat.sigma_t.w;
            if (ior != 1.0) {
                float eta = 1.0 / ior;
                float cos_i = -dot(d, n);
                float cos_t;
                float f = fresnel(cos_i, eta, cos_t);
                flux *= 1.0 - f;
                d = refract_direction(d, n, eta, cos_i, cos_t);
            }
            w.origin = vec4(p - n * eps, roulette_ref > 0.0 ? roulette_ref
                                                             : max(flux.x, max(flux.y, flux.z)));
            w.direction = vec4(d, 0.0);
            w.flux = vec4(flux, 0.0);
            w.state.y = events;
            w.state.z = m;
            w.count.z = 0u; // walk_step's cap counts boundary events within one object
            return w.origin.w > 0.0 && max(flux.x, max(flux.y, flux.z)) > 0.0;
        }
        // Index-matched objects that do not scatter (or are left again) are crossed;
        // anything else (a refracting boundary, another scattering object) ends the path.
        if (mat.sigma_t.w != 1.0 || (h.front && scatters(mat)))
            return false;
        medium = h.front ? m : NS_NONE;
        o = p - n * eps;
    }
    return false;
}

// ---------------------------------------------------------------------------------------
// The walk inside the medium, one stretch at a time.
// ---------------------------------------------------------------------------------------
// Whether the straight line from p along d meets an object of `medium` (its front face).
// p is the end of a stretch, on its own object's boundary: for render.boundary, the ghost
// there stands for the infinite medium's light going on along this line, and only where
// the line passes through that medium again does its first scattering reach a camera
// segment (render/boundary.c). Everything on the way is crossed: the line is the infinite
// medium's, not light's.
bool line_meets_medium(vec3 p, vec3 d, uint medium)
{
    float tmin = ray_epsilon(p);
    for (uint crossing = 0u; crossing < NS_VRL_LINE_CROSSINGS; crossing++) {
        Hit h;
        if (!trace_scene(p, d, tmin, NS_INF, h))
            return false;
        if (h.front && prim_at(h.prim).info.y == medium)
            return true;
        tmin = h.t + ray_epsilon(p + h.t * d);
    }
    return false;
}

// The reflection at the end of the stretch from o along d that hit h: where walk_step would
// reflect there (its medium's own refracting boundary, left from inside), the mirror
// direction and the Fresnel reflectance walk_step draws against (1 on total internal
// reflection); else 0 (vrl_method_shared.h, NS_VRL_TRACE_ENDS). For unscattered light the
// direction is scaled by the chord ahead, traced from where walk_step would start the
// reflected stretch: boundary.c's expected reflection has no stretch of the walk's own to
// take it from, and with the widest tube instead its first order lost a tenth of the
// single scattering that a glass rod guides by total internal reflection, the part of the
// tube beside its start lying outside the rod (docs/scattering.md, *The expected
// reflections' chords*).
vec4 end_reflection(GpuVrlWalk w, vec3 o, vec3 d, Hit h)
{
    float ior = materials[w.state.z].sigma_t.w;
    if (h.front || prim_at(h.prim).info.y != w.state.z || ior == 1.0)
        return vec4(0.0);
    vec3 n = -h.normal;
    float cos_t;
    float f = fresnel(-dot(d, n), ior, cos_t);
    vec3 mirror = normalize(reflect(d, n));
    if (w.state.y == 0u) {
        vec3 p = o + h.t * d;
        Hit ahead;
        if (!trace_scene(p + n * ray_epsilon(p), mirror, 0.0, NS_INF, ahead))
            return vec4(0.0);
        mirror *= ahead.t;
    }
    return vec4(mirror, f < 1.0 ? f : 1.0);
}

void store_vrl(inout GpuVrlWalk w, vec3 o, vec3 d, Hit h)
{
    if (push.write != 0u) {
        uint slot = w.count.y + w.count.x;
        if (slot < push.vrl_capacity) {
            float len = h.t;
            // The count has the low 16 bits of the word (scatter_shared.h): a count past them
            // (a walk that long) reads as that many, every order from 2 on being one table.
            uint events = min(w.state.y, NS_VRL_EVENT_COUNT);
            if ((push.options & NS_VRL_TRACE_MARK_ENVIRONMENT) != 0u && events == 0u && w.mis.w != 0.0)
                events |= NS_VRL_FROM_ENVIRONMENT;
            if ((push.options & NS_VRL_TRACE_MARK_LINES) != 0u &&
                line_meets_medium(o + len * d, d, w.state.z))
                events |= NS_VRL_LINE_RETURNS;
            // A constructor: glslang reads `v.length` as the length() method.
            vrls[slot] = GpuVrl(o, len, d, w.state.z, w.flux.xyz, events);
            if ((push.options & NS_VRL_TRACE_ENDS) != 0u)
                ends[slot] = end_reflection(w, o, d, h);
        }
    }
    w.count.x++;
}

// Spectral MIS over the whole path. A path samples its free flights with the extinction of
// one hero channel, drawn uniformly at its start; it could have been drawn with any of the
// three, so its flux in channel c is f_c / mean_k(P_k), P_k the path's pdf under channel k's
// sampling (the balance heuristic, one sample): at most 3 albedo_c^events times f_c / P_c.
// w.mis keeps s_k = P_k / mean(P), and a step whose factor is a_c in f_c and b_k in P_k takes
// the flux by a / mean(s b) and s to s b / mean(s b). Taking the mixture's pdf at every event
// instead (as free_flight does) lets a channel whose extinction differs from the others'
// gain up to 3x per event, and its flux grow without bound over a long walk: the bumpy
// sphere's red walks made a seed-to-seed spread of 16% in its multiple scattering (6% with
// this; docs/scattering.md, *Spectral MIS in the walks*).
bool mis_step(inout GpuVrlWalk w, vec3 a, vec3 b)
{
    float m = dot(w.mis.xyz * b, vec3(1.0 / 3.0));
    if (!(m > 0.0))
        return false;
    w.flux.xyz *= a / m;
    w.mis.xyz *= b / m;
    return true;
}

// false: the path is over.
bool walk_step(inout GpuVrlWalk w)
{
    out_of_budget();
    vec3 o = w.origin.xyz, d = w.direction.xyz;
    Hit h;
    if (!trace_scene(o, d, 0.0, NS_INF, h))
        return false; // an open boundary: nothing ahead to stop the stretch
    store_vrl(w, o, d, h);

    GpuMaterial mm = materials[w.state.z];
    vec3 st = mm.sigma_t.xyz;
    float st_hero = st[min(w.count.w, 2u)];
    float t = st_hero > 0.0 ? -log(1.0 - rnd()) / st_hero : NS_INF;
    if (t < h.t) {
        // f: sigma_s e^{-sigma_t t}; P: sigma_t e^{-sigma_t t}.
        vec3 tr = exp(-st * t);
        if (!mis_step(w, mm.sigma_s.xyz * tr, st * tr))
            return false;
        w.state.y++;
        w.count.z = 0u;
        if (w.state.y > NS_VRL_ROULETTE_AFTER) {
            float q = min(1.0, max(w.flux.x, max(w.flux.y, w.flux.z)) / w.origin.w);
            if (!(q > 0.0) || rnd() >= q)
                return false;
            w.flux.xyz /= q;
        }
        if (!(max(w.flux.x, max(w.flux.y, w.flux.z)) > 0.0))
            return false;
        w.origin.xyz = o + t * d;
        w.direction.xyz = hg_sample(d, mm.sigma_s.w);
        return true;
    }
    // Past the boundary: f and P both take e^{-sigma_t len}.
    vec3 tr = exp(-st * h.t);
    if (!mis_step(w, tr, tr))
        return false;
    if (++w.count.z > NS_VRL_MAX_BOUNDARY_RUN) {
        atomicAdd(counters[NS_VRL_TRACE_TRUNCATED], 1u);
        return false;
    }
    vec3 p = o + h.t * d;
    float eps = ray_epsilon(p);
    uint m = prim_at(h.prim).info.y;
    if (h.front && m == w.state.z) {
        w.origin.xyz = p + d * eps; // grazing its own boundary within float error
        return true;
    }
    if (m != w.state.z)
        return false; // another object inside the medium: not modelled (docs)
    float ior = mm.sigma_t.w;
    vec3 n = -h.normal; // inside: faces the incoming ray
    vec3 leaving = d;
    if (ior != 1.0) {
        float cos_i = -dot(d, n), cos_t;
        float f = fresnel(cos_i, ior, cos_t);
        if (!(f < 1.0) || rnd() < f) {
            w.origin.xyz = p + n * eps;
            w.direction.xyz = normalize(reflect(d, n));
            return true;
        }
        leaving = refract_direction(d, n, ior, cos_i, cos_t);
    }
    // It leaves the medium. Where a non-convex object, or another one, lies ahead, the
    // light enters again and the walk goes on there: a stretch that starts away from where
    // the one before it ended (boundary.c: a positive source). Light that has not scattered
    // yet is left out: the VRLs (vrl.comp) do not follow it either, and boundary.c could not
    // tell its stretch from a path's first.
    if (w.state.y == 0u)
        return false;
    return enter_object(w, p - n * eps, leaving, w.flux.xyz, NS_NONE, w.state.y, w.origin.w);
}

void main()
{
    uint path = gl_GlobalInvocationID.x;
    if (path >= push.path_count || push.emitter_count == 0u)
        return;
    GpuVrlWalk w = walks[path];
    if (w.state.w == NS_VRL_WALK_DONE)
        return;
    if (w.state.w == NS_VRL_WALK_FRESH) {
        rng_state = pcg_hash(pcg_hash(push.seed ^ 0x5bd1e995u) + path);
        w.count.w = min(uint(rnd() * 3.0), 2u); // the hero channel
        w.mis = vec4(1.0, 1.0, 1.0, 0.0);
        vec3 o, d, flux;
        uint target_object, kind;
        emit(path, o, d, flux, target_object, kind);
        w.mis.w = kind == NS_GPU_LIGHT_ENVIRONMENT ? 1.0 : 0.0;
        w.state.w = enter_object(w, o, d, flux, target_object, 0u, 0.0) ? NS_VRL_WALK_INSIDE
                                                                       : NS_VRL_WALK_DONE;
    } else {
        rng_state = w.state.x;
    }
    while (w.state.w == NS_VRL_WALK_INSIDE) {
        if (!walk_step(w))
            w.state.w = NS_VRL_WALK_DONE;
        if (push.yield_after != 0u && loop_count >= push.yield_after)
            break;
    }
    w.state.x = rng_state;
    walks[path] = w;
    if (push.report != 0u && w.state.w != NS_VRL_WALK_DONE)
        atomicAdd(counters[NS_VRL_TRACE_ACTIVE], 1u);
    // Counted past the scene's budget (traversals were cut short), or cut by lavapipe
    // itself: a loop with a bound the compiler cannot unroll that runs fewer than its
    // iterations proves it (as in pt.comp).
    uint probe_end = min(push.path_count, 64u), probe = 0u;
    for (uint k = 0u; k <= probe_end; k++)
        probe++;
    if ((params.limits.x != 0u && loop_count > params.limits.x) || probe != probe_end + 1u)
        atomicAdd(counters[NS_VRL_TRACE_LOOP_LIMIT], 1u);
}
