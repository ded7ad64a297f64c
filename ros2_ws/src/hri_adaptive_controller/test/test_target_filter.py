"""Unit tests of target_filter: jumps held and counted, re-anchoring, dropouts, recorded takes."""

import math
from pathlib import Path

import numpy as np
import pytest

from hri_adaptive_controller.target_filter import (
    FilteredHand,
    TargetFilter,
    TargetFilterSettings,
)
from hri_core.recorded_motion import read_vicon_csv

TAKES = sorted((Path(__file__).resolve().parents[4] / 'data' / 'human-motion').glob('*.csv'))
RATE = 100.0


def circle(duration=4.0, speed=0.3, radius=0.3, rate=RATE):
    t = np.arange(0.0, duration, 1.0 / rate)
    angle = speed / radius * t
    return t, np.column_stack([0.4 + radius * np.cos(angle), radius * np.sin(angle)])


def offer_all(flt, t, path):
    return np.array([flt.offer(float(s), p) for s, p in zip(t, path, strict=True)])


@pytest.mark.parametrize('take', TAKES, ids=lambda p: p.stem)
def test_recorded_hands_are_followed_and_only_their_swaps_held(take):
    motion = read_vicon_csv(take)
    seen = motion.valid
    flt = TargetFilter()
    accepted = offer_all(flt, motion.times[seen], motion.positions[seen, :2])
    if take.stem == 'HumanRobotHandover_0':
        # two marker swaps of 6 cm, 9 and 12 frames long, held whole; nothing else
        held = np.flatnonzero(seen)[~accepted]
        assert held.tolist() == list(range(1014, 1023)) + list(range(1062, 1074))
    else:
        assert accepted.all(), f'{flt.glitches} samples of a real hand held'
    assert flt.reanchors == 0


def test_fast_real_hand_is_followed():
    t, path = circle(speed=3.0, radius=0.25)        # 3 m/s, 36 m/s^2 centripetal
    flt = TargetFilter()
    assert offer_all(flt, t, path).all()


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_marker_swaps_are_held_and_counted(seed):
    rng = np.random.default_rng(seed)
    t, path = circle()
    glitched = path.copy()
    swaps = []
    for start in rng.choice(np.arange(20, len(t) - 30, 40), 5, replace=False):
        length = int(rng.integers(1, 12))                   # 10-110 ms
        glitched[start:start + length] += rng.uniform(-2.0, 2.0, 2)  # metres in one frame
        swaps.append((start, length))
    flt = TargetFilter()
    accepted = offer_all(flt, t, glitched)
    expected = np.ones(len(t), dtype=bool)
    for start, length in swaps:
        expected[start:start + length] = False
    np.testing.assert_array_equal(accepted, expected)
    assert flt.glitches == sum(length for _, length in swaps)
    assert flt.reanchors == 0


def run_at_1khz(hand, t, path):
    """Offers at the samples' rate, evaluations at 1 kHz between them, as the controller
    does: (accepted (N,), evaluation times (M,), x_d (M, 2))."""
    accepted, times, held = [], [], []
    for k, (s, p) in enumerate(zip(t, path, strict=True)):
        accepted.append(hand.offer(float(s), p))
        end = t[k + 1] if k + 1 < len(t) else s + 0.01
        for u in np.arange(s, end - 1e-9, 1e-3):
            times.append(u)
            held.append(hand.evaluate(float(u))[0])
    return np.array(accepted), np.array(times), np.array(held)


def test_a_long_swap_reanchors_after_the_confirm_time_with_a_slow_blend():
    t, path = circle(duration=3.0, speed=0.1)
    moved = path.copy()
    moved[100:] += (0.8, 0.0)                               # the hand "is" 0.8 m away for good
    hand = FilteredHand()
    accepted, times, held = run_at_1khz(hand, t, moved)
    assert accepted[:100].all()
    assert not accepted[100:120].any()                      # held for 0.2 s
    assert accepted[120:].all()                             # then followed
    assert hand.reanchors == 1 and hand.glitches == 20
    # x_d glides to the new place over |jump| / blend_speed (0.8 s), C1: no step
    steps = np.linalg.norm(np.diff(held, axis=0), axis=1)
    assert steps.max() < 15.0 / 8.0 * 1.0 * 1e-3 + 2e-4    # the smoothstep's peak speed
    after = times >= 1.2 + 0.8 + 0.01
    np.testing.assert_allclose(held[after][::10], moved[201:], atol=0.002)


def test_a_still_hand_after_a_stall_that_split_a_swap_is_followed_again():
    # 50 Hz, a swap of 2 frames 1.5 m away, then the sender stalls 0.34 s and the hand is
    # back where it was: it must come through a candidate (samples were held since the
    # anchor), which it does within confirm_time, though the anchor predicts it as well.
    hand, far = (0.456, 0.403), (0.456, 1.903)
    stamps = [0.02 * k for k in range(10)] + [0.2, 0.22] + [0.56 + 0.02 * k for k in range(30)]
    points = [hand] * 10 + [far] * 2 + [hand] * 30
    flt = TargetFilter()
    accepted = offer_all(flt, np.array(stamps), np.array(points))
    assert accepted[:10].all() and not accepted[10:12].any()
    back = np.flatnonzero(accepted[12:])
    assert back.size and stamps[12 + back[0]] - stamps[12] <= 0.2 + 0.02 + 1e-9
    assert accepted[12 + back[0]:].all()


@pytest.mark.parametrize('seed', [0, 1])
def test_swaps_amid_random_stalls_never_hold_the_hand_for_long(seed):
    # A still hand at 50 Hz with a 3-frame swap each second, the sender stalling now and then
    # (10 % of the frames, 0.15 s on average) and the receiver missing 30 % of the samples
    # (a depth-1 subscription): the hand is never held for more than the confirm time after
    # the longest stall.
    rng = np.random.default_rng(seed)
    hand, far = np.array([0.456, 0.403]), np.array([0.456, 1.903])
    swaps = {k for start in range(50, 600, 50) for k in (start, start + 1, start + 2)}
    gaps = 0.02 + np.where(rng.random(600) < 0.1, rng.exponential(0.15, 600), 0.0)
    stamps = np.cumsum(gaps)
    flt = TargetFilter()
    held_since = None
    longest = 0.0
    for k in np.flatnonzero(rng.random(600) >= 0.3):
        accepted = flt.offer(float(stamps[k]), far if k in swaps else hand)
        if k in swaps:
            continue
        if accepted:
            held_since = None
        else:
            held_since = stamps[k] if held_since is None else held_since
            longest = max(longest, stamps[k] - held_since)
    assert longest <= 0.2 + gaps.max() + 0.04, longest


def test_jitter_of_inconsistent_garbage_never_reanchors():
    rng = np.random.default_rng(4)
    t, path = circle(duration=2.0)
    garbage = path.copy()
    garbage[50:] = rng.uniform(-3.0, 3.0, (len(t) - 50, 2))  # no hand there at all
    hand = FilteredHand()
    accepted = np.array([hand.offer(float(s), p) for s, p in zip(t, garbage, strict=True)])
    assert not accepted[50:].any() and hand.reanchors == 0
    # the hand is gone: presence fades to 0 after timeout + fade_time
    assert hand.presence(0.49 + 0.5 - 0.01).weight == 1.0
    assert hand.presence(0.49 + 0.5 + 1.0 + 0.01).weight == 0.0


def test_dropout_holds_then_fades_then_returns():
    settings = TargetFilterSettings(timeout=0.5, fade_time=1.0)
    hand = FilteredHand(settings)
    t, path = circle(duration=1.0, speed=0.2)
    for s, p in zip(t, path, strict=True):
        hand.offer(float(s), p)
        assert hand.presence(float(s)).weight == 1.0
    last = float(t[-1])
    held, _ = hand.evaluate(last + 0.5)
    held_later, velocity = hand.evaluate(last + 1.0)
    assert held == held_later and velocity == (0.0, 0.0)    # first order for 0.05 s, then held
    weights = [hand.presence(last + 0.5 + k * 0.01) for k in range(0, 103)]
    values = np.array([w.weight for w in weights])
    assert values[0] == 1.0 and values[-1] == 0.0
    assert np.all(np.diff(values) <= 1e-12)                 # a monotone fade
    assert max(abs(w.rate) for w in weights) <= 15.0 / 8.0 + 1e-9
    # the hand comes back 0.3 m away: taken (a hand can move that far in 1.5 s), blended
    # over 0.3 m / blend_speed, and the presence fades in again
    back = last + 1.6
    there = path[-1] + (0.0, 0.3)
    assert hand.offer(back, there)
    assert hand.presence(back).weight == 0.0
    start = hand.evaluate(back)[0]
    assert np.linalg.norm(np.subtract(start, held)) < 1e-9   # no step where it lands
    assert hand.evaluate(back + 0.301)[0] == pytest.approx(tuple(there), abs=1e-9)
    for k in range(1, 120):                                  # the hand stays there
        assert hand.offer(back + k * 0.01, there)
    assert hand.presence(back + 1.01).weight == 1.0


def test_reset_forgets_the_anchor():
    flt = TargetFilter()
    assert flt.offer(0.0, (0.4, 0.0))
    assert not flt.offer(0.01, (2.4, 0.0))
    flt.reset()
    assert flt.offer(0.02, (2.4, 0.0)) and flt.glitches == 1


def test_three_dimensional_positions():
    flt = TargetFilter()
    assert flt.offer(0.0, (0.4, 0.0, 0.9))
    assert flt.offer(0.01, (0.401, 0.0, 0.9))
    assert not flt.offer(0.02, (0.402, 0.0, 1.5))


@pytest.mark.parametrize('field, value, reason', [
    ('max_speed', 0.0, 'max_speed must be finite and > 0'),
    ('tolerance', math.nan, 'tolerance must be finite'),
    ('confirm_samples', 0, 'confirm_samples must be an integer >= 1'),
    ('max_extrapolation', -1.0, 'max_extrapolation must be finite and >= 0'),
])
def test_bad_settings_are_rejected(field, value, reason):
    with pytest.raises(ValueError, match=reason):
        TargetFilterSettings(**{field: value})


def test_presence_starts_again_when_the_clock_goes_back():
    hand = FilteredHand()
    for k in range(50):
        hand.offer(100.0 + k * 0.01, (0.4, 0.0))
        assert hand.presence(100.0 + k * 0.01).weight == 1.0
    hand.reset()                                             # a source restarted at t = 0
    assert hand.offer(0.0, (0.4, 0.0))
    assert hand.presence(0.001).weight == 1.0
    assert hand.presence(0.499).weight == 1.0               # within timeout of 0.0 ...
    assert hand.presence(0.5 + 1.5).weight == 0.0           # ... then faded out
