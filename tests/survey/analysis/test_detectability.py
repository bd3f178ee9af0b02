"""Detectability study (issue 17, item 6): the quick study runs and writes what the user
gets; its smallest detectable magnitude falls with the noise; false alarms on undeformed
lining stay near 5 % or below; seeded runs repeat; the definitions against brute force
and a Monte Carlo reference; one error per bad input."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sensors import load_sensor
from survey.analysis.detect_layout import BULGE_CORE_FRACTION, DetectLayout
from survey.analysis.detect_stats import POD_TARGET, ahat_a95, detection_limit
from survey.analysis.detectability import Detectability, with_noise
from survey.cli.main import main
from survey.errors import StudyError
from survey.world.deformation import total_field
from survey.world.presets import preset


# ---------------------------------------------------------------- the quick study (CLI)
@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """The quick study as the user runs it: TLS preview stations every 10 m, noise
    factors 1 and 30, magnitudes 2, 5, 10 mm."""
    out = tmp_path_factory.mktemp("det") / "det"
    assert main(["detect", "--quick", "--quiet", "-o", str(out)]) == 0
    return out


@pytest.mark.slow
def test_quick_study_writes_its_files(quick):
    for name in ("detect.json", "detect.csv", "targets.csv", "detect.md", "detect.png"):
        assert (quick / name).is_file() and (quick / name).stat().st_size > 0
    js = json.loads((quick / "detect.json").read_text())
    assert [r["noise"] for r in js["rows"]] == [1.0, 30.0]
    assert js["layout"]["magnitudes_m"] == [0.002, 0.005, 0.01]
    # The CSV the user reads says what the JSON says.
    with open(quick / "detect.csv", newline="") as fh:
        lines = list(csv.DictReader(fh))
    assert len(lines) == 2 * 2
    for line in lines:
        row = next(r for r in js["rows"] if r["noise"] == float(line["noise"]))
        want = row["detectable_m"][line["kind"]]
        assert float(line["detectable_m"]) == pytest.approx(want)
        assert float(line["false_alarm_rate"]) == pytest.approx(row["false_alarm_rate"],
                                                                rel=1e-5)
    assert "![" not in (quick / "detect.md").read_text()   # a table, not a figure link


def test_smallest_detectable_falls_with_noise(quick):
    # Read back from the artefact: noise 1 against noise 30 on the same poses and draws
    # (common random numbers), per kind. The grid value may tie, never rise, and rises
    # for at least one kind; the a-hat vs a estimate falls strictly.
    rows = sorted(json.loads((quick / "detect.json").read_text())["rows"],
                  key=lambda r: r["noise"])
    lo, hi = rows[0], rows[-1]
    strict = 0
    for kind in ("convergence", "bulge"):
        a, b = lo["detectable_m"][kind], hi["detectable_m"][kind]
        assert a is not None and math.isfinite(a)
        assert b is None or a <= b
        strict += b is None or a < b
        assert lo["a95_m"][kind] < hi["a95_m"][kind]
    assert strict >= 1
    # More noise, larger LoD95 on the reference lining.
    assert lo["median_lod_m"] < hi["median_lod_m"]


def test_false_alarms_near_five_percent_or_below(quick):
    # LoD95 = 1.96 sigma_d flags 5 % of undeformed points for Gaussian distances. The
    # tolerance is 3 binomial standard errors of a 5 % share over the reference core
    # points (the cylinders barely overlap at 0.15 m spacing and 0.1 m radius, so the
    # points are close to independent): above it the LoD95 would be too small.
    for r in json.loads((quick / "detect.json").read_text())["rows"]:
        n = r["reference_points"]
        assert n > 500
        assert r["false_alarm_rate"] <= 0.05 + 3 * math.sqrt(0.05 * 0.95 / n)


def test_false_alarms_follow_the_observed_spread_against_lod(quick):
    # Why the rate at noise x1 is ~0 % and not 5 %: LoD95 / 1.96 against the observed
    # spread of d on the reference lining (both from the artefact). Where the noise
    # dominates (x30) LoD95 is calibrated (ratio within 25 % of 1) and the rate is the
    # nominal 5 % within 3 binomial standard errors; at the sensor's own noise the
    # cylinders' spreads hold the lining's shape, sampled at the same places in both
    # epochs, so LoD95 is too wide (ratio > 1.2) and the rate falls below 2 %, as the
    # Gaussian expectation 2 Phi(-1.96 ratio) says.
    from scipy.stats import norm

    rows = {r["noise"]: r for r in json.loads((quick / "detect.json").read_text())["rows"]}
    ratio = {k: r["median_lod_m"] / 1.96 / r["reference_sd_m"] for k, r in rows.items()}
    assert abs(ratio[30.0] - 1.0) < 0.25
    n = rows[30.0]["reference_points"]
    assert abs(rows[30.0]["false_alarm_rate"] - 0.05) < 3 * math.sqrt(0.05 * 0.95 / n)
    assert ratio[1.0] > 1.2
    expected = 2 * norm.sf(1.96 * ratio[1.0])
    assert expected < 0.02 and rows[1.0]["false_alarm_rate"] < 0.02


def test_quick_regions_are_on_the_deformation(quick):
    # The target regions really moved by about the magnitude: median M3C2 distance on
    # the convergence plateau within 0.3 mm of it at the sensor's own noise.
    js = json.loads((quick / "detect.json").read_text())
    row = next(r for r in js["rows"] if r["noise"] == 1.0)
    for t in row["targets"]:
        if t["kind"] == "convergence":
            assert t["median_distance_m"] == pytest.approx(t["magnitude_m"], abs=3e-4)
            assert t["points"] > 100


# ---------------------------------------------------------------- seeded runs (API)
@pytest.fixture(scope="module")
def small():
    tun, _ = preset("tbm", edge_length_m=0.25)
    lay = DetectLayout.build(40.0, [0.004], zone_m=1.0, taper_m=0.25, gap_m=0.5,
                       bulge_radius_m=0.4, reference_m=1.0)
    return tun, lay


def _run(small, seed):
    tun, lay = small
    det = Detectability(tun, lay, core_spacing_m=0.2, seed=seed, lead_m=1.0)
    return det.run(load_sensor("zf_imager_5016"), spacing_m=20.0, noise=20.0,
                   resolution="preview").to_dict()


@pytest.mark.slow
def test_seeded_runs_repeat(small):
    a, b = _run(small, 3), _run(small, 3)
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    c = _run(small, 4)
    assert json.dumps(a, sort_keys=True) != json.dumps(c, sort_keys=True)


# ---------------------------------------------------------------- definitions
def _limit_brute(m, p, target):
    """Smallest m_k with p_j >= target for every m_j >= m_k (brute force)."""
    best = float("nan")
    for mk in sorted(m, reverse=True):
        if all(pj >= target for mj, pj in zip(m, p) if mj >= mk):
            best = mk
        else:
            break
    return best


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(1e-4, 0.1), st.floats(0.0, 1.0)), min_size=1,
                max_size=8, unique_by=lambda x: x[0]))
def test_detection_limit_matches_brute_force(pairs):
    m, p = zip(*pairs)
    got, want = detection_limit(m, p), _limit_brute(m, p, POD_TARGET)
    assert (math.isnan(got) and math.isnan(want)) or got == want


def test_detection_limit_nan_share_is_not_detected():
    assert detection_limit([1, 2, 3], [0.5, 0.99, float("nan")]) != 2
    assert math.isnan(detection_limit([1, 2, 3], [0.5, 0.99, float("nan")]))


def test_ahat_a95_against_monte_carlo():
    # d = 0.2 mm + 0.9 a + N(0, 0.5 mm); detection where d > LoD = 1 mm. At the returned
    # a95 a fresh Monte Carlo sample must be detected 95 % of the time (tolerance:
    # 4 binomial standard errors of 200k draws plus the fit's own error, ~0.3 %).
    rng = np.random.default_rng(1)
    a = np.repeat([0.0, 0.001, 0.002, 0.004], 5000)
    d = 2e-4 + 0.9 * a + rng.normal(0, 5e-4, a.size)
    fit = ahat_a95(a, d, np.full(10, 1e-3))
    analytic = (1e-3 + 1.6448536 * 5e-4 - 2e-4) / 0.9
    assert fit["a_pod"] == pytest.approx(analytic, rel=0.02)
    mc = 2e-4 + 0.9 * fit["a_pod"] + rng.normal(0, 5e-4, 200_000) > 1e-3
    assert mc.mean() == pytest.approx(0.95, abs=0.004 + 4 * math.sqrt(0.95 * 0.05 / 2e5))
    assert math.isnan(ahat_a95([0, 0, 0], [1, 2, 3], [1])["a_pod"])


def test_layout_regions_match_the_deformation_fields():
    tun, _ = preset("tbm", edge_length_m=0.25)
    lay = DetectLayout.build(30.0, [0.003, 0.001], zone_m=2.0, taper_m=0.5,
                             bulge_radius_m=0.6)
    assert lay.magnitudes_m == (0.001, 0.003)
    conv, bulge = lay.targets
    assert lay.reference_m[1] <= conv.lo_m < conv.hi_m < bulge.lo_m
    assert bulge.lo_m < bulge.hi_m == lay.end_m
    prof = tun.profile
    per = prof.perimeter_m
    rng = np.random.default_rng(0)
    s = rng.uniform(lay.start_m, lay.end_m, 20000)
    t = rng.uniform(0, per, 20000)
    f = total_field(lay.deformations(0.003), s, t, prof)
    tc = np.array([prof.t_at_angle(a) for a in np.deg2rad((-90, -45, 0, 45, 90))])
    reg_c = conv.region(s, t, per, tc, 0.1)
    reg_b = bulge.region(s, t, per, tc, 0.1)
    assert np.allclose(f[reg_c], 0.003)                     # the plateau: full value
    assert reg_b.any() and np.all(f[reg_b] >= 0.003 * 0.75 - 1e-12)
    ref = (s >= lay.reference_m[0]) & (s < lay.reference_m[1])
    assert np.all(f[ref] == 0)
    assert BULGE_CORE_FRACTION == pytest.approx(1 / 3)


def test_with_noise_scales_range_and_angle():
    spec = load_sensor("zf_profiler_9012")
    s2 = with_noise(spec, 2.5)
    assert s2.physics.range_sigma_m == pytest.approx(2.5 * spec.physics.range_sigma_m)
    assert s2.physics.range_sigma_floor_m == pytest.approx(
        2.5 * spec.physics.range_sigma_floor_m)
    assert s2.physics.angle_sigma_rad == pytest.approx(2.5 * spec.physics.angle_sigma_rad)
    assert s2.physics.range_max_m == spec.physics.range_max_m


# ---------------------------------------------------------------- bad input
@pytest.mark.parametrize("mags, match", [([], "one or more positive magnitudes"),
                                         ([0.002, -0.001], "one or more positive"),
                                         ([0.002, 0.002], "distinct magnitudes")])
def test_bad_magnitudes(mags, match):
    with pytest.raises(StudyError, match=match):
        DetectLayout.build(10.0, mags)


def test_bad_layout_values():
    with pytest.raises(StudyError, match="positive finite `zone_m`"):
        DetectLayout.build(10.0, [0.002], zone_m=0.0)
    with pytest.raises(StudyError, match="finite start chainage"):
        DetectLayout.build(float("nan"), [0.002])


def test_layout_outside_the_tunnel(small):
    tun, _ = small
    with pytest.raises(StudyError, match="inside the tunnel"):
        Detectability(tun, DetectLayout.build(95.0, [0.002]))


def test_not_a_tunnel_mesh(small):
    _, lay = small
    with pytest.raises(StudyError, match="generated TunnelMesh"):
        Detectability(object(), lay)     # type: ignore[arg-type]


@pytest.fixture(scope="module")
def det(small):
    tun, lay = small
    return Detectability(tun, lay, core_spacing_m=0.2, lead_m=1.0)


def test_bad_configurations(det):
    tls, mls = load_sensor("zf_imager_5016"), load_sensor("zf_profiler_9012")
    with pytest.raises(StudyError, match="Expected `spacing_m` as a number, got None"):
        det.run(tls)
    with pytest.raises(StudyError, match="positive finite `speed_mps`"):
        det.run(mls, speed_mps=0.0)
    with pytest.raises(StudyError, match="non-negative finite `noise factor`"):
        det.run(tls, spacing_m=10.0, noise=-1.0)
    with pytest.raises(StudyError, match="Expected speeds for zf_profiler_9012"):
        det.grid([mls], spacings_m=[10.0])
    with pytest.raises(StudyError, match="SensorSpec"):
        det.run("zf_imager_5016", spacing_m=10.0)     # type: ignore[arg-type]


def test_cli_bad_input(tmp_path, capsys):
    assert main(["detect", "--quick", "--magnitudes", "2,x", "-o",
                 str(tmp_path / "a")]) == 2
    assert "--magnitudes (mm) as comma-separated numbers" in capsys.readouterr().err
    assert main(["detect", "--quick", "--sensor", "no_such_sensor", "-o",
                 str(tmp_path / "b")]) == 2
    assert "no_such_sensor" in capsys.readouterr().err
    assert main(["detect", "--quick", "--mesh", str(tmp_path / "t.ply"),
                 "--edge-length", "0.2", "-o", str(tmp_path / "c")]) == 2
    assert "--edge-length only with --preset" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "c").exists()
