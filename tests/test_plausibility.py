"""Plausibility of a log before the FRF: radial runs, units against the nominal model, outlier cells."""

import numpy as np
import pytest

from ambid.errors import LogError
from ambid.frf import current_etfe, frf_table, log_arrays, mimo_etfe, siso_etfe
from ambid.logs import CHANNELS, noise_from_scatter
from ambid.mfile import read_thesis_m
from ambid.plausibility import _scores, check_log, check_units, find_outliers, frf_arrays
from ambid.readers import read_uff_frf
from ambid.uff import frf_channels, write_uff58

from conftest import ROOT

EXAMPLE = ROOT / "data/demo20/thesis01/identification.m"
SOURCE = "data/demo20/thesis01/identification.m"


@pytest.fixture(scope="module")
def example():
    frame = read_thesis_m(EXAMPLE)
    lines = frame.attrs["source_lines"]
    return noise_from_scatter(frame), lines


def edited(frame, axis, step, channel, value):
    frame = frame.copy()
    cell = (frame["excited_axis"] == axis) & (frame["step"] == step) & (frame["channel"] == channel)
    frame.loc[cell, ["re", "im"]] = [value.real, value.imag]
    return frame


def scaled(frame, channels, factor, frequency=1.0):
    frame = frame.copy()
    chosen = frame["channel"].str.startswith(channels)
    frame.loc[chosen, ["re", "im", "noise_std"]] *= factor
    frame["frequency_hz"] *= frequency
    return frame


class TestUnits:
    def test_the_example_log_is_plausible(self, example, demo_plant):
        rows = check_units(log_arrays(example[0]), demo_plant, SOURCE)
        ratios = {(r["check"], r["axes"]): r["ratio"] for r in rows}
        assert set(ratios) == {(c, a) for c in ("compliance", "coil_current") for a in ("DX DY NX NY", "Z")} | {
            ("frequency", "DX DY NX NY"), ("frequency", "Z")}
        assert all(0.5 < ratio < 2 for ratio in ratios.values()), ratios  # the rig's truth is near its model

    @pytest.mark.parametrize(
        "channels, factor, frequency, named",
        [
            (("V2_",), 1e6, 1.0, "positions look like um"),
            (("V2_",), 1e3, 1.0, "positions look like mm"),
            (("U2_", "I_"), 1e3, 1.0, "currents look like mA"),
            (("I_",), 1e3, 1.0, "coil currents look like mA"),
            ((), 1.0, 1e-3, "frequencies look like kHz"),
            ((), 1.0, 2 * np.pi, "look like rad/s"),
        ],
    )
    def test_a_unit_error_is_named(self, example, demo_plant, channels, factor, frequency, named):
        frame = scaled(example[0], channels, factor, frequency) if channels else scaled(example[0], ("none",), 1.0, frequency)
        with pytest.raises(LogError, match=named) as error:
            check_units(log_arrays(frame), demo_plant, SOURCE, "config/machines/demo20.yaml")
        assert str(error.value).startswith(SOURCE) and "config/machines/demo20.yaml" in str(error.value)

    @pytest.mark.parametrize(
        "edit, named",
        [
            ({"V2_NX": "V2_NX"}, r"the compliance V2/U2 of NX has the opposite sign of the nominal model's below \d+ Hz .*"
                                 r"the sign of V2_NX or U2_NX differs from the convention of config/machines/demo20.yaml"),
            ({"U2_DX": "U2_DX", "U2_DY": "U2_DY"}, r"the compliance V2/U2 of DX, DY has the opposite sign"),
            ({"I_upper_DY": "I_lower_DY", "I_lower_DY": "I_upper_DY"},
             r"the coil current \(I_upper - I_lower\) / 2 of DY runs opposite to its command U2 .*I_upper_DY and "
             r"I_lower_DY look swapped"),
        ],
    )
    def test_a_sign_error_is_named(self, example, demo_plant, edit, named):
        """A channel of the other sign (a sensor mounted the other way, another writer's axis direction) or coil
        currents with upper and lower swapped: half a turn of phase where the model has a few degrees of lag.  Each
        went through to a diagnosis before (the independent rig's log with V2_NX negated: noncollocation named)."""
        frame = example[0].copy()
        if all(old == new for old, new in edit.items()):  # negate
            chosen = frame["channel"].isin(list(edit))
            frame.loc[chosen, ["re", "im"]] *= -1
        else:  # rename
            frame["channel"] = frame["channel"].replace(edit)
        with pytest.raises(LogError, match=named):
            check_units(log_arrays(frame), demo_plant, SOURCE, "config/machines/demo20.yaml")

    def test_complex_conjugated_coefficients_are_named(self, example, demo_plant):
        """A writer with the other sign convention of the Fourier transform: every phase mirrored.  Magnitudes and
        signs pass; the coil currents lead their commands, which an amplifier and the sampling never do (here, the
        rig's elements 5-8 at half stiffness leave a third of the compliance's imaginary parts off the model's sign,
        too few for that check; the independent rig's conjugated logs fail both, and gave element_stiffness named)."""
        frame = example[0].copy()
        frame["im"] = -frame["im"]
        with pytest.raises(LogError, match=r"of DX, DY, NX, NY lead their commands U2 .* look complex conjugated .* "
                                           r"negate every imaginary part"):
            check_units(log_arrays(frame), demo_plant, SOURCE)

    def test_the_excitation_logged_as_u2_is_named(self, example, demo_plant):
        """A writer who logs the excitation E_u (a sine of the step's amplitude) where U2 belongs: V2/U2 is then the
        closed loop V2/E_u.  It passed the unit and sign checks (|S| is near 1 below the flexible modes) and stopped at
        the coil-current check of Z as 'complex conjugated', whose remedy would have been wrong."""
        frame = example[0].copy()
        u2 = frame["channel"].str.startswith("U2_")
        own = frame["channel"] == "U2_" + frame["excited_axis"]
        frame.loc[u2, ["re", "im"]] = 0.0
        frame.loc[own, "im"] = -frame.loc[own, "amplitude_a"]  # A sin(w t), referred to the start of the excitation
        with pytest.raises(LogError, match=r"the compliance V2/U2 of DX, DY, NX, NY is the nominal model's closed loop "
                                           r"from the excitation, V2/E_u .* U2 looks like the excitation E_u logged in "
                                           r"place of the control current"):
            check_units(log_arrays(frame), demo_plant, SOURCE)

    @staticmethod
    def model_log(plant, swapped=False):
        """The model's own radial compliance below its first flexible mode as a log's steps (U2 = 1, coil current =
        U2), with the drive-end and non-drive-end labels swapped if asked."""
        frequency = np.linspace(5.0, 0.25 * plant.modes.frequency_hz[2], 40)
        diagonal = np.diagonal(plant.radial_frequency_response(frequency), axis1=1, axis2=2)
        arrays = {}
        for k, axis in enumerate(("DX", "DY", "NX", "NY")):
            label = {"DX": "NX", "DY": "NY", "NX": "DX", "NY": "DY"}[axis] if swapped else axis
            coefficients = np.full((frequency.size, len(CHANNELS)), np.nan, dtype=complex)
            coefficients[:, CHANNELS.index(f"U2_{label}")] = 1.0
            coefficients[:, CHANNELS.index(f"V2_{label}")] = diagonal[:, k]
            coefficients[:, CHANNELS.index(f"I_upper_{label}")] = 1.0
            coefficients[:, CHANNELS.index(f"I_lower_{label}")] = -1.0
            arrays[label] = (frequency, coefficients, np.full(coefficients.shape, np.nan))
        return arrays

    def test_drive_and_non_drive_end_swapped_are_named(self, hs_plant, demo_plant):
        """Another writer's bearing names: hs_eden_like's two bearings differ at low frequency by a factor 1.6 (within
        the unit check's 30), so a log with D and N swapped went to a diagnosis (the rig's ident01 log so: amplifier and
        a motor stiffness named, chi2 per point 2.8e4 left).  demo20's bearings are alike: nothing to tell, no refusal."""
        check_units(self.model_log(hs_plant), hs_plant, "hs.parquet")
        with pytest.raises(LogError, match=r"hs\.parquet: .* of DX, DY is the nominal model's of NX, NY .* drive-end \(D\) "
                                           r"and non-drive-end \(N\) channels look swapped .* rename DX <-> NX and DY <-> NY"):
            check_units(self.model_log(hs_plant, swapped=True), hs_plant, "hs.parquet")
        check_units(self.model_log(demo_plant, swapped=True), demo_plant, "demo20.parquet")

    def test_a_model_off_by_a_factor_of_three_passes(self, example, demo_plant):
        rows = check_units(log_arrays(scaled(example[0], ("V2_",), 3.0)), demo_plant, SOURCE)
        assert 2.5 < [r for r in rows if r["check"] == "compliance"][0]["ratio"] < 3.5


@pytest.fixture(scope="module")
def channels(example):
    """The example log's FRFs as `ambid.uff.frf_channels` (every kind: SISO, MIMO, coil current)."""
    arrays = log_arrays(example[0])
    return list(frf_channels(frf_table(siso_etfe(arrays), mimo_etfe(arrays), current=current_etfe(arrays))))


class TestFrfsWithoutALog:
    """A user's UFF58 FRFs (no raw log) are checked as a log is, through `frf_arrays`: before, they went unchecked."""

    def written(self, channels, path, change=lambda estimator, output, values: values):
        write_uff58(path, [(e, o, i, f, change(e, o, v)) for e, o, i, f, v in channels], description="analyser")
        return read_uff_frf(path)[0]

    def test_the_example_frfs_are_plausible(self, channels, demo_plant, tmp_path):
        table = self.written(channels, tmp_path / "frf.uff")
        rows = check_units(frf_arrays(table), demo_plant, "frf.uff")
        ratios = {(r["check"], r["axes"]): r["ratio"] for r in rows}
        assert set(ratios) == {(c, a) for c in ("compliance", "coil_current") for a in ("DX DY NX NY", "Z")} | {
            ("frequency", "DX DY NX NY"), ("frequency", "Z")}
        assert all(0.5 < ratio < 2 for ratio in ratios.values()), ratios

    def test_without_coil_current_frfs_the_rest_is_checked(self, channels, demo_plant, tmp_path):
        table = self.written([c for c in channels if c[0] != "current"], tmp_path / "frf.uff")
        assert {r["check"] for r in check_units(frf_arrays(table), demo_plant, "frf.uff")} == {"frequency", "compliance"}

    @pytest.mark.parametrize("change, named", [
        (lambda e, o, v: v * 1e6 if e != "current" else v, "positions look like um"),  # labelled m, holding um
        (lambda e, o, v: -v if o == "NX" and e != "current" else v, "the compliance V2/U2 of NX has the opposite sign"),
        (lambda e, o, v: np.conj(v), "look complex conjugated"),
    ])
    def test_a_unit_sign_or_convention_error_is_named(self, channels, demo_plant, tmp_path, change, named):
        table = self.written(channels, tmp_path / "frf.uff", change)
        with pytest.raises(LogError, match=named) as error:
            check_units(frf_arrays(table), demo_plant, str(tmp_path / "frf.uff"))
        assert str(error.value).startswith(str(tmp_path / "frf.uff"))


class TestAxes:
    def test_mimo_needs_every_radial_run(self, example):
        frame = example[0][example[0]["excited_axis"] != "NY"]
        with pytest.raises(LogError, match=r"identification.m: no run excites NY \(data_exc_ny\).*frf.estimator: siso"):
            check_log(frame, log_arrays(frame), {}, "identification.parquet", original=SOURCE)
        single = example[0][example[0]["excited_axis"] == "DX"]
        with pytest.raises(LogError, match="no run excites DY, NX, NY: the MIMO"):
            check_log(single, log_arrays(single), {}, "identification.parquet")
        kept, findings = check_log(single, log_arrays(single), {"estimator": "siso"}, "identification.parquet")
        assert len(kept) == len(single) and findings == []


class TestOutliers:
    def test_the_example_log_has_none_with_a_wide_margin(self, example):
        frame, lines = example
        kept, findings = check_log(frame, log_arrays(frame), {}, "x.parquet", lines, SOURCE)
        assert findings == [] and len(kept) == len(frame)
        # the largest score of a cell alone at its step is far below the threshold (100)
        arrays = log_arrays(frame)
        largest = 0.0
        for axis, (frequency, coefficients, noise) in arrays.items():
            amplitude = frame[frame["excited_axis"] == axis].groupby("step")["amplitude_a"].first().to_numpy()
            scores = np.array([_scores(frequency, coefficients[:, j] / amplitude, noise[:, j] / amplitude)[1]
                               for j in range(20)]).T
            alone = np.count_nonzero(scores > 10, axis=1) < 3
            largest = max(largest, scores[alone].max())
        assert largest < 20

    def test_a_typo_is_refused_with_its_line_and_column(self, example):
        frame, lines = example
        typo = edited(frame, "DX", 12, "V2_DX", 0.1 + 0j)  # 1e+05 um in the file
        with pytest.raises(LogError) as error:
            check_log(typo, log_arrays(typo), {}, "x.parquet", lines, SOURCE)
        message = str(error.value)
        assert message.startswith(f"{SOURCE}:20: data_exc_dx row 13, column 7 (V2_DX [um]) = 100000")
        assert "frf.outliers: exclude" in message

    def test_a_typo_in_a_parquet_log_names_its_rows(self, example):
        frame, _ = example
        typo = edited(frame, "NY", 40, "U2_NY", -3.0 + 1.0j)
        with pytest.raises(LogError, match=r"x.parquet: rows \d+-\d+ \(excited_axis=NY, step=40\), row \d+ \(U2_NY\)"):
            check_log(typo, log_arrays(typo), {}, "x.parquet")

    def test_a_huge_cell_is_an_outlier_not_a_crash(self, example):
        frame, _ = example
        huge = edited(frame, "DX", 12, "V2_DX", 1e300 + 0j)
        with pytest.raises(LogError, match="V2_DX = 1e\\+300"):
            check_log(huge, log_arrays(huge), {}, "x.parquet")

    def test_excluded_when_allowed_with_a_finding_on_every_radial_run(self, example):
        frame, lines = example
        typo = edited(frame, "DX", 12, "V2_DX", 0.1 + 0j)
        kept, findings = check_log(typo, log_arrays(typo), {"outliers": "exclude"}, "x.parquet", lines, SOURCE)
        assert [f.code for f in findings] == ["outlier_excluded"] and findings[0].subject == "DX step 12 (122.99 Hz)"
        assert f"{SOURCE}:20" in findings[0].message
        assert len(frame) - len(kept) == 4 * 20  # the step's frequency on the four radial runs (MIMO grid)
        assert set(kept[kept["step"] == 12]["excited_axis"]) == {"Z"}
        assert check_log(kept, log_arrays(kept), {}, "x.parquet")[1] == []

    def test_a_resonance_narrower_than_the_grid_is_no_outlier(self):
        """A pole moves two channels or more at its step (here, open loop: the positions of its plane only)."""
        frequency = np.linspace(1.0, 750.0, 250)
        mode = 1.0 / (1 - (frequency / frequency[120]) ** 2 + 2j * 1e-5 * frequency / frequency[120])
        coefficients = np.outer(np.ones(250), np.linspace(1.0, 2.0, 20)).astype(complex)
        for name in ("V2_DX", "V2_NX"):
            coefficients[:, CHANNELS.index(name)] += 1e-3 * mode
        arrays = {"DX": (frequency, coefficients, np.full(coefficients.shape, 1e-9))}
        steps = {"DX": (np.arange(250), np.ones(250))}
        assert find_outliers(arrays, steps, 100.0) == []
        coefficients[60, CHANNELS.index("V2_DX")] *= 1.5  # one cell
        found = find_outliers(arrays, steps, 100.0)
        assert [(o.step, o.channel) for o in found] == [(60, "V2_DX")]
