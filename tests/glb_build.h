/* glb_build.h — writes small glTF 2.0 binaries (GLB) in memory for the tests, so that the
 * mesh path is tested with real files whose every byte is known, plus a base64 encoder.
 * Everything returned is malloc'd; the caller frees it. */
#ifndef NS_TEST_GLB_BUILD_H
#define NS_TEST_GLB_BUILD_H

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void glb_put_u32(unsigned char *p, uint32_t v)
{
    p[0] = (unsigned char)v, p[1] = (unsigned char)(v >> 8), p[2] = (unsigned char)(v >> 16),
    p[3] = (unsigned char)(v >> 24);
}

/* A GLB container around `json` and an optional BIN chunk (bin may be NULL). */
static unsigned char *glb_pack(const char *json, const void *bin, size_t bin_len, size_t *out_len)
{
    size_t json_len = strlen(json), json_padded = (json_len + 3) & ~(size_t)3;
    size_t bin_padded = (bin_len + 3) & ~(size_t)3;
    size_t total = 12 + 8 + json_padded + (bin ? 8 + bin_padded : 0);
    unsigned char *b = calloc(1, total);
    if (!b)
        return NULL;
    memcpy(b, "glTF", 4);
    glb_put_u32(b + 4, 2);
    glb_put_u32(b + 8, (uint32_t)total);
    glb_put_u32(b + 12, (uint32_t)json_padded);
    glb_put_u32(b + 16, 0x4E4F534Au);
    memcpy(b + 20, json, json_len);
    memset(b + 20 + json_len, ' ', json_padded - json_len); /* the spec pads JSON with spaces */
    if (bin) {
        unsigned char *c = b + 20 + json_padded;
        glb_put_u32(c, (uint32_t)bin_padded);
        glb_put_u32(c + 4, 0x004E4942u);
        memcpy(c + 8, bin, bin_len);
    }
    *out_len = total;
    return b;
}

/* One mesh with one primitive on one node. idx may be NULL (non-indexed); index_ctype is
 * 5121 (u8), 5123 (u16) or 5125 (u32); mode < 0 leaves "mode" out (TRIANGLES by default);
 * node_fields is inserted into the node object (e.g. "\"translation\":[1,2,3],"). */
static unsigned char *glb_mesh(const float *pos, size_t vertex_count, const uint32_t *idx, size_t index_count,
                               int index_ctype, int mode, const char *node_fields, size_t *out_len)
{
    size_t isize = index_ctype == 5121 ? 1 : index_ctype == 5123 ? 2 : 4;
    size_t pos_bytes = vertex_count * 12, idx_bytes = idx ? index_count * isize : 0;
    size_t idx_offset = (pos_bytes + 3) & ~(size_t)3;
    size_t bin_len = idx_offset + idx_bytes;
    unsigned char *bin = calloc(1, bin_len + 4);
    char *json = malloc(4096);
    if (!bin || !json) {
        free(bin);
        free(json);
        return NULL;
    }
    memcpy(bin, pos, pos_bytes);
    for (size_t i = 0; idx && i < index_count; i++) {
        uint32_t v = idx[i];
        if (isize == 1)
            bin[idx_offset + i] = (unsigned char)v;
        else if (isize == 2)
            bin[idx_offset + 2 * i] = (unsigned char)v, bin[idx_offset + 2 * i + 1] = (unsigned char)(v >> 8);
        else
            glb_put_u32(bin + idx_offset + 4 * i, v);
    }
    char mode_text[32] = "", idx_text[32] = "", idx_acc[160] = "", idx_view[128] = "";
    if (mode >= 0)
        snprintf(mode_text, sizeof mode_text, ",\"mode\":%d", mode);
    if (idx) {
        snprintf(idx_text, sizeof idx_text, ",\"indices\":1");
        snprintf(idx_acc, sizeof idx_acc, ",{\"bufferView\":1,\"componentType\":%d,\"count\":%zu,\"type\":\"SCALAR\"}",
                 index_ctype, index_count);
        snprintf(idx_view, sizeof idx_view, ",{\"buffer\":0,\"byteOffset\":%zu,\"byteLength\":%zu}", idx_offset,
                 idx_bytes);
    }
    snprintf(json, 4096,
             "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
             "\"nodes\":[{%s\"mesh\":0}],"
             "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}%s%s}]}],"
             "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":%zu,\"type\":\"VEC3\"}%s],"
             "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":%zu}%s],"
             "\"buffers\":[{\"byteLength\":%zu}]}",
             node_fields ? node_fields : "", idx_text, mode_text, vertex_count, idx_acc, pos_bytes, idx_view, bin_len);
    unsigned char *glb = glb_pack(json, bin, bin_len, out_len);
    free(bin);
    free(json);
    return glb;
}

/* One mesh with POSITION and, when normals is not NULL, NORMAL (normal_count elements, so a
 * count that does not match can be written), u32 indices, on one node with node_fields. */
static unsigned char *glb_mesh_shaded(const float *pos, size_t vertex_count, const float *normals,
                                      size_t normal_count, const uint32_t *idx, size_t index_count,
                                      const char *node_fields, size_t *out_len)
{
    size_t pos_bytes = vertex_count * 12, nrm_bytes = normals ? normal_count * 12 : 0;
    size_t idx_bytes = index_count * 4, bin_len = pos_bytes + nrm_bytes + idx_bytes;
    unsigned char *bin = calloc(1, bin_len + 4);
    char *json = malloc(4096);
    if (!bin || !json) {
        free(bin);
        free(json);
        return NULL;
    }
    memcpy(bin, pos, pos_bytes);
    if (normals)
        memcpy(bin + pos_bytes, normals, nrm_bytes);
    for (size_t i = 0; i < index_count; i++)
        glb_put_u32(bin + pos_bytes + nrm_bytes + 4 * i, idx[i]);
    char nrm_attr[32] = "", nrm_acc[128] = "", nrm_view[128] = "";
    if (normals) {
        snprintf(nrm_attr, sizeof nrm_attr, ",\"NORMAL\":2");
        snprintf(nrm_acc, sizeof nrm_acc,
                 ",{\"bufferView\":2,\"componentType\":5126,\"count\":%zu,\"type\":\"VEC3\"}",
                 normal_count);
        snprintf(nrm_view, sizeof nrm_view, ",{\"buffer\":0,\"byteOffset\":%zu,\"byteLength\":%zu}",
                 pos_bytes, nrm_bytes);
    }
    snprintf(json, 4096,
             "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
             "\"nodes\":[{%s\"mesh\":0}],"
             "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0%s},\"indices\":1}]}],"
             "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":%zu,\"type\":\"VEC3\"},"
             "{\"bufferView\":1,\"componentType\":5125,\"count\":%zu,\"type\":\"SCALAR\"}%s],"
             "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":%zu},"
             "{\"buffer\":0,\"byteOffset\":%zu,\"byteLength\":%zu}%s],"
             "\"buffers\":[{\"byteLength\":%zu}]}",
             node_fields ? node_fields : "", nrm_attr, vertex_count, index_count, nrm_acc, pos_bytes,
             pos_bytes + nrm_bytes, idx_bytes, nrm_view, bin_len);
    unsigned char *glb = glb_pack(json, bin, bin_len, out_len);
    free(bin);
    free(json);
    return glb;
}

static char *base64_encode(const unsigned char *b, size_t n)
{
    static const char alphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    char *out = malloc((n + 2) / 3 * 4 + 1), *o = out;
    if (!out)
        return NULL;
    for (size_t i = 0; i < n; i += 3) {
        uint32_t v = (uint32_t)b[i] << 16 | (i + 1 < n ? (uint32_t)b[i + 1] << 8 : 0) | (i + 2 < n ? b[i + 2] : 0);
        *o++ = alphabet[v >> 18 & 63];
        *o++ = alphabet[v >> 12 & 63];
        *o++ = i + 1 < n ? alphabet[v >> 6 & 63] : '=';
        *o++ = i + 2 < n ? alphabet[v & 63] : '=';
    }
    *o = '\0';
    return out;
}

/* The unit tetrahedron (0,0,0), (1,0,0), (0,1,0), (0,0,1), faces counter-clockwise seen
 * from outside. */
static const float tetra_positions[12] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1};
static const uint32_t tetra_indices[12] = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3};

#endif
