"""Step 3, planning: the clips grouped by layout, a seeded sample of at most ``fit_sample`` clips
of each read in the caller and the layouts fitted on it (:func:`plan_library`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from quatmotion.codec.channels import layout_key
from quatmotion.codec.library import LayoutInfo, PreparedLibrary, prepare_library
from quatmotion.codec.settings import CompressSettings
from quatmotion.codec.writer.runner import Progress
from quatmotion.codec.writer.scan import Inputs
from quatmotion.collection import (
    read_clip,
)


@dataclass
class Plan:
    """The library planned from the scans: every clip's layout, and the sample the layouts
    and the shared models are learned on (read in the caller: at most ``fit_sample`` clips of
    each layout)."""

    layout_of: list[int]
    sample: PreparedLibrary
    given: list[Any]


def plan_library(
    inputs: Inputs,
    existing: Sequence[tuple[LayoutInfo, Any]],
    settings: CompressSettings,
    vertices: bool,
    report: Progress,
) -> Plan:
    """Group the clips by layout (the existing layouts first, then new ones in order of first
    appearance), draw the seeded sample of each layout (all of its clips up to
    ``fit_sample``), read the sample and fit the new layouts on it
    (:func:`~quatmotion.codec.library.prepare_library`)."""
    keys = [layout_key(info.skeleton) for info, _ in existing]
    layout_index = {key: k for k, key in reversed(list(enumerate(keys)))}  # first one wins
    layout_of = []
    for scan in inputs.scans:
        if scan.key not in layout_index:
            layout_index[scan.key] = len(keys)
            keys.append(scan.key)
        layout_of.append(layout_index[scan.key])
    members: list[list[int]] = [[] for _ in keys]
    for i, k in enumerate(layout_of):
        members[k].append(i)
    rng = np.random.default_rng(settings.seed)
    given = [model for _, model in existing]
    chosen: list[int] = []
    for k, group in enumerate(members):
        if len(group) > settings.fit_sample:
            group = sorted(int(i) for i in rng.choice(group, settings.fit_sample, replace=False))
        if k >= len(given) or given[k] is None:
            chosen.extend(group)
    chosen.sort(key=lambda i: (layout_of[i], i))
    report("prepare", 0, len(chosen))
    motions = []
    for n, i in enumerate(chosen, 1):
        motion = read_clip(inputs.sources[i], settings.read).motion
        name = inputs.scans[i].name
        motions.append(motion if motion.name == name else motion.renamed(name))
        if n == len(chosen) or n % 16 == 0:
            report("prepare", n, len(chosen))
    sample = prepare_library(
        motions,
        [inputs.scans[i].source for i in chosen],
        [info for info, _ in existing],
        vertices=vertices,
    )
    if len(sample.layouts) != len(keys):  # a bug of this module
        raise RuntimeError(f"{len(sample.layouts)} layouts fitted for {len(keys)}")
    return Plan(layout_of, sample, given)
