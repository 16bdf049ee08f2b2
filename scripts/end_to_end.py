#!/usr/bin/env python3
"""End to end (issue 16's targets; docs/bench.md, "End to end at 256²"): each bench scene's
own file at one image size, posted three times to a fresh `nscatter serve` (POST /v1/renders,
synchronous): the first render makes the material's tables (a new material), the second and
third find them cached. Prints the server's own time per render (Server-Timing, without
parse and queue) and the stages that take it, then one JSON line.

With --new-albedo every render after the first changes the medium's albedo (1 - albedo
scaled as scripts/material_change.py does), a new material each time, as a user sweeping it
does; --pause S waits S seconds between renders, when the server makes the albedo nodes of
a material being swept (nscatter serve --idle-work, on by default).

    python3 scripts/end_to_end.py --bin build/nscatter --assets ~/.cache/nscatter/bench/assets \\
        [--size 256] [--scenes milk,cloud] [--new-albedo --renders 5 --pause 10] [--render adaptive_spp=0]

The meshes' scenes need the bench's assets (`nscatter bench` writes them to CACHE/assets).
Python standard library only.
"""
import argparse
import json
import os
import sys
import time

from bench_sweep import ROOT, request, start
from material_change import FACTORS, stages

SCENES = ["bumpy_sphere", "bunny", "candle", "milk", "oil", "cloud"]
SHOWN = ["reconstruct", "accumulate", "ray_pass", "adaptive", "vrl", "boundary", "gather", "single"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "nscatter"))
    ap.add_argument("--assets", default=None, help="the server's --assets folder")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--renders", type=int, default=3)
    ap.add_argument("--new-albedo", action="store_true",
                    help="a new albedo of the medium at every render after the first")
    ap.add_argument("--pause", type=float, default=0.0, help="seconds between renders")
    ap.add_argument("--render", action="append", default=[], metavar="KEY=JSON",
                    help="sets render.KEY in every scene, e.g. adaptive_spp=0 (repeatable)")
    args = ap.parse_args()
    overrides = {}
    for item in args.render:
        key, _, value = item.partition("=")
        try:
            overrides[key] = json.loads(value)
        except ValueError:
            ap.error(f"--render {item}: not KEY=JSON")
    scenes = args.scenes.split(",")
    unknown = [n for n in scenes if n not in SCENES]
    if unknown:
        ap.error(f"--scenes: {', '.join(unknown)} not a bench scene ({', '.join(SCENES)})")
    if args.size < 1 or not 1 <= args.renders <= len(FACTORS):
        ap.error(f"--size at least 1, --renders 1 to {len(FACTORS)}")
    result = {}
    for name in scenes:
        scene = json.load(open(os.path.join(ROOT, "scenes", "bench", f"{name}.json")))
        scene["camera"]["width"] = scene["camera"]["height"] = args.size
        scene.setdefault("render", {}).update(overrides)
        proc, host, port = start(args.bin, ("--assets", args.assets) if args.assets else ())
        rows = []
        try:
            medium = next(m for m in scene["materials"].values() if m.get("type") == "medium")
            base = medium.get("albedo")
            for i in range(args.renders):
                if i:
                    time.sleep(args.pause)
                if args.new_albedo and i:
                    if base is None:  # the preset's: the parser says which (GET /v1/materials)
                        _, _, raw = request(host, port, "GET", "/v1/materials")
                        base = next(p["albedo"] for p in json.loads(raw)["materials"]
                                    if p["name"] == medium["preset"])
                    medium["albedo"] = [round(min(0.9999, max(0.0, 1 - FACTORS[i] * (1 - a))), 6) for a in base]
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
