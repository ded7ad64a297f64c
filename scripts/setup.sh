#!/usr/bin/env bash
# Sets up the project on this machine, idempotently: a virtual environment with the pinned
# ROS 2 Jazzy wheels and tools (requirements.lock), the wheels' CMake exports pointed at this
# machine's headers, and a colcon build of ros2_ws/src. A second run only rebuilds what changed.
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv="$root/.venv"
lock="$root/requirements.lock"
stamp="$venv/.requirements.sha256"

say() { printf '[setup] %s\n' "$*" >&2; }

find_python() {
  local candidate
  for candidate in "${HRI_PYTHON:-}" python3.11 python3; do
    [ -n "$candidate" ] || continue
    command -v "$candidate" >/dev/null 2>&1 || continue
    if "$candidate" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
      command -v "$candidate"
      return 0
    fi
  done
  return 1
}

want=$(sha256sum "$lock" | cut -d' ' -f1)
if [ ! -x "$venv/bin/python" ] || [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  python=$(find_python) || {
    say "CPython 3.11 is required (the ROS 2 Jazzy wheels are cp311); set HRI_PYTHON to one"
    exit 1
  }
  say "creating the virtual environment in $venv with $python"
  "$python" -m venv "$venv"
  say "installing the pinned packages of requirements.lock"
  pip_install() {
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check --require-virtualenv "$@"
  }
  # uv (pinned in the lock, bootstrapped with pip) installs the ~180 wheels in parallel and
  # byte-compiles them: seconds instead of pip's minute. It hard-links the files from its cache
  # (16-18 s for the whole set-up of the environment, against 39 s copying them); nothing here
  # edits an installed file in place (fix_wheel_cmake_paths.py writes new files and renames
  # them over the old), so the cache keeps its originals. Where the cache is on another file
  # system uv copies instead. The lock is the whole resolved set, so no resolution
  # (--no-deps); `uv pip check` proves it complete. uv does not read pip.conf: it takes the
  # system's CA store and UV_INDEX_URL; where that is not enough (a proxy or mirror configured
  # for pip only), pip installs the same pins.
  pip_install "$(grep -E '^uv==' "$lock")"
  if ! "$venv/bin/uv" pip install --quiet --system-certs --python "$venv/bin/python" \
      --no-deps --compile-bytecode --link-mode hardlink -r "$lock"; then
    say "uv could not install the lock (above); installing it with pip instead"
    pip_install -r "$lock"
  fi
  "$venv/bin/uv" pip check --quiet --python "$venv/bin/python"
  "$venv/bin/python" "$root/scripts/fix_wheel_cmake_paths.py" >&2
  echo "$want" > "$stamp"
fi

"$root/scripts/build.sh"
