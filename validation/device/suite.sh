#!/usr/bin/env bash
# Run on the GPU machine from the repository root, with binaries built on the development machine
# and carried in one folder (cellforce, cellforce_tests, cellforce_gpu_tests): the whole GoogleTest
# suite in 8 shards side by side (the stability checks logged as JSON lines for
# validation/stability_report.py), the GPU unit tests, and compute-sanitizer memcheck of a short
# in.lj bench with pair lists and without, and of the embedding loop (bench --embed). Logs and the
# stability log go to $OUT.
#   bash validation/device/suite.sh BIN-DIR [shards]
set -uo pipefail
bin=${1:?the folder of the carried binaries}
shards=${2:-8}
out=${OUT:-/tmp/cellforce-suite}
mkdir -p "$out"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$out/device.txt"
export CELLFORCE_EXE=$PWD/$bin/cellforce CELLFORCE_STABILITY_LOG=$out/stability.jsonl OMP_NUM_THREADS=2 \
       OMP_WAIT_POLICY=PASSIVE
for i in $(seq 0 $((shards - 1))); do
  GTEST_TOTAL_SHARDS=$shards GTEST_SHARD_INDEX=$i "$bin/cellforce_tests" --gtest_brief=1 > "$out/shard$i.log" 2>&1 &
done
"$bin/cellforce_gpu_tests" --gtest_brief=1 > "$out/gpu_tests.log" 2>&1
wait
{
  for i in $(seq 0 $((shards - 1))); do echo "== shard $i"; grep -E "^\[  (PASSED|SKIPPED|FAILED) |FAILED TEST|^\[  FAILED" "$out/shard$i.log"; done
  echo "== gpu tests"; tail -n 3 "$out/gpu_tests.log"
} | tee "$out/summary.txt"
for skin in auto 0; do
  search=(); [[ $skin == 0 ]] && search=(--skin 0)  # auto: the bench's default (pair lists on CUDA)
  compute-sanitizer --tool memcheck --error-exitcode 9 "$bin/cellforce" bench --sizes 32000 --backend cuda \
    --precision mixed "${search[@]}" --steps 200 --warmup 10 --samples 2 --no-reference > "$out/memcheck-skin-$skin.log" 2>&1
  echo "memcheck skin $skin: exit $? ($(grep -c 'ERROR SUMMARY: 0 errors' "$out/memcheck-skin-$skin.log") clean summaries)" \
    | tee -a "$out/summary.txt"
done
# compute_device's decided calls (a CUDA graph a call with the build in a conditional node): an
# embedding code's loop around it (bench --embed).
compute-sanitizer --tool memcheck --error-exitcode 9 "$bin/cellforce" bench --embed --sizes 32000 --precision mixed \
  --steps 200 --warmup 10 --samples 2 --no-reference > "$out/memcheck-embed.log" 2>&1
echo "memcheck embed: exit $? ($(grep -c 'ERROR SUMMARY: 0 errors' "$out/memcheck-embed.log") clean summaries)" \
  | tee -a "$out/summary.txt"
