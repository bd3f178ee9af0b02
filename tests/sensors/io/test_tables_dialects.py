"""Control-point tables in the dialects surveyors' software writes (issue 31, item 2),
read through the real CLI: the Helmert result from each dialect must be identical to
the one from the plain ``id,x,y,z`` file of the same numbers (the reference), and a
file that cannot be mapped must fail with one line naming what was found and the
option (``--columns``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sensors.io.errors import TableFileError
from sensors.io.tables import decode_text, parse_columns, sniff, to_float
from survey.adjust.controlpoints import read_control_points
from survey.adjust.helmert import from_parameters
from survey.cli.main import main
from survey.errors import ControlPointError

UTM = np.array([2_600_000.0, 1_200_000.0, 400.0])


def _points(n: int = 8, seed: int = 0):
    rng = np.random.default_rng(seed)
    src = UTM + rng.uniform([-60, -40, -5], [60, 40, 5], (n, 3))
    dst = from_parameters([12.0, -7.0, 0.4], [10.0, -5.0, 200.0], 15.0).apply(src)
    dst = dst + rng.normal(0.0, 0.003, dst.shape)
    return [f"P{i:02d}" for i in range(n)], src, dst


def _write(path, ids, xyz, *, delim=",", decimal=".", header=("id", "x", "y", "z"),
           encoding="utf-8", sigma=None):
    """The test's own writer: every number as repr (exact round trip), the decimal
    point replaced where asked."""
    rows = []
    if header is not None:
        rows.append(delim.join(header))
    for k, (i, p) in enumerate(zip(ids, xyz)):
        vals = [repr(float(v)) for v in p] + ([] if sigma is None else [repr(sigma[k])])
        if decimal == ",":
            vals = [v.replace(".", ",") for v in vals]
        rows.append(delim.join([i] + vals))
    path.write_bytes(("\n".join(rows) + "\n").encode(encoding))
    return path


def _adjust(*args):
    return main(["adjust", *map(str, args), "--quiet"])


DIALECTS = {
    "german_latin1": dict(delim=";", decimal=",", encoding="latin-1",
                          header=("Punkt", "Rechtswert", "Hochwert", "Höhe")),
    "tab": dict(delim="\t", header=("Name", "E", "N", "H")),
    "headerless": dict(header=None),
    "name_e_n_h": dict(header=("Name", "E", "N", "H")),
    "whitespace_decimal_comma": dict(delim="  ", decimal=",", header=None),
    "utf8_bom_units": dict(encoding="utf-8-sig",
                           header=("Point ID", "Easting [m]", "Northing [m]", "Height [m]")),
    "utf16_excel": dict(delim="\t", encoding="utf-16", header=("Nr", "Ost", "Nord", "Höhe")),
    "cp1252_semicolon_point": dict(delim=";", encoding="cp1252",
                                   header=("Punktnummer", "RW", "HW", "Hoehe")),
}


@pytest.mark.parametrize("name", sorted(DIALECTS))
def test_adjust_reads_every_dialect_to_the_plain_result(tmp_path, name):
    ids, src, dst = _points()
    _write(tmp_path / "src.csv", ids, src)
    _write(tmp_path / "plain.csv", ids, dst)
    _write(tmp_path / "other.txt", ids, dst, **DIALECTS[name])
    assert _adjust(tmp_path / "src.csv", tmp_path / "plain.csv", "--json",
                   tmp_path / "a.json") == 0
    assert _adjust(tmp_path / "src.csv", tmp_path / "other.txt", "--json",
                   tmp_path / "b.json") == 0
    a, b = (json.loads((tmp_path / f).read_text()) for f in ("a.json", "b.json"))
    for key in ("translation_m", "rotation_arcsec", "scale_ppm", "residuals", "sigma0",
                "ids", "mdb_m"):
        assert a[key] == b[key], key
    # the reference itself recovers the transform the points were made with
    np.testing.assert_allclose(a["rotation_arcsec"], [10.0, -5.0, 200.0], atol=5.0)
    read_as = b["inputs"][1]["read_as"]
    want = {",": "comma", ";": "semicolon", "\t": "tab", "  ": "white space"}[
        DIALECTS[name].get("delim", ",")]
    assert want in read_as
    assert ("decimal comma" in read_as) == (DIALECTS[name].get("decimal") == ",")
    assert ("no header" in read_as) == (DIALECTS[name].get("header", 1) is None)


def test_unmappable_header_names_what_was_found(tmp_path, capsys):
    ids, src, dst = _points()
    _write(tmp_path / "src.csv", ids, src)
    _write(tmp_path / "odd.csv", ids, dst, delim=";", decimal=",",
           header=("Code", "Foo", "Bar", "Baz"), encoding="latin-1")
    assert _adjust(tmp_path / "src.csv", tmp_path / "odd.csv") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    for part in ("semicolon ';' delimiter", "decimal comma", "'Code'", "'Baz'",
                 "--columns", "id, e, n, h"):
        assert part in err[0], part
    # --columns maps it: the same result as the plain file
    _write(tmp_path / "plain.csv", ids, dst)
    assert _adjust(tmp_path / "src.csv", tmp_path / "plain.csv", "--json",
                   tmp_path / "a.json") == 0
    assert _adjust(tmp_path / "src.csv", tmp_path / "odd.csv", "--target-columns",
                   "Code,Foo,Bar,Baz", "--json", tmp_path / "b.json") == 0
    a, b = (json.loads((tmp_path / f).read_text()) for f in ("a.json", "b.json"))
    assert a["translation_m"] == b["translation_m"] and a["residuals"] == b["residuals"]


def test_columns_option_changes_the_result(tmp_path):
    """Northing before easting under names no alias knows: --columns 1,3,2,4 puts them
    right (the plain result); without it the file is refused; with 1,2,3,4 (read as
    written) the axes are swapped and adjust refuses the mirror image."""
    ids, src, dst = _points()
    _write(tmp_path / "src.csv", ids, src)
    _write(tmp_path / "plain.csv", ids, dst)
    swapped = dst[:, [1, 0, 2]]
    _write(tmp_path / "ne.csv", ids, swapped, header=("pt", "nn", "ee", "up"))
    assert _adjust(tmp_path / "src.csv", tmp_path / "ne.csv") == 2
    assert _adjust(tmp_path / "src.csv", tmp_path / "plain.csv", "--json",
                   tmp_path / "a.json") == 0
    assert _adjust(tmp_path / "src.csv", tmp_path / "ne.csv", "--target-columns",
                   "1,3,2,4", "--json", tmp_path / "b.json") == 0
    a, b = (json.loads((tmp_path / f).read_text()) for f in ("a.json", "b.json"))
    assert a["translation_m"] == b["translation_m"]
    assert _adjust(tmp_path / "src.csv", tmp_path / "ne.csv", "--target-columns",
                   "1,2,3,4") == 2


def test_german_x_y_header_is_refused_not_guessed(tmp_path, capsys):
    ids, src, dst = _points()
    _write(tmp_path / "src.csv", ids, src)
    _write(tmp_path / "plain.csv", ids, dst)
    # Gauss-Krüger: Y = Rechtswert (easting) first, X = Hochwert (northing)
    _write(tmp_path / "gk.csv", ids, dst, delim=";", decimal=",", encoding="cp1252",
           header=("Punkt", "Y", "X", "Höhe"))
    assert _adjust(tmp_path / "src.csv", tmp_path / "gk.csv") == 2
    err = capsys.readouterr().err
    assert "Hochwert" in err and "--columns" in err
    assert _adjust(tmp_path / "src.csv", tmp_path / "plain.csv", "--json",
                   tmp_path / "a.json") == 0
    # --columns is for both files: the source has no 'Punkt' (refused, naming it)
    assert _adjust(tmp_path / "src.csv", tmp_path / "gk.csv", "--columns",
                   "id=Punkt,e=Y,n=X,h=Höhe") == 2
    assert "'Punkt'" in capsys.readouterr().err
    assert _adjust(tmp_path / "src.csv", tmp_path / "gk.csv", "--target-columns",
                   "id=Punkt,e=Y,n=X,h=Höhe", "--json", tmp_path / "b.json") == 0
    a, b = (json.loads((tmp_path / f).read_text()) for f in ("a.json", "b.json"))
    assert a["translation_m"] == b["translation_m"]


def test_messages_name_the_column_and_the_line(tmp_path):
    (tmp_path / "bad.csv").write_text("P1,100.0,200.0,3.0\nP2,abc,201.0,3.0\n"
                                      "P3,102.0,202.0,3.0\n")
    with pytest.raises(ControlPointError,
                       match=r"column 2 \(easting\) on line 2 .*'abc'.*comma ','.*"
                             r"no header row.*--columns"):
        read_control_points(tmp_path / "bad.csv")
    (tmp_path / "wide.csv").write_text("P1,1,2,3,X\nP2,1,2,3,Y\n")
    with pytest.raises(ControlPointError, match=r"Expected 4 columns .*got 5.*--columns"):
        read_control_points(tmp_path / "wide.csv")
    assert read_control_points(tmp_path / "wide.csv", columns="1,2,3,4").ids == ["P1", "P2"]
    (tmp_path / "ragged.csv").write_text("id;x;y;z\nP1;1;2;3\n" * 1 + "P2;1;2\n")
    with pytest.raises(ControlPointError, match="same"):
        read_control_points(tmp_path / "ragged.csv")
    with pytest.raises(ControlPointError, match="--columns"):
        read_control_points(tmp_path / "wide.csv", columns="1,2,9,4")


def test_sigma_and_time_columns_in_a_german_file(tmp_path):
    ids, _, dst = _points(4)
    _write(tmp_path / "s.csv", ids, dst, delim=";", decimal=",", encoding="latin-1",
           header=("Punkt", "Rechtswert", "Hochwert", "Höhe", "Sigma"),
           sigma=[0.002, 0.003, 0.004, 0.005])
    cp = read_control_points(tmp_path / "s.csv")
    np.testing.assert_array_equal(cp.sigma[:, 0], [0.002, 0.003, 0.004, 0.005])
    np.testing.assert_array_equal(cp.xyz, dst)


def test_reader_pieces():
    assert to_float("1.234.567,5", ",") == 1234567.5
    assert to_float("-0,25", ",") == -0.25
    with pytest.raises(ValueError):
        to_float("1,5", ".")
    with pytest.raises(ValueError):
        to_float("1.5", ",")
    assert decode_text("Höhe".encode("latin-1")) == ("Höhe", "cp1252")
    assert decode_text("\ufeffHöhe".encode("utf-8"))[1] == "utf-8-sig"
    assert sniff(["id, x, y, z", "A, 1.5, 2.5, 3.5"]) == (",", ".", True)
    assert sniff(["A\t1,5\t2,5\t3,5", "B\t1,5\t2,5\t3,5"]) == ("\t", ",", False)
    assert parse_columns("1,3,2,4", ("id", "e", "n", "h")) == {
        "id": "1", "e": "3", "n": "2", "h": "4"}
    with pytest.raises(TableFileError, match="--columns"):
        parse_columns("1,,2", ("id", "e", "n", "h"))


_ID = st.text("ABCDEFGHKLMNPQRSTUVWXYZ0123456789_-", min_size=1, max_size=8)
_COORD = st.floats(-1e7, 1e7, allow_nan=False, allow_infinity=False)


@settings(max_examples=100, deadline=None)
@given(ids=st.lists(_ID, min_size=1, max_size=12, unique=True),
       data=st.data(),
       dialect=st.sampled_from(sorted(DIALECTS) + ["plain"]))
def test_any_dialect_reads_back_the_same_numbers(tmp_path_factory, ids, data, dialect):
    xyz = np.array([[data.draw(_COORD) for _ in range(3)] for _ in ids])
    kw = DIALECTS.get(dialect, {})
    p = _write(tmp_path_factory.mktemp("d") / "cp.txt", ids, xyz, **kw)
    cp = read_control_points(p)
    assert cp.ids == ids
    np.testing.assert_array_equal(cp.xyz, xyz)


def test_pose_table_dialects_with_the_trajectory_aliases(tmp_path):
    """The same module reads pose tables: a EuRoC-style '#timestamp' header, German
    semicolons with decimal commas; against the plain CSV's numbers (np.loadtxt)."""
    from sensors.io.tables import map_columns, numeric_columns, read_table
    from sensors.trajectory import CSV_COLUMNS

    rng = np.random.default_rng(2)
    data = np.column_stack([np.arange(5) * 0.1, rng.normal(0, 10, (5, 3)),
                            rng.normal(0, 1, (5, 4))])
    names = ["qw", "x", "y", "z", "qx", "qy", "qz", "t"]        # any order
    perm = np.column_stack([data[:, 7], data[:, 1:7], data[:, 0]])
    plain = tmp_path / "p.csv"
    plain.write_text("#" + ",".join(names) + "\n" + "\n".join(
        ",".join(repr(float(v)) for v in row) for row in perm) + "\n")
    german = tmp_path / "g.csv"
    german.write_bytes(("# Trajektorie\n#" + ";".join(names) + "\n" + "\n".join(
        ";".join(repr(float(v)).replace(".", ",") for v in row) for row in perm)
        + "\n").encode("cp1252"))
    ref = np.loadtxt(plain, delimiter=",", comments="#")[:, [7, 1, 2, 3, 4, 5, 6, 0]]
    np.testing.assert_array_equal(ref, data)
    for p in (plain, german):
        tab = read_table(p, what="CSV trajectory", hash_header=True)
        col = map_columns(tab, CSV_COLUMNS, tuple(CSV_COLUMNS), unknown="error",
                          what="CSV trajectory")
        np.testing.assert_array_equal(numeric_columns(tab, col, tuple(CSV_COLUMNS)), ref)
    bad = tmp_path / "b.csv"
    bad.write_text("t,x,y,z,qx,qy,qz,qw,speed\n" + "0,1,2,3,0,0,0,1,5\n")
    tab = read_table(bad, hash_header=True)
    with pytest.raises(TableFileError, match="unknown 'speed'"):
        map_columns(tab, CSV_COLUMNS, tuple(CSV_COLUMNS), unknown="error")
