"""Model against measurement: error per channel and band, at the noise floor and with a missing delay."""

import numpy as np
import pytest

from ambid.compare import CompareError, channel_errors, model_channels, model_response, summarize
from ambid.machine import RADIAL_AXES as AXES
from ambid.effects import effect_from_config
from ambid.plant import Plant

F = np.linspace(1.0, 1000.0, 250)
CHANNELS = [("DX", "DX"), ("NX", "DX")]


def measure(model, relative_noise, seed):
    """A measurement of ``model`` with complex noise of standard deviation ``relative_noise * |G|``."""
    rng = np.random.default_rng(seed)
    out = {}
    for channel, values in model.items():
        std = relative_noise * np.abs(values)
        noise = std * (rng.standard_normal(F.size) + 1j * rng.standard_normal(F.size)) / np.sqrt(2)
        out[channel] = (F, values + noise, std)
    return out


def test_a_model_equal_to_the_truth_sits_at_the_noise_floor(demo_plant):
    model = model_channels(demo_plant, F, CHANNELS)
    summary = summarize(channel_errors(measure(model, 0.01, 1), model))
    overall = summary[summary["output"] == "all"].iloc[0]
    assert overall["chi2"] == pytest.approx(1.0, abs=0.15) and overall["points"] == 2 * F.size
    per_channel = summary[summary["band"] == "all"]
    assert np.all(per_channel["rms_magnitude_db"] < 0.2)


def test_a_missing_delay_shows_as_phase_lag_growing_with_frequency(demo_machine):
    truth = Plant(demo_machine.with_effects([effect_from_config({"name": "delay", "parameters": {"delay_s": 1e-4}}, "e")]))
    measured = measure(model_channels(truth, F, CHANNELS), 0.01, 2)
    errors = channel_errors(measured, model_channels(Plant(demo_machine), F, CHANNELS))
    channel = errors[(errors["output"] == "DX") & (errors["input"] == "DX")]
    # the model lacks the lag: its phase leads by 360 f tau (36 deg at 1 kHz), magnitude unchanged
    np.testing.assert_allclose(channel["phase_error_deg"], 360 * F * 1e-4, atol=2.5)
    summary = summarize(errors)  # bands from the measured grid
    bands = summary[(summary["output"] == "DX") & (summary["input"] == "DX") & (summary["band"] != "all")]
    assert bands["band"].iloc[0].startswith(f"{F[0]:.4g}-") and bands["band"].iloc[-1].endswith(f"-{F[-1]:.4g} Hz")
    assert bands["points"].min() >= 20 and bands["points"].sum() == F.size
    assert bands["excess"].iloc[-1] > 100 * max(bands["excess"].iloc[0], 1.0)
    fixed = summarize(errors, [0, 10, 100, 300, 1000, np.inf]).set_index(["output", "input", "band"])
    assert fixed.loc[("DX", "DX", "300-1000 Hz"), "excess"] > 100 * max(fixed.loc[("DX", "DX", "0-10 Hz"), "excess"], 1.0)


def test_points_inside_their_noise_carry_no_magnitude_or_phase_error(demo_plant):
    """A decoupled plane's cross channel: the model is round-off, the measurement noise; its dB error (100 dB and more)
    would swamp the overall rms the report prints, so only resolved points (|G| > 3 std) have one."""
    model = model_channels(demo_plant, F, CHANNELS)
    measured = measure(model, 0.01, 3)
    rng = np.random.default_rng(3)
    noise = 1e-9 * (rng.standard_normal(F.size) + 1j * rng.standard_normal(F.size)) / np.sqrt(2)
    measured[("DY", "DX")] = (F, noise, np.full(F.size, 1e-9))
    model[("DY", "DX")] = np.full(F.size, 1e-22 + 0j)
    errors = channel_errors(measured, model)
    cross = errors[errors["output"] == "DY"]
    assert cross["magnitude_error_db"].isna().all() and cross["phase_error_deg"].isna().all()
    assert cross["normalized_error"].notna().all()  # chi2 still counts every point
    overall = summarize(errors).query("output == 'all'").iloc[0]
    assert overall["rms_magnitude_db"] < 0.2 and overall["points"] == 3 * F.size
    # a noise point beyond three sigma against the model's round-off: no dB error either
    measured[("DY", "DX")] = (F, np.full(F.size, 4e-9 + 0j), np.full(F.size, 1e-9))
    assert channel_errors(measured, model).query("output == 'DY'")["magnitude_error_db"].isna().all()


def test_no_uncertainty_or_no_common_channel_is_an_error(demo_plant):
    model = model_channels(demo_plant, F, CHANNELS)
    with pytest.raises(CompareError, match="uncertainty"):
        channel_errors({("DX", "DX"): (F, model[("DX", "DX")], np.zeros(F.size))}, model)
    with pytest.raises(CompareError, match="no channel"):
        channel_errors({("DY", "DY"): (F, model[("DX", "DX")], np.ones(F.size))}, model)


def test_a_noise_free_channel_is_refused_by_name():
    """A simulated log without noise: the cross channels of a decoupled machine read exactly zero with zero
    uncertainty, which no misfit can weigh; the error names the channel instead of failing later as a division."""
    import pandas as pd

    from ambid.compare import measured_channels

    frequency = np.array([10.0, 20.0, 30.0])
    rows = [{"estimator": "siso", "output": "DX", "input": "DX", "frequency_hz": f, "re": 1e-6, "im": 0.0, "std": 1e-8,
             "condition": np.nan, "systematic_std": 0.0} for f in frequency]
    rows += [{"estimator": "current", "output": "DX", "input": "DX", "frequency_hz": f, "re": 0.5, "im": 0.0,
              "std": 0.0 if f > 15 else 1e-3, "condition": np.nan, "systematic_std": 0.0} for f in frequency]
    with pytest.raises(CompareError, match=r"current DX/DX: no uncertainty at 2 of 3 frequencies \(first 20 Hz\)"):
        measured_channels(pd.DataFrame(rows))
    rows[-1]["std"] = rows[-2]["std"] = 1e-3
    assert set(measured_channels(pd.DataFrame(rows))) == {("DX", "DX"), ("I_DX", "DX")}


def test_enough_modes_for_a_stiff_rotor_with_lumped_masses(demo_config):
    """A stiffer rotor carrying disks: the plain 12-mode truncation misses its anti-resonances by more than the floor
    tolerates; the static correction of `Rotor.planar_modes` keeps 12 modes enough, and `enough_modes` checks it."""
    import copy
    from dataclasses import replace

    from ambid.compare import enough_modes, truncation_error
    from ambid.machine import machine_from_config

    config = copy.deepcopy(demo_config)
    for element in config["rotor"]["elements"]:
        element["outer_diameter_m"] = 0.06
    config["rotor"]["disks"] = [{"node": n, "mass_kg": 3.0, "polar_inertia_kg_m2": 4e-3, "transverse_inertia_kg_m2": 2e-3}
                                for n in (3, 10, 17)]
    machine = machine_from_config(config)
    frequency = machine.radial_grid.frequency_hz
    reference = model_response(Plant(replace(machine, retained_modes=40)), {(o, i): (frequency,) for o in AXES for i in AXES})
    measured = {key: (frequency, values, 1e-3 * np.abs(values) + 1e-12) for key, values in reference.items()}
    plain = model_response(Plant(machine, static_correction=False), measured)
    plain_error = max(np.max(np.abs(plain[k] - reference[k]) / measured[k][2]) for k in measured)
    assert plain_error > 0.1  # what a plain truncation at 12 modes would leave: above a tenth of a 0.1 % floor
    assert truncation_error(machine, measured, 12, reference)[0] < 0.1
    modes, own, error = enough_modes(machine, measured)
    assert modes == 12 and own[0] < 0.1 and error[0] < 0.1
    # with the floor a hundred times finer, 12 modes are not enough: more are chosen
    fine = {key: (f, values, std / 100) for key, (f, values, std) in measured.items()}
    modes, own, error = enough_modes(machine, fine)
    assert modes > 12 and own[0] > 0.1 and error[0] <= 0.1
