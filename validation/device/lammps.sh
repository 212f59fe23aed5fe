#!/usr/bin/env bash
# On the GPU machine, from the repository root, with .device/lammps.tar.xz carried (made here by
# validation/device/lammps_bundle.sh): cellforce-lammps's parity with LAMMPS on the CPU and CUDA
# backends (tests/lammps/parity.py), compute-sanitizer's memcheck of a CUDA run, then
# validation/lammps_scaling.py's GPU rows and CPU rows
# (validation/reports/lammps.md). Logs and tables go to $OUT.
#   bash validation/device/lammps.sh [parity] [memcheck] [gpu] [cpu]     (default: all four)
set -uo pipefail
out=${OUT:-/tmp/cellforce-lammps}
mkdir -p "$out"
source validation/device/lammps_env.sh
# Containers forbid Open MPI's cross-process copies (CMA): shared memory copies in and out instead.
export OMPI_MCA_btl_vader_single_copy_mechanism=none
{ nproc; lscpu | grep -E "Model name|^CPU\(s\)|Thread|Core|Socket"; mpirun --version | head -1
  nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader; } > "$out/machine.txt" 2>&1
cat "$out/machine.txt"
what=${*:-parity memcheck gpu cpu}
for step in $what; do
  case $step in
    parity)
      for backend in cpu cuda; do  # on CUDA the ranks' placement over the machine's GPUs checked too
        # the GPUs the ranks see: CUDA_VISIBLE_DEVICES's list where it is set, else the machine's
        gpus=(); [[ $backend == cuda ]] && gpus=(--gpus "$(if [[ -n ${CUDA_VISIBLE_DEVICES:-} ]]; then
          tr ',' '\n' <<< "$CUDA_VISIBLE_DEVICES" | grep -c .; else nvidia-smi -L | grep -c '^GPU'; fi)")
        python3 tests/lammps/parity.py --cellforce-lammps "$CF_LAMMPS" --lmp "$CF_LMP" --mpiexec mpirun \
          --systems systems/lammps --backend $backend ${gpus[@]+"${gpus[@]}"} > "$out/parity-$backend.log" 2>&1
        echo "parity $backend: exit $? ($(grep -c '^ok' "$out/parity-$backend.log") ok, $(grep -c '^FAIL' "$out/parity-$backend.log") failed)"
        grep -E "^FAIL|skipped" "$out/parity-$backend.log" | head -5
      done ;;
    gpu)
      python3 validation/lammps_scaling.py --cellforce-lammps "$CF_LAMMPS" --lmp "$CF_LMP" --cellforce "$CF_CLI" \
        --mpirun "$MPIRUN" --cpu-cells --cpu-steps --gpu-cells ${GPU_CELLS:-40 64} --gpu-steps ${GPU_STEPS:-400 200} \
        --gpu-ranks ${GPU_RANKS:-1 2 4 8 16} --md "$out/gpu.md" --json "$out/gpu.json" --log "$out/gpu.log" \
        > "$out/gpu.out" 2>&1
      echo "gpu rows: exit $?"; cat "$out/gpu.md" ;;
    cpu)
      python3 validation/lammps_scaling.py --cellforce-lammps "$CF_LAMMPS" --lmp "$CF_LMP" --mpirun "$MPIRUN" \
        --cpu-cells ${CPU_CELLS:-20 40} --cpu-steps ${CPU_STEPS:-200 60} --ranks ${RANKS:-1 2 4 8 16} \
        --md "$out/cpu.md" --json "$out/cpu.json" --log "$out/cpu.log" > "$out/cpu.out" 2>&1
      echo "cpu rows: exit $?"; cat "$out/cpu.md" ;;
    memcheck)  # the CUDA path through LAMMPS on one rank, under compute-sanitizer
      compute-sanitizer --tool memcheck --error-exitcode 9 "$CF_LAMMPS" --cellforce-backend cuda \
        --cellforce-precision mixed -in systems/lammps/in.lj -var cells 10 -var steps 20 -log none \
        > "$out/memcheck.log" 2>&1
      echo "memcheck: exit $? ($(grep -c 'ERROR SUMMARY: 0 errors' "$out/memcheck.log") clean summaries)" ;;
  esac
done
