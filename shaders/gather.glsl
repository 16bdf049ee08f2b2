// gather.glsl — the gather shader's body, compiled once per form: NS_GATHER_FORM (the
// NS_GATHER_MODE_* it evaluates) and NS_BOUNDED_BEAMS (0 endless, 1 bounded) are defined by
// gather.comp (exact, endless: the default), gather_bounded.comp, gather_paper.comp,
// gather_paper_bounded.comp and gather_dipole.comp, and with NS_GATHER_FIRST_ORDER (the
// boundary sources' blurred first order computed, first_order) gather_exact_first.comp (the
// default form plus it) and gather_first.comp (it alone). One shader per form rather than branches
// on the uniform block: on lavapipe code that is present but never taken costs the loop
// dearly (register pressure in the vectorised walk): with the paper and dipole forms in it
// the exact gather ran 1.5-1.7x slower, with the bounded form too 1.5x slower again
// (docs/scattering.md, *One shader per form*).
//
// gather — double and multiple scattering gathered from Virtual Ray Lights (the paper's
// Algorithm 1): one invocation per camera segment walks the grid hierarchy's nodes of one
// dispatch's range, skips nodes beyond the table's reach, and sums the contribution of each VRL
// through the accumulated table A (DESIGN.md section 2):
//     L += P s^2 [A(x_entry) - e^{-s Lc} A(x_exit)]      per channel, in the VRL's frame,
// or the paper's 5-mfp form W A5(x_entry), or (dipole mode) P R_d(|x_entry - origin|) / pi.
// With bounded beams (render.vrl_beams; gather_bounded.comp) a VRL is a stretch of length
// L_v, not the endless beam the tables assume: the beam that would go on past its exit
// (power e^{-s L_v} P, from origin + L_v d) is subtracted with the same tables (DESIGN.md's
// definition is linear in the source), unless it is below table_map.w in every channel.
// The result is the radiance arriving at the segment's entry from inside the medium, before
// the segment's throughput (render.c composes it). render/gather.c has the same sum in C.
#ifndef NS_GATHER_FIRST_ORDER
#define NS_GATHER_FIRST_ORDER 0
#endif
#extension GL_KHR_shader_subgroup_vote : require
#extension GL_KHR_shader_subgroup_ballot : require
#include "shared.h"
#include "scatter_shared.h"

layout(local_size_x = NS_GATHER_GROUP) in;

layout(std140, binding = 0) uniform ParamBlock { GpuGatherParams ns_params[1]; };
#define params ns_params[NS_OPAQUE_ZERO] /* shared.h: NS_OPAQUE_ZERO */
layout(std430, binding = 1) readonly buffer SegmentBlock { GpuSegment segments[]; };
layout(std430, binding = 2) readonly buffer NodeBlock { GpuVrlNode nodes[]; };
// GpuVrl read as three vec4 (origin + length, direction + material, power + events), as in
// vrl_gather.comp: glslang takes `vrl.length` for the length() method.
layout(std430, binding = 3) readonly buffer RepresentativeBlock { vec4 representative_words[]; };
layout(std430, binding = 4) readonly buffer VrlBlock { vec4 vrl_words[]; };
// The table A as a texel buffer of floats (render/pipelines.c; a storage texel buffer, like
// every texel binding, docs/bench.md *Storage texel buffers*): its reads are at per-lane
// addresses, which lavapipe serves one lane at a time from a storage buffer and as a texel
// load from a texel buffer, 1.7-1.9x faster over the whole gather.
layout(binding = 5, r32ui) uniform readonly restrict uimageBuffer table_texels;
layout(std430, binding = 6) buffer OutBlock { vec4 radiance[]; };
layout(std430, binding = 7) buffer CounterBlock { uint counters[]; };
layout(push_constant) uniform PushBlock { GpuGatherPush ns_push[1]; };
#define push ns_push[NS_OPAQUE_ZERO]

#include "common.glsl"

struct Vrl {
    vec3 origin;
    float len; // 0: no exit was found, the beam is endless
    vec3 direction;
    vec3 power;
    float face_cos; // a boundary source's line against the face it starts on (0: none known)
};

// The face bits of a source's events word (scatter_shared.h, NS_VRL_FACE_COS_SHIFT).
float face_cos_of(float events_word)
{
    uint q = (floatBitsToUint(events_word) >> NS_VRL_FACE_COS_SHIFT) & NS_VRL_FACE_COS_MAX;
    return float(q) * (1.0 / float(NS_VRL_FACE_COS_MAX));
}

Vrl vrl_at(uint k)
{
    vec4 power = vrl_words[3u * k + 2u];
    return Vrl(vrl_words[3u * k].xyz, vrl_words[3u * k].w, vrl_words[3u * k + 1u].xyz, power.xyz,
               face_cos_of(power.w));
}

// A representative stands for several sources: no one face.
Vrl representative_at(uint k)
{
    return Vrl(representative_words[3u * k].xyz, representative_words[3u * k].w,
               representative_words[3u * k + 1u].xyz, representative_words[3u * k + 2u].xyz, 0.0);
}

const float ANGLE_BINS_PER_RADIAN = float(NS_TABLE_NTHETA) / PI; // theta and phi: 10 degrees

// The table is read between its cells (issue 15: nearest-cell reads were 5-10% off near the
// source and drew stair-step bands across the multiple-scattering image; docs/scattering.md,
// *Reading the table between cells*). accumulate.comp computes A at every cell's centre, so
// each coordinate is taken as a continuous index whose integers are the centres: linear
// interpolation between the centres around the point in asinh(z), asinh(rho) and theta
// (on a tetrahedron of the cube of 8 cells, table_at), and a bin's value held beyond its
// centre at the grid's ends (the axis rho = 0, the poles of theta, the extent). In z the two cells may lie on either side of the plane z = 0 (the
// table's z has a sign: bins below and above the source), which is where A is continuous. phi
// is read at the nearest bin. tests/oracles/gather_cpu.c does the same arithmetic in C.

// The lower of the two theta rows (bin times the phi bin count) around light along w seen from
// a VRL of axis d, and in t the weight of the upper one: the same at every point of the VRL.
// t is linear in theta between the two bins' centres. Not in cos theta: the rows hold each
// bin's mean over its solid angle, and a forward lobe read linearly in cos theta spreads the
// first bin's peak over the second, whose solid angle is three times larger: an HG lobe held
// that way carries 2.7% too much energy at g 0.7 and 12% at g 0.9 (0.9% and 4.1% linear in
// theta), which showed as double scattering 6-9% high at g 0.9 (docs/scattering.md, *Theta
// read linearly in theta*). theta - theta_i comes from its sine, sin theta cos theta_i -
// cos theta sin theta_i, and a series for asin (|theta - theta_i| < 0.27 rad: its next term
// is below 2e-7), not from acos: lavapipe's acos is a polynomial about 1e-4 rad off (it only
// picks the pair, where an error moves t by as much past 0 or 1, which the clamp takes back).
uint theta_row(vec3 w, vec3 d, out float t)
{
    float cos_theta = clamp(dot(w, d), -1.0, 1.0);
    float f = acos(cos_theta) * ANGLE_BINS_PER_RADIAN - 0.5;
    uint i = min(uint(max(f, 0.0)), NS_TABLE_NTHETA - 2u);
    float theta_i = (float(i) + 0.5) / ANGLE_BINS_PER_RADIAN;
    float sin_theta = sqrt(max(1.0 - cos_theta * cos_theta, 0.0));
    float x = sin_theta * cos(theta_i) - cos_theta * sin(theta_i), x2 = x * x;
    float past_i = x * (1.0 + x2 * (1.0 / 6.0 + x2 * (3.0 / 40.0 + x2 * (5.0 / 112.0))));
    t = clamp(past_i * ANGLE_BINS_PER_RADIAN, 0.0, 1.0);
    return i * NS_TABLE_NPHI;
}

// The phi bin at a point whose radial unit vector is e_rho (mirror-symmetric about it).
uint phi_bin(vec3 w, vec3 d, vec3 e_rho)
{
    vec3 w_perp = w - dot(w, d) * d;
    float perp = length(w_perp);
    float cos_phi = perp > 1e-6 ? clamp(dot(w_perp, e_rho) / perp, -1.0, 1.0) : 1.0;
    return min(uint(acos(cos_phi) * ANGLE_BINS_PER_RADIAN), NS_TABLE_NPHI - 1u);
}

const uint TABLE_DIRS = NS_TABLE_NTHETA * NS_TABLE_NPHI;
// A step of one cell along each axis of the interpolation, in table entries.
const uint STEP_Z = NS_TABLE_NRHO * TABLE_DIRS, STEP_RHO = TABLE_DIRS, STEP_THETA = NS_TABLE_NPHI;

// One corner of the interpolation, per channel: the table at index base + offset of each
// channel's slice (the texels hold the floats' bits).
vec3 table_corner(uvec3 base, uvec3 offset)
{
    uvec3 i = base + offset;
    return vec3(uintBitsToFloat(imageLoad(table_texels, int(i.x)).x),
                uintBitsToFloat(imageLoad(table_texels, int(i.y)).x),
                uintBitsToFloat(imageLoad(table_texels, int(i.z)).x));
}

// A at point p for light arriving along w, per channel, in mfp units; row (the lower theta
// row) and theta_t from theta_row. 0 beyond the table's extent. Vector arithmetic over the
// channels, no loop (lavapipe counts loops).
//
// Between the 8 cells around the point (z, rho, theta) the value is the linear interpolation
// on one of the cube's 6 tetrahedra (Kuhn's triangulation: the path from the lower corner to
// the upper one that steps along the axes in decreasing order of the fractions), 4 reads per
// channel instead of trilinear's 8: on lavapipe each read is paid lane by lane and the
// reads are most of the gather's time (docs/scattering.md, *Reading the table between cells*).
// Continuous, exact for a linear A, of the same order of accuracy as trilinear.
vec3 table_at(Vrl v, vec3 p, vec3 w, uint row, float theta_t)
{
    vec3 delta = p - v.origin;
    float z = dot(delta, v.direction);
    vec3 radial = delta - z * v.direction;
    float rho = length(radial);
    // On the axis any radial direction is as good: the phi bins all meet there.
    vec3 e_rho = rho > 0.0 ? radial / rho : vec3(0.0);
    uint phi = phi_bin(w, v.direction, e_rho);
    vec3 s = params.sigma_t.xyz;
    vec3 z_mfp = z * s, rho_mfp = rho * s;
    float scale = params.table_map.x, inv_step = params.table_map.y, extent = params.table_map.z;
    vec3 fz = clamp(asinh(z_mfp / scale) * inv_step + (float(NS_TABLE_NZ / 2u) - 0.5), 0.0,
                    float(NS_TABLE_NZ - 1u));
    vec3 fr = clamp(asinh(rho_mfp / scale) * inv_step - 0.5, 0.0, float(NS_TABLE_NRHO - 1u));
    uvec3 iz = min(uvec3(fz), uvec3(NS_TABLE_NZ - 2u));
    uvec3 ir = min(uvec3(fr), uvec3(NS_TABLE_NRHO - 2u));
    vec3 tz = fz - vec3(iz), tr = fr - vec3(ir), tt = vec3(theta_t);
    uvec3 base = (iz * NS_TABLE_NRHO + ir) * TABLE_DIRS + uvec3(0u, 1u, 2u) * NS_TABLE_CELLS + (row + phi);
    // The order of the three fractions per channel, ties to z, then rho (a strict order).
    bvec3 z_rho = greaterThanEqual(tz, tr), z_theta = greaterThanEqual(tz, tt), rho_theta = greaterThanEqual(tr, tt);
    bvec3 z_first = bvec3(uvec3(z_rho) & uvec3(z_theta));
    bvec3 rho_first = bvec3(uvec3(not(z_rho)) & uvec3(rho_theta));
    bvec3 theta_last = bvec3(uvec3(z_theta) & uvec3(rho_theta));
    bvec3 rho_last = bvec3(uvec3(z_rho) & uvec3(not(rho_theta)));
    uvec3 first = mix(mix(uvec3(STEP_THETA), uvec3(STEP_RHO), rho_first), uvec3(STEP_Z), z_first);
    uvec3 last = mix(mix(uvec3(STEP_Z), uvec3(STEP_RHO), rho_last), uvec3(STEP_THETA), theta_last);
    const uint all_steps = STEP_Z + STEP_RHO + STEP_THETA;
    vec3 t_max = max(tz, max(tr, tt)), t_min = min(tz, min(tr, tt));
    vec3 t_mid = tz + tr + tt - t_max - t_min;
    vec3 value = (1.0 - t_max) * table_corner(base, uvec3(0u)) + (t_max - t_mid) * table_corner(base, first) +
                 (t_mid - t_min) * table_corner(base, uvec3(all_steps) - last) +
                 t_min * table_corner(base, uvec3(all_steps));
    vec3 inside = vec3(lessThan(max(abs(z_mfp), rho_mfp), vec3(extent)));
    return inside * value;
}

vec3 dipole_rd(float r)
{
    vec3 r2 = vec3(r * r);
    vec3 dr = sqrt(r2 + params.dipole_zr.xyz * params.dipole_zr.xyz);
    vec3 dv = sqrt(r2 + params.dipole_zv.xyz * params.dipole_zv.xyz);
    vec3 str = params.dipole_sigma_tr.xyz;
    vec3 real_source = params.dipole_zr.xyz * (str * dr + 1.0) * exp(-str * dr) / (dr * dr * dr);
    vec3 virtual_source = params.dipole_zv.xyz * (str * dv + 1.0) * exp(-str * dv) / (dv * dv * dv);
    return params.dipole_alpha.xyz / (4.0 * PI) * (real_source + virtual_source);
}

// exit_matters: e^{-s Lc} is above float resolution in some channel, so A(exit) counts.
// The segment's table value for an endless beam from `origin` along v's direction.
vec3 beam_value(Vrl v, GpuSegment seg, vec3 w, uint row, float theta_t, vec3 segment_attenuation,
                vec3 paper_weight, bool exit_matters)
{
    if (NS_GATHER_FORM == NS_GATHER_MODE_PAPER)
        return paper_weight * table_at(v, seg.entry, w, row, theta_t);
    vec3 value = table_at(v, seg.entry, w, row, theta_t);
    if (exit_matters)
        value -= segment_attenuation * table_at(v, seg.exit, w, row, theta_t);
    return value;
}

#if NS_GATHER_FIRST_ORDER
// e^{x^2} erfc(x) for x >= 0: Abramowitz & Stegun 7.1.26 below 2 (|erfc error| < 1.5e-7),
// Laplace's continued fraction above (relative error below 1e-5).
float erfcx_positive(float x)
{
    if (x < 2.0) {
        float t = 1.0 / (1.0 + 0.3275911 * x);
        return t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429))));
    }
    // Written out: a loop here would count against lavapipe's loop budget, which the gather's
    // dispatches fill at NS_GATHER_ITERATIONS_PER_VRL per source (scatter_shared.h). The
    // fraction x + 5 / (x + 4.5 / (... x + 0.5 / x)), folded from the inside out, carried as
    // numerator n over denominator d (each step n <- x n + a d, d <- n), both scaled by 1 / x
    // each step so that they stay near 1 and x: two divisions instead of ten (lavapipe runs
    // both sides of the branch above for a lane group that disagrees on it).
    x = min(x, 1e18); // erfcx is 0 to float there; the scaling keeps an infinite x finite
    float inv = 1.0 / x;
    float n = x + 5.0 * inv, d = 1.0, m;
    m = n; n = n + 4.5 * d * inv; d = m * inv;
    m = n; n = n + 4.0 * d * inv; d = m * inv;
    m = n; n = n + 3.5 * d * inv; d = m * inv;
    m = n; n = n + 3.0 * d * inv; d = m * inv;
    m = n; n = n + 2.5 * d * inv; d = m * inv;
    m = n; n = n + 2.0 * d * inv; d = m * inv;
    m = n; n = n + 1.5 * d * inv; d = m * inv;
    m = n; n = n + 1.0 * d * inv; d = m * inv;
    m = n; n = n + 0.5 * d * inv; d = m * inv;
    return d / (sqrt(PI) * n);
}

// One channel of a source's first order seen along a segment: the integral over t in [0, L]
// (with z(t) = z0 + c t > 0) of e^{-s t} e^{-s z(t)} K(rho(t)), K the tube's normalised
// Gaussian of standard deviation b, on the segment x0 + t d of a source at o along u, where
// rho^2(t) = |r0 + t r1|^2 = C + 2 B t + A t^2 (r0, r1: the offset's and the direction's
// parts across u; A = sin^2 theta). The exponent is quadratic in t: its Gaussian integrates
// in closed form (erf, scaled by its largest value within the range so that nothing
// overflows), and where the Gaussian hardly bends over the range (lines nearly parallel) the
// exponent is taken as the secant between the range's ends. rho^2 is taken from the vector
// at each point where it is read: C + 2 B t + A t^2 near the closest approach is a
// difference of terms the size of the offset's square, whose float rounding a tube a
// hundredth of that wide reads as a 1% error (gpu_gather's narrow tubes).
// gpu_gather checks it against a quadrature of the definition.
float first_order_channel(float z0, float c, float A, float B, vec3 r0, vec3 r1, float lo, float hi,
                          float s, float b)
{
    if (!(s > 0.0 && b > 0.0))
        return 0.0; // a channel without extinction scatters nothing (its tube would be 0 wide)
    float two_b2 = 2.0 * b * b;
    float k = sqrt(A / two_b2), span = hi - lo;
    vec3 q_lo = r0 + lo * r1, q_hi = r0 + hi * r1;
    float e_lo = -s * (lo + z0 + c * lo) - dot(q_lo, q_lo) / two_b2;
    float e_hi = -s * (hi + z0 + c * hi) - dot(q_hi, q_hi) / two_b2;
    if (k * span < 1e-2) {
        float top = max(e_lo, e_hi), drop = min(e_lo, e_hi) - top;
        float g = drop > -1e-4 ? span : span * (1.0 - exp(drop)) / -drop;
        return exp(top) * g / (PI * two_b2);
    }
    float centre = -(B + 0.5 * two_b2 * s * (1.0 + c)) / A; // the Gaussian's centre in t
    float u_lo = (lo - centre) * k, u_hi = (hi - centre) * k;
    // The range after the centre (u_lo >= 0), before it (u_hi <= 0) or around it, each from
    // erfcx at |u_lo| and |u_hi|, picked by selects: lavapipe runs every branch of a lane
    // group whose lanes disagree, so three cases of two erfcx each cost six.
    float x_lo = erfcx_positive(abs(u_lo)), x_hi = erfcx_positive(abs(u_hi));
    bool after = u_lo >= 0.0, before = u_hi <= 0.0;
    float d2 = u_lo * u_lo - u_hi * u_hi, beyond = exp(after ? d2 : -d2);
    float side = after ? x_lo - beyond * x_hi : x_hi - beyond * x_lo;
    float around = 2.0 - exp(-u_hi * u_hi) * x_hi - exp(-u_lo * u_lo) * x_lo;
    float bracket = after || before ? side : around;
    float t_top = after ? lo : (before ? hi : centre);
    vec3 q_top = r0 + t_top * r1;
    float e_top = -s * (t_top + z0 + c * t_top) - dot(q_top, q_top) / two_b2;
    return exp(e_top) * 0.5 * sqrt(PI) / k * max(bracket, 0.0) / (PI * two_b2);
}

// The blurred first order J_1^blur = a e^{-z} [z > 0] K(rho) p_HG(cos theta) of a source
// (boundary.h) along a segment, as the table form's P s^2 A would give it read exactly: the
// light it scatters once towards the camera from a Gaussian tube around its line. Read from
// a table, its angular factor (p_HG over 10-degree bins) and its spatial one (1 / sin theta
// across the tube) are both convex in theta between the bins' centres and poorly sampled
// across a tube narrower than the first rho bins: at g 0.9 the reads missed their
// definition by factors of 0.3 to 2 (gpu_gather), and light reflected inside a thin object
// before it scattered read 2% high in single scattering, its multiple scattering 54% high
// (docs/bench.md, *The blurred first order computed*). The source's line is endless here too
// (its chord, v.len where known, sets the tube's width only): past the chord's end it leaves
// a convex object, and the ghost that would take that part away keeps no first order there
// (boundary.c; where the line returns into its medium the ghost keeps it, with the same
// chord and so the same tube); cutting the line at the chord's end moved a thin sphere's
// multiple scattering by 3 points where the tube's width moved it by 30. A source whose
// chord is not known (length 0) keeps the widest tube.
vec3 first_order(Vrl v, GpuSegment seg)
{
    vec3 d = seg.direction, u = v.direction, off = seg.entry - v.origin;
    float z0 = dot(off, u), c = dot(d, u);
    vec3 r0 = off - z0 * u, r1 = d - c * u; // across the source's line
    // A from the vector too: 1 - c^2 loses a tenth of itself to rounding at A ~ 1e-6.
    float A = dot(r1, r1), B = dot(r0, r1), C = dot(r0, r0);
    float lo = 0.0, hi = distance(seg.entry, seg.exit);
    if (c > 0.0)
        lo = max(lo, -z0 / c);
    else if (c < 0.0)
        hi = min(hi, -z0 / c);
    else if (z0 <= 0.0)
        return vec3(0.0);
    // The tube: narrower around a short chord (scatter_shared.h, NS_FIRST_BLUR_PER_CHORD).
    vec3 b = params.first_blur.xyz;
    if (v.len > 0.0)
        b = clamp(vec3(NS_FIRST_BLUR_PER_CHORD * v.len), NS_FIRST_BLUR_FLOOR * b, b);
    // Nothing within ~9 tubes' widths of the line in any channel: nothing to add.
    float b_max = max(b.x, max(b.y, b.z));
    float closest = A > 1e-8 ? C - B * B / A : C;
    if (!(hi > lo) || closest > 80.0 * b_max * b_max)
        return vec3(0.0);
    float g = params.first_order.w, cos_theta = -c; // emitted towards the camera
    float phase = (1.0 - g * g) / (4.0 * PI * pow(max(1.0 + g * g - 2.0 * g * cos_theta, 1e-12), 1.5));
    vec3 s = params.sigma_t.xyz;
    vec3 value = vec3(first_order_channel(z0, c, A, B, r0, r1, lo, hi, s.x, b.x),
                      first_order_channel(z0, c, A, B, r0, r1, lo, hi, s.y, b.y),
                      first_order_channel(z0, c, A, B, r0, r1, lo, hi, s.z, b.z));
    if (v.face_cos > 0.0) {
        // A beam that starts on a face (a reflected one) has part of its tube beyond that
        // face near its start, where no camera segment reads it: at depth z along a line at
        // angle beta to the face's normal, the face cuts the tube's cross-section z cot beta
        // from its axis, and the medium's side holds Phi(z cot beta / b) of the tube. The tube
        // is taken as renormalised to that side (a boundary-corrected kernel), its share read
        // where the segment passes closest to the line: what the tube lost comes back where
        // it was lost, without a source more (docs/scattering.md, *The tube renormalised at
        // its face*).
        float t_close = A > 1e-8 ? clamp(-B / A, lo, hi) : lo;
        float z_close = max(z0 + c * t_close, 0.0);
        float cot_beta = v.face_cos / sqrt(max(1.0 - v.face_cos * v.face_cos, 1e-12));
        vec3 depth = z_close * cot_beta / max(b, vec3(1e-30)) * (1.0 / sqrt(2.0));
        value /= vec3(1.0 - 0.5 * exp(-depth.x * depth.x) * erfcx_positive(depth.x),
                      1.0 - 0.5 * exp(-depth.y * depth.y) * erfcx_positive(depth.y),
                      1.0 - 0.5 * exp(-depth.z * depth.z) * erfcx_positive(depth.z));
    }
    return v.power * params.first_order.xyz * s * phase * value;
}
#endif

vec3 table_contribution(Vrl v, GpuSegment seg, vec3 w, vec3 segment_attenuation, vec3 paper_weight,
                        bool exit_matters)
{
    if (NS_GATHER_FORM == NS_GATHER_MODE_DIPOLE)
        return v.power * dipole_rd(distance(seg.entry, v.origin)) / PI;
    vec3 s = params.sigma_t.xyz;
    float theta_t;
    uint row = theta_row(w, v.direction, theta_t);
    vec3 value = beam_value(v, seg, w, row, theta_t, segment_attenuation, paper_weight, exit_matters);
#if NS_BOUNDED_BEAMS
    vec3 beam_attenuation = exp(-s * v.len);
    if (v.len > 0.0 && max(beam_attenuation.x, max(beam_attenuation.y, beam_attenuation.z)) > params.table_map.w) {
        Vrl beyond = v;
        beyond.origin = v.origin + v.len * v.direction;
        value -= beam_attenuation * beam_value(beyond, seg, w, row, theta_t, segment_attenuation, paper_weight, exit_matters);
        // The tables' reads in two frames (interpolated between cells, each with its own
        // discretisation error) can cross where the exact difference is ~0.
        value = max(value, vec3(0.0));
    }
#endif
    return v.power * s * s * value;
}

// A source's part: through the table, plus its blurred first order where the form computes
// it (gather_exact_first.comp: in the same walk over the sources), or that alone
// (gather_first.comp).
vec3 contribution(Vrl v, GpuSegment seg, vec3 w, vec3 segment_attenuation, vec3 paper_weight,
                  bool exit_matters)
{
#if NS_GATHER_FIRST_ORDER
    vec3 first = first_order(v, seg);
    if (NS_GATHER_FORM == NS_GATHER_MODE_FIRST)
        return first;
    return first + table_contribution(v, seg, w, segment_attenuation, paper_weight, exit_matters);
#else
    return table_contribution(v, seg, w, segment_attenuation, paper_weight, exit_matters);
#endif
}

// Lower bound of the distance between the segment's bounding box and a cell's box.
float box_distance(vec3 amin, vec3 amax, vec3 bmin, vec3 bmax)
{
    vec3 gap = max(vec3(0.0), max(amin - bmax, bmin - amax));
    return length(gap);
}

void main()
{
    uint index = push.first_segment + gl_GlobalInvocationID.x;
    if (gl_GlobalInvocationID.x >= params.counts.x)
        return;
    GpuSegment seg = segments[index];
    vec3 w = -seg.direction; // light travels towards the camera
    float length_c = distance(seg.entry, seg.exit);
    vec3 s = params.sigma_t.xyz;
    vec3 segment_attenuation = exp(-s * length_c);
    vec3 paper_weight = (1.0 - segment_attenuation) / (1.0 - exp(-float(NS_PAPER_ACCUMULATION_MFP)));
    // A(entry) integrates through the exit, so e^{-s Lc} A(exit) <= A(entry) always; past
    // ~17 mfp in every channel that term is a 6e-8 fraction of A(exit), far below what the
    // other VRLs add, and it is not read (half the work on long segments).
    bool exit_matters = max(segment_attenuation.x, max(segment_attenuation.y, segment_attenuation.z)) > 6e-8;
    vec3 smin = min(seg.entry, seg.exit), smax = max(seg.entry, seg.exit);
    // Dipole mode: only segments that enter from outside see the dipole (render.c gives
    // the others no light), evaluated at their entry point.
    bool dipole = NS_GATHER_FORM == NS_GATHER_MODE_DIPOLE;
    if (dipole)
        smax = smin = seg.entry;

    vec3 sum = vec3(0.0);
    uint interactions = 0u, culled = 0u, represented = 0u;
    uint end = min(push.first_cell + push.cell_count, params.counts.y);
    uint ci = push.first_cell;
    if (params.cull.y == 0.0) {
        // Exact: one walk per subgroup. A node goes with its subtree when it is beyond the
        // table's reach of every segment of the subgroup; a segment that alone would have
        // culled it evaluates VRLs whose tables do not reach it and adds exactly zero. The
        // node index is then the same in every invocation, and broadcast makes that known:
        // lavapipe loads the node and the leaf's VRLs once for all lanes instead of
        // gathering them per lane (2x the interactions per second of a per-lane walk).
        while (ci < end) {
            ci = subgroupBroadcastFirst(ci);
            GpuVrlNode node = nodes[ci];
            float gap = box_distance(smin, smax, node.bmin, node.bmax);
            if (subgroupAll(gap > params.cull.x)) {
                culled++;
                ci = node.skip;
                continue;
            }
            if (node.leaf == 0u) {
                ci++;
                continue;
            }
            for (uint k = node.first; k < node.first + node.count; k++)
                sum += contribution(vrl_at(k), seg, w, segment_attenuation, paper_weight, exit_matters);
            interactions += node.count;
            ci = node.skip;
        }
    } else {
        // Solid-angle option: every segment takes its own decisions (neighbours refine
        // different nodes), but the subgroup still walks one node at a time so that the
        // loads stay uniform: a lane that culled or represented a node sits out its subtree
        // (mask_until), and the walk descends while any lane still needs the node. Each
        // lane thus sees exactly the nodes of its own walk (ns_gather_cpu walks each segment
        // alone and gets the same sums and counts), without a per-lane node index, which
        // made lavapipe gather every node and VRL load lane by lane.
        uint mask_until = 0u;
        while (ci < end) {
            ci = subgroupBroadcastFirst(ci);
            GpuVrlNode node = nodes[ci];
            bool needs = ci >= mask_until;
            if (needs) {
                float gap = box_distance(smin, smax, node.bmin, node.bmax);
                // The box's solid angle seen from the segment's nearest point, bounded by
                // the sphere around its diagonal.
                vec3 extent = node.bmax - node.bmin;
                float radius2 = 0.25 * dot(extent, extent);
                if (gap > params.cull.x) {
                    culled++;
                    mask_until = node.skip;
                    needs = false;
                } else if (gap * gap > radius2 && PI * radius2 / (gap * gap) < params.cull.y) {
                    sum += contribution(representative_at(ci), seg, w, segment_attenuation, paper_weight, exit_matters);
                    represented++;
                    interactions++;
                    mask_until = node.skip;
                    needs = false;
                }
            }
            if (!subgroupAny(needs)) {
                ci = node.skip;
                continue;
            }
            if (node.leaf == 0u) {
                ci++;
                continue;
            }
            if (needs) {
                for (uint k = node.first; k < node.first + node.count; k++)
                    sum += contribution(vrl_at(k), seg, w, segment_attenuation, paper_weight, exit_matters);
                interactions += node.count;
            }
            ci = node.skip;
        }
    }
    vec4 previous = push.accumulate != 0u ? radiance[index] : vec4(0.0);
    radiance[index] = previous + vec4(sum, 0.0);
    // 64-bit interaction count from 32-bit atomics: carry into the high word on wrap.
    uint before = atomicAdd(counters[NS_GATHER_COUNTER_INTERACTIONS], interactions);
    if (before + interactions < before)
        atomicAdd(counters[NS_GATHER_COUNTER_INTERACTIONS_HIGH], 1u);
    if (culled > 0u)
        atomicAdd(counters[NS_GATHER_COUNTER_CULLED], culled);
    if (represented > 0u)
        atomicAdd(counters[NS_GATHER_COUNTER_REPRESENTED], represented);
}
