"""Decentralized digital position controller of one AMB axis.

A PID with a filtered derivative, optionally followed by a low-pass and a notch
filter, designed in continuous time and discretized at the controller cycle
(default 50 us, the PLC minimum of thesis ch. 3.4) with the bilinear (Tustin)
transform, frequency-prewarped at the notch frequency when there is one.

Sign convention
---------------
`Controller.frequency_response` returns the PID transfer ``C_pid`` from the
position error ``-y`` to the control current.  Thesis Table 4.1 writes the
controller block ``C`` (V1 -> U1) with the feedback sign inside it, so that the
input sensitivity is ``(I - P C)^-1``; in that convention ``C = -C_pid``.
"""

from dataclasses import dataclass

import numpy as np

from .errors import ConfigError

__all__ = ["Controller"]


@dataclass(frozen=True)
class Controller:
    """PID controller with derivative filter, optional low-pass and notch.

    Parameters
    ----------
    proportional_gain_a_per_m : float
        k_p [A/m].
    integral_gain_a_per_m_s : float
        k_i [A/(m s)]; 0 disables the integrator.
    derivative_gain_a_s_per_m : float
        k_d [A s/m].
    derivative_filter_hz : float
        Corner of the first-order derivative filter: ``k_d s / (1 + s / w_d)``.
    lowpass_hz : float or None
        Second-order low-pass (damping 0.7) at this frequency, or None.
    notch_hz, notch_width_hz, notch_depth : float or None
        Notch ``(s^2 + 2 z_z w s + w^2) / (s^2 + 2 z_p w s + w^2)`` with
        ``z_p = width / (2 f)`` and ``z_z = depth z_p`` (depth 0 = full notch).
    sample_time_s : float
        Controller cycle [s].
    """

    proportional_gain_a_per_m: float
    derivative_gain_a_s_per_m: float
    derivative_filter_hz: float
    integral_gain_a_per_m_s: float = 0.0
    lowpass_hz: float | None = None
    notch_hz: float | None = None
    notch_width_hz: float | None = None
    notch_depth: float = 0.0
    sample_time_s: float = 50e-6

    def __post_init__(self):
        for name in ("proportional_gain_a_per_m", "derivative_filter_hz", "sample_time_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(name, f"must be > 0, got {getattr(self, name)}")
        for name in ("derivative_gain_a_s_per_m", "integral_gain_a_per_m_s"):
            if getattr(self, name) < 0:
                raise ConfigError(name, f"must be >= 0, got {getattr(self, name)}")
        nyquist = 0.5 / self.sample_time_s
        for name in ("derivative_filter_hz", "lowpass_hz", "notch_hz"):
            value = getattr(self, name)
            if value is not None and not 0 < value < nyquist:
                raise ConfigError(name, f"{value} Hz must lie below the Nyquist frequency {nyquist:g} Hz")
        if self.notch_hz is not None and not (self.notch_width_hz or 0) > 0:
            raise ConfigError("notch_width_hz", "a notch needs a width > 0")

    def continuous_tf(self):
        """Numerator and denominator (highest power first) of C_pid(s)."""
        wd = 2 * np.pi * self.derivative_filter_hz
        kp, ki, kd = self.proportional_gain_a_per_m, self.integral_gain_a_per_m_s, self.derivative_gain_a_s_per_m
        # kp + ki/s + kd s/(1 + s/wd) over the common denominator s (1 + s/wd)
        num = np.polyadd(np.polyadd(kp * np.array([1 / wd, 1, 0]), ki * np.array([1 / wd, 1])), kd * np.array([1, 0, 0]))
        den = np.array([1 / wd, 1, 0])
        if ki == 0:  # cancel the common factor s
            num, den = num[:-1], den[:-1]
        if self.lowpass_hz is not None:
            wl = 2 * np.pi * self.lowpass_hz
            num = np.polymul(num, [wl**2])
            den = np.polymul(den, [1, 2 * 0.7 * wl, wl**2])
        if self.notch_hz is not None:
            wn = 2 * np.pi * self.notch_hz
            zp = self.notch_width_hz / (2 * self.notch_hz)
            num = np.polymul(num, [1, 2 * self.notch_depth * zp * wn, wn**2])
            den = np.polymul(den, [1, 2 * zp * wn, wn**2])
        return num, den

    def discrete_tf(self):
        """Tustin discretization: numerator and denominator in z (highest power first, monic denominator)."""
        num, den = self.continuous_tf()
        if self.notch_hz is not None:
            num, den = _prewarp(num, self.notch_hz, self.sample_time_s), _prewarp(den, self.notch_hz, self.sample_time_s)
        return _bilinear(num, den, self.sample_time_s)

    def discrete_state_space(self):
        """(A, B, C, D) of the discrete controller, input ``-y`` [m], output current [A]."""
        num, den = self.discrete_tf()
        return _controllable_canonical(num, den)

    def frequency_response(self, frequency_hz):
        """C_pid at ``z = exp(j 2 pi f T)`` (the digital controller's own response)."""
        num, den = self.discrete_tf()
        z = np.exp(2j * np.pi * np.asarray(frequency_hz, dtype=float) * self.sample_time_s)
        return np.polyval(num, z) / np.polyval(den, z)


def _controllable_canonical(num, den):
    """(A, B, C, D) of ``num / den`` in controllable canonical form (`scipy.signal.tf2ss`'s realization).

    Written out here rather than imported: ``scipy.signal`` costs ~0.5 s of import in every rule that builds a
    closed loop (a model variant's stability check among them), for a companion matrix.  ``num / den`` is proper (a
    Tustin discretization always is).
    """
    num, den = np.trim_zeros(np.atleast_1d(np.asarray(num, dtype=float)), "f"), np.asarray(den, dtype=float)
    num, den = np.concatenate([np.zeros(den.size - num.size), num]) / den[0], den / den[0]
    order = den.size - 1
    if order == 0:  # a pure gain: one state that nothing drives or reads, as scipy.signal writes it
        return np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)), np.array([[num[0]]])
    a = np.vstack([-den[None, 1:], np.eye(order - 1, order)])
    return a, np.eye(order, 1), (num[1:] - num[0] * den[1:])[None, :], np.array([[num[0]]])


def _bilinear(num, den, sample_time_s):
    """Substitute ``s = (2/T) (z - 1) / (z + 1)`` in num(s)/den(s), clearing ``(z + 1)^n``."""
    order = len(den) - 1
    c = 2.0 / sample_time_s

    def transform(poly):
        poly = np.concatenate([np.zeros(order + 1 - len(poly)), poly])
        out = np.zeros(order + 1)
        for power, coefficient in zip(range(order, -1, -1), poly):
            term = np.polymul(np.poly(np.ones(power)), np.poly(-np.ones(order - power)))
            out = np.polyadd(out, coefficient * c**power * term)
        return out

    num_z, den_z = transform(np.asarray(num, dtype=float)), transform(np.asarray(den, dtype=float))
    return num_z / den_z[0], den_z / den_z[0]


def _prewarp(polynomial, frequency_hz, sample_time_s):
    """Substitute s -> alpha s so that the bilinear transform maps ``frequency_hz`` exactly."""
    w = 2 * np.pi * frequency_hz
    alpha = w / (2 / sample_time_s * np.tan(w * sample_time_s / 2))
    polynomial = np.asarray(polynomial, dtype=float)
    return polynomial * alpha ** np.arange(len(polynomial) - 1, -1, -1)
