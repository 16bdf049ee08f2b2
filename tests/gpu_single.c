/* gpu_single.c — single scattering (render/single.c, shaders/single.comp) against closed
 * forms, on camera segments built directly in a wide slab (a box, top face y = 1):
 *   - directional light, index matched: sigma_s p E e^{-sigma_t h0/c} (1 - e^{-aL}) / a;
 *   - the same with ior 1.5: Snell, Fresnel, cos_i/cos_t and the refracted path length are
 *     exact for the planar top face, so the same form holds with the refracted quantities;
 *   - RGB coefficients throughout (each channel its own closed form);
 *   - a point light (index matched: a 1D quadrature of the exact integrand in double; ior
 *     1.5: a far point light of intensity E d^2 equals the directional closed form);
 *   - a sphere light equals a point light of intensity L pi r^2;
 *   - shadowing by a diffuse occluder (half-shadowed segments: the closed form up to the
 *     shadow edge; fully shadowed: 0);
 *   - a constant environment seen from the centre of a sphere (every direction meets the
 *     boundary at normal incidence): sigma_s n^2 (1 - F0) L_env e^{-sigma_t R} ...;
 *   - bad arguments give clear errors;
 *   - the renderer's order for the GPU: most strata first, ties in their order.
 * NSCATTER_BENCH=1 also times 128x128 and 512x512 segment sets (100 samples, one light). */
#include "gpu_util.h"
#include "scatter.h"

/* Runs ns_single_scatter on n segments; out[i] = RGB of segment i. Returns the status, and
 * checks it: a caller that gives up on a failure still counts as failed, with the error's
 * message printed (device_scene_make checks its own part). */
static int run_single(const ns_scene *s, const GpuSegment *segments, uint32_t n, uint32_t samples,
                      float (*out)[4], double *ms)
{
    ns_context *ctx = test_context();
    ns_error err = {0};
    device_scene d;
    int status = device_scene_make(s, &d);
    if (status) {
        device_scene_free(&d);
        return status;
    }
    gpu_buffer seg = {0}, result = {0};
    status = gpu_buffer_create(&ctx->dev, &seg,
                               &(gpu_buffer_desc){.size = sizeof *segments * n,
                                                  .data = segments,
                                                  .data_size = sizeof *segments * n,
                                                  .label = "test.segments"},
                               &err);
    if (!status)
        status =
            gpu_buffer_create(&ctx->dev, &result,
                              &(gpu_buffer_desc){.size = 16ull * n, .label = "test.single"}, &err);
    if (!status) {
        double t0 = ns_now_ms();
        status = ns_single_scatter(ctx, d.buffers, &seg, n, samples, &result, &err);
        if (ms)
            *ms = ns_now_ms() - t0;
    }
    if (!status)
        memcpy(out, result.mapped, 16ull * n);
    else
        fprintf(stderr, "ns_single_scatter: %s (%s)\n", err.message, ns_status_name(status));
    CHECK_INT(status, NS_OK);
    gpu_buffer_destroy(&ctx->dev, &seg);
    gpu_buffer_destroy(&ctx->dev, &result);
    device_scene_free(&d);
    return status;
}

/* ---------------------------------------------------------------------------------------
 * The slab and its segments.
 * ------------------------------------------------------------------------------------- */
static const double SIGMA_S[3] = {0.3, 0.8, 1.5}, SIGMA_A[3] = {0.2, 0.1, 0.6};
static const double G = 0.3;
static const double TOP = 1.0;

/* MAT_GLASS: a refracting medium that does not scatter much, the occluder of
 * test_refracting_occluder. */
enum { MAT_MEDIUM, MAT_DIFFUSE, MAT_GLASS, MAT_COUNT };
static const double GLASS_SIGMA_S[3] = {0.1, 0.2, 0.3}, GLASS_SIGMA_A[3] = {0.5, 0.2, 0.05};

typedef struct slab {
    ns_material materials[MAT_COUNT];
    ns_object objects[3];
    ns_light lights[2];
    ns_scene scene;
} slab;

static void make_slab(slab *s, double ior, ns_light light)
{
    memset(s, 0, sizeof *s);
    s->materials[MAT_MEDIUM] = medium(SIGMA_S, SIGMA_A, ior);
    s->materials[MAT_MEDIUM].g = (float)G;
    s->materials[MAT_DIFFUSE] = diffuse(0.5, 0.5, 0.5);
    s->materials[MAT_GLASS] = medium(GLASS_SIGMA_S, GLASS_SIGMA_A, 1.5);
    s->objects[0] = cuboid(-50, 0, -50, 50, TOP, 50, MAT_MEDIUM);
    s->lights[0] = light;
    s->scene = base_scene(16, 16, 60);
    s->scene.materials = s->materials;
    s->scene.material_count = MAT_COUNT;
    s->scene.objects = s->objects;
    s->scene.object_count = 1;
    s->scene.lights = s->lights;
    s->scene.light_count = 1;
}

static GpuSegment segment(double ex, double ey, double ez, double dx, double dy, double dz,
                          double length)
{
    GpuSegment g;
    memset(&g, 0, sizeof g);
    double n = sqrt(dx * dx + dy * dy + dz * dz);
    set3(g.entry, ex, ey, ez);
    set3(g.direction, dx / n, dy / n, dz / n);
    set3(g.exit, ex + length * dx / n, ey + length * dy / n, ez + length * dz / n);
    set3(g.throughput, 1, 1, 1);
    g.material = MAT_MEDIUM;
    return g;
}

/* Segments from the top face down to the bottom at several angles, one that starts and
 * ends inside, and one going up. */
enum { SLAB_SEGMENTS = 5 };
static void slab_segments(GpuSegment *out)
{
    out[0] = segment(0, TOP, 0, 0, -1, 0, TOP);
    out[1] = segment(1, TOP, -2, 0.4, -1, 0.3, TOP * sqrt(1.25));
    out[2] = segment(-3, TOP, 2, -1.2, -1, 0.2, TOP * sqrt(1 + 1.44 + 0.04));
    out[3] = segment(2, 0.7, 1, 0.3, -1, -0.6, 0.5);
    out[4] = segment(-1, 0.1, -1, 0.5, 1, 0.2, 0.8);
}

/* Samples per segment of the closed-form checks: the lights other than the environment take
 * one point per 4 of them (single.comp's LIGHT_STRIDE), so 400 strata of the distance CDF,
 * each with one jittered point: the smooth integrands come out within about 1e-4. */
#define CLOSED_FORM_SAMPLES 1600u

/* ---------------------------------------------------------------------------------------
 * Closed forms (double precision, derived independently of the shader).
 * ------------------------------------------------------------------------------------- */
static double dot3d(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static double hg(double cos_theta, double g)
{
    double denom = 1 + g * g - 2 * g * cos_theta;
    return (1 - g * g) / (4 * M_PI * denom * sqrt(denom));
}

/* Unpolarised Fresnel reflectance from n1 into n2 at incidence cos_i; cos_t out; 1 on TIR. */
static double fresnel_d(double cos_i, double n1, double n2, double *cos_t)
{
    double sin_t = n1 / n2 * sqrt(fmax(0, 1 - cos_i * cos_i));
    if (sin_t >= 1) {
        *cos_t = 0;
        return 1;
    }
    *cos_t = sqrt(1 - sin_t * sin_t);
    double rs = (n1 * cos_i - n2 * *cos_t) / (n1 * cos_i + n2 * *cos_t);
    double rp = (n2 * cos_i - n1 * *cos_t) / (n2 * cos_i + n1 * *cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

/* A directional light (unit travel direction `dir`, irradiance E) through the top face of
 * ior `ior`: the in-medium travel direction, the factor (1 - F) cos_i / cos_t and the
 * cosine c of that direction with the face normal (path to the face = depth / c). */
static void refract_top(const double dir[3], double ior, double travel[3], double *factor,
                        double *c)
{
    double cos_i = -dir[1];
    if (ior == 1) {
        memcpy(travel, dir, sizeof(double) * 3);
        *factor = 1;
        *c = cos_i;
        return;
    }
    double cos_t;
    double f = fresnel_d(cos_i, 1, ior, &cos_t);
    double eta = 1 / ior;
    double n[3] = {0, 1, 0};
    for (int k = 0; k < 3; k++)
        travel[k] = eta * dir[k] + (eta * cos_i - cos_t) * n[k];
    *factor = (1 - f) * cos_i / cos_t;
    *c = cos_t;
}

/* sigma_s p E factor int_0^len e^{-st t} e^{-st h(t)/c} dt, h(t) = h0 - t d_y. */
static double slab_directional(const GpuSegment *seg, double len, const double dir[3], double ior,
                               double e, int channel)
{
    double st = SIGMA_S[channel] + SIGMA_A[channel];
    double d[3] = {seg->direction[0], seg->direction[1], seg->direction[2]};
    double travel[3], factor, c;
    refract_top(dir, ior, travel, &factor, &c);
    double wo[3] = {-d[0], -d[1], -d[2]};
    double h0 = TOP - seg->entry[1];
    double a = st * (1 - d[1] / c);
    double integral = fabs(a) < 1e-12 ? len : -expm1(-a * len) / a;
    return SIGMA_S[channel] * hg(dot3d(travel, wo), G) * e * factor * exp(-st * h0 / c) * integral;
}

static double seg_length(const GpuSegment *s)
{
    double d[3] = {s->exit[0] - s->entry[0], s->exit[1] - s->entry[1], s->exit[2] - s->entry[2]};
    return sqrt(dot3d(d, d));
}

static ns_light directional(const double dir[3], const double e[3])
{
    ns_light l = light(NS_LIGHT_DIRECTIONAL, e[0], e[1], e[2]);
    set3(l.direction, dir[0], dir[1], dir[2]);
    return l;
}

static const double E_RGB[3] = {1.0, 2.0, 3.0};

static void unit(double v[3])
{
    double n = sqrt(dot3d(v, v));
    for (int k = 0; k < 3; k++)
        v[k] /= n;
}

/* The slab under the directional light most checks use: E_RGB travelling along
 * (0.35, -1, -0.2) normalised, which is written to dir. */
static void lit_slab(slab *s, double ior, double dir[3])
{
    dir[0] = 0.35;
    dir[1] = -1;
    dir[2] = -0.2;
    unit(dir);
    make_slab(s, ior, directional(dir, E_RGB));
}

/* ---------------------------------------------------------------------------------------
 * Tests
 * ------------------------------------------------------------------------------------- */
static void check_directional(double ior)
{
    double dir[3];
    slab s;
    lit_slab(&s, ior, dir);
    GpuSegment segs[SLAB_SEGMENTS];
    slab_segments(segs);
    float out[SLAB_SEGMENTS][4];
    if (run_single(&s.scene, segs, SLAB_SEGMENTS, CLOSED_FORM_SAMPLES, out, NULL))
        return;
    for (int i = 0; i < SLAB_SEGMENTS; i++)
        for (int c = 0; c < 3; c++)
            CHECK_REL(out[i][c],
                      slab_directional(&segs[i], seg_length(&segs[i]), dir, ior, E_RGB[c], c),
                      1e-3);
}

static void test_directional_index_matched(void)
{
    check_directional(1.0);
}
static void test_directional_refracted(void)
{
    check_directional(1.5);
}

/* Light at 60 degrees from the normal through ior 1.33: a second angle and index, and the
 * result must differ from the index-matched one (refraction is not passing by accident). */
static void test_directional_refracted_oblique(void)
{
    double dir[3] = {sin(60 * M_PI / 180), -cos(60 * M_PI / 180), 0};
    slab s;
    make_slab(&s, 1.33, directional(dir, E_RGB));
    GpuSegment segs[SLAB_SEGMENTS];
    slab_segments(segs);
    float out[SLAB_SEGMENTS][4];
    if (run_single(&s.scene, segs, SLAB_SEGMENTS, CLOSED_FORM_SAMPLES, out, NULL))
        return;
    double differs = 0, total = 0;
    for (int i = 0; i < SLAB_SEGMENTS; i++)
        for (int c = 0; c < 3; c++) {
            double want = slab_directional(&segs[i], seg_length(&segs[i]), dir, 1.33, E_RGB[c], c);
            double matched =
                slab_directional(&segs[i], seg_length(&segs[i]), dir, 1.0, E_RGB[c], c);
            CHECK_REL(out[i][c], want, 1e-3);
            differs += fabs(out[i][c] - matched);
            total += want;
        }
    fprintf(stderr, "  refraction changes the result by %.1f%% on average\n",
            100 * differs / total);
    CHECK(differs > 0.05 * total);
}

/* Index matched, point light at P above the slab: Simpson's rule on the exact integrand. */
static double slab_point(const GpuSegment *seg, const double p[3], double intensity, int channel)
{
    double st = SIGMA_S[channel] + SIGMA_A[channel];
    double len = seg_length(seg);
    const int n = 20000; /* even */
    double sum = 0;
    for (int i = 0; i <= n; i++) {
        double t = len * i / n;
        double x[3], v[3];
        for (int k = 0; k < 3; k++) {
            x[k] = seg->entry[k] + t * seg->direction[k];
            v[k] = p[k] - x[k];
        }
        double r = sqrt(dot3d(v, v));
        double inside = (TOP - x[1]) * r / v[1]; /* along the line to the top face */
        /* travel direction -v/r against wo = -d */
        double cos_theta =
            (v[0] * seg->direction[0] + v[1] * seg->direction[1] + v[2] * seg->direction[2]) / r;
        double f =
            SIGMA_S[channel] * hg(cos_theta, G) * intensity / (r * r) * exp(-st * (t + inside));
        sum += f * (i == 0 || i == n ? 1 : i % 2 ? 4 : 2);
    }
    return sum * len / n / 3;
}

/* A point light of unit intensity at p above the slab's ior-`ior` top face, seen from x
 * inside through that flat face exactly (planar_refracted_point, gpu_util.h): returns the
 * refracted pencil's irradiance at x; *cos_theta is the cosine between the light's direction
 * inside and -d (the segment's), *path_in the refracted path's length inside, rp the
 * refraction point. */
static double flat_face_point(const double x[3], const double p[3], double ior,
                              const GpuSegment *seg, double *cos_theta, double *path_in,
                              double rp[3])
{
    double a = p[1] - TOP, h = TOP - x[1];
    double across[3] = {p[0] - x[0], 0, p[2] - x[2]};
    double r = sqrt(dot3d(across, across)), cos_t, tan_t;
    double e = planar_refracted_point(a, h, r, ior, &cos_t, &tan_t);
    rp[0] = x[0] + (r > 0 ? across[0] / r : 0) * h * tan_t;
    rp[1] = TOP;
    rp[2] = x[2] + (r > 0 ? across[2] / r : 0) * h * tan_t;
    double travel[3] = {x[0] - rp[0], x[1] - rp[1], x[2] - rp[2]},
           len_in = sqrt(dot3d(travel, travel));
    double d[3] = {seg->direction[0], seg->direction[1], seg->direction[2]};
    /* At the face itself the light travels straight down, -n: cos = dot(-n, -d) = d_y. */
    *cos_theta = len_in > 0 ? -dot3d(travel, d) / len_in : d[1];
    *path_in = h / cos_t;
    return e;
}

/* sigma_s p E ... for a point light of `intensity` at p above the slab's ior-`ior` top face,
 * through that flat face exactly (planar_refracted_point, gpu_util.h): at each point x of the
 * segment the refraction point, the refracted pencil's irradiance, the attenuation along
 * the refracted path and the phase between its direction and -d; Simpson along the segment. */
static double slab_point_refracted(const GpuSegment *seg, const double p[3], double intensity,
                                   double ior, int channel)
{
    double st = SIGMA_S[channel] + SIGMA_A[channel];
    double len = seg_length(seg);
    const int n = 4000; /* even */
    double sum = 0;
    for (int i = 0; i <= n; i++) {
        double t = len * i / n, x[3];
        for (int k = 0; k < 3; k++)
            x[k] = seg->entry[k] + t * seg->direction[k];
        double cos_theta, path_in, unused[3];
        double e = intensity * flat_face_point(x, p, ior, seg, &cos_theta, &path_in, unused);
        double f = SIGMA_S[channel] * hg(cos_theta, G) * e * exp(-st * (t + path_in));
        sum += f * (i == 0 || i == n ? 1 : i % 2 ? 4 : 2);
    }
    return sum * len / n / 3;
}

/* A point light of intensity (4, 8, 12) at p over the slab of ior `ior`: index matched,
 * the straight-line quadrature; refracting, the flat-face solution (slab_point_refracted). */
static void check_point_light(double ior, const double p[3], double tolerance)
{
    slab s;
    ns_light l = light(NS_LIGHT_POINT, 4, 8, 12);
    set3(l.position, p[0], p[1], p[2]);
    make_slab(&s, ior, l);
    GpuSegment segs[SLAB_SEGMENTS];
    slab_segments(segs);
    float out[SLAB_SEGMENTS][4];
    if (run_single(&s.scene, segs, SLAB_SEGMENTS, CLOSED_FORM_SAMPLES, out, NULL))
        return;
    for (int i = 0; i < SLAB_SEGMENTS; i++)
        for (int c = 0; c < 3; c++)
            CHECK_REL(out[i][c],
                      ior == 1.0 ? slab_point(&segs[i], p, 4.0 * (c + 1), c)
                                 : slab_point_refracted(&segs[i], p, 4.0 * (c + 1), ior, c),
                      tolerance);
}

static void test_point_index_matched(void)
{
    check_point_light(1.0, (double[3]){0.5, 3.0, -0.4}, 1e-3);
}

/* ior 1.5, a point light 1e5 away along -dir with intensity E d^2: the directional form. */
static void test_point_far_refracted(void)
{
    double dir[3] = {0.35, -1, -0.2};
    unit(dir);
    const double far = 1e5;
    ns_light l =
        light(NS_LIGHT_POINT, E_RGB[0] * far * far, E_RGB[1] * far * far, E_RGB[2] * far * far);
    set3(l.position, -far * dir[0], TOP - far * dir[1], -far * dir[2]);
    slab s;
    make_slab(&s, 1.5, l);
    GpuSegment segs[SLAB_SEGMENTS];
    slab_segments(segs);
    float out[SLAB_SEGMENTS][4];
    if (run_single(&s.scene, segs, SLAB_SEGMENTS, CLOSED_FORM_SAMPLES, out, NULL))
        return;
    for (int i = 0; i < SLAB_SEGMENTS; i++)
        for (int c = 0; c < 3; c++)
            CHECK_REL(out[i][c],
                      slab_directional(&segs[i], seg_length(&segs[i]), dir, 1.5, E_RGB[c], c),
                      1e-3);
}


/* ior 1.5, a point light 3 above the face: the refracted pencil keeps diverging inside (the
 * far light's directional form no longer holds). The shader takes the face as the plane it
 * is, so it must equal the flat-face solution. */
static void test_point_near_refracted(void)
{
    check_point_light(1.5, (double[3]){0.5, TOP + 3.0, -0.4}, 3e-4);
}

/* A small sphere light equals a point light of intensity L pi r^2 (the irradiance of a
 * fully visible sphere is exact; the cone's spread changes phase and path only slightly). */
static void test_sphere_light(void)
{
    double p[3] = {0.5, 3.0, -0.4}, r = 0.05, radiance = 100;
    ns_light l = light(NS_LIGHT_SPHERE, radiance, 2 * radiance, 3 * radiance);
    set3(l.position, p[0], p[1], p[2]);
    l.radius = (float)r;
    GpuSegment segs[SLAB_SEGMENTS];
    slab_segments(segs);
    float sphere_out[SLAB_SEGMENTS][4], point_out[SLAB_SEGMENTS][4];
    slab s;
    make_slab(&s, 1.0, l);
    if (run_single(&s.scene, segs, SLAB_SEGMENTS, CLOSED_FORM_SAMPLES, sphere_out, NULL))
        return;
    for (int i = 0; i < SLAB_SEGMENTS; i++)
        for (int c = 0; c < 3; c++)
            CHECK_REL(sphere_out[i][c],
                      slab_point(&segs[i], p, radiance * (c + 1) * M_PI * r * r, c), 2e-3);
    /* Refracting boundary: the same equivalence through the shader's planar model. */
    make_slab(&s, 1.5, l);
    if (run_single(&s.scene, segs, SLAB_SEGMENTS, 40 * CLOSED_FORM_SAMPLES, sphere_out, NULL))
        return;
    ns_light pl = light(NS_LIGHT_POINT, radiance * M_PI * r * r, 2 * radiance * M_PI * r * r,
                        3 * radiance * M_PI * r * r);
    set3(pl.position, p[0], p[1], p[2]);
    make_slab(&s, 1.5, pl);
    if (run_single(&s.scene, segs, SLAB_SEGMENTS, CLOSED_FORM_SAMPLES, point_out, NULL))
        return;
    for (int i = 0; i < SLAB_SEGMENTS; i++)
        for (int c = 0; c < 3; c++) {
            CHECK_REL(sphere_out[i][c], point_out[i][c], 2e-3);
            CHECK(point_out[i][c] > 0);
        }
}

/* sigma_s p E ... for a sphere light of radiance `radiance` (centre c, radius r) close above
 * the slab's ior-`ior` top face, into out[3] per channel: every point y of its surface (a
 * midpoint grid over theta and phi) is a point light of intensity L cos_r dA towards the
 * refraction point, cos_r its cosine there (0 where y faces away), through the flat face
 * exactly (planar_refracted_point); Simpson along the segment. */
static void slab_sphere_refracted(const GpuSegment *seg, const double c[3], double r,
                                  const double radiance[3], double ior, double out[3])
{
    enum { N_THETA = 40, N_PHI = 80, N = 20 /* even */ };
    double len = seg_length(seg);
    out[0] = out[1] = out[2] = 0;
    for (int i = 0; i <= N; i++) {
        double t = len * i / N, x[3], simpson = (i == 0 || i == N ? 1 : i % 2 ? 4 : 2);
        for (int k = 0; k < 3; k++)
            x[k] = seg->entry[k] + t * seg->direction[k];
        for (int a_i = 0; a_i < N_THETA; a_i++)
            for (int b_i = 0; b_i < N_PHI; b_i++) {
                double theta = M_PI * (a_i + 0.5) / N_THETA, phi = 2 * M_PI * (b_i + 0.5) / N_PHI;
                double m[3] = {sin(theta) * cos(phi), cos(theta), sin(theta) * sin(phi)};
                double y[3] = {c[0] + r * m[0], c[1] + r * m[1], c[2] + r * m[2]};
                double area = r * r * sin(theta) * (M_PI / N_THETA) * (2 * M_PI / N_PHI);
                double cos_theta, path_in, rp[3];
                double e = flat_face_point(x, y, ior, seg, &cos_theta, &path_in, rp);
                double out_dir[3] = {rp[0] - y[0], rp[1] - y[1], rp[2] - y[2]};
                double cos_r = dot3d(m, out_dir) / sqrt(dot3d(out_dir, out_dir));
                if (!(cos_r > 0))
                    continue;
                for (int ch = 0; ch < 3; ch++) {
                    double st = SIGMA_S[ch] + SIGMA_A[ch];
                    out[ch] += simpson * SIGMA_S[ch] * hg(cos_theta, G) * radiance[ch] * cos_r *
                               area * e * exp(-st * (t + path_in));
                }
            }
    }
    for (int ch = 0; ch < 3; ch++)
        out[ch] *= len / N / 3;
}

/* A sphere light of radius 0.4 whose bottom is 0.1 above the refracting top face: light
 * reaches a point inside from a ring of the sphere that the cone seen from the face does not
 * contain, and each of its points diverges from its own place, not from the centre. The
 * shader (single.glsl, sphere_refracted) draws its points in the cone seen from x and
 * weighs each by its own cosine towards the refraction point: it must equal the surface
 * integral of the flat-face solution. Taken as a point at the centre's distance in a
 * direction drawn from the face (before 2026-12-02) the straight-down segment read 7% high. */
static void test_sphere_near_refracted(void)
{
    const double c[3] = {0.3, TOP + 0.5, -0.2}, r = 0.4, radiance[3] = {10, 20, 30};
    ns_light l = light(NS_LIGHT_SPHERE, radiance[0], radiance[1], radiance[2]);
    set3(l.position, c[0], c[1], c[2]);
    l.radius = (float)r;
    slab s;
    make_slab(&s, 1.5, l);
    GpuSegment segs[SLAB_SEGMENTS];
    slab_segments(segs);
    float out[SLAB_SEGMENTS][4];
    if (run_single(&s.scene, segs, SLAB_SEGMENTS, 40 * CLOSED_FORM_SAMPLES, out, NULL))
        return;
    for (int i = 0; i < SLAB_SEGMENTS; i++) {
        double want[3];
        slab_sphere_refracted(&segs[i], c, r, radiance, 1.5, want);
        printf("  segment %d: %.4f / %.4f / %.4f of the surface integral\n", i, out[i][0] / want[0],
               out[i][1] / want[1], out[i][2] / want[2]);
        for (int ch = 0; ch < 3; ch++)
            CHECK_REL(out[i][ch], want[ch], 0.025);
    }
}

/* A diffuse occluder over x < 0 (y in [2, 2.5]) and light straight down: a segment from
 * x = 0.3 to x = -0.3 is lit over its first half exactly, one at x = -5 is dark, one at
 * x = 5 is fully lit. The shadow's edge falls inside one of the lights' 400 strata of the
 * distance CDF (single.comp), whose one jittered point is lit or not: that stratum's share,
 * about 1/400 of the whole segment's light (1/200 of the half), is the tolerance of the half. */
/* The slab of make_slab under a plate of `material` over x < 0, y in [2, 2.5]. */
static void make_slab_half_covered(slab *s, double ior, ns_light light, uint32_t material)
{
    make_slab(s, ior, light);
    s->objects[1] = cuboid(-50, 2, -50, 0, 2.5, 50, material);
    s->scene.object_count = 2;
}

static void check_shadow(double ior)
{
    double dir[3] = {0, -1, 0};
    slab s;
    make_slab_half_covered(&s, ior, directional(dir, E_RGB), MAT_DIFFUSE);
    GpuSegment segs[3] = {
        segment(0.3, TOP, 0, -0.6, -TOP, 0, sqrt(0.36 + TOP * TOP)),
        segment(-5, TOP, 0, 0.2, -1, 0, sqrt(1.04)),
        segment(5, TOP, 0, 0.2, -1, 0, sqrt(1.04)),
    };
    float out[3][4];
    if (run_single(&s.scene, segs, 3, CLOSED_FORM_SAMPLES, out, NULL))
        return;
    for (int c = 0; c < 3; c++) {
        double half = slab_directional(&segs[0], seg_length(&segs[0]) / 2, dir, ior, E_RGB[c], c);
        CHECK_REL(out[0][c], half, 5e-3);
        CHECK_INT(out[1][c] == 0.0f, 1);
        CHECK_REL(out[2][c],
                  slab_directional(&segs[2], seg_length(&segs[2]), dir, ior, E_RGB[c], c), 1e-3);
    }
}

static void test_shadow_index_matched(void)
{
    check_shadow(1.0);
}
static void test_shadow_refracted(void)
{
    check_shadow(1.5);
}

/* A refracting occluder: a plate of MAT_GLASS (ior 1.5, 0.5 thick, faces parallel to the
 * slab's) over x < 0, the directional light at 0 and 60 degrees. Single scattering's shadow
 * rays cross refracting boundaries straight on (common.glsl, SHADOW_THROUGH_REFRACTING),
 * which through parallel faces is exact: a segment under the plate gets the slab's closed
 * form times (1 - F)^2 e^{-sigma_t 0.5 / cos_t}, F and cos_t of the light's angle at the
 * plate; one beside it the closed form alone. Before, the plate cast a black shadow. */
static void check_refracting_occluder(double ior, double angle_deg)
{
    double a = angle_deg * M_PI / 180, dir[3] = {sin(a), -cos(a), 0};
    slab s;
    make_slab_half_covered(&s, ior, directional(dir, E_RGB), MAT_GLASS);
    GpuSegment segs[2] = {
        segment(-5, TOP, 0, 0.2, -1, 0, sqrt(1.04)),
        segment(5, TOP, 0, 0.2, -1, 0, sqrt(1.04)),
    };
    float out[2][4];
    if (run_single(&s.scene, segs, 2, CLOSED_FORM_SAMPLES, out, NULL))
        return;
    double cos_t;
    double f = fresnel_d(cos(a), 1, 1.5, &cos_t);
    for (int c = 0; c < 3; c++) {
        double plate_t = (1 - f) * (1 - f) * exp(-(GLASS_SIGMA_S[c] + GLASS_SIGMA_A[c]) * 0.5 / cos_t);
        double open = slab_directional(&segs[0], seg_length(&segs[0]), dir, ior, E_RGB[c], c);
        CHECK_REL(out[0][c], open * plate_t, 1e-3);
        CHECK_REL(out[1][c],
                  slab_directional(&segs[1], seg_length(&segs[1]), dir, ior, E_RGB[c], c), 1e-3);
    }
}

static void test_refracting_occluder(void)
{
    check_refracting_occluder(1.0, 0);
    check_refracting_occluder(1.5, 0);
    check_refracting_occluder(1.0, 60);
    check_refracting_occluder(1.5, 60);
}

/* A short segment through the centre of a sphere (R = 1) under a constant environment: every
 * direction from (near) the centre meets the boundary at normal incidence after R, so the
 * in-scattered radiance is sigma_s n^2 (1 - F0) L_env e^{-sigma_t R} whatever the phase
 * function (n^2 (1 - F0) -> 1 when index matched), and with ior != 1 the part reflected there
 * crosses the centre to the opposite face, where (1 - F0) of it leaves: the sum over the
 * reflections divides that by 1 - F0 e^{-2 sigma_t R} (+3.7% here; a single.comp that stops
 * at the first face fails). The ray leaves or reflects by a coin weighted by F0, so ior 1.5
 * takes more samples and a tolerance of about 4 standard errors (the coin's noise is F0 of the
 * 10% that the opposite face's value differs by, 1.3e-3 at 256 samples). Small sigma_t keeps
 * the off-centre spread below 1e-3. */
static void check_environment(double ior, uint32_t samples, double tolerance)
{
    const double ss[3] = {0.01, 0.02, 0.04}, sa[3] = {0.01, 0.03, 0.005};
    ns_material m = medium(ss, sa, ior);
    m.g = 0.6f;
    ns_object ball = sphere(0, 0, 0, 1, 0);
    ns_light env = light(NS_LIGHT_ENVIRONMENT, 1, 2, 3);
    ns_scene s = base_scene(16, 16, 60);
    scene_lists(&s, &m, 1, &ball, 1, &env, 1);
    GpuSegment seg = segment(-0.01, 0, 0, 1, 0, 0, 0.02);
    seg.material = 0;
    float out[1][4];
    if (run_single(&s, &seg, 1, samples, out, NULL))
        return;
    double f0 = (ior - 1) / (ior + 1);
    f0 *= f0;
    double inside = ior * ior * (1 - f0);
    for (int c = 0; c < 3; c++) {
        double st = ss[c] + sa[c];
        double reflections = 1.0 / (1.0 - f0 * exp(-2.0 * st));
        double want =
            ss[c] * inside * reflections * (c + 1) * exp(-st * 1.0) * -expm1(-st * 0.02) / st;
        CHECK_REL(out[0][c], want, tolerance);
    }
}

static void test_environment_index_matched(void)
{
    check_environment(1.0, 256, 1e-3);
}
static void test_environment_refracted(void)
{
    check_environment(1.5, 4096, 1.5e-3);
}

/* More samples than one lavapipe dispatch can take (split across dispatches) give the same
 * closed form; and the result does not depend on how many segments share the call. */
static void test_many_samples(void)
{
    double dir[3];
    slab s;
    lit_slab(&s, 1.5, dir);
    GpuSegment segs[SLAB_SEGMENTS];
    slab_segments(segs);
    float out[SLAB_SEGMENTS][4];
    if (run_single(&s.scene, segs, SLAB_SEGMENTS, NS_MAX_SINGLE_SAMPLES, out, NULL))
        return;
    for (int i = 0; i < SLAB_SEGMENTS; i++)
        for (int c = 0; c < 3; c++)
            CHECK_REL(out[i][c],
                      slab_directional(&segs[i], seg_length(&segs[i]), dir, 1.5, E_RGB[c], c),
                      1e-3);
}

/* Where the distance sampling is stretched (single.comp's distance_sample): a horizontal
 * segment 40 long just under the top face, 20 to 84 mean free paths (the Newton inversion of
 * the mixture's CDF must reach far into the tail), and a vertical one rising through the whole
 * slab under a grazing light, whose integrand grows along it by e^{5} in the densest channel
 * (the exponentials put their points near the entry; the uniform part of the mixture must
 * carry the far end). Both against the closed form, index matched and refracting. */
static void test_long_and_rising_segments(void)
{
    const double ior[2] = {1.0, 1.5};
    for (int k = 0; k < 2; k++) {
        slab flat_slab, grazing_slab;
        double flat[3], grazing[3] = {1, -0.3, 0};
        lit_slab(&flat_slab, ior[k], flat);
        unit(grazing);
        make_slab(&grazing_slab, ior[k], directional(grazing, E_RGB));
        const slab *slabs[2] = {&flat_slab, &grazing_slab};
        const double *dirs[2] = {flat, grazing};
        GpuSegment segs[2] = {segment(-20, 0.9, 0, 1, 0, 0, 40), segment(0, 0.0, 0, 0, 1, 0, TOP)};
        for (int i = 0; i < 2; i++) {
            float out[1][4];
            if (run_single(&slabs[i]->scene, &segs[i], 1, CLOSED_FORM_SAMPLES, out, NULL))
                return;
            for (int c = 0; c < 3; c++)
                CHECK_REL(
                    out[0][c],
                    slab_directional(&segs[i], seg_length(&segs[i]), dirs[i], ior[k], E_RGB[c], c),
                    1e-3);
        }
    }
}

/* A segment's samples scale with its throughput (single.comp's segment_strata): the same
 * segment at weight 1 and at weight 1/64 of 1600 samples takes 1600 and 25 strata. Both
 * estimates hold the closed form within their strata's error (the light's 400 and 7 strata,
 * one jittered point each; for 7, up to the integrand's variation across one stratum: 5e-2),
 * and they differ, because the strata differ; at equal weight they would be the same
 * numbers bit for bit. */
static void test_samples_follow_throughput(void)
{
    double dir[3];
    slab s;
    lit_slab(&s, 1.5, dir);
    GpuSegment segs[SLAB_SEGMENTS];
    slab_segments(segs);
    GpuSegment pair[2] = {segs[1], segs[1]};
    set3(pair[1].throughput, 1.0 / 64, 1.0 / 128, 1.0 / 256); /* the largest channel counts */
    float out[2][4];
    if (run_single(&s.scene, pair, 2, CLOSED_FORM_SAMPLES, out, NULL))
        return;
    int differ = 0;
    for (int c = 0; c < 3; c++) {
        double want = slab_directional(&segs[1], seg_length(&segs[1]), dir, 1.5, E_RGB[c], c);
        CHECK_REL(out[0][c], want, 1e-3);
        CHECK_REL(out[1][c], want, 5e-2);
        differ += out[0][c] != out[1][c];
    }
    CHECK_INT(differ, 3);
}

/* The random numbers (a sphere light's cone, the environment's directions) follow each
 * segment, not its position in the buffer: the camera pass records segments in whatever
 * order its invocations finish. Reversing the buffer gives the same values bit for bit. */
static void test_order_independent(void)
{
    const double ss[3] = {0.5, 0.5, 0.5}, sa[3] = {0.1, 0.1, 0.1};
    ns_material m = medium(ss, sa, 1.5);
    ns_object ball = sphere(0, 0, 0, 1, 0);
    ns_light lights[2] = {light(NS_LIGHT_SPHERE, 5, 5, 5), light(NS_LIGHT_ENVIRONMENT, 1, 1, 1)};
    set3(lights[0].position, 0, 3, 0);
    lights[0].radius = 0.5f;
    ns_scene s = base_scene(16, 16, 60);
    scene_lists(&s, &m, 1, &ball, 1, lights, 2);
    enum { N = 8 };
    GpuSegment segs[N], reversed[N];
    for (int i = 0; i < N; i++) {
        segs[i] = segment(-0.9 + 0.2 * i, -0.3, 0.1, 0.1, 1, 0.05, 0.5);
        segs[i].material = 0;
        segs[i].pixel = (uint32_t)i;
        reversed[N - 1 - i] = segs[i];
    }
    float out[N][4], out_reversed[N][4];
    if (run_single(&s, segs, N, 16, out, NULL) ||
        run_single(&s, reversed, N, 16, out_reversed, NULL))
        return;
    for (int i = 0; i < N; i++) {
        CHECK(out[i][0] > 0);
        CHECK_INT(memcmp(out[i], out_reversed[N - 1 - i], sizeof out[i]), 0);
    }
}

/* Planes are tested after the BVH on every ray and their loop is not in the shaders' own
 * iteration count, so many of them make lavapipe's real count far larger than the counted
 * one: vertical planes far to the side (parallel to the vertical light and to every shadow
 * ray, so they block nothing). The first chunks run past lavapipe's loop limit, the shader
 * notices, and the samples are run again in smaller chunks: the closed form still holds.
 * With many lights one sample alone is too much: NS_ERR_LIMIT, never a wrong result. */
enum { SIDE_PLANES = 200 };

static void add_side_planes(ns_object *objects, uint32_t count)
{
    for (uint32_t i = 0; i < count; i++) {
        memset(&objects[i], 0, sizeof objects[i]);
        objects[i].shape = NS_SHAPE_PLANE;
        objects[i].material = MAT_DIFFUSE;
        set3(objects[i].point, 100 + i, 0, 0);
        set3(objects[i].normal, 1, 0, 0);
    }
}

/* The renderer hands segments to the GPU most strata first (ns_single_order), so that a SIMD
 * group's lanes finish together: strata as single.comp counts them (samples times the largest
 * throughput, rounded up, 1 at least, samples at most), most first, ties in their order. */
static void test_order_most_strata_first(void)
{
    /* Largest throughput and the strata it gives at 64 samples. */
    static const struct {
        float largest;
        uint32_t strata;
    } cases[] = {{0.96f, 62}, {0.01f, 1}, {1.0f, 64}, {0.0f, 1}, {0.5f, 32}, {0.96f, 62},
                 {3.0f, 64},  {0.5f, 32}, {1e-30f, 1}, {0.2f, 13}};
    enum { N = sizeof cases / sizeof cases[0] };
    GpuSegment segs[N];
    memset(segs, 0, sizeof segs);
    for (uint32_t i = 0; i < N; i++) {
        /* The largest in a different channel each time. */
        segs[i].throughput[i % 3] = cases[i].largest;
        segs[i].throughput[(i + 1) % 3] = 0.5f * cases[i].largest;
    }
    uint32_t order[N];
    CHECK_INT(ns_single_order(segs, N, 64, order), 0);
    static const uint32_t want[N] = {2, 6, 0, 5, 4, 7, 9, 1, 3, 8};
    for (uint32_t j = 0; j < N; j++) {
        CHECK_INT(order[j], want[j]);
        if (j)
            CHECK(cases[order[j - 1]].strata >= cases[order[j]].strata);
    }
    /* One sample (or 0, which ns_single_scatter refuses): every segment takes one stratum. */
    for (uint32_t samples = 0; samples < 2; samples++) {
        CHECK_INT(ns_single_order(segs, N, samples, order), 0);
        for (uint32_t j = 0; j < N; j++)
            CHECK_INT(order[j], j);
    }
}

static void test_loop_limit_retry(void)
{
    double dir[3] = {0, -1, 0};
    slab s;
    make_slab(&s, 1.5, directional(dir, E_RGB));
    ns_object objects[1 + SIDE_PLANES];
    objects[0] = s.objects[0];
    add_side_planes(objects + 1, SIDE_PLANES);
    s.scene.objects = objects;
    s.scene.object_count = 1 + SIDE_PLANES;
    GpuSegment segs[SLAB_SEGMENTS];
    slab_segments(segs);
    float out[SLAB_SEGMENTS][4];
    if (run_single(&s.scene, segs, SLAB_SEGMENTS, 1024, out, NULL))
        return;
    for (int i = 0; i < SLAB_SEGMENTS; i++)
        for (int c = 0; c < 3; c++)
            CHECK_REL(out[i][c],
                      slab_directional(&segs[i], seg_length(&segs[i]), dir, 1.5, E_RGB[c], c),
                      1e-3);
}

static void test_loop_limit_error(void)
{
    ns_context *ctx = test_context();
    if (!ctx->dev.loop_limited)
        SKIP("only lavapipe has the loop limit, and this device is not lavapipe");
    double dir[3] = {0, -1, 0};
    slab s;
    make_slab(&s, 1.0, directional(dir, E_RGB));
    enum { PLANES = 1000, LIGHTS = 64 };
    ns_object *objects = calloc(1 + PLANES, sizeof *objects);
    ns_light lights[LIGHTS];
    objects[0] = s.objects[0];
    add_side_planes(objects + 1, PLANES);
    for (int i = 0; i < LIGHTS; i++)
        lights[i] = directional(dir, E_RGB);
    s.scene.objects = objects;
    s.scene.object_count = 1 + PLANES;
    s.scene.lights = lights;
    s.scene.light_count = LIGHTS;
    GpuSegment seg = segment(0, TOP, 0, 0, -1, 0, TOP);
    device_scene d;
    if (!device_scene_make(&s.scene, &d)) {
        gpu_buffer segs = {0}, out = {0};
        ns_error err = {0};
        CHECK_INT(gpu_buffer_create(
                      &ctx->dev, &segs,
                      &(gpu_buffer_desc){.size = sizeof seg, .data = &seg, .data_size = sizeof seg},
                      &err),
                  NS_OK);
        CHECK_INT(gpu_buffer_create(&ctx->dev, &out, &(gpu_buffer_desc){.size = 16}, &err), NS_OK);
        CHECK_INT(ns_single_scatter(ctx, d.buffers, &segs, 1, 16, &out, &err), NS_ERR_LIMIT);
        CHECK_STR_CONTAINS(err.message, "loop limit");
        gpu_buffer_destroy(&ctx->dev, &segs);
        gpu_buffer_destroy(&ctx->dev, &out);
        device_scene_free(&d);
    }
    free(objects);
}

/* The single component of the path tracer against this stage composed the way render.c
 * does: every camera segment of the camera pass contributes throughput * out / spp to its
 * pixel, over ior^2 (render/scatter_render.c: radiance leaving the medium). The mean over the
 * pixels of (ours - pt) must lie within 4 standard errors of 0, per channel, with a standard error
 * small enough to mean something. */
static void check_against_path_tracer(ns_scene *s)
{
    const uint32_t pixels = s->camera.width * s->camera.height;

    /* Ours: camera pass segments, then single scattering on them. */
    s->render.spp = 8;
    uint32_t capacity = pixels * s->render.spp * 4;
    GpuSegment *segs = calloc(capacity, sizeof *segs);
    ns_render_debug debug = {.segments = segs, .segments_max = capacity};
    ns_image surface = {0};
    ns_error err = {0};
    int status = ns_render_ex(test_context(), s, &surface, NULL, &debug, &err);
    CHECK_INT(status, NS_OK);
    uint32_t n = (uint32_t)debug.segments_written;
    CHECK(n > pixels); /* the object fills a good part of the image */
    CHECK(n < capacity);
    float(*out)[4] = calloc(n ? n : 1, 16);
    double *ours = calloc(3 * pixels, sizeof *ours);
    if (!status && n && !run_single(s, segs, n, 64, out, NULL))
        for (uint32_t i = 0; i < n; i++) {
            double ior = s->materials[segs[i].material].ior;
            for (int c = 0; c < 3; c++)
                ours[3 * segs[i].pixel + c] +=
                    segs[i].throughput[c] * out[i][c] / (s->render.spp * ior * ior);
        }

    /* The path tracer's single order. */
    s->render.method = NS_METHOD_PT;
    s->render.components = NS_COMPONENT_SINGLE;
    s->render.spp = 1024;
    ns_image pt = {0};
    if (render_ok(s, &pt, NULL))
        for (int c = 0; c < 3; c++) {
            double sum = 0, sum2 = 0, level = 0;
            for (uint32_t p = 0; p < pixels; p++) {
                double d = ours[3 * p + c] - pt.rgb[3 * p + c];
                sum += d;
                sum2 += d * d;
                level += pt.rgb[3 * p + c];
            }
            double mean = sum / pixels, se = sqrt((sum2 / pixels - mean * mean) / (pixels - 1));
            level /= pixels;
            fprintf(stderr, "  channel %d: pt mean %.5f, ours - pt %.2e (standard error %.2e)\n", c,
                    level, mean, se);
            CHECK(level > 0);
            CHECK(se < 0.02 * level);
            CHECK(fabs(mean) < 4 * se);
        }
    ns_image_free(&surface);
    ns_image_free(&pt);
    free(segs);
    free(out);
    free(ours);
}

/* Next-event estimation inside an index-matched medium: a scattering sphere under a
 * directional light, a point light and the environment (single.comp's stratified phase
 * directions). */
static void test_against_path_tracer(void)
{
    const double ss[3] = {0.6, 1.2, 2.0}, sa[3] = {0.2, 0.1, 0.4};
    ns_material m = medium(ss, sa, 1.0);
    m.g = 0.4f;
    ns_object ball = sphere(0, 0, 0, 1, 0);
    ns_light lights[3] = {light(NS_LIGHT_DIRECTIONAL, 1, 1.5, 2), light(NS_LIGHT_POINT, 6, 4, 2),
                          light(NS_LIGHT_ENVIRONMENT, 0.3, 0.2, 0.1)};
    set3(lights[0].direction, 0.3, -1, 0.2);
    set3(lights[1].position, -2, 1.5, 1.5);
    ns_scene s = base_scene(16, 16, 40);
    set3(s.camera.position, 0, 0.5, 4);
    set3(s.camera.look_at, 0, 0, 0);
    scene_lists(&s, &m, 1, &ball, 1, lights, 3);
    check_against_path_tracer(&s);
}

/* The environment through a refracting cube or sphere (ior 1.5, the cube's half-width the
 * sphere's radius): light reaches the inside only through the faces. In the cube, along
 * many directions from a point inside, only after a total internal reflection at one face
 * (which a neighbouring face then lets out), so the ray back from the point must follow the
 * reflections (environment_along): stopping at the first face read its single scattering
 * 27 / 24 / 20% low against pt and fails (checked). A chord meets a sphere at the same angle
 * at both ends, so no light arrives along a totally reflected direction there: the sphere
 * checks that environment_along drops such rays at once without losing light (its partial
 * reflections are 3%, 2.4 standard errors). */
static void check_environment_reflections(int use_cube)
{
    const double ss[3] = {0.3, 0.5, 0.8}, sa[3] = {0.05, 0.1, 0.1};
    ns_material m = medium(ss, sa, 1.5);
    m.g = 0.3f;
    ns_object object = use_cube ? cuboid(-1, -1, -1, 1, 1, 1, 0) : sphere(0, 0, 0, 1, 0);
    ns_light env = light(NS_LIGHT_ENVIRONMENT, 0.3, 0.2, 0.1);
    ns_scene s = base_scene(16, 16, 50);
    set3(s.camera.position, 2.5, 2.0, 3.5);
    set3(s.camera.look_at, 0, 0, 0);
    scene_lists(&s, &m, 1, &object, 1, &env, 1);
    check_against_path_tracer(&s);
}

static void test_environment_reflections_against_path_tracer(void)
{
    check_environment_reflections(1);
    /* The sphere, whose totally reflected rays environment_along drops at once. */
    check_environment_reflections(0);
}

/* Real camera segments in a refracting sphere (entries 1e-4 inside the boundary, internal
 * reflections, total internal reflection, grazing rays at the rim) under every light kind:
 * no closed form, but every value must be finite and non-negative, and light must arrive. */
static void test_camera_segments_refracting(void)
{
    const double ss[3] = {0.8, 1.0, 1.2}, sa[3] = {0.05, 0.1, 0.2};
    ns_material m = medium(ss, sa, 1.5);
    m.g = -0.3f;
    ns_object ball = sphere(0, 0, 0, 1, 0);
    ns_light lights[4] = {light(NS_LIGHT_DIRECTIONAL, 1, 1, 1), light(NS_LIGHT_POINT, 5, 5, 5),
                          light(NS_LIGHT_SPHERE, 3, 3, 3),
                          light(NS_LIGHT_ENVIRONMENT, 0.2, 0.2, 0.2)};
    set3(lights[0].direction, 0.2, -1, -0.4);
    set3(lights[1].position, 2, 1, 2);
    set3(lights[2].position, -2, 2, 1);
    lights[2].radius = 0.4f;
    ns_scene s = base_scene(24, 24, 45);
    set3(s.camera.position, 0, 0.3, 3.5);
    scene_lists(&s, &m, 1, &ball, 1, lights, 4);
    s.render.spp = 2;
    uint32_t capacity = 24 * 24 * s.render.spp * 2;
    GpuSegment *segs = calloc(capacity, sizeof *segs);
    ns_render_debug debug = {.segments = segs, .segments_max = capacity};
    ns_image surface = {0};
    ns_error err = {0};
    CHECK_INT(ns_render_ex(test_context(), &s, &surface, NULL, &debug, &err), NS_OK);
    uint32_t n = (uint32_t)debug.segments_written;
    CHECK(n > 24 * 24);
    float(*out)[4] = calloc(n ? n : 1, 16);
    if (n && !run_single(&s, segs, n, 32, out, NULL)) {
        uint32_t bad = 0, lit = 0;
        for (uint32_t i = 0; i < n; i++)
            for (int c = 0; c < 3; c++) {
                bad += !(isfinite(out[i][c]) && out[i][c] >= 0.0f);
                lit += out[i][c] > 0.0f;
            }
        CHECK_INT(bad, 0);
        CHECK(lit > 3 * n / 2);
    }
    ns_image_free(&surface);
    free(segs);
    free(out);
}

/* Adaptive single scattering (render.single_levels): computed on a coarse lattice of pixels,
 * interpolated where the neighbours agree. Two index-matched spheres side by side, a bright
 * and a dark medium, under a directional light from above and in front; an opaque ball
 * between it and the bright sphere casts a shadow on the face the camera sees, with edges
 * single scattering shows sharply (no environment: the shadow is dark). Every render shares
 * the camera segments (one seed); the converged image has 16 times the camera samples:
 *   - tolerance 0 interpolates only where the estimate is exactly 0 (nowhere here: the
 *     shadow's view rays cross lit medium too), so the rounds must compose the image that
 *     every pixel computed gives, to float rounding;
 *   - the default tolerance interpolates a good part of the spheres, keeps each sphere's
 *     mean, and its error against the converged image is not much above that of computing
 *     every pixel: the shadow's edges and the two media are computed, not blurred. A blind
 *     interpolation (tolerance 1: wherever the neighbours see the surface) must do clearly
 *     worse, or the scene would test nothing. (Against an image of the same camera segments
 *     at more samples, interpolation would look worse than it is: an interpolated pixel
 *     loses its own segments' departure from its neighbours' mean, which is the camera's
 *     sampling error, not light.);
 *   - the background stays exactly dark. */
static int adaptive_render(const ns_scene *base, uint32_t samples, uint32_t levels, float tolerance,
                           ns_image *img, ns_render_stats *stats)
{
    ns_scene s = *base;
    s.render.single_samples = samples;
    s.render.single_levels = levels;
    s.render.single_tolerance = tolerance;
    memset(stats, 0, sizeof *stats);
    return render_ok(&s, img, stats);
}

typedef struct adaptive_error {
    double rms;        /* over the lit pixels and channels, relative to the brightest pixel */
    double mean[2];    /* each sphere's image mean over the converged one's */
    uint32_t lit_background; /* channels lit where the converged image is dark */
} adaptive_error;

static adaptive_error error_against(const ns_image *img, const ns_image *converged, uint32_t width)
{
    adaptive_error e = {0};
    double level = 0, sum[2] = {0, 0}, ref[2] = {0, 0}, sq = 0;
    size_t n = (size_t)img->width * img->height, lit = 0;
    for (size_t i = 0; i < 3 * n; i++)
        level = fmax(level, converged->rgb[i]);
    for (size_t i = 0; i < 3 * n; i++) {
        double f = converged->rgb[i], d = (img->rgb[i] - f) / level;
        int side = (i / 3) % width >= width / 2;
        sum[side] += img->rgb[i];
        ref[side] += f;
        if (f == 0.0) {
            e.lit_background += img->rgb[i] != 0.0f;
            continue;
        }
        sq += d * d;
        lit++;
    }
    e.rms = sqrt(sq / (double)(lit ? lit : 1));
    e.mean[0] = sum[0] / ref[0];
    e.mean[1] = sum[1] / ref[1];
    return e;
}

static void test_adaptive(void)
{
    const double bright_s[3] = {2.0, 1.5, 1.0}, bright_a[3] = {0.1, 0.2, 0.3};
    const double dark_s[3] = {0.3, 0.2, 0.1}, dark_a[3] = {0.5, 0.5, 0.5};
    ns_material mats[3] = {medium(bright_s, bright_a, 1.0), medium(dark_s, dark_a, 1.0),
                           diffuse(0.5, 0.5, 0.5)};
    mats[0].g = 0.3f;
    mats[1].g = 0.3f;
    ns_object objs[3] = {sphere(-1.1, 0, 0, 1, 0), sphere(1.1, 0, 0, 1, 1), sphere(-1.1, 1.6, 1.6, 0.4, 2)};
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 3, 3, 3);
    set3(sun.direction, 0, -1, -1);
    const uint32_t width = 64, height = 40;
    ns_scene s = base_scene(width, height, 50);
    set3(s.camera.position, 0, 0.4, 5);
    set3(s.camera.look_at, 0, 0, 0);
    scene_lists(&s, mats, 3, objs, 3, &sun, 1);
    s.render.components = NS_COMPONENT_SINGLE;
    ns_image converged = {0}, full = {0}, exact = {0}, adaptive = {0}, blind = {0};
    ns_render_stats st_converged, st_full, st_exact, st_adaptive, st_blind;
    ns_scene many = s;
    many.render.spp = 64;
    if (!adaptive_render(&many, 256, 0, 0.0f, &converged, &st_converged) ||
        !adaptive_render(&s, 128, 0, 0.0f, &full, &st_full) ||
        !adaptive_render(&s, 128, 2, 0.0f, &exact, &st_exact) ||
        !adaptive_render(&s, 128, 2, NS_DEFAULT_SINGLE_TOLERANCE, &adaptive, &st_adaptive) ||
        !adaptive_render(&s, 128, 2, 1.0f, &blind, &st_blind))
        goto done;
    uint32_t lit = 0;
    double worst_exact = 0;
    for (size_t i = 0; i < 3u * width * height; i++) {
        lit += converged.rgb[i] > 0.0f;
        worst_exact = fmax(worst_exact, fabs(exact.rgb[i] - full.rgb[i]) / fmax(full.rgb[i], 1e-30));
    }
    adaptive_error e_full = error_against(&full, &converged, width),
                   e_adaptive = error_against(&adaptive, &converged, width),
                   e_blind = error_against(&blind, &converged, width);
    fprintf(stderr,
            "  %u lit channels; interpolated pixels: tolerance 0 %llu, default %llu, blind %llu\n"
            "  rms error / brightest: every pixel %.4f, default %.4f, blind %.4f; sphere means "
            "%.4f / %.4f, %.4f / %.4f, %.4f / %.4f; tolerance 0 off by %.1e\n",
            lit, (unsigned long long)st_exact.single_interpolated,
            (unsigned long long)st_adaptive.single_interpolated,
            (unsigned long long)st_blind.single_interpolated, e_full.rms, e_adaptive.rms, e_blind.rms,
            e_full.mean[0], e_full.mean[1], e_adaptive.mean[0], e_adaptive.mean[1], e_blind.mean[0],
            e_blind.mean[1], worst_exact);
    CHECK(lit > width * height);
    CHECK_INT(st_full.single_interpolated, 0);
    CHECK(worst_exact < 1e-5);
    /* Measured: 778 of about 1,340 lit pixels interpolated (770 before the pixels' noise
     * weighed in); rms 1.14 and 1.62 times every pixel's; the means 0.45 and 0.41% from
     * every pixel's, the blind ones 0.73 and 1.09%. */
    CHECK(st_adaptive.single_interpolated > lit / 3 / 3);
    CHECK(e_adaptive.rms < 1.25 * e_full.rms);
    CHECK(e_blind.rms > 1.4 * e_full.rms); /* the shadow's edges are there to blur */
    for (int side = 0; side < 2; side++)
        CHECK(fabs(e_adaptive.mean[side] - e_full.mean[side]) < 0.006);
    CHECK_INT(e_adaptive.lit_background, 0);
done:
    ns_image_free(&converged);
    ns_image_free(&full);
    ns_image_free(&exact);
    ns_image_free(&adaptive);
    ns_image_free(&blind);
}

/* Adaptive single scattering where the estimate is noisy: the wide slab under the
 * environment alone, seen from above through a narrow field of view, so the light is all but
 * the same in every pixel while the estimate, one phase-sampled direction per point at 4
 * samples, is noisy (docs/rendering.md: the environment is what makes the stage noisy).
 * Second differences of noise are not curvature: with the pixels' noise (the spread of
 * their camera samples) in the rule, half the pixels are interpolated and the image is
 * nearer the converged one than computing every pixel
 * (interpolating where the curvature is buried in the noise is no worse than computing);
 * with the tolerance alone, the noise stops most of it. */
static void test_adaptive_noisy(void)
{
    slab sl;
    make_slab(&sl, 1.5, light(NS_LIGHT_ENVIRONMENT, 1, 1, 1));
    const uint32_t width = 32, height = 32;
    ns_scene s = sl.scene;
    s.camera.width = width;
    s.camera.height = height;
    s.camera.fov_deg = 10;
    set3(s.camera.position, 0, 20, 0);
    set3(s.camera.up, 0, 0, -1);
    set3(s.camera.look_at, 0, 0, 0);
    s.render.components = NS_COMPONENT_SINGLE;
    ns_image converged = {0}, full = {0}, adaptive = {0};
    ns_render_stats st_converged, st_full, st_adaptive;
    ns_scene many = s;
    many.render.spp = 16;
    if (!adaptive_render(&many, 128, 0, 0.0f, &converged, &st_converged) ||
        !adaptive_render(&s, 4, 0, 0.0f, &full, &st_full) ||
        !adaptive_render(&s, 4, 2, NS_DEFAULT_SINGLE_TOLERANCE, &adaptive, &st_adaptive))
        goto done;
    adaptive_error e_full = error_against(&full, &converged, width),
                   e_adaptive = error_against(&adaptive, &converged, width);
    double mean_full = 0.5 * (e_full.mean[0] + e_full.mean[1]),
           mean_adaptive = 0.5 * (e_adaptive.mean[0] + e_adaptive.mean[1]);
    fprintf(stderr,
            "  %u pixels, %llu interpolated; rms error / brightest: every pixel %.4f, adaptive "
            "%.4f; means %.4f, %.4f\n",
            width * height, (unsigned long long)st_adaptive.single_interpolated, e_full.rms,
            e_adaptive.rms, mean_full, mean_adaptive);
    /* Measured: 588 of 1,024 interpolated (96 with the tolerance alone); rms 0.148 against
     * 0.181 for every pixel. */
    CHECK(st_adaptive.single_interpolated > width * height / 3);
    CHECK(e_adaptive.rms < e_full.rms);
    /* The rule's bias: a pixel's noise is estimated from the same few samples as its value,
     * so a dark draw looks quiet and is kept while a bright one is smoothed away. Over 24
     * seeds the adaptive mean is 1.8% below every pixel's (each seed's difference spreads
     * by 1.4%; 1.7% more with the median of the samples' variances, which let an outlier's
     * own variance excuse it: scatter_render.c). One seed cannot tell that from noise, so
     * the mean difference is taken over four. */
    double bias = (mean_adaptive - mean_full) / 4.0;
    for (uint32_t seed = 1; seed < 4; seed++) {
        ns_image f = {0}, a = {0};
        ns_render_stats sf, sa;
        ns_scene other = s;
        other.render.seed = s.render.seed + seed;
        if (adaptive_render(&other, 4, 0, 0.0f, &f, &sf) &&
            adaptive_render(&other, 4, 2, NS_DEFAULT_SINGLE_TOLERANCE, &a, &sa)) {
            adaptive_error ef = error_against(&f, &converged, width),
                           ea = error_against(&a, &converged, width);
            bias += (0.5 * (ea.mean[0] + ea.mean[1]) - 0.5 * (ef.mean[0] + ef.mean[1])) / 4.0;
        }
        ns_image_free(&f);
        ns_image_free(&a);
    }
    fprintf(stderr, "  adaptive mean over every pixel's, four seeds: %+.4f\n", bias);
    CHECK(fabs(bias) < 0.04);
done:
    ns_image_free(&converged);
    ns_image_free(&full);
    ns_image_free(&adaptive);
}

static void test_bad_arguments(void)
{
    ns_context *ctx = test_context();
    double dir[3] = {0, -1, 0};
    slab s;
    make_slab(&s, 1.0, directional(dir, E_RGB));
    device_scene d;
    if (device_scene_make(&s.scene, &d))
        return;
    GpuSegment seg = segment(0, TOP, 0, 0, -1, 0, TOP);
    gpu_buffer segs = {0}, out = {0};
    ns_error err = {0};
    CHECK_INT(gpu_buffer_create(
                  &ctx->dev, &segs,
                  &(gpu_buffer_desc){.size = sizeof seg, .data = &seg, .data_size = sizeof seg},
                  &err),
              NS_OK);
    CHECK_INT(gpu_buffer_create(&ctx->dev, &out, &(gpu_buffer_desc){.size = 16}, &err), NS_OK);
    CHECK_INT(ns_single_scatter(ctx, d.buffers, &segs, 1, 0, &out, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "samples 0");
    CHECK_INT(ns_single_scatter(ctx, d.buffers, &segs, 2, 10, &out, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "segments buffer");
    CHECK_INT(ns_single_scatter(ctx, d.buffers, &segs, 1, 10, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "out is NULL");
    CHECK_INT(ns_single_scatter(ctx, d.buffers, &segs, 0, 10, &out, &err), NS_OK);
    CHECK_INT(ns_single_scatter(ctx, d.buffers, &segs, 1, 10, &out, &err), NS_OK);
    CHECK(((const float *)out.mapped)[0] > 0);
    /* A segment that names a diffuse material or no material at all scatters nothing. */
    GpuSegment *mapped = segs.mapped;
    const uint32_t not_media[2] = {MAT_DIFFUSE, 99};
    for (int i = 0; i < 2; i++) {
        mapped->material = not_media[i];
        CHECK_INT(ns_single_scatter(ctx, d.buffers, &segs, 1, 10, &out, &err), NS_OK);
        for (int c = 0; c < 4; c++)
            CHECK_INT(((const float *)out.mapped)[c] == 0.0f, 1);
    }
    gpu_buffer_destroy(&ctx->dev, &segs);
    gpu_buffer_destroy(&ctx->dev, &out);
    device_scene_free(&d);
    CHECK_INT(gpu_validation_count(&ctx->dev), 0);
}

/* NSCATTER_BENCH=N: median of N runs for 128^2 and 512^2 segments, 100 samples, one light. */
static int compare_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static void bench_one(int runs, double ior)
{
    double dir[3];
    slab s;
    lit_slab(&s, ior, dir);
    const uint32_t sizes[2] = {128, 512};
    for (int k = 0; k < 2; k++) {
        uint32_t n = sizes[k] * sizes[k];
        GpuSegment *segs = malloc(sizeof *segs * n);
        float(*out)[4] = malloc(16ull * n);
        for (uint32_t i = 0; i < n; i++) {
            double u = (double)(i % sizes[k]) / sizes[k] - 0.5,
                   v = (double)(i / sizes[k]) / sizes[k] - 0.5;
            segs[i] = segment(10 * u, TOP, 10 * v, 0.3 * u, -1, 0.3 * v,
                              TOP * sqrt(1 + 0.09 * (u * u + v * v)));
        }
        double ms[16];
        int done = 0;
        for (int r = 0; r < runs && r < 16; r++)
            if (!run_single(&s.scene, segs, n, 100, out, &ms[done]))
                done++;
        qsort(ms, (size_t)done, sizeof ms[0], compare_double);
        if (done)
            printf("single scattering, slab ior %.1f, %ux%u segments, 100 samples, 1 directional "
                   "light: "
                   "median %.1f ms of %d (%.1f M sample-light connections/s)\n",
                   ior, sizes[k], sizes[k], ms[done / 2], done, n * 100.0 / ms[done / 2] / 1e3);
        free(segs);
        free(out);
    }
}

static void bench(int runs)
{
    bench_one(runs, 1.0);
    bench_one(runs, 1.5);
}

int main(void)
{
    RUN(test_directional_index_matched);
    RUN(test_directional_refracted);
    RUN(test_directional_refracted_oblique);
    RUN(test_point_index_matched);
    RUN(test_point_far_refracted);
    RUN(test_point_near_refracted);
    RUN(test_sphere_light);
    RUN(test_sphere_near_refracted);
    RUN(test_shadow_index_matched);
    RUN(test_shadow_refracted);
    RUN(test_refracting_occluder);
    RUN(test_environment_index_matched);
    RUN(test_environment_refracted);
    RUN(test_many_samples);
    RUN(test_samples_follow_throughput);
    RUN(test_long_and_rising_segments);
    RUN(test_order_independent);
    RUN(test_order_most_strata_first);
    RUN(test_loop_limit_retry);
    RUN(test_loop_limit_error);
    RUN(test_against_path_tracer);
    RUN(test_environment_reflections_against_path_tracer);
    RUN(test_camera_segments_refracting);
    RUN(test_adaptive);
    RUN(test_adaptive_noisy);
    RUN(test_bad_arguments);
    const char *b = getenv("NSCATTER_BENCH");
    if (b && atoi(b) > 0)
        bench(atoi(b));
    ns_context_destroy(test_context());
    return harness_report();
}
