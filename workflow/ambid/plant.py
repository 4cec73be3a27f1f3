"""Open-loop plant of a flexible rotor on AMBs: modal model, FRFs, poles and zeros.

The rotor's free-free bending modes (one plane, mass-normalized) are the modal
basis of thesis eq. 2.10-2.12.  Coordinates are ``q = [eta_x, eta_y, h]``: the
modal coordinates of the xz and yz planes and, with a ``foundation_mode``
effect, the housing displacements.  The radial plant (control currents of DX,
DY, NX, NY [A] -> sensor positions [m]) is::

    M q'' + (D + Omega G) q' + (K - B_a kx B_a^T) q = B_a ki i_c,     y = C_s q

with ``B_a`` the actuator shape (force on the rotor, reaction on the housing)
and ``C_s`` the sensor shape (rotor relative to housing).  Input- and
output-side effects multiply the structural FRF: ``P = Out(jw) H(jw) In(jw)``.
The axial axis Z is a rigid body on its own bearing.
"""

import copy
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
import scipy.linalg

from .effects import split_effects
from .errors import ModelError
from .machine import AXIAL_AXIS, AXIS_LOCATION, BEARINGS, RADIAL_AXES
from .sampled_loop import closed_loop, sampled_system, zoh_discretize  # zoh_discretize: re-exported

__all__ = ["Plant", "damping_ratio", "zoh_discretize", "RIGID_MODES"]

RIGID_MODES = 2  # translation and tilt of the free-free rotor in each plane
# structure effects that leave the rotor and its modes as they are: a plant with them is coupled from the
# one without (`Plant.coupled_response`)
COUPLED_EFFECTS = ("actuator_coefficients", "foundation_mode", "noncollocation")


def damping_ratio(poles):
    """Damping ratio ``-Re(s) / |s|`` of continuous poles (-1 / +1 for real stable / unstable)."""
    poles = np.asarray(poles)
    magnitude = np.abs(poles)
    return np.where(magnitude > 0, -poles.real / np.where(magnitude > 0, magnitude, 1.0), 0.0)


_MODAL_SUM_PATHS = {}  # operand shapes -> the contraction order np.einsum(optimize=True) finds for them


def _modal_sum(left, resolvent, right):
    """``sum_k left[o, k] resolvent[f, k] right[k, i]``, (n_freq, n_out, n_in), in the order ``optimize=True`` picks.

    The order is found once per shapes: finding it cost as much as the sum itself (a diagnosis evaluates the model
    some ten thousand times on one grid).
    """
    key = (left.shape, resolvent.shape, right.shape)
    if key not in _MODAL_SUM_PATHS:
        _MODAL_SUM_PATHS[key] = np.einsum_path("ok,fk,ki->foi", left, resolvent, right, optimize=True)[0]
    return np.einsum("ok,fk,ki->foi", left, resolvent, right, optimize=_MODAL_SUM_PATHS[key])


@dataclass(frozen=True)
class SecondOrderModel:
    """``M q'' + (D + Omega G) q' + K q = B u``, ``y = C q`` (stiffness includes the bearings)."""

    mass: np.ndarray
    damping: np.ndarray
    gyroscopic: np.ndarray
    stiffness: np.ndarray
    input_matrix: np.ndarray
    output_matrix: np.ndarray
    speed_rad_s: float
    planes: tuple = ()  # index arrays of the x- and y-plane coordinates, coupled only by the gyroscopic terms

    def frequency_response(self, frequency_hz, output_matrix=None):
        """Structural FRF, array (n_freq, n_out, n_in).

        By modal superposition of the first-order form, ``C V (jw - Lambda)^-1 V^-1 B``
        (one eigen-decomposition per block of `uncoupled_states`, then O(n) per frequency); by a batched linear solve
        of the dynamic stiffness when the eigenvectors are ill-conditioned (a
        nearly defective system).  ``output_matrix`` replaces ``C`` (other sensors on the same structure: the
        eigen-decomposition is kept).
        """
        frequency_hz = np.asarray(frequency_hz, dtype=float)
        output_matrix = self.output_matrix if output_matrix is None else np.asarray(output_matrix, dtype=float)
        if not np.isfinite(output_matrix).all():
            raise ModelError("the structural model has non-finite entries (sensor shapes)")
        modal = self._modal_form
        if modal is not None:
            blocks, poles, vectors, right = modal
            left = np.hstack([output_matrix[:, states] @ v[: states.size] for states, v in zip(blocks, vectors)])
            resolvent = 1.0 / (2j * np.pi * frequency_hz[:, None] - poles[None, :])
            return _modal_sum(left, resolvent, right)
        w = 2 * np.pi * frequency_hz[:, None, None]
        dynamic = self.stiffness - w**2 * self.mass + 1j * w * (self.damping + self.speed_rad_s * self.gyroscopic)
        return output_matrix @ np.linalg.solve(dynamic, self.input_matrix.astype(complex))

    @cached_property
    def _modal_form(self):
        """``(blocks, poles, V, V^-1 B)`` of `frequency_response`'s modal superposition, once per model; None where the
        eigenvectors of a block are ill-conditioned."""
        a, b, c = self.state_space()
        if not (np.isfinite(a).all() and np.isfinite(b).all() and np.isfinite(c).all()):
            raise ModelError("the structural model has non-finite entries (mass, damping, stiffness or shapes)")
        blocks, poles, vectors, right = [], [], [], []
        # one eigen-decomposition per uncoupled block (the x and y planes of a rotor at standstill): the same modes
        # at about half the cost of one of the whole
        for states in self.uncoupled_states():
            block = np.concatenate([states, states + self.mass.shape[0]])
            block_poles, block_vectors = scipy.linalg.eig(a[np.ix_(block, block)], check_finite=False)  # (checked above)
            # the eigenvectors' condition from their LU factors (LAPACK gecon's 1-norm estimate), which also solve for
            # V^-1 B
            factors = scipy.linalg.lu_factor(block_vectors, check_finite=False)
            gecon = scipy.linalg.get_lapack_funcs("gecon", (factors[0],))
            reciprocal_condition, _ = gecon(factors[0], np.linalg.norm(block_vectors, 1), norm="1")
            if not reciprocal_condition > 1e-8:
                return None
            blocks.append(states)
            poles.append(block_poles)
            vectors.append(block_vectors)  # the output is C q: only the rows of the positions q count
            right.append(scipy.linalg.lu_solve(factors, b[block].astype(complex), check_finite=False))
        return blocks, np.concatenate(poles), vectors, np.vstack(right)

    def uncoupled_states(self):
        """Index arrays of the coordinates ``q`` that no term couples: the ``planes`` at standstill, else all of them."""
        if self.planes and self.speed_rad_s == 0:
            return list(self.planes)
        return [np.arange(self.mass.shape[0])]

    def state_space(self):
        """First-order form (A, B, C) with state ``[q, q']``."""
        n = self.mass.shape[0]
        inverse_mass = np.linalg.inv(self.mass)
        a = np.block(
            [
                [np.zeros((n, n)), np.eye(n)],
                [-inverse_mass @ self.stiffness, -inverse_mass @ (self.damping + self.speed_rad_s * self.gyroscopic)],
            ]
        )
        b = np.vstack([np.zeros_like(self.input_matrix), inverse_mass @ self.input_matrix])
        c = np.hstack([self.output_matrix, np.zeros_like(self.output_matrix)])
        return a, b, c


class Plant:
    """The open-loop plant of a `Machine`, with all its effects applied.

    Parameters
    ----------
    machine : ambid.machine.Machine

    static_correction : bool
        Append to the retained modes the static deflection of the dropped ones
        under the actuator forces (`ambid.rotor.Rotor.planar_modes`); False keeps
        the plain truncation (as `ambid.modal_features` does).

    Notes
    -----
    Structure effects are applied first (they change the machine), then the
    modal model is built with ``machine.retained_modes`` planar modes.
    """

    def __init__(self, machine, static_correction=True):
        structure, self.input_effects, self.output_effects = split_effects(machine.effects)
        for effect in structure:
            machine = effect.apply(machine)
        self.machine = machine
        self.rotor = machine.rotor
        self.static_correction = static_correction
        # the lowest modes plus the static correction of the dropped ones under the actuator forces
        loads = tuple(b.actuator_position_m for b in machine.radial_bearings) if static_correction else ()
        self.modes = self.rotor.planar_modes(machine.retained_modes, loads)
        self.radial = self._radial_model()
        self._responses = {}  # structural responses by frequency grid, shared with `with_signal_effects` copies
        self._coupled_from = None  # the plant this one's structural FRF is coupled from (`coupled_response`)

    def with_signal_effects(self, effects):
        """A copy with input- and output-side ``effects`` added, sharing the structural model.

        Cheap: what the diagnosis uses to try an amplifier, sensor or delay on a model.
        """
        structure, inputs, outputs = split_effects(effects)
        if structure:
            raise ModelError(f"structure effects change the modal model: build a new Plant ({structure[0].name})")
        plant = copy.copy(self)
        plant.input_effects = list(self.input_effects) + inputs
        plant.output_effects = list(self.output_effects) + outputs
        return plant

    def with_structure_effects(self, effects):
        """A new plant with more structure ``effects``, applied together on top of this plant's structure.

        One rebuild of the modal model however many effects are added (the
        diagnosis' joint refit changes every element group of an update at once);
        the effects already applied are not applied again.
        """
        effects = tuple(effects)
        wrong = [e.name for e in effects if e.location != "structure"]
        if wrong:
            raise ModelError(f"{wrong[0]} is not a structure effect: use with_signal_effects")
        if not effects:
            return self
        applied = replace(self.machine, effects=(*effects, *self.input_effects, *self.output_effects))
        plant = Plant(applied, static_correction=self.static_correction)
        plant.machine = replace(plant.machine, effects=self.machine.effects + effects)
        if self.machine.foundation is None and all(e.name in COUPLED_EFFECTS for e in effects):
            # the same rotor: its FRF from this plant's receptances, without an eigen-solution
            plant._coupled_from = self
        return plant

    def at_speed(self, speed_rad_s):
        """A copy spinning at ``speed_rad_s`` (what the ``gyroscopic`` effect does), sharing the modal model."""
        plant = copy.copy(self)
        plant.machine = replace(self.machine, speed_rad_s=float(speed_rad_s))
        plant.radial = replace(self.radial, speed_rad_s=float(speed_rad_s))
        plant._responses = {}
        plant._coupled_from = None
        return plant

    def cached(self, key, compute):
        """``compute()`` once per ``key`` for this structure (shared by the copies `with_signal_effects` makes).

        ``key`` must name everything the value depends on beyond the structure
        (frequency grid, effects); the value must not be modified by the caller.
        """
        if key not in self._responses:
            self._responses[key] = compute()
        return self._responses[key]

    # ------------------------------------------------------------------ model
    def _modal_damping(self):
        omega = self.modes.angular_frequency_rad_s
        eta = self.rotor.modal_loss_factors(self.modes)
        damping = eta * omega
        added = np.asarray(self.machine.added_modal_damping, dtype=float)
        if added.size:
            flexible = np.arange(RIGID_MODES, RIGID_MODES + (len(omega) - RIGID_MODES if added.size == 1 else added.size))
            damping[flexible] += 2 * added * omega[flexible]
        return np.diag(damping)

    def _radial_model(self):
        rotor, modes, machine = self.rotor, self.modes, self.machine
        n_modes = modes.shapes.shape[1]
        polar = modes.shapes.T @ rotor.planar_matrices()["polar"] @ modes.shapes
        modal_damping = self._modal_damping()
        housings = machine.foundation is not None
        n = 2 * n_modes + (4 if housings else 0)
        mass = np.eye(n)
        stiffness = np.zeros((n, n))
        damping = np.zeros((n, n))
        gyroscopic = np.zeros((n, n))
        xs, ys = slice(0, n_modes), slice(n_modes, 2 * n_modes)
        stiffness[xs, xs] = stiffness[ys, ys] = np.diag(modes.angular_frequency_rad_s**2)
        damping[xs, xs] = damping[ys, ys] = modal_damping
        gyroscopic[xs, ys], gyroscopic[ys, xs] = polar, -polar
        if housings:
            f = machine.foundation
            w = 2 * np.pi * f.frequency_hz
            h = slice(2 * n_modes, n)
            mass[h, h] = f.mass_kg * np.eye(4)
            stiffness[h, h] = f.mass_kg * w**2 * np.eye(4)
            damping[h, h] = 2 * f.damping_ratio * f.mass_kg * w * np.eye(4)

        actuator = np.zeros((n, 4))  # relative-displacement (and force) shape of each axis
        sensor = np.zeros((4, n))
        current_stiffness = np.zeros(4)
        position_stiffness = np.zeros(4)
        for k, axis in enumerate(RADIAL_AXES):
            bearing_name, plane = AXIS_LOCATION[axis]
            bearing = machine.bearing(bearing_name)
            part = xs if plane == "x" else ys
            actuator[part, k] = rotor.planar_displacement_row(bearing.actuator_position_m) @ modes.shapes
            sensor[k, part] = rotor.planar_displacement_row(bearing.sensor_position_m) @ modes.shapes
            if housings and bearing_name in machine.foundation.bearings:
                hk = 2 * n_modes + 2 * BEARINGS.index(bearing_name) + (0 if plane == "x" else 1)
                actuator[hk, k] = -1.0
                sensor[k, hk] = -1.0
            current_stiffness[k], position_stiffness[k] = bearing.linearize(plane)
        self.current_stiffness = current_stiffness
        self.position_stiffness = position_stiffness
        self.actuator_shape = actuator  # force / relative-displacement shape of each radial axis
        self.free_stiffness = stiffness  # structure without the bearings' negative stiffness
        return SecondOrderModel(
            mass=mass,
            damping=damping,
            gyroscopic=gyroscopic,
            stiffness=stiffness - actuator @ np.diag(position_stiffness) @ actuator.T,
            input_matrix=actuator * current_stiffness,
            output_matrix=sensor,
            speed_rad_s=machine.speed_rad_s,
            # each housing's x coordinate at 2 n_modes + 2 k, its y coordinate next to it
            planes=(np.r_[0:n_modes, 2 * n_modes:n:2], np.r_[n_modes:2 * n_modes, 2 * n_modes + 1:n:2]),
        )

    # ------------------------------------------------------------ responses
    def gravity_force(self, gravity_m_s2):
        """Generalized force of gravity along -y on the rotor (y-plane modal coordinates).

        The consistent load of a uniform body force: ``-g Psi^T M t`` with ``t`` the
        rigid translation (u = 1, theta = 0 at every node).  Housings' weight is
        carried by their mounts and left out.
        """
        n_modes = self.modes.shapes.shape[1]
        translation = np.zeros(2 * self.rotor.n_nodes)
        translation[0::2] = 1.0
        force = np.zeros(self.radial.mass.shape[0])
        force[n_modes : 2 * n_modes] = -gravity_m_s2 * self.modes.shapes.T @ self.rotor.planar_matrices()["mass"] @ translation
        return force

    def _effect_matrices(self, effects, frequency_hz, axes):
        out = None
        for effect in effects:
            r = effect.response(frequency_hz, axes)
            out = r if out is None else r @ out
        return out

    def radial_frequency_response(self, frequency_hz):
        """Radial plant P(jw), array (n_freq, 4, 4) [m/A]; rows outputs, columns inputs (DX, DY, NX, NY)."""
        frequency_hz = np.asarray(frequency_hz, dtype=float)
        response = self.cached(("radial", frequency_hz.tobytes()), lambda: self._structural_response(frequency_hz))
        axes = list(RADIAL_AXES)
        inp = self._effect_matrices(self.input_effects, frequency_hz, axes)
        out = self._effect_matrices(self.output_effects, frequency_hz, axes)
        if inp is not None:
            response = response @ inp
        if out is not None:
            response = out @ response
        return response

    def _structural_response(self, frequency_hz):
        """The structural FRF (n_freq, 4, 4): of the modal model, or coupled from another plant's receptances."""
        if self._coupled_from is None:
            return self.radial.frequency_response(frequency_hz)
        base = self._coupled_from
        sensors = self.radial.output_matrix[:, : base.radial.mass.shape[0]]  # on the modal coordinates (not housings)
        return base.coupled_response(frequency_hz, self.current_stiffness, self.position_stiffness, self.machine.foundation,
                                     None if np.array_equal(sensors, base.radial.output_matrix) else sensors)

    def receptances(self, frequency_hz, sensor_matrix=None):
        """Receptances of the structure with its bearings (their negative stiffness included) [m/N].

        Parameters
        ----------
        frequency_hz : array_like
        sensor_matrix : array (4, n), optional
            Other sensor shapes in this plant's modal coordinates (sensors moved
            along the rotor); default its own.

        Returns
        -------
        sensor, actuator : ndarray (n_freq, 4, 4)
            Displacement at each radial axis' sensor and at its actuator per
            unit force at each axis' actuator (columns); ``sensor * ki`` is the
            structural FRF.
        """
        frequency_hz = np.asarray(frequency_hz, dtype=float)
        own = sensor_matrix is None
        rows = np.vstack([self.radial.output_matrix if own else np.asarray(sensor_matrix, dtype=float),
                          self.actuator_shape.T])

        def compute():
            unit_forces = self.cached("unit_forces", lambda: replace(self.radial, input_matrix=self.actuator_shape))
            response = unit_forces.frequency_response(frequency_hz, rows)
            return response[:, :4], response[:, 4:]

        # kept for the plant's own sensors only (moved ones: one FRF per trial, kept by the plant that asks)
        return self.cached(("receptances", frequency_hz.tobytes()), compute) if own else compute()

    def coupled_response(self, frequency_hz, current_stiffness, position_stiffness, foundation=None, sensor_matrix=None):
        """Structural FRF (n_freq, 4, 4) [m/A] of this plant's rotor on other bearing coefficients, with other sensor
        positions and, with a ``foundation``, on housings: coupled through the bearings from this plant's
        `receptances` (substructuring, no new eigen-solution; what the diagnosis' ``actuator_coefficients``,
        ``noncollocation`` and ``foundation_mode`` candidates cost).

        A change ``d`` of the bearings' negative stiffness ``kx`` is a rank-4 change of
        the dynamic stiffness, ``Z' = Z - B_a d B_a^T`` (thesis eq. 2.10-2.11), so
        (Woodbury) ``R' = R + R d (1 - R_a d)^-1 R_a`` at the sensors and the actuators
        alike.  The housing of axis ``k`` (bearing on the ``foundation``) moves by
        ``u_k``; the bearing's force ``ki i_k + kx (x_k - u_k)`` acts on rotor and
        housing alike and the sensor measures ``x_k - u_k``.  With
        ``z = m (w_h^2 - w^2) + j w c`` each housing's dynamic stiffness::

            [z - kx - kx R_a kx]_JJ u_J = -[(1 + kx R_a) ki i]_J
            y = R_s (ki i - kx u) - u

        Equal to the modal model's FRF with those bearings, sensors and housing
        coordinates (`Plant` with ``actuator_coefficients``, ``noncollocation``,
        ``foundation_mode``), to rounding.

        Parameters
        ----------
        frequency_hz : array_like
        current_stiffness, position_stiffness : array_like (4,)
            The bearings' ``ki`` [N/A] and ``kx`` [N/m] per radial axis.
        foundation : ambid.machine.Foundation, optional
        sensor_matrix : array (4, n), optional
            The sensors' shapes in this plant's modal coordinates (`receptances`).
        """
        if self.machine.foundation is not None:
            raise ModelError("coupled_response: this plant's housings are already on a foundation")
        sensor, actuator = self.receptances(frequency_hz, sensor_matrix)
        ki, kx = np.asarray(current_stiffness, dtype=float), np.asarray(position_stiffness, dtype=float)
        on = [k for k, axis in enumerate(RADIAL_AXES)
              if foundation is not None and AXIS_LOCATION[axis][0] in foundation.bearings]
        change = kx - self.position_stiffness
        if np.any(change != 0):
            # R d (1 - R_a d)^-1 R_a, at the sensors and (for the housings) at the actuators
            inverse = np.linalg.solve(np.eye(4) - actuator * change, actuator)
            sensor = sensor + (sensor * change) @ inverse
            if on:
                actuator = actuator + (actuator * change) @ inverse
        forced = sensor * ki
        if not on:
            return forced
        w = 2 * np.pi * np.asarray(frequency_hz, dtype=float)
        w_h = 2 * np.pi * foundation.frequency_hz
        housing = foundation.mass_kg * (w_h**2 - w**2) + 2j * foundation.damping_ratio * foundation.mass_kg * w_h * w
        kx_on = kx[on]
        dynamic = housing[:, None, None] * np.eye(len(on)) - np.diag(kx_on) - kx_on[:, None] * actuator[:, on][:, :, on] * kx_on
        load = (np.eye(4)[on] + kx_on[:, None] * actuator[:, on, :]) * ki  # [(1 + kx R_a) ki]_J
        housing_motion = -np.linalg.solve(dynamic, load)  # u_J per unit current
        moved = sensor[:, :, on] * kx_on + np.eye(4)[:, on]  # R_s kx + 1 on the columns of J
        return forced - moved @ housing_motion

    @cached_property
    def axial_stiffness(self):
        """(ki, kx) of the axial bearing."""
        if self.machine.axial_electromagnet is None:
            raise ModelError(f"machine {self.machine.name!r} has no axial bearing")
        return self.machine.axial_electromagnet.linearize()

    def axial_frequency_response(self, frequency_hz):
        """Axial plant P_z(jw) = ki / (-w^2 m - kx) with the effects on Z [m/A]."""
        frequency_hz = np.asarray(frequency_hz, dtype=float)
        ki, kx = self.axial_stiffness
        w = 2 * np.pi * frequency_hz
        response = (ki / (-(w**2) * self.rotor.mass_kg - kx)).astype(complex)
        for effect in self.input_effects + self.output_effects:
            response = response * effect.response(frequency_hz, [AXIAL_AXIS])[:, 0, 0]
        return response

    def axial_state_space(self):
        """(A, B, C) of the axial rigid body, state [z, z']."""
        ki, kx = self.axial_stiffness
        m = self.rotor.mass_kg
        return np.array([[0.0, 1.0], [kx / m, 0.0]]), np.array([[0.0], [ki / m]]), np.array([[1.0, 0.0]])

    def to_scipy(self):
        """The radial structural plant as a ``scipy.signal.StateSpace`` (4 inputs A, 4 outputs m).

        Input- and output-side effects are not included (a delay has no state space);
        multiply by their `Effect.response` in the frequency domain.
        """
        import scipy.signal  # here, not at the top: importing it costs ~1.5 s of CPU (scipy.stats) in every rule that never calls it
        a, b, c = self.radial.state_space()
        return scipy.signal.StateSpace(a, b, c, np.zeros((c.shape[0], b.shape[1])))

    def channel_zpk(self, output_axis, input_axis):
        """One SISO channel as ``scipy.signal.ZerosPolesGain`` (its minimal form, see `zeros`)."""
        import scipy.signal  # here, not at the top: importing it costs ~1.5 s of CPU (scipy.stats) in every rule that never calls it
        poles, residues = self.channel_residues(output_axis, input_axis)
        zeros = self.zeros(output_axis, input_axis)
        s = 1j * (1.0 + np.max(np.abs(poles)))  # a point away from poles and zeros fixes the gain
        value = np.sum(residues / (s - poles))
        gain = value * np.prod(s - poles) / np.prod(s - zeros)
        return scipy.signal.ZerosPolesGain(zeros, poles, gain.real)  # real: poles and zeros are conjugate-symmetric

    # ------------------------------------------------------- poles and zeros
    def poles(self):
        """Open-loop poles of the radial structural plant [rad/s], and their eigenvectors."""
        a, _, _ = self.radial.state_space()
        return scipy.linalg.eig(a)

    def zeros(self, output_axis, input_axis):
        """Transmission zeros [rad/s] of one SISO channel of the structural plant.

        The channel is brought to its minimal modal form ``sum_k r_k / (s - p_k)``:
        residues of repeated poles are merged and poles the channel cannot see
        (uncontrollable or unobservable: the other plane at standstill) are
        dropped.  The zeros are the finite generalized eigenvalues of the
        Rosenbrock pencil of that realization, valid collocated or not.
        Rational input/output effects (low-passes) add poles but no finite
        zeros; a delay or an eddy-current lag has none either.
        """
        poles, residues = self.channel_residues(output_axis, input_axis)
        n = poles.size
        if n == 0:
            return np.array([], dtype=complex)
        pencil = np.zeros((n + 1, n + 1), dtype=complex)
        pencil[:n, :n] = np.diag(poles)
        pencil[:n, n] = 1.0
        pencil[n, :n] = residues / np.max(np.abs(residues))
        identity = np.zeros((n + 1, n + 1))
        identity[:n, :n] = np.eye(n)
        values = scipy.linalg.eigvals(pencil, identity)
        # the pencil's infinite eigenvalues come out as huge finite numbers: drop them
        finite = np.isfinite(values) & (np.abs(values) < 1e4 * np.max(np.abs(poles)))
        values = _conjugate_symmetric(values[finite])
        return values[np.argsort(np.abs(values))]

    def channel_residues(self, output_axis, input_axis, relative_tolerance=1e-8):
        """Minimal modal form of one channel: poles p_k and residues r_k of P_ij(s).

        Poles equal to within 1e-6 (relative) are merged by summing their
        residues, which undoes eig's arbitrary mixing of the x and y planes'
        identical modes; modes whose merged weight ``|r_k| / |p_k|`` is below
        ``relative_tolerance`` times the largest unmerged one are dropped as
        uncontrollable or unobservable.  A channel with no coupling at all
        returns empty arrays.
        """
        a, b, c = self.radial.state_space()
        j, i = RADIAL_AXES.index(input_axis), RADIAL_AXES.index(output_axis)
        poles, vectors = scipy.linalg.eig(a)
        observability = c[i] @ vectors
        controllability = np.linalg.solve(vectors, b[:, j])
        residues = observability * controllability
        magnitude = np.maximum(np.abs(poles), 1.0)
        reference = np.max(np.abs(observability) * np.abs(controllability) / magnitude)
        cluster = np.full(poles.size, -1)
        for k in range(poles.size):
            if cluster[k] < 0:
                cluster[(cluster < 0) & (np.abs(poles - poles[k]) <= 1e-6 * magnitude[k])] = k
        heads = np.unique(cluster)
        merged = np.array([residues[cluster == h].sum() for h in heads])
        poles = poles[heads]
        keep = np.abs(merged) / np.maximum(np.abs(poles), 1.0) > relative_tolerance * reference
        return poles[keep], merged[keep]

    def mode_kind(self, eigenvector):
        """Classify a structural eigenvector: rigid / flexible / foundation, and its whirl."""
        n_modes = self.modes.shapes.shape[1]
        q = eigenvector[: self.radial.mass.shape[0]]
        ex, ey = q[:n_modes], q[n_modes : 2 * n_modes]
        omega = self.modes.angular_frequency_rad_s
        weight = np.maximum(omega, omega[RIGID_MODES] if n_modes > RIGID_MODES else 1.0)
        energy = (np.abs(ex) ** 2 + np.abs(ey) ** 2) * weight**2
        housing = np.sum(np.abs(q[2 * n_modes :]) ** 2) * (2 * np.pi * self.machine.foundation.frequency_hz) ** 2 if self.machine.foundation else 0.0
        total = energy.sum() + housing
        if housing > 0.5 * total:
            kind = "foundation"
        else:
            kind = "rigid" if energy[:RIGID_MODES].sum() > 0.5 * energy.sum() else "flexible"
        # orbit direction of the rotor translations, summed over the nodes
        u = self.modes.shapes[0::2]
        x, y = u @ ex, u @ ey
        spin = -np.sum(np.imag(np.conj(x) * y)) / max(np.sum(np.abs(x) ** 2 + np.abs(y) ** 2), 1e-300)
        whirl = "forward" if spin > 0.05 else "backward" if spin < -0.05 else "planar"
        return kind, whirl

    # ---------------------------------------------------------- closed loop
    def sampled_loop(self, axial=False):
        """The sampled-data loop plant of the radial axes (or of Z) with every effect of the model.

        `ambid.sampled_loop.sampled_system` of the structure, linearized at the machine's operating
        point, with the amplifier and eddy-current lags, cross-coupling, sensor low-passes and
        whole plus fractional sample delays: the system the virtual rig simulates.
        """
        machine = self.machine
        # the plant's own signal effects: `with_signal_effects` adds to them, not to machine.effects
        effects = tuple(self.input_effects) + tuple(self.output_effects)
        if axial:
            ki, kx = self.axial_stiffness
            return sampled_system(np.array([[self.rotor.mass_kg]]), np.zeros((1, 1)), np.zeros((1, 1)), np.ones((1, 1)),
                                  np.ones((1, 1)), [ki], [kx], effects, [AXIAL_AXIS], machine.sample_time_s)
        radial = self.radial
        return sampled_system(radial.mass, radial.damping + radial.speed_rad_s * radial.gyroscopic, self.free_stiffness,
                              self.actuator_shape, radial.output_matrix, self.current_stiffness, self.position_stiffness,
                              effects, RADIAL_AXES, machine.sample_time_s)

    def closed_loop_poles(self):
        """Poles of the sampled-data closed loop of the radial axes with every effect of the model.

        The structural plant with the model's input- and output-side effects (amplifier
        and eddy-current lags, cross-coupling, sensor low-passes, whole and fractional
        sample delays) is discretized exactly with a zero-order hold at the controller
        cycle and closed with the four radial controllers (`ambid.sampled_loop`).

        Returns
        -------
        ambid.sampled_loop.ClosedLoop
            ``s_poles`` = log(z) / T [rad/s], ``z_poles`` (stable when all |z| < 1),
            ``vectors`` (right eigenvectors, structural states q, q' first) and
            ``plant_participation``: the share of each mode carried by the
            structural states, from the participation factors |w_ik v_ik|.
        """
        return closed_loop(self.sampled_loop(), list(self.machine.radial_controllers))

    def axial_closed_loop_poles(self):
        """`closed_loop_poles` of the axial axis Z."""
        return closed_loop(self.sampled_loop(axial=True), [self.machine.axial_controller])


def _conjugate_symmetric(values, relative_tolerance=1e-7):
    """Roots of a real polynomial computed in complex arithmetic, made exactly conjugate-symmetric.

    Nearly real roots become real; each complex root is paired with the nearest
    conjugate of another and both replaced by their mean and its conjugate.
    """
    values = np.asarray(values, dtype=complex)
    out, used = [], np.zeros(values.size, dtype=bool)
    for k in np.argsort(-np.abs(values.imag)):
        if used[k]:
            continue
        used[k] = True
        scale = max(abs(values[k]), 1.0)
        if abs(values[k].imag) <= relative_tolerance * scale:
            out.append(complex(values[k].real, 0.0))
            continue
        candidates = np.flatnonzero(~used)
        if candidates.size == 0:
            out.append(values[k])
            continue
        j = candidates[np.argmin(np.abs(values[candidates] - np.conj(values[k])))]
        used[j] = True
        mean = 0.5 * (values[k] + np.conj(values[j]))
        out += [mean, np.conj(mean)]
    return np.array(out)
