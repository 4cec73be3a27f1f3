"""Model against measurement: FRF errors per channel, frequency and band, weighted by the measurement uncertainty.

For every measured channel ``G_meas(f)`` with standard uncertainty ``sigma(f)``
(the complex standard deviation of the ETFE, ``E|n|^2 = sigma^2``) and the
model's ``G_model(f)`` (structural plant with its effects, times the digital
loop's zero-order hold, as the measurement sees it):

* ``magnitude_error_db = 20 log10 |G_model / G_meas|``
* ``phase_error_deg = angle(G_model / G_meas)`` in (-180, 180]
* ``normalized_error = |G_model - G_meas| / sigma``: about 1 where the model
  explains the data to within its noise.

The summary per channel and band is ``chi2 = mean(normalized_error^2)``
(1 at the noise floor), its excess ``max(chi2 - 1, 0)``, and the rms of the
magnitude and phase errors.  This is the "compare" step of the diagnosis loop.
"""

import numpy as np
import pandas as pd

from .errors import AmbidError
from .loop import zero_order_hold
from .machine import RADIAL_AXES

__all__ = ["CompareError", "model_channels", "channel_errors", "summarize", "DEFAULT_BANDS_HZ"]

DEFAULT_BANDS_HZ = (0.0, 10.0, 100.0, 300.0, 1000.0, np.inf)


class CompareError(AmbidError):
    """A comparison that cannot be made (no common channel, no usable uncertainty)."""


def model_channels(plant, frequency_hz, channels):
    """The model's radial FRF of each channel as the identification measures it (times the ZOH) [m/A]."""
    frequency_hz = np.asarray(frequency_hz, dtype=float)
    response = plant.radial_frequency_response(frequency_hz) * zero_order_hold(frequency_hz,
                                                                                plant.machine.sample_time_s)[:, None, None]
    return {(o, i): response[:, RADIAL_AXES.index(o), RADIAL_AXES.index(i)] for o, i in channels}


def channel_errors(measured, model):
    """Errors of the model against the measurement, one row per channel and frequency.

    Parameters
    ----------
    measured : dict (output, input) -> (frequency_hz, values, std)
    model : dict (output, input) -> values on the same frequencies

    Returns
    -------
    pandas.DataFrame
        ``output, input, frequency_hz, magnitude_error_db, phase_error_deg, normalized_error``.
    """
    rows = []
    for (output, input_axis), (frequency, values, std) in measured.items():
        if (output, input_axis) not in model:
            continue
        predicted = np.asarray(model[(output, input_axis)])
        if predicted.shape != values.shape:
            raise CompareError(f"channel {output}/{input_axis}: model and measurement have different frequencies")
        if not np.all(np.isfinite(std)) or np.any(std <= 0):
            raise CompareError(f"channel {output}/{input_axis}: the measurement has no positive, finite uncertainty")
        ratio = predicted / values
        rows.append(pd.DataFrame({"output": output, "input": input_axis, "frequency_hz": frequency,
                                  "magnitude_error_db": 20 * np.log10(np.abs(ratio)),
                                  "phase_error_deg": np.degrees(np.angle(ratio)),
                                  "normalized_error": np.abs(predicted - values) / std}))
    if not rows:
        raise CompareError("no channel is both measured and modelled")
    return pd.concat(rows, ignore_index=True)


def summarize(errors, bands_hz=DEFAULT_BANDS_HZ):
    """One row per channel and band, per channel (band ``all``) and overall (channel ``all``).

    Columns ``output, input, band, points, chi2, excess, rms_magnitude_db, rms_phase_deg``;
    ``chi2`` is the mean squared normalized error (1: within the noise),
    ``excess = max(chi2 - 1, 0)``.
    """
    edges = np.asarray(bands_hz, dtype=float)
    labels = [f"{lo:g}-{hi:g} Hz" for lo, hi in zip(edges[:-1], edges[1:])]
    frame = errors.assign(band=pd.cut(errors["frequency_hz"], edges, labels=labels, right=False).astype(str))

    def row(group, output, input_axis, band):
        chi2 = float(np.mean(group["normalized_error"] ** 2))
        return {"output": output, "input": input_axis, "band": band, "points": len(group), "chi2": chi2,
                "excess": max(chi2 - 1.0, 0.0),
                "rms_magnitude_db": float(np.sqrt(np.mean(group["magnitude_error_db"] ** 2))),
                "rms_phase_deg": float(np.sqrt(np.mean(group["phase_error_deg"] ** 2)))}

    rows = []
    for (output, input_axis), group in frame.groupby(["output", "input"], sort=False):
        rows += [row(part, output, input_axis, band) for band, part in group.groupby("band", sort=False)]
        rows.append(row(group, output, input_axis, "all"))
    rows.append(row(frame, "all", "all", "all"))
    return pd.DataFrame(rows)
