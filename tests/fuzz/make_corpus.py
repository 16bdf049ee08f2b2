#!/usr/bin/env python3
"""make_corpus.py — writes the seed corpora of the libFuzzer targets (tests/fuzz_*.c) into
tests/fuzz/corpus/<target>/. The seeds are committed; this script says where each came from
and makes them again after a format change:

    python3 tests/fuzz/make_corpus.py

Seeds are small on purpose (the fuzzers' -max_len is 16 KiB): the example scenes, tiny GLB
and glTF JSON meshes whose every byte is known, and raw HTTP requests covering every route,
Content-Length and chunked bodies, pipelining, a lying length and oversized headers.
"""
import base64
import json
import os
import struct

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
OUT = os.path.join(ROOT, "tests", "fuzz", "corpus")


def write(target, name, data):
    d = os.path.join(OUT, target)
    os.makedirs(d, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def read(path):
    with open(os.path.join(ROOT, path), "rb") as f:
        return f.read()


# --- glTF -------------------------------------------------------------------------------
TETRA = [0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1]
TETRA_IDX = [0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3]


def glb_pack(js, binary=None):
    j = js.encode()
    j += b" " * (-len(j) % 4)
    out = struct.pack("<II", len(j), 0x4E4F534A) + j
    if binary is not None:
        b = binary + b"\0" * (-len(binary) % 4)
        out += struct.pack("<II", len(b), 0x004E4942) + b
    return b"glTF" + struct.pack("<II", 2, 12 + len(out)) + out


def mesh_gltf(index_ctype=5123, mode=None, node="", uri=None, normals=False):
    """(json text, bin bytes) of the tetrahedron; uri: a data URI buffer instead of GLB;
    normals: a NORMAL attribute too (after the indices)."""
    pos = struct.pack("<12f", *TETRA)
    fmt = {5121: "B", 5123: "H", 5125: "I"}.get(index_ctype)
    idx = struct.pack("<%d%s" % (len(TETRA_IDX), fmt), *TETRA_IDX) if fmt else b""
    idx += b"\0" * (-len(idx) % 4)
    binary = pos + idx
    prim = {"attributes": {"POSITION": 0}}
    accessors = [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                  "min": [0, 0, 0], "max": [1, 1, 1]}]
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": len(pos)}]
    if fmt:
        prim["indices"] = 1
        accessors.append({"bufferView": 1, "componentType": index_ctype,
                          "count": len(TETRA_IDX), "type": "SCALAR"})
        views.append({"buffer": 0, "byteOffset": len(pos), "byteLength": len(idx)})
    if normals:
        r = 3 ** -0.5
        nrm = struct.pack("<12f", -r, -r, -r, 1, 0, 0, 0, 1, 0, 0, 0, 1)
        prim["attributes"]["NORMAL"] = len(accessors)
        accessors.append({"bufferView": len(views), "componentType": 5126, "count": 4,
                          "type": "VEC3"})
        views.append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(nrm)})
        binary += nrm
    if mode is not None:
        prim["mode"] = mode
    buf = {"byteLength": len(binary)}
    if uri:
        buf["uri"] = "data:application/octet-stream;base64," + base64.b64encode(binary).decode()
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [dict(json.loads("{" + node + "}"), mesh=0)],
           "meshes": [{"primitives": [prim]}], "accessors": accessors,
           "bufferViews": views, "buffers": [buf]}
    return json.dumps(doc, separators=(",", ":")), binary


def gltf_seeds():
    write("gltf", "octahedron.glb", read("scenes/assets/octahedron.glb"))
    for ctype, name in ((5121, "u8"), (5123, "u16"), (5125, "u32"), (None, "plain")):
        js, b = mesh_gltf(ctype)
        write("gltf", "tetra_%s.glb" % name, glb_pack(js, b))
    js, b = mesh_gltf(node='"translation":[1,2,3],"rotation":[0,0.7071068,0,0.7071068],"scale":[1,-1,1]')
    write("gltf", "tetra_trs_mirror.glb", glb_pack(js, b))
    js, b = mesh_gltf(node='"matrix":[2,0,0,0,0,2,0,0,0,0,2,0,1,1,1,1]')
    write("gltf", "tetra_matrix.glb", glb_pack(js, b))
    js, b = mesh_gltf(mode=1)
    write("gltf", "tetra_lines.glb", glb_pack(js, b))
    # Vertex normals (the NORMAL path), also under a mirroring, non-uniform node transform.
    js, b = mesh_gltf(normals=True)
    write("gltf", "tetra_normals.glb", glb_pack(js, b))
    js, b = mesh_gltf(normals=True, node='"scale":[-2,1,0.5]')
    write("gltf", "tetra_normals_mirror.glb", glb_pack(js, b))
    # glTF JSON with a data: URI buffer (the shim's second form).
    js, _ = mesh_gltf(uri=True)
    write("gltf", "tetra_data_uri.gltf", js)
    # The harness's NUL-split form: JSON, NUL, BIN chunk (fuzz_gltf wraps it in a GLB).
    js, b = mesh_gltf()
    write("gltf", "tetra_split.bin", js.encode() + b"\0" + b)
    # A hierarchy: a parent node with a child, and the default-scene fallback (no "scene").
    doc = json.loads(mesh_gltf()[0])
    doc["nodes"] = [{"children": [1], "translation": [0, 1, 0]}, {"mesh": 0, "scale": [2, 2, 2]}]
    del doc["scene"]
    write("gltf", "tetra_hierarchy.bin", json.dumps(doc).encode() + b"\0" + mesh_gltf()[1])


# --- scenes -----------------------------------------------------------------------------
def scene_seeds():
    for folder in ("scenes", "scenes/bench"):
        for name in sorted(os.listdir(os.path.join(ROOT, folder))):
            if name.endswith(".json"):
                prefix = "bench_" if folder.endswith("bench") else ""
                write("scene", prefix + name, read(os.path.join(folder, name)))


# --- sweeps -----------------------------------------------------------------------------
SMALL_SCENE = {
    "version": 1,
    "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40,
               "width": 32, "height": 32},
    "materials": {"wax": {"type": "medium", "albedo": [0.9, 0.8, 0.7], "mfp": 0.5, "g": 0.3,
                          "ior": 1.4}},
    "objects": [{"shape": "sphere", "center": [0, 0, 0], "radius": 1, "material": "wax"}],
    "lights": [{"type": "directional", "direction": [0, -1, -1], "irradiance": [2, 2, 2]}],
    "render": {"method": "pt", "spp": 4, "max_depth": 4},
}


def sweep_seeds():
    # Every example scene as a base, so that overrides meet meshes, presets and every light.
    for name in sorted(os.listdir(os.path.join(ROOT, "scenes"))):
        if name.endswith(".json"):
            base = json.loads(read(os.path.join("scenes", name)))
            first = sorted(base.get("materials", {}))[:1]
            variants = [{"/camera/width": 64, "/camera/height": 48}, {"/render/spp": 2}]
            if first:
                variants.append({"/materials/%s/ior" % first[0]: 1.3})
            write("sweep", "scene_" + name, json.dumps({"scene": base, "variants": variants}))
    write("sweep", "list.json", json.dumps(
        {"scene": SMALL_SCENE, "variants": [{"/materials/wax/g": 0.5},
                                            {"/materials/wax/g": 0.8, "/materials/wax/ior": 1.3}]}))
    write("sweep", "grid.json", json.dumps(
        {"scene": SMALL_SCENE, "grid": {"/materials/wax/albedo": [[0.9, 0.9, 0.9], [0.99, 0.99, 0.99]],
                                        "/materials/wax/g": [0.2, 0.5, 0.8]}}))
    write("sweep", "escapes.json", json.dumps(
        {"scene": SMALL_SCENE, "variants": [{"/materials/a~1b": {"type": "diffuse", "reflectance": 0.5},
                                             "/objects/0/material": "a/b"}, {"/camera/width": 16}]}))
    write("sweep", "preset.json", json.dumps(
        {"scene": SMALL_SCENE, "variants": [{"/materials/wax": {"type": "medium", "preset": "candle"}}]}))


# --- HTTP -------------------------------------------------------------------------------
def req(method, path, headers=(), body=b"", length=True):
    if isinstance(body, str):
        body = body.encode()
    lines = ["%s %s HTTP/1.1" % (method, path), "Host: 127.0.0.1"]
    lines += list(headers)
    if length and (body or method == "POST"):
        lines.append("Content-Length: %d" % len(body))
    return ("\r\n".join(lines) + "\r\n\r\n").encode() + body


def chunked(body, sizes=(7, 64, 1000000), ext=""):
    out, i, k = b"", 0, 0
    while i < len(body):
        n = min(sizes[k % len(sizes)], len(body) - i)
        out += b"%x%s\r\n" % (n, ext.encode()) + body[i:i + n] + b"\r\n"
        i, k = i + n, k + 1
    return out + b"0\r\n\r\n"


def http_seeds():
    scene = json.dumps(SMALL_SCENE).encode()
    json_type = "Content-Type: application/json"
    gets = {"livez": "/livez", "readyz": "/readyz", "info": "/v1/info", "metrics": "/metrics",
            "materials": "/v1/materials", "openapi": "/openapi.json", "index": "/",
            "web_file": "/app.js", "renders_list": "/v1/renders", "no_route": "/v2/nothing/here"}
    for name, path in gets.items():
        write("http", "get_" + name, req("GET", path))
    write("http", "head_info", req("HEAD", "/v1/info"))
    write("http", "job_image", req("GET", "/v1/renders/0123456789abcdef/image?format=half",
                                   ["Accept: image/x-exr; format=half"]))
    write("http", "sweep_image", req("GET", "/v1/sweeps/inst-0123/images/3",
                                     ["Accept: image/png;q=0.5, image/x-exr;q=0.9, */*;q=0"]))
    write("http", "sweep_routes", req("GET", "/v1/sweeps/x/sheet.png") +
          req("GET", "/v1/sweeps/x/manifest.json") + req("GET", "/v1/sweeps/x/events?last_event_id=7"))
    write("http", "events", req("GET", "/v1/renders/abc/events", ["Last-Event-ID: 12"]))
    write("http", "delete_job", req("DELETE", "/v1/renders/abc"))
    write("http", "method_not_allowed", req("PUT", "/v1/renders", [json_type], "{}"))
    write("http", "validate", req("POST", "/v1/renders/validate",
                                  [json_type + "; charset=utf-8", "X-Request-Id: seed-1"], scene))
    for name in ("default.json", "mesh_inline.json", "presets.json"):
        write("http", "validate_" + name[:-5], req("POST", "/v1/renders/validate", [json_type],
                                                  read(os.path.join("scenes", name))))
    write("http", "validate_invalid", req("POST", "/v1/renders/validate", [json_type],
                                          '{"version": 1, "camera": {"fov": 1e400}}'))
    write("http", "validate_chunked", req("POST", "/v1/renders/validate",
                                          [json_type, "Transfer-Encoding: chunked"], length=False)
          + chunked(scene))
    write("http", "validate_chunk_ext_trailer",
          req("POST", "/v1/renders/validate", [json_type, "Transfer-Encoding: chunked"],
              length=False) + chunked(scene, (100,), ";name=value")[:-2] + b"X-Trailer: 1\r\n\r\n")
    write("http", "chunked_over_limit", req("POST", "/v1/renders/validate",
                                            [json_type, "Transfer-Encoding: chunked"], length=False)
          + chunked(b" " * 5000 + b"{}", (1024,)))
    write("http", "length_over_limit", req("POST", "/v1/renders", [json_type, "Content-Length: 99999999"],
                                           length=False) + b"{}")
    write("http", "length_short", req("POST", "/v1/renders/validate", [json_type, "Content-Length: 500"],
                                      length=False) + scene[:100])
    write("http", "length_long", req("POST", "/v1/renders/validate", [json_type, "Content-Length: 20"],
                                     length=False) + scene)
    write("http", "length_and_chunked", req("POST", "/v1/renders/validate",
                                            [json_type, "Content-Length: 5", "Transfer-Encoding: chunked"],
                                            length=False) + chunked(b"{}"))
    write("http", "render_async", req("POST", "/v1/renders", [json_type, "Prefer: respond-async, wait=5",
                                                              "Accept: image/png"], scene))
    write("http", "render_sync_exr", req("POST", "/v1/renders?format=float",
                                         [json_type, "Accept: image/x-exr"], scene))
    write("http", "sweep_post", req("POST", "/v1/sweeps", [json_type], read_seed("sweep", "list.json")))
    write("http", "expect_continue", req("POST", "/v1/renders/validate", [json_type, "Expect: 100-continue"],
                                         scene))
    write("http", "pipelined", req("GET", "/livez") + req("POST", "/v1/renders/validate", [json_type], scene)
          + req("HEAD", "/readyz") + req("GET", "/v1/materials", ["Connection: close"]))
    write("http", "wrong_type", req("POST", "/v1/renders/validate", ["Content-Type: text/plain"], scene))
    write("http", "bad_query", req("GET", "/v1/renders/a/image?format=%zz&&=&x", []))
    write("http", "huge_header", req("GET", "/livez", ["X-Big: " + "a" * 9000]))
    write("http", "many_headers", req("GET", "/v1/info", ["X-H%d: %d" % (i, i) for i in range(200)]))
    write("http", "http10_keepalive", b"GET /livez HTTP/1.0\r\nConnection: keep-alive\r\n\r\n"
          b"GET /readyz HTTP/1.0\r\n\r\n")
    write("http", "bare_lf", b"GET /livez HTTP/1.1\nHost: x\n\n")
    write("http", "absolute_form", b"GET http://127.0.0.1/livez HTTP/1.1\r\nHost: x\r\n\r\n")
    write("http", "options_star", b"OPTIONS * HTTP/1.1\r\nHost: x\r\n\r\n")
    write("http", "garbage", b"\x00\xffGARBAGE / HTTP/9.9\r\n\r\n")
    write("http", "bad_utf8_body", req("POST", "/v1/renders/validate", [json_type],
                                       b'{"version": 1, "materials": {"\xc3\x28": {}}}'))


def read_seed(target, name):
    with open(os.path.join(OUT, target, name), "rb") as f:
        return f.read()


if __name__ == "__main__":
    gltf_seeds()
    scene_seeds()
    sweep_seeds()
    http_seeds()
