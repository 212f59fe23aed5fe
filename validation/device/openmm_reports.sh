#!/usr/bin/env bash
# Run on the GPU machine from the repository root (build carried as build-gpu-bin, the OpenMM
# wheels as .whl; see docs/validation.md): the OpenMM parity check on every case for the CPU and
# CUDA backends, and the error-against-time data with OpenMM's Reference, CPU and CUDA platforms.
# Writes parity.md, parity.json, error-vs-time-<device>.json and logs to $OUT.
#   bash validation/device/openmm_reports.sh [build-dir] [device-label]
set -uo pipefail
build=${1:-build-gpu-bin}
label=${2:-h100}
out=${OUT:-/tmp/cellforce-openmm}
mkdir -p "$out"
source validation/device/openmm_env.sh > "$out/openmm_env.log" 2>&1 || { cat "$out/openmm_env.log"; exit 2; }
cat "$out/openmm_env.log"
export PYTHONUNBUFFERED=1
python3 validation/parity.py --cellforce "$build/cellforce" --backend cpu cuda --require-backends \
  --report "$out/parity.md" --json "$out/parity.json" > "$out/parity.log" 2>&1
echo "parity.py: exit $? ($(tail -n 1 "$out/parity.log"))"
python3 validation/error_vs_time.py --cellforce "$build/cellforce" \
  --xyz systems/validation/lj_liquid_32k.xyz --cutoff 2.5 --mode truncate \
  --openmm-platforms Reference CPU CUDA --backends cpu cuda \
  --out "$out/error-vs-time-$label.json" > "$out/error-vs-time.log" 2>&1
echo "error_vs_time.py: exit $?"
cat "$out/error-vs-time.log"
