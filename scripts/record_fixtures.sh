#!/usr/bin/env bash
# Regenerates the committed demonstration bags bags/fixtures/follow and bags/fixtures/avoid:
# for each, starts scara_sim, the recorder (zstd-compressed MCAP chunks; /ee_position,
# /demo/reference, /joint_states) and the demonstrator in that mode, waits for the
# demonstrator to finish (it lets go, holds still and exits 0), then stops the recorder
# (SIGINT: metadata.yaml written) and the sim. Existing fixtures are replaced.
# Usage: scripts/record_fixtures.sh [follow] [avoid]      (default: both)
# Environment: ROS_DOMAIN_ID (default 47); discovery stays on loopback.
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
# shellcheck disable=SC1091
source "$root/scripts/env.sh"
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-47}"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST

fixtures="$root/bags/fixtures"
logs=$(mktemp -d -t record-fixtures-XXXXXX)
pids=()

stop_pid() {  # stop_pid PID: SIGINT, then SIGKILL after 10 s; returns the exit code
  local pid=$1 code=0
  kill -INT "$pid" 2>/dev/null || true
  for _ in $(seq 100); do
    kill -0 "$pid" 2>/dev/null || break
    sleep 0.1
  done
  kill -KILL "$pid" 2>/dev/null || true
  wait "$pid" || code=$?
  return "$code"
}

cleanup() {
  local pid
  for pid in "${pids[@]}"; do
    kill -0 "$pid" 2>/dev/null && stop_pid "$pid" || true
  done
}
trap cleanup EXIT

record() {  # record MODE DEMONSTRATOR-PARAMETERS...
  local mode=$1
  shift
  local bag="$fixtures/$mode"
  rm -rf "$bag"
  mkdir -p "$fixtures"
  echo "[fixtures] $mode: recording into ${bag#"$root"/} (logs in $logs)" >&2
  ros2 run scara_sim scara_sim >"$logs/scara_sim-$mode.log" 2>&1 &
  local sim=$!
  pids+=("$sim")
  ros2 run hri_demo_learning recorder --ros-args -p "output:=$bag" \
    -p "topics:=[/ee_position, /demo/reference, /joint_states]" -p compression:=zstd \
    >"$logs/recorder-$mode.log" 2>&1 &
  local recorder=$!
  pids+=("$recorder")
  sleep 2
  local code=0
  ros2 run scara_sim demonstrator --ros-args -p "mode:=$mode" "$@" \
    >"$logs/demonstrator-$mode.log" 2>&1 || code=$?
  sleep 0.5
  stop_pid "$recorder" || { echo "[fixtures] recorder failed:" >&2; cat "$logs/recorder-$mode.log" >&2; exit 1; }
  stop_pid "$sim" || true
  if [ "$code" -ne 0 ]; then
    echo "[fixtures] demonstrator ($mode) exited $code:" >&2
    cat "$logs/demonstrator-$mode.log" >&2
    exit 1
  fi
  grep -h 'closed bag' "$logs/recorder-$mode.log" >&2
  du -sh "$bag" >&2
}

modes=("$@")
[ ${#modes[@]} -eq 0 ] && modes=(follow avoid)
for mode in "${modes[@]}"; do
  case $mode in
    # From scara_sim's initial pose, end-effector (0.35, 0.30) m, 0.269 m from x_r.
    follow) record follow -p "reference:=[0.45, 0.05]" ;;
    # x_r 7 mm from the initial end-effector position: the hand pushes it out to 0.183 m.
    avoid) record avoid -p "reference:=[0.355, 0.295]" ;;
    *) echo "unknown mode: $mode (follow or avoid)" >&2; exit 2 ;;
  esac
done
