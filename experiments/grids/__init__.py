"""One grid file per experiment of the study (SPEC section 7); see :mod:`experiments.grid`."""
