"""Moved to :mod:`ccf_ros.node.compat` (the imu_tools drop-in profiles); this name stays for existing imports."""

from .node.compat import *  # noqa: F403
