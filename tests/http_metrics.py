"""Prometheus metrics (GET /metrics, docs/http.md "Metrics") against the real server, read
with the Prometheus client library's own parser (Debian's python3-prometheus-client), never
with a regular expression:
- every family is there with its type and help; the content type is the text format 0.0.4's;
  HEAD answers the same headers, POST answers 405 with Allow;
- nscatter_http_requests_total grows by exactly the requests made (a 404, a 405, a render,
  an asynchronous job, its polls and its image, a body refused from its Content-Length), one
  series per route template, method and status; the duration histogram's _count per route
  by the same;
- nscatter_renders_total grows by the renders, and the stage histogram's _count, _sum and
  buckets by exactly the stages those renders report (Server-Timing, timings_ms), a sweep's
  by each variant's; every histogram's buckets are cumulative, +Inf equal to _count;
- the series stay bounded: 100 requests to distinct unknown paths add no series but
  route="other", distinct job ids share their route template;
- table cache misses, then hits and BVH reuse, for a render that makes its tables and the
  same render again;
- the queue and job gauges agree with /v1/info, idle and with a pt render running;
  device live buffers are back to 0 after renders (a cancelled one included);
- the process metrics are plausible, nscatter_device_info is /v1/info's device;
- without a device /metrics still answers: nscatter_ready 0, no device sample.

Requests whose counts are compared go over one keep-alive connection: the server finishes
a request (and counts it) before it reads the next one from the same connection."""
import collections
import http.client
import json
import math
import os
import secrets
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import REQUEST_TIMEOUT_S, Checks, Server, server_timing, small_scene  # noqa: E402
from nstest_jobs import PtRate, info, wait_idle, wait_state, wait_until  # noqa: E402

try:
    from prometheus_client.parser import text_string_to_metric_families
except ImportError:
    # Debian's package installs into the system Python's dist-packages, which a python3
    # from pyenv or a virtual environment does not search.
    sys.path.append("/usr/lib/python3/dist-packages")
    try:
        from prometheus_client.parser import text_string_to_metric_families
    except ImportError:
        print("FAIL: the Prometheus client library is missing: apt-get install "
              "python3-prometheus-client (scripts/setup.sh test installs it)", file=sys.stderr)
        sys.exit(1)

CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"
# Family names as the parser gives them: a counter's without its _total.
FAMILIES = {
    "nscatter_http_requests": "counter",
    "nscatter_http_request_duration_seconds": "histogram",
    "nscatter_renders": "counter",
    "nscatter_render_stage_duration_seconds": "histogram",
    "nscatter_queue_depth": "gauge",
    "nscatter_queue_capacity": "gauge",
    "nscatter_jobs": "gauge",
    "nscatter_job_store_bytes": "gauge",
    "nscatter_table_cache_hits": "counter",
    "nscatter_table_cache_misses": "counter",
    "nscatter_table_cache_bytes": "gauge",
    "nscatter_idle_work_pending": "gauge",
    "nscatter_idle_work_running": "gauge",
    "nscatter_idle_nodes_made": "counter",
    "nscatter_idle_work_stopped": "counter",
    "nscatter_idle_work_seconds": "counter",
    "nscatter_bvh_reused": "counter",
    "nscatter_camera_reused": "counter",
    "nscatter_sources_reused": "counter",
    "nscatter_single_reused": "counter",
    "nscatter_device_info": "gauge",
    "nscatter_device_live_buffers": "gauge",
    "process_resident_memory_bytes": "gauge",
    "process_virtual_memory_bytes": "gauge",
    "process_start_time_seconds": "gauge",
    "process_cpu_seconds": "counter",
    "process_open_fds": "gauge",
}
REQUESTS = "nscatter_http_requests_total"
DURATION = "nscatter_http_request_duration_seconds"
STAGES = "nscatter_render_stage_duration_seconds"
RENDERS = "nscatter_renders_total"


# ---------------------------------------------------------------------------------------
# One keep-alive connection, and what a scrape holds
# ---------------------------------------------------------------------------------------
class Conn:
    def __init__(self, srv):
        self.c = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=REQUEST_TIMEOUT_S)

    def request(self, method, path, body=None, headers=None):
        self.c.request(method, path, body=body, headers=headers or {})
        resp = self.c.getresponse()
        data = resp.read()
        return resp.status, {k.lower(): v for k, v in resp.getheaders()}, data

    def json(self, method, path, doc=None, headers=None):
        h = dict(headers or {})
        body = None
        if doc is not None:
            body = json.dumps(doc).encode()
            h["Content-Type"] = "application/json"
        status, headers, data = self.request(method, path, body, h)
        try:
            return status, headers, json.loads(data) if data else None
        except ValueError:
            return status, headers, None

    def close(self):
        self.c.close()


class Scrape:
    """The families of one /metrics answer, and its samples by (sample name, labels)."""

    def __init__(self, status, headers, text):
        self.status, self.headers, self.text = status, headers, text
        self.families = {}
        self.duplicates = []
        for f in text_string_to_metric_families(text):
            if f.name in self.families:
                self.duplicates.append(f.name)
            self.families[f.name] = f
        self.samples = {}
        for f in self.families.values():
            for s in f.samples:
                self.samples[(s.name, frozenset(s.labels.items()))] = s.value

    def series(self, name, **match):
        """{labels as a frozenset: value} of one sample name whose labels include match."""
        out = {}
        for (n, labels), v in self.samples.items():
            d = dict(labels)
            if n == name and all(d.get(k) == v2 for k, v2 in match.items()):
                out[labels] = v
        return out

    def value(self, name, default=0.0, **labels):
        return self.samples.get((name, frozenset(labels.items())), default)


def scrape(conn):
    status, headers, data = conn.request("GET", "/metrics")
    return Scrape(status, headers, data.decode("utf-8"))


def requests_by_key(s):
    """{(route, method, status): count} of nscatter_http_requests_total."""
    return {(dict(k)["route"], dict(k)["method"], dict(k)["status"]): v
            for k, v in s.series(REQUESTS).items()}


def delta(after, before):
    keys = set(after) | set(before)
    return {k: after.get(k, 0) - before.get(k, 0) for k in keys
            if after.get(k, 0) != before.get(k, 0)}


def settled_scrape(conn):
    """A scrape after every request made before it has been counted: requests on other
    connections are counted when their answer has been sent, a moment after the client has
    it. Two scrapes in a row that differ only by the first scrape itself."""
    def settled():
        a = requests_by_key(scrape(conn))
        b = scrape(conn)
        return b if delta(requests_by_key(b), a) == {("/metrics", "GET", "200"): 1} else None
    return wait_until(settled, 30, 0.05) or scrape(conn)


def check_histograms(t, s, what):
    """Every histogram series: buckets sorted by le ending at +Inf, cumulative, +Inf equal
    to _count, _sum present and not negative."""
    for f in s.families.values():
        if f.type != "histogram":
            continue
        groups = collections.defaultdict(dict)
        for x in f.samples:
            key = frozenset((k, v) for k, v in x.labels.items() if k != "le")
            if x.name == f.name + "_bucket":
                groups[key].setdefault("buckets", []).append((float(x.labels["le"]), x.value))
            else:
                groups[key][x.name[len(f.name):]] = x.value
        for key, g in groups.items():
            buckets = g.get("buckets", [])
            les = [le for le, _ in buckets]
            counts = [c for _, c in buckets]
            label = f"{what}: {f.name}{dict(key)}"
            t.check(les == sorted(les) and les and les[-1] == math.inf,
                    f"{label}: le ascending to +Inf: {les}")
            t.check(all(a <= b for a, b in zip(counts, counts[1:])),
                    f"{label}: buckets cumulative: {counts}")
            t.check(counts and counts[-1] == g.get("_count"),
                    f"{label}: +Inf bucket {counts[-1] if counts else None} == _count "
                    f"{g.get('_count')}")
            t.check(g.get("_sum", -1) >= 0, f"{label}: _sum {g.get('_sum')}")


def stage_histograms(s, method):
    """{stage: (count, sum, {le: cumulative})} of one method's stage histograms."""
    out = {}
    for (name, labels), v in s.samples.items():
        d = dict(labels)
        if d.get("method") != method or not name.startswith(STAGES):
            continue
        count, total, buckets = out.get(d["stage"], (0, 0.0, {}))
        if name == STAGES + "_count":
            count = v
        elif name == STAGES + "_sum":
            total = v
        elif name == STAGES + "_bucket":
            buckets = dict(buckets)
            buckets[float(d["le"])] = v
        out[d["stage"]] = (count, total, buckets)
    return out


def check_stages(t, before, after, method, renders, what):
    """The stage histograms of `method` grew by exactly the stages of `renders` (each a
    {stage: ms} as the render reported it): the counts, the sums, and every bucket."""
    a, b = stage_histograms(before, method), stage_histograms(after, method)
    want = collections.defaultdict(list)
    for stages in renders:
        for stage, ms in stages.items():
            want[stage].append(ms / 1000.0)
    t.equal(sorted(s for s in b if b[s][0] != a.get(s, (0,))[0]), sorted(want),
            f"{what}: the stages observed")
    for stage, seconds in want.items():
        count0, sum0, buckets0 = a.get(stage, (0, 0.0, {}))
        count1, sum1, buckets1 = b.get(stage, (0, 0.0, {}))
        t.equal(count1 - count0, len(seconds), f"{what}: {stage} _count grew by the renders")
        t.check(abs((sum1 - sum0) - sum(seconds)) <= 1e-5 + 1e-5 * sum(seconds),
                f"{what}: {stage} _sum grew by {sum1 - sum0}, the renders say {sum(seconds)}")
        for le, c1 in buckets1.items():
            if any(abs(x - le) <= 1e-5 * max(le, 1e-3) for x in seconds):
                continue  # reported with fewer digits than the boundary needs
            t.equal(c1 - buckets0.get(le, 0), sum(1 for x in seconds if x <= le),
                    f"{what}: {stage} bucket le={le} grew by the stages within it")


def table_scene(g):
    """The wax sphere with multiple scattering: the render makes (or reuses) tables."""
    scene = small_scene(24, 16)
    scene["materials"]["wax"]["g"] = g
    scene["render"].update({"components": ["surface", "multiple"], "vrls": 1000})
    return scene


# ---------------------------------------------------------------------------------------
# Tests
# ---------------------------------------------------------------------------------------
def test_format(t, srv, started_wall):
    conn = Conn(srv)
    try:
        s = scrape(conn)
        t.equal(s.status, 200, "GET /metrics")
        t.equal(s.headers.get("content-type"), CONTENT_TYPE, "text format 0.0.4")
        t.check(s.text.endswith("\n"), "the text ends with a line feed")
        t.equal(s.duplicates, [], "no family twice")
        for name, kind in FAMILIES.items():
            f = s.families.get(name)
            if t.check(f is not None, f"family {name} present"):
                t.equal(f.type, kind, f"{name} type")
                t.check(f.documentation, f"{name} has help")
        # The parser makes an untyped family of a sample that belongs to no TYPE: none here.
        for f in s.families.values():
            t.check(f.type in ("counter", "gauge", "histogram"), f"{f.name} typed: {f.type}")
            t.check(f.name.startswith(("nscatter_", "process_")), f"{f.name} prefixed")
        check_histograms(t, s, "first scrape")
        status, headers, body = conn.request("HEAD", "/metrics")
        t.equal((status, body), (200, b""), "HEAD /metrics")
        t.equal(headers.get("content-type"), CONTENT_TYPE, "HEAD content type")
        status, headers, body = conn.request("POST", "/metrics", b"{}",
                                             {"Content-Type": "application/json"})
        t.equal(status, 405, "POST /metrics")
        t.equal(headers.get("allow"), "GET, HEAD", "Allow on /metrics")
        status, headers, body = conn.request("GET", "/metrics?x=1")
        t.equal(status, 400, "an unknown query parameter is refused, as on every route")

        # The device is /v1/info's, and the gauges of an idle service are its.
        i = info(srv)
        dev = i.get("device", {})
        t.equal(s.series("nscatter_device_info"),
                {frozenset({"name": dev.get("name"), "driver": dev.get("driver"),
                            "driver_info": dev.get("driver_info"),
                            "api_version": dev.get("api_version")}.items()): 1.0},
                "nscatter_device_info")
        t.equal(s.value("nscatter_build_info", version=i.get("version")), 1.0, "build info")
        t.equal(s.value("nscatter_ready"), 1.0, "ready")
        t.equal(s.value("nscatter_queue_capacity"), i["limits"]["queue_capacity"], "capacity")

        # The process collector's families.
        now = time.time()
        rss = s.value("process_resident_memory_bytes")
        t.check(1 << 20 < rss <= s.value("process_virtual_memory_bytes"),
                f"resident {rss} within virtual {s.value('process_virtual_memory_bytes')}")
        start = s.value("process_start_time_seconds")
        t.check(started_wall - 2 <= start <= now + 1,
                f"start time {start}: the server started at {started_wall}, now {now}")
        fds = s.value("process_open_fds")
        t.check(4 <= fds < s.value("process_max_fds", 1e9), f"open fds {fds}")
        cpu = s.value("process_cpu_seconds_total")
        t.check(cpu > 0, f"cpu seconds {cpu}")
        t.check(scrape(conn).value("process_cpu_seconds_total") >= cpu, "cpu seconds grow")
    finally:
        conn.close()


def test_counters_exact(t, srv):
    conn = Conn(srv)
    try:
        a = settled_scrape(conn)
        t.equal(conn.request("GET", "/no/such/path")[0], 404, "a 404")
        t.equal(conn.request("DELETE", "/livez")[0], 405, "a 405")
        t.equal(conn.request("HEAD", "/metrics")[0], 200, "HEAD /metrics")
        scene = small_scene(16, 16)
        status, headers, body = conn.request("POST", "/v1/renders", json.dumps(scene).encode(),
                                             {"Content-Type": "application/json"})
        t.equal(status, 200, f"a synchronous render: {body[:200]!r}")
        sync_stages = server_timing(headers.get("server-timing", ""))
        status, headers, job = conn.json("POST", "/v1/renders", small_scene(16, 8),
                                         {"Prefer": "respond-async"})
        t.equal(status, 202, "an asynchronous render")
        path = (job or {}).get("links", {}).get("self", "/v1/renders/none")
        polls = 0
        deadline = time.monotonic() + REQUEST_TIMEOUT_S
        while time.monotonic() < deadline:
            status, _, job = conn.json("GET", path)
            polls += 1
            if status != 200 or job.get("state") in ("done", "failed", "cancelled"):
                break
            time.sleep(0.02)
        t.equal((job or {}).get("state"), "done", "the asynchronous render is done")
        t.equal(conn.request("GET", path + "/image")[0], 200, "its image")
        b = scrape(conn)

        want = {("/metrics", "GET", "200"): 1,  # scrape a itself
                ("other", "GET", "404"): 1,
                ("/livez", "DELETE", "405"): 1,
                ("/metrics", "HEAD", "200"): 1,
                ("/v1/renders", "POST", "200"): 1,
                ("/v1/renders", "POST", "202"): 1,
                ("/v1/renders/{id}", "GET", "200"): polls,
                ("/v1/renders/{id}/image", "GET", "200"): 1}
        t.equal(delta(requests_by_key(b), requests_by_key(a)), want,
                "nscatter_http_requests_total grew by exactly the requests made")
        per_route = collections.Counter()
        for (route, _, _), n in want.items():
            per_route[route] += n
        for route, n in per_route.items():
            grew = (b.value(DURATION + "_count", route=route) -
                    a.value(DURATION + "_count", route=route))
            t.equal(grew, n, f"{DURATION}_count of {route}")
        t.equal(b.value(RENDERS, method="nn", state="done") -
                a.value(RENDERS, method="nn", state="done"), 2, "two nn renders done")
        t.equal(sum(delta(b.series(RENDERS), a.series(RENDERS)).values()), 2,
                "no other render counted")
        check_stages(t, a, b, "nn", [sync_stages, (job or {}).get("timings_ms", {})],
                     "a synchronous and an asynchronous render")
        check_histograms(t, b, "after renders")
    finally:
        conn.close()


def test_refused_up_front(t, srv):
    """A body declared too large is answered before it is read, on a connection that then
    closes: counted all the same, once its answer has gone."""
    conn = Conn(srv)
    try:
        a = requests_by_key(settled_scrape(conn))
        head = (b"POST /v1/renders HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                b"Content-Type: application/json\r\nContent-Length: 100000000000\r\n\r\n")
        raw = srv.raw(head, read_timeout=20)
        t.check(raw.startswith(b"HTTP/1.1 413"), f"413 at once: {raw[:40]!r}")
        grown = {}

        def counted():  # everything but the scrapes themselves
            nonlocal grown
            grown = {k: v for k, v in delta(requests_by_key(scrape(conn)), a).items()
                     if k[0] != "/metrics"}
            return grown
        wait_until(counted, 30, 0.05)
        t.equal(grown, {("/v1/renders", "POST", "413"): 1}, "the 413 counted")
    finally:
        conn.close()


def test_sweep_variants(t, srv):
    conn = Conn(srv)
    try:
        a = settled_scrape(conn)
        body = {"scene": small_scene(16, 8),
                "variants": [{"/materials/wax/ior": 1.3}, {"/materials/wax/ior": 1.4},
                             {"/materials/wax/g": 0.5}]}
        status, _, job = conn.json("POST", "/v1/sweeps", body)
        t.equal(status, 202, "a sweep")
        path = (job or {}).get("links", {}).get("self", "/v1/sweeps/none")
        job = wait_state(srv, path, ("done", "failed", "cancelled"))
        t.equal(job.get("state"), "done", "the sweep is done")
        status, _, manifest = conn.json("GET", path + "/manifest.json")
        variants = (manifest or {}).get("variants", [])
        t.equal(len(variants), 3, "three variants in the manifest")
        b = scrape(conn)
        t.equal(b.value(RENDERS, method="nn", state="done") -
                a.value(RENDERS, method="nn", state="done"), 3, "one render per variant")
        # The first variant to render carries the sweep's parse and queue.
        check_stages(t, a, b, "nn", [v.get("timings_ms", {}) for v in variants],
                     "a sweep's variants")
    finally:
        conn.close()


def test_cardinality(t, srv):
    conn = Conn(srv)
    try:
        # Two jobs, so that two real ids are asked for too.
        ids = []
        for _ in range(2):
            status, _, job = conn.json("POST", "/v1/renders", small_scene(8, 8),
                                       {"Prefer": "respond-async"})
            ids.append((job or {}).get("id", "0" * 32))
        for i in ids:
            wait_state(srv, f"/v1/renders/{i}", ("done", "failed", "cancelled"))
        a = settled_scrape(conn)
        for n in range(100):
            path = ("/unknown-%d" % n, "/v1/nope/%d" % n, "/v1/renders/%s/nope%d" %
                    (secrets.token_hex(16), n), "/a/b/c/%d.png" % n)[n % 4]
            t.check(conn.request("GET", path)[0] == 404, f"404 for {path}")
        for _ in range(10):
            t.check(conn.request("GET", "/v1/renders/" + secrets.token_hex(16))[0] == 404,
                    "404 for an id that never was")
        for i in ids:
            t.check(conn.request("GET", f"/v1/renders/{i}")[0] == 200, "a job")
            t.check(conn.request("GET", f"/v1/renders/{i}/image")[0] == 200, "its image")
        b = scrape(conn)
        d = delta(requests_by_key(b), requests_by_key(a))
        t.equal(d, {("/metrics", "GET", "200"): 1, ("other", "GET", "404"): 100,
                    ("/v1/renders/{id}", "GET", "404"): 10,
                    ("/v1/renders/{id}", "GET", "200"): 2,
                    ("/v1/renders/{id}/image", "GET", "200"): 2},
                "distinct paths and ids counted under their templates")
        allowed = {("/metrics", "GET", "200"), ("other", "GET", "404"),
                   ("/v1/renders/{id}", "GET", "404"), ("/v1/renders/{id}", "GET", "200"),
                   ("/v1/renders/{id}/image", "GET", "200")}
        t.check(set(requests_by_key(b)) - set(requests_by_key(a)) <= allowed,
                f"no new series but these: {set(requests_by_key(b)) - set(requests_by_key(a))}")
        routes_a = {dict(k)["route"] for k in a.series(DURATION + "_count")}
        routes_b = {dict(k)["route"] for k in b.series(DURATION + "_count")}
        t.check(routes_b - routes_a <= {"other", "/v1/renders/{id}", "/v1/renders/{id}/image",
                                        "/metrics"},
                f"duration series by template only: new {routes_b - routes_a}")
        values = {v for (_, labels) in b.samples for _, v in labels}
        leaked = [v for v in values if any(i in v for i in ids) or "unknown-" in v
                  or "nope" in v or len(v) >= 32 and all(c in "0123456789abcdef" for c in v)]
        t.equal(leaked, [], "no path or id in any label value")
        t.check(len(b.samples) - len(a.samples) <= 2 * (17 + 2) + 4,
                f"series grew by {len(b.samples) - len(a.samples)} samples only")
    finally:
        conn.close()


def test_table_cache(t, srv):
    conn = Conn(srv)
    try:
        names = ("nscatter_table_cache_hits_total", "nscatter_table_cache_misses_total",
                 "nscatter_bvh_reused_total", "nscatter_camera_reused_total",
                 "nscatter_sources_reused_total")
        # A g no other test renders: its tables are not in the cache yet.
        scene = json.dumps(table_scene(0.37)).encode()
        h = {"Content-Type": "application/json"}
        a = scrape(conn)
        t.equal(conn.request("POST", "/v1/renders", scene, h)[0], 200, "render making tables")
        b = scrape(conn)
        t.equal(conn.request("POST", "/v1/renders", scene, h)[0], 200, "the same again")
        c = scrape(conn)
        hits, misses, bvh, camera, sources = (b.value(n) - a.value(n) for n in names)
        t.check(misses > 0, f"the first render made tables: misses +{misses}")
        t.equal(hits, 0, "and found none in the cache")
        hits, misses, bvh, camera, sources = (c.value(n) - b.value(n) for n in names)
        t.check(hits > 0, f"the second render found its tables: hits +{hits}")
        t.equal(misses, 0, "and made none")
        t.equal(bvh, 1, "and kept the BVH")
        t.equal(camera, 1, "and the camera pass")
        t.equal(sources, 1, "and the light's sources")
        t.check(c.value("nscatter_table_cache_bytes") > 0,
                f"the cache holds bytes: {c.value('nscatter_table_cache_bytes')}")
        t.equal(c.value(RENDERS, method="nn", state="done") -
                a.value(RENDERS, method="nn", state="done"), 2, "two renders counted")
    finally:
        conn.close()


def gauges_agree(t, s, i, what):
    t.equal(s.value("nscatter_queue_depth", -1), i.get("queue_length"), f"{what}: queue depth")
    t.equal(s.value("nscatter_queue_capacity", -1), i["limits"]["queue_capacity"],
            f"{what}: queue capacity")
    t.equal({dict(k)["state"]: v for k, v in s.series("nscatter_jobs").items()},
            {k: float(v) for k, v in i.get("jobs", {}).items()}, f"{what}: jobs by state")
    t.equal(s.value("nscatter_job_store_bytes", -1), i.get("job_store_bytes_used"),
            f"{what}: job store bytes")
    t.equal(s.value("nscatter_job_store_capacity_bytes", -1), i["limits"]["job_store_bytes"],
            f"{what}: job store capacity")


def test_queue_gauges_and_live_buffers(t, srv):
    conn = Conn(srv)
    try:
        t.check(wait_idle(srv), "idle")
        gauges_agree(t, scrape(conn), info(srv), "idle")
        rate = PtRate(srv)
        t.check(rate.ok, "pt rate measured")
        scene, _ = rate.scene(60)
        a = scrape(conn)
        status, _, job = conn.json("POST", "/v1/renders", scene, {"Prefer": "respond-async"})
        t.equal(status, 202, "a long pt render")
        path = (job or {}).get("links", {}).get("self", "/v1/renders/none")
        job = wait_state(srv, path, ("running", "done", "failed", "cancelled"))
        t.equal(job.get("state"), "running", "it runs")
        s, i = scrape(conn), info(srv)
        t.equal(s.value("nscatter_queue_depth"), 1.0, "one admitted")
        gauges_agree(t, s, i, "running")
        t.check(s.value("nscatter_jobs", state="running") == 1.0, "one job running")
        t.equal(conn.request("DELETE", path)[0], 202, "cancel it")
        job = wait_state(srv, path, ("done", "failed", "cancelled"))
        t.equal(job.get("state"), "cancelled", "cancelled")
        t.check(wait_idle(srv), "idle again")
        b = scrape(conn)
        t.equal(b.value(RENDERS, method="pt", state="cancelled") -
                a.value(RENDERS, method="pt", state="cancelled"), 1, "a pt render cancelled")
        gauges_agree(t, b, info(srv), "after")
        t.equal(b.value("nscatter_device_live_buffers", -1), 0.0,
                "live buffers back to 0 after renders")
        t.equal(b.value("nscatter_device_live_buffers", -1),
                info(srv)["device"]["live_buffers"], "as /v1/info says")
    finally:
        conn.close()


def test_no_device(t):
    with Server("--device", "no-such-device-nscatter-test") as srv:
        conn = Conn(srv)
        try:
            s = scrape(conn)
            t.equal(s.status, 200, "/metrics without a device")
            t.equal(s.value("nscatter_ready", -1), 0.0, "not ready")
            t.equal(s.series("nscatter_device_info"), {}, "no device sample")
            t.check("nscatter_device_info" in s.families, "the family is still declared")
            t.equal(s.value("nscatter_queue_depth", -1), 0.0, "nothing admitted")
            t.check(s.value("process_resident_memory_bytes") > 0, "process metrics")
        finally:
            conn.close()


def main():
    t = Checks()
    started_wall = time.time()
    with Server("--queue", "2") as srv:
        t.run(test_format, srv, started_wall)
        for test in (test_counters_exact, test_refused_up_front, test_sweep_variants,
                     test_cardinality, test_table_cache, test_queue_gauges_and_live_buffers):
            t.run(test, srv)
        t.current = "end"
        conn = Conn(srv)
        check_histograms(t, scrape(conn), "last scrape")
        conn.close()
        code = srv.stop()
        t.check(srv.exited_cleanly(code), f"clean exit on SIGTERM (status {code}, own leaks "
                f"{srv.own_leaks()[:2]})")
        if t.failed:
            print(srv.log_text()[-4000:], file=sys.stderr)
    t.run(test_no_device)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
