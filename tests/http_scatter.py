"""The scattering components over HTTP, as a user scripting a material sweep sees them: a
full render (surface + single + double + multiple) reports every scattering stage in
Server-Timing and its counts and memory in X-Nscatter-Stats; sweeping the albedo and coming
back to the first material reuses its cached tables (no reconstruct/accumulate stage the
second time); the boundary correction's walks show as a stage and a count; bad scattering
settings get a 422 naming the field."""
import json
import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import Checks, Server, png_decode_rgb8, problem, server_timing, small_scene  # noqa: E402

SCATTER_STAGES = ("reconstruct", "accumulate", "vrl", "grid", "gather", "single", "composite")


def scatter_scene(albedo=(0.98, 0.962, 0.75), components=("surface", "single", "double", "multiple"),
                  method="nn", **render):
    scene = small_scene(40, 32)
    scene["materials"]["wax"]["albedo"] = list(albedo)
    # Exact tables, whose stages these tests read: with "auto" (the default) a material is
    # blended wherever its g's albedo nodes are already in the test cache folder, which
    # depends on what other tests ran before (gpu_interpolated_tables tests "auto").
    scene["render"].update({"method": method, "components": list(components), "vrls": 2000,
                            "tables": "exact"})
    scene["render"].update(render)
    return scene


def stats_of(headers):
    return json.loads(headers.get("x-nscatter-stats", "{}"))


def test_full_render_reports_stages_and_counts(t, srv):
    status, headers, body = srv.render(scatter_scene())
    t.equal(status, 200, f"full render ({body[:300]!r})")
    if status != 200:
        return
    timing = server_timing(headers.get("server-timing", ""))
    # Walks (the default) gather endless VRLs (their entry ghosts end the beams) through the
    # default shader, made at start-up: no render makes the bounded gather's shader.
    t.check("gather_pipeline" not in timing and "boundary" in timing,
            f"the walks' stage, and no shader made: {sorted(timing)}")
    for stage in SCATTER_STAGES:
        t.check(stage in timing, f"Server-Timing has {stage}: {headers.get('server-timing')}")
    stats = stats_of(headers)
    t.check(stats.get("vrl_count", 0) > 0, f"VRLs stored: {stats}")
    t.check(stats.get("vrl_paths") == 2000, f"render.vrls light paths traced: {stats}")
    t.check(stats.get("interactions", 0) > 0, "VRL-segment interactions counted")
    t.check(0 < stats.get("gather_segments", 0) <= stats.get("camera_segments", 0),
            "gathered segments are a subset of the camera segments")
    t.check(stats.get("table_bytes", 0) > 0, "table memory reported")
    t.check(0 < stats.get("weights_bytes", 0) <= 2 * 12 * 1024, "weights memory reported, <= 2 x 12 KB")


def test_sweep_returns_to_cached_material(t, srv):
    first = (0.9, 0.8, 0.7)
    renders = []
    for albedo in (first, (0.95, 0.85, 0.6), first):
        status, headers, body = srv.render(scatter_scene(albedo, components=("multiple",)))
        t.equal(status, 200, f"sweep render {albedo} ({body[:200]!r})")
        renders.append(server_timing(headers.get("server-timing", "")))
    if len(renders) == 3:
        t.check("reconstruct" in renders[0] and "accumulate" in renders[0],
                f"a new material is reconstructed and accumulated: {renders[0]}")
        t.check("reconstruct" not in renders[2] and "accumulate" not in renders[2],
                f"coming back to it costs nothing: {renders[2]}")


def metric(srv, name):
    status, _, body = srv.request("GET", "/metrics")
    if status != 200:
        return None
    for line in body.decode().splitlines():
        if line.startswith(name + " "):
            return float(line.split()[1])
    return None


def wait_for_idle_work_to_end(srv, deadline_s=300):
    """The nodes made between renders once the worker has no more to look for."""
    deadline = time.monotonic() + deadline_s
    while time.monotonic() < deadline:
        if metric(srv, "nscatter_idle_work_pending") == 0:
            return metric(srv, "nscatter_idle_nodes_made_total")
        time.sleep(0.5)
    return None


def test_idle_work_makes_the_swept_albedos_nodes(t):
    """A user sweeping one material's albedo: after the second albedo the server, left idle,
    makes the nodes those albedos blend from, so a third albedo between them renders without
    a reconstruction (auto alone would make exact tables until the fifth); a render that
    arrives while it works stops it and is answered as usual, and the work resumes."""
    def sweep_render(srv, a, g=0.8, blended=None):
        scene = scatter_scene((a, a, a), components=("multiple",), tables="auto")
        scene["materials"]["wax"]["g"] = g
        status, headers, body = srv.render(scene)
        t.equal(status, 200, f"g {g} albedo {a} ({body[:200]!r})")
        if blended is not None and status == 200:
            # X-Nscatter-Stats says whether auto blended: multiple scattering, and the
            # boundary correction's blurred first order, each a table of the one material.
            stats = json.loads(headers.get("x-nscatter-stats", "{}"))
            t.check((stats.get("tables_blended", 0) > 0) == blended,
                    f"g {g} albedo {a}: tables_blended {stats.get('tables_blended')}, blended {blended}")
        return server_timing(headers.get("server-timing", ""))

    with tempfile.TemporaryDirectory(prefix="nscatter-idle-") as cache, \
            Server(idle_work=True, env={"NSCATTER_CACHE_DIR": cache}) as srv:
        for a in (0.9, 0.92):
            timing = sweep_render(srv, a, blended=False)
            t.check("reconstruct" in timing, f"albedo {a}: exact tables made ({sorted(timing)})")
        made = wait_for_idle_work_to_end(srv)
        t.check(made is not None and made >= 6, f"nodes made between renders: {made}")
        timing = sweep_render(srv, 0.91, blended=True)
        t.check("reconstruct" not in timing, f"the third albedo blends the nodes: {sorted(timing)}")

        # Another g, two albedos far apart: eleven nodes to make, three per call. A render
        # sent while a call runs (a cached material: it waits only for the call to stop).
        for a in (0.3, 0.97):
            sweep_render(srv, a, g=0.5)
        stopped_before = metric(srv, "nscatter_idle_work_stopped_total")
        stopped = stopped_before
        for _ in range(4):
            deadline = time.monotonic() + 60
            running = 0
            while time.monotonic() < deadline and metric(srv, "nscatter_idle_work_pending") == 1:
                running = metric(srv, "nscatter_idle_work_running")
                if running == 1:
                    break
                time.sleep(0.02)
            if running != 1:
                break  # no call left to stop
            sweep_render(srv, 0.3, g=0.5)
            stopped = metric(srv, "nscatter_idle_work_stopped_total")
            if stopped is not None and stopped > stopped_before:
                break
        t.check(stopped is not None and stopped_before is not None and stopped > stopped_before,
                f"an arriving render stops the idle work ({stopped_before} -> {stopped})")
        after = wait_for_idle_work_to_end(srv)
        t.check(after is not None and made is not None and after >= made + 6,
                f"the work resumes and makes the second g's nodes: {made} -> {after}")
        code = srv.stop()
        t.check(srv.exited_cleanly(code), f"clean exit on SIGTERM (status {code})")


def expect_422(t, srv, scene, pointer, what):
    status, headers, body = srv.render(scene)
    t.equal(status, 422, f"{what}: status ({body[:300]!r})")
    if status != 422:
        return
    pointers = [e.get("pointer") for e in problem(body).get("errors", [])]
    t.check(any(p and p.startswith(pointer) for p in pointers), f"{what}: names {pointer}, got {pointers}")


def test_adaptive_gather_counts_interpolated_tiles(t, srv):
    # None: the key left out, which a scene file reads as the parser's default (2 levels).
    renders = {}
    for levels in (0, 2, None):
        extra = {} if levels is None else {"gather_levels": levels}
        status, headers, body = srv.render(scatter_scene(components=("multiple",), gather_tile=1,
                                                         gather_tolerance=0.5, **extra))
        t.equal(status, 200, f"gather_levels {levels} ({body[:300]!r})")
        renders[levels] = stats_of(headers)
    if len(renders) == 3:
        t.check(renders[None].get("tiles_interpolated", 0) > 0,
                f"tiles interpolated without gather_levels: {renders[None]}")
        t.equal(renders[0].get("tiles_interpolated"), 0, f"every tile gathered: {renders[0]}")
        t.check(renders[2].get("tiles_interpolated", 0) > 0, f"tiles interpolated: {renders[2]}")
        t.check(0 < renders[2].get("gather_segments", 0) < renders[0].get("gather_segments", 0),
                f"fewer segments gathered: {renders[2]} against {renders[0]}")


def test_adaptive_single_is_the_default(t, srv):
    # A scene without single_levels gets adaptive single scattering (the parser's default);
    # single_levels 0 computes every pixel.
    renders = {}
    for name, extra in (("default", {}), ("every pixel", {"single_levels": 0})):
        status, headers, body = srv.render(scatter_scene(components=("single",), **extra))
        t.equal(status, 200, f"single scattering, {name} ({body[:300]!r})")
        renders[name] = stats_of(headers)
    if len(renders) == 2:
        t.check(renders["default"].get("single_interpolated", 0) > 0,
                f"pixels interpolated by default: {renders['default']}")
        t.equal(renders["every pixel"].get("single_interpolated"), 0,
                f"every pixel computed: {renders['every pixel']}")


def test_gather_takes_one_camera_sample_by_default(t, srv):
    # At 4 spp a scene without gather_camera_samples gathers one camera sample of each
    # gathered pixel (the parser's default); 0 gathers all four: about 4 times the segments.
    renders = {}
    for name, extra in (("default", {}), ("every sample", {"gather_camera_samples": 0})):
        status, headers, body = srv.render(scatter_scene(components=("multiple",), spp=4, **extra))
        t.equal(status, 200, f"multiple scattering at 4 spp, {name} ({body[:300]!r})")
        renders[name] = stats_of(headers).get("gather_segments", 0)
    if len(renders) == 2:
        t.check(0 < 3 * renders["default"] < renders["every sample"],
                f"gathered segments, one sample against every sample: {renders}")


def test_bounded_beams_add_reflected_vrls(t, srv):
    counts, timings = {}, []
    for beams in ("endless", "bounded", "bounded"):
        # boundary "off": bounded beams alone (with walks, the default, the VRLs are endless).
        status, headers, body = srv.render(scatter_scene(components=("double", "multiple"),
                                                         vrl_beams=beams, boundary="off"))
        t.equal(status, 200, f"vrl_beams {beams} ({body[:300]!r})")
        counts[beams] = stats_of(headers)
        timings.append(server_timing(headers.get("server-timing", "")))
    # The bounded gather's shader is made by the first bounded render and kept.
    for beams, timing, made in zip(("endless", "bounded", "bounded"), timings, (False, True, False)):
        t.check(("gather_pipeline" in timing) == made,
                f"{beams}: the shader {'made' if made else 'not made'}: {sorted(timing)}")
    if len(counts) == 2:
        # The wax sphere reflects part of each beam where it leaves: one more VRL each time.
        t.equal(counts["bounded"].get("vrl_paths"), counts["endless"].get("vrl_paths"),
                f"same light paths: {counts}")
        t.check(counts["bounded"].get("vrl_count", 0) > counts["endless"].get("vrl_count", 0) > 0,
                f"internal reflections stored as VRLs: {counts}")


def test_boundary_walks(t, srv):
    # render.boundary "walks": the walks are a stage of their own and their sources are
    # counted; "off" (the paper's model) has neither. The image changes. Without the key,
    # nn gets walks: the same image as "walks" written out.
    answers = {}
    for boundary in ("off", "walks", None):
        extra = {"boundary": boundary} if boundary else {}
        status, headers, body = srv.render(scatter_scene(components=("multiple",), **extra))
        t.equal(status, 200, f"boundary {boundary} ({body[:300]!r})")
        answers[boundary] = (stats_of(headers), server_timing(headers.get("server-timing", "")), body)
    if len(answers) == 3:
        t.equal(answers[None][0].get("boundary_sources"), answers["walks"][0].get("boundary_sources"),
                "no key: the walks' sources")
        t.check(png_decode_rgb8(answers[None][2]) == png_decode_rgb8(answers["walks"][2]),
                "no key: the walks' image, pixel for pixel")
        (off_counts, off_timing, off_body), (counts, timing, body) = answers["off"], answers["walks"]
        t.check("boundary" in timing and "boundary" not in off_timing,
                f"the walks' stage: {sorted(timing)} / {sorted(off_timing)}")
        t.check(counts.get("boundary_sources", 0) > 0, f"sources counted: {counts}")
        t.equal(off_counts.get("boundary_sources"), 0, "no source when off")
        # The correction's own lattice (default gather_tolerance): some tiles take it from
        # their neighbours.
        t.check(counts.get("corrections_interpolated", 0) > 0, f"corrections interpolated: {counts}")
        t.equal(off_counts.get("corrections_interpolated"), 0, "no correction when off")
        t.check(body != off_body, "the correction changes the image")


def test_bad_settings_422(t, srv):
    expect_422(t, srv, scatter_scene(vrls=0), "/render/vrls", "zero VRLs")
    expect_422(t, srv, scatter_scene(gather_tile=99), "/render/gather_tile", "tile too large")
    expect_422(t, srv, scatter_scene(accumulation="sideways"), "/render/accumulation",
               "unknown accumulation")
    expect_422(t, srv, scatter_scene(cull_solid_angle=-1), "/render/cull_solid_angle",
               "negative solid angle")
    expect_422(t, srv, scatter_scene(single_samples=0), "/render/single_samples", "zero samples")
    expect_422(t, srv, scatter_scene(gather_levels=5), "/render/gather_levels", "too many levels")
    expect_422(t, srv, scatter_scene(gather_tolerance=1.5), "/render/gather_tolerance",
               "tolerance above 1")
    expect_422(t, srv, scatter_scene(gather_tolerance="loose"), "/render/gather_tolerance",
               "tolerance not a number")
    expect_422(t, srv, scatter_scene(gather_camera_samples=-1), "/render/gather_camera_samples",
               "negative camera samples")
    expect_422(t, srv, scatter_scene(gather_camera_samples="one"), "/render/gather_camera_samples",
               "camera samples not a number")
    expect_422(t, srv, scatter_scene(single_levels=5), "/render/single_levels", "too many levels")
    expect_422(t, srv, scatter_scene(single_tolerance=-0.5), "/render/single_tolerance",
               "negative tolerance")
    expect_422(t, srv, scatter_scene(method="dipole", components=("double",)), "/render/components",
               "dipole cannot give double alone")
    expect_422(t, srv, scatter_scene(vrl_beams="finite"), "/render/vrl_beams", "unknown beam model")
    expect_422(t, srv, scatter_scene(method="vrl", vrl_beams="bounded"), "/render/vrl_beams",
               "bounded beams with method vrl")
    expect_422(t, srv, scatter_scene(boundary="on"), "/render/boundary", "unknown boundary model")
    expect_422(t, srv, scatter_scene(method="dipole", boundary="walks"), "/render/boundary",
               "boundary walks with method dipole")


def main():
    t = Checks()
    with Server() as srv:
        # No render before test_bounded_beams_add_reflected_vrls asks for bounded beams: its
        # first bounded render makes their shader.
        for test in (test_full_render_reports_stages_and_counts, test_sweep_returns_to_cached_material,
                     test_bounded_beams_add_reflected_vrls, test_boundary_walks,
                     test_adaptive_gather_counts_interpolated_tiles, test_adaptive_single_is_the_default,
                     test_gather_takes_one_camera_sample_by_default,
                     test_bad_settings_422):
            t.run(test, srv)
        code = srv.stop()
        t.check(srv.exited_cleanly(code), f"clean exit on SIGTERM (status {code})")
        if t.failed:
            print(srv.log_text()[-4000:], file=sys.stderr)
    t.run(test_idle_work_makes_the_swept_albedos_nodes)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
