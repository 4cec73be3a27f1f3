"""Bad input, end to end: the workflow stops with one message naming the file or key, and writes nothing half.

Each test puts one defect where a user would (a log in data/, a key in config/) and runs Snakemake on a copy of
the working directory, as `make run` would.
"""

import numpy as np
import pytest
import yaml

from ambid.io import write_parquet
from ambid.logs import CHANNELS, UNITS, identification_frame
from ambid.mfile import write_thesis_m
from test_reproducibility import job_counts
from test_workflow import EXAMPLE_LOG, edit_config, snakemake, workdir  # noqa: F401 (workdir is a fixture)

pytestmark = pytest.mark.workflow

FRF = "results/demo20/frf/bad01/frf.parquet"


def user_run(workdir, source_format=None):
    """demo20 with one identification run bad01 from data/ and nothing else to run."""
    def change(config):
        run = {"kind": "identification", "source": "data", **({"format": source_format} if source_format else {})}
        config["machines"] = {"demo20": {**config["machines"]["demo20"], "runs": {"bad01": run}, "variants": {}}}

    edit_config(workdir, change)
    folder = workdir / "data/demo20/bad01"
    folder.mkdir(parents=True)
    return folder


def steps(n=8):
    """A small valid identification log of every axis (unit excitation, a resonance-free response)."""
    out = []
    for axis in ("DX", "DY", "NX", "NY", "Z"):
        for k in range(n):
            coefficients = np.full(len(CHANNELS), 1e-3 + 1e-4j)
            coefficients[CHANNELS.index(f"U2_{axis}")] = 0.5
            coefficients[CHANNELS.index(f"V2_{axis}")] = 2e-6 * (1 + 0.1 * k)
            out.append({"excited_axis": axis, "step": k, "frequency_hz": 10.0 + 10 * k, "amplitude_a": 0.5, "attempts": 1,
                        "coefficients": coefficients, "noise_std": np.full(len(CHANNELS), 1e-6)})
    return out


def write_raw_log(frame, path):
    """Write a log as the acquisition would, but without the contract check (a corrupt log from elsewhere)."""
    write_parquet(frame, path, units=UNITS, kind="identification_log", metadata={"machine": "demo20", "run": "bad01"})


def assert_fails_once(result, *named):
    """The run failed with exactly one ambid message, which names everything in ``named``."""
    text = result.stdout + result.stderr
    assert result.returncode != 0
    messages = [line for line in text.splitlines() if line.startswith("ambid error")]
    assert len(messages) == 1, text[-3000:]
    for name in named:
        assert name in messages[0], messages[0]
    return messages[0]


def assert_nothing_written(workdir, *paths):
    for path in paths:
        assert not (workdir / path).exists(), path


def test_corrupt_parquet_log(workdir):
    folder = user_run(workdir)
    (folder / "identification.parquet").write_bytes(b"PAR1 this is not a Parquet file")
    message = assert_fails_once(snakemake(workdir, FRF), "data/demo20/bad01/identification.parquet")
    assert "not a readable Parquet file" in message
    assert_nothing_written(workdir, "results/demo20/frf/bad01")


def test_corrupt_calibration_parquet(workdir):
    def change(config):
        config["machines"]["demo20"]["runs"]["cal09"] = {"kind": "calibration", "source": "data"}

    edit_config(workdir, change)
    folder = workdir / "data/demo20/cal09"
    folder.mkdir(parents=True)
    (folder / "calibration.parquet").write_bytes(b"\x00" * 64)
    assert_fails_once(snakemake(workdir, "results/demo20/calibration/cal09/magnetic_center.tsv"),
                      "data/demo20/cal09/calibration.parquet")
    assert_nothing_written(workdir, "results/demo20/calibration/cal09")


def test_m_file_with_a_syntax_error(workdir):
    folder = user_run(workdir, "m")
    path = folder / "identification.m"
    write_thesis_m(identification_frame(steps()), path)
    lines = path.read_text().splitlines()
    row = next(i for i, line in enumerate(lines) if line.startswith("data_exc_dy")) + 2
    lines[row] = "system('rm -rf ~');"  # code where only numbers may stand: parsed, never evaluated
    path.write_text("\n".join(lines) + "\n")
    message = assert_fails_once(snakemake(workdir, FRF), f"data/demo20/bad01/identification.m:{row + 1}:1:")
    assert "only numbers" in message
    assert_nothing_written(workdir, "data/demo20/bad01/identification.parquet", "results/demo20/frf/bad01")


def test_log_with_nan(workdir):
    frame = identification_frame(steps())
    frame.loc[(frame["excited_axis"] == "NX") & (frame["step"] == 3) & (frame["channel"] == "V2_NX"), "re"] = np.nan
    write_raw_log(frame, user_run(workdir) / "identification.parquet")
    message = assert_fails_once(snakemake(workdir, FRF), "data/demo20/bad01/identification.parquet")
    assert "excited_axis=NX, step=3" in message and "re is not finite" in message and "V2_NX" in message
    assert_nothing_written(workdir, "results/demo20/frf/bad01")


def test_log_with_zero_excitation(workdir):
    frame = identification_frame(steps())
    silent = (frame["excited_axis"] == "DY") & (frame["step"] == 5) & (frame["channel"] == "U2_DY")
    frame.loc[silent, ["re", "im"]] = 0.0
    write_raw_log(frame, user_run(workdir) / "identification.parquet")
    message = assert_fails_once(snakemake(workdir, FRF), "data/demo20/bad01/identification.parquet")
    assert "excited_axis=DY, step=5" in message and "zero excitation" in message
    assert_nothing_written(workdir, "results/demo20/frf/bad01")


@pytest.mark.parametrize(
    "variant, key",
    [
        ({"effects": [{"name": "warp_drive"}]}, "machines.demo20.variants.broken.effects[0]"),
        ({"effects": [{"name": "delay", "parameters": {"delay_s": -1e-5}}]}, "delay_s"),
        ({"base": "nonexistent"}, "nonexistent"),
    ],
)
def test_config_with_a_bad_variant_fails_before_any_job(workdir, variant, key):
    edit_config(workdir, lambda config: config["machines"]["demo20"]["variants"].update(broken=variant))
    result = snakemake(workdir, "--dry-run")
    assert result.returncode != 0 and key in result.stdout + result.stderr
    assert_nothing_written(workdir, "results")


def test_negative_element_length_fails_before_any_job(workdir):
    path = workdir / "config/machines/demo20.yaml"
    machine = yaml.safe_load(path.read_text())
    machine["rotor"]["elements"][0]["length_m"] = -0.02
    path.write_text(yaml.safe_dump(machine))
    result = snakemake(workdir)
    text = result.stdout + result.stderr
    assert result.returncode != 0 and "config/machines/demo20.yaml: rotor.elements[0].length_m: -0.02" in text
    assert_nothing_written(workdir, "results")


# ------------------------------------------------------------------ issue 16: trust, or a clear error
def dry_rules(output):
    """The rules a dry run would run (its Job stats table)."""
    return set(job_counts(output))


def shipped_log_lines(workdir):
    return (workdir / EXAMPLE_LOG).read_text().splitlines()


def demo20_only(workdir, **sections):
    """The default demo20 run on the shipped .m log (and nothing of hs_eden_like); ``sections`` update config sections."""
    def change(config):
        config["machines"] = {"demo20": config["machines"]["demo20"]}
        for name, values in sections.items():
            config[name].update(values)

    edit_config(workdir, change)


def write_lines(workdir, lines):
    (workdir / EXAMPLE_LOG).write_text("\n".join(lines) + "\n")


def typo(workdir, line=20, column=7, value="1e+05"):
    """One cell of the shipped .m changed (line 20, column 7: V2_DX of data_exc_dx row 13, 122.99 Hz)."""
    lines = shipped_log_lines(workdir)
    cells = lines[line - 1].split()
    cells[column - 1] = value
    lines[line - 1] = "  ".join(cells)
    write_lines(workdir, lines)


def without(workdir, *variables):
    kept, skipping = [], False
    for line in shipped_log_lines(workdir):
        skipping = skipping or any(line.startswith(f"{name} = [") for name in variables)
        if not skipping:
            kept.append(line)
        elif line.startswith("];"):
            skipping = False
    write_lines(workdir, kept)


UPDATE = "results/demo20/update/thesis01/comparison.tsv"


def test_case1_a_typo_is_refused_with_its_line(workdir):
    demo20_only(workdir)
    typo(workdir)
    message = assert_fails_once(snakemake(workdir, UPDATE), f"{EXAMPLE_LOG}:20: data_exc_dx row 13, column 7 (V2_DX [um])")
    assert "= 100000" in message and "times the noise" in message and "frf.outliers: exclude" in message
    assert_nothing_written(workdir, "results/demo20/frf/thesis01/frf.parquet", "results/demo20/fit", "results/demo20/update")


def test_case1_a_typo_excluded_when_allowed_leaves_the_update_right(workdir):
    import pandas as pd

    demo20_only(workdir, frf={"outliers": "exclude"})
    typo(workdir)
    result = snakemake(workdir, UPDATE, "results/demo20/fit/thesis01/findings.tsv")
    assert result.returncode == 0, result.stderr[-3000:]
    findings = pd.read_csv(workdir / "results/demo20/frf/thesis01/findings.tsv", sep="\t")
    excluded = findings[findings["code"] == "outlier_excluded"].reset_index(drop=True)  # beside the floor's notes
    assert len(excluded) == 1 and f"{EXAMPLE_LOG}:20" in excluded.loc[0, "message"]
    # besides the floor's notes and the thesis .m's lack of repeated steps, nothing
    assert set(findings["code"]) - {"outlier_excluded"} <= {"floor_fallback", "noise_rescaled", "no_repeats"}
    comparison = pd.read_csv(workdir / UPDATE, sep="\t")
    first = comparison[(comparison["quantity"] == "frequency") & (comparison["root"] == "pole")]
    assert first["measured"].between(455.0, 455.5).all() and first["updated"].between(454.0, 456.5).all()


@pytest.mark.parametrize("missing, named", [(("data_exc_ny",), "NY (data_exc_ny)"),
                                            (("data_exc_dy", "data_exc_nx", "data_exc_ny", "data_exc_z"), "DY (data_exc_dy)")])
def test_case2_a_missing_radial_run_is_an_error_for_the_mimo_estimate(workdir, missing, named):
    demo20_only(workdir)
    without(workdir, *missing)
    message = assert_fails_once(snakemake(workdir, "results/demo20/fit/thesis01/features.tsv"), EXAMPLE_LOG, named)
    assert "frf.estimator: siso" in message
    assert_nothing_written(workdir, "results/demo20/frf/thesis01/frf.parquet")


GAINS = ("proportional_gain_a_per_m", "integral_gain_a_per_m_s", "derivative_gain_a_s_per_m")


@pytest.mark.parametrize("case", ["delay 5 ms", "amplifier 10 Hz", "gain x10"])
def test_case3_an_unstable_model_stops_with_its_verdict(workdir, case):
    """The stability check judges the sampled loop with every effect, as the rig does (spectral radius > 1)."""
    from test_workflow import edit_machine

    demo20_only(workdir)
    variants = {"delay 5 ms": [{"name": "delay", "parameters": {"delay_s": 5e-3}}],
                "amplifier 10 Hz": [{"name": "amplifier_lowpass", "parameters": {"cutoff_hz": 10.0}}]}
    if case in variants:
        edit_config(workdir, lambda config: config["machines"]["demo20"]["variants"].update(probe={"effects": variants[case]}))
        target, variant = "results/demo20/model/probe/stability.tsv", "probe"
    else:
        edit_machine(workdir, "demo20", lambda m: m["controller"]["radial"].update({k: 10 * m["controller"]["radial"][k]
                                                                                      for k in GAINS}))
        target, variant = "results/demo20/model/nominal/stability.tsv", "nominal"
    message = assert_fails_once(snakemake(workdir, target), f"model variant '{variant}' is unstable in closed loop",
                                "no ISO 14839-3 zone")
    radius = float(message.split("spectral radius ")[1].split(" ")[0])
    assert radius > 1.004
    assert_nothing_written(workdir, target)


def test_case4_a_log_replaced_by_an_older_file_reruns(workdir):
    import os
    import subprocess
    import tarfile

    demo20_only(workdir)
    assert snakemake(workdir, "results/demo20/frf/thesis01/frf.parquet").returncode == 0
    older = workdir / "older.m"
    lines = shipped_log_lines(workdir)
    cells = lines[19].split()
    cells[6] = "-22.25+27.22i"  # a plausible, different value
    lines[19] = "  ".join(cells)
    older.write_text("\n".join(lines) + "\n")
    os.utime(older, (1e9, 1e9))  # 2001
    subprocess.run(["cp", "-p", str(older), str(workdir / EXAMPLE_LOG)], check=True)
    dry = snakemake(workdir, "results/demo20/frf/thesis01/frf.parquet", "--dry-run")
    assert {"import_log", "plausibility", "frf"} <= dry_rules(dry.stdout + dry.stderr), dry.stdout[-2000:]
    assert snakemake(workdir, "results/demo20/frf/thesis01/frf.parquet").returncode == 0
    with tarfile.open(workdir / "logs.tar", "w") as archive:  # an archive unpacked over the run keeps old mtimes
        cells[6] = "-22.26+27.22i"
        lines[19] = "  ".join(cells)
        older.write_text("\n".join(lines) + "\n")
        os.utime(older, (1e9, 1e9))
        archive.add(older, arcname=EXAMPLE_LOG)
    with tarfile.open(workdir / "logs.tar") as archive:
        archive.extractall(workdir, filter="data")
    dry = snakemake(workdir, "results/demo20/frf/thesis01/frf.parquet", "--dry-run")
    assert "import_log" in dry_rules(dry.stdout + dry.stderr)


def test_case4_a_leftover_converted_log_never_stands_for_another_m(workdir):
    import os
    import shutil

    demo20_only(workdir)
    assert snakemake(workdir, "data/demo20/thesis01/identification.parquet").returncode == 0
    shutil.rmtree(workdir / ".snakemake")  # Snakemake no longer knows where the converted log came from
    typo(workdir, value="-22.25+27.22i")
    os.utime(workdir / EXAMPLE_LOG, (1e9, 1e9))  # the converted log looks newer than its .m
    message = assert_fails_once(snakemake(workdir, "results/demo20/frf/thesis01/frf.parquet"),
                                "data/demo20/thesis01/identification.parquet", f"is not the conversion of {EXAMPLE_LOG}")
    assert "delete it" in message
    assert_nothing_written(workdir, "results/demo20/frf/thesis01/frf.parquet")


def shipped_log_as_parquet(workdir, change):
    """The shipped log converted to Parquet by a user, ``change`` applied, as run user01 (source: data)."""
    from ambid.mfile import read_thesis_m

    frame = change(read_thesis_m(workdir / EXAMPLE_LOG))
    write_raw_log(frame, user_run(workdir) / "identification.parquet")
    return "results/demo20/fit/bad01/features.tsv"


def scaled(channels, factor, frequency=1.0):
    def change(frame):
        chosen = frame["channel"].str.startswith(channels)
        frame.loc[chosen, ["re", "im"]] *= factor
        frame["frequency_hz"] *= frequency
        return frame
    return change


@pytest.mark.parametrize(
    "change, named",
    [
        (scaled(("V2_",), 1e6), "positions look like um"),
        (scaled(("none",), 1.0, 1e-3), "frequencies look like kHz"),
        (scaled(("U2_", "I_"), 1e3), "currents look like mA"),
        (lambda frame: frame[frame["excited_axis"] == "DX"], "no run excites DY, NX, NY"),
    ],
    ids=["um", "kHz", "mA", "single axis"],
)
def test_case5_wrong_units_and_single_axis_logs_are_named(workdir, change, named):
    target = shipped_log_as_parquet(workdir, change)
    message = assert_fails_once(snakemake(workdir, target), "data/demo20/bad01/identification.parquet", named)
    assert "config/machines/demo20.yaml" in message or "MIMO" in message
    assert_nothing_written(workdir, "results/demo20/frf/bad01/frf.parquet", "results/demo20/fit/bad01")


def test_case6_a_categorical_axis_column_is_read(workdir):
    def categorical(frame):
        return frame.assign(excited_axis=frame["excited_axis"].astype("category"))

    target = shipped_log_as_parquet(workdir, categorical)
    result = snakemake(workdir, target)
    assert result.returncode == 0, result.stderr[-3000:]


def test_case6_a_huge_cell_is_an_outlier_with_its_rows(workdir):
    def huge(frame):
        frame.loc[(frame["excited_axis"] == "DX") & (frame["step"] == 12) & (frame["channel"] == "V2_DX"), "re"] = 1e300
        return frame

    message = assert_fails_once(snakemake(workdir, shipped_log_as_parquet(workdir, huge)),
                                "data/demo20/bad01/identification.parquet: rows 240-259 (excited_axis=DX, step=12)")
    assert "V2_DX = 1e+300" in message


@pytest.mark.parametrize(
    "change, key",
    [
        (lambda c: c["update"].update(stiffness_bounds=[2.0, 1e-3]), "config/config.yaml: update.stiffness_bounds"),
        (lambda c: c["update"].update(damping_bounds=[0.2, 0.0]), "config/config.yaml: update.damping_bounds"),
        (lambda c: c["machines"]["demo20"]["update"].update(tags=["desing"]), "machines.demo20.update.tags[0]"),
        (lambda c: c["fit"].update(modes=99), "config/config.yaml: fit.modes"),
        (lambda c: c["update"].update(modes=99), "config/config.yaml: update.modes"),
        (lambda c: c["compare"].update(bands_hz=[1000, 0, 100]), "config/config.yaml: compare.bands_hz"),
    ],
    ids=["stiffness_bounds", "damping_bounds", "tags", "fit.modes", "update.modes", "bands_hz"],
)
def test_case6_7_config_errors_stop_before_any_job(workdir, change, key):
    demo20_only(workdir)
    edit_config(workdir, change)
    result = snakemake(workdir)
    text = result.stdout + result.stderr
    assert result.returncode != 0 and key in text and "Traceback" not in text, text[-2000:]
    assert_nothing_written(workdir, "results", "data/demo20/thesis01/identification.parquet")


@pytest.mark.parametrize("where", ["config/config.yaml", "config/machines/demo20.yaml", "config/rigs/demo20.yaml"])
def test_case7_duplicate_yaml_keys_are_errors(workdir, where):
    from test_workflow import demo20_on_its_rig

    if where.startswith("config/rigs"):
        edit_config(workdir, demo20_on_its_rig)
    path = workdir / where
    text = path.read_text()
    duplicated = {"config/config.yaml": ("  dpi: 120\n", "  dpi: 120\n  dpi: 60\n", "figures.dpi"),
                  "config/machines/demo20.yaml": ("    youngs_modulus_pa: 2.0e+11\n",
                                                  "    youngs_modulus_pa: 2.0e+11\n    youngs_modulus_pa: 2.0e+9\n",
                                                  "materials.steel.youngs_modulus_pa"),
                  "config/rigs/demo20.yaml": ("  gravity_m_s2: 9.81\n", "  gravity_m_s2: 9.81\n  gravity_m_s2: 0.0\n",
                                              "truth.gravity_m_s2")}[where]
    assert duplicated[0] in text
    path.write_text(text.replace(duplicated[0], duplicated[1], 1))
    result = snakemake(workdir, "--dry-run")
    assert result.returncode != 0 and f"{where}: {duplicated[2]}: duplicate key" in result.stdout + result.stderr


def test_case6_an_absurd_bias_current_stops_before_any_job(workdir):
    from test_workflow import edit_machine

    edit_machine(workdir, "demo20", lambda m: m["bearings"]["radial"]["electromagnet"].update(bias_current_a=1e6))
    result = snakemake(workdir)
    text = result.stdout + result.stderr
    assert result.returncode != 0 and "Traceback" not in text
    assert "config/machines/demo20.yaml: bearings.radial.electromagnet.bias_current_a: 1e+06 A" in text
    assert_nothing_written(workdir, "results")


def test_case9_an_oversized_m_file_is_refused(workdir):
    demo20_only(workdir)
    (workdir / EXAMPLE_LOG).write_bytes(b"data_exc_dx = [" + b"1 " * 10_000_000 + b"];\n")  # 20 MB on one line
    assert_fails_once(snakemake(workdir, "data/demo20/thesis01/identification.parquet"),
                      f"{EXAMPLE_LOG}:1:65537: line longer than 65536 bytes")
    assert_nothing_written(workdir, "data/demo20/thesis01/identification.parquet")


def test_case4_a_machine_file_or_config_section_changed_with_an_older_time_reruns(workdir):
    """Content, not time: the machine file re-runs the check against the model, the FRF after it and the fit; a fit
    setting the fit alone."""
    import os

    demo20_only(workdir)
    target = "results/demo20/fit/thesis01/features.tsv"
    assert snakemake(workdir, target).returncode == 0
    for path, old, new, rules in (("config/machines/demo20.yaml", "loss_factor: 0.004", "loss_factor: 0.005",
                                   {"plausibility", "frf", "fit"}),
                                  ("config/config.yaml", "max_chi2: 300.0", "max_chi2: 200.0", {"fit"})):
        file = workdir / path
        text = file.read_text()
        assert old in text
        file.write_text(text.replace(old, new))
        os.utime(file, (1e9, 1e9))
        dry = snakemake(workdir, target, "--dry-run")
        jobs = dry_rules(dry.stdout + dry.stderr)
        assert rules <= jobs, dry.stdout[-2000:]
        assert "import_log" not in jobs and ("frf" in jobs) == ("frf" in rules)
        file.write_text(text)
        os.utime(file, (1e9, 1e9))


def test_plain_parquet_is_refused_naming_the_keys_and_the_way_in(workdir):
    """A log with the documented columns written by pandas.to_parquet, as format parquet (the canonical log)."""
    identification_frame(steps()).to_parquet(user_run(workdir) / "identification.parquet")
    message = assert_fails_once(snakemake(workdir, FRF), "data/demo20/bad01/identification.parquet")
    assert "ambid.schema_version, ambid.kind and ambid.units" in message and "--format table" in message


def test_constant_channel_of_an_m_file_names_the_m_file_and_that_channel_only(workdir):
    """The noise estimate of a .m log (no noise in the format) fails on a stuck channel: the message names the user's .m
    and the one stuck channel, not the Parquet it was converted to nor the channels a bearing's run leaves out."""
    records = steps()
    for record in records:  # each bearing's channels only, written in the 18 + 6 column layout
        own = [c for c in CHANNELS if c.endswith("_Z") == (record["excited_axis"] == "Z")]
        record["coefficients"] = np.array([record["coefficients"][CHANNELS.index(c)] for c in own]) * (1 + 0.01 * record["step"] ** 2)
        record["coefficients"][own.index(f"U2_{record['excited_axis']}")] = 0.5 + 0.01 * record["step"] ** 2
        if "I_upper_NX" in own:
            record["coefficients"][own.index("I_upper_NX")] = 0.1  # stuck
        record["noise_std"], record["channels"] = np.zeros(len(own)), own
    write_thesis_m(identification_frame(records), user_run(workdir, "m") / "identification.m")
    message = assert_fails_once(snakemake(workdir, FRF), "data/demo20/bad01/identification.m")
    assert "channel(s) I_upper_NX do not scatter" in message and "I_lower_NX" not in message
    assert_nothing_written(workdir, "results/demo20/frf/bad01")


def test_unreadable_mat_file(workdir):
    (user_run(workdir, "mat") / "identification.mat").write_bytes(b"\x00" * 200)
    message = assert_fails_once(snakemake(workdir, FRF), "data/demo20/bad01/identification.mat")
    assert "not a readable MATLAB .mat file" in message
    assert_nothing_written(workdir, "data/demo20/bad01/identification.parquet", "results/demo20/frf/bad01")
