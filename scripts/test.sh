#!/usr/bin/env bash
# Sets the project up if needed, then runs the whole test suite: ruff, the unit tests of each
# package and the topic-level tests in tests/. The default run leaves out the groups marked
# `slow` (soak, multi-host); `scripts/test.sh --all` runs them too. Further arguments go to pytest.
#
# The tiers are markers (pytest.ini; conftest.py gives every test its tier): `pure` (no ROS
# process), `topic` (starts ROS processes; `integration` is its alias), `exclusive` (a 1 kHz
# loop with timing checks) and `slow` (only with --all). Every test has a time limit
# (pytest-timeout, pytest.ini); the pure tests beside phase 2 get a longer default (below).
#
# Two phases of topic-level tests (marker `topic`): first those not marked `exclusive`,
# in HRI_TEST_WORKERS (default 3; they wait on processes they start more than they compute, so
# three on two cores took 97 s against 128 s with two, four 104 s) pytest-xdist workers
# (worksteal: an idle worker takes tests queued for a busy one); then the `exclusive` ones (a
# 1 kHz closed loop, whose timing checks need the CPU) one at a time, and beside them the pure
# unit tests (no ROS process) at the lowest CPU priority (SCHED_IDLE, else nice 19): a
# closed-loop test keeps about 1.7 of the two cores busy, less while its processes start and
# stop, and the unit tests take what it leaves idle (beside phase 1, which keeps both cores
# busy, they slowed it by about 20 s). The unit tests' report comes at the end. The exit code
# is non-zero if any part fails. The two topic-level phases do not collect the packages' unit
# tests (HRI_TEST_SCOPE=topic, conftest.py).
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
selection='not slow'
if [ "${1:-}" = "--all" ]; then
  selection=''
  shift
fi
# shellcheck disable=SC1091
source "$root/scripts/env.sh"

echo "[test] ruff check" >&2
ruff check .

# pytest exits 5 when a part selects no test (e.g. arguments naming one test): not a failure
# of that part, but a run in which no part selects a test exits 5 like pytest.
status=0
empty=0
tally() {
  if [ "$1" -eq 5 ]; then
    empty=$((empty + 1))
  elif [ "$1" -ne 0 ]; then
    status=1
  fi
}
not_slow=${selection:+$selection and }
echo "[test] pytest, phase 1: topic-level tests not marked exclusive, ${HRI_TEST_WORKERS:-3}" \
  "workers" >&2
code=0
HRI_TEST_SCOPE=topic python -m pytest -n "${HRI_TEST_WORKERS:-3}" --dist worksteal \
  -m "${not_slow}topic and not exclusive" "$@" || code=$?
tally "$code"
echo "[test] pytest, phase 2: exclusive tests one at a time; beside them the unit tests at" \
  "the lowest priority (their report comes last)" >&2
unit_log=$(mktemp)
# SCHED_IDLE where chrt can set it: it yields a CPU to any other runnable task at once, where
# nice 19 only weighs less (the Panda's loop had its joint states stale for 0.1 s beside nice
# 19 workers).
background=(nice -n 19)
if chrt --idle 0 true 2>/dev/null; then
  background=(chrt --idle 0)
fi
# Their default time limit is 300 s instead of pytest.ini's 120: at SCHED_IDLE a test gets
# only what the loop leaves idle (the bag fuzzer took 57 s so beside a loaded phase 2).
"${background[@]}" python -m pytest -n 2 --timeout 300 -m "${not_slow}pure" "$@" \
  >"$unit_log" 2>&1 &
unit_pid=$!
# A background job of a script ignores SIGINT: end it by PID if the script ends first (^C).
trap 'kill "$unit_pid" 2>/dev/null || true; rm -f "$unit_log"' EXIT
code=0
HRI_TEST_SCOPE=topic python -m pytest -m "${not_slow}exclusive" "$@" || code=$?
tally "$code"
code=0
wait "$unit_pid" || code=$?
echo "[test] unit tests (run beside phase 2):" >&2
cat "$unit_log"
tally "$code"
if [ "$status" -ne 0 ]; then
  echo "[test] FAILED (see the summaries above)" >&2
elif [ "$empty" -eq 3 ]; then
  echo "[test] no test selected" >&2
  exit 5
fi
exit "$status"
