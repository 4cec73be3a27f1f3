# ambid: AMB identification and rotor model updating.  Thin entry point: configuration,
# validation, the stage rule files and the default target.
from snakemake.utils import min_version

min_version("9.0")


configfile: "config/config.yaml"


include: "rules/common.smk"
include: "rules/model.smk"
include: "rules/acquire.smk"
include: "rules/calibrate.smk"
include: "rules/frf.smk"
include: "rules/fit.smk"
include: "rules/export.smk"
include: "rules/update.smk"
include: "rules/diagnose.smk"
include: "rules/commissioning.smk"
include: "rules/report.smk"


rule all:
    default_target: True
    input:
        all_outputs(),
    message:
        "every machine's report"
