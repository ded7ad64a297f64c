"""A serial arm from its URDF, simulated by MuJoCo, with the person's body in the scene: the
step logic behind `arm_sim`'s `engine:=mujoco`.

`MujocoArmSimulator` has arm_simulation.ArmSimulator's interface (`arm`, `q`, `dq`, `dt`,
`applied_effort`, `step(mode, command, wrench)`, the same command modes, effort clipping,
teach mode and wrench at the tool), so the node holds either. What differs is the engine:

* **The model.** MuJoCo's URDF parser reads the arm's URDF (`package://` paths resolved in
  `package_dirs`, relative ones in `base_dir`); its collision geometry (meshes as their
  convex hulls, boxes, spheres, cylinders) is what touches. Static links keep their own
  bodies (no fusing), so a contact names the URDF link. Joints that the PinocchioModel locks
  (a gripper's fingers) are welded at the same position. Each moving body takes the
  PinocchioModel's inertia of its joint (mass, centre of mass, inertia; the `true_arm`'s
  perturbation included) and its static children none, so that without armature and with
  the same friction MuJoCo's forward dynamics equal pinocchio's ABA (unit test, 1e-9). A
  link without collision geometry (the SCARA's) gets a capsule of `LINK_RADIUS` from its
  origin to each child's.
* **Its own joint dynamics:** viscous damping `joint_damping` (N m s/rad, every joint,
  replacing the URDF's) and rotor inertia `armature` (kg m^2, added to M's diagonal);
  defaults are MuJoCo Menagerie's Franka Panda's (1 N m s/rad, 0.1 kg m^2). The URDF's
  Coulomb friction (<dynamics friction>) stays as MuJoCo's frictionloss.
* **Integration:** `implicitfast` (damping implicit), one mj_step per dt, gravity 9.81 m/s^2
  along -z. Joint limits are MuJoCo's limit constraints (soft, `LIMIT_SOLREF`): a joint
  pressed onto its stop goes in by a little (rad); `q` as returned is clipped to the limits
  (consumers check q against them), MuJoCo's own state is kept as it is.
* **The person:** each capsule of hri_core.bodies.HUMAN_CAPSULES is a mocap body with one
  capsule (or sphere) geom, moved kinematically by `set_body`; MuJoCo's contact solver lets
  it push the arm. Only arm-person pairs collide (contype / conaffinity bits): no arm-arm,
  arm-base or person-person contact is ever made, so none is reported. A capsule whose
  points are missing is taken out of the scene until they return. `take_contacts` gives,
  per step since the last call, the arm-person contacts (`Contact`: robot link, body part,
  normal force N from mj_contactForce, point m in the base frame).

No ROS import: the arm_sim node wires this to topics (scara_sim.sim_node_common).
"""

import math
import re
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hri_core.bodies import HUMAN_CAPSULES, HUMAN_RADII
from hri_core.robot_model import PinocchioModel
from scara_sim.arm_simulation import DriveTorques

LINK_RADIUS = 0.05  # m: the capsule of a link without collision geometry (bodies' SCARA's)
# MuJoCo's limit constraint: time constant (s) and damping ratio; 4 steps of 1 ms, stiffer
# than MuJoCo's default (0.02 s): the Panda's joint 4 pushed at 40 N m goes in 3 mrad.
LIMIT_SOLREF = (0.004, 1.0)
ARM_CONTYPE, PERSON_CONAFFINITY = 1, 1  # only arm-person pairs collide
AWAY = np.array([0.0, 0.0, -1.0e3])  # m: where an absent capsule waits
MAX_CONTACT_STEPS = 10_000  # steps of contacts kept between two take_contacts


def _ignore_warning(text: str) -> None:
    """MuJoCo's warning handler: the step reads data.warning itself (MujocoArmSimulator)."""


@dataclass(frozen=True)
class Contact:
    """One arm-person contact: the robot's URDF link, the person's capsule (HUMAN_CAPSULES'
    name), the normal force (N, >= 0) and the contact point (3,) m in the base frame."""

    robot_link: str
    body_part: str
    normal_force: float
    point: tuple[float, float, float]


def resolve_mesh_paths(urdf_text: str, package_dirs=(), base_dir: str = '') -> str:
    """`urdf_text` with each `package://NAME/...` filename made absolute with the first of
    `package_dirs` that holds it, and each relative one with `base_dir`. ValueError naming a
    `package://` file found in none of them."""
    def absolute(match) -> str:
        name = match.group(2)
        if name.startswith('package://'):
            relative = name.removeprefix('package://')
            for folder in package_dirs:
                if (Path(folder) / relative).is_file():
                    return f'{match.group(1)}{Path(folder) / relative}"'
            raise ValueError(f'mesh {name} is in none of the package folders '
                             f'{[str(d) for d in package_dirs]}')
        if base_dir and not name.startswith(('/', 'file://')):
            return f'{match.group(1)}{Path(base_dir) / name}"'
        return f'{match.group(1)}{name.removeprefix("file://")}"'
    return re.sub(r'(filename\s*=\s*")([^"]*)"', absolute, urdf_text)


def _axis_rotation(axis, angle: float) -> np.ndarray:
    """Quaternion (w, x, y, z) of a rotation by `angle` rad about the unit `axis` (3,)."""
    half = 0.5 * angle
    return np.concatenate([[math.cos(half)], math.sin(half) * np.asarray(axis, dtype=float)])


def _capsule_pose(a, b) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre (3,) m, quaternion (w, x, y, z) turning z onto b - a, and half-length (m) of
    the segment a-b (a sphere: the identity, 0)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    axis = b - a
    length = float(np.linalg.norm(axis))
    if length < 1e-9:
        return a, np.array([1.0, 0.0, 0.0, 0.0]), 0.0
    z = axis / length
    w = 1.0 + z[2]
    if w < 1e-12:  # b - a along -z: half a turn about x
        quat = np.array([0.0, 1.0, 0.0, 0.0])
    else:
        quat = np.array([w, -z[1], z[0], 0.0])  # z x axis, with 1 + cos as the real part
        quat /= np.linalg.norm(quat)
    return 0.5 * (a + b), quat, 0.5 * length


class MujocoArmSimulator(DriveTorques):
    """The arm `arm` (a PinocchioModel, the true arm of arm_simulation.true_arm) in MuJoCo
    (module docstring), from q (n,) rad, dq (n,) rad/s, in steps of dt s.

    joint_damping (N m s/rad) and armature (kg m^2): each joint's, >= 0. package_dirs,
    base_dir: where the URDF's meshes are (resolve_mesh_paths). teach_mode, teach_damping:
    as ArmSimulator's. ValueError with a one-line reason for a bad value or a URDF MuJoCo
    cannot compile (a mesh it cannot read, say)."""

    touches_bodies = True  # the node feeds it /human/body and publishes its contacts

    def __init__(self, arm: PinocchioModel, q, dq, dt: float = 1e-3, teach_mode: bool = False,
                 teach_damping: float = 1.0, joint_damping: float = 1.0,
                 armature: float = 0.1, package_dirs=(), base_dir: str = ''):
        import mujoco  # a heavy import, only for this engine

        # MuJoCo's warnings otherwise go to a MUJOCO_LOG.TXT in the working directory (a
        # user's checkout); the one that matters here, a bad acceleration, is read from
        # data.warning after each step and raised as a ValueError with its reason.
        mujoco.set_mju_user_warning(_ignore_warning)
        self._mj = mujoco
        self.arm = arm
        self.q = arm.joint_position(q, 'initial q')
        self.dq = arm.joint_vector(dq, 'initial dq')
        self.dt = float(dt)
        self.teach_mode = bool(teach_mode)
        self.teach_damping = float(teach_damping)
        for name, value, unit in (('dt', self.dt, 's'), ('teach_damping', teach_damping,
                                                          'N m s/rad'),
                                  ('joint_damping', joint_damping, 'N m s/rad'),
                                  ('armature', armature, 'kg m^2')):
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name} must be a finite number >= 0 {unit}, got {value!r}')
        if self.dt <= 0.0:
            raise ValueError(f'dt must be > 0 s, got {self.dt}')
        limits = arm.limits
        if not (np.all(np.isfinite(limits.effort)) and np.all(limits.effort > 0.0)):
            raise ValueError(f'effort limits must be finite and > 0, got '
                             f'{limits.effort.tolist()}')
        self._effort, self._least_effort = limits.effort, -limits.effort
        self._lower, self._upper = limits.lower, limits.upper
        self.joint_damping, self.armature = float(joint_damping), float(armature)
        self.model = self._compile(resolve_mesh_paths(arm.urdf, package_dirs, base_dir))
        self.data = mujoco.MjData(self.model)
        self.data.qpos[:] = self.q
        self.data.qvel[:] = self.dq
        mujoco.mj_forward(self.model, self.data)
        self.applied_effort = np.zeros(arm.dof)
        self._geom_part = {int(geom): name for name, geom in self._person_geoms.items()}
        self._body_link = {b: self.model.body(b).name for b in range(self.model.nbody)}
        self._present = dict.fromkeys(self._person_geoms, False)
        self._motion = None  # (from poses, to poses, steps to go, steps in all)
        self._contact_log: deque = deque(maxlen=MAX_CONTACT_STEPS)
        self._force = np.zeros(6)
        self.contacts: tuple[Contact, ...] = ()  # the last step's

    # Building ---------------------------------------------------------------------------

    def _compile(self, urdf_text: str):
        """The MuJoCo model of the arm and the person's mocap capsules."""
        mujoco, arm = self._mj, self.arm
        try:
            spec = mujoco.MjSpec.from_string(urdf_text)
        except Exception as error:  # noqa: BLE001 MuJoCo raises ValueError with its reason
            raise ValueError(f'MuJoCo cannot read the URDF of {arm.name}: '
                             f'{str(error).splitlines()[0]}') from None
        spec.compiler.fusestatic = False
        spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
        spec.option.timestep = self.dt
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        spec.option.gravity = np.array([0.0, 0.0, -9.81])
        kept = set(arm.joint_names)
        for equality in list(spec.equalities):  # a mimic joint's coupling (the fingers')
            if {equality.name1, equality.name2} - kept - {''}:
                spec.delete(equality)
        for joint in list(spec.joints):
            if joint.name not in kept:
                self._weld(spec, joint)
        for joint in spec.joints:
            joint.damping = [self.joint_damping, 0.0, 0.0]  # viscous; no higher terms
            joint.armature = self.armature
            joint.solref_limit = LIMIT_SOLREF
            joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE
        self._set_inertias(spec)
        for geom in spec.geoms:
            geom.contype, geom.conaffinity = ARM_CONTYPE, 0
        self._add_link_capsules(spec)
        self._person_geoms = {}
        for part, _, _, radius_key in HUMAN_CAPSULES:
            body = spec.worldbody.add_body(name=f'person_{part}', mocap=True, pos=AWAY)
            geom = body.add_geom(name=f'person_{part}', type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                                 size=[HUMAN_RADII[radius_key], 1e-3, 0.0])
            # Collidable from the start (a geom that collides with nothing is visual, and the
            # URDF parser discards those), but AWAY until set_body places it.
            geom.contype, geom.conaffinity = 0, PERSON_CONAFFINITY
            self._person_geoms[part] = geom
        try:
            model = spec.compile()
        except Exception as error:  # noqa: BLE001 MuJoCo's compiler: ValueError, one reason
            raise ValueError(f'MuJoCo cannot compile {arm.name}: '
                             f'{str(error).splitlines()[0]}') from None
        names = tuple(model.joint(j).name for j in range(model.njnt))
        if names != arm.joint_names or model.nq != arm.dof or model.nv != arm.dof:
            raise ValueError(f'MuJoCo made joints {names} of {arm.name}, not '
                             f'{arm.joint_names}')
        self._person_geoms = {part: model.geom(f'person_{part}').id
                              for part, *_ in HUMAN_CAPSULES}
        self._mocap = {part: model.body_mocapid[model.geom_bodyid[geom]]
                       for part, geom in self._person_geoms.items()}
        return model

    def _weld(self, spec, joint) -> None:
        """Remove `joint`, its body fixed where the joint sits at 0 clipped into its limits
        (pinocchio's locked position)."""
        mujoco = self._mj
        body = joint.parent
        lower, upper = joint.range
        value = min(max(0.0, lower), upper) if lower < upper else 0.0
        if value:
            axis = np.asarray(joint.axis, dtype=float)
            axis /= np.linalg.norm(axis)
            rotation = np.zeros(9)
            mujoco.mju_quat2Mat(rotation, np.asarray(body.quat, dtype=float))
            rotation = rotation.reshape(3, 3)
            if joint.type == mujoco.mjtJoint.mjJNT_SLIDE:
                body.pos = np.asarray(body.pos) + rotation @ (value * axis)
            else:
                turn, turned = _axis_rotation(axis, value), np.zeros(4)
                mujoco.mju_mulQuat(turned, np.asarray(body.quat, dtype=float), turn)
                spin = np.zeros(9)
                mujoco.mju_quat2Mat(spin, turn)
                anchor = np.asarray(joint.pos, dtype=float)
                body.pos = np.asarray(body.pos) + rotation @ (
                    anchor - spin.reshape(3, 3) @ anchor)
                body.quat = turned
        spec.delete(joint)

    def _set_inertias(self, spec) -> None:
        """Each joint's body takes the PinocchioModel's inertia of that joint (its whole
        rigid subtree's); every other body none."""
        inertias = self.arm.model.inertias
        by_joint = {name: inertias[i + 1] for i, name in enumerate(self.arm.joint_names)}
        for body in spec.bodies:
            if body.name == 'world':
                continue
            own = [joint.name for joint in body.joints]
            body.explicitinertial = True
            if own and own[0] in by_joint:
                inertia = by_joint[own[0]]
                matrix = np.asarray(inertia.inertia, dtype=float)
                body.mass = float(inertia.mass)
                body.ipos = np.asarray(inertia.lever, dtype=float)
                body.fullinertia = [matrix[0, 0], matrix[1, 1], matrix[2, 2], matrix[0, 1],
                                    matrix[0, 2], matrix[1, 2]]
            else:
                body.mass = 0.0
                body.ipos = np.zeros(3)
                body.fullinertia = np.full(6, np.nan)  # NaN: unset (MuJoCo's marker)
                body.inertia = np.zeros(3)

    def _add_link_capsules(self, spec) -> None:
        """A capsule (LINK_RADIUS) from each moving link's origin to each child's, for the
        links without collision geometry."""
        mujoco = self._mj
        for body in spec.bodies:
            if body.name == 'world' or body.geoms or not body.joints:
                continue
            for child in body.bodies:  # their origins in its frame
                end = np.asarray(child.pos, dtype=float)
                if np.linalg.norm(end) < 1e-6:
                    continue
                geom = body.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                                     fromto=np.concatenate([np.zeros(3), end]),
                                     size=[LINK_RADIUS, 0.0, 0.0])
                geom.contype, geom.conaffinity = ARM_CONTYPE, 0

    # Stepping ---------------------------------------------------------------------------

    def step(self, mode: str, command, wrench) -> tuple[tuple[float, ...], ...]:
        """Advance one step of dt (ArmSimulator.step's contract): the new q (rad, clipped to
        the limits), dq (rad/s) and the applied drive torque (N m) as tuples of floats.
        ValueError if MuJoCo's state becomes non-finite or it reports a bad acceleration."""
        data, dof = self.data, self.arm.dof
        if mode == 'brake':
            data.qvel[:] = 0.0
            self.dq = np.zeros(dof)
            self.applied_effort = np.zeros(dof)
            self._record(())
            return tuple(self.q.tolist()), (0.0,) * dof, (0.0,) * dof
        tau, torque = self.drive_torques(mode, command, wrench)
        self._move_person()
        data.qfrc_applied[:] = torque
        bad_before = data.warning[self._mj.mjtWarning.mjWARN_BADQACC].number
        self._mj.mj_step(self.model, data)
        q, dq = data.qpos.copy(), data.qvel.copy()
        if (data.warning[self._mj.mjtWarning.mjWARN_BADQACC].number != bad_before
                or not math.isfinite(float(q.sum() + dq.sum()))):
            raise ValueError(f'the simulated state became non-finite (MuJoCo, torque '
                             f'{torque.tolist()})')
        self.q = np.minimum(np.maximum(q, self._lower), self._upper)
        self.dq = dq
        self.applied_effort = tau
        self._record(self._arm_person_contacts() if data.ncon else ())
        return tuple(self.q.tolist()), tuple(dq.tolist()), tuple(tau.tolist())

    # The person -------------------------------------------------------------------------

    def set_body(self, capsules, over: float = 0.0) -> None:
        """Move the person to `capsules` (hri_core.bodies.Capsules: names of HUMAN_CAPSULES,
        ends a, b (K, 3) m, radius (K,) m) linearly over the next `over` s (0: at the next
        step); capsules not named are taken out of the scene. ValueError for an unknown name
        or a non-finite end."""
        if not (math.isfinite(over) and over >= 0.0):
            raise ValueError(f'over must be finite and >= 0 s, got {over}')
        unknown = set(capsules.names) - set(self._person_geoms)
        if unknown:
            raise ValueError(f'unknown body part(s) {sorted(unknown)}')
        if not (np.all(np.isfinite(capsules.a)) and np.all(np.isfinite(capsules.b))):
            raise ValueError('body capsule ends must be finite')
        target = {}
        for name, a, b, radius in zip(capsules.names, capsules.a, capsules.b,
                                      capsules.radius, strict=True):
            target[name] = (np.asarray(a, dtype=float), np.asarray(b, dtype=float),
                            float(radius))
        start = {name: self._current_ends(name) for name in target if self._present[name]}
        steps = max(1, round(over / self.dt))
        self._motion = (start, target, steps, steps)

    def _current_ends(self, name: str):
        """The ends (3,), (3,) m and radius (m) where capsule `name` is now."""
        model, data = self.model, self.data
        geom, mocap = self._person_geoms[name], self._mocap[name]
        rotation = np.zeros(9)
        self._mj.mju_quat2Mat(rotation, data.mocap_quat[mocap])
        half = float(model.geom_size[geom, 1]) * rotation.reshape(3, 3)[:, 2]
        centre = data.mocap_pos[mocap]
        return centre - half, centre + half, float(model.geom_size[geom, 0])

    def _move_person(self) -> None:
        """One step of the motion set_body started, if one is under way."""
        if self._motion is None:
            return
        start, target, left, steps = self._motion
        share = 1.0 - (left - 1) / steps
        for name, geom in self._person_geoms.items():
            if name not in target:
                if self._present[name]:
                    self._place(name, geom, AWAY, AWAY, 0.0)
                continue
            a, b, radius = target[name]
            if name in start and share < 1.0:
                a0, b0, _ = start[name]
                a, b = a0 + share * (a - a0), b0 + share * (b - b0)
            self._place(name, geom, a, b, radius)
        self._motion = None if left <= 1 else (start, target, left - 1, steps)

    def _place(self, name: str, geom: int, a, b, radius: float) -> None:
        """Capsule `name` (geom id) between a and b (m) with `radius` (m); at AWAY: absent."""
        model, data = self.model, self.data
        present = radius > 0.0
        centre, quat, half = _capsule_pose(a, b)
        mocap = self._mocap[name]
        data.mocap_pos[mocap] = centre
        data.mocap_quat[mocap] = quat
        model.geom_size[geom, :2] = (radius, half)
        model.geom_rbound[geom] = radius + half
        model.geom_aabb[geom] = (0.0, 0.0, 0.0, radius, radius, radius + half)
        affinity = PERSON_CONAFFINITY if present else 0
        model.geom_conaffinity[geom] = affinity
        model.body_conaffinity[model.geom_bodyid[geom]] = affinity
        self._present[name] = present

    def _arm_person_contacts(self) -> tuple[Contact, ...]:
        """The arm-person contacts of the step just taken (module docstring)."""
        model, data, found = self.model, self.data, []
        force = self._force
        for index in range(data.ncon):
            contact = data.contact[index]
            geoms = (int(contact.geom1), int(contact.geom2))
            part = self._geom_part.get(geoms[1]) or self._geom_part.get(geoms[0])
            if part is None:
                continue
            robot_geom = geoms[0] if geoms[1] in self._geom_part else geoms[1]
            self._mj.mj_contactForce(model, data, index, force)
            found.append(Contact(self._body_link[int(model.geom_bodyid[robot_geom])], part,
                                 float(force[0]), tuple(contact.pos.tolist())))
        return tuple(found)

    def contacts_in_state(self, q, dq, torque) -> tuple[Contact, ...]:
        """The arm-person contacts MuJoCo finds with the arm at q (rad), dq (rad/s) under the
        drive torque `torque` (N m), the person where it is now (a pending set_body motion
        advanced by one step, as `step` does): one mj_forward, nothing integrated; the arm's
        state is put back. A step's own contacts are those of the state it started from,
        under that step's torque, so a published step is checked against the state before
        it. ValueError for a wrong length or a non-finite value."""
        arm, data = self.arm, self.data
        q, dq = arm.joint_vector(q, 'q'), arm.joint_vector(dq, 'dq')
        torque = arm.joint_vector(torque, 'torque')
        saved = data.qpos.copy(), data.qvel.copy(), data.qfrc_applied.copy()
        self._move_person()
        data.qpos[:], data.qvel[:], data.qfrc_applied[:] = q, dq, torque
        try:
            self._mj.mj_forward(self.model, data)
            return self._arm_person_contacts() if data.ncon else ()
        finally:
            data.qpos[:], data.qvel[:], data.qfrc_applied[:] = saved

    def _record(self, contacts: tuple) -> None:
        self.contacts = contacts
        self._contact_log.append(contacts)

    def take_contacts(self) -> list[tuple[Contact, ...]]:
        """The contacts of every step since the last call, one tuple per step, oldest
        first (at most MAX_CONTACT_STEPS steps are kept)."""
        log = list(self._contact_log)
        self._contact_log.clear()
        return log
