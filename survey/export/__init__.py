"""Exports to other tools: Gazebo worlds (SDFormat)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from raytrace.lazy import lazy_exports_of

# The one list of public names (imported on first use; type checkers read it).
if TYPE_CHECKING:
    from .gazebo import export_gazebo, lidar_sdf

__getattr__, __dir__, __all__ = lazy_exports_of(__name__, __file__, extra=())
