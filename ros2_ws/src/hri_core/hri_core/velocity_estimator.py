"""The velocity of a point from its stamped positions: low-passed finite differences.

Used for the end-effector (the demonstrator) and for the human hand on /target (the
controller's x_d dot of eq. 14). Positions (d,) in m (d = 2, or 3 for a point in space),
stamps in s. No ROS import.
"""

import numpy as np

from hri_core.validation import planar_vector, point_vector, positive


class VelocityEstimator:
    """End-effector velocity (d,) in m/s from stamped positions: low-passed differences.

    Each new sample's finite difference goes through a first-order low-pass of time constant
    `time_constant` s. A sample whose stamp does not advance is ignored. `dimension`: d, the
    number of coordinates of each position (2 or 3).
    """

    def __init__(self, time_constant: float, dimension: int = 2):
        self._tc = positive(time_constant, 'time_constant', 's')
        if dimension not in (2, 3):
            raise ValueError(f'dimension must be 2 or 3, got {dimension}')
        self._dimension = dimension
        self._last = None
        self.velocity = np.zeros(dimension)

    def reset(self) -> None:
        """Forget the past samples (a restarted source: its stamps start again); velocity 0."""
        self._last = None
        self.velocity = np.zeros(self._dimension)

    def update(self, position, stamp: float) -> np.ndarray:
        """Feed a position (d,) in m taken at `stamp` s; return the filtered velocity."""
        if self._dimension == 2:
            position = planar_vector(position, 'position', 'm')
        else:
            position = point_vector(position, 'position', 'm')
            if position.size != 3:
                raise ValueError(f'position must be 3 values [x, y, z], got {position.size}')
        if self._last is not None:
            dt = stamp - self._last[1]
            if dt <= 0.0:
                return self.velocity
            raw = (position - self._last[0]) / dt
            alpha = dt / (self._tc + dt)
            self.velocity = self.velocity + alpha * (raw - self.velocity)
        self._last = (position, stamp)
        return self.velocity
