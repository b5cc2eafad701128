"""Scoring: what a submitter and the board need, with numpy and h5py only (no torch).

Dataset readers and versions, metrics, intervals, reference rows, the results schema and the
predictions protocol. tests/test_layout.py keeps it importable with torch blocked.
"""
