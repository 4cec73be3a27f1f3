"""Exports: FRF tables and fitted models as CSV and .mat, read back with pandas and scipy.io."""

import numpy as np
import pandas as pd
import scipy.io
from numpy.testing import assert_allclose

from ambid.channel_fit import ChannelModel, model_rows
from ambid.export import frf_csv, frf_mat, models_csv, models_mat
from ambid.frf import current_etfe, frf_table, log_arrays, mimo_etfe, siso_etfe
from ambid.logs import identification_frame
from ambid.machine import ALL_AXES
from test_logs import make_steps, own_bearing_only


def table():
    arrays = log_arrays(own_bearing_only(identification_frame(make_steps(axes=ALL_AXES, n_steps=6))))
    return frf_table(siso_etfe(arrays), mimo_etfe(arrays), current=current_etfe(arrays))


def test_frf_csv_and_mat(tmp_path):
    frf = table()
    frf_csv(frf, tmp_path / "frf.csv")
    back = pd.read_csv(tmp_path / "frf.csv")
    assert_allclose(back[["re", "im", "std"]], frf[["re", "im", "std"]], rtol=1e-11)
    assert_allclose(back["magnitude"], np.hypot(frf["re"], frf["im"]), rtol=1e-11)
    frf_mat(frf, tmp_path / "frf.mat")
    mat = scipy.io.loadmat(tmp_path / "frf.mat", squeeze_me=True, simplify_cells=True)
    assert sorted(k for k in mat if not k.startswith("__")) == ["frf_current", "frf_mimo", "frf_siso"]
    siso = mat["frf_siso"]
    assert list(siso["outputs"]) == list(ALL_AXES) and list(siso["inputs"]) == list(ALL_AXES)
    rows = frf[(frf["estimator"] == "siso") & (frf["output"] == "NX") & (frf["input"] == "DY")].sort_values("frequency_hz")
    assert_allclose(siso["H"][:, 2, 1], rows["re"] + 1j * rows["im"], rtol=1e-15)
    assert np.isnan(siso["H"][:, 4, 0]).all()  # Z/DX: the radial steps do not carry V2_Z
    assert mat["frf_mimo"]["H"].shape == (6, 4, 4) and mat["frf_current"]["unit"] == "A/A"
    first = (tmp_path / "frf.mat").read_bytes()
    frf_mat(frf, tmp_path / "frf.mat")
    assert (tmp_path / "frf.mat").read_bytes() == first and first.startswith(b"MATLAB 5.0 MAT-file, written by ambid")


class FakeFit:
    def __init__(self, model):
        self.model, self.order, self.cost, self.dropped = model, 8, 1.1, []


def test_models_round_trip_as_transfer_functions(tmp_path):
    """The .mat's num/den and delay give the fitted model's response; the CSV its parameters."""
    model = ChannelModel(gain=2e3, rigid_rad_s=np.array([300.0]), mode_rad_s=np.array([4500.0, 9000.0]),
                         mode_damping=np.array([0.01, 0.03]), zero_factors=np.array([[50.0, 6.0e6]]), residual_s2=1e-9,
                         lowpass_rad_s=2e4, delay_s=4e-5)
    rows = [model_rows(FakeFit(model), "DX", "DX"), model_rows(FakeFit(model), "NX", "DX")]
    models_mat(rows, tmp_path / "models.mat")
    models_csv(rows, tmp_path / "models.csv")
    mat = scipy.io.loadmat(tmp_path / "models.mat", squeeze_me=True, simplify_cells=True)
    fitted = mat["model_NX_DX"]
    f = np.linspace(1.0, 2000.0, 50)
    s = 2j * np.pi * f
    response = np.polyval(fitted["numerator"], s) / np.polyval(fitted["denominator"], s) * np.exp(-s * fitted["delay_s"])
    assert_allclose(response, model.frequency_response(f), rtol=1e-9)
    assert_allclose(fitted["mode_hz"], [4500 / (2 * np.pi), 9000 / (2 * np.pi)])
    csv = pd.read_csv(tmp_path / "models.csv")
    assert list(csv["output"]) == ["DX", "NX"] and csv["delay_s"].iloc[0] == 4e-5
