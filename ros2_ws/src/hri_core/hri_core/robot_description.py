"""The arm a /robot_description names, and the tool path of a whole joint trajectory at once.

A bag that carries its robot holds the URDF text that robot_state_publisher (or arm_sim)
publishes on /robot_description. `description_model(urdf_text, tool_frame)` builds the
hri_core.robot_model.PinocchioModel of it; the tool frame, when not given, is the robot's own
where the URDF names a robot the suite knows (robot_model.KNOWN_TOOL_FRAMES, from its table), else
the URDF's one end link (a serial chain ends in one link; several end links need `tool_frame`).

`ToolKinematics(model).positions(q)` is the forward kinematics of N joint vectors at once:
q (N, n) rad (m for a prismatic joint), columns in model.joint_names order -> tool points
(N, 3) m in the base frame, equal to pinocchio's forwardKinematics + updateFramePlacement
sample by sample (unit-tested to 1e-12) but about 20 times faster for a long recording:
x(q) = M_1(q_1) ... M_n(q_n) p_tool, with M_i = the joint's fixed placement in its parent
times its motion (a rotation about, or a translation along, its axis), is evaluated from the
tool point inwards, one (N, 3) array per joint (Rodrigues' formula for the rotations): no
(N, 3, 3) matrices and no Python loop over the samples. No ROS import.
"""

import xml.etree.ElementTree as ElementTree

import numpy as np

from hri_core.robot_model import KNOWN_TOOL_FRAMES, PinocchioModel


def _one_line(text) -> str:
    return ' '.join(str(text).split())


def _parse(urdf_text: str) -> ElementTree.Element:
    if not isinstance(urdf_text, str) or not urdf_text.strip():
        raise ValueError('the URDF is empty')
    try:
        root = ElementTree.fromstring(urdf_text)
    except ElementTree.ParseError as error:
        raise ValueError(f'not a valid URDF: {_one_line(error)}') from None
    if root.tag != 'robot':
        raise ValueError(f'not a valid URDF: its root element is <{root.tag}>, not <robot>')
    return root


def robot_name(urdf_text: str) -> str:
    """The name of the URDF's <robot> ('' if it has none). ValueError if not a URDF."""
    return _parse(urdf_text).get('name', '')


def urdf_joint_names(urdf_text: str) -> tuple[str, ...]:
    """Every joint the URDF declares, fixed ones included, in file order."""
    return tuple(joint.get('name', '') for joint in _parse(urdf_text).iter('joint'))


def default_tool_frame(urdf_text: str) -> str:
    """The tool frame of a URDF (module docstring); ValueError with the reason if none is
    clear."""
    root = _parse(urdf_text)
    name = root.get('name', '')
    if name in KNOWN_TOOL_FRAMES:
        return KNOWN_TOOL_FRAMES[name]
    links = [link.get('name', '') for link in root.iter('link')]
    parents = {parent.get('link') for joint in root.iter('joint')
               for parent in joint.iter('parent')}
    ends = [link for link in links if link not in parents]
    if len(ends) != 1:
        raise ValueError(f'the URDF of {name or "the robot"} has {len(ends)} end links '
                         f'({", ".join(ends[:6])}{" ..." if len(ends) > 6 else ""}): give '
                         'tool_frame, the link whose origin is the tool point')
    return ends[0]


def description_model(urdf_text: str, tool_frame: str = '') -> PinocchioModel:
    """The PinocchioModel of a /robot_description's URDF with its tool point at `tool_frame`
    ('' = default_tool_frame). ValueError with a one-line reason for an unreadable URDF or a
    tool frame it lacks."""
    name = robot_name(urdf_text) or 'urdf'
    return PinocchioModel(urdf_text, tool_frame or default_tool_frame(urdf_text), name=name)


def _rotation_matrix(placement) -> np.ndarray:
    return np.array(placement.rotation, dtype=float)


class ToolKinematics:
    """Batched forward kinematics of a PinocchioModel's tool point (module docstring).

    Raises ValueError if a joint of the model is neither a revolute nor a prismatic joint
    about a fixed axis (a helical joint, say) or the chain is not serial.
    """

    def __init__(self, model: PinocchioModel):
        import pinocchio as pin  # a heavy import, only for the arms that need it

        chain = model.model
        data = chain.createData()
        pin.computeJointJacobians(chain, data, model.home)
        self.joint_names = model.joint_names
        # Per joint: fixed rotation R (3, 3) and translation p (3,) from the parent joint's
        # frame, the unit axis a (3,) in the joint's frame, and whether it rotates about a.
        self._joints = []
        for joint in range(1, chain.njoints):
            if chain.parents[joint] != joint - 1:
                raise ValueError(f'the chain of {model.name} is not serial at joint '
                                 f'{chain.names[joint]!r}')
            motion = pin.getJointJacobian(chain, data, joint, pin.LOCAL)[:, chain.idx_vs[joint]]
            linear, angular = motion[:3], motion[3:]
            revolute = np.linalg.norm(linear) < 1e-12 and abs(np.linalg.norm(angular) - 1) < 1e-12
            prismatic = np.linalg.norm(angular) < 1e-12 and abs(np.linalg.norm(linear) - 1) < 1e-12
            if not (revolute or prismatic):
                raise ValueError(f'joint {chain.names[joint]!r} of {model.name} is neither a '
                                 'revolute nor a prismatic joint about a fixed axis')
            placement = chain.jointPlacements[joint]
            self._joints.append((_rotation_matrix(placement),
                                 np.array(placement.translation, dtype=float),
                                 angular.copy() if revolute else linear.copy(), revolute))
        tool = chain.frames[model.tool_frame_id]
        if tool.parentJoint != chain.njoints - 1:
            raise ValueError(f'the tool frame of {model.name} does not hang from its last joint')
        self._tool_point = np.array(tool.placement.translation, dtype=float)

    @property
    def dof(self) -> int:
        return len(self._joints)

    def positions(self, q) -> np.ndarray:
        """Tool points (N, 3) m of the joint vectors q (N, n) (columns in joint_names order).
        ValueError for a wrong shape or a non-finite value."""
        q = np.asarray(q, dtype=float)
        if q.ndim != 2 or q.shape[1] != self.dof:
            raise ValueError(f'joint positions must be (N, {self.dof}), got {q.shape}')
        if not np.all(np.isfinite(q)):
            raise ValueError('joint positions must be finite')
        # The point as three (N,) coordinate arrays: a rotation then costs a few scalar
        # multiplies per sample, where a (N, 3) @ (3, 3) product costs far more here.
        point = [np.full(q.shape[0], value) for value in self._tool_point]
        for column in range(self.dof - 1, -1, -1):
            rotation, translation, axis, revolute = self._joints[column]
            angle = q[:, column]
            if revolute:
                point = _rotated(point, axis, angle)
            else:
                point = [point[k] + angle * axis[k] if axis[k] else point[k] for k in range(3)]
            point = _placed(point, rotation, translation)
        return np.column_stack(point)


def _placed(point: list, rotation: np.ndarray, translation: np.ndarray) -> list:
    """R point + p for a fixed placement, point as three (N,) arrays; zero entries of R (most
    of them: URDF joints are mostly turned by multiples of 90 degrees) and unit ones cost
    nothing."""
    placed = []
    for row in range(3):
        total = None
        for column in range(3):
            weight = rotation[row, column]
            if abs(weight) < 1e-15:
                continue
            term = point[column] if weight == 1.0 else (
                -point[column] if weight == -1.0 else weight * point[column])
            total = term if total is None else total + term
        if total is None:
            total = np.zeros_like(point[0])
        placed.append(total + translation[row] if translation[row] else total)
    return placed


def _cos_sin(angle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of angle (N,) rad through t = tan(angle / 2): cos = (1 - t^2) / (1 + t^2),
    sin = 2 t / (1 + t^2), within a few 1e-16 of np.cos and np.sin. Why: numpy's float64 tan
    is vectorised here where its cos and sin are not (1M angles: tan 7 ms, cos 65-78 ms, sin
    72 ms on this machine), so the formula takes a seventh of the time."""
    half = np.tan(0.5 * angle)
    squared = half * half
    scale = 1.0 / (1.0 + squared)
    return (1.0 - squared) * scale, 2.0 * half * scale


def _rotated(point: list, axis: np.ndarray, angle: np.ndarray) -> list:
    """point (three (N,) arrays) rotated by angle[i] (rad) about the unit `axis` (3,)
    (Rodrigues: v cos + (a x v) sin + a (a . v)(1 - cos)). An axis along x, y or z (every
    joint of the usual URDFs) mixes two coordinates only."""
    cos, sin = _cos_sin(angle)
    aligned = np.flatnonzero(np.abs(axis) > 1e-15)
    if aligned.size == 1:
        k = int(aligned[0])
        i, j = (k + 1) % 3, (k + 2) % 3
        if axis[k] < 0.0:
            sin = -sin
        rotated = [None, None, None]
        rotated[i] = cos * point[i] - sin * point[j]
        rotated[j] = sin * point[i] + cos * point[j]
        rotated[k] = point[k]
        return rotated
    x, y, z = point
    a, b, c = axis
    along = (a * x + b * y + c * z) * (1.0 - cos)
    across = (b * z - c * y, c * x - a * z, a * y - b * x)
    return [point[k] * cos + across[k] * sin + axis[k] * along for k in range(3)]
