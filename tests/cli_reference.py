"""The reference workflow from the command line: `nscatter render` with method "pt" and
`nscatter compare` against an image with a closed-form answer. A white furnace (a
non-absorbing medium in a uniform environment, index matched and behind ior 1.5) rendered
by pt must match the bare environment rendered by the camera pass to float precision;
max_scatter outside pt is refused with its pointer; --timings names the pt stages."""
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import Checks, environment_scene, sanitizer_env  # noqa: E402

BIN = os.environ.get("NSCATTER_BIN", "")
TIMEOUT_S = 300
RADIANCE = [1.0, 0.5, 0.25]


def run(*args):
    p = subprocess.run([BIN, *args], capture_output=True, timeout=TIMEOUT_S, env=sanitizer_env())
    return p.returncode, p.stdout.decode(errors="replace"), p.stderr.decode(errors="replace")


def write(path, scene):
    with open(path, "w") as f:
        json.dump(scene, f)


def furnace_scene(ior, sigma_s):
    """A medium sphere filling the view (narrow fov) in the environment of RADIANCE."""
    scene = environment_scene(RADIANCE, width=16, height=16)
    scene["camera"]["fov"] = 18
    scene["materials"] = {"fog": {"type": "medium", "sigma_s": sigma_s, "sigma_a": 0, "g": 0.2,
                                  "ior": ior}}
    scene["objects"] = [{"shape": "sphere", "center": [0, 0, 0], "radius": 1, "material": "fog"}]
    scene["render"] = {"method": "pt", "spp": 8, "seed": 5}
    return scene


def render_reference(t, d):
    """The bare environment through the camera pass: every pixel is RADIANCE exactly."""
    ref = os.path.join(d, "env.exr")
    scene = environment_scene(RADIANCE, width=16, height=16)
    scene["camera"]["fov"] = 18
    write(os.path.join(d, "env.json"), scene)
    code, _, err = run("render", os.path.join(d, "env.json"), "-o", ref)
    t.equal(code, 0, f"camera-pass render ({err})")
    return ref


def test_furnace_matches_environment(t, d):
    ref = render_reference(t, d)
    for ior in (1.0, 1.5):
        path = os.path.join(d, f"furnace_{ior}.json")
        out = os.path.join(d, f"furnace_{ior}.exr")
        write(path, furnace_scene(ior, 3))
        code, stdout, err = run("render", path, "-o", out, "--timings")
        t.equal(code, 0, f"pt render ior {ior} ({err})")
        stages = json.loads(stdout)["stages"]
        t.check("pt_pass" in stages and "pt_pipeline" in stages, f"pt stages in {stages}")
        code, stdout, err = run("compare", out, ref, "--diff", os.path.join(d, "diff.png"))
        t.equal(code, 0, f"compare ({err})")
        m = json.loads(stdout)
        t.check(m["rmse"]["all"] < 1e-4, f"ior {ior}: RMSE {m['rmse']['all']} against the "
                                         "environment")
        t.equal(m["pixels"], 256, "pixels compared")
        t.check(m["peak"] == 1.0, f"peak {m['peak']} = the reference's largest value")


def test_orders_refused_outside_pt(t, d):
    scene = environment_scene(RADIANCE)
    scene["render"]["max_scatter"] = 2
    path = os.path.join(d, "bad.json")
    write(path, scene)
    code, _, err = run("render", path, "-o", os.path.join(d, "bad.png"))
    t.equal(code, 2, "max_scatter with method nn")
    t.check("/render/max_scatter" in err and "\"pt\" only" in err, f"message: {err}")


def test_single_order_is_darker(t, d):
    """Only once-scattered light: well below the environment, and above zero."""
    ref = render_reference(t, d)
    scene = furnace_scene(1.0, 3)
    scene["render"]["components"] = ["single"]
    path = os.path.join(d, "single.json")
    out = os.path.join(d, "single.exr")
    write(path, scene)
    code, _, err = run("render", path, "-o", out)
    t.equal(code, 0, f"single-order render ({err})")
    code, stdout, err = run("compare", out, ref)
    m = json.loads(stdout)
    # Mean relative error = 1 - (mean of A/B); optical radius 3: most light scatters more.
    t.check(0.3 < m["relerr"]["all"] < 0.99, f"relative error {m['relerr']['all']}")


def main():
    t = Checks()
    if not BIN:
        print("NSCATTER_BIN is not set (run through ctest)", file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory(prefix="nscatter-ref-") as d:
        for test in (test_furnace_matches_environment, test_orders_refused_outside_pt,
                     test_single_order_is_darker):
            t.run(test, d)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
