#!/bin/bash
# device_pack.sh — packs what scripts/device_check.sh needs on a borrowed GPU machine that has
# an NVIDIA driver but none of nscatter's Debian libraries: the stripped binaries (nscatter,
# the gpu_* tests, bench_rays), the shared libraries they load beyond glibc and libstdc++, the
# bench's bunny, the bench's reference cache and the tests' Monte Carlo tables. Writes
.dev/pack.tar.xz (ignored by git); run from the repository root after building `build/`.
#   usage: scripts/device_pack.sh [REFERENCE_CACHE_DIR]   (default ~/.cache/nscatter/bench)
set -euo pipefail
refs=${1:-$HOME/.cache/nscatter/bench}
stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT
mkdir -p "$stage/bin" "$stage/lib" "$stage/cache" "$stage/test-cache" .dev
for f in build/nscatter build/bench/bench_rays build/tests/gpu_*; do
    [ -f "$f" ] && [ -x "$f" ] && strip -o "$stage/bin/$(basename "$f")" "$f"
done
# Every library the binaries load except the C runtime, which the other machine has (newer).
ldd "$stage"/bin/* | awk '/=> \//{print $3}' | sort -u |
    grep -Ev '/(libc|libm|libpthread|libdl|librt|libstdc\+\+|libgcc_s)\.so' |
    while read -r lib; do cp -L "$lib" "$stage/lib/"; done
cp /usr/share/glmark2/models/bunny.obj "$stage/"
cp -r "$refs"/. "$stage/cache/"
cp build/test-cache/mc_* "$stage/test-cache/" 2>/dev/null || true
tar cf - -C "$stage" . | xz -T2 -6 > .dev/pack.tar.xz
ls -la .dev/pack.tar.xz
