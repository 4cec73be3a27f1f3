"""The effect library: named, parameterised pieces of physics that change the plant.

An effect acts at one of three places (DESIGN.md)::

    P(jw) = Output(jw) . C_s [K - w^2 M + jw (D + Omega G) - B kx B^T]^-1 B . Input(jw)

* ``structure`` effects change the machine itself (`Effect.apply`): rotor
  stiffness, damping, speed, sensor positions, housings;
* ``input`` effects shape the force a commanded control current produces
  (`Effect.response`, a matrix per frequency acting on the currents);
* ``output`` effects shape what the sensors report.

The measured coil currents see only the amplifier, which lets data tell an
amplifier from a sensor.  Effects are registered by name, so adding one to a
model is a config change::

    effects:
      - name: delay
        parameters: {delay_s: 3.0e-5}

The same library serves the virtual rig (truth = nominal machine + effects with
true parameters) and the model (nominal machine + the effects the user added).
"""

import math
from dataclasses import dataclass, replace

import numpy as np

from .bearing import force_derivatives
from .errors import ConfigError
from .machine import ALL_AXES, AXIS_LOCATION, RADIAL_AXES, Foundation

__all__ = ["Parameter", "Effect", "EFFECTS", "COIL_CURRENT_EFFECTS", "register", "effect_from_config", "split_effects",
           "series_state_space", "at_excitation_level"]


@dataclass(frozen=True)
class Parameter:
    """Declaration of one effect parameter.

    ``lower``/``upper`` are physical bounds (checked on input, used as search
    bounds by the diagnosis); ``default`` None means required.
    """

    unit: str
    description: str
    default: object = None
    lower: float | None = None
    upper: float | None = None
    kind: str = "float"  # float | floats (scalar or list) | axes | string


EFFECTS = {}
#: Input effects that shape the coil current itself (the others act between coil current and force).
COIL_CURRENT_EFFECTS = ("amplifier_lowpass",)


def register(cls):
    """Class decorator adding an effect to the registry under ``cls.name``."""
    EFFECTS[cls.name] = cls
    return cls


class Effect:
    """Base class; subclasses set ``name``, ``location``, ``parameters`` and implement
    `apply` (structure) or `response` (input / output)."""

    name = ""
    location = ""
    parameters = {}

    def __init__(self, **values):
        unknown = set(values) - set(self.parameters)
        if unknown:
            raise ConfigError(f"parameters.{sorted(unknown)[0]}", f"unknown parameter of effect {self.name!r}")
        self.values = {}
        for key, spec in self.parameters.items():
            value = values.get(key, spec.default)
            if value is None:
                raise ConfigError(f"parameters.{key}", f"required by effect {self.name!r} [{spec.unit}]")
            self.values[key] = _check_value(value, spec, f"parameters.{key}")
        self.validate()

    def validate(self):
        """Checks between parameters that need no machine; raise ConfigError."""

    def __getattr__(self, key):
        values = self.__dict__.get("values", {})
        if key in values:
            return values[key]
        raise AttributeError(key)

    def __repr__(self):
        args = ", ".join(f"{k}={v!r}" for k, v in self.values.items())
        return f"{type(self).__name__}({args})"

    def to_config(self):
        """The ``effects:`` entry that recreates this effect."""
        return {"name": self.name, "parameters": {k: _plain(v) for k, v in self.values.items()}}

    def check(self, machine):
        """Cross-check parameters against the machine (tags, positions); raise ConfigError."""

    def apply(self, machine):
        """Structure effects: the modified machine."""
        raise NotImplementedError

    def response(self, frequency_hz, axes):
        """Input/output effects: array (n_freq, n_axes, n_axes) acting on the given axes."""
        raise NotImplementedError

    def siso_state_space(self):
        """Time-domain form of a diagonal rational effect: continuous (A, B, C, D) of one axis.

        The virtual rig chains these per axis; effects without one (delay, cross
        coupling) are handled by the rig directly.
        """
        return None

    def acts_on(self, axis):
        """Whether a per-axis effect applies to ``axis``."""
        return axis in self.values.get("axes", ALL_AXES)

    # helpers for diagonal per-axis effects
    def _diagonal(self, scalar_response, frequency_hz, axes):
        out = np.zeros((len(frequency_hz), len(axes), len(axes)), dtype=complex)
        active = set(self.values.get("axes", ALL_AXES))
        for k, axis in enumerate(axes):
            out[:, k, k] = scalar_response if axis in active else 1.0
        return out


def _plain(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, tuple):
        return list(value)
    return value


def _check_value(value, spec, path):
    if spec.kind == "string":
        if not isinstance(value, str):
            raise ConfigError(path, f"must be a string, got {value!r}")
        return value
    if spec.kind == "axes":
        axes = tuple(value)
        bad = [a for a in axes if a not in ALL_AXES]
        if bad:
            raise ConfigError(path, f"unknown axis {bad[0]!r}; axes are {list(ALL_AXES)}")
        return axes
    if spec.kind == "float" and isinstance(value, (float, int)):
        # a plain number (what a fit's trial gives, thousands of times per diagnosis): checked without a numpy array
        checked = lowest = highest = float(value)
        finite = math.isfinite(checked)
    else:
        try:
            array = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise ConfigError(path, f"must be numeric, got {value!r}") from None
        if spec.kind == "float" and array.ndim != 0:
            raise ConfigError(path, "must be a single number")
        checked = float(array) if array.ndim == 0 else tuple(array.tolist())
        finite = bool(np.all(np.isfinite(array)))
        lowest, highest = (float(np.min(array)), float(np.max(array))) if array.size else (math.inf, -math.inf)
    if not finite:
        raise ConfigError(path, "must be finite")
    if spec.lower is not None and lowest < spec.lower:
        raise ConfigError(path, f"must be >= {spec.lower} {spec.unit}, got {value}")
    if spec.upper is not None and highest > spec.upper:
        raise ConfigError(path, f"must be <= {spec.upper} {spec.unit}, got {value}")
    return checked


def effect_from_config(spec, path, machine=None):
    """Build an effect from an ``effects:`` entry ``{name: ..., parameters: {...}}``."""
    if not isinstance(spec, dict) or "name" not in spec:
        raise ConfigError(f"{path}.name", "an effect needs a name")
    name = spec["name"]
    if name not in EFFECTS:
        raise ConfigError(f"{path}.name", f"unknown effect {name!r}; known effects: {sorted(EFFECTS)}")
    extra = set(spec) - {"name", "parameters"}
    if extra:
        raise ConfigError(f"{path}.{sorted(extra)[0]}", "unknown key (effect settings go under 'parameters')")
    try:
        effect = EFFECTS[name](**(spec.get("parameters") or {}))
        if machine is not None:
            effect.check(machine)
    except ConfigError as error:
        raise error.within(path) from None
    return effect


AXES = Parameter("-", "control axes the effect acts on", default=ALL_AXES, kind="axes")


# ------------------------------------------------------------------ input side
@register
class AmplifierLowpass(Effect):
    """Current-control loop of the power amplifier as a first-order low-pass.

    ``F(s) = 1 / (1 + s / (2 pi f_c))`` between commanded and coil current.
    Fingerprint: -3 dB and -45 deg at f_c, phase lag ``atan(f / f_c)``; the
    measured coil currents show it too, the position sensors alone cannot
    distinguish it from a sensor low-pass.
    """

    name = "amplifier_lowpass"
    location = "input"
    parameters = {"cutoff_hz": Parameter("Hz", "amplifier current-loop bandwidth", lower=1.0, upper=1e6), "axes": AXES}

    def response(self, frequency_hz, axes):
        return self._diagonal(1.0 / (1.0 + 1j * np.asarray(frequency_hz) / self.cutoff_hz), frequency_hz, axes)

    def siso_state_space(self):
        w = 2 * np.pi * self.cutoff_hz
        return np.array([[-w]]), np.array([[w]]), np.array([[1.0]]), np.array([[0.0]])


@register
class EddyCurrent(Effect):
    """Lossy actuator: eddy currents in the laminations delay the force.

    Flux diffusion into laminations gives a half-order lag
    ``F(s) = 1 / sqrt(1 + s / (2 pi f_e))``.  Fingerprint: -10 dB/decade above
    f_e and a phase tending to -45 deg, unlike any rational low-pass; the coil
    currents do not see it.
    """

    name = "eddy_current"
    location = "input"
    parameters = {"corner_hz": Parameter("Hz", "eddy-current corner frequency f_e", lower=1.0, upper=1e6), "axes": AXES}

    def response(self, frequency_hz, axes):
        return self._diagonal(1.0 / np.sqrt(1.0 + 1j * np.asarray(frequency_hz) / self.corner_hz), frequency_hz, axes)

    def siso_state_space(self):
        """Rational approximation for the time domain (see `half_order_lag_sections`)."""
        poles, zeros = half_order_lag_sections(2 * np.pi * self.corner_hz)
        return _lead_lag_chain(poles, zeros)


@register
class CrossCoupling(Effect):
    """Magnetic (input side) or sensor (output side) coupling between the x and y axes of a bearing.

    The coupling matrix is ``I + c (E_xy + E_yx)`` on (DX, DY) and (NX, NY):
    a current in DX also pulls along DY with ``c`` times its force.  Fingerprint:
    off-diagonal plant terms ``c P_ii`` where the nominal model has none.
    """

    name = "cross_coupling"
    location = "input"
    parameters = {
        "coefficient": Parameter("-", "coupling ratio c", lower=-0.5, upper=0.5),
        "side": Parameter("-", "'input' (forces) or 'output' (sensors)", default="input", kind="string"),
    }

    def validate(self):
        if self.side not in ("input", "output"):
            raise ConfigError("parameters.side", f"must be 'input' or 'output', got {self.side!r}")
        self.location = self.side

    def matrix(self, axes):
        """The static coupling matrix on the given axes (identity where no pair is present)."""
        axes = list(axes)
        matrix = np.eye(len(axes))
        for a, b in (("DX", "DY"), ("NX", "NY")):
            if a in axes and b in axes:
                i, j = axes.index(a), axes.index(b)
                matrix[i, j] = matrix[j, i] = self.coefficient
        return matrix

    def response(self, frequency_hz, axes):
        matrix = self.matrix(axes).astype(complex)
        return np.broadcast_to(matrix, (len(frequency_hz),) + matrix.shape).copy()


# ----------------------------------------------------------------- output side
@register
class SensorLowpass(Effect):
    """Position sensor / anti-alias filter bandwidth.

    Order 1: ``1 / (1 + s/w_c)``; order 2: Butterworth ``w_c^2 / (s^2 + sqrt(2) w_c s + w_c^2)``.
    Fingerprint: phase lag growing with frequency, magnitude -3 dB at f_c, on
    positions only (coil currents unaffected).
    """

    name = "sensor_lowpass"
    location = "output"
    parameters = {
        "cutoff_hz": Parameter("Hz", "sensor bandwidth", lower=1.0, upper=1e6),
        "order": Parameter("-", "filter order, 1 or 2", default=1.0, lower=1, upper=2),
        "axes": AXES,
    }

    def response(self, frequency_hz, axes):
        s = 1j * np.asarray(frequency_hz) / self.cutoff_hz
        scalar = 1.0 / (1.0 + s) if self.order == 1 else 1.0 / (s**2 + np.sqrt(2) * s + 1.0)
        return self._diagonal(scalar, frequency_hz, axes)

    def validate(self):
        if self.order not in (1.0, 2.0):
            raise ConfigError("parameters.order", "must be 1 or 2")

    def siso_state_space(self):
        w = 2 * np.pi * self.cutoff_hz
        if self.order == 1:
            return np.array([[-w]]), np.array([[w]]), np.array([[1.0]]), np.array([[0.0]])
        a = np.array([[0.0, 1.0], [-(w**2), -np.sqrt(2) * w]])
        return a, np.array([[0.0], [w**2]]), np.array([[1.0, 0.0]]), np.array([[0.0]])


@register
class Delay(Effect):
    """Sample-and-hold and computation delay of the digital controller.

    ``exp(-s tau)``.  A zero-order hold alone is about half a controller cycle;
    one cycle of computation adds T.  Fingerprint: magnitude unchanged, phase
    lag 360 f tau degrees growing linearly with frequency.
    """

    name = "delay"
    location = "output"
    parameters = {"delay_s": Parameter("s", "pure time delay tau", lower=0.0, upper=0.01), "axes": AXES}

    def response(self, frequency_hz, axes):
        return self._diagonal(np.exp(-2j * np.pi * np.asarray(frequency_hz) * self.delay_s), frequency_hz, axes)


# ------------------------------------------------------------------- structure
@register
class ElementStiffness(Effect):
    """Young's modulus of a tagged element group scaled (laminations, shrink fits).

    ``scale`` is one factor for the group or one per element of the group (in
    element order).  This is what the model update (thesis ch. 5.2) adjusts.
    Fingerprint: flexible resonances and anti-resonances move, rigid-body
    behaviour is unchanged.
    """

    name = "element_stiffness"
    location = "structure"
    parameters = {
        "tag": Parameter("-", "element tag of the group", kind="string"),
        "scale": Parameter("-", "factor(s) on E of the group", lower=1e-6, upper=100.0, kind="floats"),
    }

    def check(self, machine):
        group = machine.rotor.elements_tagged(self.tag)
        if not group:
            raise ConfigError("parameters.tag", f"no element carries the tag {self.tag!r}")
        if isinstance(self.scale, tuple) and len(self.scale) != len(group):
            raise ConfigError("parameters.scale", f"the group {self.tag!r} has {len(group)} elements, got {len(self.scale)} factors")

    def apply(self, machine):
        group = machine.rotor.elements_tagged(self.tag)
        return replace(machine, rotor=machine.rotor.with_youngs_modulus_scaled(group, self.scale))


@register
class ModalDamping(Effect):
    """Additional viscous damping of the flexible modes (joints, laminations, eddy losses).

    ``damping_ratio`` is one value for all retained flexible modes or one per
    flexible mode (lowest first); it adds ``2 zeta_k omega_k`` to the modal
    damping of the free-free mode k.  Fingerprint: resonance peaks lower and
    wider, frequencies unchanged.
    """

    name = "modal_damping"
    location = "structure"
    parameters = {"damping_ratio": Parameter("-", "added damping ratio zeta", lower=0.0, upper=0.5, kind="floats")}

    def check(self, machine):
        flexible = machine.retained_modes - 2  # the two rigid-body modes of each plane carry none
        if isinstance(self.damping_ratio, tuple) and len(self.damping_ratio) > flexible:
            raise ConfigError(
                "parameters.damping_ratio",
                f"{len(self.damping_ratio)} values for {flexible} retained flexible modes (rotor.retained_modes)",
            )

    def apply(self, machine):
        """Adds to the damping earlier ``modal_damping`` entries gave (a common value covers every flexible mode)."""
        new = np.atleast_1d(np.asarray(self.damping_ratio, dtype=float))
        old = np.asarray(machine.added_modal_damping, dtype=float)
        if old.size == 0:
            total = new
        elif old.size == 1 and new.size == 1:
            total = old + new
        else:
            flexible = machine.retained_modes - 2
            per_mode = lambda r: np.full(flexible, r[0]) if r.size == 1 else np.pad(r, (0, flexible - r.size))  # noqa: E731
            total = per_mode(old) + per_mode(new)
        return replace(machine, added_modal_damping=tuple(total.tolist()))


@register
class ActuatorCoefficients(Effect):
    """The bearings' current and position stiffness differ from the drawing's (thesis eq. 3.2-3.6).

    Per control axis (`ALL_AXES` order, or one value for all), a factor on the
    force constant ``k = mu0 A N^2 cos theta`` (pole area, turns, fringing) and
    one on the bias current the amplifiers deliver.  At the magnetic center
    ``ki = 4 k i_b / (2 g0 + b)^2`` and ``kx = 8 k i_b^2 cos theta / (2 g0 + b)^3``
    scale as ``s_k s_b`` and ``s_k s_b^2``, so the two factors set ``ki`` and ``kx``
    independently; the bearing is linearized at its operating point with the
    changed parameters.  Fingerprint: the rigid-body range moves (the static
    gain ``-ki / kx`` and the unstable poles ``sqrt(kx / m)``), axis by axis.
    """

    name = "actuator_coefficients"
    location = "structure"
    parameters = {
        "force_constant_scale": Parameter("-", "factor on the force constant, per axis", default=1.0, lower=0.2, upper=5.0,
                                          kind="floats"),
        "bias_current_scale": Parameter("-", "factor on the delivered bias current, per axis", default=1.0, lower=0.2,
                                        upper=5.0, kind="floats"),
    }

    def check(self, machine):
        for key in ("force_constant_scale", "bias_current_scale"):
            value = self.values[key]
            if isinstance(value, tuple) and len(value) != len(ALL_AXES):
                raise ConfigError(f"parameters.{key}", f"one value or one per axis {list(ALL_AXES)}, got {len(value)}")

    def factors(self, axis):
        """(force constant factor, bias current factor) of one axis."""
        k = ALL_AXES.index(axis)
        pick = lambda v: v[k] if isinstance(v, tuple) else v  # noqa: E731
        return pick(self.force_constant_scale), pick(self.bias_current_scale)

    def _scaled(self, electromagnet, axis):
        force, bias = self.factors(axis)
        return replace(electromagnet, pole_area_m2=electromagnet.pole_area_m2 * force,
                       bias_current_a=electromagnet.bias_current_a * bias)

    def apply(self, machine):
        bearings = []
        for bearing in machine.radial_bearings:
            planes = dict(bearing.plane_electromagnets)
            for plane in ("x", "y"):
                axis = next(a for a, (b, p) in AXIS_LOCATION.items() if b == bearing.name and p == plane)
                planes[plane] = self._scaled(bearing.electromagnet_of(plane), axis)
            bearings.append(replace(bearing, plane_electromagnets=planes))
        axial = machine.axial_electromagnet
        return replace(machine, radial_bearings=tuple(bearings),
                       axial_electromagnet=None if axial is None else self._scaled(axial, "Z"))


_GAUSS_HERMITE_NODES = 21  # per dimension: exact for the force law's derivatives to far beyond the logged spread


def at_excitation_level(machine, excitation):
    """The machine linearized as the force law averages over an excitation (thesis eq. 3.6, Bussgang).

    The best linear approximation a multisine measures (`ambid.bla`) is, for the
    bearing's static nonlinearity under Gaussian-like inputs, the mean of its
    derivatives over the run's joint distribution of control current ``i_c`` and
    position ``x``: ``ki_eff = E[dF/di_c]``, ``kx_eff = E[dF/dx]``.  With the
    current alone, ``kx (1 + E[i_c^2] / i_b^2)`` and ``ki`` unchanged (``i_u^2 +
    i_l^2 = 2 (i_b^2 + i_c^2)``); position excursions correlated with the current
    (an axial bearing driven where its loop gain is high) cancel part of it.  The
    means come from a 2-D Gauss-Hermite rule over the logged covariance of each
    axis, at the magnetic center, and are applied as `ActuatorCoefficients`
    (bias scale ``kx_eff ki / (kx ki_eff)``, force-constant scale ``ki_eff^2 kx /
    (ki^2 kx_eff)``) to the machine's own electromagnets: the variant's effects
    apply on top and stay its own.  On hs_eden_like's rig this predicts the
    multisine BLA's deviation below 100 Hz (-0.4 to -0.5 %) to within its
    standard error (`benchmarks/bench_multisine.py` part 6).

    Parameters
    ----------
    machine : ambid.machine.Machine
    excitation : dict
        Axis -> ``(var_i_a2, var_x_m2, cov_am)``: the run's variance of the
        differential coil current, of the position and their covariance
        (`ambid.bla.excitation_covariance`); axes left out keep their
        linearization.

    Returns
    -------
    ambid.machine.Machine
    """
    electromagnets = dict(zip(RADIAL_AXES, machine.radial_electromagnets))
    if machine.axial_electromagnet is not None:
        electromagnets["Z"] = machine.axial_electromagnet
    nodes, weights = np.polynomial.hermite_e.hermegauss(_GAUSS_HERMITE_NODES)
    weights = np.outer(weights, weights).ravel() / weights.sum() ** 2
    standard = np.stack([np.repeat(nodes, nodes.size), np.tile(nodes, nodes.size)])
    bias_scale, force_scale = [1.0] * len(ALL_AXES), [1.0] * len(ALL_AXES)
    for axis, values in excitation.items():
        if axis not in electromagnets:
            continue
        var_i, var_x, cov = (float(v) for v in values)
        covariance = np.array([[var_i, cov], [cov, var_x]])
        if not np.all(np.isfinite(covariance)) or np.any(np.linalg.eigvalsh(covariance) < -1e-12 * max(var_i, var_x, 1e-300)):
            raise ConfigError(f"excitation.{axis}", f"not a covariance (var_i, var_x, cov): {values}")
        current, position = np.linalg.cholesky(covariance + 1e-300 * np.eye(2)) @ standard
        magnet = electromagnets[axis]
        ki, kx = magnet.linearize()  # at the magnetic center
        _, ki_all, kx_all = force_derivatives(magnet, magnet.bias_current_a + current, magnet.bias_current_a - current,
                                              position)
        ki_ratio, kx_ratio = float(weights @ ki_all) / ki, float(weights @ kx_all) / kx
        k = ALL_AXES.index(axis)
        bias_scale[k] = kx_ratio / ki_ratio
        force_scale[k] = ki_ratio**2 / kx_ratio
    return ActuatorCoefficients(bias_current_scale=tuple(bias_scale), force_constant_scale=tuple(force_scale)).apply(machine)


@register
class Gyroscopic(Effect):
    """Rotation at ``speed_rpm``: the gyroscopic term Omega G of thesis eq. 2.1.

    Without this effect the machine is modelled at standstill, as in the
    thesis' identification.  Fingerprint: each bending resonance splits into a
    backward (lower) and a forward (higher) whirl, the split growing with
    speed, and the x and y axes become coupled.
    """

    name = "gyroscopic"
    location = "structure"
    parameters = {"speed_rpm": Parameter("rpm", "rotational speed", lower=0.0, upper=1e6)}

    def apply(self, machine):
        return replace(machine, speed_rad_s=self.speed_rpm * 2 * np.pi / 60)


@register
class Noncollocation(Effect):
    """Sensors displaced axially from where the model assumes them.

    ``de_offset_m`` and ``nde_offset_m`` move the DE and NDE sensors along z.
    Fingerprint: the anti-resonances of the same-axis channels move (and can
    vanish past a mode's node), poles do not.
    """

    name = "noncollocation"
    location = "structure"
    parameters = {
        "de_offset_m": Parameter("m", "axial sensor shift at the drive end", default=0.0, lower=-1.0, upper=1.0),
        "nde_offset_m": Parameter("m", "axial sensor shift at the non-drive end", default=0.0, lower=-1.0, upper=1.0),
    }

    def check(self, machine):
        for bearing, key in (("DE", "de_offset_m"), ("NDE", "nde_offset_m")):
            z = machine.bearing(bearing).sensor_position_m + self.values[key]
            if not 0 <= z <= machine.rotor.length_m:
                raise ConfigError(f"parameters.{key}", f"moves the {bearing} sensor off the rotor (z = {z:.4g} m)")

    def apply(self, machine):
        offsets = {"DE": self.de_offset_m, "NDE": self.nde_offset_m}
        bearings = tuple(replace(b, sensor_position_m=b.sensor_position_m + offsets[b.name]) for b in machine.radial_bearings)
        return replace(machine, radial_bearings=bearings)


@register
class FoundationMode(Effect):
    """Flexible housing: each radial bearing's stator and sensor on a mass-spring-damper.

    The AMB force acts between rotor and housing and the sensor measures their
    relative displacement.  Fingerprint: an extra resonance / anti-resonance
    pair near ``frequency_hz`` on every radial channel.
    """

    name = "foundation_mode"
    location = "structure"
    parameters = {
        "mass_kg": Parameter("kg", "housing mass per bearing", lower=1e-3, upper=1e5),
        "frequency_hz": Parameter("Hz", "housing natural frequency on its support", lower=0.1, upper=1e5),
        "damping_ratio": Parameter("-", "housing damping ratio", default=0.02, lower=0.0, upper=1.0),
    }

    def apply(self, machine):
        return replace(machine, foundation=Foundation(self.mass_kg, self.frequency_hz, self.damping_ratio))


# Poles and zeros of prod (1 + s/z_k) / (1 + s/p_k) in units of the corner w_e, fitted once by least squares on the
# complex log error of 1 / sqrt(1 + j x) relative to the lag's own log, |log H - log E| / |log E|, for 1e-5 < x < 1.6e5.
# Relative, because a measured band sees the lag where it is small: the eight sections fitted before on the absolute
# log error (within 0.03 dB and 0.2 deg) put the low-frequency phase 0.9 % short, so a log of a rig with a 1796 Hz
# corner measured to 1 kHz read 0.6-0.8 % high on every channel (1806 Hz, 4.9 of its standard deviations; stop 50).
_HALF_ORDER_POLES = (1.091185963, 2.006339424, 5.04677116, 14.19869758, 41.99629815, 128.5512755, 404.91488,
                     1308.015161, 4323.209026, 14614.76119, 51350.25402, 229455.5611)
_HALF_ORDER_ZEROS = (1.394636344, 3.112769125, 8.395747, 24.30093578, 73.1937029, 227.3888824, 725.5836687,
                     2371.401059, 7924.595407, 27173.83234, 101304.2102, 863442.2354)


def half_order_lag_sections(corner_rad_s):
    """Poles and zeros [rad/s] of a rational approximation of ``1 / sqrt(1 + s / w_e)``.

    Twelve real pole-zero pairs, fitted once on the normalized lag; the
    approximation is within 0.01 dB and 0.05 deg of the exact half-order lag from
    DC to ``10^4 w_e``, and the corner an exact lag fitted to it on any band of
    three decades below ``10^3 w_e`` takes is within 0.01 % of ``w_e`` (tested),
    so the virtual rig simulates the eddy-current effect in the time domain with
    the corner it is given.
    """
    return corner_rad_s * np.array(_HALF_ORDER_POLES), corner_rad_s * np.array(_HALF_ORDER_ZEROS)


def _lead_lag_chain(poles, zeros):
    """Continuous state space of ``prod (1 + s/z_k) / (1 + s/p_k)`` (unit DC gain), one SISO block."""
    n = len(poles)
    a = np.zeros((n, n))
    b = np.zeros((n, 1))
    c = np.zeros((1, n))
    d = 1.0
    # series connection of sections (1 + s/z)/(1 + s/p) = p/z + (1 - p/z) p / (s + p)
    for k, (p, z) in enumerate(zip(poles, zeros)):
        a[k, k] = -p
        a[k, :k] = p * c[0, :k]  # input of section k is the output of the chain so far
        b[k, 0] = p * d
        c_new = np.zeros(n)
        c_new[:k] = (p / z) * c[0, :k]
        c_new[k] = 1 - p / z
        c = c_new[None, :]
        d = (p / z) * d
    return a, b, c, np.array([[d]])


def series_state_space(blocks):
    """SISO series connection of continuous (A, B, C, D) blocks, first block first; none is a unit gain."""
    a, b, c, d = np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.eye(1)
    for a2, b2, c2, d2 in blocks:
        n1, n2 = a.shape[0], a2.shape[0]
        a = np.block([[a, np.zeros((n1, n2))], [b2 @ c, a2]])
        b = np.vstack([b, b2 @ d])
        c = np.hstack([d2 @ c, c2])
        d = d2 @ d
    return a, b, c, d


def split_effects(effects):
    """Effects grouped by where they act: (structure, input, output)."""
    groups = {"structure": [], "input": [], "output": []}
    for effect in effects:
        groups[effect.location].append(effect)
    return groups["structure"], groups["input"], groups["output"]

