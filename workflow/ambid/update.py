"""Rotor model update (thesis ch. 5.2): element moduli and modal damping from measured resonances.

The objective is thesis eq. 5.29-5.35.  For every measured feature i (a
resonance or anti-resonance of channel ij, mode k) the weighted relative errors

    r_f,i = w_f (f_model - f_meas) / f_meas            (eq. 5.29, 5.30, weights of eq. 5.33)
    r_d,i = w_d w_d,k (zeta_model - zeta_meas) / zeta_meas   (eq. 5.31, 5.32, weights of eq. 5.34-5.35)

form one residual vector; ``B(e) = sum |r|`` is the thesis' total error
(eq. 5.35, 5.36).  Two optimizers minimise it:

* ``nelder_mead``: the thesis' derivative-free simplex on ``B(e)`` (appendix 1);
* ``least_squares`` (default): bounded trust-region least squares on ``sum r^2``
  with the analytic eigenvalue sensitivities of `ambid.modal_features`, in
  log-modulus coordinates, from the configured start and random starts (the
  appendix' uniform 0 .. 2 x nominal) against the local minima the thesis
  warns about.  Both reach ``B = 0`` on consistent data.

Model roots are matched to measured ones by frequency proximity and, for
resonances, the sign of the modal constant (the mode shape's sign at sensor
and actuator), not by index, so modes that move past each other stay matched.
`identifiability` says which variables the data determine.

The measured features carry the fit stage's own error: its estimator
approximates the modes above the band by one residual factor, which moves
the roots where a channel's response is small (a cross channel's
anti-resonance).  `debiased_update` applies the same estimator to the
updated model's noise-free FRF, on the measured grid with the measured
weights (`estimator_bias`), takes what it gets wrong off each feature and
updates again, to a fixed point.
"""

from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
import scipy.optimize

from .channel_fit import FitError, feature_rows, fit_plant_channel, select_channels
from .compare import model_channels
from .errors import AmbidError, ConfigError, settings_from_mapping
from .frf import channel, radial_estimator
from .machine import machine_from_config
from .modal_features import LIGHT_DAMPING, ModalFeatureModel, design_variables, root_feature_derivatives, root_features
from .mode_shapes import ModeShapeContrasts
from .plant import Plant, damping_ratio

__all__ = ["UpdateSettings", "UpdateError", "UpdateProblem", "UpdateResult", "measured_features", "reference_features",
           "update_channels", "update_problem", "update_model",
           "least_squares_update", "nelder_mead_update", "identifiability", "comparison_rows", "updated_machine_config",
           "estimator_bias", "bias_at_values", "without_bias", "debiased_update", "BIAS_MATCH"]

THESIS_INDEX = {"NX": 1, "NY": 2, "DX": 3, "DY": 4}  # thesis Table 5.1
ORDINALS = {1: "first", 2: "second", 3: "third", 4: "fourth", 5: "fifth"}


class UpdateError(AmbidError):
    """The update cannot run: no usable measured features, an inconsistent setting."""


@dataclass(frozen=True)
class UpdateSettings:
    """The ``update:`` config section (config/README.md), merged with the machine's ``update:`` entry."""

    tags: tuple = ()
    per_element: bool = True
    damping: str = "common"
    channels: str = "same_plane"
    modes: int = 1
    optimizer: str = "least_squares"
    starts: int = 8
    seed: int = 0
    max_evaluations: int = 300
    stiffness_bounds: tuple = (1e-3, 2.0)
    damping_bounds: tuple = (0.0, 0.2)
    weights: dict = field(default_factory=lambda: dict(resonance_frequency=1.0, anti_resonance_frequency=1.0,
                                                       resonance_damping=1.0, anti_resonance_damping=1.0, damping=0.01,
                                                       mode_shape=1.0))
    feature_std_floor: dict = field(default_factory=lambda: dict(frequency=5e-4, damping=0.05, modal_constant=0.01))
    determined_std: float = 0.1
    regularization: float = 5e-4
    valley_step: float = 1.0
    estimator_bias: bool = True
    weigh_by_uncertainty: bool = True

    @classmethod
    def from_config(cls, section, machine_section=None):
        """Settings from the ``update:`` section and a machine's ``update:`` entry; `ConfigError` naming the key.

        Every check that needs no data runs here (the workflow calls it before any job).
        """
        merged = {**(section or {}), **(machine_section or {})}
        settings = settings_from_mapping(cls, merged, "update")
        # a config's weights and floors without the keys beyond the thesis (mode_shape, modal_constant) keep their defaults
        defaults = cls()
        settings = replace(settings, weights={**defaults.weights, **settings.weights},
                           feature_std_floor={**defaults.feature_std_floor, **settings.feature_std_floor})
        if settings.optimizer not in ("least_squares", "nelder_mead"):
            raise ConfigError("update.optimizer", f"must be 'least_squares' or 'nelder_mead', not {settings.optimizer!r}")
        for key in ("modes", "starts"):
            if getattr(settings, key) < 1:
                raise ConfigError(f"update.{key}", f"must be >= 1, got {getattr(settings, key)}")
        lower, upper = settings.stiffness_bounds
        if not 0 < lower < 1 < upper:
            raise ConfigError("update.stiffness_bounds", f"factors on E must satisfy 0 < lower < 1 < upper (the nominal "
                                                         f"modulus inside), got [{lower}, {upper}]")
        lower, upper = settings.damping_bounds
        if not 0 <= lower < upper:
            raise ConfigError("update.damping_bounds", f"must satisfy 0 <= lower < upper, got [{lower}, {upper}]")
        return settings

    def check_against(self, machine, key="update"):
        """Checks against the nominal machine, before any job: design tags on its rotor, modes it retains.

        ``key`` is where the machine's ``update:`` entry lives (``machines.<name>.update``).
        """
        tags = sorted({tag for element in machine.rotor.elements for tag in element.tags})
        taken = set()
        for i, tag in enumerate(self.tags):
            group = set(machine.rotor.elements_tagged(tag))
            if not group:
                raise ConfigError(f"{key}.tags[{i}]", f"no element of machine {machine.name!r} carries the tag {tag!r}; "
                                                     f"its tags: {tags}")
            if group & taken:
                raise ConfigError(f"{key}.tags[{i}]", f"tag {tag!r} shares elements with another design tag")
            taken |= group
        flexible = machine.retained_modes - 2  # the two rigid-body modes of each plane
        if self.modes > flexible:
            raise ConfigError("update.modes", f"{self.modes} flexible modes, but the model of {machine.name!r} retains "
                                              f"{flexible} (rotor.retained_modes {machine.retained_modes})")


def measured_features(frame, channels, modes):
    """The measured resonances and anti-resonances the update matches (from the fit stage's features).

    Parameters
    ----------
    frame : pandas.DataFrame
        ``features.parquet`` of the fit stage.
    channels : list of (output, input)
    modes : int
        Use flexible modes (resonance / anti-resonance numbers) 1 .. ``modes`` of each channel.
        Roots whose damping ratio the fit determines worse than to its own value are left out.

    Returns
    -------
    pandas.DataFrame
        One row per feature: ``output, input, root (pole | zero), number,
        frequency_hz, damping_ratio, frequency_std_hz, damping_std, modal_constant``.
    """
    wanted = set(channels)
    rows = frame[(frame["estimator"] == "output_error") & frame["kind"].isin(["resonance", "anti_resonance"])]
    if "flag" in rows:  # failed fits, negative delays, overdamped "resonances" (ambid.channel_fit.fit_verdict)
        rows = rows[rows["flag"].isna() | (rows["flag"] == "")]  # an all-empty column reads as NaN
    rows = rows[np.array([(o, i) in wanted for o, i in zip(rows["output"], rows["input"])], dtype=bool)]
    rows = rows[(rows["damping_ratio"] > 0) & (rows["damping_ratio"] < LIGHT_DAMPING)]
    # a root the fit cannot place (damping uncertain by more than its value: a near-cancelling pole-zero
    # pair of a noisy channel) is no feature of the machine
    rows = rows[~(rows["damping_std"] > rows["damping_ratio"])]
    # renumber the lightly damped ones per channel and root, lowest first (the fit numbers every resonance)
    rows = rows.sort_values(["output", "input", "root", "frequency_hz"]).copy()
    rows["number"] = rows.groupby(["output", "input", "root"]).cumcount() + 1
    rows = rows[rows["number"] <= modes]
    for column in ("modal_constant", "modal_constant_std"):  # features of older fits have no constants' std
        if column not in rows:
            rows[column] = np.nan
    columns = ["output", "input", "root", "number", "frequency_hz", "damping_ratio", "frequency_std_hz", "damping_std",
               "modal_constant", "modal_constant_std"]
    if rows.empty:
        raise UpdateError(f"no lightly damped resonance or anti-resonance among the fitted channels {sorted(wanted)} "
                          "(flagged fits left out: see the fit's findings.tsv)")
    return rows[columns].reset_index(drop=True)


def reference_features(plant, channels, band_hz):
    """The features of a plant known exactly, in the fit stage's table form (thesis ch. 5.3's reference model).

    Every lightly damped pole and zero below ``band_hz`` of each channel, with
    the modal constant of the poles; for model-to-model updates and their tests.
    """
    rows = []
    for output, input_axis in channels:
        poles, residues = plant.channel_residues(output, input_axis)
        for root, values, residue in (("pole", poles, residues), ("zero", plant.zeros(output, input_axis), None)):
            for k, value in enumerate(values):
                if value.imag > 0 and damping_ratio(value) < LIGHT_DAMPING and abs(value) < 2 * np.pi * band_hz:
                    rows.append({"output": output, "input": input_axis, "estimator": "output_error", "root": root,
                                 "kind": "resonance" if root == "pole" else "anti_resonance", "number": 0,
                                 "frequency_hz": abs(value) / (2 * np.pi), "damping_ratio": float(damping_ratio(value)),
                                 "frequency_std_hz": np.nan, "damping_std": np.nan,
                                 "modal_constant": np.real(2j * value.imag * residue[k]) if residue is not None else np.nan})
    return pd.DataFrame(rows)


def update_channels(kind):
    """The radial channels of ``kind`` (`ambid.channel_fit.select_channels`) whose features the update matches.

    At standstill the x and y planes do not couple, so channels across planes have no features.
    """
    return [(o, i) for o, i in select_channels(kind) if o[1] == i[1]]


def update_problem(machine, features, settings, channels=None):
    """The `UpdateProblem` of a machine against fit-stage features, as ``settings`` configure it.

    ``channels`` defaults to ``update_channels(settings.channels)``; zeros are
    computed only for the channels with a measured anti-resonance.
    """
    channels = update_channels(settings.channels) if channels is None else channels
    measured = measured_features(features, channels, settings.modes)
    variables = design_variables(machine, settings.tags, settings.per_element, settings.damping, settings.modes,
                                 settings.stiffness_bounds, settings.damping_bounds)
    zero_channels = sorted({(o, i) for o, i, root in zip(measured["output"], measured["input"], measured["root"])
                            if root == "zero"})
    return UpdateProblem(ModalFeatureModel(machine, variables, zero_channels), measured, settings)


class UpdateProblem:
    """Residuals of thesis eq. 5.29-5.35 as functions of the design variables.

    Beyond the thesis, with ``settings.weigh_by_uncertainty`` each feature's
    weight is multiplied by its floor over its standard uncertainty
    (`_feature_sigmas`), and the mode shapes' contrasts follow the features
    (`mode_shape_residuals`).

    Parameters
    ----------
    model : ambid.modal_features.ModalFeatureModel
    measured : pandas.DataFrame
        `measured_features` rows.
    settings : UpdateSettings
    sign_penalty : float
        Matching cost of a resonance whose modal-constant sign differs from
        the measured one, in units of |log frequency ratio| (0.3: a mode 35 %
        away with the right sign is preferred).
    """

    def __init__(self, model, measured, settings, sign_penalty=0.3):
        self.model, self.measured, self.settings = model, measured.reset_index(drop=True), settings
        self.variables = model.variables
        weights = settings.weights
        is_pole = (self.measured["root"] == "pole").to_numpy()
        self.frequency_weight = np.where(is_pole, weights["resonance_frequency"], weights["anti_resonance_frequency"])
        self.damping_weight = weights["damping"] * np.where(is_pole, weights["resonance_damping"],
                                                            weights["anti_resonance_damping"])
        self.frequency = self.measured["frequency_hz"].to_numpy(float)
        self.damping = self.measured["damping_ratio"].to_numpy(float)
        self.groups = [(key, index.to_numpy()) for key, index in self.measured.groupby(["output", "input", "root"]).groups.items()]
        if settings.weigh_by_uncertainty:
            # a feature at its floor keeps its weight; one the fit places worse counts less, as in a chi2
            floor = settings.feature_std_floor
            sigma_f, sigma_d = _feature_sigmas(self)
            self.frequency_weight = self.frequency_weight * floor["frequency"] * self.frequency / sigma_f
            self.damping_weight = self.damping_weight * floor["damping"] * self.damping / sigma_d
        self.sign_penalty = sign_penalty
        self.constant_sign = np.nan_to_num(np.sign(self.measured["modal_constant"].to_numpy(float)))  # 0: unknown
        # the mode shapes (`ambid.mode_shapes`): one standard uncertainty of a contrast weighs as much as one of a
        # frequency at its floor; they take part where some plane has constants of two modes or more
        self.mode_shapes = ModeShapeContrasts(self.measured, settings.feature_std_floor["modal_constant"])
        self.mode_shape_scale = (weights["mode_shape"] * settings.feature_std_floor["frequency"]
                                 if self.mode_shapes.several_modes else 0.0)
        self.log_scaled = np.array([v.kind == "stiffness" for v in self.variables])
        self.lower = np.array([v.lower for v in self.variables])
        self.upper = np.array([v.upper for v in self.variables])
        self.start = model.start
        self.history = []  # (B(e), sum of squares) of every evaluation

    # -------------------------------------------------------- coordinates
    def to_theta(self, values):
        """Optimizer coordinates: log of the modulus factors, damping ratios as they are."""
        return np.where(self.log_scaled, np.log(np.maximum(values, 1e-300)), values)

    def to_values(self, theta):
        return np.where(self.log_scaled, np.exp(theta), theta)

    def random_start(self, rng):
        """A start drawn as in the thesis' appendix: uniform between the bounds (moduli: 0 .. 2 x nominal)."""
        return rng.uniform(np.maximum(self.lower, 0.0), self.upper).clip(self.lower, self.upper)

    # ---------------------------------------------------------- prediction
    def predict(self, values, derivatives=False):
        """Model frequency [Hz] and damping of the root matched to every measured feature.

        Returns
        -------
        frequency, damping : arrays (n_features,)
        d_frequency, d_damping : arrays (n_features, n_variables) or None
            Derivatives with respect to the design values.
        """
        return self._predict(values, derivatives)[:4]

    def _predict(self, values, derivatives=False):
        """`predict`, and the model's `StructuralFeatures` with the pole index each measured pole is matched to
        (-1 for zeros)."""
        features = self.model.evaluate(values, derivatives)
        n = len(self.measured)
        frequency, damping = np.empty(n), np.empty(n)
        match = np.full(n, -1)
        d_frequency = np.empty((n, len(self.variables))) if derivatives else None
        d_damping = np.empty_like(d_frequency) if derivatives else None
        described = {}  # root set -> (frequency, damping): a plane's poles serve all its channels
        for (output, input_axis, root), index in self.groups:
            if root == "pole":
                plane = "x" if output[1] == "X" else "y"
                roots = features.poles[plane]
                derivative = features.pole_derivatives[plane] if derivatives else None
            else:
                roots = features.zeros[(output, input_axis)]
                derivative = features.zero_derivatives[(output, input_axis)] if derivatives else None
            if roots.size < index.size:
                raise UpdateError(f"channel {output}/{input_axis}: the model has {roots.size} complex {root}s, "
                                  f"{index.size} measured")
            if id(roots) not in described:  # identical planes share their arrays
                described[id(roots)] = root_features(roots)
            f_model, z_model = described[id(roots)]
            cost = np.abs(np.log(f_model[None, :] / self.frequency[index, None])) + (z_model[None, :] >= LIGHT_DAMPING)
            if root == "pole":
                signs = np.sign(features.modal_constants[(output, input_axis)])
                cost += self.sign_penalty * ((self.constant_sign[index, None] * signs[None, :]) < 0)
            if index.size == 1:
                matched = np.argmin(cost, axis=1)
            else:
                rows, columns = scipy.optimize.linear_sum_assignment(cost)
                matched = columns[np.argsort(rows)]
            frequency[index], damping[index] = f_model[matched], z_model[matched]
            if root == "pole":
                match[index] = matched
            if derivatives:
                df, dz = root_feature_derivatives(roots[matched], derivative[matched])
                d_frequency[index], d_damping[index] = df, dz
        return frequency, damping, d_frequency, d_damping, features, match

    def mode_shape_residuals(self, values, features, match, derivatives=False):
        """The modal constants' whitened contrasts (`ambid.mode_shapes.ModeShapeContrasts`) at ``values``.

        ``features`` and ``match`` are `_predict`'s at the same values.  The derivatives are forward differences
        (one model evaluation per variable, relative step 1e-6), each perturbed pole followed to its nearest.

        Returns
        -------
        residual : array (n_constants,), empty when the contrasts take no part
        jacobian : array (n_constants, n_variables) or None
        """
        shapes = self.mode_shapes
        if self.mode_shape_scale == 0 or not len(shapes):
            return np.empty(0), (np.empty((0, len(self.variables))) if derivatives else None)
        modes = match[shapes.rows]
        planes = [o[1].lower() for o in shapes.outputs]

        def constants(evaluated, pole_index):
            return np.array([evaluated.modal_constants[(o, i)][k] for o, i, k in zip(shapes.outputs, shapes.inputs,
                                                                                     pole_index)])

        model = constants(features, modes)
        if not derivatives:
            return shapes.residuals(model, modes)
        values = np.asarray(values, dtype=float)
        jacobian = np.empty((len(shapes), len(self.variables)))
        base = np.array([features.poles[plane][k] for plane, k in zip(planes, modes)])
        for k in range(len(self.variables)):
            step = 1e-6 * max(abs(values[k]), 1e-3)
            shifted = values.copy()
            shifted[k] += step
            moved = self.model.evaluate(shifted, with_zeros=False)
            followed = [int(np.argmin(np.abs(moved.poles[plane] - pole))) for plane, pole in zip(planes, base)]
            jacobian[:, k] = (constants(moved, followed) - model) / step
        return shapes.residuals(model, modes, jacobian)

    def residuals(self, values, derivatives=False):
        """Weighted relative errors (eq. 5.29-5.32 with the weights of eq. 5.33-5.35), signed; and d r / d values.

        Followed, where they take part, by the modal constants' contrasts (`mode_shape_residuals`) times
        ``weights["mode_shape"]`` and the frequency floor: beyond the thesis, the mode shapes at the bearings.
        """
        frequency, damping, d_frequency, d_damping, features, match = self._predict(values, derivatives)
        shape, d_shape = self.mode_shape_residuals(values, features, match, derivatives)
        residual = np.concatenate([self.frequency_weight * (frequency - self.frequency) / self.frequency,
                                   self.damping_weight * (damping - self.damping) / self.damping,
                                   self.mode_shape_scale * shape])
        self.history.append((float(np.sum(np.abs(residual))), float(residual @ residual)))
        if not derivatives:
            return residual, None
        jacobian = np.vstack([(self.frequency_weight / self.frequency)[:, None] * d_frequency,
                              (self.damping_weight / self.damping)[:, None] * d_damping,
                              self.mode_shape_scale * d_shape])
        return residual, jacobian

    def objective(self, values):
        """``B(e)`` of thesis eq. 5.35-5.36: the weighted sum of absolute relative errors."""
        return float(np.sum(np.abs(self.residuals(values)[0])))

    def prior(self, values, derivatives=False):
        """Regularization residuals ``lambda log(e_p / e_p,start)`` of the modulus factors, and their Jacobian.

        Appended to the least-squares residuals (not to ``B(e)``), they pick,
        among designs that fit the features equally well, the one closest to
        the machine as configured: a variable the data do not determine stays
        where the engineer put it instead of drifting to a bound.  ``lambda``
        (``settings.regularization``) is small against the frequency residuals
        of determined variables, so it does not bias them.
        """
        weight = self.settings.regularization * self.log_scaled
        residual = weight * (self.to_theta(values) - self.to_theta(self.start))
        if not derivatives:
            return residual, None
        return residual, np.diag(weight / np.where(self.log_scaled, values, 1.0))


@dataclass
class UpdateResult:
    """Outcome of `update_model`.

    Attributes
    ----------
    values : array
        Updated design values (modulus factors relative to the machine as configured; added damping ratios).
    objective : float
        ``B(e)`` at ``values``.
    history : pandas.DataFrame
        ``start, evaluation, objective_b, sum_of_squares`` of every evaluation (thesis Fig. 6.9).
    starts : pandas.DataFrame
        Per start: initial and final ``B(e)``, evaluations, and whether it was chosen.
    evaluations : int
    bias_spread : array, optional
        `debiased_update`: each value's relative move in its last pass (what the
        estimator's bias leaves uncertain where the passes do not settle).
    """

    values: np.ndarray
    objective: float
    history: pd.DataFrame
    starts: pd.DataFrame
    evaluations: int
    bias_spread: np.ndarray | None = None


def least_squares_update(problem, start, max_evaluations=300, fixed=()):
    """Bounded least squares on the residuals with analytic Jacobian, from ``start``.

    ``fixed``: indices of variables held at their ``start`` value (`identifiability`'s valley probes).
    Returns the design values found and the number of residual evaluations.
    """
    cache = {}

    def evaluate(theta, derivatives):
        key = (theta.tobytes(), derivatives)
        if key not in cache:
            cache.clear()
            values = problem.to_values(theta)
            residual, jacobian = problem.residuals(values, derivatives)
            prior, prior_jacobian = problem.prior(values, derivatives)
            residual = np.concatenate([residual, prior])
            if derivatives:  # chain rule to the log coordinates
                jacobian = np.vstack([jacobian, prior_jacobian]) * np.where(problem.log_scaled, values, 1.0)[None, :]
            cache[key] = (residual, jacobian)
        return cache[key]

    lower, upper = problem.to_theta(problem.lower), problem.to_theta(problem.upper)
    theta0 = np.clip(problem.to_theta(np.asarray(start, dtype=float)), lower, upper)
    # start strictly inside the bounds (a damping ratio of 0 sits on its bound; trf crawls away from there)
    margin = 1e-3 * (upper - lower)
    theta0 = np.where(problem.log_scaled, theta0, np.clip(theta0, lower + margin, upper - margin))
    fixed = np.asarray(fixed, dtype=int)
    if fixed.size:  # held by bounds a rounding error wide (least_squares wants lower < upper)
        pad = 1e-12 * np.maximum(1.0, np.abs(theta0[fixed]))
        lower, upper = lower.copy(), upper.copy()
        lower[fixed], upper[fixed] = theta0[fixed] - pad, theta0[fixed] + pad
    before = len(problem.history)
    # ftol 1e-4: once an iteration improves the cost by less than 0.01 %, what is left is the regularization
    # sliding undetermined variables along the valley; consistent data still converge quadratically to ~0
    solution = scipy.optimize.least_squares(
        lambda t: evaluate(t, False)[0], theta0, jac=lambda t: evaluate(t, True)[1], bounds=(lower, upper),
        method="trf", x_scale="jac", ftol=1e-4, xtol=1e-10, gtol=1e-10, max_nfev=max_evaluations)
    return problem.to_values(solution.x), len(problem.history) - before


def nelder_mead_update(problem, start, max_evaluations=2500, max_iterations=1000, tolerance=1e-10):
    """The thesis' optimizer (appendix 1: fminsearch, MaxIter 1000, MaxFunEvals 2500) on ``B(e)``, bounded."""
    before = len(problem.history)
    bounds = list(zip(problem.lower, problem.upper))
    solution = scipy.optimize.minimize(
        problem.objective, np.clip(start, problem.lower, problem.upper), method="Nelder-Mead", bounds=bounds,
        options=dict(maxiter=max_iterations, maxfev=max_evaluations, xatol=tolerance, fatol=tolerance,
                     adaptive=len(bounds) > 4))
    return solution.x, len(problem.history) - before


def _frequencies_then_shapes(optimizer, problem, start, max_evaluations):
    """``optimizer`` on the features without the mode shapes' contrasts, then with them from where it ended.

    The contrasts' log is steep where a model constant passes through zero (a node of the shape crossing a
    bearing) between a start and the solution; from the frequencies' solution the shapes only choose along what
    the frequencies leave free.  Returns the values and both stages' evaluations.
    """
    scale = problem.mode_shape_scale
    if scale == 0:
        return optimizer(problem, start, max_evaluations)
    problem.mode_shape_scale = 0.0
    try:
        first, before = optimizer(problem, start, max_evaluations)
    finally:
        problem.mode_shape_scale = scale
    values, after = optimizer(problem, first, max_evaluations)
    return values, before + after


def update_model(problem, settings, start=None):
    """Run the configured optimizer from the configured start and ``settings.starts - 1`` random starts.

    The start with the lowest ``sum r^2`` (least squares) or ``B(e)`` (Nelder-Mead)
    wins; starts that end within 1e-9 of it are ties, broken in favour of the
    smallest change from the machine as configured (undetermined variables
    then stay where the engineer put them).  ``start`` replaces the configured
    start (the design values, e.g. an earlier update's).
    """
    rng = np.random.default_rng(settings.seed)
    first = problem.start if start is None else np.asarray(start, dtype=float)
    starts = [first] + [problem.random_start(rng) for _ in range(settings.starts - 1)]
    optimizer = least_squares_update if settings.optimizer == "least_squares" else nelder_mead_update
    history, summary, outcomes = [], [], []
    for k, start in enumerate(starts):
        first = len(problem.history)
        values, evaluations = _frequencies_then_shapes(optimizer, problem, start, settings.max_evaluations)
        trace = np.array(problem.history[first:]).reshape(-1, 2)
        residual, _ = problem.residuals(values)
        problem.history.pop()
        prior = problem.prior(values)[0]
        final = (float(residual @ residual + prior @ prior) if settings.optimizer == "least_squares"
                 else float(np.sum(np.abs(residual))))
        change = float(np.linalg.norm(problem.to_theta(values) - problem.to_theta(problem.start)))
        outcomes.append((final, change, values))
        history.append(pd.DataFrame({"start": k, "evaluation": np.arange(1, len(trace) + 1), "objective_b": trace[:, 0],
                                     "sum_of_squares": trace[:, 1]}))
        summary.append({"start": k, "kind": "configured" if k == 0 else "random", "initial_b": trace[0, 0],
                        "final_b": float(np.sum(np.abs(residual))), "evaluations": evaluations})
    best = min(o[0] for o in outcomes)
    ties = [k for k, o in enumerate(outcomes) if o[0] <= best + 1e-9 * max(best, 1e-12) + 1e-18]
    chosen = min(ties, key=lambda k: outcomes[k][1])
    summary = pd.DataFrame(summary)
    summary["chosen"] = summary["start"] == chosen
    values = outcomes[chosen][2]
    return UpdateResult(values=values, objective=float(summary.loc[chosen, "final_b"]), history=pd.concat(history),
                        starts=summary, evaluations=int(summary["evaluations"].sum()))


# the estimator's root stands for the model's if each is the other's nearest and they lie this close
# (relative frequency)
BIAS_MATCH = 0.02


def estimator_bias(estimator_plant, plant, grids, measured, fit_settings):
    """What the fit stage's estimator gets wrong about each measured feature, found on ``plant``'s own FRF.

    The output-error fit (`ambid.channel_fit.fit_plant_channel`, set up from ``estimator_plant``
    as the fit stage sets it up from the nominal model) approximates the modes above the band
    by one residual factor.  Where a channel's response is small, as at the anti-resonance
    of a cross channel, that approximation moves the root by more than the noise: fitted
    on hs_eden_like's exact model FRF with the measured noise weights, DX/NX's anti-resonance
    comes out 0.14 % high, three of its standard deviations, and the drive-end stack's
    modulus updated from it 18 % low.  The same estimator applied to the noise-free FRF
    of ``plant`` (the updated model), on the measured grid with the measured weights,
    gives its error there: fitted minus exact root.

    Parameters
    ----------
    estimator_plant : ambid.plant.Plant
        The model the fit stage set the estimator up from (known factor, starting values).
    plant : ambid.plant.Plant
        The model whose exact roots are the reference (the updated one).
    grids : dict
        ``(output, input) -> (frequency_hz, std)`` of each measured channel.
    measured : pandas.DataFrame
        `measured_features` rows.
    fit_settings : mapping
        The config's ``fit:`` section.

    Returns
    -------
    pandas.DataFrame
        Per measured row: ``frequency_bias_hz`` and ``damping_bias`` (NaN where the
        estimator's nearest root and the model's are not each other's nearest of
        their kind within `BIAS_MATCH`, or the channel cannot be fitted).
    """
    out = pd.DataFrame({"frequency_bias_hz": np.nan, "damping_bias": np.nan}, index=measured.index)
    for (output, input_axis), rows in measured.groupby(["output", "input"]):
        if (output, input_axis) not in grids:
            continue
        frequency, std = grids[(output, input_axis)]
        response = model_channels(plant, frequency, [(output, input_axis)])[(output, input_axis)]
        try:
            fitted = fit_plant_channel(estimator_plant, frequency, response, std, output, input_axis, fit_settings)
        except FitError:
            continue
        exact = reference_features(plant, [(output, input_axis)], np.inf)
        found = pd.DataFrame(feature_rows(fitted, output, input_axis, "output_error"))
        for index, row in rows.iterrows():
            kind = "resonance" if row["root"] == "pole" else "anti_resonance"
            truth = exact[exact["kind"] == kind]
            estimate = found[found["kind"] == kind] if not found.empty else found
            if truth.empty or estimate.empty:
                continue
            reference = _nearest_root(truth, row["frequency_hz"])
            nearest = _nearest_root(estimate, reference["frequency_hz"])
            back = _nearest_root(truth, nearest["frequency_hz"])
            if (back["frequency_hz"] == reference["frequency_hz"]
                    and abs(nearest["frequency_hz"] / reference["frequency_hz"] - 1) <= BIAS_MATCH):
                out.loc[index] = (nearest["frequency_hz"] - reference["frequency_hz"],
                                  nearest["damping_ratio"] - reference["damping_ratio"])
    return out


def _nearest_root(roots, frequency_hz):
    """The row of ``roots`` (feature rows) whose frequency is nearest ``frequency_hz``."""
    return roots.iloc[int(np.argmin(np.abs(roots["frequency_hz"].to_numpy() - frequency_hz)))]


def bias_at_values(machine_config, problem, frf_table, fit_settings, name="machine"):
    """`estimator_bias` as a function of ``problem``'s design values, for `debiased_update`.

    The estimator is set up from ``machine_config`` (the machine the update starts
    from, as the fit stage set it up from it); the reference is that machine with
    the values' moduli and damping (`updated_machine_config`), on the grids and
    weights of the measured channels of ``frf_table`` (the MIMO estimate where it
    has one).
    """
    estimator_plant = Plant(machine_from_config(machine_config, name=name))
    kind = radial_estimator(frf_table)
    grids = {}
    for output, input_axis in sorted(set(zip(problem.measured["output"], problem.measured["input"]))):
        frequency, _, std = channel(frf_table, kind, output, input_axis)
        grids[(output, input_axis)] = (frequency, std)

    def bias(values):
        updated = machine_from_config(updated_machine_config(machine_config, problem.variables, values), name=name)
        return estimator_bias(estimator_plant, Plant(updated), grids, problem.measured, fit_settings)

    return bias


def without_bias(measured, bias):
    """The measured features less the estimator's ``bias`` (`estimator_bias`; NaN: none), with the bias as columns."""
    corrected = measured.copy()
    corrected["frequency_bias_hz"] = bias["frequency_bias_hz"].fillna(0.0).to_numpy()
    damping_bias = bias["damping_bias"].fillna(0.0).to_numpy()
    # a damping ratio the correction would take to zero or below keeps its value (eq. 5.31 divides by it)
    corrected["damping_bias"] = np.where(measured["damping_ratio"].to_numpy() - damping_bias > 0, damping_bias, 0.0)
    corrected["frequency_hz"] = measured["frequency_hz"] - corrected["frequency_bias_hz"]
    corrected["damping_ratio"] = measured["damping_ratio"] - corrected["damping_bias"]
    return corrected


def debiased_update(problem, result, settings, bias_at, passes=4, tolerance=1e-3):
    """The update again against the features less the estimator's bias at its result (`estimator_bias`), repeated.

    ``bias_at(values)`` gives the bias at the design values.  The bias depends on
    where the model's roots lie, so each pass takes it at the last pass' values and
    refits from there, once (hs_eden_like from exact features with constant weights:
    drive-end stack 0.364, then 0.607, 0.543, 0.552; the truth's 0.55); the passes
    stop when no value moves by more than ``tolerance`` (relative), or after
    ``passes``.  They need not settle: the estimator chooses its model's structure
    from a stabilization diagram, so its bias can jump between two parameter sets
    (hs_eden_like's ms01 with the bearings at the nominal operating point: the stacks
    alternated by 0.5 %).  Each value's move in the
    last pass is returned as ``bias_spread``, an uncertainty of the correction.

    Returns
    -------
    UpdateProblem
        With the last pass' corrected features.
    UpdateResult
        History and starts table hold the first update's starts and then each
        pass, kind ``estimator bias`` (the last one chosen).
    """
    history, starts = [result.history], [result.starts.assign(chosen=False)]
    evaluations, count, corrected, current = result.evaluations, int(result.starts["start"].max()) + 1, problem, result
    spread = np.zeros(len(result.values))
    for _ in range(passes):
        measured = without_bias(problem.measured, bias_at(current.values))
        corrected = UpdateProblem(problem.model, measured, problem.settings)
        refit = update_model(corrected, replace(settings, starts=1), start=current.values)
        history.append(refit.history.assign(start=count))
        starts.append(refit.starts.assign(start=count, kind="estimator bias", chosen=False))
        evaluations, count = evaluations + refit.evaluations, count + 1
        spread = np.abs(refit.values - current.values) / np.maximum(np.abs(current.values), 1e-3)
        current = refit
        if spread.max() < tolerance:
            break
    starts = pd.concat(starts, ignore_index=True)
    starts.loc[starts.index[-1], "chosen"] = True
    return corrected, UpdateResult(values=current.values, objective=current.objective,
                                   history=pd.concat(history, ignore_index=True), starts=starts,
                                   evaluations=evaluations, bias_spread=spread)


def _feature_sigmas(problem):
    """Standard uncertainty of each feature's frequency and damping: the fit's, floored at
    ``settings.feature_std_floor`` of its value (the fit's statistical uncertainty does not cover systematic errors)."""
    floor = problem.settings.feature_std_floor
    sigma_f = np.fmax(problem.measured["frequency_std_hz"].to_numpy(float), floor["frequency"] * problem.frequency)
    sigma_d = np.fmax(problem.measured["damping_std"].to_numpy(float), floor["damping"] * problem.damping)
    return sigma_f, sigma_d


def _feature_chi2(problem, values):
    """Sum of the squared feature errors in units of `_feature_sigmas`."""
    frequency, damping, _, _, features, match = problem._predict(values)
    shape, _ = problem.mode_shape_residuals(values, features, match)
    sigma_f, sigma_d = _feature_sigmas(problem)
    return float(np.sum(((frequency - problem.frequency) / sigma_f) ** 2) + np.sum(((damping - problem.damping) / sigma_d) ** 2)
                 + shape @ shape)


def identifiability(problem, values, valley=True, added_std=None):
    """Which design variables the measured features determine, and how well.

    The Jacobian of the features, each divided by its standard uncertainty
    (`_feature_sigmas`), and of the modal constants' whitened contrasts where
    they take part (`UpdateProblem.mode_shape_residuals`), with respect to the
    relative change of each variable, is decomposed by SVD.  Directions with a standard uncertainty below
    ``settings.determined_std`` are determined.  Where the features are not
    matched within their uncertainties (chi2 per degree of freedom above 1:
    the model lacks something the machine has), every uncertainty is first
    scaled by the root of it.  That covers a misfit spread like noise, not a
    wrong model: the report says so (an independent writer's demo20 to 3 kHz
    with the shear modulus of the design elements kept where ambid scales it
    with E: chi2 279 for 55 degrees of freedom, two moduli "determined" 40 %
    and 13 % from that writer's values).

    That is a statement about the neighbourhood of ``values``.  Where the
    features fix fewer combinations than there are moduli, the moduli the
    data leave free sit anywhere along a curved valley, and a modulus that is
    determined *given* them can move far when they move (demo20's thesis
    case: element 6 "determined" at 0.16 of its modulus with a 5 % standard
    uncertainty; the rig's truth is 0.40, on the same valley).  So, with
    ``valley``, each undetermined modulus is set a factor
    ``exp(settings.valley_step)`` above and below its value in turn (half and
    a quarter of that step where the data tell the point apart) and the
    others are refitted (`least_squares_update` with it held); where the fit
    stays as good (feature chi2 within 4 times the overdispersion), the
    largest move of each determined modulus is its ``valley_shift`` (the
    probes stop once every one has moved beyond ``determined_std``: then a
    lower bound).
    A modulus that moves by more than ``settings.determined_std`` is not
    determined.  ``added_std`` (relative, per variable) is added in quadrature:
    what the data's uncertainty does not hold (`debiased_update`'s ``bias_spread``).

    Returns
    -------
    rows : list of dict
        Per variable: ``std`` (relative standard uncertainty within the
        determined directions, with the valley shift added in quadrature, a
        two-sigma move: conservative; inf where not locally determined),
        ``resolution`` (diagonal of the resolution
        matrix: 1 = fixed by the data, 0 = not seen at all), ``valley_shift``
        (relative move, see above; NaN where not probed) and
        ``valley_variable`` (the modulus whose move caused it),
        ``determined`` (resolution >= 0.9 and valley shift at most
        ``settings.determined_std``), ``at_bound``.
    correlation : array (n, n)
        Correlation of the variables' estimates within the determined directions.
    summary : dict
        ``rank`` (determined directions), ``singular_values``, ``valley_probes``
        (refits the valley check ran), ``chi2`` and ``dof`` of the features at
        ``values`` (frequencies, damping ratios, the mode shapes' contrasts; less
        the variables) and ``std_scale``, ``sqrt(max(1, chi2 / dof))``, by which
        every standard uncertainty is scaled.
    """
    settings = problem.settings
    _, _, d_frequency, d_damping, features, match = problem._predict(values, derivatives=True)
    shape, d_shape = problem.mode_shape_residuals(values, features, match, derivatives=True)
    sigma_f, sigma_d = _feature_sigmas(problem)
    # how well the features are matched: a model that cannot match them within their uncertainties (chi2 per degree
    # of freedom above 1) has every uncertainty scaled by the root of it (the Birge ratio)
    chi2 = _feature_chi2(problem, values)
    contrasts = problem.mode_shapes.contrasts(match[problem.mode_shapes.rows]) if shape.size else 0
    dof = max(1, 2 * len(problem.measured) + contrasts - len(values))
    std_scale = float(np.sqrt(max(1.0, chi2 / dof)))
    scale = np.maximum(np.abs(values), np.where(problem.log_scaled, 0.0, 1e-3))  # relative change of each variable
    jacobian = np.vstack([d_frequency / sigma_f[:, None], d_damping / sigma_d[:, None], d_shape]) * scale[None, :] / std_scale
    _, singular, vt = np.linalg.svd(jacobian, full_matrices=False)
    determined = singular > 1.0 / settings.determined_std
    basis = vt[determined].T
    resolution = np.sum(basis**2, axis=1)
    covariance = (basis / singular[determined] ** 2) @ basis.T
    std = np.sqrt(np.diag(covariance))
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = covariance / np.outer(std, std)
    at_bound = (values <= problem.lower * (1 + 1e-6)) | (values >= problem.upper * (1 - 1e-6))
    locally = resolution >= 0.9
    shift, moved_by, probes = np.full(len(values), np.nan), [""] * len(values), 0
    if valley:
        shift, moved_by, probes = _valley_shifts(problem, values, locally, jacobian.shape[0], basis @ basis.T)
    # the valley's move (a two-sigma one: conservative) added to the data's standard deviation
    total = np.hypot(std, np.nan_to_num(shift))
    added = np.zeros(len(values)) if added_std is None else np.nan_to_num(np.asarray(added_std, dtype=float))
    total = np.hypot(total, added)
    rows = [{"std": float(s) if ok else np.inf, "resolution": float(r), "valley_shift": float(v), "valley_variable": by,
             "determined": bool(ok and not v > settings.determined_std and not a > settings.determined_std),
             "at_bound": bool(b)}
            for s, r, v, by, a, ok, b in zip(total, resolution, shift, moved_by, added, locally, at_bound)]
    return rows, correlation, {"rank": int(determined.sum()), "singular_values": singular, "valley_probes": probes,
                               "chi2": chi2, "dof": dof, "std_scale": std_scale}


def _valley_shifts(problem, values, locally, residuals, resolution):
    """`identifiability`'s valley check: (largest relative move of each locally determined modulus, the modulus whose
    move caused it, refits run).  ``resolution``: the resolution matrix; the undetermined moduli that leak most into
    the determined ones are probed first."""
    settings = problem.settings
    stiffness = problem.log_scaled
    rank = int(round(np.trace(resolution)))
    probed, free = np.flatnonzero(locally & stiffness), np.flatnonzero(~locally & stiffness)
    free = free[np.argsort(-np.max(np.abs(resolution[np.ix_(probed, free)]), axis=0, initial=0.0))] if probed.size else free
    shift = np.where(locally & stiffness, 0.0, np.nan)
    moved_by = [""] * len(values)
    if not probed.size or not free.size:
        return shift, moved_by, 0
    base = _feature_chi2(problem, values)
    overdispersion = max(1.0, base / max(1, residuals - rank))
    theta = problem.to_theta(values)
    lower, upper = problem.to_theta(problem.lower), problem.to_theta(problem.upper)
    probes = 0
    history = len(problem.history)
    for j in free:
        for sign in (1.0, -1.0):
            # a factor e first; where the data tell that point apart, half and a quarter of it (a modulus of
            # resolution 0.8 is undetermined, but the data do not let it move a factor e)
            for step in sign * settings.valley_step * np.array([1.0, 0.5, 0.25]):
                moved = theta.copy()
                moved[j] = np.clip(theta[j] + step, lower[j], upper[j])
                if abs(moved[j] - theta[j]) < 0.5 * abs(step):  # a bound in the way: a shorter step
                    continue
                found, _ = least_squares_update(problem, problem.to_values(moved), settings.max_evaluations, fixed=[j])
                probes += 1
                # as good: on the valley, inside the data's two-sigma region (conservative: a determined modulus must
                # stay within determined_std across it; one sigma let hs ms01's motor[0] and motor[4], 0.68 and 0.52
                # against a truth of 1.0, stay determined)
                if _feature_chi2(problem, found) <= base + 4 * overdispersion:
                    change = np.abs(problem.to_theta(found) - theta)
                    for k in probed[change[probed] > shift[probed]]:
                        shift[k], moved_by[k] = change[k], problem.variables[j].name
                    break
        if np.all(shift[probed] > settings.determined_std):  # none is determined: more probes only raise the shifts
            break
    del problem.history[history:]  # the probes are not part of the update's history
    return shift, moved_by, probes


def mode_shape_rows(problem, values):
    """The modal constants the update compared (`UpdateProblem.mode_shape_residuals`) at ``values``.

    Returns
    -------
    rows : list of dict
        Per constant: ``output, input, number, frequency_hz``, the measured ``modal_constant`` and its relative
        ``sigma``, the matched model mode's ``model_constant`` and the whitened ``contrast`` (empty when the
        contrasts take no part: one mode, or ``weights.mode_shape`` 0).
    summary : dict
        ``constants``, ``contrasts`` (constants less the offsets fitted out: the chi-square's degrees of freedom
        before the design variables), ``chi2``.
    """
    shapes = problem.mode_shapes
    if problem.mode_shape_scale == 0 or not len(shapes):
        return [], {"constants": 0, "contrasts": 0, "chi2": 0.0}
    _, _, _, _, features, match = problem._predict(values)
    residual, _ = problem.mode_shape_residuals(values, features, match)
    modes = match[shapes.rows]
    measured = problem.measured.iloc[shapes.rows]
    rows = [{"output": o, "input": i, "number": int(n), "frequency_hz": float(f), "modal_constant": float(c),
             "sigma": float(sigma), "model_constant": float(features.modal_constants[(o, i)][k]), "contrast": float(r)}
            for o, i, n, f, c, sigma, k, r in zip(shapes.outputs, shapes.inputs, measured["number"], measured["frequency_hz"],
                                                  measured["modal_constant"], shapes.sigma, modes, residual)]
    return rows, {"constants": len(rows), "contrasts": shapes.contrasts(modes), "chi2": float(residual @ residual)}


def comparison_rows(problem, original, updated):
    """Feature table in the style of thesis Tables 5.2/5.3 and 6.4/6.5: measured, original, updated, errors.

    Errors are eq. 5.29-5.32 (relative to the measured value) in percent.  ``measured`` is what the
    update matched: the fit stage's value less ``estimator_bias`` (`debiased_update`; 0 without it).
    """
    f0, z0, _, _ = problem.predict(original)
    f1, z1, _, _ = problem.predict(updated)
    rows = []
    for i, row in problem.measured.iterrows():
        kind = "resonance" if row["root"] == "pole" else "anti-resonance"
        channel = f"{row['output']}/{row['input']}"  # the one channel name of the report; the thesis' in its own column
        thesis = f"{row['input']}({THESIS_INDEX[row['input']]},{THESIS_INDEX[row['output']]})"
        ordinal = ORDINALS.get(int(row["number"]), f"#{int(row['number'])}")
        for quantity, unit, measured, std, bias, before, after in (
                ("frequency", "Hz", row["frequency_hz"], row["frequency_std_hz"], row.get("frequency_bias_hz", 0.0),
                 f0[i], f1[i]),
                ("damping ratio", "-", row["damping_ratio"], row["damping_std"], row.get("damping_bias", 0.0),
                 z0[i], z1[i])):
            rows.append({"feature": f"{channel} {ordinal} {kind} {quantity}", "thesis_channel": thesis, "output": row["output"],
                         "input": row["input"], "root": row["root"], "number": int(row["number"]), "quantity": quantity,
                         "unit": unit, "measured": measured, "measured_std": std, "estimator_bias": bias,
                         "original": before,
                         "original_error_pct": 100 * abs(before - measured) / measured, "updated": after,
                         "absolute_error": abs(after - measured), "error_pct": 100 * abs(after - measured) / measured})
    return rows


def updated_machine_config(machine_config, variables, values, note=""):
    """The machine config with the updated moduli and damping as ``effects:`` entries.

    Stiffness variables become ``element_stiffness`` entries per tag (one
    factor per element when updated per element), multiplied into an entry
    the machine already had for that tag; damping variables become one
    ``modal_damping`` entry (a value per retained flexible mode when per mode).
    """
    config = {key: value for key, value in machine_config.items() if key != "effects"}
    effects = [dict(e) for e in machine_config.get("effects") or []]
    by_tag = {}
    for variable, value in zip(variables, values):
        if variable.kind == "stiffness":
            by_tag.setdefault(variable.tag, []).append((variable, float(value)))
    for tag, entries in by_tag.items():
        factors = np.array([value for _, value in entries])
        existing = next((e for e in effects if e["name"] == "element_stiffness" and e["parameters"]["tag"] == tag), None)
        if existing is not None:
            factors = factors * np.asarray(existing["parameters"]["scale"], dtype=float)
            effects.remove(existing)
        scale = [float(f"{v:.6g}") for v in np.atleast_1d(factors)] if len(entries) > 1 else float(f"{factors[0]:.6g}")
        effects.append({"name": "element_stiffness", "parameters": {"tag": tag, "scale": scale}})
    damping = [(variable, float(value)) for variable, value in zip(variables, values) if variable.kind == "damping"]
    if damping:
        effects = [e for e in effects if e["name"] != "modal_damping"]
        if len(damping) == 1 and not damping[0][0].modes:
            ratio = float(f"{damping[0][1]:.6g}")
        else:
            n_flexible = int(machine_config.get("rotor", {}).get("retained_modes", 12)) - 2
            ratio = [float(f"{damping[-1][1]:.6g}")] * n_flexible
            for variable, value in damping[:-1]:
                ratio[variable.modes[0] - 1] = float(f"{value:.6g}")
        effects.append({"name": "modal_damping", "parameters": {"damping_ratio": ratio}})
    config["effects"] = effects
    if note:
        config["description"] = f"{machine_config.get('description', '').strip()} {note}".strip()
    return config
