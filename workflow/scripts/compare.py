"""Rule `compare`: one model variant against one identification run -> errors per channel, frequency and band, figures."""

from ambid.compare import (at_input_coupling, channel_errors, for_run, input_coupling, input_coupling_slopes,
                           measured_channels, model_response, summarize)
from ambid.findings import write_findings
from ambid.io import read_parquet, read_yaml, rule_log, write_parquet, write_tsv
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.plots import bode_compare, error_map, save_figure

log = rule_log(snakemake.log[0], "compare")

machine_name, run, variant = snakemake.wildcards.machine, snakemake.wildcards.run, snakemake.wildcards.variant
settings = snakemake.params.settings
machine = machine_from_config(read_yaml(snakemake.input.machine), name=machine_name, source=snakemake.input.machine)
table, info = read_parquet(snakemake.input.frf, kind="frf")
measured = measured_channels(table)
machine, findings = for_run(machine, measured, info["metadata"], "compare")
write_findings(findings, snakemake.output.findings)
for finding in findings:
    log.info(finding.message)
measured = at_input_coupling(measured, input_coupling_slopes(table), input_coupling(machine.effects))
model = model_response(Plant(machine), measured)
errors = channel_errors(measured, model)
bands = settings.get("bands_hz")
summary = summarize(errors, None if bands is None else list(bands) + [float("inf")])
write_parquet(errors, snakemake.output.errors, kind="compare_errors",
              units={"frequency_hz": "Hz", "magnitude_error_db": "dB", "phase_error_deg": "deg", "normalized_error": "-"},
              metadata={"machine": machine_name, "run": run, "variant": variant, **settings})
write_tsv(summary, snakemake.output.summary)
overall = summary[summary["output"] == "all"].iloc[0]
log.info("%s against %s: chi2 per point %.4g (excess %.4g), rms %.3f dB / %.2f deg over %d channels", variant, run,
         overall["chi2"], overall["excess"], overall["rms_magnitude_db"], overall["rms_phase_deg"], len(measured))
shown = [key for key in (("DX", "DX"), ("NX", "NX"), ("NX", "DX"), ("DY", "DY"), ("Z", "Z"), ("I_DX", "DX"), ("I_NX", "NX"))
         if key in measured]
title = f"{machine_name} {run}: model {variant} against the measurement"
save_figure(bode_compare(measured, {f"model {variant}": model}, shown, title), snakemake.output.bode, snakemake.params.dpi)
save_figure(error_map(errors, f"{title}: normalized error"), snakemake.output.error_map, snakemake.params.dpi)
