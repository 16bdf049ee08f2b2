/* accumulate_shared.h — the accumulation stage's GPU blocks (shaders/accumulate.glsl, in
 * accumulate.comp and accumulate_second.comp, and render/scatter_tables.c), shared by C and
 * GLSL like shared.h (include that and scatter_shared.h, included here); sizes checked at
 * the bottom.
 *
 * The stage turns J (float [3][NS_TABLE_CELLS], one table per RGB channel, on the default
 * grid) into A(x, w) = integral_0^inf e^{-u} J(x - u w, w) du at every cell centre
 * (DESIGN.md section 2), walking the straight line x - u w through the table's bins.
 *
 * What a cell holds is the mean of A over its phi bin, not A at the bin's centre: the gather
 * reads phi at the nearest bin, so the bin's mean is what makes its expectation right. A is
 * far from linear across the first bins: a line whose phi is near 0 heads for the source's
 * axis and passes it at rho0 sin(phi), through J's 1/rho peak near the beam, so its A has a
 * log peak at phi = 0 that the centre line (5 degrees) misses. Measured on a half-space lit
 * at normal incidence (g 0.5, Monte Carlo J_2, the camera at 35 degrees; docs/scattering.md,
 * *The phi bins' mean*): A at the centres read double scattering 5.5% low; the mean over
 * NS_ACCUMULATE_PHI_LINES_0 lines in the first bin and _1 in the second, the centre line
 * elsewhere, 0.5% below the converged mean (8 and 4 lines: 0.3%, for 1.85 times the stage's
 * time; 4 and 2 cost 1.43 times: 1,601 against 1,117 ms for an RGB material; on a CPU
 * without AVX-512, after the phi edges were computed, 1,186 against 852 ms, 1.39 times).
 *
 * And the two cells beside the source's plane (z bins NZ / 2 - 1 and NZ / 2) hold A on the
 * plane itself, z = 0, not at their centres (z = -/+0.029 mfp). A has a kink there: a line
 * from just in front of the source that goes back across the plane passes through J's peak
 * beside the beam's start, one from just behind does not. The gather reads z = 0 wherever a
 * source and a camera segment start on the same face (a VRL where the light enters, a ghost
 * where it leaves), halfway between those two cells: with A at their centres that read was
 * 10.5% high for a camera going against the beams (ghosts) and 1% low going with them (a
 * plane of beams, gpu_accumulate (e)); with A on the plane, -0.4% and -0.5%. Reads within a
 * bin of the plane elsewhere move by at most that bin's change of A.
 */
#ifndef NS_SHADERS_ACCUMULATE_SHARED_H
#define NS_SHADERS_ACCUMULATE_SHARED_H

#include "shared.h"
#include "scatter_shared.h"

/* Uniform block (binding 0). Kept under 256 bytes so the generic warm-up buffer covers it. */
struct GpuAccumulateParams {
    ns_vec4 grid;    /* x = sinh scale (mfp), y = sinh step, z = extent (mfp), w = unused */
    ns_vec4 j_max;   /* xyz: the largest J of each channel's table (sets the cut's floor), w 0 */
    ns_vec4 cut;     /* x = relative error allowed for the remainder, y = floor relative to
                        j_max (see accumulate.comp), z = fixed length (mfp, paper mode) or 0 */
    ns_uvec4 counts; /* x = cells walked (0: the warm-up, return at once), y = the rho bin from
                        which J is 0 in every channel and cell (NS_TABLE_NRHO: none; a line
                        that never comes inside it meets only zeros, accumulate.comp),
                        z = step cap per cell, w = the texel of J's buffer where the
                        remainder bounds begin (below) */
    ns_vec4 second_j_max; /* xyz: the largest J of each channel of the second three (below) */
    ns_uvec4 second;      /* x = 0 (none), or 1 + the rho bin from which their J is 0; y = the
                             texel where their remainder bounds begin; zw 0 */
    ns_uvec4 reach;       /* x = k: the cells walked are those of the z bins NZ / 2 - k to
                             NZ / 2 + k - 1 and the rho bins 0 to k - 1 (k = NS_TABLE_NRHO:
                             every cell); the others are left as they are (zeroed by the C
                             side). A render's table is read only within its media's size
                             (render/scatter.h, ns_table_key.reach_bins); yzw 0 */
};

/* The second three (shaders/accumulate_second.comp). A render may ask for two tables of
 * one material: of multiple scattering alone with boundary walks, its VRLs read multiple
 * scattering and the walks' sources after an event double + multiple (scatter.h,
 * ns_tables_expect_orders). Their lines are the same; only J differs. So one walk can make
 * both: J then holds a second texel per cell (below), the second A goes to binding 4 (a
 * dummy when there is none), and each set stops adding where its own walk would: the walk
 * ends when both have, so each table comes out bit for bit as its own walk would make it
 * (gpu_accumulate checks it).
 *
 * J's layout (binding 1, a texel buffer of 16-byte texels): texel i holds cell i of the three
 * channels (and 0), as four floats; with the second three, texel NS_TABLE_CELLS + i holds
 * their cell i (and 0). One texel fetch per step of the walk reads the three channels,
 * where one float per channel took three: lavapipe pays
 * for each fetch lane by lane (docs/rendering.md, *The accumulation*). The C side
 * interleaves the planes it is given (float [3][cells] per part, the .npy order). */

/* The remainder bounds. A walk stops once what is left of its line cannot add more than the
 * cut (accumulate.glsl): what is left after u is at most e^{-u} times the largest J on the
 * rest of the line. The whole table's largest J bounds it everywhere, but far from the source,
 * or on a line heading away from it, J is orders of magnitude below that peak, and such walks
 * went on for many mfp adding nothing. The rest of a line is confined, though: theta is
 * constant along it; z moves one way (down while cos theta > 0, theta bins below
 * NS_TABLE_NTHETA / 2); and rho never falls below the line's closest approach to the axis,
 * S = rho0 |sin phi0|, nor, once past it, below where it is now. So the bound of the rest is
 * a max over a box of bins, tabulated per (theta, z, rho) bin:
 *     bound[it][iz][ir] = max of J over the cells (iz', ir', it, any phi) with ir' >= ir and
 *                          iz' <= iz (theta bins below NS_TABLE_NTHETA / 2) or iz' >= iz
 * one texel per entry (the three channels and 0, as J's), NS_ACCUMULATE_BOUND_TEXELS of them,
 * after J's texels (counts.w; the second three's own after those, second.y). The rule is
 * the same (stop when the bound of the rest is below the cut, so A stays within 1e-4 of the
 * whole integral); only the bound is tighter: a network material's walk takes 32-41% fewer
 * steps (docs/rendering.md, *The accumulation*). */
NS_CONST(uint, NS_ACCUMULATE_BOUND_TEXELS, NS_TABLE_NTHETA * NS_TABLE_NZ * NS_TABLE_NRHO);

/* Push block of one dispatch: cells [first_cell, first_cell + groups * NS_ACCUMULATE_GROUP). */
struct GpuAccumulatePush {
    ns_uint first_cell;
    ns_uint cell_count; /* cells of this dispatch (the last one may hold fewer) */
    ns_uint pad0, pad1;
};

NS_CONST(uint, NS_ACCUMULATE_GROUP, 64);

/* Lines per cell (above): in phi bin 0, bin 1, and every other bin; line k of n in bin ip
 * has phi = (ip + (k + 0.5) / n) * 10 degrees. */
NS_CONST(uint, NS_ACCUMULATE_PHI_LINES_0, 4);
NS_CONST(uint, NS_ACCUMULATE_PHI_LINES_1, 2);
#if defined(__STDC__) || defined(__cplusplus)
static inline uint32_t ns_accumulate_phi_lines(uint32_t ip)
#else
uint ns_accumulate_phi_lines(uint ip)
#endif
{
    return ip == 0u ? NS_ACCUMULATE_PHI_LINES_0 : ip == 1u ? NS_ACCUMULATE_PHI_LINES_1 : 1u;
}

/* The walk crosses at most NZ z-planes, 2 NRHO cylinders (in, then out) and NPHI - 1
 * half-planes of constant phi, plus the last stretch: 128 + 128 + 17 + 1 = 274 steps. The
 * cap is far above that and far below lavapipe's 65,535 loop iterations per invocation; a
 * cell that reaches it is counted (NS_ACCUMULATE_COUNTER_CAPPED), which the C side treats
 * as a bug (NS_ERR_INTERNAL). */
NS_CONST(uint, NS_ACCUMULATE_STEP_CAP, 1024);

/* Counters (binding 3): steps walked (64-bit: low, high word) and cells that hit the cap. */
NS_CONST(uint, NS_ACCUMULATE_COUNTER_STEPS, 0);
NS_CONST(uint, NS_ACCUMULATE_COUNTER_STEPS_HIGH, 1);
NS_CONST(uint, NS_ACCUMULATE_COUNTER_CAPPED, 2);
NS_CONST(uint, NS_ACCUMULATE_COUNTER_COUNT, 4);

#if defined(__STDC__) || defined(__cplusplus)
typedef struct GpuAccumulateParams GpuAccumulateParams;
typedef struct GpuAccumulatePush GpuAccumulatePush;
_Static_assert(sizeof(GpuAccumulateParams) == 112, "GpuAccumulateParams std140 size");
_Static_assert(sizeof(GpuAccumulatePush) == 16, "GpuAccumulatePush size");
#endif

#endif
