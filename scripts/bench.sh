#!/usr/bin/env bash
# Benchmarks (measurements, not tests): sets the project up if needed, then runs, one after
# another so that they do not disturb each other,
#   step      bench/bench_step.py       one control step in-process: the compiled step and the
#                                       numpy reference on seeded random states, per task
#   learning  bench/bench_learning.py   fits on the fixtures (Gauss-Newton vs trf), fit time vs
#                                       samples, learning from a replayed 1M-message bag
#   loop      bench/bench_loop.py       the trivial rclpy echo floor and scara_sim +
#                                       event_manager + controller + hand_sim in alternating
#                                       windows (5 rounds of an echo window, then a loop
#                                       window; 20 s of each in all): joint state -> command
#                                       latency and its ratio to the echo's round trip (pooled,
#                                       and its spread over the rounds), deadline misses, CPU
#                                       (and its ratio to the echo's)
#   loop_load the same with N busy processes (`--load N`, started and ended by the bench)
#   recorder  bench/bench_recorder.py   60 s of JointState at 1 kHz: published vs recorded
#   sim       bench/bench_sim.py        scara_sim alone, 10 s
# and writes their figures with the machine's description into bench/results.json and a
# table on stdout. `scripts/bench.sh --quick` shortens every piece (a smoke run); `--load N`
# adds the loop_load piece.
# `--robot panda` runs the robot's pieces only, the Panda beside the SCARA in one run: step
# (the law's step on both arms), loop (the SCARA's, as above) and loop_panda
# (arm_sim robot:=panda + event_manager + controller robot:=panda + hand_sim in 3-D), and
# prints both robots' figures against the Panda's bars (/joint_states >= 995 Hz, step median
# <= 100 us, state -> command p99 <= 1.5 x the echo's, controller and sim <= 40 % of a core);
# learning, recorder and sim are skipped. Without --robot (or --robot scara): as before.
# Each piece ends the processes it started; a piece that fails is reported and the others
# still run; the exit code is non-zero if any piece failed (the recorder's also if it lost a
# message). ROS domains: BENCH_DOMAIN_BASE (default 90) .. +5.
# `--tree PATH` benchmarks the nodes of another checkout (set up: its .venv and install/)
# with this checkout's bench scripts: the loop pieces start that checkout's nodes (its
# `scripts/env.sh` environment); step, learning, recorder and sim are run with its Python and
# packages. Given twice or more (e.g. an old main and a new main), the loop pieces alternate
# the checkouts window by window in one run, each loop window after an echo window of its own,
# and the table has a row per checkout; the other pieces run for the first --tree only.
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
usage() {
  echo "usage: scripts/bench.sh [--quick] [--load N] [--robot scara|panda] [--tree PATH]..."
}
quick=0
load=0
robot=scara
trees=()
while [ $# -gt 0 ]; do
  case "$1" in
    --quick) quick=1 ;;
    --load)
      load=${2:-}
      shift
      [[ "$load" =~ ^[1-9][0-9]*$ ]] || { echo "--load needs a positive integer" >&2; exit 2; }
      ;;
    --robot)
      robot=${2:-}
      shift
      [[ "$robot" =~ ^(scara|panda)$ ]] || { echo "--robot needs scara or panda" >&2; exit 2; }
      ;;
    --tree)
      [ -n "${2:-}" ] && [ -d "$2" ] || { echo "--tree needs a checkout's folder" >&2; exit 2; }
      trees+=("$(cd "$2" && pwd)")
      shift
      ;;
    -h | --help) usage; exit 0 ;;
    *) usage >&2; exit 2 ;;
  esac
  shift
done

# Set up as scripts/test.sh does; the build step under the colcon lock when flock exists, so
# that it never runs at the same time as another build of this checkout.
if command -v flock >/dev/null 2>&1; then
  flock /tmp/colcon.lock "$root/scripts/setup.sh"
  export HRI_SKIP_SETUP=1
fi
# shellcheck disable=SC1091
source "$root/scripts/env.sh"
# The pieces that are not the loop run in the first --tree's environment (its .venv, its
# install/), with this checkout's bench scripts; the loop pieces stay in this one's and start
# each tree's nodes themselves (bench_loop.py --tree).
tree_args=()
other=()
if [ "${#trees[@]}" -gt 0 ]; then
  for tree in "${trees[@]}"; do
    [ -f "$tree/install/setup.bash" ] && [ -x "$tree/.venv/bin/python" ] || {
      echo "[bench] $tree is not set up: run its scripts/setup.sh first" >&2; exit 2; }
    tree_args+=(--tree "$tree")
  done
  other=(env -i HOME="$HOME" PATH=/usr/local/bin:/usr/bin:/bin HRI_SKIP_SETUP=1 bash -c
         'source "$1/scripts/env.sh" >/dev/null && shift && exec "$@"' bash "${trees[0]}")
fi

domain=${BENCH_DOMAIN_BASE:-90}
if [ "$quick" = 1 ]; then
  learning_args=(--repeats 1 --sizes 10000 100000 --replay-seconds 20)
  loop_seconds=5; recorder_seconds=5; sim_seconds=3; step_calls=2000
else
  learning_args=(--repeats 3)
  loop_seconds=20; recorder_seconds=60; sim_seconds=10; step_calls=20000
fi

work=$(mktemp -d -t hri-bench-XXXXXX)
failed=()

# run_piece NAME TIME_LIMIT COMMAND...: stdout (JSON) to $work/NAME.json, stderr to NAME.log.
# At the time limit the piece gets SIGINT (its `finally` ends its nodes), SIGKILL 30 s later.
run_piece() {
  local name=$1 limit=$2 started code=0
  shift 2
  cut -d' ' -f1-3 /proc/loadavg > "$work/$name.load"
  printf '[bench] %s: %s\n' "$name" "$*" >&2
  started=$(date +%s)
  timeout --signal=INT --kill-after=30 "$limit" "$@" > "$work/$name.json" \
    2> "$work/$name.log" || code=$?
  echo "$code" > "$work/$name.code"
  printf '[bench] %s: exit %s after %s s\n' "$name" "$code" "$(( $(date +%s) - started ))" >&2
  if [ "$code" != 0 ]; then
    failed+=("$name")
    tail -n 15 "$work/$name.log" >&2 || true
  fi
}

# skip_piece NAME REASON: a piece not run in this mode.
skip_piece() {
  printf '{"skipped": "%s"}\n' "$2" > "$work/$1.json"
  echo 0 > "$work/$1.code"
  cut -d' ' -f1-3 /proc/loadavg > "$work/$1.load"
}

run_piece step 600 "${other[@]}" python "$root/bench/bench_step.py" --json \
  --calls "$step_calls" --robot "$robot"
if [ "$robot" = panda ]; then
  skip_piece learning '--robot panda: the robot pieces only'
else
  run_piece learning 1800 "${other[@]}" python "$root/bench/bench_learning.py" --json \
    "${learning_args[@]}"
fi
# A loop piece's time: its windows (3 per round and tree: echo, loop, loop probed) and about
# 15 s a round and tree to start and stop the loop.
loop_limit=$(( (3 * loop_seconds + 15 * 5) * (${#trees[@]} > 0 ? ${#trees[@]} : 1) + 120 ))
run_piece loop "$loop_limit" python bench/bench_loop.py --json \
  --duration "$loop_seconds" --domain-id "$domain" --echo-domain-id $((domain + 5)) \
  "${tree_args[@]}"
if [ "$robot" = panda ]; then
  run_piece loop_panda "$loop_limit" python bench/bench_loop.py --json \
    --duration "$loop_seconds" --domain-id $((domain + 4)) --echo-domain-id $((domain + 5)) \
    --robot panda "${tree_args[@]}"
else
  skip_piece loop_panda 'no --robot panda given'
fi
if [ "$load" -gt 0 ]; then
  run_piece loop_load "$loop_limit" python bench/bench_loop.py --json \
    --duration "$loop_seconds" --domain-id $((domain + 3)) --echo-domain-id $((domain + 5)) \
    --load "$load" "${tree_args[@]}"
else
  skip_piece loop_load 'no --load N given'
fi
if [ "$robot" = panda ]; then
  skip_piece recorder '--robot panda: the robot pieces only'
  skip_piece sim '--robot panda: the robot pieces only'
else
  run_piece recorder $((recorder_seconds + 180)) "${other[@]}" python \
    "$root/bench/bench_recorder.py" --json --seconds "$recorder_seconds" \
    --domain-id $((domain + 1))
  run_piece sim $((sim_seconds + 120)) "${other[@]}" python "$root/bench/bench_sim.py" \
    --json --duration "$sim_seconds" --domain-id $((domain + 2))
fi

results_file=$root/bench/results.json
[ "$robot" = panda ] && results_file=$root/bench/results-panda.json
python - "$work" "$results_file" "$quick" <<'PY'
"""Collect the pieces' JSON with the machine's description; print one table."""
import datetime
import json
import platform
import subprocess
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

work, output, quick = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3] == '1'
PIECES = ('step', 'learning', 'loop', 'loop_panda', 'loop_load', 'recorder', 'sim')
# The Panda's speed bars (the issue's): /joint_states rate, step median, loop p99 / echo p99,
# CPU of the controller and of the sim.
BARS = {'rate_hz': 995.0, 'step_median_us': 100.0, 'p99_ratio': 1.5, 'cpu_percent': 40.0}


def package_version(name):
    try:
        return version(name)
    except PackageNotFoundError:
        return None


def cpu_model():
    for line in Path('/proc/cpuinfo').read_text().splitlines():
        if line.startswith('model name'):
            return line.split(':', 1)[1].strip()
    return platform.processor() or None


results = {
    'machine': {
        'nproc': int(subprocess.run(['nproc'], capture_output=True, text=True).stdout),
        'cpu_model': cpu_model(),
        'python': platform.python_version(),
        'rclpy': package_version('rclpy'),
        'rclpy_wheel': package_version('ros-rclpy'),
        'date': datetime.datetime.now().astimezone().isoformat(timespec='seconds'),
        'note': 'shared machine: other sessions may run tests at the same time; '
                'load_average_before is /proc/loadavg before each piece',
    },
    'quick': quick,
}
for name in PIECES:
    code = int((work / f'{name}.code').read_text())
    text = (work / f'{name}.json').read_text()
    try:
        piece = json.loads(text)
    except json.JSONDecodeError:
        log = (work / f'{name}.log').read_text(errors='replace').strip().splitlines()
        piece = {'error': 'no JSON output', 'log_tail': log[-10:]}
    piece['exit_code'] = code
    piece['load_average_before'] = (work / f'{name}.load').read_text().split()
    results[name] = piece
output.write_text(json.dumps(results, indent=2) + '\n')

rows = []


def row(section, item, value):
    rows.append((section, item, value))


def fmt(value, unit=''):
    return 'n/a' if value is None else f'{value:g}{unit}'


def spread(stats, unit='ms'):
    return (f"median {fmt(stats['median_ms'])} / p99 {fmt(stats['p99_ms'])} / "
            f"max {fmt(stats['max_ms'])} {unit}")


def min_med(stats, unit='s'):
    return f"{stats['min']:g} / {stats['median']:g} {unit}"


m = results['machine']
row('machine', 'cpu', f"{m['nproc']} x {m['cpu_model']}")
row('machine', 'software', f"Python {m['python']}, rclpy {m['rclpy']} "
    f"(wheel ros-rclpy {m['rclpy_wheel']})")
row('machine', 'date', f"{m['date']}{' (--quick)' if quick else ''}")
row('machine', 'note', 'shared with other sessions running tests: compare within one run')

for name in PIECES:
    piece = results[name]
    load = ' '.join(piece['load_average_before'])
    if 'error' in piece:
        row(name, 'FAILED', f"exit {piece['exit_code']}: {piece['error']}")
        continue
    if 'skipped' in piece:
        continue
    row(name, 'load average before', load)
    if piece['exit_code'] != 0:
        row(name, 'exit code', str(piece['exit_code']))
    if name == 'step':
        for robot, tasks in piece['robots'].items():
            for task, r in tasks.items():
                step, numpy_step = r['step'], r['numpy_step']
                row(name, f'{robot} {task}: step', f"median {step['median_us']} / p99 "
                    f"{step['p99_us']} / max {step['max_us']} us ({piece['calls']:,} calls)")
                row(name, f'{robot} {task}: numpy step', f"median {numpy_step['median_us']} "
                    f"us ({r['numpy_over_compiled']} x the compiled step's)")
    elif name == 'learning':
        row(name, 'rounds', f"{piece['repeats']} (times min / median)")
        for task, by_method in piece['fixtures'].items():
            for method, r in by_method.items():
                if 'refused' in r:  # the learner refuses a fit it cannot trust (max_cost)
                    row(name, f'{task} {method}', f"refused: {r['refused']}")
                    continue
                row(name, f'{task} {method}',
                    f"{r['iterations']} it, C {r['cost']:.4g}, "
                    f"{'converged' if r['converged'] else 'NOT converged'}, "
                    f"a1 {r['a1']:.4g} a2 {r['a2']:.4g}; fit {min_med(r['fit_s'])}, "
                    f"read+learn {min_med(r['total_s'])}")
        s = piece['scaling']
        for size, by_method in s['sizes'].items():
            row(name, f'fit {int(size):,} samples',
                '; '.join(f"{meth} {min_med(r['fit_s'])} ({r['iterations']} it)"
                          for meth, r in by_method.items()))
        if 'replay' in piece:
            r = piece['replay']
            row(name, f"replay {r['joint_states']:,} joint states",
                f"learner node {r['learner_process_s']} s start to exit; "
                f"read {r['read_s']} s, learn_from_bags {r['learn_total_s']} s "
                f"(read + energy + identification + fit; fit {r['fit_s']} s, "
                f"{r['iterations']} it, {r['method']}); bag {r['bag_mb']} MB written in "
                f"{r['write_s']} s; d2 {r['d2']} m")
    elif name in ('loop', 'loop_panda', 'loop_load'):
        j, c = piece['joint_states'], piece['controller']
        row(name, 'busy processes', str(piece['load_processes']))
        row(name, 'nodes run with', f"realtime_priority {piece.get('realtime_priority')}, "
            f"cpu_wakeup_latency {piece.get('cpu_wakeup_latency')} us")
        link = piece['state_to_command']
        if 'latency' in link:
            row(name, 'joint state -> command (probe)', spread(link['latency']))
            row(name, 'deadline misses (> 1.5 ms)', f"{link['deadline_miss_percent']} % of "
                f"{link['states']} states; without control {link['without_control_percent']} %")
        echo = piece.get('echo')
        if echo:
            row(name, 'echo floor round trip', spread(echo['round_trip']) +
                f"; echo CPU {echo['cpu_percent']} %")
            by_round = piece.get('latency_p99_ratio_rounds')
            row(name, 'loop p99 / echo round-trip p99', fmt(piece.get('latency_p99_ratio'))
                + (f" pooled; per round {by_round['min']:g}-{by_round['max']:g} (median "
                   f"{by_round['median']:g})" if by_round else ''))
            row(name, 'CPU / echo CPU', ', '.join(
                f'{k} {v}' for k, v in piece.get('cpu_vs_echo', {}).items()))
        row(name, 'windows', f"{piece['duration_s']} s of loop in {piece.get('windows', 1)} "
            f"windows, each after an echo window; {piece.get('tree', '')}")
        for tree, other in piece.get('trees', {}).items():
            latency = other['state_to_command'].get('latency', {})
            by_round = other.get('latency_p99_ratio_rounds') or {}
            row(name, f'checkout {tree}', f"p99 {fmt(latency.get('p99_ms'))} ms, ratio "
                f"{fmt(other.get('latency_p99_ratio'))} (rounds {fmt(by_round.get('min'))}-"
                f"{fmt(by_round.get('max'))}); controller "
                f"{fmt(other['cpu_percent'].get('controller'))} %, CPU / echo "
                f"{other.get('cpu_vs_echo')}")
        row(name, '/joint_states rate', f"{j['achieved_rate_hz']} Hz received; sim time / "
            f"wall {fmt(j['sim_realtime_factor'])}")
        row(name, '/joint_states period (stamps)', spread(j['stamp_period']))
        row(name, '/joint_states period (receive)', spread(j['receive_period']))
        row(name, 'controller rate', f"median {fmt(c['rate_hz_median'])} Hz, "
            f"min {fmt(c['rate_hz_min'])} Hz")
        row(name, 'controller deadline misses', f"{c['deadline_misses']} "
            f"({fmt(c['deadline_miss_percent'])} % of ticks); status ok "
            f"{fmt(c['ok_fraction'])}")
        row(name, 'input_age (stamp -> command)', spread(c['input_age']))
        row(name, 'CPU % of one core', ', '.join(f'{k} {v}' for k, v in
                                                 piece['cpu_percent'].items()))
        row(name, 'CPU, probe attached', ', '.join(f'{k} {v}' for k, v in
                                                   piece['cpu_percent_probed'].items()))
        row(name, 'host steal', f"{fmt(piece.get('host_steal_percent'))} % of the CPUs' "
            f"time; {fmt(piece.get('host_steal_percent_probed'))} % with the probe attached")
        if 'sim_summary' in piece:
            s = piece['sim_summary']
            row(name, 'sim timing (whole run)', f"{s['late_ticks']} late ticks, "
                f"{s['dropped_steps']} dropped steps in {s['ticks']} ticks")
    elif name == 'recorder':
        row(name, 'published / recorded', f"{piece['published']:,} / {piece['recorded']:,} "
            f"in {piece['seconds']:g} s at {piece['achieved_rate_hz']:.1f} Hz")
        row(name, 'lost', f"{piece['lost']} ({piece['loss_percent']:.3f} %), duplicates "
            f"{piece['duplicates']}")
        row(name, 'recorder CPU', f"{piece['recorder_cpu_percent']:.1f} % of one core")
        row(name, 'bag', f"{piece['bag_bytes'] / 1e6:.2f} MB "
            f"({piece['bag_bytes_per_message']:.0f} B/message)")
    elif name == 'sim':
        row(name, 'rate', f"{piece['achieved_rate_hz']} Hz in {piece['duration_s']} s")
        row(name, 'period (stamps)', spread(piece['stamp_period']))
        row(name, 'period (receive)', spread(piece['receive_period']))
        row(name, 'sim CPU', f"{piece['sim_cpu_percent']} % of one core")
        if 'sim_summary' in piece:
            s = piece['sim_summary']
            row(name, 'sim timing (whole run)', f"{s['late_ticks']} late ticks, "
                f"{s['dropped_steps']} dropped steps in {s['ticks']} ticks")



def robot_figures(loop, step, robot):
    """The bar figures of one robot's loop piece and step piece (None where missing)."""
    if not loop or 'error' in loop or 'skipped' in loop:
        return None
    sim = 'arm_sim' if robot == 'panda' else 'scara_sim'
    steps = [r['step']['median_us'] for r in step.get('robots', {}).get(robot, {}).values()]
    return {'rate_hz': loop['joint_states']['achieved_rate_hz'],
            'step_median_us': max(steps) if steps else None,
            'p99_ratio': loop.get('latency_p99_ratio'),
            'controller_cpu': loop['cpu_percent'].get('controller'),
            'sim_cpu': loop['cpu_percent'].get(sim)}


panda = robot_figures(results['loop_panda'], results['step'], 'panda')
if panda is not None:
    scara = robot_figures(results['loop'], results['step'], 'scara') or {}
    results['panda_vs_scara'] = {'panda': panda, 'scara': scara, 'bars': BARS}
    output.write_text(json.dumps(results, indent=2) + '\n')
    checks = (('/joint_states rate (Hz)', 'rate_hz', 'rate_hz', '>='),
              ('step median, slowest task (us)', 'step_median_us', 'step_median_us', '<='),
              ('state -> command p99 / echo p99', 'p99_ratio', 'p99_ratio', '<='),
              ('controller CPU (% of a core)', 'controller_cpu', 'cpu_percent', '<='),
              ('sim CPU (% of a core)', 'sim_cpu', 'cpu_percent', '<='))
    for label, key, bar_key, sense in checks:
        value, bar = panda[key], BARS[bar_key]
        met = value is not None and (value >= bar if sense == '>=' else value <= bar)
        row('panda vs scara', label, f"panda {fmt(value)} (bar {sense} {bar:g}: "
            f"{'met' if met else 'MISSED'}); scara {fmt(scara.get(key))}")

width = max(len(item) for _, item, _ in rows)
previous = None
for section, item, value in rows:
    if section != previous:
        print(f'\n{section.upper()}')
        previous = section
    print(f'  {item:<{width}}  {value}')
print(f'\nwritten: {output}')
PY

if [ "${#failed[@]}" -gt 0 ]; then
  echo "[bench] failed: ${failed[*]}; their output is in $work" >&2
  exit 1
fi
rm -rf "$work"
