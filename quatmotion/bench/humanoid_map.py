"""Acceptance of the humanoid mapping: the shared skeletons re-rigged to every naming family.

Each shared skeleton (CMU ASF, HDM05 ASF, CMU BVH, Bandai BVH; the first clip of each) is
re-rigged (:func:`quatmotion.synthetic.rerig.rerig`) to every family of
:data:`quatmotion.synthetic.rerig.FAMILIES` in four variants: as the family names it (twist
joints, toes and fingers dropped, right listed first), plain (every joint, file order),
mirrored, and with its names stripped (structure alone). A rig is accepted when its 16
joints are the original's joint for joint (a mirrored rig's left for right) and its 16-joint
positions equal the original's. The counts per family are the acceptance table of issue 31.
Bandai's rest pose lies along X, so structure alone cannot read it: its stripped variant is
reported apart (``structure_only``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from quatmotion._atomic import atomic_write_json
from quatmotion.bench._provenance import provenance

__all__ = ["run"]

VARIANTS: dict[str, dict[str, bool]] = {
    "family": {},
    "plain": {"twist": False, "drop_extremities": False, "reorder": False},
    "mirrored": {"mirror": True},
    "structure_only": {"strip_names": True},
}


def _sources() -> dict[str, Any]:
    from quatmotion import io
    from quatmotion.datasets import catalogue

    out = {}
    for name, collection in (("cmu_asf", "cmu"), ("hdm05", "hdm05"), ("cmu_bvh", "cmu_bvh"),
                             ("bandai", "bandai1")):  # fmt: skip
        entry = catalogue(collection=collection)[0]
        asf = str(entry.skeleton_path) if entry.skeleton_path else None
        out[name] = io.read_motion(str(entry.path), asf).slice(0, 30)
    return out


def accepted(motion: Any, family: str, variant: dict[str, bool]) -> tuple[bool, str]:
    """Whether the re-rigged copy maps joint for joint (and why not)."""
    from quatmotion.motion import JOINTS_16, map_humanoid
    from quatmotion.pose import skeleton16
    from quatmotion.synthetic.rerig import rerig

    mirror = [
        JOINTS_16.index(("R" if n[0] == "L" else "L") + n[1:]) if n[0] in "LR" else k
        for k, n in enumerate(JOINTS_16)
    ]
    original = map_humanoid(motion.skeleton).points
    copy = rerig(motion, family, **variant)
    try:
        mapping = map_humanoid(copy.motion.skeleton)
    except ValueError as error:
        return False, str(error)
    back = {new: old for old, new in copy.renamed.items()}
    got = [back.get(p, p) for p in mapping.points]
    want = [original[mirror[k]] for k in range(16)] if variant.get("mirror") else list(original)
    if variant.get("mirror") and not variant.get("strip_names"):
        want = list(original)  # named sides win: the joint named left is LHip
    if got != want:
        wrong = [
            f"{JOINTS_16[k]}={g}" for k, (g, w) in enumerate(zip(got, want, strict=True)) if g != w
        ]
        return False, "mapped " + ", ".join(wrong)
    if not variant.get("mirror"):
        a = skeleton16.world_positions16(copy.motion)
        b = skeleton16.world_positions16(motion)
        if not np.allclose(a, b, atol=1e-6):
            return False, "positions differ"
    return True, ""


def run(out: Path, quick: bool = False, seed: int = 0) -> dict[str, Any]:
    """Count the accepted re-rigged skeletons per family (module docstring)."""
    from quatmotion.synthetic.rerig import FAMILIES

    sources = _sources()
    table: dict[str, dict[str, Any]] = {}
    failures = []
    for family in FAMILIES:
        row = {}
        for variant, options in VARIANTS.items():
            ok = 0
            for name, motion in sources.items():
                good, why = accepted(motion, family, options)
                ok += good
                if not good:
                    failures.append(f"{family}/{variant}/{name}: {why}")
            row[variant] = f"{ok}/{len(sources)}"
        table[family] = row
    named = sum(
        int(r[v].split("/")[0]) for r in table.values() for v in VARIANTS if v != "structure_only"
    )
    total = len(FAMILIES) * (len(VARIANTS) - 1) * len(sources)
    doc = {
        **provenance("humanoid_map", out, quick, seed),
        "sources": list(sources),
        "per_family": table,
        "failures": failures,
        "headlines": [
            {"name": "named re-rigs mapped joint for joint", "value": f"{named}/{total}"}
        ],
    }
    atomic_write_json(out, doc)
    return doc
