// common.glsl — the helpers the kernels share: random numbers, ray offsets, Beer-Lambert,
// the orthonormal basis, Fresnel, Henyey-Greenstein, direction sampling and, for kernels
// that trace shadow rays, transmittance and the sphere lights. One definition each, so that
// the passes cannot drift apart on shadowing, Fresnel or a random stream.
//
// Every helper is the exact code the kernels had, operation for operation: glslang keeps
// the order of floating-point operations, so a rewritten expression (another order, a max
// for a clamp, an extra normalize) can change an image's bits. Where two kernels had
// different code for the same job, both forms are kept below under their own names, with
// what differs; merging them would change the images of one of the kernels.
//
// Needs shared.h included first. The rest reads the scene and is compiled only for kernels
// that ask for it, because GLSL rejects a function that names an undeclared buffer even
// when nothing calls it: a kernel that defines NS_COMMON_TRACE before including this file
// has included trace.glsl and declared materials[] (shadow rays, sphere lights, free
// flights); one that also defines NS_COMMON_LIGHTS has declared lights[] (the sphere lights
// a ray hits).

const float PI = 3.14159265358979;

// ---------------------------------------------------------------------------------------
// Random numbers: a PCG hash (Jarzynski & Olano 2020) chained through rng_state. Each
// kernel seeds rng_state from what a sample is (the render seed, the pixel or path, the
// sample index), never from the order invocations run in, so an image does not depend on
// scheduling or on how the work was split into dispatches.
// ---------------------------------------------------------------------------------------
uint rng_state;

uint pcg_hash(uint v)
{
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// A float in [0, 1) from the top 24 bits of a hash: a float holds 24 bits exactly, so every
// value is equally likely and 1 is never reached.
float unit_float(uint h)
{
    return float(h >> 8u) * (1.0 / 16777216.0);
}

float rnd()
{
    rng_state = pcg_hash(rng_state);
    return unit_float(rng_state);
}

// Point k of Roberts' R2 sequence (the additive recurrence on the plastic number's powers, a
// low-discrepancy sequence good for any count), shifted by `shift` (Cranley-Patterson): with
// a random shift every point is uniform, so an estimate from them stays unbiased, while N
// consecutive points cover the square evenly instead of clumping as independent draws do.
// In 32-bit fixed point: exact and periodic.
vec2 r2_point(uint k, uvec2 shift)
{
    uvec2 v = uvec2(k * 3242174889u, k * 2447445414u) + shift; // 2^32 / g, 2^32 / g^2
    return vec2(v >> 8u) * (1.0 / 16777216.0);
}

// Stratified light paths. The n paths that leave one light towards one target take the
// points of the 4-D Hammersley set (j / n, phi_2(j), phi_3(j), phi_5(j)), j = 0 .. n - 1,
// for their emission instead of independent numbers, every coordinate shifted modulo 1 by
// one random vector per (seed, stratum) (a Cranley-Patterson rotation). Each path's numbers
// are still uniform on their own, so every estimate stays unbiased; together they cover the
// light's disk, cone or surface evenly, without the clumps and gaps of independent draws
// that moved a render's image mean by several per cent from one seed to the next
// (docs/scattering.md, *Stratified light paths*).
float radical_inverse(uint j, uint base)
{
    float inv_base = 1.0 / float(base), scale = inv_base, x = 0.0;
    for (uint digit = 0u; digit < 32u && j > 0u; digit++) {
        x += float(j % base) * scale;
        j /= base;
        scale *= inv_base;
    }
    return x;
}

// Point j of n, rotated by the hash of `key`; fract keeps every coordinate in [0, 1).
vec4 stratified4(uint j, uint n, uint key)
{
    uint h0 = pcg_hash(key), h1 = pcg_hash(h0), h2 = pcg_hash(h1), h3 = pcg_hash(h2);
    vec4 shift = vec4(unit_float(h0), unit_float(h1), unit_float(h2), unit_float(h3));
    // phi_2(j) is j's bits mirrored about the binary point: unit_float keeps the top 24.
    vec4 point = vec4(float(j) / float(max(n, 1u)), unit_float(bitfieldReverse(j)),
                      radical_inverse(j, 3u), radical_inverse(j, 5u));
    return fract(point + shift);
}

// The numbers of light path `path` of the stratum whose paths are [first, first + count),
// rotated by `seed` and the stratum.
vec4 stratum_point(uint path, uint first, uint count, uint seed)
{
    return stratified4(path - first, count, pcg_hash(seed ^ 0x2545f491u) + first);
}

// ---------------------------------------------------------------------------------------
// Geometry and attenuation.
// ---------------------------------------------------------------------------------------

// Offset for spawning rays off a surface. It grows with the position's magnitude because
// the float error of a hit point does; 1 scene unit and below share one absolute offset.
float ray_epsilon(vec3 p)
{
    return 1e-4 * max(1.0, max(abs(p.x), max(abs(p.y), abs(p.z))));
}

// exp(-sigma_t * distance), but exactly 1 in a channel whose sigma_t is 0, even at infinite
// distance, where the product would be NaN (0 * inf).
vec3 beer_lambert(vec3 sigma_t, float distance)
{
    vec3 tau = vec3(sigma_t.x > 0.0 ? sigma_t.x * distance : 0.0,
                    sigma_t.y > 0.0 ? sigma_t.y * distance : 0.0,
                    sigma_t.z > 0.0 ? sigma_t.z * distance : 0.0);
    return exp(-tau);
}

// Orthonormal basis around the unit vector n (Duff et al. 2017): branch-free apart from the
// sign, and without the cancellation of cross products with a fixed axis near that axis.
void basis(vec3 n, out vec3 t, out vec3 b)
{
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}

// The unit direction at polar angle acos(cos_t) and azimuth phi about axis. The result is
// normalised again because the basis and the sum round, and callers take dot products with
// it as cosines.
vec3 around(vec3 axis, float cos_t, float phi)
{
    float sin_t = sqrt(max(0.0, 1.0 - cos_t * cos_t));
    vec3 tx, ty;
    basis(axis, tx, ty);
    return normalize(tx * (sin_t * cos(phi)) + ty * (sin_t * sin(phi)) + axis * cos_t);
}

// A hit that contradicts the medium the ray is in: leaving a medium while outside every
// medium, or entering the one it is already in. Media do not nest, so this is a grazing
// ray meeting the surface it just left within float error, and it is stepped over. (Taken
// as a real boundary, a reflection there would put the ray inside the medium with the
// medium unset, trapped by total internal reflection: seen once in a million light
// sub-paths of pt.comp on scenes/default.json.)
bool spurious_boundary(bool front, uint hit_medium, uint medium)
{
    return front ? medium == hit_medium : medium == NS_NONE;
}

// Whether a material is a medium that scatters light, rather than a diffuse surface or a
// medium that only absorbs. vrl_trace.comp tested the sum of sigma_s rather than its
// largest channel; scene_check.c holds every sigma_s finite and >= 0, and for such values
// the two tests agree.
bool scatters(GpuMaterial m)
{
    return m.reflectance.w != 0.0 && max(m.sigma_s.x, max(m.sigma_s.y, m.sigma_s.z)) > 0.0;
}

// ---------------------------------------------------------------------------------------
// Smooth dielectric boundaries.
// ---------------------------------------------------------------------------------------

// Unpolarised Fresnel reflectance; eta = n_incident / n_transmitted, cos_i > 0. Returns 1
// on total internal reflection, so that callers can take 1 - F as the transmitted part
// without a separate test, and cos_t of the refracted ray.
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

// The refracted direction of d at a boundary whose normal n points back towards where d
// comes from (cos_i = -dot(d, n) > 0), with the eta and cos_t that fresnel() returned, so
// that the direction and the Fresnel weight agree on the angle. The refractions written
// from the other side of the normal (pt.comp's leave_medium and specular_light, single.comp's
// light_refracted and environment_in) order their operations differently and keep their
// own expressions: rewritten through this one they would round differently.
vec3 refract_direction(vec3 d, vec3 n, float eta, float cos_i, float cos_t)
{
    return normalize(eta * d + (eta * cos_i - cos_t) * n);
}

// ---------------------------------------------------------------------------------------
// Henyey-Greenstein phase function; cos_t is measured between the two directions of
// travel, so g > 0 scatters forwards.
// ---------------------------------------------------------------------------------------
float hg_phase(float cos_t, float g)
{
    float denom = 1.0 + g * g - 2.0 * g * cos_t;
    return (1.0 - g * g) / (4.0 * PI * denom * sqrt(denom));
}

// A direction drawn from p_HG about d (pdf = p_HG) for the uniform numbers u (the cosine's
// CDF) and phi_u (the azimuth's; single.comp stratifies them across a segment's samples).
// Near g = 0 the inverse CDF divides by g, so the isotropic case is taken on its own.
vec3 hg_sample_at(vec3 d, float g, float u, float phi_u)
{
    float cos_t;
    if (abs(g) < 1e-3) {
        cos_t = 1.0 - 2.0 * u;
    } else {
        float s = (1.0 - g * g) / (1.0 + g - 2.0 * g * u);
        cos_t = clamp((1.0 + g * g - s * s) / (2.0 * g), -1.0, 1.0);
    }
    return around(d, cos_t, 2.0 * PI * phi_u);
}

// The same from the random stream (the cosine's number first).
vec3 hg_sample(vec3 d, float g)
{
    float u = rnd();
    return hg_sample_at(d, g, u, rnd());
}

// ---------------------------------------------------------------------------------------
// Direction and point sampling.
// ---------------------------------------------------------------------------------------

// A unit direction uniform over the sphere, from z uniform in [-1, 1] (Archimedes): z from
// the uniform number u, the azimuth from v.
vec3 uniform_sphere_at(float u, float v)
{
    float z = 1.0 - 2.0 * u, phi = 2.0 * PI * v;
    float r = sqrt(max(0.0, 1.0 - z * z));
    return vec3(r * cos(phi), r * sin(phi), z);
}

vec3 uniform_sphere()
{
    float u = rnd();
    return uniform_sphere_at(u, rnd());
}

// A cosine-distributed direction about n (pdf cos / pi), which cancels the cosine and the
// 1 / pi of a Lambertian surface or a uniform sphere light's emission.
vec3 cosine_sample_at(vec3 n, float u, float v)
{
    float r = sqrt(u), phi = 2.0 * PI * v;
    return around(n, sqrt(max(0.0, 1.0 - r * r)), phi);
}

vec3 cosine_sample(vec3 n)
{
    float u = rnd();
    return cosine_sample_at(n, u, rnd());
}

// A direction d from o uniform in the cone that the sphere (xyz, radius w) subtends; returns
// the cone's solid angle (1 / pdf). Sampling the cone rather than the sphere's surface
// wastes no sample on its far side. The result means nothing for o inside the sphere, which
// the callers test (or ignore) themselves.
// sample_cone_at: the same for the uniform numbers u (the cosine's) and v (the azimuth's).
float sample_cone_at(vec4 sphere, vec3 o, float u, float v, out vec3 d)
{
    vec3 to = sphere.xyz - o;
    float d2 = dot(to, to);
    float r2 = sphere.w * sphere.w;
    float cos_max = sqrt(max(0.0, 1.0 - r2 / d2));
    d = around(to / sqrt(d2), 1.0 - u * (1.0 - cos_max), 2.0 * PI * v);
    return 2.0 * PI * (1.0 - cos_max);
}

// Cosine of the half-angle of the cone from p that holds the sphere (c, r); -1 inside it,
// where the "cone" is every direction. The emission of vrl.comp and of pt.comp's light
// sub-paths samples that cone about normalize(c - p) with this cosine. It is not
// sample_cone_at's: that one divides c - p by the distance, which rounds differently from
// normalize, so sharing it would change the VRLs and the pt images.
float cone_cos(vec3 p, vec3 c, float r)
{
    vec3 v = c - p;
    float d2 = dot(v, v);
    return d2 > r * r ? sqrt(1.0 - r * r / d2) : -1.0;
}

// A point uniform on the disk through the centre c of a sphere of radius r across d, moved
// back along d to just outside the sphere: parallel rays along d from such points cover the
// sphere with uniform density, for lights that arrive from infinity.
// disk_before_sphere_at: the same for the uniform numbers u (the radius's) and v (the angle's).
vec3 disk_before_sphere_at(vec3 c, float r, vec3 d, float u, float v)
{
    vec3 tx, ty;
    basis(d, tx, ty);
    float rho = r * sqrt(u), phi = 2.0 * PI * v;
    return c + rho * (cos(phi) * tx + sin(phi) * ty) - (1.001 * r + ray_epsilon(c)) * d;
}

vec3 disk_before_sphere(vec3 c, float r, vec3 d)
{
    float u = rnd();
    return disk_before_sphere_at(c, r, d, u, rnd());
}

#ifdef NS_COMMON_TRACE
// ---------------------------------------------------------------------------------------
// Shadow rays, sphere lights and free flights: need trace.glsl and materials[].
// ---------------------------------------------------------------------------------------

vec3 sigma_t_of(uint material)
{
    return material == NS_NONE ? vec3(0.0) : materials[material].sigma_t.xyz;
}

// Transmittance of a shadow ray from o (in `medium`, NS_NONE outside, or an index-matched
// medium: never a refracting one) along d up to tmax. Diffuse surfaces block it; refracting
// boundaries block it too unless the pass sets SHADOW_THROUGH_REFRACTING (below), because
// light bent on the way is no straight shadow ray (pt.comp reaches it by other strategies);
// index-matched boundaries let it through with the Beer-Lambert factor of the media
// crossed.
//
// `how` (bits), fixed per pass, each pass naming its choice once (SHADOW_RAYS):
// SHADOW_COUNTED: each crossing counts one loop iteration (out_of_budget) and stops the ray
//   once the budget is spent. single.comp sets it: render/single.c sizes its dispatches from
//   the iterations counted, so they must include these, which lavapipe counts against its
//   limit. camera.comp and pt.comp do not, as they never have: counting would move their
//   budget checks, and so their images.
// SHADOW_ANY_HIT: try trace_shadow's any-hit query first. camera.comp and single.comp set
//   it. pt.comp does not: its yield budget on lavapipe (NS_PT_YIELD_LAVAPIPE) was measured
//   on the walk's ratio of real to counted loop iterations, and with the query its light
//   sub-paths ran past lavapipe's limit (gpu_single's comparison with pt caught it).
// SHADOW_THROUGH_REFRACTING: refracting boundaries let the ray through as well, straight on,
//   each crossing with the Fresnel transmittance 1 - F of the angle it meets the face at from
//   outside, and the medium between two crossings with Beer-Lambert over the refracted
//   path's length (the straight one times cos_i / cos_t at the entry): exact through a slab
//   with parallel faces for light from infinity (directional, environment), whose
//   refractions shift it but do not turn it; for a point or sphere light the plate also
//   moves the light's apparent place, which the straight ray does not see. single.comp
//   sets it: without it a part of a non-convex object between a point and the light (the
//   bunny's ears and head) cast a black shadow inside the object, where pt's light passes
//   through them (docs/rendering.md, *Single scattering*).
const uint SHADOW_COUNTED = 1u, SHADOW_ANY_HIT = 2u, SHADOW_THROUGH_REFRACTING = 4u;

vec3 transmittance(vec3 o, vec3 d, float tmax, uint medium, uint how)
{
    // Most shadow rays from outside the media meet a blocker or nothing at all: the any-hit
    // query answers those, and only a ray that meets a boundary it crosses (index matched,
    // or refracting with SHADOW_THROUGH_REFRACTING) walks its crossings in order below. A
    // ray from inside an index-matched medium would almost always meet its boundary first,
    // so it walks at once.
    bool through_refracting = (how & SHADOW_THROUGH_REFRACTING) != 0u;
    if ((how & SHADOW_ANY_HIT) != 0u && medium == NS_NONE) {
        uint crosses = NS_PRIM_SHADOW_PASSES | (through_refracting ? NS_PRIM_REFRACTS : 0u);
        uint met = trace_shadow(o, d, 0.0, tmax, crosses);
        if (met == NS_SHADOW_BLOCKED)
            return vec3(0.0);
        if (met == NS_SHADOW_CLEAR)
            return vec3(1.0);
    }
    vec3 tau = vec3(0.0);
    float t_enter = 0.0, tmin = 0.0, crossed = 1.0, stretch = 1.0;
    for (int crossing = 0; crossing < 16; crossing++) {
        if ((how & SHADOW_COUNTED) != 0u && out_of_budget())
            break;
        Hit h;
        if (!trace_scene(o, d, tmin, tmax, h))
            break;
        uint m = prim_at(h.prim).info.y;
        GpuMaterial mat = materials[m];
        float ior = mat.sigma_t.w;
        if (mat.reflectance.w == 0.0 || (ior != 1.0 && !through_refracting))
            return vec3(0.0);
        if (!h.front && medium != NS_NONE)
            tau += sigma_t_of(medium) * (stretch * (h.t - t_enter));
        // The refracted length's factor holds from a refracting entry to the next crossing.
        stretch = 1.0;
        if (ior != 1.0) {
            float cos_t;
            float cos_o = min(abs(dot(d, h.normal)), 1.0);
            crossed *= 1.0 - fresnel(cos_o, 1.0 / ior, cos_t);
            if (h.front && cos_t > 0.0)
                stretch = cos_o / cos_t;
        }
        medium = h.front ? m : NS_NONE;
        t_enter = h.t;
        tmin = h.t + ray_epsilon(o + h.t * d);
    }
    vec3 tr = crossed * exp(-tau);
    if (medium != NS_NONE)
        tr *= beer_lambert(sigma_t_of(medium), stretch * (tmax - t_enter));
    return tr;
}

// A direction wi towards the sphere light from o, uniform in the cone it subtends, and the
// distance t_light to its surface along wi; returns the cone's solid angle (1 / pdf). It
// draws its two random numbers even when o is inside the light (and the result means
// nothing), because single.comp has always drawn them there. sphere_light_toward_at: the
// same from the uniform numbers uv (the cone's cosine's, its azimuth's).
float sphere_light_toward_at(GpuLight light, vec3 o, vec2 uv, out vec3 wi, out float t_light)
{
    float solid_angle = sample_cone_at(light.position, o, uv.x, uv.y, wi);
    t_light = hit_sphere(o, wi, light.position, 0.0, NS_INF);
    if (t_light < 0.0) {
        // Grazing the silhouette the ray can miss the sphere in float: the centre's distance
        // is then off by at most the radius.
        vec3 v = light.position.xyz - o;
        t_light = sqrt(dot(v, v));
    }
    return solid_angle;
}

float sphere_light_toward(GpuLight light, vec3 o, out vec3 wi, out float t_light)
{
    vec2 uv;
    uv.x = rnd();
    uv.y = rnd();
    return sphere_light_toward_at(light, o, uv, wi, t_light);
}

// The uniform numbers a light's direction is drawn from, where the caller has its own
// (camera.comp's low-discrepancy points); DRAW_NUMBERS: draw them from rng_state.
const vec2 DRAW_NUMBERS = vec2(-1.0);

// sphere_light_toward for a point that may lie inside the light: false there, without
// drawing random numbers, because from inside the light has no cone to sample and
// camera.comp and pt.comp take no light from it. `given`: the numbers, or DRAW_NUMBERS.
bool sample_sphere_light(GpuLight light, vec3 o, vec2 given, out vec3 wi, out float t_light,
                         out float solid_angle)
{
    vec3 v = light.position.xyz - o;
    float d2 = dot(v, v);
    float r2 = light.position.w * light.position.w;
    wi = vec3(0.0, 0.0, 1.0);
    t_light = 0.0;
    solid_angle = 0.0;
    if (d2 <= r2)
        return false;
    solid_angle = given.x < 0.0 ? sphere_light_toward(light, o, wi, t_light)
                                : sphere_light_toward_at(light, o, given, wi, t_light);
    return true;
}

// Next-event estimation towards one light from o: the direction wi, the distance t_light to
// the light along it (NS_INF for a directional one) and the light's contribution before the
// shadow ray's transmittance (weight); false where the light cannot reach o. The caller
// traces one shadow ray for every kind of light: lavapipe inlines every call, so each
// transmittance() call site is another copy of the traversal for its compiler (the pt
// pipeline took 2.4 s to make with one per kind, 1.2 s with one; docs/rendering.md). The
// expressions are the ones each kind always had: the images are the same bit for bit.
//
// toward_light: the direction and distance, and what the weights need: a point light's
// squared distance d2, a sphere light's solid angle (uniform in the cone it subtends: pdf
// 1 / solid angle). Directional, point and sphere lights; false for any other kind. `given`:
// a sphere light's two numbers, or DRAW_NUMBERS.
bool toward_light(GpuLight light, vec3 o, vec2 given, out vec3 wi, out float t_light, out float d2,
                  out float solid_angle)
{
    uint kind = light.info.x;
    wi = vec3(0.0, 0.0, 1.0);
    t_light = 0.0;
    d2 = 1.0;
    solid_angle = 0.0;
    if (kind == NS_GPU_LIGHT_DIRECTIONAL) {
        wi = -light.direction.xyz;
        t_light = NS_INF;
        return true;
    }
    if (kind == NS_GPU_LIGHT_POINT) {
        vec3 v = light.position.xyz - o;
        d2 = dot(v, v);
        t_light = sqrt(d2);
        wi = v / t_light;
        return true;
    }
    return kind == NS_GPU_LIGHT_SPHERE &&
           sample_sphere_light(light, o, given, wi, t_light, solid_angle);
}

// lambert_light: into a Lambertian surface of unit reflectance with normal n at o.
bool lambert_light(GpuLight light, vec3 o, vec3 n, vec2 given, out vec3 wi, out float t_light,
                   out vec3 weight)
{
    float d2, solid_angle;
    bool reaches = toward_light(light, o, given, wi, t_light, d2, solid_angle);
    float c = dot(n, wi);
    uint kind = light.info.x;
    weight = kind == NS_GPU_LIGHT_POINT    ? light.color.rgb * (c / (PI * d2))
           : kind == NS_GPU_LIGHT_SPHERE ? light.color.rgb * (c / PI) * solid_angle
                                          : light.color.rgb * (c / PI);
    return reaches && c > 0.0;
}

// phase_light: scattered at o towards d (the direction the path arrived in) by a
// Henyey-Greenstein phase function of asymmetry g.
bool phase_light(GpuLight light, vec3 o, vec3 d, float g, out vec3 wi, out float t_light,
                 out vec3 weight)
{
    float d2, solid_angle;
    bool reaches = toward_light(light, o, DRAW_NUMBERS, wi, t_light, d2, solid_angle);
    float phase = hg_phase(dot(d, wi), g);
    uint kind = light.info.x;
    weight = kind == NS_GPU_LIGHT_POINT    ? light.color.rgb * (phase / d2)
           : kind == NS_GPU_LIGHT_SPHERE ? light.color.rgb * phase * solid_angle
                                          : light.color.rgb * phase;
    return reaches;
}

// A free-flight distance in a medium of extinction st for spectral MIS: one channel picked
// uniformly, then an exponential distance in that channel (infinite where it is clear).
// The caller weights an event at distance t by e^{-st t} sigma_s / mean(st e^{-st t}), the
// one-sample balance heuristic over the three channels' pdfs, which keeps every channel
// unbiased however different their extinctions are.
float free_flight(vec3 st)
{
    float u_channel = rnd();
    float st_c = u_channel < 1.0 / 3.0 ? st.x : (u_channel < 2.0 / 3.0 ? st.y : st.z);
    return st_c > 0.0 ? -log(1.0 - rnd()) / st_c : NS_INF;
}
#endif

#if defined(NS_COMMON_TRACE) && defined(NS_COMMON_LIGHTS)
// Where lambert_direct's numbers come from. pt.comp: one sample of each light from rng_state
// (first = NS_NONE). camera.comp: `samples` of each sphere light and of the environment, from
// points first .. first + samples - 1 of the R2 sequence, shifted by the pixel's `shift` plus
// one constant per light. A camera sample's points follow the previous sample's in its pixel,
// so that a pixel's spp * samples directions towards each light and the environment are
// spread evenly: the noise of soft shadows and of the environment's occlusion, which is most
// of what the surface image's noise is, falls faster than with independent draws. The
// diffuse surfaces that one camera sample's Fresnel branches end on take the same points:
// correlated, each still unbiased. camera.comp's position in the pixel is an R2 point of the
// sample index too, so within a pixel a sample's light numbers are a fixed (linear, mod 1)
// function of its position; each sample is still uniform in every dimension (independent
// shifts), and decoupling them (radical inverses for the lights) moved the surface images
// by 0.2 dB at most (docs/bench.md, *Camera samples spread evenly*): not worth a second
// sequence.
struct DirectNumbers {
    uint samples;
    uint first;
    uvec2 shift;
};

const DirectNumbers DIRECT_FROM_STREAM = DirectNumbers(1u, NS_NONE, uvec2(0u));

// Radiance leaving a Lambertian surface of reflectance rho at p (n faces the viewer) from
// every light, `numbers.samples` shadow rays each (`how` as transmittance's), the
// environment's along as many cosine-distributed directions, whose pdf cancels the cosine and
// 1/pi of the BRDF. The environment is one more turn of the lights' loop, so that every
// shadow ray leaves from one call site (lambert_light); out of budget, the lights stop and
// the environment still counts, as it always did.
vec3 lambert_direct(vec3 p, vec3 n, vec3 rho, uint medium, uint how, DirectNumbers numbers)
{
    vec3 o = p + n * ray_epsilon(p);
    vec3 sum = vec3(0.0);
    uint count = params.counts.y;
    bool environment = params.environment.r + params.environment.g + params.environment.b > 0.0;
    uint turns = count + 1u;
    for (uint k = 0u; k < numbers.samples * turns; k++) {
        uint i = k % turns;
        if (i < count && out_of_budget()) {
            k += count - i; // the lights stop here: on to the environment
            i = count;
        }
        // A light other than a sphere has no numbers to draw (a point, a direction): its one
        // shadow ray, in the first turn, counts for all of them.
        float copies = 1.0;
        if (i < count && lights[i].info.x != NS_GPU_LIGHT_SPHERE) {
            if (k >= turns)
                continue;
            copies = float(numbers.samples);
        }
        vec2 given = DRAW_NUMBERS;
        if (numbers.first != NS_NONE)
            given = r2_point(numbers.first + k / turns,
                             numbers.shift + uvec2(i * 0x9e3779b9u, i * 0x85ebca6bu));
        vec3 wi, weight;
        float t_light;
        bool lit;
        if (i < count) {
            lit = lambert_light(lights[i], o, n, given, wi, t_light, weight);
            weight *= copies;
        } else {
            lit = environment;
            wi = n;
            if (environment)
                wi = given.x < 0.0 ? cosine_sample(n) : cosine_sample_at(n, given.x, given.y);
            t_light = NS_INF;
            weight = params.environment.rgb;
        }
        if (lit)
            sum += weight * transmittance(o, wi, t_light, medium, how);
    }
    return rho * sum / float(numbers.samples);
}

// The nearest sphere light along the ray before tmax, with which = NS_NONE when there is
// none. Sphere lights are seen by camera rays but are not scene geometry: they cast no
// shadows.
float hit_sphere_lights(vec3 o, vec3 d, float tmax, out uint which)
{
    which = NS_NONE;
    float best = tmax;
    for (uint i = 0u; i < params.counts.y; i++) {
        if (lights[i].info.x != NS_GPU_LIGHT_SPHERE)
            continue;
        float t = hit_sphere(o, d, lights[i].position, 0.0, best);
        if (t > 0.0) {
            best = t;
            which = i;
        }
    }
    return best;
}
#endif
