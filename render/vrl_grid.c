/* vrl_grid.c — the hierarchy of regular grids over one medium's VRL origins (paper Section
 * 4.3), on the CPU.
 *
 * Lattice: cubic cells anchored at the minimum of the origins. The finest level has R0 cells
 * per axis, R0 = the smallest power of two >= extent / mfp_min, clamped to [2, 64]: cells of
 * about one mean free path, since the tables vary on that scale and finer cells would only
 * add cells to visit. Level i + 1 merges the 2 x 2 x 2 cells of level i (coordinates >> 1);
 * there are log2(R0) + 1 levels, clamped to [2, 5].
 *
 * One sort serves every level: VRLs are ordered by the Morton code of their finest cell, and
 * the Morton code of the level-i cell is that code >> 3i, so every cell of every level is a
 * contiguous run.
 *
 * Level for the gather: the finest level whose non-empty cells hold at least
 * NS_VRL_CELL_FILL VRLs on average (the coarsest if none does). The gather visits every cell
 * (a box test, about one VRL's cost) and then the VRLs of the cells it keeps, so cells much
 * emptier than that make the cell loop the cost, while coarser cells than needed cull less.
 * Small mfp and many VRLs give fine cells; few VRLs give coarse ones.
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
    double ratio = (double)extent / mfp_min;
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

static uint32_t cells_at_level(const keyed_vrl *sorted, uint32_t n, uint32_t level)
{
    uint32_t cells = 0;
    for (uint32_t i = 0; i < n; i++)
        cells += i == 0 || (sorted[i].key >> (3 * level)) != (sorted[i - 1].key >> (3 * level));
    return cells;
}

static uint32_t choose_level(const keyed_vrl *sorted, uint32_t n, uint32_t levels)
{
    for (uint32_t level = 0; level + 1 < levels; level++)
        if (n >= NS_VRL_CELL_FILL * (uint64_t)cells_at_level(sorted, n, level))
            return level;
    return levels - 1;
}

GpuVrl ns_vrl_representative(const GpuVrl *vrls, uint32_t count)
{
    GpuVrl r;
    memset(&r, 0, sizeof r);
    double weight = 0, origin[3] = {0, 0, 0}, dir[3] = {0, 0, 0};
    for (uint32_t k = 0; k < count; k++) {
        double w = (vrls[k].power[0] + vrls[k].power[1] + vrls[k].power[2]) / 3.0;
        for (int i = 0; i < 3; i++) {
            r.power[i] += vrls[k].power[i];
            origin[i] += w * vrls[k].origin[i];
            dir[i] += w * vrls[k].direction[i];
        }
        weight += w;
        r.length = fmaxf(r.length, vrls[k].length);
    }
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

int ns_vrl_grid_build_level(const ns_vrl_set *set, uint32_t material, float mfp_min, uint32_t level,
                            ns_vrl_grid *out, ns_error *err)
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
            sorted[j++] = (keyed_vrl){finest_key(&lattice, set->vrls[i].origin), i};
    qsort(sorted, n, sizeof *sorted, compare_keyed);
    if (level == NS_VRL_GRID_AUTO)
        level = choose_level(sorted, n, lattice.levels);
    out->vrl_count = n;
    out->cell_count = cells_at_level(sorted, n, level);
    out->level = level;
    out->level_count = lattice.levels;
    out->cell_size = ldexpf(lattice.size0, (int)level);
    out->vrls = malloc(sizeof *out->vrls * n);
    out->cells = malloc(sizeof *out->cells * out->cell_count);
    out->representatives = malloc(sizeof *out->representatives * out->cell_count);
    if (!out->vrls || !out->cells || !out->representatives) {
        free(sorted);
        ns_vrl_grid_free(out);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl grid: %u VRLs", n);
    }
    for (uint32_t i = 0; i < n; i++)
        out->vrls[i] = set->vrls[sorted[i].index];
    fill_cells(out, sorted, level);
    free(sorted);
    return NS_OK;
}

int ns_vrl_grid_build(const ns_vrl_set *set, uint32_t material, float mfp_min, ns_vrl_grid *out,
                      ns_error *err)
{
    return ns_vrl_grid_build_level(set, material, mfp_min, NS_VRL_GRID_AUTO, out, err);
}

void ns_vrl_grid_free(ns_vrl_grid *grid)
{
    free(grid->vrls);
    free(grid->cells);
    free(grid->representatives);
    memset(grid, 0, sizeof *grid);
}
