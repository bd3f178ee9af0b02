"""sensors.io.copc: COPC files checked with two readers that share no code with the writer,
laspy's ``CopcReader`` (lazrs) and copc-lib's Python package ``copclib`` (laz-perf),
against brute-force references: a bounds query returns exactly the points a filter of
the input keeps, a level query exactly the points a per-point recursive re-statement of
the sampling rule puts at that level; the points, header and hierarchy are the same
through both readers; the file does not depend on how the input was chunked nor on the
memory bound (streamed splits and in-memory subtrees give the same bytes)."""

from __future__ import annotations

import os
import struct

import laspy
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sensors.io.copc import GRID_BITS, CopcWriter, copc_info
from sensors.io.errors import PointFileError
from sensors.io.las import point_records

copclib = pytest.importorskip("copclib")

SCALE = 1e-4


def _header(offset=(0.0, 0.0, 0.0), extra=True, fmt=6):
    h = laspy.LasHeader(point_format=fmt, version="1.4")
    h.scales = np.full(3, SCALE)
    h.offsets = np.asarray(offset, dtype=np.float64)
    if extra:
        h.add_extra_dims([laspy.ExtraBytesParams(name="range", type=np.dtype("f8")),
                          laspy.ExtraBytesParams(name="channel", type=np.dtype("u4"))])
    h.vlrs.append(laspy.VLR(user_id="tunnelsim", record_id=1, description="info",
                            record_data=b'{"sensor": "test"}'))
    return h


def _records(header, xyz, rng):
    """Records with gps_time = the point's index (an identity that survives the octree)."""
    n = len(xyz)
    fields = {"gps_time": np.arange(n, dtype=np.float64), "bit_fields": 0x11,
              "intensity": rng.integers(0, 65535, n)}
    if "range" in header.point_format.dimension_names:
        fields.update({"range": rng.random(n), "channel": rng.integers(0, 2**32, n)})
    return point_records(header, xyz, fields).array


def _write(path, header, rec, *, pieces=1, **kw):
    with CopcWriter(path, header, **kw) as w:
        for part in np.array_split(rec, pieces):
            w.write_points(part)
    return path


def naive_levels(ints: np.ndarray, leaf_points: int) -> np.ndarray:
    """The level of every point by the rule in the module notes, restated point by
    point: a node with at most ``leaf_points`` points (or at the deepest level) keeps
    them; otherwise the first point of each of its GRID^3 cells stays and the others
    go, in order, to the child node containing them."""
    pts = [tuple(int(c) for c in row) for row in ints]
    lo = [min(p[k] for p in pts) for k in range(3)]
    span = max(max(p[k] for p in pts) - lo[k] for k in range(3))
    h = max(GRID_BITS + 1, (2 * span + 1).bit_length())
    deepest = h - GRID_BITS - 1
    v = [tuple(2 * (p[k] - lo[k]) + 1 for k in range(3)) for p in pts]
    level = np.full(len(pts), -1)
    todo = [(0, list(range(len(pts))))]
    while todo:
        lev, idx = todo.pop()
        if len(idx) <= leaf_points or lev == deepest:
            level[idx] = lev
            continue
        seen, kids = set(), {}
        for i in idx:
            cell = tuple(c >> (h - lev - GRID_BITS) for c in v[i])
            if cell in seen:
                kids.setdefault(tuple(c >> (h - lev - 1) for c in v[i]), []).append(i)
            else:
                seen.add(cell)
                level[i] = lev
        todo.extend((lev + 1, kid) for kid in kids.values())
    return level


def _vec(v):
    """A copclib Vector3 as an array."""
    return np.array([v.x, v.y, v.z])


def _ints(rec):
    return np.stack([rec["X"], rec["Y"], rec["Z"]], 1).astype(np.int64)


def _ids(points):
    return np.sort(np.asarray(points.gps_time)).astype(np.int64)


def _sorted_bytes(a):
    return a[np.argsort(a["gps_time"], kind="stable")].tobytes()


def _cloud(rng, n, offset, spread):
    return offset + rng.normal(size=(n, 3)) * spread


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """A 3,000-point cloud at UTM-sized coordinates, written with small leaves (a deep
    tree) and a memory bound that forces streamed splits, in uneven pieces."""
    rng = np.random.default_rng(4)
    offset = np.array([512000.0, 5403000.0, 310.0])
    xyz = np.concatenate([_cloud(rng, 2500, offset, [20.0, 4.0, 2.0]),
                          _cloud(rng, 500, offset + 3, [0.01, 0.01, 0.01])])
    head = _header(offset=np.round(offset / 1000) * 1000)
    rec = _records(head, xyz, rng)
    path = _write(tmp_path_factory.mktemp("copc") / "a.copc.laz", head, rec, pieces=7,
                  max_memory_points=400, leaf_points=40)
    return path, head, rec


def test_level_queries_return_exactly_the_points_of_each_level(written):
    path, _, rec = written
    want = naive_levels(_ints(rec), 40)
    assert want.max() >= 4                                     # a deep tree was built
    with laspy.CopcReader.open(path) as r:
        for lev in range(want.max() + 2):
            np.testing.assert_array_equal(_ids(r.level_query(lev)),
                                          np.flatnonzero(want == lev))
        np.testing.assert_array_equal(_ids(r.level_query(range(0, 3))),
                                      np.flatnonzero(want < 3))


def test_bounds_queries_return_exactly_the_points_inside(written):
    path, head, rec = written
    q = _ints(rec)
    rng = np.random.default_rng(9)
    with laspy.CopcReader.open(path) as r:
        for _ in range(25):
            a, b = np.sort(rng.choice(len(rec), 2, replace=False))
            lo = np.minimum(q[a], q[b]) * SCALE + head.offsets
            hi = np.maximum(q[a], q[b]) * SCALE + head.offsets + rng.uniform(0, 2, 3)
            two_d = bool(rng.integers(2))
            got = r.query(bounds=laspy.Bounds(lo[:2], hi[:2]) if two_d
                          else laspy.Bounds(lo, hi))
            # laspy filters on the integer coordinates of the rounded bounds
            imin = np.round((lo - head.offsets) / SCALE)
            imax = np.round((hi - head.offsets) / SCALE)
            dims = 2 if two_d else 3
            inside = ((q[:, :dims] >= imin[:dims]) & (q[:, :dims] <= imax[:dims])).all(1)
            np.testing.assert_array_equal(_ids(got), np.flatnonzero(inside))
            assert inside.any()


def test_the_points_read_back_are_the_points_written(written):
    path, _, rec = written
    with laspy.CopcReader.open(path) as r:
        assert _sorted_bytes(r.query().array) == _sorted_bytes(rec)
    whole = laspy.read(path)                     # a plain LAZ reader: the chunk table
    assert _sorted_bytes(whole.points.array) == _sorted_bytes(rec)
    assert whole.header.point_count == len(rec)
    np.testing.assert_array_equal(whole.header.number_of_points_by_return[:2],
                                  [len(rec), 0])


def test_nodes_hold_their_own_points_one_per_grid_cell(written):
    """Every point lies strictly inside its node's cube (from the info VLR) and a node
    with children holds at most one point per grid cell."""
    path, head, rec = written
    info = copc_info(path)
    reader = copclib.FileReader(str(path))
    dtype = head.point_format.dtype()
    keys = {(n.key.d, n.key.x, n.key.y, n.key.z) for n in reader.GetAllNodes()}
    for node in reader.GetAllNodes():
        pts = np.frombuffer(bytes(reader.GetPointData(node)), dtype=dtype)
        assert len(pts) == node.point_count > 0
        size = 2 * info["halfsize"] / 2 ** node.key.d
        lo = info["center"] - info["halfsize"] + size * np.array(
            [node.key.x, node.key.y, node.key.z])
        xyz = _ints(pts) * SCALE + head.offsets
        assert ((xyz > lo) & (xyz < lo + size)).all()
        parent = (node.key.d - 1, node.key.x // 2, node.key.y // 2, node.key.z // 2)
        assert node.key.d == 0 or parent in keys
        has_kids = any(k[0] == node.key.d + 1 and (k[1] // 2, k[2] // 2, k[3] // 2) ==
                       (node.key.x, node.key.y, node.key.z) for k in keys)
        if has_kids:
            cell = np.floor((xyz - lo) / (size / 2**GRID_BITS)).astype(np.int64)
            assert len(np.unique(cell, axis=0)) == len(pts)


def test_copclib_reads_the_same_header_hierarchy_and_points(written):
    path, head, rec = written
    reader = copclib.FileReader(str(path))
    ch = reader.copc_config.las_header
    with laspy.CopcReader.open(path) as r:
        lh, li = r.header, r.copc_info
        assert (ch.point_count, ch.point_format_id, ch.point_record_length) == \
            (lh.point_count, 6, lh.point_format.size)
        np.testing.assert_array_equal(_vec(ch.scale), lh.scales)
        np.testing.assert_array_equal(_vec(ch.offset), lh.offsets)
        np.testing.assert_array_equal(_vec(ch.min), lh.mins)
        np.testing.assert_array_equal(_vec(ch.max), lh.maxs)
        assert (ch.evlr_offset, ch.evlr_count) == (lh.start_of_first_evlr, 1)
        ci = reader.copc_config.copc_info
        np.testing.assert_array_equal([ci.center_x, ci.center_y, ci.center_z], li.center)
        assert (ci.halfsize, ci.spacing, ci.root_hier_offset, ci.root_hier_size) == \
            (li.halfsize, li.spacing, li.hierarchy_root_offset, li.hierarchy_root_size)
        assert li.spacing == 2 * li.halfsize / 2**GRID_BITS
        assert (li.gps_min, li.gps_max) == (0.0, len(rec) - 1.0)
        ours = {(k.level, k.x, k.y, k.z): (e.offset, e.byte_size, e.point_count)
                for k, e in r.root_page.entries.items()}
    theirs = {(n.key.d, n.key.x, n.key.y, n.key.z): (n.offset, n.byte_size, n.point_count)
              for n in reader.GetAllNodes()}
    assert ours == theirs
    assert sum(c for _, _, c in theirs.values()) == len(rec)
    got = np.concatenate([np.frombuffer(bytes(reader.GetPointData(n)),
                                        dtype=head.point_format.dtype())
                          for n in reader.GetAllNodes()])
    assert _sorted_bytes(got) == _sorted_bytes(rec)


def test_the_info_vlr_comes_first_and_the_other_vlrs_are_kept(written):
    path, _, _ = written
    raw = path.read_bytes()
    # COPC, "Reader Implementation Notes": 'copc' at 377, version 1.0 at 393
    assert raw[377:381] == b"copc" and raw[393:395] == b"\x01\x00"
    assert struct.unpack_from("<H", raw, 375 + 18)[0] == 1            # record id 1
    assert struct.unpack_from("<H", raw, 375 + 20)[0] == 160          # 160 bytes
    assert raw[375 + 54 + 160 - 88:375 + 54 + 160] == bytes(88)       # reserved: 0
    with laspy.open(path) as f:
        head = f.header
    assert [v.user_id for v in head.vlrs][:1] == ["copc"]
    assert any(v.user_id == "tunnelsim" for v in head.vlrs)
    assert head.global_encoding.wkt
    assert "range" in head.point_format.extra_dimension_names


def test_the_file_depends_on_the_points_not_on_chunks_or_memory(tmp_path, monkeypatch):
    from sensors.io import copc

    # split files read (and large nodes compressed) 7 records at a time: a grid cell
    # taken in one piece stays taken in the next
    monkeypatch.setattr(copc, "READ_POINTS", 7)
    rng = np.random.default_rng(2)
    head = _header()
    rec = _records(head, _cloud(rng, 2000, np.zeros(3), [5.0, 1.0, 1.0]), rng)
    files = [_write(tmp_path / f"{i}.copc.laz", head, rec, pieces=pieces,
                    max_memory_points=mem, leaf_points=30)
             for i, (pieces, mem) in enumerate([(1, 10**6), (5, 30), (13, 250)])]
    first = files[0].read_bytes()
    assert all(f.read_bytes() == first for f in files[1:])


def test_an_empty_stream_gives_a_valid_empty_file(tmp_path):
    path = _write(tmp_path / "e.copc.laz", _header(),
                  np.empty(0, _header().point_format.dtype()))
    with laspy.CopcReader.open(path) as r:
        assert len(r.query()) == 0
    assert copclib.FileReader(str(path)).copc_config.las_header.point_count == 0


def test_an_interrupted_write_leaves_no_file(tmp_path, monkeypatch):
    head = _header()
    rec = _records(head, _cloud(np.random.default_rng(0), 500, np.zeros(3), [1, 1, 1]),
                   np.random.default_rng(0))
    path = tmp_path / "a.copc.laz"
    with pytest.raises(RuntimeError, match="crash"), CopcWriter(path, head) as w:
        w.write_points(rec)
        raise RuntimeError("crash")
    assert os.listdir(tmp_path) == []
    # a crash while the octree is written (in close): no file, no spill left either
    from sensors.io import copc

    def boom(self, *a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(copc._Chunks, "flush", boom)
    with pytest.raises(OSError, match="disk full"):
        _write(path, head, rec, max_memory_points=100, leaf_points=10)
    assert os.listdir(tmp_path) == []


def test_bad_input_gives_one_clear_error(tmp_path):
    p = tmp_path / "a.copc.laz"
    with pytest.raises(PointFileError, match="Expected a LAS 1.4 header with point format"):
        CopcWriter(p, laspy.LasHeader(point_format=3, version="1.2"))
    head = _header()
    head.scales = np.array([1e-4, 1e-4, 1e-3])
    with pytest.raises(PointFileError, match="Expected equal positive x, y, z scales"):
        CopcWriter(p, head)
    with pytest.raises(PointFileError, match="Expected 1 <= leaf_points"):
        CopcWriter(p, _header(), max_memory_points=10, leaf_points=20)
    with pytest.raises(PointFileError, match="Expected existing folders"):
        CopcWriter(tmp_path / "no" / "a.copc.laz", _header())
    w = CopcWriter(p, _header())
    with pytest.raises(PointFileError, match=r"Expected \(n,\) records of point format 6"):
        w.write_points(np.zeros(3, laspy.PointFormat(6).dtype()))
    w.close()
    with pytest.raises(PointFileError, match="Expected an open writer"):
        w.write_points(np.zeros(0, w.dtype))
    assert [f for f in os.listdir(tmp_path) if f.startswith(".")] == []


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 400),
       utm=st.booleans(), spread=st.sampled_from([0.0, 1e-4, 0.05, 3.0, 400.0]),
       dup=st.booleans(), leaf=st.integers(1, 30), pieces=st.integers(1, 4))
def test_any_cloud_round_trips_with_its_levels(tmp_path, seed, n, utm, spread, dup, leaf,
                                               pieces):
    """Random clouds (UTM-sized coordinates, coincident points, a single point, spans
    from zero to kilometres): every point comes back once, at the level the brute-force
    rule gives, inside its node; the memory bound does not change the bytes."""
    rng = np.random.default_rng(seed)
    origin = np.array([6.8e5, 5.9e6, 420.0]) if utm else np.zeros(3)
    xyz = origin + rng.normal(size=(n, 3)) * spread
    if dup:
        xyz[rng.integers(0, n, n // 2)] = xyz[0]
    head = _header(offset=np.round(origin / 1000) * 1000, extra=bool(seed % 2),
                   fmt=int(rng.choice([6, 7, 8])))
    rec = _records(head, xyz, rng)
    a = _write(tmp_path / "a.copc.laz", head, rec, pieces=pieces, leaf_points=leaf)
    b = _write(tmp_path / "b.copc.laz", head, rec, max_memory_points=leaf, leaf_points=leaf)
    assert a.read_bytes() == b.read_bytes()
    want = naive_levels(_ints(rec), leaf)
    with laspy.CopcReader.open(a) as r:
        assert _sorted_bytes(r.query().array) == _sorted_bytes(rec)
        for lev in np.unique(want):
            np.testing.assert_array_equal(_ids(r.level_query(int(lev))),
                                          np.flatnonzero(want == lev))
        k = int(rng.integers(n))
        box = laspy.Bounds(xyz[k] - 0.01, xyz[k] + 0.01)
        q = _ints(rec)
        imin = np.round((box.mins - head.offsets) / SCALE)
        imax = np.round((box.maxs - head.offsets) / SCALE)
        inside = ((q >= imin) & (q <= imax)).all(1)
        np.testing.assert_array_equal(_ids(r.query(bounds=box)), np.flatnonzero(inside))


def test_open_writer_picks_copc_for_copc_laz(tmp_path):
    writers = pytest.importorskip("sensors.writers")
    if "copc" not in writers.FORMATS:
        pytest.skip("sensors.writers does not offer COPC yet")
    from sensors.io.fields import POINT_DTYPE

    pts = np.zeros(50, dtype=POINT_DTYPE)
    pts["x"] = np.linspace(0, 10, 50) + 512000.0
    pts["y"], pts["z"], pts["time"] = 5.4e6, 300.0, np.arange(50.0)
    with writers.open_writer(tmp_path / "s.copc.laz", sensor="ouster_os1_64") as w:
        w.write_points(pts)
    with laspy.CopcReader.open(tmp_path / "s.copc.laz") as r:
        np.testing.assert_allclose(np.sort(np.asarray(r.query().x)), pts["x"], atol=1e-4)
