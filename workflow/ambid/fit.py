"""Parametric models of measured FRFs (thesis ch. 5.1): rational fits, poles and zeros, resonances.

`levy_thesis` is the thesis' method as written: ``G = B(jf) / A(jf)`` with
monomials in the frequency in Hz (eq. 5.1-5.3), Levy's linearization (eq. 5.5),
the iterative weighting ``W = 1 / (A_{m-1} G)`` (eq. 5.6-5.8, Sanathanan-Koerner
iterations), the normal equations of the stacked real/imaginary system, and the
highest denominator coefficient fixed to 1.  It is the reference that better
estimators are measured against: its normal equations are astronomically
conditioned at orders above ten and its estimate is biased under noise.

`sanathanan_koerner` is the linear stage of the default estimator: the same
iterative weighting, but with the frequency scaled to the band (|x| <= 1),
columns normalized and the stacked real/imaginary system solved by least
squares (QR), never through the normal equations; it gives starting values
and the stabilization diagram (`stabilization`).  `ambid.channel_fit` refines
them by output-error nonlinear least squares.

`classify_poles` turns poles and zeros into what an AMB engineer reads: the
unstable real pole pairs of the levitated rotor's negative stiffness, the
flexible resonances numbered by frequency, anti-resonances from the zeros, and
anything else flagged (unstable complex poles are not physical in an open-loop
AMB plant).
"""

from dataclasses import dataclass

import numpy as np

from .plant import damping_ratio

__all__ = ["RationalFit", "levy_thesis", "sanathanan_koerner", "stabilization", "classify_poles"]


@dataclass(frozen=True)
class RationalFit:
    """A fitted rational transfer function.

    Attributes
    ----------
    numerator, denominator : arrays
        Coefficients in powers of ``x = s / (2 pi frequency_scale_hz)``, lowest first
        (the thesis: ``frequency_scale_hz = 1``, the Laplace variable in Hz).
    poles, zeros : arrays
        In rad/s.
    method : str
    condition : float
        Condition number of the final linear system.
    iterations : int
    """

    numerator: np.ndarray
    denominator: np.ndarray
    poles: np.ndarray
    zeros: np.ndarray
    method: str
    condition: float
    iterations: int
    frequency_scale_hz: float = 1.0

    def frequency_response(self, frequency_hz):
        """The fitted G at ``frequency_hz``."""
        x = 1j * np.asarray(frequency_hz, dtype=float) / self.frequency_scale_hz
        return np.polyval(self.numerator[::-1], x) / np.polyval(self.denominator[::-1], x)


def levy_thesis(frequency_hz, response, numerator_order, denominator_order, iterations=10):
    """The thesis' parametric fit, eq. 5.1-5.10, as written.

    Parameters
    ----------
    frequency_hz : array (n,)
    response : complex array (n,)
        Measured FRF.
    numerator_order, denominator_order : int
        n_b and n_a; ``a_{n_a} = 1``.
    iterations : int
        Weighting iterations (the first is Levy's unweighted fit, eq. 5.5).

    Returns
    -------
    RationalFit

    Notes
    -----
    Unknowns ``theta = [b_0 .. b_nb, a_0 .. a_{na-1}]``; for each frequency the
    weighted equation error ``W (B - A G)`` (eq. 5.7) is linear in theta.  The
    real and imaginary parts are stacked into ``J theta = y`` and solved through
    the normal equations ``J^T J theta = J^T y`` (eq. 5.9-5.10, Verboven 2002).
    """
    f = np.asarray(frequency_hz, dtype=float)
    g = np.asarray(response, dtype=complex)
    x = 1j * f
    powers_b = x[:, None] ** np.arange(numerator_order + 1)
    powers_a = x[:, None] ** np.arange(denominator_order)
    weight = np.ones_like(g)
    condition = np.nan
    for _ in range(iterations):
        rows = np.hstack([weight[:, None] * powers_b, -(weight * g)[:, None] * powers_a])
        rhs = weight * g * x**denominator_order
        stacked = np.vstack([rows.real, rows.imag])
        target = np.concatenate([rhs.real, rhs.imag])
        normal = stacked.T @ stacked
        condition = np.linalg.cond(normal)
        theta = np.linalg.solve(normal, stacked.T @ target)
        b = theta[: numerator_order + 1]
        a = np.concatenate([theta[numerator_order + 1 :], [1.0]])
        previous = np.polyval(a[::-1], x)
        weight = 1.0 / (previous * g)  # eq. 5.6
    poles = 2 * np.pi * np.roots(a[::-1])
    zeros = 2 * np.pi * np.roots(b[::-1]) if numerator_order > 0 else np.array([], dtype=complex)
    return RationalFit(b, a, poles, zeros, "thesis (Levy + iterative weighting, normal equations)", float(condition), iterations)


def sanathanan_koerner(frequency_hz, response, numerator_order, denominator_order, std=None, iterations=30,
                       tolerance=1e-9):
    """Rational fit by iterated weighted linear least squares in a scaled basis.

    Minimizes ``sum |(B(x) - A(x) G) / (A_{m-1}(x) sigma)|^2`` over the
    coefficients with ``a_{n_a} = 1``, ``x = j f / f_max``: thesis eq. 5.6-5.8
    with the measurement weight ``1 / sigma`` and a well-posed solve.

    Parameters
    ----------
    frequency_hz, response : arrays (n,)
    numerator_order, denominator_order : int
    std : array (n,), optional
        Standard deviation of each point [same unit as the response]; default 1.
    iterations : int
        Maximum weighting iterations; stops earlier when the poles settle.
    tolerance : float
        Relative change of the denominator coefficients that counts as settled.

    Returns
    -------
    RationalFit
        ``condition`` is the 2-norm condition number of the column-normalized
        least-squares matrix of the last iteration (the thesis' normal
        equations would have its square, before scaling).
    """
    f = np.asarray(frequency_hz, dtype=float)
    g = np.asarray(response, dtype=complex)
    scale_hz = float(np.max(np.abs(f)))
    x = 1j * f / scale_hz
    weight = 1.0 / (np.ones_like(f) if std is None else np.asarray(std, dtype=float))
    powers_b = x[:, None] ** np.arange(numerator_order + 1)
    powers_a = x[:, None] ** np.arange(denominator_order)
    previous = np.ones_like(g)
    a_old = None
    condition = np.nan
    for iteration in range(1, iterations + 1):
        w = weight / previous
        rows = np.hstack([w[:, None] * powers_b, -(w * g)[:, None] * powers_a])
        rhs = w * g * x**denominator_order
        stacked = np.vstack([rows.real, rows.imag])
        norms = np.linalg.norm(stacked, axis=0)
        norms[norms == 0] = 1.0
        theta, _, _, singular = np.linalg.lstsq(stacked / norms, np.concatenate([rhs.real, rhs.imag]), rcond=None)
        condition = singular[0] / singular[-1] if singular[-1] > 0 else np.inf
        theta = theta / norms
        b = theta[: numerator_order + 1]
        a = np.concatenate([theta[numerator_order + 1 :], [1.0]])
        previous = np.polyval(a[::-1], x)
        if a_old is not None and np.max(np.abs(a - a_old)) <= tolerance * np.max(np.abs(a)):
            break
        a_old = a
    omega = 2 * np.pi * scale_hz
    poles = omega * np.roots(a[::-1])
    zeros = omega * np.roots(b[::-1]) if numerator_order > 0 and np.any(b[1:]) else np.array([], dtype=complex)
    return RationalFit(b, a, poles, zeros, "Sanathanan-Koerner, scaled basis, least squares", float(condition),
                       iteration, scale_hz)


def stabilization(frequency_hz, response, orders, std=None, relative_degree=0, frequency_tolerance=0.01,
                  damping_tolerance=0.10, iterations=8):
    """Stabilization diagram: the poles of `sanathanan_koerner` fits of increasing order.

    Parameters
    ----------
    frequency_hz, response, std : arrays (n,)
    orders : iterable of int
        Denominator orders (numerator order = order - ``relative_degree``).
    iterations : int
        Weighting iterations per order (the physical poles settle in a few).
    frequency_tolerance, damping_tolerance : float
        A pole is *stable* when the previous order has one within these relative
        differences of frequency and damping ratio.

    Returns
    -------
    list of dict
        One row per pole with ``Im >= 0``: ``order``, ``frequency_hz``,
        ``damping_ratio``, ``stable`` (bool), ``physical`` (complex, stable, in
        band), and per order the weighted residual norm as ``residual``.
    """
    f = np.asarray(frequency_hz, dtype=float)
    g = np.asarray(response, dtype=complex)
    sigma = np.ones_like(f) if std is None else np.asarray(std, dtype=float)
    rows, previous = [], None
    for order in orders:
        fit = sanathanan_koerner(f, g, order - relative_degree, order, std=sigma, iterations=iterations)
        residual = float(np.linalg.norm((fit.frequency_response(f) - g) / sigma))
        poles = fit.poles[fit.poles.imag >= 0]
        frequency = np.abs(poles) / (2 * np.pi)
        zeta = damping_ratio(poles)
        for k, pole in enumerate(poles):
            stable = False
            if previous is not None and previous[0].size:
                close = np.abs(previous[0] / frequency[k] - 1) <= frequency_tolerance
                close &= np.abs(previous[1] - zeta[k]) <= damping_tolerance * max(abs(zeta[k]), 1e-12)
                stable = bool(np.any(close))
            physical = bool(abs(pole.imag) > 1e-3 * abs(pole) and pole.real < 0 and f.min() <= frequency[k] <= f.max())
            rows.append({"order": order, "frequency_hz": float(frequency[k]), "damping_ratio": float(zeta[k]),
                         "stable": stable, "physical": physical, "residual": residual})
        previous = (frequency, zeta)
    return rows


def classify_poles(poles, zeros, band_hz, real_tolerance=1e-3, anti_resonance_damping=0.2):
    """Resonances and anti-resonances of a fitted AMB plant channel.

    Parameters
    ----------
    poles, zeros : arrays [rad/s]
    band_hz : (float, float)
        The measured band; roots outside it are reported as out of band.
    real_tolerance : float
        ``|Im| < tol |s|`` counts as real.
    anti_resonance_damping : float
        Complex zeros damped more than this shape the response without a notch:
        ``complex_zero``, not an anti-resonance.

    Returns
    -------
    list of dict
        One per root with ``Im >= 0``: ``root`` (pole / zero), ``kind``
        (unstable_rigid / stable_rigid / resonance / unstable_complex /
        anti_resonance / nonminimum_phase_zero / complex_zero / real_zero /
        out_of_band), ``number`` (flexible resonances and anti-resonances
        counted from 1 in frequency order), ``frequency_hz`` (|s| / 2 pi),
        ``damping_ratio``.
    """
    low, high = band_hz
    rows = []
    for root_kind, roots in (("pole", np.asarray(poles)), ("zero", np.asarray(zeros))):
        for s in roots:
            if s.imag < -real_tolerance * abs(s):
                continue
            frequency = abs(s) / (2 * np.pi)
            zeta = float(damping_ratio(np.array([s]))[0])
            real = abs(s.imag) <= real_tolerance * abs(s)
            if root_kind == "pole" and real:
                kind = "unstable_rigid" if s.real > 0 else "stable_rigid"
            elif real:
                kind = "real_zero"
            elif not low <= frequency <= high:
                kind = "out_of_band"
            elif root_kind == "pole":
                kind = "unstable_complex" if s.real > 0 else "resonance"
            elif s.real > 0:
                kind = "nonminimum_phase_zero"
            else:
                kind = "anti_resonance" if zeta <= anti_resonance_damping else "complex_zero"
            rows.append({"root": root_kind, "kind": kind, "frequency_hz": float(frequency), "damping_ratio": zeta,
                         "number": 0})
    rows.sort(key=lambda r: (r["root"], r["frequency_hz"]))
    for kind in ("resonance", "anti_resonance"):
        for number, row in enumerate((r for r in rows if r["kind"] == kind), start=1):
            row["number"] = number
    return rows
