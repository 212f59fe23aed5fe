#!/usr/bin/env bash
# The Python module for the GPU machine's Python (3.12 there; .venv's is 3.11 here), from the CUDA
# build's static libraries, and a folder to carry with it: the module package, ASE's wheel (the GPU
# machine has numpy, h5py, pytest, CuPy and PyTorch) and the CLI (the tests' oracle).
#   bash validation/device/python_module.sh [BUILD_DIR] [PYTHON]
# (defaults: build, and pyenv's 3.12.1 where it is, as on the development machine: give the Python
# of the GPU machine's minor version otherwise).
#   carry .device/py.tar.xz; on the GPU machine:
#     cd .device && tar xJf py.tar.xz && cd .. && python3 -m pip install -q --no-index --no-deps \
#       --target /tmp/site .device/py/wheels/*.whl && PYTHONPATH=$PWD/.device/py/pkg:/tmp/site \
#       CELLFORCE_EXE=$PWD/.device/py/cellforce python3 -m pytest -q -rs -p no:cacheprovider tests/python
set -euo pipefail
build=$(realpath "${1:-build}")
python=${2:-/root/.pyenv/versions/3.12.1/bin/python3}
root=$(realpath "$(dirname "$0")/../..")
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$python" -m venv "$work/venv"
"$work/venv/bin/pip" install -q nanobind==3.1.0
tag=$("$work/venv/bin/python" -c "import sysconfig; print(sysconfig.get_config_var('EXT_SUFFIX'))")
nb=$("$work/venv/bin/python" -m nanobind --cmake_dir)/..
inc=$("$work/venv/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['include'])")
flags=(-O3 -DNDEBUG -fPIC -fvisibility=hidden -fno-stack-protector -ffunction-sections -fdata-sections -std=c++20
       -I"$inc" -I"$nb/include" -isystem "$nb/ext/robin_map/include")
g++ "${flags[@]}" -fno-strict-aliasing -DNB_BUILD -DNB_COMPACT_ASSERTIONS -c "$nb/src/nb_combined.cpp" -o "$work/nb.o"
objects=()
for source in "$root"/src/python/*.cpp; do
  g++ "${flags[@]}" -Os -fopenmp -DCELLFORCE_HAVE_CUDA -I"$root/include" -I"$build/include" -I"$root/src" \
      -I"$root/cuda" -isystem /usr/local/cuda/include -c "$source" -o "$work/$(basename "$source").o"
  objects+=("$work/$(basename "$source").o")
done
out="$root/.device/py"
rm -rf "$out" && mkdir -p "$out/pkg/cellforce" "$out/wheels"
# The link line of the build's own module (CMakeFiles/cellforce_python.dir/link.txt), its objects
# and output replaced by these.
link=$(cat "$build/CMakeFiles/cellforce_python.dir/link.txt")
libs=${link##*.cpp.o}
(cd "$build" && eval /usr/bin/c++ -fPIC -O3 -DNDEBUG -Wl,-s -Wl,--gc-sections -shared \
   -o "$out/pkg/cellforce/_cellforce$tag" "${objects[@]}" "$work/nb.o" "${libs//libnanobind-static.a/}")
cp "$root"/src/python/cellforce/*.py "$out/pkg/cellforce/"
cp "$build/cellforce" "$out/"
# The GPU machine has numpy, h5py, pytest, CuPy and PyTorch; ASE (pure Python) travels.
"$work/venv/bin/pip" download -q --no-deps --only-binary=:all: ase=="$("$root/.venv/bin/python" -c "import ase; print(ase.__version__)")" -d "$out/wheels"
(cd "$root/.device" && rm -f py.tar.xz && tar cJf py.tar.xz py)
ls -la "$root/.device/py.tar.xz"
