"""Multisine identification: signal design, the rig run, the BLA with its noise and distortion, zoom, the log contract."""

from dataclasses import replace

import numpy as np
import pytest
import yaml
from numpy.testing import assert_allclose

from ambid.bla import (_combine, distortion_levels, excitation_covariance, multisine_frf, multisine_passes,
                       realization_levels)
from ambid.compare import at_run_level
from ambid.errors import ConfigError, LogError
from ambid.logs import (CHANNELS, REFERENCE_CHANNELS, multisine_frame, read_multisine_log, validate_multisine_log,
                        write_multisine_log)
from ambid.machine import ALL_AXES, RADIAL_AXES
from ambid.multisine import (MultisineSettings, crest_factor, design_multisine, harmonic_grid, identify_multisine,
                             multisine_settings_from_config, orthogonal_matrix, pass_record, reduce_crest_factor,
                             run_multisine, _waveform)
from ambid.plant import Plant
from ambid.plausibility import check_units, frf_arrays
from ambid.rig import RigModel, rig_from_config
from ambid.zoom import band_lines, outside_bands, zoom_bands

from conftest import ROOT

# a short design for the rig tests: 20 Hz lines to 600 Hz, 50 ms periods
SMALL = MultisineSettings(frequency_resolution_hz=20.0, radial_band_hz=(20.0, 600.0), axial_band_hz=(20.0, 100.0),
                          relative_spacing=0.0, settle_s=0.4, realizations=2, levels=(1.0,), crest_iterations=10,
                          level_check=False, zoom=False)


def rig_model(name, quiet=False):
    config = yaml.safe_load(open(ROOT / "config" / "rigs" / f"{name}.yaml"))
    if quiet:
        config["truth"].update(sensor_noise_m=0.0, sensor_resolution_m=0.0, current_noise_a=0.0, current_resolution_a=0.0)
    as_built = yaml.safe_load(open(ROOT / config["as_built"]))
    rig = rig_from_config(config, as_built)
    return RigModel(rig, RigModel(rig).magnetic_center_sensor_m())


@pytest.fixture(scope="module")
def demo_rig():
    return rig_model("demo20")


class TestGrid:
    def test_odd_random_grid(self):
        settings = MultisineSettings(frequency_resolution_hz=1.0, radial_band_hz=(1.0, 400.0), relative_spacing=0.0,
                                     axes=tuple(RADIAL_AXES))
        grid = harmonic_grid(1.0, settings, np.random.default_rng(0))
        excited, odd = grid.lines[grid.role == "excited"], grid.lines[grid.role == "odd_detection"]
        even = grid.lines[grid.role == "even_detection"]
        assert np.all(excited % 2 == 1) and np.all(odd % 2 == 1) and np.all(even % 2 == 0)
        candidates = np.sort(np.concatenate([excited, odd]))
        assert_allclose(candidates, np.arange(1, 400, 2))  # every odd line is excited or left out
        # exactly one of every 4 consecutive candidates is left out, at random
        assert all(np.isin(candidates[k:k + 4], odd).sum() == 1 for k in range(0, 196, 4))
        assert len({tuple(np.flatnonzero(np.isin(candidates[k:k + 4], odd))) for k in range(0, 196, 4)}) == 4
        assert set(even) == set(np.setdiff1d(np.concatenate([excited - 1, excited + 1]), np.concatenate([[0], odd])))

    def test_quasi_logarithmic_spacing(self):
        settings = MultisineSettings(relative_spacing=0.01, detection_group=0, axes=("DX",))
        grid = harmonic_grid(1.0, settings, np.random.default_rng(0))
        excited = grid.lines[grid.role == "excited"]
        steps = np.diff(excited)
        assert np.all(steps >= np.maximum(2, 0.01 * excited[1:]) - 1e-9)
        assert np.all(steps[excited[1:] < 150] == 2) and excited.max() > 2900

    def test_orthogonal_design_gives_the_axial_axis_lines_of_its_own(self):
        grid = harmonic_grid(1.0, MultisineSettings(), np.random.default_rng(0))
        radial, axial = grid.excites[:, :4].any(axis=1), grid.excites[:, 4]
        assert not np.any(radial & axial) and axial.sum() > 10
        assert np.all(grid.lines[axial] <= 100) and np.all(grid.excites[radial, :4])
        per_axis = harmonic_grid(1.0, MultisineSettings(design="per_axis"), np.random.default_rng(0))
        assert np.all(per_axis.excites[per_axis.lines <= 100][per_axis.role[per_axis.lines <= 100] == "excited"])

    @pytest.mark.parametrize("size", [1, 2, 3, 4, 5])
    def test_orthogonal_matrix(self, size):
        t = orthogonal_matrix(size)
        assert_allclose(np.abs(t), 1.0)
        assert_allclose(t.conj().T @ t, size * np.eye(size), atol=1e-12)
        if size in (1, 2, 4):
            assert_allclose(t.imag, 0.0)  # Hadamard: sign flips keep the crest factor


class TestCrestFactor:
    def test_clipping_lowers_the_crest_factor_and_keeps_the_amplitudes(self):
        rng = np.random.default_rng(1)
        lines = np.arange(1, 800, 2)
        amplitudes = np.geomspace(1.0, 10.0, lines.size)
        start = rng.uniform(0, 2 * np.pi, lines.size)
        before = crest_factor(_waveform(amplitudes, start, lines, 4000))
        phases, after = reduce_crest_factor(amplitudes, start, lines, 4000, 40)
        assert before > 2.8 and after < 2.1
        spectrum = np.fft.rfft(_waveform(amplitudes, phases, lines, 4000)) * 2 / 4000
        assert_allclose(np.abs(spectrum[lines]), amplitudes, rtol=1e-9)

    def test_realizations_keep_random_phases(self, demo_plant):
        design = design_multisine(demo_plant, replace(SMALL, realizations=3), seed=5)
        phases = np.angle(design.reference[:, 0, 0, design.grid.role == "excited"])
        difference = np.angle(np.exp(1j * (phases[1] - phases[0])))
        # uniform differences between realizations: mean resultant length small
        assert abs(np.mean(np.exp(1j * difference))) < 0.4


class TestDesign:
    def test_level_respects_the_limits(self, demo_plant):
        design = design_multisine(demo_plant, SMALL, seed=1)
        peaks = design.excitation_peaks()
        bias = np.array([m.bias_current_a for m in demo_plant.machine.radial_electromagnets]
                        + [demo_plant.machine.axial_electromagnet.bias_current_a])
        assert np.all(peaks <= np.minimum(SMALL.amplitude_max_a, SMALL.coarse_bias_fraction * bias) * (1 + 1e-9))
        assert np.isclose(peaks[:4].max(), SMALL.coarse_bias_fraction * bias[0]) or "response" in " ".join(design.notes)

    def test_design_is_reproducible_and_seeded(self, demo_plant):
        a, b = design_multisine(demo_plant, SMALL, seed=3), design_multisine(demo_plant, SMALL, seed=3)
        assert np.array_equal(a.reference, b.reference)
        assert not np.array_equal(a.reference, design_multisine(demo_plant, SMALL, seed=4).reference)

    def test_machine_time(self, demo_plant):
        design = design_multisine(demo_plant, SMALL, seed=1)
        assert design.experiments == 4 and design.realizations == 2
        assert design.machine_time_s == pytest.approx(2 * 4 * (0.4 + 2 * 0.05))

    @pytest.mark.parametrize("change, key", [
        (dict(periods=1), "multisine.periods"), (dict(levels=(0.5, 1.0)), "multisine.levels"),
        (dict(realizations=1), "multisine.levels"), (dict(design="zigzag"), "multisine.design"),
        (dict(axes=("DX", "QX")), "multisine.axes"), (dict(zoom_resolution_min_hz=5.0), "zoom_resolution_min_hz")])
    def test_bad_settings_name_the_key(self, change, key):
        with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
            replace(MultisineSettings(), **change)

    def test_unknown_setting(self):
        with pytest.raises(ConfigError, match="multisine.colour"):
            multisine_settings_from_config({"colour": "red"})


class TestBLA:
    def test_linear_noise_free_rig_gives_its_frf(self, demo_plant):
        """The estimator on the linearized truth without noise: the BLA is the sampled FRF (transients only)."""
        rig = rig_model("demo20", quiet=True)
        design = design_multisine(demo_plant, SMALL, seed=2)
        spectra, stats = run_multisine(rig, design, noise=False, nonlinear=False)
        passes = [pass_record(design, spectra)]
        table, estimates = multisine_frf(passes)
        radial = estimates["radial"]
        truth = rig.sampled_frequency_response(radial.frequency_hz)[:, :4, :4]
        assert_allclose(radial.plant, truth, rtol=2e-4, atol=2e-4 * np.abs(truth).max())
        axial = estimates["axial"]
        assert_allclose(axial.plant[:, 0, 0], rig.sampled_frequency_response(axial.frequency_hz)[:, 4, 4], rtol=2e-4)
        assert np.median(radial.condition) < 3
        assert stats["machine_time_s"] == pytest.approx(design.machine_time_s)
        assert set(table.columns) >= {"estimator", "output", "input", "frequency_hz", "re", "im", "std", "systematic_std"}

    def test_noise_from_the_periods_explains_the_scatter(self, demo_plant):
        """Linear rig with its noise: the truth lies within the stated noise (chi2 per point about 1)."""
        rig = rig_model("demo20")
        design = design_multisine(demo_plant, replace(SMALL, periods=4), seed=2)
        spectra, _ = run_multisine(rig, design, seed=3, nonlinear=False)
        _, estimates = multisine_frf([pass_record(design, spectra)])
        radial = estimates["radial"]
        truth = rig.sampled_frequency_response(radial.frequency_hz)[:, :4, :4]
        chi2 = np.mean(np.abs(radial.plant - truth) ** 2 / radial.noise_std**2)
        assert 0.6 < chi2 < 1.6

    def test_two_periods_state_the_noise_once_pooled_over_lines(self, demo_plant):
        """With the default two periods and two realizations a line states its noise with about 16 degrees of
        freedom (2 per period pair, 4 experiments, 2 realizations), so |e|^2 / s^2 averages 16 / 14; pooled over 2
        lines either side (`ambid.floor.pool_variance`, config frf.noise_half_width) it averages about 1."""
        rig = rig_model("demo20")
        design = design_multisine(demo_plant, replace(SMALL, frequency_resolution_hz=4.0, periods=2, settle_s=1.0,
                                                      axial_band_hz=(2.0, 300.0)), seed=2)
        spectra, _ = run_multisine(rig, design, seed=3, nonlinear=False)
        chi2 = {}
        for half_width in (0, 2):
            _, estimates = multisine_frf([pass_record(design, spectra)], noise_half_width=half_width)
            for group, index in (("radial", slice(0, 4)), ("axial", slice(4, 5))):
                bla = estimates[group]
                truth = rig.sampled_frequency_response(bla.frequency_hz)[:, index, index]
                chi2[group, half_width] = np.mean(np.abs(bla.plant - truth) ** 2 / bla.noise_std**2)
        assert chi2["radial", 0] > 1.08
        assert 0.9 < chi2["radial", 2] < 1.1 and 0.85 < chi2["axial", 2] < 1.15

    def test_distortion_and_level_dependence_are_recovered(self):
        """Synthetic realizations: G_m = G0 + l_m^2 B + S_m + noise; sigma_S and |B| come back."""
        rng = np.random.default_rng(0)
        lines, g0, bias, sigma_s, sigma_n = 4000, 1.0 + 0.5j, 0.05, 0.02, 0.004

        def complex_normal(scale, shape):
            return scale * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / np.sqrt(2)

        levels = np.array([1.0, 1.0, 1.0, 1.0])
        estimates = g0 + complex_normal(sigma_s, (4, lines)) + complex_normal(sigma_n, (4, lines))
        noise = np.full((4, lines), sigma_n**2)
        plant, noise_var, distortion, systematic = _combine(estimates[..., None, None], noise[..., None, None], levels)
        assert np.sqrt(np.mean(distortion)) == pytest.approx(sigma_s, rel=0.05)
        assert np.sqrt(np.mean(noise_var)) == pytest.approx(sigma_n / 2, rel=1e-9)
        # two levels: the change with the level is the deterministic part the scatter cannot show
        levels = np.array([1.0, 0.5])
        estimates = g0 + levels[:, None] ** 2 * bias + complex_normal(sigma_n, (2, lines)) / levels[:, None]
        noise = (sigma_n / levels[:, None]) ** 2 * np.ones((2, lines))
        plant, _, _, systematic = _combine(estimates[..., None, None], noise[..., None, None], levels)
        assert np.sqrt(np.mean(systematic)) == pytest.approx(bias, rel=0.1)
        assert np.mean(np.abs(plant - g0) ** 2 / (noise_var.mean() + systematic[..., 0, 0])) < 2

    def test_the_run_states_its_excitation_and_the_model_takes_it(self, demo_plant):
        """`excitation_covariance` sums |c|^2 / 2 (Re(c conj(v)) / 2) over the lines of the top level's
        (I_upper - I_lower) / 2 and V2; `at_run_level` linearizes the model there (a note says so) and leaves a run
        without that record alone."""
        spectra = np.zeros((2, 4, 2, len(CHANNELS), 3), dtype=complex)
        reference = np.ones((2, 4, 5, 3))
        reference[1] *= 0.5  # the second realization at half level: left out
        spectra[0, :, :, CHANNELS.index("I_upper_DX")] = [0.3, 0.4j, 0.0]
        spectra[0, :, :, CHANNELS.index("I_lower_DX")] = [-0.3, -0.4j, 0.0]
        spectra[0, :, :, CHANNELS.index("V2_DX")] = [-1e-5, 0.0, 2e-5]
        spectra[1, :, :, CHANNELS.index("I_upper_DX")] = 5.0
        excitation = excitation_covariance(spectra, reference)
        assert excitation["DX"] == pytest.approx([(0.3**2 + 0.4**2) / 2, (1e-10 + 4e-10) / 2, -0.3e-5 / 2])
        assert excitation["NY"] == [0.0, 0.0, 0.0]
        machine = demo_plant.machine
        same, none = at_run_level(machine, {"run": "x"}, "compare")
        assert same is machine and none == []
        shifted, notes = at_run_level(machine, {"coil_mean_square_a2": 1, "excitation_covariance": excitation}, "compare")
        kx = Plant(shifted).position_stiffness / Plant(machine).position_stiffness
        assert kx[1:] == pytest.approx([1.0, 1.0, 1.0]) and kx[0] > 1
        assert [n.code for n in notes] == ["excitation_level"] and f"DX {kx[0]:.4f}" in notes[0].message

    def test_realization_levels(self):
        reference = np.ones((4, 2, 5, 3))
        reference[1::2] *= 0.5
        assert realization_levels(reference).tolist() == [1.0, 0.5, 1.0, 0.5]

    def test_detection_lines_show_the_distortion(self):
        """Synthetic spectra: distortion only at the odd detection lines is found there, not at the even ones."""
        rng = np.random.default_rng(1)
        role = np.array(["excited", "odd_detection", "even_detection"] * 50)
        frequency = np.arange(1, 151, dtype=float) * 10
        excites = np.zeros((150, 5), dtype=bool)
        excites[role == "excited", 0] = True
        spectra = 1e-9 * (rng.standard_normal((2, 4, 3, 20, 150)) + 1j * rng.standard_normal((2, 4, 3, 20, 150)))
        spectra[:, :, :, CHANNELS.index("V2_DX"), role == "excited"] += 1e-6
        spectra[:, :, :, CHANNELS.index("V2_DX"), role == "odd_detection"] += 1e-8 * np.exp(1j * rng.uniform(0, 6, 50))
        levels = distortion_levels(spectra, role, frequency, excites, axes=["DX"], bands_hz=(0, np.inf))
        row = levels.iloc[0]
        assert row["odd_db"] == pytest.approx(-40, abs=0.5)
        assert not np.isfinite(row["even_db"]) or row["even_db"] < -50
        assert row["noise_db"] < -50


class TestZoom:
    def test_bands_merge_and_skip_broad_features(self):
        features = [{"frequency_hz": 100.0, "damping_ratio": 0.01}, {"frequency_hz": 103.0, "damping_ratio": 0.01},
                    {"frequency_hz": 500.0, "damping_ratio": 0.002}, {"frequency_hz": 800.0, "damping_ratio": 0.3}]
        bands, half_power = zoom_bands(features, width=4.0, min_width=0.01)
        assert bands == [(96.0, 107.12), (495.0, 505.0)]
        assert half_power == pytest.approx(2.0)

    def test_band_lines_thin_wide_bands(self):
        lines = band_lines([(100.0, 101.0), (1000.0, 1100.0)], 0.25, 15)
        narrow, wide = lines[lines * 0.25 < 200], lines[lines * 0.25 > 200]
        assert narrow.size == 5 and 13 <= wide.size <= 17

    def test_merge_drops_the_coarse_points_the_zoom_covers(self):
        coarse = np.arange(10.0, 200.0, 5.0)
        dense = np.arange(99.0, 121.0, 1.0)
        keep = outside_bands(coarse, dense)
        assert not keep[(coarse > 99) & (coarse < 120)].any() and keep[(coarse < 99) | (coarse > 120)].all()


@pytest.fixture(scope="module")
def small_log(demo_plant):
    """A multisine log of a short noise-free linear run (a real machine's log in the contract)."""
    rig = rig_model("demo20", quiet=True)
    design = design_multisine(demo_plant, replace(SMALL, realizations=2), seed=2)
    spectra, _ = run_multisine(rig, design, noise=False, nonlinear=False)
    return multisine_frame([pass_record(design, spectra)])


class TestLog:
    def test_round_trip(self, small_log, tmp_path):
        path = tmp_path / "multisine.parquet"
        write_multisine_log(small_log, path, {"machine": "demo20"})
        frame, info = read_multisine_log(path)
        assert info["kind"] == "multisine_log" and info["metadata"]["channel_units"]["V2_DX"] == "m"
        passes = multisine_passes(frame)
        assert len(passes) == 1 and passes[0]["spectra"].shape[:3] == (2, 4, 2)
        assert set(frame["channel"]) == set(CHANNELS + REFERENCE_CHANNELS)

    def test_a_log_without_coil_currents(self, small_log, tmp_path):
        """A logger that records positions and commands only: the coil currents are optional for a whole log (as in a
        stepped-sine log), the BLA has no coil-current FRF and the excitation level takes U2 in their place; one
        missing coil channel is still an incomplete log."""
        coils = small_log["channel"].str.startswith("I_")
        without = small_log[~coils].reset_index(drop=True)
        write_multisine_log(without, tmp_path / "multisine.parquet")
        frame, _ = read_multisine_log(tmp_path / "multisine.parquet")
        passes = multisine_passes(frame)
        table, estimates = multisine_frf(passes)
        full, _ = multisine_frf(multisine_passes(small_log))
        assert "current" not in set(table["estimator"]) and "current" in set(full["estimator"])
        plant = full[full["estimator"] != "current"].reset_index(drop=True)
        assert_allclose(table[["re", "im", "std"]].to_numpy(), plant[["re", "im", "std"]].to_numpy())
        level = excitation_covariance(passes[0]["spectra"], passes[0]["reference"])
        u2 = np.mean(np.sum(np.abs(passes[0]["spectra"][:, :, :, CHANNELS.index("U2_DX")]) ** 2, axis=-1)) / 2
        assert level["DX"][0] == pytest.approx(u2)
        assert level["DX"][1] == pytest.approx(excitation_covariance(*(
            lambda p: (p["spectra"], p["reference"]))(multisine_passes(small_log)[0]))["DX"][1])
        with pytest.raises(LogError, match="lacks channel\\(s\\) I_upper_DX"):
            validate_multisine_log(small_log[small_log["channel"] != "I_upper_DX"].reset_index(drop=True), "m.parquet")

    def broken(self, frame, change):
        frame = frame.copy()
        result = change(frame)
        return frame if result is None else result

    @pytest.mark.parametrize("change, message", [
        (lambda f: f.__setitem__("channel", f["channel"].where(f.index != f.index[f["channel"] == "V2_NX"][0], "V2_DX")), "duplicate channel"),
        (lambda f: f.__setitem__("period", f["period"].where(f["period"] != 1, 0)), "duplicate channel"),
        (lambda f: f.drop(index=f.index[f["channel"] == "V2_NX"][:1]).reset_index(drop=True), "lacks channel"),
        (lambda f: f[f["period"] == 0].reset_index(drop=True), "number \\(>= 2\\) of periods"),
        (lambda f: f.loc[f.index[f["channel"] == "V2_DX"][3], "re"].__class__ and f.__setitem__(
            "re", f["re"].where(f.index != f.index[f["channel"] == "V2_DX"][3], np.nan)), "re is not finite"),
        (lambda f: f.__setitem__("frequency_hz", f["frequency_hz"].where(f["line"] != f["line"].max(),
                                                                         f["frequency_hz"] * 1.01)), "not line x f0"),
        (lambda f: f.__setitem__("role", f["role"].where(f["line"] != f["line"].min(), "odd_detection")),
         "detection line carries excitation"),
        (lambda f: f.__setitem__("im", f["im"].where(~((f["channel"] == "U2_DX") & (f["role"] == "excited")), 0.0))
         or f.__setitem__("re", f["re"].where(~((f["channel"] == "U2_DX") & (f["role"] == "excited")), 0.0)),
         "control current U2 of an axis excited"),
        (lambda f: f.__setitem__("role", f["role"].where(f["role"] != "even_detection", "odd")), "unknown role"),
    ])
    def test_bad_logs_name_the_rows(self, small_log, change, message):
        with pytest.raises(LogError, match=message) as error:
            validate_multisine_log(self.broken(small_log, change), "data/m/r/multisine.parquet")
        assert "data/m/r/multisine.parquet" in str(error.value)
        assert "row" in str(error.value) or "pass" in str(error.value)


class TestPlausibility:
    """A multisine log against the nominal model as a stepped-sine log is (`ambid.plausibility.check_units` through
    its BLA, `ambid.plausibility.frf_arrays`): before, rule bla read it unchecked."""

    def checked(self, frame, plant):
        table, _ = multisine_frf(multisine_passes(frame))
        return check_units(frf_arrays(table), plant, "data/demo20/ms/multisine.parquet")

    def test_the_log_is_plausible(self, small_log, demo_plant):
        ratios = {(r["check"], r["axes"]): r["ratio"] for r in self.checked(small_log, demo_plant)}
        assert {("compliance", "DX DY NX NY"), ("coil_current", "DX DY NX NY"), ("compliance", "Z")} <= set(ratios)
        assert all(0.5 < ratio < 2 for ratio in ratios.values()), ratios

    @staticmethod
    def scaled(frame, chosen, factor):
        frame.loc[chosen, ["re", "im"]] *= factor
        return frame

    @pytest.mark.parametrize("edit, named", [
        (lambda f: TestPlausibility.scaled(f, f["channel"].str.startswith("V2_"), 1e6), "positions look like um"),
        (lambda f: TestPlausibility.scaled(f, f["channel"] == "V2_NX", -1.0), "the compliance V2/U2 of NX has the opposite"),
        (lambda f: f.assign(channel=f["channel"].replace({"I_upper_DY": "I_lower_DY", "I_lower_DY": "I_upper_DY"})),
         "I_upper_DY and I_lower_DY look swapped"),
        (lambda f: f.assign(im=-f["im"]), "look complex conjugated"),
    ])
    def test_a_unit_sign_or_convention_error_is_named(self, small_log, demo_plant, edit, named):
        with pytest.raises(LogError, match=named) as error:
            self.checked(edit(small_log.copy()), demo_plant)
        assert str(error.value).startswith("data/demo20/ms/multisine.parquet")


def test_identification_with_zoom_on_the_nonlinear_rig(demo_plant, demo_rig):
    """The whole run, small: a coarse pass, its fit, a zoom around what it found; machine time adds up."""
    settings = replace(SMALL, frequency_resolution_hz=5.0, radial_band_hz=(5.0, 800.0), axial_band_hz=(5.0, 50.0),
                       levels=(1.0, 0.5), level_check=True, zoom=True, zoom_resolution_min_hz=1.0, settle_s=0.3)
    passes, plan = identify_multisine(demo_rig, demo_plant, settings, seed=1, fit_options={"delay": True},
                                      fit_channels="diagonal")
    assert [p["name"] for p in passes] == ["coarse", "zoom"]
    truth = 455.4  # demo20 rig: the first flexible resonance (the nominal model says 706 Hz)
    assert any(low < truth < high for low, high in plan["bands_hz"])
    assert sum(p["stats"]["machine_time_s"] for p in passes) == pytest.approx(
        sum(p["design"].machine_time_s + p["stats"]["level_check_s"] for p in passes))
    table, estimates = multisine_frf(passes)
    zoomed = estimates["radial"].frequency_hz
    assert np.sum(np.abs(zoomed - truth) < 5) > np.sum(np.abs(passes[0]["frequency_hz"] - truth) < 5)
    assert np.all(np.diff(zoomed) > 0)
    assert np.isfinite(table["systematic_std"]).any()


def test_stepped_sine_zoom_merges_into_one_valid_log(demo_plant):
    """Zoom after a stepped-sine pass: dense steps in the bands, coarse ones there dropped, one valid log."""
    from ambid.excitation import SteppedSineSettings, StepPlan, run_stepped_sine
    from ambid.logs import identification_frame, validate_identification_log
    from ambid.zoom import merge_stepped, stepped_zoom_plan

    rig = rig_model("demo20")
    fast = SteppedSineSettings(settle_min_s=0.03, settle_max_s=0.1, measure_min_s=0.02, axes=("DX", "NX"))
    coarse_f = np.linspace(400.0, 500.0, 6)
    coarse = StepPlan(np.repeat(["DX", "NX"], 6), np.tile(np.arange(6), 2), np.tile(coarse_f, 2), np.full(12, 0.5))
    dense = stepped_zoom_plan(demo_plant, [(450.0, 460.0)], fast, points_per_band=5)
    assert set(dense.axis) == {"DX", "NX"} and np.allclose(np.unique(dense.frequency_hz), np.linspace(450, 460, 5))
    first, _ = run_stepped_sine(rig, coarse, fast, seed=1)
    second, _ = run_stepped_sine(rig, dense, fast, seed=2)
    merged = merge_stepped(first, second)
    frame = identification_frame(merged)
    validate_identification_log(frame, "merged")
    grid = frame[(frame["excited_axis"] == "DX") & (frame["channel"] == "U2_DX")]["frequency_hz"].to_numpy()
    assert np.all(np.diff(grid) > 0) and grid.size == 6 - 1 + 5  # the coarse 460 Hz step lies in the band


def test_per_axis_design_gives_siso_and_mimo(demo_plant):
    """One axis per experiment (as the stepped sine): the SISO ratios and the MIMO plant, on the linear rig."""
    rig = rig_model("demo20", quiet=True)
    design = design_multisine(demo_plant, replace(SMALL, design="per_axis"), seed=2)
    assert design.experiments == 5
    spectra, _ = run_multisine(rig, design, noise=False, nonlinear=False)
    table, estimates = multisine_frf([pass_record(design, spectra)], design="per_axis")
    assert {"siso", "mimo", "current"} <= set(table["estimator"])
    assert ("NX", "DX") in estimates["siso"] and len(estimates["siso"]) == 16
    radial = estimates["radial"]
    truth = rig.sampled_frequency_response(radial.frequency_hz)[:, :4, :4]
    assert_allclose(radial.plant, truth, rtol=2e-4, atol=2e-4 * np.abs(truth).max())
