"""Offline tools on recorded data: bag reading/writing and the ``ccf`` commands that work on bags.

The subpackage's modules (``__all__``); the numpy parts they share live in :mod:`ccf_ros.core` and :mod:`ccf_ros.magcal`.
"""

__all__ = [
    'bagio',
    'calibrate_mag',
    'demo',
    'evaluate',
    'fastcdr',
    'live',
    'magcal',
    'magfit',
    'mcap',
    'messages',
    'params_file',
    'play',
    'plot',
    'replay',
    'simulate',
]
