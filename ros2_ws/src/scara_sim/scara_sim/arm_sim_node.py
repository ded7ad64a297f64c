"""The `arm_sim` node: any serial arm from its URDF, simulated at 1 kHz under joint torques.

`-p robot:=NAME`, an arm of hri_core.robot_model's table (`panda`, `ur3`, `ur5`, `ur10`,
`xarm7`, `z1` of example-robot-data, each with its tool frame; `scara`, the default: the SCARA
of scara_sim as a URDF) or `-p urdf_file:=PATH -p tool_frame:=NAME` (urdf_file, when given,
replaces robot) chooses the arm. The arm simulated is the URDF's with each link's mass and
inertia and each joint's viscous friction scaled by seeded factors within +-`perturbation`
(arm_simulation.true_arm), integrated with RK4 on pinocchio's ABA in fixed steps of
1/rate_hz s, gravity along -z, joint limits as inelastic stops, efforts clipped at the URDF's
limits (arm_simulation.ArmSimulator). Stepping, publishing, timeouts and fault handling are
scara_sim's (sim_node_common.SteppedSimNode):

* /joint_states (sensor_msgs/JointState): the URDF's joint names; position (rad), velocity
  (rad/s), effort = the drive torque applied (N m), every step;
* /ee_position (geometry_msgs/PointStamped, frame `base_frame`): the tool point (m), x, y, z;
* /robot_description (std_msgs/String, reliable, transient-local): the URDF text, once.

Inputs (reliable, depth 10):
* /effort_controller/commands (std_msgs/Float64MultiArray, one torque per joint, N m):
  clipped at the effort limits and applied; none for `command_timeout` s: zero torque;
  before the first command the joints are held still (brakes), except in teach mode;
* /human/wrench (geometry_msgs/WrenchStamped, frame `base_frame` or empty): force (N) and
  torque (N m) held at the tool point, base-frame axes, applied as J6^T w; ignored after
  `wrench_timeout` s without a new one.

The engine (`engine`): `pinocchio` (the default, as above) or `mujoco`
(mujoco_simulation.MujocoArmSimulator): MuJoCo integrates the same arm (the same perturbed
inertias, its collision geometry from the URDF, `package://` meshes found in
example-robot-data's folder, relative ones beside urdf_file) with its own joint damping
`mujoco_damping` and rotor inertia `mujoco_armature` (the controller knows neither; the
URDF's friction and the `damping` parameter are not used), its limit constraints as the
joint limits, and the person in its scene:

* /human/body (hri_interfaces/HumanBody, frame `base_frame` or empty): each capsule of the
  person (hri_core.bodies.human_capsules) a mocap body, moved from where it was to the new
  pose over the time between two messages' stamps (at most 0.1 s), pushing the arm on contact;
* /hri/contacts (hri_interfaces/Contacts): the arm's contacts with the person, every step
  that has one (and once empty when they end): link, body part, normal force (N), point (m).

Everything else (topics, timeouts, effort limits, brakes, teach mode, faults) is the same.

Teaching by hand (`-p teach_mode:=true`): the arm is gravity compensated and its joints damped
by `teach_damping`, as a Franka Panda in its guiding mode, so that with no controller running
a person (or the demonstrator node, pushing /human/wrench) moves the tool and the arm stays
where it is let go (arm_simulation has the law and why it is the robot's own). The /joint_states
effort is then the whole drive torque, gravity included.
Bad parameters (an unknown robot, an unreadable URDF, an unknown tool frame, an initial_q of
the wrong length or outside the limits): one error line, exit code 1.
"""

import sys
import time
from pathlib import Path

import numpy as np
from geometry_msgs.msg import Point, WrenchStamped

from hri_core import topics
from hri_core.bodies import human_capsules, seen_body_points
from hri_core.node_common import (
    ParameterSpec,
    StartupError,
    declare_parameters,
    load_defaults,
)
from hri_core.robot_model import EXAMPLE_ROBOTS, generic_model
from hri_core.validation import check_frame
from scara_sim.arm_simulation import ArmSimulator, true_arm
from scara_sim.sim_node_common import (
    ROBOT_PARAMETERS,
    STEPPING_PARAMETERS,
    TIMING_PARAMETERS,
    WARN_THROTTLE,
    SteppedSimNode,
    robot_from_parameters,
    run_sim_node,
)
from scara_sim.simulation import joint_command_floats

PACKAGE = 'scara_sim'
NODE_NAME = 'arm_sim'
ENGINES = ('pinocchio', 'mujoco')
LONGEST_BODY_BLEND = 0.1  # s: the most a body pose is spread over (a stalled tracker's gap)

PARAMETERS = {
    **ROBOT_PARAMETERS,
    'engine': ParameterSpec(str, 'physics engine: pinocchio (RK4 on ABA) or mujoco (MuJoCo, '
                            'with the person of /human/body in the scene and /hri/contacts)',
                            choices=ENGINES, read_only=True),
    'mujoco_damping': ParameterSpec(float, 'engine mujoco: viscous damping of each joint '
                                    '(N m s/rad), in place of the URDF friction', 0.0, 50.0,
                                    read_only=True),
    'mujoco_armature': ParameterSpec(float, 'engine mujoco: rotor inertia of each joint '
                                     '(kg m^2), added to the mass matrix diagonal', 0.0, 10.0,
                                     read_only=True),
    **STEPPING_PARAMETERS,
    'initial_q': ParameterSpec(list, "joint positions at start (rad; unset: the robot's home "
                               'pose)', read_only=True, optional=True),
    'perturbation': ParameterSpec(float, 'the simulated arm: link masses, inertias and joint '
                                  'friction scaled by factors within 1 +- this',
                                  0.0, 0.5, read_only=True),
    'perturbation_seed': ParameterSpec(int, 'seed of the perturbation factors', 0, 2 ** 31 - 1,
                                       read_only=True),
    'damping': ParameterSpec(list, "viscous friction of each joint before the perturbation "
                             "(N m s/rad; unset: the URDF's <dynamics damping>)",
                             read_only=True, optional=True),
    'teach_mode': ParameterSpec(bool, 'teach by hand: the drive compensates gravity and damps '
                                'the joints (a Panda in its guiding mode)', read_only=True),
    'teach_damping': ParameterSpec(float, 'teach mode: damping of each joint (N m s/rad)',
                                   0.0, 50.0, read_only=True),
    **TIMING_PARAMETERS,
}


class ArmSim(SteppedSimNode):
    """Integrates the arm of its URDF and publishes its state at rate_hz."""

    command_topics = {'effort': topics.EFFORT_COMMANDS}
    stepping_thread_name = 'arm_sim_steps'

    def __init__(self):
        super().__init__(NODE_NAME)
        values = declare_parameters(self, PARAMETERS, load_defaults(PACKAGE, NODE_NAME))
        self.read_stepping_settings(values)
        try:
            sim = self._simulator(values)
        except ValueError as error:
            raise StartupError(f'bad parameters: {error}') from None
        self.joint_names = sim.arm.joint_names
        # Braked until the first command, as a real arm's brakes hold it until its controller
        # runs: a Panda without torque falls onto its stops within a second. Not in teach
        # mode, where the arm is moved by hand with no controller.
        self.initial_mode = 'idle' if values['teach_mode'] else 'brake'
        self.add_post_set_parameters_callback(self.apply_timing_parameters)
        self._description_pub = self.create_publisher(
            topics.ROBOT_DESCRIPTION.type, topics.ROBOT_DESCRIPTION.name,
            topics.ROBOT_DESCRIPTION.qos)
        self._description_pub.publish(topics.ROBOT_DESCRIPTION.type(data=sim.arm.urdf))
        self._pending_body = None  # (capsules, seconds to move over), for the stepping thread
        self._last_body_stamp = None
        self._contact_pub = None
        self._touching = False  # the last step published had contacts
        if sim.touches_bodies:
            self.create_subscription(topics.HUMAN_BODY.type, topics.HUMAN_BODY.name,
                                     self._on_body, topics.HUMAN_BODY.qos)
            self._contact_pub = self.create_publisher(
                topics.CONTACTS.type, topics.CONTACTS.name, topics.CONTACTS.qos)
        rate_hz = values['rate_hz']
        engine = ('RK4 on ABA' if values['engine'] == 'pinocchio' else
                  f'MuJoCo {self._mujoco_version()}, joint damping '
                  f'{values["mujoco_damping"]:g} N m s/rad, armature '
                  f'{values["mujoco_armature"]:g} kg m^2, built in {self._build_time:.2f} s')
        self.start_stepping_setup(sim, values, (
            f'simulating {sim.arm.name} ({sim.arm.dof} joints, tool {sim.arm.tool_frame!r}) '
            f'at {rate_hz:g} Hz ({engine}, dt {1e3 / rate_hz:g} ms) from q = '
            f'{np.round(sim.q, 4).tolist()} rad; masses perturbed within '
            f'+-{100 * values["perturbation"]:g} % (seed {values["perturbation_seed"]}); '
            f'effort limits {sim.arm.limits.effort.tolist()} N m, command timeout '
            f'{self._command_timeout:g} s'
            + (f'; teach mode: gravity compensated, joints damped by '
               f'{values["teach_damping"]:g} N m s/rad' if values['teach_mode'] else '')))

    def _simulator(self, values: dict):
        """The simulator of the parameters `values` (an ArmSimulator, or a
        MujocoArmSimulator for engine mujoco); ValueError with the reason."""
        started = time.monotonic()
        nominal = generic_model(robot_from_parameters(values))
        initial_q = nominal.home if values['initial_q'] is None else values['initial_q']
        arm = true_arm(nominal, values['perturbation'], values['perturbation_seed'],
                       values['damping'])
        common = {'dt': 1.0 / values['rate_hz'], 'teach_mode': values['teach_mode'],
                  'teach_damping': values['teach_damping']}
        if values['engine'] == 'pinocchio':
            sim = ArmSimulator(arm, initial_q, np.zeros(arm.dof), **common)
        else:
            from scara_sim.mujoco_simulation import MujocoArmSimulator

            sim = MujocoArmSimulator(
                arm, initial_q, np.zeros(arm.dof), joint_damping=values['mujoco_damping'],
                armature=values['mujoco_armature'], package_dirs=self._package_dirs(),
                base_dir=str(Path(values['urdf_file']).parent) if values['urdf_file'] else '',
                **common)
        self._build_time = time.monotonic() - started
        return sim

    @staticmethod
    def _package_dirs() -> tuple[str, ...]:
        """Folders where `package://NAME/...` meshes are looked for: the one holding
        example-robot-data's robots (its `package://example-robot-data/...`), if installed."""
        from importlib import metadata

        try:
            robots = Path(metadata.distribution('example-robot-data').locate_file(
                EXAMPLE_ROBOTS))
        except metadata.PackageNotFoundError:
            return ()
        return (str(robots.parents[1]),)

    @staticmethod
    def _mujoco_version() -> str:
        import mujoco

        return mujoco.__version__

    # The person and the contacts (engine mujoco) -------------------------------------------

    def _on_body(self, msg) -> None:
        """A body on /human/body: its capsules, for the stepping thread to move in."""
        frame = msg.header.frame_id
        try:
            check_frame(frame, self._frame)
            seen = seen_body_points(msg.names, [(p.x, p.y, p.z) for p in msg.points])
            capsules = human_capsules(seen.names, seen.points)
        except ValueError as error:
            self.get_logger().warning(f'rejected /human/body: {error}',
                                      throttle_duration_sec=WARN_THROTTLE)
            return
        if seen.lost or seen.unknown:
            self.get_logger().warning(
                f'/human/body points lost (not finite): {", ".join(seen.lost) or "none"}; '
                f'ignored (not REP-155 names): {", ".join(seen.unknown) or "none"}',
                throttle_duration_sec=WARN_THROTTLE)
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        last, self._last_body_stamp = self._last_body_stamp, stamp
        over = 0.0 if last is None else min(max(stamp - last, 0.0), LONGEST_BODY_BLEND)
        self._pending_body = (capsules, over)

    def before_steps(self) -> None:
        pending, self._pending_body = self._pending_body, None
        if pending is not None:
            self._sim.set_body(*pending)

    def after_steps(self, states: list) -> None:
        if self._contact_pub is None:
            return
        per_step = self._sim.take_contacts()[-len(states):]
        for state, contacts in zip(states[len(states) - len(per_step):], per_step,
                                   strict=True):
            if not contacts and not self._touching:
                continue
            self._touching = bool(contacts)
            msg = topics.CONTACTS.type()
            msg.header.stamp.sec, msg.header.stamp.nanosec = self.stamp_of(state)
            msg.header.frame_id = self._frame
            msg.robot_links = [contact.robot_link for contact in contacts]
            msg.body_parts = [contact.body_part for contact in contacts]
            msg.normal_forces = [contact.normal_force for contact in contacts]
            msg.points = [Point(x=contact.point[0], y=contact.point[1], z=contact.point[2])
                          for contact in contacts]
            self._contact_pub.publish(msg)

    def wrench_values(self, msg: WrenchStamped) -> tuple[float, ...]:
        """Force (N) and torque (N m) at the tool point, base-frame axes."""
        force, torque = msg.wrench.force, msg.wrench.torque
        return joint_command_floats((force.x, force.y, force.z, torque.x, torque.y, torque.z),
                                    6)

    def tool_point(self, q) -> tuple[float, float, float]:
        return tuple(self._sim.arm.tool_position_unchecked(np.array(q)).tolist())


def main(args=None):
    return run_sim_node(ArmSim, NODE_NAME, args)


if __name__ == '__main__':
    sys.exit(main())
