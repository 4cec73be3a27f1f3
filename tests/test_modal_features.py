"""Fast resonances / anti-resonances for the model update, checked against the Plant and finite differences."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from ambid.effects import effect_from_config
from ambid.errors import ModelError
from ambid.modal_features import ModalFeatureModel, design_variables, root_features
from ambid.plant import Plant

SAME_PLANE = [("DX", "DX"), ("DX", "NX"), ("NX", "DX"), ("NX", "NX"), ("DY", "DY"), ("NY", "DY")]
TAGS = {"demo20": ["design"], "hs_eden_like": ["de_amb", "nde_amb", "motor"]}


def with_effects(machine, *specs):
    return machine.with_effects(machine.effects + tuple(effect_from_config(s, "effects", machine) for s in specs))


def plant_roots(plant, channel, band_hz=3000.0):
    poles, _ = plant.channel_residues(*channel)
    zeros = plant.zeros(*channel)
    pick = lambda r: np.sort_complex(r[(r.imag > 1e-6 * np.abs(r)) & (np.abs(r) < 2 * np.pi * band_hz)])  # noqa: E731
    return pick(poles), pick(zeros)


def model_roots(features, channel, band_hz=3000.0):
    plane = "x" if channel[0][1] == "X" else "y"
    pick = lambda r: np.sort_complex(r[np.abs(r) < 2 * np.pi * band_hz])  # noqa: E731
    return pick(features.poles[plane]), pick(features.zeros[channel])


@pytest.mark.parametrize("name", ["demo20", "hs_eden_like"])
def test_same_poles_and_zeros_as_the_plant(name, request):
    machine = request.getfixturevalue("demo_machine" if name == "demo20" else "hs_machine")
    variables = design_variables(machine, TAGS[name])
    model = ModalFeatureModel(machine, variables, SAME_PLANE)
    values = model.start * np.linspace(0.6, 1.3, len(variables))  # away from the start: the update's path
    values[-1] = 0.006  # added modal damping
    scales = values[:-1]
    specs = []
    for tag in TAGS[name]:
        group = [k for k, v in enumerate(variables) if v.tag == tag]
        specs.append({"name": "element_stiffness", "parameters": {"tag": tag, "scale": scales[group].tolist()}})
    specs.append({"name": "modal_damping", "parameters": {"damping_ratio": 0.006}})
    plant = Plant(with_effects(machine, *specs))
    features = model.evaluate(values)
    for channel in SAME_PLANE:
        poles, zeros = plant_roots(plant, channel)
        fast_poles, fast_zeros = model_roots(features, channel)
        assert_allclose(fast_poles, poles, rtol=1e-9)
        assert_allclose(fast_zeros, zeros, rtol=1e-9)


def test_with_a_flexible_housing(demo_machine):
    machine = with_effects(demo_machine, {"name": "foundation_mode", "parameters": {"mass_kg": 8.0, "frequency_hz": 300.0}})
    model = ModalFeatureModel(machine, design_variables(machine, ["design"]), [("DX", "DX"), ("NX", "DX")])
    features = model.evaluate(model.start)
    plant = Plant(machine)
    for channel in [("DX", "DX"), ("NX", "DX")]:
        poles, zeros = plant_roots(plant, channel)
        fast_poles, fast_zeros = model_roots(features, channel)
        assert_allclose(fast_poles, poles, rtol=1e-9)
        assert_allclose(fast_zeros, zeros, rtol=1e-9)


@pytest.mark.parametrize("name", ["demo20", "hs_eden_like"])
def test_sensitivities_equal_finite_differences(name, request):
    """d lambda / d e of every in-band pole and zero, exact (mode-shape derivatives included)."""
    machine = request.getfixturevalue("demo_machine" if name == "demo20" else "hs_machine")
    variables = design_variables(machine, TAGS[name])
    channels = [("DX", "DX"), ("DX", "NX"), ("NX", "DX"), ("NX", "NX")]
    model = ModalFeatureModel(machine, variables, channels)
    values = model.start * np.linspace(0.7, 1.2, len(variables))
    values[-1] = 0.004
    features = model.evaluate(values, derivatives=True)
    step = 1e-5  # relative; smaller steps drown in the eigensolver's rounding
    roots = [("pole", features.poles["x"], features.pole_derivatives["x"], None)]
    roots += [("zero", features.zeros[c], features.zero_derivatives[c], c) for c in channels]
    for kind, lam, analytic, channel in roots:
        band = np.abs(lam) < 2 * np.pi * 2500
        numeric = np.empty((band.sum(), len(variables)), dtype=complex)
        for p in range(len(variables)):
            shifted = []
            for sign in (1, -1):
                moved = values.copy()
                moved[p] += sign * step * max(abs(values[p]), 1e-3)
                f = model.evaluate(moved)
                other = f.poles["x"] if kind == "pole" else f.zeros[channel]
                shifted.append(np.array([other[np.argmin(np.abs(other - r))] for r in lam[band]]))
            numeric[:, p] = (shifted[0] - shifted[1]) / (2 * step * max(abs(values[p]), 1e-3))
        scale = np.max(np.abs(numeric), axis=1, keepdims=True)
        assert np.max(np.abs(analytic[band] - numeric) / scale) < 1e-4, (kind, channel)


def test_uniform_stiffness_scales_free_free_frequencies_by_its_root(demo_machine):
    """E -> s E on every element: the free-free bending frequencies scale exactly by sqrt(s)."""
    rotor = demo_machine.rotor
    scaled = rotor.with_youngs_modulus_scaled(range(rotor.n_elements), 1.44)
    assert_allclose(scaled.planar_modes(6).frequency_hz[2:], 1.2 * rotor.planar_modes(6).frequency_hz[2:], rtol=1e-10)
    group, loss = rotor.element_group_matrices(range(rotor.n_elements))
    assert_allclose(group, rotor.planar_matrices()["stiffness"], rtol=1e-12, atol=1e-6)


def test_resonance_features_and_standstill_only(demo_machine):
    model = ModalFeatureModel(demo_machine, design_variables(demo_machine, ["design"]), [("DX", "DX")])
    frequency, damping = root_features(model.evaluate(model.start).poles["x"])
    first = np.argmin(np.where(damping < 0.2, frequency, np.inf))
    assert damping[first] == pytest.approx(0.002, rel=0.01)  # loss factor 0.004 (demo20.yaml)
    spinning = with_effects(demo_machine, {"name": "gyroscopic", "parameters": {"speed_rpm": 10000}})
    with pytest.raises(ModelError, match="standstill"):
        ModalFeatureModel(spinning, design_variables(spinning, ["design"]), [("DX", "DX")])


@pytest.mark.parametrize("tags, message", [(["nope"], "no element carries"), (["design", "design"], "shares elements")])
def test_bad_design_variables(demo_machine, tags, message):
    with pytest.raises(ModelError, match=message):
        design_variables(demo_machine, tags)
