/* vrl.c — Virtual Ray Light generation, the C side (shaders/vrl.comp traces the paths).
 *
 * Plan: one target sphere per object whose material scatters (sigma_s > 0), one stratum per
 * (light, target) pair with the power the light sends through that sphere as its estimate,
 * and the `paths` light paths spread over the strata by systematic sampling in proportion to
 * that power: path i belongs to stratum s when cdf[s-1] <= (i + xi) / N < cdf[s] for one
 * offset xi drawn from the seed. Every stratum is then expected to get exactly N p_s paths,
 * and a path's flux divided by N p_s is unbiased whatever xi is. A path that reaches another
 * object first adds nothing here: what enters that object is counted by its own strata.
 *
 * After the dispatch the per-path slots are compacted in path order, so the set depends on
 * the seed only, not on the order the invocations ran in.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scatter.h"
#include "vrl_shared.h"

/* ---------------------------------------------------------------------------------------
 * Targets: a bounding sphere per scattering medium object.
 * ------------------------------------------------------------------------------------- */
static int material_scatters(const ns_material *m)
{
    return m->type == NS_MATERIAL_MEDIUM &&
           (m->sigma_s[0] > 0.0f || m->sigma_s[1] > 0.0f || m->sigma_s[2] > 0.0f);
}

static void grow_box(float lo[3], float hi[3], const float p[3])
{
    for (int k = 0; k < 3; k++) {
        lo[k] = fminf(lo[k], p[k]);
        hi[k] = fmaxf(hi[k], p[k]);
    }
}

/* The sphere around a box (centre, half diagonal), slightly enlarged so that rays through
 * its corners are not lost to rounding. */
static void box_sphere(const float lo[3], const float hi[3], float out[4])
{
    double r2 = 0;
    for (int k = 0; k < 3; k++) {
        out[k] = 0.5f * (lo[k] + hi[k]);
        r2 += 0.25 * ((double)hi[k] - lo[k]) * ((double)hi[k] - lo[k]);
    }
    out[3] = (float)(sqrt(r2) * 1.0001 + 1e-6);
}

/* A sphere is its own target, exactly: the disk and cone estimators are then exact for
 * index-matched spheres (every sample hits). */
void ns_vrl_target_sphere(const ns_scene *scene, const ns_object *o, float out[4])
{
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    switch (o->shape) {
    case NS_SHAPE_SPHERE:
        memcpy(out, o->center, sizeof o->center);
        out[3] = o->radius;
        return;
    case NS_SHAPE_BOX:
        grow_box(lo, hi, o->min);
        grow_box(lo, hi, o->max);
        break;
    default: /* mesh; planes are refused before */
        for (uint32_t t = 0; t < o->triangle_count; t++)
            for (int v = 0; v < 3; v++)
                grow_box(lo, hi, scene->triangles[o->first_triangle + t].v[v]);
        break;
    }
    box_sphere(lo, hi, out);
}

int ns_vrl_targets(const ns_scene *scene, const char *who, ns_vrl_target *out, uint32_t *count,
                   ns_error *err)
{
    uint32_t n = 0;
    for (uint32_t i = 0; i < scene->object_count; i++) {
        const ns_object *o = &scene->objects[i];
        if (!material_scatters(&scene->materials[o->material]))
            continue;
        if (o->shape == NS_SHAPE_PLANE)
            return ns_fail(err, NS_ERR_NOT_AVAILABLE,
                           "objects[%u]: a plane of scattering medium '%s' is unbounded; %s "
                           "needs a bounded medium (sphere, box or mesh)",
                           i, scene->materials[o->material].name, who);
        if (o->shape == NS_SHAPE_MESH && o->triangle_count == 0)
            continue;
        ns_vrl_target_sphere(scene, o, out[n].sphere);
        out[n++].object = i;
    }
    *count = n;
    return NS_OK;
}

/* ---------------------------------------------------------------------------------------
 * Strata: the power each light sends through each target sphere (the mean of RGB).
 * ------------------------------------------------------------------------------------- */
static double solid_angle_of(const float *from, const float sphere[4])
{
    double d2 = 0;
    for (int k = 0; k < 3; k++)
        d2 += ((double)sphere[k] - from[k]) * ((double)sphere[k] - from[k]);
    double r2 = (double)sphere[3] * sphere[3];
    return d2 > r2 ? 2 * M_PI * (1 - sqrt(1 - r2 / d2)) : 4 * M_PI;
}

/* Estimates only steer the sampling; the shader's weights make the result unbiased for any
 * positive estimate. A sphere light counts as a point of intensity L pi R^2 (exact for a
 * Lambertian sphere seen from outside). Also steers render/vrl_method.c. */
double ns_vrl_light_power(const GpuLight *light, const float sphere[4])
{
    double mean = ((double)light->color[0] + light->color[1] + light->color[2]) / 3.0;
    double disk = M_PI * (double)sphere[3] * sphere[3];
    switch (light->info[0]) {
    case NS_GPU_LIGHT_DIRECTIONAL:
        return mean * disk;
    case NS_GPU_LIGHT_POINT:
        return mean * solid_angle_of(light->position, sphere);
    case NS_GPU_LIGHT_SPHERE: {
        double r = light->position[3];
        return mean * M_PI * r * r * solid_angle_of(light->position, sphere);
    }
    default: /* environment */
        return mean * 4 * M_PI * disk;
    }
}

typedef struct vrl_plan {
    GpuVrlStratum *strata; /* strata that got at least one path, in path order */
    uint32_t count;
} vrl_plan;

double ns_vrl_seed_offset(uint32_t seed)
{
    /* splitmix64 of the seed: one uniform number in [0, 1) for the systematic offset. */
    uint64_t z = (uint64_t)seed + 0x9e3779b97f4a7c15ull;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    z ^= z >> 31;
    return (double)(z >> 11) * (1.0 / 9007199254740992.0);
}

uint64_t ns_vrl_first_path_at(double cdf, uint32_t paths, double xi)
{
    double x = ceil(cdf * paths - xi);
    return x <= 0 ? 0 : x >= paths ? paths : (uint64_t)x;
}

int ns_vrl_stratify(const ns_gpu_scene *gs, const ns_vrl_target *targets, uint32_t target_count,
                    uint32_t paths, uint32_t seed, const char *who, ns_vrl_stratum **out,
                    uint32_t *count, ns_error *err)
{
    *out = NULL;
    *count = 0;
    uint64_t pairs = (uint64_t)gs->light_count * target_count;
    if (!pairs || !paths)
        return NS_OK;
    double *power = malloc(sizeof *power * pairs);
    if (!power)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "%s: %llu strata", who,
                       (unsigned long long)pairs);
    double total = 0;
    for (uint64_t k = 0; k < pairs; k++) {
        double p =
            ns_vrl_light_power(&gs->lights[k / target_count], targets[k % target_count].sphere);
        power[k] = p > 0 && isfinite(p) ? p : 0;
        total += power[k];
    }
    if (!(total > 0)) {
        free(power);
        return NS_OK;
    }
    /* Every stratum that gets a path gets a path of its own: at most min(pairs, paths). */
    ns_vrl_stratum *strata = calloc(pairs < paths ? pairs : paths, sizeof *strata);
    if (!strata) {
        free(power);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "%s: %llu strata", who,
                       (unsigned long long)pairs);
    }
    double xi = ns_vrl_seed_offset(seed), cdf = 0;
    uint32_t n = 0;
    for (uint64_t k = 0; k < pairs; k++) {
        if (power[k] <= 0)
            continue;
        double p = power[k] / total;
        uint64_t first = ns_vrl_first_path_at(cdf, paths, xi);
        cdf += p;
        uint64_t end = ns_vrl_first_path_at(cdf, paths, xi);
        if (end <= first)
            continue; /* no path this time: expected N p < 1, weight 1 / (N p) covers it */
        strata[n++] = (ns_vrl_stratum){.light = (uint32_t)(k / target_count),
                                       .target = (uint32_t)(k % target_count),
                                       .first_path = (uint32_t)first,
                                       .path_count = (uint32_t)(end - first),
                                       .p = p};
    }
    free(power);
    *out = strata;
    *count = n;
    return NS_OK;
}

static int plan_strata(const ns_gpu_scene *gs, const ns_vrl_target *targets, uint32_t target_count,
                       uint32_t paths, uint32_t seed, vrl_plan *plan, ns_error *err)
{
    memset(plan, 0, sizeof *plan);
    ns_vrl_stratum *strata = NULL;
    uint32_t count = 0;
    int status =
        ns_vrl_stratify(gs, targets, target_count, paths, seed, "vrl", &strata, &count, err);
    plan->strata = status || !count ? NULL : calloc(count, sizeof *plan->strata);
    if (!status && count && !plan->strata)
        status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl: %u strata", count);
    for (uint32_t i = 0; !status && i < count; i++) {
        const ns_vrl_stratum *st = &strata[i];
        GpuVrlStratum *s = &plan->strata[plan->count++];
        memcpy(s->target, targets[st->target].sphere, sizeof s->target);
        s->weight[0] = (float)(1.0 / (st->p * paths));
        s->ids[0] = st->first_path;
        s->ids[1] = st->light;
        s->ids[2] = targets[st->target].object;
        s->ids[3] = st->path_count; /* the stratified emission's n (common.glsl) */
    }
    free(strata);
    return status;
}

/* ---------------------------------------------------------------------------------------
 * The dispatch and the compaction.
 * ------------------------------------------------------------------------------------- */
enum { V_STRATA, V_SLOTS, V_COUNTERS, V_OWN };

static int compact_slots(const GpuVrl *slots, uint64_t slot_count, uint32_t stored,
                         ns_vrl_set *out, ns_error *err)
{
    out->vrls = malloc(sizeof *out->vrls * (stored ? stored : 1));
    if (!out->vrls)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl: %u VRLs", stored);
    uint32_t n = 0;
    for (uint64_t i = 0; i < slot_count; i++)
        if (slots[i].material != NS_NONE && n < stored)
            out->vrls[n++] = slots[i];
    out->count = n;
    if (n != stored)
        return ns_fail(err, NS_ERR_INTERNAL, "vrl: %u VRLs counted, %u written", stored, n);
    return NS_OK;
}

static int trace_paths(ns_context *ctx, gpu_buffer *scene_buffers, const vrl_plan *plan,
                       uint32_t paths, uint32_t chain, uint32_t seed, ns_vrl_set *out,
                       ns_error *err)
{
    uint64_t slot_count = (uint64_t)paths * chain;
    gpu_buffer own[V_OWN];
    memset(own, 0, sizeof own);
    gpu_buffer_desc descs[V_OWN] = {
        {.size = (uint64_t)plan->count * sizeof(GpuVrlStratum),
         .data = plan->strata,
         .data_size = (uint64_t)plan->count * sizeof(GpuVrlStratum),
         .label = "ns.vrl.strata"},
        {.size = slot_count * sizeof(GpuVrl),
         .uninitialized = 1,
         .host_reads = 1,
         .label = "ns.vrl.slots"},
        {.size = NS_VRL_COUNTER_COUNT * sizeof(uint32_t), .label = "ns.vrl.counters"},
    };
    gpu_pipeline *pipeline = NULL;
    int status = ns_pipeline(ctx, NS_PIPELINE_VRL, &pipeline, NULL, err);
    if (!status)
        status = gpu_buffers_create(&ctx->dev, own, descs, V_OWN, err);
    if (!status) {
        gpu_buffer *bound[NS_SCENE_BUFFER_COUNT + V_OWN];
        for (int i = 0; i < NS_SCENE_BUFFER_COUNT; i++)
            bound[i] = &scene_buffers[i];
        for (int i = 0; i < V_OWN; i++)
            bound[NS_SCENE_BUFFER_COUNT + i] = &own[i];
        GpuVrlPush push = {.path_count = paths,
                           .stratum_count = plan->count,
                           .seed = seed,
                           .chain = chain,
                           .budget = ctx->dev.loop_limited ? NS_LAVAPIPE_LOOP_BUDGET : 0};
        status = gpu_dispatch_many(
            &ctx->dev,
            &(gpu_dispatch_desc){.pipeline = pipeline,
                                 .buffers = bound,
                                 .buffer_count = NS_SCENE_BUFFER_COUNT + V_OWN,
                                 .groups = {(paths + NS_VRL_GROUP - 1) / NS_VRL_GROUP, 1, 1},
                                 .push = &push},
            err);
    }
    if (!status) {
        const uint32_t *c = own[V_COUNTERS].mapped;
        if (c[NS_VRL_COUNTER_LOOP_LIMIT])
            status =
                ns_fail(err, NS_ERR_LIMIT,
                        "vrl: %u light path(s) ran past lavapipe's loop budget (%u iterations)",
                        c[NS_VRL_COUNTER_LOOP_LIMIT], NS_LAVAPIPE_LOOP_BUDGET);
        else
            status = compact_slots(own[V_SLOTS].mapped, slot_count, c[NS_VRL_COUNTER_STORED], out, err);
    }
    for (int i = 0; i < V_OWN; i++)
        gpu_buffer_destroy(&ctx->dev, &own[i]);
    return status;
}

int ns_vrl_generate(ns_context *ctx, const ns_scene *scene, const ns_gpu_scene *gs,
                    gpu_buffer *scene_buffers, uint32_t paths, uint32_t chain, uint32_t seed,
                    ns_vrl_set *out, ns_error *err)
{
    memset(out, 0, sizeof *out);
    if (chain < 1 || chain > NS_VRL_MAX_CHAIN)
        return ns_fail(err, NS_ERR_INTERNAL, "vrl: chain %u must be in [1, %u]", chain,
                       NS_VRL_MAX_CHAIN);
    if (paths > NS_MAX_VRLS)
        return ns_fail(err, NS_ERR_LIMIT, "render.vrls: %u light paths, at most %u", paths,
                       NS_MAX_VRLS);
    out->paths = paths;
    ns_vrl_target *targets =
        malloc(sizeof *targets * (scene->object_count ? scene->object_count : 1));
    uint32_t target_count = 0;
    vrl_plan plan = {0};
    int status =
        targets ? ns_vrl_targets(scene, "the VRL stage", targets, &target_count, err)
                : ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "vrl: %u targets", scene->object_count);
    if (!status && paths && target_count)
        status = plan_strata(gs, targets, target_count, paths, seed, &plan, err);
    if (!status && plan.count)
        status = trace_paths(ctx, scene_buffers, &plan, paths, chain, seed, out, err);
    free(targets);
    free(plan.strata);
    if (status)
        ns_vrl_set_free(out);
    return status;
}

void ns_vrl_set_free(ns_vrl_set *set)
{
    free(set->vrls);
    free(set->ends);
    memset(set, 0, sizeof *set);
}
