"""Accuracy study: the stepped sine's two-level repeats extrapolated to zero amplitude (issues 15 and 19).

Every second step of a stepped-sine run is measured again at half its amplitude (``identification.repeat_ratio``,
log ``level`` 1).  Today `ambid.floor` turns the pairs into a *systematic floor* that chi2 counts as independent
errors.  If the force law's error grows as the square of the amplitude, ``G(A) = G0 + k A^2``, the pair also gives
the FRF at zero amplitude (Richardson extrapolation), ``G0 = (4 G(A/2) - G(A)) / 3``, with the noise
``sqrt(16 s(A/2)^2 + s(A)^2) / 3`` and no systematic floor at all.

This script takes one hidden-effect case of the test suite (demo20 with its drawn foundation mode, seed 7, the
80 + 20-step grids from 5 Hz of ``tests/test_diagnose.py``; the case whose mass the diagnosis misses by 6.7 %, 4.7
sigma, at the floor), identifies it on the rig and compares, on the repeated steps only:

1. the measured FRF with its floor (what the diagnosis uses today),
2. the measured FRF with its noise alone,
3. the extrapolated FRF with its propagated noise alone,

each by chi2 per point of the hidden truth, the foundation candidate's own fit (``diagnose.max_evaluations`` 60 and
240) and a joint refit started from the truth.  The model side never reads the rig: the truth is used only to score.

Usage: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_extrapolation.py`` (about 25 s).
"""

from pathlib import Path

import numpy as np
import yaml

from ambid.compare import measured_channels, model_response
from ambid.diagnose import DiagnoseSettings, candidate_space, diagnose, joint_refit, misfit, plant_with_effects
from ambid.effects import effect_from_config
from ambid.excitation import StepPlan, run_stepped_sine, settings_from_config
from ambid.experiment import hidden_effect_draws, hidden_effect_rig
from ambid.frf import frf_from_log
from ambid.logs import identification_frame
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.rig import RigModel

ROOT = Path(__file__).resolve().parents[1]
SEED = 7


def machine_config():
    """demo20 on the test suite's grids: 80 radial and 20 axial steps from 5 Hz."""
    config = yaml.safe_load((ROOT / "config/machines/demo20.yaml").read_text())
    config["frequency_grid"]["radial"].update(points=80, start_hz=5.0)
    config["frequency_grid"]["axial"].update(points=20, start_hz=5.0)
    return config


def main():
    settings = settings_from_config(yaml.safe_load((ROOT / "config/config.yaml").read_text())["identification"])
    config = machine_config()
    draws = hidden_effect_draws(config, seed=SEED)
    entry = {"name": "foundation_mode", "parameters": draws["foundation_mode"]}
    truth = effect_from_config(entry, "truth")
    machine = machine_from_config(config)
    plant = Plant(machine)
    records, _ = run_stepped_sine(RigModel(hidden_effect_rig(config, [entry])), StepPlan.for_machine(plant, settings),
                                  settings, seed=SEED)
    repeated = {(r["excited_axis"], r["step"]) for r in records if r.get("level", 0) == 1}
    high = [r for r in records if r.get("level", 0) == 0 and (r["excited_axis"], r["step"]) in repeated]
    low = [dict(r, level=0) for r in records if r.get("level", 0) == 1]
    high_table, _, _ = frf_from_log(identification_frame(high))
    low_table, _, _ = frf_from_log(identification_frame(low))
    with_floor = measured_channels(high_table)
    # the noise alone: the same channels with the systematic floor set to zero
    noise_high = measured_channels(high_table.assign(systematic_std=0.0))
    noise_low = measured_channels(low_table.assign(systematic_std=0.0))
    extrapolated = {key: (frequency, (4 * noise_low[key][1] - values) / 3, np.hypot(4 * noise_low[key][2], std) / 3)
                    for key, (frequency, values, std) in noise_high.items()}
    print(f"demo20, hidden foundation mode (seed {SEED}): " + ", ".join(f"{k} {v:.6g}" for k, v in entry["parameters"].items()))
    print(f"{len(repeated)} repeated steps, repeat ratio {settings.repeat_ratio}\n")
    candidate = [c for c in candidate_space(machine) if c.label == "foundation_mode"]
    for name, measured in (("measured, with the floor", with_floor), ("measured, noise only", noise_high),
                           ("extrapolated to zero amplitude, noise only", extrapolated)):
        points = sum(values.size for _, values, _ in measured.values())
        truth_chi2 = misfit(measured, model_response(plant_with_effects(plant, [truth]), measured))[0]
        print(f"{name} ({points} points): chi2/pt of the hidden truth {truth_chi2 / points:.3f}")
        for budget in (60, 240):
            fitted = diagnose(machine, measured, candidates=candidate,
                              settings=DiagnoseSettings(max_evaluations=budget)).ranked[0]
            values = ", ".join(f"{p.name} {v:.6g} +- {s:.2g}" for p, v, s in zip(fitted.candidate.free, fitted.values,
                                                                                  fitted.std))
            print(f"  own fit, budget {budget:3d}: {values}; chi2/pt {fitted.chi2 / points:.3f} "
                  f"({fitted.evaluations} evaluations)")
        joint = joint_refit(machine.with_effects((truth,)), measured)
        values = ", ".join(f"{row.parameter.split('.')[1]} {row.value:.6g} +- {row.std:.2g}"
                           for row in joint.table.itertuples())
        print(f"  joint refit from the truth: {values}; chi2/pt {joint.chi2 / points:.3f}\n")


if __name__ == "__main__":
    main()
