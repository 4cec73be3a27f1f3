"""Rule `frf`: one identification run, its model-free checks -> SISO and MIMO ETFE, findings, Bode plots."""

import numpy as np

from ambid.errors import LogError
from ambid.findings import write_findings
from ambid.frf import channel, current_etfe, frf_table, log_arrays, mimo_etfe, siso_etfe
from ambid.io import rule_log, write_parquet
from ambid.logs import noise_from_scatter, read_identification_log
from ambid.machine import RADIAL_AXES
from ambid.plausibility import check_log
from ambid.plots import bode_measured, save_figure
from ambid.uff import write_uff58

log = rule_log(snakemake.log[0], "frf")

frame, info = read_identification_log(snakemake.input.log)
metadata = info["metadata"]
source = snakemake.params.source
if source.get("file", "").endswith(".m") and metadata.get("original_sha256") != source["digest"]:
    # a converted log left from another .m (Snakemake lost track of it): never let it stand for this one
    raise LogError(snakemake.input.log, f"is not the conversion of {source['file']} as it is now (content digest "
                                        f"{source['digest']}; converted from {metadata.get('original', 'unknown')}, digest "
                                        f"{metadata.get('original_sha256', 'unknown')}): delete it and Snakemake converts "
                                        "the .m again")
if (frame["noise_std"] == 0).all():  # no noise estimate in the log (thesis .m format)
    frame = noise_from_scatter(frame, snakemake.input.log)
    log.info("the log carries no noise estimate: each channel's noise from its scatter between steps, %s",
             ", ".join(f"{name} {value:.3g}" for name, value in frame.groupby("channel")["noise_std"].first().items()))
settings = snakemake.params.settings
frame, findings = check_log(frame, log_arrays(frame), settings, snakemake.input.log, metadata.get("source_lines"),
                            metadata.get("original"))
for finding in findings:
    log.warning("%s", finding.message)
arrays = log_arrays(frame)
siso = siso_etfe(arrays)
mimo = mimo_etfe(arrays, source=snakemake.input.log) if settings["estimator"] == "mimo" else None
table = frf_table(siso, mimo, current=current_etfe(arrays))
if mimo is not None:
    condition = mimo[3]
    log.info("MIMO: condition number of U from %.2f to %.2f (median %.2f)", condition.min(), condition.max(), np.median(condition))
write_parquet(table, snakemake.output.frf, units={"frequency_hz": "Hz", "re": "m/A (A/A: current)", "im": "m/A (A/A: current)",
                                                        "std": "m/A (A/A: current)", "condition": "-"},
              kind="frf", metadata={"machine": snakemake.wildcards.machine, "run": snakemake.wildcards.run,
                                    "source_log": snakemake.input.log, "estimators": sorted(set(table["estimator"]))})
uff_channels = [(a, a, *channel(table, "siso", a, a)[:2]) for a in ("Z",) if a in arrays]
estimator_for_uff = "mimo" if mimo is not None else "siso"
uff_channels += [(o, i, *channel(table, estimator_for_uff, o, i)[:2]) for o in RADIAL_AXES for i in RADIAL_AXES
                 if (estimator_for_uff == "mimo" or o == i) and i in arrays]
write_uff58(snakemake.output.uff, uff_channels, description=f"ambid {snakemake.wildcards.machine} {snakemake.wildcards.run} {estimator_for_uff}")
title = f"{snakemake.wildcards.machine} {snakemake.wildcards.run}"
dpi = snakemake.params.dpi
radial = [a for a in RADIAL_AXES if a in arrays]
save_figure(bode_measured([(f"{a} (SISO)", *channel(table, "siso", a, a)) for a in radial], f"{title}: radial axes, SISO"),
            snakemake.output.radial_siso, dpi)
estimator = "mimo" if mimo is not None else "siso"
save_figure(bode_measured([(f"{a} ({estimator.upper()})", *channel(table, estimator, a, a)) for a in radial], f"{title}: radial axes, {estimator.upper()}"),
            snakemake.output.radial_mimo, dpi)
save_figure(bode_measured([("Z (SISO)", *channel(table, "siso", "Z", "Z"))] if "Z" in arrays else [], f"{title}: axial"),
            snakemake.output.axial, dpi)
write_findings(findings, snakemake.output.findings)
log.info("FRF written: %d rows, %d finding(s)", len(table), len(findings))
