#!/usr/bin/env bash
# colcon build of ros2_ws/src against the wheels in .venv (build/, install/, log/ at the root).
# Symlink install: edits to Python sources take effect without a rebuild. Skipped when neither
# the sources nor the installed lock changed since the last successful build.
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv="$root/.venv"
cd "$root"
mkdir -p "$root/log"
export PATH="$venv/bin:$PATH"
export AMENT_PREFIX_PATH="$venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export CMAKE_PREFIX_PATH="$venv${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
stamp="$root/build/.sources.sha256"
sources=$( { cat "$venv/.requirements.sha256" 2>/dev/null
             find ros2_ws/src -type f -not -path '*/__pycache__/*' -print0 | sort -z \
               | xargs -0 sha256sum; } | sha256sum | cut -d' ' -f1)
if [ -f "$root/install/setup.bash" ] && [ "$(cat "$stamp" 2>/dev/null)" = "$sources" ]; then
  exit 0
fi
printf '[setup] colcon build of ros2_ws/src\n' >&2
# make -j per core without colcon's load limit (-l): the interface package's code generation
# and compilation took 29-39 s with it (the install step before leaves the load above 2, so
# make ran one job at a time) and 22 s without.
export MAKEFLAGS="${MAKEFLAGS:--j$(nproc)}"
# The wheels' prefix has no local_setup files; colcon's warning about it is expected noise.
colcon --log-level error build --symlink-install --base-paths ros2_ws/src \
  --event-handlers console_direct- summary- status- \
  --cmake-args -DPython3_EXECUTABLE="$venv/bin/python" -DBUILD_TESTING=OFF \
  > "$root/log/build.out" 2>&1 || {
    printf '[setup] colcon build failed; its output:\n' >&2
    cat "$root/log/build.out" >&2
    exit 1
  }
# The project's own modules byte-compiled now (0.5 s): with PYTHONDONTWRITEBYTECODE set, every
# process would otherwise compile them again at import (0.1 s of CPU per node start).
"$venv/bin/python" -m compileall -q -j 0 ros2_ws/src tests scripts bench conftest.py >/dev/null
# The compiled kernels (hri_adaptive_controller.arm_kernels, hri_core.capsule_kernels) into
# numba's cache beside them now: a controller or test would otherwise compile them at its
# start (2 s). Two processes, one per core: the law's per-cycle kernels and the capsule
# distances, and the whole-body barrier (6.5 s in one process, about 3.5 s in two).
( set +u
  # shellcheck disable=SC1091
  source "$root/install/setup.bash"
  "$venv/bin/python" -c 'from hri_adaptive_controller.arm_kernels import warm_up_body_barrier
warm_up_body_barrier()' &
  barrier=$!
  "$venv/bin/python" -c 'from hri_adaptive_controller.arm_law import warm_up_law
warm_up_law()'
  wait "$barrier" )
echo "$sources" > "$stamp"
