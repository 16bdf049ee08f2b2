/* bench_mesh.c — meshes for `nscatter bench`: generated shapes, the OBJ reader for the bunny,
 * and a minimal GLB writer. See bench_mesh.h. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_mesh.h"

void bench_mesh_free(bench_mesh *m)
{
    if (!m)
        return;
    free(m->positions);
    free(m->indices);
    memset(m, 0, sizeof *m);
}

static int mesh_alloc(bench_mesh *m, uint32_t vertices, uint32_t triangles, ns_error *err)
{
    memset(m, 0, sizeof *m);
    m->positions = malloc(sizeof(float) * 3 * (vertices ? vertices : 1));
    m->indices = malloc(sizeof(uint32_t) * 3 * (triangles ? triangles : 1));
    if (!m->positions || !m->indices) {
        bench_mesh_free(m);
        err->status = NS_ERR_OUT_OF_HOST_MEMORY;
        snprintf(err->message, sizeof err->message, "mesh of %u vertices: out of memory", vertices);
        return NS_ERR_OUT_OF_HOST_MEMORY;
    }
    return NS_OK;
}

static void normalise3(float *v)
{
    float l = sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    v[0] /= l, v[1] /= l, v[2] /= l;
}

/* ---------------------------------------------------------------------------------------
 * Bumpy sphere: an icosphere whose vertices move along the normal.
 * ------------------------------------------------------------------------------------- */

/* Midpoint of edge (a, b), shared by the two triangles of the edge through an open-
 * addressing table keyed by the ordered pair. */
typedef struct edge_table {
    uint64_t *keys; /* (min << 32 | max) + 1; 0 = empty */
    uint32_t *mid;
    uint32_t mask;
} edge_table;

static uint32_t edge_midpoint(edge_table *t, bench_mesh *m, uint32_t a, uint32_t b)
{
    uint32_t lo = a < b ? a : b, hi = a < b ? b : a;
    uint64_t key = ((uint64_t)lo << 32 | hi) + 1;
    uint32_t h = (uint32_t)((key * 0x9E3779B97F4A7C15ull) >> 40) & t->mask;
    while (t->keys[h] && t->keys[h] != key)
        h = (h + 1) & t->mask;
    if (t->keys[h])
        return t->mid[h];
    float *p = &m->positions[3 * m->vertex_count];
    for (int k = 0; k < 3; k++)
        p[k] = 0.5f * (m->positions[3 * a + k] + m->positions[3 * b + k]);
    normalise3(p);
    t->keys[h] = key;
    t->mid[h] = m->vertex_count;
    return m->vertex_count++;
}

static void icosahedron(bench_mesh *m)
{
    const float t = (1.0f + sqrtf(5.0f)) / 2.0f;
    const float v[12][3] = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                            {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
    static const uint32_t f[20][3] = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                      {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                      {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                      {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
    for (int i = 0; i < 12; i++) {
        memcpy(&m->positions[3 * i], v[i], sizeof v[i]);
        normalise3(&m->positions[3 * i]);
    }
    memcpy(m->indices, f, sizeof f);
    m->vertex_count = 12;
    m->triangle_count = 20;
}

/* Smooth bumps in [-1, 1]: a few products of sines of the direction, chosen so that the
 * bumps are about a fifth of the radius across (the look of the paper's Fig. 8). */
static float bump(const float *n)
{
    float s = sinf(7.0f * n[0] + 1.3f) * sinf(6.0f * n[1] + 0.4f) * sinf(8.0f * n[2] + 2.1f);
    s += 0.5f * sinf(13.0f * n[0] - 11.0f * n[2] + 0.7f) * sinf(12.0f * n[1] + 1.9f);
    return s / 1.5f;
}

int bench_mesh_bumpy_sphere(uint32_t levels, float amplitude, bench_mesh *out, ns_error *err)
{
    if (levels > 7 || !(amplitude >= 0.0f && amplitude < 0.5f)) {
        err->status = NS_ERR_INVALID_ARGUMENT;
        snprintf(err->message, sizeof err->message,
                 "bumpy sphere: levels %u (at most 7) or amplitude %g (in [0, 0.5)) out of range",
                 levels, (double)amplitude);
        return NS_ERR_INVALID_ARGUMENT;
    }
    uint32_t tris = 20u << (2 * levels), verts = 10u * (1u << (2 * levels)) + 2u;
    int status = mesh_alloc(out, verts, tris, err);
    if (status)
        return status;
    icosahedron(out);
    uint32_t *next = malloc(sizeof(uint32_t) * 3 * tris);
    uint32_t cap = 1;
    while (cap < 4 * verts)
        cap <<= 1;
    edge_table table = {calloc(cap, sizeof(uint64_t)), malloc(sizeof(uint32_t) * cap), cap - 1};
    if (!next || !table.keys || !table.mid) {
        free(next), free(table.keys), free(table.mid);
        bench_mesh_free(out);
        err->status = NS_ERR_OUT_OF_HOST_MEMORY;
        snprintf(err->message, sizeof err->message, "bumpy sphere: out of memory");
        return NS_ERR_OUT_OF_HOST_MEMORY;
    }
    for (uint32_t level = 0; level < levels; level++) {
        memset(table.keys, 0, sizeof(uint64_t) * cap);
        uint32_t n = 0;
        for (uint32_t t = 0; t < out->triangle_count; t++) {
            const uint32_t *f = &out->indices[3 * t];
            uint32_t ab = edge_midpoint(&table, out, f[0], f[1]);
            uint32_t bc = edge_midpoint(&table, out, f[1], f[2]);
            uint32_t ca = edge_midpoint(&table, out, f[2], f[0]);
            const uint32_t four[4][3] = {{f[0], ab, ca}, {f[1], bc, ab}, {f[2], ca, bc}, {ab, bc, ca}};
            memcpy(&next[3 * n], four, sizeof four);
            n += 4;
        }
        memcpy(out->indices, next, sizeof(uint32_t) * 3 * n);
        out->triangle_count = n;
    }
    free(next), free(table.keys), free(table.mid);
    for (uint32_t v = 0; v < out->vertex_count; v++) {
        float *p = &out->positions[3 * v];
        float r = 1.0f + amplitude * bump(p);
        p[0] *= r, p[1] *= r, p[2] *= r;
    }
    return NS_OK;
}

/* ---------------------------------------------------------------------------------------
 * Cylinder.
 * ------------------------------------------------------------------------------------- */
int bench_mesh_cylinder(uint32_t segments, bench_mesh *out, ns_error *err)
{
    if (segments < 3 || segments > 4096) {
        err->status = NS_ERR_INVALID_ARGUMENT;
        snprintf(err->message, sizeof err->message, "cylinder: %u segments (3 to 4096)", segments);
        return NS_ERR_INVALID_ARGUMENT;
    }
    /* Rim vertices 2i (bottom) and 2i + 1 (top), then the two cap centres. */
    int status = mesh_alloc(out, 2 * segments + 2, 4 * segments, err);
    if (status)
        return status;
    for (uint32_t i = 0; i < segments; i++) {
        double a = 2.0 * M_PI * i / segments;
        float x = (float)cos(a), z = (float)-sin(a); /* counter-clockwise seen from +y */
        float *p = &out->positions[6 * i];
        p[0] = x, p[1] = 0, p[2] = z;
        p[3] = x, p[4] = 1, p[5] = z;
    }
    uint32_t bottom = 2 * segments, top = bottom + 1;
    float *c = &out->positions[3 * bottom];
    c[0] = 0, c[1] = 0, c[2] = 0, c[3] = 0, c[4] = 1, c[5] = 0;
    uint32_t *f = out->indices;
    for (uint32_t i = 0; i < segments; i++) {
        uint32_t j = (i + 1) % segments;
        uint32_t b0 = 2 * i, t0 = 2 * i + 1, b1 = 2 * j, t1 = 2 * j + 1;
        const uint32_t quad[4][3] = {{b0, b1, t1}, {b0, t1, t0}, {top, t0, t1}, {bottom, b1, b0}};
        memcpy(f, quad, sizeof quad);
        f += 12;
    }
    out->vertex_count = 2 * segments + 2;
    out->triangle_count = 4 * segments;
    return NS_OK;
}

/* ---------------------------------------------------------------------------------------
 * Wavefront OBJ.
 * ------------------------------------------------------------------------------------- */
typedef struct grow {
    void *data;
    size_t count, cap, item;
} grow;

static void *grow_push(grow *g)
{
    if (g->count == g->cap) {
        size_t cap = g->cap ? 2 * g->cap : 1024;
        void *d = realloc(g->data, cap * g->item);
        if (!d)
            return NULL;
        g->data = d, g->cap = cap;
    }
    return (char *)g->data + g->item * g->count++;
}

static int obj_fail(ns_error *err, int status, const char *path, unsigned line, const char *what)
{
    err->status = status;
    snprintf(err->message, sizeof err->message, "%s:%u: %s", path, line, what);
    return status;
}

/* One face corner "i", "i/t", "i//n" or "i/t/n"; negative i counts back from the end. */
static int obj_corner(const char **s, size_t vertices, uint32_t *out)
{
    char *end;
    long i = strtol(*s, &end, 10);
    if (end == *s)
        return -1;
    while (*end && *end != ' ' && *end != '\t' && *end != '\r' && *end != '\n')
        end++; /* texture and normal indices are not needed */
    *s = end;
    long v = i < 0 ? (long)vertices + i : i - 1;
    if (i == 0 || v < 0 || (size_t)v >= vertices)
        return -1;
    *out = (uint32_t)v;
    return 0;
}

static int obj_parse(FILE *f, const char *path, grow *pos, grow *idx, ns_error *err)
{
    char line[4096];
    unsigned n = 0;
    while (fgets(line, sizeof line, f)) {
        n++;
        if (line[0] == 'v' && (line[1] == ' ' || line[1] == '\t')) {
            float *p = grow_push(pos);
            if (!p)
                return obj_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, path, n, "out of memory");
            if (sscanf(line + 2, "%f %f %f", &p[0], &p[1], &p[2]) != 3 || !isfinite(p[0]) ||
                !isfinite(p[1]) || !isfinite(p[2]))
                return obj_fail(err, NS_ERR_INVALID_ARGUMENT, path, n, "a vertex needs 3 finite numbers");
        } else if (line[0] == 'f' && (line[1] == ' ' || line[1] == '\t')) {
            const char *s = line + 2;
            uint32_t first = 0, prev = 0, v;
            int corners = 0;
            for (;;) {
                while (*s == ' ' || *s == '\t')
                    s++;
                if (!*s || *s == '\r' || *s == '\n')
                    break;
                if (obj_corner(&s, pos->count, &v))
                    return obj_fail(err, NS_ERR_INVALID_ARGUMENT, path, n,
                                    "a face refers to a vertex that is not defined before it");
                if (corners == 0)
                    first = v;
                if (corners >= 2) { /* fan: (first, prev, v) */
                    uint32_t *t = grow_push(idx);
                    if (!t)
                        return obj_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, path, n, "out of memory");
                    t[0] = first, t[1] = prev, t[2] = v;
                }
                prev = v;
                corners++;
            }
            if (corners < 3)
                return obj_fail(err, NS_ERR_INVALID_ARGUMENT, path, n, "a face needs 3 corners");
        }
    }
    if (ferror(f))
        return obj_fail(err, NS_ERR_IO, path, n, "read error");
    if (!idx->count)
        return obj_fail(err, NS_ERR_INVALID_ARGUMENT, path, n, "no faces");
    return NS_OK;
}

double bench_mesh_signed_volume(const bench_mesh *m)
{
    double v = 0;
    for (uint32_t t = 0; t < m->triangle_count; t++) {
        const float *a = &m->positions[3 * m->indices[3 * t]];
        const float *b = &m->positions[3 * m->indices[3 * t + 1]];
        const float *c = &m->positions[3 * m->indices[3 * t + 2]];
        v += (double)a[0] * ((double)b[1] * c[2] - (double)b[2] * c[1]) -
             (double)a[1] * ((double)b[0] * c[2] - (double)b[2] * c[0]) +
             (double)a[2] * ((double)b[0] * c[1] - (double)b[1] * c[0]);
    }
    return v / 6.0;
}

/* Counter-clockwise seen from outside: the scene model's convention (nscatter.h). */
static void orient_outward(bench_mesh *m)
{
    if (bench_mesh_signed_volume(m) >= 0)
        return;
    for (uint32_t t = 0; t < m->triangle_count; t++) {
        uint32_t s = m->indices[3 * t + 1];
        m->indices[3 * t + 1] = m->indices[3 * t + 2];
        m->indices[3 * t + 2] = s;
    }
}

int bench_mesh_load_obj(const char *path, bench_mesh *out, ns_error *err)
{
    memset(out, 0, sizeof *out);
    FILE *f = fopen(path, "r");
    if (!f) {
        err->status = NS_ERR_IO;
        snprintf(err->message, sizeof err->message, "cannot open '%s': %s", path, strerror(errno));
        return NS_ERR_IO;
    }
    grow pos = {.item = 3 * sizeof(float)}, idx = {.item = 3 * sizeof(uint32_t)};
    int status = obj_parse(f, path, &pos, &idx, err);
    fclose(f);
    if (!status && (pos.count > UINT32_MAX || idx.count > NS_MAX_TRIANGLES))
        status = obj_fail(err, NS_ERR_LIMIT, path, 0, "too many vertices or faces");
    if (status) {
        free(pos.data), free(idx.data);
        return status;
    }
    out->positions = pos.data;
    out->indices = idx.data;
    out->vertex_count = (uint32_t)pos.count;
    out->triangle_count = (uint32_t)idx.count;
    orient_outward(out);
    return NS_OK;
}

/* ---------------------------------------------------------------------------------------
 * GLB.
 * ------------------------------------------------------------------------------------- */
static void put_u32(unsigned char *p, uint32_t v)
{
    p[0] = (unsigned char)v, p[1] = (unsigned char)(v >> 8), p[2] = (unsigned char)(v >> 16),
    p[3] = (unsigned char)(v >> 24);
}

int bench_mesh_to_glb(const bench_mesh *m, unsigned char **glb, size_t *glb_size, ns_error *err)
{
    *glb = NULL;
    *glb_size = 0;
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (uint32_t v = 0; v < m->vertex_count; v++)
        for (int k = 0; k < 3; k++) {
            lo[k] = fminf(lo[k], m->positions[3 * v + k]);
            hi[k] = fmaxf(hi[k], m->positions[3 * v + k]);
        }
    size_t pos_bytes = (size_t)m->vertex_count * 12, idx_bytes = (size_t)m->triangle_count * 12;
    char json[2048];
    int json_len = snprintf(
        json, sizeof json,
        "{\"asset\":{\"version\":\"2.0\",\"generator\":\"nscatter bench\"},\"scene\":0,"
        "\"scenes\":[{\"nodes\":[0]}],\"nodes\":[{\"mesh\":0}],"
        "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0},\"indices\":1}]}],"
        "\"buffers\":[{\"byteLength\":%zu}],"
        "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":%zu},"
        "{\"buffer\":0,\"byteOffset\":%zu,\"byteLength\":%zu}],"
        "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":%u,\"type\":\"VEC3\","
        "\"min\":[%.9g,%.9g,%.9g],\"max\":[%.9g,%.9g,%.9g]},"
        "{\"bufferView\":1,\"componentType\":5125,\"count\":%u,\"type\":\"SCALAR\"}]}",
        pos_bytes + idx_bytes, pos_bytes, pos_bytes, idx_bytes, m->vertex_count, (double)lo[0],
        (double)lo[1], (double)lo[2], (double)hi[0], (double)hi[1], (double)hi[2],
        3 * m->triangle_count);
    size_t json_padded = ((size_t)json_len + 3) & ~(size_t)3;
    size_t bin_len = pos_bytes + idx_bytes; /* both multiples of 4 */
    size_t total = 12 + 8 + json_padded + 8 + bin_len;
    unsigned char *b = malloc(total);
    if (!b) {
        err->status = NS_ERR_OUT_OF_HOST_MEMORY;
        snprintf(err->message, sizeof err->message, "GLB of %zu bytes: out of memory", total);
        return NS_ERR_OUT_OF_HOST_MEMORY;
    }
    memcpy(b, "glTF", 4);
    put_u32(b + 4, 2);
    put_u32(b + 8, (uint32_t)total);
    put_u32(b + 12, (uint32_t)json_padded);
    put_u32(b + 16, 0x4E4F534Au); /* "JSON" */
    memcpy(b + 20, json, (size_t)json_len);
    memset(b + 20 + json_len, ' ', json_padded - (size_t)json_len);
    unsigned char *c = b + 20 + json_padded;
    put_u32(c, (uint32_t)bin_len);
    put_u32(c + 4, 0x004E4942u); /* "BIN\0" */
    /* Little-endian floats and integers: the host order on every machine this runs on. */
    memcpy(c + 8, m->positions, pos_bytes);
    memcpy(c + 8 + pos_bytes, m->indices, idx_bytes);
    *glb = b;
    *glb_size = total;
    return NS_OK;
}
