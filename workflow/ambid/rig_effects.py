"""Physics only a rig has: hidden effects outside the model's effect library.

A real machine has things no effect of `ambid.effects` represents.  To test
that the diagnosis says "unexplained" rather than naming a library effect that
only resembles them, the virtual rig can hide these (``truth.unmodelled`` in a
rig file).  They are not registered in `ambid.effects.EFFECTS`, so no model
can name them; only `ambid.rig` builds them.

``amplifier_second_order``
    A current loop of second order, ``w^2 / (s^2 + 2 zeta w s + w^2)``, where the
    library knows only a first-order amplifier.
``sensor_gain``
    One position sensor reading ``gain`` times the true displacement.
``sensor_notch``
    A notch in the position measurement chain (a sensor electronics filter).
``controller_notch``
    The controller's notch tuned elsewhere than the model says; invisible to the
    open-loop plant that the identification measures (U2 -> V2 and the coil
    currents do not contain the controller), so the diagnosis must find nothing.
"""

from dataclasses import replace

import numpy as np

from .effects import AXES, Effect, Parameter
from .errors import ConfigError
from .machine import ALL_AXES

__all__ = ["RIG_ONLY_EFFECTS", "rig_effect_from_config", "apply_controller_effects"]

RIG_ONLY_EFFECTS = {}


def _register(cls):
    RIG_ONLY_EFFECTS[cls.name] = cls
    return cls


@_register
class AmplifierSecondOrder(Effect):
    """Second-order current loop between commanded and coil current (rig chain ``coil``)."""

    name = "amplifier_second_order"
    location = "input"
    rig_chain = "coil"
    parameters = {
        "natural_hz": Parameter("Hz", "natural frequency of the current loop", lower=1.0, upper=1e6),
        "damping_ratio": Parameter("-", "damping ratio of the current loop", default=0.7, lower=0.05, upper=5.0),
        "axes": AXES,
    }

    def _scalar(self, frequency_hz):
        s = 1j * np.asarray(frequency_hz) / self.natural_hz
        return 1.0 / (s**2 + 2 * self.damping_ratio * s + 1.0)

    def response(self, frequency_hz, axes):
        return self._diagonal(self._scalar(frequency_hz), frequency_hz, axes)

    def siso_state_space(self):
        w, z = 2 * np.pi * self.natural_hz, self.damping_ratio
        return np.array([[0.0, 1.0], [-(w**2), -2 * z * w]]), np.array([[0.0], [w**2]]), np.array([[1.0, 0.0]]), np.array([[0.0]])


@_register
class SensorGain(Effect):
    """One radial sensor reading ``gain`` times the displacement (rig chain ``output_matrix``)."""

    name = "sensor_gain"
    location = "output"
    rig_chain = "output_matrix"
    parameters = {
        "axis": Parameter("-", "the sensor's axis", kind="string"),
        "gain": Parameter("-", "sensor gain relative to the model's", lower=0.5, upper=2.0),
    }

    def validate(self):
        if self.axis not in ALL_AXES:
            raise ConfigError("parameters.axis", f"unknown axis {self.axis!r}; axes are {list(ALL_AXES)}")

    def matrix(self, axes):
        return np.diag([self.gain if a == self.axis else 1.0 for a in axes])

    def response(self, frequency_hz, axes):
        matrix = self.matrix(axes).astype(complex)
        return np.broadcast_to(matrix, (len(frequency_hz),) + matrix.shape).copy()


@_register
class SensorNotch(Effect):
    """A notch ``(s^2 + 2 d z w s + w^2) / (s^2 + 2 z w s + w^2)`` in the position measurement (rig chain ``sensor``)."""

    name = "sensor_notch"
    location = "output"
    rig_chain = "sensor"
    parameters = {
        "frequency_hz": Parameter("Hz", "notch frequency", lower=1.0, upper=1e5),
        "width_hz": Parameter("Hz", "notch width", lower=0.1, upper=1e5),
        "depth": Parameter("-", "remaining gain at the notch (0: full notch)", default=0.1, lower=0.0, upper=1.0),
        "axes": AXES,
    }

    def _coefficients(self):
        w = 2 * np.pi * self.frequency_hz
        zeta = self.width_hz / (2 * self.frequency_hz)
        return w, zeta, self.depth * zeta

    def response(self, frequency_hz, axes):
        w, zp, zz = self._coefficients()
        s = 2j * np.pi * np.asarray(frequency_hz)
        return self._diagonal((s**2 + 2 * zz * w * s + w**2) / (s**2 + 2 * zp * w * s + w**2), frequency_hz, axes)

    def siso_state_space(self):
        w, zp, zz = self._coefficients()
        a = np.array([[0.0, 1.0], [-(w**2), -2 * zp * w]])
        # (s^2 + b1 s + b0) / (s^2 + a1 s + a0) = 1 + ((b1 - a1) s + (b0 - a0)) / (s^2 + a1 s + a0)
        return a, np.array([[0.0], [1.0]]), np.array([[0.0, 2 * (zz - zp) * w]]), np.array([[1.0]])


@_register
class ControllerNotch(Effect):
    """The radial controllers' notch as built (rig chain ``controller``: replaces the model's notch)."""

    name = "controller_notch"
    location = "controller"
    rig_chain = "controller"
    parameters = {
        "notch_hz": Parameter("Hz", "notch frequency", lower=1.0, upper=1e5),
        "notch_width_hz": Parameter("Hz", "notch width", lower=0.1, upper=1e5),
        "notch_depth": Parameter("-", "notch depth", default=0.0, lower=0.0, upper=1.0),
    }

    def apply(self, machine):
        controllers = tuple(replace(c, notch_hz=self.notch_hz, notch_width_hz=self.notch_width_hz, notch_depth=self.notch_depth)
                            for c in machine.radial_controllers)
        return replace(machine, radial_controllers=controllers)


def rig_effect_from_config(spec, path):
    """A rig-only effect from ``{name: ..., parameters: {...}}`` (`RIG_ONLY_EFFECTS`)."""
    if not isinstance(spec, dict) or spec.get("name") not in RIG_ONLY_EFFECTS:
        raise ConfigError(f"{path}.name", f"unknown rig-only effect {spec.get('name') if isinstance(spec, dict) else spec!r}; "
                                          f"known: {sorted(RIG_ONLY_EFFECTS)}")
    try:
        return RIG_ONLY_EFFECTS[spec["name"]](**(spec.get("parameters") or {}))
    except ConfigError as error:
        raise error.within(path) from None


def apply_controller_effects(machine, effects):
    """The machine with the rig-only controller effects applied; the others returned for the signal chains."""
    rest = []
    for effect in effects:
        if effect.location == "controller":
            machine = effect.apply(machine)
        else:
            rest.append(effect)
    return machine, rest

