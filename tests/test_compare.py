"""Model against measurement: error per channel and band, at the noise floor and with a missing delay."""

import numpy as np
import pytest

from ambid.compare import CompareError, channel_errors, model_channels, summarize
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
    summary = summarize(errors)
    bands = summary[(summary["output"] == "DX") & (summary["input"] == "DX")].set_index("band")
    assert bands.loc["300-1000 Hz", "excess"] > 100 * max(bands.loc["0-10 Hz", "excess"], 1.0)


def test_no_uncertainty_or_no_common_channel_is_an_error(demo_plant):
    model = model_channels(demo_plant, F, CHANNELS)
    with pytest.raises(CompareError, match="uncertainty"):
        channel_errors({("DX", "DX"): (F, model[("DX", "DX")], np.zeros(F.size))}, model)
    with pytest.raises(CompareError, match="no channel"):
        channel_errors({("DY", "DY"): (F, model[("DX", "DX")], np.ones(F.size))}, model)
