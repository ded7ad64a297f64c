"""Task files: one learned task as `tasks/<name>.yaml`, a flat mapping of TaskParameters' keys.

    name: follow          # a safe file name, equal to the file's stem
    s: 1                  # +1 or -1 (eq. 1)
    a1: 1.291             # 1/m^2, > 0
    a2: 13.66             # 1/m^2, > 0
    d1: 0.0               # m, 0 <= d1 <= d2
    d2: 0.041             # m
    n: 3                  # exponent N of eq. 2, >= 3
    cost: 0.0012          # fit cost C of eq. 8, >= 0
    iterations: 12        # fit iterations used, >= 0
    k: 0.42               # task gain K, m^2/s, >= 0; optional, 0 when missing (see below)

`k` is the task gain K of eq. 13: the task moves the arm at K |dP/dz| (m/s, capped by the
controller). The learner fits it to the demonstration's speeds. A file without `k` (Table I's
rows, written before K was learned) loads with k = 0, which means "not given": consumers use
`hri_core.potential.default_task_gain` (the pull is the controller's max_task_speed
PULL_ONSET = 0.05 m outside the region).

The learner writes these files (atomically: a temporary file in the same folder, then
os.replace), the event manager loads a folder of them, and a person may write one by hand
(e.g. Table I's rows). Loading rejects anything else with a one-line reason: not YAML, not a
mapping, missing or unknown keys, invalid values, a name that is not a safe file name or does
not match the file name. Numbers written as YAML strings that parse as floats (PyYAML reads
`1e3` as a string) are accepted.
"""

import math
import os
import re
import tempfile
from dataclasses import asdict, dataclass
from numbers import Integral, Real
from pathlib import Path

import yaml

from hri_core.potential import TaskShape

TASK_KEYS = ('name', 's', 'a1', 'a2', 'd1', 'd2', 'n', 'cost', 'iterations', 'k')
"""The keys of a task file, in the order they are written."""

OPTIONAL_TASK_KEYS = {'k': 0.0}
"""Keys a task file may leave out, with the value they then take (k = 0: no task gain
given)."""

TASK_FILE_SUFFIX = '.yaml'
MAX_TASK_FILE_BYTES = 65536

_SAFE_NAME = re.compile(r'^[A-Za-z0-9_][A-Za-z0-9_-]{0,63}$')


def is_safe_task_name(name):
    """True when name can be a file stem on any file system: 1-64 of [A-Za-z0-9_-], no
    leading '-', no dots, no path separators."""
    return isinstance(name, str) and _SAFE_NAME.fullmatch(name) is not None


@dataclass(frozen=True)
class TaskRecord:
    """One learned task: TaskShape's parameters plus its name and how the fit went.

    name: safe file name; s: +1/-1; a1, a2: 1/m^2; d1, d2: m; n: N >= 3; cost: C of eq. 8,
    >= 0; iterations: >= 0; k: task gain K, m^2/s, >= 0 (0: not given). Raises ValueError
    with the reason when a value is invalid.
    """

    name: str
    s: int
    a1: float
    a2: float
    d1: float
    d2: float
    n: int
    cost: float
    iterations: int
    k: float = 0.0

    def __post_init__(self):
        if not is_safe_task_name(self.name):
            raise ValueError(f'name {self.name!r} is not a safe file name '
                             '(1-64 of A-Z a-z 0-9 _ -, not starting with -)')
        iterations = self.iterations
        if isinstance(iterations, bool) or not isinstance(iterations, Integral) \
                or iterations < 0:
            raise ValueError(f'iterations must be an integer >= 0, got {iterations!r}')
        object.__setattr__(self, 'iterations', int(iterations))
        cost = self.cost
        if isinstance(cost, bool) or not isinstance(cost, Real) or not math.isfinite(cost) \
                or cost < 0.0:
            raise ValueError(f'cost must be a finite number >= 0, got {cost!r}')
        object.__setattr__(self, 'cost', float(cost))
        k = self.k
        if isinstance(k, bool) or not isinstance(k, Real) or not math.isfinite(k) or k < 0.0:
            raise ValueError(f'k must be a finite number >= 0 (m^2/s; 0: not given), got {k!r}')
        object.__setattr__(self, 'k', float(k))
        shape = TaskShape(self.s, self.a1, self.a2, self.d1, self.d2, self.n)
        for key in ('s', 'a1', 'a2', 'd1', 'd2', 'n'):
            object.__setattr__(self, key, getattr(shape, key))

    @property
    def shape(self):
        """The TaskShape (s, a1, a2, d1, d2, n) of this task."""
        return TaskShape(self.s, self.a1, self.a2, self.d1, self.d2, self.n)


def _coerce_number(key, value):
    """YAML scalars to numbers: ints and floats as they are, float-like strings parsed."""
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            raise ValueError(f'{key} must be a number, got {value!r}') from None
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ValueError(f'{key} must be a number, got {value!r}')
    return value


def _integer(key, value):
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise ValueError(f'{key} must be an integer, got {value!r}')
    return int(value)


def _read_task_record(path):
    """TaskRecord from a file; ValueError whose message is the reason (no path)."""
    try:
        with open(path, 'rb') as stream:
            data = stream.read(MAX_TASK_FILE_BYTES + 1)
    except OSError as err:
        raise ValueError(f'cannot read: {err.strerror or err}') from None
    if len(data) > MAX_TASK_FILE_BYTES:
        raise ValueError(f'too large for a task file (> {MAX_TASK_FILE_BYTES} bytes)')
    try:
        content = yaml.safe_load(data.decode('utf-8'))
    except UnicodeDecodeError:
        raise ValueError('not YAML: not UTF-8 text') from None
    except yaml.YAMLError as err:
        mark = getattr(err, 'problem_mark', None)
        where = f' at line {mark.line + 1}' if mark is not None else ''
        problem = getattr(err, 'problem', None) or type(err).__name__
        raise ValueError(f'not YAML{where}: {problem}') from None
    if not isinstance(content, dict):
        kind = 'empty' if content is None else type(content).__name__
        raise ValueError(f'not a mapping of task parameters (got {kind})')
    missing = [key for key in TASK_KEYS
               if key not in content and key not in OPTIONAL_TASK_KEYS]
    if missing:
        raise ValueError(f'missing keys: {", ".join(missing)}')
    unknown = sorted(str(key) for key in content if key not in TASK_KEYS)
    if unknown:
        raise ValueError(f'unknown keys: {", ".join(unknown)}')
    name = content['name']
    if not is_safe_task_name(name):
        raise ValueError(f'name {name!r} is not a safe file name '
                         '(1-64 of A-Z a-z 0-9 _ -, not starting with -)')
    stem = Path(path).name.removesuffix(TASK_FILE_SUFFIX)
    if name != stem:
        raise ValueError(f'name {name!r} does not match the file name {Path(path).name!r}')
    values = {'name': name}
    for key in ('s', 'n', 'iterations'):
        values[key] = _integer(key, content[key])
    for key in ('a1', 'a2', 'd1', 'd2', 'cost'):
        values[key] = _coerce_number(key, content[key])
    values['k'] = _coerce_number('k', content.get('k', OPTIONAL_TASK_KEYS['k']))
    return TaskRecord(**values)


def load_task_file(path):
    """TaskRecord from a task file (module docstring gives the format).

    path: str or Path. Raises ValueError('<path>: <one-line reason>') when the file cannot be
    read or is not a valid task file.
    """
    try:
        return _read_task_record(path)
    except ValueError as err:
        raise ValueError(f'{path}: {err}') from None


def save_task_file(record, directory):
    """Write record to <directory>/<record.name>.yaml atomically; returns that Path.

    The folder is created if missing. The file is written to a temporary file in the same
    folder, flushed to disk and renamed over the target (os.replace), so a reader never sees
    a partial file. Raises OSError when the folder cannot be written.
    """
    if not isinstance(record, TaskRecord):
        raise ValueError(f'record must be a TaskRecord, got {type(record).__name__}')
    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / f'{record.name}{TASK_FILE_SUFFIX}'
    fields = asdict(record)
    text = yaml.safe_dump({key: fields[key] for key in TASK_KEYS}, sort_keys=False,
                          default_flow_style=False)
    descriptor, temporary = tempfile.mkstemp(dir=folder, prefix=f'.{record.name}.',
                                             suffix='.tmp')
    try:
        with os.fdopen(descriptor, 'w', encoding='utf-8') as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        os.chmod(temporary, 0o644)
        os.replace(temporary, target)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    return target


def load_task_directory(directory):
    """All task files (*.yaml) in a folder.

    Returns (tasks, rejects): tasks maps name -> TaskRecord; rejects lists (path, reason) for
    each file that could not be loaded (reason one line, without the path). A folder that does
    not exist or is not a folder gives ({}, [(directory, reason)]).
    """
    folder = Path(directory)
    if not folder.is_dir():
        return {}, [(folder, 'not a directory')]
    tasks, rejects = {}, []
    for path in sorted(folder.glob(f'*{TASK_FILE_SUFFIX}')):
        try:
            record = _read_task_record(path)
        except ValueError as err:
            rejects.append((path, str(err)))
            continue
        tasks[record.name] = record
    return tasks, rejects
