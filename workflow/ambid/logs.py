"""The identification log (schema version 1): one row per (excited axis, step, channel).

The stepped-sine identification (thesis ch. 4.2) excites one axis at a time
and, for every accepted frequency step, records the Fourier coefficient of
every channel at the excitation frequency.  The 20 channels are, for each axis
of `ALL_AXES`, the plant input ``U2_<axis>`` (commanded control current [A]),
the plant output ``V2_<axis>`` (measured position [m]) and the measured coil
currents ``I_upper_<axis>`` and ``I_lower_<axis>`` [A].  A step carries at least
the channels of its own bearing (`axis_channels`: the 16 radial channels when a
radial axis is excited, the 4 axial ones when Z is), and either all or none of
the other bearing's, the same on every step of an excited axis.  The coil
currents are optional for a whole log: every step carries its bearing's, or no
step carries any (a logger that records positions and commands only).  Complex
coefficients are stored as ``re`` / ``im`` columns in SI units, with the
standard deviation ``noise_std`` of each coefficient.  `validate_identification_log` checks the
contract on writing and on reading, so a malformed log fails with the rows at
fault instead of corrupting an FRF downstream.

An optional column ``level`` (integer, default 0) marks repeated steps: level 0
is the step as the adaptive stepped sine accepted it; a step measured again at
a lower excitation amplitude, at the same frequency, has level 1.  Pairs of
levels measure the amplitude-dependent (nonlinear) error of the FRF
(`ambid.floor`); every estimate of the FRF itself uses level 0.

The multisine log (kind ``multisine_log``, below) is the second log kind, for
random-phase multisine runs (`ambid.multisine`): one row per pass (``coarse``,
``zoom``), realization, experiment, period, line and channel, the line's
``frequency_hz`` (a harmonic ``line`` of the pass' ``f0``) and ``role``
(excited, odd or even detection line), and the period's Fourier coefficient
``re``/``im`` of each of `CHANNELS` plus the excitation's own complex
amplitude per axis, `REFERENCE_CHANNELS` (the design).  The per-period
spectra at the excited and detection lines are the compact record from which
the FRF stage recomputes the BLA, its noise (periods), its nonlinear error
(realizations, levels) and the distortion levels (detection lines);
`validate_multisine_log` checks it the same way, errors naming the file and
the rows with their pass, realization, experiment and period.
"""

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from .errors import LogError
from .io import read_parquet, write_parquet
from .machine import ALL_AXES, RADIAL_AXES

__all__ = [
    "CHANNELS",
    "RADIAL_CHANNELS",
    "AXIAL_CHANNELS",
    "COIL_CURRENT_CHANNELS",
    "axis_channels",
    "run_matrix",
    "log_source",
    "repeated_steps",
    "peak_excitation_a",
    "COLUMNS",
    "OPTIONAL_COLUMNS",
    "KIND",
    "UNITS",
    "channel_unit",
    "identification_frame",
    "write_identification_log",
    "read_identification_log",
    "validate_identification_log",
    "noise_from_scatter",
    "scatter_std",
    "MULTISINE_KIND",
    "MULTISINE_COLUMNS",
    "MULTISINE_UNITS",
    "REFERENCE_CHANNELS",
    "LINE_ROLES",
    "multisine_frame",
    "write_multisine_log",
    "read_multisine_log",
    "is_multisine_log",
    "has_coil_currents",
    "validate_multisine_log",
]

KIND = "identification_log"

#: Channel names in their canonical order: U2 of all axes, V2 of all axes, then coil current pairs.
CHANNELS = (
    tuple(f"U2_{axis}" for axis in ALL_AXES)
    + tuple(f"V2_{axis}" for axis in ALL_AXES)
    + tuple(name for axis in ALL_AXES for name in (f"I_upper_{axis}", f"I_lower_{axis}"))
)

#: The channels of the radial bearings (DX, DY, NX, NY) and of the axial bearing (Z), in `CHANNELS` order.
COIL_CURRENT_CHANNELS = tuple(name for name in CHANNELS if name.startswith("I_"))
RADIAL_CHANNELS = tuple(name for name in CHANNELS if not name.endswith("_Z"))
AXIAL_CHANNELS = tuple(name for name in CHANNELS if name.endswith("_Z"))

#: Column name -> kind of dtype required ("str", "int" or "float").
COLUMNS = {
    "excited_axis": "str",
    "step": "int",
    "frequency_hz": "float",
    "amplitude_a": "float",
    "channel": "str",
    "re": "float",
    "im": "float",
    "noise_std": "float",
    "attempts": "int",
}
#: Columns a log may carry beyond `COLUMNS`: column name -> kind of dtype.
OPTIONAL_COLUMNS = {"level": "int"}

_COEFFICIENT_UNIT = "SI (A for U2_* and I_*, m for V2_*)"
UNITS = {
    "frequency_hz": "Hz",
    "amplitude_a": "A",
    "re": _COEFFICIENT_UNIT,
    "im": _COEFFICIENT_UNIT,
    "noise_std": _COEFFICIENT_UNIT,
    "step": "-",
    "attempts": "-",
    "level": "-",
}
_STEP_KEYS = ("excited_axis", "step", "frequency_hz", "amplitude_a", "attempts", "coefficients", "noise_std")
_MAX_GROUPS_QUOTED = 4


def channel_unit(name):
    """Unit of a channel's coefficient: ``"m"`` for positions ``V2_*``, ``"A"`` for currents.

    Raises
    ------
    LogError
        If ``name`` is not one of `CHANNELS`.
    """
    if name not in CHANNELS:
        raise LogError("channel_unit", f"unknown channel {name!r}; known: {', '.join(CHANNELS)}")
    return "m" if name.startswith("V2_") else "A"


def axis_channels(axis):
    """The channels every step exciting ``axis`` must carry: its bearing's (`RADIAL_CHANNELS` or `AXIAL_CHANNELS`)."""
    return RADIAL_CHANNELS if axis in RADIAL_AXES else AXIAL_CHANNELS


def run_matrix(arrays, kind, axes=RADIAL_AXES, part=1):
    """One kind of channel of the runs exciting ``axes`` as a matrix per frequency: the MIMO estimate's ``U`` or ``V``.

    Parameters
    ----------
    arrays : dict
        `ambid.frf.log_arrays` of a log: per excited axis its frequencies, coefficients and noise.
    kind : {"U2", "V2", "I_upper", "I_lower"}
        The channels ``{kind}_{axis}`` (control currents, positions, coil currents).
    axes : sequence of str
        The runs (columns) and the channels' axes (rows), in this order.
    part : {1, 2}
        Coefficients (1) or their noise standard deviations (2).

    Returns
    -------
    array (n, len(axes), len(axes))
        ``[f, b, r]``: channel ``{kind}_{b}`` in the run exciting ``r``.
    """
    columns = [CHANNELS.index(f"{kind}_{axis}") for axis in axes]
    return np.stack([arrays[run][part][:, columns] for run in axes], axis=2)


def log_source(path, info):
    """The file a user gave for a log: its provenance's ``file`` when it was converted (a ``.m``, a table), else ``path``.

    Errors about a log's content name this file, not the Parquet it was converted to.
    """
    original = ((info or {}).get("metadata") or {}).get("provenance", {}).get("file")
    return f"{original} (converted to {path})" if original and str(original) != str(path) else str(path)


def repeated_steps(frame):
    """How many steps of an identification log were measured again at a lower amplitude (``level`` > 0).

    A log without a ``level`` column has none.
    """
    if "level" not in frame.columns:
        return 0
    return len(frame.loc[frame["level"] > 0, ["excited_axis", "step"]].drop_duplicates())


def peak_excitation_a(frame):
    """The largest excitation amplitude of each excited axis at the log's first level [A]: ``{axis: amplitude}``."""
    first = frame if "level" not in frame.columns else frame[frame["level"] == 0]
    peaks = first.groupby("excited_axis")["amplitude_a"].max()
    return {str(axis): float(value) for axis, value in peaks.items()}


def identification_frame(steps):
    """Long-format identification log from a list of step records.

    Parameters
    ----------
    steps : list of dict
        One record per excited axis and accepted frequency step, with keys
        ``excited_axis`` (str, one of `ALL_AXES`), ``step`` (int, 0-based index
        in that axis' grid), ``frequency_hz`` (float, excitation frequency
        [Hz]), ``amplitude_a`` (float, excitation amplitude finally used [A]),
        ``attempts`` (int >= 1, amplitude adaptations used), ``coefficients``
        (complex array (20,), Fourier coefficients in `CHANNELS` order [A or m])
        and ``noise_std`` (float array (20,), standard deviation of each
        coefficient [A or m]); optionally ``channels`` (the names, in any
        order, of the channels the step carries; the two arrays then hold
        those channels only) and ``level`` (int, 0 unless the step is a repeat at
        a lower amplitude).

    Returns
    -------
    pandas.DataFrame
        Columns ``excited_axis, step, frequency_hz, amplitude_a, channel, re,
        im, noise_std, attempts``; one row per (step, channel), ordered by axis
        (`ALL_AXES` order), step and channel (`CHANNELS` order).

    Raises
    ------
    LogError
        If a record lacks a key, names an unknown axis or has arrays of the wrong shape.
    """
    for index, record in enumerate(steps):
        where = f"step record {index}"
        missing = [key for key in _STEP_KEYS if key not in record]
        if missing:
            raise LogError("identification_frame", f"{where}: missing key(s) {missing}")
        if record["excited_axis"] not in ALL_AXES:
            raise LogError("identification_frame", f"{where}: unknown axis {record['excited_axis']!r}")
        n_channels = len(record.get("channels", CHANNELS))
        for key in ("coefficients", "noise_std"):
            if np.shape(record[key]) != (n_channels,):
                raise LogError("identification_frame", f"{where}: {key} has shape {np.shape(record[key])}, expected ({n_channels},)")
    records = sorted(steps, key=lambda r: (ALL_AXES.index(r["excited_axis"]), int(r.get("level", 0)), int(r["step"])))
    index = {name: k for k, name in enumerate(CHANNELS)}
    names, coefficients, noise_std = [], [], []
    for r in records:  # each step's channels in canonical order
        channels = list(r.get("channels", CHANNELS))
        order = np.argsort([index.get(name, len(CHANNELS)) for name in channels], kind="stable")
        names.append(np.asarray(channels, dtype=object)[order])
        coefficients.append(np.asarray(r["coefficients"], dtype=complex)[order])
        noise_std.append(np.asarray(r["noise_std"], dtype=float)[order])
    counts = np.array([len(n) for n in names], dtype=np.int64)
    coefficients = np.concatenate(coefficients or [np.zeros(0, complex)])
    noise_std = np.concatenate(noise_std or [np.zeros(0)])

    def per_step(key, dtype):
        return np.repeat(np.array([r.get(key, 0) for r in records], dtype=dtype), counts)

    return pd.DataFrame(
        {
            "excited_axis": per_step("excited_axis", object),
            "step": per_step("step", np.int64),
            "frequency_hz": per_step("frequency_hz", np.float64),
            "amplitude_a": per_step("amplitude_a", np.float64),
            "channel": np.concatenate(names or [np.zeros(0, dtype=object)]),
            "re": coefficients.real.astype(np.float64),
            "im": coefficients.imag.astype(np.float64),
            "noise_std": noise_std,
            "attempts": per_step("attempts", np.int64),
            "level": per_step("level", np.int64),
        }
    )


def write_identification_log(frame, path, metadata=None):
    """Validate and write an identification log as Parquet (atomically).

    Parameters
    ----------
    frame : pandas.DataFrame
        As built by `identification_frame`.
    path : str or Path
        Target file, conventionally ``data/<machine>/<run>/identification.parquet``.
    metadata : dict, optional
        JSON-serialisable run metadata (machine, run, rig, seed, settings, ...),
        stored with ``channel_units`` (channel -> ``"A"`` / ``"m"``).

    Raises
    ------
    LogError
        If the frame breaks the contract; nothing is written then.
    """
    validate_identification_log(frame, str(path))
    channel_units = {name: channel_unit(name) for name in CHANNELS}
    columns = list(COLUMNS) + [name for name in OPTIONAL_COLUMNS if name in frame.columns]
    write_parquet(
        frame[columns].reset_index(drop=True),
        path,
        units=UNITS,
        kind=KIND,
        metadata={**(metadata or {}), "channel_units": channel_units},
    )


def read_identification_log(path):
    """Read and validate an identification log.

    Returns
    -------
    frame : pandas.DataFrame
    info : dict
        ``schema_version``, ``kind``, ``units`` and ``metadata`` (see `ambid.io.read_parquet`).

    Raises
    ------
    AmbidError
        If the file is no identification log of this schema version.
    LogError
        If its content breaks the contract.
    """
    frame, info = read_parquet(path, kind=KIND)
    frame = _plain_columns(frame)
    validate_identification_log(frame, str(path))
    if "level" not in frame.columns:
        frame = frame.assign(level=np.zeros(len(frame), dtype=np.int64))
    return frame, info


# ---------------------------------------------------------------------------- validation
def _ranges(positions):
    """``[12, 13, 14, 15, 20]`` -> ``"rows 12-15, 20"``."""
    positions = sorted(int(p) for p in positions)
    parts, start = [], positions[0]
    for previous, current in zip(positions, positions[1:] + [None]):
        if current != previous + 1:
            parts.append(f"{start}" if start == previous else f"{start}-{previous}")
            start = current
    word = "row" if len(positions) == 1 else "rows"
    return f"{word} {', '.join(parts)}"


def _where(frame, mask):
    """Rows selected by ``mask``, grouped by (excited_axis, step), as message text."""
    positions = np.flatnonzero(np.asarray(mask))
    groups = {}
    for position in positions:
        key = (frame["excited_axis"].iat[position], frame["step"].iat[position])
        groups.setdefault(key, []).append(position)
    parts = [f"{_ranges(rows)} (excited_axis={axis}, step={step})" for (axis, step), rows in list(groups.items())[:_MAX_GROUPS_QUOTED]]
    if len(groups) > _MAX_GROUPS_QUOTED:
        parts.append(f"and {len(groups) - _MAX_GROUPS_QUOTED} more (axis, step)")
    return ", ".join(parts)


def _check_row(frame, mask, source, what, per_channel=False):
    mask = np.asarray(mask, dtype=bool)
    if mask.any():
        first = int(np.flatnonzero(mask)[0])
        note = f" (first: channel {frame['channel'].iat[first]})" if per_channel else ""
        raise LogError(source, f"{_where(frame, mask)}: {what}{note}")


def _plain_columns(frame):
    """Categorical columns (pandas' or Parquet's dictionary encoding of a log from another writer) as their values."""
    categorical = [name for name in frame.columns if isinstance(frame[name].dtype, pd.CategoricalDtype)]
    if not categorical:
        return frame
    return frame.assign(**{name: frame[name].astype(frame[name].cat.categories.dtype) for name in categorical})


def _check_columns(frame, source, columns=COLUMNS, what="an identification log"):
    missing = [name for name in columns if name not in frame.columns]
    if missing:
        raise LogError(source, f"missing column(s) {missing}; {what} has {list(columns)}")
    optional = OPTIONAL_COLUMNS if columns is COLUMNS else {}
    extra = [name for name in frame.columns if name not in columns and name not in optional]
    if extra:
        also = f" and optionally {list(optional)}" if optional else ""
        raise LogError(source, f"unexpected column(s) {extra}; {what} has {list(columns)}{also}")
    required = {
        "str": pd.api.types.is_string_dtype,
        "int": pd.api.types.is_integer_dtype,
        "float": pd.api.types.is_float_dtype,
    }
    present = {**columns, **{name: kind for name, kind in optional.items() if name in frame.columns}}
    for name, kind in present.items():
        if not required[kind](frame[name]):
            raise LogError(source, f"column {name!r} has dtype {frame[name].dtype}, expected {kind}")
        missing_values = frame[name].isna().to_numpy()
        if kind != "float" and missing_values.any():  # NaN floats are reported by row, as not finite
            raise LogError(source, f"{_ranges(np.flatnonzero(missing_values)[:20])}: missing value in column {name!r}")


def _check_channel_sets(frame, sets, source):
    """Each step: its bearing's channels, all or none of the other's, the same set on every step of its axis."""

    def rows(axis, step):
        return _where(frame, ((frame["excited_axis"] == axis) & (frame["step"] == step)).to_numpy())

    # the coil currents are optional for a whole log: every step carries its bearing's, or no step carries any
    coils = any(name in COIL_CURRENT_CHANNELS for channels in sets for name in channels)
    first_of_axis = {}
    for (axis, step, *_), channels in sets.items():
        own = tuple(name for name in axis_channels(axis) if coils or name not in COIL_CURRENT_CHANNELS)
        other = AXIAL_CHANNELS if axis_channels(axis) is RADIAL_CHANNELS else RADIAL_CHANNELS
        other = tuple(name for name in other if coils or name not in COIL_CURRENT_CHANNELS)
        absent = [name for name in own if name not in channels]
        if absent:
            bearing = "radial" if axis in RADIAL_AXES else "axial"
            raise LogError(source, f"{rows(axis, step)}: missing channel(s) {', '.join(absent)} (a step exciting {axis} "
                                   f"carries the {len(own)} {bearing} channels; the other bearing's are optional, and "
                                   "the coil currents are, on every step or on none)")
        partial = [name for name in other if name not in channels]
        if 0 < len(partial) < len(other):
            raise LogError(source, f"{rows(axis, step)}: missing channel(s) {', '.join(partial)} (the other bearing's "
                                   f"channels are optional, but all or none of them)")
        if axis not in first_of_axis:
            first_of_axis[axis] = (step, channels)
        elif channels != first_of_axis[axis][1]:
            first_step, first = first_of_axis[axis]
            extra = sorted(channels ^ first, key=CHANNELS.index)
            raise LogError(source, f"{rows(axis, step)}: carries other channels than step {first_step} of {axis} "
                                   f"(differing: {', '.join(extra)}); every step of an axis carries the same channels")


def validate_identification_log(frame, source):
    """Check an identification log against the schema-1 contract.

    Parameters
    ----------
    frame : pandas.DataFrame
    source : str
        Where the frame comes from (file name), quoted in the message.

    Raises
    ------
    LogError
        Naming ``source`` and the offending rows (positional, 0-based) with
        their excited axis and step, when a column is missing, extra or of the
        wrong dtype; an axis or channel is unknown; a value is not finite;
        ``step < 0``, ``frequency_hz <= 0``, ``amplitude_a <= 0``,
        ``noise_std < 0`` or ``attempts < 1``; the excited axis' ``U2`` is 0
        (zero excitation); an (axis, step) has a duplicate channel, lacks one
        of its bearing's channels (`axis_channels`), carries part of the other
        bearing's, or carries other channels than the excited axis' first step;
        rows of an (axis, step) disagree on frequency, amplitude or attempts;
        or an axis' frequency grid does not strictly increase with step.
        With a ``level`` column: ``level < 0``, or a repeated step (level > 0)
        without its level-0 step at the same frequency.
    """
    frame = _plain_columns(frame)
    _check_columns(frame, source)
    frame = frame.reset_index(drop=True)
    if "level" not in frame.columns:
        frame = frame.assign(level=np.zeros(len(frame), dtype=np.int64))
    if frame.empty:
        raise LogError(source, "no rows (an identification log holds at least one step)")
    unknown_axis = ~frame["excited_axis"].isin(ALL_AXES).to_numpy()
    if unknown_axis.any():
        first = int(np.flatnonzero(unknown_axis)[0])
        raise LogError(
            source, f"{_where(frame, unknown_axis)}: unknown excited_axis {frame['excited_axis'].iat[first]!r}; known: {list(ALL_AXES)}"
        )
    unknown_channel = ~frame["channel"].isin(CHANNELS).to_numpy()
    if unknown_channel.any():
        first = int(np.flatnonzero(unknown_channel)[0])
        raise LogError(source, f"{_where(frame, unknown_channel)}: unknown channel {frame['channel'].iat[first]!r}")
    for name in ("frequency_hz", "amplitude_a", "re", "im", "noise_std"):
        _check_row(frame, ~np.isfinite(frame[name].to_numpy(dtype=float)), source, f"{name} is not finite", per_channel=True)
    _check_row(frame, frame["step"].to_numpy() < 0, source, "step < 0 (steps are 0-based grid indices)")
    _check_row(frame, frame["frequency_hz"].to_numpy() <= 0, source, "frequency_hz <= 0")
    _check_row(frame, frame["amplitude_a"].to_numpy() <= 0, source, "amplitude_a <= 0 (no excitation)")
    _check_row(frame, frame["noise_std"].to_numpy() < 0, source, "noise_std < 0", per_channel=True)
    _check_row(frame, frame["attempts"].to_numpy() < 1, source, "attempts < 1")
    _check_row(frame, frame["level"].to_numpy() < 0, source, "level < 0 (0: the step, 1, 2, ...: repeats at lower amplitude)")
    excitation = (frame["channel"] == "U2_" + frame["excited_axis"]).to_numpy()
    silent = excitation & (np.hypot(frame["re"].to_numpy(dtype=float), frame["im"].to_numpy(dtype=float)) == 0)
    _check_row(frame, silent, source, "the excited axis' control current U2 is 0 (zero excitation: no FRF point)",
               per_channel=True)

    duplicated = frame.duplicated(["excited_axis", "step", "level", "channel"], keep=False).to_numpy()
    _check_row(frame, duplicated, source, "duplicate channel within one (excited_axis, step, level)", per_channel=True)
    # unknown channels and duplicates are already rejected: check each step's channel set
    grouped = frame.groupby(["excited_axis", "step", "level"], sort=False)
    _check_channel_sets(frame, grouped["channel"].agg(frozenset), source)
    for name in ("frequency_hz", "amplitude_a", "attempts"):
        spread = grouped[name].nunique()
        disagreeing = spread[spread > 1]
        if len(disagreeing):
            axis, step, level = disagreeing.index[0]
            mask = ((frame["excited_axis"] == axis) & (frame["step"] == step) & (frame["level"] == level)).to_numpy()
            values = frame.loc[mask, name].unique()
            raise LogError(source, f"{_where(frame, mask)}: rows disagree on {name} ({', '.join(map(repr, values.tolist()))})")

    steps_frame = frame.groupby(["excited_axis", "level", "step"])["frequency_hz"].first().reset_index()
    base = steps_frame[steps_frame["level"] == 0].set_index(["excited_axis", "step"])["frequency_hz"]
    repeats = steps_frame[steps_frame["level"] > 0]
    if len(repeats):
        matched = base.reindex(pd.MultiIndex.from_frame(repeats[["excited_axis", "step"]])).to_numpy()
        orphan = ~(np.abs(matched / repeats["frequency_hz"].to_numpy() - 1) <= 1e-9)  # NaN (no level-0 step) is orphan too
        if orphan.any():
            axis, step, level = repeats.iloc[int(np.flatnonzero(orphan)[0])][["excited_axis", "step", "level"]]
            mask = ((frame["excited_axis"] == axis) & (frame["step"] == step) & (frame["level"] == level)).to_numpy()
            raise LogError(source, f"{_where(frame, mask)}: a repeat (level {level}) needs the level-0 step of the same "
                                   "axis and step at the same frequency")
    level0 = (frame["level"] == 0).to_numpy()
    for axis in ALL_AXES:
        grid = frame[level0 & (frame["excited_axis"] == axis)].groupby("step")["frequency_hz"].first().sort_index()
        steps, frequency_hz = grid.index.to_numpy(), grid.to_numpy()
        bad = np.flatnonzero(np.diff(frequency_hz) <= 0)
        if bad.size:
            k = bad[0]
            pair = (steps[k], steps[k + 1])
            mask = level0 & ((frame["excited_axis"] == axis) & frame["step"].isin(pair)).to_numpy()
            raise LogError(
                source,
                f"{_where(frame, mask)}: frequency grid of {axis} not strictly increasing with step "
                f"(step {pair[1]} at {frequency_hz[k + 1]:.6g} Hz follows step {pair[0]} at {frequency_hz[k]:.6g} Hz)",
            )


def noise_from_scatter(frame, source="<frame>"):
    """Fill a log's unknown noise with each channel's scatter between neighbouring steps.

    A log without a noise estimate (the thesis' ``.m`` format; ``noise_std`` all 0)
    would make every FRF point exact.  The noise of a channel is a property of its
    sensor, the same whatever axis is excited, so it is estimated per channel as
    the smallest, over the excited axes, of the robust second-difference scatter

    ``sigma = median |c[k+1] - 2 c[k] + c[k-1]| / sqrt(6 ln 2)``  (`scatter_std`)

    of the coefficients ``c`` along the steps (exact for complex white noise,
    where ``|d|^2`` is exponential with mean ``6 sigma^2``; a smooth response
    adds little to a second difference, and the axes that leave a channel at
    the noise floor give its noise directly).

    Parameters
    ----------
    frame : pandas.DataFrame
        Identification log; its ``noise_std`` is replaced.
    source : str
        Named in errors.

    Returns
    -------
    pandas.DataFrame
        A copy with ``noise_std`` per channel, constant over the steps.

    Raises
    ------
    LogError
        If no excited axis has three steps, or a channel's scatter is 0 on
        every excited axis (a constant or copied channel); an axis on which a
        channel is constant (zero-padded) is left out of that channel's estimate.
    """
    frame = frame.sort_values(["excited_axis", "channel", "step"])
    estimates, logged = {}, set()
    steps = frame if "level" not in frame.columns else frame[frame["level"] == 0]  # repeats are not neighbours
    for (axis, name), group in steps.groupby(["excited_axis", "channel"], sort=False):
        c = group["re"].to_numpy() + 1j * group["im"].to_numpy()
        if c.size >= 3:
            logged.add(name)
            sigma = scatter_std(c)
            if sigma > 0:  # a channel constant on one axis' run (zero padding) says nothing about its noise
                estimates[name] = min(estimates.get(name, np.inf), sigma)
    missing = sorted(set(frame["channel"]) - logged, key=CHANNELS.index)
    if missing:
        raise LogError(source, f"noise cannot be estimated (fewer than 3 steps on every excited axis): {', '.join(missing)}")
    silent = sorted(logged - set(estimates), key=CHANNELS.index)
    if silent:
        raise LogError(source, f"channel(s) {', '.join(silent)} do not scatter at all on any excited axis "
                               f"(constant or copied values)")
    frame = frame.assign(noise_std=frame["channel"].map(estimates).astype(float))
    return frame.sort_index()


def scatter_std(values, window=None):
    """Robust standard deviation of complex white noise on a smooth sequence, from its second differences.

    ``sigma = median |c[k+1] - 2 c[k] + c[k-1]| / sqrt(6 ln 2)``: for complex white
    noise of standard deviation ``sigma`` (per complex value, ``E|n|^2 = sigma^2``)
    the second difference has ``E|d|^2 = 6 sigma^2`` and ``|d|^2`` is exponential,
    whose median is ``ln 2`` times its mean.

    Parameters
    ----------
    values : complex array (n,), n >= 3
    window : int, optional
        None: one value for the whole sequence.  An odd number of points: a
        running median of that many second differences, one value per point
        (the ends take the nearest full window), for noise that changes along
        the sequence.

    Returns
    -------
    float or array (n,)
    """
    values = np.asarray(values, dtype=complex)
    d = np.abs(values[2:] - 2 * values[1:-1] + values[:-2]) / np.sqrt(6 * np.log(2))
    if window is None:
        return float(np.median(d))
    half = min(window // 2, (d.size - 1) // 2)
    padded = np.concatenate([np.full(1, d[0]), d, np.full(1, d[-1])])  # one per point: the ends repeat their neighbour
    starts = np.clip(np.arange(values.size) - half, 0, padded.size - 2 * half - 1)
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    return np.median(windows[starts], axis=1)


# ================================================================================ multisine log
# A second log kind, for random-phase multisine runs (`ambid.multisine`): what a record holds is the
# per-period spectrum, so that the FRF stage can recompute everything (the BLA, the noise from the
# periods, the nonlinear distortion from the realizations, the even and odd detection lines).

MULTISINE_KIND = "multisine_log"

#: The excitation's own complex amplitudes E_u per axis (the design: zero where an axis is not excited).
REFERENCE_CHANNELS = tuple(f"E_{axis}" for axis in ALL_AXES)

#: Roles of a line: excited, an odd harmonic the random grid left out, an even harmonic beside an excited one.
LINE_ROLES = ("excited", "odd_detection", "even_detection")

#: Column name -> kind of dtype required, of a multisine log.
MULTISINE_COLUMNS = {
    "pass": "str",
    "realization": "int",
    "experiment": "int",
    "period": "int",
    "line": "int",
    "frequency_hz": "float",
    "role": "str",
    "channel": "str",
    "re": "float",
    "im": "float",
}
MULTISINE_UNITS = {
    "frequency_hz": "Hz",
    "re": "SI (A for U2_*, I_* and E_*, m for V2_*)",
    "im": "SI (A for U2_*, I_* and E_*, m for V2_*)",
    "realization": "-",
    "experiment": "-",
    "period": "-",
    "line": "-",
}
_RECORD = ["pass", "realization", "experiment", "period"]


def multisine_frame(passes):
    """Long-format multisine log from the passes of a run.

    Parameters
    ----------
    passes : list of dict
        One per pass (``coarse``, ``zoom``), with ``name`` (str), ``lines``
        (int array (L,), harmonic numbers of the pass' ``f0``), ``frequency_hz``
        (array (L,) = lines * f0), ``role`` (str array (L,), `LINE_ROLES`),
        ``spectra`` (complex array (R, E, P, 20, L): per realization,
        experiment and period, the Fourier coefficient of each of `CHANNELS`
        at each line, phase referred to the start of the excitation, SI units)
        and ``reference`` (complex array (R, E, 5, L): the complex amplitude of
        each axis' excitation at each line).

    Returns
    -------
    pandas.DataFrame
        Columns of `MULTISINE_COLUMNS`; one row per (pass, realization,
        experiment, period, line, channel), the reference channels
        `REFERENCE_CHANNELS` repeated in every period.
    """
    parts = []
    names = np.array(CHANNELS + REFERENCE_CHANNELS, dtype=object)
    for item in passes:
        spectra, reference = np.asarray(item["spectra"]), np.asarray(item["reference"])
        realizations, experiments, periods, n_channels, n_lines = spectra.shape
        if n_channels != len(CHANNELS) or reference.shape != (realizations, experiments, len(ALL_AXES), n_lines):
            raise LogError("multisine_frame", f"pass {item['name']!r}: spectra {spectra.shape} and reference "
                           f"{reference.shape} do not fit (R, E, P, {len(CHANNELS)}, L) and (R, E, {len(ALL_AXES)}, L)")
        values = np.concatenate([spectra, np.repeat(reference[:, :, None], periods, axis=2)], axis=3)  # (R,E,P,25,L)
        values = np.moveaxis(values, 3, 4)  # (R, E, P, L, 25)
        r, e, p, k, c = np.indices(values.shape).reshape(5, -1)
        parts.append(pd.DataFrame({
            "pass": np.full(r.size, item["name"], dtype=object),
            "realization": r.astype(np.int64),
            "experiment": e.astype(np.int64),
            "period": p.astype(np.int64),
            "line": np.asarray(item["lines"], dtype=np.int64)[k],
            "frequency_hz": np.asarray(item["frequency_hz"], dtype=np.float64)[k],
            "role": np.asarray(item["role"], dtype=object)[k],
            "channel": names[c],
            "re": values.real.ravel().astype(np.float64),
            "im": values.imag.ravel().astype(np.float64),
        }))
    return pd.concat(parts, ignore_index=True)


def write_multisine_log(frame, path, metadata=None):
    """Validate and write a multisine log as Parquet (atomically); see `write_identification_log`."""
    validate_multisine_log(frame, str(path))
    channel_units = {name: ("A" if name.startswith("E_") else channel_unit(name)) for name in CHANNELS + REFERENCE_CHANNELS}
    write_parquet(frame[list(MULTISINE_COLUMNS)].reset_index(drop=True), path, units=MULTISINE_UNITS,
                  kind=MULTISINE_KIND, metadata={**(metadata or {}), "channel_units": channel_units})


def has_coil_currents(frame):
    """Whether a log (stepped sine or multisine) carries the coil currents, optional for a whole log."""
    return bool(frame["channel"].isin(COIL_CURRENT_CHANNELS).any())


def is_multisine_log(path):
    """Whether a Parquet file written by ambid holds a multisine log (its ``ambid.kind``), without reading its rows."""
    try:
        metadata = pq.read_schema(path).metadata or {}
    except (OSError, pa.ArrowInvalid) as error:
        raise LogError(str(path), f"not a readable Parquet file ({error})") from None
    return metadata.get(b"ambid.kind", b"").decode() == MULTISINE_KIND


def read_multisine_log(path):
    """Read and validate a multisine log; returns ``(frame, info)`` as `read_identification_log`."""
    frame, info = read_parquet(path, kind=MULTISINE_KIND)
    validate_multisine_log(frame, str(path))
    return frame, info


def _where_records(frame, mask):
    """Rows selected by ``mask``, grouped by (pass, realization, experiment, period), as message text."""
    positions = np.flatnonzero(np.asarray(mask))
    groups = {}
    for position in positions:
        key = tuple(frame[name].iat[position] for name in _RECORD)
        groups.setdefault(key, []).append(position)
    parts = [f"{_ranges(rows)} (pass={key[0]}, realization={key[1]}, experiment={key[2]}, period={key[3]})"
             for key, rows in list(groups.items())[:_MAX_GROUPS_QUOTED]]
    if len(groups) > _MAX_GROUPS_QUOTED:
        parts.append(f"and {len(groups) - _MAX_GROUPS_QUOTED} more records")
    return ", ".join(parts)


def _fail(frame, mask, source, what):
    mask = np.asarray(mask, dtype=bool)
    if mask.any():
        first = int(np.flatnonzero(mask)[0])
        raise LogError(source, f"{_where_records(frame, mask)}: {what} (first: line {frame['line'].iat[first]}, "
                               f"channel {frame['channel'].iat[first]})")


def validate_multisine_log(frame, source):
    """Check a multisine log against its contract (schema version 1).

    Parameters
    ----------
    frame : pandas.DataFrame
    source : str
        Where the frame comes from (file name), quoted in the message.

    Raises
    ------
    LogError
        Naming ``source`` and the offending rows (positional, 0-based) with
        their pass, realization, experiment and period, when a column is
        missing, extra or of the wrong dtype; a channel or role is unknown; a
        value is not finite; an index is negative, ``line < 1`` or
        ``frequency_hz <= 0``; a pass' lines are not harmonics of one ``f0``
        (``frequency_hz / line`` constant); a row is duplicated or a (record,
        line) lacks a channel (the coil currents ``I_*`` may be absent from the
        whole log); the records of a pass differ in their lines or
        periods, a pass has fewer than 2 periods (no noise estimate) or an
        incomplete realization x experiment grid; a line's role differs
        between records; a reference channel changes between periods; an
        excited line has no excitation, a detection line has one, or an axis
        excited at a line reads a control current U2 of exactly 0.
    """
    _check_columns(frame, source, MULTISINE_COLUMNS, "a multisine log")
    frame = frame.reset_index(drop=True)
    if frame.empty:
        raise LogError(source, "no rows (a multisine log holds at least one pass)")
    known = CHANNELS + REFERENCE_CHANNELS
    _fail(frame, ~frame["channel"].isin(known).to_numpy(), source, f"unknown channel; known: {', '.join(known)}")
    if not has_coil_currents(frame):  # the coil currents are optional for a whole log
        known = tuple(name for name in known if name not in COIL_CURRENT_CHANNELS)
    _fail(frame, ~frame["role"].isin(LINE_ROLES).to_numpy(), source, f"unknown role; known: {', '.join(LINE_ROLES)}")
    for name in ("frequency_hz", "re", "im"):
        _fail(frame, ~np.isfinite(frame[name].to_numpy(dtype=float)), source, f"{name} is not finite")
    for name in ("realization", "experiment", "period"):
        _fail(frame, frame[name].to_numpy() < 0, source, f"{name} < 0 (0-based)")
    _fail(frame, frame["line"].to_numpy() < 1, source, "line < 1 (lines are harmonic numbers of the period)")
    _fail(frame, frame["frequency_hz"].to_numpy() <= 0, source, "frequency_hz <= 0")
    f0 = frame["frequency_hz"].to_numpy() / frame["line"].to_numpy()
    for name, group in frame.groupby("pass", sort=False):
        reference = float(np.median(f0[group.index]))
        off = np.zeros(len(frame), dtype=bool)
        off[group.index] = np.abs(f0[group.index] / reference - 1) > 1e-9
        _fail(frame, off, source, f"frequency_hz is not line x f0 of pass {name!r} (f0 = {reference:.9g} Hz)")
    duplicated = frame.duplicated(_RECORD + ["line", "channel"], keep=False).to_numpy()
    _fail(frame, duplicated, source, "duplicate channel within one (record, line)")
    sizes = frame.groupby(_RECORD + ["line"], sort=False)["channel"].transform("size").to_numpy()
    incomplete = sizes != len(known)
    if incomplete.any():
        first = int(np.flatnonzero(incomplete)[0])
        key = frame.loc[first, _RECORD + ["line"]]
        same = np.ones(len(frame), dtype=bool)
        for name in _RECORD + ["line"]:
            same &= (frame[name] == key[name]).to_numpy()
        absent = [name for name in known if name not in set(frame.loc[same, "channel"])]
        raise LogError(source, f"{_where_records(frame, same)}: line {key['line']} lacks channel(s) {', '.join(absent)}")
    for name, group in frame.groupby("pass", sort=False):
        lines_per_record = group.groupby(_RECORD)["line"].nunique()
        if lines_per_record.nunique() != 1 or lines_per_record.iloc[0] != group["line"].nunique():
            raise LogError(source, f"pass {name!r}: the records do not all hold the same lines "
                                   f"({lines_per_record.min()} to {lines_per_record.max()} of {group['line'].nunique()})")
        periods = group.groupby(["realization", "experiment"])["period"].nunique()
        if periods.min() < 2 or periods.nunique() != 1:
            raise LogError(source, f"pass {name!r}: every (realization, experiment) needs the same number (>= 2) of "
                                   f"periods (the noise is their scatter); found {sorted(set(periods.tolist()))}")
        pairs = group.groupby(["realization", "experiment"]).ngroups
        if pairs != group["realization"].nunique() * group["experiment"].nunique():
            raise LogError(source, f"pass {name!r}: not every realization has every experiment")
        roles = group.groupby("line")["role"].nunique()
        if (roles > 1).any():
            line = int(roles[roles > 1].index[0])
            raise LogError(source, f"pass {name!r}: line {line} has different roles in different records")
    is_reference = frame["channel"].str.startswith("E_").to_numpy()
    amplitude = np.hypot(frame["re"].to_numpy(dtype=float), frame["im"].to_numpy(dtype=float))
    reference = frame[is_reference]
    spread = reference.groupby(["pass", "realization", "experiment", "line", "channel"])[["re", "im"]].transform("nunique")
    changing = np.zeros(len(frame), dtype=bool)
    changing[reference.index] = (spread.max(axis=1) > 1).to_numpy()
    _fail(frame, changing, source, "a reference channel E_* changes between periods (it is the design, one per record)")
    excitation = pd.Series(np.where(is_reference, amplitude, 0.0)).groupby(
        [frame["pass"], frame["line"]]).transform("max").to_numpy()
    excited = (frame["role"] == "excited").to_numpy()
    _fail(frame, excited & (excitation == 0), source, "an excited line has no excitation (all E_* are 0)")
    _fail(frame, ~excited & (excitation > 0), source, "a detection line carries excitation (E_* not 0)")
    # an axis excited at a line must move its control current there: U2 of exactly 0 is a dead channel
    axis_of = frame["channel"].str.slice(3).where(frame["channel"].str.startswith("U2_"))
    key = [frame["pass"], frame["realization"], frame["experiment"], frame["line"]]
    drive = {axis: pd.Series(np.where(frame["channel"] == f"E_{axis}", amplitude, 0.0)).groupby(key).transform("max")
             for axis in ALL_AXES}
    driven = np.zeros(len(frame), dtype=bool)
    for axis in ALL_AXES:
        driven |= ((axis_of == axis).to_numpy() & (drive[axis].to_numpy() > 0))
    _fail(frame, driven & (amplitude == 0), source,
          "the control current U2 of an axis excited at this line is 0 (zero excitation: no FRF point)")
