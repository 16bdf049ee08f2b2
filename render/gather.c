/* gather.c — the gather stage's C side: its uniform block (table mapping, culling reach,
 * dipole constants), the nodes of the VRL hierarchy it walks and their split across
 * dispatches (lavapipe's loop limit), and the same walk on the CPU for the tests
 * (shaders/gather.comp is the GPU one). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scatter.h"

/* Jensen et al. 2001: diffuse Fresnel reflectance of a dielectric seen from inside (their
 * polynomial fit in eta) and the dipole constants per channel. */
static void dipole_constants(GpuGatherParams *p, const GpuMaterial *m)
{
    float eta = m->sigma_t[3], g = m->sigma_s[3];
    float f_dr = -1.440f / (eta * eta) + 0.710f / eta + 0.668f + 0.0636f * eta;
    float a = (1.0f + f_dr) / (1.0f - f_dr);
    for (int c = 0; c < 3; c++) {
        float sigma_a = fmaxf(m->sigma_t[c] - m->sigma_s[c], 0.0f);
        float sigma_s_reduced = m->sigma_s[c] * (1.0f - g);
        float sigma_t_reduced = sigma_s_reduced + sigma_a;
        float zr = sigma_t_reduced > 0.0f ? 1.0f / sigma_t_reduced : 0.0f;
        p->dipole_sigma_tr[c] = sqrtf(3.0f * sigma_a * sigma_t_reduced);
        p->dipole_zr[c] = zr;
        p->dipole_zv[c] = zr * (1.0f + 4.0f * a / 3.0f);
        p->dipole_alpha[c] = sigma_t_reduced > 0.0f ? sigma_s_reduced / sigma_t_reduced : 0.0f;
    }
}

void ns_gather_params(GpuGatherParams *p, const GpuMaterial *m, uint32_t mode,
                      const ns_scatter_tables *tables, float cull_solid_angle, int bounded_beams)
{
    memset(p, 0, sizeof *p);
    memcpy(p->sigma_t, m->sigma_t, sizeof p->sigma_t);
    p->counts[3] = mode;
    p->cull[1] = cull_solid_angle;
    float s_min = fminf(m->sigma_t[0], fminf(m->sigma_t[1], m->sigma_t[2]));
    if (mode == NS_GATHER_MODE_DIPOLE) {
        dipole_constants(p, m);
        /* R_d has fallen by e^-30 at 30 / sigma_tr: beyond that a cell adds nothing. */
        float str_min = fminf(p->dipole_sigma_tr[0], fminf(p->dipole_sigma_tr[1], p->dipole_sigma_tr[2]));
        p->cull[0] = str_min > 0.0f ? 30.0f / str_min : INFINITY;
    } else if (tables) {
        p->table_map[0] = tables->scale;
        p->table_map[1] = tables->inv_step;
        p->table_map[2] = tables->extent;
        p->table_map[3] = bounded_beams ? NS_BEAM_CUTOFF : 0.0f;
        /* A point farther than extent * sqrt(2) (mfp) from every origin of a cell lies outside
         * every VRL's table (|z| and rho both below the extent): the cell adds nothing. */
        p->cull[0] = s_min > 0.0f ? tables->extent * 1.41422f / s_min : INFINITY;
    }
}

/* ---------------------------------------------------------------------------------------
 * CPU reference: the shader's arithmetic, in the same order, in float.
 * ------------------------------------------------------------------------------------- */
static float dot3(const float *a, const float *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
static float clampf(float v, float lo, float hi) { return v < lo ? lo : v > hi ? hi : v; }

static uint32_t direction_bin(const float *w, const float *d, const float *e_rho)
{
    const float bins_per_radian = (float)NS_TABLE_NTHETA / 3.14159265358979f;
    float cos_theta = clampf(dot3(w, d), -1.0f, 1.0f);
    float w_perp[3] = {w[0] - cos_theta * d[0], w[1] - cos_theta * d[1], w[2] - cos_theta * d[2]};
    float perp = sqrtf(dot3(w_perp, w_perp));
    float cos_phi = perp > 1e-6f ? clampf(dot3(w_perp, e_rho) / perp, -1.0f, 1.0f) : 1.0f;
    uint32_t it = (uint32_t)(acosf(cos_theta) * bins_per_radian);
    uint32_t ip = (uint32_t)(acosf(cos_phi) * bins_per_radian);
    if (it > NS_TABLE_NTHETA - 1)
        it = NS_TABLE_NTHETA - 1;
    if (ip > NS_TABLE_NPHI - 1)
        ip = NS_TABLE_NPHI - 1;
    return it * NS_TABLE_NPHI + ip;
}

static int spatial_bin(const GpuGatherParams *p, float z, float rho)
{
    float extent = p->table_map[2];
    if (fabsf(z) >= extent || rho >= extent)
        return -1;
    int iz = (int)floorf(asinhf(z / p->table_map[0]) * p->table_map[1]) + (int)(NS_TABLE_NZ / 2);
    int ir = (int)floorf(asinhf(rho / p->table_map[0]) * p->table_map[1]);
    iz = iz < 0 ? 0 : iz > (int)NS_TABLE_NZ - 1 ? (int)NS_TABLE_NZ - 1 : iz;
    ir = ir < 0 ? 0 : ir > (int)NS_TABLE_NRHO - 1 ? (int)NS_TABLE_NRHO - 1 : ir;
    return iz * (int)NS_TABLE_NRHO + ir;
}

static void table_at(const GpuGatherParams *p, const float *table, const GpuVrl *v,
                     const float *point, const float *w, float a[3])
{
    float delta[3] = {point[0] - v->origin[0], point[1] - v->origin[1], point[2] - v->origin[2]};
    float z = dot3(delta, v->direction);
    float radial[3] = {delta[0] - z * v->direction[0], delta[1] - z * v->direction[1],
                       delta[2] - z * v->direction[2]};
    float rho = sqrtf(dot3(radial, radial));
    float e_rho[3] = {0, 0, 0};
    if (rho > 0.0f)
        for (int i = 0; i < 3; i++)
            e_rho[i] = radial[i] / rho;
    uint32_t dir = direction_bin(w, v->direction, e_rho);
    for (int c = 0; c < 3; c++) {
        float s = p->sigma_t[c];
        int cell = spatial_bin(p, z * s, rho * s);
        a[c] = cell >= 0 ? table[(size_t)c * NS_TABLE_CELLS +
                                 (size_t)cell * (NS_TABLE_NTHETA * NS_TABLE_NPHI) + dir]
                         : 0.0f;
    }
}

static void dipole_rd(const GpuGatherParams *p, float r, float rd[3])
{
    for (int c = 0; c < 3; c++) {
        float zr = p->dipole_zr[c], zv = p->dipole_zv[c], str = p->dipole_sigma_tr[c];
        float dr = sqrtf(r * r + zr * zr), dv = sqrtf(r * r + zv * zv);
        float real_source = zr * (str * dr + 1.0f) * expf(-str * dr) / (dr * dr * dr);
        float virtual_source = zv * (str * dv + 1.0f) * expf(-str * dv) / (dv * dv * dv);
        rd[c] = p->dipole_alpha[c] / (4.0f * 3.14159265358979f) * (real_source + virtual_source);
    }
}

/* The segment's table value for an endless beam along v (gather.comp's beam_value). */
static void beam_value(const GpuGatherParams *p, const float *table, const GpuVrl *v,
                       const GpuSegment *seg, const float *w, const float *attenuation,
                       const float *paper_weight, float value[3])
{
    float a_entry[3], a_exit[3];
    table_at(p, table, v, seg->entry, w, a_entry);
    if (p->counts[3] == NS_GATHER_MODE_EXACT)
        table_at(p, table, v, seg->exit, w, a_exit);
    for (int c = 0; c < 3; c++)
        value[c] = p->counts[3] == NS_GATHER_MODE_PAPER ? paper_weight[c] * a_entry[c]
                                                        : a_entry[c] - attenuation[c] * a_exit[c];
}

/* v's contribution: its beam less the beam past its exit (gather.comp's contribution). */
static void contribution(const GpuGatherParams *p, const float *table, const GpuVrl *v,
                         const GpuSegment *seg, const float *w, const float *attenuation,
                         const float *paper_weight, float *sum)
{
    if (p->counts[3] == NS_GATHER_MODE_DIPOLE) {
        float d[3] = {seg->entry[0] - v->origin[0], seg->entry[1] - v->origin[1],
                      seg->entry[2] - v->origin[2]};
        float rd[3];
        dipole_rd(p, sqrtf(dot3(d, d)), rd);
        for (int c = 0; c < 3; c++)
            sum[c] += v->power[c] * rd[c] / 3.14159265358979f;
        return;
    }
    float value[3], beam_attenuation[3];
    beam_value(p, table, v, seg, w, attenuation, paper_weight, value);
    int truncated = 0;
    for (int c = 0; c < 3; c++) {
        beam_attenuation[c] = expf(-p->sigma_t[c] * v->length);
        truncated |= p->table_map[3] > 0.0f && v->length > 0.0f && beam_attenuation[c] > p->table_map[3];
    }
    if (truncated) {
        GpuVrl beyond = *v;
        float beyond_value[3];
        for (int i = 0; i < 3; i++)
            beyond.origin[i] = v->origin[i] + v->length * v->direction[i];
        beam_value(p, table, &beyond, seg, w, attenuation, paper_weight, beyond_value);
        for (int c = 0; c < 3; c++)
            value[c] = fmaxf(value[c] - beam_attenuation[c] * beyond_value[c], 0.0f);
    }
    for (int c = 0; c < 3; c++) {
        float s = p->sigma_t[c];
        sum[c] += v->power[c] * s * s * value[c];
    }
}

static float box_distance(const float *amin, const float *amax, const float *bmin, const float *bmax)
{
    float g2 = 0.0f;
    for (int i = 0; i < 3; i++) {
        float gap = fmaxf(0.0f, fmaxf(amin[i] - bmax[i], bmin[i] - amax[i]));
        g2 += gap * gap;
    }
    return sqrtf(g2);
}

/* ---------------------------------------------------------------------------------------
 * The nodes the gather walks: the grid's tree with every leaf of more than
 * NS_GATHER_MAX_LEAF_VRLS VRLs cut into pieces (same box, a representative each), so that one
 * dispatch can always take a whole leaf under lavapipe's loop budget. The limit does not
 * depend on the device, so the CPU reference walks exactly the GPU's nodes. A grid made by
 * hand (node_count 0, the tests) is walked as its cells, each a leaf.
 * ------------------------------------------------------------------------------------- */
#define NS_GATHER_MAX_LEAF_VRLS (2u * NS_LAVAPIPE_LOOP_BUDGET / NS_GATHER_ITERATIONS_PER_VRL - 1u)

typedef struct gather_nodes {
    GpuVrlNode *nodes;
    GpuVrl *representatives;
    uint32_t count;
} gather_nodes;

static void free_nodes(gather_nodes *n)
{
    free(n->nodes);
    free(n->representatives);
    memset(n, 0, sizeof *n);
}

static uint32_t pieces_of(uint32_t count)
{
    return count ? (count + NS_GATHER_MAX_LEAF_VRLS - 1) / NS_GATHER_MAX_LEAF_VRLS : 1;
}

/* Appends the leaf `node` (skip set here), cut into pieces when it is large. */
static void append_leaf(gather_nodes *out, const ns_vrl_grid *grid, GpuVrlNode node,
                        const GpuVrl *representative)
{
    if (node.count <= NS_GATHER_MAX_LEAF_VRLS) {
        node.skip = out->count + 1;
        out->representatives[out->count] = *representative;
        out->nodes[out->count++] = node;
        return;
    }
    for (uint32_t first = 0; first < node.count; first += NS_GATHER_MAX_LEAF_VRLS) {
        GpuVrlNode piece = node;
        piece.first = node.first + first;
        piece.count = node.count - first < NS_GATHER_MAX_LEAF_VRLS ? node.count - first
                                                                   : NS_GATHER_MAX_LEAF_VRLS;
        piece.skip = out->count + 1;
        out->representatives[out->count] = ns_vrl_representative(grid->vrls + piece.first, piece.count);
        out->nodes[out->count++] = piece;
    }
}

/* Copies the subtree of grid node i; returns the index past it in the grid's array. */
static uint32_t copy_subtree(gather_nodes *out, const ns_vrl_grid *grid, uint32_t i)
{
    const GpuVrlNode *node = &grid->nodes[i];
    if (node->leaf) {
        append_leaf(out, grid, *node, &grid->node_representatives[i]);
        return node->skip;
    }
    uint32_t index = out->count++;
    out->nodes[index] = *node;
    out->representatives[index] = grid->node_representatives[i];
    for (uint32_t child = i + 1; child < node->skip;)
        child = copy_subtree(out, grid, child);
    out->nodes[index].skip = out->count;
    return node->skip;
}

static int build_nodes(const ns_vrl_grid *grid, gather_nodes *out)
{
    memset(out, 0, sizeof *out);
    uint32_t n = 0;
    if (grid->node_count)
        for (uint32_t i = 0; i < grid->node_count; i++)
            n += grid->nodes[i].leaf ? pieces_of(grid->nodes[i].count) : 1;
    else
        for (uint32_t c = 0; c < grid->cell_count; c++)
            n += pieces_of(grid->cells[c].count);
    out->nodes = malloc(sizeof *out->nodes * (n ? n : 1));
    out->representatives = malloc(sizeof *out->representatives * (n ? n : 1));
    if (!out->nodes || !out->representatives) {
        free_nodes(out);
        return -1;
    }
    if (grid->node_count)
        for (uint32_t i = 0; i < grid->node_count;)
            i = copy_subtree(out, grid, i);
    else
        for (uint32_t c = 0; c < grid->cell_count; c++) {
            const GpuVrlCell *cell = &grid->cells[c];
            GpuVrlNode leaf = {.first = cell->first, .count = cell->count, .leaf = 1, .level = grid->level};
            memcpy(leaf.bmin, cell->bmin, sizeof leaf.bmin);
            memcpy(leaf.bmax, cell->bmax, sizeof leaf.bmax);
            append_leaf(out, grid, leaf, &grid->representatives[c]);
        }
    return 0;
}

/* The box around a segment (its entry point alone for the dipole). */
static void segment_box(const GpuGatherParams *p, const GpuSegment *seg, float smin[3], float smax[3])
{
    int dipole = p->counts[3] == NS_GATHER_MODE_DIPOLE;
    for (int c = 0; c < 3; c++) {
        smin[c] = dipole ? seg->entry[c] : fminf(seg->entry[c], seg->exit[c]);
        smax[c] = dipole ? seg->entry[c] : fmaxf(seg->entry[c], seg->exit[c]);
    }
}

typedef struct segment_terms {
    float w[3], attenuation[3], paper_weight[3];
} segment_terms;

static segment_terms terms_of(const GpuGatherParams *p, const GpuSegment *seg)
{
    segment_terms t;
    float d[3] = {seg->exit[0] - seg->entry[0], seg->exit[1] - seg->entry[1], seg->exit[2] - seg->entry[2]};
    float length_c = sqrtf(dot3(d, d));
    for (int c = 0; c < 3; c++) {
        t.w[c] = -seg->direction[c];
        t.attenuation[c] = expf(-p->sigma_t[c] * length_c);
        t.paper_weight[c] = (1.0f - t.attenuation[c]) / (1.0f - expf(-(float)NS_PAPER_ACCUMULATION_MFP));
    }
    return t;
}

static void gather_leaf(const GpuGatherParams *p, const GpuSegment *seg, const segment_terms *t,
                        const ns_vrl_grid *grid, const GpuVrlNode *node, const float *table,
                        float out[4])
{
    for (uint32_t k = node->first; k < node->first + node->count; k++)
        contribution(p, table, &grid->vrls[k], seg, t->w, t->attenuation, t->paper_weight, out);
}

/* The shader's walk with the solid-angle option of [first, end) for one segment alone. */
static void gather_one(const GpuGatherParams *p, const GpuSegment *seg, const ns_vrl_grid *grid,
                       const gather_nodes *tree, uint32_t first, uint32_t end, const float *table,
                       float out[4], ns_gather_counts *counts)
{
    segment_terms t = terms_of(p, seg);
    float smin[3], smax[3];
    segment_box(p, seg, smin, smax);
    for (uint32_t ci = first; ci < end;) {
        const GpuVrlNode *node = &tree->nodes[ci];
        float gap = box_distance(smin, smax, node->bmin, node->bmax);
        if (gap > p->cull[0]) {
            counts->cells_culled++;
            ci = node->skip;
            continue;
        }
        float e[3] = {node->bmax[0] - node->bmin[0], node->bmax[1] - node->bmin[1],
                      node->bmax[2] - node->bmin[2]};
        float radius2 = 0.25f * dot3(e, e);
        if (gap * gap > radius2 && 3.14159265358979f * radius2 / (gap * gap) < p->cull[1]) {
            contribution(p, table, &tree->representatives[ci], seg, t.w, t.attenuation,
                         t.paper_weight, out);
            counts->cells_represented++;
            counts->interactions++;
            ci = node->skip;
            continue;
        }
        if (!node->leaf) {
            ci++;
            continue;
        }
        gather_leaf(p, seg, &t, grid, node, table, out);
        counts->interactions += node->count;
        ci = node->skip;
    }
}

#define NS_GATHER_MAX_LANES 128u /* the largest subgroup of any known device */

/* The shader's exact walk (no solid-angle threshold) of [first, end) for one subgroup:
 * `lanes` consecutive segments cull a node only when it is beyond every one's reach. */
static void gather_group_exact(const GpuGatherParams *p, const GpuSegment *segs, uint32_t lanes,
                               const ns_vrl_grid *grid, const gather_nodes *tree, uint32_t first,
                               uint32_t end, const float *table, float (*out)[4],
                               ns_gather_counts *counts)
{
    segment_terms terms[NS_GATHER_MAX_LANES];
    float smin[NS_GATHER_MAX_LANES][3], smax[NS_GATHER_MAX_LANES][3];
    for (uint32_t l = 0; l < lanes; l++) {
        terms[l] = terms_of(p, &segs[l]);
        segment_box(p, &segs[l], smin[l], smax[l]);
    }
    for (uint32_t ci = first; ci < end;) {
        const GpuVrlNode *node = &tree->nodes[ci];
        int all_beyond = 1;
        for (uint32_t l = 0; l < lanes && all_beyond; l++)
            all_beyond = box_distance(smin[l], smax[l], node->bmin, node->bmax) > p->cull[0];
        if (all_beyond) {
            counts->cells_culled += lanes;
            ci = node->skip;
            continue;
        }
        if (!node->leaf) {
            ci++;
            continue;
        }
        for (uint32_t l = 0; l < lanes; l++)
            gather_leaf(p, &segs[l], &terms[l], grid, node, table, out[l]);
        counts->interactions += (uint64_t)lanes * node->count;
        ci = node->skip;
    }
}

/* Node ranges [first, first + count) for the dispatches: each a run of whole subtrees whose
 * walk stays within the loop budget even if it culls and represents nothing (every node
 * visited, every leaf's VRLs evaluated). A subtree too large for one range is left out and
 * its children are placed instead: its representative is then never used, and its light
 * comes from the children. budget 0: one range. Returns the number of ranges (push holds
 * room for nodes->count + 1). */
typedef struct range_split {
    const gather_nodes *tree;
    uint32_t budget, cost, ranges, open, first;
    GpuGatherPush *push;
} range_split;

static uint32_t subtree_cost(const gather_nodes *tree, uint32_t i)
{
    uint32_t cost = 0;
    for (uint32_t k = i; k < tree->nodes[i].skip; k++)
        cost += NS_GATHER_ITERATIONS_PER_VRL * (1 + (tree->nodes[k].leaf ? tree->nodes[k].count : 0));
    return cost;
}

static void close_range(range_split *r)
{
    if (r->open)
        r->push[r->ranges++] = (GpuGatherPush){.first_cell = r->first, .cell_count = r->open};
    r->open = 0;
    r->cost = 0;
}

static void place_subtree(range_split *r, uint32_t i)
{
    const GpuVrlNode *node = &r->tree->nodes[i];
    uint32_t cost = r->budget ? subtree_cost(r->tree, i) : 0;
    if (r->budget && cost > r->budget && !node->leaf) {
        close_range(r); /* the node itself is skipped: ranges are contiguous runs */
        for (uint32_t child = i + 1; child < node->skip; child = r->tree->nodes[child].skip)
            place_subtree(r, child);
        return;
    }
    if (r->open && (r->first + r->open != i || (r->budget && r->cost + cost > r->budget)))
        close_range(r);
    if (!r->open)
        r->first = i;
    r->open += node->skip - i;
    r->cost += cost;
}

static uint32_t split_ranges(const gather_nodes *tree, uint32_t budget, GpuGatherPush *push)
{
    range_split r = {.tree = tree, .budget = budget, .push = push};
    for (uint32_t i = 0; i < tree->count; i = tree->nodes[i].skip)
        place_subtree(&r, i);
    close_range(&r);
    if (!r.ranges)
        push[r.ranges++] = (GpuGatherPush){0};
    return r.ranges;
}

void ns_gather_cpu(const GpuGatherParams *params, const GpuSegment *segments,
                   uint32_t segment_count, const ns_vrl_grid *grid, const float *table,
                   uint32_t subgroup_size, float (*out)[4], ns_gather_counts *counts)
{
    ns_gather_counts local = {0};
    gather_nodes tree;
    if (build_nodes(grid, &tree))
        abort(); /* tests only */
    /* The GPU's ranges under lavapipe's budget: the same nodes visited in the same order. */
    GpuGatherPush *push = calloc(tree.count + 1, sizeof *push);
    if (!push)
        abort();
    uint32_t ranges = split_ranges(&tree, 2 * NS_LAVAPIPE_LOOP_BUDGET, push);
    uint32_t lanes = subgroup_size < 1                     ? 1
                     : subgroup_size > NS_GATHER_MAX_LANES ? NS_GATHER_MAX_LANES
                                                           : subgroup_size;
    for (uint32_t i = 0; i < segment_count; i += lanes) {
        uint32_t n = segment_count - i < lanes ? segment_count - i : lanes;
        memset(out[i], 0, sizeof out[i] * n);
        for (uint32_t r = 0; r < ranges; r++) {
            uint32_t first = push[r].first_cell, end = first + push[r].cell_count;
            if (params->cull[1] > 0.0f)
                for (uint32_t l = 0; l < n; l++)
                    gather_one(params, &segments[i + l], grid, &tree, first, end, table, out[i + l], &local);
            else
                gather_group_exact(params, &segments[i], n, grid, &tree, first, end, table, &out[i], &local);
        }
    }
    free(push);
    free_nodes(&tree);
    if (counts)
        *counts = local;
}

/* ---------------------------------------------------------------------------------------
 * GPU
 * ------------------------------------------------------------------------------------- */
enum { G_PARAMS, G_SEGMENTS, G_CELLS, G_REPRESENTATIVES, G_VRLS, G_TABLE, G_OUT, G_COUNTERS, G_COUNT };

/* The pipeline of each form of the gather (gather.glsl: one shader per mode x beams). */
static const struct {
    uint32_t mode;
    int bounded;
    ns_pipeline_id pipeline;
} gather_forms[] = {
    {NS_GATHER_MODE_EXACT, 0, NS_PIPELINE_GATHER},
    {NS_GATHER_MODE_EXACT, 1, NS_PIPELINE_GATHER_BOUNDED},
    {NS_GATHER_MODE_PAPER, 0, NS_PIPELINE_GATHER_PAPER},
    {NS_GATHER_MODE_PAPER, 1, NS_PIPELINE_GATHER_PAPER_BOUNDED},
    {NS_GATHER_MODE_DIPOLE, 0, NS_PIPELINE_GATHER_DIPOLE},
};

int ns_gather_pipeline(ns_context *ctx, uint32_t mode, int bounded, gpu_pipeline **pipeline,
                       double *made_ms, ns_error *err)
{
    *made_ms = 0;
    bounded = bounded && mode != NS_GATHER_MODE_DIPOLE;
    size_t i = 0;
    while (i < sizeof gather_forms / sizeof gather_forms[0] &&
           (gather_forms[i].mode != mode || gather_forms[i].bounded != bounded))
        i++;
    if (i == sizeof gather_forms / sizeof gather_forms[0])
        return ns_fail(err, NS_ERR_INTERNAL, "gather: no shader for mode %u", mode);
    /* The default form is made at start-up, the others by their first gather (pipelines.c). */
    return ns_pipeline(ctx, gather_forms[i].pipeline, pipeline, made_ms, err);
}

int ns_gather_run(ns_context *ctx, const ns_gather_desc *desc, ns_gather_counts *counts,
                  ns_error *err)
{
    memset(counts, 0, sizeof *counts);
    const ns_vrl_grid *grid = desc->grid;
    if (!desc->segment_count)
        return NS_OK;
    /* lavapipe: a dispatch's invocations stay within the loop budget (shared.h). */
    uint32_t budget = ctx->dev.loop_limited ? 2 * NS_LAVAPIPE_LOOP_BUDGET : 0;
    gather_nodes tree;
    GpuGatherPush *push = NULL;
    if (build_nodes(grid, &tree) || !(push = calloc(tree.count + 1, sizeof *push))) {
        free_nodes(&tree);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "gather: %u cells", grid->cell_count);
    }
    uint32_t ranges = split_ranges(&tree, budget, push);
    for (uint32_t i = 0; i < ranges; i++) {
        push[i].first_segment = desc->first_segment;
        push[i].accumulate = i > 0;
    }
    GpuGatherParams params = desc->params;
    params.counts[0] = desc->segment_count;
    params.counts[1] = tree.count;
    params.counts[2] = grid->vrl_count;

    gpu_buffer own[G_COUNT];
    memset(own, 0, sizeof own);
    gpu_buffer_desc descs[] = {
        {.size = sizeof params, .kind = GPU_BUFFER_UNIFORM, .data = &params, .data_size = sizeof params,
         .label = "ns.gather.params"},
        {.size = (uint64_t)tree.count * sizeof(GpuVrlNode), .data = tree.nodes,
         .data_size = (uint64_t)tree.count * sizeof(GpuVrlNode), .label = "ns.gather.nodes"},
        {.size = (uint64_t)tree.count * sizeof(GpuVrl), .data = tree.representatives,
         .data_size = (uint64_t)tree.count * sizeof(GpuVrl), .label = "ns.gather.representatives"},
        {.size = (uint64_t)grid->vrl_count * sizeof(GpuVrl), .data = grid->vrls,
         .data_size = (uint64_t)grid->vrl_count * sizeof(GpuVrl), .label = "ns.gather.vrls"},
        {.size = 16, .label = "ns.gather.no_table"},
        {.size = NS_GATHER_COUNTER_COUNT * sizeof(uint32_t), .label = "ns.gather.counters"},
    };
    int targets[] = {G_PARAMS, G_CELLS, G_REPRESENTATIVES, G_VRLS, G_TABLE, G_COUNTERS};
    gpu_pipeline *pipeline = NULL;
    double made_ms;
    int status = ns_gather_pipeline(ctx, params.counts[3], params.table_map[3] > 0.0f, &pipeline,
                                    &made_ms, err);
    for (size_t i = 0; i < sizeof targets / sizeof targets[0] && !status; i++) {
        if (targets[i] == G_TABLE && desc->table)
            continue;
        status = gpu_buffer_create(&ctx->dev, &own[targets[i]], &descs[i], err);
    }
    if (!status) {
        gpu_buffer *bound[G_COUNT];
        for (int i = 0; i < G_COUNT; i++)
            bound[i] = &own[i];
        bound[G_SEGMENTS] = desc->segments;
        bound[G_OUT] = desc->out;
        if (desc->table)
            bound[G_TABLE] = (gpu_buffer *)desc->table;
        status = gpu_dispatch_many(
            &ctx->dev,
            &(gpu_dispatch_desc){.pipeline = pipeline,
                                 .buffers = bound,
                                 .buffer_count = G_COUNT,
                                 .groups = {(desc->segment_count + NS_GATHER_GROUP - 1) / NS_GATHER_GROUP, 1, 1},
                                 .push = push,
                                 .dispatch_count = ranges},
            err);
    }
    if (!status) {
        const uint32_t *c = own[G_COUNTERS].mapped;
        counts->interactions = (uint64_t)c[NS_GATHER_COUNTER_INTERACTIONS_HIGH] << 32 |
                               c[NS_GATHER_COUNTER_INTERACTIONS];
        counts->cells_culled = c[NS_GATHER_COUNTER_CULLED];
        counts->cells_represented = c[NS_GATHER_COUNTER_REPRESENTED];
        counts->dispatches = ranges;
    }
    for (int i = 0; i < G_COUNT; i++)
        gpu_buffer_destroy(&ctx->dev, &own[i]);
    free(push);
    free_nodes(&tree);
    return status;
}
