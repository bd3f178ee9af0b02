"""Every file reader, fed damaged copies of valid files: it returns data or raises a
``TunnelsimError`` with a message; never another exception (issue 14, acceptance).

Valid files are written once (LAS, LAZ, PLY cloud and mesh, E57, a sensor TOML, a
control-point CSV, a tunnel's PLY + JSON, TUM and CSV trajectories); hypothesis then
cuts them short, flips bytes, re-counts them (a header's point count, a PLY element
count, a text file's lines duplicated or dropped) and hands the result to each reader
of that kind of file. Examples are few and files small: the module runs in seconds.
"""

from __future__ import annotations

import itertools
import re
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from raytrace.errors import TunnelsimError
from tests import iofiles as F

EXAMPLES = int(__import__("os").environ.get("FUZZ_EXAMPLES", "40"))


# ---------------------------------------------------------------------- valid files
def _las(d):
    F.las_file(d / "a.las", F.tunnel_points(40), point_format=7, extra=True, vlr=True,
               evlr=True)
    return d / "a.las"


def _laz(d):
    F.las_file(d / "a.laz", F.tunnel_points(40), version="1.2", point_format=3)
    return d / "a.laz"


def _ply_cloud(d):
    F.ply_cloud(d / "c.ply", F.tunnel_points(30), extra={"time": np.arange(30.0)})
    return d / "c.ply"


def _ply_mesh(d):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    F.ply_mesh(d / "m.ply", v, np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]))
    return d / "m.ply"


def _e57(d):
    F.e57_file(d / "s.e57", [F.tunnel_points(20, origin=(0, 0, 0))])
    return d / "s.e57"


def _toml(d):
    src = Path(__file__).resolve().parents[1] / "sensors" / "specs" / "velodyne_vlp16.toml"
    (d / "s.toml").write_bytes(src.read_bytes())
    return d / "s.toml"


def _control_csv(d):
    cp = F.tunnel_points(5, seed=2)
    (d / "cp.csv").write_text("id,x,y,z,sigma,time\n" + "".join(
        f"P{i},{x:.4f},{y:.4f},{z:.4f},0.002,{10.0 * i}\n" for i, (x, y, z) in enumerate(cp)))
    return d / "cp.csv"


def _tunnel(d):
    from survey.world.alignment import Alignment, straight
    from survey.world.generator import make_tunnel
    from survey.world.profiles import circle

    make_tunnel(Alignment([straight(4.0)]), circle(2.0), edge_length_m=0.6).write(
        d / "t.ply")
    return d / "t.ply"


def _tum(d):
    (d / "tr.txt").write_text("".join(f"{t:.2f} {t:.3f} 0 1.5 0 0 0 1\n"
                                      for t in np.arange(0.0, 2.0, 0.25)))
    return d / "tr.txt"


def _traj_csv(d):
    (d / "tr.csv").write_text("t,x,y,z,qx,qy,qz,qw\n" + "".join(
        f"{t:.2f},{t:.3f},0,1.5,0,0,0,1\n" for t in np.arange(0.0, 2.0, 0.25)))
    return d / "tr.csv"


# ---------------------------------------------------------------------- readers
def _iter_points(p):
    from sensors.io.cloudread import iter_points
    return sum(len(c) for c in iter_points(p, chunk=7))


def _cloud_bounds(p):
    from sensors.io.cloudread import cloud_bounds
    return cloud_bounds(p, chunk=7)


def _map_cloud(p):
    from sensors.io.cloudmap import map_cloud
    return map_cloud(p, p.with_name("out" + p.suffix), lambda xyz, t: xyz + 1.0, chunk=7)


def _annotate_las(p):
    from sensors.io.cloudmap import annotate_las
    return annotate_las(p, p.with_name("out.laz"),
                        lambda xyz: {"d": np.zeros(len(xyz), np.float32)}, chunk=7)


def _las_source(p):
    from sensors.io.las import LasSource
    with LasSource(p) as src:
        return sum(len(r) for r in src.chunks(7)), src.evlrs()


def _sensors_ply(p):
    from sensors.io.ply import read_ply
    return read_ply(p)


def _mesh_ply(p):
    from sensors.io.meshes import read_mesh
    return read_mesh(p)


def _reference(p):
    from sensors.io.cloudread import read_reference
    return read_reference(p)


def _read_e57(p):
    from sensors.io.e57 import read_e57
    return list(read_e57(p))


def _load_sensor(p):
    from sensors.spec import load_sensor
    return load_sensor(p)


def _control_points(p):
    from survey.adjust.controlpoints import read_control_points
    return read_control_points(p)


def _read_tunnel(p):
    from survey.world.mesh import read_tunnel
    return read_tunnel(p.with_suffix(".ply"))


def _read_axis(p):
    from survey.world.mesh import read_axis
    return read_axis(p.with_suffix(".json"))


def _trajectory(p):
    from sensors import Trajectory
    return Trajectory.read(p)


# ---------------------------------------------------------------------- re-counting
def _recount_las(data: bytes, n: int) -> bytes:
    b = bytearray(data)
    if len(b) >= 111:
        b[107:111] = struct.pack("<I", n % 2**32)
    if len(b) >= 255:
        b[247:255] = struct.pack("<Q", n)
    return bytes(b)


def _recount_ply(data: bytes, n: int) -> bytes:
    return re.sub(rb"element (\w+) \d+", lambda m: b"element " + m.group(1) + b" " +
                  str(n).encode(), data, count=1)


def _recount_lines(data: bytes, n: int) -> bytes:
    """Drop (n even) or duplicate (n odd) line n // 2 of a text file."""
    lines = data.split(b"\n")
    i = (n // 2) % max(len(lines), 1)
    lines[i:i + 1] = [] if n % 2 == 0 else [lines[i], lines[i]]
    return b"\n".join(lines)


#: kind: (make the valid file, readers, re-count, the file the damage goes to).
KINDS = {
    "las": (_las, [_iter_points, _cloud_bounds, _map_cloud, _annotate_las, _las_source],
            _recount_las, None),
    "laz": (_laz, [_iter_points, _map_cloud, _annotate_las, _las_source], _recount_las,
            None),
    "ply-cloud": (_ply_cloud, [_iter_points, _map_cloud, _sensors_ply, _reference],
                  _recount_ply, None),
    "ply-mesh": (_ply_mesh, [_mesh_ply, _reference, _sensors_ply, _iter_points],
                 _recount_ply, None),
    "e57": (_e57, [_iter_points, _read_e57], None, None),
    "toml": (_toml, [_load_sensor], _recount_lines, None),
    "control-csv": (_control_csv, [_control_points], _recount_lines, None),
    "tunnel-ply": (_tunnel, [_read_tunnel], _recount_ply, ".ply"),
    "tunnel-json": (_tunnel, [_read_tunnel, _read_axis], _recount_lines, ".json"),
    "trajectory-tum": (_tum, [_trajectory], _recount_lines, None),
    "trajectory-csv": (_traj_csv, [_trajectory], _recount_lines, None),
}


class _Files(dict):
    """The valid files, with a short repr (hypothesis prints its arguments)."""

    def __repr__(self) -> str:
        return f"<{len(self)} kinds of valid files>"


@pytest.fixture(scope="module")
def valid(tmp_path_factory):
    """{kind: (the file that gets damaged, its bytes, {other file: bytes})}"""
    out = _Files()
    for kind, (make, _, _, damaged) in KINDS.items():
        d = tmp_path_factory.mktemp(kind)
        main = make(d)
        target = main.with_suffix(damaged) if damaged else main
        others = {p.name: p.read_bytes() for p in d.iterdir() if p != target}
        out[kind] = (target.name, target.read_bytes(), others)
    return out


def _damage(data: bytes, ops, recount) -> bytes:
    for op, at, value in ops:
        if not data:
            break
        i = at % len(data)
        if op == "truncate":
            data = data[:i]
        elif op == "flip":
            data = data[:i] + bytes([data[i] ^ value]) + data[i + 1:]
        elif recount is not None:
            data = recount(data, value * 1_000_003 % 2**34 if value > 200 else value)
    return data


OPS = st.lists(st.tuples(st.sampled_from(["truncate", "flip", "recount"]),
                         st.integers(0, 2**20), st.integers(1, 255)), min_size=1,
               max_size=3)
_RUN = itertools.count()


@pytest.mark.parametrize("kind", list(KINDS))
@settings(max_examples=EXAMPLES, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(ops=OPS)
def test_damaged_files_give_data_or_a_tunnelsim_error(valid, tmp_path, kind, ops):
    name, data, others = valid[kind]
    _, readers, recount, _ = KINDS[kind]
    d = tmp_path / f"run{next(_RUN)}"
    d.mkdir()
    for other, content in others.items():
        (d / other).write_bytes(content)
    bad = _damage(data, ops, recount)
    (d / name).write_bytes(bad)
    for reader in readers:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                reader(d / name)
        except TunnelsimError as exc:
            assert str(exc).strip(), f"{reader.__name__}: empty message"
        except Exception as exc:   # the failure this test exists to find
            raise AssertionError(f"{reader.__name__} on {kind} damaged by {ops} raised "
                                 f"{type(exc).__name__}: {exc}") from exc


@pytest.mark.parametrize("kind", list(KINDS))
def test_the_valid_files_read(valid, tmp_path, kind):
    """The undamaged files are read without error (the fuzzing starts from data)."""
    name, data, others = valid[kind]
    for other, content in others.items():
        (tmp_path / other).write_bytes(content)
    (tmp_path / name).write_bytes(data)
    for reader in KINDS[kind][1]:
        if reader is _iter_points and kind == "ply-mesh":
            continue           # a mesh's vertices read as a cloud: checked by the fuzz
        assert reader(tmp_path / name) is not None


def test_a_non_ascii_byte_in_a_ply_comment_is_rewritten_not_a_crash(tmp_path):
    """Found by the property above in a clean-clone CI run: a flipped byte in a PLY
    header comment decoded to U+FFFD, and the rewrite crashed encoding it back (PLY
    headers are ASCII). The rewrite keeps the data and the comment, the byte as '?'."""
    from sensors.io.cloudmap import map_cloud
    from sensors.io.cloudread import read_points

    p = _ply_cloud(tmp_path)
    raw = bytearray(p.read_bytes())
    i = raw.index(b"comment") + len(b"comment ")
    raw[i] = 0xFF
    p.write_bytes(bytes(raw))
    n = map_cloud(p, tmp_path / "out.ply", lambda xyz, t: xyz + 1.0)
    np.testing.assert_allclose(read_points(tmp_path / "out.ply"), read_points(p) + 1.0)
    assert n == len(read_points(p))
    assert b"?" in (tmp_path / "out.ply").read_bytes()[:200]
