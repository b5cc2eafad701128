"""``benchmark train``: its options (one per ``TrainConfig`` field), the torchrun process
group, and the run (train, save the checkpoint, optionally evaluate); the training itself is
``benchmark.training.train``, which ``benchmark reproduce`` calls in-process.
"""

from __future__ import annotations

import argparse
import os
from dataclasses import fields
from pathlib import Path

import torch

from basic_shapes.infra import FlagError, add_quiet_flag, number, separate_outputs
from benchmark.scoring.data import BenchmarkData
from benchmark.training import resume
from benchmark.training.models import EMBEDDINGS
from benchmark.training.train import (
    BOUNDS,
    LOSSES,
    REGIMES,
    TrainConfig,
    evaluate_checkpoint,
    train,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``benchmark train``: one per ``TrainConfig`` field, plus I/O."""
    parser.add_argument("--data", required=True, help="directory of labelled shards")
    parser.add_argument(
        "--out",
        required=True,
        help="checkpoint directory to write (model.pt + config.json); while training it holds "
        "resume.pt, from which the same command continues a killed run",
    )
    parser.add_argument(
        "--results", help="also evaluate on the test split and write this results JSON"
    )
    parser.add_argument(
        "--device", default=None, help="torch device (default: cuda if available, else cpu)"
    )
    add_quiet_flag(parser)
    defaults = TrainConfig()
    choices = {"embedding": EMBEDDINGS, "regime": REGIMES, "loss": LOSSES}
    helps = {
        "embedding": "face embedding, or the topology-invariant model",
        "regime": "basic (simple meshes), ideal (all meshes), or pretraining by "
        "classification / autoencoder then fine-tuning on simple meshes",
        "loss": "mse, or intensity (intensity-weighted MSE + MSE)",
        "shapenet": "pretrain on a local ShapeNetCore v2 directory, not the procedural corpus",
        "pretrain_meshes": "corpus size (procedural), or a cap on ShapeNet models (0: all)",
        "epochs": "the cap on training epochs; a run with val objects stops at its plateau",
        "patience": "stop when the best val MSE is this many epochs old (the learning rate "
        "is halved at half of it)",
        "dim": "width of the face embedding and the aggregator",
        "embed_layers": "layers of the face embedding",
        "agg_layers": "transformer layers of the aggregator over the faces",
        "n_heads": "attention heads of the aggregator (dim must be a multiple)",
        "decoder_hidden": "hidden width of the decoder to the range profiles",
        "codebook_size": "token embedding: vectors per residual-quantizer codebook",
        "n_quantizers": "token embedding: residual quantizers (codebooks) per face",
        "batch_size": "meshes per batch",
        "lr": "learning rate (AdamW)",
        "weight_decay": "AdamW weight decay",
        "pretrain_epochs": "epochs of pretraining (regimes classification, autoencoder)",
        "pretrain_max_faces": "pretraining meshes are decimated to at most this many faces",
        "pretrain_lr": "learning rate of pretraining",
        "corpus_seed": "seed of the procedural pretraining corpus",
        "seed": "seed of initialisation and batch order",
    }
    for f in fields(TrainConfig):
        default = getattr(defaults, f.name)
        kind = str if f.name == "shapenet" else type(default)
        if f.name in BOUNDS:  # refused by the parser (exit 2), before any data is read
            low, high = BOUNDS[f.name]
            kind = number(
                kind, maximum=high, **({"above": 0} if low == "above" else {"minimum": low})
            )
        parser.add_argument(
            "--" + f.name.replace("_", "-"),
            type=kind,
            default=default,
            choices=choices.get(f.name),
            help=helps.get(f.name, "") + f" (default: {default})",
        )


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    try:
        return TrainConfig(**{f.name: getattr(args, f.name) for f in fields(TrainConfig)})
    except ValueError as exc:
        raise SystemExit(f"benchmark train: {exc}") from None


def check_device(text: str) -> torch.device:
    """``--device`` parsed and present on this machine (``FlagError``: exit 2, before work)."""
    try:
        device = torch.device(text)
    except RuntimeError:
        raise FlagError(f"--device {text!r} is not a torch device (cpu, cuda, cuda:0)") from None
    if device.type == "cuda" and (
        not torch.cuda.is_available() or (device.index or 0) >= torch.cuda.device_count()
    ):
        raise FlagError(
            f"--device {text}: no such CUDA device here ({torch.cuda.device_count()} available)"
        )
    if device.type not in ("cpu", "cuda"):
        raise FlagError(f"--device {text}: only cpu and cuda devices are supported")
    return device


def init_distributed() -> tuple[torch.device, int]:
    """Join the torchrun process group when launched by it; returns (device, rank)."""
    if int(os.environ.get("WORLD_SIZE", "1")) <= 1:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu"), 0
    backend = "nccl" if torch.cuda.is_available() else "gloo"
    torch.distributed.init_process_group(backend)
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if torch.cuda.is_available():
        torch.cuda.set_device(local)
        return torch.device("cuda", local), torch.distributed.get_rank()
    return torch.device("cpu"), torch.distributed.get_rank()


def run(args: argparse.Namespace) -> None:
    """``benchmark train``: train, save the checkpoint, optionally evaluate."""
    from basic_shapes.shards import ShardError
    from benchmark.training.models.checkpoint import save_checkpoint

    separate_outputs({"--out": args.out, "--results": args.results}, {"--data": args.data})
    cfg = config_from_args(args)
    device, rank = init_distributed()
    if args.device:
        device = check_device(args.device)
    try:
        with BenchmarkData(args.data) as data:
            model, config = train(
                cfg,
                data,
                device=device,
                progress=not args.quiet,
                resume=Path(args.out, resume.FILE),
            )
    except ShardError as exc:
        raise SystemExit(f"benchmark train: {exc}") from None
    if rank == 0:
        save_checkpoint(args.out, model, config)
        Path(args.out, resume.FILE).unlink(missing_ok=True)
        print(
            f"{cfg.name}: checkpoint in {args.out} "
            f"({config['train_seconds']:.1f} s, final train loss "
            f"{config['history']['train'][-1]['loss']:.3f})"
        )
        if args.results:
            from benchmark.scoring.evaluate import format_metrics

            record = evaluate_checkpoint(args.out, args.data, args.results, not args.quiet, device)
            print(format_metrics(record))
            print(f"results in {args.results}")
    if torch.distributed.is_initialized():
        torch.distributed.destroy_process_group()
