"""Model against measurement: error per channel and band, at the noise floor and with a missing delay."""

import numpy as np
import pandas as pd
import pytest

from ambid.compare import CompareError, channel_errors, excitation_against_bias, model_channels, model_response, summarize
from ambid.machine import RADIAL_AXES as AXES
from ambid.effects import effect_from_config
from ambid.logs import peak_excitation_a
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


# ------------------------------------------------------------------ coil-current sampling
def _cycle_average_by_quadrature(cutoff_hz, sample_time_s, frequency_hz, nodes=2001):
    """The first-order amplifier's current averaged over each cycle of a held command ``u_k = z^k``, by quadrature of
    its exact continuous solution (an independent check of `sampled_chain`'s closed form)."""
    w = 2 * np.pi * cutoff_hz
    z = np.exp(2j * np.pi * frequency_hz * sample_time_s)
    decay = np.exp(-w * sample_time_s)
    state = (1 - decay) / (z - decay)  # x_0 of the steady state: x_(k+1) = e^(-wT) x_k + (1 - e^(-wT)) u_k
    s = np.linspace(0.0, sample_time_s, nodes)
    within = np.exp(-w * s)[None, :] * state[:, None] + (1 - np.exp(-w * s))[None, :]  # x(kT + s) for u_k = 1
    return np.trapezoid(within, s, axis=1) / sample_time_s


def test_coil_current_sampling_conventions_against_their_definitions():
    from ambid.compare import sampled_chain
    from ambid.effects import AmplifierLowpass

    f, T = np.array([10.0, 300.0, 2500.0, 9000.0]), 50e-6
    z = np.exp(2j * np.pi * f * T)
    # an ideal amplifier: one cycle behind U2 when sampled before the command acts, U2 itself over its cycle
    assert np.allclose(sampled_chain([], T, f, "start_of_cycle"), 1 / z, rtol=0, atol=1e-15)
    assert np.allclose(sampled_chain([], T, f, "cycle_average"), 1.0, rtol=0, atol=1e-15)
    amplifier = AmplifierLowpass(cutoff_hz=2500.0)
    average = sampled_chain([amplifier], T, f, "cycle_average")
    assert np.allclose(average, _cycle_average_by_quadrature(2500.0, T, f), rtol=1e-6, atol=0)
    # a slow amplifier's current barely changes over a cycle: its mean is its value half a cycle after the start
    slow = AmplifierLowpass(cutoff_hz=5.0)
    ratio = sampled_chain([slow], T, f[:1], "cycle_average") / sampled_chain([slow], T, f[:1], "start_of_cycle")
    assert ratio[0] == pytest.approx(np.exp(1j * np.pi * f[0] * T), abs=1e-5)
    with pytest.raises(CompareError, match="end_of_cycle"):
        sampled_chain([], T, f, "end_of_cycle")


def _coil_currents(sampling, cutoff_hz, relative_noise, seed, sample_time_s=50e-6):
    from ambid.compare import sampled_chain
    from ambid.effects import AmplifierLowpass

    rng = np.random.default_rng(seed)
    chain = [] if cutoff_hz is None else [AmplifierLowpass(cutoff_hz=cutoff_hz)]
    out = {}
    for axis in AXES:
        values = sampled_chain(chain, sample_time_s, F, sampling)
        std = np.full(F.size, relative_noise)
        out[(f"I_{axis}", axis)] = (F, values + std * (rng.standard_normal(F.size) + 1j * rng.standard_normal(F.size))
                                    / np.sqrt(2), std)
    return out


@pytest.mark.parametrize("sampling, cutoff_hz", [("cycle_average", None), ("cycle_average", 2500.0),
                                                 ("start_of_cycle", 1800.0), ("start_of_cycle", None)])
def test_the_coil_current_sampling_is_taken_from_the_data(demo_machine, sampling, cutoff_hz):
    """A log that averages the current over the cycle (another writer's convention) is read so, and its amplifier's
    bandwidth is not mistaken for the other convention's cycle of lag (at low frequency 2.5 kHz lags 64 us, a cycle
    50 us): each convention is fitted with its own best bandwidth."""
    from dataclasses import replace

    from ambid.compare import coil_current_sampling_fit, with_coil_current_sampling

    measured = _coil_currents(sampling, cutoff_hz, 1e-3, seed=3)
    fit = coil_current_sampling_fit(measured, demo_machine.sample_time_s)
    chi2, amplifier = fit[sampling]
    assert chi2 / fit["points"] < 1.3
    if cutoff_hz is None:  # (noise fits: a loop far above the band is as good as none)
        assert amplifier["order"] == 0 or amplifier.get("cutoff_hz", amplifier.get("natural_hz")) > 20e3, amplifier
    else:
        assert amplifier["order"] == 1 and amplifier["cutoff_hz"] == pytest.approx(cutoff_hz, rel=0.02)
    other = next(s for s in ("start_of_cycle", "cycle_average") if s != sampling)
    # (averaging over the cycle with a second-order loop of about 4 kHz comes closest to an ideal amplifier sampled at
    # the start of the cycle: chi2/pt 2.4 at this noise)
    assert fit[other][0] / fit["points"] > 2
    assert demo_machine.coil_current_sampling == "auto"
    machine, findings = with_coil_current_sampling(demo_machine, measured, "compare")
    assert machine.coil_current_sampling == sampling
    # the default is not worth a note; another convention taken from the data is, with both fits
    assert [f.severity for f in findings] == ([] if sampling == "start_of_cycle" else ["note"])
    if findings:
        assert "averaged over the cycle" in findings[0].message and "start_of_cycle chi2/pt" in findings[0].message
    # a machine file that names the other convention keeps it, with a warning that names the key
    stated = replace(demo_machine, coil_current_sampling=other)
    kept, warnings = with_coil_current_sampling(stated, measured, "compare")
    assert kept.coil_current_sampling == other
    assert [w.severity for w in warnings] == ["warning"] and "controller.coil_current_sampling" in warnings[0].message
    # the model's coil currents follow the machine's convention
    model = model_response(Plant(machine.with_effects(
        [] if cutoff_hz is None else [effect_from_config({"name": "amplifier_lowpass",
                                                         "parameters": {"cutoff_hz": cutoff_hz}}, "e")])), measured)
    errors = summarize(channel_errors(measured, model))
    assert errors[errors["output"] == "all"].iloc[0]["chi2"] < 1.3


@pytest.mark.parametrize("sampling", ["cycle_average", "start_of_cycle"])
def test_a_second_order_current_loop_is_not_read_as_the_other_convention(demo_machine, sampling):
    """A second-order current loop (outside the library) lags like a first-order one plus part of a cycle: fitted with
    first-order amplifiers alone, the independent rig's 2 kHz, damping 0.5 loop on averaged currents was read as
    sampled at the start of the cycle.  With the second-order family both conventions are fitted fairly, the loop is
    found, and a note says the library's first-order amplifier cannot follow it."""
    from ambid.compare import sampled_chain, with_coil_current_sampling, _SecondOrderAmplifier

    rng = np.random.default_rng(5)
    chain = [_SecondOrderAmplifier(2000.0, 0.5)]
    measured = {}
    for axis in AXES:
        values = sampled_chain(chain, 50e-6, F, sampling)
        std = np.full(F.size, 1e-3)
        measured[(f"I_{axis}", axis)] = (F, values + std * (rng.standard_normal(F.size) + 1j * rng.standard_normal(F.size))
                                         / np.sqrt(2), std)
    machine, findings = with_coil_current_sampling(demo_machine, measured, "compare")
    assert machine.coil_current_sampling == sampling
    loop = [f for f in findings if f.code == "coil_current_loop"]
    assert len(loop) == 1 and "second-order current loop of 2000 Hz, damping ratio 0.5" in loop[0].message


def test_coil_currents_that_do_not_tell_the_conventions_apart_keep_the_default(demo_machine):
    measured = _coil_currents("cycle_average", None, 5.0, seed=4)  # noise 5 times the current: a cycle is invisible
    from ambid.compare import with_coil_current_sampling

    machine, findings = with_coil_current_sampling(demo_machine, measured, "diagnose")
    assert machine.coil_current_sampling == "start_of_cycle"
    assert len(findings) == 1 and "do not tell the two apart" in findings[0].message
    positions_only, none = with_coil_current_sampling(demo_machine, {}, "diagnose")
    assert positions_only.coil_current_sampling == "start_of_cycle" and none == []


def test_a_run_excited_near_the_bias_current_is_said_to_carry_more_error_than_it_states(demo_machine):
    # demo20: radial bias 3 A, axial 2 A.  The log's peak amplitude per axis (first level only: the repeats are lower)
    frame = pd.DataFrame({"excited_axis": ["DX", "DX", "DX", "NY", "Z"], "amplitude_a": [0.5, 3.0, 1.5, 1.5, 1.2],
                          "level": [0, 0, 1, 0, 0]})
    peaks = peak_excitation_a(frame)
    assert peaks == {"DX": 3.0, "NY": 1.5, "Z": 1.2}
    findings = excitation_against_bias(demo_machine, {"peak_excitation_a": peaks}, "compare")
    # DX at its whole bias current and Z at 0.6 of its 2 A are warned; NY at half of its 3 A is not
    assert [(f.subject, f.severity, f.code) for f in findings] == [("DX", "warning", "excitation_near_bias"),
                                                                    ("Z", "warning", "excitation_near_bias")]
    assert findings[0].value == pytest.approx(1.0) and "max_bias_fraction" in findings[0].message
    assert "no step was repeated" in findings[0].message  # the thesis' procedure: the describing function itself
    repeated = excitation_against_bias(demo_machine, {"peak_excitation_a": peaks, "repeated_steps": 40}, "compare")
    assert "extrapolates the repeated steps" in repeated[0].message
    # an FRF without amplitudes (a user's UFF58, an older FRF table) says nothing
    assert excitation_against_bias(demo_machine, {}, "compare") == []
