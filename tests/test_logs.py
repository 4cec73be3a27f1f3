"""Identification log: frame layout, Parquet round trip and validation errors."""

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from ambid.errors import AmbidError, LogError
from ambid.logs import (
    AXIAL_CHANNELS,
    CHANNELS,
    COIL_CURRENT_CHANNELS,
    OPTIONAL_COLUMNS,
    RADIAL_CHANNELS,
    axis_channels,
    scatter_std,
    channel_unit,
    identification_frame,
    noise_from_scatter,
    read_identification_log,
    validate_identification_log,
    write_identification_log,
)
from ambid.machine import ALL_AXES

N_STEPS = 4
COLUMNS = ["excited_axis", "step", "frequency_hz", "amplitude_a", "channel", "re", "im", "noise_std", "attempts"]


def make_steps(axes=("DY", "DX"), n_steps=N_STEPS, seed=1):
    """Synthetic step records, deliberately not in canonical order."""
    rng = np.random.default_rng(seed)
    scale = np.array([channel_unit(c) == "m" and 1e-6 or 0.1 for c in CHANNELS])
    steps = []
    for axis in axes:
        for step in reversed(range(n_steps)):
            steps.append(
                {
                    "excited_axis": axis,
                    "step": step,
                    "frequency_hz": 10.0 + 25.0 * step,
                    "amplitude_a": 0.05 + 0.01 * step,
                    "attempts": 1 + step % 2,
                    "coefficients": scale * (rng.standard_normal(20) + 1j * rng.standard_normal(20)),
                    "noise_std": scale * rng.uniform(0.001, 0.01, 20),
                }
            )
    return steps


@pytest.fixture
def steps():
    return make_steps()


@pytest.fixture
def frame(steps):
    return identification_frame(steps)


def test_channels_and_units():
    assert len(CHANNELS) == 20 and len(set(CHANNELS)) == 20
    assert CHANNELS[:10] == ("U2_DX", "U2_DY", "U2_NX", "U2_NY", "U2_Z", "V2_DX", "V2_DY", "V2_NX", "V2_NY", "V2_Z")
    assert CHANNELS[10:14] == ("I_upper_DX", "I_lower_DX", "I_upper_DY", "I_lower_DY")
    assert CHANNELS[-2:] == ("I_upper_Z", "I_lower_Z")
    assert channel_unit("V2_NY") == "m" and channel_unit("U2_Z") == "A" and channel_unit("I_lower_DX") == "A"
    with pytest.raises(LogError, match="V3_DX"):
        channel_unit("V3_DX")


def test_frame_shape_order_and_dtypes(frame, steps):
    assert list(frame.columns) == list(COLUMNS) + list(OPTIONAL_COLUMNS)
    assert frame.shape == (2 * N_STEPS * 20, 10)
    assert list(frame["excited_axis"].iloc[::20]) == ["DX"] * N_STEPS + ["DY"] * N_STEPS
    assert_array_equal(frame["step"].iloc[::20], list(range(N_STEPS)) * 2)
    assert list(frame["channel"]) == list(CHANNELS) * 2 * N_STEPS
    for name in ("step", "attempts", "level"):
        assert frame[name].dtype == np.int64
    for name in ("frequency_hz", "amplitude_a", "re", "im", "noise_std"):
        assert frame[name].dtype == np.float64
    assert pd.api.types.is_string_dtype(frame["excited_axis"]) and pd.api.types.is_string_dtype(frame["channel"])
    record = next(s for s in steps if s["excited_axis"] == "DY" and s["step"] == 2)
    rows = frame[(frame["excited_axis"] == "DY") & (frame["step"] == 2)]
    assert_array_equal(rows["re"] + 1j * rows["im"], record["coefficients"])
    assert_array_equal(rows["noise_std"], record["noise_std"])
    assert set(rows["frequency_hz"]) == {record["frequency_hz"]} and set(rows["attempts"]) == {record["attempts"]}
    validate_identification_log(frame, "frame")


def test_frame_rejects_malformed_records(steps):
    steps[0]["coefficients"] = steps[0]["coefficients"][:19]
    with pytest.raises(LogError, match=r"step record 0: coefficients has shape \(19,\)"):
        identification_frame(steps)
    steps = make_steps()
    del steps[1]["attempts"]
    with pytest.raises(LogError, match=r"step record 1: missing key\(s\) \['attempts'\]"):
        identification_frame(steps)
    steps = make_steps()
    steps[2]["excited_axis"] = "DZ"
    with pytest.raises(LogError, match="step record 2: unknown axis 'DZ'"):
        identification_frame(steps)


def test_round_trip(frame, tmp_path):
    path = tmp_path / "identification.parquet"
    write_identification_log(frame, path, {"machine": "demo20", "run": "r1", "seed": 7, "settings": {"cycles": 20}})
    back, info = read_identification_log(path)
    assert list(back.columns) == list(COLUMNS) + list(OPTIONAL_COLUMNS)
    assert_array_equal(back["excited_axis"], frame["excited_axis"])
    assert_array_equal(back["channel"], frame["channel"])
    for name in COLUMNS[1:4] + COLUMNS[5:]:
        assert back[name].dtype == frame[name].dtype
        assert_allclose(back[name], frame[name], rtol=0, atol=0)
    assert info["schema_version"] == "1" and info["kind"] == "identification_log"
    assert info["units"]["frequency_hz"] == "Hz" and info["units"]["amplitude_a"] == "A"
    assert info["units"]["step"] == "-" and info["units"]["attempts"] == "-"
    assert "m for V2_*" in info["units"]["re"] and info["units"]["im"] == info["units"]["noise_std"] == info["units"]["re"]
    metadata = info["metadata"]
    assert metadata["machine"] == "demo20" and metadata["seed"] == 7 and metadata["settings"] == {"cycles": 20}
    assert metadata["channel_units"] == {c: ("m" if c.startswith("V2_") else "A") for c in CHANNELS}


def test_read_rejects_other_kinds(tmp_path):
    from ambid.io import write_parquet

    path = tmp_path / "identification.parquet"
    write_parquet(pd.DataFrame({"x": [1.0]}), path, units={"x": "m"}, kind="calibration_log")
    with pytest.raises(AmbidError, match="expected 'identification_log'"):
        read_identification_log(path)


def test_read_validates(frame, tmp_path):
    """A file written behind the validator's back is rejected on reading."""
    from ambid.io import write_parquet
    from ambid.logs import UNITS

    bad = frame.copy()
    bad.loc[25, "noise_std"] = -1.0
    path = tmp_path / "identification.parquet"
    write_parquet(bad, path, units=UNITS, kind="identification_log")
    with pytest.raises(LogError, match=r"identification\.parquet: row 25 \(excited_axis=DX, step=1\): noise_std < 0"):
        read_identification_log(path)


def _rows(frame, axis, step):
    return frame.index[(frame["excited_axis"] == axis) & (frame["step"] == step)]


def _set(frame, axis, step, column, value, channel=None):
    rows = _rows(frame, axis, step)
    if channel is not None:
        rows = rows[frame.loc[rows, "channel"] == channel]
    frame.loc[rows, column] = value
    return frame


def _drop_channel(frame):
    return frame.drop(index=_rows(frame, "DY", 3)[-1])


def _duplicate_channel(frame):
    return pd.concat([frame, frame.loc[[_rows(frame, "DX", 2)[5]]]], ignore_index=True)


def _swap_frequencies(frame):
    _set(frame, "DY", 1, "frequency_hz", 60.0 + 25.0)
    return _set(frame, "DY", 2, "frequency_hz", 60.0)


# (mutation, regex that the message must match beyond the file name)
MUTATIONS = {
    "missing column": (lambda f: f.drop(columns="noise_std"), r"missing column\(s\) \['noise_std'\]"),
    "extra column": (lambda f: f.assign(gain=1.0), r"unexpected column\(s\) \['gain'\]"),
    "float step": (lambda f: f.astype({"step": float}), r"column 'step' has dtype float64, expected int"),
    "string amplitude": (lambda f: f.astype({"amplitude_a": str}), r"column 'amplitude_a' has dtype .*expected float"),
    "unknown channel": (
        lambda f: _set(f, "DX", 3, "channel", "V2_QQ", channel="V2_DX"),
        r"row 65 \(excited_axis=DX, step=3\): unknown channel 'V2_QQ'",
    ),
    "unknown axis": (lambda f: _set(f, "DY", 0, "excited_axis", "AX"), r"rows 80-99 \(excited_axis=AX, step=0\): unknown excited_axis"),
    "nan re": (lambda f: _set(f, "DY", 2, "re", np.nan, channel="U2_NX"), r"row 122 \(excited_axis=DY, step=2\): re is not finite"),
    "inf im": (lambda f: _set(f, "DX", 0, "im", np.inf, channel="I_lower_Z"), r"row 19 \(excited_axis=DX, step=0\): im is not finite"),
    "inf frequency": (lambda f: _set(f, "DX", 1, "frequency_hz", np.inf), r"rows 20-39 \(excited_axis=DX, step=1\): frequency_hz is not finite"),
    "negative noise": (
        lambda f: _set(f, "DY", 1, "noise_std", -1e-9, channel="V2_DY"),
        r"row 106 \(excited_axis=DY, step=1\): noise_std < 0 \(first: channel V2_DY\)",
    ),
    "zero amplitude": (lambda f: _set(f, "DX", 2, "amplitude_a", 0.0), r"rows 40-59 \(excited_axis=DX, step=2\): amplitude_a <= 0"),
    "zero attempts": (lambda f: _set(f, "DY", 3, "attempts", 0), r"rows 140-159 \(excited_axis=DY, step=3\): attempts < 1"),
    "negative step": (lambda f: _set(f, "DX", 0, "step", -1), r"rows 0-19 \(excited_axis=DX, step=-1\): step < 0"),
    "decreasing grid": (
        _swap_frequencies,
        r"rows 100-119 \(excited_axis=DY, step=1\), rows 120-139 \(excited_axis=DY, step=2\): frequency grid of DY not strictly increasing .*step 2 at 60 Hz follows step 1 at 85 Hz",
    ),
    "equal frequencies": (
        lambda f: _set(f, "DX", 3, "frequency_hz", 60.0),
        r"rows 40-59 \(excited_axis=DX, step=2\), rows 60-79 \(excited_axis=DX, step=3\): frequency grid of DX not strictly increasing",
    ),
    "missing channel": (_drop_channel, r"rows 140-158 \(excited_axis=DY, step=3\): missing channel\(s\) I_lower_Z"),
    "duplicate channel": (
        _duplicate_channel,
        r"rows 45, 160 \(excited_axis=DX, step=2\): duplicate channel .*\(first: channel V2_DX\)",
    ),
    "inconsistent frequency": (
        lambda f: _set(f, "DX", 1, "frequency_hz", 36.0, channel="U2_DY"),
        r"rows 20-39 \(excited_axis=DX, step=1\): rows disagree on frequency_hz \(35.0, 36.0\)",
    ),
    "inconsistent amplitude": (
        lambda f: _set(f, "DY", 0, "amplitude_a", 0.07, channel="I_upper_NX"),
        r"rows 80-99 \(excited_axis=DY, step=0\): rows disagree on amplitude_a",
    ),
    "inconsistent attempts": (
        lambda f: _set(f, "DY", 2, "attempts", 3, channel="V2_Z"),
        r"rows 120-139 \(excited_axis=DY, step=2\): rows disagree on attempts \(1, 3\)",
    ),
    "no rows": (lambda f: f.iloc[:0], r"no rows"),
}


@pytest.mark.parametrize("name", sorted(MUTATIONS))
def test_validation_errors_name_file_and_rows(frame, tmp_path, name):
    mutate, message = MUTATIONS[name]
    bad = mutate(frame.copy())
    path = tmp_path / "identification.parquet"
    with pytest.raises(LogError, match=r"identification\.parquet: " + message):
        write_identification_log(bad, path, {"machine": "m"})
    assert not path.exists()
    assert list(tmp_path.iterdir()) == []


def test_valid_frame_need_not_be_sorted_nor_cover_all_axes(frame):
    validate_identification_log(frame.sample(frac=1.0, random_state=3), "shuffled")
    validate_identification_log(identification_frame(make_steps(axes=ALL_AXES, n_steps=2)), "all axes")
    gaps = frame[frame["step"] != 1]  # a rejected step leaves a gap in the grid
    validate_identification_log(gaps, "gaps")


def test_noise_from_scatter_recovers_each_sensors_noise():
    """A smooth response plus complex white noise of known std per channel: the estimate within 10 %;
    a channel with a strong response on one excited axis takes its noise from the axis that leaves it quiet."""
    rng = np.random.default_rng(5)
    frequency = np.linspace(5.0, 1000.0, 200)
    sigma = np.where([channel_unit(c) == "m" for c in CHANNELS], 1e-8, 5e-4)
    steps = []
    for axis in ("DX", "DY"):
        for k, f in enumerate(frequency):
            response = np.where([c == f"V2_{axis}" for c in CHANNELS], 1e-5 / (1 - (f / 455.0) ** 2 + 0.02j * f / 455.0), 0)
            response = response + np.where([c == f"U2_{axis}" for c in CHANNELS], 0.5, 0)
            noise = sigma * (rng.standard_normal(20) + 1j * rng.standard_normal(20)) / np.sqrt(2)
            steps.append({"excited_axis": axis, "step": k, "frequency_hz": f, "amplitude_a": 0.5, "attempts": 1,
                          "coefficients": response + noise, "noise_std": np.zeros(20)})
    estimated = noise_from_scatter(identification_frame(steps)).groupby("channel")["noise_std"].first()
    assert_allclose(estimated[list(CHANNELS)].to_numpy(), sigma, rtol=0.1)
    # excited on its own axis only, the resonance inflates the resonant channel's scatter
    alone = noise_from_scatter(identification_frame([s for s in steps if s["excited_axis"] == "DX"]))
    assert alone.loc[alone["channel"] == "V2_DX", "noise_std"].iloc[0] > 1.2 * estimated["V2_DX"]


def test_noise_from_scatter_needs_three_steps():
    frame = identification_frame(make_steps(n_steps=2))
    with pytest.raises(LogError, match="fewer than 3 steps"):
        noise_from_scatter(frame, "run.m")


def test_categorical_columns_are_read_as_their_values(frame, tmp_path):
    """A log from another writer may store its names as pandas categories or Parquet dictionaries."""
    from ambid.io import write_parquet
    from ambid.logs import UNITS

    categorical = frame.assign(excited_axis=frame["excited_axis"].astype("category"),
                               channel=frame["channel"].astype("category"), step=frame["step"].astype("category"))
    validate_identification_log(categorical, "x.parquet")
    path = tmp_path / "identification.parquet"
    write_parquet(categorical, path, units=UNITS, kind="identification_log")
    back, _ = read_identification_log(path)
    assert not any(isinstance(back[c].dtype, pd.CategoricalDtype) for c in back.columns)
    assert_array_equal(back["excited_axis"].to_numpy(dtype=object), frame["excited_axis"].to_numpy(dtype=object))


def own_bearing_only(frame):
    """Each step with its own bearing's channels only (radial steps 16, axial steps 4)."""
    radial = frame["excited_axis"] != "Z"
    return frame[radial == ~frame["channel"].str.endswith("_Z")].reset_index(drop=True)


class TestPartialChannelSets:
    """Logs whose steps carry only the channels of their bearing (radial steps the 16 radial, Z steps the 4 axial)."""

    def test_channel_groups(self):
        assert len(RADIAL_CHANNELS) == 16 and len(AXIAL_CHANNELS) == 4
        assert set(RADIAL_CHANNELS) | set(AXIAL_CHANNELS) == set(CHANNELS)
        assert axis_channels("NY") == RADIAL_CHANNELS and axis_channels("Z") == AXIAL_CHANNELS

    def test_own_bearing_only_is_valid_and_round_trips(self, tmp_path):
        frame = own_bearing_only(identification_frame(make_steps(axes=ALL_AXES)))
        validate_identification_log(frame, "partial")
        write_identification_log(frame, tmp_path / "log.parquet")
        back, _ = read_identification_log(tmp_path / "log.parquet")
        pd.testing.assert_frame_equal(back, frame)

    def test_records_with_channel_subsets(self):
        steps = [{**s, "channels": CHANNELS[::-1], "coefficients": s["coefficients"][::-1], "noise_std": s["noise_std"][::-1]}
                 for s in make_steps()]
        pd.testing.assert_frame_equal(identification_frame(steps), identification_frame(make_steps()))

    def test_coil_currents_are_optional_for_a_whole_log(self, tmp_path):
        """A logger that records positions and commands only: no step carries a coil current.  Valid, and it
        round-trips; a log whose coil currents stop on one step is refused, naming them."""
        frame = identification_frame(make_steps(axes=ALL_AXES))
        positions_only = frame[~frame["channel"].isin(COIL_CURRENT_CHANNELS)].reset_index(drop=True)
        validate_identification_log(positions_only, "positions")
        write_identification_log(positions_only, tmp_path / "log.parquet")
        back, _ = read_identification_log(tmp_path / "log.parquet")
        pd.testing.assert_frame_equal(back, positions_only)
        gap = (frame["excited_axis"] == "NX") & (frame["step"] == 2) & frame["channel"].str.startswith("I_")
        with pytest.raises(LogError, match=r"excited_axis=NX, step=2\): missing channel\(s\) I_upper_DX, .* the coil "
                                           r"currents are, on every step or on none"):
            validate_identification_log(frame[~gap].reset_index(drop=True), "run.parquet")

    @pytest.mark.parametrize(
        "drop, message",
        [
            (lambda f: (f["excited_axis"] == "Z") & (f["channel"] == "V2_Z") & (f["step"] == 2),
             r"excited_axis=Z, step=2\): missing channel\(s\) V2_Z \(a step exciting Z carries the 4 axial channels"),
            (lambda f: (f["excited_axis"] == "DX") & (f["channel"] == "I_lower_Z") & (f["step"] == 1),
             r"excited_axis=DX, step=1\): missing channel\(s\) I_lower_Z \(the other bearing's channels are optional, but all"),
            (lambda f: (f["excited_axis"] == "DY") & f["channel"].str.endswith("_Z") & (f["step"] == 3),
             r"excited_axis=DY, step=3\): carries other channels than step 0 of DY \(differing: U2_Z, V2_Z, I_upper_Z, "
             r"I_lower_Z\)"),
        ],
    )
    def test_incomplete_sets_are_refused(self, drop, message):
        frame = identification_frame(make_steps(axes=("DX", "DY", "Z")))
        with pytest.raises(LogError, match=message):
            validate_identification_log(frame[~drop(frame)].reset_index(drop=True), "run.parquet")

    def test_noise_from_scatter_names_only_really_constant_channels(self):
        """Zero padding of the other bearing's channels is constant on one axis only: not an error; a channel constant
        on every axis is, and the message names it alone, with the file given."""
        steps = make_steps(axes=("DX", "Z"), n_steps=6)
        for s in steps:
            own = np.isin(CHANNELS, axis_channels(s["excited_axis"]))
            s["coefficients"] = np.where(own, s["coefficients"], 0)  # padded
        frame = identification_frame(steps)
        estimated = noise_from_scatter(frame, "user.m").groupby("channel")["noise_std"].first()
        assert (estimated > 0).all() and len(estimated) == 20
        frame.loc[frame["channel"] == "I_upper_NX", ["re", "im"]] = 0.25  # stuck on every axis
        with pytest.raises(LogError, match=r"^user\.m: channel\(s\) I_upper_NX do not scatter at all on any excited axis"):
            noise_from_scatter(frame, "user.m")


def test_scatter_std_of_white_noise_and_its_running_form():
    rng = np.random.default_rng(2)
    n = 4000
    sigma = np.where(np.arange(n) < n // 2, 1.0, 3.0)
    noise = sigma * (rng.standard_normal(n) + 1j * rng.standard_normal(n)) / np.sqrt(2)
    smooth = 50 * np.exp(2j * np.pi * np.arange(n) / n)
    assert scatter_std(noise[: n // 2] + smooth[: n // 2]) == pytest.approx(1.0, rel=0.05)
    local = scatter_std(noise + smooth, window=301)
    assert local.shape == (n,)
    assert np.median(local[:1000]) == pytest.approx(1.0, rel=0.1) and np.median(local[-1000:]) == pytest.approx(3.0, rel=0.1)
    assert_allclose(scatter_std(np.arange(5.0) * (1 + 1j), window=3), 0.0)
