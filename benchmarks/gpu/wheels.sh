#!/usr/bin/env bash
# Download, here, the wheels that the GPU machine lacks, into .whl/ at the repository root; run.sh installs them there
# with --no-index --no-deps. That machine has Python 3.12 with JAX 0.11.2 for CUDA 13, flax, optax, chex, orbax, rich,
# matplotlib, imageio, numpy, scipy, pandas and onnx, and cannot reach a registry, so every other module that canter
# (mjx and brax backends) and Brax's own PPO import comes from here. The folder travels with the device command
# (`carry: [".whl"]`, 64 MiB at most), so the tree and the wheels together must stay under 64 MiB: the archived runs
# are larger than that, and `bash benchmarks/gpu/aside.sh on` keeps them off the device (aside.sh).
#
#   bash benchmarks/gpu/wheels.sh          # then: du -sh .whl
set -euo pipefail
cd "$(dirname "$0")/../.."
mkdir -p .whl
# A wheel left from an earlier pin would be installed beside the new one, and pip refuses the pair.
rm -f .whl/*.whl
# Keep the wheels out of git (a local exclude, not .gitignore: they are a per-machine download).
exclude=.git/info/exclude
mkdir -p "$(dirname "$exclude")"
grep -qxF "/.whl/" "$exclude" 2>/dev/null || echo "/.whl/" >>"$exclude"

# name==version: canter's pins where it has them (pyproject.toml), else the versions tested with them here.
WHEELS=(
    mujoco==3.6.0 mujoco-mjx==3.6.0 glfw==2.11.0   # MJX physics; mujoco imports glfw
    brax==0.14.2 jaxopt==0.8.5 ml_collections==1.1.0 trimesh==5.2.0   # Brax's envs and PPO
    gymnasium==1.4.0 farama-notifications==0.0.6 cloudpickle==3.1.3   # the mjx backend reads Gymnasium's XML
    tensorboardX==2.6.5   # canter's logger
    filelock==4.3.1   # JAX's bounded compilation cache (canter.core.runtime.use_compile_cache)
)

PLATFORMS=(manylinux_2_28_x86_64 manylinux_2_27_x86_64 manylinux_2_17_x86_64 manylinux2014_x86_64 manylinux1_x86_64)
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    "${PLATFORMS[@]/#/--platform=}" -d .whl "${WHEELS[@]}"

# mujoco-mjx ships 6.5 MiB of test models that nothing here reads, and the tree and the wheels travel within 64 MiB.
python3 - .whl/mujoco_mjx-*.whl <<'PY'
import sys
import zipfile
from pathlib import Path

wheel = Path(sys.argv[1])
slim = wheel.with_suffix(".slim")
drop = "mujoco/mjx/test_data/"
with zipfile.ZipFile(wheel) as src, zipfile.ZipFile(slim, "w", zipfile.ZIP_DEFLATED) as dst:
    for item in src.infolist():
        if item.filename.startswith(drop):
            continue
        data = src.read(item)
        if item.filename.endswith(".dist-info/RECORD"):
            kept = [line for line in data.decode().splitlines(keepends=True) if not line.startswith(drop)]
            data = "".join(kept).encode()
        dst.writestr(item, data)
slim.replace(wheel)
PY
ls -1 .whl
du -sh .whl
bash benchmarks/gpu/aside.sh size || true  # says what to do when the tree and the wheels are over the limit
