"""Sampling poses of a ``.qmz`` clip at arbitrary times: the archive's side of the runtime's
:class:`~quatmotion.runtime.sampler.Sampler` (see :mod:`quatmotion.runtime.sampler` for the
conventions: clamp and loop, the spline between frames, the corrections).

A clip's rows (:meth:`~quatmotion.codec.archive.ArchiveReader.clip_rows`: a spline method's
control points, no frame evaluated) are decoded on its first sample and kept by the archive
(the last few clips sampled) for later samples.
"""

from __future__ import annotations

from quatmotion.runtime.sampler import MODES, ClipSampler, Sampler

__all__ = ["MODES", "ClipSampler", "Sampler", "sampler_for"]

_CACHED_CLIPS = 16


def sampler_for(archive, clip: int | str) -> ClipSampler:
    """The archive's sampler of ``clip``, decoded on first use (the last few are kept)."""
    cache = archive._samplers
    if type(clip) is int and clip in cache:  # the path of every later sample of a clip
        cache.move_to_end(clip)
        return cache[clip]
    i = archive.index_of(clip)
    sampler = cache.get(i)
    if sampler is None:
        sampler = ClipSampler(archive.clip_rows(i, lazy=True), archive.rig(i))
        cache[i] = sampler
        if len(cache) > _CACHED_CLIPS:
            cache.popitem(last=False)
    else:
        cache.move_to_end(i)
    return sampler
