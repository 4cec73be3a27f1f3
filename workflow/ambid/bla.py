"""The best linear approximation (BLA) of a nonlinear plant from periodic multisines, with noise and distortion.

Pintelon & Schoukens (*System Identification: A Frequency Domain Approach*,
2nd ed., 2012, sec. 3.4-3.7, "robust method"): for every excited line ``k``,
realization ``m`` and experiment ``e`` the logged per-period spectra of the
plant inputs ``U`` (the control currents U2 of the excited group's axes) and
outputs ``Y`` (their positions V2, or coil currents) are averaged over the P
periods, ``U_m = mean_p U_mp``, and with the E experiments as columns::

    G_m = Y_m U_m^+          (U^+ = U^H (U U^H)^-1: P = V U^-1 of thesis eq. 4.1 for E = n)

* **Noise** (from the periods): the equation error of each period,
  ``Y_mp - G_m U_mp``, scatters only by the noise (in the closed loop the
  noise of U and Y is correlated: the controller feeds the sensor noise back;
  the equation error is what the ratio sees), so the noise variance of
  ``G_m`` is ``sum_e |W_eb|^2 var_p(e_ae) / P`` with ``W = U_m^+``.
* **BLA** ``G = mean_m G_m``; its noise variance ``sigma_n^2 = sum_m
  sigma_n,m^2 / R^2``; its total variance from the realizations ``sigma^2 =
  var_m(G_m) / R``; the stochastic nonlinear distortion's share
  ``max(sigma^2 - sigma_n^2, 0)``, and its level in one realization
  ``sigma_S^2 = R max(sigma^2 - sigma_n^2, 0)`` (eq. 3.50-3.53).

* **Level dependence** (sec. 3.5): the BLA depends on the excitation's power
  spectrum.  For an AMB the force law's position stiffness grows with the
  mean-square coil current, so every line's rms current biases the BLA at
  low frequencies, and near a lightly damped resonance the smallest shift
  shows: a deterministic error the scatter of same-level realizations cannot
  see.  With realizations at a lower relative level ``l`` (`ambid.multisine`
  ``levels``) the change ``B = (G - G_l) / (1 - l^2)`` measures it (`_combine`).
* **The level, recorded** (`excitation_covariance`): each axis' coil-current and
  position variances and covariance at the top level, which the force law is
  averaged over: the model compared with the BLA is linearized there
  (`ambid.effects.at_excitation_level`), since the BLA is not the small-signal
  plant.

The FRF table's ``std`` is the noise of the BLA at the top level (pooled over
neighbouring lines) and ``systematic_std`` the standard deviation of its
systematic (nonlinear) error: the level dependence's power (noise and the
stochastic distortion's scatter removed) plus ``sigma_S^2 / n``, or, with
one level only, ``sigma_S`` itself (the distortion's level stands for the BLA's
bias, of the same origin and order, sec. 3.4.3).  The comparison's
uncertainty ``hypot(std, systematic_std)`` then covers the nonlinear error
where a constant floor was needed before.

Even and odd distortion (sec. 4.2.7): the output at the odd random grid's
detection lines, above the noise, is the nonlinear distortion itself: at the
left-out odd lines the odd nonlinearity, at the even lines the even one
(`distortion_levels`).
"""

import numpy as np
import pandas as pd

from .errors import LogError
from .floor import band_labels, frequency_bands, pool_variance
from .frf import frf_table
from .logs import CHANNELS, COIL_CURRENT_CHANNELS, has_coil_currents
from .machine import ALL_AXES, AXIAL_AXIS, RADIAL_AXES
from .zoom import outside_bands

__all__ = ["GroupBLA", "group_bla", "pass_bla", "siso_bla", "distortion_levels", "merge_passes", "bla_frf_table",
           "multisine_passes", "multisine_frf", "line_levels", "realization_levels", "excitation_covariance",
           "DEFAULT_BANDS_HZ"]

DEFAULT_BANDS_HZ = (0.0, 10.0, 100.0, 300.0, 1000.0, np.inf)
_U2 = {a: CHANNELS.index(f"U2_{a}") for a in ALL_AXES}
_V2 = {a: CHANNELS.index(f"V2_{a}") for a in ALL_AXES}
_UPPER = {a: CHANNELS.index(f"I_upper_{a}") for a in ALL_AXES}
_LOWER = {a: CHANNELS.index(f"I_lower_{a}") for a in ALL_AXES}


_PER_LINE = ("frequency_hz", "plant", "noise_std", "distortion_std", "systematic_std", "current", "current_noise_std",
             "current_distortion_std", "current_systematic_std", "condition", "compliance")


class GroupBLA:
    """The BLA of one input group (radial or axial) of one pass at its excited lines.

    Attributes
    ----------
    axes : list of str
        Inputs (and outputs) in order.
    frequency_hz : array (L,)
    plant : complex array (L, n, n)
        BLA of V2 (rows) against U2 (columns) [m/A].
    noise_std, distortion_std, systematic_std : arrays (L, n, n)
        Noise standard deviation of the BLA; ``sigma_S``, the standard
        deviation of the stochastic nonlinear distortion of one realization
        (NaN with one realization at the top level); the standard deviation of
        the BLA's systematic error (`_combine`).
    current, current_noise_std, current_distortion_std, current_systematic_std : arrays (L, n, n)
        The same for the differential coil currents ``(I_upper - I_lower) / 2`` against U2 [A/A].
    condition : array (L,)
        Condition number of U (median over the realizations).
    compliance : array (L, n, n)
        Magnitude of the measured dynamic compliance E_u -> V2 (BLA over the
        realizations) [m/A]; NaN where the reference excitation is not logged.
    realizations : int
    levels : array
        The relative excitation levels of the realizations.
    """

    def __init__(self, **values):
        self.__dict__.update(values)


def _solve(outputs, inputs):
    """``Y U^+`` per line: outputs (L, n_out, E), inputs (L, n_in, E) -> (L, n_out, n_in) and ``W = U^+`` (L, E, n_in)."""
    gram = inputs @ np.conj(np.swapaxes(inputs, 1, 2))
    pseudo = np.conj(np.swapaxes(inputs, 1, 2)) @ np.linalg.inv(gram)
    return outputs @ pseudo, pseudo


def _per_realization(inputs, outputs, noise_half_width=0):
    """Per-realization estimates ``G_m`` and their noise variances from the periods.

    ``inputs`` (R, E, P, n_in, L), ``outputs`` (R, E, P, n_out, L) per-period spectra.
    The equation error's variance of each output and experiment is pooled over
    ``noise_half_width`` lines either side (`ambid.floor.pool_variance`): from P
    periods one line has ``2 (P - 1)`` degrees of freedom per experiment, too few
    for ``|e|^2 / s^2`` to average 1 (P = 2: the noise of an output changes
    smoothly from line to line, the weights ``|W|^2`` of each line stay its own).
    Returns ``G`` (R, L, n_out, n_in), ``noise_var`` (R, L, n_out, n_in), condition numbers (R, L).
    """
    realizations, _, periods = inputs.shape[:3]
    u_mean = inputs.mean(axis=2)  # (R, E, n_in, L)
    y_mean = outputs.mean(axis=2)
    estimates, noise, condition = [], [], []
    for m in range(realizations):
        u = np.transpose(u_mean[m], (2, 1, 0))  # (L, n_in, E)
        y = np.transpose(y_mean[m], (2, 1, 0))
        g, pseudo = _solve(y, u)
        # equation error of each period: (L, n_out, E, P)
        u_p = np.transpose(inputs[m], (3, 2, 0, 1))  # (L, n_in, E, P)
        y_p = np.transpose(outputs[m], (3, 2, 0, 1))
        error = y_p - np.einsum("loi,liep->loep", g, u_p)
        error_var = pool_variance(np.var(error, axis=3, ddof=1) / periods, noise_half_width)  # (L, n_out, E)
        noise.append(np.einsum("lei,loe->loi", np.abs(pseudo) ** 2, error_var))
        estimates.append(g)
        condition.append(np.linalg.cond(u))
    return np.array(estimates), np.array(noise), np.array(condition)


def realization_levels(reference):
    """Relative rms level of each realization's excitation (1 for the top level), rounded to 1e-3."""
    rms = np.sqrt(np.mean(np.abs(reference) ** 2, axis=tuple(range(1, reference.ndim))))
    return np.round(rms / np.max(rms), 3)


def _smooth_relative(excess, reference, half_width=2):
    """Mean over the neighbouring lines ``k - half_width .. k + half_width`` (those that exist) of
    ``excess / |reference|^2``, times ``|reference|^2`` (lines on the first axis)."""
    scale = np.maximum(np.abs(reference) ** 2, 1e-300)
    relative = excess / scale
    n = relative.shape[0]
    padded = np.concatenate([np.zeros((1,) + relative.shape[1:]), np.cumsum(relative, axis=0)])
    low = np.clip(np.arange(n) - half_width, 0, n)
    high = np.clip(np.arange(n) + half_width + 1, 0, n)
    count = (high - low).reshape((-1,) + (1,) * (relative.ndim - 1))
    return (padded[high] - padded[low]) / count * scale


def _combine(estimates, noise_var, levels):
    """The BLA at the top level, its noise variance and the variance of its systematic (nonlinear) error.

    Top level (``levels == 1``), ``n`` realizations: ``G = mean G_m``, noise
    ``sum sigma_m^2 / n^2``, stochastic distortion of one realization
    ``sigma_S^2 = n max(var_m(G_m) / n - noise, 0)`` (NaN for n = 1).
    With a lower level ``l`` the level dependence ``B = (G - G_l) / (1 - l^2)``
    (the BLA's deviation from the small-signal response, to first order in the
    level squared) is measured; its power with the scatter of noise and
    stochastic distortion (both levels) removed, averaged
    over 5 neighbouring lines relative to ``|G|`` (the line's own where it
    stands out of the noise: ``|B|^2 > 4 var B``), plus ``sigma_S^2 / n``, is
    the systematic variance.  Without a lower level the systematic variance is
    ``sigma_S^2``: the distortion's level stands for the BLA's deviation, which
    is of the same order (sec. 3.4).

    Returns
    -------
    plant, noise, distortion, systematic : arrays
        The BLA at the top level, its noise variance, ``sigma_S^2`` and the
        systematic variance.
    """
    top = levels >= 1.0 - 1e-9
    n = int(top.sum())
    plant = estimates[top].mean(axis=0)
    noise = noise_var[top].sum(axis=0) / n**2
    if n > 1:
        distortion = n * np.maximum(np.var(estimates[top], axis=0, ddof=1) / n - noise, 0.0)
    else:
        distortion = np.full(plant.shape, np.nan)
    lower = levels[~top]
    if lower.size == 0:
        return plant, noise, distortion, distortion
    level = lower.min()
    low = levels == level
    low_plant, low_noise = estimates[low].mean(axis=0), noise_var[low].sum(axis=0) / low.sum() ** 2
    lever = 1.0 / (1 - level**2)
    bias = (plant - low_plant) * lever
    # the stochastic distortion (level^2 smaller at the low level) scatters B as the noise does
    stochastic = np.nan_to_num(distortion)
    stochastic_share = 1.0 / n + level**4 / low.sum()
    bias_var = (noise + low_noise + stochastic_share * stochastic) * lever**2
    excess = np.abs(bias) ** 2 - bias_var
    # smoothed where the noise dominates; the line's own value where the level effect stands out
    # (a lightly damped resonance moving with the level: sharper than any smoothing window)
    significant = np.abs(bias) ** 2 > 4 * bias_var  # 2 % of pure-noise lines
    level_var = np.maximum(np.where(significant, np.maximum(excess, _smooth_relative(excess, plant)),
                                    _smooth_relative(excess, plant)), 0.0)
    systematic = level_var + (stochastic / n if n > 1 else 0.0)
    return plant, noise, distortion, systematic


def group_bla(spectra, reference, excites, frequency_hz, axes, noise_half_width=2):
    """The BLA of one input group at the lines that excite it.

    Parameters
    ----------
    spectra : complex array (R, E, P, 20, L)
        Per-period spectra of `ambid.logs.CHANNELS` at the stored lines.
    reference : complex array (R, E, 5, L)
        The excitation's complex amplitudes (0 where an axis is not excited).
    excites : bool array (L, 5)
        Axes excited at each line.
    frequency_hz : array (L,)
    axes : list of str
        The group's axes.
    noise_half_width : int
        Lines either side over which the noise is pooled (`_per_realization`;
        config ``frf.noise_half_width``).

    Returns
    -------
    GroupBLA or None
        None when no line excites every axis of the group.

    Raises
    ------
    LogError
        When the experiments cannot separate the group's inputs (fewer experiments than axes).
    """
    index = [ALL_AXES.index(a) for a in axes]
    lines = np.flatnonzero(excites[:, index].all(axis=1))
    if lines.size == 0:
        return None
    experiments = spectra.shape[1]
    if experiments < len(axes):
        raise LogError("multisine log", f"{experiments} experiment(s) cannot separate the {len(axes)} inputs {axes}")
    part = spectra[..., lines]
    u = part[:, :, :, [_U2[a] for a in axes]]
    v = part[:, :, :, [_V2[a] for a in axes]]
    current = 0.5 * (part[:, :, :, [_UPPER[a] for a in axes]] - part[:, :, :, [_LOWER[a] for a in axes]])
    levels = realization_levels(reference)
    estimates, noise, condition = _per_realization(u, v, noise_half_width)
    plant, noise_var, distortion_var, systematic_var = _combine(estimates, noise, levels)
    if np.isfinite(current).all():
        estimates, noise, _ = _per_realization(u, current, noise_half_width)
        amplifier, current_noise_var, current_distortion_var, current_systematic_var = _combine(estimates, noise, levels)
    else:  # a log without coil currents
        amplifier = np.full(plant.shape, np.nan + 0j)
        current_noise_var = current_distortion_var = current_systematic_var = np.full(plant.shape, np.nan)
    condition = np.median(condition[levels >= 1.0 - 1e-9], axis=0)
    # measured dynamic compliance E_u -> V2: the positions against the reference excitation
    r = reference[:, :, index][..., lines]  # (R, E, n, L)
    compliance = np.full(plant.shape, np.nan)
    if np.all(np.isfinite(r)) and np.all(np.abs(r).sum(axis=(0, 1)) > 0):
        estimates = [_solve(np.transpose(v[m].mean(axis=1), (2, 1, 0)), np.transpose(r[m], (2, 1, 0)))[0]
                     for m in range(r.shape[0])]
        compliance = np.abs(np.mean(estimates, axis=0))
    return GroupBLA(axes=list(axes), frequency_hz=np.asarray(frequency_hz)[lines], plant=plant,
                    noise_std=np.sqrt(noise_var), distortion_std=np.sqrt(distortion_var),
                    systematic_std=np.sqrt(systematic_var), current=amplifier,
                    current_noise_std=np.sqrt(current_noise_var), current_distortion_std=np.sqrt(current_distortion_var),
                    current_systematic_std=np.sqrt(current_systematic_var), condition=condition, compliance=compliance,
                    realizations=spectra.shape[0], levels=np.unique(levels))


def siso_bla(spectra, reference, excites, frequency_hz, axes, noise_half_width=2):
    """SISO BLA of a per-axis design: ``V2_j / U2_i`` in the experiment exciting axis i only (as the stepped sine).

    Returns
    -------
    dict
        ``(output, input) -> (frequency_hz, G, noise_std, distortion_std)``; empty when no experiment excites one axis alone.
    """
    out = {}
    active = np.abs(reference).sum(axis=(0, 3)) > 0  # (E, 5)
    for input_axis in axes:
        i = ALL_AXES.index(input_axis)
        alone = [e for e in range(active.shape[0]) if active[e, i] and active[e].sum() == 1]
        lines = np.flatnonzero(excites[:, i])
        if len(alone) != 1 or lines.size == 0:
            continue
        part = spectra[:, alone][..., lines]
        u = part[:, :, :, [_U2[input_axis]]]
        levels = realization_levels(reference)
        for output in axes:
            estimates, noise, _ = _per_realization(u, part[:, :, :, [_V2[output]]], noise_half_width)
            g, noise_var, _, systematic_var = _combine(estimates, noise, levels)
            out[(output, input_axis)] = (np.asarray(frequency_hz)[lines], g[:, 0, 0], np.sqrt(noise_var[:, 0, 0]),
                                         np.sqrt(systematic_var[:, 0, 0]))
    return out


def pass_bla(spectra, reference, excites, frequency_hz, design, noise_half_width=2):
    """Every estimate of one pass: radial MIMO group, axial group, SISO (per-axis designs).

    Returns
    -------
    dict
        ``radial``, ``axial``: `GroupBLA` or None; ``siso``: `siso_bla` of the radial axes.
    """
    excited_axes = [a for a in ALL_AXES if excites[:, ALL_AXES.index(a)].any()]
    radial = [a for a in RADIAL_AXES if a in excited_axes]
    out = {"radial": group_bla(spectra, reference, excites, frequency_hz, radial, noise_half_width) if radial else None,
           "axial": (group_bla(spectra, reference, excites, frequency_hz, [AXIAL_AXIS], noise_half_width)
                     if AXIAL_AXIS in excited_axes else None),
           "siso": (siso_bla(spectra, reference, excites, frequency_hz, radial, noise_half_width)
                    if design == "per_axis" else {})}
    return out


def merge_passes(coarse, zoom):
    """One FRF from a coarse and a zoom pass: the coarse lines the zoom covers give way (`ambid.zoom.outside_bands`).

    Parameters
    ----------
    coarse, zoom : GroupBLA or None

    Returns
    -------
    GroupBLA or None
        Lines in ascending frequency.
    """
    if zoom is None or coarse is None:
        return coarse if zoom is None else zoom
    keep = outside_bands(coarse.frequency_hz, zoom.frequency_hz)
    order = np.argsort(np.concatenate([coarse.frequency_hz[keep], zoom.frequency_hz]), kind="stable")
    merged = {name: np.concatenate([getattr(coarse, name)[keep], getattr(zoom, name)])[order] for name in _PER_LINE}
    return GroupBLA(axes=coarse.axes, realizations=min(coarse.realizations, zoom.realizations),
                    levels=np.union1d(coarse.levels, zoom.levels), **merged)


def _merge_siso(coarse, zoom):
    out = dict(coarse)
    for key, dense in zoom.items():
        if key not in out:
            out[key] = dense
            continue
        keep = outside_bands(out[key][0], dense[0])
        order = np.argsort(np.concatenate([out[key][0][keep], dense[0]]), kind="stable")
        out[key] = tuple(np.concatenate([a[keep], b])[order] for a, b in zip(out[key], dense))
    return out


def multisine_passes(frame):
    """The passes of a multisine log as arrays, in the log's order.

    Parameters
    ----------
    frame : pandas.DataFrame
        A validated multisine log (`ambid.logs.read_multisine_log`).

    Returns
    -------
    list of dict
        ``name``, ``lines``, ``frequency_hz``, ``role`` (L,), ``excites`` (L, 5:
        axes whose reference is non-zero), ``spectra`` (R, E, P, 20, L) and
        ``reference`` (R, E, 5, L), as `ambid.logs.multisine_frame` takes them;
        the coil currents NaN in a log without them (`ambid.logs.COIL_CURRENT_CHANNELS`, optional for a whole log).
    """
    names = list(CHANNELS) + [f"E_{a}" for a in ALL_AXES]
    index = {name: k for k, name in enumerate(names)}
    absent = [] if has_coil_currents(frame) else [index[name] for name in COIL_CURRENT_CHANNELS]
    out = []
    for name, group in frame.groupby("pass", sort=False):
        realizations = np.sort(group["realization"].unique())
        experiments = np.sort(group["experiment"].unique())
        periods = np.sort(group["period"].unique())
        lines = np.sort(group["line"].unique())
        values = np.zeros((realizations.size, experiments.size, periods.size, len(names), lines.size), dtype=complex)
        values[:, :, :, absent] = np.nan
        values[np.searchsorted(realizations, group["realization"].to_numpy()),
               np.searchsorted(experiments, group["experiment"].to_numpy()),
               np.searchsorted(periods, group["period"].to_numpy()),
               group["channel"].map(index).to_numpy(),
               np.searchsorted(lines, group["line"].to_numpy())] = group["re"].to_numpy() + 1j * group["im"].to_numpy()
        per_line = group.drop_duplicates("line").set_index("line").loc[lines]
        reference = values[:, :, 0, len(CHANNELS):]
        out.append({"name": name, "lines": lines, "frequency_hz": per_line["frequency_hz"].to_numpy(),
                    "role": per_line["role"].to_numpy(), "spectra": values[:, :, :, : len(CHANNELS)],
                    "reference": reference, "excites": (np.abs(reference) > 0).any(axis=(0, 1)).T})
    return out


def multisine_frf(passes, design="orthogonal", noise_half_width=2):
    """The FRF of a multisine run: the BLA of every pass, the zoom merged into the coarse pass.

    Parameters
    ----------
    passes : list of dict
        `multisine_passes`; the first is the coarse pass, a later one named ``zoom`` refines it.
    design : str
        ``per_axis`` adds the SISO ratios.
    noise_half_width : int
        The noise pooled over this many lines either side (`_per_realization`;
        config ``frf.noise_half_width``).

    Returns
    -------
    table : pandas.DataFrame
        `bla_frf_table`.
    estimates : dict
        ``radial``, ``axial`` (merged `GroupBLA`), ``siso``, and ``by_pass`` (name -> `pass_bla`).
    """
    by_pass = {p["name"]: pass_bla(p["spectra"], p["reference"], p["excites"], p["frequency_hz"], design,
                                   noise_half_width) for p in passes}
    radial = axial = None
    siso = {}
    for p in passes:
        result = by_pass[p["name"]]
        radial = merge_passes(radial, result["radial"])
        axial = merge_passes(axial, result["axial"])
        siso = _merge_siso(siso, result["siso"])
    return bla_frf_table(radial, axial, siso), {"radial": radial, "axial": axial, "siso": siso, "by_pass": by_pass}


def bla_frf_table(radial, axial, siso=None):
    """The FRF stage's table (`ambid.frf.frf_table` columns plus ``systematic_std``) of a multisine run.

    ``mimo``: the radial BLA matrix; ``siso``: ``Z/Z`` from the axial group and, for
    per-axis designs, every radial ``V2_j / U2_i``; ``current``: the diagonal of the
    coil-current BLA of both groups.  ``std`` is the noise standard deviation of the
    BLA, ``systematic_std`` the standard deviation of its systematic (nonlinear)
    error (`_combine`; NaN with one realization at one level).
    """
    siso_noise, siso_distortion, current_noise, current_distortion = {}, {}, {}, {}
    for (output, input_axis), (f, g, noise, distortion) in (siso or {}).items():
        siso_noise[(output, input_axis)] = (f, g, noise)
        siso_distortion[(output, input_axis)] = (f, g, distortion)
    groups = [g for g in (radial, axial) if g is not None]
    for group in (g for g in groups if np.isfinite(g.current).any()):  # (none from a log without coil currents)
        for k, axis in enumerate(group.axes):
            current_noise[(axis, axis)] = (group.frequency_hz, group.current[:, k, k], group.current_noise_std[:, k, k])
            current_distortion[(axis, axis)] = (group.frequency_hz, group.current[:, k, k],
                                                group.current_systematic_std[:, k, k])
    if axial is not None:
        siso_noise[(AXIAL_AXIS, AXIAL_AXIS)] = (axial.frequency_hz, axial.plant[:, 0, 0], axial.noise_std[:, 0, 0])
        siso_distortion[(AXIAL_AXIS, AXIAL_AXIS)] = (axial.frequency_hz, axial.plant[:, 0, 0], axial.systematic_std[:, 0, 0])
    mimo_noise = mimo_distortion = None
    axes = RADIAL_AXES
    if radial is not None:
        axes = radial.axes
        mimo_noise = (radial.frequency_hz, radial.plant, radial.noise_std, radial.condition)
        mimo_distortion = (radial.frequency_hz, radial.plant, radial.systematic_std, radial.condition)
    # one table builder for both methods: the distortion column is the same table's std column built from sigma_S
    table = frf_table(siso_noise, mimo_noise, axes=axes, current=current_noise)
    distortion = frf_table(siso_distortion, mimo_distortion, axes=axes, current=current_distortion)
    return table.assign(systematic_std=distortion["std"].to_numpy())


def distortion_levels(spectra, grid_role, frequency_hz, excites, axes=ALL_AXES, bands_hz=None):
    """Output levels at the excited, odd-detection and even-detection lines, above the noise (sec. 4.2.7).

    Parameters
    ----------
    spectra : complex array (R, E, P, 20, L)
    grid_role : str array (L,)
        `ambid.logs.LINE_ROLES` of each line.
    frequency_hz : array (L,)
    excites : bool array (L, 5)
        Axes excited at each line: an output's excited lines are those of its own axis.
    axes : iterable of str
        Position outputs reported.
    bands_hz : sequence, optional
        Band edges; default: per output, from its excited lines
        (`ambid.floor.frequency_bands`, 1-2-5 per decade, at least 20 lines a
        band), so no band lies beyond the measurement or holds a line or two.

    Returns
    -------
    pandas.DataFrame
        Per output ``V2_<axis>`` and band with excited lines of that axis:
        ``excited_m``, ``odd_m``, ``even_m`` (rms over the lines, realizations
        and experiments of the period-mean amplitude, its noise power removed;
        NaN where nothing stands above the noise), ``noise_m`` (rms noise of the
        period mean at the detection lines), ``odd_db``, ``even_db`` and
        ``noise_db`` relative to ``excited_m``, and the line counts.
    """
    periods = spectra.shape[2]
    mean = spectra.mean(axis=2)  # (R, E, 20, L)
    noise_power = np.var(spectra, axis=2, ddof=1).real / periods if periods > 1 else np.zeros(mean.shape)
    rows = []
    for axis in axes:
        c = _V2[axis]
        power = np.abs(mean[:, :, c]) ** 2  # (R, E, L)
        noise = noise_power[:, :, c]
        own = excites[:, ALL_AXES.index(axis)]
        edges = np.asarray(bands_hz, dtype=float) if bands_hz is not None else frequency_bands(frequency_hz[own])
        for low, high, label in zip(edges[:-1], edges[1:], band_labels(edges)):
            band = (frequency_hz >= low) & (frequency_hz < high)
            if not (band & own).any():
                continue
            row = {"output": f"V2_{axis}", "band": label}
            for key, pick in (("excited", band & own), ("odd", band & (grid_role == "odd_detection")),
                              ("even", band & (grid_role == "even_detection"))):
                row[f"{key}_lines"] = int(pick.sum())
                above = np.mean(power[..., pick]) - np.mean(noise[..., pick]) if pick.any() else np.nan
                row[f"{key}_m"] = float(np.sqrt(above)) if above > 0 else np.nan
            detection = band & (grid_role != "excited")
            row["noise_m"] = float(np.sqrt(np.mean(noise[..., detection]))) if detection.any() else np.nan
            for key in ("odd", "even", "noise"):
                row[f"{key}_db"] = float(20 * np.log10(row[f"{key}_m"] / row["excited_m"]))
            rows.append(row)
    return pd.DataFrame(rows)


def excitation_covariance(spectra, reference):
    """Each axis' variance of the differential coil current ``(I_upper - I_lower) / 2`` and of the position ``V2``,
    and their covariance, over the top level's realizations and experiments, summed over the stored lines.

    What the force law is averaged over during the run (`ambid.effects.at_excitation_level`): the per-period spectra
    are complex amplitudes, so a line contributes ``|c|^2 / 2`` (``Re(c conj(v)) / 2``).  A log without coil currents
    has the control current U2 in their place: an amplifier follows its command, gain 1, below its bandwidth, where
    the excitation's power lies.

    Parameters
    ----------
    spectra : complex array (R, E, P, 20, L)
    reference : complex array (R, E, 5, L)

    Returns
    -------
    dict
        Axis -> ``[var_i_a2, var_x_m2, cov_am]``, every axis of `ambid.machine.ALL_AXES`.
    """
    part = spectra[realization_levels(reference) >= 1.0 - 1e-9]

    def moment(a, b):  # summed over the lines, averaged over realizations, experiments and periods
        return float(np.mean(np.sum((a * np.conj(b)).real, axis=-1)) / 2)

    out = {}
    for axis in ALL_AXES:
        coil = 0.5 * (part[:, :, :, _UPPER[axis]] - part[:, :, :, _LOWER[axis]])
        if not np.isfinite(coil).all():  # a log without coil currents
            coil = part[:, :, :, _U2[axis]]
        position = part[:, :, :, _V2[axis]]
        out[axis] = [moment(coil, coil), moment(position, position), moment(coil, position)]
    return out


def line_levels(spectra, axis):
    """Per stored line, the rms over realizations and experiments of one axis' period-mean position
    amplitude and of its noise (the standard deviation of the period mean) [m]: the detection-line picture."""
    c = _V2[axis]
    periods = spectra.shape[2]
    mean = spectra[:, :, :, c].mean(axis=2)  # (R, E, L)
    level = np.sqrt(np.mean(np.abs(mean) ** 2, axis=(0, 1)))
    noise = np.sqrt(np.mean(np.var(spectra[:, :, :, c], axis=2, ddof=1) / periods, axis=(0, 1)))
    return level, noise
