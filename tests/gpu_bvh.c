/* gpu_bvh.c — the BVH built on the CPU and traversed by the shader (trace.glsl through
 * shaders/trace_test.comp) finds the same nearest hit as brute force in double precision
 * on the CPU, for 10^4 random rays over random spheres, boxes, triangles and planes; and the
 * shadow rays' any-hit query gives brute force's answer. */
#include "gpu_util.h"

#define RAYS 10000

static uint64_t rng = 0x9e3779b97f4a7c15ull;

static double uniform(double lo, double hi)
{
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return lo + (hi - lo) * (double)(rng >> 11) * (1.0 / 9007199254740992.0);
}

static void random_unit(double d[3])
{
    double n;
    do {
        for (int k = 0; k < 3; k++)
            d[k] = uniform(-1, 1);
        n = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    } while (n > 1 || n < 1e-4);
    n = sqrt(n);
    for (int k = 0; k < 3; k++)
        d[k] /= n;
}

/* ---- brute force, double precision, written from the geometry not from the shader ---- */
static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static double cpu_hit(const GpuPrim *p, const double o[3], const double d[3])
{
    double a[3] = {p->a[0], p->a[1], p->a[2]}, b[3] = {p->b[0], p->b[1], p->b[2]},
           c[3] = {p->c[0], p->c[1], p->c[2]};
    if (p->info[0] == NS_PRIM_SPHERE) {
        double oc[3] = {o[0] - a[0], o[1] - a[1], o[2] - a[2]};
        double half_b = dot3(oc, d), cc = dot3(oc, oc) - (double)p->a[3] * p->a[3];
        double disc = half_b * half_b - cc;
        if (disc < 0)
            return -1;
        double t0 = -half_b - sqrt(disc), t1 = -half_b + sqrt(disc);
        return t0 > 0 ? t0 : t1 > 0 ? t1 : -1;
    }
    if (p->info[0] == NS_PRIM_BOX) {
        double near = -INFINITY, far = INFINITY;
        for (int k = 0; k < 3; k++) {
            if (d[k] == 0) {
                if (o[k] < a[k] || o[k] > b[k])
                    return -1;
                continue;
            }
            double t0 = (a[k] - o[k]) / d[k], t1 = (b[k] - o[k]) / d[k];
            near = fmax(near, fmin(t0, t1));
            far = fmin(far, fmax(t0, t1));
        }
        if (near > far)
            return -1;
        return near > 0 ? near : far > 0 ? far : -1;
    }
    if (p->info[0] == NS_PRIM_TRIANGLE) {
        /* Plane of the triangle, then inside-test with barycentric areas. */
        double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]},
               e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                       e1[0] * e2[1] - e1[1] * e2[0]};
        double denom = dot3(n, d);
        if (denom == 0)
            return -1;
        double ao[3] = {a[0] - o[0], a[1] - o[1], a[2] - o[2]};
        double t = dot3(n, ao) / denom;
        if (t <= 0)
            return -1;
        double q[3] = {o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]};
        const double *v[3] = {a, b, c};
        for (int i = 0; i < 3; i++) {
            const double *p0 = v[i], *p1 = v[(i + 1) % 3];
            double edge[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]},
                   to[3] = {q[0] - p0[0], q[1] - p0[1], q[2] - p0[2]};
            double cr[3] = {edge[1] * to[2] - edge[2] * to[1], edge[2] * to[0] - edge[0] * to[2],
                            edge[0] * to[1] - edge[1] * to[0]};
            if (dot3(cr, n) < 0)
                return -1;
        }
        return t;
    }
    double denom = dot3(b, d); /* plane: a = point, b = normal */
    if (denom == 0)
        return -1;
    double ao[3] = {a[0] - o[0], a[1] - o[1], a[2] - o[2]};
    double t = dot3(ao, b) / denom;
    return t > 0 ? t : -1;
}

static GpuPrim random_prim(int kind, uint32_t index)
{
    GpuPrim p;
    memset(&p, 0, sizeof p);
    p.info[0] = (uint32_t)kind;
    p.info[2] = index;
    double c[3] = {uniform(-10, 10), uniform(-10, 10), uniform(-10, 10)};
    for (int k = 0; k < 3; k++) {
        if (kind == NS_PRIM_SPHERE) {
            p.a[k] = (float)c[k];
        } else if (kind == NS_PRIM_BOX) {
            double h = uniform(0.05, 0.8);
            p.a[k] = (float)(c[k] - h);
            p.b[k] = (float)(c[k] + h);
        } else {
            p.a[k] = (float)(c[k] + uniform(-1, 1));
            p.b[k] = (float)(c[k] + uniform(-1, 1));
            p.c[k] = (float)(c[k] + uniform(-1, 1));
        }
    }
    if (kind == NS_PRIM_SPHERE)
        p.a[3] = (float)uniform(0.1, 1.0);
    return p;
}

enum {
    SPHERES = 300,
    BOXES = 300,
    TRIANGLES = 1400,
    PLANES = 2,
    PRIMS = SPHERES + BOXES + TRIANGLES
};

/* Random spheres, boxes and triangles, a floor below everything and a tilted plane beyond
 * it; `all` is the primitives then the planes, for brute force. */
static void random_scene(GpuPrim *prims, GpuPrim *planes, GpuPrim *all)
{
    for (uint32_t i = 0; i < PRIMS; i++)
        prims[i] = random_prim(i < SPHERES           ? NS_PRIM_SPHERE
                               : i < SPHERES + BOXES ? NS_PRIM_BOX
                                                     : NS_PRIM_TRIANGLE,
                               i);
    memset(planes, 0, sizeof *planes * PLANES);
    planes[0].info[0] = planes[1].info[0] = NS_PRIM_PLANE;
    planes[0].a[1] = -14;
    planes[0].b[1] = 1;
    planes[1].a[0] = 20;
    planes[1].b[0] = (float)(1 / sqrt(2.0));
    planes[1].b[2] = (float)(1 / sqrt(2.0));
    memcpy(all, prims, sizeof *prims * PRIMS);
    memcpy(all + PRIMS, planes, sizeof *planes * PLANES);
}

/* RAYS random rays from inside the scene's cube, traced on the GPU. Nearest hit: every tenth
 * with tmax 5, the rest unbounded. Any-hit (direction.w = 1): tmax uniform in [0.2, 12], so
 * that rays end before, between and after what they meet. Nonzero (and a failed check) if
 * the trace failed. */
static int trace_random_rays(const GpuPrim *prims, const GpuPrim *planes, GpuRay *rays,
                             GpuHit *hits, int any_hit, uint32_t max_depth)
{
    for (uint32_t i = 0; i < RAYS; i++) {
        double d[3];
        random_unit(d);
        for (int k = 0; k < 3; k++) {
            rays[i].origin[k] = (float)uniform(-12, 12);
            rays[i].direction[k] = (float)d[k];
        }
        rays[i].origin[3] = any_hit ? (float)uniform(0.2, 12) : i % 10 == 0 ? 5.0f : 1e30f;
        rays[i].direction[3] = any_hit ? 1.0f : 0.0f;
    }
    ns_error err = {0};
    int status = ns_trace_rays_timed(test_context(), prims, PRIMS, planes, PLANES, rays, RAYS,
                                     hits, &(ns_trace_timing){.max_depth = max_depth}, &err);
    if (status)
        fprintf(stderr, "ns_trace_rays_timed: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    return status;
}

/* max_depth: where the BVH's surface-area splits stop (0: the default). */
static void check_nearest_hits(uint32_t max_depth)
{
    static GpuPrim prims[PRIMS], planes[PLANES], all[PRIMS + PLANES];
    static GpuRay rays[RAYS];
    static GpuHit hits[RAYS];
    random_scene(prims, planes, all);
    if (trace_random_rays(prims, planes, rays, hits, 0, max_depth))
        return;

    int hit_count = 0, mismatches = 0, ties = 0;
    int kinds_hit[4] = {0};
    for (uint32_t i = 0; i < RAYS; i++) {
        double o[3] = {rays[i].origin[0], rays[i].origin[1], rays[i].origin[2]};
        double d[3] = {rays[i].direction[0], rays[i].direction[1], rays[i].direction[2]};
        double best = rays[i].origin[3];
        uint32_t best_prim = NS_NONE;
        for (uint32_t p = 0; p < PRIMS + PLANES; p++) {
            double t = cpu_hit(&all[p], o, d);
            if (t > 0 && t < best) {
                best = t;
                best_prim = p;
            }
        }
        const GpuHit *h = &hits[i];
        if (best_prim == h->prim) {
            if (best_prim != NS_NONE) {
                hit_count++;
                kinds_hit[all[best_prim].info[0]]++;
                if (!(fabs(h->t - best) <= 1e-4 * (1 + best)) && mismatches++ < 5)
                    fprintf(stderr, "ray %u: t %.7g, brute force %.7g\n", i, h->t, best);
            }
            continue;
        }
        /* Different primitive: acceptable only as a tie (both at the same distance within
         * float precision), which random scenes produce for touching primitives. */
        double t_other = h->prim == NS_NONE ? INFINITY : cpu_hit(&all[h->prim], o, d);
        if (h->prim != NS_NONE && best_prim != NS_NONE &&
            fabs(t_other - best) <= 1e-4 * (1 + best)) {
            ties++;
            continue;
        }
        if (mismatches++ < 5)
            fprintf(stderr, "ray %u: gpu prim %u t %.7g, brute force prim %u t %.7g\n", i, h->prim,
                    h->t, best_prim, best);
    }
    CHECK_INT(mismatches, 0);
    CHECK(ties <= 3);
    CHECK(hit_count > RAYS / 2); /* the rays really exercise the tree */
    for (int k = 0; k < 4; k++)
        CHECK(kinds_hit[k] > 50); /* every kind of primitive, planes included */
    fprintf(stderr, "%d of %d rays hit, %d ties\n", hit_count, RAYS, ties);
}

/* The shadow rays' any-hit query (trace.glsl's trace_shadow, direction.w = 1) against brute
 * force: it stops at the first primitive in (0, tmax) it meets, in any order, and says
 * whether that one blocks or is flagged NS_PRIM_SHADOW_PASSES (then transmittance walks the
 * crossings in order); "clear" only when there is none. So "blocked" needs an unflagged
 * primitive in range, "crosses" a flagged one, "clear" neither. A third of each kind of
 * primitive and the tilted plane are flagged; tmax is random, so that every answer occurs. */
static void check_any_hits(uint32_t max_depth)
{
    static GpuPrim prims[PRIMS], planes[PLANES], all[PRIMS + PLANES];
    static GpuRay rays[RAYS];
    static GpuHit hits[RAYS];
    random_scene(prims, planes, all);
    for (uint32_t i = 0; i < PRIMS; i++)
        if (i % 3 == 0)
            prims[i].info[3] |= NS_PRIM_SHADOW_PASSES;
    planes[1].info[3] |= NS_PRIM_SHADOW_PASSES;
    memcpy(all, prims, sizeof prims);
    memcpy(all + PRIMS, planes, sizeof planes);
    if (trace_random_rays(prims, planes, rays, hits, 1, max_depth))
        return;
    int blocked = 0, crossed = 0, clear = 0, mismatches = 0;
    for (uint32_t i = 0; i < RAYS; i++) {
        double o[3] = {rays[i].origin[0], rays[i].origin[1], rays[i].origin[2]};
        double d[3] = {rays[i].direction[0], rays[i].direction[1], rays[i].direction[2]};
        int has_blocker = 0, has_flagged = 0;
        for (uint32_t p = 0; p < PRIMS + PLANES; p++) {
            double t = cpu_hit(&all[p], o, d);
            if (t > 0 && t < rays[i].origin[3]) {
                if (all[p].info[3] & NS_PRIM_SHADOW_PASSES)
                    has_flagged = 1;
                else
                    has_blocker = 1;
            }
        }
        int got_blocked = hits[i].prim != NS_NONE, got_crosses = hits[i].crossed == 1;
        int ok = got_blocked   ? has_blocker && !got_crosses
                 : got_crosses ? has_flagged
                               : !has_blocker && !has_flagged && hits[i].t < 0;
        if (!ok && mismatches++ < 5)
            fprintf(stderr, "ray %u: gpu %s, brute force: blocker %d, flagged %d\n", i,
                    got_blocked   ? "blocked"
                    : got_crosses ? "crosses"
                                  : "clear",
                    has_blocker, has_flagged);
        blocked += got_blocked;
        crossed += got_crosses;
        clear += !got_blocked && !got_crosses;
    }
    /* A hit within float precision of tmax or grazing a primitive may go either way. */
    CHECK(mismatches <= 3);
    CHECK(blocked > RAYS / 10 && crossed > RAYS / 20 && clear > RAYS / 20);
    fprintf(stderr, "any-hit: %d blocked, %d crosses, %d clear, %d differ\n", blocked, crossed,
            clear, mismatches);
}

static void test_bvh_matches_brute_force(void)
{
    check_nearest_hits(0);
}

static void test_any_hit_matches_brute_force(void)
{
    check_any_hits(0);
}

/* Leaves built past the depth limit (render/bvh.c): with the surface-area splits stopped at
 * depth 3, the scene's primitives reach it in leaves of hundreds, which are halved to at most
 * NS_BVH_LEAF_ENTRY_MAX; the traversal reads a leaf's count from its stack entry, so a count
 * it cannot hold would lose hits here. */
static void test_leaves_past_depth_limit(void)
{
    check_nearest_hits(3);
    check_any_hits(3);
}

/* Degenerate inputs: no BVH primitives at all, and many identical primitives (all
 * centroids equal, so no SAH split separates them). */
static void test_degenerate_trees(void)
{
    GpuPrim plane;
    memset(&plane, 0, sizeof plane);
    plane.info[0] = NS_PRIM_PLANE;
    plane.b[1] = 1;
    GpuRay ray = {{0, 5, 0, 1e30f}, {0, -1, 0, 0}};
    GpuHit hit;
    ns_error err = {0};
    CHECK_INT(ns_trace_rays(test_context(), NULL, 0, &plane, 1, &ray, 1, &hit, &err), NS_OK);
    CHECK_NEAR(hit.t, 5.0, 1e-5);
    CHECK_INT(hit.prim, 0);

    static GpuPrim same[100];
    for (int i = 0; i < 100; i++) {
        memset(&same[i], 0, sizeof same[i]);
        same[i].info[0] = NS_PRIM_SPHERE;
        same[i].a[3] = i == 37 ? 1.5f : 1.0f; /* one is larger: it is hit first */
    }
    GpuRay side = {{0, 0, 10, 1e30f}, {0, 0, -1, 0}};
    CHECK_INT(ns_trace_rays(test_context(), same, 100, NULL, 0, &side, 1, &hit, &err), NS_OK);
    CHECK_INT(hit.prim, 37);
    CHECK_NEAR(hit.t, 8.5, 1e-5);
    CHECK_INT(hit.front, 1);
}

/* Rays with direction components that are exactly zero, starting exactly on the planes of
 * the BVH's boxes: a flat grid of unit squares (two triangles each) in z = 0, every box of
 * the tree bounded by whole numbers, and rays straight down (0, 0, -1) from z = 5 at every
 * quarter of the grid, whole numbers and the grid's own edges included (on an edge the
 * triangle test counts the point in), their zero components +0 or -0 (1 / d = +inf or
 * -inf). A plane through the origin gives 0 * inf = NaN: the box test must take the ray as
 * inside that slab (trace.glsl, enter_box); the min-and-max slab test before it dropped rays
 * on the lower faces, a finite stand-in for 1 / 0 those on the upper ones. Closed form:
 * every ray meets a triangle of the square under it at t = 5. */
static void test_axis_aligned_rays_on_box_planes(void)
{
    enum { N = 8, STEPS = 4 * N + 1 };
    static GpuPrim grid[2 * N * N];
    for (int y = 0; y < N; y++)
        for (int x = 0; x < N; x++)
            for (int half = 0; half < 2; half++) {
                GpuPrim *p = &grid[2 * (y * N + x) + half];
                memset(p, 0, sizeof *p);
                p->info[0] = NS_PRIM_TRIANGLE;
                float corner[4][2] = {{x, y}, {x + 1, y}, {x + 1, y + 1}, {x, y + 1}};
                int v[2][3] = {{0, 1, 2}, {0, 2, 3}};
                float *verts[3] = {p->a, p->b, p->c};
                for (int k = 0; k < 3; k++) {
                    verts[k][0] = corner[v[half][k]][0];
                    verts[k][1] = corner[v[half][k]][1];
                }
            }
    static GpuRay rays[STEPS * STEPS];
    static GpuHit hits[STEPS * STEPS];
    for (int j = 0; j < STEPS; j++)
        for (int i = 0; i < STEPS; i++)
            rays[j * STEPS + i] = (GpuRay){{0.25f * i, 0.25f * j, 5.0f, 1e30f},
                                           {(i + j) % 2 ? -0.0f : 0.0f, j % 2 ? -0.0f : 0.0f, -1.0f, 0.0f}};
    ns_error err = {0};
    CHECK_INT(ns_trace_rays(test_context(), grid, 2 * N * N, NULL, 0, rays, STEPS * STEPS, hits, &err),
              NS_OK);
    int wrong = 0;
    for (int r = 0; r < STEPS * STEPS; r++) {
        const GpuHit *h = &hits[r];
        int ok = h->prim < 2 * N * N && fabs(h->t - 5.0) <= 1e-5;
        if (ok) { /* the square under the ray: its corners bound the point, edges included */
            const GpuPrim *p = &grid[h->prim];
            float x0 = fminf(p->a[0], fminf(p->b[0], p->c[0])), x1 = fmaxf(p->a[0], fmaxf(p->b[0], p->c[0]));
            float y0 = fminf(p->a[1], fminf(p->b[1], p->c[1])), y1 = fmaxf(p->a[1], fmaxf(p->b[1], p->c[1]));
            ok = rays[r].origin[0] >= x0 && rays[r].origin[0] <= x1 && rays[r].origin[1] >= y0 &&
                 rays[r].origin[1] <= y1;
        }
        if (!ok && wrong++ < 5)
            fprintf(stderr, "ray at (%g, %g): prim %u t %g\n", rays[r].origin[0], rays[r].origin[1],
                    h->prim, h->t);
    }
    CHECK_INT(wrong, 0);
    /* The any-hit query of the same rays (trace_shadow): each is blocked before t = 10. */
    for (int r = 0; r < STEPS * STEPS; r++) {
        rays[r].origin[3] = 10.0f;
        rays[r].direction[3] = 1.0f;
    }
    CHECK_INT(ns_trace_rays(test_context(), grid, 2 * N * N, NULL, 0, rays, STEPS * STEPS, hits, &err),
              NS_OK);
    int clear = 0;
    for (int r = 0; r < STEPS * STEPS; r++)
        clear += hits[r].prim != 0;
    CHECK_INT(clear, 0);
}

int main(void)
{
    RUN(test_bvh_matches_brute_force);
    RUN(test_any_hit_matches_brute_force);
    RUN(test_leaves_past_depth_limit);
    RUN(test_degenerate_trees);
    RUN(test_axis_aligned_rays_on_box_planes);
    ns_context_destroy(test_context());
    return harness_report();
}
