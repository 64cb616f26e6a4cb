"""Parallel, resumable grids of experiment configs: the grid (``grid``), the content-addressed
result store (``store``), where tasks run (``backends``) and the sweep itself (``run``)."""
