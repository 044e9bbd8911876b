"""What every pvo node shares on the rclpy side (runner, typed parameters, diagnostics, stamps, QoS).

Stamps: :func:`pvo_core.msgconv.fill_stamp` / ``stamp_to_nanoseconds`` work on rclpy messages and are
re-exported here so that a node imports its ROS plumbing from one place.
"""

from pvo_core.msgconv import fill_stamp, stamp_to_nanoseconds

from .diagnostics import ERROR, OK, WARN, ProblemLog, status_array, status_values
from .node import PvoNode
from .parameters import ConfigParameters, ParameterPolicy, config_fields, declare_config, declared_parameter_names
from .qos import MEASUREMENT_HISTORY, SENSOR_QUEUE_DEPTH, every_message, kept_history_durability, measurements, reliable
from .runner import run_node

__all__ = [
    "ERROR",
    "MEASUREMENT_HISTORY",
    "OK",
    "SENSOR_QUEUE_DEPTH",
    "WARN",
    "ConfigParameters",
    "ParameterPolicy",
    "ProblemLog",
    "PvoNode",
    "config_fields",
    "declare_config",
    "declared_parameter_names",
    "every_message",
    "fill_stamp",
    "kept_history_durability",
    "measurements",
    "reliable",
    "run_node",
    "stamp_to_nanoseconds",
    "status_array",
    "status_values",
]
