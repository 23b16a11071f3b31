"""The ROS 2 node and what only it uses: :mod:`.node` (:class:`CcfNode`), :mod:`.lifecycle`, :mod:`.entry` (the
executables), :mod:`.sync` (IMU/magnetometer delivery order), :mod:`.compat` (the imu_tools drop-in profiles),
:mod:`.parameters`, :mod:`.stats`, :mod:`.diagnostics` and :mod:`.debug` (plain code, no ROS import). The message
code it shares with replay is :mod:`ccf_ros.messages`.

The names below resolve on first use, so that importing a plain-code module (``ccf_ros.node.compat`` from the CLI)
does not import rclpy.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = [
    'OUTPUT_DEPTH', 'TF_UNAVAILABLE', 'CcfLifecycleNode', 'CcfNode', 'complementary_filter_main',
    'endpoint_mismatch', 'imu_filter_madgwick_main', 'input_qos', 'lifecycle_main', 'main', 'tf_message_type',
]
#: Where each name of ``__all__`` lives.
_HOME = {
    'OUTPUT_DEPTH': 'node', 'TF_UNAVAILABLE': 'node', 'CcfNode': 'node', 'endpoint_mismatch': 'node',
    'input_qos': 'node', 'tf_message_type': 'node', 'CcfLifecycleNode': 'lifecycle', 'main': 'entry',
    'lifecycle_main': 'entry', 'imu_filter_madgwick_main': 'entry', 'complementary_filter_main': 'entry',
}


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    if home is None:
        # The constants the single module ccf_ros.node had (HOLD_S, TF_QOS, ...) live in node.py. Only upper-case
        # names: ``from ccf_ros.node import sync`` asks here first and must not import rclpy.
        if not name.isupper():
            raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
        module = importlib.import_module(f'{__name__}.node')
        if not hasattr(module, name):
            raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
        return getattr(module, name)
    return getattr(importlib.import_module(f'{__name__}.{home}'), name)
