"""Moved to :mod:`ccf_ros.messages.cdr` (shared by the node and replay); this name stays for existing imports."""

from ..messages.cdr import *  # noqa: F403
from ..messages.cdr import _gather as _gather
