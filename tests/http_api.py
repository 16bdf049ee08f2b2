"""HTTP API against the real `nscatter serve` on a free loopback port: images, timings,
content negotiation, every error status with its problem+json body, hostile and broken
requests, then many sequential and a few concurrent requests: the server must still answer
/livez at the end and exit cleanly on SIGTERM."""
import json
import os
import random
import socket
import sys
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import (EXR_MAGIC, PNG_SIGNATURE, Checks, Server, environment_scene,  # noqa: E402
                         exr_channels, exr_header, parse_raw_response, png_chunks,
                         png_decode_rgb8, png_texts, problem, server_timing, small_scene, srgb8)

MAX_BODY = 256 * 1024  # small, so the over-limit bodies below stay cheap to send


def check_problem(t, status, headers, body, want_status, want_code=None):
    t.equal(status, want_status, "status")
    t.check(headers.get("content-type", "").startswith("application/problem+json"),
            f"problem content type, got {headers.get('content-type')!r}")
    try:
        p = problem(body)
    except ValueError:
        t.check(False, f"problem body is JSON: {body[:200]!r}")
        return {}
    for key in ("type", "title", "status", "detail", "code", "errors"):
        t.check(key in p, f"problem has '{key}': {p}")
    t.equal(p.get("status"), want_status, "problem status member")
    t.check(isinstance(p.get("errors"), list), "errors is a list")
    if want_code:
        t.equal(p.get("code"), want_code, "problem code")
    return p


# ---------------------------------------------------------------------------------------
# Health and info
# ---------------------------------------------------------------------------------------
def test_health_and_info(t, srv):
    status, headers, body = srv.request("GET", "/livez")
    t.equal(status, 200, "/livez")
    status, headers, body = srv.request("GET", "/readyz")
    t.equal(status, 200, "/readyz once the context is made")
    status, headers, body = srv.request("GET", "/v1/info")
    t.equal(status, 200, "/v1/info")
    t.check(headers.get("content-type", "").startswith("application/json"), "info is JSON")
    info = json.loads(body)
    t.check(info.get("version"), "info names the version")
    t.check(info.get("device", {}).get("name"), "info names the device")
    t.check("driver" in info.get("device", {}), "info names the driver")
    t.check(isinstance(info.get("device", {}).get("is_cpu"), bool), "info says is_cpu")
    limits = info.get("limits", {})
    t.equal(limits.get("max_body_bytes"), MAX_BODY, "max body limit as configured")
    t.equal(limits.get("queue_capacity"), 2, "queue capacity as configured")
    t.check(limits.get("max_image_side", 0) > 0 and limits.get("max_spp", 0) > 0, "image limits")
    names = [m.get("name") for m in info.get("methods", [])]
    t.check("nn" in names, f"methods listed: {names}")
    nn = next((m for m in info.get("methods", []) if m.get("name") == "nn"), {})
    t.check("surface" in nn.get("components", []), "nn renders the surface component")
    status, headers, body = srv.request("HEAD", "/livez")
    t.equal(status, 200, "HEAD /livez")
    t.equal(body, b"", "HEAD has no body")


# ---------------------------------------------------------------------------------------
# Images
# ---------------------------------------------------------------------------------------
def test_png_render(t, srv):
    scene = small_scene(48, 32)
    status, headers, body = srv.render(scene)
    t.equal(status, 200, f"render PNG ({body[:300]!r})")
    if status != 200:
        return
    t.equal(headers.get("content-type"), "image/png", "content type")
    t.check(body.startswith(PNG_SIGNATURE), "PNG signature")
    chunks = png_chunks(body)  # raises on a bad CRC
    t.equal(chunks[0][0], "IHDR", "IHDR first")
    width, height, _, _, _, _, _ = __import__("struct").unpack(">IIBBBBB", chunks[0][1])
    t.equal((width, height), (48, 32), "IHDR size is the scene's camera size")
    texts = png_texts(body)
    t.check("nscatter:render" in texts, f"render parameters as tEXt: {list(texts)}")
    params = json.loads(texts.get("nscatter:render", "{}"))
    t.equal(params.get("width"), 48, "tEXt render width")
    t.equal(params.get("method"), "nn", "tEXt render method")
    t.equal(params.get("boundary"), "walks", "tEXt render boundary (nn's default)")
    t.check("nscatter:timings_ms" in texts, "timings as tEXt")
    t.check("nscatter:device" in texts, "device as tEXt")
    timing = server_timing(headers.get("server-timing", ""))
    for stage in ("parse", "ray_pass", "encode"):
        t.check(stage in timing, f"Server-Timing has {stage}: {headers.get('server-timing')}")
    t.check(len(timing) >= 4, f"one metric per stage: {timing}")
    t.check(all(v >= 0 for v in timing.values()), "durations are non-negative")
    info = json.loads(srv.request("GET", "/v1/info")[2])
    t.equal(headers.get("x-nscatter-device"), info["device"]["name"], "device header")
    t.equal(texts.get("nscatter:device"), info["device"]["name"], "device tEXt")


def test_png_pixels_are_srgb_of_radiance(t, srv):
    """A uniform environment and nothing else: every pixel is sRGB(L * 2^exposure)."""
    for radiance, exposure in (([0.25, 0.5, 0.05], 0.0), ([0.125, 0.02, 2.0], 1.0)):
        status, headers, body = srv.render(environment_scene(radiance, exposure))
        t.equal(status, 200, f"environment render ({body[:300]!r})")
        if status != 200:
            continue
        width, height, rows = png_decode_rgb8(body)
        want = bytes(srgb8(c * 2 ** exposure) for c in radiance)
        bad = sum(1 for row in rows for x in range(width) if row[3 * x:3 * x + 3] != want)
        t.equal(bad, 0, f"pixels off sRGB({radiance} x 2^{exposure}) = {list(want)}")


def test_exr_render(t, srv):
    for accept, path, want_type in (("image/x-exr", "/v1/renders", 2),
                                    ("image/x-exr", "/v1/renders?format=half", 1),
                                    ("image/x-exr; format=half", "/v1/renders", 1),
                                    ("image/png;q=0.5, image/x-exr", "/v1/renders", 2)):
        status, headers, body = srv.render(small_scene(24, 16), accept=accept, path=path)
        t.equal(status, 200, f"EXR render with Accept {accept!r} {path}: {body[:300]!r}")
        if status != 200:
            continue
        t.equal(headers.get("content-type"), "image/x-exr", "EXR content type")
        t.equal(body[:4], EXR_MAGIC, "EXR magic 76 2f 31 01")
        channels = exr_channels(body)
        t.equal(sorted(channels), ["B", "G", "R"], "RGB channels")
        t.check(all(v == want_type for v in channels.values()),
                f"pixel type {want_type} (1 half, 2 float): {channels}")
        attrs = exr_header(body)
        t.check("nscatter:render" in attrs, f"render parameters attribute: {list(attrs)}")
        t.check("ray_pass" in server_timing(headers.get("server-timing", "")), "Server-Timing")


def test_accept_defaults_to_png(t, srv):
    for accept in (None, "", "*/*", "image/*", "image/webp, */*;q=0.1", "IMAGE/PNG"):
        status, headers, body = srv.render(small_scene(8, 8), accept=accept)
        t.equal(status, 200, f"Accept {accept!r}")
        t.equal(headers.get("content-type"), "image/png", f"Accept {accept!r} gives PNG")


# ---------------------------------------------------------------------------------------
# Error statuses
# ---------------------------------------------------------------------------------------
def test_malformed_json_400(t, srv):
    body = b'{\n  "camera": {"fov": 30,\n    "width": ,\n  }\n}'
    status, headers, data = srv.render(body)
    p = check_problem(t, status, headers, data, 400, "malformed_json")
    t.equal(p.get("line"), 3, "syntax error line")
    t.check(isinstance(p.get("column"), int) and p.get("column") > 0, "syntax error column")
    t.check("line 3" in p.get("detail", ""), f"detail names the line: {p.get('detail')}")
    t.check(len(p.get("errors", [])) == 1 and "detail" in p["errors"][0]
            and "pointer" in p["errors"][0], "errors list with pointer and detail")


def test_invalid_scene_422(t, srv):
    scene = small_scene()
    scene["materials"]["wax"]["g"] = 2
    status, headers, data = srv.render(scene)
    p = check_problem(t, status, headers, data, 422, "invalid_scene")
    pointers = [e.get("pointer") for e in p.get("errors", [])]
    t.check("/materials/wax/g" in pointers, f"pointer to /materials/wax/g: {pointers}")
    scene = small_scene()
    scene["objects"][0]["material"] = "marble"
    scene["camera"]["fov"] = 200
    status, headers, data = srv.render(scene)
    p = check_problem(t, status, headers, data, 422, "invalid_scene")
    pointers = [e.get("pointer") for e in p.get("errors", [])]
    t.check("/objects/0/material" in pointers, f"unknown material pointer: {pointers}")
    t.check("/camera/fov" in pointers, f"fov pointer: {pointers}")


def test_body_too_large_413(t, srv):
    # From Content-Length alone: the answer must come without a byte of body sent.
    head = (b"POST /v1/renders HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            b"Content-Length: 100000000000\r\n\r\n")
    raw = srv.raw(head, read_timeout=20)
    status, headers, data = parse_raw_response(raw)
    check_problem(t, status, headers, data, 413, "body_too_large")
    # Declared just over the limit.
    head = (b"POST /v1/renders HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            b"Content-Length: %d\r\n\r\n" % (MAX_BODY + 1))
    status, headers, data = parse_raw_response(srv.raw(head, read_timeout=20))
    check_problem(t, status, headers, data, 413, "body_too_large")
    # Chunked, no length: decided when the body passes the limit, answered after the body.
    chunk = b"x" * 65536
    body = b"".join(b"%x\r\n%s\r\n" % (len(chunk), chunk) for _ in range(MAX_BODY // 65536 + 2))
    req = (b"POST /v1/renders HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
           b"Transfer-Encoding: chunked\r\n\r\n" + body + b"0\r\n\r\n")
    status, headers, data = parse_raw_response(srv.raw(req, read_timeout=30))
    check_problem(t, status, headers, data, 413, "body_too_large")


def test_content_type_415(t, srv):
    body = json.dumps(small_scene(8, 8)).encode()
    for ctype in ("text/plain", "application/xml", "application/json; charset=latin-1",
                  "application/jsonx", None):
        headers = {"Content-Type": ctype} if ctype else {}
        status, h, data = srv.request("POST", "/v1/renders", body, headers)
        check_problem(t, status, h, data, 415, "unsupported_media_type")
    status, h, data = srv.request("POST", "/v1/renders", body,
                                  {"Content-Type": "Application/JSON; Charset=UTF-8"})
    t.equal(status, 200, "media type and charset are case-insensitive")


def test_not_acceptable_406(t, srv):
    for accept in ("text/html", "image/png;q=0", "application/json", "image/x-exr; format=int"):
        status, h, data = srv.render(small_scene(8, 8), accept=accept)
        check_problem(t, status, h, data, 406, "not_acceptable")


def test_bad_query_400(t, srv):
    for path in ("/v1/renders?format=quarter", "/v1/renders?size=2", "/v1/renders?format=half"):
        status, h, data = srv.render(small_scene(8, 8), path=path)  # PNG selected: half is wrong
        check_problem(t, status, h, data, 400, "bad_query")


def test_not_found_404_and_method_405(t, srv):
    for path in ("/nope", "/v1/nope", "/v1/renders/1", "/v2/info", "/../../etc/passwd",
                 "/missing.js", "/web/index.html"):
        status, h, data = srv.request("GET", path)
        check_problem(t, status, h, data, 404, "not_found")
    for path in ("/v1/renders", "/v1/sweeps"):
        status, h, data = srv.request("PUT", path, b"{}", {"Content-Type": "application/json"})
        check_problem(t, status, h, data, 405, "method_not_allowed")
        t.equal(h.get("allow"), "GET, HEAD, POST", f"Allow on {path}")
    for path in ("/v1/renders/" + "0" * 32, "/v1/sweeps/" + "0" * 32):
        status, h, data = srv.request("POST", path, b"{}", {"Content-Type": "application/json"})
        check_problem(t, status, h, data, 405, "method_not_allowed")
        t.equal(h.get("allow"), "GET, HEAD, DELETE", f"Allow on {path}")
    status, h, data = srv.request("DELETE", "/v1/renders/" + "0" * 32 + "/image")
    check_problem(t, status, h, data, 405, "method_not_allowed")
    t.equal(h.get("allow"), "GET, HEAD", "Allow on a job's image")
    for method in ("PUT", "DELETE", "POST"):
        status, h, data = srv.request(method, "/livez", b"{}", {"Content-Type": "application/json"})
        check_problem(t, status, h, data, 405, "method_not_allowed")
        t.equal(h.get("allow"), "GET, HEAD", f"Allow on /livez for {method}")


def test_web_page(t, srv):
    status, h, data = srv.request("GET", "/")
    t.equal(status, 200, "GET /")
    t.check(h.get("content-type", "").startswith("text/html"), "index is HTML")
    t.check(b"<html" in data.lower(), "index is the page")
    status, h, data2 = srv.request("GET", "/index.html")
    t.equal((status, data2), (200, data), "/index.html is the same page")
    for name, ctype in (("app.js", "text/javascript"), ("style.css", "text/css")):
        status, h, data = srv.request("GET", "/" + name)
        if os.path.exists(os.path.join(os.environ.get("NSCATTER_SOURCE_DIR", "."), "web", name)):
            t.equal(status, 200, f"GET /{name}")
            t.check(h.get("content-type", "").startswith(ctype), f"{name} is {ctype}")
            t.check(len(data) > 0, f"{name} has content")
    status, h, data = srv.request("GET", "/eslint.config.js")
    t.equal(status, 404, "tool configuration is not served")


# ---------------------------------------------------------------------------------------
# Hostile input
# ---------------------------------------------------------------------------------------
def test_garbage_bodies(t, srv):
    rng = random.Random(7)
    bodies = [b"", b"\0" * 100, bytes(rng.randrange(256) for _ in range(5000)),
              b"\xff\xfe{\"camera\": 1}", b'{"camera": "\xc3\x28"}', b"[" * 100000 + b"]" * 100000,
              b'{"a": ' + b"9" * 10000 + b"}", b"nul", b'{"camera": {}}' * 3,
              json.dumps([small_scene()]).encode(), b'"just a string"',
              b'{"camera": {"fov": 1e999}}', b'{"camera": NaN}',
              json.dumps({"objects": [{"shape": "mesh", "glb_base64": "!!!notbase64"}]}).encode()]
    for body in bodies:
        status, h, data = srv.render(body)
        t.check(status in (400, 422), f"garbage body gets 400/422, got {status} for {body[:40]!r}")
        t.check(h.get("content-type", "").startswith("application/problem+json"),
                "garbage body gets problem+json")
    t.check(srv.request("GET", "/livez")[0] == 200, "alive after garbage bodies")


def test_random_headers(t, srv):
    """Random Accept and Content-Type values: a definite 2xx/4xx answer, never a crash."""
    rng = random.Random(11)
    alphabet = "abcdefghijklmnopqrstuvwxyz/*;=,.-+ \t\"'0123456789qQ"
    body = json.dumps(small_scene(4, 4)).encode()
    seeds = ["image/png", "image/x-exr", "application/json", "*/*", ";q=", "format=half",
             "charset=utf-8"]
    statuses = set()
    for i in range(150):
        parts = [rng.choice(seeds) if rng.random() < 0.5 else
                 "".join(rng.choice(alphabet) for _ in range(rng.randrange(1, 20)))
                 for _ in range(rng.randrange(1, 5))]
        value = rng.choice([",", ";", " "]).join(parts).strip()
        headers = {"Content-Type": "application/json", "Accept": value}
        if i % 2:
            headers = {"Content-Type": value}
        status, h, data = srv.request("POST", "/v1/renders", body, headers)
        statuses.add(status)
        t.check(status in (200, 400, 406, 415), f"status {status} for headers {headers}")
    t.check(len(statuses) >= 3, f"random headers reach several outcomes: {sorted(statuses)}")
    t.equal(srv.request("GET", "/livez")[0], 200, "alive after random headers")


def test_broken_requests(t, srv):
    cases = [
        # headers promise a body that never fully arrives, then the client goes away
        b"POST /v1/renders HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
        b"Content-Length: 1000\r\n\r\n{\"camera\":",
        b"POST /v1/ren",
        b"GARBAGE\r\n\r\n",
        b"GET / HTTP/9.9\r\n\r\n",
        b"POST /v1/renders HTTP/1.1\r\nHost: x\r\nContent-Length: -5\r\n\r\n",
        b"POST /v1/renders HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n"
        b"Content-Type: application/json\r\n\r\nzz\r\n",
        b"GET /livez HTTP/1.1\r\nHost: x\r\n" + b"X-Long: " + b"a" * 200000 + b"\r\n\r\n",
        b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03" + bytes(200),  # a TLS ClientHello
    ]
    for data in cases:
        try:
            srv.raw(data, read_timeout=5, close_write=True)
        except OSError:
            pass  # the server may reset a connection it refuses; it must not die
        t.check(srv.alive(), f"server alive after {data[:30]!r}")
    # A connection that opens and says nothing, closed by the client.
    s = socket.create_connection(("127.0.0.1", srv.port), timeout=5)
    s.close()
    t.equal(srv.request("GET", "/livez")[0], 200, "livez after broken requests")


# ---------------------------------------------------------------------------------------
# Load
# ---------------------------------------------------------------------------------------
def test_many_sequential_on_one_connection(t, srv):
    conn = srv.connection()
    body = json.dumps(small_scene(16, 16)).encode()
    ok = 0
    try:
        for i in range(40):
            if i % 2:
                conn.request("POST", "/v1/renders", body, {"Content-Type": "application/json"})
            else:
                conn.request("GET", "/v1/info")
            resp = conn.getresponse()
            resp.read()
            ok += resp.status == 200
    finally:
        conn.close()
    t.equal(ok, 40, "40 keep-alive requests answered 200")
    statuses = [srv.render(b"{bad")[0] for _ in range(20)]
    t.equal(statuses, [400] * 20, "20 malformed requests answered 400")


def test_a_few_concurrent(t, srv):
    results = []
    lock = threading.Lock()

    def worker(n):
        for _ in range(3):
            status, h, data = srv.render(small_scene(32, 24), timeout=300)
            with lock:
                results.append((status, h.get("retry-after"), data[:8]))

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(6)]
    for th in threads:
        th.start()
    for th in threads:
        th.join(400)
    t.equal(len(results), 18, "every concurrent request answered")
    for status, retry, head in results:
        t.check(status in (200, 503), f"200 or 503 under load, got {status}")
        if status == 200:
            t.equal(head, PNG_SIGNATURE, "a PNG")
        else:
            t.check(retry is not None and retry.isdigit() and int(retry) >= 1,
                    f"503 carries Retry-After, got {retry!r}")
    t.check(any(s == 200 for s, _, _ in results), "some concurrent renders succeed")


def main():
    t = Checks()
    with Server("--queue", "2", "--max-body", str(MAX_BODY)) as srv:
        for test in (test_health_and_info, test_png_render, test_png_pixels_are_srgb_of_radiance,
                     test_exr_render, test_accept_defaults_to_png, test_malformed_json_400,
                     test_invalid_scene_422, test_body_too_large_413, test_content_type_415,
                     test_not_acceptable_406, test_bad_query_400,
                     test_not_found_404_and_method_405, test_web_page, test_garbage_bodies,
                     test_random_headers, test_broken_requests, test_many_sequential_on_one_connection,
                     test_a_few_concurrent):
            t.run(test, srv)
        t.current = "end"
        t.equal(srv.request("GET", "/livez")[0], 200, "/livez still answers at the end")
        code = srv.stop()
        t.check(srv.exited_cleanly(code), f"clean exit on SIGTERM (status {code}, own leaks "
                f"{srv.own_leaks()[:2]})")
        if t.failed:
            print(srv.log_text()[-4000:], file=sys.stderr)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
