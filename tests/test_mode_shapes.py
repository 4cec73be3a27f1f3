"""The modal constants' contrasts (`ambid.mode_shapes`): what they do not see (gains, per-mode factors) and what they do."""

import numpy as np
import pandas as pd
import pytest

from ambid.mode_shapes import ModeShapeContrasts

CHANNELS = [("DX", "DX"), ("DX", "NX"), ("NX", "DX"), ("NX", "NX")]


def shapes_table(shape_d, shape_n, gains=None, mode_factors=None, std=0.01):
    """Measured pole rows of one plane: ``C_m(o, i) = s_o phi_m(o) phi_m(i) a_i mu_m`` for the given shapes."""
    gains = gains or {}
    rows = []
    for m, (d, n) in enumerate(zip(shape_d, shape_n)):
        shape = {"DX": d, "NX": n}
        for output, input_axis in CHANNELS:
            constant = (gains.get(("s", output), 1.0) * shape[output] * shape[input_axis] * gains.get(("a", input_axis), 1.0)
                        * (1.0 if mode_factors is None else mode_factors[m]))
            rows.append({"output": output, "input": input_axis, "root": "pole", "number": m + 1,
                         "frequency_hz": 500.0 * (m + 1) ** 2, "modal_constant": constant, "modal_constant_std": std})
    return pd.DataFrame(rows)


def model_constants(shape_d, shape_n):
    shape = [{"DX": d, "NX": n} for d, n in zip(shape_d, shape_n)]
    return np.array([shape[m][o] * shape[m][i] for m in range(len(shape)) for o, i in CHANNELS])


MODES = np.repeat(np.arange(3), 4)
SHAPE_D, SHAPE_N = [1.0, -0.4, 0.9], [0.8, 0.7, -0.5]


def test_gains_and_per_mode_factors_are_not_seen():
    """Sensor and actuator gains off by percents and a factor per mode (a delay's, a filter's): every contrast 0."""
    gains = {("s", "DX"): 1.04, ("s", "NX"): 0.97, ("a", "DX"): 1.02, ("a", "NX"): 0.95}
    contrasts = ModeShapeContrasts(shapes_table(SHAPE_D, SHAPE_N, gains, mode_factors=[1.0, 0.93, 0.71]), floor=0.01)
    residual, _ = contrasts.residuals(model_constants(SHAPE_D, SHAPE_N), MODES)
    np.testing.assert_allclose(residual, 0.0, atol=1e-9)


def test_a_changed_shape_is_seen_and_one_mode_gives_nothing():
    """The shape ratio of the second mode 3 % off: contrasts of about 3 standard uncertainties; of one mode alone, none."""
    contrasts = ModeShapeContrasts(shapes_table(SHAPE_D, SHAPE_N), floor=0.01)
    changed_d = [SHAPE_D[0], SHAPE_D[1] * 1.03, SHAPE_D[2]]
    residual, _ = contrasts.residuals(model_constants(changed_d, SHAPE_N), MODES)
    chi2, one_ratio = residual @ residual, (np.log(1.03) / 0.01) ** 2
    assert one_ratio < chi2 < 2 * one_ratio  # the sensor and the actuator ratio 3 % off, less what the offsets absorb
    single = ModeShapeContrasts(shapes_table(SHAPE_D[:1], SHAPE_N[:1]), floor=0.01)
    residual, _ = single.residuals(model_constants([1.3], [0.5]), MODES[:4])
    np.testing.assert_allclose(residual, 0.0, atol=1e-9)


def test_uncertain_constants_count_less_and_a_zero_crossing_is_bounded():
    """A constant the fit places to 50 % barely counts; a model constant through zero gives finite values and slopes."""
    table = shapes_table(SHAPE_D, SHAPE_N)
    table.loc[5, "modal_constant_std"] = 0.5  # DX/NX of mode 2
    contrasts = ModeShapeContrasts(table, floor=0.01)
    model = model_constants(SHAPE_D, SHAPE_N)
    off = model.copy()
    off[5] *= 1.2
    residual, _ = contrasts.residuals(off, MODES)
    assert residual @ residual < 0.3
    # 12 constants of one plane less 5 independent offsets (2 sensors, 2 actuators, 3 modes, one shared twice)
    assert contrasts.contrasts(MODES) == 7
    table.loc[6, "modal_constant_std"] = np.inf  # a constant the fit cannot place: no contrast
    assert ModeShapeContrasts(table, floor=0.01).contrasts(MODES) == 6
    through_zero = model.copy()
    through_zero[1] = 0.0
    residual, jacobian = contrasts.residuals(through_zero, MODES, np.eye(model.size))
    assert np.all(np.isfinite(residual)) and np.all(np.isfinite(jacobian))
    assert np.max(np.abs(residual)) < 2 * np.log(2 / 0.01) / 0.01  # the log bounded at log(softening / 2)


@pytest.mark.parametrize("step", [1e-6, 1e-4])
def test_the_slope_is_the_derivative_of_the_residual(step):
    contrasts = ModeShapeContrasts(shapes_table(SHAPE_D, SHAPE_N), floor=0.01)
    model = model_constants(SHAPE_D, SHAPE_N) * np.linspace(0.9, 1.1, 12)
    residual, jacobian = contrasts.residuals(model, MODES, np.eye(model.size))
    for k in (0, 5, 11):
        moved = model.copy()
        moved[k] += step * abs(model[k])
        numeric = (contrasts.residuals(moved, MODES)[0] - residual) / (step * abs(model[k]))
        np.testing.assert_allclose(jacobian[:, k], numeric, rtol=1e-3, atol=1e-6 * np.abs(jacobian).max())
