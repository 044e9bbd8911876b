"""sun_bcnn: /stereo/left/image_rect -> /pvo/sun/direction, the sun from the image by Sun-BCNN (thesis ch. 5).

Parameters mirror :class:`~pvo_pseudosensors.sun_bcnn.estimator.SunBCNNSensorConfig` (``model``, ``every_n``,
``samples``, ``mode``, ``seed``, ``threads``, ``equalize``); defaults in ``config/sun_bcnn.yaml``. A model that cannot be
loaded, or an image it cannot take, is reported on ``/pvo/sun_bcnn/status`` (and once in the log) and the
node keeps running: it publishes nothing rather than a guess.
"""

from __future__ import annotations

from typing import Any

from pvo_core.msgconv import image_to_array
from sensor_msgs.msg import Image

from pvo_msgs.msg import SunDirection
from pvo_ros import ERROR, OK, WARN, PvoNode, measurements, reliable, run_node, stamp_to_nanoseconds

from .sun_bcnn.estimator import SunBCNNSensor, SunBCNNSensorConfig
from .sun_bcnn.infer import card_fusion, fusion_arguments


class SunBCNNNode(PvoNode[SunBCNNSensorConfig, None]):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("sun_bcnn", SunBCNNSensorConfig(), status_topic="/pvo/sun_bcnn/status", **kwargs)
        self.sensor, self.model_error = self.load(lambda: SunBCNNSensor(self.config), "Sun-BCNN model")
        self.images = 0
        self.published = 0
        self.rejected = 0
        self.publisher = self.create_publisher(SunDirection, "/pvo/sun/direction", measurements())
        self.create_subscription(Image, "/stereo/left/image_rect", self._on_image, reliable(10))
        if self.sensor is not None:
            card, calibration = self.sensor.card, self.sensor.calibration
            self.get_logger().info(
                f"Sun-BCNN {self.sensor.height}x{self.sensor.width}, every {self.config.every_n} image(s), "
                f"{self.config.samples} {self.sensor.mode} MC samples, covariance scale {calibration.scale:.3g}, "
                f"tau {calibration.tau:.4g} (calibrated in {card.calibration.get('mode', 'an unrecorded mode')})"
            )
            try:
                fusion = card_fusion(card)
            except ValueError as exc:
                fusion = {}
                self.problem(f"the model card's fusion settings are unusable: {exc}")
            if fusion:  # the fusion node cannot read the card: say what it should be given
                self.get_logger().info(f"its card asks the fusion node for: {fusion_arguments(fusion)}")

    def _on_image(self, msg: Image) -> None:
        stamp = stamp_to_nanoseconds(msg.header.stamp)
        self.images += 1
        if (self.images - 1) % self.config.every_n:
            return
        if self.sensor is None:
            self._status(stamp, msg.header.frame_id, ERROR, f"no model: {self.model_error}")
            return
        try:
            estimate = self.sensor.estimate(image_to_array(msg))
        except ValueError as exc:
            self.rejected += 1
            self.problem(f"image at {stamp * 1e-9:.3f} s rejected: {exc}")
            self._status(stamp, msg.header.frame_id, WARN, f"image rejected: {exc}")
            return
        out = SunDirection()
        out.header = msg.header
        out.direction.x, out.direction.y, out.direction.z = (float(v) for v in estimate.direction)
        out.zenith = estimate.zenith
        out.azimuth = estimate.azimuth
        out.covariance = [float(v) for v in estimate.covariance.reshape(-1)]
        self.publisher.publish(out)
        self.published += 1
        self._status(stamp, msg.header.frame_id, OK, "published")

    def _status(self, stamp: int, frame_id: str, level: int, message: str) -> None:
        values = {"images": self.images, "published": self.published, "rejected": self.rejected}
        self.publish_status(stamp, frame_id, level, message, values)


def main(args: list[str] | None = None) -> None:
    run_node(SunBCNNNode, "sun_bcnn", args)


if __name__ == "__main__":
    main()
