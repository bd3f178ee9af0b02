"""A tunnel's alignment from the files a surveyor has: the tunnel JSON, LandXML, a CSV.

``load_tunnel`` is the one entry point every command's ``--tunnel`` / ``--tunnel-json``
goes through. It reads, by the file's suffix:

- ``.json``: a tunnel JSON written by ``tunnelsim tunnel`` or ``tunnelsim axis``
  (``alignment``, and the cross-section ``profile`` when present); ``.ply``: the JSON
  beside a generated tunnel's mesh.
- ``.xml`` / ``.landxml``: a LandXML 1.0-1.2 ``<Alignment>`` (``read_landxml``);
  ``file.xml#NAME`` picks one of several alignments by name.
- ``.csv`` / ``.txt``: centreline stations of chainage, E, N, H (``read_alignment_csv``).

LandXML support (LandXML-1.2 schema, ``CoordGeom``): ``<Line>``, ``<Curve>`` (circular
arc, ``rot`` cw/ccw, length from the ``length`` attribute or from Start/Center/End) and
``<Spiral>`` of ``spiType`` clothoid (the default; ``radiusStart``/``radiusEnd`` with
"INF" for a straight end, ``length``, ``rot``). Coordinates in ``<Start>``, ``<End>``,
``<Center>``, ``<PI>`` are "northing easting [elevation]" (LandXML's order). The chainage
starts at the ``staStart`` attribute. Heights: the first ``<Profile><ProfAlign>``: ``<PVI>``
("station elevation"), ``<ParaCurve length=>`` (symmetric parabola) and ``<CircCurve
length= radius=>`` (taken as the parabola of the same length: they differ by about
x^4 / (8 R^3), below 0.1 mm for x = 50 m, R = 2000 m); without a profile the elevation is
0 and a warning says so. Not supported (a clear error): other ``CoordGeom`` elements
(``IrregularLine``, ``Chain``, ``CurvedLine``), other spiral types (cubic parabola,
bloss, sinusoid ...), ``UnsymParaCurve`` and station equations (``StaEquation``).

CSV stations: one station per row, chainage, E, N, H in metres. With a header the
columns are found by name (case and a unit in brackets ignored):

- chainage: chainage, station, sta, stationing, ch, pk, s, km (a ``km`` column holds
  kilometres: 1.2345 is 1234.5 m); a value "12+345.678" is km+m in any chainage column;
- easting: e, east, easting, x, rechtswert, r;  northing: n, north, northing, y,
  hochwert;  height: h, z, height, elevation, elev, hoehe, rl, level.

DECISION: x is the easting and y the northing (the order of clouds, GIS and CAD), not
the geodetic x-north of Gauss-Krueger and Swiss LV03 tables: name such columns
rechtswert/hochwert or e/n. A file without a header has the columns chainage, E, N, H
in that order. Without a height column the elevation is 0 (a warning says so).
"""

from __future__ import annotations

import math
import re
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from survey.errors import AlignmentError, TunnelsimError

from sensors.io.errors import TunnelFileError
from survey.world.alignment import Alignment, Element
from survey.world.profiles import Profile

__all__ = ["ALIGNMENT_SUFFIXES", "CSV_COLUMNS", "LANDXML_TOL_M", "PROFILE_STEP_M",
           "TunnelAxis", "load_tunnel", "read_alignment_csv", "read_landxml"]

Floats = NDArray[np.float64]

#: Suffixes ``load_tunnel`` reads, by kind.
ALIGNMENT_SUFFIXES = {".json": "tunnel JSON", ".ply": "tunnel mesh (its JSON)",
                      ".xml": "LandXML", ".landxml": "LandXML", ".csv": "station CSV",
                      ".txt": "station CSV"}
#: Largest distance (m) between an element end a LandXML file states and the one its
#: elements give: more means elements that do not join, or a misread file.
LANDXML_TOL_M = 0.005
#: Step (m) at which vertical curves are sampled into the piecewise linear elevation
#: (a parabola of K = 1000 m between samples 1 m apart deviates by 1 / (8 K) = 0.13 mm).
PROFILE_STEP_M = 1.0
#: Header names of the station CSV columns (lower case, unit stripped).
CSV_COLUMNS = {
    "chainage": ("chainage", "station", "sta", "stationing", "ch", "pk", "s", "km",
                 "chainage_m", "station_m"),
    "e": ("e", "east", "easting", "x", "rechtswert", "r", "e_m", "x_m"),
    "n": ("n", "north", "northing", "y", "hochwert", "n_m", "y_m"),
    "h": ("h", "z", "height", "elevation", "elev", "hoehe", "höhe", "rl", "level",
          "h_m", "z_m"),
}


@dataclass(frozen=True)
class TunnelAxis:
    """A tunnel's alignment as read by ``load_tunnel``.

    alignment : the centreline with chainage.
    profile : the cross-section (offset, height above the alignment) or None (LandXML,
        CSV, or a JSON without one).
    meta : the tunnel JSON's object (control points, crs ...); {} for other files.
    source : "tunnel JSON", "LandXML" or "station CSV".
    """

    alignment: Alignment
    profile: Profile | None
    meta: dict[str, Any] = field(default_factory=dict)
    source: str = "tunnel JSON"

    @property
    def centre(self) -> Floats:
        """(2,) float64: the profile centre (offset, height above the alignment), m;
        (0, 0) without a profile: the alignment is then taken as the axis."""
        if self.profile is None:
            return np.zeros(2)
        return np.asarray(self.profile.centroid, dtype=np.float64)

    @property
    def crs(self) -> str | None:
        """The CRS (WKT) a tunnel JSON states, or None."""
        from sensors.io.tunnel_json import tunnel_crs

        return tunnel_crs(self.meta)


def load_tunnel(path: str | Path, *, option: str = "--tunnel") -> TunnelAxis:
    """The alignment (and profile, where the file has one) of a tunnel JSON, a tunnel
    PLY's JSON, a LandXML alignment or a chainage,E,N,H CSV (module doc), by suffix.

    ``option`` names the command-line option in error messages. Raises
    ``TunnelFileError`` for a missing, unreadable or unknown file and
    ``AlignmentError`` for geometry that does not hold together.
    """
    text = str(path)
    name = None
    if "#" in text and not Path(text).exists():
        text, name = text.rsplit("#", 1)
    p = Path(text)
    kind = p.suffix.lower()
    if kind not in ALIGNMENT_SUFFIXES:
        raise TunnelFileError(f"Expected {option} as a tunnel JSON (.json), a LandXML "
                              f"alignment (.xml, .landxml) or a chainage,E,N,H CSV (.csv, "
                              f".txt), got '{p}'.")
    if not p.is_file():
        raise TunnelFileError(f"Expected {option} as an existing file, got '{p}' which does "
                              "not exist.")
    if kind in (".xml", ".landxml"):
        return TunnelAxis(read_landxml(p, name=name), None, {}, "LandXML")
    if kind in (".csv", ".txt"):
        return TunnelAxis(read_alignment_csv(p), None, {}, "station CSV")
    from sensors.io.tunnel_json import read_meta, sidecar

    js = sidecar(p) if kind == ".ply" else p
    meta = read_meta(js)
    if not isinstance(meta.get("alignment"), dict):
        raise TunnelFileError(f"Expected 'alignment' and 'profile' objects in '{js}' (a "
                              f"JSON written by 'tunnelsim tunnel' or 'tunnelsim axis'; "
                              f"the profile may be left out), got no alignment; pass "
                              f"{option} a tunnel JSON, a LandXML or a station CSV.")
    try:
        al = Alignment.from_dict(meta["alignment"])
        prof = Profile.from_dict(meta["profile"]) if isinstance(meta.get("profile"),
                                                                dict) else None
    except TunnelsimError:
        raise
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise TunnelFileError(f"Expected a valid alignment and profile in '{js}', got "
                              f"{type(exc).__name__}: {exc}; rewrite it with 'tunnelsim "
                              "tunnel' or 'tunnelsim axis'.") from None
    return TunnelAxis(al, prof, meta, "tunnel JSON")


# ---------------------------------------------------------------------------- LandXML
def _tag(el: ET.Element) -> str:
    return el.tag.rsplit("}", 1)[-1]


def _kids(el: ET.Element, name: str) -> list[ET.Element]:
    return [c for c in el if _tag(c) == name]


def _numbers(el: ET.Element | None, what: str, path: Path) -> list[float]:
    if el is None or not (el.text or "").split():
        raise TunnelFileError(f"Expected {what} in '{path}', got none.")
    try:
        return [float(v) for v in (el.text or "").split()]
    except ValueError:
        raise TunnelFileError(f"Expected numbers in {what} of '{path}', got "
                              f"{(el.text or '').strip()!r}.") from None


def _en(el: ET.Element, child: str, what: str, path: Path) -> Floats | None:
    """(E, N) of a child point ("northing easting [z]" in LandXML), None if absent."""
    k = _kids(el, child)
    if not k:
        return None
    v = _numbers(k[0], f"the <{child}> of {what}", path)
    if len(v) < 2:
        raise TunnelFileError(f"Expected 'northing easting' in the <{child}> of {what} in "
                              f"'{path}', got {v}.")
    return np.array([v[1], v[0]])


def _attr(el: ET.Element, name: str, what: str, path: Path, *, default: float | None = None
          ) -> float:
    raw = el.get(name)
    if raw is None:
        if default is None:
            raise TunnelFileError(f"Expected the attribute {name} of {what} in '{path}', "
                                  "got none.")
        return default
    if raw.strip().lower() in ("inf", "infinity", "infinite"):
        return math.inf
    try:
        return float(raw)
    except ValueError:
        raise TunnelFileError(f"Expected a number for {name} of {what} in '{path}', got "
                              f"{raw!r}.") from None


def _rot(el: ET.Element, what: str, path: Path) -> float:
    r = (el.get("rot") or "").strip().lower()
    if r not in ("cw", "ccw"):
        raise TunnelFileError(f"Expected rot=\"cw\" or \"ccw\" on {what} in '{path}', got "
                              f"{el.get('rot')!r}.")
    return 1.0 if r == "ccw" else -1.0


def _pick_alignment(root: ET.Element, path: Path, name: str | None) -> ET.Element:
    found = [e for e in root.iter() if _tag(e) == "Alignment"]
    if name is not None:
        found = [e for e in found if e.get("name") == name]
        if not found:
            names = [e.get("name") for e in root.iter() if _tag(e) == "Alignment"]
            raise TunnelFileError(f"Expected an <Alignment name=\"{name}\"> in '{path}', got "
                                  f"the alignments {names}.")
    if not found:
        raise TunnelFileError(f"Expected an <Alignment> in the LandXML file '{path}', got "
                              "none.")
    if len(found) > 1:
        names = [e.get("name") for e in found]
        raise TunnelFileError(f"Expected one <Alignment> in '{path}', got {len(found)} "
                              f"({names}); name one as '{path}#NAME'.")
    return found[0]


def read_landxml(path: str | Path, *, name: str | None = None) -> Alignment:
    """The ``Alignment`` of a LandXML file's ``<Alignment>`` (module doc for what is
    supported): plan elements from ``<CoordGeom>``, chainage from ``staStart``,
    elevation from the first ``<ProfAlign>`` (0 without one, with a warning).

    The start position and heading are the rigid fit (Kabsch 1976, in the plane) of the
    element chain to every element end point the file states, so rounded coordinates
    in the file do not turn the whole alignment; any stated end farther than
    ``LANDXML_TOL_M`` from the chain raises ``TunnelFileError``.
    """
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, UnicodeDecodeError) as exc:
        raise TunnelFileError(f"Expected a LandXML file in '{path}', got XML that does not "
                              f"parse ({exc}).") from None
    aln = _pick_alignment(root, path, name)
    label = f"<Alignment name=\"{aln.get('name', '')}\">"
    if any(_tag(e) == "StaEquation" for e in aln.iter()):
        raise TunnelFileError(f"Expected a continuous chainage in {label} of '{path}', got "
                              "<StaEquation> (station equations are not supported); "
                              "export the alignment without them.")
    geom = _kids(aln, "CoordGeom")
    if not geom:
        raise TunnelFileError(f"Expected <CoordGeom> in {label} of '{path}', got none.")
    elements: list[Element] = []
    stated: list[tuple[int, str, Floats]] = []   # (element, "start"/"end", E,N)
    first_heading: float | None = None
    first_start: Floats | None = None
    for i, el in enumerate(geom[0]):
        kind = _tag(el)
        what = f"element {i + 1} (<{kind}>) of {label}"
        start, end = _en(el, "Start", what, path), _en(el, "End", what, path)
        if kind == "Line":
            if start is None or end is None:
                raise TunnelFileError(f"Expected <Start> and <End> in {what} in '{path}', "
                                      "got none.")
            ln = float(np.hypot(*(end - start)))
            e = Element(ln, 0.0, 0.0)
            head = math.atan2(end[1] - start[1], end[0] - start[0])
        elif kind == "Curve":
            sg = _rot(el, what, path)
            centre = _en(el, "Center", what, path)
            r = _attr(el, "radius", what, path, default=0.0)
            if r == 0.0 and centre is not None and start is not None:
                r = float(np.hypot(*(start - centre)))
            if not (np.isfinite(r) and r > 0):
                raise TunnelFileError(f"Expected a positive finite radius on {what} in "
                                      f"'{path}', got {el.get('radius')!r}.")
            if el.get("length") is not None:
                ln = _attr(el, "length", what, path)
            elif centre is not None and start is not None and end is not None:
                a0 = math.atan2(*(start - centre)[::-1])
                a1 = math.atan2(*(end - centre)[::-1])
                ln = r * ((a1 - a0) * sg % (2 * math.pi))
            else:
                raise TunnelFileError(f"Expected a length attribute, or <Start>, <Center> "
                                      f"and <End>, on {what} in '{path}', got neither.")
            e = Element(ln, sg / r, sg / r)
            head = math.nan
            if centre is not None and start is not None:
                rad = math.atan2(*(start - centre)[::-1])
                head = rad + sg * math.pi / 2
        elif kind == "Spiral":
            spi = (el.get("spiType") or "clothoid").strip().lower()
            if spi != "clothoid":
                raise TunnelFileError(f"Expected spiType=\"clothoid\" on {what} in '{path}', "
                                      f"got {el.get('spiType')!r}: only clothoids are "
                                      "supported.")
            sg = _rot(el, what, path)
            ln = _attr(el, "length", what, path)
            r0 = _attr(el, "radiusStart", what, path)
            r1 = _attr(el, "radiusEnd", what, path)
            if r0 <= 0 or r1 <= 0 or (math.isinf(r0) and math.isinf(r1)):
                raise TunnelFileError(f"Expected positive radii, at most one INF, on {what} "
                                      f"in '{path}', got {el.get('radiusStart')!r}, "
                                      f"{el.get('radiusEnd')!r}.")
            e = Element(ln, 0.0 if math.isinf(r0) else sg / r0,
                        0.0 if math.isinf(r1) else sg / r1)
            pi = _en(el, "PI", what, path)
            head = math.nan if pi is None or start is None else \
                math.atan2(pi[1] - start[1], pi[0] - start[0])
        else:
            raise TunnelFileError(f"Expected <Line>, <Curve> or <Spiral> (clothoid) in the "
                                  f"<CoordGeom> of {label} in '{path}', got <{kind}> as "
                                  f"element {i + 1}: it is not supported.")
        if not (np.isfinite(e.length_m) and e.length_m > 0):
            raise TunnelFileError(f"Expected a positive length of {what} in '{path}', got "
                                  f"{e.length_m}.")
        if i == 0:
            first_start, first_heading = start, head
        for tag, pt in (("start", start), ("end", end)):
            if pt is not None:
                stated.append((i, tag, pt))
        elements.append(e)
    if not elements:
        raise TunnelFileError(f"Expected elements in the <CoordGeom> of {label} in "
                              f"'{path}', got none.")
    if first_start is None or first_heading is None or not math.isfinite(first_heading):
        raise TunnelFileError(f"Expected the first element of {label} in '{path}' to state "
                              "its <Start> and direction (a Line's <End>, a Curve's "
                              "<Center>, a Spiral's <PI>), got too little.")
    sta0 = _attr(aln, "staStart", label, path, default=0.0)
    al = Alignment(elements, start_xy=first_start, heading_rad=first_heading,
                   start_chainage_m=sta0)
    # Rigid fit of the chain onto every stated end (in a local frame: UTM numbers).
    s_at = sta0 + np.concatenate([[0.0], np.cumsum([e.length_m for e in elements])])
    idx = np.array([j + (t == "end") for j, t, _ in stated])
    b = np.array([pt for _, _, pt in stated]) - first_start
    a = al.plan(s_at[idx])[0] - first_start
    if len(b) >= 2:
        ca, cb = a.mean(axis=0), b.mean(axis=0)
        hm = (a - ca).T @ (b - cb)
        dth = float(np.arctan2(hm[0, 1] - hm[1, 0], hm[0, 0] + hm[1, 1]))
        rot = np.array([[np.cos(dth), -np.sin(dth)], [np.sin(dth), np.cos(dth)]])
        start = rot @ (np.zeros(2) - ca) + cb + first_start
        al = Alignment(elements, start_xy=start, heading_rad=first_heading + dth,
                       start_chainage_m=sta0)
    got = al.plan(s_at[idx])[0]
    miss = np.hypot(*(got - (b + first_start)).T)
    if miss.max() > LANDXML_TOL_M:
        k = int(np.argmax(miss))
        j, t, _ = stated[k]
        raise TunnelFileError(f"Expected the elements of {label} in '{path}' to join "
                              f"(within {LANDXML_TOL_M * 1000:g} mm), got the {t} of element "
                              f"{j + 1} {miss[k]:.4f} m from where the elements before it "
                              "end: a gap, a wrong rot or radius, or an unsupported element.")
    prof = _landxml_profile(aln, path, label)
    if prof is None:
        warnings.warn(f"'{path}' has no <Profile><ProfAlign> for {label}: elevation 0 m "
                      "along the alignment.", UserWarning, stacklevel=2)
        return al
    return Alignment(elements, start_xy=al.plan(sta0)[0],
                     heading_rad=float(al.heading(sta0)), profile=prof,
                     start_chainage_m=sta0)


def _landxml_profile(aln: ET.Element, path: Path, label: str) -> Floats | None:
    """(k, 2) (chainage, elevation) of the first <ProfAlign>, vertical curves sampled
    every ``PROFILE_STEP_M``; None without one."""
    pa = [e for p in _kids(aln, "Profile") for e in _kids(p, "ProfAlign")]
    if not pa:
        return None
    pvi: list[tuple[float, float, float]] = []    # station, elevation, curve length
    for el in pa[0]:
        kind = _tag(el)
        if kind not in ("PVI", "ParaCurve", "CircCurve"):
            raise TunnelFileError(f"Expected <PVI>, <ParaCurve> or <CircCurve> in the "
                                  f"<ProfAlign> of {label} in '{path}', got <{kind}>: it "
                                  "is not supported.")
        v = _numbers(el, f"a <{kind}> of {label}", path)
        if len(v) < 2:
            raise TunnelFileError(f"Expected 'station elevation' in a <{kind}> of {label} "
                                  f"in '{path}', got {v}.")
        ln = 0.0 if kind == "PVI" else _attr(el, "length", f"a <{kind}>", path)
        pvi.append((v[0], v[1], ln))
    arr = np.array(pvi, dtype=np.float64)
    if len(arr) < 1 or (np.diff(arr[:, 0]) <= 0).any():
        raise TunnelFileError(f"Expected profile stations increasing in the <ProfAlign> of "
                              f"{label} in '{path}', got {arr[:, 0].tolist()[:6]}.")
    if len(arr) == 1:
        return arr[:, :2]
    s, z, ln = arr.T
    g = np.diff(z) / np.diff(s)
    pts = [(s[0], z[0])]
    for i in range(1, len(arr) - 1):
        half = 0.5 * ln[i]
        if half <= 0:
            pts.append((s[i], z[i]))
            continue
        if s[i] - half < pts[-1][0] - 1e-9 or s[i] + half > s[i + 1] + 1e-9:
            raise TunnelFileError(f"Expected the vertical curve at station {s[i]:g} of "
                                  f"{label} in '{path}' to fit between its neighbours, got "
                                  f"length {ln[i]:g} m.")
        # Symmetric parabola from BVC = s - L/2 (grade g1) to EVC = s + L/2 (grade g2):
        # z = z_bvc + g1 x + (g2 - g1) x^2 / (2 L) (e.g. AASHTO 2018, 3.4.6).
        g1, g2 = g[i - 1], g[i]
        x = np.linspace(0.0, ln[i], max(2, int(np.ceil(ln[i] / PROFILE_STEP_M)) + 1))
        zb = z[i] - g1 * half
        for xx in x:
            pts.append((s[i] - half + xx, zb + g1 * xx + (g2 - g1) * xx * xx / (2 * ln[i])))
    pts.append((s[-1], z[-1]))
    out = np.array(pts)
    keep = np.concatenate([[True], np.diff(out[:, 0]) > 1e-9])
    return out[keep]


# ---------------------------------------------------------------------------- CSV
_SPLIT = re.compile(r"[,\t ]+")
_KM_M = re.compile(r"^\s*([+-]?\d+)\+(\d+(?:\.\d*)?)\s*$")


def _cells(line: str) -> list[str]:
    if ";" in line:    # semicolon files often carry decimal commas
        return [c.strip().replace(",", ".") for c in line.split(";")]
    for sep in (",", "\t"):      # a header cell may hold a space: "Chainage [m]"
        if sep in line:
            return [c.strip() for c in line.strip().split(sep)]
    return [c for c in _SPLIT.split(line.strip()) if c != ""]


def _chainage_value(text: str) -> float:
    m = _KM_M.match(text)
    if m:
        km, metres = int(m.group(1)), float(m.group(2))
        return (abs(km) * 1000.0 + metres) * (-1.0 if m.group(1).startswith("-") else 1.0)
    return float(text)


def _column_name(text: str) -> str:
    t = re.sub(r"[\[(].*?[\])]", "", text).strip().strip('"\'').lower()
    return t.replace(" ", "_")


def read_alignment_csv(path: str | Path) -> Alignment:
    """The ``Alignment`` through the stations of a chainage, E, N, H file (module doc
    for the columns), by ``Alignment.from_stations`` (cubic splines of the chainage,
    the chainage as given)."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise TunnelFileError(f"Expected a text file of stations in '{path}', got one that "
                              f"does not read ({exc}).") from None
    rows = [(n + 1, _cells(ln)) for n, ln in enumerate(lines)
            if ln.strip() and not ln.lstrip().startswith("#")]
    if not rows:
        raise TunnelFileError(f"Expected rows of chainage, E, N, H in '{path}', got none.")
    head = rows[0][1]
    try:
        [_chainage_value(head[0])] + [float(c) for c in head[1:]]
        header = None
    except ValueError:
        header = [_column_name(c) for c in head]
        rows = rows[1:]
    scale = 1.0
    if header is None:
        if len(head) != 4:
            raise TunnelFileError(f"Expected 4 columns chainage, E, N, H in '{path}' (no "
                                  f"header), got {len(head)}; add a header naming the "
                                  "columns.")
        cols = {"chainage": 0, "e": 1, "n": 2, "h": 3}
    else:
        cols = {}
        for key, names in CSV_COLUMNS.items():
            hit = [i for i, c in enumerate(header) if c in names]
            if len(hit) > 1:
                raise TunnelFileError(f"Expected one {key} column in '{path}', got "
                                      f"{[head[i] for i in hit]}.")
            if hit:
                cols[key] = hit[0]
        missing = [k for k in ("chainage", "e", "n") if k not in cols]
        if missing:
            raise TunnelFileError(f"Expected the columns chainage, E, N (and H) in the "
                                  f"header of '{path}', got {head} with no "
                                  f"{', '.join(missing)}; name them e.g. chainage,E,N,H.")
        if header[cols["chainage"]] == "km":
            scale = 1000.0     # DECISION: a 'km' column holds kilometres
    vals = []
    for n, cells in rows:
        try:
            need = max(cols.values())
            if len(cells) <= need:
                raise ValueError(f"{len(cells)} columns")
            vals.append((_chainage_value(cells[cols["chainage"]]) * scale,
                         float(cells[cols["e"]]), float(cells[cols["n"]]),
                         float(cells[cols["h"]]) if "h" in cols else 0.0))
        except ValueError as exc:
            raise TunnelFileError(f"Expected numbers for chainage, E, N, H on line {n} of "
                                  f"'{path}', got {cells} ({exc}).") from None
    if "h" not in cols:
        warnings.warn(f"'{path}' has no height column: elevation 0 m along the "
                      "alignment.", UserWarning, stacklevel=2)
    v = np.array(vals, dtype=np.float64)
    try:
        return Alignment.from_stations(v[:, 0], v[:, 1:])
    except AlignmentError as exc:
        raise AlignmentError(f"In '{path}': {exc}") from None
