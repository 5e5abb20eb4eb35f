"""The one interface every codec implements: encode a collection, decode a clip."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quatmotion.codec.container import FORMAT_VERSION
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
    version: int = FORMAT_VERSION
    """The file's format version (a method decodes the payload of each version it wrote)."""


@dataclass(frozen=True)
class CodingOptions:
    """What a method aims at when it learns a layout's model (:meth:`Method.fit_layout`) and
    codes a clip (:meth:`Method.encode_clip`)."""

    quality: float
    """The method's quality knob (its quantiser step; larger means smaller payloads)."""
    max_error: float | None
    """The bound the encoder aims at, cm (None: none)."""
    seed: int = 0
    """Seed of the fitting's random choices (coding a clip makes none)."""


class Method(ABC):
    """A codec. Subclasses set :attr:`name` and implement :meth:`fit_layout`,
    :meth:`model_bytes`, :meth:`encode_clip`, :meth:`load_model` and :meth:`decode`.

    ``quality`` is each method's one size knob (larger gives smaller files and larger errors);
    ``None`` means the method's default. ``max_error`` (cm) is passed to methods that control
    the bound themselves; the orchestrator checks every method's output and repairs what still
    exceeds the bound.
    """

    name: str = ""
    default_quality: float = 1.0

    controls_bound: bool = False
    """Whether :meth:`encode_clip` meets ``max_error`` itself (else the orchestrator searches
    ``quality`` and repairs)."""

    def fit_models(
        self,
        library: PreparedLibrary,
        members: list[list[int]],
        *,
        quality: float,
        max_error: float | None,
        seed: int,
        models: list[Any] | None = None,
    ) -> list[Any]:
        """The encoder's model of every layout, learned on the clips ``members[k]`` of layout
        ``k`` (all of them, or a sample). ``models`` holds, per layout, a model already in the
        file (appending: returned unchanged) or ``None`` (fit one); a layout without members
        gets ``None``."""
        given = list(models or [])
        options = CodingOptions(quality, max_error, seed)
        out: list[Any] = []
        for k in range(len(library.layouts)):
            if k < len(given) and given[k] is not None:
                out.append(given[k])
            elif members[k]:
                out.append(self.fit_layout(library, k, members[k], options))
            else:
                out.append(None)
        return out

    @abstractmethod
    def fit_layout(
        self, library: PreparedLibrary, k: int, members: list[int], options: CodingOptions
    ) -> Any:
        """Layout ``k``'s model learned on the clips ``members`` (at least one)."""

    @abstractmethod
    def model_bytes(self, model: Any, layout: LayoutInfo) -> bytes:
        """The ``L`` chunk's model part of a model from :meth:`fit_models`."""

    @abstractmethod
    def encode_clip(
        self, library: PreparedLibrary, i: int, model: Any, options: CodingOptions
    ) -> bytes:
        """Clip ``i``'s payload, given its layout's model from :meth:`fit_models`. Pure: it
        reads only clip ``i``, its layout and ``model``, so clips may be coded in any order or
        in other processes with the same bytes."""

    @abstractmethod
    def load_model(self, data: bytes, layout: LayoutInfo) -> Any:
        """Parse a layout's model bytes once (the result is cached by the reader)."""

    @abstractmethod
    def decode(self, model: Any, payload: bytes, context: ClipContext) -> NDArray[np.float64]:
        """A clip's channels ``(T, C)`` (inactive channels may hold anything)."""

    def upgrade_payload(self, model: Any, payload: bytes, context: ClipContext) -> bytes:
        """A payload of format ``context.version`` in :data:`FORMAT_VERSION`, decoding to the
        same channels (appending to an older file rewrites it in the current version). A
        method whose payload no version changed returns it as it is."""
        return payload
