"""The `system` node: the live loop started as child processes from one YAML file.

    ros2 run hri_bringup system [--ros-args -p config:=PATH]

The file (parameter `config`; default this package's installed config/system.yaml) is a
standard ROS 2 parameters file, one section per node:

    system:                  # this node
      ros__parameters:
        nodes: [scara_sim, event_manager, controller, event_detector, hand_sim]  # + recorder
        log_dir: ""          # "" = <ROS log directory>/hri_system_<date-time>_<pid>
        echo_output: true    # the children's output on this stdout, lines prefixed [node]
        stop_timeout: 5.0    # s from SIGTERM to SIGKILL when the children are stopped
    hand_sim:
      ros__parameters:
        profile: circle
    event_manager:
      ros__parameters:
        tasks_dir: $(find-pkg-share hri_adaptive_controller)/tasks
        initial_task: follow

Section names are the node names of LIVE_LOOP_EXECUTABLES (scara_sim, event_manager,
controller, event_detector, recorder, hand_sim), optionally with a leading '/', or
wildcards such as `/**` (every child reads those). `$(find-pkg-share PACKAGE)` in a string
value becomes PACKAGE's installed share directory. The system writes the file with those
substitutions done to LOG_DIR/system_params.yaml and starts every child with `ros2 run
PACKAGE EXECUTABLE --ros-args --params-file LOG_DIR/system_params.yaml`: each child reads its
own section over its package's defaults (config/<node>.yaml). A setting the `system` section
leaves out keeps its value in the installed config/system.yaml, the one place the system's
defaults are written; the settings are read from the file only (the ROS parameter is
`config`).

The children inherit the environment (ROS_DOMAIN_ID, ...) and the working directory: a
relative path in a section (tasks_dir, the recorder's output) is relative to the directory
the system was started in. Each runs in a session of its own; the system logs
`started NAME (pid PID): COMMAND` for each, and `all N nodes ready` once each has logged
that it is up. Their output goes to LOG_DIR/NAME-K.log and, with echo_output, line by line
onto the system's stdout prefixed `[NAME] ` (the system's own lines are ROS log lines).

SIGINT or SIGTERM stops every child (SIGTERM; SIGKILL after stop_timeout) and the system
exits 0. SIGTERM, not SIGINT: a running node stops on either as on Ctrl-C (exit 0), but one
still importing its modules (the others are stopped because one failed at start) ends at
once on SIGTERM, where SIGINT prints Python's KeyboardInterrupt traceback. A child that exits
on its own is an error: one line names it and its exit code, the others are stopped and the
system exits 1. A bad config (a missing file, bad YAML, an unknown node or package name) is
one error line and exit 1, before any child starts.
"""

import os
import re
import signal
import time
from pathlib import Path

import rclpy
import yaml
from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from rclpy.node import Node

from hri_bringup.processes import (
    LIVE_LOOP_EXECUTABLES,
    READY_LINES,
    NodeProcess,
    start_nodes,
    stop_all,
)
from hri_core.node_common import (
    ParameterSpec,
    StartupError,
    declare_parameters,
    defaults_file,
    load_defaults,
    run_node,
)

NODE_NAME = 'system'
PACKAGE = 'hri_bringup'
PARAMETERS_KEY = 'ros__parameters'
PARAMETERS = {
    'config': ParameterSpec(str, 'the system YAML: a ROS 2 parameters file, a section per '
                            'node (hri_bringup/system.py describes it); $(find-pkg-share '
                            'PACKAGE) is replaced', read_only=True),
}
# The settings of the system section besides `config`: type and meaning. Their defaults are
# in the installed config/system.yaml.
SETTINGS = {
    'nodes': (list, 'the nodes to start, of ' + ', '.join(LIVE_LOOP_EXECUTABLES)),
    'log_dir': (str, 'folder of the nodes\' logs and of the parameters file they get ("": '
                'a new one in the ROS log directory)'),
    'echo_output': (bool, "the nodes' output on stdout, each line prefixed [node]"),
    'stop_timeout': (float, 's from SIGTERM to SIGKILL when the nodes are stopped'),
}
TYPE_NAMES = {list: 'a list of node names', str: 'a string', bool: 'true or false',
              float: 'a positive number'}
FIND_PACKAGE_SHARE = re.compile(r'\$\(find-pkg-share\s+([^)\s]*)\s*\)')
WATCH_PERIOD = 0.1  # s between looks at the children (exits, output, readiness)
GENERATED_PARAMS_FILE = 'system_params.yaml'


def yaml_problem(error: yaml.YAMLError) -> str:
    """A YAML error in one line: what is wrong and where."""
    mark = getattr(error, 'problem_mark', None)
    problem = getattr(error, 'problem', None)
    if problem and mark is not None:
        return f'{problem} (line {mark.line + 1}, column {mark.column + 1})'
    return ' '.join(str(error).split())


def substitute_shares(value, where: str):
    """`value` with every `$(find-pkg-share PACKAGE)` in its strings (in lists and mappings
    too) replaced by PACKAGE's installed share directory; `where` starts an error's line."""
    if isinstance(value, str):
        def share(match: re.Match) -> str:
            try:
                return get_package_share_directory(match.group(1))
            except (PackageNotFoundError, ValueError):
                raise StartupError(f'{where}: {match.group(0)}: no installed package '
                                   f'{match.group(1)!r}') from None
        return FIND_PACKAGE_SHARE.sub(share, value)
    if isinstance(value, list):
        return [substitute_shares(item, where) for item in value]
    if isinstance(value, dict):
        return {key: substitute_shares(item, where) for key, item in value.items()}
    return value


def is_known_section(key: str) -> bool:
    """A section this system uses: itself, a live-loop node, or a wildcard (`/**`)."""
    name = key.lstrip('/')
    return name == NODE_NAME or name in LIVE_LOOP_EXECUTABLES or '*' in key


def load_config(path: str | Path) -> dict[str, dict]:
    """The parameters file at `path`, checked, `$(find-pkg-share ...)` substituted, as
    {section: {'ros__parameters': {...}}} without empty sections. StartupError (one line)
    if it cannot be read or is not such a file for this system's nodes."""
    path = Path(path)
    where = f'config {path}'
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise StartupError(f'{where}: no such file') from None
    except (OSError, UnicodeDecodeError) as error:
        raise StartupError(f'{where}: cannot read it: '
                           f'{getattr(error, "strerror", None) or error}') from None
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise StartupError(f'{where}: not valid YAML: {yaml_problem(error)}') from None
    if not isinstance(document, dict) or not document:
        raise StartupError(f'{where}: expected sections `NODE: {{{PARAMETERS_KEY}: {{...}}}}`,'
                           ' found none')
    sections = {}
    for key, section in document.items():
        if not isinstance(key, str) or not is_known_section(key):
            raise StartupError(
                f'{where}: section {key!r} is no node of the system (known: '
                f'{", ".join([NODE_NAME, *LIVE_LOOP_EXECUTABLES])}, or a wildcard like /**)')
        if not isinstance(section, dict) or set(section) != {PARAMETERS_KEY} \
                or not isinstance(section[PARAMETERS_KEY], dict | None):
            raise StartupError(f'{where}: section {key!r} must hold exactly '
                               f'`{PARAMETERS_KEY}:` and its parameters')
        if section[PARAMETERS_KEY]:
            sections[key] = {PARAMETERS_KEY: substitute_shares(section[PARAMETERS_KEY], where)}
    return sections


def system_section(sections: dict[str, dict]) -> dict:
    """The parameters of the `system` (or `/system`) section; {} if there is none."""
    return {name: value for key, section in sections.items()
            if key.lstrip('/') == NODE_NAME for name, value in section[PARAMETERS_KEY].items()}


def setting_problem(name: str, value) -> str:
    """Why `value` is not valid for the setting `name` ('' if it is)."""
    kind = SETTINGS[name][0]
    if kind is list:
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            return f'must be {TYPE_NAMES[kind]}, got {value!r}'
        unknown = [v for v in value if v not in LIVE_LOOP_EXECUTABLES]
        if unknown:
            return (f'unknown node(s) {", ".join(unknown)} (known: '
                    f'{", ".join(LIVE_LOOP_EXECUTABLES)})')
        return '' if value else 'is empty: nothing to start'
    if kind is float:
        valid = isinstance(value, int | float) and not isinstance(value, bool) and value > 0
        return '' if valid else f'must be {TYPE_NAMES[kind]}, got {value!r}'
    return '' if type(value) is kind else f'must be {TYPE_NAMES[kind]}, got {value!r}'


def system_settings(defaults: dict, sections: dict[str, dict], where: str) -> dict:
    """SETTINGS' values: `defaults` (the installed file's system section) updated by the
    system section of `sections`; StartupError naming `where` for an unknown or bad one."""
    values = {name: defaults.get(name) for name in SETTINGS}
    for name, value in system_section(sections).items():
        if name in PARAMETERS:
            continue
        if name not in SETTINGS:
            raise StartupError(f'{where}: {NODE_NAME}: unknown parameter {name!r} (known: '
                               f'{", ".join([*PARAMETERS, *SETTINGS])})')
        values[name] = value
    for name, value in values.items():
        reason = setting_problem(name, value)
        if reason:
            raise StartupError(f'{where}: {NODE_NAME}: {name} {reason}')
    values['stop_timeout'] = float(values['stop_timeout'])
    return values


def log_directory(setting: str) -> Path:
    """The folder of the children's logs: `setting`, or a new one in the ROS log directory."""
    if setting:
        folder = Path(setting).expanduser()
    else:
        stamp = time.strftime('%Y-%m-%d-%H-%M-%S')
        folder = Path(rclpy.logging.get_logging_directory()) / \
            f'hri_system_{stamp}_{os.getpid()}'
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise StartupError(f'log_dir {folder}: {error.strerror or error}') from None
    return folder


def write_params_file(sections: dict[str, dict], path: Path) -> Path:
    """The children's parameters file (substitutions done) at `path`."""
    try:
        path.write_text(yaml.safe_dump(sections, sort_keys=False))
    except OSError as error:
        raise StartupError(f'cannot write {path}: {error.strerror or error}') from None
    return path


class System(Node):
    """Starts the configured nodes as children, watches them, stops them on request."""

    def __init__(self):
        super().__init__(NODE_NAME)
        values = declare_parameters(self, PARAMETERS, load_defaults(PACKAGE, NODE_NAME))
        config = Path(substitute_shares(values['config'], 'parameter config'))
        installed = defaults_file(PACKAGE, NODE_NAME)
        sections = load_config(config)
        defaults = system_section(sections if config == installed else load_config(installed))
        settings = system_settings(defaults, sections, f'config {config}')
        self._log_dir = log_directory(settings['log_dir'])
        self._echo = settings['echo_output']
        self._stop_timeout = settings['stop_timeout']
        params_file = write_params_file(sections, self._log_dir / GENERATED_PARAMS_FILE)
        self.exit_code: int | None = None  # set when a child ends on its own
        self._ready_reported = False
        try:
            self._children: dict[str, NodeProcess] = start_nodes(
                settings['nodes'], None, log_dir=self._log_dir, params_files=[params_file])
        except OSError as error:
            raise StartupError(f'cannot start the nodes: {error}') from None
        for name, child in self._children.items():
            self.get_logger().info(f'started {name} (pid {child.pid}): '
                                   f'{" ".join(child.command)}')
        self.get_logger().info(f'config {config}; logs in {self._log_dir}')
        self.create_timer(WATCH_PERIOD, self._watch)

    def _watch(self) -> None:
        self._echo_output()
        if not self._ready_reported and all(
                READY_LINES[LIVE_LOOP_EXECUTABLES[name][1]] in child.log()
                for name, child in self._children.items()):
            self._ready_reported = True
            self.get_logger().info(f'all {len(self._children)} nodes ready')
        if self.exit_code is not None:
            return
        for name, child in self._children.items():
            if not child.alive():
                self.get_logger().error(
                    f'{name} exited unexpectedly with exit code {child.process.returncode} '
                    f'(log {child.log_path}); stopping the others')
                self.exit_code = 1
                return

    def _echo_output(self, final: bool = False) -> None:
        if not self._echo:
            return
        for name, child in self._children.items():
            for line in child.new_lines(final):
                print(f'[{name}] {line}', flush=True)

    def stop_children(self) -> None:
        """SIGTERM to every child still running, SIGKILL after stop_timeout; keep their exit
        codes for `summary` (a warning names the children that did not exit 0)."""
        running = [name for name, child in self._children.items() if child.alive()]
        if running:
            self.get_logger().info(f'stopping {", ".join(running)}')
        codes = stop_all(self._children.values(), self._stop_timeout, signal.SIGTERM)
        self._echo_output(final=True)
        self._exit_codes = ', '.join(f'{name} {codes[child]}'
                                     for name, child in self._children.items())
        unclean = [name for name in running if codes[self._children[name]] != 0]
        if unclean:
            self.get_logger().warning(f'not stopped cleanly: {", ".join(unclean)} (logs in '
                                      f'{self._log_dir})')

    def summary(self) -> str:
        """One line on the children (run_node logs it at the stop)."""
        return (f'{len(self._children)} nodes run, then stopped; exit codes: '
                f'{getattr(self, "_exit_codes", "none")}')


def main(args=None):
    return run_node(System, NODE_NAME, args=args,
                    exit_code=lambda node: node.exit_code,
                    on_stop=lambda node: node.stop_children())


if __name__ == '__main__':
    raise SystemExit(main())
