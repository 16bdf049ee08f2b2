/* bvh.c — binned SAH BVH builder (Wald 2007, "On fast construction of SAH-based bounding
 * volume hierarchies"): at each node the primitives' centroids are binned along each axis
 * and the split with the least expected traversal cost is taken, or a leaf when splitting
 * costs more than intersecting everything. */
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bvh.h"
#include "gpu.h"

#define BINS 16

/* Every triangle and every object of a valid scene fit the traversal's stack entries. */
_Static_assert((uint64_t)NS_MAX_TRIANGLES + NS_MAX_OBJECTS <= NS_BVH_MAX_PRIMS,
               "a scene's primitives fit a BVH");
#define COST_TRAVERSE 1.0f
#define COST_INTERSECT 1.0f

typedef struct {
    float lo[3], hi[3];
} aabb;

static void aabb_empty(aabb *b)
{
    for (int k = 0; k < 3; k++) {
        b->lo[k] = FLT_MAX;
        b->hi[k] = -FLT_MAX;
    }
}

static void aabb_grow(aabb *b, const float lo[3], const float hi[3])
{
    for (int k = 0; k < 3; k++) {
        if (lo[k] < b->lo[k])
            b->lo[k] = lo[k];
        if (hi[k] > b->hi[k])
            b->hi[k] = hi[k];
    }
}

static float aabb_area(const aabb *b)
{
    if (b->lo[0] > b->hi[0])
        return 0.0f;
    float dx = b->hi[0] - b->lo[0], dy = b->hi[1] - b->lo[1], dz = b->hi[2] - b->lo[2];
    return 2.0f * (dx * dy + dy * dz + dz * dx);
}

void ns_prim_bounds(const GpuPrim *p, float lo[3], float hi[3])
{
    for (int k = 0; k < 3; k++) {
        switch (p->info[0]) {
        case NS_PRIM_SPHERE:
            lo[k] = p->a[k] - p->a[3];
            hi[k] = p->a[k] + p->a[3];
            break;
        case NS_PRIM_BOX:
            lo[k] = p->a[k];
            hi[k] = p->b[k];
            break;
        default: /* triangle */
            lo[k] = fminf(p->a[k], fminf(p->b[k], p->c[k]));
            hi[k] = fmaxf(p->a[k], fmaxf(p->b[k], p->c[k]));
            break;
        }
    }
}

typedef struct builder {
    aabb *bounds; /* per input primitive */
    float (*centroid)[3];
    uint32_t *index; /* permutation being partitioned */
    GpuNode *nodes;
    uint32_t node_count;
    uint32_t depth;
    uint32_t max_depth; /* where the surface-area splits stop (NS_BVH_MAX_DEPTH) */
} builder;

static aabb range_bounds(const builder *b, uint32_t begin, uint32_t end, aabb *centroids)
{
    aabb box;
    aabb_empty(&box);
    aabb_empty(centroids);
    for (uint32_t i = begin; i < end; i++) {
        const aabb *pb = &b->bounds[b->index[i]];
        aabb_grow(&box, pb->lo, pb->hi);
        const float *c = b->centroid[b->index[i]];
        aabb_grow(centroids, c, c);
    }
    return box;
}

static int bin_of(float c, float lo, float scale)
{
    int bin = (int)((c - lo) * scale);
    return bin < 0 ? 0 : bin >= BINS ? BINS - 1 : bin;
}

/* Best binned split over the three axes: returns its cost, and the axis and the first bin
 * of the right side. */
static float best_split(const builder *b, uint32_t begin, uint32_t end, const aabb *cb,
                        int *axis_out, int *bin_out)
{
    float best = FLT_MAX;
    for (int axis = 0; axis < 3; axis++) {
        float extent = cb->hi[axis] - cb->lo[axis];
        if (!(extent > 0.0f))
            continue;
        float scale = BINS / extent;
        aabb bin_box[BINS];
        uint32_t bin_count[BINS] = {0};
        for (int i = 0; i < BINS; i++)
            aabb_empty(&bin_box[i]);
        for (uint32_t i = begin; i < end; i++) {
            uint32_t p = b->index[i];
            int bin = bin_of(b->centroid[p][axis], cb->lo[axis], scale);
            bin_count[bin]++;
            aabb_grow(&bin_box[bin], b->bounds[p].lo, b->bounds[p].hi);
        }
        /* Sweep from the right, then from the left, accumulating area x count. */
        float right_cost[BINS];
        aabb acc;
        aabb_empty(&acc);
        uint32_t n = 0;
        for (int i = BINS - 1; i > 0; i--) {
            aabb_grow(&acc, bin_box[i].lo, bin_box[i].hi);
            n += bin_count[i];
            right_cost[i] = aabb_area(&acc) * (float)n;
        }
        aabb_empty(&acc);
        n = 0;
        for (int i = 0; i < BINS - 1; i++) {
            aabb_grow(&acc, bin_box[i].lo, bin_box[i].hi);
            n += bin_count[i];
            uint32_t right_n = (end - begin) - n;
            if (n == 0 || right_n == 0)
                continue;
            float cost = aabb_area(&acc) * (float)n + right_cost[i + 1];
            if (cost < best) {
                best = cost;
                *axis_out = axis;
                *bin_out = i + 1;
            }
        }
    }
    return best;
}

static void make_leaf(builder *b, GpuNode *node, uint32_t begin, uint32_t end)
{
    node->first = begin;
    node->count = end - begin;
    (void)b;
}

static void build_node(builder *b, uint32_t node_index, uint32_t begin, uint32_t end,
                       uint32_t depth)
{
    GpuNode *node = &b->nodes[node_index];
    aabb centroids;
    aabb box = range_bounds(b, begin, end, &centroids);
    memcpy(node->bmin, box.lo, sizeof node->bmin);
    memcpy(node->bmax, box.hi, sizeof node->bmax);
    if (depth > b->depth)
        b->depth = depth;
    uint32_t count = end - begin;
    if (count <= 1 || (depth >= b->max_depth && count <= NS_BVH_LEAF_ENTRY_MAX)) {
        make_leaf(b, node, begin, end);
        return;
    }
    if (depth >= b->max_depth) { /* too many for a leaf's stack entry: halve, no SAH */
        uint32_t left = b->node_count, mid = begin + count / 2;
        b->node_count += 2;
        node->first = left;
        node->count = 0;
        build_node(b, left, begin, mid, depth + 1);
        build_node(b, left + 1, mid, end, depth + 1);
        return;
    }

    int axis = -1, split_bin = 0;
    float sah = best_split(b, begin, end, &centroids, &axis, &split_bin);
    float area = aabb_area(&box);
    float leaf_cost = COST_INTERSECT * (float)count;
    float split_cost = area > 0.0f ? COST_TRAVERSE + COST_INTERSECT * sah / area : leaf_cost;
    if (count <= NS_BVH_LEAF_MAX && (axis < 0 || split_cost >= leaf_cost)) {
        make_leaf(b, node, begin, end);
        return;
    }

    uint32_t mid;
    if (axis >= 0) {
        float scale = BINS / (centroids.hi[axis] - centroids.lo[axis]);
        uint32_t i = begin, j = end;
        while (i < j) {
            if (bin_of(b->centroid[b->index[i]][axis], centroids.lo[axis], scale) < split_bin) {
                i++;
            } else {
                uint32_t t = b->index[i];
                b->index[i] = b->index[--j];
                b->index[j] = t;
            }
        }
        mid = i;
    } else {
        /* All centroids coincide: no split separates them, so halve the range. */
        mid = begin + count / 2;
    }
    if (mid == begin || mid == end)
        mid = begin + count / 2;

    uint32_t left = b->node_count;
    b->node_count += 2;
    node->first = left;
    node->count = 0;
    build_node(b, left, begin, mid, depth + 1);
    build_node(b, left + 1, mid, end, depth + 1);
}

int ns_bvh_build(const GpuPrim *prims, uint32_t count, ns_bvh *out, ns_error *err)
{
    return ns_bvh_build_limited(prims, count, NS_BVH_MAX_DEPTH, out, err);
}

int ns_bvh_build_limited(const GpuPrim *prims, uint32_t count, uint32_t max_depth, ns_bvh *out,
                         ns_error *err)
{
    memset(out, 0, sizeof *out);
    if (count == 0)
        return NS_OK;
    /* A scene cannot reach this (scene_check.c's limits, asserted below): only a direct
     * caller of the render library's internals can. */
    if (count > NS_BVH_MAX_PRIMS)
        return ns_fail(err, NS_ERR_LIMIT, "%u primitives in the BVH; at most %u", count,
                       NS_BVH_MAX_PRIMS);
    builder b = {.max_depth = max_depth < NS_BVH_MAX_DEPTH ? max_depth : NS_BVH_MAX_DEPTH};
    b.bounds = malloc(sizeof *b.bounds * count);
    b.centroid = malloc(sizeof *b.centroid * count);
    b.index = malloc(sizeof *b.index * count);
    /* A binary tree with leaves of at least one primitive has at most 2n - 1 nodes. */
    b.nodes = calloc(2 * (size_t)count - 1, sizeof *b.nodes);
    out->prims = malloc(sizeof *out->prims * count);
    if (!b.bounds || !b.centroid || !b.index || !b.nodes || !out->prims) {
        free(b.bounds);
        free(b.centroid);
        free(b.index);
        free(b.nodes);
        ns_bvh_free(out);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "BVH over %u primitives: out of memory",
                       count);
    }
    for (uint32_t i = 0; i < count; i++) {
        ns_prim_bounds(&prims[i], b.bounds[i].lo, b.bounds[i].hi);
        for (int k = 0; k < 3; k++)
            b.centroid[i][k] = 0.5f * (b.bounds[i].lo[k] + b.bounds[i].hi[k]);
        b.index[i] = i;
    }
    b.node_count = 1;
    build_node(&b, 0, 0, count, 1);

    for (uint32_t i = 0; i < count; i++)
        out->prims[i] = prims[b.index[i]];
    out->nodes = b.nodes;
    out->node_count = b.node_count;
    out->prim_count = count;
    out->order = b.index;
    out->depth = b.depth;
    free(b.bounds);
    free(b.centroid);
    return NS_OK;
}

void ns_bvh_free(ns_bvh *bvh)
{
    free(bvh->nodes);
    free(bvh->prims);
    free(bvh->order);
    memset(bvh, 0, sizeof *bvh);
}
