"""Stepped-sine identification (thesis ch. 4.2) on the virtual rig."""

import copy

import numpy as np
import pytest
import scipy.integrate
import yaml
from numpy.testing import assert_allclose

from ambid.errors import ConfigError
from ambid.excitation import (
    StepPlan,
    SteppedSineSettings,
    adapt_amplitude,
    amplitude_limits,
    measurement_windows,
    run_stepped_sine,
    settings_from_config,
)
from ambid.logs import CHANNELS, identification_frame, read_identification_log, validate_identification_log, write_identification_log
from ambid.plant import Plant
from ambid.rig import RigModel, rig_from_config

from conftest import ROOT

THESIS = SteppedSineSettings()
FAST = SteppedSineSettings(settle_min_s=0.03, settle_max_s=0.1, measure_min_s=0.02)  # logic tests, not accuracy
AXES = ["DX", "DY", "NX", "NY"]


def rig_config(name, quiet=False, drop=()):
    config = yaml.safe_load(open(ROOT / "config" / "rigs" / f"{name}.yaml"))
    if quiet:
        config["truth"].update(sensor_noise_m=0.0, sensor_resolution_m=0.0, current_noise_a=0.0, current_resolution_a=0.0)
    config["truth"]["effects"] = [e for e in config["truth"]["effects"] if e["name"] not in drop]
    return config


def plan(axes, frequencies, amplitude):
    n = len(frequencies)
    return StepPlan(np.repeat(axes, n), np.tile(np.arange(n), len(axes)), np.tile(frequencies, len(axes)), np.full(n * len(axes), amplitude))


class TestAmplitudeAdaptation:
    def test_thesis_rules(self):
        amplitude = np.array([1.0, 1.0, 1.0, 3.0, 0.05, 2.9, 0.06])
        peak = np.array([10e-6, 60e-6, 30e-6, 10e-6, 60e-6, 10e-6, 60e-6])
        new, accepted = adapt_amplitude(amplitude, peak, THESIS)
        assert_allclose(new, [1.2, 0.8, 1.0, 3.0, 0.05, 3.0, 0.05])  # +20 %, -20 %, clipped at the limits
        assert accepted.tolist() == [False, False, True, True, True, False, False]

    def test_limits_accept_on_the_next_measurement(self):
        new, accepted = adapt_amplitude(np.array([3.0, 0.05]), np.array([1e-6, 1e-3]), THESIS)
        assert accepted.all() and new.tolist() == [3.0, 0.05]  # A_max too weak, A_min too strong: saved anyway

    def test_the_amplitude_is_at_most_a_fraction_of_the_bias_current(self, demo_machine):
        # demo20: radial bias 3 A, axial 2 A; the thesis' A_max of 3 A would swing one coil's current to zero
        settings = SteppedSineSettings(max_bias_fraction=0.5)
        assert_allclose(amplitude_limits(demo_machine, THESIS), [3.0] * 5)
        assert_allclose(amplitude_limits(demo_machine, settings), [1.5, 1.5, 1.5, 1.5, 1.0])
        plan = StepPlan.for_machine(Plant(demo_machine), settings)
        assert_allclose(plan.amplitude_max_a, np.where(plan.axis == "Z", 1.0, 1.5))
        assert np.all(plan.initial_amplitude_a <= plan.amplitude_max_a)
        assert plan.initial_amplitude_a.max() == pytest.approx(1.5)  # the high steps start at the limit
        # the adaptation grows to each step's limit and accepts a weak response there
        limits = np.array([1.5, 1.5, 1.0])
        new, accepted = adapt_amplitude(np.array([1.4, 1.5, 0.9]), np.full(3, 1e-6), settings, limits)
        assert_allclose(new, [1.5, 1.5, 1.0])
        assert accepted.tolist() == [False, True, False]

    @pytest.mark.parametrize(
        "kwargs, key",
        [(dict(max_bias_fraction=1.5), "max_bias_fraction"), (dict(response_min_m=6e-5), "response_max_m"),
         (dict(measure_periods=1), "measure_periods"), (dict(shrink=1.0), "shrink")],
    )
    def test_bad_settings_name_the_key(self, kwargs, key):
        with pytest.raises(ConfigError, match=key):
            SteppedSineSettings(**kwargs)

    def test_unknown_setting(self):
        with pytest.raises(ConfigError, match="identification.growht"):
            settings_from_config({"growht": 0.2})


def test_windows_hold_whole_periods():
    f = np.linspace(1, 750, 250)
    settle, measure, periods, exact = measurement_windows(f, 50e-6, THESIS)
    assert_allclose(exact * measure * 50e-6, periods, rtol=1e-12)
    assert np.max(np.abs(exact / f - 1)) < 3e-4
    assert np.all(periods >= 2) and np.all(measure * 50e-6 >= THESIS.measure_min_s - 50e-6)
    assert np.all(settle * 50e-6 >= THESIS.settle_min_s)


@pytest.fixture(scope="module")
def demo_quiet(demo_config):
    return RigModel(rig_from_config(rig_config("demo20", quiet=True, drop=("delay",)), demo_config))


class TestRun:
    def test_adaptation_reaches_the_band_or_a_limit(self, demo_config):
        model = RigModel(rig_from_config(rig_config("demo20", quiet=True), demo_config))
        f = np.array([10.0, 60.0, 900.0])
        records, _ = run_stepped_sine(model, plan(["DX"], f, 0.05), FAST, noise=False)
        low, mid, high = records
        assert low["in_band"] and low["attempts"] > 1
        assert_allclose(low["amplitude_a"], 0.05 * 1.2 ** (low["attempts"] - 1), rtol=1e-12)
        assert high["amplitude_a"] == THESIS.amplitude_max_a and not high["in_band"]  # saved at A_max
        strong_settings = SteppedSineSettings(response_max_m=5e-6, response_min_m=1e-6, amplitude_min_a=0.2, settle_min_s=0.03, measure_min_s=0.02)
        strong, _ = run_stepped_sine(model, plan(["DX"], np.array([10.0]), 0.3), strong_settings, noise=False)
        assert strong[0]["amplitude_a"] == 0.2 and not strong[0]["in_band"] and strong[0]["attempts"] == 3  # 0.3, 0.24, 0.2

    def test_repeats_at_a_lower_level(self, demo_quiet):
        """Every other step measured again at half its accepted amplitude, at the same frequency, as log level 1."""
        f = np.array([40.0, 120.0, 333.0, 500.0])
        settings = SteppedSineSettings(settle_min_s=0.03, settle_max_s=0.1, measure_min_s=0.02, repeat_ratio=0.5, repeat_every=2)
        records, _ = run_stepped_sine(demo_quiet, plan(["DX"], f, 0.5), settings, noise=False)
        base = [r for r in records if r["level"] == 0]
        repeats = [r for r in records if r["level"] == 1]
        assert [r["step"] for r in base] == [0, 1, 2, 3] and [r["step"] for r in repeats] == [0, 2]
        for repeat in repeats:
            accepted = base[repeat["step"]]
            assert repeat["frequency_hz"] == accepted["frequency_hz"]
            assert repeat["amplitude_a"] == pytest.approx(0.5 * accepted["amplitude_a"])
            u = CHANNELS.index("U2_DX")
            assert abs(repeat["coefficients"][u]) == pytest.approx(0.5 * abs(accepted["coefficients"][u]), rel=0.02)
        validate_identification_log(identification_frame(records), "repeats")
        with pytest.raises(ConfigError, match="repeat_ratio"):
            SteppedSineSettings(repeat_ratio=1.5)

    def test_batch_equals_single_steps(self, demo_quiet):
        f = np.array([40.0, 120.0, 333.0])
        batch, _ = run_stepped_sine(demo_quiet, plan(["DX", "NY"], f, 0.5), FAST, noise=False)
        for record in (batch[1], batch[5]):
            single, _ = run_stepped_sine(demo_quiet, plan([record["excited_axis"]], f[[record["step"]]], 0.5), FAST, noise=False)
            assert_allclose(single[0]["coefficients"], record["coefficients"], rtol=1e-10, atol=1e-10)  # zero channels: roundoff

    def test_one_cycle_step_against_a_continuous_reference(self, demo_quiet):
        """The batched ZOH step against an ODE solution with the force law evaluated continuously."""
        model, cycles, frequency, amplitude = demo_quiet, 500, 80.0, 2.0
        t = model.sample_time_s
        excitation = amplitude * np.sin(2 * np.pi * frequency * t * np.arange(cycles))
        state = model.initial_state(1)
        batched = []
        for k in range(cycles):
            u = np.zeros((5, 1))
            u[0, 0] = excitation[k]
            batched.append(model.step(state, u)[5:10, 0])
        # reference: the same controller, the continuous truth integrated over each cycle
        x, xc = model.initial_state(1).plant[:, 0].copy(), model.initial_state(1).controller[:, 0].copy()
        reference = []
        for k in range(cycles):
            measured = model.sensor_output @ x
            reference.append(measured)
            error = model.setpoint_m - measured
            command = model.ctrl_c @ xc + model.ctrl_d @ error
            command[0] += excitation[k]
            xc = model.ctrl_a @ xc + model.ctrl_b @ error

            def rhs(_, state, command=command):
                residual = model.residual_force((model.force_state @ state + model.force_input @ command)[:, None], (model.position_state @ state)[:, None])[:, 0]
                return model.a @ state + model.b @ np.concatenate([command, residual, [1.0]])

            x = scipy.integrate.solve_ivp(rhs, (0, t), x, method="DOP853", rtol=1e-10, atol=1e-14).y[:, -1]
        batched, reference = np.array(batched), np.array(reference)
        swing = np.max(np.abs(reference[:, 0]))
        assert swing > 20e-6  # a large, nonlinear response
        assert np.max(np.abs(batched - reference)) < 2e-3 * swing
        # and the nonlinearity matters at this amplitude: the linear truth is much further off
        state = model.initial_state(1)
        linear = np.array([model.step(state, np.vstack([[excitation[k]], np.zeros((4, 1))]), nonlinear=False)[5:10, 0] for k in range(cycles)])
        assert np.max(np.abs(linear - reference)) > 5 * np.max(np.abs(batched - reference))

    def test_noise_estimate_matches_the_scatter(self, demo_config):
        model = RigModel(rig_from_config(rig_config("demo20"), demo_config))
        settings = SteppedSineSettings(response_min_m=1e-9, response_max_m=1.0)
        records, _ = run_stepped_sine(model, plan(["DX"], np.full(24, 200.0), 0.5), settings, seed=7)
        coefficients = np.array([r["coefficients"] for r in records])
        logged = np.mean([r["noise_std"] for r in records], axis=0)
        for channel in (0, 5, 7, 10):  # U2_DX, V2_DX, V2_NX, I_upper_DX
            scatter = np.sqrt(np.mean(np.abs(coefficients[:, channel] - coefficients[:, channel].mean()) ** 2))
            assert 0.6 < scatter / logged[channel] < 1.6

    @pytest.mark.parametrize("noise", [False, True])
    def test_small_amplitude_mimo_agrees_with_linearized_truth(self, hs_config, noise):
        config = rig_config("hs_eden_like", quiet=not noise)
        model = RigModel(rig_from_config(config, hs_config))
        f = np.linspace(5, 745, 12)
        settings = SteppedSineSettings(response_min_m=1e-9, response_max_m=1.0)
        records, _ = run_stepped_sine(model, plan(AXES, f, 0.3), settings, seed=3, noise=noise)
        inputs = np.zeros((f.size, 4, 4), complex)
        outputs = np.zeros_like(inputs)
        relative_noise = np.zeros((f.size, 4))
        for r in records:
            j = AXES.index(r["excited_axis"])
            inputs[r["step"], :, j], outputs[r["step"], :, j] = r["coefficients"][:4], r["coefficients"][5:9]
            relative_noise[r["step"], j] = r["noise_std"][5 + j] / abs(r["coefficients"][5 + j])
        exact = np.array([r["frequency_hz"] for r in records[: f.size]])
        estimate = outputs @ np.linalg.inv(inputs)
        truth = model.sampled_frequency_response(exact)[:, :4, :4]
        ratio = np.einsum("fkk->fk", estimate) / np.einsum("fkk->fk", truth)
        usable = relative_noise < 2e-3 if noise else np.ones_like(relative_noise, bool)
        assert usable.sum() >= 8  # where the SNR allows (relative noise < 0.2 %)
        assert np.max(np.abs(np.abs(ratio[usable]) - 1)) < 0.01
        assert np.max(np.abs(np.angle(ratio[usable], deg=True))) < 1.0


def test_log_round_trip(tmp_path, demo_quiet):
    records, _ = run_stepped_sine(demo_quiet, plan(["DX", "Z"], np.array([20.0, 50.0]), 0.5), FAST, noise=False)
    path = tmp_path / "identification.parquet"
    write_identification_log(identification_frame(records), path, {"machine": "demo20", "run": "test"})
    frame, info = read_identification_log(path)
    assert info["schema_version"] == "1" and info["metadata"]["channel_units"]["V2_DX"] == "m"
    assert len(frame) == 4 * 20 and set(frame["excited_axis"]) == {"DX", "Z"}
