"""Parquet with units and schema version; atomic writes."""

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from ambid.errors import AmbidError
from ambid.io import atomic_path, frf_frame, frf_from_frame, read_parquet, write_parquet


def test_frf_round_trip_with_metadata(tmp_path):
    f = np.linspace(1, 10, 5)
    response = (np.arange(5 * 2 * 3) + 1j * np.arange(5 * 2 * 3)[::-1]).reshape(5, 2, 3)
    frame = frf_frame(f, response, ["A", "B"], ["X", "Y", "Z"])
    path = tmp_path / "frf.parquet"
    write_parquet(frame, path, units={"frequency_hz": "Hz", "re": "m/A", "im": "m/A"}, kind="plant_frf", metadata={"machine": "m"})
    back, info = read_parquet(path, kind="plant_frf")
    assert info["units"]["re"] == "m/A" and info["schema_version"] == "1" and info["metadata"] == {"machine": "m"}
    frequency, values = frf_from_frame(back, "B", "Z")
    assert_allclose(frequency, f)
    assert_allclose(values, response[:, 1, 2])


def test_units_required_for_numeric_columns(tmp_path):
    with pytest.raises(AmbidError, match="no unit"):
        write_parquet(pd.DataFrame({"x": [1.0]}), tmp_path / "a.parquet", units={}, kind="k")


def test_wrong_kind_and_foreign_files_are_rejected(tmp_path):
    path = tmp_path / "a.parquet"
    write_parquet(pd.DataFrame({"x": [1.0]}), path, units={"x": "m"}, kind="k")
    with pytest.raises(AmbidError, match="expected 'plant_frf'"):
        read_parquet(path, kind="plant_frf")
    pd.DataFrame({"x": [1.0]}).to_parquet(tmp_path / "b.parquet")
    with pytest.raises(AmbidError, match="no ambid metadata"):
        read_parquet(tmp_path / "b.parquet")
    (tmp_path / "c.parquet").write_text("not parquet")
    with pytest.raises(AmbidError, match="c.parquet"):
        read_parquet(tmp_path / "c.parquet")


def test_atomic_path_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.txt"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as temporary:
            temporary.write_text("half")
            raise RuntimeError("crash")
    assert not target.exists() and list(tmp_path.iterdir()) == []


class TestStrictYaml:
    def test_duplicate_keys_are_refused_with_key_and_lines(self, tmp_path):
        from ambid.errors import ConfigError
        from ambid.io import load_yaml, read_yaml

        text = "materials:\n  steel:\n    youngs_modulus_pa: 2.0e+11\n    youngs_modulus_pa: 2.0e+9\n"
        with pytest.raises(ConfigError, match=r"^m.yaml: materials.steel.youngs_modulus_pa: duplicate key \(lines 3 and 4\)"):
            load_yaml(text, "m.yaml")
        with pytest.raises(ConfigError, match=r"effects\[1\].name: duplicate key"):
            load_yaml("effects:\n  - {name: delay}\n  - {name: delay, name: amplifier_lowpass}\n", "m.yaml")
        assert load_yaml("a: {b: 1, c: 2}\nd: [1, 2]\n", "m.yaml") == {"a": {"b": 1, "c": 2}, "d": [1, 2]}
        path = tmp_path / "bad.yaml"
        path.write_text("a: [1, 2\n")
        with pytest.raises(ConfigError, match=r"bad.yaml: \(file\): not valid YAML at line 2, column 1"):
            read_yaml(path)
        path.write_text("- 1\n")
        with pytest.raises(ConfigError, match="machines.m.model: .*does not hold a mapping"):
            read_yaml(path, "machines.m.model")


def test_file_digest_follows_content_not_time(tmp_path):
    import os

    from ambid.io import file_digest

    path = tmp_path / "log.m"
    path.write_text("data_exc_dx = [1 2];\n")
    first = file_digest(path)
    path.write_text("data_exc_dx = [1 3];\n")
    os.utime(path, (1e9, 1e9))  # an older modification time, as cp -p / tar leave it
    assert file_digest(path) != first and len(first) == 16
    assert file_digest(tmp_path / "absent") == "missing"


def test_project_errors_cross_process_pools():
    """A worker's ConfigError or LogError comes back whole (benchmarks and cluster jobs pickle them)."""
    import pickle

    from ambid.errors import ConfigError, LogError
    from ambid.mfile import MFileParseError

    for error in (ConfigError("truth.effects[0]", "unknown effect", source="rig.yaml"), LogError("log.parquet", "row 3"),
                  MFileParseError("x.m", 4, 2, "bad token")):
        back = pickle.loads(pickle.dumps(error))
        assert type(back) is type(error) and str(back) == str(error)
