"""Rule `plausibility`: an identification log against the nominal model (units, band) -> plausibility.tsv or one error."""

from ambid.frf import log_arrays
from ambid.io import rule_log, write_tsv
from ambid.logs import log_source, noise_from_scatter, read_identification_log
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.plausibility import check_units

log = rule_log(snakemake.log[0], "plausibility")

if hasattr(snakemake.input, "uff"):  # run format uff: FRFs without a raw log; the FRF stage reads their units
    rows = [{"check": "not run", "axes": "", "ratio": float("nan"),
             "note": f"{snakemake.input.uff} holds FRFs, not a raw log: units as its labels (or the run's units) say"}]
    log.info("%s", rows[0]["note"])
else:
    frame, info = read_identification_log(snakemake.input.log)
    if (frame["noise_std"] == 0).all():  # no noise estimate (thesis .m): a channel that never scatters is dead, first
        noise_from_scatter(frame, log_source(snakemake.input.log, info))
    nominal = Plant(machine_from_config(snakemake.params.machine_config, name=snakemake.wildcards.machine,
                                        source=snakemake.input.machine))
    rows = check_units(log_arrays(frame), nominal, info["metadata"].get("original") or snakemake.input.log,
                       snakemake.input.machine)
    for row in rows:
        log.info("%s of %s: %.3g times the nominal model's", row["check"], row["axes"], row["ratio"])
write_tsv(rows, snakemake.output.table)
