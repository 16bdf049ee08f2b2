"""What an operator relies on (issue 18): X-Request-Id on every answer and in problem bodies,
the JSON access log, POST /v1/renders/validate, GET /v1/materials, 503 before a body is read
when the queue is full, and a stop signal that turns /readyz and new renders to 503 while an
admitted render is still answered.

Python standard library only; a real `nscatter serve` on loopback (nstest_http.Server)."""
import json
import os
import re
import signal
import socket
import sys
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import Checks, Server, problem, small_scene  # noqa: E402
from nstest_jobs import PtRate, check_problem, post_async, wait_state  # noqa: E402

HEX32 = re.compile(r"^[0-9a-f]{32}$")


def job_path(jid, tail=""):
    return f"/v1/renders/{jid}{tail}"


def json_post(srv, path, body, headers=None):
    h = {"Content-Type": "application/json"}
    h.update(headers or {})
    return srv.request("POST", path, json.dumps(body).encode(), h)


def test_request_ids(t, srv):
    status, h, _ = srv.request("GET", "/livez")
    t.check(HEX32.match(h.get("x-request-id", "")), f"a generated id: {h.get('x-request-id')}")
    ids = {srv.request("GET", "/livez")[1].get("x-request-id") for _ in range(5)}
    t.equal(len(ids), 5, "a new id per request")
    status, h, _ = srv.request("GET", "/livez", headers={"X-Request-Id": "trace-42.a:b_c"})
    t.equal(h.get("x-request-id"), "trace-42.a:b_c", "a client's id is echoed")
    for bad in ("has space", "x" * 129, "semi;colon", "é"):
        status, h, _ = srv.request("GET", "/livez", headers={"X-Request-Id": bad})
        t.check(HEX32.match(h.get("x-request-id", "")), f"{bad[:20]!r} replaced by a fresh id")
    status, h, body = srv.request("GET", "/nope", headers={"X-Request-Id": "p-1"})
    t.equal((status, problem(body).get("request_id")), (404, "p-1"), "the id in a problem body")
    status, h, body = json_post(srv, "/v1/renders", {"camera": 1}, {"X-Request-Id": "p-2"})
    t.equal((status, problem(body).get("request_id"), h.get("x-request-id")), (422, "p-2", "p-2"),
            "the id of a 422")
    status, h, _ = srv.render(small_scene(8, 8))
    t.check(status == 200 and HEX32.match(h.get("x-request-id", "")), "an image has one too")


def test_access_log(t, srv):
    marker = "log-check-1"
    srv.request("GET", "/v1/info", headers={"X-Request-Id": marker})
    srv.request("GET", "/v1/renders/" + "0" * 32, headers={"X-Request-Id": marker + "b"})
    srv.render(small_scene(8, 8))
    deadline = time.monotonic() + 5
    lines = []
    while time.monotonic() < deadline:
        lines = []
        for text in srv.log_text().splitlines():
            if text.startswith("{"):
                try:
                    lines.append(json.loads(text))
                except ValueError:
                    t.check(False, f"an access log line is JSON: {text[:200]}")
        if any(e.get("request_id") == marker + "b" for e in lines):
            break
        time.sleep(0.1)
    by_id = {e.get("request_id"): e for e in lines}
    info = by_id.get(marker, {})
    t.equal((info.get("method"), info.get("route"), info.get("status")), ("GET", "/v1/info", 200),
            "the info request is logged")
    t.check(isinstance(info.get("bytes"), int) and info["bytes"] > 0, "with its size")
    t.check(isinstance(info.get("duration_ms"), float), "and its duration")
    gone = by_id.get(marker + "b", {})
    t.equal((gone.get("route"), gone.get("status")), ("/v1/renders/{id}", 404),
            "a job route is logged as its template, not its id")
    renders = [e for e in lines if e.get("route") == "/v1/renders" and e.get("status") == 200]
    t.check(renders and "ray_pass" in (renders[-1].get("stages") or {}),
            "a render's line has its stages")
    with Server("--access-log", "off") as quiet:
        quiet.request("GET", "/livez", headers={"X-Request-Id": "silent"})
        time.sleep(0.3)
        t.check("silent" not in quiet.log_text(), "--access-log off: no line")


def test_validate(t, srv):
    scene = small_scene(8, 8)
    status, h, body = json_post(srv, "/v1/renders/validate", scene)
    t.equal((status, body), (204, b""), "a valid scene: 204, no body")
    bad = json.loads(json.dumps(scene))
    bad["camera"]["fov"] = 400
    v_status, _, v_body = json_post(srv, "/v1/renders/validate", bad)
    r_status, _, r_body = json_post(srv, "/v1/renders", bad)
    v, r = problem(v_body), problem(r_body)
    t.equal(v_status, 422, "an invalid scene: 422")
    t.equal((v.get("code"), v.get("errors")), (r.get("code"), r.get("errors")),
            "the same problem a render answers")
    status, h, body = srv.request("POST", "/v1/renders/validate", b"{", {"Content-Type": "application/json"})
    check_problem(t, status, h, body, 400, "malformed_json", "validate: broken JSON")
    status, h, body = srv.request("POST", "/v1/renders/validate", b"{}", {"Content-Type": "text/plain"})
    check_problem(t, status, h, body, 415, "unsupported_media_type", "validate: wrong type")
    status, h, body = srv.request("GET", "/v1/renders/validate")
    check_problem(t, status, h, body, 405, "method_not_allowed", "GET validate")
    t.equal(h.get("allow"), "POST", "Allow on validate")
    before = json.loads(srv.request("GET", "/v1/info")[2])
    t.equal((before.get("queue_length"), before.get("jobs", {}).get("done")), (0, 0),
            "validating renders nothing and stores nothing")


def test_materials(t, srv):
    status, h, body = srv.request("GET", "/v1/materials")
    t.equal(status, 200, "GET /v1/materials")
    materials = {m.get("name"): m for m in json.loads(body).get("materials", [])}
    t.equal(sorted(materials), sorted(["bumpy_sphere", "candle", "dragon", "milk", "oil", "lucy",
                                       "cloud"]), "the paper's presets")
    candle = materials.get("candle", {})
    t.equal((candle.get("albedo"), candle.get("mfp"), candle.get("g"), candle.get("ior")),
            ([0.98, 0.962, 0.75], [0.65, 0.63, 0.59], 0.8, 1.45), "candle's parameters")
    # Every preset the list names renders as a material.
    scene = small_scene(8, 8)
    for name in materials:
        s = json.loads(json.dumps(scene))
        s["materials"]["probe"] = {"type": "medium", "preset": name}
        status, _, body = json_post(srv, "/v1/renders/validate", s)
        t.equal(status, 204, f"preset {name} is accepted ({body[:200]!r})")
    status, h, body = srv.request("DELETE", "/v1/materials")
    check_problem(t, status, h, body, 405, "method_not_allowed", "DELETE materials")


def test_full_queue_before_the_body(t):
    """With the queue full, a render is refused from its headers: the client need not send
    (here: never sends) the body it announced."""
    with Server("--queue", "1") as srv:
        rate = PtRate(srv)
        scene, _ = rate.scene(30)
        status, headers, job, raw = post_async(srv, scene)
        if not t.equal(status, 202, "a long job fills the queue"):
            return
        jid = job.get("id")
        try:
            wait_state(srv, job_path(jid), ("running", "done", "failed", "cancelled"), 60)
            sock = socket.create_connection(("127.0.0.1", srv.port), timeout=10)
            sock.sendall(b"POST /v1/renders HTTP/1.1\r\nHost: x\r\nContent-Type: application/json"
                         b"\r\nContent-Length: 1000000\r\n\r\n")
            start = time.monotonic()
            data = b""
            while b"\r\n\r\n" not in data:
                chunk = sock.recv(4096)
                if not chunk:
                    break
                data += chunk
            took = time.monotonic() - start
            sock.close()
            t.check(data.startswith(b"HTTP/1.1 503"), f"503 without the body: {data[:60]!r}")
            t.check(b"Retry-After:" in data, "with Retry-After")
            t.check(took < 5, f"at once: {took:.2f} s")
        finally:
            srv.request("DELETE", job_path(jid))
            wait_state(srv, job_path(jid), ("cancelled", "done", "failed"), 30)


def test_stop_signal(t):
    """SIGTERM: /readyz and new renders answer 503 at once on a kept-alive connection, the
    asynchronous job running at that moment is cancelled at its next submission (its result
    would die with the process) rather than waited for, the synchronous render admitted
    behind it is still rendered and answered, and the process exits 0 long before the
    cancelled job would have finished."""
    with Server() as srv:
        rate = PtRate(srv)
        long_scene, long_expected = rate.scene(60)
        scene, expected = rate.scene(6)
        keep = srv.connection()
        keep.request("GET", "/livez")
        t.equal(keep.getresponse().read() and 200, 200, "a kept-alive connection")
        status, _, job, _ = post_async(srv, long_scene)
        if not t.equal(status, 202, "a long asynchronous job"):
            return
        wait_state(srv, job_path(job["id"]), ("running",), 30)
        answer = {}

        def render():
            answer["status"] = srv.render(scene, timeout=120 + 10 * expected)[0]

        worker = threading.Thread(target=render)
        worker.start()
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            if json.loads(srv.request("GET", "/v1/info")[2]).get("queue_length") == 2:
                break
            time.sleep(0.05)
        signalled = time.monotonic()
        srv.proc.send_signal(signal.SIGTERM)
        time.sleep(0.3)
        keep.request("GET", "/readyz")
        resp = keep.getresponse()
        body = resp.read()
        t.equal((resp.status, problem(body).get("code")), (503, "shutting_down"),
                "/readyz: 503 once stopping")
        # The running asynchronous job: cancelled, not waited for.
        state = None
        until = time.monotonic() + 15
        while time.monotonic() < until:
            keep.request("GET", job_path(job["id"]))
            resp = keep.getresponse()
            state = json.loads(resp.read() or b"{}").get("state")
            if state in ("cancelled", "done", "failed"):
                break
            time.sleep(0.1)
        t.equal(state, "cancelled", "the running asynchronous job is cancelled by the stop")
        # Last: the refusal closes the connection (the body is not read).
        keep.request("POST", "/v1/renders", json.dumps(small_scene(8, 8)),
                     {"Content-Type": "application/json"})
        resp = keep.getresponse()
        body = resp.read()
        t.equal((resp.status, problem(body).get("code")), (503, "shutting_down"),
                "a new render: 503")
        t.check(resp.getheader("Retry-After"), "with Retry-After")
        keep.close()
        worker.join(120 + 10 * expected)
        t.equal(answer.get("status"), 200, "the admitted synchronous render is answered")
        code = srv.proc.wait(60)
        t.equal(code, 0, "exit 0")
        took = time.monotonic() - signalled
        t.check(took < long_expected / 2,
                f"exit {took:.1f} s after SIGTERM, not after the ~{long_expected:.0f} s job")


def test_deadline(t):
    """render.deadline_ms, capped by --max-deadline-ms (also the deadline of a render that
    names none): past it the render stops at its next submission and the answer says so."""
    with Server("--max-deadline-ms", "1500") as srv:
        limits = json.loads(srv.request("GET", "/v1/info")[2]).get("limits", {})
        t.equal(limits.get("max_deadline_ms"), 1500, "limits.max_deadline_ms")
        rate = PtRate(srv)
        buffers = json.loads(srv.request("GET", "/v1/info")[2])["device"].get("live_buffers")
        long_scene, expected = rate.scene(30)
        start = time.monotonic()
        status, h, body = srv.render(long_scene)
        took = time.monotonic() - start
        p = problem(body)
        t.equal((status, p.get("code")), (503, "deadline_exceeded"), "the server's cap applies")
        t.check("1500 ms" in p.get("detail", ""), f"the detail names the limit: {p.get('detail')}")
        t.check(took < min(expected, 15), f"stopped early: {took:.1f} s of ~{expected:.0f} s")
        asked = json.loads(json.dumps(long_scene))
        asked["render"]["deadline_ms"] = 300
        status, h, body = srv.render(asked)
        t.check(status == 503 and "300 ms" in problem(body).get("detail", ""),
                f"a shorter deadline of the scene's own: {problem(body).get('detail')}")
        status, headers, job, raw = post_async(srv, asked)
        if t.equal(status, 202, "an async job with a deadline"):
            done = wait_state(srv, job_path(job["id"]), ("done", "failed", "cancelled"), 60)
            t.equal((done.get("state"), (done.get("error") or {}).get("code")),
                    ("failed", "deadline_exceeded"), "the job fails with the deadline")
        after = json.loads(srv.request("GET", "/v1/info")[2])["device"].get("live_buffers")
        t.equal(after, buffers, "every buffer freed")
        small = small_scene(8, 8)
        small["render"] = {"deadline_ms": 60000, "components": ["surface"]}
        t.equal(srv.render(small)[0], 200, "a render within its deadline is answered")
        bad = small_scene(8, 8)
        bad["render"] = {"deadline_ms": 0}
        status, h, body = json_post(srv, "/v1/renders/validate", bad)
        t.check(status == 422 and any(e.get("pointer") == "/render/deadline_ms"
                                      for e in problem(body).get("errors", [])),
                "deadline_ms 0 is refused at its pointer")


def test_no_instance(t, srv):
    """Without --instance: no X-Nscatter-Instance header, /v1/info instance null."""
    status, h, body = srv.request("GET", "/v1/info")
    t.equal((status, "x-nscatter-instance" in h, json.loads(body).get("instance", "missing")),
            (200, False, None), "no instance")


def test_instance_ids(t):
    """serve --instance NAME: job ids name their instance, so a load balancer can route them;
    an id of another instance (or without the prefix) is not found here."""
    with Server("--instance", "b7") as srv:
        status, headers, job, raw = post_async(srv, small_scene(8, 8))
        jid = job.get("id", "")
        t.check(status == 202 and re.match(r"^b7-[0-9a-f]{32}$", jid), f"an id of b7: {jid!r}")
        t.equal(headers.get("location"), f"/v1/renders/{jid}", "Location carries it")
        t.equal(headers.get("x-nscatter-instance"), "b7", "X-Nscatter-Instance names it")
        status, h, body = srv.request("GET", "/nope")
        t.equal((status, h.get("x-nscatter-instance")), (404, "b7"), "also on a problem")
        t.equal(json.loads(srv.request("GET", "/v1/info")[2]).get("instance"), "b7",
                "/v1/info instance")
        t.equal(wait_state(srv, job_path(jid), ("done", "failed")).get("state"), "done",
                "the job is found by its id")
        for other in ("c7-" + jid[3:], jid[3:], "b7" + jid[3:]):
            status, h, body = srv.request("GET", job_path(other))
            check_problem(t, status, h, body, 404, "not_found", f"{other[:8]}...: not ours")
    for bad in ("B7", "with-dash", "x" * 17):
        proc = __import__("subprocess").run([os.environ["NSCATTER_BIN"], "serve", "--instance", bad],
                                            capture_output=True, text=True, timeout=30)
        t.check(proc.returncode == 2 and "--instance" in proc.stderr, f"--instance {bad} refused")
    for option in ("--idle-work", "--access-log"):
        proc = __import__("subprocess").run([os.environ["NSCATTER_BIN"], "serve", option, "maybe"],
                                            capture_output=True, text=True, timeout=30)
        t.check(proc.returncode == 2 and f"{option} on|off" in proc.stderr, f"{option} maybe refused")


def test_service_limits(t):
    """serve --max-pixels/--max-spp/--max-vrls: a scene over one is refused at its pointer,
    naming the limit, before anything is queued; /v1/info reports the limits in force."""
    with Server("--max-pixels", "4096", "--max-spp", "8", "--max-vrls", "2000") as srv:
        limits = json.loads(srv.request("GET", "/v1/info")[2]).get("limits", {})
        t.equal((limits.get("max_pixels"), limits.get("max_spp"), limits.get("max_vrls")),
                (4096, 8, 2000), "limits in /v1/info")
        cases = (({"camera": {"width": 128, "height": 64}}, "/camera/height", "4096"),
                 ({"render": {"spp": 9}}, "/render/spp", "8"),
                 ({"render": {"vrls": 2001}}, "/render/vrls", "2000"),
                 ({"render": {"components": ["multiple"]}}, "/render/vrls", "2000"))
        for change, pointer, number in cases:
            scene = small_scene(8, 8)
            for key, value in change.items():
                scene.setdefault(key, {}).update(value)
            status, h, body = json_post(srv, "/v1/renders", scene)
            p = problem(body)
            hit = [e for e in p.get("errors", []) if e.get("pointer") == pointer]
            t.check(status == 422 and hit and number in hit[0].get("detail", ""),
                    f"{pointer} over the service's limit: {status} {p.get('errors')}")
        ok = small_scene(64, 64)
        ok["render"] = {"spp": 8, "components": ["surface"]}
        t.equal(json_post(srv, "/v1/renders", ok)[0], 200, "at the limits: rendered")
        sweep = {"scene": small_scene(8, 8), "variants": [{"/render/spp": 4}, {"/render/spp": 16}]}
        status, h, body = json_post(srv, "/v1/sweeps", sweep)
        t.check(status == 422 and any(e.get("pointer") == "/variants/1/~1render~1spp"
                                      for e in problem(body).get("errors", [])),
                f"a sweep variant over the limit is named: {problem(body).get('errors')}")


def main():
    t = Checks()
    with Server() as srv:
        for test in (test_request_ids, test_access_log, test_validate, test_materials,
                     test_no_instance):
            t.run(test, srv)
    t.run(test_full_queue_before_the_body)
    t.run(test_deadline)
    t.run(test_instance_ids)
    t.run(test_service_limits)
    t.run(test_stop_signal)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
