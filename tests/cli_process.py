"""The nscatter process itself (cli/huge_pages.c): it starts itself again, once, with glibc's
tunable glibc.malloc.hugetlb=1, so that malloc asks for transparent huge pages for the large
buffers a render touches once (docs/rendering.md, *Huge pages*).

- By default `nscatter info --json` says malloc asks for them (malloc_huge_pages) and names
  the kernel's mode; a running `nscatter serve` has the tunable in its environment and is
  still the process its parent started (execv keeps the pid: a supervisor's pid is the
  server's).
- A user's own GLIBC_TUNABLES is kept as it is (and then malloc is not told),
  NSCATTER_HUGE_PAGES=0 turns the restart off (1 is the default, anything else is refused
  with exit status 2, naming the variable), the restarted process never restarts again,
  and a run through the dynamic loader named as the program goes on without.
The images do not depend on it: docs/bench.md (*Huge pages*) compared the bench's renders with
and without, bit for bit. Not here: the CLI tests run in the sanitizer build, whose allocator
ignores glibc's tunables, so such a comparison could not fail there."""
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import Checks, Server, sanitizer_env  # noqa: E402

BIN = os.environ.get("NSCATTER_BIN", "")
TIMEOUT_S = 300
TUNABLE = "glibc.malloc.hugetlb=1"


def clean_env(**extra):
    """The test's environment without GLIBC_TUNABLES or NSCATTER_HUGE_PAGES, plus extra."""
    env = sanitizer_env()
    env.pop("GLIBC_TUNABLES", None)
    env.pop("NSCATTER_HUGE_PAGES", None)
    env.update(extra)
    return env


def info(t, env):
    p = subprocess.run([BIN, "info", "--json"], capture_output=True, timeout=TIMEOUT_S, env=env)
    t.equal(p.returncode, 0, f"info exit status ({p.stderr.decode(errors='replace')[:300]})")
    return json.loads(p.stdout) if p.returncode == 0 else {}


def test_info_says_so(t, d):
    got = info(t, clean_env())
    t.equal(got.get("malloc_huge_pages"), True, "by default malloc asks for huge pages")
    t.check(got.get("kernel_huge_pages") in ("always", "madvise", "never", "unknown"),
            f"the kernel's mode is named: {got.get('kernel_huge_pages')!r}")
    got = info(t, clean_env(GLIBC_TUNABLES="glibc.malloc.check=0"))
    t.equal(got.get("malloc_huge_pages"), False, "a user's own GLIBC_TUNABLES is left alone")
    got = info(t, clean_env(NSCATTER_HUGE_PAGES="0"))
    t.equal(got.get("malloc_huge_pages"), False, "NSCATTER_HUGE_PAGES=0 turns it off")
    got = info(t, clean_env(NSCATTER_HUGE_PAGES="1"))
    t.equal(got.get("malloc_huge_pages"), True, "NSCATTER_HUGE_PAGES=1 is the default")
    # Any other value is refused, naming the variable, before anything else is done.
    p = subprocess.run([BIN, "info", "--json"], capture_output=True, timeout=TIMEOUT_S,
                       env=clean_env(NSCATTER_HUGE_PAGES="off"))
    t.equal(p.returncode, 2, "NSCATTER_HUGE_PAGES=off: exit status 2")
    t.check(b"NSCATTER_HUGE_PAGES: 'off'" in p.stderr and not p.stdout,
            f"the error names the variable and its value: {p.stderr[:200]!r}")
    got = info(t, clean_env(GLIBC_TUNABLES="glibc.malloc.check=0:" + TUNABLE))
    t.equal(got.get("malloc_huge_pages"), True, "the tunable among others is seen")
    # The restarted process never restarts again, even where glibc dropped the tunable.
    got = info(t, clean_env(NSCATTER_HUGE_PAGES_RESTARTED="1"))
    t.equal(got.get("malloc_huge_pages"), False, "no second restart")
    # Through the dynamic loader named as the program /proc/self/exe is the loader: no restart.
    loader = "/lib64/ld-linux-x86-64.so.2"
    if os.path.exists(loader):
        p = subprocess.run([loader, BIN, "info", "--json"], capture_output=True,
                           timeout=TIMEOUT_S, env=clean_env())
        t.equal(p.returncode, 0, "info through the loader")
        t.equal(json.loads(p.stdout or b"{}").get("malloc_huge_pages"), False,
                "through the loader it goes on as it is")


def environ_of(pid):
    with open(f"/proc/{pid}/environ", "rb") as f:
        return dict(item.split(b"=", 1) for item in f.read().split(b"\0") if b"=" in item)


def test_server_runs_restarted(t, d):
    saved = {k: os.environ.pop(k) for k in ("GLIBC_TUNABLES", "NSCATTER_HUGE_PAGES")
             if k in os.environ}
    try:
        with Server() as srv:
            env = environ_of(srv.proc.pid)
            t.equal(env.get(b"GLIBC_TUNABLES"), TUNABLE.encode(),
                    "the server's process (the pid its parent started) has the tunable")
            t.equal(srv.request("GET", "/readyz")[0], 200, "and serves")
        with Server(env={"GLIBC_TUNABLES": "glibc.malloc.check=0"}) as srv:
            t.equal(environ_of(srv.proc.pid).get(b"GLIBC_TUNABLES"), b"glibc.malloc.check=0",
                    "a user's GLIBC_TUNABLES reaches the server unchanged")
    finally:
        os.environ.update(saved)


def main():
    if not BIN:
        print("NSCATTER_BIN is not set (run through ctest)", file=sys.stderr)
        return 1
    t = Checks()
    with tempfile.TemporaryDirectory() as d:
        for test in (test_info_says_so, test_server_runs_restarted):
            t.run(test, d)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
