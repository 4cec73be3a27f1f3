"""Benchmark of the diagnosis (issue 15 targets): the hidden-effect suite, the thesis case and the default machine.

1. **The hidden-effect suite.**  For each default machine (hs_eden_like, demo20)
   and seed, rigs hide (a) every effect of the library alone, its strength drawn
   from physical ranges down to three times the data floor
   (`ambid.experiment.hidden_effect_draws`; the floor that seed's log without an
   effect measured, `SIGNATURE`), (b) three pairs, (c) physics outside
   the library (`ambid.rig_effects`: a second-order current loop, a sensor gain
   error on one axis, a notch in one sensor's electronics, a mis-tuned controller
   notch), (d) nothing (negative control; on `EXTRA_NEGATIVE_SEEDS` more seeds too).  Each rig is identified with the
   stepped sine (repeated steps included) and the nominal model diagnosed from
   the FRF alone.  Scored, per the issue:
   - top-1: the diagnosis chose exactly the hidden effects (or named them
     indistinguishable from its choice);
   - parameters: every hidden parameter within 5 % where the joint refit
     determines it, else inside two of its standard deviations;
   - final misfit: no family x band cell above the floor after the joint refit;
   - outside the library: nothing chosen or refitted at a search bound, and the
     misfit that remains called unexplained (the controller notch, invisible to
     the open-loop plant, must give "nothing");
   - negative controls: nothing missing;
   - leads (not scored as top-1): where a hidden effect's misfit is within the floor and nothing is chosen,
     whether the diagnosis' lead (`ambid.diagnose.Diagnosis.lead`) is that effect, and which negative controls
     carry a lead.
   Column ``truth``: the BIC evidence the hidden effects at their true parameters earn in the log (the scorer
   knows them): below ``INDISTINGUISHABLE_BIC`` the draw is not visible in the data; top-1 is also given among the
   visible draws, beside the overall figure the target is set on.
2. **The thesis case** (ch. 5.3): demo20 with elements 5-8 at 0.5, 0.7 and 1.3.
3. **The default machine** (needs ``make run`` first): the diagnosis rule's work
   on every variant of hs_eden_like and demo20, wall time against the targets
   (<= 15 s per variant on demo20, <= 30 s on hs_eden_like), one BLAS thread as
   the workflow's jobs have.

Usage: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_diagnose.py [seeds] [radial points] [workers]
[--suite] [--first-seed=N] [--signature=typical] [--at-floor-evidence=N] [key=value ...]`` (default 2 seeds from 2026, 120-point radial grids, 1 worker; about an
hour on an idle 2-core machine).  ``--suite`` runs section 1 alone; ``--first-seed`` draws the hidden effects anew
(out of sample: the figures below are on 2026 and 2027, the seeds the methods were developed on); ``key=value`` changes the config for this run, an ``identification`` key
(``settle_min_s=1.0``) or an ``frf`` floor key (``zero_amplitude=false``), to measure what a setting does;
``--signature=typical`` draws the hidden effects down to three times a typical floor, as until stop 57, and
``--at-floor-evidence=N`` sets `ambid.diagnose.AT_FLOOR_EVIDENCE` for the run (the suite also prints, for a few lower
values, what each diagnosis' first round would have named at the floor, `at_floor_choice`).  The suite
follows ``config/config.yaml``'s ``identification`` and ``frf`` sections otherwise.  Measured, seeds 2026 and 2027,
80 points, 2 workers (stop 27, ``2 80 2 --suite``): 42 of 50 named first, parameters 40 of 50, final misfit 50 of 50,
outside the library 8 of 8 and 8 of 8, negative controls 4 of 4; ``zero_amplitude=false`` 40 and 37 (before the MIMO
floor took its own pairs, stop 26: 41 and 35, and 41 and 36 extrapolated).  Stop 29 (misfit-peak scan, leads): the
same 42 and 40, final misfit 49 of 50; 4 of the 5 misses at the floor have the hidden effect as lead (the fifth,
demo20's gyroscopic at 52 BIC, has noncollocation); 3 of the 4 negative controls carry a noncollocation lead; median
diagnosis 2.0 -> 1.5 s.  Stop 30 (every step of a channel whose pairs measure its amplitude dependence taken to zero
amplitude, `ambid.amplitude.MEASURED_KAPPA`; no two-level floor in a channel inside its noise, `ambid.floor.RESOLVED`;
the interpolated steps' error from the pairs' curvature): top-1 43 of 50 (hs foundation 2026 now named with its
parameters within 1.9 %, demo20 modal damping 2027 chosen), parameters 42, final misfit 48 of 50 (hs's pairs delay +
foundation and modal damping + sensor low-pass leave misfit, said "unexplained"), 3 of the 4 misses at the floor with
the hidden effect as lead, the sensor notch outside the library "unexplained" on both machines (was a foundation
mode), negative controls 4 of 4 with one lead (foundation_mode, demo20 2027) instead of three noncollocation leads
(none on the invisible controller notch either, which had them).  Stop 35 (a resonance between two pairs gets the
amplitude error of its amplification, `ambid.floor.resonance_ratio`; a candidate masked by a larger misfit searched
afresh; close contenders told apart by a joint refit, `ambid.diagnose._choose`): top-1 44 -> 46 of 50 (demo20's
gyroscopic 2026 no longer with a 0.07 % stiffness change beside it; hs's modal damping + sensor low-pass named alone,
was with a delay, a sensor shift and the actuator coefficients), parameters 43 -> 44, final misfit 49 -> 50 of 50,
outside 8 of 8, negative controls 4 of 4; the four misses are all at the floor ("nothing", three with the hidden
effect as lead); diagnosis 115.8 -> 102.6 s over the 50 rigs (median 1.65 -> 1.42 s).  Stop 36 (the fit's own forward-difference
Jacobian, `ambid.diagnose._with_jacobian`; each round's contenders refitted with all the other chosen effects,
`ambid.diagnose._swap`): the same figures (46, 44, 50, 8, 4 of 4); demo20's delay + foundation pair 2026 now
named as itself (was a sensor pole, indistinguishable, beside the foundation); diagnosis 104.0 s.  Stop 37 (each
rig's model as rule diagnose makes it, `ambid.compare.for_run`: the coil-current sampling taken from the data, now
with a second-order loop among the amplifiers it is fitted with; the misfit the chosen effects leave read per output
row): the same figures; start_of_cycle, the rig's convention, on 62 of 62 rigs, and a ``coil_current_loop`` note on
the two second-order-amplifier rigs only.  Stop 38 (a channel's repeated pairs that scatter beyond their stated noise
decide by their scatter whether its amplitude dependence is measured, `ambid.amplitude.pair_noise_factor`): the same
figures, row for row; the negative controls of seeds 2028-2032 went from 4 of 10 "unexplained" (the coil currents) to
10 of 10 "nothing".  With `EXTRA_NEGATIVE_SEEDS` (seeds 2028-2035 beside 2026-2027, 78 rigs): negative controls 19 of
20; hs_eden_like 2035 said "unexplained" for its I_Z row at chi2/pt 1.61 against the limit 1.59 of its 26 points, the
normal approximation of the cell's chance limit; with the Gamma quantile (`ambid.diagnose.chance_limit`, 1.69 there)
20 of 20, the other figures the same (46, 44, 50, 8 / 8).  Stop 39 (where no cell is above the floor, a candidate
(output rows included) is missing if its evidence with each channel and band weighed by the misfit it leaves there
exceeds `ambid.diagnose.AT_FLOOR_EVIDENCE`; a lead needs that evidence above 10 too): top-1 46 -> 48 of 50 (hs_eden_like's
modal damping 2027, 296 channel by channel, and demo20's cross coupling 2026, 172, now named, with their parameters
within 5 %), parameters 44 -> 46, final misfit 50 of 50, outside 8 / 8 and 8 / 8, negative controls 20 of 20 with a lead
on 3 (was 10; their largest evidence channel by channel 35, plain 126).  The two misses left are demo20 2027's
foundation mode and gyroscopic speed: leads of 49 and 51 channel by channel (the latter a foundation mode), where that
seed's negative control has a foundation-mode lead of 31.  Out of sample (``--first-seed=2040``, the same code):
top-1 50 of 50, parameters 48 (hs_eden_like's sensor shift 13.9 and 17.8 % off on both seeds, about 10 sigma: its
cross channels below 200 Hz carry the describing function's error unfloored, `tests/test_floor.py`'s strict xfail),
final misfit 49 of 50, outside 8 / 8 and 8 / 8, negative controls 19 of 20 (demo20 2045: the I_NX row at chi2/pt 1.53
against 1.5, "unexplained").  Stop 40 (the axial noise from the scatter of log G, `ambid.floor.channel_smooth_fit_ratio`,
and every channel's noise scale from the steps its local fit is centred on): in sample row for row the same verdicts,
top-1 48 of 50, parameters 46, final misfit 50 of 50, outside 8 / 8 and 8 / 8, negative controls 20 of 20 (a lead on
4); out of sample top-1 50 of 50, parameters 48, final misfit 49 of 50, outside 8 / 8 and 8 / 8, negative controls 20
of 20 (demo20 2045 now "nothing").  Stop 41 (the MIMO cross elements at zero amplitude from the four diagonals
through ``U^-1``, `ambid.amplitude._mimo_inversion_errors`): in sample the same figures (48, 46, 50 / 50, 8 / 8, 8 / 8,
20 of 20, a lead on 5); out of sample top-1 50 of 50, parameters 48 -> 50 (hs_eden_like's sensor shift within 5 %),
final misfit 49 -> 50 of 50, outside 8 / 8 and 8 / 8, negative controls 20 of 20 (a lead on 4).  Stop 44 (the
bearing, sensor-position and housing candidates coupled from the receptances of the plant without them,
`ambid.plant.Plant.coupled_response`; the plants of the structure effects an evaluator met kept): in sample the same
figures (48, 46, 50 / 50, 8 / 8, 8 / 8, 20 of 20, a lead on 5; the two misses demo20 2027's foundation mode and
gyroscopic speed, both with a foundation-mode lead); out of sample the same (50, 50, 50 / 50, 8 / 8, 8 / 8, 20 of 20,
a lead on 4); median diagnosis 0.7 s per rig.  Stop 46 (a housing mode also searched in its weak limit,
`ambid.diagnose._weak_housing_start`; the stated standard deviations scored against the errors): in sample the same
figures (48, 46, 50 / 50, 8 / 8, 8 / 8, 20 of 20, a lead on 5: demo20 2027's control now has a foundation-mode lead,
and its gyroscopic miss too); out of sample the same (50, 50, 50 / 50, 8 / 8, 8 / 8, 20 of 20, a lead on 4).  The
stated standard deviations are too small: |error| / std over the top-1 cases' parameters has median 0.86 in sample
(104 parameters) and 0.88 out of sample (102), where honest ones give 0.67, and 79 and 80 % are within 2 std (95 %);
the largest are the eddy-current corner (4.4-5.0 std, 1.1-2.3 % high on all three seeds; the rig's rational
approximation of the half-order lag alone moves the best exact corner by +0.5-0.8 %), a delay, a sensor pole and
demo20's sensor shifts (3.0-3.3 std) in sample, and the cross coupling (11.7 and 22.5 std) and a stiffness scale (7.5
std) out of sample, each within 5 % all the same.  With each stated standard deviation at least the cluster-robust
one (`ambid.diagnose._cluster_variances`, CR2, a channel's points in a band one cluster): the same headline in and
out of sample; median 0.77 and 0.82, within 2 std 83 and 81 %, the largest 3.9 (an eddy-current corner) and 12.7 (a
cross coupling; stop 46 read the ascending list's 7.3 as the largest, so the list now comes largest first).  Stop 47
(each channel's information deflated by its own correlation time, `ambid.diagnose.correlation_time`; the joint
refit's variances plus the model-form spread where the band's parts disagree, `ambid.diagnose._band_disagreement`):
the same headline in and out of sample; median 0.64 and 0.66, within 2 std 90 and 89 %, the largest 3.4 (the three
eddy-current corners, 3.1-3.4, which no part of the band tells apart) and 11.5 (hs_eden_like 2040's cross coupling,
whose parts agree within chance; demo20 2040's, 12.7 before, is 2.1 with the model-form part).  One group size alone
(out of sample): 10 points caught both cross couplings (hs_eden_like's by Q 102.4 against 102.0), 20 neither, 5
only demo20's; so all four sizes, the tail shared.  Stop 48, a third sample (``--first-seed=2050``, negative controls
2050-2059): top-1 47 of 50, parameters 45, final misfit 50 of 50, outside 8 / 8 and 8 / 8, negative controls 17 of 20;
demo20 2051's gyroscopic draw (86 rpm, BIC evidence 325) ended at the candidate's bound of 100 rpm, which the data
resolve far below (three times the floor at 31 rpm on demo20, 3.5 rpm on hs_eden_like); from 1 rpm: top-1 48,
parameters 46, in sample and on 2040-2041 row for row the same.  The three negative controls are the axial position
cell at zero amplitude (`bench_extrapolation.py --cells`): two "unexplained", one ``actuator_coefficients`` missing,
unchanged.  Stop 49, each cell's limit at the points its shares count for (`ambid.amplitude.effective_share`; the
axial cell's 26 points count as about 6): negative controls 20 of 20 on 2050-2059 (hs_eden_like 2052, demo20 2057
and 2059 say "nothing"), every other row of the three samples the same.  Stop 50 (the rig's eddy-current lag fitted
on its relative error, `ambid.effects.half_order_lag_sections`; a cell whose variances are estimates at Fisher's F
limit): the eddy-current corners' errors 0.4-2.3 % -> 0.03-1.4 %, within 2 std 90 / 89 / 92 / 88 % -> 92 / 92 / 95 /
90 % (in sample, 2040, 2050, 2060), none of them beyond 3 std; every other row of the four samples the same.
Stop 51 (zero amplitude: `kappa / G` interpolated where the pairs prefer it, a cross element resolved at some pair
takes the diagonals' prediction; contenders within BIC 10 after the joint refits named indistinguishable): within 2
std 91 / 94 / 98 / 95 %, the gyroscopic speeds of 2040, 2050, 2061 within 0.4 %; top-1 48 / 50 / 48 / 47 (2050 and
2060 measured before the naming of close contenders; 2060's miss a delay named a sensor pole, BIC 12 apart),
parameters 46 / 50 / 46 / 45.
Stop 52 (the stepped sine's amplitude at most half the bias current, ``identification.max_bias_fraction``: at the
thesis' 3 A on demo20's 3 A bias the zero-amplitude FRF kept up to 0.24 % of error, `bench_amplitude_limit.py`):
within 2 std 93 / 94 / 99 / 99 %, beyond 3 std only the input couplings (2040: 9.7, 6.1, 3.0) and two at 3.1; top-1
48 / 50 / 47 / 47 (2060's delay + foundation pair named right, 2050's demo20 2051 gyroscopic now at the floor with
itself as lead), parameters 48 / 49 / 43 / 47 (the misses: modal dampings 8-9 % off with 8-10 % standard deviations,
"determined" below 10 %, and effects at the floor); negative controls 20 of 20, their leads 6 / 4 / 7 / 6 (all but one
a sensor shift, the describing function's look-alike) -> 1 / 0 / 0 / 0.
Stop 53 (the x-y elements at zero amplitude read at each model's input coupling, `ambid.compare.at_input_coupling`;
beside a diagonal's anti-resonance the cross elements take their own pairs, `ambid.amplitude.LINEAR_DELTA`; the
sleeves' load-carrying share in the shear area, which moves hs_eden_like's truth and model alike): the input
couplings of 2040 read 0.02-0.46 % off (0.88-1.24 %) and none of the four samples has one beyond 3 std; within 2 std
93 / 98 / 99 / 99 %, the only value beyond 3 std hs_eden_like 2050's drive-end stack (3.5); top-1 48 / 50 / 47 / 47,
parameters 48 / 49 / 42 / 46 (the new misses 5.04-5.39 % off, within their standard deviations), misfit at the floor
50 of 50 in all four, negative controls 20 of 20 (hs_eden_like 2056 read "unexplained" at 579 Hz with the FEM change
alone, "nothing" with the anti-resonance rule).
Stop 54 (`_swap` refits the chosen effects as they are once, not once per round; bit-identical): every row of the four
samples the same as stop 53's.  A second parameter figure, beside the first: "determined" read as two stated standard
deviations within 5 % (`RESOLVED_SHARE`), else covered by 2 std: 48 / 50 / 47 / 47, every top-1 case (the first
figure 48 / 49 / 42 / 46; its misses: three modal dampings 6.1-8.8 % off, hs_eden_like 2050's housing mode 5.4-5.5 %,
a sensor shift 5.04 % and a weak cross coupling 16.6 %, each inside two of its standard deviations, which exceed 2.5 %).
Logs without repeats, as the thesis' procedure and most other writers make them (``repeat_ratio=null``, in sample):
top-1 42 of 50 (84 %; 5 of the 6 misses at the floor have the hidden effect as lead, hs_eden_like 2026's actuator
coefficients read "unexplained"; hs_eden_like 2026's delay + housing mode read as a 10 kHz sensor pole named
indistinguishable from a delay, an eddy-current lag and an amplifier, BIC 3.4 apart, the housing mode not found, as it
is not alone), parameters 41 / 42, within 2 std
94 % (a gyroscopic speed 4.8 and a sensor shift 3.9 std), misfit at the floor 49 of 50, outside 8 / 8 and 8 / 8,
negative controls 20 of 20 without a lead.
Stop 55 (the noise pooled over five steps at a grid's ends as in its middle; rows as measured state their pooled
estimates' error): top-1 48 / 50 / 46 / 47, parameters 48 / 49 / 42 / 46 and 48 / 50 / 46 / 47, within 2 std
93 / 98 / 99 / 99 % (beyond 3 std hs_eden_like 2050's drive-end stack, 3.5, and 2061's amplifier corner, 3.1, 0.02 %
off), misfit at the floor 50 of 50, outside 8 / 8 and 8 / 8, negative controls 20 of 20 in all four, none with a lead
(demo20 2027's housing-mode lead gone; its gyroscopic miss now has the hidden effect as lead).  The new miss:
hs_eden_like 2051's weak cross coupling (signature 3.6), 117 -> 87 channel by channel, now its lead at the floor.
Stop 57 (the weak end three times the floor the seed's own log without an effect measured, `SIGNATURE`; amplifier and
sensor bandwidths searched to 1 MHz).  The typical floor was not the data's: on hs_eden_like seed 2051 (80 points)
the coil currents' measured floor is about a fiftieth of 0.3 %, and at a diagonal's anti-resonance the positions'
is up to 130 times the typical one.  So effects seen on the currents were drawn far above three floors (that seed's
sensor pole at 22 kHz: 3.4 typical, 26 measured; now 154 kHz at 3.7) and effects by an anti-resonance below one: of
stop 55's misses, hs_eden_like 2051's housing mode (18.7 t at 573 Hz, 11 typical) changes no measured point by more
than 0.4 of its floor, and its weak cross coupling (3.6 typical) reads 1.0.  Drawn on the measured floor, two sensor
poles (147 and 154 kHz, 3.2 and 3.7 floors) ended at the candidates' old bound of 100 kHz with a delay named in their
place; searched to 1 MHz, the delay is named with the pole indistinguishable.  With both (``2 80 1 --suite``, the four
samples run side by side): top-1 49 / 50 / 49 / 50 (98 / 100 / 98 / 100 %; in sample, 2040, 2050, 2060), parameters
46 / 49 / 47 / 50 and 49 / 50 / 49 / 50, within 2 std 95 / 96 / 100 / 99 % (none beyond 3 std), misfit at the floor
50 / 50 / 49 / 50, outside 8 / 8 and 8 / 8, negative controls 20 of 20 without a lead in all four.  The two misses:
hs_eden_like 2027's modal damping (3.2 floors, the truth's evidence 83, 80 channel by channel) at the floor with
itself as lead, and demo20 2050's delay (2.3 us, 3.4 floors, evidence 1550) "unexplained": no band cell is above the
floor but the DY row is (1.514 against 1.5), and a row above the floor kept every candidate from being found
channel by channel.  With a candidate's evidence counted outside the rows above the floor (`ambid.diagnose._Cells`)
the delay is named (2.23 us; 4.1 % off) and every other row of the four samples reads the same (stop 58, all four
re-run on the final code): top-1 49 / 50 / 50 / 50, parameters 46 / 49 / 48 / 50 and 49 / 50 / 50 / 50, within 2 std
95 / 96 / 100 / 99 %, misfit at the floor 50 of 50 in all four.  The at-floor threshold's trade-off: a lower
`AT_FLOOR_EVIDENCE` (25, 50 or 75) names 2027's modal damping too and no negative control's lead.  Diagnosis median 4.0-4.4 s per rig (four suites on two cores);
the default machine's variants take the same time with the wider search (hs_eden_like nominal 16.3 s against 15.8 s
in the same run; stop 58 on an idle machine: hs_eden_like 14.2 / 13.7 / 6.3 / 4.6 / 3.1 s for nominal, amplifier,
updated, delay, actuator, demo20 5.6 and 3.9 s; the thesis case 0.49997, 0.69993, 1.30005, 2.2-2.6 s each).  About
45-50 minutes for the four samples side by side on two cores.
"""

import concurrent.futures
import functools
import os
import sys
import time
from pathlib import Path

import numpy as np
import yaml

import ambid.diagnose
from ambid.compare import (at_input_coupling, effective_shares, for_run, input_coupling, input_coupling_slopes,
                           measured_channels, model_response)
from ambid.diagnose import (AT_FLOOR_EVIDENCE, INDISTINGUISHABLE_BIC, bic_evidence, diagnose, effect_label, misfit,
                            plant_with_effects)
from ambid.effects import EFFECTS, effect_from_config
from ambid.excitation import settings_from_config
from ambid.experiment import hidden_effect_draws, hidden_effect_rig, identify_on_rig, measured_floor
from ambid.floor import FloorSettings
from ambid.io import read_parquet, read_yaml
from ambid.kernels import rerun_pinned
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.plausibility import FRF_SETTINGS

ROOT = Path(__file__).resolve().parents[1]
CONFIG = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
MACHINES = ("hs_eden_like", "demo20")
PAIRS = (("delay", "foundation_mode"), ("amplifier_lowpass", "element_stiffness"), ("modal_damping", "sensor_lowpass"))
#: Negative controls beyond the suite's seeds (stop 38: two seeds per machine hid a false "unexplained" in the coil
#: currents that 4 of 10 further no-effect logs showed): ten per machine with the default two seeds.
EXTRA_NEGATIVE_SEEDS = 8
#: The hidden effects' weak end (`ambid.experiment.hidden_effect_draws`): three times the floor ``"measured"`` in the
#: seed's log without an effect (the issue's "down to three times the data floor"), or ``"typical"``: relative floors
#: of 1 % on positions and 0.3 % on coil currents (the suite's draws until stop 57; ``--signature=typical``).
SIGNATURE = "measured"
#: At-floor thresholds whose first-round choice the suite reports beside `AT_FLOOR_EVIDENCE`'s (`at_floor_choice`).
AT_FLOOR_TRIALS = (25.0, 50.0, 75.0, 100.0)
#: The issue's 5 %; a parameter whose two stated standard deviations exceed it is scored, in a second figure beside
#: the first, by whether they cover the truth (the first reads the joint refit's "determined", below 10 %).
RESOLVED_SHARE = 0.05
OUTSIDE = {
    "amplifier_second_order": {"natural_hz": 1500.0, "damping_ratio": 0.5},
    "sensor_gain": {"axis": "NX", "gain": 1.04},
    "sensor_notch": {"frequency_hz": 420.0, "width_hz": 60.0, "depth": 0.3, "axes": ["DX"]},
    "controller_notch": {"notch_hz": 900.0, "notch_width_hz": 100.0, "notch_depth": 0.1},
}


def machine_config(name, radial_points):
    config = yaml.safe_load((ROOT / "config" / "machines" / f"{name}.yaml").read_text())
    config["frequency_grid"]["radial"]["points"] = radial_points
    config["frequency_grid"]["axial"]["points"] = max(20, radial_points // 3)
    return config


def parameter_truth(draws, name, label):
    """The hidden value behind a joint-refit parameter label ``effect[tag].name[index]``."""
    key = label.split(".", 1)[1]
    index = int(key.split("[")[1].rstrip("]")) if "[" in key else None
    value = draws[name][key.split("[")[0]]
    return value[index] if index is not None and isinstance(value, (tuple, list)) else value


@functools.lru_cache(maxsize=None)
def drawn(machine, seed, radial_points):
    """The hidden-effect draws of a machine and seed, made once per worker process (~15 s each, and the
    identification of the seed's rig without an effect for its floor, `SIGNATURE`)."""
    config = machine_config(machine, radial_points)
    floor = measured_floor(identified(config, [], [], seed)) if SIGNATURE == "measured" else None
    return hidden_effect_draws(config, seed=seed, floor=floor)


def identified(config, effects, unmodelled, seed):
    """The FRF table of a rig hiding ``effects`` and ``unmodelled``, identified as the suite does."""
    settings = settings_from_config(CONFIG["identification"])
    return identify_on_rig(hidden_effect_rig(config, effects, unmodelled=unmodelled), config, settings, seed=seed,
                           floor_settings=FloorSettings.from_config({k: v for k, v in CONFIG["frf"].items()
                                                                     if k not in FRF_SETTINGS}))


def run_case(case):
    """Identify one rig and diagnose its nominal model; the scores of `score`."""
    machine, kind, names, seed, radial_points = case
    config = machine_config(machine, radial_points)
    # (the draws, ~15 s a seed, only where a case hides a library effect: not for the extra negative controls' seeds)
    draws = drawn(machine, seed, radial_points) if kind in ("single", "pair") else {"signature": {}}
    effects = [{"name": n, "parameters": draws[n]} for n in names] if kind in ("single", "pair") else []
    unmodelled = [{"name": names[0], "parameters": OUTSIDE[names[0]]}] if kind == "outside" else []
    started = time.perf_counter()
    try:
        table = identified(config, effects, unmodelled, seed)
    except Exception as error:  # an unstable truth cannot be identified: reported, not scored
        return {"case": case, "error": str(error)}
    identify_s = time.perf_counter() - started
    measured = measured_channels(table)
    started = time.perf_counter()
    # as rule diagnose models a run (the coil-current sampling taken from the data: the rig samples at the start of
    # the cycle)
    model, findings = for_run(machine_from_config(config), measured, {}, "diagnose")
    slopes = input_coupling_slopes(table)
    diagnosis = diagnose(model, measured, shares=effective_shares(table), coupling_slopes=slopes)
    return {"case": case, "draws": draws, "diagnosis": diagnosis, "identify_s": identify_s,
            "diagnose_s": time.perf_counter() - started,
            "truth_evidence": truth_evidence(config, measured, effects, slopes),
            "sampling": model.coil_current_sampling, "run_findings": sorted({f.code for f in findings})}


def truth_evidence(config, measured, effects, slopes=None):
    """What the hidden effects at their true parameters would earn in this log, on the diagnosis' own scale: the
    `~ambid.diagnose.bic_evidence` of their k parameters, overdispersion ``max(1, chi2_truth / N)``.

    The scorer's view (it knows the truth; the diagnosis does not): a draw whose truth does not earn
    ``INDISTINGUISHABLE_BIC`` is not visible in the data, and no honest diagnosis can name it.  NaN without effects.
    """
    if not effects:
        return np.nan
    plant = Plant(machine_from_config(config))
    keys = {key: (frequency,) for key, (frequency, _, _) in measured.items()}
    chi2_nominal, residual = misfit(measured, model_response(plant, keys))
    hidden = [effect_from_config(entry, entry["name"]) for entry in effects]
    chi2_truth, _ = misfit(at_input_coupling(measured, slopes, input_coupling(hidden)),
                           model_response(plant_with_effects(plant, hidden), keys))
    parameters = sum(np.size(value) for entry in effects for value in entry["parameters"].values()
                     if not isinstance(value, str))
    points = residual.size
    return bic_evidence(chi2_nominal, chi2_truth, parameters, points, max(1.0, chi2_truth / points))


def score(result):
    machine, kind, names, seed, _ = result["case"]
    diagnosis = result["diagnosis"]
    chosen = [f.candidate.effect for f in diagnosis.sequence]
    joint = diagnosis.joint.table if diagnosis.joint is not None else None
    at_floor = not diagnosis.cells_after["above_floor"].any()
    lead = diagnosis.lead
    out = {"chosen": ", ".join(chosen) or (f"(lead: {lead.candidate.label} {lead.channel_evidence:.0f})"
                                           if lead is not None else "-"),
           "verdict": diagnosis.verdict, "at_floor": at_floor, "lead": lead.candidate.effect if lead is not None else None,
           "at_floor_choice": {t: at_floor_choice(diagnosis, t) for t in AT_FLOOR_TRIALS}}
    if kind in ("single", "pair"):
        hidden = {effect_label(effect_from_config({"name": n, "parameters": result["draws"][n]}, n)) for n in names}
        named = {f.candidate.label for f in diagnosis.sequence} | {label for f in diagnosis.sequence for label in f.indistinguishable}
        out["top1"] = len(chosen) == len(names) and hidden <= named
        out["lead_is_truth"] = not chosen and lead is not None and lead.candidate.effect in names
        errors, covered, out["z"] = [], True, []
        resolved_ok = True  # the same with "determined" read as resolving 5 %: two stated standard deviations within it
        for name in names:
            rows = joint[(joint["origin"] == "new") & joint["parameter"].str.startswith(name + "[")
                         | joint["parameter"].str.startswith(name + ".")] if joint is not None else []
            for row in (rows.itertuples() if len(rows) else []):
                truth = parameter_truth(result["draws"], name, row.parameter)
                if out["top1"] and row.std > 0:
                    out["z"].append((abs(row.value - truth) / row.std,
                                     f"{machine} {seed} {row.parameter} {row.value:.6g} +- {row.std:.2g} (rig {truth:.6g})"))
                error = abs(row.value / truth - 1) if truth != 0 else abs(row.value)
                if row.determined:
                    errors.append(error)
                else:
                    covered &= abs(row.value - truth) <= 2 * row.std
                resolves = 2 * row.std <= RESOLVED_SHARE * abs(row.value)
                resolved_ok &= error <= RESOLVED_SHARE if resolves else abs(row.value - truth) <= 2 * row.std
        out["worst_error"] = max(errors) if errors else np.nan
        out["parameters_ok"] = out["top1"] and all(e <= 0.05 for e in errors) and covered
        out["parameters_resolved_ok"] = out["top1"] and resolved_ok
    elif kind == "outside":
        bound = any(f.at_bound for f in diagnosis.sequence) or (joint is not None and bool(joint["at_bound"].any()))
        out["no_bound"] = not bound
        expected = "nothing" if names[0] == "controller_notch" else "unexplained"
        out["honest"] = (diagnosis.verdict == "nothing") if expected == "nothing" else not diagnosis.unexplained.empty
    else:
        out["clean"] = diagnosis.verdict == "nothing"
    return out


def at_floor_choice(diagnosis, threshold):
    """The effect a diagnosis that chose nothing at the floor would name first were `AT_FLOOR_EVIDENCE` ``threshold``:
    of its first round's candidates, significant and inside their range, that with the most BIC evidence among those
    earning more than ``threshold`` channel by channel; None where none does, or where the diagnosis chose something or
    some cell (or output row) of the model it fitted on is above the floor.  One round only: what the later rounds
    would add beside it is not known here."""
    if diagnosis.sequence or not diagnosis.base_at_floor or diagnosis.cells_before["above_floor"].any():
        return None
    earning = [f for f in diagnosis.ranked if f.significant and not f.at_bound and f.channel_evidence > threshold]
    return max(earning, key=lambda f: f.evidence).candidate.effect if earning else None


def calibration_text(z):
    """The stated standard deviations against the errors, ``z`` pairs of ``|value - truth| / std`` and a description:
    the median, the share within 2 (0.67 and 95 % if honest) and every one beyond 3, largest first."""
    values = np.array([v for v, _ in z])
    return (f"|error| / std median {np.median(values):.2f} (0.67 if honest), within 2 std {np.mean(values <= 2):.0%} "
            "(95 %); beyond 3 std, largest first:" + "".join(f"\n    {v:5.1f}  {p}" for v, p in sorted(z, reverse=True)
                                                            if v > 3))


def suite(seeds, radial_points, workers):
    cases = []
    for machine in MACHINES:
        for seed in seeds:
            cases += [(machine, "single", (name,), seed, radial_points) for name in sorted(EFFECTS)]
            cases += [(machine, "none", (), seed, radial_points)]
        cases += [(machine, "none", (), max(seeds) + 1 + k, radial_points) for k in range(EXTRA_NEGATIVE_SEEDS)]
        cases += [(machine, "pair", pair, seeds[0], radial_points) for pair in PAIRS]
        cases += [(machine, "outside", (name,), seeds[0], radial_points) for name in OUTSIDE]
    print(f"1. hidden-effect suite: {len(cases)} rigs ({len(MACHINES)} machines, seeds {list(seeds)}, "
          f"{radial_points}-point radial grids, {workers} worker(s))")
    print(f"{'machine':<13} {'seed':>4} {'kind':<8} {'hidden':<36} {'sig':>7} {'truth':>8} {'chosen':<44} "
          f"{'verdict':<11} {'ok':<4} {'err %':>6} {'floor':<5} {'diag s':>6}")
    results = []
    with concurrent.futures.ProcessPoolExecutor(max_workers=workers) as pool:
        for result in pool.map(run_case, cases):
            machine, kind, names, seed, _ = result["case"]
            if "error" in result:
                print(f"{machine:<13} {seed:4d} {kind:<8} {' + '.join(names):<36} rig cannot run: {result['error']}")
                continue
            s = score(result)
            results.append((result, s))
            signature = max([result["draws"]["signature"].get(n, np.nan) for n in names], default=np.nan)
            ok = {"single": "top1", "pair": "top1", "outside": "no_bound", "none": "clean"}[kind]
            flag = "yes" if s[ok] and (kind not in ("single", "pair") or s["parameters_ok"]) else "NO"
            print(f"{machine:<13} {seed:4d} {kind:<8} {' + '.join(names):<36} {signature:7.3g} "
                  f"{result['truth_evidence']:8.3g} {s['chosen'][:44]:<44} "
                  f"{s['verdict']:<11} {flag:<4} {100 * s.get('worst_error', np.nan):6.2f} {str(s['at_floor']):<5} "
                  f"{result['diagnose_s']:6.1f}", flush=True)
    by_kind = lambda k: [s for r, s in results if r["case"][1] == k]  # noqa: E731
    library = by_kind("single") + by_kind("pair")
    print(f"\ntop-1 (or named indistinguishable): {sum(s['top1'] for s in library)} of {len(library)} "
          f"({100 * np.mean([s['top1'] for s in library]):.0f} %; target >= 95 %)")
    visible = [s for r, s in results if r["case"][1] in ("single", "pair") and r["truth_evidence"] > INDISTINGUISHABLE_BIC]
    print(f"  of them visible in their log (the truth earns BIC evidence > {INDISTINGUISHABLE_BIC:g}, column 'truth'): "
          f"{len(visible)}; top-1 among those: {sum(s['top1'] for s in visible)} "
          f"({100 * np.mean([s['top1'] for s in visible]) if visible else np.nan:.0f} %)")
    unnamed = [s for s in library if not s["top1"] and s["verdict"] in ("nothing", "retune")]
    print(f"  misses at the floor (nothing chosen) whose lead is the hidden effect (not counted above): "
          f"{sum(s['lead_is_truth'] for s in unnamed)} of {len(unnamed)}")
    print(f"parameters within 5 % where determined, else covered by 2 std: {sum(s['parameters_ok'] for s in library)} "
          f"of {len(library)}")
    print(f"  the same where the stated standard deviation resolves {100 * RESOLVED_SHARE:g} % (2 std within it), else "
          f"covered by 2 std: {sum(s['parameters_resolved_ok'] for s in library)} of {len(library)}")
    z = [(value, parameter) for s in library for value, parameter in s.get("z", [])]
    if z:
        print(f"  stated standard deviations against the errors, {len(z)} parameters of the top-1 cases: "
              + calibration_text(z))
    print(f"final misfit at the floor (no cell above it after the joint refit): {sum(s['at_floor'] for s in library)} "
          f"of {len(library)}")
    print(f"the at-floor threshold (`ambid.diagnose.AT_FLOOR_EVIDENCE`, {AT_FLOOR_EVIDENCE:g}) tried lower on these "
          "diagnoses, one round only (what a first effect so named would bring beside it is not known):")
    singles = [(r["case"][2][0], s) for r, s in results if r["case"][1] == "single"]  # (hidden effect, scores)
    negatives = by_kind("none")
    for threshold in AT_FLOOR_TRIALS:
        gained = sum(not s["top1"] and s["at_floor_choice"][threshold] == name for name, s in singles)
        wrong = sum(not s["top1"] and s["at_floor_choice"][threshold] not in (None, name) for name, s in singles)
        false = sum(s["at_floor_choice"][threshold] is not None for s in negatives)
        print(f"  {threshold:5g}: top-1 {sum(s['top1'] for s in library) + gained} of {len(library)} "
              f"({gained} single draw(s) named at the floor, {wrong} named wrong), negative controls with something "
              f"missing {false} of {len(negatives)}")
    outside = by_kind("outside")
    print(f"outside the library: nothing at a bound in {sum(s['no_bound'] for s in outside)} of {len(outside)}, "
          f"honest verdict (unexplained, or nothing for the invisible controller notch) in "
          f"{sum(s['honest'] for s in outside)} of {len(outside)}")
    print(f"negative controls with nothing missing: {sum(s['clean'] for s in negatives)} of {len(negatives)} "
          f"(with a lead: {', '.join(s['lead'] for s in negatives if s['lead']) or 'none'})")
    sampling = [r["sampling"] for r, _ in results]
    print(f"coil-current sampling taken from the data: start_of_cycle (the rig's) on "
          f"{sampling.count('start_of_cycle')} of {len(sampling)} rigs; run findings: "
          + (", ".join(f"{r['case'][0]} {r['case'][3]} {'+'.join(r['case'][2]) or 'none'}: {', '.join(r['run_findings'])}"
                       for r, _ in results if r["run_findings"]) or "none"))
    times = [r["diagnose_s"] for r, _ in results]
    print(f"diagnosis wall time per rig: median {np.median(times):.1f} s, max {np.max(times):.1f} s\n")


def thesis_case(radial_points):
    print("2. thesis ch. 5.3: demo20, elements 5-8 at another stiffness (full grid)")
    config = yaml.safe_load((ROOT / "config" / "machines" / "demo20.yaml").read_text())
    settings = settings_from_config(CONFIG["identification"])
    for scale in (0.5, 0.7, 1.3):
        rig = hidden_effect_rig(config, [{"name": "element_stiffness", "parameters": {"tag": "design", "scale": scale}}])
        table = identify_on_rig(rig, config, settings, seed=11)
        measured = measured_channels(table)
        started = time.perf_counter()
        diagnosis = diagnose(machine_from_config(config), measured, shares=effective_shares(table))
        wall = time.perf_counter() - started
        first = diagnosis.sequence[0].candidate.label if diagnosis.sequence else "-"
        value = diagnosis.joint.table.set_index("parameter")["value"].get("element_stiffness[design].scale", np.nan) \
            if diagnosis.joint is not None else np.nan
        print(f"  scale {scale}: first {first}, fitted {value:.5f} ({100 * (value / scale - 1):+.2f} %), verdict "
              f"{diagnosis.verdict}, {wall:.1f} s")
    print()


def default_machines():
    print(f"3. the diagnosis rule's work on the workflow's variants (BLAS threads: {os.environ.get('OPENBLAS_NUM_THREADS', 'default')})")
    for machine, run, target in (("hs_eden_like", "ident01", 30.0), ("demo20", "thesis01", 15.0)):
        frf = ROOT / "results" / machine / "frf" / run / "frf.parquet"
        if not frf.exists():
            print(f"  {frf} missing: run `make run` first")
            continue
        table, _ = read_parquet(frf, kind="frf")
        measured = measured_channels(table)
        for variant in ["nominal"] + list(CONFIG["machines"][machine].get("variants") or {}):
            model = machine_from_config(read_yaml(ROOT / "results" / machine / "model" / variant / "machine.yaml"))
            started = time.perf_counter()
            diagnosis = diagnose(model, measured, shares=effective_shares(table),
                                 coupling_slopes=input_coupling_slopes(table))
            wall = time.perf_counter() - started
            said = diagnosis.summary()
            print(f"  {machine:<13} {variant:<10} {wall:6.1f} s [target <= {target:.0f} s: {'ok' if wall <= target else 'MISSED'}]"
                  f"  chi2/pt {said['chi2_per_point_before']:.4g} -> {said['chi2_per_point_after']:.4g}  {said['verdict']}: "
                  f"{said['effects'] or said['retune'] or said['unexplained'] or '-'}")
    print()


if __name__ == "__main__":
    rerun_pinned()  # the same figures on every x86-64 CPU (ambid.kernels)
    # --first-seed=N: the suite on seeds N, N + 1, ... (new draws of every hidden effect: out of sample)
    first = next((int(a.split("=", 1)[1]) for a in sys.argv if a.startswith("--first-seed=")), 2026)
    seeds = range(first, first + (int(sys.argv[1]) if len(sys.argv) > 1 else 2))
    points = int(sys.argv[2]) if len(sys.argv) > 2 else 120
    workers = int(sys.argv[3]) if len(sys.argv) > 3 else 1
    only_suite = "--suite" in sys.argv
    for option in (a for a in sys.argv if a.startswith("--signature=")):
        SIGNATURE = option.split("=", 1)[1]
        if SIGNATURE not in ("measured", "typical"):
            sys.exit(f"--signature={SIGNATURE}: measured or typical")
        print(f"hidden effects drawn down to three times the {SIGNATURE} floor")
    # --at-floor-evidence=N: the diagnosis' at-floor threshold set to N for this run (a what-if, as key=value below)
    for option in (a for a in sys.argv if a.startswith("--at-floor-evidence=")):
        ambid.diagnose.AT_FLOOR_EVIDENCE = AT_FLOOR_EVIDENCE = float(option.split("=", 1)[1])
        print(f"ambid.diagnose.AT_FLOOR_EVIDENCE = {AT_FLOOR_EVIDENCE:g}")
    for option in sys.argv[4:]:  # what-ifs on the config: settle_min_s=1.0 (identification), zero_amplitude=false (frf)
        if "=" in option and not option.startswith("--"):
            key, value = option.split("=", 1)
            section = "frf" if key in FloorSettings.__dataclass_fields__ else "identification"
            CONFIG[section][key] = yaml.safe_load(value)
            if key == "settle_min_s":
                CONFIG["identification"]["settle_max_s"] = max(CONFIG["identification"]["settle_max_s"], float(value))
            print(f"config {section}.{key} = {CONFIG[section][key]}")
    if not only_suite:
        default_machines()
        thesis_case(points)
    suite(list(seeds), points, workers)
