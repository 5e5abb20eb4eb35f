"""Reading glTF 2.0 (:func:`read_gltf`, :func:`parse_gltf`): the joints, their rest pose and
one animation sampled at its frame rate, over :class:`~quatmotion.io.gltf.document.Document`;
the conventions are :mod:`quatmotion.io.gltf`'s.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quatmotion import limits, quat
from quatmotion.errors import FormatError
from quatmotion.io._text import read_bytes
from quatmotion.io.gltf.document import Document, is_index, is_object, read_document
from quatmotion.io.gltf.spec import wxyz
from quatmotion.io.units import length_unit
from quatmotion.motion import Motion, Skeleton


def read_gltf(
    path: str | Path, animation: str | int | None = None, *, units: str | float | None = None
) -> Motion:
    """Read the skeleton and one animation of a glTF 2.0 file.

    Parameters
    ----------
    path : str or Path
        ``.glb`` or ``.gltf``: its buffers embedded, or in files inside its folder (a relative
        ``uri`` that stays there once symbolic links are followed; anything else is refused).
    animation : str, int or None
        The animation's name or position; None takes the first.
    units : str, float or None
        A length unit replacing the metre (a name of :data:`quatmotion.io.units.LENGTH_UNITS`
        or cm per file unit): for files written in the wrong unit. Kept with
        ``extras["length_unit_given"] = True``.

    Returns
    -------
    Motion
        Centimetres; ``joint_translations`` when joints other than the root have translation
        channels. A file without animations gives a clip of no frames.

    Raises
    ------
    FormatError
        Naming the file and the field: not glTF 2.0, indices out of range, accessors of the
        wrong type or out of their buffer, a buffer outside the file's folder, counts, frame
        rates or durations over :func:`quatmotion.limits.current`, no such animation.
    """
    path = Path(path)
    return parse_gltf(read_bytes(path), path, animation, units=units, folder=path.parent)


def parse_gltf(
    data: bytes,
    path: str | Path,
    animation: str | int | None = None,
    *,
    units: str | float | None = None,
    folder: str | Path | None = None,
) -> Motion:
    """:func:`read_gltf` of the bytes of a file. ``path`` names it in messages and is not
    opened; ``folder`` is where buffers in other files may be read from (the file's own folder,
    for a file on disk). Without one (an upload), a buffer in another file is refused."""
    path = Path(path)
    limits.check("file_bytes", len(data), path, "the file's size")
    document, chunk = read_document(data, path)
    version = document.get("asset", {}).get("version") if is_object(document.get("asset")) else None
    if not (isinstance(version, str) and version.startswith("2.")):
        raise FormatError(f"asset.version is {version!r}: only glTF 2.0 is read", path)
    reader = _Reader(
        document,
        chunk,
        path,
        None if units is None else length_unit(units),
        None if folder is None else Path(folder),
    )
    return reader.motion(animation)


class _Reader(Document):
    """The skeleton and one animation read from a :class:`Document`."""

    # --- structure ----------------------------------------------------------------------------

    def joints(self) -> tuple[list[int], list[int], list[int], list[int]]:
        """Joint nodes parents first, their parents (joint positions), end-site nodes and their
        joints."""
        nodes = self.nodes
        if not nodes:
            raise self.fail("the file holds no nodes")
        children = [
            self.indices(node, "children", len(nodes), f"nodes[{n}]")
            for n, node in enumerate(nodes)
        ]
        parent_of: dict[int, int] = {}
        for n, kids in enumerate(children):
            for child in kids:
                if child in parent_of:
                    raise self.fail(f"nodes[{child}] has two parents")
                parent_of[child] = n
        skins = self.objects(self.document, "skins", "")
        if skins:
            members = set(self.indices(skins[0], "joints", len(nodes), "skins[0]"))
            if not members:
                raise self.fail("skins[0].joints is empty")
        else:
            scenes = self.objects(self.document, "scenes", "")
            roots: list[int] = []
            if scenes:
                scene = self.index(
                    {"scene": 0, **self.document}, "scene", len(scenes), "", "scenes"
                )
                roots = self.indices(scenes[scene], "nodes", len(nodes), f"scenes[{scene}]")
            roots = [r for r in roots if nodes[r].get("mesh") is None] or roots
            if not roots:
                raise self.fail("no skin and no scene nodes: no skeleton to read")
            members = set()
            stack = roots[:1]
            while stack:
                n = stack.pop()
                if n not in members and nodes[n].get("mesh") is None and children[n]:
                    members.add(n)
                    stack.extend(children[n])
        limits.check("joints", len(members), self.path, "the skeleton's joints")
        roots = [j for j in members if parent_of.get(j) not in members]
        if len(roots) != 1:
            raise self.fail(
                f"the skeleton has {len(roots)} root joints (nodes {sorted(roots)[:5]}); "
                "one is read"
            )
        order: list[int] = []
        parents: list[int] = []
        sites: list[int] = []
        site_parents: list[int] = []
        stack = [(roots[0], -1)]
        while stack:
            n, parent = stack.pop()
            if n in members:
                order.append(n)
                parents.append(parent)
                here = len(order) - 1
                for child in reversed(children[n]):
                    stack.append((child, here))
            elif not children[n] and all(nodes[n].get(k) is None for k in ("mesh", "camera")):
                sites.append(n)
                site_parents.append(parent)
        if len(order) != len(members):
            raise self.fail("skins[0].joints are not one tree under one root")
        self.parent_of = parent_of
        return order, parents, sites, site_parents

    def ancestors(self, root: int) -> tuple[NDArray, NDArray, float]:
        """World rotation, translation and uniform scale of the root's parent."""
        chain = []
        n = root
        while n in self.parent_of:
            n = self.parent_of[n]
            if n == root or len(chain) >= len(self.nodes):
                raise self.fail(f"nodes[{root}]'s ancestors form a cycle")
            chain.append(n)
        rotation, translation, scale = quat.identity(()), np.zeros(3), 1.0
        for n in reversed(chain):
            r, t, s = self.rest(n)
            translation = translation + scale * quat.rotate(rotation, t)
            rotation = quat.multiply(rotation, r)
            scale *= s
        return rotation, translation, scale

    def rest(self, n: int) -> tuple[NDArray, NDArray, float]:
        node = self.nodes[n]
        where = f"nodes[{n}]"
        matrix = self.numbers(node, "matrix", 16, where)
        if matrix is not None and not np.array_equal(matrix, np.eye(4).ravel()):
            m = matrix.reshape(4, 4).T
            scales = np.linalg.norm(m[:3, :3], axis=0)
            uniform = np.allclose(scales, scales[0], rtol=1e-6)
            if not (uniform and np.all(np.isfinite(scales)) and scales[0] > 0):
                raise self.fail(f"{where}.matrix is not a rotation with a uniform scale")
            r = quat.from_matrix(m[:3, :3] / scales[0])
            return r, m[:3, 3].copy(), float(scales[0])
        t = self.numbers(node, "translation", 3, where)
        r = self.numbers(node, "rotation", 4, where)
        s = self.numbers(node, "scale", 3, where)
        t = np.zeros(3) if t is None else t
        r = np.array([1.0, 0.0, 0.0, 0.0]) if r is None else wxyz(r)
        s = np.ones(3) if s is None else s
        if not np.allclose(s, s[0], rtol=1e-6) or not s[0] > 0:
            raise self.fail(f"{where}.scale {s.tolist()} is not uniform and positive")
        largest = np.max(np.abs(r))
        if not largest > 0:
            raise self.fail(f"{where}.rotation is zero, not a rotation")
        r = r / largest  # a norm of huge components would overflow
        return quat.normalize(r), t, float(s[0])

    def translation(self, n: int) -> NDArray:
        """A node's rest translation (an end site's offset): :meth:`rest`'s, quicker."""
        if "matrix" in self.nodes[n]:
            return self.rest(n)[1]
        t = self.numbers(self.nodes[n], "translation", 3, f"nodes[{n}]")
        return np.zeros(3) if t is None else t

    def animation(self, wanted: str | int | None) -> tuple[int | None, dict[str, Any] | None]:
        animations = self.objects(self.document, "animations", "")
        if wanted is None:
            return (0, animations[0]) if animations else (None, None)
        if isinstance(wanted, int) or (isinstance(wanted, str) and wanted.isdigit()):
            k = int(wanted)
            if not 0 <= k < len(animations):
                raise self.fail(f"no animation {k}: the file has {len(animations)}")
            return k, animations[k]
        names = [a.get("name") for a in animations]
        if wanted not in names:
            raise self.fail(f"no animation named {wanted!r}; the file has {names}")
        return names.index(wanted), animations[names.index(wanted)]

    def channels(
        self, k: int | None, anim: dict[str, Any] | None, index: dict[int, int]
    ) -> tuple[dict[int, _Keys], dict[int, _Keys]]:
        """The animation's rotation and translation keyframes of each joint (by joint number),
        checked: a sampler that exists, as many values as times, times that never go back, no
        more keyframes in all than :func:`quatmotion.limits.current` allows a clip."""
        rotated: dict[int, _Keys] = {}
        moved: dict[int, _Keys] = {}
        if anim is None:
            return rotated, moved
        samplers = self.objects(anim, "samplers", f"animations[{k}].")
        for c, channel in enumerate(self.objects(anim, "channels", f"animations[{k}].")):
            field = f"animations[{k}].channels[{c}]"
            target = channel.get("target")
            if not is_object(target):
                raise self.fail(f"{field}.target is missing")
            node = target.get("node")
            j = index.get(node) if is_index(node) else None
            path = target.get("path")
            if j is None or path not in ("rotation", "translation"):
                continue  # another node's, or weights and scale
            s = self.index(channel, "sampler", len(samplers), field, f"animations[{k}].samplers")
            sampler = samplers[s]
            how = sampler.get("interpolation", "LINEAR")
            if how not in ("LINEAR", "STEP", "CUBICSPLINE"):
                raise self.fail(f"animations[{k}].samplers[{s}].interpolation is {how!r}")
            n_times = self.accessor_count(sampler.get("input"), f"{field} input")
            n_values = self.accessor_count(sampler.get("output"), f"{field} output")
            per_key = 3 if how == "CUBICSPLINE" else 1
            if n_values != per_key * n_times or not n_times:
                raise self.fail(f"{field}: {n_times} times but {n_values} values ({how})")
            self.keys_read += n_times
            limits.check("joint_frames", self.keys_read, self.path, f"keyframes up to {field}")
            times = self.accessor(sampler["input"], "SCALAR", f"{field} input")[:, 0]
            kind = "VEC4" if path == "rotation" else "VEC3"
            values = self.accessor(sampler["output"], kind, f"{field} output")[
                per_key // 2 :: per_key
            ]
            if np.any(np.diff(times) < 0):
                raise self.fail(f"{field}: keyframe times go backwards")
            if path == "rotation":
                largest = np.max(np.abs(values), axis=1, keepdims=True)  # no overflow below
                if not np.all(largest > 0):
                    raise self.fail(f"{field} output holds a zero quaternion, not a rotation")
                values = values / largest
            (rotated if path == "rotation" else moved)[j] = (times, values, how)
        return rotated, moved

    # --- the motion ---------------------------------------------------------------------------

    def motion(self, wanted: str | int | None) -> Motion:
        order, parents, sites, site_parents = self.joints()
        J = len(order)
        rests = [self.rest(n) for n in order]
        for j, (_, _, s) in enumerate(rests):
            if j and abs(s - 1.0) > 1e-6:
                raise self.fail(f"nodes[{order[j]}] (a joint) is scaled: not read")
        up_r, up_t, up_s = self.ancestors(order[0])
        # The root's own scale scales the bones below it, not its own translation.
        cm = self.metre * up_s * rests[0][2]
        offsets = np.array([t for _, t, _ in rests]) * cm
        offsets[0] = self.metre * (up_t + up_s * quat.rotate(up_r, rests[0][1]))
        site_offsets = np.array([self.translation(n) for n in sites]).reshape(-1, 3) * cm
        k, anim = self.animation(wanted)
        rotated, moved = self.channels(k, anim, {n: j for j, n in enumerate(order)})
        keys = [t for t, _, _ in (*rotated.values(), *moved.values())]
        fps = 30.0 if anim is None else self._fps(k, anim, keys)
        frames = self._frame_times(k, keys, fps, J)
        n_frames = len(frames)
        for table in (rotated, moved):
            for j, (times, values, how) in table.items():
                table[j] = (_snapped(times, frames, fps), values, how)
        rotations = np.empty((n_frames, J, 4))
        translations = np.empty((n_frames, J, 3))
        for j, (r, t, _) in enumerate(rests):
            rotations[:, j] = r
            translations[:, j] = t
            if j in rotated:
                rotations[:, j] = wxyz(_sample_rotation(*rotated[j], frames))
            if j in moved:
                translations[:, j] = _sample(*moved[j], frames)
        root = self.metre * (up_t + up_s * quat.rotate(up_r, translations[:, 0]))
        rotations[:, 0] = quat.multiply(up_r, rotations[:, 0])
        translations *= cm
        joint_moves = any(j > 0 for j in moved)
        names = [self.name(n) for n in order]
        site_names = [self.name(n) for n in sites]
        name = self.path.stem
        try:
            skeleton = Skeleton(
                joint_names=tuple(unique_names(names)),
                parents=np.asarray(parents, dtype=np.int64),
                offsets=offsets,
                channels=tuple(
                    (("tx", "ty", "tz") if j == 0 or j in moved else ())
                    + (("rz", "ry", "rx") if j == 0 or j in rotated else ())
                    for j in range(J)
                ),
                euler="intrinsic",
                site_names=tuple(unique_names(site_names, taken=set(names))),
                site_parents=np.asarray(site_parents, dtype=np.int64),
                site_offsets=site_offsets,
                name=name,
                extras={
                    "format": "gltf",
                    "length_scale": cm,
                    "gltf_animation": None if anim is None else (anim.get("name") or str(k)),
                    **({"length_unit_given": True} if self.given else {}),
                },
            )
            return Motion(
                skeleton,
                fps,
                root,
                rotations,
                translations if joint_moves else None,
                name=name,
            )
        except ValueError as error:  # e.g. offsets that overflow once in centimetres
            raise self.fail(str(error)) from None

    def name(self, n: int) -> str:
        name = self.nodes[n].get("name")
        return name if isinstance(name, str) and name else f"node{n}"

    def _fps(self, k: int | None, anim: dict[str, Any], times: list[NDArray]) -> float:
        extras = anim.get("extras")
        fps = extras.get("fps") if is_object(extras) else None
        if fps is not None:
            limits.check("fps", fps, self.path, f"animations[{k}].extras.fps")
            return float(fps)
        steps = np.concatenate([np.diff(t) for t in times]) if times else np.zeros(0)
        steps = steps[steps > 0]
        if not len(steps):
            return 30.0
        fps = 1.0 / float(np.median(steps))
        limits.check("fps", fps, self.path, f"animations[{k}]'s frame rate (1 / median key step)")
        return float(round(fps)) if abs(fps - round(fps)) <= 1e-3 * fps else fps

    def _frame_times(self, k: int | None, keys: list[NDArray], fps: float, joints: int) -> NDArray:
        """The clip's frame times: from the first keyframe to the last at ``fps`` (none without
        keyframes), their number checked against the limits before they are made."""
        if not keys:
            return np.zeros(0)
        start = min(float(t[0]) for t in keys)
        end = max(float(t[-1]) for t in keys)
        field = f"animations[{k}]"
        limits.check("duration", end - start, self.path, f"{field}'s duration (keyframe times)")
        n_frames = int(round((end - start) * fps)) + 1
        limits.check("frames", n_frames, self.path, f"{field}'s frames ({fps:g} frames/s)")
        limits.check("joint_frames", n_frames * joints, self.path, f"{field}'s frames x joints")
        return start + np.arange(n_frames) / fps


def unique_names(names: list[str], taken: set[str] | None = None) -> list[str]:
    """Names made unique (glTF does not require it; a Skeleton does): ``name.1``, ``name.2``.
    Linear: each name's next suffix is remembered."""
    seen = set(taken or ())
    suffix: dict[str, int] = {}
    out = []
    for name in names:
        candidate, k = name, suffix.get(name, 1)
        while candidate in seen:
            candidate, k = f"{name}.{k}", k + 1
        suffix[name] = k
        seen.add(candidate)
        out.append(candidate)
    return out


def _sample(times: NDArray, values: NDArray, how: str, at: NDArray) -> NDArray:
    """Values at times ``at``: linear between keyframes (the last before for STEP)."""
    if how == "STEP":
        k = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 1)
        return values[k]
    return np.stack([np.interp(at, times, values[:, c]) for c in range(values.shape[1])], axis=-1)


_Keys = tuple  # (times (K,), values (K, 3 or 4), interpolation): one channel's keyframes


def _snapped(times: NDArray, frames: NDArray, fps: float) -> NDArray:
    """Keyframe times snapped to the frame grid they sit on (within a thousandth of a frame):
    they are float32, and a frame should take its keyframe's value exactly, not a mix of two."""
    start = frames[0] if len(frames) else 0.0
    grid = (times - start) * fps
    if np.all(np.abs(grid - np.round(grid)) < 1e-3):
        return start + np.round(grid) / fps
    return times


def _sample_rotation(times: NDArray, values: NDArray, how: str, at: NDArray) -> NDArray:
    """Unit quaternions (x y z w) at times ``at``: exact at keyframes, normalised linear
    interpolation between them (on the shorter arc)."""
    q = values / np.linalg.norm(values, axis=1, keepdims=True)
    signs = np.ones(len(q))
    if len(q) > 1:
        flips = np.sum(q[1:] * q[:-1], axis=1) < 0
        signs[1:] = np.where(np.cumsum(flips) % 2, -1.0, 1.0)
    q = q * signs[:, None]
    out = _sample(times, q, how, at)
    return out / np.linalg.norm(out, axis=1, keepdims=True)
