"""HydraNet's one-dimensional study (thesis §7.4.2, Figs. 7.4 and 7.5): HydraNet, direct variance regression, MC
dropout, bagging and HydraNet without its aleatoric head, each trained ``--repetitions`` times on eq. 7.7's
data; a box plot of the test NLL (all, inside and outside the training ranges) and each method's ±sigma bands."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .common import ExperimentRun

TITLE = "HydraNet 1-D (ch. 7, Figs. 7.4-7.5): test NLL of five uncertainty estimators in and out of distribution"


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--repetitions", type=int, default=20, help="trainings per method (default 20)")
    parser.add_argument("--steps", type=int, default=1500, help="Adam steps per training (default 1500)")
    parser.add_argument("--heads", type=int, default=25, help="HydraNet heads (default 25)")
    parser.add_argument("--bags", type=int, default=10, help="bagged networks (default 10)")
    parser.add_argument("--noise-sigma", type=float, default=0.03, help="sigma of w in eq. 7.7 (default 0.03)")
    parser.add_argument("--seed", type=int, default=0, help="seed of data and initialisations")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (default 2)")
    parser.add_argument("--out", "-o", type=Path, default=Path("runs/hydranet-1d"), help="output directory")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress lines")


def run(args: argparse.Namespace) -> int:
    import torch
    from pvo_core.results import RunResult
    from pvo_pseudosensors.hydranet.oned import METHODS, TRAIN_RANGES, OneDConfig, one_d_study

    from ..plots import pyplot

    if args.repetitions < 1:
        raise ValueError(f"--repetitions must be >= 1, got {args.repetitions}")
    torch.set_num_threads(args.threads)
    session = ExperimentRun.start(args)
    config = OneDConfig(steps=args.steps, heads=args.heads, bags=args.bags, noise_sigma=args.noise_sigma)
    result = one_d_study(config, args.repetitions, args.seed, say=session.say)

    def median(values: list[float]) -> float:
        ordered = sorted(values)
        mid = len(ordered) // 2
        return ordered[mid] if len(ordered) % 2 else 0.5 * (ordered[mid - 1] + ordered[mid])

    figures: dict[str, float] = {}
    rows = []
    for method in METHODS:
        for part, values in (("all", result.nll[method]), ("in", result.nll_in[method]), ("out", result.nll_out[method])):
            figures[f"{method}.nll_{part}_median"] = median(values)
        rows.append(
            f"| {method} | {figures[f'{method}.nll_all_median']:.2f} | {figures[f'{method}.nll_in_median']:.2f} | "
            f"{figures[f'{method}.nll_out_median']:.2f} |"
        )
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, (label, table) in zip(
        axes, (("inside the training ranges", result.nll_in), ("outside", result.nll_out)), strict=True
    ):
        ax.boxplot([table[m] for m in METHODS], showfliers=False)
        ax.set_xticks(range(1, len(METHODS) + 1), [m.replace("_", "\n") for m in METHODS], fontsize=8)
        ax.set_yscale("symlog")
        ax.set_ylabel("test NLL")
        ax.set_title(f"{label}, {args.repetitions} trainings each (Fig. 7.5)")
    fig.tight_layout()
    fig.savefig(session.out / "nll_boxplot.png", dpi=110)
    fig, axes = plt.subplots(1, len(METHODS), figsize=(4 * len(METHODS), 3.5), sharey=True)
    x_train, y_train, x_test, y_test = result.data  # type: ignore[misc]
    for ax, method in zip(axes, METHODS, strict=True):
        mean, variance = result.bands[method]
        sigma = variance**0.5
        for k, alpha in ((3, 0.15), (2, 0.25), (1, 0.35)):
            ax.fill_between(result.grid, mean - k * sigma, mean + k * sigma, color="tab:blue", alpha=alpha, lw=0)
        ax.plot(result.grid, mean, "b-", lw=1)
        ax.plot(x_train, y_train, "k.", ms=1)
        ax.plot(x_test, y_test, "r.", ms=3)
        for a, b in TRAIN_RANGES:
            ax.axvspan(a, b, color="0.9", zorder=0)
        ax.set_ylim(-6, 6)
        ax.set_title(method)
    fig.tight_layout()
    fig.savefig(session.out / "bands.png", dpi=110)
    report = [
        "# pvo experiment hydranet-1d",
        "",
        f"Command: `{session.command}`",
        "",
        f"Eq. 7.7 with w ~ N(0, {args.noise_sigma}²); {config.train_samples} training samples in "
        f"[0, 0.6] ∪ [0.8, 1], {config.test_samples} test samples in [-2, 2]; {args.repetitions} trainings per "
        f"method ({args.steps} Adam steps, full batch); HydraNet {args.heads} heads, bagging {args.bags} networks, "
        f"MC dropout p = {config.dropout} with {config.samples} passes. Median test NLL over the trainings:",
        "",
        "| method | all | inside the training ranges | outside |",
        "|---|---|---|---|",
        *rows,
        "",
        "![NLL](nll_boxplot.png)",
        "",
        "![bands](bands.png)",
        "",
        f"Wall time {session.seconds:.0f} s.",
    ]
    (session.out / "report.md").write_text("\n".join(report) + "\n")
    tables: dict[str, Any] = {"nll": result.nll, "nll_in": result.nll_in, "nll_out": result.nll_out}
    RunResult("experiment", "hydranet-1d", figures=figures, tables=tables, inputs={"seed": str(args.seed)}).write(session.out)
    print("\n".join(report))
    print(f"wrote {session.out}/report.md, nll_boxplot.png, bands.png and metrics.json")
    return 0
