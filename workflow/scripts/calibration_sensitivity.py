"""Rule `calibration_sensitivity`: the calibration with wrong method parameters, scored against the rig's truth."""

from ambid.calibration import calibration_settings_from_config, sensitivity_study
from ambid.io import rule_log, write_tsv
from ambid.machine import machine_from_config
from ambid.rig import RigModel, rig_from_config

log = rule_log(snakemake.log[0], "calibration_sensitivity")

settings = calibration_settings_from_config(snakemake.params.settings)
machine = machine_from_config(snakemake.params.machine_config, name=snakemake.wildcards.machine, source=snakemake.input.machine)
method_axes = machine.radial_electromagnets
rig_model = RigModel(rig_from_config(snakemake.params.rig_config, snakemake.params.as_built_config, source=snakemake.input.rig))
table = sensitivity_study(rig_model, method_axes, settings, rig_model.magnetic_center_sensor_m(), seed=snakemake.params.seed)
log.info("\n%s", table.to_string())
write_tsv(table, snakemake.output.table)
