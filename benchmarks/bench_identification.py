"""Benchmark of the virtual-rig identification run (issue 3 targets).

Prints the wall time of the default identification run (4 radial axes x 250
steps + Z x 100 steps on hs_eden_like, thesis grids and settings from
config/config.yaml), steps per second, controller cycles simulated per second,
the simulated machine time, and a baseline measured in the same run: a sample
of the same steps simulated one at a time (batch of one), extrapolated to all
steps.  Target: the batched run in <= 60 s wall on 2 cores.

Usage: ``.venv/bin/python benchmarks/bench_identification.py [machine]``.
"""

import sys
import time
from pathlib import Path

import numpy as np
import yaml

from ambid.excitation import StepPlan, run_stepped_sine, settings_from_config
from ambid.kernels import rerun_pinned
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.rig import RigModel, rig_from_config

ROOT = Path(__file__).resolve().parents[1]


def load(machine):
    config = yaml.safe_load(open(ROOT / "config" / "config.yaml"))
    entry = config["machines"][machine]
    machine_config = yaml.safe_load(open(ROOT / entry["model"]))
    rig_config = yaml.safe_load(open(ROOT / entry["rig"]))
    return machine_config, rig_config, settings_from_config(config["identification"])


def main(machine="hs_eden_like"):
    machine_config, rig_config, settings = load(machine)
    started = time.perf_counter()
    rig_model = RigModel(rig_from_config(rig_config, machine_config))
    plan = StepPlan.for_machine(Plant(machine_from_config(machine_config)), settings)
    build_s = time.perf_counter() - started
    started = time.perf_counter()
    records, stats = run_stepped_sine(rig_model, plan, settings, seed=1)
    run_s = time.perf_counter() - started

    # baseline: a spread of the same steps one at a time, extrapolated by their share of member cycles
    sample = np.linspace(0, plan.step.size - 1, 12).astype(int)
    started = time.perf_counter()
    cycles = 0
    for k in sample:
        one = StepPlan(plan.axis[[k]], plan.step[[k]], plan.frequency_hz[[k]], plan.initial_amplitude_a[[k]])
        _, single = run_stepped_sine(rig_model, one, settings, seed=1)
        cycles += single["cycles"]
    single_s = time.perf_counter() - started
    baseline_s = single_s / cycles * stats["member_cycles"]

    steps = plan.step.size
    rows = [
        ("machine", machine, ""),
        ("steps (axes x grid)", f"{steps}", ""),
        ("rig build + plan", f"{build_s:.2f} s", ""),
        ("identification run, wall", f"{run_s:.2f} s", "<= 60 s"),
        ("steps per second", f"{steps / run_s:.1f} /s", ""),
        ("controller cycles (lockstep)", f"{stats['cycles']}", ""),
        ("controller cycles per second (lockstep)", f"{stats['cycles'] / run_s:.0f} /s", ""),
        ("step-cycles simulated per second (all steps)", f"{stats['member_cycles'] / run_s:.3g} /s", ""),
        ("simulated time (lockstep)", f"{stats['simulated_s']:.2f} s", ""),
        ("machine time of the experiment (steps in sequence)", f"{stats['experiment_s']:.1f} s", ""),
        ("baseline: one step at a time (extrapolated)", f"{baseline_s:.1f} s", ""),
        ("speed-up of the batch over the baseline", f"{baseline_s / run_s:.1f} x", ""),
        ("steps outside the response band (at A_min / A_max)", f"{sum(not r['in_band'] for r in records)}", ""),
    ]
    width = max(len(r[0]) for r in rows)
    print("ambid identification benchmark (virtual rig, batched stepped sine)")
    for name, value, target in rows:
        print(f"{name:<{width}}  {value:>14}  {target}")
    print("result:", "PASS" if run_s <= 60 else "FAIL", "(target: <= 60 s wall)")


if __name__ == "__main__":
    rerun_pinned()  # the same figures on every x86-64 CPU (ambid.kernels)
    main(*sys.argv[1:])
