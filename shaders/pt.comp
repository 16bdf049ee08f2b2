#version 450
// pt.comp — the reference volumetric path tracer (render.method "pt"), one invocation per
// pixel. Each pixel runs its spp samples one after the other; a dispatch stops after a
// budget of loop iterations (lavapipe's limit, docs/rendering.md) with the path's state
// saved in the path buffer, and the next dispatch resumes it (render/pt.c repeats them
// until every pixel is done), so a path may take any number of scattering events.
//
// Light transport is the scene model every method shares (docs/rendering.md): diffuse
// surfaces take direct light from every light and end the path (no interreflection), and
// light they reflect does not enter media (a path that scattered and then meets one ends);
// shadow rays pass index-matched boundaries with their Beer-Lambert factor and stop at
// refracting ones. On top of that, and unlike the camera pass, light scatters inside media:
//   - free-flight distances with one channel picked uniformly and the one-sample balance
//     heuristic over the three channels' pdfs (spectral MIS), so per-channel extinction
//     costs no bias;
//   - Henyey-Greenstein phase sampling; next-event estimation to point, directional and
//     sphere lights from every scattering event (zero where a refracting boundary is in the
//     way: there sphere lights and the environment are reached by the phase-sampled
//     continuation, and point/directional lights by a specular connection through the
//     boundary for the single order and by light sub-paths connected to the camera
//     stretches for orders 2 and up: docs/reference.md);
//   - smooth dielectric boundaries chosen stochastically (reflect with probability F,
//     total internal reflection always reflects), weight unchanged;
//   - Russian roulette on the throughput after the third scattering event.
// Every contribution knows how many scattering events its path had and counts only when
// that order was asked for (push.components), exactly as the tables count them.
#extension GL_GOOGLE_include_directive : require
#include "shared.h"
#include "pt_shared.h"
// One loop of nodes and leaves: the traversal pt's yield budget was measured on (trace.glsl).
#define NS_TRACE_ONE_LOOP
#include "trace.glsl"

layout(local_size_x = NS_CAMERA_GROUP_X, local_size_y = NS_CAMERA_GROUP_Y) in;

layout(std430, binding = 3) readonly buffer MaterialBlock { GpuMaterial materials[]; };
layout(std430, binding = 4) readonly buffer LightBlock { GpuLight lights[]; };
layout(std430, binding = 5) buffer ImageBlock { vec4 pixels[]; };
layout(std430, binding = 6) buffer CounterBlock { uint counters[]; };
layout(std430, binding = 7) buffer PathBlock { GpuPtPath paths[]; };
layout(push_constant) uniform PushBlock { GpuPtPush ns_push[1]; };
#define push ns_push[NS_OPAQUE_ZERO] /* shared.h: NS_OPAQUE_ZERO */

#define NS_COMMON_TRACE
#define NS_COMMON_LIGHTS
#include "common.glsl"

// How this pass traces its shadow rays (common.glsl, transmittance).
const uint SHADOW_RAYS = 0u;

bool order_counts(uint events)
{
    uint bit = events == 0u ? NS_PT_SURFACE
             : events == 1u ? NS_PT_SINGLE
             : events == 2u ? NS_PT_DOUBLE : NS_PT_MULTIPLE;
    return (push.components & bit) != 0u && events <= push.max_events;
}

// Next-event estimation at a scattering event at p inside `medium` (d = the direction the
// path arrived in): point, directional and sphere lights. The environment is left to the
// phase-sampled continuation, which reaches it with weight 1.
vec3 direct_light_medium(vec3 p, vec3 d, float g, uint medium)
{
    vec3 sum = vec3(0.0);
    for (uint i = 0u; i < params.counts.y; i++) {
        if (out_of_budget())
            break;
        vec3 wi, weight;
        float t_light;
        if (phase_light(lights[i], p, d, g, wi, t_light, weight))
            sum += weight * transmittance(p, wi, t_light, medium, SHADOW_RAYS);
    }
    return sum;
}

// ---------------------------------------------------------------------------------------
// Single scattering of a point or directional light behind a refracting boundary: manifold
// next-event estimation (Hanika et al. 2015) for one refraction. The light reaches x only
// along the direction v whose refraction where it leaves the medium points exactly at the
// light: a specular connection that sampling never hits. Newton's method finds v, starting
// from the light's refraction at the face the straight line to it meets, on the residual
// of the refracted ray at the light (its miss distance for a point light, its deviation
// from the light's direction for a directional one) with central differences for the
// 2 x 2 Jacobian J. The same J gives the energy:
// light leaving a point light into solid angle dw lands on |det J| dw of area across the
// ray at x (|det J| of deviation per dw for a directional light), so the irradiance at x is
// T I / |det J| (T E / |det J|) times the n^2 of the radiance theorem, which the camera
// path's leaving refraction takes back (the radiance convention, docs/reference.md).
// Only the solution Newton reaches from that seed counts; where two refracted rays
// cross at x (a caustic of a curved boundary) or the path needs a second specular event,
// the light is missed (docs/reference.md). Used at the camera path's first event only:
// every path with more events has a light sub-path strategy.
// ---------------------------------------------------------------------------------------
const int NS_PT_MNEE_ITERATIONS = 10;
const float NS_PT_MNEE_STEP = 1e-3; // radians, for the central differences

// Where the ray from x inside `medium` along v leaves it: the point y, the outward normal
// there, the refracted direction o and the Fresnel transmittance. False when anything else
// comes first or the ray is totally reflected.
bool leave_medium(vec3 x, vec3 v, uint medium, out vec3 y, out vec3 n, out vec3 o, out float transmit)
{
    Hit h;
    y = x;
    n = v;
    o = v;
    transmit = 0.0;
    if (!trace_scene(x, v, 0.0, NS_INF, h) || h.front || prim_at(h.prim).info.y != medium)
        return false;
    float ior = materials[medium].sigma_t.w;
    y = x + h.t * v;
    n = h.normal;
    float cos_i = dot(v, n), cos_t;
    float f = fresnel(cos_i, ior, cos_t);
    if (!(cos_i > 0.0) || f >= 1.0)
        return false;
    o = normalize(ior * v + (cos_t - ior * cos_i) * n);
    transmit = 1.0 - f;
    return true;
}

// The miss at the light of the refracted ray (y, o), in the basis (b1, b2) across it.
bool miss_at_light(vec3 y, vec3 o, GpuLight light, vec3 b1, vec3 b2, out vec2 miss)
{
    if (light.info.x == NS_GPU_LIGHT_POINT) {
        vec3 to_light = light.position.xyz - y;
        float along = dot(to_light, o);
        vec3 off = to_light - along * o;
        miss = vec2(dot(off, b1), dot(off, b2));
        return along > 0.0;
    }
    miss = vec2(dot(o, b1), dot(o, b2));
    return dot(o, light.direction.xyz) < 0.0;
}

// The same for the ray from x along v, refracted where it leaves the medium.
bool light_miss(vec3 x, vec3 v, uint medium, GpuLight light, vec3 b1, vec3 b2, out vec2 miss)
{
    vec3 y, n, o;
    float transmit;
    miss = vec2(0.0);
    return leave_medium(x, v, medium, y, n, o, transmit) && miss_at_light(y, o, light, b1, b2, miss);
}

vec3 specular_light(vec3 x, vec3 d, float g, uint medium, GpuLight light)
{
    bool point = light.info.x == NS_GPU_LIGHT_POINT;
    vec3 v = point ? normalize(light.position.xyz - x) : -light.direction.xyz;
    // Seed: the light's own refraction at the face the straight line meets (the straight
    // line itself may lie beyond the critical angle).
    Hit h;
    if (trace_scene(x, v, 0.0, NS_INF, h) && !h.front && prim_at(h.prim).info.y == medium) {
        vec3 travel = point ? normalize(x + h.t * v - light.position.xyz) : light.direction.xyz;
        float cos_i = -dot(travel, h.normal), cos_t, ior = materials[medium].sigma_t.w;
        if (cos_i > 0.0 && fresnel(cos_i, 1.0 / ior, cos_t) < 1.0)
            v = -normalize(travel / ior + (cos_i / ior - cos_t) * h.normal);
    }
    // Where v leaves the medium; each step below finds it for the next v as it tries it.
    vec3 y, n, o;
    float transmit;
    if (!leave_medium(x, v, medium, y, n, o, transmit))
        return vec3(0.0);
    for (int it = 0; it < NS_PT_MNEE_ITERATIONS; it++) {
        vec3 t1, t2, b1, b2;
        basis(v, t1, t2);
        basis(point ? o : -light.direction.xyz, b1, b2);
        vec2 miss;
        const float h = NS_PT_MNEE_STEP;
        if (!miss_at_light(y, o, light, b1, b2, miss))
            return vec3(0.0);
        // The four central differences v + h t1, v - h t1, v + h t2, v - h t2 in a loop, not
        // four calls: lavapipe inlines every call, each another copy of the traversal.
        vec2 probe[4];
        for (int q = 0; q < 4; q++) {
            vec3 offset = (q < 2 ? t1 : t2) * ((q & 1) == 0 ? h : -h);
            if (!light_miss(x, normalize(v + offset), medium, light, b1, b2, probe[q]))
                return vec3(0.0);
        }
        mat2 jacobian =
            mat2((probe[0] - probe[1]) / (2.0 * h), (probe[2] - probe[3]) / (2.0 * h));
        float det = determinant(jacobian);
        if (!(abs(det) > 0.0))
            return vec3(0.0);
        float light_distance = point ? distance(light.position.xyz, y) : NS_INF;
        float tolerance = point ? 1e-5 * (light_distance + distance(x, y)) : 1e-5;
        if (length(miss) <= tolerance) {
            vec3 visible =
                transmittance(y + n * ray_epsilon(y), o, light_distance, NS_NONE, SHADOW_RAYS);
            return light.color.rgb * (hg_phase(dot(d, v), g) * transmit / abs(det)) *
                   beer_lambert(sigma_t_of(medium), distance(x, y)) * visible;
        }
        vec2 step = -(inverse(jacobian) * miss);
        float len = length(step);
        if (len > 0.25)
            step *= 0.25 / len;
        // Halve the step while it lands where the ray cannot leave (another face beyond
        // the critical angle, another object).
        bool moved = false;
        for (int k = 0; k < 6 && !moved; k++, step *= 0.5) {
            vec3 candidate = normalize(v + step.x * t1 + step.y * t2);
            if (leave_medium(x, candidate, medium, y, n, o, transmit)) {
                v = candidate;
                moved = true;
            }
        }
        if (!moved)
            return vec3(0.0);
    }
    return vec3(0.0);
}

// Every point and directional light's specular connection to x (single scattering).
vec3 specular_light_medium(vec3 x, vec3 d, float g, uint medium)
{
    vec3 sum = vec3(0.0);
    for (uint i = 0u; i < params.counts.y; i++) {
        out_of_budget();
        GpuLight light = lights[i];
        if (light.info.x == NS_GPU_LIGHT_POINT || light.info.x == NS_GPU_LIGHT_DIRECTIONAL)
            sum += specular_light(x, d, g, medium, light);
    }
    return sum;
}

// ---------------------------------------------------------------------------------------
// Light sub-paths: point and directional light reaching a medium through a refracting
// boundary. Next-event estimation cannot sample such light (the refracted path is a
// specular chain) and a camera path never hits a delta light, so each camera sample traces
// one light sub-path from a delta light into the medium, and every camera stretch inside a
// medium connects to one of its scattering events z through a point on the stretch chosen
// by equiangular sampling (Kulla & Fajardo 2012).
//
// Which events may connect, so that each full path of n >= 2 events is made exactly once:
// number its events v_1 (the light's first) ... v_n, and let v_j be the first whose edge to
// v_{j+1} is a straight line (no boundary event between them); the connection (straight)
// makes that edge, the light sub-path everything before it, the camera path everything
// after. So the light sub-path's first event may connect when the light refracted on its way
// to it (a straight light-to-z line is next-event estimation's case), and each later one
// when the light met the boundary (an internal reflection) since the event before, the walk
// stopping at the first event reached in a straight line. Before this rule only the first
// event connected, and a path whose light reflected off the boundary between its first two
// events was made by no strategy: on an index-1.3 sphere of albedo 0.999 under a point light,
// multiple scattering came out 0.80 of the same power from a sphere light of radius 0.3
// (now 1.006: gpu_pt_consistency). A path none of whose edges is straight is still made by
// none (double scattering whose light reflects between its two events: 0.93 there;
// docs/reference.md), nor one whose first straight edge comes after the light's
// NS_PT_LIGHT_VERTICES-th event (four reflected edges in a row). Up to NS_PT_LIGHT_VERTICES
// events may connect; the sample takes one of them uniformly (reservoir sampling as the walk
// goes) and weighs it by their number.
// ---------------------------------------------------------------------------------------
const uint NS_PT_LIGHT_VERTICES = 4u;

struct LightVertex {
    vec3 z;      // position of the scattering event
    vec3 beta;   // flux-like throughput (emission / pdfs, Fresnel choices, free flight)
    vec3 dir;    // the direction light travelled to reach z
    uint events; // scattering events of the light sub-path up to z, z's included
    bool valid;
};

LightVertex trace_light_subpath()
{
    LightVertex lv;
    lv.z = vec3(0.0);
    lv.beta = vec3(0.0);
    lv.dir = vec3(0.0, 0.0, 1.0);
    lv.events = 0u;
    lv.valid = false;
    uint count = push.delta_lights;
    if (count == 0u)
        return lv;
    uint pick = min(uint(rnd() * float(count)), count - 1u);
    uint index = NS_NONE;
    for (uint i = 0u, seen = 0u; i < params.counts.y; i++) {
        out_of_budget();
        uint kind = lights[i].info.x;
        if (kind == NS_GPU_LIGHT_DIRECTIONAL || kind == NS_GPU_LIGHT_POINT) {
            if (seen == pick)
                index = i;
            seen++;
        }
    }
    if (index == NS_NONE)
        return lv;
    GpuLight light = lights[index];
    vec3 c = push.target.xyz;
    float r = push.target.w;
    vec3 o, d, beta;
    if (light.info.x == NS_GPU_LIGHT_DIRECTIONAL) {
        // A point on the disk facing the light that covers the target sphere, just
        // outside it; the light must reach that point from infinity.
        d = light.direction.xyz;
        o = disk_before_sphere(c, r, d);
        beta = light.color.rgb * (PI * r * r) * transmittance(o, -d, NS_INF, NS_NONE, SHADOW_RAYS);
    } else {
        o = light.position.xyz;
        vec3 v = c - o;
        float dist2 = dot(v, v);
        float cos_max = cone_cos(o, c, r);
        d = around(dist2 > 0.0 ? normalize(v) : vec3(0.0, 0.0, 1.0), 1.0 - rnd() * (1.0 - cos_max),
                   2.0 * PI * rnd());
        beta = light.color.rgb * (2.0 * PI * (1.0 - cos_max));
    }
    beta *= float(count);
    if (!(max(beta.x, max(beta.y, beta.z)) > 0.0))
        return lv;
    uint medium = NS_NONE;
    bool entered = false;   // refracted into a scattering medium straight from the light
    bool reflected = false; // an internal reflection since the last scattering event
    uint events = 0u, eligible = 0u;
    // Boundary events since the last scattering event (or the light), as the camera path's
    // boundary_run: the walk ends at most NS_PT_LIGHT_VERTICES events in, each stretch
    // between two within the cap.
    uint run = 0u;
    bool truncated = false;
    while (true) {
        if (run++ > NS_PT_MAX_LIGHT_BOUNDARIES) {
            truncated = true;
            break;
        }
        Hit h;
        bool hit = trace_scene(o, d, 0.0, NS_INF, h);
        if (medium != NS_NONE) {
            GpuMaterial mm = materials[medium];
            vec3 st = mm.sigma_t.xyz;
            float t = free_flight(st);
            float t_end = hit ? h.t : NS_INF;
            if (t < t_end) {
                vec3 tr = exp(-st * t);
                beta *= tr * mm.sigma_s.xyz / dot(st * tr, vec3(1.0 / 3.0));
                events++;
                bool may_connect = events == 1u ? entered : reflected;
                if (!may_connect || !(max(beta.x, max(beta.y, beta.z)) > 0.0))
                    break;
                eligible++;
                if (eligible == 1u || rnd() * float(eligible) < 1.0) {
                    lv.z = o + t * d;
                    lv.dir = d;
                    lv.beta = beta;
                    lv.events = events;
                    lv.valid = true;
                }
                if (events == NS_PT_LIGHT_VERTICES)
                    break;
                o = o + t * d;
                d = hg_sample(d, mm.sigma_s.w);
                reflected = false;
                run = 0u;
                continue;
            }
            if (!hit)
                break;
            vec3 tr = beer_lambert(st, t_end);
            float survive = dot(tr, vec3(1.0 / 3.0));
            if (!(survive > 0.0))
                break;
            beta *= tr / survive;
        }
        if (!hit)
            break;
        uint m = prim_at(h.prim).info.y;
        GpuMaterial mat = materials[m];
        if (mat.reflectance.w == 0.0)
            break; // diffuse: light that reaches it is the surface estimators' business
        vec3 p = o + h.t * d;
        vec3 n = h.front ? h.normal : -h.normal;
        float eps = ray_epsilon(p);
        if (spurious_boundary(h.front, m, medium)) {
            o = p + d * eps;
            continue;
        }
        uint next_medium = h.front ? m : NS_NONE;
        float ior = mat.sigma_t.w;
        if (ior == 1.0) {
            if (events > 0u)
                break; // leaves (or meets another object inside): the walk ends
            o = p - n * eps;
            medium = next_medium;
            continue;
        }
        // Only light that refracts straight from the light into a scattering medium, then
        // stays in it (internal reflections), is followed: the other methods' model
        // follows no caustics through other objects, and light reflected off the outside
        // or leaving again reaches no light vertex this strategy may use.
        if (h.front && (entered || mat.sigma_s.x + mat.sigma_s.y + mat.sigma_s.z <= 0.0))
            break;
        float eta = h.front ? 1.0 / ior : ior;
        float cos_i = -dot(d, n);
        float cos_t;
        float f = fresnel(cos_i, eta, cos_t);
        bool reflects = f >= 1.0 || rnd() < f;
        if (h.front && !reflects) { // refracted in
            o = p - n * eps;
            d = refract_direction(d, n, eta, cos_i, cos_t);
            medium = m;
            entered = true;
        } else if (!h.front && reflects) { // reflected back in from the inside
            o = p + n * eps;
            d = normalize(reflect(d, n));
            reflected = true;
        } else {
            break; // reflected off the outside, or refracted out
        }
    }
    if (truncated)
        atomicAdd(counters[NS_PT_COUNTER_LIGHT_TRUNCATED], 1u);
    lv.beta *= float(eligible); // one of `eligible` events, each taken with 1 / eligible
    return lv;
}

// The connection of the camera stretch from o along d (length t_end, inside `medium`,
// throughput w before it) with the light vertex: a point x on the stretch sampled
// equiangularly towards z, scattered towards z, z scattered along the stretch's reverse.
vec3 connect_light_vertex(vec3 o, vec3 d, float t_end, vec3 w, uint medium, vec3 z, vec3 beta,
                          vec3 light_dir)
{
    float delta = dot(z - o, d);
    float dperp = length(z - (o + delta * d));
    if (!(dperp > 1e-7) || !(t_end < NS_INF))
        return vec3(0.0);
    float theta_a = atan(-delta, dperp), theta_b = atan(t_end - delta, dperp);
    float t = delta + dperp * tan(mix(theta_a, theta_b, rnd()));
    t = clamp(t, 0.0, t_end);
    float h = t - delta;
    float pdf = dperp / ((theta_b - theta_a) * (dperp * dperp + h * h));
    vec3 x = o + t * d;
    vec3 to_z = z - x;
    float dist2 = dot(to_z, to_z);
    float dist = sqrt(dist2);
    vec3 wi = to_z / dist;
    GpuMaterial mm = materials[medium];
    float g = mm.sigma_s.w;
    vec3 f = w * exp(-mm.sigma_t.xyz * t) * mm.sigma_s.xyz * hg_phase(dot(d, wi), g) *
             hg_phase(dot(light_dir, -wi), g) / dist2 *
                 transmittance(x, wi, dist, medium, SHADOW_RAYS);
    // beta is flux inside the medium, so f * beta is radiance inside it; leaving a medium
    // of index n into vacuum divides radiance by n^2. Camera paths that enter and leave
    // again see both factors cancel and carry neither; this connection has only the exit.
    float ior = mm.sigma_t.w;
    return f * beta / (pdf * ior * ior);
}

// ---------------------------------------------------------------------------------------
// One path, one step at a time, so that it can be suspended between dispatches.
// ---------------------------------------------------------------------------------------
struct PathState {
    vec3 o;
    vec3 d;
    vec3 w;            // throughput
    vec3 radiance;     // gathered so far by this sample
    vec3 last_event;   // position of the last scattering event
    uint medium;       // material index, NS_NONE outside every medium
    uint events;       // scattering events so far
    uint boundary_run; // boundary events since the last scattering event
    // The last scattering event's next-event estimate already covers a sphere light this
    // path hits in a straight line (index-matched crossings only), unless that event lay
    // inside the light's sphere, where it cannot be sampled: do not count it twice.
    bool nee_covered;
    LightVertex light; // this sample's light sub-path vertex
};

// Advances the path by one straight stretch and what ends it. false: the path is over.
bool path_step(inout PathState s)
{
    out_of_budget(); // counts the step (pt yields between steps, never inside one)
    Hit h;
    bool any = trace_scene(s.o, s.d, 0.0, NS_INF, h);
    uint light_index;
    float t_light = hit_sphere_lights(s.o, s.d, any ? h.t : NS_INF, light_index);
    bool at_light = light_index != NS_NONE;
    float t_end = at_light ? t_light : (any ? h.t : NS_INF);

    if (s.medium != NS_NONE) {
        // Light sub-path connection: a point on this stretch becomes camera event
        // events + 1, so the path has events + 1 + (the light sub-path's) events.
        if (s.light.valid && order_counts(s.events + 1u + s.light.events))
            s.radiance += connect_light_vertex(s.o, s.d, t_end, s.w, s.medium, s.light.z,
                                               s.light.beta, s.light.dir);
        GpuMaterial mm = materials[s.medium];
        vec3 st = mm.sigma_t.xyz;
        float t = free_flight(st);
        if (t < t_end) {
            // A scattering event: weight = transmittance * sigma_s / (mean of the three
            // channels' distance pdfs).
            vec3 tr = exp(-st * t);
            float pdf = dot(st * tr, vec3(1.0 / 3.0));
            s.w *= tr * mm.sigma_s.xyz / pdf;
            if (!(max(s.w.x, max(s.w.y, s.w.z)) > 0.0))
                return false; // absorbed in every channel
            s.o += t * s.d;
            if (s.events + 1u > push.max_events)
                return false;
            s.events++;
            s.boundary_run = 0u;
            if (s.events > 3u) {
                float q = min(1.0, max(s.w.x, max(s.w.y, s.w.z)));
                if (!(q > 0.0) || rnd() >= q)
                    return false;
                s.w /= q;
            }
            float g = mm.sigma_s.w;
            if (order_counts(s.events))
                s.radiance += s.w * direct_light_medium(s.o, s.d, g, s.medium);
            if (s.events == 1u && order_counts(1u) && mm.sigma_t.w != 1.0)
                s.radiance += s.w * specular_light_medium(s.o, s.d, g, s.medium);
            s.d = hg_sample(s.d, g);
            s.nee_covered = true;
            s.last_event = s.o;
            return true;
        }
        if (t_end == NS_INF)
            return false; // inside a medium with nothing ahead: cannot happen for closed shapes
        vec3 tr = beer_lambert(st, t_end);
        float survive = dot(tr, vec3(1.0 / 3.0));
        if (!(survive > 0.0))
            return false;
        s.w *= tr / survive;
    }

    if (at_light) {
        vec4 ball = lights[light_index].position;
        vec3 to_light = s.last_event - ball.xyz;
        bool covered = s.nee_covered && dot(to_light, to_light) > ball.w * ball.w;
        if (!covered && order_counts(s.events))
            s.radiance += s.w * lights[light_index].color.rgb;
        return false;
    }
    if (!any) {
        if (order_counts(s.events))
            s.radiance += s.w * params.environment.rgb;
        return false;
    }
    vec3 p = s.o + h.t * s.d;
    uint m = prim_at(h.prim).info.y;
    GpuMaterial mat = materials[m];
    vec3 n = h.front ? h.normal : -h.normal; // faces the incoming ray
    if (mat.reflectance.w == 0.0) {
        // Only the camera sees diffuse surfaces lit: light they reflect into a medium is
        // outside the shared model (the VRLs, the tables and the camera pass all start
        // from the lights themselves), so a path that scattered first ends here dark.
        if (s.events == 0u && order_counts(0u))
            s.radiance +=
                s.w * lambert_direct(p, n, mat.reflectance.rgb, s.medium, SHADOW_RAYS,
                                     DIRECT_FROM_STREAM);
        return false;
    }
    if (++s.boundary_run > NS_PT_MAX_BOUNDARY_RUN) {
        atomicAdd(counters[NS_PT_COUNTER_TRUNCATED], 1u);
        return false;
    }
    float eps = ray_epsilon(p);
    if (spurious_boundary(h.front, m, s.medium)) {
        s.o = p + s.d * eps;
        return true;
    }
    uint next_medium = h.front ? m : NS_NONE;
    float ior = mat.sigma_t.w;
    if (ior == 1.0) {
        s.o = p - n * eps;
        s.medium = next_medium;
        return true;
    }
    float eta = h.front ? 1.0 / ior : ior;
    float cos_i = -dot(s.d, n);
    float cos_t;
    float f = fresnel(cos_i, eta, cos_t);
    if (f >= 1.0 || rnd() < f) {
        s.o = p + n * eps;
        s.d = normalize(reflect(s.d, n));
    } else {
        s.o = p - n * eps;
        s.d = refract_direction(s.d, n, eta, cos_i, cos_t);
        s.medium = next_medium;
    }
    s.nee_covered = false;
    return true;
}

PathState start_sample(uvec2 xy, uint pixel_seed, uint sample_index)
{
    rng_state = pcg_hash(pixel_seed + sample_index);
    float u = (float(xy.x) + rnd()) / float(params.image.x);
    float v = (float(xy.y) + rnd()) / float(params.image.y);
    vec3 d = params.cam_forward.xyz + params.cam_right.xyz * ((2.0 * u - 1.0) * params.cam_position.w) +
             params.cam_up.xyz * ((1.0 - 2.0 * v) * params.cam_right.w);
    PathState s;
    s.o = params.cam_position.xyz;
    s.d = normalize(d);
    s.w = vec3(1.0);
    s.radiance = vec3(0.0);
    s.last_event = vec3(0.0);
    s.medium = NS_NONE;
    s.events = 0u;
    s.boundary_run = 0u;
    s.nee_covered = false;
    s.light = trace_light_subpath();
    return s;
}

void main()
{
    uint width = params.image.x, height = params.image.y;
    uvec2 xy = gl_GlobalInvocationID.xy;
    if (xy.x >= width || xy.y >= height)
        return;
    uint pixel = xy.y * width + xy.x;
    // A different stream from the camera pass's for the same seed.
    uint pixel_seed = pcg_hash(pcg_hash(params.image.w ^ 0x7f4a7c15u) + pixel);
    uint spp = params.image.z;

    // Resume where the previous dispatch stopped (the buffer starts zeroed: no path
    // active, sample 0 next).
    GpuPtPath saved = paths[pixel];
    PathState s;
    s.o = saved.origin.xyz;
    s.d = saved.direction.xyz;
    s.w = saved.weight.xyz;
    s.radiance = saved.radiance.xyz;
    s.last_event = saved.last_event.xyz;
    s.medium = saved.state.x;
    s.events = saved.state.y;
    s.boundary_run = saved.state.z;
    s.nee_covered = saved.state.w != 0u;
    s.light.z = saved.light_vertex.xyz;
    s.light.valid = saved.light_vertex.w != 0.0;
    s.light.beta = saved.light_weight.xyz;
    s.light.dir = saved.light_dir.xyz;
    s.light.events = uint(saved.light_dir.w);
    rng_state = saved.progress.x;
    uint next_sample = saved.progress.y;
    bool path_active = saved.progress.z != 0u;
    vec3 finished = vec3(0.0);

    while (true) {
        if (!path_active) {
            if (next_sample >= spp)
                break;
            s = start_sample(xy, pixel_seed, next_sample);
            next_sample++;
            path_active = true;
        }
        if (!path_step(s)) {
            path_active = false;
            // A NaN or Inf sample would poison the pixel for good: it is dropped and
            // counted, and the render fails rather than hide it.
            if (any(isnan(s.radiance)) || any(isinf(s.radiance)))
                atomicAdd(counters[NS_PT_COUNTER_NONFINITE], 1u);
            else
                finished += s.radiance;
        }
        if (loop_count >= push.yield_after)
            break;
    }

    saved.origin.xyz = s.o;
    saved.direction.xyz = s.d;
    saved.weight.xyz = s.w;
    saved.radiance.xyz = s.radiance;
    saved.last_event.xyz = s.last_event;
    saved.state = uvec4(s.medium, s.events, s.boundary_run, s.nee_covered ? 1u : 0u);
    saved.progress = uvec4(rng_state, next_sample, path_active ? 1u : 0u, 0u);
    saved.light_vertex = vec4(s.light.z, s.light.valid ? 1.0 : 0.0);
    saved.light_weight = vec4(s.light.beta, 0.0);
    saved.light_dir = vec4(s.light.dir, float(s.light.events));
    paths[pixel] = saved;
    if (finished != vec3(0.0))
        pixels[pixel] += vec4(finished / float(spp), 0.0);
    if (push.report != 0u && (path_active || next_sample < spp))
        atomicAdd(counters[NS_PT_COUNTER_UNFINISHED], 1u);

    // lavapipe's limit is counted over every loop an invocation (its SIMD group, in fact)
    // runs, uncounted ones too (the leaf and light loops), and once spent it makes every
    // later loop exit at once. So a loop that must run spp + 1 times (a bound the compiler
    // cannot unroll) and runs fewer proves the steps above were cut short.
    uint probe = 0u;
    for (uint k = 0u; k <= spp; k++)
        probe++;
    if (probe != spp + 1u)
        atomicAdd(counters[NS_COUNTER_LOOP_LIMIT], 1u);
}
