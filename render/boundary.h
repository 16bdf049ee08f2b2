/* boundary.h — (private to render/ and the tests) the boundary-crossing correction
 * (render.boundary, boundary.c): sources from the light's walks inside the object, grouped
 * by the tables they read. */
#ifndef NS_RENDER_BOUNDARY_H
#define NS_RENDER_BOUNDARY_H

#include "scatter.h"

/* Standard deviation (mfp) of the blurred first order's radial kernel, at its widest: light
 * that leaves a source unscattered meets a camera segment (a line) with probability zero, so
 * its first scattering there is spread over a narrow tube, like the beam x beam blur of
 * photon beams (shared/boundary/README.md: r ~ 0.25-0.5 mfp). Computed exactly in the gather
 * (gather.glsl, first_order), 0.2 instead of 0.1 took the bumpy sphere's full image up 0.46
 * dB and the candle's 0.10 dB, but the milk's down 0.46 dB and the bunny's 0.28 dB: more of
 * the tube lies outside their thin parts (docs/bench.md, *The blurred first order
 * computed*). Around a short chord the tube is narrower (scatter_shared.h,
 * NS_FIRST_BLUR_PER_CHORD): 0.1 everywhere read a 0.6-mfp refracting sphere's multiple
 * scattering 38-51% high, 0.01 everywhere cost the bumpy sphere's full image 3 dB. */
#define NS_BOUNDARY_BLUR_MFP 0.1

/* How many sources the gather takes (ns_boundary_floor): as many as VRLs, and at least
 * NS_BOUNDARY_MIN_SOURCES; and how many walks make them: render.vrls, at least
 * NS_BOUNDARY_MIN_WALKS (a scene with few VRLs, the bench's bumpy sphere at 3000 paths and
 * 423 VRLs, would otherwise get a noisy correction). On that sphere at 128², multiple only,
 * PSNR against pt / gather time (2026-11-28, one seed): at least 1024 sources 32.90 dB / 1.9
 * s, 4096 33.12 dB / 4.9 s, 16384 33.16 dB / 14.3 s (off: 32.48 dB / 0.5 s). Against its
 * converged references over four seeds (2026-12-03) 2048 reads as 4096 does (multiple 29.92
 * against 29.85 dB, full 37.26 against 37.19, PSNR of the mean MSE) for a gather 20-27%
 * shorter on the meshes at 256²; docs/scattering.md, *Source budget*. */
#define NS_BOUNDARY_MIN_SOURCES 2048u
#define NS_BOUNDARY_MIN_WALKS 20000u

/* How stretch v of a walk follows the stretch before it (NULL: none): a new start (the
 * entry into the medium, or a scattering event: its events differ), an internal reflection
 * (it starts where the previous one ended, in another direction), the same line continued
 * (the walk grazed its own boundary), or a re-entry (after scattering, the walk left its
 * object and entered one again, elsewhere: vrl_trace.comp; the events are the same, the
 * point or the medium are not). Unscattered light never re-enters (vrl_trace.comp), so a
 * stretch without events that starts elsewhere is a new path's entry. */
typedef enum {
    NS_BOUNDARY_LINK_START,
    NS_BOUNDARY_LINK_REFLECTED,
    NS_BOUNDARY_LINK_CONTINUED,
    NS_BOUNDARY_LINK_REENTERED,
} ns_boundary_link;
ns_boundary_link ns_boundary_link_of(const GpuVrl *previous, const GpuVrl *v);

/* The sources of stretches[0, count) (the `vrl` method's light paths, in path order): a
 * ghost (negative power) at the end of every stretch, except the entry stretch's unless
 * entry_ghosts (the renderer asks for them: they are its endless VRLs' beams past their
 * exits; the toy checks of tests/unit_boundary.c count without), and a positive beam for
 * the light the boundary reflects back, all endless for the tables (their length is the
 * stretch's, or for an expected reflection the chord ahead of it: the chord narrows their
 * first order's tube). That beam is the walk's own,
 * at the start of every stretch that begins with an internal reflection, except for light
 * that has not scattered yet when ends are given (ns_vrl_set.ends: per stretch, the mirror
 * direction, scaled by the chord ahead along it, and the Fresnel reflectance at its end;
 * vrl_method_shared.h): then it is its expectation, at the end
 * of every unscattered stretch, F times the ghost's light reaching it, along the mirror
 * direction, whether or not the walk reflected there (the walk's own choice only decides
 * how it goes on), unless nothing lies ahead of it (chord 0: none). And a positive beam at the
 * start of every stretch that re-enters its medium. At most two per stretch (a reflected or
 * re-entered beam at its start and a ghost, or a ghost and its expected reflection): out has room
 * for 2 count. Returns how many were written. */
uint32_t ns_boundary_sources(const GpuVrl *stretches, const float *ends, uint32_t count,
                             const GpuMaterial *materials, int entry_ghosts, GpuVrl *out);

/* What the roulette below weighs a ghost by, against a positive source of the same power: a
 * ghost stands for light that leaves, and most of what its tables spread lies outside the
 * object, where no camera segment reads it (the bumpy sphere's ghosts: 5% of the
 * correction in its image, for 63% of the sources' power). Measured on the bench's scenes,
 * multiple scattering at 128², six walk seeds: 0.2 took 20-34% of the pixel variance away
 * at the same source count on all five refracting scenes; 0.05 did as well on the candle
 * and the milk and worse on the bunny (docs/scattering.md, *The sources' roulette*). */
#define NS_BOUNDARY_GHOST_IMPORTANCE 0.2f

/* Russian roulette on weak sources. A source's importance is its power (the mean of RGB,
 * in absolute value), times NS_BOUNDARY_GHOST_IMPORTANCE for a ghost. One below `floor` is
 * kept with probability importance / floor and then carries power * floor / importance
 * (sign and colour kept), the others as they are: unbiased, and no more sources than the
 * total importance over floor besides the strong ones. The draws come from seed and each
 * source's index. Compacts sources[0, n) in place; returns how many are left. */
uint32_t ns_boundary_roulette(GpuVrl *sources, uint32_t n, float floor, uint32_t seed);

/* The floor with which ns_boundary_roulette keeps `target` of sources[0, n) in expectation
 * (the sum over them of min(1, importance / floor)); 0 when n <= target (keep them all). */
float ns_boundary_floor(const GpuVrl *sources, uint32_t n, uint32_t target);

/* The orders (NS_TABLE_FIRST_BLURRED, computed in the gather; NS_COMPONENT_DOUBLE for J_2,
 * NS_COMPONENT_MULTIPLE for J_multiple, read from the tables) a source after `events`
 * scattering events gives for the asked components (single, double, multiple); 0: none. */
uint32_t ns_boundary_orders(uint32_t events, uint32_t components);
/* The orders source s reads: ns_boundary_orders of its events, less the blurred first order
 * for a ghost (negative power), whose next event lies outside its object, unless its events
 * carry NS_VRL_LINE_RETURNS (the ghost's line passes through an object of its medium again:
 * boundary.c), and less it for the environment's unscattered light (NS_VRL_FROM_ENVIRONMENT
 * with no events: single.comp follows it through internal reflections). */
uint32_t ns_boundary_source_orders(const GpuVrl *s, uint32_t components);

/* Sources grouped by (orders, sign): one gather each. Each of events 0, 1 and more gives its
 * orders with and without the first order (a ghost without it, the environment's
 * unscattered beams without it), two signs: at most 8 of the 12 occur together (events 1
 * and more give the same orders with single, double and multiple asked; the first order of
 * events 0 only with single). */
#define NS_BOUNDARY_GROUPS 8u
typedef struct ns_source_group {
    ns_vrl_set set;
    uint32_t orders;
    int negative;
    uint32_t filled;
} ns_source_group;
typedef struct ns_boundary_groups {
    ns_source_group group[NS_BOUNDARY_GROUPS];
    uint32_t count;
} ns_boundary_groups;
int ns_boundary_group(const GpuVrl *sources, uint32_t count, uint32_t components,
                      ns_boundary_groups *out, ns_error *err);
void ns_boundary_groups_free(ns_boundary_groups *g);

#endif
