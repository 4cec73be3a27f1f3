"""Rule `import_thesis_m`: a thesis-style .m identification log -> the validated Parquet log."""

import logging
import sys

from ambid.logs import write_identification_log
from ambid.mfile import read_thesis_m

sys.stderr = open(snakemake.log[0], "w")
logging.basicConfig(stream=sys.stderr, level=logging.INFO, format="%(asctime)s %(message)s")

frame = read_thesis_m(snakemake.input.mfile)
logging.info("%s: %d steps on axes %s (the .m format carries no noise estimate: noise_std = 0)",
             snakemake.input.mfile, frame.groupby(["excited_axis", "step"]).ngroups, sorted(set(frame["excited_axis"])))
write_identification_log(frame, snakemake.output.log, {"machine": snakemake.wildcards.machine, "run": snakemake.wildcards.run,
                                                       "source": "thesis .m file", "original": snakemake.input.mfile})
