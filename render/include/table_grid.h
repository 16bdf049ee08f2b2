/* table_grid.h — the default grid of the scattering tables, defined once for every user: the
 * Monte Carlo tracer that fills it (offline/mc.c), the renderer that rebuilds its edges and
 * reads it (render/scatter_tables.c, render/gather.c) and the shaders that index it
 * (shaders/accumulate.comp, shaders/gather.glsl, through shaders/scatter_shared.h; CMake
 * passes -I render/include to glslang). Were the grid written in each of them, one could
 * change and the tables would be read with the wrong bins.
 *
 * Spatial edges follow scale * sinh(step * i), with step = asinh(extent / scale) / NRHO:
 * ~0.056 mfp wide at the source, ~11% of the distance far away, reaching NS_TABLE_EXTENT in
 * rho and in both directions of z (400 mfp: the light of a = 0.999, g = 0.9 reaches well
 * beyond 200). z is symmetric about 0 (NZ / 2 bins on each side). Angular bins are 10 degrees
 * wide in theta and phi. A table holds NS_TABLE_CELLS floats in the .npy order
 * [z][rho][theta][phi].
 */
#ifndef NS_TABLE_GRID_H
#define NS_TABLE_GRID_H

/* The bin counts are int constants in C (the type the offline code has always computed
 * with) and uint constants in GLSL (the type the shaders index with), as NS_CONST makes them
 * in shaders/shared.h; that header is not visible to offline/, so both forms are spelled out
 * here. */
#if defined(__STDC__) || defined(__cplusplus)
enum {
    NS_TABLE_NZ = 128, /* 64 below z = 0, 64 above */
    NS_TABLE_NRHO = 64,
    NS_TABLE_NTHETA = 18,
    NS_TABLE_NPHI = 18,
    NS_TABLE_CELLS = 128 * 64 * 18 * 18,
};
#else
const uint NS_TABLE_NZ = 128;
const uint NS_TABLE_NRHO = 64;
const uint NS_TABLE_NTHETA = 18;
const uint NS_TABLE_NPHI = 18;
const uint NS_TABLE_CELLS = 128 * 64 * 18 * 18;
#endif

/* The spatial edges' parameters in mfp (double in C; the shaders get them from the gather's
 * uniform block, GpuGatherParams.table_map, and do not use these). */
#define NS_TABLE_SINH_SCALE 0.5
#define NS_TABLE_EXTENT 400.0

#endif
