"""Reports: Markdown and CSV tables and PNG figures of every analysis."""

from __future__ import annotations

from typing import TYPE_CHECKING

from raytrace.lazy import lazy_exports_of

# The one list of public names (imported on first use; type checkers read it).
if TYPE_CHECKING:
    from .adjustment import drift_report, helmert_report
    from .compare import plot_histogram, stats_csv, stats_markdown
    from .planning import plan_csv, plan_markdown, plot_coverage, plan_summary
    from .study import plot_study, study_csv, study_markdown
    from .reconstruct import plot_support
    from .demo import cloud_c2m_rms, demo_summary, summary_markdown
    from .slam import plot_slam, slam_report
    from .sections import (plot_rings, plot_section, rings_csv, rings_markdown, sections_csv,
                           sections_markdown, volumes_csv)
    from .developed import (clearance_markdown, plot_developed, regions_csv, violations_csv,
                            write_developed)
    from .detectability import (detect_csv, detect_markdown, detect_summary, plot_detectability,
                                targets_csv)
    from .header import ReportHeader, ReportInput, file_sha256, header_lines, with_header
    from .html import markdown_to_html, write_report
    from .epochs import (chords_csv, convergence_markdown, m3c2_markdown, plot_m3c2_histogram,
                         plot_radial, radial_csv)

__getattr__, __dir__, __all__ = lazy_exports_of(__name__, __file__, extra=())
