"""Benchmark of the rotor model update (issue 6 targets): speed, accuracy, and the thesis' Nelder-Mead as baseline.

1. demo20, thesis ch. 5.3: the reference rotor has elements 5-8 at 107.7, 80.1,
   41.1 and 18.9 GPa (the rig's truth); its resonances and anti-resonances are
   computed exactly (same-plane channels, first three modes up to 3.5 kHz, and
   the thesis' own set: the first mode of NX(1,1) and DX(3,3)).  Printed:
   objective evaluations per second on one core (B(e), eq. 5.35, with and
   without the analytic sensitivities), the default update's wall time and its
   errors (moduli against the truth, features against the reference), and the
   thesis' Nelder-Mead from the same random start: its time to reach the
   default's final B(e) (or its final B(e) if it never does), as a ratio.
2. hs_eden_like, 14 moduli + damping, on the workflow's rig data (the fit
   stage's features of run ident01; made with snakemake if missing): wall time
   of the full update as configured (8 starts), largest matched frequency and
   damping errors against the measurement, the same against the rig's truth
   (known only here), and Nelder-Mead from the thesis' random start.

Targets: demo20 moduli within 1 %, frequencies within 0.01 %, damping within
1 %; hs every matched frequency within 0.5 %, damping within 10 %;
>= 1000 objective evaluations per second on demo20; the 14-variable update in
<= 2 s.

Usage: ``.venv/bin/python benchmarks/bench_update.py`` (one BLAS thread).
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # one core, as the target says
os.environ.setdefault("OMP_NUM_THREADS", "1")

import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import yaml  # noqa: E402

from ambid.effects import effect_from_config  # noqa: E402
from ambid.io import read_parquet  # noqa: E402
from ambid.machine import machine_from_config  # noqa: E402
from ambid.plant import Plant  # noqa: E402
from ambid.rig import rig_from_config  # noqa: E402
from ambid.update import (UpdateSettings, comparison_rows, identifiability, measured_features,  # noqa: E402
                          nelder_mead_update, reference_features, update_channels, update_model, update_problem)

ROOT = Path(__file__).resolve().parents[1]
THESIS_MODULI_GPA = np.array([107.7, 80.1, 41.1, 18.9])
SAME_PLANE = update_channels("same_plane")


def evaluations_per_second(problem, derivatives=False, seconds=1.5):
    rng = np.random.default_rng(0)
    points = [problem.random_start(rng).clip(0.05, None) for _ in range(20)]
    count, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        problem.residuals(points[count % len(points)], derivatives)
        count += 1
    problem.history.clear()
    return count / (time.perf_counter() - start)


def nelder_mead_to(problem, start, target_b):
    """Run the thesis' Nelder-Mead; seconds until B(e) first reaches ``target_b`` (None: never), final B, evaluations."""
    first = len(problem.history)
    t0 = time.perf_counter()
    stamps = []
    objective = problem.objective

    def timed(values):
        value = objective(values)
        stamps.append((time.perf_counter() - t0, value))
        return value

    problem.objective = timed
    try:
        values, evaluations = nelder_mead_update(problem, start)
    finally:
        problem.objective = objective
    del problem.history[first:]
    reached = next((t for t, b in stamps if b <= target_b), None)
    return reached, min(b for _, b in stamps), evaluations, stamps[-1][0]


def errors(problem, values):
    table = pd.DataFrame(comparison_rows(problem, problem.start, values))
    return (table[table["quantity"] == "frequency"]["error_pct"].max(),
            table[table["quantity"] == "damping ratio"]["error_pct"].max(), table)


def demo20(config):
    machine = machine_from_config(config["demo20"], name="demo20")
    scale = (THESIS_MODULI_GPA / 200).tolist()
    reference = machine.with_effects([effect_from_config({"name": "element_stiffness",
                                                          "parameters": {"tag": "design", "scale": scale}}, "e")])
    print("== demo20, thesis ch. 5.3: reference rotor with elements 5-8 at 107.7 / 80.1 / 41.1 / 18.9 GPa")
    cases = [("same-plane channels, 3 modes (default channels)", SAME_PLANE, 3, 3500.0),
             ("thesis set: NX(1,1), DX(3,3), first mode", [("NX", "NX"), ("DX", "DX")], 1, 1000.0)]
    for label, channels, modes, band in cases:
        settings = UpdateSettings.from_config({"tags": ["design"], "modes": modes, "damping": "none", "seed": 3})
        problem = update_problem(machine, reference_features(Plant(reference), channels, band), settings, channels)
        plain, with_jacobian = evaluations_per_second(problem), evaluations_per_second(problem, True)
        t0 = time.perf_counter()
        result = update_model(problem, settings)
        wall = time.perf_counter() - t0
        f_err, d_err, _ = errors(problem, result.values)
        rows, _, summary = identifiability(problem, result.values)
        moduli = 200 * result.values
        print(f"-- {label}: {len(problem.measured)} features")
        print(f"   objective evaluations/s (one core): {plain:.0f} B(e); {with_jacobian:.0f} with sensitivities")
        print(f"   least squares, {settings.starts} starts: {wall:.2f} s wall, {result.evaluations} evaluations, "
              f"B(e) {result.objective:.2e}")
        print(f"   moduli [GPa]: {np.array2string(moduli, precision=3)}; error vs truth "
              f"{np.array2string(100 * (moduli / THESIS_MODULI_GPA - 1), precision=4)} %")
        print(f"   determined: {summary['rank']} of 4 directions; per variable "
              f"{[bool(r['determined']) for r in rows]}")
        print(f"   largest feature error: frequency {f_err:.2e} %, damping {d_err:.2e} %")
        start = problem.random_start(np.random.default_rng(settings.seed))
        reached, best, evaluations, total = nelder_mead_to(problem, start, max(result.objective, 1e-12))
        t_ls = time.perf_counter()
        single = update_model(problem, UpdateSettings.from_config({**settings.__dict__, "starts": 1}))
        t_ls = time.perf_counter() - t_ls
        print(f"   Nelder-Mead (thesis, random start): {evaluations} evaluations in {total:.2f} s, best B(e) {best:.2e}; "
              + (f"reached the default's B(e) after {reached:.2f} s" if reached is not None
                 else "never reached the default's B(e)")
              + f"; the default from one start: {t_ls:.2f} s, B(e) {single.objective:.2e}; time ratio NM / default "
              + (f"{reached / wall:.1f}" if reached is not None else f"> {total / wall:.1f} (not reached)"))


def hs(config):
    features_path = ROOT / "results/hs_eden_like/fit/ident01/features.parquet"
    if not features_path.exists():
        print("   (making the fit stage's features of hs_eden_like ident01 with snakemake first)")
        # the target before --quiet, whose choices take every word after it
        subprocess.run([sys.executable, "-m", "snakemake", "-c2", str(features_path.relative_to(ROOT)), "--quiet", "all"],
                       cwd=ROOT, check=True)
    features, _ = read_parquet(features_path, kind="fit_features")
    machine = machine_from_config(config["hs_eden_like"], name="hs_eden_like")
    workflow = yaml.safe_load((ROOT / "config/config.yaml").read_text())
    settings = UpdateSettings.from_config(workflow["update"], workflow["machines"]["hs_eden_like"]["update"])
    channels = update_channels(settings.channels)
    problem = update_problem(machine, features, settings)
    print(f"== hs_eden_like on rig data (run ident01): {len(problem.measured)} features, {len(problem.variables)} variables "
          f"(14 moduli + damping), {settings.starts} starts")
    t0 = time.perf_counter()
    result = update_model(problem, settings)
    wall = time.perf_counter() - t0
    f_err, d_err, table = errors(problem, result.values)
    rows, _, summary = identifiability(problem, result.values)
    print(f"   least squares: {wall:.2f} s wall (target <= 2 s), {result.evaluations} evaluations, B(e) "
          f"{problem.objective(problem.start):.3g} -> {result.objective:.3g}")
    print(f"   largest error against the measurement: frequency {f_err:.3f} % (target < 0.5 %), damping {d_err:.1f} % "
          f"(target < 10 %)")
    damping = table[table["quantity"] == "damping ratio"]
    for kind in ("resonance", "anti-resonance"):
        part = damping[damping["feature"].str.contains(f" {kind} ")]
        print(f"     {kind} damping errors [%]: {np.array2string(part['error_pct'].to_numpy(), precision=1)}")
    print(f"   determined: {summary['rank']} directions; variables determined: "
          f"{[v.name for v, r in zip(problem.variables, rows) if r['determined']]}")
    # the rig's truth, known only to this benchmark: how far are the measured and the updated features from it?
    rig = rig_from_config(yaml.safe_load((ROOT / "config/rigs/hs_eden_like.yaml").read_text()), config["hs_eden_like"])
    truth = reference_features(Plant(rig.machine), channels, 800.0)
    truth_measured = measured_features(truth, channels, settings.modes)
    key = ["output", "input", "root"]
    merged = problem.measured.merge(truth_measured, on=key + ["number"], suffixes=("", "_truth"))
    f1, z1, _, _ = problem.predict(result.values)
    updated = problem.measured.assign(f_updated=f1, z_updated=z1).merge(truth_measured, on=key + ["number"],
                                                                        suffixes=("", "_truth"))
    print("   against the rig's truth: measured features off by up to "
          f"{100 * np.max(np.abs(merged['frequency_hz'] / merged['frequency_hz_truth'] - 1)):.3f} % (frequency), "
          f"{100 * np.max(np.abs(merged['damping_ratio'] / merged['damping_ratio_truth'] - 1)):.1f} % (damping); "
          f"updated model off by up to {100 * np.max(np.abs(updated['f_updated'] / updated['frequency_hz_truth'] - 1)):.3f} % "
          f"and {100 * np.max(np.abs(updated['z_updated'] / updated['damping_ratio_truth'] - 1)):.1f} %")
    start = problem.random_start(np.random.default_rng(settings.seed))
    reached, best, evaluations, total = nelder_mead_to(problem, start, result.objective)
    print(f"   Nelder-Mead (thesis, random start): {evaluations} evaluations in {total:.2f} s, best B(e) {best:.3g}; "
          + (f"reached the default's B(e) after {reached:.2f} s, ratio {reached / wall:.1f}" if reached is not None
             else f"never reached the default's B(e) {result.objective:.3g}: ratio > {total / wall:.1f}"))


def main():
    config = {name: yaml.safe_load((ROOT / f"config/machines/{name}.yaml").read_text()) for name in ("demo20", "hs_eden_like")}
    demo20(config)
    hs(config)


if __name__ == "__main__":
    main()
