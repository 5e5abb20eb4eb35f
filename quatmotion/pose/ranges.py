"""The pose library's settings ranges and default metric, in a module of their own so that
the command line states them in its help without importing the library (scikit-learn,
Numba kernels)."""

FPS_RANGE = (1.0, 1000.0)
"""Frame rates (frames per second) the poses of a library can be sampled at."""

DEFAULT_METRIC = "GPDR+LOGIT"
"""The metric ``pose index`` learns when none is named (the registered method measured best;
docs/performance.md)."""
