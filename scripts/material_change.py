#!/usr/bin/env python3
"""The material change (docs/bench.md, "The material change with interpolated tables"): one
fresh server per render.tables mode, and seven (--renders) synchronous renders of one scene
whose medium changes albedo each time (the preset's mean free path, g and ior kept), as a
user moving an albedo slider does. The albedos: the base one, then 1 - albedo scaled by 1.3,
0.8, 1.15, 0.9, 1.05, 0.95, 1.2, 0.85, 1.1, 0.97 and 1.02 in every channel, as many as asked.
Prints each render's reconstruct and accumulate stages and its total from Server-Timing,
its wall time as the client saw it (a render that stopped the server's work between renders
waited for it), then the medians over the renders after the first. --pause S waits S
seconds between renders, as a user looking at each image does, which is when the server
works between renders (--idle-work, nscatter serve's default on).

    python3 scripts/material_change.py --bin build/nscatter [--tables exact,interpolated,auto]
    python3 scripts/material_change.py --scene scenes/bench/milk.json --material milk \\
        --preset milk --albedo 0.999,0.999,0.999 --size 256 --assets ~/.cache/nscatter/bench/assets

Python standard library only.
"""
import argparse
import json
import os
import statistics
import sys
import time

from bench_sweep import ROOT, request, start

FACTORS = [1.0, 1.3, 0.8, 1.15, 0.9, 1.05, 0.95, 1.2, 0.85, 1.1, 0.97, 1.02]


def stages(header):
    """Server-Timing "name;dur=ms, ..." as a dict."""
    out = {}
    for metric in header.split(","):
        parts = [p.strip() for p in metric.split(";")]
        for p in parts[1:]:
            if p.startswith("dur="):
                out[parts[0]] = out.get(parts[0], 0.0) + float(p[4:])
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "nscatter"))
    ap.add_argument("--scene", default=os.path.join(ROOT, "scenes", "default.json"))
    ap.add_argument("--material", default="wax")
    ap.add_argument("--preset", default="candle", help="the medium's preset (mfp, g, ior kept)")
    ap.add_argument("--albedo", default="0.98,0.962,0.75", help="the preset's albedo: the first render's")
    ap.add_argument("--size", type=int, default=0, help="image width and height (0: the scene's)")
    ap.add_argument("--assets", default=None, help="the server's --assets folder")
    ap.add_argument("--tables", default="exact,interpolated",
                    help="render.tables modes, each on a fresh server: exact, interpolated, auto")
    ap.add_argument("--renders", type=int, default=7,
                    help=f"renders per mode, each a new albedo (at most {len(FACTORS)})")
    ap.add_argument("--pause", type=float, default=0.0, help="seconds between renders")
    ap.add_argument("--idle-work", choices=("on", "off"), default="on",
                    help="the server's --idle-work")
    args = ap.parse_args()
    if not 2 <= args.renders <= len(FACTORS):
        ap.error(f"--renders: 2 to {len(FACTORS)}")
    base = [float(x) for x in args.albedo.split(",")]
    albedos = [[round(min(0.9999, max(0.0, 1 - f * (1 - a))), 6) for a in base]
               for f in FACTORS[:args.renders]]
    result = {}
    for mode in args.tables.split(","):
        scene = json.load(open(args.scene))
        scene.setdefault("render", {})["tables"] = mode
        if args.size:
            scene["camera"]["width"] = scene["camera"]["height"] = args.size
        serve_args = ["--idle-work", args.idle_work] + (["--assets", args.assets] if args.assets else [])
        proc, host, port = start(args.bin, serve_args)
        rows = []
        try:
            for i, albedo in enumerate(albedos):
                if i:
                    time.sleep(args.pause)
                scene["materials"][args.material] = {"type": "medium", "preset": args.preset,
                                                     "albedo": albedo}
                t0 = time.monotonic()
                status, h, data = request(host, port, "POST", "/v1/renders", json.dumps(scene),
                                          {"Content-Type": "application/json"})
                if status != 200:
                    sys.exit(f"render refused: {status} {data[:400]!r}")
                st = stages(h.get("server-timing", ""))
                tables = st.get("reconstruct", 0.0) + st.get("accumulate", 0.0)
                total = sum(v for k, v in st.items() if k not in ("parse", "queue"))
                wall = 1000 * (time.monotonic() - t0)
                rows.append((tables, total, wall))
                print(f"{mode:12s} albedo {albedo}: reconstruct {st.get('reconstruct', 0):6.0f} ms, "
                      f"accumulate {st.get('accumulate', 0):6.0f} ms, render {total:6.0f} ms, "
                      f"queue {st.get('queue', 0):5.0f} ms, wall {wall:6.0f} ms", flush=True)
        finally:
            proc.terminate()
            proc.wait(timeout=60)
        later = rows[1:]
        result[mode] = {"first_tables_ms": rows[0][0],
                        "tables_ms_median": statistics.median(r[0] for r in later),
                        "render_ms_median": statistics.median(r[1] for r in later),
                        "wall_ms_median": statistics.median(r[2] for r in later)}
        print(f"{mode}: first material's tables {rows[0][0]:.0f} ms; later materials: tables "
              f"median {result[mode]['tables_ms_median']:.0f} ms, render median "
              f"{result[mode]['render_ms_median']:.0f} ms")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
