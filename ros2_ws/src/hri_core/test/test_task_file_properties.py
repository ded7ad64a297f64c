"""Property tests of hri_core.task_file: TaskRecord accepts exactly the valid records, and
every valid record survives a task-file round trip unchanged."""

import math
import re

import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from hri_core.task_file import TaskRecord, load_task_file, save_task_file

FIELDS = ('name', 's', 'a1', 'a2', 'd1', 'd2', 'n', 'cost', 'iterations', 'k')
NAME = re.compile(r'^[A-Za-z0-9_][A-Za-z0-9_-]{0,63}$')

numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 20), st.booleans(),
    st.none(), st.sampled_from((0.0, -0.0, 1e-300, 1, -1, 3)))
names = st.one_of(st.from_regex(NAME, fullmatch=True), st.text(max_size=70), st.none(),
                  st.sampled_from(('-x', 'a.b', '../up', '', 'a' * 65)))


def is_integer(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def is_real(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value)


def is_valid(name, s, a1, a2, d1, d2, n, cost, iterations, k) -> bool:
    """A valid task record, written out independently of TaskRecord (module docstrings of
    hri_core.task_file and hri_core.potential)."""
    return (isinstance(name, str) and NAME.fullmatch(name) is not None
            and is_integer(s) and s in (1, -1) and is_integer(n) and n >= 3
            and all(is_real(v) for v in (a1, a2, d1, d2, cost, k))
            and a1 > 0 and a2 > 0 and 0 <= d1 <= d2 and cost >= 0 and k >= 0
            and is_integer(iterations) and iterations >= 0)


valid_records = st.builds(
    lambda name, s, a1, a2, ds, n, cost, iterations, k: TaskRecord(
        name, s, a1, a2, min(ds), max(ds), n, cost, iterations, k),
    st.from_regex(NAME, fullmatch=True), st.sampled_from((1, -1)),
    st.floats(1e-6, 1e4), st.floats(1e-6, 1e4),
    st.tuples(st.floats(0.0, 10.0), st.floats(0.0, 10.0)), st.integers(3, 15),
    st.floats(0.0, 1e6), st.integers(0, 10**6), st.floats(0.0, 1e6))


@st.composite
def records(draw) -> dict:
    """A valid record's values with zero to three fields replaced by arbitrary values."""
    base = draw(valid_records)
    values = {key: getattr(base, key) for key in FIELDS}
    for key in draw(st.lists(st.sampled_from(FIELDS), max_size=3, unique=True)):
        values[key] = draw(names if key == 'name' else numbers)
    return values


@settings(max_examples=400)
@given(values=records())
def test_task_record_accepts_exactly_the_valid_records(values):
    valid = is_valid(**values)
    event('valid' if valid else 'invalid')
    if valid:
        record = TaskRecord(**values)
        assert {key: getattr(record, key) for key in values} == values
    else:
        with pytest.raises(ValueError, match='must be|not a safe file name'):
            TaskRecord(**values)


@settings(max_examples=100)
@given(record=valid_records)
def test_every_valid_record_survives_a_file_round_trip(record, tmp_path_factory):
    folder = tmp_path_factory.mktemp('tasks')
    assert load_task_file(save_task_file(record, folder)) == record
