"""Thesis-compatible ``.m`` export of an identification run.

The thesis' evaluation scripts read MATLAB matrices ``data_exc_dx`` ...
``data_exc_z``, one row per frequency step of the axis excited, with the
column layout `THESIS_COLUMNS` (1-based as in MATLAB).  Columns 3-10 are the
thesis' own layout, so its appendix formula
``data_exc_dx(:,7)./data_exc_dx(:,3)/1e6`` gives the DX plant in m/A; positions
are therefore written in micrometres.  Numbers are written with 17 significant
digits, so every double round-trips exactly through the text.  The file is
data for a strict parser, never to be evaluated.
"""

import numpy as np

from .io import atomic_path
from .logs import validate_identification_log
from .machine import ALL_AXES, RADIAL_AXES

__all__ = ["THESIS_COLUMNS", "write_thesis_m", "variable_name"]

_POSITION_SCALE = 1e6  # m -> um, as in the thesis

#: (channel, scale) of columns 3-22; columns 1 and 2 are frequency and amplitude.
_LAYOUT = (
    tuple((f"U2_{axis}", 1.0) for axis in RADIAL_AXES)
    + tuple((f"V2_{axis}", _POSITION_SCALE) for axis in RADIAL_AXES)
    + tuple((f"I_{side}_{axis}", 1.0) for axis in RADIAL_AXES for side in ("upper", "lower"))
    + (("U2_Z", 1.0), ("V2_Z", _POSITION_SCALE), ("I_upper_Z", 1.0), ("I_lower_Z", 1.0))
)

#: Description of the 22 columns, in order (MATLAB column = index + 1).
THESIS_COLUMNS = ("frequency [Hz]", "amplitude [A]") + tuple(
    f"{channel} [{'um' if scale != 1.0 else 'A'}]" for channel, scale in _LAYOUT
)


def variable_name(axis):
    """MATLAB variable holding the steps of an excited axis: ``"DX"`` -> ``"data_exc_dx"``."""
    return f"data_exc_{axis.lower()}"


def _real(value):
    return f"{value:.17g}"


def _complex(value):
    return f"{value.real:.17g}{value.imag:+.17g}i"


def _axis_rows(frame, axis):
    """Lines of the matrix of one excited axis, by increasing step."""
    part = frame[frame["excited_axis"] == axis]
    table = part.pivot(index="step", columns="channel", values=["re", "im"]).sort_index()
    per_step = part.groupby("step")[["frequency_hz", "amplitude_a"]].first().sort_index()
    channels = [channel for channel, _ in _LAYOUT]
    scale = np.array([scale for _, scale in _LAYOUT])
    coefficients = (table["re"][channels].to_numpy() + 1j * table["im"][channels].to_numpy()) * scale
    lines = []
    for (frequency_hz, amplitude_a), row in zip(per_step.to_numpy(), coefficients):
        values = [_real(frequency_hz), _real(amplitude_a)] + [_complex(value) for value in row]
        lines.append("  ".join(values) + ";")
    return lines


def write_thesis_m(frame, path, header_lines=()):
    """Write an identification log as a MATLAB script in the thesis' format.

    Parameters
    ----------
    frame : pandas.DataFrame
        Identification log (`ambid.logs.identification_frame`), SI units; it is
        validated first.
    path : str or Path
        Target ``.m`` file, written atomically.
    header_lines : sequence of str, optional
        Comment lines (machine, run, ...) placed at the top, each prefixed ``% ``.

    Notes
    -----
    For each axis present in ``frame`` (in `ALL_AXES` order) the file assigns
    ``data_exc_<axis> = [`` ... ``];`` with one row per step: frequency [Hz]
    and amplitude [A] as reals, then the 20 channel coefficients as complex
    literals ``re+imi`` in the `THESIS_COLUMNS` layout, positions in µm.

    Raises
    ------
    LogError
        If ``frame`` is not a valid identification log; nothing is written then.
    """
    validate_identification_log(frame, str(path))
    layout = ", ".join(f"{column} {description}" for column, description in enumerate(THESIS_COLUMNS, start=1))
    lines = [f"% {text}" for header in header_lines for text in str(header).splitlines() or [""]]
    lines.append(f"% columns: {layout}")
    present = set(frame["excited_axis"])
    for axis in (axis for axis in ALL_AXES if axis in present):
        lines += ["", f"{variable_name(axis)} = ["] + _axis_rows(frame, axis) + ["];"]
    with atomic_path(path) as temporary:
        temporary.write_text("\n".join(lines) + "\n", encoding="utf-8")
