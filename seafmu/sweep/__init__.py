"""Sweeps and Monte Carlo studies over a scenario, run on Dask (``seafmu sweep STUDY.yaml``).

- ``study``: the study file (schema, one-line errors) and its cases: grids and lists crossed,
  distributions sampled by Latin hypercube or Sobol (``scipy.stats.qmc``) or for Sobol indices
  (SALib), seeds; every case is a ``--set`` list validated as ``seafmu run`` would validate it.
- ``worker``: one case in a worker process (the same ``load_scenario`` and master as ``seafmu run``).
- ``execute``: the local ``dask.distributed`` cluster (or an existing scheduler), the study folder
  (one row file per finished case: a rerun skips them), Ctrl-C, the progress bar, ``cases.parquet``.
- ``analysis`` and ``report``: pass rates with confidence intervals, distributions, sensitivity,
  worst cases with the command that reproduces each one; Markdown + PNG.
"""
