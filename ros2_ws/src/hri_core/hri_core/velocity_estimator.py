"""The velocity of a point from its stamped positions: low-passed finite differences.

Used for the end-effector (the demonstrator) and for the human hand on /target (the
controller's x_d dot of eq. 14). Positions (2,) in m, stamps in s. No ROS import.
"""

import numpy as np

from hri_core.validation import planar_vector, positive


class VelocityEstimator:
    """End-effector velocity (2,) in m/s from stamped positions: low-passed differences.

    Each new sample's finite difference goes through a first-order low-pass of time constant
    `time_constant` s. A sample whose stamp does not advance is ignored.
    """

    def __init__(self, time_constant: float):
        self._tc = positive(time_constant, 'time_constant', 's')
        self._last = None
        self.velocity = np.zeros(2)

    def reset(self) -> None:
        """Forget the past samples (a restarted source: its stamps start again); velocity 0."""
        self._last = None
        self.velocity = np.zeros(2)

    def update(self, position, stamp: float) -> np.ndarray:
        """Feed a position (2,) in m taken at `stamp` s; return the filtered velocity."""
        position = planar_vector(position, 'position', 'm')
        if self._last is not None:
            dt = stamp - self._last[1]
            if dt <= 0.0:
                return self.velocity
            raw = (position - self._last[0]) / dt
            alpha = dt / (self._tc + dt)
            self.velocity = self.velocity + alpha * (raw - self.velocity)
        self._last = (position, stamp)
        return self.velocity
