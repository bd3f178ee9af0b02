"""Commands for cameras: render (one frame from the mesh), cameras (the models)."""

from __future__ import annotations

from survey.cli.common import CommandSet, warn_radian_like, xyz


def register(commands: CommandSet) -> None:
    """Add render and cameras."""
    c = commands.add(
        "render", cmd_render, seeded=True,
        help="render one camera frame (colour, depth or thermal) from a mesh",
        description="Render one frame of a camera in a mesh with tunnelsim's own ray "
                    "caster: a ray per pixel centre through the camera's lens model (--samples "
                    "N: N rays per pixel, averaged), lit by a spot lamp 5 cm above the "
                    "camera along its axis and/or the lamps of a --platform whose camera "
                    "mount is --at (a shadow ray per lamp). Writes into the folder: rgb.png (colour cameras, 8-bit "
                    "sRGB), thermal.png (thermal cameras, 16-bit centikelvin), depth.png "
                    "(16-bit millimetres of z-depth, 0 = no data), depth.npy (float32 "
                    "metres, NaN = no data) and camera_info.json (K, D, width, height, "
                    "model, world_from_camera of the OpenCV optical frame). Albedo and "
                    "temperature come from the mesh's vertex colours and temperatures, "
                    "else its face labels, else grey.",
        epilog="Example: tunnelsim render --mesh bfo.ply --camera realsense_d435_color "
               "--at 10,0,1.5 --heading-deg 0 -o frame/")
    c.option("--mesh", required=True, path="in", help="the mesh (PLY, OBJ, STL, ...)")
    c.option("--camera", required=True, path="toml",
             help="camera name ('tunnelsim cameras' lists them) or a camera .toml")
    c.option("--at", required=True, metavar="X,Y,Z",
             help="the camera's optical centre in the mesh's coordinates (metres)")
    c.option("--heading-deg", type=float, required=True, metavar="DEG",
             help="azimuth of the optical axis, degrees counter-clockwise from +x")
    c.option("--pitch-deg", type=float, default=0.0, metavar="DEG",
             help="tilt of the optical axis up from level, degrees (default 0)")
    c.option("--roll-deg", type=float, default=0.0, metavar="DEG",
             help="roll about the optical axis, clockwise seen from behind, degrees "
                  "(default 0)")
    c.option("--lamp-cd", type=float, metavar="CD",
             help="luminous intensity of the headlamp on its axis, candela (default "
                  "1000, an LED work light, without --platform; none with it; 0: no "
                  "headlamp). Given with --platform, both light the frame")
    c.option("--platform", path="toml", metavar="NAME|FILE",
             help="light the frame with this platform's lamps ([[lamps]] of its file): "
                  "the camera at --at is the platform's camera mount, the mast's height "
                  "above its base_link, the platform level facing --heading-deg "
                  "(colour cameras)")
    c.option("--samples", type=int, default=1, metavar="N",
             help="rays per pixel, a square number (1, 4, 9, 16 ...) on a stratified "
                  "grid, their radiance averaged: anti-aliasing (default 1: the pixel "
                  "centre; colour and thermal cameras; depth stays the pixel centre's)")
    c.option("--no-noise", action="store_true",
             help="no shot, read or NETD noise (a noiseless reference frame)")
    c.option("-o", "--output", required=True, path="out", help="output folder")

    commands.add("cameras", cmd_cameras, printing=True, help="list the camera models",
                 description="List the shipped camera models with kind, resolution, frame "
                             "rate, field of view, lens model, shutter and sources.",
                 epilog="Example: tunnelsim cameras")


def cmd_render(args) -> int:
    from survey.workflows.render import render_frame

    at = xyz(args.at, "--at")
    warn_radian_like(args.heading_deg, "--heading-deg")
    r = render_frame(args.mesh, args.camera, at, args.output,
                     heading_deg=args.heading_deg, pitch_deg=args.pitch_deg,
                     roll_deg=args.roll_deg, lamp_cd=args.lamp_cd, seed=args.seed,
                     noise=not args.no_noise, platform=args.platform,
                     samples=args.samples)
    if not args.quiet:
        print(f"{r.camera} ({r.kind}, {r.width}x{r.height}): {r.hit_fraction:.1%} of "
              f"pixels hit the mesh; depth {r.depth_min_m:.3f}-{r.depth_max_m:.3f} m "
              f"(median {r.depth_median_m:.3f} m) on {r.valid_fraction:.1%}")
        if r.kind == "color":
            light = [f"headlamp {r.lamp_cd:g} cd"] if r.lamp_cd > 0 or \
                r.platform is None else []
            if r.platform is not None:
                n = r.lamps - (r.lamp_cd > 0)
                light.append(f"{r.platform}'s {n} lamp{'s' if n != 1 else ''}")
            print(f"{' + '.join(light)}, {r.samples_per_pixel} sample"
                  f"{'s' if r.samples_per_pixel > 1 else ''} per pixel: exposure "
                  f"{r.exposure_s * 1e3:.3g} ms at gain {r.gain:.3g}, mean value "
                  f"{r.mean_value:.3f} of full scale, {r.saturated_fraction:.1%} saturated")
        elif r.kind == "thermal":
            print(f"mean apparent temperature {r.mean_value:.2f} K")
        if r.depth_clipped:
            print(f"{r.depth_clipped:,} pixels beyond 65.535 m are 0 in depth.png "
                  "(kept in depth.npy)")
        src = ", ".join(f"{k} from {v}" for k, v in r.appearance.items())
        print(f"appearance: {src}; {r.seconds:.1f} s")
        for p in r.files:
            print(f"wrote {p}")
    return 0


def cmd_cameras(args) -> int:
    from survey.workflows.render import camera_models

    for m in camera_models():
        print(f"{m.name:22s} {m.kind:8s} {m.width}x{m.height} {m.frame_rate_hz:g} Hz  "
              f"FOV {m.hfov_deg:.1f}x{m.vfov_deg:.1f} deg  {m.lens}, {m.shutter} "
              f"shutter  {m.vendor} {m.model}  [{'; '.join(m.sources)}]")
    return 0


__all__ = ["cmd_cameras", "cmd_render", "register"]
