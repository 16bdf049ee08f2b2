// accumulate.glsl — the camera-side table A of DESIGN.md section 2, per RGB channel:
//     A(x, w) = integral_0^inf e^{-u} J(x - u w, w) du        (mfp units)
// at the centre (rho, z, theta, phi) of every cell of the default grid (in phi the mean over
// the bin's lines, and on the source's plane for the two cells beside it: accumulate_shared.h).
// One invocation walks
// the straight line x - u w from one cell centre through the table's bins, exactly: J is
// constant inside a bin (it is the bin's average), so between two bin crossings the integral
// is J_bin (e^{-u0} - e^{-u1}), and the steps are the bins themselves — fine near the source
// where the sinh bins are fine, long far away where they are wide. The three channels share
// the walk (the geometry is in mfp, the same for every channel of the table).
//
// The walk in the cell's own frame: x = (rho0, 0, z0) with e_rho = +x, and
// w = (sin t cos p, sin t sin p, cos t). Along x - u w, theta stays t, z = z0 - u cos t, and
// in the horizontal plane the point moves along a line: with T(u) = rho0 cos p - u sin t (its
// coordinate along w's horizontal direction) and S = rho0 sin p (the constant distance of that
// line from the axis), rho(u) = sqrt(T^2 + S^2) and the local phi(u) (measured from e_rho at
// the point) satisfies cot phi = T / S: phi only grows, towards pi. So the next crossing is
//   z-plane      z0 - u cos t = edge                   (a plane)
//   rho-cylinder T(u)^2 + S^2 = edge^2                 (inward while T > 0, then outward)
//   phi-plane    T(u) = S cot(edge)                    (a half-plane through the axis)
// and the walk takes whichever comes first: at most 128 + 2 * 64 + 17 + 1 steps.
//
// Where to stop (exact mode). What is left after u is at most e^{-u} J_rest (the integral of
// e^{-u'} from u to infinity is e^{-u}), J_rest the largest J on the rest of the line: the
// remainder bound of its (theta, z, rho) bin (accumulate_shared.h), never above the table's
// peak J_max. The walk stops when that bound falls below cut.x (1e-4) times the larger of
// what it has gathered and a floor of cut.y (1e-10) J_max: the result is then within 1e-4
// relative of the whole integral, or within 1e-14 J_max absolute for cells so far from the
// light that A is below 1e-10 of the table's peak, values no render can show next to the
// light that made them. The bound comes from the table, not a fixed length: at low albedo J
// falls like e^{-r} away from the source, so the light reaching a far cell comes from near
// the source, up to ~32 mfp back, and a fixed short cut would lose it; and a line heading
// away from the source stops within a few bins, where the table's peak kept it going for
// many mfp. The walk also stops where it leaves the table (J is 0 outside). Paper mode
// (cut.z = 5): the integral over the first 5 mfp only, no other cut.
//
// Binding 0 params, 1 J (16-byte texels: [cells] of the three channels, then [cells] of the
// second three where they are walked, then the remainder bounds of each: accumulate_shared.h),
// 2 A out (float[3][cells]),
// 3 counters, 4 the second three's A.
//
// Two shaders include this file: accumulate.comp (NS_ACCUMULATE_SECOND 0) and
// accumulate_second.comp (1, the second three walked beside the rest). The default walk
// does not carry the second three's code: their live values cost a CPU without AVX-512
// (16 vector registers) 18% of the walk even where no lane adds them (the default scene's
// `accumulate`, five cold processes each: 2.52 s against 2.96 s, medians).
#include "shared.h"
#include "scatter_shared.h"
#include "accumulate_shared.h"

layout(local_size_x = NS_ACCUMULATE_GROUP) in;

layout(std140, binding = 0) uniform ParamBlock { GpuAccumulateParams ns_params[1]; };
#define params ns_params[NS_OPAQUE_ZERO] /* shared.h: NS_OPAQUE_ZERO */
// J as a texel buffer: lavapipe fetches texels through its texture path, where a storage
// buffer's per-lane reads are a loop over the lanes (docs/bench.md, *Texel buffers*). One
// 16-byte texel per cell holds the three channels (and 0), so a step reads one texel where
// it read one float per channel; the second three's texels follow (accumulate_shared.h).
layout(binding = 1, rgba32ui) uniform readonly restrict uimageBuffer j_texels;
vec4 j_at(uint i) { return uintBitsToFloat(imageLoad(j_texels, int(i))); }
layout(std430, binding = 2) writeonly buffer ABlock { float a[]; };
layout(std430, binding = 3) buffer CounterBlock { uint counters[]; };
layout(std430, binding = 4) writeonly buffer SecondBlock { float a_second[]; };
layout(push_constant) uniform PushBlock { GpuAccumulatePush ns_push[1]; };
#define push ns_push[NS_OPAQUE_ZERO]

#include "common.glsl"
const float ANGLE_STEP = PI / float(NS_TABLE_NTHETA); // theta and phi bins: 10 degrees
const float FAR = 3.0e38;
const float COT_STEP = 5.6712818196; // cot(10 degrees): cot(a + 10) = (cot a COT_STEP - 1) / (cot a + COT_STEP)
const int NZ = int(NS_TABLE_NZ), NRHO = int(NS_TABLE_NRHO), NPHI = int(NS_TABLE_NPHI);

// The z and rho edges are computed where they are needed, from the expression offline/mc.c's
// grid uses: a sinh costs less than a read of shared memory, which lavapipe makes one lane at
// a time, and the walk needs only one new edge per axis and step. The phi edges' cotangents
// follow from the last one by the addition formula (walk_line): 12% less time for the stage
// than reading them from shared memory (NSCATTER_BENCH_ACCUMULATE, 2026-11-29).
float z_edge(int i) { return params.grid.x * sinh(params.grid.y * float(i - NZ / 2)); }
float rho_edge(int i) { return params.grid.x * sinh(params.grid.y * float(i)); }

// u of the z-plane at height `edge` (the walk never runs parallel to them: |cos theta| >=
// cos 85 degrees at every centre).
float next_z(float edge, float z0, float inv_cos) { return (z0 - edge) * inv_cos; }

// u of the next rho-cylinder from u (where T = t0 - u sin_theta), with the current bin's
// inner and outer radii, and which way it goes: inward through the inner cylinder while T > 0
// and the line reaches it, else outward through the outer one (on the far side of the closest
// approach when T > 0).
float next_rho(int ir, float lo, float hi, float u, float t0, float s2, float sin_theta,
               float inv_sin, out int dir)
{
    float t = t0 - u * sin_theta;
    bool inward = t > 0.0 && ir > 0 && lo * lo > s2;
    dir = inward ? -1 : 1;
    return inward ? (t0 - sqrt(lo * lo - s2)) * inv_sin
                  : (t0 + sqrt(max(hi * hi - s2, 0.0))) * inv_sin;
}

// u of the next constant-phi half-plane (none after the last bin: phi tends to pi).
float next_phi(int ip, float cot_edge, float t0, float s, float inv_sin)
{
    if (ip >= NPHI - 1)
        return FAR;
    return (t0 - s * cot_edge) * inv_sin;
}

void count_steps(uint steps)
{
    uint before = atomicAdd(counters[NS_ACCUMULATE_COUNTER_STEPS], steps);
    if (before + steps < before) // the low word wrapped
        atomicAdd(counters[NS_ACCUMULATE_COUNTER_STEPS_HIGH], 1u);
}

// A along the line from the centre of cell (iz, ir, it) in phi bin ip, its own phi phi
// (inside the bin), of the three channels, and of the second three (second_sum, 0 without
// them); steps: the bins it crossed; capped: it stopped at the step cap.
#if NS_ACCUMULATE_SECOND
vec3 walk_line(int iz, int ir, int it, int ip, float phi, out vec3 second_sum, out uint steps,
               out bool capped)
#else
vec3 walk_line(int iz, int ir, int it, int ip, float phi, out uint steps, out bool capped)
#endif
{
    float rho_lo = rho_edge(ir), rho_hi = rho_edge(ir + 1);
    // The two cells beside the source's plane hold A on the plane itself (z = 0): see
    // accumulate_shared.h.
    bool beside_plane = iz == NZ / 2 - 1 || iz == NZ / 2;
    float z0 = beside_plane ? 0.0 : 0.5 * (z_edge(iz) + z_edge(iz + 1));
    float rho0 = 0.5 * (rho_lo + rho_hi);
    float theta = (float(it) + 0.5) * ANGLE_STEP;
    float cos_theta = cos(theta), sin_theta = sin(theta); // sin_theta > 0 at every centre
    float inv_cos = 1.0 / cos_theta, inv_sin = 1.0 / sin_theta; // |cos_theta| >= cos(85 deg)
    float t0 = rho0 * cos(phi), s = rho0 * sin(phi), s2 = s * s;

    // The rest of the line never comes closer to the axis than s (the remainder bounds,
    // accumulate_shared.h): its rho bin, one lower against rounding.
    int ir_closest =
        clamp(int(floor(asinh(abs(s) / params.grid.x) / params.grid.y)) - 1, 0, NRHO - 1);
    int bound_row = it * NZ; // + iz, then * NRHO + the rho bin

    bool fixed_length = params.cut.z > 0.0;
    float u_end = fixed_length ? params.cut.z : FAR;
    vec3 floor_abs = params.cut.y * params.j_max.xyz;

    // The z-plane ahead is the bin's lower one while z decreases along the walk, else its
    // upper one.
    int z_step = cos_theta > 0.0 ? -1 : 1, z_ahead = cos_theta > 0.0 ? 0 : 1;
    int rho_dir;
    float uz = next_z(z_edge(iz + z_ahead), z0, inv_cos);
    float ur = next_rho(ir, rho_lo, rho_hi, 0.0, t0, s2, sin_theta, inv_sin, rho_dir);
    float edge0 = float(ip + 1) * ANGLE_STEP;
    float cot_edge = cos(edge0) / sin(edge0);
    float up = next_phi(ip, cot_edge, t0, s, inv_sin);

    // A line that never comes inside the radius from which J is 0 (counts.y, a rho bin edge)
    // meets only zeros: A is 0 without a walk, exactly what the walk would find, since it
    // crosses a cylinder inward only where lo * lo > s2 (next_rho), with the same edges.
    int zero_from = int(params.counts.y);
    float zero_edge = rho_edge(zero_from);
    bool meets_j = ir < zero_from || zero_edge * zero_edge > s2;
#if NS_ACCUMULATE_SECOND
    // The second three's own test, with their own radius.
    bool has_second = params.second.x > 0u;
    int second_zero_from = max(int(params.second.x) - 1, 0);
    float second_edge = rho_edge(second_zero_from);
    bool meets_second =
        has_second && (ir < second_zero_from || second_edge * second_edge > s2);
    vec3 second_floor = params.cut.y * params.second_j_max.xyz;
    bool meets_any = meets_j || meets_second;
    bool adding_second = meets_second;
    second_sum = vec3(0.0);
#else
    bool meets_any = meets_j;
#endif
    uint step_cap = meets_any ? params.counts.z : 0u;
    // Each part adds until its own cut is met (accumulate_shared.h).
    bool adding_j = meets_j;

    float u = 0.0, decay = 1.0; // decay = e^{-u}
    vec3 sum = vec3(0.0);
    steps = 0u;
    capped = meets_any;
    while (steps < step_cap) {
        int event = 0;
        float u_event = uz;
        if (ur < u_event) {
            event = 1;
            u_event = ur;
        }
        if (up < u_event) {
            event = 2;
            u_event = up;
        }
        // Rounding can put a crossing a hair behind u: it then takes a zero-length step.
        float u_next = max(min(u_event, u_end), u);
        float decay_next = exp(-u_next);
        uint index = ((uint(iz) * NS_TABLE_NRHO + uint(ir)) * NS_TABLE_NTHETA + uint(it)) *
                         NS_TABLE_NPHI + uint(ip);
        vec3 jv = j_at(index).xyz;
        float weight = decay - decay_next;
        if (adding_j)
            sum += jv * weight;
#if NS_ACCUMULATE_SECOND
        if (adding_second)
            second_sum += j_at(NS_TABLE_CELLS + index).xyz * weight;
#endif
        steps++;
        u = u_next;
        decay = decay_next;
        if (u_event >= u_end) {
            capped = false;
            break;
        }
        if (!fixed_length) {
            // The rest of the line lies in z bins from iz on (its way) and rho bins from
            // ir_closest while it still heads inward, from ir once it heads outward. A line
            // that grazes its bin's inner edge has T about 0 there, which rounding may put on
            // either side: the crossing ahead going inward says so too.
            int ir_rest = t0 - u * sin_theta > 0.0 || rho_dir < 0 ? min(ir_closest, ir) : ir;
            uint bound_at = uint((bound_row + iz) * NRHO + ir_rest);
            adding_j = adding_j &&
                !all(lessThanEqual(decay * j_at(params.counts.w + bound_at).xyz,
                                   params.cut.x * (sum + floor_abs)));
#if NS_ACCUMULATE_SECOND
            adding_second = adding_second &&
                !all(lessThanEqual(decay * j_at(params.second.y + bound_at).xyz,
                                   params.cut.x * (second_sum + second_floor)));
            if (!adding_j && !adding_second) {
#else
            if (!adding_j) {
#endif
                capped = false;
                break;
            }
        }
        // Into the next bin. lavapipe runs every branch that its SIMD lanes disagree on, so
        // this is written without branches: one new edge per axis (the rho bin's new inner or
        // outer radius; its other radius is the one it crossed), kept where no event moved it.
        iz += event == 0 ? z_step : 0;
        ir += event == 1 ? rho_dir : 0;
        ip += event == 2 ? 1 : 0;
        if (iz < 0 || iz >= NZ || ir >= NRHO) { // it leaves the table
            capped = false;
            break;
        }
        float z_new = z_edge(iz + z_ahead);
        float rho_new = rho_edge(rho_dir > 0 ? ir + 1 : ir);
        bool rho_moved = event == 1;
        float lo = rho_moved ? (rho_dir > 0 ? rho_hi : rho_new) : rho_lo;
        float hi = rho_moved ? (rho_dir > 0 ? rho_new : rho_lo) : rho_hi;
        rho_lo = lo;
        rho_hi = hi;
        uz = event == 0 ? next_z(z_new, z0, inv_cos) : uz;
        int dir;
        float ur_new = next_rho(ir, rho_lo, rho_hi, u, t0, s2, sin_theta, inv_sin, dir);
        ur = rho_moved ? ur_new : ur;
        rho_dir = rho_moved ? dir : rho_dir;
        cot_edge = event == 2 ? (cot_edge * COT_STEP - 1.0) / (cot_edge + COT_STEP) : cot_edge;
        up = event == 2 ? next_phi(ip, cot_edge, t0, s, inv_sin) : up;
    }
    return sum;
}

void main()
{
    if (params.counts.x == 0u) // the warm-up
        return;
    uint order = push.first_cell + gl_GlobalInvocationID.x;
    if (gl_GlobalInvocationID.x >= push.cell_count || order >= params.counts.x)
        return;
    // The cells walked: the z bins within reach.x of the source's plane and the rho bins
    // below it (every cell when it is NRHO), z fastest.
    uint reach = params.reach.x, rest = order;
    int iz = int(rest % (2u * reach)) + NZ / 2 - int(reach);
    rest /= 2u * reach;
    int ir = int(rest % reach);
    rest /= reach;
    int it = int(rest % NS_TABLE_NTHETA);
    int ip = int(rest / NS_TABLE_NTHETA);
    uint cell = ((uint(iz) * NS_TABLE_NRHO + uint(ir)) * NS_TABLE_NTHETA + uint(it)) *
                    NS_TABLE_NPHI + uint(ip);

    // The mean over the phi bin (accumulate_shared.h). phi is the slowest index of `order`,
    // so a whole group walks the same number of lines.
    uint lines = ns_accumulate_phi_lines(uint(ip));
    vec3 sum = vec3(0.0);
    uint steps = 0u;
    bool capped = false;
#if NS_ACCUMULATE_SECOND
    vec3 second_sum = vec3(0.0);
#endif
    for (uint k = 0u; k < lines; k++) {
        float phi = (float(ip) + (float(k) + 0.5) / float(lines)) * ANGLE_STEP;
        uint line_steps;
        bool line_capped;
#if NS_ACCUMULATE_SECOND
        vec3 line_second;
        sum += walk_line(iz, ir, it, ip, phi, line_second, line_steps, line_capped);
        second_sum += line_second;
#else
        sum += walk_line(iz, ir, it, ip, phi, line_steps, line_capped);
#endif
        steps += line_steps;
        capped = capped || line_capped;
    }
    sum /= float(lines);
    for (uint c = 0u; c < 3u; c++)
        a[c * NS_TABLE_CELLS + cell] = sum[c];
#if NS_ACCUMULATE_SECOND
    second_sum /= float(lines);
    if (params.second.x > 0u)
        for (uint c = 0u; c < 3u; c++)
            a_second[c * NS_TABLE_CELLS + cell] = second_sum[c];
#endif
    count_steps(steps);
    if (capped)
        atomicAdd(counters[NS_ACCUMULATE_COUNTER_CAPPED], 1u);
}
