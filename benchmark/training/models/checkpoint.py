"""Checkpoints (state_dict + JSON config) and the protocol adapter that evaluates them.

A checkpoint is a directory: ``model.pt`` holds only tensors (loaded with
``torch.load(weights_only=True)``, so a foreign file cannot run code) and ``config.json``
holds everything needed to rebuild the model and feed it: the ``build_model`` arguments,
the target grid shape and the scale bins used in training.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import torch

from basic_shapes.infra import atomic_path, load_json
from benchmark.scoring.schema import MAX_EPOCHS
from benchmark.training.models import (
    REGISTRY,
    MeshSimulator,
    build_model,
    collate,
    count_parameters,
    featurize,
)

CHECKPOINT_FORMAT = "basic-shapes-checkpoint"
CHECKPOINT_VERSION = 1
WEIGHTS, CONFIG = "model.pt", "config.json"
CONFIG_MAX_BYTES = 16 << 20  # config.json: the config and per-epoch history


def number(v) -> bool:
    """A finite int or float (not a bool): what a config read back may be trusted to hold."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def plateau_record(config: dict) -> dict:
    """``epochs_to_plateau``, ``capped`` and the validation curve (``val_curve``) of a run,
    from its checkpoint config (Nones where absent or malformed: a run without a val split)."""
    chosen = config.get("selection") if isinstance(config.get("selection"), dict) else {}
    history = config.get("history") if isinstance(config.get("history"), dict) else {}
    epochs = history.get("train") if isinstance(history.get("train"), list) else []
    curve = [e.get("val_mse") if isinstance(e, dict) else None for e in epochs[:MAX_EPOCHS]]
    plateau = chosen.get("epochs_to_plateau")
    return {
        "epochs_to_plateau": plateau if number(plateau) else None,
        "capped": chosen.get("capped") if isinstance(chosen.get("capped"), bool) else None,
        "val_curve": curve if curve and all(number(v) for v in curve) else None,
    }


def training_record(configs: list[dict]) -> dict | None:
    """The results' ``training`` block (``schema.TRAINING``) of the runs of one row, one
    checkpoint config per training seed, in seed order: what the board plots as curves;
    None where no run kept a curve (nothing to plot)."""
    runs = [plateau_record(c if isinstance(c, dict) else {}) for c in configs]
    if not any(r["val_curve"] for r in runs):
        return None
    return {
        "val_curves": [r["val_curve"] for r in runs],
        "epochs_to_plateau": [r["epochs_to_plateau"] for r in runs],
        "capped": [r["capped"] for r in runs],
    }


class CheckpointError(ValueError):
    """A checkpoint directory is missing, foreign or inconsistent."""


def save_checkpoint(directory: str | os.PathLike, model: MeshSimulator, config: dict) -> Path:
    """Write ``model.pt`` and ``config.json`` atomically; ``config`` must hold "model"
    (``build_model`` kwargs including ``name``), "target_shape" and "scale_bins"."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    missing = {"model", "target_shape", "scale_bins"} - set(config)
    if missing:
        raise ValueError(f"checkpoint config lacks {sorted(missing)}")
    config = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "params": count_parameters(model),
        **config,
    }
    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    with atomic_path(directory / WEIGHTS) as tmp:
        torch.save(state, tmp)
    with atomic_path(directory / CONFIG) as tmp:
        tmp.write_text(json.dumps(config, indent=1, sort_keys=True))
    return directory


def load_checkpoint(
    directory: str | os.PathLike, map_location: str | torch.device = "cpu"
) -> tuple[MeshSimulator, dict]:
    """Rebuild the model of a checkpoint directory (eval mode) and return it with its config."""
    directory = Path(directory)
    config = load_json(directory / CONFIG, max_bytes=CONFIG_MAX_BYTES, error=CheckpointError)
    if not isinstance(config, dict) or config.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{directory / CONFIG}: not a {CHECKPOINT_FORMAT} config")
    kwargs = dict(config["model"])
    model = build_model(kwargs.pop("name"), **kwargs)
    try:
        state = torch.load(directory / WEIGHTS, map_location=map_location, weights_only=True)
        model.load_state_dict(state)
    except Exception as exc:
        raise CheckpointError(
            f"{directory / WEIGHTS}: cannot load weights "
            f"({exc.__class__.__name__}: {str(exc).splitlines()[0]})"
        ) from None
    return model.eval(), config


class CheckpointModel:
    """A trained checkpoint behind the benchmark's model protocol (``predict(batch)``).

    ``batch`` is the protocol batch (``benchmark.scoring.data.BenchmarkData.batch``): lists of
    normalized ``vertices`` and ``faces`` plus ``scale_m``. The scale bins are recomputed
    from ``scale_m`` with the bins stored in the checkpoint, so the model is always fed the
    discretization it was trained with.
    """

    def __init__(
        self,
        checkpoint: str | os.PathLike,
        device: str = "cpu",
        batch_size: int | str = 16,
        max_tokens: int | str = 16384,
    ):
        """Arguments may be strings (``benchmark evaluate --model-arg KEY=VALUE``).
        Meshes are run in sub-batches of similar face count, at most ``batch_size`` meshes
        and ``max_tokens`` padded faces each (padding a 12-face cube to a 6000-face sphere
        costs as much as the sphere)."""
        from benchmark.scoring.data import ScaleBins

        self.model, self.config = load_checkpoint(checkpoint, device)
        self.device, self.batch_size = torch.device(device), int(batch_size)
        self.max_tokens = int(max_tokens)
        self.model.to(self.device)
        self.scale_bins = ScaleBins(**self.config["scale_bins"])
        self.target_shape = tuple(self.config["target_shape"])
        self.needs = REGISTRY[self.config["model"]["name"]].needs
        self.name = self.config.get("name", self.config["model"]["name"])
        self.embedding = self.config.get("embedding", self.config["model"]["name"])
        self.regime = self.config.get("regime")
        self.params = count_parameters(self.model)

    def _chunks(self, n_faces: list[int]) -> list[list[int]]:
        order = sorted(range(len(n_faces)), key=lambda i: n_faces[i])
        chunks: list[list[int]] = []
        for i in order:
            if (
                chunks
                and len(chunks[-1]) < self.batch_size
                and (len(chunks[-1]) + 1) * n_faces[i] <= self.max_tokens
            ):
                chunks[-1].append(i)
            else:
                chunks.append([i])
        return chunks

    @torch.no_grad()
    def predict(self, batch: dict) -> np.ndarray:
        """(B, n_aspect, n_roll, n_range) float32 predicted dB target."""
        scale = np.asarray(batch["scale_m"], np.float64).reshape(-1, 3)
        bins = self.scale_bins.index(scale)
        items = [featurize(v, f, self.needs) for v, f in zip(batch["vertices"], batch["faces"])]
        out = np.empty((len(items), int(np.prod(self.target_shape))), np.float32)
        for chunk in self._chunks([it.n_faces for it in items]):
            sub = collate([items[i] for i in chunk], scale_bin=bins[chunk], scale_m=scale[chunk])
            pred, _ = self.model(sub.to(self.device))
            out[chunk] = pred.float().cpu().numpy()
        return out.reshape(-1, *self.target_shape)
