"""Moved to :mod:`ccf_ros.node.sync` (node-only); this name stays for existing imports."""

from .node.sync import HOLD_S, LOCKSTEP_AFTER, HoldStats, ImuMagSync

__all__ = ['HOLD_S', 'LOCKSTEP_AFTER', 'HoldStats', 'ImuMagSync']
