#!/usr/bin/env python3
"""The material change (docs/bench.md, "The material change with interpolated tables"): one
fresh server per render.tables mode, and seven synchronous renders of one scene whose medium
changes albedo each time (its mean free path, g and ior kept), as a user moving an albedo
slider does. Prints each render's reconstruct and accumulate stages and its total from
Server-Timing, then the medians over the renders after the first.

    python3 scripts/material_change.py --bin build/nscatter [--tables exact,interpolated]

Python standard library only.
"""
import argparse
import json
import os
import statistics
import sys

from bench_sweep import ROOT, request, start

# The default scene's wax (the candle preset: albedo 0.98 / 0.962 / 0.75, mfp 0.65 / 0.63 /
# 0.59, g 0.8, ior 1.45), then six neighbours of it.
ALBEDOS = [[0.980, 0.962, 0.750], [0.970, 0.950, 0.800], [0.985, 0.970, 0.700],
           [0.990, 0.960, 0.780], [0.975, 0.955, 0.720], [0.982, 0.965, 0.760],
           [0.978, 0.958, 0.740]]


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
    ap.add_argument("--mfp", default="0.65,0.63,0.59")
    ap.add_argument("--g", type=float, default=0.8)
    ap.add_argument("--ior", type=float, default=1.45)
    ap.add_argument("--tables", default="exact,interpolated")
    args = ap.parse_args()
    mfp = [float(x) for x in args.mfp.split(",")]
    result = {}
    for mode in args.tables.split(","):
        scene = json.load(open(args.scene))
        scene["render"]["tables"] = mode
        proc, host, port = start(args.bin)
        rows = []
        try:
            for albedo in ALBEDOS:
                scene["materials"][args.material] = {"type": "medium", "albedo": albedo, "mfp": mfp,
                                                     "g": args.g, "ior": args.ior}
                status, h, data = request(host, port, "POST", "/v1/renders", json.dumps(scene),
                                          {"Content-Type": "application/json"})
                if status != 200:
                    sys.exit(f"render refused: {status} {data[:400]!r}")
                st = stages(h.get("server-timing", ""))
                tables = st.get("reconstruct", 0.0) + st.get("accumulate", 0.0)
                total = sum(v for k, v in st.items() if k not in ("parse", "queue"))
                rows.append((tables, total))
                print(f"{mode:12s} albedo {albedo}: reconstruct {st.get('reconstruct', 0):6.0f} ms, "
                      f"accumulate {st.get('accumulate', 0):6.0f} ms, render {total:6.0f} ms", flush=True)
        finally:
            proc.terminate()
            proc.wait(timeout=60)
        later = rows[1:]
        result[mode] = {"first_tables_ms": rows[0][0],
                        "tables_ms_median": statistics.median(r[0] for r in later),
                        "render_ms_median": statistics.median(r[1] for r in later)}
        print(f"{mode}: first material's tables {rows[0][0]:.0f} ms; later materials: tables "
              f"median {result[mode]['tables_ms_median']:.0f} ms, render median "
              f"{result[mode]['render_ms_median']:.0f} ms")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
