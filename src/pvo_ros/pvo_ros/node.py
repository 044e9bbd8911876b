"""``PvoNode``: the base of every pvo node — typed parameters from its configs, one runtime-change rule,
a ``/pvo/<node>/status`` publisher and one warning line per distinct problem."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from typing import Any, Generic, TypeVar

from rclpy.node import Node

from .diagnostics import ProblemLog, status_array
from .parameters import ConfigParameters, ParameterPolicy, unknown_parameter_lines
from .qos import reliable

CoreConfig = TypeVar("CoreConfig")
NodeConfig = TypeVar("NodeConfig")
Loaded = TypeVar("Loaded")


class PvoNode(Node, Generic[CoreConfig, NodeConfig]):
    """A node whose parameters are the fields of ``core_defaults`` (the algorithm's config) and of
    ``node_defaults`` (frames, publishing options), with dotted names.

    runtime: node parameters that may change while running (applied after validation; the others are
    refused with the reason). ``config`` is the core config read at start-up, ``settings`` the node's current one.
    """

    def __init__(
        self,
        name: str,
        core_defaults: CoreConfig,
        node_defaults: NodeConfig | None = None,
        runtime: Mapping[str, Callable[[Any], None]] | None = None,
        status_topic: str | None = None,
        status_depth: int = 50,
        **kwargs: Any,
    ) -> None:
        super().__init__(name, **kwargs)
        self._core = ConfigParameters(self, core_defaults, name)
        self._node_parameters = ConfigParameters(self, node_defaults, name) if node_defaults is not None else None
        bindings = [b for b in (self._core, self._node_parameters) if b is not None]
        ParameterPolicy(self, bindings, runtime=dict(runtime or {}))
        self.problem = ProblemLog(self.get_logger())
        for line in unknown_parameter_lines(self):
            self.get_logger().warning(line)
        self.callback_errors: Counter[str] = Counter()
        from diagnostic_msgs.msg import DiagnosticArray

        self.status_name = f"pvo/{name}"
        topic = status_topic or f"/pvo/{name}/status"
        self.pub_status = self.create_publisher(DiagnosticArray, topic, reliable(status_depth))

    def create_subscription(self, msg_type: Any, topic: str, callback: Callable[[Any], None], *args: Any, **kwargs: Any) -> Any:
        """rclpy's, with the callback guarded: no exception escapes it (it would stop the executor and the node).
        An unexpected error is counted per topic, logged once per kind and reported on the status topic."""

        def guarded(msg: Any) -> None:
            try:
                callback(msg)
            except Exception as exc:  # noqa: BLE001 - a callback must never take the node down
                self._callback_failed(topic, msg, exc)

        return super().create_subscription(msg_type, topic, guarded, *args, **kwargs)

    def _callback_failed(self, topic: str, msg: Any, exc: Exception) -> None:
        self.callback_errors[topic] += 1
        reason = f"{type(exc).__name__}: {exc}".splitlines()[0]
        self.problem(f"{topic}: message dropped by an unexpected error at {_stamp_text(msg)}: {reason}")
        try:
            from .diagnostics import ERROR

            values = {f"callback_errors.{t}": n for t, n in sorted(self.callback_errors.items())}
            self.publish_status(_stamp_ns(msg), topic, ERROR, f"{topic}: unexpected error: {reason}", values)
        except Exception:  # noqa: BLE001 - reporting must not fail the guard either
            pass

    @property
    def config(self) -> CoreConfig:
        return self._core.value

    @property
    def settings(self) -> NodeConfig:
        if self._node_parameters is None:
            raise AttributeError(f"{self.get_name()} has no node settings")
        return self._node_parameters.value

    def load(self, factory: Callable[[], Loaded], what: str) -> tuple[Loaded | None, str]:
        """What the node needs to work (a learned model): ``(factory(), "")``, or ``(None, reason)`` with one
        log line when it raises ``ValueError`` (a missing, truncated or foreign model file says so in one
        line): the node keeps running and reports the reason on its status instead of publishing guesses."""
        try:
            return factory(), ""
        except ValueError as exc:
            self.problem(f"no {what}: {exc}")
            return None, str(exc)

    def publish_status(self, stamp_ns: int, hardware_id: str, level: int, message: str, values: Mapping[str, Any]) -> None:
        """One ``DiagnosticArray`` on ``/pvo/<node>/status``, stamped with the message time it reports on."""
        self.pub_status.publish(status_array(stamp_ns, self.status_name, hardware_id, level, message, values))


def _stamp_ns(msg: Any) -> int:
    stamp = getattr(getattr(msg, "header", None), "stamp", None)
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec) if stamp is not None else 0


def _stamp_text(msg: Any) -> str:
    return f"{_stamp_ns(msg) * 1e-9:.9f} s"
