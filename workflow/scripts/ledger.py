"""Rule `ledger`: the misfit of every model variant against every identification run of a machine, table and plot."""

import pandas as pd

from ambid.io import read_tsv, rule_log, write_parquet, write_tsv
from ambid.plots import excess_maps, ledger, save_figure

log = rule_log(snakemake.log[0], "ledger")

machine = snakemake.wildcards.machine
parts, maps = [], {}
for path, verdict_path, run, variant in zip(snakemake.input.summaries, snakemake.input.verdicts, snakemake.params.runs,
                                            snakemake.params.variants):
    summary = read_tsv(path)
    maps[f"{variant} against {run}"] = summary
    summary = summary[summary["band"] == "all"].drop(columns="band")
    verdict = {key: "" if pd.isna(value) else value for key, value in read_tsv(verdict_path).iloc[0].items()}  # empty: NaN
    text = {"missing": f"missing: {verdict['effects']}", "retune": f"retune: {verdict['retune']}",
            "unexplained": f"unexplained misfit: {verdict['unexplained']}", "nothing": "nothing missing"}[verdict["verdict"]]
    if verdict["verdict"] == "missing" and verdict["unexplained"]:
        text += f"; unexplained misfit remains: {verdict['unexplained']}"
    if verdict.get("lead"):
        text += f" (lead within the floor: {verdict['lead']})"
    parts.append(summary.assign(machine=machine, run=run, variant=variant, diagnosis=text))
table = pd.concat(parts, ignore_index=True)[["machine", "run", "variant", "output", "input", "points", "chi2", "excess",
                                             "rms_magnitude_db", "rms_phase_deg", "diagnosis"]]
write_parquet(table, snakemake.output.ledger, kind="ledger",
              units={"chi2": "-", "excess": "-", "rms_magnitude_db": "dB", "rms_phase_deg": "deg", "points": "-"},
              metadata={"machine": machine})
write_tsv(table, snakemake.output.table)
for row in table[table["output"] == "all"].itertuples():
    log.info("%s %-12s chi2 per point %10.4g  excess %10.4g  rms %.3f dB %.2f deg", row.run, row.variant, row.chi2, row.excess,
             row.rms_magnitude_db, row.rms_phase_deg)
save_figure(ledger(table, f"{machine}: misfit of each model variant"), snakemake.output.figure, snakemake.params.dpi)
save_figure(excess_maps(maps, f"{machine}: chi2 per point by channel and band, every variant (one colour scale)"),
            snakemake.output.maps, snakemake.params.dpi)
