"""Rule `acquire_calibration`: run the bias-perturbation calibration on the virtual rig, write its log."""

import numpy as np

from ambid.io import rule_log
from ambid.calibration import calibration_settings_from_config, run_calibration, write_calibration_log
from ambid.machine import machine_from_config
from ambid.rig import RigModel, rig_from_config

log = rule_log(snakemake.log[0], "acquire_calibration")

settings = calibration_settings_from_config(snakemake.params.settings)
as_built = snakemake.params.as_built_config
machine = machine_from_config(as_built, name=snakemake.wildcards.machine, source=snakemake.input.as_built)
method_axes = machine.radial_electromagnets  # what the drawing says
rig_model = RigModel(rig_from_config(snakemake.params.rig_config, as_built, source=snakemake.input.rig))


def progress(iteration, offsets, converged):
    for rep, row in enumerate(offsets):
        if not np.all(np.isnan(row)):
            log.info("iteration %d, repetition %d: offsets %s um%s", iteration, rep + 1,
                     " ".join(f"{x * 1e6:+.2f}" for x in row), " (converged)" if converged[rep] else "")


frame = run_calibration(rig_model, method_axes, settings, seed=snakemake.params.seed, progress=progress)
last = frame.sort_values("iteration").groupby(["repetition", "axis"]).tail(1)
failed = sorted(set(last.loc[np.abs(last["offset_m"]) >= settings.tolerance_m, "axis"]))
if failed:
    log.warning("iteration limit %d reached: axes %s did not converge within %g um", settings.max_iterations, failed, settings.tolerance_m * 1e6)
write_calibration_log(frame, snakemake.output.log, {"machine": snakemake.wildcards.machine, "run": snakemake.wildcards.run,
                                                    "source": "virtual rig", "seed": snakemake.params.seed,
                                                    "settings": snakemake.params.settings})
