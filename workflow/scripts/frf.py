"""Rule `frf`: SISO and MIMO ETFE of one identification run (or a user's UFF58 FRFs) -> FRF Parquet, UFF58, Bode plots."""

import numpy as np

from ambid.frf import channel, current_etfe, frf_table, log_arrays, mimo_etfe, siso_etfe
from ambid.io import rule_log, write_parquet
from ambid.logs import log_source, noise_from_scatter, read_identification_log
from ambid.machine import RADIAL_AXES
from ambid.plots import bode_measured, save_figure
from ambid.readers import read_uff_frf
from ambid.uff import frf_channels, write_uff58

log = rule_log(snakemake.log[0], "frf")

if hasattr(snakemake.input, "uff"):  # run format uff: the FRFs themselves, no raw log
    source = snakemake.input.uff
    table, provenance = read_uff_frf(source, **snakemake.params.uff_options)
    for note in provenance["notes"]:
        log.info("%s: %s", source, note)
else:
    frame, info = read_identification_log(snakemake.input.log)
    source = log_source(snakemake.input.log, info)  # errors name the user's file
    if (frame["noise_std"] == 0).all():  # no noise estimate in the log (thesis .m format)
        frame = noise_from_scatter(frame, source)
        log.info("the log carries no noise estimate: each channel's noise from its scatter between steps, %s",
                 ", ".join(f"{name} {value:.3g}" for name, value in frame.groupby("channel")["noise_std"].first().items()))
    arrays = log_arrays(frame)
    mimo = mimo_etfe(arrays, source=source) if all(a in arrays for a in RADIAL_AXES) else None
    table = frf_table(siso_etfe(arrays), mimo, current=current_etfe(arrays))
    if mimo is not None:
        condition = mimo[3]
        log.info("MIMO: condition number of U from %.2f to %.2f (median %.2f)", condition.min(), condition.max(), np.median(condition))
estimators = sorted(set(table["estimator"]))
write_parquet(table, snakemake.output.frf, units={"frequency_hz": "Hz", "re": "m/A (A/A: current)", "im": "m/A (A/A: current)",
                                                        "std": "m/A (A/A: current)", "condition": "-"},
              kind="frf", metadata={"machine": snakemake.wildcards.machine, "run": snakemake.wildcards.run,
                                    "source_log": source, "estimators": estimators})
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
log.info("FRF written: %d rows", len(table))
