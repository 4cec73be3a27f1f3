"""Thesis-compatible .m export: layout, literal syntax and exact round trip."""

import functools
import pickle
import re
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose, assert_array_equal

from ambid.errors import AmbidError, LogError
from ambid.logs import CHANNELS, channel_unit, identification_frame
from ambid.machine import ALL_AXES
from ambid.mfile import (
    AXIAL_COLUMNS,
    RADIAL_COLUMNS,
    THESIS_COLUMNS,
    MFileParseError,
    _complex,
    _real,
    parse_thesis_m,
    read_thesis_m,
    write_thesis_m,
)

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


# ---------------------------------------------------------------------------- reading back
FRAME_KEYS = ["excited_axis", "step", "frequency_hz", "amplitude_a", "channel"]


def test_read_round_trip(tmp_path):
    """write_thesis_m -> read_thesis_m gives the log back (noise_std and attempts are not in the format)."""
    frame = make_frame(axes=ALL_AXES)
    path = tmp_path / "run.m"
    write_thesis_m(frame, path, header_lines=("machine demo20, run r1",))
    back = read_thesis_m(path)
    pd.testing.assert_frame_equal(back[FRAME_KEYS], frame[FRAME_KEYS])
    position = frame["channel"].str.startswith("V2_").to_numpy()
    for part in ("re", "im"):
        # currents, frequency and amplitude: 17 significant digits round-trip exactly
        assert_array_equal(back[part].to_numpy()[~position], frame[part].to_numpy()[~position])
        # positions pass x1e6 on writing and /1e6 on reading: two roundings, at most ~2.2e-16 relative
        assert_allclose(back[part].to_numpy()[position], frame[part].to_numpy()[position], rtol=1e-15, atol=0)
    assert (back["noise_std"] == 0.0).all() and (back["attempts"] == 1).all()


def test_parse_written_file_is_complex_22_columns(written, frame):
    matrices = parse_thesis_m(written, "run.m")
    assert list(matrices) == ["data_exc_dx", "data_exc_ny"]
    for axis in ("DX", "NY"):
        matrix = matrices[f"data_exc_{axis.lower()}"]
        assert matrix.dtype == np.complex128 and matrix.shape == (N_STEPS, 22)
        assert matrix.tobytes() == expected_matrix(frame, axis).tobytes()


GRAMMAR_SAMPLE = """\
% hand-written, MATLAB-compatible
   % indented comment

data_exc_dx = [ % comment after a token
  1, 2 -3j ... the rest of a continued line is ignored
  .5 +3;  1. 2i,-0.0-1e-06i 4 , 5
  1.25+0i 1e-3  1.2E+4	7 8;

];
data_exc_z=[]   % empty: 0x0
data_exc_ny = [1;2;;3;]
"""


def test_grammar_acceptance():
    matrices = parse_thesis_m(GRAMMAR_SAMPLE)
    assert list(matrices) == ["data_exc_dx", "data_exc_z", "data_exc_ny"]
    expected = np.array(
        [
            [1, 2, complex(0.0, -3.0), 0.5, 3],  # "-3j" is 0 - 3i: the sign is the imaginary part's
            [1, 2j, complex(-0.0, -1e-06), 4, 5],
            [1.25, 1e-3, 1.2e4, 7, 8],
        ],
        dtype=complex,
    )
    assert matrices["data_exc_dx"].tobytes() == expected.tobytes()
    assert np.signbit(matrices["data_exc_dx"][1, 2].real)  # -0.0 keeps its sign
    assert matrices["data_exc_z"].shape == (0, 0) and matrices["data_exc_z"].dtype == np.complex128
    assert_array_equal(matrices["data_exc_ny"], [[1], [2], [3]])
    assert parse_thesis_m("") == {} and parse_thesis_m("% nothing\n\n") == {}


def test_grammar_matlab_details():
    """As in MATLAB's matrix context: a blank separates elements, a glued sign belongs to its number."""
    assert_array_equal(parse_thesis_m("data_exc_dx = [1 -2 +3i]")["data_exc_dx"], [[1, -2, 3j]])
    assert_array_equal(parse_thesis_m("data_exc_dx = [1-2i 3j]")["data_exc_dx"], [[1 - 2j, 3j]])
    assert_array_equal(parse_thesis_m("data_exc_dx = ...\n  [1 ...\n 2]\r\n")["data_exc_dx"], [[1, 2]])
    assert_array_equal(parse_thesis_m("data_exc_dx = [1...\n2]")["data_exc_dx"], [[1, 2]])


@pytest.mark.parametrize(
    "text, line, column, message",
    [
        ("x = [1 2]", 1, 1, "only data_exc_* assignments are allowed"),
        ("data_exc_dx = [1 2; 3]", 1, 21, "row has 1 column(s), the first row (line 1) has 2"),
        ("data_exc_dx = [1 2;\n  3 4 5]", 2, 3, "row has 3 column(s)"),
        ("data_exc_dx = [1 2", 1, 15, "unterminated matrix"),
        ("data_exc_dx = [1 2\n3 4\n", 1, 15, "unterminated matrix"),
        # MATLAB would compute 3; a standalone sign is arithmetic, refused
        ("data_exc_dx = [1 + 2]", 1, 18, "arithmetic is not allowed"),
        ("data_exc_dx = [1 - 2]", 1, 18, "arithmetic is not allowed"),
        ("data_exc_dx = [1+2]", 1, 17, "arithmetic is not allowed"),
        ("data_exc_dx = [2i+1]", 1, 18, "arithmetic is not allowed"),
        ("data_exc_dx = [1 2]*3", 1, 20, "arithmetic is not allowed"),
        ("data_exc_dx = [NaN 1]", 1, 16, "non-finite value 'NaN'"),
        ("data_exc_dx = [1 -Inf]", 1, 18, "non-finite value '-Inf'"),
        ("data_exc_dx = [1 inf]", 1, 18, "non-finite value 'inf'"),
        ("data_exc_dx = [1e999]", 1, 16, "non-finite data is not allowed"),
        ("system('rm -rf /')", 1, 1, "only data_exc_* assignments are allowed"),
        ("data_exc_dx = [[1]]", 1, 16, "nested brackets are not allowed"),
        ("data_exc_dx = [1]\n% again\ndata_exc_dx = [2]", 3, 1, "data_exc_dx is assigned twice (first at line 1)"),
        ("data_exc_dx = [0x1F]", 1, 17, "unexpected character 'x'"),
        ("data_exc_dx = [1 pi]", 1, 18, "names are not allowed"),
        ("data_exc_dx = [1 2]'", 1, 20, "transposes are not allowed"),
        ("data_exc_dx = ['12']", 1, 16, "strings"),
        ("data_exc_dx = zeros(2)", 1, 15, "expected '['"),
        ("data_exc_dx(1) = [1]", 1, 12, "function calls and indexing"),
        ("data_exc_dx = [1 2];  data_exc_dy = [1]", 1, 23, "expected end of line"),
        ("data_exc_dx = [1,,2]", 1, 18, "empty element"),
        ("data_exc_dx = [1,]", 1, 17, "trailing ','"),
        ("data_exc_dx = [1e]", 1, 17, "exponent has no digits"),
        ("data_exc_dx = [.]", 1, 16, "malformed number"),
        ("data_exc_dx = [1.2.3]", 1, 19, "unexpected character '.'"),
        ("data_exc_dx = [1\r2]", 1, 17, "unexpected character '\\r'"),
        ("%{\ndata_exc_dx = [1]\n%}", 1, 1, "block comments"),
        ("data_exc_dx =\n[1]", 1, 14, "expected '['"),
        ("\n\n  ; ", 3, 3, "expected an assignment"),
    ],
)
def test_rejections(text, line, column, message):
    with pytest.raises(MFileParseError) as info:
        parse_thesis_m(text, "bad.m")
    error = info.value
    assert (error.line, error.column) == (line, column), str(error)
    assert str(error).startswith(f"bad.m:{line}:{column}: ") and message in str(error)


def test_error_is_a_log_error_and_pickles():
    with pytest.raises(LogError) as info:
        parse_thesis_m("data_exc_dx = [1 2; 3]", "bad.m")
    error = info.value
    assert isinstance(error, AmbidError) and error.path == error.source == "bad.m"
    copy = pickle.loads(pickle.dumps(error))
    assert type(copy) is MFileParseError and str(copy) == str(error) and (copy.line, copy.column) == (1, 21)


def thesis_row(frequency, amplitude, n_values=20, imaginary="0.5"):
    return "  ".join([frequency, amplitude] + [f"1e-3+{imaginary}i"] * n_values) + ";"


def test_read_rejects_wrong_width(tmp_path):
    path = tmp_path / "narrow.m"
    path.write_text("% 21 columns\ndata_exc_dy = [\n  " + thesis_row("5", "0.1", n_values=19) + "\n];\n")
    with pytest.raises(MFileParseError, match=r"narrow\.m:3:3: data_exc_dy has 21 columns; the thesis layout has 22 "
                                              r"\(all channels\), the radial-only layout has 18"):
        read_thesis_m(path)
    path.write_text("data_exc_z = [\n  " + thesis_row("5", "0.1", n_values=16) + "\n];\n")  # 18 columns: radial only
    with pytest.raises(MFileParseError, match=r"narrow\.m:2:3: data_exc_z has 18 columns; .* the axial-only layout has 6"):
        read_thesis_m(path)


def test_read_rejects_complex_frequency(tmp_path):
    path = tmp_path / "complex.m"
    rows = [thesis_row("5", "0.1"), thesis_row("6+1e-9i", "0.1")]
    path.write_text("data_exc_z = [\n" + "\n".join(rows) + "\n];\n")
    with pytest.raises(MFileParseError, match=r"complex\.m:3:1: data_exc_z row 2: column 1 \(frequency \[Hz\]\) must be real"):
        read_thesis_m(path)


def test_read_validates_the_log(tmp_path):
    path = tmp_path / "grid.m"
    path.write_text("data_exc_nx = [\n" + thesis_row("6", "0.1") + "\n" + thesis_row("5", "0.1") + "\n];\n")
    with pytest.raises(LogError, match=r"grid\.m: rows 0-19 \(excited_axis=NX, step=0\), rows 20-39 .*NX not strictly increasing"):
        read_thesis_m(path)
    path.write_text("data_exc_nx = [\n" + thesis_row("6", "-0.1") + "\n];\n")
    with pytest.raises(LogError, match=r"grid\.m: .*amplitude_a <= 0"):
        read_thesis_m(path)


def test_read_file_errors(tmp_path):
    with pytest.raises(LogError, match=r"missing\.m: cannot read the file"):
        read_thesis_m(tmp_path / "missing.m")
    path = tmp_path / "empty.m"
    path.write_text("% no data\ndata_exc_dx = []\n")
    with pytest.raises(LogError, match=r"empty\.m: no data"):
        read_thesis_m(path)
    path.write_bytes(b"% caf\xc3\xa9\ndata_exc_dx = [1 \xff]\n")
    with pytest.raises(MFileParseError, match=r"empty\.m:2:18: not UTF-8"):
        read_thesis_m(path)


def test_read_accepts_bom_and_crlf(tmp_path):
    path = tmp_path / "windows.m"
    text = "data_exc_dx = [\r\n" + thesis_row("5", "0.1") + "\r\n" + thesis_row("7.5", "0.1") + "\r\n];\r\n"
    path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    frame = read_thesis_m(path)
    assert frame["step"].unique().tolist() == [0, 1] and frame["frequency_hz"].unique().tolist() == [5.0, 7.5]
    v2 = frame[frame["channel"] == "V2_DX"]
    assert_array_equal(v2["re"], 1e-3 / 1e6) and assert_array_equal(v2["im"], 0.5 / 1e6)


@pytest.mark.parametrize(
    "text",
    [
        "[" * 200_000,
        "data_exc_dx = [" + "[" * 200_000,
        "data_exc_dx = [" + "9" * 200_000 + "]",
        "data_exc_dx = [" + "1 " * 100_000 + "]",
        "data_exc_dx = [" + "1;" * 100_000 + "]",
        "data_exc_dx = [" + "1" * 100_000 + "e-" + "9" * 100_000 + "]",
        "data_exc_dx = [" + "..." * 100_000 + "]",
        "data_exc_dx = [1" + "e" * 200_000,
        "data_exc_dx = [" + "%" * 200_000,
        "a" * 200_000,
    ],
)
def test_adversarial_inputs_are_fast(text):
    """Linear scanner, no recursion: 200k-character pathological inputs finish quickly."""
    start = time.perf_counter()
    try:
        parse_thesis_m(text)
    except MFileParseError as error:
        assert len(str(error)) < 300  # offending text is quoted shortened
    assert time.perf_counter() - start < 5.0


# ---------------------------------------------------------------------------- properties
def check_total(text):
    """parse_thesis_m returns finite complex matrices or raises MFileParseError at a real position."""
    try:
        matrices = parse_thesis_m(text)
    except MFileParseError as error:
        lines = text.split("\n")
        assert 1 <= error.line <= len(lines)
        assert 1 <= error.column <= len(lines[error.line - 1]) + 1
        assert str(error).startswith(f"<string>:{error.line}:{error.column}: ")
        return
    assert isinstance(matrices, dict) and set(matrices) <= {f"data_exc_{a.lower()}" for a in ALL_AXES}
    for matrix in matrices.values():
        assert matrix.dtype == np.complex128 and matrix.ndim == 2 and np.isfinite(matrix).all()


# any character a UTF-8 file can hold (a lone surrogate cannot be written: the file test failed on U+D800, stop 56)
ALPHABET = st.one_of(st.sampled_from("[]0123456789ijeE+-.;,%= \t\n\r'()*xIfNa_d"), st.characters(exclude_categories=("Cs",)))
PREFIXES = st.sampled_from(["", "data_exc_dx = [", "data_exc_dx = [1 2;\n", "data_exc_z = [\n1.5+2i "])
FRAGMENTS = st.sampled_from(
    ["data_exc_dx", "data_exc_ny", " = ", "[", "]", ";", ",", "\n", "\r\n", " ", "...", "%", "%{", "1", "-2.5",
     ".5", "1.", "1e-3", "+3", "2i", "-3j", "1.25+0i", "-0.0-1e-06i", "1+", "Inf", "NaN", "e", "i", "x", "'", "("]
)


@settings(deadline=500, max_examples=300)
@given(prefix=PREFIXES, text=st.text(alphabet=ALPHABET, max_size=2000))
def test_arbitrary_text_parses_or_raises(prefix, text):
    check_total(prefix + text)


@settings(deadline=500, max_examples=300)
@given(fragments=st.lists(FRAGMENTS, max_size=300))
def test_fragment_soup_parses_or_raises(fragments):
    check_total("".join(fragments))


@functools.cache
def valid_text():
    """A small file written by write_thesis_m (two axes, four steps)."""
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "valid.m"
        write_thesis_m(make_frame(), path, header_lines=("mutation seed",))
        return path.read_text()


MUTATIONS = st.lists(
    st.tuples(st.sampled_from(["insert", "delete", "replace"]), st.floats(0, 1, exclude_max=True), ALPHABET),
    min_size=1,
    max_size=8,
)


def mutate(text, mutations):
    for kind, where, char in mutations:
        at = int(where * (len(text) + 1)) if kind == "insert" else int(where * len(text))
        if kind == "insert":
            text = text[:at] + char + text[at:]
        elif text:
            text = text[:at] + ("" if kind == "delete" else char) + text[at + 1 :]
    return text


@settings(deadline=500, max_examples=300)
@given(mutations=MUTATIONS)
def test_mutated_file_parses_or_raises(mutations):
    check_total(mutate(valid_text(), mutations))


@settings(deadline=2000, max_examples=40, suppress_health_check=[HealthCheck.too_slow])
@given(mutations=MUTATIONS)
def test_mutated_file_reads_or_raises_log_error(mutations):
    """read_thesis_m on a mutated file: a valid log or the project's own LogError, nothing else."""
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "mutated.m"
        path.write_text(mutate(valid_text(), mutations), encoding="utf-8")
        try:
            frame = read_thesis_m(path)
        except LogError as error:
            assert str(path) in str(error)
        else:
            assert len(frame) % len(CHANNELS) == 0


FINITE = st.floats(allow_nan=False, allow_infinity=False, allow_subnormal=True)
ELEMENT = st.tuples(FINITE, FINITE, st.booleans())


@st.composite
def matrices(draw):
    rows = draw(st.integers(1, 5))
    columns = draw(st.integers(1, 6))
    return [draw(st.lists(ELEMENT, min_size=columns, max_size=columns)) for _ in range(rows)]


@settings(deadline=500, max_examples=300)
@given(name=st.sampled_from([f"data_exc_{a.lower()}" for a in ALL_AXES]), elements=matrices())
def test_writer_number_format_round_trips_exactly(name, elements):
    """Every finite double (subnormals and -0.0 included), as _real or as re+imi, parses bit for bit."""
    lines = [f"{name} = ["]
    expected = []
    for row in elements:
        texts, values = [], []
        for re_part, im_part, real_only in row:
            value = complex(re_part, 0.0 if real_only else im_part)
            texts.append(_real(re_part) if real_only else _complex(value))
            values.append(value)
        lines.append("  ".join(texts) + ";")
        expected.append(values)
    lines.append("];")
    parsed = parse_thesis_m("\n".join(lines) + "\n")[name]
    assert parsed.tobytes() == np.array(expected, dtype=np.complex128).tobytes()


def test_a_step_keeps_its_line(tmp_path):
    path = tmp_path / "identification.m"
    row = "  ".join(["10", "0.5"] + ["1+0i"] * 20)
    split = "  ".join(["20", "0.5"] + ["1+0i"] * 10) + " ...\n  " + "  ".join(["1+0i"] * 10)
    path.write_text(f"% header\n\ndata_exc_nx = [\n{row};\n{split};\n{row.replace('10', '30', 1)};\n];\n")
    lines = read_thesis_m(path).attrs["source_lines"]
    assert lines["NX"][0] == 4 and lines["NX"][2] == 7
    assert lines["NX"][1] == [5] * 12 + [6] * 10  # a row continued over two lines: each element's line


def test_an_oversized_line_is_refused_without_reading_the_file(tmp_path, monkeypatch):
    import builtins

    import ambid.mfile as mfile

    path = tmp_path / "identification.m"
    path.write_bytes(b"data_exc_dx = [" + b"1 " * 10_000_000 + b"];\n")  # 20 MB on one line
    read = []

    class Counting:
        def __init__(self, handle):
            self.handle = handle

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.handle.close()

        def fileno(self):
            return self.handle.fileno()

        def read(self, size):
            data = self.handle.read(size)
            read.append(len(data))
            return data

    monkeypatch.setattr(mfile, "open", lambda *args: Counting(builtins.open(*args)), raising=False)
    with pytest.raises(MFileParseError, match=r"identification.m:1:65537: line longer than 65536 bytes"):
        read_thesis_m(path)
    assert sum(read) <= 2 * mfile.MAX_LINE_BYTES  # 128 KiB of the 20 MB


def own_channels_only(frame):
    """The log as the 18 + 6 column layout holds it: each step its own bearing's channels."""
    radial = frame["excited_axis"] != "Z"
    return frame[radial == ~frame["channel"].str.endswith("_Z")].reset_index(drop=True)


def test_radial_and_axial_layout_round_trips(tmp_path):
    """The 18-column radial + 6-column axial layout: written for a partial log, read back exactly."""
    frame = own_channels_only(make_frame(axes=("DX", "NY", "Z")))
    path = tmp_path / "split.m"
    write_thesis_m(frame, path)
    text = path.read_text()
    matrices = read_m(text)
    assert {len(row) for row in matrices["data_exc_dx"]} == {18} and {len(row) for row in matrices["data_exc_z"]} == {6}
    assert "columns of data_exc_z (axial bearing only): 1 frequency [Hz], 2 amplitude [A], 3 U2_Z [A], 4 V2_Z [um]" in text
    assert len(RADIAL_COLUMNS) == 18 and RADIAL_COLUMNS[6] == "V2_DX [um]" and AXIAL_COLUMNS[-1] == "I_lower_Z [A]"
    back = read_thesis_m(path)
    assert len(back) == 2 * N_STEPS * 16 + N_STEPS * 4
    assert_allclose(back[["re", "im"]].to_numpy(), frame[["re", "im"]].to_numpy(), rtol=1e-15, atol=0)  # um: 2 roundings
    assert list(back["channel"]) == list(frame["channel"])


def test_both_layouts_in_one_file(tmp_path):
    """A full 22-column radial matrix next to a 6-column Z matrix: each matrix's width tells its layout."""
    full = make_frame(axes=("DX",))
    axial = own_channels_only(make_frame(axes=("Z",)))
    path = tmp_path / "mixed.m"
    write_thesis_m(full, tmp_path / "dx.m")
    write_thesis_m(axial, tmp_path / "z.m")
    body = lambda name: (tmp_path / name).read_text().split("\n", 2)[-1]  # noqa: E731 (drop the columns comment)
    path.write_text(body("dx.m") + body("z.m"))
    back = read_thesis_m(path)
    assert back.groupby("excited_axis")["channel"].nunique().to_dict() == {"DX": 20, "Z": 4}


def test_zero_padding_of_the_other_bearing_is_left_out(tmp_path):
    """A user who padded the axial channels of radial steps (and vice versa) with 0 to reach 22 columns."""
    frame = own_channels_only(make_frame(axes=("DX", "Z")))
    padded = frame.copy()
    missing = []
    for (axis, step), part in frame.groupby(["excited_axis", "step"]):
        for channel in sorted(set(CHANNELS) - set(part["channel"])):
            missing.append({**part.iloc[0].to_dict(), "channel": channel, "re": 0.0, "im": 0.0})
    padded = pd.concat([padded, pd.DataFrame(missing)], ignore_index=True)
    padded = padded.assign(order=padded["channel"].map(CHANNELS.index)).sort_values(["excited_axis", "step", "order"])
    path = tmp_path / "padded.m"
    write_thesis_m(padded.drop(columns="order"), path)
    assert {len(row) for rows in read_m(path.read_text()).values() for row in rows} == {22}
    notes = []
    back = read_thesis_m(path, notes=notes)
    assert back.groupby("excited_axis")["channel"].nunique().to_dict() == {"DX": 16, "Z": 4}
    assert notes == ["data_exc_dx: the other bearing's 4 columns are 0 on every step (padding): left out",
                     "data_exc_z: the other bearing's 16 columns are 0 on every step (padding): left out"]
