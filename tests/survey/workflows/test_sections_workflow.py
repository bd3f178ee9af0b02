"""``survey.workflows.axis`` and ``survey.workflows.sections`` (issue 32): ``axis_file``,
``sections_files`` and ``rings_files`` write the files ``tunnelsim axis``, ``sections``
and ``rings`` write. Notebook-style: the command (in-process) in one folder, the library
with the same options in another, the files compared byte for byte. The reports
(report.md/.html, rings.md/.html) state the time they were computed in their header
("computed (UTC)"): that time stamp is masked, every other byte compared.

The cloud is a cone about a known straight alignment: its radius grows linearly with
the chainage (``_radius``), so every number the results carry has an analytic value.
"""

from __future__ import annotations

import contextlib
import io
import json
import re

import numpy as np
import pytest

from survey.cli.main import main
from survey.world.alignment import Alignment, straight

E0, N0, H0 = 2_600_000.0, 1_200_000.0, 500.0
LENGTH_M = 40.0
R0, SLOPE = 3.0, 0.005     # radius at the true start (m), growth per metre
R_DESIGN = 2.9              # the design circle: inside the whole lining
CH0 = 1000.0                # the user's chainage at the true start
N_POINTS = 20_000
#: The ISO time stamp the report header states.
STAMP = re.compile(rb"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ")


def _radius(s):
    return R0 + SLOPE * np.asarray(s)


def _run(argv):
    """(exit status, stdout) of ``tunnelsim`` in-process."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue()


def _same_files(a, b, stamped=()):
    """The folders hold the same files with the same bytes (``stamped``: the time stamp
    masked)."""
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    for n in names:
        x, y = (a / n).read_bytes(), (b / n).read_bytes()
        if n in stamped:
            assert len(STAMP.findall(x)) == 1, n
            x, y = STAMP.sub(b"T", x), STAMP.sub(b"T", y)
        assert x == y, n
    return names


@pytest.fixture(scope="module")
def cone(tmp_path_factory):
    """(true alignment, cloud .npz, design circle CSV, folder): lining points on a
    golden-angle helix (evenly spread in angle along any stretch)."""
    d = tmp_path_factory.mktemp("cone")
    al = Alignment([straight(LENGTH_M)], start_xy=(E0, N0), heading_rad=0.3,
                   profile=((0.0, H0),))
    k = np.arange(N_POINTS)
    s = (k + 0.5) * LENGTH_M / N_POINTS
    phi = np.mod(k * np.pi * (3.0 - np.sqrt(5.0)), 2 * np.pi) - np.pi
    p = al.to_world(s, _radius(s) * np.sin(phi), _radius(s) * np.cos(phi))
    np.savez(d / "scan.npz", x=p[:, 0], y=p[:, 1], z=p[:, 2])
    a = np.linspace(0, 2 * np.pi, 4001)
    np.savetxt(d / "design.csv", np.stack([R_DESIGN * np.sin(a), R_DESIGN * np.cos(a)], 1),
               delimiter=",", header="y,z", comments="")
    return al, d / "scan.npz", d / "design.csv", d


@pytest.fixture(scope="module")
def axis_json(cone):
    """The command's and the library's axis of the cone, with chainage CH0 at the true
    start: (command's JSON, library's result, printed line)."""
    from survey.workflows.axis import axis_file

    al, cloud, _, d = cone
    x, y = (float(v) for v in al.point(0.0)[:2])
    (d / "cli").mkdir()
    (d / "lib").mkdir()
    rc, printed = _run(["axis", cloud, "-o", d / "cli/t.json", "--start", f"{x!r},{y!r}",
                        "--chainage-at", CH0])
    assert rc == 0
    r = axis_file(cloud, d / "lib/t.json", start_xy=(x, y), chainage_at_m=CH0)
    return d / "cli/t.json", r, printed


def test_axis_is_the_commands(cone, axis_json):
    """The same JSON bytes; the result's numbers are the JSON's and the cone's."""
    from survey.world.alignment_io import load_tunnel

    al, cloud, _, d = cone
    cli_json, r, printed = axis_json
    assert cli_json.read_bytes() == r.output.read_bytes()
    meta = json.loads(r.output.read_text())
    assert meta["datum"] == dict(r.datum) and r.datum["kind"] == "start"
    assert meta["fit"]["points_used"] == r.points_used == N_POINTS
    back = load_tunnel(r.output).alignment
    assert back.chainage_range == pytest.approx((r.chainage_start_m, r.chainage_end_m))
    # The axis covers the cone from its true start (chainage CH0) to its end, and runs
    # through its centre: the fitted circle of the profile has the mean radius.
    assert r.chainage_start_m == pytest.approx(CH0, abs=0.05)
    assert r.length_m == pytest.approx(LENGTH_M, abs=0.1)
    assert np.hypot(*(np.array(r.start_point[:2]) - al.point(0.0)[:2])) < 0.05
    assert r.mean_radius_m == pytest.approx(_radius(LENGTH_M / 2), abs=0.01)
    assert printed.strip() == (
        f"axis of {r.length_m:.1f} m: chainage {r.chainage_start_m:.3f} at "
        f"({r.start_point[0]:.3f}, {r.start_point[1]:.3f}) to {r.chainage_end_m:.3f} at "
        f"({r.end_point[0]:.3f}, {r.end_point[1]:.3f}); --start lies "
        f"{r.datum['start_offset_m']:.3f} m off the axis; profile '{r.profile.name}' "
        f"(mean radius {r.mean_radius_m:.3f} m) -> {cli_json}")


def test_sections_are_the_commands(cone, axis_json, tmp_path):
    """Sections at two chainages against the design circle, with plots: the same
    files; the deviations and volumes are the cone's."""
    from survey.workflows.sections import sections_files

    al, cloud, design, _ = cone
    js = axis_json[0]
    rc, printed = _run(["sections", cloud, "--tunnel-json", js, "--at", "1015,1030",
                        "--width", "0.1", "--design", design, "--project", "Lot 3",
                        "-o", tmp_path / "cli"])
    assert rc == 0
    r = sections_files(cloud, tmp_path / "lib", tunnel_json=js, at_m=[1015.0, 1030.0],
                       width_m=0.1, design=design, project="Lot 3")
    names = _same_files(tmp_path / "cli", tmp_path / "lib",
                        stamped=("report.md", "report.html"))
    assert sorted(p.name for p in r.files) == names
    assert [n for n in names if n.endswith(".png")] == ["section_1+015.000.png",
                                                       "section_1+030.000.png"]
    # Against the cone: every deviation from the design circle is r(s) - R_DESIGN.
    ch = np.array([s.chainage_m for s in r.report.sections])
    np.testing.assert_allclose(ch, [CH0 + 15.0, CH0 + 30.0])
    for s in r.report.sections:
        assert s.mean_m == pytest.approx(_radius(s.chainage_m - CH0) - R_DESIGN, abs=0.002)
    # Average end areas between the sections: the exact integral of
    # pi (r(s)^2 - R_DESIGN^2) differs by pi SLOPE^2 L^3 / 6 = 0.1 mm^3 (r is linear).
    want = np.pi / (3 * SLOPE) * ((_radius(30.0) ** 3 - _radius(15.0) ** 3)) - \
        np.pi * R_DESIGN ** 2 * 15.0
    assert r.overbreak_m3 == pytest.approx(want, rel=0.01) and r.underbreak_m3 < 1e-3
    worst = max(r.report.sections, key=lambda s: s.max_m)
    assert (r.largest_overbreak_m, r.largest_overbreak_chainage_m) == \
        (worst.max_m, worst.chainage_m)
    assert r.sections == 2 and r.design_name == "design"
    assert printed.strip() == (
        f"2 sections against 'design': overbreak {r.overbreak_m3:.3f} m^3, underbreak "
        f"{r.underbreak_m3:.3f} m^3; largest overbreak {1000 * r.largest_overbreak_m:.0f} "
        f"mm at {r.largest_overbreak_chainage_m:g} m -> {tmp_path / 'cli'}/")


def test_rings_on_a_fitted_axis_are_the_commands(cone, tmp_path):
    """rings --fit-axis with the user's chainage and --min-height (the floor from each
    section's lowest points): the same files; diameters and floors are the cone's."""
    from survey.workflows.sections import rings_files

    al, cloud, _, _ = cone
    x, y = (float(v) for v in al.point(0.0)[:2])
    rc, printed = _run(["rings", cloud, "--fit-axis", "--start", f"{x!r},{y!r}",
                        "--chainage-at", CH0, "--at", "1010,1030", "--width", "0.1",
                        "--min-height", "0.5", "--seed", "3", "-o", tmp_path / "cli"])
    assert rc == 0
    r = rings_files(cloud, tmp_path / "lib", fit_axis=True, start_xy=(x, y),
                    chainage_at_m=CH0, at_m=[1010.0, 1030.0], width_m=0.1,
                    min_height_m=0.5, seed=3)
    names = _same_files(tmp_path / "cli", tmp_path / "lib",
                        stamped=("rings.md", "rings.html"))
    assert names == ["rings.csv", "rings.html", "rings.json", "rings.md", "rings.png"]
    rows = json.loads((tmp_path / "lib/rings.json").read_text())
    for ring, row, true_s in zip(r.rings, rows, (10.0, 30.0)):
        assert ring.chainage_m == row["chainage_m"] == pytest.approx(CH0 + true_s)
        assert ring.circle.diameter_m == pytest.approx(2 * _radius(true_s), abs=0.004)
    assert r.min_diameter_m == pytest.approx(2 * _radius(10.0), abs=0.004)
    assert r.max_diameter_m == pytest.approx(2 * _radius(30.0), abs=0.004)
    assert r.max_ovality < 1e-3 and r.poor_fits == 0
    # The floor of a fitted axis through the centre: the lowest points, about -r.
    assert [row["floor_height_m"] for row in rows] == list(r.floor_heights_m)
    for f, true_s in zip(r.floor_heights_m, (10.0, 30.0)):
        assert f == pytest.approx(-_radius(true_s), abs=0.01)
    lines = printed.strip().splitlines()
    assert lines[0] == ("--min-height 0.5 m above the floor: each section's lowest points "
                        f"(its 1st percentile of heights), at {r.floor_median_m:.3f} m in "
                        "the section frame (median)")
    assert lines[1] == (f"2 rings: diameters {1000 * r.min_diameter_m:.1f} to "
                        f"{1000 * r.max_diameter_m:.1f} mm, largest ovality "
                        f"{100 * r.max_ovality:.3f} % -> {tmp_path / 'cli'}/")


@pytest.mark.parametrize("command, argv, call", [
    ("sections", ["--tunnel-json", "JS"],
     lambda f, c, o, js: f.sections_files(c, o, tunnel_json=js)),
    ("sections", ["--tunnel-json", "JS", "--fit-axis", "--every", "10"],
     lambda f, c, o, js: f.sections_files(c, o, tunnel_json=js, fit_axis=True,
                                          every_m=10.0)),
    ("rings", ["--tunnel-json", "JS", "--every", "10", "--rail-height", "0.2"],
     lambda f, c, o, js: f.rings_files(c, o, tunnel_json=js, every_m=10.0,
                                       rail_height_m=0.2)),
    ("rings", ["--tunnel-json", "JS", "--every", "10", "--start", "1,2"],
     lambda f, c, o, js: f.rings_files(c, o, tunnel_json=js, every_m=10.0,
                                       start_xy=(1.0, 2.0))),
    ("sections", ["--tunnel-json", "JS", "--every", "10", "--width", "-1"],
     lambda f, c, o, js: f.sections_files(c, o, tunnel_json=js, every_m=10.0,
                                          width_m=-1.0)),
    ("rings", ["--tunnel-json", "JS", "--every", "10", "--classes", "64.5"],
     lambda f, c, o, js: f.rings_files(c, o, tunnel_json=js, every_m=10.0,
                                       classes=[64.5])),
])
def test_errors_are_the_commands(cone, axis_json, tmp_path, capsys, command, argv, call):
    """The library refuses what the command refuses, with the command's one-line
    message, and leaves no output folder."""
    from survey.errors import TunnelsimError
    from survey.workflows import sections as f

    _, cloud, _, _ = cone
    js = str(axis_json[0])
    argv = [js if a == "JS" else a for a in argv]
    assert main([command, str(cloud), *argv, "-o", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err.strip()
    with pytest.raises(TunnelsimError) as exc:
        call(f, cloud, tmp_path / "l", js)
    assert err == f"tunnelsim: error: {' '.join(str(exc.value).split())}"
    assert not (tmp_path / "c").exists() and not (tmp_path / "l").exists()


def test_axis_errors_are_the_commands(cone, tmp_path, capsys):
    from survey.errors import AlignmentError
    from survey.workflows.axis import axis_file

    _, cloud, _, _ = cone
    for argv, kw in ((["-o", tmp_path / "t.txt"], {}),
                     (["-o", tmp_path / "no/t.json"], {}),
                     (["-o", tmp_path / "t.json", "--alignment", cloud, "--chainage-at", "5"],
                      dict(alignment=cloud, chainage_at_m=5.0))):
        assert main(["axis", str(cloud), *map(str, argv)]) == 2
        err = capsys.readouterr().err.strip()
        with pytest.raises(AlignmentError) as exc:
            axis_file(cloud, argv[1], **kw)
        assert err == f"tunnelsim: error: {' '.join(str(exc.value).split())}"
    assert not (tmp_path / "t.json").exists()
