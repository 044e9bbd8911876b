"""``diagnostic_msgs/DiagnosticArray`` status messages (``/pvo/<node>/status``) built one way for every node."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pvo_core.msgconv import fill_stamp

OK = 0  # DiagnosticStatus.OK
WARN = 1  # DiagnosticStatus.WARN
ERROR = 2  # DiagnosticStatus.ERROR


def status_array(stamp_ns: int, name: str, hardware_id: str, level: int, message: str, values: Mapping[str, Any]) -> Any:
    """One ``DiagnosticArray`` with one status; ``values`` become ``KeyValue`` pairs (``str(value)``)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    status = DiagnosticStatus()
    status.name = name
    status.hardware_id = hardware_id
    status.level = bytes([level])  # the field is a byte
    status.message = message
    status.values = [KeyValue(key=str(k), value=str(v)) for k, v in values.items()]
    array = DiagnosticArray()
    fill_stamp(array.header.stamp, stamp_ns)
    array.status = [status]
    return array


def status_values(array: Any) -> dict[str, str]:
    """The key/value pairs of the first status of a ``DiagnosticArray`` (for tests and tools)."""
    return {kv.key: kv.value for kv in array.status[0].values}


class ProblemLog:
    """Logs one warning per distinct kind of problem (the text before `` at ``), not one per frame."""

    def __init__(self, logger: Any) -> None:
        self._logger = logger
        self.last = ""

    def __call__(self, text: str) -> None:
        if text.split(" at ")[0] != self.last.split(" at ")[0]:
            self._logger.warning(text)
        self.last = text
