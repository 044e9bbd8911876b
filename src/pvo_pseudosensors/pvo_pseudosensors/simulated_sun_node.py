"""simulated_sun: /ground_truth/sun_direction -> /pvo/sun/direction (GT-Sun-N, every N-th frame).

Parameters mirror :class:`~pvo_pseudosensors.simulated_sun.SimulatedSunConfig` (``mean_error_deg``,
``every_n``, ``covariance_floor_deg``, ``seed``); defaults in ``config/simulated_sun.yaml``. They are read
at start-up (the sensor's noise stream is seeded from them). Status (published/rejected counts) on
``/pvo/simulated_sun/status``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pvo_core.sun import vector_to_zenith_azimuth

from pvo_msgs.msg import SunDirection
from pvo_ros import OK, WARN, PvoNode, measurements, reliable, run_node, stamp_to_nanoseconds

from .simulated_sun import SimulatedSunConfig, SimulatedSunSensor


class SimulatedSunNode(PvoNode[SimulatedSunConfig, None]):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("simulated_sun", SimulatedSunConfig(), **kwargs)
        config = self.config
        self.sensor = SimulatedSunSensor(config)
        self.published = 0
        self.rejected = 0
        qos = reliable(100)
        self.publisher = self.create_publisher(SunDirection, "/pvo/sun/direction", measurements())
        self.create_subscription(SunDirection, "/ground_truth/sun_direction", self._on_truth, qos)
        self.get_logger().info(f"GT-Sun-{config.mean_error_deg:g}: every {config.every_n} frame(s), seed {config.seed}")

    def _on_truth(self, msg: SunDirection) -> None:
        truth = np.array([msg.direction.x, msg.direction.y, msg.direction.z])
        try:
            result = self.sensor.measure(truth)
        except ValueError as exc:
            self.rejected += 1
            self.problem(f"/ground_truth/sun_direction rejected at {msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d}: {exc}")
            self._status(msg, WARN, f"rejected: {exc}")
            return
        if result is None:
            return
        direction, covariance = result
        out = SunDirection()
        out.header = msg.header
        out.direction.x, out.direction.y, out.direction.z = (float(v) for v in direction)
        zenith, azimuth = vector_to_zenith_azimuth(direction)
        out.zenith = float(zenith)
        out.azimuth = float(azimuth)
        out.covariance = [float(v) for v in covariance.reshape(-1)]
        self.publisher.publish(out)
        self.published += 1
        self._status(msg, OK, "published")

    def _status(self, truth: SunDirection, level: int, message: str) -> None:
        values = {"published": self.published, "rejected": self.rejected, "every_n": self.config.every_n}
        self.publish_status(stamp_to_nanoseconds(truth.header.stamp), truth.header.frame_id, level, message, values)


def main(args: list[str] | None = None) -> None:
    run_node(SimulatedSunNode, "simulated_sun", args)


if __name__ == "__main__":
    main()
