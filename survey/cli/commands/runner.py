"""Commands that run pipelines: run (any pipeline TOML), demo (the shipped one)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from survey.errors import TunnelsimCLIError
from survey.cli.main import _write_text


def _run(args, text, source, intro_fn=None):
    from survey.cli.pipeline import load_pipeline, pipeline_report, run_pipeline

    pipe = load_pipeline(text, source)
    t0 = time.perf_counter()
    done = run_pipeline(pipe, args.output, quick=args.quick, seed=args.seed,
                        threads=args.threads, quiet=args.quiet, force=args.force)
    total = time.perf_counter() - t0
    out = Path(args.output)
    intro = intro_fn(out) if intro_fn else ""
    _write_text(out / "report.md", pipeline_report(pipe, done, out, intro=intro))
    if not args.quiet:
        print(f"{len(done)} steps in {total:.0f} s -> {out}/report.md")
    return 0


def cmd_run(args) -> int:
    p = Path(args.pipeline)
    if not p.is_file():
        raise TunnelsimCLIError(f"Expected a pipeline TOML file, got '{p}' which does not "
                                "exist.")
    return _run(args, p.read_text(), str(p))


def cmd_demo(args) -> int:
    from survey.report.demo import demo_summary, summary_markdown
    from survey.cli.pipeline import demo_text

    if args.print_config:
        sys.stdout.write(demo_text())
        return 0

    def intro(out):
        s = demo_summary(out)
        _write_text(out / "summary.json", json.dumps(s, indent=2) + "\n")
        mode = "quick mode (smaller numbers, for CI)" if args.quick else "full demo"
        return ("What tunnelsim does, on a generated copy of the seed study's gallery: "
                f"{mode}. Every figure below was made by the step under which it "
                "appears; the commands are shown so each step can be rerun alone.\n\n" +
                summary_markdown(s))

    return _run(args, demo_text(), "the shipped demo pipeline", intro)
