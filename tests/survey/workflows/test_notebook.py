"""Issue 32's notebook: a tunnel, a drive in two epochs, a mesh from the drive, C2M and
M3C2 — once through ``survey.workflows`` only (as a notebook user would), once through
the ``tunnelsim`` commands — and every file the two write is the same, byte for byte.

The differences allowed: the reports' ``computed (UTC)`` header line (the clock; it is
there in both and masked before comparing), and the folder the inputs sit in, which
reports and JSON name (each chain's folder is replaced by one placeholder). Each step of the library chain reads
the library's own files of the step before, and each CLI step the CLI's, so a drift
anywhere shows at the step where it starts.
"""

from __future__ import annotations

from pathlib import Path

from survey.cli.main import main


TIME_LINE = b"computed (UTC)"


def _files(folder: Path) -> dict[str, bytes]:
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            data = p.read_bytes().replace(str(folder).encode(), b"<FOLDER>")
            if p.suffix in (".md", ".html"):
                lines = data.splitlines(keepends=True)
                assert sum(TIME_LINE in ln for ln in lines) <= 1, p
                data = b"".join(ln for ln in lines if TIME_LINE not in ln)
            out[str(p.relative_to(folder))] = data
    return out


def test_the_library_chain_writes_what_the_commands_write(tmp_path):
    from survey.workflows import compare_files, drive_to_file, m3c2_to_file, mesh_files
    from survey.workflows import tunnel_files

    lib, cli = tmp_path / "lib", tmp_path / "cli"
    lib.mkdir()
    cli.mkdir()

    # 1. A tunnel and a second epoch converged by 20 mm between chainages 20 and 40 m.
    tunnel_files(lib / "t.ply", preset="tbm", edge_length_m=0.4, epoch2=lib / "t2.ply",
                 convergence=[(20.0, 40.0, 20.0)], seed=3)
    assert main(["tunnel", "--preset", "tbm", "--edge-length", "0.4", "--epoch2",
                 str(cli / "t2.ply"), "--convergence", "20:40:20", "--seed", "3", "-o",
                 str(cli / "t.ply")]) == 0

    # 2. The same drive through both epochs (a VLP-16 on the centreline, 2 s at 1 m/s).
    for name, mesh in (("d1.laz", "t.ply"), ("d2.laz", "t2.ply")):
        drive_to_file(lib / mesh, lib / name, sensor="velodyne_vlp16", along="centreline",
                      speed_mps=1.0, duration_s=2.0, seed=5)
        assert main(["drive", "--mesh", str(cli / mesh), "--sensor", "velodyne_vlp16",
                     "--along", "centreline", "--speed", "1", "--duration", "2",
                     "--seed", "5", "-o", str(cli / name)]) == 0

    # 3. A mesh from the first drive, along the tunnel's axis.
    m = mesh_files(lib / "d1.laz", lib / "m.ply", method="tunnel",
                   tunnel_json=lib / "t.json", cell_m=0.5, cell_deg=5.0)
    assert main(["mesh", str(cli / "d1.laz"), "--method", "tunnel", "--tunnel-json",
                 str(cli / "t.json"), "--cell", "0.5,5", "-o", str(cli / "m.ply")]) == 0
    assert m.triangles > 1000

    # 4. C2M: the second drive against the mesh of the first.
    c = compare_files([lib / "d2.laz"], lib / "m.ply", lib / "c2m")
    assert main(["compare", str(cli / "d2.laz"), str(cli / "m.ply"), "-o",
                 str(cli / "c2m"), "--quiet"]) == 0

    # 5. M3C2 between the epochs, normals towards the axis.
    r = m3c2_to_file(lib / "d1.laz", lib / "d2.laz", lib / "m3c2.laz", cyl_radius_m=0.3,
                     max_depth_m=0.2, core_spacing_m=1.0, orientation="axis",
                     tunnel=lib / "t.json")
    assert main(["m3c2", str(cli / "d1.laz"), str(cli / "d2.laz"), "--cyl-radius", "0.3",
                 "--max-depth", "0.2", "--core-spacing", "1", "--orient", "axis",
                 "--tunnel", str(cli / "t.json"), "-o", str(cli / "m3c2.laz")]) == 0

    a, b = _files(lib), _files(cli)
    assert sorted(a) == sorted(b)
    differ = [name for name in a if a[name] != b[name]]
    assert not differ, f"library and CLI files differ: {differ}"
    # The results hold what the files say.
    import json

    assert json.loads((lib / "m3c2.json").read_text())["core_points"] == \
        r.summary["core_points"] > 0
    assert f"{c.stats['d2']['rms']:.6f}" in (lib / "c2m" / "stats.csv").read_text()
