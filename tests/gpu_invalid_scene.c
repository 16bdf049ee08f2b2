/* gpu_invalid_scene.c — ns_render never trusts its caller: out-of-range indices, NaN,
 * bad counts, shading normals that are not unit vectors and unavailable components are
 * refused with a message naming the field, and
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

/* The error of the last expect_refused, for a test that checks more of its message. */
static ns_error refused;

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
    refused = err;
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
    s = valid_scene();
    s.render.light_samples = NS_MAX_LIGHT_SAMPLES + 1;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "render.light_samples");
    s = valid_scene();
    s.render.spp = 4;
    s.render.adaptive_spp = NS_MAX_ADAPTIVE_SPP + 1;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "render.adaptive_spp");
    s.render.adaptive_spp = NAN;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "render.adaptive_spp");
    s.render.adaptive_spp = -0.5f;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "render.adaptive_spp");
    /* Added samples go where the first ones spread: one sample per pixel has no spread. */
    s.render.adaptive_spp = 1.0f;
    s.render.spp = 1;
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "render.adaptive_spp");
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

/* A sheet of `count` small triangles in front of the camera; NULL when out of memory. */
static ns_triangle *triangle_sheet(uint64_t count)
{
    ns_triangle *tris = calloc(count, sizeof *tris);
    for (uint64_t i = 0; tris && i < count; i++) {
        float x = (float)(i % 2048) * 0.01f, y = (float)(i / 2048) * 0.01f;
        set3(tris[i].v[0], x, y, -3);
        set3(tris[i].v[1], x + 0.01, y, -3);
        set3(tris[i].v[2], x, y + 0.01, -3);
    }
    return tris;
}

/* The valid scene with its sphere replaced by the mesh of `count` triangles. */
static ns_scene mesh_scene(const ns_triangle *tris, uint32_t count)
{
    ns_scene s = valid_scene();
    objects[0].shape = NS_SHAPE_MESH;
    objects[0].first_triangle = 0;
    objects[0].triangle_count = count;
    s.triangles = tris;
    s.triangle_count = count;
    return s;
}

/* Shading normals must be unit vectors, or all nine zero (a flat triangle): a normal that is
 * not a unit vector, or NaN, or one zero corner among given ones, is refused at its field. */
static void test_bad_shading_normals(void)
{
    ns_triangle tri[1];
    memset(tri, 0, sizeof tri);
    set3(tri[0].v[0], -1, -1, 0);
    set3(tri[0].v[1], 1, -1, 0);
    set3(tri[0].v[2], 0, 1, 0);
    ns_scene s = mesh_scene(tri, 1);
    for (int c = 0; c < 3; c++)
        set3(tri[0].n[c], 0, 0, 1);
    ns_image img = {0};
    if (render_ok(&s, &img, NULL)) /* unit normals: a smooth triangle renders */
        ns_image_free(&img);
    set3(tri[0].n[1], 0, 0, 2);
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "triangles[0].n[1]");
    set3(tri[0].n[1], 0, 0, 0); /* one corner without a normal */
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "triangles[0].n[1]");
    tri[0].n[2][0] = NAN;
    set3(tri[0].n[1], 0, 0, 1);
    expect_refused(&s, NS_ERR_INVALID_ARGUMENT, "triangles[0].n[2]");
}

/* The size gpu_buffer_create gives the scene buffer labelled `label` (rounded up to 16). */
static uint64_t scene_buffer_bytes(const gpu_buffer_desc descs[NS_SCENE_BUFFER_COUNT],
                                   const char *label)
{
    for (int i = 0; i < NS_SCENE_BUFFER_COUNT; i++)
        if (descs[i].label && !strcmp(descs[i].label, label))
            return descs[i].size < 16 ? 16 : (descs[i].size + 15) & ~(uint64_t)15;
    return 0;
}

/* Fails after the params and BVH buffers exist: the primitive buffer is larger than the
 * device allows a storage buffer to be, and every buffer made before it is freed. No valid
 * scene reaches the limit of a desktop GPU (commonly 4 GiB, while NS_MAX_TRIANGLES x 64 bytes
 * is 256 MiB), so this test lowers the limit the context read from the device to 16 bytes
 * below a small mesh's primitive buffer, as if the device were that small: gpu_buffer_create
 * checks every buffer against that same field, so the path taken is the one a real limit
 * takes, on every device and in a fraction of a second. test_scene_beyond_the_device_limit
 * below meets the real limit where a valid scene can. */
static void test_failure_after_upload_frees_buffers(void)
{
    enum { COUNT = 4096 };
    ns_context *ctx = test_context();
    ns_triangle *tris = triangle_sheet(COUNT);
    CHECK(tris != NULL);
    if (!tris)
        return;
    ns_scene s = mesh_scene(tris, COUNT);
    /* The sizes of the buffers the render will make for this scene. */
    ns_gpu_scene gs;
    ns_error err = {0};
    int status = ns_gpu_scene_build(&s, &gs, &err);
    if (status)
        fprintf(stderr, "ns_gpu_scene_build: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    gpu_buffer_desc descs[NS_SCENE_BUFFER_COUNT];
    uint64_t nodes = 0, prims = 0;
    if (!status) {
        ns_gpu_scene_buffer_descs(&gs, descs);
        nodes = scene_buffer_bytes(descs, "ns.scene.bvh_nodes");
        prims = scene_buffer_bytes(descs, "ns.scene.prims");
    }
    ns_gpu_scene_free(&gs);
    uint64_t limit = prims - 16;
    /* The test means something only if the BVH's buffer fits under the lowered limit (it is
     * made first) and the primitive buffer does not. */
    CHECK(nodes > 0 && nodes <= limit);
    CHECK(prims > 16 && prims <= ctx->dev.properties.limits.maxStorageBufferRange);
    if (!status && nodes > 0 && nodes <= limit && prims > 16) {
        uint32_t real = ctx->dev.properties.limits.maxStorageBufferRange;
        ctx->dev.properties.limits.maxStorageBufferRange = (uint32_t)limit;
        expect_refused(&s, NS_ERR_LIMIT, "'ns.scene.prims'");
        char allows[64];
        snprintf(allows, sizeof allows, "the device allows %llu", (unsigned long long)limit);
        CHECK_STR_CONTAINS(refused.message, allows);
        ctx->dev.properties.limits.maxStorageBufferRange = real;
    }
    free(tris);
}

/* The same failure at the device's real limit (2.2 M triangles x 64 bytes > 128 MiB on
 * lavapipe), where a valid scene can exceed it. */
static void test_scene_beyond_the_device_limit(void)
{
    ns_context *ctx = test_context();
    uint64_t limit = ctx->dev.properties.limits.maxStorageBufferRange;
    uint64_t count = limit / sizeof(GpuPrim) + 16;
    if (count > NS_MAX_TRIANGLES)
        SKIP("this device's storage buffers hold NS_MAX_TRIANGLES triangles and more: no "
             "valid scene exceeds them (test_failure_after_upload_frees_buffers covers the "
             "path with a lowered limit)");
    ns_triangle *tris = triangle_sheet(count);
    CHECK(tris != NULL);
    if (!tris)
        return;
    ns_scene s = mesh_scene(tris, (uint32_t)count);
    expect_refused(&s, NS_ERR_LIMIT, "'ns.scene.prims'");
    char allows[64];
    snprintf(allows, sizeof allows, "the device allows %llu", (unsigned long long)limit);
    CHECK_STR_CONTAINS(refused.message, allows);
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
    RUN(test_bad_shading_normals);
    RUN(test_unavailable_components);
    RUN(test_failure_after_upload_frees_buffers);
    RUN(test_scene_beyond_the_device_limit);
    ns_context_destroy(test_context());
    return harness_report();
}
