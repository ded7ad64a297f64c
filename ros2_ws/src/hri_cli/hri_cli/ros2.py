"""A minimal stand-in for ros2cli (`ros2 run`, `ros2 topic`, `ros2 bag`), for environments
built from the PyPI wheels: scripts/bin/ros2 runs `main()`.

ros2cli is not packaged on the Python package index. This resolves
`ros2 run PACKAGE EXECUTABLE [ARGS...]` the way ros2cli does, through the ament index
(`<prefix of PACKAGE>/lib/PACKAGE/EXECUTABLE`), and replaces itself with that executable,
passing every further argument (`--ros-args ...` included) through unchanged.

`ros2 topic` (list, info, echo, hz, pub) and `ros2 bag` (info, play) are handed to
hri_cli.topic and hri_cli.bag, which print what ros2cli and rosbag2 print for their common
forms. scripts/env.sh puts scripts/bin on PATH only when no real `ros2` is there.
"""

import importlib
import os
import sys

USAGE = 'usage: ros2 run [--prefix PREFIX] PACKAGE EXECUTABLE [ARGS ...]'
COMMANDS_USAGE = '\n'.join([
    'usage: ros2 COMMAND ...  (the project\'s stand-in for ros2cli)',
    '  ros2 run [--prefix PREFIX] PACKAGE EXECUTABLE [ARGS ...]',
    '  ros2 topic {list,info,echo,hz,pub} ...   (ros2 topic --help)',
    '  ros2 bag {info,play} ...                 (ros2 bag --help)',
])
# The verbs besides `run`, by the module whose main(argv) runs them.
VERB_MODULES = {'topic': 'hri_cli.topic', 'bag': 'hri_cli.bag'}
# What this project offers where ros2cli has a command the stand-in does not: (the command's
# first words, the one-line answer).
ALTERNATIVES = {
    ('launch',): "'ros2 launch' is not available here (launch is not on the package index): "
                 '`ros2 run hri_bringup system` starts the live loop from one YAML '
                 '(--ros-args -p config:=FILE; README, "The live system")',
    ('bag', 'record'): "'ros2 bag record' is not available here: `ros2 run hri_demo_learning "
                       'recorder --ros-args -p output:=BAG` records the demonstration topics '
                       'into a rosbag2 (MCAP) bag (-p "topics:=[/a, /b]" for others)',
}


def fail(message: str, code: int = 1) -> int:
    print(f'ros2: {message}', file=sys.stderr)
    return code


def run(argv: list[str]) -> int:
    prefix_command: list[str] = []
    if argv[:1] == ['--prefix']:
        if len(argv) < 2:
            return fail(USAGE, 2)
        prefix_command = argv[1].split()
        argv = argv[2:]
    if argv[:1] in (['-h'], ['--help']):
        print(USAGE)
        print('Runs EXECUTABLE of PACKAGE (found through the ament index) with ARGS, '
              '--ros-args included; --prefix runs it under PREFIX (e.g. "gdb -ex run --args").')
        return 0
    if len(argv) < 2:
        return fail(USAGE, 2)
    package, executable, rest = argv[0], argv[1], argv[2:]
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix
    try:
        prefix = get_package_prefix(package)
    except PackageNotFoundError:
        return fail(f'Package not found: {package}')
    path = os.path.join(prefix, 'lib', package, executable)
    if not (os.path.isfile(path) and os.access(path, os.X_OK)):
        return fail(f'No executable found: {executable} in package {package}')
    command = prefix_command + [path] + rest
    os.execvp(command[0], command)


def run_verb(verb: str, argv: list[str]) -> int:
    """`ros2 topic|bag ARGS` through its module; Ctrl-C at any moment is a clean exit 0."""
    # KeyboardInterrupt comes only before the verb has installed its own SIGINT handler
    # (e.g. while Python imports rclpy).
    try:
        module = importlib.import_module(VERB_MODULES[verb])
    except KeyboardInterrupt:
        return 0
    except ImportError as error:
        return fail(f"'ros2 {verb}' cannot load {VERB_MODULES[verb]} ({error}); "
                    'source scripts/env.sh first')
    try:
        return module.main(argv)
    except KeyboardInterrupt:
        return 0


def main() -> int:
    args = sys.argv[1:]
    if not args or args[0] in ('-h', '--help'):
        print(COMMANDS_USAGE)
        return 0 if args else 2
    if args[0] == 'run':
        return run(args[1:])
    for words, answer in ALTERNATIVES.items():
        if tuple(args[:len(words)]) == words:
            return fail(answer, 2)
    if args[0] in VERB_MODULES:
        return run_verb(args[0], args[1:])
    return fail(f"'{args[0]}' is not available here: this environment provides only "
                "'ros2 run', 'ros2 topic' and 'ros2 bag' (ros2cli is not on the package "
                'index); install ROS 2 Jazzy from its apt repository for the full command '
                'line', 2)
