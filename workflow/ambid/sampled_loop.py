"""The sampled-data closed loop of an AMB machine with every effect: one model for the rig and the stability check.

Signal chain of one controller cycle (thesis Fig. 4.1)::

    V2 = delay(X_out sensor(C_s q))            measured position (whole + fractional sample delay)
    U2 = C(setpoint - V2) + E_u                digital controllers (Tustin, `ambid.control`)
    coil current = amplifier(U2)               what the coil-current channels measure
    force current = X_in eddy(coil current)    what produces the force (linearized eq. 3.6: ki i + kx x)

The continuous linear part (amplifier and eddy-current chains, structure, sensor
low-passes) is discretized exactly with a zero-order hold at the controller
cycle (`SampledSystem`).  A sensor delay ``tau = m T + delta`` samples the
continuous output at ``t_k - tau`` exactly: a fractional-step output pushed
into a buffer and read ``m + 1`` cycles later.  The eddy-current half-order lag
is the rational approximation of `ambid.effects.half_order_lag_sections`.

`closed_loop_matrix` is the one-cycle map of the loop closed by the
controllers (plant, controller and delay-buffer states); its eigenvalues say
whether the loop is stable.  The virtual rig simulates this very
system, adding only what a rig has (the force law's nonlinearity, gravity,
offsets, noise, quantization); the model side (`ambid.plant`, `ambid.loop`)
judges stability on it.  Both build it here, so a model and a rig with the
same effects agree on stability.
"""

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.linalg

from .effects import COIL_CURRENT_EFFECTS, series_state_space, split_effects
from .errors import ModelError

__all__ = ["SIGNAL_EFFECTS", "SampledSystem", "sampled_system", "controller_matrices", "closed_loop_matrix",
           "ClosedLoop", "closed_loop", "coupling_matrix", "zoh_discretize"]

#: Input- and output-side effects the sampled loop represents (every one in the effect library).
SIGNAL_EFFECTS = ("amplifier_lowpass", "eddy_current", "cross_coupling", "sensor_lowpass", "delay")
RIG_CHAINS = ("coil", "force", "sensor", "output_matrix")  # where the rig-only effects sit (their ``rig_chain``)


def zoh_discretize(a, b, time_s):
    """Exact zero-order-hold discretization ``(Phi, Gamma)`` of ``x' = A x + B u`` over ``time_s``."""
    n, m = b.shape
    augmented = np.zeros((n + m, n + m))
    augmented[:n, :n], augmented[:n, n:] = a, b
    transition = scipy.linalg.expm(augmented * time_s)
    return transition[:n, :n], transition[:n, n:]


def _diagonal_chains(effects, kinds, axes, chain):
    """Block-diagonal MIMO system of the per-axis SISO chains of the ``kinds`` effects acting on each axis, with the
    rig-only effects whose ``rig_chain`` is ``chain``."""
    n_axes = len(axes)
    chained = [e for e in effects if e.name in kinds or getattr(e, "rig_chain", None) == chain]
    blocks = [series_state_space([e.siso_state_space() for e in chained if e.acts_on(axis)]) for axis in axes]
    a = scipy.linalg.block_diag(*[blk[0] for blk in blocks])
    b = scipy.linalg.block_diag(*[blk[1] for blk in blocks])
    c = scipy.linalg.block_diag(*[blk[2] for blk in blocks])
    d = np.diag([blk[3][0, 0] for blk in blocks])
    return a.reshape(a.shape[0], a.shape[0]), b.reshape(a.shape[0], n_axes), c.reshape(n_axes, a.shape[0]), d


def coupling_matrix(effects, side, axes):
    """The static cross-coupling matrix of the ``side`` (input: forces, output: sensors) on ``axes``; on the output
    side with the rig-only sensor gains (``rig_chain`` output_matrix)."""
    matrix = np.eye(len(axes))
    for effect in effects:
        if (effect.name == "cross_coupling" and effect.side == side) or (
                side == "output" and getattr(effect, "rig_chain", None) == "output_matrix"):
            matrix = effect.matrix(axes) @ matrix
    return matrix


@dataclass
class SampledSystem:
    """The continuous linear plant with its signal effects, and its exact sampled form.

    State ``[input chain, force chain, q, q', sensor chain]`` (`blocks` gives the
    slices); inputs ``[U2 (n_axes), force residual (n_axes), 1]`` (the residual and
    the constant carry what the rig adds: nonlinearity, gravity, a bias force).

    Attributes
    ----------
    a, b : arrays
        Continuous ``x' = a x + b u``.
    transition, input_matrix : arrays
        Their zero-order-hold discretization at ``sample_time_s``.
    sensor_output : array (n_axes, n)
        Sensor signal before the delay (output coupling and low-passes included).
    coil_state, coil_input : arrays
        Coil current ``= coil_state x + coil_input U2``.
    force_state, force_input : arrays
        Force-producing current ``= force_state x + force_input U2``.
    position_state : array (n_axes, n)
        Rotor position at each actuator.
    delay_s : array (n_axes,)
    delay_steps : int array (n_axes,)
        Cycles between writing a sensor sample and reading it (``m + 1``).
    buffer_length : int
    delayed_state, delayed_input : arrays
        The fractional-step sensor sample ``delayed_state x_k + delayed_input u_k``.
    """

    axes: tuple
    sample_time_s: float
    a: np.ndarray
    b: np.ndarray
    offsets: np.ndarray
    sensor_output: np.ndarray
    coil_state: np.ndarray
    coil_input: np.ndarray
    force_state: np.ndarray
    force_input: np.ndarray
    position_state: np.ndarray
    transition: np.ndarray
    input_matrix: np.ndarray
    delay_s: np.ndarray = None
    delay_steps: np.ndarray = None
    buffer_length: int = 1
    delayed_state: np.ndarray = None
    delayed_input: np.ndarray = None

    @property
    def n_states(self):
        return self.a.shape[0]

    def blocks(self, k):
        """Slice of block k of the state: 0 input chain, 1 force chain, 2 q, 3 q', 4 sensor chain."""
        return slice(self.offsets[k], self.offsets[k + 1])

    def frequency_response(self, frequency_hz):
        """FRF from U2 samples to sensor samples, (n_f, n_axes, n_axes) [m/A], delays included.

        ``C_d(z) (zI - Phi)^-1 Gamma_u`` at ``z = exp(j w T)``: what the loop measures at small
        amplitude without noise (the plant as identification sees it, hold included).
        """
        n_axes = len(self.axes)
        z = np.exp(2j * np.pi * np.asarray(frequency_hz, dtype=float) * self.sample_time_s)
        gamma = self.input_matrix[:, :n_axes]
        out = np.empty((z.size, n_axes, n_axes), dtype=complex)
        identity = np.eye(self.n_states)
        for k, zk in enumerate(z):
            resolvent = np.linalg.solve(zk * identity - self.transition, gamma)
            # the fractional-step output of step j (which also sees u_j) is read d cycles later
            sample = self.delayed_state @ resolvent + self.delayed_input[:, :n_axes]
            out[k] = zk ** (-self.delay_steps[:, None]) * sample
        return out


def sampled_system(mass, damping, free_stiffness, actuator_shape, sensor_shape, current_stiffness, position_stiffness,
                   effects, axes, sample_time_s, constant_force=None, static_force=None):
    """The linear loop plant of ``axes`` with its input- and output-side effects, discretized exactly.

    Parameters
    ----------
    mass, damping, free_stiffness : arrays (n_q, n_q)
        Structure without the bearings' negative stiffness (damping includes ``Omega G``).
    actuator_shape : array (n_q, n_axes)
        Force (and relative-displacement) shape of each axis.
    sensor_shape : array (n_axes, n_q)
    current_stiffness, position_stiffness : arrays (n_axes,)
        ki [N/A] and kx [N/m] of each axis at its operating point (thesis eq. 3.5-3.6).
    effects : sequence of ambid.effects.Effect
        The machine's effects; structure effects must already be in the matrices.
    axes : sequence of str
    sample_time_s : float
    constant_force : array (n_axes,), optional
        Bearing force at zero deviation (the rig's linearization constant); default 0.
    static_force : array (n_q,), optional
        Generalized static load (gravity); default 0.

    Returns
    -------
    SampledSystem

    Raises
    ------
    ModelError
        For a signal effect the sampled loop does not represent.
    """
    _, input_effects, output_effects = split_effects(effects)
    unknown = [e.name for e in list(input_effects) + list(output_effects)
               if e.name not in SIGNAL_EFFECTS and getattr(e, "rig_chain", None) not in RIG_CHAINS]
    if unknown:
        raise ModelError(f"effect {unknown[0]!r} has no sampled-data form (known: {', '.join(SIGNAL_EFFECTS)})")
    axes = tuple(axes)
    n_axes = len(axes)
    ki, kx = np.asarray(current_stiffness, dtype=float), np.asarray(position_stiffness, dtype=float)
    ai, bi, ci, di = _diagonal_chains(input_effects, set(COIL_CURRENT_EFFECTS), axes, "coil")
    ae, be, ce, de = _diagonal_chains(input_effects, {"eddy_current"}, axes, "force")
    ao, bo, co, do = _diagonal_chains(output_effects, {"sensor_lowpass"}, axes, "sensor")
    coupling = coupling_matrix(input_effects, "input", axes)
    output_coupling = coupling_matrix(output_effects, "output", axes)
    constant = np.zeros(n_axes) if constant_force is None else constant_force
    n_q = mass.shape[0]
    static = np.zeros(n_q) if static_force is None else static_force
    n_i, n_e, n_o = ai.shape[0], ae.shape[0], ao.shape[0]
    inverse_mass = np.linalg.inv(mass)
    shape = actuator_shape
    stiffness = free_stiffness - shape @ np.diag(kx) @ shape.T
    # force-producing current = X_in (ce x_e + de (ci x_i + di u))
    offsets = np.cumsum([0, n_i, n_e, n_q, n_q, n_o])
    n = offsets[-1]
    blk = lambda k: slice(offsets[k], offsets[k + 1])  # noqa: E731
    a = np.zeros((n, n))
    b = np.zeros((n, 2 * n_axes + 1))
    u_cmd, u_res, u_one = slice(0, n_axes), slice(n_axes, 2 * n_axes), 2 * n_axes
    a[blk(0), blk(0)] = ai
    b[blk(0), u_cmd] = bi
    a[blk(1), blk(0)] = be @ ci
    a[blk(1), blk(1)] = ae
    b[blk(1), u_cmd] = be @ di
    force_gain = inverse_mass @ shape @ np.diag(ki) @ coupling
    a[blk(2), blk(3)] = np.eye(n_q)
    a[blk(3), blk(2)] = -inverse_mass @ stiffness
    a[blk(3), blk(3)] = -inverse_mass @ damping
    a[blk(3), blk(0)] = force_gain @ de @ ci
    a[blk(3), blk(1)] = force_gain @ ce
    b[blk(3), u_cmd] = force_gain @ de @ di
    b[blk(3), u_res] = inverse_mass @ shape
    b[blk(3), u_one] = inverse_mass @ (shape @ constant + static)
    a[blk(4), blk(2)] = bo @ sensor_shape
    a[blk(4), blk(4)] = ao
    sensor = np.zeros((n_axes, n))
    sensor[:, blk(2)] = output_coupling @ do @ sensor_shape
    sensor[:, blk(4)] = output_coupling @ co
    coil_state = np.zeros((n_axes, n))
    coil_state[:, blk(0)] = ci
    force_state = np.zeros((n_axes, n))
    force_state[:, blk(0)] = coupling @ de @ ci
    force_state[:, blk(1)] = coupling @ ce
    position_state = np.zeros((n_axes, n))
    position_state[:, blk(2)] = shape.T
    transition, input_matrix = zoh_discretize(a, b, sample_time_s)
    system = SampledSystem(axes, sample_time_s, a, b, offsets, sensor, coil_state, di, force_state, coupling @ de @ di,
                           position_state, transition, input_matrix)
    delay_s = np.array([sum(e.delay_s for e in output_effects if e.name == "delay" and e.acts_on(axis)) for axis in axes])
    _delays(system, delay_s)
    return system


def _delays(system, delay_s):
    """Sensor delays: each axis samples ``C x`` at ``t_k - tau`` exactly.

    With ``tau = m T + delta``, the sample is ``C (Phi(T - delta) x_j + Gamma(T -
    delta) u_j)`` of step ``j = k - m - 1``, i.e. a fractional-step output pushed
    into a buffer and read ``m + 1`` cycles later (no delay: ``m + 1 = 1``).
    """
    t = system.sample_time_s
    whole = np.floor(delay_s / t + 1e-9).astype(int)
    fraction = delay_s - whole * t
    n_axes = len(system.axes)
    system.delay_steps = whole + 1
    system.buffer_length = int(system.delay_steps.max()) + 1
    system.delayed_state = np.zeros((n_axes, system.n_states))
    system.delayed_input = np.zeros((n_axes, system.input_matrix.shape[1]))
    for k in range(n_axes):
        phi, gamma = zoh_discretize(system.a, system.b, t - fraction[k])
        system.delayed_state[k] = system.sensor_output[k] @ phi
        system.delayed_input[k] = system.sensor_output[k] @ gamma
    system.delay_s = delay_s


def controller_matrices(controllers):
    """(A, B, C, D) of the decentralized digital controllers, one per axis: input ``-y`` [m], output U2 [A]."""
    blocks = [c.discrete_state_space() for c in controllers]
    return (scipy.linalg.block_diag(*[b[0] for b in blocks]), scipy.linalg.block_diag(*[b[1] for b in blocks]),
            scipy.linalg.block_diag(*[b[2] for b in blocks]), np.diag([b[3][0, 0] for b in blocks]), blocks)


def closed_loop_matrix(system, controllers):
    """One controller cycle of the linear closed loop, as a matrix on its deviation state.

    State ``[x (plant), x_c (controllers), b_0 ... b_{L-1} (sensor samples to be read 0 ... L-1 cycles
    from now, each n_axes)]``.  A cycle reads ``b_0``, commands ``U2 = C_c x_c - D_c b_0``, writes each
    axis' fractional-step sample into ``b_{d-1}`` and steps the plant and controllers: exactly
    what the virtual rig's ``RigModel.step`` does without noise, quantization and nonlinearity.

    Returns
    -------
    array (n + n_c + L n_axes, n + n_c + L n_axes)
    """
    ctrl_a, ctrl_b, ctrl_c, ctrl_d, _ = controller_matrices(controllers)
    n_axes = len(system.axes)
    n, n_c, length = system.n_states, ctrl_a.shape[0], system.buffer_length
    size = n + n_c + length * n_axes
    x, xc = slice(0, n), slice(n, n + n_c)
    slot = lambda j: slice(n + n_c + j * n_axes, n + n_c + (j + 1) * n_axes)  # noqa: E731
    gamma = system.input_matrix[:, :n_axes]
    # u = C_c x_c - D_c b_0 as a row block over the state
    command = np.zeros((n_axes, size))
    command[:, xc] = ctrl_c
    command[:, slot(0)] = -ctrl_d
    matrix = np.zeros((size, size))
    matrix[x, x] = system.transition
    matrix[x] += gamma @ command
    matrix[xc, xc] = ctrl_a
    matrix[xc, slot(0)] = -ctrl_b
    for j in range(length - 1):
        matrix[slot(j), slot(j + 1)] = np.eye(n_axes)
    sample = system.delayed_input[:, :n_axes] @ command
    sample[:, x] += system.delayed_state
    for k in range(n_axes):
        row = n + n_c + (system.delay_steps[k] - 1) * n_axes + k
        matrix[row] = sample[k]
    return matrix


class ClosedLoop(NamedTuple):
    """Eigen-analysis of a sampled-data closed loop.

    Attributes
    ----------
    s_poles : array
        ``log(z) / T`` [rad/s] (``-inf`` for the delay buffer's poles at ``z = 0``).
    z_poles : array
        Eigenvalues of `closed_loop_matrix` (stable when all ``|z| < 1``).
    vectors : array
        Right eigenvectors, rows of the structure's ``q`` and ``q'`` first, then the other states.
    plant_participation : array
        Share of each mode carried by the structure's states, from the participation
        factors ``|w_ik v_ik|`` (invariant to how the other states are scaled).
    spectral_radius : float
    """

    s_poles: np.ndarray
    z_poles: np.ndarray
    vectors: np.ndarray
    plant_participation: np.ndarray
    spectral_radius: float


def closed_loop(system, controllers):
    """Eigenvalues, eigenvectors and structural participation of the closed loop (see `closed_loop_matrix`)."""
    matrix = closed_loop_matrix(system, controllers)
    z, left, right = scipy.linalg.eig(matrix, left=True)
    structure = np.arange(system.offsets[2], system.offsets[4])
    order = np.concatenate([structure, np.setdiff1d(np.arange(matrix.shape[0]), structure)])
    participation = np.abs(left.conj() * right)
    share = participation[structure].sum(axis=0) / np.maximum(participation.sum(axis=0), 1e-300)
    z = z.astype(complex)
    with np.errstate(divide="ignore"):
        s = np.where(np.abs(z) > 0, np.log(np.where(np.abs(z) > 0, z, 1.0)) / system.sample_time_s, -np.inf + 0j)
    return ClosedLoop(s, z, right[order], share, float(np.max(np.abs(z))))
