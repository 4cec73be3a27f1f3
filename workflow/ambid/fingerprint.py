"""A model's residual in words: where it misfits, and the shape the misfit has.

The sentences are what a machine engineer reads before any ranking: which
channels and bands carry the misfit, whether the measured phase lags the model
linearly with frequency (a delay), with a bend (a low-pass), whether the
coil currents (which see only the amplifier) agree, whether the x-y cross
channels carry signal the model lacks, and whether the error is a constant gain
confined to one output or one input axis (a sensor or actuator gain, which no
effect of the library represents).  Inputs are `ambid.compare.channel_errors`
(measurement / model ratio: a positive phase error means the machine lags more
than the model) and `ambid.compare.summarize`.
"""

import numpy as np

from .diagnose import cell_name
from .machine import RADIAL_AXES

__all__ = ["fingerprint", "where_it_helps", "gain_offsets"]


def where_it_helps(before, after, top=3):
    """The channels and bands whose chi2 a candidate lowers most: text from two `ambid.compare.summarize` tables."""
    keys = ["output", "input", "band"]
    merged = before.merge(after, on=keys, suffixes=("_before", "_after"))
    merged = merged[merged["output"] != "all"]
    merged["drop"] = merged["chi2_before"] - merged["chi2_after"]
    channels = merged[merged["band"] == "all"].sort_values("drop", ascending=False).head(top)
    bands = merged[merged["band"] != "all"].groupby("band", sort=False)["drop"].sum().sort_values(ascending=False)
    channel_text = ", ".join(f"{r.output}/{r.input} ({r.chi2_before:.3g} -> {r.chi2_after:.3g})" for r in channels.itertuples()
                             if r.drop > 0)
    return {"channels": channel_text or "none", "band": bands.index[0] if len(bands) and bands.iloc[0] > 0 else "none"}


def _phase_slope(frame):
    """Least-squares slope through the origin of phase error [deg] against frequency [Hz], and its R^2."""
    f, phase = frame["frequency_hz"].to_numpy(), frame["phase_error_deg"].to_numpy()
    good = np.isfinite(phase)
    f, phase = f[good], phase[good]
    if f.size < 3:
        return 0.0, 0.0
    slope = float(np.sum(f * phase) / np.sum(f * f))
    total = float(np.sum(phase**2))
    return slope, 1.0 - float(np.sum((phase - slope * f) ** 2)) / total if total > 0 else 0.0


def gain_offsets(errors, min_db=0.1, max_spread_db=0.1, max_phase_deg=1.0):
    """Radial axes whose row (output) or column (input) of the plant matrix is off by a constant gain.

    For each axis, the magnitude errors of its row (outputs) and its column
    (inputs) over the channels with signal: a median beyond ``min_db``, a spread
    (interquartile half-range) below ``max_spread_db`` and a median phase error
    below ``max_phase_deg``, while the other axes' rows (columns) stay within
    ``min_db`` / 2, is a gain of that sensor (actuator).

    Returns
    -------
    list of (str, str, float)
        ``("output" or "input", axis, median magnitude error [dB])``.
    """
    radial = errors[errors["output"].isin(RADIAL_AXES) & errors["input"].isin(RADIAL_AXES)]
    radial = radial[np.isfinite(radial["magnitude_error_db"]) & (radial["normalized_error"] < 1e6)]
    same_plane = radial[[RADIAL_AXES.index(o) % 2 == RADIAL_AXES.index(i) % 2 for o, i in zip(radial["output"], radial["input"])]]
    found = []
    for side in ("output", "input"):
        medians = {}
        for axis, group in same_plane.groupby(side):
            magnitude, phase = group["magnitude_error_db"].to_numpy(), group["phase_error_deg"].to_numpy()
            spread = 0.5 * (np.quantile(magnitude, 0.75) - np.quantile(magnitude, 0.25))
            medians[axis] = (float(np.median(magnitude)), spread, float(np.median(phase)))
        for axis, (median, spread, phase) in medians.items():
            others = [abs(m) for a, (m, _, _) in medians.items() if a != axis]
            if (abs(median) > min_db and spread < max_spread_db and abs(phase) < max_phase_deg and others
                    and max(others) < 0.5 * abs(median)):
                found.append((side, axis, median))
    return found


def fingerprint(errors, summary, cells=None):
    """The residual of a model in words: sentences an engineer reads before the ranking.

    Parameters
    ----------
    errors, summary : pandas.DataFrame
        `ambid.compare.channel_errors` and `summarize` of the model.
    cells : pandas.DataFrame, optional
        `ambid.diagnose.misfit_cells` of the model: the cells above the floor are named.
    """
    sentences = []
    overall = summary[(summary["output"] == "all")].iloc[0]
    if np.isfinite(overall["rms_magnitude_db"]):
        sentences.append(f"Overall chi2 per point {overall['chi2']:.3g} (1 = the floor); rms magnitude error "
                         f"{overall['rms_magnitude_db']:.2f} dB, rms phase error {overall['rms_phase_deg']:.2f} deg "
                         "(where measurement and model resolve the response).")
    else:
        sentences.append(f"Overall chi2 per point {overall['chi2']:.3g} (1 = the floor); no point resolves the response "
                         "beyond three times its noise, so no magnitude or phase error.")
    if cells is not None:
        above = cells[cells["above_floor"]]
        if above.empty:
            sentences.append("Every channel family and band is within the floor.")
        else:
            sentences.append("Above the floor: " + ", ".join(f"{cell_name(r)} (chi2 {r.chi2_per_point:.3g})"
                                                             for r in above.sort_values("chi2_per_point", ascending=False)
                                                             .head(4).itertuples()) + ".")
    per_channel = summary[(summary["band"] == "all") & (summary["output"] != "all")]
    worst = per_channel.sort_values("chi2", ascending=False).head(3)
    sentences.append("Largest misfit: " + ", ".join(f"{r.output}/{r.input} (chi2 {r.chi2:.3g})" for r in worst.itertuples()) + ".")
    diagonal = errors[(errors["output"] == errors["input"]) & errors["output"].isin(RADIAL_AXES + ("Z",))]
    currents = errors[errors["output"].str.startswith("I_")]
    for name, frame in (("position", diagonal), ("coil-current", currents)):
        if frame.empty:
            continue
        top = frame["frequency_hz"].max()
        upper = frame[frame["frequency_hz"] >= 0.8 * top]
        lag = float(upper["phase_error_deg"].median())
        magnitude = float(upper["magnitude_error_db"].median())
        slopes = [_phase_slope(group) for _, group in frame.groupby("output")]
        linear = all(r2 > 0.9 for _, r2 in slopes) and len({np.sign(s) for s, _ in slopes}) == 1
        if abs(lag) < 1.0 and abs(magnitude) < 0.2:
            sentences.append(f"On the {name} channels the model matches near {top:.0f} Hz "
                             f"(phase {lag:+.2f} deg, magnitude {magnitude:+.2f} dB).")
            continue
        shape = "grows linearly with frequency" if linear else "grows with frequency" if abs(lag) >= 1.0 else "is small"
        direction = "lag" if lag > 0 else "lead"
        text = (f"On every {name} channel the measured phase {direction} beyond the model {shape}: "
                f"{abs(lag):.1f} deg near {top:.0f} Hz; magnitude {magnitude:+.2f} dB there (model / measurement)")
        if linear and lag > 0 and abs(magnitude) < 0.5:
            text += f"; a pure delay of {np.mean([s for s, _ in slopes]) / 360 * 1e6:.0f} us would do this"
        sentences.append(text + ".")
    for side, axis, db in gain_offsets(errors):
        device = "sensor" if side == "output" else "actuator (or its amplifier)"
        sentences.append(f"Every channel with {axis} as {side} is off by a constant {db:+.2f} dB (model / measurement) at "
                         f"no phase, the other axes are not: a gain error of the {axis} {device}, which no library effect "
                         "represents.")
    cross = errors[(errors["output"] != errors["input"]) & errors["output"].isin(RADIAL_AXES)]
    cross_plane = cross[[RADIAL_AXES.index(o) % 2 != RADIAL_AXES.index(i) % 2 for o, i in zip(cross["output"], cross["input"])]]
    if not cross_plane.empty:
        chi2 = float(np.mean(cross_plane["normalized_error"] ** 2))
        if chi2 > 2.0:
            sentences.append(f"The x-y cross channels, which the model has at zero (or small), carry signal: chi2 {chi2:.3g}.")
    return sentences
