"""Rule `diagnose`: the effects a model variant lacks, from one identification run -> verdict, ranking, joint refit, figure."""

import pandas as pd

from ambid.compare import (at_input_coupling, effective_shares, for_run, input_coupling, input_coupling_slopes,
                           measured_channels, model_response)
from ambid.diagnose import JOINT_COLUMNS, DiagnoseSettings, diagnose, plant_with_effects
from ambid.diagnosis_report import diagnosis_findings, diagnosis_report
from ambid.errors import settings_from_mapping
from ambid.findings import write_findings
from ambid.io import atomic_path, read_parquet, read_yaml, rule_log, write_tsv
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.plots import residual_fingerprint, save_figure
from ambid.variants import UPDATED_EFFECTS

log = rule_log(snakemake.log[0], "diagnose")

machine_name, run, variant = snakemake.wildcards.machine, snakemake.wildcards.run, snakemake.wildcards.variant
bands = snakemake.params.compare.get("bands_hz")
bands = None if bands is None else list(bands) + [float("inf")]
settings = settings_from_mapping(DiagnoseSettings, snakemake.params.settings, "diagnose")
machine = machine_from_config(read_yaml(snakemake.input.machine), name=machine_name, source=snakemake.input.machine)
table, info = read_parquet(snakemake.input.frf, kind="frf")
measured = measured_channels(table)
machine, run_findings = for_run(machine, measured, info["metadata"], "diagnose")
alternatives = ()
if "run_update" in snakemake.input.keys():  # the variant takes another run's update: the refit also starts from this one's
    update = machine_from_config(read_yaml(snakemake.input.run_update), name=machine_name, source=snakemake.input.run_update)
    alternatives = ((f"run {run}'s own update", [e for e in update.effects if e.name in UPDATED_EFFECTS]),)
slopes = input_coupling_slopes(table)
diagnosis = diagnose(machine, measured, settings=settings, alternatives=alternatives, shares=effective_shares(table),
                     coupling_slopes=slopes)
measured = at_input_coupling(measured, slopes, input_coupling(machine.effects))  # as the variant reads them
plant = Plant(machine)
model = model_response(plant, measured)
candidates, text = diagnosis_report(diagnosis, plant, measured, bands, f"{machine_name}, run {run}, model {variant}",
                                    repeated_steps=info["metadata"].get("repeated_steps"))
write_tsv(candidates, snakemake.output.candidates)
write_tsv(diagnosis.joint.table if diagnosis.joint is not None else pd.DataFrame(columns=list(JOINT_COLUMNS)),
          snakemake.output.joint)
cell_keys = ["family", "band", "output", "points", "effective_points", "estimate_dof", "limit"]
write_tsv(diagnosis.cells_before.merge(diagnosis.cells_after, on=cell_keys, suffixes=("_before", "_after")),
          snakemake.output.cells)
write_findings(run_findings + diagnosis_findings(diagnosis), snakemake.output.findings)
write_tsv([diagnosis.summary()], snakemake.output.verdict)
with atomic_path(snakemake.output.text) as temporary:
    temporary.write_text(text)
log.info("verdict %s; %d model evaluations\n%s", diagnosis.verdict, sum(f.evaluations for f in diagnosis.ranked), text)

if diagnosis.joint is not None and diagnosis.sequence:
    label, predicted = "the joint refit", model_response(Plant(diagnosis.joint.machine), measured)
else:
    top = diagnosis.ranked[0]
    label = f"{top.candidate.label} (best, {'missing' if top.missing else 'not missing'})"
    predicted = model_response(plant_with_effects(plant, [top.effect]), measured)
shown = [key for key in (("DX", "DX"), ("NX", "NX"), ("NX", "DX"), ("I_DX", "DX"), ("Z", "Z")) if key in measured]
save_figure(residual_fingerprint(measured, model, predicted, shown,
                                 f"{machine_name} {run}, model {variant}: residual ({diagnosis.verdict})", label),
            snakemake.output.fingerprint, snakemake.params.dpi)
