/* bvh.h — CPU builder of the bounding volume hierarchy the shaders traverse (trace.glsl).
 * Binned surface-area heuristic over the primitives' bounds; planes are infinite and never
 * enter the tree. */
#ifndef NS_BVH_H
#define NS_BVH_H

#include "nscatter.h"
#include "shared.h"

typedef struct ns_bvh {
    GpuNode *nodes; /* nodes[0] is the root; children of an interior node are adjacent */
    uint32_t node_count;
    GpuPrim *prims; /* the input primitives, reordered so every leaf is a range */
    uint32_t prim_count;
    uint32_t *order; /* prims[i] is input primitive order[i] */
    uint32_t depth;  /* deepest level, root = 1 */
} ns_bvh;

/* Builds over prims[0..count) (no planes). count 0 gives an empty tree (node_count 0).
 * Allocates everything in *out; free with ns_bvh_free, also after a failure. */
int ns_bvh_build(const GpuPrim *prims, uint32_t count, ns_bvh *out, ns_error *err);
/* The same with the surface-area splits stopping at max_depth (at most NS_BVH_MAX_DEPTH),
 * so that tests reach what happens there. */
int ns_bvh_build_limited(const GpuPrim *prims, uint32_t count, uint32_t max_depth, ns_bvh *out,
                         ns_error *err);
void ns_bvh_free(ns_bvh *bvh);

/* Axis-aligned bounds of a sphere, box or triangle primitive. */
void ns_prim_bounds(const GpuPrim *prim, float lo[3], float hi[3]);

#endif
