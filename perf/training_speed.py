"""Where a training step's time goes, and what the faster training path saves (old vs new).

    python perf/training_speed.py [--data DIR] [--train-objects N] [--val-objects M]
        [--epochs 4] [--rows direct-basic,...] [--seeds 0,1]

Without --data, the test fixture's dataset is written to a temporary directory
(``tests/benchmark_fixture.make_dataset``, cpu-v1's radar grid 31 x 7 x 107, so the decoder's
output layer is the table's: 256 x 23,219); its meshes have at most 320 faces. With --data
(e.g. cpu-v1), ``--train-objects`` / ``--val-objects`` draw a seeded subset of the objects,
so an epoch has the table's batches on fewer of them (its cost scales with the objects).

Every row runs with the cpu preset's model, batch and one torch thread (as ``benchmark
reproduce`` runs each job), all in this process:

* breakdown: steps of epoch 0 timed part by part (batch building, the embedding, the
  aggregator, the decoder with the loss, each forward + backward; gradient clipping; the
  optimizer step), for the old step and the new one, with the padding (padded tokens per
  real face) and featurization (once per mesh and run: ``FeatureCache``);
* epochs: one seed trained ``--epochs`` epochs by the old loop and by ``training.train.fit``
  from the same initial weights, on the same batches in the same order: seconds per epoch
  (training + validation; the median over epochs 2.., so one-time costs are left out) and
  the val MSE of every epoch. Further seeds of the new path give
  the seed-to-seed spread, the noise within which old and new must agree.

The old path is the training step before this change (commit aacb7fe): every layer of the
aggregator over every token (``full_attention``), the graph embedding's projection of the
concatenated token embeddings (``concatenated_tokens``), the token embedding's VQ over the
padded batch (``padded_vq``), the per-tensor AdamW, validation batches in stored order. Both are
driven by the same learning-rate schedule (``benchmark.training.train.lr_factor``: warm-up, then
constant; no plateau is reached in a few epochs), so only the implementation differs.
Writes perf/results/training_speed.json (``--out``) and prints a table.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import tempfile
import time
import types
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

import benchmark.training.train as train_module
from basic_shapes.infra import atomic_path, hardware
from benchmark.reproduction.presets import PRESETS
from benchmark.reproduction.runner import row_config
from benchmark.scoring.data import FLOOR_DB, BenchmarkData
from benchmark.training.models import REGISTRY, build_model, count_parameters, featurize
from benchmark.training.models.features import TOKEN_GROUPS
from benchmark.training.train import (
    FeatureCache,
    RegressionTask,
    benchmark_examples,
    epoch_batches,
    fit,
    lr_factor,
    make_batch,
    make_optimizer,
    seed_everything,
)

RESULTS = Path(__file__).parent / "results"
ROWS = (
    "direct-basic",
    "graph-basic",
    "token-basic",
    "invariant-basic",
    "blind-basic",
    "direct-ideal",
    "graph-ideal",
    "token-ideal",
)
NO_PLATEAU = 100_000  # patience: the measured epochs never halve the rate nor stop


# --- the old path -----------------------------------------------------------------------------
def full_attention(self, emb: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The old ``Aggregator.forward``: every layer over every token, then the CLS row."""
    x = torch.cat([self.cls.expand(len(emb), -1, -1), emb], 1)
    pad = torch.cat([mask.new_zeros(len(mask), 1), ~mask], 1)
    return self.norm(self.encoder(x, src_key_padding_mask=pad)[:, 0])


def concatenated_tokens(self, batch):
    """The old ``GraphEmbedding.node_features``: token embeddings concatenated, projected."""
    tokens = batch.tokens[batch.mask]
    parts, start = [], 0
    for table, (_, n) in zip(self.tables, TOKEN_GROUPS):
        parts.append(table(tokens[:, start : start + n]).flatten(1))
        start += n
    return self.proj(torch.cat(parts, 1))


def padded_vq(self, batch):
    """The old ``TokenEmbedding.forward``: the padded batch quantized with its mask."""
    emb, _, _ = self.graph(batch)
    quantized, codes, commit = self.vq(emb, mask=batch.mask)
    self.last_codes = codes.detach()
    return quantized * batch.mask[..., None], batch.mask, commit.sum()


def old_optimizer(task: nn.Module, lr: float, weight_decay: float) -> torch.optim.Optimizer:
    return torch.optim.AdamW(task.parameters(), lr=lr, weight_decay=weight_decay)


@torch.no_grad()
def old_validation_mse(model, examples, batch_size: int) -> float:
    """The old ``validation_mse``: batches in stored order."""
    model.eval()
    errors = []
    for s in range(0, len(examples), batch_size):
        batch = make_batch(examples, list(range(s, min(s + batch_size, len(examples)))))
        pred = model(batch)[0].clamp_min(FLOOR_DB)
        errors += ((pred - batch.target) ** 2).mean(dim=1).tolist()
    model.train()
    return float(np.mean(errors))


def old_fit(task, examples, groups, val, *, epochs, batch_size, lr, weight_decay, seed, stamps):
    """The old training loop (no DDP), on ``fit``'s schedule; the history of every epoch.
    ``stamps`` gets the time at the end of every epoch."""
    task.train()
    opt = old_optimizer(task, lr, weight_decay)
    steps_per_epoch = len(epoch_batches(examples, groups, batch_size, 0, seed))
    total = max(1, epochs * steps_per_epoch)
    warm = max(1, min(total // 20, steps_per_epoch))
    history, best, step = [], None, 0
    for epoch in range(epochs):
        losses = []
        for idx in epoch_batches(examples, groups, batch_size, epoch, seed):
            loss, _ = task(make_batch(examples, idx))
            opt.zero_grad(set_to_none=True)
            loss.backward()
            nn.utils.clip_grad_norm_(task.parameters(), 1.0)
            for group in opt.param_groups:
                group["lr"] = lr * lr_factor(step, warm, total, 0)
            opt.step()
            step += 1
            losses.append(loss.item())
        record = {
            "loss": float(np.mean(losses)),
            "val_mse": old_validation_mse(task.model, val, batch_size),
        }
        stamps.append(time.perf_counter())
        if best is None or record["val_mse"] < best[0]:  # the old fit kept the best weights
            best = (
                record["val_mse"],
                {k: v.detach().clone() for k, v in task.state_dict().items()},
            )
        history.append(record)
    return history


@contextlib.contextmanager
def epoch_clock(stamps: list[float]):
    """Record the time at the end of every epoch of ``training.train.fit`` (after each call
    of its ``validation_mse``)."""
    validate = train_module.validation_mse

    def timed(*args):
        value = validate(*args)
        stamps.append(time.perf_counter())
        return value

    train_module.validation_mse = timed
    try:
        yield
    finally:
        train_module.validation_mse = validate


# --- setup ------------------------------------------------------------------------------------
def subset(data: BenchmarkData, n_train: int | None, n_val: int | None) -> None:
    """Restrict ``data``'s train and val splits to seeded random subsets of their objects
    (``mesh_rows`` and ``BasicShapes`` read the splits through ``object_rows``)."""
    rng = np.random.default_rng(0)
    keep = {}
    for split, n in (("train", n_train), ("val", n_val)):
        objects = data.object_rows(split)
        if n and n < len(objects):
            keep[split] = np.sort(rng.choice(objects, n, replace=False))
    object_rows = data.object_rows
    data.object_rows = lambda split=None: keep[split] if split in keep else object_rows(split)


def make_task(row: str, data: BenchmarkData, seed: int, old: bool) -> tuple[RegressionTask, dict]:
    """The row's model (seeded: the same initial weights old and new) in its regression task."""
    embedding, regime = row.split("-")
    cfg = row_config(PRESETS["cpu"], embedding, regime, seed, None)
    seed_everything(seed)
    model = build_model(**cfg.model_kwargs(int(np.prod(data.target_shape)), data.scale_bins.n))
    if old:
        model.aggregator.forward = types.MethodType(full_attention, model.aggregator)
        if embedding in ("graph", "token"):
            graph = model.embedding if embedding == "graph" else model.embedding.graph
            graph.node_features = types.MethodType(concatenated_tokens, graph)
        if embedding == "token":
            model.embedding.forward = types.MethodType(padded_vq, model.embedding)
    return RegressionTask(model, cfg.loss, data.target_shape), cfg


def examples_of(row: str, data: BenchmarkData, cache: FeatureCache):
    embedding, regime = row.split("-")
    needs = REGISTRY[embedding].needs
    examples, groups = benchmark_examples(data, regime, needs, data.scale_bins, cache)
    val, _ = benchmark_examples(data, regime, needs, data.scale_bins, cache, split="val")
    return examples, groups, val


def set_statistics(task: RegressionTask, examples, groups) -> None:
    task.model.decoder.set_output_statistics(
        torch.from_numpy(np.stack([examples[g[0]].target for g in groups]))
    )


# --- measurements -----------------------------------------------------------------------------
def breakdown(task, opt, examples, batches) -> dict:
    """Milliseconds per step by part (each forward + backward), over ``batches`` after two
    warm-up steps; the parts are cut apart by detaching between them."""
    model = task.model
    parts = dict.fromkeys(("batch", "embedding", "aggregator", "decoder", "clip", "optimizer"), 0.0)
    padded = real = 0
    for k, idx in enumerate(batches):
        t = [time.perf_counter()]
        batch = make_batch(examples, idx)
        t.append(time.perf_counter())
        emb, mask, aux = model.embedding(batch)
        e = emb.detach().requires_grad_()
        t.append(time.perf_counter())
        z = model.aggregator(e, mask)
        zd = z.detach().requires_grad_()
        t.append(time.perf_counter())
        loss = F.mse_loss(model.decoder(zd, batch.scale_bin), batch.target)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        t.append(time.perf_counter())
        z.backward(zd.grad)
        t.append(time.perf_counter())
        outputs = [emb, aux] if aux.requires_grad else [emb]
        grads = [e.grad, torch.ones_like(aux)] if aux.requires_grad else [e.grad]
        if emb.requires_grad:
            torch.autograd.backward(outputs, grads)
        t.append(time.perf_counter())
        nn.utils.clip_grad_norm_(task.parameters(), 1.0)
        t.append(time.perf_counter())
        opt.step()
        t.append(time.perf_counter())
        if k < 2:
            continue
        d = np.diff(t) * 1000
        for name, ms in zip(parts, (d[0], d[1] + d[5], d[2] + d[4], d[3], d[6], d[7])):
            parts[name] += ms
        padded += batch.mask.numel()
        real += int(batch.mask.sum())
    n = max(1, len(batches) - 2)
    out = {k: v / n for k, v in parts.items()}
    out["step"] = sum(out.values())
    out["padded_per_real_face"] = padded / max(real, 1)
    return out


def featurize_seconds(data: BenchmarkData, regime: str, needs: tuple, n: int = 24) -> float:
    """Seconds per mesh of ``featurize`` over a sample of the split's training meshes."""
    rows = data.mesh_rows("train", "all" if regime == "ideal" else "simple")
    sample = rows[np.linspace(0, len(rows) - 1, min(n, len(rows))).astype(int)]
    batch = data.batch(sample)
    t = time.perf_counter()
    for v, f in zip(batch["vertices"], batch["faces"]):
        featurize(v, f, needs)
    return (time.perf_counter() - t) / len(sample)


def measure_row(
    row: str, data: BenchmarkData, cache: FeatureCache, epochs: int, seeds: list[int], steps: int
) -> dict:
    examples, groups, val = examples_of(row, data, cache)
    embedding, regime = row.split("-")
    out = {
        "row": row,
        "train_objects": len(groups),
        "train_meshes": len(examples),
        "val_objects": len(val),
        "featurize_s_per_mesh": featurize_seconds(data, regime, REGISTRY[embedding].needs),
    }
    batches = epoch_batches(examples, groups, 16, 0, 0)[: steps + 2]
    for path, old in (("old", True), ("new", False)):
        task, cfg = make_task(row, data, 0, old)
        set_statistics(task, examples, groups)
        opt = (old_optimizer if old else make_optimizer)(task, cfg.lr, cfg.weight_decay)
        out[f"breakdown_{path}"] = breakdown(task, opt, examples, batches)
    out["params"] = count_parameters(task.model)
    out["output_layer_params"] = count_parameters(task.model.decoder.mlp[-1])
    runs = {}
    for path, seed in [("old", seeds[0])] + [("new", s) for s in seeds]:
        task, cfg = make_task(row, data, seed, path == "old")
        set_statistics(task, examples, groups)
        kw = dict(
            epochs=epochs,
            batch_size=cfg.batch_size,
            lr=cfg.lr,
            weight_decay=cfg.weight_decay,
            seed=seed,
        )
        load = os.getloadavg()[0]
        stamps: list[float] = []  # at the end of every epoch (its validation)
        if path == "old":
            history = old_fit(task, examples, groups, val, **kw, stamps=stamps)
        else:
            with epoch_clock(stamps):
                history = fit(
                    task,
                    examples,
                    groups,
                    **kw,
                    desc=row,
                    device=torch.device("cpu"),
                    progress=False,
                    val=val,
                    patience=NO_PLATEAU,
                )
        epoch_s = np.diff(stamps).tolist()
        runs[f"{path}-seed-{seed}"] = {
            "s_per_epoch": float(np.median(epoch_s)),
            "epoch_s": epoch_s,
            "load_avg_1m": load,
            "val_mse": [r["val_mse"] for r in history],
            "loss": [r["loss"] for r in history],
        }
    old, new = runs[f"old-seed-{seeds[0]}"], runs[f"new-seed-{seeds[0]}"]
    out.update(
        runs=runs,
        s_per_epoch_old=old["s_per_epoch"],
        s_per_epoch_new=new["s_per_epoch"],
        speedup=old["s_per_epoch"] / new["s_per_epoch"],
        val_mse_old=old["val_mse"][-1],
        val_mse_new=new["val_mse"][-1],
        seed_spread=float(np.ptp([runs[f"new-seed-{s}"]["val_mse"][-1] for s in seeds]))
        if len(seeds) > 1
        else None,
    )
    return out


def threads_probe(row: str, data: BenchmarkData, cache: FeatureCache, steps: int) -> dict:
    """Milliseconds per new step of ``row`` with one and with two torch threads."""
    examples, groups, _ = examples_of(row, data, cache)
    batches = epoch_batches(examples, groups, 16, 0, 0)[: steps + 2]
    out = {}
    previous = torch.get_num_threads()
    for threads in (1, 2):
        torch.set_num_threads(threads)
        task, cfg = make_task(row, data, 0, False)
        set_statistics(task, examples, groups)
        opt = make_optimizer(task, cfg.lr, cfg.weight_decay)
        out[f"{threads}_threads_ms_per_step"] = breakdown(task, opt, examples, batches)["step"]
    torch.set_num_threads(previous)
    return out


def table(rows: list[dict]) -> str:
    lines = [
        "| row | s/epoch old | s/epoch new | speed-up | val MSE old | val MSE new | "
        "seed spread (new) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        spread = "-" if r["seed_spread"] is None else f"{r['seed_spread']:.2f}"
        lines.append(
            f"| {r['row']} | {r['s_per_epoch_old']:.2f} | {r['s_per_epoch_new']:.2f} | "
            f"{r['speedup']:.1f}x | {r['val_mse_old']:.2f} | {r['val_mse_new']:.2f} | "
            f"{spread} |"
        )
    lines += ["", "ms per step by part (old -> new):", ""]
    parts = ("batch", "embedding", "aggregator", "decoder", "clip", "optimizer", "step")
    lines += [
        "| row | " + " | ".join(parts) + " | padded/real |",
        "|---|" + "---:|" * (len(parts) + 1),
    ]
    for r in rows:
        o, n = r["breakdown_old"], r["breakdown_new"]
        lines.append(
            f"| {r['row']} | "
            + " | ".join(f"{o[p]:.0f} -> {n[p]:.0f}" for p in parts)
            + f" | {n['padded_per_real_face']:.2f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", help="labelled dataset (default: the test fixture, cpu-v1 grid)")
    parser.add_argument(
        "--objects-per-class",
        type=int,
        default=40,
        help="fixture objects per class (without --data)",
    )
    parser.add_argument("--train-objects", type=int, help="seeded subset of the train objects")
    parser.add_argument("--val-objects", type=int, help="seeded subset of the val objects")
    parser.add_argument("--epochs", type=int, default=4)
    parser.add_argument("--seeds", default="0,1", help="first: old and new; others: new only")
    parser.add_argument("--steps", type=int, default=8, help="steps timed by part per row")
    parser.add_argument("--rows", default=",".join(ROWS))
    parser.add_argument("--out", default=str(RESULTS / "training_speed.json"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    seeds = [int(s) for s in args.seeds.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        if args.data:
            directory = args.data
        else:
            sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
            from tests.benchmark_fixture import make_dataset

            directory = make_dataset(
                Path(tmp) / "fixture",
                args.objects_per_class,
                n_test_per_class=2,
                n_val_per_class=4,
                grid=(31, 7, 107),
            )
        with BenchmarkData(directory) as data:
            subset(data, args.train_objects, args.val_objects)
            cache = FeatureCache()
            rows = []
            for row in args.rows.split(","):
                rows.append(measure_row(row, data, cache, args.epochs, seeds, args.steps))
                r = rows[-1]
                print(
                    f"{row}: {r['s_per_epoch_old']:.2f} -> {r['s_per_epoch_new']:.2f} s/epoch "
                    f"({r['speedup']:.1f}x), val MSE {r['val_mse_old']:.2f} / "
                    f"{r['val_mse_new']:.2f}",
                    flush=True,
                )
            threads = threads_probe(args.rows.split(",")[0], data, cache, args.steps)
    record = {
        "command": "python perf/training_speed.py "
        + " ".join(
            f"--{k.replace('_', '-')} {v}"
            for k, v in vars(args).items()
            if v is not None and k != "out"
        ),
        "dataset": str(args.data or f"fixture, {args.objects_per_class} objects per class"),
        "machine": hardware(1),
        "epochs": args.epochs,
        "seeds": seeds,
        "threads_probe": threads,
        "rows": rows,
    }
    with atomic_path(args.out) as tmp_out:
        Path(tmp_out).write_text(json.dumps(record, indent=1) + "\n")
    print(table(rows))
    print(f"threads ({args.rows.split(',')[0]}): {threads}")


if __name__ == "__main__":
    main()
