"""Output-error fit of one FRF channel of an AMB plant (the default estimator, beyond thesis ch. 5.1).

The model of a radial channel (excitation current -> sensor position) is::

    G(s) = K  prod_k (s^2 + c1_k s + c0_k) (1 + d s^2)
              ----------------------------------------------  e^{-s tau}  H(s)
              prod_r (s^2 - a_r^2) prod_m (s^2 + 2 zeta_m w_m s + w_m^2) (1 + s / w_lp)

* ``s^2 - a_r^2``: the levitated rotor's rigid-body modes, real pole pairs
  ``+-a`` of the negative-stiffness plant (fixed structure: never merged into a
  complex pair, never mirrored).
* ``w_m, zeta_m``: the flexible resonances in the band.
* ``c1, c0``: anti-resonances (``c0 > 0``) and real zero pairs (``c0 < 0``).
* ``1 + d s^2``: the residual flexibility of the modes above the band.
* ``tau`` and ``w_lp``: a delay and a first-order low-pass the model lacks
  (computation delay, amplifier or sensor bandwidth) put into the model instead
  of being absorbed by extra poles.
* ``H(s)``: what is known and not fitted (the zero-order hold, the nominal
  model's input/output effects).

Starting values come from `ambid.fit.sanathanan_koerner` at the order the
stabilization diagram selects; pole-zero pairs that cancel to within the noise
and unstable complex poles are dropped; then the output error
``(G(jw) - G_meas) / sigma`` is minimized by Levenberg-Marquardt with the
analytic Jacobian ``dG/dtheta = G dlogG/dtheta``.
"""

from dataclasses import dataclass, field

import numpy as np
import scipy.optimize

from .errors import AmbidError, ConfigError
from .findings import Finding
from .fit import classify_poles, sanathanan_koerner, stabilization
from .loop import zero_order_hold
from .machine import RADIAL_AXES
from .modal_features import LIGHT_DAMPING
from .plant import RIGID_MODES, damping_ratio

__all__ = ["ChannelModel", "ChannelFit", "FitError", "fit_channel", "fit_plant_channel", "select_modes", "known_response",
           "rigid_pole_hz", "select_channels", "feature_rows", "model_rows", "model_from_row", "fit_orders", "max_fit_modes",
           "real_zero_hz", "fit_verdict", "dipole_hz", "negative_delay", "MAX_CHI2", "OVERDAMPED", "DIPOLE", "NEGATIVE_DELAY_SIGMAS"]


class FitError(AmbidError):
    """A channel cannot be fitted (too little signal, nothing to fit, no convergence)."""


@dataclass(frozen=True)
class ChannelModel:
    """A fitted channel in physical units (rad/s, s, m/A).

    Attributes
    ----------
    gain : float
        ``K`` [m/A (rad/s)^(2 n_den - 2 n_num)].
    rigid_rad_s : array (n_r,)
        ``a_r > 0``: unstable real poles ``+a_r`` and stable ``-a_r``.
    mode_rad_s, mode_damping : arrays (m,)
        Natural frequencies and damping ratios of the flexible poles.
    zero_factors : array (k, 2)
        ``(c1, c0)`` of each numerator factor ``s^2 + c1 s + c0`` [rad/s, (rad/s)^2].
    residual_s2 : float
        ``d`` of ``1 + d s^2`` [s^2].
    lowpass_rad_s : float
        Corner of the fitted low-pass (``inf``: none).
    delay_s : float
    """

    gain: float
    rigid_rad_s: np.ndarray
    mode_rad_s: np.ndarray
    mode_damping: np.ndarray
    zero_factors: np.ndarray
    residual_s2: float = 0.0
    lowpass_rad_s: float = np.inf
    delay_s: float = 0.0

    @property
    def poles(self):
        """Poles of the rational part [rad/s] (both signs of the rigid pairs, both conjugates)."""
        w, z = self.mode_rad_s, self.mode_damping
        flexible = w * (-z + 1j * np.sqrt(np.maximum(1 - z**2, 0.0)))
        parts = [self.rigid_rad_s, -self.rigid_rad_s, flexible, np.conj(flexible)]
        if np.isfinite(self.lowpass_rad_s):
            parts.append([-self.lowpass_rad_s])
        return np.concatenate([np.asarray(p, dtype=complex) for p in parts])

    @property
    def zeros(self):
        """Finite zeros [rad/s], the residual factor's included."""
        parts = [np.roots([1.0, c1, c0]) for c1, c0 in self.zero_factors]
        if self.residual_s2 != 0:
            parts.append(np.roots([self.residual_s2, 0.0, 1.0]))
        return np.concatenate(parts) if parts else np.array([], dtype=complex)

    def frequency_response(self, frequency_hz, known=None):
        """``G(j 2 pi f)`` including the delay, times ``known`` when given."""
        s = 2j * np.pi * np.asarray(frequency_hz, dtype=float)
        g = np.exp(-s * self.delay_s) * self._rational(s)
        return g if known is None else g * known

    def _rational(self, s, skip_mode=None):
        """The rational part at complex ``s``, without the factor of flexible mode ``skip_mode``."""
        g = self.gain * (1 + self.residual_s2 * s**2)
        for c1, c0 in self.zero_factors:
            g = g * (s**2 + c1 * s + c0)
        for a in self.rigid_rad_s:
            g = g / (s**2 - a**2)
        for m, (w, z) in enumerate(zip(self.mode_rad_s, self.mode_damping)):
            if m != skip_mode:
                g = g / (s**2 + 2 * z * w * s + w**2)
        if np.isfinite(self.lowpass_rad_s):
            g = g / (1 + s / self.lowpass_rad_s)
        return g

    def modal_constants(self):
        """``Re(2 j Im(p) r)`` of each flexible pole ``p`` (Im p > 0) with residue ``r`` of the rational part.

        For a lightly damped mode this is the product of the mode shape at
        the sensor and at the actuator (times the current gain): its sign
        tells modes apart in a cross channel, the model update uses it to
        match modes (`ambid.modal_features`).
        """
        out = np.empty(self.mode_rad_s.size)
        for m, (w, z) in enumerate(zip(self.mode_rad_s, self.mode_damping)):
            pole = w * (-z + 1j * np.sqrt(max(1 - z**2, 0.0)))
            residue = self._rational(pole, skip_mode=m) / (pole - np.conj(pole))
            out[m] = np.real(2j * pole.imag * residue)
        return out

    def to_scipy(self):
        """The rational part as `scipy.signal.ZerosPolesGain` (the delay is not rational: see ``delay_s``)."""
        import scipy.signal  # here, not at the top: importing it costs ~1.5 s of CPU (scipy.stats) in every rule that never calls it
        zeros, poles = self.zeros, self.poles
        # ZerosPolesGain's gain multiplies monic factors; absorb the non-monic ones
        gain = self.gain * (self.residual_s2 if self.residual_s2 != 0 else 1.0)
        if np.isfinite(self.lowpass_rad_s):
            gain = gain * self.lowpass_rad_s
        return scipy.signal.ZerosPolesGain(zeros, poles, gain)


@dataclass(frozen=True)
class ChannelFit:
    """Result of `fit_channel`.

    Attributes
    ----------
    model : ChannelModel
    features : list of dict
        `ambid.fit.classify_poles` rows of the final model, each with the
        standard uncertainty ``frequency_std_hz`` and ``damping_std`` from the
        Jacobian at the optimum (linearized, scaled by the fit's residual).
    stabilization : list of dict
        The stabilization diagram the order was chosen from.
    order : int
        Denominator order of the starting fit.
    iterations : int
        Function evaluations of the refinement.
    selected_hz : array
        The flexible modes the stabilization diagram supported [Hz].
    cost : float
        Weighted residual norm squared per degree of freedom (about 1 when the
        model explains the data to within the stated noise).
    dropped : list of str
        What was dropped from the starting fit and why.
    delay_std_s : float
        Standard uncertainty of the fitted delay [s] (NaN: not known).
    converged : bool
        Whether the refinement met its tolerances.  False: it stopped at ``max_iterations``, and
        its features depend on where the search stopped, beyond their stated uncertainties.
    """

    model: ChannelModel
    features: list
    stabilization: list
    order: int
    cost: float
    iterations: int
    dropped: list = field(default_factory=list)
    selected_hz: np.ndarray = field(default_factory=lambda: np.array([]))
    delay_std_s: float = np.nan
    converged: bool = True


#: A fitted delay is negative (non-causal) when it lies this many standard uncertainties below zero: hs_eden_like's
#: DX/DX from 2 Hz to 3 kHz at 3 % noise fits its two modes at chi2/dof 2.9 with a delay of -1.1 +- 0.4 us, zero
#: within the noise; calling any negative delay a flaw traded that fit for a one-mode fit at 154.
NEGATIVE_DELAY_SIGMAS = 3.0


def negative_delay(delay_s, delay_std_s=np.nan):
    """Whether a fitted delay is significantly negative (`NEGATIVE_DELAY_SIGMAS`; any negative value where its
    uncertainty is not known)."""
    return bool(delay_s < (-NEGATIVE_DELAY_SIGMAS * delay_std_s if np.isfinite(delay_std_s) else 0.0))


# ----------------------------------------------------------------- parameters
class _Layout:
    """Scaled parameter vector: x = s / omega (omega: the band's top, rad/s)."""

    def __init__(self, n_rigid, n_modes, n_zero, lowpass, delay):
        self.n_rigid, self.n_modes, self.n_zero = n_rigid, n_modes, n_zero
        self.lowpass, self.delay = lowpass, delay
        self.size = 1 + n_rigid + 2 * n_modes + 2 * n_zero + 1 + int(lowpass) + int(delay)

    def split(self, theta):
        k = 1
        parts = {"log_gain": theta[0]}
        for name, n in (("log_rigid", self.n_rigid), ("log_mode", self.n_modes), ("zeta", self.n_modes),
                        ("c1", self.n_zero), ("c0", self.n_zero)):
            parts[name] = theta[k : k + n]
            k += n
        parts["d"] = theta[k]
        k += 1
        parts["p"] = theta[k] if self.lowpass else 0.0
        k += int(self.lowpass)
        parts["t"] = theta[k] if self.delay else 0.0
        return parts

    def join(self, log_gain, log_rigid, log_mode, zeta, c1, c0, d, p, t):
        theta = [[log_gain], log_rigid, log_mode, zeta, c1, c0, [d]]
        if self.lowpass:
            theta.append([p])
        if self.delay:
            theta.append([t])
        return np.concatenate([np.asarray(v, dtype=float).ravel() for v in theta])


def _log_response(theta, layout, x, sign):
    """``log G`` (up to the known factor) and its derivatives ``d log G / d theta``, (n,) and (n, p)."""
    q = layout.split(theta)
    n = x.size
    x2 = x**2
    jac = np.empty((n, layout.size), dtype=complex)
    log_g = np.full(n, q["log_gain"], dtype=complex) + np.log(sign + 0j)
    jac[:, 0] = 1.0
    k = 1
    for log_a in q["log_rigid"]:
        a2 = np.exp(2 * log_a)
        factor = x2 - a2
        log_g -= np.log(factor)
        jac[:, k] = 2 * a2 / factor
        k += 1
    modes = []
    for log_w, zeta in zip(q["log_mode"], q["zeta"]):
        w = np.exp(log_w)
        factor = x2 + 2 * zeta * w * x + w**2
        log_g -= np.log(factor)
        modes.append((w, zeta, factor))
    for w, zeta, factor in modes:
        jac[:, k] = -(2 * zeta * w * x + 2 * w**2) / factor
        k += 1
    for w, zeta, factor in modes:
        jac[:, k] = -2 * w * x / factor
        k += 1
    zero_factors = [x2 + c1 * x + c0 for c1, c0 in zip(q["c1"], q["c0"])]
    for factor in zero_factors:
        log_g += np.log(factor)
        jac[:, k] = x / factor
        k += 1
    for factor in zero_factors:
        jac[:, k] = 1.0 / factor
        k += 1
    residual = 1 + q["d"] * x2
    log_g += np.log(residual)
    jac[:, k] = x2 / residual
    k += 1
    if layout.lowpass:
        lowpass = 1 + q["p"] * x
        log_g -= np.log(lowpass)
        jac[:, k] = -x / lowpass
        k += 1
    if layout.delay:
        log_g -= q["t"] * x
        jac[:, k] = -x
    return log_g, jac


def _to_model(theta, layout, omega, sign):
    q = layout.split(theta)
    n_num = 2 * layout.n_zero
    n_den = 2 * layout.n_rigid + 2 * layout.n_modes
    gain = sign * np.exp(q["log_gain"]) * omega ** (n_den - n_num)
    return ChannelModel(
        gain=float(gain),
        rigid_rad_s=omega * np.exp(q["log_rigid"]),
        mode_rad_s=omega * np.exp(q["log_mode"]),
        mode_damping=np.array(q["zeta"], dtype=float),
        zero_factors=np.column_stack([omega * np.asarray(q["c1"]), omega**2 * np.asarray(q["c0"])]).reshape(-1, 2),
        residual_s2=float(q["d"] / omega**2),
        lowpass_rad_s=float(omega / q["p"]) if layout.lowpass and q["p"] > 0 else np.inf,
        delay_s=float(q["t"] / omega) if layout.delay else 0.0,
    )


# ------------------------------------------------------- what the model knows
def known_response(plant, output_axis, input_axis, frequency_hz):
    """What a radial channel's measurement contains that the fit need not estimate.

    The digital loop's zero-order hold and the nominal model's own input- and
    output-side effects of those axes (their diagonal: a low-pass, a delay the
    model already has).  What the model lacks is left to the fitted delay and
    low-pass.

    Returns
    -------
    complex array (n,)
    """
    frequency_hz = np.asarray(frequency_hz, dtype=float)
    known = zero_order_hold(frequency_hz, plant.machine.sample_time_s).astype(complex)
    axes = list(RADIAL_AXES)
    for effects, axis in ((plant.input_effects, input_axis), (plant.output_effects, output_axis)):
        for effect in effects:
            known = known * effect.response(frequency_hz, axes)[:, axes.index(axis), axes.index(axis)]
    return known


def fit_plant_channel(plant, frequency_hz, response, std, output_axis, input_axis, settings, known=None):
    """The fit stage's estimator on one radial channel: `fit_channel` with what the model ``plant`` knows.

    The hold and the model's own effects as the known factor (`known_response`), the model's
    rigid poles and real zeros as starting values, and the options of the config's ``fit:``
    section (``modes``, ``orders``, ``lowpass``, ``delay``).  The fit stage applies it to the
    measured FRF, `ambid.update.estimator_bias` to a model's own.

    Returns
    -------
    ChannelFit
    """
    frequency_hz = np.asarray(frequency_hz, dtype=float)
    if known is None:
        known = known_response(plant, output_axis, input_axis, frequency_hz)
    return fit_channel(frequency_hz, response, std=std, known=known, modes=settings["modes"], orders=settings["orders"],
                       lowpass=settings["lowpass"], delay=settings["delay"], rigid_hint_hz=rigid_pole_hz(plant),
                       zero_hint_hz=real_zero_hz(plant, output_axis, input_axis, frequency_hz.max()))


def real_zero_hz(plant, output_axis, input_axis, band_hz):
    """Magnitudes of the nominal channel's real zero pairs below ``band_hz`` [Hz], ascending (starting values)."""
    zeros = plant.zeros(output_axis, input_axis)
    real = np.abs(zeros[(np.abs(zeros.imag) <= 1e-6 * np.abs(zeros)) & (zeros.real > 0)].real) / (2 * np.pi)
    return np.unique(np.round(real[real < band_hz], 9))


def rigid_pole_hz(plant):
    """Magnitudes of the nominal plant's unstable real poles [Hz], ascending: starting values for merged pairs."""
    poles, _ = plant.poles()
    real = poles[(np.abs(poles.imag) <= 1e-6 * np.abs(poles)) & (poles.real > 0)].real / (2 * np.pi)
    return np.unique(np.round(real, 9))


# ------------------------------------------------------------ starting values
def select_modes(diagram, min_orders=2, frequency_tolerance=0.01):
    """Flexible modes the stabilization diagram supports.

    A mode is a cluster of *physical* poles (complex, stable, in band) within
    ``frequency_tolerance`` of each other that appears, stable, at
    ``min_orders`` or more orders.

    Returns
    -------
    array
        The clusters' median frequencies [Hz], ascending.
    """
    rows = sorted((r for r in diagram if r["physical"]), key=lambda r: r["frequency_hz"])
    clusters, current = [], []
    for row in rows:
        if current and row["frequency_hz"] > current[0]["frequency_hz"] * (1 + frequency_tolerance):
            clusters.append(current)
            current = []
        current.append(row)
    if current:
        clusters.append(current)
    modes = []
    for cluster in clusters:
        orders = {r["order"] for r in cluster if r["stable"]}
        if len(orders) >= min_orders:
            modes.append(float(np.median([r["frequency_hz"] for r in cluster])))
    return np.array(modes)


def _pair_real(values):
    """Pair real roots into quadratic factors ``(c1, c0)``; an odd one out is dropped."""
    values = np.sort(np.asarray(values, dtype=float))
    # pair opposite signs first (the +-a pairs of a levitated rotor), by magnitude
    factors = []
    positive, negative = list(values[values >= 0]), list(-values[values < 0][::-1])
    while positive and negative:
        p, n = positive.pop(0), negative.pop(0)
        factors.append((p - n, -p * n))  # (x - p)(x + n)
    rest = sorted(positive) + sorted(-np.asarray(negative))
    for k in range(0, len(rest) - 1, 2):
        factors.append((-(rest[k] + rest[k + 1]), rest[k] * rest[k + 1]))
    return factors


def _cancels(pole, zero, x, tolerance):
    """Whether the conjugate pairs of ``pole`` and ``zero`` (scaled) change G by less than ``tolerance`` in band."""
    ratio = (x - zero) * (x - np.conj(zero)) / ((x - pole) * (x - np.conj(pole)))
    return bool(np.max(np.abs(ratio - 1)) < tolerance)


def _starting_point(fit, x, omega, n_rigid, mode_hz, relative_noise, rigid_hint_hz, zero_band=1.5):
    """Structure and scaled starting values from a linear fit; what was dropped and why.

    Returns rigid magnitudes, whether they are the hint (the linear fit showed
    none), flexible poles, numerator factors ``(c1, c0)``, the residual
    flexibility ``d`` and notes, all in the scaled variable.
    """
    dropped = []
    top = np.max(np.abs(x))
    hz = omega / (2 * np.pi)
    poles, zeros = fit.poles / omega, fit.zeros / omega
    is_real = lambda v: np.abs(v.imag) <= 1e-3 * np.abs(v)  # noqa: E731
    # rigid: opposite-sign real poles paired by magnitude (the +-a of the negative stiffness);
    # a pair the channel does not see (cancelled by a real zero pair) is simply not there
    real_poles = poles[is_real(poles)].real
    positive = list(np.sort(real_poles[(real_poles > 0) & (real_poles <= top)]))
    negative = list(np.sort(-real_poles[(real_poles < 0) & (real_poles >= -top)]))
    rigid = []
    for p in positive[::-1]:
        ratios = [abs(n / p - 1) for n in negative]
        if ratios and min(ratios) < 0.25 and len(rigid) < n_rigid:
            n = negative.pop(int(np.argmin(ratios)))
            rigid.append(float(np.sqrt(p * n)))
    rigid.sort()
    from_hint = bool(n_rigid and not rigid)
    if from_hint:
        hint = np.asarray(rigid_hint_hz if rigid_hint_hz is not None else [0.03 * hz], dtype=float)
        rigid = [float(hint[0] / hz)]
        dropped.append(f"the linear fit shows no real pole pair: started the rigid pair at {hint[0]:.1f} Hz")
    # flexible: the stable complex pole nearest each selected mode
    candidates = [p for p in poles[(poles.imag > 0) & ~is_real(poles)]]
    flexible = []
    for f_hz in mode_hz:
        stable = [p for p in candidates if p.real < 0]
        if not stable:
            break
        k = int(np.argmin([abs(abs(p) * hz / f_hz - 1) for p in stable]))
        flexible.append(stable[k])
        candidates.remove(stable[k])
    for p in candidates:
        if abs(p) <= top:
            kind = "unstable complex pole" if p.real > 0 else "pole not stable in the diagram"
            dropped.append(f"{kind} at {abs(p) * hz:.2f} Hz")
    # zeros: a complex zero that cancels a dropped pole goes with it
    complex_zeros = [z for z in zeros[(zeros.imag > 0) & ~is_real(zeros)]]
    for p in candidates:
        partner = min(complex_zeros, key=lambda z: abs(z - p), default=None)
        if partner is not None and abs(partner - p) < 0.02 * abs(p):
            complex_zeros.remove(partner)
    kept = []
    for p in flexible:
        partner = min(complex_zeros, key=lambda z: abs(z - p), default=None)
        if partner is not None and _cancels(p, partner, x, 3 * relative_noise):
            complex_zeros.remove(partner)
            dropped.append(f"pole-zero pair cancelling within the noise at {abs(p) * hz:.2f} Hz")
        else:
            kept.append(p)
    # numerator factors in and near the band; far zeros only bend the response: residual flexibility
    factors, residual = [], 0.0
    for z in complex_zeros:
        if abs(z) <= zero_band * top:
            factors.append((-2 * z.real, abs(z) ** 2))
        else:
            residual += 1.0 / abs(z) ** 2
    real_zeros = zeros[is_real(zeros)].real
    for c1, c0 in _pair_real(real_zeros):
        if abs(c0) <= (zero_band * top) ** 2:
            factors.append((c1, c0))
        else:
            residual += 1.0 / c0
    return rigid, from_hint, kept, factors, residual, dropped


def _scan_delay(shape, data, weights, x, top_delay):
    """Scaled delay ``t`` in [0, top_delay] maximizing the weighted correlation of ``shape e^{-x t}`` with the data."""
    grid = np.linspace(0.0, top_delay, 241)
    rotated = shape[None, :] * np.exp(-np.outer(grid, x))
    correlation = np.abs(rotated.conj() @ (weights * data)) ** 2
    best = int(np.argmax(correlation))
    return float(grid[best])


#: Function evaluations an output-error refinement may take.  At 200 (until stop 56) 2 to 4 of the 8 channel fits of
#: each default run stopped there, their features depending on where the search stopped (demo20's thesis NY/NY
#: anti-resonance 3.1 of its standard deviations short of where it converges, at 534; hs_eden_like's multisine DX/DX
#: kept a spurious fourth mode its converged fit, at 679, drops).  At 1000 one per run does not converge; from 200 to
#: 1000 evaluations those three moved by at most 0.15 of their standard deviations.
MAX_EVALUATIONS = 1000


# ------------------------------------------------------------------- the fit
def fit_channel(frequency_hz, response, std=None, known=None, n_rigid=RIGID_MODES, modes=None, orders=None,
                lowpass=False, delay=True, rigid_hint_hz=None, zero_hint_hz=None, max_iterations=MAX_EVALUATIONS):
    """Fit one channel of an AMB plant FRF: stabilization, linear start, output-error refinement.

    Parameters
    ----------
    frequency_hz, response : arrays (n,)
        Measured FRF [Hz, m/A].
    std : array (n,), optional
        Standard deviation of each point.  Missing or non-positive (a thesis
        ``.m`` log has none): 3 % of ``|response|``, a relative weighting.
    known : complex array (n,), optional
        Known factor of the measured response (zero-order hold, nominal
        effects); the fitted model is ``G(s) known``.
    n_rigid : int
        Rigid-body real pole pairs (2 per plane for a radial channel; 0 for a
        plant with positive bearing stiffness).
    modes : int, optional
        Number of flexible modes in the band (default: chosen from the
        stabilization diagram).
    orders : iterable of int, optional
        Denominator orders of the stabilization diagram (default
        ``2 n_rigid + 2, ..., 2 n_rigid + 12``).
    lowpass, delay : bool
        Fit a first-order low-pass / a delay.
    rigid_hint_hz : array, optional
        Starting rigid-pole magnitudes [Hz] should the linear fit merge them
        (for example from the nominal model).
    zero_hint_hz : array, optional
        Magnitudes [Hz] of the channel's real zero pairs in the nominal model
        (`real_zero_hz`): starting values of the zeros that go with a hinted rigid pair.
    max_iterations : int
        Function evaluations each output-error refinement may take (`MAX_EVALUATIONS`); a fit
        stopped there says so (``ChannelFit.converged``).

    Returns
    -------
    ChannelFit

    Raises
    ------
    FitError
        On non-finite input, too few points, or no flexible mode where ``modes`` demands one.
    """
    f = np.asarray(frequency_hz, dtype=float)
    g = np.asarray(response, dtype=complex)
    if f.ndim != 1 or f.shape != g.shape or f.size < 8:
        raise FitError(f"need matching 1-D frequency and response arrays with at least 8 points (got {f.shape}, {g.shape})")
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(g))):
        raise FitError("frequency or response contains NaN or inf")
    if np.all(g == 0):
        raise FitError("the response is identically zero: nothing to fit")
    h = np.ones_like(g) if known is None else np.asarray(known, dtype=complex)
    sigma = None if std is None else np.asarray(std, dtype=float)
    if sigma is None or not np.all(np.isfinite(sigma)) or np.any(sigma <= 0):
        sigma = 0.03 * np.maximum(np.abs(g), 1e-6 * np.max(np.abs(g)))
    relative_noise = float(np.median(sigma / np.maximum(np.abs(g), 1e-300)))
    omega = 2 * np.pi * np.max(f)
    x = 1j * f / np.max(f)
    reduced = g / h
    reduced_sigma = sigma / np.abs(h)
    orders = fit_orders(orders, n_rigid)
    diagram = stabilization(f, reduced, orders, std=reduced_sigma)
    dropped = []
    # the stated noise must explain what even the highest-order linear fit leaves; where it does
    # not (systematic error: nonlinearity, drift), every sigma is scaled up, so that thresholds and
    # reported uncertainties follow the real scatter
    highest = max(orders)
    scatter = diagram[-1]["residual"] ** 2 / max(f.size - (2 * highest + 1) / 2, 1) if diagram else 1.0
    inflation = float(np.sqrt(scatter)) if scatter > 2.0 else 1.0
    if inflation > 1.0:
        sigma, reduced_sigma = sigma * inflation, reduced_sigma * inflation
        relative_noise *= inflation
        dropped.append(f"the stated noise explains 1/{inflation:.1f} of the scatter: sigma scaled by {inflation:.1f}")
    mode_hz = select_modes(diagram) if modes is None else None
    if modes is not None:
        # a fixed number of modes: the most persistent physical clusters
        ranked = select_modes(diagram, min_orders=1)
        mode_hz = ranked if ranked.size <= modes else _most_persistent(diagram, ranked, modes)
        if mode_hz.size < modes:
            raise FitError(f"asked for {modes} flexible modes; the stabilization diagram shows {mode_hz.size}")
    noise_known = std is not None and np.all(np.asarray(std) > 0)
    band = (f.min(), f.max())
    problem = (f, x, reduced, reduced_sigma, orders, omega, n_rigid, relative_noise, rigid_hint_hz, zero_hint_hz,
               noise_known, lowpass, delay, max_iterations)
    best, order, rigid_from_hint, notes = _fit_structure(problem, mode_hz)
    if modes is None and noise_known and not _consistent(best):
        # a mode the diagram shows at too few orders to be selected may still be in the data (hs_eden_like's DY/NY
        # multisine channel: 2755 Hz, seen at one order, chi2/dof 5.6 without it and 1.1 with it): each such pole,
        # most persistent first, is offered as one more mode; kept where the fit keeps it there, lightly damped (not
        # moved off to bend the response elsewhere: demo20's thesis DY/DY took 490 Hz to 1276 Hz at zeta 0.31) and
        # the information criterion prefers it
        seen = select_modes(diagram, min_orders=1)
        extra = np.array([m for m in seen if not np.any(np.abs(mode_hz / m - 1) < 0.01)])
        for more in (_most_persistent(diagram, extra, min(2, extra.size)) if extra.size else []):
            alternative = np.sort(np.append(mode_hz, more))
            trial = _fit_structure(problem, alternative)
            fitted = _to_model(trial[0][0].x, trial[0][1], omega, trial[0][2])
            kept = np.any((np.abs(fitted.mode_rad_s / (2 * np.pi * more) - 1) < 0.02) & (fitted.mode_damping < OVERDAMPED))
            if (kept and len(_flaws(trial[0], omega, band)) <= len(_flaws(best, omega, band))
                    and _criterion(trial[0], noise_known) < _criterion(best, noise_known)):
                notes = trial[3] + [f"structure: the diagram's {mode_hz.size} mode(s) and {more:.2f} Hz, seen at too "
                                    f"few orders to be selected (chi2/dof {_cost(trial[0]):.3g} against {_cost(best):.3g})"]
                best, order, rigid_from_hint, mode_hz = trial[0], trial[1], trial[2], alternative
    if modes is None and not _acceptable(best, omega, band):
        # the structure the diagram suggests fits badly, needs a negative delay or an overdamped "mode": the
        # same data with fewer modes and with the zeros beyond the band as residual flexibility
        for alternative, zero_band in _alternative_structures(diagram, mode_hz):
            trial = _fit_structure(problem, alternative, zero_band)
            if _preferred(trial[0], best, omega, band, noise_known):
                why = ", ".join(_flaws(best, omega, band)) or "a higher information criterion"
                notes = trial[3] + [f"structure: {alternative.size} of the diagram's {mode_hz.size} mode(s)"
                                    + (", zeros beyond the band as residual flexibility" if zero_band < 1.5 else "")
                                    + f", preferred to a fit with {why} (chi2/dof {_cost(trial[0]):.3g} against "
                                      f"{_cost(best):.3g})"]
                best, order, rigid_from_hint, mode_hz = trial[0], trial[1], trial[2], alternative
    dropped += notes
    solution, layout, sign = best
    if not rigid_from_hint and layout.n_rigid < n_rigid:
        dropped.append(f"{n_rigid - layout.n_rigid} of {n_rigid} rigid pole pairs not seen by this channel "
                       "(cancelled by real zeros)")
    model = _to_model(solution.x, layout, omega, sign)
    cost = _cost(best)
    features = _features(model, best, omega, band)
    return ChannelFit(model, features, diagram, order, cost, int(solution.nfev), dropped, np.asarray(mode_hz),
                      _delay_std_s(best, omega), converged=bool(solution.status > 0))


def _fit_structure(problem, mode_hz, zero_band=1.5):
    """Starting fits with the flexible modes ``mode_hz``, then output-error refinement; (best, order, rigid_from_hint, notes).

    ``zero_band``: numerator factors beyond this multiple of the band's top go into the residual flexibility.
    """
    f, x, reduced, reduced_sigma, orders, omega, n_rigid, relative_noise, rigid_hint_hz, zero_hint_hz, noise_known, \
        lowpass, delay, max_iterations = problem
    # starting fit: the lowest order that shows every selected mode and has room for the rigid poles besides them;
    # where its refinement needs a flaw, also the lowest order that shows the modes, and the better kept (fewer flaws,
    # then the information criterion).  At the lower order the modes can take every pole: hs_eden_like's DX/NX
    # multisine channel, three modes at order 6, started without its rigid pairs and ended at chi2/dof 21 with a
    # rigid "pair" at 370 Hz and its third mode lost (1.13 and all three from order 10); yet demo20's DX/NX from
    # 2 Hz to 3 kHz fits from order 6 and takes a delay of -49 us from order 10.
    band = (f.min(), f.max())
    room = 2 * n_rigid + 2 * len(mode_hz)
    best, tried = None, set()
    for lowest in (room, orders[0]):
        if best is not None and _acceptable(best[0], omega, band):
            break
        order, start = orders[-1], None
        for candidate in orders:
            if candidate < lowest and candidate < orders[-1]:
                continue
            trial = sanathanan_koerner(f, reduced, candidate, candidate, std=reduced_sigma)
            found = trial.poles[(trial.poles.imag > 0) & (trial.poles.real < 0)] / (2 * np.pi)
            if all(np.any(np.abs(np.abs(found) / m - 1) < 0.01) for m in mode_hz):
                order, start = candidate, trial
                break
        if order in tried:
            continue
        tried.add(order)
        if start is None:
            start = sanathanan_koerner(f, reduced, order, order, std=reduced_sigma)
        result, rigid_from_hint, notes = _refine_start(problem, start, mode_hz, zero_band)
        if best is None or _preferred(result, best[0], omega, band, noise_known):
            best = (result, order, rigid_from_hint, notes)
    return best


def _refine_start(problem, start, mode_hz, zero_band):
    """Output-error refinement from one linear fit, with the full rigid structure offered where it merged rigid pairs."""
    f, x, reduced, reduced_sigma, orders, omega, n_rigid, relative_noise, rigid_hint_hz, zero_hint_hz, noise_known, \
        lowpass, delay, max_iterations = problem
    rigid, rigid_from_hint, flexible, factors, residual, notes = _starting_point(
        start, x, omega, n_rigid, mode_hz, relative_noise, rigid_hint_hz, zero_band)
    best = _refine(rigid, flexible, factors, residual, x, reduced, reduced_sigma, lowpass, delay, max_iterations)
    missing = n_rigid - len(rigid)
    if missing > 0 and rigid_hint_hz is not None and (not noise_known or not _acceptable(best, omega, (f.min(), f.max()))):
        # the linear fit merged rigid pairs: offer the data the full structure, a hinted pole pair
        # with a real zero pair next to it (a neutral start), and keep what the criterion prefers (also where the
        # fit without them is within the noise but needs a flaw to be: a channel fitted with one rigid pair and a
        # delay of -180 us standing in for the other pair and its real zeros)
        hint = sorted(np.asarray(rigid_hint_hz, dtype=float) * 2 * np.pi / omega)
        extra = [a for a in hint if min(abs(a / r - 1) for r in rigid) > 0.05][:missing]
        starts = [(rigid + extra, factors + [(0.0, -(0.9 * a) ** 2) for a in extra])] if extra else []
        if zero_hint_hz is not None and len(zero_hint_hz):
            # the nominal channel's low-frequency structure: every rigid pair, its real zero pairs in place of the
            # linear fit's real factors
            complex_factors = [factor for factor in factors if factor[0] ** 2 < 4 * factor[1]]
            starts.append((hint[:n_rigid], complex_factors + [(0.0, -(z * 2 * np.pi / omega) ** 2) for z in zero_hint_hz]))
        for trial_rigid, trial_factors in starts:
            trial = _refine(trial_rigid, flexible, trial_factors, residual, x, reduced, reduced_sigma, lowpass, delay,
                            max_iterations)
            if _criterion(trial, noise_known) < _criterion(best, noise_known):
                best = trial
    return best, rigid_from_hint, notes


#: A fitted "resonance" damped more than this is no lightly damped mode (the model update's own limit): a pole
#: pair the fit needed elsewhere.
OVERDAMPED = LIGHT_DAMPING


#: A resonance whose pole an anti-resonance of the same channel cancels to within this (largest relative change of
#: |G| anywhere in the band) is a pole-zero dipole: it bends the response by a few percent, it is no mode.
DIPOLE = 0.05


def dipole_hz(model, band_hz):
    """Frequencies [Hz] of the flexible poles of ``model`` that a complex zero nearly cancels (`DIPOLE`), and of those zeros."""
    poles = model.mode_rad_s * (-model.mode_damping + 1j * np.sqrt(np.maximum(1 - model.mode_damping**2, 0.0)))
    zeros = [np.roots([1.0, c1, c0])[0] for c1, c0 in model.zero_factors if c1**2 < 4 * c0]
    found = []
    for pole in poles:
        for zero in zeros:
            zero = zero if zero.imag > 0 else np.conj(zero)
            # the pair changes |G| most near its own frequency: the band's grid and the pair's frequencies
            s = 1j * np.concatenate([2 * np.pi * np.linspace(band_hz[0], band_hz[1], 400),
                                     [pole.imag, zero.imag, abs(pole), abs(zero)]])
            change = (s - zero) * (s - np.conj(zero)) / ((s - pole) * (s - np.conj(pole))) - 1
            if np.max(np.abs(change)) < DIPOLE:
                found.append((abs(pole) / (2 * np.pi), abs(zero) / (2 * np.pi)))
    return found


def _covariance(result):
    """Linearized covariance of a refinement's scaled parameters, scaled by its residual where that exceeds the noise."""
    solution = result[0]
    try:
        return np.linalg.pinv(solution.jac.T @ solution.jac) * max(_cost(result), 1.0)
    except np.linalg.LinAlgError:
        return np.full((result[1].size, result[1].size), np.nan)


def _delay_std_s(result, omega):
    """Standard uncertainty of a refinement's delay [s] (0 without a fitted delay)."""
    return float(np.sqrt(max(_covariance(result)[-1, -1], 0.0)) / omega) if result[1].delay else 0.0


def _flaws(result, omega, band_hz):
    """What makes a refinement physically implausible: a significantly negative delay, overdamped resonances,
    pole-zero dipoles."""
    model = _to_model(result[0].x, result[1], omega, result[2])
    flaws = []
    if negative_delay(model.delay_s, _delay_std_s(result, omega)):
        flaws.append("negative delay")
    in_band = (model.mode_rad_s >= 2 * np.pi * band_hz[0]) & (model.mode_rad_s <= 2 * np.pi * band_hz[1])
    if np.any(in_band & (model.mode_damping > OVERDAMPED)):
        flaws.append("overdamped resonance")
    flaws += ["pole-zero dipole"] * len(dipole_hz(model, band_hz))
    return flaws


def _acceptable(result, omega, band_hz):
    return _consistent(result) and not _flaws(result, omega, band_hz)


def _preferred(trial, best, omega, band_hz, noise_known):
    """Whether ``trial`` beats ``best``: fewer physical flaws first, then the information criterion."""
    if _cost(trial) > MAX_CHI2 >= _cost(best):
        # a model must describe the data before it is judged physical: a flaw-free structure whose fit would be
        # flagged failed is no alternative (demo20's DX/NX multisine channel: 2 of its 3 modes at chi2/dof 4.5e3
        # preferred to 0.41 with a negative delay, until the full rigid structure was offered to that fit)
        return False
    rank = lambda r: (len(_flaws(r, omega, band_hz)), _criterion(r, noise_known))  # noqa: E731
    return rank(trial) < rank(best)


def _alternative_structures(diagram, mode_hz):
    """Other structures to try: the zeros beyond the band as residual flexibility, fewer modes (most persistent)."""
    out = [(mode_hz, 1.0)]
    for count in range(mode_hz.size - 1, 0, -1):
        subset = _most_persistent(diagram, mode_hz, count)
        out += [(subset, 1.5), (subset, 1.0)]
    return out


def _refine(rigid, flexible, factors, residual, x, data, sigma, lowpass, delay, max_iterations):
    """Output-error Levenberg-Marquardt from a starting structure (scaled); returns (solution, layout, sign)."""
    layout = _Layout(len(rigid), len(flexible), len(factors), lowpass, delay)
    flexible = np.array(flexible, dtype=complex)
    c = np.array(factors, dtype=float).reshape(-1, 2)
    theta = layout.join(0.0, np.log(rigid), np.log(np.abs(flexible)), damping_ratio(flexible), c[:, 0], c[:, 1],
                        residual, 0.0, 0.0)
    weights = 1 / sigma**2
    shape = np.exp(_log_response(theta, layout, x, 1.0)[0])
    if delay:
        # the linear fit absorbed the delay into far-off poles and zeros, now dropped: recover it
        theta[-1] = _scan_delay(shape, data, weights, x, top_delay=1.5 * np.pi)
        shape = np.exp(_log_response(theta, layout, x, 1.0)[0])
    k0 = np.sum(weights * np.conj(shape) * data).real / np.sum(weights * np.abs(shape) ** 2)
    if k0 == 0:
        raise FitError("the starting model is orthogonal to the data")
    sign = float(np.sign(k0))
    theta[0] = np.log(abs(k0))
    # sigma is the standard deviation of the complex value: each of Re and Im has sigma / sqrt(2)
    component_sigma = sigma / np.sqrt(2)

    def residuals(th):
        with np.errstate(over="ignore", invalid="ignore"):  # a rejected trial step may overflow
            r = (np.exp(_log_response(th, layout, x, sign)[0]) - data) / component_sigma
        r = np.concatenate([r.real, r.imag])
        return np.where(np.isfinite(r), r, 1e150)

    def jacobian(th):
        log_g, d = _log_response(th, layout, x, sign)
        with np.errstate(over="ignore", invalid="ignore"):
            j = np.exp(log_g)[:, None] * d / component_sigma[:, None]
        j = np.vstack([j.real, j.imag])
        return np.where(np.isfinite(j), j, 0.0)

    solution = _levenberg_marquardt(residuals, jacobian, theta, max_iterations)
    if not np.all(np.isfinite(solution.x)):
        raise FitError("the output-error refinement diverged")
    return solution, layout, sign


def _levenberg_marquardt(residuals, jacobian, theta, max_iterations):
    """MINPACK's Levenberg-Marquardt (`scipy.optimize.least_squares`, ``method="lm"``), the same bytes in every process.

    scipy 1.17.1's MINPACK (its C translation) reads one value past the end of its Jacobian array where ``qrfac``
    recomputes the norm of the last column after heavy cancellation (valgrind: an 8-byte read 0 bytes after the
    block, in ``enorm`` called from ``qrfac``).  That value is whatever the heap left there, so one fit could give
    one of two results from one process to the next (hs_eden_like's multisine DY/DY: 1e-12 apart in its poles).
    The fit is handed one more parameter with an identically zero Jacobian column: a zero column is last in the
    pivoting, never moved and never renormalized, so the read never happens; the parameter does not enter the
    residuals and is dropped from the result (with one zero residual more where the data have no more residuals
    than parameters: MINPACK needs at least as many).  It changes the path, not the problem: with a singular ``R``
    MINPACK starts its search for the damping parameter from zero, so results move within the tolerances
    (``ftol``, ``xtol`` 1e-7), and more where ``max_iterations`` ends the search (stop 56: the multisine NX/NX
    third mode 2761.5 -> 2762.4 Hz, both at the then cap of 200).
    """
    extra_row = np.size(residuals(theta)) < np.size(theta) + 1

    def padded_residuals(th):
        r = residuals(th[:-1])
        return np.append(r, 0.0) if extra_row else r

    def padded_jacobian(th):
        j = jacobian(th[:-1])
        j = np.hstack([j, np.zeros((j.shape[0], 1))])
        return np.vstack([j, np.zeros((1, j.shape[1]))]) if extra_row else j

    solution = scipy.optimize.least_squares(padded_residuals, np.append(theta, 0.0), jac=padded_jacobian, method="lm",
                                            max_nfev=max_iterations, x_scale="jac", ftol=1e-7, xtol=1e-7)
    rows = solution.fun.size - int(extra_row)
    solution.x, solution.grad = solution.x[:-1], solution.grad[:-1]
    solution.fun, solution.jac = solution.fun[:rows], solution.jac[:rows, :-1]
    return solution


def _cost(result):
    """Weighted residual sum of squares per degree of freedom (about 1 for a right model and right sigma)."""
    solution, layout, _ = result
    return float(2 * solution.cost / max(solution.fun.size - layout.size, 1))


def _consistent(result):
    """Whether the residual is what the stated noise explains (chi-square per dof within 3 sigma of 1)."""
    solution, layout, _ = result
    dof = max(solution.fun.size - layout.size, 1)
    return _cost(result) < 1 + 3 * np.sqrt(2 / dof)


def _criterion(result, noise_known):
    """Bayesian information criterion of a refinement (chi-square form when the noise is known)."""
    solution, layout, _ = result
    n = solution.fun.size
    rss = 2 * solution.cost
    fit_term = rss if noise_known else n * np.log(rss / n)
    return fit_term + layout.size * np.log(n)


def _most_persistent(diagram, candidates_hz, count):
    counts = [sum(1 for r in diagram if r["physical"] and abs(r["frequency_hz"] / c - 1) < 0.01) for c in candidates_hz]
    keep = np.sort(np.argsort(counts)[::-1][:count])
    return candidates_hz[keep]


def _modal_constant_std(result, omega, covariance):
    """Relative standard uncertainty of each flexible mode's modal constant (`ChannelModel.modal_constants`).

    The delta method on the refinement's covariance, with ``d log|constant| / d theta`` by central differences in
    the scaled parameters (the constant depends on every factor of the rational part: the gain, the other modes,
    the zeros).  Relative, so a ratio of two channels' constants has the quadrature sum as its relative uncertainty.
    """
    solution, layout, sign = result
    theta = solution.x
    if layout.n_modes == 0:
        return np.empty(0)
    step = 1e-6 * np.maximum(np.abs(theta), 1.0)
    gradient = np.empty((layout.n_modes, theta.size))
    for k in range(theta.size):
        up, down = theta.copy(), theta.copy()
        up[k] += step[k]
        down[k] -= step[k]
        with np.errstate(divide="ignore"):
            gradient[:, k] = (np.log(np.abs(_to_model(up, layout, omega, sign).modal_constants()))
                              - np.log(np.abs(_to_model(down, layout, omega, sign).modal_constants()))) / (2 * step[k])
    variance = np.einsum("mi,ij,mj->m", gradient, covariance, gradient)
    return np.where(np.isfinite(variance), np.sqrt(np.maximum(variance, 0.0)), np.inf)


def _features(model, result, omega, band_hz):
    """classify_poles rows of the model with linearized standard uncertainties of the flexible modes."""
    rows = classify_poles(model.poles, model.zeros, band_hz)
    layout = result[1]
    covariance = _covariance(result)
    q_index = 1 + layout.n_rigid
    constant_std = _modal_constant_std(result, omega, covariance)
    for m, (w, zeta, constant) in enumerate(zip(model.mode_rad_s, model.mode_damping, model.modal_constants())):
        i_w, i_z = q_index + m, q_index + layout.n_modes + m
        for row in rows:
            if row["root"] == "pole" and abs(row["frequency_hz"] - w / (2 * np.pi)) <= 1e-9 * w:
                row["frequency_std_hz"] = float(w / (2 * np.pi) * np.sqrt(max(covariance[i_w, i_w], 0.0)))
                row["damping_std"] = float(np.sqrt(max(covariance[i_z, i_z], 0.0)))
                row["modal_constant"] = float(constant)
                row["modal_constant_std"] = float(constant_std[m])
    # complex zero factors x^2 + c1 x + c0 (x = s / omega): f = omega sqrt(c0) / 2 pi, zeta = c1 / (2 sqrt(c0))
    c_index = q_index + 2 * layout.n_modes
    for m, (c1, c0) in enumerate(model.zero_factors):
        if c1**2 >= 4 * c0:
            continue
        frequency = np.sqrt(c0) / (2 * np.pi)
        i_1, i_0 = c_index + m, c_index + layout.n_zero + m
        scaled_c0 = c0 / omega**2
        gradient_f = np.array([0.0, frequency / (2 * scaled_c0)])  # d f / d (c1, c0) in scaled units
        gradient_z = np.array([1 / (2 * np.sqrt(scaled_c0)), -c1 / omega / (4 * scaled_c0**1.5)])
        block = covariance[np.ix_([i_1, i_0], [i_1, i_0])]
        for row in rows:
            if row["root"] == "zero" and abs(row["frequency_hz"] - frequency) <= 1e-9 * frequency:
                row["frequency_std_hz"] = float(np.sqrt(max(gradient_f @ block @ gradient_f, 0.0)))
                row["damping_std"] = float(np.sqrt(max(gradient_z @ block @ gradient_z, 0.0)))
    return rows


# -------------------------------------------------------- a whole FRF table
CHANNEL_SETS = ("diagonal", "same_plane", "all")


def fit_orders(orders=None, n_rigid=RIGID_MODES):
    """Denominator orders of the stabilization diagram: ``orders``, or ``2 n_rigid + 2, ..., 2 n_rigid + 12``."""
    base = 2 * n_rigid
    return list(range(base + 2, base + 13, 2)) if orders is None else list(orders)


def max_fit_modes(settings):
    """Most flexible modes the ``fit:`` settings can give a channel (the modes they fix, or half the highest order).

    Raises
    ------
    ConfigError
        ``fit.modes`` more than the stabilization diagram's highest order can hold, before any data is read.
    """
    highest = max(fit_orders(settings.get("orders")))
    modes = settings.get("modes")
    if modes is not None and modes > highest // 2:
        raise ConfigError("fit.modes", f"{modes} flexible modes need a denominator order >= {2 * modes}; the stabilization "
                                       f"diagram's highest order is {highest} (fit.orders), {highest // 2} modes at most")
    return highest // 2 if modes is None else modes


def select_channels(kind, axes=RADIAL_AXES):
    """Radial channels ``(output, input)`` to fit.

    ``diagonal``: each axis to itself; ``same_plane``: outputs and inputs in the
    same plane (DX, NX / DY, NY; at standstill the planes do not couple);
    ``all``: the 4 x 4 matrix.
    """
    if kind not in CHANNEL_SETS:
        raise FitError(f"fit.channels must be one of {CHANNEL_SETS}, not {kind!r}")
    plane = {a: a[-1] for a in axes}
    return [(o, i) for o in axes for i in axes
            if kind == "all" or (kind == "same_plane" and plane[o] == plane[i]) or o == i]


#: Default of ``fit.max_chi2``: chi-square per degree of freedom (against the noise, or the scatter a
#: high-order rational fit leaves where that is larger) above which a channel's fit has failed.
MAX_CHI2 = 300.0


def fit_verdict(channel_fit, frequency_hz, response, known, label, max_chi2=MAX_CHI2):
    """What is wrong with a fitted channel, as a flag for its features and findings for the user.

    Returns
    -------
    flag : str
        ``fit_failed`` (chi2/dof above ``max_chi2``), ``negative_delay`` (a non-causal fit: its
        structure compensates something it lacks) or ``""``.  Features of a flagged channel are
        not used by the model update.
    findings : list of ambid.findings.Finding
        One per flag, one where the refinement stopped at its evaluation cap (``not_converged``),
        and one per in-band "resonance" damped more than `OVERDAMPED` (no mode: a pole pair the
        fit needed elsewhere; flagged ``overdamped`` by `feature_rows`).
    """
    model = channel_fit.model
    fitted = model.frequency_response(frequency_hz, known)
    misfit = float(np.sqrt(np.mean(np.abs(fitted / response - 1) ** 2)))
    findings, flag = [], ""
    if not channel_fit.cost <= max_chi2:
        flag = "fit_failed"
        findings.append(Finding("fit", "failure", "fit_failed", label,
                                f"chi2/dof {channel_fit.cost:.6g} above fit.max_chi2 {max_chi2:g} (rms relative misfit "
                                f"{100 * misfit:.3g} %): the fitted model does not follow the data; its resonances and "
                                "anti-resonances are not used by the model update", channel_fit.cost))
    elif negative_delay(model.delay_s, channel_fit.delay_std_s):
        flag = "negative_delay"
        findings.append(Finding("fit", "warning", "negative_delay", label,
                                f"fitted delay {1e6 * model.delay_s:.4g}"
                                + (f" +- {1e6 * channel_fit.delay_std_s:.2g}" if np.isfinite(channel_fit.delay_std_s) else "")
                                + " us < 0: a non-causal fit, its structure compensates something it lacks; its features "
                                "are not used by the model update", model.delay_s))
    if not channel_fit.converged:
        findings.append(Finding("fit", "warning", "not_converged", label,
                                f"the output-error refinement stopped at its cap of {channel_fit.iterations} evaluations "
                                "before its tolerances were met: its resonances and anti-resonances depend on where the "
                                "search stopped, beyond their stated uncertainties (another solver path moved hs_eden_like's "
                                "multisine NX/NX third mode by 1.2 of its standard deviations)", channel_fit.iterations))
    for row in channel_fit.features:
        if row["kind"] == "resonance" and row["damping_ratio"] > OVERDAMPED:
            findings.append(Finding("fit", "warning", "overdamped", label,
                                    f"a fitted pole pair at {row['frequency_hz']:.4g} Hz with damping ratio "
                                    f"{row['damping_ratio']:.3g} > {OVERDAMPED}: no lightly damped mode; not used by the "
                                    "model update", row["damping_ratio"]))
    for pole_hz, zero_hz in dipole_hz(model, (np.min(frequency_hz), np.max(frequency_hz))):
        findings.append(Finding("fit", "warning", "dipole", label,
                                f"the pole pair at {pole_hz:.4g} Hz and the zero pair at {zero_hz:.4g} Hz nearly cancel "
                                f"(|G| changes by less than {100 * DIPOLE:g} % anywhere in the band): a bend of the response, "
                                "no mode; not used by the model update", pole_hz))
    return flag, findings


def feature_rows(channel_fit, output_axis, input_axis, estimator, flag="", band_hz=None):
    """The features of one fitted channel as table rows (resonances, anti-resonances, rigid poles, delay).

    ``flag`` (`fit_verdict`) marks every row; a resonance damped more than `OVERDAMPED` is ``overdamped``, the
    pole and zero of a pole-zero dipole (`dipole_hz` in ``band_hz``, default: the span of the in-band features)
    are ``dipole``.
    """
    if band_hz is None:
        in_band = [r["frequency_hz"] for r in channel_fit.features if r["kind"] in ("resonance", "anti_resonance")]
        band_hz = (min(in_band, default=0.0), max(in_band, default=0.0))
    dipoles = [f for pair in dipole_hz(channel_fit.model, band_hz) for f in pair]
    rows = []
    for row in channel_fit.features:
        if row["kind"] in ("stable_rigid",):
            continue
        if any(abs(row["frequency_hz"] / f - 1) < 1e-9 for f in dipoles) and row["kind"] in ("resonance", "anti_resonance"):
            overdamped = "dipole"
        else:
            overdamped = "overdamped" if row["kind"] == "resonance" and row["damping_ratio"] > OVERDAMPED else ""
        rows.append({"output": output_axis, "input": input_axis, "estimator": estimator, "root": row["root"],
                     "kind": row["kind"], "number": row["number"], "frequency_hz": row["frequency_hz"],
                     "damping_ratio": row["damping_ratio"], "frequency_std_hz": row.get("frequency_std_hz", np.nan),
                     "damping_std": row.get("damping_std", np.nan), "modal_constant": row.get("modal_constant", np.nan),
                     "modal_constant_std": row.get("modal_constant_std", np.nan), "flag": flag or overdamped})
    return rows


def model_rows(channel_fit, output_axis, input_axis):
    """One row per channel: the fitted model's parameters (enough to rebuild `ChannelModel`)."""
    m = channel_fit.model
    return {"output": output_axis, "input": input_axis, "gain": m.gain,
            "rigid_rad_s": " ".join(f"{v:.12g}" for v in m.rigid_rad_s),
            "mode_rad_s": " ".join(f"{v:.12g}" for v in m.mode_rad_s),
            "mode_damping": " ".join(f"{v:.12g}" for v in m.mode_damping),
            "zero_factors": " ".join(f"{c1:.12g},{c0:.12g}" for c1, c0 in m.zero_factors),
            "residual_s2": m.residual_s2, "lowpass_rad_s": m.lowpass_rad_s, "delay_s": m.delay_s,
            "order": channel_fit.order, "cost": channel_fit.cost, "dropped": "; ".join(channel_fit.dropped)}


def model_from_row(row):
    """Inverse of `model_rows`: a `ChannelModel` from a stored row (for example of models.parquet)."""
    numbers = lambda text: np.array([float(v) for v in str(text).split()]) if str(text).strip() else np.array([])  # noqa: E731
    factors = [tuple(float(v) for v in pair.split(",")) for pair in str(row["zero_factors"]).split()]
    return ChannelModel(float(row["gain"]), numbers(row["rigid_rad_s"]), numbers(row["mode_rad_s"]),
                        numbers(row["mode_damping"]), np.array(factors, dtype=float).reshape(-1, 2),
                        float(row["residual_s2"]), float(row["lowpass_rad_s"]), float(row["delay_s"]))
