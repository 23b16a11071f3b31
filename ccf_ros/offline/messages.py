"""Moved to :mod:`ccf_ros.messages.convert` (shared by the node and replay); this name stays for existing imports."""

from ..messages.convert import *  # noqa: F403
