"""The pose library's settings ranges and defaults, in a module of their own so that the
command line states them in its help and options without importing the library (NumPy,
scikit-learn, Numba kernels): :class:`~quatmotion.pose.library.PoseSettings` reads its
defaults from here, and so does ``quatmotion pose index``."""

from types import MappingProxyType

FPS_RANGE = (1.0, 1000.0)
"""Frame rates (frames per second) the poses of a library can be sampled at."""

DEFAULT_METRIC = "GPDR+LOGIT"
"""The metric ``pose index`` learns when none is named (the registered method measured best;
docs/performance.md)."""

DEFAULTS = MappingProxyType(
    {
        "fps": 30.0,
        "height": 170.0,
        "metric": DEFAULT_METRIC,
        "rank": 50,
        "n_unlabeled": 5000,
        "n_pairs": 500,
        "seed": 0,
        "fit_poses": 20_000,
        "index_threads": 1,
    }
)
"""The defaults of the :class:`~quatmotion.pose.library.PoseSettings` fields the command line
sets (their meaning: its docstring)."""
