"""Rule `acquire_multisine`: drive the virtual rig through a multisine identification (coarse pass, fit, zoom), write the log."""

import time

import numpy as np

from ambid.calibration import calibrated_setpoint, calibration_settings_from_config
from ambid.io import rule_log
from ambid.logs import multisine_frame, write_multisine_log
from ambid.machine import machine_from_config
from ambid.multisine import identify_multisine, multisine_settings_from_config
from ambid.plant import Plant
from ambid.rig import RigModel, rig_from_config

log = rule_log(snakemake.log[0], "acquire_multisine")

machine_name, run = snakemake.wildcards.machine, snakemake.wildcards.run
settings = multisine_settings_from_config(snakemake.params.settings)
as_built = snakemake.params.as_built_config  # planned with the drawing of the machine as built
nominal = Plant(machine_from_config(as_built, name=machine_name, source=snakemake.input.as_built))
rig = rig_from_config(snakemake.params.rig_config, as_built, source=snakemake.input.rig)
started = time.perf_counter()
setpoint_m = None
if "calibration_log" in snakemake.input.keys():  # the center the bench found, with the drawing's bearing parameters
    setpoint_m = calibrated_setpoint(snakemake.input.calibration_log, nominal.machine.radial_electromagnets,
                                     calibration_settings_from_config(snakemake.params.calibration))
    log.info("set points at the calibrated magnetic center [um]: %s", np.array2string(setpoint_m * 1e6, precision=2))
fit = snakemake.params.fit
fit_options = {"modes": fit["modes"], "orders": fit["orders"], "lowpass": fit["lowpass"], "delay": fit["delay"]}
passes, plan = identify_multisine(RigModel(rig, setpoint_m), nominal, settings, seed=snakemake.params.seed,
                                  fit_options=fit_options, fit_channels=fit["channels"], log=log)
machine_time_s = sum(p["stats"]["machine_time_s"] for p in passes)
log.info("done in %.1f s wall: %.1f s of machine time (%s)", time.perf_counter() - started, machine_time_s,
         ", ".join(f"{p['name']} {p['stats']['machine_time_s']:.1f} s" for p in passes))
metadata = {
    "machine": machine_name,
    "run": run,
    "source": "virtual rig",
    "method": "multisine",
    "rig": rig.name,
    "seed": snakemake.params.seed,
    "settings": snakemake.params.settings,
    "design": settings.design,
    "sample_time_s": nominal.machine.sample_time_s,
    "machine_time_s": machine_time_s,
    "passes": {p["name"]: {"f0_hz": p["design"].f0_hz, "realizations": p["design"].realizations,
                           "experiments": p["design"].experiments, "periods": p["design"].periods,
                           "settle_s": p["design"].settle_samples * p["design"].sample_time_s,
                           "machine_time_s": p["stats"]["machine_time_s"],
                           "crest_factor": float(np.nanmean(p["design"].crest)),
                           "peak_response_m": p["stats"]["peak_response_m"].tolist(),
                           "peak_excitation_a": p["stats"]["peak_excitation_a"].tolist(),
                           "notes": p["stats"]["notes"]} for p in passes},
    "zoom": {"bands_hz": [list(b) for b in plan["bands_hz"]], "half_power_hz": float(plan["half_power_hz"]),
             "features": plan["features"], "skipped": plan["skipped"], "notes": plan["notes"]},
}
write_multisine_log(multisine_frame(passes), snakemake.output.log, metadata)
