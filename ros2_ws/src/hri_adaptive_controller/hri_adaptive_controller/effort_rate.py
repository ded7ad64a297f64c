"""Rate limit of the commanded torque: the last stage of the torque command, after the clamp.

Like libfranka's rate limiter (franka::limitRate), each joint's torque moves from the last
command towards the one the control law asks for by at most max_rate * dt,

    tau_i = tau_prev_i + clip(tau_law_i - tau_prev_i, -max_rate dt, max_rate dt),

dt (s) the time since the last command. The controller node passes the joint states' stamp
difference but at most one control period: after cycles it skipped (a loaded machine), the
drive may still apply its command one step after the previous one (measured on the topics:
commands from states 2 ms apart applied at consecutive 1 ms steps), so each command moves by
at most one cycle's worth.

That bounds each command against the one before, not what the drive applies: on a loaded
machine the simulator took commands in late bursts and applied only the newest, stepping its
torque by the sum of the commands it skipped (2.95 N m between consecutive joint states,
measured, with every command within 1 N m of the one before). Where the joint states report
the torque the drive applies (a simulator's JointState.effort: an echo of a command sent,
which CommandEcho recognises; a measured torque never is one), each command also stays within
applied_band of it: a burst computed while the drive held one torque lies within that band of
it, whichever command of the burst the drive takes. The step bound is never given up for the
band: where the drive lags further than the band reaches (the last command more than a step
outside the band of the torque it applies), the command walks back towards the band at the
rate limit (a command stepping 1.5 N m was seen beside a busy process when the band won).
Applied after the clamp to
effort_limit: tau_prev and tau_law both lie in the box |tau_i| <= effort_limit, so tau does too.
It bounds what reaches the drives whatever the reason the law's torque jumps (a control cycle
the loaded machine ran late, an input that arrived late); the law itself is continuous
(task_variable, signal_hold), so in normal operation the limit does not act. The zero-torque
paths (stale or invalid input, a fault) bypass it and reset it to zero: safety first.
Units: N m, N m/s, s. No ROS import.
"""

import math
from collections.abc import Sequence


class EffortRateLimiter:
    """Limits the change of a torque vector to max_rate (N m/s, > 0) times the elapsed time.

    Starts from zero torque (what the drives apply before the first command).
    """

    def __init__(self, max_rate: float, joints: int = 2):
        if not (math.isfinite(max_rate) and max_rate > 0.0):
            raise ValueError(f'max_rate must be finite and > 0 N m/s, got {max_rate}')
        self.max_rate = float(max_rate)
        self._joints = joints
        self.reset()

    def reset(self, tau: Sequence[float] | None = None) -> None:
        """The torque now applied (default zero), the start of the next limited change."""
        self.previous = tuple(0.0 for _ in range(self._joints)) if tau is None else tuple(
            float(v) for v in tau)

    def limit(self, tau: Sequence[float], dt: float, applied: Sequence[float] | None = None,
              applied_band: float = math.inf) -> tuple[tuple[float, ...], bool]:
        """(torque to command, whether a limit acted) for the law's torque `tau` (n,) N m,
        dt s after the previous command (dt >= 0; finite values, checked by the caller).

        applied (n,) N m: the torque the drive reports it applies now (None: not known),
        clamped by the caller to the effort limits (so the command stays within them); each
        joint's command then also stays within applied_band (N m) of it where that is within
        a step of the last command, else it moves a whole step towards that band.
        """
        step = self.max_rate * max(dt, 0.0)
        limited = False
        out = []
        for i, (wanted, before) in enumerate(zip(tau, self.previous, strict=True)):
            change = wanted - before
            if change > step:
                change, limited = step, True
            elif change < -step:
                change, limited = -step, True
            value = before + change
            if applied is not None:
                low = max(applied[i] - applied_band, before - step)
                high = min(applied[i] + applied_band, before + step)
                if low > high:  # the band is more than a step away: a step towards it
                    value = before - step if applied[i] < before else before + step
                    limited = True
                elif value > high:
                    value, limited = high, True
                elif value < low:
                    value, limited = low, True
            out.append(value)
        self.previous = tuple(out)
        return self.previous, limited


class CommandEcho:
    """Recognises a joint state's effort as a command this controller sent: the torque a
    simulator reports as applied is the command it took, bit for bit, while a real drive's
    JointState.effort is a measured torque that never equals one. Only an echo is a torque
    the applied band may be centred on.

    Keeps the last `depth` commands (tuples of floats, N m); a late burst is a few tens.
    """

    def __init__(self, depth: int = 64):
        if depth < 1:
            raise ValueError(f'depth must be >= 1, got {depth}')
        self._depth = depth
        self._sent: dict[tuple, None] = {}

    def sent(self, command: tuple) -> None:
        """Remember `command`, the newest sent (forgetting the oldest beyond depth)."""
        sent = self._sent
        sent.pop(command, None)
        sent[command] = None
        if len(sent) > self._depth:
            del sent[next(iter(sent))]

    def applied(self, effort: tuple | None) -> tuple | None:
        """`effort` if it is one of the remembered commands (the drive applies it), else
        None."""
        return effort if effort is not None and effort in self._sent else None
