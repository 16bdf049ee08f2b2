"""Helpers for the HTTP tests (tests/http_*.py): start the real `nscatter serve` on a free
loopback port, talk to it over TCP, decode what it answers, count checks.

Python 3 standard library only. Every wait is bounded; the server is always stopped.
"""
import http.client
import json
import os
import select
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
import zlib

STARTUP_TIMEOUT_S = 240  # context creation warms every pipeline; lavapipe compiles slowly
REQUEST_TIMEOUT_S = 120
# Under ASan+UBSan (NS_SANITIZE) LeakSanitizer runs at exit. It is told not to change the
# exit status (exitcode=0), so the real status stays visible, and its report is read
# instead: a leak through nscatter's own code fails the test (see own_leaks); leaks only
# inside the Vulkan driver do not. LSAN_EXIT_CODE stands for "own leaks found".
LSAN_EXIT_CODE = 23


class Checks:
    """cmark-style counting: a failed check prints what and where, the run goes on."""

    def __init__(self):
        self.passed = 0
        self.failed = 0
        self.current = ""

    def check(self, cond, what):
        if cond:
            self.passed += 1
        else:
            self.failed += 1
            print(f"FAIL {self.current}: {what}", file=sys.stderr, flush=True)
        return bool(cond)

    def equal(self, got, want, what):
        return self.check(got == want, f"{what}: got {got!r}, expected {want!r}")

    def run(self, fn, *args):
        self.current = fn.__name__
        before = self.failed
        start = time.monotonic()
        try:
            fn(self, *args)
        except Exception as e:  # a crash in one test is a failure, not the end of the run
            self.failed += 1
            print(f"FAIL {fn.__name__}: exception {type(e).__name__}: {e}", file=sys.stderr,
                  flush=True)
        print(f"{'ok  ' if self.failed == before else 'FAIL'} {fn.__name__} "
              f"({time.monotonic() - start:.1f} s)", file=sys.stderr, flush=True)

    def report(self):
        print(f"{self.passed} passed, {self.failed} failed", flush=True)
        if self.passed + self.failed == 0:
            # A program that checked nothing proves nothing (tests/harness.h does the same).
            print("FAIL: no check ran", file=sys.stderr, flush=True)
            return 1
        return 1 if self.failed else 0


def own_leaks(report, binary):
    """LeakSanitizer reports in `report` whose stack passes through nscatter's own code.
    Leaks only inside the Vulkan driver (lavapipe/LLVM, unloaded before the report, so its
    frames show as '<unknown module>') are not ours to fix and are not counted."""
    source = os.path.realpath(os.environ.get("NSCATTER_SOURCE_DIR", "/nonexistent"))
    binary = os.path.realpath(binary)
    own = []
    for block in report.split("leak of ")[1:]:
        stack = block.split("\n\n")[0]
        if binary in stack or source + "/" in stack:
            own.append(stack)
    return own


def sanitizer_env():
    """The environment for a child nscatter: LeakSanitizer reports but keeps the status."""
    env = dict(os.environ)
    env["LSAN_OPTIONS"] = ":".join(filter(None, [env.get("LSAN_OPTIONS"), "exitcode=0"]))
    return env


class Server:
    """`nscatter serve --port 0` on 127.0.0.1; the real port is read from its first line.

    Without idle work unless asked (idle_work=True): between a test's requests the worker
    would otherwise make albedo nodes, which takes the CPU from timed jobs and writes node
    files to the shared test cache folder, where they change what render.tables "auto"
    chooses in later tests. http_scatter tests the idle work itself. env: added to the
    server's environment."""

    def __init__(self, *extra_args, idle_work=False, env=None):
        binary = os.environ.get("NSCATTER_BIN")
        if not binary:
            raise RuntimeError("NSCATTER_BIN is not set (run through ctest)")
        self.log = tempfile.NamedTemporaryFile(prefix="nscatter-serve-", suffix=".log",
                                               delete=False)
        self.binary = os.path.realpath(binary)
        server_env = sanitizer_env()
        server_env.update(env or {})
        idle = [] if idle_work else ["--idle-work", "off"]
        self.proc = subprocess.Popen(
            [binary, "serve", "--host", "127.0.0.1", "--port", "0", *idle, *extra_args],
            stdout=subprocess.PIPE, stderr=self.log, stdin=subprocess.DEVNULL, env=server_env)
        self.port = self._read_port()

    def _read_port(self):
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        line = b""
        fd = self.proc.stdout.fileno()
        while not line.endswith(b"\n"):
            left = deadline - time.monotonic()
            if left <= 0 or self.proc.poll() is not None:
                self.stop()
                raise RuntimeError(f"server did not start; log:\n{self.log_text()}")
            ready, _, _ = select.select([fd], [], [], min(left, 1.0))
            if ready:
                chunk = os.read(fd, 1)
                if not chunk:
                    continue
                line += chunk
        text = line.decode().strip()
        prefix = "listening on http://127.0.0.1:"
        if not text.startswith(prefix):
            self.stop()
            raise RuntimeError(f"unexpected first line {text!r}")
        return int(text[len(prefix):])

    def log_text(self):
        with open(self.log.name, "r", errors="replace") as f:
            return f.read()

    def own_leaks(self):
        return own_leaks(self.log_text(), self.binary)

    def exited_cleanly(self, code):
        """Exit status 0 and no leak report through nscatter's own code."""
        return code == 0 and not self.own_leaks()

    def alive(self):
        return self.proc.poll() is None

    def connection(self, timeout=REQUEST_TIMEOUT_S):
        return http.client.HTTPConnection("127.0.0.1", self.port, timeout=timeout)

    def request(self, method, path, body=None, headers=None, timeout=REQUEST_TIMEOUT_S):
        """One request on a fresh connection; returns (status, headers dict lower-case, body)."""
        conn = self.connection(timeout)
        try:
            conn.request(method, path, body=body, headers=headers or {})
            resp = conn.getresponse()
            data = resp.read()
            return resp.status, {k.lower(): v for k, v in resp.getheaders()}, data
        finally:
            conn.close()

    def render(self, scene, accept=None, path="/v1/renders", timeout=REQUEST_TIMEOUT_S):
        body = scene if isinstance(scene, (bytes, bytearray)) else json.dumps(scene).encode()
        headers = {"Content-Type": "application/json"}
        if accept is not None:
            headers["Accept"] = accept
        return self.request("POST", path, body, headers, timeout)

    def raw(self, data, read_timeout=30, close_write=False):
        """Sends raw bytes on a new socket; returns whatever comes back before the server
        closes or read_timeout passes."""
        with socket.create_connection(("127.0.0.1", self.port), timeout=read_timeout) as s:
            s.sendall(data)
            if close_write:
                s.shutdown(socket.SHUT_WR)
            out = b""
            deadline = time.monotonic() + read_timeout
            while time.monotonic() < deadline:
                try:
                    chunk = s.recv(65536)
                except socket.timeout:
                    break
                except ConnectionResetError:
                    break
                if not chunk:
                    break
                out += chunk
                if response_complete(out):
                    break
            return out

    def stop(self, sig=signal.SIGTERM, timeout=60):
        """Signals the server and waits for it; returns its exit status (None if killed)."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
                return None
        if self.proc.stdout:
            self.proc.stdout.close()
        return self.proc.returncode

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
        try:
            os.unlink(self.log.name)
        except OSError:
            pass


def response_complete(data):
    """True once `data` holds a whole HTTP response with a Content-Length body."""
    head, sep, body = data.partition(b"\r\n\r\n")
    if not sep:
        return False
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            return len(body) >= int(value.strip())
    return False


def parse_raw_response(data):
    """(status, headers dict lower-case, body) of a raw HTTP/1.1 response."""
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1]) if lines and len(lines[0].split()) > 1 else 0
    headers = {}
    for line in lines[1:]:
        name, _, value = line.partition(":")
        headers[name.strip().lower()] = value.strip()
    return status, headers, body


# ---------------------------------------------------------------------------------------
# Scenes
# ---------------------------------------------------------------------------------------
def small_scene(width=48, height=32, spp=1):
    """A sphere of wax on a floor; the surface component only (the scattering components
    are reported as not available until they land)."""
    return {
        "camera": {"position": [0, 2, 6], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 30,
                   "width": width, "height": height},
        "materials": {
            "floor": {"type": "diffuse", "reflectance": [0.5, 0.5, 0.5]},
            "wax": {"type": "medium", "albedo": [0.98, 0.962, 0.75], "mfp": [0.65, 0.63, 0.59],
                    "g": 0.8, "ior": 1.45}},
        "objects": [
            {"shape": "sphere", "center": [0, 0, 0], "radius": 1, "material": "wax"},
            {"shape": "plane", "point": [0, -1, 0], "normal": [0, 1, 0], "material": "floor"}],
        "lights": [
            {"type": "directional", "direction": [0, -1, -1], "irradiance": [2, 2, 2]},
            {"type": "environment", "radiance": [0.2, 0.2, 0.2]}],
        "render": {"method": "nn", "components": ["surface"], "spp": spp, "seed": 1,
                   "max_depth": 8},
    }


def environment_scene(radiance, exposure=0.0, width=16, height=8):
    """Nothing but a uniform environment: every pixel sees exactly `radiance`."""
    return {
        "camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40,
                   "width": width, "height": height},
        "materials": {"grey": {"type": "diffuse", "reflectance": [0.5, 0.5, 0.5]}},
        "objects": [],
        "lights": [{"type": "environment", "radiance": radiance}],
        "render": {"method": "nn", "components": ["surface"], "spp": 1, "seed": 1,
                   "max_depth": 4, "exposure": exposure},
    }


# ---------------------------------------------------------------------------------------
# Image decoding
# ---------------------------------------------------------------------------------------
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
EXR_MAGIC = b"\x76\x2f\x31\x01"


def png_chunks(data):
    """[(type, payload)] with every CRC verified; raises ValueError on any defect."""
    if not data.startswith(PNG_SIGNATURE):
        raise ValueError("no PNG signature")
    at, chunks = 8, []
    while at + 12 <= len(data):
        length, = struct.unpack(">I", data[at:at + 4])
        kind = data[at + 4:at + 8]
        payload = data[at + 8:at + 8 + length]
        crc, = struct.unpack(">I", data[at + 8 + length:at + 12 + length])
        if zlib.crc32(kind + payload) & 0xffffffff != crc:
            raise ValueError(f"bad CRC in {kind!r}")
        chunks.append((kind.decode("latin-1"), payload))
        at += 12 + length
        if kind == b"IEND":
            break
    if not chunks or chunks[-1][0] != "IEND" or at != len(data):
        raise ValueError("PNG does not end with IEND")
    return chunks


def png_texts(data):
    out = {}
    for kind, payload in png_chunks(data):
        if kind == "tEXt":
            key, _, value = payload.partition(b"\0")
            out[key.decode("latin-1")] = value.decode("latin-1")
    return out


def png_decode_rgb8(data):
    """(width, height, rows of bytes) of an 8-bit RGB, non-interlaced PNG."""
    chunks = png_chunks(data)
    ihdr = chunks[0][1]
    width, height, depth, color, _, _, interlace = struct.unpack(">IIBBBBB", ihdr)
    if (depth, color, interlace) != (8, 2, 0):
        raise ValueError(f"not 8-bit RGB: depth {depth} color {color} interlace {interlace}")
    raw = zlib.decompress(b"".join(p for k, p in chunks if k == "IDAT"))
    stride, bpp = 3 * width, 3
    if len(raw) != height * (stride + 1):
        raise ValueError("IDAT size does not match IHDR")
    rows, prev = [], bytearray(stride)
    for y in range(height):
        f = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for x in range(stride):
            a = line[x - bpp] if x >= bpp else 0
            b = prev[x]
            c = prev[x - bpp] if x >= bpp else 0
            if f == 1:
                line[x] = (line[x] + a) & 255
            elif f == 2:
                line[x] = (line[x] + b) & 255
            elif f == 3:
                line[x] = (line[x] + (a + b) // 2) & 255
            elif f == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                line[x] = (line[x] + pred) & 255
            elif f != 0:
                raise ValueError(f"bad filter {f}")
        rows.append(bytes(line))
        prev = line
    return width, height, rows


def srgb8(linear):
    """The sRGB transfer, closed form, to 8 bits."""
    v = max(0.0, min(1.0, linear))
    s = 12.92 * v if v <= 0.0031308 else 1.055 * v ** (1 / 2.4) - 0.055
    return int(s * 255 + 0.5)


def exr_header(data):
    """{attribute name: (type, raw value)} of a single-part scanline EXR."""
    if not data.startswith(EXR_MAGIC):
        raise ValueError("no EXR magic")
    at, attrs = 8, {}
    while True:
        end = data.index(b"\0", at)
        name = data[at:end].decode("latin-1")
        if not name:
            return attrs
        tend = data.index(b"\0", end + 1)
        kind = data[end + 1:tend].decode("latin-1")
        size, = struct.unpack("<i", data[tend + 1:tend + 5])
        attrs[name] = (kind, data[tend + 5:tend + 5 + size])
        at = tend + 5 + size


def exr_channels(data):
    """{channel name: pixel type} (0 uint, 1 half, 2 float) from the chlist attribute."""
    kind, raw = exr_header(data)["channels"]
    out, at = {}, 0
    while raw[at:at + 1] != b"\0":
        end = raw.index(b"\0", at)
        name = raw[at:end].decode("latin-1")
        ptype, = struct.unpack("<i", raw[end + 1:end + 5])
        out[name] = ptype
        at = end + 1 + 16
    return out


def server_timing(value):
    """{metric: dur ms} from a Server-Timing header."""
    out = {}
    for metric in value.split(","):
        parts = [p.strip() for p in metric.split(";")]
        name = parts[0]
        for p in parts[1:]:
            if p.startswith("dur="):
                out[name] = float(p[4:])
    return out


def problem(body):
    return json.loads(body.decode())
