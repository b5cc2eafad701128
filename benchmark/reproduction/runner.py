"""Running the (row, seed) jobs of ``benchmark reproduce``: their configs, the output layout,
resume, the process pool, timing each row alone and publishing rows for the board.

Every (row, seed) already finished with the same configuration on the same dataset is reused
(``_finished``), so a killed run resumes where it stopped. The layout under ``--out``:
``checkpoints/<row>/seed-<s>/`` (model.pt, config.json), ``results/<row>/seed-<s>/``
(results.json, predictions.h5) and ``results/<row>/`` (the row as the board takes it).
"""

from __future__ import annotations

import math
import os
import re
import sys
import time
from dataclasses import asdict, fields
from pathlib import Path

from basic_shapes.infra import atomic_path, load_json
from benchmark.reproduction.presets import Preset
from benchmark.training.models import REGISTRY
from benchmark.training.models.checkpoint import (
    CONFIG_MAX_BYTES,
    plateau_record,
    training_record,
)

COST = {"ideal": 4.0, "classification": 2.0, "autoencoder": 1.5, "basic": 1.0}
"""Relative training time per regime (times the embedding's ``cost``): within a seed, costly
runs go first."""
TIMED_ALONE = "timed alone"
TIMING_MESHES = 480
"""Test meshes (about) that ``time_alone`` times per row."""
_WORKER: dict = {}


# --- configs and layout -----------------------------------------------------------------------
def row_config(preset: Preset, embedding: str, regime: str, seed: int, shapenet: str | None):
    from benchmark.training.train import TrainConfig

    return TrainConfig(
        embedding=embedding, regime=regime, seed=seed, shapenet=shapenet, **preset.train
    )


def job_name(cfg) -> str:
    return f"{cfg.name}/seed-{cfg.seed}"


def row_files(out: Path, name: str, seed: int | None = None) -> tuple[Path, Path]:
    """(results JSON, predictions HDF5) of a row's seed (``results/<row>/seed-<s>/``) or,
    with ``seed`` None, of the row as the board takes it (``results/<row>/``: the first
    seed's files, the layout that ``leaderboard seed --from <out>/results`` submits)."""
    d = out / "results" / name / ("" if seed is None else f"seed-{seed}")
    return d / "results.json", d / "predictions.h5"


def checkpoint_dir(out: Path, name: str, seed: int) -> Path:
    return out / "checkpoints" / name / f"seed-{seed}"


# --- resume -----------------------------------------------------------------------------------
def trained(out: Path, cfg, fingerprint: str) -> dict | None:
    """The checkpoint config of a (row, seed) trained earlier with this exact config on
    this dataset."""
    try:
        ck = load_json(
            checkpoint_dir(out, cfg.name, cfg.seed) / "config.json", max_bytes=CONFIG_MAX_BYTES
        )
    except (OSError, ValueError):
        return None
    if (
        not isinstance(ck, dict)
        or ck.get("train") != asdict(cfg)
        or ck.get("dataset_fingerprint") != fingerprint
    ):
        return None
    return ck


def _finished(out: Path, cfg, fingerprint: str) -> dict | None:
    """The results of a (row, seed) finished earlier with this exact config on this dataset."""
    from benchmark.scoring.protocol import ResultsError, load_results

    ck = trained(out, cfg, fingerprint)
    results_path, predictions_path = row_files(out, cfg.name, cfg.seed)
    try:
        results = load_results(results_path)
    except (OSError, ValueError, ResultsError):
        return None
    if (
        ck is None
        or results["dataset_fingerprint"] != fingerprint
        or not predictions_path.is_file()
        or "per_object" not in results
    ):
        return None
    return {"results": results, "train_seconds": ck.get("train_seconds"), **plateau_record(ck)}


def resume(cfgs: list, out: Path, fingerprint: str, overwrite: bool) -> tuple[list, dict]:
    """(the configs still to run, records of the finished ones by row name and seed)."""
    records: dict[str, dict[int, dict]] = {}
    todo = []
    for cfg in cfgs:
        done = None if overwrite else _finished(out, cfg, fingerprint)
        if done is None:
            todo.append(cfg)
        else:
            print(f"{job_name(cfg)}: reusing the finished run in {out}")
            records.setdefault(cfg.name, {})[cfg.seed] = done
    return todo, records


# --- one run ----------------------------------------------------------------------------------
def pretraining_corpus(
    cfgs: list, out: Path, preset: Preset, shapenet: str | None, progress: bool, fingerprint: str
) -> tuple[str | None, object]:
    """What the pretrained rows still to train pretrain on, built once for all of them: (the
    procedural corpus file written in ``out``, None), or (None, the config that names
    ShapeNet); nothing where every one was trained (released weights: evaluation only)."""
    from benchmark.training import corpus as corpus_mod

    pretrained = [
        c
        for c in cfgs
        if c.regime in ("classification", "autoencoder") and trained(out, c, fingerprint) is None
    ]
    if not pretrained:
        return None, None
    if shapenet:
        return None, pretrained[0]
    tc = preset.train
    return str(
        corpus_mod.build_corpus_file(
            out / "corpus.h5", tc["pretrain_meshes"], 0, tc["pretrain_max_faces"], progress=progress
        )
    ), None


def _train_flags(cfg) -> list[str]:
    flags = []
    for f in fields(cfg):
        value = getattr(cfg, f.name)
        if value is not None:
            flags += [f"--{f.name.replace('_', '-')}", str(value)]
    return flags


def run_tool(cmd: list[str], what: str) -> None:
    """Run a toolkit CLI in a child process (torchrun); its one-line error becomes ours."""
    import subprocess

    result = subprocess.run(cmd, stderr=subprocess.PIPE, text=True)
    if result.returncode != 0:
        tail = (result.stderr or "").strip().splitlines()
        raise ValueError(
            f"{what} failed: {tail[-1] if tail else 'exit code ' + str(result.returncode)}"
        )


def run_row(
    cfg,
    data_dir: Path,
    out: Path,
    preset: Preset,
    shared: dict,
    nproc: int,
    progress: bool,
    log=None,
) -> dict:
    """Train (in-process or under torchrun) and evaluate one (row, seed); return its record."""
    from benchmark.training import resume
    from benchmark.training.models.checkpoint import save_checkpoint
    from benchmark.training.train import evaluate_checkpoint, train

    ckpt = checkpoint_dir(out, cfg.name, cfg.seed)
    t0 = time.perf_counter()
    earlier = trained(out, cfg, shared["fingerprint"])
    if earlier is not None:  # trained earlier, evaluation missing or interrupted
        train_seconds = earlier["train_seconds"]
    elif preset.launcher == "torchrun" and nproc > 1:
        run_tool(
            [
                sys.executable,
                "-m",
                "torch.distributed.run",
                f"--nproc_per_node={nproc}",
                "-m",
                "benchmark.cli",
                "train",
                "--data",
                str(data_dir),
                "--out",
                str(ckpt),
                "--quiet",
                *_train_flags(cfg),
            ],
            f"training {job_name(cfg)}",
        )
        train_seconds = load_json(ckpt / "config.json", max_bytes=CONFIG_MAX_BYTES)["train_seconds"]
    else:
        from benchmark.scoring.data import BenchmarkData

        with BenchmarkData(data_dir) as data:
            model, config = train(
                cfg,
                data,
                cache=shared["cache"],
                corpus=shared.get("corpus"),
                device=shared["device"],
                progress=progress,
                log=log,
                resume=ckpt / resume.FILE,
            )
        save_checkpoint(ckpt, model, config)
        (ckpt / resume.FILE).unlink(missing_ok=True)
        train_seconds = config["train_seconds"]
    results_path, predictions_path = row_files(out, cfg.name, cfg.seed)
    results = evaluate_checkpoint(
        ckpt,
        data_dir,
        results_path,
        progress,
        device=shared["device"],
        predictions=predictions_path,
    )
    config = load_json(ckpt / "config.json", max_bytes=CONFIG_MAX_BYTES)
    return {
        "results": results,
        "train_seconds": train_seconds,
        "wall_seconds": time.perf_counter() - t0,
        **plateau_record(config if isinstance(config, dict) else {}),
    }


# --- many runs --------------------------------------------------------------------------------
def _start_worker(
    threads: int, fingerprint: str, corpus_path: str | None, pretrain_cfg=None
) -> None:
    """Process-pool initializer: a torch thread budget, a feature cache and the pretraining
    corpus (the procedural corpus file, or ShapeNet as ``pretrain_cfg`` says), once per worker."""
    import torch

    from benchmark.training import corpus as corpus_mod
    from benchmark.training.train import FeatureCache, corpus_meshes

    torch.set_num_threads(threads)
    _WORKER.update(cache=FeatureCache(), device=torch.device("cpu"), fingerprint=fingerprint)
    if corpus_path:
        _WORKER["corpus"] = (corpus_mod.load_corpus_file(corpus_path), list(corpus_mod.FAMILIES))
    elif pretrain_cfg is not None:
        _WORKER["corpus"] = corpus_meshes(pretrain_cfg)


def _row_job(
    cfg, data_dir: Path, out: Path, preset: Preset, progress: bool = True
) -> tuple[object, dict]:
    """One pooled run. Its progress is a line per epoch, not a bar: the workers train at once
    and share one terminal, where their bars would overwrite each other."""
    record = run_row(
        cfg,
        data_dir,
        out,
        preset,
        _WORKER,
        1,
        progress=False,
        log=(lambda line: print(line, flush=True)) if progress else None,
    )
    return cfg, record


def run_jobs(
    cfgs: list,
    todo: list,
    records: dict,
    *,
    data_dir: Path,
    out: Path,
    preset: Preset,
    fingerprint: str,
    corpus: tuple[str | None, object],
    first_seed: int,
    jobs: int,
    threads: int,
    nproc: int,
    progress: bool,
    done,
) -> None:
    """Run every config of ``todo`` and call ``done(cfg, record)`` after each (which adds it
    to ``records``); then re-time the first seed (``first_seed``) of every row of ``cfgs``
    that was not timed alone.

    With several jobs, runs are independent: a pool of single-threaded workers keeps every
    core busy without OpenMP threads of one process waiting on each other. Seeds go in
    order, costly rows first within a seed, so that a long run stopped anywhere (a session's
    end) leaves every row with the same finished seeds, which paired intervals need. Else
    one at a time in this process. Either way speed is measured afterwards by ``time_alone``
    (the evaluation's own pass is one pass, its first batch included).
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    import torch

    pooled = jobs > 1 and len(todo) > 1
    if pooled:
        todo = sorted(todo, key=lambda c: (c.seed, -COST[c.regime] * REGISTRY[c.embedding].cost))
        with ProcessPoolExecutor(
            jobs,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_start_worker,
            initargs=(threads, fingerprint, *corpus),
        ) as pool:
            futures = [pool.submit(_row_job, cfg, data_dir, out, preset, progress) for cfg in todo]
            for k, fut in enumerate(as_completed(futures)):
                cfg, result = fut.result()
                if progress:
                    print(
                        f"{job_name(cfg)}: done ({result['wall_seconds']:.0f} s), "
                        f"{k + 1}/{len(todo)} runs",
                        flush=True,
                    )
                done(cfg, result)
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        if todo and not pooled:
            _start_worker(threads, fingerprint, *corpus)
            _WORKER["device"] = torch.device("cuda" if torch.cuda.is_available() else "cpu")
            for cfg in todo:
                done(cfg, run_row(cfg, data_dir, out, preset, _WORKER, nproc, progress))
        firsts = [(c, records[c.name][c.seed]) for c in cfgs if c.seed == first_seed]
        time_alone(out, data_dir, firsts, threads, preset.timing_passes, progress=progress)
    finally:
        torch.set_num_threads(previous)
        _WORKER.clear()


def _mark_timed_alone(out: Path, cfg, record: dict, ms_per_mesh: float, threads: int, how: str):
    """Store a speed measured with no other job of this run on the CPU, and say so and
    ``how``."""
    from benchmark.scoring.evaluate import speed_block
    from benchmark.scoring.protocol import write_results

    speed = speed_block(ms_per_mesh, threads)
    speed["hardware"] += f"; {TIMED_ALONE} {how}"
    record["results"]["speed"] = speed
    write_results(row_files(out, cfg.name, cfg.seed)[0], record["results"])


def time_alone(
    out: Path,
    data_dir: Path,
    jobs: list[tuple],
    threads: int,
    passes: int = 3,
    progress: bool = True,
) -> None:
    """Time the first seed of every row not yet timed so: ``predict`` in the harness's
    batches, one row at a time, after a warm-up batch, the fastest of ``passes`` passes
    (other processes only ever add time; an evaluation's own pass measures whatever shared
    the CPU); I/O excluded, as in the harness.

    Timed on TIMING_MESHES meshes, every k-th batch of the face-count order (cost grows with
    the faces, so this is a sample stratified by cost): all 2,850 test meshes of cpu-v1 would
    take 13 rows x 2-5 min of a machine that must stay otherwise idle."""
    import torch
    from tqdm import tqdm

    from benchmark.scoring.data import BenchmarkData
    from benchmark.scoring.evaluate import face_count_batches
    from benchmark.scoring.protocol import scored_mesh_rows
    from benchmark.training.models.checkpoint import CheckpointModel

    todo = [(cfg, r) for cfg, r in jobs if not _timed(r, passes)]
    if not todo:
        return
    device = "cuda" if torch.cuda.is_available() else "cpu"
    with BenchmarkData(data_dir) as data:
        chunks = face_count_batches(data, scored_mesh_rows(data), 16)
        step = max(1, len(chunks) * 16 // TIMING_MESHES)
        batches = [data.batch(chunk) for chunk in chunks[step // 2 :: step]]
    n = sum(len(b["faces"]) for b in batches)
    how = f"on {n} test meshes, fastest of {passes} pass(es) after a warm-up"
    for cfg, record in tqdm(todo, desc="timing", unit="row", disable=not progress):
        model = CheckpointModel(checkpoint_dir(out, cfg.name, cfg.seed), device=device)
        model.predict(batches[0])
        fastest = math.inf
        for _ in range(passes):
            t0 = time.perf_counter()
            for batch in batches:
                model.predict(batch)
            fastest = min(fastest, time.perf_counter() - t0)
        _mark_timed_alone(out, cfg, record, 1000.0 * fastest / n, threads, how)


def _timed(record: dict, passes: int) -> bool:
    """Timed alone with at least ``passes`` passes (older records: one pass)."""
    found = re.search(r"fastest of (\d+) pass", record["results"]["speed"].get("hardware") or "")
    return found is not None and int(found[1]) >= passes


def publish_row(out: Path, name: str, seeds: list[int]) -> None:
    """``results/<row>/``: the first seed's predictions and results (naming every seed, with
    every seed's validation curve), for ``leaderboard seed``; hard-linked where the file
    system allows, else copied."""
    import shutil

    from benchmark.scoring.protocol import load_results, write_results

    src_results, src_preds = row_files(out, name, seeds[0])
    dst_results, dst_preds = row_files(out, name)
    with atomic_path(dst_preds) as tmp:
        try:
            os.link(src_preds, tmp)
        except OSError:
            shutil.copyfile(src_preds, tmp)
    results = load_results(src_results)
    results["seeds"]["train_all"] = list(seeds)
    configs = [checkpoint_dir(out, name, s) / "config.json" for s in seeds]
    training = training_record(
        [load_json(c, max_bytes=CONFIG_MAX_BYTES) if c.is_file() else {} for c in configs]
    )
    results.pop("training", None)
    if training:
        results["training"] = training
    write_results(dst_results, results)
