"""Figures: Bode plots of plant FRFs and rotor mode shapes.

Figures are written with blank metadata (no creation date, no software
version) so the same inputs give byte-identical files.
"""

import textwrap
import matplotlib
import matplotlib.colors
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
import numpy as np  # noqa: E402

from .io import atomic_path  # noqa: E402

__all__ = ["bode_matrix", "bode_siso", "bode_measured", "stabilization_diagram", "mode_shapes",
           "calibration_convergence", "youngs_modulus", "update_convergence", "bode_compare", "error_map",
           "residual_fingerprint", "ledger", "save_figure"]


def save_figure(figure, path, dpi=120):
    """Save a figure atomically with reproducible (blank) metadata and close it."""
    with atomic_path(path) as temporary:
        figure.savefig(temporary, dpi=dpi, format="png", metadata={"Software": None})
    plt.close(figure)


def _bode_axes(magnitude_axis, phase_axis, frequency_hz, values, label=None, **style):
    magnitude_axis.semilogy(frequency_hz, np.abs(values), label=label, **style)
    phase_axis.plot(frequency_hz, np.degrees(np.angle(values)), **style)


def bode_matrix(frequency_hz, response, outputs, inputs, title, unit="m/A"):
    """Bode plots of every channel of a MIMO FRF, one column per input.

    Parameters
    ----------
    frequency_hz : array (n_f,)
    response : complex array (n_f, n_out, n_in)
    outputs, inputs : sequences of axis names
    """
    n_out, n_in = response.shape[1:]
    figure, axes = plt.subplots(2, n_in, figsize=(3.2 * n_in + 1, 6), sharex=True, squeeze=False)
    for j, input_name in enumerate(inputs):
        for i, output_name in enumerate(outputs):
            style = dict(lw=1.6 if i == j else 0.8, ls="-" if i == j else "--")
            _bode_axes(axes[0, j], axes[1, j], frequency_hz, response[:, i, j], label=f"{output_name}", **style)
        axes[0, j].set_title(f"input {input_name}")
        axes[1, j].set_xlabel("frequency [Hz]")
        axes[0, j].grid(True, which="both", alpha=0.3)
        axes[1, j].grid(True, alpha=0.3)
        axes[1, j].set_ylim(-190, 190)
        axes[1, j].set_yticks([-180, -90, 0, 90, 180])
    axes[0, 0].set_ylabel(f"|P| [{unit}]")
    axes[1, 0].set_ylabel("phase [deg]")
    axes[0, -1].legend(title="output", fontsize=8)
    figure.suptitle(title)
    figure.tight_layout()
    return figure


def bode_siso(frequency_hz, values, title, unit="m/A", markers=False):
    """Bode plot of one channel; ``markers`` marks every measurement point (thesis Fig. 6.3)."""
    figure, (magnitude_axis, phase_axis) = plt.subplots(2, 1, figsize=(6, 5), sharex=True)
    style = dict(marker=".", ms=3) if markers else {}
    _bode_axes(magnitude_axis, phase_axis, frequency_hz, values, **style)
    magnitude_axis.set_ylabel(f"|G| [{unit}]")
    phase_axis.set_ylabel("phase [deg]")
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
    figure, axes = plt.subplots(2, len(channels), figsize=(3.4 * len(channels) + 0.6, 5.4), sharex="col", squeeze=False)
    for k, (label, frequency, values, std) in enumerate(channels):
        magnitude = np.abs(values)
        axes[0, k].fill_between(frequency, np.maximum(magnitude - 2 * std, magnitude * 1e-3), magnitude + 2 * std,
                                alpha=0.25, lw=0, color="C0")
        axes[0, k].semilogy(frequency, magnitude, label="measured", **measured_style)
        axes[1, k].plot(frequency, np.degrees(np.angle(values)), **measured_style)
        for n, (name, model) in enumerate((fits[k] if fits is not None else {}).items(), start=1):
            axes[0, k].semilogy(frequency, np.abs(model), lw=1.0, color=f"C{n}", label=name)
            axes[1, k].plot(frequency, np.degrees(np.angle(model)), lw=1.0, color=f"C{n}")
        axes[0, k].set_title(label)
        axes[1, k].set_xlabel("frequency [Hz]")
        axes[1, k].set_ylim(-190, 190)
        axes[1, k].set_yticks([-180, -90, 0, 90, 180])
        for axis in axes[:, k]:
            axis.grid(True, which="both", alpha=0.3)
    axes[0, 0].set_ylabel(f"|G| [{unit}]")
    axes[1, 0].set_ylabel("phase [deg]")
    if fits is not None:
        axes[0, 0].legend(fontsize=7, loc="lower left")
    figure.suptitle(title)
    figure.tight_layout()
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
    for axis, name in zip(axes[0], axes_names):
        for repetition, group in offsets[offsets["axis"] == name].groupby("repetition"):
            axis.plot(group["iteration"], group["offset_m"] * 1e6, marker="o", ms=3, lw=1, label=f"rep. {repetition}")
        axis.axhspan(-tolerance_m * 1e6, tolerance_m * 1e6, color="green", alpha=0.15)
        axis.set_title(name)
        axis.set_xlabel("iteration")
        axis.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
        axis.grid(True, alpha=0.3)
    axes[0, 0].set_ylabel("offset x_c [um]")
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
    axis.legend(handles=handles, fontsize=7)
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
    output, input_axis = key
    return f"{output} / U2_{input_axis}" if output.startswith("I_") else f"{output} / {input_axis}"


def bode_compare(measured, models, channels, title):
    """Measured channels with their uncertainty band beside one or more models' responses.

    Parameters
    ----------
    measured : dict (output, input) -> (frequency_hz, values, std)
    models : dict label -> {(output, input): values}
    channels : list of (output, input), one row of (magnitude, phase) each
    """
    figure, axes = plt.subplots(len(channels), 2, figsize=(11, 2.1 * len(channels) + 0.8), squeeze=False)
    for row, key in enumerate(channels):
        frequency, values, std = measured[key]
        unit = "A/A" if key[0].startswith("I_") else "m/A"
        magnitude, phase = axes[row]
        magnitude.fill_between(frequency, np.maximum(np.abs(values) - 2 * std, 1e-3 * np.abs(values)), np.abs(values) + 2 * std,
                               color="0.8", label="measured +-2 sigma")
        magnitude.semilogy(frequency, np.abs(values), "k.", ms=2.5, label="measured")
        band_deg = np.degrees(np.minimum(2 * std / np.maximum(np.abs(values), 1e-300), np.pi))
        measured_phase = np.degrees(np.angle(values))
        phase.fill_between(frequency, measured_phase - band_deg, measured_phase + band_deg, color="0.8")
        phase.plot(frequency, measured_phase, "k.", ms=2.5)
        for label, response in models.items():
            if key in response:
                magnitude.semilogy(frequency, np.abs(response[key]), lw=1.2, label=label)
                phase.plot(frequency, np.degrees(np.angle(response[key])), lw=1.2)
        magnitude.set_ylabel(f"|{_channel_label(key)}| [{unit}]", fontsize=8)
        phase.set_ylabel("phase [deg]")
        phase.set_ylim(-190, 190)
        phase.set_yticks([-180, -90, 0, 90, 180])
        for axis in (magnitude, phase):
            axis.grid(True, which="both", alpha=0.3)
    axes[0, 0].legend(fontsize=7, loc="best")
    for axis in axes[-1]:
        axis.set_xlabel("frequency [Hz]")
    figure.suptitle(title)
    figure.tight_layout()
    return figure


def error_map(errors, title):
    """Channel x frequency map of the normalized error |G_model - G_meas| / sigma (log colour scale)."""
    channels = list(dict.fromkeys(zip(errors["output"], errors["input"])))
    figure, axis = plt.subplots(figsize=(10, 0.32 * len(channels) + 1.8))
    norm = matplotlib.colors.LogNorm(vmin=0.1, vmax=max(10.0, float(errors["normalized_error"].max())))
    image = None
    for row, (output, input_axis) in enumerate(channels):
        part = errors[(errors["output"] == output) & (errors["input"] == input_axis)].sort_values("frequency_hz")
        frequency = part["frequency_hz"].to_numpy()
        edges = np.concatenate([[frequency[0]], 0.5 * (frequency[1:] + frequency[:-1]), [frequency[-1]]])
        image = axis.pcolormesh(edges, [row - 0.5, row + 0.5], np.maximum(part["normalized_error"].to_numpy(), 0.1)[None, :],
                                norm=norm, cmap="magma_r", shading="flat")
    axis.set_yticks(range(len(channels)))
    axis.set_yticklabels([_channel_label(c) for c in channels], fontsize=7)
    axis.invert_yaxis()
    axis.set_xlabel("frequency [Hz]")
    figure.colorbar(image, ax=axis, label="|G_model - G_meas| / sigma  (1 = noise floor)")
    axis.set_title(title)
    figure.tight_layout()
    return figure


def residual_fingerprint(measured, model, predicted, channels, title, candidate_label):
    """The residual ``G_meas / G_model`` (points) beside what the best candidate predicts, ``G_candidate / G_model``."""
    figure, axes = plt.subplots(2, len(channels), figsize=(3.0 * len(channels) + 1, 5.4), squeeze=False, sharex="col")
    for column, key in enumerate(channels):
        frequency, values, _ = measured[key]
        ratio = values / model[key]
        axes[0, column].plot(frequency, 20 * np.log10(np.abs(ratio)), "k.", ms=2.5, label="measured / model")
        axes[1, column].plot(frequency, np.degrees(np.angle(ratio)), "k.", ms=2.5)
        if predicted is not None:
            change = predicted[key] / model[key]
            axes[0, column].plot(frequency, 20 * np.log10(np.abs(change)), "C3", lw=1.4, label=f"{candidate_label} / model")
            axes[1, column].plot(frequency, np.degrees(np.angle(change)), "C3", lw=1.4)
        axes[0, column].set_title(_channel_label(key), fontsize=9)
        axes[1, column].set_xlabel("frequency [Hz]")
        for axis in axes[:, column]:
            axis.grid(True, alpha=0.3)
    axes[0, 0].set_ylabel("magnitude ratio [dB]")
    axes[1, 0].set_ylabel("phase difference [deg]")
    axes[0, 0].legend(fontsize=7)
    figure.suptitle(title)
    figure.tight_layout()
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
