"""The one interface every codec implements: encode a collection, decode a clip."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quatmotion.codec.library import LayoutInfo, PreparedLibrary
from quatmotion.motion import Skeleton

__all__ = ["ClipContext", "EncodedLibrary", "Method"]


@dataclass(frozen=True)
class EncodedLibrary:
    """What a method writes: one model per layout (``L`` chunks, after the shared part) and
    one payload per clip (``C`` chunks, after the shared part)."""

    models: list[bytes]
    clips: list[bytes]


@dataclass(frozen=True)
class ClipContext:
    """What the decoder of one clip knows from the header and the shared layout part."""

    layout: LayoutInfo
    skeleton: Skeleton
    n_frames: int
    fps: float
    active: NDArray[np.bool_]
    """Which of the layout's channels the clip codes (translation joints at rest are not)."""


class Method(ABC):
    """A codec. Subclasses set :attr:`name` and implement the three methods.

    ``quality`` is each method's one size knob (larger gives smaller files and larger errors);
    ``None`` means the method's default. ``max_error`` (cm) is passed to methods that control
    the bound themselves; the orchestrator checks every method's output and repairs what still
    exceeds the bound.
    """

    name: str = ""
    default_quality: float = 1.0

    controls_bound: bool = False
    """Whether :meth:`encode` meets ``max_error`` itself (else the orchestrator searches
    ``quality`` and repairs)."""

    @abstractmethod
    def encode(
        self,
        library: PreparedLibrary,
        *,
        quality: float,
        max_error: float | None,
        seed: int,
        models: list[Any] | None = None,
    ) -> EncodedLibrary:
        """Code every clip of ``library``. ``models`` holds, per layout, a model already in the
        file (appending: use it unchanged) or ``None`` (fit one); the returned models of given
        layouts are ignored."""

    @abstractmethod
    def load_model(self, data: bytes, layout: LayoutInfo) -> Any:
        """Parse a layout's model bytes once (the result is cached by the reader)."""

    @abstractmethod
    def decode(self, model: Any, payload: bytes, context: ClipContext) -> NDArray[np.float64]:
        """A clip's channels ``(T, C)`` (inactive channels may hold anything)."""
