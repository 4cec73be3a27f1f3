"""Plausibility of an identification log against the nominal model, before any estimate.

A log from another writer can be well formed (`ambid.logs.validate_identification_log`)
and still not be what it claims.  Three checks, each raising a `LogError` that
names the file, the rows (or, for a converted thesis ``.m`` log, its lines)
and the likely cause.  Axes and outliers need no model and run in the FRF
stage (`check_log`); units need the nominal model and run in their own rule
before it (`check_units`), so that the FRF does not depend on the model.

* **Axes**: the MIMO estimate ``P = V U^-1`` (`ambid.frf.mimo_etfe`) needs a
  run exciting each radial axis; a log without one is refused for it instead
  of silently falling back to SISO.
* **Units**: the log's frequencies against the machine's identification band,
  and its low-frequency compliance ``|V2/U2|`` (dominated by the bearings'
  negative stiffness, ``-ki/kx``, which a model knows to well within a factor
  of 30) and coil-current ratio ``|I/U2|`` (1 at low frequency) against the
  nominal model.  A factor of about 10^3 or 10^6 names the likely unit
  (positions in um or mm, currents in mA, frequencies in kHz).  The signs too:
  below the flexible modes a log and its model differ by a lag of a few
  degrees, so a compliance half a turn off is a channel of the other sign (a
  sensor mounted the other way, another writer's axis direction), and a coil
  current opposite to its command is upper and lower swapped.  A compliance that is
  the model's closed loop from the excitation, V2/E_u, rather than its plant is a
  log of the excitation in place of U2.  The bearings too: a
  log whose drive-end axes have the model's non-drive-end compliance and the other
  way round has the two bearings' channels swapped (on a machine whose bearings
  differ, as hs_eden_like's do by a factor 1.6).  A log of complex
  conjugated coefficients (the other sign convention of the Fourier transform)
  shows as a compliance whose imaginary part has the other sign of the model's
  where that is resolved (damping and the loop's lags give it one sign), or as
  coil currents that lead their commands over the upper half of the band (an
  amplifier and the sampling only lag).
* **Outliers**: each channel's response to the excitation, ``c / amplitude``
  (a closed-loop transfer function, smooth in frequency), against the
  interpolation of its neighbours, in units of the larger of the logged noise
  and the local scatter of the neighbours' own interpolation residuals.  A cell
  far above the threshold, alone at its step, is an outlier: a typo, a glitch.
  A resonance narrower than the grid looks the same in one channel, but it
  moves at least two at its step (in closed loop the excited axis' position,
  control current and coil currents; open-loop, the positions of its plane).  The workflow
  refuses it, or excludes its step when ``frf.outliers: exclude``.
"""

from dataclasses import dataclass

import numpy as np

from .errors import LogError
from .findings import Finding
from .logs import CHANNELS, _where
from .loop import axial_transfer_functions, transfer_functions
from .machine import AXIAL_AXIS, RADIAL_AXES
from .mfile import THESIS_COLUMNS, _LAYOUT, variable_name
from .plant import RIGID_MODES

__all__ = ["FRF_SETTINGS", "Outlier", "check_axes", "check_units", "frf_arrays", "find_outliers", "outlier_text",
           "exclude_outliers", "check_log"]

#: Defaults of the ``frf:`` config section.
FRF_SETTINGS = {"estimator": "mimo", "outliers": "refuse", "outlier_threshold": 100.0}
#: A unit error is called when the log is this far from the nominal model (a model is rarely off by 3x).
UNIT_FACTOR = 30.0
#: The excitation logged as U2 when the log's compliance deviates from the model's closed loop V2/E_u by less than half,
#: and by this much less (median |ratio - 1|), than from its plant: the rig's logs deviate 2-10 % from the plant and
#: 55-110 % from the closed loop, and so edited (E_u in U2) 58-136 % and 2-14 %.
EXCITATION_AS_U2 = 0.3
#: Each radial axis and the same direction at the other bearing.
OTHER_BEARING = {"DX": "NX", "DY": "NY", "NX": "DX", "NY": "DY"}
#: Bearings swapped when the log's low-frequency compliance deviates from the other bearing's by less than half, and
#: by this much less (median |log| of the magnitude ratio: 0.2, about 22 %), than from its own; a machine with equal
#: bearings (demo20) is never refused; on hs_eden_like's rig log the right labels deviate by |log| 0.010-0.028 per axis
#: and the swapped ones by 0.44-0.47 (a factor 1.55-1.60).
BEARING_SWAP_LOG = 0.2
_WINDOW = 6  # neighbours on each side that set an outlier's local scale
_COHERENT = 2  # channels departing together at a step: a resonance (seen by two sensors at least), not a typo


def check_axes(frame, estimator, source):
    """Refuse a log without a run exciting each radial axis when the MIMO estimate is asked for."""
    present = set(frame["excited_axis"])
    missing = [axis for axis in RADIAL_AXES if axis not in present]
    if estimator == "mimo" and missing:
        thesis = str(source).endswith(".m")
        names = ", ".join(f"{axis} ({variable_name(axis)})" if thesis else axis for axis in missing)
        raise LogError(source, f"no run excites {names}: the MIMO estimate needs a run exciting each of "
                               f"{', '.join(RADIAL_AXES)} (set frf.estimator: siso for SISO estimates of the axes present)")


def _nearest_unit(log_ratio, kind):
    """A unit that explains a factor 10^log_ratio between the log and the model ("" for none, or a dead channel)."""
    if not np.isfinite(log_ratio):
        return ""
    steps = int(np.round(log_ratio / 3))
    if kind == "frequency":
        return {-1: "frequencies look like kHz", 1: "frequencies look like mHz"}.get(steps, "")
    if kind == "current":
        return {1: "coil currents look like mA", -1: "the control currents U2 look like mA (coil currents in A)"}.get(steps, "")
    return {3: "positions look like nm", 2: "positions look like um", 1: "positions look like mm",
            -1: "currents look like mA (U2 and coil currents)",
            -2: "positions look like m where um are expected (a thesis .m holds positions in um)"}.get(steps, "")


def _refuse(source, what, ratio, kind, detail, model_source):
    with np.errstate(divide="ignore"):
        unit = _nearest_unit(np.log10(ratio), kind)
    hint = f"{unit} (the log must hold SI units: m, A, Hz)" if unit else "check the units of the log (SI: m, A, Hz)"
    raise LogError(source, f"{what} is {ratio:.3g} times the nominal model's {detail}: {hint}, or the model "
                           f"({model_source}) is off by as much")


def frf_arrays(table):
    """An FRF table as `check_units` reads a log: per axis, one unit command ``U2 = 1`` per frequency.

    For FRFs without a raw log behind them in the workflow's order: a multisine
    run's BLA (`ambid.bla.multisine_frf`) and a user's UFF58 FRFs
    (`ambid.readers.read_uff_frf`).  ``V2`` is the axis' compliance (the MIMO
    diagonal where the table has it, else the SISO ratio) and the coil current
    ``(I_upper - I_lower) / 2`` its coil-current FRF (interpolated onto the
    compliance's frequencies, NaN outside its range or where the table has
    none), so every check of `check_units` reads them as it reads a log's steps.

    Parameters
    ----------
    table : pandas.DataFrame
        `ambid.frf.frf_table` columns.

    Returns
    -------
    dict
        As `ambid.frf.log_arrays`: axis -> (frequencies (n,), coefficients (n, 20), noise (n, 20), NaN).
    """
    from .frf import channel  # (the FRF stage runs this module's checks)

    out = {}
    for axis in (*RADIAL_AXES, AXIAL_AXIS):
        frequency, compliance, _ = channel(table, "mimo", axis, axis)
        if frequency.size == 0:
            frequency, compliance, _ = channel(table, "siso", axis, axis)
        if frequency.size == 0:
            continue
        coefficients = np.full((frequency.size, len(CHANNELS)), np.nan, dtype=complex)
        coefficients[:, CHANNELS.index(f"U2_{axis}")] = 1.0
        coefficients[:, CHANNELS.index(f"V2_{axis}")] = compliance
        current_hz, current, _ = channel(table, "current", axis, axis)
        if current_hz.size >= 2:
            inside = (frequency >= current_hz[0]) & (frequency <= current_hz[-1])
            coil = np.full(frequency.size, np.nan, dtype=complex)
            coil[inside] = (np.interp(frequency[inside], current_hz, current.real)
                            + 1j * np.interp(frequency[inside], current_hz, current.imag))
            coefficients[:, CHANNELS.index(f"I_upper_{axis}")] = coil
            coefficients[:, CHANNELS.index(f"I_lower_{axis}")] = -coil
        out[axis] = (frequency, coefficients, np.full(coefficients.shape, np.nan))
    return out


def _explains_better(as_labelled, alternative, margin):
    """The median deviations of a log from its model as labelled and under another reading (lists of per-axis
    arrays, pooled), and whether the other reading explains it: below half the labelled deviation, and by ``margin``."""
    labelled, other = (float(np.median(np.concatenate(x))) for x in (as_labelled, alternative))
    return labelled, other, other < 0.5 * labelled and labelled - other > margin


def check_units(arrays, plant, source, model_source="the machine file"):
    """Refuse a log whose frequencies, positions or currents are off the nominal model by `UNIT_FACTOR` or more, whose
    compliance or coil current has the other sign (half a turn of phase below 0.3 x the first flexible mode), whose
    compliance is the model's closed loop from the excitation (E_u logged as U2, `EXCITATION_AS_U2`), whose bearings'
    channels are swapped (`BEARING_SWAP_LOG`), or whose coefficients are complex conjugated.

    Parameters
    ----------
    arrays : dict
        `ambid.frf.log_arrays` of the log, or `frf_arrays` of FRFs without a raw log in the workflow (a
        multisine run's BLA, a user's UFF58 FRFs); their frequencies count as steps in the messages.
    plant : ambid.plant.Plant
        The nominal model (machine file): its identification grids, its first
        flexible mode, its low-frequency compliance.
    source : str
    model_source : str
        The machine file, named as the other suspect.

    Returns
    -------
    list of dict
        One row per check passed: ``check`` (frequency / compliance / coil_current), ``axes``,
        ``ratio`` (log over nominal model) and ``below_hz`` (the band compared; NaN for frequencies).
    """
    from .compare import model_response  # (compare reads the FRF stage, which runs this module's checks)

    machine = plant.machine
    rows = []
    for axes, grid in ((RADIAL_AXES, machine.radial_grid), ((AXIAL_AXIS,), machine.axial_grid)):
        frequency = np.concatenate([arrays[a][0] for a in axes if a in arrays] or [np.array([])])
        if frequency.size == 0:
            continue
        ratio = np.median(frequency) / np.median(grid.frequency_hz)
        if abs(np.max(frequency) / grid.stop_hz / (2 * np.pi) - 1) < 0.01:
            raise LogError(source, f"frequencies of {', '.join(a for a in axes if a in arrays)} end at "
                                   f"{np.max(frequency):.6g}, 2 pi times the {grid.stop_hz:g} Hz of {model_source} "
                                   "(frequency_grid): they look like rad/s; the log must hold Hz")
        if not 1 / UNIT_FACTOR < ratio < UNIT_FACTOR:
            _refuse(source, f"the median frequency of {', '.join(a for a in axes if a in arrays)}", ratio, "frequency",
                    f"identification grid ({grid.start_hz:g}-{grid.stop_hz:g} Hz, frequency_grid)", model_source)
        rows.append({"check": "frequency", "axes": " ".join(a for a in axes if a in arrays), "ratio": float(ratio),
                     "below_hz": np.nan})
    first_flexible_hz = plant.modes.frequency_hz[RIGID_MODES]
    for axes, functions in ((RADIAL_AXES, transfer_functions), ((AXIAL_AXIS,), axial_transfer_functions)):
        present = [a for a in axes if a in arrays]
        if not present or (axes == (AXIAL_AXIS,) and machine.axial_electromagnet is None):
            continue
        compliance, amplifier, flipped, swapped, lead, damping_sign = [], [], [], [], [], []
        own_bearing, other_bearing = [], []  # |log| deviation from the model's own axis and from the other bearing's
        open_loop, closed_loop = [], []  # |V2/U2 / model - 1| against the plant and against the closed loop V2/E
        for axis in present:
            frequency, coefficients, _ = arrays[axis]
            # where the model's compliance has an imaginary part (damping, lags) the log's has its sign
            measured = coefficients[:, CHANNELS.index(f"V2_{axis}")] / coefficients[:, CHANNELS.index(f"U2_{axis}")]
            expected = model_response(plant, {(axis, axis): (frequency,)})[(axis, axis)]  # the sampled chain's lags too
            resolved = np.abs(expected.imag) > 0.1 * np.abs(expected)
            damping_sign.append(np.sign(measured.imag[resolved]) == np.sign(expected.imag[resolved]))
            upper = frequency >= np.median(frequency)
            lead.append(np.angle(0.5 * (coefficients[upper, CHANNELS.index(f"I_upper_{axis}")]
                                        - coefficients[upper, CHANNELS.index(f"I_lower_{axis}")])
                                 / coefficients[upper, CHANNELS.index(f"U2_{axis}")]))
            low = frequency <= 0.3 * first_flexible_hz
            low = low if np.count_nonzero(low) >= 3 else np.ones_like(low)
            u = coefficients[low, CHANNELS.index(f"U2_{axis}")]
            v = coefficients[low, CHANNELS.index(f"V2_{axis}")]
            coil = 0.5 * (coefficients[low, CHANNELS.index(f"I_upper_{axis}")] - coefficients[low, CHANNELS.index(f"I_lower_{axis}")])
            loop = functions(plant, frequency[low], hold=True)  # (the identified plant holds the DAC's hold too)
            diagonal = np.diagonal(loop["plant"], axis1=1, axis2=2)
            nominal = diagonal[:, axes.index(axis)]
            compliance.append(np.abs(v / u) / np.abs(nominal))
            open_loop.append(np.abs(v / u / nominal - 1))
            closed_loop.append(np.abs(v / u / loop["dynamic_compliance"][:, axes.index(axis), axes.index(axis)] - 1))
            if axis in OTHER_BEARING:
                own_bearing.append(np.abs(np.log(compliance[-1])))
                other_bearing.append(np.abs(np.log(np.abs(v / u) / np.abs(diagonal[:, axes.index(OTHER_BEARING[axis])]))))
            amplifier.append(np.abs(coil / u))
            # the sign: below the flexible modes a log and its model differ by a small lag, not half a turn
            if np.median(np.cos(np.angle(v / u / nominal))) < 0:
                flipped.append(axis)
            coil_sign = np.cos(np.angle(coil / u))
            coil_sign = coil_sign[np.isfinite(coil_sign)]  # (none without coil currents)
            if coil_sign.size and np.median(coil_sign) < 0:
                swapped.append(axis)
        names = ", ".join(present)
        ratio = float(np.median(np.concatenate(compliance)))
        if not 1 / UNIT_FACTOR < ratio < UNIT_FACTOR:
            _refuse(source, f"the low-frequency compliance |V2/U2| of {names}", ratio, "position",
                    f"(median below {0.3 * first_flexible_hz:.0f} Hz, 0.3 x its first flexible mode)", model_source)
        open_fit, closed_fit, closed_explains = _explains_better(open_loop, closed_loop, EXCITATION_AS_U2)
        if closed_explains:
            raise LogError(source, f"the compliance V2/U2 of {names} is the nominal model's closed loop from the "
                                   f"excitation, V2/E_u (dynamic compliance; median deviation {100 * closed_fit:.0f} %), "
                                   f"not its plant V2/U2 ({100 * open_fit:.0f} %), below {0.3 * first_flexible_hz:.0f} Hz: "
                                   "U2 looks like the excitation E_u logged in place of the control current (U2 is the "
                                   "controller's output plus E_u, the amplifiers' command); log U2, unless the "
                                   f"controller of {model_source} is far from this machine's")
        if len(own_bearing) == len(OTHER_BEARING):
            own_fit, other_fit, swap_explains = _explains_better(own_bearing, other_bearing, BEARING_SWAP_LOG)
            if swap_explains:
                raise LogError(source, f"the low-frequency compliance |V2/U2| of DX, DY is the nominal model's of NX, NY "
                                       f"and the other way round (median deviation {100 * np.expm1(other_fit):.1f} % so, "
                                       f"{100 * np.expm1(own_fit):.0f} % as labelled, below {0.3 * first_flexible_hz:.0f} "
                                       "Hz): the drive-end (D) and non-drive-end (N) channels look swapped (another "
                                       "writer's bearing names); rename DX <-> NX and DY <-> NY in the log (U2, V2, the "
                                       f"coil currents and the excited axis), unless {model_source} has its bearings the "
                                       "other way round")
        rows.append({"check": "compliance", "axes": " ".join(present), "ratio": ratio, "below_hz": 0.3 * first_flexible_hz})
        if flipped:
            channels = ", ".join(f"V2_{a} or U2_{a}" for a in flipped)
            raise LogError(source, f"the compliance V2/U2 of {', '.join(flipped)} has the opposite sign of the nominal "
                                   f"model's below {0.3 * first_flexible_hz:.0f} Hz (0.3 x its first flexible mode; its "
                                   "phase is half a turn off, where a lag would be a few degrees): the sign of "
                                   f"{channels} differs from the convention of {model_source} (a sensor mounted or "
                                   "wired the other way, another writer's axis direction); negate that channel in the log")
        damping_sign = np.concatenate(damping_sign)
        if damping_sign.size >= 10 and np.mean(damping_sign) < 0.2:
            raise LogError(source, f"the compliance V2/U2 of {names} has the imaginary part of the other sign than the "
                                   f"nominal model's at {100 * (1 - np.mean(damping_sign)):.0f} % of the "
                                   f"{damping_sign.size} steps where the model's is at least a tenth of its magnitude "
                                   "(damping and lags give it one sign; a model error shifts resonances, not that): the "
                                   "log's Fourier coefficients look complex conjugated (the other sign convention of the "
                                   f"transform, e^(+j w t)); negate every imaginary part, unless the model ({model_source}) "
                                   "is far off")
        amplifier = np.concatenate(amplifier)
        amplifier = amplifier[np.isfinite(amplifier)]  # (where an FRF table's coil-current FRF reaches, `frf_arrays`)
        if not amplifier.size:  # a log without coil currents (optional, `ambid.logs`)
            continue
        ratio = float(np.median(amplifier))
        if not 1 / UNIT_FACTOR < ratio < UNIT_FACTOR:
            _refuse(source, f"the low-frequency coil-current ratio |I/U2| of {names}", ratio, "current",
                    "(1: the amplifier's DC gain, I = (I_upper - I_lower) / 2)", model_source)
        rows.append({"check": "coil_current", "axes": " ".join(present), "ratio": ratio, "below_hz": 0.3 * first_flexible_hz})
        lead = np.concatenate(lead)
        lead = lead[np.isfinite(lead)]
        if lead.size and np.median(lead) > 0 and np.mean(lead > 0) > 0.75:
            raise LogError(source, f"the coil currents of {names} lead their commands U2 (median {np.degrees(np.median(lead)):+.2f} "
                                   f"deg over the upper half of the band, {100 * np.mean(lead > 0):.0f} % of the steps), "
                                   "where an amplifier and the sampling only lag: the log's Fourier coefficients look "
                                   "complex conjugated (the other sign convention of the transform, e^(+j w t)); negate "
                                   "every imaginary part")
        if swapped:
            channels = ", ".join(f"I_upper_{a} and I_lower_{a}" for a in swapped)
            raise LogError(source, f"the coil current (I_upper - I_lower) / 2 of {', '.join(swapped)} runs opposite to its "
                                   f"command U2 below {0.3 * first_flexible_hz:.0f} Hz (an amplifier follows its command): "
                                   f"{channels} look swapped (or U2 and V2 of that axis both have the other sign, "
                                   "which leaves the compliance's sign alone); swap them in the log")
    return rows


@dataclass(frozen=True)
class Outlier:
    """One cell far from its neighbours: excited axis, step, channel, frequency, and its score in noise units."""

    axis: str
    step: int
    channel: str
    frequency_hz: float
    score: float
    value: complex


def _scores(frequency, response, noise):
    """Interpolation residuals of one channel along its steps and their scores (residual over its local scale)."""
    n = response.size
    residual = np.zeros(n, dtype=complex)
    if n >= 3:
        weight = (frequency[2:] - frequency[1:-1]) / (frequency[2:] - frequency[:-2])
        residual[1:-1] = response[1:-1] - (weight * response[:-2] + (1 - weight) * response[2:])
        residual[0] = response[0] - (2 * response[1] - response[2])
        residual[-1] = response[-1] - (2 * response[-2] - response[-3])
    size = np.abs(residual)
    local = np.empty(n)
    for k in range(n):
        others = np.concatenate([size[max(0, k - _WINDOW - 1) : max(0, k - 1)], size[k + 2 : k + _WINDOW + 2]])
        local[k] = 1.4826 * np.median(others) if others.size else 0.0
    # the residual of a point carries its own noise and half of each neighbour's (interpolation)
    scale = np.maximum(np.sqrt(1.5) * noise, local)
    scale = np.maximum(scale, 1e-12 * np.median(np.abs(response)) + np.finfo(float).tiny)
    return size, size / scale


def find_outliers(arrays, steps, threshold):
    """Cells far from their neighbours, alone at their step.

    Parameters
    ----------
    arrays : dict
        `ambid.frf.log_arrays`: per excited axis (frequency, coefficients (n, 20), noise (n, 20)).
    steps : dict
        Per excited axis, (step numbers, excitation amplitude [A]) of the rows of ``arrays``.
    threshold : float
        Score (residual over the larger of the noise and the neighbours' local scatter) above which a
        cell is an outlier.

    Returns
    -------
    list of Outlier
        Largest score first.

    Notes
    -----
    A cell counts when its score exceeds ``threshold``, its residual is the
    largest of its own and its two neighbours' (the neighbours' residuals carry
    half of it, by the interpolation), and no other channel of its step scores
    above a tenth of the threshold (a resonance narrower than the grid moves two
    channels or more together; a typo moves one).
    """
    found = []
    for axis, (frequency, coefficients, noise) in arrays.items():
        numbers, amplitude = steps[axis]
        response = coefficients / amplitude[:, None]
        sigma = noise / amplitude[:, None]
        sizes, scores = np.zeros(response.shape), np.zeros(response.shape)
        for j in range(len(CHANNELS)):
            sizes[:, j], scores[:, j] = _scores(frequency, response[:, j], sigma[:, j])
        crowded = np.count_nonzero(scores > 0.1 * threshold, axis=1) >= _COHERENT
        for k, j in zip(*np.nonzero(scores > threshold)):
            if crowded[k] or sizes[k, j] < np.max(sizes[max(k - 1, 0) : k + 2, j]):
                continue
            found.append(Outlier(axis, int(numbers[k]), CHANNELS[j], float(frequency[k]), float(scores[k, j]),
                                 complex(coefficients[k, j])))
    return sorted(found, key=lambda o: -o.score)


def outlier_text(outlier, frame, source, source_lines=None, original=None):
    """Where an outlier is (the ``.m`` file:line, or the log and its rows) and what it is, for a message."""
    distance = f"at {outlier.frequency_hz:.6g} Hz departs from its neighbours by {outlier.score:.3g} times the noise"
    lines = (source_lines or {}).get(outlier.axis)
    if original and lines is not None and outlier.step < len(lines):
        index = [name for name, _ in _LAYOUT].index(outlier.channel)
        column = 3 + index
        line = lines[outlier.step]
        line = line[column - 1] if isinstance(line, list) else line
        value = outlier.value * _LAYOUT[index][1]  # in the file's unit (um for positions)
        return (f"{original}:{line}", f"{variable_name(outlier.axis)} row {outlier.step + 1}, column {column} "
                                      f"({THESIS_COLUMNS[column - 1]}) = {value:.6g} {distance}")
    what = f"channel {outlier.channel} = {outlier.value:.6g} {distance}"
    mask = ((frame["excited_axis"] == outlier.axis) & (frame["step"] == outlier.step)).to_numpy()
    row = np.flatnonzero(mask & (frame["channel"] == outlier.channel).to_numpy())
    return source, f"{_where(frame, mask)}, row {int(row[0])} ({outlier.channel}): {what}"


def exclude_outliers(frame, outliers, estimator):
    """The log without the steps of ``outliers``; for the MIMO estimate a radial step goes on every radial axis.

    The four radial runs share one frequency grid, and ``P = V U^-1`` needs all four at a frequency.
    """
    frequency = frame["frequency_hz"].to_numpy()
    drop = np.zeros(len(frame), dtype=bool)
    for outlier in outliers:
        if estimator == "mimo" and outlier.axis in RADIAL_AXES:
            drop |= frame["excited_axis"].isin(RADIAL_AXES).to_numpy() & (np.abs(frequency / outlier.frequency_hz - 1) <= 1e-6)
        else:
            drop |= ((frame["excited_axis"] == outlier.axis) & (frame["step"] == outlier.step)).to_numpy()
    return frame[~drop].reset_index(drop=True)


def check_log(frame, arrays, settings, source, source_lines=None, original=None):
    """The model-free plausibility checks of an identification log, as the FRF stage runs them (axes, outliers).

    Parameters
    ----------
    frame : pandas.DataFrame
        The validated log (noise filled in where it had none).
    arrays : dict
        `ambid.frf.log_arrays` of ``frame``.
    settings : dict
        The ``frf:`` config section (`FRF_SETTINGS`).
    source : str
        The log file.
    source_lines, original : optional
        For a log converted from a thesis ``.m`` file: the line of each step (per axis) and the ``.m`` path.

    Returns
    -------
    frame : pandas.DataFrame
        The log, without excluded steps.
    findings : list of ambid.findings.Finding

    Raises
    ------
    LogError
        A missing radial axis (MIMO), or an outlier when ``settings["outliers"] == "refuse"``.
    """
    settings = {**FRF_SETTINGS, **(settings or {})}
    check_axes(frame, settings["estimator"], original or source)
    steps = {}
    for axis, group in frame.groupby("excited_axis", sort=False):
        per_step = group.groupby("step")["amplitude_a"].first().sort_index()
        steps[axis] = (per_step.index.to_numpy(), per_step.to_numpy())
    outliers = find_outliers(arrays, steps, settings["outlier_threshold"])
    if not outliers:
        return frame, []
    texts = [outlier_text(o, frame, source, source_lines, original) for o in outliers]
    if settings["outliers"] != "exclude":
        where, what = texts[0]
        more = f" ({len(outliers) - 1} more such cell(s))" if len(outliers) > 1 else ""
        raise LogError(where, f"{what}: a typo or a glitch{more}; correct the log, or set frf.outliers: exclude to leave "
                              "such steps out")
    mimo = settings["estimator"] == "mimo"
    findings = [Finding("frf", "warning", "outlier_excluded", f"{o.axis} step {o.step} ({o.frequency_hz:.6g} Hz)",
                        f"{where}: {what}; the step is left out of the FRF"
                        + (" (on every radial axis, for the MIMO estimate)" if mimo and o.axis in RADIAL_AXES else ""),
                        o.score)
                for o, (where, what) in zip(outliers, texts)]
    return exclude_outliers(frame, outliers, settings["estimator"]), findings
