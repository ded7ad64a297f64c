"""The controller node's parameters: their table (types, ranges, descriptions; the defaults
are in config/controller.yaml), which of them may change while it runs (the gains), and what
the node builds from their values: the robot model, the law's gains, the initial estimate,
an avoid task's rest position and the robot's capsules for the whole-body clearance (each a
ValueError with a one-line reason).

controller_node declares them and re-exports these names; scripts/parameters_doc.py writes
docs/parameters.md from the table.
"""

import dataclasses
from pathlib import Path

import numpy as np

from hri_adaptive_controller.arm_law import ArmGains, default_gains
from hri_core.bodies import RobotBody, panda_package_dirs, robot_body
from hri_core.node_common import CPU_WAKEUP_LATENCY, REALTIME_PRIORITY, ParameterSpec
from hri_core.robot_model import ROBOT_NAMES, RobotModel, robot_model

PARAMETERS = {
    'robot': ParameterSpec(str, 'the arm (hri_core.robot_model); ignored when urdf_file is given',
                           choices=ROBOT_NAMES, read_only=True),
    'urdf_file': ParameterSpec(str, 'URDF of another arm ("": the robot parameter)',
                               read_only=True),
    'tool_frame': ParameterSpec(str, 'URDF link or frame of the tool point ("": the robot\'s '
                                'own; required with urdf_file)', read_only=True),
    'base_frame': ParameterSpec(str, 'frame of /target and /human/body (the arm\'s base); a '
                                'message in another frame is dropped ("" on a message: '
                                'taken as this frame)', read_only=True),
    'home_position': ParameterSpec(
        list, 'the joint posture the null space of a redundant arm pulls towards (rad, one '
        "per joint, within the limits); unset: the robot's home (the Panda's ready pose; a "
        "URDF arm's: the middle of its joint limits)", optional=True, read_only=True),
    'ks': ParameterSpec(list, 'diagonal of Ks, one per joint (N m s/rad); unset: the '
                        "robot's (arm_law.ROBOT_GAINS; another arm's from its effort limits "
                        'and inertias, arm_law.default_arm_ks)', optional=True),
    'adaptation_gain': ParameterSpec(
        list, "diagonal of L (eq. 19), one rate per kind of the robot's parameters (the "
        "SCARA's 7: pi1, pi2, pi3, b1, b2, mlc1, mlc2; a URDF arm's m, mcx, mcy, mcz, Ixx, "
        "Ixy, Iyy, Ixz, Iyz, Izz, damping, every joint alike); unset: the robot's",
        optional=True),
    'theta_hat0': ParameterSpec(list, "initial theta_hat, one per parameter of the robot's "
                                "model; unset: the robot's initial_estimate share of its "
                                'nominal values (arm_law.ArmGains)', optional=True,
                                read_only=True),
    'rate_hz': ParameterSpec(float, 'expected /joint_states rate, which paces control; '
                             'deadlines and the zero-torque rate (Hz)', low=10.0, high=2000.0,
                             read_only=True),
    'realtime_priority': REALTIME_PRIORITY,
    'cpu_wakeup_latency': CPU_WAKEUP_LATENCY,
    'state_rate_hz': ParameterSpec(float, 'ControllerState rate (Hz)', low=1.0, high=1000.0,
                                   read_only=True),
    'mode': ParameterSpec(str, 'effort: torques (eq. 16); velocity: qdot_r (eq. 14)',
                          choices=('effort', 'velocity'), read_only=True),
    'kp': ParameterSpec(float, 'task gain Kp (N s/m)', low=0.001, high=1000.0),
    'max_task_speed': ParameterSpec(float,
                                    'largest task-space reference speed (m/s)',
                                    low=0.01, high=2.0),
    'approach_speed': ParameterSpec(float, 'most the approach floor may be (m/s; 0: none); '
                                    "the floor is the task's own pull 0.2 m from its region",
                                    low=0.0, high=2.0),
    'region_margin': ParameterSpec(float, 'how far inside the learned region the approach '
                                   'speed fades out (m)', low=0.0, high=0.1),
    'rest_gain': ParameterSpec(float, 'avoid tasks: rate of the return to the rest position '
                               '(1/s)', low=0.0, high=100.0),
    'rest_gate': ParameterSpec(float, "avoid tasks: the return fades in over this distance "
                               "outside the region's edge (m)", low=0.001, high=1.0),
    'rest_position': ParameterSpec(list, 'avoid tasks: rest position on the task axes (m: '
                                   '[x, y] for a planar arm, [x, y, z] otherwise); unset: '
                                   'where the arm was when the task became active',
                                   optional=True),
    'effort_limit': ParameterSpec(float, "a cap on every joint's torque limit (N m; 0: the "
                                  "robot's own limits alone)", low=0.0, high=500.0),
    'max_effort_rate': ParameterSpec(float, 'largest torque change per joint, per second of '
                                     'the joint states\' clock (N m/s; 1000: 1 N m per 1 ms '
                                     'cycle)', low=1.0, high=1e6),
    'applied_effort_cycles': ParameterSpec(int, 'each command also stays within '
                                           'max_effort_rate times this many control periods '
                                           'of the effort the joint state reports, when that '
                                           'is a command this node sent (a simulator echoing '
                                           'the torque it applies; a measured torque is left '
                                           'alone), whichever command of a late burst the '
                                           'drive takes; 0: off', low=0, high=100),
    'joint_state_timeout': ParameterSpec(float, 'joint states older than this: the arm is '
                                         'held against gravity (s)',
                                         low=0.002, high=10.0),
    'task_state_timeout': ParameterSpec(float, 'no TaskState for this long: the task fades '
                                        'out over task_fade_time (s)', low=0.1, high=3600.0),
    'task_fade_time': ParameterSpec(float, 'a full fade of the task when TaskStates stop or '
                                    'return (s, the C2 ramp of eq. 13)', low=0.01, high=60.0),
    'restart_jump': ParameterSpec(float, 'stamps this far behind the last used one start a '
                                  'candidate source restart (s)', low=0.001, high=3600.0),
    'restart_confirm': ParameterSpec(int, 'advancing messages that confirm a source restart',
                                     low=1, high=1000),
    'target_filter_time': ParameterSpec(float, 'time constant of the hand velocity estimate (s)',
                                        low=0.001, high=5.0, read_only=True),
    'max_target_distance': ParameterSpec(float, 'targets farther than this from the base are '
                                         'dropped (m)', low=0.1, high=100.0),
    'joint_limit_band': ParameterSpec(float, 'the barrier and the feed-forward gate act this '
                                      'near a joint limit (rad)', low=0.01, high=1.0),
    'barrier_torque': ParameterSpec(float, "the barrier's torque at a joint limit (N m; above "
                                    "the task's largest)", low=0.0, high=100.0),
    'separation_speed_limit': ParameterSpec(
        bool, "cap the task's speed towards the hand from /hri/separation so that ISO/TS "
        "15066's S_p stays within the separation, and the closest pair's robot point's speed "
        'towards the person (separation_cap; no approach while /hri/separation is stale)',
        read_only=True),
    'reach_round': ParameterSpec(bool, 'blend in a joint-space motion where the straight '
                                 'task-space descent is blocked or the hand out of reach'),
    'target_max_speed': ParameterSpec(float, 'a /target implying a faster hand is held as a '
                                      'glitch (m/s)', low=0.1, high=100.0, read_only=True),
    'target_max_acceleration': ParameterSpec(float, 'a /target off the predicted hand path by '
                                             'more than this allows is held as a glitch '
                                             '(m/s^2)', low=1.0, high=1e4, read_only=True),
    'target_timeout': ParameterSpec(float, 'no /target accepted for this long: the task fades '
                                    'out over task_fade_time (s)', low=0.01, high=3600.0,
                                    read_only=True),
    'clearance': ParameterSpec(float, 'every link keeps this far from every capsule of the '
                               "person on /human/body (m; 0: off); the tool may reach the "
                               "tracked hand's wrist and forearm in a task whose region reaches "
                               'the hand', low=0.0, high=1.0, read_only=True),
}
GAIN_PARAMETERS = ('ks', 'kp', 'adaptation_gain', 'max_task_speed', 'approach_speed',
                   'region_margin', 'effort_limit', 'max_effort_rate', 'applied_effort_cycles',
                   'rest_gain', 'rest_gate', 'joint_limit_band', 'barrier_torque', 'reach_round')


def model_from(values: dict) -> RobotModel:
    """The arm's model: urdf_file with tool_frame, else robot; its home pose home_position if
    set. ValueError with the reason."""
    if values['urdf_file']:
        model = robot_model(urdf_file=values['urdf_file'], tool_frame=values['tool_frame'])
    else:
        model = robot_model(values['robot'], tool_frame=values['tool_frame'])
    if values.get('home_position') is not None:
        model.home = model.joint_position(values['home_position'], 'home_position')
    return model


def gains_from(values: dict, model: RobotModel) -> ArmGains:
    """The law's gains for `model` from parameter values: ks and adaptation_gain if set, else
    the robot's (arm_law.default_gains); the task, speed, rate-limit and barrier parameters
    from the values. ValueError with the reason if invalid."""
    robot = default_gains(model)
    ks, adaptation = values.get('ks'), values.get('adaptation_gain')
    if ks is not None and len(ks) != model.dof:
        raise ValueError(f'ks must have {model.dof} values for {model.name}, got {len(ks)}')
    if adaptation is not None and len(adaptation) != len(model.adaptation_kinds):
        raise ValueError(f'adaptation_gain must have {len(model.adaptation_kinds)} values for '
                         f'{model.name} ({", ".join(model.adaptation_kinds)}), got '
                         f'{len(adaptation)}')
    return dataclasses.replace(
        robot, ks=robot.ks if ks is None else tuple(ks), kp=values['kp'],
        adaptation=robot.adaptation if adaptation is None else tuple(adaptation),
        approach_speed=values['approach_speed'], region_margin=values['region_margin'],
        max_task_speed=values['max_task_speed'], rest_gain=values['rest_gain'],
        rest_gate=values['rest_gate'], max_effort_rate=values['max_effort_rate'],
        effort_limit=values['effort_limit'] or None, limit_band=values['joint_limit_band'],
        barrier_torque=values['barrier_torque'],
        body=dataclasses.replace(robot.body, clearance=values.get('clearance',
                                                                  robot.body.clearance)),
        reach_round=dataclasses.replace(robot.reach_round, enabled=values['reach_round']))


def initial_estimate(values: dict, model: RobotModel, gains: ArmGains):
    """theta_hat(0) (p,): theta_hat0 if set, else the gains' initial_estimate share of the
    model's nominal theta. ValueError with the reason."""
    theta = values.get('theta_hat0')
    if theta is None:
        return gains.initial_estimate * model.theta
    if len(theta) != model.theta.size:
        raise ValueError(f'theta_hat0 must have {model.theta.size} values for {model.name} '
                         f'({", ".join(model.parameter_names[:8])}'
                         f'{" ..." if model.theta.size > 8 else ""}), got {len(theta)}')
    return np.array(theta, dtype=float)


def rest_position_from(values: dict, model: RobotModel) -> tuple[float, ...] | None:
    """The fixed rest position of avoid tasks (m, one per task axis of `model`), or None when
    unset. ValueError with the reason."""
    fixed = values.get('rest_position')
    if fixed is None:
        return None
    axes = model.task_axes
    if len(fixed) != axes:
        raise ValueError(f'rest_position must have {axes} values '
                         f'{["[x, y]", "[x, y, z]"][axes - 2]} (m) for {model.name}, got '
                         f'{len(fixed)}')
    return tuple(float(v) for v in fixed)


def robot_body_from(values: dict, model: RobotModel) -> tuple[RobotBody | None, str]:
    """(the robot's capsules for the whole-body clearance and the separation cap's pairs, '')
    or (None, why not): None with clearance 0 and the cap off, or where the arm's collision
    geometry cannot be read (its meshes are looked for where example-robot-data's and the
    URDF file's folders hold them)."""
    if values.get('clearance', 0.0) <= 0.0 and not values.get('separation_speed_limit'):
        return None, ''
    folders = [str(Path(values['urdf_file']).resolve().parent)] if values['urdf_file'] else []
    try:
        folders += list(panda_package_dirs())
    except ValueError:
        pass  # no example-robot-data: a URDF file's own folder only
    try:
        return robot_body(model, folders), ''
    except ValueError as error:
        return None, str(error)

