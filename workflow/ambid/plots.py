"""Figures: Bode plots of plant FRFs and rotor mode shapes.

Figures are written with blank metadata (no creation date, no software
version) so the same inputs give byte-identical files.
"""

import textwrap
import matplotlib
import matplotlib.collections
import matplotlib.colors
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.patches  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
import numpy as np  # noqa: E402

from .io import atomic_path  # noqa: E402

__all__ = ["bode_matrix", "bode_siso", "bode_measured", "stabilization_diagram", "mode_shapes",
           "calibration_convergence", "youngs_modulus", "update_convergence", "bode_compare", "error_map",
           "residual_fingerprint", "ledger", "excess_maps", "sensitivity_zones", "campbell_diagram", "db", "phase_deg", "frequency_axis", "bla_distortion", "method_comparison", "save_figure"]


def save_figure(figure, path, dpi=120):
    """Save a figure atomically with reproducible (blank) metadata and close it."""
    for axis in figure.axes:
        _minor_log_grid(axis)
    with atomic_path(path) as temporary:
        figure.savefig(temporary, dpi=dpi, format="png", metadata={"Software": None})
    plt.close(figure)


def _minor_log_grid(axis):
    """Draw the minor grid of a log axis as one line collection instead of one tick per line.

    Matplotlib builds every tick as three lines and two labels; the minor ticks of the log
    frequency axes made up 40 % of a many-panel Bode figure's drawing time.  Where the minor
    grid is on, its lines (at the positions and in the style the ticks would have) replace
    the minor ticks; the major ticks, their labels and grid stay as they are.
    """
    for name, scale_axis, transform in (("x", axis.xaxis, axis.get_xaxis_transform()),
                                        ("y", axis.yaxis, axis.get_yaxis_transform())):
        # the keywords `Axes.grid` and `tick_params` left for minor ticks (a private attribute: where a matplotlib
        # release drops it, the minor ticks stay and draw the grid as before, only slower)
        style = getattr(scale_axis, "_minor_tick_kw", None)
        if scale_axis.get_scale() != "log" or not isinstance(style, dict) or not style.get("gridOn", False):
            continue
        low, high = sorted(getattr(axis, f"get_{name}lim")())
        positions = np.asarray(scale_axis.get_minor_locator().tick_values(low, high), dtype=float)
        positions = positions[(positions >= low) & (positions <= high)]
        ends = np.column_stack([positions, np.zeros_like(positions), positions, np.ones_like(positions)])
        segments = ends.reshape(-1, 2, 2) if name == "x" else ends.reshape(-1, 2, 2)[:, :, ::-1]
        grid = {key[len("grid_"):]: value for key, value in style.items() if key.startswith("grid_")}
        lines = matplotlib.collections.LineCollection(
            segments, transform=transform,
            zorder={True: 0.5, "line": 1.5, False: 2.5}[axis.get_axisbelow()],  # where matplotlib puts gridlines
            colors=grid.pop("color", matplotlib.rcParams["grid.color"]),
            linewidths=grid.pop("linewidth", matplotlib.rcParams["grid.linewidth"]),
            linestyles=grid.pop("linestyle", matplotlib.rcParams["grid.linestyle"]),
            alpha=grid.pop("alpha", matplotlib.rcParams["grid.alpha"]))
        axis.add_collection(lines, autolim=False)
        scale_axis.set_minor_locator(matplotlib.ticker.NullLocator())


def db(values):
    """Magnitude in dB (20 log10 |values|); -inf-free (zero gives NaN, not drawn)."""
    magnitude = np.abs(np.asarray(values))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(magnitude > 0, 20 * np.log10(np.where(magnitude > 0, magnitude, 1.0)), np.nan)


def phase_deg(values):
    """Phase in degrees, unwrapped along the frequency axis, starting in [-270, 90) deg.

    The field draws a Bode phase continuous: no vertical +-180 degree strokes
    at the wraps.  The start convention puts an AMB plant's low-frequency phase
    (negative stiffness: a negative real response) at -180 deg and a
    well-behaved response at 0, so measured and model curves drawn on the same
    axes start on the same branch.
    """
    phase = np.degrees(np.unwrap(np.angle(np.asarray(values))))
    if phase.size:
        phase = phase - 360.0 * np.floor((phase[0] + 270.0) / 360.0)
    return phase


def phase_near(values, reference_deg):
    """Phase in degrees on the branch of ``reference_deg`` (within 180 deg of it, point by point).

    Measured points unwrapped on their own can take the other branch at an
    anti-resonance (noise decides whether the phase steps by +180 or -180
    deg) and end 360 deg away from the model drawn over them; drawn near the
    model's unwrapped phase they stay on its branch, and what is plotted is
    the physical phase difference.
    """
    reference_deg = np.asarray(reference_deg, dtype=float)
    return reference_deg + np.degrees(np.angle(np.asarray(values) * np.exp(-1j * np.radians(reference_deg))))


def frequency_axis(axis, frequency_hz):
    """Log frequency axis where the band spans a decade or more (the field's Bode convention), linear below."""
    frequency_hz = np.asarray(frequency_hz, dtype=float)
    positive = frequency_hz[np.isfinite(frequency_hz) & (frequency_hz > 0)]
    if positive.size and positive.max() >= 10 * positive.min():
        axis.set_xscale("log")


def _phase_axis(axis):
    axis.yaxis.set_major_locator(matplotlib.ticker.MaxNLocator(nbins=6, steps=[4.5, 9]))  # multiples of 45 or 90 deg


def _fixed_margins(size_in, rows, columns, left, right, top, bottom, between_columns, between_rows):
    """GridSpec keywords for ``rows x columns`` panels with margins and gaps fixed in inches.

    The figures here carry known labels, so their room is set, not measured:
    a layout engine measures every tick label of every axis twice, half the
    drawing time of a many-panel figure.
    """
    width, height = size_in
    panel_width = (width - left - right - (columns - 1) * between_columns) / columns
    panel_height = (height - top - bottom - (rows - 1) * between_rows) / rows
    return dict(left=left / width, right=1 - right / width, bottom=bottom / height, top=1 - top / height,
                wspace=between_columns / panel_width, hspace=between_rows / panel_height)


def _title(figure, title):
    """The figure's title a fixed 0.12 inch below its top edge (with `_fixed_margins`, whatever the figure's height)."""
    figure.suptitle(title, y=1 - 0.12 / figure.get_figheight(), va="top")


def _bode_grid(panels, columns=2, width=11.0, height=3.6):
    """Figure and one (magnitude, phase) pair of axes per panel, laid out ``columns`` wide to be read at page width.

    Panels fill rows left to right; each pair is magnitude above phase sharing
    the frequency axis (`_fixed_margins`).
    """
    columns = max(1, min(columns, panels))
    rows = -(-panels // columns)
    size = (width if columns > 1 else width / 1.7, height * rows + 0.7)
    figure = plt.figure(figsize=size)
    outer = figure.add_gridspec(rows, columns, **_fixed_margins(size, rows, columns, left=0.85, right=0.2, top=0.65,
                                                                bottom=0.55, between_columns=0.95, between_rows=0.85))
    pairs = []
    for k in range(panels):
        inner = outer[divmod(k, columns)].subgridspec(2, 1, height_ratios=[1.3, 1], hspace=0.08)
        magnitude = figure.add_subplot(inner[0])
        phase = figure.add_subplot(inner[1], sharex=magnitude)
        magnitude.tick_params(labelbottom=False)
        pairs.append((magnitude, phase))
    return figure, pairs


def _bode_axes(magnitude_axis, phase_axis, frequency_hz, values, label=None, **style):
    magnitude_axis.plot(frequency_hz, db(values), label=label, **style)
    phase_axis.plot(frequency_hz, phase_deg(values), **style)
    frequency_axis(phase_axis, frequency_hz)


def bode_matrix(frequency_hz, response, outputs, inputs, title, unit="m/A"):
    """Bode plots of every channel of a MIMO FRF, one column per input.

    Parameters
    ----------
    frequency_hz : array (n_f,)
    response : complex array (n_f, n_out, n_in)
    outputs, inputs : sequences of axis names
    """
    n_out, n_in = response.shape[1:]
    figure, pairs = _bode_grid(n_in)
    for j, (input_name, (magnitude, phase)) in enumerate(zip(inputs, pairs)):
        for i, output_name in enumerate(outputs):
            style = dict(lw=1.6 if i == j else 0.8, ls="-" if i == j else "--")
            _bode_axes(magnitude, phase, frequency_hz, response[:, i, j], label=f"{output_name}", **style)
        magnitude.set_title(f"input {input_name}", fontsize=9)
        magnitude.set_ylabel(f"|P| [dB re 1 {unit}]", fontsize=8)
        phase.set_ylabel("phase [deg]", fontsize=8)
        phase.set_xlabel("frequency [Hz]")
        magnitude.grid(True, which="both", alpha=0.3)
        phase.grid(True, which="both", alpha=0.3)
        _phase_axis(phase)
    pairs[0][0].legend(title="output", fontsize=7, title_fontsize=7)
    _title(figure, title)
    return figure


def bode_siso(frequency_hz, values, title, unit="m/A", markers=False):
    """Bode plot of one channel; ``markers`` marks every measurement point (thesis Fig. 6.3)."""
    figure, (magnitude_axis, phase_axis) = plt.subplots(2, 1, figsize=(6, 5), sharex=True)
    style = dict(marker=".", ms=3) if markers else {}
    _bode_axes(magnitude_axis, phase_axis, frequency_hz, values, **style)
    magnitude_axis.set_ylabel(f"|G| [dB re 1 {unit}]")
    phase_axis.set_ylabel("phase [deg]")
    _phase_axis(phase_axis)
    phase_axis.set_xlabel("frequency [Hz]")
    for axis in (magnitude_axis, phase_axis):
        axis.grid(True, which="both", alpha=0.3)
    magnitude_axis.set_title(title)
    figure.tight_layout()
    return figure


def bode_measured(channels, title, unit="m/A", fits=None):
    """Measured FRFs with every measurement point marked and a +-2 sigma band (thesis Fig. 6.3, 6.4).

    Parameters
    ----------
    channels : list of (label, frequency_hz, values, std)
        One panel column per channel.
    fits : list of dict, optional
        Per channel, fitted models ``name -> complex array`` on the same
        frequencies, drawn as lines over the measured points (for example the
        default fit and the thesis' method).
    """
    if not channels:  # e.g. a run without the axial axis
        figure, axis = plt.subplots(figsize=(4, 2))
        axis.text(0.5, 0.5, "no measurement", ha="center", va="center")
        axis.set_axis_off()
        figure.suptitle(title)
        return figure
    # with fits overlaid, the measurement is points only so that the lines stand out
    measured_style = dict(marker=".", ms=3, lw=0.8) if fits is None else dict(marker=".", ms=3, ls="none", color="C0")
    figure, pairs = _bode_grid(len(channels))
    for k, ((label, frequency, values, std), (magnitude_axis, phase_axis)) in enumerate(zip(channels, pairs)):
        magnitude = np.abs(values)
        magnitude_axis.fill_between(frequency, db(np.maximum(magnitude - 2 * std, magnitude * 1e-3)), db(magnitude + 2 * std),
                                    alpha=0.25, lw=0, color="C0")
        magnitude_axis.plot(frequency, db(values), label="measured", **measured_style)
        models = fits[k] if fits is not None else {}
        reference = phase_deg(next(iter(models.values()))) if models else phase_deg(values)  # the first fit's branch
        phase_axis.plot(frequency, phase_near(values, reference), **measured_style)
        for n, (name, model) in enumerate(models.items(), start=1):
            magnitude_axis.plot(frequency, db(model), lw=1.0, color=f"C{n}", label=name)
            phase_axis.plot(frequency, phase_near(model, reference), lw=1.0, color=f"C{n}")
        frequency_axis(phase_axis, frequency)
        magnitude_axis.set_title(label, fontsize=9)
        magnitude_axis.set_ylabel(f"|G| [dB re 1 {unit}]", fontsize=8)
        phase_axis.set_ylabel("phase [deg]", fontsize=8)
        phase_axis.set_xlabel("frequency [Hz]")
        _phase_axis(phase_axis)
        for axis in (magnitude_axis, phase_axis):
            axis.grid(True, which="both", alpha=0.3)
    if fits is not None:
        pairs[0][0].legend(fontsize=7, loc="lower left")
    _title(figure, title)
    return figure


def stabilization_diagram(diagrams, selected_hz, band_hz, title):
    """Stabilization diagrams: pole frequency against model order, one panel per channel.

    Parameters
    ----------
    diagrams : dict label -> list of rows (`ambid.fit.stabilization`)
    selected_hz : dict label -> array of the modes kept [Hz]
    band_hz : (float, float)
    """
    labels = list(diagrams)
    figure, axes = plt.subplots(len(labels), 1, figsize=(7, 1.6 * len(labels) + 0.8), sharex=True, squeeze=False)
    styles = {(True, True): ("s", "C2", "stable, physical"), (False, True): ("o", "C0", "physical, not stable"),
              (True, False): ("x", "C1", "stable, unphysical"), (False, False): (".", "0.6", "other")}
    for axis, label in zip(axes[:, 0], labels):
        rows = [r for r in diagrams[label] if band_hz[0] <= r["frequency_hz"] <= band_hz[1]]
        for (stable, physical), (marker, color, name) in styles.items():
            pick = [r for r in rows if r["stable"] == stable and r["physical"] == physical]
            axis.plot([r["frequency_hz"] for r in pick], [r["order"] for r in pick], marker, color=color, ms=4,
                      ls="none", label=name)
        for frequency in selected_hz.get(label, []):
            axis.axvline(frequency, color="C3", lw=0.8, alpha=0.7)
        axis.set_ylabel(f"{label}\norder")
        axis.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel("pole frequency [Hz] (red: modes kept)")
    axes[0, 0].set_xlim(*band_hz)
    handles, names = axes[0, 0].get_legend_handles_labels()
    figure.legend(handles, names, fontsize=7, ncol=4, loc="lower center")
    figure.suptitle(title)
    figure.tight_layout(rect=(0, 0.03, 1, 1))
    return figure


def mode_shapes(node_positions_m, shapes, frequency_hz, bearing_positions_m, sensor_positions_m, title):
    """Planar bending mode shapes (displacement along the rotor), normalized to unit peak.

    Parameters
    ----------
    node_positions_m : array (n_nodes,)
    shapes : array (2 n_nodes, n_modes)
        Planar mode shapes ``[u, theta]`` per node.
    frequency_hz : array (n_modes,)
    bearing_positions_m, sensor_positions_m : sequences
        Marked on the plot (actuators as solid, sensors as dotted lines).
    """
    figure, axis = plt.subplots(figsize=(8, 4))
    displacement = shapes[0::2]
    for k in range(shapes.shape[1]):
        u = displacement[:, k]
        u = u / np.max(np.abs(u))
        u = u * np.sign(u[np.argmax(np.abs(u))])
        axis.plot(node_positions_m, u, marker="o", ms=2.5, label=f"{frequency_hz[k]:.1f} Hz")
    for z in bearing_positions_m:
        axis.axvline(z, color="k", lw=1.2)
    for z in sensor_positions_m:
        axis.axvline(z, color="k", lw=1.0, ls=":")
    axis.axhline(0, color="grey", lw=0.5)
    axis.set_xlabel("axial position z [m] (solid: actuators, dotted: sensors)")
    axis.set_ylabel("normalized displacement")
    axis.set_title(title)
    axis.legend(fontsize=8, ncol=2)
    axis.grid(True, alpha=0.3)
    figure.tight_layout()
    return figure


def calibration_convergence(offsets, tolerance_m, title):
    """Position offset x_c per iteration and axis, one line per repetition (thesis Fig. 6.2, Table 6.1).

    Parameters
    ----------
    offsets : pandas.DataFrame
        Columns ``repetition``, ``iteration``, ``axis``, ``offset_m``.
    tolerance_m : float
        Drawn as a band.
    """
    axes_names = list(dict.fromkeys(offsets["axis"]))
    figure, axes = plt.subplots(1, len(axes_names), figsize=(3.2 * len(axes_names), 3.4), sharey=True, squeeze=False)
    repetitions = list(dict.fromkeys(offsets["repetition"]))
    # repetitions often agree to well below a line width: each is shifted sideways a little, with its own marker
    shift = {r: 0.25 * (k - (len(repetitions) - 1) / 2) / max(len(repetitions) - 1, 1) for k, r in enumerate(repetitions)}
    markers = "osD^vP*X"
    for axis, name in zip(axes[0], axes_names):
        for repetition, group in offsets[offsets["axis"] == name].groupby("repetition"):
            k = repetitions.index(repetition)
            axis.plot(group["iteration"] + shift[repetition], group["offset_m"] * 1e6, marker=markers[k % len(markers)],
                      ms=3.5, lw=1, alpha=0.85, label=f"rep. {repetition}")
        axis.axhspan(-tolerance_m * 1e6, tolerance_m * 1e6, color="green", alpha=0.15)
        axis.set_title(name)
        axis.set_xlabel("iteration")
        axis.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
        axis.grid(True, alpha=0.3)
    axes[0, 0].set_ylabel("offset x_c [um] (repetitions shifted sideways)")
    axes[0, -1].legend(fontsize=7)
    figure.suptitle(title)
    figure.tight_layout()
    return figure


def youngs_modulus(variables, title):
    """Young's modulus of each design element before and after the update (thesis Fig. 5.5, 6.8).

    Parameters
    ----------
    variables : pandas.DataFrame
        The update's stiffness variables: ``label``, ``youngs_modulus_start_pa``,
        ``youngs_modulus_updated_pa``, ``std`` (relative), ``determined``.
        Variables the data do not determine are drawn hatched: their value is
        not a measurement.
    """
    figure, axis = plt.subplots(figsize=(max(7.0, 0.45 * len(variables) + 2.0), 3.8))
    x = np.arange(len(variables))
    start = variables["youngs_modulus_start_pa"].to_numpy(float) / 1e9
    updated = variables["youngs_modulus_updated_pa"].to_numpy(float) / 1e9
    determined = variables["determined"].to_numpy(bool)
    axis.bar(x - 0.2, start, width=0.4, color="0.7")
    bars = axis.bar(x + 0.2, updated, width=0.4, color=np.where(determined, "C0", "white"), edgecolor="C0")
    for bar, ok in zip(bars, determined):
        if not ok:
            bar.set_hatch("//")
    std = variables["std"].to_numpy(float)
    finite = np.isfinite(std) & determined
    axis.errorbar(x[finite] + 0.2, updated[finite], yerr=2 * std[finite] * updated[finite], fmt="none", ecolor="k",
                  capsize=2, lw=0.8)
    axis.set_xticks(x)
    axis.set_xticklabels(variables["label"], rotation=60, ha="right", fontsize=7)
    axis.set_ylabel("Young's modulus E [GPa]")
    axis.grid(True, axis="y", alpha=0.3)
    handles = [Patch(color="0.7", label="original"), Patch(color="C0", label="updated (+-2 sigma)"),
               Patch(facecolor="white", edgecolor="C0", hatch="//", label="updated, not determined by the data")]
    # the legend in a row above the bars (headroom), not over the first of them
    axis.set_ylim(0.0, 1.25 * max(np.nanmax(start), np.nanmax(updated)))
    axis.legend(handles=handles, fontsize=7, loc="upper center", ncol=3)
    axis.set_title(title)
    figure.tight_layout()
    return figure


def update_convergence(history, chosen_start, title):
    """``B(e)`` (thesis eq. 5.35) at every objective evaluation of every start (thesis Fig. 6.9)."""
    figure, axis = plt.subplots(figsize=(6.5, 3.8))
    for start, group in history.groupby("start"):
        chosen = start == chosen_start
        axis.semilogy(group["evaluation"], np.maximum(group["objective_b"], 1e-16), lw=1.6 if chosen else 0.7,
                      color="C3" if chosen else "0.6", alpha=1.0 if chosen else 0.7,
                      label=f"start {start} (chosen)" if chosen else None)
    axis.plot([], [], color="0.6", lw=0.7, label="other starts")
    axis.set_xlabel("objective evaluation")
    axis.set_ylabel("B(e) (eq. 5.35)")
    axis.grid(True, which="both", alpha=0.3)
    axis.legend(fontsize=7)
    axis.set_title(title)
    figure.tight_layout()
    return figure


def _channel_label(key):
    """The one channel name used in text, tables and figures: ``output/input`` (e.g. ``DX/NX``, ``I_NX/NX``)."""
    output, input_axis = key
    return f"{output}/{input_axis}"


def bode_compare(measured, models, channels, title):
    """Measured channels with their uncertainty band beside one or more models' responses.

    Parameters
    ----------
    measured : dict (output, input) -> (frequency_hz, values, std)
    models : dict label -> {(output, input): values}
    channels : list of (output, input), one row of (magnitude, phase) each
    """
    figure, pairs = _bode_grid(len(channels))
    for key, (magnitude, phase) in zip(channels, pairs):
        frequency, values, std = measured[key]
        unit = "A/A" if key[0].startswith("I_") else "m/A"
        size = np.abs(values)
        magnitude.fill_between(frequency, db(np.maximum(size - 2 * std, 1e-3 * size)), db(size + 2 * std), color="0.8",
                               label="measured +-2 sigma")
        magnitude.plot(frequency, db(values), "k.", ms=2.5, label="measured")
        band_deg = np.degrees(np.minimum(2 * std / np.maximum(size, 1e-300), np.pi))
        drawn = [response[key] for response in models.values() if key in response]
        reference = phase_deg(drawn[0]) if drawn else phase_deg(values)  # the first model's branch for every curve
        measured_phase = phase_near(values, reference)
        phase.fill_between(frequency, measured_phase - band_deg, measured_phase + band_deg, color="0.8")
        phase.plot(frequency, measured_phase, "k.", ms=2.5)
        for label, response in models.items():
            if key in response:
                magnitude.plot(frequency, db(response[key]), lw=1.2, label=label)
                phase.plot(frequency, phase_near(response[key], reference), lw=1.2)
        frequency_axis(phase, frequency)
        magnitude.set_title(_channel_label(key), fontsize=9)
        magnitude.set_ylabel(f"[dB re 1 {unit}]", fontsize=8)
        phase.set_ylabel("phase [deg]", fontsize=8)
        phase.set_xlabel("frequency [Hz]")
        _phase_axis(phase)
        for axis in (magnitude, phase):
            axis.grid(True, which="both", alpha=0.3)
    pairs[0][0].legend(fontsize=7, loc="best")
    _title(figure, title)
    return figure


# One fixed colour scale for every misfit map of every report, so colours compare across variants and machines:
# chi2 per point (|G_model - G_meas|^2 / sigma^2 averaged) from 0.1 to 1e4 on a log scale, everything at or below the
# floor of 1 in one pale green, above it magma from pale to black; NaN (not measured) shows a grey hatch.
MISFIT_RANGE = (0.1, 1e4)


def _misfit_colours():
    low = np.log10(MISFIT_RANGE[0])
    share = (0 - low) / (np.log10(MISFIT_RANGE[1]) - low)  # where 1 sits on the scale
    below = int(round(256 * share))
    colours = np.vstack([np.tile(matplotlib.colors.to_rgba("#d4ecd4"), (below, 1)),
                         plt.get_cmap("magma_r")(np.linspace(0.08, 1.0, 256 - below))])
    cmap = matplotlib.colors.ListedColormap(colours).with_extremes(bad=(0, 0, 0, 0))
    return cmap, matplotlib.colors.LogNorm(*MISFIT_RANGE, clip=True)


def _not_measured_background(axis):
    axis.set_facecolor("0.93")
    axis.add_patch(matplotlib.patches.Rectangle((0, 0), 1, 1, transform=axis.transAxes, facecolor="none",
                                                edgecolor="0.6", hatch="///", lw=0, zorder=0))


def _misfit_colorbar(figure, image, axes, label, height_in=4.5):
    """The misfit scale right of ``axes``, level with their top, at most ``height_in`` tall."""
    boxes = [axis.get_position() for axis in np.atleast_1d(axes).flat]
    top, bottom, right = max(b.y1 for b in boxes), min(b.y0 for b in boxes), max(b.x1 for b in boxes)
    width_in, figure_height_in = figure.get_size_inches()
    height = min(top - bottom, height_in / figure_height_in)
    bar = figure.colorbar(image, cax=figure.add_axes((right + 0.2 / width_in, top - height, 0.15 / width_in, height)),
                          extend="both", label=label)
    bar.ax.axhline(1.0, color="k", lw=2)
    ticks = [t for t in (0.1, 1, 10, 100, 1e3, 1e4, 1e5, 1e6) if MISFIT_RANGE[0] <= t <= MISFIT_RANGE[1]]
    bar.set_ticks(ticks, labels=["1 = floor" if t == 1 else f"{t:g}" for t in ticks])
    figure.legend(handles=[Patch(facecolor="0.93", edgecolor="0.6", hatch="///", label="not measured")], fontsize=7,
                  loc="lower right", frameon=False)
    return bar


def error_map(errors, title):
    """Channel x frequency map of the squared normalized error |G_model - G_meas|^2 / sigma^2.

    On the one fixed scale of `MISFIT_RANGE` (the floor at 1 marked), the same
    for every variant, so a colour means the same misfit on every map.
    """
    channels = list(dict.fromkeys(zip(errors["output"], errors["input"])))
    size = (10, 0.3 * len(channels) + 1.8)
    figure, axes = plt.subplots(figsize=size, squeeze=False, gridspec_kw=_fixed_margins(
        size, 1, 1, left=0.8, right=1.3, top=0.4, bottom=0.55, between_columns=0, between_rows=0))
    axis = axes[0, 0]
    cmap, norm = _misfit_colours()
    _not_measured_background(axis)
    image = None
    for row, (output, input_axis) in enumerate(channels):
        part = errors[(errors["output"] == output) & (errors["input"] == input_axis)].sort_values("frequency_hz")
        frequency = part["frequency_hz"].to_numpy()
        edges = np.concatenate([[frequency[0]], 0.5 * (frequency[1:] + frequency[:-1]), [frequency[-1]]])
        image = axis.pcolormesh(edges, [row - 0.5, row + 0.5], (part["normalized_error"].to_numpy() ** 2)[None, :],
                                norm=norm, cmap=cmap, shading="flat")
    frequency_axis(axis, errors["frequency_hz"])
    axis.set_yticks(range(len(channels)))
    axis.set_yticklabels([_channel_label(c) for c in channels], fontsize=7)
    axis.set_ylim(len(channels) - 0.5, -0.5)
    axis.set_xlabel("frequency [Hz]")
    _misfit_colorbar(figure, image, axis, "|G_model - G_meas|^2 / sigma^2  (1 = floor)")
    axis.set_title(title)
    return figure


def _band_edges(label):
    """``'20-50 Hz'`` -> (20.0, 50.0); an open band (``inf``) is drawn one octave wide."""
    low, high = (float(x) for x in str(label).replace("Hz", "").split("-"))
    return low, high if np.isfinite(high) else 2 * low


def _compact(value):
    return f"{value:.2g}".replace("e+0", "e").replace("e+", "e")


def excess_maps(summaries, title, columns=2):
    """Channel x band chi2 per point of every variant, one panel each, on the one fixed scale (`MISFIT_RANGE`).

    Each band is drawn over the frequencies it spans (log axis), so channel
    families with different bands (each derived from its measured grid,
    `ambid.floor.frequency_bands`) line up; where a channel has no band the
    cell is hatched (not measured), never white.

    Parameters
    ----------
    summaries : dict label -> pandas.DataFrame
        `ambid.compare.summarize` tables (``output``, ``input``, ``band``,
        ``points``, ``chi2``); the ``all`` band is left out.
    """
    parts = {label: frame[(frame["band"] != "all") & (frame["output"] != "all")] for label, frame in summaries.items()}
    channels = list(dict.fromkeys(key for frame in parts.values() for key in zip(frame["output"], frame["input"])))
    edges = [_band_edges(b) for frame in parts.values() for b in frame["band"]]
    span = (min(e[0] for e in edges), max(e[1] for e in edges))
    columns = max(1, min(columns, len(parts)))
    rows = -(-len(parts) // columns)
    size = (5.0 * columns + 1.2, (0.24 * len(channels) + 1.2) * rows + 0.6)
    figure, axes = plt.subplots(rows, columns, figsize=size, squeeze=False, gridspec_kw=_fixed_margins(
        size, rows, columns, left=0.8, right=1.3, top=0.7, bottom=0.45, between_columns=0.8, between_rows=0.65))
    cmap, norm = _misfit_colours()
    image = None
    for axis, (label, frame) in zip(axes.flat, parts.items()):
        _not_measured_background(axis)
        cells, values = [], []  # one collection of the panel's cells: an artist per cell took seconds to draw
        for row in frame[frame["points"] > 0].itertuples():
            i = channels.index((row.output, row.input))
            low, high = _band_edges(row.band)
            cells.append([(low, i - 0.5), (high, i - 0.5), (high, i + 0.5), (low, i + 0.5)])
            values.append(row.chi2)
            axis.text(np.sqrt(low * high) if low > 0 else 0.5 * high, i, _compact(row.chi2), ha="center", va="center",
                      fontsize=5.5, color="white" if row.chi2 > 300 else "black")
        if cells:
            image = axis.add_collection(matplotlib.collections.PolyCollection(
                cells, array=np.asarray(values, dtype=float), cmap=cmap, norm=norm, edgecolors="white", linewidths=0.3))
        axis.set_xscale("log" if span[0] > 0 else "linear")
        axis.set_xlim(*span)
        axis.set_xlabel("frequency [Hz] (cells: the bands of each channel family)", fontsize=7)
        axis.set_yticks(range(len(channels)))
        axis.set_yticklabels([_channel_label(c) for c in channels], fontsize=6.5)
        axis.set_ylim(len(channels) - 0.5, -0.5)
        axis.set_title(label, fontsize=9)
    for axis in list(axes.flat)[len(parts):]:
        axis.set_axis_off()
    _title(figure, title)
    _misfit_colorbar(figure, image, axes, "chi2 per point")
    return figure


def residual_fingerprint(measured, model, predicted, channels, title, candidate_label):
    """The residual ``G_meas / G_model`` (points) beside what the best candidate predicts, ``G_candidate / G_model``."""
    figure, pairs = _bode_grid(len(channels))
    for key, (magnitude, phase) in zip(channels, pairs):
        frequency, values, _ = measured[key]
        ratio = values / model[key]
        magnitude.plot(frequency, db(ratio), "k.", ms=2.5, label="measured / model")
        phase.plot(frequency, phase_deg(ratio), "k.", ms=2.5)
        if predicted is not None:
            change = predicted[key] / model[key]
            magnitude.plot(frequency, db(change), "C3", lw=1.4, label=f"{candidate_label} / model")
            phase.plot(frequency, phase_deg(change), "C3", lw=1.4)
        frequency_axis(phase, frequency)
        magnitude.set_title(_channel_label(key), fontsize=9)
        magnitude.set_ylabel("ratio [dB]", fontsize=8)
        phase.set_ylabel("phase diff. [deg]", fontsize=8)
        phase.set_xlabel("frequency [Hz]")
        for axis in (magnitude, phase):
            axis.grid(True, which="both", alpha=0.3)
    pairs[0][0].legend(fontsize=7)
    _title(figure, title)
    return figure


def ledger(table, title):
    """Excess over the noise floor (chi2 per point - 1) of each model variant, overall and per channel."""
    variants = list(dict.fromkeys(table["variant"]))
    figure, axis = plt.subplots(figsize=(max(6.0, 1.6 * len(variants) + 3), 4.6))
    x = np.arange(len(variants))
    for run, part in table.groupby("run", sort=False):
        channels = part[part["output"] != "all"]
        for (output, input_axis), rows in channels.groupby(["output", "input"], sort=False):
            rows = rows.set_index("variant").reindex(variants)
            axis.semilogy(x, np.maximum(rows["excess"], 1e-3), color="0.75", lw=0.7)
        overall = part[part["output"] == "all"].set_index("variant").reindex(variants)
        axis.semilogy(x, np.maximum(overall["excess"], 1e-3), "o-", lw=2.2, label=f"{run}: overall")
    axis.plot([], [], color="0.75", lw=0.7, label="single channels")
    axis.set_xticks(x)
    if "diagnosis" in table.columns:  # what the diagnosis of each variant says, under its name
        said = table.drop_duplicates("variant").set_index("variant")["diagnosis"]
        labels = [f"{v}\n" + textwrap.fill(str(said.get(v, "")), 22) for v in variants]
    else:
        labels = variants
    axis.set_xticklabels(labels, fontsize=7)
    axis.set_ylabel("excess over the floor (chi2 per point - 1)")
    axis.grid(True, which="both", alpha=0.3)
    axis.legend(fontsize=8)
    axis.set_title(title)
    figure.tight_layout()
    return figure


def bla_distortion(channels, spectra, title):
    """The multisine's measured floors (Pintelon & Schoukens 2012, Fig. 3.9 style).

    Top row, per channel: ``|G_BLA|``, its noise standard deviation and the
    standard deviation of its systematic (nonlinear) error.  Bottom row, per
    output: the period-averaged output at the excited lines, at the left-out
    odd lines (odd nonlinear distortion) and at the even lines (even
    distortion), with the noise level of the period mean.

    Parameters
    ----------
    channels : list of (label, frequency_hz, values, std, systematic_std)
    spectra : list of (label, frequency_hz, level_m, role, noise_m)
        ``role`` per line as in `ambid.logs.LINE_ROLES` (other values: not drawn, e.g. another axis' lines).
    """
    columns = max(len(channels), len(spectra), 1)
    figure, axes = plt.subplots(2, columns, figsize=(3.4 * columns + 0.6, 6.0), squeeze=False)
    for k, (label, frequency, values, std, systematic) in enumerate(channels):
        axis = axes[0, k]
        axis.loglog(frequency, np.abs(values), "k.", ms=2.5, label="|G_BLA|")
        axis.loglog(frequency, std, ".", color="C0", ms=2, label="noise std")
        axis.loglog(frequency, systematic, ".", color="C3", ms=2, label="systematic std")
        axis.set_title(label, fontsize=9)
        axis.grid(True, which="both", alpha=0.3)
    for k, (label, frequency, level, role, noise) in enumerate(spectra):
        axis = axes[1, k]
        for name, style, text in (("excited", dict(color="k", ms=2.5), "excited"),
                                  ("odd_detection", dict(color="C3", ms=3), "odd detection"),
                                  ("even_detection", dict(color="C0", ms=2), "even detection")):
            pick = role == name
            axis.loglog(frequency[pick], np.maximum(level[pick], 1e-14), ".", label=text, **style)
        detection = np.isin(role, ("odd_detection", "even_detection"))
        axis.loglog(frequency[detection], noise[detection], "-", color="0.6", lw=0.6, label="noise")
        axis.set_title(label, fontsize=9)
        axis.set_xlabel("frequency [Hz]")
        axis.grid(True, which="both", alpha=0.3)
    for row in range(2):
        for k in range(columns):
            if not axes[row, k].has_data():
                axes[row, k].set_axis_off()
    axes[0, 0].set_ylabel("[m/A]")
    axes[1, 0].set_ylabel("output amplitude [m]")
    axes[0, 0].legend(fontsize=7, loc="lower left")
    axes[1, 0].legend(fontsize=7, loc="lower left")
    figure.suptitle(title)
    figure.tight_layout()
    return figure


def method_comparison(runs, channel_label, title):
    """One channel measured by several identification runs: relative noise and systematic standard deviations.

    Parameters
    ----------
    runs : list of (label, frequency_hz, values, std, systematic_std)
        ``systematic_std`` NaN where the run has no estimate.
    """
    figure, (magnitude, relative) = plt.subplots(2, 1, figsize=(8, 6.4), sharex=True)
    for k, (label, frequency, values, std, systematic) in enumerate(runs):
        magnitude.loglog(frequency, np.abs(values), ".", ms=2.5, color=f"C{k}", label=label)
        relative.loglog(frequency, std / np.abs(values), ".", ms=2.5, color=f"C{k}", label=f"{label}: noise")
        if np.any(np.isfinite(systematic)):
            relative.loglog(frequency, systematic / np.abs(values), "x", ms=2.5, color=f"C{k}",
                            label=f"{label}: systematic")
    magnitude.set_ylabel(f"|{channel_label}| [m/A]")
    relative.set_ylabel("standard deviation / |G|")
    relative.set_xlabel("frequency [Hz]")
    for axis in (magnitude, relative):
        axis.grid(True, which="both", alpha=0.3)
        axis.legend(fontsize=7)
    figure.suptitle(title)
    figure.tight_layout()
    return figure


def sensitivity_zones(measured, models, zone_limits_db, title, columns=2):
    """Measured output sensitivity ``|U2/Eu|`` per axis beside the models', with the ISO 14839-3 zone limits.

    Parameters
    ----------
    measured : dict axis -> (frequency_hz, sensitivity, std)
    models : dict label -> {axis: (frequency_hz, sensitivity)}
    zone_limits_db : sequence of (limit_db, zone)
        Upper limit of each zone (A, B, C); above the last is D.
    """
    axes_names = list(measured) or sorted({a for curves in models.values() for a in curves})
    columns = max(1, min(columns, len(axes_names)))
    rows = -(-len(axes_names) // columns)
    figure, axes = plt.subplots(rows, columns, figsize=(5.5 * columns, 3.0 * rows + 0.6), squeeze=False,
                                layout="constrained")
    shades = ("#d4ecd4", "#fff3c4", "#ffd8b0", "#f4b6b6")
    for axis, name in zip(axes.flat, axes_names):
        lower = -60.0
        for (limit, zone), shade in zip(list(zone_limits_db) + [(60.0, "D")], shades):
            axis.axhspan(lower, limit, color=shade, lw=0, zorder=0)
            axis.text(1.01, min(limit, 18) - 0.4, zone, transform=axis.get_yaxis_transform(), fontsize=7, va="top")
            lower = limit
        for limit, _ in zone_limits_db:
            axis.axhline(limit, color="0.4", lw=0.6, ls="--")
        for k, (label, curves) in enumerate(models.items(), start=1):
            if name in curves:
                frequency, values = curves[name]
                axis.plot(frequency, db(values), lw=1.2, color=f"C{k}", label=f"model {label}")
        if name in measured:
            frequency, values, std = measured[name]
            size = np.abs(values)
            axis.fill_between(frequency, db(np.maximum(size - 2 * std, 1e-3 * size)), db(size + 2 * std), color="0.6",
                              alpha=0.5, lw=0)
            axis.plot(frequency, db(values), "k.", ms=2.5, label="measured |U2/Eu| (+-2 sigma)")
            peak = int(np.argmax(size))
            axis.plot(frequency[peak], db(size[peak]), "kv", ms=6)
            axis.annotate(f"{db(size[peak]):.1f} dB at {frequency[peak]:.0f} Hz", (frequency[peak], db(size[peak])),
                          textcoords="offset points", xytext=(4, 6), fontsize=7)
        frequency_axis(axis, np.concatenate([c[name][0] for c in models.values() if name in c]
                                            + ([measured[name][0]] if name in measured else [])))
        axis.set_ylim(-20, 18)
        axis.set_title(f"axis {name}", fontsize=9)
        axis.set_ylabel("|S| [dB]", fontsize=8)
        axis.set_xlabel("frequency [Hz]", fontsize=8)
        axis.grid(True, which="both", alpha=0.3)
    for axis in list(axes.flat)[len(axes_names):]:
        axis.set_axis_off()
    axes.flat[0].legend(fontsize=7, loc="lower right")
    figure.suptitle(title)
    return figure


def campbell_diagram(modes, measured_hz, max_frequency_hz, title):
    """Closed-loop natural frequencies over rotor speed with the synchronous line and the modes measured at standstill.

    Parameters
    ----------
    modes : pandas.DataFrame
        `ambid.commissioning.campbell`: ``speed_rpm``, ``frequency_hz``, ``whirl``.
    measured_hz : array
        Resonances identified at standstill, marked at speed 0.
    """
    figure, axis = plt.subplots(figsize=(8, 5), layout="constrained")
    styles = {"forward": ("^", "C3", "forward whirl"), "backward": ("v", "C0", "backward whirl"),
              "planar": ("o", "0.3", "standstill (planar)")}
    for whirl, (marker, colour, label) in styles.items():
        part = modes[modes["whirl"] == whirl]
        if not part.empty:
            axis.plot(part["speed_rpm"], part["frequency_hz"], marker, color=colour, ms=3, ls="none", label=label)
    other = modes[~modes["whirl"].isin(list(styles))]
    if not other.empty:
        axis.plot(other["speed_rpm"], other["frequency_hz"], ".", color="0.6", ms=3, ls="none", label="other")
    speeds = np.linspace(0, float(modes["speed_rpm"].max()) if not modes.empty else 1.0, 50)
    axis.plot(speeds, speeds / 60, "k-", lw=1.0, label="1x (synchronous)")
    measured_hz = np.asarray(measured_hz, dtype=float)
    if measured_hz.size:
        axis.plot(np.zeros_like(measured_hz), measured_hz, "*", color="C2", ms=10, mec="k", mew=0.5, clip_on=False,
                  label="identified at standstill (fit)", zorder=5)
    axis.set_ylim(0, max_frequency_hz)
    axis.set_xlim(left=0)
    axis.set_xlabel("rotor speed [rpm]")
    axis.set_ylabel("closed-loop natural frequency [Hz]")
    axis.grid(True, alpha=0.3)
    axis.legend(fontsize=7, loc="upper left")
    axis.set_title(title)
    return figure
