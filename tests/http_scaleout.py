"""Scale-out (issue 18): three real `nscatter serve --instance aN` behind a real nginx that
runs the committed deploy/nginx.conf, on loopback.

- requests spread over the instances (X-Nscatter-Instance says which answered);
- X-Request-Id goes through nginx to the instance and back, the same id in both logs;
- an asynchronous render or sweep made through nginx is read, streamed (unbuffered),
  cancelled and discarded through nginx, always by the instance whose name its id carries;
  an id of no instance is a 404 of the instances, a body over the limit nginx's own 413;
- one instance is stopped with SIGTERM while clients keep sending renders and GETs through
  nginx: no client sees a 502, a 504 or a broken connection, every answer is a 200 (or a 503
  with Retry-After that every instance refused), nginx's log shows the retries, the stopped
  instance answers the renders it had admitted and exits 0, and its jobs then answer
  nginx's 410 job_gone rather than a 502.

The config is deploy/nginx.conf as committed, with one substitution: its addresses
127.0.0.1:8080 (nginx) and 127.0.0.1:8081..8083 (a1..a3) become free loopback ports.
nginx runs in the foreground as this user with a private prefix (-p) for its logs and
temporary files (docs/container.md, "Scale-out"). scripts/setup.sh installs nginx-light with
the test packages, so a missing nginx fails the test rather than skipping it.

Python standard library only."""
import http.client
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import Checks, Server, png_chunks, small_scene  # noqa: E402
from nstest_jobs import (PtRate, check_problem, read_events, wait_state,  # noqa: E402
                         wait_until)

INSTANCES = ("a1", "a2", "a3")
VICTIM = "a1"  # the instance test_drain_under_load stops
HEX32 = re.compile(r"^[0-9a-f]{32}$")
SOURCE = os.environ.get("NSCATTER_SOURCE_DIR",
                        os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CONF = os.path.join(SOURCE, "deploy", "nginx.conf")


class Endpoint:
    """Something on a loopback port that nstest's request helpers can talk to."""

    def __init__(self, port):
        self.port = port

    connection = Server.connection
    request = Server.request
    render = Server.render


class Nginx(Endpoint):
    """nginx -p TMP -c TMP/nginx.conf in the foreground; the conf is deploy/nginx.conf with
    its addresses moved to the given ports."""

    def __init__(self, upstream_ports):
        binary = shutil.which("nginx") or next(
            (p for p in ("/usr/sbin/nginx", "/sbin/nginx") if os.path.exists(p)), None)
        if not binary:
            raise RuntimeError("nginx is not installed (scripts/setup.sh test installs "
                               "nginx-light)")
        self.dir = tempfile.mkdtemp(prefix="nscatter-nginx-")
        # Run as root, nginx's workers are another user: they must reach temp/.
        os.chmod(self.dir, 0o755)
        for sub in ("logs", "temp"):
            os.mkdir(os.path.join(self.dir, sub))
        port = free_port()
        with open(CONF) as f:
            text = f.read()
        ports = {"8080": port}
        for i, p in enumerate(upstream_ports):
            ports[str(8081 + i)] = p
        for old in ports:
            if f"127.0.0.1:{old}" not in text:
                raise RuntimeError(f"deploy/nginx.conf has no 127.0.0.1:{old} to replace")
        text = re.sub(r"127\.0\.0\.1:(808[0-3])\b", lambda m: f"127.0.0.1:{ports[m.group(1)]}",
                      text)
        self.conf = os.path.join(self.dir, "nginx.conf")
        with open(self.conf, "w") as f:
            f.write(text)
        self.error_log = os.path.join(self.dir, "logs", "error.log")
        self.access_log = os.path.join(self.dir, "logs", "access.log")
        self.proc = subprocess.Popen(
            [binary, "-p", self.dir + "/", "-c", self.conf, "-e", self.error_log, "-g",
             f"daemon off; pid {self.dir}/nginx.pid; error_log {self.error_log} notice;"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        super().__init__(port)
        deadline = time.monotonic() + 20
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f"nginx exited {self.proc.returncode}: "
                                   f"{self.proc.stderr.read().decode(errors='replace')}"
                                   f"{self.log('error')}")
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                if time.monotonic() > deadline:
                    self.stop()
                    raise RuntimeError(f"nginx did not listen; {self.log('error')}")
                time.sleep(0.05)

    def log(self, which):
        try:
            with open(self.error_log if which == "error" else self.access_log,
                      errors="replace") as f:
                return f.read()
        except OSError:
            return ""

    def access_lines(self):
        out = []
        for line in self.log("access").splitlines():
            try:
                out.append(json.loads(line))
            except ValueError:
                pass
        return out

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGQUIT)  # graceful: finish what is in flight
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self.proc.stderr.close()
        return self.proc.returncode


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def json_headers(extra=None):
    h = {"Content-Type": "application/json"}
    h.update(extra or {})
    return h


def post(ep, path, doc, headers=None, timeout=120):
    status, h, raw = ep.request("POST", path, json.dumps(doc).encode(), json_headers(headers),
                                timeout)
    try:
        body = json.loads(raw) if raw and h.get("content-type", "").endswith("json") else raw
    except ValueError:
        body = raw
    return status, h, body


def post_async_to(ep, path, doc):
    return post(ep, path, doc, {"Prefer": "respond-async"})


def async_on(t, lb, instance, doc, path="/v1/renders", tries=12):
    """Posts async jobs through nginx until one lands on `instance` (round robin: within as
    many posts as there are instances); returns its id. The others made on the way are
    cancelled, so that they do not take the CPU from the test."""
    for _ in range(tries):
        status, h, job = post_async_to(lb, path, doc)
        if status != 202:
            t.check(False, f"async POST {path}: {status} {job!r:.200}")
            return None
        if job["id"].startswith(instance + "-"):
            return job["id"]
        lb.request("DELETE", f"{path}/{job['id']}")
    t.check(False, f"no job landed on {instance} in {tries} posts")
    return None


def instance_log_ids(srv):
    ids = set()
    for line in srv.log_text().splitlines():
        if line.startswith("{"):
            try:
                ids.add(json.loads(line).get("request_id"))
            except ValueError:
                pass
    return ids


# ---------------------------------------------------------------------------------------
def test_spread(t, lb, servers):
    counts = {name: 0 for name in INSTANCES}
    for i in range(12):
        status, h, body = lb.render(small_scene(16, 16))
        name = h.get("x-nscatter-instance")
        t.check(status == 200 and body.startswith(b"\x89PNG") and name in counts,
                f"render {i} through nginx: {status} from {name!r}")
        if name in counts:
            counts[name] += 1
    print(f"renders per instance: {counts}", file=sys.stderr)
    t.check(all(n >= 2 for n in counts.values()), f"every instance rendered: {counts}")
    seen = set()
    for _ in range(6):
        status, h, body = lb.request("GET", "/v1/info")
        info = json.loads(body)
        t.equal(info.get("instance"), h.get("x-nscatter-instance"),
                "/v1/info instance = X-Nscatter-Instance")
        seen.add(info.get("instance"))
    t.equal(seen, set(INSTANCES), "info from every instance")


def test_request_id(t, lb, servers):
    status, h, _ = lb.request("GET", "/v1/info", headers={"X-Request-Id": "scaleout-rid-1"})
    t.equal((status, h.get("x-request-id")), (200, "scaleout-rid-1"), "the client's id echoed")
    status, h, _ = lb.render(small_scene(16, 16))
    rid, name = h.get("x-request-id", ""), h.get("x-nscatter-instance")
    t.check(status == 200 and HEX32.match(rid), f"without one: nginx's $request_id: {rid!r}")
    status, h, _ = lb.request("GET", "/livez", headers={"X-Request-Id": "has space"})
    t.check(HEX32.match(h.get("x-request-id", "")), "an id that is no token is replaced")
    if name in servers:
        t.check(wait_until(lambda: rid in instance_log_ids(servers[name]), 5),
                f"{name}'s access log has nginx's id {rid}")
    t.check(wait_until(lambda: any(e.get("request_id") == rid and e.get("instance") == name
                                   for e in lb.access_lines()), 5),
            "nginx's access log has the same id and instance")


def check_job_routes(t, lb, jid, kind="renders"):
    name = jid.split("-")[0]
    path = f"/v1/{kind}/{jid}"
    for i in range(5):
        status, h, body = lb.request("GET", path)
        t.check(status == 200 and h.get("x-nscatter-instance") == name,
                f"GET {path} #{i} from {h.get('x-nscatter-instance')}: {status}")
    job = wait_state(lb, path, ("done", "failed", "cancelled"), 60)
    t.equal(job.get("state"), "done", f"{jid} done, read through nginx")
    return path, name


def test_async_routing(t, lb, servers):
    ids = {}
    for _ in range(9):
        status, h, job = post_async_to(lb, "/v1/renders", small_scene(16, 16))
        if not t.equal(status, 202, "async POST through nginx"):
            return
        jid = job["id"]
        t.check(re.match(r"^a[1-3]-[0-9a-f]{32}$", jid), f"an id naming its instance: {jid}")
        t.equal(h.get("x-nscatter-instance"), jid.split("-")[0], "made where its id says")
        t.equal(h.get("location"), f"/v1/renders/{jid}", "Location")
        ids.setdefault(jid.split("-")[0], jid)
        if len(ids) == len(INSTANCES):
            break
    t.equal(sorted(ids), list(INSTANCES), "jobs on every instance")
    for name, jid in sorted(ids.items()):
        path, _ = check_job_routes(t, lb, jid)
        status, h, body = lb.request("GET", path + "/image")
        t.check(status == 200 and h.get("x-nscatter-instance") == name and png_chunks(body),
                f"{jid[:8]} image through nginx: {status} from {h.get('x-nscatter-instance')}")
        s = read_events(lb, path + "/events", timeout=20)
        t.check(s.status == 200 and s.closed and s.events and s.events[-1].name == "done"
                and s.headers.get("x-nscatter-instance") == name,
                f"{jid[:8]} events replayed through nginx: {s.status} {s.events[-1:]} {s.error}")
        status, h, body = lb.request("DELETE", path)
        t.equal((status, h.get("x-nscatter-instance")), (204, name), f"{jid[:8]} discarded")
        status, h, body = lb.request("GET", path)
        check_problem(t, status, h, body, 410, "job_gone", f"{jid[:8]} after DELETE")
        t.equal(h.get("x-nscatter-instance"), name, "410 from its instance")
    # An id naming no instance goes to the pool, whose instances do not know it.
    status, h, body = lb.request("GET", "/v1/renders/zz-" + "0" * 32)
    check_problem(t, status, h, body, 404, "not_found", "an id of no instance")
    status, h, body = lb.request("GET", "/v1/renders/a2-" + "0" * 32)
    check_problem(t, status, h, body, 404, "not_found", "an a2 id a2 never made")
    t.equal(h.get("x-nscatter-instance"), "a2", "asked of a2")

    # A sweep: made on one instance, its manifest, images and sheet read from it.
    sweep = {"scene": small_scene(16, 16),
             "variants": [{"/materials/wax/g": 0.5}, {"/materials/wax/g": 0.8}]}
    status, h, job = post_async_to(lb, "/v1/sweeps", sweep)
    if t.equal(status, 202, "sweep through nginx"):
        path, name = check_job_routes(t, lb, job["id"], "sweeps")
        for tail in ("/manifest.json", "/images/1", "/sheet.png"):
            status, h, body = lb.request("GET", path + tail)
            t.check(status == 200 and h.get("x-nscatter-instance") == name,
                    f"sweep {tail}: {status} from {h.get('x-nscatter-instance')}")


def test_stream_and_cancel(t, lb, servers):
    """A running job's events arrive through nginx as they happen (unbuffered), and a DELETE
    through nginx reaches the instance that runs it."""
    rate = PtRate(servers["a2"])
    t.check(rate.ok, "pt rate measured")
    scene, expected = rate.scene(8)
    jid = async_on(t, lb, "a2", scene)
    if not jid:
        return
    path = f"/v1/renders/{jid}"
    start = time.monotonic()
    s = read_events(lb, path + "/events", timeout=30, max_events=4)
    first = time.monotonic() - start
    t.check(s.status == 200 and len(s.events) == 4 and s.headers.get("x-nscatter-instance") == "a2",
            f"the first events of a running job: {s.status} {s.events} {s.error}")
    t.check(first < expected / 2, f"they came at once ({first:.2f} s of a ~{expected:.0f} s job)")
    status, h, job = lb.request("DELETE", path)
    t.check(status in (200, 202) and h.get("x-nscatter-instance") == "a2",
            f"DELETE through nginx: {status} from {h.get('x-nscatter-instance')}")
    s = read_events(lb, path + "/events", timeout=30)
    t.check(s.closed and s.events and s.events[-1].name == "cancelled",
            f"the stream through nginx ends cancelled: {s.events[-1:]} {s.error}")
    t.equal(wait_state(lb, path, ("cancelled", "done", "failed"), 30).get("state"), "cancelled",
            "the job is cancelled")


def test_body_limit(t, lb, servers):
    with socket.create_connection(("127.0.0.1", lb.port), timeout=10) as sock:
        sock.sendall(b"POST /v1/renders HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                     b"X-Request-Id: big-1\r\nContent-Length: 70000000\r\n\r\n")
        data = b""
        while b"\r\n\r\n" not in data or not data.rstrip().endswith(b"}"):
            chunk = sock.recv(65536)
            if not chunk:
                break
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    t.check(head.startswith(b"HTTP/1.1 413"), f"413 from nginx: {head[:80]!r}")
    t.check(b"application/problem+json" in head and b"X-Request-Id: big-1" in head,
            f"problem+json with the id: {head!r}")
    try:
        p = json.loads(body)
    except ValueError:
        p = {}
    t.equal((p.get("code"), p.get("request_id")), ("body_too_large", "big-1"), "its body")


def test_drain_under_load(t, lb, servers):
    """SIGTERM to one instance while 6 clients send renders and GETs through nginx."""
    victim = servers[VICTIM]
    rate = PtRate(victim)
    scene, expected = rate.scene(0.3)
    kept = async_on(t, lb, "a3", small_scene(16, 16))     # a survivor's job, read under load
    doomed = async_on(t, lb, VICTIM, small_scene(16, 16))  # the victim's, gone with it
    if not kept or not doomed:
        return
    wait_state(lb, f"/v1/renders/{kept}", ("done",), 30)
    wait_state(lb, f"/v1/renders/{doomed}", ("done",), 30)
    answers, lock, stop = [], threading.Lock(), threading.Event()

    def client(i):
        n = 0
        while not stop.is_set():
            n += 1
            for kind in ("render", "info", "job"):
                rid = f"load-{i}-{n}-{kind}"
                start = time.monotonic()
                try:
                    if kind == "render":
                        status, h, body = lb.render(scene, timeout=60)
                    elif kind == "info":
                        status, h, body = lb.request("GET", "/v1/info", timeout=30,
                                                     headers={"X-Request-Id": rid})
                    else:
                        status, h, body = lb.request("GET", f"/v1/renders/{kept}", timeout=30,
                                                     headers={"X-Request-Id": rid})
                    a = (kind, start, time.monotonic(), status, h.get("x-nscatter-instance"),
                         h.get("retry-after"), h.get("x-request-id"), None)
                except (OSError, http.client.HTTPException) as e:
                    a = (kind, start, time.monotonic(), None, None, None, rid, repr(e))
                with lock:
                    answers.append(a)

    threads = [threading.Thread(target=client, args=(i,)) for i in range(6)]
    for th in threads:
        th.start()
    try:
        t.check(wait_until(lambda: sum(a[0] == "render" for a in answers) >= 12, 60, 0.05),
                "load is running")
        busy = wait_until(lambda: json.loads(victim.request("GET", "/v1/info")[2])
                          .get("queue_length", 0) >= 1, 20, 0.01)
        t.check(busy, f"{VICTIM} has renders admitted when it is stopped")
        signalled = time.monotonic()
        victim.proc.send_signal(signal.SIGTERM)
        try:
            code = victim.proc.wait(60)
        except subprocess.TimeoutExpired:
            code = None
        exited = time.monotonic()
        t.check(victim.exited_cleanly(code), f"{VICTIM} exits 0 after the drain: {code}")
        # Keep the load on the two left for a while, through nginx's refused connections.
        before = len(answers)
        wait_until(lambda: len(answers) >= before + 30, 20, 0.05)
    finally:
        stop.set()
        for th in threads:
            th.join(90)
    print(f"drain: {len(answers)} answers, {VICTIM} drained in {exited - signalled:.2f} s",
          file=sys.stderr)
    broken = [a for a in answers if a[3] is None]
    t.check(not broken, f"no connection error reached a client: {broken[:3]}")
    bad = [a for a in answers if a[3] not in (200, 503)]
    t.check(not bad, f"no 502/504 or other status reached a client: {bad[:5]}")
    refused = [a for a in answers if a[3] == 503]
    log = {e.get("request_id"): e for e in lb.access_lines()}
    for a in refused:
        tried = log.get(a[6], {}).get("upstream_status", "")
        t.check(a[5] and tried.count(",") >= 1,
                f"a 503 only with Retry-After, once more than one instance refused: {a} {tried}")
    print(f"drain: {len(refused)} answers were 503 (all instances busy)", file=sys.stderr)
    kinds = {k: sum(a[0] == k and a[3] == 200 for a in answers) for k in ("render", "info", "job")}
    t.check(all(kinds.values()), f"renders, infos and job reads answered: {kinds}")
    finished = [a for a in answers if a[4] == VICTIM and a[0] == "render" and a[1] < signalled
                and a[2] > signalled]
    t.check(finished and all(a[3] == 200 for a in finished),
            f"{VICTIM} answered the renders it had admitted: {len(finished)}")
    after = [a for a in answers if a[1] > exited and a[0] == "render"]
    t.check(after and all(a[3] == 200 and a[4] != VICTIM for a in after),
            f"after {VICTIM} is gone the others render: {len(after)}")
    retried = [e for e in log.values() if "," in e.get("upstream_status", "")]
    t.check(retried, "nginx's log shows retried requests (upstream_status \"503, 200\"...)")
    print(f"drain: nginx retried {len(retried)} requests, e.g. "
          f"{[e.get('upstream_status') for e in retried[:5]]}", file=sys.stderr)
    t.check(not [e for e in log.values() if e.get("status") in (502, 504)],
            "nginx's log has no 502/504")
    # The stopped instance's job went with it: nginx answers 410, not 502.
    status, h, body = lb.request("GET", f"/v1/renders/{doomed}",
                                 headers={"X-Request-Id": "gone-1"})
    p = check_problem(t, status, h, body, 410, "job_gone", f"{VICTIM}'s job after it stopped")
    t.check(VICTIM in p.get("detail", "") and p.get("request_id") == "gone-1"
            and h.get("x-request-id") == "gone-1", f"naming the instance: {p}")
    s = read_events(lb, f"/v1/renders/{doomed}/events", timeout=10)
    t.equal(s.status, 410, "its events too")
    status, h, _ = lb.request("GET", f"/v1/renders/{kept}")
    t.equal((status, h.get("x-nscatter-instance")), (200, "a3"), "a3's job is still there")


def main():
    t = Checks()
    servers, lb = {}, None
    try:
        for name in INSTANCES:
            servers[name] = Server("--instance", name, "--queue", "4")
        lb = Nginx([servers[name].port for name in INSTANCES])
        for test in (test_spread, test_request_id, test_async_routing, test_stream_and_cancel,
                     test_body_limit, test_drain_under_load):
            t.run(test, lb, servers)
    except RuntimeError as e:
        t.check(False, f"setup: {e}")
    finally:
        if lb:
            code = lb.stop()
            t.equal(code, 0, "nginx stops cleanly")
            errors = [line for line in lb.log("error").splitlines()
                      if "[emerg]" in line or "[alert]" in line or "[crit]" in line]
            t.check(not errors, f"nginx's error log has no emerg/alert/crit: {errors[:3]}")
            shutil.rmtree(lb.dir, ignore_errors=True)
        for name, srv in servers.items():
            if srv.alive():
                code = srv.stop()
                t.check(srv.exited_cleanly(code), f"{name} exits 0 without own leaks: {code}")
            srv.__exit__()
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
