"""Virtual rig: truth from config, operating point, exact discretization, delays, stability."""

import copy

import numpy as np
import pytest
import yaml
from numpy.testing import assert_allclose

from ambid.errors import ConfigError, ModelError
from ambid.machine import ALL_AXES
from ambid.rig import RigModel, rig_from_config

from conftest import ROOT


def rig_config(name):
    return yaml.safe_load(open(ROOT / "config" / "rigs" / f"{name}.yaml"))


def quiet(config, **truth):
    """A copy with no noise or quantization (and optional overrides of the truth)."""
    config = copy.deepcopy(config)
    config["truth"].update(sensor_noise_m=0.0, sensor_resolution_m=0.0, current_noise_a=0.0, current_resolution_a=0.0, **truth)
    return config


@pytest.fixture(scope="module")
def hs_rig_model(hs_config):
    return RigModel(rig_from_config(rig_config("hs_eden_like"), hs_config))


class TestOperatingPoint:
    def test_forces_carry_the_weight_and_sensors_sit_at_the_set_point(self, hs_rig_model):
        op, model = hs_rig_model.operating_point, hs_rig_model
        forces = dict(zip(ALL_AXES, op["force"]))
        assert_allclose(forces["DY"] + forces["NY"], model.rotor_mass_kg * 9.81, rtol=1e-6)
        assert abs(forces["DX"] + forces["NX"]) < 1e-6 and abs(forces["Z"]) < 1e-6
        assert_allclose(model.sensor_shape @ op["q"], 0.0, atol=1e-12)
        assert np.all(model.true_bias_a - np.abs(op["force_current"]) > 0)

    def test_magnetic_center_offset_needs_static_current(self, hs_config):
        centered = RigModel(rig_from_config(quiet(rig_config("hs_eden_like"), magnetic_center_offset_m={}, gravity_m_s2=0.0), hs_config))
        assert_allclose(centered.operating_point["command"], 0.0, atol=1e-9)
        offset = RigModel(rig_from_config(quiet(rig_config("hs_eden_like"), gravity_m_s2=0.0), hs_config))
        # the rotor is held away from the magnetic center against the negative stiffness
        assert abs(offset.operating_point["command"][2]) > 0.1

    def test_rest_is_an_equilibrium(self, hs_config):
        model = RigModel(rig_from_config(quiet(rig_config("hs_eden_like")), hs_config))
        state = model.initial_state(2)
        for _ in range(2000):
            channels = model.step(state, np.zeros((5, 2)))
        assert np.max(np.abs(channels[5:10])) < 1e-9  # stays at the set point to roundoff (1/50 of an ADC step)
        assert_allclose(channels[:5, 0], model.operating_point["command"], atol=1e-5)  # 10 uA

    def test_linearization_matches_force_law(self, hs_rig_model):
        model, op = hs_rig_model, hs_rig_model.operating_point
        small = 1e-7
        residual = model.residual_force(op["force_current"][:, None] + small, op["actuator_position"][:, None] + small)
        assert np.max(np.abs(residual)) < 1e-6 * np.max(np.abs(op["force"])) + 1e-9


    def test_residual_is_the_bearing_force_law_minus_its_linearization(self, hs_rig_model):
        """The per-cycle residual writes eq. 3.6 out with per-axis constants: it is `ambid.bearing.force` (at the
        magnetic center's offset, coils that cannot reverse) minus the linearization, far from the operating point too."""
        from ambid.bearing import force

        model, op = hs_rig_model, hs_rig_model.operating_point
        rng = np.random.default_rng(3)
        force_current = op["force_current"][:, None] + rng.uniform(-4.0, 4.0, (5, 40))  # some coils switched off
        position = op["actuator_position"][:, None] + rng.uniform(-2e-4, 2e-4, (5, 40))
        bias = model.true_bias_a[:, None]
        exact = force(model.actuators, np.maximum(bias + force_current, 0.0), np.maximum(bias - force_current, 0.0),
                      position - model.imperfections.magnetic_center_offset_m[:, None])
        linear = (op["force"][:, None] + op["current_stiffness"][:, None] * (force_current - op["force_current"][:, None])
                  + op["position_stiffness"][:, None] * (position - op["actuator_position"][:, None]))
        assert_allclose(model.residual_force(force_current, position), exact - linear, rtol=1e-9,
                        atol=1e-9 * np.max(np.abs(exact)))


class TestLinearPart:
    @pytest.mark.parametrize(
        "tau, band_hz, tolerance",
        [
            (50e-6, 2000.0, 1e-7),  # a whole cycle: exactly z^-1
            # fractional: the continuous output delayed, then sampled; differs from exp(-jw tau) by O((w T)^2) through
            # the ZOH staircase, times the plant's content above the Nyquist frequency (its retained modes up to 23 kHz
            # and the static-correction vectors at 32-34 kHz of `Rotor.planar_modes`: 2.5e-4 at 750 Hz)
            (30e-6, 750.0, 3e-4),
            (55e-6, 750.0, 3e-4),
        ],
    )
    def test_delay_in_the_sampled_response(self, demo_config, tau, band_hz, tolerance):
        base = quiet(rig_config("demo20"))
        base["truth"]["effects"] = [e for e in base["truth"]["effects"] if e["name"] != "delay"]
        delayed = copy.deepcopy(base)
        delayed["truth"]["effects"].append({"name": "delay", "parameters": {"delay_s": tau}})
        f = np.array([10.0, 250.0, 700.0, band_hz])
        plain = RigModel(rig_from_config(base, demo_config)).sampled_frequency_response(f)
        late = RigModel(rig_from_config(delayed, demo_config)).sampled_frequency_response(f)
        for k in range(5):
            assert_allclose(late[:, k, k] / plain[:, k, k], np.exp(-2j * np.pi * f * tau), rtol=tolerance)

    def test_sampled_response_approaches_the_continuous_plant(self, demo_config):
        """Without effects the sampled truth is the model plant seen through a ZOH (half-cycle lag at low f)."""
        config = quiet(rig_config("demo20"), magnetic_center_offset_m={}, gravity_m_s2=0.0, bias_current_error={})
        config["truth"]["effects"] = []
        model = RigModel(rig_from_config(config, demo_config))
        f = np.array([20.0, 100.0])
        sampled = model.sampled_frequency_response(f)[:, :4, :4]
        continuous = model.plant.radial_frequency_response(f)
        zoh = np.exp(-1j * np.pi * f * model.sample_time_s)[:, None, None]
        assert_allclose(sampled, continuous * zoh, rtol=2e-3, atol=1e-3 * np.abs(continuous).max())

    def test_closed_loop_stable_and_unstable_truth_refused(self, demo_config):
        assert RigModel(rig_from_config(rig_config("demo20"), demo_config)).closed_loop_spectral_radius() < 1
        weak = copy.deepcopy(demo_config)
        weak["controller"]["radial"]["proportional_gain_a_per_m"] = 3.0e3  # below kx / ki
        with pytest.raises(ModelError, match="unstable"):
            RigModel(rig_from_config(rig_config("demo20"), weak))


class TestConfig:
    @pytest.mark.parametrize(
        "change, key",
        [
            (lambda t: t.update(magnetic_center_offset_m={"QX": 1e-5}), "truth.magnetic_center_offset_m.QX"),
            (lambda t: t.update(current_offset_a={"DX": [0.1]}), "truth.current_offset_a.DX"),
            (lambda t: t.update(effects=[{"name": "warp"}]), r"truth.effects\[0\].name"),
            (lambda t: t.update(sensor_noise_m=-1.0), "truth.sensor_noise_m"),
        ],
    )
    def test_errors_name_the_key(self, demo_config, change, key):
        config = rig_config("demo20")
        change(config["truth"])
        with pytest.raises(ConfigError, match=key):
            rig_from_config(config, demo_config, source="config/rigs/demo20.yaml")


def test_model_side_never_reads_the_rig():
    """Only the rig module, the procedures that drive a rig they are handed, the virtual experiments of the
    diagnosis suite and the acquisition scripts."""
    allowed = {"rig.py", "rig_effects.py", "excitation.py", "multisine.py", "calibration.py", "experiment.py",
               "acquire_identification.py", "acquire_multisine.py", "acquire_calibration.py", "calibration_sensitivity.py"}
    for path in list((ROOT / "workflow" / "ambid").glob("*.py")) + list((ROOT / "workflow" / "scripts").glob("*.py")):
        text = path.read_text()
        if path.name in allowed:
            continue
        assert "config/rigs" not in text and "from .rig" not in text and "ambid.rig" not in text, path.name
    for path in (ROOT / "workflow" / "ambid").glob("*.py"):
        assert "from .experiment" not in path.read_text(), path.name
        if path.name not in allowed:  # the physics outside the library is the rig's alone
            assert "rig_effects" not in path.read_text(), path.name
    for rules in ("model.smk", "calibrate.smk", "frf.smk", "fit.smk", "update.smk", "diagnose.smk", "report.smk"):
        assert "rig" not in (ROOT / "rules" / rules).read_text()
