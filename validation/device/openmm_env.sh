# Sourced on the GPU machine: installs the carried OpenMM wheels (.whl: openmm and openmm-cuda-13
# of one version, cp312 manylinux) into /tmp/site, puts them on PYTHONPATH, and adds the folders
# holding the CUDA libraries that OpenMM's CUDA plugin needs (libcufft.so.12, libnvrtc.so.13) to
# LD_LIBRARY_PATH. Prints OpenMM's platforms and any plugin that failed to load.
if [ ! -d /tmp/site/openmm ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || { echo "openmm_env: cannot install the wheels in .whl"; return 1; }
fi
export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
for lib in libcufft.so.12 libnvrtc.so.13; do
  dir=$(dirname "$(find / -xdev -name "$lib" -not -path '*/proc/*' 2>/dev/null | head -n 1)" 2>/dev/null)
  [ -n "$dir" ] && [ "$dir" != . ] && export LD_LIBRARY_PATH=$dir${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
done
python3 - <<'PY'
import openmm
names = [openmm.Platform.getPlatform(i).getName() for i in range(openmm.Platform.getNumPlatforms())]
print("openmm", openmm.__version__, "platforms:", ", ".join(names))
for failure in openmm.Platform.getPluginLoadFailures():
    print("  plugin load failure:", failure.splitlines()[0][:200])
PY
