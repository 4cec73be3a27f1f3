"""Benchmark of the diagnosis (issue 7 targets).

1. The default machine: the diagnosis rule's work (`ambid.diagnose.diagnose`
   with the configured settings) on each model variant of hs_eden_like against
   the workflow's run ident01, wall time on the machine's cores (target
   <= 30 s on 2 cores) and with one BLAS thread, evaluations per second, and
   the ranking.  Needs the workflow's results: run ``make run`` first.
2. The hidden-effect suite over several seeds: for every effect of the
   library, a rig of the default machine hides it with parameters drawn from
   physical ranges (`ambid.experiment.hidden_effect_draws`); the nominal model
   is diagnosed from the identified FRF alone.  Printed: whether the hidden
   effect ranks first (or is named indistinguishable from the first), the
   fitted parameters' worst relative error, and the excess over the noise
   floor before and after adding it; plus a negative control per seed.

Usage: ``.venv/bin/python benchmarks/bench_diagnose.py [seeds]`` (default 2 seeds: 20 rigs, about 10 minutes).
"""

import os
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from ambid.compare import measured_channels
from ambid.diagnose import diagnose
from ambid.excitation import settings_from_config
from ambid.experiment import hidden_effect_draws, hidden_effect_rig, identify_on_rig
from ambid.io import read_parquet, read_yaml
from ambid.machine import machine_from_config

ROOT = Path(__file__).resolve().parents[1]
CONFIG = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
FLOORS = CONFIG["compare"]["position_floor"], CONFIG["compare"]["current_floor"]


def default_machine():
    machine = "hs_eden_like"
    frf = ROOT / "results" / machine / "frf" / "ident01" / "frf.parquet"
    if not frf.exists():
        print(f"{frf} missing: run `make run` first; skipping part 1\n")
        return
    table, _ = read_parquet(frf, kind="frf")
    measured = measured_channels(table, *FLOORS)
    settings = CONFIG["diagnose"]
    print(f"1. {machine}, run ident01, diagnosis as the rule runs it (max_evaluations {settings['max_evaluations']}, "
          f"sequence_length {settings['sequence_length']}); BLAS threads: {os.environ.get('OMP_NUM_THREADS', 'default')}")
    print(f"{'variant':<10} {'wall s':>7} {'evals':>6} {'evals/s':>8} {'chi2/N':>10}  verdict")
    for variant in ["nominal"] + list(CONFIG["machines"][machine].get("variants") or {}):
        model = machine_from_config(read_yaml(ROOT / "results" / machine / "model" / variant / "machine.yaml"))
        started = time.perf_counter()
        result = diagnose(model, measured, max_evaluations=settings["max_evaluations"],
                          sequence_length=settings["sequence_length"])
        wall = time.perf_counter() - started
        evaluations = sum(f.evaluations for f in result.ranked)
        verdict = " then ".join(f"{f.candidate.label} ({', '.join(f'{v:.4g}' for v in f.values)})" for f in result.sequence)
        print(f"{variant:<10} {wall:7.2f} {evaluations:6d} {evaluations / wall:8.0f} {result.chi2 / result.points:10.4g}  "
              f"{verdict or 'nothing significant missing'}   [target <= 30 s: {'ok' if wall <= 30 else 'MISSED'}]")
    print()


def suite(seeds):
    machine_config = yaml.safe_load((ROOT / "config" / "machines" / "hs_eden_like.yaml").read_text())
    machine_config["frequency_grid"]["radial"]["points"] = 80  # as the test suite
    machine_config["frequency_grid"]["axial"]["points"] = 30
    identification = settings_from_config(CONFIG["identification"])
    nominal = machine_from_config(machine_config)
    print("2. hidden-effect suite (hs_eden_like, 80-point radial grid, nominal model)")
    print(f"{'seed':>4} {'hidden effect':<18} {'first?':>6} {'top candidate':<26} {'max param err %':>15} "
          f"{'excess before':>13} {'after':>8} {'cut %':>6} {'diag s':>6}")
    firsts, errors, cuts, negatives = [], [], [], []
    for seed in seeds:
        draws = hidden_effect_draws(seed)
        for name in [*sorted(draws), None]:
            effects = [] if name is None else [{"name": name, "parameters": draws[name]}]
            try:
                table = identify_on_rig(hidden_effect_rig(machine_config, effects), machine_config, identification, seed=seed)
            except Exception as error:  # an unstable truth cannot be identified: reported, not scored
                print(f"{seed:4d} {name:<18} rig cannot run: {error}")
                continue
            measured = measured_channels(table, *FLOORS)
            started = time.perf_counter()
            result = diagnose(nominal, measured)
            wall = time.perf_counter() - started
            top = result.ranked[0]
            if name is None:
                negatives.append(result.best is None)
                print(f"{seed:4d} {'(none)':<18} {'':>6} {top.candidate.label:<26} {'':>15} {result.excess:13.4g} "
                      f"{'':>8} {'':>6} {wall:6.1f}  significant: {result.best is not None}")
                continue
            hidden = next(f for f in result.ranked if f.candidate.effect == name
                          and all(f.candidate.fixed.get(k, v) == v for k, v in draws[name].items()
                                  if k not in {p.name for p in f.candidate.free}))
            first = top.candidate.effect == name or hidden.candidate.label in top.indistinguishable
            error = max(abs(v / draws[name][p.name] - 1) for p, v in zip(hidden.candidate.free, hidden.values))
            cut = 1 - result.excess_after(hidden) / result.excess if result.excess > 0 else np.nan
            firsts.append(first)
            errors.append(error)
            cuts.append(cut)
            print(f"{seed:4d} {name:<18} {'yes' if first else 'NO':>6} {top.candidate.label:<26} {100 * error:15.2f} "
                  f"{result.excess:13.4g} {result.excess_after(hidden):8.3g} {100 * cut:6.1f} {wall:6.1f}")
    cuts = np.array(cuts)
    print(f"\nranked first (or named indistinguishable from the first): {sum(firsts)} of {len(firsts)}; "
          f"parameters within 10 %: {sum(e <= 0.1 for e in errors)} of {len(errors)}; "
          f"excess cut >= 80 %: {int(np.sum(cuts[np.isfinite(cuts)] >= 0.8))} of {int(np.sum(np.isfinite(cuts)))} "
          f"({int(np.sum(~np.isfinite(cuts)))} hid below the noise floor); "
          f"negative controls clean: {sum(negatives)} of {len(negatives)}")


if __name__ == "__main__":
    default_machine()
    suite(range(2026, 2026 + (int(sys.argv[1]) if len(sys.argv) > 1 else 2)))
