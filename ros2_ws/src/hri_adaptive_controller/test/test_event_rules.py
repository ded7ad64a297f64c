"""Unit tests of event_rules: every rule kind's edge, hysteresis, dwell, hold-off and required
task, the YAML loader's one-line errors, and (hypothesis) no chatter from a noisy resting hand."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hri_adaptive_controller.event_rules import (
    EventDetector,
    Observation,
    RuleError,
    load_rules,
    parse_rules,
)
from hri_core.node_common import load_defaults

DT = 0.02  # s, the node's default tick (50 Hz)


def detector(**rules) -> EventDetector:
    return EventDetector(parse_rules(rules))


def run(events: EventDetector, observations, task='follow') -> list[tuple[float, str]]:
    """(time, rule name) of every firing over `observations`."""
    fired = []
    for obs in observations:
        fired += [(round(f.time, 6), f.rule.name) for f in events.update(obs, task)]
    return fired


def separations(values, start=0.0, **speeds) -> list[Observation]:
    """One observation per tick with these separations (m), a hand present."""
    return [Observation(start + i * DT, value, since_hand=0.0, **speeds)
            for i, value in enumerate(values)]


def ticks(start: float, end: float) -> np.ndarray:
    return np.arange(round(start / DT), round(end / DT)) * DT


ZONE = {'kind': 'zone_entered', 'task': 'avoid', 'distance': 0.3, 'hysteresis': 0.04,
        'dwell': 0.1}


# -- zones --------------------------------------------------------------------------------------

def test_zone_entered_fires_once_on_the_edge_not_while_inside():
    events = detector(near=ZONE)
    # 0.5 m -> 0.1 m over 1 s, then inside for 2 s: one firing, dwell after the crossing.
    path = list(np.linspace(0.5, 0.1, 51)) + [0.1] * 100
    fired = run(events, separations(path))
    assert [name for _, name in fired] == ['near']
    crossing = next(i for i, s in enumerate(path) if s < 0.3 - 0.02) * DT
    assert fired[0][0] == pytest.approx(crossing + 0.1, abs=DT + 1e-9)


def test_zone_hysteresis_keeps_a_hand_inside_until_it_is_past_the_band():
    events = detector(near={**ZONE, 'hold_off': 0.0})
    inside = separations([0.25] * 10)
    # Swings within the band (0.28-0.32 m) after entering: still inside, no new edge.
    band = separations([0.315, 0.285] * 50, start=0.2)
    out_and_back = separations([0.33] * 10 + [0.27] * 10, start=2.2)
    fired = run(events, inside + band + out_and_back)
    assert [t for t, _ in fired] == pytest.approx([0.1, 2.4 + 0.1], abs=1e-9)


def test_zone_dwell_ignores_a_dip_shorter_than_the_dwell():
    events = detector(near=ZONE)
    short_dip = separations([0.4] * 5 + [0.2] * 4 + [0.4] * 20)  # 0.08 s inside < 0.1 s
    assert run(events, short_dip) == []
    long_dip = separations([0.2] * 6, start=1.0)  # 0.1 s inside
    assert run(events, long_dip) == [(1.1, 'near')]


def test_zone_left_fires_when_the_hand_goes_out_or_vanishes_but_not_when_it_appears_outside():
    events = detector(away={**ZONE, 'kind': 'zone_left', 'hold_off': 0.0})
    appears_outside = separations([0.5] * 10)
    assert run(events, appears_outside) == []
    enter_then_leave = separations([0.2] * 10 + [0.4] * 10, start=0.2)
    assert run(events, enter_then_leave) == [(0.4 + 0.1, 'away')]
    back_in = separations([0.2] * 10, start=0.6)
    gone = [Observation(t, None, since_hand=0.5) for t in ticks(0.8, 1.2)]
    assert run(events, back_in + gone) == [(0.8 + 0.1, 'away')]


def test_zone_entered_by_a_hand_that_appears_inside():
    events = detector(near=ZONE)
    nothing = [Observation(t, None) for t in ticks(0.0, 0.5)]
    fired = run(events, nothing + separations([0.1] * 10, start=0.5))
    assert fired == [(0.6, 'near')]


# -- approach -----------------------------------------------------------------------------------

APPROACH = {'kind': 'approach', 'task': 'avoid', 'min_speed': 0.3, 'dwell': 0.04}


def test_approach_by_speed_fires_on_the_edge_with_hysteresis_and_within():
    events = detector(reach={**APPROACH, 'within': 0.6, 'hold_off': 0.0})
    slow = separations([0.5] * 10, hand_speed=0.29)
    fast = separations([0.5] * 10, start=0.2, hand_speed=0.35)
    # Between min_speed - hysteresis and min_speed: still on, no new edge.
    dither = separations([0.5] * 10, start=0.4, hand_speed=0.27)
    release = separations([0.5] * 2, start=0.6, hand_speed=0.2)
    again = separations([0.5] * 5, start=0.64, hand_speed=0.4)
    too_far = separations([0.7] * 20, start=1.0, hand_speed=0.2) + \
        separations([0.7] * 20, start=1.4, hand_speed=1.0)
    fired = run(events, slow + fast + dither + release + again + too_far)
    assert fired == [(0.24, 'reach'), (0.68, 'reach')]


def test_approach_speed_of_hand_ignores_the_robot_coming_to_a_still_hand():
    rule = {**APPROACH, 'min_speed': 0.2}
    robot_comes = separations([0.4] * 20, robot_speed=0.3)
    assert run(detector(hand={**rule, 'speed_of': 'hand'}), robot_comes) == []
    assert run(detector(both=rule), robot_comes) == [(0.04, 'both')]
    hand_comes = separations([0.4] * 20, hand_speed=0.25)
    assert run(detector(hand={**rule, 'speed_of': 'hand'}), hand_comes) == [(0.04, 'hand')]


def test_approach_by_time_to_contact():
    events = detector(ttc={'kind': 'approach', 'task': 'avoid', 'max_time_to_contact': 0.5,
                           'dwell': 0.0, 'hysteresis': 0.1, 'hold_off': 0.0})
    # 0.3 m at 0.5 m/s: 0.6 s to contact; at 0.7 m/s: 0.43 s.
    assert run(events, separations([0.3] * 5, hand_speed=0.5)) == []
    assert run(events, separations([0.3] * 5, start=0.1, hand_speed=0.4, robot_speed=0.3)) \
        == [(0.1, 'ttc')]
    # 0.55 s is within the hysteresis: held; moving apart releases it.
    assert run(events, separations([0.3] * 5, start=0.2, hand_speed=0.55)) == []
    assert run(events, separations([0.3], start=0.3, hand_speed=-0.1)) == []
    assert run(events, separations([0.3], start=0.32, hand_speed=1.0)) == [(0.32, 'ttc')]


# -- still --------------------------------------------------------------------------------------

STILL = {'kind': 'still', 'task': 'follow_safe', 'max_speed': 0.05, 'duration': 1.0}


def test_still_fires_after_the_duration_and_a_move_restarts_it():
    events = detector(rests={**STILL, 'hold_off': 0.0})
    moving = separations([0.2] * 10, hand_motion=0.3)
    stops_briefly = separations([0.2] * 40, start=0.2, hand_motion=0.02)  # 0.8 s < 1 s
    moves = separations([0.2] * 5, start=1.0, hand_motion=0.2)
    creeps = separations([0.2] * 100, start=1.1, hand_motion=0.055)  # above max_speed
    assert run(events, moving + stops_briefly + moves + creeps) == []
    rests = separations([0.2] * 60, start=3.1, hand_motion=0.04)
    # Then 0.055 m/s again: within the hysteresis (0.01 m/s), still held, no new edge.
    still_held = separations([0.2] * 40, start=4.3, hand_motion=0.055)
    assert run(events, rests + still_held) == [(4.1, 'rests')]


def test_still_needs_a_hand():
    events = detector(rests=STILL)
    nothing = [Observation(t, None, since_hand=1.0) for t in ticks(0.0, 3.0)]
    assert run(events, nothing) == []


# -- lost ---------------------------------------------------------------------------------------

LOST = {'kind': 'lost', 'task': '', 'timeout': 0.5}


def test_lost_fires_once_per_loss_and_not_before_a_hand_was_seen():
    events = detector(gone={**LOST, 'hold_off': 0.0})
    never_seen = [Observation(t, None, since_hand=None) for t in ticks(0.0, 2.0)]
    assert run(events, never_seen) == []
    seen = separations([0.3] * 10, start=2.0)
    gone = [Observation(t, None, since_hand=t - 2.18) for t in ticks(2.2, 4.0)]
    back = separations([0.3] * 10, start=4.0)
    gone_again = [Observation(t, None, since_hand=t - 4.18) for t in ticks(4.2, 5.0)]
    fired = run(events, seen + gone + back + gone_again)
    assert fired == [(2.68, 'gone'), (4.68, 'gone')]


# -- hold-off and the required task -----------------------------------------------------------

def test_hold_off_drops_an_edge_within_it_and_does_not_fire_it_later():
    events = detector(near={**ZONE, 'dwell': 0.0, 'hold_off': 1.0})
    in_out_in = separations([0.2] * 5 + [0.4] * 5 + [0.2] * 50)  # second entry at 0.2 s
    assert run(events, in_out_in) == [(0.0, 'near')]
    later = separations([0.4] * 5 + [0.2] * 5, start=1.2)
    assert run(events, later) == [(1.3, 'near')]


def test_required_task_gates_the_edge():
    rules = {'near': {**ZONE, 'dwell': 0.0, 'hold_off': 0.0, 'when_task': ['follow']},
             'idle_near': {**ZONE, 'dwell': 0.0, 'hold_off': 0.0, 'when_task': ''}}
    events = detector(**rules)
    # The edge comes under avoid: not fired, not even once the task is follow.
    assert run(events, separations([0.2] * 5), task='avoid') == []
    assert run(events, separations([0.2] * 5, start=0.1), task='follow') == []
    # Unknown task (no TaskState yet): rules with when_task stay quiet.
    assert run(events, separations([0.4] + [0.2] * 2, start=0.2), task=None) == []
    assert run(events, separations([0.4] + [0.2], start=0.3), task='follow') == \
        [(0.32, 'near')]
    assert run(events, separations([0.4] + [0.2], start=0.4), task='') == [(0.42, 'idle_near')]


def test_a_rule_without_when_task_fires_under_any_task_and_time_must_advance():
    events = detector(near={**ZONE, 'dwell': 0.0})
    assert run(events, separations([0.2]), task=None) == [(0.0, 'near')]
    with pytest.raises(ValueError, match='time went backwards'):
        events.update(Observation(-1.0, 0.2), 'follow')
    with pytest.raises(ValueError, match='time must be finite'):
        events.update(Observation(math.nan, 0.2), 'follow')


def test_firing_names_the_event_and_task_and_says_why():
    events = detector(near={**ZONE, 'dwell': 0.0, 'event': 'hand_too_close'})
    firing, = events.update(Observation(0.0, 0.2, since_hand=0.0), 'follow')
    assert (firing.rule.event, firing.rule.task) == ('hand_too_close', 'avoid')
    assert firing.reason.startswith('separation 0.200 m: inside 0.3 m')


# -- loading ------------------------------------------------------------------------------------

def test_the_default_rule_set_loads_and_runs_follow_avoid_follow_safe():
    rules = load_rules(load_defaults('hri_adaptive_controller', 'event_detector')['rules'])
    assert {r.name: r.task for r in rules} == {'hand_reaches_in': 'avoid',
                                               'hand_rests': 'follow_safe',
                                               'hand_lost': '', 'hand_back': 'follow_safe'}
    events = EventDetector(rules)
    task, switches = 'follow', []
    # The arm follows a still hand 0.3 m away (the arm comes at 0.25 m/s: no event) ...
    timeline = separations(np.linspace(0.3, 0.05, 50), robot_speed=0.25)
    # ... the hand reaches in at 0.5 m/s, rests 4 s, withdraws slowly.
    timeline += separations(np.linspace(0.3, 0.1, 20), start=1.0, hand_speed=0.5,
                            hand_motion=0.5)
    timeline += separations([0.18] * 200, start=1.4, hand_motion=0.01)
    timeline += separations(np.linspace(0.2, 0.25, 100), start=5.4, hand_speed=-0.1,
                            hand_motion=0.1)
    for obs in timeline:
        for firing in events.update(obs, task):
            task = firing.rule.task
            switches.append((round(firing.time, 6), firing.rule.event, task))
    assert switches == [(1.0, 'hand_reaches_in', 'avoid'),
                        (1.4 + 3.0, 'hand_rests', 'follow_safe')]


@pytest.mark.parametrize(('text', 'message'), [
    ('- a\n- b', 'rules must be a mapping of rule name -> settings, got list'),
    ('a: {kind: zone_entered, task: avoid, distance: 0.3}\na: {kind: lost, task: x, '
     'timeout: 1}', "rules: 'a' is given twice \\(line 2\\)"),
    ('a: [1, 2', 'rules: not valid YAML'),
    ('a: 3', "rule 'a': expected a mapping of settings, got int"),
    ('a: {kind: wave, task: avoid}', "rule 'a': kind must be one of zone_entered, "),
    ('a: {kind: zone_entered, distance: 0.3}', "rule 'a': task is missing"),
    ('a: {kind: zone_entered, task: avoid, distnace: 0.3}',
     "rule 'a': unknown setting 'distnace' \\(settings of zone_entered: "),
    ('a: {kind: zone_entered, task: avoid}', "rule 'a': distance is missing \\(m\\)"),
    ('a: {kind: zone_entered, task: avoid, distance: -1}',
     "rule 'a': distance must be a number > 0 \\(m\\), got -1"),
    ('a: {kind: zone_entered, task: avoid, distance: .nan}', "distance must be a number > 0"),
    ('a: {kind: zone_entered, task: avoid, distance: true}', "distance must be a number > 0"),
    ('a: {kind: zone_entered, task: avoid, distance: 0.1, hysteresis: 0.2}',
     'hysteresis 0.2 m must be below twice the distance 0.1 m'),
    ('a: {kind: approach, task: avoid}', 'give exactly one of min_speed .* got 0'),
    ('a: {kind: approach, task: avoid, min_speed: 1, max_time_to_contact: 1}',
     'give exactly one of min_speed .* got 2'),
    ('a: {kind: approach, task: avoid, min_speed: 0.1, hysteresis: 0.1}',
     'hysteresis 0.1 m/s must be below min_speed 0.1 m/s'),
    ('a: {kind: approach, task: avoid, min_speed: 0.3, speed_of: tool}',
     "speed_of must be one of closing, hand, got 'tool'"),
    ('a: {kind: still, task: avoid, max_speed: 0.1}', "rule 'a': duration is missing \\(s\\)"),
    ('a: {kind: lost, task: 3, timeout: 1}', "rule 'a': task must be a string, got 3"),
    ('a: {kind: lost, task: x, timeout: 1, event: ""}', 'event must be a non-empty string'),
    ('a: {kind: lost, task: x, timeout: 1, when_task: [1]}', 'when_task must be a task name'),
    ('a: {kind: lost, task: x, timeout: 1, hold_off: -1}', 'hold_off must be a number >= 0'),
])
def test_a_bad_rule_is_one_line_naming_it(text, message):
    with pytest.raises(RuleError, match=message) as error:
        load_rules(text)
    assert '\n' not in str(error.value)


def test_no_rules_is_allowed():
    assert load_rules('') == ()
    assert load_rules('{}') == ()


# -- property: no chatter from a noisy resting hand -------------------------------------------

BOUNDARY = 0.3  # m
NOISE = 0.005  # m


def hand_noise(kind: str, seed: int, frequency: float, times: np.ndarray) -> np.ndarray:
    """+-5 mm of noise: uniform, alternating every sample, or a square wave (Hz)."""
    if kind == 'uniform':
        return np.random.default_rng(seed).uniform(-NOISE, NOISE, times.size)
    if kind == 'alternating':
        return NOISE * (-1.0) ** np.arange(times.size)
    return NOISE * np.sign(np.sin(2.0 * math.pi * frequency * times + seed))


@settings(max_examples=40, deadline=None)
@given(kind=st.sampled_from(['uniform', 'alternating', 'square']),
       seed=st.integers(0, 2 ** 16), frequency=st.floats(0.2, 20.0),
       from_inside=st.booleans(), task=st.sampled_from(['follow', 'follow_safe', 'avoid']))
def test_a_hand_resting_on_a_zone_boundary_with_5_mm_noise_fires_nothing_for_10_s(
        kind, seed, frequency, from_inside, task):
    """The hand comes slowly (0.1 m/s) to a zone boundary from either side, then rests on it
    for 10 s with +-5 mm of noise on its position; the hand's velocity is estimated from the
    noisy positions at 100 Hz as the node does (hri_core.velocity_estimator, the node's
    default hand_filter_time). Zone, approach and lost rules, with no dwell, and the default
    rule set but its still rule (a resting hand is still): nothing fires while it rests."""
    from hri_core.velocity_estimator import VelocityEstimator
    defaults = load_defaults('hri_adaptive_controller', 'event_detector')
    default_rules = [rule for rule in load_rules(defaults['rules']) if rule.kind != 'still']
    rules = parse_rules({
        'in': {'kind': 'zone_entered', 'task': 'avoid', 'distance': BOUNDARY, 'dwell': 0.0},
        'out': {'kind': 'zone_left', 'task': 'follow', 'distance': BOUNDARY, 'dwell': 0.0},
        'reach': {'kind': 'approach', 'task': 'avoid', 'min_speed': 0.2, 'dwell': 0.0},
        'ttc': {'kind': 'approach', 'task': 'avoid', 'max_time_to_contact': 0.5, 'dwell': 0.0},
        'gone': {'kind': 'lost', 'task': '', 'timeout': 0.2},
    })
    events = EventDetector([*rules, *default_rules])
    estimator = VelocityEstimator(defaults['hand_filter_time'])
    start = BOUNDARY + (-0.1 if from_inside else 0.1)
    arrive = 1.0  # s at 0.1 m/s
    times = np.arange(0.0, arrive + 10.0, 0.01)
    path = np.where(times < arrive, start + (BOUNDARY - start) * times / arrive, BOUNDARY)
    path = path + np.where(times >= arrive, hand_noise(kind, seed, frequency, times), 0.0)
    fired = []
    for t, sep in zip(times, path, strict=True):
        velocity = estimator.update((sep, 0.0), t)[0]  # the tool at the origin
        obs = Observation(t, sep, hand_speed=-velocity, hand_motion=abs(velocity),
                          since_hand=0.0)
        fired += [(t, f.rule.name) for f in events.update(obs, task)]
    resting = [(t, name) for t, name in fired if t >= arrive]
    assert resting == []
