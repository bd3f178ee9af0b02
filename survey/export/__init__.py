"""Exports to other tools: Gazebo worlds (SDFormat)."""

from .gazebo import export_gazebo, lidar_sdf

__all__ = ["export_gazebo", "lidar_sdf"]
