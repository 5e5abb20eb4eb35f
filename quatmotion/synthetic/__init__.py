"""Generated motion for tests, benchmarks and the demo: seeded procedural clips of labelled kinds.

A layer of its own above :mod:`quatmotion.io` (the generator builds skeletons the readers build
and writes clips the readers read back), below everything that tests or measures with it.
"""

from quatmotion.synthetic.motions import *  # noqa: F403
from quatmotion.synthetic.motions import __all__  # noqa: F401
