/* gather_cpu.c — the tests' oracle of the gather (render/gather.c, shaders/gather.comp):
 * the shader's arithmetic on the CPU, in the same order, in float, walking the same nodes in
 * the same dispatch ranges (ns_gather_nodes_build and ns_gather_ranges of the render
 * library). It lives with the tests because only they use it: the library keeps the GPU path
 * alone. Keep it in step with gather.glsl line by line; gpu_gather compares the two. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gather_cpu.h"

static float dot3(const float *a, const float *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
static float clampf(float v, float lo, float hi) { return v < lo ? lo : v > hi ? hi : v; }

/* gather.glsl's theta_row: the lower of the two theta rows around w seen from axis d and the
 * weight of the upper one, linear in theta between the bins' centres (theta - theta_i from
 * its sine and a series for asin), held beyond the first and last. */
static uint32_t theta_row(const float *w, const float *d, float *t)
{
    const float bins_per_radian = (float)NS_TABLE_NTHETA / 3.14159265358979f;
    float cos_theta = clampf(dot3(w, d), -1.0f, 1.0f);
    float f = acosf(cos_theta) * bins_per_radian - 0.5f;
    uint32_t i = (uint32_t)fmaxf(f, 0.0f);
    if (i > NS_TABLE_NTHETA - 2)
        i = NS_TABLE_NTHETA - 2;
    float theta_i = ((float)i + 0.5f) / bins_per_radian;
    float sin_theta = sqrtf(fmaxf(1.0f - cos_theta * cos_theta, 0.0f));
    float x = sin_theta * cosf(theta_i) - cos_theta * sinf(theta_i), x2 = x * x;
    float past_i = x * (1.0f + x2 * (1.0f / 6.0f + x2 * (3.0f / 40.0f + x2 * (5.0f / 112.0f))));
    *t = clampf(past_i * bins_per_radian, 0.0f, 1.0f);
    return i * NS_TABLE_NPHI;
}

/* gather.glsl's phi_bin: nearest. */
static uint32_t phi_bin(const float *w, const float *d, const float *e_rho)
{
    const float bins_per_radian = (float)NS_TABLE_NTHETA / 3.14159265358979f;
    float cos_theta = clampf(dot3(w, d), -1.0f, 1.0f);
    float w_perp[3] = {w[0] - cos_theta * d[0], w[1] - cos_theta * d[1], w[2] - cos_theta * d[2]};
    float perp = sqrtf(dot3(w_perp, w_perp));
    float cos_phi = perp > 1e-6f ? clampf(dot3(w_perp, e_rho) / perp, -1.0f, 1.0f) : 1.0f;
    uint32_t ip = (uint32_t)(acosf(cos_phi) * bins_per_radian);
    return ip > NS_TABLE_NPHI - 1 ? NS_TABLE_NPHI - 1 : ip;
}

#define TABLE_DIRS (NS_TABLE_NTHETA * NS_TABLE_NPHI)
#define STEP_Z (NS_TABLE_NRHO * TABLE_DIRS)
#define STEP_RHO TABLE_DIRS
#define STEP_THETA NS_TABLE_NPHI

/* gather.glsl's table_at: A between the cells' centres in asinh(z), asinh(rho) and theta,
 * linear on the tetrahedron of Kuhn's triangulation that holds the point (the axes stepped in
 * decreasing order of their fractions, ties to z, then rho), phi at the nearest bin, 0
 * beyond the extent. */
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
    float tt;
    uint32_t row = theta_row(w, v->direction, &tt);
    uint32_t phi = phi_bin(w, v->direction, e_rho);
    float scale = p->table_map[0], inv_step = p->table_map[1], extent = p->table_map[2];
    const size_t all_steps = STEP_Z + STEP_RHO + STEP_THETA;
    for (int c = 0; c < 3; c++) {
        float s = p->sigma_t[c];
        float z_mfp = z * s, rho_mfp = rho * s;
        float fz = clampf(asinhf(z_mfp / scale) * inv_step + ((float)(NS_TABLE_NZ / 2) - 0.5f), 0.0f,
                          (float)(NS_TABLE_NZ - 1));
        float fr = clampf(asinhf(rho_mfp / scale) * inv_step - 0.5f, 0.0f, (float)(NS_TABLE_NRHO - 1));
        uint32_t iz = (uint32_t)fz, ir = (uint32_t)fr;
        iz = iz > NS_TABLE_NZ - 2 ? NS_TABLE_NZ - 2 : iz;
        ir = ir > NS_TABLE_NRHO - 2 ? NS_TABLE_NRHO - 2 : ir;
        float tz = fz - (float)iz, tr = fr - (float)ir;
        const float *cell = table + (size_t)c * NS_TABLE_CELLS + ((size_t)iz * NS_TABLE_NRHO + ir) * TABLE_DIRS +
                            row + phi;
        int z_rho = tz >= tr, z_theta = tz >= tt, rho_theta = tr >= tt;
        size_t first = z_rho && z_theta ? STEP_Z : !z_rho && rho_theta ? STEP_RHO : STEP_THETA;
        size_t last = z_theta && rho_theta ? STEP_THETA : z_rho && !rho_theta ? STEP_RHO : STEP_Z;
        float t_max = fmaxf(tz, fmaxf(tr, tt)), t_min = fminf(tz, fminf(tr, tt));
        float t_mid = tz + tr + tt - t_max - t_min;
        float value = (1.0f - t_max) * cell[0] + (t_max - t_mid) * cell[first] +
                      (t_mid - t_min) * cell[all_steps - last] + t_min * cell[all_steps];
        float inside = fmaxf(fabsf(z_mfp), rho_mfp) < extent ? 1.0f : 0.0f;
        a[c] = inside * value;
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
                       const ns_gather_nodes *tree, uint32_t first, uint32_t end, const float *table,
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
                               const ns_vrl_grid *grid, const ns_gather_nodes *tree, uint32_t first,
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

void ns_gather_cpu(const GpuGatherParams *params, const GpuSegment *segments,
                   uint32_t segment_count, const ns_vrl_grid *grid, const float *table,
                   uint32_t subgroup_size, float (*out)[4], ns_gather_counts *counts)
{
    ns_gather_counts local = {0};
    ns_gather_nodes tree;
    if (ns_gather_nodes_build(grid, &tree))
        abort(); /* tests only */
    /* The GPU's ranges under lavapipe's budget: the same nodes visited in the same order. */
    GpuGatherPush *push = calloc(tree.count + 1, sizeof *push);
    if (!push)
        abort();
    uint32_t ranges = ns_gather_ranges(&tree, 2 * NS_LAVAPIPE_LOOP_BUDGET, push);
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
    ns_gather_nodes_free(&tree);
    if (counts)
        *counts = local;
}
