/* vrl_grid.h — (private to render/) the VRL grid built at a level the caller picks, for the
 * tests that check how levels merge; ns_vrl_grid_build (scatter.h) picks it by the rule in
 * render/vrl_grid.c. */
#ifndef NS_RENDER_VRL_GRID_H
#define NS_RENDER_VRL_GRID_H

#include "scatter.h"

/* Finest cells per mean free path (the lattice's resolution, render/vrl_grid.c). */
#define NS_VRL_CELLS_PER_MFP 8.0
/* Direction classes per axis of the octahedral map that splits the VRLs before space. */
#define NS_VRL_DIRECTION_CLASSES 4u
/* Finest grid: at most this many cells per axis. */
#define NS_VRL_GRID_MAX_RESOLUTION 64u
/* level argument: choose by the rule. */
#define NS_VRL_GRID_AUTO 0xffffffffu

/* As ns_vrl_grid_build, but keeps `level` (0 = finest; NS_INVALID_ARGUMENT when it is not
 * below the level count the medium gets) unless it is NS_VRL_GRID_AUTO. The lattice starts
 * at the componentwise minimum `lo` of the medium's VRL origins; a VRL lies in the finest
 * cell (c_x, c_y, c_z), c_k = min((uint32_t)((origin[k] - lo[k]) / s0), R0 - 1), with
 * s0 = cell_size / 2^level and R0 the finest resolution; level i groups c >> i. */
int ns_vrl_grid_build_level(const ns_vrl_set *set, uint32_t material, float mfp_min,
                            uint32_t leaf_fill, uint32_t level, ns_vrl_grid *out, ns_error *err);

#endif
