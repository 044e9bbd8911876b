"""The HydraNet network (thesis §7.4, Fig. 7.3) and its loss (eq. 7.17).

A convolutional body reads the optical flow; H quaternion heads each predict C_k,k-1; one head predicts the
aleatoric covariance Sigma_a through the Cholesky factor of its inverse. In training every head's output is
paired with the target and the shared Sigma_a (the heads learn to be good alone; their spread is what the
data did not pin down). At prediction the heads' mean (eq. 7.14) is the estimate and
Sigma = Sigma_e (eq. 7.16) + Sigma_a its covariance, in the left tangent space of the mean (rad²).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import torch
from torch import nn

from ..learning.checkpoint import ModelCard
from . import quaternion as quat
from .config import ARCHITECTURE, HydraNetConfig

#: The aleatoric head starts at sigma = 1/this rad (0.57 deg) per axis: near a frame-to-frame error, so the
#: first steps neither explode nor vanish.
INITIAL_PRECISION_ROOT = 100.0
#: log of the largest precision root (sigma >= 1e-5 rad): keeps exp() finite on a bad batch.
MAX_LOG_ROOT = math.log(1e5)
HEAD_INIT_SCALE = 0.01  # the heads start near the identity rotation, each from its own random weights


class HydraNet(nn.Module):
    def __init__(self, config: HydraNetConfig) -> None:
        super().__init__()
        self.config = config
        layers: list[nn.Module] = []
        channels = config.channels + (2 if config.coordinates else 0)
        for width in config.widths:
            layers += [
                nn.Conv2d(channels, width, 3, stride=2, padding=1, bias=False),
                nn.BatchNorm2d(width),
                nn.ReLU(inplace=True),
            ]
            channels = width
        self.body = nn.Sequential(*layers)
        with torch.no_grad():
            flat = self.body(self._with_coordinates(torch.zeros(1, config.channels, *config.size))).numel()
        self.feature = nn.Sequential(nn.Flatten(), nn.Linear(flat, config.feature), nn.ReLU(inplace=True))
        self.heads = nn.ModuleList(
            nn.Sequential(
                nn.Linear(config.feature, config.head_hidden),
                nn.PReLU(),
                nn.Dropout(config.head_dropout),
                nn.Linear(config.head_hidden, 4),
            )
            for _ in range(config.heads)
        )
        for head in self.heads:
            last = head[-1]
            assert isinstance(last, nn.Linear)
            with torch.no_grad():
                last.weight.mul_(HEAD_INIT_SCALE)
                last.bias.copy_(torch.tensor([1.0, 0.0, 0.0, 0.0]))
        outputs = 6 if config.covariance == "cholesky" else 3
        self.covariance = nn.Sequential(nn.Linear(config.feature, 128), nn.PReLU(), nn.Linear(128, outputs))
        with torch.no_grad():
            last = self.covariance[-1]
            assert isinstance(last, nn.Linear)
            last.weight.mul_(HEAD_INIT_SCALE)
            last.bias.zero_()

    @property
    def head_count(self) -> int:
        """Quaternion heads a forward pass gives (H)."""
        return self.config.heads

    def _with_coordinates(self, inputs: torch.Tensor) -> torch.Tensor:
        """``inputs`` (B, C, H, W) and, with ``coordinates``, each pixel's (u - W/2) / W and (v - H/2) / H after them."""
        if not self.config.coordinates:
            return inputs
        count, _, height, width = inputs.shape
        u = (torch.arange(width, dtype=inputs.dtype) + 0.5 - width / 2) / width
        v = (torch.arange(height, dtype=inputs.dtype) + 0.5 - height / 2) / height
        grid = torch.stack(torch.meshgrid(u, v, indexing="xy"))  # (2, H, W): u along the width, v down the height
        return torch.cat([inputs, grid.expand(count, -1, -1, -1)], dim=1)

    def forward(self, flow: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """flow (B, C, H, W): the flow in pixels (and the texture channel) -> the heads' unit quaternions
        (B, heads, 4) of C_k,k-1 (w >= 0) and the lower-triangular Cholesky factor L (B, 3, 3) of the aleatoric
        precision Sigma_a^-1 = L L^T."""
        heads, root, _ = self.forward_features(flow)
        return heads, root

    def forward_features(self, flow: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """:meth:`forward`'s heads and Cholesky factor, and the body's features (B, feature) the heads read."""
        features = self.feature(self.body(self._with_coordinates(flow)))
        heads = torch.stack([head(features) for head in self.heads], dim=1)
        heads = nn.functional.normalize(heads, dim=-1)
        heads = torch.where(heads[..., :1] < 0.0, -heads, heads)
        return heads, precision_root(self.covariance(features)), features


class HydraEnsemble(nn.Module):
    """Several independently trained HydraNets read as one (a deep ensemble of bodies; bagging's idea, the thesis's
    reference in the 1-D study): ``forward`` gives every member's heads side by side (B, M·H, 4), so eq. 7.14's
    mean and eq. 7.16's Sigma_e run over all of them — bodies that disagree, as independently seeded ones do
    where their training data did not reach, show as epistemic spread, which one body's heads barely give —
    and Sigma_a the mean of the members' aleatoric covariances, returned as the Cholesky factor of its inverse
    like a single network's. The members read the same input (size and channels; :func:`~.infer.load_hydranet`
    checks), ``config`` is the first's."""

    def __init__(self, members: list[HydraNet]) -> None:
        super().__init__()
        if len(members) < 2:
            raise ValueError(f"an ensemble needs at least two HydraNets, got {len(members)}")
        self.members = nn.ModuleList(members)
        self.config = members[0].config

    @property
    def head_count(self) -> int:
        """Quaternion heads a forward pass gives (every member's)."""
        return sum(member.head_count for member in self.members)

    def forward(self, flow: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        outputs = [member(flow) for member in self.members]
        heads = torch.cat([heads for heads, _ in outputs], dim=1)
        aleatoric = torch.stack([torch.cholesky_inverse(root.double()) for _, root in outputs]).mean(0)
        root = torch.linalg.cholesky(torch.linalg.inv(aleatoric))
        return heads, root.to(flow.dtype)


#: What :func:`predict_rotations` runs: one network or an ensemble of them.
RotationNetwork = HydraNet | HydraEnsemble


def precision_root(raw: torch.Tensor) -> torch.Tensor:
    """L (B, 3, 3) from the covariance head's output (B, 6) or (B, 3): L = diag(exp(a)) M with M unit lower
    triangular (its three off-diagonal entries from the last outputs; none for the diagonal form), so log det
    of the precision is 2 sum(a) and the off-diagonal terms scale with their row."""
    log_root = (raw[:, :3] + math.log(INITIAL_PRECISION_ROOT)).clamp(max=MAX_LOG_ROOT)
    unit = torch.eye(3, dtype=raw.dtype, device=raw.device).expand(len(raw), 3, 3).clone()
    if raw.shape[1] == 6:
        rows, columns = torch.tril_indices(3, 3, offset=-1)
        unit[:, rows, columns] = raw[:, 3:]
    return torch.exp(log_root).unsqueeze(-1) * unit


def head_nll(heads: torch.Tensor, target: torch.Tensor, root: torch.Tensor) -> torch.Tensor:
    """Eq. 7.17 per sample and head (B, H), each head paired with the target (B, 4) and the shared
    precision L L^T: 1/2 |L^T phi|^2 - log det L (+ constant), phi = Log(q_i (x) q_t^-1)."""
    phi = quat.log(quat.multiply(heads, quat.conjugate(target).unsqueeze(1)))  # (B, H, 3)
    whitened = phi @ root  # rows phi^T L = (L^T phi)^T
    log_det = torch.log(torch.diagonal(root, dim1=-2, dim2=-1)).sum(-1)
    return 0.5 * (whitened**2).sum(-1) - log_det.unsqueeze(-1)


def bootstrap_mask(batch: dict[str, torch.Tensor], heads: int) -> torch.Tensor:
    """(B, heads) 0/1: whether each head trains on each sample, half of them each, fixed per sample (a hash of
    its sequence, frame and direction) so every epoch each head sees the same half — bootstrapped heads, as
    bagging's networks see their own resamples, so that they disagree where the data did not pin them down."""
    key = batch["sequence"].long() * 1_000_003 + batch["frame"].long() * 2 + batch["reversed"].long()
    head = torch.arange(1, heads + 1, dtype=torch.long)
    mixed = (key[:, None] * 2_654_435_761 + head[None, :] * 40_503) % 4_294_967_296
    mixed = (mixed ^ (mixed >> 16)) * 73_244_475 % 4_294_967_296
    return ((mixed >> 15) & 1).to(torch.float32)


#: The quaternion (w, x, y, z) of C_k,k-1 seen in a left-right mirror image, element-wise: M C M with M =
#: diag(-1, 1, 1) on the camera's x axis has the rotation vector (x, -y, -z) (the optical frame's axes).
MIRROR_QUATERNION_SIGNS = (1.0, 1.0, -1.0, -1.0)


def mirror_flow(flow: torch.Tensor) -> torch.Tensor:
    """Network inputs (B, C, H, W) as the mirror image would give them: flipped along the width, the flow's
    horizontal component negated (a texture channel only flipped). Exact for a principal point at the image's
    centre, as the rendered rig and, to a pixel, KITTI's."""
    signs = torch.ones(flow.shape[1], dtype=flow.dtype)
    signs[0] = -1.0
    return flow.flip(-1) * signs.view(1, -1, 1, 1)


def mirror_pairs(flow: torch.Tensor, rotation: torch.Tensor, which: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The samples ``which`` (B,) bool mirrored left-right: the flow by :func:`mirror_flow`, the rotation (B, 4)
    (w, x, y, z) of C_k,k-1 conjugated by the mirror (:data:`MIRROR_QUATERNION_SIGNS`)."""
    mirrored_rotation = rotation * torch.tensor(MIRROR_QUATERNION_SIGNS, dtype=rotation.dtype)
    return (
        torch.where(which[:, None, None, None], mirror_flow(flow), flow),
        torch.where(which[:, None], mirrored_rotation, rotation),
    )


@dataclass
class HydraTask:
    """HydraNet for the training loop: the heads' NLL (eq. 7.17) averaged over batch and heads."""

    config: HydraNetConfig
    architecture: str = ARCHITECTURE

    def build(self) -> nn.Module:
        return HydraNet(self.config)

    def loss(self, model: nn.Module, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        flow, rotation = batch["flow"], batch["rotation"]
        if self.config.mirror and model.training:
            flow, rotation = mirror_pairs(flow, rotation, torch.rand(len(flow)) < 0.5)  # the global RNG: seeded
        heads, root = model(flow)
        nll = head_nll(heads, rotation, root)
        if not (self.config.bootstrap and model.training):
            return nll.mean()
        mask = bootstrap_mask(batch, nll.shape[1])
        return (nll * mask).sum() / mask.sum().clamp(min=1.0)

    def card(self) -> ModelCard:
        return ModelCard(
            architecture=ARCHITECTURE,
            hyperparameters=asdict(self.config),
            input={
                "size": list(self.config.size),
                "colour": False,
                "normalisation": "Farneback flow (pixels at the input size) between the grey left images resized to it",
            },
        )


@dataclass
class RotationOutput:
    """Per sample (float64): the mean quaternion (B, 4) of C_k,k-1 (eq. 7.14, w >= 0), Sigma_e and Sigma_a
    (B, 3, 3) in rad², left tangent space; Sigma = Sigma_e + Sigma_a."""

    quaternion: torch.Tensor
    epistemic: torch.Tensor
    aleatoric: torch.Tensor

    @property
    def covariance(self) -> torch.Tensor:
        return self.epistemic + self.aleatoric


#: How a trained model is run (its card's ``calibration.mode``): "plain"; "mirrored" — each pair also through its
#: mirror image; "reversed" — each pair also as the flow from the later image to the earlier. The sets of heads
#: are pooled (:func:`predict_rotations`).
MODES = ("plain", "mirrored", "reversed")

#: C_k-1,k's quaternion (w, x, y, z) times these is C_k,k-1's: the inverse rotation.
INVERSE_QUATERNION_SIGNS = (1.0, -1.0, -1.0, -1.0)


def predict_rotations(
    model: RotationNetwork, flow: torch.Tensor, mirrored: bool = False, reversed_flow: torch.Tensor | None = None
) -> RotationOutput:
    """The estimate for a batch of network inputs (B, C, H, W): eval mode (the heads' dropout off, as the
    authors' code), no gradients. ``mirrored``: the inputs also go through the network mirrored left-right
    (:func:`mirror_flow`); those H heads, mirrored back, join the H heads of the inputs as they are, so the mean
    (eq. 7.14) and Sigma_e (eq. 7.16) are over 2H heads — a disagreement between a pair and its mirror image
    shows as epistemic spread — and Sigma_a is the mean of the two aleatoric outputs (the mirrored one
    conjugated by the mirror, diag(1, -1, -1) on the rotation vector). ``reversed_flow``: the same pairs' inputs
    from the later image to the earlier (B, C, H, W), which the network reads as C_k-1,k; those heads, inverted,
    are pooled the same way, their Sigma_a carried into C_k,k-1's left tangent space (R Sigma R^T, R = C_k,k-1).
    A network with a ``density`` (:class:`~.density.FeatureDensity`, attached by :func:`~.infer.load_hydranet` from
    its card) widens each pair's covariance by the density's factor g of the pair's features (as ``flow`` gives
    them), the added part counted in Sigma_e; one with a ``widening`` (:class:`~.widening.SpreadWidening`, from its
    card too) widens Sigma_a by how far the heads' spread exceeds its usual size, the added part counted in Sigma_e."""
    model.eval()
    density = getattr(model, "density", None)
    with torch.no_grad():
        if density is not None:
            heads, root, features = model.forward_features(flow)
        else:
            heads, root = model(flow)
        heads, root = heads.double(), root.double()
        aleatoric = [torch.linalg.inv(root @ root.transpose(-1, -2))]
        if mirrored:
            mirror_heads, mirror_root = model(mirror_flow(flow))
            signs = torch.tensor(MIRROR_QUATERNION_SIGNS, dtype=torch.float64)
            heads = torch.cat([heads, mirror_heads.double() * signs], dim=-2)
            axes = torch.diag(signs[1:])
            mirror_root = mirror_root.double()
            aleatoric.append(axes @ torch.linalg.inv(mirror_root @ mirror_root.transpose(-1, -2)) @ axes)
        inverse = None
        if reversed_flow is not None:
            if reversed_flow.shape != flow.shape:
                raise ValueError(f"reversed inputs {tuple(reversed_flow.shape)} do not match the inputs {tuple(flow.shape)}")
            reverse_heads, reverse_root = model(reversed_flow)
            heads = torch.cat([heads, reverse_heads.double() * torch.tensor(INVERSE_QUATERNION_SIGNS, dtype=torch.float64)], -2)
            reverse_root = reverse_root.double()
            inverse = torch.linalg.inv(reverse_root @ reverse_root.transpose(-1, -2))
    mean = quat.mean(heads)
    if inverse is not None:
        rotation = quat.rotation_matrix(mean)
        aleatoric.append(rotation @ inverse @ rotation.transpose(-1, -2))
    epistemic, aleatoric_mean = quat.epistemic_covariance(heads, mean), torch.stack(aleatoric).mean(dim=0)
    widening = getattr(model, "widening", None)
    if widening is not None:  # heads disagreeing beyond their usual spread: Sigma_a widened with it, counted in Sigma_e
        epistemic = widening.widen(epistemic, aleatoric_mean)
    if density is not None:  # pairs unlike the data the model was made for: their covariance widened, as epistemic
        extra = density.inflation(features.double()) - 1.0
        epistemic = epistemic + extra[:, None, None] * (epistemic + aleatoric_mean)
    return RotationOutput(mean, epistemic, aleatoric_mean)


def inference_mode(card: Any) -> str:
    """How ``card``'s model runs (``calibration.mode``, one of :data:`MODES`; plain when unset, as models before
    it); ValueError naming an unknown mode."""
    mode = (card.calibration or {}).get("mode", "plain")
    if mode not in MODES:
        raise ValueError(f"unknown HydraNet mode {mode!r} in the model card: choose one of {', '.join(MODES)}")
    return str(mode)
