"""Resonances and anti-resonances of the structural plant, and their sensitivities (thesis ch. 5.2).

The model update evaluates the plant's poles and zeros thousands of times for
different element moduli and modal damping.  This module does it without
rebuilding a `~ambid.plant.Plant`.  The planar stiffness is linear in the
moduli of the design elements (`~ambid.rotor.Rotor.element_group_matrices`)::

    K(e) = K_fixed + sum_p e_p K_p          (the loss stiffness alike)

so one evaluation is a symmetric eigenproblem for the free-free modes
(thesis eq. 2.10-2.12, the `Plant`'s modal truncation), the bearings'
negative stiffness in modal coordinates, one small eigenproblem for the poles
of each plane and one for the zeros of each channel, from its *zero
dynamics*: with ``c^T T = 0`` and ``L^T b = 0``, the zeros of
``c^T (s^2 M + s D + K)^-1 b`` are the eigenvalues of
``s^2 L^T M T + s L^T D T + L^T K T`` (a channel of relative degree two, as
every force-to-position channel with ``c^T M^-1 b != 0``).

The derivatives ``d lambda / d e_p`` follow from the left and right
eigenvectors of the same problems, ``dlambda = -h^H (dK v + dD s v) / (w^H v)``,
with the modal basis held fixed (first-order perturbation; exact when all
modes are retained).  At standstill the x and y planes do not couple and are
solved separately, once when they are identical.
"""

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.linalg

from .errors import ModelError
from .machine import AXIS_LOCATION, BEARINGS, RADIAL_AXES
from .plant import RIGID_MODES, Plant

__all__ = ["DesignVariable", "design_variables", "StructuralFeatures", "ModalFeatureModel", "LIGHT_DAMPING", "root_features",
           "root_feature_derivatives"]

LIGHT_DAMPING = 0.2  # resonances and anti-resonances: complex roots with damping ratio below this


@dataclass(frozen=True)
class DesignVariable:
    """One parameter the model update adjusts.

    Attributes
    ----------
    name : str
        For tables, e.g. ``E de_amb[2] (element 7)`` or ``zeta mode 1``.
    kind : {"stiffness", "damping"}
        ``stiffness``: a factor on the Young's modulus (and shear modulus) of
        ``elements`` relative to the machine as configured; ``damping``: the
        added modal damping ratio (effect ``modal_damping``) of the flexible
        modes ``modes`` (1 = lowest; empty = every flexible mode).
    elements : tuple of int
    modes : tuple of int
    tag : str
        The element tag (stiffness) the variable belongs to.
    start, lower, upper : float
        Value in the machine as configured, and bounds.
    """

    name: str
    kind: str
    elements: tuple = ()
    modes: tuple = ()
    tag: str = ""
    start: float = 1.0
    lower: float = 1e-3
    upper: float = 2.0


def design_variables(machine, stiffness_tags, per_element=True, damping="common", damping_modes=1,
                     stiffness_bounds=(1e-3, 2.0), damping_bounds=(0.0, 0.2)):
    """The design vector ``e`` of thesis eq. 5.28, extended with damping.

    Parameters
    ----------
    machine : ambid.machine.Machine
    stiffness_tags : sequence of str
        Element tags whose modulus is uncertain (thesis: the AMB lamination
        stacks and the motor section).
    per_element : bool
        One variable per element of each tag (thesis: 14 on HS-Eden) or one per tag.
    damping : {"none", "common", "per_mode"}
        ``common``: one added damping ratio for every flexible mode;
        ``per_mode``: one for each of the lowest ``damping_modes`` flexible
        modes (the modes above share the last one).
    stiffness_bounds : (float, float)
        Bounds on the modulus factor (thesis appendix: 0 .. 2 x nominal; 0 is
        excluded, E > 0).
    damping_bounds : (float, float)

    Returns
    -------
    list of DesignVariable
    """
    rotor = machine.rotor
    lower, upper = stiffness_bounds
    if not 0 < lower < 1 < upper:
        raise ModelError(f"stiffness bounds must satisfy 0 < lower < 1 < upper, got {stiffness_bounds}")
    variables, taken = [], set()
    for tag in stiffness_tags:
        group = rotor.elements_tagged(tag)
        if not group:
            raise ModelError(f"no element carries the tag {tag!r}")
        if taken & set(group):
            raise ModelError(f"tag {tag!r} shares elements with another design tag")
        taken |= set(group)
        if per_element:
            variables += [DesignVariable(f"E {tag}[{k}] (element {e + 1})", "stiffness", (e,), tag=tag, lower=lower, upper=upper)
                          for k, e in enumerate(group)]
        else:
            variables.append(DesignVariable(f"E {tag}", "stiffness", tuple(group), tag=tag, lower=lower, upper=upper))
    existing = np.atleast_1d(np.asarray(machine.added_modal_damping or (0.0,), dtype=float))
    lo, hi = damping_bounds
    if damping == "common":
        variables.append(DesignVariable("zeta (all flexible modes)", "damping", (), start=float(existing[0]), lower=lo, upper=hi))
    elif damping == "per_mode":
        for k in range(1, damping_modes + 1):
            start = float(existing[min(k, existing.size) - 1])
            modes = (k,) if k < damping_modes else ()  # the last one also damps the modes above
            name = f"zeta mode {k}" if modes else f"zeta mode {k}+"
            variables.append(DesignVariable(name, "damping", modes or (-k,), start=start, lower=lo, upper=hi))
    elif damping != "none":
        raise ModelError(f"damping must be 'none', 'common' or 'per_mode', got {damping!r}")
    if not variables:
        raise ModelError("no design variables: give stiffness tags or damping")
    return variables


@dataclass
class StructuralFeatures:
    """Poles and zeros of the structural plant for one design vector.

    Attributes
    ----------
    poles : dict plane -> array
        Complex poles with Im > 0 of each plane's block [rad/s].
    zeros : dict (output, input) -> array
        Complex zeros with Im > 0 of each requested channel [rad/s].
    modal_constants : dict (output, input) -> array
        ``2 j Im(p) r`` (real part) of each pole of the channel's plane: the
        sign of the mode's shape product at sensor and actuator.
    pole_derivatives, zero_derivatives : dicts alike, arrays (n_roots, n_variables)
        ``d lambda / d e_p`` (None unless requested).
    """

    poles: dict
    zeros: dict
    modal_constants: dict
    pole_derivatives: dict | None = None
    zero_derivatives: dict | None = None


class ModalFeatureModel:
    """Fast evaluation of a machine's resonances and anti-resonances as functions of design variables.

    Parameters
    ----------
    machine : ambid.machine.Machine
        The model as configured, its effects included (structure effects are
        applied here; input and output effects have no poles or finite zeros
        in the structural plant and are ignored).
    variables : list of DesignVariable
    channels : sequence of (output, input)
        Radial channels whose zeros are wanted.

    Notes
    -----
    The result for ``values = [v.start for v in variables]`` equals the
    `Plant` of the same machine (tested), so an updated machine rebuilt from
    the returned effects reproduces the features the update matched.
    """

    def __init__(self, machine, variables, channels):
        plant = Plant(machine)
        structural = plant.machine
        if structural.speed_rad_s != 0:
            raise ModelError("the model update works at standstill; remove the gyroscopic effect to update")
        self.machine, self.variables = structural, list(variables)
        self.channels = [tuple(c) for c in channels]
        rotor = structural.rotor
        planar = rotor.planar_matrices()
        # mass-normalizing coordinates y = L^T u (M = L L^T): the modes are the symmetric eigenvectors of L^-1 K L^-T
        self.to_planar = np.linalg.inv(np.linalg.cholesky(planar["mass"])).T  # u = L^-T y

        def transformed(matrix):
            return self.to_planar.T @ matrix @ self.to_planar

        stiffness_vars = [v for v in self.variables if v.kind == "stiffness"]
        groups = [rotor.element_group_matrices(v.elements) for v in stiffness_vars]
        n = planar["mass"].shape[0]
        self.group_stiffness = np.array([transformed(g[0]) for g in groups]).reshape(-1, n, n)
        self.group_loss = np.array([transformed(g[1]) for g in groups]).reshape(-1, n, n)
        self.fixed_stiffness = transformed(planar["stiffness"]) - self.group_stiffness.sum(axis=0)
        self.fixed_loss = transformed(planar["loss_stiffness"]) - self.group_loss.sum(axis=0)
        self.stiffness_index = np.array([k for k, v in enumerate(self.variables) if v.kind == "stiffness"], dtype=int)
        self.damping_index = np.array([k for k, v in enumerate(self.variables) if v.kind == "damping"], dtype=int)
        # the retained modes and, when modes are dropped, the static correction of the dropped ones under the
        # actuator forces (as `ambid.plant.Plant` builds them): one Ritz vector per radial bearing
        self.n_exact = structural.retained_modes
        self.correct = self.n_exact < planar["mass"].shape[0]
        self.n_modes = self.n_exact + (len(structural.radial_bearings) if self.correct else 0)
        added = np.atleast_1d(np.asarray(structural.added_modal_damping or (0.0,), dtype=float))
        n_flexible = self.n_modes - RIGID_MODES
        # added damping of each flexible mode as configured (a scalar applies to all of them)
        self.base_added = np.full(n_flexible, added[0]) if added.size == 1 else np.pad(added, (0, n_flexible - added.size))
        self.damping_masks = []
        for k in self.damping_index:
            mask = np.zeros(n_flexible, dtype=bool)
            modes = self.variables[k].modes
            if not modes:
                mask[:] = True
            elif modes[0] < 0:
                mask[-modes[0] - 1 :] = True
            else:
                mask[np.asarray(modes) - 1] = True
            self.damping_masks.append(mask)
        # actuator and sensor rows (independent of the moduli: phi does not change)
        self.axis_rows = {}
        for axis in RADIAL_AXES:
            bearing = structural.bearing(AXIS_LOCATION[axis][0])
            self.axis_rows[axis] = (
                rotor.planar_displacement_row(bearing.actuator_position_m) @ self.to_planar,
                rotor.planar_displacement_row(bearing.sensor_position_m) @ self.to_planar,
            )
        self.axis_stiffness = dict(zip(RADIAL_AXES, zip(plant.current_stiffness, plant.position_stiffness)))
        self.loads = np.stack([rotor.planar_displacement_row(b.actuator_position_m) @ self.to_planar
                               for b in structural.radial_bearings], axis=1)  # unit forces in mass-normalized coordinates
        self.foundation = structural.foundation
        # identical planes are solved once
        x_axes, y_axes = ("DX", "NX"), ("DY", "NY")
        same = all(np.allclose(self.axis_stiffness[a], self.axis_stiffness[b], rtol=1e-12) for a, b in zip(x_axes, y_axes))
        self.planes = {"x": x_axes, "y": y_axes}
        self.solve_planes = ["x"] if same else ["x", "y"]
        self.zero_pairs = {plane: [] for plane in self.solve_planes}
        for output, input_axis in self.channels:
            plane = _plane_of(output)
            if plane != _plane_of(input_axis):
                raise ModelError(f"channel {output}/{input_axis}: the planes do not couple at standstill; it has no zeros")
            solve = plane if plane in self.solve_planes else "x"
            pair = (self.planes[plane].index(output), self.planes[plane].index(input_axis))
            if pair not in self.zero_pairs[solve]:
                self.zero_pairs[solve].append(pair)
        self.evaluations = 0

    @property
    def start(self):
        return np.array([v.start for v in self.variables])

    # ----------------------------------------------------------- the modes
    def _modes(self, values):
        """Free-free modes for ``values`` (all of them: the shape derivatives need the complete basis)."""
        factors = values[self.stiffness_index]
        stiffness = self.fixed_stiffness + np.tensordot(factors, self.group_stiffness, axes=1)
        loss = self.fixed_loss + np.tensordot(factors, self.group_loss, axes=1)
        all_omega2, all_shapes = np.linalg.eigh(stiffness)  # LAPACK's full solver beats a subset at this size
        n = self.n_exact
        shapes = all_shapes[:, :n]
        omega2 = all_omega2[:n]
        if self.correct:
            ritz_omega2, ritz = self._static_correction(all_omega2, all_shapes, stiffness)
            shapes = np.hstack([shapes, ritz])
            omega2 = np.concatenate([omega2, ritz_omega2])
        omega = np.sqrt(np.clip(omega2, 0.0, None))
        flexible = np.arange(self.n_modes) >= RIGID_MODES
        loss_energy = np.einsum("ik,ij,jk->k", shapes, loss, shapes)
        added = self.base_added.copy()
        for k, mask in zip(self.damping_index, self.damping_masks):
            added[mask] = values[k]
        zeta_added = np.concatenate([np.zeros(RIGID_MODES), added])
        safe = np.where(flexible, omega, 1.0)
        damping = np.where(flexible, loss_energy / safe + 2 * zeta_added * omega, 0.0)
        return _Modes(omega, shapes, damping, all_omega2, all_shapes, loss, loss_energy, zeta_added)

    def _static_correction(self, all_omega2, all_shapes, stiffness, reference=None):
        """Rayleigh-Ritz in the span of the dropped modes' static deflections under the loads (`Rotor.planar_modes`).

        ``reference`` (shapes of an earlier call) fixes each vector's sign, for finite differences.
        """
        n = self.n_exact
        dropped = all_shapes[:, n:]
        basis = scipy.linalg.orth(dropped @ ((dropped.T @ self.loads) / all_omega2[n:, None]))
        ritz_omega2, vectors = np.linalg.eigh(basis.T @ stiffness @ basis)
        ritz = basis @ vectors
        if reference is not None:
            ritz = ritz * np.where(np.sum(ritz * reference, axis=0) < 0, -1.0, 1.0)
        return ritz_omega2, ritz

    def _plane_system(self, plane, modes):
        """M, D, K, B (n_q, 2), C (2, n_q) of one plane: modal rotor coordinates, then the two housings."""
        n = self.n_modes
        housing = self.foundation is not None
        n_q = n + (2 if housing else 0)
        mass = np.eye(n_q)
        stiffness = np.zeros((n_q, n_q))
        damp = np.zeros((n_q, n_q))
        stiffness[:n, :n] = np.diag(modes.omega**2)
        damp[:n, :n] = np.diag(modes.damping)
        if housing:
            f = self.foundation
            w = 2 * np.pi * f.frequency_hz
            h = slice(n, n_q)
            mass[h, h] = f.mass_kg * np.eye(2)
            stiffness[h, h] = f.mass_kg * w**2 * np.eye(2)
            damp[h, h] = 2 * f.damping_ratio * f.mass_kg * w * np.eye(2)
        actuator = np.zeros((n_q, 2))
        sensor = np.zeros((2, n_q))
        current_stiffness, position_stiffness = np.zeros(2), np.zeros(2)
        for k, axis in enumerate(self.planes[plane]):
            act_row, sens_row = self.axis_rows[axis]
            actuator[:n, k] = act_row @ modes.shapes
            sensor[k, :n] = sens_row @ modes.shapes
            bearing = AXIS_LOCATION[axis][0]
            if housing and bearing in self.foundation.bearings:
                actuator[n + BEARINGS.index(bearing), k] = -1.0
                sensor[k, n + BEARINGS.index(bearing)] = -1.0
            current_stiffness[k], position_stiffness[k] = self.axis_stiffness[axis]
            stiffness -= position_stiffness[k] * np.outer(actuator[:, k], actuator[:, k])
        return _PlaneSystem(mass, damp, stiffness, actuator * current_stiffness, sensor, actuator, current_stiffness,
                            position_stiffness)

    # ---------------------------------------------------------- evaluation
    def evaluate(self, values, derivatives=False, with_zeros=True):
        """Poles, zeros and modal constants for the design vector ``values``.

        Parameters
        ----------
        values : array (n_variables,)
        derivatives : bool
            Also return ``d lambda / d e`` of every pole and zero.
        with_zeros : bool
            False: poles and modal constants only (half the cost; the zeros' tables are empty).

        Returns
        -------
        StructuralFeatures
        """
        values = np.asarray(values, dtype=float)
        if not np.all(np.isfinite(values)) or np.any(values[self.stiffness_index] <= 0):
            raise ModelError(f"design values must be finite and the modulus factors > 0, got {values}")
        self.evaluations += 1
        modes = self._modes(values)
        modal_derivatives = self._modal_derivatives(modes) if derivatives else None
        poles, zeros, constants = {}, {}, {}
        pole_derivatives, zero_derivatives = {}, {}
        for plane in self.solve_planes:
            system = self._plane_system(plane, modes)
            change = self._plane_derivatives(plane, system, modal_derivatives) if derivatives else None
            axes = self.planes[plane]
            roots, plane_constants, d_roots = _poles(system, change)
            poles[plane], pole_derivatives[plane] = roots, d_roots
            for k, j in np.ndindex(2, 2):
                constants[(axes[k], axes[j])] = plane_constants[k, j]
            pairs = self.zero_pairs[plane] if with_zeros else []
            for (k, j), roots, d_roots in zip(pairs, *_zeros(system, pairs, change, axes)):
                zeros[(axes[k], axes[j])], zero_derivatives[(axes[k], axes[j])] = roots, d_roots
        if self.solve_planes == ["x"]:  # identical planes: the y plane's results are the x plane's
            poles["y"], pole_derivatives["y"] = poles["x"], pole_derivatives["x"]
            for table in (zeros, constants, zero_derivatives):
                for (output, input_axis) in list(table):
                    table[(_twin(output), _twin(input_axis))] = table[(output, input_axis)]
        if not derivatives:
            pole_derivatives = zero_derivatives = None
        return StructuralFeatures(poles, zeros, constants, pole_derivatives, zero_derivatives)

    def _modal_derivatives(self, modes):
        """Exact derivatives of the retained modes with respect to every variable.

        ``d omega_k^2 = psi_k^T K_p psi_k`` and, by expansion over all modes of
        the (mass-normalized, fixed-mass) problem,
        ``d psi_k = sum_{j != k} psi_j (psi_j^T K_p psi_k) / (omega_k^2 - omega_j^2)``;
        rigid-body modes do not change (every element stiffness annihilates them).

        Returns ``d_omega2`` (n_vars, n_modes), ``d_shapes`` (n_vars, 2 N, n_modes)
        and ``d_damping`` (n_vars, n_modes), the change of the modal damping
        ``eta_k omega_k + 2 zeta_k omega_k``.  The static-correction vectors are
        differentiated by central differences (a full eigen-solve per variable and
        side; they depend on every dropped mode).
        """
        n_vars, n = len(self.variables), self.n_modes
        exact = self.n_exact
        omega, shapes = modes.omega, modes.shapes
        d_omega2 = np.zeros((n_vars, n))
        d_shapes = np.zeros((n_vars, shapes.shape[0], n))
        d_damping = np.zeros((n_vars, n))
        flexible = np.arange(n) >= RIGID_MODES
        safe = np.where(flexible, omega, 1.0)
        if self.stiffness_index.size:
            coupling = modes.all_shapes.T @ self.group_stiffness @ shapes[:, :exact]  # (p, all modes j, retained k)
            gap = modes.all_omega2[:exact][None, :] - modes.all_omega2[:, None]  # omega_k^2 - omega_j^2
            usable = flexible[None, :exact] & (np.arange(gap.shape[0])[:, None] != np.arange(exact)[None, :])
            weights = np.where(usable, coupling / np.where(usable, gap, 1.0), 0.0)
            shape_change = np.zeros((self.stiffness_index.size, shapes.shape[0], n))
            shape_change[:, :, :exact] = modes.all_shapes @ weights
            d_omega2[self.stiffness_index, :exact] = np.diagonal(coupling[:, :exact, :], axis1=1, axis2=2)
            if self.correct:
                stiffness = modes.all_shapes @ np.diag(modes.all_omega2) @ modes.all_shapes.T
                for p, group in enumerate(self.group_stiffness):
                    step = 1e-6
                    sides = []
                    for sign in (1.0, -1.0):
                        changed = stiffness + sign * step * group
                        values, vectors = np.linalg.eigh(changed)
                        sides.append(self._static_correction(values, vectors, changed, reference=shapes[:, exact:]))
                    d_omega2[self.stiffness_index[p], exact:] = (sides[0][0] - sides[1][0]) / (2 * step)
                    shape_change[p, :, exact:] = (sides[0][1] - sides[1][1]) / (2 * step)
            d_shapes[self.stiffness_index] = shape_change
            d_loss = (np.sum(shapes[None] * (self.group_loss @ shapes), axis=1)
                      + 2 * np.sum(shape_change * (modes.loss @ shapes)[None], axis=1))
            d_omega = d_omega2[self.stiffness_index] / (2 * safe)
            d_damping[self.stiffness_index] = np.where(
                flexible, d_loss / safe - modes.loss_energy / safe**2 * d_omega + 2 * modes.zeta_added * d_omega, 0.0)
        for k, mask in zip(self.damping_index, self.damping_masks):
            d_damping[k, RIGID_MODES:] = np.where(mask, 2 * omega[RIGID_MODES:], 0.0)
        return d_omega2, d_shapes, d_damping

    def _plane_derivatives(self, plane, system, modal_derivatives):
        """Derivatives of one plane's K, D (n_vars, n_q, n_q), B (n_vars, n_q, 2) and C (n_vars, 2, n_q)."""
        d_omega2, d_shapes, d_damping = modal_derivatives
        n_vars, n = d_omega2.shape
        n_q = system.mass.shape[0]
        d_stiffness = np.zeros((n_vars, n_q, n_q))
        d_damp = np.zeros((n_vars, n_q, n_q))
        modal = np.arange(n)
        d_stiffness[:, modal, modal] = d_omega2
        d_damp[:, modal, modal] = d_damping
        d_inputs = np.zeros((n_vars, n_q, 2))
        d_outputs = np.zeros((n_vars, 2, n_q))
        for k, axis in enumerate(self.planes[plane]):
            act_row, sens_row = self.axis_rows[axis]
            d_actuator = np.zeros((n_vars, n_q))
            d_actuator[:, :n] = act_row @ d_shapes
            d_outputs[:, k, :n] = sens_row @ d_shapes
            a = system.actuator[:, k]
            d_stiffness -= system.position_stiffness[k] * (d_actuator[:, :, None] * a[None, None, :]
                                                           + a[None, :, None] * d_actuator[:, None, :])
            d_inputs[:, :, k] = system.current_stiffness[k] * d_actuator
        return d_stiffness, d_damp, d_inputs, d_outputs


class _Modes(NamedTuple):
    omega: np.ndarray
    shapes: np.ndarray
    damping: np.ndarray
    all_omega2: np.ndarray
    all_shapes: np.ndarray
    loss: np.ndarray
    loss_energy: np.ndarray
    zeta_added: np.ndarray


class _PlaneSystem(NamedTuple):
    mass: np.ndarray
    damping: np.ndarray
    stiffness: np.ndarray
    inputs: np.ndarray
    outputs: np.ndarray
    actuator: np.ndarray
    current_stiffness: np.ndarray
    position_stiffness: np.ndarray


def _plane_of(axis):
    return AXIS_LOCATION[axis][1]


def _twin(axis):
    return axis[0] + ("Y" if axis[1] == "X" else "X")


def _companion(inverse_mass, damping, stiffness):
    """State matrix of ``M q'' + D q' + K q = 0`` with state ``[q, q']``."""
    n = stiffness.shape[0]
    a = np.zeros((2 * n, 2 * n))
    a[:n, n:] = np.eye(n)
    a[n:, :n] = -inverse_mass @ stiffness
    a[n:, n:] = -inverse_mass @ damping
    return a


def _root_derivatives(roots, left, right, system, change, extra=None):
    """``d lambda / d e`` of roots of ``Q(s) = s^2 M + s D + K`` (or a channel's system matrix).

    ``left`` y and ``right`` v (n_q, roots) are the null vectors of Q(lambda);
    ``d lambda = -(y^H (dK + lambda dD) v + extra) / (y^H (2 lambda M + D) v)``,
    where ``extra`` (roots, n_vars) carries a channel's input/output terms.
    """
    d_stiffness, d_damping = change[0], change[1]
    conjugate = left.conj()[None]
    numerator = (np.sum(conjugate * (d_stiffness @ right), axis=1)
                 + roots[None, :] * np.sum(conjugate * (d_damping @ right), axis=1)).T
    if extra is not None:
        numerator = numerator + extra
    slope = np.sum(left.conj() * ((2 * roots[None, :]) * (system.mass @ right) + system.damping @ right), axis=0)
    return -numerator / slope[:, None]


def _poles(system, change):
    """Complex poles (Im > 0) of one plane, the modal constants of its 2 x 2 channels, and ``d p / d e``.

    The modal constant of pole ``p`` in channel (k, j) is ``Re(2 j Im(p) r)``
    with ``r`` the residue: for a lightly damped mode, the product of the mode
    shape at sensor k and actuator j, whose sign tells modes apart.
    """
    inverse_mass = np.diag(1.0 / np.diag(system.mass))
    roots, right = np.linalg.eig(_companion(inverse_mass, system.damping, system.stiffness))
    left = np.linalg.inv(right).conj().T  # w^H v = 1
    keep = roots.imag > 0
    roots, left, right = roots[keep], left[:, keep], right[:, keep]
    n_q = system.mass.shape[0]
    observed = system.outputs @ right[:n_q]  # (2, roots)
    controlled = left[n_q:].conj().T @ (inverse_mass @ system.inputs)  # (roots, 2)
    residues = observed[:, None, :] * controlled.T[None, :, :]  # (out, in, roots)
    constants = np.real(2j * roots.imag * residues)
    if change is None:
        return roots, constants, None
    # the null vectors of Q(p): y = M^-H w_2 (left), v = the position part (right)
    return roots, constants, _root_derivatives(roots, inverse_mass @ left[n_q:], right[:n_q], system, change)


def _zeros(system, pairs, change, axes):
    """Complex zeros (Im > 0) of channels ``c_k^T (s^2 M + s D + K)^-1 b_j`` for (k, j) in ``pairs``, from their zero dynamics.

    Returns two lists (roots, derivatives or None), one entry per pair; the
    channels are solved as one stack.  The derivatives are those of the
    Rosenbrock system matrix ``S(s) = [[Q(s), -b], [c^T, 0]]``, whose null
    vectors follow from the zero dynamics.
    """
    if not pairs:
        return [], []
    mass, damping, stiffness = system.mass, system.damping, system.stiffness
    b = system.inputs[:, [j for _, j in pairs]].T  # (m, n_q)
    c = system.outputs[[k for k, _ in pairs]]
    inverse_mass = 1.0 / np.diag(mass)  # M is diagonal: unit modal masses and housing masses
    coupling = np.abs(np.sum(c * inverse_mass * b, axis=1)) / (np.linalg.norm(c, axis=1) * np.linalg.norm(b, axis=1)
                                                               * inverse_mass.max())
    if np.any(coupling < 1e-10):
        k, j = pairs[int(np.argmin(coupling))]
        raise ModelError(f"channel {axes[k]}/{axes[j]}: no direct force-to-position coupling (c^T M^-1 b = 0); "
                         "its zeros are not those of a relative-degree-two channel")
    right_basis, left_basis = _complement(c), _complement(b)  # c^T T = 0, L^T b = 0
    left_t = left_basis.transpose(0, 2, 1)
    inverse = np.linalg.inv(left_t @ (mass @ right_basis))
    n = right_basis.shape[2]
    a = np.zeros((len(pairs), 2 * n, 2 * n))
    a[:, :n, n:] = np.eye(n)
    a[:, n:, :n] = -inverse @ (left_t @ (stiffness @ right_basis))
    a[:, n:, n:] = -inverse @ (left_t @ (damping @ right_basis))
    if change is None:
        roots = np.linalg.eigvals(a)
        return [r[r.imag > 0] for r in roots], [None] * len(pairs)
    roots, right = np.linalg.eig(a)
    left = np.linalg.inv(right).conj().transpose(0, 2, 1)
    d_inputs, d_outputs = change[2], change[3]
    out_roots, out_derivatives = [], []
    for m, (k, j) in enumerate(pairs):
        keep = roots[m].imag > 0
        z = roots[m][keep]
        v = right_basis[m] @ right[m][:n, keep]  # null vectors of S(z): [v; u] and [y; eta]
        y = left_basis[m] @ (inverse[m].conj().T @ left[m][n:, keep])
        q_v = (z[None, :] ** 2) * (mass @ v) + z[None, :] * (damping @ v) + stiffness @ v
        u = (b[m] @ q_v) / (b[m] @ b[m])
        q_c = (z[None, :] ** 2) * (mass @ c[m][:, None]) + z[None, :] * (damping @ c[m][:, None]) + (stiffness @ c[m])[:, None]
        eta = -np.sum(y.conj() * q_c, axis=0) / (c[m] @ c[m])
        extra = (-(y.conj().T @ d_inputs[:, :, j].T) * u[:, None]
                 + eta[:, None] * (d_outputs[:, k, :] @ v).T)
        out_roots.append(z)
        out_derivatives.append(_root_derivatives(z, y, v, system, change, extra))
    return out_roots, out_derivatives


def _complement(vectors):
    """Orthonormal bases (m, n, n - 1) of the vectors orthogonal to each row of ``vectors`` (m, n).

    Columns 2.. of the Householder reflector that maps the vector onto the first axis.
    """
    u = np.array(vectors, dtype=float)
    u[:, 0] += np.copysign(np.linalg.norm(u, axis=1), u[:, 0])
    reflector = np.eye(u.shape[1]) - (2.0 / np.sum(u * u, axis=1))[:, None, None] * (u[:, :, None] * u[:, None, :])
    return reflector[:, :, 1:]


def root_features(roots):
    """Natural frequency [Hz] and damping ratio of complex roots [rad/s] (none of them zero)."""
    magnitude = np.abs(roots)
    return magnitude / (2 * np.pi), -roots.real / magnitude


def root_feature_derivatives(roots, derivatives):
    """``d f / d e`` [Hz] and ``d zeta / d e`` from ``d lambda / d e``, arrays (n_roots, n_variables)."""
    magnitude = np.abs(roots)[:, None]
    d_magnitude = np.real(np.conj(roots)[:, None] * derivatives) / magnitude
    d_frequency = d_magnitude / (2 * np.pi)
    d_zeta = -derivatives.real / magnitude + roots.real[:, None] * d_magnitude / magnitude**2
    return d_frequency, d_zeta
