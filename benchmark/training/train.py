"""Training regimes of the paper, for one (embedding, regime) at a time.

* ``basic``: from scratch on the simple meshes of the training objects.
* ``ideal``: from scratch on all meshes of the training objects (normally unavailable).
  Every epoch visits each training object once, through a uniformly random one of its
  meshes, so Ideal gets the same number of steps and the same exposure to each object as
  Basic; only the meshings differ.
* ``classification`` / ``autoencoder``: the face embedding (and, for classification, the
  aggregator) is first pretrained on a mesh corpus (``benchmark.training.corpus``: procedural, or
  ShapeNetCore v2), by shape classification or by MeshGPT-style reconstruction of the
  discretized face coordinates; then the whole model is fine-tuned as in ``basic``.

The loss is MSE on the dB target (or the intensity-weighted MSE of ``benchmark.scoring.metrics``),
plus the token embedding's commitment loss. The decoder predicts in units standardized by
the training responses (``Decoder.set_output_statistics``). Training runs to a plateau of
the Simple MSE on the validation split (``plateau``: the learning rate is halved when the
best epoch is ``patience // 2`` epochs old, training stops when it is ``patience`` epochs
old, ``epochs`` is the cap) and the checkpoint is the best epoch (``fit``; without val
objects, all ``epochs`` with a cosine decay, and the last epoch); the test split is never
looked at. Runs are deterministic for a seed and a thread count on one CPU machine (on a GPU
they are not: memory-efficient attention's backward, docs/RESULTS.md). Under
``torchrun`` (``WORLD_SIZE`` > 1, joined by ``benchmark.training.train_cli``) the loss module is
wrapped in DistributedDataParallel and every epoch's objects are sharded with a
DistributedSampler; rank 0's val MSE decides for all ranks; rank 0 writes the checkpoint.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.data import DistributedSampler
from tqdm import tqdm

from benchmark.scoring.data import FLOOR_DB, BasicShapes, BenchmarkData, ScaleBins
from benchmark.training.models import (
    EMBEDDINGS,
    FACE_EMBEDDINGS,
    REGISTRY,
    ClassificationHead,
    MeshSimulator,
    ReconstructionHead,
    build_model,
    collate,
    featurize,
)
from benchmark.training.models.features import MeshFeatures
from benchmark.training.resume import Resume

REGIMES = ("basic", "ideal", "classification", "autoencoder")
PRETRAINED = ("classification", "autoencoder")
LOSSES = ("mse", "intensity")
BUCKET = 8  # batches per length bucket: meshes of similar face count are batched together


BOUNDS = {  # numeric fields of TrainConfig: (minimum, maximum); "above" 0 for rates
    "dim": (1, 4096),
    "embed_layers": (1, 64),
    "agg_layers": (1, 64),
    "n_heads": (1, 256),
    "decoder_hidden": (1, 65536),
    "codebook_size": (2, 65536),
    "n_quantizers": (1, 64),
    "epochs": (1, 100_000),
    "patience": (1, 100_000),
    "batch_size": (1, 65536),
    "lr": ("above", 10.0),
    "weight_decay": (0.0, 10.0),
    "pretrain_meshes": (0, 10_000_000),
    "pretrain_epochs": (0, 100_000),
    "pretrain_max_faces": (4, 10_000_000),
    "pretrain_lr": ("above", 10.0),
    "corpus_seed": (0, 2**63 - 1),
    "seed": (0, 2**63 - 1),
}


def _out_of_bounds(name: str, value) -> str | None:
    low, high = BOUNDS[name]
    if not math.isfinite(value) or value > high or (value <= 0 if low == "above" else value < low):
        return (
            f"{name} must be {'> 0' if low == 'above' else f'>= {low}'} and <= {high}, got {value}"
        )
    return None


@dataclass
class TrainConfig:
    """Everything that determines a training run (stored in the checkpoint)."""

    embedding: str = "graph"
    regime: str = "basic"
    dim: int = 64
    embed_layers: int = 3
    agg_layers: int = 2
    n_heads: int = 4
    decoder_hidden: int = 256
    codebook_size: int = 128
    n_quantizers: int = 2
    epochs: int = 200  # the cap: a run stops earlier at its validation plateau
    patience: int = 10  # epochs without a new best val MSE before stopping (see ``plateau``)
    batch_size: int = 16
    lr: float = 1e-3
    weight_decay: float = 1e-4
    loss: str = "mse"
    pretrain_meshes: int = 1000
    pretrain_epochs: int = 10
    pretrain_max_faces: int = 800
    pretrain_lr: float = 1e-3
    corpus_seed: int = 0
    shapenet: str | None = None
    seed: int = 0

    def __post_init__(self):
        if self.embedding not in EMBEDDINGS:
            raise ValueError(f"unknown embedding {self.embedding!r}; choose one of {EMBEDDINGS}")
        if self.regime not in REGIMES:
            raise ValueError(f"unknown regime {self.regime!r}; choose one of {REGIMES}")
        if self.regime in PRETRAINED and self.embedding not in FACE_EMBEDDINGS:
            raise ValueError(
                f"the {self.embedding} model has no face embedding to pretrain; "
                f"use regime basic or ideal"
            )
        if self.loss not in LOSSES:
            raise ValueError(f"unknown loss {self.loss!r}; choose one of {LOSSES}")
        for name in BOUNDS:
            problem = _out_of_bounds(name, getattr(self, name))
            if problem:
                raise ValueError(problem)
        if self.dim % self.n_heads:
            raise ValueError(f"dim ({self.dim}) must be a multiple of n_heads ({self.n_heads})")

    @property
    def name(self) -> str:
        return f"{self.embedding}-{self.regime}"

    def model_kwargs(self, n_outputs: int, n_scale_bins: int) -> dict:
        return {
            "name": self.embedding,
            "n_outputs": n_outputs,
            "n_scale_bins": n_scale_bins,
            "dim": self.dim,
            "embed_layers": self.embed_layers,
            "agg_layers": self.agg_layers,
            "n_heads": self.n_heads,
            "decoder_hidden": self.decoder_hidden,
            "codebook_size": self.codebook_size,
            "n_quantizers": self.n_quantizers,
        }


# --- examples ---------------------------------------------------------------------------------
@dataclass
class Example:
    """One training mesh, featurized once."""

    features: MeshFeatures
    scale_bin: np.ndarray  # (3,) int64
    target: np.ndarray | None = None  # (n_outputs,) float32 dB
    label: int | None = None  # pretraining class
    scale_m: np.ndarray | None = None  # (3,) float64, the object's extents in metres


class FeatureCache:
    """Featurized meshes by key, so several runs in one process featurize each mesh once."""

    def __init__(self):
        self.items: dict = {}

    def get(self, key, make):
        if key not in self.items:
            self.items[key] = make()
        return self.items[key]


def benchmark_examples(
    data: BenchmarkData,
    regime: str,
    needs: tuple[str, ...],
    scale_bins: ScaleBins,
    cache: FeatureCache | None = None,
    progress: bool = False,
    split: str = "train",
) -> tuple[list[Example], list[np.ndarray]]:
    """Examples of a split for a regime, read through ``BasicShapes`` (the one data path), with
    the optional features ``needs`` (``Embedding.needs``), and their grouping by object (one
    group per object; Ideal groups hold all of an object's meshes, the others only the simple
    one). Validation uses simple meshes."""
    cache = cache or FeatureCache()
    variants = "all" if regime == "ideal" and split == "train" else "simple"
    ds = BasicShapes(data, split, variants, scale_bins)

    def example(i: int) -> Example:
        item = ds[i]
        target = cache.get(
            ("target", data.directory, ds.object_of(i)),  # one copy per object
            lambda: item["target"].numpy().reshape(-1),
        )
        return Example(
            featurize(item["vertices"].numpy(), item["faces"].numpy(), needs),
            item["scale_bins"].numpy(),
            target,
            scale_m=np.asarray(data.objects["scale"][ds.object_of(i)], np.float64),
        )

    examples = [
        cache.get(
            ("mesh", data.directory, int(ds.rows[i]), needs, scale_bins), lambda i=i: example(i)
        )
        for i in tqdm(range(len(ds)), desc=f"features ({split})", unit="mesh", disable=not progress)
    ]
    objects = np.array([ds.object_of(i) for i in range(len(ds))], np.int64)
    starts = np.flatnonzero(np.r_[True, objects[1:] != objects[:-1]]) if len(objects) else []
    groups = np.split(np.arange(len(ds)), starts[1:]) if len(objects) else []
    return examples, groups


def corpus_meshes(cfg: TrainConfig, progress: bool = False) -> tuple[list, list[str]]:
    """The pretraining corpus: ShapeNetCore v2 if configured, else the procedural one."""
    from benchmark.training import corpus

    if cfg.shapenet:
        meshes = corpus.load_shapenet(
            cfg.shapenet,
            max_faces=cfg.pretrain_max_faces,
            limit=cfg.pretrain_meshes or None,
            seed=cfg.corpus_seed,
        )
        return meshes, corpus.shapenet_class_names(cfg.shapenet)
    meshes = corpus.procedural_corpus(
        cfg.pretrain_meshes, cfg.corpus_seed, max_faces=cfg.pretrain_max_faces, progress=progress
    )
    return meshes, list(corpus.FAMILIES)


def corpus_examples(
    meshes: list, cache: FeatureCache | None = None, key: tuple = ()
) -> list[Example]:
    cache = cache or FeatureCache()
    zero = np.zeros(3, np.int64)
    return [
        cache.get(
            ("corpus", *key, i), lambda v=v, f=f, c=c: Example(featurize(v, f), zero, None, c)
        )
        for i, (v, f, c) in enumerate(meshes)
    ]


# --- batching ---------------------------------------------------------------------------------
def epoch_batches(
    examples: list[Example],
    groups: list[np.ndarray],
    batch_size: int,
    epoch: int,
    seed: int,
    rank: int = 0,
    world_size: int = 1,
) -> list[list[int]]:
    """This rank's batches of example indices for one epoch, deterministic in (seed, epoch).

    Objects are shuffled and sharded by a DistributedSampler (one replica when not
    distributed); each object contributes one of its meshes, drawn at random; batches are
    formed within buckets of similar face count and then shuffled.
    """
    sampler = DistributedSampler(
        range(len(groups)),
        num_replicas=world_size,
        rank=rank,
        shuffle=True,
        seed=seed,
        drop_last=False,
    )
    sampler.set_epoch(epoch)
    g = torch.Generator().manual_seed(seed * 100_003 + epoch)
    chosen = []
    for k in sampler:
        members = groups[k]
        pick = int(torch.randint(len(members), (1,), generator=g)) if len(members) > 1 else 0
        chosen.append(int(members[pick]))
    batches = []
    span = batch_size * BUCKET
    for s in range(0, len(chosen), span):
        bucket = sorted(chosen[s : s + span], key=lambda i: examples[i].features.n_faces)
        batches += [bucket[j : j + batch_size] for j in range(0, len(bucket), batch_size)]
    order = torch.randperm(len(batches), generator=g).tolist()
    return [batches[i] for i in order]


def make_batch(examples: list[Example], idx: list[int]):
    items = [examples[i] for i in idx]
    target = None if items[0].target is None else np.stack([it.target for it in items])
    label = None if items[0].label is None else [it.label for it in items]
    scale_m = None if items[0].scale_m is None else np.stack([it.scale_m for it in items])
    return collate(
        [it.features for it in items],
        scale_bin=np.stack([it.scale_bin for it in items]),
        target=target,
        label=label,
        scale_m=scale_m,
    )


# --- tasks (loss modules, what DDP wraps) -----------------------------------------------------
class RegressionTask(nn.Module):
    """The radar regression: MSE (or intensity-weighted MSE) in dB² plus the auxiliary loss."""

    def __init__(self, model: MeshSimulator, loss: str, target_shape: tuple[int, ...]):
        super().__init__()
        self.model, self.loss_name, self.target_shape = model, loss, tuple(target_shape)

    def forward(self, batch) -> tuple[torch.Tensor, dict]:
        pred, aux = self.model(batch)
        if self.loss_name == "intensity":
            from benchmark.scoring.metrics import intensity_weighted_mse

            shape = (len(pred), *self.target_shape)
            loss = intensity_weighted_mse(pred.view(shape), batch.target.view(shape))
        else:
            loss = F.mse_loss(pred, batch.target)
        return loss + aux, {"mse": F.mse_loss(pred.detach(), batch.target).item()}


class PretrainTask(nn.Module):
    def __init__(self, model: MeshSimulator, head: nn.Module):
        super().__init__()
        self.model, self.head = model, head

    def forward(self, batch) -> tuple[torch.Tensor, dict]:
        return self.head.loss(self.model, batch)


@torch.no_grad()
def validation_mse(
    model: MeshSimulator, examples: list[Example], batch_size: int, device: torch.device
) -> float:
    """Mean over validation objects of the MSE (dB²) of the floored prediction on the
    simple mesh: the benchmark's Simple MSE, which model selection may look at. Batched in
    face-count order (little padding), averaged in the examples' order."""
    was_training = model.training
    model.eval()
    order = sorted(range(len(examples)), key=lambda i: examples[i].features.n_faces)
    errors = np.empty(len(examples))
    for s in range(0, len(order), batch_size):
        idx = order[s : s + batch_size]
        batch = make_batch(examples, idx).to(device)
        pred = model(batch)[0].clamp_min(FLOOR_DB)
        errors[idx] = ((pred - batch.target) ** 2).mean(dim=1).cpu().numpy()
    model.train(was_training)
    return float(np.mean(errors))


def plateau(val_mse: list[float], patience: int) -> dict:
    """Where a validation curve stands after its last epoch (a pure function of the curve).

    ``best``: the epoch of the lowest val MSE (the first of ties). ``halvings``: how often
    the learning rate has been halved, once each time the best reached ``patience // 2``
    epochs of age (at least 1), so a stalled run is annealed before it is stopped. ``stop``:
    the best is ``patience`` epochs old (no new best in the last ``patience`` epochs).
    """
    best, halvings, wait = 0, 0, max(1, patience // 2)
    for epoch, value in enumerate(val_mse):
        if value < val_mse[best]:
            best = epoch
        halvings += epoch - best == wait
    return {"best": best, "halvings": halvings, "stop": len(val_mse) - 1 - best >= patience}


def lr_factor(step: int, warm: int, total: int, halvings: int | None) -> float:
    """The learning rate's multiplier at an optimizer step: linear warm-up over ``warm``
    steps, then halved ``halvings`` times (a run selected on val, ``plateau``) or, without
    validation (``halvings`` None: a fixed length), cosine decay to 5% at ``total``."""
    up = min(1.0, (step + 1) / warm)
    if halvings is not None:
        return up * 0.5**halvings
    return up * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(step, total) / total)))


def make_optimizer(task: nn.Module, lr: float, weight_decay: float) -> torch.optim.Optimizer:
    """AdamW, fused: one pass over each parameter instead of one per operation. The decoder's
    output layer (n_outputs x decoder_hidden, nearly all of the parameters) made the
    per-tensor step the most expensive part of a small-mesh training step."""
    return torch.optim.AdamW(task.parameters(), lr=lr, weight_decay=weight_decay, fused=True)


def fit(
    task: nn.Module,
    examples: list[Example],
    groups: list[np.ndarray],
    *,
    epochs: int,
    batch_size: int,
    lr: float,
    weight_decay: float,
    seed: int,
    desc: str,
    device: torch.device,
    progress: bool = True,
    val: list[Example] | None = None,
    patience: int | None = None,
    log=None,
    resume: Resume | None = None,
    phase: str = "train",
) -> list[dict]:
    """AdamW with linear warm-up, gradient clipping at 1; returns the mean loss and
    statistics of every epoch, and its learning rate.

    With ``val`` examples (a regression task), every epoch's model is scored on them
    (``val_mse``), the learning rate is halved and training stopped by ``plateau`` with
    ``patience`` (``epochs`` is the cap), and the weights of the best epoch are kept: the
    checkpoint is selected on the validation split, never on test, and its record is marked
    ``selected``. Without, all ``epochs`` run with a cosine decay and the last is kept.
    ``log`` (a callable taking one line) reports each finished epoch where no progress bar
    can be shown (pool workers of ``benchmark reproduce``). With ``resume``, the run continues
    from the state its ``phase`` was saved in and keeps saving it (``resume.Resume``)."""
    distributed = torch.distributed.is_available() and torch.distributed.is_initialized()
    rank = torch.distributed.get_rank() if distributed else 0
    world = torch.distributed.get_world_size() if distributed else 1
    if val and patience is None:
        raise ValueError("fit with val examples needs a patience")
    task.to(device).train()
    runner = task
    if distributed:
        runner = nn.parallel.DistributedDataParallel(
            task,
            device_ids=[device.index] if device.type == "cuda" else None,
            find_unused_parameters=isinstance(task, PretrainTask),
        )
    opt = make_optimizer(task, lr, weight_decay)
    steps_per_epoch = len(epoch_batches(examples, groups, batch_size, 0, seed, rank, world))
    total = max(1, epochs * steps_per_epoch)
    warm = max(1, min(total // 20, steps_per_epoch))
    resume = resume or Resume(None)
    start, step, history, best = resume.restore(phase, task, opt)
    halvings, stop = (0 if val else None), False
    if val and history:
        state = plateau([r["val_mse"] for r in history], patience)
        halvings, stop = state["halvings"], state["stop"]
    bar = tqdm(
        range(start, start if stop else epochs),
        initial=start,
        total=epochs,
        desc=desc,
        unit="epoch",
        disable=not progress or rank != 0,
    )
    t0 = time.perf_counter()
    for epoch in bar:
        sums: dict[str, float] = {}
        batches = epoch_batches(examples, groups, batch_size, epoch, seed, rank, world)
        for idx in batches:
            batch = make_batch(examples, idx).to(device)
            loss, stats = runner(batch)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            nn.utils.clip_grad_norm_(task.parameters(), 1.0)
            for group in opt.param_groups:
                group["lr"] = lr * lr_factor(step, warm, total, halvings)
            opt.step()
            step += 1
            for k, v in {"loss": loss.item(), **stats}.items():
                sums[k] = sums.get(k, 0.0) + v
        record = {k: v / max(len(batches), 1) for k, v in sums.items()}
        record["lr"] = opt.param_groups[0]["lr"]
        if val:
            record["val_mse"] = _same_on_every_rank(
                validation_mse(task.model, val, batch_size, device), device, distributed
            )
            if best is None or record["val_mse"] < best[0]:
                best = (
                    record["val_mse"],
                    epoch,
                    {k: v.detach().clone() for k, v in task.state_dict().items()},
                )
        history.append(record)
        bar.set_postfix({k: f"{v:.3g}" for k, v in record.items()})
        if log is not None and rank == 0:  # pooled workers: lines, as bars would collide
            log(
                f"{desc}: epoch {epoch + 1}/{epochs}, {time.perf_counter() - t0:.0f} s, "
                + ", ".join(f"{k} {v:.3g}" for k, v in record.items())
            )
        if val:
            state = plateau([r["val_mse"] for r in history], patience)
            halvings, stop = state["halvings"], state["stop"]
        if rank == 0:
            last = stop or epoch + 1 == epochs
            resume.save(phase, epoch + 1, step, history, best, task, opt, last)
        if stop:
            break
    if best is not None:
        task.load_state_dict(best[2])
        history[best[1]]["selected"] = True
    task.eval()
    return history


def _same_on_every_rank(value: float, device: torch.device, distributed: bool) -> float:
    """Rank 0's value on every rank, so that all ranks stop at the same epoch."""
    if not distributed:
        return value
    t = torch.tensor([value], dtype=torch.float64, device=device)
    torch.distributed.broadcast(t, src=0)
    return float(t.item())


def selection(history: list[dict], patience: int) -> dict:
    """Which epoch the checkpoint holds, on what it was chosen, and how training ended:
    ``epochs_to_plateau`` (epochs up to the best one) and ``capped`` (the cap, not the
    plateau, ended the run: its best epoch is within the last ``patience``, so it was still
    improving)."""
    chosen = [k for k, r in enumerate(history) if r.get("selected")]
    if chosen:
        k = chosen[0]
        return {
            "on": "val",
            "epoch": k,
            "val_mse": history[k]["val_mse"],
            "epochs_trained": len(history),
            "epochs_to_plateau": k + 1,
            "patience": patience,
            "capped": len(history) - 1 - k < patience,
        }
    return {
        "on": "last epoch (no val split)",
        "epoch": len(history) - 1,
        "val_mse": None,
        "epochs_trained": len(history),
        "epochs_to_plateau": None,
        "patience": None,
        "capped": None,
    }


# --- one run ----------------------------------------------------------------------------------
def seed_everything(seed: int) -> None:
    torch.manual_seed(seed)
    torch.use_deterministic_algorithms(True, warn_only=True)


def train(
    cfg: TrainConfig,
    data: BenchmarkData,
    *,
    scale_bins: ScaleBins = ScaleBins(),
    cache: FeatureCache | None = None,
    corpus: tuple[list, list[str]] | None = None,
    device: str | torch.device = "cpu",
    progress: bool = True,
    log=None,
    resume: str | os.PathLike | None = None,
) -> tuple[MeshSimulator, dict]:
    """Train one (embedding, regime); return the model (eval mode) and its checkpoint config.

    ``corpus`` = (meshes, class names) overrides the configured pretraining corpus (lets
    several runs share one); ``cache`` shares featurized meshes between runs. ``resume``: a
    state file that lets a killed run continue between epochs (``resume.Resume``; the caller
    deletes it once the checkpoint is saved).
    """
    device = torch.device(device)
    cache = cache or FeatureCache()
    identity = {
        "dataset_fingerprint": data.fingerprint,  # both verified against the
        "label_fingerprint": data.label_fingerprint,
    }  # content before any training
    seed_everything(cfg.seed)
    n_outputs = int(np.prod(data.target_shape))
    kwargs = cfg.model_kwargs(n_outputs, scale_bins.n)
    model = build_model(**kwargs)
    history: dict[str, list] = {}
    key = {**identity, "train": asdict(cfg), "torch": [torch.__version__, torch.get_num_threads()]}
    state = Resume(resume, key)
    if cfg.regime in PRETRAINED and "pretrain" in state.finished:
        history["pretrain"] = state.finished["pretrain"]  # its weights are in the train state
    elif cfg.regime in PRETRAINED:
        meshes, names = corpus if corpus is not None else corpus_meshes(cfg, progress)
        key = (cfg.shapenet, cfg.pretrain_meshes, cfg.corpus_seed, cfg.pretrain_max_faces)
        examples = corpus_examples(meshes, cache, key)
        head = (
            ClassificationHead(cfg.dim, len(names))
            if cfg.regime == "classification"
            else ReconstructionHead(cfg.dim)
        )
        groups = [np.array([i]) for i in range(len(examples))]
        history["pretrain"] = fit(
            PretrainTask(model, head),
            examples,
            groups,
            epochs=cfg.pretrain_epochs,
            batch_size=cfg.batch_size,
            lr=cfg.pretrain_lr,
            weight_decay=cfg.weight_decay,
            seed=cfg.seed + 1,
            desc=f"{cfg.name}/seed-{cfg.seed} pretrain",
            device=device,
            progress=progress,
            log=log,
            resume=state,
            phase="pretrain",
        )
        state.finished["pretrain"] = history["pretrain"]
    examples, groups = benchmark_examples(
        data, cfg.regime, REGISTRY[cfg.embedding].needs, scale_bins, cache, progress
    )
    val, _ = benchmark_examples(
        data, cfg.regime, REGISTRY[cfg.embedding].needs, scale_bins, cache, progress, split="val"
    )
    model.decoder.set_output_statistics(
        torch.from_numpy(np.stack([examples[g[0]].target for g in groups]))
    )
    task = RegressionTask(model, cfg.loss, data.target_shape)
    history["train"] = fit(
        task,
        examples,
        groups,
        epochs=cfg.epochs,
        batch_size=cfg.batch_size,
        lr=cfg.lr,
        weight_decay=cfg.weight_decay,
        seed=cfg.seed,
        desc=f"{cfg.name}/seed-{cfg.seed}",
        device=device,
        progress=progress,
        val=val,
        patience=cfg.patience,
        log=log,
        resume=state,
    )
    model.to("cpu").eval()
    config = {
        "name": cfg.name,
        "embedding": cfg.embedding,
        "regime": cfg.regime,
        "model": kwargs,
        "target_shape": list(data.target_shape),
        "scale_bins": {"lo": scale_bins.lo, "hi": scale_bins.hi, "n": scale_bins.n},
        "train": asdict(cfg),
        "history": history,
        "selection": selection(history["train"], cfg.patience),
        "train_seconds": state.seconds(),
        **identity,
    }
    return model, config


# --- evaluation -----------------------------------------------------------------------------
def evaluate_checkpoint(
    checkpoint: str | os.PathLike,
    data_dir: str | os.PathLike,
    results: str | os.PathLike | None = None,
    progress: bool = True,
    device: str | torch.device = "cpu",
    predictions: str | os.PathLike | None = None,
) -> dict:
    """Results record of a checkpoint on the test split (harness ``evaluate``); the
    predictions file is kept at ``predictions`` when given (a leaderboard submission)."""
    from benchmark.scoring.evaluate import evaluate
    from benchmark.scoring.protocol import write_results
    from benchmark.training.models.checkpoint import CheckpointModel, training_record

    model = CheckpointModel(checkpoint, device=str(device))
    if predictions:
        Path(predictions).parent.mkdir(parents=True, exist_ok=True)
    record = evaluate(
        data_dir,
        model=model,
        train_seed=model.config["train"]["seed"],
        progress=progress,
        write_predictions=predictions,
    )
    training = training_record([model.config])
    if training:
        record["training"] = training
    if results:
        Path(results).parent.mkdir(parents=True, exist_ok=True)
        write_results(results, record)
    return record
