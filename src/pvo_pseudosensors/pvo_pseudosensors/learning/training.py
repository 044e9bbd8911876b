"""The one training loop every learned pseudo-sensor uses.

A model plugs in as a :class:`Task`: its architecture name, a network, a loss and its model card. The
loop is seeded and deterministic (the same command gives the same weights; ``--resume`` continues to the
same weights an uninterrupted run reaches: the shuffle of epoch e is drawn from (seed, e) and the RNG
state is checkpointed), sets torch's thread count, validates every epoch, keeps the best-on-validation
model (``weights.safetensors`` + ``model.yaml``), stops early after ``patience`` epochs without
improvement, follows a learning-rate schedule and writes ``history.csv`` and ``loss.png``.

Distributed data parallel comes from PyTorch alone: run the same command under ``torchrun
--nproc-per-node N``; the loop then joins the process group torchrun describes (gloo on CPU, NCCL on
GPUs), wraps the network in ``DistributedDataParallel`` and gives each process its share of every batch
through ``DistributedSampler`` (the batch size is the global one). A single process uses the same sampler
with one replica, so one process and N processes see the same batches in the same order.
"""

from __future__ import annotations

import csv
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

import torch
from torch.utils.data import DataLoader, Dataset
from torch.utils.data.distributed import DistributedSampler

from .checkpoint import ModelCard, current_commit, save_model

STATE = "checkpoint.pt"
SCHEDULES = ("cosine", "step", "constant")


@dataclass(frozen=True)
class TrainConfig:
    """epochs: at most this many; batch_size: global (split over processes); schedule: cosine (to 1 % of the
    rate), step (times ``step_gamma`` every ``step_size`` epochs) or constant; patience: stop after this many
    epochs without a better validation loss (0: never); threads: torch threads per process."""

    epochs: int = 30
    batch_size: int = 32
    learning_rate: float = 1e-3
    weight_decay: float = 1e-4
    schedule: str = "cosine"
    step_size: int = 10
    step_gamma: float = 0.5
    patience: int = 8
    seed: int = 0
    threads: int = 2

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.batch_size < 1:
            raise ValueError(f"epochs and batch_size must be >= 1, got {self.epochs} and {self.batch_size}")
        if not self.learning_rate > 0 or self.weight_decay < 0:
            raise ValueError("the learning rate must be positive and the weight decay >= 0")
        if self.schedule not in SCHEDULES:
            raise ValueError(f"unknown schedule {self.schedule!r}: choose one of {', '.join(SCHEDULES)}")
        if self.patience < 0 or self.threads < 1:
            raise ValueError("patience must be >= 0 and threads >= 1")


class Task(Protocol):
    """What a model brings to the loop."""

    architecture: str

    def build(self) -> torch.nn.Module: ...

    def loss(self, model: torch.nn.Module, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """The mean loss over the batch (a scalar tensor)."""
        ...

    def card(self) -> ModelCard:
        """The model card without the training figures (architecture, hyper-parameters, input)."""
        ...


@dataclass
class TrainResult:
    out: Path
    best_epoch: int
    best_validation: float
    epochs_run: int
    stopped_early: bool
    history: list[dict[str, float]] = field(default_factory=list)
    seconds: float = 0.0


@dataclass(frozen=True)
class Processes:
    """This process's place among the ones torchrun started (rank 0 of 1 without torchrun)."""

    rank: int
    world: int
    device: torch.device

    @property
    def main(self) -> bool:
        return self.rank == 0


def join_processes() -> Processes:
    """Join the process group torchrun set up in the environment (WORLD_SIZE, RANK, MASTER_ADDR, ...)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return Processes(0, 1, torch.device("cpu"))
    import torch.distributed as dist

    cuda = torch.cuda.is_available()
    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if cuda else "gloo")
    local = int(os.environ.get("LOCAL_RANK", "0"))
    device = torch.device(f"cuda:{local}") if cuda else torch.device("cpu")
    if cuda:
        torch.cuda.set_device(device)
    return Processes(dist.get_rank(), dist.get_world_size(), device)


def _schedule(optimizer: torch.optim.Optimizer, config: TrainConfig) -> torch.optim.lr_scheduler.LRScheduler:
    if config.schedule == "cosine":
        return torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=config.epochs, eta_min=0.01 * config.learning_rate)
    if config.schedule == "step":
        return torch.optim.lr_scheduler.StepLR(optimizer, step_size=config.step_size, gamma=config.step_gamma)
    return torch.optim.lr_scheduler.LambdaLR(optimizer, lambda _: 1.0)


def _to(batch: dict[str, torch.Tensor], device: torch.device) -> dict[str, torch.Tensor]:
    return {k: v.to(device) for k, v in batch.items()}


def _average(value: float, processes: Processes) -> float:
    if processes.world == 1:
        return value
    import torch.distributed as dist

    tensor = torch.tensor([value], dtype=torch.float64, device=processes.device)
    dist.all_reduce(tensor)
    return float(tensor.item()) / processes.world


def evaluate(task: Task, model: torch.nn.Module, data: Dataset, batch_size: int, device: torch.device) -> float:
    """The mean loss over ``data`` (weighted by batch size), without gradients, in eval mode."""
    loader = DataLoader(data, batch_size=batch_size, shuffle=False)
    model.eval()
    total, count = 0.0, 0
    with torch.no_grad():
        for batch in loader:
            n = len(next(iter(batch.values())))
            total += float(task.loss(model, _to(batch, device))) * n
            count += n
    return total / max(count, 1)


def fit(
    task: Task,
    train: Dataset,
    validation: Dataset,
    config: TrainConfig,
    out: Path,
    resume: bool = False,
    progress: Callable[[int, int], None] | None = None,
    say: Callable[[str], None] = print,
    card_extra: dict[str, Any] | None = None,
) -> TrainResult:
    """Train ``task`` on ``train``, selecting on ``validation``; everything is written under ``out``.

    progress(step, steps_per_epoch) after every training step of this process. card_extra: fields for the
    model card (corpus, commands, notes)."""
    out = Path(out)
    processes = join_processes()
    if not processes.main:  # one voice: the other processes of a torchrun stay quiet
        say = _silent
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    torch.use_deterministic_algorithms(True)
    if config.batch_size % processes.world:
        raise ValueError(f"batch size {config.batch_size} does not split over {processes.world} processes")
    model = task.build().to(processes.device)
    optimizer = torch.optim.AdamW(
        [p for p in model.parameters() if p.requires_grad], lr=config.learning_rate, weight_decay=config.weight_decay
    )
    scheduler = _schedule(optimizer, config)
    history: list[dict[str, float]] = []
    best, best_epoch, waited, start_epoch = math.inf, -1, 0, 0
    state_file = out / STATE
    if resume and state_file.is_file():
        state = torch.load(state_file, map_location=processes.device, weights_only=False)
        if state["config"] != asdict(config):
            raise ValueError(f"{state_file}: made with other training settings; resume with the same ones or start afresh")
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        scheduler.load_state_dict(state["scheduler"])
        torch.set_rng_state(state["rng"])
        history, best, best_epoch, waited = state["history"], state["best"], state["best_epoch"], state["waited"]
        start_epoch = state["epoch"] + 1
        say(
            f"resuming after epoch {state['epoch'] + 1} of {config.epochs} (best validation {best:.5g} at epoch {best_epoch + 1})"
        )
    elif resume:
        say(f"{state_file} not found: starting afresh")
    trained = model
    if processes.world > 1:
        trained = torch.nn.parallel.DistributedDataParallel(model)
    sampler = DistributedSampler(train, num_replicas=processes.world, rank=processes.rank, shuffle=True, seed=config.seed)
    loader = DataLoader(train, batch_size=config.batch_size // processes.world, sampler=sampler)
    card = task.card()
    for key, value in (card_extra or {}).items():
        setattr(card, key, value)
    stopped = False
    started = time.perf_counter()
    epoch = start_epoch - 1
    for epoch in range(start_epoch, config.epochs):
        if config.patience and waited >= config.patience:
            stopped = True
            break
        tic = time.perf_counter()
        sampler.set_epoch(epoch)
        trained.train()
        total, count = 0.0, 0
        for step, batch in enumerate(loader, start=1):
            optimizer.zero_grad(set_to_none=True)
            loss = task.loss(trained, _to(batch, processes.device))
            if not torch.isfinite(loss):
                raise FloatingPointError(f"epoch {epoch + 1}, step {step}: the loss is {float(loss)}; lower the learning rate")
            loss.backward()
            optimizer.step()
            n = len(next(iter(batch.values())))
            total, count = total + float(loss.detach()) * n, count + n
            if progress:
                progress(step, len(loader))
        learning_rate = optimizer.param_groups[0]["lr"]
        scheduler.step()
        train_loss = _average(total / max(count, 1), processes)
        validation_loss = evaluate(task, model, validation, config.batch_size, processes.device)
        row = {
            "epoch": epoch + 1,
            "train_loss": train_loss,
            "validation_loss": validation_loss,
            "learning_rate": learning_rate,
            "seconds": time.perf_counter() - tic,
        }
        history.append(row)
        improved = validation_loss < best
        if improved:
            best, best_epoch, waited = validation_loss, epoch, 0
        else:
            waited += 1
        if processes.main:
            if improved:
                card.validation = {"loss": validation_loss}
                card.training = {
                    "best_epoch": epoch + 1,
                    "epochs": config.epochs,
                    "processes": processes.world,
                    "threads": config.threads,
                    "config": asdict(config),
                    "train_samples": len(train),
                    "validation_samples": len(validation),
                    "seconds_to_best": round(sum(r["seconds"] for r in history), 1),
                }
                card.commit = card.commit or current_commit()
                save_model(out, model, card)
            _write_history(out, history)
            torch.save(
                {
                    "epoch": epoch,
                    "config": asdict(config),
                    "model": model.state_dict(),
                    "optimizer": optimizer.state_dict(),
                    "scheduler": scheduler.state_dict(),
                    "rng": torch.get_rng_state(),
                    "history": history,
                    "best": best,
                    "best_epoch": best_epoch,
                    "waited": waited,
                },
                out / f".{STATE}.tmp",
            )
            (out / f".{STATE}.tmp").replace(state_file)
        say(
            f"epoch {epoch + 1}/{config.epochs}: train {train_loss:.5g}, validation {validation_loss:.5g}"
            f"{' (best)' if improved else ''}, lr {learning_rate:.3g}, {row['seconds']:.1f} s"
        )
    if processes.main and history:
        _plot(out, history)
    if processes.world > 1:
        # leave together: a process that exits while another still holds the group's connections can abort
        import torch.distributed as dist

        dist.barrier()
        dist.destroy_process_group()
    return TrainResult(out, best_epoch + 1, best, len(history), stopped, history, seconds=time.perf_counter() - started)


def _silent(_: str) -> None:
    pass


def _write_history(out: Path, history: list[dict[str, float]]) -> None:
    with (out / "history.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(history[0]))
        writer.writeheader()
        writer.writerows(history)


def _plot(out: Path, history: list[dict[str, float]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = [row["epoch"] for row in history]
    figure, axis = plt.subplots(figsize=(6, 3.5))
    axis.plot(epochs, [row["train_loss"] for row in history], label="training")
    axis.plot(epochs, [row["validation_loss"] for row in history], label="validation")
    best = min(history, key=lambda row: row["validation_loss"])
    axis.axvline(best["epoch"], color="grey", linestyle=":", label=f"best (epoch {best['epoch']})")
    axis.set_xlabel("epoch")
    axis.set_ylabel("loss")
    axis.legend()
    figure.tight_layout()
    figure.savefig(out / "loss.png", dpi=100)
    plt.close(figure)


@dataclass
class FineTune:
    """``task`` with its network starting from the trained weights of ``initial`` (a model directory of the
    same architecture and settings; :class:`~.checkpoint.ModelFileError` when it does not fit). The card
    records where it started.

    ``trainable`` limits what the fine-tune changes: parameter-name prefixes (``"features.0."``) and the word
    ``"norm"`` (the affine parameters of every normalisation layer); every other parameter keeps its starting
    value (``requires_grad`` off, so the optimiser skips it). Empty: everything trains. Normalisation layers
    outside it still re-estimate their running statistics in training mode."""

    task: Any
    initial: Path
    trainable: tuple[str, ...] = ()

    @property
    def architecture(self) -> str:
        return self.task.architecture

    def build(self) -> torch.nn.Module:
        from .checkpoint import load_model

        model, _ = load_model(Path(self.initial), self.task.architecture, lambda _card: self.task.build())
        model.train()
        if self.trainable:
            chosen = trainable_parameters(model, self.trainable)
            for name, parameter in model.named_parameters():
                parameter.requires_grad_(name in chosen)
        return model

    def loss(self, model: torch.nn.Module, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.task.loss(model, batch)

    def card(self) -> ModelCard:
        card = self.task.card()
        trained = f" (trained: {', '.join(self.trainable)}; the rest kept)" if self.trainable else ""
        card.notes = (card.notes + " " if card.notes else "") + f"fine-tuned from {self.initial}{trained}"
        return card


def trainable_parameters(model: torch.nn.Module, selection: Sequence[str]) -> set[str]:
    """Names of ``model``'s parameters that ``selection`` picks (prefixes of parameter names, and ``"norm"``:
    the affine parameters of batch, group, instance and layer normalisation). ValueError when an entry picks
    nothing, naming it and what there is."""
    norm_types = (torch.nn.modules.batchnorm._NormBase, torch.nn.GroupNorm, torch.nn.LayerNorm)
    names = [name for name, _ in model.named_parameters()]
    chosen: set[str] = set()
    for entry in selection:
        if entry == "norm":
            picked = {
                f"{module_name}.{name}" if module_name else name
                for module_name, module in model.named_modules()
                if isinstance(module, norm_types)
                for name, _ in module.named_parameters(recurse=False)
            }
        else:
            picked = {name for name in names if name.startswith(entry)}
        if not picked:
            tops = sorted({name.split(".")[0] for name in names})
            parts = ", ".join(tops)
            raise ValueError(f"trainable entry {entry!r} picks no parameter of this network (its parts: {parts}; or 'norm')")
        chosen |= picked
    return chosen
