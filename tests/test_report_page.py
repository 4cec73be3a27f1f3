"""The report page as a browser reads it: navigation, alt text, nothing fetched, tables that scroll, nothing wider
than the page; the engineering units and the summary's verdict helpers.  Rendered from a small fixture (no workflow)."""

import re
from html.parser import HTMLParser

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402

from ambid.diagnosis_report import lead_support, run_disagreements, share_text  # noqa: E402
from ambid.plots import excess_maps, phase_deg, phase_near, save_figure  # noqa: E402
from ambid.report import (Figure, Section, Table, Text, _lead_support, _run_disagreements, _valley_text,  # noqa: E402
                          engineering_units, render_report, update_caveat, verdict_markdown)


class Page(HTMLParser):
    """Every start tag with its attributes and the chain of open tags above it."""

    VOID = {"img", "meta", "br", "hr", "link", "input"}

    def __init__(self):
        super().__init__()
        self.tags, self.stack = [], []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs), tuple(self.stack)))
        if tag not in self.VOID:
            self.stack.append((tag, dict(attrs).get("class", "")))

    def handle_endtag(self, tag):
        while self.stack:
            if self.stack.pop()[0] == tag:
                break


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    figure, axis = plt.subplots(figsize=(3, 2))
    axis.plot([0, 1], [0, 1])
    save_figure(figure, root / "plot.png", dpi=40)
    wide = pd.DataFrame({f"column_{k}_m": np.linspace(1e-6, 2e-6, 3) for k in range(30)})
    sections = [Section("Summary", [Text("**Missing: `delay` (delay_s = 1.2e-05 +- 3e-07)**."),
                                    Figure(root / "plot.png", "The ledger of every variant. More text.")]),
                Section("Model variants", [Text("| a | b |\n|---|---|\n| 1 | 2 |")]),
                Section("Model nominal", [Table(wide, "A wide table [um].", "results/x/wide.tsv"),
                                          Figure(root / "plot.png", "")], level=3),
                Section("Model delay", [Text("Nothing.")], level=3)]
    text = render_report("ambid report: fixture", sections, "Introduction.")
    parser = Page()
    parser.feed(text)
    return text, parser.tags


def test_navigation_lists_every_section_and_its_variants(page):
    text, tags = page
    nav = [t for t in tags if t[0] == "nav"]
    assert len(nav) == 1 and "contents" in nav[0][1].get("class", "")
    links = [a["href"] for tag, a, stack in tags if tag == "a" and any(s[0] == "nav" for s in stack)]
    ids = {a["id"] for _, a, _ in tags if "id" in a}
    assert links == ["#summary", "#model-variants", "#model-nominal", "#model-delay"] and set(l[1:] for l in links) <= ids
    # the variants are nested under their stage in the contents
    nested = [a["href"] for tag, a, stack in tags if tag == "a" and [s[0] for s in stack].count("ul") == 2]
    assert nested == ["#model-nominal", "#model-delay"]
    assert "position: sticky" in text  # the contents stay on screen
    assert sum(t[0] == "details" for t in tags) == 4  # every section folds away


def test_every_image_has_alt_text_and_is_embedded(page):
    _, tags = page
    images = [a for tag, a, _ in tags if tag == "img"]
    assert len(images) == 2
    assert all(a.get("alt", "").strip() for a in images)
    assert images[0]["alt"] == "The ledger of every variant."
    assert all(a["src"].startswith("data:image/png;base64,") for a in images)


def test_nothing_is_fetched_and_nothing_runs(page):
    text, tags = page
    for tag, attributes, _ in tags:
        for name in ("src", "href"):
            value = attributes.get(name, "")
            assert not re.match(r"\s*(https?:)?//", value), (tag, value)
    assert not any(tag in ("script", "link", "iframe") for tag, _, _ in tags)
    assert "@import" not in text and "url(" not in text


def test_tables_scroll_inside_themselves_and_nothing_is_wider_than_the_page(page):
    text, tags = page
    tables = [stack for tag, _, stack in tags if tag == "table"]
    assert len(tables) == 2 and all(stack[-1] == ("div", "scroll") for stack in tables)
    assert re.search(r"\.scroll\s*\{[^}]*overflow-x:\s*auto", text)
    style = text.split("<style>", 1)[1].split("</style>", 1)[0]
    # no fixed width beyond a page: every width in px is small, images shrink to their container
    assert all(int(w) <= 1500 for w in re.findall(r"(?<![-\w])(?:min-)?width:\s*(\d+)px", style))
    assert re.search(r"figure img\s*\{[^}]*max-width:\s*100%", style)
    assert not any("width" in a or "style" in a for tag, a, _ in tags if tag in ("table", "img", "div", "figure"))


def test_the_page_is_the_same_bytes_twice(tmp_path):
    pages = []
    for name in ("a", "b"):
        figure, axis = plt.subplots(figsize=(3, 2))
        axis.plot([0, 1], [0, 1])
        save_figure(figure, tmp_path / f"{name}.png", dpi=40)
        sections = [Section("Summary", [Figure(tmp_path / f"{name}.png", "A figure."),
                                        Table(pd.DataFrame({"x_m": [1e-6]}), "A table.")])]
        pages.append(render_report("t", sections, "i"))
    assert pages[0] == pages[1]


def test_engineering_units():
    frame = pd.DataFrame({"axis": ["DX"], "magnetic_center_m": [6.174e-05], "delay_s": [1.2e-4], "time_s": [60.0],
                          "youngs_modulus_pa": [2.0e11], "stiffness_n_per_m": [6.2e5], "DY": [1.358e-05],
                          "frequency_hz": [658.3]})
    out = engineering_units(frame, metres=("DY",))
    assert list(out.columns) == ["axis", "magnetic_center_um", "delay_us", "time_s", "youngs_modulus_gpa",
                                 "stiffness_n_per_um", "DY [um]", "frequency_hz"]
    assert out.iloc[0, 1:].tolist() == pytest.approx([61.74, 120.0, 60.0, 200.0, 0.62, 13.58, 658.3])


def test_the_summary_says_what_it_does_not_know():
    assert "none of the 14 update variables is determined" in update_caveat(14, 14)
    assert "3 of the 14" in update_caveat(3, 14) and update_caveat(0, 14) == "."
    assert share_text(-3.45) == "none (worse than without it)" and share_text(0.232) == "23.2 %"
    markdown = ("# Diagnosis: m\n\n**Missing: `delay` (delay_s = 1.2e-05 +- 3e-07)**.\n\nChosen one after the other.\n\n"
                "**The data move parameters**:\n\n- `a`: 1 -> 2 +- 0.1\n\nSet them where the variant takes them.\n\n"
                "## Fingerprint\n\n- more")
    verdict = verdict_markdown(markdown)
    assert "delay_s = 1.2e-05 +- 3e-07" in verdict and "- `a`: 1 -> 2 +- 0.1" in verdict
    assert "Set them" not in verdict and "Fingerprint" not in verdict and "# Diagnosis" not in verdict


def test_phase_has_no_wrap_strokes():
    frequency = np.linspace(1, 100, 400)
    values = -np.exp(-2j * np.pi * frequency * 0.1)  # a negative stiffness and a delay: the phase wraps ten times
    phase = phase_deg(values)
    assert phase.size == frequency.size and np.all(np.abs(np.diff(phase)) < 180)  # continuous: no +-180 strokes
    assert phase[0] == pytest.approx(-180 - 36, abs=1e-6)  # starts on the -180 deg branch of an AMB plant
    assert phase[-1] - phase[0] == pytest.approx(-360 * 0.1 * 99, abs=1e-6)
    assert phase_deg(np.array([1 + 0.01j]))[0] == pytest.approx(np.degrees(0.01), rel=1e-3)  # a plain response at 0
    # measured points follow the model's branch: 350 deg below on their own, 10 deg above the model here
    assert phase_near(np.exp(1j * np.radians(-350.0)), -20.0) == pytest.approx(10.0)


def test_excess_maps_share_one_scale_and_hatch_what_is_not_measured(tmp_path):
    rows = [("DX", "DX", "1-100 Hz", 30, 5.0), ("DX", "DX", "100-750 Hz", 40, 2e4), ("Z", "Z", "1-50 Hz", 10, 0.5)]
    first = pd.DataFrame(rows, columns=["output", "input", "band", "points", "chi2"])
    second = first.assign(chi2=first["chi2"] / 100)
    figure = excess_maps({"nominal": first, "delay": second}, "maps")
    meshes = [c for axis in figure.axes[:2] for c in axis.collections]
    assert {(m.norm.vmin, m.norm.vmax) for m in meshes} == {(0.1, 1e4)}  # one fixed scale, whatever the values
    hatched = [p for p in figure.axes[0].patches if p.get_hatch()]
    assert hatched  # not measured (Z above 50 Hz, DX below... ) is hatched, not white
    save_figure(figure, tmp_path / "maps.png", dpi=40)


def test_runs_that_disagree_beyond_their_uncertainty_are_named(tmp_path):
    """Two runs' joint refits of the same variant: a parameter both determine, 6 sigma apart, is a warning in the
    summary; one within its uncertainty, one undetermined in a run and an empty joint table are not."""
    joint = lambda rows: pd.DataFrame(rows, columns=["parameter", "value", "std", "determined"])  # noqa: E731
    joints = {"ident01": joint([("delay.delay_s", 60e-6, 3e-8, True), ("bias[0]", 1.0095, 1.3e-4, True),
                                ("scale[0]", 0.8, 0.1, True)]),
              "ms01": joint([("delay.delay_s", 60.05e-6, 4e-8, True), ("bias[0]", 1.0183, 1.45e-3, True),
                             ("scale[0]", 2.0, 0.1, False)]),
              "empty": joint([])}
    found = run_disagreements(joints)
    assert list(found["parameter"]) == ["bias[0]"] and found["sigma"].iloc[0] == pytest.approx(6.045, abs=0.001)
    assert run_disagreements(joints, threshold=0.5)["parameter"].tolist() == ["bias[0]", "delay.delay_s"]
    for run, frame in joints.items():
        (tmp_path / f"diagnose/{run}/last").mkdir(parents=True)
        frame.to_csv(tmp_path / f"diagnose/{run}/last/joint.tsv", sep="\t", index=False)
    (warning,) = _run_disagreements(tmp_path, ["ident01", "ms01", "empty"], "last")
    assert warning["where"] == "diagnoses of last on ident01 and ms01" and warning["severity"] == "warning"
    assert "`bias[0]` 1.0095 +- 0.00013 against 1.0183 +- 0.0014 (6.0 sigma)" in warning["message"]


def test_a_lead_is_checked_against_the_other_runs(tmp_path):
    """ident01's lead (within its floor) against ms01's and ms02's fits of the same candidate on the same variant: one
    gives it no support, one supports it; a run without the candidate says so; a run without a lead says nothing."""
    ranking = lambda rows: pd.DataFrame(rows, columns=["candidate", "evidence_bic", "significant"])  # noqa: E731
    rankings = {"ms01": ranking([("foundation_mode", -20.48, False), ("delay", 3.0, False)]),
                "ms02": ranking([("foundation_mode", 140.0, True)]), "old": ranking([("delay", 1.0, False)])}
    sentence = lead_support("foundation_mode", rankings)
    assert "run `ms01` does not support it (its best fit earns BIC evidence -20.5)" in sentence
    assert "run `ms02` supports it (its best fit earns BIC evidence 140)" in sentence
    assert "run `old` did not try it" in sentence and lead_support("foundation_mode", {}) == ""
    for run, lead in (("ident01", "foundation_mode"), ("ms01", "")):
        (tmp_path / f"diagnose/{run}/last").mkdir(parents=True)
        pd.DataFrame([{"verdict": "nothing", "effects": "", "lead": lead}]).to_csv(
            tmp_path / f"diagnose/{run}/last/verdict.tsv", sep="\t", index=False)
        rankings["ms01" if run == "ms01" else "ms02"].to_csv(tmp_path / f"diagnose/{run}/last/candidates.tsv", sep="\t",
                                                            index=False)
    text = _lead_support(tmp_path, "ident01", ["ident01", "ms01"], "last")
    assert text.startswith("\n\nThe lead `foundation_mode` on the other runs of this variant: run `ms01` does not support it")
    assert _lead_support(tmp_path, "ms01", ["ident01", "ms01"], "last") == ""


def test_minor_log_grid_is_drawn_once_per_line_where_it_is_on(tmp_path):
    """`save_figure` draws the minor grid of a log axis as one line collection at the minor tick positions (2-9 of
    each decade) in the grid's style, and leaves a linear axis and an axis without a minor grid alone."""
    figure, (log_axis, plain_axis) = plt.subplots(2)
    log_axis.semilogx([1.0, 1000.0], [0.0, 1.0])
    log_axis.set_xlim(1.0, 1000.0)
    log_axis.grid(True, which="both", color="0.8", linewidth=0.4)
    plain_axis.semilogx([1.0, 1000.0], [0.0, 1.0])
    plain_axis.grid(True, which="major")  # no minor grid asked for: the minor ticks stay matplotlib's
    before = plain_axis.xaxis.get_minor_locator()
    save_figure(figure, tmp_path / "grid.png", dpi=40)
    grids = [c for c in log_axis.collections if isinstance(c, matplotlib.collections.LineCollection)]
    assert len(grids) == 1
    positions = sorted(segment[0, 0] for segment in grids[0].get_segments())
    expected = sorted(m * 10.0**d for d in range(3) for m in range(2, 10))
    assert positions == pytest.approx(expected)
    assert matplotlib.colors.to_hex(grids[0].get_colors()[0]) == matplotlib.colors.to_hex("0.8")
    assert grids[0].get_linewidths()[0] == pytest.approx(0.4)
    assert isinstance(log_axis.xaxis.get_minor_locator(), matplotlib.ticker.NullLocator)  # no tick per line
    assert not [c for c in plain_axis.collections if isinstance(c, matplotlib.collections.LineCollection)]
    assert plain_axis.xaxis.get_minor_locator() is before


def test_the_update_section_names_what_is_determined_only_near_the_solution():
    """A modulus of resolution >= 0.9 that the valley check undetermined is named with its factor and the modulus
    that moved it; a determined one and one the data do not see are not; a table from before the check says nothing."""
    variables = pd.DataFrame({"variable": ["E design[0]", "E design[1]", "E design[3]"], "resolution": [0.005, 0.97, 0.999],
                              "valley_shift": [np.nan, 0.326, 0.069], "valley_variable": ["", "E design[2]", "E design[2]"],
                              "determined": [False, False, True]})
    (text,) = _valley_text(variables)
    assert "E design[1] moves by a factor 1.39 when E design[2] is moved" in text.markdown
    assert "E design[3]" not in text.markdown and "E design[0]" not in text.markdown
    assert _valley_text(variables.drop(columns=["valley_shift", "valley_variable"])) == []
    assert _valley_text(variables.assign(determined=[False, True, True])) == []
