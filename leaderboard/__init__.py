"""Leaderboard: verified Basic Shapes results -> a static site and a Markdown board.

``evaluate-model`` is the ranked track: it runs an ONNX model (data only) with onnxruntime on a
held-out build whose labels are never published, and times it and counts its parameters
itself. ``submit`` is the self-scored track: it re-scores a predictions file against a public
dataset (nothing from a submission is executed). Each writes one JSON entry per accepted
submission into a folder of the repository, so that publishing a result is a pull request.
``render`` turns the entries into a static site (sortable table, per-class breakdown,
speed-vs-error chart, example predictions) and a Markdown board; ``serve`` previews the
site. This package never imports bpy.
"""

from leaderboard.store import DEFAULT_ENTRIES, EntryError, load_entries

__all__ = ["DEFAULT_ENTRIES", "EntryError", "load_entries"]
