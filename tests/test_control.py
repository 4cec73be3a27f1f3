"""Digital PID controller: discretization, filters, validation."""

import numpy as np
import pytest
import scipy.signal
from numpy.testing import assert_allclose

from ambid.control import Controller
from ambid.errors import ConfigError


def continuous_response(controller, frequency_hz):
    num, den = controller.continuous_tf()
    s = 2j * np.pi * np.asarray(frequency_hz)
    return np.polyval(num, s) / np.polyval(den, s)


class TestController:
    controller = Controller(1.5e4, derivative_gain_a_s_per_m=30.0, derivative_filter_hz=2500, integral_gain_a_per_m_s=5e4, lowpass_hz=3000)

    def test_pid_terms(self):
        pid = Controller(2e4, 10.0, 5000, 3e5)
        s = 2j * np.pi * 50.0
        expected = 2e4 + 3e5 / s + 10.0 * s / (1 + s / (2 * np.pi * 5000))
        assert_allclose(continuous_response(pid, 50.0), expected, rtol=1e-12)

    def test_tustin_matches_continuous_well_below_nyquist(self):
        f = np.array([5.0, 50.0, 300.0])
        assert_allclose(self.controller.frequency_response(f), continuous_response(self.controller, f), rtol=2e-2)

    @pytest.mark.filterwarnings("ignore::scipy.linalg.LinAlgWarning")  # scipy's own reference path
    def test_against_scipy_bilinear(self):
        num, den = self.controller.continuous_tf()
        ref_num, ref_den, _ = scipy.signal.cont2discrete((num, den), 50e-6, method="bilinear")
        z = np.exp(2j * np.pi * np.array([10.0, 700.0, 4000.0]) * 50e-6)
        ours = self.controller.frequency_response([10.0, 700.0, 4000.0])
        assert_allclose(ours, np.polyval(np.squeeze(ref_num), z) / np.polyval(ref_den, z), rtol=1e-6)

    def test_state_space_is_scipys_realization(self):
        """The controller's state space is `scipy.signal.tf2ss`'s controllable canonical form, entry for entry."""
        for controller in (self.controller, Controller(2e4, 10.0, 5000, 3e5), Controller(1.5e4, 30.0, 2500, notch_hz=1200.0, notch_width_hz=100.0)):
            for ours, reference in zip(controller.discrete_state_space(), scipy.signal.tf2ss(*controller.discrete_tf())):
                assert ours.shape == reference.shape
                assert_allclose(ours, reference, rtol=1e-14, atol=0)

    def test_notch_is_exact_at_its_frequency(self):
        notched = Controller(1.5e4, 30.0, 2500, notch_hz=1200.0, notch_width_hz=100.0)
        assert abs(notched.frequency_response([1200.0])[0]) < 1e-6 * abs(notched.frequency_response([100.0])[0])

    def test_state_space_reproduces_transfer_function(self):
        a, b, c, d = self.controller.discrete_state_space()
        z = np.exp(2j * np.pi * 400.0 * 50e-6)
        from_ss = (c @ np.linalg.solve(z * np.eye(a.shape[0]) - a, b) + d)[0, 0]
        assert_allclose(from_ss, self.controller.frequency_response([400.0])[0], rtol=1e-8)


@pytest.mark.parametrize(
    "kwargs, key",
    [
        (dict(proportional_gain_a_per_m=-1.0, derivative_gain_a_s_per_m=1.0, derivative_filter_hz=100), "proportional_gain"),
        (dict(proportional_gain_a_per_m=1.0, derivative_gain_a_s_per_m=1.0, derivative_filter_hz=20000), "derivative_filter_hz"),
        (dict(proportional_gain_a_per_m=1.0, derivative_gain_a_s_per_m=1.0, derivative_filter_hz=100, notch_hz=500), "notch_width_hz"),
    ],
)
def test_invalid_settings_name_the_key(kwargs, key):
    with pytest.raises(ConfigError, match=key):
        Controller(**kwargs)
