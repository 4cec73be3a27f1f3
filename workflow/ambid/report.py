"""One self-contained HTML report per machine: every stage's figures and tables, in thesis order.

The report follows a machine from its measurements to the diagnosis of its
model: calibration (thesis ch. 3, 6.1), identification (ch. 4, 6.2), the
parametric fit (ch. 5.1), the rotor model update (ch. 5.2-5.3, 6.3), the model
variants and the diagnosis loop (beyond the thesis).  Figures are embedded as
PNG data, tables are written out, and nothing in the page depends on the time
or place it was made, so the same results give the same bytes.  Captions are
Markdown templates (``workflow/report/*.md``) with ``{machine}``, ``{run}`` and
``{variant}`` fields; each names the thesis figure or table it corresponds to.
"""

import base64
import html
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .diagnosis_report import DISAGREEMENT_SIGMA, format_value, lead_support, run_disagreements
from .errors import AmbidError
from .findings import findings_frame, read_findings
from .io import read_parquet, read_tsv

__all__ = ["Figure", "Table", "Text", "Section", "markdown_html", "render_report", "machine_report", "engineering_units",
           "verdict_markdown", "update_caveat"]


@dataclass
class Figure:
    """A PNG figure and its caption (Markdown)."""

    path: Path
    caption: str = ""


@dataclass
class Table:
    """A table and its caption (Markdown); ``source`` is the file it came from."""

    frame: pd.DataFrame
    caption: str = ""
    source: str = ""


@dataclass
class Text:
    """A block of Markdown."""

    markdown: str


@dataclass
class Section:
    """A titled part of the report; ``level`` 2 for a stage, 3 for a run or variant within it."""

    title: str
    blocks: list = field(default_factory=list)
    level: int = 2

    @property
    def anchor(self):
        return re.sub(r"[^a-z0-9]+", "-", self.title.lower()).strip("-")


#: Caption of a run's plausibility table (`ambid.plausibility.check_units`).
PLAUSIBILITY_CAPTION = ("The log against the nominal model, before the FRF: its frequencies, low-frequency compliance "
                        "and coil-current ratio over the model's (a unit error is 10^3 or 10^6 off; beyond 30x the run "
                        "stops), and their signs (a channel of the other sign, swapped coil currents and complex "
                        "conjugated coefficients stop it too).")


# ------------------------------------------------------------------------------ Markdown
_INLINE = [
    (re.compile(r"`([^`]+)`"), r"<code>\1</code>"),
    (re.compile(r"\*\*([^*]+)\*\*"), r"<strong>\1</strong>"),
]


def _inline(text):
    text = html.escape(text, quote=False)
    for pattern, replacement in _INLINE:
        text = pattern.sub(replacement, text)
    return text


def markdown_html(text):
    """HTML of the Markdown ambid writes: headings, paragraphs, ``-`` lists, pipe tables, fenced code,
    ``code`` and **bold**.

    A small, strict subset (the diagnosis and the captions use nothing else);
    every character of the text is escaped, so a file can never inject markup.
    """
    out, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        line = lines[i]
        if not line.strip():
            i += 1
        elif line.startswith("```"):
            end = next((j for j in range(i + 1, len(lines)) if lines[j].startswith("```")), len(lines))
            out.append("<pre><code>" + html.escape("\n".join(lines[i + 1:end]), quote=False) + "</code></pre>")
            i = end + 1
        elif line.startswith("#"):
            level = min(len(line) - len(line.lstrip("#")) + 2, 6)  # '#' inside a section is an h3
            out.append(f"<h{level}>{_inline(line.lstrip('#').strip())}</h{level}>")
            i += 1
        elif line.startswith("|"):
            rows = []
            while i < len(lines) and lines[i].startswith("|"):
                cells = [cell.strip() for cell in lines[i].strip().strip("|").split("|")]
                if not all(set(cell) <= set("-: ") for cell in cells):
                    rows.append(cells)
                i += 1
            head = "".join(f"<th>{_inline(c)}</th>" for c in rows[0])
            body = "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in row) + "</tr>" for row in rows[1:])
            out.append(f'<div class="scroll"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>')
        elif line.startswith("- "):
            items = []
            while i < len(lines) and lines[i].startswith("- "):
                items.append(f"<li>{_inline(lines[i][2:])}</li>")
                i += 1
            out.append("<ul>" + "".join(items) + "</ul>")
        else:
            paragraph = []
            while i < len(lines) and lines[i].strip() and not lines[i].startswith(("#", "|", "- ", "```")):
                paragraph.append(lines[i].strip())
                i += 1
            out.append(f"<p>{_inline(' '.join(paragraph))}</p>")
    return "\n".join(out)


# ------------------------------------------------------------------------------ HTML
# A contents sidebar that stays on screen (position: sticky), collapsible sections (<details>), tables that scroll
# inside themselves: pure CSS, no script, no external resource.
_STYLE = """
* { box-sizing: border-box; }
body { font-family: system-ui, sans-serif; margin: 0; color: #222; }
.page { display: grid; grid-template-columns: 16rem minmax(0, 1fr); gap: 1.5em; max-width: 1500px; margin: 0 auto; }
nav.contents { position: sticky; top: 0; align-self: start; max-height: 100vh; overflow-y: auto; padding: 1em 0.5em 1em 1em;
  font-size: 0.85em; border-right: 1px solid #ddd; }
nav.contents ul { list-style: none; padding-left: 0; margin: 0.2em 0; } nav.contents ul ul { padding-left: 1em; }
nav.contents li { margin: 0.15em 0; } nav.contents a { text-decoration: none; color: #0645ad; }
main { min-width: 0; padding: 0 1em 3em 0; max-width: 1150px; }
@media (max-width: 900px) { .page { grid-template-columns: minmax(0, 1fr); } nav.contents { position: static;
  max-height: none; border-right: none; } }
h1 { border-bottom: 2px solid #444; } summary h2, summary h3 { display: inline; }
details.level2 > summary { border-bottom: 1px solid #aaa; margin-top: 1.5em; padding-bottom: 0.2em; cursor: pointer; }
details.level3 { margin-left: 0.5em; } details.level3 > summary { margin-top: 1em; cursor: pointer; }
.scroll { max-width: 100%; overflow-x: auto; margin: 0.5em 0 1em; }
table { border-collapse: collapse; font-size: 0.85em; }
th, td { border: 1px solid #ccc; padding: 2px 6px; text-align: left; vertical-align: top; } th { background: #eee; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
figure { margin: 1em 0; } figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption, .caption { font-size: 0.9em; color: #444; }
code { background: #f4f4f4; padding: 0 2px; overflow-wrap: anywhere; } pre { background: #f4f4f4; padding: 0.5em; overflow-x: auto; }
.source { color: #888; font-size: 0.8em; } .warning { border-left: 4px solid #c60; padding-left: 0.6em; }
"""


def _alt_text(block):
    """Alt text of a figure: the first sentence of its caption without markup, else the file name."""
    text = re.sub(r"[`*]", "", block.caption or "").strip()
    first = re.split(r"(?<=[.:;])\s", text, maxsplit=1)[0].strip() if text else ""
    return first or Path(block.path).stem.replace("_", " ")


def _scroll(table_html):
    """A table in a container that scrolls sideways by itself, so the page never does."""
    return f'<div class="scroll">{table_html}</div>'


def _block_html(block):
    if isinstance(block, Figure):
        data = base64.b64encode(Path(block.path).read_bytes()).decode("ascii")
        return (f'<figure><img alt="{html.escape(_alt_text(block))}" src="data:image/png;base64,{data}">'
                f"<figcaption>{markdown_html(block.caption)}</figcaption></figure>")
    if isinstance(block, Table):
        table = _table_html(block.frame)
        source = f'<div class="source">{html.escape(block.source)}</div>' if block.source else ""
        return f'<div class="caption">{markdown_html(block.caption)}</div>{_scroll(table)}{source}'
    return markdown_html(block.markdown)


def _cell(value):
    if isinstance(value, (float, np.floating)):
        return "" if np.isnan(value) else f"{value:.4g}"
    return html.escape(str(value))


def _table_html(frame):
    """A data frame as an HTML table: numbers right-aligned (class ``num``), text left, NaN empty."""
    numeric = [pd.api.types.is_numeric_dtype(frame[c]) and not pd.api.types.is_bool_dtype(frame[c]) for c in frame.columns]
    head = "".join(f'<th{" class=num" if n else ""}>{html.escape(str(c))}</th>' for c, n in zip(frame.columns, numeric))
    rows = "".join("<tr>" + "".join(f'<td{" class=num" if n else ""}>{_cell(v)}</td>' for v, n in zip(row, numeric))
                   + "</tr>" for row in frame.itertuples(index=False))
    return f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>"


def _contents(sections):
    """The sidebar: every stage, and under it its runs and variants."""
    items, open_item = [], None
    for section in sections:
        link = f'<a href="#{section.anchor}">{html.escape(section.title)}</a>'
        if section.level == 2 or open_item is None:
            open_item = [link, []]
            items.append(open_item)
        else:
            open_item[1].append(f"<li>{link}</li>")
    return "<ul>" + "".join(f"<li>{link}" + (f"<ul>{''.join(sub)}</ul>" if sub else "") + "</li>"
                            for link, sub in items) + "</ul>"


def render_report(title, sections, introduction=""):
    """The report as one HTML document (figures embedded, no external resource, no script).

    A contents sidebar stays on screen and lists every section with its runs
    and variants; every section is a ``<details>`` element (open), so it folds
    away; every table scrolls inside its own container.
    """
    body, open_level2 = [], False
    for section in sections:
        heading = f'<h{section.level} id="{section.anchor}">{html.escape(section.title)}</h{section.level}>'
        if section.level == 2:
            if open_level2:
                body.append("</details>")
            body.append(f'<details class="level2" open><summary>{heading}</summary>')
            open_level2 = True
        inner = [_block_html(block) for block in section.blocks]
        if section.level == 2:
            body += inner
        else:
            body.append(f'<details class="level3" open><summary>{heading}</summary>' + "\n".join(inner) + "</details>")
    if open_level2:
        body.append("</details>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>\n<div class=\"page\">\n"
            f'<nav class="contents" aria-label="contents"><strong>Contents</strong>{_contents(sections)}</nav>\n'
            f"<main>\n<h1>{html.escape(title)}</h1>\n{markdown_html(introduction)}\n"
            + "\n".join(body) + "\n</main>\n</div>\n</body></html>\n")


# ------------------------------------------------------------------------------ a machine's report
class _Captions:
    """Caption templates (name -> Markdown), filled with the machine, run and variant."""

    def __init__(self, templates, machine):
        self.templates, self.machine = templates, machine

    def __call__(self, name, **fields):
        try:
            return self.templates[name].format(machine=self.machine, **fields)
        except (KeyError, IndexError, ValueError) as error:
            raise AmbidError(f"caption template {name!r} cannot be filled: {error!r}") from None


def _findings(root, path, machine, what):
    """The findings a stage wrote next to a result (`ambid.findings`), as a block where the result is quoted."""
    if not (root / path).exists():
        return Text(f"No findings table for {what}.")
    frame = findings_frame(read_findings(root / path))
    if frame.empty:
        return Text(f"Findings of {what}: none.")
    return Table(frame.drop(columns=["stage"]), f"Findings of {what}: **{len(frame)}** (most severe first; a "
                 "`failure` must not be used as it is).", f"results/{machine}/{path}")


def verdict_markdown(markdown):
    """The verdict of a diagnosis (``diagnosis.md``) with its uncertainties: every block before its first subsection.

    That is what is missing with the values and standard deviations of its
    parameters, which effects the data cannot tell apart, the parameters the
    data move, the misfit no effect explains, or that nothing is missing at
    the floor; the advice on where to set them is left out.
    """
    head = markdown.split("\n## ", 1)[0]
    blocks = [b.strip() for b in head.split("\n\n") if b.strip() and not b.lstrip().startswith("# ")]
    return "\n\n".join(b for b in blocks if not b.startswith("Set them where"))


# Columns in SI units shown in engineering units: suffix -> (new suffix, factor)
_ENGINEERING = (("_n_per_m", "_n_per_um", 1e-6), ("_pa", "_gpa", 1e-9), ("_m", "_um", 1e6), ("_s", "_us", 1e6))


def engineering_units(frame, metres=()):
    """A table in the units an engineer reads: metres as um, seconds as us, pascal as GPa, N/m as N/um.

    Columns are converted by the SI suffix of their name (``offset_m`` ->
    ``offset_um``); ``metres`` names further columns in metres whose names
    carry no unit (e.g. the axes ``DX``..``NY`` of a calibration table), shown
    in um with the unit added to the name.
    """
    out = frame.copy()
    renames = {}
    for column in out.columns:
        if not pd.api.types.is_float_dtype(out[column]):
            continue
        name = str(column)
        if name in metres:
            out[column] = out[column] * 1e6
            renames[column] = f"{name} [um]"
            continue
        for suffix, new, factor in _ENGINEERING:
            if name.endswith(suffix) and (suffix != "_s" or "delay" in name):  # a duration of minutes stays in s
                out[column] = out[column] * factor
                renames[column] = name[: -len(suffix)] + new
                break
    return out.rename(columns=renames)


def _valley_text(variables):
    """The variables the data fix only given where the undetermined moduli were left (`ambid.update.identifiability`)."""
    if "valley_shift" not in variables:
        return []
    # probed (a valley shift) and yet undetermined: locally determined, moved beyond determined_std along the valley
    conditional = variables[variables["valley_shift"].notna() & ~variables["determined"].astype(bool)]
    if conditional.empty:
        return []
    return [Text("Determined near the solution but not beyond it: " + "; ".join(
        f"{r.variable} moves by a factor {np.exp(r.valley_shift):.2f} when {r.valley_variable} is moved (by up to a "
        "factor e), the features matched as well" for r in conditional.itertuples()) +
        ". The data fix a combination of them, not each.")]


def _feature_fit_text(variables):
    """How well the updated model matches the features it was fitted to (`ambid.update.identifiability`'s chi2)."""
    ratio, scale = float(variables["features_chi2_per_dof"].iloc[0]), float(variables["std_scale"].iloc[0])
    if ratio <= 2.0:
        scaled = f"; the uncertainties below are scaled by its root, {scale:.3g}" if scale > 1 else ""
        return [Text(f"The updated model matches the features within their uncertainties (chi-square per degree of "
                     f"freedom {ratio:.2f}{scaled}).")]
    return [Text(f"**The updated model does not match the features within their uncertainties** (chi-square per degree "
                 f"of freedom {ratio:.3g}): the model lacks something the machine has (an effect, a stack's shear "
                 f"stiffness, a joint), and its moduli are effective values of this model.  The uncertainties below are "
                 f"scaled by {scale:.3g}; that covers a misfit spread like noise, not a wrong model (`comparison.tsv` "
                 "shows which features are missed; the diagnosis names what is missing).")]


def _mode_shape_text(path):
    """Whether the update compared the mode shapes (`ambid.update.mode_shape_rows`), and how well they are matched."""
    shapes = read_tsv(path)
    if shapes.empty:
        return [Text("Mode shapes in the update: not compared (fewer than two modes in a plane, or "
                     "`update.weights.mode_shape` 0); the update matched frequencies and damping ratios only.")]
    modes = shapes.groupby(shapes["output"].str[1])["number"].nunique().max()
    worst = shapes.loc[shapes["contrast"].abs().idxmax()]
    return [Text(f"Mode shapes in the update (README \"Rotor model update\"): {len(shapes)} modal constants of up to "
                 f"{modes} modes per plane took part, as ratios free of the sensors' and actuators' gains; at the updated "
                 f"model their chi-square is {(shapes['contrast'] ** 2).sum():.1f}, the largest contrast {worst['contrast']:+.2f} "
                 f"standard uncertainties ({worst['output']}/{worst['input']}, mode {int(worst['number'])}) "
                 "(`mode_shapes.tsv`).")]


def update_caveat(undetermined, total):
    """What an updated-model number is worth when the data leave update variables undetermined (text after it)."""
    if total == 0 or undetermined == 0:
        return "."
    if undetermined == total:
        return (f"; **none of the {total} update variables is determined by the data**, so the updated model matches "
                "this frequency without establishing the values it changed.")
    return f"; {undetermined} of the {total} update variables are not determined by the data."


def _misfit_change(verdict_path):
    """``chi2 per point X -> Y`` of a diagnosis (before its effects, after the joint refit)."""
    if not Path(verdict_path).exists():
        return "no verdict table"
    row = read_tsv(verdict_path).iloc[0]
    before, after = float(row["chi2_per_point_before"]), float(row["chi2_per_point_after"])
    if not np.isfinite(after):
        return f"chi2 per point {before:.4g}; 1 is the floor"
    return f"chi2 per point {before:.4g} before, {after:.4g} after the joint refit; 1 is the floor"


def _warnings_block(warnings):
    """Every warning and failure of every stage, in one table at the top of the page; one row per warning, with every
    place it was said (a run's warnings, such as its excitation level or its modes, are said by each variant's
    comparison and diagnosis)."""
    if not warnings:
        return Text("Warnings of the stages: none (notes are where each result is quoted).")
    frame = pd.DataFrame(warnings)
    frame = frame.groupby(["severity", "subject", "message"], sort=False, as_index=False).agg(
        where=("where", "; ".join))[["where", "severity", "subject", "message"]]
    frame = frame.assign(order=frame["severity"].map({"failure": 0, "warning": 1})).sort_values(
        "order", kind="stable").drop(columns="order")
    return Table(frame, f"**{len(frame)} warning(s) and failure(s)** of the stages (each also where its result is "
                        "quoted; a `failure` must not be used as it is).")


def _lead_support(root, run, runs, variant):
    """The other runs' word on this run's lead (`ambid.diagnosis_report.lead_support`), as a paragraph, or ""."""
    verdict = root / f"diagnose/{run}/{variant}/verdict.tsv"
    lead = read_tsv(verdict).iloc[0].get("lead") if verdict.exists() else None
    lead = "" if pd.isna(lead) else lead  # an empty column reads back as NaN (as in the ledger rule)
    rankings = {other: read_tsv(path) for other in runs
                if other != run and (path := root / f"diagnose/{other}/{variant}/candidates.tsv").exists()}
    sentence = lead_support(lead, rankings) if lead else ""
    return f"\n\n{sentence}" if sentence else ""


def _run_disagreements(root, runs, variant, shown=4):
    """A warning per pair of runs whose diagnoses of the last variant determine a parameter differently
    (`ambid.diagnosis_report.run_disagreements`)."""
    joints = {run: read_tsv(path) for run in runs if (path := root / f"diagnose/{run}/{variant}/joint.tsv").exists()}
    out = []
    for (first, second), rows in run_disagreements(joints).groupby(["run_1", "run_2"], sort=False):
        listed = "; ".join(f"`{r.parameter}` {format_value(r.value_1, r.std_1)} against {format_value(r.value_2, r.std_2)}"
                           f" ({r.sigma:.1f} sigma)" for r in rows.head(shown).itertuples())
        more = f"; {len(rows) - shown} more" if len(rows) > shown else ""
        out.append({"where": f"diagnoses of {variant} on {first} and {second}", "severity": "warning",
                    "subject": "the runs disagree",
                    "message": f"{len(rows)} parameter(s) determined by both runs differ beyond {DISAGREEMENT_SIGMA:g} "
                               f"combined standard deviations ({first} against {second}): {listed}{more}. At least one "
                               "run carries a systematic error its uncertainty does not state (a method's bias, such "
                               "as an FRF at a finite excitation level, or a changed operating point); neither value "
                               "is to be taken as it is."})
    return out


def _fit_quality(root, machine, run):
    """Fit quality per channel (chi2 per degree of freedom of the output-error fit) with the fitted order and delay."""
    path = root / f"fit/{run}/models.parquet"
    if not path.exists():
        return Text(f"No fit models for run `{run}`.")
    models, _ = read_parquet(path)
    columns = [c for c in ("output", "input", "order", "cost", "delay_s", "lowpass_rad_s", "dropped") if c in models.columns]
    frame = models[columns].drop_duplicates(["output", "input"]).rename(columns={"cost": "chi2_per_dof"})
    if "lowpass_rad_s" in frame:
        frame = frame.assign(lowpass_hz=frame.pop("lowpass_rad_s") / (2 * np.pi))
    worst = frame.sort_values("chi2_per_dof", ascending=False).head(1)
    text = ("Fit quality per channel: chi2 per degree of freedom of the output-error fit (1: the model explains the "
            "channel to within its uncertainty)")
    text += (f"; worst {worst['output'].iloc[0]}/{worst['input'].iloc[0]} at {worst['chi2_per_dof'].iloc[0]:.3g}."
             if len(worst) else ".")
    return Table(engineering_units(frame), text, f"results/{machine}/fit/{run}/models.parquet")


def machine_report(machine, results_dir, calibration_runs=(), identification_runs=(), variants=("nominal",),
                   updated=False, captions=None, multisine_runs=(), commissioning_runs=()):
    """Sections of the report of one machine, read from the workflow's results.

    Parameters
    ----------
    machine : str
    results_dir : str or Path
        ``results/<machine>``.
    calibration_runs, identification_runs : sequence of str
    variants : sequence of str
        Model variants in configured order (nominal first).
    updated : bool
        Whether the identification runs have an ``update`` stage.
    captions : dict
        Caption templates by name (``workflow/report/<name>.md``).
    multisine_runs : sequence of str
        The identification runs made by multisine (their FRF stage is the BLA).
    commissioning_runs : sequence of str
        The runs with a commissioning view (measured sensitivity, zones, margins, Campbell diagram).

    Returns
    -------
    (str, list of Section)
        The introduction (Markdown) and the sections.
    """
    root, caption = Path(results_dir), _Captions(captions or {}, machine)

    def table(path, text="", metres=()):
        return Table(engineering_units(read_tsv(root / path), metres), text, f"results/{machine}/{path}")

    def warnings_of(path, where):
        """The warnings and failures of a stage's findings, for the summary (notes stay where the result is)."""
        if not (root / path).exists():
            return []
        frame = findings_frame(read_findings(root / path))
        frame = frame[frame["severity"].isin(["warning", "failure"])]
        return [{"where": where, "severity": r.severity, "subject": r.subject, "message": r.message}
                for r in frame.itertuples()]

    warnings = []

    sections = []
    summary = Section("Summary")
    sections.append(summary)
    facts, verdicts = [], []  # the summary's lines, assembled at the end: verdict first, then the figures, then facts
    for run in calibration_runs:
        base = f"calibration/{run}"
        center = read_tsv(root / base / "magnetic_center.tsv")
        facts.append(Text(f"Magnetic center found by calibration run `{run}` [um]: " + ", ".join(
            f"{a} {x * 1e6:+.2f} +- {u * 1e6:.3f}" for a, x, u in
            zip(center["axis"], center["magnetic_center_m"], center["standard_uncertainty_m"])) + "."))
        blocks = [Figure(root / base / "figures/convergence.png", caption("calibration_convergence", run=run)),
                  table(f"{base}/magnetic_center.tsv", "Magnetic center and its standard uncertainty over the repetitions [um]."),
                  table(f"{base}/pairs.tsv", "Rotor position from each bias-current pair [um] (thesis Table 6.2).",
                        metres=("DX", "DY", "NX", "NY", "Z")),
                  table(f"{base}/repeatability.tsv", "Magnetic center of each repetition [um] (thesis Table 6.3).",
                        metres=("DX", "DY", "NX", "NY", "Z")),
                  table(f"{base}/stiffness.tsv", "Current and position stiffness at the magnetic center and at the "
                                                 "geometric center (thesis eq. 3.5-3.6).")]
        if (root / base / "sensitivity.tsv").exists():
            blocks.append(table(f"{base}/sensitivity.tsv", "The calibration run with wrong method parameters, scored "
                                                           "against the virtual rig's truth [um] (beyond the thesis)."))
        sections.append(Section(f"Calibration {run} (thesis ch. 3, 6.1)", blocks))
    if multisine_runs:
        sections.append(Section("Identification methods: stepped sine and multisine (beyond the thesis)", [
            Text(caption("methods")),
            table("methods/comparison.tsv", "Machine time and the median relative noise and systematic standard "
                                            "deviations of the radial diagonal FRFs per band, per run."),
            Figure(root / "methods/figures/methods.png", caption("methods_figure"))]))
    for run in identification_runs:
        base = f"frf/{run}"
        if run in multisine_runs:
            sections.append(Section(f"Identification {run} (multisine BLA, beyond the thesis)", [
                table(f"{base}/plausibility.tsv", PLAUSIBILITY_CAPTION + " The multisine run is read through its BLA: "
                                                  "its compliance and coil-current FRF.")] + [
                Figure(root / base / f"figures/{name}.png", caption("frf", run=run)) for name in ("radial_mimo", "axial")]
                + [Figure(root / base / "figures/distortion.png", caption("distortion", run=run)),
                   table(f"{base}/distortion.tsv", "Output at the excited, odd-detection and even-detection lines of "
                                                   "the coarse pass (rms per line [um]) and their ratios [dB].")]))
        else:
            floors = read_tsv(root / base / "floor.tsv")
            pooled = int(floors["noise_pooled_steps"].max()) if len(floors) and "noise_pooled_steps" in floors else 1
            warnings += warnings_of(f"{base}/findings.tsv", f"identification {run}")
            facts.append(Text(
                f"Floor of run `{run}` (the uncertainty beyond the noise that every chi-square divides by): "
                + "; ".join(f"{family} {', '.join(sorted(set(part['method'])))}"
                            for family, part in floors.groupby("family", sort=False))
                + (f"; each step's noise pooled over {pooled} steps" if pooled > 1 else "")
                + ("; no step repeated at a lower amplitude, so the FRF is the describing function at the excitation "
                   "amplitude, with the force law's amplitude-dependent error in it (see the run's findings)"
                   if "no_repeats" in set(findings_frame(read_findings(root / base / "findings.tsv"))["code"]) else "")
                + "."))
            sections.append(Section(f"Identification {run} (thesis ch. 4, 6.2)", [
                table(f"{base}/plausibility.tsv", PLAUSIBILITY_CAPTION),
                _findings(root, f"{base}/findings.tsv", machine,
                          f"the log of run `{run}` (outlier steps before the FRF, how its floor was measured)")] + [
                Figure(root / base / f"figures/{name}.png", caption("frf", run=run))
                for name in ("radial_siso", "radial_mimo", "axial")] + [
                table(f"{base}/floor.tsv",
                      "The FRF's systematic floor per channel family and band and how it was measured: `two_level` "
                      "from steps repeated at a lower amplitude (the force law's amplitude-dependent error), "
                      "`smooth_fit` from the scatter between neighbouring steps beyond the noise, `fallback` the "
                      "documented constant (config `frf.fallback_floor`) where the data cannot tell; "
                      "`zero_amplitude` (config `frf.zero_amplitude`, on by default): `zero_amplitude_points` points of the "
                      "band hold the FRF extrapolated to zero amplitude from the repeats, where that is more accurate "
                      "than the measured value with its floor, their systematic_std the interpolation's error; "
                      "`relative_median` / `relative_p90` of systematic_std / |G|, `noise_relative_median` of the "
                      "noise std / |G| where the response stands out of it (the floor far above it hides what the "
                      "noise would show), `noise_scale` where the scatter "
                      "shows the logged noise overstated; `noise_pooled_steps`: each step's logged noise is the mean "
                      "over that many neighbouring steps (config `frf.noise_half_width`), since a step's own estimate "
                      "from the two DFT lines beside its excitation line would weight chi-square twice too high on "
                      "average.")]))
        features = read_tsv(root / f"fit/{run}/features.tsv")
        features = features[(features["estimator"] == "output_error")
                            & features["kind"].isin(["resonance", "anti_resonance"])]
        warnings += warnings_of(f"fit/{run}/findings.tsv", f"parametric fit {run}")
        sections.append(Section(f"Parametric fit {run} (thesis ch. 5.1)", [
            _findings(root, f"fit/{run}/findings.tsv", machine, f"the fit of run `{run}` (flagged features stay out of "
                      "the model update)"),
            _fit_quality(root, machine, run),
            Table(features.drop(columns=["estimator"]), "Resonances (poles) and anti-resonances (zeros) of every fitted "
                  "channel with their standard uncertainties (the measured columns of thesis Table 6.4 / 5.2).",
                  f"results/{machine}/fit/{run}/features.tsv"),
            Figure(root / f"fit/{run}/figures/bode_fit.png", caption("fit_bode", run=run)),
            Figure(root / f"fit/{run}/figures/stabilization.png", caption("fit_stabilization", run=run))]))
        if updated:
            base = f"update/{run}"
            comparison = read_tsv(root / base / "comparison.tsv")
            variables = read_tsv(root / base / "variables.tsv")
            undetermined = int((~variables["determined"].astype(bool)).sum())
            caveat = update_caveat(undetermined, len(variables))
            first = comparison[(comparison["quantity"] == "frequency") & (comparison["root"] == "pole")].head(1)
            for _, row in first.iterrows():
                facts.append(Text(
                    f"First flexible resonance in run `{run}`: measured {row['measured']:.1f} +- {row['measured_std']:.2g} Hz, "
                    f"nominal model {row['original']:.1f} Hz ({row['original_error_pct']:.1f} % off), updated model "
                    f"{row['updated']:.1f} Hz ({row['error_pct']:.2f} % off){caveat}"))
            sections.append(Section(f"Model update {run} (thesis ch. 5.2-5.3, 6.3)", [
                table(f"{base}/comparison.tsv", "Measured features against the original and the updated model "
                                                "(thesis Tables 6.4 and 6.5; reference rotor: Tables 5.2 and 5.3). "
                                                "`measured` is what the update matched: the fit's value less "
                                                "`estimator_bias`, what the fit's estimator gets wrong on the updated "
                                                "model's own FRF (README \"Rotor model update\")."),
                Text(f"**{undetermined} of {len(variables)} update variables are not determined by the data**: their "
                     "updated values are not measurements (hatched in the figure below)." if undetermined else
                     f"All {len(variables)} update variables are determined by the data."),
                *_feature_fit_text(variables),
                *_valley_text(variables),
                *_mode_shape_text(root / base / "mode_shapes.tsv"),
                table(f"{base}/variables.tsv", "Design variables: start, updated value, standard uncertainty and "
                                               "resolution; `determined` is False where the data cannot fix a value, "
                                               "`valley_shift` is how far a value moves (log of the factor) when the "
                                               "undetermined modulus `valley_variable` is moved by up to a factor e "
                                               "(the fit as good); `std_scale` is the factor every uncertainty is "
                                               "scaled by where the features are not matched within theirs."),
                Figure(root / base / "figures/bode_update.png", caption("update_bode", run=run)),
                Figure(root / base / "figures/youngs_modulus.png", caption("update_modulus", run=run)),
                Figure(root / base / "figures/convergence.png", caption("update_convergence", run=run))]))
    for run in commissioning_runs:
        base = f"commissioning/{run}"
        sensitivity = read_tsv(root / base / "sensitivity.tsv")
        measured = sensitivity[sensitivity["source"] == "measured"]
        notes = sorted(set(measured["note"].dropna())) if "note" in measured else []
        if (measured["iso_14839_zone"] == "not graded").any():
            facts.append(Text(f"Measured sensitivity of run `{run}` **not graded** (ISO 14839-3): {'; '.join(notes)}."))
        else:
            facts.append(Text(f"Measured sensitivity peak per axis (run `{run}`, ISO 14839-3 zone): " + ", ".join(
                f"{r.axis} {r.sensitivity_peak_db:.1f} dB at {r.sensitivity_peak_hz:.0f} Hz (zone {r.iso_14839_zone})"
                for r in measured.itertuples()) + "." + (f" Margins not given: {'; '.join(notes)}." if notes else "")))
        sections.append(Section(f"Commissioning view {run} (ISO 14839-3, beyond the thesis)", [
            Text(caption("commissioning", run=run)),
            Figure(root / base / "figures/sensitivity.png", caption("commissioning_sensitivity", run=run)),
            table(f"{base}/sensitivity.tsv", "Sensitivity peak, ISO 14839-3 zone (A < 9.5 dB, B < 12 dB, C < 14 dB, D "
                                             "above) and the margins of the loop gain L = 1/S - 1 per axis: measured, "
                                             "and each model on the measured frequencies and from 1 Hz to Nyquist. An "
                                             "empty margin: no crossing on that grid (for the measurement: not within "
                                             "the measured band)."),
            Figure(root / base / "figures/campbell.png", caption("campbell", run=run)),
            Figure(root / base / "figures/levitated_modes.png", caption("levitated_modes", run=run))]))
    model = Section("Model variants", [Text(caption("variants"))])
    sections.append(model)
    for variant in variants:
        base = f"model/{variant}"
        blocks = [table(f"{base}/stability.tsv", "Closed-loop stability of the model variant per axis "
                                                 "(spectral radius, sensitivity peak, ISO 14839-3 zone)."),
                  Figure(root / base / "figures/plant_bode.png", caption("plant_bode", variant=variant)),
                  Figure(root / base / "figures/axial_bode.png", caption("plant_bode", variant=variant))]
        if variant == variants[0]:
            blocks.append(Figure(root / base / "figures/mode_shapes.png", caption("mode_shapes", variant=variant)))
        sections.append(Section(f"Model {variant}", blocks, level=3))
    if identification_runs:
        ledger = read_tsv(root / "ledger/ledger.tsv")
        overall = ledger[ledger["output"] == "all"].drop(columns=["machine", "output", "input"])
        verdicts.append(Figure(root / "ledger/figures/ledger.png", caption("ledger")))
        if (root / "ledger/figures/excess_maps.png").exists():
            verdicts.append(Figure(root / "ledger/figures/excess_maps.png", caption("excess_maps")))
        facts.append(Table(overall, "Misfit of every model variant over every measured channel (chi2 per point; "
                                    "excess over the floor of 1).", f"results/{machine}/ledger/ledger.tsv"))
        sections.append(Section("Diagnosis loop (beyond the thesis)", [
            Text(caption("diagnosis_loop") + "\n\nThe ledger and the misfit maps of every variant are in the "
                 "Summary above; the comparison and diagnosis of each variant follow.")]))
    for run in identification_runs:
        for variant in variants:
            compare, diagnose = f"compare/{run}/{variant}", f"diagnose/{run}/{variant}"
            diagnosis = (root / diagnose / "diagnosis.md").read_text()
            warnings += warnings_of(f"{compare}/findings.tsv", f"{variant} against {run}")
            if variant == variants[-1]:
                warnings += warnings_of(f"{diagnose}/findings.tsv", f"diagnosis of {variant} on {run}")
                verdicts.insert(0, Text(f"**Diagnosis of the last variant, `{variant}`, on run `{run}`** "
                                        f"({_misfit_change(root / diagnose / 'verdict.tsv')}):\n\n"
                                        + verdict_markdown(diagnosis) + _lead_support(root, run, identification_runs, variant)))
            sections.append(Section(f"{variant} against {run}", [
                Figure(root / compare / "figures/bode_compare.png", caption("compare_bode", run=run, variant=variant)),
                Figure(root / compare / "figures/error_map.png", caption("compare_error_map", run=run, variant=variant)),
                _findings(root, f"{compare}/findings.tsv", machine, f"the comparison of `{variant}` with run `{run}`"),
                Text(caption("diagnosis", run=run, variant=variant)),
                _findings(root, f"{diagnose}/findings.tsv", machine,
                          f"the diagnosis of `{variant}` on run `{run}` (effects missing, parameters the data move, at a "
                          "bound or undetermined, misfit no effect explains)"),
                Text(diagnosis),
                Figure(root / diagnose / "figures/fingerprint.png",
                       caption("diagnose_fingerprint", run=run, variant=variant))], level=3))
    warnings += _run_disagreements(root, identification_runs, variants[-1])
    summary.blocks = verdicts + [_warnings_block(warnings)] + facts
    introduction = caption("introduction")
    return introduction, sections
