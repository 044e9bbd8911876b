"""``diagnostic_msgs/DiagnosticArray`` status messages (``/pvo/<node>/status``) built one way for every node."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from pvo_core.msgconv import fill_stamp

_STAMP = re.compile(r"-?\d+(\.\d+)?(e[-+]?\d+)? s\b")

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
    """Logs one warning per distinct problem: its text with the stamps (numbers followed by `` s``) taken
    out, so a new reason is always logged and a repeated one only once in ``repeat_every`` occurrences."""

    def __init__(self, logger: Any, repeat_every: int = 1000) -> None:
        self._logger = logger
        self._seen: dict[str, int] = {}
        self._repeat = repeat_every
        self.last = ""

    def __call__(self, text: str) -> None:
        key = _STAMP.sub("<t>", text)
        count = self._seen.get(key, 0)
        if count % self._repeat == 0:
            suffix = f" (seen {count} times before)" if count else ""
            self._logger.warning(text + suffix)
        if len(self._seen) > 10_000:  # unbounded distinct texts must not grow memory without bound
            self._seen.clear()
        self._seen[key] = count + 1
        self.last = text
