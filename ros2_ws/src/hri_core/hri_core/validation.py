"""Checks of numbers, planar and spatial vectors at the boundary of the pure modules. No ROS
import.

Each returns the value converted (float, a (2,) or (3,) float array, or an (N, 3) one) or raises
ValueError with a one-line reason naming the argument, so that a node can log that line as it
is. Positions travel in 3-D ([x, y, z]); the planar checks stay for the planar arm's code.
"""

import math

import numpy as np


def planar_vector(value, name: str, unit: str = '') -> np.ndarray:
    """`value` as a finite float array of shape (2,) ([x, y], in `unit`); ValueError otherwise.

    A (1, 2) or (2, 1) input is accepted and flattened; any other size is refused.
    """
    array = np.asarray(value, dtype=float).reshape(-1)
    if array.shape != (2,) or not np.all(np.isfinite(array)):
        where = f' in {unit}' if unit else ''
        raise ValueError(f'{name} must be 2 finite values [x, y]{where}, got {np.ravel(value)}')
    return array


def spatial_vector(value, name: str, unit: str = '') -> np.ndarray:
    """`value` as a finite float array of shape (3,) ([x, y, z], in `unit`); ValueError
    otherwise. A (1, 3) or (3, 1) input is accepted and flattened; any other size is refused.
    """
    array = np.asarray(value, dtype=float).reshape(-1)
    if array.shape != (3,) or not np.all(np.isfinite(array)):
        where = f' in {unit}' if unit else ''
        raise ValueError(f'{name} must be 3 finite values [x, y, z]{where}, '
                         f'got {np.ravel(value)}')
    return array


def spatial_points(value, name: str, unit: str = '') -> np.ndarray:
    """`value` as a finite float array (N, 3) of points [x, y, z] (in `unit`); planar points
    (N, 2) are the plane z = 0 and get a zero z column. ValueError otherwise."""
    array = np.asarray(value, dtype=float)
    if array.ndim != 2 or array.shape[1] not in (2, 3):
        raise ValueError(f'{name} must be (N, 3) points [x, y, z] (or (N, 2) in the plane '
                         f'z = 0), got shape {array.shape}')
    if not np.all(np.isfinite(array)):
        raise ValueError(f'{name} must be finite{" (" + unit + ")" if unit else ""}')
    if array.shape[1] == 2:
        array = np.column_stack([array, np.zeros(len(array))])
    return array


def positive(value: float, name: str, unit: str = '') -> float:
    """`value` as a float; ValueError unless it is finite and > 0 (`unit` names its unit)."""
    value = float(value)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f'{name} must be finite and > 0{" " + unit if unit else ""}, '
                         f'got {value}')
    return value


def point_vector(value, name: str, unit: str = '') -> np.ndarray:
    """`value` as a finite float array of shape (2,) ([x, y], a point of a planar arm) or
    (3,) ([x, y, z]); ValueError otherwise. A row or column of 2 or 3 is flattened."""
    array = np.asarray(value, dtype=float).reshape(-1)
    if array.shape not in ((2,), (3,)) or not np.all(np.isfinite(array)):
        where = f' in {unit}' if unit else ''
        raise ValueError(f'{name} must be 2 or 3 finite values [x, y(, z)]{where}, got '
                         f'{np.ravel(value)}')
    return array


def check_frame(frame: str, base_frame: str) -> None:
    """ValueError unless a message's header frame `frame` is `base_frame` or unset (''): the
    project's nodes transform nothing, so a point in another frame would be used at the wrong
    place; an empty frame_id is taken as the base frame (a bare publisher)."""
    if frame not in ('', base_frame):
        raise ValueError(f'frame {frame!r} is not base_frame {base_frame!r}')
