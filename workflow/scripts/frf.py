"""Rule `frf`: SISO and MIMO ETFE of one identification run -> FRF Parquet and Bode plots."""

import numpy as np

from ambid.findings import Finding, write_findings
from ambid.floor import FloorSettings
from ambid.frf import channel, frf_from_log
from ambid.io import rule_log, write_parquet, write_tsv
from ambid.logs import noise_from_scatter, read_identification_log
from ambid.machine import RADIAL_AXES
from ambid.plots import bode_measured, save_figure
from ambid.uff import write_uff58

log = rule_log(snakemake.log[0], "frf")

frame, info = read_identification_log(snakemake.input.log)
if (frame["noise_std"] == 0).all():  # no noise estimate in the log (thesis .m format)
    frame = noise_from_scatter(frame, snakemake.input.log)
    log.info("the log carries no noise estimate: each channel's noise from its scatter between steps, %s",
             ", ".join(f"{name} {value:.3g}" for name, value in frame.groupby("channel")["noise_std"].first().items()))
table, floors, mimo = frf_from_log(frame, FloorSettings.from_config(snakemake.params.floor), source=snakemake.input.log)
excited = set(frame["excited_axis"])
write_tsv(floors, snakemake.output.floor)
findings = []
for row in floors.itertuples():
    log.info("floor %s %s: %s, systematic %.3g %% median (p90 %.3g %%), noise scaled by %.3g", row.family, row.band, row.method,
             100 * row.relative_median, 100 * row.relative_p90, row.noise_scale)
    if "fallback" in row.method or "smooth_fit" in row.method:
        findings.append(Finding("frf", "note", "floor_fallback", f"{row.family} {row.band}",
                                f"no repeated steps here: the systematic floor is the {'smooth-fit excess' if 'smooth_fit' in row.method else 'documented constant'} "
                                f"({100 * row.relative_median:.3g} % of |G|)", row.relative_median))
    if row.noise_scale < 1:
        findings.append(Finding("frf", "note", "noise_rescaled", f"{row.family} {row.band}",
                                f"the scatter between neighbouring steps is {row.noise_scale:.2g} times the logged noise "
                                "(noise of U2 and the outputs correlated through the loop): the noise uses the scatter",
                                row.noise_scale))
write_findings(findings, snakemake.output.findings)
if mimo is not None:
    condition = mimo[3]
    log.info("MIMO: condition number of U from %.2f to %.2f (median %.2f)", condition.min(), condition.max(), np.median(condition))
write_parquet(table, snakemake.output.frf, units={"frequency_hz": "Hz", "re": "m/A (A/A: current)", "im": "m/A (A/A: current)",
                                                        "std": "m/A (A/A: current)", "condition": "-",
                                                        "systematic_std": "m/A (A/A: current)"},
              kind="frf", metadata={"machine": snakemake.wildcards.machine, "run": snakemake.wildcards.run,
                                    "source_log": snakemake.input.log, "estimators": sorted(set(table["estimator"]))})
uff_channels = [(a, a, *channel(table, "siso", a, a)[:2]) for a in ("Z",) if a in excited]
estimator_for_uff = "mimo" if mimo is not None else "siso"
uff_channels += [(o, i, *channel(table, estimator_for_uff, o, i)[:2]) for o in RADIAL_AXES for i in RADIAL_AXES
                 if (estimator_for_uff == "mimo" or o == i) and i in excited]
write_uff58(snakemake.output.uff, uff_channels, description=f"ambid {snakemake.wildcards.machine} {snakemake.wildcards.run} {estimator_for_uff}")
title = f"{snakemake.wildcards.machine} {snakemake.wildcards.run}"
dpi = snakemake.params.dpi
radial = [a for a in RADIAL_AXES if a in excited]
save_figure(bode_measured([(f"{a} (SISO)", *channel(table, "siso", a, a)) for a in radial], f"{title}: radial axes, SISO"),
            snakemake.output.radial_siso, dpi)
estimator = "mimo" if mimo is not None else "siso"
save_figure(bode_measured([(f"{a} ({estimator.upper()})", *channel(table, estimator, a, a)) for a in radial], f"{title}: radial axes, {estimator.upper()}"),
            snakemake.output.radial_mimo, dpi)
save_figure(bode_measured([("Z (SISO)", *channel(table, "siso", "Z", "Z"))] if "Z" in excited else [], f"{title}: axial"),
            snakemake.output.axial, dpi)
log.info("FRF written: %d rows", len(table))
