"""Leaderboard: verified Basic Shapes results -> a static site and a Markdown board.

``submit`` re-scores a predictions file against the dataset (nothing from a submission is
executed) and writes one JSON entry per accepted submission into a folder of the repository,
so that publishing a result is a pull request. ``render`` turns the entries into a static
site (sortable table, per-class breakdown, speed-vs-error chart, example predictions) and a
Markdown board; ``serve`` previews the site. This package never imports bpy.
"""

from leaderboard.store import DEFAULT_ENTRIES, EntryError, load_entries

__all__ = ["DEFAULT_ENTRIES", "EntryError", "load_entries"]
