"""Multiple returns in LAS/LAZ/COPC: return numbers in the point's return bits and the
echo's width and amplitude as described extra bytes, read back with laspy; files of
single returns keep their return 1 of 1."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from sensors import physics as ph
from sensors import waveform as wf
from sensors.io.fields import POINT_DTYPE
from sensors.writers import open_writer

MODEL = wf.WaveformModel(pulse_fwhm_s=4e-9, threshold_power=1e-7)
RET_DTYPE = np.dtype(POINT_DTYPE.descr + list(wf.RETURN_FIELDS))


def _records():
    """Returns of three pulses along +x through two planes (1.5 m apart in pulse 0,
    one plane in pulse 1, three in pulse 2) in "all" mode, as records."""
    _, w = ph.subray_offsets(7)
    r = np.array([[5.0] * 4 + [6.5] * 3, [8.0] * 7, [3.0] * 2 + [4.0] * 2 + [9.0] * 3])
    p = ph.power(0.5, 1.0, r, 0.0)
    out = wf.chunk_returns(r, p, np.ones_like(r), np.zeros(r.shape, np.int32), w, MODEL,
                           "all", max_returns=4)
    rec = np.zeros(len(out), dtype=RET_DTYPE)
    rec["x"] = out.range_m
    rec["y"] = out.pulse
    rec["time"] = out.pulse * 1e-3
    rec["range"] = out.range_m
    rec["flag"] = out.flag
    rec["return_number"] = out.return_number
    rec["number_of_returns"] = out.number_of_returns
    rec["echo_width"] = out.width_m
    rec["echo_amplitude"] = out.amplitude
    return rec


@pytest.mark.parametrize("suffix", ["las", "laz", "copc.laz"])
def test_return_numbers_and_echo_fields_read_back(tmp_path, suffix):
    rec = _records()
    assert list(rec["return_number"]) == [1, 2, 1, 1, 2, 3]
    path = tmp_path / f"r.{suffix}"
    with open_writer(path, sensor="velodyne_vlp16", seed=3) as w:
        w.write_points(rec)
    las = laspy.read(path)
    order = np.lexsort((np.asarray(las.x), np.asarray(las.gps_time)))
    assert np.array_equal(np.asarray(las.return_number)[order], rec["return_number"])
    assert np.array_equal(np.asarray(las.number_of_returns)[order],
                          rec["number_of_returns"])
    np.testing.assert_array_equal(np.asarray(las.echo_width)[order], rec["echo_width"])
    np.testing.assert_array_equal(np.asarray(las.echo_amplitude)[order],
                                  rec["echo_amplitude"])
    desc = {e.name: e.description for e in las.point_format.extra_dimensions}
    assert desc["echo_width"].startswith("echo Gaussian sigma")
    # Consistent on every point: 1 <= return_number <= number_of_returns, one point per
    # return number of each pulse, and farther returns have larger numbers.
    rn, nr = np.asarray(las.return_number)[order], np.asarray(las.number_of_returns)[order]
    pulse = np.round(np.asarray(las.y)[order]).astype(int)
    assert np.all((rn >= 1) & (rn <= nr))
    for i in np.unique(pulse):
        k = pulse == i
        assert sorted(rn[k]) == list(range(1, nr[k][0] + 1))
        assert np.all(np.diff(np.asarray(las.x)[order][k]) > 0)


def test_single_returns_stay_one_of_one(tmp_path):
    rec = np.zeros(3, dtype=POINT_DTYPE)
    rec["x"] = [1.0, 2.0, 3.0]
    with open_writer(tmp_path / "s.las", sensor="velodyne_vlp16") as w:
        w.write_points(rec)
    las = laspy.read(tmp_path / "s.las")
    assert np.all(las.return_number == 1) and np.all(las.number_of_returns == 1)
    assert "echo_width" not in las.point_format.dimension_names

