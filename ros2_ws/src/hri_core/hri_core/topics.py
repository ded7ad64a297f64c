"""Every topic of the suite: its default name, message type and the QoS of its publisher.

One place for what both ends of a topic must agree on. Names are the defaults of the design's
topic table; a node still takes any of them remapped with `--ros-args -r OLD:=NEW`, since it
creates its publishers and subscriptions under these names and rcl applies the remapping.

QoS profiles are named by purpose: sensor streams are offered reliable with a short history;
a consumer that only needs the newest sample subscribes with `LATEST_SAMPLE_QOS`; commands are
reliable; the latest task state and the learned tasks are transient-local, so a late joiner
gets them at once.
"""

from dataclasses import dataclass

from geometry_msgs.msg import PointStamped, WrenchStamped
from hri_interfaces.msg import (
    Contacts,
    ControllerState,
    HumanBody,
    SeparationState,
    TaskEvent,
    TaskParameters,
    TaskState,
)
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String

# What a publisher of a measured stream offers (joint states, end-effector, hand position).
SENSOR_STREAM_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
# The tracked hand, judged sample by sample against the one before (the controller's glitch
# filter): 2 s at 50 Hz kept for a reader held back. With 10 (0.2 s), a controller stopped for
# 0.6 s lost the samples before a marker swap, then took the swap, the first sample after the
# gap, as a hand that could have got there (and blended back to the real one over 6 s).
HAND_STREAM_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
# A consumer that acts on the newest sample only (the 1 kHz controller): no backlog.
LATEST_SAMPLE_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
# Joint commands and the human's wrench: every one delivered, in order, to a reader held back
# for up to 0.1 s (1 kHz): the writer keeps 100 (with 10, a probe starved beside a busy
# process lost commands and saw them step by 2.0 and 10.3 N m).
COMMAND_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
# Monitoring output (ControllerState): reliable, a short history.
MONITOR_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
# Events: a burst of them must not be cut short by a small history.
EVENT_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
# The active task, a and da/dt: a late controller gets the latest state at once.
TASK_STATE_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
# The robot's URDF: published once, kept for late joiners (as robot_state_publisher does).
ROBOT_DESCRIPTION_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Learned tasks: every one reaches late joiners (keep_last >= 16).
LEARNED_TASKS_QOS = QoSProfile(depth=16, history=HistoryPolicy.KEEP_LAST,
                               reliability=ReliabilityPolicy.RELIABLE,
                               durability=DurabilityPolicy.TRANSIENT_LOCAL)


@dataclass(frozen=True)
class Topic:
    """A topic's default name, its message class and the QoS its publisher offers."""

    name: str
    type: type
    qos: QoSProfile

    @property
    def type_name(self) -> str:
        """The ROS type name, e.g. 'sensor_msgs/msg/JointState' (as bags store it)."""
        module = self.type.__module__.split('.')
        return f'{module[0]}/msg/{self.type.__name__}'


JOINT_STATES = Topic('/joint_states', JointState, SENSOR_STREAM_QOS)
EE_POSITION = Topic('/ee_position', PointStamped, SENSOR_STREAM_QOS)
EFFORT_COMMANDS = Topic('/effort_controller/commands', Float64MultiArray, COMMAND_QOS)
VELOCITY_COMMANDS = Topic('/velocity_controller/commands', Float64MultiArray, COMMAND_QOS)
HUMAN_WRENCH = Topic('/human/wrench', WrenchStamped, COMMAND_QOS)
DEMO_REFERENCE = Topic('/demo/reference', PointStamped, SENSOR_STREAM_QOS)
TARGET = Topic('/target', PointStamped, HAND_STREAM_QOS)
# The person's body as REP-155-named points (m, base frame): hand_sim, a body tracker.
HUMAN_BODY = Topic('/human/body', HumanBody, SENSOR_STREAM_QOS)
TASK = Topic('/hri/task', TaskParameters, LEARNED_TASKS_QOS)
EVENTS = Topic('/hri/events', TaskEvent, EVENT_QOS)
TASK_STATE = Topic('/hri/task_state', TaskState, TASK_STATE_QOS)
SEPARATION = Topic('/hri/separation', SeparationState, MONITOR_QOS)
CONTROLLER_STATE = Topic('/hri/controller_state', ControllerState, MONITOR_QOS)
ROBOT_DESCRIPTION = Topic('/robot_description', String, ROBOT_DESCRIPTION_QOS)
# The arm's contacts with the person's body (arm_sim engine:=mujoco): link, part, N, m.
CONTACTS = Topic('/hri/contacts', Contacts, MONITOR_QOS)

# What the recorder writes by default: everything the learner and the reports read, and the
# arm that made the demonstration (its URDF, latched: the recorder gets it however late it joins).
DEMONSTRATION_TOPICS = (JOINT_STATES, EE_POSITION, DEMO_REFERENCE, TARGET, HUMAN_WRENCH,
                        ROBOT_DESCRIPTION, HUMAN_BODY, CONTACTS)
