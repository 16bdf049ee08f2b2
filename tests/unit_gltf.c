/* unit_gltf.c — the tinygltf shim: real GLB files built in memory, node transforms with
 * closed-form results, winding kept outward, and hostile input (truncation at every
 * length, random corruption, wrong modes, out-of-range indices) refused without a crash. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "glb_build.h"
#include "gltf_shim.h"
#include "harness.h"
#include "nscatter.h"

static unsigned char *tetra_glb(const char *node_fields, int mode, size_t *len)
{
    return glb_mesh(tetra_positions, 4, tetra_indices, 12, 5123, mode, node_fields, len);
}

/* Outward normal of triangle t times a vector from the centroid of the solid to the face:
 * positive when the face is wound counter-clockwise seen from outside. */
static double outwardness(const float *tri, const double centre[3])
{
    double e1[3], e2[3], n[3], c[3];
    for (int a = 0; a < 3; a++) {
        e1[a] = tri[3 + a] - tri[a];
        e2[a] = tri[6 + a] - tri[a];
        c[a] = (tri[a] + tri[3 + a] + tri[6 + a]) / 3 - centre[a];
    }
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    return n[0] * c[0] + n[1] * c[1] + n[2] * c[2];
}

static void check_all_outward(const float *pos, size_t count)
{
    double centre[3] = {0, 0, 0};
    for (size_t i = 0; i < count * 3; i++)
        for (int a = 0; a < 3; a++)
            centre[a] += pos[i * 3 + a] / (double)(count * 3);
    for (size_t t = 0; t < count; t++)
        CHECK(outwardness(pos + t * 9, centre) > 0);
}

static void test_indexed_tetrahedron(void)
{
    size_t len, count = 99;
    unsigned char *glb = tetra_glb(NULL, -1, &len);
    float *pos = NULL;
    char err[256];
    CHECK_INT(gltf_load(glb, len, 1000, &pos, &count, err, sizeof err), 0);
    CHECK_INT(count, 4);
    if (pos && count == 4) {
        for (size_t t = 0; t < 4; t++)
            for (int c = 0; c < 3; c++)
                for (int a = 0; a < 3; a++)
                    CHECK_NEAR(pos[t * 9 + c * 3 + a], tetra_positions[tetra_indices[t * 3 + c] * 3 + a], 0);
        check_all_outward(pos, count);
    }
    free(pos);
    free(glb);
}

static void test_index_widths_and_non_indexed(void)
{
    static const int ctypes[] = {5121, 5123, 5125};
    for (int i = 0; i < 3; i++) {
        size_t len, count = 0;
        unsigned char *glb = glb_mesh(tetra_positions, 4, tetra_indices, 12, ctypes[i], 4, NULL, &len);
        float *pos = NULL;
        char err[256];
        CHECK_INT(gltf_load(glb, len, 1000, &pos, &count, err, sizeof err), 0);
        CHECK_INT(count, 4);
        if (pos)
            CHECK_NEAR(pos[9 * 3 + 8], 1.0, 0); /* last face, last corner: vertex 3, z = 1 */
        free(pos);
        free(glb);
    }
    /* Non-indexed: the 12 corners spelled out. */
    float corners[36];
    for (int k = 0; k < 12; k++)
        for (int a = 0; a < 3; a++)
            corners[k * 3 + a] = tetra_positions[tetra_indices[k] * 3 + a];
    size_t len, count = 0;
    unsigned char *glb = glb_mesh(corners, 12, NULL, 0, 0, -1, NULL, &len);
    float *pos = NULL;
    char err[256];
    CHECK_INT(gltf_load(glb, len, 1000, &pos, &count, err, sizeof err), 0);
    CHECK_INT(count, 4);
    if (pos && count == 4)
        CHECK(memcmp(pos, corners, sizeof corners) == 0);
    free(pos);
    free(glb);
}

/* TRS: p' = T + R (S p). R is 90 degrees about z: (x, y, z) -> (-y, x, z). */
static void test_node_trs(void)
{
    size_t len, count = 0;
    const double h = 0.70710678118654752;
    char fields[256];
    snprintf(fields, sizeof fields,
             "\"translation\":[10,20,30],\"rotation\":[0,0,%.17g,%.17g],\"scale\":[2,3,4],", h, h);
    unsigned char *glb = tetra_glb(fields, 4, &len);
    float *pos = NULL;
    char err[256];
    CHECK_INT(gltf_load(glb, len, 1000, &pos, &count, err, sizeof err), 0);
    CHECK_INT(count, 4);
    if (pos && count == 4) {
        for (size_t k = 0; k < 12; k++) {
            const float *v = &tetra_positions[tetra_indices[k] * 3];
            double sx = 2 * v[0], sy = 3 * v[1], sz = 4 * v[2];
            CHECK_NEAR(pos[k * 3 + 0], 10 - sy, 1e-5);
            CHECK_NEAR(pos[k * 3 + 1], 20 + sx, 1e-5);
            CHECK_NEAR(pos[k * 3 + 2], 30 + sz, 1e-5);
        }
        check_all_outward(pos, count);
    }
    free(pos);
    free(glb);
}

static void test_node_matrix_and_mirroring(void)
{
    /* Column-major matrix: mirror x and translate by (5, 0, 0). */
    size_t len, count = 0;
    unsigned char *glb = tetra_glb("\"matrix\":[-1,0,0,0, 0,1,0,0, 0,0,1,0, 5,0,0,1],", 4, &len);
    float *pos = NULL;
    char err[256];
    CHECK_INT(gltf_load(glb, len, 1000, &pos, &count, err, sizeof err), 0);
    CHECK_INT(count, 4);
    if (pos && count == 4) {
        /* Vertex 1 (1,0,0) lands on (4,0,0); the mirror must not turn the faces inward. */
        int found = 0;
        for (size_t k = 0; k < 12; k++)
            found |= pos[k * 3] == 4.0f && pos[k * 3 + 1] == 0.0f && pos[k * 3 + 2] == 0.0f;
        CHECK(found);
        check_all_outward(pos, count);
    }
    free(pos);
    free(glb);
}

/* A parent node's transform applies to its child: child at +1 in y under a parent at +2 in x. */
static void test_hierarchy(void)
{
    const char *json =
        "{\"asset\":{\"version\":\"2.0\"},\"scenes\":[{\"nodes\":[0]}],"
        "\"nodes\":[{\"translation\":[2,0,0],\"children\":[1]},{\"translation\":[0,1,0],\"mesh\":0}],"
        "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}],"
        "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"}],"
        "\"bufferViews\":[{\"buffer\":0,\"byteLength\":36}],\"buffers\":[{\"byteLength\":36}]}";
    const float tri[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    size_t len, count = 0;
    unsigned char *glb = glb_pack(json, tri, sizeof tri, &len);
    float *pos = NULL;
    char err[256];
    CHECK_INT(gltf_load(glb, len, 1000, &pos, &count, err, sizeof err), 0);
    CHECK_INT(count, 1);
    if (pos && count == 1) {
        CHECK_NEAR(pos[0], 2, 0);
        CHECK_NEAR(pos[1], 1, 0);
        CHECK_NEAR(pos[7], 2, 0); /* third corner (0,1,0) -> (2,2,0) */
    }
    free(pos);
    free(glb);
}

/* A cycle in the node graph must be refused, not recursed into forever. */
static void test_node_cycle(void)
{
    const char *json =
        "{\"asset\":{\"version\":\"2.0\"},\"scenes\":[{\"nodes\":[0]}],"
        "\"nodes\":[{\"children\":[1]},{\"children\":[0],\"mesh\":0}],"
        "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}],"
        "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"}],"
        "\"bufferViews\":[{\"buffer\":0,\"byteLength\":36}],\"buffers\":[{\"byteLength\":36}]}";
    const float tri[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    size_t len, count = 0;
    unsigned char *glb = glb_pack(json, tri, sizeof tri, &len);
    float *pos = NULL;
    char err[256];
    CHECK_INT(gltf_load(glb, len, 1000, &pos, &count, err, sizeof err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err, "appears twice");
    CHECK(pos == NULL);
    free(glb);
}

static void test_non_triangle_mode(void)
{
    size_t len, count = 0;
    unsigned char *glb = tetra_glb(NULL, 1, &len);
    float *pos = NULL;
    char err[256];
    CHECK_INT(gltf_load(glb, len, 1000, &pos, &count, err, sizeof err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err, "LINES");
    CHECK_STR_CONTAINS(err, "only TRIANGLES");
    CHECK(pos == NULL);
    free(glb);
    glb = tetra_glb(NULL, 5, &len);
    CHECK_INT(gltf_load(glb, len, 1000, &pos, &count, err, sizeof err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err, "TRIANGLE_STRIP");
    free(glb);
}

static void test_index_out_of_range(void)
{
    const uint32_t bad[3] = {0, 1, 7};
    size_t len, count = 0;
    unsigned char *glb = glb_mesh(tetra_positions, 4, bad, 3, 5123, 4, NULL, &len);
    float *pos = NULL;
    char err[256];
    CHECK_INT(gltf_load(glb, len, 1000, &pos, &count, err, sizeof err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err, "index 7 is out of range");
    free(glb);
}

/* An accessor claiming more vertices than its bufferView holds. */
static void test_accessor_past_buffer(void)
{
    const char *json =
        "{\"asset\":{\"version\":\"2.0\"},\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}],"
        "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":300,\"type\":\"VEC3\"}],"
        "\"bufferViews\":[{\"buffer\":0,\"byteLength\":36}],\"buffers\":[{\"byteLength\":36}]}";
    const float tri[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    size_t len, count = 0;
    unsigned char *glb = glb_pack(json, tri, sizeof tri, &len);
    float *pos = NULL;
    char err[256];
    CHECK_INT(gltf_load(glb, len, 1000, &pos, &count, err, sizeof err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err, "runs past");
    free(glb);
}

static void test_triangle_limit(void)
{
    size_t len, count = 0;
    unsigned char *glb = tetra_glb(NULL, 4, &len);
    float *pos = NULL;
    char err[256];
    CHECK_INT(gltf_load(glb, len, 3, &pos, &count, err, sizeof err), NS_ERR_LIMIT);
    CHECK(pos == NULL);
    CHECK_INT(gltf_load(glb, len, 4, &pos, &count, err, sizeof err), 0);
    free(pos);
    free(glb);
}

static void test_size_limit(void)
{
    size_t big = GLTF_MAX_BYTES + 1;
    unsigned char *b = calloc(1, big);
    float *pos = NULL;
    size_t count;
    char err[256];
    if (b) {
        memcpy(b, "glTF", 4);
        CHECK_INT(gltf_load(b, big, 1000, &pos, &count, err, sizeof err), NS_ERR_LIMIT);
        CHECK_STR_CONTAINS(err, "limit");
    }
    free(b);
}

/* Every proper prefix of a valid GLB is refused cleanly (ASan watches the reads). */
static void test_truncated_at_every_length(void)
{
    size_t len, count;
    unsigned char *glb = tetra_glb(NULL, 4, &len);
    int all_refused = 1;
    for (size_t n = 0; n < len; n++) {
        unsigned char *copy = malloc(n ? n : 1);
        memcpy(copy, glb, n);
        float *pos = NULL;
        char err[256];
        int rc = gltf_load(copy, n, 1000, &pos, &count, err, sizeof err);
        if (rc != NS_ERR_INVALID_ARGUMENT || pos) {
            all_refused = 0;
            fprintf(stderr, "prefix %zu: rc %d\n", n, rc);
        }
        free(pos);
        free(copy);
    }
    CHECK(all_refused);
    free(glb);
}

/* Random byte corruption: any answer is fine except a crash, a leak or a success that
 * reports no triangles. */
static void test_random_corruption(void)
{
    size_t len;
    unsigned char *glb = tetra_glb("\"translation\":[1,2,3],", 4, &len);
    uint32_t state = 12345;
    int consistent = 1;
    for (int trial = 0; trial < 3000; trial++) {
        unsigned char *copy = malloc(len);
        memcpy(copy, glb, len);
        int flips = 1 + trial % 4;
        for (int f = 0; f < flips; f++) {
            state = state * 1664525u + 1013904223u;
            size_t at = (state >> 8) % len;
            state = state * 1664525u + 1013904223u;
            copy[at] = (unsigned char)(state >> 24);
        }
        float *pos = NULL;
        size_t count = 0;
        char err[256];
        int rc = gltf_load(copy, len, 1000, &pos, &count, err, sizeof err);
        if (rc == 0 ? (count == 0 || !pos) : (pos != NULL || err[0] == '\0'))
            consistent = 0;
        free(pos);
        free(copy);
    }
    CHECK(consistent);
    free(glb);
}

static void test_garbage(void)
{
    const char *inputs[] = {"", "hello world", "glTF", "{", "{\"asset\":{\"version\":\"2.0\"}}", "[1,2,3]"};
    for (size_t i = 0; i < sizeof inputs / sizeof inputs[0]; i++) {
        float *pos = NULL;
        size_t count;
        char err[256] = "";
        int rc = gltf_load(inputs[i], strlen(inputs[i]), 1000, &pos, &count, err, sizeof err);
        CHECK_INT(rc, NS_ERR_INVALID_ARGUMENT);
        CHECK(err[0] != '\0');
        CHECK(pos == NULL);
    }
    /* Deep JSON nesting inside a GLB is refused before tinygltf recurses into it. */
    char *deep = malloc(20000 + 64);
    strcpy(deep, "{\"asset\":{\"version\":\"2.0\"},\"extras\":");
    size_t n = strlen(deep);
    for (int i = 0; i < 9000; i++)
        deep[n++] = '[';
    deep[n] = '\0';
    size_t len;
    unsigned char *glb = glb_pack(deep, NULL, 0, &len);
    float *pos = NULL;
    size_t count;
    char err[256];
    CHECK_INT(gltf_load(glb, len, 1000, &pos, &count, err, sizeof err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err, "nested deeper");
    free(glb);
    free(deep);
}

/* glTF JSON text with the buffer as a data: URI is accepted; any other URI is refused
 * (the shim has no file system). */
static void test_gltf_json_with_data_uri(void)
{
    const float tri[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    char *b64 = base64_encode((const unsigned char *)tri, sizeof tri);
    char json[1024];
    snprintf(json, sizeof json,
             "{\"asset\":{\"version\":\"2.0\"},\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}],"
             "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"}],"
             "\"bufferViews\":[{\"buffer\":0,\"byteLength\":36}],"
             "\"buffers\":[{\"byteLength\":36,\"uri\":\"data:application/octet-stream;base64,%s\"}]}",
             b64);
    float *pos = NULL;
    size_t count = 0;
    char err[256];
    CHECK_INT(gltf_load(json, strlen(json), 1000, &pos, &count, err, sizeof err), 0);
    CHECK_INT(count, 1);
    if (pos && count == 1)
        CHECK(memcmp(pos, tri, sizeof tri) == 0);
    free(pos);
    pos = NULL;
    snprintf(json, sizeof json,
             "{\"asset\":{\"version\":\"2.0\"},\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}],"
             "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"}],"
             "\"bufferViews\":[{\"buffer\":0,\"byteLength\":36}],"
             "\"buffers\":[{\"byteLength\":36,\"uri\":\"/etc/passwd\"}]}");
    CHECK_INT(gltf_load(json, strlen(json), 1000, &pos, &count, err, sizeof err), NS_ERR_INVALID_ARGUMENT);
    CHECK(pos == NULL);
    free(b64);
}

/* Vertex normals: read, carried to world space by the inverse transpose of the node
 * transform (a non-uniform scale bends them; a mirror keeps them outward), kept with their
 * corner when mirroring swaps corners; absent NORMAL gives no normals; a NORMAL of the
 * wrong count or a zero normal is refused. */
static const float tetra_normals[12] = {-0.57735027f, -0.57735027f, -0.57735027f, 1, 0, 0,
                                        0,            1,            0,            0, 0, 1};

static void check_normals(const char *node_fields, const double scale[3])
{
    size_t len, count = 0;
    unsigned char *glb = glb_mesh_shaded(tetra_positions, 4, tetra_normals, 4, tetra_indices, 12,
                                         node_fields, &len);
    float *pos = NULL, *nrm = NULL;
    char err[256];
    CHECK_INT(gltf_load_shaded(glb, len, 1000, &pos, &nrm, &count, err, sizeof err), 0);
    CHECK_INT(count, 4);
    CHECK(nrm != NULL);
    for (size_t c = 0; nrm && pos && c < count * 3; c++) {
        /* The source vertex of this corner: the one the scale maps onto its position. */
        int found = -1;
        for (int v = 0; v < 4; v++) {
            int same = 1;
            for (int a = 0; a < 3; a++)
                same &= fabs(tetra_positions[v * 3 + a] * scale[a] - pos[c * 3 + a]) < 1e-6;
            if (same)
                found = v;
        }
        CHECK(found >= 0);
        if (found < 0)
            continue;
        double want[3], len2 = 0;
        for (int a = 0; a < 3; a++) {
            want[a] = tetra_normals[found * 3 + a] / scale[a]; /* diag(s)^-T n */
            len2 += want[a] * want[a];
        }
        for (int a = 0; a < 3; a++)
            CHECK_NEAR(nrm[c * 3 + a], want[a] / sqrt(len2), 1e-6);
    }
    free(pos);
    free(nrm);
    free(glb);
}

static void test_vertex_normals(void)
{
    check_normals(NULL, (const double[3]){1, 1, 1});
    check_normals("\"scale\":[2,1,0.5],", (const double[3]){2, 1, 0.5});
    check_normals("\"scale\":[-1,1,1],", (const double[3]){-1, 1, 1});

    size_t len, count;
    float *pos = NULL, *nrm = (float *)1;
    char err[256];
    /* No NORMAL: no normals, and the positions as gltf_load gives them. */
    unsigned char *glb = glb_mesh_shaded(tetra_positions, 4, NULL, 0, tetra_indices, 12, NULL, &len);
    CHECK_INT(gltf_load_shaded(glb, len, 1000, &pos, &nrm, &count, err, sizeof err), 0);
    CHECK(nrm == NULL);
    CHECK_INT(count, 4);
    free(pos);
    free(glb);
    /* NORMAL present but not asked for: gltf_load reads the positions alone. */
    glb = glb_mesh_shaded(tetra_positions, 4, tetra_normals, 4, tetra_indices, 12, NULL, &len);
    CHECK_INT(gltf_load(glb, len, 1000, &pos, &count, err, sizeof err), 0);
    free(pos);
    free(glb);
    /* A NORMAL of three elements for four vertices. */
    glb = glb_mesh_shaded(tetra_positions, 4, tetra_normals, 3, tetra_indices, 12, NULL, &len);
    CHECK_INT(gltf_load_shaded(glb, len, 1000, &pos, &nrm, &count, err, sizeof err),
              NS_ERR_INVALID_ARGUMENT);
    CHECK(strstr(err, "NORMAL") != NULL);
    CHECK(pos == NULL && nrm == NULL);
    free(glb);
    /* A zero normal. */
    float zero[12];
    memcpy(zero, tetra_normals, sizeof zero);
    zero[3] = 0.0f;
    glb = glb_mesh_shaded(tetra_positions, 4, zero, 4, tetra_indices, 12, NULL, &len);
    CHECK_INT(gltf_load_shaded(glb, len, 1000, &pos, &nrm, &count, err, sizeof err),
              NS_ERR_INVALID_ARGUMENT);
    CHECK(strstr(err, "NORMAL of vertex 1") != NULL);
    free(glb);
}

int main(void)
{
    RUN(test_indexed_tetrahedron);
    RUN(test_index_widths_and_non_indexed);
    RUN(test_node_trs);
    RUN(test_node_matrix_and_mirroring);
    RUN(test_hierarchy);
    RUN(test_node_cycle);
    RUN(test_non_triangle_mode);
    RUN(test_index_out_of_range);
    RUN(test_accessor_past_buffer);
    RUN(test_triangle_limit);
    RUN(test_size_limit);
    RUN(test_truncated_at_every_length);
    RUN(test_random_corruption);
    RUN(test_garbage);
    RUN(test_gltf_json_with_data_uri);
    RUN(test_vertex_normals);
    return harness_report();
}
