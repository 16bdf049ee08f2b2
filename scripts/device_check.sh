#!/bin/bash
# device_check.sh — one prepared run on a borrowed NVIDIA machine (docs/bench.md, *On an
# NVIDIA GPU*): unpacks .dev/pack.tar.xz (scripts/device_pack.sh) and the GL loader packages
# in .gl/, then, each stage bounded by `timeout` and its output written under $OUT at once:
#   1. nscatter info on the NVIDIA Vulkan driver (ray queries, subgroup size, memory);
#   2. bench_rays: the compute BVH's ray throughput against Embree on the host's cores;
#   3. the bench at 512² (nn multiple only and full; references of REF512_SPP samples, there
#      only for the bench to run: the times per stage are what this stage is for);
#   4. the bench's progressive references pushed towards a 40 dB ceiling in chunks of
#      REF_SPP samples (a tarball of the cache comes back), with the gpu_* tests running
#      beside them on the NVIDIA device;
#   5. the whole bench at 128² against those references.
# Run from the repository root there; stage budgets in seconds come from the environment;
# the defaults add up to about 560 s with the set-up, within one call's 600 s (give the
# device tool timeout_s 590).
# The first run (2026-11-30, docs/bench.md) taught: a 64-spp chunk costs ~0.2 s of overhead
# on an H200, so chunks of 1,024 spp (a new chunk size starts new references); and 512²
# references of 16 spp took 1-11 s each, so 4.
set -u
t0=$(date +%s)
log() { echo "[$(($(date +%s) - t0)) s] $*"; }
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
root=$PWD
device=${DEVICE:-nvidia}
if [ -z "${SKIP_GL:-}" ]; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
dev=/tmp/dev
# A warm machine keeps /tmp between calls: start from nothing.
rm -rf $dev /tmp/tests.txt /tmp/tlog.* /tmp/b512 /tmp/c512 /tmp/b128 /tmp/brefs /tmp/tcache
mkdir -p $dev && tar xJf .dev/pack.tar.xz -C $dev
export LD_LIBRARY_PATH=$dev/lib
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
[ -f $icd ] && export VK_DRIVER_FILES=$icd VK_ICD_FILENAMES=$icd
export NSCATTER_DEVICE=$device
# The tests and the bench find weights/ and scenes/ under the source folder they were built in.
mkdir -p /work && [ -e /work/main ] || ln -s "$root" /work/main
bin=$dev/bin
common=(--device $device --bunny $dev/bunny.obj --scene-dir "$root/scenes/bench")

log "machine"
{ nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv; nproc;
  grep -m1 'model name' /proc/cpuinfo; } >"$OUT/info.txt" 2>&1
log "info"
if ! $bin/nscatter info >>"$OUT/info.txt" 2>&1; then
    cat "$OUT/info.txt"
    VK_LOADER_DEBUG=error,warn $bin/nscatter info 2>&1 | tail -30
    ls /usr/local/nvidia/share/vulkan/icd.d/ /usr/share/vulkan/icd.d/ /etc/vulkan/icd.d/ 2>&1
    exit 1
fi
$bin/nscatter info --json >>"$OUT/info.txt" 2>&1
cat "$OUT/info.txt"

log "bench_rays"
for size in 512x512 1024x1024; do
    timeout "${RAYS_S:-30}" $bin/bench_rays --device $device --bunny $dev/bunny.obj \
        --scene "$root/scenes/bench/bunny.json" --size $size --repeat 7 --threads "$(nproc)" 2>&1 |
        tee -a "$OUT/rays.txt" | tail -12
done

log "bench 512x512"
timeout "${B512_S:-150}" $bin/nscatter bench "${common[@]}" --width 512 --height 512 \
    --methods nn_multiple,nn_full --ref-spp "${REF512_SPP:-4}" --repeat 5 --out /tmp/b512 --cache /tmp/c512 \
    >/tmp/bench512.log 2>&1
log "bench 512 exit $?"
{ cat /tmp/b512/report.md; echo '## log'; cat /tmp/bench512.log; } >"$OUT/bench512.md" 2>&1
head -c 5000 /tmp/b512/report.md

log "tests (background) and references"
tcache=/tmp/tcache && mkdir -p $tcache && cp $dev/test-cache/* $tcache/ 2>/dev/null
# The whole stage is bounded too (TESTS_S), whatever the tests' count and each one's bound.
(
    cd /tmp && ls $bin | grep '^gpu_' |
        timeout "${TESTS_S:-210}" xargs -P 6 -I{} sh -c "NSCATTER_BIN=$bin/nscatter \
            NSCATTER_SOURCE_DIR=$root NSCATTER_CACHE_DIR=$tcache timeout ${TEST_S:-200} $bin/{} \
            >/tmp/tlog.{} 2>&1; echo \"{} exit \$?\" >>/tmp/tests.txt"
) &
tests_pid=$!
timeout "${REFS_S:-200}" $bin/nscatter bench "${common[@]}" --references --ref-spp "${REF_SPP:-1024}" \
    --ref-ceiling 40 --ref-budget "${REFS_BUDGET_S:-170}" --ref-max-spp 262144 \
    --cache $dev/cache --out /tmp/brefs >/tmp/refs.log 2>&1
log "references exit $?"
cp /tmp/refs.log "$OUT/refs.log"
tail -30 /tmp/refs.log
tar czf "$OUT/refs.tar.gz" -C $dev/cache --exclude=assets .
wait $tests_pid
sort /tmp/tests.txt
{ sort /tmp/tests.txt; for f in /tmp/tlog.*; do echo "== $f"; tail -25 "$f"; done; } >"$OUT/tests.txt"
grep -v ' exit 0$' /tmp/tests.txt | while read -r t _; do tail -20 /tmp/tlog.$t; done

log "bench 128x128"
timeout "${B128_S:-100}" $bin/nscatter bench "${common[@]}" \
    --methods nn_surface,nn_multiple,nn_double,nn_full,dipole,vrl,pt --ref-spp "${REF_SPP:-1024}" \
    --ref-ceiling 40 --ref-budget 1 --ref-max-spp 262144 --cache $dev/cache --out /tmp/b128 \
    >/tmp/bench128.log 2>&1
log "bench 128 exit $?"
{ cat /tmp/b128/report.md; echo '## log'; cat /tmp/bench128.log; } >"$OUT/bench128.md" 2>&1
cp /tmp/b128/contact_sheet.png "$OUT/contact128.png" 2>/dev/null
log "done"
