"""Rule `identification_methods`: a machine's identification runs side by side (stepped sine, multisine)."""

import numpy as np
import pandas as pd

from ambid.frf import channel, radial_estimator
from ambid.io import read_parquet, rule_log, write_tsv
from ambid.machine import RADIAL_AXES
from ambid.plots import method_comparison, save_figure

log = rule_log(snakemake.log[0], "identification_methods")

BANDS_HZ = (0.0, 100.0, 300.0, 1000.0, 3000.0, np.inf)
rows, runs = [], []
for run, frf_path, log_path in zip(snakemake.params.runs, snakemake.input.frf, snakemake.input.logs):
    table, info = read_parquet(frf_path, kind="frf")
    _, log_info = read_parquet(log_path)
    metadata = log_info["metadata"]
    method = "multisine" if log_info["kind"] == "multisine_log" else "stepped sine"
    machine_time_s = metadata.get("machine_time_s", metadata.get("experiment_s", np.nan))
    estimator = radial_estimator(table)
    if "systematic_std" not in table:
        table = table.assign(systematic_std=np.nan)
    diagonal = table[(table["estimator"] == estimator) & (table["output"] == table["input"])
                     & table["output"].isin(RADIAL_AXES)]
    magnitude = np.hypot(diagonal["re"], diagonal["im"])
    noise, systematic = diagonal["std"] / magnitude, diagonal["systematic_std"] / magnitude
    row = {"run": run, "method": method, "machine_time_s": machine_time_s, "estimator": estimator,
           "points_per_channel": int(len(diagonal) / max(diagonal["output"].nunique(), 1)),
           "band_hz": f"{diagonal['frequency_hz'].min():.4g}-{diagonal['frequency_hz'].max():.4g}"}
    for low, high in zip(BANDS_HZ[:-1], BANDS_HZ[1:]):
        pick = ((diagonal["frequency_hz"] >= low) & (diagonal["frequency_hz"] < high)).to_numpy()
        label = f"{low:g}-{high:g} Hz"
        row[f"noise {label}"] = float(np.median(noise[pick])) if pick.any() else np.nan
        row[f"systematic {label}"] = float(np.nanmedian(systematic[pick])) if pick.any() and np.isfinite(systematic[pick]).any() else np.nan
    rows.append(row)
    frequency, values, std = channel(table, estimator, "DX", "DX")
    part = diagonal[diagonal["output"] == "DX"].sort_values("frequency_hz")
    runs.append((f"{run} ({method})", frequency, values, std, part["systematic_std"].to_numpy()))
    log.info("%s: %s, %.1f s of machine time, %d points per channel", run, method, machine_time_s, row["points_per_channel"])
comparison = pd.DataFrame(rows)
write_tsv(comparison, snakemake.output.table)
save_figure(method_comparison(runs, "DX/DX", f"{snakemake.wildcards.machine}: identification methods, channel DX/DX"),
            snakemake.output.figure, snakemake.params.dpi)
