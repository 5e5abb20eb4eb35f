"""How a ``.qmz`` library is made: one settings object, validated once, stored in the file.

:class:`CompressSettings` is what :meth:`quatmotion.codec.Archive.build` takes, what the
command line and the server pass whole, and what ``ls`` prints back from a file (format
version 2 stores its JSON in the header).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from numbers import Integral, Real
from typing import Any, ClassVar

from quatmotion._settings import Interval, Settings, StrOptions
from quatmotion.codec.methods import METHODS
from quatmotion.collection import ReadSettings

__all__ = ["DEFAULT_MAX_ERROR_CM", "FIT_SAMPLE_CLIPS", "CompressSettings"]

DEFAULT_MAX_ERROR_CM = 1.0
"""The bound used when none is given: every joint within 1 cm."""

FIT_SAMPLE_CLIPS = 256
"""Most clips of one skeleton structure its shared model is learned on; a larger library
learns on a seeded sample of this many and encodes every clip with it."""


@dataclass(frozen=True)
class CompressSettings(Settings):
    """How clips are compressed into a ``.qmz`` library.

    Attributes
    ----------
    max_error : float or None
        Bound on the position error of every joint and end site of every frame, centimetres
        (default :data:`DEFAULT_MAX_ERROR_CM`). The encoder checks by decoding and repairs what
        exceeds it. None with ``ratio`` None: no bound (``quality`` alone sets the size).
    ratio : float or None
        Target compression ratio against the source text (or the writers' text for clips given
        in memory) instead of a bound: give ``max_error=None`` with it.
    method : {"best", "spline", "naive", "qssd", "ksvd"}
    quality : float or None
        The method's size knob (its quantiser step; larger means smaller files). With
        ``max_error`` it caps the step the rate control may use (``best``, ``spline``) or fixes
        it (the others; without it they try their default and 1/2, 1/4, 1/8 of it and keep the
        smallest file after repair). None: the method's default.
    bound_on : {"joints", "vertices"}
        What ``max_error`` bounds: joint and end-site positions, or also the virtual vertices
        3 cm along each joint's axes (the Animation Compression Library's measure).
    seed : int
        Seed of every random choice (the fitting sample, dictionary initialisation): same
        input and seed, same bytes.
    on_error : {"raise", "skip"}
        What a file that cannot be read, or a clip that cannot be stored, does: stop (nothing
        is written), or be left out and listed in the report's failures.
    fit_sample : int
        Most clips of one skeleton structure the shared model is learned on
        (:data:`FIT_SAMPLE_CLIPS`; a seeded sample of a larger library).
    read : ReadSettings
        How the clips are read (BVH unit, AMC skeleton, strictness).
    """

    max_error: float | None = DEFAULT_MAX_ERROR_CM
    ratio: float | None = None
    method: str = "best"
    quality: float | None = None
    bound_on: str = "joints"
    seed: int = 0
    on_error: str = "raise"
    fit_sample: int = FIT_SAMPLE_CLIPS
    read: ReadSettings = field(default_factory=ReadSettings)

    _parameter_constraints: ClassVar[dict[str, list[Any]]] = {
        "max_error": [None, Interval(Real, 0, None, closed="neither")],
        "ratio": [None, Interval(Real, 1, None, closed="neither")],
        "method": [StrOptions(set(METHODS))],
        "quality": [None, Interval(Real, 0, None, closed="neither")],
        "bound_on": [StrOptions({"joints", "vertices"})],
        "seed": [Interval(Integral, 0, None, closed="left")],
        "on_error": [StrOptions({"raise", "skip"})],
        "fit_sample": [Interval(Integral, 1, None, closed="left")],
        "read": [ReadSettings],
    }

    def _check(self) -> None:
        if self.max_error is not None and self.ratio is not None:
            raise ValueError(
                "give max_error or ratio, not both (ratio replaces the bound: max_error=None)"
            )
