"""Zoom: where a coarse identification pass is refined by a dense one (either method), and the merge of both.

Multisine runs zoom in `ambid.multisine.identify_multisine`; for the stepped
sine, `stepped_zoom_plan` gives the dense steps and `merge_stepped` one log.

After a coarse pass the FRF is fitted (`ambid.channel_fit.fit_channel`, the fit
stage's estimator, with the nominal model's known parts); every lightly damped
resonance and anti-resonance of the fitted channels gets a band of half width
``max(width zeta f, min_width f)`` (``zeta f``: half the half-power bandwidth),
overlapping bands are merged, and a second pass measures only there, densely
and with all the excitation's power.  Planning from the coarse pass' fit is
measurement-derived: the rig's truth is never read.  The merged FRF keeps the
coarse points outside the zoom bands.
"""

import numpy as np

from .channel_fit import FitError, fit_channel, known_response, rigid_pole_hz, select_channels
from .frf import channel, radial_estimator
from .modal_features import LIGHT_DAMPING

__all__ = ["fitted_features", "zoom_bands", "band_lines", "outside_bands", "stepped_zoom_plan", "merge_stepped"]


def fitted_features(table, plant, channels="same_plane", estimator=None, max_relative_std=0.5, **fit_options):
    """Resonances and anti-resonances of the fitted channels of a coarse FRF table.

    Parameters
    ----------
    table : pandas.DataFrame
        `ambid.frf.frf_table` of the coarse pass.
    plant : ambid.plant.Plant
        The nominal model (the known hold and effects, the rigid-pole hint).
    channels : str
        `ambid.channel_fit.select_channels` kind.
    estimator : str, optional
        ``mimo`` or ``siso``; default ``mimo`` when logged.
    max_relative_std : float
        Only roots whose damping ratio the fit determines to this relative
        standard uncertainty count (a near-cancelling pole-zero pair of a noisy
        channel has a damping ratio of any value).
    fit_options
        Passed to `fit_channel` (``modes``, ``orders``, ``lowpass``, ``delay``).

    Returns
    -------
    list of dict
        ``output, input, root (pole | zero), frequency_hz, damping_ratio,
        damping_std`` of every complex root with damping below
        `ambid.modal_features.LIGHT_DAMPING` in the band and determined damping.
    skipped : list of str
        Channels that could not be fitted, and why.
    """
    if estimator is None:
        estimator = radial_estimator(table)
    hint = rigid_pole_hz(plant)
    rows, skipped = [], []
    for output, input_axis in select_channels(channels):
        frequency, values, std = channel(table, estimator, output, input_axis)
        if frequency.size < 8:
            continue
        try:
            fit = fit_channel(frequency, values, std=std, known=known_response(plant, output, input_axis, frequency),
                              rigid_hint_hz=hint, **fit_options)
        except FitError as error:
            skipped.append(f"{output}/{input_axis}: {error}")
            continue
        for row in fit.features:
            zeta, zeta_std = row["damping_ratio"], row.get("damping_std", np.inf)
            if (row["kind"] in ("resonance", "anti_resonance") and 0 < zeta < LIGHT_DAMPING
                    and zeta_std <= max_relative_std * zeta):
                rows.append({"output": output, "input": input_axis, "root": row["root"],
                             "frequency_hz": row["frequency_hz"], "damping_ratio": zeta, "damping_std": zeta_std})
    return rows, skipped


def zoom_bands(features, width=4.0, min_width=0.01, band_hz=(0.0, np.inf), max_damping=0.05):
    """Merged zoom bands around features, and the narrowest half-power bandwidth among them.

    Parameters
    ----------
    features : list of dict
        ``frequency_hz`` and ``damping_ratio`` of each resonance / anti-resonance.
    width : float
        Half width in units of ``zeta f`` (half the half-power bandwidth).
    min_width : float
        Smallest half width, relative to ``f``.
    band_hz : (float, float)
        Bands are clipped to this range.
    max_damping : float
        Features damped more than this are broad: the coarse pass resolves them, no zoom.

    Returns
    -------
    bands : list of (low, high)
        Ascending, disjoint [Hz].
    half_power_hz : float
        Smallest ``2 zeta f`` of the features (inf without features).
    """
    spans, half_power = [], np.inf
    for row in features:
        f, zeta = float(row["frequency_hz"]), float(row["damping_ratio"])
        if zeta > max_damping:
            continue
        half = max(width * zeta * f, min_width * f)
        low, high = max(f - half, band_hz[0]), min(f + half, band_hz[1])
        if low < high:
            spans.append((low, high))
            half_power = min(half_power, 2 * zeta * f)
    spans.sort()
    merged = []
    for low, high in spans:
        if merged and low <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], high))
        else:
            merged.append((low, high))
    return merged, half_power


def band_lines(bands, f0_hz, lines_per_band):
    """Harmonics of ``f0_hz`` spread over each band: every harmonic, or every m-th so that a band holds
    about ``lines_per_band`` (a wide band of a higher mode needs no finer spacing than a narrow one).

    Returns
    -------
    int array
        Ascending harmonic numbers.
    """
    out = []
    for low, high in bands:
        first, last = int(np.ceil(low / f0_hz)), int(np.floor(high / f0_hz))
        if last < first:
            continue
        step = max(1, int(round((last - first + 1) / lines_per_band)))
        out.append(np.arange(first, last + 1, step))
    return np.unique(np.concatenate(out)) if out else np.array([], dtype=int)


def outside_bands(frequency_hz, dense_hz):
    """Which coarse points stay in a merged FRF: those not between two neighbouring dense points
    closer together than the coarse points' own local spacing (the zoom covers them).

    Parameters
    ----------
    frequency_hz : array
        Coarse frequencies, ascending.
    dense_hz : array
        The zoom pass' frequencies, ascending.

    Returns
    -------
    bool array
    """
    frequency_hz = np.asarray(frequency_hz, dtype=float)
    dense_hz = np.sort(np.asarray(dense_hz, dtype=float))
    if dense_hz.size < 2 or frequency_hz.size == 0:
        return np.ones(frequency_hz.size, dtype=bool)
    spacing = np.gradient(frequency_hz) if frequency_hz.size > 1 else np.full(1, np.inf)
    right = np.searchsorted(dense_hz, frequency_hz, side="left")
    inside = (right > 0) & (right < dense_hz.size)
    left_hz = dense_hz[np.clip(right - 1, 0, dense_hz.size - 1)]
    right_hz = dense_hz[np.clip(right, 0, dense_hz.size - 1)]
    covered = inside & (right_hz - left_hz < np.abs(spacing))
    exact = np.isin(frequency_hz, dense_hz)
    return ~(covered | exact)


# ------------------------------------------------------------------------------ the stepped sine's zoom
def stepped_zoom_plan(plant, bands_hz, settings, points_per_band=15, axes=None):
    """A dense stepped-sine pass over zoom bands (`ambid.excitation.StepPlan`), the same steps on every axis.

    Parameters
    ----------
    plant : ambid.plant.Plant
        The nominal model (start amplitudes, as the coarse pass).
    bands_hz : list of (low, high)
    settings : ambid.excitation.SteppedSineSettings
    points_per_band : int
        Linearly spaced steps per band.
    axes : sequence of str, optional
        Default the radial axes of ``settings.axes``.
    """
    from .excitation import StepPlan, amplitude_limits, initial_amplitudes
    from .machine import ALL_AXES, RADIAL_AXES

    axes = [a for a in settings.axes if a in RADIAL_AXES] if axes is None else list(axes)
    frequency = np.unique(np.concatenate([np.linspace(low, high, points_per_band) for low, high in bands_hz]))
    limits = amplitude_limits(plant.machine, settings)
    return StepPlan(np.repeat(axes, frequency.size), np.tile(np.arange(frequency.size), len(axes)),
                    np.tile(frequency, len(axes)),
                    np.concatenate([initial_amplitudes(plant, axis, frequency, settings) for axis in axes]),
                    np.repeat([limits[ALL_AXES.index(a)] for a in axes], frequency.size))


def merge_stepped(coarse, dense):
    """One stepped-sine log from a coarse and a dense pass: per axis, the coarse steps the dense ones
    cover give way (`outside_bands`), and the steps are renumbered in frequency order.

    Parameters
    ----------
    coarse, dense : list of dict
        Step records of `ambid.excitation.run_stepped_sine`.

    Returns
    -------
    list of dict
        Copies of the records kept, with ``step`` the index in the merged grid of their axis.
    """
    merged = []
    for axis in dict.fromkeys(r["excited_axis"] for r in coarse + dense):
        first = sorted((r for r in coarse if r["excited_axis"] == axis), key=lambda r: r["frequency_hz"])
        second = [r for r in dense if r["excited_axis"] == axis]
        keep = outside_bands(np.array([r["frequency_hz"] for r in first]), np.array([r["frequency_hz"] for r in second]))
        records = sorted([r for r, k in zip(first, keep) if k] + second, key=lambda r: r["frequency_hz"])
        merged += [{**record, "step": k} for k, record in enumerate(records)]
    return merged
