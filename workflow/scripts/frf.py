"""Rule `frf`: one identification run (or a user's UFF58 FRFs), its model-free checks -> SISO and MIMO ETFE, floor,
findings, UFF58, Bode plots."""

import numpy as np

from ambid.amplitude import AMPLITUDE_ERROR_ALIKE
from ambid.errors import LogError
from ambid.findings import Finding, write_findings
from ambid.floor import FloorSettings, systematic_floor
from ambid.frf import FRF_UNITS, channel, frf_stage
from ambid.io import rule_log, write_parquet, write_tsv
from ambid.logs import log_source, peak_excitation_a, read_identification_log
from ambid.machine import RADIAL_AXES
from ambid.plausibility import FRF_SETTINGS
from ambid.plots import bode_measured, save_figure
from ambid.readers import read_uff_frf
from ambid.uff import frf_channels, write_uff58

log = rule_log(snakemake.log[0], "frf")

settings = {**FRF_SETTINGS, **snakemake.params.settings}
floor_settings = FloorSettings.from_config({k: v for k, v in settings.items() if k not in FRF_SETTINGS})
findings = []
if hasattr(snakemake.input, "uff"):  # run format uff: the FRFs themselves, no raw log
    source = snakemake.input.uff
    table, provenance = read_uff_frf(source, **snakemake.params.uff_options)
    for note in provenance["notes"]:
        log.info("%s: %s", source, note)
    table, floors = systematic_floor(table, {}, settings=floor_settings)
    repeated, peaks = 0, {}  # FRFs carry no repeats, no amplitudes
else:
    frame, info = read_identification_log(snakemake.input.log)
    metadata = info["metadata"]
    user = snakemake.params.source
    if user and user["file"] != snakemake.input.log and metadata.get("original_sha256") != user["digest"]:
        # a converted log left from another version of the user's file (Snakemake lost track of it): never let it
        # stand for this one
        raise LogError(snakemake.input.log, f"is not the conversion of {user['file']} as it is now (content digest "
                                            f"{user['digest']}; converted from {metadata.get('original', 'unknown')}, "
                                            f"digest {metadata.get('original_sha256', 'unknown')}): delete it and "
                                            "Snakemake converts the file again")
    source = log_source(snakemake.input.log, info)  # errors name the user's file
    stage = frf_stage(frame, settings, snakemake.input.log, source, metadata.get("source_lines"), metadata.get("original"))
    if stage.scatter_noise is not None:  # no noise estimate in the log (thesis .m format)
        log.info("the log carries no noise estimate: each channel's noise from its scatter between steps, %s",
                 ", ".join(f"{name} {value:.3g}" for name, value in stage.scatter_noise.items()))
    for finding in stage.findings:
        log.warning("%s", finding.message)
    table, floors, findings, repeated = stage.table, stage.floors, stage.findings, stage.repeated_steps
    peaks = peak_excitation_a(frame)
    if stage.mimo is not None:
        condition = stage.mimo[3]
        log.info("MIMO: condition number of U from %.2f to %.2f (median %.2f)", condition.min(), condition.max(), np.median(condition))
write_tsv(floors, snakemake.output.floor)
for row in floors.itertuples():
    log.info("floor %s %s: %s, systematic %.3g %% median (p90 %.3g %%), noise scaled by %.3g", row.family, row.band, row.method,
             100 * row.relative_median, 100 * row.relative_p90, row.noise_scale)
    if "fallback" in row.method:
        also = (f", or the step-to-step scatter beyond the noise where larger ({row.smooth_fit_points} points)"
                if "smooth_fit" in row.method else "")
        noise = getattr(row, "noise_relative_median", np.nan)
        blind = (f", {row.relative_median / noise:.3g} times the noise there ({100 * noise:.3g} %): a difference "
                 "between model and machine smaller than the floor is not seen; repeat some steps at a lower amplitude "
                 "to measure it" if noise > 0 and row.relative_median > noise else "")
        findings.append(Finding("frf", "note", "floor_fallback", f"{row.family} {row.band}",
                                f"no repeated steps here: the systematic floor is the documented constant "
                                f"(config frf.fallback_floor){also}; median {100 * row.relative_median:.3g} % of |G|"
                                f"{blind}", row.relative_median))
    if getattr(row, "zero_amplitude_points", 0):
        log.info("  %d of %d points extrapolated to zero amplitude from the repeats", row.zero_amplitude_points, row.points)
    if row.noise_scale < 1:
        findings.append(Finding("frf", "note", "noise_rescaled", f"{row.family} {row.band}",
                                f"the scatter between neighbouring steps is {row.noise_scale:.2g} times the logged noise "
                                "(the loop correlates the noise of U2 and of the outputs): the noise uses the scatter",
                                row.noise_scale))
if repeated == 0:
    findings.append(Finding("frf", "note", "no_repeats", "run",
                            "no step was repeated at a lower amplitude (log column level; identification.repeat_ratio on "
                            "the rig), so the FRF is the describing function at each step's excitation amplitude, not the "
                            "plant at zero amplitude: the force law's amplitude-dependent error stays in it, inside the "
                            f"floor, and a diagnosis may read it as the bearings' coefficients ({', '.join(AMPLITUDE_ERROR_ALIKE)}; "
                            "as a lead or as missing). Repeat some steps at a lower amplitude to measure and remove it.",
                            0.0))
write_findings(findings, snakemake.output.findings)
estimators = sorted(set(table["estimator"]))
write_parquet(table, snakemake.output.frf, units=FRF_UNITS, kind="frf",
              metadata={"machine": snakemake.wildcards.machine, "run": snakemake.wildcards.run,
                        "source_log": source, "estimators": estimators, "repeated_steps": repeated,
                        "peak_excitation_a": peaks})
write_uff58(snakemake.output.uff, frf_channels(table), description=f"ambid {snakemake.wildcards.machine} {snakemake.wildcards.run}")
title = f"{snakemake.wildcards.machine} {snakemake.wildcards.run}"
dpi = snakemake.params.dpi
siso = set(table.loc[table["estimator"] == "siso", "output"] + "/" + table.loc[table["estimator"] == "siso", "input"])
radial = [a for a in RADIAL_AXES if f"{a}/{a}" in siso]
estimator = "mimo" if "mimo" in estimators else "siso"
diagonal = [a for a in RADIAL_AXES if ((table["estimator"] == estimator) & (table["output"] == a) & (table["input"] == a)).any()]
save_figure(bode_measured([(f"{a} (SISO)", *channel(table, "siso", a, a)) for a in radial], f"{title}: radial axes, SISO"),
            snakemake.output.radial_siso, dpi)
save_figure(bode_measured([(f"{a} ({estimator.upper()})", *channel(table, estimator, a, a)) for a in diagonal],
                          f"{title}: radial axes, {estimator.upper()}"), snakemake.output.radial_mimo, dpi)
save_figure(bode_measured([("Z (SISO)", *channel(table, "siso", "Z", "Z"))] if "Z/Z" in siso else [], f"{title}: axial"),
            snakemake.output.axial, dpi)
log.info("FRF written: %d rows, %d finding(s)", len(table), len(findings))
