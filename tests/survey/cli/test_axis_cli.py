"""From a cloud alone to every command that takes a tunnel (issue 31, items 1 and 3).

Clouds are made here about a known alignment with a radius that rises and falls
linearly with the true chainage (``_radius``: +-SLOPE m per m, a triangle wave), so a
section's radius tells the true chainage where it was cut: ``sections``' mean
deviation from a circle of R_DESIGN is ``_radius(true chainage) - R_DESIGN``. The user's chainage is
the true one plus CH0 (stated with --start at the true chainage-0 point and
--chainage-at CH0).
"""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from survey.cli.main import main
from survey.world.alignment import Alignment, curve, straight
from survey.world.alignment_io import load_tunnel

E0, N0, H0 = 2_600_000.0, 1_200_000.0, 500.0
SLOPE = 0.03        # radius change per metre of true chainage
R0 = 3.0
#: Design circle of the sections and develop tests: inside the whole lining (every
#: deviation is overbreak).
R_DESIGN = 2.5
CH0 = 1000.0        # the user's chainage at the true start
N_POINTS = 100_000


def _true(kind: str) -> Alignment:
    if kind == "straight":
        return Alignment([straight(60.0)], start_xy=(E0, N0), heading_rad=0.3,
                         profile=((0.0, H0),))
    return Alignment([straight(15.0), *curve(0.3, 200.0, 20.0), straight(15.0)],
                     start_xy=(E0, N0), heading_rad=2.0,
                     profile=((0.0, H0), (110.0, H0 + 2.0)))


def _radius(s):
    """Lining radius (m) at true chainage s: peaks at s = 5, 45, ... (R0 + 10 SLOPE),
    troughs at 25, 65, ... (R0 - 10 SLOPE); sections at whole 10 m lie on the slopes."""
    u = np.mod(np.asarray(s) - 5.0, 40.0)
    return R0 + SLOPE * (np.abs(u - 20.0) - 10.0)


def _cone(true: Alignment, n: int, seed: int, shrink_m: float = 0.0):
    """n lining points on a golden-angle helix (evenly spread: any run of consecutive
    points covers the angles evenly, so a section's mean is not sampling noise)."""
    k = np.arange(n)
    s = (k + 0.5) * true.length_m / n
    phi = np.mod(k * np.pi * (3.0 - np.sqrt(5.0)) + seed, 2 * np.pi) - np.pi
    r = _radius(s) - shrink_m
    return true.to_world(s, r * np.sin(phi), r * np.cos(phi))


def _circle(path, radius):
    a = np.linspace(0, 2 * np.pi, 4001)   # sagitta 1e-6 m; closed: last = first
    np.savetxt(path, np.stack([radius * np.sin(a), radius * np.cos(a)], 1),
               delimiter=",", header="y,z", comments="")
    return path


def _npz(path, p):
    np.savez(path, x=p[:, 0], y=p[:, 1], z=p[:, 2])
    return path


@pytest.fixture(scope="module", params=["straight", "curved"])
def fitted(request, tmp_path_factory):
    d = tmp_path_factory.mktemp(request.param)
    true = _true(request.param)
    cloud = _npz(d / "scan.npz", _cone(true, N_POINTS, 1))
    start = true.point(0.0)
    js = d / "tunnel.json"
    assert main(["axis", str(cloud), "-o", str(js), "--start",
                 f"{start[0]:.4f},{start[1]:.4f}", "--chainage-at", str(CH0)]) == 0
    return request.param, true, cloud, js, d


def test_axis_json_carries_the_users_chainage(fitted):
    kind, true, _, js, _ = fitted
    t = load_tunnel(js)
    lo, hi = t.alignment.chainage_range
    assert lo == pytest.approx(CH0, abs=0.01)
    assert hi == pytest.approx(CH0 + true.length_m, abs=0.01)
    c = np.arange(CH0 + 5, CH0 + true.length_m - 4, 5.0)
    s, off, h = true.to_local(t.alignment.point(c))
    np.testing.assert_allclose(s, c - CH0, atol=0.003)    # a few mm along the axis
    assert np.abs(off).max() < 0.02
    meta = json.loads(js.read_text())
    assert meta["datum"]["kind"] == "start" and meta["datum"]["chainage_at_m"] == CH0
    # The fitted profile: sectors about the axis, the median radius (R0 here).
    y0, y1, z0, z1 = _extent(t.profile)
    assert (y1 - y0) / 2 == pytest.approx(R0, abs=0.1)
    assert (z1 - z0) / 2 == pytest.approx(R0, abs=0.1)


def _extent(prof):
    p = prof.points(prof.sample(0.05))
    return p[:, 0].min(), p[:, 0].max(), p[:, 1].min(), p[:, 1].max()


def _sections(out):
    with open(out / "sections.csv") as fh:
        return [row for row in csv.DictReader(fh)]


def test_sections_fall_at_the_users_chainages(fitted, capsys):
    kind, true, cloud, js, d = fitted
    design = _circle(d / "c3.csv", R_DESIGN)
    out = d / "sec"
    assert main(["sections", str(cloud), "--tunnel-json", str(js), "--every", "10",
                 "--width", "0.2", "--design", str(design), "--no-plots", "-o",
                 str(out)]) == 0
    rows = _sections(out)
    got = [float(r["chainage_m"]) for r in rows]
    want = np.arange(CH0 + 10, CH0 + true.length_m - 0.05, 10.0)
    np.testing.assert_allclose(got, want)
    rep = json.loads((out / "report.json").read_text())
    for sec in rep["sections"]:
        # The radius where the section was cut is the one at the true chainage: 5 mm
        # of chainage is 0.15 mm of radius.
        want_dev = _radius(sec["chainage_m"] - CH0) - R_DESIGN
        assert sec["mean_m"] == pytest.approx(want_dev, abs=SLOPE * 0.005)


def test_sections_fit_axis_takes_the_start(fitted):
    """The issue's case: sections --fit-axis --every 10 on the cloud alone."""
    kind, true, cloud, _, d = fitted
    design = _circle(d / "c3b.csv", R_DESIGN)
    start = true.point(0.0)
    out = d / "secfit"
    assert main(["sections", str(cloud), "--fit-axis", "--start",
                 f"{start[0]:.4f},{start[1]:.4f}", "--every", "10", "--width", "0.2",
                 "--design", str(design), "--no-plots", "-o", str(out)]) == 0
    rep = json.loads((out / "report.json").read_text())
    ch = np.array([s["chainage_m"] for s in rep["sections"]])
    np.testing.assert_allclose(ch, np.arange(10.0, true.length_m - 0.05, 10.0))
    s20 = next(s for s in rep["sections"] if s["chainage_m"] == 20.0)
    assert s20["mean_m"] == pytest.approx(_radius(20.0) - R_DESIGN, abs=SLOPE * 0.005)
    assert s20["coverage"] > 0.75      # the whole ring is cut (sparse points: < 1)


@pytest.mark.parametrize("fitted", ["curved"], indirect=True)   # the harder one
def test_convergence_and_m3c2_on_the_axis_json(fitted):
    kind, true, cloud, js, d = fitted
    e2 = _npz(d / "e2.npz", _cone(true, N_POINTS, 2, shrink_m=0.004))
    out = d / "conv"
    assert main(["convergence", str(cloud), str(e2), "--tunnel", str(js), "--every", "10",
                 "--band", "0.5", "--angle-step", "30", "-o", str(out)]) == 0
    summ = json.loads((out / "convergence.json").read_text())
    ch = np.array([s["chainage_m"] for s in summ["sections"]])
    assert len(ch) >= 4
    np.testing.assert_allclose(ch % 10.0, 0.0, atol=1e-9)     # 1010, 1020, ... not 1009
    assert ch.min() >= CH0 and ch.max() <= CH0 + true.length_m
    for s in summ["sections"]:
        assert s["median_m"] == pytest.approx(0.004, abs=5e-4)
    las = d / "m3c2.las"
    assert main(["m3c2", str(cloud), str(e2), "--core-spacing", "2", "--cyl-radius",
                 "0.3", "--max-depth", "0.1", "--orient", "axis", "--tunnel", str(js),
                 "-o", str(las)]) == 0
    rep = json.loads(las.with_name("m3c2.json").read_text())
    assert rep["median_m"] == pytest.approx(0.004, abs=5e-4)   # positive: convergence


@pytest.mark.parametrize("fitted", ["curved"], indirect=True)   # the harder one
def test_develop_and_clearance_on_the_axis_json(fitted):
    kind, true, cloud, js, d = fitted
    out = d / "dev"
    design = _circle(d / "c3c.csv", R_DESIGN)
    assert main(["develop", str(cloud), "--tunnel-json", str(js), "--design", str(design),
                 "--cell", "0.2", "--cell-arc", "0.5", "-o", str(out)]) == 0
    grid = json.loads(next(out.glob("developed_deviation_*.json")).read_text())
    v = np.load(next(out.glob("developed_deviation_*.npy")))
    s0, ds = _chainage_axis(grid)
    col = s0 + (np.arange(v.shape[1]) + 0.5) * ds
    u = np.mod(col - CH0 - 5.0, 20.0)       # leave out the cells on a peak or trough
    inner = (col > CH0 + 1) & (col < CH0 + true.length_m - 1) & (u > 0.5) & (u < 19.5)
    dev = np.nanmedian(v[:, inner], axis=0)
    # The deviation is the radius at the true chainage: the raster's chainage is the
    # user's (2 cm of chainage is 0.6 mm of radius).
    np.testing.assert_allclose(dev, _radius(col[inner] - CH0) - R_DESIGN,
                               atol=SLOPE * 0.02)
    env = _circle(d / "env.csv", R0)
    out = d / "clr"
    assert main(["clearance", str(cloud), "--tunnel-json", str(js), "--envelope",
                 str(env), "--cell", "0.1", "-o", str(out)]) == 0
    res = json.loads((out / "clearance.json").read_text())
    # The lining is inside the 3 m envelope between the true chainages 15 and 35
    # (and 55 to 75 ...): the first region spans them in the user's chainage.
    first = min(res["regions"], key=lambda r: r["chainage_from_m"])
    assert first["chainage_from_m"] == pytest.approx(CH0 + 15.0, abs=0.15)
    assert first["chainage_to_m"] == pytest.approx(CH0 + 35.0, abs=0.15)


def _chainage_axis(grid):
    """(first chainage, cell) of a developed raster's JSON."""
    g = grid["grid"]
    return float(g["chainage_origin_m"]), float(g["cell_chainage_m"])


def test_axis_datum_errors_name_the_options(tmp_path, capsys):
    true = _true("straight")
    cloud = _npz(tmp_path / "c.npz", _cone(true, 20_000, 3))
    code = main(["sections", str(cloud), "--tunnel-json", str(tmp_path / "t.json"),
                 "--start", "1,2", "--every", "10", "-o", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "--start" in err and "--fit-axis" in err
    code = main(["axis", str(cloud), "-o", str(tmp_path / "t.txt")])
    assert code == 2 and "-o as a .json" in capsys.readouterr().err


@pytest.mark.parametrize("fitted", ["straight"], indirect=True)
def test_datum_start_reverse_default_and_reference(fitted):
    """apply_datum on the fitted axis: the chainage at true points, as each datum
    states it (library level: the axis is fitted once)."""
    from survey.clouds.axis import apply_datum

    kind, true, cloud, js, d = fitted
    al = load_tunnel(js).alignment
    pts = _cone(true, 20_000, 5)
    L = true.length_m
    s_true = np.array([5.0, 20.0, 40.0, 55.0])
    where = true.point(s_true)

    def chain(a):
        return a.to_local(where)[0]

    # --start at the far end: chainage runs back towards the true start.
    a, rec = apply_datum(al, pts, start_xy=true.point(L)[:2], chainage_at_m=200.0)
    np.testing.assert_allclose(chain(a), 200.0 + (L - s_true), atol=0.005)
    # --start at the true start with --reverse: it runs the other way (down from 300).
    a, _ = apply_datum(al, pts, start_xy=true.point(0.0)[:2], chainage_at_m=300.0,
                       reverse=True)
    assert a.chainage_range[1] == pytest.approx(300.0, abs=0.005)
    np.testing.assert_allclose(chain(a), 300.0 - s_true, atol=0.005)
    # No start: from the west end (heading 0.3 rad runs east), where the data begin.
    a, rec = apply_datum(al.reversed(), pts)
    assert rec["kind"] == "end"
    np.testing.assert_allclose(chain(a), s_true, atol=0.01)
    # A reference running the other way with its own chainage: the axis takes both.
    ref = true.reversed().with_start_chainage(5000.0)
    a, rec = apply_datum(al, pts, reference=ref)
    np.testing.assert_allclose(chain(a), 5000.0 + (L - s_true), atol=0.005)
    assert rec["kind"] == "alignment" and rec["max_difference_m"] < 0.005


def test_axis_takes_the_chainage_of_a_station_csv(tmp_path):
    true = _true("straight")
    cloud = _npz(tmp_path / "c.npz", _cone(true, N_POINTS, 4))
    st = np.arange(0.0, 60.0 + 1e-9, 5.0)
    p = true.point(st)
    csv_ = tmp_path / "design.csv"
    csv_.write_text("chainage,E,N,H\n" + "".join(
        f"{s + 2000.0!r},{e!r},{n!r},{h!r}\n" for s, (e, n, h) in zip(st.tolist(),
                                                                     p.tolist())))
    js = tmp_path / "t.json"
    assert main(["axis", str(cloud), "--alignment", str(csv_), "--profile", "circle",
                 "-o", str(js)]) == 0
    t = load_tunnel(js)
    np.testing.assert_allclose(t.alignment.to_local(true.point([10.0, 30.0, 50.0]))[0],
                               [2010.0, 2030.0, 2050.0], atol=0.005)
    assert json.loads(js.read_text())["datum"]["kind"] == "alignment"
    assert t.profile.name.startswith("fitted circle")
