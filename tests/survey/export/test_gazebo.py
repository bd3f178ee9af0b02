"""Gazebo export: the world validates with the real SDFormat library (libsdformat-dev,
compiled checker), the lidar reads back as the spec, bad input is refused."""

from __future__ import annotations

import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from sensors import load_sensor
from survey.world.alignment import Alignment, straight
from survey.cli.main import main
from survey.errors import GazeboExportError
from survey.export.gazebo import decimate, export_gazebo, unit_warnings
from survey.export.gazebo_sdf import lidar_sdf
from survey.world.profiles import horseshoe
from survey.world.generator import make_tunnel

@pytest.fixture(scope="module")
def tunnel_ply(tmp_path_factory):
    t = make_tunnel(Alignment([straight(20.0)]), horseshoe(5.0), edge_length_m=0.3,
                    roughness_rms_m=0.0)
    path = tmp_path_factory.mktemp("gz") / "t.ply"
    t.write(path)
    return path


def _check(exe, world_dir):
    r = subprocess.run([str(exe), str(world_dir / "world.sdf"), str(world_dir / "models")],
                       capture_output=True, text=True)
    return r.returncode, r.stdout + r.stderr


def _lidar_line(out):
    line = [x for x in out.splitlines() if x.startswith("lidar ")][0]
    return dict(kv.split("=", 1) for kv in line.split()[1:])


@pytest.mark.parametrize("name", ["robosense_airy", "velodyne_vlp16", "zf_profiler_9012"])
def test_world_validates_with_sdformat(sdf_check, tunnel_ply, tmp_path, name):
    spec = load_sensor(name)
    info = export_gazebo(tunnel_ply, spec, tmp_path / "w")
    rc, out = _check(sdf_check, tmp_path / "w")
    assert rc == 0, out
    assert "error" not in out
    assert "mesh visual model://tunnel/meshes/tunnel.obj -> ok" in out
    assert "mesh collision model://tunnel/meshes/tunnel_collision.stl -> ok" in out
    li = _lidar_line(out)
    ph = spec.physics
    assert float(li["range_min"]) == pytest.approx(ph.range_min_m)
    assert float(li["range_max"]) == pytest.approx(ph.range_max_m)
    assert float(li["noise_stddev"]) == pytest.approx(np.hypot(ph.range_sigma_floor_m,
                                                               ph.range_sigma_m), rel=1e-5)
    if spec.kind == "spinning":
        p = spec.pattern
        assert int(li["h_samples"]) == round(1 / (p.rotation_hz * p.column_period_s))
        assert int(li["v_samples"]) == spec.channels
        assert float(li["v_min"]) == pytest.approx(p.elevations_rad.min(), abs=1e-8)
        assert float(li["v_max"]) == pytest.approx(p.elevations_rad.max(), abs=1e-8)
        assert float(li["update_rate"]) == pytest.approx(p.rotation_hz)
    else:
        p = spec.pattern
        arc = 2 * np.pi - (p.blind_sector_rad[1] - p.blind_sector_rad[0])
        assert float(li["h_max"]) - float(li["h_min"]) == pytest.approx(arc, abs=1e-8)
        assert int(li["v_samples"]) == 1
        assert float(li["update_rate"]) == pytest.approx(p.profile_rate_hz)
    assert info["limitations"]


def test_checker_catches_broken_worlds(sdf_check, tunnel_ply, tmp_path):
    # The checker is not a rubber stamp: a missing mesh and an unknown element fail.
    export_gazebo(tunnel_ply, load_sensor("velodyne_vlp16"), tmp_path / "w")
    (tmp_path / "w" / "models" / "tunnel" / "meshes" / "tunnel_collision.stl").unlink()
    rc, out = _check(sdf_check, tmp_path / "w")
    assert rc == 1 and "MISSING" in out
    export_gazebo(tunnel_ply, load_sensor("velodyne_vlp16"), tmp_path / "w2")
    w = tmp_path / "w2" / "world.sdf"
    w.write_text(w.read_text().replace("<gravity>", "<gravitee>1</gravitee><gravity>"))
    rc, out = _check(sdf_check, tmp_path / "w2")
    assert rc == 1 and "gravitee" in out


@pytest.mark.parametrize("name", ["robosense_airy", "velodyne_vlp16", "ouster_os1_64",
                                  "zf_profiler_9012"])
def test_lidar_round_trip_xml(name):
    spec = load_sensor(name)
    xml, limits = lidar_sdf(spec)
    s = ET.fromstring(xml.strip())
    assert s.get("type") == "gpu_lidar"
    g = lambda path: float(s.find(path).text)      # noqa: E731
    assert g("lidar/range/min") == spec.physics.range_min_m
    assert g("lidar/range/max") == spec.physics.range_max_m
    if spec.kind == "spinning":
        p = spec.pattern
        assert g("update_rate") == p.rotation_hz
        assert g("lidar/scan/vertical/samples") == spec.channels
        assert g("lidar/scan/vertical/min_angle") == pytest.approx(p.elevations_rad.min())
        assert g("lidar/scan/vertical/max_angle") == pytest.approx(p.elevations_rad.max())
        n = g("lidar/scan/horizontal/samples")
        assert n == round(1 / (p.rotation_hz * p.column_period_s))
        # One full turn: max - min = 2 pi (1 - 1/n).
        span = g("lidar/scan/horizontal/max_angle") - g("lidar/scan/horizontal/min_angle")
        assert span == pytest.approx(2 * np.pi * (1 - 1 / n), abs=1e-8)
    else:
        assert g("update_rate") == spec.pattern.profile_rate_hz
    assert any("rolling shutter" in x for x in limits)


def test_tls_has_no_gazebo_sensor():
    with pytest.raises(GazeboExportError, match="spinning lidar or a profiler"):
        lidar_sdf(load_sensor("zf_imager_5016"))


def test_unit_and_axis_warnings():
    v = np.array([[0, 0, 0], [30_000, 500, 600.0]])          # a 300 m tunnel in cm
    w = unit_warnings(v)
    assert len(w) == 1 and "in centimetres it would be 300 m long" in w[0]
    assert "in millimetres it would be 300 m long" in unit_warnings(v * 10)[0]
    assert unit_warnings(np.array([[0, 0, 0], [300, 6, 6.0]])) == []
    assert "Y-up" in unit_warnings(np.array([[0, 0, 0], [6, 6, 300.0]]))[0]


def test_existing_folder_refused_and_force_replaces(tunnel_ply, tmp_path, capsys):
    out = tmp_path / "w"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    with pytest.raises(GazeboExportError, match="--force"):
        export_gazebo(tunnel_ply, load_sensor("velodyne_vlp16"), out)
    assert main(["gazebo", "--mesh", str(tunnel_ply), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--force" in err[0]
    assert main(["gazebo", "--mesh", str(tunnel_ply), "-o", str(out), "--force",
                 "--quiet"]) == 0
    assert (out / "world.sdf").is_file() and not (out / "keep.txt").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["w"]     # no temporary left over


def test_cm_mesh_warns_on_cli(tmp_path, capsys):
    t = make_tunnel(Alignment([straight(40.0)]), horseshoe(5.0), edge_length_m=0.3,
                    roughness_rms_m=0.0)
    from survey.world.mesh import write_ply

    write_ply(tmp_path / "cm.ply", t.vertices * 100.0, t.faces)     # no JSON: axis fit
    rc = main(["gazebo", "--mesh", str(tmp_path / "cm.ply"), "-o", str(tmp_path / "w"),
               "--sensor", "velodyne_vlp16", "--quiet"])
    err = capsys.readouterr().err
    assert "warning: mesh extents 4,000 m" not in err      # 40 m * 100 = 4 km: plausible
    write_ply(tmp_path / "cm2.ply", t.vertices * 1000.0, t.faces)
    rc = main(["gazebo", "--mesh", str(tmp_path / "cm2.ply"), "-o", str(tmp_path / "w2"),
               "--sensor", "velodyne_vlp16", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert "in millimetres it would be 40 m long" in err[0]
    assert rc in (0, 2) and (rc == 0 or err[-1].startswith("tunnelsim: error:"))


def test_crash_leaves_no_partial_world(tunnel_ply, tmp_path, monkeypatch):
    import survey.export.gazebo as gz

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(gz, "write_obj", boom)
    with pytest.raises(RuntimeError):
        export_gazebo(tunnel_ply, load_sensor("velodyne_vlp16"), tmp_path / "w")
    assert list(tmp_path.iterdir()) == []


def test_obj_round_trip(tmp_path):
    import trimesh

    from survey.export.gazebo import write_obj

    t = make_tunnel(Alignment([straight(5.0)]), horseshoe(5.0), edge_length_m=0.3,
                    roughness_rms_m=0.0)
    write_obj(tmp_path / "m.obj", t.vertices, t.faces)
    m = trimesh.load(tmp_path / "m.obj", process=False, maintain_order=True)
    np.testing.assert_allclose(m.vertices, t.vertices, atol=5e-5)
    np.testing.assert_array_equal(m.faces, t.faces)


def test_decimate_bounds_the_error():
    from survey.analysis.compare import cloud_to_mesh

    t = make_tunnel(Alignment([straight(10.0)]), horseshoe(5.0), edge_length_m=0.1,
                    roughness_rms_m=0.0)
    v2, f2 = decimate(t.vertices, t.faces, 0.3)
    assert len(f2) < len(t.faces) / 5
    # Each merged vertex is the mean of vertices within one 0.3 m cell: it lies within
    # the cell diagonal of the original surface.
    d = cloud_to_mesh(v2[np.unique(f2)], t.vertices, t.faces).distance
    assert np.abs(d).max() < 0.3 * np.sqrt(3)
    assert f2.max() < len(v2) and (f2[:, 0] != f2[:, 1]).all()
