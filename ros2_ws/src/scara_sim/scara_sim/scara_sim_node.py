"""The `scara_sim` node: a simulated horizontal 2-link SCARA driven by joint commands.

Integrates the arm of `dynamics.py` with RK4 in fixed steps of 1/rate_hz s (default 1 ms).
A stepping thread ticks at rate_hz (it sleeps to the end of each step) and runs the steps
that real time has reached since the last tick (at most `max_catch_up_steps` per tick, the
older ones are dropped and counted), and publishes the state after every step it integrated,
those caught up after a late tick included (simulation.RealTimeStepper). The stepping thread
takes the joint commands received since the last tick itself, at each tick (from the
subscriptions of a second node, `<name>_commands`, that no executor spins); the executor runs
the other callbacks (the wrench, parameters) beside it. A step that fails (a non-finite
state) ends the process with exit code 1 and one error line:

* /joint_states (sensor_msgs/JointState): joint1, joint2; position (rad), velocity (rad/s),
  effort = the drive torque applied (N m, the human's J^T f not included);
* /ee_position (geometry_msgs/PointStamped, frame `base_frame`): forward kinematics (m), of
  the newest state only (once per tick: a late tick's caught-up steps are not repeated here).
The header stamp is the time the state stands for: the ROS time of the first tick plus the
simulated time of that step, which follows real time. With `realtime_priority` > 0 the process
asks for SCHED_FIFO at that priority (hri_core.realtime) and logs once whether it got it; with
`cpu_wakeup_latency` >= 0 it holds a PM QoS request that idle CPUs wake within that many
microseconds (0: they poll).

Inputs (reliable, depth 10); the most recent valid joint command chooses the drive mode:
* /effort_controller/commands (std_msgs/Float64MultiArray [tau1, tau2], N m): clipped at
  effort_limit and applied;
* /velocity_controller/commands (Float64MultiArray [dq1, dq2], rad/s): tracked by the
  drive's internal stiff PI velocity loop (`velocity_kp`, `velocity_ki`; see
  simulation.VelocityLoop), its torque clipped at effort_limit;
* /human/wrench (geometry_msgs/WrenchStamped, frame `base_frame` or empty): force x, y in N
  on the end-effector, applied as J^T f; ignored after `wrench_timeout` s without a new one.
No command for `command_timeout` s: zero torque (logged once, and once when commands
resume). A malformed command or wrench (wrong length, NaN/inf, wrong frame) is rejected
with a throttled warning; the last good one stays in force.
"""

import sys

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rcl_interfaces.msg import SetParametersResult

from hri_core import topics
from hri_core.dynamics import ScaraParameters, forward_kinematics_pair
from hri_core.node_common import (
    ParameterSpec,
    StartupError,
    declare_parameters,
    float_array_problem,
    load_defaults,
)
from scara_sim.sim_node_common import (
    STEPPING_PARAMETERS,
    TIMING_PARAMETERS,
    SteppedSimNode,
    run_sim_node,
)
from scara_sim.simulation import (
    ScaraSimulator,
    VelocityLoop,
    joint_command_floats,
)

PACKAGE = 'scara_sim'
NODE_NAME = 'scara_sim'
JOINT_NAMES = ['joint1', 'joint2']

ARM_PARAMETERS = {  # ScaraParameters fields; every one may change at run time
    'l1': ParameterSpec(float, 'length of link 1 (m)', 0.05, 2.0),
    'l2': ParameterSpec(float, 'length of link 2 (m)', 0.05, 2.0),
    'lc1': ParameterSpec(float, 'joint 1 to the centre of mass of link 1 (m)', 0.0, 2.0),
    'lc2': ParameterSpec(float, 'joint 2 to the centre of mass of link 2 and its load (m)',
                         0.0, 2.0),
    'm1': ParameterSpec(float, 'mass of link 1 (kg)', 0.01, 100.0),
    'm2': ParameterSpec(float, 'mass of link 2 with quill and tool (kg)', 0.01, 100.0),
    'i1': ParameterSpec(float, 'inertia of link 1 about its centre of mass (kg m^2)',
                        1e-5, 10.0),
    'i2': ParameterSpec(float, 'inertia of link 2 about its centre of mass (kg m^2)',
                        1e-5, 10.0),
    'b1': ParameterSpec(float, 'viscous friction of joint 1 (N m s/rad)', 0.0, 100.0),
    'b2': ParameterSpec(float, 'viscous friction of joint 2 (N m s/rad)', 0.0, 100.0),
    'gravity': ParameterSpec(float, 'gravity along -y of the arm plane (m/s^2); 0: horizontal',
                             -20.0, 20.0),
}
ARRAY_PARAMETERS = {
    'joint_lower_limits': ParameterSpec(list, 'lower joint limits (rad)', size=2),
    'joint_upper_limits': ParameterSpec(list, 'upper joint limits (rad)', size=2),
    'velocity_kp': ParameterSpec(list,
                                 'velocity-mode PI loop: proportional gains (N m s/rad)',
                                 size=2),
    'velocity_ki': ParameterSpec(list,
                                 'velocity-mode PI loop: integral gains (N m/rad)', size=2),
}
PARAMETERS = {
    **STEPPING_PARAMETERS,
    **ARM_PARAMETERS,
    **ARRAY_PARAMETERS,
    'initial_q': ParameterSpec(list, 'joint positions at start (rad)', size=2,
                               read_only=True),
    'effort_limit': ParameterSpec(float, 'drive torque limit of each joint (N m)', 0.1, 1000.0),
    **TIMING_PARAMETERS,
}


class ScaraSim(SteppedSimNode):
    """Integrates the arm and publishes its state at rate_hz."""

    joint_names = tuple(JOINT_NAMES)
    command_topics = {'effort': topics.EFFORT_COMMANDS, 'velocity': topics.VELOCITY_COMMANDS}
    stepping_thread_name = 'scara_sim_steps'

    def __init__(self):
        super().__init__(NODE_NAME)
        values = declare_parameters(self, PARAMETERS, load_defaults(PACKAGE, NODE_NAME))
        rate_hz = values['rate_hz']
        self.read_stepping_settings(values)
        initial_q = values['initial_q']
        self._effort_limit = values['effort_limit']
        try:
            params, limits, loop = self._model_from({})
            sim = ScaraSimulator(
                params=params, q=np.array(initial_q), dq=np.zeros(2), lower=limits[0],
                upper=limits[1], effort_limit=self._effort_limit, velocity_loop=loop,
                dt=1.0 / rate_hz)
        except ValueError as error:
            raise StartupError(f'bad parameters: {error}') from None
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.start_stepping_setup(sim, values, (
            f'simulating at {rate_hz:g} Hz (RK4, dt {1e3 / rate_hz:g} ms) from q = '
            f'{np.round(sim.q, 4).tolist()} rad; effort limit {self._effort_limit:g} '
            f'N m, command timeout {self._command_timeout:g} s'))

    def wrench_values(self, msg: WrenchStamped) -> tuple[float, float]:
        """Force x, y (N) on the end-effector."""
        return joint_command_floats((msg.wrench.force.x, msg.wrench.force.y))

    def tool_point(self, q) -> tuple[float, float, float]:
        params = self._sim.params
        return (*forward_kinematics_pair(*q, params.l1, params.l2), 0.0)

    def on_new_mode(self, mode: str) -> None:
        if mode == 'velocity':
            self._sim.velocity_loop.reset()

    # Parameters -------------------------------------------------------------------------

    def _model_from(self, overrides: dict):
        """ScaraParameters, joint limits and velocity loop from current params + overrides."""
        def value(name):
            return overrides[name] if name in overrides else self.get_parameter(name).value

        params = ScaraParameters(**{name: float(value(name)) for name in ARM_PARAMETERS})
        limits = (np.array(value('joint_lower_limits'), float),
                  np.array(value('joint_upper_limits'), float))
        if np.any(limits[0] >= limits[1]):
            raise ValueError(f'joint_lower_limits {limits[0].tolist()} must be below '
                             f'joint_upper_limits {limits[1].tolist()}')
        loop = VelocityLoop(kp=value('velocity_kp'), ki=value('velocity_ki'),
                            effort_limit=float(value('effort_limit')))
        return params, limits, loop

    def _validate_parameters(self, parameters) -> SetParametersResult:
        overrides = {p.name: p.value for p in parameters}
        for name in ARRAY_PARAMETERS:
            if name in overrides:
                reason = float_array_problem(overrides[name], 2)
                if reason:
                    return SetParametersResult(successful=False, reason=f'{name}: {reason}')
        try:
            self._model_from(overrides)
        except ValueError as error:
            return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters) -> None:
        params, limits, loop = self._model_from({})
        sim = self._sim
        sim.params, sim.lower, sim.upper = params, limits[0], limits[1]
        loop.integral = sim.velocity_loop.integral
        sim.velocity_loop = loop
        self._effort_limit = sim.effort_limit = self.get_parameter('effort_limit').value
        self.apply_timing_parameters(parameters)


def main(args=None):
    return run_sim_node(ScaraSim, NODE_NAME, args)


if __name__ == '__main__':
    sys.exit(main())
