#!/usr/bin/env python3
"""End to end (issue 16's targets; docs/bench.md, "End to end at 256²"): each bench scene's
own file at one image size, posted three times to a fresh `nscatter serve` (POST /v1/renders,
synchronous): the first render makes the material's tables (a new material), the second and
third find them cached. Prints the server's own time per render (Server-Timing, without
parse and queue) and the stages that take it, then one JSON line.

    python3 scripts/end_to_end.py --bin build/nscatter --assets ~/.cache/nscatter/bench/assets \\
        [--size 256] [--scenes milk,cloud]

The meshes' scenes need the bench's assets (`nscatter bench` writes them to CACHE/assets).
Python standard library only.
"""
import argparse
import json
import os
import sys

from bench_sweep import ROOT, request, start
from material_change import stages

SCENES = ["bumpy_sphere", "bunny", "candle", "milk", "oil", "cloud"]
SHOWN = ["reconstruct", "accumulate", "ray_pass", "vrl", "boundary", "gather", "single"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "nscatter"))
    ap.add_argument("--assets", default=None, help="the server's --assets folder")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--renders", type=int, default=3)
    args = ap.parse_args()
    scenes = args.scenes.split(",")
    unknown = [n for n in scenes if n not in SCENES]
    if unknown:
        ap.error(f"--scenes: {', '.join(unknown)} not a bench scene ({', '.join(SCENES)})")
    if args.size < 1 or args.renders < 1:
        ap.error("--size and --renders: at least 1")
    result = {}
    for name in scenes:
        scene = json.load(open(os.path.join(ROOT, "scenes", "bench", f"{name}.json")))
        scene["camera"]["width"] = scene["camera"]["height"] = args.size
        proc, host, port = start(args.bin, ("--assets", args.assets) if args.assets else ())
        rows = []
        try:
            for _ in range(args.renders):
                status, h, data = request(host, port, "POST", "/v1/renders", json.dumps(scene),
                                          {"Content-Type": "application/json"})
                if status != 200:
                    sys.exit(f"{name}: render refused: {status} {data[:400]!r}")
                st = stages(h.get("server-timing", ""))
                total = sum(v for k, v in st.items() if k not in ("parse", "queue"))
                rows.append({"total_ms": round(total, 1), **{k: round(st.get(k, 0.0), 1) for k in SHOWN}})
                print(f"{name:12s} {total:8.0f} ms  " +
                      "  ".join(f"{k} {st.get(k, 0.0):.0f}" for k in SHOWN), flush=True)
        finally:
            proc.terminate()
            proc.wait(timeout=60)
        result[name] = rows
    print(json.dumps(result))


if __name__ == "__main__":
    main()
