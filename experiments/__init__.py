"""Experiments of the study as data: grid files, a launcher, aggregation, plots and reports.

``python -m experiments run GRID --scale quick`` (or ``make sweep GRID=... SCALE=...``) runs a
grid's configurations x seeds as ``python -m dqn_mine.train`` subprocesses under
``results/<grid>/<config>/seed<k>/`` and writes ``summary.csv``, ``report.md`` and PNG plots.
"""
