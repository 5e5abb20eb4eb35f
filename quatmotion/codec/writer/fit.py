"""Step 4a, fitting: the shared models (:class:`SharedModels`) learned on the planned sample,
sent to every worker once as the batch's context.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from quatmotion.codec.library import LayoutInfo
from quatmotion.codec.methods import Method
from quatmotion.codec.writer.plan import Plan
from quatmotion.collection import (
    ReadSettings,
)


@dataclass(frozen=True)
class SharedModels:
    """What every clip's job shares, sent to each worker once per batch (the batch's context,
    :meth:`quatmotion.parallel.Runner.map`): the layouts and the models learned on the sample.

    Attributes
    ----------
    method : Method
    layouts : list of LayoutInfo
        Every layout of the library (those of the file appended to first).
    models : list
        Per layout, the encoder's model (:meth:`Method.fit_models`).
    decoder_models : list
        Per layout, the same model as the decoder reads it from the file.
    quality : float
    max_error : float or None
        The bound the encoder aims at and the repair enforces (``None``: none).
    vertices : bool
        The bound also covers the virtual vertices.
    read : ReadSettings
        How a worker reads its clip.
    """

    method: Method
    layouts: list[LayoutInfo]
    models: list[Any]
    decoder_models: list[Any]
    quality: float
    max_error: float | None
    vertices: bool
    read: ReadSettings


def fit_shared_models(
    method: Method,
    plan: Plan,
    quality: float,
    max_error: float | None,
    seed: int,
    read: ReadSettings,
) -> tuple[SharedModels, list[bytes]]:
    """The shared models learned on the sample (the models of the file appended to kept), and
    the ``L`` chunks' model bytes (empty for a given model: already in the file)."""
    sample, given = plan.sample, plan.given
    fitted = method.fit_models(
        sample, sample.members, quality=quality, max_error=max_error, seed=seed, models=given
    )
    blobs, decoder_models = [], []
    for k, info in enumerate(sample.layouts):
        if k < len(given) and given[k] is not None:
            blobs.append(b"")  # already in the file
            decoder_models.append(given[k])
        else:
            blob = method.model_bytes(fitted[k], info) if fitted[k] is not None else b""
            blobs.append(blob)
            used = blob or sample.members[k]
            decoder_models.append(method.load_model(blob, info) if used else None)
    models = SharedModels(
        method, sample.layouts, fitted, decoder_models, quality, max_error, sample.vertices, read
    )
    return models, blobs
