"""``tunnelsim develop`` and ``tunnelsim clearance`` against their library functions
(issue 32), notebook style: the CLI in-process and ``survey.workflows.inspection`` on
the same small tunnel (12 m, r = 3 m, one 5 cm inward bulge at chainage 6 m) in two
folders give the same files byte for byte. The one difference allowed is the time the
report header states ("computed (UTC)", in developed/clearance .md and .html): it is
replaced by a marker in both before comparing. The results' numbers are checked
against the files (the raster's NPY, regions.csv, clearance.json) and against the
lines the CLI prints."""

from __future__ import annotations

import csv
import json
import re

import numpy as np
import pytest

from survey.cli.main import main
from survey.errors import CompareError
from survey.workflows.inspection import clearance_files, develop_files
from survey.world.alignment import Alignment, straight
from survey.world.deformation import Bulge
from survey.world.generator import make_tunnel
from survey.world.mesh import write_tunnel
from survey.world.profiles import circle

R = 3.0
BULGE = Bulge(chainage_m=6.0, angle_rad=0.5, radius_m=1.0, amplitude_m=0.05)
STAMP = re.compile(rb"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ")


@pytest.fixture(scope="module")
def bulged(tmp_path_factory):
    """The bulged tunnel's PLY, with its JSON beside it."""
    al = Alignment([straight(12.0)], start_xy=(512_345.678, 5_345_678.901),
                   heading_rad=0.3, profile=((0.0, 400.0),))
    tun = make_tunnel(al, circle(R), edge_length_m=0.2, roughness_rms_m=0.0)
    ply = tmp_path_factory.mktemp("bulged") / "t.ply"
    write_tunnel(tun.deformed([BULGE]), ply)
    return ply


def _same_folders(a, b):
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir()) and names
    for n in names:
        x, y = (a / n).read_bytes(), (b / n).read_bytes()
        if n.endswith((".md", ".html")):
            assert len(STAMP.findall(x)) == 1, n      # exactly the header's time
            x, y = STAMP.sub(b"<time>", x), STAMP.sub(b"<time>", y)
        assert x == y, f"{n} differs between the CLI and the library"
    return names


def test_develop_cli_and_library_write_the_same_files(bulged, tmp_path, capsys):
    cli, lib = tmp_path / "cli", tmp_path / "lib"
    tj = bulged.with_suffix(".json")
    assert main(["develop", str(bulged), "--tunnel-json", str(tj), "--cell", "0.25",
                 "--tile-m", "4", "--tolerance", "-40,-10,0,10", "--project", "Lot 3",
                 "-o", str(cli)]) == 0
    said = capsys.readouterr().out.splitlines()
    r = develop_files(bulged, lib, tunnel=tj, cell_m=0.25, tile_m=4.0,
                      tolerance_mm=[-40, -10, 0, 10], project="Lot 3")
    names = _same_folders(cli, lib)
    assert {f.name for f in r.files} == set(names)
    assert r.figures == tuple(sorted(n for n in names if n.endswith(".png")))
    # The numbers the result holds are the files' and the printed lines'.
    assert r.report == (lib / "developed.md").read_text(encoding="utf-8")
    assert "| project | Lot 3 |" in r.report
    tiles = [json.loads((lib / n).read_text()) for n in names
             if n.endswith(".json")]
    assert sum(int(np.isfinite(np.load(lib / t["file"])).sum()) for t in tiles) == \
        int((r.raster.count > 0).sum())
    assert r.share_with_data == pytest.approx((r.raster.count > 0).mean())
    assert said[0] == (f"developed deviation (mean): {r.points:,} points in {r.rows} x "
                       f"{r.columns} cells, {100 * r.share_with_data:.0f} % with data, "
                       f"3 tiles -> {cli}/")
    assert said[1:] == [r.cell_chosen, r.scale_line]
    assert r.scale_line.startswith("colour classes at -40, -10, 0, 10 mm")
    # The deepest cell is the bulge: 5 cm inward (a negative deviation).
    assert np.nanmin(r.raster.statistic("mean")) == pytest.approx(-0.05, abs=5e-3)


@pytest.mark.parametrize("envelope, violated", [("box:4.2,4.0,1.0", False), (None, True)])
def test_clearance_cli_and_library_write_the_same_files(bulged, tmp_path, capsys,
                                                        envelope, violated):
    if envelope is None:      # a circle 3 cm inside the lining: the bulge enters it
        env = tmp_path / "envelope.csv"
        a = np.linspace(0, 2 * np.pi, 360, endpoint=False)
        np.savetxt(env, np.stack([(R - 0.03) * np.cos(a), R + (R - 0.03) * np.sin(a)], 1),
                   delimiter=",", header="y,z", comments="")
        envelope = str(env)
    cli, lib = tmp_path / "cli", tmp_path / "lib"
    assert main(["clearance", str(bulged), "--envelope", envelope, "--cell", "0.2",
                 "--merge-gap", "0", "--instrument", "mesh", "-o", str(cli)]) == 0
    said = capsys.readouterr().out.splitlines()
    r = clearance_files(bulged, lib, envelope=envelope, cell_m=0.2, merge_gap_m=0.0,
                        instrument="mesh")
    names = _same_folders(cli, lib)
    assert {f.name for f in r.files} == set(names)
    rows = list(csv.DictReader((lib / "regions.csv").open()))
    js = json.loads((lib / "clearance.json").read_text())
    assert r.regions == len(rows) == len(js["regions"])
    assert "| instrument | mesh |" in r.report
    if violated:
        # 5 cm bulge into an envelope 3 cm inside the lining: 2 cm deep, at 6 m.
        assert r.regions == 1 and r.max_depth_m == pytest.approx(0.02, abs=1e-3)
        # regions.csv states the depth to 0.01 mm.
        assert r.max_depth_m == pytest.approx(float(rows[0]["max_depth_m"]), abs=1e-5)
        assert r.deepest_chainage_m == pytest.approx(6.0, abs=0.2)
        assert said == [f"clearance against '{r.envelope_name}': 1 violation region, "
                        f"deepest {1000 * r.max_depth_m:.1f} mm at chainage "
                        f"{r.deepest_chainage_m:.3f} m -> {cli}/", r.cell_chosen,
                        r.merge_line]
    else:
        assert r.regions == 0 and r.deepest_chainage_m is None
        assert r.min_margin_m == pytest.approx(js["min_margin_m"]) and r.min_margin_m > 0
        assert said == [f"clearance against '{r.envelope_name}': clear, smallest margin "
                        f"{1000 * r.min_margin_m:.1f} mm -> {cli}/"]


def test_library_and_cli_refuse_alike(bulged, tmp_path, capsys):
    """The library raises the message the command prints (it names the options)."""
    with pytest.raises(CompareError, match=r"^Expected --tile-m a whole multiple of "
                                           r"--cell \(0.3 m\), got 1 m\.$"):
        develop_files(bulged, tmp_path / "a", cell_m=0.3, tile_m=1.0)
    assert main(["develop", str(bulged), "--cell", "0.3", "--tile-m", "1", "-o",
                 str(tmp_path / "b")]) == 2
    assert capsys.readouterr().err.strip() == ("tunnelsim: error: Expected --tile-m a "
                                               "whole multiple of --cell (0.3 m), got 1 m.")
    with pytest.raises(CompareError, match="--tolerance edges increasing"):
        develop_files(bulged, tmp_path / "c", tolerance_mm=[5, 1])
    with pytest.raises(CompareError, match="--required >= 0 m"):
        clearance_files(bulged, tmp_path / "d", envelope="box:4,4", required_m=-1.0)
    assert not (tmp_path / "a").exists() and not (tmp_path / "d").exists()
