"""``benchmark reproduce``: the paper's table, every (embedding, regime) row evaluated by the
harness.

``benchmark reproduce --preset tiny|small|cpu|paper --out DIR`` builds the preset's labelled
dataset version (or reuses ``--data``), the pretraining corpus, trains and evaluates every row
once per training seed of the preset, and writes ``DIR/table.md``, ``DIR/table.json`` and
``DIR/speed_vs_error.png``. This module is the command's wiring: the presets are ``presets``,
the runs (resume, the process pool, timing) ``runner``, and the table ``report``, which
``benchmark report`` rebuilds from the results alone.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from basic_shapes.infra import add_quiet_flag, hardware, number
from benchmark.reproduction import report, runner
from benchmark.reproduction.presets import PRESETS, ROWS, Preset, rows_of, seeds_of

TABLE_EVERY_S = 30.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--preset",
        choices=tuple(PRESETS),
        required=True,
        help="; ".join(
            f"{k}: dataset {v.dataset}, {len(v.seeds)} seed(s), {v.expected}"
            for k, v in PRESETS.items()
        ),
    )
    parser.add_argument(
        "--out",
        required=True,
        help="output directory (table.md, table.json, "
        "speed_vs_error.png, checkpoints/, results/, data/)",
    )
    parser.add_argument("--data", help="reuse this labelled dataset instead of generating one")
    parser.add_argument("--seeds", help="comma-separated training seeds (default: the preset's)")
    parser.add_argument(
        "--rows",
        help="comma-separated subset of rows, e.g. graph-basic,graph-ideal "
        f"(default: all {len(ROWS)})",
    )
    parser.add_argument("--shapenet", help="pretrain on a local ShapeNetCore v2 directory")
    parser.add_argument(
        "--nproc",
        type=number(int, minimum=1, maximum=1024),
        default=None,
        help="GPUs for torchrun (paper preset; default: all visible)",
    )
    parser.add_argument(
        "--workers",
        type=number(int, minimum=0, maximum=1024),
        default=None,
        help="runs trained at once in worker processes (default: the preset's; "
        "0 or 1 = one at a time in this process; 1 on GPU)",
    )
    parser.add_argument(
        "--threads",
        type=number(int, minimum=1, maximum=1024),
        default=None,
        help="torch threads per worker (default: CPU cores / workers)",
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="retrain runs that are already done"
    )
    add_quiet_flag(parser)


def make_dataset(preset: Preset, directory: Path, quiet: bool) -> dict:
    """Build the preset's dataset version (generate + label; both resume). Its
    ``VersionError`` comes after work, so the CLI boundary's exit 1, not a ``FlagError``'s 2."""
    from benchmark.scoring import versions

    return versions.build(
        versions.get(preset.dataset), directory, workers=preset.workers, quiet=quiet
    )


def _command(args: argparse.Namespace) -> str:
    command = f"benchmark reproduce --preset {args.preset} --out {args.out}"
    for flag in ("data", "rows", "shapenet", "seeds"):
        if getattr(args, flag):
            command += f" --{flag} {getattr(args, flag)}"
    return command


def _warn(text: str) -> None:
    print(f"benchmark reproduce: warning: {text}", file=sys.stderr)


def _warn_disk(out: Path, runs: int, per_run: int) -> None:
    """Say at the start when the runs' predictions files (float32, every test mesh) will not
    fit: the paper preset writes 18 GB per run. A full disk stops the run with a one-line
    error and the same command resumes it."""
    free = shutil.disk_usage(out).free
    if runs * per_run > free:
        _warn(
            f"{runs} run(s) will write about {runs * per_run / 1e9:.1f} GB of predictions "
            f"({per_run / 1e9:.2f} GB each) and {out} has {free / 1e9:.1f} GB free"
        )


def run(args: argparse.Namespace) -> None:
    """``benchmark reproduce``: dataset -> corpus -> every (row, seed) -> table, JSON, plot."""
    import torch

    from benchmark.scoring.data import BenchmarkData
    from benchmark.scoring.protocol import scored_mesh_rows

    t_start = time.perf_counter()
    preset = PRESETS[args.preset]
    rows = rows_of(args.rows)
    seeds = seeds_of(args.seeds, preset)
    jobs = preset.jobs if args.workers is None else max(1, args.workers)
    threads = args.threads or max(1, (os.cpu_count() or 1) // jobs)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if preset.launcher == "torchrun" and not torch.cuda.is_available():  # sized for GPUs
        _warn(
            f"the {args.preset} preset is sized for GPUs and none is visible: a training step "
            "that takes 0.05-0.2 s on an H200 takes 7-50 s on a 2-core CPU (docs/RESULTS.md)"
        )
    timing: dict = {}
    if args.data:
        data_dir = Path(args.data)
    else:
        data_dir = out / "data"
        timing.update(make_dataset(preset, data_dir, args.quiet))
    with BenchmarkData(data_dir) as data:
        dataset = report.dataset_info(data, data_dir)
        ref_scorers, ref_rows, oracle = report.reference_rows(data)
        per_run = 4 * len(scored_mesh_rows(data)) * int(np.prod(data.target_shape))
    fingerprint = dataset["fingerprint"]
    cfgs = [runner.row_config(preset, e, r, s, args.shapenet) for e, r in rows for s in seeds]
    if args.overwrite:  # retrain: a run whose checkpoint config is gone trains again
        for cfg in cfgs:
            (runner.checkpoint_dir(out, cfg.name, cfg.seed) / "config.json").unlink(missing_ok=True)
    t0 = time.perf_counter()
    corpus = runner.pretraining_corpus(
        cfgs, out, preset, args.shapenet, not args.quiet, fingerprint
    )
    if corpus[0]:
        timing["corpus_s"] = time.perf_counter() - t0
    todo, records = runner.resume(cfgs, out, fingerprint, args.overwrite)
    saved = sum(runner.trained(out, c, fingerprint) is not None for c in todo)  # evaluated only
    _warn_disk(out, len(todo), per_run)
    t_rows = time.perf_counter()

    def write(with_plot: bool = False) -> None:
        provenance = {
            "command": _command(args),
            "hardware": hardware(threads)["text"],
            "python": platform.python_version(),
            "timing": {
                **timing,
                "rows_s": time.perf_counter() - t_rows,
                "total_s": time.perf_counter() - t_start,
                "jobs": jobs,
                "threads_per_job": threads,
                "rows_trained": len(todo) - saved,
                "rows_evaluated": saved,
                "rows_reused": len(cfgs) - len(todo),
            },
        }
        report.write_outputs(
            out,
            report.build_table(
                args.preset, seeds, records, dataset, ref_scorers, ref_rows, provenance, oracle
            ),
            with_plot,
        )

    written = time.perf_counter()

    def done(cfg, result) -> None:
        """The table follows a long run row by row; rows that take seconds (the tiny preset)
        are tabled together, at most every TABLE_EVERY_S and once at the end."""
        nonlocal written
        records.setdefault(cfg.name, {})[cfg.seed] = result
        if time.perf_counter() - written >= TABLE_EVERY_S:
            write()
            written = time.perf_counter()

    runner.run_jobs(
        cfgs,
        todo,
        records,
        data_dir=data_dir,
        out=out,
        preset=preset,
        fingerprint=fingerprint,
        corpus=corpus,
        first_seed=seeds[0],
        jobs=jobs,
        threads=threads,
        nproc=args.nproc or max(torch.cuda.device_count(), 1),
        progress=not args.quiet,
        done=done,
    )
    for e, r in rows:
        runner.publish_row(out, f"{e}-{r}", seeds)
    write(with_plot=True)
    print((out / "table.md").read_text(), end="")
    print(f"table, JSON and plot in {out}")
