"""``survey.workflows.clouds`` (issue 32): ``mesh_files`` and ``preprocess_file`` write
the files ``tunnelsim mesh`` / ``tunnelsim preprocess`` write, notebook-style: the
command (in-process, as a user runs it) in one folder, the library function with the
same options in another, and the files compared byte for byte. The result objects are
checked against the files (read back with trimesh and laspy) and the printed summary,
and the meshes against the analytic surfaces they were sampled from.

The solid route (the auto fallback) is the exception: Open3D's multithreaded Poisson
orders and rounds its float32 vertices differently from run to run (measured: 223 of
20 786 vertices moved by up to 7.6 um between two runs of the same call in one
process), so there the files are compared as meshes, within 0.1 mm, and the JSON field
by field (its mean distance to 1e-6 relative).
"""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from survey.cli.main import main
from survey.errors import ReconstructionError
from survey.workflows.clouds import MeshResult, mesh_files, preprocess_file
from survey.world.alignment import Alignment, straight

pytest.importorskip("open3d", reason="decimation and the solid route need Open3D")

#: Profile centre above the alignment (m) of the tubes made here.
HC = 1.5
LENGTH_M = 40.0


def _radius(a):
    """The lobed tube's radius (m) at angle a about its axis."""
    return 3.0 + 0.2 * np.cos(2 * a)


def _tube(n, seed=0, noise_m=0.002):
    """(alignment, points (n, 3)): a lobed tube about a straight alignment at UTM-sized
    coordinates, uniform in chainage and angle."""
    rng = np.random.default_rng(seed)
    al = Alignment([straight(LENGTH_M)], start_xy=(2_600_000.0, 1_200_000.0),
                   heading_rad=0.4, profile=((0.0, 450.0),))
    s = rng.uniform(0.0, LENGTH_M, n)
    a = rng.uniform(-np.pi, np.pi, n)
    r = _radius(a) + rng.normal(0.0, noise_m, n)
    return al, al.to_world(s, r * np.sin(a), HC + r * np.cos(a))


def _run(argv):
    """(exit status, stdout) of ``tunnelsim`` in-process."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue()


def _radial_error(al, vertices):
    """Distance (m) of mesh vertices from the analytic lobed tube, along its radius."""
    _, o, h = al.to_local(vertices)
    a = np.arctan2(o, h - HC)
    return np.hypot(o, h - HC) - _radius(a)


#: Points of the tube cloud: about 8 a cell of 0.5 m x 6 deg.
N_TUBE = 40_000


@pytest.fixture(scope="module")
def tube(tmp_path_factory):
    """(true alignment, the tube's LAZ, its axis as a chainage,E,N,H CSV: the true
    alignment raised to the profile centre)."""
    from sensors.io.cloudmap import write_points_las

    d = tmp_path_factory.mktemp("tube")
    al, pts = _tube(N_TUBE)
    write_points_las(d / "c.laz", pts)
    s = np.arange(0.0, LENGTH_M + 0.5, 1.0)
    p = al.point(s)
    np.savetxt(d / "axis.csv", np.column_stack([s, p[:, 0], p[:, 1], p[:, 2] + HC]),
               delimiter=",", fmt="%.6f", header="chainage,E,N,H", comments="")
    return al, d / "c.laz", d / "axis.csv"


def test_tunnel_mesh_with_decimation_is_the_commands(tube, tmp_path):
    """--method tunnel, a cell, a triangle budget, JSON and the support figure: the same
    bytes from the command and the library; the result's numbers are the files'."""
    import trimesh

    from tests.iofiles import mesh_fields

    al, cloud, axis = tube
    (tmp_path / "cli").mkdir()
    (tmp_path / "lib").mkdir()
    rc, printed = _run(["mesh", cloud, "-o", tmp_path / "cli/m.ply", "--method", "tunnel",
                        "--tunnel-json", axis, "--cell", "0.5,6", "--max-triangles",
                        "3000", "--json", tmp_path / "cli/m.json", "--figure",
                        tmp_path / "cli/m.png"])
    assert rc == 0
    r = mesh_files(cloud, tmp_path / "lib/m.ply", method="tunnel", tunnel_json=axis,
                   cell_m=0.5, cell_deg=6.0, max_triangles=3000,
                   json_path=tmp_path / "lib/m.json", figure=tmp_path / "lib/m.png")
    for name in ("m.ply", "m.json", "m.png"):
        assert (tmp_path / "cli" / name).read_bytes() == (tmp_path / "lib" / name).read_bytes()
    assert isinstance(r, MeshResult) and r.method == "tunnel" and r.method_asked == "tunnel"
    assert r.json_path == tmp_path / "lib/m.json" and r.figure == tmp_path / "lib/m.png"
    # The result against the files: trimesh counts the faces, the JSON holds the rest.
    m = trimesh.load(tmp_path / "lib/m.ply", process=False)
    q = json.loads((tmp_path / "lib/m.json").read_text())
    assert r.triangles == len(m.faces) == q["triangles"] <= 3000
    assert r.triangles_undecimated == q["triangles_undecimated"] > r.triangles
    assert r.decimation["triangles_before"] == r.triangles_undecimated
    assert r.input_points == q["points"] == N_TUBE
    assert r.voxels is not None and r.voxels <= N_TUBE and r.voxel_m == 0.02
    assert dict(r.report) == q
    # The printed summary states the result's numbers.
    assert f"{r.input_points:,} points ({r.voxels:,} voxels of 0.02 m) -> " \
           f"{r.triangles_undecimated:,} triangles" in printed
    assert f"decimated {r.triangles_undecimated:,} -> {r.triangles:,} triangles" in printed
    # The decimated mesh still lies on the analytic tube (2 mm noise, medians of ~8
    # points a cell; decimation adds its own error).
    err = _radial_error(al, mesh_fields(tmp_path / "lib/m.ply")["vertices"])
    assert np.median(np.abs(err)) < 0.005
    assert np.percentile(np.abs(err), 95) < 3 * r.decimation["error"][
        "original_to_decimated"]["p95_m"] + 0.005


def test_profile_cloud_cell_is_chosen_as_the_command_chooses_it(tmp_path):
    """A profile cloud (profiles every 0.5 m) without --cell: one cell per profile, said
    in the result as the command prints it, in the same files."""
    from sensors.io.cloudmap import write_points_las

    rng = np.random.default_rng(4)
    al, _ = _tube(1)
    s = np.repeat(np.arange(0.25, LENGTH_M, 0.5), 360)
    a = np.tile(np.linspace(-np.pi, np.pi, 360, endpoint=False), len(s) // 360)
    r = _radius(a) + rng.normal(0.0, 0.001, len(s))
    write_points_las(tmp_path / "p.laz", al.to_world(s, r * np.sin(a), HC + r * np.cos(a)))
    (tmp_path / "cli").mkdir()
    (tmp_path / "lib").mkdir()
    rc, printed = _run(["mesh", tmp_path / "p.laz", "-o", tmp_path / "cli/m.ply",
                        "--method", "tunnel", "--voxel", "0", "--json",
                        tmp_path / "cli/m.json"])
    assert rc == 0
    res = mesh_files(tmp_path / "p.laz", tmp_path / "lib/m.ply", method="tunnel",
                     voxel_m=0.0, json_path=tmp_path / "lib/m.json")
    for name in ("m.ply", "m.json"):
        assert (tmp_path / "cli" / name).read_bytes() == (tmp_path / "lib" / name).read_bytes()
    # The profiles' spacing as built (0.5 m), to the 1 mm the chosen cell is rounded to.
    assert res.profile_spacing_m == pytest.approx(0.5, abs=0.001)
    assert res.cell_m == round(res.profile_spacing_m, 3) and res.cell_deg == 2.0
    assert res.voxels is None
    assert printed.splitlines()[0] == (
        f"cell: {res.cell_m:g} m along the axis ({res.cell_how}) x 2 deg; --cell M,DEG "
        "sets it")
    q = json.loads((tmp_path / "lib/m.json").read_text())
    assert q["cell_chosen"] == {"cell_m": res.cell_m, "cell_deg": 2.0, "how": res.cell_how}
    # No --voxel grid: every point counted once.
    assert res.input_points == q["points"] == len(s)


@pytest.fixture(scope="module")
def mine_stations(tmp_path_factory):
    """Five stations of the branching mine of ``test_mesh_auto`` (2 deg steps), one LAZ
    each with its pose, as ``tunnelsim scan`` writes them."""
    from raytrace import Scene
    from sensors import simulate_station
    from tests.survey.clouds.test_mesh_auto import MINE_STATIONS, mine_mesh

    v, f = mine_mesh()
    d = tmp_path_factory.mktemp("mine")
    return [str(simulate_station(Scene(v, f), "zf_imager_5016", s,
                                 step_rad=np.deg2rad(2.0), seed=k)
                .write(d / f"st{k}.laz")["path"])
            for k, s in enumerate(MINE_STATIONS[[0, 2, 4, 5, 6]])]


def test_auto_fallback_to_solid_is_the_commands(mine_stations, tmp_path):
    """--method auto on a branching mine: the tunnel fit is judged poor and the solid
    route runs, in the command and in the library alike (the same judgement, the same
    mesh within the Poisson's run-to-run noise, module doc)."""
    from scipy.spatial import cKDTree

    from tests.iofiles import mesh_fields

    (tmp_path / "cli").mkdir()
    (tmp_path / "lib").mkdir()
    rc, printed = _run(["mesh", *mine_stations, "-o", tmp_path / "cli/m.ply", "--voxel",
                        "0.15", "--json", tmp_path / "cli/m.json"])
    assert rc == 0
    r = mesh_files(mine_stations, tmp_path / "lib/m.ply", voxel_m=0.15,
                   json_path=tmp_path / "lib/m.json")
    assert r.method == "solid" and r.method_asked == "auto"
    assert r.method_reason.startswith("tunnel fit rejected")
    assert r.method_reason.endswith("fell back to solid")
    assert f"method solid: {r.method_reason}" in printed.splitlines()
    a, b = (json.loads((tmp_path / d / "m.json").read_text()) for d in ("cli", "lib"))
    assert dict(r.report) == b
    assert a["auto"] == b["auto"] and a["auto"]["tunnel_fit_good"] is False
    for key in ("method", "method_asked", "method_reason", "input_points", "depth",
                "cell_m", "trim_m", "cell_chosen"):
        assert a[key] == b[key], key
    assert a["mean_m"] == pytest.approx(b["mean_m"], rel=1e-6)
    assert a["triangles"] == pytest.approx(b["triangles"], rel=0.01)
    # The tunnel mesher ran first: its cell is the result's, the solid cell the JSON's.
    assert r.cell_m == b["cell_chosen"]["cell_m"] and b["cell_m"] == 0.15
    va, vb = (mesh_fields(tmp_path / d / "m.ply")["vertices"] for d in ("cli", "lib"))
    for x, y in ((va, vb), (vb, va)):
        assert cKDTree(x).query(y)[0].max() < 1e-4


@pytest.mark.parametrize("argv, kwargs", [
    (["--max-triangles", "3"], dict(max_triangles=3)),
    (["--max-error", "-1"], dict(max_error_m=-1.0)),
    (["--voxel", "-1"], dict(voxel_m=-1.0)),
    (["--method", "solid", "--detail"], dict(method="solid", detail=True)),
    (["--method", "tunnel", "--trim", "0.5"], dict(method="tunnel", trim_m=0.5)),
])
def test_errors_are_the_commands(tube, tmp_path, capsys, argv, kwargs):
    """The library refuses what the command refuses, with the command's message (the
    one line after 'tunnelsim: error: '), and writes nothing."""
    _, cloud, _ = tube
    assert main(["mesh", str(cloud), "-o", str(tmp_path / "c.ply"), *argv]) == 2
    err = capsys.readouterr().err.strip()
    with pytest.raises(ReconstructionError) as exc:
        mesh_files(cloud, tmp_path / "l.ply", **kwargs)
    assert err == f"tunnelsim: error: {' '.join(str(exc.value).split())}"
    assert not (tmp_path / "c.ply").exists() and not (tmp_path / "l.ply").exists()


@settings(max_examples=25, deadline=None)
@given(n=st.integers(-10**6, 3), error=st.floats(max_value=0.0) | st.just(float("nan")))
def test_bad_compaction_is_refused_before_any_reading(n, error):
    """Invariant: a budget below 4 triangles or a non-positive / NaN error is refused
    by name before a cloud is opened (the cloud here does not exist)."""
    with pytest.raises(ReconstructionError, match="--max-triangles >= 4"):
        mesh_files("/nonexistent/c.laz", "/nonexistent/m.ply", max_triangles=n)
    with pytest.raises(ReconstructionError, match="positive --max-error"):
        mesh_files("/nonexistent/c.laz", "/nonexistent/m.ply", max_error_m=error)


def test_one_of_cell_m_and_cell_deg_is_refused(tube, tmp_path):
    _, cloud, _ = tube
    with pytest.raises(ReconstructionError, match=r"cell_m and cell_deg together \(--cell"):
        mesh_files(cloud, tmp_path / "m.ply", cell_m=0.5)
    assert not (tmp_path / "m.ply").exists()


def test_preprocess_is_the_commands(tube, tmp_path):
    """Voxel grid, crop on the tube's axis and both outlier filters: the same LAZ
    bytes, and the result's counts are the file's (laspy) and the analytic crop's."""
    import laspy

    al, cloud, axis = tube
    (tmp_path / "cli").mkdir()
    (tmp_path / "lib").mkdir()
    rc, printed = _run(["preprocess", cloud, "-o", tmp_path / "cli/p.laz", "--voxel",
                        "0.05", "--crop", "5,12", "--tunnel-json", axis, "--sor", "8,2.0",
                        "--ror", "2,0.2"])
    assert rc == 0
    r = preprocess_file(cloud, tmp_path / "lib/p.laz", voxel_m=0.05, crop_m=(5.0, 12.0),
                        tunnel_json=axis, sor=(8, 2.0), ror=(2, 0.2))
    assert (tmp_path / "cli/p.laz").read_bytes() == (tmp_path / "lib/p.laz").read_bytes()
    out = laspy.read(tmp_path / "lib/p.laz")
    assert r.kept_points == len(out.x) < r.voxel_points < r.input_points == N_TUBE
    assert printed.strip() == (f"{r.input_points:,} points -> {r.voxel_points:,} after "
                               f"the voxel grid -> {r.kept_points:,} after outlier "
                               f"removal -> {tmp_path / 'cli/p.laz'}")
    # The crop keeps chainage 5 to 12 m of the 40 m tube (voxel centroids within half a
    # voxel of the cut; the filters remove a few per cent at most).
    s, _, _ = al.to_local(np.stack([out.x, out.y, out.z], 1))
    assert 5.0 <= s.min() < 5.1 and 11.9 < s.max() <= 12.0
    assert 0.9 * 7 / LENGTH_M < r.kept_points / r.voxel_points <= 1.1 * 7 / LENGTH_M
    assert r.classes is None
