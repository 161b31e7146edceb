"""Seeded episodes of a policy on the vector env: summaries, tables, figures, videos."""
