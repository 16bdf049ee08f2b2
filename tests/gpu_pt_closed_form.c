/* gpu_pt_closed_form.c — the reference path tracer against closed forms: Beer-Lambert
 * through an absorbing slab (index matched, and behind ior 1.5 faces with the Fresnel
 * series), the diffuse plane rho E cos / pi under a directional light, single scattering
 * of a directional light in a slab (next-event estimation from inside the medium), and the
 * error of the mean falling like 1/sqrt(spp). */
#include "gpu_util.h"

#define SIDE 16

static ns_scene pt_scene(void)
{
    ns_scene s = base_scene(SIDE, SIDE, 5);
    s.render.method = NS_METHOD_PT;
    s.render.components = NS_COMPONENT_ALL;
    return s;
}

static ns_object slab(double y0, double y1, uint32_t material)
{
    ns_object o;
    memset(&o, 0, sizeof o);
    o.shape = NS_SHAPE_BOX;
    set3(o.min, -50, y0, -50);
    set3(o.max, 50, y1, 50);
    o.material = material;
    return o;
}

/* Camera 5 units above the origin looking straight down. */
static void look_down(ns_scene *s)
{
    set3(s->camera.position, 0, 5, 0);
    set3(s->camera.look_at, 0, 0, 0);
    set3(s->camera.up, 0, 0, -1);
}

/* Mean over all pixels of `expected(dir, channel)`, the camera ray through each pixel
 * centre (the renderer jitters within the pixel; at 5 deg the difference is < 1e-5). */
static double mean_expected(const ns_camera *cam, int c,
                            double (*expected)(const double d[3], int c))
{
    double sum = 0;
    for (uint32_t y = 0; y < cam->height; y++)
        for (uint32_t x = 0; x < cam->width; x++) {
            double d[3];
            camera_ray(cam, (x + 0.5) / cam->width, (y + 0.5) / cam->height, d);
            sum += expected(d, c);
        }
    return sum / ((double)cam->width * cam->height);
}

typedef struct image_stats {
    double mean, se; /* over pixels */
} image_stats;

static image_stats channel_stats(const ns_image *img, int c)
{
    double sum = 0, sum2 = 0;
    size_t n = (size_t)img->width * img->height;
    for (size_t i = 0; i < n; i++) {
        double v = img->rgb[3 * i + c];
        sum += v;
        sum2 += v * v;
    }
    image_stats st = {sum / n, 0};
    st.se = sqrt(fmax(0, sum2 / n - st.mean * st.mean) / n);
    return st;
}

/* Renders s and checks each channel's mean over the pixels against want(c): within 4
 * standard errors plus `slack` of it, the standard error itself below 1% (a test that can
 * fail). per_pixel: want is the mean of expected(ray, c) over the pixels instead. */
static void check_channel_means(const char *label, const ns_scene *s, double (*want)(int c),
                                double (*per_pixel)(const double d[3], int c), double slack)
{
    ns_image img;
    if (render_ok(s, &img, NULL))
        for (int c = 0; c < 3; c++) {
            image_stats st = channel_stats(&img, c);
            double expected = per_pixel ? mean_expected(&s->camera, c, per_pixel) : want(c);
            fprintf(stderr, "  %s, channel %d: %.6f +- %.6f, expected %.6f\n", label, c, st.mean,
                    st.se, expected);
            CHECK(st.se < 0.01 * expected);
            CHECK_NEAR(st.mean, expected, 4 * st.se + slack * expected);
        }
    ns_image_free(&img);
}

/* ---------------------------------------------------------------------------------------
 * Beer-Lambert through an absorbing slab of thickness 1 (y in [-0.5, 0.5]) in front of a
 * uniform environment of radiance 1.
 * ------------------------------------------------------------------------------------- */
static const double slab_sigma_a[3] = {0.5, 1.0, 2.0};

static double beer_expected(const double d[3], int c)
{
    return exp(-slab_sigma_a[c] / fabs(d[1]));
}

/* Behind ior 1.5 faces (near-normal incidence, R = 0.04): a uniform environment is seen
 * both through the slab and reflected by it: R_total + T_total with
 * T_total = (1-R)^2 T / (1 - R^2 T^2), R_total = R + (1-R)^2 R T^2 / (1 - R^2 T^2). */
static double fresnel_slab_expected(const double d[3], int c)
{
    (void)d;
    double r = 0.04, t = exp(-slab_sigma_a[c]);
    double denom = 1 - r * r * t * t;
    return (1 - r) * (1 - r) * t / denom + r + (1 - r) * (1 - r) * r * t * t / denom;
}

static void check_slab(double ior, double (*expected)(const double d[3], int c))
{
    ns_scene s = pt_scene();
    look_down(&s);
    ns_material m = medium((double[3]){0, 0, 0}, slab_sigma_a, ior);
    ns_object o = slab(-0.5, 0.5, 0);
    ns_light l = light(NS_LIGHT_ENVIRONMENT, 1, 1, 1);
    scene_lists(&s, &m, 1, &o, 1, &l, 1);
    s.render.spp = 256;
    ns_image img;
    if (render_ok(&s, &img, NULL))
        for (int c = 0; c < 3; c++) {
            image_stats st = channel_stats(&img, c);
            double want = mean_expected(&s.camera, c, expected);
            fprintf(stderr, "  ior %.1f channel %d: %.5f +- %.5f, expected %.5f\n", ior, c, st.mean,
                    st.se, want);
            CHECK(st.se < 0.01 * want);
            CHECK_NEAR(st.mean, want, 4 * st.se + 1e-4);
        }
    ns_image_free(&img);
}

static void test_beer_lambert_index_matched(void)
{
    check_slab(1.0, beer_expected);
}

static void test_beer_lambert_dielectric(void)
{
    check_slab(1.5, fresnel_slab_expected);
}

/* ---------------------------------------------------------------------------------------
 * A diffuse plane under a directional light: rho E cos(theta) / pi, no noise.
 * ------------------------------------------------------------------------------------- */
static void test_diffuse_plane(void)
{
    ns_scene s = pt_scene();
    look_down(&s);
    ns_material m = diffuse(0.2, 0.5, 0.8);
    ns_object o = plane(0, 0);
    double theta = 60 * M_PI / 180;
    ns_light l = light(NS_LIGHT_DIRECTIONAL, 1, 2, 3);
    set3(l.direction, sin(theta), -cos(theta), 0);
    scene_lists(&s, &m, 1, &o, 1, &l, 1);
    s.render.spp = 2;
    ns_image img;
    if (render_ok(&s, &img, NULL)) {
        const double rho[3] = {0.2, 0.5, 0.8}, e[3] = {1, 2, 3};
        double worst = 0;
        for (size_t i = 0; i < SIDE * SIDE; i++)
            for (int c = 0; c < 3; c++) {
                double want = rho[c] * e[c] * cos(theta) / M_PI;
                worst = fmax(worst, fabs(img.rgb[3 * i + c] / want - 1));
            }
        CHECK_NEAR(worst, 0, 1e-5);
    }
    ns_image_free(&img);
}

/* ---------------------------------------------------------------------------------------
 * Single scattering: a slab y in [-1, 0], index matched, lit from straight above by a
 * directional light of irradiance 1, seen from straight above. Light scattered once
 * straight back (cos = -1):  L = sigma_s E p_HG(-1) (1 - exp(-2 sigma_t T)) / (2 sigma_t).
 * ------------------------------------------------------------------------------------- */
static const double ss_sigma_s[3] = {0.5, 1.0, 1.5}, ss_sigma_a[3] = {0.1, 0.1, 0.1};
static const double ss_g = 0.5;

static double single_expected(const double d[3], int c)
{
    double st = ss_sigma_s[c] + ss_sigma_a[c];
    double mu = fabs(d[1]); /* path length factor of the camera ray */
    /* Light travels down (0, -1, 0) before the event and along -d after it. */
    double cos_t = -d[1] * -1.0;
    double denom = 1 + ss_g * ss_g - 2 * ss_g * cos_t;
    double phase = (1 - ss_g * ss_g) / (4 * M_PI * denom * sqrt(denom));
    /* Along the camera ray s in [0, 1/mu]: depth s mu, attenuation exp(-st s (1 + mu)). */
    double k = st * (1 + mu);
    return ss_sigma_s[c] * phase * (1 - exp(-k / mu)) / k;
}

static ns_scene single_scene(ns_material *m, ns_object *o, ns_light *l)
{
    ns_scene s = pt_scene();
    look_down(&s);
    *m = medium(ss_sigma_s, ss_sigma_a, 1.0);
    m->g = (float)ss_g;
    *o = slab(-1, 0, 0);
    *l = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(l->direction, 0, -1, 0);
    scene_lists(&s, m, 1, o, 1, l, 1);
    s.render.components = NS_COMPONENT_SINGLE;
    return s;
}

static void test_single_scattering_slab(void)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = single_scene(&m, &o, &l);
    s.render.spp = 64;
    check_channel_means("single", &s, NULL, single_expected, 2e-4);
}

/* Single scattering of a sphere light (centre (2, 2, 0), radius 1, radiance 1) in the same
 * slab, seen straight down through a 1-degree field of view. Next-event estimation samples
 * the light's cone from each scattering event; the phase-sampled continuation often hits
 * the light too and must not be counted again. Expected value for the central ray, by
 * quadrature over depth z and the cone (cos theta, phi):
 *   L = int_0^1 sigma_s e^{-sigma_t z} int_cone p(dot(d, wi)) e^{-sigma_t z / wi_y} dw dz.
 * Over the symmetric pixel grid the first-order change across the 0.09-wide patch cancels;
 * what is left is below 1e-3. */
static double sphere_light_expected(int c)
{
    const double centre[3] = {2, 2, 0}, radius = 1;
    const int nz = 200, nc = 64, nphi = 64;
    double st = ss_sigma_s[c] + ss_sigma_a[c], g = ss_g, total = 0;
    for (int iz = 0; iz < nz; iz++) {
        double z = (iz + 0.5) / nz;
        double v[3] = {centre[0], centre[1] + z, centre[2]};
        double dist = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        double axis[3] = {v[0] / dist, v[1] / dist, v[2] / dist};
        double cos_max = sqrt(1 - radius * radius / (dist * dist));
        /* Basis around the axis (it lies in the x-y plane). */
        double t1[3] = {-axis[1], axis[0], 0}, t2[3] = {0, 0, 1};
        double cone = 0;
        for (int ic = 0; ic < nc; ic++) {
            double ct = cos_max + (1 - cos_max) * (ic + 0.5) / nc;
            double stheta = sqrt(1 - ct * ct);
            for (int ip = 0; ip < nphi; ip++) {
                double phi = 2 * M_PI * (ip + 0.5) / nphi;
                double wi_y = axis[1] * ct + t1[1] * stheta * cos(phi) + t2[1] * stheta * sin(phi);
                double cos_s = -wi_y; /* d = (0, -1, 0) */
                double denom = 1 + g * g - 2 * g * cos_s;
                double phase = (1 - g * g) / (4 * M_PI * denom * sqrt(denom));
                cone += phase * exp(-st * z / wi_y);
            }
        }
        cone *= 2 * M_PI * (1 - cos_max) / (nc * nphi);
        total += ss_sigma_s[c] * exp(-st * z) * cone / nz;
    }
    return total;
}

static void test_single_scattering_sphere_light(void)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = single_scene(&m, &o, &l);
    s.camera.fov_deg = 1;
    l = light(NS_LIGHT_SPHERE, 1, 1, 1);
    set3(l.position, 2, 2, 0);
    l.radius = 1;
    s.render.spp = 64;
    check_channel_means("sphere light, single", &s, sphere_light_expected, NULL, 1e-3);
}

/* ---------------------------------------------------------------------------------------
 * Single scattering behind a refracting face (ior 1.5): the specular connection. A deep
 * slab y in [-30, 0] (no light comes back from its floor), seen from above.
 * ------------------------------------------------------------------------------------- */
static const double dielectric_ior = 1.5;

/* Unpolarised Fresnel reflectance, eta = n_incident / n_transmitted; cos_t returned. */
static double fresnel_reflectance(double cos_i, double eta, double *cos_t)
{
    double sin2_t = eta * eta * (1 - cos_i * cos_i);
    if (sin2_t >= 1)
        return *cos_t = 0, 1;
    *cos_t = sqrt(1 - sin2_t);
    double rs = (eta * cos_i - *cos_t) / (eta * cos_i + *cos_t);
    double rp = (cos_i - eta * *cos_t) / (cos_i + eta * *cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

static double hg(double cos_t, double g)
{
    double denom = 1 + g * g - 2 * g * cos_t;
    return (1 - g * g) / (4 * M_PI * denom * sqrt(denom));
}

/* The light's direction of travel: 50 degrees from the vertical, towards +x. */
static const double oblique_sin = 0.766044443118978, oblique_cos = 0.642787609686539;

/* Directional light of irradiance E = 1 through the face (Hanrahan & Krueger 1993): inside,
 * the refracted beam has irradiance T_i E mu_i' / mu_i across it; seen along a camera ray
 * refracted to cosine mu_o, the single scattering sums to sigma_s p E_in mu_i /
 * (sigma_t (mu_i + mu_o)), and leaves with T_o / n^2:
 *   L = T_i T_o E mu_i' sigma_s p / (sigma_t (mu_i + mu_o) n^2). */
static double refracted_single_expected(const double d[3], int c)
{
    double eta = 1 / dielectric_ior, mu_i, mu_o;
    double t_i = 1 - fresnel_reflectance(oblique_cos, eta, &mu_i);
    double mu_o_out = fabs(d[1]);
    double t_o = 1 - fresnel_reflectance(mu_o_out, eta, &mu_o);
    /* Propagation directions inside: the light's (down, towards +x), the camera ray's. */
    double light_in[3] = {eta * oblique_sin, -mu_i, 0};
    double cam_in[3] = {eta * d[0], -mu_o, eta * d[2]};
    /* Scattered from the light's direction into the camera ray's reverse. */
    double cos_s = -(light_in[0] * cam_in[0] + light_in[1] * cam_in[1] + light_in[2] * cam_in[2]);
    double st = ss_sigma_s[c] + ss_sigma_a[c];
    return t_i * t_o * oblique_cos * ss_sigma_s[c] * hg(cos_s, ss_g) /
           (st * (mu_i + mu_o) * dielectric_ior * dielectric_ior);
}

static ns_scene refracted_scene(ns_material *m, ns_object *o, ns_light *l)
{
    ns_scene s = single_scene(m, o, l);
    m->ior = (float)dielectric_ior;
    *o = slab(-30, 0, 0);
    set3(l->direction, oblique_sin, -oblique_cos, 0);
    return s;
}

static void test_single_scattering_refracted_directional(void)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = refracted_scene(&m, &o, &l);
    s.render.spp = 64;
    check_channel_means("refracted directional, single", &s, NULL, refracted_single_expected, 1e-3);
}

/* A point light of intensity 1 at height a = 2 above the face and 1.5 to the side of the
 * central camera ray (straight down, 1-degree field of view). At each depth b the light
 * bends once (planar_refracted_point, gpu_util.h: the refraction point by bisection and the
 * refracted pencil's irradiance), then attenuation, phase and the quadrature over depth,
 * and T_o / n^2 on the way out (T_o at normal incidence). A derivation independent of the
 * shader's numerical Jacobian. */
static double refracted_point_expected(int c)
{
    const double a = 2, side = 1.5, n = dielectric_ior, st = ss_sigma_s[c] + ss_sigma_a[c];
    double mu_o;
    double t_o = 1 - fresnel_reflectance(1, 1 / n, &mu_o);
    const int steps = 4000;
    const double depth = 30 / st;
    double sum = 0;
    for (int k = 0; k < steps; k++) {
        double b = (k + 0.5) / steps * depth, cos_t, tan_t;
        double irradiance = planar_refracted_point(a, b, side, n, &cos_t, &tan_t) * exp(-st * b / cos_t);
        /* Light travels (-sin t_t, -cos t_t, 0), then up towards the camera: cos = -cos t_t. */
        sum += ss_sigma_s[c] * hg(-cos_t, ss_g) * irradiance * exp(-st * b);
    }
    return t_o * sum * depth / steps / (n * n);
}

static void test_single_scattering_refracted_point(void)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = refracted_scene(&m, &o, &l);
    s.camera.fov_deg = 1;
    l = light(NS_LIGHT_POINT, 1, 1, 1);
    set3(l.position, 1.5, 2, 0);
    s.render.spp = 64;
    check_channel_means("refracted point, single", &s, refracted_point_expected, NULL, 2e-3);
}

/* RMS over pixels of (pixel - expected) at N and 4N samples per pixel: ratio 2 when the
 * estimator is unbiased with finite variance (bias would flatten the ratio towards 1). */
static double rms_error(int spp, uint32_t seed)
{
    ns_material m;
    ns_object o;
    ns_light l;
    ns_scene s = single_scene(&m, &o, &l);
    s.render.spp = (uint32_t)spp;
    s.render.seed = seed;
    ns_image img;
    double sum2 = 0;
    if (render_ok(&s, &img, NULL))
        for (uint32_t y = 0; y < SIDE; y++)
            for (uint32_t x = 0; x < SIDE; x++) {
                double d[3];
                camera_ray(&s.camera, (x + 0.5) / SIDE, (y + 0.5) / SIDE, d);
                for (int c = 0; c < 3; c++) {
                    double e = pixel_at(&img, x, y)[c] - single_expected(d, c);
                    sum2 += e * e;
                }
            }
    else
        sum2 = NAN;
    ns_image_free(&img);
    return sqrt(sum2 / (SIDE * SIDE * 3));
}

static void test_error_falls_like_inverse_sqrt_spp(void)
{
    double e4 = rms_error(4, 11), e16 = rms_error(16, 12), e64 = rms_error(64, 13);
    fprintf(stderr, "  rms error: spp 4 %.3g, spp 16 %.3g, spp 64 %.3g (ratios %.2f, %.2f)\n", e4,
            e16, e64, e4 / e16, e16 / e64);
    /* 768 values per image: the RMS is known to ~3%, a ratio to ~5%. */
    CHECK_NEAR(e4 / e16, 2.0, 0.35);
    CHECK_NEAR(e16 / e64, 2.0, 0.35);
}

int main(void)
{
    RUN(test_diffuse_plane);
    RUN(test_beer_lambert_index_matched);
    RUN(test_beer_lambert_dielectric);
    RUN(test_single_scattering_slab);
    RUN(test_single_scattering_sphere_light);
    RUN(test_single_scattering_refracted_directional);
    RUN(test_single_scattering_refracted_point);
    RUN(test_error_falls_like_inverse_sqrt_spp);
    ns_context_destroy(test_context());
    return harness_report();
}
