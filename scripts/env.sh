# Source this file (`source scripts/env.sh`) for a shell in which `ros2 run PACKAGE EXECUTABLE`
# works for every executable of the project. Sets the project up first if needed.
# Every DDS process started from this shell stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE).

_hri_root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)

if [ -z "${HRI_SKIP_SETUP:-}" ]; then
  "$_hri_root/scripts/setup.sh" || return 1 2>/dev/null || exit 1
fi

export PATH="$_hri_root/.venv/bin:$PATH"
export VIRTUAL_ENV="$_hri_root/.venv"
export AMENT_PREFIX_PATH="$_hri_root/.venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
# Nodes find each other 0.1 s after start instead of 2.3 s (config/fastdds.xml says why).
export FASTRTPS_DEFAULT_PROFILES_FILE="${FASTRTPS_DEFAULT_PROFILES_FILE:-$_hri_root/config/fastdds.xml}"
export PYTHONUNBUFFERED=1
# colcon's setup scripts refer to unset variables; they must not trip a caller's `set -u`.
case $- in *u*) _hri_nounset=1; set +u ;; *) _hri_nounset= ;; esac
# shellcheck disable=SC1091
source "$_hri_root/install/setup.bash"
[ -n "$_hri_nounset" ] && set -u
# A real ROS 2 install's ros2cli wins; otherwise the project's small `ros2` (run, topic, bag).
if ! command -v ros2 >/dev/null 2>&1; then
  export PATH="$_hri_root/scripts/bin:$PATH"
fi
unset _hri_root _hri_nounset
