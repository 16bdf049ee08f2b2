#!/usr/bin/env bash
# serve_memory.sh — resident memory of `nscatter serve`, for sizing containers
# (docs/container.md, "Memory"; deploy/k8s/deployment.yaml's resources).
#
#   scripts/serve_memory.sh [BINARY]      default build/nscatter
#
# Prints VmRSS (now) and VmHWM (peak so far) from /proc: idle after start-up, after each of
# three 256x256 renders of scenes/default.json, then after one render of each other example
# scene (each adds its scattering tables to the context's cache, bounded at 1 GiB).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${1:-build/nscatter}
dir=$(mktemp -d)
trap 'kill "$pid" 2>/dev/null || true; rm -rf "$dir"' EXIT
"$BIN" serve --host 127.0.0.1 --port 0 --access-log off --assets scenes/assets >"$dir/out" 2>"$dir/err" &
pid=$!
for _ in $(seq 2400); do grep -q listening "$dir/out" 2>/dev/null && break; sleep 0.1; done
port=$(sed -n 's/^listening on http:\/\/127.0.0.1:\([0-9]*\)$/\1/p' "$dir/out")
[ -n "$port" ] || { echo "serve_memory: the server did not start" >&2; cat "$dir/err" >&2; exit 1; }
mem() { awk '/^VmRSS|^VmHWM/ {printf "%s %.0f MB  ", $1, $2 / 1000}' "/proc/$pid/status"; echo; }
render() {
  curl -sS -o /dev/null -w '%{http_code} %{time_total} s' -H 'Content-Type: application/json' \
       --data-binary @"$1" "http://127.0.0.1:$port/v1/renders"
}
sleep 1
echo "idle:                        $(mem)"
for i in 1 2 3; do
  echo "default.json 256x256 #$i: $(render scenes/default.json)  $(mem)"
done
for s in scenes/*.json; do
  [ "$s" = scenes/default.json ] && continue
  echo "$(basename "$s"): $(render "$s")  $(mem)"
done
curl -fsS "http://127.0.0.1:$port/metrics" | grep -E '^nscatter_table_cache_bytes'
kill -TERM "$pid"; wait "$pid"
