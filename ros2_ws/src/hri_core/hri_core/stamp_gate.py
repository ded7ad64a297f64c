"""Which messages of a stream to use, by their header stamps, across restarts of the source.

A subscriber uses a message only if its stamp is newer than the last one it used: a delayed or
repeated message must not replace a newer state. Taken alone that rule ignores a restarted
source for good whenever the new source's stamps start behind the old one's (a simulator whose
clock starts again, a source on a machine whose clock is behind, a bag replayed again).

`StampGate` therefore recognises a restart: a stamp more than `restart_jump` s behind the last
one used starts a candidate stream, and once `confirm_count` consecutive messages of that
stream have advanced (each newer than the one before, all still behind the old stream), the
gate accepts the new stream: the message that confirms it is used, and the gate follows the
new stream from then on. A single stale or stray message never does this, nor does jitter
smaller than `restart_jump`. Messages of the old stream that arrive after the switch are then
far ahead of the new stream and are used (the stamps decide, as before); a source that stays
down does not send any.

Pure: no ROS import; stamps are seconds (float) on the source's clock.
"""

from dataclasses import dataclass

USED = 'used'
"""The message is newer than the last one used: use it."""
DROPPED = 'dropped'
"""The message is not newer than the last one used (and does not confirm a restart)."""
RESTARTED = 'restarted'
"""The message confirms a restarted source: use it; the gate now follows the new stream."""


@dataclass
class StampGate:
    """Stamp filter of one message stream (module docstring gives the rule).

    restart_jump: s, > 0; how far behind the last used stamp a stamp must be to start a
    candidate restart. confirm_count: >= 1; advancing messages of the candidate stream that
    confirm the restart. strict: True to drop a stamp equal to the last one used (for a stream
    in which two messages must not share a stamp), False to use it.
    """

    restart_jump: float
    confirm_count: int
    strict: bool = True

    def __post_init__(self):
        if not self.restart_jump > 0.0:
            raise ValueError(f'restart_jump must be > 0 s, got {self.restart_jump}')
        if self.confirm_count < 1:
            raise ValueError(f'confirm_count must be >= 1, got {self.confirm_count}')
        self.last: float | None = None
        self._candidate_last: float | None = None
        self._candidate_count = 0

    def offer(self, stamp: float) -> str:
        """USED, DROPPED or RESTARTED for a message stamped `stamp` (s, finite)."""
        last = self.last
        if last is None or stamp > last or (stamp == last and not self.strict):
            self.last = stamp
            self._candidate_last, self._candidate_count = None, 0
            return USED
        if last - stamp <= self.restart_jump:
            return DROPPED
        if self._candidate_last is not None and stamp > self._candidate_last:
            self._candidate_count += 1
        else:
            self._candidate_count = 1
        self._candidate_last = stamp
        if self._candidate_count < self.confirm_count:
            return DROPPED
        self.last = stamp
        self._candidate_last, self._candidate_count = None, 0
        return RESTARTED

    def behind(self, stamp: float) -> float:
        """How far (s) `stamp` is behind the last used stamp (0 if not behind)."""
        return 0.0 if self.last is None else max(0.0, self.last - stamp)
