"""Sweeps (issue 17's contract) against the real server: one scene rendered with many sets
of overrides (JSON pointers into the scene).
- both forms: a list of variants, and a grid whose first pointer varies slowest;
- every variant's image is pixel for pixel the synchronous render of the scene with the
  override applied by this test (EXR pixel data compared byte for byte);
- variants are rendered grouped by their media's table key (g, albedo), in their own order
  within a group; `reused` says "bvh" after the first and "tables" when an earlier variant
  had the same key, never "tables" for a new key;
- events: variant_start/variant_end around each variant's stages, in render order;
- refusals: one 422 invalid_sweep naming the variant and the pointer in the request body, a
  pointer whose parent does not exist, a bad base scene, more than 256 variants;
- manifest.json, and sheet.png growing with the number of variants;
- DELETE of a running sweep cancels it and every variant not rendered yet;
- examples/sweep.py, run as a user would, saves the sheet, the manifest and the images, and
  cancels its sweep on Ctrl-C."""
import copy
import json
import os
import re
import select
import signal
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import (EXR_MAGIC, PNG_SIGNATURE, Checks, Server, png_chunks,  # noqa: E402
                         png_decode_rgb8, png_texts, small_scene)
from nstest_jobs import (FINISHED, HEX32, PtRate, check_event_sequence,  # noqa: E402
                         check_job_json, check_problem, check_stream_format, exr_pixel_chunks,
                         get_json, info, pointer_escape, pointer_set, post_json, read_events,
                         wait_idle, wait_state)

MAX_VARIANTS = 256
CANCEL_WITHIN_S = 5
SOURCE_DIR = os.environ.get("NSCATTER_SOURCE_DIR",
                            os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
EXAMPLE = os.path.join(SOURCE_DIR, "examples", "sweep.py")
G, IOR, ALBEDO = "/materials/wax/g", "/materials/wax/ior", "/materials/wax/albedo"


def sweep_scene(width=32, height=24):
    """The wax sphere with the multiple-scattering component, so that variants use tables.
    boundary "off": the sweep's contract does not depend on the boundary model, and the
    walks' 20,000 light paths per material would be most of each 32x24 variant's time
    (http_scatter renders walks, the default, over HTTP)."""
    scene = small_scene(width, height)
    scene["render"].update({"components": ["surface", "multiple"], "vrls": 1000, "boundary": "off"})
    return scene


def tiny_scene():
    return small_scene(8, 8)


def sweep_path(sid, tail=""):
    return f"/v1/sweeps/{sid}{tail}"


def post_sweep(srv, body):
    return post_json(srv, "/v1/sweeps", body)


def submit(t, srv, body, what):
    """Posts a sweep; returns its 202 job JSON ({} when refused)."""
    status, headers, job, raw = post_sweep(srv, body)
    if not t.equal(status, 202, f"{what}: 202 ({raw[:300]!r})"):
        return {}
    sid = (job or {}).get("id", "")
    t.equal(headers.get("location"), sweep_path(sid), f"{what}: Location")
    return job


def variant_scene(base, overrides):
    scene = copy.deepcopy(base)
    for pointer, value in overrides.items():
        pointer_set(scene, pointer, copy.deepcopy(value))
    return scene


def check_sweep_json(t, sweep, overrides, what):
    """The sweep's job JSON: kind sweep, its links, one entry per variant with its overrides,
    a render order that is a permutation of the indices."""
    state = check_job_json(t, sweep, what, kind="sweep")
    variants = sweep.get("variants")
    if not t.check(isinstance(variants, list) and len(variants) == len(overrides),
                   f"{what}: {len(overrides)} variants: {variants!r:.300}"):
        return state
    sid = sweep.get("id")
    for i, v in enumerate(variants):
        t.equal(v.get("index"), i, f"{what}: variant {i} index")
        t.equal(v.get("overrides"), overrides[i], f"{what}: variant {i} overrides")
        t.check(v.get("state") in ("queued", "running", "done", "failed", "cancelled"),
                f"{what}: variant {i} state {v.get('state')!r}")
        t.equal(v.get("image"), sweep_path(sid, f"/images/{i}"), f"{what}: variant {i} image link")
        t.check(isinstance(v.get("timings_ms"), dict), f"{what}: variant {i} timings_ms")
        t.check(isinstance(v.get("reused"), list) and
                set(v["reused"]) <= {"bvh", "camera", "tables", "sources", "single"},
                f"{what}: variant {i} reused {v.get('reused')!r}")
    order = sweep.get("order")
    t.check(isinstance(order, list) and sorted(order) == list(range(len(overrides))),
            f"{what}: order is a permutation of the indices: {order!r}")
    current = sweep.get("current_variant")
    t.check(current is None or current in range(len(overrides)), f"{what}: current_variant")
    if state != "running":
        t.equal(current, None, f"{what}: current_variant when {state}")
    return state


def check_variant_events(t, events, sweep, what):
    """variant_start in render order with its position in that order, variant_end with the
    same state, timings and reuse as the sweep JSON says."""
    starts = [e.json() or {} for e in events if e.name == "variant_start"]
    ends = [e.json() or {} for e in events if e.name == "variant_end"]
    order = sweep.get("order") or []
    t.equal([d.get("index") for d in starts], order, f"{what}: variant_start in render order")
    t.equal([d.get("position") for d in starts], list(range(len(order))),
            f"{what}: variant_start positions")
    t.equal([d.get("index") for d in ends], order, f"{what}: variant_end in render order")
    by_index = {v.get("index"): v for v in sweep.get("variants") or []}
    for d in ends:
        v = by_index.get(d.get("index"), {})
        t.equal((d.get("state"), d.get("reused"), d.get("timings_ms")),
                (v.get("state"), v.get("reused"), v.get("timings_ms")),
                f"{what}: variant_end {d.get('index')} agrees with the sweep JSON")


def check_images_match_sync(t, srv, sweep, base, what):
    """Every done variant's image, as EXR, carries the pixels of a synchronous render of the
    base scene with its overrides; the PNG is the default."""
    for v in sweep.get("variants") or []:
        i = v.get("index")
        path = sweep_path(sweep["id"], f"/images/{i}")
        status, headers, exr = srv.request("GET", path, headers={"Accept": "image/x-exr"})
        t.equal((status, headers.get("content-type")), (200, "image/x-exr"), f"{what}: image {i}")
        scene = variant_scene(base, v.get("overrides") or {})
        s_status, _, sync = srv.render(scene, accept="image/x-exr")
        t.equal(s_status, 200, f"{what}: synchronous render of variant {i}")
        if status == 200 and s_status == 200 and exr[:4] == EXR_MAGIC:
            t.check(exr_pixel_chunks(exr) == exr_pixel_chunks(sync),
                    f"{what}: variant {i} pixels equal the synchronous render of "
                    f"{scene['materials']}")
        status, headers, png = srv.request("GET", path)
        t.equal((status, headers.get("content-type"), png[:8]), (200, "image/png", PNG_SIGNATURE),
                f"{what}: image {i} is a PNG by default")
        for h in ("server-timing", "x-nscatter-device"):
            t.check(headers.get(h), f"{what}: image {i} has {h}")


def sheet_size(t, srv, sid, what):
    status, headers, data = srv.request("GET", sweep_path(sid, "/sheet.png"))
    t.equal((status, headers.get("content-type")), (200, "image/png"), f"{what}: sheet.png")
    try:
        chunks = png_chunks(data)
    except ValueError as e:
        t.check(False, f"{what}: sheet.png is a valid PNG: {e}")
        return 0, 0
    ihdr = chunks[0][1]
    width, height = int.from_bytes(ihdr[0:4], "big"), int.from_bytes(ihdr[4:8], "big")
    t.check(png_texts(data).get("Software", "").startswith("nscatter"),
            f"{what}: sheet.png names its software")
    return width, height


# ---------------------------------------------------------------------------------------
# Tests
# ---------------------------------------------------------------------------------------
def test_info_limit(t, srv):
    t.equal(info(srv).get("limits", {}).get("max_sweep_variants"), MAX_VARIANTS,
            "limits.max_sweep_variants")


def test_variants_form(t, srv):
    base = sweep_scene()
    overrides = [{G: 0.5}, {G: 0.37}, {G: 0.5, IOR: 1.3}]
    job = submit(t, srv, {"scene": base, "variants": overrides}, "variants sweep")
    if not job:
        return
    sid = job.get("id")
    t.check(HEX32.match(sid or ""), "sweep id is 32 lowercase hex")
    check_sweep_json(t, job, overrides, "202 body")
    live = read_events(srv, sweep_path(sid, "/events"), timeout=300)
    check_stream_format(t, live, "sweep events")
    final = check_event_sequence(t, live.events, "sweep events", sweep=True)
    t.check(live.closed, f"the stream closes after done ({live.error})")
    status, headers, sweep = get_json(srv, sweep_path(sid))
    t.equal(status, 200, "GET sweep")
    if check_sweep_json(t, sweep, overrides, "done sweep") != "done":
        return
    check_sweep_json(t, final, overrides, "done event data")
    t.equal([v.get("state") for v in sweep["variants"]], ["done"] * 3, "every variant done")
    # Grouped by table key (g 0.5: variants 0 and 2; g 0.37: variant 1), in order within.
    t.equal(sweep.get("order"), [0, 2, 1], "render order grouped by table key")
    check_variant_events(t, live.events, sweep, "sweep events")
    reused = {v["index"]: v.get("reused") or [] for v in sweep["variants"]}
    for i in sweep["order"][1:]:
        t.check("bvh" in reused[i], f"variant {i} kept the BVH: {reused[i]}")
    t.check("tables" in reused[2], f"variant 2 has variant 0's g and albedo: {reused[2]}")
    t.check("tables" not in reused[1], f"variant 1's g is new: {reused[1]}")
    check_images_match_sync(t, srv, sweep, base, "variants sweep")
    for n in ("3", "-1", "abc", "1x"):
        status, headers, raw = srv.request("GET", sweep_path(sid, f"/images/{n}"))
        check_problem(t, status, headers, raw, 404, "not_found", f"images/{n}")

    status, headers, manifest = get_json(srv, sweep_path(sid, "/manifest.json"))
    t.equal(status, 200, "manifest.json")
    t.check(headers.get("content-type", "").startswith("application/json"), "manifest type")
    manifest = manifest or {}
    t.equal((manifest.get("id"), manifest.get("state")), (sid, "done"), "manifest id and state")
    keys = ("index", "overrides", "state", "timings_ms", "reused")
    t.equal([{k: v.get(k) for k in keys} for v in manifest.get("variants") or []],
            [{k: v.get(k) for k in keys} for v in sweep["variants"]],
            "manifest variants agree with the sweep")
    t.check(all(set(keys) <= set(v) for v in manifest.get("variants") or [{}]),
            "every manifest entry has index, overrides, state, timings_ms, reused")
    width, height = sheet_size(t, srv, sid, "variants sweep")
    t.check(width > 0 and height > 0, "sheet has a size")

    replay = read_events(srv, sweep_path(sid, "/events"), timeout=30)
    t.equal([(e.id, e.name) for e in replay.events], [(e.id, e.name) for e in live.events],
            "a finished sweep's stream replays its log")
    status, _, raw = srv.request("HEAD", sweep_path(sid))
    t.equal((status, raw), (200, b""), "HEAD sweep")
    renders = (get_json(srv, "/v1/renders")[2] or {}).get("jobs", [])
    t.check(sid not in [j.get("id") for j in renders], "sweeps are not in the render list")


def test_grid_form(t, srv):
    base = sweep_scene()
    albedos = [[0.9, 0.9, 0.9], [0.98, 0.962, 0.75]]
    grid = {ALBEDO: albedos, IOR: [1.3, 1.5]}
    overrides = [{ALBEDO: a, IOR: ior} for a in albedos for ior in (1.3, 1.5)]
    job = submit(t, srv, {"scene": base, "grid": grid}, "grid sweep")
    if not job:
        return
    sid = job["id"]
    check_sweep_json(t, job, overrides, "grid 202 body")
    sweep = wait_state(srv, sweep_path(sid), FINISHED, 300)
    if check_sweep_json(t, sweep, overrides, "grid sweep") != "done":
        t.check(False, f"grid sweep done: {sweep!r:.500}")
        return
    t.equal(sweep.get("order"), [0, 1, 2, 3], "already grouped: render order is index order")
    reused = {v["index"]: v.get("reused") or [] for v in sweep["variants"]}
    for i in (1, 2, 3):
        t.check("bvh" in reused[i], f"grid variant {i} kept the BVH: {reused[i]}")
    for i in (1, 3):
        t.check("tables" in reused[i], f"grid variant {i} only changes ior: {reused[i]}")
    check_images_match_sync(t, srv, sweep, base, "grid sweep")

    # Three axes' order without the cost: the first pointer slowest, the last fastest. The
    # last one adds a key the base scene does not have (JSON Patch "add").
    base = tiny_scene()
    t.check("exposure" not in base["render"], "the base scene has no render.exposure")
    grid = {"/render/seed": [1, 2], "/camera/fov": [30, 40, 50], "/render/exposure": [0.5]}
    job = submit(t, srv, {"scene": base, "grid": grid}, "three-axis grid")
    if job:
        want = [{"/render/seed": s, "/camera/fov": f, "/render/exposure": 0.5}
                for s in (1, 2) for f in (30, 40, 50)]
        check_sweep_json(t, job, want, "three-axis grid")
        sweep = wait_state(srv, sweep_path(job["id"]), FINISHED, 120)
        t.equal(sweep.get("state"), "done", "three-axis grid done")
        check_images_match_sync(t, srv, sweep, base, "three-axis grid")


def expect_invalid(t, srv, body, pointer, detail_prefix, what):
    before = info(srv)
    status, headers, _, raw = post_sweep(srv, body)
    p = check_problem(t, status, headers, raw, 422, "invalid_sweep", what)
    errors = p.get("errors") or []
    t.equal([e.get("pointer") for e in errors], [pointer], f"{what}: one error at the pointer")
    if errors and detail_prefix is not None:
        t.check(str(errors[0].get("detail", "")).startswith(detail_prefix),
                f"{what}: detail starts with {detail_prefix!r}: {errors[0].get('detail')!r}")
    after = info(srv)
    t.equal((after.get("jobs"), after.get("queue_length")),
            (before.get("jobs"), before.get("queue_length")), f"{what}: nothing queued")


def test_albedo_g_grid_keeps_the_camera_pass(t, srv):
    """Albedo (at the scene's mean free path) and g are what the camera pass does not read:
    every variant after the first keeps it, and its image is still the synchronous one; a
    variant that changes the ior traces again. Single scattering is kept too where only the
    albedo changed (the same g), its image still the synchronous one."""
    base = sweep_scene()
    base["render"]["components"] = ["surface", "single", "multiple"]
    albedos = [[0.9, 0.9, 0.9], [0.97, 0.95, 0.71]]
    # An ior no other test renders this scene with: the server keeps two camera passes.
    overrides = [{ALBEDO: a, G: g} for g in (0.3, 0.6) for a in albedos] + [{IOR: 1.37}]
    job = submit(t, srv, {"scene": base, "variants": overrides}, "albedo x g sweep")
    if not job:
        return
    sweep = wait_state(srv, sweep_path(job["id"]), FINISHED, 300)
    if check_sweep_json(t, sweep, overrides, "albedo x g sweep") != "done":
        t.check(False, f"albedo x g sweep done: {sweep!r:.500}")
        return
    order = sweep["order"]
    reused = {v["index"]: v.get("reused") or [] for v in sweep["variants"]}
    t.check("camera" not in reused[order[0]], f"the first variant traces: {reused[order[0]]}")
    for k, i in enumerate(order[1:], 1):
        want = "ior" not in json.dumps(overrides[i]) and "ior" not in json.dumps(
            overrides[order[k - 1]])
        t.equal("camera" in reused[i], want,
                f"variant {i} after {order[k - 1]} keeps the camera pass: {reused[i]}")
        timings = next(v for v in sweep["variants"] if v["index"] == i).get("timings_ms") or {}
        t.equal("ray_pass" in timings, not want, f"variant {i} lists ray_pass: {timings}")
        same_g = overrides[i].get(G) is not None and overrides[i].get(G) == overrides[order[k - 1]].get(G)
        t.equal("single" in reused[i], want and same_g,
                f"variant {i} after {order[k - 1]} keeps single scattering: {reused[i]}")
        t.equal("single" in timings, not (want and same_g), f"variant {i} lists single: {timings}")
    check_images_match_sync(t, srv, sweep, base, "albedo x g sweep")


def test_refusals(t, srv):
    base = tiny_scene()
    expect_invalid(t, srv, {"scene": base, "variants": [{G: 0.5}, {G: 2}]},
                   "/variants/1/" + pointer_escape(G), "variant 1: ", "a bad value in variant 1")
    expect_invalid(t, srv, {"scene": base, "grid": {G: [0.5, 2]}},
                   f"/grid/{pointer_escape(G)}/1", "variant 1: ", "a bad value in a grid")
    expect_invalid(t, srv, {"scene": base, "variants": [{"/materials/nope/g": 0.5}]},
                   "/variants/0/" + pointer_escape("/materials/nope/g"), "variant 0: ",
                   "a pointer whose parent does not exist")
    expect_invalid(t, srv, {"scene": base, "variants": [{G: 0.5}, {"/camera/lens/f": 2}]},
                   "/variants/1/" + pointer_escape("/camera/lens/f"), "variant 1: ",
                   "a parent two levels missing")
    expect_invalid(t, srv, {"scene": base, "variants": [{"materials/wax/g": 0.5}]},
                   "/variants/0/materials~1wax~1g", "variant 0: ", "not a JSON pointer")
    bad_base = copy.deepcopy(base)
    bad_base["materials"]["wax"]["g"] = 2
    expect_invalid(t, srv, {"scene": bad_base, "variants": [{IOR: 1.3}]},
                   "/scene/materials/wax/g", None, "a bad base scene")
    expect_invalid(t, srv, {"scene": base, "variants": [{"/render/seed": i}
                                                        for i in range(MAX_VARIANTS + 1)]},
                   "/variants", None, "257 variants")
    expect_invalid(t, srv, {"scene": base, "grid": {"/render/seed": list(range(17)),
                                                    "/camera/fov": list(range(20, 36))}},
                   "/grid", None, "a grid of 17 x 16 = 272 variants")
    # Malformed requests, answered as for a render.
    status, headers, _, raw = post_sweep(srv, b'{"scene": ')
    check_problem(t, status, headers, raw, 400, "malformed_json", "malformed sweep")
    status, headers, raw = srv.request("POST", "/v1/sweeps", json.dumps(
        {"scene": base, "variants": [{}]}).encode(), {"Content-Type": "text/plain"})
    check_problem(t, status, headers, raw, 415, "unsupported_media_type", "sweep as text/plain")
    # Neither form, both forms, nothing to sweep: one 422 invalid_sweep each.
    for body, what in (({"scene": base}, "neither variants nor grid"),
                       ({"scene": base, "variants": [{G: 0.5}], "grid": {G: [0.5]}}, "both"),
                       ({"scene": base, "variants": []}, "no variants"),
                       ({"scene": base, "grid": {G: []}}, "an empty grid axis"),
                       ({"variants": [{G: 0.5}]}, "no scene"),
                       ({"scene": base, "variants": [1]}, "a variant that is not an object")):
        status, headers, _, raw = post_sweep(srv, body)
        check_problem(t, status, headers, raw, 422, "invalid_sweep", what)


def test_sheet_grows_and_256_variants(t, srv):
    sizes = []
    for count in (1, 3, MAX_VARIANTS):
        body = {"scene": tiny_scene(), "variants": [{"/render/seed": i + 1} for i in range(count)]}
        job = submit(t, srv, body, f"{count} variants")
        if not job:
            return
        sid = job["id"]
        if count == MAX_VARIANTS:
            # The most a sweep may have is accepted; cancel it rather than wait for it all.
            status = srv.request("DELETE", sweep_path(sid))[0]
            t.check(status in (200, 202), f"DELETE of a live sweep: {status}")
            sweep = wait_state(srv, sweep_path(sid), FINISHED, 60)
            t.equal(sweep.get("state"), "cancelled", "the 256-variant sweep is cancelled")
            states = [v.get("state") for v in sweep.get("variants") or []]
            t.equal(len(states), MAX_VARIANTS, "256 variants listed")
            t.check(set(states) <= {"done", "cancelled"} and "cancelled" in states,
                    f"unrendered variants are cancelled: {sorted(set(states))}")
        else:
            t.equal(wait_state(srv, sweep_path(sid), FINISHED, 120).get("state"), "done",
                    f"{count}-variant sweep done")
        sizes.append(sheet_size(t, srv, sid, f"{count} variants"))
    areas = [w * h for w, h in sizes]
    t.check(areas == sorted(areas) and len(set(areas)) == len(areas),
            f"the sheet grows with the variant count: {sizes}")


def test_delete_running_sweep(t, srv, rate):
    base, _ = rate.scene(4)
    overrides = [{"/render/seed": s} for s in (1, 2, 3)]
    job = submit(t, srv, {"scene": base, "variants": overrides}, "slow sweep")
    if not job:
        return
    sid = job["id"]
    sweep = wait_state(srv, sweep_path(sid), ("running",) + FINISHED, 60)
    t.equal(sweep.get("state"), "running", "the slow sweep runs")
    t.check(sweep.get("current_variant") in (0, 1, 2),
            f"current_variant: {sweep.get('current_variant')}")
    status, headers, raw = srv.request("GET", sweep_path(sid, "/images/2"))
    check_problem(t, status, headers, raw, 409, "job_not_done", "image of a variant not rendered")
    sheet_size(t, srv, sid, "sheet of a running sweep")
    t0 = time.monotonic()
    status, headers, raw = srv.request("DELETE", sweep_path(sid))
    t.equal(status, 202, "DELETE of a running sweep")
    answer = json.loads(raw) if status == 202 else {}
    t.check(answer.get("state") in ("running", "cancelled")
            and answer.get("cancel_requested") is True,
            f"running (or just cancelled), cancel requested: {answer.get('state')}, "
            f"{answer.get('cancel_requested')}")
    sweep = wait_state(srv, sweep_path(sid), FINISHED, 30)
    took = time.monotonic() - t0
    t.equal(sweep.get("state"), "cancelled", "the sweep is cancelled")
    t.check(took <= CANCEL_WITHIN_S, f"within {CANCEL_WITHIN_S} s: {took:.2f} s")
    check_sweep_json(t, sweep, overrides, "cancelled sweep")
    states = [v.get("state") for v in sweep.get("variants") or []]
    t.check("running" not in states and "queued" not in states and states.count("cancelled") >= 2,
            f"the running variant and those after it are cancelled: {states}")
    s = read_events(srv, sweep_path(sid, "/events"), timeout=30)
    check_event_sequence(t, s.events, "cancelled sweep", final="cancelled", sweep=True)
    for i, state in enumerate(states):
        if state == "cancelled":
            status, headers, raw = srv.request("GET", sweep_path(sid, f"/images/{i}"))
            check_problem(t, status, headers, raw, 409, "job_not_done", f"cancelled variant {i}")
    sheet_size(t, srv, sid, "cancelled sweep")
    manifest = get_json(srv, sweep_path(sid, "/manifest.json"))[2] or {}
    t.equal(manifest.get("state"), "cancelled", "manifest state")
    status, _, raw = srv.request("DELETE", sweep_path(sid))
    t.equal((status, raw), (204, b""), "DELETE of a finished sweep")
    for tail in ("", "/sheet.png", "/manifest.json", "/images/0", "/events"):
        status, headers, raw = srv.request("GET", sweep_path(sid, tail))
        check_problem(t, status, headers, raw, 410, "job_gone", f"discarded sweep {tail}")


def test_unknown_sweep_and_methods(t, srv):
    never = "fedcba9876543210fedcba9876543210"
    for tail in ("", "/sheet.png", "/manifest.json", "/images/0", "/events"):
        status, headers, raw = srv.request("GET", sweep_path(never, tail))
        check_problem(t, status, headers, raw, 404, "not_found", f"unknown sweep {tail}")
    status, headers, raw = srv.request("GET", sweep_path("NOTANID"))
    check_problem(t, status, headers, raw, 404, "not_found", "malformed sweep id")
    job = submit(t, srv, {"scene": tiny_scene(), "variants": [{"/render/seed": 3}]}, "a sweep")
    if not job:
        return
    sid = job["id"]
    wait_state(srv, sweep_path(sid), FINISHED, 120)
    for path, method, allowed in ((sweep_path(sid), "POST", {"GET", "HEAD", "DELETE"}),
                                  (sweep_path(sid, "/sheet.png"), "DELETE", {"GET", "HEAD"}),
                                  (sweep_path(sid, "/manifest.json"), "POST", {"GET", "HEAD"}),
                                  (sweep_path(sid, "/images/0"), "DELETE", {"GET", "HEAD"}),
                                  (sweep_path(sid, "/events"), "POST", {"GET", "HEAD"}),
                                  ("/v1/sweeps", "PUT", None)):
        status, headers, raw = srv.request(method, path, b"{}",
                                           {"Content-Type": "application/json"})
        check_problem(t, status, headers, raw, 405, "method_not_allowed", f"{method} {path}")
        allow = {m.strip() for m in headers.get("allow", "").split(",") if m.strip()}
        if allowed is None:
            t.check("POST" in allow, f"Allow on /v1/sweeps has POST: {allow}")
        else:
            t.equal(allow, allowed, f"Allow on {path}")


# ---------------------------------------------------------------------------------------
# examples/sweep.py
# ---------------------------------------------------------------------------------------
def run_example(srv, scene_path, out, *args, timeout=300):
    return subprocess.run([sys.executable, EXAMPLE, "--server", f"http://127.0.0.1:{srv.port}",
                           "--scene", scene_path, "--out", out, *args],
                          capture_output=True, text=True, timeout=timeout)


def test_example_script(t, srv):
    with tempfile.TemporaryDirectory(prefix="nscatter-sweep-") as d:
        scene = small_scene(16, 16)
        scene_path = os.path.join(d, "scene.json")
        with open(scene_path, "w") as f:
            json.dump(scene, f)
        out = os.path.join(d, "out")
        p = run_example(srv, scene_path, out, "--grid", f"{G}=[0.5,0.8]",
                        "--grid", "/render/seed=[1]")
        t.equal(p.returncode, 0, f"sweep.py exit status (stderr: {p.stderr[-1000:]})")
        lines = p.stdout.splitlines()
        t.check(lines and re.match(r"^sweep [0-9a-f]{32}: 2 variants", lines[0]),
                f"first line names the sweep: {lines[:1]}")
        rows = [ln.split() for ln in lines if re.match(r"^\s*\d+\s+done\b", ln)]
        t.equal(sorted(int(r[0]) for r in rows), [0, 1], f"one line per variant: {lines}")
        t.check(any("g=0.5" in ln for ln in lines) and any("g=0.8" in ln for ln in lines),
                "lines name the overrides")
        with open(os.path.join(out, "sheet.png"), "rb") as f:
            t.equal(f.read(8), PNG_SIGNATURE, "sheet.png saved")
        with open(os.path.join(out, "manifest.json")) as f:
            manifest = json.load(f)
        t.equal((manifest.get("state"), len(manifest.get("variants", []))), ("done", 2),
                "manifest.json saved")
        for i, g in enumerate((0.5, 0.8)):
            path = os.path.join(out, "images", f"{i:03d}.png")
            if not t.check(os.path.exists(path), f"{path} saved"):
                continue
            with open(path, "rb") as f:
                saved = f.read()
            variant = variant_scene(scene, {G: g, "/render/seed": 1})
            status, _, sync = srv.render(variant)
            t.equal(png_decode_rgb8(saved)[2], png_decode_rgb8(sync)[2],
                    f"images/{i:03d}.png is the render of g={g}")

        # A refused sweep: the problems printed with their pointers, exit status 2.
        p = run_example(srv, scene_path, os.path.join(d, "bad"), "--variant", json.dumps({G: 2}))
        t.equal(p.returncode, 2, "a refused sweep exits with 2")
        t.check("invalid_sweep" in p.stderr and "/variants/0/~1materials~1wax~1g" in p.stderr,
                f"the 422 printed with its pointer: {p.stderr!r}")


def read_line(proc, timeout):
    """The first line the process writes on stdout, waiting at most timeout seconds."""
    deadline, line = time.monotonic() + timeout, b""
    fd = proc.stdout.fileno()
    while not line.endswith(b"\n") and time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
        chunk = os.read(fd, 1) if ready else b""
        if ready and not chunk:
            break
        line += chunk
    return line.decode(errors="replace")


def test_example_script_ctrl_c(t, srv, rate):
    with tempfile.TemporaryDirectory(prefix="nscatter-sweep-") as d:
        scene, _ = rate.scene(4)
        scene_path = os.path.join(d, "scene.json")
        with open(scene_path, "w") as f:
            json.dump(scene, f)
        proc = subprocess.Popen([sys.executable, EXAMPLE, "--server",
                                 f"http://127.0.0.1:{srv.port}", "--scene", scene_path,
                                 "--out", os.path.join(d, "out"), "--grid",
                                 # Six variants of ~4 s: work left at the Ctrl-C even when the
                                 # machine is several times faster than when the rate was taken.
                                 "/render/seed=[1,2,3,4,5,6]"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            first = read_line(proc, 60)
            m = re.match(r"^sweep ([0-9a-f]{32}):", first)
            if not t.check(m, f"the script names its sweep: {first!r}"):
                return
            sid = m.group(1)
            sweep = wait_state(srv, sweep_path(sid), ("running",) + FINISHED, 60)
            t.equal(sweep.get("state"), "running", "the sweep runs")
            proc.send_signal(signal.SIGINT)
            code = proc.wait(30)
            t.equal(code, 130, "Ctrl-C exits with 130")
            sweep = wait_state(srv, sweep_path(sid), FINISHED, 30)
            if not t.equal(sweep.get("state"), "cancelled", "and cancels the sweep on the server"):
                proc.wait(10)
                print(f"sweep.py said: {proc.stderr.read().decode(errors='replace')[-2000:]}",
                      file=sys.stderr)
                deletes = [line for line in srv.log_text().splitlines() if '"DELETE"' in line]
                print(f"the server's DELETEs: {deletes[-3:]}", file=sys.stderr)
            t.check(not os.path.exists(os.path.join(d, "out", "sheet.png")),
                    "nothing saved after Ctrl-C")
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.communicate(timeout=10)


def main():
    t = Checks()
    with Server("--queue", "8") as srv:
        rate = PtRate(srv)
        t.current = "pt rate"
        t.check(rate.ok, "a pt render to measure the rate")
        for test in (test_info_limit, test_variants_form, test_grid_form,
                     test_albedo_g_grid_keeps_the_camera_pass, test_refusals,
                     test_sheet_grows_and_256_variants, test_unknown_sweep_and_methods,
                     test_example_script):
            t.run(test, srv)
            wait_idle(srv, 60)
        for test in (test_delete_running_sweep, test_example_script_ctrl_c):
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
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
