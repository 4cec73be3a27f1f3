"""The effect library: registry, parameters, and each effect's fingerprint on the plant FRF."""

from pathlib import Path

import numpy as np
import scipy.optimize
import pytest
import yaml
from numpy.testing import assert_allclose

from ambid.effects import EFFECTS, at_excitation_level, effect_from_config
from ambid.bearing import force_derivatives
from ambid.errors import ConfigError
from ambid.plant import Plant, damping_ratio

ROOT = Path(__file__).resolve().parents[1]
FREQUENCY = np.linspace(1.0, 1000.0, 400)


def plant_with(machine, *specs):
    effects = [effect_from_config({"name": name, "parameters": params}, "test", machine) for name, params in specs]
    return Plant(machine.with_effects(effects))


def first_flexible_pole(plant):
    poles, _ = plant.poles()
    flexible = poles[poles.imag > 2 * np.pi * 100]
    return flexible[np.argmin(np.abs(flexible))]


@pytest.fixture(scope="module")
def nominal(demo_plant):
    return demo_plant.radial_frequency_response(FREQUENCY)


class TestRegistry:
    def test_all_design_effects_registered(self):
        assert set(EFFECTS) == {
            "amplifier_lowpass", "sensor_lowpass", "delay", "eddy_current", "noncollocation",
            "foundation_mode", "cross_coupling", "gyroscopic", "element_stiffness", "modal_damping", "actuator_coefficients",
        }

    def test_schema_lists_exactly_the_registry(self):
        schema = yaml.safe_load(open(ROOT / "workflow/schemas/machine.schema.yaml"))
        assert set(schema["properties"]["effects"]["items"]["properties"]["name"]["enum"]) == set(EFFECTS)

    @pytest.mark.parametrize("name", sorted(EFFECTS))
    def test_every_effect_documented(self, name):
        cls = EFFECTS[name]
        assert "Fingerprint" in (cls.__doc__ or "")
        assert cls.location in ("structure", "input", "output")
        assert all(p.unit and p.description for p in cls.parameters.values())

    def test_round_trip_to_config(self, demo_machine):
        effect = effect_from_config({"name": "delay", "parameters": {"delay_s": 1e-4, "axes": ["DX"]}}, "e", demo_machine)
        assert effect_from_config(effect.to_config(), "e", demo_machine).values == effect.values

    @pytest.mark.parametrize(
        "spec, key",
        [
            ({"name": "warp_drive"}, r"effects\[0\].name"),
            ({"name": "delay", "parameters": {"delay_s": 1e-4, "gain": 2}}, r"effects\[0\].parameters.gain"),
            ({"name": "delay", "parameters": {}}, r"effects\[0\].parameters.delay_s"),
            ({"name": "delay", "parameters": {"delay_s": -1e-4}}, r"effects\[0\].parameters.delay_s"),
            ({"name": "delay", "parameters": {"delay_s": 1e-4, "axes": ["QX"]}}, r"effects\[0\].parameters.axes"),
            ({"name": "element_stiffness", "parameters": {"tag": "nope", "scale": 0.5}}, r"effects\[0\].parameters.tag"),
            ({"name": "element_stiffness", "parameters": {"tag": "design", "scale": [1, 2]}}, r"effects\[0\].parameters.scale"),
            ({"name": "noncollocation", "parameters": {"de_offset_m": -0.5}}, r"effects\[0\].parameters.de_offset_m"),
            ({"name": "cross_coupling", "parameters": {"coefficient": 0.1, "side": "both"}}, r"effects\[0\].parameters.side"),
            ({"name": "modal_damping", "parameters": {"damping_ratio": [0.01] * 11}}, r"effects\[0\].parameters.damping_ratio"),
        ],
    )
    def test_bad_parameters_name_the_key(self, demo_machine, spec, key):
        with pytest.raises(ConfigError, match=key):
            effect_from_config(spec, "effects[0]", demo_machine)


class TestInputOutputFingerprints:
    def test_delay_is_pure_phase(self, demo_machine, nominal):
        tau = 1.5e-4
        with_delay = plant_with(demo_machine, ("delay", {"delay_s": tau})).radial_frequency_response(FREQUENCY)
        ratio = with_delay[:, 0, 0] / nominal[:, 0, 0]
        assert_allclose(np.abs(ratio), 1.0, rtol=1e-12)
        assert_allclose(-np.degrees(np.unwrap(np.angle(ratio))), 360 * FREQUENCY * tau, rtol=1e-9)

    def test_delay_only_on_selected_axes(self, demo_machine, nominal):
        response = plant_with(demo_machine, ("delay", {"delay_s": 1e-4, "axes": ["NX"]})).radial_frequency_response(FREQUENCY)
        assert_allclose(response[:, 0, 0], nominal[:, 0, 0])
        assert not np.allclose(response[:, 2, 2], nominal[:, 2, 2])

    @pytest.mark.parametrize("name", ["amplifier_lowpass", "sensor_lowpass"])
    def test_first_order_lowpass_corner(self, demo_machine, name):
        corner = 400.0
        f = np.array([corner, 10 * corner])
        ratio = plant_with(demo_machine, (name, {"cutoff_hz": corner})).radial_frequency_response(f)[:, 0, 0] / Plant(demo_machine).radial_frequency_response(f)[:, 0, 0]
        assert_allclose(20 * np.log10(abs(ratio[0])), -3.0103, atol=1e-3)
        assert_allclose(np.degrees(np.angle(ratio[0])), -45.0, atol=1e-9)
        assert_allclose(np.degrees(np.angle(ratio[1])), -np.degrees(np.arctan(10.0)), atol=1e-9)

    def test_second_order_sensor_lowpass(self, demo_machine):
        ratio = plant_with(demo_machine, ("sensor_lowpass", {"cutoff_hz": 500.0, "order": 2})).radial_frequency_response([500.0])[0, 0, 0]
        ratio /= Plant(demo_machine).radial_frequency_response([500.0])[0, 0, 0]
        assert_allclose(abs(ratio), 1 / np.sqrt(2), rtol=1e-12)
        assert_allclose(np.degrees(np.angle(ratio)), -90.0, atol=1e-9)

    def test_eddy_current_is_half_order(self, demo_machine):
        corner = 10.0
        f = np.array([1e3, 1e4])
        ratio = plant_with(demo_machine, ("eddy_current", {"corner_hz": corner})).radial_frequency_response(f)[:, 0, 0]
        ratio /= Plant(demo_machine).radial_frequency_response(f)[:, 0, 0]
        slope_db_per_decade = 20 * np.log10(abs(ratio[1]) / abs(ratio[0]))
        assert_allclose(slope_db_per_decade, -10.0, atol=0.1)  # a first-order lag would give -20
        assert -45.0 < np.degrees(np.angle(ratio[1])) < -44.0

    def test_eddy_current_time_domain_approximation(self):
        a, b, c, d = EFFECTS["eddy_current"](corner_hz=150.0).siso_state_space()
        f = np.logspace(-1, np.log10(150.0 * 1e4), 300)
        s = 2j * np.pi * f
        rational = np.array([(c @ np.linalg.solve(sk * np.eye(a.shape[0]) - a, b) + d)[0, 0] for sk in s])
        exact = 1 / np.sqrt(1 + 1j * f / 150.0)
        assert np.max(np.abs(20 * np.log10(np.abs(rational / exact)))) < 0.01
        assert np.max(np.abs(np.angle(rational / exact, deg=True))) < 0.05
        assert np.all(np.linalg.eigvals(a).real < 0)

    def test_eddy_current_time_domain_approximation_keeps_its_corner_on_every_band(self):
        """A band sees the lag where it is small: there the rig's chain must still carry the corner it is given.

        The exact lag's corner fitted to the chain on three decades of frequency up to each upper end; the eight
        sections fitted on the absolute error (stop 49 and before) gave up to +0.87 %.
        """
        corner = 150.0
        a, b, c, d = EFFECTS["eddy_current"](corner_hz=corner).siso_state_space()
        errors = []
        for top_hz in corner * np.logspace(-3.5, 3, 14):
            f = np.logspace(np.log10(top_hz) - 3, np.log10(top_hz), 60)
            s = 2j * np.pi * f
            chain = np.log([(c @ np.linalg.solve(sk * np.eye(a.shape[0]) - a, b) + d)[0, 0] for sk in s])
            fitted = scipy.optimize.minimize_scalar(
                lambda log_corner: np.sum(np.abs(chain + 0.5 * np.log(1 + 1j * f / np.exp(log_corner))) ** 2),
                bounds=(np.log(corner) - 0.05, np.log(corner) + 0.05), method="bounded", options={"xatol": 1e-9})
            errors.append(np.exp(fitted.x) / corner - 1)
        assert np.max(np.abs(errors)) < 1e-4

    @pytest.mark.parametrize("name, parameters", [("amplifier_lowpass", {"cutoff_hz": 300.0}), ("sensor_lowpass", {"cutoff_hz": 300.0, "order": 2})])
    def test_state_space_matches_response(self, name, parameters):
        effect = EFFECTS[name](**parameters)
        a, b, c, d = effect.siso_state_space()
        f = np.array([10.0, 300.0, 3000.0])
        from_ss = [(c @ np.linalg.solve(2j * np.pi * fk * np.eye(a.shape[0]) - a, b) + d)[0, 0] for fk in f]
        assert_allclose(from_ss, effect.response(f, ["DX"])[:, 0, 0], rtol=1e-12)

    def test_cross_coupling_creates_off_diagonal_terms(self, demo_machine, nominal):
        c = 0.05
        response = plant_with(demo_machine, ("cross_coupling", {"coefficient": c})).radial_frequency_response(FREQUENCY)
        assert np.allclose(nominal[:, 1, 0], 0.0)  # none at standstill without coupling
        assert_allclose(response[:, 1, 0], c * nominal[:, 1, 1], rtol=1e-10)  # DX current pulls along DY
        sensor = plant_with(demo_machine, ("cross_coupling", {"coefficient": c, "side": "output"})).radial_frequency_response(FREQUENCY)
        assert_allclose(sensor[:, 1, 0], c * nominal[:, 0, 0], rtol=1e-10)  # DY sensor sees DX motion


class TestStructuralFingerprints:
    def test_element_stiffness_moves_flexible_modes_only(self, demo_machine, demo_plant):
        soft = plant_with(demo_machine, ("element_stiffness", {"tag": "design", "scale": 0.5}))
        assert abs(first_flexible_pole(soft)) < 0.97 * abs(first_flexible_pole(demo_plant))
        rigid = lambda p: np.sort(p.poles()[0].real[p.poles()[0].real > 0])  # noqa: E731
        assert_allclose(rigid(soft), rigid(demo_plant), rtol=1e-2)

    def test_element_stiffness_per_element_factors(self, demo_machine):
        uniform = plant_with(demo_machine, ("element_stiffness", {"tag": "design", "scale": 0.7}))
        listed = plant_with(demo_machine, ("element_stiffness", {"tag": "design", "scale": [0.7, 0.7, 0.7, 0.7]}))
        assert_allclose(first_flexible_pole(uniform), first_flexible_pole(listed))

    def test_modal_damping_per_mode(self, demo_machine, demo_plant):
        damped = plant_with(demo_machine, ("modal_damping", {"damping_ratio": [0.02, 0.0]}))
        assert_allclose(damping_ratio(first_flexible_pole(damped)) - damping_ratio(first_flexible_pole(demo_plant)), 0.02, rtol=0.05)

    def test_modal_damping_adds_damping_not_frequency(self, demo_machine, demo_plant):
        damped = plant_with(demo_machine, ("modal_damping", {"damping_ratio": 0.01}))
        before, after = first_flexible_pole(demo_plant), first_flexible_pole(damped)
        assert_allclose(damping_ratio(after) - damping_ratio(before), 0.01, rtol=0.05)
        assert_allclose(abs(after), abs(before), rtol=1e-3)

    def test_gyroscopic_splits_whirl(self, demo_machine, demo_plant):
        spinning = plant_with(demo_machine, ("gyroscopic", {"speed_rpm": 60000}))
        poles, vectors = spinning.poles()
        near = np.abs(np.abs(poles) - abs(first_flexible_pole(demo_plant))) < 0.2 * abs(first_flexible_pole(demo_plant))
        pair = poles[near & (poles.imag > 0)]
        assert pair.size == 2 and abs(pair[0].imag - pair[1].imag) > 2 * np.pi * 5
        kinds = {spinning.mode_kind(vectors[: spinning.radial.mass.shape[0], k])[1]: abs(poles[k]) for k in np.flatnonzero(near & (poles.imag > 0))}
        assert kinds["forward"] > kinds["backward"]  # gyroscopic stiffening of the forward whirl

    def test_noncollocation_moves_zeros_not_poles(self, demo_machine, demo_plant):
        moved = plant_with(demo_machine, ("noncollocation", {"de_offset_m": 0.03}))
        assert_allclose(np.sort_complex(moved.poles()[0]), np.sort_complex(demo_plant.poles()[0]), rtol=1e-9, atol=1e-6)
        flexible_zero = lambda p: [z for z in p.zeros("DX", "DX") if z.imag > 2 * np.pi * 100][0]  # noqa: E731
        assert abs(flexible_zero(moved)) / abs(flexible_zero(demo_plant)) - 1 > 0.02

    def test_foundation_mode_adds_a_resonance(self, demo_machine, demo_plant):
        housing = plant_with(demo_machine, ("foundation_mode", {"mass_kg": 20.0, "frequency_hz": 250.0, "damping_ratio": 0.02}))
        poles = housing.poles()[0]
        extra = poles[(poles.imag > 0) & (np.abs(np.abs(poles) / (2 * np.pi) - 250) < 50)]
        assert extra.size >= 1
        assert not np.any((demo_plant.poles()[0].imag > 0) & (np.abs(np.abs(demo_plant.poles()[0]) / (2 * np.pi) - 250) < 50))
        table = __import__("ambid.modes", fromlist=["x"]).mode_table(housing)
        assert any(r["kind"] == "foundation" for r in table)


class TestActuatorCoefficients:
    """Force constant and bias current factors move ki and kx as thesis eq. 3.6 says (at the magnetic center)."""

    def test_current_and_position_stiffness_scale(self, demo_machine):
        from ambid.plant import Plant

        effect = effect_from_config({"name": "actuator_coefficients",
                                     "parameters": {"force_constant_scale": [1.1, 1.0, 1.0, 1.0, 0.9],
                                                    "bias_current_scale": [1.0, 1.02, 1.0, 1.0, 1.05]}}, "e", demo_machine)
        before, after = Plant(demo_machine), Plant(demo_machine.with_effects((effect,)))
        ki, kx = after.current_stiffness / before.current_stiffness, after.position_stiffness / before.position_stiffness
        assert ki == pytest.approx([1.1, 1.02, 1.0, 1.0])  # ki ~ k i_b
        assert kx == pytest.approx([1.1, 1.02**2, 1.0, 1.0])  # kx ~ k i_b^2
        axial = np.array(after.axial_stiffness) / np.array(before.axial_stiffness)
        assert axial == pytest.approx([0.9 * 1.05, 0.9 * 1.05**2])

    def test_the_force_law_averaged_over_an_excitation(self, demo_machine):
        """Current alone: kx (1 + E[i_c^2] / i_b^2), ki unchanged (eq. 3.6 averaged, exact); a position excursion
        correlated with the current changes both, as a Monte Carlo average of the force law's derivatives says; the
        variant's own effects stay its own and apply on top."""
        magnet = demo_machine.radial_electromagnets[0]
        bias, gap = magnet.bias_current_a, magnet.nominal_air_gap_m
        own = effect_from_config({"name": "actuator_coefficients", "parameters": {"bias_current_scale": 1.01}}, "e",
                                 demo_machine)
        machine = demo_machine.with_effects((own,))
        shifted = at_excitation_level(machine, {"DX": [0.02 * bias**2, 0.0, 0.0], "NY": [0.01 * bias**2, 0.0, 0.0]})
        assert shifted.effects == machine.effects
        before, after = Plant(machine), Plant(shifted)
        ki, kx = after.current_stiffness / before.current_stiffness, after.position_stiffness / before.position_stiffness
        assert ki == pytest.approx([1.0, 1.0, 1.0, 1.0], abs=1e-9)
        assert kx == pytest.approx([1.02, 1.0, 1.0, 1.01], rel=1e-9)
        # current and position together, correlated -0.8: the Gauss-Hermite mean against 4e6 samples
        var_i, var_x = (0.1 * bias) ** 2, (0.05 * gap) ** 2
        cov = -0.8 * np.sqrt(var_i * var_x)
        correlated = Plant(at_excitation_level(demo_machine, {"DY": [var_i, var_x, cov]}))
        rng = np.random.default_rng(0)
        current, position = np.linalg.cholesky([[var_i, cov], [cov, var_x]]) @ rng.standard_normal((2, 4_000_000))
        _, ki_all, kx_all = force_derivatives(demo_machine.radial_electromagnets[1], bias + current, bias - current, position)
        _, ki0, kx0 = force_derivatives(demo_machine.radial_electromagnets[1], bias, bias, 0.0)
        nominal = Plant(demo_machine)
        assert correlated.current_stiffness[1] / nominal.current_stiffness[1] == pytest.approx(ki_all.mean() / ki0, rel=2e-4)
        assert correlated.position_stiffness[1] / nominal.position_stiffness[1] == pytest.approx(kx_all.mean() / kx0, rel=2e-4)
        with pytest.raises(ConfigError, match="excitation.DX"):
            at_excitation_level(machine, {"DX": [-1.0, 0.0, 0.0]})

    def test_one_value_per_axis_or_one_for_all(self, demo_machine):
        with pytest.raises(ConfigError, match="one per axis"):
            effect_from_config({"name": "actuator_coefficients", "parameters": {"bias_current_scale": [1.0, 1.0]}}, "e",
                               demo_machine)
