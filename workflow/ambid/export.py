"""FRFs and fitted models as CSV and MATLAB ``.mat`` files, for the tools users already have.

The FRF table (`ambid.frf.frf_table`) goes out as CSV with one row per
(estimator, output, input, frequency), magnitude and phase added, and as a
``.mat`` file with one struct per estimator: ``frequency_hz`` (n x 1),
``H`` (n x outputs x inputs, complex, NaN where a channel was not measured),
``std`` (the same shape), ``outputs`` and ``inputs`` (axis names), so that
``frf_siso.H(:, 1, 1)`` is DX/DX.  The fitted models (`ambid.channel_fit`,
thesis ch. 5.1) go out as CSV (one row per channel, as ``models.parquet``)
and as ``.mat`` with one struct per channel (``model_DX_DX``) holding the
gain, poles, zeros, numerator and denominator polynomial coefficients of the
rational part in s [rad/s] (highest power first, as MATLAB's ``tf``), and the
delay: ``G(s) = num(s) / den(s) exp(-s delay_s)``, times the known response
the fit was made against (the zero-order hold and the model's own effects).

``.mat`` files are written in the version 5 format (MATLAB, Octave, scipy)
with a fixed header text instead of scipy's creation time, so the same
results give the same bytes.
"""

import io

import numpy as np
import pandas as pd
import scipy.io

from .channel_fit import model_from_row
from .io import atomic_path
from .machine import ALL_AXES

__all__ = ["frf_csv", "frf_mat", "models_csv", "models_mat", "write_mat"]

_HEADER_BYTES = 116  # the descriptive text at the start of a MATLAB 5 file


def write_mat(variables, path, description="MATLAB 5.0 MAT-file, written by ambid"):
    """``scipy.io.savemat`` of ``variables`` to ``path`` (atomically), with a fixed header text (reproducible bytes)."""
    buffer = io.BytesIO()
    scipy.io.savemat(buffer, variables, format="5", long_field_names=True, do_compression=False, oned_as="column")
    data = bytearray(buffer.getvalue())
    data[:_HEADER_BYTES] = description.encode("ascii")[:_HEADER_BYTES].ljust(_HEADER_BYTES)
    with atomic_path(path) as temporary:
        temporary.write_bytes(bytes(data))


def frf_csv(table, path):
    """The FRF table as CSV, with ``magnitude`` and ``phase_deg`` of each point."""
    values = table["re"].to_numpy() + 1j * table["im"].to_numpy()
    frame = table.assign(magnitude=np.abs(values), phase_deg=np.degrees(np.angle(values)))
    with atomic_path(path) as temporary:
        frame.to_csv(temporary, index=False, float_format="%.12g")


def _axes(names):
    return [axis for axis in ALL_AXES if axis in set(names)]


def frf_mat(table, path):
    """The FRF table as a ``.mat`` file: one struct ``frf_<estimator>`` per estimator (module docstring)."""
    variables = {}
    for estimator, part in table.groupby("estimator", sort=True):
        frequency = np.unique(part["frequency_hz"].to_numpy())
        outputs, inputs = _axes(part["output"]), _axes(part["input"])
        h = np.full((frequency.size, len(outputs), len(inputs)), np.nan, dtype=complex)
        std = np.full(h.shape, np.nan)
        row = np.searchsorted(frequency, part["frequency_hz"].to_numpy())
        out = part["output"].map(outputs.index).to_numpy()
        inp = part["input"].map(inputs.index).to_numpy()
        h[row, out, inp] = part["re"].to_numpy() + 1j * part["im"].to_numpy()
        std[row, out, inp] = part["std"].to_numpy()
        variables[f"frf_{estimator}"] = {"frequency_hz": frequency, "H": h, "std": std,
                                         "outputs": np.array(outputs, dtype=object), "inputs": np.array(inputs, dtype=object),
                                         "unit": "A/A" if estimator == "current" else "m/A"}
    write_mat(variables, path)


def models_csv(models, path):
    """The fitted models (rows of ``models.parquet``) as CSV."""
    with atomic_path(path) as temporary:
        pd.DataFrame(models).to_csv(temporary, index=False, float_format="%.12g")


def models_mat(models, path):
    """The fitted models as a ``.mat`` file: one struct ``model_<output>_<input>`` per channel (module docstring)."""
    variables = {}
    for row in pd.DataFrame(models).to_dict("records"):
        model = model_from_row(row)
        zeros, poles = model.zeros, model.poles
        numerator = model.gain * np.real(np.poly(zeros)) * (model.residual_s2 if model.residual_s2 != 0 else 1.0)
        denominator = np.real(np.poly(poles))
        if np.isfinite(model.lowpass_rad_s):  # the low-pass is 1 / (1 + s / w): pole -w, gain w
            numerator = numerator * model.lowpass_rad_s
        variables[f"model_{row['output']}_{row['input']}"] = {
            "output": row["output"], "input": row["input"], "gain": model.gain, "poles_rad_s": poles, "zeros_rad_s": zeros,
            "numerator": numerator, "denominator": denominator, "delay_s": model.delay_s,
            "mode_hz": model.mode_rad_s / (2 * np.pi), "mode_damping": model.mode_damping,
            "order": row["order"], "cost": row["cost"],
        }
    write_mat(variables, path)
