"""Readers for the logs users have, converted once, at the edge, into the canonical identification log.

Every reader returns the canonical log (`ambid.logs`, schema version 1, SI
units, validated) and its provenance: the user's file, the format and layout
read, the units assumed and one line per conversion decision (``notes``).
Errors are `ambid.errors.LogError` naming the user's file.

Formats (`FORMATS`, told from the file name by `detect_format`):

``parquet``
    The canonical log, as ambid writes it (Parquet with ambid metadata).
``table``
    CSV or Parquet written by other software, in one of two layouts:

    *long*, one row per (excited axis, step, channel): columns
    ``excited_axis, frequency_hz, channel, re, im`` and optionally ``step``
    (default: the rank of the frequency within the axis), ``amplitude_a``
    (default: the excited axis' ``|U2|``), ``noise_std`` (default 0: estimated
    from the scatter by the FRF stage), ``attempts`` (default 1) and ``level``
    (default 0; 1, 2, ...: the step measured again at a lower amplitude, with
    its step's number, `ambid.logs`);

    *wide*, one row per (excited axis, step, level): ``excited_axis, frequency_hz``
    and the optional ``step, amplitude_a, attempts, level``, then per channel
    ``<channel>_re`` and ``<channel>_im`` and optionally
    ``<channel>_noise_std``.  A unit may end a channel column's name
    (``V2_DX_re_um``); an empty cell means the step does not carry that channel.

    Coefficients are SI (m for ``V2_*``, A for ``U2_*`` and ``I_*``) unless
    the column names or the options ``position_unit`` (`POSITION_UNITS`) and
    ``current_unit`` (`CURRENT_UNITS`) say otherwise.  A logger that measures
    one current per axis, the control current ``I_<axis> = (I_upper - I_lower) / 2``
    (`CONTROL_CURRENT_CHANNELS`), gives it as such: it is written as ``I_upper = I``,
    ``I_lower = -I``, each with noise ``sqrt(2)`` times its own, so the FRF stage's
    coil current and its noise are the logged ones.
``m``
    A thesis-style ``.m`` file (`ambid.mfile`: 22 columns, or 18 radial and 6
    axial), parsed by a strict grammar, never evaluated.
``mat``
    A MATLAB ``.mat`` file (v4 to v7, through `scipy.io.loadmat`) holding the
    thesis matrices ``data_exc_dx`` ... ``data_exc_z`` in either layout of the
    ``.m`` file.  A v7.3 file (HDF5) is refused with how to re-save it.

and, at the FRF level (when no raw log exists), ``uff``: UFF dataset 58 FRFs
through pyuff (`read_uff_frf`), giving the FRF stage's table directly.
"""

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from .errors import AmbidError, LogError
from .frf import frf_table
from .io import read_parquet
from .logs import CHANNELS, KIND, identification_frame, scatter_std, validate_identification_log
from .machine import ALL_AXES, RADIAL_AXES
from .mfile import read_thesis_m, thesis_log
from .uff import AXIS_NODE_DIRECTION, ESTIMATORS

__all__ = [
    "FORMATS",
    "POSITION_UNITS",
    "CURRENT_UNITS",
    "detect_format",
    "read_log",
    "read_table_log",
    "read_mat_log",
    "read_uff_frf",
    "UFF_STD_WINDOW",
    "CONTROL_CURRENT_CHANNELS",
]

FORMATS = ("parquet", "table", "m", "mat", "uff")
#: unit name (lower case) -> factor to SI
POSITION_UNITS = {"m": 1.0, "mm": 1e-3, "um": 1e-6}
CURRENT_UNITS = {"a": 1.0, "ma": 1e-3}
#: points of the running median that estimates an imported FRF's standard deviation
UFF_STD_WINDOW = 15

_SUFFIXES = {".m": "m", ".mat": "mat", ".csv": "table", ".uff": "uff", ".unv": "uff"}
#: One current per axis, the control current ``(I_upper - I_lower) / 2``: a table may give it in place of the pair.
CONTROL_CURRENT_CHANNELS = tuple(f"I_{axis}" for axis in ALL_AXES)
_LONG_REQUIRED = ("excited_axis", "frequency_hz", "channel", "re", "im")
_PER_STEP = ("excited_axis", "step", "frequency_hz", "amplitude_a", "attempts", "level")
_WIDE_COLUMN = re.compile(rf"^({'|'.join(CHANNELS + CONTROL_CURRENT_CHANNELS)})_(re|im|noise_std)(?:_(\w+))?$")


def detect_format(path):
    """The format of a log file from its name (and, for ``.parquet``, whether ambid wrote it)."""
    path = Path(path)
    if path.is_dir():
        raise LogError(str(path), "is a directory, not a log file")
    suffix = path.suffix.lower()
    if suffix == ".parquet":
        try:
            metadata = pq.read_schema(path).metadata or {}
        except (OSError, pa.ArrowInvalid) as error:
            raise LogError(str(path), f"not a readable Parquet file ({error})") from None
        return "parquet" if b"ambid.schema_version" in metadata else "table"
    if suffix not in _SUFFIXES:
        raise LogError(str(path), f"cannot tell the format from the suffix {suffix!r}; give one of {', '.join(FORMATS)}")
    return _SUFFIXES[suffix]


def read_log(path, format=None, position_unit=None, current_unit=None):
    """Any identification log a user has, as the canonical log.

    Parameters
    ----------
    path : str or Path
    format : str, optional
        One of `FORMATS` but ``uff`` (an FRF, `read_uff_frf`); default from the file name (`detect_format`).
    position_unit, current_unit : str, optional
        Units of a table's coefficients (`POSITION_UNITS`, `CURRENT_UNITS`), when its column names do not say.

    Returns
    -------
    frame : pandas.DataFrame
        The validated canonical log, SI units.
    provenance : dict
        ``file``, ``format``, ``layout``, ``units`` and ``notes`` (a list of str).
    """
    path = str(path)
    format = format or detect_format(path)
    if Path(path).is_dir():
        raise LogError(path, "is a directory, not a log file")
    if format == "parquet":
        try:
            frame, _ = read_parquet(path, kind=KIND)
        except LogError:
            raise
        except AmbidError as error:
            raise LogError(path, str(error).removeprefix(f"{path}: ")) from None
        validate_identification_log(frame, path)
        return frame, {"file": path, "format": "parquet", "layout": "canonical (ambid schema 1)", "units": "SI", "notes": []}
    if format == "table":
        return read_table_log(path, position_unit, current_unit)
    if format == "m":
        notes = []
        frame = read_thesis_m(path, notes=notes)
        return frame, {"file": path, "format": "m", "layout": _thesis_layout(frame), "units": "um (V2), A", "notes": notes}
    if format == "mat":
        return read_mat_log(path)
    if format == "uff":
        raise LogError(path, "a UFF58 file holds FRFs, not an identification log: read it with read_uff_frf (run format uff)")
    raise LogError(path, f"unknown format {format!r}; known: {', '.join(FORMATS)}")


def _thesis_layout(frame):
    full = frame.groupby("excited_axis")["channel"].nunique().eq(len(CHANNELS)).all()
    return "thesis, 22 columns" if full else "thesis, 18 columns radial / 6 axial (each bearing's channels)"


def _unit_factor(name, units, source):
    if name.lower() not in units:
        raise LogError(source, f"unknown unit {name!r}; known: {', '.join(units)}")
    return units[name.lower()]


# ---------------------------------------------------------------------------- tables
def _read_any_table(path):
    if Path(path).is_dir():
        raise LogError(path, "is a directory, not a log file")
    try:
        if Path(path).suffix.lower() == ".parquet":
            return pq.read_table(path).to_pandas()
        return pd.read_csv(path, skipinitialspace=True)
    except (OSError, pa.ArrowInvalid, pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as error:
        raise LogError(path, f"not a readable table ({type(error).__name__}: {error})") from None


def _numeric(frame, name, path):
    """Column ``name`` as float; a cell that is no number is an error naming its row (1-based, after the header)."""
    values = pd.to_numeric(frame[name], errors="coerce")
    bad = values.isna() & frame[name].notna() & (frame[name].astype(str).str.strip() != "")
    if bad.any():
        row = int(np.flatnonzero(bad.to_numpy())[0])
        raise LogError(path, f"row {row + 1}: column {name!r} holds {frame[name].iat[row]!r}, not a number")
    return values.astype(float)


def read_table_log(path, position_unit=None, current_unit=None):
    """A CSV or plain Parquet log in the long or wide layout (module docstring) as the canonical log.

    Returns
    -------
    frame, provenance
        As `read_log`.
    """
    path = str(path)
    table = _read_any_table(path)
    table.columns = [str(c).strip() for c in table.columns]
    if table.empty:
        raise LogError(path, "no rows")
    if "channel" in table.columns:
        layout, records, notes, units = "long", *_long_records(table, path, position_unit, current_unit)
    elif any(_WIDE_COLUMN.match(c) for c in table.columns):
        layout, records, notes, units = "wide", *_wide_records(table, path, position_unit, current_unit)
    else:
        raise LogError(
            path,
            f"neither layout of a plain log table: the long layout has the columns {', '.join(_LONG_REQUIRED)} "
            f"(+ step, amplitude_a, noise_std, attempts), the wide one excited_axis, frequency_hz and <channel>_re, "
            f"<channel>_im per channel (e.g. V2_DX_re); found {', '.join(table.columns[:12])}",
        )
    frame = identification_frame(_control_currents(records, path, notes))
    validate_identification_log(frame, path)
    return frame, {"file": path, "format": "table", "layout": layout, "units": units, "notes": notes}


def _check_axes(axes, path):
    unknown = ~axes.isin(ALL_AXES)
    if unknown.any():
        row = int(np.flatnonzero(unknown.to_numpy())[0])
        raise LogError(path, f"row {row + 1}: unknown excited_axis {axes.iat[row]!r}; known: {', '.join(ALL_AXES)}")


def _per_step_defaults(steps, path, notes):
    """Fill step and attempts where the table has none (in place); amplitude_a is filled per record (`_record`)."""
    if "step" not in steps:  # a repeat (level > 0) is at its step's frequency, so it takes its number
        steps["step"] = steps.groupby("excited_axis")["frequency_hz"].rank(method="dense").astype(np.int64) - 1
        notes.append("no step column: steps numbered by increasing frequency within each excited axis")
    if "attempts" not in steps:
        steps["attempts"] = 1
    if "level" not in steps:
        steps["level"] = 0
    level = steps["level"].to_numpy(dtype=float)
    wrong = (level < 0) | (level != np.round(level))
    if wrong.any():
        row = int(np.flatnonzero(wrong)[0])
        raise LogError(path, f"row {row + 1}: level {level[row]:g} is not a whole number >= 0 (0: the step; 1, 2, ...: "
                             "the step measured again at a lower amplitude)")
    if "amplitude_a" not in steps:
        notes.append("no amplitude_a column: the excitation amplitude is taken as |U2| of the excited axis")


def _long_records(table, path, position_unit, current_unit):
    missing = [c for c in _LONG_REQUIRED if c not in table.columns]
    if missing:
        raise LogError(path, f"long layout (it has a channel column): missing column(s) {', '.join(missing)}; "
                             f"it has {', '.join(_LONG_REQUIRED)} and optionally step, amplitude_a, noise_std, attempts, level")
    notes = []
    extra = [c for c in table.columns if c not in _LONG_REQUIRED + ("step", "amplitude_a", "noise_std", "attempts", "level")]
    if extra:
        notes.append(f"column(s) not read: {', '.join(extra)}")
    table = table.copy()
    table["excited_axis"] = table["excited_axis"].astype(str).str.strip()
    table["channel"] = table["channel"].astype(str).str.strip()
    _check_axes(table["excited_axis"], path)
    unknown = ~table["channel"].isin(CHANNELS + CONTROL_CURRENT_CHANNELS)
    if unknown.any():
        row = int(np.flatnonzero(unknown.to_numpy())[0])
        raise LogError(path, f"row {row + 1}: unknown channel {table['channel'].iat[row]!r}; known: "
                             f"{', '.join(CHANNELS + CONTROL_CURRENT_CHANNELS)}")
    for name in ("frequency_hz", "re", "im", "noise_std", "amplitude_a", "step", "attempts", "level"):
        if name in table:
            table[name] = _numeric(table, name, path)
    position = _unit_factor(position_unit or "m", POSITION_UNITS, path)
    current = _unit_factor(current_unit or "A", CURRENT_UNITS, path)
    scale = np.where(table["channel"].str.startswith("V2_"), position, current)
    values = (table["re"].to_numpy() + 1j * table["im"].to_numpy()) * scale
    noise = table["noise_std"].to_numpy() * scale if "noise_std" in table else np.zeros(len(table))
    if "noise_std" not in table:
        notes.append("no noise_std column: noise estimated from the scatter between steps by the FRF stage")
    _per_step_defaults(table, path, notes)  # per row: the same for every row of a step
    per_step = table[[c for c in _PER_STEP if c in table]].drop_duplicates(["excited_axis", "step", "level"])
    records = []
    for (axis, step, _), rows in table.groupby(["excited_axis", "step", "level"], sort=False):
        index = rows.index.to_numpy()
        first = rows.iloc[0]
        records.append(_record(axis, step, first, list(rows["channel"]), values[index], noise[index], per_step))
    units = f"V2 {position_unit or 'm'}, U2 and I {current_unit or 'A'}"
    return records, notes, units


def _control_currents(records, path, notes):
    """Each control current ``I_<axis>`` of the records as the coil-current pair ``I_upper = I``, ``I_lower = -I``
    (noise ``sqrt(2)`` times: the pair's propagated noise of ``(I_upper - I_lower) / 2`` is the logged one)."""
    found = False
    for record in records:
        channels = list(record["channels"])
        given = [c for c in channels if c in CONTROL_CURRENT_CHANNELS]
        if not given:
            continue
        found = True
        both = [c for c in given if f"I_upper_{c[2:]}" in channels or f"I_lower_{c[2:]}" in channels]
        if both:
            raise LogError(path, f"step {record['step']} of {record['excited_axis']}: {both[0]} (the control current) "
                                 f"and the coil-current pair of {both[0][2:]} both given; give one of them")
        coefficients, noise = list(record["coefficients"]), list(record["noise_std"])
        for name in given:
            k = channels.index(name)
            value, sigma = coefficients[k], noise[k] * np.sqrt(2)
            channels[k:k + 1] = [f"I_upper_{name[2:]}", f"I_lower_{name[2:]}"]
            coefficients[k:k + 1] = [value, -value]
            noise[k:k + 1] = [sigma, sigma]
        record.update(channels=channels, coefficients=np.array(coefficients), noise_std=np.array(noise))
    if found:
        notes.append("control currents I_<axis> = (I_upper - I_lower) / 2 given: written as I_upper = I, I_lower = -I")
    return records


def _record(axis, step, first, channels, coefficients, noise, per_step):
    if "amplitude_a" in per_step:
        amplitude = float(first["amplitude_a"])
    else:
        u2 = [k for k, c in enumerate(channels) if c == f"U2_{axis}"]
        amplitude = float(np.abs(coefficients[u2[0]])) if u2 else np.nan
    return {"excited_axis": axis, "step": int(step), "frequency_hz": float(first["frequency_hz"]), "amplitude_a": amplitude,
            "attempts": int(first["attempts"]) if "attempts" in first and not pd.isna(first["attempts"]) else 1,
            "level": int(first["level"]), "channels": channels, "coefficients": coefficients, "noise_std": noise}


def _wide_records(table, path, position_unit, current_unit):
    columns = {}  # channel -> part -> (column, unit)
    notes = []
    for name in table.columns:
        match = _WIDE_COLUMN.match(name)
        if match:
            channel, part, unit = match.groups()
            columns.setdefault(channel, {})[part] = (name, unit)
    missing = [c for c in ("excited_axis", "frequency_hz") if c not in table.columns]
    if missing:
        raise LogError(path, f"wide layout: missing column(s) {', '.join(missing)}")
    extra = [c for c in table.columns if not _WIDE_COLUMN.match(c) and c not in _PER_STEP]
    if extra:
        notes.append(f"column(s) not read: {', '.join(extra)}")
    table = table.copy()
    table["excited_axis"] = table["excited_axis"].astype(str).str.strip()
    _check_axes(table["excited_axis"], path)
    for name in ("frequency_hz", "amplitude_a", "step", "attempts", "level"):
        if name in table:
            table[name] = _numeric(table, name, path)
    units_seen = set()
    factors = {}
    for channel, parts in columns.items():
        for part in ("re", "im"):
            if part not in parts:
                raise LogError(path, f"wide layout: {channel} has no {channel}_{part} column (it has {parts[next(iter(parts))][0]})")
        position = channel.startswith("V2_")
        option, known, default = (position_unit, POSITION_UNITS, "m") if position else (current_unit, CURRENT_UNITS, "A")
        for part, (name, unit) in parts.items():
            if unit and option and unit.lower() != option.lower():
                raise LogError(path, f"column {name!r} says {unit}, the option says {option}")
            chosen = unit or option or default
            factors[name] = _unit_factor(chosen, known, f"{path}: column {name!r}")
            units_seen.add(f"{'V2' if position else 'U2 and I'} {chosen}")
            table[name] = _numeric(table, name, path)
    steps = table[[c for c in _PER_STEP if c in table]].copy()
    _per_step_defaults(steps, path, notes)
    if not any("noise_std" in parts for parts in columns.values()):
        notes.append("no <channel>_noise_std columns: noise estimated from the scatter between steps by the FRF stage")
    records = []
    order = list(columns)
    for position_in_table, (row_index, row) in enumerate(table.iterrows()):
        present = [c for c in order if not (pd.isna(row[columns[c]["re"][0]]) and pd.isna(row[columns[c]["im"][0]]))]
        coefficients = np.array([row[columns[c]["re"][0]] * factors[columns[c]["re"][0]]
                                 + 1j * row[columns[c]["im"][0]] * factors[columns[c]["im"][0]] for c in present])
        noise = np.array([row[columns[c]["noise_std"][0]] * factors[columns[c]["noise_std"][0]]
                          if "noise_std" in columns[c] else 0.0 for c in present])
        first = steps.loc[row_index]
        records.append(_record(row["excited_axis"], first["step"], first, present, coefficients, noise, steps))
    return records, notes, ", ".join(sorted(units_seen))


# ---------------------------------------------------------------------------- MATLAB .mat
def read_mat_log(path):
    """A MATLAB ``.mat`` file with the thesis matrices ``data_exc_*`` (`ambid.mfile` layouts) as the canonical log.

    Returns
    -------
    frame, provenance
        As `read_log`.

    Raises
    ------
    LogError
        Naming the file: not a MAT file, a v7.3 (HDF5) file, no ``data_exc_*``
        variable, a variable that is no numeric matrix, a wrong width, or a
        log breaking the contract.
    """
    import scipy.io

    path = str(path)
    if Path(path).is_dir():
        raise LogError(path, "is a directory, not a log file")
    try:
        content = scipy.io.loadmat(path)
    except NotImplementedError:
        raise LogError(path, "a MATLAB v7.3 (HDF5) file, which scipy.io.loadmat does not read: in MATLAB, save it again "
                             "as version 7, e.g. save('identification.mat', '-regexp', '^data_exc_', '-v7')") from None
    except (OSError, ValueError, TypeError, EOFError, scipy.io.matlab.MatReadError) as error:
        raise LogError(path, f"not a readable MATLAB .mat file ({error})") from None
    variables = {name: value for name, value in content.items() if not name.startswith("__")}
    wanted = [f"data_exc_{axis.lower()}" for axis in ALL_AXES]
    matrices, notes = {}, []
    for name in wanted:
        if name not in variables:
            continue
        value = variables[name]
        if not (isinstance(value, np.ndarray) and value.ndim == 2 and np.issubdtype(value.dtype, np.number)):
            raise LogError(path, f"variable {name} is not a numeric matrix ({type(value).__name__}, "
                                 f"{getattr(value, 'dtype', '')} {getattr(value, 'shape', '')})")
        if not np.all(np.isfinite(value)):
            row = int(np.flatnonzero(~np.isfinite(value).all(axis=1))[0])
            raise LogError(path, f"{name} row {row + 1}: a value is not finite")
        matrices[name] = value.astype(np.complex128)
    if not matrices:
        raise LogError(path, f"no data_exc_* variable (the thesis matrices, data_exc_dx ... data_exc_z); "
                             f"the file holds {', '.join(variables) or 'nothing'}")
    ignored = [name for name in variables if name not in wanted]
    if ignored:
        notes.append(f"variable(s) not read: {', '.join(ignored)}")
    frame = thesis_log(matrices, path, notes=notes)
    return frame, {"file": path, "format": "mat", "layout": _thesis_layout(frame), "units": "um (V2), A", "notes": notes}


# ---------------------------------------------------------------------------- UFF58 FRFs
_ID_TAG = re.compile(rf"^({'|'.join(ESTIMATORS)}) ({'|'.join(ALL_AXES)})/({'|'.join(ALL_AXES)}):")
_UNIT_ALIASES = {"µm": "um", "μm": "um", "micron": "um", "microns": "um"}


def _uff_sets(path):
    import pyuff

    if Path(path).is_dir():
        raise LogError(path, "is a directory, not a UFF file")
    if not Path(path).exists():
        raise LogError(path, "no such file")
    try:
        sets = pyuff.UFF(path).read_sets()
    except Exception as error:  # noqa: BLE001 (pyuff raises bare Exception on malformed files)
        raise LogError(path, f"not a readable UFF file ({error})") from None
    return [sets] if isinstance(sets, dict) else list(sets)


def read_uff_frf(path, estimator=None, position_unit=None, current_unit=None, nodes=None):
    """UFF dataset 58 FRFs (as signal analysers and ambid write them) as the FRF stage's table.

    Parameters
    ----------
    path : str or Path
    estimator : str, optional
        ``siso`` or ``mimo``: what the plant FRFs of a file from another writer
        are (default ``siso``).  ambid's own files say it in ID line 2.
    position_unit, current_unit : str, optional
        The ordinate's units when its unit label does not say (`POSITION_UNITS`, `CURRENT_UNITS`).
    nodes : dict, optional
        Control axis -> (node, direction) of the file (default `ambid.uff.AXIS_NODE_DIRECTION`:
        DE = 1, NDE = 2, axial = 3; x = 1, y = 2, z = 3).  A negative direction flips the sign.

    Returns
    -------
    table : pandas.DataFrame
        `ambid.frf.frf_table` layout; ``std`` estimated from the scatter between
        neighbouring points (`ambid.logs.scatter_std`, running median over
        `UFF_STD_WINDOW` points), since UFF58 carries no uncertainty.
    provenance : dict
        ``file``, ``format``, ``estimator``, ``notes``.

    Raises
    ------
    LogError
        Naming the file and the dataset: unreadable, no FRF (function type 4),
        a node / direction of no control axis, an abscissa not in Hz, an
        unknown ordinate unit, a channel twice, fewer than 3 points, or an
        incomplete MIMO matrix.
    """
    path = str(path)
    nodes = nodes or AXIS_NODE_DIRECTION
    by_node = {value: axis for axis, value in nodes.items()}
    sets = _uff_sets(path)
    notes = [f"std of every point estimated from the scatter between neighbouring points (running median of second "
             f"differences over {UFF_STD_WINDOW} points): UFF58 carries no uncertainty"]
    frfs = [(k, s) for k, s in enumerate(sets) if s.get("type") == 58 and s.get("func_type") == 4]
    skipped = len(sets) - len(frfs)
    if not frfs:
        kinds = sorted({f"{s.get('type')}" + (f"/function type {s.get('func_type')}" if s.get("type") == 58 else "") for s in sets})
        raise LogError(path, f"no FRF dataset (type 58, function type 4); found dataset type(s) {', '.join(kinds) or 'none'}")
    if skipped:
        notes.append(f"{skipped} dataset(s) that are no FRF left out")
    channels = {}
    for k, dataset in frfs:
        where = f"dataset {k + 1}"
        key = (abs(int(dataset["rsp_node"])), abs(int(dataset["rsp_dir"])))
        ref = (abs(int(dataset["ref_node"])), abs(int(dataset["ref_dir"])))
        if key not in by_node or ref not in by_node:
            raise LogError(path, f"{where}: response node/direction {key} or reference {ref} is no control axis; "
                                 f"known: {', '.join(f'{a} {v}' for a, v in nodes.items())}")
        output, input_axis = by_node[key], by_node[ref]
        sign = np.sign(int(dataset["rsp_dir"])) * np.sign(int(dataset["ref_dir"]))
        abscissa = str(dataset.get("abscissa_axis_units_lab", "")).strip().lower()
        if int(dataset.get("abscissa_spec_data_type", 18)) != 18 or abscissa not in ("hz", ""):
            raise LogError(path, f"{where}: the abscissa is not a frequency in Hz ({abscissa or 'no unit'})")
        tag = _ID_TAG.match(str(dataset.get("id2", "")).strip())
        kind, factor = _uff_kind(dataset, tag, estimator, position_unit, current_unit, path, where)
        if tag and (tag.group(2), tag.group(3)) != (output, input_axis):
            raise LogError(path, f"{where}: ID line 2 names {tag.group(2)}/{tag.group(3)}, its nodes {output}/{input_axis}")
        frequency = np.asarray(dataset["x"], dtype=float)
        values = np.asarray(dataset["data"], dtype=complex) * factor * sign
        if frequency.size < 3 or not np.all(np.isfinite(values)) or np.any(np.diff(frequency) <= 0):
            raise LogError(path, f"{where} ({kind} {output}/{input_axis}): needs at least 3 finite points on increasing "
                                 f"frequencies")
        if (kind, output, input_axis) in channels:
            raise LogError(path, f"{where}: {kind} {output}/{input_axis} is in the file twice")
        channels[(kind, output, input_axis)] = (frequency, values, scatter_std(values, UFF_STD_WINDOW))
    siso = {(o, i): v for (kind, o, i), v in channels.items() if kind == "siso"}
    current = {(o, i): v for (kind, o, i), v in channels.items() if kind == "current"}
    mimo = _uff_mimo({(o, i): v for (kind, o, i), v in channels.items() if kind == "mimo"}, path)
    table = frf_table(siso, mimo, current=current)
    kinds = sorted({kind for kind, _, _ in channels})
    return table, {"file": path, "format": "uff", "estimator": ", ".join(kinds), "notes": notes}


def _uff_kind(dataset, tag, estimator, position_unit, current_unit, path, where):
    """(estimator, factor to SI) of one dataset, from ambid's ID tag or the ordinate's unit label."""
    numerator = str(dataset.get("ordinate_axis_units_lab", "")).strip()
    numerator = _UNIT_ALIASES.get(numerator, numerator)
    denominator = str(dataset.get("orddenom_axis_units_lab", "")).strip()
    per = _unit_factor(current_unit or (denominator if denominator.lower() in CURRENT_UNITS else "A"), CURRENT_UNITS, f"{path}: {where}")
    if tag:
        kind = tag.group(1)
    elif numerator.lower() in CURRENT_UNITS or int(dataset.get("ordinate_spec_data_type", 0)) not in (0, 1, 8):
        kind = "current" if numerator.lower() in CURRENT_UNITS else None
    else:
        kind = estimator or "siso"
    if kind is None:
        raise LogError(path, f"{where}: the ordinate (spec data type {dataset.get('ordinate_spec_data_type')}, unit "
                             f"{numerator!r}) is neither a position nor a coil current")
    if kind not in ESTIMATORS:
        raise LogError(path, f"{where}: unknown estimator {kind!r}; known: {', '.join(ESTIMATORS)}")
    if kind == "current":
        return kind, _unit_factor(current_unit or (numerator or "A"), CURRENT_UNITS, f"{path}: {where}") / per
    unit = position_unit or numerator
    if not unit:
        raise LogError(path, f"{where}: the ordinate has no unit label; give the position unit (m, mm, um)")
    return kind, _unit_factor(unit, POSITION_UNITS, f"{path}: {where}") / per


def _uff_mimo(channels, path):
    """(frequency, plant, std, condition) of a complete 4 x 4 MIMO set, None when there is none."""
    if not channels:
        return None
    missing = [f"{o}/{i}" for o in RADIAL_AXES for i in RADIAL_AXES if (o, i) not in channels]
    if missing:
        raise LogError(path, f"MIMO FRFs need all 16 radial channels; missing {', '.join(missing)}")
    frequency = channels[(RADIAL_AXES[0], RADIAL_AXES[0])][0]
    n = len(RADIAL_AXES)
    plant = np.zeros((frequency.size, n, n), dtype=complex)
    std = np.zeros((frequency.size, n, n))
    for a, o in enumerate(RADIAL_AXES):
        for b, i in enumerate(RADIAL_AXES):
            f, values, s = channels[(o, i)]
            if f.shape != frequency.shape or np.max(np.abs(f / frequency - 1)) > 1e-5:
                raise LogError(path, f"MIMO channel {o}/{i} is on another frequency grid than {RADIAL_AXES[0]}/{RADIAL_AXES[0]}")
            plant[:, a, b], std[:, a, b] = values, s
    return frequency, plant, std, np.full(frequency.size, np.nan)
