"""Rule `acquire_identification`: drive the virtual rig through the stepped-sine run, write the logs."""

import time

import numpy as np

from ambid.calibration import calibrated_setpoint, calibration_settings_from_config
from ambid.excitation import StepPlan, run_stepped_sine, settings_from_config
from ambid.io import rule_log
from ambid.logs import identification_frame, write_identification_log
from ambid.machine import machine_from_config
from ambid.mfile import write_thesis_m
from ambid.plant import Plant
from ambid.rig import RigModel, rig_from_config

log = rule_log(snakemake.log[0], "acquire_identification")

machine_name, run = snakemake.wildcards.machine, snakemake.wildcards.run
settings = settings_from_config(snakemake.params.settings)
as_built = snakemake.params.as_built_config  # planned with the drawing of the machine as built
nominal = Plant(machine_from_config(as_built, name=machine_name, source=snakemake.input.as_built))
rig = rig_from_config(snakemake.params.rig_config, as_built, source=snakemake.input.rig)
started = time.perf_counter()
setpoint_m = None
if "calibration_log" in snakemake.input.keys():  # the center the bench found, with the drawing's bearing parameters
    setpoint_m = calibrated_setpoint(snakemake.input.calibration_log, nominal.machine.radial_electromagnets,
                                     calibration_settings_from_config(snakemake.params.calibration))
    log.info("set points at the calibrated magnetic center [um]: %s", np.array2string(setpoint_m * 1e6, precision=2))
rig_model = RigModel(rig, setpoint_m)
plan = StepPlan.for_machine(nominal, settings)
totals = {axis: int((plan.axis == axis).sum()) for axis in settings.axes}
log.info("rig %s: %d steps (%s), seed %d", rig.name, plan.step.size, totals, snakemake.params.seed)


reported = [0.0]


def progress(accepted, simulated_s):
    """Log the steps accepted per axis at every further 10 % of the run."""
    fraction = sum(accepted.values()) / plan.step.size
    if fraction - reported[0] >= 0.1 or fraction == 1.0:
        reported[0] = fraction
        done = ", ".join(f"{axis} {accepted[axis]}/{totals[axis]}" for axis in settings.axes)
        log.info("steps accepted: %s (simulated %.2f s)", done, simulated_s)


records, stats = run_stepped_sine(rig_model, plan, settings, seed=snakemake.params.seed, progress=progress)
wall_s = time.perf_counter() - started
outside = [r for r in records if not r["in_band"]]
log.info("done in %.1f s wall: %d controller cycles (%.2f s simulated in lockstep; %.1f s of machine time "
         "if run step after step); %d steps ended outside the response band (amplitude limit)",
         wall_s, stats["cycles"], stats["simulated_s"], stats["experiment_s"], len(outside))
frame = identification_frame(records)
metadata = {
    "machine": machine_name,
    "run": run,
    "source": "virtual rig",
    "rig": rig.name,
    "seed": snakemake.params.seed,
    "settings": snakemake.params.settings,
    "simulated_s": stats["simulated_s"],
    "experiment_s": stats["experiment_s"],
    "sample_time_s": rig_model.sample_time_s,
}
write_identification_log(frame, snakemake.output.log, metadata)
write_thesis_m(frame, snakemake.output.mfile, header_lines=[f"ambid identification run {run} of {machine_name} (virtual rig, seed {snakemake.params.seed})"])
