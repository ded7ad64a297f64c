"""Unit tests of hri_core.stamp_gate: stale messages dropped, a restarted source accepted."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hri_core.stamp_gate import DROPPED, RESTARTED, USED, StampGate


def offer_all(gate, stamps):
    return [gate.offer(stamp) for stamp in stamps]


def test_advancing_stamps_are_used_and_stale_ones_dropped():
    gate = StampGate(restart_jump=0.5, confirm_count=5)
    assert offer_all(gate, [1.0, 1.001, 1.002]) == [USED] * 3
    assert offer_all(gate, [1.002, 1.0015, 0.9]) == [DROPPED] * 3
    assert gate.last == 1.002
    assert gate.behind(0.9) == pytest.approx(0.102)


def test_equal_stamps_are_used_only_when_not_strict():
    assert offer_all(StampGate(0.5, 5, strict=False), [1.0, 1.0]) == [USED, USED]
    assert offer_all(StampGate(0.5, 5, strict=True), [1.0, 1.0]) == [USED, DROPPED]


def test_a_restarted_source_is_accepted_after_confirm_count_advancing_messages():
    gate = StampGate(restart_jump=0.5, confirm_count=5)
    offer_all(gate, [30.0 + 0.001 * k for k in range(10)])
    restarted = [0.001 * k for k in range(8)]  # the new source's clock starts at 0
    assert offer_all(gate, restarted) == [DROPPED] * 4 + [RESTARTED] + [USED] * 3
    assert gate.last == restarted[-1]


def test_stray_stale_messages_never_restart_the_gate():
    gate = StampGate(restart_jump=0.5, confirm_count=3)
    gate.offer(10.0)
    # Stale messages that do not advance among themselves (e.g. a repeated old one).
    assert offer_all(gate, [2.0, 2.0, 1.0, 2.0, 1.5, 1.5]) == [DROPPED] * 6
    # Jitter within restart_jump never counts towards a restart.
    assert offer_all(gate, [9.6, 9.7, 9.8, 9.9]) == [DROPPED] * 4
    assert gate.last == 10.0


def test_a_new_message_of_the_old_stream_resets_the_candidate():
    gate = StampGate(restart_jump=0.5, confirm_count=3)
    gate.offer(10.0)
    assert offer_all(gate, [1.0, 1.1, 10.1, 1.2, 1.3]) == [DROPPED, DROPPED, USED, DROPPED,
                                                          DROPPED]
    assert gate.offer(1.4) == RESTARTED


@pytest.mark.parametrize(('kwargs', 'match'), [
    ({'restart_jump': 0.0, 'confirm_count': 3}, 'restart_jump must be > 0'),
    ({'restart_jump': float('nan'), 'confirm_count': 3}, 'restart_jump must be > 0'),
    ({'restart_jump': 0.5, 'confirm_count': 0}, 'confirm_count must be >= 1'),
])
def test_bad_settings_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        StampGate(**kwargs)


@given(stamps=st.lists(st.floats(-1e6, 1e6), max_size=60), jump=st.floats(1e-3, 10.0),
       count=st.integers(1, 6))
def test_used_stamps_advance_except_at_a_confirmed_restart(stamps, jump, count):
    gate = StampGate(jump, count)
    used = []
    for stamp in stamps:
        verdict = gate.offer(stamp)
        if verdict == USED:
            assert not used or stamp > used[-1]
        elif verdict == RESTARTED:
            assert used and used[-1] - stamp > jump
        if verdict != DROPPED:
            used.append(stamp)
        assert gate.last == (used[-1] if used else None)
