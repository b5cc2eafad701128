"""Reproduce the paper's table: every (embedding, regime) row, evaluated by the harness.

``benchmark reproduce --preset tiny|small|paper --out DIR`` generates a labelled dataset
with the toolkit's own CLIs (``basic-shapes generate``, ``radar-sim label``; or reuses
``--data``), builds the pretraining corpus, trains and evaluates every row once per
training seed of the preset, and writes ``DIR/table.md``, ``DIR/table.json`` and
``DIR/speed_vs_error.png`` (ms per mesh against Complex MSE). Every (row, seed) already
finished with the same configuration on the same dataset is reused, so a killed run
resumes where it stopped.

The table carries the reference rows (``benchmark.references``), each row's mean ± std
across seeds with the 95% interval of the seed-mean (bootstrap over test objects of the
per-object errors averaged over seeds), its skill against the strongest reference, and
the paper's findings decided by paired intervals (``findings``). The presets, and why they
are sized as they are, are documented in ``PRESETS`` and docs/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from basic_shapes.infra import add_quiet_flag, atomic_path, number
from basic_shapes.shards import ShardError
from benchmark.models import FACE_EMBEDDINGS, REGISTRY

EMBEDDINGS = FACE_EMBEDDINGS  # the paper's encoders: pretrained, with an Ideal row
ROWS: tuple[tuple[str, str], ...] = (
    *[(e, r) for e in EMBEDDINGS for r in ("basic", "classification", "autoencoder")],
    *[(e, "ideal") for e in EMBEDDINGS],
    *[(e, "basic") for e in REGISTRY if e not in EMBEDDINGS],
)
PRETRAINING = {"basic": "none", "classification": "classification", "autoencoder": "autoencoder",
               "ideal": "none"}


@dataclass(frozen=True)
class Preset:
    """A dataset version and a model/training size that fit a time budget."""

    dataset: str  # a registered version (benchmark.versions), built unless --data is given
    train: dict  # TrainConfig fields
    workers: int | None  # Dask workers for generate/label (0: in-process, None: per core)
    jobs: int = 1  # rows trained at once, in separate single-threaded processes (CPU)
    launcher: str = "inprocess"  # or "torchrun" (one process per GPU, DDP)
    expected: str = ""
    seeds: tuple[int, ...] = (0, 1, 2)  # training seeds per row (mean ± std across them)
    findings: bool = True  # False: too small to decide any claim (the table says why)


SMALL_MODEL = dict(dim=32, embed_layers=2, agg_layers=1, n_heads=2, decoder_hidden=256,
                   codebook_size=64, pretrain_meshes=1500, pretrain_epochs=8,
                   pretrain_max_faces=400)
"""CPU-sized models: complex meshes reach ~4000 faces, so self-attention over faces dominates;
one aggregator layer, two heads, one thread per job with two jobs at once."""

PRESETS = {
    # For the test suite: every row on a few objects, with models too small to learn much.
    "tiny": Preset(
        dataset="tiny-v1", workers=0,
        train=dict(dim=16, embed_layers=1, agg_layers=1, n_heads=2, decoder_hidden=32,
                   codebook_size=16, epochs=2, batch_size=8, pretrain_meshes=20,
                   pretrain_epochs=1, pretrain_max_faces=100),
        expected="about a minute on 2 CPU cores", seeds=(0,), findings=False),
    # The demo's dataset with the CPU models: a quick look, too few test objects for findings.
    "small": Preset(
        dataset="demo-v1", workers=None, jobs=2, train=dict(SMALL_MODEL, epochs=30, batch_size=8),
        expected="about 10 minutes on 2 CPU cores", seeds=(0,), findings=False),
    # The CPU benchmark (docs/RESULTS.md): 150 test objects, 3 seeds, paired intervals.
    "cpu": Preset(
        dataset="cpu-v1", workers=None, jobs=2, train=dict(SMALL_MODEL, epochs=8, batch_size=16),
        expected="estimated 4-6 hours on 2 CPU cores (resumable: rerun to continue)"),
    # The paper's scale: 3000 objects x 100 meshes, full radar grid, GPU(s).
    "paper": Preset(
        dataset="paper-v1", workers=None,
        train=dict(dim=256, embed_layers=5, agg_layers=6, n_heads=8, decoder_hidden=1024,
                   codebook_size=512, epochs=100, batch_size=32, pretrain_meshes=20000,
                   pretrain_epochs=30, pretrain_max_faces=800, lr=3e-4, pretrain_lr=3e-4),
        launcher="torchrun",
        expected="estimated (not measured) 3-4 hours of training and evaluation on one "
                 "H100-class GPU, divided roughly by N with torchrun on N GPUs; generating and "
                 "labelling the 300,000 meshes is about 30 CPU-minutes (a Dask cluster)"),
}


# --- dataset ----------------------------------------------------------------------------------
def make_dataset(preset: Preset, directory: Path, quiet: bool) -> dict:
    """Build the preset's dataset version (generate + label; both resume)."""
    from benchmark import versions

    try:
        return versions.build(versions.get(preset.dataset), directory, workers=preset.workers,
                              quiet=quiet)
    except versions.VersionError as exc:
        raise SystemExit(f"benchmark reproduce: {exc}") from None


# --- rows ---------------------------------------------------------------------------------
def row_config(preset: Preset, embedding: str, regime: str, seed: int, shapenet: str | None):
    from benchmark.train import TrainConfig

    return TrainConfig(embedding=embedding, regime=regime, seed=seed, shapenet=shapenet,
                       **preset.train)


def job_name(cfg) -> str:
    return f"{cfg.name}/seed-{cfg.seed}"


def row_files(out: Path, name: str, seed: int | None = None) -> tuple[Path, Path]:
    """(results JSON, predictions HDF5) of a row's seed (``results/<row>/seed-<s>/``) or,
    with ``seed`` None, of the row as the board takes it (``results/<row>/``: the first
    seed's files, the layout that ``leaderboard seed --from <out>/results`` submits)."""
    d = out / "results" / name / ("" if seed is None else f"seed-{seed}")
    return d / "results.json", d / "predictions.h5"


def _checkpoint_dir(out: Path, cfg) -> Path:
    return out / "checkpoints" / cfg.name / f"seed-{cfg.seed}"


def _trained(out: Path, cfg, fingerprint: str) -> dict | None:
    """The checkpoint config of a (row, seed) trained earlier with this exact config on
    this dataset."""
    try:
        ck = json.loads((_checkpoint_dir(out, cfg) / "config.json").read_text())
    except (OSError, ValueError):
        return None
    if ck.get("train") != asdict(cfg) or ck.get("dataset_fingerprint") != fingerprint:
        return None
    return ck


def _finished(out: Path, cfg, fingerprint: str) -> dict | None:
    """The results of a (row, seed) finished earlier with this exact config on this dataset."""
    from benchmark.protocol import ResultsError, load_results

    ck = _trained(out, cfg, fingerprint)
    results_path, predictions_path = row_files(out, cfg.name, cfg.seed)
    try:
        results = load_results(results_path)
    except (OSError, ValueError, ResultsError):
        return None
    if ck is None or results["dataset_fingerprint"] != fingerprint \
            or not predictions_path.is_file() or "per_object" not in results:
        return None
    return {"results": results, "train_seconds": ck.get("train_seconds")}


def _train_flags(cfg) -> list[str]:
    flags = []
    for f in fields(cfg):
        value = getattr(cfg, f.name)
        if value is not None:
            flags += [f"--{f.name.replace('_', '-')}", str(value)]
    return flags


def run_row(cfg, data_dir: Path, out: Path, preset: Preset, shared: dict, nproc: int,
            progress: bool, log=None) -> dict:
    """Train (in-process or under torchrun) and evaluate one (row, seed); return its record."""
    from benchmark.models.checkpoint import save_checkpoint
    from benchmark.train import evaluate_checkpoint, train

    ckpt = _checkpoint_dir(out, cfg)
    t0 = time.perf_counter()
    trained = _trained(out, cfg, shared["fingerprint"])
    if trained is not None:  # trained earlier, evaluation missing or interrupted
        train_seconds = trained["train_seconds"]
    elif preset.launcher == "torchrun" and nproc > 1:
        from benchmark.versions import run_tool

        run_tool([sys.executable, "-m", "torch.distributed.run", f"--nproc_per_node={nproc}",
                  "-m", "benchmark.cli", "train", "--data", str(data_dir), "--out", str(ckpt),
                  "--quiet", *_train_flags(cfg)], f"training {job_name(cfg)}", quiet=False)
        train_seconds = json.loads((ckpt / "config.json").read_text())["train_seconds"]
    else:
        from benchmark.data import BenchmarkData

        with BenchmarkData(data_dir) as data:
            model, config = train(cfg, data, cache=shared["cache"], corpus=shared.get("corpus"),
                                  device=shared["device"], progress=progress, log=log)
        save_checkpoint(ckpt, model, config)
        train_seconds = config["train_seconds"]
    results_path, predictions_path = row_files(out, cfg.name, cfg.seed)
    results = evaluate_checkpoint(ckpt, data_dir, results_path, progress, device=shared["device"],
                                  predictions=predictions_path)
    return {"results": results, "train_seconds": train_seconds,
            "wall_seconds": time.perf_counter() - t0}


TIMED_ALONE = "timed alone"


def _mark_timed_alone(out: Path, cfg, record: dict, ms_per_mesh: float, threads: int) -> None:
    """Store a speed measured with no other job of this run on the CPU, and say so."""
    from benchmark.evaluate import speed_block
    from benchmark.protocol import write_results

    speed = speed_block(ms_per_mesh, threads)
    speed["hardware"] += f"; {TIMED_ALONE}"
    record["results"]["speed"] = speed
    write_results(row_files(out, cfg.name, cfg.seed)[0], record["results"])


def time_alone(out: Path, data_dir: Path, jobs: list[tuple], threads: int,
               progress: bool = True) -> None:
    """Re-time the first seed of rows that were evaluated while another job shared the CPU
    (their ms per mesh measured contention, not the model): ``predict`` over the whole test
    split, one row at a time, after a warm-up batch; I/O excluded, as in the harness."""
    import torch
    from tqdm import tqdm

    from benchmark.data import BenchmarkData
    from benchmark.models.checkpoint import CheckpointModel

    todo = [(cfg, r) for cfg, r in jobs
            if TIMED_ALONE not in (r["results"]["speed"].get("hardware") or "")]
    if not todo:
        return
    device = "cuda" if torch.cuda.is_available() else "cpu"
    with BenchmarkData(data_dir) as data:
        rows = data.mesh_rows("test")
        batches = [data.batch(rows[s:s + 16]) for s in range(0, len(rows), 16)]
    for cfg, record in tqdm(todo, desc="timing", unit="row", disable=not progress):
        model = CheckpointModel(_checkpoint_dir(out, cfg), device=device)
        model.predict(batches[0])
        t0 = time.perf_counter()
        for batch in batches:
            model.predict(batch)
        ms = 1000.0 * (time.perf_counter() - t0) / len(rows)
        _mark_timed_alone(out, cfg, record, ms, threads)


def publish_row(out: Path, name: str, seeds: list[int]) -> None:
    """``results/<row>/``: the first seed's predictions and results (naming every seed), for
    ``leaderboard seed``; hard-linked where the file system allows, else copied."""
    import shutil

    from benchmark.protocol import load_results, write_results

    src_results, src_preds = row_files(out, name, seeds[0])
    dst_results, dst_preds = row_files(out, name)
    tmp = dst_preds.with_name(dst_preds.name + ".tmp")
    tmp.unlink(missing_ok=True)
    try:
        os.link(src_preds, tmp)
    except OSError:
        shutil.copyfile(src_preds, tmp)
    os.replace(tmp, dst_preds)
    results = load_results(src_results)
    results["seeds"]["train_all"] = list(seeds)
    write_results(dst_results, results)


# --- table ------------------------------------------------------------------------------------
METRICS = ("simple_mse", "complex_mse", "variation_mse")
OOD_METRICS = ("ood_complex_mse", "ood_variation_mse")


def _mean_per_object(seed_results: list[dict]) -> dict:
    """Per-object errors averaged over seeds (NaN where an object lacks a metric); the OOD
    errors when every seed has them (results made before OOD scoring lack them)."""
    from benchmark.metrics import ood_keys

    first = seed_results[0]["per_object"]
    for r in seed_results[1:]:
        if r["per_object"]["object_id"] != first["object_id"]:
            raise ValueError("seeds of a row were scored on different test objects")
    out = {"object_id": np.array(first["object_id"]), "class_index": np.array(first["class_index"])}
    keys = METRICS + (ood_keys() if all("ood_complex_mse" in r["per_object"]
                                        for r in seed_results) else ())
    for m in keys:
        arr = np.array([[np.nan if x is None else x for x in r["per_object"][m]]
                        for r in seed_results], np.float64)
        out[m] = arr.mean(axis=0)
    return out


def table_rows(records: dict, ref_scorers: dict | None = None,
               ref_rows: dict | None = None) -> list[dict]:
    """One row per (embedding, regime) with every finished seed: mean ± std across seeds,
    the interval of the seed-mean, per class and (OOD metrics) per remesher, no-skill votes
    and skill vs the references."""
    from benchmark import references
    from benchmark.metrics import metric_block, per_remesher

    rows = []
    for (embedding, regime) in ROWS:
        name = f"{embedding}-{regime}"
        seeds = sorted(records.get(name, {}))
        if not seeds:
            continue
        recs = [records[name][s] for s in seeds]
        res = [r["results"] for r in recs]
        po = _mean_per_object(res)
        block = metric_block(po, po["class_index"])
        cols = METRICS + OOD_METRICS
        row = {"name": name, "embedding": embedding, "regime": regime,
               "pretraining": PRETRAINING[regime],
               "training_meshes": "all" if regime == "ideal" else "simple", "seeds": seeds,
               **{k: block.get(k) for k in cols}, **{k + "_ci": block.get(k + "_ci") for k in cols},
               **{k + "_std": _std([r["metrics"].get(k) for r in res]) for k in cols},
               "per_remesher": per_remesher(po, po["class_index"]),
               "per_seed": {str(s): {**{k: r["metrics"].get(k) for k in cols},
                                     "no_skill": r["metrics"]["no_skill"]}
                            for s, r in zip(seeds, res)},
               "no_skill_seeds": sum(bool(r["metrics"]["no_skill"]) for r in res),
               "params": res[0]["model"]["params"], "ms_per_mesh": res[0]["speed"]["ms_per_mesh"],
               "speed": res[0]["speed"],
               "train_seconds": _mean([r.get("train_seconds") for r in recs]),
               "per_class": {}, "per_object": {k: [None if np.isnan(x) else float(x) for x in v]
                                               if v.dtype.kind == "f" else v.tolist()
                                               for k, v in po.items()}}
        row["no_skill"] = row["no_skill_seeds"] * 2 > len(seeds)
        names = res[0]["metrics"]["per_class"]
        for c, cname in enumerate(names):
            sel = po["class_index"] == c
            if sel.any():
                row["per_class"][cname] = metric_block({k: v[sel] for k, v in po.items()},
                                                       po["class_index"][sel])
        if ref_scorers is not None:
            row["skill"] = references.skill(po, ref_scorers, ref_rows)
        rows.append(row)
    return rows


def _std(values: list) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.std(v, ddof=1)) if len(v) > 1 else None


def _mean(values: list) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.mean(v)) if v else None


def _per_object(row: dict) -> dict:
    po = row["per_object"]
    return {"class_index": np.array(po["class_index"]),
            **{m: np.array([np.nan if x is None else x for x in po[m]], np.float64)
               for m in METRICS}}


def _decide(pairs: list[tuple], by: dict, metrics: tuple[str, ...]) -> dict:
    """Paired comparisons "a has lower error than b" on each metric, and the claim's verdict:
    holds when every comparison holds, reversed when any is reversed, else inconclusive."""
    from benchmark.uncertainty import paired, verdict

    comps = []
    for a, b in pairs:
        if a not in by or b not in by:
            continue
        pa, pb = _per_object(by[a]), _per_object(by[b])
        for m in metrics:
            p = paired(pa[m], pb[m], pa["class_index"])
            if p is None:
                continue
            comps.append({"better": "-".join(a), "than": "-".join(b), "metric": m,
                          "diff": p["diff"], "ci": p["ci"], "half_width": p["half_width"],
                          "verdict": verdict(p["ci"])})
    counts = {v: sum(c["verdict"] == v for c in comps)
              for v in ("holds", "reversed", "inconclusive")}
    if not comps:
        overall = None
    elif counts["holds"] == len(comps):
        overall = "holds"
    elif counts["reversed"]:
        overall = "reversed"
    else:
        overall = "inconclusive"
    return {"verdict": overall, **counts, "of": len(comps), "comparisons": comps,
            "max_half_width": max((c["half_width"] for c in comps), default=None)}


def findings(rows: list[dict]) -> list[dict]:
    """The paper's claims, each decided by paired 95% intervals over the same test objects
    (of per-object errors averaged over seeds); ``verdict`` None when rows are missing."""
    by = {(r["embedding"], r["regime"]): r for r in rows}
    pre = ("basic", "classification", "autoencoder")
    out = [
        {"claim": "graph and token embeddings beat direct (same pretraining, all three metrics)",
         **_decide([((e, r), ("direct", r)) for e in ("graph", "token") for r in pre], by,
                   METRICS)},
        {"claim": "autoencoder pretraining beats classification pretraining and none "
                  "(same embedding, all three metrics)",
         **_decide([((e, "autoencoder"), (e, r)) for e in EMBEDDINGS
                    for r in ("classification", "basic")], by, METRICS)},
        {"claim": "graph + autoencoder is best of the non-Ideal paper rows on all three metrics",
         **_decide([(("graph", "autoencoder"), (e, r)) for e in EMBEDDINGS for r in pre
                    if (e, r) != ("graph", "autoencoder")], by, METRICS)},
        {"claim": "every non-Ideal model falls short of its Ideal model on Variation MSE",
         **_decide([((e, "ideal"), (e, r)) for e in EMBEDDINGS for r in pre], by,
                   ("variation_mse",))},
    ]
    return out


def _num(x, digits: int = 1) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def _cell(mean, std, ci, digits: int = 1) -> str:
    """mean ± std (across seeds) [95% interval of the seed-mean]."""
    if mean is None:
        return "-"
    text = _num(mean, digits) + (f" ± {_num(std, digits)}" if std is not None else "")
    return text + (f" [{_num(ci[0], digits)}, {_num(ci[1], digits)}]" if ci else "")


NO_FINDINGS = ("No findings: this preset is a smoke test (a few test objects, one seed, models "
               "too small to learn); its differences are noise and decide nothing.")


def _digits(metric: str) -> int:
    return 2 if "variation" in metric else 1


def _metric_cells(r: dict, dagger: str, seeds: bool = True) -> str:
    """The five metric cells of a row (the no-skill dagger after Variation MSE); a record
    made before OOD scoring shows "-" for the OOD ones."""
    cells = [_cell(r.get(k), r.get(k + "_std") if seeds else None, r.get(k + "_ci"),
                   _digits(k)) for k in METRICS + OOD_METRICS]
    cells[2] += dagger
    return " | ".join(cells)


def remesher_table(rows: list[dict], references: dict) -> list[str]:
    """Markdown lines: OOD Complex / OOD Variation per remesher for every reference and model
    row (none when no row has OOD meshes)."""
    from basic_shapes.shards import OOD_REMESHERS

    rows = [{**r, "embedding": f"reference: {n}", "pretraining": "-"}
            for n, r in references.items()] + rows
    names = [n for n in OOD_REMESHERS if any(n in r.get("per_remesher", {}) for r in rows)]
    if not names:
        return []
    lines = ["", "### Out-of-distribution meshes per remesher", "",
             "OOD Complex / OOD Variation MSE (dB²) on each remesher's meshes, mean over seeds "
             "[95% interval of the seed-mean].", "",
             "| Embedding | Pretraining | " + " | ".join(f"{n} Complex | {n} Variation"
                                                    for n in names) + " |",
             "|---|---|" + "---:|---:|" * len(names)]
    for r in rows:
        pr = r.get("per_remesher", {})
        cells = [_cell(pr.get(n, {}).get(k), None, pr.get(n, {}).get(k + "_ci"), _digits(k))
                 for n in names for k in OOD_METRICS]
        lines.append(f"| {r['embedding']} | {r['pretraining']} | " + " | ".join(cells) + " |")
    return lines


def render_markdown(table: dict) -> str:
    t = table["timing"]
    lines = [f"# Basic Shapes reproduction: preset `{table['preset']}`", "",
             f"Command: `{table['command']}`", "",
             f"Dataset: {table['dataset']['description']}  ",
             f"fingerprint `{table['dataset']['fingerprint']}`  ",
             f"Hardware: {table['hardware']}; this invocation took "
             f"{t['total_s'] / 60:.1f} min, {t['rows_trained']} (row, seed) runs "
             f"trained and {t['rows_reused']} reused from an earlier run "
             f"(generate {_num(t.get('generate_s'))} s, label "
             f"{_num(t.get('label_s'))} s, rows + timing "
             f"{_num(t['rows_s'])} s, {t['jobs']} job(s) x "
             f"{t['threads_per_job']} thread(s)). ms / mesh: `predict` over the "
             f"test split (first seed), timed with no other job of this run on the CPU.", "",
             f"MSE in dB² on T = 20 log10 max(|profile|, 1e-4), predictions clipped at the same "
             f"-80 dB floor. Model rows: mean ± std across the training seeds "
             f"{table['seeds']} [95% interval of the seed-mean: bootstrap over test objects, "
             f"stratified by class]. `†` marks no skill (not better than the training mean by a "
             f"paired 95% interval, in most seeds). Skill: 1 - Complex MSE / Complex MSE of the "
             f"strongest reference; Δ: the paired difference to it with its 95% interval.", "",
             "OOD Complex / OOD Variation: Complex / Variation MSE on the test objects' "
             "out-of-distribution meshes (remeshers no training mesh comes from; per remesher "
             "below).", "",
             "| Embedding | Pretraining | Training meshes | Simple MSE | Complex MSE | "
             "Variation MSE | OOD Complex | OOD Variation | Skill | Δ Complex vs ref | Params | "
             "ms / mesh | Train s |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, r in table["references"].items():
        lines.append(f"| reference: {name} | - | - | "
                     + _metric_cells(r, " †" if r["no_skill"] else "", seeds=False)
                     + " | - | - | 0 | - | - |")
    for r in table["rows"]:
        sk = (r.get("skill") or {}).get("vs_reference", {})
        key = "complex_mse" if "complex_mse" in sk else "simple_mse"
        v = sk.get(key)
        skill = "-" if v is None or v["skill"] is None else f"{v['skill']:+.2f}"
        delta = "-" if v is None else f"{v['diff']:+.1f} [{v['ci'][0]:+.1f}, {v['ci'][1]:+.1f}]"
        lines.append(f"| {r['embedding']} | {r['pretraining']} | {r['training_meshes']} | "
                     + _metric_cells(r, " †" if r["no_skill"] else "")
                     + f" | {skill} | {delta} | {r['params']:,} | "
                     f"{_num(r['ms_per_mesh'], 2)} | {_num(r['train_seconds'], 0)} |")
    strongest = table.get("strongest_reference")
    if strongest:
        lines += ["", f"Strongest reference: `{strongest}` (lowest Complex MSE)."]
    lines += remesher_table(table["rows"], table["references"])
    lines += ["", "## The paper's findings on this table", ""]
    if not table["findings"]:
        lines.append(table.get("no_findings", NO_FINDINGS))
    for f in table["findings"]:
        mark = f["verdict"] or "not tested (rows missing)"
        hw = "" if f["max_half_width"] is None else \
            f"; largest paired 95% half-width {f['max_half_width']:.2f} dB²"
        lines.append(f"- {f['claim']}: **{mark}** ({f['holds']} hold, {f['reversed']} reversed, "
                     f"{f['inconclusive']} inconclusive of {f['of']}{hw})")
        for c in f["comparisons"]:
            lines.append(f"  - {c['better']} < {c['than']} on {c['metric']}: Δ {c['diff']:+.2f} "
                         f"[{c['ci'][0]:+.2f}, {c['ci'][1]:+.2f}] (±{c['half_width']:.2f}): "
                         f"{c['verdict']}")
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path, title: str, references: dict | None = None) -> None:
    """Speed against error: ms per mesh (log) vs Complex MSE with its interval, one point per
    row; the strongest reference as a horizontal line (it costs nothing to run)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    markers = {"basic": "o", "classification": "s", "autoencoder": "^", "ideal": "*"}
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for r in rows:
        if r["ms_per_mesh"] is None or r["complex_mse"] is None:
            continue
        ci = r.get("complex_mse_ci")
        if ci:
            ax.errorbar(r["ms_per_mesh"], r["complex_mse"], fmt="none", ecolor="0.6",
                        yerr=[[r["complex_mse"] - ci[0]], [ci[1] - r["complex_mse"]]])
        ax.scatter(r["ms_per_mesh"], r["complex_mse"], c=REGISTRY[r["embedding"]].colour,
                   marker=markers[r["regime"]], s=80 if r["regime"] == "ideal" else 45,
                   edgecolors="black" if r["no_skill"] else "none", zorder=3)
        ax.annotate(r["name"], (r["ms_per_mesh"], r["complex_mse"]), fontsize=7,
                    xytext=(4, 3), textcoords="offset points")
    for name, ref in (references or {}).items():
        if ref.get("complex_mse") is not None:
            ax.axhline(ref["complex_mse"], color="0.5", lw=0.8, ls="--")
            ax.annotate(f"reference: {name}", (0.01, ref["complex_mse"]), fontsize=6,
                        xycoords=("axes fraction", "data"), color="0.4")
    ax.set_xscale("log")
    ax.set_xlabel("ms per mesh (inference, including featurization)")
    ax.set_ylabel("Complex MSE (dB², 95% interval)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    plt.close(fig)


def write_outputs(out: Path, table: dict, with_plot: bool = True) -> None:
    with atomic_path(out / "table.json") as tmp:
        tmp.write_text(json.dumps(table, indent=1, sort_keys=True, allow_nan=False) + "\n")
    with atomic_path(out / "table.md") as tmp:
        tmp.write_text(render_markdown(table))
    if with_plot:
        plot(table["rows"], out / "speed_vs_error.png",
             f"Basic Shapes, preset {table['preset']}: speed vs error", table["references"])


# --- CLI --------------------------------------------------------------------------------------
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--preset", choices=tuple(PRESETS), required=True,
                        help="; ".join(f"{k}: dataset {v.dataset}, {len(v.seeds)} seed(s), "
                                       f"{v.expected}" for k, v in PRESETS.items()))
    parser.add_argument("--out", required=True, help="output directory (table.md, table.json, "
                        "speed_vs_error.png, checkpoints/, results/, data/)")
    parser.add_argument("--data", help="reuse this labelled dataset instead of generating one")
    parser.add_argument("--seeds", help="comma-separated training seeds (default: the preset's)")
    parser.add_argument(
        "--rows",
        help="comma-separated subset of rows, e.g. graph-basic,graph-ideal "
        f"(default: all {len(ROWS)})",
    )
    parser.add_argument("--shapenet", help="pretrain on a local ShapeNetCore v2 directory")
    parser.add_argument("--nproc", type=number(int, minimum=1, maximum=1024), default=None,
                        help="GPUs for torchrun (paper preset; default: all visible)")
    parser.add_argument("--workers", type=number(int, minimum=0, maximum=1024), default=None,
                        help="runs trained at once in worker processes (default: the preset's; "
                        "0 or 1 = one at a time in this process; 1 on GPU)")
    parser.add_argument("--threads", type=number(int, minimum=1, maximum=1024), default=None,
                        help="torch threads per worker (default: CPU cores / workers)")
    parser.add_argument("--overwrite", action="store_true",
                        help="retrain runs that are already done")
    add_quiet_flag(parser)


def _rows(spec: str | None) -> list[tuple[str, str]]:
    if not spec:
        return list(ROWS)
    known = {f"{e}-{r}": (e, r) for e, r in ROWS}
    bad = [s for s in spec.split(",") if s not in known]
    if bad:
        raise SystemExit(f"benchmark reproduce: unknown row(s) {', '.join(bad)}; "
                         f"known: {', '.join(known)}")
    return [known[s] for s in spec.split(",")]


def _seeds(spec: str | None, preset: Preset) -> list[int]:
    if not spec:
        return list(preset.seeds)
    try:
        seeds = [int(x) for x in spec.split(",")]
    except ValueError:
        raise SystemExit(f"benchmark reproduce: --seeds must be comma-separated integers, "
                         f"got {spec!r}") from None
    if len(set(seeds)) != len(seeds) or any(x < 0 for x in seeds):
        raise SystemExit(f"benchmark reproduce: --seeds must be distinct and >= 0, got {spec!r}")
    return seeds


_WORKER: dict = {}
COST = {"ideal": 4.0, "classification": 2.0, "autoencoder": 1.5, "basic": 1.0}


def _start_worker(threads: int, fingerprint: str, corpus_path: str | None,
                  pretrain_cfg=None) -> None:
    """Process-pool initializer: a torch thread budget, a feature cache and the pretraining
    corpus (the procedural corpus file, or ShapeNet as ``pretrain_cfg`` says), once per worker."""
    import torch

    from benchmark import corpus as corpus_mod
    from benchmark.train import FeatureCache, corpus_meshes

    torch.set_num_threads(threads)
    _WORKER.update(cache=FeatureCache(), device=torch.device("cpu"), fingerprint=fingerprint)
    if corpus_path:
        _WORKER["corpus"] = (corpus_mod.load_corpus_file(corpus_path), list(corpus_mod.FAMILIES))
    elif pretrain_cfg is not None:
        _WORKER["corpus"] = corpus_meshes(pretrain_cfg)


def _row_job(cfg, data_dir: Path, out: Path, preset: Preset) -> tuple[object, dict]:
    record = run_row(cfg, data_dir, out, preset, _WORKER, 1, progress=False,
                     log=lambda line: print(line, flush=True))
    return cfg, record


def run(args: argparse.Namespace) -> None:
    """``benchmark reproduce``: dataset -> corpus -> every (row, seed) -> table, JSON, plot."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    import torch

    from benchmark import corpus as corpus_mod
    from benchmark import references
    from benchmark.data import BenchmarkData
    from benchmark.evaluate import hardware

    t_start = time.perf_counter()
    preset = PRESETS[args.preset]
    rows = _rows(args.rows)
    seeds = _seeds(args.seeds, preset)
    jobs = preset.jobs if args.workers is None else max(1, args.workers)
    threads = args.threads or max(1, (os.cpu_count() or 1) // jobs)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    timing: dict = {}
    if args.data:
        data_dir = Path(args.data)
    else:
        data_dir = out / "data"
        timing.update(make_dataset(preset, data_dir, args.quiet))
    try:
        with BenchmarkData(data_dir) as data:
            fingerprint, description = data.fingerprint, data.describe()
            _, ref_scorers = references.reference_scores(data)
    except (ShardError, ValueError) as exc:
        raise SystemExit(f"benchmark reproduce: {exc}") from None
    ref_rows = {n: references.summary(sc) for n, sc in ref_scorers.items()}
    nproc = args.nproc or max(torch.cuda.device_count(), 1)
    cfgs = [row_config(preset, e, r, s, args.shapenet) for e, r in rows for s in seeds]
    corpus_path = None
    pretrained = [c for c in cfgs if c.regime in ("classification", "autoencoder")]
    shapenet_cfg = pretrained[0] if pretrained and args.shapenet else None
    if pretrained and not args.shapenet:
        t0 = time.perf_counter()
        tc = preset.train
        corpus_path = str(corpus_mod.build_corpus_file(
            out / "corpus.h5", tc["pretrain_meshes"], 0, tc["pretrain_max_faces"],
            progress=not args.quiet))
        timing["corpus_s"] = time.perf_counter() - t0
    records: dict[str, dict[int, dict]] = {}
    todo = []
    for cfg in cfgs:
        done = None if args.overwrite else _finished(out, cfg, fingerprint)
        if done is None:
            todo.append(cfg)
        else:
            print(f"{job_name(cfg)}: reusing the finished run in {out}")
            records.setdefault(cfg.name, {})[cfg.seed] = done
    t_rows = time.perf_counter()

    def write(with_plot: bool = False) -> None:
        write_outputs(out, _table(args, preset, seeds, records, fingerprint, description,
                                  {**timing, "rows_s": time.perf_counter() - t_rows,
                                   "total_s": time.perf_counter() - t_start, "jobs": jobs,
                                   "threads_per_job": threads, "rows_trained": len(todo),
                                   "rows_reused": len(cfgs) - len(todo)},
                                  hardware(threads)["text"], ref_scorers, ref_rows), with_plot)

    def finished(cfg, result) -> None:
        records.setdefault(cfg.name, {})[cfg.seed] = result
        write()

    if jobs > 1 and len(todo) > 1:
        # Runs are independent: a pool of single-threaded workers keeps both cores busy
        # without OpenMP threads of one process waiting on each other; costly rows first.
        todo.sort(key=lambda c: (-COST[c.regime] * REGISTRY[c.embedding].cost,
                                 c.seed))
        with ProcessPoolExecutor(
            jobs,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_start_worker,
            initargs=(threads, fingerprint, corpus_path, shapenet_cfg),
        ) as pool:
            futures = [pool.submit(_row_job, cfg, data_dir, out, preset) for cfg in todo]
            for k, fut in enumerate(as_completed(futures)):
                cfg, result = fut.result()
                print(f"{job_name(cfg)}: done ({result['wall_seconds']:.0f} s), "
                      f"{k + 1}/{len(todo)} runs")
                finished(cfg, result)
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        if todo and not (jobs > 1 and len(todo) > 1):
            _start_worker(threads, fingerprint, corpus_path, shapenet_cfg)
            _WORKER["device"] = torch.device("cuda" if torch.cuda.is_available() else "cpu")
            for cfg in todo:
                result = run_row(cfg, data_dir, out, preset, _WORKER, nproc, not args.quiet)
                if cfg.seed == seeds[0]:
                    _mark_timed_alone(out, cfg, result, result["results"]["speed"]["ms_per_mesh"],
                                      threads)
                finished(cfg, result)
        firsts = [(c, records[c.name][c.seed]) for c in cfgs if c.seed == seeds[0]]
        time_alone(out, data_dir, firsts, threads, progress=not args.quiet)
    finally:
        torch.set_num_threads(previous)
        _WORKER.clear()
    for e, r in rows:
        publish_row(out, f"{e}-{r}", seeds)
    write(with_plot=True)
    table = json.loads((out / "table.json").read_text())
    print(render_markdown(table))
    print(f"table, JSON and plot in {out}")


def _table(args, preset: Preset, seeds: list[int], records: dict, fingerprint: str,
           description: str, timing: dict, hw: str, ref_scorers: dict, ref_rows: dict) -> dict:
    from benchmark import references

    command = f"benchmark reproduce --preset {args.preset} --out {args.out}"
    for flag in ("data", "rows", "shapenet", "seeds"):
        if getattr(args, flag):
            command += f" --{flag} {getattr(args, flag)}"
    rows = table_rows(records, ref_scorers, ref_rows)
    table = {"preset": args.preset, "command": command, "preset_config": asdict(preset),
             "dataset": {"fingerprint": fingerprint, "description": description,
                         "version": preset.dataset},
             "seeds": seeds, "hardware": hw, "python": platform.python_version(),
             "timing": timing, "references": ref_rows,
             "strongest_reference": references.strongest(ref_rows), "rows": rows,
             "findings": findings(rows) if preset.findings else []}
    if not preset.findings:
        table["no_findings"] = NO_FINDINGS
    return table


__all__ = ["PRESETS", "ROWS", "Preset", "add_arguments", "findings", "run"]
