"""The paper's reproduction: presets, the row runs, the table and its report."""
