"""Readers at the edge: plain tables (long and wide, CSV and Parquet), MATLAB .mat and UFF58 FRFs, and their bad input."""

import numpy as np
import pandas as pd
import pytest
import scipy.io
from numpy.testing import assert_allclose

from ambid.errors import AmbidError, LogError
from ambid.frf import current_etfe, frf_table, log_arrays, mimo_etfe, siso_etfe
from ambid.io import read_parquet
from ambid.logs import CHANNELS, identification_frame, read_identification_log, write_identification_log
from ambid.machine import ALL_AXES
from ambid.mfile import write_thesis_m
from ambid.readers import detect_format, read_log, read_mat_log, read_table_log, read_uff_frf
from ambid.uff import frf_channels, write_uff58
from test_logs import make_steps, own_bearing_only

KEYS = ["excited_axis", "step", "channel"]


@pytest.fixture
def frame():
    return identification_frame(make_steps(axes=ALL_AXES, n_steps=5))


def same_log(back, frame, rtol=1e-12):
    keys = KEYS + (["level"] if "level" in frame else [])
    back = back.sort_values(keys).reset_index(drop=True)
    frame = frame.sort_values(keys).reset_index(drop=True)
    pd.testing.assert_frame_equal(back[keys + ["frequency_hz"]], frame[keys + ["frequency_hz"]], check_dtype=False)
    assert_allclose(back[["re", "im", "noise_std", "amplitude_a"]].to_numpy(), frame[["re", "im", "noise_std", "amplitude_a"]].to_numpy(),
                    rtol=rtol, atol=0)


def wide(frame, position_suffix=""):
    """The log as one row per step and two (three) columns per channel; empty cells where a step lacks a channel."""
    index = ["excited_axis", "step", "frequency_hz", "amplitude_a", "attempts"] + (["level"] if "level" in frame else [])
    table = frame.pivot_table(index=index, columns="channel", values=["re", "im", "noise_std"], sort=False)
    out = table.index.to_frame(index=False)
    for channel in CHANNELS:
        if ("re", channel) not in table:
            continue
        scale, suffix = (1e6, position_suffix) if channel.startswith("V2_") and position_suffix else (1.0, "")
        for part in ("re", "im", "noise_std"):
            out[f"{channel}_{part}{suffix}"] = table[(part, channel)].to_numpy() * scale
    return out


class TestTables:
    def test_long_csv_in_micrometres(self, frame, tmp_path):
        table = frame.copy()
        position = table["channel"].str.startswith("V2_")
        table.loc[position, ["re", "im", "noise_std"]] *= 1e6
        table.to_csv(tmp_path / "log.csv", index=False)
        back, provenance = read_log(tmp_path / "log.csv", position_unit="um")
        same_log(back, frame)
        assert provenance["format"] == "table" and provenance["layout"] == "long" and "V2 um" in provenance["units"]

    def test_one_control_current_per_axis(self, frame, tmp_path):
        """A logger that measures the control current (I_upper - I_lower) / 2 alone, as I_<axis>: the coil-current
        FRF and its noise are the same as from the pair (long and wide layouts); the pair beside it is an error."""
        keys = ["excited_axis", "step"]
        pairs = frame[frame["channel"].str.startswith("I_")].copy()
        pairs["axis"] = pairs["channel"].str.split("_").str[-1]
        pairs["side"] = pairs["channel"].str.split("_").str[1]
        wide_pairs = pairs.pivot_table(index=keys + ["axis", "frequency_hz", "amplitude_a", "attempts"], columns="side",
                                       values=["re", "im", "noise_std"]).reset_index()
        control = pd.DataFrame({**{k: wide_pairs[k] for k in keys + ["frequency_hz", "amplitude_a", "attempts"]},
                                "channel": "I_" + wide_pairs["axis"],
                                "re": 0.5 * (wide_pairs[("re", "upper")] - wide_pairs[("re", "lower")]),
                                "im": 0.5 * (wide_pairs[("im", "upper")] - wide_pairs[("im", "lower")]),
                                "noise_std": 0.5 * np.hypot(wide_pairs[("noise_std", "upper")], wide_pairs[("noise_std", "lower")])})
        control.columns = [c[0] if isinstance(c, tuple) else c for c in control.columns]
        control["level"] = 0
        table = pd.concat([frame[~frame["channel"].str.startswith("I_")], control], ignore_index=True)
        table.to_csv(tmp_path / "long.csv", index=False)
        back, provenance = read_log(tmp_path / "long.csv")
        assert any("control currents I_<axis>" in note for note in provenance["notes"])
        expected, got = current_etfe(log_arrays(frame)), current_etfe(log_arrays(back))
        assert set(got) == set(expected)
        for key in expected:
            assert_allclose(got[key][1], expected[key][1], rtol=1e-12)
            assert_allclose(got[key][2], expected[key][2], rtol=1e-12)
        wide_table = wide(table)  # the canonical channels (wide() knows no others), then the control currents
        rows = wide_table.set_index(keys).index
        for name in ALL_AXES:
            part = control[control["channel"] == f"I_{name}"].set_index(keys)
            for piece in ("re", "im", "noise_std"):
                wide_table[f"I_{name}_{piece}_mA"] = 1e3 * part[piece].reindex(rows).to_numpy()
        wide_table.to_csv(tmp_path / "wide.csv", index=False)
        back, _ = read_log(tmp_path / "wide.csv")
        got = current_etfe(log_arrays(back))
        assert set(got) == set(expected)
        for key in expected:
            assert_allclose(got[key][1], expected[key][1], rtol=1e-12)
        both = pd.concat([frame, control[control["channel"] == "I_DX"]], ignore_index=True)
        both.to_csv(tmp_path / "both.csv", index=False)
        with pytest.raises(LogError, match=r"both\.csv: step \d+ of \w+: I_DX \(the control current\) and the "
                                           r"coil-current pair of DX both given"):
            read_log(tmp_path / "both.csv")

    def test_plain_parquet_without_metadata(self, frame, tmp_path):
        """As users write it (pandas.to_parquet): the canonical reader names the keys it wants, the table reader reads it."""
        path = tmp_path / "identification.parquet"
        frame.to_parquet(path)
        with pytest.raises(AmbidError, match=r"no ambid metadata \(the Parquet key-value metadata ambid.schema_version, "
                                             r"ambid.kind and ambid.units .*ambid import .* --format table"):
            read_identification_log(path)
        assert detect_format(path) == "table"
        back, provenance = read_log(path)
        same_log(back, frame)

    def test_long_table_with_the_minimum_of_columns(self, frame, tmp_path):
        minimal = frame[["excited_axis", "frequency_hz", "channel", "re", "im"]].sample(frac=1.0, random_state=1)
        minimal.to_csv(tmp_path / "log.csv", index=False)
        back, provenance = read_table_log(tmp_path / "log.csv")
        assert (back["noise_std"] == 0).all() and (back["attempts"] == 1).all()
        assert back.groupby("excited_axis")["step"].max().eq(4).all()
        u2 = back[back["channel"] == "U2_" + back["excited_axis"]]
        assert_allclose(u2["amplitude_a"], np.hypot(u2["re"], u2["im"]))
        assert any("steps numbered by increasing frequency" in n for n in provenance["notes"])
        assert any("|U2| of the excited axis" in n for n in provenance["notes"])

    def test_wide_csv_with_units_in_names_and_each_bearings_channels(self, frame, tmp_path):
        partial = own_bearing_only(frame)
        wide(partial, position_suffix="_um").to_csv(tmp_path / "wide.csv", index=False)
        back, provenance = read_log(tmp_path / "wide.csv")
        same_log(back, partial)
        assert provenance["layout"] == "wide" and provenance["units"] == "U2 and I A, V2 um"
        assert back.groupby("excited_axis")["channel"].nunique().to_dict() == {"DX": 16, "DY": 16, "NX": 16, "NY": 16, "Z": 4}

    @pytest.mark.parametrize(
        "change, message",
        [
            (lambda t: t.drop(columns="im"), r"long layout .*missing column\(s\) im"),
            (lambda t: t.assign(channel=t["channel"].replace("V2_NX", "V2_NQ")), r"row \d+: unknown channel 'V2_NQ'"),
            (lambda t: t.assign(excited_axis=t["excited_axis"].replace("DY", "dy")), r"row \d+: unknown excited_axis 'dy'"),
            (lambda t: t.astype({"re": object}).assign(re=lambda u: u["re"].where(u.index != 7, "1,5e-3")),
             r"row 8: column 're' holds '1,5e-3', not a number"),
            (lambda t: t.drop(columns="channel").rename(columns={"re": "real"}), r"neither layout of a plain log table"),
            (lambda t: t[~((t["excited_axis"] == "NX") & (t["channel"] == "V2_NX"))],
             r"rows .*\(excited_axis=NX, step=\d\): missing channel\(s\) V2_NX"),
        ],
    )
    def test_bad_tables_name_the_file(self, frame, tmp_path, change, message):
        path = tmp_path / "mine.csv"
        change(frame.copy()).to_csv(path, index=False)
        with pytest.raises(LogError, match=rf"^{tmp_path}/mine\.csv: {message}"):
            read_log(path)

    def test_repeated_steps_in_both_layouts(self, frame, tmp_path):
        """A column level carries steps measured again at a lower amplitude (what the floor and the zero-amplitude FRF
        need), in either layout, with or without a step column: a repeat takes its step's number."""
        repeats = frame[frame["step"].isin([0, 2])].assign(level=1, amplitude_a=lambda t: 0.5 * t["amplitude_a"],
                                                           re=lambda t: 0.5 * t["re"], im=lambda t: 0.5 * t["im"])
        logged = pd.concat([frame.assign(level=0), repeats], ignore_index=True)
        logged.to_csv(tmp_path / "long.csv", index=False)
        logged.drop(columns="step").to_csv(tmp_path / "unnumbered.csv", index=False)
        wide(logged).to_csv(tmp_path / "wide.csv", index=False)
        for name in ("long.csv", "unnumbered.csv", "wide.csv"):
            back, _ = read_log(tmp_path / name)
            same_log(back, logged)
            assert len(back.loc[back["level"] == 1, ["excited_axis", "step"]].drop_duplicates()) == 2 * len(ALL_AXES)
        logged.assign(level=logged["level"].astype(float).where(logged.index != 300, 1.5)).to_csv(tmp_path / "bad.csv",
                                                                                                  index=False)
        with pytest.raises(LogError, match=r"bad\.csv: row 301: level 1\.5 is not a whole number >= 0"):
            read_log(tmp_path / "bad.csv")

    def test_bad_units_and_files(self, frame, tmp_path):
        wide(frame, position_suffix="_um").to_csv(tmp_path / "wide.csv", index=False)
        with pytest.raises(LogError, match=r"column 'V2_DX_re_um' says um, the option says mm"):
            read_log(tmp_path / "wide.csv", position_unit="mm")
        frame.to_csv(tmp_path / "long.csv", index=False)
        with pytest.raises(LogError, match=r"long\.csv: unknown unit 'inch'; known: m, mm, um"):
            read_log(tmp_path / "long.csv", position_unit="inch")
        (tmp_path / "folder.csv").mkdir()
        with pytest.raises(LogError, match=r"folder\.csv: is a directory"):
            read_log(tmp_path / "folder.csv")
        (tmp_path / "empty.csv").write_text("")
        with pytest.raises(LogError, match=r"empty\.csv: not a readable table"):
            read_log(tmp_path / "empty.csv")
        (tmp_path / "log.xlsx").write_text("x")
        with pytest.raises(LogError, match=r"log\.xlsx: cannot tell the format from the suffix '.xlsx'"):
            read_log(tmp_path / "log.xlsx")
        (tmp_path / "log.parquet").mkdir()
        with pytest.raises(LogError, match=r"log\.parquet: is a directory, not a log file"):
            read_log(tmp_path / "log.parquet")
        with pytest.raises(AmbidError, match=r"log\.parquet: is a directory, not a Parquet file"):
            read_identification_log(tmp_path / "log.parquet")


class TestMat:
    def matrices(self, frame, tmp_path):
        """The thesis matrices of a log, as the .m writer lays them out (parsed back from its file)."""
        from ambid.mfile import parse_thesis_m

        write_thesis_m(frame, tmp_path / "log.m")
        return parse_thesis_m((tmp_path / "log.m").read_text())

    @pytest.mark.parametrize("partial", [False, True])
    def test_both_layouts(self, frame, tmp_path, partial):
        log = own_bearing_only(frame) if partial else frame
        path = tmp_path / "identification.mat"
        scipy.io.savemat(path, {**self.matrices(log, tmp_path), "comment": "from the rig"})
        back, provenance = read_log(path)
        same_log(back.assign(noise_std=log["noise_std"].to_numpy()), log, rtol=1e-14)
        assert provenance["format"] == "mat" and ("18 columns" in provenance["layout"]) == partial
        assert provenance["notes"] == ["variable(s) not read: comment"]

    def test_bad_mat_files(self, frame, tmp_path):
        path = tmp_path / "bad.mat"
        path.write_bytes(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: HDF5 schema 1.00 .".ljust(116)
                         + b"\x00" * 8 + b"\x00\x02IM" + b"\x00" * 512)
        with pytest.raises(LogError, match=r"bad\.mat: a MATLAB v7.3 \(HDF5\) file, .* save it again as version 7"):
            read_mat_log(path)
        for content in (b"this is no MAT file at all, only text, long enough to have a header" * 3, b"\x00" * 200):
            path.write_bytes(content)
            with pytest.raises(LogError, match=r"bad\.mat: not a readable MATLAB \.mat file"):
                read_mat_log(path)
        scipy.io.savemat(path, {"x": np.ones(3)})
        with pytest.raises(LogError, match=r"bad\.mat: no data_exc_\* variable .* the file holds x"):
            read_mat_log(path)
        scipy.io.savemat(path, {"data_exc_dx": "not numbers"})
        with pytest.raises(LogError, match=r"bad\.mat: variable data_exc_dx is not a numeric matrix"):
            read_mat_log(path)
        scipy.io.savemat(path, {"data_exc_dx": np.ones((3, 21))})
        with pytest.raises(LogError, match=r"bad\.mat: data_exc_dx has 21 columns; the thesis layout has 22"):
            read_mat_log(path)
        matrices = self.matrices(frame, tmp_path)
        matrices["data_exc_ny"][2, 7] = np.nan
        scipy.io.savemat(path, matrices)
        with pytest.raises(LogError, match=r"bad\.mat: data_exc_ny row 3: a value is not finite"):
            read_mat_log(path)


def frf_of(frame):
    arrays = log_arrays(frame)
    return frf_table(siso_etfe(arrays), mimo_etfe(arrays), current=current_etfe(arrays))


class TestUff:
    def test_every_kind_round_trips_through_pyuff(self, frame, tmp_path):
        import pyuff

        table = frf_of(frame)
        path = tmp_path / "frf.uff"
        write_uff58(path, frf_channels(table), description="ambid test")
        sets = pyuff.UFF(str(path)).read_sets()
        assert len(sets) == 25 + 16 + 5
        by_key = {}
        for dataset in sets:
            assert dataset["type"] == 58 and dataset["func_type"] == 4 and dataset["id1"].strip() == "ambid test"
            estimator, channel = dataset["id2"].split(":")[0].split()
            by_key[(estimator, *channel.split("/"))] = dataset
        nodes = {"DX": (1, 1), "DY": (1, 2), "NX": (2, 1), "NY": (2, 2), "Z": (3, 3)}
        for estimator, output, input_axis, frequency, values in frf_channels(table):
            dataset = by_key[(estimator, output, input_axis)]
            assert (dataset["rsp_node"], dataset["rsp_dir"]) == nodes[output]
            assert (dataset["ref_node"], dataset["ref_dir"]) == nodes[input_axis]
            assert dataset["ordinate_axis_units_lab"].strip() == ("A" if estimator == "current" else "m")
            assert_allclose(dataset["x"], frequency, rtol=1e-5)
            assert_allclose(dataset["data"], values, rtol=1e-11)

    def test_read_back_as_the_frf_table(self, frame, tmp_path):
        table = frf_of(frame)
        write_uff58(tmp_path / "frf.uff", frf_channels(table))
        back, provenance = read_uff_frf(tmp_path / "frf.uff")
        key = ["estimator", "output", "input", "frequency_hz"]
        a = table.sort_values(key).reset_index(drop=True)
        b = back.sort_values(key).reset_index(drop=True)
        assert list(a[key[:3]].itertuples(index=False)) == list(b[key[:3]].itertuples(index=False))
        assert_allclose(b[["re", "im"]], a[["re", "im"]], rtol=1e-11)
        assert_allclose(b["frequency_hz"], a["frequency_hz"], rtol=1e-5)
        assert (b["std"] > 0).all() and provenance["estimator"] == "current, mimo, siso"
        assert "UFF58 carries no uncertainty" in provenance["notes"][0]

    def test_std_estimate_follows_the_noise(self, tmp_path):
        rng = np.random.default_rng(3)
        f = np.linspace(5.0, 500.0, 400)
        clean = 1e-5 / (1 - (f / 300.0) ** 2 + 0.05j * f / 300.0)
        sigma = 2e-8
        noisy = clean + sigma * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)) / np.sqrt(2)
        write_uff58(tmp_path / "one.uff", [("siso", "DX", "DX", f, noisy)])
        back, _ = read_uff_frf(tmp_path / "one.uff")
        assert np.median(back["std"]) == pytest.approx(sigma, rel=0.2)

    def test_other_writers_units_and_signs(self, tmp_path):
        """A file as an analyser writes it: position in um per control current in mA, node 2 direction -1 (= -x)."""
        import pyuff

        f = np.linspace(10.0, 100.0, 10)
        values = (1 + 1j) * np.linspace(1.0, 2.0, 10)
        dataset = pyuff.prepare_58(func_type=4, rsp_node=2, rsp_dir=-1, ref_node=2, ref_dir=1, ord_data_type=6,
                                   abscissa_spacing=0, data=values, x=f, id1="analyser", ordinate_axis_units_lab="um",
                                   orddenom_axis_units_lab="mA", abscissa_spec_data_type=18, abscissa_axis_units_lab="Hz",
                                   ordinate_spec_data_type=8, orddenom_spec_data_type=0, z_axis_spec_data_type=0,
                                   ordinate_len_unit_exp=1, orddenom_len_unit_exp=0)
        pyuff.UFF(str(tmp_path / "analyser.uff")).write_sets([dataset], mode="overwrite")
        back, provenance = read_uff_frf(tmp_path / "analyser.uff")
        assert set(back["estimator"]) == {"siso"} and set(back["output"]) == {"NX"}
        assert_allclose(back["re"] + 1j * back["im"], -values * 1e-6 / 1e-3)

    def test_bad_uff_files(self, frame, tmp_path):
        import pyuff

        path = tmp_path / "bad.uff"
        path.write_text("    -1\n    58\nthis is not a dataset\n    -1\n")
        with pytest.raises(LogError, match=r"bad\.uff: not a readable UFF file|bad\.uff: no FRF dataset"):
            read_uff_frf(path)
        with pytest.raises(LogError, match=r"missing\.uff: no such file"):
            read_uff_frf(tmp_path / "missing.uff")
        (tmp_path / "dir.uff").mkdir()
        with pytest.raises(LogError, match=r"dir\.uff: is a directory"):
            read_uff_frf(tmp_path / "dir.uff")
        nodes = pyuff.prepare_15(node_nums=[1, 2], def_cs=[0, 0], disp_cs=[0, 0], color=[1, 1], x=[0.0, 1.0], y=[0.0, 0.0], z=[0.0, 0.0])
        pyuff.UFF(str(path)).write_sets([nodes], mode="overwrite")
        with pytest.raises(LogError, match=r"bad\.uff: no FRF dataset \(type 58, function type 4\); found dataset type\(s\) 15"):
            read_uff_frf(path)
        f = np.linspace(1.0, 5.0, 5)
        write_uff58(path, [("siso", "DX", "DX", f, np.ones(5))])
        with pytest.raises(LogError, match=r"bad\.uff: dataset 1: response node/direction \(1, 1\) or reference \(1, 1\) is "
                                           r"no control axis"):
            read_uff_frf(path, nodes={"DX": (7, 1)})
        write_uff58(path, [("mimo", "DX", "DX", f, np.ones(5))])
        with pytest.raises(LogError, match=r"bad\.uff: MIMO FRFs need all 16 radial channels; missing DX/DY"):
            read_uff_frf(path)
        write_uff58(path, [("siso", "DX", "DX", f, np.ones(5)), ("siso", "DX", "DX", f, np.ones(5))])
        with pytest.raises(LogError, match=r"bad\.uff: dataset 2: siso DX/DX is in the file twice"):
            read_uff_frf(path)


def test_canonical_parquet_through_read_log(frame, tmp_path):
    write_identification_log(frame, tmp_path / "identification.parquet")
    back, provenance = read_log(tmp_path / "identification.parquet")
    pd.testing.assert_frame_equal(back, frame)
    assert provenance["format"] == "parquet" and detect_format(tmp_path / "identification.parquet") == "parquet"
    _, info = read_parquet(tmp_path / "identification.parquet")
    assert info["kind"] == "identification_log"
