"""ROS parameters declared from typed config dataclasses, one rule for every node.

A node hands :func:`declare_config` the defaults of its configs (the core algorithm's, e.g.
``VOConfig()``, and the node's own, e.g. frames and publishing options). Every leaf field becomes one
parameter under its dotted name (``solver.loss``, ``inputs.sun.huber_k``), typed as the field; the values
given at start-up are read back through :func:`pvo_core.config.from_flat`, so a wrong name, type or
range raises ``ValueError`` naming the parameter (the runner turns it into one ``<node>: error:`` line).

Runtime changes (``ros2 param set``): a parameter listed in ``runtime`` is applied — validated through
its config first, then handed to the node's callback with the new typed config; every other change is
refused with the reason, since the algorithm objects are built from the start-up values.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable
from typing import Any, Generic, TypeVar

from pvo_core.config import flatten, from_flat

C = TypeVar("C")


class ConfigParameters(Generic[C]):
    """The typed config a node runs with, bound to its declared parameters."""

    def __init__(self, node: Any, defaults: C, what: str) -> None:
        self._node = node
        self.what = what
        self.names = list(flatten(defaults))
        for name, value in flatten(defaults).items():
            if node.has_parameter(name):
                raise ValueError(f"{what}: parameter {name} is declared by two configs")
            node.declare_parameter(name, value)
        values = {name: node.get_parameter(name).value for name in self.names}
        self.value: C = from_flat(values, defaults, what=what)

    def replaced(self, changes: dict[str, Any]) -> C:
        """The current config with ``changes`` (dotted names) applied and validated."""
        return from_flat({**flatten(self.value), **changes}, self.value, what=self.what)


def declare_config(node: Any, defaults: C, what: str | None = None) -> C:
    """Declare one parameter per field of ``defaults`` on ``node`` and return the typed config read back."""
    return ConfigParameters(node, defaults, what or node.get_name()).value


class ParameterPolicy:
    """Refuses runtime changes, except the names whose appliers are given (validated, then applied)."""

    def __init__(
        self,
        node: Any,
        bindings: Iterable[ConfigParameters[Any]],
        runtime: dict[str, Callable[[Any], None]] | None = None,
    ) -> None:
        self._node = node
        self._bindings = list(bindings)
        self._runtime = dict(runtime or {})
        owner = {name: b for b in self._bindings for name in b.names}
        unknown = sorted(set(self._runtime) - set(owner))
        if unknown:
            raise ValueError(f"runtime appliers for undeclared parameter(s): {', '.join(unknown)}")
        self._owner = owner
        node.add_on_set_parameters_callback(self._on_set)

    def _on_set(self, params: list) -> Any:
        from rcl_interfaces.msg import SetParametersResult

        name = self._node.get_name()
        changes: dict[ConfigParameters[Any], dict[str, Any]] = {}
        for param in params:
            if param.name in RCLPY_PARAMETERS:
                continue  # rclpy's own, applied by rclpy
            if param.name not in self._runtime:
                return SetParametersResult(
                    successful=False,
                    reason=f"{name}: {param.name} is read at start-up; restart the node to change it",
                )
            changes.setdefault(self._owner[param.name], {})[param.name] = param.value
        updated = []
        for binding, values in changes.items():
            try:
                updated.append((binding, binding.replaced(values), values))
            except ValueError as exc:
                return SetParametersResult(successful=False, reason=f"{name}: {exc}")
        for binding, config, values in updated:
            binding.value = config
            for parameter in values:
                self._runtime[parameter](config)
        return SetParametersResult(successful=True)


RCLPY_PARAMETERS = frozenset({"use_sim_time", "start_type_description_service"})  # every rclpy node has them


def declared_parameter_names(node: Any) -> set[str]:
    """Every parameter a node declared, without rclpy's own."""
    return set(node.list_parameters([], 0).names) - RCLPY_PARAMETERS


def config_fields(*configs: Any) -> set[str]:
    """The dotted leaf names of config dataclass instances or classes (instantiated with defaults)."""
    names: set[str] = set()
    for config in configs:
        instance = config() if isinstance(config, type) else config
        if not dataclasses.is_dataclass(instance):
            raise TypeError(f"{config!r} is not a config dataclass")
        names |= set(flatten(instance))
    return names
