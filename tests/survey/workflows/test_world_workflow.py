"""``tunnelsim tunnel``, ``gazebo``, ``info`` and ``sensors`` against their library
functions (issue 32): the CLI in-process and ``survey.workflows.world`` on the same
inputs in two folders write the same files byte for byte (every file of the tunnel
and its second epoch; every file of the Gazebo world folder), and the CLI prints the
result's numbers. Neither output embeds a time stamp, so nothing is left out."""

from __future__ import annotations

import json
from importlib import metadata

import pytest

from survey.cli.main import main
from survey.errors import GazeboExportError, TunnelError
from survey.workflows.world import (gazebo_files, sensor_models, software_info,
                                    tunnel_files)


def _tree(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


def test_tunnel_cli_and_library_write_the_same_files(tmp_path, capsys):
    cli, lib = tmp_path / "cli", tmp_path / "lib"
    cli.mkdir()
    lib.mkdir()
    assert main(["tunnel", "-o", str(cli / "t.ply"), "--preset", "tbm", "--edge-length",
                 "0.6", "--relief", "rock", "--relief-scale", "2", "--origin",
                 "2600000,1200000,400", "--heading-deg", "30", "--seed", "3",
                 "--epoch2", str(cli / "t2.ply"), "--convergence", "10:20:30",
                 "--bulge", "15:30:1.5:40"]) == 0
    said = capsys.readouterr().out.splitlines()
    r = tunnel_files(lib / "t.ply", preset="tbm", edge_length_m=0.6, relief="rock",
                     relief_scale=2.0, origin=(2_600_000, 1_200_000, 400),
                     heading_deg=30.0, seed=3, epoch2=lib / "t2.ply",
                     convergence=[(10, 20, 30)], bulges=[(15, 30, 1.5, 40)])
    a, b = _tree(cli), _tree(lib)
    assert sorted(a) == ["t.json", "t.ply", "t2.json", "t2.ply"] and a == b
    meta = json.loads(b["t.json"])
    assert r.triangles == sum(meta["face_counts"].values()) and r.relief == "rock"
    assert r.face_counts == meta["face_counts"]
    assert said[0].startswith(f"tbm: {r.triangles:,} triangles (") and \
        f"{r.vertices:,} vertices, edge length 0.6 m, {r.control_points} control " \
        f"points, relief rock, {r.crs_name}, " in said[0]
    assert said[1:] == [f"wrote {p}" for p in (cli / "t.ply", cli / "t.json",
                                               cli / "t2.ply", cli / "t2.json")]
    # The second epoch moved: convergence and bulge change the vertices, not the faces.
    assert a["t2.ply"] != a["t.ply"]


def test_tunnel_refuses_alike(tmp_path, capsys):
    with pytest.raises(TunnelError, match=r"--relief-scale with rock relief.*tbm"):
        tunnel_files(tmp_path / "t.ply", preset="tbm", relief_scale=2.0)
    assert main(["tunnel", "-o", str(tmp_path / "u.ply"), "--preset", "tbm",
                 "--relief-scale", "2"]) == 2
    err = capsys.readouterr().err
    assert "--relief-scale with rock relief" in err and len(err.splitlines()) == 1
    with pytest.raises(TunnelError, match="ending in .ply"):
        tunnel_files(tmp_path / "t.obj")
    assert not list(tmp_path.iterdir())


def test_gazebo_cli_and_library_write_the_same_world(tmp_path, capsys):
    pytest.importorskip("trimesh")
    mesh = tmp_path / "t.ply"
    assert main(["tunnel", "-o", str(mesh), "--preset", "tbm", "--edge-length", "0.75",
                 "--quiet"]) == 0
    # The README names its folder ("cd world"): the same name under two parents.
    cli, lib = tmp_path / "cli" / "world", tmp_path / "lib" / "world"
    cli.parent.mkdir()
    lib.parent.mkdir()
    assert main(["gazebo", "--mesh", str(mesh), "--sensor", "velodyne_vlp16",
                 "--flavour", "fortress", "--chainage", "5", "-o", str(cli)]) == 0
    said = capsys.readouterr().out.splitlines()
    r = gazebo_files(mesh, lib, sensor="velodyne_vlp16", flavour="fortress",
                     chainage_m=5.0)
    a, b = _tree(cli), _tree(lib)
    assert "world.sdf" in a and a == b
    assert r.flavour == "fortress" and r.sensor == "velodyne_vlp16" and r.route is None
    assert said[0].startswith(f"wrote {cli}/world.sdf, bridge.yaml and "
                              f"models/tunnel ({r.triangles:,} triangles, collision "
                              f"{r.collision_triangles:,}")
    assert said[2] == "velodyne_vlp16 as gpu_lidar; SDF cannot express:"
    assert said[3:3 + len(r.limitations)] == [f"  - {x}" for x in r.limitations]
    with pytest.raises(GazeboExportError, match="positive --voxel in metres"):
        gazebo_files(mesh, tmp_path / "x", voxel_m=-1.0)
    assert not (tmp_path / "x").exists()


def test_info_and_sensors_print_the_library_result(capsys):
    info = software_info()
    assert info.version == metadata.version("tunnelsim")
    assert dict(info.packages)["numpy"] == metadata.version("numpy")
    assert main(["info"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"tunnelsim {info.version}"
    assert f"numba threads: {info.threads} of {info.max_threads}" in lines
    models = sensor_models()
    assert main(["sensors"]) == 0
    rows = capsys.readouterr().out.splitlines()
    assert [ln.split()[0] for ln in rows] == [m.name for m in models]
    from sensors import list_sensors

    assert [m.name for m in models] == list(list_sensors())
