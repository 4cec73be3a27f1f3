"""Rule `export`: a run's FRF table and fitted models -> CSV and MATLAB .mat files (ambid.export)."""

from ambid.export import frf_csv, frf_mat, models_csv, models_mat
from ambid.io import read_parquet, rule_log

log = rule_log(snakemake.log[0], "export")

table, _ = read_parquet(snakemake.input.frf, kind="frf")
models, _ = read_parquet(snakemake.input.models, kind="fit_models")
frf_csv(table, snakemake.output.frf_csv)
frf_mat(table, snakemake.output.frf_mat)
models_csv(models, snakemake.output.models_csv)
models_mat(models, snakemake.output.models_mat)
log.info("exported %d FRF rows and %d fitted channels", len(table), len(models))
