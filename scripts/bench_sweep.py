#!/usr/bin/env python3
"""What a sweep saves (docs/bench.md, "Sweeps"): a grid of albedo x g x ior over one scene,
rendered as one sweep (POST /v1/sweeps) on a fresh server; the albedo x g grid at one ior as
one sweep on another fresh server; and the same albedo x g variants as independent
synchronous requests (POST /v1/renders), one after the other, on a third fresh server.

The ior axis has two values so that every material (g, albedo: the tables' key) renders
twice in the first sweep: its first render pays for the tables, the second finds them
cached; consecutive variants there differ in ior or in the material's tables, so the camera
pass is traced every time. In the albedo x g sweep at one ior every variant makes new tables
and every variant after the first keeps the camera pass (albedo at a fixed mean free path
and g are what it does not read). Times are the server's own (Server-Timing / timings_ms, no
network); medians per kind.

    python3 scripts/bench_sweep.py --bin build/nscatter [--size 256] [--n 5]

Python standard library only.
"""
import argparse
import http.client
import json
import os
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def start(binary, extra_args=()):
    proc = subprocess.Popen([binary, "serve", "--port", "0", "--queue", "4", *extra_args],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    line = proc.stdout.readline()
    if not line.startswith("listening on http://"):
        proc.kill()
        sys.exit(f"server did not start: {line!r}")
    host, port = line.split("//")[1].strip().rsplit(":", 1)
    return proc, host, int(port)


def request(host, port, method, path, body=None, headers=None, timeout=3600):
    conn = http.client.HTTPConnection(host, port, timeout=timeout)
    conn.request(method, path, body=body, headers=headers or {})
    resp = conn.getresponse()
    data = resp.read()
    conn.close()
    return resp.status, {k.lower(): v for k, v in resp.getheaders()}, data


def server_timing_ms(header):
    total = 0.0
    for metric in header.split(","):
        for part in metric.split(";"):
            if part.strip().startswith("dur="):
                total += float(part.strip()[4:])
    return total


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "nscatter"))
    ap.add_argument("--scene", default=os.path.join(ROOT, "scenes", "default.json"))
    ap.add_argument("--material", default="wax")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--n", type=int, default=5, help="values of albedo and of g (n x n)")
    args = ap.parse_args()

    scene = json.load(open(args.scene))
    scene["camera"]["width"] = scene["camera"]["height"] = args.size
    n = args.n
    albedos = [[round(0.9 + 0.099 * i / max(n - 1, 1), 4)] * 3 for i in range(n)]
    gs = [round(0.0 + 0.8 * i / max(n - 1, 1), 3) for i in range(n)]
    base = f"/materials/{args.material}"
    grid = {f"{base}/albedo": albedos, f"{base}/g": gs, f"{base}/ior": [1.3, 1.5]}

    def run_sweep(host, port, grid):
        t0 = time.time()
        status, h, data = request(host, port, "POST", "/v1/sweeps", json.dumps(
            {"scene": scene, "grid": grid}), {"Content-Type": "application/json"})
        if status != 202:
            sys.exit(f"sweep refused: {status} {data[:400]!r}")
        path = h["location"]
        while True:
            status, _, data = request(host, port, "GET", path)
            sweep = json.loads(data)
            if sweep["state"] not in ("queued", "running"):
                return sweep, time.time() - t0
            time.sleep(0.5)

    def variant_ms(v):
        return sum(t for k, t in v["timings_ms"].items() if k not in ("parse", "queue"))

    proc, host, port = start(args.bin)
    try:
        sweep, sweep_wall = run_sweep(host, port, grid)
        first, repeat = [], []
        for v in sweep["variants"]:
            (repeat if "tables" in v["reused"] else first).append((variant_ms(v), v["reused"]))
        # Fresh servers, so that nothing finds a table an earlier run made.
        proc.terminate()
        proc.wait(timeout=60)
        proc, host, port = start(args.bin)
        one_ior = {f"{base}/albedo": albedos, f"{base}/g": gs, f"{base}/ior": [1.3]}
        camera_sweep, camera_wall = run_sweep(host, port, one_ior)
        camera_kept = [variant_ms(v) for v in camera_sweep["variants"] if "camera" in v["reused"]]
        # What keeping the camera pass saves: the ray_pass stage of the variants that traced.
        ray_pass = [v["timings_ms"]["ray_pass"] for v in sweep["variants"]
                    if "ray_pass" in v["timings_ms"]]
        proc.terminate()
        proc.wait(timeout=60)
        proc, host, port = start(args.bin)
        t1 = time.time()
        independent = []
        for albedo in albedos:
            for g in gs:
                one = json.loads(json.dumps(scene))
                one["materials"][args.material].update({"albedo": albedo, "g": g, "ior": 1.3})
                status, h, _ = request(host, port, "POST", "/v1/renders", json.dumps(one),
                                       {"Content-Type": "application/json"})
                if status != 200:
                    sys.exit(f"render refused: {status}")
                independent.append(server_timing_ms(h.get("server-timing", "")))
        independent_wall = time.time() - t1
    finally:
        proc.terminate()
        proc.wait(timeout=60)

    def med(rows):
        return statistics.median(r[0] if isinstance(r, tuple) else r for r in rows) if rows else 0

    print(f"sweep of {len(sweep['variants'])} variants ({n} albedo x {n} g x 2 ior) at "
          f"{args.size}x{args.size}, state {sweep['state']}, wall {sweep_wall:.1f} s")
    print(f"  first render of a material:    median {med(first):8.0f} ms  ({len(first)} variants;"
          f" bvh reused in {sum('bvh' in r for _, r in first)})")
    print(f"  repeated material (tables hit): median {med(repeat):8.0f} ms  ({len(repeat)} variants)")
    print(f"albedo x g sweep at ior 1.3, {len(camera_sweep['variants'])} variants, state "
          f"{camera_sweep['state']}, wall {camera_wall:.1f} s")
    print(f"  new material, camera pass kept: median {med(camera_kept):8.0f} ms  "
          f"({len(camera_kept)} variants; the camera pass, where traced: median "
          f"{med(ray_pass):.0f} ms)")
    print(f"{n * n} independent synchronous renders (ior 1.3): median {med(independent):8.0f} ms,"
          f" wall {independent_wall:.1f} s")
    print(json.dumps({"size": args.size, "variants": len(sweep["variants"]),
                      "first_ms": med(first), "repeat_ms": med(repeat),
                      "camera_kept_ms": med(camera_kept), "camera_kept_variants": len(camera_kept),
                      "ray_pass_ms": med(ray_pass),
                      "camera_sweep_wall_s": camera_wall,
                      "independent_ms": med(independent), "sweep_wall_s": sweep_wall,
                      "independent_wall_s": independent_wall}))


if __name__ == "__main__":
    main()
