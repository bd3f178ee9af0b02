"""MLS speed and scan-rate study (seed Figure 7): how point density, line spacing, gaps
and rolling-shutter distortion depend on the platform speed, the rotation rate and the
mounting of a moving lidar.

Each configuration drives the sensor along the axis at constant speed through an
evaluation strip [s_a, s_b] with ``lead_m`` before and after it, and counts the points
that land in the strip while the sensor is in that window. Because the set of sensor
positions is the same for every speed, the count scales as 1/v for a constant pulse
rate: density per pass ~ pulse rate x (window length / v) x (share landing in the
strip). At v = 0 the sensor stands at the strip's centre for one sweep and the
densities are per sweep (marked as such).

Metrics per configuration:

- density on lining and floor (points/m^2): points in the strip's lining/floor cells
  (``planning.lining_cells``) over the cells' area;
- empty lining share: lining cells (``cell_m`` x ``cell_rad``) without a point;
- along-track line spacing: for the forward-looking beams (|azimuth| < 2 deg) on the
  floor, the median shift in chainage of each channel's footprint between consecutive
  sweeps (analytic: v / f);
- rolling-shutter distortion: each point's device-frame coordinates placed with the
  pose at its sweep's start (what a driver does that assembles a sweep with one pose),
  minus the true point; max and RMS (analytic for straight, level motion: v x time
  since the sweep started, at most v / f).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from survey.errors import StudyError

#: Forward beams used for the along-track line spacing (|azimuth| below this, rad).
FORWARD_AZ_RAD = np.deg2rad(2.0)
MOUNTS = ("level", "down")


@dataclass
class StudyRow:
    speed_mps: float
    rate_hz: float
    mount: str
    points: int
    density_lining: float        # points / m^2 (per pass; per sweep at v = 0)
    density_floor: float
    empty_lining_share: float
    line_spacing_m: float        # measured (NaN where no forward floor beams)
    line_spacing_analytic_m: float
    distortion_max_m: float
    distortion_rms_m: float
    distortion_analytic_max_m: float
    pulses: int
    seconds: float

    def to_dict(self):
        return dict(self.__dict__)


def _with_rate(spec, rate_hz):
    from sensors.spec import with_rate

    if spec.kind in ("spinning", "profiler"):
        return with_rate(spec, rate_hz)
    raise StudyError(f"Expected a moving sensor (spinning or profiler), got {spec.name} "
                     f"({spec.kind}); plan TLS stations with 'tunnelsim plan'.")


class Study:
    """One tunnel, one sensor; ``run`` evaluates a configuration."""

    def __init__(self, scene, alignment, centre_height_m, sensor, *, strip=None,
                 lead_m=5.0, height_m=0.5, cell_m=0.1, cell_rad=np.deg2rad(2.0),
                 settings=None, seed=0, reflectivity=None, keep_points=0):
        from survey.analysis.planning import axis_stations, lining_cells

        self.scene, self.al, self.hc = scene, alignment, float(centre_height_m)
        self.sensor = sensor
        _with_rate(sensor, 1.0)                        # kind check
        c0, c1 = alignment.chainage_range
        if strip is None:
            mid = 0.5 * (c0 + c1)
            strip = (mid - 2.5, mid + 2.5)
        sa, sb = map(float, strip)
        if not (c0 <= sa - lead_m and sb + lead_m <= c1 and sb > sa):
            raise StudyError(f"Expected the strip [{sa}, {sb}] m with {lead_m} m lead on "
                             f"both sides inside the tunnel [{c0}, {c1}] m, got it outside; "
                             "shorten the strip or the lead.")
        self.strip, self.lead = (sa, sb), float(lead_m)
        self.cells = lining_cells(scene, alignment, self.hc, s_range=(sa, sb), cell_m=cell_m,
                                  cell_rad=cell_rad, keep_floor=True)
        self.cell_m, self.n_a = cell_m, self.cells.shape[1]
        self.height_m = height_m
        self.settings, self.seed, self.refl = settings, seed, reflectivity
        self.keep_points = int(keep_points)
        # Sensor path: height_m above the floor below the axis, sampled every 0.25 m.
        s = np.arange(sa - lead_m, sb + lead_m + 1e-9, 0.25)
        self.path_s = s
        self.path = axis_stations(scene, alignment, self.hc, s, height_m=height_m)
        # A ball that holds the strip: points outside it skip the exact (slow) chainage.
        self._ball_c = alignment.to_world(0.5 * (sa + sb), 0.0, self.hc)
        self._ball_r = float(np.linalg.norm(self.cells.points - self._ball_c, axis=1).max()
                             + 2 * cell_m)
        self.kept = {}

    def run(self, speed_mps, rate_hz, mount="level") -> StudyRow:
        from sensors import Mount, Trajectory, simulate_drive
        from scipy.spatial.transform import Rotation

        if not (np.isfinite(speed_mps) and speed_mps >= 0):
            raise StudyError(f"Expected a speed >= 0 m/s, got {speed_mps}.")
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise StudyError(f"Expected a positive rotation/profile rate, got {rate_hz} Hz.")
        if mount not in MOUNTS:
            raise StudyError(f"Expected a mount in {MOUNTS}, got {mount!r}.")
        spec = _with_rate(self.sensor, rate_hz)
        mnt = Mount.pointing_down() if mount == "down" else Mount()
        if speed_mps > 0:
            traj = Trajectory.along_polyline(self.path, speed_mps)
            t0, t1 = traj.start_s, traj.end_s
        else:
            mid = len(self.path) // 2
            d = self.path[mid + 1] - self.path[mid - 1]
            rot = Rotation.from_euler("z", np.arctan2(d[1], d[0]))
            traj = Trajectory.static(self.path[mid], rot)
            t0, t1 = 0.0, 1.0 / rate_hz + 1e-6
        run = simulate_drive(self.scene, spec, traj, mnt, settings=self.settings,
                             seed=self.seed, reflectivity=self.refl, t_start=t0, t_end=t1)
        c = self.cells
        counts = np.zeros(c.shape, dtype=np.int64)
        lookup = np.full(c.shape, -1, dtype=np.int64)
        lookup[c.ring, c.col] = np.arange(len(c.area))
        fwd = {}
        dmax, dsq, nd = 0.0, 0.0, 0
        keep = []
        sa, sb = self.strip
        for pts in run:
            if len(pts) == 0:
                continue
            xyz = np.stack([pts["x"], pts["y"], pts["z"]], 1)
            near = np.einsum("ni,ni->n", xyz - self._ball_c, xyz - self._ball_c) <= \
                self._ball_r ** 2
            pts, xyz = pts[near], xyz[near]
            s, off, h = self.al.to_local(xyz)
            ins = (s >= sa) & (s < sb)
            if not ins.any():
                continue
            p = pts[ins]
            s, off, h = s[ins], off[ins], h[ins]
            phi = np.arctan2(off, h - self.hc)
            ring = np.clip(((s - sa) / self.cell_m).astype(np.int64), 0, c.shape[0] - 1)
            col = np.clip(((phi + np.pi) / (2 * np.pi) * self.n_a).astype(np.int64), 0,
                          self.n_a - 1)
            np.add.at(counts, (ring, col), 1)
            # Rolling shutter: the sweep assembled with the pose at its start.
            fr = p["frame"].astype(np.int64)
            tf = t0 + fr / rate_hz
            pos, mats = traj.sensor_matrices(np.minimum(tf, t1), mnt)
            sxyz = np.stack([p["sx"], p["sy"], p["sz"]], 1)
            ref = np.einsum("nij,nj->ni", mats, sxyz) + pos
            dd = np.linalg.norm(ref - np.stack([p["x"], p["y"], p["z"]], 1), axis=1)
            dmax = max(dmax, float(dd.max()))
            dsq += float((dd * dd).sum())
            nd += len(dd)
            # Forward floor beams for the line spacing.
            cell = lookup[ring, col]
            floor = (cell >= 0) & c.is_floor[np.maximum(cell, 0)]
            f = floor & (np.abs(p["azimuth"]) < FORWARD_AZ_RAD)
            for ch, frm, ss in zip(p["channel"][f], fr[f], s[f]):
                a = fwd.setdefault((int(ch), int(frm)), [0.0, 0])
                a[0] += ss
                a[1] += 1
            if self.keep_points:
                # Floor footprint of three sweeps from when the sensor passes the strip
                # centre (the rings of the seed's Figure 7).
                tc = t0 + (self.lead + 0.5 * (sb - sa)) / speed_mps if speed_mps > 0 else t0
                k = floor & (p["time"] >= tc) & (p["time"] < tc + 3.0 / rate_hz) & \
                    (p["channel"] % 6 == 0)
                keep.append(np.stack([s, off, h, p["time"] - tc], 1)[k])
        if self.keep_points:
            kp = np.concatenate(keep) if keep else np.zeros((0, 4))
            if len(kp) > self.keep_points:
                kp = kp[np.random.default_rng(0).choice(len(kp), self.keep_points,
                                                        replace=False)]
            self.kept[(float(speed_mps), float(rate_hz), mount)] = kp
        got = counts[c.ring, c.col]
        lin, flo = ~c.is_floor, c.is_floor
        dens_l = got[lin].sum() / max(c.area[lin].sum(), 1e-12)
        dens_f = got[flo].sum() / max(c.area[flo].sum(), 1e-12)
        empty = float(c.area[lin & (got == 0)].sum() / max(c.area[lin].sum(), 1e-12))
        # Line spacing: per channel, mean footprint chainage per sweep, consecutive diffs.
        by_ch = {}
        for (ch, frm), (tot, n) in fwd.items():
            by_ch.setdefault(ch, []).append((frm, tot / n))
        diffs = []
        for v in by_ch.values():
            v.sort()
            fr_, ss_ = np.array(v).T
            ok = np.diff(fr_) == 1
            diffs.extend(np.abs(np.diff(ss_))[ok].tolist())
        spacing = float(np.median(diffs)) if diffs else float("nan")
        st = run.stats
        return StudyRow(float(speed_mps), float(rate_hz), mount, int(got.sum()),
                        float(dens_l), float(dens_f), empty, spacing,
                        float(speed_mps / rate_hz), dmax,
                        float(np.sqrt(dsq / nd)) if nd else 0.0,
                        float(speed_mps / rate_hz), int(st.get("pulses", 0)),
                        float(st.get("seconds", 0.0)))

    def grid(self, speeds, rates, mounts=("level",), progress=None) -> list:
        rows = []
        combos = [(v, f, m) for m in mounts for f in rates for v in speeds]
        for i, (v, f, m) in enumerate(combos):
            rows.append(self.run(v, f, m))
            if progress:
                progress(i + 1, len(combos))
        return rows
