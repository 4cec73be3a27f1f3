"""AMB force law (eq. 3.6) and its linearization (eq. 2.6)."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from ambid.bearing import MU0, ActuatorAxis, force, force_derivatives
from ambid.errors import ConfigError

AXIS = ActuatorAxis(
    pole_area_m2=6e-4, turns=80, pole_angle_rad=np.pi / 8, nominal_air_gap_m=5e-4, iron_path_m=1e-4, bias_current_a=5.0
)


class TestForceLaw:
    def test_force_constant(self):
        assert_allclose(AXIS.force_constant, MU0 * 6e-4 * 80**2 * np.cos(np.pi / 8))

    def test_balanced_at_center(self):
        assert force(AXIS, 5.0, 5.0, 0.0) == pytest.approx(0.0, abs=1e-12)

    def test_signs(self):
        assert force(AXIS, 6.0, 4.0, 0.0) > 0  # more upper current pulls up
        assert force(AXIS, 5.0, 5.0, 1e-5) > 0  # displacement toward the upper pole is unstable

    def test_textbook_linearization_at_center(self):
        gap = 2 * AXIS.nominal_air_gap_m + AXIS.iron_path_m
        ki, kx = AXIS.linearize()
        assert_allclose(ki, 4 * AXIS.force_constant * 5.0 / gap**2)
        assert_allclose(kx, 8 * AXIS.force_constant * 25.0 * np.cos(np.pi / 8) / gap**3)

    @pytest.mark.parametrize("position_m, control_a", [(0.0, 0.0), (40e-6, 0.3), (-120e-6, -1.0), (150e-6, 2.0)])
    def test_linearization_against_finite_differences(self, position_m, control_a):
        ib, h_i, h_x = AXIS.bias_current_a, 1e-6, 1e-10
        ki, kx = AXIS.linearize(position_m, control_a)
        dfdi = (force(AXIS, ib + control_a + h_i, ib - control_a - h_i, position_m) - force(AXIS, ib + control_a - h_i, ib - control_a + h_i, position_m)) / (2 * h_i)
        dfdx = (force(AXIS, ib + control_a, ib - control_a, position_m + h_x) - force(AXIS, ib + control_a, ib - control_a, position_m - h_x)) / (2 * h_x)
        assert_allclose(ki, dfdi, rtol=1e-6)
        assert_allclose(kx, dfdx, rtol=1e-5)

    def test_force_derivatives_returns_force(self):
        f, _, _ = force_derivatives(AXIS, 5.5, 4.5, 2e-5)
        assert_allclose(f, force(AXIS, 5.5, 4.5, 2e-5))

    def test_iron_path_lowers_stiffness(self):
        ideal = ActuatorAxis(6e-4, 80, np.pi / 8, 5e-4, 0.0, 5.0)
        assert AXIS.linearize()[0] < ideal.linearize()[0]


def test_invalid_parameters_name_the_key():
    with pytest.raises(ConfigError, match="nominal_air_gap_m"):
        ActuatorAxis(6e-4, 80, 0.3, -1e-4, 0.0, 5.0)


def test_a_bias_beyond_saturation_is_refused():
    from ambid.bearing import ActuatorAxis
    from ambid.errors import ConfigError

    axis = dict(pole_area_m2=4e-4, turns=80, pole_angle_rad=np.pi / 8, nominal_air_gap_m=5e-4, iron_path_m=1e-4)
    assert ActuatorAxis(bias_current_a=3.0, **axis).bias_flux_density_t == pytest.approx(0.274, abs=1e-3)
    with pytest.raises(ConfigError, match=r"bias_current_a: 1e\+06 A gives a bias flux density .* 9.14e\+04 T"):
        ActuatorAxis(bias_current_a=1e6, **axis)
