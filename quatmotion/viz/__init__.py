"""Pictures of what quatmotion computes: figures for the benchmarks and the demo.

:mod:`quatmotion.viz.figures` is the one place that makes and saves matplotlib figures (the Agg
backend, atomic PNG output). The 3D viewer pages and the benchmark report grow here too.
"""

from quatmotion.viz.figures import pyplot, save_figure

__all__ = ["pyplot", "save_figure"]
