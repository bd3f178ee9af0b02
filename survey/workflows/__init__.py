"""Workflows: one typed library function for every ``tunnelsim`` command.

Each takes paths or arrays and keyword options, writes the same files as its command,
and returns a frozen result object with the paths written and the numbers the command
prints; the command line only parses, calls one of these, and prints. They never print
(progress goes to an optional ``progress(done, total)`` callback).

======================  ========================================  ============================
command                 function                                  module
======================  ========================================  ============================
compare                 ``compare_files``                         ``survey.workflows.compare``
plan, study             ``plan_stations``, ``run_study``          ``.planning``
m3c2, convergence       ``m3c2_to_file``, ``convergence_files``   ``.epochs``
develop, clearance      ``develop_files``, ``clearance_files``    ``.inspection``
tunnel, gazebo, info    ``tunnel_files``, ``gazebo_files``,       ``.world``
                        ``software_info``, ``sensor_models``
adjust, transform,      ``adjust_files``, ``transform_file``,     ``.adjust``
correct                 ``correct_file``
slam                    ``slam_file``                             ``.slam``
detect                  ``detect_study``                          ``.detect``
preprocess, mesh        ``preprocess_file``, ``mesh_files``       ``.clouds``
axis                    ``axis_file``                             ``.axis``
sections, rings         ``sections_files``, ``rings_files``       ``.sections``
scan                    ``scan_to_file``, ``scan_campaign``       ``.scan``
drive                   ``drive_to_file``                         ``.drive``
render, cameras         ``render_frame``, ``camera_models``       ``.render``
======================  ========================================  ============================
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from raytrace.lazy import lazy_exports_of

# The one list of public names (imported on first use; type checkers read it).
if TYPE_CHECKING:
    from .adjust import (AdjustResult, CorrectResult, TransformResult, adjust_files,
                         correct_file, transform_file)
    from .axis import AxisResult, axis_file
    from .clouds import MeshResult, PreprocessResult, mesh_files, preprocess_file
    from .compare import CompareResult, compare_files
    from .detect import DetectResult, detect_study
    from .drive import DriveResult, drive_to_file
    from .epochs import ConvergenceResult, M3C2FileResult, convergence_files, m3c2_to_file
    from .inspection import (ClearanceFilesResult, DevelopFilesResult, clearance_files,
                             develop_files)
    from .planning import PlanResult, StudyResult, plan_stations, run_study
    from .render import CameraModel, RenderResult, camera_models, render_frame
    from .robotbag import write_robot_bag
    from .scan import CampaignResult, ScanResult, scan_campaign, scan_to_file
    from .sections import RingsResult, SectionsResult, rings_files, sections_files
    from .slam import SlamResult, slam_file
    from .world import (GazeboResult, SensorModel, SoftwareInfo, TunnelResult, gazebo_files,
                        sensor_models, software_info, tunnel_files)

__getattr__, __dir__, __all__ = lazy_exports_of(__name__, __file__, extra=())
