/* unit_vrl_grid.c — the VRL grid hierarchy (render/vrl_grid.c): every VRL of the medium in
 * exactly one cell, cells contiguous and covering the sorted buffer, boxes around their
 * origins, representatives that sum the power and average origin and direction by power,
 * the documented lattice (cells of level i are the finest cells >> i, so level i + 1 merges
 * 2 x 2 x 2 cells of level i, within direction classes), the level count and the level rule,
 * the depth-first tree over the levels the gather walks, and bad arguments. */
#include <stdlib.h>

#include "harness.h"
#include "vrl_grid.h"

static uint32_t rng = 2024u;
static float uniform01(void)
{
    rng = rng * 1664525u + 1013904223u;
    return (float)(rng >> 8) * (1.0f / 16777216.0f);
}

/* n VRLs, origins in [-1, 1]^3 (clustered towards one corner so cells fill unevenly), every
 * fifth in material 1; events carries the VRL's index so the tests can follow it. */
static ns_vrl_set random_set(uint32_t n)
{
    ns_vrl_set set = {.vrls = calloc(n, sizeof(GpuVrl)), .count = n, .paths = n};
    for (uint32_t i = 0; i < n; i++) {
        GpuVrl *v = &set.vrls[i];
        for (int k = 0; k < 3; k++) {
            float u = uniform01();
            v->origin[k] = 2 * u * u - 1;
            v->power[k] = uniform01() + 0.01f;
        }
        float z = 2 * uniform01() - 1, phi = 6.2831853f * uniform01(), r = sqrtf(1 - z * z);
        v->direction[0] = r * cosf(phi);
        v->direction[1] = r * sinf(phi);
        v->direction[2] = z;
        v->length = uniform01();
        v->material = i % 5 == 4 ? 1 : 0;
        v->events = i;
    }
    return set;
}

typedef struct lattice {
    float lo[3];
    float s0;
    uint32_t r0;
} lattice;

static lattice lattice_of(const ns_vrl_set *set, uint32_t material, const ns_vrl_grid *g)
{
    lattice l = {{INFINITY, INFINITY, INFINITY}, 0, 0};
    float hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (uint32_t i = 0; i < set->count; i++)
        if (set->vrls[i].material == material)
            for (int k = 0; k < 3; k++) {
                l.lo[k] = fminf(l.lo[k], set->vrls[i].origin[k]);
                hi[k] = fmaxf(hi[k], set->vrls[i].origin[k]);
            }
    float extent = fmaxf(hi[0] - l.lo[0], fmaxf(hi[1] - l.lo[1], hi[2] - l.lo[2]));
    l.s0 = ldexpf(g->cell_size, -(int)g->level);
    l.r0 = (uint32_t)lroundf(extent / l.s0);
    return l;
}

/* The documented direction class of a VRL (vrl_grid.h): the cell of its direction on an
 * N x N octahedral map, N = NS_VRL_DIRECTION_CLASSES. */
static uint32_t expected_class(const float d[3])
{
    const float n = (float)NS_VRL_DIRECTION_CLASSES;
    float l1 = fabsf(d[0]) + fabsf(d[1]) + fabsf(d[2]);
    float u = d[0] / l1, v = d[1] / l1;
    if (d[2] < 0) {
        float fu = (1 - fabsf(v)) * (u < 0 ? -1.0f : 1.0f), fv = (1 - fabsf(u)) * (v < 0 ? -1.0f : 1.0f);
        u = fu;
        v = fv;
    }
    uint32_t iu = (uint32_t)fminf((u + 1) * 0.5f * n, n - 1), iv = (uint32_t)fminf((v + 1) * 0.5f * n, n - 1);
    return iv * NS_VRL_DIRECTION_CLASSES + iu;
}

/* The documented cell of a VRL at `level` (vrl_grid.h) within its direction class, packed
 * into one integer. */
static uint32_t expected_cell(const lattice *l, const GpuVrl *vrl, uint32_t level)
{
    uint32_t packed = expected_class(vrl->direction) << 24;
    for (int k = 0; k < 3; k++) {
        float x = (vrl->origin[k] - l->lo[k]) / l->s0;
        uint32_t c = x > 0.0f ? (uint32_t)x : 0;
        if (c > l->r0 - 1)
            c = l->r0 - 1;
        packed |= (c >> level) << (8 * k);
    }
    return packed;
}

/* The tree (GpuVrlNode): depth first, skip past the subtree, leaves = the cells in order,
 * inner nodes with two children at least whose runs tile theirs, boxes and representatives
 * of their VRLs, leaves at the chosen level and inner nodes above it. */
static void check_tree(const ns_vrl_grid *g)
{
    CHECK(g->node_count >= g->cell_count && g->node_count < 2 * g->cell_count + 1);
    uint32_t leaves = 0, bad = 0, next_vrl = 0;
    for (uint32_t i = 0; i < g->node_count; i++) {
        const GpuVrlNode *n = &g->nodes[i];
        bad += n->skip <= i || n->skip > g->node_count || n->count == 0;
        if (n->leaf) {
            const GpuVrlCell *c = &g->cells[leaves++];
            bad += n->skip != i + 1 || n->level != g->level || n->first != c->first ||
                   n->count != c->count || memcmp(n->bmin, c->bmin, sizeof n->bmin) ||
                   memcmp(n->bmax, c->bmax, sizeof n->bmax);
            bad += n->first != next_vrl;
            next_vrl = n->first + n->count;
            continue;
        }
        uint32_t children = 0, covered = n->first;
        float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        for (uint32_t c = i + 1; c < n->skip; c = g->nodes[c].skip) {
            const GpuVrlNode *child = &g->nodes[c];
            children++;
            bad += child->first != covered || child->level >= n->level || child->skip > n->skip;
            covered = child->first + child->count;
            for (int a = 0; a < 3; a++) {
                lo[a] = fminf(lo[a], child->bmin[a]);
                hi[a] = fmaxf(hi[a], child->bmax[a]);
            }
        }
        bad += children < 2 || covered != n->first + n->count || n->level <= g->level;
        for (int a = 0; a < 3; a++)
            bad += lo[a] != n->bmin[a] || hi[a] != n->bmax[a];
        double power = 0;
        for (uint32_t k = n->first; k < n->first + n->count; k++)
            power += g->vrls[k].power[0];
        bad += fabs(g->node_representatives[i].power[0] - power) > 1e-5 * power;
    }
    CHECK_INT(leaves, g->cell_count);
    CHECK_INT(bad, 0);
    /* The roots (reached by skips from 0) cover every VRL. */
    uint32_t covered = 0;
    for (uint32_t i = 0; i < g->node_count; i = g->nodes[i].skip)
        covered += g->nodes[i].count;
    CHECK_INT(covered, g->vrl_count);
}

/* cell_of[id] = index of the cell holding VRL id (NS_NONE when absent). */
static void check_level(const ns_vrl_set *set, const ns_vrl_grid *g, uint32_t *cell_of)
{
    uint32_t in_medium = 0;
    for (uint32_t i = 0; i < set->count; i++) {
        in_medium += set->vrls[i].material == 0;
        cell_of[i] = NS_NONE;
    }
    CHECK_INT(g->vrl_count, in_medium);
    CHECK(g->cell_count >= 1 && g->cell_count <= g->vrl_count);
    lattice l = lattice_of(set, 0, g);
    uint32_t next = 0, twice = 0, wrong_material = 0, outside_box = 0, loose_box = 0;
    uint32_t mixed = 0, bad_power = 0, bad_origin = 0, bad_direction = 0;
    for (uint32_t c = 0; c < g->cell_count; c++) {
        const GpuVrlCell *cell = &g->cells[c];
        CHECK_INT(cell->first, next);
        CHECK(cell->count >= 1);
        next = cell->first + cell->count;
        double power[3] = {0, 0, 0}, origin[3] = {0, 0, 0}, dir[3] = {0, 0, 0}, weight = 0;
        float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        uint32_t key = expected_cell(&l, &g->vrls[cell->first], g->level);
        for (uint32_t k = cell->first; k < next && k < g->vrl_count; k++) {
            const GpuVrl *v = &g->vrls[k];
            twice += v->events < set->count && cell_of[v->events] != NS_NONE;
            if (v->events < set->count)
                cell_of[v->events] = c;
            wrong_material += v->material != 0;
            mixed += expected_cell(&l, v, g->level) != key;
            double w = (v->power[0] + v->power[1] + v->power[2]) / 3.0;
            weight += w;
            for (int a = 0; a < 3; a++) {
                outside_box += v->origin[a] < cell->bmin[a] || v->origin[a] > cell->bmax[a];
                lo[a] = fminf(lo[a], v->origin[a]);
                hi[a] = fmaxf(hi[a], v->origin[a]);
                power[a] += v->power[a];
                origin[a] += w * v->origin[a];
                dir[a] += w * v->direction[a];
            }
        }
        double norm = sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
        const GpuVrl *r = &g->representatives[c];
        for (int a = 0; a < 3; a++) {
            loose_box += lo[a] != cell->bmin[a] || hi[a] != cell->bmax[a] ||
                         hi[a] - lo[a] > g->cell_size * 1.0001f;
            bad_power += fabs(r->power[a] - power[a]) > 1e-5 * power[a];
            bad_origin += fabs(r->origin[a] - origin[a] / weight) > 1e-5;
            bad_direction += fabs(r->direction[a] - dir[a] / norm) > 1e-5;
        }
    }
    CHECK_INT(next, g->vrl_count);
    CHECK_INT(twice, 0);
    CHECK_INT(wrong_material, 0);
    CHECK_INT(outside_box, 0);
    CHECK_INT(loose_box, 0);
    CHECK_INT(mixed, 0);
    CHECK_INT(bad_power, 0);
    CHECK_INT(bad_origin, 0);
    CHECK_INT(bad_direction, 0);
    /* Every VRL of the medium is in a cell, none of the other medium's is; distinct cells
     * are distinct lattice cells. */
    uint32_t missing = 0;
    for (uint32_t i = 0; i < set->count; i++)
        missing += (set->vrls[i].material == 0) != (cell_of[i] != NS_NONE);
    CHECK_INT(missing, 0);
    uint32_t same_key = 0;
    for (uint32_t c = 1; c < g->cell_count; c++)
        for (uint32_t d = 0; d < c; d++)
            same_key += expected_cell(&l, &g->vrls[g->cells[c].first], g->level) ==
                        expected_cell(&l, &g->vrls[g->cells[d].first], g->level);
    CHECK_INT(same_key, 0);
}

static void test_levels(float mfp, uint32_t want_levels, uint32_t want_r0)
{
    ns_vrl_set set = random_set(3000);
    ns_error err = {0};
    ns_vrl_grid auto_grid;
    CHECK_INT(ns_vrl_grid_build(&set, 0, mfp, 0, &auto_grid, &err), NS_OK);
    CHECK_INT(auto_grid.level_count, want_levels);
    uint32_t levels = auto_grid.level_count;
    uint32_t *cells_of[5] = {0}, cell_counts[5] = {0};
    for (uint32_t level = 0; level < levels && level < 5; level++) {
        ns_vrl_grid g;
        CHECK_INT(ns_vrl_grid_build_level(&set, 0, mfp, 0, level, &g, &err), NS_OK);
        CHECK_INT(g.level, level);
        CHECK_INT(g.level_count, levels);
        CHECK_INT(lattice_of(&set, 0, &g).r0, want_r0);
        cells_of[level] = malloc(sizeof(uint32_t) * set.count);
        check_level(&set, &g, cells_of[level]);
        check_tree(&g);
        cell_counts[level] = g.cell_count;
        if (level > 0) {
            /* Merging: VRLs together at level - 1 stay together, and a cell gathers at
             * most 8 cells of the level below. */
            uint32_t split = 0, too_many = 0;
            uint32_t *children = calloc(g.cell_count, sizeof *children);
            uint32_t *parent = malloc(sizeof *parent * cell_counts[level - 1]);
            for (uint32_t c = 0; c < cell_counts[level - 1]; c++)
                parent[c] = NS_NONE;
            for (uint32_t a = 0; a < set.count; a++) {
                if (cells_of[level][a] == NS_NONE)
                    continue;
                uint32_t child = cells_of[level - 1][a];
                if (parent[child] == NS_NONE) {
                    parent[child] = cells_of[level][a];
                    children[parent[child]]++;
                }
                split += parent[child] != cells_of[level][a];
            }
            for (uint32_t c = 0; c < g.cell_count; c++)
                too_many += children[c] > 8 || children[c] == 0;
            CHECK_INT(split, 0);
            CHECK_INT(too_many, 0);
            CHECK(g.cell_count <= cell_counts[level - 1]);
            free(children);
            free(parent);
        }
        ns_vrl_grid_free(&g);
    }
    /* The rule: the finest level with at least NS_VRL_CELL_FILL VRLs per cell on average,
     * else the coarsest. */
    uint32_t want = levels - 1;
    for (uint32_t level = levels - 1; level-- > 0;)
        if (auto_grid.vrl_count >= NS_VRL_CELL_FILL * cell_counts[level])
            want = level;
    CHECK_INT(auto_grid.level, want);
    for (int i = 0; i < 5; i++)
        free(cells_of[i]);
    /* Deterministic. */
    ns_vrl_grid again;
    CHECK_INT(ns_vrl_grid_build(&set, 0, mfp, 0, &again, &err), NS_OK);
    CHECK(again.cell_count == auto_grid.cell_count &&
          !memcmp(again.vrls, auto_grid.vrls, sizeof(GpuVrl) * again.vrl_count) &&
          !memcmp(again.cells, auto_grid.cells, sizeof(GpuVrlCell) * again.cell_count));
    ns_vrl_grid_free(&again);
    ns_vrl_grid_free(&auto_grid);
    free(set.vrls);
}

/* Extent of the origins is just under 2: ratio 8 * extent / mfp (NS_VRL_CELLS_PER_MFP) decides the finest resolution
 * (power of two, 2..64) and the level count log2 + 1 (2..5). */
static void test_coarse_medium(void)
{
    test_levels(12.0f, 2, 2);
}
static void test_mid_medium(void)
{
    test_levels(2.4f, 4, 8);
}
static void test_fine_medium(void)
{
    test_levels(0.56f, 5, 32);
}
static void test_very_fine_medium(void)
{
    test_levels(0.001f, 5, 64);
}

static void test_level_follows_count(void)
{
    /* Few VRLs choose coarser cells than many VRLs in the same medium. */
    ns_vrl_set few = random_set(200), many = random_set(60000);
    ns_vrl_grid a, b;
    ns_error err = {0};
    CHECK_INT(ns_vrl_grid_build(&few, 0, 1.0f, 0, &a, &err), NS_OK);
    CHECK_INT(ns_vrl_grid_build(&many, 0, 1.0f, 0, &b, &err), NS_OK);
    CHECK(a.level > b.level);
    CHECK(a.vrl_count >= NS_VRL_CELL_FILL * a.cell_count || a.level + 1 == a.level_count);
    ns_vrl_grid_free(&a);
    ns_vrl_grid_free(&b);
    free(few.vrls);
    free(many.vrls);
}

static void test_degenerate_sets(void)
{
    ns_error err = {0};
    ns_vrl_grid g;
    /* No VRL of this medium: an empty grid. */
    ns_vrl_set set = random_set(10);
    CHECK_INT(ns_vrl_grid_build(&set, 7, 0.1f, 0, &g, &err), NS_OK);
    CHECK(g.vrl_count == 0 && g.cell_count == 0 && g.cells == NULL);
    ns_vrl_grid_free(&g);
    ns_vrl_set empty = {0};
    CHECK_INT(ns_vrl_grid_build(&empty, 0, 0.1f, 0, &g, &err), NS_OK);
    CHECK_INT(g.cell_count, 0);
    ns_vrl_grid_free(&g);
    /* Every origin in one point and one direction: one cell at every level. */
    for (uint32_t i = 0; i < set.count; i++) {
        memcpy(set.vrls[i].origin, set.vrls[0].origin, sizeof set.vrls[0].origin);
        memcpy(set.vrls[i].direction, set.vrls[0].direction, sizeof set.vrls[0].direction);
    }
    CHECK_INT(ns_vrl_grid_build_level(&set, 0, 0.1f, 0, 0, &g, &err), NS_OK);
    CHECK_INT(g.cell_count, 1);
    CHECK_INT(g.cells[0].count, g.vrl_count);
    ns_vrl_grid_free(&g);
    /* A medium that does not attenuate (mfp infinite): the coarsest lattice. */
    CHECK_INT(ns_vrl_grid_build(&set, 0, INFINITY, 0, &g, &err), NS_OK);
    CHECK_INT(g.level_count, 2);
    ns_vrl_grid_free(&g);
    /* Bad arguments name themselves. */
    CHECK_INT(ns_vrl_grid_build(&set, 0, 0.0f, 0, &g, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "mfp_min");
    CHECK_INT(ns_vrl_grid_build(&set, 0, NAN, 0, &g, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_INT(ns_vrl_grid_build_level(&set, 0, 1.0f, 0, 2, &g, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "level 2");
    CHECK(g.cells == NULL && g.vrls == NULL);
    free(set.vrls);
}

int main(void)
{
    RUN(test_coarse_medium);
    RUN(test_mid_medium);
    RUN(test_fine_medium);
    RUN(test_very_fine_medium);
    RUN(test_level_follows_count);
    RUN(test_degenerate_sets);
    return harness_report();
}
