#!/usr/bin/env bash
# Run on the GPU machine from the repository root with the carried binaries (build-gpu-bin: the
# cellforce binary, the two test binaries and cellforce-bench-gpu-forces): the checks of
# validation/reports/reliability.md there.
#   - the GPU tests and the whole GoogleTest suite (the GPU backends run instead of skipping; the
#     reliability tests of tests/reliability_test.cpp take every backend and precision);
#   - compute-sanitizer memcheck on the reliability tests of the GPU backends (huge boxes, far-out
#     coordinates: the exact wrap in the staging kernel);
#   - the GPU force benchmark, whose traversal times show what the exact wrap in the staging costs
#     (against data/gpu-forces-h100-compensated.json, the same command before the change).
# Everything lands in $OUT.   bash validation/device/reliability.sh [build-dir]
set -uo pipefail
build=${1:-build-gpu-bin}
out=${OUT:-/tmp/cellforce-reliability}
mkdir -p "$out"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$out/device.txt"
nproc | sed 's/^/cpu cores: /' | tee -a "$out/device.txt"

timeout 60 "$build/tests/cellforce_gpu_tests" --gtest_brief=1 > "$out/gpu_tests.log" 2>&1
tail -n 3 "$out/gpu_tests.log"
OMP_WAIT_POLICY=PASSIVE timeout 330 "$build/tests/cellforce_tests" --gtest_brief=1 > "$out/tests.log" 2>&1
echo "cellforce_tests: exit $?"
tail -n 8 "$out/tests.log"

rc=0
timeout 100 compute-sanitizer --tool memcheck --error-exitcode 3 "$build/tests/cellforce_tests" \
  --gtest_brief=1 --gtest_filter='Backends/LargeBox.*gpu*:Backends/FarOut.*gpu*' \
  > "$out/sanitizer_memcheck.log" 2>&1 || rc=$?
echo "compute-sanitizer memcheck on the reliability tests: exit $rc ($(grep -E 'ERROR SUMMARY' "$out/sanitizer_memcheck.log" | sort | uniq -c | tr '\n' ' '))"

timeout 90 "$build/cellforce-bench-gpu-forces" --cells 20 64 102 --thread-form false --chapter-sort false \
  --json "$out/bench_gpu_forces.json" > "$out/bench_gpu_forces.md" 2>&1
tail -n 30 "$out/bench_gpu_forces.md"
