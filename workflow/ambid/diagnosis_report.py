"""The diagnosis as the user reads it: verdict with uncertainty, fingerprint, ranking, the lines to add.

`diagnosis_report` turns an `ambid.diagnose.Diagnosis` into the candidates table
(with where each candidate helps), the Markdown of ``diagnosis.md`` and the
stage's findings (`ambid.findings`): effects missing with their joint values and
standard deviations, variant parameters the data move, parameters at a bound or
undetermined, misfit no effect explains.  `effects_config_lines` writes the
``effects:`` entries with every digit, so adding them reproduces the diagnosed
model exactly.
"""

import itertools

import numpy as np
import pandas as pd
import yaml

from .amplitude import AMPLITUDE_ERROR_ALIKE
from .compare import channel_errors, model_response, summarize
from .diagnose import AT_FLOOR_EVIDENCE, INDISTINGUISHABLE_BIC, cell_name, effect_label
from .effects import EFFECTS
from .findings import Finding
from .fingerprint import fingerprint, where_it_helps

__all__ = ["effects_config_lines", "diagnosis_report", "diagnosis_findings", "format_value", "share_text",
           "run_disagreements", "DISAGREEMENT_SIGMA"]

#: Two runs' joint values of one parameter disagree beyond this many combined standard deviations
#: (`run_disagreements`; by chance one parameter in 16,000 goes beyond 4 sigma).
DISAGREEMENT_SIGMA = 4.0


#: Said of a retuned parameter that ended at its search bound: the data push it beyond what the refit allows.
_AT_BOUND = " (at its search bound: the data want it further, so the value is a limit, not an estimate)"


def effects_config_lines(effects):
    """The ``effects:`` lines to add to a machine config (YAML), every parameter with all its digits.

    Floats are written by YAML's shortest round-trip representation, so the
    lines rebuild exactly the effect the diagnosis fitted; default ``axes`` are left out.
    """
    entries = []
    for effect in effects:
        entry = effect.to_config()
        entry["parameters"] = {k: v for k, v in entry["parameters"].items()
                               if k != "axes" or tuple(v) != tuple(EFFECTS[effect.name].parameters["axes"].default)}
        entries.append(entry)
    return yaml.safe_dump({"effects": entries}, sort_keys=False, default_flow_style=None, width=1000).rstrip("\n")


def format_value(value, std):
    """``value +- std`` with the digits the uncertainty supports (two significant digits of ``std``)."""
    if not np.isfinite(std) or std <= 0:
        return f"{value:.6g}"
    digits = max(0, int(np.floor(np.log10(abs(value)))) - int(np.floor(np.log10(std))) + 2) if value != 0 else 2
    return f"{value:.{min(max(digits, 2), 12)}g} +- {std:.2g}"


def share_text(share):
    """The share of the misfit above the floor a candidate removes, in words where it removes none.

    A candidate fitted alone can leave the misfit larger than the model
    without it (its parameters are pulled by one band and spoil another); a
    negative percentage would read as a number to compare, so it is said.
    """
    if not np.isfinite(share):
        return "not computed"
    if share <= 0:
        return "none (worse than without it)" if share < -1e-3 else "none"
    return f"{100 * share:.1f} %"


def lead_support(lead, rankings):
    """What the other runs' diagnoses of the same model variant say about one run's lead.

    A lead (`ambid.diagnose.Diagnosis.lead`) is within the floor of the run that names it; another run of the same
    machine fitted the same candidate on its own data (``candidates.tsv``): significant BIC evidence there supports
    the lead, none does not.

    Parameters
    ----------
    lead : str
        The lead's candidate label.
    rankings : dict
        ``other run -> its candidates table`` (columns ``candidate, evidence_bic, significant``).

    Returns
    -------
    str
        One sentence ("" without other runs).
    """
    parts = []
    for run, table in rankings.items():
        rows = table[table["candidate"] == lead]
        if rows.empty:
            parts.append(f"run `{run}` did not try it")
            continue
        row = rows.iloc[0]
        verdict = "supports it" if bool(row["significant"]) else "does not support it"
        parts.append(f"run `{run}` {verdict} (its best fit earns BIC evidence {float(row['evidence_bic']):.3g})")
    return (f"The lead `{lead}` on the other runs of this variant: " + "; ".join(parts) + ".") if parts else ""


def run_disagreements(joints, threshold=DISAGREEMENT_SIGMA):
    """Parameters that the diagnoses of one model variant on different runs determine differently.

    Each run's joint refit (``joint.tsv``) states a value and a standard deviation
    for every parameter of the variant.  Two runs of the same machine measure the
    same physics, so ``z = |v_1 - v_2| / hypot(s_1, s_2)`` beyond ``threshold``
    says that at least one run carries a systematic error its uncertainty does not
    state (a method's bias, a changed operating point).

    Parameters
    ----------
    joints : dict
        ``run -> joint table`` (columns ``parameter, value, std, determined``).
    threshold : float
        ``z`` beyond which two runs disagree.

    Returns
    -------
    pandas.DataFrame
        ``run_1, run_2, parameter, value_1, std_1, value_2, std_2, sigma`` for every pair of runs and
        parameter determined in both with ``sigma = z > threshold``, largest first.
    """
    columns = ["run_1", "run_2", "parameter", "value_1", "std_1", "value_2", "std_2", "sigma"]
    rows = []
    for (run_1, first), (run_2, second) in itertools.combinations(joints.items(), 2):
        both = first[first["determined"].astype(bool)].merge(second[second["determined"].astype(bool)], on="parameter",
                                                             suffixes=("_1", "_2"))
        sigma = np.abs(both["value_1"] - both["value_2"]) / np.hypot(both["std_1"], both["std_2"])
        both = both.assign(run_1=run_1, run_2=run_2, sigma=sigma)
        rows.append(both.loc[both["sigma"] > threshold, columns])
    frame = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(columns=columns)
    return frame.sort_values("sigma", ascending=False, ignore_index=True)


def _marked_bounds(fitted):
    """``name=value`` of each free parameter, those at a bound of their physical range marked."""
    return ", ".join(f"{p.name}={v:.6g}" + (" (at its bound)" if p.name in fitted.at_bound else "")
                     for p, v in zip(fitted.candidate.free, fitted.values))


def _cells_text(cells):
    """Cells in words: chi2 per point against their limit, and their points (what they count for, where fewer, and
    the degrees of freedom of their stated noise, where it is an estimate that few)."""
    def dof_text(r):
        return (f", their noise estimated with {r.estimate_dof:.0f} degrees of freedom" if r.estimate_dof < 1000
                else "")  # (inf where the variances are known)

    return ", ".join(f"{cell_name(r)} (chi2 per point {r.chi2_per_point:.3g} against {r.limit:.3g}, {r.points} points"
                     + (f" counting as {r.effective_points:.{0 if r.effective_points >= 100 else 1}f} independent"
                        if r.effective_points < 0.95 * r.points else "") + dof_text(r) + ")"
                     for r in cells.sort_values("chi2_per_point", ascending=False).itertuples())


def _removes_text(fitted):
    """What a missing effect removes: its share of the misfit above the floor, or, chosen where every cell is within
    the floor (`ambid.diagnose.AT_FLOOR_EVIDENCE`), its evidence channel by channel."""
    if fitted.share > 0:
        return f"{100 * fitted.share:.1f} % of the misfit above the floor (BIC evidence {fitted.evidence:.4g})"
    return (f"misfit that every channel family's cells hold within their floor, but on few channels and bands: BIC "
            f"evidence {fitted.evidence:.4g}, {fitted.channel_evidence:.4g} with each channel and band weighed by the misfit "
            f"it leaves there (missing beyond {AT_FLOOR_EVIDENCE:g})")


def diagnosis_findings(diagnosis, stage="diagnose"):
    """What the user must know about a diagnosis, as `ambid.findings.Finding` rows."""
    out = []
    joint = diagnosis.joint.table if diagnosis.joint is not None else None
    for fitted in diagnosis.sequence:
        out.append(Finding(stage, "warning", "missing_effect", fitted.candidate.label,
                           f"{fitted.candidate.label} is missing: it removes " + _removes_text(fitted), fitted.evidence))
    for label, evidence, why in diagnosis.dropped:
        out.append(Finding(stage, "note", "dropped_effect", label,
                           f"{label} was chosen in its round but is no longer missing once the effects chosen later are "
                           f"in the model ({why}): not an effect to add", evidence))
    if diagnosis.joint is not None and diagnosis.joint.began_at:
        name, there, other, at_other = diagnosis.joint.began_at
        out.append(Finding(stage, "note", "alternative_start", name,
                           f"the joint refit kept its descent from {name}, not from {other}: the model's parameters the "
                           "data do not determine are that start's", there / diagnosis.points))  # (chi2 per point there)
    if joint is not None and not joint.empty:
        for row in joint.itertuples():
            if row.at_bound:
                out.append(Finding(stage, "warning", "at_bound", row.parameter,
                                   f"the joint refit puts {row.parameter} at a bound of its range ({row.value:.6g})", row.value))
            elif not row.determined:
                out.append(Finding(stage, "note", "undetermined", row.parameter,
                                   f"{row.parameter} is not determined by these data: {format_value(row.value, row.std)} "
                                   f"({100 * row.relative_std:.0f} % relative with the prior, "
                                   f"{100 * row.data_relative_std:.0f} % from the data alone)", row.data_relative_std))
        form = joint[joint["form_std"] > 0]
        if not form.empty:
            # one note for all of them: a variant far above the floor has a dozen
            out.append(Finding(stage, "note", "model_form", ", ".join(form["parameter"]),
                               "the parts of the band disagree beyond chance about "
                               + ", ".join(f"{r.parameter} ({format_value(r.value, r.std)}, of which model form "
                                           f"{r.form_std:.2g})" for r in form.itertuples())
                               + ": the refitted model does not describe every part of the band alike (an effect still "
                               "missing, or a form the library lacks), and their standard deviations hold that spread",
                               float(len(form))))
    if diagnosis.retune is not None:
        for row in diagnosis.retune.itertuples():
            out.append(Finding(stage, "warning", "retune", row.parameter,
                               f"the data move {row.parameter} from {row.start:.6g} to {format_value(row.value, row.std)}"
                               + (_AT_BOUND if row.at_bound else ""), row.value))
    for fitted in diagnosis.ranked:
        if fitted.significant and fitted.at_bound and fitted.share >= 0.1:
            out.append(Finding(stage, "note", "candidate_at_bound", fitted.candidate.label,
                               f"{fitted.candidate.label} would explain part of the misfit only with "
                               f"{', '.join(fitted.at_bound)} at the bound of its physical range: not an explanation",
                               fitted.evidence))
    lead = diagnosis.lead
    if lead is not None:
        out.append(Finding(stage, "note", "lead", lead.candidate.label,
                           f"the data favour {lead.candidate.label} (BIC evidence {lead.evidence:.3g}, "
                           f"{lead.channel_evidence:.3g} channel by channel), but the misfit it "
                           "would remove lies within the floor: a lead to check with more data, not an effect to add",
                           lead.evidence))
    unexplained = diagnosis.unexplained
    if not unexplained.empty:
        out.append(Finding(stage, "warning", "unexplained_misfit", ", ".join(sorted(set(unexplained["family"]))),
                           "misfit above the floor that no effect of the library explains: " + _cells_text(unexplained),
                           float(unexplained["chi2_per_point"].max())))
    return out


def _describing_function(subject):
    """The caveat of a diagnosis on a run without repeated steps, about ``subject``."""
    return (f"This run has no step repeated at a lower amplitude, so its FRF is the describing function at the "
            f"excitation amplitude: {subject} may be the force law's amplitude-dependent error (it reads most like the "
            "bearings' coefficients) rather than the machine. Repeat some steps at a lower amplitude, or run a "
            "multisine, to tell them apart.")


def _residual_errors(measured, residual):
    """A diagnosis residual (`ambid.diagnose`: one complex point per measured point, channel after channel) in the
    layout of `ambid.compare.channel_errors`, normalized errors only, for `ambid.compare.summarize`."""
    lengths = [len(frequency) for frequency, _, _ in measured.values()]
    if sum(lengths) != len(residual):
        raise ValueError(f"a residual of {len(residual)} points for {sum(lengths)} measured points")
    missing = np.full(len(residual), np.nan)
    return pd.DataFrame({"output": np.repeat([output for output, _ in measured], lengths),
                         "input": np.repeat([input_axis for _, input_axis in measured], lengths),
                         "frequency_hz": np.concatenate([frequency for frequency, _, _ in measured.values()]),
                         "magnitude_error_db": missing, "phase_error_deg": missing, "normalized_error": np.abs(residual)})


def diagnosis_report(diagnosis, plant, measured, bands_hz, title, shown=8, repeated_steps=None):
    """The candidates table (with where each helps) and the diagnosis in Markdown.

    Parameters
    ----------
    diagnosis : ambid.diagnose.Diagnosis
    plant : ambid.plant.Plant
        The model the diagnosis started from.
    measured : dict
        `ambid.compare.measured_channels`.
    bands_hz : sequence or None
        Band edges of `ambid.compare.summarize` (None: from the measured grid).
    title : str
    shown : int
        Candidates in the page's table.
    repeated_steps : int, optional
        Steps of the run repeated at a lower amplitude (the FRF's metadata); with none, a lead, or a chosen effect of
        `AMPLITUDE_ERROR_ALIKE`, is said to be possibly the describing function's amplitude error (`ambid.amplitude`).

    Returns
    -------
    table : pandas.DataFrame
    markdown : str
    """
    model = model_response(plant, measured)
    errors = channel_errors(measured, model)
    before = summarize(errors, bands_hz)
    table = diagnosis.table()
    # where each candidate helps: its fit's residual against that of the model it was fitted on (the variant, or the
    # variant retuned), channel by channel and band by band
    base = summarize(_residual_errors(measured, diagnosis.base_residual), bands_hz)
    helps = [where_it_helps(base, summarize(_residual_errors(measured, f.residual), bands_hz)) for f in diagnosis.ranked]
    table["helps_channels"] = [h["channels"] for h in helps]
    table["helps_band"] = [h["band"] for h in helps]
    lines = [f"# Diagnosis: {title}", ""]
    joint = diagnosis.joint
    limit = diagnosis.cells_before
    if diagnosis.verdict == "nothing":
        worst = float(limit["chi2_per_point"].max())
        lines += [f"**Nothing is missing at the floor**: every channel family and band is within the floor (largest chi2 "
                  f"per point {worst:.3g}); no candidate effect is needed.", ""]
    lead = diagnosis.lead
    if lead is not None:
        band = [min(float(np.min(f)) for f, _, _ in measured.values()), max(float(np.max(f)) for f, _, _ in measured.values())]
        values = ", ".join(f"{p.name} = {format_value(v, s)}"
                           + (" (not determined)" if not abs(s) < diagnosis.determined_std * abs(v) else "")
                           + (f" (outside the measured {band[0]:.4g}-{band[1]:.4g} Hz)"
                              if p.at_misfit_peaks and not band[0] <= v <= band[1] else "")  # a resonance
                           for p, v, s in zip(lead.candidate.free, lead.values, lead.std))
        where = helps[diagnosis.ranked.index(lead)]
        lines += [f"A lead, not a finding: the data favour `{lead.candidate.label}` ({values}; BIC evidence "
                  f"{lead.evidence:.4g}, {lead.channel_evidence:.4g} channel by channel against the "
                  f"{AT_FLOOR_EVIDENCE:g} a missing effect needs there; most on {where['channels']}, {where['band']} band), "
                  "but the misfit it would remove "
                  f"lies within the floor{' of the model retuned below' if diagnosis.verdict == 'retune' else ''}. Whether "
                  "it is there takes more data: repeated steps, a denser grid or a multisine run where it acts."
                  + (" " + _describing_function("the lead") if repeated_steps == 0 else ""), ""]
    if diagnosis.dropped:
        names = ", ".join(f"`{label}` (BIC evidence {evidence:.3g}: {why})" for label, evidence, why in diagnosis.dropped)
        lines += [f"**Dropped after the selection**: {names}. Each was chosen in its round, but weighed against the "
                  "other chosen effects refitted without it, it is no longer missing: a missing effect needs BIC "
                  f"evidence above {INDISTINGUISHABLE_BIC:g}, a material share of the misfit and no parameter at a bound "
                  "of its range.", ""]
    if diagnosis.sequence:
        new = joint.table[joint.table["origin"] == "new"] if joint is not None else None
        parts = []
        for fitted, effect in zip(diagnosis.sequence, joint.effects if joint is not None else [f.effect for f in diagnosis.sequence]):
            rows = new[new["parameter"].str.startswith(effect_label(fitted.effect) + ".")] if new is not None else None
            values = ", ".join(f"{r.parameter.split('.', 1)[1]} = {format_value(r.value, r.std)}" for r in rows.itertuples()) \
                if rows is not None and len(rows) else ", ".join(f"{p.name} = {v:.6g}" for p, v in zip(fitted.candidate.free, fitted.values))
            parts.append(f"`{fitted.candidate.label}` ({values})")
        lines += [("**Missing: " if len(parts) == 1 else "**Missing, together: ") + "; ".join(parts) + "**.", ""]
        first = diagnosis.sequence[0]
        index = next((i for i, f in enumerate(diagnosis.ranked) if f is first), None)  # (a later round's when pruned)
        lines += ["Chosen one after the other, then refitted jointly with the model's own parameters. The first "
                  + (f"removes {_removes_text(first)}; it helps most on {helps[index]['channels']} and in the "
                     f"{helps[index]['band']} band." if index is not None else
                     f"kept, chosen in a later round, removed {_removes_text(first)} there."), ""]
        if first.indistinguishable:
            lines += [f"The data in the measured band cannot tell `{first.candidate.label}` from: "
                      f"{', '.join(first.indistinguishable)} (BIC evidence within {INDISTINGUISHABLE_BIC:g}); either explains "
                      "the measurement.", ""]
        for fitted in diagnosis.sequence[1:]:
            if fitted.contenders:
                others = [(label, chi2) for label, chi2 in fitted.contenders if label != fitted.candidate.label]
                own = dict(fitted.contenders)[fitted.candidate.label]
                lines += [f"`{fitted.candidate.label}` was chosen over " + ", ".join(f"`{label}`" for label, _ in others)
                          + " (close to it with the effects chosen before held) because it fits best refitted jointly "
                          f"with them: chi2 {own:.5g} against " + ", ".join(f"{chi2:.5g}" for _, chi2 in others) + ".", ""]
        for fitted in diagnosis.sequence:
            if fitted.replaced:
                own = dict(fitted.replaced)[fitted.candidate.label]
                label, chi2 = next((label, chi2) for label, chi2 in fitted.replaced if label != fitted.candidate.label)
                lines += [f"`{fitted.candidate.label}` replaced `{label}`, which its round had chosen before the effects "
                          "chosen after it were in the model: refitted jointly with all the other effects chosen, it fits "
                          f"best (chi2 {own:.5g} against {chi2:.5g}).", ""]
        if any(f.candidate.effect == "sensor_lowpass" for f in diagnosis.sequence):
            lines += ["On the position channels a first-order `sensor_lowpass` is the same as a first-order lag of the "
                      "force behind the coil current (a slow flux, eddy currents in solid iron), and the coil currents "
                      "see neither: where the sensors' bandwidth is known to be higher, read it as that lag "
                      "(`eddy_current` is the laminations' half-order one).", ""]
        alike = [f.candidate.label for f in diagnosis.sequence if f.candidate.effect in AMPLITUDE_ERROR_ALIKE]
        if repeated_steps == 0 and alike:
            names = " and ".join(f"`{a}`" for a in alike)
            lines += [_describing_function(f"part of what {names} {'takes' if len(alike) == 1 else 'take'} up"), ""]
    if diagnosis.retune is not None and not diagnosis.retune.empty:
        lines += ["**The data move parameters the model already has** (joint refit, beyond three standard deviations"
                  + (f"; the model as it is lies within the floor, but its own parameters refitted earn BIC evidence "
                     f"{diagnosis.retune_evidence:.4g} channel by channel, beyond the {AT_FLOOR_EVIDENCE:g} a missing "
                     "effect needs there" if diagnosis.retune_evidence is not None else "") + "):", ""]
        lines += [f"- `{r.parameter}`: {r.start:.6g} -> {format_value(r.value, r.std)}" + (_AT_BOUND if r.at_bound else "")
                  for r in diagnosis.retune.itertuples()]
        lines += ["", "Set them where the variant takes them (its machine file, variant or update)."
                  + (f" The refit kept its descent from {joint.began_at[0]}, so the values the data do not determine "
                     "are that start's (table below): set them all, or let the variant take that update (its "
                     "`update:`) and then the moved values above." if joint is not None and joint.began_at else ""), ""]
    unexplained = diagnosis.unexplained
    if not unexplained.empty:
        lines += [f"**Unexplained misfit**{' remains' if diagnosis.sequence else ''}: no effect of the library brings "
                  f"{_cells_text(unexplained)} to the floor. Read the fingerprint below for its shape.", ""]
    lines += ["## Fingerprint of the residual", ""]
    lines += [f"- {s}" for s in fingerprint(errors, before, diagnosis.cells_before)] + [""]
    if joint is not None and not joint.table.empty:
        lines += ["## Joint refit", "",
                  "Every chosen effect and the model's own parameters refitted together (the model's own under a prior of "
                  "its configured values, so what the data do not determine stays put; **determined** by the data alone: "
                  "their relative standard deviation, without the prior, below "
                  f"{diagnosis.determined_std:g}). A standard deviation is the parameter's precision within this model: "
                  "where the model's rotor differs from the machine's (another FEM of the same drawing differs by "
                  "0.05-0.1 %), a structural parameter takes up the difference, and no standard deviation read from "
                  "the data includes it. Where parts of the band (5-40 consecutive points of a channel) want values "
                  "that differ beyond chance, the spread of those values is added to the standard deviation as **model "
                  "form**: the refitted model does not describe every part of the band alike (an effect still missing, "
                  "or a form the library lacks), the fit averages the difference, and the data cannot tell which part "
                  "is right.",
                  "",
                  "| parameter | origin | before | joint value +- std | determined |", "|---|---|---|---|---|"]
        for r in joint.table.itertuples():
            note = "yes" if r.determined else f"no ({100 * r.data_relative_std:.0f} % from the data alone)"
            if r.at_bound:
                note += ", at a bound"
            if r.form_std > 0:
                note += f"; model form +- {r.form_std:.2g} of the std"
            lines.append(f"| {r.parameter} | {r.origin} | {r.start:.6g} | {format_value(r.value, r.std)} | {note} |")
        lines += ["", f"After it: chi2 per point {joint.chi2 / diagnosis.points:.4g} (before {diagnosis.chi2 / diagnosis.points:.4g}).",
                  ""]
        if joint.began_at:
            name, there, other, at_other = joint.began_at
            lines += [f"The refit of the model's own parameters had two starts, {name} and {other} (chi2 per point "
                      f"{there / diagnosis.points:.4g} and {at_other / diagnosis.points:.4g} there). The values above come "
                      f"from the descent that began at {name}: the lower end, or the first to reach the floor (after which "
                      "no other start is tried). Those the data do not determine keep that start's values, not the "
                      "model's: to reproduce this fit, set them all, not only those that moved.", ""]
    retuned = diagnosis.base_chi2 < diagnosis.chi2
    lines += ["## Ranking against the model " + ("with its own parameters refitted first (chi2 per point "
                                                 f"{diagnosis.base_chi2 / diagnosis.points:.4g})" if retuned else "as it is"), "",
              "| rank | candidate | parameters | misfit above the floor removed | BIC evidence | evidence channel by channel | "
              "verdict |",
              "|---|---|---|---|---|---|---|"]
    for fitted, row in zip(diagnosis.ranked[:shown], table.head(shown).itertuples()):
        if fitted.missing:
            verdict = "missing"
        elif fitted.at_bound:
            verdict = f"at bound ({', '.join(fitted.at_bound)})"
        elif not fitted.significant:
            verdict = "not significant"
        elif diagnosis.base_at_floor and fitted.channel_evidence <= AT_FLOOR_EVIDENCE:
            verdict = f"within the floor (channel by channel at most {AT_FLOOR_EVIDENCE:g})"
        elif diagnosis.base_at_floor:  # an output row above the floor: misfit outside the library, `ambid.diagnose._Cells`
            verdict = (f"not chosen: an output row is above the floor, and outside it the candidate earns at most "
                       f"{AT_FLOOR_EVIDENCE:g}")
        else:
            verdict = "removes too little"
        lines.append(f"| {row.rank} | {row.candidate} | {_marked_bounds(fitted)} | {share_text(fitted.share)} | "
                     f"{row.evidence_bic:.4g} | {row.channel_evidence_bic:.4g} | {verdict} |")
    lines += ["", "**Evidence channel by channel**: the BIC evidence with each channel and band weighed by the misfit the "
              "candidate leaves there (at least its floor), so what it gains where the model misses anyway counts less; "
              f"where no cell is above the floor, a candidate is missing beyond {AT_FLOOR_EVIDENCE:g}.", ""]
    if diagnosis.sequence and joint is not None:
        lines += ["## Add it", "", "Append to a new variant's `effects:` in config/config.yaml "
                  "(`machines.<machine>.variants.<new variant>: {base: <this variant>, effects: [...]}`), "
                  "or to the machine file (joint values, all digits):", "", "```yaml", effects_config_lines(joint.effects),
                  "```", ""]
    lines += [f"Misfit chi2 per point {diagnosis.chi2 / diagnosis.points:.4g} over {diagnosis.points} complex points; "
              f"overdispersion {diagnosis.overdispersion:.3g}; "
              f"{sum(f.evaluations for f in diagnosis.ranked) + (joint.evaluations if joint else 0)} model evaluations.", ""]
    return table, "\n".join(lines)

