#!/usr/bin/env bash
# Sets the project up if needed, then runs the whole test suite: ruff, the unit tests of each
# package and the topic-level tests in tests/. The default run leaves out the groups marked
# `slow` (soak, multi-host); `scripts/test.sh --all` runs them too. Further arguments go to pytest.
#
# The tiers are markers (pytest.ini; conftest.py gives every test its tier): `pure` (no ROS
# process), `topic` (starts ROS processes; `integration` is its alias), `exclusive` (a 1 kHz
# loop with timing checks) and `slow` (only with --all). Every test has a time limit
# (pytest-timeout, pytest.ini).
#
# The unit tests (marker `pure`, no ROS process) run from the start in two workers in the
# background (worksteal: a long test left to the end no longer holds one worker alone; 89 s
# against 100 s alone), at the lowest priority: nice 19 in a session of their own whose autogroup is
# set to nice 19 too (Linux shares the CPU between sessions first, and each node a test starts
# has its own session, so a plain nice 19 counted for nothing against them). They take the CPU
# the topic-level phases leave, and their output is printed once they are done.
# Phase 1: the topic-level tests not marked `exclusive`, in HRI_TEST_WORKERS (default 3 on two
# cores: its tests mostly wait for messages; 121 s against 151 s with 2) pytest-xdist
# workers (worksteal; tests marked `first`, the long ones, start first).
# Phase 2: the `exclusive` ones (a 1 kHz closed loop, whose timing checks need the CPU), one
# at a time.
# The exit code is non-zero if any part fails. The topic-level phases do not collect the
# packages' unit tests (HRI_TEST_SCOPE, conftest.py).
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
# pytest keeps the test modules it rewrites (its assert messages) in __pycache__ only where
# bytecode may be written: without that every pytest process and xdist worker rewrote all
# the modules it collects again (1.2 s of the 2.9 s a topic phase's collection took). The
# build writes the project's bytecode already (scripts/build.sh); __pycache__ is ignored by git.
unset PYTHONDONTWRITEBYTECODE
# The topic-level phases hold no property test: hypothesis's pytest plugin would still import
# hypothesis for its end-of-run summary (1.5 s in each phase).
topic_plugins=(-p no:hypothesispytest)

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
unit_log=$(mktemp)
unit_pid=
# An interrupted run does not leave the unit tests running.
trap 'if [ -n "$unit_pid" ]; then kill "$unit_pid" 2>/dev/null || true; fi; rm -f "$unit_log"' \
  EXIT
echo "[test] pytest, the unit tests (no ROS process): two workers at nice 19, in the" \
  "background" >&2
# shellcheck disable=SC2016
setsid bash -c 'echo 19 > /proc/self/autogroup 2> /dev/null || true; exec "$@"' unit \
  env HRI_TEST_BACKGROUND=1 nice -n 19 python -m pytest -n 2 --dist worksteal \
  -m "${not_slow}pure" "$@" \
  > "$unit_log" 2>&1 &
unit_pid=$!
echo "[test] pytest, phase 1: topic-level tests not marked exclusive, ${HRI_TEST_WORKERS:-3}" \
  "workers" >&2
code=0
HRI_TEST_SCOPE=topic python -m pytest "${topic_plugins[@]}" -n "${HRI_TEST_WORKERS:-3}" \
  --dist worksteal \
  -m "${not_slow}topic and not exclusive" "$@" || code=$?
tally "$code"
echo "[test] pytest, phase 2: exclusive tests one at a time" >&2
code=0
HRI_TEST_SCOPE=topic python -m pytest "${topic_plugins[@]}" -m "${not_slow}exclusive" "$@" \
  || code=$?
tally "$code"
code=0
wait "$unit_pid" || code=$?
unit_pid=
echo "[test] the unit tests' output:" >&2
cat "$unit_log"
tally "$code"
if [ "$status" -ne 0 ]; then
  echo "[test] FAILED (see the summaries above)" >&2
elif [ "$empty" -eq 3 ]; then
  echo "[test] no test selected" >&2
  exit 5
fi
exit "$status"
