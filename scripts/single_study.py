#!/usr/bin/env python3
"""single_study.py — the error and time of single scattering per bench scene, as a function of
render.single_samples, against the same estimator converged on the same camera segments
(docs/bench.md, "Single scattering and whole renders").

Each bench scene's own file renders with "components": ["single"], method nn, 4 spp, seed 1,
so every run sees the same camera segments; the error is the PSNR against a run at
--truth samples (seed 1 too), so it measures what the samples along a segment add and
nothing of the camera's sampling. Each run is a cold `nscatter render --timings`; the time
is its `single` stage. --baseline BIN adds a row rendered by another binary (an older build)
at --baseline-samples, to compare estimators at equal error.

    scripts/single_study.py --assets CACHE/assets --out /tmp/single
    scripts/single_study.py --assets CACHE/assets --samples 16,32,64 \\
        --baseline /path/to/old/nscatter --baseline-samples 100

CACHE/assets holds the bench meshes (`nscatter bench` writes them). Prints a Markdown table;
every image and timing stays in --out. Exit status 0, 1 a render failed, 2 bad arguments.
"""
import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = ["cloud", "milk", "candle", "bunny", "oil", "bumpy_sphere"]


def scene_file(out, scene, samples):
    with open(os.path.join(ROOT, "scenes", "bench", scene + ".json")) as f:
        d = json.load(f)
    r = d.setdefault("render", {})
    r.update(method="nn", components=["single"], single_samples=samples, spp=4, seed=1)
    path = os.path.join(out, f"{scene}-{samples}.json")
    with open(path, "w") as f:
        json.dump(d, f)
    return path


def render(binary, scene_json, image, assets):
    timings = image + ".timings.json"
    with open(timings, "w") as t:
        rc = subprocess.run([binary, "render", scene_json, "-o", image, "--timings",
                             "--assets", assets], stdout=t, stderr=subprocess.PIPE, text=True)
    if rc.returncode != 0:
        sys.exit(f"single_study: {binary} render {scene_json} failed: {rc.stderr.strip()}")
    with open(timings) as t:
        return json.load(t)["stages"]["single"]


def psnr(binary, image, truth):
    rc = subprocess.run([binary, "compare", image, truth], capture_output=True, text=True)
    if rc.returncode != 0:
        sys.exit(f"single_study: compare {image} {truth} failed: {rc.stderr.strip()}")
    d = json.loads(rc.stdout)
    return d["psnr"]["all"], d["mean_ratio"]["all"]


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--nscatter", default=os.path.join(ROOT, "build", "nscatter"))
    p.add_argument("--assets", required=True, help="folder with the bench meshes (CACHE/assets)")
    p.add_argument("--out", default="single-study")
    p.add_argument("--scenes", default=",".join(SCENES))
    p.add_argument("--samples", default="16,32,64", help="render.single_samples to measure")
    p.add_argument("--truth", type=int, default=512, help="samples of the converged image")
    p.add_argument("--baseline", help="another nscatter binary (an older build) for one more row")
    p.add_argument("--baseline-samples", type=int, default=100)
    a = p.parse_args()
    scenes = a.scenes.split(",")
    for s in scenes:
        if s not in SCENES:
            p.error(f"--scenes: '{s}' is not one of {', '.join(SCENES)}")
    try:
        samples = [int(x) for x in a.samples.split(",")]
    except ValueError:
        p.error(f"--samples: '{a.samples}' is not a list of whole numbers")
    if any(n < 1 or n > 4096 for n in samples + [a.truth, a.baseline_samples]):
        p.error("samples must be in [1, 4096]")
    os.makedirs(a.out, exist_ok=True)
    columns = ([f"baseline {a.baseline_samples}"] if a.baseline else []) + [str(n) for n in samples]
    print("| scene | " + " | ".join(columns) + " |")
    print("|---" * (len(columns) + 1) + "|")
    for scene in scenes:
        truth = os.path.join(a.out, f"{scene}-truth.exr")
        render(a.nscatter, scene_file(a.out, scene, a.truth), truth, a.assets)
        cells = []
        runs = ([(a.baseline, a.baseline_samples, "baseline")] if a.baseline else []) + \
               [(a.nscatter, n, "n") for n in samples]
        for binary, n, tag in runs:
            image = os.path.join(a.out, f"{scene}-{tag}{n}.exr")
            ms = render(binary, scene_file(a.out, scene, n), image, a.assets)
            db, mean = psnr(a.nscatter, image, truth)
            cells.append(f"{ms:,.0f} ms, {db:.1f} dB, mean {mean:.3f}")
        print(f"| {scene} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
