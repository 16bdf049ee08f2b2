/* gpu_boundary.c — render.boundary "walks" (the boundary-crossing correction) against the
 * path tracer, per order, where the paper's infinite-medium tables are known to be wrong:
 *   (a) an index-matched sphere ~3.3 mfp across (a cloud): the tables go on scattering light
 *       that has left, too bright;
 *   (b) index-matched slabs 0.5, 2 and 8 mfp thick under a directional light (the 2 and 8 mfp
 *       ones also with Monte Carlo tables of the exact material, method "table": within 3%),
 *       and the thinnest one's double scattering (nn, and exact tables within 3%);
 *   (c) a sphere 8 mfp across at ior 1.5: Fresnel and total internal reflection send light
 *       back that the tables never see, too dark;
 *   (d) two boxes face to face: light that leaves one enters the other.
 *   (e) a sphere 200 mfp across: locally a half-space, where the correction must fade away
 *       from the boundary.
 *   (f) a glass rod lit through its top face, which guides the light down by total internal
 *       reflection: single scattering, the walks' reflected beams' blurred first order;
 *   (g) the same rod lit on two faces: single scattering through both (single_box_faces.comp).
 * Each case checks the image mean of nn with the correction within a tolerance of pt's per
 * channel, and that without it nn is off by more (so that the scene tells them apart).
 * Image means over 32 x 32 pixels (the slabs: 16 x 16). Also: off is the default and adds no
 * source; the other methods refuse the setting naming it. */
#include "gpu_mc.h"
#include "pipelines.h"

typedef struct means {
    double v[3];
    uint64_t sources;
} means;

static int mean_in(ns_context *ctx, ns_scene s, ns_method method, ns_boundary boundary,
                   uint32_t spp, means *out)
{
    s.render.method = method;
    s.render.boundary = boundary;
    s.render.spp = spp;
    ns_image img = {0};
    ns_render_stats stats = {0};
    if (!render_ok_in(ctx, &s, &img, &stats))
        return -1;
    image_mean(&img, out->v);
    out->sources = stats.boundary_sources;
    ns_image_free(&img);
    return 0;
}

static int mean_of(ns_scene s, ns_method method, ns_boundary boundary, uint32_t spp, means *out)
{
    return mean_in(test_context(), s, method, boundary, spp, out);
}

/* walks_tolerance: |walks / pt - 1| allowed; off_off: |off / pt - 1| required; closer: walks
 * at least this many times closer to pt than off, in every channel. nn traces one camera
 * path per pixel: the noise of its image mean is the VRLs', not the camera's, while its
 * gather costs in proportion to camera paths (at 4 per pixel the slabs alone took 460 s;
 * the means moved by at most 1.1 points at 1). pt_means, when not NULL, receives pt's (0 where
 * a render failed). */
static void compare_at(const char *name, ns_scene s, uint32_t components, uint32_t pt_spp,
                       uint32_t walks_spp, double walks_tolerance, double off_off, double closer,
                       means *pt_means)
{
    s.render.components = components;
    means pt = {0}, walks, off;
    int failed = mean_of(s, NS_METHOD_PT, NS_BOUNDARY_OFF, pt_spp, &pt);
    if (pt_means)
        *pt_means = pt;
    if (failed || mean_of(s, NS_METHOD_NN, NS_BOUNDARY_WALKS, walks_spp, &walks) ||
        mean_of(s, NS_METHOD_NN, NS_BOUNDARY_OFF, 1, &off))
        return;
    CHECK(walks.sources > 0);
    CHECK(off.sources == 0);
    for (int c = 0; c < 3; c++) {
        fprintf(stderr, "  %s, %s, channel %d: pt %.6g, nn walks %.6g (%+.1f%%), off %.6g (%+.1f%%)\n",
                name, ns_component_name(components), c, pt.v[c],
                walks.v[c], 100 * (walks.v[c] / pt.v[c] - 1), off.v[c], 100 * (off.v[c] / pt.v[c] - 1));
        CHECK(pt.v[c] > 0);
        CHECK(fabs(walks.v[c] / pt.v[c] - 1) < walks_tolerance);
        CHECK(fabs(off.v[c] / pt.v[c] - 1) > off_off);
        CHECK(closer * fabs(walks.v[c] / pt.v[c] - 1) < fabs(off.v[c] / pt.v[c] - 1));
    }
}

/* nn with one camera path per pixel (compare_at). */
static void compare(const char *name, ns_scene s, uint32_t components, uint32_t pt_spp,
                    double walks_tolerance, double off_off, double closer)
{
    compare_at(name, s, components, pt_spp, 1, walks_tolerance, off_off, closer, NULL);
}

static ns_material material(const double albedo[3], double mfp, double g, double ior)
{
    double sigma_s[3], sigma_a[3];
    for (int c = 0; c < 3; c++) {
        sigma_s[c] = albedo[c] / mfp;
        sigma_a[c] = (1 - albedo[c]) / mfp;
    }
    ns_material m = medium(sigma_s, sigma_a, ior);
    m.g = (float)g;
    return m;
}

/* One medium m, its objects o[0, count) and one light. */
static ns_scene medium_scene(ns_material *m, ns_object *o, uint32_t count, ns_light *l)
{
    ns_scene s = base_scene(32, 32, 30);
    scene_lists(&s, m, 1, o, count, l, 1);
    s.render.vrls = 40000;
    /* The product's default adaptive gather (one gathered pixel per 2 x 2 tile where the
     * image is smooth), at about a quarter of the gather, which was most of this test's time
     * (178 s to 80 s). The "Measured" figures below gathered every pixel; with tiles the image
     * means moved by at most 0.3 points on the slabs, 1 on the cloud, 2.1 on the refracting
     * sphere and 2.1 on the facing boxes (2026-11-29), well inside every tolerance. */
    s.render.gather_tile = 2;
    s.render.seed = 1;
    return s;
}

/* An index-matched sphere of one medium (mfp 1) under a directional light from above, seen
 * from `camera` towards its centre. One such scene at a time: the scene keeps pointers to
 * its lists, which are static. */
static ns_scene lit_sphere_scene(const double albedo[3], double g, double radius,
                                 const double camera[3])
{
    static ns_material m;
    static ns_object ball;
    static ns_light sun;
    m = material(albedo, 1.0, g, 1.0);
    ball = sphere(0, 0, 0, radius, 0);
    sun = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(sun.direction, 0.3, -1, -0.2);
    ns_scene s = medium_scene(&m, &ball, 1, &sun);
    set3(s.camera.position, camera[0], camera[1], camera[2]);
    set3(s.camera.look_at, 0, 0, 0);
    return s;
}

/* An index-matched sphere 3.3 mfp across (a cloud). */
static ns_scene cloud_scene(void)
{
    static const double albedo[3] = {0.909, 0.8, 0.95}, camera[3] = {0, 0, 9};
    return lit_sphere_scene(albedo, 0.0, 1.65, camera);
}

static void test_cloud(void)
{
    ns_scene s = cloud_scene();
    /* Measured (2026-12-01, the tiles' representatives weighed where they are): walks -0.5
     * / -0.7 / +0.3%, off +88 / +60 / +111% (weighed half a pixel off: -1.8 / -2.2 /
     * -1.0%; 2026-11-27, ghosts with the blurred first order: -5.1 / -5.0 / -4.0%).
     * Over six seeds (2026-12-03, nscatter render of this scene, each against its own pt at
     * 256 spp): walks 0.975 to 1.005 (mean 0.988 / 0.985 / 0.995), exact tables 0.995 / 0.993
     * / 0.996, nn over them 0.992 / 0.992 / 1.000; pt itself moved by up to 1.7% between seeds
     * (against pt pooled over the six, walks 0.979 to 1.010). So pt takes 1,024 spp here and
     * walks are held to issue 15's 3% per channel (seed 1: -0.4 / -0.7 / +0.4%; -0.7 / -1.0 /
     * +0.1% with the double network fine-tuned the same day). */
    /* Multiple scattering alone: the VRLs read its table, the walks' sources double +
     * multiple. The render says so, and both tables come from one walk: the first test of
     * the program, so its render is what makes the second three's shader (docs/rendering.md,
     * *The second three*). */
    const gpu_pipeline *second = &test_context()->pipelines[NS_PIPELINE_ACCUMULATE_SECOND];
    CHECK(second->pipeline == VK_NULL_HANDLE);
    compare("cloud sphere 3.3 mfp, ior 1", s, NS_COMPONENT_MULTIPLE, 1024, 0.03, 0.3, 8);
    CHECK(second->pipeline != VK_NULL_HANDLE);
}

/* The slabs' scene: a box 60 wide and `thickness` mfp thick of one medium (albedo 0.909 /
 * 0.5 / 0.99, g 0.5, index matched) lit from straight above, seen from above at 30 degrees.
 * One at a time: the scene points at this function's static lists. */
static ns_scene slab_scene(double thickness)
{
    static const double albedo[3] = {0.909, 0.5, 0.99};
    static ns_material m;
    static ns_object box;
    static ns_light sun;
    m = material(albedo, 1.0, 0.5, 1.0);
    memset(&box, 0, sizeof box);
    box.shape = NS_SHAPE_BOX;
    set3(box.min, -30, -thickness, -30);
    set3(box.max, 30, 0, 30);
    sun = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(sun.direction, 0, -1, 0);
    ns_scene s = medium_scene(&m, &box, 1, &sun);
    set3(s.camera.position, 0, 10, 17.32);
    set3(s.camera.look_at, 0, 0, 0);
    s.render.vrls = 100000; /* the slab is 60 wide: VRLs spread over all of it */
    /* 16 x 16 pixels: the slab fills the image, whose mean's noise is the VRLs' for nn (and
     * pt keeps its paths at 1024 spp), and the gather costs in proportion to the pixels (the
     * slabs 68.7 s to 49.5 s; the means moved by at most 0.8 points, 2026-11-30). */
    s.camera.width = s.camera.height = 16;
    return s;
}

/* Scene s (its components set) rendered with Monte Carlo tables of the exact material
 * (method "table" with the walks, `paths` light paths) within issue 15's 3% of pt's means in
 * every channel. That is the estimator's own error; nn's tolerances hold the network's on
 * top of it (docs/scattering.md, *The slabs with exact tables*). */
static void check_exact_tables(const char *name, ns_scene s, uint32_t paths, const means *pt)
{
    if (!(pt->v[0] > 0)) /* pt failed: compare_at said so */
        return;
    s.render.vrls = paths;
    means exact;
    if (mean_in(mc_test_context(), s, NS_METHOD_TABLE, NS_BOUNDARY_WALKS, 1, &exact))
        return;
    CHECK(exact.sources > 0);
    for (int c = 0; c < 3; c++) {
        fprintf(stderr,
                "  %s, %s, exact tables, %u light paths, channel %d: pt %.6g, table walks %.6g "
                "(%+.1f%%)\n",
                name, ns_component_name(s.render.components), paths, c, pt->v[c], exact.v[c],
                100 * (exact.v[c] / pt->v[c] - 1));
        CHECK(fabs(exact.v[c] / pt->v[c] - 1) < 0.03);
    }
}

/* Multiple scattering; exact_paths, when not 0: also with exact tables (check_exact_tables). */
static void test_slab(double thickness, double walks_tolerance, double off_off, double closer,
                      uint32_t exact_paths)
{
    ns_scene s = slab_scene(thickness);
    char name[64];
    snprintf(name, sizeof name, "slab %g mfp, ior 1", thickness);
    means pt;
    compare_at(name, s, NS_COMPONENT_MULTIPLE, 1024, 1, walks_tolerance, off_off, closer, &pt);
    s.render.components = NS_COMPONENT_MULTIPLE;
    if (exact_paths)
        check_exact_tables(name, s, exact_paths, &pt);
}

/* With exact tables ("table"; 2026-12-03, six seeds, each against its own pt, means of the
 * ratios): 0.5 mfp 0.989 / 0.999 / 1.027, 2 mfp 1.000 / 0.994 / 1.022, 8 mfp 0.995 / 0.994 /
 * 0.999; nn over table (the networks alone) 0.5 mfp 1.025 / 0.980 / 0.900, 2 mfp 1.032 /
 * 1.008 / 1.064, 8 mfp 1.021 / 1.007 / 1.043. table's albedo-0.99 channel by seed: 2 mfp
 * 0.964-1.077 at 100,000 light paths, 0.975-1.019 at 400,000, 1.001-1.007 at 700,000 (hence
 * 700,000 here); 8 mfp 0.979-1.013 at 100,000; 0.5 mfp 0.80-1.16 at 400,000 (the ghosts take
 * 96% of the infinite tables' blue away: too noisy to hold to 3%). docs/scattering.md, *The
 * slabs with exact tables*.
 * Over four seeds (2026-12-03; seed 1 is the test's): 0.5 mfp +5.0 / -0.6 / +0.5% (blue
 * +2.2 to -19.9%), 2 mfp +3.4 / +0.2 / +10.0% (blue +3.2 to +14.5%), 8 mfp +1.7 / +0.0 /
 * +4.7%: the albedo-0.99 channel reads high (docs/scattering.md, *A sphere 200 mfp across*).
 * Measured at 16 x 16 with the multiple network fine-tuned on its near field (2026-12-01,
 * docs/network.md): walks 0.5 mfp +8.3 / +0.4 / +2.1%, 2 mfp +2.0 / -0.1 / +3.0%, 8 mfp
 * +1.9 / +0.1 / +5.6% (off as below).
 * Measured at 16 x 16 (2026-11-30): walks / off 0.5 mfp +8.0 / +1.6 / -8.6% against +592 /
 * +154 / +2340%; 2 mfp +4.5 / +1.1 / +7.7% against +91 / +14 / +458%; 8 mfp +3.3 / +0.9 /
 * +7.8% against +31 / +5.6 / +168%.
 * Measured at 32 x 32 (2026-11-29, light paths stratified, walks with spectral MIS over the path),
 * walks / off against pt per channel (albedo 0.909 / 0.5 / 0.99): 0.5 mfp +7.2 / +0.9 /
 * -9.4% against +596 / +156 / +2349%; 2 mfp +5.0 / +1.5 / +8.2% against +92 / +14 / +460%;
 * 8 mfp +3.9 / +1.4 / +8.1% against +32 / +6.0 / +168% (stratified, MIS per event: 8 mfp
 * +2.4 / +1.3 / +2.4%). With independent light paths the same seed read walks 0.5 mfp +16.3
 * / +6.5 / +7.1%, 2 mfp +8.6 / +4.8 / +15.7%, 8 mfp +6.0 / +4.7 / +10.4% (off +35 / +10 /
 * +172% at 8 mfp): much of what looked like the tables' own error was where that seed's
 * VRLs fell (docs/scattering.md, *Stratified light paths*). The paper's model is off by
 * less in the albedo-0.5 channel (+14%, +6%), so off_off asks 10% and 4% there. */
static void test_slabs(void)
{
    /* Tolerances with room for another CPU's lavapipe to draw other samples: one seed's
     * image mean still moves by a few per cent (docs/scattering.md, *The phi bins' mean*). */
    test_slab(0.5, 0.2, 1.0, 3, 0);
    test_slab(2.0, 0.12, 0.1, 3, 700000);
    test_slab(8.0, 0.15, 0.04, 1.5, 100000);
    /* Double scattering, where the correction shows: the thinnest slab (2026-12-03, three
     * seeds, each against its own pt; one channel stands for three, the order's shape being
     * the albedo's alone): walks +3.5 / +4.2 / +1.1%, off +22.3% (seed 1), exact tables -0.8 /
     * -0.1 / -2.8%; with the double network fine-tuned the same day, seed 1's walks +3.0 ->
     * +1.6%. At 2 and 8 mfp off reads +2.5% and +2.3% (as walks: +1.9 and +2.3%), the
     * light's second event lying near the lit face: nothing there to tell them apart. */
    ns_scene s = slab_scene(0.5);
    means pt;
    compare_at("slab 0.5 mfp, ior 1", s, NS_COMPONENT_DOUBLE, 1024, 1, 0.06, 0.12, 3, &pt);
    s.render.components = NS_COMPONENT_DOUBLE;
    check_exact_tables("slab 0.5 mfp, ior 1", s, 100000, &pt);
}

/* A sphere 200 mfp across (issue 15's "where the correction must vanish away from the
 * boundary"): locally a half-space, so the infinite tables are wrong only by the light
 * that leaves through the face nearby, and the walks' sources sit at that face; a source
 * that leaked into the interior, or a correction that did not fade with the distance from
 * the boundary, would show over so much medium. The slabs' medium and light. */
static void test_large_sphere(void)
{
    static const double albedo[3] = {0.909, 0.5, 0.99}, camera[3] = {0, 150, 450};
    ns_scene s = lit_sphere_scene(albedo, 0.5, 100, camera);
    s.camera.width = s.camera.height = 16;
    /* The product's 2 x 2 tiles, where a pixel is some 14 mfp across: the upsampling must
     * weigh each representative where it is (until 2026-12-01 half a pixel off, this image
     * read 6-11% below every pixel gathered; scattering.md, *The tiles there*). A pixel this
     * wide spans e^2 to e^5 of the field near the lit side, so with one camera path per pixel
     * the image mean is the camera's noise: on eight seeds walks read -2.3 to +6.8% of pt
     * (their mean +1.9 / +0.4 / +2.8%). With 8 paths a pixel, four seeds each against its
     * own pt at 1,024 spp: -0.5 to +1.8 / -2.1 to +1.2 / -0.2 to +2.4% (2026-12-03); pt
     * itself moves by 1% between seeds at 1,024 spp, so it takes 4,096 here. Off: +35.5 /
     * +9.2 / +155.5%; the albedo-0.5 channel's off is nearly right already, so no "closer"
     * is asked, only that off is off (the correction fades inside). */
    s.render.gather_tile = 2;
    compare_at("sphere 200 mfp, ior 1", s, NS_COMPONENT_MULTIPLE, 4096, 8, 0.03, 0.05, 0.0, NULL);
}

/* Lit by a sphere light, not a directional one: behind a refracting boundary pt reaches a
 * point or directional light only through its light sub-paths, which cannot make a path
 * whose light reflects off the boundary between its last two scattering events (nothing
 * samples it: docs/reference.md), so against a delta light pt itself is low. A sphere light
 * pt reaches by its phase-sampled continuation, through any reflections. */
static void test_refracting_sphere(void)
{
    const double albedo[3] = {0.938, 0.8, 0.97};
    ns_material m = material(albedo, 1.0, 0.5, 1.5);
    ns_object ball = sphere(0, 0, 0, 4, 0);
    ns_light bulb = light(NS_LIGHT_SPHERE, 8, 8, 8);
    set3(bulb.position, 0, 15, 4.5);
    bulb.radius = 3;
    ns_scene s = medium_scene(&m, &ball, 1, &bulb);
    set3(s.camera.position, 0, 2, 20);
    set3(s.camera.look_at, 0, 0, 0);
    /* Measured (2026-12-01): walks +0.9 / -0.5 / +1.9%, off -27 / -22 / -27% (2026-11-27,
     * ghosts with the blurred first order: -1.5 / -3.0 / -1.1%; under the directional light
     * before: +11 / +8 / +12% against -18 / -13 / -17%, pt low). */
    compare("sphere 8 mfp, ior 1.5", s, NS_COMPONENT_MULTIPLE, 1024, 0.06, 0.15, 4);
}

/* Two index-matched boxes of one medium, 2 mfp wide, face to face across a gap of 0.1,
 * lit from above: much of the light that scatters in one leaves through its inner face into
 * the other. A walk that leaves its object goes on and enters the first scattering object
 * it meets (vrl_trace.comp; boundary.c makes the re-entered stretch a positive source), as
 * light that leaves a non-convex object and comes back does. Measured (2026-12-01): walks
 * +1.1 / -0.9 / +8.0% (-3.8 / -6.1 / +7.0% while every ghost of a medium that a walk
 * re-entered read its first order, not only those whose line comes back); without
 * re-entry (the walk ended where it left) -23 / -24 / -14%. Over six seeds (2026-12-03):
 * nn over exact tables ("table") 1.030 / 1.000 / 1.103, table over pt 1.009 / 1.003 / 1.017:
 * the blue excess is the multiple network's at albedo 0.99 (docs/scattering.md, *The slabs
 * with exact tables*). */
static void test_facing_boxes(void)
{
    const double albedo[3] = {0.95, 0.8, 0.99};
    ns_material m = material(albedo, 1.0, 0.0, 1.0);
    ns_object boxes[2];
    memset(boxes, 0, sizeof boxes);
    for (int i = 0; i < 2; i++) {
        double x0 = i ? 0.05 : -2.05;
        boxes[i].shape = NS_SHAPE_BOX;
        set3(boxes[i].min, x0, -1, -1);
        set3(boxes[i].max, x0 + 2, 1, 1);
    }
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(sun.direction, 0, -1, 0);
    ns_scene s = medium_scene(&m, boxes, 2, &sun);
    set3(s.camera.position, 0, 0, 9);
    set3(s.camera.look_at, 0, 0, 0);
    /* 0.15 (0.12 until the tables' own errors near a source were fixed, which raised the blue
     * channel from +7 to +9.6%: the error that reads high) still fails without re-entry in
     * the red and green channels (-23 / -24%). */
    compare("facing boxes 2 mfp, ior 1", s, NS_COMPONENT_MULTIPLE, 256, 0.15, 0.3, 2);
}

/* The glass rod (gpu_util.h, glass_rod) under `light`, framed from the side (10 x 48, every
 * pixel gathered), single scattering: the image means of pt at pt_spp and of nn with the
 * walks, and without them where off is given, each over four seeds. The lists are static:
 * one such scene at a time. */
static int rod_single_means(ns_light light, uint32_t pt_spp, double pt[3], double walks[3],
                            double off[3])
{
    static ns_material m;
    static ns_object rod;
    static ns_light lit;
    glass_rod(&m, &rod);
    lit = light;
    ns_scene s = medium_scene(&m, &rod, 1, &lit);
    s.camera.width = 10;
    s.camera.height = 48;
    s.camera.fov_deg = 5.6f;
    set3(s.camera.position, 0, 3, 14);
    set3(s.camera.look_at, 0, 3, 0);
    s.render.components = NS_COMPONENT_SINGLE;
    s.render.gather_tile = 1;
    s.render.method = NS_METHOD_PT;
    s.render.spp = pt_spp;
    if (image_mean_over_seeds(s, 4, pt))
        return -1;
    s.render.method = NS_METHOD_NN;
    s.render.spp = 1;
    s.render.boundary = NS_BOUNDARY_WALKS;
    if (image_mean_over_seeds(s, 4, walks))
        return -1;
    s.render.boundary = NS_BOUNDARY_OFF;
    return off ? image_mean_over_seeds(s, 4, off) : 0;
}

/* The glass rod (gpu_util.h, glass_rod) under a small sphere light just above its top face,
 * which the side faces do not see: every refracted beam meets a side wall at 48 degrees or
 * more from its normal (the critical angle is 41.8) and is guided down, so more than half of
 * the single scattering comes from light the walls reflected (single scattering connects
 * straight through the top face only: the rest is the walks' reflected beams' blurred first
 * order, gather.glsl). pt reaches the light only by
 * its escaping rays hitting the small sphere: its image mean over four seeds of 4,096
 * samples has a standard error near 1%. The image is framed on the rod (10 x 48) and every
 * pixel gathered. Measured (2026-12-03): this test's seeds -1.3%, off 0.38; -5.7% while each
 * reflected beam's first-order tube lost its part beyond the face the beam starts on (now
 * renormalised to the medium's side, gather.glsl first_order; docs/scattering.md, *The tube
 * at a face*), which this test fails by (checked). Before 2026-12-02 it read +1.4%:
 * single.comp took this large sphere, so near the face, as a point at its centre's distance,
 * whose light straight through the top face read 7% high (single.glsl, sphere_refracted), and
 * that hid the tubes' loss; 0.900 with an expected reflection's tube the widest (its chord
 * unknown). Against the same rod half as wide the walks still read lower (docs/scattering.md,
 * *The expected reflections' chords*), not tested. */
static void test_light_guide(void)
{
    ns_light bulb = light(NS_LIGHT_SPHERE, 10, 10, 10);
    set3(bulb.position, 0, 6.5, 0);
    bulb.radius = 0.4;
    double pt[3], walks[3], off[3];
    if (rod_single_means(bulb, 4096, pt, walks, off))
        return;
    for (int c = 0; c < 3; c++) {
        fprintf(stderr,
                "  glass rod, single, channel %d: pt %.6g, nn walks %.6g (%+.1f%%), off %.6g "
                "(%+.1f%%)\n",
                c, pt[c], walks[c], 100 * (walks[c] / pt[c] - 1), off[c],
                100 * (off[c] / pt[c] - 1));
        CHECK(pt[c] > 0);
        CHECK(fabs(walks[c] / pt[c] - 1) < 0.03);
        CHECK(off[c] / pt[c] < 0.7);
    }
}

/* A refracting box lit on two faces: the glass rod (gpu_util.h, glass_rod) beside a sphere
 * light that its +x and +z faces both see. Light reaches a
 * point inside through each (single_box_faces.comp, light_through_box_face); through the
 * face that the straight line towards the light crosses alone (the boundary's tangent plane,
 * which spheres and meshes still take) the image read 17.6% low (checked). The whole render
 * (walks included: light that the faces reflect inside before it scatters) against pt's
 * single order, image means over four seeds each (pt 2,048 samples a pixel: standard error
 * 0.3%); the image is framed on the rod. Measured (2026-12-02): +0.2% (+1.1% with the sphere
 * as a point at its centre's distance, single.glsl sphere_refracted). */
static void test_box_lit_on_two_faces(void)
{
    ns_light bulb = light(NS_LIGHT_SPHERE, 1, 1, 1);
    set3(bulb.position, 4, 3, 2);
    bulb.radius = 1.5;
    double pt[3], nn[3];
    if (rod_single_means(bulb, 2048, pt, nn, NULL))
        return;
    for (int c = 0; c < 3; c++) {
        fprintf(stderr, "  channel %d: pt %.6g, nn %.6g (%+.1f%%)\n", c, pt[c], nn[c],
                100 * (nn[c] / pt[c] - 1));
        CHECK(pt[c] > 0);
        CHECK(fabs(nn[c] / pt[c] - 1) < 0.05);
    }
}

/* Double scattering in an index-matched convex object: the light scattered once on a VRL
 * that leaves the object never scatters again inside it, so the only sources with walks are
 * the ghosts of the entry stretches, the beams past their exits (scatter_render.c,
 * vrls_bounded), which the bounded beams subtract VRL by VRL: the two images agree within
 * the light paths' noise. The other ghosts take nothing away (boundary.c,
 * ns_boundary_source_orders): when they read the blurred first-order table, its tube reached
 * inside near each exit and removed light that is there (this sphere: 0.907 of pt against
 * the bounded beams' 0.959, 2026-11-29). Measured 2026-11-30: walks +0.2% of the bounded
 * beams in every channel, endless beams +7.7% (what the beams past the exits add). */
#define WALKS_VS_BOUNDED 0.015
static void test_double_walks_are_bounded_beams(void)
{
    const double albedo[3] = {0.999, 0.9, 0.95};
    ns_material m = material(albedo, 1.0, 0.0, 1.0);
    ns_object ball = sphere(0, 0, 0, 1, 0);
    ns_light sky = light(NS_LIGHT_ENVIRONMENT, 1, 1, 1);
    ns_scene s = medium_scene(&m, &ball, 1, &sky);
    set3(s.camera.position, 0, 0, 6);
    set3(s.camera.look_at, 0, 0, 0);
    s.camera.width = s.camera.height = 24;
    s.render.vrls = 4000;
    s.render.components = NS_COMPONENT_DOUBLE;
    s.render.method = NS_METHOD_NN;
    ns_image bounded = {0}, walks = {0}, endless = {0};
    ns_render_stats stats = {0};
    s.render.vrl_beams = NS_VRL_BEAMS_BOUNDED;
    int ok = render_ok(&s, &bounded, NULL);
    s.render.vrl_beams = NS_VRL_BEAMS_ENDLESS;
    ok = ok && render_ok(&s, &endless, NULL);
    s.render.boundary = NS_BOUNDARY_WALKS;
    ok = ok && render_ok(&s, &walks, &stats);
    CHECK(ok);
    if (ok) {
        CHECK(stats.boundary_sources > 0);
        double mean_bounded[3], mean_walks[3], mean_endless[3];
        image_mean(&bounded, mean_bounded);
        image_mean(&walks, mean_walks);
        image_mean(&endless, mean_endless);
        for (int c = 0; c < 3; c++) {
            double ratio = mean_walks[c] / mean_bounded[c];
            printf("  channel %d: bounded beams %.6g, walks %.6g (%+.1f%%), endless %.6g (%+.1f%%)\n", c,
                   mean_bounded[c], mean_walks[c], 100 * (ratio - 1), mean_endless[c],
                   100 * (mean_endless[c] / mean_bounded[c] - 1));
            CHECK(mean_bounded[c] > 0 && fabs(ratio - 1) < WALKS_VS_BOUNDED);
            /* What the entry ghosts take away: far more than the two estimates differ. */
            CHECK(mean_endless[c] / mean_bounded[c] - 1 > 0.05);
        }
    }
    ns_image_free(&bounded);
    ns_image_free(&walks);
    ns_image_free(&endless);
}

/* The correction's own lattice (scatter_render.c, plan_round): with a tolerance the boundary
 * sources are gathered at fewer tiles than the VRLs, which are gathered at the same tiles as
 * with tolerance 0 (the correction at every one), and the image keeps its means (the same
 * VRLs and sources in both: only the interpolation differs). The cloud sphere at 48 x 48,
 * where the correction is smooth. Measured (2026-11-29): interactions -25.2%, means +0.27
 * to +0.59% (64 x 64 with 40,000 VRLs: -26.6%, +0.18 to +0.43%). */
static void test_correction_lattice(void)
{
    ns_scene s = cloud_scene();
    s.camera.width = s.camera.height = 48;
    s.render.vrls = 10000;
    s.render.method = NS_METHOD_NN;
    s.render.boundary = NS_BOUNDARY_WALKS;
    s.render.components = NS_COMPONENT_MULTIPLE;
    s.render.spp = 1;
    ns_image every = {0}, lattice = {0};
    ns_render_stats every_stats = {0}, lattice_stats = {0};
    s.render.gather_tolerance = 0.0f;
    int ok = render_ok(&s, &every, &every_stats);
    s.render.gather_tolerance = NS_DEFAULT_GATHER_TOLERANCE;
    ok = ok && render_ok(&s, &lattice, &lattice_stats);
    CHECK(ok);
    if (ok) {
        double a[3], b[3];
        image_mean(&every, a);
        image_mean(&lattice, b);
        fprintf(stderr, "  interactions %llu -> %llu (%+.1f%%), segments %llu and %llu\n",
                (unsigned long long)every_stats.interactions,
                (unsigned long long)lattice_stats.interactions,
                100.0 * ((double)lattice_stats.interactions / (double)every_stats.interactions - 1),
                (unsigned long long)every_stats.gather_segments,
                (unsigned long long)lattice_stats.gather_segments);
        CHECK(lattice_stats.gather_segments == every_stats.gather_segments);
        CHECK(every_stats.corrections_interpolated == 0);
        CHECK(lattice_stats.corrections_interpolated > 0);
        CHECK((double)lattice_stats.interactions < 0.8 * (double)every_stats.interactions);
        for (int c = 0; c < 3; c++) {
            fprintf(stderr, "  channel %d: every tile %.6g, lattice %.6g (%+.2f%%)\n", c, a[c],
                    b[c], 100 * (b[c] / a[c] - 1));
            CHECK(a[c] > 0);
            CHECK(fabs(b[c] / a[c] - 1) < 0.01);
        }
    }
    ns_image_free(&every);
    ns_image_free(&lattice);
}

static void test_bad_setting(void)
{
    ns_material m = diffuse(0.5, 0.5, 0.5);
    ns_object ball = sphere(0, 0, 0, 1, 0);
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(sun.direction, 0, -1, 0);
    ns_scene s = medium_scene(&m, &ball, 1, &sun);
    set3(s.camera.position, 0, 0, 10);
    s.render.boundary = NS_BOUNDARY_WALKS;
    s.render.method = NS_METHOD_DIPOLE;
    ns_error err = {0};
    CHECK_INT(ns_scene_validate(&s, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK(strstr(err.message, "render.boundary") != NULL);
}

int main(int argc, char **argv)
{
    const char *only = argc > 1 ? argv[1] : NULL;
#define PICK(t)                                                                                    \
    if (!only || strstr(#t, only))                                                                 \
    RUN(t)
    PICK(test_cloud);
    PICK(test_slabs);
    PICK(test_large_sphere);
    PICK(test_refracting_sphere);
    PICK(test_facing_boxes);
    PICK(test_light_guide);
    PICK(test_box_lit_on_two_faces);
    PICK(test_double_walks_are_bounded_beams);
    PICK(test_correction_lattice);
    PICK(test_bad_setting);
    mc_test_context_destroy();
    ns_context_destroy(test_context());
    return harness_report();
}
