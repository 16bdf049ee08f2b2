// single.glsl — the body of single.comp and single_box_faces.comp (NS_SINGLE_BOX_FACES 0 and
// 1: the faces of a refracting box taken one by one, light_through_box_face). Single
// scattering along camera segments (paper Section 4.1, step 3): one invocation per segment
// takes the samples [first_sample, first_sample + sample_count) of
// its strata (at most `samples`, fewer for a segment of low throughput: segment_strata),
// each a point drawn along the segment (distance_sample), connects it to the lights and adds
//     e^{-sigma_t t} sigma_s p_HG(cos) L_in(x) / (strata pdf(t))
// to the segment's output: the radiance arriving at the segment's entry from inside the
// medium (render/scatter.h). main() says how the environment and the other lights share
// the strata. The C side (render/single.c) splits the samples across
// dispatches so that no invocation runs past lavapipe's loop limit (shared.h).
//
// Light reaching a point x inside the medium:
//   ior 1 (index matched): a shadow ray through the scene with Beer-Lambert (as camera.comp).
//   ior != 1: Jensen et al. 2001. The boundary point b on the straight line from x to the
//     light is treated as a locally planar interface: the light is refracted there (nothing
//     on total internal reflection), Fresnel-transmitted (1 - F), its irradiance carried
//     into the medium as E_perp (1 - F) cos_i / cos_t (flux through the plane is kept), and
//     attenuated along the refracted direction over the exact distance from x to that plane.
//     Outside, a shadow ray from b to the light. Point and sphere lights are refracted
//     exactly through that plane instead (point_refracted: the refraction point and the
//     pencil's divergence inside), which is exact on flat faces. In a box (single_box_faces
//     .comp) through each face that sees the light, where the refraction point lies on it.
//   Environment: one in-medium direction per sample, drawn from the phase function; through
//     a refracting boundary the ray back along it is followed through the boundary's
//     internal reflections until it leaves, bringing n^2 L_env (environment_along).
//
// Bindings: the five scene buffers (render/internal.h), then segments, output, counters.
#ifndef NS_SINGLE_BOX_FACES
#define NS_SINGLE_BOX_FACES 0
#endif
#extension GL_GOOGLE_include_directive : require
#include "shared.h"
#include "trace.glsl"

layout(local_size_x = 64) in;
#include "groups.glsl"

layout(std430, binding = 3) readonly buffer MaterialBlock { GpuMaterial materials[]; };
layout(std430, binding = 4) readonly buffer LightBlock { GpuLight lights[]; };
layout(std430, binding = 5) readonly buffer SegmentBlock { GpuSegment segments[]; };
layout(std430, binding = 6) buffer OutBlock { vec4 radiance[]; };
// counters[0]: invocations whose loops were cut short (lavapipe's limit or the scene's loop
// budget); counters[1]: the most loop iterations one invocation counted (out_of_budget) in
// one dispatch, which render/single.c uses to size the next dispatches.
layout(std430, binding = 7) buffer CounterBlock { uint counters[]; };
// GpuSinglePush (shared.h): which samples this dispatch takes.
layout(push_constant) uniform PushBlock { GpuSinglePush ns_push[1]; };
#define push ns_push[NS_OPAQUE_ZERO] /* shared.h: NS_OPAQUE_ZERO */

#define NS_COMMON_TRACE
#include "common.glsl"

// How this pass traces its shadow rays (common.glsl, transmittance).
const uint SHADOW_RAYS = SHADOW_COUNTED | SHADOW_ANY_HIT | SHADOW_THROUGH_REFRACTING;

// ---------------------------------------------------------------------------------------
// Light seen from a point p (outside the medium, or inside an index-matched one): the
// direction towards it, the distance to it along that direction, and its perpendicular
// irradiance there (a sphere light: one direction of its cone, radiance / pdf).
// ---------------------------------------------------------------------------------------
struct LightSample {
    vec3 toward;
    float distance;
    vec3 irradiance;
    bool valid;
};

LightSample sample_light(GpuLight light, vec3 p)
{
    LightSample s;
    s.valid = true;
    uint kind = light.info.x;
    if (kind == NS_GPU_LIGHT_DIRECTIONAL) {
        s.toward = -light.direction.xyz;
        s.distance = NS_INF;
        s.irradiance = light.color.rgb;
    } else if (kind == NS_GPU_LIGHT_POINT) {
        vec3 v = light.position.xyz - p;
        float d2 = dot(v, v);
        s.distance = sqrt(d2);
        s.toward = v / s.distance;
        s.irradiance = light.color.rgb / d2;
        s.valid = d2 > 0.0;
    } else {
        // Sphere: uniform over the cone it subtends (pdf 1 / solid angle), as camera.comp.
        // The direction is drawn even from inside the light, where the sample is invalid,
        // so that the random stream stays as it always was.
        vec3 v = light.position.xyz - p;
        float d2 = dot(v, v);
        float r2 = light.position.w * light.position.w;
        s.valid = d2 > r2;
        s.irradiance = light.color.rgb * sphere_light_toward(light, p, s.toward, s.distance);
    }
    return s;
}

// The point the straight line from x towards the light aims at (for finding b).
vec3 light_aim(GpuLight light, vec3 x, out float distance)
{
    if (light.info.x == NS_GPU_LIGHT_DIRECTIONAL) {
        distance = NS_INF;
        return -light.direction.xyz;
    }
    vec3 v = light.position.xyz - x;
    distance = length(v);
    return v / max(distance, 1e-30);
}

// ---------------------------------------------------------------------------------------
// In-scattering at x (before sigma_s) from one light: p_HG * irradiance arriving. Each way
// the light can arrive ends in one shadow ray, described by a LightPath and traced in one
// place (light_in): lavapipe inlines every call, so each transmittance() call site is
// another two copies of the traversal for its compiler (making this pipeline took 1.2 s
// with one per case, 0.45 s now). The light is before * T * inside * phase, T the shadow
// ray's transmittance, the factors in the order they always had: the images are the same
// bit for bit, but for sphere lights seen through a refracting face, where the compiler
// now rounds differently (relative error 5e-10 on the bench's candle and milk).
// ---------------------------------------------------------------------------------------
struct LightPath {
    bool traced;   // false: no shadow ray, `before` is the whole answer
    vec3 from;     // the shadow ray: its origin, direction, length and the medium it starts
    vec3 toward;   // in (NS_NONE outside every medium)
    float distance;
    uint through;
    vec3 before;   // the light's factors before and after the shadow ray's transmittance
    vec3 inside;
    float phase;
};

LightPath no_light()
{
    LightPath lp;
    lp.traced = false;
    lp.from = lp.toward = vec3(0.0, 0.0, 1.0);
    lp.distance = 0.0;
    lp.through = NS_NONE;
    lp.before = lp.inside = vec3(0.0);
    lp.phase = 0.0;
    return lp;
}

// Index matched: a shadow ray through the scene from x itself, Beer-Lambert on the way.
LightPath light_index_matched(GpuLight light, vec3 x, vec3 wo, uint medium, float g)
{
    LightSample s = sample_light(light, x);
    LightPath lp = no_light();
    if (!s.valid)
        return lp;
    lp.traced = true;
    lp.from = x;
    lp.toward = s.toward;
    lp.distance = s.distance;
    lp.through = medium;
    lp.before = s.irradiance * hg_phase(dot(-s.toward, wo), g);
    lp.inside = vec3(1.0);
    lp.phase = 1.0;
    return lp;
}

// A point light through the face at b, taken as the plane (b, n), as a flat face exactly:
// the refraction point on that plane (the light at height a above the plane, x at depth h
// below it, r apart along it: a tan t_o + h tan t_t = r, sin t_o = n sin t_t), and the
// irradiance of the refracted pencil, which keeps diverging inside: the solid angle
// sin t_o dt_o dphi lands on r dphi by dr cos t_t across the ray, so
// E = T I sin t_o / (r cos t_t dr/dt_o) with dr/dt_o = a / cos^2 t_o + h cos t_o /
// (n cos^3 t_t); on the normal, T I / (a + h/n)^2.
LightPath point_refracted(GpuLight light, vec3 x, vec3 wo, GpuMaterial mat, vec3 b, vec3 n)
{
    LightPath lp = no_light();
    float ior = mat.sigma_t.w;
    vec3 p = light.position.xyz;
    float a = dot(p - b, n), h = max(0.0, dot(b - x, n));
    if (!(a > 0.0))
        return lp; // the light is behind the tangent plane at b
    vec3 along = (p - x) - dot(p - x, n) * n;
    float r = length(along);
    vec3 e_r = r > 0.0 ? along / r : vec3(0.0);
    // Newton on w = tan t_o: f(w) = a w + h tan t_t - r is increasing and concave (tan t_t
    // stays below 1 / sqrt(n^2 - 1)). tan t_t <= w / n puts the root at or right of the
    // paraxial w = r / (a + h / n), where Newton starts and from where it converges
    // monotonically; r / a bounds it on the right (steps beyond the bracket bisect it).
    float lo = r / (a + h / ior), hi = r / a, w = lo;
    float sin_t = 0.0, cos_t = 1.0;
    loop_count += 4u; // lavapipe counts these iterations: so must the dispatch sizing
    for (int it = 0; it < 4; it++) {
        float k = 1.0 + w * w;
        sin_t = w / (ior * sqrt(k));
        cos_t = sqrt(1.0 - sin_t * sin_t);
        float f_w = a * w + h * sin_t / cos_t - r;
        if (f_w > 0.0)
            hi = w;
        else
            lo = w;
        float next = w - f_w / (a + h / (ior * cos_t * cos_t * cos_t * k * sqrt(k)));
        w = next >= lo && next <= hi ? next : 0.5 * (lo + hi); // converged: next == w
    }
    float k = 1.0 + w * w;
    sin_t = w / (ior * sqrt(k));
    cos_t = sqrt(1.0 - sin_t * sin_t);
    float sin_o = w / sqrt(k), cos_o = 1.0 / sqrt(k);
    float u = h * sin_t / cos_t;
    float unused;
    float f = fresnel(cos_o, 1.0 / ior, unused);
    if (f >= 1.0 || cos_o <= 1e-6)
        return lp;
    float spread;
    if (r > 1e-5 * (a + h)) {
        float dr = a / (cos_o * cos_o) + h * cos_o / (ior * cos_t * cos_t * cos_t);
        spread = sin_o / (r * cos_t * dr);
    } else {
        spread = 1.0 / ((a + h / ior) * (a + h / ior));
    }
    vec3 y = x + h * n + u * e_r; // the refraction point on the plane
    vec3 travel = h > 0.0 ? normalize(x - y) : -n;
    vec3 to_light = p - y;
    float d_light = length(to_light);
    lp.traced = true;
    lp.from = y + n * ray_epsilon(y);
    lp.toward = to_light / d_light;
    lp.distance = d_light;
    lp.before = light.color.rgb * ((1.0 - f) * spread);
    lp.inside = beer_lambert(mat.sigma_t.xyz, h / cos_t);
    lp.phase = hg_phase(dot(travel, wo), mat.sigma_s.w);
    return lp;
}

// A sphere light refracted into the medium through the plane (b, n) on its way to x: one
// point y of its surface, drawn uniformly in the cone the sphere subtends seen straight
// from x, refracted exactly as a point light (point_refracted) of the intensity its area
// element sends towards the refraction point: L cos_r / pdf_area(y), pdf_area = cos_x /
// (|y - x|^2 solid angle), with cos_x and cos_r the cosines at y towards x and towards the
// refraction point. Unbiased wherever the points that reach x through the plane are seen
// straight from x (refraction bends the path towards the normal inside, so the refraction
// point lies between x's foot and where the straight line crosses). It was a point at the
// centre's distance along a direction drawn from the plane, which a sphere of radius 0.4
// whose bottom was 0.1 above a refracting slab read 7-8% high straight under it (and the
// sampled point's own distance from the plane 30% low: light reaches x from a ring of the
// sphere that the cone seen from the plane does not contain; docs/scattering.md, *A sphere
// light through a refracting face*).
LightPath sphere_refracted(GpuLight light, vec3 x, vec3 wo, GpuMaterial mat, vec3 b, vec3 n)
{
    LightSample s = sample_light(light, x);
    if (!s.valid)
        return no_light();
    GpuLight point = light;
    vec3 y = x + s.toward * s.distance;
    point.position.xyz = y;
    point.color.rgb = s.irradiance * (s.distance * s.distance);
    LightPath lp = point_refracted(point, x, wo, mat, b, n);
    vec3 outward = normalize(y - light.position.xyz);
    float cos_x = dot(outward, -s.toward), cos_r = dot(outward, -lp.toward);
    lp.before *= cos_x > 0.0 ? max(cos_r, 0.0) / cos_x : 0.0;
    return lp;
}

// A directional light refracted into the medium through the plane (b, n) (n outward) on its
// way to x: Snell, Fresnel, the irradiance carried in as E (1 - F) cos_i / cos_t, attenuated
// over the exact distance from x back to the plane along the refracted direction; y, where
// that refracted ray crosses the plane. The shadow ray leaves from b.
LightPath directional_through_plane(GpuLight light, vec3 x, vec3 wo, GpuMaterial mat, vec3 b,
                                    vec3 n, out vec3 y)
{
    LightPath lp = no_light();
    y = b;
    LightSample s = sample_light(light, b);
    float cos_i = dot(s.toward, n);
    if (!s.valid || cos_i <= 0.0)
        return lp; // the light is behind the plane
    float ior = mat.sigma_t.w, cos_t;
    float f = fresnel(cos_i, 1.0 / ior, cos_t);
    if (f >= 1.0 || cos_t <= 1e-6)
        return lp;
    float eta = 1.0 / ior;
    vec3 travel = normalize(-eta * s.toward + (eta * cos_i - cos_t) * n);
    float s_inside = max(0.0, dot(b - x, n)) / cos_t;
    y = x - travel * s_inside;
    lp.traced = true;
    lp.from = b + n * ray_epsilon(b);
    lp.toward = s.toward;
    lp.distance = s.distance;
    lp.before = s.irradiance * ((1.0 - f) * cos_i / cos_t);
    lp.inside = beer_lambert(mat.sigma_t.xyz, s_inside);
    lp.phase = hg_phase(dot(travel, wo), mat.sigma_s.w);
    return lp;
}

// A box's faces that can pass a light's light to a point inside: those with some of the
// light beyond their plane (a sphere light's centre within its radius of it; a directional
// light's direction against the outward normal). faces[k] = 2 axis + (1 on the max side).
uint box_faces_lit(GpuLight light, GpuPrim box, out uint faces[6])
{
    uint n = 0u;
    loop_count += 3u; // lavapipe counts these iterations: so must the dispatch sizing
    for (uint axis = 0u; axis < 3u; axis++) {
        float lo = box.a[axis], hi = box.b[axis];
        bool up, down;
        if (light.info.x == NS_GPU_LIGHT_DIRECTIONAL) {
            up = light.direction[axis] < 0.0;
            down = light.direction[axis] > 0.0;
        } else {
            float p = light.position[axis];
            float r = light.info.x == NS_GPU_LIGHT_SPHERE ? light.position.w : 0.0;
            up = p + r > hi;
            down = p - r < lo;
        }
        if (up)
            faces[n++] = 2u * axis + 1u;
        if (down)
            faces[n++] = 2u * axis;
    }
    return n;
}

// Whether a point of a box face's plane (normal along axis) lies on the face, with a margin
// of 1e-4 of the box's size for rounding.
bool on_face(GpuPrim box, uint axis, vec3 y)
{
    vec3 slack = 1e-4 * (box.b.xyz - box.a.xyz);
    vec3 lo = box.a.xyz - slack, hi = box.b.xyz + slack;
    lo[axis] = -NS_INF;
    hi[axis] = NS_INF;
    return all(greaterThanEqual(y, lo)) && all(lessThanEqual(y, hi));
}

// Light reaching x inside a box through its face `face` (box_faces_lit), which refracts it
// exactly (a flat face): the refraction point must lie on the face itself, not on its plane
// beyond an edge. A box lit on several faces gets light through each: the straight line
// towards the light crosses one of them, and single scattering through the others was lost
// (a box lit on two faces read 17% low against pt; docs/scattering.md, *A box's faces*).
LightPath light_through_box_face(GpuLight light, vec3 x, vec3 wo, GpuMaterial mat, GpuPrim box,
                                 uint face)
{
    LightPath lp = no_light();
    uint axis = face / 2u;
    vec3 n = vec3(0.0);
    n[axis] = (face & 1u) != 0u ? 1.0 : -1.0;
    // b, a point of the face: where the line from x towards the light's centre crosses its
    // plane (as light_refracted's b, for the face that line leaves by), held on the face;
    // else the face's point nearest x. A point of the face lies outside the light unless the
    // light overlaps the box.
    float plane = (face & 1u) != 0u ? box.b[axis] : box.a[axis];
    vec3 b = x;
    vec3 to_centre = light.position.xyz - x;
    uint kind = light.info.x;
    if (kind != NS_GPU_LIGHT_DIRECTIONAL && dot(to_centre, n) > 0.0) {
        float t = (plane - x[axis]) / to_centre[axis];
        if (t <= 1.0)
            b = x + to_centre * t;
    }
    b = clamp(b, box.a.xyz, box.b.xyz);
    b[axis] = plane;
    if (kind == NS_GPU_LIGHT_DIRECTIONAL) {
        vec3 y;
        lp = directional_through_plane(light, x, wo, mat, b, n, y);
        // From where the light that reaches x crossed the plane, which must be the face.
        if (!lp.traced || !on_face(box, axis, y))
            return no_light();
        lp.from = y + n * ray_epsilon(y);
        return lp;
    }
    lp = kind == NS_GPU_LIGHT_SPHERE ? sphere_refracted(light, x, wo, mat, b, n)
                                     : point_refracted(light, x, wo, mat, b, n);
    // lp.from: the refraction point, moved off the plane along n (on_face ignores that axis).
    return lp.traced && !on_face(box, axis, lp.from) ? no_light() : lp;
}

// in_box: the boundary crossed is a box's (box: its prim), whose faces light_in takes one by
// one (light_through_box_face); then no light here.
LightPath light_refracted(GpuLight light, vec3 x, vec3 wo, uint medium, GpuMaterial mat,
                          out bool in_box, out GpuPrim box)
{
    LightPath lp = no_light();
    in_box = false;
    float g = mat.sigma_s.w;
    float aim_distance;
    vec3 aim = light_aim(light, x, aim_distance);
    Hit h;
    if (!trace_scene(x, aim, 0.0, aim_distance, h)) {
        // No boundary between x and the light (a light inside the medium): Beer-Lambert only.
        LightSample s = sample_light(light, x);
        if (s.valid)
            lp.before = s.irradiance * hg_phase(dot(-s.toward, wo), g) *
                        beer_lambert(mat.sigma_t.xyz, s.distance);
        return lp;
    }
    // Anything but this medium's own boundary, left from inside, blocks the light.
    box = prim_at(h.prim);
    if (box.info.y != medium || h.front)
        return lp;
    in_box = NS_SINGLE_BOX_FACES != 0 && box.info.x == NS_PRIM_BOX;
    if (in_box)
        return lp;
    vec3 b = x + h.t * aim;
    vec3 n = h.normal; // outward: the light arrives against it, through the tangent plane at b
    uint kind = light.info.x;
    if (kind == NS_GPU_LIGHT_SPHERE)
        return sphere_refracted(light, x, wo, mat, b, n);
    if (kind == NS_GPU_LIGHT_POINT)
        return point_refracted(light, x, wo, mat, b, n);
    vec3 unused;
    return directional_through_plane(light, x, wo, mat, b, n, unused);
}

vec3 light_in(GpuLight light, vec3 x, vec3 wo, uint medium, GpuMaterial mat)
{
    // One path, or one per face of a box that sees the light: each ends in a shadow ray,
    // traced at the one call site below (see LightPath).
    bool in_box = false;
    GpuPrim box;
    LightPath first = mat.sigma_t.w == 1.0 ? light_index_matched(light, x, wo, medium, mat.sigma_s.w)
                                           : light_refracted(light, x, wo, medium, mat, in_box, box);
    uint faces[6];
    uint paths = in_box ? box_faces_lit(light, box, faces) : 1u;
    if (in_box)
        loop_count += paths; // lavapipe counts these iterations: so must the dispatch sizing
    vec3 sum = vec3(0.0);
    for (uint k = 0u; k < paths; k++) {
        LightPath lp = first;
        if (in_box)
            lp = light_through_box_face(light, x, wo, mat, box, faces[k]);
        if (!lp.traced)
            sum += lp.before;
        else
            sum += lp.before * transmittance(lp.from, lp.toward, lp.distance, lp.through, SHADOW_RAYS) *
                   lp.inside * lp.phase;
    }
    return sum;
}

// How environment_along follows the ray back from a point through internal reflections: at
// most this many, and Russian roulette past a reflection on what the ray can still bring
// (carried on with probability min(1, ENVIRONMENT_ROULETTE x its largest channel): 5 cost
// the bumpy sphere's single scattering 20% more than 1 and the bunny's 23%, 20 more still,
// for the same error over four seeds).
const uint ENVIRONMENT_REFLECTIONS = 8u;
const float ENVIRONMENT_ROULETTE = 1.0;

// Environment radiance arriving at x from inside the medium, travelling along -back (back
// points where the light comes from). Through a refracting boundary the ray back from x is
// followed through the boundary's internal reflections: at each face it meets from inside it
// leaves with probability 1 - F, bringing n^2 of the environment (its weight (1 - F) / (1 -
// F)) if the shadow ray beyond sees it, and reflects otherwise (always on total internal
// reflection), attenuated by Beer-Lambert along the way; ENVIRONMENT_REFLECTIONS and
// ENVIRONMENT_ROULETTE bound the chain. Until 2026-12-02 nothing came back on total internal
// reflection (about three quarters of the directions at a face of ior 1.5) nor from the
// reflected part; the boundary walks' expected reflections of the environment's unscattered
// light stood in for them, a few thousand sources whose blurred first order made rare bright
// streaks, and render/boundary.c now leaves their first order to this (docs/rendering.md,
// *Single scattering*). One shadow ray, from one call site (as light_in):
// environment * before * T.
vec3 environment_along(vec3 x, vec3 back, uint medium, GpuMaterial mat)
{
    float ior = mat.sigma_t.w;
    vec3 from = x, toward = back, before = vec3(1.0);
    uint through = medium;
    if (ior != 1.0) {
        // The chain's coins from a stream of their own: the lights' loop draws its distances
        // from the stratum's stream after the environment's first number.
        rng_state = pcg_hash(rng_state ^ 0x2545f491u);
        vec3 p = x, dir = back;
        bool left = false;
        for (uint reflection = 0u; reflection <= ENVIRONMENT_REFLECTIONS; reflection++) {
            loop_count++; // lavapipe counts these iterations: so must the dispatch sizing
            Hit h;
            if (!trace_scene(p, dir, 0.0, NS_INF, h))
                return params.environment.rgb * before * beer_lambert(mat.sigma_t.xyz, NS_INF);
            uvec4 info = prim_at(h.prim).info;
            if (info.y != medium || h.front)
                return vec3(0.0);
            vec3 b = p + h.t * dir;
            vec3 n = h.normal;
            float cos_i = dot(dir, n);
            if (cos_i <= 0.0)
                return vec3(0.0);
            before *= beer_lambert(mat.sigma_t.xyz, h.t);
            float cos_t;
            float f = fresnel(cos_i, ior, cos_t);
            // A chord of a sphere meets it at the same angle at both ends: totally reflected
            // once inside an analytic sphere, the ray is for ever, so no light comes along it.
            if (f >= 1.0 && info.x == NS_PRIM_SPHERE)
                return vec3(0.0);
            if (f < 1.0 && rnd() >= f) {
                from = b + n * ray_epsilon(b);
                toward = normalize(ior * dir - (ior * cos_i - cos_t) * n);
                before *= ior * ior;
                left = true;
                break;
            }
            // Russian roulette on what the reflected ray can still bring.
            float q = min(1.0, max(before.x, max(before.y, before.z)) * ENVIRONMENT_ROULETTE);
            if (!(rnd() < q))
                break;
            before /= q;
            p = b - n * ray_epsilon(b);
            dir = reflect(dir, n);
        }
        if (!left)
            return vec3(0.0);
        through = NS_NONE;
    }
    return params.environment.rgb * before * transmittance(from, toward, NS_INF, through, SHADOW_RAYS);
}

// The environment's in-scattering at x (before sigma_s): integral of p_HG L_in over the
// sphere, from one phase-sampled direction (the uniform numbers `phase_u`, stratified across
// the segment): p_HG and its pdf cancel, the estimate is L_in itself. (Sampling directions
// towards the face the segment entered through instead, half the time, weighted by the
// balance heuristic, made the bench's milk 4 dB noisier at 8 samples: with g = 0.7 the phase
// function favours light from deeper along the segment, not from that face. Tried again on
// 2026-12-01 with the face's normal traced per segment and directions whose density falls
// as the transmittance to its plane: every pixel at 64 samples, the bumpy sphere 39.5 ->
// 37.8 dB (red, the densest channel, 35.5 -> 33.6), the milk 37.7 -> 34.4 dB. Even 36 mean
// free paths deep the light comes along the lobe, near the silhouettes.)
vec3 environment_in(vec3 x, vec3 wo, uint medium, GpuMaterial mat, vec2 phase_u)
{
    vec3 back = -hg_sample_at(wo, mat.sigma_s.w, phase_u.x, phase_u.y);
    return environment_along(x, back, medium, mat);
}

// In-scattering at x (before sigma_s) from the lights other than the environment: the sum
// over them of p_HG * irradiance arriving.
vec3 lights_in(vec3 x, vec3 wo, uint medium, GpuMaterial mat)
{
    vec3 sum = vec3(0.0);
    for (uint i = 0u; i < params.counts.y; i++) {
        if (out_of_budget())
            break;
        GpuLight light = lights[i];
        if (light.info.x == NS_GPU_LIGHT_ENVIRONMENT)
            continue; // all environment lights together: environment_in
        sum += light_in(light, x, wo, medium, mat);
    }
    return sum;
}

// The random stream of a segment comes from what it is (the camera sample it belongs to and
// where it starts), not from its index: the camera pass records segments in whatever order
// its invocations finish, and the same seed must still give the same image. Each sample
// then has its own stream, so the result does not depend on the split into dispatches.
uint segment_stream(GpuSegment seg)
{
    uint h = pcg_hash(params.image.w);
    h = pcg_hash(h + seg.pixel);
    h = pcg_hash(h + seg.sample_index);
    h = pcg_hash(h + seg.depth);
    h = pcg_hash(h ^ floatBitsToUint(seg.entry.x));
    h = pcg_hash(h ^ floatBitsToUint(seg.entry.y));
    return pcg_hash(h ^ floatBitsToUint(seg.entry.z));
}

// ---------------------------------------------------------------------------------------
// Where along the segment the samples go. The integrand is e^{-sigma_t t} times the light
// arriving at x(t): on a segment many mean free paths long most of it lies in the first few,
// which regular points waste their samples past. The distances are drawn from the mixture,
// in equal parts, of one exponential per channel truncated to [0, L] and of the uniform
// density: the exponentials follow the camera's transmittance of each channel, the uniform
// part keeps every point of the segment at least 1/4 of the uniform density (light arriving
// from behind the object, where the camera's transmittance is not what shapes the
// integrand). The samples are stratified in that mixture's CDF, one jittered point per
// stratum, so the estimate is unbiased and the exponential part's error falls as N^-1.5.
// ---------------------------------------------------------------------------------------
struct DistanceDensity {
    vec3 rate;  // sigma_t per channel, 0 where the truncated exponential is uniform
    vec3 norm;  // 1 / (1 - e^{-rate L}) per channel (1 / L where uniform)
    float len;  // the segment's length L
};

DistanceDensity distance_density(vec3 sigma_t, float len)
{
    DistanceDensity d;
    d.len = len;
    for (int c = 0; c < 3; c++) {
        float tau = sigma_t[c] * len;
        // Below 1e-4 optical depth the exponential is flat to float precision: uniform.
        d.rate[c] = tau > 1e-4 ? sigma_t[c] : 0.0;
        d.norm[c] = tau > 1e-4 ? 1.0 / (1.0 - exp(-tau)) : 1.0 / len;
    }
    return d;
}

// The mixture's CDF and density at t.
float distance_cdf(DistanceDensity d, float t, out float pdf)
{
    float cdf = t / d.len;
    pdf = 1.0 / d.len;
    for (int c = 0; c < 3; c++) {
        if (d.rate[c] > 0.0) {
            float e = exp(-d.rate[c] * t);
            cdf += (1.0 - e) * d.norm[c];
            pdf += d.rate[c] * e * d.norm[c];
        } else {
            cdf += t * d.norm[c];
            pdf += d.norm[c];
        }
    }
    pdf *= 0.25;
    return 0.25 * cdf;
}

// The t with CDF u, and its density. The CDF is increasing and concave (every part's density
// is non-increasing), so Newton from t = 0 stays left of the root and climbs to it without
// overshooting; 12 steps reach it to float precision from any u < 1 on segments of up to
// hundreds of mean free paths (the uniform part bounds each step's slope below).
float distance_sample(DistanceDensity d, float u, out float pdf)
{
    float t = 0.0;
    loop_count += 12u; // lavapipe counts these iterations: so must the dispatch sizing
    for (int it = 0; it < 12; it++) {
        float cdf = distance_cdf(d, t, pdf);
        t = min(d.len, t + max(0.0, u - cdf) / pdf);
    }
    distance_cdf(d, t, pdf);
    return t;
}

// The strata of one segment: render.single_samples N scaled by the segment's throughput (the
// weight its result gets in its pixel), at least 1. The first stretch into an object carries
// (1 - F) of its camera sample, a stretch after an internal reflection F times the light that
// crossed the object before it, often a few per cent: spending N samples there buys noise
// nobody sees. Samples in proportion to the weight is what minimises the pixel's variance
// for a given total when the segments' own variances are alike; every segment's estimate
// stays unbiased at any count.
uint segment_strata(GpuSegment seg, uint samples)
{
    float weight = max(seg.throughput.x, max(seg.throughput.y, seg.throughput.z));
    return clamp(uint(ceil(float(samples) * min(weight, 1.0))), 1u, samples);
}

// One light sample per this many strata of the environment's (main, below).
const uint LIGHT_STRIDE = 4u;

void main()
{
    uint index = interleaved_invocation_x();
    if (index >= push.segment_count || push.samples == 0u)
        return;
    GpuSegment seg = segments[index];
    // Not a material of this scene, or not a medium (its ior would be 0): nothing scatters.
    if (seg.material >= params.prims.z || materials[seg.material].reflectance.w == 0.0) {
        radiance[index] = vec4(0.0);
        return;
    }
    GpuMaterial mat = materials[seg.material];
    vec3 wo = -seg.direction; // towards the camera
    float len = distance(seg.entry, seg.exit);
    uint segment_seed = segment_stream(seg);
    uvec2 phase_shift =
        uvec2(pcg_hash(segment_seed ^ 0x5bd1e995u), pcg_hash(segment_seed ^ 0x27d4eb2fu));

    // Two estimates share the segment's samples: the environment's at every one of the N
    // (its one phase-sampled direction per point is what makes single scattering noisy), the
    // other lights' at one point per LIGHT_STRIDE strata, M = ceil(N / LIGHT_STRIDE) strata
    // of their own (a light's connection is smooth along a segment and costs as much as the
    // environment's direction; on the bench's milk at 8 samples the sphere light alone is
    // 45 dB from its converged value, the environment alone 23 dB).
    uint strata = segment_strata(seg, push.samples);
    uint light_strata = (strata + LIGHT_STRIDE - 1u) / LIGHT_STRIDE;
    bool environment = params.environment.r + params.environment.g + params.environment.b > 0.0;
    vec3 sum_environment = vec3(0.0), sum_lights = vec3(0.0);
    if (len > 0.0) {
        DistanceDensity density = distance_density(mat.sigma_t.xyz, len);
        uint end = min(push.first_sample + push.sample_count, strata);
        // Two loops, not one with the lights behind `k % LIGHT_STRIDE == 0`: lavapipe runs a
        // branch's code for the whole SIMD group whether or not any lane takes it, but a
        // loop no lane enters costs nothing, so the lights cost 1/LIGHT_STRIDE of the
        // environment here. Stratum k's random stream is the same in both: the environment
        // takes its first number (its reflections' coins a stream of their own), the lights
        // the ones after it.
        for (uint k = push.first_sample; environment && k < end; k++) {
            if (out_of_budget())
                break;
            rng_state = pcg_hash(segment_seed + k);
            float pdf;
            float t = distance_sample(density, (float(k) + rnd()) / float(strata), pdf);
            vec3 x = seg.entry + t * seg.direction;
            vec2 phase_u = r2_point(k, phase_shift); // common.glsl
            sum_environment += beer_lambert(mat.sigma_t.xyz, t) / pdf *
                               environment_in(x, wo, seg.material, mat, phase_u);
        }
        uint first_light = (push.first_sample + LIGHT_STRIDE - 1u) / LIGHT_STRIDE;
        for (uint j = first_light; j * LIGHT_STRIDE < end; j++) {
            if (out_of_budget())
                break;
            rng_state = pcg_hash(segment_seed + j * LIGHT_STRIDE);
            if (environment)
                rnd(); // the environment's
            float pdf;
            float t = distance_sample(density, (float(j) + rnd()) / float(light_strata), pdf);
            vec3 x = seg.entry + t * seg.direction;
            sum_lights +=
                beer_lambert(mat.sigma_t.xyz, t) * lights_in(x, wo, seg.material, mat) / pdf;
        }
    }
    vec3 sum =
        mat.sigma_s.xyz * (sum_environment / float(strata) + sum_lights / float(light_strata));
    // lavapipe stops loops silently once an invocation has run 65535 iterations in all
    // (shared.h), and from then on every loop ends after its first iteration: a loop of two
    // iterations here tells whether that happened anywhere above. Its trip count comes from
    // the push block so that the compiler cannot unroll it away.
    uint canary = 0u;
    for (uint i = 0u; i < 2u + (push.segment_count >> 31); i++)
        canary++;
    if (canary != 2u || (params.limits.x != 0u && loop_count > params.limits.x))
        atomicAdd(counters[0], 1u);
    atomicMax(counters[1], loop_count);
    vec4 previous = push.first_sample == 0u ? vec4(0.0) : radiance[index];
    radiance[index] = previous + vec4(sum, 0.0);
}
