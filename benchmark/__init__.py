"""Benchmark: how much a neural physics simulator is fooled by mesh topology.

Readers, metrics and the evaluation protocol are torch-free; only training code and the
torch Dataset import torch (lazily), so that scoring a predictions file never needs it.
"""

__version__ = "0.1.0"
