/* scatter_tables.c — the accumulated camera-side tables A of a material (render/scatter.h):
 * J from the networks (built-in weights, renormalised to the exact energy) or from the
 * caller's Monte Carlo provider, accumulated by shaders/accumulate.comp, or (render.tables
 * "interpolated") blended from the A of albedo nodes; and a cache of J (per source, g,
 * albedo: one channel), of the nodes (per g, accumulation and node) and of A (per whole
 * key), least recently used first out, bounded in bytes.
 *
 * Buffers that live as long as the context (the network's parameter block, cached A tables)
 * are taken out of dev.live_buffers while they live: that count measures what a request
 * leaves behind, and a cached table is kept on purpose.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <dirent.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include "accumulate_shared.h"
#include "boundary.h"
#include "nn_reconstruct.h"
#include "scatter.h"

/* Accumulation cut (see shaders/accumulate.comp): the remainder bound e^{-u} J_max must fall
 * below CUT_RELATIVE times max(sum so far, CUT_FLOOR J_max). */
#define CUT_RELATIVE 1e-4f
#define CUT_FLOOR 1e-10f
/* Cells per dispatch: keeps each submission short on any device. */
#define CELLS_PER_DISPATCH (NS_ACCUMULATE_GROUP * 8192u)

struct ns_nn_state {
    ns_nn_gpu gpu;
    ns_nn_weights nets[2];
    int nets_ok;
    ns_error nets_error; /* why NS_METHOD_NN is not available */
    /* Double scattering per unit a^2 at unit_double_g (network_tables); NULL until made. */
    float *unit_double;
    float unit_double_g;
};

typedef enum { ENTRY_J, ENTRY_A, ENTRY_NODE } entry_kind;

/* One cache entry: J of one channel (both orders, host memory), A of a whole key, or one
 * albedo node of the interpolated tables (host memory). */
typedef struct cache_entry {
    entry_kind kind;
    ns_method source;    /* J */
    float g, albedo;     /* J; node: g */
    float *j[2];         /* J: double, multiple (NS_TABLE_CELLS each); node: A / E_k of each */
    uint32_t node;                /* node: its index */
    ns_accumulation accumulation; /* node */
    ns_table_key key;    /* A */
    ns_scatter_tables a; /* A */
    uint64_t bytes;
    uint64_t last_use;
    uint64_t counted; /* ns_run.serial of the render that last counted it made or reused */
    uint64_t counted_blended; /* A blended from nodes: the render that last counted it so */
} cache_entry;

/* render.tables "auto" makes exact tables for this many albedos at a g before it makes that
 * g's nodes (auto_mode), and remembers as many materials as it needs to count them. */
#define AUTO_EXACT_BEFORE_NODES 4u
#define AUTO_EXACT_KEPT 16u
/* ns_context_idle_work makes a g's nodes once auto made exact tables at this many of its
 * albedos: one albedo is a material tried, a second one is the start of a sweep. */
#define IDLE_NODES_AFTER 2u
/* Nodes are made this many at a time: the channels of one walk (build_nodes). */
#define NODES_PER_BATCH 3u

struct ns_table_cache {
    cache_entry *entries;
    uint32_t count, capacity;
    uint64_t bytes; /* changed atomically: ns_context_table_cache_bytes reads it anywhere */
    uint64_t clock;
    /* The base order sets (double and/or multiple) that the render of serial + 1 ==
     * orders_expected_serial reads (ns_tables_expect_orders): an exact table of one is
     * walked together with another's (accumulate_shared.h, the second three). */
    uint64_t orders_expected_serial;
    uint32_t orders_expected[4], orders_expected_count;
    /* render.tables "auto": the last materials whose exact tables it chose (auto_mode), a
     * ring, counted per (g, accumulation). */
    struct auto_exact {
        float g, albedo[3];
        ns_accumulation accumulation;
        int used;
    } auto_exact[AUTO_EXACT_KEPT];
    uint32_t auto_exact_next;
};

/* ---------------------------------------------------------------------------------------
 * Grid
 * ------------------------------------------------------------------------------------- */
void ns_table_grid_default(ns_table_grid *g)
{
    g->scale = NS_TABLE_SINH_SCALE;
    g->extent = NS_TABLE_EXTENT;
    g->step = asinh(NS_TABLE_EXTENT / NS_TABLE_SINH_SCALE) / NS_TABLE_NRHO;
    for (uint32_t i = 0; i <= NS_TABLE_NZ; i++)
        g->z[i] = g->scale * sinh(g->step * ((double)i - NS_TABLE_NZ / 2));
    for (uint32_t i = 0; i <= NS_TABLE_NRHO; i++)
        g->rho[i] = g->scale * sinh(g->step * i);
    g->z[NS_TABLE_NZ / 2] = 0.0; /* exactly, as offline/mc.c writes it */
    g->rho[0] = 0.0;
    for (uint32_t i = 0; i <= NS_TABLE_NTHETA; i++)
        g->theta[i] = M_PI * i / NS_TABLE_NTHETA;
    for (uint32_t i = 0; i <= NS_TABLE_NPHI; i++)
        g->phi[i] = M_PI * i / NS_TABLE_NPHI;
}

/* ---------------------------------------------------------------------------------------
 * Context-lifetime buffers (see the header comment)
 * ------------------------------------------------------------------------------------- */
static void keep_buffer(gpu_device *dev)
{
    __atomic_sub_fetch(&dev->live_buffers, 1, __ATOMIC_SEQ_CST);
}
static void destroy_kept_buffer(gpu_device *dev, gpu_buffer *b)
{
    if (b->buffer)
        __atomic_add_fetch(&dev->live_buffers, 1, __ATOMIC_SEQ_CST);
    gpu_buffer_destroy(dev, b);
}

/* ---------------------------------------------------------------------------------------
 * Accumulation
 * ------------------------------------------------------------------------------------- */
static void channel_max(const float *j, int channels, float *j_max)
{
    for (int c = 0; c < channels; c++) {
        const float *t = j + (size_t)c * NS_TABLE_CELLS;
        float m = 0.0f;
        for (size_t i = 0; i < NS_TABLE_CELLS; i++)
            m = t[i] > m ? t[i] : m;
        j_max[c] = m;
    }
}

/* The first rho bin from which J is 0 in every channel, z, theta and phi (NS_TABLE_NRHO when
 * the last bin holds light): A is 0 along every line that stays farther out (accumulate.glsl). */
static uint32_t zero_from_rho(const float *j, int channels)
{
    const size_t angles = (size_t)NS_TABLE_NTHETA * NS_TABLE_NPHI; /* cells of one (z, rho) */
    uint32_t from = 0;
    for (size_t row = 0; row < (size_t)channels * NS_TABLE_NZ * NS_TABLE_NRHO; row++) {
        uint32_t ir = (uint32_t)(row % NS_TABLE_NRHO);
        if (ir < from)
            continue;
        const float *t = j + row * angles;
        for (size_t k = 0; k < angles; k++)
            if (t[k] > 0.0f) {
                from = ir + 1;
                break;
            }
    }
    return from;
}

static int check_j(const float *j, int channels, ns_error *err)
{
    if (!j)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "J table: missing (NULL)");
    for (size_t i = 0; i < (size_t)channels * NS_TABLE_CELLS; i++)
        if (!(j[i] >= 0.0f) || isinf(j[i]))
            return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                           "J table: channel %zu cell %zu is %g (must be finite and >= 0)",
                           i / NS_TABLE_CELLS, i % NS_TABLE_CELLS, (double)j[i]);
    return NS_OK;
}

/* What one walk makes beside the three channels' A (accumulate_shared.h): the second three
 * (second_j float [3][cells], their A created in *second_out); NULL where absent. */
typedef struct accumulate_parts {
    const float *second_j;
    ns_scatter_tables *second_out;
} accumulate_parts;

/* The cells an accumulation within reach_bins walks (accumulate_shared.h, reach). */
static uint32_t walked_cells(uint32_t reach_bins)
{
    return 2u * reach_bins * reach_bins * NS_TABLE_NTHETA * NS_TABLE_NPHI;
}

uint32_t ns_table_reach_bins(double reach_mfp)
{
    ns_table_grid grid;
    ns_table_grid_default(&grid);
    if (!(reach_mfp >= 0.0 && reach_mfp < grid.extent))
        return NS_TABLE_NRHO;
    /* A point at distance d <= reach (in |z| or in rho) sits at the continuous index
     * asinh(d / scale) / step - 0.5 from the source's bin edge, and the gather's reads take
     * the bin below and the one above it (gather.glsl, table_at): within ceil(q) + 1 bins of
     * the source's plane and the axis. Two more bins stand for rounding. */
    double q = asinh(reach_mfp / grid.scale) / grid.step;
    double bins = ceil(q) + 3.0;
    return bins < NS_TABLE_NRHO ? (uint32_t)bins : NS_TABLE_NRHO;
}

/* j_max: the three channels ([0..2]) and the second three ([3..5]); each set's J is 0 from
 * its own rho bin (*zero_from). */
static GpuAccumulateParams accumulate_params(const ns_table_grid *grid, const float j_max[6],
                                             const accumulate_parts *parts,
                                             ns_accumulation accumulation, uint32_t zero_from,
                                             uint32_t second_zero_from, uint32_t reach_bins)
{
    GpuAccumulateParams p;
    memset(&p, 0, sizeof p);
    p.grid[0] = (float)grid->scale;
    p.grid[1] = (float)grid->step;
    p.grid[2] = (float)grid->extent;
    int second = parts && parts->second_j;
    memcpy(p.j_max, j_max, 3 * sizeof(float));
    if (second)
        memcpy(p.second_j_max, j_max + 3, 3 * sizeof(float));
    p.second[0] = second ? 1 + second_zero_from : 0;
    p.cut[0] = CUT_RELATIVE;
    p.cut[1] = CUT_FLOOR;
    p.cut[2] = accumulation == NS_ACCUMULATION_PAPER ? (float)NS_PAPER_ACCUMULATION_MFP : 0.0f;
    p.reach[0] = reach_bins;
    p.counts[0] = walked_cells(reach_bins);
    p.counts[1] = zero_from;
    p.counts[2] = NS_ACCUMULATE_STEP_CAP;
    return p;
}

enum { B_PARAMS, B_J, B_A, B_COUNTERS, B_SECOND, B_COUNT };

/* The grid fields every A table carries (the default grid) and its device bytes. */
static void set_default_grid(ns_scatter_tables *t, uint64_t bytes)
{
    ns_table_grid grid;
    ns_table_grid_default(&grid);
    t->scale = (float)grid.scale;
    t->inv_step = (float)(1.0 / grid.step);
    t->extent = (float)grid.extent;
    t->bytes = bytes;
}

static int dispatch_accumulate(ns_context *ctx, gpu_buffer *bound[B_COUNT], int second,
                               uint32_t cells, ns_error *err)
{
    gpu_pipeline *pipeline;
    int status = ns_pipeline(ctx, second ? NS_PIPELINE_ACCUMULATE_SECOND : NS_PIPELINE_ACCUMULATE,
                             &pipeline, NULL, err);
    if (status)
        return status;
    uint32_t dispatches = (cells + CELLS_PER_DISPATCH - 1) / CELLS_PER_DISPATCH;
    GpuAccumulatePush push[(NS_TABLE_CELLS + CELLS_PER_DISPATCH - 1) / CELLS_PER_DISPATCH];
    for (uint32_t i = 0; i < dispatches; i++) {
        uint32_t first = i * CELLS_PER_DISPATCH;
        uint32_t n = cells - first;
        push[i] = (GpuAccumulatePush){
            .first_cell = first, .cell_count = n < CELLS_PER_DISPATCH ? n : CELLS_PER_DISPATCH};
    }
    /* One submission, or one per dispatch where a stop must come soon (the whole walk is
     * about a second on lavapipe, one dispatch a sixth of it). */
    uint32_t per_submission = ctx->run.preemptible ? 1 : dispatches;
    for (uint32_t i = 0; i < dispatches && !status; i += per_submission)
        status = gpu_dispatch_many(
            &ctx->dev,
            &(gpu_dispatch_desc){.pipeline = pipeline,
                                 .buffers = bound,
                                 .buffer_count = B_COUNT,
                                 .groups = {CELLS_PER_DISPATCH / NS_ACCUMULATE_GROUP, 1, 1},
                                 .push = push + i,
                                 .dispatch_count = dispatches - i < per_submission ? dispatches - i
                                                                                   : per_submission},
            err);
    return status;
}

static int accumulate(ns_context *ctx, const float *j, const accumulate_parts *parts,
                      ns_accumulation accumulation, uint32_t zero_from, uint32_t reach_bins,
                      int a_host_reads, ns_scatter_tables *out, uint64_t *steps, ns_error *err);

int ns_tables_accumulate(ns_context *ctx, const float *j, ns_accumulation accumulation,
                         ns_scatter_tables *out, uint64_t *steps, ns_error *err)
{
    return accumulate(ctx, j, NULL, accumulation, j ? zero_from_rho(j, 3) : NS_TABLE_NRHO,
                      NS_TABLE_NRHO, 0, out, steps, err);
}

int ns_tables_accumulate_for_host(ns_context *ctx, const float *j, ns_accumulation accumulation,
                                  ns_scatter_tables *out, uint64_t *steps, ns_error *err)
{
    return accumulate(ctx, j, NULL, accumulation, j ? zero_from_rho(j, 3) : NS_TABLE_NRHO,
                      NS_TABLE_NRHO, 1, out, steps, err);
}

int ns_tables_accumulate_within(ns_context *ctx, const float *j, ns_accumulation accumulation,
                                uint32_t zero_from, ns_scatter_tables *out, uint64_t *steps,
                                ns_error *err)
{
    return accumulate(ctx, j, NULL, accumulation, zero_from, NS_TABLE_NRHO, 0, out, steps, err);
}

int ns_tables_accumulate_parts(ns_context *ctx, const float *j, const float *second_j,
                               ns_accumulation accumulation, uint32_t reach_bins,
                               ns_scatter_tables *out, ns_scatter_tables *second_out,
                               uint64_t *steps, ns_error *err)
{
    if (!second_j != !second_out)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "accumulate: the second three need their J and their A");
    accumulate_parts parts = {.second_j = second_j, .second_out = second_out};
    return accumulate(ctx, j, &parts, accumulation, j ? zero_from_rho(j, 3) : NS_TABLE_NRHO,
                      reach_bins, 0, out, steps, err);
}

/* J's texels (accumulate_shared.h): cell i of the three planes of j (float [3][cells]) as
 * texel i. */
static void interleave_j(float (*texel)[4], const float *j)
{
    for (size_t i = 0; i < NS_TABLE_CELLS; i++) {
        texel[i][0] = j[i];
        texel[i][1] = j[NS_TABLE_CELLS + i];
        texel[i][2] = j[2 * (size_t)NS_TABLE_CELLS + i];
        texel[i][3] = 0.0f;
    }
}

/* The remainder bounds of j (float [3][cells]) as texels (accumulate_shared.h): per theta
 * bin the max over phi of each (z, rho) cell, then the max from each rho bin outward, then
 * from each z bin along the way lines of that theta walk. */
static void remainder_bounds(float (*texel)[4], const float *j)
{
    const size_t per_theta = (size_t)NS_TABLE_NZ * NS_TABLE_NRHO;
    for (int c = 0; c < 3; c++) {
        /* J in its own order (z, rho, theta, phi), read once: the max over phi. */
        const float *t = j + (size_t)c * NS_TABLE_CELLS;
        for (size_t zr = 0; zr < per_theta; zr++)
            for (int it = 0; it < NS_TABLE_NTHETA; it++) {
                const float *cell = t + (zr * NS_TABLE_NTHETA + it) * NS_TABLE_NPHI;
                float m = 0.0f;
                for (int ip = 0; ip < NS_TABLE_NPHI; ip++)
                    m = cell[ip] > m ? cell[ip] : m;
                texel[it * per_theta + zr][c] = m;
            }
    }
    for (int it = 0; it < NS_TABLE_NTHETA; it++) {
        float(*row)[4] = texel + it * per_theta;
        for (int iz = 0; iz < NS_TABLE_NZ; iz++) /* from each rho bin outward */
            for (int ir = NS_TABLE_NRHO - 2; ir >= 0; ir--)
                for (int c = 0; c < 3; c++) {
                    float *b = &row[iz * NS_TABLE_NRHO + ir][c];
                    float outer = row[iz * NS_TABLE_NRHO + ir + 1][c];
                    *b = outer > *b ? outer : *b;
                }
        /* Along z the way lines of this theta walk: down while cos theta > 0 (the lower half
         * of the theta bins). */
        int down = it < NS_TABLE_NTHETA / 2;
        for (int k = 1; k < NS_TABLE_NZ; k++) {
            int iz = down ? k : NS_TABLE_NZ - 1 - k, before = down ? iz - 1 : iz + 1;
            for (int ir = 0; ir < NS_TABLE_NRHO; ir++)
                for (int c = 0; c < 3; c++) {
                    float *b = &row[iz * NS_TABLE_NRHO + ir][c];
                    float prior = row[before * NS_TABLE_NRHO + ir][c];
                    *b = prior > *b ? prior : *b;
                }
        }
    }
    for (size_t i = 0; i < NS_ACCUMULATE_BOUND_TEXELS; i++)
        texel[i][3] = 0.0f;
}

/* j: float [3][cells]; parts (may be NULL): what the same walk makes beside it. */
static int accumulate(ns_context *ctx, const float *j, const accumulate_parts *parts,
                      ns_accumulation accumulation, uint32_t zero_from, uint32_t reach_bins,
                      int a_host_reads, ns_scatter_tables *out, uint64_t *steps, ns_error *err)
{
    const float *second_j = parts ? parts->second_j : NULL;
    memset(out, 0, sizeof *out);
    if (second_j)
        memset(parts->second_out, 0, sizeof *parts->second_out);
    if (zero_from > NS_TABLE_NRHO)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "accumulate: rho bin %u beyond the grid's %u",
                       zero_from, NS_TABLE_NRHO);
    if (reach_bins < 1 || reach_bins > NS_TABLE_NRHO)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "accumulate: reach of %u bins outside 1 to %u",
                       reach_bins, NS_TABLE_NRHO);
    if (accumulation != NS_ACCUMULATION_EXACT && accumulation != NS_ACCUMULATION_PAPER)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "render.accumulation: %d unknown",
                       (int)accumulation);
    int status = check_j(j, 3, err);
    if (!status && second_j)
        status = check_j(second_j, 3, err);
    if (status)
        return status;
    ns_table_grid grid;
    ns_table_grid_default(&grid);
    float j_max[6] = {0};
    channel_max(j, 3, j_max);
    if (second_j)
        channel_max(second_j, 3, j_max + 3);
    GpuAccumulateParams params =
        accumulate_params(&grid, j_max, parts, accumulation, zero_from,
                          second_j ? zero_from_rho(second_j, 3) : 0, reach_bins);
    /* Cells beyond the reach are not walked: they hold zeros. */
    int every_cell = reach_bins == NS_TABLE_NRHO;
    int all_zero = 1;
    for (int c = 0; c < 6; c++)
        all_zero = all_zero && j_max[c] == 0.0f;
    uint64_t table_bytes = 3ull * NS_TABLE_CELLS * sizeof(float);
    /* J in one buffer of 16-byte texels: per cell the three channels, then per cell the
     * second three, then the remainder bounds of each (accumulate_shared.h). */
    uint32_t parts_walked = second_j ? 2 : 1;
    params.counts[3] = parts_walked * NS_TABLE_CELLS;
    params.second[1] = second_j ? params.counts[3] + NS_ACCUMULATE_BOUND_TEXELS : 0;
    uint64_t j_bytes =
        4ull * sizeof(float) * parts_walked * (NS_TABLE_CELLS + NS_ACCUMULATE_BOUND_TEXELS);

    gpu_buffer own[B_COUNT];
    memset(own, 0, sizeof own);
    gpu_buffer_desc descs[B_COUNT] = {
        [B_PARAMS] = {.size = sizeof params,
                      .kind = GPU_BUFFER_UNIFORM,
                      .data = &params,
                      .data_size = sizeof params,
                      .label = "ns.accumulate.params"},
        /* Interleaved below. */
        [B_J] = {.size = j_bytes, .uninitialized = 1, .label = "ns.accumulate.j"},
        /* A J of zeros (every albedo 0) needs no walk: A is the zeroed buffer. */
        [B_A] = {.size = table_bytes,
                 .uninitialized = !all_zero && every_cell,
                 .host_reads = a_host_reads,
                 .label = "ns.tables.a"},
        [B_COUNTERS] = {.size = NS_ACCUMULATE_COUNTER_COUNT * sizeof(uint32_t),
                        .label = "ns.accumulate.counters"},
        /* A table of its own, as the three's: a word stands in without the second three. */
        [B_SECOND] = {.size = second_j ? table_bytes : sizeof(float),
                      .uninitialized = second_j && !all_zero && every_cell,
                      .host_reads = a_host_reads,
                      .label = second_j ? "ns.tables.a" : "ns.accumulate.second"},
    };
    status = gpu_buffers_create(&ctx->dev, own, descs, B_COUNT, err);
    if (!status) {
        float(*texel)[4] = own[B_J].mapped;
        interleave_j(texel, j);
        remainder_bounds(texel + params.counts[3], j);
        if (second_j) {
            interleave_j(texel + NS_TABLE_CELLS, second_j);
            remainder_bounds(texel + params.second[1], second_j);
        }
    }
    if (!status && !all_zero) {
        gpu_buffer *bound[B_COUNT] = {&own[B_PARAMS], &own[B_J], &own[B_A], &own[B_COUNTERS],
                                      &own[B_SECOND]};
        status = dispatch_accumulate(ctx, bound, second_j != NULL, params.counts[0], err);
    }
    if (!status) {
        const uint32_t *c = own[B_COUNTERS].mapped;
        if (c[NS_ACCUMULATE_COUNTER_CAPPED])
            status = ns_fail(err, NS_ERR_INTERNAL,
                             "accumulate: %u cells walked past %u steps (at most 274 bins lie "
                             "on a line)",
                             c[NS_ACCUMULATE_COUNTER_CAPPED], NS_ACCUMULATE_STEP_CAP);
        if (steps)
            *steps = (uint64_t)c[NS_ACCUMULATE_COUNTER_STEPS_HIGH] << 32 |
                     c[NS_ACCUMULATE_COUNTER_STEPS];
    }
    if (!status) {
        out->a = own[B_A];
        own[B_A] = (gpu_buffer){0};
        set_default_grid(out, table_bytes);
    }
    if (!status && second_j) {
        parts->second_out->a = own[B_SECOND];
        own[B_SECOND] = (gpu_buffer){0};
        set_default_grid(parts->second_out, table_bytes);
    }
    for (int i = 0; i < B_COUNT; i++)
        gpu_buffer_destroy(&ctx->dev, &own[i]);
    return status;
}

void ns_scatter_tables_free(ns_context *ctx, ns_scatter_tables *t)
{
    gpu_buffer_destroy(&ctx->dev, &t->a);
    memset(t, 0, sizeof *t);
}

/* ---------------------------------------------------------------------------------------
 * Cache
 * ------------------------------------------------------------------------------------- */
/* The same material, orders and modes (reach aside: find_a). */
static int same_key(const ns_table_key *a, const ns_table_key *b)
{
    return a->source == b->source && a->g == b->g && a->albedo[0] == b->albedo[0] &&
           a->albedo[1] == b->albedo[1] && a->albedo[2] == b->albedo[2] && a->orders == b->orders &&
           a->accumulation == b->accumulation && a->tables == b->tables;
}

static uint32_t key_reach(const ns_table_key *key)
{
    return key->reach_bins && key->reach_bins < NS_TABLE_NRHO ? key->reach_bins : NS_TABLE_NRHO;
}

/* The A of key's material, orders and modes that reaches at least as far as key asks. */
static cache_entry *find_a(struct ns_table_cache *cache, const ns_table_key *key)
{
    for (uint32_t i = 0; i < cache->count; i++) {
        cache_entry *e = &cache->entries[i];
        if (e->kind == ENTRY_A && same_key(&e->key, key) && key_reach(&e->key) >= key_reach(key))
            return e;
    }
    return NULL;
}

/* Two channel albedos share one J when their tables differ by less than 1e-4 in energy:
 * |a - b| <= 1e-4 min(a, 1 - a) bounds the change of a^2 (near 0) and of a^3 / (1 - a)
 * (near 1) to ~3e-4 relative, far below the network's or the Monte Carlo's own error. It
 * matters because an RGB medium with one albedo often arrives with three that differ in the
 * last bits of sigma_s / sigma_t. */
static int same_albedo(float a, float b)
{
    float hi = fmaxf(a, b);
    return a == b || fabsf(a - b) <= 1e-4f * fminf(hi, 1.0f - hi);
}

static cache_entry *find_j(struct ns_table_cache *cache, ns_method source, float g, float albedo)
{
    for (uint32_t i = 0; i < cache->count; i++) {
        cache_entry *e = &cache->entries[i];
        if (e->kind == ENTRY_J && e->source == source && e->g == g &&
            same_albedo(e->albedo, albedo))
            return e;
    }
    return NULL;
}

static void touch(struct ns_table_cache *cache, cache_entry *e)
{
    e->last_use = ++cache->clock;
}

static void free_entry(ns_context *ctx, cache_entry *e)
{
    if (e->kind == ENTRY_A) {
        destroy_kept_buffer(&ctx->dev, &e->a.a);
    } else {
        free(e->j[0]);
        free(e->j[1]);
    }
    memset(e, 0, sizeof *e);
}

static uint32_t lru_index(const struct ns_table_cache *cache)
{
    uint32_t oldest = 0;
    for (uint32_t i = 1; i < cache->count; i++)
        if (cache->entries[i].last_use < cache->entries[oldest].last_use)
            oldest = i;
    return oldest;
}

static void remove_entry(ns_context *ctx, struct ns_table_cache *cache, uint32_t index)
{
    __atomic_sub_fetch(&cache->bytes, cache->entries[index].bytes, __ATOMIC_RELAXED);
    free_entry(ctx, &cache->entries[index]);
    cache->entries[index] = cache->entries[--cache->count];
}

/* Adds e (copied) and returns where it lives now; NULL when out of memory (e untouched). */
static cache_entry *insert(struct ns_table_cache *cache, const cache_entry *e)
{
    if (cache->count == cache->capacity) {
        uint32_t capacity = cache->capacity ? 2 * cache->capacity : 16;
        cache_entry *grown = realloc(cache->entries, capacity * sizeof *grown);
        if (!grown)
            return NULL;
        cache->entries = grown;
        cache->capacity = capacity;
    }
    cache_entry *slot = &cache->entries[cache->count++];
    *slot = *e;
    __atomic_add_fetch(&cache->bytes, e->bytes, __ATOMIC_RELAXED);
    touch(cache, slot);
    return slot;
}

/* Evicts least recently used entries until the cache fits ctx->table_cache_bytes, never the
 * A entry `keep` (the caller is about to use it: it stays even when it alone is too big).
 * Returns keep's new address (entries move when others are removed). */
static cache_entry *evict(ns_context *ctx, struct ns_table_cache *cache, cache_entry *keep)
{
    uint32_t kept = (uint32_t)(keep - cache->entries);
    while (cache->bytes > ctx->table_cache_bytes) {
        uint32_t oldest = UINT32_MAX;
        for (uint32_t i = 0; i < cache->count; i++) {
            if (i == kept)
                continue;
            if (oldest == UINT32_MAX || cache->entries[i].last_use < cache->entries[oldest].last_use)
                oldest = i;
        }
        if (oldest == UINT32_MAX)
            break;
        remove_entry(ctx, cache, oldest);
        if (kept == cache->count) /* the last entry, moved into the slot removed */
            kept = oldest;
    }
    return &cache->entries[kept];
}

void ns_tables_cache_usage(const ns_context *ctx, uint64_t *bytes, uint32_t *entries)
{
    const struct ns_table_cache *cache = ctx->tables;
    *bytes = cache ? cache->bytes : 0;
    *entries = cache ? cache->count : 0;
}

uint64_t ns_context_table_cache_bytes(const ns_context *ctx)
{
    return ctx && ctx->tables ? __atomic_load_n(&ctx->tables->bytes, __ATOMIC_RELAXED) : 0;
}

const float *ns_tables_cached_j(const ns_context *ctx, ns_method source, float g, float albedo,
                                uint32_t order)
{
    if (!ctx->tables || order > 1)
        return NULL;
    const cache_entry *e = find_j((struct ns_table_cache *)ctx->tables, source, g, albedo);
    return e ? e->j[order] : NULL;
}

/* ---------------------------------------------------------------------------------------
 * What a render took from the cache and what it made (ns_render_stats.tables_reused and
 * tables_made): each table counts once per render, however many rounds and batches ask.
 * ------------------------------------------------------------------------------------- */
static void count_reused(const ns_context *ctx, cache_entry *e, ns_table_stats *stats)
{
    if (e->counted == ctx->run.serial)
        return; /* made or counted already by this render */
    e->counted = ctx->run.serial;
    stats->tables_reused++;
}

static void count_made(const ns_context *ctx, cache_entry *e, ns_table_stats *stats)
{
    e->counted = ctx->run.serial;
    stats->tables_made++;
}

/* An A that is a blend of albedo nodes (render.tables "interpolated", or "auto" where it
 * chose them), counted once per render as the others are (made: just inserted, so not
 * counted yet whatever its field says): renders of one scene with "auto" can differ within
 * the blend's error, and this says which did. */
static void count_blended(const ns_context *ctx, cache_entry *e, int made, ns_table_stats *stats)
{
    if (e->key.tables != NS_TABLES_INTERPOLATED || (!made && e->counted_blended == ctx->run.serial))
        return;
    e->counted_blended = ctx->run.serial;
    stats->tables_blended++;
}

/* ---------------------------------------------------------------------------------------
 * J: from the networks or the Monte Carlo provider, one cache entry per distinct albedo
 * ------------------------------------------------------------------------------------- */
static const uint64_t j_entry_bytes = 2ull * NS_TABLE_CELLS * sizeof(float);

/* Channels of key whose J is missing, each distinct albedo once; the others are counted as
 * reused. */
static uint32_t missing_albedos(ns_context *ctx, const ns_table_key *key, float albedo[3],
                                ns_table_stats *stats)
{
    uint32_t n = 0;
    for (int c = 0; c < 3; c++) {
        float a = key->albedo[c];
        int listed = 0;
        for (uint32_t k = 0; k < n; k++)
            listed |= same_albedo(albedo[k], a);
        if (listed)
            continue;
        cache_entry *e = find_j(ctx->tables, key->source, key->g, a);
        if (e)
            count_reused(ctx, e, stats);
        else
            albedo[n++] = a;
    }
    return n;
}

static int alloc_j_entry(cache_entry *e, const ns_table_key *key, float albedo, ns_error *err)
{
    memset(e, 0, sizeof *e);
    e->kind = ENTRY_J;
    e->source = key->source;
    e->g = key->g;
    e->albedo = albedo;
    e->bytes = j_entry_bytes;
    e->j[0] = malloc(NS_TABLE_CELLS * sizeof(float));
    e->j[1] = malloc(NS_TABLE_CELLS * sizeof(float));
    if (!e->j[0] || !e->j[1]) {
        free(e->j[0]);
        free(e->j[1]);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "tables: out of memory for J");
    }
    return NS_OK;
}

static int insert_j_entry(ns_context *ctx, cache_entry *e, ns_table_stats *stats, ns_error *err)
{
    e->counted = ctx->run.serial;
    if (insert(ctx->tables, e)) {
        stats->tables_made++;
        return NS_OK;
    }
    free(e->j[0]);
    free(e->j[1]);
    return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "tables: out of memory for the cache");
}

/* The networks' reconstruction on the default grid, renormalised to the exact energies (the
 * default of `nscatter table`), of the orders asked for (0: both) for n channels of albedo[c]
 * and g, into out (float [2][3][cells]; only those channels and orders are written). */
static int reconstruct(ns_context *ctx, float g, const double *albedo, uint32_t n, uint32_t orders,
                       float *out, ns_error *err)
{
    struct ns_nn_state *nn = ctx->nn;
    ns_table_grid grid;
    ns_table_grid_default(&grid);
    ns_nn_reconstruct_desc desc = {
        .nets = {&nn->nets[0], &nn->nets[1]},
        .grid = {.n = {NS_TABLE_NZ, NS_TABLE_NRHO, NS_TABLE_NTHETA, NS_TABLE_NPHI},
                 .edges = {grid.z, grid.rho, grid.theta, grid.phi}},
        .g = g,
        .renormalise = 1,
        .channels = n,
        .out = out,
        .orders = orders,
    };
    for (uint32_t c = 0; c < 3; c++)
        desc.albedo[c] = albedo[c < n ? c : 0];
    return ns_nn_reconstruct(&ctx->dev, &nn->gpu, &desc, NULL, err);
}

/* Double scattering is the light of exactly two events, lengths in mfp: it depends on the
 * albedo only through a^2, J_2(a) = a^2 U_g. The double network takes the albedo as an
 * input all the same, and the shapes of its tables differ across albedos by 0.1-0.9%
 * (energy-weighted L1 between albedos 0.3 and 0.995 at g 0.45, 0.8 and 0.95), while its
 * error against Monte Carlo is 4.5% at every albedo (g 0.45; docs/network.md, *One double
 * table per g*): the differences are the network's noise, not physics. So the renderer
 * evaluates the double network once per g, at the albedo in the middle of its input
 * (1 - sqrt(1 - albedo_max), 0.968), keeps that table per unit a^2, and makes every
 * channel's double table a^2 times it: a new albedo at the same g runs the multiple network
 * alone, and a material's tables do not depend on which albedos came before. One g is kept
 * (10.6 MB): a sweep over g, or a scene of two media of different g at a new albedo, makes
 * it again per g, one channel of one order (about a sixth of an RGB material's networks). */
static int unit_double(ns_context *ctx, float g, const float **unit, ns_error *err)
{
    struct ns_nn_state *nn = ctx->nn;
    *unit = NULL;
    if (nn->unit_double && nn->unit_double_g == g) {
        *unit = nn->unit_double;
        return NS_OK;
    }
    /* Made aside: a failed or cancelled attempt keeps the last g's table. */
    float *made = malloc(NS_TABLE_CELLS * sizeof(float));
    if (!made)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "tables: out of memory for J");
    double reference = 1.0 - sqrt(1.0 - (double)nn->nets[0].h.albedo_max);
    /* One channel of the double order alone writes the first cells of out (nn.h). */
    int status = reconstruct(ctx, g, &reference, 1, NS_NN_ORDER_DOUBLE, made, err);
    if (status) {
        free(made);
        return status;
    }
    float per_unit = (float)(1.0 / (reference * reference));
    for (size_t i = 0; i < NS_TABLE_CELLS; i++)
        made[i] *= per_unit;
    free(nn->unit_double);
    nn->unit_double = made;
    nn->unit_double_g = g;
    *unit = made;
    return NS_OK;
}

/* J of both orders from the networks for n (1 to 3) channels of albedo[c] and g, into out
 * (float [2][3][cells]; only the n channels are defined): multiple scattering from its network
 * at each albedo, double scattering a^2 times the g's unit table (unit_double). */
static int network_tables(ns_context *ctx, float g, const double *albedo, uint32_t n, float *out,
                          ns_error *err)
{
    const float *unit;
    int status = unit_double(ctx, g, &unit, err);
    if (!status)
        status = reconstruct(ctx, g, albedo, n, NS_NN_ORDER_MULTIPLE, out, err);
    for (uint32_t c = 0; c < n && !status; c++) {
        float *j = out + (size_t)c * NS_TABLE_CELLS;
        float energy = (float)(albedo[c] * albedo[c]);
        for (size_t i = 0; i < NS_TABLE_CELLS; i++)
            j[i] = unit[i] * energy;
    }
    return status;
}

static int network_j(ns_context *ctx, const ns_table_key *key, const float *albedo, uint32_t n,
                     ns_table_stats *stats, ns_error *err)
{
    struct ns_nn_state *nn = ctx->nn;
    if (!nn->nets_ok)
        return ns_fail(err, NS_ERR_NOT_AVAILABLE, "method nn: %s", nn->nets_error.message);
    size_t cells = NS_TABLE_CELLS;
    float *out = malloc(2 * 3 * cells * sizeof(float));
    if (!out)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "tables: out of memory for J");
    const double channel_albedo[3] = {albedo[0], n > 1 ? albedo[1] : 0, n > 2 ? albedo[2] : 0};
    int status = network_tables(ctx, key->g, channel_albedo, n, out, err);
    for (uint32_t c = 0; c < n && !status; c++) {
        cache_entry e;
        status = alloc_j_entry(&e, key, albedo[c], err);
        if (status)
            break;
        for (int o = 0; o < 2; o++)
            memcpy(e.j[o], out + ((size_t)o * 3 + c) * cells, cells * sizeof(float));
        status = insert_j_entry(ctx, &e, stats, err);
    }
    free(out);
    return status;
}

/* A provider's tables are input from outside: finite and non-negative, or refused. */
static int check_j_pair(float *const j[2], float albedo, ns_error *err)
{
    for (int o = 0; o < 2; o++)
        for (size_t i = 0; i < NS_TABLE_CELLS; i++)
            if (!(j[o][i] >= 0.0f) || isinf(j[o][i]))
                return ns_fail(err, NS_ERR_INTERNAL,
                               "method table: the Monte Carlo provider's %s table for albedo %g "
                               "has %g at cell %zu",
                               o ? "multiple" : "double", (double)albedo, (double)j[o][i], i);
    return NS_OK;
}

static int monte_carlo_j(ns_context *ctx, const ns_table_key *key, const float *albedo, uint32_t n,
                         ns_table_stats *stats, ns_error *err)
{
    if (!ctx->mc_tables)
        return ns_fail(err, NS_ERR_NOT_AVAILABLE,
                       "method table: this context has no Monte Carlo table provider");
    int status = NS_OK;
    for (uint32_t c = 0; c < n && !status; c++) {
        /* The provider runs on the CPU, seconds per channel, and cannot be stopped: the
         * render's cancellation is checked before each (the channels done stay cached). */
        status = ns_run_check(ctx, err);
        if (status)
            break;
        if (c > 0)
            ns_progress_tick(ctx, (double)c / n);
        cache_entry e;
        status = alloc_j_entry(&e, key, albedo[c], err);
        if (status)
            break;
        status = ctx->mc_tables(ctx->mc_user, key->g, albedo[c], e.j[0], e.j[1], err);
        if (!status)
            status = check_j_pair(e.j, albedo[c], err);
        if (status) {
            free(e.j[0]);
            free(e.j[1]);
            break;
        }
        status = insert_j_entry(ctx, &e, stats, err);
    }
    return status;
}

/* J of each channel for key: the network's or the provider's, computed once per albedo (the
 * stage "reconstruct", the first half of the current span). */
static int ensure_j(ns_context *ctx, const ns_table_key *key, ns_table_stats *stats, ns_error *err)
{
    float albedo[3];
    uint32_t n = missing_albedos(ctx, key, albedo, stats);
    stats->reconstruct_ms = 0.0;
    /* Albedo 0 (clear glass, a pure absorber) emits nothing after the first event: J is 0
     * exactly, with no network or simulation to run. */
    for (uint32_t c = 0; c < n; c++) {
        if (albedo[c] != 0.0f)
            continue;
        cache_entry e;
        int status = alloc_j_entry(&e, key, 0.0f, err);
        if (!status) {
            memset(e.j[0], 0, NS_TABLE_CELLS * sizeof(float));
            memset(e.j[1], 0, NS_TABLE_CELLS * sizeof(float));
            status = insert_j_entry(ctx, &e, stats, err);
        }
        if (status)
            return status;
        albedo[c--] = albedo[--n];
    }
    if (!n)
        return NS_OK;
    ns_stage stage = ns_stage_begin(ctx, "reconstruct", 0.0, 0.5);
    int status = key->source == NS_METHOD_NN ? network_j(ctx, key, albedo, n, stats, err)
                                             : monte_carlo_j(ctx, key, albedo, n, stats, err);
    stats->reconstruct_ms = ns_stage_end(ctx, &stage);
    stats->reconstructed = 1;
    return status;
}

/* The J that key asks for, [3][cells]: the chosen orders summed, per channel. */
static int sum_orders(ns_context *ctx, const ns_table_key *key, float **out, ns_error *err)
{
    size_t cells = NS_TABLE_CELLS;
    float *j = malloc(3 * cells * sizeof(float));
    if (!j)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "tables: out of memory for J");
    int want_double = (key->orders & NS_COMPONENT_DOUBLE) != 0;
    int want_multiple = (key->orders & NS_COMPONENT_MULTIPLE) != 0;
    for (int c = 0; c < 3; c++) {
        cache_entry *e = find_j(ctx->tables, key->source, key->g, key->albedo[c]);
        if (!e) { /* ensure_j put every channel there just before */
            free(j);
            return ns_fail(err, NS_ERR_INTERNAL, "tables: J of albedo %g vanished from the cache",
                           (double)key->albedo[c]);
        }
        touch(ctx->tables, e);
        float *dst = j + c * cells;
        for (size_t i = 0; i < cells; i++)
            dst[i] = (want_double ? e->j[0][i] : 0.0f) + (want_multiple ? e->j[1][i] : 0.0f);
    }
    *out = j;
    return NS_OK;
}

static int check_key(const ns_table_key *key, ns_error *err)
{
    if (key->source != NS_METHOD_NN && key->source != NS_METHOD_TABLE)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "render.method: tables exist for nn and table only (got %d)",
                       (int)key->source);
    if (!(key->g > -1.0f && key->g < 1.0f))
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "material g: %g outside (-1, 1)",
                       (double)key->g);
    for (int c = 0; c < 3; c++)
        if (!(key->albedo[c] >= 0.0f && key->albedo[c] < 1.0f))
            return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                           "material albedo[%d]: %g outside [0, 1) (multiple scattering of a "
                           "medium that absorbs nothing has no finite table)",
                           c, (double)key->albedo[c]);
    uint32_t orders = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE;
    if (!key->orders || (key->orders & ~orders))
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "tables: orders 0x%x (double and/or multiple only: the blurred first order "
                       "is computed in the gather)",
                       key->orders);
    if (key->accumulation != NS_ACCUMULATION_EXACT && key->accumulation != NS_ACCUMULATION_PAPER)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "render.accumulation: %d unknown",
                       (int)key->accumulation);
    if (key->tables != NS_TABLES_EXACT && key->tables != NS_TABLES_INTERPOLATED &&
        key->tables != NS_TABLES_AUTO)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "render.tables: %d unknown", (int)key->tables);
    if (key->tables == NS_TABLES_INTERPOLATED && key->source != NS_METHOD_NN)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "render.tables: interpolated tables apply to method nn only");
    return NS_OK;
}

static uint64_t weights_bytes(const ns_table_key *key)
{
    /* Both networks, as their files hold them (header + float parameters). */
    return key->source == NS_METHOD_NN ? 2ull * (NS_NN_HEADER_SIZE + NS_NN_PARAMS * sizeof(float))
                                       : 0;
}

void ns_tables_expect_orders(ns_context *ctx, uint32_t orders)
{
    struct ns_table_cache *cache = ctx->tables;
    uint64_t serial = ctx->run.serial + 1;
    if (cache->orders_expected_serial != serial) {
        cache->orders_expected_serial = serial;
        cache->orders_expected_count = 0;
    }
    orders &= NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE;
    int listed = !orders;
    for (uint32_t i = 0; i < cache->orders_expected_count; i++)
        listed |= cache->orders_expected[i] == orders;
    uint32_t cap = sizeof cache->orders_expected / sizeof cache->orders_expected[0];
    if (!listed && cache->orders_expected_count < cap)
        cache->orders_expected[cache->orders_expected_count++] = orders;
}

/* ---------------------------------------------------------------------------------------
 * Interpolated tables (render.tables "interpolated"; docs/rendering.md, *Interpolated
 * tables*). In the source frame every length is in mfp, so a channel's table depends on its
 * albedo and g only, and each order's A divided by its exact energy E_k is a smooth function
 * of u = -ln(1 - a), the variable the networks take their albedo in (scaled to 1 at their
 * albedo_max, beyond which they clamp it). A node holds that normalised A of both orders at
 * one u; a material's table is E_k(a) times the cubic Lagrange interpolation of its four
 * nearest nodes, per channel and order. The nodes are made with the networks and the
 * accumulation of the exact path, three at a time (one per channel), when a material first
 * needs them, and stay in the cache like any table.
 *
 * Measured (docs/rendering.md): 14 intervals put the interpolated A within 0.35% (energy-
 * weighted L1) of the exact one, against the networks' own 3-15% from Monte Carlo.
 * ------------------------------------------------------------------------------------- */
#define ALBEDO_NODE_INTERVALS (NS_TABLE_ALBEDO_NODES - 1u)
/* Node 0 stands for u = 0, where the energies vanish and A / E_k is their limit: the
 * networks are evaluated at this albedo instead (its u is 0.002 of an interval). */
#define ALBEDO_NODE_FIRST 1e-3

/* An empty cache entry for node `node` of key's g and accumulation (the size of a J entry:
 * two orders of one channel). */
static int alloc_node_entry(cache_entry *e, const ns_table_key *key, uint32_t node, ns_error *err)
{
    int status = alloc_j_entry(e, key, 0.0f, err);
    if (status)
        return status;
    e->kind = ENTRY_NODE;
    e->node = node;
    e->accumulation = key->accumulation;
    return NS_OK;
}

static double node_u_max(const ns_nn_header *h)
{
    return -log1p(-(double)h->albedo_max);
}

static double node_u(const ns_nn_header *h, uint32_t i)
{
    if (i == 0)
        return -log1p(-ALBEDO_NODE_FIRST);
    if (i == ALBEDO_NODE_INTERVALS) /* exactly: an albedo beyond albedo_max weighs it 1 */
        return node_u_max(h);
    return node_u_max(h) * i / ALBEDO_NODE_INTERVALS;
}

static double node_albedo(const ns_nn_header *h, uint32_t i)
{
    return i == 0 ? ALBEDO_NODE_FIRST : -expm1(-node_u(h, i));
}

int ns_tables_node_albedos(ns_context *ctx, double albedo[NS_TABLE_ALBEDO_NODES], ns_error *err)
{
    struct ns_nn_state *nn = ctx->nn;
    if (!nn || !nn->nets_ok)
        return ns_fail(err, NS_ERR_NOT_AVAILABLE, "method nn: %s",
                       nn ? nn->nets_error.message : "no networks");
    for (uint32_t i = 0; i < NS_TABLE_ALBEDO_NODES; i++)
        albedo[i] = node_albedo(&nn->nets[0].h, i);
    return NS_OK;
}

/* The four nodes first..first + 3 around albedo a (> 0) and their Lagrange weights. */
static uint32_t node_stencil(const ns_nn_header *h, double a, double w[4])
{
    double u = fmin(-log1p(-a), node_u_max(h)); /* the networks clamp beyond albedo_max */
    uint32_t k = 0;
    while (k + 1 < ALBEDO_NODE_INTERVALS && node_u(h, k + 1) <= u)
        k++;
    uint32_t first = k == 0 ? 0 : k - 1;
    if (first > ALBEDO_NODE_INTERVALS - 3)
        first = ALBEDO_NODE_INTERVALS - 3;
    for (uint32_t i = 0; i < 4; i++) {
        w[i] = 1.0;
        for (uint32_t j = 0; j < 4; j++)
            if (j != i)
                w[i] *= (u - node_u(h, first + j)) / (node_u(h, first + i) - node_u(h, first + j));
    }
    return first;
}

static cache_entry *find_node(struct ns_table_cache *cache, float g, ns_accumulation accumulation,
                              uint32_t node)
{
    for (uint32_t i = 0; i < cache->count; i++) {
        cache_entry *e = &cache->entries[i];
        if (e->kind == ENTRY_NODE && e->g == g && e->accumulation == accumulation && e->node == node)
            return e;
    }
    return NULL;
}

/* Tables on disk (ns_context_desc.table_node_dir): each albedo node, one file per (networks,
 * g, accumulation, node). A file is
 * this header, then its tables (float [tables][cells], native byte order). It is never
 * trusted: every header field is checked against what the table must be, and the payload
 * against the hash recorded when it was written; a file that fails is made again and
 * overwritten (stderr says which and why). Writes are atomic; a folder that cannot be written
 * costs only the next process the table.
 *
 * What made a table is part of its identity, in its header and its name (so that two builds
 * sharing a folder keep their own files instead of overwriting each other's): the networks
 * (their CRCs; nodes only), the SPIR-V of the three shaders that compute them
 * (nn_reconstruct, nn_interpolate, accumulate), the accumulation's parameters in both modes
 * (its cut, its floor, the paper's length, the step cap), the networks' sampling of the grid
 * and the node albedos' placement, and TABLE_FILE_CODE_VERSION for what none of those show (the
 * renormalisation, the blend, double scattering from one table per g: 2 since 2026-12-02):
 * bump it when that changes. The folder is kept within ns_context_desc.table_dir_bytes, the
 * least recently used files first (prune_table_files). */
#define TABLE_FILE_CODE_VERSION 2u
enum { TABLE_FILE_NODE = 1 };
typedef struct table_file_header {
    char magic[8];            /* TABLE_FILE_MAGIC */
    uint64_t code_hash;       /* table_code_hash() */
    uint32_t kind;            /* TABLE_FILE_* */
    uint32_t tables;          /* float [cells] arrays in the payload */
    uint32_t grid[4];         /* NZ, NRHO, NTHETA, NPHI */
    uint32_t node, accumulation;
    uint32_t weights_crc[2];  /* the networks' payload CRC-32s */
    double g, albedo, scale, extent;
    uint64_t payload_hash;    /* payload_hash() of the tables */
} table_file_header;
static const char TABLE_FILE_MAGIC[8] = "NSTABLE";

static uint64_t fnv_bytes(uint64_t h, const void *data, size_t size)
{
    const unsigned char *p = data;
    for (size_t i = 0; i < size; i++)
        h = (h ^ p[i]) * 0x100000001b3ull;
    return h;
}

/* 64-bit FNV-1a over 8-byte words: a changed, swapped or truncated value shows, at a few
 * milliseconds per table (byte by byte, or a CRC, costs several times that). */
_Static_assert(NS_TABLE_CELLS * sizeof(float) % 8 == 0, "payload_hash reads 8-byte words");
static uint64_t payload_hash(float *const *tables, uint32_t n)
{
    uint64_t h = 0xcbf29ce484222325ull;
    for (uint32_t t = 0; t < n; t++) {
        const unsigned char *bytes = (const unsigned char *)tables[t];
        for (size_t i = 0; i < NS_TABLE_CELLS * sizeof(float); i += 8) {
            uint64_t w;
            memcpy(&w, bytes + i, 8);
            h = (h ^ w) * 0x100000001b3ull;
        }
    }
    return h;
}

static uint64_t table_code_hash(void)
{
    static const char *const shaders[] = {"nn_reconstruct", "nn_interpolate", "accumulate"};
    uint32_t version = TABLE_FILE_CODE_VERSION;
    uint64_t h = fnv_bytes(0xcbf29ce484222325ull, &version, sizeof version);
    for (size_t i = 0; i < sizeof shaders / sizeof shaders[0]; i++) {
        size_t size = 0;
        const uint32_t *code = ns_shader_code(shaders[i], &size);
        h = code ? fnv_bytes(h, code, size) : h;
    }
    ns_table_grid grid;
    ns_table_grid_default(&grid);
    const float no_j[6] = {0};
    for (int mode = 0; mode < 2; mode++) {
        GpuAccumulateParams p =
            accumulate_params(&grid, no_j, NULL, (ns_accumulation)mode, NS_TABLE_NRHO, 0,
                              NS_TABLE_NRHO);
        h = fnv_bytes(h, &p, sizeof p);
    }
    ns_nn_sampling sampling = ns_nn_sampling_default();
    h = fnv_bytes(h, sampling.stride, sizeof sampling.stride);
    h = fnv_bytes(h, &sampling.full_radius, sizeof sampling.full_radius);
    const double nodes[2] = {ALBEDO_NODE_FIRST, ALBEDO_NODE_INTERVALS};
    return fnv_bytes(h, nodes, sizeof nodes);
}

static table_file_header file_header(uint32_t kind, uint32_t tables, ns_accumulation accumulation)
{
    ns_table_grid grid;
    ns_table_grid_default(&grid);
    table_file_header h;
    memset(&h, 0, sizeof h); /* the padding too: the header is written as bytes */
    memcpy(h.magic, TABLE_FILE_MAGIC, sizeof h.magic);
    h.code_hash = table_code_hash();
    h.kind = kind;
    h.tables = tables;
    h.grid[0] = NS_TABLE_NZ;
    h.grid[1] = NS_TABLE_NRHO;
    h.grid[2] = NS_TABLE_NTHETA;
    h.grid[3] = NS_TABLE_NPHI;
    h.accumulation = (uint32_t)accumulation;
    h.scale = grid.scale;
    h.extent = grid.extent;
    return h;
}

static table_file_header node_header(const ns_context *ctx, const ns_table_key *key, uint32_t node)
{
    const ns_nn_weights *nets = ctx->nn->nets;
    table_file_header h = file_header(TABLE_FILE_NODE, 2, key->accumulation);
    h.node = node;
    h.weights_crc[0] = nets[0].h.payload_crc32;
    h.weights_crc[1] = nets[1].h.payload_crc32;
    h.g = key->g;
    h.albedo = node_albedo(&nets[0].h, node);
    return h;
}

/* The file of the table h describes; 0 when its name does not fit in cap (the folder is then
 * not used: a cut name could be another table's). */
static int file_path(const ns_context *ctx, const table_file_header *h, char *path, size_t cap)
{
    const char *mode = h->accumulation ? "paper" : "exact";
    int n = snprintf(path, cap, "%s/node_%016llx_w%08x%08x_g%.9g_%s_%02u.bin", ctx->table_node_dir,
                     (unsigned long long)h->code_hash, h->weights_crc[0], h->weights_crc[1], h->g,
                     mode, h->node);
    return n > 0 && (size_t)n < cap;
}

/* Whether a name in the folder is one of the table files (prune_table_files may remove it):
 * blur_unit_* are the blurred first order's tables that earlier builds kept there. */
static int is_table_file(const char *name)
{
    size_t len = strlen(name);
    return (strncmp(name, "node_", 5) == 0 || strncmp(name, "blur_unit_", 10) == 0) && len > 4 &&
           strcmp(name + len - 4, ".bin") == 0;
}

typedef struct table_file_use {
    struct timespec used; /* modification time: written, or last read (read_table_file) */
    off_t size;
    char name[256];
} table_file_use;

static int older_first(const void *a, const void *b)
{
    const struct timespec *x = &((const table_file_use *)a)->used;
    const struct timespec *y = &((const table_file_use *)b)->used;
    if (x->tv_sec != y->tv_sec)
        return x->tv_sec < y->tv_sec ? -1 : 1;
    return x->tv_nsec < y->tv_nsec ? -1 : x->tv_nsec > y->tv_nsec;
}

/* Removes the least recently used table files until the folder's hold at most
 * ctx->table_dir_bytes; other files are never touched. */
static void prune_table_files(const ns_context *ctx)
{
    DIR *dir = ctx->table_node_dir ? opendir(ctx->table_node_dir) : NULL;
    if (!dir)
        return;
    table_file_use *files = NULL;
    size_t count = 0, capacity = 0;
    uint64_t total = 0;
    struct dirent *d;
    while ((d = readdir(dir))) {
        if (!is_table_file(d->d_name) || strlen(d->d_name) >= sizeof files->name)
            continue;
        char path[4096];
        struct stat st;
        int n = snprintf(path, sizeof path, "%s/%s", ctx->table_node_dir, d->d_name);
        if (n < 0 || (size_t)n >= sizeof path || stat(path, &st) != 0 || !S_ISREG(st.st_mode))
            continue;
        if (count == capacity) {
            size_t grown_capacity = capacity ? 2 * capacity : 64;
            table_file_use *grown = realloc(files, grown_capacity * sizeof *files);
            if (!grown)
                break;
            files = grown;
            capacity = grown_capacity;
        }
        files[count] = (table_file_use){.used = st.st_mtim, .size = st.st_size};
        snprintf(files[count].name, sizeof files[count].name, "%s", d->d_name);
        total += (uint64_t)st.st_size;
        count++;
    }
    closedir(dir);
    if (total > ctx->table_dir_bytes) {
        qsort(files, count, sizeof *files, older_first);
        for (size_t i = 0; i < count && total > ctx->table_dir_bytes; i++) {
            char path[4096];
            snprintf(path, sizeof path, "%s/%s", ctx->table_node_dir, files[i].name);
            if (unlink(path) == 0)
                total -= (uint64_t)files[i].size;
        }
    }
    free(files);
}

/* Why the file at path cannot be the table `want` describes (its tables read into out), or
 * NULL. */
static const char *read_file_problem(const char *path, const table_file_header *want, float *const *out)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return "it cannot be opened";
    table_file_header h;
    const char *problem = NULL;
    if (fread(&h, sizeof h, 1, f) != 1)
        problem = "its header is cut short";
    else if (memcmp(h.magic, want->magic, sizeof h.magic) != 0)
        problem = "it is not an nscatter table file";
    else if (h.code_hash != want->code_hash)
        problem = "another version of nscatter made it";
    else if (memcmp(h.grid, want->grid, sizeof h.grid) != 0 || h.scale != want->scale ||
             h.extent != want->extent)
        problem = "its grid is not the default grid";
    else if (h.kind != want->kind || h.tables != want->tables || h.node != want->node ||
             h.accumulation != want->accumulation || h.g != want->g || h.albedo != want->albedo)
        problem = "it holds another table";
    else if (memcmp(h.weights_crc, want->weights_crc, sizeof h.weights_crc) != 0)
        problem = "other networks made it";
    for (uint32_t t = 0; t < want->tables && !problem; t++)
        if (fread(out[t], sizeof(float), NS_TABLE_CELLS, f) != NS_TABLE_CELLS)
            problem = "its data are cut short";
    if (!problem && fgetc(f) != EOF)
        problem = "it is longer than its header says";
    if (!problem && payload_hash(out, want->tables) != h.payload_hash)
        problem = "its data do not match their recorded hash";
    fclose(f);
    return problem;
}

/* The tables of `want` from the folder into out: 1 when read (a missing file is not news; a
 * rejected one is said on stderr). */
static int read_table_file(const ns_context *ctx, const table_file_header *want, float *const *out)
{
    char path[4096];
    struct stat st;
    if (!file_path(ctx, want, path, sizeof path) || stat(path, &st) != 0)
        return 0;
    const char *problem = read_file_problem(path, want, out);
    if (problem)
        fprintf(stderr, "nscatter: table file %s rejected (%s); making it again\n", path, problem);
    else
        utimensat(AT_FDCWD, path, NULL, 0); /* used now: the last to be pruned */
    return problem == NULL;
}

static void write_table_file(const ns_context *ctx, table_file_header h, float *const *tables)
{
    h.payload_hash = payload_hash(tables, h.tables);
    char path[4096];
    if (!file_path(ctx, &h, path, sizeof path)) {
        fprintf(stderr, "nscatter: table files: the folder's name is too long; not kept\n");
        return;
    }
    ns_file_part parts[3] = {{&h, sizeof h}};
    for (uint32_t t = 0; t < h.tables; t++)
        parts[1 + t] = (ns_file_part){tables[t], NS_TABLE_CELLS * sizeof(float)};
    ns_error err = {0};
    int status = ns_make_dirs(ctx->table_node_dir, "table files", &err);
    if (!status)
        status = ns_write_file_atomic_parts(path, parts, 1 + h.tables, &err);
    if (status) /* the render still gets its table; only the next process pays again */
        fprintf(stderr, "nscatter: %s\n", err.message);
    else
        prune_table_files(ctx);
}

/* Node `node` of key's g and accumulation from the folder into the cache: 1 when read. */
static int load_node(ns_context *ctx, const ns_table_key *key, uint32_t node, ns_table_stats *stats)
{
    cache_entry e;
    ns_error err = {0};
    if (alloc_node_entry(&e, key, node, &err))
        return 0;
    table_file_header want = node_header(ctx, key, node);
    if (!read_table_file(ctx, &want, e.j)) {
        free(e.j[0]);
        free(e.j[1]);
        return 0;
    }
    e.counted = ctx->run.serial;
    if (!insert(ctx->tables, &e)) {
        free(e.j[0]);
        free(e.j[1]);
        return 0;
    }
    stats->tables_reused++;
    return 1;
}

static void save_node(ns_context *ctx, const ns_table_key *key, const cache_entry *e)
{
    write_table_file(ctx, node_header(ctx, key, e->node), e->j);
}

/* Makes the n (<= 3) nodes of key's g and accumulation listed in node[], one per channel of
 * one reconstruction and of one accumulation per order, and caches them. */
static int build_nodes(ns_context *ctx, const ns_table_key *key, const uint32_t *node, uint32_t n,
                       ns_table_stats *stats, ns_error *err)
{
    const ns_nn_header *h = &ctx->nn->nets[0].h;
    size_t cells = NS_TABLE_CELLS;
    cache_entry e[NODES_PER_BATCH];
    uint32_t made = 0;
    int status = NS_OK;
    for (; made < n && !status; made++) {
        status = alloc_node_entry(&e[made], key, node[made], err);
        if (status)
            break;
    }
    float *j = status ? NULL : calloc(2 * 3 * cells, sizeof(float));
    if (!status && !j)
        status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "tables: out of memory for J");
    double albedo[3];
    for (uint32_t c = 0; c < 3; c++)
        albedo[c] = node_albedo(h, node[c < n ? c : 0]);
    if (!status) {
        ns_stage stage = ns_stage_begin(ctx, "reconstruct", 0.0, 0.3);
        status = network_tables(ctx, key->g, albedo, n, j, err);
        stats->reconstruct_ms += ns_stage_end(ctx, &stage);
        stats->reconstructed = 1;
    }
    if (!status) /* only the channels computed are defined: the others walk zeros */
        for (int o = 0; o < 2; o++)
            memset(j + ((size_t)o * 3 + n) * cells, 0, (3 - n) * cells * sizeof(float));
    for (int o = 0; o < 2 && !status; o++) {
        ns_scatter_tables a;
        ns_stage stage = ns_stage_begin(ctx, "accumulate", 0.3 + 0.35 * o, 0.65 + 0.35 * o);
        status = ns_tables_accumulate_for_host(ctx, j + (size_t)o * 3 * cells, key->accumulation, &a,
                                               NULL, err);
        stats->accumulate_ms += ns_stage_end(ctx, &stage);
        stats->accumulated = 1;
        if (status)
            break;
        const float *src = a.a.mapped;
        for (uint32_t c = 0; c < n; c++) {
            float scale = (float)(1.0 / ns_nn_exact_energy(o, albedo[c]));
            for (size_t i = 0; i < cells; i++)
                e[c].j[o][i] = src[c * cells + i] * scale;
        }
        ns_scatter_tables_free(ctx, &a);
    }
    free(j);
    /* Made whole, they are kept; but a run asked to stop since the last walk does not wait
     * for the files (hashing and writing 21 MB each): the next process makes them again. */
    const int *stop = ctx->dev.cancel;
    int save = ctx->table_node_dir && !(stop && __atomic_load_n(stop, __ATOMIC_ACQUIRE));
    for (uint32_t c = 0; c < made; c++) {
        if (status) {
            free(e[c].j[0]);
            free(e[c].j[1]);
            continue;
        }
        if (save)
            save_node(ctx, key, &e[c]);
        status = insert_j_entry(ctx, &e[c], stats, err);
    }
    return status;
}

/* Where the host builds a table's A (float [3][cells] in `a`): a's own mapping where it is
 * host-cached (lavapipe), else host memory, written into a once by table_work_end. A discrete
 * GPU's device memory is mapped uncached: a loop that reads what it wrote there (a sum)
 * crawls. NULL out of memory. */
static float *table_work_begin(const gpu_buffer *a, float **scratch)
{
    *scratch = a->host_cached ? NULL : malloc(a->size);
    return a->host_cached ? a->mapped : *scratch;
}

static void table_work_end(gpu_buffer *a, float *scratch)
{
    if (scratch)
        memcpy(a->mapped, scratch, a->size);
    free(scratch);
}

/* One order's part of a channel's blend: dst = (or +=, with add) the cubic of its four nodes,
 * clamped at 0 with clamp (the cubic may undershoot where A is ~0). The sum runs in the same
 * order for one order or two. */
static void blend_order(float *restrict dst, const float *const node[4], const float coef[4],
                        int add, int clamp)
{
    for (size_t i = 0; i < NS_TABLE_CELLS; i++) {
        float v = add ? dst[i] : 0.0f;
        v = (add ? v + coef[0] * node[0][i] : coef[0] * node[0][i]) + coef[1] * node[1][i] +
            coef[2] * node[2][i] + coef[3] * node[3][i];
        dst[i] = clamp && !(v > 0.0f) ? 0.0f : v;
    }
}

/* A of key (float [3][cells]) into *out, from its channels' nodes, made first where the
 * cache lacks them. */
static int interpolate_table(ns_context *ctx, const ns_table_key *key, ns_scatter_tables *out,
                             ns_table_stats *stats, ns_error *err)
{
    struct ns_nn_state *nn = ctx->nn;
    if (!nn->nets_ok)
        return ns_fail(err, NS_ERR_NOT_AVAILABLE, "method nn: %s", nn->nets_error.message);
    const ns_nn_header *h = &nn->nets[0].h;
    struct ns_table_cache *cache = ctx->tables;
    uint32_t first[3] = {0}, missing[12], n_missing = 0;
    double w[3][4] = {{0}};
    for (int c = 0; c < 3; c++) {
        if (key->albedo[c] == 0.0f)
            continue; /* J is 0 exactly (ensure_j) */
        first[c] = node_stencil(h, key->albedo[c], w[c]);
        for (uint32_t i = first[c]; i < first[c] + 4; i++) {
            int listed = 0;
            for (uint32_t k = 0; k < n_missing; k++)
                listed |= missing[k] == i;
            cache_entry *e = listed ? NULL : find_node(cache, key->g, key->accumulation, i);
            if (e)
                count_reused(ctx, e, stats);
            else if (!listed)
                missing[n_missing++] = i;
        }
    }
    int status = NS_OK;
    if (ctx->table_node_dir && n_missing) {
        ns_stage stage = ns_stage_begin(ctx, "accumulate", 0.0, 0.0);
        for (uint32_t k = 0; k < n_missing; k++)
            if (load_node(ctx, key, missing[k], stats))
                missing[k--] = missing[--n_missing];
        stats->accumulate_ms += ns_stage_end(ctx, &stage);
        stats->accumulated = 1;
    }
    uint32_t batches = (n_missing + NODES_PER_BATCH - 1) / NODES_PER_BATCH;
    for (uint32_t b = 0; b < batches && !status; b++) {
        uint32_t done = NODES_PER_BATCH * b;
        uint32_t n = n_missing - done < NODES_PER_BATCH ? n_missing - done : NODES_PER_BATCH;
        ns_span span = ns_progress_push(ctx, (double)b / batches, (double)(b + 1) / batches);
        status = ns_run_check(ctx, err);
        if (!status)
            status = build_nodes(ctx, key, missing + done, n, stats, err);
        ns_progress_pop(ctx, span);
    }
    if (status)
        return status;

    size_t cells = NS_TABLE_CELLS;
    uint64_t table_bytes = 3ull * cells * sizeof(float);
    ns_stage stage = ns_stage_begin(ctx, "accumulate", 1.0, 1.0);
    status = gpu_buffer_create(&ctx->dev, &out->a,
                               &(gpu_buffer_desc){.size = table_bytes, .label = "ns.tables.a"}, err);
    /* The blend reads what it wrote (the second order adds to the first). */
    float *scratch = NULL, *dst = status ? NULL : table_work_begin(&out->a, &scratch);
    if (!status && !dst)
        status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "tables: out of memory for a blend");
    for (int c = 0; c < 3 && !status; c++) {
        float *channel = dst + c * cells;
        if (key->albedo[c] == 0.0f) {
            memset(channel, 0, cells * sizeof(float));
            continue;
        }
        /* Only the orders the key asks for (a walk's shifted key often has one), their node
         * pointers taken now: making nodes above may have moved the entries. */
        int want[2] = {(key->orders & NS_COMPONENT_DOUBLE) != 0,
                       (key->orders & NS_COMPONENT_MULTIPLE) != 0};
        for (int o = 0; o < 2 && !status; o++) {
            if (!want[o])
                continue;
            const float *node[4];
            float coef[4];
            double energy = ns_nn_exact_energy(o, key->albedo[c]);
            for (uint32_t k = 0; k < 4 && !status; k++) {
                cache_entry *e = find_node(cache, key->g, key->accumulation, first[c] + k);
                if (!e) {
                    status = ns_fail(err, NS_ERR_INTERNAL, "tables: albedo node %u vanished",
                                     first[c] + k);
                    break;
                }
                touch(cache, e);
                node[k] = e->j[o];
                coef[k] = (float)(energy * w[c][k]);
            }
            if (!status)
                blend_order(channel, node, coef, o == 1 && want[0], o == 1 || !want[1]);
        }
    }
    if (status)
        free(scratch);
    else
        table_work_end(&out->a, scratch);
    stats->accumulate_ms += ns_stage_end(ctx, &stage);
    stats->accumulated = 1;
    if (status) {
        gpu_buffer_destroy(&ctx->dev, &out->a);
        return status;
    }
    set_default_grid(out, table_bytes);
    return NS_OK;
}

/* The key that the render running will also ask for (ns_tables_expect_orders): key with
 * another of the announced order sets, not cached yet; 0 when there is none. Exact tables
 * only: an interpolated one is a blend, with no walk to share. The sets are the render's,
 * not each material's: a material none of whose boundary sources reach a camera segment
 * still gets its companion (rare; a walk of about 0.8 more). */
static int companion_key(ns_context *ctx, const ns_table_key *key, ns_table_key *companion)
{
    const struct ns_table_cache *cache = ctx->tables;
    if (key->tables != NS_TABLES_EXACT || cache->orders_expected_serial != ctx->run.serial + 1)
        return 0;
    for (uint32_t i = 0; i < cache->orders_expected_count; i++) {
        *companion = *key;
        companion->orders = cache->orders_expected[i];
        if (companion->orders != key->orders && !find_a(ctx->tables, companion))
            return 1;
    }
    return 0;
}

/* A host-cached view of a table's first `bytes`: its own mapping where that is host-cached
 * (lavapipe), else a copy made on the device into *staging (a host_reads buffer, destroyed by
 * the caller; zeroed when there is none). */
static int host_readable(ns_context *ctx, const gpu_buffer *table, uint64_t bytes,
                         gpu_buffer *staging, const float **out, ns_error *err)
{
    *staging = (gpu_buffer){0};
    if (table->host_cached) {
        *out = table->mapped;
        return NS_OK;
    }
    int status = gpu_buffer_create(&ctx->dev, staging,
                                   &(gpu_buffer_desc){.size = bytes, .uninitialized = 1, .host_reads = 1,
                                                      .label = "ns.tables.staging"},
                                   err);
    if (!status)
        status = gpu_copy_buffer(&ctx->dev, table, staging, bytes, err);
    if (status) {
        gpu_buffer_destroy(&ctx->dev, staging);
        return status;
    }
    *out = staging->mapped;
    return NS_OK;
}

int ns_scatter_tables_read(ns_context *ctx, const ns_scatter_tables *t, float *out, ns_error *err)
{
    uint64_t bytes = 3ull * NS_TABLE_CELLS * sizeof(float);
    if (t->a.size < bytes)
        return ns_fail(err, NS_ERR_INTERNAL, "tables: a table of %llu bytes, not %llu",
                       (unsigned long long)t->a.size, (unsigned long long)bytes);
    gpu_buffer staging;
    const float *host = NULL;
    int status = host_readable(ctx, &t->a, bytes, &staging, &host, err);
    if (!status)
        memcpy(out, host, bytes);
    gpu_buffer_destroy(&ctx->dev, &staging);
    return status;
}

/* A made now (e->a) into the cache, kept out of the live-buffer count and counted as made;
 * NULL out of memory, its buffer destroyed. Inserting may move the other entries. */
static cache_entry *insert_a(ns_context *ctx, cache_entry *e, ns_table_stats *stats)
{
    e->bytes = e->a.bytes;
    keep_buffer(&ctx->dev);
    cache_entry *slot = insert(ctx->tables, e);
    if (slot)
        count_made(ctx, slot, stats);
    else
        destroy_kept_buffer(&ctx->dev, &e->a.a);
    return slot;
}

/* Whether node i of key's g and accumulation is in the cache or in the table folder (a file
 * of its name: read_table_file checks it when it is read, and makes it again if it fails). */
static int node_exists(ns_context *ctx, const ns_table_key *key, uint32_t i)
{
    if (find_node(ctx->tables, key->g, key->accumulation, i))
        return 1;
    char path[4096];
    table_file_header want = node_header(ctx, key, i);
    struct stat st;
    return ctx->table_node_dir && file_path(ctx, &want, path, sizeof path) && stat(path, &st) == 0;
}

/* Whether every node a blend of key's albedos needs exists. */
static int nodes_available(ns_context *ctx, const ns_table_key *key)
{
    if (!ctx->nn->nets_ok)
        return 0;
    const ns_nn_header *h = &ctx->nn->nets[0].h;
    for (int c = 0; c < 3; c++) {
        if (key->albedo[c] == 0.0f)
            continue;
        double w[4];
        uint32_t first = node_stencil(h, key->albedo[c], w);
        for (uint32_t i = first; i < first + 4; i++)
            if (!node_exists(ctx, key, i))
                return 0;
    }
    return 1;
}

/* The materials at (g, accumulation) whose exact tables auto chose (the ring): how many, and
 * whether `albedo` (NULL: none) is one of them. With nodes non-NULL also the nodes their
 * blends read, nodes[0]..nodes[1] (nodes[0] > nodes[1]: none). */
static uint32_t auto_exact_materials(ns_context *ctx, float g, ns_accumulation accumulation,
                                     const float *albedo, int *listed, uint32_t nodes[2])
{
    const struct ns_table_cache *cache = ctx->tables;
    uint32_t count = 0;
    *listed = 0;
    if (nodes) {
        nodes[0] = ALBEDO_NODE_INTERVALS;
        nodes[1] = 0;
    }
    for (uint32_t i = 0; i < AUTO_EXACT_KEPT; i++) {
        const struct auto_exact *e = &cache->auto_exact[i];
        if (!e->used || e->g != g || e->accumulation != accumulation)
            continue;
        count++;
        *listed |= albedo && memcmp(e->albedo, albedo, sizeof e->albedo) == 0;
        for (int c = 0; nodes && c < 3; c++) {
            if (e->albedo[c] == 0.0f)
                continue;
            double w[4];
            uint32_t first = node_stencil(&ctx->nn->nets[0].h, e->albedo[c], w);
            nodes[0] = first < nodes[0] ? first : nodes[0];
            nodes[1] = first + 3 > nodes[1] ? first + 3 : nodes[1];
        }
    }
    return count;
}

/* render.tables "auto" for one key (docs/rendering.md, *Interpolated tables*): exact where
 * its exact table is cached; interpolated where its blend is, or the nodes it needs exist, or
 * exact tables were made at its g for AUTO_EXACT_BEFORE_NODES other albedos already; else
 * exact, remembered. Making a g's nodes costs about four materials' exact tables, after which
 * every albedo at that g costs tens of milliseconds: renting (exact) until the rent paid
 * equals the price (the nodes) and then buying never costs more than twice the better of
 * the two choices made knowing how many albedos will come (the ski-rental rule), and a
 * material tried at a few albedos is never made to pay for nodes. A material whose exact
 * tables were chosen keeps that answer for every key it asks for later, whatever nodes have
 * been made since. */
static ns_tables_mode auto_mode(ns_context *ctx, const ns_table_key *key)
{
    struct ns_table_cache *cache = ctx->tables;
    ns_table_key exact = *key, blended = *key;
    exact.tables = NS_TABLES_EXACT;
    blended.tables = NS_TABLES_INTERPOLATED;
    if (key->source != NS_METHOD_NN || find_a(cache, &exact))
        return NS_TABLES_EXACT;
    if (find_a(cache, &blended))
        return NS_TABLES_INTERPOLATED;
    /* A material whose exact tables were chosen stays exact for every key it asks for later
     * (other orders, a correction first gathered in a later round), nodes or not. The ring
     * holds each material once. */
    int listed;
    uint32_t others = auto_exact_materials(ctx, key->g, key->accumulation, key->albedo, &listed, NULL);
    if (listed)
        return NS_TABLES_EXACT;
    if (others >= AUTO_EXACT_BEFORE_NODES || nodes_available(ctx, key))
        return NS_TABLES_INTERPOLATED;
    struct auto_exact *slot = &cache->auto_exact[cache->auto_exact_next++ % AUTO_EXACT_KEPT];
    *slot = (struct auto_exact){.g = key->g, .accumulation = key->accumulation, .used = 1};
    memcpy(slot->albedo, key->albedo, sizeof slot->albedo);
    return NS_TABLES_EXACT;
}

/* The nodes ns_context_idle_work makes next, into missing (at most NS_TABLE_ALBEDO_NODES),
 * and the key they belong to: for the (g, accumulation) of the material auto chose exact
 * tables for most recently, among those with IDLE_NODES_AFTER or more such materials and a
 * node still to make, the nodes from the lowest that their albedos' blends read to the
 * highest, then one below and one above. */
static uint32_t idle_missing_nodes(ns_context *ctx, ns_table_key *key, uint32_t *missing)
{
    struct ns_table_cache *cache = ctx->tables;
    /* Newest first (the counter's wrap keeps the ring's order: 2^32 is a multiple of its
     * size). */
    for (uint32_t back = 1; back <= AUTO_EXACT_KEPT; back++) {
        const struct auto_exact *e = &cache->auto_exact[(cache->auto_exact_next - back) % AUTO_EXACT_KEPT];
        if (!e->used)
            continue;
        int listed;
        uint32_t nodes[2];
        uint32_t materials = auto_exact_materials(ctx, e->g, e->accumulation, NULL, &listed, nodes);
        uint32_t lo = nodes[0], hi = nodes[1];
        if (materials < IDLE_NODES_AFTER || lo > hi)
            continue;
        *key = (ns_table_key){.source = NS_METHOD_NN,
                              .g = e->g,
                              .accumulation = e->accumulation,
                              .tables = NS_TABLES_INTERPOLATED};
        /* The nodes the blends read first (an albedo between those explored is the likeliest
         * next), then the one on each side. */
        uint32_t n = 0;
        for (uint32_t i = lo; i <= hi; i++)
            if (!node_exists(ctx, key, i))
                missing[n++] = i;
        if (lo > 0 && !node_exists(ctx, key, lo - 1))
            missing[n++] = lo - 1;
        if (hi < ALBEDO_NODE_INTERVALS && !node_exists(ctx, key, hi + 1))
            missing[n++] = hi + 1;
        if (n)
            return n;
    }
    return 0;
}

int ns_context_idle_work(ns_context *ctx, const int *cancel, uint32_t *made, ns_error *err)
{
    if (made)
        *made = 0;
    if (!ctx || !made)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "ns_context_idle_work: %s is NULL",
                       ctx ? "made" : "the context");
    if (!ctx->nn->nets_ok)
        return NS_OK; /* auto chose no nodes, and needs none */
    pthread_mutex_lock(&ctx->lock);
    ns_table_key key;
    uint32_t missing[NS_TABLE_ALBEDO_NODES];
    uint32_t n = idle_missing_nodes(ctx, &key, missing);
    int status = NS_OK;
    n = n < NODES_PER_BATCH ? n : NODES_PER_BATCH;
    /* Work nobody asked for never displaces tables someone did from the cache (the folder
     * bounds its files like any others): without room for the batch
     * in the cache, nothing (the caller stops asking until its next render). */
    if (n && ctx->tables->bytes + n * j_entry_bytes > ctx->table_cache_bytes)
        n = 0;
    if (n) {
        ns_render_control control = {.cancel = cancel};
        ns_run_begin(ctx, &control, 0);
        ctx->run.preemptible = 1;
        ns_table_stats stats = {0};
        status = ns_run_check(ctx, err);
        if (!status)
            status = build_nodes(ctx, &key, missing, n, &stats, err);
        status = ns_run_end(ctx, status, err);
        if (!status)
            *made = n;
    }
    pthread_mutex_unlock(&ctx->lock);
    return status;
}

int ns_tables_get(ns_context *ctx, const ns_table_key *key, const ns_scatter_tables **out,
                  ns_table_stats *stats, ns_error *err)
{
    ns_table_stats local;
    if (!stats)
        stats = &local;
    memset(stats, 0, sizeof *stats);
    *out = NULL;
    int status = check_key(key, err);
    if (status)
        return status;
    ns_table_key resolved = *key;
    if (key->tables == NS_TABLES_AUTO) {
        resolved.tables = auto_mode(ctx, key);
        key = &resolved;
    }
    struct ns_table_cache *cache = ctx->tables;
    stats->weights_bytes = weights_bytes(key);
    cache_entry *hit = find_a(cache, key);
    if (hit) {
        touch(cache, hit);
        stats->cache_hit = 1;
        count_reused(ctx, hit, stats);
        count_blended(ctx, hit, 0, stats);
        *out = &hit->a;
        return NS_OK;
    }
    cache_entry e = {.kind = ENTRY_A, .key = *key};
    cache_entry second = {.kind = ENTRY_A};
    float *j = NULL, *second_j = NULL;
    if (key->tables == NS_TABLES_INTERPOLATED) {
        status = interpolate_table(ctx, key, &e.a, stats, err);
        e.key.reach_bins = NS_TABLE_NRHO; /* a blend fills every cell */
    } else {
        int paired = companion_key(ctx, key, &second.key);
        status = ensure_j(ctx, key, stats, err);
        if (!status)
            status = sum_orders(ctx, key, &j, err);
        if (!status && paired)
            status = sum_orders(ctx, &second.key, &second_j, err);
        if (!status) {
            ns_stage stage = ns_stage_begin(ctx, "accumulate", 0.5, 1.0);
            /* The companion's A on the same walk (accumulate_shared.h, the second three). */
            status = ns_tables_accumulate_parts(ctx, j, second_j, key->accumulation,
                                                key_reach(key), &e.a, paired ? &second.a : NULL,
                                                NULL, err);
            stats->accumulate_ms = ns_stage_end(ctx, &stage);
            stats->accumulated = 1;
        }
    }
    free(j);
    free(second_j);
    /* The companion first: inserting may move the entries, and the key's own slot is the
     * one returned. Out of memory for it only costs its walk again later. */
    if (!status && second.a.a.buffer)
        insert_a(ctx, &second, stats);
    else
        ns_scatter_tables_free(ctx, &second.a);
    if (status) {
        /* J made before the failure stays cached; keep the bound anyway. */
        while (cache->bytes > ctx->table_cache_bytes && cache->count)
            remove_entry(ctx, cache, lru_index(cache));
        return status;
    }
    cache_entry *slot = insert_a(ctx, &e, stats);
    if (!slot)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "tables: out of memory for the cache");
    slot = evict(ctx, cache, slot);
    count_blended(ctx, slot, 1, stats);
    *out = &slot->a;
    return NS_OK;
}

/* ---------------------------------------------------------------------------------------
 * Context hooks
 * ------------------------------------------------------------------------------------- */
static int load_networks(struct ns_nn_state *nn)
{
    for (uint32_t o = 0; o < 2; o++)
        if (ns_nn_weights_builtin(o, &nn->nets[o], &nn->nets_error))
            return 0;
    return 1;
}

int ns_tables_init(ns_context *ctx, ns_error *err)
{
    ctx->tables = calloc(1, sizeof *ctx->tables);
    ctx->nn = calloc(1, sizeof *ctx->nn);
    if (!ctx->tables || !ctx->nn)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "context: out of memory");
    ctx->nn->nets_ok = load_networks(ctx->nn);
    prune_table_files(ctx); /* a bound smaller than before applies at once */
    /* Created and compiled now even without weights: lavapipe compiles at the first
     * dispatch (seconds for this unrolled shader), which must never land in a request. */
    int status = ns_nn_gpu_create(&ctx->dev, &ctx->nn->gpu, err);
    if (!status) {
        keep_buffer(&ctx->dev); /* params */
        keep_buffer(&ctx->dev); /* dummy */
    }
    return status;
}

void ns_tables_destroy(ns_context *ctx)
{
    if (ctx->tables) {
        while (ctx->tables->count)
            remove_entry(ctx, ctx->tables, ctx->tables->count - 1);
        free(ctx->tables->entries);
        free(ctx->tables);
        ctx->tables = NULL;
    }
    if (ctx->nn) {
        if (ctx->nn->gpu.created) {
            __atomic_add_fetch(&ctx->dev.live_buffers, 2, __ATOMIC_SEQ_CST);
            ns_nn_gpu_destroy(&ctx->dev, &ctx->nn->gpu);
        }
        free(ctx->nn->unit_double);
        free(ctx->nn);
        ctx->nn = NULL;
    }
}
