// gltf_shim.cpp — the only C++ file: tinygltf behind the extern "C" gltf_load() (see
// gltf_shim.h). tinygltf is trusted with JSON and glTF structure only; everything it
// hands back (indices, offsets, strides, counts) is bounds-checked here before use,
// because a scene arrives from the network.

#define TINYGLTF_IMPLEMENTATION
#define TINYGLTF_NO_FS
#define TINYGLTF_NO_STB_IMAGE
#define TINYGLTF_NO_STB_IMAGE_WRITE
#define TINYGLTF_NO_EXTERNAL_IMAGE
// tinygltf 2.7's writer (never called here) uses std::ofstream even under TINYGLTF_NO_FS.
#include <fstream>
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wshadow"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#endif
#include <tiny_gltf.h>
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic pop
#endif

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <new>
#include <string>
#include <vector>

#include "gltf_shim.h"
#include "nscatter.h"

namespace {

// Deeper JSON than this is refused before tinygltf sees it: its "extras" parser recurses.
constexpr int kMaxJsonDepth = 64;
// Node hierarchies deeper than this are refused (the walk below recurses).
constexpr int kMaxNodeDepth = 128;

struct LoadError {
    int status;
    std::string message;
};

[[noreturn]] void fail(int status, const std::string &message)
{
    throw LoadError{status, message};
}

// ---------------------------------------------------------------------------------------
// Input checks done before tinygltf parses anything.
// ---------------------------------------------------------------------------------------

uint32_t read_u32le(const unsigned char *p)
{
    return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
}

void check_json_depth(const unsigned char *text, size_t len)
{
    int depth = 0;
    bool in_string = false;
    for (size_t i = 0; i < len; i++) {
        unsigned char c = text[i];
        if (in_string) {
            if (c == '\\')
                i++;
            else if (c == '"')
                in_string = false;
        } else if (c == '"') {
            in_string = true;
        } else if (c == '[' || c == '{') {
            if (++depth > kMaxJsonDepth)
                fail(NS_ERR_INVALID_ARGUMENT, "glTF JSON nested deeper than " +
                                                  std::to_string(kMaxJsonDepth) + " levels");
        } else if (c == ']' || c == '}') {
            depth--;
        }
    }
}

// Validates the GLB container strictly (tinygltf 2.7 lets a BIN chunk's payload run 8
// bytes past the declared length) and returns the length tinygltf may read.
size_t check_glb_container(const unsigned char *b, size_t len)
{
    if (len < 20)
        fail(NS_ERR_INVALID_ARGUMENT, "GLB truncated: " + std::to_string(len) +
                                          " bytes, the header alone needs 20");
    uint32_t version = read_u32le(b + 4), length = read_u32le(b + 8);
    if (version != 2)
        fail(NS_ERR_INVALID_ARGUMENT,
             "GLB version " + std::to_string(version) + " is not supported (only 2)");
    if (length > len)
        fail(NS_ERR_INVALID_ARGUMENT, "GLB truncated: header declares " +
                                          std::to_string(length) + " bytes, got " +
                                          std::to_string(len));
    uint64_t json_len = read_u32le(b + 12);
    if (read_u32le(b + 16) != 0x4E4F534Au)
        fail(NS_ERR_INVALID_ARGUMENT, "GLB first chunk is not JSON");
    uint64_t json_end = 20 + json_len;
    if (json_len == 0 || json_end > length)
        fail(NS_ERR_INVALID_ARGUMENT, "GLB JSON chunk runs past the end of the file");
    if (json_end < length) {
        if (json_end + 8 > length)
            fail(NS_ERR_INVALID_ARGUMENT, "GLB truncated inside the BIN chunk header");
        uint64_t bin_len = read_u32le(b + json_end);
        if (read_u32le(b + json_end + 4) != 0x004E4942u)
            fail(NS_ERR_INVALID_ARGUMENT, "GLB second chunk is not BIN");
        if (json_end + 8 + bin_len > length)
            fail(NS_ERR_INVALID_ARGUMENT, "GLB truncated: the BIN chunk runs past the end");
    }
    check_json_depth(b + 20, size_t(json_len));
    return length;
}

// ---------------------------------------------------------------------------------------
// Accessors, bounds-checked.
// ---------------------------------------------------------------------------------------

struct AccessorView {
    const unsigned char *base; // first element
    size_t stride;
    size_t count;
    int component_type;
};

size_t component_size(int component_type)
{
    switch (component_type) {
    case TINYGLTF_COMPONENT_TYPE_BYTE:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
        return 1;
    case TINYGLTF_COMPONENT_TYPE_SHORT:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT:
        return 2;
    case TINYGLTF_COMPONENT_TYPE_INT:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
    case TINYGLTF_COMPONENT_TYPE_FLOAT:
        return 4;
    default:
        return 0;
    }
}

AccessorView view_accessor(const tinygltf::Model &model, int index, int want_type,
                           const std::string &what)
{
    if (index < 0 || size_t(index) >= model.accessors.size())
        fail(NS_ERR_INVALID_ARGUMENT, what + " accessor " + std::to_string(index) + " does not exist");
    const tinygltf::Accessor &acc = model.accessors[size_t(index)];
    const std::string name = what + " accessor " + std::to_string(index);
    if (acc.sparse.isSparse)
        fail(NS_ERR_INVALID_ARGUMENT, name + " is sparse; sparse accessors are not supported");
    if (acc.type != want_type)
        fail(NS_ERR_INVALID_ARGUMENT, name + " has the wrong type (" + what +
                                          (want_type == TINYGLTF_TYPE_VEC3 ? " must be VEC3)"
                                                                           : " must be SCALAR)"));
    size_t csize = component_size(acc.componentType);
    if (csize == 0)
        fail(NS_ERR_INVALID_ARGUMENT, name + " has an unknown component type");
    size_t elem = csize * (want_type == TINYGLTF_TYPE_VEC3 ? 3 : 1);
    AccessorView v{nullptr, elem, acc.count, acc.componentType};
    if (acc.count == 0)
        return v;
    if (acc.bufferView < 0 || size_t(acc.bufferView) >= model.bufferViews.size())
        fail(NS_ERR_INVALID_ARGUMENT, name + " has no valid bufferView");
    const tinygltf::BufferView &bv = model.bufferViews[size_t(acc.bufferView)];
    if (bv.buffer < 0 || size_t(bv.buffer) >= model.buffers.size())
        fail(NS_ERR_INVALID_ARGUMENT, name + ": its bufferView names no valid buffer");
    const std::vector<unsigned char> &data = model.buffers[size_t(bv.buffer)].data;
    if (bv.byteOffset > data.size() || bv.byteLength > data.size() - bv.byteOffset)
        fail(NS_ERR_INVALID_ARGUMENT, name + ": its bufferView runs past the buffer");
    if (bv.byteStride != 0) {
        if (bv.byteStride < elem)
            fail(NS_ERR_INVALID_ARGUMENT, name + ": byteStride is smaller than an element");
        v.stride = bv.byteStride;
    }
    // offset + stride * (count - 1) + elem <= byteLength, without overflow.
    if (acc.byteOffset > bv.byteLength || elem > bv.byteLength - acc.byteOffset ||
        acc.count - 1 > (bv.byteLength - acc.byteOffset - elem) / v.stride)
        fail(NS_ERR_INVALID_ARGUMENT, name + " runs past the end of its bufferView");
    v.base = data.data() + bv.byteOffset + acc.byteOffset;
    return v;
}

uint32_t read_index(const AccessorView &v, size_t i)
{
    const unsigned char *p = v.base + i * v.stride;
    switch (v.component_type) {
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
        return p[0];
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
        uint16_t x;
        std::memcpy(&x, p, 2);
        return x;
    }
    default: {
        uint32_t x;
        std::memcpy(&x, p, 4);
        return x;
    }
    }
}

// ---------------------------------------------------------------------------------------
// Node transforms: 4x4 column-major matrices, as glTF stores them.
// ---------------------------------------------------------------------------------------

struct Mat4 {
    double m[16];
};

Mat4 identity()
{
    Mat4 r{};
    r.m[0] = r.m[5] = r.m[10] = r.m[15] = 1;
    return r;
}

Mat4 multiply(const Mat4 &a, const Mat4 &b)
{
    Mat4 r{};
    for (int col = 0; col < 4; col++)
        for (int row = 0; row < 4; row++) {
            double s = 0;
            for (int k = 0; k < 4; k++)
                s += a.m[k * 4 + row] * b.m[col * 4 + k];
            r.m[col * 4 + row] = s;
        }
    return r;
}

Mat4 node_local_matrix(const tinygltf::Node &node)
{
    if (node.matrix.size() == 16) {
        Mat4 r;
        for (int i = 0; i < 16; i++)
            r.m[i] = node.matrix[size_t(i)];
        return r;
    }
    // M = T * R * S (glTF 2.0, section 5.25).
    Mat4 t = identity(), r = identity(), s = identity();
    if (node.translation.size() == 3)
        for (int i = 0; i < 3; i++)
            t.m[12 + i] = node.translation[size_t(i)];
    if (node.scale.size() == 3)
        for (int i = 0; i < 3; i++)
            s.m[i * 5] = node.scale[size_t(i)];
    if (node.rotation.size() == 4) {
        double x = node.rotation[0], y = node.rotation[1], z = node.rotation[2],
               w = node.rotation[3];
        double n = std::sqrt(x * x + y * y + z * z + w * w);
        if (!(n > 0) || !std::isfinite(n))
            fail(NS_ERR_INVALID_ARGUMENT, "node " + node.name + " has a zero rotation quaternion");
        x /= n, y /= n, z /= n, w /= n;
        r.m[0] = 1 - 2 * (y * y + z * z), r.m[1] = 2 * (x * y + z * w), r.m[2] = 2 * (x * z - y * w);
        r.m[4] = 2 * (x * y - z * w), r.m[5] = 1 - 2 * (x * x + z * z), r.m[6] = 2 * (y * z + x * w);
        r.m[8] = 2 * (x * z + y * w), r.m[9] = 2 * (y * z - x * w), r.m[10] = 1 - 2 * (x * x + y * y);
    }
    return multiply(t, multiply(r, s));
}

double det3(const Mat4 &a)
{
    const double *m = a.m;
    return m[0] * (m[5] * m[10] - m[9] * m[6]) - m[4] * (m[1] * m[10] - m[9] * m[2]) +
           m[8] * (m[1] * m[6] - m[5] * m[2]);
}

// The inverse transpose of the upper 3x3, up to a positive factor, column-major as out[3c + r]:
// its cofactor matrix, times the sign of the determinant so that a mirroring transform keeps
// outward normals outward. Normals carried by it are normalised afterwards.
void cofactor3(const Mat4 &a, double out[9])
{
    auto at = [&](int r, int c) { return a.m[c * 4 + r]; };
    double sign = det3(a) < 0 ? -1.0 : 1.0;
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            out[3 * c + r] = sign * (at((r + 1) % 3, (c + 1) % 3) * at((r + 2) % 3, (c + 2) % 3) -
                                     at((r + 1) % 3, (c + 2) % 3) * at((r + 2) % 3, (c + 1) % 3));
}

// ---------------------------------------------------------------------------------------
// Flattening primitives into world-space triangles.
// ---------------------------------------------------------------------------------------

const char *mode_name(int mode)
{
    switch (mode) {
    case TINYGLTF_MODE_POINTS: return "POINTS";
    case TINYGLTF_MODE_LINE: return "LINES";
    case TINYGLTF_MODE_LINE_LOOP: return "LINE_LOOP";
    case TINYGLTF_MODE_LINE_STRIP: return "LINE_STRIP";
    case TINYGLTF_MODE_TRIANGLE_STRIP: return "TRIANGLE_STRIP";
    case TINYGLTF_MODE_TRIANGLE_FAN: return "TRIANGLE_FAN";
    default: return "unknown";
    }
}

// Triangles are gathered straight into malloc'd memory, the form the C caller frees, so
// that a large mesh is not held twice (a std::vector and then a copy).
struct FloatBuffer {
    float *data = nullptr;
    size_t size = 0, capacity = 0;
    FloatBuffer() = default;
    FloatBuffer(const FloatBuffer &) = delete;
    FloatBuffer &operator=(const FloatBuffer &) = delete;
    ~FloatBuffer() { std::free(data); }

    void reserve_more(size_t extra)
    {
        if (extra <= capacity - size)
            return;
        size_t want = std::max(size + extra, capacity * 2);
        void *grown = std::realloc(data, want * sizeof(float));
        if (!grown)
            throw std::bad_alloc();
        data = static_cast<float *>(grown);
        capacity = want;
    }
    void push(float x) { data[size++] = x; } // after reserve_more
    float *release()
    {
        float *p = data;
        data = nullptr;
        size = capacity = 0;
        return p;
    }
};

struct Flattener {
    const tinygltf::Model &model;
    size_t max_triangles;
    FloatBuffer out; // 9 floats per triangle
    std::vector<char> visited;
    bool want_normals;
    FloatBuffer normals; // 9 floats per triangle (zero where a primitive has no NORMAL)
    bool any_normals;

    void add_primitive(const tinygltf::Primitive &prim, const Mat4 &world, size_t mesh_index)
    {
        const std::string where = "mesh " + std::to_string(mesh_index);
        if (prim.mode != TINYGLTF_MODE_TRIANGLES && prim.mode != -1)
            fail(NS_ERR_INVALID_ARGUMENT, where + " has a primitive of mode " +
                                              std::to_string(prim.mode) + " (" +
                                              mode_name(prim.mode) +
                                              "); only TRIANGLES (4) is supported");
        auto pos_it = prim.attributes.find("POSITION");
        if (pos_it == prim.attributes.end())
            fail(NS_ERR_INVALID_ARGUMENT, where + " has a primitive without POSITION");
        AccessorView pos = view_accessor(model, pos_it->second, TINYGLTF_TYPE_VEC3, "POSITION");
        if (pos.count > 0 && pos.component_type != TINYGLTF_COMPONENT_TYPE_FLOAT)
            fail(NS_ERR_INVALID_ARGUMENT, where + ": POSITION must be FLOAT (quantized positions are not supported)");
        bool indexed = prim.indices >= 0;
        AccessorView idx{};
        size_t corner_count = pos.count;
        if (indexed) {
            idx = view_accessor(model, prim.indices, TINYGLTF_TYPE_SCALAR, "indices");
            if (idx.count > 0 && idx.component_type != TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE &&
                idx.component_type != TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT &&
                idx.component_type != TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT)
                fail(NS_ERR_INVALID_ARGUMENT, where + ": indices must be unsigned integers");
            corner_count = idx.count;
        }
        if (corner_count % 3 != 0)
            fail(NS_ERR_INVALID_ARGUMENT, where + ": " + std::to_string(corner_count) +
                                              " corners is not a whole number of triangles");
        size_t tris = corner_count / 3;
        size_t have = out.size / 9;
        if (tris > max_triangles || have > max_triangles - tris)
            fail(NS_ERR_LIMIT, "the mesh has more than " + std::to_string(max_triangles) +
                                   " triangles (the limit left for this scene)");
        // Vertex normals, when asked for and given: VEC3 FLOAT, one per vertex, carried to
        // world space by the inverse transpose of the node transform (its cofactor matrix,
        // whose scale does not matter: each is normalised).
        AccessorView nrm{};
        bool has_normals = false;
        auto nrm_it = prim.attributes.find("NORMAL");
        if (want_normals && nrm_it != prim.attributes.end()) {
            nrm = view_accessor(model, nrm_it->second, TINYGLTF_TYPE_VEC3, "NORMAL");
            if (nrm.count != pos.count)
                fail(NS_ERR_INVALID_ARGUMENT, where + ": NORMAL has " + std::to_string(nrm.count) +
                                                  " elements for " + std::to_string(pos.count) +
                                                  " vertices");
            if (nrm.count > 0 && nrm.component_type != TINYGLTF_COMPONENT_TYPE_FLOAT)
                fail(NS_ERR_INVALID_ARGUMENT, where + ": NORMAL must be FLOAT");
            has_normals = nrm.count > 0;
        }
        double cof[9];
        cofactor3(world, cof);
        // A mirroring transform turns counter-clockwise into clockwise; swap two corners
        // so that the outside stays outside.
        bool mirrored = det3(world) < 0;
        out.reserve_more(tris * 9);
        if (want_normals)
            normals.reserve_more(tris * 9);
        for (size_t t = 0; t < tris; t++) {
            for (int c = 0; c < 3; c++) {
                int corner = mirrored && c > 0 ? 3 - c : c;
                size_t k = t * 3 + size_t(corner);
                size_t vi = indexed ? read_index(idx, k) : k;
                if (vi >= pos.count)
                    fail(NS_ERR_INVALID_ARGUMENT, where + ": index " + std::to_string(vi) +
                                                      " is out of range (" +
                                                      std::to_string(pos.count) + " vertices)");
                float p[3];
                std::memcpy(p, pos.base + vi * pos.stride, sizeof p);
                for (int a = 0; a < 3; a++) {
                    const double *m = world.m;
                    double w = m[a] * p[0] + m[4 + a] * p[1] + m[8 + a] * p[2] + m[12 + a];
                    if (!std::isfinite(w) || std::fabs(w) > 3.0e38)
                        fail(NS_ERR_INVALID_ARGUMENT, where + ": vertex " + std::to_string(vi) +
                                                          " is not finite after its node transform");
                    out.push(float(w));
                }
                if (!want_normals)
                    continue;
                float n[3] = {0, 0, 0};
                if (has_normals) {
                    std::memcpy(n, nrm.base + vi * nrm.stride, sizeof n);
                    double w[3], len2 = 0;
                    for (int a = 0; a < 3; a++) {
                        w[a] = cof[a] * n[0] + cof[3 + a] * n[1] + cof[6 + a] * n[2];
                        len2 += w[a] * w[a];
                    }
                    if (!(len2 > 1e-30) || !std::isfinite(len2))
                        fail(NS_ERR_INVALID_ARGUMENT, where + ": NORMAL of vertex " +
                                                          std::to_string(vi) +
                                                          " is not a direction (zero or not finite)");
                    for (int a = 0; a < 3; a++)
                        n[a] = float(w[a] / std::sqrt(len2));
                    any_normals = true;
                }
                for (int a = 0; a < 3; a++)
                    normals.push(n[a]);
            }
        }
    }

    void add_mesh(int mesh, const Mat4 &world)
    {
        if (mesh < 0 || size_t(mesh) >= model.meshes.size())
            fail(NS_ERR_INVALID_ARGUMENT, "a node names mesh " + std::to_string(mesh) +
                                              ", which does not exist");
        for (const tinygltf::Primitive &prim : model.meshes[size_t(mesh)].primitives)
            add_primitive(prim, world, size_t(mesh));
    }

    void add_node(int node, const Mat4 &parent, int depth)
    {
        if (node < 0 || size_t(node) >= model.nodes.size())
            fail(NS_ERR_INVALID_ARGUMENT, "node " + std::to_string(node) + " does not exist");
        // glTF node hierarchies are strict trees: a node reached twice means a cycle or a
        // shared child, both invalid (and a cycle would never end).
        if (visited[size_t(node)])
            fail(NS_ERR_INVALID_ARGUMENT, "node " + std::to_string(node) +
                                              " appears twice in the scene graph");
        if (depth > kMaxNodeDepth)
            fail(NS_ERR_INVALID_ARGUMENT, "node hierarchy deeper than " +
                                              std::to_string(kMaxNodeDepth) + " levels");
        visited[size_t(node)] = 1;
        const tinygltf::Node &n = model.nodes[size_t(node)];
        Mat4 world = multiply(parent, node_local_matrix(n));
        if (n.mesh >= 0)
            add_mesh(n.mesh, world);
        for (int child : n.children)
            add_node(child, world, depth + 1);
    }

    void run()
    {
        visited.assign(model.nodes.size(), 0);
        if (model.scenes.empty()) {
            // No scene graph: each mesh once, as stored.
            for (size_t m = 0; m < model.meshes.size(); m++)
                add_mesh(int(m), identity());
        } else {
            size_t scene = model.defaultScene >= 0 ? size_t(model.defaultScene) : 0;
            if (scene >= model.scenes.size())
                fail(NS_ERR_INVALID_ARGUMENT, "the default scene does not exist");
            for (int root : model.scenes[scene].nodes)
                add_node(root, identity(), 0);
        }
        if (out.size == 0)
            fail(NS_ERR_INVALID_ARGUMENT, "the glTF holds no triangles in its scene");
    }
};

// Images are irrelevant to geometry; accept them undecoded instead of failing.
bool ignore_image(tinygltf::Image *, const int, std::string *, std::string *, int, int,
                  const unsigned char *, int, void *)
{
    return true;
}

std::string one_line(std::string s)
{
    for (char &c : s)
        if (c == '\n' || c == '\r')
            c = ' ';
    while (!s.empty() && s.back() == ' ')
        s.pop_back();
    return s;
}

// Returns the malloc'd triangles; *count is their number. normals: NULL, or where the
// malloc'd vertex normals go (NULL when no primitive has any).
float *load(const unsigned char *b, size_t len, size_t max_triangles, size_t *count, float **normals)
{
    if (len > GLTF_MAX_BYTES)
        fail(NS_ERR_LIMIT, "glTF data of " + std::to_string(len) + " bytes is over the " +
                               std::to_string(GLTF_MAX_BYTES) + "-byte limit");
    tinygltf::TinyGLTF loader;
    loader.SetImageLoader(ignore_image, nullptr);
    tinygltf::Model model;
    std::string err, warn;
    bool ok;
    size_t first = 0;
    while (first < len && (b[first] == ' ' || b[first] == '\t' || b[first] == '\n' || b[first] == '\r'))
        first++;
    if (len >= 4 && std::memcmp(b, "glTF", 4) == 0) {
        size_t length = check_glb_container(b, len);
        ok = loader.LoadBinaryFromMemory(&model, &err, &warn, b, unsigned(length), "");
    } else if (first < len && b[first] == '{') {
        check_json_depth(b, len);
        ok = loader.LoadASCIIFromString(&model, &err, &warn, reinterpret_cast<const char *>(b),
                                        unsigned(len), "");
    } else {
        fail(NS_ERR_INVALID_ARGUMENT, "not glTF: neither a GLB (magic \"glTF\") nor glTF JSON");
    }
    if (!ok)
        fail(NS_ERR_INVALID_ARGUMENT,
             "invalid glTF: " + one_line(err.empty() ? std::string("tinygltf refused it") : err));
    Flattener f{model, max_triangles, {}, {}, normals != nullptr, {}, false};
    f.run();
    *count = f.out.size / 9;
    if (normals) {
        float *kept = f.normals.release();
        if (f.any_normals) {
            *normals = kept;
        } else {
            std::free(kept);
        }
    }
    return f.out.release();
}

void copy_message(char *dst, size_t cap, const std::string &msg)
{
    if (dst && cap > 0)
        std::snprintf(dst, cap, "%s", msg.c_str());
}

} // namespace

extern "C" int gltf_load_shaded(const void *bytes, size_t len, size_t max_triangles,
                                float **positions_out, float **normals_out,
                                size_t *triangle_count, char *err, size_t errlen)
{
    if (positions_out)
        *positions_out = nullptr;
    if (normals_out)
        *normals_out = nullptr;
    if (triangle_count)
        *triangle_count = 0;
    if (!bytes || !positions_out || !triangle_count) {
        copy_message(err, errlen, "gltf_load: NULL argument");
        return NS_ERR_INVALID_ARGUMENT;
    }
    try {
        size_t count = 0;
        *positions_out = load(static_cast<const unsigned char *>(bytes), len, max_triangles,
                              &count, normals_out);
        *triangle_count = count;
        copy_message(err, errlen, "");
        return 0;
    } catch (const LoadError &e) {
        copy_message(err, errlen, e.message);
        return e.status;
    } catch (const std::bad_alloc &) {
        copy_message(err, errlen, "out of memory reading the glTF");
        return NS_ERR_OUT_OF_HOST_MEMORY;
    } catch (const std::exception &e) {
        copy_message(err, errlen, std::string("invalid glTF: ") + one_line(e.what()));
        return NS_ERR_INVALID_ARGUMENT;
    } catch (...) {
        copy_message(err, errlen, "invalid glTF: unexpected error");
        return NS_ERR_INVALID_ARGUMENT;
    }
}

extern "C" int gltf_load(const void *bytes, size_t len, size_t max_triangles,
                         float **positions_out, size_t *triangle_count, char *err,
                         size_t errlen)
{
    return gltf_load_shaded(bytes, len, max_triangles, positions_out, nullptr, triangle_count,
                            err, errlen);
}
