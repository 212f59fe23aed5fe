#!/usr/bin/env bash
# Run on the GPU machine from the repository root, with a build made on the development machine
# (`cmake --preset gpu && cmake --build --preset gpu`, carried as build-gpu): the whole GoogleTest
# suite (the GPU backends and GPU tests run there instead of skipping), compute-sanitizer memcheck
# and racecheck on the GPU tests, and the benchmarks. Logs go to $OUT.
#   bash validation/device/check.sh [build-dir] [tests|bench|sanitize|all]
# (tests = the suites and the sanitizers; SANITIZER_TIMEOUT bounds each sanitizer run, seconds)
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
fi

if [[ $what == bench || $what == all ]]; then
  "$build/cellforce-bench-gpu" --json "$out/bench_gpu_stages.json" 2>&1 | tee "$out/bench_gpu_stages.md"
  "$build/cellforce-bench-gpu-forces" --json "$out/bench_gpu_forces.json" 2>&1 \
    | tee "$out/bench_gpu_forces.md"
fi

if [[ $what == tests || $what == all || $what == sanitize ]]; then
  # The sanitizers run on every kernel: all stage tests, and the GPU engine tests that reach each
  # traversal form, precision, accumulation, observables, the pair recorder (with its buffer
  # growing) and the error flags. Racecheck follows the shared-memory kernels (warp per cell, the
  # chapter's sort). The whole GPU half of the suite under memcheck takes over 10 minutes.
  gpu_filter='Scenes/GpuVsCpu.*:Forms/GpuDenseCluster.*:GpuEngineReuse.*:EntryPoints/BadInput.*gpu*'
  gpu_filter+=':Scenes/PairCoverage.*gpu*_jacobi_random*:Scenes/PairCoverage.*gpu*_clustered*'
  race_filter='Scenes/GpuVsCpu.*/warp*:Forms/GpuDenseCluster.*/warp:Scenes/PairCoverage.*gpuwarp_jacobi_random*'
  race_filter+=':Scenes/Invariance.*gpuwarp_gaussseidel*'
  for tool in memcheck racecheck; do
    filter=$gpu_filter
    [[ $tool == racecheck ]] && filter=$race_filter
    rc=0
    timeout "${SANITIZER_TIMEOUT:-1200}" compute-sanitizer --tool "$tool" --error-exitcode 3 "$build/tests/cellforce_gpu_tests" \
      > "$out/sanitizer_$tool.log" 2>&1 || rc=$?
    timeout "${SANITIZER_TIMEOUT:-1200}" compute-sanitizer --tool "$tool" --error-exitcode 3 "$build/tests/cellforce_tests" \
      --gtest_brief=1 --gtest_filter="$filter" >> "$out/sanitizer_$tool.log" 2>&1 || rc=$?
    echo "compute-sanitizer $tool: exit $rc ($(grep -E 'ERROR SUMMARY|RACECHECK SUMMARY' "$out/sanitizer_$tool.log" | sort | uniq -c | tr '\n' ' '))"
  done
fi

