"""The ``tunnelsim`` command: version, info, one-line errors with exit status 2."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import pytest

from survey.cli import main


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("tunnelsim ") and out.strip().split()[1][0].isdigit()


def test_info_reports_threading(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    assert f"numba {numba.__version__}" in out
    layer = [line for line in out.splitlines() if line.startswith("numba threading layer")]
    assert layer and layer[0].split(": ")[1] in {"tbb", "omp", "workqueue"}
    assert f"numba threads: {numba.get_num_threads()} of" in out


def test_bad_command_is_one_line_exit_2(capsys):
    assert main(["frobnicate"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "invalid choice" in err


def test_console_script_installed():
    beside = Path(sys.executable).with_name("tunnelsim")
    exe = str(beside) if beside.exists() else shutil.which("tunnelsim")
    if exe is None:
        pytest.skip("tunnelsim console script not on PATH (package not installed)")
    res = subprocess.run([exe, "nope"], capture_output=True, text=True)
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr


def test_import_compiles_nothing():
    """The first import must not compile (or load) kernels: Numba compiles lazily."""
    code = ("import raytrace, survey.cli\n"
            "from raytrace._kernels import build, cubemap, traverse\n"
            "fs = [build.build_top, build._grow_pending, build.triangle_setup, "
            "traverse.closest_hit, traverse.any_hit, cubemap.closest_hit_view]\n"
            "print(sum(len(f.signatures) for f in fs))\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert res.stdout.strip() == "0"


def test_tunnel_writes_mesh_metadata_and_epoch(tmp_path, capsys):
    out = tmp_path / "tbm.ply"
    ep = tmp_path / "tbm2.ply"
    assert main(["tunnel", "-o", str(out), "--preset", "tbm", "--edge-length", "0.5",
                 "--epoch2", str(ep), "--convergence", "40:60:5", "--origin",
                 "451000,5352000,600"]) == 0
    text = capsys.readouterr().out
    assert "wrote" in text and str(out) in text
    import json

    from survey.tunnel_io import read_ply, read_tunnel
    a, b = read_tunnel(out), read_tunnel(ep)
    assert json.loads(out.with_suffix(".json").read_text())["face_counts"]["cable"] > 0
    mid = np.isclose(a.vertex_chainage, 50.0)  # lining and attached features alike
    d = np.linalg.norm(b.vertices - a.vertices, axis=1)
    assert np.all(np.abs(d[mid & np.isfinite(a.vertex_param)] - 0.005) < 1e-9)
    assert np.all(d[np.isclose(a.vertex_chainage, 20.0)] == 0)
    assert a.vertices[:, 0].min() > 450_000
    np.testing.assert_allclose(read_ply(ep)["dx"], b.vertices[:, 0] - a.vertices[:, 0],
                               atol=1e-7)


@pytest.mark.parametrize("argv, match", [
    (["tunnel", "-o", "x.txt"], "ending in .ply"),
    (["tunnel", "-o", "no/such/dir/x.ply"], "existing output folder"),
    (["tunnel", "-o", "x.ply", "--convergence", "1:2"], "START:END:MM"),
    (["tunnel", "-o", "x.ply", "--edge-length", "0.0001"], "at most"),
    (["tunnel", "-o", "x.ply", "--preset", "moon"], "invalid choice"),
    (["tunnel"], "required"),
])
def test_tunnel_bad_input_is_one_line(argv, match, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and match in err
    assert not list(tmp_path.iterdir())


@pytest.fixture(scope="module")
def tbm(tmp_path_factory):
    out = tmp_path_factory.mktemp("tbm") / "tbm.ply"
    assert main(["tunnel", "-o", str(out), "--preset", "tbm", "--edge-length", "0.3",
                 "--quiet"]) == 0
    return out


def test_sensors_lists_every_model(capsys):
    from sensors import list_sensors
    assert main(["sensors"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in list_sensors())


def test_scan_writes_a_station_with_the_mesh_reflectivity(tbm, tmp_path, capsys):
    import laspy

    from survey.tunnel_io import read_tunnel
    out = tmp_path / "st.laz"
    assert main(["scan", "--mesh", str(tbm), "--at", "50,0,1.5", "--resolution", "preview",
                 "--ideal", "--fields", "full", "-o", str(out)]) == 0
    assert "points" in capsys.readouterr().out
    las = laspy.read(out)
    tun = read_tunnel(tbm)
    tri = np.asarray(las["triangle"])
    assert len(las.points) > 500_000 and tri.min() >= 0
    # intensity follows the label reflectivity: dark cable faces return weaker than
    # lining faces at similar range and incidence
    refl = tun.reflectivity[tri]
    rng = np.asarray(las["range"])
    inc = np.asarray(las["incidence"])
    band = (rng > 2.0) & (rng < 3.0) & (inc < 0.3)
    cable = band & (refl < 0.1)
    lining = band & (np.abs(refl - 0.4) < 1e-6)
    assert cable.sum() > 20 and lining.sum() > 20
    assert np.median(las.intensity[cable]) < np.median(las.intensity[lining])


def test_drive_along_the_centreline(tbm, tmp_path, capsys):
    import laspy
    out = tmp_path / "dr.laz"
    assert main(["drive", "--mesh", str(tbm), "--sensor", "velodyne_vlp16", "--along",
                 "centreline", "--speed", "2", "--duration", "0.3", "-o", str(out)]) == 0
    las = laspy.read(out)
    t = np.asarray(las.gps_time)
    assert len(t) > 10_000 and t.max() <= 0.3 + 1e-9
    assert set(np.unique(las.point_source_id)) <= {0, 1, 2, 3}       # frames at 10 Hz


@pytest.mark.parametrize("argv, match", [
    (["scan", "--mesh", "nope.ply", "--at", "1,2,3", "-o", "x.laz"], "does not exist"),
    (["scan", "--mesh", "TBM", "--at", "1,2", "-o", "x.laz"], "X,Y,Z"),
    (["scan", "--mesh", "TBM", "--at", "50,0,1.5", "--sensor", "nope", "-o", "x.laz"],
     "zf_imager_5016"),
    (["scan", "--mesh", "TBM", "--at", "50,0,1.5", "--resolution", "max", "-o", "x.laz"],
     "resolution"),
    (["scan", "--mesh", "TBM", "--at", "50,0,1.5", "--resolution", "preview", "-o", "x.txt"],
     "format"),
    (["drive", "--mesh", "TBM", "-o", "x.laz"], "--trajectory"),
    (["drive", "--mesh", "TBM", "--trajectory", "none.txt", "-o", "x.laz"], "does not exist"),
])
def test_scan_and_drive_bad_input(argv, match, tbm, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = [str(tbm) if a == "TBM" else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and match in err
    assert not list(tmp_path.iterdir())
