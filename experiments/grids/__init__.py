"""One grid file per experiment of the study; see :mod:`experiments.grid`."""
