#!/usr/bin/env bash
# Run on the GPU machine from the repository root (binaries carried as build-gpu-bin, the OpenMM
# wheels as .whl; see docs/validation.md). The checks of the device-resident engine and public API
# (validation/reports/md-run.md):
#   bash validation/device/md_run.sh quick [build]  the API, MD and run tests, the GPU core tests,
#                                                   and `cellforce run` of in.lj at 32k and 1M
#   bash validation/device/md_run.sh suite [build]  the whole test suite
#   bash validation/device/md_run.sh peer  [build]  validation/md_peer.py: cellforce run and OpenMM
#                                                   CUDA on the in.lj fluid, 32k to 4.2M particles
# Logs and tables go to $OUT.
set -uo pipefail
what=${1:-quick}
build=${2:-build-gpu-bin}
out=${OUT:-/tmp/cellforce-md}
mkdir -p "$out"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$out/device.txt"
case "$what" in
  quick)
    "$build/tests/cellforce_tests" --gtest_brief=1 \
      --gtest_filter='Api*:CApi*:ApiVsForcesCommand*:ApiDevice*:Backends/MdApi*:RunFolder*:ForcesCommand*' \
      > "$out/tests-api.log" 2>&1
    echo "api/md/run tests: exit $?"; grep -E "PASSED|FAILED|SKIPPED|^NVE|^Langevin" "$out/tests-api.log" | head -40
    "$build/tests/cellforce_gpu_tests" --gtest_brief=1 > "$out/gpu-tests.log" 2>&1
    echo "gpu tests: exit $?"; tail -n 3 "$out/gpu-tests.log"
    for cells in 20 64; do
      "$build/cellforce" run --steps 500 --backend cuda --quiet > "$out/run-$cells.log" 2>&1 \
        || echo "run at cells $cells failed"
    done
    tail -n 9 "$out/run-20.log"
    ;;
  suite)
    timeout 560 "$build/tests/cellforce_tests" --gtest_brief=1 > "$out/tests-all.log" 2>&1
    echo "cellforce_tests: exit $?"; tail -n 30 "$out/tests-all.log"
    ;;
  peer)
    source validation/device/openmm_env.sh > "$out/openmm_env.log" 2>&1 || { cat "$out/openmm_env.log"; exit 2; }
    cat "$out/openmm_env.log"
    PYTHONUNBUFFERED=1 python3 validation/md_peer.py --cellforce "$build/cellforce" --cells ${CELLS:-20 40 64 102} \
      --precisions single mixed --md "$out/md-peer.md" --json "$out/md-peer.json" > "$out/md-peer.log" 2>&1
    echo "md_peer.py: exit $?"; cat "$out/md-peer.md"
    ;;
esac
