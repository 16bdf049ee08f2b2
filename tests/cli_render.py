"""`nscatter render` from the command line: images with closed-form pixels, --timings JSON,
exit statuses and messages for every kind of bad input, and atomic writes (a failed render
leaves the earlier file untouched and no temporary file behind)."""
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import (EXR_MAGIC, LSAN_EXIT_CODE, Checks, environment_scene,  # noqa: E402
                         exr_channels, exr_header, own_leaks, png_decode_rgb8, png_texts,
                         sanitizer_env, small_scene, srgb8)

BIN = os.environ.get("NSCATTER_BIN", "")
TIMEOUT_S = 300


def run(*args):
    """(exit status, stdout, stderr). Under the sanitizer build a leak report is cut from
    stderr; one whose stack passes through nscatter's own code turns the status into
    LSAN_EXIT_CODE so that the checks fail; driver-only leaks change nothing."""
    p = subprocess.run([BIN, "render", *args], capture_output=True, timeout=TIMEOUT_S,
                       env=sanitizer_env())
    code, stderr = p.returncode, p.stderr.decode(errors="replace")
    marker = "=================================================================\n=="
    if marker in stderr and "LeakSanitizer" in stderr:
        report = stderr[stderr.index(marker):]
        stderr = stderr[:stderr.index(marker)]
        if own_leaks(report, BIN):
            print(report[:3000], file=sys.stderr)
            code = LSAN_EXIT_CODE
    return code, p.stdout.decode(errors="replace"), stderr


def write(path, scene):
    with open(path, "wb") as f:
        f.write(scene if isinstance(scene, bytes) else json.dumps(scene, indent=1).encode())


def read(path):
    with open(path, "rb") as f:
        return f.read()


def uniform_pixel(t, data, want, what):
    width, height, rows = png_decode_rgb8(data)
    bad = sum(1 for row in rows for x in range(width) if row[3 * x:3 * x + 3] != want)
    t.equal(bad, 0, f"{what}: every pixel {list(want)}")


def test_png_pixels_and_exposure(t, d):
    scene = os.path.join(d, "env.json")
    radiance = [0.25, 0.05, 0.5]
    write(scene, environment_scene(radiance, exposure=0.0))
    out = os.path.join(d, "env.png")
    code, stdout, stderr = run(scene, "-o", out)
    t.equal(code, 0, f"render exit status ({stderr})")
    t.equal(stdout, "", "nothing on stdout without --timings")
    uniform_pixel(t, read(out), bytes(srgb8(c) for c in radiance), "exposure 0")
    texts = png_texts(read(out))
    t.check("nscatter:render" in texts and "nscatter:timings_ms" in texts, f"tEXt: {list(texts)}")
    code, _, stderr = run(scene, "-o", out, "--exposure", "1.5")
    t.equal(code, 0, f"--exposure ({stderr})")
    uniform_pixel(t, read(out), bytes(srgb8(c * 2 ** 1.5) for c in radiance), "exposure 1.5")
    settings = json.loads(png_texts(read(out))["nscatter:render"])
    t.equal(settings.get("exposure"), 1.5, "exposure recorded in the metadata")
    # The environment scene renders with nn, whose boundary model defaults to walks.
    t.equal(settings.get("boundary"), "walks", "boundary model recorded in the metadata")


def test_exr_float_and_half(t, d):
    scene = os.path.join(d, "small.json")
    write(scene, small_scene(20, 10))
    for flag, ptype in ((None, 2), ("--half", 1)):
        out = os.path.join(d, "small.exr")
        code, _, stderr = run(scene, "-o", out, *([flag] if flag else []))
        t.equal(code, 0, f"EXR {flag} ({stderr})")
        data = read(out)
        t.equal(data[:4], EXR_MAGIC, "EXR magic")
        t.check(all(v == ptype for v in exr_channels(data).values()), f"pixel type {ptype}")
        t.check("nscatter:timings_ms" in exr_header(data), "timings attribute")


def test_timings_json(t, d):
    scene = os.path.join(d, "small.json")
    write(scene, small_scene(24, 16))
    out = os.path.join(d, "t.png")
    code, stdout, stderr = run(scene, "-o", out, "--timings")
    t.equal(code, 0, f"--timings ({stderr})")
    lines = stdout.strip().splitlines()
    t.equal(len(lines), 1, "one line on stdout")
    doc = json.loads(lines[0]) if lines else {}
    t.check(doc.get("device"), "device named")
    stages = doc.get("stages", {})
    for name in ("parse", "ray_pass", "encode", "write"):
        t.check(name in stages, f"stage {name}: {list(stages)}")
    t.check(all(isinstance(v, (int, float)) and v >= 0 for v in stages.values()), "ms >= 0")
    t.check(abs(doc.get("total_ms", -1) - sum(stages.values())) < 0.01, "total is the sum")
    t.equal((doc.get("width"), doc.get("height")), (24, 16), "size")
    t.equal(doc.get("bytes"), os.path.getsize(out), "bytes written")


def test_bad_input_exit_2(t, d):
    good = os.path.join(d, "good.json")
    write(good, small_scene(8, 8))
    bad_scene = small_scene(8, 8)
    bad_scene["materials"]["wax"]["g"] = 2
    invalid = os.path.join(d, "invalid.json")
    write(invalid, bad_scene)
    code, _, stderr = run(invalid, "-o", os.path.join(d, "x.png"))
    t.equal(code, 2, "invalid scene exit status")
    t.check(f"{invalid}: /materials/wax/g:" in stderr, f"issue names file and pointer: {stderr}")
    malformed = os.path.join(d, "malformed.json")
    write(malformed, b'{\n "camera": {\n  "fov": 30,,\n}}')
    code, _, stderr = run(malformed, "-o", os.path.join(d, "x.png"))
    t.equal(code, 2, "malformed JSON exit status")
    t.check(f"{malformed}:3:" in stderr, f"file:line:column: {stderr}")
    cases = [
        ([good, "-o", os.path.join(d, "x.jpg")], "-o"),
        ([good, "-o", os.path.join(d, "x.png"), "--half"], "--half"),
        ([good, "-o", os.path.join(d, "x.png"), "--exposure", "bright"], "--exposure"),
        ([good, "-o", os.path.join(d, "x.png"), "--exposure", "nan"], "--exposure"),
        ([good, "-o", os.path.join(d, "x.png"), "--frobnicate"], "--frobnicate"),
        ([good], "-o"),
        (["-o", os.path.join(d, "x.png")], "SCENE"),
        ([os.path.join(d, "missing.json"), "-o", os.path.join(d, "x.png")], "missing.json"),
    ]
    for args, named in cases:
        code, _, stderr = run(*args)
        t.equal(code, 2, f"exit status for {args[1:]}")
        t.check(named in stderr, f"message names {named}: {stderr[:200]}")
    t.check(not os.path.exists(os.path.join(d, "x.jpg")) and
            not os.path.exists(os.path.join(d, "x.png")), "nothing written on bad input")


def test_failed_render_keeps_old_file(t, d):
    scene = os.path.join(d, "small.json")
    write(scene, small_scene(8, 8))
    out = os.path.join(d, "keep.png")
    with open(out, "wb") as f:
        f.write(b"earlier image")
    code, _, stderr = run(scene, "-o", out, "--device", "no-such-device-nscatter-test")
    t.equal(code, 1, f"render failure exit status ({stderr})")
    t.check("no_device" in stderr or "not_available" in stderr, f"names the status: {stderr}")
    t.equal(read(out), b"earlier image", "earlier file untouched")
    code, _, stderr = run(scene, "-o", os.path.join(d, "no-such-dir", "x.png"))
    t.equal(code, 1, "unwritable output exit status")
    t.check("no-such-dir" in stderr, f"names the path: {stderr}")
    leftovers = [n for n in os.listdir(d) if ".tmp." in n]
    t.equal(leftovers, [], "no temporary files left")


def main():
    t = Checks()
    if not BIN:
        print("NSCATTER_BIN is not set (run through ctest)", file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory(prefix="nscatter-cli-") as d:
        for test in (test_png_pixels_and_exposure, test_exr_float_and_half, test_timings_json,
                     test_bad_input_exit_2, test_failed_render_keeps_old_file):
            t.run(test, d)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
