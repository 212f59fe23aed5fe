#!/usr/bin/env bash
# cellforce-lammps for the GPU machine, which has Open MPI (4.1, libmpi.so.40, the ABI of Debian's
# 4.1 here) but no LAMMPS: the program, the CLI, Debian's `lmp` (LAMMPS's own, the baseline) and the
# shared libraries they need beyond the C and C++ runtimes, in one folder to carry.
#   bash validation/device/lammps_bundle.sh [BUILD_DIR]      -> .device/lammps.tar.xz
# On the GPU machine: source validation/device/lammps_env.sh (unpacks it, puts on LD_LIBRARY_PATH
# only the libraries that machine lacks, and names the binaries).
set -euo pipefail
build=$(realpath "${1:-build}")
root=$(realpath "$(dirname "$0")/../..")
out="$root/.device/lammps"
rm -rf "$out" && mkdir -p "$out/bin" "$out/libs"
strip -o "$out/bin/cellforce-lammps" "$build/cellforce-lammps"
strip -o "$out/bin/cellforce" "$build/cellforce"
cp /usr/bin/lmp "$out/bin/lmp"
# Every library the three load, except the C and C++ runtimes (the GPU machine's are newer).
for binary in "$out"/bin/*; do ldd "$binary"; done | awk '$2 == "=>" && $3 ~ /^\// { print $3 }' | sort -u |
  grep -Ev '/(libc|libm|libdl|librt|libpthread|libstdc\+\+|libgcc_s|libcuda)\.so' |
  while read -r lib; do cp -L "$lib" "$out/libs/$(basename "$lib")"; done
(cd "$root/.device" && rm -f lammps.tar.xz && tar cJf lammps.tar.xz lammps)
du -sh "$out" "$root/.device/lammps.tar.xz"
