#!/usr/bin/env bash
# Run on the GPU machine from the repository root with the carried binaries (docs/validation.md,
# "On a GPU machine"): the material for validation/reports/stability.md. In one go:
#   - the NVE drift runs (validation/nve_drift.py, CPU and CUDA, 500 particles, dt 0.002 / 0.005 /
#     0.01 over 100 time units, truncate and force shift, every precision), in the background;
#   - the whole GoogleTest suite, with the stability checks logged as JSON lines;
#   - compute-sanitizer memcheck on the stability cases of the GPU backends;
#   - the GPU force benchmark (the cost of the float staging, against gpu-forces-h100.json).
# Everything lands in $OUT.
#   bash validation/device/stability.sh [build-dir] [device label]
set -uo pipefail
build=${1:-build-gpu-bin}
label=${2:-H100 machine}
out=${OUT:-/tmp/cellforce-stability}
mkdir -p "$out"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$out/device.txt"
nproc | sed 's/^/cpu cores: /' | tee -a "$out/device.txt"

OMP_NUM_THREADS=2 OMP_WAIT_POLICY=PASSIVE timeout 540 python3 validation/nve_drift.py \
  --cellforce "$build/cellforce" --backends cpu cuda --cells 5 --time 100 --dt 0.002 0.005 0.01 \
  --mode truncate force-shift --jobs 6 --device "$label" --json "$out/drift.json" \
  > "$out/drift.log" 2>&1 &
drift=$!

"$build/tests/cellforce_gpu_tests" --gtest_brief=1 > "$out/gpu_tests.log" 2>&1
tail -n 3 "$out/gpu_tests.log"
CELLFORCE_STABILITY_LOG="$out/stability.jsonl" OMP_WAIT_POLICY=PASSIVE \
  "$build/tests/cellforce_tests" --gtest_brief=1 > "$out/tests.log" 2>&1
tail -n 6 "$out/tests.log"

rc=0
timeout 200 compute-sanitizer --tool memcheck --error-exitcode 3 "$build/tests/cellforce_tests" \
  --gtest_brief=1 --gtest_filter='Targets/Stability.*/gpu*:-*CrowdedAndDilute*:*FarFromTheOrigin*' \
  > "$out/sanitizer_memcheck.log" 2>&1 || rc=$?
echo "compute-sanitizer memcheck on the stability cases: exit $rc ($(grep -E 'ERROR SUMMARY' "$out/sanitizer_memcheck.log" | sort | uniq -c | tr '\n' ' '))"

timeout 120 "$build/cellforce-bench-gpu-forces" --cells 20 64 102 --thread-form false --chapter-sort false --json "$out/bench_gpu_forces.json" > "$out/bench_gpu_forces.md" 2>&1
tail -n 30 "$out/bench_gpu_forces.md"

wait "$drift"
echo "drift runs: exit $?"
tail -n 40 "$out/drift.log"
