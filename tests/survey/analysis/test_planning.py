"""Station planning on a straight generated tunnel: monotone coverage, spacings, the
optimiser against exhaustive search and greedy, analytic quality, outputs, errors."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from raytrace import Scene
from sensors import load_sensor
from survey.world.alignment import Alignment, straight
from survey.cli.main import main
from survey.analysis.planning import Planner, Thresholds, station_quality
from survey.errors import PlanningError
from survey.world.profiles import horseshoe
from survey.world.generator import make_tunnel


@pytest.fixture(scope="module")
def tunnel():
    return make_tunnel(Alignment([straight(60.0)]), horseshoe(5.0), edge_length_m=0.25,
                       roughness_rms_m=0.0)


@pytest.fixture(scope="module")
def planner(tunnel):
    scene = Scene(tunnel.vertices, tunnel.faces)
    return Planner(scene, tunnel.alignment, float(tunnel.profile.centroid[1]),
                   load_sensor("zf_imager_5016"), resolution="high", cell_m=0.5,
                   cell_rad=np.deg2rad(4.0))


def test_cells_cover_the_lining(planner, tunnel):
    # The cells' area is the lining's (floor excluded): compare with the mesh's lining
    # triangles (label 0) - same surface, sampled differently.
    from survey.world.mesh import LABEL

    v, f = tunnel.vertices, tunnel.faces[tunnel.labels == LABEL["lining"]]
    a = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]),
                             axis=1).sum()
    assert planner.cells.total_area == pytest.approx(a, rel=0.03)


def test_quality_is_analytic(planner):
    c = planner.cells
    st = planner.stations_at([30.0])[0]
    q = station_quality(planner.scene, c, st, planner.step_rad, range_max_m=365.0,
                        vertical_fov_rad=planner.sensor.pattern.vertical_fov_rad)
    d = c.points - st
    r = np.linalg.norm(d, axis=1)
    np.testing.assert_allclose(q.range_m, r)
    inc = np.arccos(np.clip(np.abs(np.einsum("ni,ni->n", d, c.normals)) / r, 0, 1))
    np.testing.assert_allclose(q.incidence_rad, inc, atol=1e-9)
    np.testing.assert_allclose(q.spacing_m, r * planner.step_rad / np.cos(inc), rtol=1e-9)
    # A straight empty tube: the lining is visible from the axis up to the blind cone
    # (nothing occludes), so every cell within range and above -70 deg is visible.
    el = np.degrees(np.arcsin(d[:, 2] / r))
    assert q.visible[el > -69].all()


def test_coverage_is_monotone_and_5m_beats_10m(planner):
    p5 = planner.evaluate(planner.spaced(5.0))
    p10 = planner.evaluate(planner.spaced(10.0, start_m=2.5))
    assert set(p10.chainages) <= set(p5.chainages)     # nested station sets
    assert p5.coverage > p10.coverage
    covs = [planner.evaluate(p5.chainages[:k]).coverage for k in range(len(p5.chainages) + 1)]
    assert all(b >= a for a, b in zip(covs, covs[1:]))
    assert covs[0] == 0.0
    # Gaps are reported where cells are not served, and their areas add up.
    gap_area = sum(g["area_m2"] for g in p10.gaps)
    unserved = planner.cells.area[p10.served == 0].sum()
    assert gap_area == pytest.approx(unserved)
    assert len(p5.overlap) == len(p5.chainages) - 1 and (p5.overlap > 0.5).all()


def test_optimiser_meets_target_and_beats_greedy_and_matches_exhaustive(planner):
    cand = np.arange(3.0, 60.0, 6.0)                     # 10 candidates
    best, greedy, info = planner.optimize(cand, target=0.9)
    assert best.coverage >= 0.9 - 1e-9 and greedy.coverage >= 0.9 - 1e-9
    assert len(best.chainages) <= len(greedy.chainages)
    assert info["optimal"] and info["gap"] == 0.0
    # Exhaustive search over all subsets for the same target.
    smallest = None
    for k in range(1, len(cand) + 1):
        for sub in itertools.combinations(cand, k):
            if planner.evaluate(sub).coverage >= 0.9 - 1e-9:
                smallest = k
                break
        if smallest:
            break
    assert len(best.chainages) == smallest


def test_unreachable_target_is_reported(planner):
    best, _, info = planner.optimize([30.0], target=0.99)
    assert info["reachable"] < 0.99 and "not reachable" in info["note"]
    assert best.coverage == pytest.approx(info["reachable"])


def test_bad_inputs(tunnel, planner):
    scene = planner.scene
    with pytest.raises(PlanningError, match="TLS sensor"):
        Planner(scene, tunnel.alignment, 0.0, load_sensor("velodyne_vlp16"))
    with pytest.raises(PlanningError, match="resolution"):
        Planner(scene, tunnel.alignment, 0.0, load_sensor("zf_imager_5016"),
                resolution="huge")
    with pytest.raises(PlanningError, match="threshold"):
        Thresholds(spacing_m=0.0)
    with pytest.raises(PlanningError, match="target"):
        planner.optimize([10.0], target=1.5)
    with pytest.raises(ValueError, match="chainages within"):
        planner.stations_at([500.0])


def test_cli_plan_outputs(tmp_path, tunnel, capsys):
    tunnel.write(tmp_path / "t.ply")
    out = tmp_path / "plan"
    assert main(["plan", "--mesh", str(tmp_path / "t.ply"), "--resolution", "high",
                 "--spacing", "5,10", "--optimize", "--target", "0.95", "--candidate-step",
                 "5", "--cell", "0.5,4", "-o", str(out), "--quiet"]) == 0
    rows = (out / "plan.csv").read_text().splitlines()
    assert rows[0].startswith("plan,station,chainage_m")
    names = {r.split(",")[0] for r in rows[1:]}
    assert names == {"every 5 m", "every 10 m", "optimised", "greedy"}
    assert len([r for r in rows if r.startswith("every 5 m,")]) == 12
    md = (out / "plan.md").read_text()
    assert "| every 5 m | 12 |" in md and "optimality gap" in md
    png = (out / "coverage.png").read_bytes()
    assert png[:4] == b"\x89PNG" and int.from_bytes(png[20:24], "big") > 600
    assert main(["plan", "--mesh", str(tmp_path / "t.ply"), "--sensor", "velodyne_vlp16",
                 "-o", str(tmp_path / "p2")]) == 2
    assert "TLS sensor" in capsys.readouterr().err


def test_read_axis_bad_input(tmp_path):
    from sensors.io.errors import TunnelFileError
    from survey.world.mesh import read_axis

    with pytest.raises(TunnelFileError, match="does not exist"):
        read_axis(tmp_path / "none.json")
    (tmp_path / "x.json").write_text('{"format": "other"}')
    with pytest.raises(TunnelFileError, match="'alignment' and 'profile'"):
        read_axis(tmp_path / "x.json")


def test_planner_cells_and_plans_print_one_line(planner):
    plan = planner.evaluate([10.0, 30.0], "two")
    for obj, start in ((planner, "Planner(zf_imager_5016 at high, "),
                       (planner.cells, f"Cells({len(planner.cells.area):,} cells on a "),
                       (plan, f"Plan('two', 2 stations, coverage {100 * plan.coverage:.2f} %"),
                       (planner.quality(plan.stations[0]), "StationQuality(")):
        text = repr(obj)
        assert text.startswith(start) and "\n" not in text and len(text) < 200, text
