"""Pictures of what quatmotion computes: figures, the 3D viewer page and the benchmark report.

* :mod:`quatmotion.viz.figures`: the one place that makes and saves matplotlib figures (the
  Agg backend, atomic PNG output).
* :mod:`quatmotion.viz.viewer`: the standalone 3D viewer page (three.js, vendored), built on
  the compact clip payloads of :mod:`quatmotion.viz.frame_data`, which a web server reuses;
  :mod:`quatmotion.viz.framing` says which points of a clip are the body (followed, drawn).
* :mod:`quatmotion.viz.report`: one standalone page gathering benchmark results.
"""

from quatmotion.viz.figures import pyplot, save_figure
from quatmotion.viz.report import write_report
from quatmotion.viz.viewer import view_data, write_view

__all__ = ["pyplot", "save_figure", "view_data", "write_report", "write_view"]
