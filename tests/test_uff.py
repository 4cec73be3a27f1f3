"""UFF dataset 58 export, read back with a fixed-width reader of the format."""

import numpy as np
import pytest
import scipy.signal
from numpy.testing import assert_allclose

from ambid.uff import write_uff58


def read_uff58(path):
    """Minimal reader of our datasets: header records by column position, data as E13.5 + 2 E20.12."""
    lines = path.read_text().splitlines()
    out, k = [], 0
    while k < len(lines):
        assert lines[k] == "    -1" and lines[k + 1] == "    58"
        record6, record7 = lines[k + 7], lines[k + 8]
        n = int(record7[10:20])
        assert int(record6[0:5]) == 4 and int(record7[0:10]) == 6 and int(record7[20:30]) == 0
        data = lines[k + 13 : k + 13 + n]
        f = np.array([float(line[0:13]) for line in data])
        values = np.array([float(line[13:33]) + 1j * float(line[33:53]) for line in data])
        # record 6: I5 I10 I5 I10 1X A10 I10 I4 1X A10 I10 I4
        out.append((record6[31:41].strip(), int(record6[41:51]), int(record6[51:55]), record6[56:66].strip(), int(record6[66:76]), int(record6[76:80]), f, values))
        assert lines[k + 13 + n] == "    -1"
        k += 14 + n
    return out


def test_round_trip(tmp_path):
    f = np.linspace(1.0, 750.0, 250)
    values = 1e-4 / (1 + 1j * f / 300.0) * np.exp(-1j * f / 100)
    path = tmp_path / "frf.uff"
    write_uff58(path, [("mimo", "NX", "DX", f, values), ("siso", "Z", "Z", f[:10], values[:10])])
    datasets = read_uff58(path)
    assert [(d[0], d[1], d[2], d[3], d[4], d[5]) for d in datasets] == [("NX", 2, 1, "DX", 1, 1), ("Z", 3, 3, "Z", 3, 3)]
    assert_allclose(datasets[0][6], f, rtol=1e-5)
    assert_allclose(datasets[0][7], values, rtol=1e-11)
    assert all(len(line) <= 80 for line in path.read_text().splitlines())


def test_non_finite_is_refused(tmp_path):
    with pytest.raises(ValueError, match="siso DX/DX"):
        write_uff58(tmp_path / "x.uff", [("siso", "DX", "DX", [1.0], [np.nan])])
    with pytest.raises(ValueError, match="unknown estimator 'bla'"):
        write_uff58(tmp_path / "x.uff", [("bla", "DX", "DX", [1.0], [1.0])])
    assert not (tmp_path / "x.uff").exists()


def test_plant_exports_to_scipy(hs_plant):
    f = np.array([50.0, 400.0, 650.0])
    system = hs_plant.to_scipy()
    w = 2 * np.pi * f
    response = np.array([system.C @ np.linalg.solve(1j * wk * np.eye(system.A.shape[0]) - system.A, system.B) for wk in w])
    assert_allclose(response, hs_plant.radial_frequency_response(f), rtol=1e-8, atol=1e-16)
    zpk = hs_plant.channel_zpk("NX", "NX")
    _, h = scipy.signal.freqresp(zpk, w)
    assert_allclose(h, hs_plant.radial_frequency_response(f)[:, 2, 2], rtol=1e-6)
