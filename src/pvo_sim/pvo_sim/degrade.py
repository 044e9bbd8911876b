"""Image and calibration degradations for the pseudo-sensor studies, each a flag with a strength.

Applied to the rendered 8-bit images in this order: radial distortion then crop (thesis ch. 6: an
output pixel at normalised radius r shows the scene at r (1 + kappa r^2), cropped to the valid centre
and scaled back to the full size), horizontal motion blur (a box kernel of ``blur_px`` pixels), exposure changes
(a smooth seeded gain per frame, the same for both cameras), sensor noise (Gaussian, grey levels).
``focal_scale`` and ``baseline_scale`` write a wrong ``calib.txt`` while rendering with the true one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Degradations:
    distortion: float | tuple[float, ...] = 0.0  # plumb-bob radial coefficients k1 [, k2, k3]; one number is k1
    blur_px: float = 0.0
    exposure: float = 0.0  # relative gain amplitude, e.g. 0.3 = +-30 %
    noise: float = 0.0  # grey levels (std)
    focal_scale: float = 1.0
    baseline_scale: float = 1.0
    texture_poor: float = 0.0  # urban: fraction of buildings with plain, untextured walls
    moving_vehicles: int = 3
    # m/s, each vehicle's own (a draw within +-30 %): past a stopped or crawling camera too; 0: each vehicle replays
    # the camera's own path in the oncoming lane, shifted in time, at the camera's speed of another moment
    vehicle_speed: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.distortion, int | float):  # a YAML list from a manifest, or the command's numbers
            object.__setattr__(self, "distortion", tuple(float(v) for v in self.distortion))
            if not 1 <= len(self.distortion) <= 3:
                raise ValueError(f"--distortion takes one to three coefficients (k1 k2 k3), got {len(self.distortion)}")
        checks = [
            (all(-0.5 <= k <= 0.5 for k in self.radial), "--distortion coefficients must be in [-0.5, 0.5]"),
            (0.0 <= self.blur_px <= 50.0, "--blur must be in [0, 50] px"),
            (0.0 <= self.exposure < 1.0, "--exposure must be in [0, 1)"),
            (self.noise >= 0.0, "--noise must be >= 0"),
            (self.focal_scale > 0.0 and self.baseline_scale > 0.0, "--focal-scale and --baseline-scale must be positive"),
            (0.0 <= self.texture_poor <= 1.0, "--texture-poor must be in [0, 1]"),
            (0 <= self.moving_vehicles <= 20, "--moving must be in [0, 20]"),
            (0.0 <= self.vehicle_speed <= 40.0, f"--vehicle-speed must be in [0, 40] m/s, got {self.vehicle_speed}"),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(message)

    @property
    def radial(self) -> tuple[float, float, float]:
        """(k1, k2, k3) of the plumb-bob radial model r_d = r (1 + k1 r² + k2 r⁴ + k3 r⁶)."""
        values = (self.distortion,) if isinstance(self.distortion, int | float) else tuple(self.distortion)
        return tuple(float(v) for v in values) + (0.0,) * (3 - len(values))  # type: ignore[return-value]

    @property
    def touches_images(self) -> bool:
        return bool(any(self.radial) or self.blur_px or self.exposure or self.noise)


def exposure_gains(frames: int, amplitude: float, seed: int) -> NDArray[np.float64]:
    """Smooth per-frame gains 1 + amplitude * (sum of two seeded slow sinusoids)/2."""
    if amplitude == 0.0:
        return np.ones(frames)
    rng = np.random.default_rng(seed + 104729)
    k = np.arange(frames)
    periods = rng.uniform(20, 80, 2)
    phases = rng.uniform(0, 2 * np.pi, 2)
    wave = 0.5 * (np.sin(2 * np.pi * k / periods[0] + phases[0]) + np.sin(2 * np.pi * k / periods[1] + phases[1]))
    return 1.0 + amplitude * wave


def distortion_maps(
    width: int, height: int, focal: float, coefficients: float | tuple[float, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap maps giving the radially distorted, cropped image (same size) from the pinhole render.

    ``coefficients``: k1 or (k1, k2, k3) of the plumb-bob model (the thesis's ch. 6 uses (-0.3, 0.2, 0.01)). An
    output pixel at normalised radius r samples the render at ``s x f(s r)``, f(q) = 1 + k1 q² + k2 q⁴ + k3 q⁶;
    the crop factor ``s <= 1`` keeps every sample inside the render (s = 1 when the corner already samples
    inside). ``ValueError`` when the model folds the image (r f(r) not increasing out to the corner).
    """
    k1, k2, k3 = Degradations(distortion=coefficients).radial

    def factor(q: np.ndarray | float) -> np.ndarray | float:
        q2 = np.square(q)
        return 1.0 + k1 * q2 + k2 * q2**2 + k3 * q2**3

    cu, cv = (width - 1) / 2.0, (height - 1) / 2.0
    corner = np.hypot(cu, cv) / focal
    radii = np.linspace(0.0, corner, 512)
    if np.any(np.diff(radii * factor(radii)) <= 0.0):
        raise ValueError(
            f"--distortion {k1:g} {k2:g} {k3:g} folds the image: r (1 + k1 r² + k2 r⁴ + k3 r⁶) must grow to the corner"
        )
    crop = 1.0
    if corner * factor(corner) > corner:
        lo, hi = 0.0, 1.0
        for _ in range(60):  # bisection on s f(s c) = 1
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if mid * factor(mid * corner) < 1.0 else (lo, mid)
        crop = lo
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    x = (u - cu) / focal * crop
    y = (v - cv) / focal * crop
    scale = factor(np.hypot(x, y))
    return (cu + focal * x * scale).astype(np.float32), (cv + focal * y * scale).astype(np.float32)


@dataclass(frozen=True)
class CameraModel:
    """The sensor and its processing, between the scene radiance MuJoCo renders (taken as linear light, 0-255)
    and the 8-bit image a camera writes: exposure, vignetting, shot and read noise, gamma, compression.

    auto_exposure: the gain drives the mean encoded brightness towards ``target`` (0-1), adapting by
    ``adaptation`` of the correction per frame as a real auto-exposure does (the same gain for both cameras,
    metered on the left); otherwise the gain is ``gain``. vignetting: relative fall-off at the image corners
    (quadratic in the radius). full_well: electrons at saturation, for shot noise (0: none); read_noise: std
    in grey levels of the linear signal. gamma: the encoding exponent (image = linear^(1/gamma)); 1 keeps the
    render linear. sharpening: the in-camera unsharp mask (amount; radius 1 px) most machine-vision cameras
    apply after encoding. jpeg_quality: 1-100 compresses each image, 0 writes it losslessly."""

    auto_exposure: bool = True
    target: float = 0.42
    gain: float = 1.0
    adaptation: float = 0.3
    gamma: float = 2.2
    vignetting: float = 0.25
    full_well: float = 6000.0
    read_noise: float = 1.0
    sharpening: float = 1.0
    jpeg_quality: int = 0

    def __post_init__(self) -> None:
        checks = [
            (0.05 <= self.target <= 0.95, "camera target brightness must be in [0.05, 0.95]"),
            (self.gain > 0.0, "camera gain must be positive"),
            (0.0 < self.adaptation <= 1.0, "camera adaptation must be in (0, 1]"),
            (0.5 <= self.gamma <= 4.0, "camera gamma must be in [0.5, 4]"),
            (0.0 <= self.vignetting < 1.0, "camera vignetting must be in [0, 1)"),
            (self.full_well >= 0.0 and self.read_noise >= 0.0, "camera full_well and read_noise must be >= 0"),
            (0 <= self.jpeg_quality <= 100, "camera jpeg_quality must be in [0, 100] (0: no compression)"),
            (0.0 <= self.sharpening <= 3.0, "camera sharpening must be in [0, 3]"),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(message)

    @classmethod
    def linear(cls) -> CameraModel:
        """The render as it is: no exposure control, noise, vignetting, gamma or compression."""
        return cls(auto_exposure=False, gamma=1.0, vignetting=0.0, full_well=0.0, read_noise=0.0, sharpening=0.0)


class ImageDegrader:
    """Optics (distortion, blur), then the camera (exposure, vignetting, noise, gamma, compression), then the
    extra noise of the degradation study. Noise draws are seeded per (frame, camera), whatever the call order."""

    def __init__(
        self,
        degradations: Degradations,
        width: int,
        height: int,
        focal: float,
        frames: int,
        seed: int,
        camera: CameraModel | None = None,
    ) -> None:
        self.d = degradations
        self.camera = camera or CameraModel.linear()
        self.seed = seed
        self.gains = exposure_gains(frames, degradations.exposure, seed)
        self.rng = np.random.default_rng(seed + 15485863)
        self.maps = distortion_maps(width, height, focal, degradations.distortion) if any(degradations.radial) else None
        v, u = np.mgrid[0:height, 0:width].astype(np.float32)
        radius2 = ((u - (width - 1) / 2) ** 2 + (v - (height - 1) / 2) ** 2) / (((width - 1) / 2) ** 2 + ((height - 1) / 2) ** 2)
        self.vignette = 1.0 - self.camera.vignetting * radius2
        self.exposure_gain: float | None = None
        self._metered_frame = -1

    def __call__(self, image: NDArray[np.uint8], frame: int, camera: int = 0) -> NDArray[np.uint8]:
        """The degraded image (H, W) or (H, W, 3) uint8 of ``camera`` (0 left, 1 right) at ``frame``."""
        import cv2

        out = image
        if self.maps is not None:
            out = cv2.remap(out, self.maps[0], self.maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if self.d.blur_px >= 1.0:
            size = round(self.d.blur_px)
            kernel = np.full((1, size), 1.0 / size, dtype=np.float32)
            out = cv2.filter2D(out, -1, kernel, borderType=cv2.BORDER_REPLICATE)
        out = self._sensor(out, frame, camera)
        if self.d.noise:
            value = out.astype(np.float32) + self.rng.normal(0.0, self.d.noise, out.shape).astype(np.float32)
            out = np.clip(np.round(value), 0, 255).astype(np.uint8)
        return out

    def _sensor(self, image: NDArray[np.uint8], frame: int, camera: int) -> NDArray[np.uint8]:
        model = self.camera
        linear = image.astype(np.float32) / 255.0
        vignette = self.vignette if image.ndim == 2 else self.vignette[:, :, None]
        if model.vignetting:
            linear = linear * vignette
        if frame != self._metered_frame:  # meter once per frame (on the first camera given, the left)
            self._metered_frame = frame
            gain = model.gain
            if model.auto_exposure:
                wanted = model.target**model.gamma / max(float(linear.mean()), 1e-4)
                if self.exposure_gain is None:
                    gain = wanted
                else:
                    gain = float(np.exp(np.log(self.exposure_gain) + model.adaptation * np.log(wanted / self.exposure_gain)))
            self.exposure_gain = gain
        gain = self.exposure_gain * float(self.gains[frame])
        if gain != 1.0:
            linear = linear * np.float32(gain)
        if model.full_well or model.read_noise:
            rng = np.random.default_rng([self.seed, frame, camera, 7])
            variance = np.clip(linear, 0.0, 1.0) / model.full_well if model.full_well else 0.0
            variance = variance + (model.read_noise / 255.0) ** 2
            linear = linear + np.sqrt(variance).astype(np.float32) * rng.standard_normal(linear.shape, dtype=np.float32)
        encoded = np.clip(linear, 0.0, 1.0)
        if model.gamma != 1.0:
            encoded = encoded ** np.float32(1.0 / model.gamma)
        if model.sharpening:
            import cv2

            blurred = cv2.GaussianBlur(encoded, (0, 0), 1.0)
            encoded = np.clip(encoded + np.float32(model.sharpening) * (encoded - blurred), 0.0, 1.0)
        out = np.round(encoded * 255.0).astype(np.uint8)
        if model.jpeg_quality:
            import cv2

            _ok, data = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(model.jpeg_quality)])
            out = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        return out
