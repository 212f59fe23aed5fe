#!/usr/bin/env bash
# Run on the GPU machine from the repository root, with a build made on the development machine
# (`cmake --preset gpu && cmake --build --preset gpu`, carried as build-gpu): the whole GoogleTest
# suite (the GPU backends and GPU tests run there instead of skipping), compute-sanitizer memcheck
# and racecheck on the GPU tests, and the benchmarks. Logs go to $OUT.
#   bash validation/device/check.sh [build-dir] [tests|bench|all]
set -uo pipefail
build=${1:-build-gpu}
what=${2:-all}
out=${OUT:-/tmp/cellforce-check}
mkdir -p "$out"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$out/device.txt"
nproc | sed 's/^/cpu cores: /' | tee -a "$out/device.txt"
ldd "$build/tests/cellforce_tests" "$build/tests/cellforce_gpu_tests" | grep -E 'not found' && exit 1

if [[ $what == tests || $what == all ]]; then
  # Test binaries are run directly: ctest files hold the build machine's absolute paths.
  "$build/tests/cellforce_gpu_tests" 2>&1 | tee "$out/gpu_tests.log" | tail -n 4
  OMP_WAIT_POLICY=PASSIVE "$build/tests/cellforce_tests" --gtest_brief=1 2>&1 \
    | tee "$out/tests.log" | tail -n 6
  # The sanitizers run on everything that launches kernels: the stage tests, the GPU engine tests
  # and the GPU backends of the shared test bodies (racecheck on the cooperative kernel's
  # shared-memory traffic, i.e. the warp-per-cell backends).
  gpu_filter='*gpu*:*Gpu*'
  race_filter='*gpuwarp*:*gpuchaptersort*:GpuStages*:Forms/GpuDenseCluster*:Scenes/GpuVsCpu.*warp*'
  for tool in memcheck racecheck; do
    filter=$gpu_filter
    [[ $tool == racecheck ]] && filter=$race_filter
    rc=0
    compute-sanitizer --tool "$tool" --error-exitcode 3 "$build/tests/cellforce_gpu_tests" \
      > "$out/sanitizer_$tool.log" 2>&1 || rc=$?
    compute-sanitizer --tool "$tool" --error-exitcode 3 "$build/tests/cellforce_tests" \
      --gtest_brief=1 --gtest_filter="$filter" >> "$out/sanitizer_$tool.log" 2>&1 || rc=$?
    echo "compute-sanitizer $tool: exit $rc ($(grep -E 'ERROR SUMMARY|RACECHECK SUMMARY' "$out/sanitizer_$tool.log" | sort | uniq -c | tr '\n' ' '))"
  done
fi

if [[ $what == bench || $what == all ]]; then
  "$build/cellforce-bench-gpu" --json "$out/bench_gpu_stages.json" 2>&1 | tee "$out/bench_gpu_stages.md"
  "$build/cellforce-bench-gpu-forces" --json "$out/bench_gpu_forces.json" 2>&1 \
    | tee "$out/bench_gpu_forces.md"
fi
