#!/usr/bin/env bash
# Sets the project up if needed, then runs the whole test suite: ruff, the unit tests of each
# package and the topic-level tests in tests/. The default run leaves out the groups marked
# `slow` (soak, multi-host); `scripts/test.sh --all` runs them too. Further arguments go to pytest.
# Tests run in HRI_TEST_WORKERS (default 2) pytest-xdist workers; the tests of the 1 kHz closed
# loop form one group (xdist_group 'closed_loop') that runs on one worker, one at a time, so two
# of them never share the CPUs. HRI_TEST_WORKERS=0 runs everything in one process.
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
marker=()
if [ "${1:-}" = "--all" ]; then
  marker=(-m "")
  shift
fi
# shellcheck disable=SC1091
source "$root/scripts/env.sh"

echo "[test] ruff check" >&2
ruff check .
echo "[test] pytest" >&2
python -m pytest -n "${HRI_TEST_WORKERS:-2}" --dist loadgroup "${marker[@]}" "$@"
