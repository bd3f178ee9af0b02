"""M3C2 (survey.analysis.m3c2) against py4dgeo (3DGeo Heidelberg) for the same normals
and parameters, against a brute force over every point, and on epochs simulated from a
generated tunnel with a known 5 mm convergence.

py4dgeo is given the clouds shifted to a local origin: at UTM-sized coordinates its
cylinder membership changes (tested below); ours gets the UTM coordinates.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from survey.analysis.m3c2 import (
    M3C2,
    M3C2Params,
    lod95,
    m3c2,
    subsample,
    towards_axis,
)
from survey.errors import CompareError

UTM = np.array([500_000.0, 5_000_000.0, 300.0])


def _surface(rng, n, shift=0.0, noise=0.01):
    """A wavy surface z = 0.05 sin(x) over 10 m x 10 m with Gaussian noise, m."""
    xy = rng.uniform(0, 10, (n, 2))
    z = shift + noise * rng.standard_normal(n) + 0.05 * np.sin(xy[:, 0])
    return np.c_[xy, z]


@pytest.fixture(scope="module")
def clouds():
    rng = np.random.default_rng(0)
    e1, e2 = _surface(rng, 20_000), _surface(rng, 20_000, shift=0.02)
    core = e1[::100] + rng.normal(0, 0.01, (200, 3))    # off the cloud's points
    return e1, e2, core


# ---------------------------------------------------------------------- brute force
def naive_m3c2(e1, e2, core, normals, r, half_len, reg=0.0, robust=False):
    """Every point tested against every cylinder: |t| <= L, distance to axis <= r."""
    out = []
    for c, n in zip(core, normals):
        ts = []
        for e in (e1, e2):
            v = e - c
            t = v @ n
            perp = np.sum((v - np.outer(t, n)) ** 2, axis=1)
            ts.append(np.sort(t[(np.abs(t) <= half_len) & (perp <= r * r)]))
        if robust:
            cs = [np.median(t) if len(t) else np.nan for t in ts]
        else:
            cs = [t.mean() if len(t) else np.nan for t in ts]
        sd = [t.std(ddof=1) if len(t) > 1 else np.nan for t in ts]
        d = cs[1] - cs[0]
        lod = 1.96 * (np.sqrt(sd[0] ** 2 / len(ts[0]) + sd[1] ** 2 / len(ts[1])) + reg) \
            if len(ts[0]) and len(ts[1]) else np.nan
        out.append((d, lod, len(ts[0]), len(ts[1])))
    return np.array(out, dtype=np.float64).reshape(-1, 4)


def naive_normals(cloud, core, radii, up):
    """numpy.linalg.eigh on each ball; highest planarity wins; oriented to ``up``."""
    out = np.full((len(core), 3), np.nan)
    for i, c in enumerate(core):
        best = 0.0
        for r in radii:
            s = cloud[np.sum((cloud - c) ** 2, axis=1) <= r * r]
            if len(s) < 3:
                continue
            w, v = np.linalg.eigh(np.cov(s.T))
            p = (w[1] - w[0]) / w[2]
            if p > best:
                best = p
                out[i] = v[:, 0] * (-1.0 if v[:, 0] @ up < 0 else 1.0)
    return out


# ---------------------------------------------------------------------- py4dgeo
@pytest.fixture(scope="module")
def py4dgeo():
    mod = pytest.importorskip("py4dgeo")
    logging.getLogger("py4dgeo").setLevel(logging.WARNING)
    return mod


def _py4dgeo_run(mod, e1, e2, core, normals, r, depth, reg=0.0, robust=False):
    m = mod.M3C2(epochs=(mod.Epoch(e1), mod.Epoch(e2)), corepoints=core,
                 corepoint_normals=normals, cyl_radius=r, max_distance=depth,
                 registration_error=reg, robust_aggr=robust)
    return m.run()


@pytest.mark.parametrize("robust", [False, True])
@pytest.mark.parametrize("r,depth", [(0.3, 1.0), (0.3, 0.1), (0.05, 0.5), (0.2, 0.9)])
def test_equals_py4dgeo_for_the_same_normals_at_utm_coordinates(py4dgeo, clouds, robust,
                                                                r, depth):
    e1, e2, core = clouds
    normals = naive_normals(e1, core, (0.5, 1.0), np.array([0.0, 0.0, 1.0]))
    d, u = _py4dgeo_run(py4dgeo, e1, e2, core, normals, r, depth, 0.002, robust)
    res = m3c2(e1 + UTM, e2 + UTM, core + UTM, normals=normals, cyl_radius_m=r,
               max_depth_m=depth, registration_error_m=0.002, robust=robust)
    assert np.array_equal(res.n1, u["num_samples1"])
    assert np.array_equal(res.n2, u["num_samples2"])
    assert np.array_equal(np.isnan(res.distance), np.isnan(d))
    np.testing.assert_allclose(res.distance, d, atol=1e-6, equal_nan=True)
    np.testing.assert_allclose(res.lod, u["lodetection"], atol=1e-6, equal_nan=True)
    np.testing.assert_allclose(res.spread1, u["spread1"], atol=1e-6, equal_nan=True)
    sig = np.abs(d) > u["lodetection"]
    assert np.array_equal(res.significant, sig)
    assert np.isfinite(res.distance).sum() >= 0.5 * len(core)


def test_core_points_from_the_cloud_match_py4dgeo_with_an_odd_slab_count(py4dgeo, clouds):
    """py4dgeo cuts the cylinder into ceil(L / r) slabs and drops points on a slab
    boundary; with an odd count the core point (t = 0) is mid-slab and counts in both."""
    e1, e2, _ = clouds
    core = e1[::97]
    normals = naive_normals(e1, core, (0.5,), np.array([0.0, 0.0, 1.0]))
    d, u = _py4dgeo_run(py4dgeo, e1, e2, core, normals, 0.3, 0.9)       # 3 slabs
    res = m3c2(e1, e2, core, normals=normals, cyl_radius_m=0.3, max_depth_m=0.9)
    assert np.array_equal(res.n1, u["num_samples1"])
    np.testing.assert_allclose(res.distance, d, atol=1e-6)
    # With 4 slabs t = 0 is a slab boundary: py4dgeo counts the core point 0, 1 or 2
    # times as rounding falls; we count it once, as Lague et al. and CloudCompare do.
    d4, u4 = _py4dgeo_run(py4dgeo, e1, e2, core, normals, 0.3, 1.0)
    res4 = m3c2(e1, e2, core, normals=normals, cyl_radius_m=0.3, max_depth_m=1.0)
    diff = res4.n1 - u4["num_samples1"]
    assert set(np.unique(diff).tolist()) == {-1, 0, 1}
    assert np.array_equal(res4.n2, u4["num_samples2"])


def test_py4dgeo_needs_the_shift_at_utm_coordinates(py4dgeo, clouds):
    """Why the comparisons shift py4dgeo's input: fed UTM coordinates, py4dgeo's own
    result changes; ours does not (within 1e-9 m)."""
    e1, e2, _ = clouds
    core = e1[::100]
    normals = naive_normals(e1, core, (0.5,), np.array([0.0, 0.0, 1.0]))
    _, u0 = _py4dgeo_run(py4dgeo, e1, e2, core, normals, 0.3, 1.0)
    _, u1 = _py4dgeo_run(py4dgeo, e1 + UTM, e2 + UTM, core + UTM, normals, 0.3, 1.0)
    assert np.any(u0["num_samples1"] != u1["num_samples1"])
    a = m3c2(e1, e2, core, normals=normals, cyl_radius_m=0.3, max_depth_m=1.0)
    b = m3c2(e1 + UTM, e2 + UTM, core + UTM, normals=normals, cyl_radius_m=0.3,
             max_depth_m=1.0)
    assert np.array_equal(a.n1, b.n1)
    np.testing.assert_allclose(a.distance, b.distance, atol=1e-9)


def test_multiscale_normals_equal_lapack_and_pick_py4dgeos_radius(py4dgeo, clouds):
    """Normals against numpy.linalg.eigh per ball (1e-9); py4dgeo's chosen radius is
    the same but at near-ties of planarity. (py4dgeo solves the 3 x 3 problem in closed form, Eigen's computeDirect,
    whose smallest eigenvector is off by up to ~1e-3 on these patches, so its normals
    are compared loosely.)"""
    e1, e2, core = clouds
    up = np.array([0.2, 0.0, 1.0])
    job = M3C2(e1 + UTM, e2 + UTM, M3C2Params(0.3, 1.0, (0.5, 1.0)))
    n, rad = job.normals(core + UTM, orientation=up)
    np.testing.assert_allclose(n, naive_normals(e1, core, (0.5, 1.0), up), atol=1e-9)
    m = py4dgeo.M3C2(epochs=(py4dgeo.Epoch(e1), py4dgeo.Epoch(e2)), corepoints=core,
                     normal_radii=(0.5, 1.0), orientation_vector=up, cyl_radius=0.3,
                     max_distance=1.0)
    m.directions()
    same = rad == m.directions_radii()      # near-ties of planarity may go either way
    assert same.mean() > 0.95
    assert np.abs(n - m.corepoint_normals)[same].max() < 1e-2
    assert np.all(n @ up >= 0)


# ---------------------------------------------------------------------- properties
@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(seed=st.integers(0, 2**32 - 1), r=st.floats(0.05, 0.6),
       depth=st.floats(0.0, 1.5), robust=st.booleans())
def test_agrees_with_brute_force_on_random_input(seed, r, depth, robust):
    rng = np.random.default_rng(seed)
    e1 = rng.uniform(-1, 1, (400, 3)) * [1.0, 1.0, 0.3]
    e2 = rng.uniform(-1, 1, (300, 3)) * [1.0, 1.0, 0.3] + [0, 0, 0.05]
    core = rng.uniform(-1, 1, (30, 3)) * [1.0, 1.0, 0.2]
    normals = rng.standard_normal((30, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    res = m3c2(e1, e2, core, normals=normals, cyl_radius_m=r, max_depth_m=depth,
               registration_error_m=0.001, robust=robust)
    want = naive_m3c2(e1, e2, core, normals, r, max(depth, r), 0.001, robust)
    assert np.array_equal(res.n1, want[:, 2].astype(np.int64))
    assert np.array_equal(res.n2, want[:, 3].astype(np.int64))
    np.testing.assert_allclose(res.distance, want[:, 0], atol=1e-12, equal_nan=True)
    if not robust:
        np.testing.assert_allclose(res.lod, want[:, 1], atol=1e-12, equal_nan=True)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1),
       offset=st.tuples(st.floats(-3e6, 3e6), st.floats(0, 1e7), st.floats(-500, 3000)))
def test_invariant_under_rigid_motion_and_utm_offset(seed, offset):
    """Moving both epochs and the core points rigidly (any rotation, a UTM-sized
    translation) changes no count and no distance beyond 1e-9 m."""
    rng = np.random.default_rng(seed)
    e1, e2 = _surface(rng, 3000), _surface(rng, 3000, shift=0.01)
    core = _surface(rng, 40, noise=0.0)
    rot = Rotation.random(random_state=seed % (2**32))
    t = np.asarray(offset)
    prm = dict(cyl_radius_m=0.4, max_depth_m=0.5, normal_radii_m=(0.6, 1.2))
    a = m3c2(e1, e2, core, **prm)
    up = rot.apply([0.0, 0.0, 1.0])
    b = m3c2(rot.apply(e1) + t, rot.apply(e2) + t, rot.apply(core) + t,
             orientation=up, **prm)
    assert np.array_equal(a.n1, b.n1) and np.array_equal(a.n2, b.n2)
    np.testing.assert_allclose(a.distance, b.distance, atol=1e-9, equal_nan=True)
    np.testing.assert_allclose(a.lod, b.lod, atol=1e-9, equal_nan=True)


# ---------------------------------------------------------------------- edges
def test_chunks_do_not_change_results(clouds):
    e1, e2, core = clouds
    prm = dict(cyl_radius_m=0.2, max_depth_m=0.5, normal_radii_m=(0.5,))
    a, b = m3c2(e1, e2, core, **prm), m3c2(e1, e2, core, chunk=7, **prm)
    for f in ("distance", "lod", "n1", "n2", "normal"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))


def test_empty_and_single_point_cylinders():
    e1 = np.array([[0.0, 0.0, 0.0], [5.0, 5.0, 0.0], [5.1, 5.0, 0.0]])
    e2 = np.array([[0.0, 0.0, 0.01], [9.0, 9.0, 0.0]])
    core = np.array([[0.0, 0.0, 0.0], [5.0, 5.0, 0.0]])
    res = m3c2(e1, e2, core, normals=[0.0, 0.0, 1.0], cyl_radius_m=0.3, max_depth_m=1.0)
    assert res.distance[0] == pytest.approx(0.01, abs=1e-15)
    assert np.isnan(res.lod[0]) and not res.significant[0]     # one point each: no s
    assert np.isnan(res.distance[1]) and res.n2[1] == 0 and res.n1[1] == 2
    single = m3c2(e1, e2, core[0], normals=[0.0, 0.0, 1.0], cyl_radius_m=0.3,
                  max_depth_m=1.0)
    assert len(single) == 1


def test_too_few_neighbours_give_no_normal():
    e = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [3.0, 0.0, 0.0]])
    res = m3c2(e, e, e[:1], cyl_radius_m=0.3, max_depth_m=1.0, normal_radii_m=(0.5,))
    assert np.isnan(res.normal).all() and np.isnan(res.distance[0]) and res.n1[0] == 0


def test_lod95_formula_and_cloudcompare_parameters():
    assert lod95(0.01, 100, 0.02, 25, 0.003) == pytest.approx(
        1.96 * (np.sqrt(1e-4 / 100 + 4e-4 / 25) + 0.003))
    p = M3C2Params.from_cloudcompare(normal_scales_m=[1.0, 2.0], projection_scale_m=0.5,
                                     max_depth_m=2.0, use_median=True)
    assert (p.cyl_radius_m, p.normal_radii_m, p.max_depth_m, p.robust) == \
        (0.25, (0.5, 1.0), 2.0, True)
    assert M3C2Params(0.3, 1.0).n_slabs == 4 and M3C2Params(0.3, 0.1).half_length_m == 0.3


def test_subsample_keeps_one_point_per_cell():
    rng = np.random.default_rng(3)
    p = rng.uniform(0, 10, (5000, 3)) + UTM
    sub = subsample(p, 1.0)
    cells = np.floor((sub - p.min(0)) / 1.0)
    assert len(np.unique(cells, axis=0)) == len(sub) == len(
        np.unique(np.floor((p - p.min(0)) / 1.0), axis=0))


@pytest.mark.parametrize("kwargs,match", [
    (dict(cyl_radius_m=0.0, max_depth_m=1.0), "positive finite `cyl_radius_m`"),
    (dict(cyl_radius_m=0.1, max_depth_m=-1.0), "non-negative finite `max_depth_m`"),
    (dict(cyl_radius_m=0.1, max_depth_m=1.0, registration_error_m=float("nan")),
     "registration_error_m"),
    (dict(cyl_radius_m=0.1, max_depth_m=1.0, normal_radii_m=(0.5, -1)),
     "normal_radii_m"),
    (dict(cyl_radius_m=0.1, max_depth_m=1.0), "Expected `normal_radii_m`"),
    (dict(cyl_radius_m=0.1, max_depth_m=1.0, normals=np.ones((2, 3))),
     "Expected `normals`"),
    (dict(cyl_radius_m=0.1, max_depth_m=1.0, normal_radii_m=(0.5,),
          orientation=(0, 0, 0)), "non-zero"),
])
def test_bad_parameters_raise(kwargs, match):
    e = np.random.default_rng(0).uniform(0, 1, (50, 3))
    with pytest.raises(CompareError, match=match):
        m3c2(e, e, e[:5], **kwargs)


def test_epochs_in_different_frames_are_refused():
    e = np.random.default_rng(0).uniform(0, 1, (50, 3))
    with pytest.raises(CompareError, match="different coordinate systems"):
        M3C2(e + UTM, e, M3C2Params(0.1, 0.5))
    with pytest.raises(CompareError, match="Expected `epoch2` with points"):
        M3C2(e, np.empty((0, 3)), M3C2Params(0.1, 0.5))


# ---------------------------------------------------------------------- generated tunnel
@pytest.fixture(scope="module")
def tunnel_epochs():
    """A 24 m circular tunnel (r = 3 m) at UTM coordinates, a 5 mm convergence from 4 m
    to 20 m (survey.world.deformation), scanned from mid-tunnel by the ZF Imager 5016
    model (0.4 degree step): noise-free, and with the sensor's noise plus 1 mm of
    Gaussian noise per coordinate (ASSUMED: a conservative field figure)."""
    from raytrace import Scene
    from sensors import Settings, simulate_station
    from survey.world.alignment import Alignment, straight
    from survey.world.deformation import Convergence
    from survey.world.generator import make_tunnel
    from survey.world.profiles import circle

    al = Alignment([straight(24.0)], start_xy=UTM[:2], heading_rad=0.7,
                   profile=((0.0, UTM[2]),))
    prof = circle(3.0)
    tun = make_tunnel(al, prof, edge_length_m=0.1, seed=1)
    ep = tun.deformed([Convergence(4.0, 20.0, 0.005, taper_m=2.0)])
    at = al.to_world(np.array([12.0]), *prof.centroid)[0]

    def scan(mesh, ideal, seed):
        run = simulate_station(Scene(mesh.vertices, mesh.faces), "zf_imager_5016", at,
                               step_rad=np.deg2rad(0.4), seed=seed,
                               settings=Settings.ideal() if ideal else None)
        return np.concatenate([np.stack([c["x"], c["y"], c["z"]], 1) for c in run])

    rng = np.random.default_rng(5)
    noisy = [scan(m, False, s) for m, s in ((tun, 1), (ep, 2))]
    noisy = [p + rng.normal(0, 0.001, p.shape) for p in noisy]
    return al, prof, (scan(tun, True, 1), scan(ep, True, 2)), noisy


def test_generated_5mm_convergence_is_recovered_and_significant(tunnel_epochs):
    al, prof, ideal, noisy = tunnel_epochs
    s, _, _ = al.to_local(ideal[0])
    core = subsample(ideal[0][np.abs(s - 12.0) < 4.0], 0.5)     # full-value zone
    prm = dict(cyl_radius_m=0.1, max_depth_m=0.05, normal_radii_m=(0.1, 0.2))
    tw = towards_axis(al, core, prof.centroid)
    clean = m3c2(*ideal, core, towards=tw, **prm)
    assert np.isfinite(clean.distance).all()
    assert np.abs(clean.distance - 0.005).max() < 0.001        # noise-free: within 1 mm
    assert abs(np.median(clean.distance) - 0.005) < 1e-4
    real = m3c2(*noisy, core, towards=tw, registration_error_m=0.0005, **prm)
    assert real.significant.mean() > 0.95
    assert abs(np.median(real.distance) - 0.005) < 5e-4
    # Undeformed lining (beyond the window) is not flagged: false alarms stay rare.
    sn, _, _ = al.to_local(noisy[0])
    calm = subsample(noisy[0][(sn > 21.0) & (sn < 23.0)], 0.5)
    quiet = m3c2(*noisy, calm, towards=towards_axis(al, calm, prof.centroid),
                 registration_error_m=0.0005, **prm)
    assert quiet.significant.mean() < 0.1


# ---------------------------------------------------------------------- command line
@pytest.fixture(scope="module")
def epoch_files(tmp_path_factory):
    """Two epochs of a wavy surface at UTM coordinates as LAZ (epoch 2 raised 20 mm)."""
    from sensors.io.cloudmap import write_points_las

    d = tmp_path_factory.mktemp("m3c2")
    rng = np.random.default_rng(7)
    e1, e2 = _surface(rng, 20_000) + UTM, _surface(rng, 20_000, shift=0.02) + UTM
    write_points_las(d / "e1.laz", e1)
    write_points_las(d / "e2.laz", e2)
    write_points_las(d / "core.laz", e1[::200])
    return d


def test_cli_writes_the_fields_the_library_computes(epoch_files, capsys):
    import json

    import laspy

    from survey.cli.main import main
    from sensors.io.cloudread import read_points

    d = epoch_files
    out = d / "m.laz"
    assert main(["m3c2", str(d / "e1.laz"), str(d / "e2.laz"), "--core",
                 str(d / "core.laz"), "--cyl-radius", "0.3", "--max-depth", "0.5",
                 "--normal-radii", "0.5,1.0", "--reg-error", "0.001", "-o", str(out),
                 "--quiet"]) == 0
    las = laspy.read(out)
    e1, e2, core = (read_points(d / f) for f in ("e1.laz", "e2.laz", "core.laz"))
    want = m3c2(e1, e2, core, cyl_radius_m=0.3, max_depth_m=0.5, normal_radii_m=(0.5, 1.0),
                registration_error_m=0.001)
    np.testing.assert_allclose(np.asarray(las["distance"]), want.distance, atol=1e-6)
    np.testing.assert_allclose(np.asarray(las["lod"]), want.lod, atol=1e-6)
    assert np.array_equal(np.asarray(las["significant"]).astype(bool), want.significant)
    summ = json.loads((d / "m.json").read_text())
    assert summ["core_points"] == len(core)
    assert summ["median_m"] == pytest.approx(0.02, abs=0.003)
    assert (d / "m_report.md").is_file() and (d / "m.png").is_file()


def _one_line_error(capsys, *words):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tunnelsim: error: "), err
    for w in words:
        assert w in err[0], (w, err[0])


def test_cli_refuses_epochs_in_different_frames_or_crs(epoch_files, tmp_path, capsys):
    from survey.cli.main import main
    from sensors.io.cloudread import read_points
    from sensors.io.cloudmap import write_points_las

    d = epoch_files
    far = tmp_path / "far.laz"
    write_points_las(far, read_points(d / "e2.laz") - UTM)
    args = ["--cyl-radius", "0.3", "--max-depth", "0.5", "--quiet"]
    assert main(["m3c2", str(d / "e1.laz"), str(far), "-o", str(tmp_path / "a.laz"),
                 *args]) == 2
    _one_line_error(capsys, "different coordinate systems")
    assert not (tmp_path / "a.laz").exists()
    pytest.importorskip("pyproj")
    crs = tmp_path / "crs.laz"
    write_points_las(crs, read_points(d / "e2.laz"), crs="EPSG:32632")
    write_points_las(tmp_path / "crs1.laz", read_points(d / "e1.laz"), crs="EPSG:2056")
    assert main(["m3c2", str(tmp_path / "crs1.laz"), str(crs), "-o",
                 str(tmp_path / "b.laz"), *args]) == 2
    _one_line_error(capsys, "EPSG:2056", "EPSG:32632")


@pytest.mark.parametrize("extra,match", [
    (["-o", "x.txt"], "Expected -o as .las/.laz"),
    (["-o", "x.laz", "--orient", "axis"], "Expected --tunnel"),
    (["-o", "x.laz", "--orient", "1,2"], "--orient as z, axis or X,Y,Z"),
    (["-o", "x.laz", "--normal-radii", "0.5,-1"], "normal_radii_m"),
])
def test_cli_bad_arguments_are_one_line_errors(epoch_files, tmp_path, capsys, extra, match):
    from survey.cli.main import main

    d = epoch_files
    extra = [str(tmp_path / e) if e.startswith("x.") else e for e in extra]
    assert main(["m3c2", str(d / "e1.laz"), str(d / "e2.laz"), "--cyl-radius", "0.3",
                 "--max-depth", "0.5", "--quiet", *extra]) == 2
    _one_line_error(capsys, match)
