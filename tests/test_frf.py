"""ETFE: SISO as the thesis, MIMO P = V U^-1, uncertainty, on rig data with known truth."""

import copy

import numpy as np
import pytest
import yaml
from numpy.testing import assert_allclose

from ambid.errors import LogError
from ambid.excitation import StepPlan, SteppedSineSettings, run_stepped_sine
from ambid.frf import channel, frf_table, log_arrays, mimo_etfe, siso_etfe
from ambid.logs import identification_frame
from ambid.rig import RigModel, rig_from_config

from conftest import ROOT

AXES = ["DX", "DY", "NX", "NY"]
WIDE = SteppedSineSettings(response_min_m=1e-9, response_max_m=1.0)  # fixed small amplitude: the linear regime


def coupled_rig(hs_config, quiet):
    config = yaml.safe_load(open(ROOT / "config/rigs/hs_eden_like.yaml"))
    config["truth"]["effects"].append({"name": "cross_coupling", "parameters": {"coefficient": 0.1}})
    if quiet:
        config["truth"].update(sensor_noise_m=0.0, sensor_resolution_m=0.0, current_noise_a=0.0, current_resolution_a=0.0)
    return RigModel(rig_from_config(config, hs_config))


def identify(model, frequency, amplitude=0.15, noise=True, axes=AXES, seed=4):
    n = len(frequency)
    plan = StepPlan(np.repeat(axes, n), np.tile(np.arange(n), len(axes)), np.tile(frequency, len(axes)), np.full(n * len(axes), amplitude))
    records, _ = run_stepped_sine(model, plan, WIDE, seed=seed, noise=noise)
    return identification_frame(records)


@pytest.fixture(scope="module")
def quiet_run(hs_config):
    model = coupled_rig(hs_config, quiet=True)
    return model, log_arrays(identify(model, np.linspace(5, 745, 10), noise=False))


class TestEstimators:
    def test_a_channel_that_reads_exactly_zero_has_a_finite_uncertainty(self):
        from ambid.frf import _ratio

        ratio, std = _ratio(np.array([0.0, 3 + 4j]), np.array([0.1, 0.1]), np.array([2.0, 2.0]), np.array([0.01, 0.01]))
        assert_allclose(ratio, [0.0, 1.5 + 2j])
        assert_allclose(std, [0.1 / 2, 2.5 * np.hypot(0.1 / 5, 0.01 / 2)])  # first order: the noise of n / d

    def test_siso_is_the_thesis_ratio(self, quiet_run):
        _, arrays = quiet_run
        frequency, coefficients, _ = arrays["DX"]
        f, g, _ = siso_etfe(arrays)[("DX", "DX")]
        assert_allclose(g, coefficients[:, 5] / coefficients[:, 0])  # V2_DX / U2_DX, thesis appendix

    def test_mimo_recovers_the_plant_where_siso_cannot(self, quiet_run):
        model, arrays = quiet_run
        frequency, plant, _, condition = mimo_etfe(arrays)
        truth = model.sampled_frequency_response(frequency)[:, :4, :4]
        siso = siso_etfe(arrays)
        assert np.all(condition < 10)
        for k, axis in enumerate(AXES):
            assert np.max(np.abs(plant[:, k, k] / truth[:, k, k] - 1)) < 5e-3
            assert np.max(np.abs(siso[(axis, axis)][1] / truth[:, k, k] - 1)) > 0.03  # the controller's feedback
        cross = np.abs(plant[:, 1, 0] - truth[:, 1, 0]) / np.abs(truth[:, 1, 0])
        siso_cross = np.abs(siso[("DY", "DX")][1] - truth[:, 1, 0]) / np.abs(truth[:, 1, 0])
        assert cross.max() < 1e-2 and siso_cross.max() > 0.5  # x-y cross-coupling: SISO is far off, MIMO is not

    def test_uncertainty_matches_the_errors(self, hs_config):
        model = coupled_rig(hs_config, quiet=False)
        arrays = log_arrays(identify(model, np.linspace(5, 745, 10), noise=True))
        frequency, plant, std, _ = mimo_etfe(arrays)
        truth = model.sampled_frequency_response(frequency)[:, :4, :4]
        normalized = np.abs(plant - truth) / std
        assert 0.5 < np.sqrt(np.mean(normalized**2)) < 2.5  # errors the size the logged noise predicts

    def test_missing_run_and_mismatched_grids(self, quiet_run):
        _, arrays = quiet_run
        with pytest.raises(LogError, match="missing"):
            mimo_etfe({k: v for k, v in arrays.items() if k != "NY"})
        shifted = dict(arrays)
        shifted["NX"] = (arrays["NX"][0] * 1.01, *arrays["NX"][1:])
        with pytest.raises(LogError, match="different frequency grids"):
            mimo_etfe(shifted)

    def test_table_round_trip(self, quiet_run):
        _, arrays = quiet_run
        siso, mimo = siso_etfe(arrays), mimo_etfe(arrays)
        table = frf_table(siso, mimo)
        assert set(table["estimator"]) == {"siso", "mimo"}
        f, values, std = channel(table, "mimo", "NX", "DX")
        assert_allclose(values, mimo[1][:, 2, 0])
        assert np.all(std >= 0)


def test_logs_with_each_bearings_channels_only():
    """Radial steps with the 16 radial channels, Z steps with the 4 axial ones: every FRF the log supports, no other."""
    from ambid.frf import current_etfe
    from ambid.logs import CHANNELS, axis_channels, identification_frame

    rng = np.random.default_rng(4)
    steps = []
    for axis in ("DX", "DY", "NX", "NY", "Z"):
        own = list(axis_channels(axis))
        for k in range(5):
            coefficients = 1e-3 * (rng.standard_normal(len(own)) + 1j * rng.standard_normal(len(own)))
            coefficients[own.index(f"U2_{axis}")] = 1.0
            steps.append({"excited_axis": axis, "step": k, "frequency_hz": 10.0 + k, "amplitude_a": 1.0, "attempts": 1,
                          "channels": own, "coefficients": coefficients, "noise_std": np.full(len(own), 1e-5)})
    arrays = log_arrays(identification_frame(steps))
    assert np.isnan(arrays["DX"][1][:, CHANNELS.index("V2_Z")]).all()
    siso = siso_etfe(arrays)
    assert ("Z", "DX") not in siso and ("DX", "Z") not in siso and ("NY", "DX") in siso and ("Z", "Z") in siso
    table = frf_table(siso, mimo_etfe(arrays), current=current_etfe(arrays))
    assert np.isfinite(table[["re", "im", "std"]].to_numpy()).all()
    assert set(table["estimator"]) == {"siso", "mimo", "current"} and len(table) == 5 * (17 + 16 + 5)
