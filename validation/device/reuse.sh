#!/usr/bin/env bash
# Run on the GPU machine from the repository root with the carried binaries (docs/validation.md,
# "On a GPU machine"): the material of cases 11-13 of validation/reports/stability.md, in two
# calls that each fit one device command (10 minutes):
#   bash validation/device/reuse.sh tests [build-dir] [label]
#     the whole GoogleTest suite with the stability checks logged, memcheck on the GPU reuse
#     cases, and (in the background) the CUDA force-shift NVE drift rows at dt 0.002 and 0.01;
#   bash validation/device/reuse.sh bench [build-dir] [label]
#     skin reuse against skin 0 (validation/skin_reuse.py, CUDA 32k and 256k, CPU 4k), the
#     overlap / hot dense scenes of item 13 on the GPU, the stability cases again with their log
#     (for the report at this commit), and memcheck on one GPU backend's reuse cases.
# At most 8 files land in $OUT (the device tool's limit): logs are gathered in one tar file.
set -uo pipefail
what=${1:?tests or bench}
build=${2:-build-gpu-bin}
label=${3:-H100 machine}
out=${OUT:-/tmp/cellforce-reuse}
mkdir -p "$out"
logs=$(mktemp -d)
{ nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader; nproc | sed 's/^/cpu cores: /'; } \
  | tee "$out/device.txt"

if [ "$what" = tests ]; then
  OMP_NUM_THREADS=4 OMP_WAIT_POLICY=PASSIVE timeout 560 python3 validation/nve_drift.py \
    --cellforce "$build/cellforce" --backends cuda --cells 5 --time 100 --dt 0.002 0.01 \
    --mode force-shift --jobs 3 --device "$label" --json "$out/drift_cuda_fs.json" \
    > "$logs/drift.log" 2>&1 &
  drift=$!
  "$build/tests/cellforce_gpu_tests" --gtest_brief=1 > "$logs/gpu_tests.log" 2>&1
  tail -n 3 "$logs/gpu_tests.log"
  CELLFORCE_STABILITY_LOG="$out/stability.jsonl" OMP_WAIT_POLICY=PASSIVE \
    "$build/tests/cellforce_tests" --gtest_brief=1 > "$logs/tests.log" 2>&1
  tail -n 8 "$logs/tests.log"
  rc=0
  timeout 150 compute-sanitizer --tool memcheck --error-exitcode 3 "$build/tests/cellforce_tests" \
    --gtest_brief=1 --gtest_filter='Targets/Stability.SkinReuse/gpu*:Backends/ReuseMd.*/gpu*' \
    > "$logs/sanitizer_memcheck.log" 2>&1 || rc=$?
  echo "compute-sanitizer memcheck on the reuse cases: exit $rc ($(grep -E 'ERROR SUMMARY' "$logs/sanitizer_memcheck.log" | sort | uniq -c | tr '\n' ' '))"
  wait "$drift"
  echo "drift runs: exit $?"
  tail -n 10 "$logs/drift.log"
else
  OMP_WAIT_POLICY=PASSIVE timeout 300 python3 validation/skin_reuse.py --cellforce "$build/cellforce" \
    --backends cuda --precisions double mixed --cells 20 --steps 2000 --skins 0 0.1 0.2 0.3 0.4 0.5 \
    --device "$label" --json "$out/skin_cuda_32k.json" --md "$logs/skin_cuda_32k.md" > "$logs/skin_cuda_32k.log" 2>&1
  cat "$logs/skin_cuda_32k.md"
  OMP_WAIT_POLICY=PASSIVE timeout 150 python3 validation/skin_reuse.py --cellforce "$build/cellforce" \
    --backends cuda --precisions mixed --cells 40 --steps 500 --skins 0 0.2 0.3 0.4 \
    --device "$label" --json "$out/skin_cuda_256k.json" --md "$logs/skin_cuda_256k.md" > "$logs/skin_cuda_256k.log" 2>&1
  cat "$logs/skin_cuda_256k.md"
  OMP_WAIT_POLICY=PASSIVE timeout 120 python3 validation/skin_reuse.py --cellforce "$build/cellforce" \
    --backends cpu --precisions double --cells 10 --steps 300 --skins 0 0.2 0.3 0.4 \
    --device "$label" --json "$out/skin_cpu_4k.json" --md "$logs/skin_cpu_4k.md" > "$logs/skin_cpu_4k.log" 2>&1
  cat "$logs/skin_cpu_4k.md"
  for scene in overlap_random hot_dense_T2 hot_dense_T5; do
    (cd "$logs" && timeout 60 "$OLDPWD/$build/cellforce" run "$OLDPWD/systems/$scene.toml" --backend cuda \
       --quiet --overwrite > "$scene.log" 2>&1; echo "$scene: exit $?" >> "$scene.log")
    tail -n 12 "$logs/$scene.log"
  done
  CELLFORCE_STABILITY_LOG="$out/stability.jsonl" OMP_WAIT_POLICY=PASSIVE timeout 240 \
    "$build/tests/cellforce_tests" --gtest_brief=1 --gtest_filter='Targets/Stability.*:StabilityNaive.*' \
    > "$logs/stability_tests.log" 2>&1
  echo "stability cases: exit $?"; tail -n 4 "$logs/stability_tests.log"
  rc=0
  timeout 170 compute-sanitizer --tool memcheck --error-exitcode 3 "$build/tests/cellforce_tests" \
    --gtest_filter='Targets/Stability.SkinReuse/gpuwarp_mixed:Backends/ReuseMd.*/gpuwarp' \
    > "$logs/sanitizer_memcheck.log" 2>&1 || rc=$?
  echo "compute-sanitizer memcheck on the gpuwarp reuse cases: exit $rc ($(grep -E 'ERROR SUMMARY' "$logs/sanitizer_memcheck.log" | sort | uniq -c | tr '\n' ' '); $(grep -cE '^\[       OK' "$logs/sanitizer_memcheck.log") tests OK)"
fi
tar -C "$logs" -czf "$out/logs-$what.tar.gz" .
