#!/usr/bin/env bash
# Sets the project up if needed, then runs the whole test suite: ruff, the unit tests of each
# package and the topic-level tests in tests/. The default run leaves out the groups marked
# `slow` (soak, multi-host); `scripts/test.sh --all` runs them too. Further arguments go to pytest.
#
# Two phases: first every test not marked `exclusive`, in HRI_TEST_WORKERS (default 2)
# pytest-xdist workers (worksteal: an idle worker takes tests queued for a busy one, so a
# long test late in the queue does not leave the other worker idle); then the `exclusive` ones
# (the 1 kHz closed loop, whose timing checks need the CPUs to themselves) one at a time. The exit code is non-zero if either phase fails.
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

# pytest exits 5 when a phase selects no test (e.g. arguments naming one test): not a failure
# of that phase, but a run in which neither phase selects a test exits 5 like pytest.
status=0
empty=0
phase() {
  local code=0
  python -m pytest "$@" || code=$?
  if [ "$code" -eq 5 ]; then
    empty=$((empty + 1))
  elif [ "$code" -ne 0 ]; then
    status=1
  fi
}
echo "[test] pytest, phase 1: tests not marked exclusive, ${HRI_TEST_WORKERS:-2} workers" >&2
phase -n "${HRI_TEST_WORKERS:-2}" --dist worksteal -m "${selection:+$selection and }not exclusive" "$@"
echo "[test] pytest, phase 2: exclusive tests, one at a time" >&2
phase -m "${selection:+$selection and }exclusive" "$@"
if [ "$status" -ne 0 ]; then
  echo "[test] FAILED (see the phase summaries above)" >&2
elif [ "$empty" -eq 2 ]; then
  echo "[test] no test selected" >&2
  exit 5
fi
exit "$status"
