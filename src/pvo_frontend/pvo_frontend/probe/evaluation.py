"""PROBE's experiments as library calls (thesis Table 4.1): estimators over frame pairs, trajectories composed
from their motions, translational and rotational ARMSE against the truth."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from pvo_core.camera import StereoCamera
from pvo_core.lie import se3_inverse
from pvo_core.readers import KittiSequence, KLTTracks

from pvo_core import metrics

from ..vo import VOConfig
from ..vo.solver import RobustLoss
from .gk import GKConfig, GKModel
from .knn import KNNConfig, KNNModel, train_knn
from .model import ProbeModel
from .predictors import PredictorConfig, compute_predictors
from .synthetic import PREDICTORS, PointWorldConfig, simulate
from .training import FramePair, solve_pair, solve_with_noise, train_expectation_maximisation, train_with_ground_truth

Array = NDArray[np.float64]
Solver = Callable[[FramePair, Array], Array]

#: Table 4.1's rows.
ESTIMATORS = ("Fixed covariance", "Static M-estimator", "PROBE-GK-GT", "PROBE-GK-EM")
#: and the isotropic k-NN PROBE of app. A (trained with ground truth) beside them
KNN_ROW = "PROBE k-NN"


def compose(first_pose: Array, motions: Sequence[Array]) -> Array:
    """Camera poses T_world,cam (N + 1, 4, 4) from the first and the motions T_cur,ref."""
    poses = [np.asarray(first_pose, dtype=float)]
    for motion in motions:
        poses.append(poses[-1] @ se3_inverse(motion))
    return np.array(poses)


def run_estimator(pairs: Sequence[FramePair], solve: Solver) -> list[Array]:
    """Each pair's motion, each solve started from the previous motion (constant velocity)."""
    motions, previous = [], np.eye(4)
    for pair in pairs:
        previous = solve(pair, previous)
        motions.append(previous)
    return motions


def fixed_solver(camera: StereoCamera, sigma: Sequence[float], loss: RobustLoss) -> Solver:
    """One covariance diag(sigma^2) for every feature, under ``loss``."""
    information = np.linalg.inv(np.diag(np.asarray(sigma, dtype=float) ** 2))

    def solve(pair: FramePair, initial: Array) -> Array:
        return solve_pair(camera, pair, np.broadcast_to(information, (len(pair), 3, 3)), loss, initial)

    return solve


def knn_solver(camera: StereoCamera, model: KNNModel, sigma: Sequence[float]) -> Solver:
    """Isotropic PROBE: the nominal covariance scaled by beta(phi), features above the weight limit dropped,
    least squares (app. A)."""
    nominal = np.diag(np.asarray(sigma, dtype=float) ** 2)

    def solve(pair: FramePair, initial: Array) -> Array:
        covariances, keep = model.covariances(pair.predictors, nominal)
        if keep.sum() < 6:
            keep = np.ones(len(pair), dtype=bool)
        kept = FramePair(pair.reference[keep], pair.current[keep], pair.predictors[keep])
        return solve_pair(camera, kept, np.linalg.inv(covariances[keep]), RobustLoss("l2"), initial)

    return solve


def gk_solver(camera: StereoCamera, model: GKModel) -> Solver:
    """PROBE-GK: each feature's Student-t noise from the model (Algorithm 2)."""

    def solve(pair: FramePair, initial: Array) -> Array:
        return solve_with_noise(camera, pair, model.noise(pair.predictors), initial)

    return solve


@dataclass
class ProbeTable:
    """ARMSE per estimator (``ESTIMATORS`` and ``KNN_ROW``): {'trans': m, 'rot': rad}; the EM log-likelihood history; the
    estimated trajectories (N, 4, 4) and the truth."""

    armse: dict[str, dict[str, float]]
    em_log_likelihood: list[float]
    trajectories: dict[str, Array] = field(default_factory=dict)
    truth: Array | None = None

    def change(self, row: str, against: str = "Fixed covariance", key: str = "trans") -> float:
        """Relative change of ``row``'s ARMSE against ``against`` (negative = better)."""
        return self.armse[row][key] / self.armse[against][key] - 1.0


def estimator_solvers(
    train_camera: StereoCamera,
    train_pairs: Sequence[FramePair],
    train_motions: Sequence[Array],
    test_camera: StereoCamera,
    names: tuple[str, ...],
    gk: GKConfig | None = None,
    knn: KNNConfig | None = None,
    em_iterations: int = 5,
    fixed_sigma: Sequence[float] = (2.0, 2.0, 2.8),
    student_dof: float = 5.0,
    seed: int = 0,
    say: Callable[[str], None] | None = None,
) -> tuple[dict[str, Solver], list[float]]:
    """Table 4.1's estimators for the test camera, their models trained on a training traverse: a fixed
    covariance (least squares), the static Student-t M-estimator (Kerl et al.), PROBE-GK with ground truth and by
    EM (initialised with the M-estimator's motions), and the k-NN PROBE; and EM's log-likelihood per iteration."""
    gk = gk or GKConfig()
    static_train = fixed_solver(train_camera, fixed_sigma, RobustLoss("student_t", student_dof))
    gt_model = train_with_ground_truth(train_camera, train_pairs, train_motions, names, gk)
    em = train_expectation_maximisation(
        train_camera, train_pairs, run_estimator(train_pairs, static_train), names, gk, em_iterations, say=say
    )
    knn_model = train_knn(train_camera, train_pairs, train_motions, names, fixed_sigma, knn or KNNConfig(), seed=seed)
    solvers = {
        "Fixed covariance": fixed_solver(test_camera, fixed_sigma, RobustLoss("l2")),
        "Static M-estimator": fixed_solver(test_camera, fixed_sigma, RobustLoss("student_t", student_dof)),
        "PROBE-GK-GT": gk_solver(test_camera, gt_model),
        "PROBE-GK-EM": gk_solver(test_camera, em.model),
        KNN_ROW: knn_solver(test_camera, knn_model, fixed_sigma),
    }
    return solvers, em.log_likelihood


def per_frame_table(
    segments: Sequence[tuple[Sequence[FramePair], dict[str, Solver]]],
    test_poses: Array,
    em_log_likelihood: list[float] | None = None,
    say: Callable[[str], None] | None = None,
) -> ProbeTable:
    """Table 4.1's rows on one test traverse (true poses (N + 1, 4, 4)) solved in consecutive segments, each
    frame pair by its segment's solver of the row — the predictors each frame has (say, the image ones only
    where the images are) — the constant-velocity start carried across segments; ARMSE of the whole."""
    rows = list(segments[0][1])
    table = ProbeTable({}, em_log_likelihood or [], truth=test_poses)
    for name in rows:
        motions, previous = [], np.eye(4)
        for pairs, solvers in segments:
            for pair in pairs:
                previous = solvers[name](pair, previous)
                motions.append(previous)
        if len(motions) != len(test_poses) - 1:
            raise ValueError(f"{len(motions)} frame pairs in the segments for {len(test_poses)} true poses")
        poses = compose(test_poses[0], motions)
        figures = metrics.armse(test_poses, poses)
        table.armse[name] = {"trans": figures["trans"], "rot": figures["rot"]}
        table.trajectories[name] = poses
        if say:
            say(f"{name:<20} trans ARMSE {figures['trans']:7.3f} m, rot {figures['rot']:.4f} rad")
    return table


def synthetic_experiment(
    config: PointWorldConfig | None = None,
    gk: GKConfig | None = None,
    train_seconds: float = 30.0,
    test_seconds: float = 60.0,
    seed: int = 0,
    em_iterations: int = 5,
    fixed_sigma: Sequence[float] = (2.0, 2.0, 2.8),
    student_dof: float = 5.0,
    knn: KNNConfig | None = None,
    say: Callable[[str], None] | None = None,
) -> ProbeTable:
    """Table 4.1's first row: training and test traverses in two worlds drawn from ``seed``
    (:func:`estimator_solvers`, :func:`per_frame_table`); the predictor is the feature's image row."""
    config = config or PointWorldConfig()
    train = simulate(config, train_seconds, seed=2 * seed + 1)
    test = simulate(config, test_seconds, seed=2 * seed + 2)
    solvers, log_likelihood = estimator_solvers(
        config.camera, train.pairs, train.motions, config.camera, PREDICTORS,
        gk, knn, em_iterations, fixed_sigma, student_dof, seed, say,
    )  # fmt: skip
    return per_frame_table([(test.pairs, solvers)], test.poses, log_likelihood, say)


def track_pairs(
    tracks: KLTTracks,
    predictors: PredictorConfig,
    frames: Sequence[int],
    image_of: Callable[[int], NDArray[np.uint8] | None] | None = None,
) -> tuple[list[FramePair], list[Array], Array]:
    """Frame pairs (k - 1 -> k for k in ``frames``, k >= 1) of raw-derived KLT tracks with their predictors (the
    image ones from ``image_of(k)``, the current left image; IMU ones from the drive's specific force and
    angular rate), the true motions, and the true poses of frames[0] - 1 .. frames[-1] (len(frames) + 1)."""
    pairs, motions = [], []
    for k in frames:
        ref, cur, _ = tracks.pair(k)
        imu = np.array([np.linalg.norm(tracks.specific_force[k]), np.linalg.norm(tracks.angular_rate[k])])
        image = image_of(k) if (image_of is not None and predictors.image) else None
        phi = compute_predictors(predictors, ref[:, :2], cur[:, :2], image, imu if predictors.imu else None, ref[:, 2])
        pairs.append(FramePair(ref, cur, phi))
        motions.append(tracks.motion(k))
    poses = tracks.poses[frames[0] - 1 : frames[-1] + 1]
    return pairs, motions, poses


def tracks_experiment(
    train: KLTTracks,
    test: KLTTracks,
    predictors: PredictorConfig,
    train_frames: Sequence[int],
    test_frames: Sequence[int],
    train_images: Callable[[int], NDArray[np.uint8] | None] | None = None,
    test_images: Callable[[int], NDArray[np.uint8] | None] | None = None,
    gk: GKConfig | None = None,
    em_iterations: int = 5,
    say: Callable[[str], None] | None = None,
) -> ProbeTable:
    """Table 4.1 on real KITTI tracks: models trained on ``train``'s frames, tested on ``test``'s."""
    solvers, log_likelihood = tracks_solvers(train, test, predictors, train_frames, train_images, gk, em_iterations, say)
    test_pairs, _, test_poses = track_pairs(test, predictors, test_frames, test_images)
    return per_frame_table([(test_pairs, solvers)], test_poses, log_likelihood, say)


def tracks_solvers(
    train: KLTTracks,
    test: KLTTracks,
    predictors: PredictorConfig,
    train_frames: Sequence[int],
    train_images: Callable[[int], NDArray[np.uint8] | None] | None = None,
    gk: GKConfig | None = None,
    em_iterations: int = 5,
    say: Callable[[str], None] | None = None,
) -> tuple[dict[str, Solver], list[float]]:
    """:func:`estimator_solvers` trained on ``train``'s frames, for ``test``'s camera (to solve test pairs made
    with the same ``predictors`` by :func:`track_pairs`)."""
    train_pairs, train_motions, _ = track_pairs(train, predictors, train_frames, train_images)
    return estimator_solvers(
        train.camera, train_pairs, train_motions, test.camera, predictors.names, gk, None, em_iterations, say=say
    )


@dataclass
class SequenceComparison:
    """One test sequence through the default VO and the VO with PROBE: ARMSE {'trans': m, 'rot': rad} each, the
    mean over the RANSAC seeds run; ``default_runs`` / ``probe_runs`` hold each seed's translational ARMSE (m)."""

    name: str
    default: dict[str, float]
    probe: dict[str, float]
    default_runs: list[float] = field(default_factory=list)
    probe_runs: list[float] = field(default_factory=list)

    @property
    def change(self) -> float:
        """Relative change of the translational ARMSE with PROBE (negative = better)."""
        return self.probe["trans"] / self.default["trans"] - 1.0

    @property
    def default_spread(self) -> float:
        """(max - min) / mean of the default VO's translational ARMSE over the seeds: how much the RANSAC draws
        alone move it (0 with one seed)."""
        runs = self.default_runs
        return (max(runs) - min(runs)) / (sum(runs) / len(runs)) if len(runs) > 1 else 0.0


def compare_on_sequences(
    sequences: Sequence[tuple[str, KittiSequence, Array | None]],
    vo_config: VOConfig,
    model: ProbeModel,
    say: Callable[[str], None] | None = None,
    seeds: Sequence[int] = (0,),
) -> list[SequenceComparison]:
    """Each (name, sequence with poses, its IMU per frame or None) through the default VO and the VO with
    ``model``'s noise, once per RANSAC seed (``ransac.seed``); the ARMSE of each is the mean over the seeds, so
    that a change smaller than what the random draws alone cause is not read as PROBE's."""
    from ..offline import run_sequence

    if not seeds:
        raise ValueError("compare_on_sequences needs at least one RANSAC seed")
    out = []
    for name, sequence, imu in sequences:
        assert sequence.poses is not None
        runs: dict[str, list[dict[str, float]]] = {"default": [], "probe": []}
        for seed in seeds:
            config = replace(vo_config, ransac=replace(vo_config.ransac, seed=int(seed)))
            runs["default"].append(metrics.armse(sequence.poses, run_sequence(sequence, config).poses))
            with_probe = run_sequence(sequence, config, feature_noise=model.feature_noise(), imu=imu)
            runs["probe"].append(metrics.armse(sequence.poses, with_probe.poses))
        mean = {kind: {k: float(np.mean([r[k] for r in rs])) for k in ("trans", "rot")} for kind, rs in runs.items()}
        result = SequenceComparison(
            name, mean["default"], mean["probe"], [r["trans"] for r in runs["default"]], [r["trans"] for r in runs["probe"]]
        )
        out.append(result)
        if say:
            spread = f", default spread over {len(seeds)} seeds {100 * result.default_spread:.0f} %" if len(seeds) > 1 else ""
            say(
                f"{name}: ARMSE default {result.default['trans']:.3f} m, PROBE {result.probe['trans']:.3f} m "
                f"({100 * result.change:+.1f} %{spread})"
            )
    return out
