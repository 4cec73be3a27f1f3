"""Thesis-compatible .m export: layout, literal syntax and exact round trip."""

import re

import numpy as np
import pytest
from numpy.testing import assert_allclose

from ambid.errors import LogError
from ambid.logs import CHANNELS, channel_unit, identification_frame
from ambid.mfile import THESIS_COLUMNS, write_thesis_m

N_STEPS = 4
NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?"
REAL = re.compile(rf"^{NUMBER}$")
COMPLEX = re.compile(rf"^({NUMBER})([+-](?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?)i$")
ASSIGNMENT = re.compile(r"^(\w+) = \[\n(.*?)^\];$", re.MULTILINE | re.DOTALL)


def read_m(text):
    """Minimal test-only reader: variable name -> list of rows of numbers (complex from col. 3)."""
    matrices = {}
    for name, body in ASSIGNMENT.findall(text):
        rows = []
        for line in body.splitlines():
            assert line.endswith(";") and "   " not in line, line
            fields = line[:-1].split("  ")
            assert all(REAL.match(f) for f in fields[:2]), fields[:2]
            values = [float(f) for f in fields[:2]]
            for field in fields[2:]:
                match = COMPLEX.match(field)
                assert match, field
                values.append(complex(float(match.group(1)), float(match.group(2))))
            rows.append(values)
        matrices[name] = rows
    return matrices


def make_frame(axes=("DX", "NY"), seed=5):
    rng = np.random.default_rng(seed)
    scale = np.array([1e-6 if channel_unit(c) == "m" else 0.1 for c in CHANNELS])
    steps = [
        {
            "excited_axis": axis,
            "step": step,
            "frequency_hz": 5.0 + 13.7 * step + 0.1 / 3,
            "amplitude_a": 0.02 * (1 + step) / 3,
            "attempts": 1,
            "coefficients": scale * (rng.standard_normal(20) + 1j * rng.standard_normal(20)) * 10.0 ** rng.integers(-3, 3, 20),
            "noise_std": scale * 1e-3,
        }
        for axis in axes
        for step in range(N_STEPS)
    ]
    return identification_frame(steps)


@pytest.fixture
def frame():
    return make_frame()


@pytest.fixture
def written(frame, tmp_path):
    path = tmp_path / "run.m"
    write_thesis_m(frame, path, header_lines=("machine demo20, run r1", "seed 5"))
    return path.read_text()


def expected_matrix(frame, axis):
    """(n_steps, 22) complex matrix in the thesis layout, positions in µm."""
    index = {name: i for i, name in enumerate(CHANNELS)}
    order = (
        [f"U2_{a}" for a in ("DX", "DY", "NX", "NY")]
        + [f"V2_{a}" for a in ("DX", "DY", "NX", "NY")]
        + [f"I_{side}_{a}" for a in ("DX", "DY", "NX", "NY") for side in ("upper", "lower")]
        + ["U2_Z", "V2_Z", "I_upper_Z", "I_lower_Z"]
    )
    rows = []
    for step in range(N_STEPS):
        part = frame[(frame["excited_axis"] == axis) & (frame["step"] == step)]
        values = (part["re"] + 1j * part["im"]).to_numpy()
        assert list(part["channel"]) == list(CHANNELS)
        row = [part["frequency_hz"].iloc[0], part["amplitude_a"].iloc[0]]
        row += [values[index[name]] * (1e6 if name.startswith("V2_") else 1.0) for name in order]
        rows.append(row)
    return np.array(rows, dtype=complex)


def test_thesis_columns():
    assert len(THESIS_COLUMNS) == 22
    assert THESIS_COLUMNS[0].startswith("frequency") and "[Hz]" in THESIS_COLUMNS[0]
    assert THESIS_COLUMNS[2].startswith("U2_DX") and THESIS_COLUMNS[6].startswith("V2_DX") and "um" in THESIS_COLUMNS[6]
    assert THESIS_COLUMNS[10].startswith("I_upper_DX") and THESIS_COLUMNS[17].startswith("I_lower_NY")
    assert [c.split()[0] for c in THESIS_COLUMNS[18:]] == ["U2_Z", "V2_Z", "I_upper_Z", "I_lower_Z"]


def test_header_and_assignments(written):
    lines = written.splitlines()
    assert lines[0] == "% machine demo20, run r1" and lines[1] == "% seed 5"
    assert lines[2].startswith("% ") and "7 V2_DX [um]" in lines[2] and "22 I_lower_Z [A]" in lines[2]
    assert re.findall(r"^(\w+) = \[$", written, re.MULTILINE) == ["data_exc_dx", "data_exc_ny"]
    assert written.count("];") == 2 and written.endswith("];\n")
    for line in lines:
        assert line == "" or line.startswith("% ") or line.endswith("= [") or line.endswith(";")


def test_rows_round_trip_exactly(frame, written):
    matrices = read_m(written)
    assert sorted(matrices) == ["data_exc_dx", "data_exc_ny"]
    for axis in ("DX", "NY"):
        rows = matrices[f"data_exc_{axis.lower()}"]
        assert len(rows) == N_STEPS and all(len(row) == 22 for row in rows)
        actual = np.array(rows, dtype=complex)
        expected = expected_matrix(frame, axis)
        assert_allclose(actual.real, expected.real, rtol=1e-15, atol=0)
        assert_allclose(actual.imag, expected.imag, rtol=1e-15, atol=0)
        assert np.all(actual[:, :2].imag == 0)


def test_positions_in_micrometres(frame, written):
    dx = np.array(read_m(written)["data_exc_dx"], dtype=complex)
    part = frame[(frame["excited_axis"] == "DX") & (frame["channel"] == "V2_NX")].sort_values("step")
    assert_allclose(dx[:, 8], (part["re"] + 1j * part["im"]).to_numpy() * 1e6, rtol=1e-15)
    part = frame[(frame["excited_axis"] == "DX") & (frame["channel"] == "V2_Z")].sort_values("step")
    assert_allclose(dx[:, 19], (part["re"] + 1j * part["im"]).to_numpy() * 1e6, rtol=1e-15)


def test_thesis_plant_formula(frame, written):
    """The appendix' data_exc_dx(:,7)./data_exc_dx(:,3)/1e6 is the DX plant in m/A."""
    dx = np.array(read_m(written)["data_exc_dx"], dtype=complex)
    thesis_plant = dx[:, 6] / dx[:, 2] / 1e6
    part = frame[frame["excited_axis"] == "DX"]
    by_channel = {c: (g.sort_values("step")["re"] + 1j * g.sort_values("step")["im"]).to_numpy() for c, g in part.groupby("channel")}
    assert_allclose(thesis_plant, by_channel["V2_DX"] / by_channel["U2_DX"], rtol=1e-14)


def test_complex_literal_syntax(tmp_path):
    frame = make_frame(axes=("Z",))
    frame.loc[2, ["re", "im"]] = [-3.2e-06, -1.1e-04]  # U2_NX of step 0
    frame.loc[3, ["re", "im"]] = [1.25, 0.0]  # U2_NY of step 0
    path = tmp_path / "z.m"
    write_thesis_m(frame, path)
    text = path.read_text()
    assert re.findall(r"^(\w+) = \[$", text, re.MULTILINE) == ["data_exc_z"]
    first = text.split("data_exc_z = [\n")[1].splitlines()[0].split("  ")
    assert first[4] == "-3.1999999999999999e-06-0.00011i"
    assert first[5] == "1.25+0i"
    assert float(first[0]) == frame["frequency_hz"].iloc[0]


def test_invalid_frame_writes_nothing(frame, tmp_path):
    path = tmp_path / "run.m"
    bad = frame.drop(index=frame.index[5])
    with pytest.raises(LogError, match=r"run\.m: rows 0-18 \(excited_axis=DX, step=0\): missing channel\(s\) V2_DX"):
        write_thesis_m(bad, path)
    assert list(tmp_path.iterdir()) == []
