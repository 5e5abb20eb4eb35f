"""Writing ASF and AMC text (:func:`write_asf`, :func:`asf_text`, :func:`write_amc`,
:func:`amc_channel_values`), atomically; the conventions are :mod:`quatmotion.io.asf_amc`'s.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from quatmotion import quat
from quatmotion.io._text import (
    atomic_write,
    decompose_channels,
)
from quatmotion.io.asf_amc.asf import ROTATION_DOFS, asf_names
from quatmotion.motion import Motion, Skeleton


def _g(value: float) -> str:
    return f"{value:.10g}"


def write_asf(skeleton: Skeleton, path: str | Path) -> None:
    """Write a skeleton read from an ASF back to an ASF file (atomically).

    The bones, units, ids, limits and hierarchy come from ``skeleton.extras`` (see the module
    docstring), so a read-write trip reproduces the file's content.

    Parameters
    ----------
    skeleton : Skeleton
        Read with :func:`read_asf` (``extras["format"] == "asf"``); ``ValueError`` otherwise.
    path : str or Path
    """
    atomic_write(path, asf_text(skeleton))


def asf_text(skeleton: Skeleton) -> str:
    """The ASF text :func:`write_asf` writes for ``skeleton`` (read from an ASF)."""
    names = asf_names(skeleton, "write_asf")
    ex = skeleton.extras
    out = [f":version {ex['asf_version']}", f":name {ex['asf_name'] or skeleton.name}", ":units"]
    out += [f"  {k} {v}" for k, v in ex["asf_units"]]
    if ex["asf_documentation"]:
        out.append(":documentation")
        out += [f"  {d}" for d in ex["asf_documentation"]]
    root = ex["asf_root"]
    out += [
        ":root",
        f"   order {' '.join(root['order'])}",
        f"   axis {root['axis'].upper()}",
        f"   position {' '.join(_g(v) for v in root['position'])}",
        f"   orientation {' '.join(_g(v) for v in root['orientation'])}",
        ":bonedata",
    ]
    for bone in ex["asf_bones"]:
        out.append("  begin")
        if bone["id"] is not None:
            out.append(f"     id {bone['id']}")
        out.append(f"     name {names[bone['name']]}")
        out.append(f"     direction {' '.join(_g(v) for v in bone['direction'])}")
        out.append(f"     length {_g(bone['length'])}")
        out.append(
            f"     axis {' '.join(_g(v) for v in bone['axis'])} {bone['axis_order'].upper()}"
        )
        if bone["dof"]:
            out.append(f"    dof {' '.join(bone['dof'])}")
        for k, (lo, hi) in enumerate(bone["limits"]):
            out.append(f"    {'limits ' if k == 0 else '       '}({lo} {hi})")
        out += [f"     {o}" for o in bone["other"]]
        out.append("  end")
    out += [":hierarchy", "  begin"]
    out += [f"    {' '.join(names[n] for n in h)}" for h in ex["asf_hierarchy"]]
    out += ["  end", ""]
    return "\n".join(out)


def amc_channel_values(
    motion: Motion, degrees: bool = True
) -> tuple[list[str], list[int], NDArray[np.float64]]:
    """The AMC values of every frame of a motion on an ASF skeleton.

    Parameters
    ----------
    motion : Motion
        On a skeleton read with :func:`read_asf` (``ValueError`` otherwise).
    degrees : bool
        Angles in degrees (else radians).

    Returns
    -------
    names : list of str
        ``"root"`` then the bones with dofs, in ASF file order.
    counts : list of int
        Number of values of each.
    values : ndarray, shape (T, sum(counts))
        File units: angles in degrees (or radians), root translation in ASF length units
        (relative to the root ``position``); ``l`` dofs are 0.
    """
    sk = motion.skeleton
    renamed = asf_names(sk, "write_amc")
    to_deg = 180.0 / np.pi if degrees else 1.0
    to_cm = sk.extras["length_scale"]
    T = motion.n_frames
    names = ["root"] + [renamed[b["name"]] for b in sk.extras["asf_bones"] if b["dof"]]
    dofs = {renamed[b["name"]]: b["dof"] for b in sk.extras["asf_bones"]}
    dofs["root"] = sk.channels[0]
    counts = [len(dofs[n]) for n in names]
    values = np.zeros((T, sum(counts)))
    c = sk.axes
    local_m = quat.multiply(quat.multiply(quat.conjugate(c), motion.rotations), c)
    groups: dict[str, tuple[list[int], list[list[int]]]] = {}
    column = 0
    for bone in names:
        letters = ""
        columns = []
        for k, d in enumerate(dofs[bone]):
            if d in ROTATION_DOFS:
                letters += ROTATION_DOFS[d]
                columns.append(column + k)
            elif d in ("tx", "ty", "tz"):
                axis = "xyz".index(d[1])
                values[:, column + k] = (
                    motion.root_translation[:, axis] - sk.offsets[0, axis]
                ) / to_cm
        column += len(dofs[bone])
        if letters:
            joints, cols = groups.setdefault(letters, ([], []))
            joints.append(0 if bone == "root" else sk.index(bone))
            cols.append(columns)
    for letters, (joints, cols) in groups.items():
        values[:, cols] = decompose_channels(local_m[:, joints], letters, intrinsic=False) * to_deg
    return names, counts, values


def write_amc(motion: Motion, path: str | Path) -> None:
    """Write a motion on an ASF skeleton as an AMC file (atomically), angles in degrees.

    Only the AMC is written; write the skeleton with :func:`write_asf` if it is needed too.
    Values are written with 10 significant digits (far below 1e-4 degree); each joint's
    angles are extracted for exactly its dofs (principal range: a file's angles within
    ``(-180, 180]``, the middle of three within ``[-90, 90]``, come back unchanged).

    Parameters
    ----------
    motion : Motion
        On a skeleton read with :func:`read_asf` (``ValueError`` otherwise).
    path : str or Path
    """
    names, counts, values = amc_channel_values(motion)
    frame_format = "%d\n" + "".join(
        f"{n}{' %.10g' * c}\n" for n, c in zip(names, counts, strict=True)
    )
    T = motion.n_frames
    table = np.concatenate((np.arange(1, T + 1, dtype=np.float64)[:, None], values), axis=1)
    header = "#!OML:ASF written by quatmotion\n:FULLY-SPECIFIED\n:DEGREES\n"
    body = (frame_format * T) % tuple(table.ravel().tolist()) if T else ""
    atomic_write(path, header + body)
