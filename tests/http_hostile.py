"""A catalogue of malformed and hostile requests (issue 18) against a real `nscatter serve` on
loopback: truncated, deeply nested and huge JSON, NaN and 1e400, negative and absurd sizes,
duplicate and unknown keys, invalid UTF-8, bad base64 and data URIs, glTF that names files or
has out-of-range accessors, wrong content types, bodies longer or shorter than their
Content-Length, ambiguous framing, chunked bodies over the limit, slow clients that send a
byte a second, hundreds of idle connections.

Every case states the exact status it must get. An answer of the service itself must be
`application/problem+json` with `type`, `title`, `status`, `code` and — where one field is at
fault — the JSON pointer of that field in `errors`. A handful of requests are refused by
libmicrohttpd before the service sees them (a Content-Length that is not a number, a
malformed chunk, a request line or header block it cannot parse): those are checked for
their status and `Connection: close` only, since libmicrohttpd 0.9.75 writes its own short
HTML body and offers no hook to replace it (docs/http.md, "Hostile input"). After every case
`/readyz` must answer 200, and at the end a tiny scene still renders.

Raw sockets wherever http.client would "fix" the request. Python standard library only."""
import base64
import json
import os
import socket
import struct
import sys
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import (PNG_SIGNATURE, Checks, Server, parse_raw_response,  # noqa: E402
                         response_complete, small_scene)

MAX_BODY = 1 << 20          # --max-body: small, so over-limit bodies stay cheap to send
REQUEST_TIMEOUT_S = 3       # --request-timeout: how long a request may take to arrive
IDLE_TIMEOUT_S = 4          # --idle-timeout: a silent connection is closed after this
IDLE_CONNECTIONS = 300      # "hundreds of idle connections"
ASAN = os.environ.get("NSCATTER_SANITIZED") == "1"


# ---------------------------------------------------------------------------------------
# Building requests
# ---------------------------------------------------------------------------------------
def scene(width=16, height=16, **changes):
    """A tiny valid scene with JSON-pointer changes applied ({"/camera/fov": 400})."""
    s = small_scene(width, height)
    for pointer, value in changes.items():
        parts = [p.replace("~1", "/").replace("~0", "~") for p in pointer.split("/")[1:]]
        node = s
        for p in parts[:-1]:
            node = node[int(p)] if isinstance(node, list) else node[p]
        last = parts[-1]
        if isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value
    return s


def with_mesh(mesh):
    s = scene()
    s["objects"][0] = dict({"shape": "mesh", "material": "wax"}, **mesh)
    return s


def gltf_json(positions=(0, 0, 0, 1, 0, 0, 0, 1, 0), indices=(0, 1, 2), buffer_uri=None,
              count=None, index_count=None):
    """A glTF JSON text of one triangle mesh whose buffer is a data URI (or `buffer_uri`)."""
    pos = struct.pack("<%df" % len(positions), *positions)
    idx = struct.pack("<%dH" % len(indices), *indices)
    if len(idx) % 4:
        idx += b"\0" * (4 - len(idx) % 4)
    data = pos + idx
    uri = buffer_uri or "data:application/octet-stream;base64," + base64.b64encode(data).decode()
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": 4}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": count or len(positions) // 3,
             "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5123, "count": index_count or len(indices),
             "type": "SCALAR"}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(pos)},
                        {"buffer": 0, "byteOffset": len(pos), "byteLength": len(indices) * 2}],
        "buffers": [{"byteLength": len(data), "uri": uri}],
    }
    return json.dumps(doc)


def gltf_uri(**kw):
    return "data:model/gltf+json;base64," + base64.b64encode(gltf_json(**kw).encode()).decode()


def dumps(doc):
    return json.dumps(doc).encode()


def nested(depth, open_="[", close="]"):
    return open_ * depth + close * depth


def nested_objects(depth):
    return ('{"a":' * depth + "1" + "}" * depth)


HEAD = b"Host: 127.0.0.1\r\n"


def raw_post(path, body, extra=b"", ctype=b"application/json"):
    return (b"POST " + path.encode() + b" HTTP/1.1\r\n" + HEAD + b"Content-Type: " + ctype +
            b"\r\n" + extra + b"\r\n" + body)


def chunked(body, size=4096):
    out = b""
    for at in range(0, len(body), size):
        piece = body[at:at + size]
        out += b"%x\r\n%s\r\n" % (len(piece), piece)
    return out + b"0\r\n\r\n"


# ---------------------------------------------------------------------------------------
# Sending
# ---------------------------------------------------------------------------------------
def post(srv, body, path="/v1/renders", ctype="application/json", headers=None):
    h = {} if ctype is None else {"Content-Type": ctype}
    h.update(headers or {})
    return srv.request("POST", path, body if isinstance(body, bytes) else dumps(body), h,
                       timeout=60)


def raw(srv, data, read_timeout=15, shut=False):
    """Sends `data` on a fresh socket, reads one answer; (status, headers, body, closed)."""
    with socket.create_connection(("127.0.0.1", srv.port), timeout=read_timeout) as s:
        try:
            s.sendall(data)
        except OSError:
            pass  # the server may answer and close before taking everything
        if shut:
            s.shutdown(socket.SHUT_WR)
        return read_answer(s, read_timeout)


def read_answer(s, read_timeout):
    out, closed = b"", False
    deadline = time.monotonic() + read_timeout
    s.settimeout(0.5)
    while time.monotonic() < deadline:
        try:
            chunk = s.recv(65536)
        except socket.timeout:
            if response_complete(out):
                break
            continue
        except (ConnectionResetError, BrokenPipeError):
            closed = True
            break
        if not chunk:
            closed = True
            break
        out += chunk
        if response_complete(out):
            # Whether the server closes after it: look a little longer.
            try:
                s.settimeout(0.3)
                more = s.recv(65536)
                closed = not more
                out += more
            except socket.timeout:
                pass
            except (ConnectionResetError, BrokenPipeError):
                closed = True
            break
    status, headers, body = parse_raw_response(out)
    headers["_closed"] = closed
    return status, headers, body


def slow(srv, data, per_byte_s=1.0, give_up_s=30):
    """Sends `data` a byte at a time, one per `per_byte_s`, until the server answers or
    closes; returns (status, headers, body, seconds until the answer, bytes sent)."""
    start = time.monotonic()
    with socket.create_connection(("127.0.0.1", srv.port), timeout=5) as s:
        sent = 0
        got = b""
        s.settimeout(per_byte_s)
        while time.monotonic() - start < give_up_s:
            if sent < len(data):
                try:
                    s.sendall(data[sent:sent + 1])
                    sent += 1
                except OSError:
                    break
            try:
                chunk = s.recv(65536)
                if not chunk:
                    break
                got += chunk
                if response_complete(got):
                    break
            except socket.timeout:
                continue
            except (ConnectionResetError, BrokenPipeError):
                break
        took = time.monotonic() - start
    status, headers, body = parse_raw_response(got)
    return status, headers, body, took, sent


# ---------------------------------------------------------------------------------------
# Checking
# ---------------------------------------------------------------------------------------
def check_answer(t, name, got, want_status, code=None, pointer=None, mhd=False, close=None):
    status, headers, body = got[:3]
    if not t.equal(status, want_status, f"{name}: status ({body[:300]!r})"):
        return None
    if close is not None:
        t.equal(headers.get("_closed"), close, f"{name}: connection closed after the answer")
    if mhd:
        # libmicrohttpd's own refusal: the status, and the connection is not reused.
        t.check(headers.get("connection", "").lower() == "close" or headers.get("_closed"),
                f"{name}: libmicrohttpd's refusal closes the connection")
        return None
    t.check(headers.get("content-type", "").startswith("application/problem+json"),
            f"{name}: problem content type, got {headers.get('content-type')!r}")
    try:
        p = json.loads(body.decode("utf-8"))
    except ValueError:
        t.check(False, f"{name}: a problem body in JSON: {body[:200]!r}")
        return None
    for key in ("type", "title", "status", "detail", "code", "errors"):
        t.check(key in p, f"{name}: problem has '{key}'")
    t.equal(p.get("status"), want_status, f"{name}: problem status member")
    t.check(str(p.get("type", "")).startswith("urn:nscatter:problem:"), f"{name}: problem type")
    if code:
        t.equal(p.get("code"), code, f"{name}: problem code")
    if pointer is not None:
        pointers = [e.get("pointer") for e in p.get("errors", [])]
        t.check(pointer in pointers, f"{name}: pointer {pointer!r} in {pointers} "
                f"({p.get('detail', '')[:200]})")
    if status == 503:
        t.check(headers.get("retry-after", "").isdigit(), f"{name}: 503 has Retry-After")
    return p


def ready(t, srv, name):
    try:
        status = srv.request("GET", "/readyz", timeout=10)[0]
    except OSError as e:
        status = f"{type(e).__name__}: {e}"
    t.equal(status, 200, f"/readyz after {name}")
    t.check(srv.alive(), f"server alive after {name}")


# ---------------------------------------------------------------------------------------
# The catalogue: (name, send(srv) -> answer, status, code, pointer, options)
# ---------------------------------------------------------------------------------------
VALID = dumps(scene())
GLB = open(os.path.join(os.environ.get("NSCATTER_SOURCE_DIR", "."), "scenes", "assets",
                        "octahedron.glb"), "rb").read()


def catalogue():
    c = []

    def add(name, send, status, code=None, pointer=None, **opts):
        c.append((name, send, status, code, pointer, opts))

    # --- truncated JSON ------------------------------------------------------------------
    add("truncated object", lambda s: post(s, b'{"camera": {"fov": 30'), 400, "malformed_json")
    add("scene cut in half", lambda s: post(s, VALID[:len(VALID) // 2]), 400, "malformed_json")
    add("empty body", lambda s: post(s, b""), 400, "malformed_json")
    add("cut inside a string", lambda s: post(s, b'{"camera": {"fov": "3'), 400, "malformed_json")
    add("cut inside an escape", lambda s: post(s, b'{"materials": {"w\\u00'), 400,
        "malformed_json")
    add("trailing garbage", lambda s: post(s, VALID + b" {}"), 400, "malformed_json")
    add("validate: truncated", lambda s: post(s, VALID[:-1], "/v1/renders/validate"), 400,
        "malformed_json")
    add("sweep: truncated", lambda s: post(s, b'{"scene": {', "/v1/sweeps"), 400,
        "malformed_json")

    # --- deeply nested and huge JSON -----------------------------------------------------
    add("100000 nested arrays", lambda s: post(s, nested(100000).encode()), 422,
        "invalid_scene", "")
    add("5000 nested objects", lambda s: post(s, nested_objects(5000).encode()), 422,
        "invalid_scene", "")
    add("nested arrays as the camera",
        lambda s: post(s, b'{"camera": ' + nested(3000).encode() + b"}"), 422, "invalid_scene",
        "")
    add("sweep: 100000 nested arrays", lambda s: post(s, nested(100000).encode(), "/v1/sweeps"),
        422, "invalid_sweep", "")
    add("nested under the limit, unknown key",
        lambda s: post(s, VALID[:-1] + b', "deep": ' + nested(1000).encode() + b"}"), 422,
        "invalid_scene",
        "/deep")
    add("10000 objects", lambda s: post(s, dict(scene(), objects=[
        {"shape": "sphere", "center": [0, 0, 0], "radius": 1, "material": "wax"}] * 10000)),
        422, "invalid_scene", "/objects")
    add("300 materials", lambda s: post(s, dict(scene(), materials=dict(
        scene()["materials"], **{f"m{i}": {"type": "diffuse", "reflectance": 0.5}
                                 for i in range(300)}))), 422, "invalid_scene", "/materials")
    add("a 900 kB string", lambda s: post(s, scene(**{"/camera/fov": "x" * 900000})), 422,
        "invalid_scene", "/camera/fov")
    add("a 900 kB number", lambda s: post(s, b'{"camera": {"fov": 1' + b"0" * 900000 + b"}}"),
        422, "invalid_scene", "/camera/fov")
    add("200000-element array", lambda s: post(s, scene(**{"/lights/0/direction": [1] * 200000})),
        422, "invalid_scene", "/lights/0/direction")

    # --- NaN, infinities, 1e400 ----------------------------------------------------------
    add("NaN literal", lambda s: post(s, b'{"camera": {"fov": NaN}}'), 400, "malformed_json")
    add("Infinity literal", lambda s: post(s, b'{"camera": {"fov": -Infinity}}'), 400,
        "malformed_json")
    add("fov 1e400", lambda s: post(s, VALID.replace(b'"fov": 30', b'"fov": 1e400')), 422,
        "invalid_scene", "/camera/fov")
    add("albedo -1e400 in an array", lambda s: post(s, VALID.replace(
        b'"albedo": [0.98', b'"albedo": [-1e400')), 422, "invalid_scene",
        "/materials/wax/albedo/0")
    add("fov 1e-400", lambda s: post(s, VALID.replace(b'"fov": 30', b'"fov": 1e-400')), 422,
        "invalid_scene", "/camera/fov")
    add("fov 3.5e38 (over a float)", lambda s: post(s, scene(**{"/camera/fov": 3.5e38})), 422,
        "invalid_scene", "/camera/fov")
    add("spp 1e30", lambda s: post(s, scene(**{"/render/spp": 1e30})), 422, "invalid_scene",
        "/render/spp")
    add("sweep: g 1e400", lambda s: post(s, b'{"scene": ' + VALID + b', "variants": '
                                         b'[{"/materials/wax/g": 1e400}]}', "/v1/sweeps"),
        422, "invalid_sweep", "/variants/0/~1materials~1wax~1g")

    # --- negative and absurd sizes -------------------------------------------------------
    add("width -16", lambda s: post(s, scene(**{"/camera/width": -16})), 422, "invalid_scene",
        "/camera/width")
    add("width 0", lambda s: post(s, scene(**{"/camera/width": 0})), 422, "invalid_scene",
        "/camera/width")
    add("width 1e9", lambda s: post(s, scene(**{"/camera/width": 1e9})), 422, "invalid_scene",
        "/camera/width")
    add("width 16.5", lambda s: post(s, scene(**{"/camera/width": 16.5})), 422,
        "invalid_scene", "/camera/width")
    add("8192 x 8192", lambda s: post(s, scene(8192, 8192)), 422, "invalid_scene",
        "/camera/height")
    add("spp -1", lambda s: post(s, scene(**{"/render/spp": -1})), 422, "invalid_scene",
        "/render/spp")
    add("radius -1", lambda s: post(s, scene(**{"/objects/0/radius": -1})), 422,
        "invalid_scene", "/objects/0/radius")
    add("max_depth 100000", lambda s: post(s, scene(**{"/render/max_depth": 100000})), 422,
        "invalid_scene", "/render/max_depth")
    add("vrls 1e12", lambda s: post(s, scene(**{"/render/vrls": 1e12})), 422, "invalid_scene",
        "/render/vrls")
    add("deadline_ms -5", lambda s: post(s, scene(**{"/render/deadline_ms": -5})), 422,
        "invalid_scene", "/render/deadline_ms")
    add("async: 4096 x 4096 over --job-bytes",
        lambda s: post(s, scene(4096, 4096), headers={"Prefer": "respond-async"}), 422,
        "limit_exceeded")
    add("sweep: 100000 variants", lambda s: post(s, {"scene": scene(), "variants": [{}] * 100000},
                                                 "/v1/sweeps"), 422, "invalid_sweep",
        "/variants")

    # --- duplicate and unknown keys ------------------------------------------------------
    add("camera twice", lambda s: post(s, VALID[:-1] + b', "camera": {}}'), 422,
        "invalid_scene", "/camera")
    add("fov twice", lambda s: post(s, VALID.replace(b'"fov": 30', b'"fov": 30, "fov": 40')),
        422, "invalid_scene", "/camera/fov")
    add("material twice", lambda s: post(s, VALID.replace(
        b'"floor": {', b'"wax": {"type": "diffuse", "reflectance": 0.5}, "floor": {')), 422,
        "invalid_scene", "/materials/wax")
    add("unknown top-level key", lambda s: post(s, dict(scene(), cmaera={})), 422,
        "invalid_scene", "/cmaera")
    add("unknown render key", lambda s: post(s, scene(**{"/render/turbo": True})), 422,
        "invalid_scene", "/render/turbo")
    add("sweep: scene twice", lambda s: post(s, b'{"scene": ' + VALID + b', "scene": ' + VALID +
                                             b', "variants": [{}]}', "/v1/sweeps"),
        422, "invalid_sweep", "/scene")
    add("sweep: override twice", lambda s: post(s, b'{"scene": ' + VALID + b', "variants": '
                                                b'[{"/materials/wax/g": 0.5, '
                                                b'"/materials/wax/g": 0.6}]}', "/v1/sweeps"),
        422, "invalid_sweep", "/variants/0/~1materials~1wax~1g")
    add("sweep: unknown key", lambda s: post(s, {"scene": scene(), "variants": [{}],
                                                 "bogus": 1}, "/v1/sweeps"),
        422, "invalid_sweep", "/bogus")

    # --- invalid UTF-8 and bad escapes -----------------------------------------------------
    add("invalid UTF-8 in a value", lambda s: post(s, VALID.replace(b'"wax"}', b'"w\xc3\x28x"}')),
        400, "malformed_json")
    add("overlong UTF-8 in a key", lambda s: post(s, VALID.replace(b'"floor": {', b'"\xc0\xaf": {')),
        400, "malformed_json")
    add("lone surrogate escape", lambda s: post(s, VALID.replace(b'"floor": {', b'"\\ud800": {')),
        400, "malformed_json")
    add("NUL escape in a key", lambda s: post(s, VALID.replace(b'"floor": {', b'"fl\\u0000r": {')),
        400, "malformed_json")
    add("UTF-8 BOM first", lambda s: post(s, b"\xef\xbb\xbf" + VALID), 400, "malformed_json")
    add("UTF-16 body", lambda s: post(s, json.dumps(scene()).encode("utf-16")), 400,
        "malformed_json")

    # --- bad base64 and data URIs ----------------------------------------------------------
    add("glb_base64 not base64", lambda s: post(s, with_mesh({"glb_base64": "!!!notbase64"})),
        422, "invalid_scene", "/objects/0/glb_base64")
    add("glb_base64 of garbage", lambda s: post(s, with_mesh(
        {"glb_base64": base64.b64encode(os.urandom(300)).decode()})), 422, "invalid_scene",
        "/objects/0/glb_base64")
    add("glb_base64 cut short", lambda s: post(s, with_mesh(
        {"glb_base64": base64.b64encode(GLB[:len(GLB) // 2]).decode()})), 422, "invalid_scene",
        "/objects/0/glb_base64")
    add("glb_base64 bad padding", lambda s: post(s, with_mesh(
        {"glb_base64": base64.b64encode(GLB).decode()[:-4] + "A=A="})), 422, "invalid_scene",
        "/objects/0/glb_base64")
    add("data URI with bad base64", lambda s: post(s, with_mesh(
        {"uri": "data:model/gltf-binary;base64,%%%%"})), 422, "invalid_scene", "/objects/0/uri")
    add("data URI not base64", lambda s: post(s, with_mesh({"uri": "data:text/plain,hello"})),
        422, "invalid_scene", "/objects/0/uri")
    add("data URI without a comma", lambda s: post(s, with_mesh(
        {"uri": "data:model/gltf-binary;base64"})), 422, "invalid_scene", "/objects/0/uri")
    add("file: URI", lambda s: post(s, with_mesh({"uri": "file:///etc/passwd"})), 422,
        "invalid_scene", "/objects/0/uri")
    add("http: URI", lambda s: post(s, with_mesh({"uri": "http://169.254.169.254/x.glb"})), 422,
        "invalid_scene", "/objects/0/uri")
    add("asset path traversal", lambda s: post(s, with_mesh({"asset": "../../etc/passwd"})), 422,
        "invalid_scene", "/objects/0/asset")
    add("asset hidden name", lambda s: post(s, with_mesh({"asset": ".octahedron.glb"})), 422,
        "invalid_scene", "/objects/0/asset")
    add("asset that is not there", lambda s: post(s, with_mesh({"asset": "nothere.glb"})), 422,
        "invalid_scene", "/objects/0/asset")
    add("two mesh sources", lambda s: post(s, with_mesh(
        {"asset": "octahedron.glb", "glb_base64": base64.b64encode(GLB).decode()})), 422,
        "invalid_scene")

    # --- glTF that names files or reads past its buffers --------------------------------------
    add("glTF buffer names a file", lambda s: post(s, with_mesh(
        {"uri": gltf_uri(buffer_uri="mesh.bin")})), 422, "invalid_scene", "/objects/0/uri")
    add("glTF buffer names /etc/passwd", lambda s: post(s, with_mesh(
        {"uri": gltf_uri(buffer_uri="/etc/passwd")})), 422, "invalid_scene", "/objects/0/uri")
    add("glTF buffer names a URL", lambda s: post(s, with_mesh(
        {"uri": gltf_uri(buffer_uri="http://example.com/a.bin")})), 422, "invalid_scene",
        "/objects/0/uri")
    add("glTF accessor past its buffer", lambda s: post(s, with_mesh(
        {"uri": gltf_uri(count=1000)})), 422, "invalid_scene", "/objects/0/uri")
    add("glTF index out of range", lambda s: post(s, with_mesh(
        {"uri": gltf_uri(indices=(0, 1, 200))})), 422, "invalid_scene", "/objects/0/uri")
    add("glTF index count past its view", lambda s: post(s, with_mesh(
        {"uri": gltf_uri(index_count=3000)})), 422, "invalid_scene", "/objects/0/uri")
    add("glTF JSON nested 200000 deep", lambda s: post(s, with_mesh(
        {"uri": "data:model/gltf+json;base64," + base64.b64encode(
            b'{"asset": {"version": "2.0"}, "extras": ' + nested(200000).encode() + b"}").decode()})),
        422, "invalid_scene", "/objects/0/uri")
    add("GLB chunk length past the end", lambda s: post(s, with_mesh(
        {"glb_base64": base64.b64encode(GLB[:12] + struct.pack("<I", 1 << 30) + GLB[16:]).decode()})),
        422, "invalid_scene", "/objects/0/glb_base64")

    # --- wrong content types -----------------------------------------------------------------
    for ctype in ("text/plain", "application/x-www-form-urlencoded",
                  "multipart/form-data; boundary=x", "application/json; charset=utf-16", None):
        add(f"Content-Type {ctype}", lambda s, ct=ctype: post(s, VALID, ctype=ct), 415,
            "unsupported_media_type")
    add("sweep as text/plain", lambda s: post(s, b"{}", "/v1/sweeps", "text/plain"), 415,
        "unsupported_media_type")

    # --- bodies longer or shorter than Content-Length; framing ---------------------------------
    add("body shorter than Content-Length", lambda s: raw(
        s, raw_post("/v1/renders", VALID[:100], b"Content-Length: %d\r\n" % len(VALID)),
        read_timeout=REQUEST_TIMEOUT_S + 10), 408, "request_timeout", close=True)
    add("body longer than Content-Length", lambda s: raw(
        s, raw_post("/v1/renders", VALID, b"Content-Length: 10\r\n")), 400, "malformed_json")
    add("Content-Length 0", lambda s: raw(
        s, raw_post("/v1/renders", b"", b"Content-Length: 0\r\n")), 400, "malformed_json")
    add("declared over --max-body", lambda s: raw(
        s, raw_post("/v1/renders", b"", b"Content-Length: %d\r\n" % (MAX_BODY + 1))), 413,
        "body_too_large", close=True)
    add("declared 10^20 bytes", lambda s: raw(
        s, raw_post("/v1/renders", b"", b"Content-Length: 100000000000000000000\r\n")), 413,
        mhd=True)
    add("Content-Length -5", lambda s: raw(
        s, raw_post("/v1/renders", b"{}", b"Content-Length: -5\r\n")), 400, mhd=True)
    add("Content-Length not a number", lambda s: raw(
        s, raw_post("/v1/renders", b"{}", b"Content-Length: 12abc\r\n")), 400, mhd=True)
    add("Content-Length and chunked", lambda s: raw(
        s, raw_post("/v1/renders", chunked(VALID),
                    b"Content-Length: 5\r\nTransfer-Encoding: chunked\r\n")), 400, "bad_framing",
        close=True)
    add("two different Content-Lengths", lambda s: raw(
        s, raw_post("/v1/renders", VALID,
                    b"Content-Length: %d\r\nContent-Length: 5\r\n" % len(VALID))), 400,
        "bad_framing", close=True)
    add("Transfer-Encoding gzip", lambda s: raw(
        s, raw_post("/v1/renders", VALID, b"Transfer-Encoding: gzip\r\n"), shut=True), 400,
        "bad_framing", close=True)
    add("Transfer-Encoding chunked, gzip", lambda s: raw(
        s, raw_post("/v1/renders", chunked(VALID), b"Transfer-Encoding: chunked, gzip\r\n")),
        400, "bad_framing", close=True)
    add("chunked over the limit", lambda s: raw(
        s, raw_post("/v1/renders", chunked(b" " * (MAX_BODY + 65536), 65536),
                    b"Transfer-Encoding: chunked\r\n")), 413, "body_too_large")
    add("chunked, one chunk over the limit", lambda s: raw(
        s, raw_post("/v1/sweeps", chunked(b" " * (MAX_BODY + 10), MAX_BODY + 10),
                    b"Transfer-Encoding: chunked\r\n")), 413, "body_too_large")
    add("chunk size not hex", lambda s: raw(
        s, raw_post("/v1/renders", b"zz\r\n{}\r\n0\r\n\r\n", b"Transfer-Encoding: chunked\r\n")),
        400, mhd=True)
    add("chunked valid scene", lambda s: raw(
        s, raw_post("/v1/renders/validate", chunked(dumps(scene(**{"/camera/fov": 400}))),
                    b"Transfer-Encoding: chunked\r\n")), 422, "invalid_scene", "/camera/fov")
    add("header block over 32 KiB", lambda s: raw(
        s, b"GET /readyz HTTP/1.1\r\n" + HEAD + b"X-Long: " + b"a" * 100000 + b"\r\n\r\n"), 431,
        mhd=True)
    # libmicrohttpd closes on a request line without a target, answering nothing (status 0).
    add("request line garbage", lambda s: raw(s, b"GARBAGE\r\n\r\n"), 0, mhd=True)

    # --- methods, paths, queries, headers --------------------------------------------------
    add("unknown method", lambda s: raw(s, b"BREW /v1/renders HTTP/1.1\r\n" + HEAD + b"\r\n"), 405,
        "method_not_allowed")
    add("path traversal", lambda s: raw(s, b"GET /../../etc/passwd HTTP/1.1\r\n" + HEAD + b"\r\n"),
        404, "not_found")
    add("a 4 kB job id", lambda s: s.request("GET", "/v1/renders/" + "a" * 4000), 404,
        "not_found")
    add("bad percent-encoding in the query", lambda s: post(s, VALID, "/v1/renders?format=%zz"),
        400, "bad_query")
    add("unknown query parameter", lambda s: post(s, VALID, "/v1/renders?x=1"), 400, "bad_query")
    add("Accept nothing we make", lambda s: post(s, VALID, headers={"Accept": "text/html"}), 406,
        "not_acceptable")
    add("Last-Event-ID absurd", lambda s: s.request(
        "GET", "/v1/renders/" + "0" * 32 + "/events", headers={"Last-Event-ID": "-1e9"}), 400,
        "bad_query")
    add("Expect 100-continue over the limit", lambda s: raw(
        s, raw_post("/v1/renders", b"", b"Expect: 100-continue\r\nContent-Length: %d\r\n"
                    % (MAX_BODY * 4))), 413, "body_too_large", close=True)
    return c


# ---------------------------------------------------------------------------------------
# Slow and idle clients
# ---------------------------------------------------------------------------------------
def test_slow_headers(t, srv):
    """Headers a byte a second: refused with 408 once --request-timeout has passed, never
    held for ever (each byte would reset a plain inactivity timeout)."""
    data = b"GET /readyz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 200 + b"\r\n\r\n"
    status, headers, body, took, sent = slow(srv, data, 1.0, REQUEST_TIMEOUT_S + 15)
    check_answer(t, "headers a byte a second", (status, headers, body), 408, "request_timeout")
    t.check(REQUEST_TIMEOUT_S - 0.5 <= took <= REQUEST_TIMEOUT_S + 5,
            f"408 about --request-timeout after the first byte: {took:.1f} s, {sent} bytes sent")
    ready(t, srv, "headers a byte a second")


def test_slow_body(t, srv):
    head = raw_post("/v1/renders", b"", b"Content-Length: %d\r\n" % len(VALID))
    with socket.create_connection(("127.0.0.1", srv.port), timeout=5) as s:
        s.sendall(head)
        start = time.monotonic()
        status = None
        for i in range(REQUEST_TIMEOUT_S + 15):
            try:
                s.sendall(VALID[i:i + 1])
            except OSError:
                break
            s.settimeout(1.0)
            try:
                chunk = s.recv(65536)
            except socket.timeout:
                continue
            got = chunk
            s.settimeout(2)
            while not response_complete(got):
                more = s.recv(65536)
                if not more:
                    break
                got += more
            status, headers, body = parse_raw_response(got)
            break
        took = time.monotonic() - start
    if status is None:
        t.check(False, f"body a byte a second: no answer in {took:.1f} s")
        return
    check_answer(t, "body a byte a second", (status, headers, body), 408, "request_timeout")
    t.check(took <= REQUEST_TIMEOUT_S + 5, f"408 within --request-timeout: {took:.1f} s")
    ready(t, srv, "body a byte a second")


def test_idle_connections(t, srv):
    """Hundreds of connections that say nothing: real clients are still answered at once,
    and the idle ones are closed after --idle-timeout."""
    socks = []
    try:
        for _ in range(IDLE_CONNECTIONS):
            socks.append(socket.create_connection(("127.0.0.1", srv.port), timeout=5))
        time.sleep(0.5)
        start = time.monotonic()
        status = srv.request("GET", "/readyz", timeout=10)[0]
        took = time.monotonic() - start
        t.equal(status, 200, f"/readyz with {IDLE_CONNECTIONS} idle connections open")
        t.check(took < 5, f"answered at once: {took:.2f} s")
        status, h, body = post(srv, scene(8, 8))
        t.check(status == 200 and body.startswith(PNG_SIGNATURE),
                f"a render with {IDLE_CONNECTIONS} idle connections open: {status}")
        # Every idle connection is closed by the server within the idle timeout (+ slack).
        deadline = time.monotonic() + IDLE_TIMEOUT_S + 10
        open_ = list(socks)
        while open_ and time.monotonic() < deadline:
            still = []
            for s in open_:
                s.settimeout(0.01)
                try:
                    if s.recv(4096) == b"":
                        continue
                    still.append(s)  # a byte came: read on (408 then the close)
                except socket.timeout:
                    still.append(s)
                except OSError:
                    continue
            open_ = still
            time.sleep(0.2)
        t.equal(len(open_), 0, f"every idle connection closed within {IDLE_TIMEOUT_S + 10} s")
    finally:
        for s in socks:
            s.close()
    ready(t, srv, "hundreds of idle connections")


def test_idle_eviction(t):
    """More idle connections than --max-connections: the guard closes the oldest idle ones
    to make room, so a real client still gets in quickly (no 60 s wait for a free slot)."""
    with Server("--max-connections", "32", "--access-log", "off") as small:
        socks = []
        try:
            for _ in range(100):
                socks.append(socket.create_connection(("127.0.0.1", small.port), timeout=5))
            time.sleep(1.0)
            start = time.monotonic()
            status = small.request("GET", "/readyz", timeout=15)[0]
            took = time.monotonic() - start
            t.equal(status, 200, "/readyz with 100 idle connections and --max-connections 32")
            t.check(took < 5, f"answered within seconds: {took:.2f} s")
            print(f"  /readyz behind 100 idle connections: {took:.2f} s", file=sys.stderr)
            status, h, body = post(small, scene(8, 8))
            t.equal(status, 200, "a render gets through too")
            info = json.loads(small.request("GET", "/v1/info")[2])
            t.equal(info.get("limits", {}).get("max_connections"), 32, "limits.max_connections")
        finally:
            for s in socks:
                s.close()


def test_idle_and_slow_flood(t, srv):
    """Many slow-header clients at once (a slowloris): /readyz is still answered, and each of
    them gets its 408."""
    results = []
    lock = threading.Lock()

    def one():
        got = slow(srv, b"GET /readyz HTTP/1.1\r\nHost: x\r\nX-A: " + b"b" * 100, 0.5,
                   REQUEST_TIMEOUT_S + 15)
        with lock:
            results.append(got[0])

    threads = [threading.Thread(target=one) for _ in range(40)]
    for th in threads:
        th.start()
    time.sleep(1.0)
    start = time.monotonic()
    status = srv.request("GET", "/readyz", timeout=10)[0]
    t.equal(status, 200, "/readyz during a slowloris")
    t.check(time.monotonic() - start < 5, "answered at once")
    for th in threads:
        th.join(REQUEST_TIMEOUT_S + 20)
    t.equal(sorted(set(results)), [408], f"every slow client got 408 ({len(results)} answers)")
    ready(t, srv, "a slowloris")


# ---------------------------------------------------------------------------------------
def test_catalogue(t, srv):
    cases = catalogue()
    print(f"{len(cases)} cases", file=sys.stderr, flush=True)
    t.check(len(cases) >= 50, f"at least 50 cases: {len(cases)}")
    names = [c[0] for c in cases]
    t.equal(len(set(names)), len(names), "case names are distinct")
    problem_json = sum(1 for c in cases if not c[5].get("mhd"))
    t.check(problem_json >= 50, f"at least 50 answered with problem+json: {problem_json}")
    for name, send, status, code, pointer, opts in cases:
        t.current = f"test_catalogue: {name}"
        start = time.monotonic()
        try:
            got = send(srv)
        except Exception as e:  # one broken case must not end the catalogue
            t.check(False, f"{name}: {type(e).__name__}: {e}")
            got = None
        if got is not None:
            check_answer(t, name, got, status, code, pointer, **opts)
        took = time.monotonic() - start
        if took > 5:
            print(f"  {name}: {took:.1f} s", file=sys.stderr, flush=True)
        ready(t, srv, name)


def test_still_renders(t, srv):
    status, h, body = post(srv, scene(16, 16))
    t.check(status == 200 and body.startswith(PNG_SIGNATURE), f"a tiny scene renders: {status}")
    info = json.loads(srv.request("GET", "/v1/info")[2])
    t.equal(info.get("device", {}).get("live_buffers"), 0, "no device buffer left behind")
    t.equal(info.get("queue_length"), 0, "nothing left admitted")


def main():
    t = Checks()
    assets = os.path.join(os.environ.get("NSCATTER_SOURCE_DIR", "."), "scenes", "assets")
    with Server("--max-body", str(MAX_BODY), "--queue", "2", "--assets", assets,
                "--job-bytes", str(64 << 20), "--request-timeout", str(REQUEST_TIMEOUT_S),
                "--idle-timeout", str(IDLE_TIMEOUT_S), "--access-log", "off") as srv:
        for test in (test_catalogue, test_slow_headers, test_slow_body, test_idle_connections,
                     test_idle_and_slow_flood, test_still_renders):
            t.run(test, srv)
        t.current = "end"
        info = json.loads(srv.request("GET", "/v1/info")[2]).get("limits", {})
        t.equal((info.get("request_timeout_s"), info.get("idle_timeout_s"),
                 info.get("max_connections")), (REQUEST_TIMEOUT_S, IDLE_TIMEOUT_S, 512),
                "the connection limits in /v1/info")
        code = srv.stop()
        t.check(srv.exited_cleanly(code), f"clean exit on SIGTERM (status {code}, own leaks "
                f"{srv.own_leaks()[:2]})")
        if t.failed:
            print(srv.log_text()[-3000:], file=sys.stderr)
    t.run(test_idle_eviction)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
