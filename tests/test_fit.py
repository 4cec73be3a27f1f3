"""The thesis' parametric fit (ch. 5.1) and the classification of poles and zeros."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from ambid.channel_fit import select_modes
from ambid.fit import classify_poles, levy_thesis, sanathanan_koerner, stabilization
from ambid.plant import damping_ratio


def synthetic(frequency_hz):
    """An exactly rational AMB-like channel: rigid +-40, +-50 Hz, mode 700 Hz, anti-resonance 590 Hz."""
    def pair(f, zeta):
        w = 2 * np.pi * f
        return w * np.array([-zeta + 1j * np.sqrt(1 - zeta**2), -zeta - 1j * np.sqrt(1 - zeta**2)])

    poles = np.concatenate([2 * np.pi * np.array([40.0, -40.0, 50.0, -50.0]), pair(700.0, 0.002)])
    zeros = np.concatenate([2 * np.pi * np.array([45.0, -45.0]), pair(590.0, 0.0015)])
    s = 2j * np.pi * np.asarray(frequency_hz)[:, None]
    return -1e-4 * np.prod(s - zeros, axis=1) / np.prod(s - poles, axis=1) * np.prod(-poles) / np.prod(-zeros)


class TestThesisMethod:
    def test_recovers_an_exactly_rational_channel(self):
        f = np.linspace(1, 750, 250)
        fit = levy_thesis(f, synthetic(f), 4, 6)
        rows = classify_poles(fit.poles, fit.zeros, (1, 750))
        resonance = next(r for r in rows if r["kind"] == "resonance")
        anti = next(r for r in rows if r["kind"] == "anti_resonance")
        assert_allclose([resonance["frequency_hz"], anti["frequency_hz"]], [700.0, 590.0], rtol=1e-8)
        assert_allclose([resonance["damping_ratio"], anti["damping_ratio"]], [0.002, 0.0015], rtol=1e-5)
        assert sorted(round(r["frequency_hz"], 3) for r in rows if r["kind"] == "unstable_rigid") == [40.0, 50.0]
        assert fit.condition > 1e20  # the normal equations in Hz monomials: why it is only the reference
        assert_allclose(fit.frequency_response(f), synthetic(f), rtol=1e-6)

    def test_finds_the_model_plants_first_mode(self, demo_plant):
        f = np.linspace(1, 750, 250)
        fit = levy_thesis(f, demo_plant.radial_frequency_response(f)[:, 0, 0], 4, 6)
        resonance = next(r for r in classify_poles(fit.poles, fit.zeros, (1, 750)) if r["kind"] == "resonance")
        poles, _ = demo_plant.poles()
        first = poles[(poles.imag > 0) & (np.abs(poles) < 2 * np.pi * 750)][0]
        assert_allclose(resonance["frequency_hz"], abs(first) / (2 * np.pi), rtol=1e-4)
        assert_allclose(resonance["damping_ratio"], damping_ratio(np.array([first]))[0], rtol=2e-2)


def test_classification_numbers_flexible_modes_and_flags_unphysical_poles():
    w = 2 * np.pi
    poles = np.array([w * 30, -w * 30, w * (-1 + 300j), w * (-1 - 300j), w * (-2 + 600j), w * (-2 - 600j), w * (5 + 400j), w * (5 - 400j), w * (-10 + 2000j), w * (-10 - 2000j)])
    zeros = np.array([w * (-1 + 250j), w * (-1 - 250j)])
    rows = classify_poles(poles, zeros, (1, 750))
    kinds = [(r["kind"], r["number"]) for r in rows]
    assert ("resonance", 1) in kinds and ("resonance", 2) in kinds and ("anti_resonance", 1) in kinds
    assert ("unstable_complex", 0) in kinds and ("out_of_band", 0) in kinds and ("unstable_rigid", 0) in kinds
    first = next(r for r in rows if r["kind"] == "resonance" and r["number"] == 1)
    assert first["frequency_hz"] == pytest.approx(300.0, rel=1e-4)


class TestScaledLeastSquares:
    def test_same_answer_as_the_thesis_without_its_conditioning(self):
        f = np.linspace(1, 750, 250)
        fit = sanathanan_koerner(f, synthetic(f), 4, 6)
        rows = classify_poles(fit.poles, fit.zeros, (1, 750))
        resonance = next(r for r in rows if r["kind"] == "resonance")
        assert resonance["frequency_hz"] == pytest.approx(700.0, rel=1e-9)
        assert resonance["damping_ratio"] == pytest.approx(0.002, rel=1e-6)
        assert fit.condition < 1e6  # the thesis' normal equations: > 1e20 on the same problem
        assert_allclose(fit.frequency_response(f), synthetic(f), rtol=1e-8)

    def test_stabilization_marks_the_true_mode_stable(self):
        f = np.linspace(1, 750, 250)
        rng = np.random.default_rng(0)
        g = synthetic(f) * (1 + 0.02 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)))
        rows = stabilization(f, g, range(6, 17, 2), std=0.03 * np.abs(g))
        stable_physical = [r["frequency_hz"] for r in rows if r["stable"] and r["physical"]]
        assert sum(abs(x / 700 - 1) < 0.01 for x in stable_physical) >= 3
        # whatever else is physical and stable is not persistent at 700 Hz-like rates
        assert select_modes(rows) == pytest.approx([700.0], rel=1e-3)
