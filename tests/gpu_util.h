/* gpu_util.h — shared helpers of the GPU known-answer tests: one context per program
 * (validation on when ctest sets NSCATTER_VALIDATION=1), scene building in C, and an
 * independent re-derivation of the pinhole camera's rays. */
#ifndef NS_TEST_GPU_UTIL_H
#define NS_TEST_GPU_UTIL_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "harness.h"
#include "internal.h"
#include "nscatter.h"

static inline ns_context *test_context(void)
{
    static ns_context *ctx;
    if (!ctx) {
        ns_error err = {0};
        int status = ns_context_create(&(ns_context_desc){0}, &ctx, &err);
        if (status) {
            fprintf(stderr, "ns_context_create: %s (%s)\n", err.message, ns_status_name(status));
            exit(1);
        }
    }
    return ctx;
}

/* A scene on the device as render.c uploads it: its GPU form and the five scene buffers, with
 * lavapipe's loop budget, for tests that drive one stage alone. make checks its status (a
 * failure is a failed test, its message printed). */
typedef struct device_scene {
    ns_gpu_scene gs;
    gpu_buffer buffers[NS_SCENE_BUFFER_COUNT];
} device_scene;

static inline int device_scene_make(const ns_scene *s, device_scene *d)
{
    ns_context *ctx = test_context();
    ns_error err = {0};
    memset(d, 0, sizeof *d);
    int status = ns_gpu_scene_build(s, &d->gs, &err);
    if (!status) {
        d->gs.params.limits[0] = ctx->dev.loop_limited ? NS_LAVAPIPE_LOOP_BUDGET : 0;
        gpu_buffer_desc descs[NS_SCENE_BUFFER_COUNT];
        ns_gpu_scene_buffer_descs(&d->gs, descs);
        status = gpu_buffers_create(&ctx->dev, d->buffers, descs, NS_SCENE_BUFFER_COUNT, &err);
    }
    if (status)
        fprintf(stderr, "device scene: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    return status;
}

static inline void device_scene_free(device_scene *d)
{
    for (int i = 0; i < NS_SCENE_BUFFER_COUNT; i++)
        gpu_buffer_destroy(&test_context()->dev, &d->buffers[i]);
    ns_gpu_scene_free(&d->gs);
}

static inline void set3(float v[3], double x, double y, double z)
{
    v[0] = (float)x;
    v[1] = (float)y;
    v[2] = (float)z;
}

static inline ns_scene base_scene(uint32_t width, uint32_t height, double fov)
{
    ns_scene s;
    memset(&s, 0, sizeof s);
    s.camera.fov_deg = (float)fov;
    s.camera.width = width;
    s.camera.height = height;
    set3(s.camera.up, 0, 1, 0);
    /* The other settings are left 0: ns_render gives them their defaults. */
    s.render.components = NS_COMPONENT_SURFACE;
    s.render.spp = 4;
    s.render.seed = 7;
    return s;
}

static inline ns_material diffuse(double r, double g, double b)
{
    ns_material m;
    memset(&m, 0, sizeof m);
    m.type = NS_MATERIAL_DIFFUSE;
    set3(m.reflectance, r, g, b);
    return m;
}

static inline ns_material medium(const double sigma_s[3], const double sigma_a[3], double ior)
{
    ns_material m;
    memset(&m, 0, sizeof m);
    m.type = NS_MATERIAL_MEDIUM;
    set3(m.sigma_s, sigma_s[0], sigma_s[1], sigma_s[2]);
    set3(m.sigma_a, sigma_a[0], sigma_a[1], sigma_a[2]);
    m.ior = (float)ior;
    return m;
}

static inline ns_object sphere(double x, double y, double z, double r, uint32_t material)
{
    ns_object o;
    memset(&o, 0, sizeof o);
    o.shape = NS_SHAPE_SPHERE;
    set3(o.center, x, y, z);
    o.radius = (float)r;
    o.material = material;
    return o;
}

/* An axis-aligned box from (x0, y0, z0) to (x1, y1, z1). */
static inline ns_object cuboid(double x0, double y0, double z0, double x1, double y1, double z1,
                               uint32_t material)
{
    ns_object o;
    memset(&o, 0, sizeof o);
    o.shape = NS_SHAPE_BOX;
    set3(o.min, x0, y0, z0);
    set3(o.max, x1, y1, z1);
    o.material = material;
    return o;
}

static inline ns_object plane(double py, uint32_t material)
{
    ns_object o;
    memset(&o, 0, sizeof o);
    o.shape = NS_SHAPE_PLANE;
    set3(o.point, 0, py, 0);
    set3(o.normal, 0, 1, 0);
    o.material = material;
    return o;
}

/* A point light of unit intensity at height a above a flat refracting face (ior n, light
 * outside), seen from depth h below it, r apart along the face: the single refraction by
 * bisection on the inside angle t_t (a tan t_o + h tan t_t = r, sin t_o = n sin t_t), and
 * the irradiance across the refracted ray at depth h, T sin t_o / (r cos t_t dr/dt_o) with
 * T = 1 - F (unpolarised) and dr/dt_o = a / cos^2 t_o + h cos t_o / (n cos^3 t_t): the
 * pencil of solid angle sin t_o dt_o dphi lands on r dphi by dr cos t_t. *tan_t gives the
 * refraction point (r_in = h tan t_t from the foot of x), *cos_t the path h / cos t_t. */
static inline double planar_refracted_point(double a, double h, double r, double n, double *cos_t,
                                            double *tan_t)
{
    double lo = 0, hi = asin(1 / n);
    for (int it = 0; it < 100; it++) {
        double ti = 0.5 * (lo + hi), to = asin(fmin(1, n * sin(ti)));
        if (a * tan(to) + h * tan(ti) < r)
            lo = ti;
        else
            hi = ti;
    }
    double ti = 0.5 * (lo + hi), to = asin(fmin(1, n * sin(ti)));
    *cos_t = cos(ti);
    *tan_t = tan(ti);
    double ci = cos(to), ct = cos(ti), eta = 1 / n;
    /* Fresnel of the light arriving from outside at t_o (cos of the refracted ray: ct). */
    double rs = (eta * ci - ct) / (eta * ci + ct), rp = (ci - eta * ct) / (ci + eta * ct);
    double transmit = 1 - 0.5 * (rs * rs + rp * rp);
    if (r < 1e-9 * (a + h))
        return transmit / ((a + h / n) * (a + h / n));
    double dr = a / (ci * ci) + h * ci / (n * ct * ct * ct);
    return transmit * sin(to) / (r * ct * dr);
}

/* Points a scene at its lists of materials, objects and lights (which must outlive it). */
static inline void scene_lists(ns_scene *s, const ns_material *materials, uint32_t material_count,
                               const ns_object *objects, uint32_t object_count,
                               const ns_light *lights, uint32_t light_count)
{
    s->materials = materials;
    s->material_count = material_count;
    s->objects = objects;
    s->object_count = object_count;
    s->lights = lights;
    s->light_count = light_count;
}

static inline ns_light light(ns_light_type type, double r, double g, double b)
{
    ns_light l;
    memset(&l, 0, sizeof l);
    l.type = type;
    set3(l.color, r, g, b);
    return l;
}

/* The camera's ray through image position (u, v) in [0,1]^2 (u right, v down), derived
 * here from the documented contract (horizontal fov, row 0 at the top) in double. */
static inline void camera_ray(const ns_camera *c, double u, double v, double dir[3])
{
    double f[3], r[3], up[3], n;
    for (int k = 0; k < 3; k++)
        f[k] = c->look_at[k] - c->position[k];
    n = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
    for (int k = 0; k < 3; k++)
        f[k] /= n;
    r[0] = f[1] * c->up[2] - f[2] * c->up[1];
    r[1] = f[2] * c->up[0] - f[0] * c->up[2];
    r[2] = f[0] * c->up[1] - f[1] * c->up[0];
    n = sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]);
    for (int k = 0; k < 3; k++)
        r[k] /= n;
    up[0] = r[1] * f[2] - r[2] * f[1];
    up[1] = r[2] * f[0] - r[0] * f[2];
    up[2] = r[0] * f[1] - r[1] * f[0];
    double tx = tan(c->fov_deg * M_PI / 360.0), ty = tx * c->height / c->width;
    for (int k = 0; k < 3; k++)
        dir[k] = f[k] + r[k] * (2 * u - 1) * tx + up[k] * (1 - 2 * v) * ty;
    n = sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    for (int k = 0; k < 3; k++)
        dir[k] /= n;
}

/* Renders s in ctx; a failure is a failed test, its message printed. */
static inline int render_ok_in(ns_context *ctx, const ns_scene *s, ns_image *img,
                               ns_render_stats *stats)
{
    ns_error err = {0};
    int status = ns_render(ctx, s, img, stats, &err);
    if (status)
        fprintf(stderr, "ns_render: %s (%s)\n", err.message, ns_status_name(status));
    CHECK_INT(status, NS_OK);
    return status == NS_OK;
}

static inline int render_ok(const ns_scene *s, ns_image *img, ns_render_stats *stats)
{
    return render_ok_in(test_context(), s, img, stats);
}

static inline const float *pixel_at(const ns_image *img, uint32_t x, uint32_t y)
{
    return img->rgb + 3 * ((size_t)y * img->width + x);
}

/* Mean of each channel over the image. */
static inline void image_mean(const ns_image *img, double out[3])
{
    size_t n = (size_t)img->width * img->height;
    for (int c = 0; c < 3; c++)
        out[c] = 0;
    for (size_t i = 0; i < n; i++)
        for (int c = 0; c < 3; c++)
            out[c] += img->rgb[3 * i + c] / (double)n;
}

/* Image means over seeds 1 to `seeds` of s (each its own render), averaged: what a noisy
 * reference or estimate is compared by. 0, or -1 when a render failed (checked). */
static inline int image_mean_over_seeds(ns_scene s, uint32_t seeds, double out[3])
{
    for (int c = 0; c < 3; c++)
        out[c] = 0;
    for (uint32_t seed = 1; seed <= seeds; seed++) {
        s.render.seed = seed;
        ns_image img = {0};
        double mean[3];
        if (!render_ok(&s, &img, NULL))
            return -1;
        image_mean(&img, mean);
        ns_image_free(&img);
        for (int c = 0; c < 3; c++)
            out[c] += mean[c] / seeds;
    }
    return 0;
}

/* The glass rod of the light-guide tests (gpu_bounded_beams, gpu_boundary, gpu_single): a
 * box 1 x 6 x 1 standing on y = 0, of mfp 2, albedo 0.95 / 0.8 / 0.5, g 0, ior 1.5, which
 * guides light that enters its top face by total internal reflection at its sides. */
static inline void glass_rod(ns_material *m, ns_object *rod)
{
    const double albedo[3] = {0.95, 0.8, 0.5};
    double sigma_s[3], sigma_a[3];
    for (int c = 0; c < 3; c++) {
        sigma_s[c] = albedo[c] / 2;
        sigma_a[c] = (1 - albedo[c]) / 2;
    }
    *m = medium(sigma_s, sigma_a, 1.5);
    *rod = cuboid(-0.5, 0, -0.5, 0.5, 6, 0.5, 0);
}

/* A small scene with every component lit: a unit medium sphere (sigma_s 4, 3, 2; ior 1.4;
 * g 0.5) above a diffuse floor, under a directional and an environment light, seen from
 * (0, 1, 5). The lists are the caller's and must outlive s; s's other fields are untouched. */
static inline void lit_medium_sphere(ns_scene *s, ns_material mats[2], ns_object objs[2],
                                     ns_light lights[2])
{
    set3(s->camera.position, 0, 1, 5);
    set3(s->camera.look_at, 0, 0, 0);
    mats[0] = diffuse(0.5, 0.5, 0.5);
    mats[1] = medium((double[3]){4, 3, 2}, (double[3]){0.1, 0.2, 0.3}, 1.4);
    mats[1].g = 0.5f;
    objs[0] = plane(-1, 0);
    objs[1] = sphere(0, 0, 0, 1, 1);
    lights[0] = light(NS_LIGHT_DIRECTIONAL, 2, 2, 2);
    set3(lights[0].direction, 0, -0.8, -0.6);
    lights[1] = light(NS_LIGHT_ENVIRONMENT, 0.2, 0.2, 0.25);
    scene_lists(s, mats, 2, objs, 2, lights, 2);
}

#endif
