"""Accuracy study: the stepped sine's two-level repeats extrapolated to zero amplitude (issues 15 and 19).

Every second step of a stepped-sine run is measured again at half its amplitude (``identification.repeat_ratio``,
log ``level`` 1).  `ambid.floor` turns the pairs into a *systematic floor* that chi2 counts as independent errors.
If the force law's error grows as the square of the amplitude, ``G(A) = G0 + k A^2``, the pair also gives the FRF
at zero amplitude (Richardson extrapolation), ``G0 = (4 G(A/2) - G(A)) / 3``, with the noise
``sqrt(16 s(A/2)^2 + s(A)^2) / 3`` and no systematic floor at all; the FRF stage does this where it is the more
accurate estimate (``frf.zero_amplitude``, `ambid.amplitude`).

Part 1 takes one hidden-effect case of the test suite (demo20 with its drawn foundation mode, seed 7, the 80 +
20-step grids from 5 Hz of ``tests/test_diagnose.py``; the case whose mass the diagnosis missed by 6.7 %, 4.7 sigma,
with the floor), identifies it on the rig and compares, on the repeated steps only:

1. the measured FRF with its floor,
2. the measured FRF with its noise alone,
3. the extrapolated FRF with its propagated noise alone,

each by chi2 per point of the hidden truth, the foundation candidate's own fit (``diagnose.max_evaluations`` 60 and
240) and a joint refit started from the truth.

Part 2 runs whole logs (every step) through the FRF stage with ``zero_amplitude`` off and on: chi2 per point of the
hidden truth per channel family, and the hidden effect's own fit, on demo20 and hs_eden_like, with the drawn
foundation mode and with no effect.

Part 3 is what the extrapolation needs of the log's noise estimate: on the diagnosis benchmark's grid (80 points from
1 Hz, seeds 2026-2028) the hs_eden_like rig's extrapolated points, with the noise as each step states it (two DFT
lines, 4 degrees of freedom) and pooled over neighbouring steps as the FRF stage does (`ambid.floor.pooled_noise`),
at the thesis' settling (0.3 s) and at 1 s.  Measured (stop 26, kernels pinned): mean (max) |error|^2 / stated^2
at 300-500 Hz 3.71 (38.7) as stated, 1.38 (6.1) pooled at 0.3 s; 1.35 (7.5) and 0.97 (2.4) at 1 s.  A rig without
noise and without ADC quantization shows what the A^2 law leaves (single points near the first flexible mode above 500 Hz).  (Without noise
but with quantization, the rig's undithered ADC steps dominate every error above ~300 Hz: not a useful reference.)  The
model side never reads the rig: the truth is used only to score.

Part 4 is what the diagnosis' cells see on logs without a hidden effect: the rig of each default machine on the
diagnosis benchmark's grid (80 radial points from 1 Hz, 26 axial), over many seeds, through the FRF stage with
``zero_amplitude`` on and off, the nominal model as rule diagnose makes it (`ambid.compare.for_run`).  Per family and
band cell (`ambid.diagnose.misfit_cells`): the mean and standard deviation of chi2 per point over the seeds, the
effective number of independent points ``(mean / sd)^2`` (the cell's point count where its errors are independent)
beside the sum of its points' ``effective_share`` that the FRF stage states (median over the logs), the cell's chance
limit (`ambid.diagnose.chance_limit` of those and of the degrees of freedom of their stated variances, median and
largest: Fisher's F where those are estimates, else Gamma) and on how many seeds the cell reads above it (0.135 % of
them if the stated shares and degrees of freedom are right).  Measured (stop 48, seeds 2040-2079, 40 logs a
machine, every point counted as independent): the axial
position cell (26 points, 1-100 Hz) at zero amplitude reads mean 1.14 and 1.04 (demo20, hs_eden_like), standard
deviation 0.52 and 0.46 where independent points give 0.22 and 0.20: 4.8 and 5.1 effective points of 26, above its
limit of 1.69 on 5 and 3 of 40 logs.  The steps between two repeated pairs take the amplitude coefficient
interpolated from those pairs, so one pair's noise is in all of them (their standardized errors correlate 0.57 from
one step to the next).  The hidden-effect suite's negative controls on seeds 2050-2059 read "unexplained" (twice) and
"actuator_coefficients missing" for exactly that cell.  Measured without the extrapolation the same cell reads 0.72
and 0.65, standard deviation 0.06.  A coefficient fitted over the whole channel (the lowest polynomial in log
frequency its pairs allow) was tried and is wrong: the pairs' coefficients below 20 Hz carry standard deviations of
0.06-0.15, those near 100 Hz 0.0002-0.0004 (hs_eden_like 2057), so the line through the latter passes the test and
extrapolates to the low steps, where the axial cell then read 3.06 on all three hs_eden_like logs.

Stop 49, the same logs with each point's share stated (`ambid.amplitude.effective_share`: the pairs' noise in the
steps between them, the pooled noise estimates, the scale to the neighbours' scatter): the axial cell's points state
6.1 and 5.8 independent ones (the spread shows 4.8 and 5.1), its limit is 2.65 and 2.71 (median; 2.74 and 2.80 at
most), and it reads above it on 1 of 40 logs of each machine: demo20 2071 at 2.62 against 2.52, hs_eden_like 2078 at
2.68 against 2.55.
The coil-current cells state their point counts (26.0 and 25.3 for the 26 I_Z points; their spread shows 23 and 25).

Stop 55, the same logs with the rows left as measured stating their pooled noise estimates' error too
(`ambid.amplitude.measured_variance_errors`), first with the scale to the neighbours' scatter counted as well: the
coil-current cells spread as 41-154 independent points (demo20: 42, 112 and 110 of the bands' 57, 129 and 160, the
rows 41-70 of 80, I_Z 23; hs_eden_like: 42, 154 and 121 of 69, 169 and 108, the rows 57-101, I_Z 25) and stated
14-44, their limits 1.65-2.48; every cell within its limit on all 80 logs but hs_eden_like's NY row without the
extrapolation (2 of 40).  The scale is measured from the misfit it then divides, so it is no error of its own there:
without it the rows state the pooling alone, at most two thirds of their points.

Usage: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_extrapolation.py`` (parts 1-3, about 3 minutes);
``... bench_extrapolation.py --cells [first seed] [logs] [workers]`` (part 4 alone, default 2040, 40 and 2: about 15
minutes on 2 cores).
"""

import concurrent.futures
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from ambid.compare import effective_shares, for_run, measured_channels, model_response
from ambid.diagnose import (DiagnoseSettings, candidate_space, diagnose, joint_refit, misfit,
                            misfit_cells, plant_with_effects)
from ambid.effects import effect_from_config
from ambid.excitation import StepPlan, run_stepped_sine, settings_from_config
from ambid.experiment import hidden_effect_draws, hidden_effect_rig
from ambid.floor import FloorSettings, pooled_noise
from ambid.frf import frf_from_log, log_arrays, mimo_etfe
from ambid.kernels import rerun_pinned
from ambid.logs import CHANNELS, identification_frame
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.rig import RigModel

from bench_diagnose import machine_config as suite_machine_config  # noqa: E402  (the suite's grids)

ROOT = Path(__file__).resolve().parents[1]
SEED = 7


def machine_config():
    """demo20 on the test suite's grids: 80 radial and 20 axial steps from 5 Hz."""
    config = yaml.safe_load((ROOT / "config/machines/demo20.yaml").read_text())
    config["frequency_grid"]["radial"].update(points=80, start_hz=5.0)
    config["frequency_grid"]["axial"].update(points=20, start_hz=5.0)
    return config


def family_chi2(measured, predicted):
    """chi2 per point per channel family (`ambid.diagnose.misfit_cells` summed over bands): ``{family: (chi2/pt, points)}``."""
    cells = misfit_cells(measured, predicted).query("output == 'all'").assign(chi2=lambda c: c["chi2_per_point"] * c["points"])
    totals = cells.groupby("family")[["chi2", "points"]].sum()
    return {family: (row.chi2 / row.points, int(row.points)) for family, row in totals.iterrows()}


def full_log_study(name, config, entries, settings, seed):
    """The whole log (every step, repeats where planned) through the FRF stage with and without the zero-amplitude
    estimate: chi2/pt of the hidden truth per family, and the leading candidate's own fit."""
    machine = machine_from_config(config)
    plant = Plant(machine)
    truth = [effect_from_config(entry, "truth") for entry in entries]
    records, _ = run_stepped_sine(RigModel(hidden_effect_rig(config, entries)), StepPlan.for_machine(plant, settings),
                                  settings, seed=seed)
    frame = identification_frame(records)
    label = ", ".join(e["name"] for e in entries) or "no effect"
    print(f"-- {name}, {label} (seed {seed}), full log:")
    for zero in (False, True):
        table, floors, _ = frf_from_log(frame, FloorSettings(zero_amplitude=zero))
        measured = measured_channels(table)
        predicted = model_response(plant_with_effects(plant, truth), measured)
        figures = family_chi2(measured, predicted)
        extrapolated = int(floors["zero_amplitude_points"].sum()) if "zero_amplitude_points" in floors else 0
        print(f"   zero_amplitude {str(zero):5s}: truth chi2/pt " + ", ".join(
            f"{family} {value:.3f} ({points})" for family, (value, points) in sorted(figures.items()))
              + f"; {extrapolated} rows extrapolated")
        if entries:
            candidate = [c for c in candidate_space(machine) if c.label == entries[0]["name"]]
            fitted = diagnose(machine, measured, candidates=candidate).ranked[0]
            values = ", ".join(f"{p.name} {v:.6g} +- {s:.2g}" for p, v, s in zip(fitted.candidate.free, fitted.values,
                                                                                  fitted.std))
            print(f"      own fit: {values} (truth " + ", ".join(f"{k} {v:.6g}" for k, v in entries[0]["parameters"].items())
                  + ")")


def noise_study(config, settings, seeds, sensor_noise_m, current_noise_a, resolution=True, half_widths=(0, 2)):
    """What the extrapolation needs of the log's noise: the hs_eden_like rig without hidden effects on the diagnosis
    benchmark's grid (80 points from 1 Hz), the DX/DX element of the MIMO FRF at the repeated steps per band, over
    ``seeds``: the rms relative error against the truth and the rms stated noise, at the measured amplitude, at half
    of it and extrapolated, and the mean and largest |error|^2 / stated^2 of the extrapolation (1 where the log's
    noise estimate is right), with the log's noise as each step states it (``half_widths`` 0) and pooled over its
    neighbours as the FRF stage does (`ambid.floor.pooled_noise`, config ``frf.noise_half_width``)."""
    plant = Plant(machine_from_config(config))
    rig = hidden_effect_rig(config, [], sensor_noise_m=sensor_noise_m, current_noise_a=current_noise_a,
                            **({} if resolution else {"sensor_resolution_m": 0.0, "current_resolution_a": 0.0}))
    frames = [identification_frame(run_stepped_sine(RigModel(rig), StepPlan.for_machine(plant, settings), settings,
                                                    seed=seed)[0]) for seed in seeds]
    rms = lambda x: 100 * np.sqrt(np.mean(x**2))  # noqa: E731
    u2 = CHANNELS.index("U2_DX")
    for half_width in half_widths:
        columns = []
        for frame in frames:
            frame = pooled_noise(frame, half_width)
            high, low = log_arrays(frame), log_arrays(frame, level=1)
            f, plant_high, std_high, _ = mimo_etfe(high)
            f_low, plant_low, std_low, _ = mimo_etfe(low)
            at = np.searchsorted(f, f_low)
            lever = 1 / (1 - np.abs(low["DX"][1][:, u2]) ** 2 / np.abs(high["DX"][1][at, u2]) ** 2)
            g, g1, s, s1 = plant_high[at, 0, 0], plant_low[:, 0, 0], std_high[at, 0, 0], std_low[:, 0, 0]
            zero, zero_std = g - lever * (g - g1), np.sqrt((lever - 1) ** 2 * s**2 + lever**2 * s1**2)
            truth = model_response(plant, {("DX", "DX"): (f_low, None, None)})[("DX", "DX")]
            columns.append((f_low, g, g1, s, s1, zero, zero_std, truth))
        f_low, g, g1, s, s1, zero, zero_std, truth = (np.concatenate(c) for c in zip(*columns))
        print(f"-- hs_eden_like, no hidden effect, sensor noise {sensor_noise_m:.0e} m, current noise "
              f"{current_noise_a:.0e} A, {'the rig' + chr(39) + 's' if resolution else 'no'} ADC quantization, settling "
              f"from {settings.settle_min_s} s, seeds {list(seeds)}, noise "
              + (f"pooled over {half_width} steps either side" if half_width else "as each step states it")
              + ": DX/DX at the repeated steps, rms relative error / rms stated noise [%]")
        print("   band         measured amplitude  half amplitude   extrapolated   extrapolated |error|^2/stated^2 mean, max")
        for lo, hi in ((1, 100), (100, 300), (300, 500), (500, 800)):
            m = (f_low >= lo) & (f_low < hi)
            z2 = np.abs(zero - truth)[m] ** 2 / zero_std[m] ** 2
            print(f"   {lo:3d}-{hi:3d} Hz   {rms(np.abs(g / truth - 1)[m]):6.3f} / {rms(s[m] / np.abs(truth[m])):5.3f}"
                  f"   {rms(np.abs(g1 / truth - 1)[m]):6.3f} / {rms(s1[m] / np.abs(truth[m])):5.3f}"
                  f"   {rms(np.abs(zero / truth - 1)[m]):6.3f} / {rms(zero_std[m] / np.abs(truth[m])):5.3f}"
                  f"   {np.mean(z2):8.2f} {np.max(z2):7.1f}  ({m.sum()} points)")


def no_effect_cells(case):
    """Part 4, one log: each cell's chi2 per point of the nominal model, ``{zero_amplitude: cells frame}``."""
    name, seed = case
    config = suite_machine_config(name, 80)  # the diagnosis benchmark's grid: 80 radial points from 1 Hz, 26 axial
    settings = settings_from_config(yaml.safe_load((ROOT / "config/config.yaml").read_text())["identification"])
    machine = machine_from_config(config)
    plan = StepPlan.for_machine(Plant(machine), settings)
    records, _ = run_stepped_sine(RigModel(hidden_effect_rig(config, [])), plan, settings, seed=seed)
    frame = identification_frame(records)
    out = {}
    for zero in (True, False):
        table = frf_from_log(frame, FloorSettings(zero_amplitude=zero))[0]
        measured = measured_channels(table)
        model, _ = for_run(machine, measured, {}, "diagnose")
        out[zero] = misfit_cells(measured, model_response(Plant(model), measured), shares=effective_shares(table))
    return name, seed, out


def cell_study(first_seed, logs, workers):
    """Part 4: the cells' chi2 per point over ``logs`` no-effect logs of each default machine."""
    cases = [(name, seed) for name in ("demo20", "hs_eden_like") for seed in range(first_seed, first_seed + logs)]
    results = {}
    with concurrent.futures.ProcessPoolExecutor(max_workers=workers) as pool:
        for name, seed, out in pool.map(no_effect_cells, cases):
            results.setdefault(name, []).append(out)
    for name, outs in results.items():
        print(f"-- {name}, no hidden effect, seeds {first_seed}-{first_seed + logs - 1}: chi2 per point of each cell")
        print("   cell                          zero amplitude  points   mean     sd  (independent)  effective points:"
              " from the spread, stated (median)  estimate dof (median)  limit (median, max)  above it")
        for zero in (True, False):
            cells = outs[0][zero]
            per_point = np.array([out[zero]["chi2_per_point"].to_numpy() for out in outs])
            above = np.array([out[zero]["above_floor"].to_numpy() for out in outs])
            stated = np.array([out[zero]["effective_points"].to_numpy() for out in outs])
            limit = np.array([out[zero]["limit"].to_numpy() for out in outs])
            dof = np.array([out[zero]["estimate_dof"].to_numpy() for out in outs])
            for k, cell in enumerate(cells.itertuples()):
                mean, sd = per_point[:, k].mean(), per_point[:, k].std(ddof=1)
                print(f"   {cell.family:9s} {cell.band:12s} {cell.output:6s} {str(zero):5s}  {cell.points:6d}  "
                      f"{mean:6.2f} {sd:6.2f}  ({mean / np.sqrt(cell.points):5.2f})  "
                      f"{(mean / sd) ** 2 if sd > 0 else np.inf:14.1f} {np.median(stated[:, k]):8.1f}"
                      f"  {np.median(dof[:, k]):8.1f}"
                      f"  {np.median(limit[:, k]):6.2f} {limit[:, k].max():6.2f}"
                      f"  {np.sum(above[:, k]):3d} of {len(outs)}")


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
    full_log_study("demo20", config, [entry], settings, SEED)
    full_log_study("demo20", config, [], settings, SEED)
    hs = yaml.safe_load((ROOT / "config/machines/hs_eden_like.yaml").read_text())
    hs["frequency_grid"]["radial"].update(points=80, start_hz=5.0)
    hs["frequency_grid"]["axial"].update(points=20, start_hz=5.0)
    full_log_study("hs_eden_like", hs, [], settings, SEED)
    hs_draw = {"name": "foundation_mode", "parameters": hidden_effect_draws(hs, seed=SEED)["foundation_mode"]}
    full_log_study("hs_eden_like", hs, [hs_draw], settings, SEED)
    # part 3: the log's noise estimate on the diagnosis benchmark's grid (from 1 Hz), with the rig's noise and without
    grid = yaml.safe_load((ROOT / "config/machines/hs_eden_like.yaml").read_text())
    grid["frequency_grid"]["radial"]["points"] = 80
    grid["frequency_grid"]["axial"]["points"] = 26
    seeds = (2026, 2027, 2028)
    noise_study(grid, settings, seeds, 2e-7, 5e-3)
    noise_study(grid, replace(settings, settle_min_s=1.0), seeds, 2e-7, 5e-3)
    noise_study(grid, settings, seeds[:1], 1e-12, 1e-12, resolution=False, half_widths=(0,))


if __name__ == "__main__":
    rerun_pinned()  # the same figures on every x86-64 CPU (ambid.kernels)
    if "--cells" in sys.argv:
        numbers = [int(a) for a in sys.argv[sys.argv.index("--cells") + 1:]]
        cell_study(*(numbers + [2040, 40, 2][len(numbers):]))
    else:
        main()
