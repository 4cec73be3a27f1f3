"""Machine model: rotor, bearings, sensors, controller and effects, built from a config mapping.

A machine config (``config/machines/<name>.yaml``, schema
``workflow/schemas/machine.schema.yaml``) describes what the engineer believes
the machine is.  `machine_from_config` turns it into a `Machine`, checking the
cross-references a JSON schema cannot (materials, tags, positions on the rotor,
effect names and parameters) and naming the offending key in a `ConfigError`.
"""

from dataclasses import dataclass, field, replace

import numpy as np

from .bearing import ActuatorAxis
from .control import Controller
from .errors import ConfigError
from .rotor import Disk, Material, Rotor, ShaftElement, Sleeve

__all__ = [
    "RADIAL_AXES",
    "AXIAL_AXIS",
    "ALL_AXES",
    "RadialBearing",
    "Foundation",
    "Machine",
    "FrequencyGrid",
    "machine_from_config",
]

RADIAL_AXES = ("DX", "DY", "NX", "NY")
AXIAL_AXIS = "Z"
ALL_AXES = RADIAL_AXES + (AXIAL_AXIS,)
#: When a log's coil current is measured against the cycle's command (`ambid.compare.sampled_chain`): sampled at the
#: start of the cycle, before the command acts (the default), or averaged over the cycle of the command.
COIL_CURRENT_SAMPLING = ("start_of_cycle", "cycle_average")
BEARINGS = ("DE", "NDE")
#: control axis -> (bearing, plane)
AXIS_LOCATION = {"DX": ("DE", "x"), "DY": ("DE", "y"), "NX": ("NDE", "x"), "NY": ("NDE", "y")}


@dataclass(frozen=True)
class RadialBearing:
    """A radial AMB with x and y control axes and its position sensors.

    Parameters
    ----------
    name : {"DE", "NDE"}
        Drive end or non-drive end.
    actuator_position_m : float
        Axial position of the electromagnet's force centre on the rotor [m].
    sensor_position_m : float
        Axial position of the displacement sensor [m]; differs from the actuator's
        for a non-collocated layout.
    electromagnet : ActuatorAxis
        Parameters of each of its two control axes.
    plane_electromagnets : dict
        ``plane -> ActuatorAxis`` where one axis differs from ``electromagnet``
        (the ``actuator_coefficients`` effect).
    """

    name: str
    actuator_position_m: float
    sensor_position_m: float
    electromagnet: ActuatorAxis
    operating_point: dict = field(default_factory=dict)  # plane -> (position_m, control_current_a)
    plane_electromagnets: dict = field(default_factory=dict)

    def electromagnet_of(self, plane):
        """The electromagnet of the bearing's ``x`` or ``y`` axis."""
        return self.plane_electromagnets.get(plane, self.electromagnet)

    def linearize(self, plane):
        """(ki, kx) of the bearing's x or y axis at its operating point (default: the magnetic center)."""
        position, current = self.operating_point.get(plane, (0.0, 0.0))
        return self.electromagnet_of(plane).linearize(position, current)


@dataclass(frozen=True)
class Foundation:
    """Flexible bearing housings: each radial bearing stator on a mass-spring-damper to ground."""

    mass_kg: float
    frequency_hz: float
    damping_ratio: float
    bearings: tuple = BEARINGS


@dataclass(frozen=True)
class FrequencyGrid:
    """Linear frequency grid (thesis ch. 4.2: linearly spaced steps)."""

    start_hz: float
    stop_hz: float
    points: int

    @property
    def frequency_hz(self):
        return np.linspace(self.start_hz, self.stop_hz, self.points)


@dataclass(frozen=True)
class Machine:
    """Everything needed to compute the plant of one machine.

    Structural effects are applied by `ambid.plant` through the fields
    ``speed_rad_s``, ``added_modal_damping``, ``foundation``, sensor positions
    and the rotor itself; input- and output-side effects stay in ``effects``.
    """

    name: str
    rotor: Rotor
    radial_bearings: tuple
    axial_electromagnet: ActuatorAxis | None
    radial_controllers: tuple
    axial_controller: Controller | None
    retained_modes: int
    radial_grid: FrequencyGrid
    axial_grid: FrequencyGrid
    effects: tuple = ()
    speed_rad_s: float = 0.0
    added_modal_damping: tuple = ()
    foundation: Foundation | None = None
    coil_current_sampling: str = "auto"  # one of COIL_CURRENT_SAMPLING, or auto: from each run's data
    description: str = ""
    sources: dict = field(default_factory=dict, compare=False)

    def bearing(self, name):
        return next(b for b in self.radial_bearings if b.name == name)

    @property
    def radial_electromagnets(self):
        """The electromagnet of each radial control axis, in `RADIAL_AXES` order (DX, DY, NX, NY)."""
        return tuple(b.electromagnet_of(plane) for b in self.radial_bearings for plane in ("x", "y"))

    @property
    def bias_currents_a(self):
        """The drawing's bias current of each control axis, in `ALL_AXES` order [A] (infinite for Z without an axial
        bearing)."""
        axial = self.axial_electromagnet.bias_current_a if self.axial_electromagnet is not None else np.inf
        return np.array([m.bias_current_a for m in self.radial_electromagnets] + [axial])

    @property
    def sample_time_s(self):
        """Controller cycle [s] (the same for every axis)."""
        return self.radial_controllers[0].sample_time_s

    def with_effects(self, effects):
        """A copy with another list of effects (the nominal structure is unchanged)."""
        return replace(self, effects=tuple(effects))


# ---------------------------------------------------------------------------- parsing
def _require(mapping, key, path):
    if key not in mapping:
        raise ConfigError(f"{path}.{key}", "is required")
    return mapping[key]


def _positive(value, path, allow_zero=False):
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ConfigError(path, f"must be a number, got {value!r}") from None
    if not np.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        raise ConfigError(path, f"must be {'>= 0' if allow_zero else '> 0'}, got {value}")
    return value


def _materials(config):
    out = {}
    for name, spec in (config.get("materials") or {}).items():
        path = f"materials.{name}"
        out[name] = Material(
            name=name,
            youngs_modulus_pa=_positive(_require(spec, "youngs_modulus_pa", path), f"{path}.youngs_modulus_pa"),
            density_kg_m3=_positive(_require(spec, "density_kg_m3", path), f"{path}.density_kg_m3"),
            shear_modulus_pa=(
                _positive(spec["shear_modulus_pa"], f"{path}.shear_modulus_pa") if "shear_modulus_pa" in spec else None
            ),
            poisson_ratio=float(spec.get("poisson_ratio", 0.3)),
            loss_factor=_positive(spec.get("loss_factor", 0.0), f"{path}.loss_factor", allow_zero=True),
        )
    return out


def _rotor(config, materials):
    rotor_cfg = _require(config, "rotor", "")
    elements = []
    for i, spec in enumerate(_require(rotor_cfg, "elements", "rotor")):
        path = f"rotor.elements[{i}]"
        material_name = _require(spec, "material", path)
        if material_name not in materials:
            raise ConfigError(f"{path}.material", f"unknown material {material_name!r}; defined: {sorted(materials)}")
        element = ShaftElement(
            length_m=_positive(_require(spec, "length_m", path), f"{path}.length_m"),
            outer_diameter_m=_positive(_require(spec, "outer_diameter_m", path), f"{path}.outer_diameter_m"),
            inner_diameter_m=_positive(spec.get("inner_diameter_m", 0.0), f"{path}.inner_diameter_m", allow_zero=True),
            material=materials[material_name],
            tags=tuple(spec.get("tags", ())),
        )
        if element.inner_diameter_m >= element.outer_diameter_m:
            raise ConfigError(f"{path}.inner_diameter_m", "must be smaller than outer_diameter_m")
        elements.extend([element] * int(spec.get("repeat", 1)))
    n_nodes = len(elements) + 1
    disks = []
    for i, spec in enumerate(rotor_cfg.get("disks", ())):
        path = f"rotor.disks[{i}]"
        node = int(_require(spec, "node", path))
        if not 0 <= node < n_nodes:
            raise ConfigError(f"{path}.node", f"node {node} is not on the rotor (0 .. {n_nodes - 1})")
        disks.append(
            Disk(
                node=node,
                mass_kg=_positive(_require(spec, "mass_kg", path), f"{path}.mass_kg", allow_zero=True),
                polar_inertia_kg_m2=_positive(spec.get("polar_inertia_kg_m2", 0), f"{path}.polar_inertia_kg_m2", True),
                transverse_inertia_kg_m2=_positive(
                    spec.get("transverse_inertia_kg_m2", 0), f"{path}.transverse_inertia_kg_m2", True
                ),
            )
        )
    sleeves = []
    for i, spec in enumerate(rotor_cfg.get("sleeves", ())):
        path = f"rotor.sleeves[{i}]"
        tag = _require(spec, "tag", path)
        host = [e for e, element in enumerate(elements) if tag in element.tags]
        if not host:
            raise ConfigError(f"{path}.tag", f"no element carries the tag {tag!r}")
        sleeves.append(
            Sleeve(
                name=spec.get("name", tag),
                elements=tuple(host),
                outer_diameter_m=_positive(_require(spec, "outer_diameter_m", path), f"{path}.outer_diameter_m"),
                inner_diameter_m=_positive(spec.get("inner_diameter_m", 0.0), f"{path}.inner_diameter_m", True),
                density_kg_m3=_positive(_require(spec, "density_kg_m3", path), f"{path}.density_kg_m3"),
                stiffness_fraction=float(spec.get("stiffness_fraction", 0.0)),
            )
        )
    return Rotor(elements=tuple(elements), disks=tuple(disks), sleeves=tuple(sleeves))


def _electromagnet(spec, path):
    try:
        return ActuatorAxis(
            pole_area_m2=float(_require(spec, "pole_area_m2", path)),
            turns=float(_require(spec, "turns", path)),
            pole_angle_rad=np.deg2rad(float(_require(spec, "pole_angle_deg", path))),
            nominal_air_gap_m=float(_require(spec, "nominal_air_gap_m", path)),
            iron_path_m=float(spec.get("iron_path_m", 0.0)),
            bias_current_a=float(_require(spec, "bias_current_a", path)),
        )
    except ConfigError as error:
        raise error.within(path) from None


def _operating_point(radial_cfg, bearing):
    """Per plane (position relative to the magnetic center, static control current) of one bearing."""
    points = radial_cfg.get("operating_point") or {}
    unknown = set(points) - set(RADIAL_AXES)
    if unknown:
        raise ConfigError(f"bearings.radial.operating_point.{sorted(unknown)[0]}", f"not a radial axis {list(RADIAL_AXES)}")
    out = {}
    for axis, (name, plane) in AXIS_LOCATION.items():
        if name == bearing and axis in points:
            spec = points[axis]
            out[plane] = (float(spec.get("position_m", 0.0)), float(spec.get("control_current_a", 0.0)))
            gap = radial_cfg["electromagnet"]["nominal_air_gap_m"]
            if abs(out[plane][0]) >= gap:
                raise ConfigError(f"bearings.radial.operating_point.{axis}.position_m", f"outside the air gap ({gap} m)")
    return out


def _controller(spec, sample_time_s, path):
    known = {
        "proportional_gain_a_per_m",
        "integral_gain_a_per_m_s",
        "derivative_gain_a_s_per_m",
        "derivative_filter_hz",
        "lowpass_hz",
        "notch_hz",
        "notch_width_hz",
        "notch_depth",
    }
    unknown = set(spec) - known
    if unknown:
        raise ConfigError(f"{path}.{sorted(unknown)[0]}", "unknown controller setting")
    values = {key: _positive(value, f"{path}.{key}", allow_zero=True) for key, value in spec.items()}
    try:
        return Controller(sample_time_s=sample_time_s, **values)
    except ConfigError as error:
        raise error.within(path) from None


def _grid(spec, path):
    grid = FrequencyGrid(
        start_hz=_positive(_require(spec, "start_hz", path), f"{path}.start_hz"),
        stop_hz=_positive(_require(spec, "stop_hz", path), f"{path}.stop_hz"),
        points=int(_require(spec, "points", path)),
    )
    if grid.stop_hz <= grid.start_hz or grid.points < 2:
        raise ConfigError(path, "needs stop_hz > start_hz and at least 2 points")
    return grid


def machine_from_config(config, name=None, source=None):
    """Build a `Machine` from a parsed machine config mapping.

    Parameters
    ----------
    config : dict
        The machine YAML, already validated against ``machine.schema.yaml``.
    name : str, optional
        Machine name (defaults to ``config["name"]``).
    source : str, optional
        File name, quoted in error messages.

    Raises
    ------
    ConfigError
        Naming the offending key, for any inconsistency.
    """
    from .effects import effect_from_config  # effects import machine types

    try:
        materials = _materials(config)
        rotor = _rotor(config, materials)
        bearings_cfg = _require(config, "bearings", "")
        radial_cfg = _require(bearings_cfg, "radial", "bearings")
        magnet = _electromagnet(_require(radial_cfg, "electromagnet", "bearings.radial"), "bearings.radial.electromagnet")
        radial = []
        for bearing in BEARINGS:
            path = f"bearings.radial.{bearing}"
            spec = _require(radial_cfg, bearing, "bearings.radial")
            actuator = float(_require(spec, "actuator_position_m", path))
            sensor = float(spec.get("sensor_position_m", actuator))
            for key, z in (("actuator_position_m", actuator), ("sensor_position_m", sensor)):
                if not 0 <= z <= rotor.length_m:
                    raise ConfigError(f"{path}.{key}", f"{z} m is not on the rotor (0 .. {rotor.length_m:.6g} m)")
            radial.append(RadialBearing(bearing, actuator, sensor, magnet, _operating_point(radial_cfg, bearing)))
        axial_magnet = None
        if "axial" in bearings_cfg:
            axial_magnet = _electromagnet(bearings_cfg["axial"]["electromagnet"], "bearings.axial.electromagnet")
        control_cfg = _require(config, "controller", "")
        sample_time = _positive(control_cfg.get("sample_time_s", 50e-6), "controller.sample_time_s")
        sampling = control_cfg.get("coil_current_sampling", "auto")
        if sampling not in ("auto", *COIL_CURRENT_SAMPLING):
            raise ConfigError("controller.coil_current_sampling", f"{sampling!r} is not one of auto, "
                                                                  f"{', '.join(COIL_CURRENT_SAMPLING)}")
        radial_settings = _require(control_cfg, "radial", "controller")
        per_axis = control_cfg.get("per_axis") or {}
        unknown_axes = set(per_axis) - set(RADIAL_AXES)
        if unknown_axes:
            raise ConfigError(f"controller.per_axis.{sorted(unknown_axes)[0]}", f"not a radial axis {list(RADIAL_AXES)}")
        radial_controllers = tuple(
            _controller(
                {**radial_settings, **per_axis.get(axis, {})},
                sample_time,
                f"controller.per_axis.{axis}" if axis in per_axis else "controller.radial",
            )
            for axis in RADIAL_AXES
        )
        axial_controller = None
        if axial_magnet is not None:
            axial_controller = _controller(_require(control_cfg, "axial", "controller"), sample_time, "controller.axial")
        grids = _require(config, "frequency_grid", "")
        retained = int(config.get("rotor", {}).get("retained_modes", 12))
        if not 2 < retained <= 2 * rotor.n_nodes:
            raise ConfigError("rotor.retained_modes", f"must lie in 3 .. {2 * rotor.n_nodes}")
        machine = Machine(
            name=name or config.get("name", "machine"),
            description=config.get("description", ""),
            rotor=rotor,
            radial_bearings=tuple(radial),
            axial_electromagnet=axial_magnet,
            radial_controllers=radial_controllers,
            axial_controller=axial_controller,
            retained_modes=retained,
            coil_current_sampling=sampling,
            radial_grid=_grid(_require(grids, "radial", "frequency_grid"), "frequency_grid.radial"),
            axial_grid=_grid(_require(grids, "axial", "frequency_grid"), "frequency_grid.axial"),
            sources=dict(config.get("sources", {})),
        )
        effects = tuple(effect_from_config(spec, f"effects[{i}]", machine) for i, spec in enumerate(config.get("effects") or ()))
        return machine.with_effects(effects)
    except ConfigError as error:
        raise error.within(source=source) from None
