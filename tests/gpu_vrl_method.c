/* gpu_vrl_method.c — the `vrl` method (Novak et al. 2012, render/vrl_method.c):
 *   - the GPU gather equals its CPU copy (tests/oracles/vrl_method_cpu.c; same random
 *     numbers) on random VRLs and segments, with enough VRLs that lavapipe's loop limit
 *     splits them across dispatches;
 *   - the estimator's mean equals a numerical double integral of the ray-to-ray transport
 *     (oblique, nearly crossing and parallel pairs);
 *   - the first-stretch VRLs carry exactly the flux that enters an index-matched sphere, for
 *     each light kind (closed forms; Monte Carlo error for a sphere light);
 *   - double and multiple scattering of an index-matched sphere under a directional light,
 *     composed into pixels, agree with the path tracer's components within the noise of both.
 * Validation layers on (NSCATTER_VALIDATION=1). */
#include <stdlib.h>

#include "gpu_util.h"
#include "oracles/vrl_method_cpu.h"

static uint32_t rng = 2024u;
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

static void random_in_ball(float p[3], float radius)
{
    do
        set3(p, 2 * uniform01() - 1, 2 * uniform01() - 1, 2 * uniform01() - 1);
    while (p[0] * p[0] + p[1] * p[1] + p[2] * p[2] > 1);
    for (int k = 0; k < 3; k++)
        p[k] *= radius;
}

/* An index-matched scattering sphere of radius 1 at the origin, lit by `lights`. */
static ns_material sphere_medium;
static ns_object unit_sphere;

static ns_scene sphere_scene(const ns_light *lights, uint32_t light_count, double ior)
{
    static const double ss[3] = {0.8, 1.2, 0.5}, sa[3] = {0.2, 0.3, 0.5};
    sphere_medium = medium(ss, sa, ior);
    sphere_medium.g = 0.3f;
    unit_sphere = sphere(0, 0, 0, 1, 0);
    ns_scene s = base_scene(24, 24, 40);
    set3(s.camera.position, 0, 0, 4);
    scene_lists(&s, &sphere_medium, 1, &unit_sphere, 1, lights, light_count);
    s.render.method = NS_METHOD_VRL;
    return s;
}

/* ---------------------------------------------------------------------------------------
 * (a) GPU gather == CPU gather, same random numbers.
 * ------------------------------------------------------------------------------------- */
static GpuVrl random_vrl(uint32_t events)
{
    GpuVrl v;
    memset(&v, 0, sizeof v);
    random_in_ball(v.origin, 0.9f);
    random_unit(v.direction);
    v.length = 0.05f + 1.5f * uniform01();
    set3(v.power, uniform01(), uniform01(), uniform01());
    v.events = events;
    return v;
}

static GpuSegment random_segment(uint32_t i)
{
    GpuSegment s;
    memset(&s, 0, sizeof s);
    random_in_ball(s.entry, 0.9f);
    random_unit(s.direction);
    float len = 0.05f + 1.5f * uniform01();
    for (int k = 0; k < 3; k++)
        s.exit[k] = s.entry[k] + len * s.direction[k];
    set3(s.throughput, 1, 1, 1);
    s.pixel = i;
    return s;
}

static void test_gather_matches_cpu(void)
{
    ns_context *ctx = test_context();
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(sun.direction, 0, -1, 0);
    ns_scene s = sphere_scene(&sun, 1, 1.0);
    device_scene d;
    if (device_scene_make(&s, &d))
        return;
    /* More VRLs than one lavapipe dispatch takes, a parallel pair and a crossing pair. */
    enum { SEGMENTS = 48, VRLS = 40000 };
    GpuSegment *segs = calloc(SEGMENTS, sizeof *segs);
    GpuVrl *vrls = calloc(VRLS, sizeof *vrls);
    for (uint32_t i = 0; i < SEGMENTS; i++)
        segs[i] = random_segment(i);
    for (uint32_t k = 0; k < VRLS; k++)
        vrls[k] = random_vrl(k % 3 == 0 ? 0u : 1u + k % 5);
    vrls[0].origin[0] = segs[0].entry[0] + 0.01f;
    memcpy(vrls[0].direction, segs[0].direction, sizeof vrls[0].direction);
    memcpy(vrls[1].origin, segs[1].entry, sizeof vrls[1].origin);
    vrls[1].origin[1] += 0.001f;

    ns_error err = {0};
    gpu_buffer seg_buf = {0}, out[2] = {{0}};
    int status = gpu_buffer_create(&ctx->dev, &seg_buf,
                                   &(gpu_buffer_desc){.size = sizeof *segs * SEGMENTS,
                                                      .data = segs,
                                                      .data_size = sizeof *segs * SEGMENTS},
                                   &err);
    for (int i = 0; i < 2 && !status; i++)
        status =
            gpu_buffer_create(&ctx->dev, &out[i], &(gpu_buffer_desc){.size = 16 * SEGMENTS}, &err);
    ns_vrl_gather_counts counts;
    if (!status)
        status = ns_vrl_method_gather_vrls(ctx, d.buffers, &d.gs, &seg_buf, SEGMENTS, vrls, VRLS,
                                           99u, NULL, &out[0], &out[1], &counts, &err);
    if (status)
        fprintf(stderr, "gather: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    CHECK(counts.interactions == (uint64_t)SEGMENTS * VRLS);
    if (ctx->dev.loop_limited)
        CHECK(counts.dispatches > 1); /* the split across dispatches was exercised */

    float(*cpu_d)[4] = calloc(SEGMENTS, sizeof *cpu_d),
    (*cpu_m)[4] = calloc(SEGMENTS, sizeof *cpu_m);
    ns_vrl_method_gather_cpu(d.gs.materials, segs, SEGMENTS, vrls, VRLS, 99u, cpu_d, cpu_m);
    const float(*gpu_d)[4] = out[0].mapped, (*gpu_m)[4] = out[1].mapped;
    double worst = 0;
    int nonzero = 0;
    for (uint32_t i = 0; !status && i < SEGMENTS; i++)
        for (int c = 0; c < 3; c++) {
            double pairs[2][2] = {{gpu_d[i][c], cpu_d[i][c]}, {gpu_m[i][c], cpu_m[i][c]}};
            for (int o = 0; o < 2; o++) {
                double rel = fabs(pairs[o][0] - pairs[o][1]) / fmax(fabs(pairs[o][1]), 1e-12);
                worst = fmax(worst, rel);
                nonzero += pairs[o][1] > 0;
            }
        }
    fprintf(stderr,
            "  gather GPU vs CPU: worst relative difference %.2e over %d sums (%u dispatches)\n",
            worst, nonzero, counts.dispatches);
    CHECK(nonzero == SEGMENTS * 6);
    CHECK(worst < 1e-3);
    free(cpu_d);
    free(cpu_m);
    gpu_buffer_destroy(&ctx->dev, &seg_buf);
    gpu_buffer_destroy(&ctx->dev, &out[0]);
    gpu_buffer_destroy(&ctx->dev, &out[1]);
    free(segs);
    free(vrls);
    device_scene_free(&d);
}

/* With shadow rays (two spheres of one material, 4 apart): a segment in the VRLs' sphere
 * gets what the CPU copy (no shadow rays) gives, since a chord of a sphere stays inside it;
 * a segment in the other sphere gets exactly 0. Shadow rays cost several counted
 * iterations per VRL, so the first batch of dispatches leaves work and the C side repeats. */
static float dot3f(const float *a, const float *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static float distance3f(const float *a, const float *b)
{
    float d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return sqrtf(dot3f(d, d));
}

static void test_gather_visibility(void)
{
    ns_context *ctx = test_context();
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(sun.direction, 0, -1, 0);
    ns_scene s = sphere_scene(&sun, 1, 1.0);
    ns_object pair[2] = {sphere(0, 0, 0, 1, 0), sphere(4, 0, 0, 1, 0)};
    s.objects = pair;
    s.object_count = 2;
    device_scene d;
    if (device_scene_make(&s, &d))
        return;
    enum { SEGMENTS = 64, VRLS = 3000 };
    GpuSegment *segs = calloc(SEGMENTS, sizeof *segs);
    GpuVrl *vrls = calloc(VRLS, sizeof *vrls);
    for (uint32_t i = 0; i < SEGMENTS; i++) {
        segs[i] = random_segment(i);
        /* Clip to the sphere of radius 0.99: a chord stays inside. */
        const float *p = segs[i].entry, *dir = segs[i].direction;
        float b = dot3f(p, dir), c = dot3f(p, p) - 0.99f * 0.99f;
        float len = fminf(distance3f(segs[i].exit, p), -b + sqrtf(b * b - c));
        for (int k = 0; k < 3; k++)
            segs[i].exit[k] = p[k] + len * dir[k];
        if (i % 2) /* into the other sphere */
            for (int k = 0; k < 3; k++) {
                segs[i].entry[k] += k == 0 ? 4.0f : 0.0f;
                segs[i].exit[k] += k == 0 ? 4.0f : 0.0f;
            }
    }
    for (uint32_t k = 0; k < VRLS; k++) {
        vrls[k] = random_vrl(k % 2);
        /* Shorten the VRL so that it stays inside the unit sphere. */
        vrls[k].length = fminf(vrls[k].length, 0.08f);
    }
    ns_error err = {0};
    gpu_buffer seg_buf = {0}, out[2] = {{0}};
    int status = gpu_buffer_create(&ctx->dev, &seg_buf,
                                   &(gpu_buffer_desc){.size = sizeof *segs * SEGMENTS,
                                                      .data = segs,
                                                      .data_size = sizeof *segs * SEGMENTS},
                                   &err);
    for (int i = 0; i < 2 && !status; i++)
        status =
            gpu_buffer_create(&ctx->dev, &out[i], &(gpu_buffer_desc){.size = 16 * SEGMENTS}, &err);
    const uint8_t visibility[1] = {1};
    ns_vrl_gather_counts counts = {0};
    if (!status)
        status = ns_vrl_method_gather_vrls(ctx, d.buffers, &d.gs, &seg_buf, SEGMENTS, vrls, VRLS,
                                           3u, visibility, &out[0], &out[1], &counts, &err);
    if (status)
        fprintf(stderr, "gather: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    float(*cpu_d)[4] = calloc(SEGMENTS, sizeof *cpu_d),
    (*cpu_m)[4] = calloc(SEGMENTS, sizeof *cpu_m);
    ns_vrl_method_gather_cpu(d.gs.materials, segs, SEGMENTS, vrls, VRLS, 3u, cpu_d, cpu_m);
    const float(*gpu_d)[4] = out[0].mapped, (*gpu_m)[4] = out[1].mapped;
    double worst = 0;
    int zeros = 0, same_sphere = 0;
    for (uint32_t i = 0; !status && i < SEGMENTS; i++)
        for (int c = 0; c < 3; c++) {
            if (i % 2) {
                zeros += gpu_d[i][c] == 0.0f && gpu_m[i][c] == 0.0f;
                continue;
            }
            same_sphere += cpu_d[i][c] > 0 && cpu_m[i][c] > 0;
            worst = fmax(worst, fabs(gpu_d[i][c] - cpu_d[i][c]) / cpu_d[i][c]);
            worst = fmax(worst, fabs(gpu_m[i][c] - cpu_m[i][c]) / cpu_m[i][c]);
        }
    fprintf(stderr,
            "  shadow rays: %u dispatches, worst relative difference %.2e in the same sphere\n",
            counts.dispatches, worst);
    CHECK(zeros == SEGMENTS / 2 * 3);
    CHECK(same_sphere == SEGMENTS / 2 * 3);
    CHECK(worst < 1e-3);
    if (ctx->dev.loop_limited)
        CHECK(counts.dispatches > 3); /* more than VRLS / 1000: the repeat loop ran */
    free(cpu_d);
    free(cpu_m);
    gpu_buffer_destroy(&ctx->dev, &seg_buf);
    gpu_buffer_destroy(&ctx->dev, &out[0]);
    gpu_buffer_destroy(&ctx->dev, &out[1]);
    free(segs);
    free(vrls);
    device_scene_free(&d);
}

/* lavapipe's loop limit: 2000 diffuse planes far below the sphere make every traversal run a
 * 2000-iteration loop that the shaders do not count, so the first budgets get cut; the
 * passes start again with smaller ones. The light paths never meet the planes (light from
 * above, paths end when they leave), so the VRLs are bit for bit those of the scene without
 * planes, and the gather with shadow rays equals the CPU copy. */
static void test_loop_limit_retry(void)
{
    ns_context *ctx = test_context();
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(sun.direction, 0.2, -1, 0.1);
    float n = sqrtf(1.05f);
    for (int k = 0; k < 3; k++)
        sun.direction[k] /= n;
    enum { PLANES = 2000, PATHS = 500 };
    ns_scene s = sphere_scene(&sun, 1, 1.0);
    /* Albedo 0.995 over 20 mfp: long walks, many traversals per invocation. */
    set3(sphere_medium.sigma_s, 10, 10, 10);
    set3(sphere_medium.sigma_a, 0.05, 0.05, 0.05);
    ns_material mats[2] = {sphere_medium, diffuse(0.5, 0.5, 0.5)};
    ns_object *objects = calloc(PLANES + 1, sizeof *objects);
    objects[0] = unit_sphere;
    for (uint32_t i = 0; i < PLANES; i++)
        objects[1 + i] = plane(-10.0 - 0.001 * i, 1);
    ns_vrl_set plain = {0}, crowded = {0};
    uint32_t restarts = 0;
    ns_error err = {0};
    device_scene d;
    int status = device_scene_make(&s, &d);
    if (!status) {
        status = ns_vrl_method_trace(ctx, &s, &d.gs, d.buffers, PATHS, 3u, 0, &plain, NULL, &err);
        device_scene_free(&d);
    }
    s.materials = mats;
    s.material_count = 2;
    s.objects = objects;
    s.object_count = PLANES + 1;
    if (!status)
        status = device_scene_make(&s, &d);
    if (!status)
        status =
            ns_vrl_method_trace(ctx, &s, &d.gs, d.buffers, PATHS, 3u, 0, &crowded, &restarts, &err);
    if (status)
        fprintf(stderr, "trace: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    CHECK(plain.count > PATHS);
    CHECK(crowded.count == plain.count);
    CHECK(!status && crowded.count == plain.count &&
          memcmp(crowded.vrls, plain.vrls, sizeof *plain.vrls * plain.count) == 0);

    /* The gather with shadow rays over the same planes. */
    enum { SEGMENTS = 16, VRLS = 400 };
    GpuSegment *segs = calloc(SEGMENTS, sizeof *segs);
    for (uint32_t i = 0; i < SEGMENTS; i++) {
        segs[i] = random_segment(i);
        const float *p = segs[i].entry, *dir = segs[i].direction;
        float b = dot3f(p, dir), c = dot3f(p, p) - 0.99f * 0.99f;
        float len = fminf(distance3f(segs[i].exit, p), -b + sqrtf(b * b - c));
        for (int k = 0; k < 3; k++)
            segs[i].exit[k] = p[k] + len * dir[k];
    }
    gpu_buffer seg_buf = {0}, out[2] = {{0}};
    if (!status)
        status = gpu_buffer_create(&ctx->dev, &seg_buf,
                                   &(gpu_buffer_desc){.size = sizeof *segs * SEGMENTS,
                                                      .data = segs,
                                                      .data_size = sizeof *segs * SEGMENTS},
                                   &err);
    for (int i = 0; i < 2 && !status; i++)
        status =
            gpu_buffer_create(&ctx->dev, &out[i], &(gpu_buffer_desc){.size = 16 * SEGMENTS}, &err);
    /* The traced VRLs that stay inside the sphere of radius 0.99 (a chord between them and
     * the segments never meets a plane). */
    GpuVrl *vrls = calloc(VRLS, sizeof *vrls);
    uint32_t kept = 0;
    for (uint32_t k = 0; !status && k < plain.count && kept < VRLS; k++) {
        GpuVrl v = plain.vrls[k];
        v.length = fminf(v.length, 0.05f);
        float end[3];
        for (int i = 0; i < 3; i++)
            end[i] = v.origin[i] + v.length * v.direction[i];
        if (dot3f(v.origin, v.origin) < 0.98f && dot3f(end, end) < 0.98f)
            vrls[kept++] = v;
    }
    const uint8_t visibility[2] = {1, 1};
    ns_vrl_gather_counts counts = {0};
    if (!status)
        status = ns_vrl_method_gather_vrls(ctx, d.buffers, &d.gs, &seg_buf, SEGMENTS, vrls, kept,
                                           5u, visibility, &out[0], &out[1], &counts, &err);
    if (status)
        fprintf(stderr, "gather: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    float(*cpu_d)[4] = calloc(SEGMENTS, sizeof *cpu_d),
    (*cpu_m)[4] = calloc(SEGMENTS, sizeof *cpu_m);
    ns_vrl_method_gather_cpu(d.gs.materials, segs, SEGMENTS, vrls, kept, 5u, cpu_d, cpu_m);
    double worst = 0;
    for (uint32_t i = 0; !status && i < SEGMENTS; i++)
        for (int c = 0; c < 3; c++) {
            const float(*gd)[4] = out[0].mapped, (*gm)[4] = out[1].mapped;
            worst = fmax(worst, fabs(gd[i][c] - cpu_d[i][c]) / fmax(cpu_d[i][c], 1e-30));
            worst = fmax(worst, fabs(gm[i][c] - cpu_m[i][c]) / fmax(cpu_m[i][c], 1e-30));
        }
    fprintf(stderr,
            "  %u planes: %u VRLs identical (%u trace restarts), gather over %u VRLs in %u "
            "dispatches (%u restarts), worst %.2e\n",
            PLANES, crowded.count, restarts, kept, counts.dispatches, counts.restarts, worst);
    if (ctx->dev.loop_limited)
        CHECK(restarts > 0 && counts.restarts > 0); /* the retry was exercised */
    CHECK(kept == VRLS);
    CHECK(worst < 1e-3);
    free(cpu_d);
    free(cpu_m);
    free(vrls);
    free(segs);
    gpu_buffer_destroy(&ctx->dev, &seg_buf);
    gpu_buffer_destroy(&ctx->dev, &out[0]);
    gpu_buffer_destroy(&ctx->dev, &out[1]);
    if (d.gs.materials)
        device_scene_free(&d);
    free(plain.vrls);
    free(crowded.vrls);
    free(objects);
}

/* ---------------------------------------------------------------------------------------
 * The estimator's mean against a numerical integral of the same transport.
 * ------------------------------------------------------------------------------------- */
static double hg(double c, double g)
{
    double d = 1 + g * g - 2 * g * c;
    return (1 - g * g) / (4 * M_PI * d * sqrt(d));
}

/* Midpoint rule on an n x n grid, in double, channel 0. */
static double transport_integral(const GpuSegment *seg, const GpuVrl *v, const GpuMaterial *m,
                                 int n)
{
    double lc = 0, sum = 0;
    for (int k = 0; k < 3; k++)
        lc += ((double)seg->exit[k] - seg->entry[k]) * ((double)seg->exit[k] - seg->entry[k]);
    lc = sqrt(lc);
    double g = m->sigma_s[3], ss = m->sigma_s[0], st = m->sigma_t[0];
    for (int i = 0; i < n; i++) {
        double t = (i + 0.5) * lc / n;
        for (int j = 0; j < n; j++) {
            double u = (j + 0.5) * v->length / n, w[3], d2 = 0;
            for (int k = 0; k < 3; k++) {
                w[k] =
                    (seg->entry[k] + t * seg->direction[k]) - (v->origin[k] + u * v->direction[k]);
                d2 += w[k] * w[k];
            }
            double dist = sqrt(d2), cw = 0, cc = 0;
            for (int k = 0; k < 3; k++) {
                cw += v->direction[k] * w[k] / dist;
                cc -= seg->direction[k] * w[k] / dist;
            }
            sum += ss * ss * hg(cw, g) * hg(cc, g) * exp(-st * (t + u + dist)) / d2;
        }
    }
    return sum * (lc / n) * (v->length / n);
}

static void check_estimator_mean(const char *name, const GpuSegment *seg, const GpuVrl *v,
                                 const GpuMaterial *m)
{
    enum { BATCHES = 20, COPIES = 2000 };
    GpuVrl *copies = malloc(sizeof *copies * COPIES);
    for (int k = 0; k < COPIES; k++)
        copies[k] = *v;
    double mean = 0, sq = 0;
    float dbl[1][4], mult[1][4];
    for (uint32_t b = 0; b < BATCHES; b++) {
        ns_vrl_method_gather_cpu(m, seg, 1, copies, COPIES, 1000u + b, dbl, mult);
        double x = dbl[0][0] / COPIES;
        mean += x / BATCHES;
        sq += x * x / BATCHES;
    }
    double se = sqrt(fmax(0, sq - mean * mean) / (BATCHES - 1));
    double want = transport_integral(seg, v, m, 1500);
    fprintf(stderr, "  %s: estimator %.6g +- %.2g, integral %.6g\n", name, mean, se, want);
    CHECK(want > 0);
    CHECK(fabs(mean - want) < 4 * se + 2e-3 * want);
    free(copies);
}

static void test_estimator_mean(void)
{
    GpuMaterial m;
    memset(&m, 0, sizeof m);
    set3(m.sigma_s, 0.9, 0.9, 0.9);
    set3(m.sigma_t, 1.2, 1.2, 1.2);
    m.sigma_s[3] = 0.4f;
    GpuSegment seg;
    memset(&seg, 0, sizeof seg);
    set3(seg.entry, 0, 0, 0);
    set3(seg.direction, 1, 0, 0);
    set3(seg.exit, 1.5, 0, 0);
    GpuVrl v;
    memset(&v, 0, sizeof v);
    set3(v.power, 1, 1, 1);
    /* Oblique, 0.3 apart. */
    set3(v.origin, 0.2, -0.5, 0.3);
    float n = sqrtf(0.5f * 0.5f + 1.0f + 0.2f * 0.2f);
    set3(v.direction, 0.5 / n, 1 / n, -0.2 / n);
    v.length = 1.2f;
    check_estimator_mean("oblique", &seg, &v, &m);
    /* Nearly crossing: 0.02 apart, perpendicular. */
    set3(v.origin, 0.7, -0.6, 0.02);
    set3(v.direction, 0, 1, 0);
    check_estimator_mean("nearly crossing", &seg, &v, &m);
    /* Nearly parallel (sin 0.005, above the parallel threshold), 0.2 apart: the lines' closest
     * points lie about 40 away, far outside both (the sampling must not cancel there). */
    set3(v.origin, 0.1, 0.2, 0.0);
    set3(v.direction, cos(0.005), sin(0.005), 0);
    v.length = 1.2f;
    check_estimator_mean("nearly parallel", &seg, &v, &m);
    /* Parallel, 0.25 apart, opposite directions. */
    set3(v.origin, 1.2, 0.25, 0);
    set3(v.direction, -1, 0, 0);
    v.length = 1.0f;
    check_estimator_mean("parallel", &seg, &v, &m);
}

/* ---------------------------------------------------------------------------------------
 * (c) Flux entering the sphere: the first-stretch VRLs (events 0; ior 1, so no internal
 * reflection makes other events-0 stretches).
 * ------------------------------------------------------------------------------------- */
typedef struct flux_sum {
    double total[3], sq[3];
    uint32_t first_stretches, all;
} flux_sum;

static int trace_flux(const ns_light *lights, uint32_t count, uint32_t paths, uint32_t seed,
                      flux_sum *f)
{
    memset(f, 0, sizeof *f);
    ns_scene s = sphere_scene(lights, count, 1.0);
    device_scene d;
    if (device_scene_make(&s, &d))
        return -1;
    ns_vrl_set set;
    ns_error err = {0};
    int status =
        ns_vrl_method_trace(test_context(), &s, &d.gs, d.buffers, paths, seed, 0, &set, NULL, &err);
    if (status)
        fprintf(stderr, "trace: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    for (uint32_t i = 0; !status && i < set.count; i++) {
        const GpuVrl *v = &set.vrls[i];
        CHECK(v->material == 0);
        if (v->events)
            continue;
        f->first_stretches++;
        for (int c = 0; c < 3; c++) {
            f->total[c] += v->power[c];
            f->sq[c] += (double)v->power[c] * v->power[c];
        }
    }
    f->all = set.count;
    free(set.vrls);
    device_scene_free(&d);
    return status;
}

static void check_flux(const char *name, const flux_sum *f, const double want[3], uint32_t paths,
                       double rel_floor)
{
    for (int c = 0; c < 3; c++) {
        /* Standard error of the sum of N per-path fluxes (paths that missed give 0). */
        double mean = f->total[c] / paths;
        double se = sqrt(fmax(0, f->sq[c] / paths - mean * mean) * paths);
        fprintf(stderr, "  %s channel %d: flux %.6g (+- %.2g), expected %.6g\n", name, c,
                f->total[c], se, want[c]);
        CHECK(fabs(f->total[c] - want[c]) <= 4 * se + rel_floor * want[c]);
    }
}

static void test_first_stretch_flux(void)
{
    enum { PATHS = 4000 };
    const double color[3] = {1.0, 2.0, 0.5};
    flux_sum f;

    ns_light sun = light(NS_LIGHT_DIRECTIONAL, color[0], color[1], color[2]);
    set3(sun.direction, 0.3, -0.9, 0.2);
    float n = sqrtf(0.09f + 0.81f + 0.04f);
    for (int k = 0; k < 3; k++)
        sun.direction[k] /= n;
    if (!trace_flux(&sun, 1, PATHS, 5u, &f)) {
        double want[3];
        for (int c = 0; c < 3; c++)
            want[c] = color[c] * M_PI; /* E pi R^2 */
        check_flux("directional", &f, want, PATHS, 1e-3);
        CHECK(f.first_stretches == PATHS);
        CHECK(f.all > f.first_stretches); /* the walk made later stretches too */
    }

    ns_light point = light(NS_LIGHT_POINT, color[0], color[1], color[2]);
    set3(point.position, 0, 3, 0);
    if (!trace_flux(&point, 1, PATHS, 5u, &f)) {
        double want[3];
        for (int c = 0; c < 3; c++)
            want[c] = color[c] * 2 * M_PI * (1 - sqrt(1 - 1.0 / 9.0)); /* I x solid angle */
        check_flux("point", &f, want, PATHS, 1e-3);
    }

    ns_light env = light(NS_LIGHT_ENVIRONMENT, color[0], color[1], color[2]);
    if (!trace_flux(&env, 1, PATHS, 5u, &f)) {
        double want[3];
        for (int c = 0; c < 3; c++)
            want[c] = color[c] * 4 * M_PI * M_PI; /* L 4 pi x pi R^2 */
        check_flux("environment", &f, want, PATHS, 1e-3);
    }

    /* A Lambertian sphere light radiates into a sphere outside it like a point of intensity
     * L pi Rl^2 (the sphere-to-sphere view factor): Monte Carlo error only. */
    ns_light bulb = light(NS_LIGHT_SPHERE, color[0], color[1], color[2]);
    set3(bulb.position, 0, 0, -4);
    bulb.radius = 0.5f;
    if (!trace_flux(&bulb, 1, 4 * PATHS, 5u, &f)) {
        double want[3];
        for (int c = 0; c < 3; c++)
            want[c] = color[c] * M_PI * 0.25 * 2 * M_PI * (1 - sqrt(1 - 1.0 / 16.0));
        check_flux("sphere light", &f, want, 4 * PATHS, 0);
    }

    /* Its paths are stratified (common.glsl, stratified4): over sixteen seeds the error's
     * root mean square, in standard errors of independent paths, is below 0.4 (they reach it
     * about once in 100,000: chi-square, 16 degrees of freedom, below 2.56). */
    double sq = 0;
    enum { SEEDS = 16 };
    for (uint32_t seed = 1; seed <= SEEDS; seed++) {
        if (trace_flux(&bulb, 1, PATHS, seed, &f))
            break;
        double want = color[0] * M_PI * 0.25 * 2 * M_PI * (1 - sqrt(1 - 1.0 / 16.0));
        double mean = f.total[0] / PATHS;
        double se = sqrt(fmax(0, f.sq[0] / PATHS - mean * mean) * PATHS);
        sq += (f.total[0] - want) * (f.total[0] - want) / (se * se) / SEEDS;
    }
    fprintf(stderr, "  sphere light, stratified: rms error over %d seeds %.3f standard errors\n",
            SEEDS, sqrt(sq));
    CHECK(sqrt(sq) < 0.4);

    /* All four at once: the paths are shared out and the weights keep the sum. */
    ns_light all[4] = {sun, point, env, bulb};
    if (!trace_flux(all, 4, 4 * PATHS, 5u, &f)) {
        double want[3];
        for (int c = 0; c < 3; c++)
            want[c] = color[c] * (M_PI + 2 * M_PI * (1 - sqrt(1 - 1.0 / 9.0)) + 4 * M_PI * M_PI +
                                  M_PI * 0.25 * 2 * M_PI * (1 - sqrt(1 - 1.0 / 16.0)));
        check_flux("four lights", &f, want, 4 * PATHS, 2e-3);
    }
}

/* Spectral MIS over the whole path (vrl_trace.comp, mis_step): a walk's flux in any channel
 * stays within 3 times its flux at the entry, however long it walks, because the balance
 * heuristic divides by the mean of the three channels' path pdfs. A medium whose channels'
 * extinctions differ 5x, albedo 0.99, lit from one direction: taking the mixture's pdf at
 * every event instead, the thinnest channel's flux grows up to 3x per event, and some
 * stretches carry many times the entry flux. */
static void test_walk_weights_bounded(void)
{
    const double albedo = 0.99, sigma_t[3] = {0.2, 0.5, 1.0};
    double ss[3], sa[3];
    for (int c = 0; c < 3; c++) {
        ss[c] = albedo * sigma_t[c] * 4; /* the unit sphere is 0.8-4 mfp across */
        sa[c] = (1 - albedo) * sigma_t[c] * 4;
    }
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(sun.direction, 0, -1, 0);
    ns_scene s = sphere_scene(&sun, 1, 1.0);
    sphere_medium = medium(ss, sa, 1.0);
    sphere_medium.g = 0.3f;
    device_scene d;
    if (device_scene_make(&s, &d))
        return;
    ns_vrl_set set;
    ns_error err = {0};
    int status = ns_vrl_method_trace(test_context(), &s, &d.gs, d.buffers, 4000, 7u, 0, &set, NULL, &err);
    CHECK_INT(status, NS_OK);
    double entry = 0, worst = 0;
    uint32_t later = 0;
    for (uint32_t i = 0; !status && i < set.count; i++)
        if (!set.vrls[i].events)
            entry = fmax(entry, set.vrls[i].power[0]);
    for (uint32_t i = 0; !status && i < set.count; i++) {
        later += set.vrls[i].events > 0;
        for (int c = 0; c < 3; c++)
            worst = fmax(worst, set.vrls[i].power[c] / entry);
    }
    fprintf(stderr, "  walk weights: %u stretches after an event, largest flux %.3g x the entry's\n",
            later, worst);
    CHECK(later > 5000); /* long walks: the bound is tested where it matters */
    CHECK(worst <= 3.0 * (1 + 1e-4));
    if (!status)
        free(set.vrls);
    device_scene_free(&d);
}

/* ---------------------------------------------------------------------------------------
 * (b) Double and multiple scattering in pixels against the path tracer.
 * ------------------------------------------------------------------------------------- */
enum { RUNS = 6 };

/* Image means of the vrl method's double and multiple components for one seed. */
static int vrl_image_means(ns_scene s, uint32_t seed, double dbl[3], double mult[3])
{
    ns_context *ctx = test_context();
    s.render.seed = seed;
    s.render.method = NS_METHOD_VRL;
    s.render.components = NS_COMPONENT_SURFACE;
    uint32_t pixels = s.camera.width * s.camera.height;
    /* Internal reflections make several stretches per sample behind a refracting boundary. */
    uint32_t max_segments = pixels * s.render.spp * 16;
    GpuSegment *segs = calloc(max_segments, sizeof *segs);
    ns_render_debug debug = {
        .segment_capacity = max_segments, .segments = segs, .segments_max = max_segments};
    ns_image img = {0};
    ns_error err = {0};
    int status = ns_render_ex(ctx, &s, &img, NULL, &debug, &err);
    ns_image_free(&img);
    uint32_t n = (uint32_t)debug.segments_written;
    CHECK(debug.segments_overflow == 0);
    device_scene d;
    memset(&d, 0, sizeof d);
    if (!status)
        status = device_scene_make(&s, &d);
    gpu_buffer seg_buf = {0}, out[2] = {{0}};
    if (!status) {
        status = gpu_buffer_create(&ctx->dev, &seg_buf,
                                   &(gpu_buffer_desc){.size = sizeof *segs * n,
                                                      .data = segs,
                                                      .data_size = sizeof *segs * n},
                                   &err);
        for (int i = 0; i < 2 && !status; i++)
            status =
                gpu_buffer_create(&ctx->dev, &out[i], &(gpu_buffer_desc){.size = 16ull * n}, &err);
        ns_render_stats stats = {0};
        if (!status)
            status = ns_vrl_method_gather(ctx, &s, &d.gs, d.buffers, &seg_buf, n, &out[0], &out[1],
                                          &stats, &err);
        if (!status && seed == 1)
            fprintf(stderr, "  vrl: %u segments, %llu VRLs from %llu paths, %llu interactions\n", n,
                    (unsigned long long)stats.vrl_count, (unsigned long long)stats.vrl_paths,
                    (unsigned long long)stats.interactions);
    }
    if (status)
        fprintf(stderr, "vrl render: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    for (int c = 0; c < 3; c++)
        dbl[c] = mult[c] = 0;
    if (!status) {
        /* pixel += throughput * L / spp (ior 1: no boundary factor); image mean. */
        const float(*ld)[4] = out[0].mapped, (*lm)[4] = out[1].mapped;
        double ior = s.materials[0].ior;
        double norm = 1.0 / ((double)s.render.spp * pixels * ior * ior);
        for (uint32_t i = 0; i < n; i++)
            for (int c = 0; c < 3; c++) {
                dbl[c] += segs[i].throughput[c] * ld[i][c] * norm;
                mult[c] += segs[i].throughput[c] * lm[i][c] * norm;
            }
    }
    gpu_buffer_destroy(&ctx->dev, &seg_buf);
    gpu_buffer_destroy(&ctx->dev, &out[0]);
    gpu_buffer_destroy(&ctx->dev, &out[1]);
    if (d.buffers[0].buffer || d.gs.materials)
        device_scene_free(&d);
    free(segs);
    return status;
}

static int pt_image_mean(ns_scene s, uint32_t seed, uint32_t components, double mean[3])
{
    s.render.seed = seed;
    s.render.method = NS_METHOD_PT;
    s.render.components = components;
    ns_image img = {0};
    if (!render_ok(&s, &img, NULL))
        return -1;
    image_mean(&img, mean);
    ns_image_free(&img);
    return 0;
}

static void mean_and_se(double runs[RUNS][3], double mean[3], double se[3])
{
    for (int c = 0; c < 3; c++) {
        double m = 0, sq = 0;
        for (int r = 0; r < RUNS; r++)
            m += runs[r][c] / RUNS;
        for (int r = 0; r < RUNS; r++)
            sq += (runs[r][c] - m) * (runs[r][c] - m);
        mean[c] = m;
        se[c] = sqrt(sq / (RUNS - 1) / RUNS);
    }
}

static void compare_with_path_tracer(double ior, uint32_t vrl_spp, uint32_t vrls)
{
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 1.0, 1.0, 1.0);
    set3(sun.direction, -0.6, -0.7, -0.4);
    float n = sqrtf(0.36f + 0.49f + 0.16f);
    for (int k = 0; k < 3; k++)
        sun.direction[k] /= n;
    ns_scene s = sphere_scene(&sun, 1, ior);
    s.render.spp = vrl_spp;
    s.render.vrls = vrls;
    double vd[RUNS][3], vm[RUNS][3], pd[RUNS][3], pm[RUNS][3];
    double t0 = ns_now_ms();
    for (uint32_t r = 0; r < RUNS; r++)
        if (vrl_image_means(s, 1 + r, vd[r], vm[r]))
            return;
    double t1 = ns_now_ms();
    s.render.spp = 32;
    for (uint32_t r = 0; r < RUNS; r++)
        if (pt_image_mean(s, 101 + r, NS_COMPONENT_DOUBLE, pd[r]) ||
            pt_image_mean(s, 201 + r, NS_COMPONENT_MULTIPLE, pm[r]))
            return;
    double t2 = ns_now_ms();
    fprintf(stderr, "  ior %.2f, %d runs: vrl %.1f s, pt %.1f s\n", ior, RUNS, (t1 - t0) / 1e3,
            (t2 - t1) / 1e3);
    const char *names[2] = {"double", "multiple"};
    double(*vrl_runs[2])[3] = {vd, vm}, (*pt_runs[2])[3] = {pd, pm};
    for (int o = 0; o < 2; o++) {
        double vmean[3], vse[3], pmean[3], pse[3];
        mean_and_se(vrl_runs[o], vmean, vse);
        mean_and_se(pt_runs[o], pmean, pse);
        for (int c = 0; c < 3; c++) {
            double se = sqrt(vse[c] * vse[c] + pse[c] * pse[c]);
            fprintf(stderr, "  %s channel %d: vrl %.5g +- %.2g, pt %.5g +- %.2g (%.1f se)\n",
                    names[o], c, vmean[c], vse[c], pmean[c], pse[c],
                    fabs(vmean[c] - pmean[c]) / se);
            CHECK(pmean[c] > 0);
            if (o == 1 && ior != 1.0) // see test_against_path_tracer_refracting
                CHECK(vmean[c] - pmean[c] < 4 * se);
            else
                CHECK(fabs(vmean[c] - pmean[c]) < 4 * se);
        }
    }
}

static void test_against_path_tracer(void)
{
    compare_with_path_tracer(1.0, 2, 1500);
}

/* Through a refracting boundary: Fresnel transmission, internal reflection in the walk, and
 * the 1/ior^2 radiance factor of the composition. Double scattering must agree: under a
 * directional light neither method can make a double-scattering path whose light reflects
 * off the boundary between its two events (a VRL meets the camera stretch only in a straight
 * line; pt's light sub-path connects straight too), and both make all the others. Multiple
 * scattering only one way: the VRLs miss every path whose last edge (VRL to camera stretch)
 * reflects off the boundary, which pt's light sub-paths make when an earlier edge is
 * straight (docs/reference.md), so the VRLs must not exceed pt (measured: 12-22% below). */
static void test_against_path_tracer_refracting(void)
{
    compare_with_path_tracer(1.5, 1, 1000);
}

/* ---------------------------------------------------------------------------------------
 * Bad input.
 * ------------------------------------------------------------------------------------- */
static void test_bad_input(void)
{
    ns_context *ctx = test_context();
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(sun.direction, 0, -1, 0);
    ns_scene s = sphere_scene(&sun, 1, 1.0);
    device_scene d;
    if (device_scene_make(&s, &d))
        return;
    ns_error err = {0};
    gpu_buffer small = {0};
    CHECK_INT(gpu_buffer_create(&ctx->dev, &small, &(gpu_buffer_desc){.size = 16}, &err), NS_OK);
    int status =
        ns_vrl_method_gather(ctx, &s, &d.gs, d.buffers, &small, 4, &small, &small, NULL, &err);
    CHECK_INT(status, NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "segments buffer");
    status = ns_vrl_method_gather(ctx, &s, &d.gs, d.buffers, &small, 0, NULL, &small, NULL, &err);
    CHECK_INT(status, NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "out_double");
    ns_vrl_set set;
    status = ns_vrl_method_trace(ctx, &s, &d.gs, d.buffers, NS_MAX_VRLS + 1, 1, 0, &set, NULL, &err);
    CHECK_INT(status, NS_ERR_LIMIT);
    CHECK_STR_CONTAINS(err.message, "render.vrls");
    /* A plane of scattering medium has no bounding sphere to aim at. */
    ns_object slab = plane(-1, 0);
    s.objects = &slab;
    status = ns_vrl_method_trace(ctx, &s, &d.gs, d.buffers, 10, 1, 0, &set, NULL, &err);
    CHECK_INT(status, NS_ERR_NOT_AVAILABLE);
    CHECK_STR_CONTAINS(err.message, "objects[0]");
    gpu_buffer_destroy(&ctx->dev, &small);
    device_scene_free(&d);
    CHECK_INT(ctx->dev.live_buffers, 0);
}

/* ---------------------------------------------------------------------------------------
 * NSCATTER_BENCH=N: medians of N runs at 128 x 128, spp 1, every segment gathered (no
 * tiling), render.vrls light paths (NSCATTER_BENCH_VRLS, default 10000).
 * ------------------------------------------------------------------------------------- */
static int compare_doubles(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

static void bench(int runs)
{
    enum { MAX_RUNS = 32 };
    ns_context *ctx = test_context();
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 1.0, 1.0, 1.0);
    set3(sun.direction, -0.6, -0.7, -0.4);
    ns_scene s = sphere_scene(&sun, 1, 1.0);
    s.camera.width = s.camera.height = 128;
    s.camera.fov_deg = 35;
    s.render.spp = 1;
    const char *v = getenv("NSCATTER_BENCH_VRLS");
    s.render.vrls = v && atoi(v) > 0 ? (uint32_t)atoi(v) : NS_DEFAULT_VRLS;
    uint32_t cap = 128 * 128 * 4;
    GpuSegment *segs = calloc(cap, sizeof *segs);
    ns_render_debug debug = {.segment_capacity = cap, .segments = segs, .segments_max = cap};
    ns_image img = {0};
    ns_error err = {0};
    device_scene d;
    memset(&d, 0, sizeof d);
    int status = ns_render_ex(ctx, &s, &img, NULL, &debug, &err);
    ns_image_free(&img);
    if (!status)
        status = device_scene_make(&s, &d);
    uint32_t n = (uint32_t)debug.segments_written;
    gpu_buffer seg_buf = {0}, out[2] = {{0}};
    if (!status)
        status = gpu_buffer_create(&ctx->dev, &seg_buf,
                                   &(gpu_buffer_desc){.size = sizeof *segs * n,
                                                      .data = segs,
                                                      .data_size = sizeof *segs * n},
                                   &err);
    for (int i = 0; i < 2 && !status; i++)
        status = gpu_buffer_create(&ctx->dev, &out[i], &(gpu_buffer_desc){.size = 16ull * n}, &err);
    double trace_ms[MAX_RUNS], gather_ms[MAX_RUNS];
    uint64_t interactions = 0, vrl_count = 0;
    if (runs > MAX_RUNS)
        runs = MAX_RUNS;
    for (int r = 0; r < runs && !status; r++) {
        ns_vrl_set set;
        double t0 = ns_now_ms();
        status = ns_vrl_method_trace(ctx, &s, &d.gs, d.buffers, s.render.vrls, 1u + (uint32_t)r,
                                     0, &set, NULL, &err);
        double t1 = ns_now_ms();
        ns_vrl_gather_counts counts;
        if (!status)
            status =
                ns_vrl_method_gather_vrls(ctx, d.buffers, &d.gs, &seg_buf, n, set.vrls, set.count,
                                          7u, NULL, &out[0], &out[1], &counts, &err);
        trace_ms[r] = t1 - t0;
        gather_ms[r] = ns_now_ms() - t1;
        interactions = counts.interactions;
        vrl_count = set.count;
        free(set.vrls);
    }
    CHECK_INT(status, NS_OK);
    if (!status) {
        qsort(trace_ms, (size_t)runs, sizeof *trace_ms, compare_doubles);
        qsort(gather_ms, (size_t)runs, sizeof *gather_ms, compare_doubles);
        double g = gather_ms[runs / 2];
        printf("vrl method bench (%s): 128x128 spp 1, %u segments, %u paths -> %llu VRLs, "
               "%llu interactions; median of %d: trace %.1f ms, gather %.1f ms (%.1f M "
               "interactions/s)\n",
               ctx->dev.info.device_name, n, s.render.vrls, (unsigned long long)vrl_count,
               (unsigned long long)interactions, runs, trace_ms[runs / 2], g,
               interactions / (g * 1e3));
    } else {
        fprintf(stderr, "bench: %s\n", err.message);
    }
    gpu_buffer_destroy(&ctx->dev, &seg_buf);
    gpu_buffer_destroy(&ctx->dev, &out[0]);
    gpu_buffer_destroy(&ctx->dev, &out[1]);
    if (d.gs.materials)
        device_scene_free(&d);
    free(segs);
}

int main(void)
{
    const char *bench_runs = getenv("NSCATTER_BENCH");
    if (bench_runs && atoi(bench_runs) > 0) {
        bench(atoi(bench_runs));
        return harness_report();
    }
    RUN(test_estimator_mean);
    RUN(test_gather_matches_cpu);
    RUN(test_gather_visibility);
    RUN(test_loop_limit_retry);
    RUN(test_first_stretch_flux);
    RUN(test_walk_weights_bounded);
    RUN(test_bad_input);
    RUN(test_against_path_tracer);
    RUN(test_against_path_tracer_refracting);
    return harness_report();
}
