"""Rule `bla`: the best linear approximation of a multisine run -> FRF Parquet (with its floors), distortion, plots."""

import numpy as np

from ambid.bla import distortion_levels, excitation_covariance, line_levels, multisine_frf, multisine_passes
from ambid.floor import FloorSettings
from ambid.frf import FRF_UNITS, channel, radial_estimator
from ambid.io import rule_log, write_parquet, write_tsv
from ambid.logs import read_multisine_log
from ambid.machine import ALL_AXES, RADIAL_AXES
from ambid.plausibility import FRF_SETTINGS
from ambid.plots import bla_distortion, bode_measured, save_figure
from ambid.uff import frf_channels, write_uff58

log = rule_log(snakemake.log[0], "bla")

machine, run = snakemake.wildcards.machine, snakemake.wildcards.run
frame, info = read_multisine_log(snakemake.input.log)
passes = multisine_passes(frame)
design = info["metadata"].get("design", "orthogonal")
floor_settings = FloorSettings.from_config({k: v for k, v in snakemake.params.settings.items() if k not in FRF_SETTINGS})
table, estimates = multisine_frf(passes, design, floor_settings.noise_half_width)
for p in passes:
    result = estimates["by_pass"][p["name"]]
    group = result["radial"]
    if group is not None:
        log.info("%s pass: %d radial lines %.4g-%.4g Hz, %d realization(s) at level(s) %s, U condition median %.2f",
                 p["name"], group.frequency_hz.size, group.frequency_hz.min(), group.frequency_hz.max(),
                 p["spectra"].shape[0], group.levels.tolist(), np.median(group.condition))
coarse = passes[0]
coil_currents = bool(np.isfinite(coarse["spectra"]).all())  # (optional for a whole log)
if not coil_currents:
    log.warning("the log has no coil currents: no coil-current FRF, and the excitation level from the control "
                "currents U2 in their place")
# what the force law is averaged over in this run: the model compared with it is linearized there
excitation = excitation_covariance(coarse["spectra"], coarse["reference"])
log.info("coarse pass, top level, rms %s / position / correlation: %s", "coil current" if coil_currents else "U2",
         "; ".join(f"{a} {np.sqrt(i):.3f} A, {1e6 * np.sqrt(x):.2f} um, {c / np.sqrt(max(i * x, 1e-300)):+.2f}"
                   for a, (i, x, c) in excitation.items()))
write_parquet(table, snakemake.output.frf, units=FRF_UNITS, kind="frf",
              metadata={"machine": machine, "run": run, "source_log": snakemake.input.log,
                        "method": "multisine", "estimators": sorted(set(table["estimator"])),
                        "std": "noise of the BLA (scatter between periods)",
                        "systematic_std": "nonlinear distortion of the BLA (scatter between realizations "
                                          "and the change between excitation levels)",
                        "excitation_covariance": excitation,
                        "excitation_current": "coil" if coil_currents else "U2",
                        "noise_pooled_lines": 2 * floor_settings.noise_half_width + 1})
excited_axes = [a for k, a in enumerate(ALL_AXES) if coarse["excites"][:, k].any()]
levels = distortion_levels(coarse["spectra"], coarse["role"], coarse["frequency_hz"], coarse["excites"], axes=excited_axes)
write_tsv(levels, snakemake.output.distortion)
for _, row in levels.iterrows():
    log.info("%s %s: odd distortion %s, even %s, noise %.1f dB relative to the excited lines", row["output"], row["band"],
             *(f"{row[k]:.1f} dB" if np.isfinite(row[k]) else "below the noise" for k in ("odd_db", "even_db")),
             row["noise_db"])
estimator = radial_estimator(table)
write_uff58(snakemake.output.uff, frf_channels(table), description=f"ambid {machine} {run} multisine BLA ({estimator})")
title = f"{machine} {run} (multisine BLA)"
dpi = snakemake.params.dpi
radial = [a for a in RADIAL_AXES if channel(table, estimator, a, a)[0].size]
save_figure(bode_measured([(f"{a} ({estimator.upper()})", *channel(table, estimator, a, a)) for a in radial],
                          f"{title}: radial axes, {estimator.upper()}"), snakemake.output.radial_mimo, dpi)
axial = channel(table, "siso", "Z", "Z")
save_figure(bode_measured([("Z (SISO)", *axial)] if axial[0].size else [], f"{title}: axial"), snakemake.output.axial, dpi)


def with_systematic(output, input_axis):
    rows = table[(table["estimator"] == estimator) & (table["output"] == output) & (table["input"] == input_axis)]
    rows = rows.sort_values("frequency_hz")
    return (f"{output}/{input_axis}", rows["frequency_hz"].to_numpy(), rows["re"].to_numpy() + 1j * rows["im"].to_numpy(),
            rows["std"].to_numpy(), rows["systematic_std"].to_numpy())


spectra = []
for axis in radial:
    level, noise = line_levels(coarse["spectra"], axis)
    own = np.where((coarse["role"] == "excited") & ~coarse["excites"][:, ALL_AXES.index(axis)], "other", coarse["role"])
    spectra.append((f"V2_{axis} (coarse pass)", coarse["frequency_hz"], level, own, noise))
save_figure(bla_distortion([with_systematic(a, a) for a in radial], spectra, f"{title}: noise and nonlinear distortion"),
            snakemake.output.distortion_figure, dpi)
log.info("FRF written: %d rows", len(table))
