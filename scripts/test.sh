#!/usr/bin/env bash
# Sets the project up if needed, then runs the whole test suite: ruff, the unit tests of each
# package and the topic-level tests in tests/. The default run leaves out the groups marked
# `slow` (soak, multi-host); `scripts/test.sh --all` runs them too. Further arguments go to pytest.
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
python -m pytest "${marker[@]}" "$@"
