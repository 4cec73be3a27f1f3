"""Rule `diagnose`: the effect a model variant lacks, from one identification run -> ranking, explanation, figure."""

from ambid.compare import measured_channels, model_response
from ambid.diagnose import diagnose, diagnosis_report, plant_with_effect
from ambid.io import atomic_path, read_parquet, read_yaml, rule_log, write_tsv
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.plots import residual_fingerprint, save_figure

log = rule_log(snakemake.log[0], "diagnose")

machine_name, run, variant = snakemake.wildcards.machine, snakemake.wildcards.run, snakemake.wildcards.variant
floors, bands = snakemake.params.compare, list(snakemake.params.compare["bands_hz"]) + [float("inf")]
machine = machine_from_config(read_yaml(snakemake.input.machine), name=machine_name, source=snakemake.input.machine)
table, _ = read_parquet(snakemake.input.frf, kind="frf")
measured = measured_channels(table, floors["position_floor"], floors["current_floor"])
settings = snakemake.params.settings
diagnosis = diagnose(machine, measured, max_evaluations=settings["max_evaluations"], sequence_length=settings["sequence_length"])
plant = Plant(machine)
model = model_response(plant, measured)
candidates, text = diagnosis_report(diagnosis, plant, measured, bands, f"{machine_name}, run {run}, model {variant}")
write_tsv(candidates, snakemake.output.candidates)
with atomic_path(snakemake.output.text) as temporary:
    temporary.write_text(text)
log.info("\n%s", text)

top = diagnosis.ranked[0]
predicted = model_response(plant_with_effect(plant, top.effect), measured)
shown = [key for key in (("DX", "DX"), ("NX", "NX"), ("NX", "DX"), ("I_DX", "DX"), ("Z", "Z")) if key in measured]
verdict = "best candidate" if diagnosis.best is not None else "best (not significant) candidate"
save_figure(residual_fingerprint(measured, model, predicted, shown,
                                 f"{machine_name} {run}, model {variant}: residual and the {verdict}", top.candidate.label),
            snakemake.output.fingerprint, snakemake.params.dpi)
