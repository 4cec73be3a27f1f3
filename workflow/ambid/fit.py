"""Parametric models of measured FRFs (thesis ch. 5.1): rational fits, poles and zeros, resonances.

`levy_thesis` is the thesis' method as written: ``G = B(jf) / A(jf)`` with
monomials in the frequency in Hz (eq. 5.1-5.3), Levy's linearization (eq. 5.5),
the iterative weighting ``W = 1 / (A_{m-1} G)`` (eq. 5.6-5.8, Sanathanan-Koerner
iterations), the normal equations of the stacked real/imaginary system, and the
highest denominator coefficient fixed to 1.  It is the reference that better
estimators are measured against: its normal equations are astronomically
conditioned at orders above ten and its estimate is biased under noise.

`classify_poles` turns poles and zeros into what an AMB engineer reads: the
unstable real pole pairs of the levitated rotor's negative stiffness, the
flexible resonances numbered by frequency, anti-resonances from the zeros, and
anything else flagged (unstable complex poles are not physical in an open-loop
AMB plant).
"""

from dataclasses import dataclass

import numpy as np

from .plant import damping_ratio

__all__ = ["RationalFit", "levy_thesis", "classify_poles"]


@dataclass(frozen=True)
class RationalFit:
    """A fitted rational transfer function.

    Attributes
    ----------
    numerator, denominator : arrays
        Coefficients in powers of ``x = s / (2 pi)`` (the Laplace variable in Hz), lowest first.
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

    def frequency_response(self, frequency_hz):
        """The fitted G at ``frequency_hz``."""
        x = 1j * np.asarray(frequency_hz, dtype=float)
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


def classify_poles(poles, zeros, band_hz, real_tolerance=1e-3):
    """Resonances and anti-resonances of a fitted AMB plant channel.

    Parameters
    ----------
    poles, zeros : arrays [rad/s]
    band_hz : (float, float)
        The measured band; roots outside it are reported as out of band.
    real_tolerance : float
        ``|Im| < tol |s|`` counts as real.

    Returns
    -------
    list of dict
        One per root with ``Im >= 0``: ``kind`` (unstable_rigid / stable_rigid /
        resonance / anti_resonance / unstable_complex / real_zero / out_of_band),
        ``number`` (flexible resonances and anti-resonances counted from 1 in
        frequency order), ``frequency_hz`` (|s| / 2 pi), ``damping_ratio``.
    """
    low, high = band_hz
    rows = []
    for root_kind, roots in (("pole", np.asarray(poles)), ("zero", np.asarray(zeros))):
        for s in roots:
            if s.imag < -real_tolerance * abs(s):
                continue
            frequency = abs(s) / (2 * np.pi)
            real = abs(s.imag) <= real_tolerance * abs(s)
            if root_kind == "pole" and real:
                kind = "unstable_rigid" if s.real > 0 else "stable_rigid"
            elif real:
                kind = "real_zero"
            elif not low <= frequency <= high:
                kind = "out_of_band"
            elif root_kind == "pole" and s.real > 0:
                kind = "unstable_complex"
            else:
                kind = "resonance" if root_kind == "pole" else "anti_resonance"
            rows.append({"root": root_kind, "kind": kind, "frequency_hz": float(frequency),
                         "damping_ratio": float(damping_ratio(np.array([s]))[0]), "number": 0})
    rows.sort(key=lambda r: (r["root"], r["frequency_hz"]))
    for kind in ("resonance", "anti_resonance"):
        for number, row in enumerate((r for r in rows if r["kind"] == kind), start=1):
            row["number"] = number
    return rows
