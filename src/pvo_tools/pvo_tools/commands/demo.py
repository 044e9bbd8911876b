"""`pvo demo`: the main job. The embedded sample bags replayed through the real node graph over DDS —
``pvo bag play`` → ``stereo_vo`` → a sun sensor → ``fusion`` — recorded, evaluated against the ground truth
(VO alone and fused), checked against the same algorithms run without ROS, and written up in
``runs/demo/<sample>/`` (report.md, metrics.json, trajectory.png, errors.png, the recorded bag, node logs).

The sun sensor: ``sun_bcnn`` (Sun-BCNN on the left images, the shipped model) where the bag has GPS fixes,
with the fusion's sun reference from the ephemeris at the first fix; elsewhere (the KITTI sample: no GPS)
``simulated_sun`` (GT-Sun-10) with the reference from the ground truth. With the learned sun comes
``hydranet`` (HydraNet's rotation between consecutive left images, the shipped model), fused by the
rotation factor, and ``dpc_net`` (DPC-Net's corrections of the VO over Δp frames, the shipped clean-rig model
``dpc_net_clean``: the sample's lens is not distorted), fused by the correction factor."""

from __future__ import annotations

import argparse
import os
import random
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ..errors import PvoError

SAMPLES = ("bags/kitti06_sample", "bags/sim_urban_sample")
INPUT_TOPICS = [
    "/stereo/left/image_rect",
    "/stereo/right/image_rect",
    "/stereo/left/camera_info",
    "/stereo/right/camera_info",
    "/ground_truth/sun_direction",
]
OUTPUT_TOPICS = [
    "/pvo/vo/relative",
    "/pvo/vo/odometry",
    "/pvo/vo/status",
    "/pvo/sun/direction",
    "/pvo/fusion/odometry",
    "/pvo/fusion/path",
    "/pvo/fusion/status",
]
AGREEMENT_M = 1e-6  # node graph vs ROS-free objects: the largest position difference allowed
# after discovery, for every publisher/subscriber pair to match: on a loaded CI machine the fusion node's
# subscriptions once matched over 2 s late (hydranet's first five rotations lost, DPC-Net's windows shifted)
GRAPH_SETTLE_S = 5.0


def register(sub: Any) -> None:
    demo = sub.add_parser("demo", help="the main job: sample bags through the real node graph, evaluated (runs/demo)")
    demo.set_defaults(handler=run)
    demo.add_argument("bags", nargs="*", type=Path, help=f"sample bags (default: {' '.join(SAMPLES)})")
    demo.add_argument("--out", "-o", type=Path, default=Path("runs/demo"), help="output directory (default runs/demo)")
    demo.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1: real time)")
    demo.add_argument("--sun-error", type=float, default=10.0, help="simulated sun mean error, degrees (default 10: GT-Sun-10)")
    demo.add_argument("--timeout", type=float, default=120.0, help="seconds to wait for the graph to finish a bag")
    demo.add_argument(
        "--sun",
        choices=SUN_SOURCES,
        default="auto",
        help="sun sensor: sun-bcnn, simulated (GT-Sun) or auto (default: sun-bcnn where the bag has /gps/fix)",
    )
    demo.add_argument("--sun-model", default="", help="Sun-BCNN model directory (default: the shipped model)")
    demo.add_argument(
        "--hydranet",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="run hydranet beside the learned sun (default: yes)",
    )
    demo.add_argument("--hydranet-model", default="", help="HydraNet model directory (default: the shipped model)")
    demo.add_argument(
        "--dpc-net",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="run dpc_net beside the learned sun (default: yes)",
    )
    demo.add_argument(
        "--dpc-net-model",
        default="dpc_net_clean",
        help="DPC-Net model directory or shipped name (default dpc_net_clean: the sample's rig, no lens distortion)",
    )
    demo.add_argument(
        "--ablation",
        action="store_true",
        help="run each bag once per sensor set (every sensor; without each; each alone) on the same VO and tabulate "
        "what each adds (OUT/ablation/)",
    )
    demo.add_argument(
        "--probe-model",
        default="probe_sim",
        help="PROBE model of stereo_vo (probe.model) beside the learned sun: a directory or shipped name (default "
        "probe_sim: the synthetic sample's rig); '' for the VO's default noise",
    )
    demo.add_argument(
        "--vo-calibration",
        default="default_vo",
        help="where the learned graph runs the VO without PROBE, the fusion weighs its covariances as this "
        "calibration (`pvo vo calibrate`) scales them: a file, or default_vo (default: the shipped one); '' for as read "
        "(a PROBE model's VO: its card's calibration, if any)",
    )


def run(args: argparse.Namespace) -> int:
    from ..paths import repository_root

    root = repository_root()
    bags = args.bags or [(root or Path.cwd()) / s for s in SAMPLES]
    settings = DemoSettings(
        args.rate,
        args.sun_error,
        args.timeout,
        args.sun,
        args.sun_model,
        args.hydranet,
        args.hydranet_model,
        args.dpc_net,
        args.dpc_net_model,
        args.probe_model,
        vo_calibration=args.vo_calibration,
    )
    domain = int(os.environ.get("ROS_DOMAIN_ID") or random.Random().randint(40, 89))
    if args.ablation:
        return run_ablation(bags, args.out / "ablation", settings, domain)
    start = time.perf_counter()
    results = []
    for bag in bags:
        out = args.out / Path(bag).name
        print(f"== {bag} -> {out} (ROS_DOMAIN_ID={domain}) ==", flush=True)
        result = run_demo_sample(Path(bag), out, settings, domain)
        print(result.table)
        print(f"wrote {out}/report.md, metrics.json, trajectory.png, errors.png ({result.seconds:.1f} s)\n", flush=True)
        results.append(result)
    (args.out / "report.md").write_text(summary_report(results, time.perf_counter() - start))
    print(f"demo: {len(results)} sample(s) in {time.perf_counter() - start:.1f} s; summary in {args.out / 'report.md'}")
    failed = [r for r in results if not r.agrees]
    if failed:
        raise PvoError(
            "the node graph and the ROS-free objects disagree on "
            + ", ".join(f"{r.name} ({r.max_difference_m:.2e} m)" for r in failed)
            + f" (allowed {AGREEMENT_M:g} m)"
        )
    return 0


def write_params(path: Path, parameters: dict[str, dict[str, Any]]) -> Path:
    """A ROS 2 parameter file: ``node: ros__parameters: {...}`` per node."""
    path.write_text(yaml.safe_dump({node: {"ros__parameters": values} for node, values in parameters.items()}, sort_keys=False))
    return path


SUN_SOURCES = ("auto", "sun-bcnn", "simulated", "none")


@dataclass(frozen=True)
class DemoSettings:
    rate: float = 1.0
    sun_error_deg: float = 10.0
    timeout_s: float = 120.0
    sun: str = "auto"  # one of SUN_SOURCES
    sun_model: str = ""  # Sun-BCNN model directory; "" = the shipped one
    hydranet: bool = True  # hydranet beside the learned sun
    hydranet_model: str = ""  # HydraNet model directory; "" = the shipped one
    dpc_net: bool = True  # dpc_net beside the learned sun
    dpc_net_model: str = "dpc_net_clean"  # DPC-Net model directory or shipped name
    probe_model: str = "probe_sim"  # stereo_vo's probe.model beside the learned sun; "" = the default noise
    # stereo_vo runs the VO the DPC-Net model learned to correct even where dpc_net does not run (an ablation
    # compares the sensors on one VO)
    vo_of_dpc_net: bool = False
    # the calibration of the VO without PROBE (a PROBE model's VO: its card's): the shipped default_vo, a file, or
    # "" for none (its covariances as read)
    vo_calibration: str = "default_vo"


@dataclass(frozen=True)
class DemoNodes:
    """Which nodes a sample's graph runs: ``sun_node`` (``sun_bcnn``, ``simulated_sun`` or None: no sun sensor),
    ``learned`` (the learned pseudo-sensors run: the bag has GPS for the learned sun's reference, or Sun-BCNN was
    asked for), ``sensors`` (the learned sensor nodes among `LEARNED_SENSORS`) and ``probe`` (stereo_vo with PROBE)."""

    sun_node: str | None
    learned: bool
    sensors: tuple[str, ...]
    probe: bool

    @property
    def names(self) -> tuple[str, ...]:
        """The graph's nodes in data-flow order, as its report names them."""
        sun = () if self.sun_node is None or self.sun_node in self.sensors else (self.sun_node,)
        return ("stereo_vo", *sun, *self.sensors, "fusion")


def plan_nodes(settings: DemoSettings, gps_fixes: int) -> DemoNodes:
    """The nodes ``settings`` run on a bag with ``gps_fixes`` /gps/fix messages: the learned sun where the bag has
    at least 3 fixes (its reference comes from the ephemeris there) and ``sun`` is auto, GT-Sun elsewhere; with the
    learned sun (or with none asked for, on such a bag) come PROBE, hydranet and dpc_net as ``settings`` ask."""
    has_gps = gps_fixes >= 3
    learned = settings.sun == "sun-bcnn" or (settings.sun in ("auto", "none") and has_gps)
    if settings.sun == "none":
        sun_node = None
    else:
        sun_node = "sun_bcnn" if settings.sun == "sun-bcnn" or (settings.sun == "auto" and has_gps) else "simulated_sun"
    if not learned:
        return DemoNodes(sun_node, False, (), False)
    sensors = (
        *(("sun_bcnn",) if sun_node == "sun_bcnn" else ()),
        *(("hydranet",) if settings.hydranet else ()),
        *(("dpc_net",) if settings.dpc_net else ()),
    )
    return DemoNodes(sun_node, True, sensors, bool(settings.probe_model))


@dataclass
class SampleResult:
    name: str
    table: str
    seconds: float
    max_difference_m: float
    agrees: bool
    figures: dict[str, dict[str, Any]] = field(default_factory=dict)


ESTIMATES = (
    ("VO (stereo_vo)", "vo"),
    ("fused online (/pvo/fusion/odometry)", "fused_online"),
    ("fused smoothed (/pvo/fusion/path)", "fused_smoothed"),
)


def run_demo_sample(bag: Path, out: Path, settings: DemoSettings, domain_id: int) -> SampleResult:
    """One sample bag through the graph, recorded, evaluated and compared with the ROS-free objects."""
    import shutil

    import numpy as np
    from pvo_core.msgconv import pose_to_xyz_xyzw, xyz_xyzw_to_pose
    from pvo_fusion.sun_reference import TabulatedSunReference
    from pvo_pseudosensors.simulated_sun import SimulatedSunConfig

    from pvo_fusion.config import FusionConfig
    from pvo_fusion.config import from_flat as fusion_from_flat

    from ..samples import read_stereo_sample

    start = time.perf_counter()
    sample = read_stereo_sample(bag)
    stamps = sample.frame_stamps
    ground_truth = sample.ground_truth_at(stamps)
    plan = plan_nodes(settings, len(sample.gps))
    learned = plan.learned
    if out.exists():
        if any(out.iterdir()) and not (out / "params.yaml").is_file():
            raise PvoError(f"{out} exists and is not an earlier demo output (no params.yaml); not replaced")
        shutil.rmtree(out)
    out.mkdir(parents=True)
    reference_table = out / "sun_reference.csv"
    sun_config: Any = None
    sun_node = plan.sun_node
    if sun_node is None:
        pass  # no sun sensor: the fusion gets none to weigh and needs no reference
    elif sun_node == "sun_bcnn":
        from pvo_pseudosensors.sun_bcnn.estimator import SunBCNNSensorConfig

        fixes = [s for s in sorted(sample.gps) if s in sample.ground_truth]
        if len(fixes) < 3:
            raise PvoError(f"{bag}: fewer than 3 /gps/fix at ground-truth stamps: no ephemeris for Sun-BCNN's reference")
        reference, _ = TabulatedSunReference.from_ephemeris_in_map(
            stamps, [sample.gps[s] for s in fixes], sample.ground_truth_at(np.array(fixes))[:, :3, 3]
        )
        TabulatedSunReference.write(reference_table, stamps, reference.directions)
        sun_config = SunBCNNSensorConfig(model=settings.sun_model)
        sun_parameters: dict[str, Any] = {"model": settings.sun_model}
    else:
        sun_stamps = sorted(s for s in sample.sun if s in sample.ground_truth)
        if not sun_stamps:
            raise PvoError(
                f"{bag}: no /ground_truth/sun_direction at a ground-truth stamp: the simulated sun has nothing to read"
            )
        TabulatedSunReference.write(
            reference_table,
            sun_stamps,
            TabulatedSunReference.from_ground_truth(
                sun_stamps, sample.ground_truth_at(sun_stamps), [sample.sun[s] for s in sun_stamps]
            ).directions,
        )
        sun_config = SimulatedSunConfig(mean_error_deg=settings.sun_error_deg)
        sun_parameters = {"mean_error_deg": settings.sun_error_deg}
    initial_pose = pose_to_xyz_xyzw(ground_truth[0])
    fusion_overrides: dict[str, Any] = {"prior.source": "given"}
    if sun_node is None:
        fusion_overrides["inputs.sun.enabled"] = False
    else:
        fusion_overrides.update({"inputs.sun.reference": "table", "inputs.sun.reference_table": str(reference_table.resolve())})
    graph = learned_graph(settings, plan.sensors) if learned else LearnedGraph({}, {}, {})
    fusion_overrides.update(graph.fusion)
    vo_parameters = graph.vo
    rotation_config = None
    if "hydranet" in graph.sensors:
        from pvo_pseudosensors.hydranet.estimator import HydraNetSensorConfig

        rotation_config = HydraNetSensorConfig(model=settings.hydranet_model)
    correction_config = None
    if "dpc_net" in graph.sensors:
        from pvo_pseudosensors.dpc_net.estimator import DPCNetSensorConfig

        correction_config = DPCNetSensorConfig(model=settings.dpc_net_model)
    parameters = {
        "stereo_vo": vo_parameters,
        **({sun_node: sun_parameters} if sun_node is not None else {}),
        **{name: values for name, values in graph.sensors.items() if name != "sun_bcnn"},
        "fusion": {**fusion_overrides, "initial_pose": initial_pose, "path_period": 0.0, "path_max_poses": 0},
    }
    params_file = write_params(out / "params.yaml", parameters)
    recorded_bag = out / "recorded"
    hydranet = rotation_config is not None
    dpc_net = correction_config is not None
    run_graph(bag, params_file, recorded_bag, out / "logs", settings, domain_id, len(stamps), sun_node, hydranet, dpc_net)
    graph_seconds = time.perf_counter() - start

    from pvo_frontend.vo import VOConfig, from_flat

    from ..pipeline import run_pipeline
    from ..recorded import read_arrivals, read_header_stamps, read_windows

    fusion_config: FusionConfig = fusion_from_flat(fusion_overrides)
    sun_stamps = read_header_stamps(recorded_bag, "/pvo/sun/direction") if sun_node == "sun_bcnn" else None
    # the objects estimate the sun at the frames the sun node chose (it counts the images it received)
    vo_config: VOConfig = from_flat(vo_parameters)  # the node's parameters, so the objects run the same VO
    ros_free = run_pipeline(
        sample,
        vo_config,
        sun_config,
        fusion_config,
        TabulatedSunReference.read(reference_table) if sun_node is not None else None,
        xyz_xyzw_to_pose(initial_pose),
        sun_stamps=sun_stamps,
        rotation_config=rotation_config,
        # the sensors race the VO for each image (load decides who wins): the objects take every measurement in
        # the order the fusion node did (its status lists what it took before each frame)
        arrivals=read_arrivals(recorded_bag),
        correction_config=correction_config,
        correction_windows=read_windows(recorded_bag, "/pvo/dpc/correction") if dpc_net else None,
    )
    result = evaluate_sample(bag.name, recorded_bag, stamps, ground_truth, ros_free, out, sun_node)
    result.seconds = time.perf_counter() - start
    result.figures["timing"] = {"graph_s": graph_seconds, "total_s": result.seconds}
    return result


LEARNED_SENSORS = ("sun_bcnn", "hydranet", "dpc_net")


@dataclass(frozen=True)
class LearnedGraph:
    """The learned pseudo-sensors as the main job runs them, each node's parameters (dotted names) read from the
    model cards: ``vo`` for stereo_vo (PROBE's model, the VO the DPC-Net model learned to correct), ``fusion`` for
    how the fusion weighs the learned sun and the corrections, ``sensors`` for each sensor node that runs."""

    vo: dict[str, Any]
    fusion: dict[str, Any]
    sensors: dict[str, dict[str, Any]]


def learned_graph(settings: DemoSettings, sensors: tuple[str, ...] | None = None, who: str = "pvo demo") -> LearnedGraph:
    """The node parameters of the learned graph: ``sensors`` among `LEARNED_SENSORS` (default: sun_bcnn, with
    hydranet and dpc_net as ``settings`` ask); a card the fusion cannot take is one line (`PvoError`)."""
    from pvo_fusion.config import from_flat as fusion_from_flat

    if sensors is None:
        sensors = ("sun_bcnn", *(("hydranet",) if settings.hydranet else ()), *(("dpc_net",) if settings.dpc_net else ()))
    unknown = [name for name in sensors if name not in LEARNED_SENSORS]
    if unknown:
        raise PvoError(f"unknown learned sensor(s) {', '.join(unknown)}: choose among {', '.join(LEARNED_SENSORS)}")
    fusion: dict[str, Any] = {}
    nodes: dict[str, dict[str, Any]] = {}
    if "sun_bcnn" in sensors:  # how the fusion weighs the learned sun: its card says (an offset shared by a drive's readings)
        from pvo_pseudosensors.learning.checkpoint import ModelFileError, read_card
        from pvo_pseudosensors.sun_bcnn.estimator import resolve_model
        from pvo_pseudosensors.sun_bcnn.infer import card_fusion

        try:
            fusion.update(card_fusion(read_card(resolve_model(settings.sun_model))))
            fusion_from_flat(fusion)  # a bad card entry is one line here, not a fusion node dying later
        except (ModelFileError, ValueError) as exc:
            raise PvoError(f"{settings.sun_model}: {exc}") from None
        nodes["sun_bcnn"] = {"model": settings.sun_model}
    if "hydranet" in sensors:
        nodes["hydranet"] = {"model": settings.hydranet_model}
    vo: dict[str, Any] = {"probe.model": settings.probe_model} if settings.probe_model else {}
    if "dpc_net" in sensors or settings.vo_of_dpc_net:  # DPC-Net corrects the VO it learned: the graph runs that one
        vo = dpc_net_vo(settings.dpc_net_model, who) | vo
    # the fusion weighs the VO's motions by their covariances as that VO's calibration scales them (a DPC-Net card
    # that fuses sets its own after)
    fusion.update(vo_fusion(settings, vo, who))
    if "dpc_net" in sensors:
        # ... and weighs its corrections against that VO as the card's validation drives chose (`pvo dpc-net correct`)
        fusion.update(dpc_net_fusion(settings.dpc_net_model, who))
        nodes["dpc_net"] = {"model": settings.dpc_net_model}
    return LearnedGraph(vo, fusion, nodes)


def vo_fusion(settings: DemoSettings, vo: dict[str, Any], who: str = "pvo demo") -> dict[str, Any]:
    """The fusion's ``inputs.vo.covariance_scale`` for the VO the graph runs (``vo``: stereo_vo's parameters) from
    that VO's calibration record (`pvo_frontend.vo_calibration`): the PROBE model's card where it runs one (`pvo probe
    calibrate`), else ``settings.vo_calibration`` (the shipped ``default_vo``: `pvo vo calibrate`), announced on stderr.
    None when there is no record, or when the record measured a VO with other settings (said on stderr: its scales
    are not this VO's)."""
    from pvo_frontend.probe.model import card_vo_calibration
    from pvo_frontend.probe.model import resolve_model as resolve_probe_model
    from pvo_frontend.vo_calibration import differing_settings, read_vo_calibration, resolve_calibration

    if settings.probe_model:
        where = f"{settings.probe_model}'s card"
        try:
            calibration = card_vo_calibration(resolve_probe_model(settings.probe_model))
        except ValueError as exc:
            raise PvoError(f"{settings.probe_model}: {exc}") from None
    elif settings.vo_calibration:
        path = resolve_calibration(settings.vo_calibration)
        where = str(path) if settings.vo_calibration != path.stem else f"the {path.stem} calibration ({path})"
        if not path.is_file():
            raise PvoError(f"{settings.vo_calibration}: no VO calibration file there ({path})")
        try:
            calibration = read_vo_calibration(path)
        except ValueError as exc:
            raise PvoError(str(exc)) from None
        if calibration is None:
            raise PvoError(f"{path}: no vo_calibration entry (write one with pvo vo calibrate)")
    else:
        return {}
    if calibration is None:
        return {}
    try:
        differ = differing_settings(calibration, vo)
    except ValueError as exc:
        raise PvoError(f"stereo_vo's parameters {vo}: {exc}") from None
    if differ:
        listed = ", ".join(f"{name} {recorded!r} there, {value!r} here" for name, (recorded, value) in differ.items())
        print(
            f"{who}: {where} calibrated another VO ({listed}): the fusion weighs the VO's covariances as read",
            file=sys.stderr,
            flush=True,
        )
        return {}
    scale = list(calibration.covariance_scale)
    listed = " ".join(f"{v:.3g}" for v in scale)
    print(
        f"{who}: fusion weighs the VO by its covariances scaled as {where} calibrated them ({listed})",
        file=sys.stderr,
        flush=True,
    )
    return {"inputs.vo.covariance_scale": scale}


def dpc_net_vo(model: str, who: str = "pvo demo") -> dict[str, Any]:
    """The VO settings (dotted names) that differ from the defaults in the VO the DPC-Net ``model`` learned (its
    card names it), announced on stderr when there are any."""
    from pvo_pseudosensors.dpc_net.config import vo_differences
    from pvo_pseudosensors.dpc_net.estimator import resolve_model
    from pvo_pseudosensors.learning.checkpoint import ModelFileError, read_card

    try:
        rig = read_card(resolve_model(model)).input.get("rig") or {}
        differences = vo_differences(rig.get("vo_settings") or {})
    except (ModelFileError, ValueError) as exc:
        raise PvoError(f"{model}: {exc}") from None
    if differences:
        listed = ", ".join(f"{name}={value}" for name, value in differences.items())
        print(f"{who}: stereo_vo runs the VO that {model} learned to correct ({listed})", file=sys.stderr, flush=True)
    return differences


def dpc_net_fusion(model: str, who: str = "pvo demo") -> dict[str, Any]:
    """The fusion node's parameters that weigh the DPC-Net ``model``'s corrections as its card's calibration does
    (`pvo dpc-net calibrate --drives`): the VO's covariance scales (``inputs.vo.covariance_scale``, ROS order) when the
    card fuses some axis and carries them, and the corrections over which the VO's translation bias is learned from
    them and the scale of its turns when the card chose that (``inputs.correction.vo_bias_windows``,
    ``inputs.correction.vo_rotation_scale_*``), announced on stderr; else none (the VO's own covariances, as read)."""
    from pvo_pseudosensors.dpc_net.estimator import resolve_model
    from pvo_pseudosensors.learning.checkpoint import ModelFileError, read_card

    from ..dpc import card_vo_calibration, card_vo_fusion, describe_vo_fusion

    try:
        card = read_card(resolve_model(model))
        calibration = card_vo_calibration(card)
        debias = card_vo_fusion(card)
    except (ModelFileError, ValueError) as exc:
        raise PvoError(f"{model}: {exc}") from None
    if calibration is None or not (card.calibration or {}).get("fused_axes"):
        return {}
    scale = [float(v) for v in calibration.scale]
    listed = " ".join(f"{v:.3g}" for v in scale)
    print(
        f"{who}: fusion weighs {model}'s corrections against the VO's covariances scaled by its card ({listed})"
        + (f", {describe_vo_fusion(debias)}" if debias else ""),
        file=sys.stderr,
        flush=True,
    )
    return {"inputs.vo.covariance_scale": scale} | debias


def run_graph(
    bag: Path,
    params_file: Path,
    recorded_bag: Path,
    log_dir: Path,
    settings: DemoSettings,
    domain_id: int,
    frames: int,
    sun_node: str | None = "simulated_sun",
    hydranet: bool = False,
    dpc_net: bool = False,
) -> None:
    """stereo_vo, the sun node (simulated_sun, sun_bcnn or None: no sun sensor), hydranet and dpc_net (when asked)
    and fusion as processes; the bag played and the outputs recorded in this process."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node

    from ..launch import STOP_TIMEOUT_S, NodeGroup, wait_for_graph, wait_until
    from ..player import BagPlayer, PlayOptions
    from ..recorder import BagRecorder, RecordOptions
    from ..testing import Spinner

    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))
    nodes = NodeGroup()
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    try:
        executables = [("pvo_frontend", "stereo_vo"), ("pvo_fusion", "fusion")]
        if sun_node is not None:
            executables.insert(1, ("pvo_pseudosensors", sun_node))
        if hydranet:
            executables.insert(2, ("pvo_pseudosensors", "hydranet"))
        if dpc_net:
            executables.insert(2, ("pvo_pseudosensors", "dpc_net"))
        for package, executable in executables:
            nodes.start(package, executable, params_file, log_dir, env)
        recorder_node = Node("pvo_demo_recorder", context=context)
        player_node = Node("pvo_demo_player", context=context)
        outputs = [
            *(t for t in OUTPUT_TOPICS if sun_node is not None or t != "/pvo/sun/direction"),
            *(["/pvo/hydranet/rotation"] if hydranet else []),
            *(["/pvo/dpc/correction"] if dpc_net else []),
        ]
        recorder = BagRecorder(recorder_node, recorded_bag, RecordOptions(topics=outputs, stamp="header"))
        player = BagPlayer(player_node, bag, PlayOptions(rate=settings.rate, topics=INPUT_TOPICS, wait_for_subscribers=0))
        try:
            with Spinner(context, recorder_node):
                # Every edge of the graph, publishers and subscribers, as this process sees them.
                image_readers = 1 + (sun_node == "sun_bcnn") + hydranet + dpc_net
                sun_input = {"/ground_truth/sun_direction": (0, 1)} if sun_node == "simulated_sun" else {}
                sun_output = {"/pvo/sun/direction": (1, 2)} if sun_node is not None else {}
                rotation = {"/pvo/hydranet/rotation": (1, 2)} if hydranet else {}
                correction = {"/pvo/dpc/correction": (1, 2), "/stereo/right/image_rect": (0, 1 + dpc_net)} if dpc_net else {}
                wait_for_graph(
                    player_node,
                    {
                        "/stereo/left/image_rect": (0, image_readers),
                        **sun_input,
                        **rotation,
                        **correction,
                        "/pvo/vo/relative": (1, 2 + dpc_net),
                        **sun_output,
                        "/pvo/fusion/odometry": (1, 1),
                        "/pvo/fusion/path": (1, 1),
                    },
                    timeout_s=60.0,
                    check=nodes.check,
                )
                wait_until(lambda: len(recorder.subscribed_topics) == len(outputs), 10.0, nodes.check)
                # Discovery shows the endpoints before each pair of them has matched: let the matching settle.
                time.sleep(GRAPH_SETTLE_S)
                player.play()  # returns once every subscriber acknowledged every message
                finished = wait_until(
                    lambda: recorder.received("/pvo/vo/relative") >= frames - 1, settings.timeout_s, nodes.check
                )
                finished = finished and wait_until(
                    lambda: (
                        recorder.received("/pvo/fusion/odometry") >= recorder.received("/pvo/vo/relative")
                        and recorder.received("/pvo/fusion/path") >= recorder.received("/pvo/vo/relative")
                    ),
                    settings.timeout_s,
                    nodes.check,
                    stalled=lambda: (recorder.received("/pvo/fusion/status"), recorder.received("/pvo/fusion/odometry")),
                )
                counts = {topic: recorder.received(topic) for topic in outputs}
        finally:
            recorder.close()
            for node in (recorder_node, player_node):
                node.destroy_node()
    finally:
        codes = nodes.stop()
        rclpy.shutdown(context=context)
    died = failed_nodes(codes, nodes.escalated, nodes.killed)
    for name in nodes.escalated:
        if name not in died:  # stopped, but not by SIGINT: say so, and where its stacks at that moment are
            print(
                f"pvo demo: warning: {name} did not stop within {STOP_TIMEOUT_S / 2:g} s of SIGINT; SIGTERM stopped it "
                f"(its threads' stacks when it hung: {log_dir / (name + '.log')})",
                file=sys.stderr,
            )
    if died:
        killed = f"killed: still running {STOP_TIMEOUT_S:g} s after SIGINT, SIGTERM at {STOP_TIMEOUT_S / 2:g} s"
        raise PvoError(
            "node(s) did not exit cleanly: "
            + ", ".join(
                f"{name} ({killed if name in nodes.killed else f'exit {code}'}, log {log_dir / (name + '.log')})"
                for name, code in died.items()
            )
        )
    expected = [
        "/pvo/vo/relative",
        *(["/pvo/sun/direction"] if sun_node is not None else []),
        "/pvo/fusion/odometry",
        *(["/pvo/hydranet/rotation"] if hydranet else []),
        *(["/pvo/dpc/correction"] if dpc_net else []),
    ]
    empty = [topic for topic in expected if counts[topic] == 0]
    if empty:
        raise PvoError(f"{bag}: nothing received on {', '.join(empty)} (node logs in {log_dir})")
    if not finished:
        raise PvoError(
            f"{bag}: the graph did not finish within {settings.timeout_s:g} s: "
            + ", ".join(f"{topic} {counts[topic]}" for topic in ("/pvo/vo/relative", "/pvo/fusion/odometry", "/pvo/fusion/path"))
            + f" of {frames - 1} frames"
        )


def failed_nodes(codes: dict[str, int], escalated: list[str], killed: list[str]) -> dict[str, int]:
    """The nodes whose exit is a failure of the run: a non-zero exit status, except a node that did not stop on
    SIGINT and then stopped on the SIGTERM it was sent (status -15): its work was done and its outputs are checked
    on their own; what hung was its teardown (DDS's node destruction, now and then under load; its threads' stacks
    are in its log), which ros2 launch reports as a warning too. A node killed (SIGKILL) is a failure."""
    return {
        name: code
        for name, code in codes.items()
        if code != 0 and not (name in escalated and name not in killed and code == -signal.SIGTERM)
    }


def evaluate_sample(
    name: str,
    recorded_bag: Path,
    stamps: Any,
    ground_truth: Any,
    ros_free: Any,
    out: Path,
    sun_node: str | None = "simulated_sun",
) -> SampleResult:
    """Metrics of VO alone and fused against the ground truth, agreement with the ROS-free run, report files."""
    import numpy as np
    from pvo_core.evaluation import evaluate, pose_consistency
    from pvo_core.results import RunResult

    from pvo_core import metrics

    from ..plots import plot_demo
    from ..recorded import read_recorded

    recorded = read_recorded(recorded_bag, ["/pvo/vo/odometry", "/pvo/fusion/odometry", "/pvo/fusion/path"])
    missing = [t for t in ("/pvo/vo/odometry", "/pvo/fusion/odometry", "/pvo/fusion/path") if t not in recorded]
    if missing:
        raise PvoError(f"{recorded_bag}: nothing recorded on {', '.join(missing)}")
    vo_poses, vo_cov = recorded["/pvo/vo/odometry"].at(stamps)
    online, online_cov = recorded["/pvo/fusion/odometry"].at(stamps)
    smoothed, _ = recorded["/pvo/fusion/path"].at(stamps)
    # frame 0 defines the frames: odom is the first camera, the fusion's first state is its prior
    vo_poses[0], online[0] = ros_free.vo_poses[0], smoothed[0]
    estimates = {"vo": (vo_poses, vo_cov), "fused_online": (online, online_cov), "fused_smoothed": (smoothed, None)}
    frames = list(range(len(stamps)))
    figures: dict[str, dict[str, Any]] = {}
    for _, key in ESTIMATES:
        poses, covariances = estimates[key]
        complete = metrics.count_finite_poses(poses)
        if complete != len(stamps):
            raise PvoError(f"{recorded_bag}: {key} has poses for {complete} of {len(stamps)} frames")
        ev = evaluate(ground_truth, poses, frames)
        row = {
            k: ev.figures[k]
            for k in ("frames", "path_length_m", "end_drift_percent", "ate_rmse_m", "m_ate_translation_m", "m_ate_rotation_deg")
        }
        row.update(
            rpe_translation_mean_m=ev.figures["rpe_translation_mean_m"],
            rpe_rotation_mean_deg=ev.figures["rpe_rotation_mean_deg"],
        )
        if covariances is not None:
            row.update(pose_consistency(ground_truth, poses, covariances))
        figures[key] = row
    agreement = {
        "vo_max_position_difference_m": metrics.max_position_difference(vo_poses, ros_free.vo_poses),
        "fused_smoothed_max_position_difference_m": metrics.max_position_difference(smoothed, ros_free.fused.poses),
        "fused_online_max_position_difference_m": metrics.max_position_difference(online[1:], ros_free.fused.online_poses[1:]),
    }
    if ros_free.rotations:
        published, expected = published_and_expected(recorded_bag, "/pvo/hydranet/rotation", ros_free.rotations, "hydranet")
        # the rotation matrices element by element (an angle through arccos would stop at 1e-8 near identity)
        agreement["hydranet_max_rotation_difference"] = float(np.max(np.abs(published[:, :3, :3] - expected[:, :3, :3])))
    if ros_free.corrections:
        published, expected = published_and_expected(recorded_bag, "/pvo/dpc/correction", ros_free.corrections, "dpc_net")
        agreement["dpc_net_max_position_difference_m"] = metrics.max_position_difference(published, expected)
        agreement["dpc_net_max_rotation_difference"] = float(np.max(np.abs(published[:, :3, :3] - expected[:, :3, :3])))
    worst = max(v for k, v in agreement.items() if k.endswith(("_m", "_difference")))
    figures["agreement_with_ros_free"] = agreement
    table = format_demo_table(name, figures)
    record = RunResult(
        "demo",
        name,
        figures={f"{key}.{k}": v for key, row in figures.items() for k, v in row.items()},
        tables={"estimates": {key: figures[key] for _, key in ESTIMATES}},
        inputs={"bag": name, "recorded": str(recorded_bag), "params": str(out / "params.yaml")},
        notes={
            "pose_anees": "ANEES per dof of absolute poses Log(T_gt T_est^-1) against the published covariance",
            "agreement": "largest position difference between the node graph and the same objects run without ROS, "
            "the objects taking the measurements in the order the fusion node reported taking them",
        },
    )
    record.write(out)
    plot_demo(out, name, ground_truth, {label: estimates[key][0] for label, key in ESTIMATES})
    (out / "report.md").write_text(
        f"# pvo demo: {name}\n\nThe sample replayed through stereo_vo -> "
        + " + ".join(
            [
                *([sun_node] if sun_node is not None else []),
                *(["hydranet"] if ros_free.rotations else []),
                *(["dpc_net"] if ros_free.corrections else []),
            ]
        )
        + (" -> " if sun_node is not None or ros_free.rotations or ros_free.corrections else "")
        + "fusion over DDS "
        "and recorded (`recorded/`), evaluated against its ground truth.\n\n```\n"
        + table
        + "\n```\n\n![trajectory](trajectory.png)\n\n![errors](errors.png)\n"
    )
    return SampleResult(name, table, 0.0, worst, worst <= AGREEMENT_M, figures)


def published_and_expected(recorded_bag: Path, topic: str, measurements: list[Any], node: str) -> tuple[Any, Any]:
    """The transforms a node published on ``topic`` (recorded) at the stamps of the ROS-free ``measurements``,
    and theirs: (N, 4, 4) each; a clear error when the node published fewer."""
    import numpy as np

    from pvo_core import metrics

    from ..recorded import read_recorded

    recorded = read_recorded(recorded_bag, [topic]).get(topic)
    if recorded is None:
        raise PvoError(f"{recorded_bag}: nothing recorded on {topic}")
    expected = np.array([m.transform for m in measurements])
    published, _ = recorded.at(np.array([m.stamp for m in measurements]))
    if metrics.count_finite_poses(published) != len(expected):
        raise PvoError(f"{recorded_bag}: {node} published {len(recorded.stamps)} of the {len(expected)} expected on {topic}")
    return published, expected


def format_demo_table(name: str, figures: dict[str, dict[str, Any]]) -> str:
    head = (
        f"{name}: {figures['vo']['frames']} frames, {figures['vo']['path_length_m']:.1f} m\n"
        f"{'estimate':<38}{'end drift':>10}{'ATE rmse':>10}{'RPE trans':>11}{'RPE rot':>10}{'ANEES':>8}\n"
        f"{'':<38}{'[%]':>10}{'[m]':>10}{'[m/frame]':>11}{'[deg]':>10}{'[/dof]':>8}"
    )
    lines = [head]
    for label, key in ESTIMATES:
        f = figures[key]
        anees = f"{f['pose_anees']:8.2f}" if "pose_anees" in f else f"{'-':>8}"
        lines.append(
            f"{label:<38}{f['end_drift_percent']:>10.3f}{f['ate_rmse_m']:>10.3f}"
            f"{f['rpe_translation_mean_m']:>11.4f}{f['rpe_rotation_mean_deg']:>10.4f}{anees}"
        )
    a = figures["agreement_with_ros_free"]
    fused = (
        f"fused smoothed {a['fused_smoothed_max_position_difference_m']:.1e} m, "
        f"fused online {a['fused_online_max_position_difference_m']:.1e} m"
    )
    lines.append(f"nodes vs ROS-free objects, max position difference: VO {a['vo_max_position_difference_m']:.1e} m, {fused}")
    if "hydranet_max_rotation_difference" in a:
        lines.append(
            f"hydranet node vs HydraNet object, max rotation-matrix difference: {a['hydranet_max_rotation_difference']:.1e}"
        )
    if "dpc_net_max_position_difference_m" in a:
        lines.append(
            f"dpc_net node vs DPC-Net object, max difference: position {a['dpc_net_max_position_difference_m']:.1e} m, "
            f"rotation matrix {a['dpc_net_max_rotation_difference']:.1e}"
        )
    return "\n".join(lines)


def summary_report(results: list[SampleResult], seconds: float) -> str:
    parts = [f"# pvo demo\n\n{len(results)} sample(s) through the real node graph in {seconds:.1f} s.\n"]
    for r in results:
        parts.append(f"## {r.name}\n\n```\n{r.table}\n```\n\nDetails: [{r.name}/report.md]({r.name}/report.md)\n")
    return "\n".join(parts)


# The sensor sets of an ablation, as changes to the settings asked for: every sensor, without each, each alone.
ABLATIONS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("every sensor", {}),
    ("without PROBE", {"probe_model": ""}),
    ("without the sun", {"sun": "none"}),
    ("without hydranet", {"hydranet": False}),
    ("without dpc_net", {"dpc_net": False}),
    ("VO, fused alone", {"sun": "none", "hydranet": False, "dpc_net": False}),
    ("VO + the sun", {"hydranet": False, "dpc_net": False}),
    ("VO + hydranet", {"sun": "none", "dpc_net": False}),
    ("VO + dpc_net", {"sun": "none", "hydranet": False}),
)


@dataclass(frozen=True)
class AblationVariant:
    label: str
    slug: str
    settings: DemoSettings
    nodes: DemoNodes


def ablation_variants(settings: DemoSettings, gps_fixes: int) -> list[AblationVariant]:
    """The distinct graphs of `ABLATIONS` on a bag with ``gps_fixes`` /gps/fix messages, each on the VO of the
    graph ``settings`` ask for (the one DPC-Net's model corrects, where dpc_net runs there): a sensor set that
    gives the same nodes as an earlier one (a sensor the bag's graph does not run) is left out."""
    from dataclasses import replace

    full = plan_nodes(settings, gps_fixes)
    same_vo = "dpc_net" in full.sensors
    variants: list[AblationVariant] = []
    seen: set[tuple[Any, ...]] = set()
    for label, changes in ABLATIONS:
        variant = replace(settings, **changes, vo_of_dpc_net=same_vo)
        nodes = plan_nodes(variant, gps_fixes)
        key = (nodes.sun_node, nodes.sensors, nodes.probe)
        if key in seen:
            continue
        seen.add(key)
        slug = label.lower().replace(",", "").replace("+", "and").replace(" ", "-").replace("--", "-")
        variants.append(AblationVariant(label, slug, variant, nodes))
    return variants


def describe_nodes(nodes: DemoNodes) -> str:
    """The graph in one line: ``stereo_vo(PROBE) sun_bcnn hydranet fusion``."""
    return " ".join(f"{name}(PROBE)" if name == "stereo_vo" and nodes.probe else name for name in nodes.names)


ESTIMATE_KEYS = tuple(key for _, key in ESTIMATES)
ABLATION_KEYS = ("end_drift_percent", "ate_rmse_m", "m_ate_translation_m", "m_ate_rotation_deg", "rpe_rotation_mean_deg")


def format_ablation_table(name: str, rows: list[tuple[str, str, dict[str, dict[str, Any]]]]) -> str:
    """``rows``: (label, nodes, the demo's figures) per variant, the first the full graph. Each variant's fused
    online estimate, and its change against the VO alone of the same run (the same VO in every run but those
    without PROBE)."""
    first = rows[0][2]["vo"]
    width = max(len(label) for label, _, _ in rows) + 2
    nodes_width = max(len(nodes) for _, nodes, _ in rows) + 2
    lines = [
        f"{name}: {first['frames']} frames, {first['path_length_m']:.1f} m; fused online (/pvo/fusion/odometry), the change "
        "against the same run's VO alone",
        f"{'graph':<{width}}{'nodes':<{nodes_width}}{'end drift':>10}{'ATE rmse':>10}{'m-ATE t':>9}{'m-ATE r':>9}"
        f"{'RPE rot':>9}{'Δ m-ATE t':>11}{'Δ m-ATE r':>11}",
        f"{'':<{width}}{'':<{nodes_width}}{'[%]':>10}{'[m]':>10}{'[m]':>9}{'[deg]':>9}{'[deg]':>9}{'[%]':>11}{'[%]':>11}",
    ]

    def row(label: str, nodes: str, f: dict[str, Any], vo: dict[str, Any] | None) -> str:
        def change(key: str) -> str:
            if vo is None or not vo[key]:
                return f"{'-':>11}"
            percent = round(100.0 * (f[key] - vo[key]) / vo[key], 1)
            return f"{percent:>+11.1f}" if percent else f"{'0.0':>11}"  # no "-0.0": unchanged is unchanged

        return (
            f"{label:<{width}}{nodes:<{nodes_width}}{f['end_drift_percent']:>10.3f}{f['ate_rmse_m']:>10.3f}"
            f"{f['m_ate_translation_m']:>9.3f}{f['m_ate_rotation_deg']:>9.3f}{f['rpe_rotation_mean_deg']:>9.4f}"
            f"{change('m_ate_translation_m')}{change('m_ate_rotation_deg')}"
        )

    vo_rows: dict[str, dict[str, Any]] = {}
    for _, nodes, figures in rows:
        vo_nodes = nodes.split(" ")[0]
        vo_rows.setdefault(vo_nodes, figures["vo"])
    for vo_nodes, figures in vo_rows.items():
        lines.append(row("VO alone", vo_nodes, figures, None))
    for label, nodes, figures in rows:
        lines.append(row(label, nodes, figures["fused_online"], figures["vo"]))
    return "\n".join(lines)


def run_ablation(bags: list[Path], out: Path, settings: DemoSettings, domain_id: int) -> int:
    """Every bag through each distinct graph of `ablation_variants`, as the demo runs it (nodes checked against
    the ROS-free objects), tabulated per bag (``OUT/<bag>/ablation.md``, ``metrics.json``) and in ``OUT/report.md``."""
    from pvo_core.results import RunResult

    from ..baginfo import bag_info

    start = time.perf_counter()
    reports = []
    disagreements = []
    for bag in bags:
        bag = Path(bag)
        if not bag.exists():
            raise PvoError(f"{bag}: no such bag")
        fixes = sum(count for topic, _, count, _ in bag_info(bag).topics if topic == "/gps/fix")
        variants = ablation_variants(settings, fixes)
        rows = []
        for k, variant in enumerate(variants, 1):
            target = out / bag.name / variant.slug
            described = describe_nodes(variant.nodes)
            print(f"== {bag.name} [{k}/{len(variants)}] {variant.label}: {described} -> {target} ==", flush=True)
            result = run_demo_sample(bag, target, variant.settings, domain_id)
            print(
                f"   fused online: end drift {result.figures['fused_online']['end_drift_percent']:.3f} %, ATE "
                f"{result.figures['fused_online']['ate_rmse_m']:.3f} m ({result.seconds:.1f} s)",
                flush=True,
            )
            if not result.agrees:
                disagreements.append(f"{bag.name} {variant.label} ({result.max_difference_m:.2e} m)")
            rows.append((variant.label, described, result.figures))
        table = format_ablation_table(bag.name, rows)
        print(table + "\n", flush=True)
        RunResult(
            "demo-ablation",
            bag.name,
            tables={
                variant.slug: {
                    key: {k: rows[i][2][key][k] for k in ABLATION_KEYS} for key in ("vo", "fused_online", "fused_smoothed")
                }
                for i, variant in enumerate(variants)
            },
            inputs={"bag": str(bag), "graphs": {v.slug: describe_nodes(v.nodes) for v in variants}},
            notes={"change": "each graph's fused online estimate against the VO alone of the same run"},
        ).write(out / bag.name)
        (out / bag.name / "ablation.md").write_text(f"# pvo demo --ablation: {bag.name}\n\n```\n{table}\n```\n")
        reports.append(f"## {bag.name}\n\n```\n{table}\n```\n")
    seconds = time.perf_counter() - start
    (out / "report.md").write_text(f"# pvo demo --ablation\n\n{len(bags)} bag(s) in {seconds:.1f} s.\n\n" + "\n".join(reports))
    print(f"demo --ablation: {len(bags)} bag(s) in {seconds:.1f} s; summary in {out / 'report.md'}")
    if disagreements:
        raise PvoError(
            f"the node graph and the ROS-free objects disagree on {', '.join(disagreements)} (allowed {AGREEMENT_M:g} m)"
        )
    return 0
