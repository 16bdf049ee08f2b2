"""A bounded load test on loopback (issue 18): 16 concurrent clients send a mix of requests —
probes, info, metrics, the OpenAPI document, validations, small synchronous renders,
asynchronous renders followed to their image, cancels, small sweeps and bodies over the limit
— against one real `nscatter serve`, first as a warm-up, then for the measured run.

What must hold:
- every answer has a status that is legitimate for its kind (LEGIT below): the service is
  either doing the work (200/202/204) or says it is full (503, always with Retry-After), and
  the one hostile kind, a body declared over --max-body, is 413;
- no connection error (reset, refused, timed out), no crash;
- after the run, once the service is idle again: the resident memory (VmRSS of the process)
  within 10% of its value after the warm-up, and the device's live-buffer counter
  (/v1/info device.live_buffers) back to its idle value (0).

Every asynchronous job and sweep is discarded (DELETE) once finished, so the job store does
not legitimately grow. Under the sanitizer build (libasan in the process) the memory check is
reported, not enforced — ASan's quarantine holds freed blocks on purpose — and LeakSanitizer's
report at exit stands in for it. `LOAD_SECONDS`, `LOAD_ROUNDS` stretch the run into a soak
(docs/http.md, "Load and soak").

Python standard library only."""
import http.client
import json
import os
import random
import socket
import sys
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import (PNG_SIGNATURE, Checks, Server, parse_raw_response,  # noqa: E402
                         small_scene)

CLIENTS = 16
MAX_BODY = 1 << 20
QUEUE = 4
WARMUP_OPS = 30        # per client: the same as a run, so every path is warm
RUN_OPS = 30           # per client: 480 operations, each one or more requests
ROUNDS = int(os.environ.get("LOAD_ROUNDS", "1"))          # soak: repeat the run
SOAK_SECONDS = float(os.environ.get("LOAD_SECONDS", "0"))  # soak: or run this long
TIMEOUT_S = 120

# Per kind of request, the statuses that are a correct answer under load.
LEGIT = {
    "livez": {200}, "readyz": {200}, "info": {200}, "metrics": {200}, "openapi": {200},
    "materials": {200},
    "validate": {204},
    "render": {200, 503},
    "async_post": {202, 503}, "async_poll": {200}, "async_image": {200},
    "async_events": {200, 503},            # 503 too_many_streams, with Retry-After
    "async_delete": {204},                 # discarding a finished job
    "cancel": {200, 202, 204},             # queued: 200, running: 202, finished already: 204
    "sweep_post": {202, 503}, "sweep_poll": {200}, "sweep_sheet": {200},
    "sweep_delete": {204},
    "oversized": {413},
}

WEIGHTS = [("livez", 2), ("readyz", 2), ("info", 3), ("metrics", 2), ("openapi", 1),
           ("materials", 1), ("validate", 3), ("render", 6), ("async", 4), ("cancel", 3),
           ("sweep", 1), ("oversized", 1)]


def tiny(rng, size=None):
    s = small_scene(size or rng.choice((8, 12, 16)), size or rng.choice((8, 16)))
    s["render"]["seed"] = rng.randrange(1, 1 << 30)
    return s


RETRIED = [0]  # kept-alive connections found closed and retried on a fresh one


class Client:
    """One client thread: a keep-alive connection, reopened after the server closes it."""

    lock = threading.Lock()

    def __init__(self, srv, rng, record):
        self.srv, self.rng, self.record = srv, rng, record
        self.conn = None

    def request(self, kind, method, path, body=None, headers=None):
        h = dict(headers or {})
        if body is not None and not isinstance(body, bytes):
            body = json.dumps(body).encode()
            h.setdefault("Content-Type", "application/json")
        for attempt in (0, 1):
            reused = self.conn is not None
            if self.conn is None:
                self.conn = http.client.HTTPConnection("127.0.0.1", self.srv.port,
                                                       timeout=TIMEOUT_S)
            try:
                self.conn.request(method, path, body=body, headers=h)
                resp = self.conn.getresponse()
                data = resp.read()
                if resp.getheader("Connection", "").lower() == "close":
                    self.close()
                self.record(kind, resp.status, resp.getheader("Retry-After"), None)
                if resp.status == 503:
                    # Back off as a client should, but briefly: the run stays short.
                    time.sleep(min(float(resp.getheader("Retry-After") or 1), 0.2))
                return resp.status, data
            except (http.client.RemoteDisconnected, BrokenPipeError,
                    ConnectionResetError) as e:
                # A kept-alive connection the server closed between two requests (idle
                # timeout, or after an answer with Connection: close) is retried once on a
                # fresh connection, as every HTTP client does; a fresh one must not fail.
                self.close()
                if attempt or not reused:
                    self.record(kind, None, None, f"{type(e).__name__}: {e}")
                    return None, b""
                with self.lock:
                    RETRIED[0] += 1
            except OSError as e:
                self.close()
                self.record(kind, None, None, f"{type(e).__name__}: {e}")
                return None, b""
        return None, b""

    def close(self):
        if self.conn is not None:
            self.conn.close()
            self.conn = None

    # --- the operations ------------------------------------------------------------------
    def op(self, kind):
        getattr(self, "op_" + kind, None)(kind) if hasattr(self, "op_" + kind) else \
            self.request(kind, "GET", {"livez": "/livez", "readyz": "/readyz", "info": "/v1/info",
                                       "metrics": "/metrics", "openapi": "/openapi.json",
                                       "materials": "/v1/materials"}[kind])

    def op_validate(self, kind):
        self.request(kind, "POST", "/v1/renders/validate", tiny(self.rng))

    def op_render(self, kind):
        status, data = self.request(kind, "POST", "/v1/renders", tiny(self.rng))
        if status == 200 and not data.startswith(PNG_SIGNATURE):
            self.record(kind, status, None, "a 200 render that is not a PNG")

    def wait_job(self, kind, path, deadline_s=60):
        end = time.monotonic() + deadline_s
        while time.monotonic() < end:
            status, data = self.request(kind, "GET", path)
            if status != 200:
                return None
            job = json.loads(data)
            if job.get("state") in ("done", "failed", "cancelled"):
                return job
            time.sleep(0.05)
        self.record(kind, None, None, f"{path} not finished in {deadline_s} s")
        return None

    def op_async(self, kind):
        status, data = self.request("async_post", "POST", "/v1/renders", tiny(self.rng),
                                    {"Prefer": "respond-async"})
        if status != 202:
            return
        path = "/v1/renders/" + json.loads(data)["id"]
        job = self.wait_job("async_poll", path)
        if job and job.get("state") == "done":
            status, data = self.request("async_image", "GET", path + "/image")
            if status == 200 and not data.startswith(PNG_SIGNATURE):
                self.record("async_image", status, None, "an image that is not a PNG")
            if self.rng.random() < 0.3:
                self.request("async_events", "GET", path + "/events")
        elif job:
            self.record("async_poll", None, None, f"a tiny job ended {job.get('state')}: "
                        f"{job.get('error')}")
        if job:
            self.request("async_delete", "DELETE", path)

    def op_cancel(self, kind):
        status, data = self.request("async_post", "POST", "/v1/renders",
                                    tiny(self.rng, 32), {"Prefer": "respond-async"})
        if status != 202:
            return
        path = "/v1/renders/" + json.loads(data)["id"]
        status, _ = self.request("cancel", "DELETE", path)
        if status in (200, 202):
            job = self.wait_job("async_poll", path)
            if job:
                self.request("async_delete", "DELETE", path)

    def op_sweep(self, kind):
        body = {"scene": tiny(self.rng, 8),
                "variants": [{"/materials/wax/g": 0.2}, {"/materials/wax/g": 0.7}]}
        status, data = self.request("sweep_post", "POST", "/v1/sweeps", body)
        if status != 202:
            return
        path = "/v1/sweeps/" + json.loads(data)["id"]
        job = self.wait_job("sweep_poll", path)
        if job:
            self.request("sweep_sheet", "GET", path + "/sheet.png")
            self.request("sweep_delete", "DELETE", path)

    def op_oversized(self, kind):
        """A body declared over --max-body: answered 413 from the headers, before a byte of
        it is sent, and the connection closed (a raw socket: http.client would send it)."""
        try:
            with socket.create_connection(("127.0.0.1", self.srv.port), timeout=TIMEOUT_S) as s:
                s.sendall(b"POST /v1/renders HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                          b"Content-Type: application/json\r\nContent-Length: %d\r\n\r\n"
                          % (MAX_BODY * self.rng.choice((2, 64, 4096))))
                data = b""
                while True:
                    chunk = s.recv(65536)
                    if not chunk:
                        break
                    data += chunk
            status, headers, _ = parse_raw_response(data)
            self.record(kind, status, headers.get("retry-after"), None)
        except OSError as e:
            self.record(kind, None, None, f"{type(e).__name__}: {e}")


class Load:
    def __init__(self, srv):
        self.srv = srv
        self.lock = threading.Lock()
        self.answers = []   # (kind, status, retry_after)
        self.errors = []

    def record(self, kind, status, retry_after, error):
        with self.lock:
            if error:
                self.errors.append((kind, error))
            else:
                self.answers.append((kind, status, retry_after))

    def run(self, ops, seed, seconds=0.0):
        kinds = [k for k, w in WEIGHTS for _ in range(w)]
        start = time.monotonic()

        def worker(i):
            rng = random.Random(seed * 1000 + i)
            c = Client(self.srv, rng, self.record)
            n = 0
            while n < ops or (seconds and time.monotonic() - start < seconds):
                c.op(rng.choice(kinds))
                n += 1
            c.close()

        threads = [threading.Thread(target=worker, args=(i,)) for i in range(CLIENTS)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        return time.monotonic() - start


def rss_kib(pid):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


def sanitized(pid):
    with open(f"/proc/{pid}/maps") as f:
        return "libasan" in f.read()


def info(srv):
    return json.loads(srv.request("GET", "/v1/info")[2])


def settle(srv, timeout=60):
    """Waits until nothing is admitted and no job is kept; returns /v1/info then."""
    end = time.monotonic() + timeout
    i = info(srv)
    while time.monotonic() < end:
        i = info(srv)
        jobs = i.get("jobs") or {}
        if i.get("queue_length") == 0 and not any(jobs.values()):
            break
        time.sleep(0.1)
    time.sleep(0.5)  # connection threads finish their last answers
    return info(srv)


def check_answers(t, load, phase):
    t.equal(load.errors[:5], [], f"{phase}: no connection error ({len(load.errors)})")
    by_kind = {}
    for kind, status, retry in load.answers:
        by_kind.setdefault(kind, {}).setdefault(status, 0)
        by_kind[kind][status] += 1
        if status not in LEGIT[kind]:
            t.check(False, f"{phase}: {kind} answered {status}")
        if status == 503:
            t.check(retry is not None and retry.isdigit() and int(retry) >= 1,
                    f"{phase}: {kind} 503 with Retry-After, got {retry!r}")
    return by_kind


def test_load(t, srv):
    load = Load(srv)
    took = load.run(WARMUP_OPS, seed=1)
    check_answers(t, load, "warm-up")
    idle = settle(srv)
    t.equal(idle.get("queue_length"), 0, "idle after the warm-up")
    live_idle = idle["device"].get("live_buffers")
    t.equal(live_idle, 0, "no live device buffer after the warm-up")
    rss_warm = rss_kib(srv.proc.pid)
    print(f"warm-up: {len(load.answers)} answers in {took:.1f} s, VmRSS {rss_warm} KiB",
          file=sys.stderr, flush=True)

    total = 0
    rss_trend = []
    soak_end = time.monotonic() + SOAK_SECONDS
    round_ = 0
    while True:
        round_ += 1
        load = Load(srv)
        took = load.run(RUN_OPS, seed=100 + round_)
        by_kind = check_answers(t, load, f"run {round_}")
        total += len(load.answers)
        done = settle(srv)
        rss = rss_kib(srv.proc.pid)
        rss_trend.append(rss)
        print(f"run {round_}: {len(load.answers)} answers in {took:.1f} s "
              f"({len(load.answers) / took:.0f}/s), VmRSS {rss} KiB, live buffers "
              f"{done['device'].get('live_buffers')}", file=sys.stderr, flush=True)
        if round_ == 1:
            print("  " + json.dumps({k: v for k, v in sorted(by_kind.items())}),
                  file=sys.stderr, flush=True)
            t.check(len(load.answers) >= 400, f"at least 400 requests: {len(load.answers)}")
            t.check(by_kind.get("render", {}).get(200, 0) > 0,
                    "some synchronous renders were rendered")
            t.check(by_kind.get("async_image", {}).get(200, 0) > 0, "some async images fetched")
            t.check(sum(by_kind.get("cancel", {}).values()) > 0, "some cancels")
            t.check(by_kind.get("oversized", {}).get(413, 0) > 0, "oversized bodies refused")
        t.equal(done["device"].get("live_buffers"), live_idle,
                f"run {round_}: live device buffers back to the idle value")
        t.equal((done.get("queue_length"), sum((done.get("jobs") or {}).values())), (0, 0),
                f"run {round_}: nothing admitted or kept")
        if round_ >= ROUNDS and time.monotonic() >= soak_end:
            break
    growth = (rss_trend[-1] - rss_warm) / rss_warm if rss_warm else 1
    print(f"kept-alive connections retried after the server closed them: {RETRIED[0]}",
          file=sys.stderr, flush=True)
    print(f"total {total} answers in {round_} runs; VmRSS after warm-up {rss_warm} KiB, after "
          f"the runs {rss_trend} KiB ({growth * 100:+.1f}%)", file=sys.stderr, flush=True)
    if sanitized(srv.proc.pid):
        print("sanitizer build: resident memory reported, not checked (ASan quarantine); "
              "LeakSanitizer checks at exit", file=sys.stderr, flush=True)
    else:
        t.check(abs(growth) <= 0.10, f"VmRSS within 10% of the warm-up's: {rss_warm} KiB -> "
                f"{rss_trend[-1]} KiB ({growth * 100:+.1f}%)")
    t.check(srv.alive(), "the server is alive")
    t.equal(srv.request("GET", "/readyz")[0], 200, "/readyz at the end")


def main():
    t = Checks()
    with Server("--queue", str(QUEUE), "--max-body", str(MAX_BODY), "--access-log", "off") as srv:
        t.run(test_load, srv)
        t.current = "end"
        code = srv.stop()
        t.check(srv.exited_cleanly(code), f"clean exit on SIGTERM (status {code}, own leaks "
                f"{srv.own_leaks()[:2]})")
        # Under the sanitizer build: what LeakSanitizer said in all (the driver's own leaks
        # at exit included, which are not counted), for the soak's record.
        summary = [l for l in srv.log_text().splitlines() if l.startswith("SUMMARY:")]
        if summary:
            print(f"LeakSanitizer: {summary[-1]}; through nscatter's own code: "
                  f"{len(srv.own_leaks())} leaks", file=sys.stderr, flush=True)
        if t.failed:
            print(srv.log_text()[-3000:], file=sys.stderr)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
