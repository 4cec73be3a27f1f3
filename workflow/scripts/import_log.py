"""Rule `import_log`: a user's log (thesis .m, plain CSV / Parquet table, MATLAB .mat) -> the validated canonical log."""

from ambid.io import rule_log
from ambid.logs import write_identification_log
from ambid.readers import read_log

log = rule_log(snakemake.log[0], "import_log")

frame, provenance = read_log(snakemake.input.raw, snakemake.params.format, **snakemake.params.units)
log.info("%s (%s, %s): %d steps on axes %s", snakemake.input.raw, provenance["format"], provenance["layout"],
         frame.groupby(["excited_axis", "step"]).ngroups, sorted(set(frame["excited_axis"])))
for note in provenance["notes"]:
    log.info("%s: %s", snakemake.input.raw, note)
metadata = {"machine": snakemake.wildcards.machine, "run": snakemake.wildcards.run, "provenance": provenance,
            "original": snakemake.input.raw,
            # the user's file as converted: the FRF stage refuses a converted log that stands for another version of it
            "original_sha256": snakemake.params.source["digest"]}
if "source_lines" in frame.attrs:  # a .m file: the line of each step, for messages that name it
    metadata["source_lines"] = frame.attrs["source_lines"]
write_identification_log(frame, snakemake.output.log, metadata)
