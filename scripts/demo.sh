#!/usr/bin/env bash
# The main job: sets the project up if needed, then runs paper Section IV in simulation
# (record demonstrations, learn, run the behaviours closed-loop, write report/).
# Options: --quick (shorter runs; the SCARA only), --robot scara|panda (one robot; the Panda
# in 3-D, every stage, into OUT/panda/; default: the SCARA, then a short Panda run),
# --out DIR (default report/). Its ROS domain: HRI_DEMO_DOMAIN_ID (not ROS_DOMAIN_ID; --help).
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
# shellcheck disable=SC1091
source "$root/scripts/env.sh"
exec python "$root/scripts/demo.py" "$@"
