"""A training run's state between epochs, so that a run killed mid-way (a session's end, a
reboot) continues where it stopped and ends with the same bytes as one uninterrupted run.

``benchmark train`` and ``benchmark reproduce`` keep it as ``resume.pt`` beside the checkpoint
and delete it once the checkpoint is written. It holds, for the phase in progress
(``pretrain`` or ``train``): the epochs done, the step, the history, the best epoch's weights,
the task's weights, the optimizer's state and torch's CPU random state (no model draws random
numbers in training today; dropout would); and the histories of the phases already
finished. Loading it unpickles nothing (``torch.load(weights_only=True)``). A state saved under
another ``key`` (another config, dataset, torch or thread count) or one that does not load is
ignored, and the run starts from its first epoch.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import torch

from basic_shapes.infra import atomic_path

FILE = "resume.pt"
"""Its name in a checkpoint directory."""
EVERY_S = 60.0
"""Seconds of training between two saves (and after the last epoch of a phase): a state is a
few copies of the weights (about 100 MB for the CPU preset's models), too much for every
short epoch."""


class Resume:
    """The state file of one run (``path``; None: none, nothing is kept) under its identity
    ``key`` (JSON-able)."""

    def __init__(self, path: str | os.PathLike | None, key: dict | None = None):
        self.path = None if path is None else Path(path)
        self.key = json.dumps(key, sort_keys=True)
        self.state = None if path is None else self._load()
        self.finished: dict[str, list] = dict(self.state["finished"]) if self.state else {}
        done = self.state["seconds"] if self.state else 0.0
        self._t0 = time.perf_counter() - done
        self._saved = time.perf_counter()

    def _load(self) -> dict | None:
        try:
            state = torch.load(self.path, map_location="cpu", weights_only=True)
        except Exception:  # missing, truncated or foreign: start afresh
            return None
        return state if isinstance(state, dict) and state.get("key") == self.key else None

    def seconds(self) -> float:
        """Training time of the run so far, its earlier processes included."""
        return time.perf_counter() - self._t0

    def restore(self, phase: str, task: torch.nn.Module, opt: torch.optim.Optimizer) -> tuple:
        """Load the saved state of ``phase`` (if that phase was in progress) into ``task``,
        ``opt`` and torch's random state; return (epochs done, step, history, best) where best
        is (val MSE, epoch, weights) or None."""
        if self.state is None or self.state["phase"] != phase:
            return 0, 0, [], None
        s = self.state
        task.load_state_dict(s["task"])
        opt.load_state_dict(s["opt"])
        torch.set_rng_state(s["rng"])
        best = s["best"] and (s["best"]["val_mse"], s["best"]["epoch"], s["best"]["task"])
        return s["epoch"], s["step"], s["history"], best

    def save(self, phase, epoch, step, history, best, task, opt, last: bool) -> None:
        """Keep the state after ``epoch`` epochs of ``phase`` if ``EVERY_S`` have passed since
        the last save, or if it is the phase's ``last`` epoch."""
        if self.path is None or (not last and time.perf_counter() - self._saved < EVERY_S):
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        payload = {
            "key": self.key,
            "phase": phase,
            "finished": self.finished,
            "seconds": self.seconds(),
            "rng": torch.get_rng_state(),
            "epoch": epoch,
            "step": step,
            "history": history,
            "best": best and {"val_mse": best[0], "epoch": best[1], "task": best[2]},
            "task": task.state_dict(),
            "opt": opt.state_dict(),
        }
        with atomic_path(self.path) as tmp:
            torch.save(payload, tmp)
        self._saved = time.perf_counter()
