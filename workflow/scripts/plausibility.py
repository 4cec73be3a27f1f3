"""Rule `plausibility`: an identification run against the nominal model (units, signs, band) -> plausibility.tsv or
one error.  A stepped-sine log is read step by step; a multisine run through its BLA and a user's UFF58 FRFs as they
are (`ambid.plausibility.frf_arrays`)."""

from ambid.bla import multisine_frf, multisine_passes
from ambid.frf import log_arrays
from ambid.io import rule_log, write_tsv
from ambid.logs import log_source, noise_from_scatter, read_identification_log, read_multisine_log
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.plausibility import check_units, frf_arrays
from ambid.readers import read_uff_frf

log = rule_log(snakemake.log[0], "plausibility")

if hasattr(snakemake.input, "uff"):  # run format uff: FRFs without a raw log, in the units its labels (or the run) say
    source = snakemake.input.uff
    table, _ = read_uff_frf(source, **snakemake.params.uff_options)
    arrays = frf_arrays(table)
elif snakemake.params.method == "multisine":  # the BLA's compliance and coil-current FRF (their floors are rule bla's)
    frame, info = read_multisine_log(snakemake.input.log)
    source = snakemake.input.log
    table, _ = multisine_frf(multisine_passes(frame), info["metadata"].get("design", "orthogonal"))
    arrays = frf_arrays(table)
else:
    frame, info = read_identification_log(snakemake.input.log)
    if (frame["noise_std"] == 0).all():  # no noise estimate (thesis .m): a channel that never scatters is dead, first
        noise_from_scatter(frame, log_source(snakemake.input.log, info))
    source = info["metadata"].get("original") or snakemake.input.log
    arrays = log_arrays(frame)
nominal = Plant(machine_from_config(snakemake.params.machine_config, name=snakemake.wildcards.machine,
                                    source=snakemake.input.machine))
rows = check_units(arrays, nominal, source, snakemake.input.machine)
for row in rows:
    log.info("%s of %s: %.3g times the nominal model's", row["check"], row["axes"], row["ratio"])
write_tsv(rows, snakemake.output.table)
