"""Which physical effect does the model lack?  Fit each candidate on top of the model, rank by evidence.

The measurement is every logged channel (`ambid.compare.measured_channels`):
radial plant matrix, axial plant and coil currents, each with its uncertainty
``sigma`` (noise plus a relative floor).  For a model with response ``G(f)``
the misfit is ``chi2 = sum |G - G_meas|^2 / sigma^2`` over the ``N`` complex
points (``E chi2 = N`` at the noise floor; the *excess* is ``chi2 / N - 1``).

For each candidate of the effect library (`candidate_space`), its few
parameters are fitted on top of the current model: a scan of the leading
parameter over its physical range, then bounded least squares on all of them.
Candidates are ranked by the Bayesian information criterion of the complex
Gaussian likelihood, ``BIC = 2 chi2 / c + k ln(2N)``: ``k`` fitted parameters,
``2N`` real data, and ``c >= 1`` the overdispersion (``chi2 / (N - k)`` of the
best candidate), so that a floor set too low does not make every
candidate "significant".  The *evidence* of a candidate is its BIC drop
against the model as it is; it is significant above `INDISTINGUISHABLE_BIC`,
and two
candidates whose evidence differs by less than `INDISTINGUISHABLE_BIC`
(Kass & Raftery's "very strong" threshold) are reported as indistinguishable
in the measured band: both are named.
"""

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import scipy.optimize
import yaml

from .compare import channel_errors, model_response, summarize
from .effects import EFFECTS, split_effects
from .errors import AmbidError, ConfigError, ModelError
from .machine import RADIAL_AXES
from .plant import Plant

__all__ = ["DiagnoseError", "FreeParameter", "Candidate", "candidate_space", "FittedCandidate", "Diagnosis", "diagnose",
           "misfit", "plant_with_effect", "where_it_helps", "diagnosis_report", "fingerprint", "effects_config_lines", "INDISTINGUISHABLE_BIC"]

#: BIC difference below which two candidates explain the data equally well (Kass & Raftery 1995: > 10 is very strong).
INDISTINGUISHABLE_BIC = 10.0


class DiagnoseError(AmbidError):
    """A diagnosis that cannot be made (no channel, a model that cannot be evaluated)."""


@dataclass(frozen=True)
class FreeParameter:
    """A fitted parameter of a candidate: search range, scale of the search, and the value the scan starts from."""

    name: str
    lower: float
    upper: float
    log: bool = True
    start: float | None = None  # None: the scan's best

    def to_search(self, value):
        return np.log(value) if self.log else value

    def from_search(self, value):
        return float(np.exp(value)) if self.log else float(value)


@dataclass(frozen=True)
class Candidate:
    """One effect of the library with its fixed and fitted parameters."""

    label: str
    effect: str
    free: tuple
    fixed: dict = field(default_factory=dict)
    scan_points: int = 12

    def build(self, values):
        return EFFECTS[self.effect](**self.fixed, **{p.name: v for p, v in zip(self.free, values)})


def candidate_space(machine):
    """The candidates the diagnosis tries on a machine, one per effect (and per element tag, per coupling side).

    Search ranges cover the physical ranges of AMB machines generously:
    amplifier and sensor bandwidths 50 Hz - 100 kHz, eddy-current corners
    50 Hz - 1 MHz, delays 0.1 us - 1 ms, couplings +-20 %, stiffness factors
    0.05 - 5, added damping ratios up to 0.1, speeds 100 - 200 000 rpm,
    sensor shifts up to 60 mm (kept on the rotor) and housing modes 20 Hz -
    5 kHz of 0.05 - 50 rotor masses.
    """
    rotor = machine.rotor
    mass = rotor.mass_kg
    candidates = [
        Candidate("amplifier_lowpass", "amplifier_lowpass", (FreeParameter("cutoff_hz", 50.0, 1e5),)),
        Candidate("eddy_current", "eddy_current", (FreeParameter("corner_hz", 50.0, 1e6),)),
        Candidate("sensor_lowpass", "sensor_lowpass", (FreeParameter("cutoff_hz", 50.0, 1e5),), {"order": 1.0}),
        Candidate("delay", "delay", (FreeParameter("delay_s", 1e-7, 1e-3),)),
        Candidate("cross_coupling[input]", "cross_coupling", (FreeParameter("coefficient", -0.2, 0.2, log=False, start=0.0),),
                  {"side": "input"}),
        Candidate("cross_coupling[output]", "cross_coupling", (FreeParameter("coefficient", -0.2, 0.2, log=False, start=0.0),),
                  {"side": "output"}),
    ]
    tags = sorted({tag for element in rotor.elements for tag in element.tags})
    candidates += [Candidate(f"element_stiffness[{tag}]", "element_stiffness", (FreeParameter("scale", 0.05, 5.0, start=1.0),),
                             {"tag": tag}) for tag in tags]
    candidates += [
        Candidate("modal_damping", "modal_damping", (FreeParameter("damping_ratio", 0.0, 0.1, log=False),)),
        # the misfit's minimum in speed is a few per cent wide: a fine log scan finds it
        Candidate("gyroscopic", "gyroscopic", (FreeParameter("speed_rpm", 100.0, 2e5),), scan_points=240),
    ]
    shifts = []
    for bearing, key in (("DE", "de_offset_m"), ("NDE", "nde_offset_m")):
        z = machine.bearing(bearing).sensor_position_m
        shifts.append(FreeParameter(key, max(-0.06, -z), min(0.06, rotor.length_m - z), log=False, start=0.0))
    candidates.append(Candidate("noncollocation", "noncollocation", tuple(shifts), scan_points=9))
    candidates.append(Candidate("foundation_mode", "foundation_mode",
                                (FreeParameter("frequency_hz", 20.0, 5000.0), FreeParameter("mass_kg", 0.05 * mass, 50 * mass, start=mass),
                                 FreeParameter("damping_ratio", 1e-3, 0.3, start=0.02)), scan_points=24))
    return candidates


def misfit(measured, predicted):
    """``chi2 = sum |G - G_meas|^2 / sigma^2`` over all points of all channels, and the complex residual vector."""
    for (output, input_axis), (_, _, std) in measured.items():
        if not np.all(np.isfinite(std)) or np.any(std <= 0):
            raise DiagnoseError(f"channel {output}/{input_axis}: the measurement has no positive, finite uncertainty")
    parts = [(predicted[key] - values) / std for key, (_, values, std) in measured.items()]
    residual = np.concatenate(parts)
    if not np.all(np.isfinite(residual)):
        raise DiagnoseError("the model's response is not finite on the measured frequencies")
    return float(np.vdot(residual, residual).real), residual


def plant_with_effect(plant, effect):
    """The plant with one more effect: signal effects and speed reuse the modal model, structure effects rebuild it."""
    if effect is None:
        return plant
    if effect.name == "gyroscopic":
        return plant.at_speed(effect.speed_rpm * np.pi / 30)
    structure, _, _ = split_effects([effect])
    if structure:
        return Plant(plant.machine.with_effects(plant.machine.effects + (effect,)))
    return plant.with_signal_effects([effect])


class _Evaluator:
    """Misfit of the model with one candidate effect added; counts the evaluations."""

    def __init__(self, machine, measured):
        self.machine = machine
        self.measured = measured
        self.plant = Plant(machine)
        self.evaluations = 0

    def residual(self, effect):
        self.evaluations += 1
        return misfit(self.measured, model_response(plant_with_effect(self.plant, effect), self.measured))


@dataclass
class FittedCandidate:
    """A candidate with its fitted parameters and what it does to the misfit."""

    candidate: Candidate
    values: tuple
    std: tuple
    chi2: float
    evidence: float = 0.0  # BIC drop against the model as it is
    significant: bool = False
    indistinguishable: tuple = ()
    evaluations: int = 0

    @property
    def effect(self):
        return self.candidate.build(self.values)


@dataclass
class Diagnosis:
    """Result of `diagnose`: the ranking and what is needed to explain it."""

    chi2: float  # of the model as it is
    points: int  # complex points N
    overdispersion: float
    ranked: list  # FittedCandidate, best first
    sequence: list = field(default_factory=list)  # significant effects, each fitted on top of the ones before

    @property
    def excess(self):
        return max(self.chi2 / self.points - 1.0, 0.0)

    def excess_after(self, fitted):
        return max(fitted.chi2 / self.points - 1.0, 0.0)

    @property
    def best(self):
        return self.ranked[0] if self.ranked and self.ranked[0].significant else None

    def table(self):
        """One row per candidate, best first."""
        rows = []
        for rank, fitted in enumerate(self.ranked, start=1):
            removed = 1.0 - self.excess_after(fitted) / self.excess if self.excess > 0 else 0.0
            rows.append({
                "rank": rank, "candidate": fitted.candidate.label, "effect": fitted.candidate.effect,
                "parameters": ", ".join(f"{p.name}={v:.6g}" for p, v in zip(fitted.candidate.free, fitted.values)),
                "parameter_std": ", ".join(f"{p.name}={s:.3g}" for p, s in zip(fitted.candidate.free, fitted.std)),
                "k": len(fitted.candidate.free), "chi2": fitted.chi2, "chi2_per_point": fitted.chi2 / self.points,
                "excess_removed": removed, "evidence_bic": fitted.evidence, "significant": fitted.significant,
                "indistinguishable_from": ", ".join(fitted.indistinguishable), "evaluations": fitted.evaluations,
            })
        return pd.DataFrame(rows)


def _fit(evaluator, candidate, max_evaluations):
    """Scan the leading parameter, then bounded least squares on all of them (search coordinates)."""
    free = candidate.free
    lower = np.array([p.to_search(p.lower) for p in free])
    upper = np.array([p.to_search(p.upper) for p in free])
    start = np.array([p.to_search(p.start) if p.start is not None else 0.5 * (lo + hi) for p, lo, hi in zip(free, lower, upper)])
    count = evaluator.evaluations

    def residual(x):
        try:
            effect = candidate.build([p.from_search(v) for p, v in zip(free, x)])
            effect.check(evaluator.machine)
            _, r = evaluator.residual(effect)
        except (ConfigError, ModelError, DiagnoseError, np.linalg.LinAlgError):
            return np.full(2 * points, 1e6)
        return np.concatenate([r.real, r.imag])

    points = sum(values.size for _, values, _ in evaluator.measured.values())
    best_x, best_chi2 = start, np.inf
    for value in np.linspace(lower[0], upper[0], candidate.scan_points):
        x = start.copy()
        x[0] = value
        chi2 = float(np.sum(residual(x) ** 2))
        if chi2 < best_chi2:
            best_x, best_chi2 = x, chi2
    span = upper - lower
    solution = scipy.optimize.least_squares(residual, np.clip(best_x, lower + 1e-9 * span, upper - 1e-9 * span),
                                            bounds=(lower, upper), x_scale=span / 10, diff_step=1e-4, method="trf",
                                            max_nfev=max_evaluations, xtol=1e-8, ftol=1e-10)
    x = solution.x
    chi2 = float(np.sum(solution.fun**2))
    if best_chi2 < chi2:
        x, chi2 = best_x, best_chi2
    values = tuple(p.from_search(v) for p, v in zip(free, x))
    # standard deviation from the Jacobian (search coordinates, then to values): each real component of the
    # residual has variance 1/2 at the noise floor, inflated by the misfit left (chi2 per point above 1)
    jacobian = solution.jac
    try:
        covariance = 0.5 * max(1.0, chi2 / points) * np.linalg.pinv(jacobian.T @ jacobian)
        std_search = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    except np.linalg.LinAlgError:
        std_search = np.full(len(free), np.inf)
    std = tuple(float(s * v) if p.log else float(s) for p, s, v in zip(free, std_search, values))
    return FittedCandidate(candidate, values, std, chi2, evaluations=evaluator.evaluations - count)


def diagnose(machine, measured, candidates=None, max_evaluations=60, sequence_length=1):
    """Fit every candidate effect on top of ``machine`` and rank them by evidence.

    Parameters
    ----------
    machine : ambid.machine.Machine
        The current model (a model variant: nominal, or with effects added).
    measured : dict
        `ambid.compare.measured_channels` of one identification run.
    candidates : list of Candidate, optional
        Default `candidate_space` of the machine.
    max_evaluations : int
        Least-squares evaluations per candidate after its scan.
    sequence_length : int
        With more than one missing effect, a single effect explains only part
        of the misfit and effects of similar shape can absorb part of another's
        (a low-pass bending a housing resonance): up to this many significant
        effects are chosen one after the other (forward selection), each
        fitted on top of the ones before and each a different candidate
        (`Diagnosis.sequence`).

    Returns
    -------
    Diagnosis
    """
    if not measured:
        raise DiagnoseError("no measured channel to diagnose")
    evaluator = _Evaluator(machine, measured)
    chi2, residual = evaluator.residual(None)
    points = residual.size
    candidates = candidates or candidate_space(machine)
    fitted = [_fit(evaluator, candidate, max_evaluations) for candidate in candidates]
    best_chi2 = min([f.chi2 for f in fitted] + [chi2])
    overdispersion = max(1.0, best_chi2 / points)
    penalty = np.log(2 * points)
    for f in fitted:
        f.evidence = 2 * (chi2 - f.chi2) / overdispersion - len(f.candidate.free) * penalty
        f.significant = f.evidence > INDISTINGUISHABLE_BIC
    fitted.sort(key=lambda f: -f.evidence)
    for f in fitted:
        if f.significant:
            f.indistinguishable = tuple(g.candidate.label for g in fitted if g is not f and g.significant
                                        and abs(g.evidence - f.evidence) < INDISTINGUISHABLE_BIC)
    diagnosis = Diagnosis(chi2=chi2, points=points, overdispersion=overdispersion, ranked=fitted)
    if diagnosis.best is not None:
        diagnosis.sequence = [diagnosis.best]
        if sequence_length > 1:
            others = [c for c in candidates if c.label != diagnosis.best.candidate.label]  # a different effect next
            following = diagnose(machine.with_effects(machine.effects + (diagnosis.best.effect,)), measured, others,
                                 max_evaluations, sequence_length - 1)
            diagnosis.sequence += following.sequence
    return diagnosis


def where_it_helps(before, after, top=3):
    """The channels and bands whose chi2 a candidate lowers most: text from two `ambid.compare.summarize` tables."""
    keys = ["output", "input", "band"]
    merged = before.merge(after, on=keys, suffixes=("_before", "_after"))
    merged = merged[merged["output"] != "all"]
    merged["drop"] = merged["chi2_before"] - merged["chi2_after"]
    channels = merged[merged["band"] == "all"].sort_values("drop", ascending=False).head(top)
    bands = merged[merged["band"] != "all"].groupby("band", sort=False)["drop"].sum().sort_values(ascending=False)
    channel_text = ", ".join(f"{r.output}/{r.input} ({r.chi2_before:.3g} -> {r.chi2_after:.3g})" for r in channels.itertuples()
                             if r.drop > 0)
    return {"channels": channel_text or "none", "band": bands.index[0] if len(bands) and bands.iloc[0] > 0 else "none"}


def effects_config_lines(effects):
    """The ``effects:`` lines to add to a machine config (YAML), parameters rounded to 4 significant digits."""
    entries = []
    for effect in effects:
        entry = effect.to_config()
        entry["parameters"] = {k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in entry["parameters"].items()
                               if k != "axes" or tuple(v) != tuple(EFFECTS[effect.name].parameters["axes"].default)}
        entries.append(entry)
    return yaml.safe_dump({"effects": entries}, sort_keys=False, default_flow_style=None).rstrip("\n")


def _phase_slope(frame):
    """Least-squares slope through the origin of phase error [deg] against frequency [Hz], and its R^2."""
    f, phase = frame["frequency_hz"].to_numpy(), frame["phase_error_deg"].to_numpy()
    good = np.isfinite(phase)
    f, phase = f[good], phase[good]
    if f.size < 3:
        return 0.0, 0.0
    slope = float(np.sum(f * phase) / np.sum(f * f))
    total = float(np.sum(phase**2))
    return slope, 1.0 - float(np.sum((phase - slope * f) ** 2)) / total if total > 0 else 0.0


def fingerprint(errors, summary):
    """The residual of a model in words: sentences an engineer reads before the ranking.

    ``errors`` / ``summary`` are `ambid.compare.channel_errors` / `summarize` of
    the model (measurement / model ratio: a positive phase error means the
    model leads the measurement, i.e. the machine lags more than the model).
    """
    sentences = []
    overall = summary[(summary["output"] == "all")].iloc[0]
    sentences.append(f"Overall chi2 per point {overall['chi2']:.3g} (1 = noise floor); rms magnitude error "
                     f"{overall['rms_magnitude_db']:.2f} dB, rms phase error {overall['rms_phase_deg']:.2f} deg.")
    per_channel = summary[(summary["band"] == "all") & (summary["output"] != "all")]
    worst = per_channel.sort_values("chi2", ascending=False).head(3)
    sentences.append("Largest misfit: " + ", ".join(f"{r.output}/{r.input} (chi2 {r.chi2:.3g})" for r in worst.itertuples()) + ".")
    bands = summary[(summary["output"] != "all") & (summary["band"] != "all")].groupby("band", sort=False)["chi2"].mean()
    if len(bands):
        sentences.append(f"The misfit is largest in the {bands.idxmax()} band (mean chi2 {bands.max():.3g}).")
    diagonal = errors[(errors["output"] == errors["input"]) & errors["output"].isin(RADIAL_AXES + ("Z",))]
    currents = errors[errors["output"].str.startswith("I_")]
    for name, frame in (("position", diagonal), ("coil-current", currents)):
        if frame.empty:
            continue
        top = frame["frequency_hz"].max()
        upper = frame[frame["frequency_hz"] >= 0.8 * top]
        lag = float(upper["phase_error_deg"].median())
        magnitude = float(upper["magnitude_error_db"].median())
        slopes = [_phase_slope(group) for _, group in frame.groupby("output")]
        linear = all(r2 > 0.9 for _, r2 in slopes) and len({np.sign(s) for s, _ in slopes}) == 1
        if abs(lag) < 1.0 and abs(magnitude) < 0.2:
            sentences.append(f"On the {name} channels the model matches near {top:.0f} Hz "
                             f"(phase {lag:+.2f} deg, magnitude {magnitude:+.2f} dB).")
            continue
        shape = "grows linearly with frequency" if linear else "grows with frequency" if abs(lag) >= 1.0 else "is small"
        direction = "lag" if lag > 0 else "lead"
        text = (f"On every {name} channel the measured phase {direction} beyond the model {shape}: "
                f"{abs(lag):.1f} deg near {top:.0f} Hz; magnitude {magnitude:+.2f} dB there (model / measurement)")
        if linear and lag > 0 and abs(magnitude) < 0.5:
            text += f"; a pure delay of {np.mean([s for s, _ in slopes]) / 360 * 1e6:.0f} us would do this"
        sentences.append(text + ".")
    cross = errors[(errors["output"] != errors["input"]) & errors["output"].isin(RADIAL_AXES)]
    cross_plane = cross[[RADIAL_AXES.index(o) % 2 != RADIAL_AXES.index(i) % 2 for o, i in zip(cross["output"], cross["input"])]]
    if not cross_plane.empty:
        chi2 = float(np.mean(cross_plane["normalized_error"] ** 2))
        if chi2 > 2.0:
            sentences.append(f"The x-y cross channels, which the model has at zero (or small), carry signal: chi2 {chi2:.3g}.")
    return sentences


def diagnosis_report(diagnosis, plant, measured, bands_hz, title, shown=8):
    """The candidates table (with where each helps) and the diagnosis in Markdown: verdict, fingerprint, config lines.

    Parameters
    ----------
    diagnosis : Diagnosis
    plant : ambid.plant.Plant
        The model the diagnosis started from.
    measured : dict
        `ambid.compare.measured_channels`.
    bands_hz : sequence
        Band edges of `ambid.compare.summarize`.
    """
    model = model_response(plant, measured)
    errors = channel_errors(measured, model)
    before = summarize(errors, bands_hz)
    table = diagnosis.table()
    helps = [where_it_helps(before, summarize(channel_errors(measured, model_response(plant_with_effect(plant, f.effect), measured)),
                                              bands_hz)) for f in diagnosis.ranked]
    table["helps_channels"] = [h["channels"] for h in helps]
    table["helps_band"] = [h["band"] for h in helps]
    lines = [f"# Diagnosis: {title}", ""]
    best = diagnosis.best
    excess = diagnosis.excess
    if best is None:
        lines += ["**Nothing significant is missing**: no candidate effect lowers the misfit by more than the penalty "
                  f"for its parameters (BIC evidence > {INDISTINGUISHABLE_BIC:g}). Excess over the noise floor {excess:.3g}.", ""]
    else:
        removed = 1 - diagnosis.excess_after(best) / excess if excess > 0 else 0.0
        lines += [f"**Missing: `{best.candidate.label}`** with "
                  + ", ".join(f"{p.name} = {v:.4g} +- {s:.2g}" for p, v, s in zip(best.candidate.free, best.values, best.std))
                  + f". It removes {100 * removed:.1f} % of the excess over the noise floor "
                  f"({excess:.4g} -> {diagnosis.excess_after(best):.4g}); it helps most on {helps[0]['channels']} "
                  f"and in the {helps[0]['band']} band.", ""]
        if best.indistinguishable:
            lines += [f"The data in the measured band cannot tell it from: {', '.join(best.indistinguishable)} "
                      f"(BIC evidence within {INDISTINGUISHABLE_BIC:g}); either explains the measurement.", ""]
        if len(diagnosis.sequence) > 1:
            lines += ["More than one effect is missing.  Chosen one after the other, each fitted on top of the ones before: "
                      + "; then ".join(f"`{f.candidate.label}` ("
                                       + ", ".join(f"{p.name} = {v:.4g}" for p, v in zip(f.candidate.free, f.values)) + ")"
                                       for f in diagnosis.sequence)
                      + ".  Add the first, rerun, and let the next diagnosis confirm the rest: effects fitted alone "
                      "absorb part of each other's misfit.", ""]
    lines += ["## Fingerprint of the residual", ""] + [f"- {sentence}" for sentence in fingerprint(errors, before)] + [""]
    lines += ["## Ranking", "", "| rank | candidate | parameters | excess removed | BIC evidence | significant |",
              "|---|---|---|---|---|---|"]
    for row in table.head(shown).itertuples():
        lines.append(f"| {row.rank} | {row.candidate} | {row.parameters} | {100 * row.excess_removed:.1f} % | "
                     f"{row.evidence_bic:.4g} | {'yes' if row.significant else 'no'} |")
    lines.append("")
    if best is not None:
        lines += ["## Add it", "", "Append to the variant's `effects:` in config/config.yaml "
                  "(`machines.<machine>.variants.<new variant>: {base: <this variant>, effects: [...]}`), "
                  "or to the machine file:", "", "```yaml", effects_config_lines([best.effect]), "```", ""]
    lines += [f"Misfit chi2 per point {diagnosis.chi2 / diagnosis.points:.4g} over {diagnosis.points} complex points; "
              f"overdispersion {diagnosis.overdispersion:.3g}; {sum(f.evaluations for f in diagnosis.ranked)} model evaluations.", ""]
    return table, "\n".join(lines)
