"""Asynchronous render jobs (docs/http.md, issue 17's contract) against the real server:
- POST /v1/renders with Prefer: respond-async: 202, Location, Preference-Applied, the job
  JSON with every member; validation still happens before anything is queued;
- a job queued behind a running one goes queued -> running -> done, its image is 409
  job_not_done until then, then PNG, EXR and half EXR by Accept or ?format, pixel for pixel
  the synchronous render of the same scene;
- its events (Server-Sent Events): state first, stages paired, progress never decreasing,
  a final `done` with the job JSON, then the stream closes; a finished job's stream replays
  the same log; Last-Event-ID (header or query) resumes after an event, also after a
  dropped connection; a silent stream gets `: keep-alive` comments (--sse-keepalive 1);
- DELETE: a queued job leaves the queue (200) and the job behind it moves up; a running
  path-traced job is cancelled (202, then `cancelled` within seconds) and the next job runs;
  a finished job is discarded (204, then 410 job_gone everywhere);
- unknown and malformed ids are 404, wrong methods 405 with Allow, the list is newest first;
- finished jobs expire after --job-ttl and are evicted oldest first over --job-bytes;
- a synchronous render whose client hangs up is cancelled: the next request is served at
  once and nothing stays admitted.
Slow jobs are path-traced scenes sized from a rate measured on the server itself (PtRate),
so that "still running" holds on fast and slow machines alike; each test cancels its slow
jobs before it ends, so a cancellation that works keeps the whole file short."""
import json
import os
import socket
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import (EXR_MAGIC, PNG_SIGNATURE, Checks, Server, exr_channels,  # noqa: E402
                         png_decode_rgb8, server_timing, small_scene)
from nstest_jobs import (FINISHED, HEX32, STATES, PtRate, check_event_sequence,  # noqa: E402
                         check_job_json, check_problem, check_stream_format, exr_pixel_chunks,
                         get_json, info, parse_time, post_async, post_json, read_events,
                         wait_idle, wait_state, wait_until)

RUNNING_WAIT_S = 60  # for a job to leave the queue once the one ahead of it is cancelled
CANCEL_WITHIN_S = 5  # "cancelled at the next dispatch boundary"
BLOCKER_S = 12       # how long a job that must stay running is sized to take
DEFAULT_TTL_S = 3600
DEFAULT_JOB_BYTES = 1 << 30


def job_path(jid, tail=""):
    return f"/v1/renders/{jid}{tail}"


def submit(t, srv, scene, what):
    """Posts scene as a job; returns its id (None when refused)."""
    status, headers, job, raw = post_async(srv, scene)
    if not t.equal(status, 202, f"{what}: 202 Accepted ({raw[:300]!r})"):
        return None
    return job.get("id")


def start_blocker(t, srv, rate, what="blocker"):
    """A path-traced job sized to run BLOCKER_S seconds, once it runs; returns its id."""
    scene, _ = rate.scene(BLOCKER_S)
    jid = submit(t, srv, scene, what)
    if jid:
        job = wait_state(srv, job_path(jid), ("running",) + FINISHED, RUNNING_WAIT_S)
        t.equal(job.get("state"), "running", f"{what} runs")
    return jid


def finish(srv, jid):
    """Cleanup: cancels or discards a job whatever its state and waits until it is over."""
    if jid:
        srv.request("DELETE", job_path(jid))
        wait_state(srv, job_path(jid), FINISHED, 30)


def state_order_ok(states):
    """States seen by polling never go back: queued* running* (done|failed|cancelled)."""
    rank = [STATES.index(s) if s in ("queued", "running") else 2 for s in states]
    return rank == sorted(rank)


# ---------------------------------------------------------------------------------------
# Info, admission, the job JSON
# ---------------------------------------------------------------------------------------
def test_info_limits_and_counts(t, srv):
    i = info(srv)
    limits = i.get("limits", {})
    t.equal(limits.get("job_ttl_s"), DEFAULT_TTL_S, "limits.job_ttl_s default")
    t.equal(limits.get("job_store_bytes"), DEFAULT_JOB_BYTES, "limits.job_store_bytes default")
    jobs = i.get("jobs")
    t.check(isinstance(jobs, dict) and set(jobs) == set(STATES),
            f"info.jobs counts every state: {jobs}")
    t.equal(jobs, {s: 0 for s in STATES} if isinstance(jobs, dict) else None,
            "no jobs on a fresh server")
    t.equal(i.get("queue_length"), 0, "queue_length on a fresh server")


def test_async_accepted(t, srv):
    before = info(srv).get("jobs", {})
    scene = small_scene(48, 32)
    status, headers, job, raw = post_async(srv, scene)
    t.equal(status, 202, f"Prefer: respond-async -> 202 ({raw[:300]!r})")
    if status != 202:
        return
    t.check(headers.get("content-type", "").startswith("application/json"),
            f"job JSON content type: {headers.get('content-type')!r}")
    jid = job.get("id", "")
    t.check(HEX32.match(jid or ""), f"id is 32 lowercase hex: {jid!r}")
    t.equal(headers.get("location"), job_path(jid), "Location")
    t.equal(headers.get("preference-applied"), "respond-async", "Preference-Applied")
    state = check_job_json(t, job, "202 body")
    t.check(state in ("queued", "running", "done"), f"a new job is queued (or already further): "
            f"{state}")
    t.equal(job.get("render", {}).get("method"), "nn", "render.method")
    t.equal(job.get("render", {}).get("components"), ["surface"], "render.components")
    t.equal((job.get("render", {}).get("width"), job.get("render", {}).get("height"),
             job.get("render", {}).get("spp")), (48, 32, 1), "render width, height, spp")
    t.check("parse" in (job.get("timings_ms") or {}), f"timings_ms has parse: {job}")
    done = wait_state(srv, job_path(jid), FINISHED)
    t.equal(done.get("state"), "done", "the job finishes")
    check_job_json(t, done, "done job")

    # Prefer among other preferences, in either order.
    for prefer in ("respond-async, wait=0", "wait=5, respond-async", "respond-async; x=1"):
        status, headers, job, raw = post_async(srv, scene, prefer=prefer)
        t.equal(status, 202, f"Prefer: {prefer} -> 202 ({raw[:200]!r})")
        t.equal(headers.get("preference-applied"), "respond-async",
                f"Preference-Applied for Prefer: {prefer}")
        if status == 202:
            wait_state(srv, job_path(job["id"]), FINISHED)
    # Without respond-async the call is synchronous exactly as before.
    for prefer in (None, "wait=10", "return=minimal"):
        status, headers, _, raw = post_async(srv, scene, prefer=prefer)
        t.equal(status, 200, f"Prefer: {prefer} -> synchronous 200")
        t.equal(raw[:8], PNG_SIGNATURE, f"Prefer: {prefer} -> the PNG itself")
        t.check("respond-async" not in headers.get("preference-applied", ""),
                "a synchronous answer does not claim respond-async")
    after = info(srv).get("jobs", {})
    t.equal(after.get("done", 0) - before.get("done", 0), 4, "four more done jobs in info.jobs")


def test_validation_before_queueing(t, srv):
    """Bad requests with Prefer: respond-async are answered like synchronous ones and queue
    nothing."""
    before_info = info(srv).get("jobs")
    before_list = get_json(srv, "/v1/renders")[2]
    bad = small_scene(8, 8)
    bad["materials"]["wax"]["g"] = 2
    status, headers, _, raw = post_async(srv, bad)
    p = check_problem(t, status, headers, raw, 422, "invalid_scene", "invalid scene, async")
    t.check(any(e.get("pointer") == "/materials/wax/g" for e in p.get("errors", [])),
            f"names the field: {p}")
    status, headers, _, raw = post_async(srv, b'{"camera": {,}}')
    check_problem(t, status, headers, raw, 400, "malformed_json", "malformed, async")
    status, headers, raw = srv.request("POST", "/v1/renders",
                                       json.dumps(small_scene(8, 8)).encode(),
                                       {"Content-Type": "text/plain", "Prefer": "respond-async"})
    check_problem(t, status, headers, raw, 415, "unsupported_media_type", "wrong type, async")
    t.equal(info(srv).get("jobs"), before_info, "info.jobs unchanged by refused requests")
    t.equal(get_json(srv, "/v1/renders")[2], before_list, "the job list unchanged")


def test_accept_is_not_read_at_post(t, srv):
    status, _, job, raw = post_async(srv, small_scene(16, 8),
                                     headers={"Accept": "image/x-exr; format=half"})
    t.equal(status, 202, f"async POST with an EXR Accept ({raw[:200]!r})")
    if status != 202:
        return
    wait_state(srv, job_path(job["id"]), FINISHED)
    status, headers, data = srv.request("GET", job_path(job["id"], "/image"))
    t.equal(status, 200, "image")
    t.equal(headers.get("content-type"), "image/png", "the image is negotiated when fetched")
    t.equal(data[:8], PNG_SIGNATURE, "PNG by default")


def test_queued_running_done(t, srv, rate):
    blocker = start_blocker(t, srv, rate)
    jid = None
    try:
        scene = small_scene(48, 32)
        status, headers, job, raw = post_async(srv, scene)
        t.equal(status, 202, "job behind the blocker")
        jid = job.get("id") if status == 202 else None
        if not jid or not blocker:
            return
        t.equal((job.get("state"), job.get("queue_position")), ("queued", 0),
                "behind one running job: queued, position 0 (next)")
        status, _, job = get_json(srv, job_path(jid))
        t.equal(status, 200, "GET the queued job")
        check_job_json(t, job, "queued job")
        t.equal((job.get("state"), job.get("queue_position"), job.get("progress"),
                 job.get("stage"), job.get("started")), ("queued", 0, 0, None, None),
                "queued job members")
        jobs = info(srv).get("jobs", {})
        t.equal((jobs.get("queued"), jobs.get("running")), (1, 1), "info.jobs: 1 queued, 1 running")
        t.equal(info(srv).get("queue_length"), 2, "both hold a queue slot")
        for path in (job_path(jid, "/image"), job_path(blocker, "/image")):
            status, headers, raw = srv.request("GET", path)
            p = check_problem(t, status, headers, raw, 409, "job_not_done", f"{path} before done")
            t.check(("queued" if path.startswith(job_path(jid)) else "running")
                    in p.get("detail", ""), f"the detail says the state: {p.get('detail')!r}")
        status, _, running = get_json(srv, job_path(blocker))
        check_job_json(t, running, "running job")
        t.check(isinstance(running.get("stage"), str), f"a running job names its stage: {running}")
        seen = []
        finish(srv, blocker)
        done = wait_state(srv, job_path(jid), FINISHED, RUNNING_WAIT_S, seen)
        t.equal(done.get("state"), "done", "the queued job ran once the blocker was gone")
        check_job_json(t, done, "done job")
        t.check(state_order_ok([j.get("state") for j in seen]),
                f"states in order: {[j.get('state') for j in seen]}")
        progress = [j.get("progress", 0) for j in seen]
        t.check(progress == sorted(progress), f"progress never decreases: {progress}")
        timings = done.get("timings_ms", {})
        t.check("parse" in timings and "ray_pass" in timings,
                f"timings_ms has the stages so far: {timings}")
        finished, expires = parse_time(done.get("finished")), parse_time(done.get("expires"))
        if finished and expires:
            t.check(abs((expires - finished).total_seconds() - DEFAULT_TTL_S) <= 1,
                    f"expires = finished + job ttl: {done.get('finished')} {done.get('expires')}")
        # The log of the whole life: queued, running, stages, done.
        s = read_events(srv, job_path(jid, "/events"), timeout=30)
        check_stream_format(t, s, "replayed log")
        check_event_sequence(t, s.events, "replayed log")
        t.check(s.closed, "the stream of a finished job closes")
    finally:
        finish(srv, blocker)


def test_queue_full(t, srv, rate):
    """Async jobs and sweeps hold a queue slot until they finish: with --queue 8 taken by a
    running job, six queued ones and a sweep, the next render of any kind is 503 queue_full."""
    capacity = info(srv).get("limits", {}).get("queue_capacity")
    t.equal(capacity, 8, "queue capacity as configured")
    blocker = start_blocker(t, srv, rate)
    queued, sweep = [], None
    try:
        queued = [submit(t, srv, small_scene(8, 8), f"queued {i}") for i in range(6)]
        status, _, job, raw = post_json(srv, "/v1/sweeps", {"scene": small_scene(8, 8),
                                                            "variants": [{"/render/seed": 2}]})
        t.equal(status, 202, f"a sweep takes the last slot ({raw[:200]!r})")
        sweep = (job or {}).get("id") if status == 202 else None
        t.equal(info(srv).get("queue_length"), 8, "eight admitted")
        for what, send in (("async", lambda: post_async(srv, small_scene(8, 8))),
                           ("sync", lambda: post_async(srv, small_scene(8, 8), prefer=None)),
                           ("sweep", lambda: post_json(srv, "/v1/sweeps", {
                               "scene": small_scene(8, 8), "variants": [{"/render/seed": 3}]}))):
            status, headers, _, raw = send()
            check_problem(t, status, headers, raw, 503, "queue_full", f"{what} on a full queue")
            t.check(headers.get("retry-after", "").isdigit(), f"{what}: Retry-After")
        if not (blocker and queued[-1]):
            return
        status, _, raw = srv.request("DELETE", job_path(queued[-1]))
        t.equal(status, 200, "a queued job cancelled")
        queued.append(submit(t, srv, small_scene(8, 8), "a job in the freed slot"))
    finally:
        for jid in queued:
            finish(srv, jid)
        if sweep:
            srv.request("DELETE", f"/v1/sweeps/{sweep}")
        finish(srv, blocker)


# ---------------------------------------------------------------------------------------
# The image
# ---------------------------------------------------------------------------------------
def test_image_negotiation(t, srv):
    scene = small_scene(48, 32)
    jid = submit(t, srv, scene, "image job")
    if not jid:
        return
    t.equal(wait_state(srv, job_path(jid), FINISHED).get("state"), "done", "image job done")
    path = job_path(jid, "/image")

    status, headers, png = srv.request("GET", path)
    t.equal(status, 200, "GET image")
    t.equal(headers.get("content-type"), "image/png", "PNG by default")
    for h in ("server-timing", "x-nscatter-device", "x-nscatter-stats"):
        t.check(headers.get(h), f"image answer has {h} as the sync answer does")
    t.check("ray_pass" in headers.get("server-timing", ""), "Server-Timing names the stages")
    try:
        w, h, rows = png_decode_rgb8(png)
        t.equal((w, h), (48, 32), "PNG size")
        s_status, _, sync_png = srv.render(scene)
        t.equal(s_status, 200, "synchronous render of the same scene")
        t.equal(png_decode_rgb8(sync_png)[2], rows, "PNG pixels equal the synchronous render's")
    except ValueError as e:
        t.check(False, f"PNG decodes: {e}")

    status, headers, exr = srv.request("GET", path, headers={"Accept": "image/x-exr"})
    t.equal((status, headers.get("content-type")), (200, "image/x-exr"), "EXR by Accept")
    t.equal(exr[:4], EXR_MAGIC, "EXR magic")
    if exr[:4] == EXR_MAGIC:
        t.equal(exr_channels(exr), {"R": 2, "G": 2, "B": 2}, "float channels by default")
        _, _, sync_exr = srv.render(scene, accept="image/x-exr")
        t.equal(exr_pixel_chunks(exr), exr_pixel_chunks(sync_exr),
                "EXR pixel data equals the synchronous render's")
    for accept, query, want in (("image/x-exr", "?format=half", 1),
                                ("image/x-exr; format=half", "", 1),
                                ("image/x-exr", "?format=float", 2)):
        status, headers, data = srv.request("GET", path + query, headers={"Accept": accept})
        t.equal(status, 200, f"Accept {accept!r} {query}")
        if status == 200 and data[:4] == EXR_MAGIC:
            t.equal(set(exr_channels(data).values()), {want}, f"pixel type for {accept!r} {query}")
    status, headers, raw = srv.request("GET", path + "?format=half")
    check_problem(t, status, headers, raw, 400, "bad_query", "format with a PNG answer")
    status, headers, raw = srv.request("GET", path + "?size=2")
    check_problem(t, status, headers, raw, 400, "bad_query", "unknown query parameter")
    status, headers, raw = srv.request("GET", path, headers={"Accept": "text/html"})
    check_problem(t, status, headers, raw, 406, "not_acceptable", "Accept text/html")
    status, headers, raw = srv.request("HEAD", path)
    t.equal((status, headers.get("content-type"), raw), (200, "image/png", b""), "HEAD image")
    status, headers, raw = srv.request("HEAD", job_path(jid))
    t.equal((status, raw), (200, b""), "HEAD job")
    t.check(headers.get("content-type", "").startswith("application/json"), "HEAD job type")


# ---------------------------------------------------------------------------------------
# Events
# ---------------------------------------------------------------------------------------
def test_events_live_replay_and_resume(t, srv, rate):
    scene, expected_s = rate.scene(1.5)
    jid = submit(t, srv, scene, "events job")
    if not jid:
        return
    path = job_path(jid, "/events")
    live = read_events(srv, path, timeout=60 + 10 * expected_s)
    check_stream_format(t, live, "live stream")
    job = check_event_sequence(t, live.events, "live stream")
    check_job_json(t, job, "done event data")
    t.check(live.closed, f"the live stream closes after done ({live.error})")
    t.check(all(e.id is not None for e in live.events), "every event has an id")
    names = [e.name for e in live.events]
    t.check("stage_start" in names and "stage_end" in names, f"stage events: {names}")
    t.check("pt_pass" in [(e.json() or {}).get("stage") for e in live.events],
            "the pt pass is a stage")
    ticks = [e for e in live.events if e.name == "progress"]
    if len(live.events) > 1:
        span = live.events[-1].at - live.events[0].at
        t.check(len(ticks) <= 12 * span + 3, f"at most ~10 progress ticks a second: {len(ticks)} "
                f"in {span:.2f} s")

    replay = read_events(srv, path, timeout=30)
    check_stream_format(t, replay, "replay")
    t.check(replay.closed, "the replay closes")
    t.equal([(e.id, e.name) for e in replay.events], [(e.id, e.name) for e in live.events],
            "the replay is the same log")
    t.equal([e.json() for e in replay.events[:-1]], [e.json() for e in live.events[:-1]],
            "with the same data")
    if len(replay.events) < 4:
        t.check(False, f"enough events to resume after the third: {replay.events}")
        return
    third = replay.events[2].id
    rest = [(e.id, e.name, e.data) for e in replay.events[3:]]
    for headers, query, how in (({"Last-Event-ID": third}, "", "Last-Event-ID header"),
                                ({}, f"?last_event_id={third}", "last_event_id query")):
        s = read_events(srv, path + query, headers=headers, timeout=30)
        t.equal(s.status, 200, how)
        t.equal([(e.id, e.name, e.data) for e in s.events], rest,
                f"{how} {third}: exactly the events after it")
        t.check(s.closed, f"{how}: closes")
    s = read_events(srv, path, headers={"Last-Event-ID": replay.events[-1].id}, timeout=30)
    # Nothing left to send of a finished job: 204, which stops an EventSource reconnecting.
    t.equal((s.status, s.events, s.closed), (204, [], True), "resuming after the last event")

    # A live stream dropped after three events, resumed with the third's id.
    scene, expected_s = rate.scene(1.5, seed=2)
    jid = submit(t, srv, scene, "dropped stream job")
    if not jid:
        return
    path = job_path(jid, "/events")
    first = read_events(srv, path, timeout=60, max_events=3)
    t.equal(len(first.events), 3, "three events before the drop")
    if len(first.events) == 3:
        second = read_events(srv, path, headers={"Last-Event-ID": first.events[2].id},
                             timeout=60 + 10 * expected_s)
        t.check(second.closed, "the resumed stream runs to the end")
        whole = read_events(srv, path, timeout=30)
        t.equal([(e.id, e.name) for e in first.events + second.events],
                [(e.id, e.name) for e in whole.events],
                "before the drop + after the resume = the whole log")
        t.equal(whole.events[-1].name if whole.events else None, "done", "the job finished")
    status, headers, raw = srv.request("HEAD", path)
    t.equal(status, 200, "HEAD events")
    t.check(headers.get("content-type", "").startswith("text/event-stream"), "HEAD events type")


def test_keepalive_comments(t, srv, rate):
    """--sse-keepalive 1: the stream of a job waiting in the queue says nothing but
    ': keep-alive' comments."""
    blocker = start_blocker(t, srv, rate)
    jid = None
    try:
        jid = submit(t, srv, small_scene(16, 16), "queued job")
        if not jid or not blocker:
            return
        s = read_events(srv, job_path(jid, "/events"), timeout=4, until_comment=True)
        t.equal(s.status, 200, "events of the queued job")
        t.equal([e.name for e in s.events], ["state"], "only its queued state so far")
        t.check(s.comments, f"a comment within 4 s (error {s.error})")
        if s.comments:
            at, text = s.comments[0]
            t.equal(":" + text, ": keep-alive", "the keep-alive comment")
            last = s.events[-1].at if s.events else 0.0
            t.check(0.5 <= at - last <= 3.0, f"after about a second of silence: {at - last:.2f} s")
        finish(srv, blocker)
        done = wait_state(srv, job_path(jid), FINISHED, RUNNING_WAIT_S)
        t.equal(done.get("state"), "done", "the queued job completes")
    finally:
        finish(srv, blocker)


# ---------------------------------------------------------------------------------------
# DELETE
# ---------------------------------------------------------------------------------------
def test_delete_queued(t, srv, rate):
    blocker = start_blocker(t, srv, rate)
    first = second = None
    try:
        first = submit(t, srv, small_scene(16, 16), "first queued")
        second = submit(t, srv, small_scene(16, 16), "second queued")
        if not (blocker and first and second):
            return
        t.equal(get_json(srv, job_path(second))[2].get("queue_position"), 1,
                "second queued: position 1")
        before = info(srv).get("jobs", {})
        status, headers, raw = srv.request("DELETE", job_path(first))
        t.equal(status, 200, "DELETE of a queued job")
        job = json.loads(raw) if status == 200 else {}
        check_job_json(t, job, "DELETE answer")
        t.equal(job.get("state"), "cancelled", "cancelled at once")
        job = get_json(srv, job_path(first))[2]
        t.equal((job.get("state"), job.get("queue_position")), ("cancelled", None),
                "GET after DELETE")
        t.equal(get_json(srv, job_path(second))[2].get("queue_position"), 0,
                "the job behind it moved up")
        after = info(srv).get("jobs", {})
        t.equal((after.get("queued"), after.get("cancelled")),
                (before.get("queued", 0) - 1, before.get("cancelled", 0) + 1),
                f"info.jobs: {before} -> {after}")
        t.equal(info(srv).get("queue_length"), 2, "its queue slot is free")
        s = read_events(srv, job_path(first, "/events"), timeout=30)
        check_event_sequence(t, s.events, "cancelled while queued", final="cancelled")
        t.check(not any(e.name.startswith("stage") for e in s.events), "it never ran a stage")
        status, headers, raw = srv.request("GET", job_path(first, "/image"))
        p = check_problem(t, status, headers, raw, 409, "job_not_done", "image of a cancelled job")
        t.check("cancelled" in p.get("detail", ""), f"the detail says cancelled: {p}")
        finish(srv, blocker)
        t.equal(wait_state(srv, job_path(second), FINISHED, RUNNING_WAIT_S).get("state"), "done",
                "the job behind it runs")
        # A cancelled job is finished: DELETE discards it.
        status, _, raw = srv.request("DELETE", job_path(first))
        t.equal((status, raw), (204, b""), "DELETE of a cancelled job: 204, no body")
        status, headers, raw = srv.request("GET", job_path(first))
        check_problem(t, status, headers, raw, 410, "job_gone", "GET after discarding")
    finally:
        finish(srv, blocker)


def live_buffers(srv):
    return (info(srv).get("device") or {}).get("live_buffers")


def test_delete_running(t, srv, rate):
    buffers_before = live_buffers(srv)
    t.check(isinstance(buffers_before, int), f"info.device.live_buffers: {buffers_before!r}")
    blocker = start_blocker(t, srv, rate)
    nxt = None
    try:
        nxt = submit(t, srv, small_scene(16, 16), "next job")
        if not (blocker and nxt):
            return
        t0 = time.monotonic()
        status, headers, raw = srv.request("DELETE", job_path(blocker))
        t.equal(status, 202, "DELETE of a running job")
        job = json.loads(raw) if status == 202 else {}
        check_job_json(t, job, "202 answer")
        # Running when the answer was made; the worker may have stopped it an instant later.
        t.check(job.get("state") in ("running", "cancelled")
                and job.get("cancel_requested") is True,
                f"running (or just cancelled), cancel requested: {job.get('state')}, "
                f"{job.get('cancel_requested')}")
        job = wait_state(srv, job_path(blocker), FINISHED, 30)
        took = time.monotonic() - t0
        t.equal(job.get("state"), "cancelled", "the running job is cancelled")
        t.check(took <= CANCEL_WITHIN_S, f"within {CANCEL_WITHIN_S} s: {took:.2f} s")
        check_job_json(t, job, "cancelled job")
        t.equal(job.get("cancel_requested"), True, "cancel_requested stays true")
        status, headers, raw = srv.request("GET", job_path(blocker, "/image"))
        check_problem(t, status, headers, raw, 409, "job_not_done", "image of a cancelled job")
        s = read_events(srv, job_path(blocker, "/events"), timeout=30)
        check_event_sequence(t, s.events, "cancelled while running", final="cancelled")
        t.check(s.closed, "its stream closes")
        done = wait_state(srv, job_path(nxt), FINISHED, RUNNING_WAIT_S)
        took = time.monotonic() - t0
        t.equal(done.get("state"), "done", "the next job starts and completes")
        t.check(took < CANCEL_WITHIN_S + 3, f"without waiting for the blocker's {BLOCKER_S} s: "
                f"{took:.2f} s")
        # The cancelled pt render freed every device buffer it made (pt caches nothing).
        t.equal(live_buffers(srv), buffers_before, "device buffers back after the cancel")
    finally:
        finish(srv, blocker)


def test_delete_finished(t, srv):
    jid = submit(t, srv, small_scene(16, 16), "finished job")
    if not jid:
        return
    t.equal(wait_state(srv, job_path(jid), FINISHED).get("state"), "done", "done")
    before = info(srv).get("jobs", {})
    status, headers, raw = srv.request("DELETE", job_path(jid))
    t.equal((status, raw), (204, b""), "DELETE of a done job: 204, no body")
    t.equal(info(srv).get("jobs", {}).get("done"), before.get("done", 0) - 1,
            "info.jobs.done counts it no more")
    for method, tail in (("GET", ""), ("GET", "/image"), ("GET", "/events"), ("DELETE", "")):
        status, headers, raw = srv.request(method, job_path(jid, tail))
        check_problem(t, status, headers, raw, 410, "job_gone", f"{method} {tail or 'job'} after")
    status, headers, raw = srv.request("HEAD", job_path(jid))
    t.equal(status, 410, "HEAD after discarding")
    jobs = (get_json(srv, "/v1/renders")[2] or {}).get("jobs", [])
    t.check(jid not in [j.get("id") for j in jobs], "not listed any more")


# ---------------------------------------------------------------------------------------
# Ids, methods, the list
# ---------------------------------------------------------------------------------------
def test_unknown_and_malformed_ids(t, srv):
    never = "0123456789abcdef0123456789abcdef"
    for method, tail in (("GET", ""), ("DELETE", ""), ("GET", "/image"), ("GET", "/events")):
        status, headers, raw = srv.request(method, job_path(never, tail))
        check_problem(t, status, headers, raw, 404, "not_found", f"{method} unknown id {tail}")
    for bad in ("xyz", never[:31], never + "0", never.upper(), "0123456789abcdef0123456789abcdeg",
                "%30123456789abcdef0123456789abcde", "-1", ""):
        status, headers, raw = srv.request("GET", f"/v1/renders/{bad}/image")
        check_problem(t, status, headers, raw, 404, "not_found", f"malformed id {bad!r}")
    jid = submit(t, srv, small_scene(8, 8), "a job")
    if jid:
        wait_state(srv, job_path(jid), FINISHED)
        for tail in ("/nope", "/image/x", "/events/"):
            status, headers, raw = srv.request("GET", job_path(jid, tail))
            check_problem(t, status, headers, raw, 404, "not_found", f"no such path {tail}")


def allow_set(headers):
    return {m.strip() for m in headers.get("allow", "").split(",") if m.strip()}


def test_methods_405(t, srv):
    jid = submit(t, srv, small_scene(8, 8), "a job")
    if not jid:
        return
    wait_state(srv, job_path(jid), FINISHED)
    cases = [("/v1/renders", ("PUT", "DELETE", "PATCH"), {"GET", "HEAD", "POST"}),
             (job_path(jid), ("POST", "PUT", "PATCH"), {"GET", "HEAD", "DELETE"}),
             (job_path(jid, "/image"), ("POST", "PUT", "DELETE"), {"GET", "HEAD"}),
             (job_path(jid, "/events"), ("POST", "PUT", "DELETE"), {"GET", "HEAD"})]
    for path, methods, allowed in cases:
        for method in methods:
            status, headers, raw = srv.request(method, path, b"{}",
                                               {"Content-Type": "application/json"})
            check_problem(t, status, headers, raw, 405, "method_not_allowed", f"{method} {path}")
            t.equal(allow_set(headers), allowed, f"Allow on {path}")


def test_list_newest_first(t, srv):
    a = submit(t, srv, small_scene(8, 8), "list job a")
    b = submit(t, srv, small_scene(8, 8), "list job b")
    if not (a and b):
        return
    wait_state(srv, job_path(b), FINISHED)
    status, headers, body = get_json(srv, "/v1/renders")
    t.equal(status, 200, "GET /v1/renders")
    jobs = (body or {}).get("jobs")
    if not t.check(isinstance(jobs, list), f"a list of jobs: {body!r:.300}"):
        return
    for j in jobs[:3]:
        check_job_json(t, j, "listed job")
    ids = [j.get("id") for j in jobs]
    t.check(a in ids and b in ids and ids.index(b) < ids.index(a), "the newer job first")
    created = [parse_time(j.get("created")) for j in jobs]
    t.check(None not in created and created == sorted(created, reverse=True),
            "newest first by created")
    t.check(all(j.get("kind") == "render" for j in jobs), "renders only")
    status, headers, raw = srv.request("HEAD", "/v1/renders")
    t.equal((status, raw), (200, b""), "HEAD /v1/renders")


# ---------------------------------------------------------------------------------------
# A synchronous client that hangs up
# ---------------------------------------------------------------------------------------
def test_sync_disconnect_cancels(t, srv, rate):
    """The long render is sized far beyond the checks (they take a second or two when it is
    cancelled), so that even a rate measured under a heavier load than now cannot make it
    end on its own while they run."""
    scene, expected_s = rate.scene(40)
    body = json.dumps(scene).encode()
    request = (b"POST /v1/renders HTTP/1.1\r\nHost: 127.0.0.1\r\n"
               b"Content-Type: application/json\r\nContent-Length: " + str(len(body)).encode()
               + b"\r\n\r\n" + body)
    sock = socket.create_connection(("127.0.0.1", srv.port), timeout=30)
    try:
        sock.sendall(request)
        admitted = wait_until(lambda: info(srv).get("queue_length") == 1, 30)
        t.check(admitted, "the long synchronous render is admitted")
        time.sleep(1.0)
    finally:
        sock.close()
    t0 = time.monotonic()
    status, headers, data = srv.render(small_scene(16, 16), timeout=expected_s + 120)
    took = time.monotonic() - t0
    t.equal(status, 200, "the next request is served")
    t.check(took < min(5.0, expected_s / 4), f"promptly: {took:.2f} s, against "
            f"{expected_s:.1f} s expected for the abandoned render")
    waited = server_timing(headers.get("server-timing", "")).get("queue")
    t.check(waited is not None and waited < 5000, f"it hardly waited for the worker: {waited} ms")
    t.check(wait_until(lambda: info(srv).get("queue_length") == 0, 10),
            "queue_length back to 0")
    jobs = info(srv).get("jobs", {})
    t.equal((jobs.get("queued"), jobs.get("running")), (0, 0), "no job queued or running")


# ---------------------------------------------------------------------------------------
# Expiry and the byte budget (servers of their own)
# ---------------------------------------------------------------------------------------
def test_ttl_expiry(t):
    with Server("--job-ttl", "1") as srv:
        t.equal(info(srv).get("limits", {}).get("job_ttl_s"), 1, "limits.job_ttl_s as configured")
        rate = PtRate(srv)
        t.check(rate.ok, "pt rate measured")
        # Running longer than the TTL does not expire a job: the TTL starts when it finishes.
        scene, _ = rate.scene(BLOCKER_S)
        slow = submit(t, srv, scene, "slow job")
        if not slow:
            return
        t.equal(wait_state(srv, job_path(slow), ("running",) + FINISHED, RUNNING_WAIT_S)
                .get("state"), "running", "slow job runs")
        time.sleep(2.0)
        status, _, job = get_json(srv, job_path(slow))
        t.equal((status, (job or {}).get("state")), (200, "running"),
                "a job running longer than the TTL is still there")
        finish(srv, slow)
        jid = submit(t, srv, small_scene(16, 16), "small job")
        if not jid:
            return
        job = wait_state(srv, job_path(jid), FINISHED, RUNNING_WAIT_S)
        t.equal(job.get("state"), "done", "small job done")
        status = srv.request("GET", job_path(jid, "/image"))[0]
        t.equal(status, 200, "its image right after it finished")
        finished, expires = parse_time(job.get("finished")), parse_time(job.get("expires"))
        if finished and expires:
            t.check(abs((expires - finished).total_seconds() - 1) <= 0.01,
                    f"expires = finished + 1 s: {job.get('finished')} {job.get('expires')}")
        gone = wait_until(lambda: srv.request("GET", job_path(jid))[0] == 410, 4, 0.1)
        t.check(gone, "410 about a second after it finished")
        for tail in ("", "/image", "/events"):
            status, headers, raw = srv.request("GET", job_path(jid, tail))
            check_problem(t, status, headers, raw, 410, "job_gone", f"expired job {tail}")
        status, headers, raw = srv.request("GET", job_path(slow))
        check_problem(t, status, headers, raw, 410, "job_gone", "the cancelled job expired too")
        code = srv.stop()
        t.check(srv.exited_cleanly(code), f"clean exit (status {code})")
        if t.failed:
            print(srv.log_text()[-3000:], file=sys.stderr)


def test_job_bytes_eviction(t):
    # Two 64 x 64 images: 49152 bytes each as float RGB, the form a job keeps to answer PNG,
    # EXR and half alike. One fits in 80000 bytes, two do not.
    budget = 80000
    with Server("--job-bytes", str(budget)) as srv:
        t.equal(info(srv).get("limits", {}).get("job_store_bytes"), budget,
                "limits.job_store_bytes as configured")
        older = submit(t, srv, small_scene(64, 64), "older job")
        if not older:
            return
        t.equal(wait_state(srv, job_path(older), FINISHED).get("state"), "done", "older done")
        t.equal(srv.request("GET", job_path(older, "/image"))[0], 200, "older image kept alone")
        newer = submit(t, srv, small_scene(64, 64), "newer job")
        if not newer:
            return
        t.equal(wait_state(srv, job_path(newer), FINISHED).get("state"), "done", "newer done")
        status, headers, raw = srv.request("GET", job_path(older))
        check_problem(t, status, headers, raw, 410, "job_gone", "the older job is evicted")
        t.equal(srv.request("GET", job_path(newer, "/image"))[0], 200, "the newer job is kept")
        # An image over the whole budget would be dropped as it finished: refused up front.
        before = info(srv).get("jobs", {})
        status, headers, job, raw = post_async(srv, small_scene(128, 128))
        check_problem(t, status, headers, raw, 422, "limit_exceeded", "a render over --job-bytes")
        t.equal(info(srv).get("jobs", {}), before, "nothing admitted for it")
        code = srv.stop()
        t.check(srv.exited_cleanly(code), f"clean exit (status {code})")
        if t.failed:
            print(srv.log_text()[-3000:], file=sys.stderr)


def test_event_stream_limit(t, srv, rate):
    """32 open streams at most; streams whose clients hung up free their places (the server
    looks at each quiet stream's socket every second)."""
    blocker = start_blocker(t, srv, rate)
    queued = submit(t, srv, small_scene(8, 8), "a job waiting behind the blocker")
    socks = []
    try:
        if not (blocker and queued):
            return
        path = job_path(queued, "/events")
        for _ in range(32):
            sock = socket.create_connection(("127.0.0.1", srv.port), timeout=10)
            sock.sendall(f"GET {path} HTTP/1.1\r\nHost: x\r\n\r\n".encode())
            socks.append(sock)
        for sock in socks:  # each one answered (200, streaming) before the next check
            t.check(sock.recv(64).startswith(b"HTTP/1.1 200"), "a stream opens")
        s = read_events(srv, path, timeout=10)
        check_problem(t, s.status, s.headers, s.body, 503, "too_many_streams", "stream 33")
        t.check(s.headers.get("retry-after"), "with Retry-After")
        for sock in socks:
            sock.close()
        socks = []
        deadline = time.monotonic() + 5
        status = None
        while time.monotonic() < deadline and status != 200:
            time.sleep(0.5)
            status = read_events(srv, path, timeout=2, max_events=1).status
        t.equal(status, 200, "the closed streams' places are free again within 5 s")
    finally:
        for sock in socks:
            sock.close()
        finish(srv, blocker)
        finish(srv, queued)


def main():
    t = Checks()
    with Server("--queue", "8", "--sse-keepalive", "1") as srv:
        t.run(test_info_limits_and_counts, srv)
        rate = PtRate(srv)
        t.current = "pt rate"
        t.check(rate.ok, "a pt render to measure the rate")
        print(f"pt: {rate.ms_per_sample * 1e3:.3f} us per pixel-sample", file=sys.stderr)
        for test in (test_async_accepted, test_validation_before_queueing,
                     test_accept_is_not_read_at_post, test_image_negotiation,
                     test_delete_finished, test_unknown_and_malformed_ids, test_methods_405,
                     test_list_newest_first):
            t.run(test, srv)
        for test in (test_queued_running_done, test_queue_full, test_events_live_replay_and_resume,
                     test_keepalive_comments, test_delete_queued, test_delete_running,
                     test_sync_disconnect_cancels, test_event_stream_limit):
            t.run(test, srv, rate)
            wait_idle(srv, 60)
        t.current = "end"
        t.check(wait_idle(srv, 30), "nothing left admitted")
        t.equal(srv.request("GET", "/livez")[0], 200, "/livez at the end")
        code = srv.stop()
        t.check(srv.exited_cleanly(code), f"clean exit on SIGTERM (status {code}, own leaks "
                f"{srv.own_leaks()[:2]})")
        if t.failed:
            print(srv.log_text()[-4000:], file=sys.stderr)
    t.run(test_ttl_expiry)
    t.run(test_job_bytes_eviction)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
