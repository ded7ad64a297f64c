"""Unit tests of hri_core.task_file: task YAML round trip and rejected files."""

import os

import pytest
import yaml

from hri_core.potential import TaskShape
from hri_core.task_file import (
    TASK_KEYS,
    TaskRecord,
    load_task_directory,
    load_task_file,
    save_task_file,
)

FOLLOW = TaskRecord(name='follow', s=1, a1=1.291, a2=13.66, d1=0.0, d2=0.041, n=3,
                    cost=0.0014657942, iterations=20)
GOOD = {'name': 'avoid', 's': 1, 'a1': 0.056, 'a2': 25.46, 'd1': 0.183, 'd2': 2.0, 'n': 3,
        'cost': 0.0, 'iterations': 0}


def write(folder, name, text):
    path = folder / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def test_round_trip(tmp_path):
    path = save_task_file(FOLLOW, tmp_path / 'tasks')
    assert path == tmp_path / 'tasks' / 'follow.yaml'
    assert load_task_file(path) == FOLLOW
    assert list(yaml.safe_load(path.read_text())) == list(TASK_KEYS)
    assert [p.name for p in path.parent.iterdir()] == ['follow.yaml']   # no temporary left
    assert FOLLOW.shape == TaskShape(1, 1.291, 13.66, 0.0, 0.041, 3)


def test_save_replaces_an_existing_file(tmp_path):
    save_task_file(FOLLOW, tmp_path)
    changed = TaskRecord(**{**FOLLOW.__dict__, 'a1': 2.5, 'iterations': 7})
    path = save_task_file(changed, tmp_path)
    assert load_task_file(path) == changed


def test_failed_save_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    path = save_task_file(FOLLOW, tmp_path)

    def fail(*_args):
        raise OSError('disk full')

    monkeypatch.setattr(os, 'replace', fail)
    with pytest.raises(OSError, match='disk full'):
        save_task_file(TaskRecord(**{**FOLLOW.__dict__, 'a1': 9.0}), tmp_path)
    assert load_task_file(path) == FOLLOW
    assert [p.name for p in tmp_path.iterdir()] == ['follow.yaml']


def test_hand_written_table_i_row_loads(tmp_path):
    # PyYAML reads 1e-3 as a string; a person writing the row by hand may still use it.
    path = write(tmp_path, 'follow_safe.yaml', '# Table I\nname: follow_safe\ns: 1\n'
                 'a1: 1.576\na2: 30.78\nd1: 0.183\nd2: 0.271\nn: 3\ncost: 1e-3\n'
                 'iterations: 1628\n')
    record = load_task_file(path)
    assert record.cost == 1e-3 and record.iterations == 1628
    assert record.shape == TaskShape(1, 1.576, 30.78, 0.183, 0.271)


def dump(**changes):
    values = {**GOOD, **changes}
    return yaml.safe_dump({k: v for k, v in values.items() if v is not None}, sort_keys=False)


@pytest.mark.parametrize(('text', 'reason'), [
    ('name: [avoid\n', 'not YAML at line'),
    (b'\xff\xfe\x00name', 'not YAML: not UTF-8'),
    ('', r'not a mapping of task parameters \(got empty\)'),
    ('- 1\n- 2\n', r'not a mapping of task parameters \(got list\)'),
    (dump(a2=None, d2=None), 'missing keys: a2, d2'),
    (dump() + 'gain: 5\n', 'unknown keys: gain'),
    (dump(s=2), 's must be \\+1 or -1'),
    (dump(s=True), 's must be an integer'),
    (dump(s=1.0), 's must be an integer'),
    (dump(a1=-0.5), 'a1 and a2 must be > 0'),
    (dump(a2='steep'), "a2 must be a number, got 'steep'"),
    (dump(d1=0.5, d2=0.2), 'd1 must be <= d2'),
    (dump(d1=-0.1), 'd1 and d2 must be >= 0'),
    (dump(n=2), 'n must be >= 3'),
    (dump(cost=float('nan')), 'cost must be a finite number >= 0'),
    (dump(a1=float('inf')), 'a1 must be finite'),
    (dump(iterations=-1), 'iterations must be an integer >= 0'),
    (dump(name='other'), "name 'other' does not match the file name 'avoid.yaml'"),
    (dump(name='../avoid'), 'not a safe file name'),
    (dump(name=7), 'not a safe file name'),
])
def test_bad_task_files_are_rejected_with_a_reason(tmp_path, text, reason):
    path = write(tmp_path, 'avoid.yaml', text)
    with pytest.raises(ValueError, match=reason) as error:
        load_task_file(path)
    message = str(error.value)
    assert message.startswith(f'{path}: ') and '\n' not in message


def test_missing_and_oversized_files_are_rejected(tmp_path):
    with pytest.raises(ValueError, match='cannot read: No such file'):
        load_task_file(tmp_path / 'nothing.yaml')
    path = write(tmp_path, 'avoid.yaml', dump() + '#' * 70000 + '\n')
    with pytest.raises(ValueError, match='too large'):
        load_task_file(path)


def test_task_record_validates_on_construction():
    with pytest.raises(ValueError, match='not a safe file name'):
        TaskRecord(**{**FOLLOW.__dict__, 'name': 'a/b'})
    with pytest.raises(ValueError, match='cost must be'):
        TaskRecord(**{**FOLLOW.__dict__, 'cost': -1.0})
    with pytest.raises(ValueError, match='a1 and a2 must be > 0'):
        TaskRecord(**{**FOLLOW.__dict__, 'a1': 0.0})


def test_load_task_directory_keeps_good_files_and_lists_rejects(tmp_path):
    save_task_file(FOLLOW, tmp_path)
    write(tmp_path, 'avoid.yaml', dump())
    write(tmp_path, 'broken.yaml', 'name: [\n')
    write(tmp_path, 'notes.txt', 'not a task file')
    tasks, rejects = load_task_directory(tmp_path)
    assert sorted(tasks) == ['avoid', 'follow']
    assert tasks['follow'] == FOLLOW
    assert [(path.name, reason.split(':')[0]) for path, reason in rejects] == [
        ('broken.yaml', 'not YAML at line 2')]


def test_load_task_directory_of_a_missing_folder(tmp_path):
    assert load_task_directory(tmp_path / 'absent') == ({}, [(tmp_path / 'absent',
                                                              'not a directory')])


def test_a_file_without_k_loads_with_k_zero_and_k_is_written(tmp_path):
    path = tmp_path / 'follow.yaml'
    path.write_text('name: follow\ns: 1\na1: 1.291\na2: 13.66\nd1: 0.0\nd2: 0.041\nn: 3\n'
                    'cost: 0.0\niterations: 2468\n')
    assert load_task_file(path).k == 0.0
    learned = TaskRecord(**{**FOLLOW.__dict__, 'k': 0.42})
    assert load_task_file(save_task_file(learned, tmp_path / 'out')).k == 0.42


@pytest.mark.parametrize('k', [-0.1, float('nan'), float('inf'), True])
def test_a_bad_k_is_rejected(k):
    with pytest.raises(ValueError, match='k must be a finite number >= 0'):
        TaskRecord(**{**FOLLOW.__dict__, 'k': k})
