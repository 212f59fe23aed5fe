#!/usr/bin/env bash
# Run on the GPU machine from the repository root, with a build made on the development machine
# (`cmake --preset gpu && cmake --build --preset gpu`, carried as build-gpu): the whole GoogleTest
# suite (the GPU tests run there instead of skipping), compute-sanitizer memcheck and racecheck on
# the GPU tests, and the CPU benchmark on that machine's cores. Logs go to $OUT.
set -uo pipefail
build=${1:-build-gpu}
out=${OUT:-/tmp/cellforce-check}
mkdir -p "$out"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$out/device.txt"
nproc | sed 's/^/cpu cores: /' | tee -a "$out/device.txt"
ldd "$build/tests/cellforce_tests" "$build/tests/cellforce_gpu_tests" | grep -E 'not found' && exit 1
# Test binaries are run directly: ctest files hold the build machine's absolute paths.
"$build/tests/cellforce_gpu_tests" 2>&1 | tee "$out/gpu_tests.log" | tail -n 4
"$build/tests/cellforce_tests" --gtest_brief=1 2>&1 | tee "$out/cpu_tests.log" | tail -n 4
for tool in memcheck racecheck; do
  compute-sanitizer --tool "$tool" --error-exitcode 3 "$build/tests/cellforce_gpu_tests" \
    > "$out/sanitizer_$tool.log" 2>&1
  echo "compute-sanitizer $tool: exit $? ($(grep -E 'ERROR SUMMARY|RACECHECK SUMMARY' "$out/sanitizer_$tool.log" | tail -n 1))"
done
"$build/cellforce-bench-cpu" --cells 20 --repeats 9 --brute-repeats 1 --json "$out/bench_cpu.json" \
  2>&1 | tee "$out/bench_cpu.md"
