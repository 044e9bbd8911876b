"""The Sun-BCNN network, its loss and its MC-dropout prediction.

A small CNN for a CPU (input and widths in :class:`SunBCNNConfig`), dropout after the convolutional blocks
and the fully connected layer, a unit-norm 3-vector output in the camera's optical frame (x right, y down,
z forward), trained with the loss 1 - s·ŝ (thesis eq. 5.3); optionally (``aleatoric``) a concentration kappa
of a von Mises-Fisher distribution about it, trained by its negative log-likelihood with the direction held
fixed and from a small head of its own on the pooled features, which it does not train (so the direction learns
exactly as the thesis's, and kappa learns how far off it tends to be). With ``bins`` the head classifies the
sun into directions spread over the sphere instead of regressing the vector (:func:`decode_bins`).
Prediction (MC dropout) is in :mod:`.infer`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import lru_cache

import torch
from torch import nn

from ..learning.checkpoint import ModelCard
from .config import ARCHITECTURE, SunBCNNConfig

CONCENTRATION_HIDDEN = 32  # units of the aleatoric head


class SunBCNN(nn.Module):
    def __init__(self, config: SunBCNNConfig) -> None:
        super().__init__()
        self.config = config
        layers: list[nn.Module] = []
        channels = 3 if config.colour else 1
        for width in config.widths:
            for stride, inputs in ((2, channels), (1, width)):
                layers.append(nn.Conv2d(inputs, width, 3, stride=stride, padding=1, bias=not config.batch_norm))
                if config.batch_norm:
                    layers.append(nn.BatchNorm2d(width))
                layers.append(nn.ReLU(inplace=True))
            layers.append(nn.Dropout2d(config.dropout))
            channels = width
        self.features = nn.Sequential(*layers)
        pooled = channels * (1 + config.grid[0] * config.grid[1])
        self.head = nn.Sequential(
            nn.Flatten(),
            nn.Linear(pooled, config.hidden),
            nn.ReLU(inplace=True),
            nn.Dropout(config.dropout),
            nn.Linear(config.hidden, config.bins or 3),
        )
        # kappa reads the pooled features without training them: the direction learns exactly as without it
        self.concentration = (
            nn.Sequential(nn.Linear(pooled, CONCENTRATION_HIDDEN), nn.ReLU(inplace=True), nn.Linear(CONCENTRATION_HIDDEN, 1))
            if config.aleatoric
            else None
        )

    def mc_dropout(self) -> SunBCNN:
        """Dropout on everywhere (an MC-dropout pass), everything else as in evaluation: batch normalisation
        keeps its running statistics, so a pass does not depend on the other images in its batch."""
        self.eval()
        for module in self.modules():
            if isinstance(module, nn.Dropout | nn.Dropout2d):
                module.train()
        return self

    @property
    def stem_length(self) -> int:
        """Layers of :attr:`features` before the first dropout: deterministic even in MC-dropout passes, so
        computed once per image however many passes follow."""
        return next(i for i, layer in enumerate(self.features) if isinstance(layer, nn.Dropout2d))

    def stem(self, image: torch.Tensor) -> torch.Tensor:
        """(B, C, H, W) in [0, 1] -> the first block's features, before its dropout."""
        x = (equalize_histograms(image) if self.config.equalize else image) - 0.5
        for layer in self.features[: self.stem_length]:
            x = layer(x)
        return x

    def pooled(self, image: torch.Tensor) -> torch.Tensor:
        """The backbone: (B, C, H, W) in [0, 1] -> (B, (1 + grid cells) x last width): max-pooled features and
        features average-pooled over a grid of image regions."""
        return self.pooled_from_stem(self.stem(image))

    def pooled_from_stem(self, x: torch.Tensor) -> torch.Tensor:
        """The backbone after :meth:`stem` (its dropouts live in training mode)."""
        for layer in self.features[self.stem_length :]:
            x = layer(x)
        regions = nn.functional.adaptive_avg_pool2d(x, self.config.grid).flatten(1)
        return torch.cat([x.amax(dim=(2, 3)), regions], dim=1)

    def outputs(self, pooled: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The head: pooled features -> (B, 3) unit vectors towards the sun and (B,) concentrations kappa
        (>= 1; None without the aleatoric output)."""
        raw, kappa = self.raw_outputs(pooled)
        if self.config.bins:
            return decode_bins(raw, sphere_directions(self.config.bins), self.config.decode_radius), kappa
        return nn.functional.normalize(raw, dim=1), kappa

    def raw_outputs(self, pooled: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The head before decoding: (B, 3) unnormalised vectors, or (B, bins) logits with ``bins``; and kappa."""
        raw = self.head(pooled)
        if self.concentration is None:
            return raw, None
        return raw, nn.functional.softplus(self.concentration(pooled.detach())[:, 0]) + 1.0

    def direction(self, pooled: torch.Tensor) -> torch.Tensor:
        """The head: pooled features -> (B, 3) unit vectors towards the sun."""
        return self.outputs(pooled)[0]

    def forward(self, image: torch.Tensor, with_concentration: bool = False, raw: bool = False):
        """(B, C, H, W) in [0, 1] -> (B, 3) unit vectors towards the sun; with_concentration: also the (B,)
        kappas, as :meth:`outputs` (through forward, so that DistributedDataParallel syncs the gradients); raw:
        the head's output before decoding (:meth:`raw_outputs`) in place of the vectors."""
        pooled = self.pooled(image)
        outputs, kappa = self.raw_outputs(pooled) if raw else self.outputs(pooled)
        return (outputs, kappa) if with_concentration else outputs


@lru_cache(maxsize=8)
def trainable_selection(text: str, config: SunBCNNConfig) -> tuple[str, ...]:
    """A fine-tune's ``trainable`` entries (:class:`~pvo_pseudosensors.learning.training.FineTune`) from a
    comma-separated ``text``: parameter-name prefixes (``features``, ``head``, ``concentration``), ``norm`` (the
    normalisation layers' affine parameters) and ``blocks:K``, the first K convolutional blocks of
    :attr:`SunBCNN.features` (K in 1..len(widths)). ValueError on a K out of range."""
    entries: list[str] = []
    for entry in (part.strip() for part in text.split(",")):
        if not entry.startswith("blocks:"):
            entries.append(entry)
            continue
        count = entry.removeprefix("blocks:")
        if not count.isdigit() or not 1 <= int(count) <= len(config.widths):
            raise ValueError(f"trainable entry {entry!r}: K must be 1 to {len(config.widths)}, the network's blocks")
        layers = SunBCNN(config).features
        ends = [i for i, layer in enumerate(layers) if isinstance(layer, nn.Dropout2d)]
        entries += [f"features.{i}." for i in range(ends[int(count) - 1]) if any(True for _ in layers[i].parameters())]
    return tuple(entries)


def sphere_directions(count: int) -> torch.Tensor:
    """(count, 3) unit vectors spread evenly over the sphere: a Fibonacci lattice, the same for every call
    (do not modify the cached tensor)."""
    index = torch.arange(count, dtype=torch.float64) + 0.5
    z = 1.0 - 2.0 * index / count
    radius = torch.sqrt(1.0 - z * z)
    longitude = math.pi * (1.0 + math.sqrt(5.0)) * index
    return torch.stack([radius * torch.cos(longitude), radius * torch.sin(longitude), z], dim=1).float()


def bin_spacing(count: int) -> float:
    """The typical angle (rad) between neighbouring directions of :func:`sphere_directions`: the side of a
    square of the sphere's area / count."""
    return math.sqrt(4.0 * math.pi / count)


def soft_bin_targets(sun: torch.Tensor, count: int) -> torch.Tensor:
    """(B, count) training targets for suns (B, 3): a von Mises-Fisher kernel about each sun over the
    directions, one bin spacing wide (a sun between bins shares itself among them, so the decoded mean can land
    between bins)."""
    directions = sphere_directions(count).to(sun.dtype)
    return torch.softmax((sun @ directions.T - 1.0) / bin_spacing(count) ** 2, dim=1)


def decode_bins(logits: torch.Tensor, directions: torch.Tensor, radius: float = 4.0) -> torch.Tensor:
    """(B, N) logits over the directions (N, 3) -> (B, 3) unit vectors: the probability-weighted mean of the
    directions within ``radius`` bin spacings of the most probable one — the mode, refined between bins (the soft
    targets of a sun decode to it within 0.25 deg at 512 bins; two spacings would truncate the kernel and err
    up to 3 deg); a second mode farther away (the sun ahead or behind) does not drag it. A radius of pi / spacing
    or more (``math.inf``) is the mean over the whole sphere: the regressed vector's answer."""
    probabilities = torch.softmax(logits, dim=1)
    directions = directions.to(logits.dtype)
    angle = radius * bin_spacing(len(directions))
    if angle >= math.pi:
        return nn.functional.normalize(probabilities @ directions, dim=1)
    mode = directions[logits.argmax(dim=1)]
    near = (mode @ directions.T) > math.cos(angle)
    return nn.functional.normalize((probabilities * near) @ directions, dim=1)


GREY_LEVELS = 256


def equalize_histograms(images: torch.Tensor) -> torch.Tensor:
    """(B, C, H, W) in [0, 1] -> each channel of each image histogram-equalised over 256 grey levels, as OpenCV's
    ``equalizeHist`` does to the 8-bit image (level v -> round(255 (cdf(v) - cdf(v_min)) / (n - cdf(v_min))), v_min
    the darkest level present); a channel of one grey level is left as it is. No gradient flows to the images."""
    count, channels, height, width = images.shape
    pixels = height * width
    with torch.no_grad():
        levels = (images.clamp(0.0, 1.0) * (GREY_LEVELS - 1)).round().long().reshape(count * channels, pixels)
        histogram = torch.zeros(count * channels, GREY_LEVELS, dtype=torch.float64)
        histogram.scatter_add_(1, levels, torch.ones_like(levels, dtype=torch.float64))
        cdf = histogram.cumsum(1)
        darkest = cdf.gather(1, levels.amin(1, keepdim=True))  # pixels at the darkest level present
        spread = pixels - darkest
        lookup = ((cdf - darkest) * (GREY_LEVELS - 1) / spread.clamp_min(1.0)).round().clamp(0, GREY_LEVELS - 1)
        equalised = lookup.gather(1, levels).to(images.dtype) / (GREY_LEVELS - 1)
        flat = images.reshape(count * channels, pixels)
        equalised = torch.where(spread > 0, equalised, flat)
    return equalised.reshape(images.shape)


def photometric_jitter(images: torch.Tensor) -> torch.Tensor:
    """Per image: a gain in [0.6, 1.4], a gamma in [exp(-0.4), exp(0.4)] and Gaussian noise of up to 3 % —
    what another camera, exposure or sensor would change, not where the sun is (the global RNG: seeded)."""
    n = len(images)
    gain = torch.empty(n, 1, 1, 1).uniform_(0.6, 1.4)
    gamma = torch.exp(torch.empty(n, 1, 1, 1).uniform_(-0.4, 0.4))
    noise = torch.empty(n, 1, 1, 1).uniform_(0.0, 0.03) * torch.randn_like(images)
    return ((images.clamp(0.0, 1.0) * gain).clamp(1e-6, 1.0) ** gamma + noise).clamp(0.0, 1.0)


def rotation_matrices(yaw: torch.Tensor, pitch: torch.Tensor, roll: torch.Tensor) -> torch.Tensor:
    """(B, 3, 3) rotations of the camera optical frame (x right, y down, z forward): R = Rz(roll) Ry(yaw) Rx(pitch),
    angles (B,) in radians."""
    zero, one = torch.zeros_like(yaw), torch.ones_like(yaw)

    def matrix(*rows: torch.Tensor) -> torch.Tensor:
        return torch.stack(rows, dim=-1).reshape(-1, 3, 3)

    c, s = torch.cos(pitch), torch.sin(pitch)
    about_x = matrix(one, zero, zero, zero, c, -s, zero, s, c)
    c, s = torch.cos(yaw), torch.sin(yaw)
    about_y = matrix(c, zero, s, zero, one, zero, -s, zero, c)
    c, s = torch.cos(roll), torch.sin(roll)
    about_z = matrix(c, -s, zero, s, c, zero, zero, zero, one)
    return about_z @ about_y @ about_x


def rotate_cameras(
    images: torch.Tensor, sun: torch.Tensor, camera: torch.Tensor, rotation: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Images (B, C, H, W) as a pinhole camera (B, 4: fx, fy, cx, cy in pixels of these images) would have
    seen them after turning by ``rotation`` (B, 3, 3; a point X in the old camera frame is R X in the new), and
    the sun vectors (B, 3) in the new frame. Each output pixel samples the old image at K Rᵀ K⁻¹ of itself
    (bilinear; outside the old image the nearest border pixel)."""
    batch, _, height, width = images.shape
    fx, fy, cx, cy = camera.unbind(dim=1)
    intrinsics = torch.zeros(batch, 3, 3, dtype=images.dtype)
    intrinsics[:, 0, 0], intrinsics[:, 1, 1], intrinsics[:, 0, 2], intrinsics[:, 1, 2] = fx, fy, cx, cy
    intrinsics[:, 2, 2] = 1.0
    new_to_old = intrinsics @ rotation.transpose(1, 2) @ torch.linalg.inv(intrinsics)
    u = torch.arange(width, dtype=images.dtype)[None, None, :]
    v = torch.arange(height, dtype=images.dtype)[None, :, None]
    m = new_to_old[:, :, :, None, None]  # each coefficient (B, 1, 1), broadcast over the (H, W) pixels

    def row(i: int) -> torch.Tensor:
        return m[:, i, 0] * u + m[:, i, 1] * v + m[:, i, 2]

    depth = row(2).clamp_min(1e-6)  # turns this small keep every ray in front of the old camera
    grid = torch.stack([(2.0 * row(0) / depth + 1.0) / width - 1.0, (2.0 * row(1) / depth + 1.0) / height - 1.0], dim=-1)
    warped = nn.functional.grid_sample(images, grid, mode="bilinear", padding_mode="border", align_corners=False)
    return warped, (rotation @ sun[:, :, None])[:, :, 0]


def random_rotations(count: int, max_yaw_deg: float) -> torch.Tensor:
    """(count, 3, 3) camera turns: yaw uniform in ±max_yaw_deg, pitch and roll in ±max_yaw_deg / 4 (the global
    RNG: seeded)."""
    limit = math.radians(max_yaw_deg)
    yaw = torch.empty(count).uniform_(-limit, limit)
    pitch = torch.empty(count).uniform_(-limit / 4.0, limit / 4.0)
    roll = torch.empty(count).uniform_(-limit / 4.0, limit / 4.0)
    return rotation_matrices(yaw, pitch, roll)


def vmf_negative_log_likelihood(kappa: torch.Tensor, cosine: torch.Tensor) -> torch.Tensor:
    """-log p(s | mu, kappa) of the von Mises-Fisher distribution on the sphere, for mu·s = ``cosine``:
    -log kappa + log(2 pi (1 - exp(-2 kappa))) + kappa (1 - cosine), stable for any kappa > 0."""
    return -torch.log(kappa) + math.log(2.0 * math.pi) + torch.log(-torch.expm1(-2.0 * kappa)) + kappa * (1.0 - cosine)


@dataclass
class SunTask:
    """Sun-BCNN for the training loop: loss 1 - s·ŝ averaged over the batch (with ``bins``: the cross-entropy
    of the soft targets), plus the von Mises-Fisher negative log-likelihood of the true sun about the (fixed)
    prediction with the aleatoric output."""

    config: SunBCNNConfig
    architecture: str = ARCHITECTURE

    def build(self) -> nn.Module:
        return SunBCNN(self.config)

    def loss(self, model: nn.Module, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        images, sun = batch["left"], batch["sun"]
        if self.config.augment and model.training:
            images = photometric_jitter(images)
        camera = batch.get("camera")
        if self.config.mirror and model.training:
            flip = torch.rand(len(images)) < 0.5  # the global RNG: seeded, and checkpointed for --resume
            images = torch.where(flip[:, None, None, None], images.flip(-1), images)
            sun = torch.where(flip[:, None], sun * torch.tensor([-1.0, 1.0, 1.0]), sun)
            if camera is not None:  # the mirrored image's principal point
                mirrored = torch.stack([camera[:, 0], camera[:, 1], images.shape[-1] - 1.0 - camera[:, 2], camera[:, 3]], 1)
                camera = torch.where(flip[:, None], mirrored, camera)
        if self.config.rotate > 0.0 and model.training:
            if camera is None:
                raise ValueError("rotate needs each sample's camera intrinsics (a dataset built with DataSpec camera=True)")
            images, sun = rotate_cameras(images, sun, camera, random_rotations(len(images), self.config.rotate))
        if self.config.bins:
            logits, kappa = model(images, with_concentration=True, raw=True)
            targets = soft_bin_targets(sun, self.config.bins)
            loss = -(targets * torch.log_softmax(logits, dim=1)).sum(dim=1).mean()
            predicted = decode_bins(logits.detach(), sphere_directions(self.config.bins), self.config.decode_radius)
            cosine = (predicted * sun).sum(dim=1)
        else:
            predicted, kappa = model(images, with_concentration=True)
            cosine = (predicted * sun).sum(dim=1)
            loss = (1.0 - cosine).mean()
        if kappa is not None:
            loss = loss + vmf_negative_log_likelihood(kappa, cosine.detach()).mean()
        return loss

    def card(self) -> ModelCard:
        spec = self.config.spec
        return ModelCard(
            architecture=ARCHITECTURE,
            hyperparameters=asdict(self.config),
            input={
                "size": list(spec.size),
                "colour": spec.colour,
                "normalisation": ("histogram-equalised, " if self.config.equalize else "") + "grey levels / 255, minus 0.5",
            },
        )
