"""Commands that run pipelines: run (any pipeline TOML), demo (the shipped one)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from survey.cli.common import (
    CommandSet,
    cluster_options,
    open_cluster,
    write_json,
    write_text,
)
from survey.errors import TunnelsimCLIError


def register(commands: CommandSet) -> None:
    """Add demo and run."""
    c = commands.add(
        "demo", cmd_demo, seeded=True,
        help="the whole seed workflow on a generated tunnel, with a report",
        description="Run the shipped demo pipeline (print it with --print-config): "
                    "generate the BFO-like tunnel; simulate an MLS run (a RoboSense Airy "
                    "for SLAM with GenZ-ICP and a Z+F profiler on one trolley), place the "
                    "profiler with the SLAM trajectory and correct its drift with the prisms "
                    "(without the slam extra: the drift model instead of SLAM); "
                    "preprocess and reconstruct, compare TLS stations on the reconstruction "
                    "with the truth (Table 1), plan stations (Figure 6), study MLS speeds "
                    "(Figure 7), export to Gazebo; writes report.md and summary.json.",
        epilog="Example: tunnelsim demo -o tunnelsim-demo")
    c.option("-o", "--output", default="tunnelsim-demo", path="out",
             help="output folder (default ./tunnelsim-demo)")
    c.option("--quick", action="store_true",
             help="smaller numbers throughout (a few minutes; what the tests run)")
    c.option("--print-config", action="store_true",
             help="print the demo pipeline (TOML for 'tunnelsim run') and exit")
    c.option("--seed", type=int,
             help="random seed for every step (default: the pipeline's, 0)")
    c.option("--threads", type=int, help="Numba threads (default: all cores)")
    c.option("--force", action="store_true", help="write into a non-empty folder")
    c.option("--quiet", action="store_true", help="no progress lines")

    c = commands.add(
        "run", cmd_run, seeded=True,
        help="run a pipeline TOML file (a sequence of tunnelsim steps)",
        description="Run the steps of a pipeline TOML file in order, inside one output "
                    "folder, and write report.md. Each step is a tunnelsim command with its "
                    "options; see 'tunnelsim demo --print-config' for an example.",
        epilog="Example: tunnelsim run demo.toml -o my-demo --quick  (after 'tunnelsim demo "
               "--print-config > demo.toml')")
    c.option("pipeline", path="in", help="pipeline TOML file")
    c.option("-o", "--output", required=True, path="out", help="output folder")
    c.option("--quick", action="store_true", help="apply the steps' [quick] options")
    c.option("--seed", type=int, help="random seed for every step that takes one")
    cluster_options(c)
    c.option("--threads", type=int, help="Numba threads (default: all cores)")
    c.option("--force", action="store_true", help="write into a non-empty folder")
    c.option("--quiet", action="store_true", help="no progress lines")


def _run(args, text, source, intro_fn=None) -> int:
    from survey.cli.pipeline import load_pipeline, pipeline_report, run_pipeline

    pipe = load_pipeline(text, source)
    t0 = time.perf_counter()
    workers, scheduler = getattr(args, "workers", None), getattr(args, "scheduler", None)
    if workers is None and scheduler is None:
        done = run_pipeline(pipe, args.output, quick=args.quick, seed=args.seed,
                            threads=args.threads, quiet=args.quiet, force=args.force)
    else:
        # One cluster for the whole pipeline: the steps that fan out connect to it.
        with open_cluster(args) as ex:
            done = run_pipeline(pipe, args.output, quick=args.quick, seed=args.seed,
                                threads=args.threads, quiet=args.quiet, force=args.force,
                                scheduler=ex.address)
    total = time.perf_counter() - t0
    out = Path(args.output)
    intro = intro_fn(out, done) if intro_fn else ""
    write_text(out / "report.md", pipeline_report(pipe, done, out, intro=intro))
    if not args.quiet:
        print(f"{len(done)} steps in {total:.0f} s -> {out}/report.md")
    return 0


def cmd_run(args) -> int:
    p = Path(args.pipeline)
    if not p.is_file():
        raise TunnelsimCLIError(f"Expected a pipeline TOML file, got '{p}' which does not "
                                "exist.")
    try:
        text = p.read_text()
    except UnicodeDecodeError as exc:
        raise TunnelsimCLIError(f"Expected a TOML text file, got '{p}' which is not text "
                                f"({exc}).") from exc
    return _run(args, text, str(p))


def cmd_demo(args) -> int:
    from survey.cli.pipeline import demo_text
    from survey.report.demo import demo_summary, summary_markdown

    if args.print_config:
        sys.stdout.write(demo_text())
        return 0

    def intro(out, done):
        # The branch that ran (requires/unless "slam"), not a guess from the files.
        s = demo_summary(out, slam=any(st["command"] == "slam" for st, _, _ in done))
        write_json(out / "summary.json", s)
        mode = "quick mode (smaller numbers, for CI)" if args.quick else "full demo"
        return ("What tunnelsim does, on a generated copy of the seed study's gallery: "
                f"{mode}. Every figure below was made by the step under which it "
                "appears; the commands are shown so each step can be rerun alone.\n\n" +
                summary_markdown(s))

    return _run(args, demo_text(), "the shipped demo pipeline", intro)


__all__ = ["cmd_demo", "cmd_run", "register"]
