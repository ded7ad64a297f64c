"""Scripted demonstrations of any arm written as bags, without a simulator (no ROS import).

What the benchmark and the tests feed the learner when they need a demonstration of a known
shape, or one far longer than a simulation could record in time:

* `push_path(times, start, goal, begin, duration)`: the tool at rest at `start` (3,) m, a
  minimum-jerk push to `goal` (3,) m from `begin` s for `duration` s, at rest at `goal` after;
  (N, 3) m at `times` (N,) s;
* `joint_path(model, points, q0)`: joint positions (N, n) whose tool point (RobotModel) follows
  `points` (N, 3) m, by damped Gauss-Newton steps from `q0` (each sample starting from the
  last one's solution; a sample equal to the one before costs nothing), with the joints kept
  inside their limits; ValueError if a point is not reached within IK_TOLERANCE;
* `write_demonstration_bag(path, demo)`: a rosbag2 bag (bag_io.BagWriter) of a
  `JointDemonstration`: /joint_states (its joint names; positions, velocities by
  finite differences, zero efforts) at every sample, /demo/reference (x_r) every
  `reference_period` samples, optionally the URDF on /robot_description (std_msgs/String,
  once, first) and the tool path on /ee_position.
"""

import os
from dataclasses import dataclass

import numpy as np

from hri_core import topics
from hri_core.cdr import joint_state_template, point_stamped_template
from hri_core.robot_model import RobotModel
from hri_demo_learning.bag_io import BagWriter

IK_TOLERANCE = 1e-9  # m: largest distance of the tool point from the path it must follow
IK_DAMPING = 1e-6  # m^2: damping of the Gauss-Newton step (J^T (J J^T + damping I)^-1)
IK_MAX_STEPS = 50  # per sample


def minimum_jerk(tau: np.ndarray) -> np.ndarray:
    """The minimum-jerk blend 10 tau^3 - 15 tau^4 + 6 tau^5 of tau clipped to [0, 1]."""
    tau = np.clip(tau, 0.0, 1.0)
    return tau ** 3 * (10.0 - 15.0 * tau + 6.0 * tau ** 2)


def push_path(times, start, goal, begin: float, duration: float) -> np.ndarray:
    """Tool points (N, 3) m at `times` (N,) s: at `start` until `begin` s, a minimum-jerk
    push to `goal` lasting `duration` s, at `goal` after."""
    start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
    blend = minimum_jerk((np.asarray(times, dtype=float) - begin) / duration)
    return start + blend[:, None] * (goal - start)


def joint_path(model: RobotModel, points, q0) -> np.ndarray:
    """Joint positions (N, n) whose tool point follows `points` (N, 3) m (module docstring)."""
    points = np.asarray(points, dtype=float)
    q = model.joint_vector(q0, 'q0').copy()
    lower, upper = model.limits.lower, model.limits.upper
    path = np.empty((len(points), model.dof))
    previous = None
    for index, point in enumerate(points):
        if previous is not None and np.array_equal(point, previous):
            path[index] = q
            continue
        for _ in range(IK_MAX_STEPS):
            error = point - model.tool_position(q)
            if np.linalg.norm(error) <= IK_TOLERANCE:
                break
            jacobian = model.tool_jacobian(q)
            step = jacobian.T @ np.linalg.solve(jacobian @ jacobian.T + IK_DAMPING * np.eye(3),
                                                error)
            q = np.clip(q + step, lower, upper)
        else:
            raise ValueError(f'the tool point of {model.name} does not reach {point.tolist()} '
                             f'(sample {index}) within {IK_TOLERANCE} m')
        path[index] = q
        previous = point
    return path


@dataclass(frozen=True)
class JointDemonstration:
    """A scripted demonstration: the joints' names (n), times (N,) s from `start_ns`, joint
    positions (N, n), the reference x_r (3,) m, and what else the bag carries: the URDF text
    ('' = no /robot_description), the tool path (N, 3) m for /ee_position (None = none);
    reference_period: samples between /demo/reference messages."""

    joint_names: tuple[str, ...]
    times: np.ndarray
    q: np.ndarray
    reference: np.ndarray
    urdf: str = ''
    tool_path: np.ndarray | None = None
    reference_period: int = 100
    start_ns: int = 1_700_000_000 * 10**9


def write_demonstration_bag(path: str | os.PathLike, demo: JointDemonstration) -> dict:
    """Write `demo` into a new bag at `path` (module docstring); returns messages per topic."""
    stamps = demo.start_ns + np.rint(np.asarray(demo.times) * 1e9).astype(np.int64)
    velocities = np.gradient(demo.q, demo.times, axis=0) if len(demo.times) > 1 \
        else np.zeros_like(demo.q)
    joints = joint_state_template(demo.joint_names)
    point = point_stamped_template('base')
    zeros = [0.0] * len(demo.joint_names)
    reference = [float(v) for v in demo.reference]
    with BagWriter(path) as writer:
        types = writer.typestore.types
        if demo.urdf:
            description = writer.add_topic(topics.ROBOT_DESCRIPTION.name,
                                           topics.ROBOT_DESCRIPTION.type_name)
            writer.write(description, int(stamps[0]), writer.typestore.serialize_cdr(
                types['std_msgs/msg/String'](data=demo.urdf), 'std_msgs/msg/String'))
        joint_states = writer.add_topic(topics.JOINT_STATES.name, topics.JOINT_STATES.type_name)
        references = writer.add_topic(topics.DEMO_REFERENCE.name, topics.DEMO_REFERENCE.type_name)
        tool = None if demo.tool_path is None else writer.add_topic(
            topics.EE_POSITION.name, topics.EE_POSITION.type_name)
        for index, stamp in enumerate(stamps.tolist()):
            clock = (stamp // 10**9, stamp % 10**9)
            if index % demo.reference_period == 0:
                writer.write(references, stamp, point.encode(reference, stamp=clock))
            writer.write(joint_states, stamp, joints.encode(
                demo.q[index].tolist(), velocities[index].tolist(), zeros, stamp=clock))
            if tool is not None:
                writer.write(tool, stamp, point.encode(demo.tool_path[index].tolist(),
                                                       stamp=clock))
        return writer.counts
