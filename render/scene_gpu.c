/* scene_gpu.c — a validated ns_scene in the shaders' layout (shaders/shared.h): camera
 * frame, primitives in BVH order followed by the planes, materials, lights; and the last BVH
 * kept in the context for the next render of the same geometry (a sweep of materials,
 * lights or cameras over one scene builds it once); and the scene buffers as bytes, which the
 * camera pass and the light's sources kept in the context are compared by. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bvh.h"
#include "internal.h"

static void normalize3(float v[3])
{
    double n = sqrt((double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2]);
    for (int k = 0; k < 3; k++)
        v[k] = (float)(v[k] / n);
}

/* A unit normal in 32 bits, octahedral (Cigolle et al. 2014, "A Survey of Efficient
 * Representations for Independent Unit Vectors"), as GLSL's packSnorm2x16 lays it out (x in
 * the low half); trace.glsl's decode_normal reads it back, within about 1e-4 rad. Stored in
 * the w of a triangle's vertex, which nothing else uses, so smooth meshes need no buffer of
 * their own. The bits go in by memcpy: they are not a float's value. */
static void store_normal(float *slot, const float n[3])
{
    double ax = fabs(n[0]) + fabs(n[1]) + fabs(n[2]);
    double x = n[0] / ax, y = n[1] / ax;
    if (n[2] < 0) {
        double fx = (1.0 - fabs(y)) * (x >= 0 ? 1.0 : -1.0);
        double fy = (1.0 - fabs(x)) * (y >= 0 ? 1.0 : -1.0);
        x = fx;
        y = fy;
    }
    int16_t qx = (int16_t)lround(fmax(-1.0, fmin(1.0, x)) * 32767.0);
    int16_t qy = (int16_t)lround(fmax(-1.0, fmin(1.0, y)) * 32767.0);
    uint32_t bits = (uint32_t)(uint16_t)qx | (uint32_t)(uint16_t)qy << 16;
    memcpy(slot, &bits, sizeof bits);
}

static void cross3(const float a[3], const float b[3], float out[3])
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

static void set4(float out[4], const float v[3], float w)
{
    out[0] = v[0];
    out[1] = v[1];
    out[2] = v[2];
    out[3] = w;
}

/* Pinhole frame: fov is horizontal, so tan(vertical / 2) = tan(horizontal / 2) * h / w. */
static void camera_params(const ns_camera *c, GpuParams *p)
{
    float forward[3] = {c->look_at[0] - c->position[0], c->look_at[1] - c->position[1],
                        c->look_at[2] - c->position[2]};
    normalize3(forward);
    float right[3], up[3];
    cross3(forward, c->up, right);
    normalize3(right);
    cross3(right, forward, up);
    double tan_x = tan(c->fov_deg * M_PI / 360.0);
    double tan_y = tan_x * (double)c->height / (double)c->width;
    set4(p->cam_position, c->position, (float)tan_x);
    set4(p->cam_right, right, (float)tan_y);
    set4(p->cam_up, up, 0.0f);
    set4(p->cam_forward, forward, 0.0f);
}

/* The flag bits every primitive of material m carries: shadow rays cross the boundary of an
 * index-matched medium (with its Beer-Lambert factor), single scattering's cross a
 * refracting one too (common.glsl, SHADOW_THROUGH_REFRACTING), and they stop at diffuse
 * surfaces, so the shaders' any-hit query (trace.glsl's trace_shadow) must know which is
 * which. */
static uint32_t material_flags(const ns_scene *s, uint32_t m)
{
    const ns_material *mat = &s->materials[m];
    if (mat->type != NS_MATERIAL_MEDIUM)
        return 0u;
    return mat->ior == 1.0f ? NS_PRIM_SHADOW_PASSES : NS_PRIM_REFRACTS;
}

static GpuPrim object_prim(const ns_scene *s, const ns_object *o, uint32_t index)
{
    GpuPrim p;
    memset(&p, 0, sizeof p);
    p.info[1] = o->material;
    p.info[2] = index;
    p.info[3] = material_flags(s, o->material);
    switch (o->shape) {
    case NS_SHAPE_SPHERE:
        p.info[0] = NS_PRIM_SPHERE;
        set4(p.a, o->center, o->radius);
        break;
    case NS_SHAPE_BOX:
        p.info[0] = NS_PRIM_BOX;
        set4(p.a, o->min, 0.0f);
        set4(p.b, o->max, 0.0f);
        break;
    default: /* plane; meshes are expanded by the caller */
        p.info[0] = NS_PRIM_PLANE;
        set4(p.a, o->point, 0.0f);
        set4(p.b, o->normal, 0.0f);
        normalize3(p.b);
        break;
    }
    return p;
}

/* =======================================================================================
 * The kept BVH (internal.h, ns_bvh_keep).
 *
 * The builder reads the BVH primitives' kind and numbers (sphere centre and radius, box
 * corners, triangle vertices) in scene order, nothing else (not their materials, not their
 * objects), and only reorders them: prims[i] = input[order[i]]. So when a scene's primitives
 * equal the kept ones in kind and numbers, bit for bit and position for position, the kept
 * nodes and order are exactly what a build would give; the primitives are taken from the new
 * scene in that order, so they carry its materials and objects. Planes never enter the BVH
 * and are converted every time.
 * ===================================================================================== */
static int same_geometry(const GpuPrim *a, const GpuPrim *b)
{
    return a->info[0] == b->info[0] && memcmp(a->a, b->a, sizeof a->a) == 0 &&
           memcmp(a->b, b->b, sizeof a->b) == 0 && memcmp(a->c, b->c, sizeof a->c) == 0;
}

static int keep_matches(const ns_bvh_keep *keep, const GpuPrim *input, uint32_t count)
{
    if (!keep || !keep->nodes || keep->count != count || count == 0)
        return 0;
    for (uint32_t i = 0; i < count; i++)
        if (!same_geometry(&keep->prims[i], &input[keep->order[i]]))
            return 0;
    return 1;
}

void ns_bvh_keep_free(ns_bvh_keep *keep)
{
    free(keep->nodes);
    free(keep->prims);
    free(keep->order);
    memset(keep, 0, sizeof *keep);
}

/* Keeps a copy of bvh in place of what keep held, when it fits the bound (else keep stays as
 * it was: it may still serve the render after next). Out of memory keeps nothing. */
static void keep_bvh(ns_bvh_keep *keep, const ns_bvh *bvh)
{
    uint64_t bytes = (uint64_t)bvh->node_count * sizeof(GpuNode) +
                     (uint64_t)bvh->prim_count * (sizeof(GpuPrim) + sizeof(uint32_t));
    if (!bvh->prim_count || bytes > NS_BVH_KEEP_BYTES_MAX)
        return;
    ns_bvh_keep_free(keep);
    keep->nodes = malloc(sizeof *keep->nodes * bvh->node_count);
    keep->prims = malloc(sizeof *keep->prims * bvh->prim_count);
    keep->order = malloc(sizeof *keep->order * bvh->prim_count);
    if (!keep->nodes || !keep->prims || !keep->order) {
        ns_bvh_keep_free(keep);
        return;
    }
    memcpy(keep->nodes, bvh->nodes, sizeof *keep->nodes * bvh->node_count);
    memcpy(keep->prims, bvh->prims, sizeof *keep->prims * bvh->prim_count);
    memcpy(keep->order, bvh->order, sizeof *keep->order * bvh->prim_count);
    keep->node_count = bvh->node_count;
    keep->count = bvh->prim_count;
}

/* The BVH of input[0..n) from keep: nodes copied, primitives in the kept order. */
static int reuse_bvh(const ns_bvh_keep *keep, const GpuPrim *input, uint32_t n, ns_bvh *out,
                     ns_error *err)
{
    memset(out, 0, sizeof *out);
    out->nodes = malloc(sizeof *out->nodes * keep->node_count);
    out->prims = malloc(sizeof *out->prims * n);
    if (!out->nodes || !out->prims) {
        ns_bvh_free(out);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "scene: BVH of %u primitives", n);
    }
    memcpy(out->nodes, keep->nodes, sizeof *out->nodes * keep->node_count);
    for (uint32_t i = 0; i < n; i++)
        out->prims[i] = input[keep->order[i]];
    out->node_count = keep->node_count;
    out->prim_count = n;
    return NS_OK;
}

/* =======================================================================================
 * Conversion
 * ===================================================================================== */
static int convert_geometry(const ns_scene *s, ns_bvh_keep *keep, ns_gpu_scene *gs, int *reused,
                            ns_error *err)
{
    uint64_t bvh_count = 0, plane_count = 0;
    for (uint32_t i = 0; i < s->object_count; i++) {
        const ns_object *o = &s->objects[i];
        if (o->shape == NS_SHAPE_PLANE)
            plane_count++;
        else
            bvh_count += o->shape == NS_SHAPE_MESH ? o->triangle_count : 1;
        if (s->materials[o->material].type == NS_MATERIAL_MEDIUM)
            gs->has_media = 1;
    }
    if (bvh_count + plane_count > (uint64_t)NS_MAX_TRIANGLES + NS_MAX_OBJECTS)
        return ns_fail(err, NS_ERR_LIMIT, "scene: %llu primitives",
                       (unsigned long long)(bvh_count + plane_count));
    GpuPrim *input = malloc(sizeof *input * (bvh_count ? bvh_count : 1));
    GpuPrim *planes = malloc(sizeof *planes * (plane_count ? plane_count : 1));
    gs->plane_count = (uint32_t)plane_count;
    if (!input || !planes) {
        free(input);
        free(planes);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "scene: %llu primitives",
                       (unsigned long long)bvh_count);
    }
    uint32_t n = 0, np = 0;
    for (uint32_t i = 0; i < s->object_count; i++) {
        const ns_object *o = &s->objects[i];
        if (o->shape == NS_SHAPE_PLANE) {
            planes[np++] = object_prim(s, o, i);
        } else if (o->shape == NS_SHAPE_MESH) {
            for (uint32_t t = 0; t < o->triangle_count; t++) {
                const ns_triangle *tri = &s->triangles[o->first_triangle + t];
                GpuPrim *p = &input[n++];
                memset(p, 0, sizeof *p);
                p->info[0] = NS_PRIM_TRIANGLE;
                p->info[1] = o->material;
                p->info[2] = i;
                p->info[3] = material_flags(s, o->material);
                set4(p->a, tri->v[0], 0.0f);
                set4(p->b, tri->v[1], 0.0f);
                set4(p->c, tri->v[2], 0.0f);
                if (ns_triangle_is_smooth(tri)) {
                    p->info[3] |= NS_PRIM_SMOOTH;
                    store_normal(&p->a[3], tri->n[0]);
                    store_normal(&p->b[3], tri->n[1]);
                    store_normal(&p->c[3], tri->n[2]);
                }
            }
        } else {
            input[n++] = object_prim(s, o, i);
        }
    }
    ns_bvh bvh;
    int status;
    if (keep_matches(keep, input, n)) {
        status = reuse_bvh(keep, input, n, &bvh, err);
        *reused = !status;
    } else {
        status = ns_bvh_build(input, n, &bvh, err);
        if (!status && keep)
            keep_bvh(keep, &bvh);
    }
    free(input);
    if (status) {
        free(planes);
        return status;
    }
    gs->prims = malloc(sizeof *gs->prims * ((size_t)n + np + 1));
    if (!gs->prims) {
        free(planes);
        ns_bvh_free(&bvh);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "scene: %u primitives", n + np);
    }
    if (n)
        memcpy(gs->prims, bvh.prims, sizeof *gs->prims * n);
    if (np)
        memcpy(gs->prims + n, planes, sizeof *planes * np);
    free(planes);
    gs->bvh_prim_count = n;
    gs->nodes = bvh.nodes; /* taken over from the BVH */
    gs->node_count = bvh.node_count;
    bvh.nodes = NULL;
    ns_bvh_free(&bvh);
    return NS_OK;
}

static int convert_materials_and_lights(const ns_scene *s, ns_gpu_scene *gs, ns_error *err)
{
    gs->materials = calloc(s->material_count + 1, sizeof *gs->materials);
    gs->lights = calloc(s->light_count + 1, sizeof *gs->lights);
    if (!gs->materials || !gs->lights)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "scene: materials and lights");
    for (uint32_t i = 0; i < s->material_count; i++) {
        const ns_material *m = &s->materials[i];
        GpuMaterial *g = &gs->materials[i];
        if (m->type == NS_MATERIAL_DIFFUSE) {
            set4(g->reflectance, m->reflectance, 0.0f);
            continue;
        }
        g->reflectance[3] = 1.0f;
        for (int k = 0; k < 3; k++) {
            g->sigma_t[k] = m->sigma_s[k] + m->sigma_a[k];
            g->sigma_s[k] = m->sigma_s[k];
        }
        g->sigma_t[3] = m->ior;
        g->sigma_s[3] = m->g;
    }
    gs->material_count = s->material_count;
    float environment[3] = {0, 0, 0};
    for (uint32_t i = 0; i < s->light_count; i++) {
        const ns_light *l = &s->lights[i];
        GpuLight *g = &gs->lights[i];
        g->info[0] = (uint32_t)l->type;
        set4(g->position, l->position, l->type == NS_LIGHT_SPHERE ? l->radius : 0.0f);
        set4(g->direction, l->direction, 0.0f);
        if (l->type == NS_LIGHT_DIRECTIONAL)
            normalize3(g->direction);
        set4(g->color, l->color, 0.0f);
        if (l->type == NS_LIGHT_ENVIRONMENT)
            for (int k = 0; k < 3; k++)
                environment[k] += l->color[k];
    }
    gs->light_count = s->light_count;
    set4(gs->params.environment, environment, 0.0f);
    return NS_OK;
}

int ns_gpu_scene_build(const ns_scene *s, ns_gpu_scene *gs, ns_error *err)
{
    return ns_gpu_scene_build_reusing(s, NULL, gs, NULL, err);
}

int ns_gpu_scene_build_reusing(const ns_scene *s, ns_bvh_keep *keep, ns_gpu_scene *gs, int *reused,
                               ns_error *err)
{
    int reused_here = 0;
    if (!reused)
        reused = &reused_here;
    *reused = 0;
    memset(gs, 0, sizeof *gs);
    int status = convert_geometry(s, keep, gs, reused, err);
    if (!status)
        status = convert_materials_and_lights(s, gs, err);
    if (status)
        return status;
    GpuParams *p = &gs->params;
    camera_params(&s->camera, p);
    p->image[0] = s->camera.width;
    p->image[1] = s->camera.height;
    p->image[2] = s->render.spp;
    p->image[3] = s->render.seed;
    ns_render_settings resolved = ns_render_settings_resolve(s->render);
    p->surface[0] = resolved.light_samples;
    float adaptive = ns_adaptive_spp_used(&resolved);
    memcpy(&p->surface[1], &adaptive, sizeof p->surface[1]);
    /* single.c's form of single scattering: one that takes a box's faces one by one, where
     * a box of a refracting medium scatters. */
    for (uint32_t i = 0; i < s->object_count; i++) {
        const ns_object *o = &s->objects[i];
        const ns_material *m = &s->materials[o->material];
        int scatters = m->sigma_s[0] > 0.0f || m->sigma_s[1] > 0.0f || m->sigma_s[2] > 0.0f;
        if (o->shape == NS_SHAPE_BOX && m->type == NS_MATERIAL_MEDIUM && m->ior != 1.0f && scatters)
            p->surface[2] = 1;
    }
    p->counts[0] = s->render.max_depth;
    p->counts[1] = gs->light_count;
    p->counts[2] = 0; /* segment capacity: set by the render job */
    p->counts[3] = gs->node_count;
    p->prims[0] = gs->bvh_prim_count;
    p->prims[1] = gs->plane_count;
    p->prims[2] = gs->material_count;
    return NS_OK;
}

void ns_gpu_scene_free(ns_gpu_scene *gs)
{
    free(gs->nodes);
    free(gs->prims);
    free(gs->materials);
    free(gs->lights);
    memset(gs, 0, sizeof *gs);
}

static gpu_buffer_desc scene_desc(const void *data, uint64_t size, gpu_buffer_kind kind,
                                  const char *label)
{
    return (gpu_buffer_desc){
        .size = size, .kind = kind, .data = data, .data_size = size, .label = label};
}

void ns_gpu_scene_buffer_descs(const ns_gpu_scene *gs, gpu_buffer_desc descs[NS_SCENE_BUFFER_COUNT])
{
    descs[0] = scene_desc(&gs->params, sizeof gs->params, GPU_BUFFER_UNIFORM, "ns.scene.params");
    descs[1] = scene_desc(gs->nodes, (uint64_t)gs->node_count * sizeof(GpuNode),
                          GPU_BUFFER_STORAGE, "ns.scene.bvh_nodes");
    descs[2] = scene_desc(gs->prims, (uint64_t)(gs->bvh_prim_count + gs->plane_count) * sizeof(GpuPrim),
                          GPU_BUFFER_STORAGE, "ns.scene.prims");
    descs[3] = scene_desc(gs->materials, (uint64_t)gs->material_count * sizeof(GpuMaterial),
                          GPU_BUFFER_STORAGE, "ns.scene.materials");
    descs[4] = scene_desc(gs->lights, (uint64_t)gs->light_count * sizeof(GpuLight),
                          GPU_BUFFER_STORAGE, "ns.scene.lights");
}

/* ---------------------------------------------------------------------------------------
 * Signature (internal.h): what camera_keep.c and source_keep.c compare.
 * ------------------------------------------------------------------------------------- */
static void append(unsigned char **at, const void *data, size_t bytes)
{
    if (bytes)
        memcpy(*at, data, bytes);
    *at += bytes;
}

/* Its cost is a copy and a compare of the scene buffers, 96 bytes a triangle (the bench
 * bunny: 6.7 MB, a few milliseconds, against a render of seconds); nodes and primitives are
 * also in the kept BVH, but that one compares geometry alone, without the materials'
 * indices, so each keep holds its own copy rather than share it. */
unsigned char *ns_scene_signature(const ns_gpu_scene *gs, const GpuParams *params, int clear_sigma_s,
                                  const void *prefix, size_t prefix_bytes, size_t *bytes)
{
    size_t prims = gs->bvh_prim_count + gs->plane_count;
    size_t counts[4] = {gs->node_count, prims, gs->material_count, gs->light_count};
    size_t size = prefix_bytes + sizeof counts + sizeof *params + counts[0] * sizeof(GpuNode) +
                  counts[1] * sizeof(GpuPrim) + counts[2] * sizeof(GpuMaterial) +
                  counts[3] * sizeof(GpuLight);
    unsigned char *sig = malloc(size), *at = sig;
    if (!sig)
        return NULL; /* no reuse: the stage runs */
    append(&at, prefix, prefix_bytes);
    append(&at, counts, sizeof counts);
    append(&at, params, sizeof *params);
    append(&at, gs->nodes, counts[0] * sizeof(GpuNode));
    append(&at, gs->prims, counts[1] * sizeof(GpuPrim));
    for (size_t i = 0; i < counts[2]; i++) {
        GpuMaterial m = gs->materials[i];
        if (clear_sigma_s)
            memset(m.sigma_s, 0, sizeof m.sigma_s);
        append(&at, &m, sizeof m);
    }
    append(&at, gs->lights, counts[3] * sizeof(GpuLight));
    *bytes = size;
    return sig;
}
