"""Developed views (issue 17, item 4): a known bulge on a generated tunnel appears at its
chainage and angle on the raster (and the whole raster equals the analytic field),
the arc-length zero and direction, accumulation independent of chunking and of a
UTM-sized offset (hypothesis), per-point fields from files (intensity, an M3C2-like
distance), the artefacts of ``tunnelsim develop`` (PNG, NPY + JSON grid, tiles) and
one clear error per bad input."""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from survey.analysis.design import DesignProfile
from survey.analysis.developed import (DevelopedFrame,
    DevelopedGrid,
    RasterAccumulator,
    crown_t,
    develop,
    develop_file,
    mesh_samples)
from sensors.io.cloudfields import iter_field
from survey.cli.main import main
from survey.errors import AlignmentError, CompareError
from sensors.io.errors import PointFileError
from survey.world.alignment import Alignment, straight
from survey.world.deformation import Bulge
from survey.world.generator import make_tunnel
from survey.world.mesh import write_tunnel
from survey.world.profiles import circle, horseshoe

UTM = (512_345.678, 5_345_678.901)
R = 3.0
BULGE = Bulge(chainage_m=6.0, angle_rad=0.5, radius_m=1.0, amplitude_m=0.05)


@functools.lru_cache(maxsize=None)
def _design(kind: str) -> DesignProfile:
    """Design lines built once (their self-intersection check is O(k^2))."""
    return DesignProfile.from_profile(circle(R) if kind == "circle" else horseshoe(5.0))


@pytest.fixture(scope="module")
def bulged():
    """A 12 m circular tunnel (r = 3 m, smooth, UTM-placed) with one inward bulge."""
    al = Alignment([straight(12.0)], start_xy=UTM, heading_rad=0.3, profile=((0.0, 400.0),))
    tun = make_tunnel(al, circle(R), edge_length_m=0.1, roughness_rms_m=0.0)
    return al, tun.deformed([BULGE])


def _png(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
    return data


# ---------------------------------------------------------------------- the frame
def test_crown_zero_and_left_positive_arc():
    d = DesignProfile.from_profile(circle(R))
    fr = DevelopedFrame(Alignment([straight(5.0)]), d)
    assert np.allclose(d.points(crown_t(d)), [0.0, 2 * R], atol=1e-9)
    # A point on the left wall (offset +R at the springline) is a quarter turn to the
    # left of the crown: u = +pi R / 2; the right wall -pi R / 2; the invert +-pi R.
    _, t = d.locate(np.array([[R, R], [-R, R], [0.0, 0.0]]))
    u = fr.arc(t)
    assert u[0] == pytest.approx(np.pi * R / 2, abs=1e-3)
    assert u[1] == pytest.approx(-np.pi * R / 2, abs=1e-3)
    assert abs(u[2]) == pytest.approx(np.pi * R, abs=1e-3)
    assert fr.arc_range == pytest.approx((-d.length_m / 2, d.length_m / 2))
    assert np.allclose(fr.design_t(fr.arc(t)), t)


def test_open_design_runs_from_its_ends():
    ang = np.linspace(0.0, np.pi, 91)   # an arch without invert, radius 2
    d = DesignProfile(np.stack([2 * np.cos(ang), 1 + 2 * np.sin(ang)], 1), closed=False)
    fr = DevelopedFrame(Alignment([straight(5.0)]), d)
    lo, hi = fr.arc_range
    assert hi - lo == pytest.approx(d.length_m)
    assert lo == pytest.approx(-d.length_m / 2, abs=1e-9)   # symmetric arch
    s, u, dev, _, _ = fr.locate(np.array([[2.0, 2.0, 1.0], [2.0, -2.0, 1.0]]))
    assert u[0] == pytest.approx(d.length_m / 2, abs=1e-9)   # left end (+2, 1)
    assert u[1] == pytest.approx(-d.length_m / 2, abs=1e-9)
    assert abs(dev[0]) < 1e-12
    # Beyond an end (below the springline): no deviation, the end's u.
    _, u2, dev2, _, _ = fr.locate(np.array([[2.0, 2.0, 0.5]]))
    assert np.isnan(dev2[0]) and u2[0] == pytest.approx(d.length_m / 2, abs=1e-9)


# ---------------------------------------------------------------------- the bulge
def test_known_bulge_appears_at_its_chainage_and_angle(bulged):
    al, tun = bulged
    design = _design("circle")
    r = develop(mesh_samples(tun.vertices, tun.faces, 0.05), al, design, cell_m=0.1)
    g = r.grid
    assert r.meta["points"] > 0 and (r.count > 0).all()
    # The deepest cell is where the bulge is: chainage 6, arc R * 0.5 to the left.
    i, j = np.unravel_index(np.nanargmin(r.mean), r.mean.shape)
    assert abs(g.chainage_centres()[j] - BULGE.chainage_m) <= g.cell_s_m
    assert abs(g.arc_centres()[i] - R * BULGE.angle_rad) <= g.cell_arc_m
    assert r.mean[i, j] == pytest.approx(-BULGE.amplitude_m, abs=1.5e-3)
    # The whole raster equals the analytic field (inward = negative deviation) at the
    # cell centres, within the cell average of the cosine bump and the mesh's chords
    # (h^2 / 8R = 0.4 mm for 10 cm edges).
    fr = DevelopedFrame(al, design)
    S, U = np.meshgrid(g.chainage_centres(), g.arc_centres())
    truth = -BULGE.field(S, fr.design_t(U), circle(R))
    assert np.abs(r.mean - truth).max() < 2.5e-3
    assert np.abs(r.mean - truth)[np.abs(truth) == 0].max() < 5e-4


def test_bulge_on_the_npy_file_written_by_the_cli(bulged, tmp_path):
    al, tun = bulged
    ply = tmp_path / "t2.ply"
    write_tunnel(tun, ply)
    out = tmp_path / "dev"
    assert main(["develop", str(ply), "--cell", "0.25", "--tile-m", "4", "-o", str(out),
                 "--quiet"]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert "developed.md" in names
    stems = ["developed_deviation_0+000.000_0+004.000",
             "developed_deviation_0+004.000_0+008.000",
             "developed_deviation_0+008.000_0+012.000"]
    for s in stems:
        assert {f"{s}.npy", f"{s}.json", f"{s}.png"} <= set(names)
        _png(out / f"{s}.png")
    # Read the tile holding the bulge as a user would: the grid from the JSON only.
    meta = json.loads((out / f"{stems[1]}.json").read_text())
    a = np.load(out / meta["file"])
    gr = meta["grid"]
    assert a.dtype == np.float32 and list(a.shape) == meta["array"]["shape"]
    assert a.shape == (gr["rows"], gr["columns"]) and meta["unit"] == "m"
    i, j = np.unravel_index(np.nanargmin(a), a.shape)
    s = gr["chainage_origin_m"] + (j + 0.5) * gr["cell_chainage_m"]
    u = gr["arc_origin_m"] + (i + 0.5) * gr["cell_arc_m"]
    assert abs(s - BULGE.chainage_m) <= gr["cell_chainage_m"]
    assert abs(u - R * BULGE.angle_rad) <= gr["cell_arc_m"]
    assert a[i, j] == pytest.approx(-0.05, abs=5e-3)
    assert meta["arc"]["zero"] == "crown" and meta["alignment"]["start_xy"] == list(UTM)


# ---------------------------------------------------------------------- properties
def _cloud(seed: int, n: int, al: Alignment):
    rng = np.random.default_rng(seed)
    ang = rng.uniform(-np.pi, np.pi, n)
    rad = R + rng.normal(0.0, 0.05, n)
    s = rng.uniform(*al.chainage_range, n)
    return al.to_world(s, rad * np.sin(ang), R + rad * np.cos(ang)), rng.random(n)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 10_000), st.lists(st.integers(1, 400), min_size=1, max_size=6))
def test_accumulation_does_not_depend_on_chunking(seed, cuts):
    al = Alignment([straight(4.0)])
    design = _design("circle")
    p, v = _cloud(seed, 600, al)
    whole = develop(p, al, design, values=v, cell_m=0.25)
    edges = np.unique(np.clip(np.cumsum(cuts), 0, len(p)))
    parts = np.split(np.arange(len(p)), edges)
    chunked = develop(((p[k], v[k]) for k in parts), al, design, cell_m=0.25)
    assert np.array_equal(whole.count, chunked.count)
    assert np.array_equal(whole.min, chunked.min, equal_nan=True)
    assert np.array_equal(whole.max, chunked.max, equal_nan=True)
    assert np.allclose(whole.mean, chunked.mean, rtol=1e-12, atol=0, equal_nan=True)
    # And against a brute-force binning of the same cells.
    fr = DevelopedFrame(al, design)
    s, u, _, _, _ = fr.locate(p)
    g = whole.grid
    j = np.floor((s - g.chainage0_m) / g.cell_s_m).astype(int)
    i = np.mod(np.floor((u - g.arc0_m) / g.cell_arc_m).astype(int), g.n_arc)
    for ii, jj in list(zip(i, j))[:50]:
        sel = (i == ii) & (j == jj)
        assert whole.count[ii, jj] == sel.sum()
        assert whole.mean[ii, jj] == pytest.approx(v[sel].mean(), rel=1e-12)


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 10_000), st.floats(-np.pi, np.pi))
def test_raster_is_invariant_under_a_utm_offset_and_rotation(seed, heading):
    local = Alignment([straight(4.0)])
    utm = Alignment([straight(4.0)], start_xy=UTM, heading_rad=heading,
                    profile=((0.0, 812.5),))
    design = _design("horseshoe")
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, design.length_m, 500)
    yz = design.points(t) + design.normals(t) * rng.normal(0, 0.03, 500)[:, None]
    s = rng.uniform(0.01, 3.99, 500)
    a = develop(local.to_world(s, yz[:, 0], yz[:, 1]), local, design, cell_m=0.2)
    b = develop(utm.to_world(s, yz[:, 0], yz[:, 1]), utm, design, cell_m=0.2)
    assert np.array_equal(a.count, b.count)
    assert np.allclose(a.mean, b.mean, atol=1e-7, equal_nan=True)


# ---------------------------------------------------------------------- fields in files
def test_intensity_and_distance_fields_stream_from_files(tmp_path):
    from sensors.io.cloudmap import write_points_las

    al = Alignment([straight(4.0)], start_xy=UTM)
    design = DesignProfile.from_profile(circle(R))
    p, _ = _cloud(3, 4000, al)
    fr = DevelopedFrame(al, design)
    s, u, _, _, _ = fr.locate(p)
    # Intensity: 0.2 on the left half, 0.8 on the right (NPZ, as tunnelsim writes).
    inten = np.where(u > 0, 0.2, 0.8).astype(np.float32)
    npz = tmp_path / "scan.npz"
    np.savez(npz, x=p[:, 0], y=p[:, 1], z=p[:, 2], intensity=inten)
    r = develop_file(npz, al, design, field="intensity", cell_m=0.5)
    g = r.grid
    up = g.arc_centres() > g.cell_arc_m
    down = g.arc_centres() < -g.cell_arc_m
    assert np.allclose(r.mean[up][np.isfinite(r.mean[up])], 0.2, atol=1e-6)
    assert np.allclose(r.mean[down][np.isfinite(r.mean[down])], 0.8, atol=1e-6)
    # An M3C2-like distance field in LAS extra bytes: distance = chainage / 1000.
    las = tmp_path / "m3c2.las"
    write_points_las(las, p, {"distance": (s / 1000.0).astype(np.float32)})
    d = develop_file(las, al, design, field="distance", cell_m=0.5)
    cols = np.isfinite(d.mean)
    S = np.broadcast_to(d.grid.chainage_centres(), d.mean.shape)
    assert np.abs(d.mean[cols] - S[cols] / 1000.0).max() <= 0.25 / 1000 + 1e-6
    # Chunks of a file come in as asked (and the LAS field as stored).
    got = np.concatenate([v for _, v in iter_field(las, "distance", chunk=1000)])
    assert np.allclose(got, s / 1000.0, atol=1e-6)


def test_grid_tiles_line_up_with_whole_multiples():
    al = Alignment([straight(250.0)], start_chainage_m=1030.0)
    fr = DevelopedFrame(al, DesignProfile.from_profile(circle(R)))
    g = DevelopedGrid.covering(fr, 0.5)
    tiles = g.tiles(100.0)
    assert [(a, b) for a, b, _ in tiles] == [(1000.0, 1100.0), (1100.0, 1200.0),
                                            (1200.0, 1300.0)]
    assert sum(c.stop - c.start for _, _, c in tiles) == g.n_s == 500
    acc = RasterAccumulator(g)
    assert acc.add([1030.1, 1279.9, 1280.5], [0.0, 0.0, 0.0], [1.0, 2.0, 3.0]) == 2


# ---------------------------------------------------------------------- bad input
def test_one_clear_error_per_bad_input(tmp_path):
    al = Alignment([straight(4.0)])
    d = DesignProfile.from_profile(circle(R))
    p = np.array([[1.0, 0.0, 6.0]])
    with pytest.raises(CompareError, match="positive finite `cell_m`"):
        develop(p, al, d, cell_m=0.0)
    with pytest.raises(AlignmentError, match="within the alignment"):
        develop(p, al, d, chainage_range=(-1.0, 2.0))
    with pytest.raises(CompareError, match="to > from"):
        develop(p, al, d, chainage_range=(3.0, 2.0))
    with pytest.raises(CompareError, match="one value per point"):
        develop(p, al, d, values=[1.0, 2.0])
    with pytest.raises(CompareError, match="zero 'crown'"):
        develop(p, al, d, zero="invert")
    with pytest.raises(CompareError, match="whole multiple of the cell"):
        DevelopedGrid.covering(DevelopedFrame(al, d), 0.3).tiles(1.0)
    with pytest.raises(CompareError, match="shape"):
        develop(np.zeros((3, 2)), al, d)
    npz = tmp_path / "x.npz"
    np.savez(npz, x=[0.0], y=[0.0], z=[0.0])
    with pytest.raises(PointFileError, match="field 'intensity'.*'x', 'y', 'z'"):
        develop_file(npz, al, d, field="intensity")
    tun = make_tunnel(al, circle(R), edge_length_m=0.5, roughness_rms_m=0.0)
    ply = tmp_path / "t.ply"
    write_tunnel(tun, ply)
    with pytest.raises(CompareError, match="point cloud for the field 'intensity'"):
        develop_file(ply, al, d, field="intensity")


@pytest.mark.parametrize("extra, message", [
    (["--cell", "0.3", "--tile-m", "1"], "whole multiple of --cell"),
    (["--cell", "-1"], "--cell > 0"),
    (["--from", "-1"], "within the alignment"),
    (["--field", "intensity"], "point cloud for the field"),
])
def test_cli_errors_are_one_line_exit_2(tmp_path, capsys, extra, message):
    al = Alignment([straight(4.0)])
    tun = make_tunnel(al, circle(R), edge_length_m=0.5, roughness_rms_m=0.0)
    ply = tmp_path / "t.ply"
    write_tunnel(tun, ply)
    out = tmp_path / "dev"
    assert main(["develop", str(ply), "-o", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not out.exists() or not any(out.iterdir())


def test_cli_needs_a_tunnel_json(tmp_path, capsys):
    cloud = tmp_path / "c.csv"
    cloud.write_text("x,y,z\n0,0,0\n1,1,1\n")
    assert main(["develop", str(cloud), "-o", str(tmp_path / "o")]) == 2
    assert "--tunnel-json" in capsys.readouterr().err
