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
NUMERIC_COLUMNS = ["render.vrls", "VRLs", "spp", "time ms", "first ms", "PSNR dB", "RMSE", "rel. err",
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
    code, _, err = run(*TINY[:4], "--width", "8", "--height", "8", *TINY[8:], "--cache", cache,
                       "--out", os.path.join(d, "out4"))
    t.equal(code, 0, f"8x8 run ({err.strip()[-300:]})")
    t.check("references: 2 rendered" in err, "another size renders its own references")


def main():
    t = Checks()
    if not BIN:
        print("NSCATTER_BIN is not set (run through ctest)", file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory(prefix="nscatter-bench-") as d:
        for test in (test_bad_arguments, test_report_and_reference_cache):
            t.run(test, d)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
