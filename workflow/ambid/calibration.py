"""Magnetic center calibration by bias-current perturbation (thesis ch. 3.2-3.3, after Prins 2007).

The position controller holds the rotor at its set point for any bias current.
Two bias levels give two pairs of coil currents that must produce the same
force (eq. 3.6), so eq. 3.7 holds::

    (i_u1^2 - i_u2^2) / G_u^2 = (i_l1^2 - i_l2^2) / G_l^2,
    G_u = 2 (g0 - x cos theta) + b,   G_l = 2 (g0 + x cos theta) + b.

With ``r = sqrt((i_l1^2 - i_l2^2) / (i_u1^2 - i_u2^2))`` the two roots are
``G_l = +r G_u`` and ``G_l = -r G_u``; only the first keeps both gaps positive::

    x = (2 g0 + b) (r - 1) / (2 cos(theta) (r + 1))                  (in the gap)
    x = (2 g0 + b) (r + 1) / (2 cos(theta) (r - 1))                  (|x cos theta| > g0 + b/2)

(the printed eq. 3.8 is garbled; this is the closed form of eq. 3.7).  Five
bias levels (-20 % ... +20 %) give ten pairs whose positions are averaged; the
set point is moved by eq. 3.9, ``x_s,n+1 = x_s,n - x_c,n``, on all radial axes at
once until every ``|x_c|`` is within the tolerance.

Note what follows from the closed form: the fixed point ``x_c = 0`` is ``r = 1``,
which does not depend on g0, b or theta.  Errors in those change how fast the
iteration converges, not where; a current-measurement offset moves the result.
"""

from dataclasses import dataclass
from itertools import combinations

import numpy as np
import pandas as pd

from .bearing import force
from .errors import ConfigError, LogError, settings_from_mapping
from .io import read_parquet, write_parquet
from .machine import ALL_AXES, RADIAL_AXES
from .logs import CHANNELS

__all__ = [
    "CalibrationSettings",
    "calibration_settings_from_config",
    "position_from_pair",
    "bias_pairs",
    "pair_positions",
    "run_calibration",
    "LOG_UNITS",
    "validate_calibration_log",
    "analyse_calibration",
    "calibrated_setpoint",
    "write_calibration_log",
    "read_calibration_log",
    "stiffness_at_magnetic_center",
    "sensitivity_study",
]


@dataclass(frozen=True)
class CalibrationSettings:
    """Settings of the calibration procedure (thesis ch. 3.3, 6.1 defaults)."""

    bias_fractions: tuple = (-0.2, -0.1, 0.0, 0.1, 0.2)
    tolerance_m: float = 3e-6
    max_iterations: int = 15
    average_s: float = 1.0
    settle_s: float = 0.5
    repetitions: int = 5

    def __post_init__(self):
        fractions = np.asarray(self.bias_fractions, dtype=float)
        checks = [
            ("bias_fractions", fractions.size >= 2 and np.unique(fractions).size == fractions.size and np.all(fractions > -1), "needs >= 2 distinct levels above -100 %"),
            ("tolerance_m", self.tolerance_m > 0, "must be > 0"),
            ("max_iterations", self.max_iterations >= 1, "must be >= 1"),
            ("average_s", self.average_s > 0, "must be > 0"),
            ("settle_s", self.settle_s >= 0, "must be >= 0"),
            ("repetitions", self.repetitions >= 1, "must be >= 1"),
        ]
        for key, ok, message in checks:
            if not ok:
                raise ConfigError(f"calibration.{key}", message)


def calibration_settings_from_config(config):
    """`CalibrationSettings` from the ``calibration:`` mapping."""
    return settings_from_mapping(CalibrationSettings, config, "calibration")


def position_from_pair(upper_1, lower_1, upper_2, lower_2, nominal_air_gap_m, iron_path_m, pole_angle_rad):
    """Rotor position relative to the magnetic center from two current pairs (closed form of eq. 3.7).

    Parameters
    ----------
    upper_1, lower_1, upper_2, lower_2 : float or array
        Averaged coil currents at the two bias levels [A].
    nominal_air_gap_m, iron_path_m, pole_angle_rad : float or array
        g0, b and theta of the axis as the method believes them.

    Returns
    -------
    position_m : array
        x along the control axis [m]; NaN where eq. 3.7 has no root inside the gap
        (the two differences of squares of opposite sign, or both zero).
    """
    du = np.asarray(upper_1, dtype=float) ** 2 - np.asarray(upper_2, dtype=float) ** 2
    dl = np.asarray(lower_1, dtype=float) ** 2 - np.asarray(lower_2, dtype=float) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = dl / du
        r = np.sqrt(np.where(ratio > 0, ratio, np.nan))
        x = (2 * nominal_air_gap_m + iron_path_m) * (r - 1) / (2 * np.cos(pole_angle_rad) * (r + 1))
    return np.where(np.abs(x * np.cos(pole_angle_rad)) < nominal_air_gap_m, x, np.nan)


def bias_pairs(n_levels):
    """All pairs (i < j) of bias levels: ten for five levels (thesis ch. 3.3)."""
    return list(combinations(range(n_levels), 2))


def pair_positions(upper_a, lower_a, axes_parameters):
    """Positions from every bias pair.

    Parameters
    ----------
    upper_a, lower_a : arrays (n_levels, n_axes)
        Averaged coil currents per bias level and axis.
    axes_parameters : sequence of ActuatorAxis (n_axes)

    Returns
    -------
    array (n_pairs, n_axes)
        NaN where a pair has no physical root.
    """
    g0 = np.array([a.nominal_air_gap_m for a in axes_parameters])
    b = np.array([a.iron_path_m for a in axes_parameters])
    theta = np.array([a.pole_angle_rad for a in axes_parameters])
    pairs = bias_pairs(upper_a.shape[0])
    first, second = np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])
    return position_from_pair(upper_a[first], lower_a[first], upper_a[second], lower_a[second], g0, b, theta)


# ------------------------------------------------------------------ acquisition
def run_calibration(rig_model, method_axes, settings, seed=0, current_offset_a=0.0, progress=None):
    """Run the calibration procedure against the virtual rig, all repetitions at once.

    Parameters
    ----------
    rig_model : ambid.rig.RigModel
    method_axes : sequence of 4 ActuatorAxis, or one such sequence per repetition
        The electromagnet parameters the method uses (the engineer's, per radial axis).
    settings : CalibrationSettings
    seed : int
    current_offset_a : float, or array (repetitions,) or (repetitions, 4)
        Extra offset on the upper-coil current measurement the method sees (sensitivity studies).
    progress : callable, optional
        ``progress(iteration, offsets (repetitions, 4), converged (repetitions,))``.

    Returns
    -------
    pandas.DataFrame
        The calibration log: one row per (repetition, iteration, bias level, axis).
    """
    fractions = np.asarray(settings.bias_fractions, dtype=float)
    n_levels, n_rep = fractions.size, settings.repetitions
    radial = [ALL_AXES.index(a) for a in RADIAL_AXES]
    t = rig_model.sample_time_s
    settle, average = int(round(settings.settle_s / t)), int(round(settings.average_s / t))
    rng = np.random.default_rng(seed)
    per_repetition = isinstance(method_axes[0], (list, tuple))
    axes_of = (lambda rep: method_axes[rep]) if per_repetition else (lambda rep: method_axes)
    extra = np.asarray(current_offset_a, dtype=float)
    if extra.ndim == 1:  # one value per repetition
        extra = extra[:, None]
    extra = np.broadcast_to(extra, (n_rep, len(RADIAL_AXES)))
    members = n_rep * n_levels  # member m = repetition m // n_levels, level m % n_levels
    state = rig_model.initial_state(members)
    level = np.tile(np.arange(n_levels), n_rep)
    state.bias_a[radial] = rig_model.nominal_bias_a[radial, None] * (1 + fractions[level])
    setpoints = np.zeros((n_rep, len(radial)))
    active = np.ones(n_rep, dtype=bool)
    rows = []
    excitation = np.zeros((len(ALL_AXES), members))
    for iteration in range(1, settings.max_iterations + 1):
        state.setpoint_m[radial] = np.repeat(setpoints, n_levels, axis=0).T
        total = np.zeros((20, members))
        for cycle in range(settle + average):
            channels = rig_model.step(state, excitation, rng)
            if cycle >= settle:
                total += channels
        mean = total / average
        upper = mean[[CHANNELS.index(f"I_upper_{ALL_AXES[a]}") for a in radial]].T + np.repeat(extra, n_levels, axis=0)
        lower = mean[[CHANNELS.index(f"I_lower_{ALL_AXES[a]}") for a in radial]].T  # (members, 4)
        position = mean[[CHANNELS.index(f"V2_{ALL_AXES[a]}") for a in radial]].T
        offsets = np.full((n_rep, len(radial)), np.nan)
        for rep in np.flatnonzero(active):
            block = slice(rep * n_levels, (rep + 1) * n_levels)
            offsets[rep] = np.nanmean(pair_positions(upper[block], lower[block], axes_of(rep)), axis=0)
            for k in range(n_levels):
                m = rep * n_levels + k
                for a, axis in enumerate(RADIAL_AXES):
                    rows.append(dict(repetition=rep + 1, iteration=iteration, bias_level=k, bias_fraction=fractions[k],
                                     axis=axis, setpoint_m=setpoints[rep, a], bias_current_a=state.bias_a[radial[a], m],
                                     upper_current_a=upper[m, a], lower_current_a=lower[m, a], position_m=position[m, a],
                                     offset_m=offsets[rep, a]))
        converged = active & np.all(np.abs(offsets) < settings.tolerance_m, axis=1)
        if progress is not None:
            progress(iteration, offsets, converged)
        setpoints[active] -= offsets[active]
        active &= ~converged
        if not active.any():
            break
    return pd.DataFrame(rows)


LOG_UNITS = {
    "repetition": "-", "iteration": "-", "bias_level": "-", "bias_fraction": "-", "setpoint_m": "m",
    "bias_current_a": "A", "upper_current_a": "A", "lower_current_a": "A", "position_m": "m", "offset_m": "m",
}


def write_calibration_log(frame, path, metadata=None):
    """Write the calibration log (Parquet, kind ``calibration_log``, units in the metadata)."""
    validate_calibration_log(frame, str(path))
    write_parquet(frame, path, LOG_UNITS, kind="calibration_log", metadata=metadata)


def read_calibration_log(path):
    """Read and validate a calibration log; returns (frame, info)."""
    frame, info = read_parquet(path, kind="calibration_log")
    validate_calibration_log(frame, str(path))
    return frame, info


def sensitivity_study(rig_model, method_axes, settings, truth_m, seed=0, relative_error=0.1, current_offset_a=0.05):
    """How far the found center moves when the method's g0, b or theta are off, or a current sensor is.

    One calibration (one repetition) per variant on the rig; the error is
    measured against the rig's truth ``truth_m`` (sensor coordinates, 4 axes).

    Returns
    -------
    pandas.DataFrame
        ``variant``, ``iterations``, ``converged``, ``max_error_m`` and the error per axis.
    """
    from dataclasses import replace

    variants = [("nominal parameters", list(method_axes), 0.0)]
    for name, key in (("g0", "nominal_air_gap_m"), ("b", "iron_path_m"), ("theta", "pole_angle_rad")):
        for sign in (-1, +1):
            scaled = [replace(a, **{key: getattr(a, key) * (1 + sign * relative_error)}) for a in method_axes]
            variants.append((f"{name} {sign * relative_error:+.0%}", scaled, 0.0))
    variants.append((f"upper-coil current sensor offset {current_offset_a:+g} A", list(method_axes), current_offset_a))
    # the variants run side by side, one "repetition" each
    batch = replace(settings, repetitions=len(variants))
    log = run_calibration(rig_model, [v[1] for v in variants], batch, seed=seed, current_offset_a=np.array([v[2] for v in variants]))
    rows = []
    for k, (name, axes, _) in enumerate(variants):
        one = log[log["repetition"] == k + 1]
        analysis = analyse_calibration(one, axes, replace(settings, repetitions=1))
        error = analysis["result"]["magnetic_center_m"].to_numpy() - np.asarray(truth_m)[:4]
        rows.append({"variant": name, "iterations": int(analysis["result"]["max_iterations_used"].iloc[0]),
                     "converged": bool(analysis["result"]["all_repetitions_converged"].iloc[0]),
                     "max_error_m": float(np.max(np.abs(error))),
                     **{f"error_{axis}_m": float(e) for axis, e in zip(RADIAL_AXES, error)}})
    return pd.DataFrame(rows)


def stiffness_at_magnetic_center(method_axes, magnetic_center_m, control_current_a):
    """ki and kx when the rotor runs at the magnetic center versus at the geometric center.

    At the magnetic center the rotor carries its static load with the measured
    control current ``control_current_a``; at the geometric center (sensor zero,
    ``-magnetic_center_m`` from the magnetic center) the current that carries the
    same force is solved for.

    Returns
    -------
    pandas.DataFrame
        Per axis: both (ki, kx) pairs and their relative change.
    """
    rows = []
    for axis, parameters, center, current in zip(RADIAL_AXES, method_axes, magnetic_center_m, control_current_a):
        ib = parameters.bias_current_a
        load = force(parameters, ib + current, ib - current, 0.0)
        # current that carries the same load off-center: force is monotonic in the control current
        grid = np.linspace(-0.95 * ib, 0.95 * ib, 20001)
        off_center = force(parameters, ib + grid, ib - grid, -center)
        geometric_current = float(np.interp(load, off_center, grid))
        ki_m, kx_m = parameters.linearize(0.0, current)
        ki_g, kx_g = parameters.linearize(-center, geometric_current)
        rows.append({"axis": axis, "magnetic_center_m": center, "control_current_a": current,
                     "current_stiffness_at_magnetic_center_n_per_a": ki_m, "position_stiffness_at_magnetic_center_n_per_m": kx_m,
                     "control_current_at_geometric_center_a": geometric_current,
                     "current_stiffness_at_geometric_center_n_per_a": ki_g, "position_stiffness_at_geometric_center_n_per_m": kx_g,
                     "current_stiffness_change": ki_g / ki_m - 1, "position_stiffness_change": kx_g / kx_m - 1})
    return pd.DataFrame(rows)


# --------------------------------------------------------------------- analysis
def validate_calibration_log(frame, source, n_levels=None):
    """Check a calibration log; raise LogError naming the axis, repetition and iteration at fault."""
    missing = [c for c in ["axis", *LOG_UNITS] if c not in frame.columns]
    if missing:
        raise LogError(source, f"missing column(s) {missing}")
    for column in ("setpoint_m", "bias_current_a", "upper_current_a", "lower_current_a", "position_m"):
        bad = frame[~np.isfinite(frame[column].to_numpy(dtype=float))]
        if len(bad):
            row = bad.iloc[0]
            raise LogError(source, f"axis {row['axis']}, repetition {row['repetition']}, iteration {row['iteration']}: {column} is not finite")
    levels = n_levels or frame["bias_level"].nunique()
    for (rep, iteration, axis), group in frame.groupby(["repetition", "iteration", "axis"]):
        found = sorted(group["bias_level"])
        if found != list(range(levels)):
            raise LogError(source, f"axis {axis}, repetition {rep}, iteration {iteration}: bias levels {found}, expected {list(range(levels))}")


def analyse_calibration(frame, method_axes, settings, source="calibration.parquet"):
    """Recompute the calibration from its log alone: thesis tables 6.1-6.3 and the result.

    Parameters
    ----------
    frame : pandas.DataFrame
        The calibration log.
    method_axes : sequence of 4 ActuatorAxis
        g0, b, theta the method uses.
    settings : CalibrationSettings

    Returns
    -------
    dict of pandas.DataFrame
        ``offsets`` (per repetition, iteration and axis: x_c recomputed, set point),
        ``pairs`` (positions per bias pair, first repetition's last iteration, and their average:
        thesis Table 6.2), ``repeatability`` (magnetic center per repetition, average and spread:
        Table 6.3), ``result`` (per axis: magnetic center, standard uncertainty, spread,
        iterations, converged).
    """
    validate_calibration_log(frame, source, len(settings.bias_fractions))
    offsets, pair_tables = [], {}
    for (rep, iteration), group in frame.groupby(["repetition", "iteration"]):
        table = group.pivot(index="bias_level", columns="axis")
        upper = table["upper_current_a"][list(RADIAL_AXES)].to_numpy()
        lower = table["lower_current_a"][list(RADIAL_AXES)].to_numpy()
        positions = pair_positions(upper, lower, method_axes)
        for a, axis in enumerate(RADIAL_AXES):
            if np.all(np.isnan(positions[:, a])):
                raise LogError(source, f"axis {axis}, repetition {rep}, iteration {iteration}: no bias pair has a physical root (eq. 3.7)")
        setpoint = table["setpoint_m"][list(RADIAL_AXES)].to_numpy()[0]
        x_c = np.nanmean(positions, axis=0)
        for a, axis in enumerate(RADIAL_AXES):
            offsets.append(dict(repetition=rep, iteration=iteration, axis=axis, setpoint_m=setpoint[a], offset_m=x_c[a],
                                magnetic_center_m=setpoint[a] - x_c[a], valid_pairs=int(np.sum(~np.isnan(positions[:, a])))))
        pair_tables[(rep, iteration)] = (setpoint - positions)
    offsets = pd.DataFrame(offsets)
    last = offsets.sort_values("iteration").groupby(["repetition", "axis"]).tail(1)
    converged = last.groupby("repetition")["offset_m"].apply(lambda s: bool(np.all(np.abs(s) < settings.tolerance_m)))
    first_rep = offsets["repetition"].min()
    last_iteration = offsets.loc[offsets["repetition"] == first_rep, "iteration"].max()
    pairs_values = pair_tables[(first_rep, last_iteration)]
    names = [f"{i + 1}-{j + 1}" for i, j in bias_pairs(len(settings.bias_fractions))]
    pairs = pd.DataFrame(pairs_values, columns=list(RADIAL_AXES))
    pairs.insert(0, "bias_pair", names)
    pairs.loc[len(pairs)] = ["average", *np.nanmean(pairs_values, axis=0)]
    repeat = last.pivot(index="repetition", columns="axis", values="magnetic_center_m")[list(RADIAL_AXES)]
    summary = pd.DataFrame([repeat.mean(), repeat.max() - repeat.min()], index=["average", "spread"])
    repeatability = pd.concat([repeat, summary])
    repeatability.index.name = "repetition"
    iterations = last.groupby("repetition")["iteration"].first()
    n = len(repeat)
    result = pd.DataFrame({
        "axis": list(RADIAL_AXES),
        "magnetic_center_m": repeat.mean().to_numpy(),
        "standard_uncertainty_m": (repeat.std(ddof=1) / np.sqrt(n)).to_numpy() if n > 1 else np.full(4, np.nan),
        "spread_m": (repeat.max() - repeat.min()).to_numpy(),
        "max_iterations_used": int(iterations.max()),
        "all_repetitions_converged": bool(converged.all()),
    })
    # static control current at the found center: (i_upper - i_lower) / 2 at the unperturbed bias level
    final = frame.merge(last[["repetition", "iteration"]].drop_duplicates(), on=["repetition", "iteration"])
    nominal_level = int(np.argmin(np.abs(np.asarray(settings.bias_fractions, dtype=float))))
    at_bias = final[final["bias_level"] == nominal_level]
    control = ((at_bias["upper_current_a"] - at_bias["lower_current_a"]) / 2).groupby(at_bias["axis"]).mean()
    result["control_current_a"] = control[list(RADIAL_AXES)].to_numpy()
    not_converged = sorted(set(last.loc[np.abs(last["offset_m"]) >= settings.tolerance_m, "axis"]))
    return {"offsets": offsets, "pairs": pairs, "repeatability": repeatability.reset_index(), "result": result,
            "not_converged_axes": not_converged}


def calibrated_setpoint(path, method_axes, settings):
    """Position set points [m] on `ALL_AXES` at the magnetic center a calibration log finds (0 on axes it leaves).

    Parameters
    ----------
    path : str or Path
        The calibration log.
    method_axes : sequence of 4 ActuatorAxis
        g0, b, theta the method uses (the drawing's bearing parameters).
    settings : CalibrationSettings
    """
    frame, _ = read_calibration_log(path)
    center = analyse_calibration(frame, method_axes, settings, source=str(path))["result"].set_index("axis")
    return np.array([center["magnetic_center_m"].get(axis, 0.0) for axis in ALL_AXES])
