"""The presets of ``benchmark reproduce`` and the rows of the paper's table.

A preset names a dataset version and a model/training size that fit a time budget; the rows
derive from the embedding registry (``training.models.REGISTRY``), so adding an embedding adds
its rows. Why the presets are sized as they are: ``PRESETS`` and docs/RESULTS.md.
"""

from __future__ import annotations

from dataclasses import dataclass

from basic_shapes.infra import FlagError
from benchmark.training.models import FACE_EMBEDDINGS, REGISTRY

ROWS: tuple[tuple[str, str], ...] = (  # the paper's face encoders: pretrained, with an Ideal row
    *[(e, r) for e in FACE_EMBEDDINGS for r in ("basic", "classification", "autoencoder")],
    *[(e, "ideal") for e in FACE_EMBEDDINGS],
    *[(e, "basic") for e in REGISTRY if e not in FACE_EMBEDDINGS],
)
PRETRAINING = {
    "basic": "none",
    "classification": "classification",
    "autoencoder": "autoencoder",
    "ideal": "none",
}


@dataclass(frozen=True)
class Preset:
    """A dataset version and a model/training size that fit a time budget."""

    dataset: str  # a registered version (benchmark.scoring.versions), built unless --data is given
    train: dict  # TrainConfig fields
    workers: int | None  # Dask workers for generate/label (0: in-process, None: per core)
    jobs: int = 1  # rows trained at once, in separate single-threaded processes (CPU)
    launcher: str = "inprocess"  # or "torchrun" (one process per GPU, DDP)
    expected: str = ""
    seeds: tuple[int, ...] = (0, 1, 2)  # training seeds per row (mean ± std across them)
    findings: bool = True  # False: too small to decide any claim (the table says why)
    timing_passes: int = 3  # ms / mesh: the fastest of these passes (``runner.time_alone``)


SMALL_MODEL = dict(
    dim=32,
    embed_layers=2,
    agg_layers=1,
    n_heads=2,
    decoder_hidden=256,
    codebook_size=64,
    pretrain_meshes=1500,
    pretrain_epochs=8,
    pretrain_max_faces=400,
)
"""CPU-sized models: complex meshes reach ~4000 faces; one aggregator layer (computed for the
CLS token alone, so linear in the faces), two heads, one thread per job with two jobs at once
(two threads per job ran 10-50x slower per step whenever other work shared the 2 cores)."""
PLATEAU = dict(epochs=150, patience=10)
"""Train to the validation plateau (``benchmark.training.train.plateau``), capped at 150 epochs. On
cpu-v1 an epoch of all 14 rows x 3 seeds costs ~150 s of one core (perf/training_speed.py,
scaled from 240 to 1,200 training objects); with pretraining (~9 min), evaluation (~20-50 s
per run) and twice that for two jobs contending, the table takes at most ~7 hours on 2
cores even if every run reaches the cap, about 3.5 without contention. The three rows beyond
the paper (meshgraph, pointcloud, regressor: training steps ~2.1x, 2.7x and 0.7x direct's, on
demo-v2's simple meshes with this model) add about 30% to an epoch of all rows."""

PRESETS = {
    # For the test suite: every row on a few objects, with models too small to learn much.
    "tiny": Preset(
        dataset="tiny-v3",
        workers=0,
        train=dict(
            dim=16,
            embed_layers=1,
            agg_layers=1,
            n_heads=2,
            decoder_hidden=32,
            codebook_size=16,
            epochs=2,
            batch_size=8,
            pretrain_meshes=20,
            pretrain_epochs=1,
            pretrain_max_faces=100,
        ),
        expected="about a minute on 2 CPU cores",
        seeds=(0,),
        findings=False,
        timing_passes=1,  # a smoke test: its speeds decide nothing either
    ),
    # The demo's dataset with the CPU models: a quick look, too few test objects for findings.
    "small": Preset(
        dataset="demo-v3",
        workers=None,
        jobs=2,
        train=dict(SMALL_MODEL, **PLATEAU, batch_size=8),
        expected="about 5 minutes on 2 CPU cores",
        seeds=(0,),
        findings=False,
    ),
    # The CPU benchmark (docs/RESULTS.md): 150 test objects, 3 seeds, paired intervals.
    "cpu": Preset(
        dataset="cpu-v2",
        workers=None,
        jobs=2,
        train=dict(SMALL_MODEL, **PLATEAU, batch_size=16),
        expected="estimated at most 8 hours on 2 CPU cores, less where runs plateau before "
        "the cap (resumable: rerun to continue)",
    ),
    # The paper's scale: 3000 objects x 100 meshes, full radar grid, GPU(s).
    "paper": Preset(
        dataset="paper-v3",
        workers=None,
        train=dict(
            dim=256,
            embed_layers=5,
            agg_layers=6,
            n_heads=8,
            decoder_hidden=1024,
            codebook_size=512,
            epochs=100,
            patience=10,
            batch_size=32,
            pretrain_meshes=20000,
            pretrain_epochs=30,
            pretrain_max_faces=800,
            lr=3e-4,
            pretrain_lr=3e-4,
        ),
        launcher="torchrun",
        expected="12 hours on one H200 GPU for the 13 rows measured with every run at the "
        "epoch cap (docs/RESULTS.md: less where runs plateau, more with the other 4 rows), "
        "and 18 GB of predictions per run; under torchrun each row trains on N GPUs (DDP); "
        "generating and labelling the 300,000 meshes is an estimated 2.4 CPU-hours (a Dask "
        "cluster)",
    ),
}


def rows_of(spec: str | None) -> list[tuple[str, str]]:
    """``--rows``: a comma-separated subset of the rows by name (default: all)."""
    if not spec:
        return list(ROWS)
    known = {f"{e}-{r}": (e, r) for e, r in ROWS}
    bad = [s for s in spec.split(",") if s not in known]
    if bad:
        raise FlagError(f"--rows: unknown row(s) {', '.join(bad)}; known: {', '.join(known)}")
    return [known[s] for s in spec.split(",")]


def seeds_of(spec: str | None, preset: Preset) -> list[int]:
    """``--seeds``: comma-separated distinct training seeds (default: the preset's)."""
    if not spec:
        return list(preset.seeds)
    try:
        seeds = [int(x) for x in spec.split(",")]
    except ValueError:
        raise FlagError(f"--seeds must be comma-separated integers, got {spec!r}") from None
    if len(set(seeds)) != len(seeds) or any(x < 0 for x in seeds):
        raise FlagError(f"--seeds must be distinct and >= 0, got {spec!r}")
    return seeds
