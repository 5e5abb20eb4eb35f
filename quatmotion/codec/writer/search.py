"""The quality search: which pass a build's settings ask for (:func:`encode_step`): a ``ratio``
target (the quality knob bisected until the file fits, then verified), a bound the method
cannot aim at itself (four quality steps, the smallest file after repair kept), or one pass.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from quatmotion.codec.writer.spool import Coded, Job


def _search_ratio(job: Job, ratio: float, size_of: Callable[[Coded], int]) -> tuple[float, Coded]:
    """The smallest quality knob (best fidelity) whose file fits ``source / ratio``: doubling
    or halving until the target is bracketed, then geometric bisection."""
    method, scans = job.method, job.inputs.scans
    target = sum(s.source[0] or s.text_bytes for s in scans) / ratio
    # the sizes below are measured with zeros for the declared errors, which deflate better
    # than the final values: keep room for their 8 bytes per clip
    target -= 8 * len(scans) + 8
    fits: set[float] = set()
    best: tuple[float, Coded] | None = None  # the smallest quality that fits, kept
    too_big: set[float] = set()
    q = method.default_quality
    try:
        for _ in range(24):
            coded = job.encode(q, None, verify=False)
            if size_of(coded) <= target:
                fits.add(q)
                if best is None or q < best[0]:
                    if best is not None:
                        best[1].close()
                    best = (q, coded)
                else:
                    coded.close()
            else:
                too_big.add(q)
                coded.close()
            smallest_fit = min(fits, default=None)
            largest_miss = max(
                (b for b in too_big if smallest_fit is None or b < smallest_fit), default=None
            )
            if smallest_fit is None:
                q *= 2.0
            elif largest_miss is None:
                q /= 2.0
            elif smallest_fit / largest_miss < 1.06:
                break
            else:
                q = float(np.sqrt(smallest_fit * largest_miss))
    except BaseException:
        if best is not None:
            best[1].close()
        raise
    if best is None:
        raise ValueError(f"no setting of {method.name} reaches ratio {ratio:g}")
    return best


def encode_step(job: Job, size_of: Callable[[Coded], int]) -> tuple[float, Coded]:
    """Fit, encode, verify and repair, by the settings' target: a ratio (search the quality
    knob, then verify), a bound the method cannot aim at itself (try four quality steps and
    keep the smallest file after repair), or one pass."""
    codec, settings = job.method, job.settings
    q = settings.quality if settings.quality is not None else codec.default_quality
    max_error = settings.max_error
    if settings.ratio is not None:
        q, coded = _search_ratio(job, settings.ratio, size_of)
        return q, job.verify(coded, None)
    if max_error is not None and not codec.controls_bound and settings.quality is None:
        best: tuple[int, float, Coded] | None = None
        try:
            for scale in (1.0, 0.5, 0.25, 0.125):
                coded = job.encode(q * scale, max_error, verify=True)
                size = size_of(coded)
                if best is None or size < best[0]:
                    if best is not None:
                        best[2].close()
                    best = (size, q * scale, coded)
                else:
                    coded.close()
        except BaseException:
            if best is not None:
                best[2].close()
            raise
        assert best is not None
        return best[1], best[2]
    return q, job.encode(q, max_error, verify=True)
