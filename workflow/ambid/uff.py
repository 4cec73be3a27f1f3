"""FRFs as Universal File Format dataset 58 (function at nodal DOF), read by modal-analysis tools.

Each channel is one dataset: a frequency response function (function type 4),
complex double-precision ordinate (data type 6) on an uneven abscissa (the
exact excitation frequencies), the response and reference as node / direction
(DE = node 1, NDE = node 2, axial = node 3; x = 1, y = 2, z = 3).  Every kind
of FRF the FRF stage makes is written (`frf_channels`): the plant FRFs (SISO
and MIMO estimates, radial and axial), position [m] per control current [A],
and the coil-current FRFs, coil current [A] per control current [A].  ID line
2 starts with the estimator (``siso``, ``mimo``, ``current``) and the channel
``output/input``, which is how `ambid.readers.read_uff_frf` tells them apart
on reading.
"""

import numpy as np

from .io import atomic_path
from .machine import ALL_AXES

__all__ = ["AXIS_NODE_DIRECTION", "ESTIMATORS", "frf_channels", "write_uff58"]

#: control axis -> (node, direction) in the UFF sense
AXIS_NODE_DIRECTION = {"DX": (1, 1), "DY": (1, 2), "NX": (2, 1), "NY": (2, 2), "Z": (3, 3)}
#: the FRF table's estimators, in the order they are written
ESTIMATORS = ("siso", "mimo", "current")

FREQUENCY_RESPONSE_FUNCTION = 4
COMPLEX_DOUBLE = 6
SPEC_FREQUENCY, SPEC_DISPLACEMENT, SPEC_UNKNOWN = 18, 8, 0


def _dataset(estimator, output, input_axis, frequency_hz, values, description):
    response_node, response_direction = AXIS_NODE_DIRECTION[output]
    reference_node, reference_direction = AXIS_NODE_DIRECTION[input_axis]
    current = estimator == "current"
    what = "coil current / control current" if current else "sensor position / control current"
    lines = [f"{-1:6d}", f"{58:6d}"]
    ids = [description, f"{estimator} {output}/{input_axis}: {what}", "NONE", "ambid", "NONE"]
    lines += [f"{text[:80]:<80s}" for text in ids]
    # record 6: function type, id, version, load case, response and reference entity / node / direction
    lines.append(f"{FREQUENCY_RESPONSE_FUNCTION:5d}{0:10d}{0:5d}{0:10d} {output:<10s}{response_node:10d}{response_direction:4d}"
                 f" {input_axis:<10s}{reference_node:10d}{reference_direction:4d}")
    # record 7: ordinate type, points, spacing (0 = uneven), abscissa min, increment, z value
    lines.append(f"{COMPLEX_DOUBLE:10d}{len(frequency_hz):10d}{0:10d}{0.0:13.5e}{0.0:13.5e}{0.0:13.5e}")
    # records 8-11: data characteristics (spec type, length / force / temperature exponents, labels)
    lines.append(f"{SPEC_FREQUENCY:10d}{0:5d}{0:5d}{0:5d} {'Frequency':<20s} {'Hz':<20s}")
    if current:
        lines.append(f"{SPEC_UNKNOWN:10d}{0:5d}{0:5d}{0:5d} {'Coil current':<20s} {'A':<20s}")
    else:
        lines.append(f"{SPEC_DISPLACEMENT:10d}{1:5d}{0:5d}{0:5d} {'Displacement':<20s} {'m':<20s}")
    lines.append(f"{SPEC_UNKNOWN:10d}{0:5d}{0:5d}{0:5d} {'Control current':<20s} {'A':<20s}")
    lines.append(f"{SPEC_UNKNOWN:10d}{0:5d}{0:5d}{0:5d} {'NONE':<20s} {'NONE':<20s}")
    # record 12: abscissa E13.5 then real and imaginary parts E20.12, one point per line
    for f, value in zip(frequency_hz, values):
        lines.append(f"{f:13.5e}{value.real:20.12e}{value.imag:20.12e}")
    lines.append(f"{-1:6d}")
    return lines


def frf_channels(table):
    """Every channel of an FRF table (`ambid.frf.frf_table`) as ``(estimator, output, input, frequency_hz, values)``.

    In a fixed order: estimators as `ESTIMATORS`, then output and input axes in `ambid.machine.ALL_AXES` order.
    """
    rank = {axis: k for k, axis in enumerate(ALL_AXES)}
    keys = table[["estimator", "output", "input"]].drop_duplicates().itertuples(index=False)
    for estimator, output, input_axis in sorted(keys, key=lambda k: (ESTIMATORS.index(k[0]), rank[k[1]], rank[k[2]])):
        rows = table[(table["estimator"] == estimator) & (table["output"] == output) & (table["input"] == input_axis)]
        rows = rows.sort_values("frequency_hz")
        yield estimator, output, input_axis, rows["frequency_hz"].to_numpy(), rows["re"].to_numpy() + 1j * rows["im"].to_numpy()


def write_uff58(path, channels, description="ambid FRF"):
    """Write FRF channels as UFF dataset 58 blocks, atomically.

    Parameters
    ----------
    path : str or Path
    channels : iterable of (estimator, output, input, frequency_hz, values)
        Estimator one of `ESTIMATORS`; axis names of ``AXIS_NODE_DIRECTION``;
        values complex [m/A], or [A/A] for ``current``.
    description : str
        ID line 1 of every dataset.

    Notes
    -----
    The abscissa is written as E13.5 (6 significant digits) as the format
    prescribes; frequencies are recovered to 1e-5 relative.
    """
    lines = []
    for estimator, output, input_axis, frequency_hz, values in channels:
        if estimator not in ESTIMATORS:
            raise ValueError(f"{path}: unknown estimator {estimator!r}; known: {ESTIMATORS}")
        values = np.asarray(values, dtype=complex)
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{path}: channel {estimator} {output}/{input_axis} has non-finite values")
        lines += _dataset(estimator, output, input_axis, np.asarray(frequency_hz, dtype=float), values, description)
    with atomic_path(path) as temporary:
        temporary.write_text("\n".join(lines) + "\n")
