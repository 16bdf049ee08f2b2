/* gather.c — the gather stage's C side: its uniform block (table mapping, culling reach,
 * dipole constants), the nodes of the VRL hierarchy it walks and their split across
 * dispatches (lavapipe's loop limit), and the dispatches of shaders/gather.comp. The same
 * walk on the CPU, the tests' oracle, is tests/oracles/gather_cpu.c: it builds its nodes and
 * ranges with the functions here, so that it visits exactly what the GPU visits. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "boundary.h"
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
    } else if (mode == NS_GATHER_MODE_FIRST) {
        ns_gather_params_first(p, m);
        /* Every point of a source's first order lies within a few tubes' widths of its line
         * and, through e^{-z}, within 40 mfp of its origin (e^-40) in every channel. */
        p->cull[0] = s_min > 0.0f ? (40.0f + 8.0f * (float)NS_BOUNDARY_BLUR_MFP) / s_min : INFINITY;
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

void ns_gather_params_first(GpuGatherParams *p, const GpuMaterial *m)
{
    for (int c = 0; c < 3; c++) {
        float s = m->sigma_t[c];
        p->first_order[c] = s > 0.0f ? m->sigma_s[c] / s : 0.0f;
        p->first_blur[c] = s > 0.0f ? (float)NS_BOUNDARY_BLUR_MFP / s : 0.0f;
    }
    p->first_order[3] = m->sigma_s[3]; /* g */
    p->first_blur[3] = 1.0f;           /* the form adds it */
}

/* ---------------------------------------------------------------------------------------
 * The nodes the gather walks: the grid's tree with every leaf of more than
 * NS_GATHER_MAX_LEAF_VRLS VRLs cut into pieces (same box, a representative each), so that one
 * dispatch can always take a whole leaf under lavapipe's loop budget. The limit does not
 * depend on the device, so the CPU reference (tests/oracles/gather_cpu.c) walks exactly the
 * GPU's nodes. A grid made by hand (node_count 0, the tests) is walked as its cells, each a
 * leaf.
 * ------------------------------------------------------------------------------------- */
#define NS_GATHER_MAX_LEAF_VRLS (2u * NS_LAVAPIPE_LOOP_BUDGET / NS_GATHER_ITERATIONS_PER_VRL - 1u)

void ns_gather_nodes_free(ns_gather_nodes *n)
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
static void append_leaf(ns_gather_nodes *out, const ns_vrl_grid *grid, GpuVrlNode node,
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
static uint32_t copy_subtree(ns_gather_nodes *out, const ns_vrl_grid *grid, uint32_t i)
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

int ns_gather_nodes_build(const ns_vrl_grid *grid, ns_gather_nodes *out)
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
        ns_gather_nodes_free(out);
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

/* ---------------------------------------------------------------------------------------
 * The node ranges of the dispatches (ns_gather_ranges in scatter.h says what they are).
 * ------------------------------------------------------------------------------------- */
typedef struct range_split {
    const ns_gather_nodes *tree;
    uint32_t budget, cost, ranges, open, first;
    GpuGatherPush *push;
} range_split;

static uint32_t subtree_cost(const ns_gather_nodes *tree, uint32_t i)
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

uint32_t ns_gather_ranges(const ns_gather_nodes *tree, uint32_t budget, GpuGatherPush *push)
{
    range_split r = {.tree = tree, .budget = budget, .push = push};
    for (uint32_t i = 0; i < tree->count; i = tree->nodes[i].skip)
        place_subtree(&r, i);
    close_range(&r);
    if (!r.ranges)
        push[r.ranges++] = (GpuGatherPush){0};
    return r.ranges;
}

/* ---------------------------------------------------------------------------------------
 * GPU
 * ------------------------------------------------------------------------------------- */
enum { G_PARAMS, G_SEGMENTS, G_CELLS, G_REPRESENTATIVES, G_VRLS, G_TABLE, G_OUT, G_COUNTERS, G_COUNT };

/* The pipeline of each form of the gather (gather.glsl: one shader per mode x beams). */
static const struct {
    uint32_t mode;
    int bounded, first; /* first: adds the blurred first order (ns_gather_params_first) */
    ns_pipeline_id pipeline;
} gather_forms[] = {
    {NS_GATHER_MODE_EXACT, 0, 0, NS_PIPELINE_GATHER},
    {NS_GATHER_MODE_EXACT, 1, 0, NS_PIPELINE_GATHER_BOUNDED},
    {NS_GATHER_MODE_PAPER, 0, 0, NS_PIPELINE_GATHER_PAPER},
    {NS_GATHER_MODE_PAPER, 1, 0, NS_PIPELINE_GATHER_PAPER_BOUNDED},
    {NS_GATHER_MODE_DIPOLE, 0, 0, NS_PIPELINE_GATHER_DIPOLE},
    {NS_GATHER_MODE_FIRST, 0, 1, NS_PIPELINE_GATHER_FIRST},
    {NS_GATHER_MODE_EXACT, 0, 1, NS_PIPELINE_GATHER_EXACT_FIRST},
};

int ns_gather_pipeline(ns_context *ctx, const GpuGatherParams *params, gpu_pipeline **pipeline,
                       double *made_ms, ns_error *err)
{
    *made_ms = 0;
    uint32_t mode = params->counts[3];
    int bounded = params->table_map[3] > 0.0f && mode != NS_GATHER_MODE_DIPOLE;
    int first = params->first_blur[3] > 0.0f;
    size_t i = 0;
    while (i < sizeof gather_forms / sizeof gather_forms[0] &&
           (gather_forms[i].mode != mode || gather_forms[i].bounded != bounded ||
            gather_forms[i].first != first))
        i++;
    if (i == sizeof gather_forms / sizeof gather_forms[0])
        return ns_fail(err, NS_ERR_INTERNAL, "gather: no shader for mode %u", mode);
    /* The default form is made at start-up, the others by their first gather (pipelines.c):
     * then a stage of its own (progress; the caller adds *made_ms to the stats), taking no
     * part of the render's fraction. */
    ns_pipeline_id id = gather_forms[i].pipeline;
    if (ctx->pipelines[id].pipeline)
        return ns_pipeline(ctx, id, pipeline, made_ms, err);
    ns_stage stage = ns_stage_begin(ctx, "gather_pipeline", 0.0, 0.0);
    int status = ns_pipeline(ctx, id, pipeline, made_ms, err);
    *made_ms = ns_stage_end(ctx, &stage); /* the time reported is the time in the stats */
    return status;
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
    ns_gather_nodes tree;
    GpuGatherPush *push = NULL;
    if (ns_gather_nodes_build(grid, &tree) || !(push = calloc(tree.count + 1, sizeof *push))) {
        ns_gather_nodes_free(&tree);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "gather: %u cells", grid->cell_count);
    }
    uint32_t ranges = ns_gather_ranges(&tree, budget, push);
    for (uint32_t i = 0; i < ranges; i++) {
        push[i].first_segment = desc->first_segment;
        push[i].accumulate = desc->add || i > 0;
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
    int status = ns_gather_pipeline(ctx, &params, &pipeline, &made_ms, err);
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
    ns_gather_nodes_free(&tree);
    return status;
}
