#!/usr/bin/env python3
"""single_study.py — the error and time of single scattering per bench scene, as a function of
render.single_samples and of adaptive single scattering (render.single_levels and
single_tolerance), against the same estimator converged (docs/bench.md, "Single scattering and
whole renders", "Adaptive single scattering").

Each bench scene's own file renders with "components": ["single"], method nn, 4 spp, seed 1.
The error is the PSNR against a run at --truth samples and --truth-spp camera samples per pixel,
every pixel computed (seed 1 too). At --truth-spp 4 (the default) every run sees the same camera
segments, so the error is what the samples along a segment add and nothing of the camera's
sampling; an interpolated pixel then counts its own segments' departure from its neighbours as
error, though it is the camera's. At --truth-spp 16 the truth is also converged in the camera's
samples: the error a user sees at 4 spp. Each run is a cold `nscatter render --timings`; the time
is its `single` stage. --baseline BIN adds a row rendered by another binary (an older build) at
--baseline-samples, to compare estimators at equal error.

    scripts/single_study.py --assets CACHE/assets --out /tmp/single
    scripts/single_study.py --assets CACHE/assets --samples 16,32,64 \\
        --baseline /path/to/old/nscatter --baseline-samples 100
    scripts/single_study.py --assets CACHE/assets --truth 256 --truth-spp 16 \\
        --samples 16,32,64,64/2/0.05,32/2/0.05

A run is SAMPLES, or SAMPLES/LEVELS/TOLERANCE for adaptive single scattering (SAMPLES alone
computes every pixel: single_levels 0). CACHE/assets holds the bench meshes (`nscatter bench`
writes them). Prints a Markdown table; every image and timing stays in --out. Exit status 0, 1 a
render failed, 2 bad arguments.
"""
import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = ["cloud", "milk", "candle", "bunny", "oil", "bumpy_sphere"]


def scene_file(out, scene, run, spp=4):
    """run: (samples, levels, tolerance); levels None writes neither key (an older binary)."""
    samples, levels, tolerance = run
    with open(os.path.join(ROOT, "scenes", "bench", scene + ".json")) as f:
        d = json.load(f)
    r = d.setdefault("render", {})
    r.update(method="nn", components=["single"], single_samples=samples, spp=spp, seed=1)
    if levels is not None:
        r.update(single_levels=levels, single_tolerance=tolerance)
    path = os.path.join(out, f"{scene}-{run_name(run)}-{spp}spp.json")
    with open(path, "w") as f:
        json.dump(d, f)
    return path


def run_name(run):
    samples, levels, tolerance = run
    return f"{samples}" if not levels else f"{samples}-l{levels}-t{tolerance:g}"


def parse_run(text):
    parts = text.split("/")
    if len(parts) not in (1, 3):
        raise ValueError(text)
    samples = int(parts[0])
    levels, tolerance = (int(parts[1]), float(parts[2])) if len(parts) == 3 else (0, 0.0)
    if not (1 <= samples <= 4096 and 0 <= levels <= 4 and 0 <= tolerance <= 1):
        raise ValueError(text)
    return samples, levels, tolerance


def render(binary, scene_json, image, assets):
    timings = image + ".timings.json"
    with open(timings, "w") as t:
        rc = subprocess.run([binary, "render", scene_json, "-o", image, "--timings",
                             "--assets", assets], stdout=t, stderr=subprocess.PIPE, text=True)
    if rc.returncode != 0:
        sys.exit(f"single_study: {binary} render {scene_json} failed: {rc.stderr.strip()}")
    with open(timings) as t:
        d = json.load(t)
    return d["stages"]["single"], d["counts"].get("single_interpolated", 0)


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
    p.add_argument("--samples", default="16,32,64",
                   help="runs: SAMPLES (every pixel) or SAMPLES/LEVELS/TOLERANCE (adaptive)")
    p.add_argument("--truth", type=int, default=512, help="samples of the converged image")
    p.add_argument("--truth-spp", type=int, default=4,
                   help="camera samples per pixel of the converged image (4: the runs' own segments)")
    p.add_argument("--baseline", help="another nscatter binary (an older build) for one more row")
    p.add_argument("--baseline-samples", type=int, default=100)
    a = p.parse_args()
    scenes = a.scenes.split(",")
    for s in scenes:
        if s not in SCENES:
            p.error(f"--scenes: '{s}' is not one of {', '.join(SCENES)}")
    try:
        runs = [parse_run(x) for x in a.samples.split(",")]
    except ValueError:
        p.error(f"--samples: '{a.samples}' is not a list of SAMPLES or SAMPLES/LEVELS/TOLERANCE "
                "(samples in [1, 4096], levels in [0, 4], tolerance in [0, 1])")
    if any(n < 1 or n > 4096 for n in [a.truth, a.baseline_samples]):
        p.error("samples must be in [1, 4096]")
    if not 1 <= a.truth_spp <= 4096:
        p.error("--truth-spp must be in [1, 4096]")
    os.makedirs(a.out, exist_ok=True)
    columns = ([f"baseline {a.baseline_samples}"] if a.baseline else []) + \
              [a.samples.split(",")[i] for i in range(len(runs))]
    print("| scene | " + " | ".join(columns) + " |")
    print("|---" * (len(columns) + 1) + "|")
    for scene in scenes:
        truth = os.path.join(a.out, f"{scene}-truth-{a.truth}-{a.truth_spp}spp.exr")
        render(a.nscatter, scene_file(a.out, scene, (a.truth, 0, 0.0), a.truth_spp), truth, a.assets)
        cells = []
        todo = ([(a.baseline, (a.baseline_samples, None, 0.0), "baseline")] if a.baseline else []) + \
               [(a.nscatter, run, "n") for run in runs]
        for binary, run, tag in todo:
            image = os.path.join(a.out, f"{scene}-{tag}{run_name(run)}.exr")
            ms, interpolated = render(binary, scene_file(a.out, scene, run), image, a.assets)
            db, mean = psnr(a.nscatter, image, truth)
            cell = f"{ms:,.0f} ms, {db:.1f} dB, mean {mean:.3f}"
            cells.append(cell + (f", {interpolated:,} px interpolated" if interpolated else ""))
        print(f"| {scene} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
