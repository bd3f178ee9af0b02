"""Reports a client can take (issue 31, item 5): every report states its inputs with
their SHA-256 (checked against hashlib), the CRS, software, date, project and
instrument; σ0 carries its unit under a label that says what it is (checked against
σ0 recomputed from the residuals); the MDB states its power; the HTML beside the
Markdown is self-contained (the embedded figure decodes to the PNG's bytes)."""

from __future__ import annotations

import base64
import hashlib
import json
import re
from datetime import datetime, timezone
from importlib import metadata

import numpy as np
import pytest
from scipy.stats import norm

from survey.adjust.controlpoints import ControlPoints
from survey.adjust.helmert import from_parameters
from survey.adjust.helmert_stats import ALPHA, DELTA0, POWER
from survey.cli.main import main
from survey.report.html import markdown_to_html, write_report

UTM = np.array([2_600_000.0, 1_200_000.0, 400.0])


def _sha(p) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def _files(tmp_path, sigma: bool, crs: str | None = None):
    rng = np.random.default_rng(3)
    src = UTM + rng.uniform([-50, -30, -4], [50, 30, 4], (9, 3))
    dst = from_parameters([3.0, -2.0, 0.1], [5.0, 2.0, -40.0], 8.0).apply(src)
    dst = dst + rng.normal(0.0, 0.002, dst.shape)
    ids = [f"S{i}" for i in range(9)]
    ControlPoints(ids, src).write(tmp_path / "mls.csv")
    ControlPoints(ids, dst, np.full((9, 3), 0.002) if sigma else None).write(
        tmp_path / "ts.csv")
    if crs is not None:
        for f in ("mls.csv", "ts.csv"):
            p = tmp_path / f
            p.write_text(f"# crs: {crs}\n" + p.read_text())
    return tmp_path / "mls.csv", tmp_path / "ts.csv"


def _run_adjust(tmp_path, *extra, sigma=True, crs=None):
    a, b = _files(tmp_path, sigma, crs)
    assert main(["adjust", str(a), str(b), "--report", str(tmp_path / "adjust.md"),
                 "--json", str(tmp_path / "h.json"), "--quiet", *extra]) == 0
    md = (tmp_path / "adjust.md").read_text(encoding="utf-8")
    return a, b, md, json.loads((tmp_path / "h.json").read_text())


def test_adjust_report_header_states_inputs_crs_software_and_user_words(tmp_path):
    pytest.importorskip("pyproj")
    a, b, md, res = _run_adjust(tmp_path, "--project", "Lot 3 Nord", "--instrument",
                                "TS16 SN 123456", crs="EPSG:2056")
    for p in (a, b):
        assert f"`{_sha(p)}`" in md and f"`{p}`" in md
    assert "| project | Lot 3 Nord |" in md and "| instrument | TS16 SN 123456 |" in md
    assert "LV95" in md.split("## Parameters")[0]        # the CRS, in the header
    assert f"tunnelsim {metadata.version('tunnelsim')}" in md
    stamp = re.search(r"\| computed \(UTC\) \| (\S+) \|", md).group(1)
    when = datetime.strptime(stamp, "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=timezone.utc)
    assert abs((datetime.now(timezone.utc) - when).total_seconds()) < 3600
    assert [i["sha256"] for i in res["inputs"]] == [_sha(a), _sha(b)]
    assert res["project"] == "Lot 3 Nord"
    # without the options the header says so: the options change the file
    (tmp_path / "x").mkdir()
    md2 = _run_adjust(tmp_path / "x")[2]
    assert "not given (--project)" in md2 and "Lot 3 Nord" not in md2
    assert "| coordinate reference system | none stated |" in md2


def test_sigma0_with_given_sigmas_is_a_unitless_ratio_and_variance_factor(tmp_path):
    _, _, md, res = _run_adjust(tmp_path, sigma=True)
    v = np.asarray(res["residuals"])
    s0 = np.sqrt(np.sum((v / 0.002) ** 2) / res["dof"])        # vᵀPv / r, P = 1/σ²
    assert res["sigma0"] == pytest.approx(s0, rel=1e-9)
    assert res["sigma0_unit"] == "1" and res["variance_factor"] == pytest.approx(s0 ** 2)
    assert f"σ0 a posteriori (ratio of actual to stated precision): {s0:.4f} (unitless)" in md
    assert f"Variance factor σ0² (a posteriori / a priori): {s0 ** 2:.4f} (unitless)" in md
    assert "σ0 a priori: 1 (unitless" in md
    assert "MDB (mm, power 80 %, α0 0.1 %)" in md and "δ0 = 4.13" in md


def test_sigma0_with_unit_weights_is_in_metres(tmp_path):
    _, _, md, res = _run_adjust(tmp_path, sigma=False)
    v = np.asarray(res["residuals"])
    s0 = np.sqrt(np.sum(v ** 2) / res["dof"])
    assert res["sigma0_unit"] == "m" and res["variance_factor"] is None
    assert f"{s0:.6f} m = {s0 * 1000:.2f} mm" in md
    assert "Variance factor: not defined" in md
    assert "(unitless)" in md.split("## Residuals")[1]       # redundancy and τ columns
    # MDB column against Baarda's formula: σ0 δ0 / sqrt(r_i), largest of x, y, z
    r = np.asarray(res["redundancy"])
    mdb = (s0 * DELTA0 / np.sqrt(r)).max(axis=1)
    np.testing.assert_allclose(res["mdb_m"], mdb, rtol=1e-9)


def test_delta0_is_baardas_value_for_alpha_and_power():
    # Baarda 1968: delta0 = Phi^-1(1 - alpha0/2) + Phi^-1(1 - beta0)
    assert norm.ppf(1 - ALPHA / 2) + norm.ppf(POWER) == pytest.approx(DELTA0, abs=0.005)


def test_adjust_html_is_self_contained_and_says_the_same(tmp_path):
    a, b, md, _ = _run_adjust(tmp_path)
    html = (tmp_path / "adjust.html").read_text(encoding="utf-8")
    assert html.startswith("<!DOCTYPE html>")
    assert not re.search(r"(?:src|href)=\"(?!data:)", html)
    assert "http://" not in html and "https://" not in html
    assert _sha(a) in html and _sha(b) in html
    for row in ("tx (m)", "σ0 a posteriori", "MDB (mm, power 80 %"):
        assert row in html


def test_html_embeds_the_figure_bytes(tmp_path):
    png = tmp_path / "fig.png"
    from survey.report.plotting import pyplot, save_png

    plt = pyplot()
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    save_png(fig, png)
    md, html_path = write_report(tmp_path / "r.md",
                                 "# T\n\n| a (m) | b |\n|---|---:|\n| 1 | 2 |\n\n"
                                 "- item `code`\n\n![plot](fig.png)\n")
    html = html_path.read_text(encoding="utf-8")
    m = re.search(r'src="data:image/png;base64,([^"]+)"', html)
    assert m and base64.b64decode(m.group(1)) == png.read_bytes()
    assert "<th>a (m)</th>" in html and '<td class="r">2</td>' in html
    assert "<li>item <code>code</code></li>" in html
    # a missing figure is said, not linked
    out = markdown_to_html("![gone](nothere.png)", base=tmp_path)
    assert "not found" in out and "src=" not in out


def test_convergence_report_names_epochs_band_and_step(tmp_path):
    t, t2 = tmp_path / "t.ply", tmp_path / "t2.ply"
    assert main(["tunnel", "--preset", "tbm", "--edge-length", "0.1", "-o", str(t),
                 "--epoch2", str(t2), "--quiet"]) == 0
    out = tmp_path / "conv"
    assert main(["convergence", str(t), str(t2), "--tunnel", str(t.with_suffix(".json")),
                 "--at", "50", "--band", "0.3", "--angle-step", "10", "--project", "P7",
                 "-o", str(out), "--quiet"]) == 0
    md = (out / "convergence.md").read_text(encoding="utf-8")
    assert "Epochs: earlier t.ply, later t2.ply." in md
    assert "±0.3 m" in md and "bins of 10°" in md
    assert "| angle step | 10° |" in md and "| band (half-width along the axis) | 0.3 m |" in md
    for p in (t, t2, t.with_suffix(".json")):
        assert _sha(p) in md
    html = (out / "convergence.html").read_text(encoding="utf-8")
    m = re.search(r'src="data:image/png;base64,([^"]+)"', html)
    assert m and base64.b64decode(m.group(1)) == (out / "radial.png").read_bytes()
    summ = json.loads((out / "convergence.json").read_text())
    assert summ["band_m"] == 0.3 and summ["angle_step_deg"] == 10.0


def test_with_header_puts_the_block_below_the_title(tmp_path):
    from survey.report.header import ReportHeader, ReportInput, with_header

    f = tmp_path / "cloud.laz"
    f.write_bytes(b"abc")
    head = ReportHeader(inputs=[ReportInput.of("cloud", f)], crs="EPSG:2056",
                        project="P", instrument="I")
    text = with_header("# Distances\n\n| a | b |\n|---|---:|\n| 1 | 2 |\n", head)
    lines = text.splitlines()
    assert lines[0] == "# Distances" and lines[2] == "| report | |"
    assert hashlib.sha256(b"abc").hexdigest() in text
    assert text.index("SHA-256") < text.index("| a | b |")
    assert with_header("x\n", None) == "x\n"


def test_compare_report_states_inputs_crs_units_and_embeds_its_histogram(tmp_path):
    # compare's stats.md/.html (wired through survey.cli.common.write_headed_report):
    # both inputs with their SHA-256, the CRS the clouds state, every statistic in mm,
    # and the HTML carries the histogram's own bytes.
    pytest.importorskip("pyproj")
    import laspy

    from sensors.io.las import set_las_crs

    rng = np.random.default_rng(5)
    paths = []
    for name, dz in (("cmp.las", 0.004), ("ref.las", 0.0)):
        xyz = UTM + rng.uniform([0, 0, 0], [20, 20, 0.001], (3000, 3)) + [0, 0, dz]
        h = laspy.LasHeader(point_format=6, version="1.4")
        h.offsets, h.scales = UTM, [1e-4] * 3
        set_las_crs(h, "EPSG:2056")
        las = laspy.LasData(h)
        las.x, las.y, las.z = xyz.T
        las.write(tmp_path / name)
        paths.append(tmp_path / name)
    out = tmp_path / "cmp"
    assert main(["compare", *map(str, paths), "-o", str(out), "--quiet",
                 "--project", "Lot 7"]) == 0
    md = (out / "stats.md").read_text(encoding="utf-8")
    for p in paths:
        assert _sha(p) in md
    assert "Lot 7" in md and "2056" in md
    head = next(ln for ln in md.splitlines() if ln.startswith("| C2C"))
    assert all(col.strip().endswith("(mm)") for col in head.strip("|").split("|")[2:])
    html = (out / "stats.html").read_text(encoding="utf-8")
    assert not re.search(r"""(src|href)=["']https?:""", html)
    embedded = re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", html)
    assert base64.b64decode(embedded[0]) == (out / "histogram.png").read_bytes()
