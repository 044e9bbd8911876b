"""hydranet: /stereo/left/image_rect -> /pvo/hydranet/rotation, the rotation between consecutive images by
HydraNet (thesis ch. 7).

Parameters mirror :class:`~pvo_pseudosensors.hydranet.estimator.HydraNetSensorConfig` (``model``,
``max_gap``, ``threads``); defaults in ``config/hydranet.yaml``. Each message is a ``RelativePose`` with
``rotation_only: true``: the quaternion of C_k,k-1 (T_to,from with zero translation) and Sigma = Sigma_e +
Sigma_a in its rotation block (the translation block is marked unmeasured with 9999). A model that cannot be
loaded, an image it cannot take, the first image and a size change are reported on
``/pvo/hydranet/status``; the node keeps running and publishes nothing rather than a guess.
"""

from __future__ import annotations

from typing import Any

from pvo_core.msgconv import image_to_array
from sensor_msgs.msg import Image

from pvo_msgs.msg import RelativePose
from pvo_ros import ERROR, OK, WARN, PvoNode, fill_stamp, measurements, reliable, run_node, stamp_to_nanoseconds

from .hydranet.estimator import HydraNetSensor, HydraNetSensorConfig, RotationEstimate


def rotation_message(estimate: RotationEstimate, header: Any) -> RelativePose:
    out = RelativePose()
    out.header = header
    fill_stamp(out.reference_stamp, estimate.earlier_stamp)
    w, x, y, z = (float(v) for v in estimate.quaternion)
    out.pose.pose.orientation.w, out.pose.pose.orientation.x = w, x
    out.pose.pose.orientation.y, out.pose.pose.orientation.z = y, z
    out.pose.covariance = [float(v) for v in estimate.pose_covariance.reshape(-1)]
    out.rotation_only = True
    return out


def widening_words(calibration: dict[str, Any]) -> str:
    """What the start-up line says of a card's covariance widening (the user should know the covariance is not the
    network's alone)."""
    words = ""
    spread = calibration.get("spread_widening")
    if isinstance(spread, dict):
        gamma = float(spread.get("gamma", 0.0))
        words += (
            f", Sigma_a widened by 1 + {gamma:g} max(0, r - 1), r the heads' spread over its reference (card: spread_widening)"
        )
    shortfall = calibration.get("flow_shortfall_widening")
    if isinstance(shortfall, dict):
        gamma = float(shortfall.get("gamma", 0.0))
        words += (
            f", and by 1 + {gamma:.4g} max(0, d - 1), d the flow's shortfall against the images' shift over its reference "
            "(card: flow_shortfall_widening)"
        )
    return words


class HydraNetNode(PvoNode[HydraNetSensorConfig, None]):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("hydranet", HydraNetSensorConfig(), status_topic="/pvo/hydranet/status", **kwargs)
        self.sensor, self.model_error = self.load(lambda: HydraNetSensor(self.config), "HydraNet model")
        self.images = 0
        self.published = 0
        self.rejected = 0
        self.publisher = self.create_publisher(RelativePose, "/pvo/hydranet/rotation", measurements())
        self.create_subscription(Image, "/stereo/left/image_rect", self._on_image, reliable(10))
        if self.sensor is not None:
            card = self.sensor.card
            self.get_logger().info(
                f"HydraNet {self.sensor.height}x{self.sensor.width} flow"
                + ("" if self.sensor.flow_prior == "none" else f" (Farneback from the global {self.sensor.flow_prior})")
                + f", {card.hyperparameters['heads']} heads, "
                f"{card.hyperparameters['covariance']} aleatoric covariance"
                + ("" if self.sensor.pitch_deg is None else f", told the camera's pitch {self.sensor.pitch_deg:g} deg")
                + widening_words(card.calibration or {})
            )
            if self.sensor.pitch_deg is None and self.config.camera_pitch_deg != 0.0:
                self.get_logger().warning(
                    f"camera_pitch_deg {self.config.camera_pitch_deg:g} ignored: this model has no pitch input "
                    "(the default model, hydranet, has)"
                )

    def _on_image(self, msg: Image) -> None:
        stamp = stamp_to_nanoseconds(msg.header.stamp)
        self.images += 1
        if self.sensor is None:
            self._status(stamp, msg.header.frame_id, ERROR, f"no model: {self.model_error}")
            return
        try:
            estimate = self.sensor.estimate(image_to_array(msg), stamp)
        except ValueError as exc:
            self.rejected += 1
            self.problem(f"image at {stamp * 1e-9:.3f} s: {exc}")
            self._status(stamp, msg.header.frame_id, WARN, f"image rejected: {exc}")
            return
        if estimate is None:
            self._status(stamp, msg.header.frame_id, OK, "waiting for the next image (no predecessor to pair with)")
            return
        self.publisher.publish(rotation_message(estimate, msg.header))
        self.published += 1
        self._status(stamp, msg.header.frame_id, OK, "published")

    def _status(self, stamp: int, frame_id: str, level: int, message: str) -> None:
        values = {"images": self.images, "published": self.published, "rejected": self.rejected}
        self.publish_status(stamp, frame_id, level, message, values)


def main(args: list[str] | None = None) -> None:
    run_node(HydraNetNode, "hydranet", args)


if __name__ == "__main__":
    main()
