/* gpu_boundary_walks.c — the boundary-crossing estimator (render/boundary.c) against the
 * bounded walk, without tables. The light's real walks inside an object come from the
 * renderer's own trace (ns_vrl_method_trace, on the device); everything else is on the CPU:
 *   truth      the walk's own scattering events of order >= m inside the object, weighted by
 *              the flux after each (the quantity the image integrates, without the camera);
 *   corrected  T(entry; 0) + sum over ns_boundary_sources' sources (the entry's ghost too) of
 *              their signed power times T(source; k), where T(b, w; k) counts the same events
 *              (total order >= m, inside the object) of one infinite-medium walk from b
 *              along w after k events: what a table would return, estimated without one.
 * Per path the difference of the two is averaged; it must be 0 within 4 standard errors, for
 * a sphere, a box and a cylinder (a mesh) at ior 1, 1.3 and 1.5, for orders >= 2 and >= 3,
 * and per channel on a sphere whose channels differ in extinction and albedo.
 * The infinite medium alone (corrected without the sources) must be off by more than 4
 * standard errors, so that each case can tell the two apart. Also: the walk's mark on the
 * stretches whose line past the end meets their medium again (NS_VRL_LINE_RETURNS) against
 * the same lines traced on the CPU. */
#include <stdlib.h>

#include "boundary.h"
#include "gpu_util.h"
#include "vrl_method.h"

/* ---------------------------------------------------------------------------------------
 * The objects, in mean free paths (sigma_t = 1), and their insides.
 * ------------------------------------------------------------------------------------- */
enum { SPHERE, BOX, CYLINDER };
#define SPHERE_RADIUS 2.0
#define BOX_HALF 1.5
#define CYL_RADIUS 1.3
#define CYL_HEIGHT 3.8
#define CYL_SEGMENTS 48

static int shape;

static int inside(const double p[3])
{
    switch (shape) {
    case SPHERE:
        return p[0] * p[0] + p[1] * p[1] + p[2] * p[2] < SPHERE_RADIUS * SPHERE_RADIUS;
    case BOX:
        return fabs(p[0]) < BOX_HALF && fabs(p[1]) < BOX_HALF && fabs(p[2]) < BOX_HALF;
    default:
        if (p[1] <= 0 || p[1] >= CYL_HEIGHT)
            return 0;
        /* The mesh's polygon: rim vertices at (R cos a, -R sin a), a = 2 pi i / N. */
        for (int k = 0; k < CYL_SEGMENTS; k++) {
            double m = 2 * M_PI * (k + 0.5) / CYL_SEGMENTS;
            if (p[0] * cos(m) - p[2] * sin(m) >= CYL_RADIUS * cos(M_PI / CYL_SEGMENTS))
                return 0;
        }
        return 1;
    }
}

static ns_triangle cylinder_triangles[4 * CYL_SEGMENTS];

static void cylinder_mesh(void)
{
    double rim[CYL_SEGMENTS][2];
    for (int i = 0; i < CYL_SEGMENTS; i++) {
        double a = 2 * M_PI * i / CYL_SEGMENTS;
        rim[i][0] = CYL_RADIUS * cos(a);
        rim[i][1] = -CYL_RADIUS * sin(a); /* counter-clockwise seen from +y */
    }
    memset(cylinder_triangles, 0, sizeof cylinder_triangles);
    for (int i = 0; i < CYL_SEGMENTS; i++) {
        int j = (i + 1) % CYL_SEGMENTS;
        double b0[3] = {rim[i][0], 0, rim[i][1]}, b1[3] = {rim[j][0], 0, rim[j][1]};
        double t0[3] = {rim[i][0], CYL_HEIGHT, rim[i][1]}, t1[3] = {rim[j][0], CYL_HEIGHT, rim[j][1]};
        double top[3] = {0, CYL_HEIGHT, 0}, bottom[3] = {0, 0, 0};
        const double *quad[4][3] = {{b0, b1, t1}, {b0, t1, t0}, {top, t0, t1}, {bottom, b1, b0}};
        for (int q = 0; q < 4; q++)
            for (int v = 0; v < 3; v++)
                set3(cylinder_triangles[4 * i + q].v[v], quad[q][v][0], quad[q][v][1], quad[q][v][2]);
    }
}

/* ---------------------------------------------------------------------------------------
 * T(b, w; k): one infinite-medium walk (albedo a, Henyey-Greenstein g, mfp 1).
 * ------------------------------------------------------------------------------------- */
static uint64_t rng_state = 88172645463325252ull;
static double rnd(void)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (double)(rng_state >> 11) * (1.0 / 9007199254740992.0);
}

static void hg(double w[3], double g)
{
    double c;
    if (fabs(g) < 1e-3)
        c = 1 - 2 * rnd();
    else {
        double q = (1 - g * g) / (1 - g + 2 * g * rnd());
        c = (1 + g * g - q * q) / (2 * g);
    }
    double s = sqrt(fmax(0.0, 1 - c * c)), phi = 2 * M_PI * rnd();
    double t[3] = {fabs(w[0]) < 0.9 ? 1 : 0, fabs(w[0]) < 0.9 ? 0 : 1, 0};
    double u[3] = {w[1] * t[2] - w[2] * t[1], w[2] * t[0] - w[0] * t[2], w[0] * t[1] - w[1] * t[0]};
    double un = sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
    for (int i = 0; i < 3; i++)
        u[i] /= un;
    double v[3] = {w[1] * u[2] - w[2] * u[1], w[2] * u[0] - w[0] * u[2], w[0] * u[1] - w[1] * u[0]};
    for (int i = 0; i < 3; i++)
        w[i] = u[i] * s * cos(phi) + v[i] * s * sin(phi) + w[i] * c;
}

static double table_walk(const float origin[3], const float direction[3], uint32_t k, double sigma_t,
                         double albedo, double g, uint32_t min_order)
{
    double p[3] = {origin[0], origin[1], origin[2]}, w[3] = {direction[0], direction[1], direction[2]};
    double weight = 1, sum = 0;
    for (int step = 0; step < 100000; step++) {
        double t = -log(1 - rnd()) / sigma_t;
        for (int i = 0; i < 3; i++)
            p[i] += t * w[i];
        k++;
        weight *= albedo;
        if (k >= min_order && inside(p))
            sum += weight;
        if (p[0] * p[0] + p[1] * p[1] + p[2] * p[2] > 1e6)
            break;
        if (weight < 1e-4) {
            if (rnd() < 0.5)
                break;
            weight *= 2;
        }
        hg(w, g);
    }
    return sum;
}

/* ---------------------------------------------------------------------------------------
 * One case.
 * ------------------------------------------------------------------------------------- */
/* sigma_t, albedo: per channel (scene units); channels: how many to check (1 when all are
 * alike). */
/* The renderer's light walks in the device scene d (ns_vrl_method_trace with `options`), its
 * status checked (and its error printed). */
static int trace_walks(const ns_scene *s, device_scene *d, uint32_t paths, uint32_t seed,
                       uint32_t options, ns_vrl_set *walks)
{
    ns_error err = {0};
    int status = ns_vrl_method_trace(test_context(), s, &d->gs, d->buffers, paths, seed, options,
                                     walks, NULL, &err);
    if (status)
        fprintf(stderr, "trace: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    return status;
}

static void run_channels(int which, double ior, const double sigma_t[3], const double albedo[3],
                         int channels)
{
    static const char *const names[] = {"sphere 4 mfp", "box 3 mfp", "cylinder 2.6 x 3.8 mfp"};
    const double g = 0.5;
    shape = which;
    double sigma_s[3], sigma_a[3];
    for (int c = 0; c < 3; c++) {
        sigma_s[c] = albedo[c] * sigma_t[c];
        sigma_a[c] = (1 - albedo[c]) * sigma_t[c];
    }
    ns_material m = medium(sigma_s, sigma_a, ior);
    m.g = (float)g;
    ns_object o;
    memset(&o, 0, sizeof o);
    ns_scene s = base_scene(8, 8, 30);
    if (which == SPHERE) {
        o = sphere(0, 0, 0, SPHERE_RADIUS, 0);
    } else if (which == BOX) {
        o.shape = NS_SHAPE_BOX;
        set3(o.min, -BOX_HALF, -BOX_HALF, -BOX_HALF);
        set3(o.max, BOX_HALF, BOX_HALF, BOX_HALF);
    } else {
        cylinder_mesh();
        o.shape = NS_SHAPE_MESH;
        o.first_triangle = 0;
        o.triangle_count = 4 * CYL_SEGMENTS;
        s.triangles = cylinder_triangles;
        s.triangle_count = 4 * CYL_SEGMENTS;
    }
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(sun.direction, 0.3, -1, -0.2);
    scene_lists(&s, &m, 1, &o, 1, &sun, 1);
    set3(s.camera.position, 0, 0, 20);

    device_scene d;
    if (device_scene_make(&s, &d))
        return;
    const uint32_t paths = 20000;
    ns_vrl_set walks = {0};
    int status = trace_walks(&s, &d, paths, 7, NS_VRL_TRACE_ENDS, &walks);
    CHECK(status || walks.ends != NULL);
    GpuVrl *sources = malloc(sizeof *sources * 2 * (walks.count + 1));
    CHECK(sources != NULL);
    if (status || !sources || !walks.ends) {
        free(sources);
        ns_vrl_set_free(&walks);
        device_scene_free(&d);
        return;
    }

    /* The ends the trace recorded are the reflections the walks took: wherever a stretch
     * goes on reflected, the one before it ends with F > 0 and the mirror direction the
     * walk took (and at ior 1 nothing reflects), scaled for unscattered light by the chord
     * ahead, which is the reflected stretch's own length, and of unit length after a
     * scattering. */
    uint32_t reflections = 0, mismatched = 0, wrong_chord = 0, unscattered = 0;
    for (uint32_t i = 0; i + 1 < walks.count; i++) {
        if (ns_boundary_link_of(&walks.vrls[i], &walks.vrls[i + 1]) != NS_BOUNDARY_LINK_REFLECTED)
            continue;
        const float *e = walks.ends + 4 * (size_t)i;
        const GpuVrl *next = &walks.vrls[i + 1];
        float chord = sqrtf(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]);
        float along =
            e[0] * next->direction[0] + e[1] * next->direction[1] + e[2] * next->direction[2];
        reflections++;
        mismatched += !(e[3] > 0.0f && chord > 0.0f && along / chord > 0.9999f);
        float want = walks.vrls[i].events == 0 ? next->length : 1.0f;
        unscattered += walks.vrls[i].events == 0;
        wrong_chord += !(fabsf(chord - want) <= 1e-3f * want);
    }
    CHECK(ior == 1.0 ? reflections == 0 : reflections > 100);
    CHECK(ior == 1.0 || unscattered > 10);
    CHECK_INT(mismatched, 0);
    CHECK_INT(wrong_chord, 0);
    /* Every end's F is a probability; at ior 1 every one is 0 (nothing reflects). */
    uint32_t bad_f = 0;
    for (uint32_t i = 0; i < walks.count; i++) {
        float f = walks.ends[4 * (size_t)i + 3];
        bad_f += !(f >= 0.0f && f <= 1.0f) || (ior == 1.0 && f != 0.0f);
    }
    CHECK_INT(bad_f, 0);

    /* Both estimators: the walk's own reflected beams (ends NULL), and unscattered light's in
     * expectation (the ends); orders >= 1 (single scattering's correction: reflected light
     * that has not scattered), >= 2 and (the walk's, which the ends do not change there)
     * >= 3. */
    double spread_k0[2] = {0, 0};
    for (int expected = 0; expected < 2; expected++) {
        const float *ends = expected ? walks.ends : NULL;
        uint32_t source_count =
            ns_boundary_sources(walks.vrls, ends, walks.count, d.gs.materials, 1, sources);
        CHECK(source_count > 0);
        int orders = expected ? 2 : 3;
        for (int pass = 0; pass < orders * channels; pass++) {
            int c = pass / orders;
            uint32_t min_order = 1 + (uint32_t)(pass % orders);
            /* Per path: truth, corrected and the infinite medium's T(entry) alone; and the
             * weight of the unscattered light's reflected beams. The sources come in stretch
             * order, so path p's are those made from its stretches. */
            double sum_d = 0, sum_d2 = 0, sum_i = 0, sum_i2 = 0, sum_truth = 0, sum_r = 0,
                   sum_r2 = 0;
            uint32_t path_count = 0, next_source = 0;
            uint32_t i = 0;
            while (i < walks.count) {
                uint32_t end = i + 1;
                while (end < walks.count &&
                       !(walks.vrls[end].events == 0 &&
                         ns_boundary_link_of(&walks.vrls[end - 1], &walks.vrls[end]) ==
                             NS_BOUNDARY_LINK_START))
                    end++;
                double truth = 0;
                for (uint32_t j = i + 1; j < end; j++) {
                    const GpuVrl *v = &walks.vrls[j];
                    if (v->events >= min_order && v->events >= 1 &&
                        ns_boundary_link_of(&walks.vrls[j - 1], v) == NS_BOUNDARY_LINK_START)
                        truth += v->power[c];
                }
                const GpuVrl *entry = &walks.vrls[i];
                double infinite = entry->power[c] * table_walk(entry->origin, entry->direction, 0,
                                                               sigma_t[c], albedo[c], g, min_order);
                double corrected = infinite, reflected_k0 = 0;
                /* This path's sources: those whose origin stretch lies in [i, end); sources
                 * are written in stretch order, 0 to 3 per stretch, so recount them. */
                uint32_t made =
                    ns_boundary_sources(walks.vrls + i, ends ? ends + 4 * (size_t)i : NULL, end - i,
                                        d.gs.materials, 1, sources + next_source);
                for (uint32_t k = next_source; k < next_source + made; k++) {
                    /* The events alone (a reflected beam's face bits aside). */
                    uint32_t events = sources[k].events & NS_VRL_EVENT_COUNT;
                    corrected += sources[k].power[c] *
                                 table_walk(sources[k].origin, sources[k].direction, events,
                                            sigma_t[c], albedo[c], g, min_order);
                    if (events == 0 && sources[k].power[c] > 0)
                        reflected_k0 += sources[k].power[c];
                }
                next_source += made;
                sum_d += corrected - truth;
                sum_d2 += (corrected - truth) * (corrected - truth);
                sum_i += infinite - truth;
                sum_i2 += (infinite - truth) * (infinite - truth);
                sum_truth += truth;
                sum_r += reflected_k0;
                sum_r2 += reflected_k0 * reflected_k0;
                path_count++;
                i = end;
            }
            CHECK(next_source == source_count);
            double n = paths; /* paths that made no stretch add 0 to every sum */
            double mean_d = sum_d / n, se_d = sqrt((sum_d2 / n - mean_d * mean_d) / (n - 1));
            double mean_i = sum_i / n, se_i = sqrt((sum_i2 / n - mean_i * mean_i) / (n - 1));
            double mean_r = sum_r / n, sd_r = sqrt(fmax(0.0, sum_r2 / n - mean_r * mean_r));
            double truth = sum_truth / n;
            fprintf(
                stderr,
                "  %s, ior %.1f, channel %d (sigma_t %.2f, albedo %.2f), %s reflections, orders >= "
                "%u: "
                "truth %.5f, corrected - truth %+.5f (%.1f se, %+.2f%%), infinite - truth %+.5f "
                "(%.1f se); %u paths entered, %u sources; unscattered light's reflected beams per "
                "path %.5f +- %.5f\n",
                names[which], ior, c, sigma_t[c], albedo[c], expected ? "expected" : "the walk's",
                min_order, truth, mean_d, mean_d / se_d, 100 * mean_d / truth, mean_i,
                mean_i / se_i, path_count, source_count, mean_r, sd_r);
            CHECK(truth > 0);
            CHECK(fabs(mean_d) < 4 * se_d);
            /* Single scattering's truth is the infinite medium's where nothing reflects. */
            if (min_order > 1 || ior != 1.0)
                CHECK(fabs(mean_i) > 4 * se_i);
            if (c == 0 && min_order == 1)
                spread_k0[expected] = sd_r;
        }
    }
    /* The expectation takes the walk's coins (reaching the boundary unscattered, then
     * reflecting) out of unscattered light's reflections: their weight per path spreads
     * less (measured: 0.68 of the walk's in the box and the cylinder, where paths differ in
     * which faces they meet, 0.05 in the sphere; nothing reflects at ior 1). */
    if (ior != 1.0) {
        fprintf(stderr,
                "  unscattered reflections' spread per path: the walk's %.5f, expected %.5f\n",
                spread_k0[0], spread_k0[1]);
        CHECK(spread_k0[1] < 0.8 * spread_k0[0]);
    } else {
        CHECK(spread_k0[0] == 0.0 && spread_k0[1] == 0.0);
    }
    free(sources);
    ns_vrl_set_free(&walks);
    device_scene_free(&d);
}

static void run_case(int which, double ior)
{
    const double sigma_t[3] = {1, 1, 1}, albedo[3] = {0.9, 0.9, 0.9};
    run_channels(which, ior, sigma_t, albedo, 1);
}

/* Channels that differ in extinction and albedo: the walk picks one channel's free flight
 * and weighs the others by the balance heuristic (vrl_trace.comp), the ghosts attenuate each
 * channel by its own extinction (boundary.c); each channel must be exact on its own. */
static void test_channels(void)
{
    const double sigma_t[3] = {0.8, 1.0, 1.3}, albedo[3] = {0.6, 0.9, 0.97};
    run_channels(SPHERE, 1.3, sigma_t, albedo, 3);
}

static void test_sphere(void)
{
    run_case(SPHERE, 1.0);
    run_case(SPHERE, 1.3);
    run_case(SPHERE, 1.5);
}

static void test_box(void)
{
    run_case(BOX, 1.0);
    run_case(BOX, 1.3);
    run_case(BOX, 1.5);
}

static void test_cylinder(void)
{
    run_case(CYLINDER, 1.0);
    run_case(CYLINDER, 1.3);
    run_case(CYLINDER, 1.5);
}

/* Whether the ray from o along d (t > 1e-4) passes through the box [lo, hi]. */
static int ray_meets_box(const float o[3], const float d[3], const double lo[3], const double hi[3])
{
    double t0 = 1e-4, t1 = INFINITY;
    for (int a = 0; a < 3; a++) {
        if (d[a] == 0.0f) {
            if (o[a] < lo[a] || o[a] > hi[a])
                return 0;
            continue;
        }
        double ta = (lo[a] - o[a]) / d[a], tb = (hi[a] - o[a]) / d[a];
        t0 = fmax(t0, fmin(ta, tb));
        t1 = fmin(t1, fmax(ta, tb));
    }
    return t0 < t1;
}

/* NS_VRL_LINE_RETURNS (the walk's mark on a stretch whose line, past its end, passes through
 * an object of its medium again: the ghost there keeps its first order, boundary.c) against
 * the line traced on the CPU. Two boxes of medium 0 face to face across a gap of 0.1, a third
 * of medium 1 beyond the first; at ior 1 (the walks cross the gap) and 1.5 (they refract and
 * reflect; the marked line is the straight one all the same). Without mark_lines nothing is
 * marked. */
static void line_flags_case(double ior)
{
    double sigma_s[3] = {0.9, 0.9, 0.9}, sigma_a[3] = {0.1, 0.1, 0.1};
    ns_material m[2] = {medium(sigma_s, sigma_a, ior), medium(sigma_s, sigma_a, ior)};
    m[1].g = 0.5f; /* another material, the same extinction */
    const double box_lo[3][3] = {{-2.05, -1, -1}, {0.05, -1, -1}, {-4.1, -1, -1}};
    const double box_hi[3][3] = {{-0.05, 1, 1}, {2.05, 1, 1}, {-2.1, 1, 1}};
    const uint32_t box_medium[3] = {0, 0, 1};
    ns_object o[3];
    memset(o, 0, sizeof o);
    for (int b = 0; b < 3; b++) {
        o[b].shape = NS_SHAPE_BOX;
        o[b].material = box_medium[b];
        set3(o[b].min, box_lo[b][0], box_lo[b][1], box_lo[b][2]);
        set3(o[b].max, box_hi[b][0], box_hi[b][1], box_hi[b][2]);
    }
    ns_light sun = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(sun.direction, 0.2, -1, 0.1);
    ns_scene s = base_scene(8, 8, 30);
    scene_lists(&s, m, 2, o, 3, &sun, 1);
    set3(s.camera.position, 0, 0, 20);
    device_scene d;
    if (device_scene_make(&s, &d))
        return;
    for (int mark = 0; mark < 2; mark++) {
        ns_vrl_set walks = {0};
        int status = trace_walks(&s, &d, 4000, 11, mark ? NS_VRL_TRACE_MARK_LINES : 0u, &walks);
        uint32_t marked = 0, expected = 0, wrong = 0;
        for (uint32_t i = 0; !status && i < walks.count; i++) {
            const GpuVrl *v = &walks.vrls[i];
            float end[3];
            for (int c = 0; c < 3; c++)
                end[c] = v->origin[c] + v->length * v->direction[c];
            int meets = 0;
            for (int b = 0; b < 3; b++)
                meets |= box_medium[b] == v->material &&
                         ray_meets_box(end, v->direction, box_lo[b], box_hi[b]);
            int flag = (v->events & NS_VRL_LINE_RETURNS) != 0;
            marked += flag;
            expected += meets;
            wrong += mark && flag != meets;
        }
        fprintf(stderr, "  ior %.1f, mark_lines %d: %u stretches, %u marked, %u lines return, %u differ\n",
                ior, mark, walks.count, marked, expected, wrong);
        if (mark) {
            CHECK(expected > walks.count / 20);
            CHECK(walks.count - expected > walks.count / 20);
            CHECK(wrong <= walks.count / 1000); /* grazing a box's edge within float error */
        } else {
            CHECK_INT(marked, 0);
        }
        ns_vrl_set_free(&walks);
    }
    device_scene_free(&d);
}

/* NS_VRL_FROM_ENVIRONMENT (with NS_VRL_TRACE_MARK_ENVIRONMENT): set on exactly the stretches
 * without scattering events of the paths from the environment (single.comp follows that
 * light through internal reflections itself, boundary.c). A refracting sphere under the
 * environment alone, then under a directional light alone: every unscattered stretch is
 * marked in the first, none in the second, none after a scattering event in either, and
 * nothing without the option. */
static void test_environment_flags(void)
{
    double sigma_s[3] = {0.9, 0.9, 0.9}, sigma_a[3] = {0.1, 0.1, 0.1};
    ns_material m = medium(sigma_s, sigma_a, 1.5);
    ns_object ball = sphere(0, 0, 0, 1, 0);
    ns_light lights[2] = {light(NS_LIGHT_ENVIRONMENT, 1, 1, 1),
                          light(NS_LIGHT_DIRECTIONAL, 1, 1, 1)};
    set3(lights[1].direction, 0, -1, 0);
    for (int which = 0; which < 2; which++) {
        ns_scene s = base_scene(8, 8, 30);
        scene_lists(&s, &m, 1, &ball, 1, &lights[which], 1);
        set3(s.camera.position, 0, 0, 20);
        device_scene d;
        if (device_scene_make(&s, &d))
            return;
        for (int mark = 0; mark < 2; mark++) {
            ns_vrl_set walks = {0};
            int status =
                trace_walks(&s, &d, 4000, 5, mark ? NS_VRL_TRACE_MARK_ENVIRONMENT : 0u, &walks);
            uint32_t unscattered = 0, marked = 0, marked_wrongly = 0;
            for (uint32_t i = 0; !status && i < walks.count; i++) {
                uint32_t events = walks.vrls[i].events;
                int flag = (events & NS_VRL_FROM_ENVIRONMENT) != 0;
                events &= ~NS_VRL_FROM_ENVIRONMENT;
                unscattered += events == 0;
                marked += flag;
                marked_wrongly += flag && events != 0;
            }
            fprintf(stderr, "  %s, mark %d: %u stretches, %u unscattered, %u marked\n",
                    which ? "directional" : "environment", mark, walks.count, unscattered, marked);
            CHECK(walks.count > 1000 && unscattered > 100 && unscattered < walks.count);
            CHECK_INT(marked_wrongly, 0);
            CHECK_INT(marked, mark && which == 0 ? unscattered : 0);
            ns_vrl_set_free(&walks);
        }
        device_scene_free(&d);
    }
}

static void test_line_flags(void)
{
    line_flags_case(1.0);
    line_flags_case(1.5);
}

int main(void)
{
    RUN(test_sphere);
    RUN(test_box);
    RUN(test_cylinder);
    RUN(test_channels);
    RUN(test_line_flags);
    RUN(test_environment_flags);
    ns_context_destroy(test_context());
    return harness_report();
}
