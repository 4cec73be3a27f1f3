"""The FRF at zero excitation amplitude: the stepped sine's two-level repeats extrapolated (Richardson).

A stepped sine measures the describing function of the bearing at the
excitation amplitude ``A`` (``|U2|``), not the linearized plant the model is:
the force law's cubic terms (thesis eq. 3.6) make ``G(A) = G_0 + k(f) A^2 + ...``
(`ambid.floor`).  A step measured again at a lower amplitude ``A_1`` (log
``level`` 1, ``identification.repeat_ratio``) gives both ``k`` and the value at
zero amplitude, which is what the model predicts::

    G_0 = G(A) - lambda (G(A) - G(A_1)),   lambda = A^2 / (A^2 - A_1^2)

(``(4 G(A/2) - G(A)) / 3`` at half the amplitude), with the noise
``sqrt((lambda - 1)^2 s^2 + lambda^2 s_1^2)`` and no systematic error of order
``A^2`` left.  Steps that were not repeated take ``G_0 = G(A) / (1 + kappa A^2)``
with the amplitude coefficient ``kappa = (G(A) / G_0 - 1) / A^2`` interpolated
(linear in log frequency) from the nearest repeated steps either side: the
coefficient, not the correction, is smooth in frequency when the adaptive
amplitude changes from step to step.  Its noise adds to theirs, and the
interpolation's own error, from the curvature the pairs show (each pair against
the line through its neighbours, beyond their noise), becomes their systematic
error: the interpolation cannot follow a coefficient that changes within a few
steps, as it does at a lightly damped resonance.  A resonance that peaks between
two pairs is not seen by their curvature at all; there the coefficient grows with
the amplification (`ambid.floor.resonance_ratio` ``r``: how far ``|G|`` stands above
the pairs' line), and the interpolated one misses it by about ``|r - 1|`` times
itself, which the systematic error adds.  Where the pairs show it to be the
smoother one, a step interpolates ``kappa / G`` instead and multiplies it by its
own ``G`` (`_follows_response`): the force law's amplitude-dependent stiffness
changes a position response by ``G dk G``, an error that follows ``G`` through a
resonance, peak and phase; the two interpolations' difference is then part of
the systematic error.

Where a channel's amplitude dependence is measured (its pairs' coefficients
jointly `MEASURED_KAPPA` standard deviations away from zero: the positions near
a bearing), every point of the channel takes the extrapolated value.  The
describing function's error ``kappa A^2`` has one sign over a band, so points
left at their amplitude, each within its noise, add up to a bias a fit over
hundreds of points reads as physics (on the suite's demo20 rigs without a hidden
effect, a sensor offset of 0.1 mm at BIC evidence 80-118); at zero amplitude the
noise is larger but averages out.  The MIMO cross elements, whose own pairs
are too noisy for that, take the error the four diagonal elements' coefficients
predict through the MIMO estimate's ``U^-1`` (`_mimo_inversion_errors`), on every
point, unless their own pairs refute it.  Elsewhere (the coil currents, whose
pairs are noise) a point takes the extrapolated
value only where its error variance (noise plus interpolation error) is below the
measured point's noise plus its floor (the ``two_level`` floor of `ambid.floor`):
halving the amplitude costs more than the error it removes.  Both choices depend
on estimated errors and on a whole channel's pairs, never on one point's value,
so they add no bias.

On by default (config ``frf.zero_amplitude``; false keeps the describing function
at the measured amplitude with its two-level floor).  It trusts each point's
stated noise, which is why it waited for the stepped sine's noise to be pooled
over neighbouring steps (`ambid.floor.pooled_noise`).  Where a channel's pairs
scatter beyond their stated noise (each against the line through its neighbours,
`pair_noise_factor`), the scatter decides whether the dependence is measured:
the coil currents' pairs, stated too quiet, read as a dependence the amplifier
does not have.  In a channel whose dependence is not measured the scatter is
noise, and the pairs' noise is raised to it; in one whose dependence is measured
(the positions near a bearing) it is partly the coefficient's curvature, which
the interpolation's error already counts, and the stated noise stays.  This is beyond the thesis
(its FRFs are the describing function at one level).
"""

import numpy as np
import scipy.special

from .floor import (RESOLVED, FloorSettings, excitation_amplitude_squared, family_of, level_pairs, local_fits,
                    noise_relative_median, pool_windows, resonance_ratio)
from .logs import run_matrix
from .machine import RADIAL_AXES

__all__ = ["MEASURED_KAPPA", "AMPLITUDE_ERROR_ALIKE", "amplitude_dependence", "pair_noise_factor", "zero_amplitude",
           "account_zero_amplitude", "effective_share", "measured_variance_errors"]

#: Library effects the describing function's amplitude-dependent error reads like (stop 30: the leads of centred rigs
#: without zero amplitude): what a diagnosis of a run without repeated steps may name for it.
AMPLITUDE_ERROR_ALIKE = ("actuator_coefficients", "noncollocation")

#: Degrees of freedom of one step's noise variance (the two DFT lines beside its excitation line, `ambid.floor`).
NOISE_DOF = 4

#: A channel's amplitude dependence is measured where its pairs put it this many standard deviations from zero
#: (`amplitude_dependence`).
MEASURED_KAPPA = 5.0

#: The input cross coupling at which `zero_amplitude` differences `_mimo_inversion_errors` for its slope (the error
#: is smooth in it: a step of 1e-3 against the library's range of +-0.5).
COUPLING_STEP = 1e-3

#: `_mimo_inversion_errors` is first order in the diagonals' relative corrections ``delta`` (``G = P / (1 + delta)``):
#: at a step where one of them is uncertain beyond this (noise and interpolation error together) it says nothing.
LINEAR_DELTA = 0.1

#: A MIMO cross element's pairs state a departure from the error the diagonals predict for it where they put it this
#: many standard deviations beyond their noise (`_structured_zero`; beyond `MEASURED_KAPPA` they refute it).
DEPARTURE = 2.0


def amplitude_dependence(kappa, variance):
    """How far a channel's pairs put its amplitude coefficient from zero, in standard deviations.

    ``(sum |kappa_k|^2 / var_k - n) / sqrt(n)`` over its ``n`` pairs: each term has
    mean 1 where kappa is noise, so the sum is ``n`` with a standard deviation of
    about ``sqrt(n)`` (first order; in a channel whose response is inside its noise
    the terms are ratios of noise and the sum reads lower).
    """
    significance = np.abs(kappa) ** 2 / variance
    return float((np.sum(significance) - significance.size) / np.sqrt(significance.size))


def pair_noise_factor(log_frequency, kappa, variance):
    """How many times the pairs' stated noise variance understates their scatter (at least 1).

    Each interior pair's amplitude coefficient against the line through its
    neighbours (in log frequency, as `_interpolated` draws it), over that
    residual's stated variance: for a complex Gaussian noise of those variances
    the ratio has median ``ln 2``, and a coefficient that changes linearly adds
    nothing, so the factor is the ratios' median over ``ln 2``.  A median, so the
    few pairs where a resonance bends the coefficient do not count.  On demo20's
    rig without a hidden effect, a coil-current channel's pairs scatter up to 4.5
    times their stated variance: taken at their word, a coil-current channel showed
    an amplitude dependence of 6.1-8.3 standard deviations, where the amplifier has
    none, in 3 of 6 logs (seeds 2026-2031), went to zero amplitude with its noise
    understated, and the diagnosis called the coil currents unexplained misfit.
    """
    x, kappa, variance = (np.asarray(a) for a in (log_frequency, kappa, variance))
    if kappa.size < 3:
        return 1.0
    _, residual, stated = _leave_one_out(x, kappa, variance)
    return max(1.0, float(np.median(np.abs(residual) ** 2 / stated)) / np.log(2))


def _bracket(log_frequency, repeated):
    """Each point's repeated points either side (indices into ``repeated``) and its weight ``w`` on the right one.

    Linear in ``log_frequency`` between them; beyond the ends, the nearest one (``w`` 0 or 1).
    """
    x = log_frequency[repeated]
    right = np.clip(np.searchsorted(x, log_frequency), 1, x.size - 1)
    left = right - 1
    weight = np.clip((log_frequency - x[left]) / np.maximum(x[right] - x[left], 1e-12), 0.0, 1.0)
    return left, right, weight


def _interpolated(log_frequency, repeated, coefficient, variance, bracket=None, basis=None):
    """A coefficient, its noise variance and its interpolation error at every point of one channel.

    ``repeated`` indexes the points with their own estimate (``coefficient`` and
    ``variance`` in that order); the others interpolate ``coefficient / basis``
    linearly in ``log_frequency`` between the repeated points either side (the
    nearest one beyond the ends), as ``bracket`` (`_bracket`, made here if not
    given) gives them, and multiply it by their own ``basis`` (1 where none:
    the coefficient itself; `_follows_response`).
    """
    x = log_frequency[repeated]
    basis = np.ones(log_frequency.size) if basis is None else basis
    left, right, weight = bracket or _bracket(log_frequency, repeated)
    spacing = np.maximum(x[right] - x[left], 1e-12)
    scaled, scaled_variance = coefficient / basis[repeated], variance / np.abs(basis[repeated]) ** 2
    value = ((1 - weight) * scaled[left] + weight * scaled[right]) * basis
    noise = ((1 - weight) ** 2 * scaled_variance[left] + weight**2 * scaled_variance[right]) * np.abs(basis) ** 2
    # linear interpolation errs by w (1 - w) h^2 q'' / 2 at the fraction w of a spacing h; each interior pair's
    # leave-one-out residual (its neighbours' line against its own estimate, beyond their noise) measures
    # (q'' / 2)^2, averaged over the two pairs either side of a step; a coefficient that changes within a few steps
    # (a lightly damped resonance) has large residuals there, one that changes linearly none
    curvature = np.zeros(x.size)
    if x.size >= 3:
        u, residual, stated = _leave_one_out(x, scaled, scaled_variance)
        beyond = np.abs(residual) ** 2 - stated
        curvature[1:-1] = beyond / np.maximum(u * (1 - u) * (x[2:] - x[:-2]) ** 2, 1e-300) ** 2
        curvature[0], curvature[-1] = curvature[1], curvature[-2]
    local = np.clip(0.5 * (curvature[left] + curvature[right]), 0.0, None)
    error = weight * (1 - weight) * spacing**2 * np.sqrt(local) * np.abs(basis)
    value[repeated], noise[repeated], error[repeated] = coefficient, 0.0, 0.0
    return value, noise, error


def _leave_one_out(x, coefficient, variance):
    """Each interior pair against the line through its neighbours: ``u``, the residual and its stated variance."""
    u = (x[1:-1] - x[:-2]) / np.maximum(x[2:] - x[:-2], 1e-12)
    residual = coefficient[1:-1] - ((1 - u) * coefficient[:-2] + u * coefficient[2:])
    return u, residual, variance[1:-1] + (1 - u) ** 2 * variance[:-2] + u**2 * variance[2:]


def _follows_response(log_frequency, repeated, coefficient, variance, values, bracket):
    """Which points interpolate their amplitude coefficient relative to the FRF itself (``kappa / G``), not as it is.

    The force law's amplitude-dependent negative stiffness changes a position
    response by ``dG = G dk_x G`` (collocated), a relative error ``kappa A^2``
    that follows ``G`` through a resonance, rotating by half a turn across it,
    where ``kappa`` itself, interpolated between two pairs, misses the peak
    between them; near an anti-resonance, where the sensor and the actuator are
    not collocated, the error does not vanish with ``G`` and ``kappa`` is the
    smoother one.  The pairs decide, locally: each interior pair predicted from
    its neighbours (`_leave_one_out`) by either interpolation, in units of its
    stated variance; a point takes the one that predicts the two pairs either
    side of it better, and the difference between the two interpolations joins
    its systematic error (the choice is uncertain by that much).  On demo20's
    rig spinning at 2132 rpm, noise-free, the MIMO elements' zero-amplitude
    errors at the steps either side of the first bending mode fell from 6.5 and
    2.7 % of ``G`` to 2.3 and 0.9 % (`tests/test_floor.py`).  Beyond the thesis.

    Returns
    -------
    numpy.ndarray of bool
        Per point; False at the repeated points (they have their own value), beyond the end pairs, and throughout
        where ``values`` are not finite or vanish at a pair.
    """
    relative = np.zeros(log_frequency.size, dtype=bool)
    x, at_pairs = log_frequency[repeated], values[repeated]
    if x.size < 3 or not (np.all(np.isfinite(values)) and np.all(np.abs(at_pairs) > 0)):
        return relative
    scores = []
    for basis in (np.ones(at_pairs.size), at_pairs):
        # (the ratio is the same in the coefficient's own units: residual and variance both scale by the pair's basis)
        _, residual, stated = _leave_one_out(x, coefficient / basis, variance / np.abs(basis) ** 2)
        score = np.abs(residual) ** 2 / stated
        scores.append(np.concatenate([score[:1], score, score[-1:]]))  # the end pairs: their interior neighbour's
    left, right, _ = bracket
    relative = scores[1][left] + scores[1][right] < scores[0][left] + scores[0][right]
    # beyond the end pairs there is one pair, nothing to interpolate between: the coefficient is taken as it is
    relative &= (log_frequency > x[0]) & (log_frequency < x[-1])
    relative[repeated] = False
    return relative


def _mimo_inversion_errors(channels, values, arrays, input_coupling=0.0):
    """The describing function's error in every MIMO element, from the four diagonal elements' measured dependence.

    The run exciting axis ``r`` measures the plant at its own amplitudes: the
    force law changes that bearing's coefficients (``k_i`` at the excitation
    current, ``k_x`` at its air-gap change), and with ``G = C (Z - B K_x
    B^T)^-1 B K_i`` both change the run's plant by a rank-one term in the column
    ``G[:, r]`` (collocated or not).  `ambid.frf.mimo_etfe`'s ``P = V U^-1``
    combines the runs, so::

        P = G (I + C W),   C = diag(c_r),   W = U^-1

    Column ``e`` of the error is not a scaling of column ``e``: run ``r``'s error
    leaks into it through ``W[r, e]``, the controller's currents at the other
    bearing in run ``e``.  At the cross element ``G[j, e]``, ten times smaller
    than ``G[j, j]`` on hs_eden_like, that leak is half its error (mostly a phase:
    +0.4 % in quadrature beside -1 to -2 % in phase at 60-200 Hz).  The four
    diagonal elements' relative errors ``delta_e`` (their pairs, interpolated)
    give ``c``, ``diag(G) = diag(P) / (1 + delta)``: to first order
    ``delta_e = sum_r P[e, r] W[r, e] c_r / P[e, e]``, four equations per step,
    then Newton steps on that Jacobian to the exact solution (the first order
    leaves ``delta^2``, 4e-4 of each element, coherent over a band: on demo20's
    rig without a hidden effect it made a 0.09 mm noncollocation the lead at 32
    chi2 units); and ``c`` gives every element.  ``W`` is the measured one, and
    the noise the diagonals' ``delta`` carry propagates to first order.

    With an ``input_coupling`` ``c`` (`ambid.effects.CrossCoupling` on the input
    side: the force-producing currents are ``K = I + c (E_xy + E_yx)`` times the
    commands) the force law changes run ``r``'s force current at axis ``r``, so
    its error is ``G K^-1 e_r`` and not ``G e_r``: ``P = G (I + K^-1 C W)``.  At an
    x-y element, which the coupling makes (``~ c G_xx``), the difference is as
    large as its whole error: on demo20's rig with ``c`` = 0.03 the prediction
    without it is 0.4 % of the element off, and the suite's input couplings read
    1-2 % high, up to 9.7 standard deviations (stop 52).  The FRF stage does not
    know ``c``; `zero_amplitude` states how the zero-amplitude values move with it.

    At a step where a diagonal's ``delta`` is uncertain beyond `LINEAR_DELTA`
    the first order does not hold, and the error is NaN there: between two pairs
    beside an anti-resonance of DX/DX, on a hs_eden_like rig without a hidden
    effect (seed 2056, 579 Hz), its interpolated ``delta`` was -1.05 +- 0.98 +- 1.2
    (the pair's own -0.015), and the predicted error of DX/NX 60 times the true one,
    20 times its stated error; no other cell of that log was above the floor.

    Returns
    -------
    dict
        ``("mimo", output, input) -> (error, variance, systematic)`` at the element's rows (`level_pairs`
        order): the absolute error ``P - G``, its noise variance (the diagonals' propagated) and its systematic
        error (the diagonals' interpolation error, propagated), NaN at the steps beyond `LINEAR_DELTA`; empty where
        the four diagonals are not all repeated on one grid, none of them measures its dependence, or the matrices
        are not finite.
    """
    axes = list(RADIAL_AXES)
    keys = [[("mimo", o, i) for i in axes] for o in axes]
    if not all(key in channels for row in keys for key in row) or not all(a in arrays for a in axes):
        return {}
    diagonal = [channels[keys[e][e]] for e in range(len(axes))]
    frequency = diagonal[0]["frequency"]
    if not any(d["measured"] for d in diagonal) or not all(
            np.array_equal(channels[key]["frequency"], frequency) for row in keys for key in row):
        return {}
    plant = np.stack([np.stack([values[channels[key]["rows"]] for key in row], axis=-1) for row in keys], axis=1)
    grid = arrays[axes[0]][0]
    at = np.clip(np.searchsorted(grid, frequency), 0, grid.size - 1)
    inputs = run_matrix(arrays, "U2", axes)[at]
    diagonal_plant = np.einsum("nee->ne", plant)
    if not (np.all(np.isfinite(plant)) and np.all(np.isfinite(inputs)) and np.all(diagonal_plant != 0)):
        return {}
    inverse = np.linalg.inv(inputs)  # W (n, run, column)
    delta = np.stack([d["correction"] for d in diagonal], axis=1)
    delta_variance = np.stack([d["correction_variance"] for d in diagonal], axis=1)
    delta_systematic = np.stack([d["relative_error"] for d in diagonal], axis=1)
    identity = np.eye(len(axes))
    to_force = np.linalg.inv(identity + input_coupling * np.kron(np.eye(2), [[0.0, 1.0], [1.0, 0.0]]))  # K^-1
    along_runs = plant @ to_force  # P K^-1: run r's error lies along its column r
    jacobian = np.einsum("ner,nre->ner", along_runs, inverse) / diagonal_plant[:, :, None]  # delta = jacobian @ c
    try:
        solve = np.linalg.inv(jacobian)
        column = np.einsum("ned,nd->ne", solve, delta)
        for _ in range(4):
            linearized = plant @ np.linalg.inv(identity + to_force @ (column[:, :, None] * inverse))
            column -= np.einsum("ned,nd->ne", solve, diagonal_plant / np.einsum("nee->ne", linearized) - 1 - delta)
        error = plant - plant @ np.linalg.inv(identity + to_force @ (column[:, :, None] * inverse))
    except np.linalg.LinAlgError:
        return {}
    if not np.all(np.isfinite(error)):
        return {}
    # E[o, e] = sum_r (P K^-1)[o, r] W[r, e] c_r to first order: the squared sensitivity of E[o, e] to each diagonal's
    # delta_d
    weight = np.abs(np.einsum("nor,nre,nrd->noed", along_runs, inverse, solve)) ** 2
    variance = np.einsum("noed,nd->noe", weight, delta_variance)
    systematic = np.sqrt(np.einsum("noed,nd->noe", weight, delta_systematic**2))
    beyond = np.any(delta_variance + delta_systematic**2 > LINEAR_DELTA**2, axis=1)
    error[beyond], variance[beyond], systematic[beyond] = np.nan, np.nan, np.nan
    return {keys[o][e]: (error[:, o, e], variance[:, o, e], systematic[:, o, e])
            for o in range(len(axes)) for e in range(len(axes)) if o != e}


def _structured_zero(channel, inversion, measured, noise):
    """A MIMO cross element at zero amplitude from `_mimo_inversion_errors`, tested against its own pairs, or None.

    Its own pairs measure ``G(A) - G_0 = lambda (G(A) - G(A_1))``, too noisy to
    extrapolate it by themselves but enough to refute the diagonals' prediction:
    where they depart from it by more than `MEASURED_KAPPA` standard deviations
    (`amplitude_dependence`) it is not used (None); where they depart by more
    than `DEPARTURE` standard deviations, their rms departure beyond their noise,
    as a fraction of the predicted error, joins its systematic error (that fraction
    of the error at every step).  Below that the departure is their noise: counted,
    it stated the cross elements of hs_eden_like's default run at chi2 per point
    0.25-0.39.  An element whose response is inside its noise at every repeated step
    (`ambid.floor.RESOLVED`) keeps the old path: its pairs are ratios of noise.  One
    that stands out of it somewhere does not, even where its median does not: demo20's
    gyroscopic cross elements at 2132 rpm stand out only near the first bending mode,
    where the old path kept their measured values, 5 % off with 1.6 % noise and no
    floor (the channel's median was inside its noise), and the suite's gyroscopic
    speed read 2 % low at 8.9 standard deviations.

    Returns
    -------
    tuple or None
        ``(zero, noise, systematic)`` at the channel's rows, NaN where there is no prediction (`LINEAR_DELTA`);
        ``noise`` is the prediction's only (the measured point's adds to it).
    """
    repeated = channel["repeated"]
    if inversion is None or not np.any(np.abs(measured[repeated]) > RESOLVED * noise[repeated]):
        return None
    error, variance, systematic = inversion
    predicted = np.isfinite(error[repeated])
    if not predicted.any():
        return None
    difference = (channel["pair_change"] - error[repeated])[predicted]
    expected = (channel["pair_change_variance"] + variance[repeated])[predicted]
    significance = amplitude_dependence(difference, expected)
    if significance > MEASURED_KAPPA:
        return None
    # the prediction's own error, as a fraction of it (a model of the force law's change errs in proportion to what it
    # predicts; a ratio of sums, so a pair where the element or its error passes near zero does not decide it)
    beyond = float(np.sum(np.abs(difference) ** 2 - expected)) if significance > DEPARTURE else 0.0
    departure = np.sqrt(max(0.0, beyond) / max(float(np.sum(np.abs(error[repeated][predicted]) ** 2)), 1e-300))
    return measured - error, np.sqrt(variance), np.hypot(systematic, departure * np.abs(error))


def zero_amplitude(table, low_table, arrays, low_arrays, noise_scale=None, settings=None, max_ratio=0.9):
    """The FRF table at zero excitation amplitude: every point of a channel whose amplitude dependence is measured, else
    where that estimate is the more accurate one.

    Parameters
    ----------
    table : pandas.DataFrame
        `ambid.frf.frf_table` of the level-0 steps with ``std`` and ``systematic_std``
        (`ambid.floor.systematic_floor`).
    low_table : pandas.DataFrame
        `ambid.frf.frf_table` of the level-1 repeats (the same estimators).
    arrays, low_arrays : dict
        `ambid.frf.log_arrays` of both levels (the excitation amplitudes).
    noise_scale : array, optional
        Per row of ``table``: the factor `ambid.floor.systematic_floor` scaled its
        noise by (the scatter between steps); the repeats' noise takes the same.
    settings : ambid.floor.FloorSettings, optional
        ``min_pairs`` (the repeated steps a channel needs), and how the noise was
        pooled (``noise_half_width``) and scaled (``scatter_half_width``,
        ``smooth_half_width``), for the rows' ``effective_share``.
    max_ratio : float
        Pairs whose amplitudes' squared ratio ``A_1^2 / A^2`` exceeds this carry
        no information on the amplitude dependence and are left out.

    Returns
    -------
    table : pandas.DataFrame
        A copy; rows that take the zero-amplitude estimate have it in ``re``,
        ``im``, ``std`` (propagated noise) and ``systematic_std`` (interpolation
        error; 0 at repeated steps), its ``effective_share`` (`effective_share`:
        the steps between two pairs share their noise) and its ``variance_error``
        (``sum_j c_ij``: the variance of its stated variance's relative error with
        the covariances of the other points' that share it, what a cell's chance
        limit takes its noise estimate's degrees of freedom from); the others keep
        the table's (`measured_variance_errors`, which `ambid.frf.frf_from_log`
        states first).  A MIMO cross element that took the
        diagonals' prediction (`_structured_zero`) states in
        ``input_coupling_slope_re`` / ``_im`` how its value moves per unit input
        cross coupling (`_mimo_inversion_errors`), what a model with one reads it
        at (`ambid.compare.at_input_coupling`); 0 elsewhere.
    extrapolated : numpy.ndarray of bool
        Which rows took it.
    """
    table = table.copy()
    settings = settings or FloorSettings()
    extrapolated = np.zeros(len(table), dtype=bool)
    if low_table is None or low_table.empty:
        return table, extrapolated
    square = excitation_amplitude_squared(table, arrays)
    low_square = excitation_amplitude_squared(low_table, low_arrays)
    values = table["re"].to_numpy() + 1j * table["im"].to_numpy()
    low_values = low_table["re"].to_numpy() + 1j * low_table["im"].to_numpy()
    noise, systematic = table["std"].to_numpy(), table["systematic_std"].to_numpy()
    low_noise = low_table["std"].to_numpy()
    scale = np.ones(len(table)) if noise_scale is None else np.asarray(noise_scale, dtype=float)
    frequency_all = table["frequency_hz"].to_numpy()
    new_values, new_noise, new_systematic = values.copy(), noise.copy(), systematic.copy()
    shares = (table["effective_share"].to_numpy(dtype=float, copy=True) if "effective_share" in table
              else np.ones(len(table)))
    variance_errors = (table["variance_error"].to_numpy(dtype=float, copy=True) if "variance_error" in table
                       else np.zeros(len(table)))
    channels = {}
    for key, (rows, repeated, low) in level_pairs(table, low_table, square, low_square, max_ratio).items():
        if repeated.size < settings.min_pairs:
            continue
        frequency, high = frequency_all[rows], rows[repeated]
        lever = 1.0 / (1.0 - low_square[low] / square[high])  # lambda = A^2 / (A^2 - A_1^2)
        g, g1 = values[high], low_values[low]
        s, s1 = noise[high], low_noise[low] * scale[high]
        zero_repeated = g - lever * (g - g1)
        # the amplitude coefficient kappa = (G(A) / G_0 - 1) / A^2 of each pair: smooth in frequency whatever the
        # (adaptive) amplitude of each step, so it is what the steps between the pairs interpolate
        kappa = (g / zero_repeated - 1) / square[high]
        variance = (lever / square[high]) ** 2 * np.abs(g1 / zero_repeated) ** 2 * ((s / np.abs(g)) ** 2 + (s1 / np.abs(g1)) ** 2)
        # the pairs' scatter decides whether the dependence is measured; where it is not, the scatter is their noise
        factor = pair_noise_factor(np.log(frequency[repeated]), kappa, variance)
        measured = amplitude_dependence(kappa, variance * factor) > MEASURED_KAPPA
        if not measured:
            variance, s, s1 = variance * factor, s * np.sqrt(factor), s1 * np.sqrt(factor)
        x, g_all = np.log(frequency), values[rows]
        bracket = _bracket(x, repeated)
        k, k_variance, k_error = _interpolated(x, repeated, kappa, variance, bracket)
        relative = _follows_response(x, repeated, kappa, variance, g_all, bracket)
        if relative.any():
            # where the two interpolations disagree, the pairs' choice between them is uncertain by that much
            followed, followed_variance, followed_error = _interpolated(x, repeated, kappa, variance, bracket, g_all)
            followed_error = np.hypot(followed_error, np.abs(followed - k))
            k, k_variance, k_error = (np.where(relative, a, b) for a, b in zip(
                (followed, followed_variance, followed_error), (k, k_variance, k_error)))
        a2 = square[rows]
        # a resonance between the pairs: the interpolated coefficient misses it by about |r - 1| times itself (one
        # interpolated relative to G follows it where the pairs chose well, but beside a peak that choice is uncertain:
        # on demo20's rig with an amplifier lag, 1 % off one step above the first bending mode where the coefficient
        # itself was 0.5 % off, so the term is kept)
        ratio = resonance_ratio(frequency, np.abs(g_all), frequency[repeated])
        relative_error = np.hypot(k_error, np.abs(k) * np.abs(ratio - 1)) * a2
        k_variance[repeated] = variance  # the pairs' own: `_mimo_inversion_errors` reads it, their own value does not
        # each pair's level-0 and level-1 noise (unit sources xi, eta) in its coefficient, delta kappa = (z dg - g dz)
        # / (z^2 A^2) = lambda (g1 dg - g dg1) / (z^2 A^2), and in its own zero-amplitude value, (1 - lambda) dg
        # + lambda dg1
        to_kappa = lever / (zero_repeated**2 * square[high])
        channels[key] = dict(
            rows=rows, frequency=frequency, repeated=repeated, measured=measured,
            bracket=bracket, relative=relative, values=g_all, amplitude_squared=a2,
            kappa_sources=np.stack([to_kappa * g1 * s, -to_kappa * g * s1], axis=1),
            zero_sources=np.stack([(1 - lever) * s, lever * s1], axis=1),
            correction=k * a2, correction_variance=k_variance * a2**2, relative_error=relative_error,
            zero_repeated=zero_repeated, zero_repeated_noise=np.sqrt((lever - 1) ** 2 * s**2 + lever**2 * s1**2),
            pair_change=lever * (g - g1), pair_change_variance=lever**2 * (s**2 + s1**2))
    inversion = _mimo_inversion_errors(channels, values, arrays)
    stepped = _mimo_inversion_errors(channels, values, arrays, input_coupling=COUPLING_STEP) if inversion else {}
    slopes = np.zeros(len(table), dtype=complex)
    for key, channel in channels.items():
        rows, repeated = channel["rows"], channel["repeated"]
        structured = _structured_zero(channel, inversion.get(key), values[rows], noise[rows])
        # its own pairs' extrapolation: the channel's, or where the diagonals' prediction says nothing
        g_all = channel["values"]
        zero = g_all / (1 + channel["correction"])
        zero_noise = np.sqrt(noise[rows] ** 2 * np.abs(_own_gain(channel)) ** 2
                             + channel["correction_variance"] * np.abs(zero) ** 2)
        zero_systematic = channel["relative_error"] * np.abs(zero)
        zero[repeated], zero_noise[repeated] = channel["zero_repeated"], channel["zero_repeated_noise"]
        zero_systematic[repeated] = 0.0
        own = np.ones(rows.size, dtype=bool)
        if structured is not None:
            own = ~np.isfinite(structured[0])
            predicted = (structured[0], np.hypot(noise[rows], structured[1]), structured[2])
            zero, zero_noise, zero_systematic = (np.where(own, a, b) for a, b in zip(
                (zero, zero_noise, zero_systematic), predicted))
            if key in stepped:  # the zero-amplitude value is the measured one less the error: it moves against it
                slopes[rows] = np.where(own, 0.0, -(stepped[key][0] - inversion[key][0]) / COUPLING_STEP)
        if channel["measured"] or structured is not None:
            better = np.ones(rows.size, dtype=bool)
        else:
            measured_error = noise[rows] ** 2 + np.nan_to_num(systematic[rows]) ** 2
            better = zero_noise**2 + zero_systematic**2 < measured_error
        chosen = rows[better]
        new_values[chosen], new_noise[chosen], new_systematic[chosen] = zero[better], zero_noise[better], zero_systematic[better]
        extrapolated[chosen] = True
        sharing = better & own  # (the rows its own pairs extrapolate; a row left as measured keeps its share)
        if sharing.any():
            shared, alone, estimate = _shared_errors(channel, sharing, zero, noise[rows], zero_systematic, scale[rows],
                                                     settings)
            shares[rows[sharing]] = effective_share(shared, alone, estimate)[sharing]
            variance_errors[rows[sharing]] = estimate.sum(axis=1)[sharing]
    table["re"], table["im"] = new_values.real, new_values.imag
    table["std"], table["systematic_std"] = new_noise, new_systematic
    table["effective_share"], table["variance_error"] = shares, variance_errors
    table["input_coupling_slope_re"], table["input_coupling_slope_im"] = slopes.real, slopes.imag
    return table, extrapolated


def _shared_errors(channel, chosen, zero, noise, systematic, noise_scale, settings):
    """What one channel's points at zero amplitude share: their errors, and the errors of their stated noise.

    A step between two pairs takes their interpolated coefficient, ``(1 - w)
    kappa_L + w kappa_R`` (``(1 - w) kappa_L G / G_L + w kappa_R G / G_R`` where it
    follows the response, `_follows_response`), and with it their noise: ``dG_0 =
    dG / (1 + c) - G_0 A^2 ((1 - w) d kappa_L + w d kappa_R)`` (the same factors);
    a repeated step's own value shares
    its pair's.  Points that keep their measured value (not ``chosen``) share
    nothing of that.  The stated variance of every point is a sum of the steps'
    noise estimates (`ambid.floor.pooled_noise`: each `NOISE_DOF` degrees of
    freedom, the mean over ``2 half_width + 1`` neighbours of its level), so
    points whose variances draw on one estimate share its error too, and so do
    the points whose noise `ambid.floor.systematic_floor` scaled down to the
    scatter of the neighbouring steps (``noise_scale`` below 1: a mean of
    `ambid.floor.smooth_fit_ratio`'s ``|r_k|^2 / s_k^2`` over ``2
    scatter_half_width + 1`` steps, of relative variance 1 each, and two of them
    covary by ``|rho|^2`` of their residuals, which overlapping local fits
    correlate, and by their noise estimates).

    Returns
    -------
    shared : numpy.ndarray
        ``(n, 2 p)`` complex: each point's error in the ``p`` pairs' level-0 and level-1 noise (unit sources).
    alone : numpy.ndarray
        ``(n,)``: the standard deviation of what is each point's own (its noise, its systematic error).
    estimate : numpy.ndarray
        ``(n, n)``: the covariance of the points' stated variances' relative errors.
    """
    left, right, weight = channel["bracket"]
    repeated, sources, relative, values = (channel[k] for k in ("repeated", "kappa_sources", "relative", "values"))
    n, pairs = zero.size, sources.shape[0]
    points = np.arange(n)
    scale = -zero * channel["amplitude_squared"]
    shared = np.zeros((n, pairs, 2), dtype=complex)
    # a point interpolating kappa / G (`_follows_response`) takes kappa_L G / G_L
    to_left = np.where(relative, values / values[repeated][left], 1.0)
    to_right = np.where(relative, values / values[repeated][right], 1.0)
    shared[points, left] += ((1 - weight) * scale * to_left)[:, None] * sources[left]
    shared[points, right] += (weight * scale * to_right)[:, None] * sources[right]
    own = np.abs(noise * _own_gain(channel)) ** 2
    own[repeated] = 0.0
    shared[repeated] = 0.0
    shared[repeated, np.arange(pairs)] = channel["zero_sources"]
    own[~chosen], shared[~chosen] = noise[~chosen] ** 2, 0.0
    # each point's variance in the level-0 estimates (at every step) and the level-1 ones (at every pair)
    level0, level1 = np.diag(own), np.zeros((n, pairs))
    level0[:, repeated] += np.abs(shared[:, :, 0]) ** 2
    level1 += np.abs(shared[:, :, 1]) ** 2
    variance = level0.sum(axis=1) + level1.sum(axis=1) + systematic**2
    variance = np.where(variance > 0, variance, 1.0)
    level0, level1 = level0 / variance[:, None], level1 / variance[:, None]
    half_width = settings.noise_half_width
    pooled = _pooled_covariance(n, half_width)
    estimate = level0 @ pooled @ level0.T + level1 @ _pooled_covariance(pairs, half_width) @ level1.T
    # the scale: a running mean of the ratios |r_k|^2 / s_k^2 of the steps whose local fit is centred on them; two
    # ratios covary by |rho_kl|^2 of their residuals (overlapping fits) and by their noise estimates
    centred = np.zeros(n)
    centred[settings.smooth_half_width: n - settings.smooth_half_width] = 1.0
    mean = (np.abs(np.subtract.outer(points, points)) <= settings.scatter_half_width) * centred[None, :]
    mean /= np.maximum(mean.sum(axis=1, keepdims=True), 1.0)
    fits = np.zeros((n, n))
    for k, (window, j, hat) in enumerate(local_fits(channel["frequency"], settings.smooth_half_width)):
        fits[k, window] = -hat
        fits[k, k] += 1.0
    residual = fits @ fits.T
    spread = np.sqrt(np.clip(residual.diagonal(), 1e-300, None))
    ratios = (residual / spread[:, None] / spread[None, :]) ** 2 + pooled
    scale_covariance = mean @ ratios @ mean.T
    # the scale is the mean clipped at 1: a mean near 1 is clipped as often as not, and its error with it; each point's
    # noise share counts as often as its mean, normal about the scale squared, falls below 1
    below = scipy.special.ndtr((1 - noise_scale**2) / np.sqrt(np.clip(scale_covariance.diagonal(), 1e-300, None)))
    scaled = np.sqrt(below) * (noise_scale < 1) * (level0.sum(axis=1) + level1.sum(axis=1))
    estimate += np.outer(scaled, scaled) * scale_covariance
    return shared.reshape(n, 2 * pairs), np.hypot(np.sqrt(own), systematic), estimate


def _own_gain(channel):
    """``dG_0 / dG`` of each step's zero-amplitude value ``G / (1 + c)`` in its own measured value's noise.

    ``1 / (1 + c)``; where the correction follows the response (``c = q A^2 G``, `_follows_response`), ``1 / (1 +
    c)^2``.
    """
    gain = 1.0 / (1 + channel["correction"])
    return np.where(channel["relative"], gain**2, gain)


def _pooled_covariance(steps, half_width):
    """Covariance of the relative errors of `ambid.floor.pooled_noise`'s variances along ``steps`` steps of one level.

    Each pooled variance is the mean of the ``W`` estimates of its window
    (`ambid.floor.pool_windows`), each of `NOISE_DOF` degrees of freedom (relative
    variance ``2 / NOISE_DOF``); two windows whose starts are ``d`` apart share
    ``W - d`` of them.
    """
    starts, window = pool_windows(steps, half_width)
    distance = np.abs(np.subtract.outer(starts, starts))
    return (2.0 / NOISE_DOF) * np.clip(window - distance, 0, None) / window**2


def effective_share(shared, alone, estimate=None):
    """Each point's share of an independent point at the floor: ``1 / sum_j (|rho_ij|^2 + c_ij)``.

    A cell's ``chi2 = sum |e_i|^2 / s_i^2`` over points whose errors correlate
    (``rho``) and whose stated variances ``s^2`` are estimates with correlated
    relative errors (covariance ``c``) has the mean of ``n`` independent points
    and, to first order, the variance ``sum_ij (|rho_ij|^2 + c_ij)``:
    Satterthwaite's ``n_eff = n^2 / sum_ij (...)`` independent points.  A point's
    share counts the points whose noise or noise estimate it shares, so a cell's
    effective points are the sum of its points' shares (exact where points share
    in blocks).  Beyond the thesis.

    Parameters
    ----------
    shared : numpy.ndarray
        ``(n, m)`` complex: each point's error in ``m`` independent unit sources.
    alone : numpy.ndarray
        ``(n,)``: the standard deviation of each point's error that no other point shares.
    estimate : numpy.ndarray, optional
        ``(n, n)``: covariance of the relative errors of the points' stated variances (none: known variances).

    Returns
    -------
    numpy.ndarray
        ``(n,)`` in ``(0, 1]``; 1 where a point shares nothing and its variance is known.
    """
    covariance = shared @ shared.conj().T
    variance = covariance.diagonal().real + np.asarray(alone, dtype=float) ** 2
    covariance[np.diag_indices_from(covariance)] = variance
    scale = np.sqrt(np.where(variance > 0, variance, 1.0))
    correlation = np.abs(covariance / scale[:, None] / scale[None, :]) ** 2
    correlation[np.diag_indices_from(correlation)] = 1.0
    if estimate is not None:
        correlation += estimate
    return 1.0 / correlation.sum(axis=1)


def measured_variance_errors(table, settings=None):
    """Every row's ``effective_share`` and ``variance_error`` as measured: its stated variance is an estimate.

    A row's noise is the mean of its window's noise estimates
    (`ambid.floor.pooled_noise`, each `NOISE_DOF` degrees of freedom), which the
    points of a channel share.  A cell's chance limit reads its noise estimates'
    degrees of freedom from these (`ambid.diagnose.chance_limit`: Fisher's F,
    not the Gamma of known variances); `zero_amplitude` states them for the
    rows it extrapolates and leaves the others with these.

    The scale to the scatter between neighbouring steps
    (`ambid.floor.systematic_floor`) is not counted here (`zero_amplitude`
    counts it for the rows it extrapolates): it is measured from the same
    steps' noise that a measured row's misfit holds, so it normalizes that
    misfit rather than adding an error of its own.  Over 40 no-effect logs of
    each default machine (`bench_extrapolation.py --cells`, stop 55), the
    coil-current cells, whose noise is scaled to a twentieth, spread as 41-154
    independent points (of 26-169); counted with the scale's error they stated
    14-44, as known variances 26-169; with the pooling alone they state at most
    ``n / 1.5`` of their ``n`` (17-113).  Until stop 55 rows as measured counted
    as known variances, and a demo20 negative control (seed 2114) read
    "unexplained" for its 57-point coil-current band at 1.55 against 1.5 (its
    limit with the pooled estimates' 219 degrees of freedom: 1.61).

    Parameters
    ----------
    table : pandas.DataFrame
        `ambid.frf.frf_table` with ``std`` and ``systematic_std`` (`ambid.floor.systematic_floor`).
    settings : ambid.floor.FloorSettings, optional
        How the noise was pooled.

    Returns
    -------
    pandas.DataFrame
        A copy with ``variance_error`` ``e = sum_j c_ij`` (`_pooled_covariance`, each row weighted by the noise's
        share of its variance) and ``effective_share`` ``1 / (1 + e)`` (`effective_share`) on every row.
    """
    settings = settings or FloorSettings()
    noise = table["std"].to_numpy(dtype=float)
    systematic = np.nan_to_num(table["systematic_std"].to_numpy(dtype=float))
    frequency = table["frequency_hz"].to_numpy(dtype=float)
    shares, errors = np.ones(len(table)), np.zeros(len(table))
    for rows in table.groupby(["estimator", "output", "input"], sort=False).indices.values():
        rows = rows[np.argsort(frequency[rows], kind="stable")]
        variance = noise[rows] ** 2 + systematic[rows] ** 2
        noise_share = noise[rows] ** 2 / np.where(variance > 0, variance, 1.0)
        estimate = noise_share[:, None] * _pooled_covariance(rows.size, settings.noise_half_width) * noise_share[None, :]
        errors[rows] = estimate.sum(axis=1)
        shares[rows] = effective_share(np.zeros((rows.size, 0)), np.ones(rows.size), estimate)
    return table.assign(effective_share=shares, variance_error=errors)


def account_zero_amplitude(floors, table, extrapolated):
    """`ambid.floor.systematic_floor`'s account per family and band, after `zero_amplitude`.

    Adds ``zero_amplitude_points`` (rows that took the extrapolated value) and
    ``zero_amplitude`` to ``method`` where there are any, and recomputes the
    relative systematic error's median and p90, and the relative noise's median, over the band's rows as they are now.
    """
    floors = floors.copy()
    floors["zero_amplitude_points"] = 0
    if floors.empty:
        return floors
    families = np.array([family_of(e, o, i) for e, o, i in zip(table["estimator"], table["output"], table["input"])])
    frequency = table["frequency_hz"].to_numpy()
    magnitude = np.hypot(table["re"], table["im"]).to_numpy()
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # (a row reading 0 has no relative error)
        relative = np.where(magnitude > 0, table["systematic_std"].to_numpy() / magnitude, np.nan)
    noise = table["std"].to_numpy() if "noise_relative_median" in floors else None
    for k, row in floors.iterrows():
        inside = (families == row["family"]) & (frequency >= row["band_lo_hz"]) & (frequency < row["band_hi_hz"])
        count = int(np.count_nonzero(inside & extrapolated))
        if count == 0:
            continue
        floors.loc[k, "zero_amplitude_points"] = count
        floors.loc[k, "method"] = row["method"] + " + zero_amplitude"
        values = relative[inside]
        values = values[np.isfinite(values)]
        floors.loc[k, "relative_median"] = float(np.median(values)) if values.size else np.nan
        floors.loc[k, "relative_p90"] = float(np.quantile(values, 0.9)) if values.size else np.nan
        if noise is not None:  # the extrapolated points carry the noise their extrapolation propagates
            floors.loc[k, "noise_relative_median"] = noise_relative_median(magnitude, noise, inside)
    return floors
