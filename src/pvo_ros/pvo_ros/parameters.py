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
    """The typed config a node runs with, bound to its declared parameters.

    A start-up value of another type than its field's is one ``ValueError`` line naming the parameter, not
    rclpy's traceback; an integer given for a float field (``-p inputs.vo.lost_variance:=1000``) is the number
    meant and is taken as a float, as are integer lists for lists of floats."""

    def __init__(self, node: Any, defaults: C, what: str) -> None:
        from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException

        self._node = node
        self.what = what
        self.names = list(flatten(defaults))
        # rclpy keeps the start-up values (--ros-args -p, parameter files) by name until each is declared
        overrides: dict[str, Any] = getattr(node, "_parameter_overrides", {})
        for name, value in flatten(defaults).items():
            if node.has_parameter(name):
                raise ValueError(f"{what}: parameter {name} is declared by two configs")
            given = overrides.get(name)
            if given is not None:
                overrides[name] = _as_field_type(given, value)
            try:
                node.declare_parameter(name, value)
            except (InvalidParameterTypeException, InvalidParameterValueException):
                shown = given.value if given is not None else None
                raise ValueError(f"parameter {name} must be {_kind(value)}, got {shown!r}") from None
        values = {name: node.get_parameter(name).value for name in self.names}
        self.value: C = from_flat(values, defaults, what=what)

    def replaced(self, changes: dict[str, Any]) -> C:
        """The current config with ``changes`` (dotted names) applied and validated."""
        return from_flat({**flatten(self.value), **changes}, self.value, what=self.what)


def _as_field_type(given: Any, default: Any) -> Any:
    """An integer start-up value (or integer list) for a float field (or float list) as the float it means; any
    other value as given (a wrong type is then refused by the declaration)."""
    from rclpy.parameter import Parameter

    if isinstance(default, float) and not isinstance(default, bool) and given.type_ == Parameter.Type.INTEGER:
        return Parameter(given.name, Parameter.Type.DOUBLE, float(given.value))
    floats = isinstance(default, list | tuple) and default and all(isinstance(v, float) for v in default)
    if floats and given.type_ == Parameter.Type.INTEGER_ARRAY:
        return Parameter(given.name, Parameter.Type.DOUBLE_ARRAY, [float(v) for v in given.value])
    return given


def _kind(default: Any) -> str:
    """What a parameter with this default takes, in words."""
    if isinstance(default, bool):
        return "true or false"
    if isinstance(default, int):
        return "an integer"
    if isinstance(default, float):
        return "a number"
    if isinstance(default, str):
        return "a string"
    if isinstance(default, list | tuple):
        words = {float: "numbers", int: "integers", str: "strings", bool: "booleans"}
        kinds = {type(v) for v in default}
        return f"a list of {words.get(next(iter(kinds)), 'values') if len(kinds) == 1 else 'values'}"
    return f"a {type(default).__name__}"


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


def unknown_parameter_lines(node: Any) -> list[str]:
    """One line per start-up value (--ros-args -p, a parameter file) that names no parameter of ``node``: ROS
    ignores such a value, so a misspelt name would otherwise leave the default in force unseen."""
    import difflib

    declared = declared_parameter_names(node)
    given = set(getattr(node, "_parameter_overrides", {})) - declared - RCLPY_PARAMETERS
    lines = []
    for name in sorted(n for n in given if not n.startswith("qos_overrides.")):
        close = difflib.get_close_matches(name, sorted(declared), n=1)
        hint = f"; did you mean {close[0]}?" if close else ""
        lines.append(f"parameter {name} is not one of {node.get_name()}'s and is ignored{hint}")
    return lines
