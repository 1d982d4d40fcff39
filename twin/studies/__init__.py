"""Monte Carlo noise studies and algorithm benchmarks (``twin study``).

:mod:`.spec` reads and validates a study file, :mod:`.trials` runs one trial as a pure function
of (study, cell, trial), :mod:`.runner` runs every trial on a process pool or a Dask cluster and
streams the results to Parquet (resumable), :mod:`.report` writes the Markdown report and plot.
"""

from twin.studies.spec import Study, load_study

__all__ = ["Study", "load_study"]
