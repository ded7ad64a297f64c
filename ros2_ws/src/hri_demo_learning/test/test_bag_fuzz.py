"""Fuzzing the learner's input: 200 seeded mutations of the fixture bags.

The first cases delete each bag's metadata.yaml; every other case truncates the .mcap at a
random offset, flips bytes inside its chunks (the messages) or flips bytes in its summary
section, and in one case of four also deletes metadata.yaml. `learn_from_bags` (the part of the
learner node's `learn_task` that reads and fits; `learn_task` writes the task file and figure
only after it returns) must then either learn a valid task or raise LearningError with a
one-line reason; any other exception is a traceback in the node, and a case using over
CASE_TIME_LIMIT s of CPU is a hang (CPU, not wall time: the unit tests run at nice 19 beside
the topic-level phases, where the first case, with its imports, once took over 10 s of wall
time; and SIGPROF leaves pytest-timeout's SIGALRM alone). tests/test_learner.py checks that a
LearningError becomes one ERROR line, a non-zero exit of the node and no task file.
"""

import random
import shutil
import signal
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader

from hri_demo_learning.learning import LearningError, LearningSettings, learn_from_bags

FIXTURES = Path(__file__).resolve().parents[4] / 'bags' / 'fixtures'
LEARNER_DEFAULTS = Path(__file__).resolve().parents[1] / 'config' / 'learner.yaml'
SEED = 20261201
CASES = 200
CASE_TIME_LIMIT = 10.0  # s of the process's CPU: a case using more counts as a hang
BYTE_MUTATIONS = ('truncate', 'flip_chunks', 'flip_summary')

pytestmark = pytest.mark.skipif(not FIXTURES.is_dir(), reason='bags/fixtures is not there')


class CaseTimeoutError(Exception):
    """Raised by the profiling timer when a case uses over CASE_TIME_LIMIT s of CPU."""


def learner_defaults() -> LearningSettings:
    """learn_from_bags' settings from the learner's config/learner.yaml (the node's own
    defaults)."""
    values = yaml.safe_load(LEARNER_DEFAULTS.read_text())['learner']['ros__parameters']
    return LearningSettings.from_parameters(values)


def bag_layout(bag: Path) -> tuple[Path, list[tuple[int, int]], tuple[int, int]]:
    """The bag's .mcap, the byte ranges of its chunks and of its summary section."""
    mcap = next(bag.glob('*.mcap'))
    with open(mcap, 'rb') as stream:
        summary = make_reader(stream).get_summary()
    chunks = [(index.chunk_start_offset, index.chunk_start_offset + index.chunk_length)
              for index in summary.chunk_indexes]
    size = mcap.stat().st_size
    with open(mcap, 'rb') as stream:
        # The footer record: opcode (1), length (8), summary_start (8), summary_offset_start
        # (8), summary_crc (4); then the closing magic (8).
        stream.seek(size - 8 - 29)
        footer = stream.read(29)
    summary_start = int.from_bytes(footer[9:17], 'little')
    return mcap, chunks, (summary_start, size - 8)


def flip_bytes(data: bytearray, ranges: list[tuple[int, int]], count: int,
               rng: random.Random) -> list[int]:
    offsets = []
    for _ in range(count):
        start, end = rng.choice(ranges)
        offset = rng.randrange(start, end)
        data[offset] ^= rng.randrange(1, 256)
        offsets.append(offset)
    return offsets


def mutate(source: Path, target: Path, kind: str | None, delete_metadata: bool,
           rng: random.Random) -> str:
    """Copy bag `source` to `target`, apply byte mutation `kind` (None: none) to its .mcap and
    delete its metadata.yaml if asked; return what was done."""
    shutil.copytree(source, target)
    mcap, chunks, summary = bag_layout(target)
    data = bytearray(mcap.read_bytes())
    done = []
    if kind == 'truncate':
        offset = rng.randrange(0, len(data))
        del data[offset:]
        done.append(f'truncated at {offset} of {mcap.stat().st_size}')
    elif kind == 'flip_chunks':
        done.append(f'chunk bytes flipped at {flip_bytes(data, chunks, rng.randint(1, 8), rng)}')
    elif kind == 'flip_summary':
        offsets = flip_bytes(data, [summary], rng.randint(1, 4), rng)
        done.append(f'summary bytes flipped at {offsets}')
    mcap.write_bytes(bytes(data))
    if delete_metadata:
        (target / 'metadata.yaml').unlink()
        done.append('metadata.yaml deleted')
    return ', '.join(done)


def _alarm(_signum, _frame):
    raise CaseTimeoutError


# 200 bags of up to 10 s each: 6 s in all, alone on this machine.
@pytest.mark.first
@pytest.mark.timeout(600)
def test_mutated_bags_are_learned_or_refused_in_one_line(tmp_path):
    rng = random.Random(SEED)
    settings = learner_defaults()
    sources = sorted(path for path in FIXTURES.iterdir() if path.is_dir())
    outcomes = {'learned': 0, 'refused': 0}
    previous = signal.signal(signal.SIGPROF, _alarm)
    try:
        for case in range(CASES):
            source = sources[case % len(sources)]
            bag = tmp_path / f'case{case}'
            if case < len(sources):
                done = mutate(source, bag, None, True, rng)
            else:
                done = mutate(source, bag, rng.choice(BYTE_MUTATIONS), rng.random() < 0.25, rng)
            what = f'case {case}: {source.name} {done}'
            signal.setitimer(signal.ITIMER_PROF, CASE_TIME_LIMIT)
            try:
                learned = learn_from_bags([str(bag)], [0.0], 'fuzz', settings)
            except LearningError as error:
                reason = str(error)
                assert reason and '\n' not in reason, what
                outcomes['refused'] += 1
            except CaseTimeoutError:
                pytest.fail(f'{what}: no answer within {CASE_TIME_LIMIT} s of CPU')
            except Exception as error:  # noqa: BLE001 - any other exception is the failure
                pytest.fail(f'{what}: {type(error).__name__} escaped: {error}')
            else:
                assert learned.record.name == 'fuzz', what  # a valid TaskRecord
                outcomes['learned'] += 1
            finally:
                signal.setitimer(signal.ITIMER_PROF, 0.0)
            shutil.rmtree(bag)
    finally:
        signal.signal(signal.SIGPROF, previous)
    print(f'bag fuzz: {CASES} cases, {outcomes}')
    assert sum(outcomes.values()) == CASES
