"""Active magnetic bearing force law and its linearization (thesis ch. 3.1, eq. 3.1-3.6).

One control axis is a pair of opposed electromagnets (upper and lower coil) with
currents ``i_b + i_c`` and ``i_b - i_c``.  The force along the control axis is
eq. 3.6::

    F = k [ i_u^2 / (2 (g0 - x cos theta) + b)^2 - i_l^2 / (2 (g0 + x cos theta) + b)^2 ]

with ``k = mu0 A_g N^2 cos theta`` (eq. 3.2) and ``b = L_i / mu_r`` the equivalent
iron path (eq. 3.5).  Linearized at an operating point it gives the current
stiffness ``ki = dF/di_c`` [N/A] and the position stiffness ``kx = dF/dx`` [N/m],
which is positive (a destabilizing, negative mechanical stiffness) and enters
the rotor equations as in thesis eq. 2.6: ``M q'' + ... = Kx q + Ki i_c``.
"""

from dataclasses import dataclass

import numpy as np

from .errors import ConfigError

__all__ = ["MU0", "ActuatorAxis", "ActuatorAxes", "force", "force_derivatives"]

MU0 = 4e-7 * np.pi  # vacuum permeability [H/m] (air is taken equal to vacuum)
#: Highest plausible bias flux density [T]: above the saturation of any soft magnetic steel (cobalt-iron: 2.35 T).
MAX_BIAS_FLUX_DENSITY_T = 2.5


@dataclass(frozen=True)
class ActuatorAxis:
    """Electromagnetic parameters of one AMB control axis (eq. 3.2-3.6).

    Parameters
    ----------
    pole_area_m2 : float
        Stator pole face area A_g [m^2].
    turns : float
        Coil turns N per pole pair.
    pole_angle_rad : float
        Angle theta between the control axis and the pole axis (pi/8 for an
        eight-pole radial bearing, 0 for an axial bearing).
    nominal_air_gap_m : float
        g0 [m].
    iron_path_m : float
        Equivalent iron flux path b = L_i / mu_r [m].
    bias_current_a : float
        i_b [A].
    """

    pole_area_m2: float
    turns: float
    pole_angle_rad: float
    nominal_air_gap_m: float
    iron_path_m: float
    bias_current_a: float

    def __post_init__(self):
        for name in ("pole_area_m2", "turns", "nominal_air_gap_m", "bias_current_a"):
            if not getattr(self, name) > 0:
                raise ConfigError(name, f"must be > 0, got {getattr(self, name)}")
        if self.iron_path_m < 0:
            raise ConfigError("iron_path_m", f"must be >= 0, got {self.iron_path_m}")
        if not 0 <= self.pole_angle_rad < np.pi / 2:
            raise ConfigError("pole_angle_rad", "must lie in [0, pi/2)")
        if not self.bias_flux_density_t < MAX_BIAS_FLUX_DENSITY_T:
            raise ConfigError("bias_current_a", f"{self.bias_current_a:g} A gives a bias flux density mu0 N i_b / (2 g0 + b) = "
                              f"{self.bias_flux_density_t:.3g} T, beyond the saturation of any electrical steel (about 2 T): "
                              "check bias_current_a, turns and nominal_air_gap_m (SI units: A, -, m)")

    @property
    def bias_flux_density_t(self):
        """Air-gap flux density at the bias current, ``mu0 N i_b / (2 g0 + b)`` [T] (eq. 3.2-3.5)."""
        return MU0 * self.turns * self.bias_current_a / (2 * self.nominal_air_gap_m + self.iron_path_m)

    @property
    def force_constant(self):
        """k = mu0 A_g N^2 cos(theta) [N m^2 / A^2] (eq. 3.2)."""
        return MU0 * self.pole_area_m2 * self.turns**2 * np.cos(self.pole_angle_rad)

    def linearize(self, position_m=0.0, control_current_a=0.0):
        """Current stiffness ki [N/A] and position stiffness kx [N/m] at an operating point.

        At the magnetic center (``x = 0``, ``i_c = 0``) this is the textbook pair
        ``ki = 4 k i_b / (2 g0 + b)^2`` and ``kx = 8 k i_b^2 cos(theta) / (2 g0 + b)^3``.
        """
        _, d_current, d_position = force_derivatives(
            self, self.bias_current_a + control_current_a, self.bias_current_a - control_current_a, position_m
        )
        return d_current, d_position


@dataclass(frozen=True)
class ActuatorAxes:
    """Several control axes' parameters as column arrays, for vectorized force evaluation.

    Built by `ActuatorAxes.stack`; `force` and `force_derivatives` accept it in
    place of an `ActuatorAxis`, with currents and positions of shape (n_axes, ...).
    """

    pole_area_m2: np.ndarray
    turns: np.ndarray
    pole_angle_rad: np.ndarray
    nominal_air_gap_m: np.ndarray
    iron_path_m: np.ndarray
    bias_current_a: np.ndarray

    force_constant: np.ndarray = None

    def __post_init__(self):
        # computed once: this object sits in the rig's per-cycle loop
        object.__setattr__(self, "force_constant", MU0 * self.pole_area_m2 * self.turns**2 * np.cos(self.pole_angle_rad))

    @classmethod
    def stack(cls, axes):
        """Column arrays (n_axes, 1) from a sequence of validated `ActuatorAxis`."""
        names = ("pole_area_m2", "turns", "pole_angle_rad", "nominal_air_gap_m", "iron_path_m", "bias_current_a")
        return cls(**{name: np.array([[getattr(a, name)] for a in axes], dtype=float) for name in names})


def _gaps(axis, position_m):
    c = np.cos(axis.pole_angle_rad)
    upper = 2 * (axis.nominal_air_gap_m - position_m * c) + axis.iron_path_m
    lower = 2 * (axis.nominal_air_gap_m + position_m * c) + axis.iron_path_m
    return upper, lower, c


def force(axis, upper_current_a, lower_current_a, position_m):
    """Nonlinear force of one control axis, thesis eq. 3.6 [N].

    Parameters
    ----------
    axis : ActuatorAxis
    upper_current_a, lower_current_a : float or array
        Coil currents i_upper, i_lower [A].
    position_m : float or array
        Rotor position x along the control axis relative to the magnetic center [m].
    """
    upper, lower, _ = _gaps(axis, position_m)
    k = axis.force_constant
    return k * (np.square(upper_current_a) / upper**2 - np.square(lower_current_a) / lower**2)


def force_derivatives(axis, upper_current_a, lower_current_a, position_m):
    """Force and its derivatives with respect to i_c and x at (i_u, i_l, x).

    The control current enters as ``i_u = i_b + i_c``, ``i_l = i_b - i_c``, so
    ``dF/di_c = dF/di_u - dF/di_l``.

    Returns
    -------
    force_n, current_stiffness_n_per_a, position_stiffness_n_per_m
    """
    upper, lower, c = _gaps(axis, position_m)
    k = axis.force_constant
    iu, il = np.asarray(upper_current_a, dtype=float), np.asarray(lower_current_a, dtype=float)
    f = k * (iu**2 / upper**2 - il**2 / lower**2)
    d_current = k * (2 * iu / upper**2 + 2 * il / lower**2)
    # d(upper)/dx = -2c, d(lower)/dx = +2c
    d_position = k * (4 * c * iu**2 / upper**3 + 4 * c * il**2 / lower**3)
    return f, d_current, d_position
