"""Virtual AMB test rig: a nonlinear, closed-loop, sampled-data simulation of a machine's truth.

The truth is a nominal machine plus hidden effects with true parameters (the
effect library) plus what only a rig has: magnetic-center offsets, gravity,
sensor noise and ADC quantization, current-measurement noise and offsets, and
bias-current errors (``config/rigs/<name>.yaml``).  Nothing on the model side
reads it; only the acquisition rules drive it.

Signal chain of one controller cycle (thesis Fig. 4.1, ISO 14839-3)::

    V2 = Q(delay(sensor(x)) + noise)        measured position
    U1 = C(setpoint - V2)                   digital controller
    U2 = U1 + E_u                           excitation at the controller output
    coil current = amplifier(U2)            measured as i_b +- i + offset + noise
    F = eq. 3.6 (i_b +- eddy(coupling(i)), x - x_magnetic_center)

Linear parts are discretized exactly with a zero-order hold at the controller
cycle, around the true operating point (the static equilibrium under gravity
and offsets that the integral action settles to).  The force law's deviation
from its linearization there is evaluated every cycle from the sampled state
and held over the cycle, so the simulation is exact for the linearized truth
and second-order accurate in the nonlinearity.  Many frequency steps run as
one batch: every array has a trailing batch axis.
"""

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize

from .bearing import ActuatorAxes, force, force_derivatives
from .effects import effect_from_config, split_effects
from .errors import ConfigError, ModelError
from .machine import ALL_AXES, machine_from_config
from .plant import Plant
from .rig_effects import apply_controller_effects, rig_effect_from_config
from .sampled_loop import closed_loop_matrix, controller_matrices, coupling_matrix, sampled_system

__all__ = ["RigImperfections", "Rig", "rig_from_config", "RigModel", "SimulationState"]

N_AXES = len(ALL_AXES)


@dataclass(frozen=True)
class RigImperfections:
    """What only a real rig has (all per axis in ALL_AXES order, SI units).

    Attributes
    ----------
    magnetic_center_offset_m : array (5,)
        Position of the magnetic center in sensor coordinates.
    gravity_m_s2 : float
        Acts along -y on the rotor (DY, NY axes).
    sensor_noise_m, sensor_resolution_m : float
        Standard deviation of the position noise and the ADC step (0: none).
    current_noise_a, current_resolution_a : float
        Same for the coil-current measurements.
    current_offset_a : array (5, 2)
        Offsets of the upper and lower coil-current measurements.
    bias_current_error : array (5,)
        Relative error of the bias current the amplifiers actually deliver.
    """

    magnetic_center_offset_m: np.ndarray
    gravity_m_s2: float = 9.81
    sensor_noise_m: float = 0.0
    sensor_resolution_m: float = 0.0
    current_noise_a: float = 0.0
    current_resolution_a: float = 0.0
    current_offset_a: np.ndarray = None
    bias_current_error: np.ndarray = None


@dataclass(frozen=True)
class Rig:
    """A virtual rig: the truth machine (with its effects) and the rig's imperfections."""

    name: str
    machine: object
    imperfections: RigImperfections
    description: str = ""


def _per_axis(mapping, path, default=0.0, width=None):
    mapping = mapping or {}
    unknown = set(mapping) - set(ALL_AXES)
    if unknown:
        raise ConfigError(f"{path}.{sorted(unknown)[0]}", f"not an axis {list(ALL_AXES)}")
    shape = () if width is None else (width,)
    values = np.zeros((N_AXES,) + shape)
    for k, axis in enumerate(ALL_AXES):
        value = np.asarray(mapping.get(axis, default), dtype=float)
        if value.shape != shape or not np.all(np.isfinite(value)):
            raise ConfigError(f"{path}.{axis}", f"expected {'a number' if width is None else f'{width} numbers'}, got {mapping.get(axis)}")
        values[k] = value
    return values


def rig_from_config(rig_config, machine_config, source=None):
    """Build a `Rig` from its YAML mapping and the nominal machine's.

    ``truth.effects`` are added to the nominal machine's own effects;
    ``truth.unmodelled`` are effects outside the model's library
    (`ambid.rig_effects`): the controller ones change the rig's controllers,
    the others join its signal chains.
    """
    try:
        truth = rig_config.get("truth") or {}
        machine = machine_from_config(machine_config, name=rig_config.get("machine"))
        hidden = [effect_from_config(spec, f"truth.effects[{i}]", machine) for i, spec in enumerate(truth.get("effects") or ())]
        unmodelled = [rig_effect_from_config(spec, f"truth.unmodelled[{i}]") for i, spec in enumerate(truth.get("unmodelled") or ())]
        machine, unmodelled = apply_controller_effects(machine, unmodelled)
        machine = machine.with_effects(list(machine.effects) + hidden + unmodelled)
        imperfections = RigImperfections(
            magnetic_center_offset_m=_per_axis(truth.get("magnetic_center_offset_m"), "truth.magnetic_center_offset_m"),
            gravity_m_s2=float(truth.get("gravity_m_s2", 9.81)),
            sensor_noise_m=float(truth.get("sensor_noise_m", 0.0)),
            sensor_resolution_m=float(truth.get("sensor_resolution_m", 0.0)),
            current_noise_a=float(truth.get("current_noise_a", 0.0)),
            current_resolution_a=float(truth.get("current_resolution_a", 0.0)),
            current_offset_a=_per_axis(truth.get("current_offset_a"), "truth.current_offset_a", default=[0.0, 0.0], width=2),
            bias_current_error=_per_axis(truth.get("bias_current_error"), "truth.bias_current_error"),
        )
        for key in ("sensor_noise_m", "sensor_resolution_m", "current_noise_a", "current_resolution_a", "gravity_m_s2"):
            if getattr(imperfections, key) < 0:
                raise ConfigError(f"truth.{key}", "must be >= 0")
        if machine.axial_electromagnet is None:
            raise ConfigError("machine", "the virtual rig needs a machine with an axial bearing")
        return Rig(name=rig_config.get("name", "rig"), machine=machine, imperfections=imperfections,
                   description=rig_config.get("description", ""))
    except ConfigError as error:
        raise error.within(source=source) from None


@dataclass
class SimulationState:
    """Batched state of the rig and its controllers; trailing axis = batch member.

    ``setpoint_m`` and ``bias_a`` (5, B) are what the PLC commands per member: the
    position set points and the bias currents (the amplifiers deliver them with
    the rig's bias error).  ``held_a`` (5, B) is the control current commanded in
    the cycle before, which the amplifiers hold when the PLC samples the coil
    currents at the start of a cycle (with the positions, before its new output).
    """

    plant: np.ndarray  # (n_states, B)
    controller: np.ndarray  # (n_controller_states, B)
    sensor_buffer: np.ndarray  # (buffer_length, 5, B) delayed sensor samples
    step: int
    setpoint_m: np.ndarray  # (5, B)
    bias_a: np.ndarray  # (5, B) commanded bias currents
    held_a: np.ndarray  # (5, B) control currents of the cycle before

    def take(self, members):
        """Keep only the given batch members (compaction of finished ones)."""
        return SimulationState(self.plant[:, members], self.controller[:, members], self.sensor_buffer[:, :, members],
                               self.step, self.setpoint_m[:, members], self.bias_a[:, members], self.held_a[:, members])


class RigModel:
    """The rig's truth, linearized at its operating point and discretized, plus the nonlinear step.

    Parameters
    ----------
    rig : Rig
    setpoint_m : array (5,), optional
        Position controller set points (default 0, the sensor zero).
    """

    def __init__(self, rig, setpoint_m=None):
        self.rig = rig
        machine = rig.machine
        self.imperfections = imp = rig.imperfections
        self.sample_time_s = machine.sample_time_s
        self.setpoint_m = np.zeros(N_AXES) if setpoint_m is None else np.asarray(setpoint_m, dtype=float)
        plant = Plant(machine)
        self.plant = plant
        machine = plant.machine  # with the structure effects applied (the actuators' parameters among them)
        nominal = [*machine.radial_electromagnets, machine.axial_electromagnet]
        self.nominal_bias_a = np.array([a.bias_current_a for a in nominal])
        self.true_bias_a = self.nominal_bias_a * (1 + imp.bias_current_error)
        self.actuators = ActuatorAxes.stack(nominal)
        self.rotor_mass_kg = machine.rotor.mass_kg

        # structure: radial modal model (no bearing stiffness) + axial rigid body
        radial = plant.radial
        n_r = radial.mass.shape[0]
        n_q = n_r + 1
        self.n_q = n_q
        self.mass = scipy.linalg.block_diag(radial.mass, [[self.rotor_mass_kg]])
        self.damping = scipy.linalg.block_diag(radial.damping + radial.speed_rad_s * radial.gyroscopic, [[0.0]])
        self.free_stiffness = scipy.linalg.block_diag(plant.free_stiffness, [[0.0]])
        self.actuator_shape = np.zeros((n_q, N_AXES))
        self.actuator_shape[:n_r, :4] = plant.actuator_shape
        self.actuator_shape[n_r, 4] = 1.0
        self.sensor_shape = np.zeros((N_AXES, n_q))
        self.sensor_shape[:4, :n_r] = radial.output_matrix
        self.sensor_shape[4, n_r] = 1.0
        self.gravity = np.concatenate([plant.gravity_force(imp.gravity_m_s2), [0.0]])

        _, input_effects, output_effects = split_effects(machine.effects)
        self.input_coupling = coupling_matrix(input_effects, "input", ALL_AXES)  # for the static operating point
        self.output_coupling = coupling_matrix(output_effects, "output", ALL_AXES)

        self.controllers = list(machine.radial_controllers) + [machine.axial_controller]
        self._controller_matrices(self.controllers)
        self.operating_point = self._operating_point()
        self._linear_system()
        self._initial = self._steady_state()
        # one product gives every per-cycle output of the state: coil current, force-producing current, actuator
        # position; one more gives the next state and the sensor sample later cycles read (from state and inputs)
        self.state_outputs = np.vstack([self.coil_state, self.force_state, self.position_state])
        self.state_update = np.block([[self.transition, self.input_matrix], [self.delayed_state, self.delayed_input]])
        # one product gives the command and the next controller state from the controller state and the error
        self.controller_update = np.block([[self.ctrl_c, self.ctrl_d], [self.ctrl_a, self.ctrl_b]])
        self._residual_constants()
        radius = self.closed_loop_spectral_radius()
        if radius >= 1.0:
            raise ModelError(f"rig {rig.name}: the linearized truth's closed loop is unstable (spectral radius {radius:.6f})")

    # ------------------------------------------------------------ controller
    def _controller_matrices(self, controllers):
        self.ctrl_a, self.ctrl_b, self.ctrl_c, self.ctrl_d, blocks = controller_matrices(controllers)
        self.controller_blocks = blocks
        self.integral_action = np.array([c.integral_gain_a_per_m_s > 0 for c in controllers])
        self.dc_gain = np.array([c.frequency_response([0.0])[0].real if c.integral_gain_a_per_m_s == 0 else np.inf for c in controllers])

    # -------------------------------------------------------- operating point
    def _force_current(self, command_a):
        """Static force-producing current from a static command (all chains have unit DC gain)."""
        return self.input_coupling @ command_a

    def _operating_point(self):
        """Static equilibrium: structure at rest under gravity, sensors at the set points.

        With integral action the controller drives the measured position to its
        set point; without, the static current is ``kp (setpoint - y)``.
        """
        q, command = self._equilibrium(hold="set_point")
        imp = self.imperfections
        current = self._force_current(command)
        position = self.actuator_shape.T @ q - imp.magnetic_center_offset_m
        bias = self.true_bias_a[:, None]
        f0, ki, kx = force_derivatives(self.actuators, bias + current[:, None], bias - current[:, None], position[:, None])
        if np.any(self.true_bias_a - np.abs(current) <= 0):
            raise ModelError(f"rig {self.rig.name}: a coil current is negative at the operating point")
        return dict(q=q, command=command, force_current=current, actuator_position=position + imp.magnetic_center_offset_m,
                    force=f0[:, 0], current_stiffness=ki[:, 0], position_stiffness=kx[:, 0])

    def _equilibrium(self, hold):
        """Static structure displacement and control currents.

        ``hold="set_point"``: the sensors read the set points (integral action);
        ``hold="magnetic_center"``: every actuator sits at its magnetic center.
        """
        imp, shape = self.imperfections, self.actuator_shape
        scale_q = 1e-6
        proportional = np.where(self.integral_action, 0.0, self.dc_gain)

        def residual(v):
            q, command = v[: self.n_q] * scale_q, v[self.n_q :]
            current = self._force_current(command)
            x = shape.T @ q - imp.magnetic_center_offset_m
            bias = self.true_bias_a[:, None]
            f = force(self.actuators, bias + current[:, None], bias - current[:, None], x[:, None])[:, 0]
            statics = self.free_stiffness @ q - shape @ f - self.gravity
            if hold == "magnetic_center":
                return np.concatenate([statics, x / scale_q])
            sensed = self.output_coupling @ (self.sensor_shape @ q) - self.setpoint_m
            loop = np.where(self.integral_action, sensed / scale_q, command + proportional * sensed)
            return np.concatenate([statics, loop])

        solution = scipy.optimize.root(residual, np.zeros(self.n_q + N_AXES), method="hybr", options={"xtol": 1e-13})
        if not solution.success or np.max(np.abs(residual(solution.x))) > 1e-6:
            raise ModelError(f"rig {self.rig.name}: no static equilibrium found ({solution.message})")
        return solution.x[: self.n_q] * scale_q, solution.x[self.n_q :]

    def magnetic_center_sensor_m(self):
        """The truth the calibration should find: sensor readings with every actuator at its magnetic center [m].

        Differs from ``magnetic_center_offset_m`` (given at the actuators) by the rotor's
        tilt between non-collocated sensors and actuators and its static sag.
        """
        q, _ = self._equilibrium(hold="magnetic_center")
        return self.output_coupling @ (self.sensor_shape @ q)

    # ------------------------------------------------------------ linear part
    def _linear_system(self):
        """The sampled-data loop plant around the operating point (`ambid.sampled_loop.sampled_system`).

        State ``[input chain, force chain, q, q', sensor chain]``; inputs ``[U2 (5),
        force-law residual (5), 1]``; the constant input carries the linearization's
        force at the operating point and gravity.
        """
        op = self.operating_point
        ki, kx = op["current_stiffness"], op["position_stiffness"]
        constant = op["force"] - ki * op["force_current"] - kx * op["actuator_position"]
        system = sampled_system(self.mass, self.damping, self.free_stiffness, self.actuator_shape, self.sensor_shape, ki, kx,
                                self.rig.machine.effects, ALL_AXES, self.sample_time_s, constant_force=constant,
                                static_force=self.gravity)
        self.system = system
        self.a, self.b, self.n_states, self.blocks = system.a, system.b, system.n_states, system.blocks
        self.sensor_output = system.sensor_output
        self.coil_state, self.coil_input = system.coil_state, system.coil_input
        self.force_state, self.force_input = system.force_state, system.force_input
        self.position_state = system.position_state
        self.transition, self.input_matrix = system.transition, system.input_matrix
        self.delay_s, self.delay_steps, self.buffer_length = system.delay_s, system.delay_steps, system.buffer_length
        self.delayed_state, self.delayed_input = system.delayed_state, system.delayed_input
        self._axis_index = np.arange(N_AXES)

    def _steady_state(self):
        op = self.operating_point
        inputs = np.concatenate([op["command"], np.zeros(N_AXES), [1.0]])
        state = np.linalg.solve(self.a, -self.b @ inputs)
        if np.max(np.abs(state[self.blocks(2)] - op["q"])) > 1e-9 + 1e-6 * np.max(np.abs(op["q"])):
            raise ModelError("linearized rig is not at rest at its operating point")
        controller = []
        error = self.setpoint_m - self.output_coupling @ (self.sensor_shape @ op["q"])
        for k, (ac, bc, cc, dc) in enumerate(self.controller_blocks):
            n = ac.shape[0]
            if self.integral_action[k]:
                lhs = np.vstack([np.eye(n) - ac, cc])
                rhs = np.concatenate([np.zeros(n), [op["command"][k]]])
                controller.append(np.linalg.lstsq(lhs, rhs, rcond=None)[0])
            else:
                controller.append(np.linalg.solve(np.eye(n) - ac, bc[:, 0] * error[k]))
        return state, np.concatenate(controller), inputs

    # ----------------------------------------------------------- simulation
    def initial_state(self, batch):
        """All members at rest at the operating point (set points and bias as configured)."""
        plant, controller, inputs = self._initial
        sensor = self.delayed_state @ plant + self.delayed_input @ inputs
        buffer = np.broadcast_to(sensor[None, :, None], (self.buffer_length, N_AXES, batch)).copy()
        return SimulationState(
            np.repeat(plant[:, None], batch, axis=1),
            np.repeat(controller[:, None], batch, axis=1),
            buffer,
            0,
            np.repeat(self.setpoint_m[:, None], batch, axis=1),
            np.repeat(self.nominal_bias_a[:, None], batch, axis=1),
            np.repeat(inputs[:N_AXES, None], batch, axis=1),
        )

    def _residual_constants(self):
        """Per-axis constants of `residual_force`, column arrays (5, 1): the per-cycle loop evaluates eq. 3.6 and its
        linearization with them instead of rebuilding them from the actuator and the operating point every cycle."""
        op, axes = self.operating_point, self.actuators
        cosine = np.cos(axes.pole_angle_rad)
        self._gap_sum = 2 * axes.nominal_air_gap_m + axes.iron_path_m  # upper / lower path at x = 0
        self._gap_slope = 2 * cosine  # d(lower path)/dx = -d(upper path)/dx
        self._force_constant = axes.force_constant
        self._center_m = self.imperfections.magnetic_center_offset_m[:, None]
        self._current_stiffness = op["current_stiffness"][:, None]
        self._position_stiffness = op["position_stiffness"][:, None]
        self._bias_delivered = (1 + self.imperfections.bias_current_error)[:, None]
        self._linear_offset = (op["force"] - op["current_stiffness"] * op["force_current"]
                               - op["position_stiffness"] * op["actuator_position"])[:, None]

    def residual_force(self, force_current, position, bias_a=None):
        """Force law (eq. 3.6) minus its linearization at the operating point, per axis [N].

        ``bias_a`` (5, B) are the delivered bias currents (default: the operating
        point's).  Coil currents cannot reverse: a coil whose current would go
        negative carries none.
        """
        bias = self.true_bias_a[:, None] if bias_a is None else bias_a
        upper = np.maximum(bias + force_current, 0.0)
        lower = np.maximum(bias - force_current, 0.0)
        # eq. 3.6 (`ambid.bearing.force`, its gaps `ambid.bearing._gaps`) relative to the magnetic center, written out
        # with the per-axis constants for the per-cycle loop; tests/test_rig.py holds it to `ambid.bearing.force`
        shift = self._gap_slope * (position - self._center_m)
        upper /= self._gap_sum - shift
        lower /= self._gap_sum + shift
        upper *= upper
        lower *= lower
        upper -= lower
        upper *= self._force_constant  # the exact force
        upper -= self._linear_offset
        upper -= self._current_stiffness * force_current
        upper -= self._position_stiffness * position
        return upper

    def closed_loop_spectral_radius(self):
        """Largest |eigenvalue| of the linearized, noise-free closed loop (plant, controllers, delays).

        The loop the model side judges too (`ambid.sampled_loop.closed_loop_matrix`), here at the
        rig's true operating point.
        """
        return float(np.max(np.abs(np.linalg.eigvals(closed_loop_matrix(self.system, self.controllers)))))

    def step(self, state, excitation_a, rng=None, nonlinear=True, quantize=True):
        """Advance every member one controller cycle.

        Parameters
        ----------
        state : SimulationState
            Updated in place.
        excitation_a : array (5, B)
            E_u added to the controller outputs during this cycle.
        rng : numpy.random.Generator, optional
            Noise source; None gives a noise-free (but still quantized) run.
        nonlinear : bool
            False simulates the linearized truth (the cross-check reference).
        quantize : bool
            False skips the ADC quantization (for the linear analysis only).

        Returns
        -------
        channels : array (20, B)
            In `ambid.logs.CHANNELS` order: U2 and V2 of every axis, then I_upper, I_lower of each axis [A, m].
        """
        imp = self.imperfections
        x = state.plant
        n, batch = x.shape
        sensed = state.sensor_buffer[state.step % self.buffer_length]
        if rng is not None and imp.sensor_noise_m > 0:
            sensed = sensed + imp.sensor_noise_m * rng.standard_normal((N_AXES, batch))
        measured = _quantize(sensed, imp.sensor_resolution_m) if quantize else sensed
        error = state.setpoint_m - measured
        controller = self.controller_update @ np.concatenate([state.controller, error])
        command = controller[:N_AXES]
        command += excitation_a
        state.controller = controller[N_AXES:]
        outputs = self.state_outputs @ x
        # the coil currents are sampled at the start of the cycle, with the positions: the amplifiers still hold the
        # command of the cycle before (an ideal amplifier's current is one cycle behind U2, as a fast one's is)
        coil = outputs[:N_AXES] + self.coil_input @ state.held_a
        state.held_a = command
        # [state; inputs]: the inputs are U2 (5), the force law's residual (5) and the constant 1
        extended = np.empty((self.state_update.shape[1], batch))
        extended[:n] = x
        extended[n : n + N_AXES] = command
        extended[n + 2 * N_AXES] = 1.0
        bias = state.bias_a * self._bias_delivered  # what the amplifiers deliver
        if nonlinear:
            force_current = outputs[N_AXES : 2 * N_AXES] + self.force_input @ command
            extended[n + N_AXES : n + 2 * N_AXES] = self.residual_force(force_current, outputs[2 * N_AXES :], bias)
        else:
            extended[n + N_AXES : n + 2 * N_AXES] = 0.0
        updated = self.state_update @ extended
        state.plant = updated[:n]
        # sensor samples that later cycles will read (fractional-step outputs)
        slots = (state.step + self.delay_steps) % self.buffer_length
        state.sensor_buffer[slots, self._axis_index] = updated[n:]
        state.step += 1
        # ambid.logs.CHANNELS order: U2 and V2 of every axis, then the (upper, lower) pair of each axis
        channels = np.empty((4 * N_AXES, batch))
        channels[:N_AXES] = command
        channels[N_AXES : 2 * N_AXES] = measured
        upper, lower = channels[2 * N_AXES :: 2], channels[2 * N_AXES + 1 :: 2]
        np.add(bias, coil, out=upper)
        upper += imp.current_offset_a[:, :1]
        np.subtract(bias, coil, out=lower)
        lower += imp.current_offset_a[:, 1:]
        if rng is not None and imp.current_noise_a > 0:
            upper += imp.current_noise_a * rng.standard_normal((N_AXES, batch))
            lower += imp.current_noise_a * rng.standard_normal((N_AXES, batch))
        if quantize:
            channels[2 * N_AXES :] = _quantize(channels[2 * N_AXES :], imp.current_resolution_a)
        return channels

    # --------------------------------------------------------- linear model
    def sampled_frequency_response(self, frequency_hz):
        """FRF of the linearized truth from U2 samples to sensor samples, (n_f, 5, 5) [m/A].

        What the rig measures at small amplitude without noise (`ambid.sampled_loop.SampledSystem.frequency_response`).
        """
        return self.system.frequency_response(frequency_hz)


def _quantize(values, step):
    return values if step <= 0 else np.rint(values / step) * step
