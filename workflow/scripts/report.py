"""Rule `report`: the machine's results -> one self-contained HTML page (ambid.report)."""

from pathlib import Path

from ambid.io import atomic_path, rule_log
from ambid.report import machine_report, render_report

log = rule_log(snakemake.log[0], "report")

machine = snakemake.wildcards.machine
introduction, sections = machine_report(
    machine, Path(snakemake.output.report).parent, snakemake.params.calibration_runs, snakemake.params.identification_runs,
    snakemake.params.variants, snakemake.params.updated, snakemake.params.captions, snakemake.params.multisine_runs,
    snakemake.params.commissioning_runs)
with atomic_path(snakemake.output.report) as temporary:
    temporary.write_text(render_report(f"ambid report: {machine}", sections, introduction), encoding="utf-8")
log.info("%s: %d sections", snakemake.output.report, len(sections))
