/* vrl_grid.c — the hierarchy of regular grids over one medium's VRL origins (paper Section
 * 4.3), on the CPU.
 *
 * Lattice: cubic cells anchored at the minimum of the origins. The finest level has R0 cells
 * per axis, R0 = the smallest power of two >= NS_VRL_CELLS_PER_MFP * extent / mfp_min,
 * clamped to [2, 64]; level i + 1 merges the 2 x 2 x 2 cells of level i (coordinates >> 1);
 * there are log2(R0) + 1 levels, clamped to [2, 5]. Cells of an eighth of a mean free path
 * at the finest level: the solid-angle option (render.cull_solid_angle) lets a node stand
 * for its VRLs from a distance proportional to its size, so small leaves near the segment
 * and large nodes far from it are what make it cheap (docs/scattering.md measures it).
 *
 * Direction classes: VRLs are first split by the cell of their direction on a 4 x 4
 * octahedral map, then by space. A representative has one direction, and one for VRLs of
 * every direction (the environment's, through one face) was the largest error of the
 * option: 0.59% against 0.19% with the point light alone (docs/scattering.md).
 *
 * One sort serves every level: VRLs are ordered by direction class, then by the Morton
 * code of their finest cell; the key of the level-i cell is that key >> 3i, so every cell
 * of every level is a contiguous run.
 *
 * Leaf level: the finest level whose non-empty cells hold at least leaf_fill VRLs on
 * average (the coarsest if none does): NS_VRL_CELL_FILL (16) for the exact gather, which
 * visits every node it does not cull and evaluates all their VRLs, so emptier leaves make
 * the node visits the cost; NS_VRL_LEAF_FILL_REPRESENTED (4) with the solid-angle option.
 *
 * Tree: the cells of every level from the coarsest down to the leaf level in depth-first
 * order (GpuVrlNode), an inner cell with a single child left out.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "vrl_grid.h"

typedef struct keyed_vrl {
    uint32_t key;   /* Morton code of the finest cell */
    uint32_t index; /* into the set: ties keep path order */
} keyed_vrl;

static int compare_keyed(const void *a, const void *b)
{
    const keyed_vrl *x = a, *y = b;
    if (x->key != y->key)
        return x->key < y->key ? -1 : 1;
    return x->index < y->index ? -1 : x->index > y->index;
}

/* Spreads the low 6 bits of v to every third bit. */
static uint32_t spread_bits(uint32_t v)
{
    uint32_t r = 0;
    for (int b = 0; b < 6; b++)
        r |= ((v >> b) & 1u) << (3 * b);
    return r;
}

typedef struct grid_lattice {
    float lo[3];
    float size0;     /* finest cell edge */
    uint32_t r0;     /* finest cells per axis */
    uint32_t levels; /* 2 to 5 */
} grid_lattice;

static void lattice_for(const ns_vrl_set *set, uint32_t material, float mfp_min, grid_lattice *g)
{
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (uint32_t i = 0; i < set->count; i++) {
        if (set->vrls[i].material != material)
            continue;
        for (int k = 0; k < 3; k++) {
            lo[k] = fminf(lo[k], set->vrls[i].origin[k]);
            hi[k] = fmaxf(hi[k], set->vrls[i].origin[k]);
        }
    }
    float extent = fmaxf(hi[0] - lo[0], fmaxf(hi[1] - lo[1], hi[2] - lo[2]));
    if (!(extent > 0.0f))
        extent = 1e-20f; /* every origin in one point: one cell whatever the size */
    double ratio = (double)extent / mfp_min * NS_VRL_CELLS_PER_MFP;
    uint32_t r0 = 2;
    while (r0 < NS_VRL_GRID_MAX_RESOLUTION && r0 < ratio)
        r0 *= 2;
    uint32_t levels = 1;
    while ((r0 >> levels) >= 1 && levels < 5)
        levels++;
    memcpy(g->lo, lo, sizeof lo);
    g->size0 = extent / (float)r0;
    g->r0 = r0;
    g->levels = levels < 2 ? 2 : levels;
}

static uint32_t finest_key(const grid_lattice *g, const float origin[3])
{
    uint32_t key = 0;
    for (int k = 0; k < 3; k++) {
        float x = (origin[k] - g->lo[k]) / g->size0;
        uint32_t c = x > 0.0f ? (uint32_t)x : 0;
        if (c > g->r0 - 1)
            c = g->r0 - 1;
        key |= spread_bits(c) << k;
    }
    return key;
}

/* Direction class of a VRL: its direction's cell on an N x N octahedral map. */
static uint32_t direction_class(const float d[3])
{
    const uint32_t n = NS_VRL_DIRECTION_CLASSES;
    float l1 = fabsf(d[0]) + fabsf(d[1]) + fabsf(d[2]);
    float u = l1 > 0 ? d[0] / l1 : 0, v = l1 > 0 ? d[1] / l1 : 0;
    if (d[2] < 0) {
        float fu = (1 - fabsf(v)) * (u < 0 ? -1.0f : 1.0f), fv = (1 - fabsf(u)) * (v < 0 ? -1.0f : 1.0f);
        u = fu;
        v = fv;
    }
    uint32_t iu = (uint32_t)((u + 1) * 0.5f * n), iv = (uint32_t)((v + 1) * 0.5f * n);
    iu = iu > n - 1 ? n - 1 : iu;
    iv = iv > n - 1 ? n - 1 : iv;
    return iv * n + iu;
}

/* The sort key: direction class above the Morton code of the finest cell (18 bits), so that
 * key >> 3i is the cell of level i within its class. */
static uint32_t vrl_key(const grid_lattice *g, const GpuVrl *v)
{
    return direction_class(v->direction) << 18 | finest_key(g, v->origin);
}

static uint32_t cells_at_level(const keyed_vrl *sorted, uint32_t n, uint32_t level)
{
    uint32_t cells = 0;
    for (uint32_t i = 0; i < n; i++)
        cells += i == 0 || (sorted[i].key >> (3 * level)) != (sorted[i - 1].key >> (3 * level));
    return cells;
}

static uint32_t choose_level(const keyed_vrl *sorted, uint32_t n, uint32_t levels, uint32_t fill)
{
    for (uint32_t level = 0; level + 1 < levels; level++)
        if (n >= (uint64_t)fill * cells_at_level(sorted, n, level))
            return level;
    return levels - 1;
}

GpuVrl ns_vrl_representative(const GpuVrl *vrls, uint32_t count)
{
    GpuVrl r;
    memset(&r, 0, sizeof r);
    double weight = 0, origin[3] = {0, 0, 0}, dir[3] = {0, 0, 0}, length = 0;
    int endless = 0;
    for (uint32_t k = 0; k < count; k++) {
        double w = (vrls[k].power[0] + vrls[k].power[1] + vrls[k].power[2]) / 3.0;
        for (int i = 0; i < 3; i++) {
            r.power[i] += vrls[k].power[i];
            origin[i] += w * vrls[k].origin[i];
            dir[i] += w * vrls[k].direction[i];
        }
        weight += w;
        length += w * vrls[k].length;
        endless |= vrls[k].length <= 0.0f;
    }
    /* The gather subtracts the beam past a VRL's exit: the representative's ends where its
     * VRLs' do on average, and never if one of them is endless (length 0). */
    r.length = endless || weight <= 0 ? 0.0f : (float)(length / weight);
    double norm = sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    for (int i = 0; i < 3; i++) {
        r.origin[i] = (float)(weight > 0 ? origin[i] / weight : vrls[0].origin[i]);
        r.direction[i] = (float)(norm > 0 ? dir[i] / norm : vrls[0].direction[i]);
    }
    r.material = vrls[0].material;
    return r;
}

static void fill_cells(ns_vrl_grid *g, const keyed_vrl *sorted, uint32_t level)
{
    uint32_t c = 0;
    for (uint32_t i = 0; i < g->vrl_count; i++) {
        if (i > 0 && (sorted[i].key >> (3 * level)) == (sorted[i - 1].key >> (3 * level))) {
            g->cells[c - 1].count++;
            continue;
        }
        g->cells[c++] = (GpuVrlCell){.first = i, .count = 1};
    }
    for (c = 0; c < g->cell_count; c++) {
        GpuVrlCell *cell = &g->cells[c];
        const GpuVrl *v = g->vrls + cell->first;
        memcpy(cell->bmin, v[0].origin, sizeof cell->bmin);
        memcpy(cell->bmax, v[0].origin, sizeof cell->bmax);
        for (uint32_t k = 1; k < cell->count; k++)
            for (int a = 0; a < 3; a++) {
                cell->bmin[a] = fminf(cell->bmin[a], v[k].origin[a]);
                cell->bmax[a] = fmaxf(cell->bmax[a], v[k].origin[a]);
            }
        g->representatives[c] = ns_vrl_representative(v, cell->count);
    }
}

/* The tree over the levels [leaf_level, levels): emit_subtree writes the node of one cell of
 * `level`, whose VRLs are sorted[lo, hi), then its children's subtrees, then its skip. */
typedef struct tree_builder {
    ns_vrl_grid *g;
    const keyed_vrl *sorted;
    uint32_t leaf_level;
} tree_builder;

static uint32_t run_end(const keyed_vrl *sorted, uint32_t lo, uint32_t hi, uint32_t level)
{
    uint32_t key = sorted[lo].key >> (3 * level), i = lo + 1;
    while (i < hi && (sorted[i].key >> (3 * level)) == key)
        i++;
    return i;
}

static void emit_subtree(tree_builder *b, uint32_t level, uint32_t lo, uint32_t hi)
{
    ns_vrl_grid *g = b->g;
    /* A cell whose VRLs all lie in one child adds a node to visit and nothing to cull or
     * represent that the child does not: the child stands for it. */
    while (level > b->leaf_level && run_end(b->sorted, lo, hi, level - 1) == hi)
        level--;
    uint32_t index = g->node_count++;
    GpuVrlNode *node = &g->nodes[index];
    const GpuVrl *v = g->vrls + lo;
    *node = (GpuVrlNode){.first = lo, .count = hi - lo, .leaf = level == b->leaf_level, .level = level};
    memcpy(node->bmin, v[0].origin, sizeof node->bmin);
    memcpy(node->bmax, v[0].origin, sizeof node->bmax);
    for (uint32_t k = 1; k < hi - lo; k++)
        for (int a = 0; a < 3; a++) {
            node->bmin[a] = fminf(node->bmin[a], v[k].origin[a]);
            node->bmax[a] = fmaxf(node->bmax[a], v[k].origin[a]);
        }
    g->node_representatives[index] = ns_vrl_representative(v, hi - lo);
    if (!node->leaf)
        for (uint32_t a = lo; a < hi;) {
            uint32_t end = run_end(b->sorted, a, hi, level - 1);
            emit_subtree(b, level - 1, a, end);
            a = end;
        }
    g->nodes[index].skip = g->node_count; /* nodes may have moved: no pointer kept */
}

static void build_tree(ns_vrl_grid *g, const keyed_vrl *sorted)
{
    tree_builder b = {.g = g, .sorted = sorted, .leaf_level = g->level};
    for (uint32_t lo = 0; lo < g->vrl_count;) {
        uint32_t end = run_end(sorted, lo, g->vrl_count, g->level_count - 1);
        emit_subtree(&b, g->level_count - 1, lo, end);
        lo = end;
    }
}

int ns_vrl_grid_build_level(const ns_vrl_set *set, uint32_t material, float mfp_min,
                            uint32_t leaf_fill, uint32_t level, ns_vrl_grid *out, ns_error *err)
{
    memset(out, 0, sizeof *out);
    if (!(mfp_min > 0.0f))
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "vrl grid: mfp_min %g must be positive",
                       (double)mfp_min);
    uint32_t n = 0;
    for (uint32_t i = 0; i < set->count; i++)
        n += set->vrls[i].material == material;
    if (!n)
        return NS_OK; /* no VRL in this medium: an empty grid, no level */
    grid_lattice lattice;
    lattice_for(set, material, mfp_min, &lattice);
    if (level != NS_VRL_GRID_AUTO && level >= lattice.levels)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "vrl grid: level %u, the medium has %u", level,
                       lattice.levels);
    keyed_vrl *sorted = malloc(sizeof *sorted * n);
    if (!sorted)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl grid: %u VRLs", n);
    for (uint32_t i = 0, j = 0; i < set->count; i++)
        if (set->vrls[i].material == material)
            sorted[j++] = (keyed_vrl){vrl_key(&lattice, &set->vrls[i]), i};
    qsort(sorted, n, sizeof *sorted, compare_keyed);
    if (level == NS_VRL_GRID_AUTO)
        level = choose_level(sorted, n, lattice.levels, leaf_fill ? leaf_fill : NS_VRL_CELL_FILL);
    out->vrl_count = n;
    out->cell_count = cells_at_level(sorted, n, level);
    out->level = level;
    out->level_count = lattice.levels;
    out->cell_size = ldexpf(lattice.size0, (int)level);
    out->vrls = malloc(sizeof *out->vrls * n);
    out->cells = malloc(sizeof *out->cells * out->cell_count);
    out->representatives = malloc(sizeof *out->representatives * out->cell_count);
    /* Every inner node kept has two children at least: fewer nodes than twice the leaves. */
    out->nodes = malloc(sizeof *out->nodes * 2 * out->cell_count);
    out->node_representatives = malloc(sizeof *out->node_representatives * 2 * out->cell_count);
    if (!out->vrls || !out->cells || !out->representatives || !out->nodes || !out->node_representatives) {
        free(sorted);
        ns_vrl_grid_free(out);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl grid: %u VRLs", n);
    }
    for (uint32_t i = 0; i < n; i++)
        out->vrls[i] = set->vrls[sorted[i].index];
    fill_cells(out, sorted, level);
    build_tree(out, sorted);
    free(sorted);
    return NS_OK;
}

int ns_vrl_grid_build(const ns_vrl_set *set, uint32_t material, float mfp_min, uint32_t leaf_fill,
                      ns_vrl_grid *out, ns_error *err)
{
    return ns_vrl_grid_build_level(set, material, mfp_min, leaf_fill, NS_VRL_GRID_AUTO, out, err);
}

void ns_vrl_grid_free(ns_vrl_grid *grid)
{
    free(grid->vrls);
    free(grid->cells);
    free(grid->representatives);
    free(grid->nodes);
    free(grid->node_representatives);
    memset(grid, 0, sizeof *grid);
}
