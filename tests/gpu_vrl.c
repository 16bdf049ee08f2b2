/* gpu_vrl.c — Virtual Ray Light generation (shaders/vrl.comp, render/vrl.c) against closed
 * forms: the VRLs' total power equals the flux that enters the medium, Fresnel-transmitted,
 * for every light kind; origins lie on the boundary and directions obey Snell's law; the
 * beam's internal reflections (mirror directions, e^{-sigma_t L} power, total reflection
 * always followed, partial with the Fresnel probability); the result is deterministic for a
 * seed; blockers and bad input behave. Validation on.
 *
 * Monte Carlo bound: the total is a sum over N independent paths of x_i (a path's VRL power,
 * 0 when it stored none), so its standard deviation is sqrt(N var(x)), estimated from the
 * same x_i; the tests allow 4 of those (a false failure about once in 16,000 runs) and check
 * that this bound is tight (below 1% of the answer) so that it cannot hide a wrong result. */
#include "gpu_util.h"
#include "scatter.h"
#include "vrl_shared.h"

enum { PATHS = 20000 };

/* ---------------------------------------------------------------------------------------
 * Closed forms, in double.
 * ------------------------------------------------------------------------------------- */
/* Unpolarised Fresnel reflectance from vacuum into ior at incidence cosine mu. */
static double fresnel_in(double mu, double ior)
{
    if (mu <= 0)
        return 1; /* grazing: 0/0 in the formulas below */
    double sin2_t = (1 - mu * mu) / (ior * ior);
    double cos_t = sqrt(1 - sin2_t);
    double rs = (mu - ior * cos_t) / (mu + ior * cos_t);
    double rp = (ior * mu - cos_t) / (ior * mu + cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

/* 2 * integral_0^1 (1 - F(mu)) mu dmu: the transmitted fraction of a uniform beam (or of
 * uniform radiance) falling on a sphere. Simpson's rule on 20,000 intervals. */
static double sphere_transmittance(double ior)
{
    const int n = 20000;
    double sum = 0;
    for (int i = 0; i <= n; i++) {
        double mu = (double)i / n;
        double w = i == 0 || i == n ? 1 : (i % 2 ? 4 : 2);
        sum += w * (1 - fresnel_in(mu, ior)) * mu;
    }
    return 2 * sum / (3.0 * n);
}

/* integral over the cone from a point at distance dist of a sphere of radius r of
 * (1 - F(incidence)) d omega: what a unit point intensity sends into the sphere. In the
 * incidence cosine mu (smooth, unlike the cone angle): sin(alpha) = (r / dist) sqrt(1 - mu^2),
 * so d omega = 2 pi (r / dist)^2 mu / cos(alpha) d mu. */
static double point_cone_transmittance(double dist, double r, double ior)
{
    const int n = 20000;
    double k2 = (r / dist) * (r / dist), sum = 0;
    for (int i = 0; i <= n; i++) {
        double mu = (double)i / n;
        double cos_alpha = sqrt(1 - k2 * (1 - mu * mu));
        double w = i == 0 || i == n ? 1 : (i % 2 ? 4 : 2);
        sum += w * (1 - fresnel_in(mu, ior)) * 2 * M_PI * k2 * mu / cos_alpha;
    }
    return sum / (3.0 * n);
}

/* ---------------------------------------------------------------------------------------
 * A scene on the device, and its VRLs.
 * ------------------------------------------------------------------------------------- */
typedef struct vrl_case {
    ns_material materials[4];
    uint32_t material_count;
    ns_object objects[4];
    uint32_t object_count;
    ns_light lights[4];
    uint32_t light_count;
    ns_triangle triangles[12];
    uint32_t triangle_count;
} vrl_case;

static ns_scene scene_of(const vrl_case *c)
{
    ns_scene s = base_scene(8, 8, 60);
    set3(s.camera.position, 0, 0, 10);
    scene_lists(&s, c->materials, c->material_count, c->objects, c->object_count, c->lights,
                c->light_count);
    s.triangles = c->triangles;
    s.triangle_count = c->triangle_count;
    s.render.components = NS_COMPONENT_MULTIPLE;
    s.render.vrls = PATHS;
    return s;
}

static double last_generate_ms; /* ns_vrl_generate alone, for the benchmark */
static uint32_t generate_chain = 1; /* stretches per path: the first ones alone, unless a test says */

static int generate(const vrl_case *c, uint32_t paths, uint32_t seed, ns_vrl_set *set,
                    ns_error *err)
{
    ns_context *ctx = test_context();
    ns_scene s = scene_of(c);
    ns_gpu_scene gs;
    int status = ns_scene_validate(&s, err);
    if (!status)
        status = ns_gpu_scene_build(&s, &gs, err);
    if (status)
        return status;
    gs.params.limits[0] = ctx->dev.loop_limited ? NS_LAVAPIPE_LOOP_BUDGET : 0;
    gpu_buffer_desc descs[NS_SCENE_BUFFER_COUNT];
    gpu_buffer bufs[NS_SCENE_BUFFER_COUNT];
    memset(bufs, 0, sizeof bufs);
    ns_gpu_scene_buffer_descs(&gs, descs);
    status = gpu_buffers_create(&ctx->dev, bufs, descs, NS_SCENE_BUFFER_COUNT, err);
    double t0 = ns_now_ms();
    if (!status)
        status = ns_vrl_generate(ctx, &s, &gs, bufs, paths, generate_chain, seed, set, err);
    last_generate_ms = ns_now_ms() - t0;
    for (int i = 0; i < NS_SCENE_BUFFER_COUNT; i++)
        gpu_buffer_destroy(&ctx->dev, &bufs[i]);
    ns_gpu_scene_free(&gs);
    return status;
}

static int generate_ok(const vrl_case *c, uint32_t paths, uint32_t seed, ns_vrl_set *set)
{
    ns_error err = {0};
    int status = generate(c, paths, seed, set, &err);
    if (status)
        fprintf(stderr, "ns_vrl_generate: %s (%s)\n", err.message, ns_status_name(status));
    CHECK_INT(status, NS_OK);
    CHECK_INT(set->paths, status ? 0 : paths);
    return status == NS_OK;
}

/* Sum of channel k of the VRLs of `material` (NS_NONE: all) and its 1-sigma bound. */
typedef struct power_sum {
    double total, sigma;
    uint32_t count;
} power_sum;

static power_sum sum_power(const ns_vrl_set *set, int k, uint32_t material)
{
    power_sum p = {0};
    double sq = 0;
    for (uint32_t i = 0; i < set->count; i++) {
        if (material != NS_NONE && set->vrls[i].material != material)
            continue;
        double x = set->vrls[i].power[k];
        p.total += x;
        sq += x * x;
        p.count++;
    }
    double n = (double)set->paths, mean = p.total / n;
    p.sigma = sqrt(n * fmax(0.0, sq / n - mean * mean));
    return p;
}

/* tight: the bound must be below this fraction of the answer (so it cannot hide an error
 * larger than that); 1% where the estimator's spread allows it at PATHS paths. */
static void check_total(const ns_vrl_set *set, int k, uint32_t material, double want, double tight)
{
    power_sum p = sum_power(set, k, material);
    fprintf(stderr, "    channel %d: %.6g W, expected %.6g, 4 sigma = %.3g (%.2f%%), %u VRLs\n", k,
            p.total, want, 4 * p.sigma, 400 * p.sigma / want, p.count);
    CHECK_NEAR(p.total, want, 4 * p.sigma + 1e-5 * want);
    CHECK(4 * p.sigma < tight * want);
}

static void sphere_medium(vrl_case *c, double ior, double radius)
{
    const double sigma_s[3] = {1, 2, 3}, sigma_a[3] = {0.1, 0.1, 0.1};
    c->materials[c->material_count] = medium(sigma_s, sigma_a, ior);
    snprintf(c->materials[c->material_count].name, NS_NAME_MAX, "m%u", c->material_count);
    c->objects[c->object_count++] = sphere(0, 0, 0, radius, c->material_count++);
}

/* One medium box of half extents `half` at the origin (c is cleared first). */
static void box_medium(vrl_case *c, const double half[3], const double sigma_s[3],
                       const double sigma_a[3], double ior)
{
    memset(c, 0, sizeof *c);
    c->materials[0] = medium(sigma_s, sigma_a, ior);
    c->material_count = 1;
    c->objects[0].shape = NS_SHAPE_BOX;
    set3(c->objects[0].min, -half[0], -half[1], -half[2]);
    set3(c->objects[0].max, half[0], half[1], half[2]);
    c->object_count = 1;
}

/* Origins on the sphere of `radius` at the origin; Snell's law between d_in and each
 * direction; length = the chord along it; unit directions; material and events. */
static void check_geometry(const ns_vrl_set *set, const double *d_in, double radius, double ior,
                           uint32_t material)
{
    uint32_t bad_origin = 0, bad_snell = 0, bad_length = 0, bad_fields = 0, bad_side = 0;
    for (uint32_t i = 0; i < set->count; i++) {
        const GpuVrl *v = &set->vrls[i];
        double n[3], d[3], r = 0, dn = 0, din_n = 0, unit = 0;
        for (int k = 0; k < 3; k++)
            r += (double)v->origin[k] * v->origin[k];
        r = sqrt(r);
        for (int k = 0; k < 3; k++) {
            n[k] = v->origin[k] / r;
            d[k] = v->direction[k];
            dn += d[k] * n[k];
            din_n += d_in[k] * n[k];
            unit += d[k] * d[k];
        }
        double sin_in = sqrt(fmax(0.0, 1 - din_n * din_n)), sin_out = sqrt(fmax(0.0, 1 - dn * dn));
        bad_origin += fabs(r - radius) > 1e-4 * radius;
        bad_snell += fabs(sin_in - ior * sin_out) > 2e-3;
        bad_side += !(dn < 0 && din_n < 0);
        bad_length += fabs(v->length - (-2 * radius * dn)) > 1e-3 * radius;
        bad_fields += v->material != material || v->events != 0 || fabs(unit - 1) > 1e-5;
    }
    CHECK(set->count > 0);
    CHECK_INT(bad_origin, 0);
    CHECK_INT(bad_snell, 0);
    CHECK_INT(bad_side, 0);
    CHECK_INT(bad_length, 0);
    CHECK_INT(bad_fields, 0);
}

/* ---------------------------------------------------------------------------------------
 * Tests
 * ------------------------------------------------------------------------------------- */
static const double E[3] = {2, 3, 0.5}; /* directional irradiance, W/m^2 */

static void directional_case(vrl_case *c, double ior)
{
    memset(c, 0, sizeof *c);
    sphere_medium(c, ior, 1.0);
    c->lights[0] = light(NS_LIGHT_DIRECTIONAL, E[0], E[1], E[2]);
    set3(c->lights[0].direction, 0.3, -1, 0.2);
    c->light_count = 1;
}

static void test_directional_fresnel(void)
{
    vrl_case c;
    directional_case(&c, 1.5);
    ns_vrl_set set = {0};
    if (!generate_ok(&c, PATHS, 1, &set))
        return;
    double t = sphere_transmittance(1.5);
    for (int k = 0; k < 3; k++)
        check_total(&set, k, 0, E[k] * M_PI * t, 0.01);
    double n = sqrt(0.09 + 1 + 0.04), d_in[3] = {0.3 / n, -1 / n, 0.2 / n};
    check_geometry(&set, d_in, 1.0, 1.5, 0);
    /* Every channel carries the same factor: power ratios equal the irradiance ratios. */
    uint32_t bad_ratio = 0;
    for (uint32_t i = 0; i < set.count; i++)
        bad_ratio += fabs(set.vrls[i].power[1] * E[0] - set.vrls[i].power[0] * E[1]) >
                     1e-5 * set.vrls[i].power[1] * E[0];
    CHECK_INT(bad_ratio, 0);
    ns_vrl_set_free(&set);
}

static void test_directional_index_matched(void)
{
    vrl_case c;
    directional_case(&c, 1.0);
    ns_vrl_set set = {0};
    if (!generate_ok(&c, PATHS, 2, &set))
        return;
    /* Every path hits the sphere and carries E pi R^2 / N: exact up to float sums. */
    CHECK_INT(set.count, PATHS);
    for (int k = 0; k < 3; k++)
        CHECK_REL(sum_power(&set, k, 0).total, E[k] * M_PI, 1e-4);
    double n = sqrt(0.09 + 1 + 0.04), d_in[3] = {0.3 / n, -1 / n, 0.2 / n};
    check_geometry(&set, d_in, 1.0, 1.0, 0);
    ns_vrl_set_free(&set);
}

/* The 12 triangles of the box [-half, half], counter-clockwise seen from outside: the face
 * of axis k and sign s spans axes u = k + 1 and v = k + 2 (cyclic), e_u x e_v = e_k. */
static void box_triangles(const double half[3], ns_triangle tris[12])
{
    int t = 0;
    for (int k = 0; k < 3; k++)
        for (int s = -1; s <= 1; s += 2) {
            int u = (k + 1) % 3, v = (k + 2) % 3;
            double corner[4][3];
            const double a[4] = {-1, 1, 1, -1}, b[4] = {-1, -1, 1, 1};
            for (int i = 0; i < 4; i++) {
                corner[i][k] = s * half[k];
                corner[i][u] = a[i] * half[u];
                corner[i][v] = b[i] * half[v];
            }
            /* (0, 1, 2) and (0, 2, 3) face +e_k; reversed for the face at -half[k]. */
            const int order[2][2][3] = {{{0, 2, 1}, {0, 3, 2}}, {{0, 1, 2}, {0, 2, 3}}};
            for (int h = 0; h < 2; h++, t++)
                for (int i = 0; i < 3; i++) {
                    const double *p = corner[order[s > 0][h][i]];
                    set3(tris[t].v[i], p[0], p[1], p[2]);
                }
        }
}

/* Defined below: the distance from p inside the box to its boundary along d. */
static double box_exit(const double half[3], const float p[3], const float d[3], double n[3]);

static void test_directional_box(void)
{
    /* A box, as a primitive and as a closed mesh: its bounding sphere is larger than it (paths
     * miss), and each face k lit at incidence cosine |d_k| takes E |d_k| area_k (1 - F(|d_k|)):
     * exact, no integral. */
    const double half[3] = {1, 0.5, 0.25}, d[3] = {0.3, -1, 0.2};
    double n = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    for (int variant = 0; variant < 3; variant++) {
        int glass = variant > 0, mesh = variant == 2;
        double ior = glass ? 1.5 : 1.0;
        vrl_case c;
        const double sigma_s[3] = {1, 1, 1}, sigma_a[3] = {0, 0, 0};
        box_medium(&c, half, sigma_s, sigma_a, ior);
        if (mesh) {
            box_triangles(half, c.triangles);
            c.triangle_count = 12;
            c.objects[0].shape = NS_SHAPE_MESH;
            c.objects[0].triangle_count = 12;
        }
        c.lights[0] = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
        set3(c.lights[0].direction, d[0], d[1], d[2]);
        c.light_count = 1;
        ns_vrl_set set = {0};
        if (!generate_ok(&c, 5 * PATHS, 8, &set))
            return;
        double want = 0;
        for (int k = 0; k < 3; k++) {
            double mu = fabs(d[k]) / n, area = 4 * half[(k + 1) % 3] * half[(k + 2) % 3];
            want += mu * area * (1 - (glass ? fresnel_in(mu, ior) : 0));
        }
        check_total(&set, 0, 0, want, 0.03);
        /* Origins on the lit faces, directions refracted about the face normal. */
        uint32_t off_face = 0, bad_snell = 0;
        for (uint32_t i = 0; i < set.count; i++) {
            const GpuVrl *v = &set.vrls[i];
            int face = -1, faces = 0; /* the lit face the origin lies on */
            for (int k = 0; k < 3; k++)
                if (fabs(fabs(v->origin[k]) - half[k]) < 1e-4) {
                    faces++;
                    if (v->origin[k] * d[k] < 0)
                        face = k;
                }
            off_face += face < 0;
            if (faces > 1)
                continue; /* on an edge the shader may take either face's normal */
            if (face < 0)
                continue;
            double mu_in = fabs(d[face]) / n, mu_out = fabs(v->direction[face]);
            bad_snell +=
                fabs(sqrt(1 - mu_in * mu_in) - ior * sqrt(fmax(0, 1 - mu_out * mu_out))) > 2e-3;
        }
        CHECK_INT(off_face, 0);
        CHECK_INT(bad_snell, 0);
        /* Each beam's length is the distance to the face it leaves through (closed form);
         * at ior 1.5 a beam may be followed by its reflection, which starts inside too. */
        uint32_t bad_length = 0;
        double worst = 0;
        for (uint32_t i = 0; i < set.count; i++) {
            const GpuVrl *v = &set.vrls[i];
            double n_exit[3];
            double want_len = box_exit(half, v->origin, v->direction, n_exit);
            double err = fabs(v->length - want_len);
            worst = fmax(worst, err);
            bad_length += err > 1e-3 * (1 + want_len);
        }
        if (bad_length)
            fprintf(stderr, "box variant %d: %u of %u beam lengths off (worst %g)\n", variant,
                    bad_length, set.count, worst);
        CHECK_INT(bad_length, 0);
        ns_vrl_set_free(&set);
    }
}

static double box_exit(const double half[3], const float p[3], const float d[3], double n[3])
{
    double best = INFINITY;
    int axis = 0;
    for (int k = 0; k < 3; k++) {
        if (d[k] == 0)
            continue;
        double t = ((d[k] > 0 ? half[k] : -half[k]) - p[k]) / d[k];
        if (t < best) {
            best = t;
            axis = k;
        }
    }
    n[0] = n[1] = n[2] = 0;
    n[axis] = d[axis] > 0 ? 1 : -1;
    return best;
}

/* Unpolarised Fresnel reflectance from inside ior into vacuum at incidence cosine mu; 1 past
 * the critical angle. */
static double fresnel_out(double mu, double ior)
{
    double sin2_t = ior * ior * (1 - mu * mu);
    if (sin2_t >= 1)
        return 1;
    double cos_t = sqrt(1 - sin2_t);
    double rs = (ior * mu - cos_t) / (ior * mu + cos_t);
    double rp = (mu - ior * cos_t) / (mu + ior * cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

static void test_internal_reflections(void)
{
    /* A tall box under a point light just above its top face: every beam enters the top and
     * meets a side wall beyond the critical angle (ior 1.5: 41.8 degrees; the walls are met at
     * 52 degrees or more). Each stretch after a path's first starts where the one before
     * ends, runs along its mirror image about that face's normal, carries its power times
     * e^{-sigma_t L} per channel and is as long as the box allows; a stretch ending beyond
     * the critical angle is always followed, one ending below it with the Fresnel
     * probability (a binomial count); at ior 1 none is. Following the beam changes nothing of
     * the first stretches (same seed, chain 1). */
    const double half[3] = {0.5, 3, 0.5};
    const double sigma_s[3] = {0.2, 0.3, 0.4}, sigma_a[3] = {0.05, 0.05, 0.05};
    for (int variant = 0; variant < 2; variant++) {
        double ior = variant ? 1.0 : 1.5;
        vrl_case c;
        box_medium(&c, half, sigma_s, sigma_a, ior);
        c.lights[0] = light(NS_LIGHT_POINT, 1, 1, 1);
        set3(c.lights[0].position, 0, half[1] + 0.3, 0);
        c.light_count = 1;
        ns_vrl_set set = {0}, first = {0};
        generate_chain = NS_VRL_MAX_CHAIN;
        int ok = generate_ok(&c, PATHS, 11, &set);
        generate_chain = 1;
        if (!ok || !generate_ok(&c, PATHS, 11, &first)) {
            ns_vrl_set_free(&set);
            return;
        }
        uint32_t bad_length = 0, bad_reflection = 0, bad_power = 0, missed_total = 0;
        uint32_t total_children = 0, partial_children = 0, deepest = 0, firsts = 0, bad_first = 0;
        uint32_t edge = 0;
        double partial_expected = 0, partial_variance = 0;
        uint32_t position = 0;
        for (uint32_t i = 0; i < set.count; i++) {
            const GpuVrl *v = &set.vrls[i];
            double n[3];
            double length = box_exit(half, v->origin, v->direction, n);
            /* A beam entering within the ray offset (3e-4 here) of an edge leaves before the
             * exit search starts: no exit (length 0, an endless beam) is the shader's answer. */
            int at_edge = length < 1e-3;
            edge += at_edge;
            bad_length += !at_edge && fabs(v->length - length) > 1e-3 * length + 1e-4;
            if (position == 0) {
                /* A first stretch: the same as with chain 1, in the same order. */
                bad_first += firsts >= first.count ||
                             memcmp(v, &first.vrls[firsts], sizeof *v) != 0;
                firsts++;
            }
            int child = 0;
            if (i + 1 < set.count) {
                const GpuVrl *w = &set.vrls[i + 1];
                double gap = 0;
                for (int k = 0; k < 3; k++) {
                    double end = v->origin[k] + (double)v->length * v->direction[k];
                    gap += (w->origin[k] - end) * (w->origin[k] - end);
                }
                child = sqrt(gap) < 2e-3;
            }
            double mu = v->direction[0] * n[0] + v->direction[1] * n[1] + v->direction[2] * n[2];
            double f = fresnel_out(mu, ior);
            if (child) {
                const GpuVrl *w = &set.vrls[i + 1];
                for (int k = 0; k < 3; k++) {
                    bad_reflection += fabs(w->direction[k] - (v->direction[k] - 2 * mu * n[k])) > 1e-4;
                    double want = v->power[k] * exp(-(sigma_s[k] + sigma_a[k]) * v->length);
                    bad_power += fabs(w->power[k] - want) > 1e-4 * want;
                }
                total_children += f >= 1;
                partial_children += f < 1;
            } else if (position + 1 < NS_VRL_MAX_CHAIN && !at_edge) {
                missed_total += f >= 1;
            }
            if (position + 1 < NS_VRL_MAX_CHAIN && f < 1 && !at_edge) {
                partial_expected += f;
                partial_variance += f * (1 - f);
            }
            position = child ? position + 1 : 0;
            deepest = position > deepest ? position : deepest;
        }
        fprintf(stderr,
                "  ior %.1f: %u stretches from %u first ones; followed: %u by total reflection, "
                "%u by Fresnel (expected %.1f); deepest chain %u\n",
                ior, set.count, firsts, total_children, partial_children, partial_expected,
                deepest + 1);
        CHECK_INT(firsts, first.count);
        CHECK_INT(bad_first, 0);
        CHECK_INT(bad_length, 0);
        CHECK(edge < set.count / 100);
        CHECK_INT(bad_reflection, 0);
        CHECK_INT(bad_power, 0);
        CHECK_INT(missed_total, 0);
        CHECK(fabs(partial_children - partial_expected) <= 4 * sqrt(partial_variance) + 1);
        if (ior == 1.0) {
            CHECK_INT(set.count, first.count);
        } else {
            CHECK(total_children > first.count / 2);
            CHECK_INT(deepest + 1, NS_VRL_MAX_CHAIN);
        }
        ns_vrl_set_free(&set);
        ns_vrl_set_free(&first);
    }
}

static void test_point_light(void)
{
    vrl_case c;
    memset(&c, 0, sizeof c);
    sphere_medium(&c, 1.5, 1.0);
    c.lights[0] = light(NS_LIGHT_POINT, 5, 4, 3);
    set3(c.lights[0].position, 0, 4, 0);
    c.light_count = 1;
    ns_vrl_set set = {0};
    if (!generate_ok(&c, PATHS, 3, &set))
        return;
    double cone = point_cone_transmittance(4, 1, 1.5);
    /* Sanity of the closed form: with ior 1 it is the cone's solid angle. */
    CHECK_REL(point_cone_transmittance(4, 1, 1.0), 2 * M_PI * (1 - sqrt(1 - 1 / 16.0)), 1e-9);
    check_total(&set, 0, 0, 5 * cone, 0.01);
    check_total(&set, 2, 0, 3 * cone, 0.01);
    uint32_t bad_snell = 0;
    for (uint32_t i = 0; i < set.count; i++) {
        const GpuVrl *v = &set.vrls[i];
        double din[3] = {v->origin[0], v->origin[1] - 4, v->origin[2]}, len = 0, cos_in = 0,
               cos_out = 0;
        for (int k = 0; k < 3; k++)
            len += din[k] * din[k];
        len = sqrt(len);
        for (int k = 0; k < 3; k++) {
            cos_in += din[k] / len * v->origin[k];
            cos_out += v->direction[k] * v->origin[k];
        }
        bad_snell += fabs(sqrt(fmax(0, 1 - cos_in * cos_in)) -
                          1.5 * sqrt(fmax(0, 1 - cos_out * cos_out))) > 2e-3;
    }
    CHECK_INT(bad_snell, 0);
    ns_vrl_set_free(&set);
}

static void test_environment_light(void)
{
    vrl_case c;
    memset(&c, 0, sizeof c);
    sphere_medium(&c, 1.5, 0.5);
    c.lights[0] = light(NS_LIGHT_ENVIRONMENT, 1, 0.5, 2);
    c.light_count = 1;
    ns_vrl_set set = {0};
    if (!generate_ok(&c, PATHS, 4, &set))
        return;
    /* Uniform radiance L on a sphere: L * pi * 4 pi R^2, times the Fresnel average. */
    double flux = 4 * M_PI * M_PI * 0.25 * sphere_transmittance(1.5);
    check_total(&set, 0, 0, 1 * flux, 0.01);
    check_total(&set, 2, 0, 2 * flux, 0.01);
    ns_vrl_set_free(&set);

    /* A diffuse ground plane below blocks every direction that travels upwards: exactly
     * half of the flux whatever the plane's distance. */
    c.materials[1] = diffuse(0.5, 0.5, 0.5);
    c.material_count = 2;
    c.objects[1] = plane(-3, 1);
    c.object_count = 2;
    if (!generate_ok(&c, PATHS, 4, &set))
        return;
    check_total(&set, 0, 0, 0.5 * flux, 0.04);
    ns_vrl_set_free(&set);
}

static void test_sphere_light(void)
{
    /* A small sphere light (radius 0.01 at distance 5) acts as a point of intensity
     * L pi r^2 (up to (r/d)^2 ~ 4e-6); index matched target: I times the cone's solid angle. */
    vrl_case c;
    memset(&c, 0, sizeof c);
    sphere_medium(&c, 1.0, 1.0);
    c.lights[0] = light(NS_LIGHT_SPHERE, 2e4, 1e4, 3e4);
    set3(c.lights[0].position, 5, 0, 0);
    c.lights[0].radius = 0.01f;
    c.light_count = 1;
    ns_vrl_set set = {0};
    if (!generate_ok(&c, PATHS, 5, &set))
        return;
    double omega = 2 * M_PI * (1 - sqrt(1 - 1 / 25.0)), area = M_PI * 1e-4;
    check_total(&set, 0, 0, 2e4 * area * omega, 0.04);
    check_total(&set, 1, 0, 1e4 * area * omega, 0.04);
    ns_vrl_set_free(&set);
}

/* The paths of one light and target are stratified (common.glsl, stratified4): the flux
 * they carry into an object that fills only part of the emission disk, or that each path
 * brings with another weight, is right to far better than independent paths could be. Over
 * sixteen seeds the error's root mean square, in standard errors of independent paths
 * (sum_power's sigma), is below 0.4: independent paths reach it about once in 100,000
 * (chi-square, 16 degrees of freedom, below 2.56); stratified ones measured 0.16-0.19. */
enum { STRATIFIED_SEEDS = 16 };

static void check_stratified(const char *name, const vrl_case *c, double want)
{
    double sq = 0;
    for (uint32_t seed = 1; seed <= STRATIFIED_SEEDS; seed++) {
        ns_vrl_set set = {0};
        if (!generate_ok(c, PATHS / 5, seed, &set))
            return;
        power_sum p = sum_power(&set, 0, 0);
        double z = (p.total - want) / p.sigma;
        sq += z * z / STRATIFIED_SEEDS;
        ns_vrl_set_free(&set);
    }
    fprintf(stderr, "    %s: rms error over %d seeds %.3f standard errors of independent paths\n",
            name, STRATIFIED_SEEDS, sqrt(sq));
    CHECK(sqrt(sq) < 0.4);
}

static void test_stratified_paths(void)
{
    /* A box under an oblique directional light (as test_directional_box, index matched):
     * paths from the disk that miss it carry nothing. */
    const double half[3] = {1, 0.5, 0.25}, d[3] = {0.3, -1, 0.2};
    double n = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]), want = 0;
    vrl_case c;
    const double sigma_s[3] = {1, 1, 1}, sigma_a[3] = {0, 0, 0};
    box_medium(&c, half, sigma_s, sigma_a, 1.0);
    c.lights[0] = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(c.lights[0].direction, d[0], d[1], d[2]);
    c.light_count = 1;
    for (int k = 0; k < 3; k++)
        want += fabs(d[k]) / n * 4 * half[(k + 1) % 3] * half[(k + 2) % 3];
    check_stratified("directional light, box", &c, want);

    /* A sphere light (radius 0.5, 4 away) and a unit sphere: each path's flux L cos A W
     * varies with its point and direction; the total is that of a point of intensity
     * L pi r^2 (the sphere-to-sphere view factor). */
    memset(&c, 0, sizeof c);
    sphere_medium(&c, 1.0, 1.0);
    c.lights[0] = light(NS_LIGHT_SPHERE, 1, 1, 1);
    set3(c.lights[0].position, 0, 0, -4);
    c.lights[0].radius = 0.5f;
    c.light_count = 1;
    check_stratified("sphere light, sphere", &c, M_PI * 0.25 * 2 * M_PI * (1 - sqrt(1 - 1.0 / 16.0)));
}

static void test_two_media_and_lights(void)
{
    /* Two spheres side by side (no shadowing) under a directional light and a point light
     * far above: each medium gets its own flux; the paths are shared by power. */
    vrl_case c;
    memset(&c, 0, sizeof c);
    const double sigma_s[3] = {1, 1, 1}, sigma_a[3] = {0, 0, 0};
    c.materials[0] = medium(sigma_s, sigma_a, 1.0);
    c.materials[1] = medium(sigma_s, sigma_a, 1.0);
    c.materials[2] = diffuse(0.5, 0.5, 0.5);
    c.material_count = 3;
    c.objects[0] = sphere(-2, 0, 0, 1, 0);
    c.objects[1] = sphere(3, 0, 0, 0.5, 1);
    c.objects[2] = sphere(0, 5, 0, 0.5, 2); /* a diffuse ball, off every light path */
    c.object_count = 3;
    c.lights[0] = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(c.lights[0].direction, 0, -1, 0);
    c.lights[1] = light(NS_LIGHT_POINT, 400, 400, 400);
    set3(c.lights[1].position, 0.5, 100, 0);
    c.light_count = 2;
    ns_vrl_set set = {0};
    if (!generate_ok(&c, PATHS, 6, &set))
        return;
    for (uint32_t m = 0; m < 2; m++) {
        double r = m ? 0.5 : 1.0, cx = m ? 3 : -2;
        double d2 = (cx - 0.5) * (cx - 0.5) + 100 * 100;
        double want = M_PI * r * r + 400 * 2 * M_PI * (1 - sqrt(1 - r * r / d2));
        /* The bound treats paths as independent draws; the systematic split over the
         * strata makes the real spread smaller, so it is loose here, not wrong. */
        check_total(&set, 0, m, want, 0.06);
    }
    ns_vrl_set_free(&set);
}

static void test_blocked(void)
{
    /* A diffuse sphere between a directional light and the medium casts a shadow: the
     * flux is E (pi R^2 - pi r^2) for a centred blocker smaller than the medium. */
    vrl_case c;
    memset(&c, 0, sizeof c);
    sphere_medium(&c, 1.0, 1.0);
    c.materials[1] = diffuse(0.5, 0.5, 0.5);
    c.material_count = 2;
    c.objects[1] = sphere(0, 3, 0, 0.5, 1);
    c.object_count = 2;
    c.lights[0] = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(c.lights[0].direction, 0, -1, 0);
    c.light_count = 1;
    ns_vrl_set set = {0};
    if (!generate_ok(&c, PATHS, 7, &set))
        return;
    check_total(&set, 0, 0, M_PI * (1 - 0.25), 0.03);
    uint32_t in_shadow = 0;
    for (uint32_t i = 0; i < set.count; i++)
        in_shadow += hypot(set.vrls[i].origin[0], set.vrls[i].origin[2]) < 0.499;
    CHECK_INT(in_shadow, 0);
    ns_vrl_set_free(&set);

    /* A glass (refracting, non-scattering) shell in the way: no caustics, nothing gets in. */
    const double none[3] = {0, 0, 0}, absorb[3] = {0.1, 0.1, 0.1};
    c.materials[1] = medium(none, absorb, 1.5);
    c.objects[1] = sphere(0, 4, 0, 2, 1); /* its shadow covers the whole medium */
    if (!generate_ok(&c, PATHS, 7, &set))
        return;
    CHECK_INT(set.count, 0);
    ns_vrl_set_free(&set);

    /* The same absorber index matched: light crosses it, attenuated by exp(-sigma_t chord). */
    c.materials[1] = medium(none, absorb, 1.0);
    c.objects[1] = sphere(0, 3, 0, 1.5, 1);
    if (!generate_ok(&c, PATHS, 7, &set))
        return;
    /* A ray at distance b from the axis crosses a chord 2 sqrt(1.5^2 - b^2), b <= 1:
     * integral over the unit disk of exp(-0.1 * chord). */
    double want = 0;
    const int n = 20000;
    for (int i = 0; i < n; i++) {
        double b = (i + 0.5) / n;
        want += exp(-0.2 * sqrt(2.25 - b * b)) * 2 * M_PI * b / n;
    }
    check_total(&set, 0, 0, want, 0.01);
    ns_vrl_set_free(&set);
}

static void test_deterministic(void)
{
    vrl_case c;
    directional_case(&c, 1.5);
    c.lights[1] = light(NS_LIGHT_ENVIRONMENT, 0.2, 0.2, 0.2);
    c.light_count = 2;
    ns_vrl_set a = {0}, b = {0}, other = {0};
    if (!generate_ok(&c, 5000, 11, &a) || !generate_ok(&c, 5000, 11, &b) ||
        !generate_ok(&c, 5000, 12, &other))
        goto done;
    CHECK_INT(a.count, b.count);
    CHECK(a.count == b.count && memcmp(a.vrls, b.vrls, sizeof *a.vrls * a.count) == 0);
    CHECK(other.count != a.count || memcmp(a.vrls, other.vrls, sizeof *a.vrls * a.count) != 0);
done:
    ns_vrl_set_free(&a);
    ns_vrl_set_free(&b);
    ns_vrl_set_free(&other);
}

static void test_grid_of_generated(void)
{
    /* The grid over real VRLs keeps every one and their total power. */
    vrl_case c;
    directional_case(&c, 1.5);
    ns_vrl_set set = {0};
    if (!generate_ok(&c, PATHS, 13, &set))
        return;
    ns_vrl_grid grid;
    ns_error err = {0};
    CHECK_INT(ns_vrl_grid_build(&set, 0, 0.1f, 0, &grid, &err), NS_OK);
    CHECK_INT(grid.vrl_count, set.count);
    double cells = 0;
    for (uint32_t i = 0; i < grid.cell_count; i++)
        cells += grid.representatives[i].power[0];
    CHECK_REL(cells, sum_power(&set, 0, 0).total, 1e-4);
    CHECK(grid.level_count >= 2 && grid.level_count <= 5 && grid.level < grid.level_count);
    ns_vrl_grid_free(&grid);
    ns_vrl_set_free(&set);
}

static void test_edge_cases(void)
{
    vrl_case c;
    directional_case(&c, 1.5);
    ns_vrl_set set = {0};
    ns_error err = {0};
    CHECK_INT(generate(&c, NS_MAX_VRLS + 1, 1, &set, &err), NS_ERR_LIMIT);
    CHECK_STR_CONTAINS(err.message, "render.vrls");
    CHECK(set.vrls == NULL && set.count == 0);

    /* No light: no VRL, no failure. */
    c.light_count = 0;
    if (generate_ok(&c, 1000, 1, &set))
        CHECK_INT(set.count, 0);
    ns_vrl_set_free(&set);

    /* A plane of scattering medium has no bounding sphere: refused, naming it. */
    directional_case(&c, 1.5);
    c.objects[1] = plane(-1, 0);
    c.object_count = 2;
    memset(&err, 0, sizeof err);
    CHECK_INT(generate(&c, 1000, 1, &set, &err), NS_ERR_NOT_AVAILABLE);
    CHECK_STR_CONTAINS(err.message, "objects[1]");

    /* The light points away: every path misses, nothing is stored. */
    directional_case(&c, 1.5);
    c.objects[0] = sphere(0, 0, 0, 1, 0);
    c.materials[1] = diffuse(1, 1, 1);
    c.material_count = 2;
    c.objects[1] = plane(2, 1); /* a ceiling between the light and the medium */
    c.object_count = 2;
    if (generate_ok(&c, 1000, 1, &set))
        CHECK_INT(set.count, 0);
    ns_vrl_set_free(&set);
}

/* Generation and grid times for 10k and 100k paths (NSCATTER_BENCH=1 only: not a timed
 * test): a glass-boundary sphere over a diffuse ground plane, directional + environment
 * light; generation is ns_vrl_generate alone (the scene buffers are already uploaded). */
static void sort5(double *v)
{
    for (int i = 0; i < 5; i++)
        for (int j = i + 1; j < 5; j++)
            if (v[j] < v[i]) {
                double t = v[i];
                v[i] = v[j];
                v[j] = t;
            }
}

static void bench(void)
{
    if (!getenv("NSCATTER_BENCH"))
        return;
    vrl_case c;
    directional_case(&c, 1.5);
    c.lights[1] = light(NS_LIGHT_ENVIRONMENT, 0.2, 0.2, 0.2);
    c.light_count = 2;
    c.materials[1] = diffuse(0.5, 0.5, 0.5);
    c.material_count = 2;
    c.objects[1] = plane(-1, 1);
    c.object_count = 2;
    uint32_t sizes[] = {10000, 100000};
    for (int s = 0; s < 2; s++) {
        double gen[5], grid_ms[5];
        uint32_t count = 0, cells = 0, level = 0;
        for (int r = 0; r < 5; r++) {
            ns_vrl_set set = {0};
            ns_error err = {0};
            CHECK_INT(generate(&c, sizes[s], (uint32_t)r, &set, &err), NS_OK);
            gen[r] = last_generate_ms;
            ns_vrl_grid grid;
            double t1 = ns_now_ms();
            /* mfp of the sphere's material: 1 / max sigma_t = 1 / 3.1 */
            CHECK_INT(ns_vrl_grid_build(&set, 0, 1.0f / 3.1f, 0, &grid, &err), NS_OK);
            grid_ms[r] = ns_now_ms() - t1;
            count = set.count;
            cells = grid.cell_count;
            level = grid.level;
            ns_vrl_grid_free(&grid);
            ns_vrl_set_free(&set);
        }
        sort5(gen);
        sort5(grid_ms);
        printf("bench: %u paths -> %u VRLs: generation median %.1f ms (min %.1f, max %.1f); "
               "grid median %.2f ms (min %.2f, max %.2f), level %u, %u cells\n",
               sizes[s], count, gen[2], gen[0], gen[4], grid_ms[2], grid_ms[0], grid_ms[4], level,
               cells);
    }
}

int main(void)
{
    RUN(test_directional_fresnel);
    RUN(test_directional_index_matched);
    RUN(test_directional_box);
    RUN(test_internal_reflections);
    RUN(test_point_light);
    RUN(test_environment_light);
    RUN(test_sphere_light);
    RUN(test_stratified_paths);
    RUN(test_two_media_and_lights);
    RUN(test_blocked);
    RUN(test_deterministic);
    RUN(test_grid_of_generated);
    RUN(test_edge_cases);
    RUN(bench);
    ns_context_destroy(test_context());
    return harness_report();
}
