#!/usr/bin/env bash
# On a GPU machine of several GPUs, from the repository root, with .device/lammps.tar.xz carried
# (validation/device/lammps_bundle.sh): in.lj by cellforce-lammps with the CUDA backend (mixed) on
# 1..G GPUs of the host (CUDA_VISIBLE_DEVICES; rank r computes on GPU r mod G), R ranks a GPU; then
# LAMMPS's own lj/cut/opt on the host's cores and `cellforce run` on one GPU. Each run's summary
# lines are appended to $OUT/runs.txt as it ends (a run cut short by the call's limit loses only
# itself; each run is stopped after RUN_TIMEOUT seconds, default 120, its output line-buffered so
# that a stopped run's log shows how far it came); every output to $OUT/logs.tgz at the end.
#   bash validation/device/lammps_gpus.sh "GPUS RANKS_A_GPU CELLS STEPS" ...   (cellforce-lammps runs)
#   LMP_RUNS="CELLS STEPS ..." RUN_CELLS="CELLS ..." to add the baselines.
# The table and plot from runs.txt: validation/lammps_gpus_report.py.
set -uo pipefail
out=${OUT:-/tmp/cellforce-gpus}
mkdir -p "$out" /tmp/gpus-logs
source validation/device/lammps_env.sh > /dev/null
export OMPI_MCA_btl_vader_single_copy_mechanism=none
cores=$(nproc)
{ nvidia-smi --query-gpu=index,name,memory.total --format=csv,noheader; echo "cores $cores"; } >> "$out/runs.txt"
summary() {  # the lines of a LAMMPS log that the report reads
  grep -E "^(Pair|Neigh|Comm|Modify|Other) |Loop time|cellforce-lammps|Nghost|^ +[0-9]+ +[-0-9.e]+ +[-0-9.e]+ " "$1" | tail -n 20
}
for run in "$@"; do
  read -r gpus per cells steps <<< "$run"
  np=$((gpus * per)); visible=$(seq -s, 0 $((gpus - 1)))
  log=/tmp/gpus-logs/cf-g$gpus-r$per-c$cells.txt
  echo "== cellforce-lammps cuda mixed: $gpus GPUs ($visible), $np ranks, cells $cells, $steps steps" >> "$out/runs.txt"
  CUDA_VISIBLE_DEVICES=$visible CELLFORCE_BACKEND=cuda CELLFORCE_PRECISION=mixed CELLFORCE_THREADS=1 OMP_NUM_THREADS=1 \
    timeout ${RUN_TIMEOUT:-120} stdbuf -oL $MPIRUN -np $np --bind-to core --map-by core "$CF_LAMMPS" -in systems/lammps/in.lj -var cells $cells \
    -var steps $steps -var every 1 -var check yes -log none > "$log" 2>&1
  echo "exit $?" >> "$out/runs.txt"; summary "$log" >> "$out/runs.txt"
done
set -- ${LMP_RUNS:-}
while [ $# -ge 2 ]; do
  cells=$1 steps=$2; shift 2
  log=/tmp/gpus-logs/lmp-c$cells.txt
  echo "== lammps lj/cut/opt: $cores ranks, cells $cells, $steps steps" >> "$out/runs.txt"
  OMP_NUM_THREADS=1 timeout ${RUN_TIMEOUT:-120} stdbuf -oL $MPIRUN -np $cores --bind-to core --map-by core "$CF_LMP" -sf opt -in systems/lammps/in.lj \
    -var cells $cells -var steps $steps -var every 1 -var check yes -log none > "$log" 2>&1
  echo "exit $?" >> "$out/runs.txt"; summary "$log" >> "$out/runs.txt"
done
for cells in ${RUN_CELLS:-}; do
  echo "== cellforce run: 1 GPU, cells $cells" >> "$out/runs.txt"
  python3 -c "
import sys, tempfile; sys.path.insert(0, 'validation')
from md_peer import cellforce_steps_per_second
from pathlib import Path
with tempfile.TemporaryDirectory() as t:
    r = cellforce_steps_per_second('$CF_CLI', $cells, 'mixed', 300, Path(t))
print('ms per step', r['ms_per_step'], 'forces ms per step', r['forces_ms_per_step'])" >> "$out/runs.txt" 2>&1
done
tar czf "$out/logs.tgz" -C /tmp gpus-logs
cat "$out/runs.txt"
