"""Timoshenko-beam finite element model of a rotor (thesis ch. 2.2, eq. 2.7-2.9).

The rotor is a chain of axisymmetric shaft elements (hollow cylinders, each with
its own diameters and material), rigid disks at nodes, and sleeves (lamination
stacks, magnets, retaining sleeves) that add mass and inertia to elements but
little or no stiffness.

Degrees of freedom
------------------
Each node has four degrees of freedom ``[x, y, beta_x, beta_y]`` (thesis ch. 2.1):
translations along x and y and small rotations about the x and y axes, with z
along the shaft.  Right-handed rotations give the slopes ``dx/dz = beta_y`` and
``dy/dz = -beta_x``.  Global index of DOF ``d`` of node ``n`` is ``4 n + d``.

Because the rotor is axisymmetric, bending in the xz plane and in the yz plane
is described by the same *planar* matrices in the coordinates ``[u, theta]`` per
node (displacement and section rotation, with ``theta = du/dz`` for a slender
beam).  The x plane uses ``(x, beta_y)`` and the y plane ``(y, -beta_x)``.  The
two planes are coupled only by the gyroscopic matrix, which is built from the
planar polar-inertia matrix.  This module assembles the planar matrices (fast:
half the size, no coupling) and expands them to the 4-DOF form on request.
"""

from dataclasses import dataclass, field, replace

import numpy as np
import scipy.linalg

from .errors import ConfigError

__all__ = [
    "Material",
    "ShaftElement",
    "Disk",
    "Sleeve",
    "Rotor",
    "PlanarModes",
    "hollow_shear_coefficient",
    "timoshenko_element_matrices",
    "timoshenko_shape_functions",
    "planar_to_full",
]

DOF_PER_NODE = 4
X, Y, BETA_X, BETA_Y = range(DOF_PER_NODE)


@dataclass(frozen=True)
class Material:
    """Linear elastic isotropic material.

    Parameters
    ----------
    name : str
    youngs_modulus_pa : float
        Young's modulus E [Pa].
    density_kg_m3 : float
        Density rho [kg/m^3].
    shear_modulus_pa : float, optional
        Shear modulus G [Pa]; if omitted it is E / (2 (1 + nu)).
    poisson_ratio : float
        Poisson's ratio nu (default 0.3).
    loss_factor : float
        Structural loss factor eta [-]; a mode whose strain energy lies in this
        material gets the viscous modal damping ratio eta / 2 (see
        `Rotor.modal_loss_factors`).
    """

    name: str
    youngs_modulus_pa: float
    density_kg_m3: float
    shear_modulus_pa: float | None = None
    poisson_ratio: float = 0.3
    loss_factor: float = 0.0

    @property
    def shear_modulus(self):
        """Shear modulus G [Pa]."""
        if self.shear_modulus_pa is not None:
            return self.shear_modulus_pa
        return self.youngs_modulus_pa / (2.0 * (1.0 + self.poisson_ratio))


@dataclass(frozen=True)
class ShaftElement:
    """One Timoshenko beam element: a hollow cylinder between two nodes.

    Parameters
    ----------
    length_m, outer_diameter_m, inner_diameter_m : float
        Geometry [m]; ``inner_diameter_m`` is 0 for a solid section.
    material : Material
    tags : tuple of str
        Names of groups this element belongs to (``design``, ``de_amb``, ...).
    """

    length_m: float
    outer_diameter_m: float
    material: Material
    inner_diameter_m: float = 0.0
    tags: tuple = ()


@dataclass(frozen=True)
class Disk:
    """Rigid disk attached to a node (thesis eq. 2.3-2.4 for one body).

    Parameters
    ----------
    node : int
    mass_kg : float
    polar_inertia_kg_m2 : float
        Moment of inertia about the spin axis, I_p.
    transverse_inertia_kg_m2 : float
        Moment of inertia about a diameter, I_t.
    """

    node: int
    mass_kg: float
    polar_inertia_kg_m2: float
    transverse_inertia_kg_m2: float


@dataclass(frozen=True)
class Sleeve:
    """A hollow cylinder of added mass over one or more elements.

    Represents lamination stacks, permanent magnets, retaining sleeves: parts
    shrunk onto the shaft that add mass and rotary inertia but carry little
    load.  The share ``stiffness_fraction`` of their section carries it, with
    the moduli of the host element, in bending (``E I``) and in shear (``G A``)
    alike: 0 is pure mass, 1 makes the sleeve part of the shaft.

    Parameters
    ----------
    name : str
    elements : tuple of int
        Indices of the host elements.
    outer_diameter_m, inner_diameter_m : float
    density_kg_m3 : float
    stiffness_fraction : float
    """

    name: str
    elements: tuple
    outer_diameter_m: float
    inner_diameter_m: float
    density_kg_m3: float
    stiffness_fraction: float = 0.0


def hollow_shear_coefficient(outer_diameter_m, inner_diameter_m, poisson_ratio):
    """Shear coefficient of a hollow circular section (Cowper 1966).

    ``kappa = 6 (1 + nu) (1 + m^2)^2 / ((7 + 6 nu) (1 + m^2)^2 + (20 + 12 nu) m^2)``
    with ``m = d_i / d_o``; the solid section gives ``6 (1 + nu) / (7 + 6 nu)``.
    """
    m2 = (np.asarray(inner_diameter_m) / np.asarray(outer_diameter_m)) ** 2
    nu = np.asarray(poisson_ratio)
    return 6 * (1 + nu) * (1 + m2) ** 2 / ((7 + 6 * nu) * (1 + m2) ** 2 + (20 + 12 * nu) * m2)


def timoshenko_element_matrices(length_m, bending_stiffness, shear_parameter, mass_per_length, inertia_per_length):
    """Planar Timoshenko beam element matrices, vectorized over elements.

    Coordinates per element ``[u1, theta1, u2, theta2]``.  Stiffness, translational
    and rotary-inertia consistent mass after Friedman and Kosmatka (1993), the
    element form of thesis eq. 2.7.

    Parameters
    ----------
    length_m : array (n,)
    bending_stiffness : array (n,)
        E I [N m^2].
    shear_parameter : array (n,)
        phi = 12 E I / (kappa G A L^2); 0 gives Euler-Bernoulli elements.
    mass_per_length : array (n,)
        rho A (+ sleeves) [kg/m].
    inertia_per_length : array (n,)
        rho I (+ sleeves) [kg m]; the polar value 2 rho I gives the gyroscopic matrix.

    Returns
    -------
    stiffness, translational_mass, rotary_inertia : arrays (n, 4, 4)
        ``rotary_inertia`` is the matrix R = int N_theta^T N_theta dz scaled by
        ``inertia_per_length``; the gyroscopic matrix uses the same R.
    """
    L = np.asarray(length_m, dtype=float)[:, None, None]
    phi = np.asarray(shear_parameter, dtype=float)[:, None, None]
    ei = np.asarray(bending_stiffness, dtype=float)[:, None, None]
    one = np.ones_like(L)

    def block(entries):
        return np.concatenate([np.concatenate(row, axis=2) for row in entries], axis=1)

    k = ei / ((1 + phi) * L**3)
    stiffness = k * block(
        [
            [12 * one, 6 * L, -12 * one, 6 * L],
            [6 * L, (4 + phi) * L**2, -6 * L, (2 - phi) * L**2],
            [-12 * one, -6 * L, 12 * one, -6 * L],
            [6 * L, (2 - phi) * L**2, -6 * L, (4 + phi) * L**2],
        ]
    )

    m1 = 13 / 35 + 7 * phi / 10 + phi**2 / 3
    m2 = (11 / 210 + 11 * phi / 120 + phi**2 / 24) * L
    m3 = 9 / 70 + 3 * phi / 10 + phi**2 / 6
    m4 = (13 / 420 + 3 * phi / 40 + phi**2 / 24) * L
    m5 = (1 / 105 + phi / 60 + phi**2 / 120) * L**2
    m6 = (1 / 140 + phi / 60 + phi**2 / 120) * L**2
    mu = np.asarray(mass_per_length, dtype=float)[:, None, None]
    translational = (mu * L / (1 + phi) ** 2) * block(
        [[m1, m2, m3, -m4], [m2, m5, m4, -m6], [m3, m4, m1, -m2], [-m4, -m6, -m2, m5]]
    )

    r1 = 6 / 5 * one
    r2 = (1 / 10 - phi / 2) * L
    r3 = (2 / 15 + phi / 6 + phi**2 / 3) * L**2
    r4 = (-1 / 30 - phi / 6 + phi**2 / 6) * L**2
    j = np.asarray(inertia_per_length, dtype=float)[:, None, None]
    rotary = (j / ((1 + phi) ** 2 * L)) * block(
        [[r1, r2, -r1, r2], [r2, r3, -r2, r4], [-r1, -r2, r1, -r2], [r2, r4, -r2, r3]]
    )
    return stiffness, translational, rotary


def timoshenko_shape_functions(xi, length_m, shear_parameter):
    """Displacement interpolation inside a Timoshenko element (thesis eq. 2.8).

    Parameters
    ----------
    xi : float or array
        Local coordinate z / L in [0, 1].
    length_m, shear_parameter : float

    Returns
    -------
    array (..., 4)
        Row ``N`` with ``u(xi) = N @ [u1, theta1, u2, theta2]``.
    """
    xi = np.asarray(xi, dtype=float)
    L, phi = float(length_m), float(shear_parameter)
    c = 1.0 / (1.0 + phi)
    return np.stack(
        [
            c * (2 * xi**3 - 3 * xi**2 - phi * xi + 1 + phi),
            c * L * (xi**3 - (2 + phi / 2) * xi**2 + (1 + phi / 2) * xi),
            c * (-2 * xi**3 + 3 * xi**2 + phi * xi),
            c * L * (xi**3 - (1 - phi / 2) * xi**2 - (phi / 2) * xi),
        ],
        axis=-1,
    )


def planar_to_full(n_nodes):
    """Index maps from the two planar coordinate sets to the 4-DOF global vector.

    Returns
    -------
    x_index, y_index : arrays (2 n_nodes,)
        Global DOF index of planar coordinate k in the x plane (``x, beta_y``) and
        in the y plane (``y, beta_x``).
    y_sign : array (2 n_nodes,)
        +1 for translations and -1 for rotations: the y-plane section rotation is
        ``-beta_x``.
    """
    nodes = np.arange(n_nodes)
    x_index = np.empty(2 * n_nodes, dtype=int)
    y_index = np.empty(2 * n_nodes, dtype=int)
    x_index[0::2], x_index[1::2] = DOF_PER_NODE * nodes + X, DOF_PER_NODE * nodes + BETA_Y
    y_index[0::2], y_index[1::2] = DOF_PER_NODE * nodes + Y, DOF_PER_NODE * nodes + BETA_X
    y_sign = np.tile([1.0, -1.0], n_nodes)
    return x_index, y_index, y_sign


@dataclass(frozen=True)
class PlanarModes:
    """Undamped free-free bending modes of the non-rotating rotor in one plane.

    Attributes
    ----------
    angular_frequency_rad_s : array (n_modes,)
        Natural angular frequencies; rigid-body modes are (numerically) zero.
    shapes : array (2 n_nodes, n_modes)
        Mass-normalized shapes in planar coordinates ``[u, theta]`` per node.
    """

    angular_frequency_rad_s: np.ndarray
    shapes: np.ndarray

    @property
    def frequency_hz(self):
        return self.angular_frequency_rad_s / (2 * np.pi)


#: Modes by (rotor, n_modes, loads), shared by equal rotors: a diagnosis builds the same updated rotor again for every
#: evaluation that moves only a bearing, damping or signal parameter (bounded; a rotor is immutable and hashable).
_MODES_OF_EQUAL_ROTORS = {}


@dataclass(frozen=True)
class Rotor:
    """A flexible rotor: shaft elements in a chain, disks and sleeves.

    Parameters
    ----------
    elements : tuple of ShaftElement
        Element ``e`` joins nodes ``e`` and ``e + 1``; node 0 is at z = 0.
    disks : tuple of Disk
    sleeves : tuple of Sleeve
    """

    elements: tuple
    disks: tuple = ()
    sleeves: tuple = ()
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        if len(self.elements) == 0:
            raise ConfigError("rotor.elements", "a rotor needs at least one element")
        for e, element in enumerate(self.elements):
            for name in ("length_m", "outer_diameter_m"):
                if not getattr(element, name) > 0:
                    raise ConfigError(f"rotor.elements[{e}].{name}", f"must be > 0, got {getattr(element, name)}")
            if not 0 <= element.inner_diameter_m < element.outer_diameter_m:
                raise ConfigError(
                    f"rotor.elements[{e}].inner_diameter_m", "must satisfy 0 <= inner diameter < outer diameter"
                )
        for d, disk in enumerate(self.disks):
            if not 0 <= disk.node <= len(self.elements):
                raise ConfigError(f"rotor.disks[{d}].node", f"node {disk.node} is not on the rotor")
        for s, sleeve in enumerate(self.sleeves):
            bad = [e for e in sleeve.elements if not 0 <= e < len(self.elements)]
            if bad:
                raise ConfigError(f"rotor.sleeves[{s}].elements", f"no such element(s) {bad}")

    # ------------------------------------------------------------------ geometry
    @property
    def n_elements(self):
        return len(self.elements)

    @property
    def n_nodes(self):
        return len(self.elements) + 1

    @property
    def n_dof(self):
        return DOF_PER_NODE * self.n_nodes

    @property
    def node_positions_m(self):
        """Axial position z of each node [m], node 0 at z = 0 (cached: do not modify)."""
        if "nodes" not in self._cache:
            nodes = np.concatenate([[0.0], np.cumsum([e.length_m for e in self.elements])])
            nodes.flags.writeable = False
            self._cache["nodes"] = nodes
        return self._cache["nodes"]

    @property
    def length_m(self):
        return float(self.node_positions_m[-1])

    def element_properties(self):
        """Section properties of all elements as arrays (cached).

        Returns
        -------
        dict of arrays (n_elements,)
            ``length_m``, ``bending_stiffness`` (E I + sleeve share), ``shear_parameter``
            (phi ``= 12 E I / (kappa G A L^2)``, the sleeve's share in ``A``),
            ``mass_per_length``, ``inertia_per_length`` (transverse, rho I),
            ``loss_factor``, ``youngs_modulus_pa``.
        """
        if "props" in self._cache:
            return self._cache["props"]
        els = self.elements
        length = np.array([e.length_m for e in els])
        do = np.array([e.outer_diameter_m for e in els])
        di = np.array([e.inner_diameter_m for e in els])
        young = np.array([e.material.youngs_modulus_pa for e in els])
        shear = np.array([e.material.shear_modulus for e in els])
        rho = np.array([e.material.density_kg_m3 for e in els])
        nu = young / (2.0 * shear) - 1.0  # consistent with G when the material gives it
        area = np.pi / 4 * (do**2 - di**2)
        inertia = np.pi / 64 * (do**4 - di**4)
        kappa = hollow_shear_coefficient(do, di, nu)
        bending = young * inertia
        mass_per_length = rho * area
        inertia_per_length = rho * inertia
        shear_area = area.copy()
        for sleeve in self.sleeves:
            idx = np.asarray(sleeve.elements, dtype=int)
            s_area = np.pi / 4 * (sleeve.outer_diameter_m**2 - sleeve.inner_diameter_m**2)
            s_inertia = np.pi / 64 * (sleeve.outer_diameter_m**4 - sleeve.inner_diameter_m**4)
            mass_per_length[idx] += sleeve.density_kg_m3 * s_area
            inertia_per_length[idx] += sleeve.density_kg_m3 * s_inertia
            # the share of the sleeve that carries load carries it in bending and in shear alike
            bending[idx] += sleeve.stiffness_fraction * young[idx] * s_inertia
            shear_area[idx] += sleeve.stiffness_fraction * s_area
        phi = 12 * bending / (kappa * shear * shear_area * length**2)
        props = dict(
            length_m=length,
            bending_stiffness=bending,
            shear_parameter=phi,
            mass_per_length=mass_per_length,
            inertia_per_length=inertia_per_length,
            loss_factor=np.array([e.material.loss_factor for e in els]),
            youngs_modulus_pa=young,
        )
        self._cache["props"] = props
        return props

    def with_youngs_modulus_scaled(self, element_indices, scale):
        """A copy with E (and G) of the given elements multiplied by ``scale`` (scalar or per element)."""
        scale = np.broadcast_to(np.asarray(scale, dtype=float), (len(element_indices),))
        elements = list(self.elements)
        for e, s in zip(element_indices, scale):
            m = elements[e].material
            new = replace(
                m,
                youngs_modulus_pa=m.youngs_modulus_pa * s,
                shear_modulus_pa=None if m.shear_modulus_pa is None else m.shear_modulus_pa * s,
            )
            elements[e] = replace(elements[e], material=new)
        return replace(self, elements=tuple(elements))

    def elements_tagged(self, tag):
        """Indices of the elements carrying ``tag``."""
        return [e for e, element in enumerate(self.elements) if tag in element.tags]

    @property
    def mass_kg(self):
        props = self.element_properties()
        return float(np.sum(props["mass_per_length"] * props["length_m"]) + sum(d.mass_kg for d in self.disks))

    # ---------------------------------------------------------------- assembly
    def planar_matrices(self):
        """Assemble the planar mass, stiffness, polar-inertia and loss matrices (cached).

        Returns
        -------
        dict of arrays (2 n_nodes, 2 n_nodes)
            ``mass`` (translational + rotary inertia + disks), ``stiffness``,
            ``polar`` (the matrix P with G = [[0, P], [-P, 0]] between the planes),
            ``loss_stiffness`` (sum over elements of eta_e K_e).
        """
        if "planar" in self._cache:
            return self._cache["planar"]
        p = self.element_properties()
        stiffness, translational, rotary = timoshenko_element_matrices(
            p["length_m"], p["bending_stiffness"], p["shear_parameter"], p["mass_per_length"], p["inertia_per_length"]
        )
        assemble = self._assemble
        mass = assemble(translational + rotary)
        polar = assemble(2.0 * rotary)  # polar inertia per length = 2 x transverse for tubes
        stiff = assemble(stiffness)
        loss = assemble(p["loss_factor"][:, None, None] * stiffness)
        for disk in self.disks:
            u, t = 2 * disk.node, 2 * disk.node + 1
            mass[u, u] += disk.mass_kg
            mass[t, t] += disk.transverse_inertia_kg_m2
            polar[t, t] += disk.polar_inertia_kg_m2
        out = dict(mass=mass, stiffness=stiff, polar=polar, loss_stiffness=loss)
        self._cache["planar"] = out
        return out

    def _assemble(self, element_matrices, elements=None):
        """Planar global matrix from element matrices (n, 4, 4) of ``elements`` (default: all, in order)."""
        n = 2 * self.n_nodes
        elements = np.arange(self.n_elements) if elements is None else np.asarray(elements, dtype=int)
        rows = (2 * elements)[:, None] + np.arange(4)  # element e occupies planar rows/cols 2e .. 2e+3
        r_idx = np.broadcast_to(rows[:, :, None], (elements.size, 4, 4)).ravel()
        c_idx = np.broadcast_to(rows[:, None, :], (elements.size, 4, 4)).ravel()
        out = np.bincount(r_idx * n + c_idx, weights=np.asarray(element_matrices).ravel(), minlength=n * n)
        return out.reshape(n, n)

    def element_group_matrices(self, elements):
        """Planar stiffness and loss stiffness of one group of elements alone.

        Both scale with the group's Young's modulus (the shear modulus scales
        with it, so the shear parameter phi does not change): the rotor's
        stiffness is ``K = K_rest + sum_g s_g K_g`` for factors ``s_g`` on the
        groups' moduli, the linearity the model update (thesis ch. 5.2) uses.

        Returns
        -------
        stiffness, loss_stiffness : arrays (2 n_nodes, 2 n_nodes)
        """
        elements = np.asarray(elements, dtype=int)
        p = self.element_properties()
        stiffness, _, _ = timoshenko_element_matrices(
            p["length_m"][elements], p["bending_stiffness"][elements], p["shear_parameter"][elements],
            p["mass_per_length"][elements], p["inertia_per_length"][elements]
        )
        loss = p["loss_factor"][elements][:, None, None] * stiffness
        return self._assemble(stiffness, elements), self._assemble(loss, elements)

    def matrices(self):
        """Full 4-DOF global matrices M, K, G and D of thesis eq. 2.9.

        Returns
        -------
        dict of arrays (n_dof, n_dof)
            ``mass``, ``stiffness``, ``gyroscopic`` (multiply by the speed Omega
            [rad/s]) and ``damping`` (material damping, see `damping_matrix_planar`).
        """
        planar = self.planar_matrices()
        xi, yi, ys = planar_to_full(self.n_nodes)
        n = self.n_dof

        def expand(a):
            full = np.zeros((n, n))
            full[np.ix_(xi, xi)] = a
            full[np.ix_(yi, yi)] = ys[:, None] * a * ys[None, :]
            return full

        gyro = np.zeros((n, n))
        gyro[np.ix_(xi, yi)] = planar["polar"] * ys[None, :]
        gyro[np.ix_(yi, xi)] = -ys[:, None] * planar["polar"]
        return dict(
            mass=expand(planar["mass"]),
            stiffness=expand(planar["stiffness"]),
            gyroscopic=gyro,
            damping=expand(self.damping_matrix_planar()),
        )

    # ------------------------------------------------------------------ modes
    def planar_modes(self, n_modes=None, static_loads_m=()):
        """Free-free undamped bending modes of one plane (mass-normalized), with static correction.

        Parameters
        ----------
        n_modes : int, optional
            Number of lowest modes to return (all if omitted).  The two rigid-body
            modes (translation and tilt) come first.
        static_loads_m : sequence of float
            Axial positions of point forces (the actuators).  With fewer than all
            modes, the modes dropped still bend the rotor statically under those
            forces; one Ritz vector per load, the static deflection of the dropped
            modes ``sum_{k > n} psi_k psi_k^T f / w_k^2`` (residual flexibility),
            is appended after a Rayleigh-Ritz solve in their span, so the reduced
            model's static response to the loads is exact and its error below
            the first dropped mode is of order ``(w / w_(n+1))^2`` of what the
            plain truncation leaves.

        Returns
        -------
        PlanarModes
            ``n_modes`` eigenmodes, then the static-correction vectors (their
            Rayleigh-Ritz frequencies lie above the retained modes').
        """
        key = ("modes", n_modes, tuple(static_loads_m))
        if key in self._cache:  # a rotor is immutable: variants that change only damping or sensors reuse its modes
            return self._cache[key]
        shared = (self, *key)
        try:
            found = _MODES_OF_EQUAL_ROTORS.get(shared)  # a copy with the same elements (an update applied again)
        except TypeError:  # a rotor built with a list where a tuple belongs (tags, sleeve elements): not shared
            shared = found = None
        if found is not None:
            self._cache[key] = found
            return found
        planar = self.planar_matrices()
        n = planar["mass"].shape[0]
        truncated = n_modes is not None and n_modes < n
        subset = (0, n_modes - 1) if truncated and not static_loads_m else None
        eigval, shapes = scipy.linalg.eigh(planar["stiffness"], planar["mass"], subset_by_index=subset)
        omega = np.sqrt(np.clip(eigval, 0.0, None))
        if truncated and static_loads_m:
            dropped, dropped_omega = shapes[:, n_modes:], omega[n_modes:]
            forces = np.stack([self.planar_displacement_row(z) for z in static_loads_m], axis=1)
            residual = dropped @ ((dropped.T @ forces) / dropped_omega[:, None] ** 2)
            basis = scipy.linalg.orth(residual)
            ritz_values, ritz_vectors = scipy.linalg.eigh(basis.T @ planar["stiffness"] @ basis, basis.T @ planar["mass"] @ basis)
            omega = np.concatenate([omega[:n_modes], np.sqrt(np.clip(ritz_values, 0.0, None))])
            shapes = np.hstack([shapes[:, :n_modes], basis @ ritz_vectors])
        elif truncated:
            omega, shapes = omega[:n_modes], shapes[:, :n_modes]
        self._cache[key] = PlanarModes(angular_frequency_rad_s=omega, shapes=shapes)
        if shared is not None:
            if len(_MODES_OF_EQUAL_ROTORS) >= 64:
                _MODES_OF_EQUAL_ROTORS.clear()
            _MODES_OF_EQUAL_ROTORS[shared] = self._cache[key]
        return self._cache[key]

    def modal_loss_factors(self, modes):
        """Strain-energy weighted loss factor of each mode.

        ``eta_k = psi_k^T (sum_e eta_e K_e) psi_k / omega_k^2``; rigid-body modes get 0.
        A viscous modal damping ``2 zeta_k omega_k`` with ``zeta_k = eta_k / 2``
        reproduces hysteretic damping at resonance and stays causal for the
        time-domain rig.
        """
        loss = self.planar_matrices()["loss_stiffness"]
        energy = np.einsum("ik,ij,jk->k", modes.shapes, loss, modes.shapes)
        omega2 = modes.angular_frequency_rad_s**2
        flexible = omega2 > _rigid_threshold(omega2)
        return np.where(flexible, energy / np.where(flexible, omega2, 1.0), 0.0)

    def damping_matrix_planar(self):
        """Planar material damping matrix from the modal loss factors of all modes.

        ``D = M Psi diag(eta_k omega_k) Psi^T M`` (mass-normalized Psi), so that each
        mode has damping ratio eta_k / 2 and modal truncation of D is exact.
        """
        modes = self.planar_modes()
        eta = self.modal_loss_factors(modes)
        mass = self.planar_matrices()["mass"]
        mpsi = mass @ modes.shapes
        return (mpsi * (eta * modes.angular_frequency_rad_s)) @ mpsi.T

    # ------------------------------------------------------------- locations
    def locate(self, z_m):
        """Element index and local coordinate of an axial position."""
        z = self.node_positions_m
        if not (z[0] - 1e-12 <= z_m <= z[-1] + 1e-12):
            raise ConfigError("position_m", f"z = {z_m} m lies outside the rotor (0 .. {z[-1]:.6g} m)")
        e = int(np.clip(np.searchsorted(z, z_m, side="right") - 1, 0, self.n_elements - 1))
        return e, (z_m - z[e]) / self.elements[e].length_m

    def planar_displacement_row(self, z_m):
        """Row vector mapping planar coordinates to the displacement at ``z_m``.

        Uses the element's own Timoshenko interpolation (eq. 2.8), so sensors
        and actuators may sit inside elements.  The same row serves the x plane
        (``x = row @ q_x``) and the y plane (``y = row @ q_y``); by reciprocity its
        transpose is the generalized force of a unit point force at ``z_m``.  Cached per position (a model
        build asks for each sensor and actuator row several times): do not modify the row.
        """
        key = ("row", float(z_m))
        if key not in self._cache:
            e, xi = self.locate(z_m)
            props = self.element_properties()
            row = np.zeros(2 * self.n_nodes)
            row[2 * e : 2 * e + 4] = timoshenko_shape_functions(xi, props["length_m"][e], props["shear_parameter"][e])
            row.flags.writeable = False
            self._cache[key] = row
        return self._cache[key]


def _rigid_threshold(omega2):
    """Eigenvalue magnitude below which a free-free mode counts as rigid."""
    top = np.max(np.abs(omega2)) if np.size(omega2) else 0.0
    return max(1e-9 * top, 1e-6)
