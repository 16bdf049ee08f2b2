/* scene_check.c — the renderer's own structural check of a scene. The parser validates the
 * JSON, but ns_render is a library entry point: it never trusts its caller with indices,
 * counts or non-finite numbers that would send the GPU out of bounds or poison an image. */
#include <math.h>
#include <stdio.h>

#include "internal.h"

static int finite3(const float v[3])
{
    return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

static int nonnegative3(const float v[3])
{
    return v[0] >= 0.0f && v[1] >= 0.0f && v[2] >= 0.0f;
}

static double length3(const float v[3])
{
    return sqrt((double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2]);
}

#define BAD(...) ns_fail(err, NS_ERR_INVALID_ARGUMENT, __VA_ARGS__)

static int check_camera(const ns_camera *c, ns_error *err)
{
    if (!finite3(c->position) || !finite3(c->look_at) || !finite3(c->up))
        return BAD("camera: position, look_at and up must be finite");
    float forward[3] = {c->look_at[0] - c->position[0], c->look_at[1] - c->position[1],
                        c->look_at[2] - c->position[2]};
    double f = length3(forward), u = length3(c->up);
    if (!(f > 0.0))
        return BAD("camera.look_at: equals camera.position");
    if (!(u > 0.0))
        return BAD("camera.up: zero vector");
    double dot = (forward[0] * c->up[0] + forward[1] * c->up[1] + forward[2] * c->up[2]) / (f * u);
    if (fabs(dot) > 0.999999)
        return BAD("camera.up: parallel to the viewing direction");
    if (!(c->fov_deg > 0.0f && c->fov_deg < 180.0f))
        return BAD("camera.fov: %g outside (0, 180)", (double)c->fov_deg);
    if (c->width == 0 || c->height == 0 || c->width > NS_MAX_IMAGE_SIDE ||
        c->height > NS_MAX_IMAGE_SIDE)
        return BAD("camera.width/height: %ux%u outside 1..%d", c->width, c->height,
                   NS_MAX_IMAGE_SIDE);
    if ((uint64_t)c->width * c->height > NS_MAX_PIXELS)
        return BAD("camera: %ux%u is more than %u pixels", c->width, c->height, NS_MAX_PIXELS);
    return NS_OK;
}

static int check_material(const ns_material *m, uint32_t i, ns_error *err)
{
    if (m->type == NS_MATERIAL_DIFFUSE) {
        if (!finite3(m->reflectance) || !nonnegative3(m->reflectance) || m->reflectance[0] > 1.0f ||
            m->reflectance[1] > 1.0f || m->reflectance[2] > 1.0f)
            return BAD("materials[%u].reflectance: must be finite and in [0, 1]", i);
        return NS_OK;
    }
    if (m->type != NS_MATERIAL_MEDIUM)
        return BAD("materials[%u].type: unknown type %d", i, (int)m->type);
    if (!finite3(m->sigma_s) || !nonnegative3(m->sigma_s))
        return BAD("materials[%u].sigma_s: must be finite and >= 0", i);
    if (!finite3(m->sigma_a) || !nonnegative3(m->sigma_a))
        return BAD("materials[%u].sigma_a: must be finite and >= 0", i);
    if (!(m->g > -1.0f && m->g < 1.0f))
        return BAD("materials[%u].g: %g outside (-1, 1)", i, (double)m->g);
    if (!(m->ior >= 1.0f) || !isfinite(m->ior))
        return BAD("materials[%u].ior: %g must be finite and >= 1", i, (double)m->ior);
    return NS_OK;
}

static int check_object(const ns_scene *s, const ns_object *o, uint32_t i, ns_error *err)
{
    if (o->material >= s->material_count)
        return BAD("objects[%u].material: %u out of range (%u materials)", i, o->material,
                   s->material_count);
    switch (o->shape) {
    case NS_SHAPE_SPHERE:
        if (!finite3(o->center))
            return BAD("objects[%u].center: must be finite", i);
        if (!(o->radius > 0.0f) || !isfinite(o->radius))
            return BAD("objects[%u].radius: %g must be finite and > 0", i, (double)o->radius);
        return NS_OK;
    case NS_SHAPE_PLANE:
        if (!finite3(o->point))
            return BAD("objects[%u].point: must be finite", i);
        if (!finite3(o->normal) || !(length3(o->normal) > 1e-12))
            return BAD("objects[%u].normal: must be finite and non-zero", i);
        return NS_OK;
    case NS_SHAPE_BOX:
        if (!finite3(o->min) || !finite3(o->max))
            return BAD("objects[%u].min/max: must be finite", i);
        for (int k = 0; k < 3; k++)
            if (!(o->min[k] < o->max[k]))
                return BAD("objects[%u].min: must be below max on every axis", i);
        return NS_OK;
    case NS_SHAPE_MESH:
        if (o->triangle_count == 0 || o->first_triangle > s->triangle_count ||
            o->triangle_count > s->triangle_count - o->first_triangle)
            return BAD("objects[%u]: triangles [%u, +%u) outside the scene's %u triangles", i,
                       o->first_triangle, o->triangle_count, s->triangle_count);
        return NS_OK;
    }
    return BAD("objects[%u].shape: unknown shape %d", i, (int)o->shape);
}

static int check_light(const ns_light *l, uint32_t i, ns_error *err)
{
    if (!finite3(l->color) || !nonnegative3(l->color))
        return BAD("lights[%u]: irradiance/intensity/radiance must be finite and >= 0", i);
    switch (l->type) {
    case NS_LIGHT_DIRECTIONAL:
        if (!finite3(l->direction) || !(length3(l->direction) > 1e-12))
            return BAD("lights[%u].direction: must be finite and non-zero", i);
        return NS_OK;
    case NS_LIGHT_POINT:
        return finite3(l->position) ? NS_OK : BAD("lights[%u].position: must be finite", i);
    case NS_LIGHT_SPHERE:
        if (!finite3(l->position))
            return BAD("lights[%u].center: must be finite", i);
        if (!(l->radius > 0.0f) || !isfinite(l->radius))
            return BAD("lights[%u].radius: %g must be finite and > 0", i, (double)l->radius);
        return NS_OK;
    case NS_LIGHT_ENVIRONMENT:
        return NS_OK;
    }
    return BAD("lights[%u].type: unknown type %d", i, (int)l->type);
}

static int check_render(const ns_render_settings *r, ns_error *err)
{
    if (r->spp < 1 || r->spp > NS_MAX_SPP)
        return BAD("render.spp: %u outside 1..%d", r->spp, NS_MAX_SPP);
    if (r->max_depth > NS_MAX_DEPTH)
        return BAD("render.max_depth: %u over %d", r->max_depth, NS_MAX_DEPTH);
    if (r->light_samples < 1 || r->light_samples > NS_MAX_LIGHT_SAMPLES)
        return BAD("render.light_samples: %u outside 1..%u", r->light_samples,
                   NS_MAX_LIGHT_SAMPLES);
    if (!(r->adaptive_spp >= 0.0f && r->adaptive_spp <= (float)NS_MAX_ADAPTIVE_SPP))
        return BAD("render.adaptive_spp: %g outside 0..%u", (double)r->adaptive_spp,
                   NS_MAX_ADAPTIVE_SPP);
    /* Only pt has no use for it; elsewhere asking for samples that cannot be placed would be
     * silently meaningless. */
    if (ns_adaptive_spp_refused(r->method, r->spp, r->adaptive_spp))
        return BAD("render.adaptive_spp: needs render.spp >= 2 (the added samples go where "
                   "the first ones spread), got spp %u",
                   r->spp);
    if ((unsigned)r->method > NS_METHOD_PT)
        return BAD("render.method: unknown method %d", (int)r->method);
    if (r->deadline_ms > NS_MAX_DEADLINE_MS)
        return BAD("render.deadline_ms: %u over %u", r->deadline_ms, NS_MAX_DEADLINE_MS);
    if (r->components == 0)
        return BAD("render.components: none requested");
    if (r->components & ~(uint32_t)(NS_COMPONENT_SURFACE | NS_COMPONENT_SINGLE |
                                    NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE))
        return BAD("render.components: unknown component bits 0x%x", r->components);
    if ((unsigned)r->tables > NS_TABLES_AUTO)
        return BAD("render.tables: unknown value %d", (int)r->tables);
    if (r->tables == NS_TABLES_INTERPOLATED && r->method != NS_METHOD_NN)
        return BAD("render.tables: interpolated tables apply to method nn only");
    if (r->method != NS_METHOD_PT) {
        uint32_t gathered = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE;
        if ((r->components & gathered) && (r->vrls < 1 || r->vrls > NS_MAX_VRLS))
            return BAD("render.vrls: %u outside 1..%u", r->vrls, NS_MAX_VRLS);
        if ((r->components & gathered) && (r->gather_tile < 1 || r->gather_tile > NS_MAX_GATHER_TILE))
            return BAD("render.gather_tile: %u outside 1..%u", r->gather_tile, NS_MAX_GATHER_TILE);
        if (r->gather_levels > NS_MAX_GATHER_LEVELS)
            return BAD("render.gather_levels: %u over %u", r->gather_levels, NS_MAX_GATHER_LEVELS);
        if (!(r->gather_tolerance >= 0.0f && r->gather_tolerance <= 1.0f))
            return BAD("render.gather_tolerance: %g outside 0..1", (double)r->gather_tolerance);
        if (r->gather_camera_samples > NS_MAX_SPP)
            return BAD("render.gather_camera_samples: %u over %u", r->gather_camera_samples, NS_MAX_SPP);
        if ((r->components & NS_COMPONENT_SINGLE) &&
            (r->single_samples < 1 || r->single_samples > NS_MAX_SINGLE_SAMPLES))
            return BAD("render.single_samples: %u outside 1..%u", r->single_samples,
                       NS_MAX_SINGLE_SAMPLES);
        if (r->single_levels > NS_MAX_GATHER_LEVELS)
            return BAD("render.single_levels: %u over %u", r->single_levels, NS_MAX_GATHER_LEVELS);
        if (!(r->single_tolerance >= 0.0f && r->single_tolerance <= 1.0f))
            return BAD("render.single_tolerance: %g outside 0..1", (double)r->single_tolerance);
        if ((unsigned)r->vrl_beams > NS_VRL_BEAMS_BOUNDED)
            return BAD("render.vrl_beams: %d is not a beam model", (int)r->vrl_beams);
        if (r->vrl_beams == NS_VRL_BEAMS_BOUNDED && !ns_method_uses_tables(r->method))
            return BAD("render.vrl_beams: bounded beams apply to methods nn and table");
        if ((unsigned)r->boundary > NS_BOUNDARY_WALKS)
            return BAD("render.boundary: %d is not a boundary model", (int)r->boundary);
        if (r->boundary != NS_BOUNDARY_OFF && !ns_method_uses_tables(r->method))
            return BAD("render.boundary: the boundary correction applies to methods nn and table");
        if ((unsigned)r->accumulation > NS_ACCUMULATION_PAPER)
            return BAD("render.accumulation: unknown value %d", (int)r->accumulation);
        if (!(r->cull_solid_angle >= 0.0f && r->cull_solid_angle <= 12.57f))
            return BAD("render.cull_solid_angle: %g outside 0..4pi", (double)r->cull_solid_angle);
    }
    return NS_OK;
}

int ns_scene_validate(const ns_scene *s, ns_error *err)
{
    if (!s)
        return BAD("scene: NULL");
    int status = check_camera(&s->camera, err);
    /* Settings left 0 are checked as the defaults ns_render renders them with. */
    ns_render_settings render = ns_render_settings_resolve(s->render);
    if (!status)
        status = check_render(&render, err);
    if (status)
        return status;
    if (s->material_count > NS_MAX_MATERIALS || (s->material_count && !s->materials))
        return BAD("materials: %u given (at most %d, array required)", s->material_count,
                   NS_MAX_MATERIALS);
    if (s->object_count > NS_MAX_OBJECTS || (s->object_count && !s->objects))
        return BAD("objects: %u given (at most %d, array required)", s->object_count,
                   NS_MAX_OBJECTS);
    if (s->light_count > NS_MAX_LIGHTS || (s->light_count && !s->lights))
        return BAD("lights: %u given (at most %d, array required)", s->light_count, NS_MAX_LIGHTS);
    if (s->triangle_count > NS_MAX_TRIANGLES || (s->triangle_count && !s->triangles))
        return BAD("triangles: %u given (at most %u, array required)", s->triangle_count,
                   NS_MAX_TRIANGLES);
    for (uint32_t i = 0; i < s->material_count && !status; i++)
        status = check_material(&s->materials[i], i, err);
    for (uint32_t i = 0; i < s->object_count && !status; i++)
        status = check_object(s, &s->objects[i], i, err);
    for (uint32_t i = 0; i < s->light_count && !status; i++)
        status = check_light(&s->lights[i], i, err);
    for (uint32_t i = 0; i < s->triangle_count && !status; i++) {
        const ns_triangle *t = &s->triangles[i];
        for (int v = 0; v < 3 && !status; v++)
            if (!finite3(t->v[v]))
                status = BAD("triangles[%u].v[%d]: must be finite", i, v);
        if (!status && ns_triangle_is_smooth(t))
            for (int v = 0; v < 3 && !status; v++) {
                double len = sqrt((double)t->n[v][0] * t->n[v][0] + (double)t->n[v][1] * t->n[v][1] +
                                  (double)t->n[v][2] * t->n[v][2]);
                if (!finite3(t->n[v]) || !(fabs(len - 1.0) <= 1e-3))
                    status = BAD("triangles[%u].n[%d]: must be a unit vector, or all three "
                                 "normals zero (a flat triangle)",
                                 i, v);
            }
    }
    return status;
}
