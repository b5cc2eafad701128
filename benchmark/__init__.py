"""Benchmark: how much a neural physics simulator is fooled by mesh topology.

Readers, metrics and the evaluation protocol are torch-free; only training code and the
torch Dataset import torch (lazily), so that scoring a predictions file never needs it.
"""

__version__ = "0.1.0"


def __getattr__(name: str):
    """``benchmark.BasicShapes`` and ``benchmark.Evaluator``, imported on first use."""
    if name == "BasicShapes":
        from benchmark.scoring.data import BasicShapes

        return BasicShapes
    if name == "Evaluator":
        from benchmark.scoring.evaluate import Evaluator

        return Evaluator
    raise AttributeError(f"module 'benchmark' has no attribute {name!r}")
