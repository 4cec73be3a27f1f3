"""Empirical transfer function estimates from identification logs (thesis eq. 4.1), SISO and MIMO.

SISO, as the thesis: for excitation on axis i, ``G_ji(f) = V2_j / U2_i`` (the
thesis' ``data_exc_dx(:,7) ./ data_exc_dx(:,3)``).  With the loop closed, the
controllers feed the excitation back onto every axis, so every U2 moves and
the SISO ratio of a coupled plant is not its (j, i) element.

MIMO, beyond the thesis: from the four radial excitation runs at the same
frequency, ``U`` and ``V`` (4 x 4, column k = the run exciting axis k) give
``P = V U^-1``.  Its reliability is the conditioning of U, reported per
frequency.

Coil currents, beyond the thesis: ``A_i(f) = I_i / U2_i`` of the run exciting
axis i, with ``I = (I_upper - I_lower) / 2`` the differential coil current.  It
is the amplifier's response alone (the position sensors never enter it), which
is what tells an amplifier low-pass from a sensor low-pass or a delay.

Uncertainty: the logged noise of each Fourier coefficient (independent, zero
mean) propagates to first order, ``dP = (dV - P dU) U^-1``, giving a standard
deviation per FRF point that later stages use as fit weights.
"""

from typing import NamedTuple

import numpy as np
import pandas as pd

from .amplitude import account_zero_amplitude, measured_variance_errors, zero_amplitude
from .errors import LogError
from .floor import FloorSettings, pooled_noise, systematic_floor
from .findings import Finding
from .logs import CHANNELS, has_coil_currents, noise_from_scatter, repeated_steps, run_matrix
from .machine import ALL_AXES, RADIAL_AXES
from .plausibility import FRF_SETTINGS, check_log

__all__ = ["FRF_UNITS", "log_arrays", "siso_etfe", "mimo_etfe", "current_etfe", "frf_table", "frf_from_log", "FrfStage",
           "frf_stage", "channel", "radial_estimator"]


def log_arrays(frame, level=0):
    """Per excited axis: frequencies (n,), coefficients (n, 20) and their noise (n, 20), steps in order.

    A channel the axis' run does not carry (the other bearing's, `ambid.logs.axis_channels`) is NaN.
    ``level`` selects the steps as accepted (0, the default) or their repeats at a
    lower amplitude (1, ...; see `ambid.logs`); a log without a ``level`` column is all level 0.
    """
    out = {}
    index = {name: k for k, name in enumerate(CHANNELS)}
    frame = frame[frame["level"] == level] if "level" in frame.columns else (frame if level == 0 else frame.iloc[:0])
    for axis, group in frame.groupby("excited_axis", sort=False):
        group = group.sort_values(["step", "channel"])
        steps = group["step"].unique()
        coefficients = np.full((steps.size, len(CHANNELS)), np.nan, dtype=complex)
        noise = np.full((steps.size, len(CHANNELS)), np.nan)
        row = np.searchsorted(steps, group["step"].to_numpy())
        column = group["channel"].map(index).to_numpy()
        coefficients[row, column] = group["re"].to_numpy() + 1j * group["im"].to_numpy()
        noise[row, column] = group["noise_std"].to_numpy()
        frequency = group.groupby("step")["frequency_hz"].first().to_numpy()
        out[axis] = (frequency, coefficients, noise)
    return out


def _u2(axis):
    return CHANNELS.index(f"U2_{axis}")


def _v2(axis):
    return CHANNELS.index(f"V2_{axis}")


def _ratio(numerator, numerator_std, denominator, denominator_std):
    """``numerator / denominator`` and its first-order standard deviation from independent noise of both."""
    ratio = numerator / denominator
    # |r| sqrt((sn/|n|)^2 + (sd/|d|)^2) written without dividing by |n|: finite where a channel reads exactly zero
    std = np.sqrt(numerator_std**2 + (np.abs(ratio) * denominator_std) ** 2) / np.abs(denominator)
    return ratio, std


def siso_etfe(arrays):
    """SISO ETFE of every excited axis to every output axis.

    Returns
    -------
    dict
        ``(output, input) -> (frequency_hz, G, std)``; G [m/A] = V2_output / U2_input
        of the run exciting ``input``; std from the logged noise,
        ``|G| sqrt((s_V / |V|)^2 + (s_U / |U|)^2)``.  Outputs the run does not
        carry (the other bearing's, when the log leaves them out) have no entry.
    """
    out = {}
    for excited, (frequency, coefficients, noise) in arrays.items():
        u, su = coefficients[:, _u2(excited)], noise[:, _u2(excited)]
        for output in ALL_AXES:
            v, sv = coefficients[:, _v2(output)], noise[:, _v2(output)]
            if np.isnan(v).all():
                continue
            out[(output, excited)] = (frequency, *_ratio(v, sv, u, su))
    return out


def current_etfe(arrays):
    """Coil-current response of every excited axis: ``I / U2`` [A/A].

    Returns
    -------
    dict
        ``(axis, axis) -> (frequency_hz, A, std)``; ``I = (I_upper - I_lower) / 2``
        with noise ``sqrt(s_upper^2 + s_lower^2) / 2``, propagated like `siso_etfe`.
        A log without coil currents (`ambid.logs`: optional for a whole log) has no entry.
    """
    out = {}
    for excited, (frequency, coefficients, noise) in arrays.items():
        upper, lower = CHANNELS.index(f"I_upper_{excited}"), CHANNELS.index(f"I_lower_{excited}")
        if np.isnan(coefficients[:, upper]).all():
            continue
        u, su = coefficients[:, _u2(excited)], noise[:, _u2(excited)]
        current = 0.5 * (coefficients[:, upper] - coefficients[:, lower])
        s_current = 0.5 * np.hypot(noise[:, upper], noise[:, lower])
        out[(excited, excited)] = (frequency, *_ratio(current, s_current, u, su))
    return out


def mimo_etfe(arrays, axes=RADIAL_AXES, relative_frequency_tolerance=1e-6, source="identification log"):
    """MIMO ETFE ``P = V U^-1`` from the runs exciting each of ``axes``.

    Returns
    -------
    frequency_hz : array (n,)
    plant : array (n, m, m)
        Rows outputs, columns inputs, in ``axes`` order [m/A].
    std : array (n, m, m)
        First-order standard deviation of each element.
    condition : array (n,)
        2-norm condition number of U (large: the runs excite nearly the same direction).

    Raises
    ------
    LogError
        When a run is missing or the runs' frequency grids differ.
    """
    missing = [a for a in axes if a not in arrays]
    if missing:
        raise LogError(source, f"MIMO estimate needs a run exciting each of {list(axes)}; missing {missing}")
    frequency = arrays[axes[0]][0]
    for axis in axes[1:]:
        other = arrays[axis][0]
        if other.shape != frequency.shape or np.max(np.abs(other / frequency - 1)) > relative_frequency_tolerance:
            raise LogError(source, f"the runs exciting {axes[0]} and {axis} are on different frequency grids")
    inputs, outputs = run_matrix(arrays, "U2", axes), run_matrix(arrays, "V2", axes)  # (n, rows=channel axis, cols=run)
    input_noise, output_noise = run_matrix(arrays, "U2", axes, part=2), run_matrix(arrays, "V2", axes, part=2)
    inverse = np.linalg.inv(inputs)
    plant = outputs @ inverse
    # Var dP_ab = sum_k |W_kb|^2 (sV_ak^2 + sum_l |P_al|^2 sU_lk^2),  W = U^-1
    weight = np.abs(inverse) ** 2
    variance = np.einsum("nak,nkb->nab", output_noise**2, weight)
    variance += np.einsum("nal,nlk,nkb->nab", np.abs(plant) ** 2, input_noise**2, weight)
    return frequency, plant, np.sqrt(variance), np.linalg.cond(inputs)


#: Units of the `frf_table` columns, as the FRF rules write them.
FRF_UNITS = {"frequency_hz": "Hz", "re": "m/A (A/A: current)", "im": "m/A (A/A: current)", "std": "m/A (A/A: current)",
             "systematic_std": "m/A (A/A: current)", "condition": "-",
             "effective_share": "- (share of an independent point)",
             "variance_error": "- (variance of the stated variance's relative error, with its shared covariances)",
             "input_coupling_slope_re": "m/A per unit input cross coupling",
             "input_coupling_slope_im": "m/A per unit input cross coupling"}


def frf_table(siso, mimo=None, axes=RADIAL_AXES, current=None):
    """Long-format FRF table: ``estimator`` (siso / mimo / current), ``output``, ``input``, ``frequency_hz``,
    ``re``, ``im``, ``std`` (noise) [m/A; A/A for ``current``], ``condition`` (of U, MIMO only) and
    ``systematic_std`` (NaN here; `ambid.floor.systematic_floor` estimates it), ``effective_share`` (1 here: the
    share of an independent point a row's error carries, below 1 where `ambid.amplitude.zero_amplitude` makes rows
    share their repeats' noise) and ``variance_error`` (0 here: how uncertain a row's stated variance is;
    `frf_from_log` states both from the pooled noise estimates, `ambid.amplitude.measured_variance_errors`, and
    `ambid.amplitude.zero_amplitude` from the repeats' shared ones), ``input_coupling_slope_re`` / ``_im``
    (0 here: how a row's value at zero amplitude moves with an input cross coupling the FRF stage cannot know)."""
    parts = []
    for (output, input_axis), (frequency, a, std) in (current or {}).items():
        parts.append(pd.DataFrame({"estimator": "current", "output": output, "input": input_axis, "frequency_hz": frequency,
                                   "re": a.real, "im": a.imag, "std": std, "condition": np.nan}))
    for (output, input_axis), (frequency, g, std) in siso.items():
        parts.append(pd.DataFrame({"estimator": "siso", "output": output, "input": input_axis, "frequency_hz": frequency,
                                   "re": g.real, "im": g.imag, "std": std, "condition": np.nan}))
    if mimo is not None:
        frequency, plant, std, condition = mimo
        for i, output in enumerate(axes):
            for j, input_axis in enumerate(axes):
                parts.append(pd.DataFrame({"estimator": "mimo", "output": output, "input": input_axis, "frequency_hz": frequency,
                                           "re": plant[:, i, j].real, "im": plant[:, i, j].imag, "std": std[:, i, j],
                                           "condition": condition}))
    return pd.concat(parts, ignore_index=True).assign(systematic_std=np.nan, effective_share=1.0, variance_error=0.0,
                                                      input_coupling_slope_re=0.0, input_coupling_slope_im=0.0)


def frf_from_log(frame, floor_settings=None, source="identification log", estimator="mimo"):
    """Every FRF of an identification log with its noise and its systematic floor (what the ``frf`` rule writes).

    Parameters
    ----------
    frame : pandas.DataFrame
        A validated identification log.
    floor_settings : ambid.floor.FloorSettings, optional
    source : str
        The log, named in errors.
    estimator : {"mimo", "siso"}
        ``siso`` leaves the MIMO estimate out (config ``frf.estimator``).

    Returns
    -------
    table : pandas.DataFrame
        `frf_table` of the log's level-0 steps (their noise pooled over
        ``floor_settings.noise_half_width`` neighbours, `ambid.floor.pooled_noise`): SISO, MIMO (when all four radial
        axes were excited and ``estimator`` is mimo) and coil currents,
        ``systematic_std`` from `ambid.floor`; with ``floor_settings.zero_amplitude``,
        extrapolated to zero amplitude from the repeats where that is more
        accurate (`ambid.amplitude`).
    floors : pandas.DataFrame
        `ambid.floor.systematic_floor`'s account of how, per family and band, with
        ``noise_pooled_steps`` (the steps each step's noise is pooled over).
    mimo : tuple or None
        `mimo_etfe`'s output (its condition numbers).
    """
    settings = floor_settings or FloorSettings()
    frame = pooled_noise(frame, settings.noise_half_width)
    arrays = log_arrays(frame)
    mimo = (mimo_etfe(arrays, source=source) if estimator == "mimo" and all(a in arrays for a in RADIAL_AXES)
            else None)
    measured = frf_table(siso_etfe(arrays), mimo, current=current_etfe(arrays))
    low, low_arrays = None, log_arrays(frame, level=1)
    if low_arrays:
        try:
            low_mimo = mimo_etfe(low_arrays, source=source) if mimo is not None else None
        except LogError:  # the four radial axes' repeats are not at the same steps: no MIMO pairs
            low_mimo = None
        low = frf_table(siso_etfe(low_arrays), low_mimo, current=current_etfe(low_arrays))
    table, floors = systematic_floor(measured, arrays, low, low_arrays, settings)
    table = measured_variance_errors(table, settings)
    extrapolated = np.zeros(len(table), dtype=bool)
    if settings.zero_amplitude and low is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = table["std"].to_numpy() / measured["std"].to_numpy()
        table, extrapolated = zero_amplitude(table, low, arrays, low_arrays, np.nan_to_num(scale, nan=1.0), settings)
    floors = account_zero_amplitude(floors, table, extrapolated).assign(
        noise_pooled_steps=2 * settings.noise_half_width + 1)
    return table, floors, mimo


class FrfStage(NamedTuple):
    """What `frf_stage` makes of one log."""

    table: pd.DataFrame  # `frf_from_log`'s
    floors: pd.DataFrame  # `frf_from_log`'s
    mimo: tuple | None  # `mimo_etfe`'s output (its condition numbers), or None
    findings: list  # the checks' `ambid.findings.Finding`s
    scatter_noise: pd.Series | None  # each channel's noise from its scatter, where the log carried none
    repeated_steps: int  # `ambid.logs.repeated_steps` of the steps kept


def frf_stage(frame, settings, log, source=None, source_lines=None, original=None):
    """The FRF stage of one identification log, as rule `frf` runs it.

    Where the log carries no noise estimate (``noise_std`` all 0: a thesis ``.m``, a user's table), each channel's
    noise from its scatter between neighbouring steps (`ambid.logs.noise_from_scatter`); the model-free checks
    (`ambid.plausibility.check_log`: radial runs, outlier cells); then `frf_from_log` with the floor.  A log without
    coil currents gets a ``no_coil_currents`` note.

    Parameters
    ----------
    frame : pandas.DataFrame
        The validated log.
    settings : dict
        The config's ``frf`` section: `ambid.plausibility.FRF_SETTINGS` keys (defaults where absent) and
        `ambid.floor.FloorSettings` keys.
    log : str
        The log file the checks name.
    source : str, optional
        The file errors name where it is another (the user's file a log was converted from); default ``log``.
    source_lines, original : optional
        As `ambid.plausibility.check_log` (a log converted from a thesis ``.m``).

    Returns
    -------
    FrfStage
    """
    settings = {**FRF_SETTINGS, **settings}
    floor_settings = FloorSettings.from_config({k: v for k, v in settings.items() if k not in FRF_SETTINGS})
    source = source or log
    scatter_noise = None
    if (frame["noise_std"] == 0).all():
        frame = noise_from_scatter(frame, source)
        scatter_noise = frame.groupby("channel")["noise_std"].first()
    frame, findings = check_log(frame, log_arrays(frame), settings, log, source_lines, original)
    if not has_coil_currents(frame):
        findings.append(Finding("frf", "note", "no_coil_currents", "run",
                                "the log carries no coil currents: the FRFs are the positions' alone, and the diagnosis "
                                "cannot tell an amplifier's lag from a sensor's or a delay (they differ in the coil "
                                "currents only); log I_upper and I_lower to tell them apart", 0.0))
    table, floors, mimo = frf_from_log(frame, floor_settings, source=source, estimator=settings["estimator"])
    return FrfStage(table, floors, mimo, findings, scatter_noise, repeated_steps(frame))


def radial_estimator(table):
    """The radial estimator a stage reads from an `frf_table`: ``mimo`` where it has the MIMO estimate, else ``siso``."""
    return "mimo" if (table["estimator"] == "mimo").any() else "siso"


def channel(table, estimator, output, input_axis, systematic=False, share=False, coupling=False):
    """Frequencies, complex values and standard deviations of one channel of an `frf_table`.

    With ``systematic``, also the ``systematic_std`` (NaN where the table has none); with ``share``, also the
    ``effective_share`` and the ``variance_error`` (1 and 0 where the table has none); with ``coupling``, also the
    complex ``input_coupling_slope`` (0 where the table has none).
    """
    rows = table[(table["estimator"] == estimator) & (table["output"] == output) & (table["input"] == input_axis)]
    rows = rows.sort_values("frequency_hz")
    out = (rows["frequency_hz"].to_numpy(), rows["re"].to_numpy() + 1j * rows["im"].to_numpy(), rows["std"].to_numpy())
    if systematic:
        extra = rows["systematic_std"].to_numpy() if "systematic_std" in rows.columns else np.full(len(rows), np.nan)
        out += (extra,)
    if share:
        out += (rows["effective_share"].to_numpy(dtype=float) if "effective_share" in rows.columns
                else np.ones(len(rows)),
                rows["variance_error"].to_numpy(dtype=float) if "variance_error" in rows.columns
                else np.zeros(len(rows)))
    if coupling:
        out += ((rows["input_coupling_slope_re"].to_numpy(dtype=float)
                 + 1j * rows["input_coupling_slope_im"].to_numpy(dtype=float))
                if "input_coupling_slope_re" in rows.columns else np.zeros(len(rows), dtype=complex),)
    return out
