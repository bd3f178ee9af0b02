"""Alignments from LandXML and station CSV files (issue 31, item 1).

The LandXML file is written by hand here from an independent evaluation of a
line-spiral-arc-spiral-line alignment: clothoids by Fresnel integrals
(``scipy.special.fresnel``: x = a C(l/a), y = a S(l/a), a = A sqrt(pi), A^2 = R L),
arcs by exact circle geometry; the reader's positions must match it within 1 mm.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import fresnel

from survey.cli.main import main
from survey.errors import AlignmentError
from sensors.io.errors import TunnelFileError
from survey.world.alignment import Alignment, arc, straight
from survey.world.alignment_io import load_tunnel, read_alignment_csv, read_landxml

E0, N0 = 2_600_000.0, 1_200_000.0       # UTM-sized (LV95) coordinates
TH0 = 0.5                               # heading, rad ccw from east
L1, LS, R, LA, L2 = 40.0, 30.0, 150.0, 50.0, 40.0
STA0 = 1234.5
# Vertical: PVIs with a symmetric parabola of 60 m at the middle one.
PVI = ((STA0, 400.0), (STA0 + 100.0, 402.0), (STA0 + 190.0, 401.1))
VC_LEN = 60.0


def _t(th):
    return np.array([np.cos(th), np.sin(th)])


def _rot(th, v):
    c, s = np.cos(th), np.sin(th)
    return np.array([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]]).T


def _clothoid(l):
    """Local clothoid from curvature 0 (x along the start tangent, y to the left)."""
    a = np.sqrt(R * LS) * np.sqrt(np.pi)
    S, C = fresnel(np.asarray(l) / a)
    return np.stack([a * C, a * S], axis=-1)


class Truth:
    """The independent evaluation: plan position at local chainage u (from STA0)."""

    def __init__(self, sg):
        self.sg = sg
        self.p1 = np.array([E0, N0]) + L1 * _t(TH0)
        c = _clothoid(LS) * [1, sg]
        self.p2 = self.p1 + _rot(TH0, c)
        self.th2 = TH0 + sg * LS / (2 * R)
        self.centre = self.p2 + sg * R * np.array([-np.sin(self.th2), np.cos(self.th2)])
        self.p3 = self.centre + _rot(sg * LA / R, self.p2 - self.centre)
        self.th3 = self.th2 + sg * LA / R
        self.th4 = self.th3 + sg * LS / (2 * R)
        # The exit spiral run backwards from its end E: a clothoid turning the other way.
        self.e = self.p3 - _rot(self.th4 + np.pi, _clothoid(LS) * [1, -sg])
        self.length = L1 + LS + LA + LS + L2

    def __call__(self, u):
        u = np.atleast_1d(np.asarray(u, dtype=np.float64))
        out = np.empty((len(u), 2))
        b = np.cumsum([0, L1, LS, LA, LS])
        for i, x in enumerate(u):
            if x <= b[1]:
                out[i] = np.array([E0, N0]) + x * _t(TH0)
            elif x <= b[2]:
                out[i] = self.p1 + _rot(TH0, _clothoid(x - b[1]) * [1, self.sg])
            elif x <= b[3]:
                out[i] = self.centre + _rot(self.sg * (x - b[2]) / R, self.p2 - self.centre)
            elif x <= b[4]:
                out[i] = self.e + _rot(self.th4 + np.pi,
                                       _clothoid(LS - (x - b[3])) * [1, -self.sg])
            else:
                out[i] = self.e + (x - b[4]) * _t(self.th4)
        return out


def _elev_truth(s):
    (s0, z0), (s1, z1), (s2, z2) = PVI
    g1, g2 = (z1 - z0) / (s1 - s0), (z2 - z1) / (s2 - s1)
    bvc, evc = s1 - VC_LEN / 2, s1 + VC_LEN / 2
    s = np.asarray(s, dtype=np.float64)
    x = s - bvc
    zb = z1 - g1 * VC_LEN / 2
    return np.where(s < bvc, z0 + g1 * (s - s0),
                    np.where(s > evc, z1 + g2 * (s - s1),
                             zb + g1 * x + (g2 - g1) * x * x / (2 * VC_LEN)))


def _ne(p):
    return f"{p[1]:.6f} {p[0]:.6f}"     # LandXML: northing easting


def _pi(pa, tha, pb, thb):
    """Intersection of the tangent lines (pa, tha) and (pb, thb)."""
    m = np.array([_t(tha), -_t(thb)]).T
    k = np.linalg.solve(m, pb - pa)
    return pa + k[0] * _t(tha)


def landxml(tr: Truth, *, spi="clothoid", gap=0.0, second=False, profile=True) -> str:
    rot = "ccw" if tr.sg > 0 else "cw"
    p0 = np.array([E0, N0])
    end = tr.e + L2 * _t(tr.th4)
    els = [
        f'<Line><Start>{_ne(p0)}</Start><End>{_ne(tr.p1)}</End></Line>',
        f'<Spiral length="{LS}" radiusStart="INF" radiusEnd="{R}" rot="{rot}" '
        f'spiType="{spi}"><Start>{_ne(tr.p1 + [gap, 0])}</Start>'
        f'<PI>{_ne(_pi(tr.p1, TH0, tr.p2, tr.th2))}</PI><End>{_ne(tr.p2)}</End></Spiral>',
        f'<Curve rot="{rot}" radius="{R}" length="{LA}"><Start>{_ne(tr.p2)}</Start>'
        f'<Center>{_ne(tr.centre)}</Center><End>{_ne(tr.p3)}</End></Curve>',
        f'<Spiral length="{LS}" radiusStart="{R}" radiusEnd="INF" rot="{rot}">'
        f'<Start>{_ne(tr.p3)}</Start><PI>{_ne(_pi(tr.p3, tr.th3, tr.e, tr.th4))}</PI>'
        f'<End>{_ne(tr.e)}</End></Spiral>',
        f'<Line><Start>{_ne(tr.e)}</Start><End>{_ne(end)}</End></Line>',
    ]
    prof = ""
    if profile:
        (s0, z0), (s1, z1), (s2, z2) = PVI
        prof = (f'<Profile name="p"><ProfAlign name="design"><PVI>{s0} {z0}</PVI>'
                f'<ParaCurve length="{VC_LEN}">{s1} {z1}</ParaCurve><PVI>{s2} {z2}</PVI>'
                f'</ProfAlign></Profile>')
    one = (f'<Alignment name="Tunnel" length="{tr.length}" '
           f'staStart="{STA0}"><CoordGeom>{"".join(els)}</CoordGeom>{prof}</Alignment>')
    two = one.replace('name="Tunnel"', 'name="Other"') if second else ""
    return ('<?xml version="1.0" encoding="UTF-8"?>\n<LandXML xmlns="http://www.landxml.org/'
            'schema/LandXML-1.2" version="1.2"><Units><Metric linearUnit="meter"/></Units>'
            f'<Alignments name="set">{one}{two}</Alignments></LandXML>\n')


@pytest.fixture(scope="module", params=[1.0, -1.0], ids=["ccw", "cw"])
def design(request, tmp_path_factory):
    tr = Truth(request.param)
    p = tmp_path_factory.mktemp("lx") / "design.xml"
    p.write_text(landxml(tr))
    return tr, p


def test_landxml_positions_match_fresnel_and_circle_within_1mm(design):
    tr, path = design
    al = read_landxml(path)
    assert al.chainage_range == pytest.approx((STA0, STA0 + tr.length), abs=1e-6)
    u = np.arange(0.0, tr.length + 1e-9, 1.0)
    got = al.point(STA0 + u)
    assert np.abs(got[:, :2] - tr(u)).max() < 1e-3
    assert np.abs(got[:, 2] - _elev_truth(STA0 + u)).max() < 1e-3
    # The end heading: the deflection of the whole curve, LS / R + LA / R.
    assert al.heading(STA0 + tr.length) == pytest.approx(tr.th4, abs=1e-7)


@settings(max_examples=40, deadline=None)
@given(u=st.floats(0.0, 1.0), off=st.floats(-4.0, 4.0), h=st.floats(-3.0, 3.0))
def test_chainage_round_trip_on_the_landxml_alignment(design, u, off, h):
    tr, path = design
    al = read_landxml(path)
    s = STA0 + u * tr.length
    p = al.to_world(s, off, h)
    s2, off2, h2 = al.to_local(p)
    assert s2[0] == pytest.approx(s, abs=1e-6)
    assert off2[0] == pytest.approx(off, abs=1e-6)
    assert h2[0] == pytest.approx(h, abs=1e-6)


def test_landxml_refuses_what_it_does_not_support(tmp_path):
    tr = Truth(1.0)
    bad = tmp_path / "bloss.xml"
    bad.write_text(landxml(tr, spi="bloss"))
    with pytest.raises(TunnelFileError, match="only clothoids are supported"):
        read_landxml(bad)
    gap = tmp_path / "gap.xml"
    gap.write_text(landxml(tr, gap=0.05))
    with pytest.raises(TunnelFileError, match="to join"):
        read_landxml(gap)
    two = tmp_path / "two.xml"
    two.write_text(landxml(tr, second=True))
    with pytest.raises(TunnelFileError, match=r"got 2 .*name one as"):
        load_tunnel(two)
    # One picked by name: the same alignment as the single file's.
    a = load_tunnel(f"{two}#Other").alignment
    np.testing.assert_allclose(a.point(STA0 + 100.0)[:2], tr(100.0)[0], atol=1e-3)
    flat = tmp_path / "flat.xml"
    flat.write_text(landxml(tr, profile=False))
    with pytest.warns(UserWarning, match="elevation 0 m"):
        assert read_landxml(flat).elevation(STA0 + 50.0) == 0.0
    eq = tmp_path / "eq.xml"
    eq.write_text(landxml(tr).replace("<CoordGeom>", '<StaEquation staAhead="5" '
                                      'staBack="4"/><CoordGeom>'))
    with pytest.raises(TunnelFileError, match="StaEquation"):
        read_landxml(eq)


# ---------------------------------------------------------------------------- CSV
def _truth_alignment():
    return Alignment([straight(30.0), arc(40.0, 120.0), straight(30.0)],
                     start_xy=(E0, N0), heading_rad=-0.4,
                     profile=((500.0, 300.0), (600.0, 301.0)), start_chainage_m=500.0)


@pytest.mark.parametrize("layout", ["plain", "header", "rechtswert", "km", "kmplus",
                                    "semicolon"])
def test_station_csv_reads_every_layout_to_the_same_alignment(tmp_path, layout):
    true = _truth_alignment()
    s = np.arange(500.0, 600.0 + 1e-9, 5.0)
    p = true.point(s)
    rows = {
        "plain": ["{s},{e},{n},{h}"],
        "header": ["Chainage [m],E,N,H", "{s},{e},{n},{h}"],
        "rechtswert": ["station\tHochwert\tRechtswert\tHoehe", "{s}\t{n}\t{e}\t{h}"],
        "km": ["km,x,y,z", "{km},{e},{n},{h}"],
        "kmplus": ["# exported by hand", "pk e n h", "{kmp} {e} {n} {h}"],
        "semicolon": ["Station;Easting;Northing;Elevation", "{sc};{ec};{nc};{hc}"],
    }[layout]
    lines = rows[:-1]
    for si, (e, n, h) in zip(s, p):
        lines.append(rows[-1].format(
            s=repr(float(si)), e=repr(float(e)), n=repr(float(n)), h=repr(float(h)),
            km=repr(float(si) / 1000.0),
            kmp=f"{int(si // 1000)}+{si % 1000:07.3f}",
            sc=f"{si:.6f}".replace(".", ","), ec=f"{e:.6f}".replace(".", ","),
            nc=f"{n:.6f}".replace(".", ","), hc=f"{h:.6f}".replace(".", ",")))
    f = tmp_path / "stations.csv"
    f.write_text("\n".join(lines) + "\n")
    al = read_alignment_csv(f)
    assert al.chainage_range == pytest.approx((500.0, 600.0), abs=1e-3)
    # Between the stations (every 5 m) on straights, arc and their joints: the cubic
    # spline's error on a 120 m arc sampled every 5 m, and at the curvature jumps.
    u = np.arange(500.0, 600.0, 0.5)
    err = np.hypot(*(al.point(u)[:, :2] - true.point(u)[:, :2]).T)
    assert err.max() < 0.01
    assert np.median(err) < 1e-3
    np.testing.assert_allclose(al.elevation(u), true.elevation(u), atol=1e-9)


def test_station_csv_errors(tmp_path):
    f = tmp_path / "s.csv"
    f.write_text("chainage,E,N,H\n0,0,0,0\n10,10,0,0\n5,20,0,0\n")
    with pytest.raises(AlignmentError, match="strictly increasing"):
        read_alignment_csv(f)
    f.write_text("chainage,E,N,H\n0,0,0,0\n10,10,0,0\n20,20,0,0\n35,30,0,0\n")
    with pytest.raises(AlignmentError, match="not the distance along"):
        read_alignment_csv(f)
    f.write_text("a,b,c\n0,0,0\n")
    with pytest.raises(TunnelFileError, match="no chainage, e, n"):
        read_alignment_csv(f)
    f.write_text("0,0,0\n10,10,0\n")
    with pytest.raises(TunnelFileError, match="Expected 4 columns"):
        read_alignment_csv(f)


def test_unknown_tunnel_file_names_the_option(tmp_path, capsys):
    bad = tmp_path / "t.dxf"
    bad.write_text("0")
    cloud = tmp_path / "c.xyz"
    cloud.write_text("0 0 0\n1 0 0\n")
    code = main(["convergence", "--tunnel", str(bad), "--control1", str(cloud),
                 "--control2", str(cloud), "-o", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "--tunnel" in err and ".landxml" in err
    assert len(err.strip().splitlines()) == 1


# ---------------------------------------------------------------------------- CLI
def _helix(al, s0, s1, radius, n, turn=0.0):
    """n points of a circle of ``radius`` about the alignment's 3-D line between
    chainages s0 and s1 (a golden-angle helix: angles evenly spread in every band)."""
    k = np.arange(n)
    s = s0 + (k + 0.5) * (s1 - s0) / n
    phi = np.mod(k * np.pi * (3.0 - np.sqrt(5.0)) + turn, 2 * np.pi) - np.pi
    return al.to_world(s, radius * np.sin(phi), radius * np.cos(phi))


def test_commands_take_landxml_and_station_csv(design, tmp_path):
    """sections --tunnel-json design.xml and convergence --tunnel stations.csv: the
    sections fall at the file's chainages and the design's frame."""
    tr, path = design
    al = read_landxml(path)
    # The lining: radius 3 m for chainages below STA0 + 100, 3.1 m beyond.
    p = np.concatenate([_helix(al, STA0 + 20, STA0 + 100, 3.0, 40_000),
                        _helix(al, STA0 + 100, STA0 + 180, 3.1, 40_000)])
    cloud = tmp_path / "c.npz"
    np.savez(cloud, x=p[:, 0], y=p[:, 1], z=p[:, 2])
    a = np.linspace(0, 2 * np.pi, 2001)
    np.savetxt(tmp_path / "d.csv", np.stack([2.9 * np.sin(a), 2.9 * np.cos(a)], 1),
               delimiter=",")
    out = tmp_path / "sec"
    assert main(["sections", str(cloud), "--tunnel-json", str(path), "--at",
                 f"{STA0 + 60},{STA0 + 140}", "--design", str(tmp_path / "d.csv"),
                 "--no-plots", "-o", str(out)]) == 0
    import json
    rep = json.loads((out / "report.json").read_text())
    assert [s["chainage_m"] for s in rep["sections"]] == [STA0 + 60, STA0 + 140]
    assert rep["sections"][0]["mean_m"] == pytest.approx(0.1, abs=2e-4)
    assert rep["sections"][1]["mean_m"] == pytest.approx(0.2, abs=2e-4)
    # The same alignment as stations every 2 m (E, N, H columns), for convergence.
    st_ = np.arange(STA0, STA0 + tr.length, 2.0)
    pts = al.point(st_)
    csv_ = tmp_path / "stations.csv"
    csv_.write_text("station,easting,northing,elevation\n" + "".join(
        f"{s!r},{e!r},{n!r},{h!r}\n" for s, (e, n, h) in zip(st_.tolist(), pts.tolist())))
    q = np.concatenate([_helix(al, STA0 + 20, STA0 + 100, 2.995, 40_000, 1.0),
                        _helix(al, STA0 + 100, STA0 + 180, 3.1, 40_000, 1.0)])
    cloud2 = tmp_path / "c2.npz"
    np.savez(cloud2, x=q[:, 0], y=q[:, 1], z=q[:, 2])
    out = tmp_path / "conv"
    assert main(["convergence", str(cloud), str(cloud2), "--tunnel", str(csv_), "--every",
                 "25", "--angle-step", "30", "-o", str(out)]) == 0
    rows = json.loads((out / "convergence.json").read_text())["sections"]
    ch = np.array([r["chainage_m"] for r in rows])
    np.testing.assert_allclose(ch, np.arange(1275.0, STA0 + 180, 25.0))   # multiples
    med = np.array([r["median_m"] for r in rows])
    # 5 mm of convergence below chainage STA0 + 100, none beyond.
    np.testing.assert_allclose(med, np.where(ch < STA0 + 100, 0.005, 0.0), atol=3e-4)


@settings(max_examples=30, deadline=None)
@given(u=st.floats(0.0, 1.0), shift=st.floats(-5000.0, 5000.0),
       before=st.floats(0.0, 20.0), after=st.floats(0.0, 20.0))
def test_datum_operations_keep_the_curve(design, u, shift, before, after):
    """reversed / with_start_chainage / extended move the chainage, never the curve:
    the same world point at the mapped chainage (and the reversed frame mirrored)."""
    _, path = design
    al = read_landxml(path)
    c0, c1 = al.chainage_range
    s = c0 + u * (c1 - c0)
    p = al.point(s)
    rev = al.reversed()
    np.testing.assert_allclose(rev.point(c0 + c1 - s), p, atol=1e-6)
    assert rev.heading(c0 + c1 - s) == pytest.approx(al.heading(s) + np.pi, abs=1e-9)
    np.testing.assert_allclose(al.with_start_chainage(c0 + shift).point(s + shift), p,
                               atol=1e-9)
    ext = al.extended(before, after)
    assert ext.chainage_range == pytest.approx((c0 - before, c1 + after))
    np.testing.assert_allclose(ext.point(s), p, atol=1e-6)
    # The added straights continue the end tangents.
    t = np.array([np.cos(al.heading(c0)), np.sin(al.heading(c0))])
    np.testing.assert_allclose(ext.point(c0 - before)[:2], al.point(c0)[:2] - before * t,
                               atol=1e-6)
