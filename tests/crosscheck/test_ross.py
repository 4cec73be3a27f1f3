"""Cross-check of the ambid rotor model against ROSS (independent rotordynamics software).

The same rotors are built in ambid and in ROSS (ross-rotordynamics 2.3.0) and the
natural frequencies of the free-free rotor are compared:

(a) a uniform steel shaft,
(b) a stepped shaft of two materials with hollow sections and two rigid disks,
(c) the demo20 rotor of ``config/machines/demo20.yaml``,
(d) the forward and backward whirl frequencies of rotor (b) at 20000 rpm,
(e) the open-loop AMB plant P(jw) [m/A] of demo20 (the bearings' negative
    position stiffness, actuators and sensors at their own nodes), at standstill,
    at 30000 rpm and with elements 5-8 at half stiffness (thesis ch. 5.3): ambid's
    modal model with static correction against ROSS' direct solve of the full
    finite-element dynamic stiffness, ``ki (K - w^2 M + j w Omega G)^-1``.

Same physics in both codes
--------------------------
* Timoshenko beam elements with shear deformation and rotary inertia
  (ROSS: ``shear_effects=True, rotary_inertia=True``, the defaults).
* Same material: E, G and rho; both codes derive the Poisson ratio in the
  shear coefficient as E / (2 G) - 1, so an explicit ``shear_modulus_pa`` is
  honoured the same way in both.
* Same shear coefficient: both use Cowper's (1966) hollow-circle formula
  ``kappa = 6 (1 + nu) (1 + m^2)^2 / ((7 + 6 nu) (1 + m^2)^2 + (20 + 12 nu) m^2)``,
  ``m = d_i / d_o`` (ROSS: ``shear_method_calc="cowper"``, the default).
* Rigid disks with mass, transverse (diametral) and polar inertia.
* No bearings at all: ROSS accepts a rotor without bearing elements, so both
  models are truly free-free.

Only lateral (bending) modes are compared.  ROSS has 6 DOF per node, so its
modal analysis also returns axial and torsional modes; they are dropped with
ROSS' own classification (``Shape.mode_type``).  Rigid-body modes (numerically
zero at standstill) are skipped: below `RIGID_LIMIT_HZ` in both codes.  At
standstill each bending frequency appears twice in ROSS (x and y planes).
At speed, ROSS' whirl label (``Shape.whirl``) is compared with the orbit sense
of ambid's eigenvector, so the sign convention of the gyroscopic matrix is
checked too.

ROSS' modal analysis is ``Rotor.run_modal(speed, sparse=False)`` (dense
``scipy.linalg.eig`` of its state matrix).  The first call compiles ROSS' numba
orbit code (about 5 s); the whole module runs in about 10 s.
"""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import yaml

rs = pytest.importorskip("ross")

REPO = Path(__file__).resolve().parents[2]
try:
    import ambid  # noqa: F401
except ModuleNotFoundError:  # not installed: use the source tree
    sys.path.insert(0, str(REPO / "workflow"))

from ambid.effects import effect_from_config  # noqa: E402
from ambid.machine import RADIAL_AXES, machine_from_config  # noqa: E402
from ambid.plant import Plant  # noqa: E402
from ambid.ross_export import to_ross_rotor  # noqa: E402
from ambid.rotor import Disk, Material, Rotor, ShaftElement  # noqa: E402

RELATIVE_TOLERANCE = 0.005  # 0.5 %
RIGID_LIMIT_HZ = 1.0  # modes below this count as rigid-body (numerically zero) modes
RIGID_PLANAR_MODES = 2  # translation and tilt, first in ambid's planar modes
N_FLEXIBLE = 6  # flexible bending modes compared per case
ROSS_NUM_MODES = 60  # ROSS post-processes num_modes // 2 modes (lateral, axial, torsional)
SPEED_RPM = 20000.0

STEEL = Material("steel", youngs_modulus_pa=2.0e11, density_kg_m3=7850.0, poisson_ratio=0.3)
TITANIUM = Material("titanium", youngs_modulus_pa=1.14e11, density_kg_m3=4430.0, poisson_ratio=0.34)


# ------------------------------------------------------------------- rotors
def uniform_shaft():
    """(a) Free-free steel shaft, 1 m long, 50 mm diameter, 40 elements."""
    return Rotor(elements=tuple(ShaftElement(1.0 / 40, 0.050, STEEL) for _ in range(40)))


def stepped_shaft():
    """(b) Stepped shaft, 0.7 m, 28 elements of 25 mm, two materials, two rigid disks.

    Sections: solid steel 40 mm; hollow steel 60/30 mm; hollow titanium 50/20 mm;
    solid steel 35 mm.  Disks at node 4 (5 kg) and node 20 (3 kg).
    """
    length_m = 0.025
    elements = (
        [ShaftElement(length_m, 0.040, STEEL)] * 4
        + [ShaftElement(length_m, 0.060, STEEL, inner_diameter_m=0.030)] * 8
        + [ShaftElement(length_m, 0.050, TITANIUM, inner_diameter_m=0.020)] * 12
        + [ShaftElement(length_m, 0.035, STEEL)] * 4
    )
    disks = (
        Disk(node=4, mass_kg=5.0, polar_inertia_kg_m2=0.020, transverse_inertia_kg_m2=0.012),
        Disk(node=20, mass_kg=3.0, polar_inertia_kg_m2=0.010, transverse_inertia_kg_m2=0.006),
    )
    return Rotor(elements=tuple(elements), disks=disks)


def demo20_rotor():
    """(c) The rotor of config/machines/demo20.yaml."""
    with open(REPO / "config" / "machines" / "demo20.yaml") as stream:
        config = yaml.safe_load(stream)
    return machine_from_config(config).rotor


def ross_rotor(rotor):
    """The same free-free rotor in ROSS (no bearings), checking the material conversion."""
    converted = to_ross_rotor(rotor)
    for element, original in zip(converted.shaft_elements, rotor.elements):
        # both codes use E / (2 G) - 1 in the shear coefficient
        assert element.material.Poisson == pytest.approx(original.material.poisson_ratio, rel=1e-12)
    return converted


# ------------------------------------------------------------ frequencies
def ross_lateral_modes(rotor, speed_rad_s):
    """ROSS' lateral modes above `RIGID_LIMIT_HZ`: frequencies [Hz] (ascending) and whirl labels."""
    modal = ross_rotor(rotor).run_modal(speed=speed_rad_s, num_modes=ROSS_NUM_MODES, sparse=False)
    frequency_hz, whirl = [], []
    for wd, shape in zip(modal.wd, modal.shapes):
        if shape.mode_type == "Lateral" and wd / (2 * np.pi) > RIGID_LIMIT_HZ:
            frequency_hz.append(wd / (2 * np.pi))
            whirl.append(shape.whirl)
    order = np.argsort(frequency_hz)
    return np.asarray(frequency_hz)[order], np.asarray(whirl)[order]


def ambid_whirl_modes(rotor, speed_rad_s):
    """ambid's whirl frequencies [Hz] at a speed, from the full 4-DOF matrices.

    Eigenvalues of the first-order form of ``M q'' + Omega G q' + K q = 0``
    (state ``[q, q']``, free-free, undamped).  The whirl sense of each mode is
    that of the x-y orbits of its nodes: forward when they turn like the spin
    (from +x to +y), i.e. ``Im(conj(X) Y) < 0`` for ``s = +j omega``.

    Returns
    -------
    forward_hz, backward_hz : arrays
        Ascending, modes above `RIGID_LIMIT_HZ` only.
    """
    matrices = rotor.matrices()
    mass, stiffness, gyroscopic = matrices["mass"], matrices["stiffness"], matrices["gyroscopic"]
    n = mass.shape[0]
    state = np.block(
        [
            [np.zeros((n, n)), np.eye(n)],
            [-np.linalg.solve(mass, stiffness), -speed_rad_s * np.linalg.solve(mass, gyroscopic)],
        ]
    )
    eigenvalues, eigenvectors = scipy.linalg.eig(state)
    frequency_hz = eigenvalues.imag / (2 * np.pi)
    keep = frequency_hz > RIGID_LIMIT_HZ
    frequency_hz, eigenvectors = frequency_hz[keep], eigenvectors[:, keep]
    x, y = eigenvectors[0:n:4], eigenvectors[1:n:4]
    spin = -np.sum(np.imag(np.conj(x) * y), axis=0) / np.sum(np.abs(x) ** 2 + np.abs(y) ** 2, axis=0)
    assert np.all(np.abs(spin) > 0.05), "a whirl mode of the free rotor should not be planar"
    return np.sort(frequency_hz[spin > 0]), np.sort(frequency_hz[spin < 0])


def assert_close(ours_hz, ross_hz, label):
    """Relative agreement within `RELATIVE_TOLERANCE`; prints the largest difference."""
    ours_hz, ross_hz = np.asarray(ours_hz), np.asarray(ross_hz)
    relative = np.abs(ours_hz - ross_hz) / ross_hz
    print(f"{label}: max relative difference {relative.max():.2e}")
    for a, b, r in zip(ours_hz, ross_hz, relative):
        print(f"  ambid {a:12.4f} Hz   ross {b:12.4f} Hz   {r:.2e}")
    assert relative.max() < RELATIVE_TOLERANCE, f"{label}: ambid {ours_hz} Hz vs ROSS {ross_hz} Hz"


def check_standstill(rotor, label):
    """Compare the first `N_FLEXIBLE` free-free bending frequencies at standstill."""
    ours_hz = rotor.planar_modes(RIGID_PLANAR_MODES + N_FLEXIBLE).frequency_hz
    assert np.all(ours_hz[:RIGID_PLANAR_MODES] < RIGID_LIMIT_HZ), "ambid's first two modes should be rigid"
    ours_hz = ours_hz[RIGID_PLANAR_MODES:]
    ross_hz, _ = ross_lateral_modes(rotor, 0.0)
    assert ross_hz.size >= 2 * N_FLEXIBLE, f"ROSS returned only {ross_hz.size} lateral modes"
    pairs = ross_hz[: 2 * N_FLEXIBLE].reshape(N_FLEXIBLE, 2)  # x and y plane of each mode
    np.testing.assert_allclose(pairs[:, 0], pairs[:, 1], rtol=1e-6, err_msg="ROSS' x and y modes differ")
    assert_close(ours_hz, pairs[:, 0], label)


# -------------------------------------------------------------------- tests
def test_uniform_shaft_free_free():
    check_standstill(uniform_shaft(), "(a) uniform shaft")


def test_stepped_hollow_shaft_with_disks_free_free():
    check_standstill(stepped_shaft(), "(b) stepped hollow shaft with disks")


def test_demo20_rotor_free_free():
    check_standstill(demo20_rotor(), "(c) demo20 rotor")


def test_stepped_shaft_whirl_frequencies_at_speed():
    """(d) Forward and backward whirl of rotor (b) at 20000 rpm.

    Compares the first `N_FLEXIBLE` forward and backward modes above
    `RIGID_LIMIT_HZ`.  At speed the rigid-body tilt splits into a backward mode
    at zero (skipped) and a forward nutation mode at about Omega I_p / I_t, which
    is not zero and is compared as the first forward mode.
    """
    rotor = stepped_shaft()
    speed_rad_s = SPEED_RPM * 2 * np.pi / 60
    forward_hz, backward_hz = ambid_whirl_modes(rotor, speed_rad_s)
    ross_hz, ross_whirl = ross_lateral_modes(rotor, speed_rad_s)
    ross_forward = ross_hz[ross_whirl == "Forward"]
    ross_backward = ross_hz[ross_whirl == "Backward"]
    assert ross_forward.size >= N_FLEXIBLE and ross_backward.size >= N_FLEXIBLE
    assert forward_hz.size >= N_FLEXIBLE and backward_hz.size >= N_FLEXIBLE
    assert_close(forward_hz[:N_FLEXIBLE], ross_forward[:N_FLEXIBLE], "(d) forward whirl at 20000 rpm")
    assert_close(backward_hz[:N_FLEXIBLE], ross_backward[:N_FLEXIBLE], "(d) backward whirl at 20000 rpm")
    # gyroscopic stiffening: each forward mode lies above its backward partner
    assert np.all(forward_hz[1:N_FLEXIBLE] > backward_hz[: N_FLEXIBLE - 1])


# ------------------------------------------------------------ (e) AMB plant
PLANT_FREQUENCY_HZ = np.geomspace(1.0, 3000.0, 120)
AXIS_PLANE = {"DX": ("DE", 0), "DY": ("DE", 1), "NX": ("NDE", 0), "NY": ("NDE", 1)}


def demo20_on_nodes(retained_modes=None):
    """demo20 with its actuators moved onto nodes 3 and 17 (ROSS puts bearings at nodes) and no material damping
    (ROSS' shaft has none): the same physics in both codes, nothing else changed."""
    with open(REPO / "config" / "machines" / "demo20.yaml") as stream:
        config = yaml.safe_load(stream)
    for material in config["materials"].values():
        material["loss_factor"] = 0.0
    config["bearings"]["radial"]["DE"]["actuator_position_m"] = 0.075
    config["bearings"]["radial"]["NDE"]["actuator_position_m"] = 0.425
    if retained_modes is not None:
        config["rotor"]["retained_modes"] = retained_modes
    return machine_from_config(config, name="demo20_on_nodes")


def plant_against_ross(machine):
    """Relative complex error of ambid's radial plant against ROSS', per channel: dict (output, input) -> array."""
    plant = Plant(machine)
    rotor = plant.machine.rotor  # with the structure effects applied
    positions = np.asarray(rotor.node_positions_m)

    def node(position_m):
        k = int(np.argmin(np.abs(positions - position_m)))
        assert abs(positions[k] - position_m) < 1e-12, f"{position_m} m is not a node"
        return k

    bearings = {b.name: b for b in plant.machine.radial_bearings}
    linear = {name: (b.linearize("x"), b.linearize("y")) for name, b in bearings.items()}  # ((ki, kx) per plane)
    converted = to_ross_rotor(rotor, [(node(b.actuator_position_m), -linear[name][0][1], -linear[name][1][1])
                                      for name, b in bearings.items()])
    dof = converted.number_dof  # x, y first of each node's degrees of freedom
    ross_h = np.array([converted.transfer_matrix(speed=machine.speed_rad_s, frequency=2 * np.pi * f)
                       for f in PLANT_FREQUENCY_HZ])
    ours = plant.radial_frequency_response(PLANT_FREQUENCY_HZ)
    errors = {}
    for o, output in enumerate(RADIAL_AXES):
        for i, inp in enumerate(RADIAL_AXES):
            (out_bearing, out_plane), (in_bearing, in_plane) = AXIS_PLANE[output], AXIS_PLANE[inp]
            current_stiffness = linear[in_bearing][in_plane][0]
            reference = current_stiffness * ross_h[:, dof * node(bearings[out_bearing].sensor_position_m) + out_plane,
                                                   dof * node(bearings[in_bearing].actuator_position_m) + in_plane]
            if np.max(np.abs(reference)) == 0:  # the planes at standstill: both codes exactly zero
                assert np.max(np.abs(ours[:, o, i])) == 0, (output, inp)
                continue
            errors[output, inp] = np.abs(ours[:, o, i] - reference) / np.abs(reference)
            print(f"{output}/{inp}: |P| up to {np.max(np.abs(reference)):.3g} m/A, relative error median "
                  f"{np.median(errors[output, inp]):.1e}, max {np.max(errors[output, inp]):.1e}")
    return errors


@pytest.mark.parametrize("case", ["standstill", "elements 5-8 at half stiffness", "30000 rpm"])
def test_amb_plant_frequency_response_against_ross(case):
    """(e) ambid's plant FRF (12 retained modes plus the static correction; 30 at speed) against ROSS' full
    finite-element solve, 1 Hz - 3 kHz, every radial channel.

    Measured: 4e-10 median and 5e-5 largest relative error at standstill; at 30000 rpm with 12 modes the small
    gyroscopic cross-plane channels (2 % of the direct ones) err by up to 4 % near 2.6 kHz, by 4e-4 with 30.
    """
    machine = demo20_on_nodes(retained_modes=30 if case == "30000 rpm" else None)
    if case == "30000 rpm":
        machine = replace(machine, speed_rad_s=30000.0 * np.pi / 30)
    if case == "elements 5-8 at half stiffness":
        machine = replace(machine, effects=(effect_from_config(
            {"name": "element_stiffness", "parameters": {"tag": "design", "scale": 0.5}}, "effects[0]"),))
    errors = plant_against_ross(machine)
    assert len(errors) == (16 if case == "30000 rpm" else 8)  # at standstill the x and y planes do not couple
    assert max(np.median(e) for e in errors.values()) < 1e-5
    assert max(np.max(e) for e in errors.values()) < 1e-3


def test_updated_rotor_exports_its_scaled_moduli():
    """An updated rotor's scaled elements keep their material's name with another modulus: ROSS must get both."""
    rotor = demo20_rotor()
    design = rotor.elements_tagged("design")
    converted = to_ross_rotor(rotor.with_youngs_modulus_scaled(design, 0.5))
    moduli = np.array([element.material.E for element in converted.shaft_elements])
    original = np.array([element.material.youngs_modulus_pa for element in rotor.elements])
    np.testing.assert_allclose(moduli[design], 0.5 * original[design], rtol=1e-12)
    np.testing.assert_allclose(np.delete(moduli, design), np.delete(original, design), rtol=1e-12)
