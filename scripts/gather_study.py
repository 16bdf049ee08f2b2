#!/usr/bin/env python3
"""gather_study.py — the error and time of the gather (double and multiple scattering) per bench
scene, as a function of render.vrls and render.gather_camera_samples, against a judge with many
more light paths on another seed (docs/bench.md, "One camera sample per gathered pixel").

Each bench scene's own file renders with "components": ["double", "multiple"], method nn, 4 spp,
seed 1, its other settings the file's (boundary walks, tile 2). A run is VRLS/CAMERA_SAMPLES
(camera samples 0 = every sample). The judge renders --judge (same form) on --judge-seed: its
light paths are not the runs', so its PSNR measures the runs' noise plus its own (each row
states the judge). Each run is a cold `nscatter render --timings`; the time is its `gather`
stage and its total. Prints a Markdown table; every image and timing stays in --out.

    scripts/gather_study.py --assets CACHE/assets --out /tmp/gather \\
        --runs 10000/0,10000/1,40000/1 --judge 100000/1

CACHE/assets holds the bench meshes (`nscatter bench` writes them). Exit status 0, 1 a render
failed, 2 bad arguments.
"""
import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = ["cloud", "milk", "candle", "bunny", "oil", "bumpy_sphere"]


def parse_run(text):
    parts = text.split("/")
    if len(parts) != 2 or not all(p.isdigit() for p in parts) or int(parts[0]) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: a run is VRLS/CAMERA_SAMPLES, e.g. 10000/1")
    return int(parts[0]), int(parts[1])


def render(args, scene, run, seed):
    vrls, samples = run
    with open(os.path.join(ROOT, "scenes", "bench", scene + ".json")) as f:
        d = json.load(f)
    d.setdefault("render", {}).update(method="nn", components=["double", "multiple"], spp=4, seed=seed,
                                      vrls=vrls, gather_camera_samples=samples)
    name = f"{scene}-{vrls}-{samples}-s{seed}"
    path = os.path.join(args.out, name + ".json")
    with open(path, "w") as f:
        json.dump(d, f)
    image = os.path.join(args.out, name + ".exr")
    p = subprocess.run([args.bin, "render", path, "-o", image, "--timings", "--assets", args.assets],
                       capture_output=True, text=True)
    if p.returncode:
        print(f"{name}: {p.stderr.strip()[-300:]}", file=sys.stderr)
        return None
    t = json.loads(p.stdout)
    return image, t["stages"].get("gather", 0.0), t["total_ms"], t["counts"]["gather_segments"]


def compare(args, a, b):
    p = subprocess.run([args.bin, "compare", a, b], capture_output=True, text=True)
    if p.returncode not in (0, 1):
        return None
    return json.loads(p.stdout)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "nscatter"))
    ap.add_argument("--assets", required=True)
    ap.add_argument("--out", default="/tmp/gather_study")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--runs", type=lambda s: [parse_run(x) for x in s.split(",")],
                    default=[(10000, 0), (10000, 1), (40000, 1)])
    ap.add_argument("--judge", type=parse_run, default=(100000, 1))
    ap.add_argument("--judge-seed", type=int, default=7)
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    print(f"judge: {args.judge[0]} light paths, camera samples {args.judge[1]}, seed {args.judge_seed}\n")
    print("| scene | vrls | camera samples | gather segments | gather ms | total ms | PSNR dB | mean / judge's |")
    print("|---|---|---|---|---|---|---|---|")
    status = 0
    for scene in args.scenes.split(","):
        judge = render(args, scene, args.judge, args.judge_seed)
        if not judge:
            status = 1
            continue
        for run in args.runs:
            got = render(args, scene, run, 1)
            c = got and compare(args, got[0], judge[0])
            if not c:
                status = 1
                continue
            print(f"| {scene} | {run[0]} | {run[1] or 'all'} | {got[3]} | {got[1]:.0f} | {got[2]:.0f} | "
                  f"{c['psnr']['all']:.2f} | {c['mean_ratio']['all']:.4f} |", flush=True)
    return status


if __name__ == "__main__":
    sys.exit(main())
