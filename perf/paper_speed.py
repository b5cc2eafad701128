"""What the paper preset costs on one GPU, measured step by step and extrapolated to its hours.

    python perf/paper_speed.py --data DIR --pack FILE [--objects-per-class 3] [--meshes 99]
    python perf/paper_speed.py --set FILE [--device cuda] [--steps 12] [--rows ROW,...]
    python perf/paper_speed.py --probe MESHES FACES [--device cuda]

The paper preset (``benchmark reproduce --preset paper``: paper-v3, 3,000 objects x 100
meshes, the full 61 x 21 x 107 grid, width 256, 5 graph and 6 transformer layers) needs a GPU
and a 300,000-mesh dataset; neither is at hand here. What its hours depend on is:

* ``--pack``: from a slice of paper-v3 (whole shards, the same bytes as in a full build;
  the recorded run: ``benchmark dataset paper-v3 --shards 0,1,2,3,125,126,250,251 --data
  DIR``, 40 s here), the training objects' meshes as the one data path reads them
  (``BasicShapes``: normalized, with their scale bins and VV dB targets),
  ``--objects-per-class`` objects per class, each with its simple mesh and its first
  ``--meshes`` complex ones: an 8 MB ``.npz`` that travels to a GPU machine without Blender.
* ``--set``: every row of the paper's table built at the paper preset's size
  (``runner.row_config``) and trained by ``training.train.fit`` itself, one epoch of
  ``--steps`` batches of 32 after a warm-up epoch (the objects are repeated to fill the
  batches; each draw picks one of an object's meshes and batches are bucketed by face count,
  as in training); prediction timed as validation and evaluation run it; pretraining steps on
  the procedural corpus (its generation timed on this CPU); peak GPU memory of training and
  of prediction. Then the preset's hours: paper-v3's splits (``generate.plan_objects``) times
  the measured seconds, every run at the epoch cap (an upper bound: runs stop at their
  validation plateau), 100 meshes + 9 OOD per test object. Rows already in ``--out`` are kept
  (a run cut off continues); the record is rewritten after every row.
* ``--probe``: the aggregator alone, prediction with and without torch's fast inference path
  (``aggregator._inner_path``), and a training step; appended to ``--out``.

Writes perf/results/paper_speed.json (``--out``) and prints a table.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import hashlib
import json
import math
import time
from dataclasses import replace
from pathlib import Path
from unittest import mock

import numpy as np
import torch

from basic_shapes.generate import _mesh_count, plan_objects
from basic_shapes.infra import atomic_path, hardware
from benchmark.reproduction.presets import PRESETS, ROWS
from benchmark.reproduction.runner import row_config
from benchmark.scoring.data import BasicShapes, BenchmarkData, ScaleBins
from benchmark.scoring.versions import get as get_version
from benchmark.training.models import (
    FACE_EMBEDDINGS,
    REGISTRY,
    ClassificationHead,
    ReconstructionHead,
    build_model,
    featurize,
)
from benchmark.training.train import (
    Example,
    PretrainTask,
    RegressionTask,
    corpus_examples,
    epoch_batches,
    fit,
    seed_everything,
    validation_mse,
)

PRESET = PRESETS["paper"]


# --- the timing set (here) --------------------------------------------------------------------
def pack(data_dir: str, out: str, per_class: int, meshes: int) -> dict:
    """The training objects' meshes and targets of a paper-v3 slice, as ``BasicShapes`` reads
    them, into one ``.npz``: per mesh its vertices and faces (ragged, with offsets), scale
    bins and object; per object its VV dB target."""
    with BenchmarkData(data_dir) as data:
        ds = BasicShapes(data, "train", "all")
        objects = np.array([ds.object_of(i) for i in range(len(ds))])
        classes = data.objects["class_index"]
        keep: list[int] = []
        for c in np.unique(classes[objects]):
            chosen = [o for o in dict.fromkeys(objects) if classes[o] == c][:per_class]
            for o in chosen:
                keep += list(np.flatnonzero(objects == o)[: meshes + 1])  # simple mesh first
        items = [ds[i] for i in keep]
        variant = np.array([int(it["variant"]) for it in items])
        if not np.all(variant[np.r_[True, objects[keep][1:] != objects[keep][:-1]]] == 0):
            raise ValueError(f"{data_dir}: an object's first mesh is not its simple mesh")
        obj_ids, obj_index = np.unique(objects[keep], return_inverse=True)
        arrays = {
            "vertices": np.concatenate([it["vertices"].numpy() for it in items]),
            "faces": np.concatenate([it["faces"].numpy() for it in items]),
            "n_vertices": np.array([len(it["vertices"]) for it in items]),
            "n_faces": np.array([len(it["faces"]) for it in items]),
            "scale_bins": np.stack([it["scale_bins"].numpy() for it in items]),
            "scale_m": np.stack([it["scale_m"].numpy() for it in items]),
            "variant": variant,
            "object": obj_index,
            "targets": np.stack([ds.target(int(o)).reshape(-1) for o in obj_ids]),
            "target_shape": np.array(data.target_shape),
            "source": np.array(f"{data_dir} (dataset {data.fingerprint[:12]})"),
        }
    with atomic_path(out) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return {"meshes": len(items), "objects": len(obj_ids), "bytes": Path(out).stat().st_size}


@functools.cache
def load_set(path: str, needs: tuple[str, ...]) -> tuple[list[Example], np.ndarray, tuple]:
    """Examples (featurized as training does) of a packed set, their object and target shape;
    rows that need the same features share them."""
    z = np.load(path, allow_pickle=False)
    v_end, f_end = np.cumsum(z["n_vertices"]), np.cumsum(z["n_faces"])
    examples = []
    for k in range(len(v_end)):
        v = z["vertices"][v_end[k] - z["n_vertices"][k] : v_end[k]]
        f = z["faces"][f_end[k] - z["n_faces"][k] : f_end[k]]
        examples.append(
            Example(
                featurize(v, f, needs),
                z["scale_bins"][k],
                z["targets"][z["object"][k]],
                scale_m=z["scale_m"][k].astype(np.float64),
            )
        )
    return examples, z["object"], tuple(int(n) for n in z["target_shape"])


# --- timing (on the device) -------------------------------------------------------------------
def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _peak(device: torch.device) -> float | None:
    """GiB of GPU memory allocated at most since the last call (None on CPU)."""
    if device.type != "cuda":
        return None
    peak = torch.cuda.max_memory_allocated(device) / 2**30
    torch.cuda.reset_peak_memory_stats(device)
    return peak


def seconds_per_step(task, examples, groups, steps: int, lr: float, device) -> float:
    """``fit`` for one epoch of ``steps`` batches (objects repeated to fill them), after a
    warm-up epoch of two batches: seconds per optimizer step."""
    size = PRESET.train["batch_size"]
    groups = [groups[i % len(groups)] for i in range(steps * size)]
    common = dict(batch_size=size, lr=lr, weight_decay=1e-4, seed=0, device=device)
    fit(task, examples, groups[: 2 * size], epochs=1, desc="warm-up", progress=False, **common)
    _sync(device)
    t0 = time.perf_counter()
    fit(task, examples, groups, epochs=1, desc="timed", progress=False, **common)
    _sync(device)
    return (time.perf_counter() - t0) / len(epoch_batches(examples, groups, size, 0, 0))


def seconds_per_mesh(model, examples: list[Example], device) -> float:
    """Prediction as validation and evaluation run it (batches of similar face count)."""
    size = PRESET.train["batch_size"]
    validation_mse(model, examples[:size], size, device)  # warm-up
    _sync(device)
    t0 = time.perf_counter()
    validation_mse(model, examples, size, device)
    _sync(device)
    return (time.perf_counter() - t0) / len(examples)


def measure_row(embedding: str, regime: str, path: str, corpus, steps: int, device) -> dict:
    """One row at the paper preset's size: training step, prediction, pretraining step."""
    cfg = row_config(PRESET, embedding, regime, seed=0, shapenet=None)
    examples, objects, target_shape = load_set(path, REGISTRY[embedding].needs)
    simple = [k for k in range(len(examples)) if k == 0 or objects[k] != objects[k - 1]]
    ideal = regime == "ideal"
    groups = [
        np.flatnonzero(objects == o) if ideal else np.array([simple[j]])
        for j, o in enumerate(np.unique(objects))
    ]
    seed_everything(0)
    model = build_model(**cfg.model_kwargs(int(np.prod(target_shape)), ScaleBins().n))
    out = {"row": cfg.name, "parameters": sum(p.numel() for p in model.parameters())}
    if regime in ("classification", "autoencoder"):
        meshes, names = corpus
        head = (
            ClassificationHead(cfg.dim, len(names))
            if regime == "classification"
            else ReconstructionHead(cfg.dim)
        )
        pre = corpus_examples(meshes)
        out["pretrain_step_s"] = seconds_per_step(
            PretrainTask(model, head), pre, [np.array([i]) for i in range(len(pre))],
            steps, cfg.pretrain_lr, device,
        )  # fmt: skip
    task = RegressionTask(model, cfg.loss, target_shape)
    model.decoder.set_output_statistics(torch.from_numpy(np.stack([e.target for e in examples])))
    _peak(device)
    out["train_step_s"] = seconds_per_step(task, examples, groups, steps, cfg.lr, device)
    out["train_peak_gib"] = _peak(device)
    first = set(simple)
    complex_ = [e for k, e in enumerate(examples) if k not in first]
    out["predict_simple_s"] = seconds_per_mesh(model, [examples[k] for k in simple], device)
    out["predict_complex_s"] = seconds_per_mesh(model, complex_, device)
    trained_on = np.concatenate(groups)
    out["faces_per_mesh"] = float(np.mean([examples[k].features.n_faces for k in trained_on]))
    out["predict_peak_gib"] = _peak(device)
    return {k: v for k, v in out.items() if v is not None}


def aggregator_probe(device: torch.device, batch: int = 32, faces: int = 4000) -> list[dict]:
    """The paper preset's aggregator alone on ``batch`` meshes of 3,000-``faces`` faces: time
    (second of two calls) and peak memory of prediction with torch's fast inference path (the
    aggregator before ``aggregator._inner_path``) and without (now), and of a training step;
    the largest difference of the outputs from the first."""
    from benchmark.training.models import aggregator

    t = PRESET.train
    torch.manual_seed(0)
    agg = aggregator.Aggregator(t["dim"], t["agg_layers"], t["n_heads"]).to(device)
    emb = torch.randn(batch, faces, t["dim"], device=device)
    lengths = torch.linspace(3000, faces, batch, device=device)
    mask = torch.arange(faces, device=device)[None, :] < lengths[:, None]
    out, ref = [], None
    for train, fast in [(False, True), (False, False), (True, False)]:
        agg.train(train)
        for _ in range(2):
            _peak(device)
            t0 = time.perf_counter()
            before = (contextlib.nullcontext if fast else aggregator._inner_path,)
            with mock.patch.object(aggregator, "_inner_path", *before):  # fast: as before
                with torch.set_grad_enabled(train):
                    y = agg(emb, mask)
                if train:
                    y.sum().backward()
            _sync(device)
            seconds = time.perf_counter() - t0
        ref = y.detach() if ref is None else ref
        out.append(
            {
                "train": train,
                "fast_path": fast,
                "s": seconds,
                "peak_gib": _peak(device),
                "max_abs_diff_to_first": (y.detach() - ref).abs().max().item(),
            }
        )
    return out


def preset_hours(rows: list[dict], corpus_s_per_mesh: float) -> dict:
    """The paper preset's hours from the measured seconds: every row and seed at the epoch
    cap (validation once per epoch on the val objects' simple meshes), pretraining where the
    row has it, evaluation of the test objects' 100 meshes + OOD, the corpus built once."""
    t = PRESET.train
    generator = get_version(PRESET.dataset).generator()
    plans = plan_objects(generator)
    split = {s: sum(p.split == s for p in plans) for s in ("train", "val", "test")}
    steps = math.ceil(split["train"] / t["batch_size"])  # = len(epoch_batches) at 2,400
    pre_steps = math.ceil(t["pretrain_meshes"] / t["batch_size"])
    test = [p for p in plans if p.split == "test"]
    complex_meshes = _mesh_count([(None, test)], generator.to_dict()) - len(test)  # + OOD
    per_row = {}
    for r in rows:
        epoch = steps * r["train_step_s"] + split["val"] * r["predict_simple_s"]
        pre = t["pretrain_epochs"] * pre_steps * r.get("pretrain_step_s", 0.0)
        evaluate = len(test) * r["predict_simple_s"] + complex_meshes * r["predict_complex_s"]
        per_row[r["row"]] = {
            "epoch_s": epoch,
            "pretrain_s": pre,
            "evaluate_s": evaluate,
            "seed_s_at_cap": t["epochs"] * epoch + pre + evaluate,
        }
    seeds = len(PRESET.seeds)
    corpus = corpus_s_per_mesh * t["pretrain_meshes"]
    total = seeds * sum(v["seed_s_at_cap"] for v in per_row.values()) + corpus
    return {
        "rows_not_measured": [f"{e}-{r}" for e, r in ROWS if f"{e}-{r}" not in per_row],
        "splits": split,
        "steps_per_epoch": steps,
        "seeds": seeds,
        "epochs_cap": t["epochs"],
        "corpus_s": corpus,
        "rows": per_row,
        "total_hours_at_cap": total / 3600,
    }


def table(rows: list[dict], hours: dict) -> str:
    lines = [
        "| row | params (M) | train step ms | faces per mesh | pretrain step ms "
        "| predict ms/mesh simple, complex | peak GiB train, predict | one seed at the cap, min |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        pre = f"{1e3 * r['pretrain_step_s']:.0f}" if "pretrain_step_s" in r else "-"
        mem = (
            f"{r['train_peak_gib']:.1f}, {r['predict_peak_gib']:.1f}"
            if "train_peak_gib" in r
            else f"{r['peak_memory_gib']:.1f} (both)"  # the first version: one peak for both
            if "peak_memory_gib" in r
            else "-"
        )
        lines.append(
            f"| {r['row']} | {r['parameters'] / 1e6:.0f} | {1e3 * r['train_step_s']:.0f} "
            f"| {r['faces_per_mesh']:.0f} | {pre} | {1e3 * r['predict_simple_s']:.2f}, "
            f"{1e3 * r['predict_complex_s']:.2f} | {mem} "
            f"| {hours['rows'][r['row']]['seed_s_at_cap'] / 60:.0f} |"
        )
    missing = hours["rows_not_measured"]
    lines.append(
        (f"\nNot measured: {', '.join(missing)}." if missing else "")
        + f"\nThe paper preset at the epoch cap ({hours['epochs_cap']} epochs, {hours['seeds']} "
        f"seeds, {hours['steps_per_epoch']} steps per epoch), the rows measured: "
        f"{hours['total_hours_at_cap']:.1f} h"
    )
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--data", help="a slice of paper-v3 (--pack)")
    p.add_argument("--pack", help="write the timing set here (.npz) and exit")
    p.add_argument("--objects-per-class", type=int, default=3)
    p.add_argument("--meshes", type=int, default=99, help="complex meshes per object")
    p.add_argument("--set", help="the timing set to measure on")
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    p.add_argument("--steps", type=int, default=12, help="timed training steps per row")
    p.add_argument("--rows", help="comma-separated rows (default: all)")
    p.add_argument("--corpus", type=int, default=256, help="pretraining corpus meshes timed")
    p.add_argument(
        "--probe",
        nargs=2,
        type=int,
        metavar=("MESHES", "FACES"),
        help="only time the aggregator's prediction paths on MESHES meshes of 3,000-FACES "
        "faces (the device run: 32 4000); added to --out's aggregator_probe",
    )
    p.add_argument("--out", default="perf/results/paper_speed.json")
    args = p.parse_args()
    if args.pack:
        if not args.data:
            raise SystemExit("paper_speed: --pack needs --data (a slice of paper-v3)")
        print(json.dumps(pack(args.data, args.pack, args.objects_per_class, args.meshes)))
        return
    device = torch.device(args.device)
    if args.probe:
        runs = aggregator_probe(device, *args.probe)
        print(json.dumps(runs, indent=1))
        record = json.loads(Path(args.out).read_text()) if Path(args.out).exists() else {}
        record.setdefault("aggregator_probe", []).append(
            {"machine": hardware(), "meshes": args.probe[0], "faces": args.probe[1], "runs": runs}
        )
        with atomic_path(args.out) as tmp:
            Path(tmp).write_text(json.dumps(record, indent=1) + "\n")
        return
    if not args.set:
        raise SystemExit("paper_speed: give --set FILE (made by --pack), --pack FILE or --probe")
    from benchmark.training.train import corpus_meshes

    rows = [(e, r) for e, r in ROWS if not args.rows or f"{e}-{r}" in args.rows.split(",")]
    run = {
        "device": str(device),
        "gpu": hardware()["gpu"],
        "torch": torch.__version__,
        "steps": args.steps,
        "corpus": args.corpus,
        "set_sha256": hashlib.sha256(Path(args.set).read_bytes()).hexdigest(),
    }
    kept = json.loads(Path(args.out).read_text()) if Path(args.out).exists() else {}
    if "rows" in kept and kept.get("run") != run:
        raise SystemExit(
            f"paper_speed: {args.out} holds rows of another run (GPU, torch, --steps, --corpus "
            "or set); give another --out"
        )
    measured = kept.get("rows", [])  # a cut-off run continues with the rows it lacks
    todo = [(e, r) for e, r in rows if f"{e}-{r}" not in {m["row"] for m in measured}]
    corpus, corpus_s = None, kept.get("corpus_s_per_mesh")
    if any(r in ("classification", "autoencoder") for _, r in todo) or corpus_s is None:
        cfg = row_config(PRESET, FACE_EMBEDDINGS[0], "classification", 0, None)
        t0 = time.perf_counter()
        corpus = corpus_meshes(replace(cfg, pretrain_meshes=args.corpus))
        corpus_s = corpus_s or (time.perf_counter() - t0) / args.corpus
    for e, r in todo:
        measured.append(measure_row(e, r, args.set, corpus, args.steps, device))
        print(json.dumps(measured[-1]), flush=True)
        record = {
            **kept,
            "command": "python perf/paper_speed.py --set SET "
            + f"--steps {args.steps} --corpus {args.corpus}",
            "machine": hardware(),
            "device": str(device),
            "torch": torch.__version__,
            "set": str(np.load(args.set)["source"]),
            "run": run,
            "corpus_s_per_mesh": corpus_s,
            "rows": measured,
            "preset": preset_hours(measured, corpus_s),
        }
        with atomic_path(args.out) as tmp:  # after every row: a cut-off run keeps its rows
            Path(tmp).write_text(json.dumps(record, indent=1) + "\n")
    hours = preset_hours(measured, corpus_s)
    print(table(measured, hours))


if __name__ == "__main__":
    main()
