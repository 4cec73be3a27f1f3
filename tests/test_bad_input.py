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
