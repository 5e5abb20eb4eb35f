"""Transition labels judged on the blended transition itself (issue 20), not by a distance.

A candidate transition ``(A, i) -> (B, j)`` (pose ``i`` of clip ``A`` followed by what follows
pose ``j`` of clip ``B``) is synthesised as a motion-graph system plays it, then judged by what
a person would see in it, against the same quantities in natural motion of the same data set.

Synthesis (:func:`synthesise`), on the canonical 16-joint body (:mod:`quatmotion.pose.skeleton16`):

1. *Root aligned in position and heading*: ``B``'s root path after ``j`` is rotated about the
   vertical by ``heading_A(i) - heading_B(j)`` and translated so that ``B_j`` sits where ``A_i``
   is (pose ``A_i`` is identified with ``B_j``: a transition to the same frame is natural
   motion, exactly). Heading is the yaw of the hip line (LHip -> RHip).
2. *A short blend of joint rotations*: every bone's direction in the body frame is ``B``'s
   rotated by the offset rotation that takes ``B_j``'s bone onto ``A_i``'s, the offset slerped
   to the identity over ``blend_s`` (0.3 s) with a smoothstep weight; the hip height offset
   decays alike. Bones keep ``A``'s lengths (the canonical body: every clip has the same).
3. *Foot contacts kept planted*: a foot is in contact where its source frame has it within
   ``contact_height_cm`` of the source clip's floor and slower than ``contact_speed_cm_s``. A
   root-offset clean-up moves the root horizontally, frame by frame, by minus the mean slide of
   the feet in contact since the previous frame, and vertically so that the feet in contact
   keep their source height above the floor on average and no foot is below the floor (no
   IK: what one root offset cannot fix stays as skating, or as root jumps).

Judged quantities (:data:`QUANTITIES`), over the synthesised window of ``context_s`` before
``i`` to ``blend_s + context_s`` after it:

- ``skate``: largest horizontal speed of a foot in contact after the clean-up, cm/s;
- ``bone_acc``: largest bone angular acceleration, rad/s^2 (second difference of directions);
- ``bone_jerk``: largest bone angular jerk, rad/s^3;
- ``root_jump``: largest change of the root's travel velocity, cm/s^2 (second difference of its
  floor-plane path; its height is the gait's bounce and the clean-up's);
- ``penetration``: deepest joint below the floor, cm (floor: the source clip's 2nd percentile
  of foot heights; the clean-up keeps the feet above it, so this is the rest of the body).

Judgement (:func:`judge`), in the terms of ``docs/metrics.md``: every quantity ``q`` is
divided by its reference ``max(P95 of q over natural windows of the data set, q of the natural
window of A at i, q of the natural window of B at j)``, with a floor of ``penetration_floor_cm``
for penetration; the worst of these ratios is the transition's *artefact*. **Good** when the
artefact is at most ``GOOD_RATIO`` (1.25: nothing a quarter beyond what natural motion of
the data set, and the two source motions themselves, show; a one-frame skip stays inside),
**bad** at ``BAD_RATIO`` (2.5) or more, left out in between. Natural windows are identity
transitions ``(A, i) -> (A, i)`` at random frames.

Conventions
-----------
- Positions are centimetres, Y up, :data:`~quatmotion.pose.skeleton16.JOINTS_16` order; clip
  lists hold ``world`` (T, 16, 3) arrays at one frame rate ``fps``.
- Frames outside a clip are its edge frame repeated (a transition near a clip's end holds the
  last pose, as a motion graph would not play it anyway: such pairs are rarely good).
- Seeded: the same clips, pairs and seed give the same labels.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion.pose.labels import TransitionPairs, balanced_sample, candidate_pairs
from quatmotion.pose.skeleton16 import FEET_16, JOINTS_16, PARENTS_16

__all__ = [
    "BAD_RATIO",
    "GOOD_RATIO",
    "QUANTITIES",
    "BlendSettings",
    "artefact_quantities",
    "blended_transition_labels",
    "candidate_pairs",
    "judge",
    "natural_reference",
    "synthesise",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

QUANTITIES: tuple[str, ...] = ("skate", "bone_acc", "bone_jerk", "root_jump", "penetration")
GOOD_RATIO = 1.25
BAD_RATIO = 2.5
_FEET = FEET_16
_HIPS = (JOINTS_16.index("LHip"), JOINTS_16.index("RHip"))
_PARENTS = np.asarray(PARENTS_16)


@dataclass(frozen=True)
class BlendSettings:
    """How transitions are synthesised and judged (module docstring).

    Attributes
    ----------
    blend_s : float
        Seconds over which the rotation offset decays to the identity.
    context_s : float
        Seconds judged before the transition and after the blend.
    contact_height_cm, contact_speed_cm_s : float
        A foot within this height of its clip's floor and slower than this is in contact.
    penetration_floor_cm : float
        Smallest penetration reference (natural motion rarely goes below its floor).
    natural_percentile : float
        Percentile of natural windows each quantity is referred to.
    """

    blend_s: float = 0.3
    context_s: float = 0.2
    contact_height_cm: float = 6.0
    contact_speed_cm_s: float = 40.0
    penetration_floor_cm: float = 1.0
    natural_percentile: float = 95.0

    def __post_init__(self) -> None:
        for name in ("blend_s", "context_s", "contact_height_cm", "contact_speed_cm_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if not 50 <= self.natural_percentile < 100:
            raise ValueError(
                f"natural_percentile must be in [50, 100), got {self.natural_percentile}"
            )


def _heading(world: FloatArray) -> FloatArray:
    """Yaw of the hip line, (...,) radians, from positions (..., 16, 3)."""
    d = world[..., _HIPS[1], :] - world[..., _HIPS[0], :]
    return np.arctan2(-d[..., 2], d[..., 0])


def _rot_y(yaw: FloatArray) -> FloatArray:
    """Rotation matrices (..., 3, 3) about +Y by ``yaw`` (x -> z is -yaw, right-handed)."""
    c, s = np.cos(yaw), np.sin(yaw)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack(
        [np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2
    )


def _unit(v: FloatArray) -> FloatArray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-12, n, 1.0)


def _rotate_towards(d: FloatArray, src: FloatArray, dst: FloatArray, w: FloatArray) -> FloatArray:
    """``d`` rotated by fraction ``w`` of the shortest rotation taking ``src`` onto ``dst``
    (Rodrigues; all unit vectors (..., 3), ``w`` broadcast (..., 1))."""
    axis = np.cross(src, dst)
    sin = np.linalg.norm(axis, axis=-1, keepdims=True)
    cos = np.sum(src * dst, axis=-1, keepdims=True)
    angle = np.arctan2(sin, cos) * w
    k = axis / np.where(sin > 1e-9, sin, 1.0)
    c, s = np.cos(angle), np.sin(angle)
    return d * c + np.cross(k, d) * s + k * np.sum(k * d, axis=-1, keepdims=True) * (1 - c)


def _frames(world: FloatArray, start: int, n: int) -> FloatArray:
    idx = np.clip(np.arange(start, start + n), 0, len(world) - 1)
    return world[idx]


def _floor(world: FloatArray) -> float:
    return float(np.percentile(world[:, _FEET, 1], 2))


def synthesise(
    world_a: ArrayLike,
    i: int,
    world_b: ArrayLike,
    j: int,
    fps: float,
    settings: BlendSettings = BlendSettings(),
) -> tuple[FloatArray, NDArray[np.bool_], FloatArray]:
    """The transition ``(A, i) -> (B, j)`` as played, with its foot contacts, cleaned up.

    Parameters
    ----------
    world_a, world_b : array_like, shape (T, 16, 3)
        World positions of the two clips, centimetres, Y up.
    i, j : int
        Frames of the transition (``A_i`` is identified with ``B_j``).
    fps : float

    Returns
    -------
    motion : ndarray, shape (F, 16, 3)
        ``context`` frames of A up to ``A_i``, then ``blend + context`` frames of B, in A's
        world frame, root-offset cleaned.
    contact : ndarray of bool, shape (F, 2)
        Left and right foot contacts.
    floors : ndarray, shape (F,)
        Floor height under each frame, cm (the source clip's).
    """
    A = np.asarray(world_a, dtype=np.float64)
    B = np.asarray(world_b, dtype=np.float64)
    c = max(2, int(round(settings.context_s * fps)))
    n_blend = max(1, int(round(settings.blend_s * fps)))
    before = _frames(A, i - c, c + 1)  # A_{i-c} .. A_i
    after = _frames(B, j, n_blend + c + 1)  # B_j .. (B_j is A_i: dropped below)
    motion = _blend_one(before, after, _heading(A[i]) - _heading(B[j]), n_blend)
    return _plant_one(motion, before, after, (_floor(A), _floor(B)), fps, settings)


def _blend_weights(n_frames: int, n_blend: int) -> FloatArray:
    """How much of A_i's bones a frame of B keeps, shape (n_frames,): 1 at B_j (= A_i), a
    smoothstep down to 0 at ``n_blend`` frames, 0 after."""
    k = np.arange(n_frames, dtype=np.float64) / n_blend
    w = 1.0 - np.clip(3 * k**2 - 2 * k**3, 0.0, 1.0)
    w[k >= 1] = 0.0
    return w


def _blend_one(before: FloatArray, after: FloatArray, turn: float, n_blend: int) -> FloatArray:
    """Steps 1 and 2 of :func:`synthesise`: ``before`` (A up to A_i) then ``after`` (B from
    B_j) turned by ``turn`` and placed at A_i, B's bones blended from A_i's over ``n_blend``
    frames."""
    # 1. root: B's path relative to B_j, turned into A_i's heading and placed at A_i
    R = _rot_y(np.asarray(turn))
    centre = after[0, 0] * np.array([1.0, 0.0, 1.0])  # B_j's root on the floor plane
    out_after = (after - centre) @ R.T  # turned about B_j's root, B's own heights kept
    out_after[..., [0, 2]] += before[-1, 0, [0, 2]]
    # 2. blend of bone directions: B's bones offset onto A_i's, the offset decaying
    w = _blend_weights(len(after), n_blend)
    bones_a = _unit(before[-1, 1:] - before[-1, _PARENTS[1:]])  # A_i's bones (15, 3)
    bones_b = _unit(out_after[:, 1:] - out_after[:, _PARENTS[1:]])  # (n, 15, 3)
    length = np.linalg.norm(before[-1, 1:] - before[-1, _PARENTS[1:]], axis=-1)
    bones = _rotate_towards(bones_b, bones_b[0][None], bones_a[None], w[:, None, None])
    root = out_after[:, 0].copy()
    root[:, 1] += w * (before[-1, 0, 1] - out_after[0, 0, 1])
    blended = np.empty_like(out_after)
    blended[:, 0] = root
    for joint in range(1, 16):  # parents come first
        blended[:, joint] = blended[:, _PARENTS[joint]] + bones[:, joint - 1] * length[joint - 1]
    motion = np.concatenate((before, blended[1:]))
    return motion


def _plant_one(
    motion: FloatArray,
    before: FloatArray,
    after: FloatArray,
    floor_ab: tuple[float, float],
    fps: float,
    settings: BlendSettings,
) -> tuple[FloatArray, NDArray[np.bool_], FloatArray]:
    """Step 3 of :func:`synthesise`: the sources' foot contacts, planted by a horizontal root
    offset, feet in contact at their source height and none below the floor."""
    floor_a, floor_b = floor_ab
    # 3. contacts from the sources, planted by a root offset
    src = np.concatenate((before, after[1:]))
    floors = np.r_[np.full(len(before), floor_a), np.full(len(after) - 1, floor_b)]
    speed = np.zeros((len(src), 2))
    speed[1:] = np.linalg.norm(np.diff(src[:, _FEET][..., [0, 2]], axis=0), axis=-1) * fps
    speed[0] = speed[1]
    contact = (src[:, _FEET, 1] - floors[:, None] < settings.contact_height_cm) & (
        speed < settings.contact_speed_cm_s
    )
    offset = np.zeros(2)  # horizontal root offset so far
    for f in range(len(before), len(motion)):
        motion[f, :, 0] += offset[0]
        motion[f, :, 2] += offset[1]
        planted = [_FEET[m] for m in np.flatnonzero(contact[f] & contact[f - 1])]
        if planted:
            step = motion[f, planted] - motion[f - 1, planted]
            slide = step[:, [0, 2]].mean(axis=0)
            motion[f, :, 0] -= slide[0]
            motion[f, :, 2] -= slide[1]
            offset -= slide
        on = [_FEET[m] for m in np.flatnonzero(contact[f])]
        if on:  # feet in contact keep their source height above the floor
            lift = (src[f, on, 1] - floors[f]) - (motion[f, on, 1] - floors[f])
            motion[f, :, 1] += lift.mean()
        depth = floors[f] - motion[f, list(_FEET), 1].min()
        if depth > 0:  # and no foot goes below the floor
            motion[f, :, 1] += depth
    return motion, contact, floors


def artefact_quantities(
    motion: ArrayLike, contact: ArrayLike, floors: ArrayLike, fps: float
) -> dict[str, float]:
    """The judged quantities of a played window (module docstring, :data:`QUANTITIES`).

    Parameters
    ----------
    motion : array_like, shape (F, 16, 3)
    contact : array_like of bool, shape (F, 2)
    floors : array_like, shape (F,)
        Floor height under each frame, cm.
    fps : float
    """
    m = np.asarray(motion, dtype=np.float64)
    on = np.asarray(contact, dtype=bool)
    feet = m[:, _FEET]
    speed = np.linalg.norm(np.diff(feet[..., [0, 2]], axis=0), axis=-1) * fps  # (F-1, 2)
    planted = on[1:] & on[:-1]
    bones = _unit(m[:, 1:] - m[:, _PARENTS[1:]])
    acc = np.linalg.norm(np.diff(bones, 2, axis=0), axis=-1) * fps**2
    jerk = np.linalg.norm(np.diff(bones, 3, axis=0), axis=-1) * fps**3
    root_jump = np.linalg.norm(np.diff(m[:, 0, ::2], 2, axis=0), axis=-1) * fps**2
    depth = np.asarray(floors, dtype=np.float64)[:, None] - m[..., 1]  # any joint
    return {
        "skate": float(np.max(speed[planted], initial=0.0)),
        "bone_acc": float(acc.max(initial=0.0)),
        "bone_jerk": float(jerk.max(initial=0.0)),
        "root_jump": float(root_jump.max(initial=0.0)),
        "penetration": float(max(0.0, depth.max(initial=0.0))),
    }


_BATCH = 1024  # transitions played at once (memory: ~9 MB per 1,024 at 30 fps)


def _synthesise_batch(
    flat: FloatArray,
    starts: IntArray,
    lengths: IntArray,
    floors_of: FloatArray,
    pairs: IntArray,
    fps: float,
    settings: BlendSettings,
) -> tuple[FloatArray, NDArray[np.bool_], FloatArray]:
    """:func:`synthesise` of many transitions at once, the same arithmetic per pair.

    ``flat`` is every clip's world positions concatenated ((sum T, 16, 3)), ``starts`` and
    ``lengths`` each clip's rows, ``floors_of`` each clip's floor; ``pairs`` (P, 4). Returns
    ``motion`` (P, F, 16, 3), ``contact`` (P, F, 2), ``floors`` (P, F).
    """
    c = max(2, int(round(settings.context_s * fps)))
    n_blend = max(1, int(round(settings.blend_s * fps)))
    ca, fa, cb, fb = pairs.T
    idx_a = starts[ca, None] + np.clip(fa[:, None] + np.arange(-c, 1), 0, lengths[ca, None] - 1)
    idx_b = starts[cb, None] + np.clip(
        fb[:, None] + np.arange(n_blend + c + 1), 0, lengths[cb, None] - 1
    )
    before = flat[idx_a]  # (P, c+1, 16, 3)
    after = flat[idx_b]  # (P, n+c+1, 16, 3)
    turn = _heading(flat[starts[ca] + fa]) - _heading(flat[starts[cb] + fb])
    motion = _blend_many(before, after, turn, n_blend)
    return _plant_many(motion, before, after, (floors_of[ca], floors_of[cb]), fps, settings)


def _blend_many(
    before: FloatArray, after: FloatArray, turn: FloatArray, n_blend: int
) -> FloatArray:
    """:func:`_blend_one` of many transitions at once (``before``, ``after``: (P, n, 16, 3))."""
    # 1. root
    R = _rot_y(turn)  # (P, 3, 3)
    centre = after[:, 0, 0] * np.array([1.0, 0.0, 1.0])
    out_after = np.matmul(after - centre[:, None, None], np.swapaxes(R, 1, 2)[:, None])
    out_after[..., [0, 2]] += before[:, -1, 0, [0, 2]][:, None, None]
    # 2. blend of bone directions
    w = _blend_weights(after.shape[1], n_blend)
    last = before[:, -1]
    bones_a = _unit(last[:, 1:] - last[:, _PARENTS[1:]])  # (P, 15, 3)
    bones_b = _unit(out_after[:, :, 1:] - out_after[:, :, _PARENTS[1:]])  # (P, n, 15, 3)
    length = np.linalg.norm(last[:, 1:] - last[:, _PARENTS[1:]], axis=-1)  # (P, 15)
    bones = _rotate_towards(bones_b, bones_b[:, :1], bones_a[:, None], w[None, :, None, None])
    root = out_after[:, :, 0].copy()
    root[:, :, 1] += w[None] * (last[:, 0, 1] - out_after[:, 0, 0, 1])[:, None]
    blended = np.empty_like(out_after)
    blended[:, :, 0] = root
    for joint in range(1, 16):
        blended[:, :, joint] = (
            blended[:, :, _PARENTS[joint]]
            + bones[:, :, joint - 1] * length[:, None, joint - 1, None]
        )
    motion = np.concatenate((before, blended[:, 1:]), axis=1)
    return motion


def _plant_many(
    motion: FloatArray,
    before: FloatArray,
    after: FloatArray,
    floor_ab: tuple[FloatArray, FloatArray],
    fps: float,
    settings: BlendSettings,
) -> tuple[FloatArray, NDArray[np.bool_], FloatArray]:
    """:func:`_plant_one` of many transitions at once (``floor_ab``: each one's floors, (P,))."""
    floor_a, floor_b = floor_ab
    P = len(motion)
    # 3. contacts and the root-offset clean-up
    nb, na = before.shape[1], after.shape[1] - 1
    src = np.concatenate((before, after[:, 1:]), axis=1)
    floors = np.concatenate(
        (np.repeat(floor_a[:, None], nb, 1), np.repeat(floor_b[:, None], na, 1)), axis=1
    )
    feet = list(_FEET)
    speed = np.zeros((P, src.shape[1], 2))
    speed[:, 1:] = np.linalg.norm(np.diff(src[:, :, feet][..., [0, 2]], axis=1), axis=-1) * fps
    speed[:, 0] = speed[:, 1]
    contact = (src[:, :, feet, 1] - floors[:, :, None] < settings.contact_height_cm) & (
        speed < settings.contact_speed_cm_s
    )
    offset = np.zeros((P, 2))
    for f in range(nb, motion.shape[1]):
        motion[:, f, :, 0] += offset[:, 0, None]
        motion[:, f, :, 2] += offset[:, 1, None]
        planted = contact[:, f] & contact[:, f - 1]  # (P, 2)
        n_planted = planted.sum(axis=1)
        step = (motion[:, f, feet] - motion[:, f - 1, feet])[..., [0, 2]]  # (P, 2, 2)
        slide = np.where(
            planted[..., None], step, 0.0
        ).sum(axis=1) / np.maximum(n_planted, 1)[:, None]  # fmt: skip
        slide[n_planted == 0] = 0.0
        motion[:, f, :, 0] -= slide[:, 0, None]
        motion[:, f, :, 2] -= slide[:, 1, None]
        offset -= slide
        on = contact[:, f]
        n_on = on.sum(axis=1)
        fl = floors[:, f, None]
        lift = (src[:, f, feet, 1] - fl) - (motion[:, f, feet, 1] - fl)  # (P, 2)
        lift = np.where(on, lift, 0.0).sum(axis=1) / np.maximum(n_on, 1)
        motion[:, f, :, 1] += np.where(n_on > 0, lift, 0.0)[:, None]
        depth = floors[:, f] - motion[:, f, feet, 1].min(axis=1)
        motion[:, f, :, 1] += np.where(depth > 0, depth, 0.0)[:, None]
    return motion, contact, floors


def _artefact_batch(
    motion: FloatArray, contact: NDArray[np.bool_], floors: FloatArray, fps: float
) -> FloatArray:
    """:func:`artefact_quantities` of a batch: (P, F, 16, 3) windows -> (P, 5)."""
    feet = motion[:, :, list(_FEET)]
    speed = np.linalg.norm(np.diff(feet[..., [0, 2]], axis=1), axis=-1) * fps  # (P, F-1, 2)
    planted = contact[:, 1:] & contact[:, :-1]
    bones = _unit(motion[:, :, 1:] - motion[:, :, _PARENTS[1:]])
    acc = np.linalg.norm(np.diff(bones, 2, axis=1), axis=-1) * fps**2
    jerk = np.linalg.norm(np.diff(bones, 3, axis=1), axis=-1) * fps**3
    root_jump = np.linalg.norm(np.diff(motion[:, :, 0, ::2], 2, axis=1), axis=-1) * fps**2
    depth = floors[:, :, None] - motion[..., 1]
    return np.stack(
        [
            np.where(planted, speed, 0.0).max(axis=(1, 2)),
            acc.max(axis=(1, 2)),
            jerk.max(axis=(1, 2)),
            root_jump.max(axis=1),
            np.maximum(0.0, depth.max(axis=(1, 2))),
        ],
        axis=1,
    )


def _quantities(
    world: Sequence[FloatArray], pairs: IntArray, fps: float, settings: BlendSettings
) -> FloatArray:
    """(P, 5) quantities of the played transitions ``(clip_a, frame_a, clip_b, frame_b)``,
    :data:`_BATCH` at a time (:func:`_synthesise_batch`; equal to :func:`synthesise` and
    :func:`artefact_quantities` pair by pair, tested)."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 4)
    out = np.empty((len(pairs), len(QUANTITIES)))
    if not len(pairs):
        return out
    lengths = np.array([len(w) for w in world], dtype=np.int64)
    starts = np.r_[0, np.cumsum(lengths)[:-1]]
    flat = np.concatenate(world)
    floors_of = np.array([_floor(w) for w in world])
    for s in range(0, len(pairs), _BATCH):
        batch = pairs[s : s + _BATCH]
        motion, contact, floors = _synthesise_batch(
            flat, starts, lengths, floors_of, batch, fps, settings
        )
        out[s : s + len(batch)] = _artefact_batch(motion, contact, floors, fps)
    return out


def _quantities_one_by_one(
    world: Sequence[FloatArray], pairs: IntArray, fps: float, settings: BlendSettings
) -> FloatArray:
    """:func:`_quantities` pair by pair through :func:`synthesise` (the reference the batch is
    tested against)."""
    out = np.empty((len(pairs), len(QUANTITIES)))
    for p, (ca, fa, cb, fb) in enumerate(pairs):
        motion, contact, floors = synthesise(world[ca], fa, world[cb], fb, fps, settings)
        q = artefact_quantities(motion, contact, floors, fps)
        out[p] = [q[name] for name in QUANTITIES]
    return out


def judge(
    world: Sequence[ArrayLike],
    pairs: ArrayLike,
    fps: float,
    natural_reference: ArrayLike,
    settings: BlendSettings = BlendSettings(),
) -> tuple[FloatArray, FloatArray]:
    """Artefact ratio of each transition (module docstring) and its quantities.

    Parameters
    ----------
    world : sequence of array_like, each (T_c, 16, 3)
    pairs : array_like of int, shape (P, 4)
        ``(clip_a, frame_a, clip_b, frame_b)``.
    fps : float
    natural_reference : array_like, shape (5,)
        The data set's natural percentile of every quantity (:func:`natural_reference`).

    Returns
    -------
    artefact : ndarray, shape (P,)
        Worst quantity over its reference: at most :data:`GOOD_RATIO` is good, from
        :data:`BAD_RATIO` bad.
    quantities : ndarray, shape (P, 5)
    """
    world = [np.asarray(w, dtype=np.float64) for w in world]
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 4)
    ref = np.asarray(natural_reference, dtype=np.float64).reshape(len(QUANTITIES))
    q = _quantities(world, pairs, fps, settings)
    # the natural windows of the sources, each pose once
    ends, where = np.unique(
        np.concatenate((pairs[:, :2], pairs[:, 2:])), axis=0, return_inverse=True
    )
    own = _quantities(world, ends[:, [0, 1, 0, 1]], fps, settings)[where.reshape(-1)]
    own_a, own_b = own[: len(pairs)], own[len(pairs) :]
    scale = np.maximum(np.maximum(own_a, own_b), ref[None])
    scale[:, QUANTITIES.index("penetration")] = np.maximum(
        scale[:, QUANTITIES.index("penetration")], settings.penetration_floor_cm
    )
    scale = np.maximum(scale, 1e-9)
    return (q / scale).max(axis=1), q


def natural_reference(
    world: Sequence[ArrayLike],
    fps: float,
    clips: ArrayLike | None = None,
    n_windows: int = 400,
    settings: BlendSettings = BlendSettings(),
    random_state: int | np.random.Generator | None = 0,
) -> FloatArray:
    """The natural percentile of every quantity over ``n_windows`` identity transitions at
    random frames of ``clips`` (default all), shape (5,)."""
    rng = np.random.default_rng(random_state)
    world = [np.asarray(w, dtype=np.float64) for w in world]
    clips = np.arange(len(world)) if clips is None else np.asarray(clips, dtype=np.int64)
    c = rng.choice(clips, n_windows)
    f = np.array([rng.integers(0, len(world[k])) for k in c])
    q = _quantities(world, np.stack([c, f, c, f], axis=1), fps, settings)
    return np.percentile(q, settings.natural_percentile, axis=0)


def blended_transition_labels(
    local: Sequence[FloatArray],
    world: Sequence[FloatArray],
    fps: float,
    clips: ArrayLike | None = None,
    reference: ArrayLike | None = None,
    n_positive: int = 500,
    n_negative: int = 500,
    max_mean_distance: float = 25.0,
    n_queries: int = 4000,
    settings: BlendSettings = BlendSettings(),
    random_state: int | np.random.Generator | None = 0,
) -> tuple[TransitionPairs, FloatArray]:
    """Balanced good/bad transition pairs of ``clips`` judged on their blended transitions.

    Candidates are :func:`~quatmotion.pose.labels.candidate_pairs` (cross-clip, Eq. 35 under
    ``max_mean_distance``: 25 cm, wider than the point-cloud labels' 10 cm, since few pairs
    that close play badly once blended and cleaned up); each is played and judged
    (:func:`judge`). ``reference`` (the natural percentiles) is computed on ``clips`` unless
    given (fit it on training clips, reuse on test clips). Returns the pairs (positives first;
    ``cloud_distance`` holds the artefact ratio) and the reference used.
    """
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if len(local) != len(world):
        raise ValueError("local and world must list the same clips")
    rng = np.random.default_rng(random_state)
    if reference is None:
        reference = natural_reference(world, fps, clips, settings=settings, random_state=rng)
    cand, mean_d = candidate_pairs(
        local, clips, max_mean_distance, n_queries=n_queries, random_state=rng
    )
    if len(cand) == 0:
        raise ValueError(f"no pose pairs from different clips are within {max_mean_distance} cm")
    artefact, _ = judge(world, cand, fps, reference, settings)
    pos = np.flatnonzero(artefact <= GOOD_RATIO)
    neg = np.flatnonzero(artefact >= BAD_RATIO)
    keep, labels = balanced_sample(pos, neg, n_positive, n_negative, rng)
    pairs = TransitionPairs(cand[keep], labels, artefact[keep], mean_d[keep])
    return pairs, np.asarray(reference, dtype=np.float64)
