"""`nscatter bench` from the command line, on one tiny scene: the report and the contact
sheet are written, every number of a rendered row in the report parses back and is finite,
bad arguments exit 2 naming the argument, and a missing reference is rendered once and
read from the cache the second time (and rendered again only by --references)."""
import json
import math
import os
import struct
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import Checks, sanitizer_env  # noqa: E402

BIN = os.environ.get("NSCATTER_BIN", "")
TIMEOUT_S = 300
SIZE = 16
# The cheapest scene (a sphere primitive, index matched) and methods that need no tables.
TINY = ["--scenes", "cloud", "--methods", "nn_surface,pt", "--width", str(SIZE), "--height",
        str(SIZE), "--ref-spp", "4", "--pt-spp", "1,2", "--repeat", "1"]
NUMERIC_COLUMNS = ["render.vrls", "VRLs", "spp", "time ms", "first ms", "camera ms", "PSNR dB", "RMSE", "rel. err",
                   "interactions", "table MB", "weights KB"]


def run(*args):
    p = subprocess.run([BIN, "bench", *args], capture_output=True, timeout=TIMEOUT_S,
                       env=sanitizer_env())
    return p.returncode, p.stdout.decode(errors="replace"), p.stderr.decode(errors="replace")


def markdown_table(text, heading):
    """Rows of the first table after `heading`, as dicts keyed by the header cells."""
    lines = text.split(heading, 1)[1].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("|"))
    header = [c.strip() for c in lines[start].strip("|").split("|")]
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        rows.append(dict(zip(header, cells)))
    return rows


def png_size(path):
    with open(path, "rb") as f:
        data = f.read(32)
    if data[:8] != b"\x89PNG\r\n\x1a\n" or data[12:16] != b"IHDR":
        return None
    return struct.unpack(">II", data[16:24])


def references(cache):
    return sorted(n for n in os.listdir(cache) if n.endswith(".exr"))


def test_bad_arguments(t, d):
    cases = [
        (["--widht", "16"], "--widht"),
        (["--width", "0"], "--width"),
        (["--ref-spp", "2.5"], "--ref-spp"),
        (["--methods", "nn_fast"], "nn_fast"),
        (["--scenes", "teapot"], "teapot"),
        (["--diff", "upbp"], "--diff"),
        (["--pt-spp", "1,,4"], "--pt-spp"),
        (["--boundary", "on"], "--boundary"),
        (["--seeds", "0"], "--seeds"),
        (["--seeds", "65"], "--seeds"),
        (["--cache"], "--cache"),
    ]
    for args, named in cases:
        code, _, err = run(*args, "--cache", os.path.join(d, "bad-cache"), "--out",
                           os.path.join(d, "bad-out"))
        if args == ["--cache"]:  # the value is missing: run it alone
            code, _, err = run("--cache")
        t.equal(code, 2, f"exit status of bench {' '.join(args)}")
        t.check(named in err, f"bench {' '.join(args)}: message names {named!r}: {err.strip()}")
    t.check(not os.path.exists(os.path.join(d, "bad-out", "report.md")),
            "no report after bad arguments")


def check_report(t, out):
    report_path = os.path.join(out, "report.md")
    sheet_path = os.path.join(out, "contact_sheet.png")
    t.check(os.path.isfile(report_path), "report.md written")
    t.check(os.path.isfile(sheet_path), "contact_sheet.png written")
    if not os.path.isfile(report_path):
        return
    text = open(report_path, encoding="utf-8").read()
    # Without --boundary the rows render as their scene files say (the default, walks).
    t.check("- render.boundary of the nn and table rows: the scene files' (walks where they do not say)"
            in text, "the report names the boundary model")
    t.check("## Seeds" not in text, "no Seeds section without --seeds")
    rows = markdown_table(text, "## Results")
    methods = {r["method"]: r for r in rows if r["scene"] == "cloud"}
    t.check(set(methods) == {"nn_surface", "pt"}, f"result rows: {sorted(methods)}")
    for name, row in methods.items():
        t.equal(row["status"], "ok", f"{name} status")
        for col in NUMERIC_COLUMNS:
            try:
                v = float(row[col])
            except (KeyError, ValueError):
                t.check(False, f"{name} {col}: {row.get(col)!r} is not a number")
                continue
            t.check(math.isfinite(v) and v >= 0, f"{name} {col} = {v} finite and >= 0")
    if "nn_surface" in methods:
        # The camera pass against pt's order 0: the same light transport, so only pt's noise
        # at 4 spp separates them; a factor error (exposure, 1/spp) would cost far more.
        psnr = float(methods["nn_surface"]["PSNR dB"])
        t.check(15 < psnr < 200, f"nn_surface PSNR {psnr} dB against the surface reference")
    # Each component set's reference is listed with its spp and time.
    refs = markdown_table(text, "## References")
    got = {r["components"] for r in refs if r["scene"] == "cloud"}
    t.equal(got, {"full", "surface"}, "reference component sets")
    for r in refs:
        t.equal(r["spp"], "4", "reference spp")
        t.check(math.isfinite(float(r["time s"])), f"reference time {r['time s']}")
        # The noise ceiling: the reference's own noise measured from a second render; at
        # 4 spp it is low, but it is a number.
        try:
            ceiling = float(r["noise ceiling dB"])
        except (KeyError, ValueError):
            ceiling = float("nan")
        t.check(math.isfinite(ceiling) and 0 < ceiling < 200, f"noise ceiling {r.get('noise ceiling dB')!r}")
        meta = json.load(open(r["file"].strip("`") + ".json", encoding="utf-8"))
        t.check(meta.get("variance", 0) > 0, f"variance kept beside the reference: {meta}")
    for row in rows:
        t.check("PSNR, ref noise out dB" in row, "results carry the PSNR with the reference's noise out")
    # Contact sheet: columns reference, nn_surface, pt, difference; 2-pixel gaps.
    size = png_size(sheet_path)
    t.equal(size, (4 * (SIZE + 2) - 2, SIZE), "contact sheet size (4 columns, 1 row)")
    return refs


def test_report_and_reference_cache(t, d):
    cache = os.path.join(d, "cache")
    code, _, err = run(*TINY, "--cache", cache, "--out", os.path.join(d, "out1"))
    t.equal(code, 0, f"first bench run ({err.strip()[-400:]})")
    refs = check_report(t, os.path.join(d, "out1"))
    t.check(refs and all(r["this run"] == "rendered" for r in refs), "first run renders references")
    files = references(cache)
    t.equal(len(files), 2, f"references cached: {files}")
    mtimes = {f: os.stat(os.path.join(cache, f)).st_mtime_ns for f in files}

    code, _, err = run(*TINY, "--cache", cache, "--out", os.path.join(d, "out2"))
    t.equal(code, 0, f"second bench run ({err.strip()[-400:]})")
    refs = check_report(t, os.path.join(d, "out2"))
    t.check(refs and all(r["this run"] == "cached" for r in refs), "second run reuses references")
    t.check("references: 0 rendered" in err, f"second run renders no reference: {err[-300:]}")
    t.equal(references(cache), files, "same reference files")
    t.check(all(os.stat(os.path.join(cache, f)).st_mtime_ns == m for f, m in mtimes.items()),
            "reference files untouched")

    # --references renders them again (the sets the chosen methods need), reports its time,
    # writes no report.
    code, _, err = run(*TINY, "--references", "--cache", cache, "--out", os.path.join(d, "out3"))
    t.equal(code, 0, f"--references ({err.strip()[-300:]})")
    t.check("references: 2 rendered in" in err, f"--references reports its time: {err[-300:]}")
    t.check(not os.path.exists(os.path.join(d, "out3", "report.md")), "--references writes no report")

    # A different size is a different scene: a new reference, the old ones stay.
    code, _, err = run(*TINY[:2], "--methods", "nn_full,vrl,pt", "--width", "8", "--height", "8",
                       *TINY[8:-2], "--repeat", "2", "--seeds", "2", "--cache", cache, "--out",
                       os.path.join(d, "out4"))
    t.equal(code, 0, f"8x8 run ({err.strip()[-300:]})")
    t.check("references: 1 rendered" in err, f"another size renders its own reference: {err[-300:]}")
    # Rendered twice, nn_full's second render keeps the first one's camera pass (a render with
    # scattering keeps it): its time leaves the pass out, and the camera column gives it
    # back. pt keeps none.
    report = os.path.join(d, "out4", "report.md")
    text = open(report, encoding="utf-8").read() if os.path.isfile(report) else ""
    camera = {r["method"]: r["camera ms"] for r in markdown_table(text, "## Results")} if text else {}
    t.check(float(camera.get("nn_full", "nan")) > 0, f"nn_full's kept camera pass: {camera}")
    t.equal(camera.get("pt"), "0.0", "pt keeps no camera pass")
    # The speed-up over pt for a new view counts that pass: not above the one for a kept view
    # (both printed to 3 digits).
    targets = markdown_table(text, "## Targets") if text else []
    speeds = [(r["speedup over pt"], r["speedup, new view"]) for r in targets if r["scene"] == "cloud"]
    t.check(len(speeds) == 1 and all(v != "n/a" for v in speeds[0]) and
            float(speeds[0][1].lstrip("≥ ")) <= float(speeds[0][0].lstrip("≥ ")),
            f"speed-ups kept view, new view: {speeds}")
    # With --seeds the targets read each row's error over its seeds, not its first seed's
    # (three numbers printed to 0.005 dB each).
    seeds = {r["method"]: r["PSNR of the mean MSE dB"] for r in markdown_table(text, "## Seeds")} if text else {}
    gaps = [r["nn full − vrl dB"] for r in targets if r["scene"] == "cloud"]
    t.check(len(gaps) == 1 and "nn_full" in seeds and "vrl" in seeds and
            abs(float(gaps[0]) - (float(seeds["nn_full"]) - float(seeds["vrl"]))) <= 0.016,
            f"nn full − vrl {gaps} from the seeds' PSNR of the mean MSE {seeds}")
    # And so does pt's time for nn's error: the MSE its estimate starts from (printed with the
    # reference's noise v / spp taken out) is the seeds' mean, peak^2 / 10^(PSNR/10), with
    # the peak from the Results row's own PSNR and RMSE (printed to 4 digits: 1% allowed).
    results = {r["method"]: r for r in markdown_table(text, "## Results")} if text else {}
    refs = [r for r in markdown_table(text, "## References") if r["components"] == "full"] if text else []
    lines = text.splitlines()
    head = next((i for i, line in enumerate(lines) if line.startswith("| scene | variance per sample")), None)
    estimate = dict(zip([c.strip() for c in lines[head].strip("|").split("|")],
                        [c.strip() for c in lines[head + 2].strip("|").split("|")])) if head is not None else {}
    nn = results.get("nn_full", {})
    if nn and refs and estimate and "nn_full" in seeds:
        peak = float(nn["RMSE"]) * 10 ** (float(nn["PSNR dB"]) / 20)
        mean_mse = peak ** 2 / 10 ** (float(seeds["nn_full"]) / 10)
        used = (float(estimate["nn full MSE (reference noise removed; over its seeds with --seeds)"]) +
                float(estimate["variance per sample"]) / float(refs[0]["spp"]))
        t.check(abs(used / mean_mse - 1) < 0.01,
                f"pt's estimate starts from the seeds' mean MSE {mean_mse:.4e}: {used:.4e} "
                f"(seed 1's own: {float(nn['RMSE']) ** 2:.4e})")
    else:
        t.check(False, f"the 8x8 report has its nn_full row, full reference, pt estimate and seeds")


def test_seeds(t, d):
    """--seeds 3: the nn row rendered on two more seeds; its spread is reported (camera
    samples change with the seed, so the spread is not zero), and the row's own seed is one
    of the three."""
    out = os.path.join(d, "seeds")
    code, _, err = run(*TINY, "--seeds", "3", "--cache", os.path.join(d, "cache"), "--out", out)
    t.equal(code, 0, f"bench --seeds 3 ({err.strip()[-400:]})")
    text = open(os.path.join(out, "report.md"), encoding="utf-8").read()
    t.check("Each row rendered on 3 seeds" in text, "the Seeds section says how many")
    rows = [r for r in markdown_table(text, "## Seeds") if r["scene"] == "cloud"]
    t.equal([r["method"] for r in rows], ["nn_surface"], "one Seeds row: nn_surface (pt is the reference)")
    if not rows:
        return
    row = rows[0]
    t.equal(row["seeds"], "3", "seeds rendered")
    own = markdown_table(text, "## Results")
    own = next(r for r in own if r["method"] == "nn_surface")["mean / ref R G B"].split()
    for channel, key in enumerate(("mean / ref R", "G", "B")):
        mean, sd = (float(x) for x in row[key].split("±"))
        t.check(0.5 < mean < 2 and 0 < sd < 0.5, f"{key}: {mean} ± {sd}")
        # The row's own mean / ref is one of the three: within 2 sd of their mean (sd of 3).
        t.check(abs(float(own[channel]) - mean) <= 2 * sd + 1e-3, f"{key}: row's own {own[channel]} in {mean} ± {sd}")
    lo, median, hi = float(row["min"]), float(row["PSNR dB median"]), float(row["max"])
    t.check(15 < lo <= median <= hi < 200, f"PSNR min {lo} <= median {median} <= max {hi}")
    # Three seeds are the min, the median and the max: the PSNR of their mean squared error
    # follows from them (each printed to 0.005 dB).
    of_mean = -10 * math.log10(sum(10 ** (-p / 10) for p in (lo, median, hi)) / 3)
    t.check(abs(float(row["PSNR of the mean MSE dB"]) - of_mean) <= 0.011,
            f"PSNR of the mean MSE {row['PSNR of the mean MSE dB']}, from the three seeds {of_mean:.3f}")

    # A scene whose seed is the largest there is: the seed after it wraps to 1, never to 0
    # (which the bench reads as "the scene's own" and would render the same image again, a
    # spread of exactly 0).
    scene_dir = os.path.join(d, "max-seed-scenes")
    os.makedirs(scene_dir, exist_ok=True)
    source = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scenes", "bench")
    for name in os.listdir(source):
        if name.endswith(".json"):
            scene = json.load(open(os.path.join(source, name), encoding="utf-8"))
            if name == "cloud.json":
                scene.setdefault("render", {})["seed"] = 4294967295
            json.dump(scene, open(os.path.join(scene_dir, name), "w", encoding="utf-8"))
    out = os.path.join(d, "seeds-max")
    code, _, err = run(*TINY, "--seeds", "2", "--scene-dir", scene_dir, "--cache", os.path.join(d, "cache-max"),
                       "--out", out)
    t.equal(code, 0, f"bench --seeds 2 at seed 4294967295 ({err.strip()[-400:]})")
    if code == 0:
        rows = [r for r in markdown_table(open(os.path.join(out, "report.md"), encoding="utf-8").read(), "## Seeds")
                if r["method"] == "nn_surface"]
        sd = float(rows[0]["mean / ref R"].split("±")[1]) if rows else 0.0
        t.check(sd > 0, f"the seed after 4294967295 renders another image: sd {sd}")


def compare(a, b):
    p = subprocess.run([BIN, "compare", a, b], capture_output=True, timeout=TIMEOUT_S,
                       env=sanitizer_env())
    return json.loads(p.stdout) if p.returncode == 0 else None


def progressive_refs(t, out):
    """The References rows of a run with --ref-ceiling, each with its checkpoint's .json."""
    text = open(os.path.join(out, "report.md"), encoding="utf-8").read()
    refs = markdown_table(text, "## References")
    for r in refs:
        path = r["file"].strip("`")
        r["path"] = path
        r["meta"] = json.load(open(path.rsplit("-k", 1)[0] + ".json", encoding="utf-8"))
    return refs


def test_progressive_references(t, d):
    """--ref-ceiling: chunks of --ref-spp (4) on successive seeds until the noise ceiling
    reaches the target, checkpointed per chunk, resumed by the next run; the noise it claims
    is the noise it has, against an independent render."""
    cache = os.path.join(d, "progressive")
    target = 28.0
    args = [*TINY, "--ref-ceiling", str(target), "--cache", cache]
    # The budget only bounds a broken estimate that would never reach the target.
    code, _, err = run(*args, "--ref-budget", "60", "--out", os.path.join(d, "p1"))
    t.equal(code, 0, f"progressive run ({err.strip()[-400:]})")
    refs = progressive_refs(t, os.path.join(d, "p1"))
    t.equal({r["components"] for r in refs}, {"full", "surface"}, "progressive reference sets")
    chunks_of = {}
    # A target above every ceiling reached (8 chunks at least may overshoot the first).
    higher = max(float(r["noise ceiling dB"]) for r in refs) + 2
    for r in refs:
        chunks, chunk_spp = (int(x) for x in r["chunks"].split(" × "))
        chunks_of[r["components"]] = chunks
        t.check(chunks >= 8 and chunk_spp == 4, f"{r['components']}: {r['chunks']} chunks of 4 spp (8 at least)")
        t.equal(int(r["spp"]), chunks * 4, f"{r['components']}: spp = chunks x chunk spp")
        t.check(float(r["noise ceiling dB"]) >= target, f"{r['components']}: ceiling {r['noise ceiling dB']}"
                f" reaches {target}")
        t.equal(r["meta"]["chunks"], chunks, f"{r['components']}: the checkpoint names {chunks} chunks")
        t.check(r["meta"]["ceiling_db"] >= target and r["meta"]["noise_mse"] > 0,
                f"{r['components']}: checkpoint {r['meta']}")
    files = sorted(f for f in os.listdir(cache) if f.endswith(".exr"))
    t.equal(len(files), 4, f"one mean and one M2 per reference, older chunks' removed: {files}")

    # Honest noise: the surface reference against an independent pt render of 256 spp on
    # another seed. Their MSE is the reference's noise plus that render's (the per-sample
    # variance over 256); the chunks' spread must predict it. Forgetting to divide the
    # spread by the chunk count would be off by that count (>= 2).
    surface = next(r for r in refs if r["components"] == "surface")
    scene = json.load(open(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                        "scenes", "bench", "cloud.json"), encoding="utf-8"))
    scene["camera"].update(width=SIZE, height=SIZE)
    scene["render"].update(method="pt", components=["surface"], spp=256, seed=4242)
    scene["render"].pop("vrls", None)
    scene_path = os.path.join(d, "independent.json")
    with open(scene_path, "w", encoding="utf-8") as f:
        json.dump(scene, f)
    independent = os.path.join(d, "independent.exr")
    p = subprocess.run([BIN, "render", scene_path, "-o", independent], capture_output=True,
                       timeout=TIMEOUT_S, env=sanitizer_env())
    t.equal(p.returncode, 0, f"independent render ({p.stderr.decode(errors='replace')[-300:]})")
    m = compare(surface["path"], independent)
    if m:
        measured = m["rmse"]["all"] ** 2
        meta = surface["meta"]
        expected = meta["noise_mse"] + meta["variance"] / 256
        t.check(0.5 < measured / expected < 2.0,
                f"MSE against an independent render {measured:.3g}, predicted {expected:.3g}")
        print(f"progressive surface reference: {meta['chunks']} chunks, MSE against an independent "
              f"256-spp render {measured:.4g}, predicted {expected:.4g}")

    # Nothing to add: the second run reads the checkpoints and touches no file.
    mtimes = {f: os.stat(os.path.join(cache, f)).st_mtime_ns for f in os.listdir(cache)}
    code, _, err = run(*args, "--out", os.path.join(d, "p2"))
    t.equal(code, 0, f"second progressive run ({err.strip()[-300:]})")
    t.check("references: 0 rendered" in err, f"second run renders no chunk: {err[-300:]}")
    t.check(all(os.stat(os.path.join(cache, f)).st_mtime_ns == m for f, m in mtimes.items()),
            "checkpoints untouched")

    # A higher target resumes: more chunks than before, the first ones kept (the chunk count
    # grows from where it was, and the earlier pair is replaced by the new one). Noise
    # ceilings are still estimates: the target is set 2 dB above the highest one reached.
    code, _, err = run(*TINY, "--ref-ceiling", str(higher), "--cache", cache, "--out",
                       os.path.join(d, "p3"))
    t.equal(code, 0, f"resumed run ({err.strip()[-300:]})")
    resumed = progressive_refs(t, os.path.join(d, "p3"))
    higher = max(float(r["noise ceiling dB"]) for r in resumed) + 2
    for r in resumed:
        before = chunks_of[r["components"]]
        t.check(r["meta"]["chunks"] > before, f"{r['components']}: {r['meta']['chunks']} chunks after {before}")
        t.check(f"chunk {before + 1}," in err, f"{r['components']}: resumed at chunk {before + 1}")
    t.check("chunk 1," not in err, "resumed, not started again")
    t.equal(len([f for f in os.listdir(cache) if f.endswith(".exr")]), 4, "still one pair per reference")

    # --references works on the references only and resumes them (hours of chunks are not
    # thrown away): a higher target adds chunks, writes no report.
    code, _, err = run(*TINY, "--references", "--ref-ceiling", str(higher), "--cache", cache,
                       "--out", os.path.join(d, "p5"))
    t.equal(code, 0, f"--references with --ref-ceiling ({err.strip()[-300:]})")
    t.check("chunk 1," not in err and "references: 0 rendered" not in err, f"resumed: {err[-300:]}")
    t.check(not os.path.exists(os.path.join(d, "p5", "report.md")), "--references writes no report")
    t.equal(len([f for f in os.listdir(cache) if f.endswith(".exr")]), 4, "one pair per reference")

    # A budget stops early and says so; the report gives the ceiling reached.
    code, _, err = run(*TINY, "--ref-ceiling", "120", "--ref-budget", "1", "--cache", cache, "--out",
                       os.path.join(d, "p4"))
    t.equal(code, 0, f"budgeted run ({err.strip()[-300:]})")
    t.check("share of --ref-budget spent" in err, f"the budget's end is reported: {err[-300:]}")
    for r in progressive_refs(t, os.path.join(d, "p4")):
        t.check(float(r["noise ceiling dB"]) < 120, f"{r['components']}: below the target")

    # --ref-max-spp stops a target that is out of reach: 3 chunks of 4 spp, then no more.
    capped = os.path.join(d, "capped")
    code, _, err = run(*TINY, "--ref-ceiling", "120", "--ref-max-spp", "12", "--cache", capped,
                       "--out", os.path.join(d, "p6"))
    t.equal(code, 0, f"--ref-max-spp run ({err.strip()[-300:]})")
    t.check("--ref-max-spp 12 reached at 3 chunks" in err, f"the cap is reported: {err[-300:]}")
    metas = {}
    for r in progressive_refs(t, os.path.join(d, "p6")):
        t.equal((r["meta"]["chunks"], r["spp"]), (3, "12"), f"{r['components']}: capped at 12 spp")
        metas[r["components"]] = r["path"].rsplit("-k", 1)[0] + ".json"

    # The ceiling's rise over the last doubling of the chunks: 16 chunks (the cap), the
    # checkpoint keeps every chunk's ceiling, and the report gives the rise from 8 to 16
    # chunks against the 3 dB of a finite variance, which pt's surface and full solution of
    # this cloud have (measured +2.8 and +3.0 dB; no heavy-tail warning). Without the history the
    # column reads "–".
    tail = os.path.join(d, "tail")
    code, _, err = run(*TINY, "--ref-ceiling", "120", "--ref-max-spp", "64", "--cache", tail,
                       "--out", os.path.join(d, "p8"))
    t.equal(code, 0, f"16-chunk run ({err.strip()[-300:]})")
    t.check("heavy tail" not in err, f"no heavy-tail warning for the cloud: {err[-400:]}")
    for r in progressive_refs(t, os.path.join(d, "p8")):
        ceilings = r["meta"].get("ceilings") or []
        t.equal(len(ceilings), 16, f"{r['components']}: a ceiling per chunk: {ceilings}")
        t.check(ceilings[:1] == [None] and all(isinstance(c, float) for c in ceilings[1:]),
                f"{r['components']}: none after one chunk, numbers after: {ceilings}")
        if len(ceilings) == 16 and isinstance(ceilings[15], float):
            t.check(abs(ceilings[15] - r["meta"]["ceiling_db"]) < 1e-6, f"{r['components']}: the last is the ceiling")
        rise = r["ceiling rise dB"]
        parts = rise.replace("(of", "").replace(")", "").split()
        t.check(len(parts) == 2, f"{r['components']}: rise column {rise!r}")
        if len(parts) == 2:
            got, expected = float(parts[0]), float(parts[1])
            t.check(abs(expected - 3.0) < 0.05, f"{r['components']}: 3 dB expected from 8 to 16 chunks: {rise}")
            t.check(1.0 < got < 5.0, f"{r['components']}: the ceiling rose {got} dB from 8 to 16 chunks")
            print(f"progressive {r['components']} reference: ceiling rose {got:+.1f} dB from 8 to 16 chunks")

    # Damaged checkpoints are bad input too: a .json that is not JSON starts that reference
    # again, one whose time is not a number and whose ceilings are not a list keeps its chunks
    # (time 0, no history); neither crashes.
    if set(metas) == {"full", "surface"}:
        with open(metas["surface"], "w", encoding="utf-8") as f:
            f.write("{not json")
        meta = json.load(open(metas["full"], encoding="utf-8"))
        meta["ms"] = "soon"
        meta["ceilings"] = "rising"
        with open(metas["full"], "w", encoding="utf-8") as f:
            json.dump(meta, f)
        code, _, err = run(*TINY, "--ref-ceiling", "120", "--ref-max-spp", "16", "--cache", capped,
                           "--out", os.path.join(d, "p7"))
        t.equal(code, 0, f"damaged checkpoints ({err.strip()[-300:]})")
        got = {r["components"]: r["meta"]["chunks"] for r in progressive_refs(t, os.path.join(d, "p7"))}
        t.equal(got, {"full": 4, "surface": 4}, "full resumed from 3 chunks, surface started again")
        t.check("surface): chunk 1," in err and "full): chunk 4," in err, f"which resumed: {err[-400:]}")

    for bad, named in ((["--ref-budget", "5"], "--ref-budget"), (["--ref-ceiling", "0"], "--ref-ceiling"),
                       (["--ref-ceiling", "loud"], "--ref-ceiling"), (["--ref-max-spp", "8"], "--ref-max-spp"),
                       (["--ref-ceiling", "30", "--ref-max-spp", "0"], "--ref-max-spp")):
        code, _, err = run(*TINY, *bad, "--cache", cache, "--out", os.path.join(d, "bad"))
        t.equal(code, 2, f"exit status of bench {' '.join(bad)}")
        t.check(named in err, f"bench {' '.join(bad)}: message names {named!r}: {err.strip()[-200:]}")


def main():
    t = Checks()
    if not BIN:
        print("NSCATTER_BIN is not set (run through ctest)", file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory(prefix="nscatter-bench-") as d:
        for test in (test_bad_arguments, test_report_and_reference_cache, test_seeds,
                     test_progressive_references):
            t.run(test, d)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
