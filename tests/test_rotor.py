"""Timoshenko rotor FEM against closed forms (Euler-Bernoulli, Timoshenko, rigid body)."""

from dataclasses import replace

import numpy as np
import pytest
import scipy.linalg
from numpy.testing import assert_allclose

from ambid.errors import ConfigError
from ambid.rotor import (
    Disk,
    Material,
    Rotor,
    ShaftElement,
    Sleeve,
    hollow_shear_coefficient,
    timoshenko_element_matrices,
    timoshenko_shape_functions,
)

STEEL = Material("steel", youngs_modulus_pa=2.1e11, density_kg_m3=7850, poisson_ratio=0.3)
FREE_FREE_BETA_L = np.array([4.730040745, 7.853204624, 10.99560784, 14.13716549])


def uniform(length_m, diameter_m, n_elements, inner_m=0.0, material=STEEL, disks=()):
    element = ShaftElement(length_m / n_elements, diameter_m, material, inner_diameter_m=inner_m)
    return Rotor(tuple([element] * n_elements), disks=tuple(disks))


def euler_bernoulli_hz(beta_l, length_m, diameter_m, inner_m=0.0, material=STEEL):
    area = np.pi / 4 * (diameter_m**2 - inner_m**2)
    inertia = np.pi / 64 * (diameter_m**4 - inner_m**4)
    return beta_l**2 / (2 * np.pi * length_m**2) * np.sqrt(material.youngs_modulus_pa * inertia / (material.density_kg_m3 * area))


def pinned_pinned_hz(rotor, n_modes):
    """Planar FE frequencies with the end translations removed."""
    planar = rotor.planar_matrices()
    n = planar["mass"].shape[0]
    keep = np.setdiff1d(np.arange(n), [0, n - 2])
    values = scipy.linalg.eigh(planar["stiffness"][np.ix_(keep, keep)], planar["mass"][np.ix_(keep, keep)], eigvals_only=True)
    return np.sqrt(values[:n_modes]) / (2 * np.pi)


def timoshenko_pinned_hz(mode, length_m, diameter_m, material=STEEL):
    """Exact simply supported Timoshenko beam: lower root of the 2x2 frequency determinant."""
    area, inertia = np.pi / 4 * diameter_m**2, np.pi / 64 * diameter_m**4
    kappa = hollow_shear_coefficient(diameter_m, 0.0, material.poisson_ratio)
    ga, ei, rho = kappa * material.shear_modulus * area, material.youngs_modulus_pa * inertia, material.density_kg_m3
    k = mode * np.pi / length_m
    # (rho A w2 - kGA k^2)(rho I w2 - EI k^2 - kGA) - (kGA k)^2 = 0, a quadratic in w2
    a = rho * area * rho * inertia
    b = -(rho * area * (ei * k**2 + ga) + ga * k**2 * rho * inertia)
    c = ga * k**2 * (ei * k**2 + ga) - (ga * k) ** 2
    w2 = (-b - np.sqrt(b**2 - 4 * a * c)) / (2 * a)
    return np.sqrt(w2) / (2 * np.pi)


class TestSlenderBeams:
    def test_free_free_matches_euler_bernoulli(self):
        rotor = uniform(1.0, 0.01, 60)  # L/D = 100
        fe = rotor.planar_modes(6).frequency_hz[2:6]
        assert_allclose(fe, euler_bernoulli_hz(FREE_FREE_BETA_L, 1.0, 0.01), rtol=5e-3)

    def test_pinned_pinned_matches_euler_bernoulli(self):
        rotor = uniform(1.0, 0.01, 60)
        exact = euler_bernoulli_hz(np.pi * np.arange(1, 5), 1.0, 0.01)
        assert_allclose(pinned_pinned_hz(rotor, 4), exact, rtol=5e-3)

    def test_hollow_shaft_free_free(self):
        rotor = uniform(3.0, 0.02, 120, inner_m=0.012)
        fe = rotor.planar_modes(6).frequency_hz[2:6]
        assert_allclose(fe, euler_bernoulli_hz(FREE_FREE_BETA_L, 3.0, 0.02, 0.012), rtol=5e-3)


class TestThickBeam:
    def test_timoshenko_lowering_direction_and_size(self):
        length, diameter = 0.5, 0.1  # L/D = 5: shear and rotary inertia matter
        rotor = uniform(length, diameter, 80)
        fe = pinned_pinned_hz(rotor, 3)
        bernoulli = euler_bernoulli_hz(np.pi * np.arange(1, 4), length, diameter)
        timoshenko = np.array([timoshenko_pinned_hz(n, length, diameter) for n in (1, 2, 3)])
        assert np.all(fe < bernoulli)  # right direction
        assert_allclose(fe, timoshenko, rtol=5e-3)  # right size: the exact Timoshenko solution
        assert 1 - fe[2] / bernoulli[2] > 0.15  # a large effect on the third mode, not a rounding error

    def test_mesh_convergence_is_monotone_from_above(self):
        length, diameter = 0.5, 0.1
        exact = timoshenko_pinned_hz(2, length, diameter)
        errors = [pinned_pinned_hz(uniform(length, diameter, n), 2)[1] / exact - 1 for n in (4, 8, 16, 32)]
        assert all(e > -1e-6 for e in errors)  # consistent mass: frequencies converge from above
        assert all(later < earlier for earlier, later in zip(errors, errors[1:]))
        assert errors[-1] < 1e-3

    def test_a_sleeve_that_carries_its_whole_share_is_the_thicker_shaft(self):
        """A solid 50 mm shaft under a 50-80 mm sleeve of the same steel with ``stiffness_fraction`` 1 is a solid
        80 mm shaft, in shear as in bending (at L/D = 5 the shear term moves the third mode by ~15 %)."""
        length, n = 0.4, 40
        thick = uniform(length, 0.08, n)
        sleeved = replace(uniform(length, 0.05, n), sleeves=(
            Sleeve("sleeve", tuple(range(n)), 0.08, 0.05, STEEL.density_kg_m3, stiffness_fraction=1.0),))
        for name in ("bending_stiffness", "shear_parameter", "mass_per_length", "inertia_per_length"):
            assert_allclose(sleeved.element_properties()[name], thick.element_properties()[name], rtol=1e-12)
        assert_allclose(pinned_pinned_hz(sleeved, 3), pinned_pinned_hz(thick, 3), rtol=1e-10)


class TestMatrices:
    @pytest.fixture
    def rotor(self):
        elements = tuple(ShaftElement(0.05, d, STEEL, inner_diameter_m=di) for d, di in [(0.04, 0), (0.06, 0.02), (0.05, 0.01), (0.04, 0)])
        return Rotor(elements, disks=(Disk(2, 2.0, 0.01, 0.006),))

    def test_symmetry_definiteness_and_skew_gyroscopic(self, rotor):
        m = rotor.matrices()
        assert_allclose(m["mass"], m["mass"].T, atol=1e-14)
        assert_allclose(m["stiffness"], m["stiffness"].T, rtol=1e-12, atol=1e-3)
        assert_allclose(m["gyroscopic"], -m["gyroscopic"].T, atol=1e-14)
        assert np.linalg.eigvalsh(m["mass"]).min() > 0

    def test_two_rigid_body_modes_per_plane(self, rotor):
        m = rotor.matrices()
        values = scipy.linalg.eigh(m["stiffness"], m["mass"], eigvals_only=True)
        assert np.sum(np.abs(values) < 1e-6 * values.max()) == 4  # x, y translation and two tilts
        planar = rotor.planar_modes(4).angular_frequency_rad_s
        assert planar[1] < 1e-4 * planar[2]

    def test_rigid_motion_costs_no_strain_energy(self):
        stiffness, _, _ = timoshenko_element_matrices([0.1], [1e4], [0.3], [10.0], [1e-3])
        translation = np.array([1.0, 0.0, 1.0, 0.0])
        rotation = np.array([0.0, 1.0, 0.1, 1.0])  # u = z about node 1, theta = 1
        assert_allclose(stiffness[0] @ translation, 0, atol=1e-9)
        assert_allclose(stiffness[0] @ rotation, 0, atol=1e-9)

    def test_total_mass(self, rotor):
        expected = sum(STEEL.density_kg_m3 * np.pi / 4 * (e.outer_diameter_m**2 - e.inner_diameter_m**2) * e.length_m for e in rotor.elements) + 2.0
        assert_allclose(rotor.mass_kg, expected)
        # the x-translation rigid mode carries the total mass
        ones = np.zeros(rotor.n_dof)
        ones[0::4] = 1.0
        assert_allclose(ones @ rotor.matrices()["mass"] @ ones, expected, rtol=1e-12)

    def test_shape_functions_interpolate_nodes(self):
        n = timoshenko_shape_functions(np.array([0.0, 1.0]), 0.2, 0.4)
        assert_allclose(n, [[1, 0, 0, 0], [0, 0, 1, 0]], atol=1e-14)

    def test_displacement_row_inside_element_is_exact_for_rigid_tilt(self, rotor):
        z = rotor.node_positions_m
        q = np.zeros(2 * rotor.n_nodes)
        q[0::2], q[1::2] = 0.3 + 2.0 * z, 2.0  # u = 0.3 + 2 z, theta = du/dz
        for position in (0.0, 0.037, 0.1, 0.2):
            assert_allclose(rotor.planar_displacement_row(position) @ q, 0.3 + 2.0 * position)


class TestGyroscopics:
    def test_whirl_split_grows_with_speed(self):
        disk = Disk(node=9, mass_kg=2.0, polar_inertia_kg_m2=0.01, transverse_inertia_kg_m2=0.005)
        rotor = uniform(0.6, 0.03, 12, disks=[disk])
        m = rotor.matrices()
        n = m["mass"].shape[0]
        inverse_mass = np.linalg.inv(m["mass"])
        standstill = rotor.planar_modes(3).frequency_hz[2]
        pairs = []
        for rpm in (0.0, 5000.0, 10000.0, 20000.0):
            omega = rpm * 2 * np.pi / 60
            a = np.block([[np.zeros((n, n)), np.eye(n)], [-inverse_mass @ m["stiffness"], -omega * inverse_mass @ m["gyroscopic"]]])
            f = np.unique(np.round(np.abs(np.linalg.eigvals(a).imag) / (2 * np.pi), 6))
            nearest = np.sort(f[np.argsort(np.abs(f - standstill))[:2]])
            pairs.append(nearest if rpm else np.array([standstill, standstill]))
        backward, forward = np.array(pairs).T
        splits = forward - backward
        assert all(b > a for a, b in zip(splits, splits[1:]))
        assert np.all(backward[1:] < standstill) and np.all(forward[1:] > standstill)


class TestValidation:
    def test_negative_length_names_element(self):
        with pytest.raises(ConfigError, match=r"rotor.elements\[1\].length_m"):
            Rotor((ShaftElement(0.1, 0.05, STEEL), ShaftElement(-0.1, 0.05, STEEL)))

    def test_position_off_rotor(self):
        with pytest.raises(ConfigError, match="outside the rotor"):
            uniform(1.0, 0.05, 4).planar_displacement_row(1.5)


def test_equal_rotors_share_their_modes_and_a_changed_one_does_not():
    """A rotor rebuilt with the same elements (an update applied again) reuses the modes of the first; a modulus
    changed by 1e-9 does not; a rotor whose tags are a list (unhashable) still gets its modes."""
    rotor = uniform(1.0, 0.05, 10)
    modes = rotor.planar_modes(6, (0.25,))
    assert rotor.with_youngs_modulus_scaled([3], 1.0).planar_modes(6, (0.25,)) is modes
    changed = rotor.with_youngs_modulus_scaled([3], 1.0 + 1e-9).planar_modes(6, (0.25,))
    assert changed is not modes and not np.array_equal(changed.angular_frequency_rad_s, modes.angular_frequency_rad_s)
    listed = Rotor(tuple(replace(e, tags=["shaft"]) for e in rotor.elements))
    assert_allclose(listed.planar_modes(6, (0.25,)).angular_frequency_rad_s, modes.angular_frequency_rad_s)
    row = rotor.planar_displacement_row(0.25)
    assert row is rotor.planar_displacement_row(0.25) and not row.flags.writeable
