"""`pvo <model> train|predict|eval` for every learned pseudo-sensor of :mod:`pvo_pseudosensors.registry`.

The options of `train` are the model's settings (one per field of its config dataclass) plus the training
loop's (:class:`pvo_pseudosensors.learning.TrainConfig`); run it under ``torchrun --nproc-per-node N`` for
distributed data parallel training."""

from __future__ import annotations

import argparse
import dataclasses
import os
import shlex
import sys
from pathlib import Path
from typing import Any

from pvo_pseudosensors.registry import ModelEntry, models

from ..progress import Progress

TRAIN_DEFAULTS = {
    "epochs": (int, 30, "at most this many epochs"),
    "batch_size": (int, 32, "global batch size (split over torchrun processes)"),
    "learning_rate": (float, 1e-3, "AdamW learning rate"),
    "weight_decay": (float, 1e-4, "AdamW weight decay"),
    "schedule": (str, "cosine", "learning-rate schedule: cosine | step | constant"),
    "patience": (int, 8, "stop after this many epochs without a better validation loss (0: never)"),
    "seed": (int, 0, "seed of initialisation, shuffling and dropout"),
    "threads": (int, 2, "torch threads per process"),
}


#: command modules adding a model's own actions (``register_actions``): its predict / eval where they are not the
#: generated ones, and actions no other model has
CUSTOM_ACTIONS = {"dpc-net": "pvo_tools.commands.dpc_net", "hydranet": "pvo_tools.commands.hydranet"}


def register(sub: Any) -> None:
    for entry in models().values():
        parser = sub.add_parser(entry.name, help=entry.description)
        actions = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
        _train_parser(actions, entry)
        if entry.predict is not None:
            _predict_parser(actions, entry)
            _eval_parser(actions, entry)
        elif entry.name not in CUSTOM_ACTIONS:  # a model whose predict / eval take other inputs brings its own
            raise RuntimeError(f"model {entry.name!r} has no predict/eval and no command module in CUSTOM_ACTIONS")
        if entry.name in CUSTOM_ACTIONS:
            import importlib

            importlib.import_module(CUSTOM_ACTIONS[entry.name]).register_actions(actions, entry)
        if entry.calibrate is not None:
            _calibrate_parser(actions, entry)


def _option(name: str) -> str:
    return "--" + name.replace("_", "-")


def _train_parser(actions: Any, entry: ModelEntry) -> None:
    train = actions.add_parser("train", help=f"train {entry.name} on a corpus (model selection on its validation split)")
    train.set_defaults(handler=lambda args: run_train(args, entry))
    train.add_argument(
        "--corpus",
        type=Path,
        action="append",
        required=True,
        help="corpus directory rendered by `pvo sim corpus` (repeat to train on several: their splits are joined)",
    )
    train.add_argument("--out", "-o", type=Path, required=True, help="model directory (weights, card, history, plots)")
    train.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    train.add_argument(
        "--init",
        type=Path,
        metavar="MODEL",
        help="fine-tune: start from this model directory's weights (the same settings; its card says which)",
    )
    train.add_argument("--cache", type=Path, help="decoded-image cache (default CORPUS/.cache of each corpus)")
    train.add_argument("--max-sequences", type=int, default=0, help="use at most this many sequences per split (0: all)")
    train.add_argument(
        "--presets-only",
        type=lambda text: tuple(p.strip() for p in text.split(",") if p.strip()),
        default=(),
        help="train and validate on these presets' sequences only (e.g. urban: the others are then out of distribution)",
    )
    train.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    loop = train.add_argument_group("training loop")
    for name, (kind, default, text) in TRAIN_DEFAULTS.items():
        loop.add_argument(_option(name), type=kind, default=default, help=f"{text} (default {default})")
    model = train.add_argument_group(f"{entry.name} settings")
    for field in dataclasses.fields(entry.config):
        default = field.default
        text = entry.options.get(field.name, field.name)
        if isinstance(default, bool):
            model.add_argument(_option(field.name), action=argparse.BooleanOptionalAction, default=default, help=text)
        elif isinstance(default, tuple):
            model.add_argument(_option(field.name), default=",".join(map(str, default)), help=f"{text} (default {default})")
        else:
            model.add_argument(_option(field.name), type=type(default), default=default, help=f"{text} (default {default})")


def _predict_parser(actions: Any, entry: ModelEntry) -> None:
    predict = actions.add_parser("predict", help=f"run a trained {entry.name} over a sequence's images")
    predict.set_defaults(handler=lambda args: run_predict(args, entry))
    predict.add_argument("sequence", type=Path, help="KITTI-layout sequence directory")
    names = f", or a shipped model's name ({', '.join(entry.shipped)})" if entry.shipped else ""
    predict.add_argument("--model", type=Path, required=True, help=f"model directory (weights.safetensors + model.yaml){names}")
    predict.add_argument("--out", "-o", type=Path, required=True, help="prediction file (CSV)")
    predict.add_argument("--cache", type=Path, help="decoded-image cache directory (default: none, decode afresh)")
    if any(field.name == "pitch" for field in dataclasses.fields(entry.config)):  # a model that can read the pitch
        predict.add_argument(
            "--pitch-deg",
            type=float,
            help="the camera's pitch below the horizon (deg), read by a model trained with --pitch (default: the pitch "
            "the sequence's sim.yaml records; 0, level, where it has none)",
        )
    if not entry.mc_sampling:
        return
    if any(field.name == "equalize" for field in dataclasses.fields(entry.config)):  # Sun-BCNN: a real camera's images
        predict.add_argument(
            "--equalize",
            action="store_true",
            help="histogram-equalise every image before the network reads it, whatever the model was trained on (the "
            "synthetic model on a real camera)",
        )
    predict.add_argument("--samples", type=int, default=25, help="MC-dropout samples per image (default 25)")
    predict.add_argument("--seed", type=int, default=0, help="seed of the dropout samples (default 0)")
    predict.add_argument(
        "--mode",
        help="MC sampling: full (dropout everywhere, every pass) | head (backbone once), either with -mirrored "
        "(half the passes over the image mirrored left-right); default head-mirrored",
    )


def _calibrate_parser(actions: Any, entry: ModelEntry) -> None:
    what = "uncertainty" if entry.mc_sampling else "inference mode (recorded with its figures)"
    calibrate = actions.add_parser("calibrate", help=f"calibrate {entry.name}'s {what} on a corpus's validation split")
    calibrate.set_defaults(handler=lambda args: run_calibrate(args, entry))
    calibrate.add_argument("--model", type=Path, required=True, help="model directory; its model.yaml gets the result")
    calibrate.add_argument("--corpus", type=Path, required=True, help="corpus whose validation split to use")
    if entry.mc_sampling:
        calibrate.add_argument("--samples", type=int, default=25, help="MC-dropout samples per image (default 25)")
    calibrate.add_argument(
        "--mode",
        help="sun-bcnn's MC sampling: full | head | full-mirrored | head-mirrored (default head-mirrored); "
        "hydranet's inference: plain | mirrored | reversed (default plain)",
    )
    calibrate.add_argument("--max-sequences", type=int, default=0, help="at most this many sequences (0: all)")


def _eval_parser(actions: Any, entry: ModelEntry) -> None:
    evaluate = actions.add_parser("eval", help=f"evaluate {entry.name} predictions against the truth")
    evaluate.set_defaults(handler=lambda args: run_eval(args, entry))
    evaluate.add_argument("--pred", type=Path, required=True, help="prediction file from `predict`")
    evaluate.add_argument("--gt", type=Path, required=True, help=entry.truth)
    evaluate.add_argument("--json", type=Path, help="also write the figures as a run-result record here")


def _model_config(args: argparse.Namespace, entry: ModelEntry) -> Any:
    values = {}
    for field in dataclasses.fields(entry.config):
        value = getattr(args, field.name)
        if isinstance(field.default, tuple):
            try:
                value = tuple(int(v) for v in str(value).split(","))
            except ValueError:
                raise ValueError(f"{_option(field.name)} {value!r} must be comma-separated integers") from None
        values[field.name] = value
    return entry.config(**values)


def _corpus_command(manifest: Any) -> str:
    import yaml

    whole = yaml.safe_load(manifest.path.read_text())
    if whole.get("generator") == "pvo sim mirror":
        return f"pvo sim mirror {whole['mirrored_from']} {manifest.path.parent}"
    data = whole.get("corpus", {})
    if not data:
        return ""
    size = f"{data['width']}x{data['height']}"
    presets = ",".join(data["presets"])
    colour = " --colour" if data.get("colour") else ""
    colour += f" --supersample {data['supersample']}" if data.get("supersample", 1) != 1 else ""
    colour += f" --sky {data['sky']}" if data.get("sky", "gradient") != "gradient" else ""
    if data.get("lens_distortion"):
        colour += " --lens-distortion " + " ".join(f"{k:g}" for k in data["lens_distortion"])
    for name in ("focal", "baseline"):
        if data.get(f"calib_{name}_scale", 1.0) != 1.0:
            colour += f" --calib-{name}-scale {data[f'calib_{name}_scale']:g}"
    from pvo_sim.corpus import CorpusConfig

    from .corpus import DEGRADATION_SHARES

    defaults = CorpusConfig()
    for name in DEGRADATION_SHARES:
        if name in data and float(data[name]) != getattr(defaults, name):
            colour += f" --{name.replace('_', '-')} {float(data[name]):g}"
    if data.get("urban_pitch") and [float(v) for v in data["urban_pitch"]] != [0.0, 0.0]:
        colour += " --urban-pitch " + " ".join(f"{float(v):g}" for v in data["urban_pitch"])
    shares = data.get("split")
    if shares and [round(float(v), 6) for v in shares] != [0.7, 0.15, 0.15]:  # `pvo sim corpus`'s default shares
        colour += " --split " + ",".join(f"{float(v):g}" for v in shares)
    if data.get("kitti_poses"):
        drives = {split: ",".join(data[f"kitti_{split}"]) for split in ("train", "validation", "test")}
        colour += (
            f" --kitti-poses {data['kitti_poses']} --kitti-train {drives['train']} --kitti-validation {drives['validation']}"
            f" --kitti-test {drives['test']}"
        )
        if data.get("kitti_turning"):
            colour += " --kitti-turning"
        if data.get("kitti_level_frames"):
            colour += f" --kitti-level-frames {data['kitti_level_frames']}"
        if data.get("kitti_speed_scale") and [float(v) for v in data["kitti_speed_scale"]] != [1.0, 1.0]:
            colour += " --kitti-speed-scale " + " ".join(f"{float(v):g}" for v in data["kitti_speed_scale"])
    return (
        f"pvo sim corpus {manifest.path.parent} --sequences {data['sequences']} --frames {data['frames']} --size {size} "
        f"--presets {presets} --seed {data['seed']}{colour}"
    )


def _dataset(entry: ModelEntry, config: Any, sources: list, cache: Path, label: str, quiet: bool) -> Any:
    """The dataset of ``sources``, with a progress bar while images are decoded (and, for a model with a
    dataset of its own, what it derives from them) into the cache (none when warm)."""
    from pvo_pseudosensors.learning import FrameDataset

    spec = entry.spec(config)
    bar: Progress | None = None

    def decoded() -> None:
        nonlocal bar
        if bar is None:
            frames = [len(s.images("left", spec.colour)) for s in sources]
            work = entry.work(config, frames, label == "train") if entry.work else sum(frames) * (2 if spec.right else 1)
            bar = Progress(work, f"{label}: decoding images{' and computing their inputs' if entry.work else ''} into {cache}")
        bar.update()

    progress = None if quiet else decoded
    if entry.dataset is not None:
        data = entry.dataset(config, sources, cache, progress, training=label == "train")
    else:
        data = FrameDataset(sources, spec, cache, progress=progress)
    if bar is not None:
        bar.close()
    return data


def run_train(args: argparse.Namespace, entry: ModelEntry) -> int:
    from pvo_core.readers import read_corpus_manifest
    from pvo_pseudosensors.learning import Source, TrainConfig, fit
    from torch.utils.data import ConcatDataset

    config = _model_config(args, entry)
    if int(os.environ.get("RANK", "0")) != 0:  # under torchrun only the first process talks
        args.quiet = True
        sys.stdout = sys.stderr = open(os.devnull, "w")  # for the life of this worker process
    loop = TrainConfig(**{name: getattr(args, name) for name in TRAIN_DEFAULTS})
    manifests = [read_corpus_manifest(corpus) for corpus in args.corpus]
    sets = {}
    for split in ("train", "validation"):
        parts = []
        for manifest in manifests:
            sequences = [s for s in manifest.split(split) if not args.presets_only or s.preset in args.presets_only]
            off_rig = [s.name for s in sequences if set(s.conditions) & set(entry.off_rig)]
            if off_rig:
                print(
                    f"{entry.name}: {len(off_rig)} {split} sequence(s) of {manifest.path.parent} left out, another rig's "
                    f"({' or '.join(entry.off_rig)}): {', '.join(off_rig)}",
                    file=sys.stderr,
                )
                sequences = [s for s in sequences if s.name not in off_rig]
            sequences = sequences[: args.max_sequences or None]
            if not sequences:
                if len(manifests) == 1:
                    raise ValueError(f"{manifest.path}: no sequence in the {split} split")
                # an extra training corpus rendered with --split 1,0,0 adds no validation sequence: the others do
                print(f"{entry.name}: {manifest.path.parent} has no {split} sequence", file=sys.stderr)
                continue
            sources = [Source(sequence.root, sequence.name, split) for sequence in sequences]
            parts.append(_dataset(entry, config, sources, args.cache or manifest.path.parent / ".cache", split, args.quiet))
        if not parts:
            raise ValueError(f"no sequence in the {split} split of {', '.join(str(m.path) for m in manifests)}")
        sets[split] = parts[0] if len(parts) == 1 else ConcatDataset(parts)
    print(f"{entry.name}: {len(sets['train'])} training and {len(sets['validation'])} validation samples", file=sys.stderr)
    bar: Progress | None = None

    def progress(step: int, steps: int) -> None:
        nonlocal bar
        if args.quiet:
            return
        if bar is None or step == 1:
            if bar is not None:
                bar.close()
            bar = Progress(steps, "  batches")
        bar.update()

    corpora = [{"path": str(m.path.parent), "sha256": m.sha256, "sequences": len(m.sequences)} for m in manifests]
    if args.presets_only:  # the model card says which rig the model is for
        for corpus in corpora:
            corpus["presets"] = list(args.presets_only)
    extra = {
        "corpus": corpora[0] if len(corpora) == 1 else {"corpora": corpora},
        "commands": {
            "corpus": " && ".join(_corpus_command(m) for m in manifests),
            "train": "pvo " + shlex.join(getattr(args, "argv", sys.argv[1:])),
        },
    }
    task = entry.task(config) if entry.fit_task is None else entry.fit_task(config, sets["train"])
    if args.init is not None:
        from pvo_pseudosensors.learning.checkpoint import read_card
        from pvo_pseudosensors.learning.training import FineTune

        if not (args.init / "model.yaml").is_file():
            raise ValueError(f"--init {args.init}: not a model directory (no model.yaml)")
        if (read_card(args.init).calibration or {}).get("members"):
            raise ValueError(f"--init {args.init}: an ensemble; fine-tune each of its members instead")
        task = FineTune(task, args.init)
        # the card remakes the weights from nothing: the commands that made the initial model come first
        initial = read_card(args.init).commands
        extra["commands"] = {f"initial_{k}": v for k, v in initial.items()} | extra["commands"]
    result = fit(
        task,
        sets["train"],
        sets["validation"],
        loop,
        args.out,
        resume=args.resume,
        progress=progress,
        say=lambda line: print(line, file=sys.stderr, flush=True),
        card_extra=extra,
    )
    if bar is not None:
        bar.close()
    print(
        f"{args.out}: best validation loss {result.best_validation:.5g} at epoch {result.best_epoch} of {result.epochs_run}"
        f"{' (stopped early)' if result.stopped_early else ''}; {result.seconds:.0f} s"
    )
    return 0


def _reads_pitch(model: Path) -> bool:
    """Whether the model's card says it was trained with the camera's pitch as an input (False where unreadable:
    the predict call then names what is wrong with the model)."""
    from pvo_pseudosensors.learning.checkpoint import ModelFileError, read_card

    try:
        return bool(read_card(model).hyperparameters.get("pitch"))
    except ModelFileError:
        return False


def run_predict(args: argparse.Namespace, entry: ModelEntry) -> int:
    assert entry.predict is not None
    if entry.shipped:
        from pvo_pseudosensors.learning.checkpoint import resolve_model

        args.model = resolve_model(str(args.model), entry.shipped)
    if not entry.mc_sampling:
        extra = {"pitch_deg": args.pitch_deg} if getattr(args, "pitch_deg", None) is not None else {}
        if not extra and hasattr(args, "pitch_deg") and _reads_pitch(args.model) and not (args.sequence / "sim.yaml").is_file():
            # As the node's camera_pitch_deg default: a recording without the simulator's record is taken as level.
            extra = {"pitch_deg": 0.0}
            print(
                f"{args.sequence}: no sim.yaml, the camera's pitch taken as 0 deg (level; --pitch-deg to say otherwise)",
                file=sys.stderr,
            )
        predictions = entry.predict(args.model, args.sequence, cache_dir=args.cache, **extra)
        path = predictions.write_csv(args.out)
        print(f"{path}: {len(predictions.frames)} predictions")
        return 0
    if args.samples < 2:
        raise ValueError(f"--samples must be >= 2 (the covariance needs two), got {args.samples}")
    extra = {"equalize": True} if getattr(args, "equalize", False) else {}
    predictions = entry.predict(
        args.model, args.sequence, samples=args.samples, seed=args.seed, mode=args.mode, cache_dir=args.cache, **extra
    )
    path = predictions.write_csv(args.out)
    print(f"{path}: {len(predictions.frames)} predictions ({args.samples} MC samples each)")
    return 0


def run_calibrate(args: argparse.Namespace, entry: ModelEntry) -> int:
    from pvo_core.readers import read_corpus_manifest

    manifest = read_corpus_manifest(args.corpus)
    sequences = [s.root for s in manifest.split("validation")][: args.max_sequences or None]
    if not sequences:
        raise ValueError(f"{manifest.path}: no sequence in the validation split")
    assert entry.calibrate is not None
    samples = getattr(args, "samples", None)  # MC sampling only
    figures = entry.calibrate(args.model, sequences, samples=samples, mode=args.mode, cache_dir=args.corpus / ".cache")
    if "tau" in figures:
        print(
            f"{args.model}: tau {figures['tau']:.4g} (tau^-1 {1 / figures['tau']:.4g} rad^2), covariance scale "
            f"{figures['scale']:.4g} on {len(sequences)} validation sequences; ANEES over the {int(figures['kept'])} of "
            f"{int(figures['images'])} images the cosine-distance filter keeps {figures['anees_uncalibrated']:.2f} -> "
            f"{figures['anees']:.2f}, over all {figures['anees_all_uncalibrated']:.2f} -> {figures['anees_all']:.2f}"
        )
    else:
        mode = f" ({args.mode} mode)" if args.mode else ""
        print(f"{args.model}{mode} on {len(sequences)} validation sequences:")
        print("\n".join(f"  {line}" for line in entry.summary(figures)) if entry.summary else figures)
    return 0


def run_eval(args: argparse.Namespace, entry: ModelEntry) -> int:
    from pvo_core.results import RunResult

    assert entry.evaluate is not None and entry.summary is not None
    figures = entry.evaluate(args.pred, args.gt)
    for line in entry.summary(figures):
        print(line)
    if args.json:
        inputs = {"pred": str(args.pred), "gt": str(args.gt)}
        RunResult("eval", f"{entry.name} {args.pred.name}", figures=figures, inputs=inputs).write(args.json)
    return 0
