"""Coordinate reference systems (issue 21): parsing, comparison, sidecars, and every
writer stating the CRS where its format keeps it. References are independent of
``sensors.io.crs``: pyproj builds and compares the expected CRSs, laspy reads LAS headers
(``parse_crs``), pye57 reads E57's ``coordinateMetadata``, the sidecar is read as text.
"""

from __future__ import annotations

import builtins
import json

import laspy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors import simulate_station
from sensors.io.crs import (
    CRSError,
    area_warning,
    comment_crs,
    crs_comment,
    crs_label,
    crs_mismatch,
    crs_wkt,
    file_wkt,
    mismatch_message,
    parse_crs,
    read_sidecar,
    same_crs,
    sidecar_path,
    text_file_crs,
    write_sidecar,
)
from sensors.io.las import CRS_USER, las_crs_wkt, set_las_crs, write_las

pyproj = pytest.importorskip("pyproj", reason="CRS handling needs pyproj (pip install "
                              "'tunnelsim[crs]'); every test here uses it")
CRS = pyproj.CRS
Transformer = pyproj.Transformer

LV95 = CRS("EPSG:2056")
#: A station's surroundings in LV95 (Bern, near the projection's origin).
ORIGIN = np.array([2_600_000.0, 1_200_000.0, 500.0])


def _no_pyproj(monkeypatch):
    """Make ``import pyproj`` fail, as where the extra is not installed."""
    real = builtins.__import__

    def fake(name, *a, **k):
        if name == "pyproj" or name.startswith("pyproj."):
            raise ImportError("No module named 'pyproj'")
        return real(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", fake)


# ---------------------------------------------------------------------------- parsing
@pytest.mark.parametrize("form", [
    "EPSG:2056", " epsg:2056 ", "urn:ogc:def:crs:EPSG::2056",
    LV95.to_wkt("WKT1_GDAL"), LV95.to_wkt("WKT2_2019"), LV95.to_wkt(pretty=True),
    LV95.to_json(), LV95.to_json_dict(), LV95])
def test_every_form_gives_the_same_crs(form):
    assert parse_crs(form).equals(LV95)


@pytest.mark.parametrize("bad, words", [
    ("2056", "bare number '2056'; write EPSG:2056"),
    ("LV95", "names and PROJ strings are ambiguous"),
    ("+proj=utm +zone=32 +datum=WGS84", "names and PROJ strings are ambiguous"),
    ("EPSG:999999", "that PROJ knows, got 'EPSG:999999', which it refuses"),
    ("PROJCS[broken", "which it refuses"),
    ("", "got an empty string"),
    (2056, "as a string"),
    ("EPSG:4326", "axes in metres .* got EPSG:4326 \\(WGS 84\\) \\(Geographic 2D CRS; "
                  "degree, degree\\)"),
    ("EPSG:2229", "axes in metres .*US survey foot"),
])
def test_bad_crs_is_refused_with_the_reason(bad, words):
    with pytest.raises(CRSError, match="Expected --crs " if bad != 2056 else "Expected"):
        parse_crs(bad, what="--crs")
    with pytest.raises(CRSError, match=words):
        parse_crs(bad, what="--crs")


def test_a_crs_in_degrees_is_read_from_a_file_but_not_taken_for_metres():
    assert parse_crs("EPSG:4326", metric=False).equals(CRS("EPSG:4326"))


def test_labels_name_the_code_and_the_name():
    assert crs_label(LV95) == "EPSG:2056 (CH1903+ / LV95)"
    assert crs_label(CRS("EPSG:2056+5728")) == \
        "EPSG:2056+5728 (CH1903+ / LV95 + LN02 height)"
    custom = CRS.from_proj4("+proj=tmerc +lat_0=0 +lon_0=9 +k=1 +x_0=0 +y_0=0 "
                            "+ellps=GRS80 +units=m +no_defs")
    assert crs_label(custom) == repr(custom.name)


def test_pyproj_is_needed_only_when_a_crs_is_given(monkeypatch, tmp_path):
    _no_pyproj(monkeypatch)
    with pytest.raises(CRSError, match="pip install 'tunnelsim\\[crs\\]'"):
        parse_crs("EPSG:2056")
    # Identical texts are the same CRS without pyproj; files without a CRS need none.
    wkt = LV95.to_wkt()
    assert same_crs(wkt, " ".join(wkt.split()))
    assert crs_mismatch([("a", None), ("b", wkt), ("c", wkt)]) is None
    path = write_las(tmp_path / "plain.las", np.zeros((3, 3)))
    assert las_crs_wkt(laspy.read(path).header) is None


# ---------------------------------------------------------------------------- WKT
#: Metric CRSs of every kind tunnel surveys meet: projected (UTM, national grids, an
#: oblique Mercator, Krovak), compounds with a vertical CRS, geocentric.
METRIC = ["EPSG:2056", "EPSG:21781", "EPSG:2056+5728", "EPSG:25832", "EPSG:32632",
          "EPSG:32633", "EPSG:31287", "EPSG:5514", "EPSG:7415", "EPSG:27700",
          "EPSG:3857", "EPSG:4978", "EPSG:4936", "EPSG:28992", "EPSG:2154",
          "EPSG:25833+7837", "EPSG:3044"]


@settings(max_examples=len(METRIC), deadline=None)
@given(st.sampled_from(METRIC))
def test_the_wkt_written_into_files_is_the_same_crs(code):
    c = CRS(code)
    text = file_wkt(code)
    assert CRS.from_wkt(text).equals(c)            # whatever the version, no loss
    assert CRS.from_wkt(crs_wkt(code)).equals(c)
    assert crs_wkt(code).startswith(("PROJCRS", "COMPOUNDCRS", "GEODCRS", "BOUNDCRS"))


def test_wkt1_where_it_holds_the_crs():
    # LAS 1.4 names WKT1; LAStools reads nothing else.
    assert file_wkt("EPSG:2056").startswith('PROJCS["CH1903+ / LV95"')
    assert file_wkt("EPSG:2056+5728").startswith("COMPD_CS[")


def test_same_crs_is_projs_equivalence():
    assert same_crs("EPSG:2056", LV95.to_wkt("WKT1_GDAL"))
    assert same_crs("EPSG:2056", LV95.to_json_dict())
    assert not same_crs("EPSG:2056", "EPSG:32632")
    assert not same_crs("EPSG:2056", "EPSG:2056+5728")     # a vertical CRS more
    assert not same_crs("EPSG:2056", "EPSG:21781")         # LV95 vs LV03


def test_a_mismatch_names_both_inputs_and_both_crss():
    pair = crs_mismatch([("a.laz", "EPSG:2056"), ("b.e57", None), ("c.laz", "EPSG:2056"),
                         ("d.laz", "EPSG:32632")])
    assert pair == (("a.laz", "EPSG:2056"), ("d.laz", "EPSG:32632"))
    text = mismatch_message(*pair, hint="reproject one")
    assert text == ("Expected the inputs in one coordinate reference system, got 'a.laz' "
                    "in EPSG:2056 (CH1903+ / LV95) and 'd.laz' in EPSG:32632 (WGS 84 / "
                    "UTM zone 32N); reproject one.")
    assert crs_mismatch([("a", "EPSG:2056"), ("b", LV95.to_wkt("WKT1_GDAL"))]) is None


# ---------------------------------------------------------------------------- sidecars
def test_sidecar_round_trip_and_a_stale_one_removed(tmp_path):
    f = tmp_path / "scan.ply"
    assert sidecar_path(f) == tmp_path / "scan.ply.prj"
    assert read_sidecar(f) is None
    write_sidecar(f, "EPSG:2056")
    assert CRS.from_wkt((tmp_path / "scan.ply.prj").read_text()).equals(LV95)
    assert CRS(read_sidecar(f)).equals(LV95)
    write_sidecar(f, None)                        # a file written without a CRS
    assert not (tmp_path / "scan.ply.prj").exists()
    (tmp_path / "scan.ply.prj").write_text("\n")
    assert read_sidecar(f) is None


def test_comment_line_states_a_text_files_crs(tmp_path):
    f = tmp_path / "cp.csv"
    f.write_text("# surveyed 2026-05-04\n\n#  CRS = EPSG:2056 \nid,x,y,z\nA,1,2,3\n")
    assert comment_crs(f) == "EPSG:2056"
    f.write_text("id,x,y,z\n# crs: EPSG:2056\nA,1,2,3\n")   # after the data: not a header
    assert comment_crs(f) is None
    write_sidecar(f, "EPSG:32632")
    assert CRS(text_file_crs(f)).equals(CRS("EPSG:32632"))
    f.write_text("# crs: EPSG:2056\nid,x,y,z\n")
    assert text_file_crs(f) == "EPSG:2056"         # the file's own line wins


@pytest.mark.parametrize("crs", ["EPSG:2056", "EPSG:2056+5728", LV95.to_wkt("WKT1_GDAL"),
                                 "+proj=tmerc +lon_0=9 +ellps=GRS80 +units=m"])
def test_the_comment_line_written_reads_back_as_the_same_crs(tmp_path, crs):
    c = CRS.from_user_input(crs)
    line = crs_comment(c)
    assert line.startswith("# crs: ") and "\n" not in line
    f = tmp_path / "cp.csv"
    f.write_text(line + "\nid,x,y,z\n")
    assert CRS.from_user_input(comment_crs(f)).equals(c)
    if crs == "EPSG:2056":
        assert line == "# crs: EPSG:2056"


# ---------------------------------------------------------------------------- area of use
def test_points_outside_the_area_of_use_are_named():
    assert area_warning("EPSG:2056", ORIGIN) is None
    assert area_warning("EPSG:2056+5728", ORIGIN + [100.0, 0.0, 0.0]) is None
    text = area_warning("EPSG:2056", [0.0, 0.0, 0.0], what="--origin")
    assert text.startswith("--origin at (0.000, 0.000, 0.000) is outside the area of use "
                           "of EPSG:2056 (CH1903+ / LV95) (Liechtenstein; Switzerland:")
    swapped = area_warning("EPSG:2056", [1_200_000.0, 2_600_000.0, 500.0])
    assert swapped is not None and "easting and northing swapped" in swapped
    assert area_warning("EPSG:4978", [0.0, 0.0, 0.0]) is None       # no projection
    # The reference: PROJ's own inverse projection (to WGS 84) and the EPSG area of use,
    # on a grid of offsets from Bern reaching beyond every border of the area.
    to_ll = Transformer.from_crs(LV95, "EPSG:4326", always_xy=True)
    box = LV95.area_of_use
    for de in (-300e3, -150e3, 0.0, 150e3, 300e3):
        for dn in (-200e3, -100e3, 0.0, 100e3, 200e3):
            lon, lat = to_ll.transform(ORIGIN[0] + de, ORIGIN[1] + dn)
            outside = not (box.west - 0.5 <= lon <= box.east + 0.5 and
                           box.south - 0.5 <= lat <= box.north + 0.5)
            got = area_warning("EPSG:2056", ORIGIN + [de, dn, 0.0])
            assert (got is not None) == outside, (de, dn, lon, lat)


# ---------------------------------------------------------------------------- LAS
def test_las_states_its_crs_as_las_14_asks(tmp_path):
    path = write_las(tmp_path / "a.laz", ORIGIN + np.eye(3), crs="EPSG:2056")
    head = laspy.read(path).header
    assert head.global_encoding.wkt                      # LAS 1.4 R15: the WKT bit
    crs_vlrs = [v for v in head.vlrs if v.user_id == CRS_USER]
    assert [(v.user_id, v.record_id) for v in crs_vlrs] == [(CRS_USER, 2112)]
    assert head.parse_crs().equals(LV95)
    assert CRS.from_wkt(las_crs_wkt(head)).equals(LV95)


def test_set_las_crs_replaces_and_removes(tmp_path):
    head = laspy.read(write_las(tmp_path / "a.las", ORIGIN + np.eye(3),
                                crs="EPSG:2056")).header
    set_las_crs(head, "EPSG:32632")
    assert len([v for v in head.vlrs if v.user_id == CRS_USER]) == 1
    assert CRS.from_wkt(las_crs_wkt(head)).equals(CRS("EPSG:32632"))
    set_las_crs(head, None)
    assert las_crs_wkt(head) is None and not head.global_encoding.wkt
    assert not [v for v in head.vlrs if v.user_id == CRS_USER]


def test_las_12_gets_geotiff_keys(tmp_path):
    head = laspy.LasHeader(point_format=3, version="1.2")
    set_las_crs(head, "EPSG:2056")
    las = laspy.LasData(head)
    las.x, las.y, las.z = ORIGIN[:1], ORIGIN[1:2], ORIGIN[2:]
    las.write(tmp_path / "old.las")
    back = laspy.read(tmp_path / "old.las").header
    assert las_crs_wkt(back) is None                    # no WKT record in LAS 1.2
    assert back.parse_crs().equals(LV95)                # GeoTIFF keys, read by laspy


# ---------------------------------------------------------------------------- writers
@pytest.fixture(scope="module")
def lv95_scene():
    v, f = tunnel_tube(4_000, length_m=30.0)
    return Scene(v + ORIGIN, f)


def _run(scene):
    return simulate_station(scene, "zf_imager_5016", ORIGIN + [15.0, 0.0, 1.5],
                            resolution="preview", seed=3)


@pytest.mark.parametrize("suffix", ["las", "laz", "e57", "ply", "npz"])
def test_every_writer_states_the_crs(lv95_scene, tmp_path, suffix):
    import pye57

    path = tmp_path / f"s.{suffix}"
    stats = _run(lv95_scene).write(path, crs="EPSG:2056")
    assert stats["points"] > 1000
    if suffix in ("las", "laz"):
        got = laspy.read(path).header.parse_crs()
    elif suffix == "e57":
        e57 = pye57.E57(str(path))
        got = CRS.from_wkt(e57.root["coordinateMetadata"].value())
        e57.close()
    else:
        got = CRS.from_wkt((tmp_path / f"s.{suffix}.prj").read_text())
    assert got.equals(LV95)


@pytest.mark.parametrize("suffix", ["laz", "e57", "ply", "npz"])
def test_without_a_crs_a_file_states_none(lv95_scene, tmp_path, suffix):
    import pye57

    path = tmp_path / f"s.{suffix}"
    _run(lv95_scene).write(path, crs="EPSG:2056")
    _run(lv95_scene).write(path)                  # again, without: no stale statement
    if suffix == "laz":
        head = laspy.read(path).header
        assert head.parse_crs() is None and not head.global_encoding.wkt
    elif suffix == "e57":
        e57 = pye57.E57(str(path))
        assert e57.root["coordinateMetadata"].value() == ""
        e57.close()
    else:
        assert not (tmp_path / f"s.{suffix}.prj").exists()


def test_a_bad_crs_fails_before_anything_is_simulated(lv95_scene, tmp_path):
    run = _run(lv95_scene)
    with pytest.raises(CRSError, match="the output CRS with axes in metres"):
        run.write(tmp_path / "s.laz", crs="EPSG:4326")
    assert run.stats == {} and list(tmp_path.iterdir()) == []


def test_the_simulation_info_vlr_is_kept_beside_the_crs(lv95_scene, tmp_path):
    path = tmp_path / "s.las"
    _run(lv95_scene).write(path, crs="EPSG:2056")
    las = laspy.read(path)
    info = json.loads(las.header.vlrs.get_by_id("tunnelsim", [1])[0].record_data)
    assert info["station_position"] == (ORIGIN + [15.0, 0.0, 1.5]).tolist()


def test_a_ros_bag_records_the_crs_in_its_metadata(tmp_path):
    """A rosbag2 folder: ``metadata.yaml``'s custom data ``tunnelsim`` (JSON) holds the
    WKT of the ``map`` frame."""
    pytest.importorskip("rosbags", reason="rosbags is in the test extra")
    import yaml

    from sensors import Trajectory, simulate_drive

    v, f = tunnel_tube(4_000, length_m=30.0)
    traj = Trajectory.along_polyline(ORIGIN + [[5.0, 0.0, 1.4], [20.0, 0.0, 1.4]], 2.0,
                                     rate_hz=100)
    run = simulate_drive(Scene(v + ORIGIN, f), "velodyne_vlp16", traj, seed=1,
                         t_end=traj.start_s + 0.25)
    run.write(tmp_path / "bag", crs="EPSG:2056")
    meta = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())
    info = json.loads(meta["rosbag2_bagfile_information"]["custom_data"]["tunnelsim"])
    assert CRS.from_wkt(info["crs"]).equals(LV95)
