"""``ccf_lifecycle_node``'s class: :class:`~ccf_ros.node.node.CcfNode` as a managed (lifecycle) node."""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.parameter import Parameter

from .compat import NodeProfile
from .node import CcfNode
from .stats import InputStats


class CcfLifecycleNode(LifecycleNodeMixin, CcfNode):
    """``ccf_lifecycle_node``: :class:`CcfNode` as a managed (lifecycle) node, for bring-ups that activate nodes in
    order (Nav2's lifecycle manager, ``ros2 lifecycle set``).

    configure: parameters declared (once) and validated, the engine built (an invalid value: the transition fails
    with the reason logged, the node stays unconfigured, the value can be set; one rclpy refuses to declare is
    declared with its default, and configure fails until it is set); activate: publishers, subscriptions,
    ``~/reset`` and the timer made, messages flow; deactivate: held samples answered, all of them destroyed
    (parameters stay, the estimate too); cleanup: the filter state dropped (the next configure starts a fresh
    estimate); shutdown, from every state: whatever exists is destroyed.
    """

    def __init__(self, profile: NodeProfile | str = 'ccf_node', *, node_name: str | None = None,
                 **kwargs: Any) -> None:
        self._init_profile(profile)
        self._configured = False
        self._refused = {}  # (a start-up value rclpy refuses fails configure, which can be corrected)
        Node.__init__(self, node_name or self.profile.node_name, **kwargs)
        LifecycleNodeMixin.__init__(self, enable_communication_interface=True)

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self._configure_ccf()
        except (ValueError, ParameterException) as err:
            self.get_logger().error(f'configure failed: {err}')
            return TransitionCallbackReturn.FAILURE
        self._configured = True
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._open_ccf()
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close_ccf()
        self.save_state()
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.save_state()  # before the estimate is dropped
        self._drop_pending_pose('cleanup drops the filter state')
        self.engine.reset()
        self.sync.reset()
        self._forget_mag_clock()
        self.stats = InputStats()
        self._configured = False
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._drop_pending_pose('the node shuts down')
        self._close_ccf()
        self._configured = False
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._drop_pending_pose('an error transition')
        self._close_ccf()
        self._configured = False
        return TransitionCallbackReturn.SUCCESS

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        if not self._configured:  # checked on configure
            return SetParametersResult(successful=True)
        return super()._validate_parameters(params)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        if self._refused:  # set since: the next configure takes it
            for p in params:
                self._refused.pop(p.name, None)
        if self._configured:
            super()._apply_parameters(params)
