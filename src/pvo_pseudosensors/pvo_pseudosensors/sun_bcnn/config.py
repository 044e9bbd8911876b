"""Sun-BCNN's settings (no torch: the `pvo sun-bcnn` options are built from them)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..learning.spec import DataSpec

#: Models installed with the package, by name (``model: NAME``).
SHIPPED = ("sun_bcnn", "sun_bcnn_kitti")  # trained on the synthetic corpus / fine-tuned on KITTI 07

ARCHITECTURE = "sun-bcnn"


@dataclass(frozen=True)
class SunBCNNConfig:
    """height, width: the input (px); colour: RGB or grey; widths: channels of the convolutional blocks (each
    a stride-2 3x3 convolution and a 3x3 one); hidden: the fully connected layer; dropout: probability after
    every block and the hidden layer (kept on for MC sampling); grid: rows and columns of the average pooling
    before the head (where things are in the image says where the sun is; (1, 1) is global pooling);
    mirror: in training, each image is mirrored left-right at random with the sun's x negated (a mirrored
    world has a mirrored sun: twice the suns to learn from a corpus of few sequences); rotate: in training,
    each image is warped as if the camera had turned by a random rotation — yaw uniform in ±rotate degrees,
    pitch and roll in ±rotate/4 (real cameras pitch and roll less than they turn) — and the sun vector turned
    with it: the same scene with the sun at another bearing, exact for a pinhole camera (the homography
    K R K^-1 with the sequence's own intrinsics; 0: off); aleatoric: a fourth
    output, the concentration kappa of a von Mises-Fisher distribution about the predicted direction, trained
    by its negative log-likelihood, so that hard images (overcast, no shadows in view, blur) get a larger
    covariance than easy ones (the thesis's single tau cannot: its §5.8.1); augment: photometric jitter in
    training (gain, gamma, noise per image); batch_norm: batch normalisation after every convolution (its
    running statistics in every MC pass: the passes differ by their dropout masks alone); bins: 0 regresses the
    unit vector (the thesis), N > 0 classifies the sun into N directions spread evenly over the sphere instead
    (soft targets about the true sun, a cross-entropy loss; the answer is the probability-weighted mean direction
    about the most probable bin): a distribution keeps "ahead or behind" and "low or high" apart where a
    regressed vector averages them; decode_radius: how far about the most probable bin that mean reaches, in bin
    spacings (inf: the whole sphere); equalize: every image the network reads is histogram-equalised first (each
    channel over its 256 grey levels, inside the network, so training, prediction and the node see the same): its
    answer then depends on the order of the grey levels, not on how a camera or renderer spread them."""

    height: int = 94
    width: int = 310
    colour: bool = False
    widths: tuple[int, ...] = (8, 16, 32, 64)
    hidden: int = 128
    dropout: float = 0.2
    mirror: bool = True
    rotate: float = 10.0
    grid: tuple[int, ...] = (2, 4)
    aleatoric: bool = True
    augment: bool = True
    batch_norm: bool = False
    bins: int = 256
    decode_radius: float = 4.0
    equalize: bool = False

    def __post_init__(self) -> None:
        if min(self.height, self.width) < 16 or not self.widths or not 0.0 <= self.dropout < 1.0:
            raise ValueError("Sun-BCNN needs an input of at least 16 px, at least one block and dropout in [0, 1)")
        if not 0.0 <= self.rotate <= 60.0:
            raise ValueError(f"rotate must be a yaw range in [0, 60] degrees, got {self.rotate}")
        if self.bins != 0 and not 20 <= self.bins <= 5000:
            raise ValueError(f"bins must be 0 (regress the vector) or a number of directions in [20, 5000], got {self.bins}")
        if not self.decode_radius >= 1.0:  # also NaN
            raise ValueError(f"decode_radius must be at least 1 bin spacing (inf: the whole sphere), got {self.decode_radius}")
        if len(self.grid) != 2 or min(self.grid) < 1:
            raise ValueError(f"grid must be two positive numbers (rows, columns), got {self.grid}")

    @property
    def spec(self) -> DataSpec:
        return DataSpec((self.height, self.width), colour=self.colour, sun=True, camera=self.rotate > 0.0)

    @classmethod
    def from_card(cls, card: Any) -> SunBCNNConfig:
        values = dict(card.hyperparameters)
        values["widths"] = tuple(values["widths"])
        values["grid"] = tuple(values.get("grid", (1, 1)))
        values.setdefault("aleatoric", False)  # models from before the options had neither
        values.setdefault("augment", False)
        values.setdefault("batch_norm", False)
        values.setdefault("rotate", 0.0)  # nor the turned cameras
        values.setdefault("bins", 0)  # nor the classified directions
        values.setdefault("decode_radius", 4.0)  # the one radius of stop 47
        return cls(**values)
