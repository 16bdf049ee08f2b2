"""The bounded render queue and the service's life cycle, against the real server:
- with --queue 1, a render that arrives while another runs gets 503 + Retry-After at once,
  while /livez and /readyz keep answering (one thread per connection, renders apart);
- SIGTERM while a render runs: the render is finished and answered, then a clean exit;
- without a usable device the service still starts: /livez 200, /readyz 503, renders 503
  naming the ns_status, /v1/info says ready false.
Renders are made slow by size and samples (a few seconds on lavapipe), and the test waits
until /v1/info shows the render admitted before it fires the next one, so the outcome does
not depend on timing luck."""
import json
import os
import signal
import sys
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import PNG_SIGNATURE, Checks, Server, problem, small_scene  # noqa: E402

WAIT_ADMITTED_S = 60


def slow_scene():
    return small_scene(320, 240, spp=12)


def start_render(srv, scene, results):
    def run():
        try:
            results.append(srv.render(scene, timeout=300))
        except Exception as e:  # recorded, checked by the caller
            results.append((0, {}, repr(e).encode()))
    th = threading.Thread(target=run)
    th.start()
    return th


def wait_queue_length(srv, want):
    deadline = time.monotonic() + WAIT_ADMITTED_S
    while time.monotonic() < deadline:
        info = json.loads(srv.request("GET", "/v1/info")[2])
        if info.get("queue_length") == want:
            return True
        time.sleep(0.005)
    return False


def test_queue_full_503(t, srv):
    results = []
    th = start_render(srv, slow_scene(), results)
    admitted = t.check(wait_queue_length(srv, 1), "first render admitted")
    if admitted:
        t0 = time.monotonic()
        status, headers, body = srv.render(small_scene(8, 8))
        answered_in = time.monotonic() - t0
        t.equal(status, 503, "second render while the queue is full")
        retry = headers.get("retry-after", "")
        t.check(retry.isdigit() and 1 <= int(retry) <= 3600, f"Retry-After seconds: {retry!r}")
        t.check(headers.get("content-type", "").startswith("application/problem+json"),
                "503 is problem+json")
        t.equal(problem(body).get("code"), "queue_full", "code queue_full")
        t.check(answered_in < 5.0, f"503 answered at once ({answered_in:.2f} s)")
        # Health endpoints are not behind the render queue.
        t0 = time.monotonic()
        t.equal(srv.request("GET", "/livez")[0], 200, "/livez during a render")
        t.equal(srv.request("GET", "/readyz")[0], 200, "/readyz during a render")
        t.check(time.monotonic() - t0 < 5.0, "health answers do not wait for the render")
        t.check(wait_queue_length(srv, 1), "the slow render was still running during the checks")
    th.join(300)
    t.check(results and results[0][0] == 200, f"the slow render finished: {results[:1]}")
    if results and results[0][0] == 200:
        t.equal(results[0][2][:8], PNG_SIGNATURE, "slow render is a PNG")
        timing = results[0][1].get("server-timing", "")
        t.check("queue;dur=" in timing, f"queue wait reported: {timing}")
    status, headers, body = srv.render(small_scene(8, 8))
    t.equal(status, 200, "a slot is free again after the render")


def test_sigterm_finishes_the_render_in_flight(t):
    with Server("--queue", "1") as srv:
        results = []
        th = start_render(srv, slow_scene(), results)
        if not t.check(wait_queue_length(srv, 1), "render admitted before SIGTERM"):
            th.join(300)
            return
        srv.proc.send_signal(signal.SIGTERM)
        th.join(300)
        t.check(results and results[0][0] == 200,
                f"render in flight answered after SIGTERM: {results[:1]}")
        try:
            code = srv.proc.wait(60)
        except Exception:
            code = None
        t.check(srv.exited_cleanly(code), f"clean exit after SIGTERM (status {code}, own "
                f"leaks {srv.own_leaks()[:2]})")


def test_sigint_exits_cleanly(t):
    with Server() as srv:
        t.equal(srv.request("GET", "/livez")[0], 200, "alive")
        code = srv.stop(signal.SIGINT)
        t.check(srv.exited_cleanly(code), f"clean exit after SIGINT (status {code})")


def test_no_device(t):
    with Server("--device", "no-such-device-nscatter-test") as srv:
        t.equal(srv.request("GET", "/livez")[0], 200, "/livez without a device")
        status, headers, body = srv.request("GET", "/readyz")
        t.equal(status, 503, "/readyz without a device")
        info = json.loads(srv.request("GET", "/v1/info")[2])
        t.equal(info.get("ready"), False, "info: not ready")
        status, headers, body = srv.render(small_scene(8, 8))
        t.equal(status, 503, "render without a device")
        p = problem(body)
        t.check(p.get("code") not in (None, "", "queue_full"), f"names the status: {p}")
        t.check(p.get("detail"), "explains why")
        # Validation renders nothing: it answers without a device, as with one.
        status, headers, body = srv.render(small_scene(8, 8), path="/v1/renders/validate")
        t.equal(status, 204, "validate without a device: a good scene")
        bad = small_scene(8, 8)
        bad["camera"]["fov"] = 500
        status, headers, body = srv.render(bad, path="/v1/renders/validate")
        t.equal(status, 422, "validate without a device: a bad scene")
        t.equal(problem(body).get("code"), "invalid_scene", "the render's problem")
        code = srv.stop()
        t.check(srv.exited_cleanly(code), f"clean exit (status {code}, own leaks "
                f"{srv.own_leaks()[:2]})")


def main():
    t = Checks()
    with Server("--queue", "1") as srv:
        t.run(test_queue_full_503, srv)
        t.current = "end"
        t.equal(srv.request("GET", "/livez")[0], 200, "/livez at the end")
        code = srv.stop()
        t.check(srv.exited_cleanly(code), f"clean exit (status {code}, own leaks "
                f"{srv.own_leaks()[:2]})")
        if t.failed:
            print(srv.log_text()[-4000:], file=sys.stderr)
    t.run(test_sigterm_finishes_the_render_in_flight)
    t.run(test_sigint_exits_cleanly)
    t.run(test_no_device)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
