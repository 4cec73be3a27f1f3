"""Commissioning views: margins against closed forms, the measured sensitivity from a log, the ISO zone limits."""

import re

import numpy as np
import pandas as pd
import pytest

from ambid.commissioning import ISO_ZONE_LIMITS_DB, excitation_check, loop_margins, measured_sensitivity, sensitivity_rows


def integrator_with_delay(frequency_hz, gain_rad_s, delay_s):
    s = 2j * np.pi * frequency_hz
    loop = gain_rad_s * np.exp(-s * delay_s) / s
    return 1.0 / (1.0 + loop)


def test_margins_of_an_integrator_with_delay_match_the_closed_form():
    k, tau = 2 * np.pi * 50.0, 1e-3  # crossover at 50 Hz, 1 ms
    frequency = np.logspace(0, 3.5, 3000)
    margins = loop_margins(frequency, integrator_with_delay(frequency, k, tau))
    # |L| = 1 at w = k: phase -90 deg - k tau
    assert margins["phase_margin_deg"] == pytest.approx(90 - np.degrees(k * tau), abs=0.05)
    assert margins["phase_margin_hz"] == pytest.approx(50.0, rel=1e-3)
    # phase -180 deg at w = pi / (2 tau): |L| = k / w there
    w180 = np.pi / (2 * tau)
    assert margins["upper_gain_margin_db"] == pytest.approx(20 * np.log10(w180 / k), abs=0.02)
    assert margins["upper_gain_margin_hz"] == pytest.approx(w180 / (2 * np.pi), rel=1e-3)
    assert np.isnan(margins["lower_gain_margin_db"])  # a stable plant has no lower margin


def test_no_crossing_in_the_band_gives_nan_not_a_number():
    frequency = np.logspace(0, 1, 50)  # far below the crossover at 50 Hz
    margins = loop_margins(frequency, integrator_with_delay(frequency, 2 * np.pi * 50, 1e-3))
    assert all(np.isnan(v) for v in margins.values())


def test_measured_sensitivity_is_u2_over_the_known_sine_excitation():
    frequency = np.linspace(5, 500, 40)
    truth = integrator_with_delay(frequency, 2 * np.pi * 60, 5e-4)
    amplitude = np.full(frequency.size, 0.3)
    u2 = truth * (-1j * amplitude)  # E_u = A sin(w t): the phasor -j A
    rows = []
    for f, a, value in zip(frequency, amplitude, u2):
        rows.append({"excited_axis": "DX", "step": len(rows), "frequency_hz": f, "amplitude_a": a, "channel": "U2_DX",
                     "re": value.real, "im": value.imag, "noise_std": 1e-4, "level": 0})
        rows.append({"excited_axis": "DX", "step": len(rows), "frequency_hz": f, "amplitude_a": a / 2, "channel": "U2_DX",
                     "re": 9.0, "im": 9.0, "noise_std": 1e-4, "level": 1})  # a repeated step: not the sensitivity
    measured = measured_sensitivity(pd.DataFrame(rows))
    f, s, std = measured["DX"]
    assert np.allclose(f, frequency) and np.allclose(s, truth) and np.allclose(std, 1e-4 / 0.3)
    row = sensitivity_rows({"DX": (f, s)}, "measured")[0]
    peak = np.max(np.abs(truth))
    assert row["sensitivity_peak_db"] == pytest.approx(20 * np.log10(peak))
    assert row["iso_14839_zone"] == ("A" if peak < 3 else "B" if peak < 4 else "C" if peak < 5 else "D")


def test_iso_zone_limits_in_db():
    assert [round(limit, 1) for limit, _ in ISO_ZONE_LIMITS_DB] == [9.5, 12.0, 14.0]
    assert [zone for _, zone in ISO_ZONE_LIMITS_DB] == ["A", "B", "C"]


def test_measured_and_model_sensitivity_agree_on_a_simulated_loop(demo_plant):
    """The model's own output sensitivity, put into a log as U2 = S (-j A), comes back with its ISO zone and margins."""
    from ambid.commissioning import model_sensitivity

    frequency = np.logspace(0, 3, 300)
    model = model_sensitivity(demo_plant, frequency)
    assert set(model) >= {"DX", "DY", "NX", "NY"}
    # an AMB loop stabilizes an unstable plant: S -> 1 at high frequency, a lower gain margin exists (negative dB)
    for axis in ("DX", "NX"):
        s = model[axis]
        assert abs(s[-1]) == pytest.approx(1.0, abs=0.3)
        margins = loop_margins(frequency, s)
        assert margins["lower_gain_margin_db"] < 0 and 0 < margins["phase_margin_deg"] < 90


def test_levitated_modes_and_campbell(demo_plant):
    from ambid.commissioning import campbell, levitated_modes

    frequency, damping, shapes = levitated_modes(demo_plant, count=4)
    flexible = demo_plant.modes.frequency_hz[demo_plant.modes.frequency_hz > 0.5]
    # two rigid-body suspension modes far below the first free-free bending mode (demo20's housing mode follows),
    # then the first bending mode near its free-free frequency; each mode once (x plane)
    assert frequency.size == 4 and np.all(np.diff(frequency) > 0)
    assert frequency[1] < 0.1 * flexible[0] and np.any(np.abs(frequency / flexible[0] - 1) < 0.1)
    assert np.allclose(np.max(np.abs(shapes), axis=0), 1.0) and np.all(damping > 0)
    modes = campbell(demo_plant, [0.0, 30000.0], 2 * flexible[0])
    spinning = modes[modes["speed_rpm"] > 0]
    assert set(modes.loc[modes["speed_rpm"] == 0, "whirl"]) == {"planar"}
    assert {"forward", "backward"} <= set(spinning["whirl"])
    # the gyroscopic split of the first bending mode: forward above backward
    bending = frequency[np.argmin(np.abs(frequency / flexible[0] - 1))]
    near = spinning[np.abs(spinning["frequency_hz"] - bending) < 0.1 * bending]
    assert near.loc[near["whirl"] == "forward", "frequency_hz"].max() > near.loc[near["whirl"] == "backward",
                                                                                 "frequency_hz"].min()


@pytest.fixture(scope="module")
def example():
    from ambid.mfile import read_thesis_m
    from conftest import ROOT

    return read_thesis_m(ROOT / "data/demo20/thesis01/identification.m")


class TestExcitationCheck:
    """A log from another writer may not carry what S = U2 / E_u needs; a meaningless |S| grades any loop in zone A."""

    def test_the_example_log_is_graded(self, example, demo_plant):
        assert excitation_check(measured_sensitivity(example), demo_plant) == ("", "")

    def test_amplitude_in_ma_is_not_graded(self, example, demo_plant):
        grade, _ = excitation_check(measured_sensitivity(example.assign(amplitude_a=1e3 * example["amplitude_a"])),
                                    demo_plant)
        assert re.search(r"\|S\| is 0\.00\d+ times the model's .* amplitude_a is not the excitation's amplitude in A "
                         r"\(it looks like mA\)", grade), grade

    def test_amplitude_taken_from_u2_is_not_graded(self, example, demo_plant):
        """What the table reader does without an amplitude_a column: |S| = 1 at every step, zone A for any loop."""
        u2 = example[example["channel"] == "U2_" + example["excited_axis"]]
        amplitude = dict(zip(zip(u2["excited_axis"], u2["step"]), np.hypot(u2["re"], u2["im"])))
        frame = example.assign(amplitude_a=[amplitude[key] for key in zip(example["excited_axis"], example["step"])])
        assert all(r["iso_14839_zone"] == "A" for r in sensitivity_rows(
            {a: (f, s) for a, (f, s, _) in measured_sensitivity(frame).items()}, "measured"))  # what was reported
        grade, _ = excitation_check(measured_sensitivity(frame), demo_plant)
        assert "excitation amplitude is |U2| at every step" in grade

    def test_phases_of_another_reference_give_no_margins(self, example, demo_plant):
        """Phases referred to a cosine (or to each window's start) instead of the start of A sin(w t): the zone reads
        |S| and stands, the margins read the phase of L and are not given."""
        frame = example.copy()
        frame["re"], frame["im"] = -example["im"], example["re"]  # every coefficient times j (a quarter turn)
        grade, margins = excitation_check(measured_sensitivity(frame), demo_plant)
        assert grade == "" and re.search(r"the phase of S is \d+ degrees off the model's .* margins, are unknown", margins)
