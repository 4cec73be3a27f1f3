"""Rule `calibrate`: magnetic center, thesis tables 6.1-6.3, stiffness change and figure, from the log alone."""

import yaml

from ambid.calibration import analyse_calibration, calibration_settings_from_config, read_calibration_log, stiffness_at_magnetic_center
from ambid.io import atomic_path, rule_log, write_tsv
from ambid.machine import machine_from_config
from ambid.plots import calibration_convergence, save_figure

log = rule_log(snakemake.log[0], "calibrate")

settings = calibration_settings_from_config(snakemake.params.settings)
machine = machine_from_config(snakemake.params.machine_config, name=snakemake.wildcards.machine, source=snakemake.input.machine)
method_axes = machine.radial_electromagnets
frame, _ = read_calibration_log(snakemake.input.log)
analysis = analyse_calibration(frame, method_axes, settings, source=snakemake.input.log)
if analysis["not_converged_axes"]:
    log.warning("axes %s did not converge within %g um", analysis["not_converged_axes"], settings.tolerance_m * 1e6)
result = analysis["result"]
stiffness = stiffness_at_magnetic_center(method_axes, result["magnetic_center_m"], result["control_current_a"])
for row in stiffness.itertuples():
    log.info("%s: magnetic center %+.2f um; at the geometric center ki %+.2f %%, kx %+.2f %%", row.axis,
             row.magnetic_center_m * 1e6, 100 * row.current_stiffness_change, 100 * row.position_stiffness_change)
write_tsv(analysis["offsets"], snakemake.output.offsets)
write_tsv(analysis["pairs"], snakemake.output.pairs)
write_tsv(analysis["repeatability"], snakemake.output.repeatability)
write_tsv(result, snakemake.output.result)
write_tsv(stiffness, snakemake.output.stiffness)
# a config fragment: with the set points at the found center the model linearizes at the magnetic
# center, carrying the measured static control currents
fragment = {"bearings": {"radial": {"operating_point": {
    row.axis: {"position_m": 0.0, "control_current_a": round(float(row.control_current_a), 6)} for row in result.itertuples()}}}}
with atomic_path(snakemake.output.operating_point) as temporary:
    temporary.write_text("# Operating point found by the magnetic center calibration (merge into the machine config)\n"
                         + yaml.safe_dump(fragment, sort_keys=True))
save_figure(calibration_convergence(analysis["offsets"], settings.tolerance_m, f"{machine.name}: magnetic center calibration"),
            snakemake.output.convergence, snakemake.params.dpi)
