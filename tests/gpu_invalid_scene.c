/* gpu_invalid_scene.c — ns_render never trusts its caller: out-of-range indices, NaN,
 * bad counts and unavailable components are refused with a message naming the field, and
 * a failing render leaves no buffer behind (also on the path that fails after uploading). */
#include "gpu_util.h"

static ns_material m[2];
static ns_object objects[2];
static ns_light l;

static ns_scene valid_scene(void)
{
    ns_scene s = base_scene(8, 8, 40);
    set3(s.camera.position, 0, 0, 5);
    m[0] = diffuse(0.5, 0.5, 0.5);
    const double zero[3] = {0, 0, 0}, absorb[3] = {1, 1, 1};
    m[1] = medium(zero, absorb, 1.3);
    objects[0] = sphere(0, 0, 0, 1, 0);
    objects[1] = plane(-1, 1);
    l = light(NS_LIGHT_DIRECTIONAL, 1, 1, 1);
    set3(l.direction, 0, -1, 0);
    scene_lists(&s, m, 2, objects, 2, &l, 1);
    return s;
}

static void expect_refused(const ns_scene *s, int want_status, const char *field)
{
    ns_context *ctx = test_context();
    uint32_t buffers_before = ctx->dev.live_buffers;
    ns_image img = {.width = 99, .rgb = (float *)&img}; /* garbage the call must reset */
    ns_error err = {0};
    int status = ns_render(ctx, s, &img, NULL, &err);
    CHECK_INT(status, want_status);
    CHECK_INT(err.status, want_status);
    CHECK_STR_CONTAINS(err.message, field);
    CHECK(img.rgb == NULL && img.width == 0);
    CHECK_INT(ctx->dev.live_buffers, buffers_before);
}

static void test_valid_scene_renders(void)
{
    ns_scene s = valid_scene();
    ns_image img = {0};
    if (render_ok(&s, &img, NULL))
        CHECK(img.rgb && img.width == 8);
    ns_image_free(&img);
    CHECK_INT(test_context()->dev.live_buffers, 0);
}

static void test_material_index_out_of_range(void)
{
    ns_scene s = valid_scene();
    objects[0].material = 2;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "objects[0].material");
}

static void test_nan_centre(void)
{
    ns_scene s = valid_scene();
    objects[0].center[1] = NAN;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "objects[0].center");
}

static void test_infinite_light(void)
{
    ns_scene s = valid_scene();
    l.color[2] = INFINITY;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "lights[0]");
}

static void test_bad_numbers(void)
{
    ns_scene s = valid_scene();
    m[1].ior = 0.5f;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "materials[1].ior");
    s = valid_scene();
    m[1].sigma_a[0] = -1;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "materials[1].sigma_a");
    s = valid_scene();
    objects[0].radius = 0;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "objects[0].radius");
    s = valid_scene();
    s.camera.fov_deg = 180;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "camera.fov");
    s = valid_scene();
    s.camera.width = 0;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "camera.width");
    s = valid_scene();
    s.render.spp = NS_MAX_SPP + 1;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "render.spp");
    s = valid_scene();
    s.render.max_depth = NS_MAX_DEPTH + 1;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "render.max_depth");
}

static void test_bad_counts_and_ranges(void)
{
    ns_scene s = valid_scene();
    s.object_count = NS_MAX_OBJECTS + 1;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "objects");
    s = valid_scene();
    s.lights = NULL;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "lights");
    s = valid_scene();
    objects[0].shape = NS_SHAPE_MESH;
    objects[0].first_triangle = 0xfffffff0u;
    objects[0].triangle_count = 0x20;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "objects[0]: triangles");
    s = valid_scene();
    objects[1].shape = (ns_shape)42;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "objects[1].shape");
}

/* The dipole holds double and multiple scattering together: one of them alone is refused,
 * naming it, rather than rendered as something else. */
static void test_unavailable_components(void)
{
    ns_scene s = valid_scene();
    s.render.method = NS_METHOD_DIPOLE;
    s.render.components = NS_COMPONENT_SURFACE | NS_COMPONENT_SINGLE | NS_COMPONENT_MULTIPLE;
    expect_refused(&s, NS_ERR_NOT_AVAILABLE, "multiple");
}

/* Fails after the params and BVH buffers exist: the primitive buffer is larger than a
 * storage buffer may be (2.2 M triangles x 64 bytes > 128 MiB on lavapipe). */
static void test_failure_after_upload_frees_buffers(void)
{
    ns_context *ctx = test_context();
    uint64_t limit = ctx->dev.properties.limits.maxStorageBufferRange;
    uint64_t count = limit / sizeof(GpuPrim) + 16;
    if (count > NS_MAX_TRIANGLES) {
        fprintf(stderr, "skip: this device's storage buffers hold every allowed triangle\n");
        return;
    }
    ns_triangle *tris = malloc(sizeof *tris * count);
    if (!tris)
        return;
    for (uint64_t i = 0; i < count; i++) {
        float x = (float)(i % 2048) * 0.01f, y = (float)(i / 2048) * 0.01f;
        set3(tris[i].v[0], x, y, -3);
        set3(tris[i].v[1], x + 0.01, y, -3);
        set3(tris[i].v[2], x, y + 0.01, -3);
    }
    ns_scene s = valid_scene();
    objects[0].shape = NS_SHAPE_MESH;
    objects[0].first_triangle = 0;
    objects[0].triangle_count = (uint32_t)count;
    s.triangles = tris;
    s.triangle_count = (uint32_t)count;
    expect_refused(&s, NS_ERR_LIMIT, "ns.scene.prims");
    free(tris);
}

int main(void)
{
    RUN(test_valid_scene_renders);
    RUN(test_material_index_out_of_range);
    RUN(test_nan_centre);
    RUN(test_infinite_light);
    RUN(test_bad_numbers);
    RUN(test_bad_counts_and_ranges);
    RUN(test_unavailable_components);
    RUN(test_failure_after_upload_frees_buffers);
    ns_context_destroy(test_context());
    return harness_report();
}
