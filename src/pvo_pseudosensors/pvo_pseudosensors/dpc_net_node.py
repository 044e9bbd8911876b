"""dpc_net: stereo images + /pvo/vo/relative -> /pvo/dpc/correction, DPC-Net's correction of the VO over Δp
frames (thesis ch. 6), fused by the fusion node's correction factor (the smoother relaxes the pose graph).

Parameters mirror :class:`~pvo_pseudosensors.dpc_net.estimator.DPCNetSensorConfig` (``model``, ``threads``,
``lost_variance``, ``any_rig``); defaults in ``config/dpc_net.yaml``. The right camera_info is checked against
the model card's rig (image size, focal length, baseline): another rig's camera gets no correction (unless
``any_rig``). A model that cannot be loaded, a stereo pair it cannot take, a window it cannot correct (a VO gap
or lost frame inside it, a missing pair, a size change) are reported on ``/pvo/dpc_net/status``; the node keeps
running.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pvo_core.msgconv import fill_pose, image_to_array, pose_to_matrix
from sensor_msgs.msg import CameraInfo, Image

from pvo_msgs.msg import RelativePose
from pvo_ros import ERROR, OK, WARN, PvoNode, fill_stamp, measurements, reliable, run_node, stamp_to_nanoseconds

from .dpc_net.estimator import DPCNetSensor, DPCNetSensorConfig

#: what the status says when the model card's calibration measures no axis (`pvo dpc-net calibrate --drives` found
#: no weighing that lowered the mean m-ATE within its harm tolerance on every validation drive, or no axis improved
#: on the validation windows)
NOTHING_FUSED = "the model card's calibration measures no axis; the corrections carry no weight"


class DPCNetNode(PvoNode[DPCNetSensorConfig, None]):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("dpc_net", DPCNetSensorConfig(), status_topic="/pvo/dpc_net/status", **kwargs)
        self.sensor, self.model_error = self.load(lambda: DPCNetSensor(self.config), "DPC-Net model")
        if self.sensor is not None and not self.sensor.measures_anything:
            # published all the same (the graph stays whole), each axis marked unmeasured
            self.get_logger().warning(f"{self.config.model or 'dpc_net'}: {NOTHING_FUSED}")
        if self.sensor is not None and self.sensor.vo_differences:
            # the node cannot see the stereo_vo node's parameters: it says which VO its corrections are for
            listed = " ".join(f"-p {name}:={value}" for name, value in self.sensor.vo_differences.items())
            self.get_logger().info(f"{self.config.model or 'dpc_net'} corrects the VO run with {listed}")
        self.lefts: dict[int, Image] = {}
        self.vo_frame_id = ""
        self.published = 0
        self.rejected = 0
        self.publisher = self.create_publisher(RelativePose, "/pvo/dpc/correction", measurements())
        self.create_subscription(Image, "/stereo/left/image_rect", lambda m: self._on_image(m, "left"), reliable(10))
        self.create_subscription(Image, "/stereo/right/image_rect", lambda m: self._on_image(m, "right"), reliable(10))
        self.create_subscription(RelativePose, "/pvo/vo/relative", self._on_vo, reliable(100))
        self.rights: dict[int, Image] = {}
        self.camera: tuple[int, int, float, float] | None = None
        self.refusal: str | None = None  # the rig check's verdict on this camera, when it refuses
        self.create_subscription(CameraInfo, "/stereo/right/camera_info", self._on_camera_info, reliable(10))

    def _on_camera_info(self, msg: CameraInfo) -> None:
        """The rig check, once per distinct camera (size, focal length, baseline from the right P: P[3] = -f b)."""
        focal = float(msg.p[0])
        if self.sensor is None or focal <= 0.0:
            return
        camera = (int(msg.width), int(msg.height), focal, -float(msg.p[3]) / focal)
        if camera == self.camera:
            return
        self.camera = camera
        refusals, warnings = self.sensor.check_camera(*camera)
        stamp = stamp_to_nanoseconds(msg.header.stamp)
        self.refusal = None
        if refusals:
            text = f"not this DPC-Net model's rig: {'; '.join(refusals)}"
            self.problem(f"camera at {stamp * 1e-9:.3f} s: {text}" + (" (any_rig: used anyway)" if self.config.any_rig else ""))
            if not self.config.any_rig:
                self.refusal = text
            self._status(stamp, WARN if self.config.any_rig else ERROR, text)
        elif warnings:
            self._status(stamp, OK, "rig check: " + "; ".join(warnings))

    def _on_image(self, msg: Image, side: str) -> None:
        stamp = stamp_to_nanoseconds(msg.header.stamp)
        (self.lefts if side == "left" else self.rights)[stamp] = msg
        for store in (self.lefts, self.rights):
            while len(store) > 32:
                del store[min(store)]
        if self.sensor is None or stamp not in self.lefts or stamp not in self.rights:
            return
        left, right = self.lefts.pop(stamp), self.rights.pop(stamp)
        try:
            waited = self.sensor.add_images(stamp, image_to_array(left), image_to_array(right))
        except ValueError as exc:
            self.rejected += 1
            self.problem(f"stereo pair at {stamp * 1e-9:.3f} s: {exc}")
            self._status(stamp, WARN, f"stereo pair rejected: {exc}")
            return
        if waited is not None:  # the VO had completed this window before its images came
            self._publish(waited, self.vo_frame_id)

    def _on_vo(self, msg: RelativePose) -> None:
        stamp = stamp_to_nanoseconds(msg.header.stamp)
        self.vo_frame_id = msg.header.frame_id  # the corrections' frame: the VO transforms' own
        if self.sensor is None:
            self._status(stamp, ERROR, f"no model: {self.model_error}")
            return
        if self.refusal is not None:
            self.rejected += 1
            self._status(stamp, ERROR, self.refusal)
            return
        try:
            transform = pose_to_matrix(msg.pose.pose)
        except ValueError as exc:
            self.rejected += 1
            self._status(stamp, WARN, f"VO transform rejected: {exc}")
            return
        covariance = np.reshape(np.asarray(msg.pose.covariance, dtype=float), (6, 6))
        correction = self.sensor.add_vo(stamp_to_nanoseconds(msg.reference_stamp), stamp, transform, covariance)
        if self.sensor.dropped is not None:  # this window, or an older one that waited for images in vain
            self.rejected += 1
            self._status(stamp, WARN, self.sensor.dropped)
        if correction is not None:
            self._publish(correction, self.vo_frame_id)

    def _publish(self, correction: Any, frame_id: str) -> None:
        """The corrected transform over its window, stamped at the window's last frame."""
        out = RelativePose()
        fill_stamp(out.header.stamp, correction.stamp)
        out.header.frame_id = frame_id
        fill_stamp(out.reference_stamp, correction.reference_stamp)
        fill_pose(out.pose.pose, correction.transform)
        out.pose.covariance = [float(v) for v in correction.covariance.reshape(-1)]
        out.rotation_only = False
        self.publisher.publish(out)
        self.published += 1
        if self.sensor is not None and not self.sensor.measures_anything:
            self._status(correction.stamp, WARN, f"published with no axis measured: {NOTHING_FUSED}")
        else:
            self._status(correction.stamp, OK, "published")

    def _status(self, stamp: int, level: int, message: str) -> None:
        values = {"published": self.published, "rejected": self.rejected}
        self.publish_status(stamp, "camera_left_optical", level, message, values)


def main(args: list[str] | None = None) -> None:
    run_node(DPCNetNode, "dpc_net", args)


if __name__ == "__main__":
    main()
