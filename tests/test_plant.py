"""Open-loop plant: full vs modal-reduced, rigid-body closed form, poles and zeros, closed loop."""

from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose

from ambid.effects import EFFECTS, effect_from_config
from ambid.errors import ConfigError, ModelError
from ambid.loop import stability_summary, transfer_functions
from ambid.machine import AXIS_LOCATION, RADIAL_AXES, machine_from_config
from ambid.plant import Plant, damping_ratio
from ambid.rotor import planar_to_full


def full_order_response(machine, frequency_hz, speed_rad_s=0.0):
    """Plant from the full 4-DOF FE matrices (eq. 2.9 plus bearings), independent of the modal path."""
    rotor = machine.rotor
    m = rotor.matrices()
    xi, yi, ys = planar_to_full(rotor.n_nodes)

    def row(z_m, plane):
        planar = rotor.planar_displacement_row(z_m)
        full = np.zeros(rotor.n_dof)
        if plane == "x":
            full[xi] = planar
        else:
            full[yi] = planar * ys
        return full

    actuator = np.array([row(machine.bearing(AXIS_LOCATION[a][0]).actuator_position_m, AXIS_LOCATION[a][1]) for a in RADIAL_AXES]).T
    sensor = np.array([row(machine.bearing(AXIS_LOCATION[a][0]).sensor_position_m, AXIS_LOCATION[a][1]) for a in RADIAL_AXES])
    ki, kx = machine.radial_bearings[0].electromagnet.linearize()
    stiffness = m["stiffness"] - kx * actuator @ actuator.T
    w = 2 * np.pi * np.asarray(frequency_hz)[:, None, None]
    dynamic = stiffness - w**2 * m["mass"] + 1j * w * (m["damping"] + speed_rad_s * m["gyroscopic"])
    return sensor @ np.linalg.solve(dynamic, ki * actuator.astype(complex))


def with_effect(machine, name, **parameters):
    return machine.with_effects(list(machine.effects) + [effect_from_config({"name": name, "parameters": parameters}, "test")])


class TestModalReduction:
    @pytest.mark.parametrize("rpm", [0.0, 20000.0])
    def test_reduced_agrees_with_full_order_in_band(self, hs_machine, rpm):
        machine = with_effect(hs_machine, "gyroscopic", speed_rpm=rpm) if rpm else hs_machine
        frequency = machine.radial_grid.frequency_hz
        reduced = Plant(machine).radial_frequency_response(frequency)
        full = full_order_response(hs_machine, frequency, rpm * 2 * np.pi / 60)
        error = np.linalg.norm(reduced - full, axis=(1, 2)) / np.linalg.norm(full, axis=(1, 2))
        assert error.max() < 1e-2
        # the same-axis channels point by point, away from their anti-resonances
        for k in range(4):
            ratio = np.abs(reduced[:, k, k] / full[:, k, k])
            away = np.abs(full[:, k, k]) > 0.2 * np.median(np.abs(full[:, k, k]))
            assert_allclose(ratio[away], 1.0, atol=1e-2)

    @pytest.mark.parametrize("rpm, foundation, blocks", [(0.0, False, 2), (0.0, True, 2), (20000.0, False, 1)])
    def test_modal_superposition_per_uncoupled_block(self, hs_machine, rpm, foundation, blocks):
        """At standstill the x and y planes (with their housings) decouple and are eigen-decomposed apart; spinning, the
        gyroscopic terms couple them.  Either way the FRF is the direct solve of the same second-order model."""
        machine = with_effect(hs_machine, "gyroscopic", speed_rpm=rpm) if rpm else hs_machine
        if foundation:
            machine = with_effect(machine, "foundation_mode", frequency_hz=300.0, mass_kg=20.0, damping_ratio=0.02)
        model = Plant(machine).radial
        assert len(model.uncoupled_states()) == blocks
        assert sorted(np.concatenate(model.uncoupled_states())) == list(range(model.mass.shape[0]))
        frequency = np.geomspace(1.0, 3000.0, 200)
        w = 2 * np.pi * frequency[:, None, None]
        dynamic = model.stiffness - w**2 * model.mass + 1j * w * (model.damping + model.speed_rad_s * model.gyroscopic)
        direct = model.output_matrix @ np.linalg.solve(dynamic, model.input_matrix.astype(complex))
        error = np.linalg.norm(model.frequency_response(frequency) - direct, axis=(1, 2)) / np.linalg.norm(direct, axis=(1, 2))
        assert error.max() < 1e-9

    @pytest.mark.parametrize("machine_fixture", ["hs_machine", "demo_machine"])
    @pytest.mark.parametrize("effects", [
        [("foundation_mode", {"frequency_hz": 300.0, "mass_kg": 20.0, "damping_ratio": 0.02})],
        [("foundation_mode", {"frequency_hz": 2100.0, "mass_kg": 0.2, "damping_ratio": 0.001})],
        [("actuator_coefficients", {"force_constant_scale": [1.1, 0.9, 1.3, 0.8, 1.0],
                                    "bias_current_scale": [0.95, 1.05, 1.3, 0.75, 1.0]})],
        [("actuator_coefficients", {"force_constant_scale": [1.2, 1.0, 1.0, 0.7, 1.0]}),
         ("foundation_mode", {"frequency_hz": 40.0, "mass_kg": 3000.0, "damping_ratio": 0.3})],
        [("noncollocation", {"de_offset_m": 0.012, "nde_offset_m": -0.02})],
        [("noncollocation", {"de_offset_m": -0.004, "nde_offset_m": 0.005}),
         ("actuator_coefficients", {"bias_current_scale": [1.1, 0.9, 1.0, 1.0, 1.0]}),
         ("foundation_mode", {"frequency_hz": 900.0, "mass_kg": 1.0, "damping_ratio": 0.05})],
    ])
    def test_bearings_and_housings_coupled_from_the_receptances_equal_the_modal_model(self, request, machine_fixture,
                                                                                      effects):
        """The diagnosis' actuator, sensor-position and housing candidates take their FRF from the plant without them
        (Woodbury on the bearings' kx, its eigenvectors at the moved sensors, the housings' Schur complement): it must be
        the modal model's with those effects, to rounding."""
        machine = request.getfixturevalue(machine_fixture)
        base = Plant(machine)
        added = [EFFECTS[name](**parameters) for name, parameters in effects]
        plant = base.with_structure_effects(added)
        assert plant._coupled_from is base  # the coupled path is the one under test
        frequency = np.geomspace(1.0, 3000.0, 300)
        coupled = plant.radial_frequency_response(frequency)
        modal = plant.radial.frequency_response(frequency)
        assert np.max(np.abs(coupled - modal)) < 1e-9 * np.max(np.abs(modal))
        # and the ordinary path of a plant built from scratch gives the same
        assert_allclose(Plant(machine.with_effects([*machine.effects, *added])).radial_frequency_response(frequency), modal,
                        rtol=1e-12, atol=0)

    def test_coupling_only_where_it_holds(self, hs_machine):
        """Not on top of housings already there, not for a rotor change, not spinning up: the modal model then."""
        base = Plant(hs_machine)
        housed = base.with_structure_effects([EFFECTS["foundation_mode"](frequency_hz=300.0, mass_kg=20.0)])
        assert housed._coupled_from is base
        assert housed.with_structure_effects([EFFECTS["actuator_coefficients"]()])._coupled_from is None
        assert base.with_structure_effects([EFFECTS["element_stiffness"](tag="motor", scale=0.9)])._coupled_from is None
        assert housed.at_speed(1000.0)._coupled_from is None
        with pytest.raises(ModelError, match="already on a foundation"):
            housed.coupled_response([100.0], housed.current_stiffness, housed.position_stiffness)

    def test_more_modes_converge(self, hs_machine):
        frequency = np.linspace(1, 750, 50)
        full = full_order_response(hs_machine, frequency)
        errors = []
        for modes in (4, 8, 16):
            reduced = Plant(replace(hs_machine, retained_modes=modes)).radial_frequency_response(frequency)
            errors.append(np.max(np.linalg.norm(reduced - full, axis=(1, 2)) / np.linalg.norm(full, axis=(1, 2))))
        assert errors[0] > errors[1] > errors[2]


class TestRigidBody:
    def test_open_loop_poles_match_rigid_rotor_closed_form(self, demo_machine):
        stiff = demo_machine.rotor.with_youngs_modulus_scaled(range(demo_machine.rotor.n_elements), 1e4)
        plant = Plant(replace(demo_machine, rotor=stiff))
        element = demo_machine.rotor.elements[0]
        length = demo_machine.rotor.length_m
        mass = element.material.density_kg_m3 * np.pi / 4 * element.outer_diameter_m**2 * length
        inertia_center = mass * length**2 / 12 + mass * element.outer_diameter_m**2 / 16
        z = np.array([b.actuator_position_m for b in demo_machine.radial_bearings]) - length / 2
        _, kx = demo_machine.radial_bearings[0].electromagnet.linearize()
        rigid_mass = np.diag([mass, inertia_center])
        negative_stiffness = kx * np.array([[2.0, z.sum()], [z.sum(), np.sum(z**2)]])
        expected = np.sort(np.sqrt(np.linalg.eigvals(np.linalg.solve(rigid_mass, negative_stiffness)).real))
        poles, _ = plant.poles()
        unstable = np.unique(np.round(poles[(poles.real > 0) & (np.abs(poles.imag) < 1e-6)].real, 6))
        assert_allclose(np.sort(unstable), expected, rtol=5e-3)

    def test_unstable_pairs_are_reported(self, hs_plant):
        poles, _ = hs_plant.poles()
        real = poles[np.abs(poles.imag) < 1e-6]
        assert np.sum(real.real > 0) == 4 and np.sum(real.real < 0) == 4  # +-a for translation and tilt, x and y


class TestPolesAndZeros:
    def test_first_flexible_mode_in_band_with_material_damping(self, hs_plant):
        poles, _ = hs_plant.poles()
        flexible = poles[(poles.imag > 2 * np.pi * 100)]
        first = flexible[np.argmin(np.abs(flexible))]
        assert 600 < abs(first) / (2 * np.pi) < 700  # thesis Fig. 6.3
        assert_allclose(damping_ratio(first), 0.004 / 2, rtol=0.05)  # loss factor / 2

    def test_collocated_poles_and_zeros_interlace(self, demo_machine):
        bearings = tuple(replace(b, sensor_position_m=b.actuator_position_m) for b in demo_machine.radial_bearings)
        plant = Plant(replace(demo_machine, radial_bearings=bearings))
        poles, _ = plant.poles()
        zeros = plant.zeros("DX", "DX")
        pole_hz = np.unique(np.round(np.abs(poles[poles.imag > 1.0]) / (2 * np.pi), 3))
        zero_hz = np.unique(np.round(np.abs(zeros[zeros.imag > 1.0]) / (2 * np.pi), 3))
        pole_hz, zero_hz = pole_hz[pole_hz < 8000], zero_hz[zero_hz < 8000]
        merged = sorted([(f, "p") for f in pole_hz] + [(f, "z") for f in zero_hz])
        kinds = [k for _, k in merged]
        assert kinds[0] == "z" and all(a != b for a, b in zip(kinds, kinds[1:]))

    def test_zeros_are_frf_minima_also_noncollocated(self, hs_plant):
        for axis in ("DX", "NX"):
            zeros = hs_plant.zeros(axis, axis)
            zero = zeros[(zeros.imag > 2 * np.pi * 100) & (np.abs(zeros) < 2 * np.pi * 1000)][0]
            f0 = abs(zero.imag) / (2 * np.pi)
            k = RADIAL_AXES.index(axis)
            grid = f0 * np.linspace(0.97, 1.03, 601)
            magnitude = np.abs(hs_plant.radial_frequency_response(grid)[:, k, k])
            # a damped zero next to a pole: the magnitude minimum sits within 0.1 % of Im(zero)
            assert abs(grid[np.argmin(magnitude)] / f0 - 1) < 1e-3
            assert magnitude.min() < 0.1 * magnitude.max()

    def test_thesis_pattern_of_anti_resonances(self, hs_plant):
        """DX anti-resonance below the first resonance, NX above it (thesis Table 6.4)."""
        poles, _ = hs_plant.poles()
        resonance = np.min(np.abs(poles[poles.imag > 2 * np.pi * 100])) / (2 * np.pi)
        dx, nx = (hs_plant.zeros(a, a) for a in ("DX", "NX"))
        dx_hz = np.abs(dx[dx.imag > 2 * np.pi * 100][0]) / (2 * np.pi)
        nx_hz = np.abs(nx[nx.imag > 2 * np.pi * 100][0]) / (2 * np.pi)
        assert dx_hz < resonance < nx_hz

    def test_uncoupled_channel_has_no_residues_at_standstill(self, hs_plant):
        poles, residues = hs_plant.channel_residues("DY", "DX")
        assert poles.size == 0 and hs_plant.zeros("DY", "DX").size == 0


class TestClosedLoop:
    def test_table_4_1_identities(self, hs_plant):
        f = np.array([20.0, 300.0, 650.0])
        tf = transfer_functions(hs_plant, f)
        assert_allclose(np.linalg.inv(tf["dynamic_stiffness"]), tf["dynamic_compliance"], rtol=1e-8)
        assert_allclose(tf["output_sensitivity"], tf["input_sensitivity"], rtol=1e-8)  # equal controllers on all axes
        assert_allclose(tf["input_sensitivity"] @ (np.eye(4) - tf["open_loop"]), np.broadcast_to(np.eye(4), (3, 4, 4)), atol=1e-10)

    def test_zero_order_hold(self):
        from ambid.loop import zero_order_hold

        f, t = np.array([0.0, 1000.0, 5000.0]), 50e-6
        hold = zero_order_hold(f, t)
        assert_allclose(np.abs(hold), np.abs(np.sinc(f * t)))
        assert_allclose(np.angle(hold), -np.pi * f * t)

    @pytest.mark.parametrize("name", ["hs_plant", "demo_plant"])
    def test_default_machines_stable_with_margins(self, name, request):
        rows = stability_summary(request.getfixturevalue(name))
        assert all(r["stable"] for r in rows)
        assert all(r["iso_14839_zone"] in ("A", "B") for r in rows)

    def test_unstable_controller_is_detected(self, hs_machine):
        weak = replace(hs_machine.radial_controllers[2], proportional_gain_a_per_m=2e3)  # kp ki < kx on NX only
        controllers = hs_machine.radial_controllers[:2] + (weak,) + hs_machine.radial_controllers[3:]
        rows = stability_summary(Plant(replace(hs_machine, radial_controllers=controllers)))
        assert not any(r["stable"] for r in rows[:4])  # one coupled radial loop

    @pytest.mark.parametrize("name, parameters", [("amplifier_lowpass", {"cutoff_hz": 300.0}),
                                                  ("delay", {"delay_s": 250e-6})])
    def test_added_signal_effects_enter_the_closed_loop(self, hs_machine, name, parameters):
        """A plant given an effect by `Plant.with_signal_effects` (what the diagnosis tries) has the closed loop of the
        machine built with that effect: a 300 Hz amplifier or a 250 us delay destabilizes hs_eden_like in both."""
        added = Plant(hs_machine).with_signal_effects([effect_from_config({"name": name, "parameters": parameters}, "t")])
        built = Plant(with_effect(hs_machine, name, **parameters))
        radius = built.closed_loop_poles().spectral_radius
        assert radius > 1.0
        assert added.closed_loop_poles().spectral_radius == pytest.approx(radius, rel=1e-9)
        assert added.axial_closed_loop_poles().spectral_radius == pytest.approx(
            built.axial_closed_loop_poles().spectral_radius, rel=1e-9)

    def test_per_axis_controller_override(self, hs_config):
        config = {**hs_config, "controller": {**hs_config["controller"], "per_axis": {"NX": {"derivative_gain_a_s_per_m": 20.0}}}}
        machine = machine_from_config(config)
        gains = [c.derivative_gain_a_s_per_m for c in machine.radial_controllers]
        assert gains == [30.0, 30.0, 20.0, 30.0]
        rows = {r["axis"]: r for r in stability_summary(Plant(machine))}
        nominal = {r["axis"]: r for r in stability_summary(Plant(machine_from_config(hs_config)))}
        assert rows["NX"]["sensitivity_peak_db"] != pytest.approx(nominal["NX"]["sensitivity_peak_db"], abs=0.05)
        assert rows["NY"]["sensitivity_peak_db"] == pytest.approx(nominal["NY"]["sensitivity_peak_db"], abs=0.05)

    def test_per_axis_override_names_bad_axis(self, hs_config):
        config = {**hs_config, "controller": {**hs_config["controller"], "per_axis": {"QX": {}}}}
        with pytest.raises(ConfigError, match="controller.per_axis.QX"):
            machine_from_config(config)
