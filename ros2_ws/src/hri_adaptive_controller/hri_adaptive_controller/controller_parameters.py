"""The controller node's parameters: their table (types, ranges, descriptions; the defaults
are in config/controller.yaml) and which of them may change while it runs (the gains).

controller_node declares them and re-exports both names; scripts/parameters_doc.py writes
docs/parameters.md from the table.
"""

from hri_core.node_common import CPU_WAKEUP_LATENCY, REALTIME_PRIORITY, ParameterSpec
from hri_core.robot_model import ROBOT_NAMES

PARAMETERS = {
    'robot': ParameterSpec(str, 'the arm (hri_core.robot_model); ignored when urdf_file is given',
                           choices=ROBOT_NAMES, read_only=True),
    'urdf_file': ParameterSpec(str, 'URDF of another arm ("": the robot parameter)',
                               read_only=True),
    'tool_frame': ParameterSpec(str, 'URDF link or frame of the tool point ("": the robot\'s '
                                'own; required with urdf_file)', read_only=True),
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
        "15066's S_p stays within the separation (separation_cap; no approach while "
        '/hri/separation is stale)', read_only=True),
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
}
GAIN_PARAMETERS = ('ks', 'kp', 'adaptation_gain', 'max_task_speed', 'approach_speed',
                   'region_margin', 'effort_limit', 'max_effort_rate', 'applied_effort_cycles',
                   'rest_gain', 'rest_gate', 'joint_limit_band', 'barrier_torque', 'reach_round')
