/* rays.c — bench_rays: ray throughput of nscatter's BVH traversal on the device against
 * Embree on the CPU, the same rays side by side in one run (issue 16's first target).
 *
 * The rays: the bench's bunny (io/bench_mesh from glmark2-data's OBJ) placed as
 * scenes/bench/bunny.json places it, on that scene's floor plane, seen by that scene's
 * pinhole camera at WIDTHxHEIGHT (512² by default): one primary ray through every pixel
 * centre (row by row), then for every primary hit one shadow ray towards a directional
 * light (from the hit point moved off the surface by the renderer's ray_epsilon, to infinity;
 * made once from Embree's primary hits, untimed, so that both sides trace the same shadow
 * rays).
 *
 *   nscatter  ns_trace_rays_timed (render/trace_rays.c): the real traversal (trace.glsl,
 *             through shaders/trace_test.comp): trace_scene's nearest hit for primary rays,
 *             trace_shadow's any-hit query for shadow rays as the renderer traces them
 *             (--nearest-shadow: their nearest hit, as before that query existed).
 *             Timed by two timestamp queries around the dispatch (device time only: no BVH
 *             build, no upload, no readback); the host time from recording to the fence is
 *             printed beside it.
 *   Embree    rtcIntersect1 for primary rays and rtcOccluded1 for shadow rays on T threads
 *             (pthreads, each taking chunks of CHUNK consecutive rays from a shared counter),
 *             T = the threads lavapipe uses (LP_NUM_THREADS, else the online CPUs); also
 *             rtcIntersect16 / rtcOccluded16 on 16 consecutive rays, reported apart. Timed
 *             by the wall clock from starting the threads to joining them (thread start
 *             included, tens of microseconds). The scene is built once (untimed). The
 *             threads flush denormals to zero (FTZ and DAZ), as Embree asks.
 *
 * Every measurement is one warm-up and then --repeat timed runs, best and median reported;
 * each repetition runs nscatter's dispatch, then Embree scalar, then Embree packets, back to
 * back (ns_trace_timing.between), so that on a shared machine both sides see the same load;
 * the ratio is given from the medians and as the median of the per-repetition ratios. Three
 * sets: all rays in one dispatch / one run (the headline), the primary rays alone, the
 * shadow rays alone.
 *
 * The floor: nscatter traces it as the renderer does, an infinite plane kept outside the BVH
 * and tested by every ray. Embree has no infinite plane, so its floor is a square of two
 * triangles in the plane, centred on the scene's point, whose half side is a power of two
 * at least twice the farthest floor hit of any primary ray (computed from the rays): every
 * ray of the set that meets the plane meets the square, so both sides see the same surface.
 * --floor quad gives nscatter the same two triangles in its BVH instead.
 *
 * Honesty check: each side's hits are compared (primary: same triangle or both the floor or
 * both nothing, and hit distance within 1e-4 relative; shadow: same occluded or not), and
 * the run fails (exit 1) when fewer than 99.9% of the rays agree.
 *
 * Output: a text table and one line of JSON (starting {"bench":"rays"). Exit status: 0
 * measured, 1 a side failed or the sides disagree, 2 bad arguments or input files.
 */
#define _GNU_SOURCE
#include <embree3/rtcore.h>
#include <jansson.h>
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

#include "bench_mesh.h"
#include "internal.h"
#include "nscatter.h"

#define CHUNK 1024
#define AGREE_MIN 0.999
#define T_TOLERANCE 1e-4

#ifndef NS_SOURCE_DIR
#define NS_SOURCE_DIR "."
#endif

/* ---------------------------------------------------------------------------------------
 * Arguments
 * ------------------------------------------------------------------------------------- */
typedef struct args {
    const char *scene, *bunny, *device;
    const char *embree_isa; /* Embree's config "max_isa=": the widest instructions it may use */
    uint32_t width, height, repeat, threads;
    double light[3];
    int no_packets;
    int nearest_shadow; /* nscatter's shadow rays: 0 any-hit (as the renderer), 1 nearest */
    int floor_quad; /* nscatter's floor: 0 its plane (as the renderer), 1 Embree's square */
} args;

static void usage(FILE *f)
{
    fprintf(f,
            "usage: bench_rays [options]\n"
            "  --scene FILE    camera, floor and bunny placement (default: the source tree's\n"
            "                  scenes/bench/bunny.json)\n"
            "  --bunny OBJ     the Stanford bunny (default NSCATTER_BUNNY_OBJ, else\n"
            "                  /usr/share/glmark2/models/bunny.obj)\n"
            "  --size WxH      image size, one primary ray per pixel (default 512x512)\n"
            "  --repeat N      timed runs per side, after one untimed warm-up (default 7)\n"
            "  --threads N     Embree's threads (default LP_NUM_THREADS, else the online CPUs:\n"
            "                  the threads lavapipe uses)\n"
            "  --light X,Y,Z   direction towards the directional light (default 3,5,3)\n"
            "  --no-packets    skip the rtcIntersect16/rtcOccluded16 runs\n"
            "  --nearest-shadow  nscatter traces shadow rays for their nearest hit (as before\n"
            "                  the any-hit query), not with the renderer's any-hit query\n"
            "  --floor F       nscatter's floor: plane (default: an infinite plane outside the\n"
            "                  BVH, as the renderer traces a plane) or quad (Embree's square, its\n"
            "                  two triangles built into nscatter's BVH with the bunny)\n"
            "  --device D      Vulkan device (index or name part; default lavapipe)\n"
            "  --embree-isa I  the widest instructions Embree may use (its config's max_isa=:\n"
            "                  sse2, sse4.2, avx, avx2, avx512; default: what the CPU has). With\n"
            "                  avx2, and lavapipe told GALLIUM_OVERRIDE_CPU_CAPS=avx (which\n"
            "                  leaves it AVX2 without AVX-512), both sides run as on a CPU\n"
            "                  without AVX-512\n");
}

static int parse_u32(const char *name, const char *text, uint32_t lo, uint32_t hi, uint32_t *out)
{
    char *end;
    unsigned long v = strtoul(text, &end, 10);
    if (!*text || *end || text[0] == '-' || v < lo || v > hi) {
        fprintf(stderr, "bench_rays: %s: '%s' is not a whole number in [%u, %u]\n", name, text, lo,
                hi);
        return 2;
    }
    *out = (uint32_t)v;
    return 0;
}

static int parse_args(int argc, char **argv, args *a)
{
    memset(a, 0, sizeof *a);
    a->width = a->height = 512;
    a->repeat = 7;
    a->light[0] = 3;
    a->light[1] = 5;
    a->light[2] = 3;
    const char *lp = getenv("LP_NUM_THREADS");
    long cpus = sysconf(_SC_NPROCESSORS_ONLN);
    a->threads = lp && atoi(lp) > 0 ? (uint32_t)atoi(lp) : cpus > 0 ? (uint32_t)cpus : 1;
    for (int i = 1; i < argc; i++) {
        const char *o = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        int rc = 0;
        if (!strcmp(o, "--help") || !strcmp(o, "-h")) {
            usage(stdout);
            exit(0);
        } else if (!strcmp(o, "--no-packets")) {
            a->no_packets = 1;
            continue;
        } else if (!strcmp(o, "--nearest-shadow")) {
            a->nearest_shadow = 1;
            continue;
        }
        if (!v) {
            fprintf(stderr, "bench_rays: %s needs a value (or is unknown)\n", o);
            return 2;
        }
        i++;
        if (!strcmp(o, "--scene")) {
            a->scene = v;
        } else if (!strcmp(o, "--bunny")) {
            a->bunny = v;
        } else if (!strcmp(o, "--device")) {
            a->device = v;
        } else if (!strcmp(o, "--embree-isa")) {
            static const char *const isas[] = {"sse2", "sse4.2", "avx", "avx2", "avx512"};
            size_t k = 0;
            while (k < sizeof isas / sizeof isas[0] && strcmp(v, isas[k]))
                k++;
            if (k == sizeof isas / sizeof isas[0]) {
                fprintf(stderr, "bench_rays: --embree-isa: '%s' is none of sse2, sse4.2, avx, "
                                "avx2, avx512\n", v);
                return 2;
            }
            a->embree_isa = isas[k];
        } else if (!strcmp(o, "--floor")) {
            if (!strcmp(v, "plane") || !strcmp(v, "quad")) {
                a->floor_quad = !strcmp(v, "quad");
            } else {
                fprintf(stderr, "bench_rays: --floor: '%s' is neither plane nor quad\n", v);
                return 2;
            }
        } else if (!strcmp(o, "--repeat")) {
            rc = parse_u32(o, v, 1, 1000, &a->repeat);
        } else if (!strcmp(o, "--threads")) {
            rc = parse_u32(o, v, 1, 256, &a->threads);
        } else if (!strcmp(o, "--size")) {
            char w[32];
            const char *x = strchr(v, 'x');
            if (!x || (size_t)(x - v) >= sizeof w) {
                fprintf(stderr, "bench_rays: --size: '%s' is not WxH\n", v);
                return 2;
            }
            memcpy(w, v, (size_t)(x - v));
            w[x - v] = 0;
            rc = parse_u32(o, w, 1, 8192, &a->width);
            if (!rc)
                rc = parse_u32(o, x + 1, 1, 8192, &a->height);
        } else if (!strcmp(o, "--light")) {
            char *end;
            const char *p = v;
            for (int k = 0; k < 3 && !rc; k++) {
                a->light[k] = strtod(p, &end);
                if (end == p || !isfinite(a->light[k]) || (k < 2 ? *end != ',' : *end != 0))
                    rc = 2;
                p = end + 1;
            }
            if (!rc && a->light[0] == 0 && a->light[1] == 0 && a->light[2] == 0)
                rc = 2;
            if (rc)
                fprintf(stderr, "bench_rays: --light: '%s' is not a nonzero X,Y,Z\n", v);
        } else {
            fprintf(stderr, "bench_rays: unknown option %s\n", o);
            usage(stderr);
            return 2;
        }
        if (rc)
            return rc;
    }
    return 0;
}

/* ---------------------------------------------------------------------------------------
 * The scene: camera, floor and bunny placement read from the bench's scene file
 * ------------------------------------------------------------------------------------- */
typedef struct setup {
    double cam_pos[3], cam_look[3], cam_up[3], fov_deg;
    double floor_point[3], floor_normal[3];
    double translate[3];
} setup;

static int read_vec3(json_t *parent, const char *key, double out[3], const char *where)
{
    json_t *v = json_object_get(parent, key);
    if (!json_is_array(v) || json_array_size(v) != 3) {
        fprintf(stderr, "bench_rays: %s.%s: not an array of 3 numbers\n", where, key);
        return 2;
    }
    for (size_t k = 0; k < 3; k++) {
        if (!json_is_number(json_array_get(v, k))) {
            fprintf(stderr, "bench_rays: %s.%s[%zu]: not a number\n", where, key, k);
            return 2;
        }
        out[k] = json_number_value(json_array_get(v, k));
    }
    return 0;
}

static int read_setup(const char *path, setup *s)
{
    json_error_t jerr;
    json_t *root = json_load_file(path, 0, &jerr);
    if (!root) {
        fprintf(stderr, "bench_rays: %s: %s (line %d)\n", path, jerr.text, jerr.line);
        return 2;
    }
    memset(s, 0, sizeof *s);
    json_t *cam = json_object_get(root, "camera");
    int rc = read_vec3(cam, "position", s->cam_pos, "camera");
    if (!rc)
        rc = read_vec3(cam, "look_at", s->cam_look, "camera");
    if (!rc)
        rc = read_vec3(cam, "up", s->cam_up, "camera");
    if (!rc) {
        json_t *fov = json_object_get(cam, "fov");
        s->fov_deg = json_is_number(fov) ? json_number_value(fov) : 0;
        if (!(s->fov_deg > 0 && s->fov_deg < 180)) {
            fprintf(stderr, "bench_rays: %s: camera.fov missing or outside (0, 180)\n", path);
            rc = 2;
        }
    }
    int planes = 0, meshes = 0;
    json_t *objects = json_object_get(root, "objects");
    for (size_t i = 0; !rc && i < json_array_size(objects); i++) {
        json_t *o = json_array_get(objects, i);
        const char *shape = json_string_value(json_object_get(o, "shape"));
        if (shape && !strcmp(shape, "plane")) {
            rc = read_vec3(o, "point", s->floor_point, "plane");
            if (!rc)
                rc = read_vec3(o, "normal", s->floor_normal, "plane");
            planes++;
        } else if (shape && !strcmp(shape, "mesh")) {
            json_t *t = json_object_get(o, "transform");
            const char *key;
            json_t *value;
            json_object_foreach(t, key, value)
            {
                (void)value;
                if (strcmp(key, "translate")) {
                    fprintf(stderr,
                            "bench_rays: %s: mesh transform \"%s\": only translate is "
                            "supported here\n",
                            path, key);
                    rc = 2;
                }
            }
            if (!rc && json_object_get(t, "translate"))
                rc = read_vec3(t, "translate", s->translate, "mesh.transform");
            meshes++;
        }
    }
    if (!rc && (planes != 1 || meshes != 1)) {
        fprintf(stderr, "bench_rays: %s: needs one plane and one mesh (has %d and %d)\n", path,
                planes, meshes);
        rc = 2;
    }
    double n =
        sqrt(s->floor_normal[0] * s->floor_normal[0] + s->floor_normal[1] * s->floor_normal[1] +
             s->floor_normal[2] * s->floor_normal[2]);
    if (!rc && !(n > 0)) {
        fprintf(stderr, "bench_rays: %s: the plane's normal is zero\n", path);
        rc = 2;
    }
    for (int k = 0; !rc && k < 3; k++)
        s->floor_normal[k] /= n;
    json_decref(root);
    return rc;
}

/* ---------------------------------------------------------------------------------------
 * Small vector helpers (double)
 * ------------------------------------------------------------------------------------- */
static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void cross3(const double a[3], const double b[3], double out[3])
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

static void normalize3(double v[3])
{
    double n = sqrt(dot3(v, v));
    for (int k = 0; k < 3; k++)
        v[k] /= n;
}

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

typedef struct timing {
    double best, median; /* ms over the timed runs */
} timing;

static timing summarize(const double *ms, uint32_t n)
{
    double *sorted = malloc(sizeof *sorted * n);
    memcpy(sorted, ms, sizeof *sorted * n);
    qsort(sorted, n, sizeof *sorted, cmp_double);
    timing t = {sorted[0], n % 2 ? sorted[n / 2] : 0.5 * (sorted[n / 2 - 1] + sorted[n / 2])};
    free(sorted);
    return t;
}

/* The renderer's ray offset (common.glsl's ray_epsilon). */
static double ray_epsilon(const double p[3])
{
    double m = fmax(1.0, fmax(fabs(p[0]), fmax(fabs(p[1]), fabs(p[2]))));
    return 1e-4 * m;
}

/* ---------------------------------------------------------------------------------------
 * The rays: GpuRay (origin.w = tmax), shared by both sides. Primary rays first (row by row,
 * pixel centres), then the shadow rays in the order of their primary hits.
 * ------------------------------------------------------------------------------------- */
static void primary_rays(const setup *s, uint32_t w, uint32_t h, GpuRay *rays)
{
    /* The pinhole camera's frame (render/scene_gpu.c): horizontal fov, row 0 at the top. */
    double f[3], r[3], up[3];
    for (int k = 0; k < 3; k++)
        f[k] = s->cam_look[k] - s->cam_pos[k];
    normalize3(f);
    cross3(f, s->cam_up, r);
    normalize3(r);
    cross3(r, f, up);
    double tx = tan(s->fov_deg * M_PI / 360.0), ty = tx * h / w;
    for (uint32_t y = 0; y < h; y++)
        for (uint32_t x = 0; x < w; x++) {
            double u = (x + 0.5) / w, v = (y + 0.5) / h, d[3];
            for (int k = 0; k < 3; k++)
                d[k] = f[k] + r[k] * (2 * u - 1) * tx + up[k] * (1 - 2 * v) * ty;
            normalize3(d);
            GpuRay *ray = &rays[(size_t)y * w + x];
            memset(ray, 0, sizeof *ray);
            for (int k = 0; k < 3; k++) {
                ray->origin[k] = (float)s->cam_pos[k];
                ray->direction[k] = (float)d[k];
            }
            ray->origin[3] = INFINITY;
        }
}

/* ---------------------------------------------------------------------------------------
 * Embree
 * ------------------------------------------------------------------------------------- */
enum { EMBREE_SCALAR = 0, EMBREE_PACKET16 = 1 };
enum { FLOOR_ID = 0xfffffffeu }; /* the hit class of the floor (either side) */

typedef struct embree_job {
    RTCScene scene;
    const GpuRay *rays;
    uint32_t first_shadow, count; /* rays [0, first_shadow) are primary, the rest shadow */
    uint32_t floor_geom;
    int mode;
    uint32_t *prim; /* per ray: triangle, FLOOR_ID or NS_NONE; shadow rays: 1 occluded, 0 not */
    float *t;
    uint32_t next; /* shared chunk counter */
} embree_job;

static void embree_record(embree_job *job, uint32_t i, unsigned geom, unsigned prim, float tfar)
{
    if (geom == RTC_INVALID_GEOMETRY_ID) {
        job->prim[i] = NS_NONE;
        job->t[i] = -1;
    } else {
        job->prim[i] = geom == job->floor_geom ? FLOOR_ID : prim;
        job->t[i] = tfar;
    }
}

static void embree_scalar(embree_job *job, uint32_t begin, uint32_t end)
{
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    for (uint32_t i = begin; i < end; i++) {
        const GpuRay *g = &job->rays[i];
        if (i < job->first_shadow) {
            struct RTCRayHit rh;
            rh.ray.org_x = g->origin[0];
            rh.ray.org_y = g->origin[1];
            rh.ray.org_z = g->origin[2];
            rh.ray.tnear = 0.0f;
            rh.ray.dir_x = g->direction[0];
            rh.ray.dir_y = g->direction[1];
            rh.ray.dir_z = g->direction[2];
            rh.ray.time = 0.0f;
            rh.ray.tfar = g->origin[3];
            rh.ray.mask = 0xffffffffu;
            rh.ray.id = i;
            rh.ray.flags = 0;
            rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
            rtcIntersect1(job->scene, &ctx, &rh);
            embree_record(job, i, rh.hit.geomID, rh.hit.primID, rh.ray.tfar);
        } else {
            struct RTCRay ray;
            ray.org_x = g->origin[0];
            ray.org_y = g->origin[1];
            ray.org_z = g->origin[2];
            ray.tnear = 0.0f;
            ray.dir_x = g->direction[0];
            ray.dir_y = g->direction[1];
            ray.dir_z = g->direction[2];
            ray.time = 0.0f;
            ray.tfar = g->origin[3];
            ray.mask = 0xffffffffu;
            ray.id = i;
            ray.flags = 0;
            rtcOccluded1(job->scene, &ctx, &ray);
            job->prim[i] = ray.tfar == -INFINITY ? 1u : 0u;
            job->t[i] = 0;
        }
    }
}

/* Packets of 16 consecutive rays of one kind (a packet never mixes primary and shadow). */
static void embree_packets(embree_job *job, uint32_t begin, uint32_t end)
{
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    for (uint32_t base = begin; base < end;) {
        uint32_t stop = base < job->first_shadow ? job->first_shadow : end;
        if (stop > end)
            stop = end;
        if (stop - base > 16)
            stop = base + 16;
        int valid[16];
        struct RTCRayHit16 rh;
        struct RTCRay16 *ray = &rh.ray;
        for (uint32_t j = 0; j < 16; j++) {
            uint32_t i = base + j < stop ? base + j : base;
            const GpuRay *g = &job->rays[i];
            valid[j] = base + j < stop ? -1 : 0;
            ray->org_x[j] = g->origin[0];
            ray->org_y[j] = g->origin[1];
            ray->org_z[j] = g->origin[2];
            ray->tnear[j] = 0.0f;
            ray->dir_x[j] = g->direction[0];
            ray->dir_y[j] = g->direction[1];
            ray->dir_z[j] = g->direction[2];
            ray->time[j] = 0.0f;
            ray->tfar[j] = g->origin[3];
            ray->mask[j] = 0xffffffffu;
            ray->id[j] = i;
            ray->flags[j] = 0;
            rh.hit.geomID[j] = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0][j] = RTC_INVALID_GEOMETRY_ID;
        }
        if (base < job->first_shadow) {
            rtcIntersect16(valid, job->scene, &ctx, &rh);
            for (uint32_t j = 0; base + j < stop; j++)
                embree_record(job, base + j, rh.hit.geomID[j], rh.hit.primID[j], ray->tfar[j]);
        } else {
            rtcOccluded16(valid, job->scene, &ctx, ray);
            for (uint32_t j = 0; base + j < stop; j++) {
                job->prim[base + j] = ray->tfar[j] == -INFINITY ? 1u : 0u;
                job->t[base + j] = 0;
            }
        }
        base = stop;
    }
}

static void *embree_worker(void *arg)
{
    embree_job *job = arg;
#if defined(__SSE__)
    /* Flush denormals to zero and read them as zero, as Embree asks of every thread that
     * traces (its verbose start-up warns without them); the caller's mode is restored after. */
    unsigned int csr = _mm_getcsr();
    _mm_setcsr(csr | 0x8040u); /* FTZ (bit 15) | DAZ (bit 6) */
#endif
    for (;;) {
        uint32_t begin = __atomic_fetch_add(&job->next, CHUNK, __ATOMIC_RELAXED);
        if (begin >= job->count)
            break;
        uint32_t end = begin + CHUNK < job->count ? begin + CHUNK : job->count;
        if (job->mode == EMBREE_PACKET16)
            embree_packets(job, begin, end);
        else
            embree_scalar(job, begin, end);
    }
#if defined(__SSE__)
    _mm_setcsr(csr);
#endif
    return NULL;
}

/* One run over all rays on `threads` threads; returns its wall time in ms. */
static double embree_run(embree_job *job, uint32_t threads)
{
    pthread_t tid[256];
    job->next = 0;
    double start = now_ms();
    for (uint32_t i = 1; i < threads; i++)
        pthread_create(&tid[i], NULL, embree_worker, job);
    embree_worker(job);
    for (uint32_t i = 1; i < threads; i++)
        pthread_join(tid[i], NULL);
    return now_ms() - start;
}

/* The Embree runs made between nscatter's dispatches (ns_trace_timing.between). */
typedef struct interleave {
    embree_job scalar, packet;
    uint32_t threads;
    double *scalar_ms, *packet_ms; /* packet_ms NULL: no packet runs */
} interleave;

static void interleave_run(void *user, uint32_t r)
{
    interleave *il = user;
    il->scalar_ms[r] = embree_run(&il->scalar, il->threads);
    if (il->packet_ms)
        il->packet_ms[r] = embree_run(&il->packet, il->threads);
}

static void embree_error(void *user, enum RTCError code, const char *str)
{
    (void)user;
    fprintf(stderr, "bench_rays: Embree error %d: %s\n", (int)code, str ? str : "");
}

/* ---------------------------------------------------------------------------------------
 * Comparing the sides
 * ------------------------------------------------------------------------------------- */
typedef struct agreement {
    uint64_t primary_differ, shadow_differ;
} agreement;

/* ns: nscatter's hits (prim in caller order; tri_count = the floor plane); e: Embree's. */
static agreement compare(const GpuHit *ns, const uint32_t *e_prim, const float *e_t,
                         uint32_t primary, uint32_t total, uint32_t tri_count, int verbose)
{
    agreement a = {0, 0};
    for (uint32_t i = 0; i < total; i++) {
        uint32_t np = ns[i].prim;
        if (i < primary) {
            uint32_t cls = np == NS_NONE ? NS_NONE : np >= tri_count ? FLOOR_ID : np;
            int same = cls == e_prim[i];
            if (same && cls != NS_NONE)
                same = fabs((double)ns[i].t - e_t[i]) <= T_TOLERANCE * fabs((double)e_t[i]);
            if (!same && a.primary_differ++ < 5 && verbose)
                fprintf(stderr,
                        "  primary ray %u: nscatter prim %d t %.7g, Embree prim %d t %.7g\n", i,
                        (int)cls, (double)ns[i].t, (int)e_prim[i], (double)e_t[i]);
        } else {
            uint32_t occluded = np != NS_NONE;
            if (occluded != e_prim[i] && a.shadow_differ++ < 5 && verbose)
                fprintf(stderr, "  shadow ray %u: nscatter %s (prim %d t %.7g), Embree %s\n", i,
                        occluded ? "occluded" : "clear", (int)np, (double)ns[i].t,
                        e_prim[i] ? "occluded" : "clear");
        }
    }
    return a;
}

/* ---------------------------------------------------------------------------------------
 * Reporting
 * ------------------------------------------------------------------------------------- */
static void cpu_name(char *out, size_t cap)
{
    snprintf(out, cap, "unknown CPU");
    FILE *f = fopen("/proc/cpuinfo", "r");
    if (!f)
        return;
    char line[512];
    while (fgets(line, sizeof line, f)) {
        if (!strncmp(line, "model name", 10)) {
            char *c = strchr(line, ':');
            if (c) {
                c++;
                while (*c == ' ' || *c == '\t')
                    c++;
                c[strcspn(c, "\n")] = 0;
                snprintf(out, cap, "%s", c);
            }
            break;
        }
    }
    fclose(f);
}

static void loadavg(double out[3])
{
    out[0] = out[1] = out[2] = -1;
    FILE *f = fopen("/proc/loadavg", "r");
    if (f) {
        if (fscanf(f, "%lf %lf %lf", &out[0], &out[1], &out[2]) != 3)
            out[0] = out[1] = out[2] = -1;
        fclose(f);
    }
}

typedef struct side_result {
    timing all, primary, shadow;
} side_result;

static double mrays(uint32_t rays, double ms)
{
    return ms > 0 ? rays / (ms * 1e3) : 0;
}

static void print_row(const char *name, const char *how, const side_result *r, uint32_t rays)
{
    printf("%-22s %-34s %9.2f %9.2f %8.2f | %8.2f %8.2f\n", name, how, r->all.best, r->all.median,
           mrays(rays, r->all.median), r->primary.median, r->shadow.median);
}

static void json_side(const char *name, const side_result *r, uint32_t rays, uint32_t primary,
                      uint32_t shadow, int last)
{
    printf("\"%s\":{\"ms_best\":%.3f,\"ms_median\":%.3f,\"mrays_per_s\":%.3f,"
           "\"primary_ms_median\":%.3f,\"primary_mrays_per_s\":%.3f,"
           "\"shadow_ms_median\":%.3f,\"shadow_mrays_per_s\":%.3f}%s",
           name, r->all.best, r->all.median, mrays(rays, r->all.median), r->primary.median,
           mrays(primary, r->primary.median), r->shadow.median, mrays(shadow, r->shadow.median),
           last ? "" : ",");
}

/* ---------------------------------------------------------------------------------------
 * main
 * ------------------------------------------------------------------------------------- */
int main(int argc, char **argv)
{
    args a;
    int rc = parse_args(argc, argv, &a);
    if (rc)
        return rc;
    const char *scene_path = a.scene ? a.scene : NS_SOURCE_DIR "/scenes/bench/bunny.json";
    const char *obj = a.bunny ? a.bunny : getenv("NSCATTER_BUNNY_OBJ");
    if (!obj || !*obj)
        obj = "/usr/share/glmark2/models/bunny.obj";
    setup s;
    if ((rc = read_setup(scene_path, &s)))
        return rc;
    bench_mesh mesh;
    ns_error err = {0};
    if (bench_mesh_load_obj(obj, &mesh, &err)) {
        fprintf(stderr, "bench_rays: %s (the bunny comes from Debian's glmark2-data)\n",
                err.message);
        return 2;
    }
    for (uint32_t v = 0; v < mesh.vertex_count; v++)
        for (int k = 0; k < 3; k++)
            mesh.positions[3 * v + k] += (float)s.translate[k];
    uint32_t tris = mesh.triangle_count;
    double light[3] = {a.light[0], a.light[1], a.light[2]};
    normalize3(light);

    /* ---- the primary rays, and the floor square that covers all their floor hits ---- */
    uint32_t primary = a.width * a.height;
    GpuRay *rays = malloc(sizeof *rays * (size_t)primary * 2);
    if (!rays)
        return 1;
    primary_rays(&s, a.width, a.height, rays);
    double far_hit = 1.0;
    for (uint32_t i = 0; i < primary; i++) {
        double o[3] = {rays[i].origin[0], rays[i].origin[1], rays[i].origin[2]};
        double d[3] = {rays[i].direction[0], rays[i].direction[1], rays[i].direction[2]};
        double denom = dot3(d, s.floor_normal);
        if (denom == 0)
            continue;
        double po[3] = {s.floor_point[0] - o[0], s.floor_point[1] - o[1], s.floor_point[2] - o[2]};
        double t = dot3(po, s.floor_normal) / denom;
        if (t <= 0)
            continue;
        double q[3] = {o[0] + t * d[0] - s.floor_point[0], o[1] + t * d[1] - s.floor_point[1],
                       o[2] + t * d[2] - s.floor_point[2]};
        far_hit = fmax(far_hit, sqrt(dot3(q, q)));
    }
    double half = exp2(ceil(log2(2 * far_hit)));
    double t1[3], t2[3];
    {
        double helper[3] = {fabs(s.floor_normal[0]) < 0.9 ? 1 : 0,
                            fabs(s.floor_normal[0]) < 0.9 ? 0 : 1, 0};
        cross3(s.floor_normal, helper, t1);
        normalize3(t1);
        cross3(s.floor_normal, t1, t2);
    }

    /* ---- Embree: the bunny and the floor square ---- */
    char config[64];
    snprintf(config, sizeof config, "threads=%u%s%s", a.threads, a.embree_isa ? ",max_isa=" : "",
             a.embree_isa ? a.embree_isa : "");
    RTCDevice edev = rtcNewDevice(config);
    if (!edev) {
        fprintf(stderr, "bench_rays: rtcNewDevice failed (%d)\n", (int)rtcGetDeviceError(NULL));
        return 1;
    }
    rtcSetDeviceErrorFunction(edev, embree_error, NULL);
    RTCScene escene = rtcNewScene(edev);
    RTCGeometry bunny = rtcNewGeometry(edev, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetSharedGeometryBuffer(bunny, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, mesh.positions,
                               0, 3 * sizeof(float), mesh.vertex_count);
    rtcSetSharedGeometryBuffer(bunny, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, mesh.indices, 0,
                               3 * sizeof(uint32_t), tris);
    rtcCommitGeometry(bunny);
    unsigned bunny_geom = rtcAttachGeometry(escene, bunny);
    rtcReleaseGeometry(bunny);
    RTCGeometry floor_geom = rtcNewGeometry(edev, RTC_GEOMETRY_TYPE_TRIANGLE);
    float *fv = rtcSetNewGeometryBuffer(floor_geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                        3 * sizeof(float), 4);
    unsigned *fi = rtcSetNewGeometryBuffer(floor_geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                           3 * sizeof(unsigned), 2);
    static const double corner[4][2] = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}};
    float floor_v[12];
    for (int c = 0; c < 4; c++)
        for (int k = 0; k < 3; k++)
            floor_v[3 * c + k] =
                (float)(s.floor_point[k] + half * (corner[c][0] * t1[k] + corner[c][1] * t2[k]));
    memcpy(fv, floor_v, sizeof floor_v);
    static const unsigned quad[6] = {0, 1, 2, 0, 2, 3};
    memcpy(fi, quad, sizeof quad);
    rtcCommitGeometry(floor_geom);
    unsigned floor_id = rtcAttachGeometry(escene, floor_geom);
    rtcReleaseGeometry(floor_geom);
    double build_start = now_ms();
    rtcCommitScene(escene);
    double embree_build_ms = now_ms() - build_start;
    if (bunny_geom != 0 || rtcGetDeviceError(edev) != RTC_ERROR_NONE) {
        fprintf(stderr, "bench_rays: Embree scene failed\n");
        return 1;
    }

    /* ---- shadow rays from Embree's primary hits (one per hit, towards the light) ---- */
    uint32_t *e_prim = malloc(sizeof *e_prim * (size_t)primary * 2);
    float *e_t = malloc(sizeof *e_t * (size_t)primary * 2);
    embree_job job = {escene, rays, primary, primary, floor_id, EMBREE_SCALAR, e_prim, e_t, 0};
    embree_run(&job, a.threads);
    uint32_t shadow = 0;
    for (uint32_t i = 0; i < primary; i++) {
        if (e_prim[i] == NS_NONE)
            continue;
        double n[3], p[3];
        for (int k = 0; k < 3; k++)
            p[k] = rays[i].origin[k] + (double)e_t[i] * rays[i].direction[k];
        if (e_prim[i] == FLOOR_ID) {
            memcpy(n, s.floor_normal, sizeof n);
        } else {
            const float *v0 = &mesh.positions[3 * mesh.indices[3 * e_prim[i]]],
                        *v1 = &mesh.positions[3 * mesh.indices[3 * e_prim[i] + 1]],
                        *v2 = &mesh.positions[3 * mesh.indices[3 * e_prim[i] + 2]];
            double e1[3] = {v1[0] - v0[0], v1[1] - v0[1], v1[2] - v0[2]},
                   e2[3] = {v2[0] - v0[0], v2[1] - v0[1], v2[2] - v0[2]};
            cross3(e1, e2, n);
            normalize3(n);
        }
        double d[3] = {rays[i].direction[0], rays[i].direction[1], rays[i].direction[2]};
        double side = dot3(n, d) < 0 ? 1 : -1, eps = ray_epsilon(p);
        GpuRay *r = &rays[primary + shadow++];
        memset(r, 0, sizeof *r);
        for (int k = 0; k < 3; k++) {
            r->origin[k] = (float)(p[k] + side * eps * n[k]);
            r->direction[k] = (float)light[k];
        }
        r->origin[3] = INFINITY;
        r->direction[3] = a.nearest_shadow ? 0.0f : 1.0f; /* trace_test.comp: any-hit */
    }
    uint32_t total = primary + shadow;
    job.count = total;

    /* ---- nscatter: the bunny's triangles in the BVH, the floor as its plane ---- */
    ns_context *ctx = NULL;
    rc = ns_context_create(&(ns_context_desc){.device = a.device}, &ctx, &err);
    if (rc) {
        fprintf(stderr, "bench_rays: ns_context_create: %s\n", err.message);
        return 1;
    }
    ns_device_info info;
    ns_context_device_info(ctx, &info);
    GpuPrim *prims = calloc((size_t)tris + 2, sizeof *prims), plane;
    for (uint32_t i = 0; i < tris; i++) {
        prims[i].info[0] = NS_PRIM_TRIANGLE;
        prims[i].info[2] = 1;
        for (int k = 0; k < 3; k++) {
            prims[i].a[k] = mesh.positions[3 * mesh.indices[3 * i] + k];
            prims[i].b[k] = mesh.positions[3 * mesh.indices[3 * i + 1] + k];
            prims[i].c[k] = mesh.positions[3 * mesh.indices[3 * i + 2] + k];
        }
    }
    memset(&plane, 0, sizeof plane);
    plane.info[0] = NS_PRIM_PLANE;
    for (int k = 0; k < 3; k++) {
        plane.a[k] = (float)s.floor_point[k];
        plane.b[k] = (float)s.floor_normal[k];
    }
    /* --floor quad: Embree's two triangles, same vertices, after the bunny's in the BVH. */
    for (uint32_t q = 0; q < 2; q++) {
        GpuPrim *p = &prims[tris + q];
        p->info[0] = NS_PRIM_TRIANGLE;
        p->info[2] = 0;
        for (int k = 0; k < 3; k++) {
            p->a[k] = floor_v[3 * quad[3 * q] + k];
            p->b[k] = floor_v[3 * quad[3 * q + 1] + k];
            p->c[k] = floor_v[3 * quad[3 * q + 2] + k];
        }
    }
    uint32_t ns_prims = a.floor_quad ? tris + 2 : tris, ns_planes = a.floor_quad ? 0 : 1;

    double load_start[3];
    loadavg(load_start);
    uint32_t runs = a.repeat + 1; /* the first of each set is a warm-up, never counted */
    double *dev_ms = malloc(sizeof *dev_ms * runs), *wall_ms = malloc(sizeof *wall_ms * runs),
           *scalar_ms = malloc(sizeof *scalar_ms * runs),
           *packet_ms = malloc(sizeof *packet_ms * runs),
           *pair_ratio = malloc(sizeof *pair_ratio * runs);
    GpuHit *hits = malloc(sizeof *hits * (size_t)total);
    uint32_t *p_prim = malloc(sizeof *p_prim * (size_t)total);
    float *p_t = malloc(sizeof *p_t * (size_t)total);
    side_result ns_dev, ns_wall, em_scalar, em_packet;
    memset(&em_packet, 0, sizeof em_packet);
    struct {
        uint32_t first, count;
        timing *dev, *wall, *scalar, *packet;
    } sets[3] = {
        {0, total, &ns_dev.all, &ns_wall.all, &em_scalar.all, &em_packet.all},
        {0, primary, &ns_dev.primary, &ns_wall.primary, &em_scalar.primary, &em_packet.primary},
        {primary, shadow, &ns_dev.shadow, &ns_wall.shadow, &em_scalar.shadow, &em_packet.shadow},
    };
    int timestamps = 1;
    timing pair = {0, 0};
    agreement agree = {0, 0}, agree_packet = {0, 0};
    for (int set = 0; set < 3; set++) {
        /* Embree's runs of the same rays, scalar then packets, interleaved with nscatter's
         * dispatches (one of each per repetition) so that both sides see the same load. */
        interleave il = {.scalar = job,
                         .threads = a.threads,
                         .scalar_ms = scalar_ms,
                         .packet_ms = a.no_packets ? NULL : packet_ms};
        il.scalar.rays = rays + sets[set].first;
        il.scalar.first_shadow = set == 2 ? 0 : set == 1 ? sets[set].count : primary;
        il.scalar.count = sets[set].count;
        il.packet = il.scalar;
        il.packet.mode = EMBREE_PACKET16;
        il.packet.prim = p_prim;
        il.packet.t = p_t;
        /* nscatter: one BVH and one upload, then `runs` dispatches of the same rays. */
        rc = ns_trace_rays_timed(ctx, prims, ns_prims, &plane, ns_planes, rays + sets[set].first,
                                 sets[set].count, hits,
                                 &(ns_trace_timing){.repeats = runs,
                                                    .device_ms = dev_ms,
                                                    .wall_ms = wall_ms,
                                                    .between = interleave_run,
                                                    .user = &il},
                                 &err);
        if (rc) {
            fprintf(stderr, "bench_rays: ns_trace_rays_timed: %s\n", err.message);
            return 1;
        }
        if (dev_ms[1] < 0)
            timestamps = 0;
        const double *ns_ms = timestamps ? dev_ms : wall_ms;
        *sets[set].dev = summarize(ns_ms + 1, a.repeat);
        *sets[set].wall = summarize(wall_ms + 1, a.repeat);
        *sets[set].scalar = summarize(scalar_ms + 1, a.repeat);
        if (!a.no_packets)
            *sets[set].packet = summarize(packet_ms + 1, a.repeat);
        if (set == 0) {
            for (uint32_t r = 1; r < runs; r++)
                pair_ratio[r] = ns_ms[r] > 0 ? scalar_ms[r] / ns_ms[r] : 0;
            pair = summarize(pair_ratio + 1, a.repeat);
            agree = compare(hits, e_prim, e_t, primary, total, tris, 1);
            if (!a.no_packets)
                agree_packet = compare(hits, p_prim, p_t, primary, total, tris, 0);
        }
    }
    double load_end[3];
    loadavg(load_end);

    /* ---- report ---- */
    char cpu[256];
    cpu_name(cpu, sizeof cpu);
    char eversion[64];
    snprintf(eversion, sizeof eversion, "%s", RTC_VERSION_STRING);
    uint64_t differ = agree.primary_differ + agree.shadow_differ;
    double agree_fraction = 1.0 - (double)differ / total;
    double ratio = ns_dev.all.median > 0 ? em_scalar.all.median / ns_dev.all.median : 0;
    printf("bench_rays: %s, %u triangles on a floor (Embree: a %.0f x %.0f square, nscatter: "
           "%s), %ux%u, 1 spp\n",
           obj, tris, 2 * half, 2 * half, a.floor_quad ? "the same square in its BVH" : "its plane",
           a.width, a.height);
    printf("rays: %u = %u primary + %u shadow (light towards %.3f,%.3f,%.3f)\n", total, primary,
           shadow, light[0], light[1], light[2]);
    printf("device: %s (%s; %s), %u thread(s) for Embree; CPU %s\n", info.device_name,
           info.driver_name, info.driver_info, a.threads, cpu);
    printf("Embree %s (isa: %s), scene build %.1f ms (not timed below); load average %.2f -> "
           "%.2f\n",
           eversion, a.embree_isa ? a.embree_isa : "the CPU's", embree_build_ms, load_start[0],
           load_end[0]);
    printf("timed runs: %u per side and set, after one warm-up; nscatter = %s; nscatter's shadow "
           "rays: %s\n\n",
           a.repeat,
           timestamps ? "device time between two timestamp queries around the dispatch"
                      : "host time from recording to the fence (the queue has no timestamps)",
           a.nearest_shadow ? "nearest hit" : "any-hit");
    printf("%-22s %-34s %9s %9s %8s | %8s %8s\n", "side", "how", "best ms", "median ms", "Mrays/s",
           "prim ms", "shadow ms");
    print_row("nscatter", timestamps ? "trace_test.comp, timestamps" : "trace_test.comp, host",
              &ns_dev, total);
    print_row("nscatter (host)", "record + submit + fence", &ns_wall, total);
    char how[64];
    snprintf(how, sizeof how, "rtcIntersect1/rtcOccluded1, %u thr", a.threads);
    print_row("embree scalar", how, &em_scalar, total);
    if (!a.no_packets) {
        snprintf(how, sizeof how, "rtcIntersect16/rtcOccluded16, %u thr", a.threads);
        print_row("embree packets16", how, &em_packet, total);
    }
    printf("\nnscatter / embree scalar throughput: %.4f (1/%.1f) from the medians, %.4f (1/%.1f) "
           "median of the %u back-to-back pairs; issue 16's target >= 1/3\n",
           ratio, ratio > 0 ? 1 / ratio : 0, pair.median, pair.median > 0 ? 1 / pair.median : 0,
           a.repeat);
    printf("agreement: %llu of %u rays differ (%llu primary, %llu shadow): %.4f%% agree "
           "(needs >= %.1f%%)",
           (unsigned long long)differ, total, (unsigned long long)agree.primary_differ,
           (unsigned long long)agree.shadow_differ, 100 * agree_fraction, 100 * AGREE_MIN);
    if (!a.no_packets)
        printf("; packets vs nscatter: %llu differ",
               (unsigned long long)(agree_packet.primary_differ + agree_packet.shadow_differ));
    printf("\n");

    printf("{\"bench\":\"rays\",\"width\":%u,\"height\":%u,\"triangles\":%u,\"rays\":%u,"
           "\"primary\":%u,\"shadow\":%u,\"repeat\":%u,\"threads\":%u,\"device\":\"%s\","
           "\"driver\":\"%s\",\"cpu\":\"%s\",\"embree\":\"%s\",\"nscatter_timing\":\"%s\","
           "\"floor\":\"%s\",\"shadow_query\":\"%s\",\"embree_isa\":\"%s\",\"load_start\":%.2f,"
           "\"load_end\":%.2f,",
           a.width, a.height, tris, total, primary, shadow, a.repeat, a.threads, info.device_name,
           info.driver_info, cpu, eversion, timestamps ? "timestamps" : "host",
           a.floor_quad ? "quad" : "plane", a.nearest_shadow ? "nearest" : "any",
           a.embree_isa ? a.embree_isa : "native", load_start[0], load_end[0]);
    json_side("nscatter", &ns_dev, total, primary, shadow, 0);
    json_side("nscatter_host", &ns_wall, total, primary, shadow, 0);
    json_side("embree_scalar", &em_scalar, total, primary, shadow, 0);
    if (!a.no_packets)
        json_side("embree_packet16", &em_packet, total, primary, shadow, 0);
    printf("\"ratio\":%.5f,\"ratio_pairs_median\":%.5f,\"differ_primary\":%llu,\"differ_shadow\":%"
           "llu,\"agree\":%.6f}\n",
           ratio, pair.median, (unsigned long long)agree.primary_differ,
           (unsigned long long)agree.shadow_differ, agree_fraction);

    int ok = agree_fraction >= AGREE_MIN;
    if (!ok)
        fprintf(stderr,
                "bench_rays: the sides disagree on %.3f%% of the rays: not a fair "
                "comparison\n",
                100 * (1 - agree_fraction));
    free(hits);
    free(dev_ms);
    free(wall_ms);
    free(scalar_ms);
    free(packet_ms);
    free(pair_ratio);
    free(p_prim);
    free(p_t);
    free(prims);
    free(e_prim);
    free(e_t);
    free(rays);
    ns_context_destroy(ctx);
    rtcReleaseScene(escene);
    rtcReleaseDevice(edev);
    bench_mesh_free(&mesh);
    return ok ? 0 : 1;
}
