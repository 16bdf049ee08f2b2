/* scatter_shared.h — GPU structs and constants of the scattering stages (issue 5): Virtual Ray
 * Lights, their grid, the accumulated tables, the gather and single scattering. Shared by C
 * and GLSL like shared.h (include that first); sizes checked at the bottom.
 *
 * Units: positions and lengths in scene units; power in W (RGB); the tables in mfp units
 * (DESIGN.md section 2), scaled to the scene per channel by the medium's extinction.
 */
#ifndef NS_SHADERS_SCATTER_SHARED_H
#define NS_SHADERS_SCATTER_SHARED_H

/* A Virtual Ray Light: the first stretch of a light path inside a medium (for the table
 * methods and the dipole), or any stretch of a light path between two events inside a
 * medium (the `vrl` method). origin = where the stretch starts (on the boundary for a first
 * stretch); direction = unit travel direction; length = distance to the next boundary along
 * it; power = RGB flux carried by the stretch at its origin (W), already multiplied by the
 * Fresnel transmittance and divided by the number of light samples traced;
 * material = the medium's material index; events = scattering events before this stretch
 * (0 for a stretch that starts on the boundary). A light walk traced for render.boundary
 * (vrl_trace.comp, GpuVrlTracePush.options & NS_VRL_TRACE_MARK_LINES) also sets
 * NS_VRL_LINE_RETURNS in events when the stretch's straight line, continued past its end,
 * passes through an object of its medium again (render/boundary.c: that stretch's ghost must read its first order). */
struct GpuVrl {
    ns_vec3 origin;
    float length;
    ns_vec3 direction;
    ns_uint material;
    ns_vec3 power;
    ns_uint events;
};

/* events' flag bits (above): the line past the stretch's end meets its medium again; the
 * stretch's light came from the environment and has not scattered yet (a walk traced with
 * NS_VRL_TRACE_MARK_ENVIRONMENT: single.comp follows that light through internal reflections
 * itself, so render/boundary.c leaves out its reflected beams' first order). */
NS_CONST(uint, NS_VRL_LINE_RETURNS, 0x80000000u);
NS_CONST(uint, NS_VRL_FROM_ENVIRONMENT, 0x40000000u);
/* The scattering events themselves: the low 16 bits. A positive boundary source that starts
 * on a face it was reflected by (render/boundary.c) carries in bits 16-29 the cosine of its
 * line's angle to that face's normal, times NS_VRL_FACE_COS_MAX (0: none known): the share
 * of its first order's tube on the medium's side of the face (gather.glsl, first_order). */
NS_CONST(uint, NS_VRL_EVENT_COUNT, 0xffffu);
NS_CONST(uint, NS_VRL_FACE_COS_SHIFT, 16u);
NS_CONST(uint, NS_VRL_FACE_COS_MAX, 0x3fffu);

/* One cell of a VRL grid level: its VRLs are vrls[first, first + count) of the cell-sorted
 * buffer, their origins lie in [bmin, bmax] (the bounding box of the VRLs' origins, not of
 * the cell), and a representative VRL (power = the sum of the cell's powers, origin = the
 * power-weighted mean origin, direction = the power-weighted mean direction, normalised) is
 * stored at the same index in a parallel array. */
struct GpuVrlCell {
    ns_vec3 bmin;
    ns_uint first;
    ns_vec3 bmax;
    ns_uint count;
};

/* A node of the hierarchy the gather walks (render/vrl_grid.c): the cells of every level from
 * the coarsest down to the chosen leaf level, in depth-first order, so that a node's
 * children follow it and `skip` is the index just past its subtree. A node covers
 * vrls[first, first + count) (its subtree's VRLs are contiguous thanks to the Morton sort)
 * and [bmin, bmax] is the box of their origins; a representative VRL is stored at the same
 * index in a parallel array. leaf = 1: the gather evaluates the node's VRLs; 0: its
 * children follow. An inner node with one child is left out (the child stands for it). */
struct GpuVrlNode {
    ns_vec3 bmin;
    ns_uint first;
    ns_vec3 bmax;
    ns_uint count;
    ns_uint skip;
    ns_uint leaf;
    ns_uint level; /* grid level, 0 = finest */
    ns_uint pad;
};
/* The render tables: the default Monte Carlo grid (NS_TABLE_NZ .. NS_TABLE_CELLS, the edges'
 * scale and extent), defined once for C and GLSL in render/include/table_grid.h. A table
 * buffer holds the three RGB channels one after another, each in the .npy order
 * [z][rho][theta][phi]. */
#include "table_grid.h"

/* Uniform block of the gather (binding 0). One gather dispatch serves one medium. */
struct GpuGatherParams {
    ns_vec4 sigma_t;   /* xyz: extinction per scene unit of each channel; w = ior */
    ns_vec4 table_map; /* x = sinh scale (mfp), y = 1 / sinh step, z = extent (mfp), w = the
                          beam cutoff of bounded beams (NS_BEAM_CUTOFF; 0: endless beams) */
    ns_uvec4 counts;   /* x = segments, y = cells, z = VRLs, w = mode (NS_GATHER_MODE_*: each
                          shader is compiled for one, gather.glsl; the C side picks it) */
    ns_vec4 cull;      /* x = cull distance (scene units): cells farther from a segment add
                          nothing; y = solid-angle threshold (0 = off): a cell whose box
                          subtends less from the segment is replaced by its representative */
    ns_vec4 dipole_sigma_tr; /* dipole mode: xyz = sigma_tr per channel; w = unused */
    ns_vec4 dipole_zr;       /* xyz = z_r per channel (scene units); w = unused */
    ns_vec4 dipole_zv;       /* xyz = z_v per channel; w = unused */
    ns_vec4 dipole_alpha;    /* xyz = reduced albedo alpha' per channel; w = unused */
    ns_vec4 first_order;     /* with the first order: xyz = albedo per channel; w = g */
    ns_vec4 first_blur;      /* xyz = the first order's tube's standard deviation per channel
                                (scene units: NS_BOUNDARY_BLUR_MFP / sigma_t), the widest (a
                                source's chord narrows it: NS_FIRST_BLUR_PER_CHORD); w = 1 when the form
                                computes the first order (ns_gather_params_first), which picks
                                its shader (ns_gather_pipeline) */
};

/* Bounded beams (render.vrl_beams): the beam past a VRL's exit is subtracted in the gather
 * (gather.comp), and the beam is reflected at its exit (vrl.comp), while its transmittance
 * e^{-s L} exceeds this in some channel. Leaving it out below changes that VRL's contribution
 * by less than this fraction: the part past the exit is at most e^{-s L} of the whole beam's,
 * all terms being positive. */
#if defined(__STDC__) || defined(__cplusplus)
#define NS_BEAM_CUTOFF 1e-3f
#else
const float NS_BEAM_CUTOFF = 1e-3;
#endif

/* Gather modes: the exact segment form A(entry) - exp(-s Lc) A(exit); the paper's 5-mfp
 * table with its weight W; the dipole's R_d(|entry - origin|) of Jensen et al. 2001. */
NS_CONST(uint, NS_GATHER_MODE_EXACT, 0);
NS_CONST(uint, NS_GATHER_MODE_PAPER, 1);
NS_CONST(uint, NS_GATHER_MODE_DIPOLE, 2);
/* The blurred first order of boundary sources (render/boundary.h), computed per source and
 * segment instead of read from a table (gather.glsl, first_order). */
NS_CONST(uint, NS_GATHER_MODE_FIRST, 3);

/* The first order's tube around a source whose chord is known (a reflected or re-entered
 * beam: GpuVrl.length, the stretch to the boundary ahead) is at most this fraction of the
 * chord wide, and at least NS_FIRST_BLUR_FLOOR of first_blur (0.01 mfp): the blur's bias
 * grows with its width against the object's (a tube a third of a thin sphere's radius read
 * its multiple scattering 38-51% high; 0.01 mfp everywhere fixed that, but cost the bumpy
 * sphere's full image 3 dB), its noise as it narrows, where a camera segment runs close
 * and nearly parallel to a source (the floor bounds a grazing chord's spike; the oil's
 * multiple-only image still spikes on 2 seeds of 8). docs/bench.md, *The oil placed: the
 * first order's tube*. */
#define NS_FIRST_BLUR_PER_CHORD 0.03
#define NS_FIRST_BLUR_FLOOR 0.1

/* The paper's accumulated length (mfp) for NS_GATHER_MODE_PAPER. */
NS_CONST(uint, NS_PAPER_ACCUMULATION_MFP, 5);

/* Push block of a gather dispatch: the segments [first_segment, first_segment + groups * 64)
 * visit the cells [first_cell, first_cell + cell_count). The C side splits cells across
 * dispatches so that no invocation runs past lavapipe's loop limit (shared.h). */
struct GpuGatherPush {
    ns_uint first_cell;
    ns_uint cell_count;
    ns_uint first_segment;
    ns_uint accumulate; /* 0: the first dispatch of a segment range writes, others add */
};

NS_CONST(uint, NS_GATHER_GROUP, 64);

/* Gather counters (binding 7): VRL-segment interactions evaluated (low and high words of a
 * 64-bit count), cells culled by distance, cells replaced by their representative. */
NS_CONST(uint, NS_GATHER_COUNTER_INTERACTIONS, 0);
NS_CONST(uint, NS_GATHER_COUNTER_CULLED, 1);
NS_CONST(uint, NS_GATHER_COUNTER_REPRESENTED, 2);
NS_CONST(uint, NS_GATHER_COUNTER_INTERACTIONS_HIGH, 3);
NS_CONST(uint, NS_GATHER_COUNTER_COUNT, 4);

/* Loop iterations budgeted for one VRL in the gather (its loop has no inner loop; 2 leaves
 * a margin for what lavapipe counts besides), used to split cells across dispatches.
 * tests/gpu_gather.c runs dispatches filled to the budget and compares with the CPU. */
NS_CONST(uint, NS_GATHER_ITERATIONS_PER_VRL, 2);

#if defined(__STDC__) || defined(__cplusplus)
typedef struct GpuVrl GpuVrl;
typedef struct GpuVrlCell GpuVrlCell;
typedef struct GpuVrlNode GpuVrlNode;
typedef struct GpuGatherParams GpuGatherParams;
typedef struct GpuGatherPush GpuGatherPush;
_Static_assert(sizeof(GpuVrl) == 48 && offsetof(GpuVrl, power) == 32, "GpuVrl layout");
_Static_assert(offsetof(GpuVrl, material) == 28 && offsetof(GpuVrl, events) == 44, "GpuVrl");
_Static_assert(sizeof(GpuVrlCell) == 32 && offsetof(GpuVrlCell, count) == 28, "GpuVrlCell");
_Static_assert(sizeof(GpuVrlNode) == 48 && offsetof(GpuVrlNode, skip) == 32, "GpuVrlNode");
_Static_assert(sizeof(GpuGatherParams) == 160, "GpuGatherParams std140 size");
_Static_assert(sizeof(GpuGatherPush) == 16, "GpuGatherPush size");
#endif

#endif
