"""The one sampled-data closed loop: the rig simulates it, the model's stability check judges it, and they agree."""

import copy

import numpy as np
import pytest
import yaml
from numpy.testing import assert_allclose

from ambid.errors import ModelError
from ambid.loop import stability_summary
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.rig import RigModel, rig_from_config
from ambid.sampled_loop import closed_loop_matrix, sampled_system

from conftest import ROOT

#: a rig without imperfections: linearized at the magnetic center, as the model is
IDEAL = {"name": "ideal", "truth": {"effects": [], "gravity_m_s2": 0.0}}

GAIN_KEYS = ("proportional_gain_a_per_m", "integral_gain_a_per_m_s", "derivative_gain_a_s_per_m")


def with_effects(config, *effects):
    config = copy.deepcopy(config)
    config["effects"] = list(config.get("effects") or []) + [{"name": n, "parameters": p} for n, p in effects]
    return config


def gain_times(config, factor):
    config = copy.deepcopy(config)
    for key in GAIN_KEYS:
        config["controller"]["radial"][key] *= factor
    return config


def stepped_one_cycle(model):
    """The rig's one-cycle map obtained by stepping unit deviations through `RigModel.step` (linear, noise-free)."""
    rest = model.initial_state(1)
    sizes = [rest.plant.shape[0], rest.controller.shape[0], rest.sensor_buffer[:, :, 0].size]
    n = sum(sizes)
    batch = model.initial_state(n + 1)
    deviation = np.eye(n + 1)[:n]
    batch.plant += deviation[: sizes[0]]
    batch.controller += deviation[sizes[0] : sizes[0] + sizes[1]]
    batch.sensor_buffer += deviation[sizes[0] + sizes[1] :].reshape(rest.sensor_buffer.shape[:2] + (n + 1,))
    model.step(batch, np.zeros((5, n + 1)), nonlinear=False, quantize=False)
    after = np.vstack([batch.plant, batch.controller, np.roll(batch.sensor_buffer, -1, axis=0).reshape(-1, n + 1)])
    return after[:, :n] - after[:, n:]


def test_closed_loop_matrix_is_what_the_rig_steps(demo_config):
    """Every signal effect at once (fractional delays on some axes, both couplings, eddy lag, low-passes):
    the analytic one-cycle matrix and the rig's simulation step are the same map."""
    config = with_effects(demo_config, ("delay", {"delay_s": 6e-5, "axes": ["DX", "NY"]}),
                          ("amplifier_lowpass", {"cutoff_hz": 2500.0}), ("eddy_current", {"corner_hz": 3000.0}),
                          ("sensor_lowpass", {"cutoff_hz": 8000.0, "order": 2}),
                          ("cross_coupling", {"coefficient": 0.05}), ("cross_coupling", {"coefficient": -0.02, "side": "output"}))
    rig = yaml.safe_load((ROOT / "config/rigs/demo20.yaml").read_text())  # offsets, gravity: an off-center operating point
    rig["truth"]["effects"] = []
    model = RigModel(rig_from_config(rig, config))
    stepped = stepped_one_cycle(model)
    analytic = closed_loop_matrix(model.system, model.controllers)
    # the rig's ring buffer hands the slot it just read on as the last one, which is stale (every axis writes
    # the slot of its delay, shorter than the buffer, before reading it again); the analytic map clears it
    length = model.system.buffer_length
    first = stepped.shape[0] - 5 * length
    stepped[first + 5 * (length - 1) : first + 5 * length, first : first + 5] = 0.0
    assert_allclose(analytic, stepped, rtol=0, atol=1e-12 * np.max(np.abs(stepped)))
    assert model.system.buffer_length == 3 and list(model.system.delay_steps) == [2, 1, 1, 2, 1]


@pytest.mark.parametrize("machine", ["demo20", "hs_eden_like"])
@pytest.mark.parametrize("case", ["nominal", "delay 5 ms", "amplifier 10 Hz", "gain x10", "all effects"])
def test_model_and_rig_agree_on_stability(machine, case, request):
    config = request.getfixturevalue("demo_config" if machine == "demo20" else "hs_config")
    config = {
        "nominal": lambda c: c,
        "delay 5 ms": lambda c: with_effects(c, ("delay", {"delay_s": 5e-3})),
        "amplifier 10 Hz": lambda c: with_effects(c, ("amplifier_lowpass", {"cutoff_hz": 10.0})),
        "gain x10": lambda c: gain_times(c, 10.0),
        "all effects": lambda c: with_effects(c, ("delay", {"delay_s": 3.3e-5}), ("amplifier_lowpass", {"cutoff_hz": 3000.0}),
                                              ("eddy_current", {"corner_hz": 5000.0}), ("sensor_lowpass", {"cutoff_hz": 8000.0}),
                                              ("cross_coupling", {"coefficient": 0.02})),
    }[case](config)
    rows = {row["axis"]: row for row in stability_summary(Plant(machine_from_config(config)))}
    try:
        radius = RigModel(rig_from_config({**IDEAL, "machine": machine}, config)).closed_loop_spectral_radius()
    except ModelError as error:  # the rig refuses an unstable truth, quoting its spectral radius
        radius = float(str(error).rsplit("spectral radius ", 1)[1].rstrip(")"))
    model_radius = max(row["spectral_radius"] for row in rows.values())
    assert model_radius == pytest.approx(radius, abs=1e-6)  # the rig quotes 6 decimals when it refuses
    expected_stable = case in ("nominal", "all effects")
    assert all(row["stable"] is expected_stable for row in list(rows.values())[:4])
    for row in rows.values():
        assert (row["iso_14839_zone"] != "") is row["stable"]
        assert row["verdict"] == ("stable" if row["stable"] else "unstable")


def test_sampled_system_frequency_response_is_the_continuous_plant_with_hold_and_delay(demo_plant):
    """Far below the sampling rate the sampled loop plant is P(jw) times the hold and the delay."""
    delayed = Plant(demo_plant.machine.with_effects([]))
    system = sampled_system(delayed.radial.mass, delayed.radial.damping, delayed.free_stiffness, delayed.actuator_shape,
                            delayed.radial.output_matrix, delayed.current_stiffness, delayed.position_stiffness, [],
                            ("DX", "DY", "NX", "NY"), 5e-5)
    f = np.array([5.0, 50.0, 200.0])
    hold = np.exp(-1j * np.pi * f * 5e-5)  # a zero-order hold is half a cycle of delay, to first order
    expected = delayed.radial_frequency_response(f) * hold[:, None, None]
    # rtol on the coupled elements; the uncoupled ones are 0 in one and round-off (1e-19 m/A) in the other
    assert_allclose(system.frequency_response(f), expected, rtol=2e-3, atol=1e-12 * np.abs(expected).max())


def test_an_unstable_model_is_an_error_naming_it(demo_config):
    from ambid.loop import check_stable

    check_stable(Plant(machine_from_config(demo_config)), "nominal")
    with pytest.raises(ModelError, match=r"^demo20.yaml: variant 'probe' is unstable in closed loop \(spectral radius "
                                         r"1\.01174\d on DX, DY, NX, NY, 1\.0058\d+ on Z.*no ISO 14839-3 zone"):
        check_stable(Plant(machine_from_config(with_effects(demo_config, ("delay", {"delay_s": 5e-3})))),
                     "demo20.yaml: variant 'probe'")
