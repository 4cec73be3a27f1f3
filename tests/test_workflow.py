"""The Snakemake workflow, run as a user would (subprocesses on a copy of the config)."""

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from ambid.io import read_parquet

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]

pytestmark = pytest.mark.workflow


def snakemake(workdir, *args, snakefile=ROOT / "Snakefile"):
    return subprocess.run(
        [*SNAKEMAKE, "-s", str(snakefile), "-d", str(workdir), "--cores", "1", *args],
        capture_output=True,
        text=True,
        timeout=600,
    )


EXAMPLE_LOG = "data/demo20/thesis01/identification.m"  # shipped with the repository


@pytest.fixture
def workdir(tmp_path):
    """A user's working directory: the config and the shipped example log."""
    shutil.copytree(ROOT / "config", tmp_path / "config")
    (tmp_path / EXAMPLE_LOG).parent.mkdir(parents=True)
    shutil.copy(ROOT / EXAMPLE_LOG, tmp_path / EXAMPLE_LOG)
    return tmp_path


def edit_yaml(path, change):
    """Apply ``change`` to the YAML file at ``path`` in place."""
    content = yaml.safe_load(path.read_text())
    change(content)
    path.write_text(yaml.safe_dump(content))


def edit_config(workdir, change):
    edit_yaml(workdir / "config" / "config.yaml", change)


def demo20_on_its_rig(config):
    """demo20 measured on its virtual rig: a calibration run and an identification at the center it finds."""
    config["machines"]["demo20"].update(
        runs={"cal01": {"kind": "calibration", "source": "rig", "seed": 2},
              "ident01": {"kind": "identification", "source": "rig", "seed": 1, "calibration": "cal01"}},
        operating_point="cal01", variants={"updated": {"update": "ident01"}})


def edit_machine(workdir, name, change):
    edit_yaml(workdir / "config" / "machines" / f"{name}.yaml", change)


def edit_as_built(workdir, name, change):
    """Edit the drawing of machine ``name`` as built, which its rig's acquisition runs are planned with."""
    edit_yaml(workdir / "config" / "rigs" / f"{name}.as_built.yaml", change)


@pytest.mark.parametrize(
    "change, key",
    [
        (lambda c: c["rotor"]["elements"][0].update(length_m=-0.01), "length_m"),
        (lambda c: c["rotor"]["elements"][0].update(material="unobtainium"), "rotor.elements[0].material"),
        (lambda c: c.update(effects=[{"name": "warp_drive"}]), "warp_drive"),
        (lambda c: c["rotor"].update(colour="red"), "colour"),
        (lambda c: c["materials"].update(copper=c["materials"].pop("steel")), "unknown material 'steel'"),
        (lambda c: c["materials"].clear(), "config/machines/demo20.yaml: materials: {} should be non-empty"),
    ],
)
def test_config_errors_fail_before_any_job(workdir, change, key):
    edit_machine(workdir, "demo20", change)
    result = snakemake(workdir, "--dry-run")
    assert result.returncode != 0
    assert key in result.stdout + result.stderr
    assert not (workdir / "results").exists()


@pytest.mark.parametrize(
    "change, key",
    [
        (lambda c: c["truth"].update(colour="red"), "colour"),
        (lambda c: c["truth"].update(magnetic_center_offset_m={"QX": 1e-5}), "QX"),
        (lambda c: c.update(machine="hs_eden_like"), "is the rig of machine 'hs_eden_like'"),
    ],
)
def test_rig_config_errors_fail_before_any_job(workdir, change, key):
    edit_config(workdir, demo20_on_its_rig)
    edit_yaml(workdir / "config" / "rigs" / "demo20.yaml", change)
    result = snakemake(workdir, "--dry-run")
    assert result.returncode != 0 and key in result.stdout + result.stderr


def test_unknown_calibration_setting_is_rejected(workdir):
    config = yaml.safe_load((workdir / "config/config.yaml").read_text())
    config["calibration"]["tolerance_um"] = 3
    (workdir / "config/config.yaml").write_text(yaml.safe_dump(config))
    result = snakemake(workdir, "--dry-run")
    assert result.returncode != 0 and "tolerance_um" in result.stdout + result.stderr


def plant_log_steps(plant, rng, relative_noise=1e-4, frequencies=None, sensor_floor=False):
    """Step records of a noisy identification of ``plant`` (unit excitation, its FRF times the hold, an ideal amplifier).

    ``frequencies`` (radial, axial) default to the machine's identification grids; ``sensor_floor``: every
    channel scatters too, 1e-9 m and 1e-5 A (a log without a noise estimate, the thesis .m format, needs that).
    """
    from ambid.logs import CHANNELS
    from ambid.loop import zero_order_hold
    from ambid.machine import ALL_AXES, RADIAL_AXES

    machine = plant.machine
    steps = []
    for axis in ALL_AXES:
        if frequencies is None:
            frequency = (machine.axial_grid if axis == "Z" else machine.radial_grid).frequency_hz
        else:
            frequency = frequencies[axis == "Z"]
        hold = zero_order_hold(frequency, machine.sample_time_s)
        if axis == "Z":
            response = {"Z": plant.axial_frequency_response(frequency) * hold}
        else:
            matrix = plant.radial_frequency_response(frequency) * hold[:, None, None]
            response = {out: matrix[:, k, RADIAL_AXES.index(axis)] for k, out in enumerate(RADIAL_AXES)}
        for k, f in enumerate(frequency):
            coefficients = np.zeros(len(CHANNELS), dtype=complex)
            coefficients[CHANNELS.index(f"U2_{axis}")] = 1.0
            for out, values in response.items():
                coefficients[CHANNELS.index(f"V2_{out}")] = values[k] * (1 + relative_noise * rng.standard_normal())
            # coil current (upper - lower) / 2: an ideal amplifier, sampled at the start of the cycle (one cycle behind U2)
            cycle_behind = np.exp(-2j * np.pi * f * machine.sample_time_s)
            coefficients[CHANNELS.index(f"I_upper_{axis}")] = 0.5 + cycle_behind
            coefficients[CHANNELS.index(f"I_lower_{axis}")] = 0.5 - cycle_behind
            if sensor_floor:
                floor = np.array([1e-9 if name.startswith("V2_") else 1e-5 for name in CHANNELS])
                coefficients += floor * (rng.standard_normal(len(CHANNELS)) + 1j * rng.standard_normal(len(CHANNELS)))
            noise = np.abs(coefficients) * relative_noise + 1e-12
            steps.append({"excited_axis": axis, "step": k, "frequency_hz": f, "amplitude_a": 1.0, "attempts": 1,
                          "coefficients": coefficients, "noise_std": noise})
    return steps


def test_real_logs_in_thesis_m_format(workdir):
    """A user's .m file in data/ (no rig): parsed, never evaluated, and carried to the FRF stage."""
    from ambid.logs import identification_frame
    from ambid.machine import machine_from_config
    from ambid.mfile import write_thesis_m
    from ambid.plant import Plant

    plant = Plant(machine_from_config(yaml.safe_load((workdir / "config/machines/demo20.yaml").read_text())))
    grid = 10.0 + 5 * np.arange(6)
    steps = plant_log_steps(plant, np.random.default_rng(0), 1e-3, (grid, grid), sensor_floor=True)
    run = workdir / "data/demo20/mine01"
    run.mkdir(parents=True)
    write_thesis_m(identification_frame(steps), run / "identification.m")
    config = yaml.safe_load((workdir / "config/config.yaml").read_text())
    config["machines"]["demo20"]["runs"] = {"mine01": {"kind": "identification", "source": "data", "format": "m"}}
    config["machines"]["demo20"].pop("variants")  # it names the run dropped here
    (workdir / "config/config.yaml").write_text(yaml.safe_dump(config))
    result = snakemake(workdir, "results/demo20/frf/mine01/frf.parquet")
    assert result.returncode == 0, result.stderr[-3000:]
    assert re.search(r"^import_log\s+1$", result.stdout + result.stderr, re.M)  # the Job stats table
    assert "acquire_identification" not in result.stdout + result.stderr
    frame, info = read_parquet(workdir / "results/demo20/frf/mine01/frf.parquet", kind="frf")
    assert set(frame["estimator"]) == {"siso", "mimo", "current"}
    # a thesis .m has no repeated steps: the FRF says so, for the diagnosis' leads and the report
    assert info["metadata"]["repeated_steps"] == 0
    findings = pd.read_csv(workdir / "results/demo20/frf/mine01/findings.tsv", sep="\t")
    assert "no_repeats" in set(findings["code"])
    # and each band at the documented constant says how far above the log's own noise that is
    fallback = findings[findings["code"] == "floor_fallback"]
    assert len(fallback) and fallback["message"].str.contains("times the noise there").all(), fallback["message"]


def test_unknown_top_level_key_is_rejected(workdir):
    config = yaml.safe_load((workdir / "config/config.yaml").read_text())
    config["machnies"] = config["machines"]
    (workdir / "config/config.yaml").write_text(yaml.safe_dump(config))
    result = snakemake(workdir, "--dry-run")
    assert result.returncode != 0 and "machnies" in result.stdout + result.stderr


def test_library_change_reruns_the_rules(tmp_path):
    """A copy of the workflow whose library source changes: the model rule must rerun."""
    copy = tmp_path / "wf"
    copy.mkdir()
    for part in ("Snakefile", "rules", "workflow", "config"):
        source = ROOT / part
        (shutil.copytree if source.is_dir() else shutil.copy)(source, copy / part, **({"ignore": shutil.ignore_patterns("__pycache__")} if source.is_dir() else {}))
    target = "results/demo20/model/nominal/stability.tsv"
    assert snakemake(copy, target, snakefile=copy / "Snakefile").returncode == 0
    assert "Nothing to be done" in "".join(snakemake(copy, target, "-n", snakefile=copy / "Snakefile").stdout)
    with open(copy / "workflow/ambid/rotor.py", "a") as handle:
        handle.write("\n# a change to the library\n")
    dry = snakemake(copy, target, "-n", snakefile=copy / "Snakefile")
    assert re.search(r"^model\s+1$", dry.stdout, re.M) and "Nothing to be done" not in dry.stdout


def test_lint_and_format_are_clean():
    """snakemake --lint finds nothing (every rule names the conda environment), snakefmt would change nothing, every
    rule prints a message and every job writes its benchmark."""
    result = subprocess.run([*SNAKEMAKE, "--lint"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    findings = [line.strip() for line in (result.stdout + result.stderr).splitlines() if line.strip().startswith("* ")]
    assert result.returncode == 0 and findings == [], (result.stdout + result.stderr)[-3000:]
    formatted = subprocess.run([sys.executable, "-m", "snakefmt", "--check", "Snakefile", "rules"], cwd=ROOT,
                               capture_output=True, text=True, timeout=300)
    assert formatted.returncode == 0, formatted.stderr[-3000:]
    texts = [p.read_text() for p in [ROOT / "Snakefile", *(ROOT / "rules").glob("*.smk")]]
    rules = sum(len(re.findall(r"^rule \w+:", text, re.M)) for text in texts)
    assert rules > 15 and sum(len(re.findall(r"^    message:", text, re.M)) for text in texts) == rules
    # and every rule that runs something records its time (all of them but the target rule `all`)
    assert sum(len(re.findall(r"^    benchmark:", text, re.M)) for text in texts) == rules - 1


def test_fit_and_update_stages_on_a_user_log(workdir):
    """A log of the thesis' reference rotor (ch. 5.3) dropped in data/: fit -> update -> an updated machine."""
    from ambid.effects import effect_from_config
    from ambid.logs import identification_frame, write_identification_log
    from ambid.machine import machine_from_config
    from ambid.plant import Plant

    nominal = machine_from_config(yaml.safe_load((workdir / "config/machines/demo20.yaml").read_text()))
    scale = {"tag": "design", "scale": [0.5385, 0.4005, 0.2055, 0.0945]}  # 107.7, 80.1, 41.1, 18.9 GPa
    reference = Plant(nominal.with_effects([effect_from_config({"name": "element_stiffness", "parameters": scale}, "e")]))
    steps = plant_log_steps(reference, np.random.default_rng(7))
    run = workdir / "data/demo20/user01"
    run.mkdir(parents=True)
    write_identification_log(identification_frame(steps), run / "identification.parquet")
    config = yaml.safe_load((workdir / "config/config.yaml").read_text())
    config["machines"] = {"demo20": {**config["machines"]["demo20"], "runs": {"user01": {"kind": "identification",
                                                                                       "source": "data"}}}}
    config["machines"]["demo20"]["variants"] = {"updated": {"update": "user01"}}
    config["update"]["starts"] = 3
    config["diagnose"]["sequence_length"] = 1  # the first choice is what is checked below
    (workdir / "config/config.yaml").write_text(yaml.safe_dump(config))
    base = workdir / "results/demo20/update/user01"
    result = snakemake(workdir, str(base.relative_to(workdir) / "comparison.tsv"))
    assert result.returncode == 0, result.stderr[-3000:]
    comparison, info = read_parquet(base / "comparison.parquet", kind="update_comparison")
    frequency = comparison[comparison["quantity"] == "frequency"]
    assert frequency["original_error_pct"].min() > 10  # nominal 706 Hz against the reference's 455 Hz
    assert frequency["error_pct"].max() < 0.05
    variables = (base / "variables.tsv").read_text()
    assert "resolution" in variables and "False" in variables  # one mode cannot determine four moduli: flagged
    updated = yaml.safe_load((base / "machine.yaml").read_text())
    assert any(e["name"] == "element_stiffness" for e in updated["effects"])
    machine_from_config(updated)
    for figure in ("bode_update", "youngs_modulus", "convergence"):
        assert (base / f"figures/{figure}.png").stat().st_size > 10_000
    # the diagnosis loop on the same user log: the nominal model lacks the design group's stiffness, the
    # updated variant (the update's moduli) explains the measurement far better
    result = snakemake(workdir, "results/demo20/diagnose/user01/nominal/diagnosis.md", "results/demo20/ledger/ledger.tsv")
    assert result.returncode == 0, result.stderr[-3000:]
    candidates = pd.read_csv(workdir / "results/demo20/diagnose/user01/nominal/candidates.tsv", sep="\t")
    assert candidates.loc[0, "candidate"] == "element_stiffness[design]" and bool(candidates.loc[0, "missing"])
    text = (workdir / "results/demo20/diagnose/user01/nominal/diagnosis.md").read_text()
    assert "Missing" in text and "`element_stiffness[design]`" in text and "name: element_stiffness" in text
    verdict = pd.read_csv(workdir / "results/demo20/diagnose/user01/nominal/verdict.tsv", sep="\t").iloc[0]
    assert verdict["verdict"] == "missing" and verdict["effects"].startswith("element_stiffness[design]")
    ledger = pd.read_csv(workdir / "results/demo20/ledger/ledger.tsv", sep="\t").set_index(["variant", "output"])
    assert ledger.loc[("updated", "all"), "excess"] < 0.01 * ledger.loc[("nominal", "all"), "excess"]


def test_a_diagnosis_of_a_variant_updated_from_another_run_waits_for_the_runs_own_update(workdir):
    """The joint refit also descends from the diagnosed run's own update (`ambid.diagnose.joint_refit`, alternatives)."""
    edit_config(workdir, lambda c: c["machines"]["demo20"]["runs"].update(
        ms01={"kind": "identification", "source": "rig", "seed": 3, "method": "multisine"}))
    planned = {}
    for run in ("ms01", "thesis01"):
        result = snakemake(workdir, "--dry-run", f"results/demo20/diagnose/{run}/updated/diagnosis.md")
        assert result.returncode == 0, result.stderr[-3000:]
        planned[run] = re.findall(r"demo20 (\w+): rotor model update", result.stdout + result.stderr)
    assert sorted(planned["ms01"]) == ["ms01", "thesis01"]  # the variant's update and the run's own
    assert planned["thesis01"] == ["thesis01"]  # the variant's update is the run's own: nothing more


def test_the_update_linearizes_the_bearings_where_the_variants_do(workdir):
    """With ``operating_point:`` the update waits for the calibration and takes its operating point (as rule variant)."""
    result = snakemake(workdir, "--dry-run", "results/hs_eden_like/update/ident01/machine.yaml")
    assert result.returncode == 0, result.stderr[-3000:]
    assert "hs_eden_like cal01: magnetic center from the calibration log" in result.stdout + result.stderr
    result = snakemake(workdir, "--dry-run", "results/demo20/update/thesis01/machine.yaml")
    assert result.returncode == 0 and "magnetic center from the calibration log" not in result.stdout + result.stderr


def test_multisine_run_on_the_rig_to_fit_and_the_methods_table(workdir):
    """A multisine run of demo20 on its rig (short settings, same code path): log, BLA with its floors, fit, methods."""
    def change(config):
        config["machines"]["demo20"]["runs"]["ms01"] = {"kind": "identification", "source": "rig", "seed": 3,
                                                        "method": "multisine"}
        config["multisine"].update(frequency_resolution_hz=5.0, radial_band_hz=[5.0, 800.0], axial_band_hz=[5.0, 50.0],
                                   zoom_resolution_min_hz=1.0, settle_s=0.3, crest_iterations=10)

    edit_config(workdir, change)
    targets = ["results/demo20/frf/ms01/frf.parquet", "results/demo20/frf/ms01/distortion.tsv",
               "results/demo20/fit/ms01/features.tsv", "results/demo20/methods/comparison.tsv"]
    result = snakemake(workdir, *targets)
    assert result.returncode == 0, result.stderr[-3000:]
    frame, info = read_parquet(workdir / "data/demo20/ms01/multisine.parquet", kind="multisine_log")
    assert set(frame["pass"]) == {"coarse", "zoom"} and info["metadata"]["machine_time_s"] > 0
    assert "truth" not in json.dumps(info["metadata"])  # the log does not leak the rig's truth
    frf, frf_info = read_parquet(workdir / targets[0], kind="frf")
    assert {"mimo", "siso", "current"} <= set(frf["estimator"]) and "systematic_std" in frf_info["units"]
    assert (frf["systematic_std"].dropna() >= 0).all() and frf["systematic_std"].notna().any()
    methods = pd.read_csv(workdir / targets[3], sep="\t")
    assert methods.set_index("run").loc["ms01", "method"] == "multisine"
    assert methods.set_index("run").loc["thesis01", "method"] == "stepped sine"
    assert (workdir / "results/demo20/methods/figures/methods.png").stat().st_size > 10_000


def test_multisine_log_with_a_dead_channel_names_file_and_rows(workdir):
    """A user's multisine log (source data) whose excited control current reads 0: one message, nothing written."""
    import numpy as np

    from ambid.io import write_parquet
    from ambid.logs import MULTISINE_UNITS, multisine_frame
    from ambid.machine import machine_from_config
    from ambid.multisine import MultisineSettings, design_multisine, pass_record
    from ambid.plant import Plant

    plant = Plant(machine_from_config(yaml.safe_load((workdir / "config/machines/demo20.yaml").read_text())))
    design = design_multisine(plant, MultisineSettings(frequency_resolution_hz=20.0, radial_band_hz=(20.0, 400.0),
                                                       axial_band_hz=(20.0, 60.0), levels=(1.0,), crest_iterations=0),
                              seed=1)
    spectra = np.ones((2, 4, 2, 20, design.grid.lines.size), dtype=complex) * (1e-6 + 1e-7j)
    spectra[0, 1, :, 2, :] = 0.0  # U2_NX of realization 0, experiment 1 reads nothing
    frame = multisine_frame([pass_record(design, spectra)])
    folder = workdir / "data/demo20/ms02"
    folder.mkdir(parents=True)
    write_parquet(frame, folder / "multisine.parquet", units=MULTISINE_UNITS, kind="multisine_log")
    edit_config(workdir, lambda c: c["machines"]["demo20"]["runs"].update(
        ms02={"kind": "identification", "source": "data", "method": "multisine"}))
    result = snakemake(workdir, "results/demo20/frf/ms02/frf.parquet")
    text = result.stdout + result.stderr
    messages = [line for line in text.splitlines() if line.startswith("ambid error")]
    assert result.returncode != 0 and len(messages) == 1, text[-3000:]
    assert "data/demo20/ms02/multisine.parquet" in messages[0] and "experiment=1" in messages[0]
    assert "control current U2" in messages[0]
    assert not (workdir / "results/demo20/frf/ms02/frf.parquet").exists()


def test_the_same_log_in_every_format_gives_the_same_frf(workdir):
    """The shipped example as a thesis .m, a MATLAB .mat and a wide CSV in um: one FRF; its UFF58 export, read back as a
    run of format uff (no raw log), gives the FRF table again and feeds the fit."""
    import numpy as np
    import scipy.io
    from numpy.testing import assert_allclose

    from ambid.mfile import parse_thesis_m, read_thesis_m
    from test_readers import wide

    example = workdir / EXAMPLE_LOG
    for run in ("asmat", "ascsv", "asuff"):
        (workdir / f"data/demo20/{run}").mkdir(parents=True)
    scipy.io.savemat(workdir / "data/demo20/asmat/identification.mat", parse_thesis_m(example.read_text()))
    wide(read_thesis_m(example), position_suffix="_um").to_csv(workdir / "data/demo20/ascsv/mine.csv", index=False)

    def change(config):
        runs = config["machines"]["demo20"]["runs"]
        runs["asmat"] = {"kind": "identification", "source": "data", "format": "mat"}
        runs["ascsv"] = {"kind": "identification", "source": "data", "format": "table", "file": "mine.csv"}
        runs["asuff"] = {"kind": "identification", "source": "data", "format": "uff"}

    edit_config(workdir, change)
    targets = [f"results/demo20/frf/{run}/frf.parquet" for run in ("thesis01", "asmat", "ascsv")]
    result = snakemake(workdir, *targets, "--cores", "2")
    assert result.returncode == 0, result.stderr[-3000:]
    tables = [read_parquet(workdir / target, kind="frf")[0] for target in targets]
    for other in tables[1:]:
        assert_allclose(other[["re", "im", "std"]], tables[0][["re", "im", "std"]], rtol=1e-12)
    shutil.copy(workdir / "results/demo20/frf/thesis01/frf.uff", workdir / "data/demo20/asuff/frf.uff")
    result = snakemake(workdir, "results/demo20/fit/asuff/models.parquet", "results/demo20/export/asuff/frf.mat")
    assert result.returncode == 0, result.stderr[-3000:]
    assert "import_log" not in result.stdout + result.stderr  # the FRFs go straight to the FRF stage
    imported, info = read_parquet(workdir / "results/demo20/frf/asuff/frf.parquet", kind="frf")
    key = ["estimator", "output", "input", "frequency_hz"]
    original = tables[0].sort_values(key).reset_index(drop=True)
    imported = imported.sort_values(key).reset_index(drop=True)
    assert (original[key[:3]] == imported[key[:3]]).all().all()
    assert_allclose(imported[["re", "im"]], original[["re", "im"]], rtol=1e-10, atol=1e-12 * np.abs(original["re"]).max())
    assert info["metadata"]["source_log"] == "data/demo20/asuff/frf.uff"
    ratio = imported["std"] / original["std"]
    assert 0.2 < ratio.median() < 5  # the scatter estimate is of the order of the propagated noise
