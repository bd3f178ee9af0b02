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


def test_wave_packets_round_trip(tmp_path):
    """LAS 1.4 point format 9 with the waveform in the waveform data packet record
    (EVLR): laspy reads the points' wave packet fields and the descriptors back, and
    the samples at each point's offset are the pulse's waveform (to half a digitizer
    step), with the return's peak at its return point location."""
    from sensors.io.las import WAVEFORM_EVLR, LasWriter

    _, w = ph.subray_offsets(7)
    # Pulse 0: two planes 1.5 m apart; pulse 1: one plane behind dust at 2 m.
    r = np.array([[5.0] * 4 + [6.5] * 3 + [np.inf], [9.0] * 7 + [2.0]])
    pw = np.concatenate([ph.power(0.5, 1.0, r[:, :7], 0.0) * w,
                         [[0.0], [ph.power(0.1, 1.0, 2.0, 0.0)]]], axis=1)
    e = wf.detect_echoes(r, pw, MODEL)
    ret = wf.select_returns(e, "all", max_returns=4)
    rng_m = ret.take(e.range_m)
    d = np.tile([1.0, 0.0, 0.0], (len(ret), 1))
    full = 1.0 / 0.5 ** 2                                 # white target at 0.5 m
    wp = wf.wave_packets(r, pw, MODEL, return_pulse=ret.pulse, return_range_m=rng_m,
                         direction=d, full_scale=full)
    head = laspy.LasHeader(point_format=9, version="1.4")
    head.global_encoding.waveform_data_packets_internal = True
    for rid, payload in wp.descriptors:
        head.vlrs.append(laspy.VLR("LASF_Spec", rid, "wave packet descriptor", payload))
    pts = laspy.ScaleAwarePointRecord.zeros(len(ret), header=head)
    pts.x, pts.return_number = rng_m, ret.return_number
    pts.number_of_returns = ret.number_of_returns
    pts.wavepacket_index, pts.wavepacket_offset = wp.index, wp.offset
    pts.wavepacket_size, pts.return_point_wave_location = wp.size, wp.location_ps
    pts.x_t, pts.y_t, pts.z_t = wp.xyz_t.T
    path = tmp_path / "fwf.las"
    with LasWriter(path, head, evlrs=[laspy.VLR(*WAVEFORM_EVLR, "waveform data",
                                                wp.data)]) as lw:
        lw.write_points(pts)
    las = laspy.read(path)
    assert las.header.point_format.id == 9
    # laspy parses the descriptors itself (its WaveformPacketVlr).
    descr = {v.record_id: tuple(getattr(v.parsed_record, f) for f, _ in
                                v.parsed_record._fields_)
             for v in las.header.vlrs if type(v).__name__ == "WaveformPacketVlr"}
    assert sorted(descr) == list(range(100, 100 + len(wf.WAVE_PACKET_SAMPLES)))
    blob = path.read_bytes()
    start = int(las.header.start_of_waveform_data_packet_record)
    assert blob[start + 2:start + 18].rstrip(b"\0") == b"LASF_Spec"
    _, waves = wf.waveforms(r, pw, MODEL)
    for q in range(len(ret)):
        bits, comp, n, spacing, gain, off = descr[99 + int(las.wavepacket_index[q])]
        assert (bits, comp, spacing, off) == (16, 0, 250, 0.0)
        assert int(las.wavepacket_size[q]) == n * 2
        o = start + int(las.wavepacket_offset[q])
        samples = np.frombuffer(blob[o:o + 2 * n], dtype="<u2") * gain
        row = waves[ret.pulse[q]][:n]
        np.testing.assert_allclose(samples[:len(row)], row, atol=gain / 2 + 1e-15)
        # The return's sample: its peak (the first echo of pulse 1 is the dust).
        k = int(round(float(las.return_point_wave_location[q]) / spacing))
        win = samples[max(k - 8, 0):k + 9]
        assert samples[k] == win.max()
        np.testing.assert_allclose(las.x_t[q], -C_HALF_PER_PS, rtol=1e-6)
    assert list(las.return_number) == [1, 2, 1, 2]


C_HALF_PER_PS = 299_792_458.0 / 2 * 1e-12
