"""The node's executables: ``ccf_node``, ``ccf_lifecycle_node`` and the imu_tools drop-ins (setup.py's entry points
name them through :mod:`ccf_ros.node`)."""

from __future__ import annotations

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.qos_overriding_options import InvalidQosOverridesError

from .executor import LeanExecutor
from .lifecycle import CcfLifecycleNode
from .node import CcfNode


def _is_startup_error(err: BaseException) -> bool:
    """An error in the user's start-up parameters (shown as one line), not a bug."""
    if isinstance(err, (ValueError, ParameterException, InvalidQosOverridesError)):
        return True
    # rclpy's QoS override of an unknown policy value (e.g. reliability: sometimes)
    return isinstance(err, RuntimeError) and str(err).startswith('Unexpected QoS override')


def main(args: list[str] | None = None, profile: str = 'ccf_node', lifecycle: bool = False) -> None:
    """Entry point of ``ccf_node`` / ``ros2 run ccf_ros ccf_node`` (and, with ``profile``, of the drop-ins; with
    ``lifecycle``, of ``ccf_lifecycle_node``)."""
    node: CcfNode | None = None
    executor: LeanExecutor | None = None
    try:
        rclpy.init(args=args)
        executor = LeanExecutor()
        node = CcfLifecycleNode(profile) if lifecycle else CcfNode(profile)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as err:
        # Only what the start-up raised is the user's parameters; an error while running is a bug: its traceback.
        if node is not None or not _is_startup_error(err):
            raise
        # Invalid parameters at start-up: one clear line, non-zero exit.
        print(f'{profile}: error: {err}', flush=True)
        raise SystemExit(2) from None
    finally:
        if executor is not None:
            executor.shutdown()  # (releases the handles it holds)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


def lifecycle_main(args: list[str] | None = None) -> None:
    """Entry point of ``ccf_lifecycle_node``: ccf_node as a managed node (starts unconfigured)."""
    main(args, lifecycle=True)


def imu_filter_madgwick_main(args: list[str] | None = None) -> None:
    """Entry point of ``imu_filter_madgwick_node``: the ccf filter as imu_filter_madgwick presents itself."""
    main(args, 'imu_filter_madgwick_node')


def complementary_filter_main(args: list[str] | None = None) -> None:
    """Entry point of ``complementary_filter_node``: the ccf filter as imu_complementary_filter presents itself."""
    main(args, 'complementary_filter_node')


