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
