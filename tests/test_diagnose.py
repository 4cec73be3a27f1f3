"""Diagnosis: candidates, their global fit, significance, joint refit, verdicts; the thesis case and hidden effects on rigs.

Unit tests use synthetic measurements (the model's own response plus complex
noise of a known standard deviation).  The rig tests hide effects in virtual
rigs of both default machines (`ambid.experiment`), identify them with the
stepped sine (repeated steps included, so the floor is measured) and diagnose
the nominal model from the FRF table alone: the model side never sees the rig.
The full suite (two machines, every effect, several seeds, pairs, effects
outside the library, negative controls) is `benchmarks/bench_diagnose.py`;
this file runs one seed of it, on shorter grids from 5 Hz (`small_grid`).
"""

import functools
import re
import unittest.mock
from dataclasses import replace

import numpy as np
import scipy.stats
import pandas as pd
import pytest
import yaml

from ambid.compare import PointShares, channel_errors, effective_shares, measured_channels, model_response, summarize
from ambid.diagnose import (AT_FLOOR_EVIDENCE, CELL_TAIL, Candidate, DiagnoseError, DiagnoseSettings, FreeParameter,
                            _Cells, _Evaluator, _covariance, _fit, _least_bic, _prune, _weak_housing_start, bic_evidence,
                            candidate_space, chance_limit, diagnose, effect_label, joint_refit, misfit, misfit_cells,
                            misfit_peaks, plant_with_effects)
from ambid.diagnosis_report import AMPLITUDE_ERROR_ALIKE, diagnosis_findings, diagnosis_report, effects_config_lines
from ambid.effects import EFFECTS, effect_from_config
from ambid.excitation import settings_from_config
from ambid.experiment import effect_signature, hidden_effect_draws, hidden_effect_rig, identify_on_rig, measured_floor
from ambid.fingerprint import fingerprint
from ambid.floor import FloorSettings
from ambid.machine import machine_from_config
from ambid.plant import Plant

from conftest import ROOT, load_machine_config


def effect(name, **parameters):
    return effect_from_config({"name": name, "parameters": parameters}, name)


def synthetic_measurement(machine, effects=(), relative_noise=1e-3, seed=0, reported=1.0):
    """Measured channels of ``machine`` plus ``effects``, with complex noise of a known std (reported times ``reported``)."""
    plant = Plant(machine.with_effects(machine.effects + tuple(effects)))
    frequency = machine.radial_grid.frequency_hz
    axes = ("DX", "DY", "NX", "NY")
    template = {(o, i): (frequency, None, None) for o in axes for i in axes}
    template.update({(f"I_{a}", a): (frequency, None, None) for a in axes})
    truth = model_response(plant, template)
    rng = np.random.default_rng(seed)
    out = {}
    scale = {kind: max(np.max(np.abs(v)) for k, v in truth.items() if k[0].startswith("I_") == kind) for kind in (False, True)}
    for key, values in truth.items():
        std = relative_noise * np.maximum(np.abs(values), 1e-3 * scale[key[0].startswith("I_")])
        noise = std * (rng.standard_normal(values.size) + 1j * rng.standard_normal(values.size)) / np.sqrt(2)
        out[key] = (frequency, values + noise, reported * std)
    return out


@pytest.fixture(scope="module")
def demo(demo_machine):
    return demo_machine


# --------------------------------------------------------------------------------------------- units
def test_candidates_cover_the_library_and_their_bounds(demo):
    candidates = candidate_space(demo)
    assert {c.effect for c in candidates} == set(EFFECTS)
    for candidate in candidates:
        for parameter in candidate.free:
            assert parameter.lower < parameter.upper
            spec = EFFECTS[candidate.effect].parameters[parameter.name]
            assert spec.lower is None or parameter.lower >= spec.lower
        candidate.build([p.start_value for p in candidate.free]).check(demo)  # a valid effect inside its range


def test_delay_recovered_on_synthetic_data_and_nothing_else_missing(demo):
    measured = synthetic_measurement(demo, [effect("delay", delay_s=8e-5)])
    diagnosis = diagnose(demo, measured)
    assert diagnosis.verdict == "missing"
    assert [f.candidate.label for f in diagnosis.sequence] == ["delay"]
    joint = diagnosis.joint.table.set_index("parameter")
    assert joint.loc["delay.delay_s", "value"] == pytest.approx(8e-5, rel=1e-3)
    assert joint.loc["delay.delay_s", "std"] < 1e-6
    assert diagnosis.chi2 / diagnosis.points > 100
    assert diagnosis.joint.chi2 / diagnosis.points == pytest.approx(1.0, abs=0.1)  # down to the noise
    assert not diagnosis.cells_after["above_floor"].any()
    table = diagnosis.table()
    assert list(table.columns[:4]) == ["rank", "candidate", "effect", "parameters"]
    assert table.loc[0, "share_above_floor"] > 0.99


def test_a_slow_rotation_the_data_resolve_is_named_not_held_at_a_bound(demo):
    # demo20 at 40 rpm: the gyroscopic term is proportional to the speed and these data resolve it; with the search
    # starting at 100 rpm (before stop 48) the fit ended at that bound and the misfit was called unexplained
    measured = synthetic_measurement(demo, [effect("gyroscopic", speed_rpm=40.0)])
    measured = {key: tuple(v[::5] for v in values) for key, values in measured.items()}
    diagnosis = diagnose(demo, measured)
    assert diagnosis.verdict == "missing" and [f.candidate.label for f in diagnosis.sequence] == ["gyroscopic"]
    row = diagnosis.joint.table.set_index("parameter").loc["gyroscopic.speed_rpm"]
    assert not row["at_bound"] and abs(row["value"] - 40.0) <= 2 * row["std"] and row["std"] < 0.01 * 40.0


def test_nothing_missing_on_the_model_itself(demo):
    diagnosis = diagnose(demo, synthetic_measurement(demo))
    assert diagnosis.chi2 / diagnosis.points == pytest.approx(1.0, abs=0.1)
    assert diagnosis.verdict == "nothing" and diagnosis.best is None and not diagnosis.sequence


def test_a_floor_a_little_low_does_not_make_anything_missing(demo):
    # the reported uncertainty 15 % below the truth: chi2 per point about 1.3, still inside the floor band; fitting the
    # noise would win thousands of BIC points but nothing may be "missing" there
    diagnosis = diagnose(demo, synthetic_measurement(demo, reported=0.87, seed=3))
    assert 1.15 < diagnosis.chi2 / diagnosis.points < 1.5
    assert diagnosis.verdict == "nothing", diagnosis.table()


def test_a_parameter_at_its_bound_is_never_missing_and_the_misfit_is_unexplained(demo):
    # a 20 Hz current loop lies below the amplifier candidate's range (50 Hz - 1 MHz): its best fit runs into the bound
    measured = synthetic_measurement(demo, [effect("amplifier_lowpass", cutoff_hz=20.0)])
    amplifier_only = [c for c in candidate_space(demo) if c.label == "amplifier_lowpass"]
    diagnosis = diagnose(demo, measured, candidates=amplifier_only)
    fitted = diagnosis.ranked[0]
    assert fitted.significant and fitted.at_bound == ("cutoff_hz",)
    assert not fitted.missing
    assert diagnosis.verdict == "unexplained"
    assert not diagnosis.unexplained.empty
    codes = {f.code for f in diagnosis_findings(diagnosis)}
    assert {"unexplained_misfit", "candidate_at_bound"} <= codes


def test_joint_refit_moves_what_the_variant_has_wrong(demo):
    # the model carries an amplifier at 1775 Hz, the truth has 1800 Hz and a delay: the delay is missing, and the
    # joint refit puts the amplifier where the data want it (as the stepwise fits could not)
    truth = [effect("amplifier_lowpass", cutoff_hz=1800.0), effect("delay", delay_s=6e-5)]
    measured = synthetic_measurement(demo, truth)
    model = demo.with_effects((effect("amplifier_lowpass", cutoff_hz=1775.0),))
    diagnosis = diagnose(model, measured)
    assert [f.candidate.label for f in diagnosis.sequence] == ["delay"]
    joint = diagnosis.joint.table.set_index("parameter")
    assert joint.loc["amplifier_lowpass.cutoff_hz", "origin"] == "variant"
    assert joint.loc["amplifier_lowpass.cutoff_hz", "value"] == pytest.approx(1800.0, rel=2e-3)
    assert joint.loc["delay.delay_s", "value"] == pytest.approx(6e-5, rel=2e-3)
    assert "amplifier_lowpass.cutoff_hz" in set(diagnosis.retune["parameter"])
    assert not diagnosis.cells_after["above_floor"].any()
    correlation = diagnosis.joint.correlation
    assert correlation.shape == (2, 2) and np.allclose(np.diag(correlation), 1.0)
    # a retune that ends at its search bound is said to be a limit, on the page and in the findings
    diagnosis.retune = diagnosis.retune.assign(at_bound=True)
    _, page = diagnosis_report(diagnosis, Plant(model), measured, None, "retune at a bound")
    assert "amplifier_lowpass.cutoff_hz`: 1775 -> " in page and "at its search bound" in page
    retunes = [f for f in diagnosis_findings(diagnosis) if f.code == "retune"]
    assert retunes and all("at its search bound" in f.message for f in retunes)


def test_a_variant_within_the_floor_retunes_its_own_parameter_instead_of_adding_a_second(demo):
    # the model carries a modal damping of 0.0048, the truth 0.005: every cell within the floor, and the data determine
    # the damping to 0.2 %; the same effect on top of the variant's own is degenerate with it (hs_eden_like's `actuator`
    # variant: "missing: modal_damping 0.00014 +- 0.0078" on top of its own 0.00786, each undetermined alone)
    measured = synthetic_measurement(demo, [effect("modal_damping", damping_ratio=0.005)], relative_noise=1e-2, seed=3)
    model = demo.with_effects((effect("modal_damping", damping_ratio=0.0048),))
    diagnosis = diagnose(model, measured)
    assert not diagnosis.cells_before["above_floor"].any()
    assert diagnosis.verdict == "retune" and not diagnosis.sequence
    joint = diagnosis.joint.table.set_index("parameter")
    assert list(joint.index) == ["modal_damping.damping_ratio"]
    assert abs(joint.loc["modal_damping.damping_ratio", "value"] - 0.005) <= 2 * joint.loc["modal_damping.damping_ratio", "std"]
    assert joint.loc["modal_damping.damping_ratio", "relative_std"] < 0.01
    assert diagnosis.retune_evidence > AT_FLOOR_EVIDENCE
    _, page = diagnosis_report(diagnosis, Plant(model), measured, None, "retune within the floor")
    assert "lies within the floor, but its own parameters refitted earn BIC evidence" in page
    # a variant that has it right is not retuned: the refit earns nothing at the floor
    right = diagnose(demo.with_effects((effect("modal_damping", damping_ratio=0.005),)), measured)
    assert right.verdict == "nothing" and right.joint is None


def test_a_candidate_masked_by_a_larger_misfit_is_searched_afresh():
    """hs_eden_like with a 5776 Hz current loop and the DE bearing's elements 1.14 % stiffer (the suite's pair draw,
    on the DE side), on the suite's 80-point grid: judged against the amplifier's misfit, the DE stiffness barely
    pays.  Once the amplifier is chosen that misfit is gone; refined from where it ended (or not tried again), the
    stiffness was named on the motor with a sensor shift beside it (noncollocation).  Searched afresh, the pair is
    named alone and the scale recovered."""
    machine = machine_from_config(small_grid("hs_eden_like"))
    truth = [effect("amplifier_lowpass", cutoff_hz=5776.0), effect("element_stiffness", tag="de_amb", scale=1.0114)]
    diagnosis = diagnose(machine, synthetic_measurement(machine, truth, relative_noise=3e-3))
    assert sorted(f.candidate.label for f in diagnosis.sequence) == ["amplifier_lowpass", "element_stiffness[de_amb]"]
    joint = diagnosis.joint.table.set_index("parameter")
    assert joint.loc["element_stiffness[de_amb].scale", "value"] == pytest.approx(1.0114, rel=1e-3)
    assert joint.loc["amplifier_lowpass.cutoff_hz", "value"] == pytest.approx(5776.0, rel=0.01)


def test_a_weaker_effect_beside_one_that_brings_the_model_to_the_floor_is_still_searched():
    """demo20 with a 6809 Hz current loop and its design elements 0.11 % softer (the suite's draw 2060), 1 % noise:
    once the amplifier is chosen every cell is within the floor, and the selection stopped there; the stiffness, on top
    of the amplifier, earns what a missing effect at the floor needs channel by channel (`AT_FLOOR_EVIDENCE`), so it is
    searched and named (stop 49)."""
    machine = machine_from_config(small_grid("demo20"))
    truth = [effect("amplifier_lowpass", cutoff_hz=6809.0), effect("element_stiffness", tag="design", scale=0.99886)]
    diagnosis = diagnose(machine, synthetic_measurement(machine, truth, relative_noise=1e-2))
    assert [f.candidate.label for f in diagnosis.sequence] == ["amplifier_lowpass", "element_stiffness[design]"]
    assert diagnosis.sequence[1].share == 0 and diagnosis.sequence[1].channel_evidence > AT_FLOOR_EVIDENCE
    scale = diagnosis.joint.table.set_index("parameter").loc["element_stiffness[design].scale"]
    assert abs(scale["value"] - 0.99886) < 2 * scale["std"], scale


def test_joint_refit_keeps_what_the_data_do_not_determine(demo):
    # the model's own modal damping of 0.01 is barely seen by a measurement that stops below the first mode:
    # the prior keeps it within its own uncertainty of the configured value and the table says it is undetermined
    measured = synthetic_measurement(demo)
    low = {key: tuple(v[:40] for v in values) for key, values in measured.items()}  # below ~160 Hz
    model = demo.with_effects((effect("modal_damping", damping_ratio=0.01),))
    joint = joint_refit(model, low)
    row = joint.table.set_index("parameter").loc["modal_damping.damping_ratio"]
    assert not row["determined"] and row["relative_std"] > 0.3
    assert row["data_relative_std"] >= row["relative_std"]  # "determined" asks the data alone, without the prior
    assert abs(np.log(row["value"] / 0.01)) < 2 * row["relative_std"]
    # the posterior's: the precisions of the prior (width 1 on the log scale) and of the data add (measured 0.635
    # against 0.615; before stop 46 the prior counted twice, 0.52)
    assert row["relative_std"] == pytest.approx((1 / DiagnoseSettings().prior_width**2
                                                 + 1 / row["data_relative_std"]**2) ** -0.5, rel=0.05)


def test_joint_refit_of_an_update_moves_along_what_the_data_determine(demo):
    # thesis ch. 5.3: an update's per-element moduli of elements 5-8 are determined in combinations, not one by one; the
    # truth has the group at 0.6, the variant each element at 1. The refit follows the combinations the data determine
    # (found afresh at each outer step; the full-space refit this replaced stopped at chi2/pt 1.7e6) under a prior
    # weighed against the data as deflated by the misfit left: without that weight the first steps, made far above the
    # floor, ran to a local minimum at chi2/pt 1.23 with "determined" moduli 0.92, 0.30, 21 and 0.45
    measured = synthetic_measurement(demo, [effect("element_stiffness", tag="design", scale=0.6)])
    model = demo.with_effects((effect("element_stiffness", tag="design", scale=(1.0, 1.0, 1.0, 1.0)),))
    before = misfit(measured, model_response(Plant(model), measured))[0]
    joint = joint_refit(model, measured)
    points = sum(v[1].size for v in measured.values())
    assert before > 100 * points
    assert joint.chi2 < 1.1 * points
    table = joint.table
    assert len(table) == 4 and not (table["at_bound"] & table["determined"]).any(), table
    for row in table.itertuples():  # each modulus at the truth within three of its standard deviations, or undetermined
        assert not row.determined or abs(row.value - 0.6) < 3 * row.std, table


def test_joint_refit_also_descends_from_an_alternative_start(demo):
    # an update from a run of another band can leave the moduli where this run's modes are out of reach of a local
    # descent (hs_eden_like's ms01 from ident01's update: chi2 per point 1.12 and a foundation mode named at 1.6 kHz).
    # Here the variant has the design elements at 3 (the descent from there ends at chi2/pt 7.6e6); the run's own update
    # has them near the truth, 0.6
    measured = synthetic_measurement(demo, [effect("element_stiffness", tag="design", scale=0.6)])
    points = sum(v[1].size for v in measured.values())
    model = demo.with_effects((effect("element_stiffness", tag="design", scale=(3.0, 3.0, 3.0, 3.0)),))
    alone = joint_refit(model, measured)
    assert alone.chi2 > 100 * points and alone.began_at == ()
    own_update = [effect("element_stiffness", tag="design", scale=(0.62, 0.58, 0.61, 0.6))]
    joint = joint_refit(model, measured, alternatives=[("run 2's own update", own_update)])
    assert joint.chi2 < 1.1 * points
    name, there, other, at_other = joint.began_at
    before = misfit(measured, model_response(Plant(model), measured))[0]
    assert name == "run 2's own update" and other == "the model's values"
    assert at_other == pytest.approx(before, rel=1e-9) and there < at_other
    table = joint.table.set_index("parameter")
    assert table["start"].to_numpy() == pytest.approx(3.0)  # the prior and the "before" column stay the variant's
    # an alternative that ends worse changes nothing
    worse = joint_refit(model, measured, alternatives=[("elsewhere", [effect("element_stiffness", tag="design",
                                                                              scale=(0.1, 0.1, 0.1, 0.1))])])
    assert worse.began_at == () and worse.chi2 == alone.chi2
    # where the first descent reaches the floor, no other is tried (the alternative's start is evaluated once, to
    # order the starts by their posterior)
    at_truth = demo.with_effects((effect("element_stiffness", tag="design", scale=(0.6, 0.6, 0.6, 0.6)),))
    plain = joint_refit(at_truth, measured)
    offered = joint_refit(at_truth, measured, alternatives=[("run 2's own update", own_update)])
    assert offered.began_at == () and offered.chi2 == plain.chi2 and offered.evaluations == plain.evaluations + 1


def test_a_diagnosis_from_an_alternative_start_says_so(demo):
    # the same variant diagnosed with the run's own update as the alternative: its moduli retuned to the truth, and the
    # report says where the refit came from
    measured = synthetic_measurement(demo, [effect("element_stiffness", tag="design", scale=0.6)])
    measured = {key: tuple(v[::5] for v in values) for key, values in measured.items()}
    model = demo.with_effects((effect("element_stiffness", tag="design", scale=(3.0, 3.0, 3.0, 3.0)),))
    own_update = [effect("element_stiffness", tag="design", scale=(0.62, 0.58, 0.61, 0.6))]
    diagnosis = diagnose(model, measured, alternatives=[("run 2's own update", own_update)])
    assert diagnosis.verdict == "retune" and diagnosis.summary()["chi2_per_point_after"] < 1.1
    # the four design elements are 92-99 % correlated (1000 points): each is stated to 1.6-5 %, and where a machine's
    # last digits end the descent along that valley differs; each value is inside two of its standard deviations and
    # their mean, which the data do fix, within 1 %
    retune = diagnosis.retune
    assert len(retune) == 4 and np.all(np.abs(retune["value"] - 0.6) <= 2 * retune["std"])
    assert retune["value"].mean() == pytest.approx(0.6, rel=0.01)
    _, text = diagnosis_report(diagnosis, Plant(model), measured, None, "demo20, run 2, model far")
    assert "had two starts, run 2's own update and the model's values" in text
    assert "The refit kept its descent from run 2's own update" in text  # beside the moved values: set them all
    assert "alternative_start" in {f.code for f in diagnosis_findings(diagnosis)}


def test_an_effect_the_later_choices_explain_is_dropped(demo):
    # forward selection can choose an effect that only stands in for one chosen after it (demo20's multisine run: an
    # eddy-current corner before the delay, at 70 +- 62 kHz in the joint refit); weighed against the others refitted
    # without it, it is no longer missing and goes, and the joint refit without it puts the delay back at the truth
    measured = synthetic_measurement(demo, [effect("delay", delay_s=5e-5)])
    measured = {key: tuple(v[::5] for v in values) for key, values in measured.items()}
    cells = _Cells(measured)
    evaluator = _Evaluator(Plant(demo), measured, cells)
    space = {c.label: c for c in candidate_space(demo)}
    chosen = [_fit(evaluator, space["eddy_current"]), _fit(evaluator, space["delay"])]
    joint = joint_refit(demo, measured, chosen, cells=cells)
    kept, refit, dropped = _prune(demo, measured, chosen, DiagnoseSettings(), cells, joint)
    assert [f.candidate.label for f in kept] == ["delay"]
    assert [label for label, _, _ in dropped] == ["eddy_current"] and dropped[0][1] < 10
    assert refit.effects[0].values["delay_s"] == pytest.approx(5e-5, rel=1e-3)
    # nothing to drop: the same joint back
    assert _prune(demo, measured, kept, DiagnoseSettings(), cells, refit)[1] is refit


def test_config_lines_round_trip_exactly(demo):
    fitted = effect("foundation_mode", mass_kg=12.345678901234, frequency_hz=345.6789012345)
    lines = effects_config_lines([fitted])
    assert lines.startswith("effects:")
    parsed = yaml.safe_load(lines)["effects"][0]
    rebuilt = effect_from_config(parsed, "effects[0]", demo)
    assert rebuilt.values == fitted.values  # every digit: adding it reproduces the diagnosed model
    tiny = effect("element_stiffness", tag="design", scale=1.00043)
    assert yaml.safe_load(effects_config_lines([tiny]))["effects"][0]["parameters"]["scale"] == 1.00043
    assert "axes" not in effects_config_lines([effect("delay", delay_s=1e-4)])  # the default is left out


def test_fingerprint_names_a_linear_phase_lag_and_a_sensor_gain(demo):
    measured = synthetic_measurement(demo, [effect("delay", delay_s=1e-4)])
    errors = channel_errors(measured, model_response(Plant(demo), measured))
    text = " ".join(fingerprint(errors, summarize(errors)))
    assert "grows linearly with frequency" in text
    assert "delay of 100 us" in text
    assert "coil-current channels the model matches" in text
    # a sensor reading 4 % high on NX: every channel with NX as output is off by the same gain, no phase
    measured = synthetic_measurement(demo)
    measured = {key: (f, values * (1.04 if key[0] == "NX" else 1.0), std) for key, (f, values, std) in measured.items()}
    errors = channel_errors(measured, model_response(Plant(demo), measured))
    text = " ".join(fingerprint(errors, summarize(errors)))
    assert "gain error of the NX sensor" in text
    assert "-0.34 dB" in text


def test_cells_and_report(demo):
    measured = synthetic_measurement(demo, [effect("delay", delay_s=8e-5)])
    cells = misfit_cells(measured, model_response(Plant(demo), measured))
    assert set(cells["family"]) == {"positions", "currents"}
    assert cells.loc[cells["family"] == "positions", "above_floor"].any()
    assert not cells.loc[cells["family"] == "currents", "above_floor"].any()  # a delay acts on the positions only
    diagnosis = diagnose(demo, measured)
    table, text = diagnosis_report(diagnosis, Plant(demo), measured, None, "demo20 test")
    assert "**Missing: `delay`" in text and "## Joint refit" in text and "```yaml" in text
    assert "helps_channels" in table.columns


def test_plants_kept_by_their_structure_give_the_same_response(demo):
    """An evaluator keeps the plants of the structure effects it has met (`plant_with_effects`' ``structures``) and
    puts the bearings', sensors' and housings' effects on top of the others' plant, coupled from its receptances: the
    response must be the plant's built afresh with all the effects, and the plants kept are bounded."""
    from ambid.diagnose import STRUCTURES_KEPT

    base = Plant(demo)
    frequency = demo.radial_grid.frequency_hz
    template = {(o, i): (frequency, None, None) for o in ("DX", "NX") for i in ("DX", "NX")}
    template.update({("I_DX", "DX"): (frequency, None, None)})
    structures = {}
    for k in range(2 * STRUCTURES_KEPT):
        effects = [effect("element_stiffness", tag="design", scale=0.9 + 0.01 * (k % 3)),
                   effect("delay", delay_s=1e-5 * (1 + k)),
                   effect("actuator_coefficients", force_constant_scale=[1.0 + 0.01 * k, 1.0, 0.98, 1.0, 1.0]),
                   effect("noncollocation", de_offset_m=0.001 * k, nde_offset_m=0.0),
                   effect("foundation_mode", frequency_hz=300.0 + 10 * k, mass_kg=5.0, damping_ratio=0.02)]
        kept = model_response(plant_with_effects(base, effects, structures), template)
        afresh = model_response(Plant(demo.with_effects(demo.effects + tuple(effects))), template)
        for key in template:
            assert np.max(np.abs(kept[key] - afresh[key])) < 1e-9 * np.max(np.abs(afresh[key]))
        assert len(structures) <= STRUCTURES_KEPT
    # a rotor's plant is met again while it is kept: built once, the bearings, sensors and housings coupled on top
    assert any(len(key) == 1 for key in structures) and any(len(key) == 2 for key in structures)


def _linear_fit(jacobian, error):
    """Least squares of a linear model on complex errors: the estimate, the complex residual and its chi2."""
    data = np.concatenate([error.real, error.imag])
    x = np.linalg.lstsq(jacobian, data, rcond=None)[0]
    residual = data - jacobian @ x
    residual = residual[: error.size] + 1j * residual[error.size:]
    return x, residual, float(np.vdot(residual, residual).real)


def _clustered_least_squares(shared, draws=400, clusters=30, size=20, seed=1):
    """A linear least squares of 3 parameters on ``clusters`` x ``size`` complex points at the floor (variance 1/2 per
    component) plus, with ``shared``, an error common to each cluster's points (rms ``shared`` per component): the
    estimates' scatter over ``draws``, and the mean variances `_covariance` states without and with the clusters."""
    rng = np.random.default_rng(seed)
    points = clusters * size
    index = np.repeat(np.arange(clusters), size)
    frequency = np.linspace(0.0, 1.0, points)
    # a smooth design, as a model's slopes over frequency are
    jacobian = np.stack([np.ones(2 * points), np.tile(frequency, 2), np.concatenate([np.sin(3 * frequency),
                                                                                  np.cos(3 * frequency)])], axis=1)
    estimates, plain, robust = [], [], []
    for _ in range(draws):
        error = (rng.standard_normal(points) + 1j * rng.standard_normal(points)) / np.sqrt(2)
        error = error + shared * (rng.standard_normal(clusters) + 1j * rng.standard_normal(clusters))[index]
        x, residual, chi2 = _linear_fit(jacobian, error)
        estimates.append(x)
        plain.append(np.diag(_covariance(jacobian, chi2, points, 3)))
        robust.append(np.diag(_covariance(jacobian, chi2, points, 3, clusters=index, residual=residual)))
    return np.var(estimates, axis=0), np.mean(plain, axis=0), np.mean(robust, axis=0)


def test_the_stated_variances_hold_errors_a_channel_and_band_share():
    """The floor's systematic part is shared by a channel's points in a band (a cluster).  With errors independent
    from point to point, the cluster-robust variances (CR2, `_cluster_variances`) add little: the stated variance is
    the scatter of the estimates (measured 0.87-1.11 of it).  With an error common to each cluster as large as the
    noise, the plain variances are 11-12 times too small, the cluster-robust ones 0.92-1.0 of the scatter."""
    scatter, plain, robust = _clustered_least_squares(shared=0.0)
    assert np.allclose(plain / scatter, 1, atol=0.2) and np.allclose(robust / scatter, 1, atol=0.2)
    scatter, plain, robust = _clustered_least_squares(shared=np.sqrt(0.5))
    assert np.all(scatter / plain > 5)
    assert np.allclose(robust / scatter, 1, atol=0.2)


def test_a_fit_through_no_change_keeps_a_jacobian():
    """A stiffness factor near 1 sits near 0 on its log search scale, where scipy's relative ``diff_step`` takes a step
    near 0 and a Jacobian of rounding noise: on the independent rig's demo20 log with the design elements 5 % stiffer
    the fit stopped within 1e-9 of scale 1 (the model as it was) and a modal damping was named instead.  The fit's
    own forward differences (steps ``1e-4 max(1, |x|)``) keep the slope there, and the least squares reach 1.05."""
    import scipy.optimize

    from ambid.diagnose import _with_jacobian

    def fun(x):  # a stiffness factor's misfit, smooth, in log coordinates; rounded like a model's response
        return np.round(np.array([np.exp(x[0]) - 1.05, 0.1 * (np.exp(x[0]) - 1.05)]), 12)

    value, jacobian = _with_jacobian(fun, np.array([np.log(0.05)]), np.array([np.log(5.0)]))
    near_zero = np.array([3e-10])
    assert jacobian(near_zero)[:, 0] == pytest.approx([1.0, 0.1], rel=1e-3)
    relative = scipy.optimize.least_squares(fun, near_zero, diff_step=1e-4, bounds=(np.log(0.05), np.log(5.0)))
    assert abs(np.exp(relative.x[0]) - 1) < 1e-6  # the old way: stuck at no change
    solution = scipy.optimize.least_squares(value, near_zero, jac=jacobian, bounds=(np.log(0.05), np.log(5.0)))
    assert np.exp(solution.x[0]) == pytest.approx(1.05, rel=1e-6)


def test_a_weak_narrow_housing_mode_away_from_the_misfit_peaks_is_found_from_its_weak_limit():
    """A 10 t frame's mode (zeta 0.005, 7.7 Hz wide at 770 Hz) halfway between two of the coarse scan's frequencies,
    the misfit peaks not scanned (as where a larger misfit elsewhere takes them): the coarse scan alone ends in another
    basin (at 5 kHz, chi2 1721); the weak limit's dense scan (`_weak_housing_start`) promises the chi2 the model gives at
    its start (to 1 %), and the fit ends at the mode (chi2 1617 for 1600 points), its frequency to 0.1 % and its mass
    to 10 %."""
    config = load_machine_config("demo20")
    config["frequency_grid"]["radial"]["points"] = 80
    machine = machine_from_config(config)
    housing = next(c for c in candidate_space(machine) if c.label == "foundation_mode")
    scan = housing.free[0].grid()
    frequency_hz = float(np.exp(0.5 * (scan[20] + scan[21])))
    measured = synthetic_measurement(machine, [effect("foundation_mode", frequency_hz=frequency_hz, mass_kg=10000.0,
                                                      damping_ratio=0.005)], seed=3)
    blind = replace(housing, free=(replace(housing.free[0], at_misfit_peaks=False), *housing.free[1:]))
    evaluator = _Evaluator(Plant(machine), measured, _Cells(measured))
    nominal = evaluator.residual(())
    start, promised = _weak_housing_start(evaluator, blind)
    at_start = evaluator.residual((blind.build([p.from_search(v) for p, v in zip(blind.free, start)]),))
    assert promised == pytest.approx(float(np.vdot(at_start, at_start).real), rel=0.01)
    assert promised < float(np.vdot(nominal, nominal).real) - 100
    with unittest.mock.patch("ambid.diagnose._weak_housing_start", return_value=None):
        coarse = _fit(evaluator, blind)
    found = _fit(evaluator, blind)
    names = [p.name for p in blind.free]
    assert abs(dict(zip(names, coarse.values))["frequency_hz"] / frequency_hz - 1) > 0.01
    values = dict(zip(names, found.values))
    assert values["frequency_hz"] == pytest.approx(frequency_hz, rel=1e-3)
    assert values["mass_kg"] == pytest.approx(10000.0, rel=0.1)
    assert found.chi2 < coarse.chi2 - 50 and found.chi2 < 1.05 * nominal.size and not found.at_bound


def test_a_weak_narrow_housing_mode_between_scan_points_is_a_lead_where_the_misfit_peaks():
    """A 12 t frame's mode (zeta 0.01, 15 Hz wide) on demo20's 80-point grid (12.5 Hz steps), halfway between two of
    the frequency scan's points (steps of 20 %): found from where the nominal model's misfit peaks, with its frequency
    to 1 %; the misfit it leaves is within the floor, so it is the diagnosis' lead, not a missing effect."""
    config = load_machine_config("demo20")
    config["frequency_grid"]["radial"]["points"] = 80
    machine = machine_from_config(config)
    housing = next(c for c in candidate_space(machine) if c.label == "foundation_mode")
    scan = housing.free[0].grid()  # the candidate's own frequency scan (without misfit peaks)
    assert housing.free[0].name == "frequency_hz" and 0.15 < np.exp(scan[1] - scan[0]) - 1 < 0.25
    frequency_hz = float(np.exp(0.5 * (scan[20] + scan[21])))
    measured = synthetic_measurement(machine, [effect("foundation_mode", frequency_hz=frequency_hz, damping_ratio=0.01,
                                                      mass_kg=12000.0)], seed=5)
    _, residual = misfit(measured, model_response(Plant(machine), measured))
    assert np.min(np.abs(misfit_peaks(measured, residual) / frequency_hz - 1)) < 0.02
    diagnosis = diagnose(machine, measured)
    assert diagnosis.verdict == "nothing" and not diagnosis.cells_before["above_floor"].any()
    lead = diagnosis.lead
    assert lead is not None and lead.candidate.label == "foundation_mode" and lead.evidence > 20
    fitted = dict(zip([p.name for p in lead.candidate.free], lead.values))
    assert fitted["frequency_hz"] == pytest.approx(frequency_hz, rel=0.01)
    assert fitted["mass_kg"] == pytest.approx(12000.0, rel=0.25) and not lead.at_bound
    assert diagnosis.summary()["lead"] == "foundation_mode"
    assert "lead" in {f.code for f in diagnosis_findings(diagnosis)}
    _, text = diagnosis_report(diagnosis, Plant(machine), measured, None, "demo20 lead")
    assert "**Nothing is missing at the floor**" in text and "A lead, not a finding: the data favour `foundation_mode`" in text
    assert "no step repeated" not in text  # unknown, or repeats measured: no caveat
    _, text = diagnosis_report(diagnosis, Plant(machine), measured, None, "demo20 lead", repeated_steps=0)
    assert "no step repeated at a lower amplitude" in text and "describing function" in text


def test_no_lead_on_noise_alone(demo):
    diagnosis = diagnose(demo, synthetic_measurement(demo, seed=1))
    assert diagnosis.verdict == "nothing" and diagnosis.lead is None and diagnosis.summary()["lead"] == ""


def test_bad_input():
    with pytest.raises(DiagnoseError):
        diagnose(None, {})
    frequency = np.array([1.0, 2.0])
    with pytest.raises(DiagnoseError, match="uncertainty"):
        misfit({("DX", "DX"): (frequency, np.ones(2), np.zeros(2))}, {("DX", "DX"): np.ones(2)})
    with pytest.raises(DiagnoseError, match="not finite"):
        misfit({("DX", "DX"): (frequency, np.ones(2), np.ones(2))}, {("DX", "DX"): np.array([np.nan, 1.0])})


def test_contenders_the_joint_refits_cannot_tell_apart_are_named_indistinguishable(monkeypatch):
    """`ambid.diagnose._choose`: of a round's close contenders refitted jointly with the effects chosen before, the
    least BIC is picked, and the others within `INDISTINGUISHABLE_BIC` of it are named indistinguishable from it (demo20
    2040's sensor pole and eddy-current lag, 6 apart, were named alone); one 20 apart is not."""
    import ambid.diagnose as diagnose_module
    from ambid.diagnose import FittedCandidate, _choose

    chi2 = {"delay": 1000.0, "sensor_lowpass": 1002.0, "eddy_current": 1020.0, "modal_damping": 5000.0}

    class Joint:  # what `_choose` reads of a joint refit
        def __init__(self, label):
            self.chi2, self.residual = chi2[label], np.zeros(500, dtype=complex)

    monkeypatch.setattr(diagnose_module, "joint_refit",
                        lambda machine, measured, effects, *args, **kwargs: Joint(effects[-1].candidate.label))
    monkeypatch.setattr(diagnose_module, "_variant", lambda joint: None)

    def fitted(label):
        return FittedCandidate(Candidate(label, label, (FreeParameter("x", 1.0, 2.0),)), (1.5,), (0.1,), chi2[label])

    chosen = [fitted("modal_damping")]
    contenders = [fitted("eddy_current"), fitted("sensor_lowpass"), fitted("delay")]
    # overdispersion 1000 / 500 = 2: BIC 2 chi2 / 2 + ln(1000), so 2 and 20 apart
    pick, joint = _choose(None, {}, chosen, contenders, DiagnoseSettings(), None, None)
    assert pick.candidate.label == "delay" and joint.chi2 == 1000.0
    assert pick.indistinguishable == ("sensor_lowpass",)


def test_a_candidate_that_cannot_be_built_does_not_stop_the_diagnosis(demo):
    # shifts below -25 mm move the DE sensor off the rotor: invalid effects the fit steps around
    shift = Candidate("noncollocation", "noncollocation",
                      (FreeParameter("de_offset_m", -0.04, 0.02, log=False, start=0.0, scan=9),))
    diagnosis = diagnose(demo, synthetic_measurement(demo), candidates=[shift])
    assert len(diagnosis.ranked) == 1 and np.isfinite(diagnosis.ranked[0].chi2)
    assert isinstance(diagnosis.table(), pd.DataFrame)


# --------------------------------------------------------------------------------------------- rigs
@pytest.fixture(scope="module")
def identification():
    config = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    return settings_from_config(config["identification"])


def small_grid(name, radial_points=80, axial_points=20, start_hz=5.0):
    """The machine on shorter grids from ``start_hz``: a 1 Hz step alone takes 6 s of the rig's time (1 s settling,
    2 s measuring, then its repeat), while every other step is done in 1 s; from 5 Hz a rig's identification
    simulates 1.6 s instead of 6 s (7 s of CPU instead of 17 s)."""
    machine_config = load_machine_config(name)
    machine_config["frequency_grid"]["radial"].update(points=radial_points, start_hz=start_hz)
    machine_config["frequency_grid"]["axial"].update(points=axial_points, start_hz=start_hz)
    return machine_config


@pytest.mark.parametrize("scale", [0.5, 0.7, 1.3])
def test_the_thesis_update_case_is_named(scale, identification):
    """Thesis ch. 5.3: demo20 with elements 5-8 at another stiffness; the element group is named, its scale within 2 %."""
    machine_config = small_grid("demo20")
    rig = hidden_effect_rig(machine_config, [{"name": "element_stiffness", "parameters": {"tag": "design", "scale": scale}}])
    table = identify_on_rig(rig, machine_config, identification, seed=11)
    diagnosis = diagnose(machine_from_config(machine_config), measured_channels(table), shares=effective_shares(table))
    first = diagnosis.sequence[0] if diagnosis.sequence else diagnosis.ranked[0]
    assert first.candidate.label == "element_stiffness[design]", diagnosis.table()
    value = diagnosis.joint.table.set_index("parameter").loc["element_stiffness[design].scale", "value"]
    assert value == pytest.approx(scale, rel=0.02)
    assert not diagnosis.cells_after["above_floor"].any(), diagnosis.cells_after


def hidden_entry(draws, name):
    """The ``effects:`` entry of a drawn hidden effect."""
    return {"name": name, "parameters": draws[name]}


def named_first(diagnosis, draws, names):
    """Whether the diagnosis chose exactly the hidden effects (any order; the right tag or side), or named them
    indistinguishable from its choice."""
    if len(diagnosis.sequence) != len(names):
        return False
    hidden = {effect_label(effect_from_config(hidden_entry(draws, n), n)) for n in names}
    named = {f.candidate.label for f in diagnosis.sequence} | {label for f in diagnosis.sequence for label in f.indistinguishable}
    return hidden <= named


def test_an_axial_effect_is_named_above_the_limit_of_the_points_it_counts_for(identification):
    """demo20 with the axial bearing's force constant 0.4 % high: the axial cell's 20 points, extrapolated to zero
    amplitude, count for about 9 independent ones, their variances for 80 degrees of freedom (their limit 2.49, F's;
    2.28 Gamma's, 1.81 of 20 independent points), and the effect, at chi2 per point 7.1 there, is still missing, its
    factor within two of its stated standard deviations (stops 49 and 50)."""
    machine_config = small_grid("demo20")
    truth = {"name": "actuator_coefficients", "parameters": {"force_constant_scale": [1, 1, 1, 1, 1.004]}}
    table = identify_on_rig(hidden_effect_rig(machine_config, [truth]), machine_config, identification, seed=11)
    diagnosis = diagnose(machine_from_config(machine_config), measured_channels(table), shares=effective_shares(table))
    axial = diagnosis.cells_before.query("family == 'axial'").iloc[0]
    assert axial["effective_points"] < 0.75 * axial["points"] and axial["limit"] > chance_limit(axial["points"])
    assert axial["above_floor"] and diagnosis.verdict == "missing", diagnosis.cells_before
    assert [f.candidate.label for f in diagnosis.sequence] == ["actuator_coefficients"], diagnosis.table()
    row = diagnosis.joint.table.set_index("parameter").loc["actuator_coefficients.force_constant_scale[4]"]
    assert abs(row["value"] - 1.004) < 2 * row["std"], row


@pytest.mark.parametrize("machine", ["hs_eden_like", "demo20"])
def test_drawn_truths_are_commissioned_machines(machine):
    """Every drawn hidden effect leaves a machine that levitates outside ISO 14839-3 zone D, judged by the model and
    by the rig (seed 2027 drew a 707 Hz amplifier that made demo20's rig unstable before the draws were limited)."""
    from ambid.loop import stability_summary
    from ambid.rig import RigModel

    machine_config = small_grid(machine)
    draws = hidden_effect_draws(machine_config, seed=2027)
    plant = Plant(machine_from_config(machine_config))
    for name in draws["signature"]:
        effect = effect_from_config(hidden_entry(draws, name), name)
        rows = stability_summary(plant_with_effects(plant, [effect]))
        assert all(row["stable"] and row["iso_14839_zone"] != "D" for row in rows), (name, rows)
        assert RigModel(hidden_effect_rig(machine_config, [hidden_entry(draws, name)])).closed_loop_spectral_radius() < 1.0


def test_a_signature_is_read_on_the_floor_a_log_measured(identification):
    """`effect_signature` against the floor of a log without the effect (`measured_floor`), the benchmark suite's weak
    end.  The typical floor (1 % of positions, 0.3 % of coil currents, a tenth of the row at a cross channel) misjudges
    it both ways: a housing mode by a diagonal's anti-resonance (hs_eden_like, 573 Hz, 18.7 t: the suite's seed 2051
    drew it) reads 8 typical floors where the log's noise keeps every point within half its floor, and a sensor pole
    at 100 kHz reads 0.75 typical floors where the coil currents, measured some fifty times better than 0.3 %, see it
    at 5."""
    machine_config = small_grid("hs_eden_like")
    machine = machine_from_config(machine_config)
    floor = measured_floor(identify_on_rig(hidden_effect_rig(machine_config, []), machine_config, identification,
                                           seed=2051))
    housing = effect_from_config({"name": "foundation_mode", "parameters": {
        "frequency_hz": 573.25, "damping_ratio": 0.0474, "mass_kg": 18675.0}}, "foundation_mode")
    assert effect_signature(machine, [housing]) > 3 and effect_signature(machine, [housing], floor) < 1
    pole = effect_from_config({"name": "sensor_lowpass", "parameters": {"cutoff_hz": 1e5}}, "sensor_lowpass")
    assert effect_signature(machine, [pole]) < 1 and effect_signature(machine, [pole], floor) > 3


@functools.cache
def drawn(machine, seed):
    """The hidden-effect draws of a machine and seed on `small_grid`, made once per process (~15 s each): under
    pytest-xdist a module fixture is made again whenever a worker's tests of this module are interleaved with others."""
    return hidden_effect_draws(small_grid(machine), seed=seed)


@pytest.fixture(scope="module")
def suite(identification):
    """One seed of the benchmark's suite on both machines, identified once and shared."""
    cases = {}

    def run(machine, names=(), unmodelled=(), seed=7):
        key = (machine, tuple(names), tuple(u["name"] for u in unmodelled), seed)
        if key not in cases:
            machine_config = small_grid(machine)
            draws = drawn(machine, seed)
            rig = hidden_effect_rig(machine_config, [hidden_entry(draws, n) for n in names], unmodelled=unmodelled)
            table = identify_on_rig(rig, machine_config, identification, seed=seed)
            measured = measured_channels(table)
            cases[key] = draws, diagnose(machine_from_config(machine_config), measured, shares=effective_shares(table))
            run.measured[key] = measured
        return cases[key]

    run.measured = {}  # each case's measured channels, for the tests that also write its page
    return run


@pytest.mark.parametrize("machine, name", [
    (machine, name) for machine in ("hs_eden_like", "demo20")
    for name in ("amplifier_lowpass", "delay", "element_stiffness", "foundation_mode")])
def test_a_hidden_effect_is_named_with_its_parameters(machine, name, suite):
    """The hidden effect is chosen, or named indistinguishable from the choice (a 10 us delay and a 15 kHz sensor pole
    cannot be told apart below 1 kHz); its own fit recovers the drawn parameters (within 5 %, or within the 2 sigma it
    states), and nothing is left above the floor."""
    draws, diagnosis = suite(machine, [name])
    assert named_first(diagnosis, draws, [name]), diagnosis.table()
    label = effect_label(effect_from_config(hidden_entry(draws, name), name))
    own = next(f for f in diagnosis.ranked if f.candidate.label == label)
    for parameter, value, std in zip(own.candidate.free, own.values, own.std):
        truth = draws[name][parameter.name]
        if parameter.index is not None:
            truth = truth[parameter.index]
        # within 5 %, or within twice the uncertainty the diagnosis states (a weak effect's correlated parameters)
        assert abs(value - truth) <= max(0.05 * abs(truth), 2 * std), (parameter, value, std, truth)
    assert not diagnosis.cells_after["above_floor"].any(), diagnosis.cells_after


def test_close_contenders_are_told_apart_by_the_joint_refit(identification):
    """hs_eden_like with the suite's pair draw (seed 2026: modal damping 0.0167 and a 4241 Hz sensor pole).  The
    damping is chosen first (fitted with the pole missing, it also stands in for part of the pole's magnitude roll-off);
    with it held there, a 37 us delay fit better than the pole itself, and a sensor shift and the actuator
    coefficients were then named beside the delay to make up the pole's magnitude.  Refitted jointly with the damping, the pole wins (`_choose`): the pair alone, each
    parameter within 1 %."""
    machine_config = small_grid("hs_eden_like")
    truth = [{"name": "modal_damping", "parameters": {"damping_ratio": 0.01673890402966119}},
             {"name": "sensor_lowpass", "parameters": {"cutoff_hz": 4241.277586591596}}]
    table = identify_on_rig(hidden_effect_rig(machine_config, truth), machine_config, identification, seed=2026)
    machine, measured = machine_from_config(machine_config), measured_channels(table)
    diagnosis = diagnose(machine, measured, shares=effective_shares(table))
    assert [f.candidate.label for f in diagnosis.sequence] == ["modal_damping", "sensor_lowpass"], diagnosis.table()
    joint = diagnosis.joint.table.set_index("parameter")
    assert joint.loc["modal_damping.damping_ratio", "value"] == pytest.approx(0.01673890402966119, rel=0.01)
    assert joint.loc["sensor_lowpass.cutoff_hz", "value"] == pytest.approx(4241.277586591596, rel=0.01)
    assert not diagnosis.cells_after["above_floor"].any()
    # the page says which contenders the joint refit told apart, with their chi2
    contenders = dict(diagnosis.sequence[1].contenders)
    assert "delay" in contenders and contenders["sensor_lowpass"] < contenders["delay"]
    _, page = diagnosis_report(diagnosis, Plant(machine), measured, None, "contenders")
    assert re.search(r"`sensor_lowpass` was chosen over (`\w+`, )*`delay`", page), page  # (with any other contenders)
    assert "the same as a first-order lag of the force" in page  # what else a sensor pole on positions can be


def test_the_zero_amplitude_frf_gives_the_weak_foundation_its_mass(identification):
    """demo20's drawn foundation mode (227.4 Hz, 76.6 kg, zeta 0.0278) to 1 % and 3 sigma, not only the suite's 5 %:
    with the FRF at the measured amplitude and its floor the mass came out 81.8 +- 1.1 kg (6.7 %, 4.7 sigma; a strict
    xfail until stop 27), the force law's amplitude error being a systematic pattern the floor counts as independent
    errors; extrapolated to zero amplitude (``frf.zero_amplitude``, the default since stop 27) it is gone
    (bench_extrapolation.py: 76.72 +- 0.12 kg; 76.58 +- 0.12 kg since stop 30: every step of a measured channel at zero
    amplitude, the interpolation's error from the pairs' curvature)."""
    machine_config = small_grid("demo20")
    draws = drawn("demo20", 7)
    rig = hidden_effect_rig(machine_config, [hidden_entry(draws, "foundation_mode")])
    table = identify_on_rig(rig, machine_config, identification, seed=7, floor_settings=FloorSettings(zero_amplitude=True))
    machine = machine_from_config(machine_config)
    candidate = [c for c in candidate_space(machine) if c.label == "foundation_mode"]
    fitted = diagnose(machine, measured_channels(table), candidates=candidate).ranked[0]
    for parameter, value, std in zip(fitted.candidate.free, fitted.values, fitted.std):
        truth = draws["foundation_mode"][parameter.name]
        assert value == pytest.approx(truth, rel=0.01) and abs(value - truth) < 3 * std, (parameter.name, value, std, truth)


@pytest.mark.parametrize("machine", ["hs_eden_like", "demo20"])
def test_negative_control_finds_nothing(machine, suite):
    _, diagnosis = suite(machine)
    assert diagnosis.verdict == "nothing", (diagnosis.table(), diagnosis.cells_before)
    # the model is the rig's truth here: against the FRF and its measured floor it sits at chi2 per point about 1 on the
    # position and coil-current families (issue 15: 0.7-1.5; the axial family's 20 points are too few to say)
    bands = diagnosis.cells_before[diagnosis.cells_before["output"] == "all"]
    cells = bands.assign(chi2=lambda c: c["chi2_per_point"] * c["points"]).groupby("family")[
        ["chi2", "points"]].sum()
    per_point = cells["chi2"] / cells["points"]
    assert per_point["positions"] == pytest.approx(1.0, abs=0.3) and per_point["currents"] == pytest.approx(1.0, abs=0.3), (
        per_point)


def test_two_hidden_effects_at_once(suite):
    draws, diagnosis = suite("hs_eden_like", ["delay", "foundation_mode"])
    assert named_first(diagnosis, draws, ["delay", "foundation_mode"]), diagnosis.table()
    assert not diagnosis.cells_after["above_floor"].any()


@pytest.mark.parametrize("unmodelled", [
    {"name": "sensor_gain", "parameters": {"axis": "NX", "gain": 1.05}},
    {"name": "amplifier_second_order", "parameters": {"natural_hz": 1500.0, "damping_ratio": 0.5}},
], ids=lambda u: u["name"])
def test_physics_outside_the_library_is_not_named_at_a_bound(unmodelled, suite):
    _, diagnosis = suite("hs_eden_like", unmodelled=[unmodelled])
    for fitted in diagnosis.sequence:
        assert not fitted.at_bound
    joint = diagnosis.joint.table if diagnosis.joint is not None else pd.DataFrame(columns=["at_bound"])
    assert not joint["at_bound"].any(), joint
    assert diagnosis.verdict in ("unexplained", "missing")
    assert not diagnosis.unexplained.empty, (diagnosis.table(), diagnosis.cells_after)
    if unmodelled["name"] == "sensor_gain":
        # a gain error on one sensor reads as the bearings' coefficients, as the describing function's amplitude error
        # does: on a run without repeated steps the page says that part of it may be that error
        alike = [f.candidate.label for f in diagnosis.sequence if f.candidate.effect in AMPLITUDE_ERROR_ALIKE]
        assert alike, diagnosis.table()
        plant = Plant(machine_from_config(small_grid("hs_eden_like")))
        measured = suite.measured[("hs_eden_like", (), ("sensor_gain",), 7)]
        _, page = diagnosis_report(diagnosis, plant, measured, None, "sensor gain", repeated_steps=0)
        assert f"part of what `{alike[0]}`" in page and "describing function" in page
        _, page = diagnosis_report(diagnosis, plant, measured, None, "sensor gain", repeated_steps=40)
        assert "describing function" not in page


def test_correlation_time_of_white_and_smooth_residuals():
    """White residuals carry independent information (1); an AR(1) residual with rho 0.8 carries a ninth of it."""
    from ambid.diagnose import correlation_time

    rng = np.random.default_rng(3)
    white = rng.standard_normal(20000) + 1j * rng.standard_normal(20000)
    assert correlation_time(white) == pytest.approx(1.0, abs=0.05)
    smooth = np.zeros(20000, dtype=complex)
    for k in range(1, smooth.size):
        smooth[k] = 0.8 * smooth[k - 1] + white[k]
    assert correlation_time(smooth) == pytest.approx(9.0, rel=0.1)
    assert correlation_time(np.zeros(5)) == 1.0


def test_a_cross_coupling_read_high_over_part_of_the_band_is_named_with_its_model_form(demo):
    """The suite's demo20 2040 cross coupling, made plain: a coupling of 0.03 whose off-diagonal FRF reads 2 % high
    over 190-310 Hz.  It is still named; the fit takes it 0.34 % high, and the model-form part of its standard
    deviation (the groups of points disagree) covers that, where the data's noise alone states 0.003 %.  The report's
    findings say so; on the same log without the error there is no model-form part."""
    from ambid.diagnosis_report import diagnosis_findings

    measured = synthetic_measurement(demo, [effect("cross_coupling", coefficient=0.03)])
    clean = diagnose(demo, measured)
    assert clean.joint.table["form_std"].eq(0).all()
    assert "model_form" not in {f.code for f in diagnosis_findings(clean)}
    distorted = {key: (f, v * np.where((f > 190) & (f < 310) & (key[0] != key[1]) & (key[0][:2] != "I_"), 1.02, 1.0), s)
                 for key, (f, v, s) in measured.items()}
    diagnosis = diagnose(demo, distorted)
    assert [f.candidate.label for f in diagnosis.sequence] == ["cross_coupling[input]"]
    row = diagnosis.joint.table.iloc[0]
    assert row["form_std"] > 0.9 * row["std"] and abs(row["value"] - 0.03) < 2 * row["std"]
    findings = {f.code: f for f in diagnosis_findings(diagnosis)}
    assert "cross_coupling[input].coefficient" in findings["model_form"].message


def test_cross_elements_at_zero_amplitude_are_read_at_each_models_input_coupling(demo):
    """The FRF stage extrapolates the x-y elements to zero amplitude assuming no input coupling and states how they move
    with one (`ambid.amplitude._mimo_inversion_errors`, `ambid.compare.input_coupling_slopes`).  A coupling of 0.03
    whose x-y elements were extrapolated 0.9 % low (the size the suite's rigs showed): read as they are, the coupling is
    fitted 0.5 % low, covered only by the model-form part of its standard deviation (the x-y elements disagree with
    the rest); read at each model's own coupling, within 0.01 % and its standard deviation, with no model-form part."""
    from ambid.compare import at_input_coupling

    measured = synthetic_measurement(demo, [effect("cross_coupling", coefficient=0.03)])
    crossed = [("DX", "DY"), ("DY", "DX"), ("NX", "NY"), ("NY", "NX")]
    slopes = {key: 0.3 * measured[key][1] for key in crossed}  # 0.3 x 0.03: 0.9 %
    extrapolated = at_input_coupling(measured, slopes, -0.03)
    assert at_input_coupling(extrapolated, slopes, 0.0) is extrapolated
    assert all(np.allclose(at_input_coupling(extrapolated, slopes, 0.03)[key][1], measured[key][1]) for key in measured)
    coupling = [c for c in candidate_space(demo) if c.label == "cross_coupling[input]"]
    for given, within in ((None, False), (slopes, True)):  # (read as they are; at each model's coupling)
        diagnosis = diagnose(demo, extrapolated, candidates=coupling, coupling_slopes=given)
        assert [f.candidate.label for f in diagnosis.sequence] == ["cross_coupling[input]"]
        row = diagnosis.joint.table.iloc[0]
        error = abs(row["value"] / 0.03 - 1)
        if within:
            assert error < 1e-4 and abs(row["value"] - 0.03) < 2 * row["std"] and row["form_std"] == 0, row
        else:
            assert error > 4e-3 and row["form_std"] > 0.9 * row["std"], row
    with pytest.raises(DiagnoseError, match="input-coupling slope"):
        diagnose(demo, extrapolated, coupling_slopes={("DX", "DY"): np.zeros(3)})


def test_each_channel_carries_its_own_correlation_time():
    """The floor's systematic part is smooth in the channels near a mode and absent from the others: one correlation
    time over all channels dilutes it.  One channel of five with AR(1) errors (rho 0.6, correlation time 4) determines
    a parameter: stated with the residual's correlation time over all channels, its variance is 0.35 of the estimates'
    scatter (and the white channels' parameter's 1.26 of theirs); with each channel's own, 1.07 and 1.04."""
    from ambid.diagnose import correlation_time

    rng = np.random.default_rng(5)
    size, channels = 200, 5
    channel = np.repeat(np.arange(channels), size)
    points = channel.size
    # a level on the smooth channel, another on the four white ones
    design = np.stack([channel == 0, channel > 0], axis=1).astype(float)
    jacobian = np.concatenate([design, design])
    estimates, pooled, own = [], [], []
    for _ in range(300):
        error = (rng.standard_normal(points) + 1j * rng.standard_normal(points)) / np.sqrt(2)
        smooth = error[:size].copy()
        for k in range(1, size):
            smooth[k] = 0.6 * smooth[k - 1] + np.sqrt(1 - 0.36) * error[k]
        error[:size] = smooth
        x, residual, chi2 = _linear_fit(jacobian, error)
        estimates.append(x)
        pooled.append(np.diag(_covariance(jacobian, chi2, points, 2, residual=residual)))
        own.append(np.diag(_covariance(jacobian, chi2, points, 2, residual=residual, channels=channel)))
    scatter = np.var(estimates, axis=0)
    assert np.mean(pooled, axis=0)[0] / scatter[0] < 0.5
    assert np.allclose(np.mean(own, axis=0) / scatter, 1, atol=0.2)
    assert correlation_time(residual, channel)[0] == pytest.approx(4.0, rel=0.35)


def test_a_bias_that_changes_over_the_band_is_stated_as_model_form():
    """A level fitted to four channels of 80 points each.  With white errors, the groups of `FORM_GROUP_POINTS` agree
    within chance (Cochran's Q beyond its 0.135 % tail, shared among the group sizes, in none of 200 draws), so the
    model-form variance adds nothing.  With the data 3 % of the level high above the grid's middle and right below it
    (a cross channel's describing-function error), the fit lands 1.5 % high, 9-12 of its statistical standard
    deviations (ten draws); with the groups' disagreement, 0.8-1.0 of the stated one."""
    from ambid.diagnose import _band_disagreement

    rng = np.random.default_rng(11)
    channel = np.repeat(np.arange(4), 80)
    points = channel.size
    level = 50.0  # the parameter's effect on every point, in units of the floor
    jacobian = np.concatenate([np.full((points, 1), level), np.zeros((points, 1))])
    bias = np.where(np.tile(np.arange(80), 4) >= 40, 0.03 * level, 0.0)

    def stated(biased):
        error = (rng.standard_normal(points) + 1j * rng.standard_normal(points)) / np.sqrt(2)
        x, residual, chi2 = _linear_fit(jacobian, error + biased)
        plain = float(np.sqrt(_covariance(jacobian, chi2, points, 1, residual=residual, channels=channel)[0, 0]))
        form = _band_disagreement(jacobian, residual, channel, chi2, 1)
        return float(x[0]), plain, float(np.sqrt(plain**2 + form[0])), form[0]

    flagged = [stated(np.zeros(points))[3] > 0 for _ in range(200)]
    assert sum(flagged) <= 4
    value, plain, total, _ = stated(bias)
    assert value == pytest.approx(0.015, abs=0.003)
    assert value / plain > 5
    assert value / total < 2


def test_what_the_data_alone_determine():
    """The data's own standard deviations: the covariance's without a prior where the data see every direction,
    as large as the arithmetic allows for a parameter in a direction they do not see (a pseudo-inverse would give it
    none)."""
    from ambid.diagnose import _covariance, _data_standard_deviations

    rng = np.random.default_rng(5)
    jacobian = rng.standard_normal((400, 3))
    full = _data_standard_deviations(jacobian, 400.0, 200, 3)
    assert full == pytest.approx(np.sqrt(np.diag(_covariance(jacobian, 400.0, 200, 3))), rel=1e-9)
    with_prior = np.sqrt(np.diag(_covariance(jacobian, 400.0, 200, 3, prior=np.array([0.0, 0.0, 1e5]))))
    assert with_prior[2] < 0.1 * full[2]  # a prior holds what the data alone leave loose
    blind = jacobian.copy()
    blind[:, 2] = blind[:, 1]  # the data see only the sum of the last two
    alone = _data_standard_deviations(blind, 400.0, 200, 3)
    assert alone[0] == pytest.approx(full[0], rel=0.5) and min(alone[1:]) > 1e4 * max(full)
    assert np.all(np.isfinite(np.diag(_covariance(blind, 400.0, 200, 3))))  # where the pseudo-inverse sees no problem


def test_a_cell_at_the_floor_exceeds_its_chance_limit_as_rarely_as_meant():
    """A cell of n complex points at the floor (|r|^2 exponential, mean 1): its chi2 per point exceeds `chance_limit`
    with the 3-sigma tail's probability; the normal approximation 1 + 3 / sqrt(n) let a 26-point cell (the axial coil
    current's row) through about four times as often (hs_eden_like 2035's negative control: 1.61, "unexplained")."""
    rng = np.random.default_rng(11)
    cells = rng.exponential(size=(400_000, 26)).mean(axis=1)
    assert np.mean(cells > chance_limit(26)) == pytest.approx(CELL_TAIL, rel=0.25)
    assert np.mean(cells > 1 + 3 / np.sqrt(26)) > 3 * CELL_TAIL
    assert chance_limit(10_000) == pytest.approx(1 + 3 / np.sqrt(10_000), rel=1e-3)  # many points: the normal limit


def test_a_cell_whose_variances_are_estimates_exceeds_its_chance_limit_as_rarely_as_meant():
    """Points whose stated variances share an estimate of nu degrees of freedom: the cell's chi2 per point is
    F(2 n, nu), and `chance_limit` with ``estimate_dof`` is its 3-sigma quantile.  The Gamma of the same variance
    (Satterthwaite's effective points, the limit of stop 49) lets such cells through about ten times as often: the
    axial position cell's 15.5 noise points and 17 degrees of freedom, two of 80 no-effect logs of the suite above
    2.7 (stop 50)."""
    rng = np.random.default_rng(12)
    draws = 1_000_000
    for points, dof in ((16, 17.0), (26, 40.0)):
        numerator = rng.standard_gamma(points, size=draws) / points  # n exponential |r|^2 at the floor, their mean
        estimate = rng.chisquare(dof, size=draws) / dof  # the shared estimate's relative variance
        cells = numerator / estimate
        limit = chance_limit(points, estimate_dof=dof)
        assert np.mean(cells > limit) == pytest.approx(CELL_TAIL, rel=0.15)
        satterthwaite = 1 / (1 / points + 2 / dof)  # the same variance, as independent points
        assert np.mean(cells > chance_limit(satterthwaite)) > 5 * CELL_TAIL
    assert chance_limit(26, estimate_dof=1e12) == pytest.approx(chance_limit(26), rel=1e-6)  # a known variance


def test_a_cell_whose_points_share_their_errors_takes_the_limit_of_fewer_points():
    """A cell's chance limit counts the sum of its points' effective shares (`ambid.compare.effective_shares`): 26
    axial points that count as 5.2 independent ones are above the floor at the limit of 5.2 (2.83), not of 26 (1.69);
    a point's share out of (0, 1] is an error."""
    frequency = np.geomspace(1.0, 100.0, 26)
    measured = {("Z", "Z"): (frequency, np.ones(26, dtype=complex), np.ones(26))}
    predicted = {("Z", "Z"): np.full(26, 1 + np.sqrt(2.2), dtype=complex)}  # chi2 per point 2.2
    independent = misfit_cells(measured, predicted)
    shared = misfit_cells(measured, predicted, shares={("Z", "Z"): np.full(26, 0.2)})
    assert independent["limit"].iloc[0] == pytest.approx(chance_limit(26)) and independent["above_floor"].all()
    assert shared["effective_points"].iloc[0] == pytest.approx(5.2)
    assert shared["limit"].iloc[0] == pytest.approx(chance_limit(5.2)) == pytest.approx(2.83, abs=0.01)
    assert not shared["above_floor"].any()
    with pytest.raises(DiagnoseError, match="effective share"):
        misfit_cells(measured, predicted, shares={("Z", "Z"): np.full(26, 1.2)})
    with pytest.raises(DiagnoseError, match="effective share"):
        misfit_cells(measured, predicted, shares={("Z", "Z"): np.full(25, 0.2)})
    # the same shares, of which a variance error of 3.3 a point is the stated variances' (as the suite's axial cell:
    # the noise's points 26 / (5 - 3.3) = 15.3, the estimates' degrees of freedom 2 26^2 / (26 3.3) = 15.8): the F
    # limit, far above the Gamma's of 5.2 points; the cell at 2.2 within it
    estimated = misfit_cells(measured, predicted, shares={("Z", "Z"): PointShares(np.full(26, 0.2), np.full(26, 3.3))})
    assert estimated["effective_points"].iloc[0] == pytest.approx(5.2)
    assert estimated["estimate_dof"].iloc[0] == pytest.approx(2 * 26 / 3.3)
    assert estimated["limit"].iloc[0] == pytest.approx(chance_limit(26 / 1.7, estimate_dof=2 * 26 / 3.3))
    assert estimated["limit"].iloc[0] == pytest.approx(scipy.stats.f.isf(CELL_TAIL, 2 * 26 / 1.7, 2 * 26 / 3.3))  # 4.51
    assert not estimated["above_floor"].any()
    assert np.isinf(shared["estimate_dof"].iloc[0])
    from ambid.diagnosis_report import _cells_text  # the words the report gives an unexplained cell
    assert _cells_text(estimated).endswith("(chi2 per point 2.2 against 4.51, 26 points counting as 5.2 independent, "
                                           "their noise estimated with 16 degrees of freedom)")
    assert _cells_text(shared).endswith("counting as 5.2 independent)")
    with pytest.raises(DiagnoseError, match="variance error"):  # more than the share counts
        misfit_cells(measured, predicted, shares={("Z", "Z"): PointShares(np.full(26, 0.2), np.full(26, 4.5))})


def test_evidence_channel_by_channel_discounts_gains_on_channels_the_model_misses_anyway():
    """Two channels of 40 points in two bands each.  A candidate that takes one channel's low band from chi2 per point 6
    to 3 (the model misses it either way, as a negative control's cross channels) earns plain evidence but little
    channel by channel; one that takes it from 3 to the floor keeps its evidence; noise alone gains nothing."""
    frequency = np.linspace(1.0, 1000.0, 40)
    measured = {("DX", "DX"): (frequency, None, None), ("DY", "DY"): (frequency, None, None)}
    cells = _Cells(measured, min_points=20)
    rng = np.random.default_rng(3)
    floor = (rng.standard_normal(80) + 1j * rng.standard_normal(80)) / np.sqrt(2)
    low = np.zeros(80, dtype=bool)
    low[:40] = frequency < frequency[20]  # the DX channel's low band: 20 points

    def with_excess(chi2_per_point):
        residual = floor.copy()
        residual[low] *= np.sqrt(chi2_per_point / np.mean(np.abs(floor[low]) ** 2))
        return residual

    def plain(before, after):
        return bic_evidence(np.vdot(before, before).real, np.vdot(after, after).real, 1, before.size)

    before, after = with_excess(6.0), with_excess(3.0)
    assert plain(before, after) > 100 and cells.channel_evidence(before, after, 1) < plain(before, after) / 2.5
    before, after = with_excess(3.0), with_excess(1.0)
    assert cells.channel_evidence(before, after, 1) == pytest.approx(plain(before, after), rel=0.05)
    assert cells.channel_evidence(floor, floor, 1) == pytest.approx(-np.log(160))


def test_a_row_above_its_floor_does_not_hide_an_effect_found_outside_it(identification):
    """The benchmark suite's demo20 2050 delay (2.33 us, three floors; 80 points from 1 Hz, seed 2050, as the suite
    identifies and models it): no band cell is above the floor, but the DY row is (1.514 against 1.5).  What the delay
    gains outside that row names it; until stop 57 a row above the floor kept every candidate from being found channel
    by channel, and the verdict read "unexplained" with nothing named."""
    from ambid.compare import for_run, input_coupling_slopes
    from ambid.plausibility import FRF_SETTINGS

    config = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    machine_config = load_machine_config("demo20")
    machine_config["frequency_grid"]["radial"]["points"] = 80
    machine_config["frequency_grid"]["axial"]["points"] = 26
    delay_s = 2.3313395361562398e-06
    rig = hidden_effect_rig(machine_config, [{"name": "delay", "parameters": {"delay_s": delay_s}}])
    floor_settings = FloorSettings.from_config({k: v for k, v in config["frf"].items() if k not in FRF_SETTINGS})
    table = identify_on_rig(rig, machine_config, identification, seed=2050, floor_settings=floor_settings)
    measured = measured_channels(table)
    model, _ = for_run(machine_from_config(machine_config), measured, {}, "diagnose")
    diagnosis = diagnose(model, measured, shares=effective_shares(table), coupling_slopes=input_coupling_slopes(table))
    cells = diagnosis.cells_before
    band, row = cells[cells["output"] == "all"], cells[cells["output"] != "all"]
    assert not band["above_floor"].any() and row["above_floor"].any(), cells  # the case: a row alone above the floor
    assert [f.candidate.label for f in diagnosis.sequence] == ["delay"], diagnosis.table()
    value = diagnosis.joint.table.set_index("parameter").loc["delay.delay_s"]
    assert abs(value["value"] - delay_s) <= max(0.05 * delay_s, 2 * value["std"]), value
    assert not diagnosis.cells_after["above_floor"].any()


def test_an_effect_within_every_cells_floor_but_strong_channel_by_channel_is_missing():
    """An added modal damping of 5e-5 on demo20 (synthetic, 0.3 % noise): no channel family and band rises above its
    floor (the resonances' few points are diluted in their cells), but channel by channel its evidence is far beyond
    `AT_FLOOR_EVIDENCE`: missing, with its value, and the report says how it was found."""
    config = load_machine_config("demo20")
    config["frequency_grid"]["radial"]["points"] = 80
    machine = machine_from_config(config)
    measured = synthetic_measurement(machine, [effect("modal_damping", damping_ratio=5e-5)], seed=2, relative_noise=3e-3)
    candidates = [c for c in candidate_space(machine) if c.effect in ("modal_damping", "foundation_mode", "noncollocation")]
    diagnosis = diagnose(machine, measured, candidates=candidates)
    assert diagnosis.base_at_floor and not diagnosis.cells_before["above_floor"].any()
    assert diagnosis.verdict == "missing" and [f.candidate.label for f in diagnosis.sequence] == ["modal_damping"]
    first = diagnosis.sequence[0]
    assert first.share == 0 and first.channel_evidence > AT_FLOOR_EVIDENCE
    damping = diagnosis.joint.table.set_index("parameter").loc["modal_damping.damping_ratio"]
    assert abs(damping["value"] - 5e-5) < max(3 * damping["std"], 0.1 * 5e-5)
    message = next(f.message for f in diagnosis_findings(diagnosis) if f.code == "missing_effect")
    assert "weighed by the misfit it leaves there" in message


def test_candidates_the_data_cannot_tell_apart_keep_their_order():
    """Two refits whose chi2 differ in the last digits (hs_eden_like's input and output cross couplings on the
    independent rig's log) keep the order they came in; a real difference of BIC decides."""
    from types import SimpleNamespace

    def refit(label, chi2, parameters=1):
        free = (FreeParameter("coefficient", -0.2, 0.2),) * parameters
        return SimpleNamespace(candidate=Candidate(label, "cross_coupling", free)), SimpleNamespace(chi2=chi2, residual=np.zeros(5200))

    first, second = refit("cross_coupling[input]", 3594.2067190001), refit("cross_coupling[output]", 3594.2067190000)
    assert _least_bic([first, second]) is first[0] and _least_bic([second, first]) is second[0]
    better = refit("cross_coupling[output]", 3590.0)
    assert _least_bic([first, better]) is better[0]
    # a parameter more costs ln(2N) of BIC: the simpler of two equal fits wins whatever the order
    richer = refit("element_stiffness[motor]", 3594.2067190000, parameters=2)
    assert _least_bic([richer, first]) is first[0]
