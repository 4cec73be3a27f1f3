"""Rule `import_thesis_m`: a thesis-style .m identification log -> the validated Parquet log."""

from ambid.io import rule_log
from ambid.logs import write_identification_log
from ambid.mfile import read_thesis_m

log = rule_log(snakemake.log[0], "import_thesis_m")

frame = read_thesis_m(snakemake.input.mfile)
log.info("%s: %d steps on axes %s (the .m format carries no noise estimate: noise_std = 0)",
         snakemake.input.mfile, frame.groupby(["excited_axis", "step"]).ngroups, sorted(set(frame["excited_axis"])))
write_identification_log(frame, snakemake.output.log, {"machine": snakemake.wildcards.machine, "run": snakemake.wildcards.run,
                                                       "source": "thesis .m file", "original": snakemake.input.mfile,
                                                       "original_sha256": snakemake.params.source["digest"],
                                                       "source_lines": frame.attrs["source_lines"]})
