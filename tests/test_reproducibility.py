"""The whole workflow, twice from clean on a small configuration: the same bytes; then what a change re-runs.

The read-only checks of single stages (the model's default target, the calibration stage, the identification log)
read the second run's files too: one run serves them all (``tests/conftest.py`` keeps this module on one worker).
"""

import json
import re
import shutil

import pytest
import yaml

from ambid.io import read_parquet
from test_workflow import ROOT, demo20_on_its_rig, edit_as_built, edit_config, snakemake

pytestmark = pytest.mark.workflow

ROOT_FILES = ("results", "data")


def small_configuration(config):
    """demo20 on its rig, every stage, with a shorter calibration and a one-step diagnosis."""
    config["machines"] = {"demo20": config["machines"]["demo20"]}
    demo20_on_its_rig(config)
    config["calibration"].update(repetitions=2, average_s=0.3)
    config["diagnose"]["sequence_length"] = 1


def coarser_grid(as_built):
    """The identification planned on 120 + 40 steps from 5 Hz (the rig's as-built drawing: 250 + 100 from 1 Hz)."""
    as_built["frequency_grid"] = {"radial": {"start_hz": 5.0, "stop_hz": 1000.0, "points": 120},
                                  "axial": {"start_hz": 5.0, "stop_hz": 100.0, "points": 40}}


def job_counts(output):
    """Rule -> number of jobs from the 'Job stats' table of a dry run (empty when there is nothing to be done)."""
    if "Job stats:" not in output:
        return {}
    table = output.split("Job stats:", 1)[1].split("total", 1)[0]
    return {rule: int(count) for rule, count in re.findall(r"^(\w+)\s+(\d+)\s*$", table, re.M)}


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    """The small configuration run from clean in two directories."""
    directories = []
    for name in ("first", "second"):
        workdir = tmp_path_factory.mktemp(name)
        shutil.copytree(ROOT / "config", workdir / "config")
        edit_config(workdir, small_configuration)
        edit_as_built(workdir, "demo20", coarser_grid)
        result = snakemake(workdir, "--cores", "2")
        assert result.returncode == 0, result.stderr[-3000:]
        directories.append(workdir)
    return directories


def test_two_clean_runs_give_the_same_bytes(two_runs):
    first, second = two_runs
    files = sorted(p.relative_to(first) for top in ROOT_FILES for p in (first / top).rglob("*") if p.is_file())
    assert {p.suffix for p in files} >= {".parquet", ".tsv", ".png", ".html", ".yaml", ".md", ".m", ".uff"}
    assert "results/demo20/report.html" in {str(p) for p in files}
    assert files == sorted(p.relative_to(second) for top in ROOT_FILES for p in (second / top).rglob("*") if p.is_file())
    different = [str(p) for p in files if (first / p).read_bytes() != (second / p).read_bytes()]
    assert different == []


def test_second_run_does_nothing_and_a_model_change_reruns_only_downstream(two_runs):
    workdir = two_runs[0]
    again = snakemake(workdir, "--dry-run")
    assert again.returncode == 0 and "Nothing to be done" in again.stdout + again.stderr
    path = workdir / "config/machines/demo20.yaml"
    machine = yaml.safe_load(path.read_text())
    machine["materials"]["steel"]["youngs_modulus_pa"] *= 0.98  # one model parameter
    path.write_text(yaml.safe_dump(machine))
    dry = snakemake(workdir, "--dry-run")
    assert dry.returncode == 0, dry.stderr[-3000:]
    jobs = job_counts(dry.stdout + dry.stderr)
    # the measurements do not depend on the model: the rig is planned with its as-built drawing
    assert not {"acquire_calibration", "acquire_identification"} & set(jobs), jobs
    # everything that reads the machine file (the log's check against the model, and the FRF made only of a log that
    # passed it), and what follows from it
    assert set(jobs) == {"plausibility", "frf", "calibrate", "calibration_sensitivity", "fit", "export", "update",
                         "variant", "model", "commissioning", "compare", "diagnose", "ledger", "report", "all"}, jobs


def test_the_report_covers_every_stage_with_thesis_references(two_runs):
    page = (two_runs[0] / "results/demo20/report.html").read_text()
    for title in ("Summary", "Calibration cal01", "Identification ident01", "Parametric fit ident01",
                  "Model update ident01", "Model variants", "Diagnosis loop", "updated against ident01"):
        assert f">{title}" in page, title
    for reference in ("Fig. 6.2", "Table 6.3", "Fig. 6.3", "Fig. 6.6", "Fig. 6.8", "Fig. 6.9", "Table 6.4"):
        assert reference in page, reference
    figures = page.count('src="data:image/png;base64,')
    # embedded, nothing fetched (the embedded figures' base64 may spell "http" by chance: look outside them)
    body = re.sub(r'data:image/png;base64,[A-Za-z0-9+/=]+', "", page.split("<body>", 1)[1])
    assert figures >= 20 and "http" not in body
    assert "<strong>Missing" in page or "Nothing is missing at the floor" in page or "Unexplained misfit" in page  # rendered
    # where the log and the fit are quoted: the checks against the model and the findings (none on this run)
    assert "The log against the nominal model" in page and "Findings of the log of run <code>ident01</code>" in page
    assert "Findings of the fit of run <code>ident01</code>" in page


def test_the_model_stage_writes_its_units_and_figures(two_runs):
    workdir = two_runs[1]
    frame, info = read_parquet(workdir / "results/demo20/model/nominal/plant_frf.parquet", kind="plant_frf")
    assert info["units"] == {"frequency_hz": "Hz", "im": "m/A", "re": "m/A"}
    assert set(frame["output"]) == {"DX", "DY", "NX", "NY", "Z"}
    assert len(frame) == 16 * 250 + 100  # 4x4 radial on the model's 250 points plus Z on 100
    modes = (workdir / "results/demo20/model/nominal/modes.tsv").read_text()
    assert "rigid" in modes and "flexible" in modes
    for figure in ("plant_bode", "axial_bode", "mode_shapes"):
        assert (workdir / f"results/demo20/model/nominal/figures/{figure}.png").stat().st_size > 10_000
    assert "ISO 14839-3 zone" in (workdir / "logs/demo20/model_nominal.log").read_text()
    again = snakemake(workdir, "results/demo20/model/nominal/plant_frf.parquet", "--dry-run")
    assert again.returncode == 0 and "Nothing to be done" in again.stdout + again.stderr


def test_calibration_stage_from_log_to_operating_point(two_runs):
    workdir = two_runs[1]
    base = workdir / "results/demo20/calibration/cal01"
    for name in ("magnetic_center.tsv", "offsets.tsv", "pairs.tsv", "repeatability.tsv", "stiffness.tsv",
                 "figures/convergence.png"):
        assert (base / name).exists(), name
    assert (workdir / "data/demo20/cal01/calibration.parquet").exists()
    # the fragment merges into the machine config and the model linearizes there
    fragment = yaml.safe_load((base / "operating_point.yaml").read_text())
    machine = yaml.safe_load((workdir / "config/machines/demo20.yaml").read_text())
    machine["bearings"]["radial"]["operating_point"] = fragment["bearings"]["radial"]["operating_point"]
    from ambid.machine import machine_from_config
    from ambid.plant import Plant

    Plant(machine_from_config(machine))
    log = (workdir / "logs/demo20/acquire_calibration_cal01.log").read_text()
    assert "iteration 1, repetition 1: offsets" in log and "(converged)" in log


def test_the_identification_log_is_the_rig_run_and_hides_its_truth(two_runs):
    """The acquisition's log (its bytes the same in both runs: `test_two_clean_runs_give_the_same_bytes`)."""
    workdir = two_runs[1]
    frame, info = read_parquet(workdir / "data/demo20/ident01/identification.parquet", kind="identification_log")
    assert set(frame["excited_axis"]) == {"DX", "DY", "NX", "NY", "Z"} and info["metadata"]["seed"] == 1
    assert set(frame.loc[frame["excited_axis"] == "Z", "step"]) == set(range(40))  # the as-built drawing's grid
    assert "truth" not in json.dumps(info["metadata"])  # the log does not leak the rig's truth
    assert (workdir / "data/demo20/ident01/identification.m").stat().st_size > 0
    progress = (workdir / "logs/demo20/acquire_identification_ident01.log").read_text()
    assert "steps accepted: DX" in progress and "Z 40/40" in progress


def test_markdown_is_escaped():
    from ambid.report import markdown_html

    html = markdown_html("# T\n\n**bold** and `code` <script>x</script>\n\n| a | b |\n|---|---|\n| 1 | 2 |\n")
    assert "<h3>T</h3>" in html and "<strong>bold</strong>" in html and "<code>code</code>" in html
    assert "<script>" not in html and "&lt;script&gt;" in html and "<td>1</td>" in html
