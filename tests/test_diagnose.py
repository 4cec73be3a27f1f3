"""Diagnosis: the candidate effects, their fit and ranking, and the hidden-effect suite on the virtual rig.

The suite hides each effect of the library in a rig of the default machine
(parameters drawn, seeded, from physical ranges), identifies it with the
stepped sine, and diagnoses the nominal model from the FRF table alone.  The
model side never sees the rig: `hidden_effect_rig` builds the truth and only
the FRF table crosses over.
"""

import numpy as np
import pandas as pd
import pytest
import yaml

from ambid.compare import channel_errors, measured_channels, model_response, summarize
from ambid.diagnose import (Candidate, DiagnoseError, FreeParameter, candidate_space, diagnose, effects_config_lines,
                            fingerprint, misfit)
from ambid.effects import EFFECTS, effect_from_config
from ambid.excitation import settings_from_config
from ambid.experiment import hidden_effect_draws, hidden_effect_rig, identify_on_rig
from ambid.machine import machine_from_config
from ambid.plant import Plant

from conftest import ROOT, load_machine_config

POSITION_FLOOR, CURRENT_FLOOR = 0.02, 0.001


DRAWS = hidden_effect_draws()


@pytest.fixture(scope="module")
def setup():
    config = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    machine_config = load_machine_config("hs_eden_like")
    machine_config["frequency_grid"]["radial"]["points"] = 80  # a third of the default grid keeps the suite fast
    machine_config["frequency_grid"]["axial"]["points"] = 30
    return machine_config, settings_from_config(config["identification"])


@pytest.fixture(scope="module")
def experiments(setup):
    """Lazily identified rigs, keyed by the tuple of hidden effect names."""
    machine_config, settings = setup
    cache = {}

    def run(*names):
        if names not in cache:
            effects = [{"name": name, "parameters": DRAWS[name]} for name in names]
            table = identify_on_rig(hidden_effect_rig(machine_config, effects), machine_config, settings, seed=5)
            cache[names] = measured_channels(table, POSITION_FLOOR, CURRENT_FLOOR)
        return cache[names]

    return run


def hidden_candidate(diagnosis, name):
    """The fitted candidate of the hidden effect (the right tag / side where the effect has one)."""
    parameters = DRAWS[name]
    for fitted in diagnosis.ranked:
        candidate = fitted.candidate
        if candidate.effect == name and all(candidate.fixed.get(k, v) == v for k, v in parameters.items()
                                            if k not in {p.name for p in candidate.free}):
            return fitted
    raise AssertionError(f"no candidate for {name}")


def ranked_first(diagnosis, name):
    """Whether the hidden effect is ranked first, or named indistinguishable from the first."""
    top = diagnosis.ranked[0]
    hidden = hidden_candidate(diagnosis, name)
    return top.candidate.effect == name or hidden.candidate.label in top.indistinguishable


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_hidden_effect_is_found(name, setup, experiments):
    machine_config, _ = setup
    measured = experiments(name)
    diagnosis = diagnose(machine_from_config(machine_config), measured)
    hidden = hidden_candidate(diagnosis, name)
    assert diagnosis.best is not None, f"{name}: nothing significant found\n{diagnosis.table()}"
    assert ranked_first(diagnosis, name), f"{name} not ranked first\n{diagnosis.table()}"
    for parameter, value in zip(hidden.candidate.free, hidden.values):
        truth = DRAWS[name][parameter.name]
        assert value == pytest.approx(truth, rel=0.10), f"{name}.{parameter.name}: fitted {value}, truth {truth}"
    # adding it cuts the excess over the noise floor by at least 80 % (vacuous when the effect hides in the floor)
    assert diagnosis.excess_after(hidden) <= 0.2 * diagnosis.excess


def test_negative_control_finds_nothing(setup, experiments):
    machine_config, _ = setup
    diagnosis = diagnose(machine_from_config(machine_config), experiments())
    assert diagnosis.chi2 / diagnosis.points < 1.5
    assert diagnosis.best is None, diagnosis.table()


def test_two_hidden_effects_found_one_after_the_other(setup, experiments):
    machine_config, _ = setup
    measured = experiments("delay", "foundation_mode")
    machine = machine_from_config(machine_config)
    first = diagnose(machine, measured, sequence_length=3)
    # the diagnosis' answer: the significant effects chosen one after the other (in the single-step ranking the
    # lag-type candidates eddy_current and sensor_lowpass bend the housing resonance and rank above the delay)
    chosen = [f.candidate.effect for f in first.sequence]
    assert {"delay", "foundation_mode"} <= set(chosen[:3]), first.table()
    added = first.ranked[0]
    second = diagnose(machine.with_effects(machine.effects + (added.effect,)), measured)
    other = ({"delay", "foundation_mode"} - {added.candidate.effect}).pop()
    assert second.ranked[0].candidate.effect == other, second.table()
    both = machine.with_effects(machine.effects + (added.effect, second.ranked[0].effect))
    after, _ = misfit(measured, model_response(Plant(both), measured))
    assert after / first.points - 1 <= 0.2 * first.excess


# ----------------------------------------------------------------------------- units
@pytest.fixture(scope="module")
def demo(demo_machine):
    return demo_machine


def synthetic_measurement(machine, effects=(), relative_noise=1e-3, seed=0):
    """Measured channels of ``machine`` plus ``effects``, with complex noise of a known std."""
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
        out[key] = (frequency, values + noise, std)
    return out


def test_candidates_cover_the_library_and_their_bounds(demo):
    candidates = candidate_space(demo)
    assert {c.effect for c in candidates} == set(EFFECTS)
    for candidate in candidates:
        for parameter in candidate.free:
            assert parameter.lower < parameter.upper
            spec = EFFECTS[candidate.effect].parameters[parameter.name]
            assert spec.lower is None or parameter.lower >= spec.lower
        mid = [np.sqrt(p.lower * p.upper) if p.log else 0.5 * (p.lower + p.upper) for p in candidate.free]
        candidate.build(mid).check(demo)  # every candidate is a valid effect inside its range


def test_delay_recovered_on_synthetic_data_and_nothing_else_significant(demo):
    effect = effect_from_config({"name": "delay", "parameters": {"delay_s": 8e-5}}, "effects[0]")
    measured = synthetic_measurement(demo, [effect])
    diagnosis = diagnose(demo, measured)
    best = diagnosis.best
    assert best.candidate.label == "delay"
    assert best.values[0] == pytest.approx(8e-5, rel=1e-3)
    assert best.std[0] < 1e-6
    assert diagnosis.chi2 / diagnosis.points > 100
    assert best.chi2 / diagnosis.points == pytest.approx(1.0, abs=0.1)  # down to the noise
    table = diagnosis.table()
    assert list(table.columns[:4]) == ["rank", "candidate", "effect", "parameters"]
    assert table.loc[0, "excess_removed"] > 0.99


def test_nothing_missing_on_the_model_itself(demo):
    diagnosis = diagnose(demo, synthetic_measurement(demo))
    assert diagnosis.chi2 / diagnosis.points == pytest.approx(1.0, abs=0.1)
    assert diagnosis.best is None


def test_config_lines_round_trip(demo):
    effect = effect_from_config({"name": "foundation_mode", "parameters": {"mass_kg": 12.34567, "frequency_hz": 345.678}}, "e")
    lines = effects_config_lines([effect])
    assert lines.startswith("effects:")
    parsed = yaml.safe_load(lines)["effects"][0]
    assert parsed["parameters"]["mass_kg"] == 12.35
    rebuilt = effect_from_config(parsed, "effects[0]", demo)
    assert rebuilt.frequency_hz == pytest.approx(345.7)
    delay = effect_from_config({"name": "delay", "parameters": {"delay_s": 1e-4}}, "e")
    assert "axes" not in effects_config_lines([delay])  # the default is left out


def test_fingerprint_names_a_linear_phase_lag(demo):
    effect = effect_from_config({"name": "delay", "parameters": {"delay_s": 1e-4}}, "e")
    measured = synthetic_measurement(demo, [effect])
    errors = channel_errors(measured, model_response(Plant(demo), measured))
    text = " ".join(fingerprint(errors, summarize(errors)))
    assert "grows linearly with frequency" in text
    assert "delay of 100 us" in text
    assert "coil-current channels the model matches" in text


def test_bad_input():
    with pytest.raises(DiagnoseError):
        diagnose(None, {})
    frequency = np.array([1.0, 2.0])
    with pytest.raises(DiagnoseError, match="uncertainty"):
        misfit({("DX", "DX"): (frequency, np.ones(2), np.zeros(2))}, {("DX", "DX"): np.ones(2)})
    with pytest.raises(DiagnoseError, match="not finite"):
        misfit({("DX", "DX"): (frequency, np.ones(2), np.ones(2))}, {("DX", "DX"): np.array([np.nan, 1.0])})


def test_a_candidate_that_cannot_be_built_does_not_stop_the_diagnosis(demo):
    # shifts below -25 mm move the DE sensor off the rotor: invalid effects the fit steps around
    shift = Candidate("noncollocation", "noncollocation", (FreeParameter("de_offset_m", -0.04, 0.02, log=False, start=0.0),))
    diagnosis = diagnose(demo, synthetic_measurement(demo), candidates=[shift])
    assert len(diagnosis.ranked) == 1 and np.isfinite(diagnosis.ranked[0].chi2)
    assert isinstance(diagnosis.table(), pd.DataFrame)
