/* unit_bvh.c — invariants of the CPU SAH builder (render/bvh.c): every primitive in exactly
 * one leaf, child bounds inside their parent's, leaf bounds around their primitives, the
 * tree within the traversal stack's depth, and splits that follow the geometry. */
#include <stdlib.h>

#include "bvh.h"
#include "harness.h"

static uint64_t rng = 12345;

static double uniform(double lo, double hi)
{
    rng = rng * 6364136223846793005ull + 1442695040888963407ull;
    return lo + (hi - lo) * (double)(rng >> 11) * (1.0 / 9007199254740992.0);
}

static GpuPrim random_prim(uint32_t i, double spread)
{
    GpuPrim p;
    memset(&p, 0, sizeof p);
    p.info[0] = i % 3;
    p.info[2] = i;
    for (int k = 0; k < 3; k++) {
        double c = uniform(-spread, spread);
        p.a[k] = (float)(p.info[0] == NS_PRIM_BOX ? c - 0.2 : c + uniform(-0.3, 0.3));
        p.b[k] = (float)(p.info[0] == NS_PRIM_BOX ? c + 0.2 : c + uniform(-0.3, 0.3));
        p.c[k] = (float)(c + uniform(-0.3, 0.3));
    }
    if (p.info[0] == NS_PRIM_SPHERE)
        p.a[3] = (float)uniform(0.05, 0.5);
    return p;
}

static int inside(const float lo[3], const float hi[3], const float outer_lo[3],
                  const float outer_hi[3])
{
    for (int k = 0; k < 3; k++)
        if (lo[k] < outer_lo[k] || hi[k] > outer_hi[k])
            return 0;
    return 1;
}

typedef struct {
    int bad_child, bad_leaf, oversized_leaves;
    uint32_t leaves;
    uint32_t *seen;
} walk_state;

static void walk(const ns_bvh *bvh, uint32_t index, uint32_t depth, walk_state *w)
{
    const GpuNode *n = &bvh->nodes[index];
    if (n->count > 0) {
        w->leaves++;
        if ((n->count > NS_BVH_LEAF_MAX && depth < NS_BVH_MAX_DEPTH) ||
            n->count > NS_BVH_LEAF_ENTRY_MAX)
            w->oversized_leaves++;
        for (uint32_t i = n->first; i < n->first + n->count && i < bvh->prim_count; i++) {
            w->seen[i]++;
            float lo[3], hi[3];
            ns_prim_bounds(&bvh->prims[i], lo, hi);
            w->bad_leaf += !inside(lo, hi, n->bmin, n->bmax);
        }
        return;
    }
    for (uint32_t c = n->first; c < n->first + 2; c++) {
        if (c >= bvh->node_count || c <= index) {
            w->bad_child++;
            continue;
        }
        w->bad_child += !inside(bvh->nodes[c].bmin, bvh->nodes[c].bmax, n->bmin, n->bmax);
        walk(bvh, c, depth + 1, w);
    }
}

static void check_tree(const GpuPrim *prims, uint32_t count)
{
    ns_bvh bvh;
    ns_error err = {0};
    CHECK_INT(ns_bvh_build(prims, count, &bvh, &err), NS_OK);
    CHECK_INT(bvh.prim_count, count);
    CHECK(bvh.node_count <= 2 * count - 1);
    CHECK(bvh.depth <= NS_BVH_MAX_DEPTH + 20 && bvh.depth < NS_BVH_STACK);
    walk_state w = {0};
    w.seen = calloc(count, sizeof *w.seen);
    walk(&bvh, 0, 1, &w);
    int once = 1;
    for (uint32_t i = 0; i < count; i++)
        once &= w.seen[i] == 1;
    CHECK(once); /* every primitive in exactly one leaf */
    CHECK_INT(w.bad_child, 0);
    CHECK_INT(w.bad_leaf, 0);
    CHECK_INT(w.oversized_leaves, 0);
    /* order is a permutation and prims[i] really is input order[i] */
    uint32_t *hits = calloc(count, sizeof *hits);
    int same = 1;
    for (uint32_t i = 0; i < count; i++) {
        if (bvh.order[i] < count)
            hits[bvh.order[i]]++;
        same &= memcmp(&bvh.prims[i], &prims[bvh.order[i] < count ? bvh.order[i] : 0],
                       sizeof(GpuPrim)) == 0;
    }
    int permutation = 1;
    for (uint32_t i = 0; i < count; i++)
        permutation &= hits[i] == 1;
    CHECK(permutation);
    CHECK(same);
    free(hits);
    free(w.seen);
    ns_bvh_free(&bvh);
}

static void test_random_scenes(void)
{
    static GpuPrim prims[5000];
    const uint32_t sizes[] = {1, 2, 3, 5, 17, 100, 1000, 5000};
    for (size_t s = 0; s < sizeof sizes / sizeof sizes[0]; s++) {
        for (uint32_t i = 0; i < sizes[s]; i++)
            prims[i] = random_prim(i, 10.0);
        check_tree(prims, sizes[s]);
    }
}

static void test_identical_primitives(void)
{
    static GpuPrim prims[300];
    for (uint32_t i = 0; i < 300; i++) {
        memset(&prims[i], 0, sizeof prims[i]);
        prims[i].info[0] = NS_PRIM_SPHERE;
        prims[i].a[3] = 1;
    }
    check_tree(prims, 300);
}

static void test_empty(void)
{
    ns_bvh bvh;
    CHECK_INT(ns_bvh_build(NULL, 0, &bvh, NULL), NS_OK);
    CHECK_INT(bvh.node_count, 0);
    ns_bvh_free(&bvh);
}

/* Two far-apart clusters: the SAH puts them on the two sides of the root. */
static void test_sah_separates_clusters(void)
{
    static GpuPrim prims[200];
    for (uint32_t i = 0; i < 200; i++) {
        prims[i] = random_prim(i, 1.0);
        float shift = i % 2 ? 100.0f : -100.0f;
        prims[i].a[0] += shift;
        prims[i].b[0] += shift;
        prims[i].c[0] += shift;
    }
    ns_bvh bvh;
    CHECK_INT(ns_bvh_build(prims, 200, &bvh, NULL), NS_OK);
    const GpuNode *l = &bvh.nodes[bvh.nodes[0].first], *r = l + 1;
    CHECK(l->bmax[0] < -90 || l->bmin[0] > 90);
    CHECK(r->bmax[0] < -90 || r->bmin[0] > 90);
    CHECK((l->bmax[0] < 0) != (r->bmax[0] < 0));
    ns_bvh_free(&bvh);
}

/* Past the depth limit: with the surface-area splits stopped at depth 3, 5000 primitives
 * reach it in leaves of hundreds, more than a leaf's stack entry holds, so they are halved
 * further: every leaf within NS_BVH_LEAF_ENTRY_MAX, each primitive once, inside the stack. */
static void test_leaves_past_depth_limit(void)
{
    static GpuPrim prims[5000];
    for (uint32_t i = 0; i < 5000; i++)
        prims[i] = random_prim(i, 10.0);
    ns_bvh bvh;
    CHECK_INT(ns_bvh_build_limited(prims, 5000, 3, &bvh, NULL), NS_OK);
    walk_state w = {0};
    w.seen = calloc(5000, sizeof *w.seen);
    walk(&bvh, 0, 1, &w);
    int once = 1, largest = 0;
    for (uint32_t i = 0; i < 5000; i++)
        once &= w.seen[i] == 1;
    CHECK(once);
    CHECK_INT(w.bad_child, 0);
    CHECK_INT(w.bad_leaf, 0);
    for (uint32_t i = 0; i < bvh.node_count; i++)
        if (bvh.nodes[i].count > (uint32_t)largest)
            largest = (int)bvh.nodes[i].count;
    CHECK(largest <= (int)NS_BVH_LEAF_ENTRY_MAX && largest > (int)NS_BVH_LEAF_MAX);
    CHECK(bvh.depth > 3 && bvh.depth <= 3 + 20);
    free(w.seen);
    ns_bvh_free(&bvh);
}

int main(void)
{
    RUN(test_random_scenes);
    RUN(test_identical_primitives);
    RUN(test_empty);
    RUN(test_sah_separates_clusters);
    RUN(test_leaves_past_depth_limit);
    return harness_report();
}
