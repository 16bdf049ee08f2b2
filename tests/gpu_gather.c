/* gpu_gather.c — the gather shader equals the CPU implementation of the same sum
 * (tests/oracles/gather_cpu.c ns_gather_cpu): random VRLs, random camera segments and a random
 * table, in the exact segment form and the paper's W form (each with endless and with bounded
 * beams: the beam past each VRL's length subtracted, the gather_bounded shader) and the dipole; and
 * a case large enough that lavapipe's loop limit splits the cells (and one oversized cell) across
 * dispatches, which must not change the result. The boundary sources' blurred first order
 * (gather_first.comp) equals a quadrature of its definition, evaluates every pair within the loop
 * budget, and is the same computed in the default form's walk as in a walk of its own added to it;
 * a beam that starts on a face, with the face's cosine, gives its line's whole first order to
 * the medium's side (its tube renormalised there), within 2%, and 6-13% less without it.
 * Validation layers on (NSCATTER_VALIDATION=1). */
#include "gpu_util.h"
#include "boundary.h"
#include "oracles/gather_cpu.h"

static uint32_t rng = 12345u;
static float uniform01(void)
{
    rng = rng * 1664525u + 1013904223u;
    return (float)(rng >> 8) * (1.0f / 16777216.0f);
}

static void random_unit(float v[3])
{
    float z = 2.0f * uniform01() - 1.0f, phi = 6.2831853f * uniform01();
    float r = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    set3(v, r * cosf(phi), r * sinf(phi), z);
}

/* smooth_table: a table that changes by a few percent from bin to bin, as real ones do.
 * With random values, a point that the GPU's asinh/acos put in the neighbouring bin of the
 * CPU's changes its term completely; with thousands of VRLs per segment such flips, not the
 * arithmetic, would set the difference. */
static int smooth_table;

static float *random_table(void)
{
    float *t = malloc(sizeof *t * 3 * (size_t)NS_TABLE_CELLS);
    for (size_t i = 0; i < 3 * (size_t)NS_TABLE_CELLS; i++) {
        t[i] = uniform01();
        if (smooth_table) {
            size_t cell = i % NS_TABLE_CELLS, dir = cell % (NS_TABLE_NTHETA * NS_TABLE_NPHI);
            size_t spatial = cell / (NS_TABLE_NTHETA * NS_TABLE_NPHI);
            double z = fabs((double)(spatial / NS_TABLE_NRHO) - NS_TABLE_NZ / 2.0);
            double rho = (double)(spatial % NS_TABLE_NRHO);
            t[i] = (float)((1 + i / NS_TABLE_CELLS) * (1 + 0.02 * dir) / (1 + 0.05 * (z + rho)));
        }
    }
    return t;
}

/* VRLs in a 2 x 2 box, spread over `cells` cells of consecutive VRLs (the last cell takes the
 * rest), with boxes and representatives as render/vrl_grid.c defines them. */
static void random_grid(ns_vrl_grid *g, uint32_t vrl_count, uint32_t cells)
{
    memset(g, 0, sizeof *g);
    g->vrls = calloc(vrl_count, sizeof *g->vrls);
    g->cells = calloc(cells, sizeof *g->cells);
    g->representatives = calloc(cells, sizeof *g->representatives);
    g->vrl_count = vrl_count;
    g->cell_count = cells;
    for (uint32_t i = 0; i < vrl_count; i++) {
        GpuVrl *v = &g->vrls[i];
        set3(v->origin, 2 * uniform01() - 1, 2 * uniform01() - 1, 2 * uniform01() - 1);
        random_unit(v->direction);
        set3(v->power, uniform01(), uniform01(), uniform01());
        v->length = 1.0f;
    }
    uint32_t per = vrl_count / cells;
    for (uint32_t c = 0; c < cells; c++) {
        GpuVrlCell *cell = &g->cells[c];
        cell->first = c * per;
        cell->count = c + 1 == cells ? vrl_count - c * per : per;
        set3(cell->bmin, 1e9, 1e9, 1e9);
        set3(cell->bmax, -1e9, -1e9, -1e9);
        GpuVrl *r = &g->representatives[c];
        float weight = 0;
        for (uint32_t k = cell->first; k < cell->first + cell->count; k++)
            for (int i = 0; i < 3; i++) {
                cell->bmin[i] = fminf(cell->bmin[i], g->vrls[k].origin[i]);
                cell->bmax[i] = fmaxf(cell->bmax[i], g->vrls[k].origin[i]);
                r->power[i] += g->vrls[k].power[i];
            }
        for (uint32_t k = cell->first; k < cell->first + cell->count; k++) {
            float w = (g->vrls[k].power[0] + g->vrls[k].power[1] + g->vrls[k].power[2]) / 3;
            weight += w;
            for (int i = 0; i < 3; i++) {
                r->origin[i] += w * g->vrls[k].origin[i];
                r->direction[i] += w * g->vrls[k].direction[i];
            }
        }
        float n = sqrtf(r->direction[0] * r->direction[0] + r->direction[1] * r->direction[1] +
                        r->direction[2] * r->direction[2]);
        for (int i = 0; i < 3; i++) {
            r->origin[i] /= weight;
            r->direction[i] /= n;
        }
    }
}

/* far_pattern 1: segments in alternate blocks of 64 (whole subgroups) lie 300 units away,
 * beyond the tables' reach (400 mfp / extinction 3 = 188 units); 2: every third segment
 * does, so that subgroups mix near and far segments. */
static uint32_t far_pattern;

static int is_far(uint32_t i)
{
    return far_pattern == 1 ? (i / 64) % 2 == 0 : far_pattern == 2 ? i % 3 == 0 : 0;
}

static GpuSegment *random_segments(uint32_t n)
{
    GpuSegment *s = calloc(n, sizeof *s);
    for (uint32_t i = 0; i < n; i++) {
        set3(s[i].entry, 2 * uniform01() - 1, 2 * uniform01() - 1, 2 * uniform01() - 1);
        if (is_far(i))
            s[i].entry[0] += 300.0f;
        float d[3];
        random_unit(d);
        float len = 0.05f + 1.5f * uniform01();
        for (int k = 0; k < 3; k++) {
            s[i].direction[k] = d[k];
            s[i].exit[k] = s[i].entry[k] + len * d[k];
        }
    }
    return s;
}

static GpuMaterial test_material(void)
{
    GpuMaterial m;
    memset(&m, 0, sizeof m);
    /* Extinctions 3, 5, 8 per unit: the 2-unit box spans 6 to 16 mfp, well inside 400. */
    set3(m.sigma_t, 3, 5, 8);
    m.sigma_t[3] = 1.3f;
    set3(m.sigma_s, 2.7f, 4.0f, 5.0f);
    m.sigma_s[3] = 0.4f;
    m.reflectance[3] = 1;
    return m;
}

static ns_scatter_tables table_geometry(void)
{
    ns_scatter_tables t;
    memset(&t, 0, sizeof t);
    t.scale = 0.5f;
    t.inv_step = (float)(NS_TABLE_NRHO / asinh(400.0 / 0.5));
    t.extent = 400.0f;
    return t;
}

/* Runs the GPU gather and the CPU one; returns the largest relative difference (relative to
 * the larger of the CPU value and floor_fraction of the mean, so that a segment whose
 * entry and exit terms nearly cancel cannot inflate it). */
/* The hierarchy render/vrl_grid.c builds over random VRLs (medium mfp 1/8 as test_material's
 * largest extinction): several levels and direction classes. */
static void hierarchy_grid(ns_vrl_grid *g, uint32_t vrl_count, uint32_t leaf_fill)
{
    ns_vrl_grid flat;
    random_grid(&flat, vrl_count, 1);
    ns_vrl_set set = {.vrls = flat.vrls, .count = vrl_count, .paths = vrl_count};
    ns_error err = {0};
    CHECK_INT(ns_vrl_grid_build(&set, 0, 1.0f / 8.0f, leaf_fill, g, &err), NS_OK);
    ns_vrl_grid_free(&flat);
}

/* Runs the GPU gather and the CPU one; returns the largest relative difference (relative to
 * the larger of the CPU value and floor_fraction of the mean, so that a segment whose
 * entry and exit terms nearly cancel cannot inflate it). cells 0: the real hierarchy
 * (hierarchy_grid) instead of cells of consecutive VRLs; solid_angle: the option's threshold
 * (render.cull_solid_angle). cpu_out (optional) receives the CPU sums. */
/* 1: the gather_bounded shader and the CPU's bounded sum (the beam past each VRL's length,
 * 1 here, subtracted); 0: endless beams, the default shader. */
/* A device buffer of `bytes`, holding `data` when it is not NULL. */
static int upload(gpu_buffer *b, const void *data, uint64_t bytes, const char *label, ns_error *err)
{
    return gpu_buffer_create(
        &test_context()->dev, b,
        &(gpu_buffer_desc){
            .size = bytes, .data = data, .data_size = data ? bytes : 0, .label = label},
        err);
}

static const uint64_t TABLE_BYTES = sizeof(float) * 3 * (uint64_t)NS_TABLE_CELLS;

static int bounded_beams;

static double compare_walk(uint32_t mode, uint32_t vrl_count, uint32_t cells, uint32_t segment_count,
                           double floor_fraction, float solid_angle, ns_gather_counts *gpu_counts,
                           float (*cpu_out)[4])
{
    ns_context *ctx = test_context();
    ns_error err = {0};
    float *table = mode == NS_GATHER_MODE_DIPOLE ? NULL : random_table();
    ns_vrl_grid grid;
    if (cells)
        random_grid(&grid, vrl_count, cells);
    else
        hierarchy_grid(&grid, vrl_count, solid_angle > 0 ? NS_VRL_LEAF_FILL_REPRESENTED : 0);
    GpuSegment *segments = random_segments(segment_count);
    GpuMaterial m = test_material();
    ns_scatter_tables tables = table_geometry();

    gpu_buffer seg_buf = {0}, out_buf = {0};
    int status =
        upload(&seg_buf, segments, sizeof *segments * segment_count, "test.segments", &err);
    if (!status)
        status = upload(&out_buf, NULL, 16ull * segment_count, "test.out", &err);
    if (table && !status)
        status = upload(&tables.a, table, TABLE_BYTES, "test.table", &err);
    ns_gather_desc desc = {.segments = &seg_buf,
                           .first_segment = 0,
                           .segment_count = segment_count,
                           .grid = &grid,
                           .table = table ? &tables.a : NULL,
                           .out = &out_buf};
    ns_gather_params(&desc.params, &m, mode, table ? &tables : NULL, solid_angle, bounded_beams);
    if (!status)
        status = ns_gather_run(ctx, &desc, gpu_counts, &err);
    if (status)
        fprintf(stderr, "gather: %s\n", err.message);
    CHECK(status == NS_OK);
    CHECK(gpu_validation_count(&ctx->dev) == 0);

    float(*cpu)[4] = calloc(segment_count, sizeof *cpu);
    ns_gather_counts cpu_counts;
    desc.params.counts[0] = segment_count;
    ns_gather_cpu(&desc.params, segments, segment_count, &grid, table, ctx->dev.subgroup_size, cpu, &cpu_counts);
    CHECK(cpu_counts.interactions == gpu_counts->interactions);
    CHECK(cpu_counts.cells_represented == gpu_counts->cells_represented);
    CHECK(cpu_counts.cells_culled == gpu_counts->cells_culled);
    if (cpu_out)
        memcpy(cpu_out, cpu, sizeof *cpu * segment_count);

    double mean = 0, worst = 0;
    for (uint32_t i = 0; i < segment_count; i++)
        for (int c = 0; c < 3; c++)
            mean += fabs(cpu[i][c]) / (3.0 * segment_count);
    CHECK(mean > 0);
    const float(*gpu)[4] = status ? cpu : out_buf.mapped;
    for (uint32_t i = 0; i < segment_count; i++)
        for (int c = 0; c < 3; c++) {
            double ref = fmax(fabs(cpu[i][c]), floor_fraction * mean);
            worst = fmax(worst, fabs(gpu[i][c] - cpu[i][c]) / ref);
            if (getenv("DBG") && fabs(gpu[i][c] - cpu[i][c]) / ref > 1e-4)
                printf("seg %u c %d gpu %g cpu %g len %g dir %g %g %g\n", i, c, gpu[i][c], cpu[i][c],
                       (double)segments[i].exit[0]-segments[i].entry[0], segments[i].direction[0], segments[i].direction[1], segments[i].direction[2]);
        }
    gpu_buffer_destroy(&ctx->dev, &seg_buf);
    gpu_buffer_destroy(&ctx->dev, &out_buf);
    gpu_buffer_destroy(&ctx->dev, &tables.a);
    free(cpu);
    free(segments);
    free(table);
    ns_vrl_grid_free(&grid);
    return worst;
}

static double compare(uint32_t mode, uint32_t vrl_count, uint32_t cells, uint32_t segment_count,
                      double floor_fraction, ns_gather_counts *gpu_counts)
{
    return compare_walk(mode, vrl_count, cells, segment_count, floor_fraction, 0.0f, gpu_counts, NULL);
}

static void test_exact_form_small(void)
{
    for (bounded_beams = 0; bounded_beams <= 1; bounded_beams++) {
        /* Bounded beams read twice the bins, in two frames: with random values a bin flip
         * between the GPU's and the CPU's asinh/acos would decide the sum (smooth_table). */
        smooth_table = bounded_beams;
        ns_gather_counts counts;
        double worst = compare(NS_GATHER_MODE_EXACT, 7, 3, 64, 1e-3, &counts);
        printf("exact form, %s beams, 7 VRLs x 64 segments: worst relative difference %.2e\n",
               bounded_beams ? "bounded" : "endless", worst);
        CHECK(worst <= 1e-4);
        CHECK(counts.interactions == 7u * 64u);
    }
    bounded_beams = smooth_table = 0;
}

static void test_paper_form_small(void)
{
    for (bounded_beams = 0; bounded_beams <= 1; bounded_beams++) {
        smooth_table = bounded_beams; /* as in test_exact_form_small */
        ns_gather_counts counts;
        double worst = compare(NS_GATHER_MODE_PAPER, 9, 2, 64, 1e-3, &counts);
        printf("paper W form, %s beams: worst relative difference %.2e\n",
               bounded_beams ? "bounded" : "endless", worst);
        CHECK(worst <= 1e-4);
    }
    bounded_beams = smooth_table = 0;
}

static void test_dipole(void)
{
    ns_gather_counts counts;
    double worst = compare(NS_GATHER_MODE_DIPOLE, 50, 5, 128, 1e-3, &counts);
    printf("dipole: worst relative difference %.2e\n", worst);
    CHECK(worst <= 1e-4);
}

/* One VRL at the origin along +z, gathered in the exact form through `table` along `count`
 * segments; the outputs into out (mapped). */
static int run_one_vrl(const float *table, const GpuSegment *segs, uint32_t count, gpu_buffer *out)
{
    ns_context *ctx = test_context();
    ns_error err = {0};
    ns_vrl_grid grid;
    random_grid(&grid, 1, 1);
    GpuVrl *v = &grid.vrls[0];
    set3(v->origin, 0, 0, 0);
    set3(v->direction, 0, 0, 1);
    set3(v->power, 1, 1, 1);
    grid.representatives[0] = *v;
    set3(grid.cells[0].bmin, 0, 0, 0);
    set3(grid.cells[0].bmax, 0, 0, 0);
    GpuMaterial m = test_material();
    ns_scatter_tables tables = table_geometry();
    gpu_buffer seg_buf = {0};
    int status = upload(&seg_buf, segs, sizeof *segs * count, "test.segments", &err);
    if (!status)
        status = upload(out, NULL, 16ull * count, "test.out", &err);
    if (!status)
        status = upload(&tables.a, table, TABLE_BYTES, "test.table", &err);
    ns_gather_desc desc = {
        .segments = &seg_buf, .segment_count = count, .grid = &grid, .table = &tables.a, .out = out};
    ns_gather_params(&desc.params, &m, NS_GATHER_MODE_EXACT, &tables, 0.0f, 0);
    ns_gather_counts counts;
    if (!status)
        status = ns_gather_run(ctx, &desc, &counts, &err);
    if (status)
        fprintf(stderr, "gather: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    CHECK(gpu_validation_count(&ctx->dev) == 0);
    gpu_buffer_destroy(&ctx->dev, &seg_buf);
    gpu_buffer_destroy(&ctx->dev, &tables.a);
    ns_vrl_grid_free(&grid);
    return status;
}

/* The theta read keeps a forward lobe's energy. The table's rows hold each theta bin's mean
 * over its solid angle; here the mean of an HG lobe (g 0.5, 0.8 and 0.9 in the three
 * channels), the same at every z, rho and phi, so that what the gather reads along a
 * segment is the theta read alone (times a factor that a table of ones gives). Over
 * segments whose directions cover the sphere evenly (stratified in cos theta), the mean of
 * that read is the lobe's energy as the gather sees it, against the bins' own. Read linearly
 * in theta between the bins' centres (each read is checked against that interpolation, done
 * here in double): +0.25%, +1.9%, +4.1%; linearly in cos theta (until
 * 2026-12-02): +0.75%, +5.6%, +12.4%, which showed as double scattering 6-9% high at g 0.9
 * (docs/scattering.md, *Theta read linearly in theta*). */
static void test_theta_read_keeps_lobe_energy(void)
{
    const double g[3] = {0.5, 0.8, 0.9}, bound[3] = {0.005, 0.025, 0.05};
    enum { COUNT = 4096 };
    float *lobe = malloc(TABLE_BYTES), *ones = malloc(TABLE_BYTES);
    double bin_mean[3][NS_TABLE_NTHETA], energy[3] = {0, 0, 0};
    for (int c = 0; c < 3; c++)
        for (int b = 0; b < NS_TABLE_NTHETA; b++) {
            /* HG's integral over cos theta: F(mu) = (1 - g^2) / (4 pi g sqrt(1 + g^2 - 2 g mu)) */
            double top = cos(b * M_PI / NS_TABLE_NTHETA), bottom = cos((b + 1) * M_PI / NS_TABLE_NTHETA);
            double k = (1 - g[c] * g[c]) / (4 * M_PI * g[c]);
            double integral = k / sqrt(1 + g[c] * g[c] - 2 * g[c] * top) -
                              k / sqrt(1 + g[c] * g[c] - 2 * g[c] * bottom);
            bin_mean[c][b] = integral / (top - bottom);
            energy[c] += integral / 2; /* the sphere's mean: half the integral over cos theta */
        }
    for (size_t i = 0; i < 3 * (size_t)NS_TABLE_CELLS; i++) {
        size_t cell = i % NS_TABLE_CELLS, c = i / NS_TABLE_CELLS;
        size_t theta = cell % (NS_TABLE_NTHETA * NS_TABLE_NPHI) / NS_TABLE_NPHI;
        lobe[i] = (float)bin_mean[c][theta];
        ones[i] = 1.0f;
    }
    GpuSegment *segs = calloc(COUNT, sizeof *segs);
    for (uint32_t k = 0; k < COUNT; k++) {
        double mu = 1 - 2 * (k + 0.5) / COUNT, phi = 2.399963 * k, r = sqrt(1 - mu * mu);
        float d[3] = {(float)(r * cos(phi)), (float)(r * sin(phi)), (float)mu};
        set3(segs[k].entry, 0.3f, -0.2f, 0.4f);
        for (int i = 0; i < 3; i++) {
            segs[k].direction[i] = d[i];
            segs[k].exit[i] = segs[k].entry[i] + 0.05f * d[i];
        }
    }
    gpu_buffer out_lobe = {0}, out_ones = {0};
    if (!run_one_vrl(lobe, segs, COUNT, &out_lobe) && !run_one_vrl(ones, segs, COUNT, &out_ones)) {
        const float(*a)[4] = out_lobe.mapped, (*one)[4] = out_ones.mapped;
        const double step = M_PI / NS_TABLE_NTHETA;
        for (int c = 0; c < 3; c++) {
            double sum = 0, worst = 0;
            int finite = 1;
            for (uint32_t k = 0; k < COUNT; k++) {
                finite &= one[k][c] > 0 && isfinite(a[k][c]);
                double read = a[k][c] / one[k][c];
                sum += read;
                /* Each read against the linear interpolation in theta between the bins'
                 * centres, in double (the light travels along -direction: theta from -z),
                 * held beyond the first and last centre. */
                double theta = acos(-(double)segs[k].direction[2]), f = theta / step - 0.5;
                int i = f <= 0 ? 0 : f >= NS_TABLE_NTHETA - 2 ? NS_TABLE_NTHETA - 2 : (int)f;
                double t = fmin(fmax(f - i, 0.0), 1.0);
                double want = (1 - t) * bin_mean[c][i] + t * bin_mean[c][i + 1];
                worst = fmax(worst, fabs(read - want) / want);
            }
            double ratio = sum / COUNT / energy[c];
            printf("theta read of an HG lobe, g %.1f: %.4f of its energy; each read within %.1e of "
                   "the linear interpolation in theta\n",
                   g[c], ratio, worst);
            CHECK(finite);
            CHECK_NEAR(ratio, 1.0, bound[c]);
            CHECK(worst < 1e-3);
        }
    }
    ns_context *ctx = test_context();
    gpu_buffer_destroy(&ctx->dev, &out_lobe);
    gpu_buffer_destroy(&ctx->dev, &out_ones);
    free(segs);
    free(lobe);
    free(ones);
}

/* 70,000 VRLs in 3 cells of 23,333: each dispatch on lavapipe is filled close to its loop
 * budget and the cells are spread over several dispatches; were the budget too generous,
 * lavapipe would cut invocations short and the sums would fall below the CPU's. The sum must
 * not change beyond float rounding (relative to the larger of the value and a tenth of the
 * mean). */
static void test_split_across_dispatches(void)
{
    ns_gather_counts counts;
    double worst = compare(NS_GATHER_MODE_EXACT, 70000, 3, 96, 0.1, &counts);
    printf("70000 VRLs: %u dispatches, worst relative difference %.2e\n", counts.dispatches, worst);
    /* Both sides add 70,000 float terms, in different groupings (one partial sum per
     * dispatch on the GPU): rounding alone may reach N * 2^-24 = 4e-3 relative. */
    CHECK(worst <= 70000 * ldexp(1.0, -24) * 1.5);
    CHECK(counts.interactions == 70000u * 96u);
    if (test_context()->dev.loop_limited)
        CHECK(counts.dispatches > 1);
}

/* The hierarchy walked exactly (no threshold): every VRL meets every segment (nothing lies
 * beyond the table's reach here), and the sum equals the flat sum over one cell of all the
 * VRLs on the CPU, whatever the tree's shape; the GPU walk equals the CPU walk. */
static void test_hierarchy_exact(void)
{
    enum { VRLS = 3000, SEGMENTS = 128 };
    ns_gather_counts counts;
    smooth_table = 1;
    static float tree_sum[SEGMENTS][4], flat_sum[SEGMENTS][4];
    uint32_t rng_before = rng;
    double worst = compare_walk(NS_GATHER_MODE_EXACT, VRLS, 0, SEGMENTS, 1e-3, 0.0f, &counts, tree_sum);
    printf("hierarchy, exact: worst relative difference GPU vs CPU %.2e\n", worst);
    /* 3000 float terms per segment, summed in the same order: rounding bounds it. */
    CHECK(worst <= VRLS * ldexp(1.0, -24) * 1.5);
    CHECK(counts.interactions == (uint64_t)VRLS * SEGMENTS);
    CHECK(counts.cells_represented == 0);
    /* Same random draws again: the same VRLs, segments and table, in one flat cell. */
    rng = rng_before;
    worst = compare_walk(NS_GATHER_MODE_EXACT, VRLS, 1, SEGMENTS, 1e-3, 0.0f, &counts, flat_sum);
    double flat_vs_tree = 0, mean = 0;
    for (int i = 0; i < SEGMENTS; i++)
        for (int c = 0; c < 3; c++)
            mean += fabs(flat_sum[i][c]) / (3.0 * SEGMENTS);
    for (int i = 0; i < SEGMENTS; i++)
        for (int c = 0; c < 3; c++)
            flat_vs_tree = fmax(flat_vs_tree, fabs(tree_sum[i][c] - flat_sum[i][c]) /
                                                   fmax(fabs(flat_sum[i][c]), 1e-3 * mean));
    printf("hierarchy, exact: tree walk vs flat sum %.2e\n", flat_vs_tree);
    CHECK(mean > 0);
    CHECK(flat_vs_tree <= VRLS * ldexp(1.0, -24) * 2);
    smooth_table = 0;
}

/* With the solid-angle option the walk replaces far nodes by their representatives: fewer
 * interactions, and the GPU still equals the CPU walk node for node (counts equal too). */
static void test_hierarchy_representatives(void)
{
    ns_gather_counts counts;
    smooth_table = 1;
    double worst = compare_walk(NS_GATHER_MODE_EXACT, 3000, 0, 128, 1e-3, 0.05f, &counts, NULL);
    smooth_table = 0;
    printf("hierarchy, solid angle 0.05: %llu interactions (%llu represented) of %u, worst "
           "relative difference GPU vs CPU %.2e\n",
           (unsigned long long)counts.interactions, (unsigned long long)counts.cells_represented,
           3000u * 128u, worst);
    CHECK(worst <= 3000 * ldexp(1.0, -24) * 1.5);
    CHECK(counts.cells_represented > 0);
    CHECK(counts.interactions < 3000u * 128u);
}

/* Culling: segments beyond every VRL's reach get nothing, whole subtrees go at once, and
 * the exact walk culls a node only when every segment of the subgroup is beyond it (the
 * CPU's counts, grouped by the device's subgroup size, equal the GPU's). */
static void test_hierarchy_culling(void)
{
    ns_gather_counts counts;
    static float sums[256][4];
    smooth_table = 1;
    for (far_pattern = 1; far_pattern <= 2; far_pattern++) {
        double worst = compare_walk(NS_GATHER_MODE_EXACT, 2000, 0, 256, 1e-3, 0.0f, &counts, sums);
        printf("culling, %s: %llu nodes culled, %llu interactions, worst difference %.2e\n",
               far_pattern == 1 ? "far subgroups" : "a third far, mixed", (unsigned long long)counts.cells_culled,
               (unsigned long long)counts.interactions, worst);
        double far_sum = 0;
        for (uint32_t i = 0; i < 256; i++)
            if (is_far(i))
                far_sum += fabs(sums[i][0]) + fabs(sums[i][1]) + fabs(sums[i][2]);
        CHECK(far_sum == 0.0);
        CHECK(worst <= 5e-4); /* 2000 terms: rounding, and bins a last bit apart */
        if (far_pattern == 1) {
            CHECK(counts.cells_culled > 0);
            CHECK(counts.interactions == 2000u * 128u); /* the near half only */
        }
    }
    far_pattern = 0;
    smooth_table = 0;
}

/* The standard deviation of source v's tube in a channel of extinction s (scene units):
 * NS_BOUNDARY_BLUR_MFP / s, narrowed to NS_FIRST_BLUR_PER_CHORD of a known chord (v's
 * length) down to NS_FIRST_BLUR_FLOOR of it (scatter_shared.h). */
static double tube_width(const GpuVrl *v, double s)
{
    double widest = NS_BOUNDARY_BLUR_MFP / s;
    if (!(v->length > 0))
        return widest;
    return fmin(widest, fmax(NS_FIRST_BLUR_FLOOR * widest, NS_FIRST_BLUR_PER_CHORD * v->length));
}

/* The definition of a source's blurred first order along a segment (render/boundary.h,
 * gather.glsl first_order), by quadrature in double: power x albedo x sigma_t x p_HG(cos
 * theta) x the integral over the segment of e^{-s t} e^{-s z} [z > 0] K(rho), K the
 * normalised Gaussian of standard deviation b across the line (tube_width, or `wide`: the
 * widest whatever the chord). */
static double first_order_by_quadrature(const GpuMaterial *m, int c, const GpuVrl *v,
                                        const GpuSegment *seg, int wide)
{
    double s = m->sigma_t[c], a = m->sigma_s[c] / s, g = m->sigma_s[3],
           b = wide ? NS_BOUNDARY_BLUR_MFP / s : tube_width(v, s);
    double len = 0, cos_theta = 0;
    for (int k = 0; k < 3; k++) {
        len += (seg->exit[k] - seg->entry[k]) * (seg->exit[k] - seg->entry[k]);
        cos_theta -= (double)seg->direction[k] * v->direction[k];
    }
    len = sqrt(len);
    /* The part of the segment where z > 0 (z = z0 - cos_theta t), so that the midpoints
     * never straddle the cut: a narrow tube's Gaussian cut there in mid-step read 1% off. */
    double z0 = 0, lo = 0, hi = len;
    for (int k = 0; k < 3; k++)
        z0 += ((double)seg->entry[k] - v->origin[k]) * v->direction[k];
    if (cos_theta < 0)
        lo = fmax(lo, z0 / cos_theta);
    else if (cos_theta > 0)
        hi = fmin(hi, z0 / cos_theta);
    else if (z0 <= 0)
        hi = lo;
    const int n = 20000;
    double sum = 0, step = (hi - lo) / n;
    for (int i = 0; i < n && hi > lo; i++) {
        double t = lo + (i + 0.5) * step, off[3], z = 0, r2 = 0;
        for (int k = 0; k < 3; k++) {
            off[k] = seg->entry[k] + t * seg->direction[k] - v->origin[k];
            z += off[k] * v->direction[k];
            r2 += off[k] * off[k];
        }
        r2 -= z * z;
        sum += exp(-s * (t + z) - r2 / (2 * b * b)) / (2 * M_PI * b * b) * step;
    }
    double phase = (1 - g * g) / (4 * M_PI * pow(1 + g * g - 2 * g * cos_theta, 1.5));
    return v->power[c] * a * s * phase * sum;
}

/* Runs the first-order form (gather_first.comp) of `grid` over `segs` into out (mapped);
 * returns the status. */
static int run_first_order(const GpuMaterial *m, const ns_vrl_grid *grid, const GpuSegment *segs,
                           uint32_t count, gpu_buffer *out, ns_gather_counts *counts)
{
    ns_context *ctx = test_context();
    ns_error err = {0};
    gpu_buffer seg_buf = {0};
    int status = upload(&seg_buf, segs, sizeof *segs * count, "test.segments", &err);
    if (!status)
        status = upload(out, NULL, 16ull * count, "test.out", &err);
    ns_gather_desc desc = {.segments = &seg_buf, .segment_count = count, .grid = grid, .out = out};
    ns_gather_params(&desc.params, m, NS_GATHER_MODE_FIRST, NULL, 0.0f, 0);
    if (!status)
        status = ns_gather_run(ctx, &desc, counts, &err);
    if (status)
        fprintf(stderr, "gather: %s\n", err.message);
    CHECK(gpu_validation_count(&ctx->dev) == 0);
    gpu_buffer_destroy(&ctx->dev, &seg_buf);
    return status;
}

/* A beam that starts on a plane face, at 70 degrees to its normal (a totally reflected beam
 * in glass): y > 0 is the medium, camera segments start on the face and run straight in, one
 * for every point of a fine grid on it. Their first order, summed over the grid (times its
 * cell's area), is the volume integral of e^{-s y} J_1 over the medium: for the beam's line
 * itself, power x albedo x p / (1 + cos beta) in every channel, whatever the extinction. The
 * tube around the line puts part of that beyond the face near the start (here 6-13%); with
 * the face's cosine in its events (scatter_shared.h, NS_VRL_FACE_COS_SHIFT) the tube is
 * taken as renormalised to the medium's side, which gives it back, within 2%.
 * docs/scattering.md, *The tube renormalised at its face*. */
static void test_first_order_at_a_face(void)
{
    GpuMaterial m = test_material();
    m.sigma_s[3] = 0.0f; /* isotropic: p = 1 / (4 pi) */
    const double beta = 70.0 * M_PI / 180.0, h = 0.005, depth = 12.0 / 3.0;
    /* The footprint of the line (to 12 mean free paths) and ~9 widest tubes around it. */
    const double x_lo = -0.3, x_hi = 12.0 / 3.0 * sin(beta) + 0.3, z_lo = -0.3, z_hi = 0.3;
    const uint32_t nx = (uint32_t)((x_hi - x_lo) / h), nz = (uint32_t)((z_hi - z_lo) / h);
    const uint32_t count = nx * nz;
    GpuSegment *segs = calloc(count, sizeof *segs);
    for (uint32_t i = 0; segs && i < count; i++) {
        set3(segs[i].entry, (float)(x_lo + (i % nx + 0.5) * h), 0.0f,
             (float)(z_lo + (i / nx + 0.5) * h));
        set3(segs[i].exit, segs[i].entry[0], (float)depth, segs[i].entry[2]);
        set3(segs[i].direction, 0, 1, 0);
    }
    /* The widest tube (no chord) and a chord's narrower one in two channels. */
    const float chords[2] = {0.0f, 0.5f};
    for (int chord = 0; segs && chord < 2; chord++) {
        double sums[2][3] = {{0}};
        for (int face = 0; face < 2; face++) {
            GpuVrl v = {.length = chords[chord]};
            set3(v.direction, (float)sin(beta), (float)cos(beta), 0);
            set3(v.power, 1, 1, 1);
            v.events = 1u | (face ? (uint32_t)lrint(cos(beta) * NS_VRL_FACE_COS_MAX) << NS_VRL_FACE_COS_SHIFT : 0u);
            GpuVrlCell cell = {.first = 0, .count = 1};
            ns_vrl_grid grid = {
                .vrls = &v, .vrl_count = 1, .cells = &cell, .cell_count = 1, .representatives = &v};
            gpu_buffer out = {0};
            ns_gather_counts counts;
            CHECK_INT(run_first_order(&m, &grid, segs, count, &out, &counts), NS_OK);
            const float(*value)[4] = out.mapped;
            for (uint32_t i = 0; value && i < count; i++)
                for (int c = 0; c < 3; c++)
                    sums[face][c] += value[i][c] * h * h;
            gpu_buffer_destroy(&test_context()->dev, &out);
        }
        double alone[3], with[3];
        for (int c = 0; c < 3; c++) {
            double line = (m.sigma_s[c] / m.sigma_t[c]) / (4 * M_PI) / (1 + cos(beta));
            alone[c] = sums[0][c] / line;
            with[c] = sums[1][c] / line;
            CHECK(fabs(with[c] - 1) < 0.02);
            CHECK(alone[c] < 0.95);
        }
        printf("first order at a face, chord %.1f: the tube as it is %.4f / %.4f / %.4f of the "
               "line's, renormalised to the medium's side %.4f / %.4f / %.4f\n",
               chords[chord], alone[0], alone[1], alone[2], with[0], with[1], with[2]);
    }
    free(segs);
}

/* Segments that pass within a few tubes' widths of a source's line (source i % sources, at
 * most miss[i % 4] away, NULL: 0.03), at angles from crossing to nearly parallel and
 * antiparallel, starting before or after the source's origin, a tenth of a mean free path
 * long to several. */
static GpuSegment *segments_near(const ns_vrl_grid *grid, uint32_t sources, uint32_t count,
                                 const float *miss_of)
{
    GpuSegment *segs = calloc(count, sizeof *segs);
    for (uint32_t i = 0; i < count; i++) {
        const GpuVrl *v = &grid->vrls[i % sources];
        float d[3], side[3], along = 0.4f * uniform01() - 0.05f;
        float miss = (miss_of ? miss_of[i % sources % 4] : 0.03f) * uniform01();
        random_unit(d);
        if (i % 4 == 1) {
            float sign = i % 8 == 1 ? 1.0f : -1.0f, tilt = powf(10.0f, -4.0f + 3.0f * uniform01());
            for (int k = 0; k < 3; k++)
                d[k] = sign * v->direction[k] + tilt * d[k];
            float n = sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            for (int k = 0; k < 3; k++)
                d[k] /= n;
        }
        random_unit(side);
        float len = 0.03f + 1.5f * uniform01(), back = len * uniform01();
        for (int k = 0; k < 3; k++) {
            segs[i].entry[k] =
                v->origin[k] + along * v->direction[k] + miss * side[k] - back * d[k];
            segs[i].exit[k] = segs[i].entry[k] + len * d[k];
            segs[i].direction[k] = d[k];
        }
    }
    return segs;
}

/* Random boundary sources (random_grid of that seed), their lengths (chords) chords[i % 4], or
 * all endless (0) where chords is NULL. */
static void source_grid(ns_vrl_grid *grid, uint32_t sources, uint32_t seed, const float *chords)
{
    random_grid(grid, sources, seed);
    for (uint32_t i = 0; i < sources; i++)
        grid->vrls[i].length = chords ? chords[i % 4] : 0.0f;
}

/* Chords of every class for test_material's extinctions 3, 5, 8: endless, as an expected
 * reflection is; long (the widest tube: 0.03 x 2 > 0.1 / 3); short (narrower in two
 * channels); very short (the floor in two). */
static const float every_chord[4] = {0.0f, 2.0f, 0.5f, 0.05f};

/* The first-order form against the quadrature of its definition, within 5e-3 of each value
 * (or of 1e-6 of the largest: the Gaussian's far tails), at g 0.9 (a narrow lobe, as the
 * oil's). Read from the composed table instead, the same sums came to a third of these.
 * Sources with a chord (a reflected beam's length) get narrower tubes: a long chord none, a
 * short one a fraction of its length, a very short one the floor; the tube of the widest
 * width around them would give other values (the test tells them apart). */
static void test_first_order(void)
{
    enum { SOURCES = 8, SEGMENTS = 128 };
    GpuMaterial m = test_material();
    m.sigma_s[3] = 0.9f;
    ns_vrl_grid grid;
    source_grid(&grid, SOURCES, 2, every_chord);
    /* Segments near the very short chord's tubes (0.0015-0.0033 wide) pass closer. */
    const float miss[4] = {0.03f, 0.03f, 0.03f, 0.005f};
    GpuSegment *segs = segments_near(&grid, SOURCES, SEGMENTS, miss);
    gpu_buffer out = {0};
    ns_gather_counts counts;
    int status = run_first_order(&m, &grid, segs, SEGMENTS, &out, &counts);
    CHECK_INT(status, NS_OK);
    if (!status) {
        const float(*gpu)[4] = out.mapped;
        double(*want)[3] = calloc(SEGMENTS, sizeof *want), largest = 0, worst = 0;
        double(*wide)[3] = calloc(SEGMENTS, sizeof *wide), worst_wide = 0;
        for (uint32_t i = 0; i < SEGMENTS; i++)
            for (int c = 0; c < 3; c++) {
                for (uint32_t k = 0; k < SOURCES; k++) {
                    want[i][c] += first_order_by_quadrature(&m, c, &grid.vrls[k], &segs[i], 0);
                    wide[i][c] += first_order_by_quadrature(&m, c, &grid.vrls[k], &segs[i], 1);
                }
                largest = fmax(largest, want[i][c]);
            }
        uint32_t lit = 0, lit_floor = 0;
        for (uint32_t i = 0; i < SEGMENTS; i++)
            for (int c = 0; c < 3; c++) {
                double floor = 1e-6 * largest;
                lit += want[i][c] > floor;
                lit_floor += i % SOURCES % 4 == 3 && want[i][c] > floor;
                worst = fmax(worst, fabs(gpu[i][c] - want[i][c]) / fmax(want[i][c], floor));
                worst_wide =
                    fmax(worst_wide, fabs(gpu[i][c] - wide[i][c]) / fmax(wide[i][c], floor));
            }
        printf("first order: %u of %u values above 1e-6 of the largest; worst relative difference "
               "%.2e (%.2e from the widest tubes' values)\n",
               lit, 3 * SEGMENTS, worst, worst_wide);
        CHECK(lit > SEGMENTS);
        CHECK(lit_floor > SEGMENTS / 8); /* of 3 x SEGMENTS / 4 near the floor's tubes */
        CHECK(worst < 5e-3);
        CHECK(worst_wide > 0.1);
        free(want);
        free(wide);
    }
    /* A channel without extinction (allowed: sigma_s = sigma_a = 0) scatters nothing: exactly
     * 0 there, the other channels as they were (its tube of width 0 once made NaN). */
    GpuMaterial clear = m;
    clear.sigma_t[2] = clear.sigma_s[2] = 0.0f;
    gpu_buffer clear_out = {0};
    CHECK_INT(run_first_order(&clear, &grid, segs, SEGMENTS, &clear_out, &counts), NS_OK);
    if (!status && clear_out.mapped) {
        const float(*a)[4] = out.mapped, (*b)[4] = clear_out.mapped;
        uint32_t wrong = 0;
        for (uint32_t i = 0; i < SEGMENTS; i++)
            wrong += !(b[i][2] == 0.0f && b[i][0] == a[i][0] && b[i][1] == a[i][1]);
        CHECK_INT(wrong, 0);
    }
    gpu_buffer_destroy(&test_context()->dev, &clear_out);
    gpu_buffer_destroy(&test_context()->dev, &out);
    free(segs);
    ns_vrl_grid_free(&grid);
}

/* 30,000 sources over 64 segments: every pair is evaluated although the dispatches are filled
 * to lavapipe's loop budget at NS_GATHER_ITERATIONS_PER_VRL per source. A loop inside the
 * form's evaluation (its erfc's continued fraction, its channels) spent more than that, and
 * lavapipe cut the invocations short: a tenth of the pairs were evaluated, silently. */
static void test_first_order_within_the_loop_budget(void)
{
    enum { SOURCES = 30000, SEGMENTS = 64 };
    GpuMaterial m = test_material();
    ns_vrl_grid grid;
    source_grid(&grid, SOURCES, 3, NULL);
    GpuSegment *segs = segments_near(&grid, SOURCES, SEGMENTS, NULL);
    gpu_buffer out = {0};
    ns_gather_counts counts;
    CHECK_INT(run_first_order(&m, &grid, segs, SEGMENTS, &out, &counts), NS_OK);
    printf("first order, %u sources: %u dispatches, %llu interactions\n", SOURCES,
           counts.dispatches, (unsigned long long)counts.interactions);
    CHECK(counts.interactions == (uint64_t)SOURCES * SEGMENTS);
    if (test_context()->dev.loop_limited)
        CHECK(counts.dispatches > 1);
    gpu_buffer_destroy(&test_context()->dev, &out);
    free(segs);
    ns_vrl_grid_free(&grid);
}

/* The default form with the first order in its walk (gather_exact_first.comp) equals the
 * default form's walk with the first order's own walk added to it (ns_gather_desc.add, the
 * path of the paper's accumulation), within float rounding, for sources of every chord: both
 * narrow the tube alike, and the table's part reads the sources as endless either way. */
static void test_first_order_in_the_default_walk(void)
{
    enum { SOURCES = 8, SEGMENTS = 128 };
    ns_context *ctx = test_context();
    ns_error err = {0};
    GpuMaterial m = test_material();
    ns_vrl_grid grid;
    source_grid(&grid, SOURCES, 2, every_chord);
    GpuSegment *segs = segments_near(&grid, SOURCES, SEGMENTS, NULL);
    smooth_table = 1;
    float *table = random_table();
    smooth_table = 0;
    /* Scaled so that the first order is a good part of the sum. */
    for (size_t i = 0; i < 3 * (size_t)NS_TABLE_CELLS; i++)
        table[i] *= 1e-4f;
    ns_scatter_tables tables = table_geometry();
    gpu_buffer seg_buf = {0}, two = {0}, one = {0};
    int status = upload(&seg_buf, segs, sizeof *segs * SEGMENTS, "test.segments", &err);
    if (!status)
        status = upload(&tables.a, table, TABLE_BYTES, "test.table", &err);
    for (int i = 0; i < 2 && !status; i++)
        status = upload(i ? &one : &two, NULL, 16ull * SEGMENTS, "test.out", &err);
    ns_gather_counts counts;
    ns_gather_desc desc = {.segments = &seg_buf,
                           .segment_count = SEGMENTS,
                           .grid = &grid,
                           .table = &tables.a,
                           .out = &two};
    /* Two walks: the table's, then the first order added. */
    ns_gather_params(&desc.params, &m, NS_GATHER_MODE_EXACT, &tables, 0.0f, 0);
    if (!status)
        status = ns_gather_run(ctx, &desc, &counts, &err);
    ns_gather_desc first = desc;
    first.table = NULL;
    first.add = 1;
    ns_gather_params(&first.params, &m, NS_GATHER_MODE_FIRST, NULL, 0.0f, 0);
    if (!status)
        status = ns_gather_run(ctx, &first, &counts, &err);
    /* One walk. */
    ns_gather_desc both = desc;
    both.out = &one;
    ns_gather_params_first(&both.params, &m);
    if (!status)
        status = ns_gather_run(ctx, &both, &counts, &err);
    if (status)
        fprintf(stderr, "gather: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    CHECK(gpu_validation_count(&ctx->dev) == 0);
    if (!status) {
        const float(*a)[4] = two.mapped, (*b)[4] = one.mapped;
        double mean = 0, worst = 0, first_part = 0;
        for (uint32_t i = 0; i < SEGMENTS; i++)
            for (int c = 0; c < 3; c++)
                mean += a[i][c] / (3.0 * SEGMENTS);
        for (uint32_t i = 0; i < SEGMENTS; i++)
            for (int c = 0; c < 3; c++)
                worst = fmax(worst, fabs(a[i][c] - b[i][c]) / fmax(fabs(a[i][c]), 1e-3 * mean));
        /* Both parts must weigh in, or the comparison says nothing about one of them. */
        ns_gather_desc alone = first;
        alone.add = 0;
        alone.out = &one;
        CHECK_INT(ns_gather_run(ctx, &alone, &counts, &err), NS_OK);
        for (uint32_t i = 0; i < SEGMENTS; i++)
            for (int c = 0; c < 3; c++)
                first_part += b[i][c] / (3.0 * SEGMENTS);
        printf("first order in the default walk: worst relative difference %.2e; the first order "
               "%.3g of the mean\n",
               worst, first_part / mean);
        CHECK(worst < 1e-5);
        CHECK(first_part > 0.05 * mean && first_part < 0.99 * mean); /* the table's part too */
    }
    gpu_buffer_destroy(&ctx->dev, &seg_buf);
    gpu_buffer_destroy(&ctx->dev, &tables.a);
    gpu_buffer_destroy(&ctx->dev, &two);
    gpu_buffer_destroy(&ctx->dev, &one);
    free(table);
    free(segs);
    ns_vrl_grid_free(&grid);
}

int main(void)
{
    RUN(test_hierarchy_culling);
    RUN(test_hierarchy_exact);
    RUN(test_hierarchy_representatives);
    RUN(test_exact_form_small);
    RUN(test_paper_form_small);
    RUN(test_dipole);
    RUN(test_theta_read_keeps_lobe_energy);
    RUN(test_split_across_dispatches);
    RUN(test_first_order);
    RUN(test_first_order_at_a_face);
    RUN(test_first_order_within_the_loop_budget);
    RUN(test_first_order_in_the_default_walk);
    return harness_report();
}
