# Sourced on the GPU machine from the repository root, with .device/lammps.tar.xz carried (made by
# validation/device/lammps_bundle.sh): unpacks it, links into .device/lammps/use the libraries the
# machine lacks (and only those: its own Open MPI, FFTW and the rest stay), and exports
# LD_LIBRARY_PATH, CF_LAMMPS (cellforce-lammps), CF_LMP (LAMMPS's lmp), CF_CLI (cellforce) and
# MPIRUN (Open MPI's mpirun, allowed to run as root).
(cd .device && tar xJf lammps.tar.xz)
bundle=$PWD/.device/lammps
mkdir -p "$bundle/use"
export LD_LIBRARY_PATH=$bundle/use${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
for round in 1 2 3 4 5; do
  missing=$(for b in "$bundle"/bin/*; do ldd "$b"; done | awk '$3 == "not" { print $1 }' | sort -u)
  [ -z "$missing" ] && break
  for lib in $missing; do
    if [ -e "$bundle/libs/$lib" ]; then ln -sf "../libs/$lib" "$bundle/use/$lib"
    else echo "lammps_env: $lib is missing and not in the bundle" >&2; fi
  done
done
echo "lammps_env: carried libraries used: $(ls "$bundle/use" | tr '\n' ' ')"
export CF_LAMMPS=$bundle/bin/cellforce-lammps CF_LMP=$bundle/bin/lmp CF_CLI=$bundle/bin/cellforce
export MPIRUN="mpirun --allow-run-as-root -x LD_LIBRARY_PATH"
