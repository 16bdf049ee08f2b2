"""Helpers for the tests of asynchronous jobs and sweeps (tests/http_jobs.py,
tests/http_sweeps.py), on top of nstest_http.py: posting a job, bounded waits for a state,
reading a Server-Sent Events stream (ids, names, multi-line data, comments, whether the
server closed it), the pixel data of an EXR, JSON pointers, and slow path-traced scenes
sized from a measured rate so that "running for a few seconds" holds on any machine.

Python 3 standard library only. Every wait is bounded.
"""
import datetime
import http.client
import json
import math
import re
import struct
import time

from nstest_http import EXR_MAGIC, REQUEST_TIMEOUT_S, problem, server_timing, small_scene

HEX32 = re.compile(r"^[0-9a-f]{32}$")
# RFC 3339 in UTC, as the contract's example: 2026-11-25T10:00:00.123Z
TIMESTAMP = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d{1,9})?Z$")
STATES = ("queued", "running", "done", "failed", "cancelled")
FINISHED = ("done", "failed", "cancelled")
POLL_S = 0.02


# ---------------------------------------------------------------------------------------
# Requests
# ---------------------------------------------------------------------------------------
def post_json(srv, path, doc, headers=None, timeout=REQUEST_TIMEOUT_S):
    """POST a JSON document; returns (status, headers, parsed body or None, raw body)."""
    body = doc if isinstance(doc, (bytes, bytearray)) else json.dumps(doc).encode()
    h = {"Content-Type": "application/json"}
    h.update(headers or {})
    status, headers, raw = srv.request("POST", path, body, h, timeout)
    return status, headers, parse_json(raw), raw


def post_async(srv, scene, prefer="respond-async", headers=None, path="/v1/renders"):
    h = {"Prefer": prefer} if prefer is not None else {}
    h.update(headers or {})
    return post_json(srv, path, scene, h)


def get_json(srv, path, headers=None):
    """GET; returns (status, headers, parsed body or None)."""
    status, headers, raw = srv.request("GET", path, None, headers or {})
    return status, headers, parse_json(raw)


def parse_json(raw):
    try:
        return json.loads(raw.decode("utf-8")) if raw else None
    except ValueError:
        return None


def check_problem(t, status, headers, body, want_status, want_code, what):
    """An RFC 9457 answer with the service's members; returns the problem (or {})."""
    t.equal(status, want_status, f"{what}: status")
    t.check(headers.get("content-type", "").startswith("application/problem+json"),
            f"{what}: problem content type, got {headers.get('content-type')!r}")
    try:
        p = problem(body) if isinstance(body, (bytes, bytearray)) else body
    except ValueError:
        p = None
    if not isinstance(p, dict):
        t.check(False, f"{what}: problem body is a JSON object: {body!r:.200}")
        return {}
    for key in ("type", "title", "status", "detail", "code", "errors"):
        t.check(key in p, f"{what}: problem has '{key}': {p}")
    t.equal(p.get("status"), want_status, f"{what}: problem status member")
    t.equal(p.get("code"), want_code, f"{what}: problem code")
    t.check(isinstance(p.get("errors"), list), f"{what}: errors is a list")
    return p


def wait_until(fn, timeout, interval=POLL_S):
    """Calls fn until it returns something true or timeout passes; returns its last value."""
    deadline = time.monotonic() + timeout
    while True:
        value = fn()
        if value or time.monotonic() >= deadline:
            return value
        time.sleep(interval)


def wait_state(srv, path, states, timeout=REQUEST_TIMEOUT_S, seen=None):
    """Polls the job at path until its state is one of states; returns the job JSON (the
    last one seen when the wait ran out). `seen`, a list, collects every answer."""
    last = {}

    def poll():
        nonlocal last
        status, _, job = get_json(srv, path)
        if status != 200 or not isinstance(job, dict):
            last = {"status": status, "body": job}
            return True  # not a job any more: let the caller's checks say so
        last = job
        if seen is not None:
            seen.append(job)
        return job.get("state") in states

    wait_until(poll, timeout)
    return last


def info(srv):
    return json.loads(srv.request("GET", "/v1/info")[2])


def wait_idle(srv, timeout=REQUEST_TIMEOUT_S):
    """True once nothing is admitted (queue_length 0, no job queued or running)."""
    def idle():
        i = info(srv)
        jobs = i.get("jobs") or {}
        return i.get("queue_length") == 0 and not jobs.get("queued") and not jobs.get("running")
    return bool(wait_until(idle, timeout, 0.05))


def parse_time(text):
    """A contract timestamp as an aware datetime (None when it is not one)."""
    if not isinstance(text, str) or not TIMESTAMP.match(text):
        return None
    return datetime.datetime.fromisoformat(text[:-1] + "+00:00")


def check_job_json(t, job, what, kind="render"):
    """The members of the contract's job JSON, their types, and how they depend on the
    state. Returns the state."""
    if not isinstance(job, dict):
        t.check(False, f"{what}: job JSON is an object: {job!r:.300}")
        return None
    for key in ("id", "kind", "state", "queue_position", "progress", "stage", "timings_ms",
                "created", "started", "finished", "expires", "cancel_requested", "error",
                "links"):
        t.check(key in job, f"{what}: job has '{key}': {sorted(job)}")
    jid, state = job.get("id"), job.get("state")
    t.check(isinstance(jid, str) and HEX32.match(jid), f"{what}: id is 32 lowercase hex: {jid!r}")
    t.equal(job.get("kind"), kind, f"{what}: kind")
    t.check(state in STATES, f"{what}: state {state!r}")
    qp = job.get("queue_position")
    if state == "queued":
        t.check(isinstance(qp, int) and not isinstance(qp, bool) and qp >= 0,
                f"{what}: queue_position of a queued job: {qp!r}")
    else:
        t.equal(qp, None, f"{what}: queue_position when {state}")
    p = job.get("progress")
    t.check(isinstance(p, (int, float)) and not isinstance(p, bool) and 0 <= p <= 1,
            f"{what}: progress in [0, 1]: {p!r}")
    if state == "done":
        t.equal(p, 1, f"{what}: progress when done")
    if state == "queued":
        t.equal(p, 0, f"{what}: progress when queued")
    stage = job.get("stage")
    if state == "running":
        t.check(stage is None or isinstance(stage, str), f"{what}: stage {stage!r}")
    else:
        t.equal(stage, None, f"{what}: stage when {state}")
    timings = job.get("timings_ms")
    t.check(isinstance(timings, dict) and all(
        isinstance(k, str) and isinstance(v, (int, float)) and v >= 0 for k, v in timings.items()),
        f"{what}: timings_ms maps stage names to ms: {timings!r}")
    created, started = parse_time(job.get("created")), parse_time(job.get("started"))
    finished, expires = parse_time(job.get("finished")), parse_time(job.get("expires"))
    t.check(created is not None, f"{what}: created is a UTC timestamp: {job.get('created')!r}")
    if state == "queued":
        t.equal(job.get("started"), None, f"{what}: started when queued")
    if state in ("running", "done"):
        t.check(started is not None, f"{what}: started when {state}: {job.get('started')!r}")
    if state in FINISHED:
        t.check(finished is not None, f"{what}: finished when {state}: {job.get('finished')!r}")
        t.check(expires is not None, f"{what}: expires when {state}: {job.get('expires')!r}")
        if finished and expires:
            t.check(expires > finished, f"{what}: expires after finished")
    else:
        t.equal((job.get("finished"), job.get("expires")), (None, None),
                f"{what}: finished and expires when {state}")
    times = [x for x in (created, started, finished) if x is not None]
    t.check(times == sorted(times), f"{what}: created <= started <= finished")
    t.check(isinstance(job.get("cancel_requested"), bool), f"{what}: cancel_requested is a bool")
    error = job.get("error")
    if state in ("queued", "running", "done"):
        t.equal(error, None, f"{what}: error when {state}")
    elif state == "cancelled":
        t.check(isinstance(error, dict) and error.get("code") == "cancelled",
                f"{what}: error of a cancelled job has code cancelled: {error!r}")
    elif state == "failed":
        t.check(isinstance(error, dict) and error.get("code") and error.get("status"),
                f"{what}: error of a failed job is a problem: {error!r}")
    links = job.get("links")
    base = f"/v1/{'renders' if kind == 'render' else 'sweeps'}/{jid}"
    if kind == "render":
        want = {"self": base, "image": base + "/image", "events": base + "/events"}
    else:
        want = {"self": base, "events": base + "/events", "sheet": base + "/sheet.png",
                "manifest": base + "/manifest.json"}
    t.check(isinstance(links, dict) and all(links.get(k) == v for k, v in want.items()),
            f"{what}: links {links!r}, expected at least {want}")
    if kind == "render":
        r = job.get("render")
        t.check(isinstance(r, dict) and all(k in r for k in ("method", "components", "spp",
                                                             "width", "height")),
                f"{what}: render settings: {r!r}")
    return state


# ---------------------------------------------------------------------------------------
# Server-Sent Events
# ---------------------------------------------------------------------------------------
class Event:
    def __init__(self, event_id, name, data, at):
        self.id, self.name, self.data, self.at = event_id, name, data, at

    def json(self):
        try:
            return json.loads(self.data)
        except ValueError:
            return None

    def __repr__(self):
        return f"Event(id={self.id!r}, {self.name!r}, {self.data[:120]!r})"


class SSEParser:
    """The WHATWG event-stream rules: lines end in LF (a CR before it is dropped); a blank line
    dispatches the event collected so far (none if it has no data); a line starting with ':'
    is a comment; 'field: value' loses one space after the colon; data lines join with LF;
    the id is kept (last_id) across events, as a reconnecting client needs it."""

    def __init__(self):
        self.last_id = None
        self.comments = []  # (time, text after the colon)
        self.fields = []    # every field line, in order, for checks on the raw format
        self._name, self._data, self._id_set = "", [], False

    def feed(self, line, at):
        line = line[:-1] if line.endswith("\n") else line
        line = line[:-1] if line.endswith("\r") else line
        if line == "":
            event = None
            if self._data:
                event = Event(self.last_id if self._id_set else None, self._name or "message",
                              "\n".join(self._data), at)
            self._name, self._data, self._id_set = "", [], False
            return event
        if line.startswith(":"):
            self.comments.append((at, line[1:]))
            return None
        field, colon, value = line.partition(":")
        if colon and value.startswith(" "):
            value = value[1:]
        self.fields.append((field, value))
        if field == "event":
            self._name = value
        elif field == "data":
            self._data.append(value)
        elif field == "id" and "\0" not in value:
            self.last_id, self._id_set = value, True
        return None


class Stream:
    """One GET of an event stream. events, comments, status, headers, and closed: whether the
    server ended the stream (end of body) rather than the reader stopping."""

    def __init__(self):
        self.status, self.headers, self.body = 0, {}, b""
        self.events, self.comments, self.fields, self.raw_lines = [], [], [], []
        self.closed, self.error = False, None


def read_events(srv, path, headers=None, timeout=60, max_events=None, until_comment=False,
                method="GET"):
    """Reads the stream at path until the server closes it, `max_events` events have come
    (then the reader hangs up, as a dropped connection would), a comment has come
    (`until_comment`), or `timeout` seconds pass. The socket's timeout is the time left, so a
    timeout always ends the read (a timed-out socket file cannot be read again)."""
    s = Stream()
    start = time.monotonic()
    conn = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=timeout)
    parser = SSEParser()
    try:
        conn.request(method, path, headers=headers or {})
        resp = conn.getresponse()
        s.status = resp.status
        s.headers = {k.lower(): v for k, v in resp.getheaders()}
        if resp.status != 200 or method == "HEAD":
            s.body = resp.read()
            s.closed = True
            return s
        while True:
            conn.sock.settimeout(max(0.05, timeout - (time.monotonic() - start)))
            line = resp.readline()
            now = time.monotonic() - start
            if not line:
                s.closed = True
                break
            text = line.decode("utf-8")
            s.raw_lines.append(text)
            event = parser.feed(text, now)
            if event is not None:
                s.events.append(event)
                if max_events is not None and len(s.events) >= max_events:
                    break
            if until_comment and parser.comments:
                break
    except (OSError, http.client.HTTPException, UnicodeDecodeError) as e:
        s.error = e
    finally:
        s.comments = parser.comments
        s.fields = parser.fields
        conn.close()
    return s


def check_stream_format(t, s, what):
    """Every event of the contract has an id, a name and JSON data; ids count 1, 2, 3, ...
    from the first event the stream sent."""
    t.equal(s.status, 200, f"{what}: events status")
    t.check(s.headers.get("content-type", "").startswith("text/event-stream"),
            f"{what}: content type {s.headers.get('content-type')!r}")
    for e in s.events:
        t.check(e.id is not None and e.id.isdigit(), f"{what}: event has a numeric id: {e}")
        t.check(isinstance(e.json(), dict), f"{what}: event data is a JSON object: {e}")
    ids = [int(e.id) for e in s.events if e.id and e.id.isdigit()]
    if ids:
        t.equal(ids, list(range(ids[0], ids[0] + len(ids))), f"{what}: ids consecutive")


def check_event_sequence(t, events, what, final="done", sweep=False):
    """The order the contract gives: a `state` queued first, `running` before any stage,
    stage_start/stage_end properly paired, progress in [0, 1] never decreasing, one final
    event last with the job JSON. For sweeps, stages lie between a variant_start and its
    variant_end. Returns the final event's job JSON (or {})."""
    if not events:
        t.check(False, f"{what}: no events")
        return {}
    t.equal(events[0].id, "1", f"{what}: the first event has id 1")
    first = events[0].json() or {}
    t.equal((events[0].name, first.get("state")), ("state", "queued"),
            f"{what}: the first event is the state at creation")
    t.check(isinstance(first.get("queue_position"), int) and first["queue_position"] >= 0,
            f"{what}: the first state names its queue_position: {first}")
    names = [e.name for e in events]
    t.equal(names[-1], final, f"{what}: last event")
    t.equal(sum(n in FINISHED for n in names), 1, f"{what}: exactly one final event: {names}")
    running = [i for i, e in enumerate(events)
               if e.name == "state" and (e.json() or {}).get("state") == "running"]
    stages_at = [i for i, n in enumerate(names) if n.startswith("stage_")]
    if final == "done" or stages_at:
        t.check(running, f"{what}: a state running event: {names}")
    if running and stages_at:
        t.check(running[0] < stages_at[0], f"{what}: running comes before the first stage")
    open_stages, progress, variant = [], 0.0, None
    allowed = {"state", "stage_start", "stage_end", "progress"} | set(FINISHED)
    if sweep:
        allowed |= {"variant_start", "variant_end"}
    for e in events:
        d = e.json() or {}
        t.check(e.name in allowed, f"{what}: known event name {e.name!r}")
        if "progress" in d and e.name not in FINISHED:
            p = d["progress"]
            t.check(isinstance(p, (int, float)) and 0 <= p <= 1, f"{what}: progress in [0, 1]: {e}")
            if isinstance(p, (int, float)):
                t.check(p >= progress, f"{what}: progress never decreases ({progress} then {e})")
                progress = max(progress, p)
        if e.name == "stage_start":
            t.check(isinstance(d.get("stage"), str) and d["stage"], f"{what}: stage named: {e}")
            t.check("progress" in d, f"{what}: stage_start has progress: {e}")
            if sweep:
                t.check(variant is not None, f"{what}: a stage outside any variant: {e}")
            open_stages.append(d.get("stage"))
        elif e.name == "stage_end":
            t.check(open_stages and open_stages[-1] == d.get("stage"),
                    f"{what}: stage_end {d.get('stage')!r} closes the open stage {open_stages}")
            if open_stages:
                open_stages.pop()
            t.check(isinstance(d.get("ms"), (int, float)) and d["ms"] >= 0,
                    f"{what}: stage_end has ms: {e}")
            t.check("progress" in d, f"{what}: stage_end has progress: {e}")
        elif e.name == "progress":
            t.check(d.get("stage") in open_stages,
                    f"{what}: a progress tick names an open stage {open_stages}: {e}")
        elif e.name == "variant_start":
            t.check(variant is None, f"{what}: variant_start {d} while {variant} is open")
            t.check(not open_stages, f"{what}: no stage open at variant_start: {open_stages}")
            variant = d.get("index")
        elif e.name == "variant_end":
            t.equal(d.get("index"), variant, f"{what}: variant_end closes the open variant")
            t.check(not open_stages, f"{what}: no stage open at variant_end: {open_stages}")
            variant = None
    if final == "done":  # a cancelled render may stop inside a stage
        t.equal(open_stages, [], f"{what}: every stage_start has its stage_end")
    job = events[-1].json() or {}
    t.equal(job.get("state"), final, f"{what}: the final event's data is the job JSON")
    if final == "done":
        t.equal(job.get("progress"), 1, f"{what}: progress 1 when done")
    return job


# ---------------------------------------------------------------------------------------
# Images
# ---------------------------------------------------------------------------------------
def exr_pixel_chunks(data):
    """The bytes of a single-part scanline EXR after its header and offset table: the
    compressed pixel chunks alone, without the metadata (timings differ from one render of
    the same pixels to the next; the pixels, and so these bytes, do not)."""
    if not data.startswith(EXR_MAGIC):
        raise ValueError("no EXR magic")
    at, attrs = 8, {}
    while True:
        end = data.index(b"\0", at)
        name = data[at:end].decode("latin-1")
        if not name:
            at = end + 1
            break
        tend = data.index(b"\0", end + 1)
        size, = struct.unpack("<i", data[tend + 1:tend + 5])
        attrs[name] = data[tend + 5:tend + 5 + size]
        at = tend + 5 + size
    xmin, ymin, xmax, ymax = struct.unpack("<iiii", attrs["dataWindow"])
    lines_per_chunk = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16}.get(attrs["compression"][0], 16)
    chunks = math.ceil((ymax - ymin + 1) / lines_per_chunk)
    return data[at + 8 * chunks:]


# ---------------------------------------------------------------------------------------
# Scenes
# ---------------------------------------------------------------------------------------
def pointer_set(doc, pointer, value):
    """RFC 6901 pointer, JSON Patch 'add' on an object member (replace or add) or an array
    element (replace); the parent must exist (KeyError/IndexError otherwise)."""
    parts = [p.replace("~1", "/").replace("~0", "~") for p in pointer.split("/")[1:]]
    parent = doc
    for p in parts[:-1]:
        parent = parent[int(p)] if isinstance(parent, list) else parent[p]
    if isinstance(parent, list):
        parent[int(parts[-1])] = value
    else:
        parent[parts[-1]] = value
    return doc


def pointer_escape(pointer):
    """A pointer as one reference token inside another pointer: / -> ~1, ~ -> ~0."""
    return pointer.replace("~", "~0").replace("/", "~1")


def pt_scene(width, height, spp, seed=1):
    scene = small_scene(width, height)
    scene["render"] = {"method": "pt", "spp": spp, "seed": seed}
    return scene


class PtRate:
    """Milliseconds per pixel-sample of a `pt` render on this server, measured with one short
    synchronous render of the size the slow scenes have (the per-submission overhead weighs
    differently at other sizes), after a first one of 1 spp that makes the pt pipeline (made
    on first use) and has lavapipe compile its shader: llvmpipe compiles a compute shader at
    its first dispatch, inside pt_pass, unless Mesa's shader cache already holds it. With a
    cold cache (a fresh machine, a container) that first pt_pass takes 20 s and more on 2
    cores, over ten times a warm one, and scenes sized from it would end long before the
    checks that need them running. The machines tests run on are shared, so the rate is a
    guess within a few times: scenes that must outlast a test's checks are sized well beyond
    them and cancelled after."""

    SIDE, SPP = 64, 16

    def __init__(self, srv):
        self.ok = False
        ms = None
        for spp in (1, self.SPP):  # 1 spp compiles the shader, the second render measures
            status, headers, _ = srv.render(pt_scene(self.SIDE, self.SIDE, spp))
            stages = server_timing(headers.get("server-timing", "")) if status == 200 else {}
            ms = stages.get("pt_pass")
            self.ok = status == 200 and bool(ms)
            if not self.ok:
                break
        self.ms_per_sample = (ms or 1000.0) / (self.SIDE * self.SIDE * self.SPP)

    def scene(self, seconds, seed=1):
        """A pt scene expected to take about `seconds` (within the limits: 4096 spp, then a
        larger image); returns (scene, expected seconds)."""
        side = self.SIDE
        while True:
            spp = math.ceil(seconds * 1000.0 / (self.ms_per_sample * side * side))
            if spp <= 4096 or side >= 1024:
                spp = max(4, min(spp, 4096))
                return (pt_scene(side, side, spp, seed),
                        self.ms_per_sample * side * side * spp / 1000.0)
            side *= 2
