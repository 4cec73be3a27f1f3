"""The ambid command: new-machine, check-log, import, and the README's five steps followed as they stand."""

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from ambid.cli import add_run, check_log, import_log, main, new_machine
from ambid.errors import ConfigError, LogError
from ambid.io import read_parquet
from ambid.logs import CHANNELS, identification_frame, multisine_frame, write_multisine_log
from ambid.machine import ALL_AXES, machine_from_config
from ambid.uff import frf_channels, write_uff58
from conftest import ROOT
from test_logs import make_steps, own_bearing_only
from test_readers import frf_of, wide


@pytest.fixture
def project(tmp_path):
    """A working directory with the repository's configuration."""
    shutil.copytree(ROOT / "config", tmp_path / "config")
    return tmp_path


class TestNewMachine:
    def test_in_a_configured_directory(self, project):
        before = (project / "config/config.yaml").read_text()
        lines = new_machine("rotor1", "demo20", project)
        assert lines[0].startswith("wrote") and "added machines.rotor1" in lines[1]
        text = (project / "config/config.yaml").read_text()
        assert all(line in text for line in before.splitlines())  # comments and all kept
        config = yaml.safe_load(text)
        assert config["machines"]["rotor1"] == {"model": "config/machines/rotor1.yaml", "runs": {}}
        assert set(config["machines"]) == {"hs_eden_like", "demo20", "rotor1"}
        machine_text = (project / "config/machines/rotor1.yaml").read_text()
        assert "# planar free-free modes kept by the modal reduction (eq. 2.10)" in machine_text
        machine = yaml.safe_load(machine_text)
        assert machine["name"] == "rotor1"
        machine_from_config(machine, name="rotor1")
        demo = yaml.safe_load((ROOT / "config/machines/demo20.yaml").read_text())
        assert {k: v for k, v in machine.items() if k != "name"} == {k: v for k, v in demo.items() if k != "name"}

    def test_from_nothing(self, tmp_path):
        new_machine("rotor_2", "hs_eden_like", tmp_path)
        config = yaml.safe_load((tmp_path / "config/config.yaml").read_text())
        repository = yaml.safe_load((ROOT / "config/config.yaml").read_text())
        assert list(config["machines"]) == ["rotor_2"]
        assert {k: v for k, v in config.items() if k != "machines"} == {k: v for k, v in repository.items() if k != "machines"}

    def test_refusals(self, project):
        new_machine("rotor1", "demo20", project)
        with pytest.raises(ConfigError, match="rotor1.yaml exists"):
            new_machine("rotor1", "demo20", project)
        (project / "config/machines/rotor1.yaml").unlink()
        with pytest.raises(ConfigError, match="machines.rotor1: is already in the configuration"):
            new_machine("rotor1", "demo20", project)
        with pytest.raises(ConfigError, match="letters, digits and _ only"):
            new_machine("my rotor", "demo20", project)
        with pytest.raises(ConfigError, match=r"no machine file .*nonesuch.yaml \(shipped: demo20, hs_eden_like\)"):
            new_machine("rotor3", "nonesuch", project)


class TestAddRun:
    @pytest.mark.parametrize("runs_text", ["", "    runs: {}\n", "    runs:  # mine\n      old: {kind: identification, source: data}\n"])
    def test_keeps_the_file_and_adds_the_run(self, tmp_path, runs_text):
        path = tmp_path / "config.yaml"
        path.write_text(f"# my config\nmachines:\n  m1:\n    model: a.yaml\n{runs_text}  m2:\n    model: b.yaml\nfigures: {{dpi: 90}}\n")
        message = add_run(path, "m1", "r1", {"kind": "identification", "source": "data", "format": "uff"})
        assert message.endswith("machines.m1.runs.r1: {kind: identification, source: data, format: uff}")
        config = yaml.safe_load(path.read_text())
        assert config["machines"]["m1"]["runs"]["r1"] == {"kind": "identification", "source": "data", "format": "uff"}
        assert config["machines"]["m2"] == {"model": "b.yaml"} and path.read_text().startswith("# my config\n")

    def test_refusals(self, tmp_path):
        path = tmp_path / "config.yaml"
        path.write_text("machines:\n  m1: {model: a.yaml, runs: {r1: {kind: identification, source: data}}}\n")
        with pytest.raises(ConfigError, match="machines.m9: not in the configuration: `ambid new-machine m9"):
            add_run(path, "m9", "r1", {"kind": "identification"})
        with pytest.raises(ConfigError, match="machines.m1.runs.r1: is already"):
            add_run(path, "m1", "r1", {"kind": "identification"})
        with pytest.raises(ConfigError, match="could not be added .* by hand"):  # flow style: not editable as text
            add_run(path, "m1", "r2", {"kind": "identification", "source": "data"})


class TestImport:
    def test_a_csv_log(self, project, tmp_path):
        frame = identification_frame(make_steps(axes=ALL_AXES, n_steps=5))
        frame.to_csv(tmp_path / "mine.csv", index=False)
        lines = import_log(tmp_path / "mine.csv", "demo20", "r7", directory=project)
        assert lines[0].startswith("wrote ") and "25 steps" in lines[0]
        log, info = read_parquet(project / "data/demo20/r7/identification.parquet", kind="identification_log")
        assert info["metadata"]["provenance"]["file"] == str(tmp_path / "mine.csv")
        assert info["metadata"]["provenance"]["format"] == "table" and len(log) == len(frame)
        config = yaml.safe_load((project / "config/config.yaml").read_text())
        assert config["machines"]["demo20"]["runs"]["r7"] == {"kind": "identification", "source": "data"}
        with pytest.raises(ConfigError, match=r"identification.parquet exists \(--force replaces it\)"):
            import_log(tmp_path / "mine.csv", "demo20", "r7", directory=project)
        target = project / "data/demo20/r7/identification.parquet"
        with pytest.raises(ConfigError, match="is the file the import would write"):
            import_log(target, "demo20", "r7", directory=project, force=True)

    def test_uff_frfs(self, project, tmp_path):
        write_uff58(tmp_path / "analyser.uff", frf_channels(frf_of(identification_frame(make_steps(axes=ALL_AXES, n_steps=5)))))
        lines = import_log(tmp_path / "analyser.uff", "demo20", "u1", directory=project)
        assert (project / "data/demo20/u1/frf.uff").read_bytes() == (tmp_path / "analyser.uff").read_bytes()
        assert lines[-1].endswith("runs.u1: {kind: identification, source: data, format: uff}")

    def test_a_bad_log_writes_nothing(self, project, tmp_path):
        (tmp_path / "bad.csv").write_text("excited_axis,frequency_hz,channel,re,im\nDX,10,V2_QQ,1,2\n")
        with pytest.raises(LogError, match=r"bad\.csv: row 1: unknown channel 'V2_QQ'"):
            import_log(tmp_path / "bad.csv", "demo20", "r8", directory=project)
        assert not (project / "data").exists()
        assert "r8" not in yaml.safe_load((project / "config/config.yaml").read_text())["machines"]["demo20"]["runs"]


class TestCheckLog:
    def test_partial_wide_table(self, tmp_path):
        frame = own_bearing_only(identification_frame(make_steps(axes=("DX", "DY", "NX", "Z"), n_steps=5)))
        wide(frame.assign(noise_std=0.0)).to_csv(tmp_path / "log.csv", index=False)
        text = "\n".join(check_log(tmp_path / "log.csv"))
        assert re.search(r"^DX\s+5\s+10-110 Hz, linear", text, re.M) and re.search(r"^Z\s+5 .* 4$", text, re.M)
        assert "noise: none logged; estimated from the scatter" in text and "V2 [um]: DX " in text
        assert "radial axes excited: DX, DY, NX: no MIMO estimate" in text
        assert "steps of DX, DY, NX, Z carry their own bearing's channels only" in text
        assert "no step repeated at a lower amplitude (column level)" in text and "repeats:" not in text

    def test_repeated_steps_are_counted(self, tmp_path):
        frame = identification_frame(make_steps(axes=("DX", "Z"), n_steps=5))
        repeats = frame[frame["step"].isin([0, 2])].assign(level=1)
        pd.concat([frame.assign(level=0), repeats]).to_csv(tmp_path / "log.csv", index=False)
        text = "\n".join(check_log(tmp_path / "log.csv"))
        assert "repeats: 4 steps measured again at a lower amplitude" in text and "no step repeated" not in text

    def test_uff(self, tmp_path):
        write_uff58(tmp_path / "f.uff", frf_channels(frf_of(identification_frame(make_steps(axes=ALL_AXES, n_steps=5)))))
        text = "\n".join(check_log(tmp_path / "f.uff"))
        assert "FRFs (UFF58), estimator(s) current, mimo, siso" in text and re.search(r"^mimo\s+NY/DX\s+5\s+10-110 Hz", text, re.M)

    def test_multisine_log(self, tmp_path):
        """A multisine log is summarized per pass (it was refused as 'holds multisine_log'); without coil currents too."""
        rng = np.random.default_rng(1)
        lines = np.arange(1, 11)
        spectra = rng.standard_normal((1, 4, 3, len(CHANNELS), lines.size)) + 1j  # R x E x P, channels, lines
        reference = np.exp(2j * np.pi * rng.random((1, 4, len(ALL_AXES), lines.size)))
        frame = multisine_frame([{"name": "coarse", "lines": lines, "frequency_hz": 10.0 * lines,
                                  "role": np.full(lines.size, "excited"), "spectra": spectra, "reference": reference}])
        write_multisine_log(frame, tmp_path / "ms.parquet", {"design": "orthogonal"})
        text = "\n".join(check_log(tmp_path / "ms.parquet"))
        assert re.search(r"^coarse\s+10\s+10-100 Hz\s+10\s+1 x 4 x 3\s+1$", text, re.M), text
        assert "axes excited: DX, DY, NX, NY, Z" in text and "I [A]: upper_DX" in text
        assert "no nonlinear-distortion estimate" in text and "no detection lines" in text
        assert "no coil currents" not in text
        write_multisine_log(frame[~frame["channel"].str.startswith("I_")], tmp_path / "without.parquet")
        text = "\n".join(check_log(tmp_path / "without.parquet"))
        assert "I [A]" not in text and "no coil currents (I_upper, I_lower): no coil-current FRF" in text

    def test_command_line_errors(self, tmp_path, capsys):
        (tmp_path / "log.m").write_text("data_exc_dx = [1 2 pi];\n")
        assert main(["check-log", str(tmp_path / "log.m")]) == 1
        assert re.match(r"^ambid error: .*log\.m:1:20: names are not allowed inside a matrix", capsys.readouterr().err)


@pytest.mark.workflow
def test_readme_five_steps_as_written(tmp_path):
    """The README's 'Your machine in five steps' block, run by bash as it stands, in a fresh temporary directory."""
    readme = (ROOT / "README.md").read_text()
    section = readme.split("## Your machine in five steps", 1)[1]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    assert block.count("\nambid ") == 4 and "ambid run" in block
    environment = {**os.environ, "TMPDIR": str(tmp_path), "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
    result = subprocess.run(["bash", "-euo", "pipefail", "-c", block], cwd=ROOT, env=environment, capture_output=True,
                            text=True, timeout=900)
    assert result.returncode == 0, (result.stdout + result.stderr)[-3000:]
    reports = list(tmp_path.glob("*/results/rotor1/report.html"))
    assert len(reports) == 1 and reports[0].stat().st_size > 100_000
    assert "each step's noise pooled over 5 steps" in reports[0].read_text()  # the floor fact (frf.noise_half_width)
    workdir = reports[0].parents[2]
    assert "axis  steps  frequency grid" in result.stdout and "DX      100  2-1000 Hz" in result.stdout
    assert (workdir / "data/rotor1/run01/identification.parquet").exists()
    assert (workdir / "results/rotor1/export/run01/models.mat").exists()
    assert not (ROOT / "config/machines/rotor1.yaml").exists()  # nothing written into the repository
