/* gpu_loop_cut.c — the camera pass never returns a silently wrong image when lavapipe cuts
 * an invocation's loops short (65535 iterations in all, shared.h). 4000 planes that are never
 * a ray's nearest hit (below the floor, parallel to it: every ray that goes down meets the
 * floor first, and the sun's shadow rays go up) are still tested by every ray, and a
 * refracting sphere multiplies the rays per pixel: the iterations lavapipe counts run far past
 * its limit while the pass's own count stays within its budget. Either the render is
 * refused with NS_ERR_LIMIT (lavapipe), or its image equals the one without the planes (a
 * device without the limit, such as NVIDIA's driver: there the image is checked). The planes
 * once stood behind the camera; planes are two-sided, and the rays that the sphere sends back
 * met them, which only a device without the limit showed. */
#include "gpu_util.h"

#define PLANES 4000

static ns_object objects[PLANES + 2];

static ns_scene build(ns_material mats[2], ns_light *sun, uint32_t planes)
{
    ns_scene s = base_scene(8, 8, 40);
    s.render.spp = 1;
    set3(s.camera.position, 0, 0.5, 4);
    set3(s.camera.look_at, 0, 0, 0);
    mats[0] = diffuse(0.5, 0.5, 0.5);
    mats[1] = medium((double[3]){0.2, 0.2, 0.2}, (double[3]){0.1, 0.1, 0.1}, 1.5);
    objects[0] = plane(-1, 0);
    objects[1] = sphere(0, 0, 0, 1, 1);
    for (uint32_t i = 0; i < planes; i++) {
        ns_object *o = &objects[2 + i];
        memset(o, 0, sizeof *o);
        o->shape = NS_SHAPE_PLANE;
        set3(o->point, 0, -10 - 0.01 * i, 0);
        set3(o->normal, 0, 1, 0);
        o->material = 0;
    }
    *sun = light(NS_LIGHT_DIRECTIONAL, 2, 2, 2);
    set3(sun->direction, 0, -1, 0);
    scene_lists(&s, mats, 2, objects, 2 + planes, sun, 1);
    return s;
}

/* Renders the scene with `planes` planes; 1 when it was refused with NS_ERR_LIMIT, else
 * checks that its image equals `want` and returns 0. */
static int render_with_planes(uint32_t planes, const ns_image *want)
{
    ns_material mats[2];
    ns_light sun;
    ns_scene heavy = build(mats, &sun, planes);
    ns_image got = {0};
    ns_error err = {0};
    int status = ns_render(test_context(), &heavy, &got, NULL, &err);
    printf("with %u planes: %s (%s)\n", planes, ns_status_name(status), err.message);
    CHECK(status == NS_OK || status == NS_ERR_LIMIT);
    if (status == NS_OK) {
        double worst = 0;
        for (size_t i = 0; i < 8 * 8 * 3; i++)
            worst = fmax(worst, fabs(got.rgb[i] - want->rgb[i]));
        printf("  worst difference from the image without the planes: %g\n", worst);
        CHECK(worst < 1e-5);
    }
    ns_image_free(&got);
    return status == NS_ERR_LIMIT;
}

static void test_cut_is_never_silent(void)
{
    ns_material mats[2];
    ns_light sun;
    ns_scene plain = build(mats, &sun, 0);
    ns_image want = {0};
    if (!render_ok(&plain, &want, NULL))
        return;
    /* A few planes stay within every device's limit: the image must not change, which
     * proves the planes are never a nearest hit, on lavapipe too. */
    CHECK_INT(render_with_planes(40, &want), 0);
    int refused = render_with_planes(PLANES, &want);
    ns_device_info info;
    ns_context_device_info(test_context(), &info);
    if (strstr(info.device_name, "llvmpipe"))
        CHECK_INT(refused, 1); /* lavapipe's limit is met: the canary must say so */
    ns_image_free(&want);
}

int main(void)
{
    RUN(test_cut_is_never_silent);
    return harness_report();
}
