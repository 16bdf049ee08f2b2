#!/usr/bin/env python3
"""sweep.py — render one scene many times with some values changed, through nscatter's HTTP
service, and keep every image, a labelled contact sheet and a manifest.

    python3 examples/sweep.py --server http://127.0.0.1:8080 --scene scenes/default.json \\
        --grid '/materials/wax/g=[0.2,0.5,0.8]' \\
        --grid '/materials/wax/albedo=[[0.9,0.9,0.9],[0.99,0.99,0.99]]' \\
        --out sweep-out/

renders the 3 x 2 = 6 combinations (the first --grid varies slowest). Instead of --grid, give
each variant yourself, as a JSON object of JSON pointers (RFC 6901) and their values:

    python3 examples/sweep.py --scene scenes/default.json \\
        --variant '{"/materials/wax/g": 0.5}' \\
        --variant '{"/materials/wax/g": 0.8, "/materials/wax/ior": 1.3}' --out sweep-out/

What it does (the HTTP API is in docs/http.md):
  1. POST /v1/sweeps with the scene and the variants; a refused sweep (422) prints every
     problem with the pointer it names, and the script exits with status 2;
  2. follows GET /v1/sweeps/{id}/events (Server-Sent Events), printing one line per variant
     as it finishes, and reconnects with Last-Event-ID if the stream drops;
  3. saves sheet.png, manifest.json and images/NNN.png (one per finished variant) into --out.
Ctrl-C cancels the sweep on the server (DELETE /v1/sweeps/{id}) before exiting.

Python 3 standard library only.
"""
import argparse
import http.client
import json
import os
import sys
import time
import urllib.error
import urllib.parse
import urllib.request

TIMEOUT_S = 60           # one request; the event stream sends a keep-alive well before this
RECONNECT_ATTEMPTS = 10  # reconnections in a row without an event before giving up
FINAL_EVENTS = ("done", "failed", "cancelled")


# ---------------------------------------------------------------------------------------
# HTTP
# ---------------------------------------------------------------------------------------
class HTTPFailure(Exception):
    """An answer other than 2xx, with its problem+json body when there is one."""

    def __init__(self, status, body):
        self.status = status
        try:
            self.problem = json.loads(body.decode("utf-8"))
        except ValueError:
            self.problem = {"detail": body.decode("utf-8", "replace")[:500]}
        super().__init__(f"HTTP {status}: {self.problem.get('detail', '')}")


def request(method, url, body=None, headers=None, timeout=TIMEOUT_S):
    """(status, headers, body) of one request; raises HTTPFailure on a 4xx/5xx answer."""
    req = urllib.request.Request(url, data=body, method=method, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as resp:
            return resp.status, resp.headers, resp.read()
    except urllib.error.HTTPError as e:
        raise HTTPFailure(e.code, e.read()) from None


def print_problem(failure):
    p = failure.problem
    print(f"refused: HTTP {failure.status} {p.get('code', '')}: {p.get('detail', '')}",
          file=sys.stderr)
    for e in p.get("errors") or []:
        print(f"  {e.get('pointer', '')}: {e.get('detail', '')}", file=sys.stderr)


# ---------------------------------------------------------------------------------------
# Server-Sent Events (https://html.spec.whatwg.org/multipage/server-sent-events.html)
# ---------------------------------------------------------------------------------------
class Event:
    def __init__(self, name, data, event_id):
        self.name, self.data, self.id = name, data, event_id


class SSEParser:
    """Feed it lines; it returns an Event at each blank line that ends one. Comments (lines
    starting with ':') are skipped; several data lines are joined with newlines; the last
    id seen is kept for reconnecting."""

    def __init__(self):
        self.last_id = None
        self.retry_ms = None
        self._reset()

    def _reset(self):
        self._name, self._data = "", []

    def feed(self, line):
        line = line.rstrip("\r\n")
        if line == "":
            if not self._data:  # nothing to dispatch (only comments or ids)
                self._reset()
                return None
            event = Event(self._name or "message", "\n".join(self._data), self.last_id)
            self._reset()
            return event
        if line.startswith(":"):
            return None
        field, colon, value = line.partition(":")
        if colon and value.startswith(" "):
            value = value[1:]
        if field == "event":
            self._name = value
        elif field == "data":
            self._data.append(value)
        elif field == "id" and "\0" not in value:
            self.last_id = value
        elif field == "retry" and value.isdigit():
            self.retry_ms = int(value)
        return None


def events(url):
    """Yields the events of the stream at url until a final one, reconnecting with
    Last-Event-ID when the connection drops or stalls."""
    parser, failures = SSEParser(), 0
    while True:
        headers = {"Accept": "text/event-stream"}
        if parser.last_id is not None:
            headers["Last-Event-ID"] = parser.last_id
        try:
            req = urllib.request.Request(url, headers=headers)
            with urllib.request.urlopen(req, timeout=TIMEOUT_S) as resp:
                for raw in resp:  # one line at a time, as the server sends them
                    event = parser.feed(raw.decode("utf-8"))
                    if event is None:
                        continue
                    failures = 0
                    yield event
                    if event.name in FINAL_EVENTS:
                        return
            print("(event stream ended early; reconnecting)", file=sys.stderr)
        except urllib.error.HTTPError as e:
            raise HTTPFailure(e.code, e.read()) from None  # the sweep is gone: no retry
        except (OSError, ValueError, http.client.HTTPException) as e:  # dropped, stalled, cut
            print(f"(event stream: {e}; reconnecting)", file=sys.stderr)
        failures += 1
        if failures > RECONNECT_ATTEMPTS:
            raise ConnectionError(f"no event after {RECONNECT_ATTEMPTS} reconnections")
        time.sleep((parser.retry_ms or 1000) / 1000.0)


# ---------------------------------------------------------------------------------------
# The sweep
# ---------------------------------------------------------------------------------------
def parse_grid(option):
    """'/materials/wax/g=[0.2,0.5]' -> ('/materials/wax/g', [0.2, 0.5])."""
    pointer, eq, values = option.partition("=")
    if not eq or not pointer.startswith("/"):
        raise argparse.ArgumentTypeError(f"--grid {option!r}: expected /json/pointer=[v1,v2,...]")
    try:
        values = json.loads(values)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"--grid {option!r}: values are not JSON: {e}")
    if not isinstance(values, list) or not values:
        raise argparse.ArgumentTypeError(f"--grid {option!r}: values must be a non-empty JSON list")
    return pointer, values


def parse_variant(option):
    try:
        variant = json.loads(option)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"--variant {option!r}: not JSON: {e}")
    if not isinstance(variant, dict):
        raise argparse.ArgumentTypeError(f"--variant {option!r}: expected a JSON object")
    return variant


def describe(overrides):
    return " ".join(f"{k}={json.dumps(v, separators=(',', ':'))}" for k, v in overrides.items())


def total_ms(timings):
    return sum(v for v in (timings or {}).values() if isinstance(v, (int, float)))


def at(server, link):
    """The URL of a link the server gave ("/v1/sweeps/ID/sheet.png")."""
    return urllib.parse.urljoin(server + "/", link)


def save(path, data):
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    with open(path, "wb") as f:
        f.write(data)


def download(server, sweep, out):
    """sheet.png, manifest.json and images/NNN.png of every finished variant."""
    links = sweep["links"]
    save(os.path.join(out, "sheet.png"), request("GET", at(server, links["sheet"]))[2])
    save(os.path.join(out, "manifest.json"), request("GET", at(server, links["manifest"]))[2])
    saved = 0
    for v in sweep["variants"]:
        if v["state"] == "done":
            png = request("GET", at(server, v["image"]), headers={"Accept": "image/png"})[2]
            save(os.path.join(out, "images", f"{v['index']:03d}.png"), png)
            saved += 1
    return saved


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--server", default="http://127.0.0.1:8080")
    ap.add_argument("--scene", required=True, help="the base scene (JSON file)")
    ap.add_argument("--grid", action="append", type=parse_grid, default=[],
                    metavar="POINTER=[V1,V2,...]", help="one axis of a grid (repeatable)")
    ap.add_argument("--variant", action="append", type=parse_variant, default=[],
                    metavar="JSON", help='one variant, {"/pointer": value, ...} (repeatable)')
    ap.add_argument("--out", default="sweep-out", help="folder for the results")
    args = ap.parse_args()
    if bool(args.grid) == bool(args.variant):
        ap.error("give either --grid (one or more) or --variant (one or more)")

    server = args.server.rstrip("/")
    with open(args.scene, encoding="utf-8") as f:
        body = {"scene": json.load(f)}
    if args.grid:
        body["grid"] = dict(args.grid)  # insertion order: the first --grid varies slowest
    else:
        body["variants"] = args.variant

    try:
        status, headers, answer = request("POST", server + "/v1/sweeps",
                                          json.dumps(body).encode(),
                                          {"Content-Type": "application/json"})
    except HTTPFailure as e:
        print_problem(e)
        return 2
    sweep = json.loads(answer)
    url = at(server, headers.get("Location") or sweep["links"]["self"])
    overrides = {v["index"]: v["overrides"] for v in sweep["variants"]}
    try:  # from here on, Ctrl-C cancels the sweep: the id is printed inside
        print(f"sweep {sweep['id']}: {len(overrides)} variants, {url}", flush=True)
        final = None
        for event in events(at(server, sweep["links"]["events"])):
            data = json.loads(event.data) if event.data else {}
            if event.name == "variant_end":
                i = data["index"]
                reused = ",".join(data.get("reused") or []) or "-"
                print(f"{i:3d}  {data['state']:9s} {total_ms(data.get('timings_ms')):9.1f} ms  "
                      f"reused {reused:11s} {describe(overrides.get(i, {}))}", flush=True)
            elif event.name in FINAL_EVENTS:
                final = data
    except KeyboardInterrupt:
        print(f"\ninterrupted: cancelling sweep {sweep['id']}", file=sys.stderr)
        try:
            request("DELETE", url, timeout=10)
        except (HTTPFailure, OSError) as e:
            print(f"cancelling failed: {e}", file=sys.stderr)
        return 130

    sweep = final or json.loads(request("GET", url)[2])
    saved = download(server, sweep, args.out)
    print(f"sweep {sweep['state']}: {saved} of {len(sweep['variants'])} images, sheet.png and "
          f"manifest.json in {args.out}")
    return 0 if sweep["state"] == "done" else 1


if __name__ == "__main__":
    try:
        sys.exit(main())
    except HTTPFailure as e:
        print_problem(e)
        sys.exit(1)
    except OSError as e:  # the server is not there, or went away
        print(f"sweep.py: {e}", file=sys.stderr)
        sys.exit(1)
    except KeyboardInterrupt:
        sys.exit(130)
