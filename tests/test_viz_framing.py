"""Which points of a clip the viewer shows as the body: the point it follows and the bones it
draws (quatmotion.viz.framing), on the four skeleton families and on made-up root layouts of
skeletons the 16-joint mapping does not know (tests/test_viz_browser.py plays them)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from quatmotion import quat
from quatmotion.datasets import data_root
from quatmotion.io import read_motion
from quatmotion.motion import Motion, Skeleton
from quatmotion.synthetic import generate_clip
from quatmotion.viz import frame_data
from quatmotion.viz.framing import body_framing

BANDAI_WALK = "bandai1/clips/dataset-1_walk_active_001.bvh"
FAMILIES = {
    "cmu": "cmu/02/02_01.amc",
    "hdm05": "hdm05/clips/jogLeftCircle4StepsRstart/HDM_bd_jogLeftCircle4StepsRstart_001_120.amc",
    "cmu_bvh": "cmu_bvh/07/07_01.bvh",
}


def _framing(motion: Motion):
    positions, _, _ = frame_data.clip_points(motion)
    return body_framing(motion.skeleton, positions)


def _anonymous(motion: Motion) -> Motion:
    """The clip on a skeleton whose names the 16-joint mapping does not know."""
    sk = motion.skeleton
    renamed = dataclasses.replace(
        sk,
        joint_names=tuple(f"j{k}" for k in range(sk.n_joints)),
        site_names=tuple(f"s{k}" for k in range(sk.n_sites)),
    )
    return dataclasses.replace(motion, skeleton=renamed)


def _under_reference(
    motion: Motion,
    reference_track: np.ndarray,
    body_track: np.ndarray,
    reference_turn: np.ndarray | None = None,
    extra_references: int = 0,
) -> Motion:
    """``motion`` hung under new root joints (6 channels each, as bandai1's): the first at
    ``reference_track`` turned by ``reference_turn`` (radians about Y), ``extra_references``
    more at its origin, then the clip's own root at ``body_track`` in the last one's frame."""
    sk, T = motion.skeleton, motion.n_frames
    k = 1 + extra_references
    skeleton = Skeleton(
        joint_names=(*(f"ref{i}" for i in range(k)), *(f"b{i}" for i in range(sk.n_joints))),
        parents=np.concatenate(
            (np.arange(-1, k - 1), np.where(sk.parents < 0, k - 1, sk.parents + k))
        ),
        offsets=np.concatenate((np.zeros((k, 3)), sk.offsets)),
        channels=(*(("tx", "ty", "tz", "rz", "rx", "ry"),) * k, *sk.channels),
        euler=sk.euler,
        axes=np.concatenate((quat.identity((k,)), sk.axes)),
        site_names=tuple(f"s{i}" for i in range(sk.n_sites)),
        site_parents=sk.site_parents + k,
        site_offsets=sk.site_offsets,
    )
    turn = np.zeros(T) if reference_turn is None else reference_turn
    reference = quat.about_axis(turn, "y")
    rotations = np.concatenate(
        (reference[:, None], quat.identity((T, extra_references)), motion.rotations), axis=1
    )
    translations = np.broadcast_to(skeleton.offsets, (T, skeleton.n_joints, 3)).copy()
    translations[:, k] = body_track
    return Motion(skeleton, motion.fps, reference_track, rotations, translations, name="wrapped")


@pytest.fixture(scope="module")
def walk() -> Motion:
    return generate_clip("walk", 3, n_frames=240)  # travels about 3 m


@pytest.mark.needs_data
def test_bandai_follows_the_hips_and_draws_nothing_from_its_static_root():
    motion = read_motion(data_root() / BANDAI_WALK)
    names = motion.skeleton.joint_names
    hips, root = names.index("Hips"), names.index("joint_Root")
    framing = _framing(motion)
    assert (framing.centre, framing.rule) == (hips, "hip16")
    assert framing.detached == (root,) and framing.hidden == (root,)
    assert not any(root in bone for bone in framing.bones)
    # Every other bone is drawn: one per joint below the hips and per end site.
    assert len(framing.bones) == motion.n_joints - 2 + motion.skeleton.n_sites

    # The same body found without the 16-joint names, on the whole clip and on one frame
    # (the web app's pose viewer sends single frames).
    for clip in (_anonymous(motion), _anonymous(motion.slice(100, 101))):
        other = _framing(clip)
        assert (other.centre, other.rule) == (hips, "first body joint")
        assert (other.detached, other.bones) == (framing.detached, framing.bones)

    # The payload carries it; positions still cover every point, the root included.
    payload = frame_data.encode_clip(motion)
    assert payload["follow"] == hips and payload["hidden"] == [root]
    assert [tuple(b) for b in payload["bones"]] == list(framing.bones)
    decoded = frame_data.decode_clip(payload)
    assert decoded.shape[1] == len(payload["point_names"])
    np.testing.assert_allclose(decoded[:, root], 0.0, atol=payload["max_quantisation_cm"])


@pytest.mark.needs_data
@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_skeletons_whose_root_is_the_pelvis_show_every_bone(family):
    motion = read_motion(data_root() / FAMILIES[family])
    # without its names, the humanoid mapping finds the same Hip by the skeleton's structure
    for clip in (motion, _anonymous(motion)):
        framing = _framing(clip)
        assert (framing.centre, framing.rule) == (0, "hip16")
        assert framing.detached == framing.hidden == ()
        assert len(framing.bones) == motion.n_joints - 1 + motion.skeleton.n_sites


def test_a_static_reference_joint_the_body_walks_away_from_is_detached(walk):
    T = walk.n_frames
    wrapped = _anonymous(_under_reference(walk, np.zeros((T, 3)), walk.root_translation))
    framing = _framing(wrapped)
    assert (framing.centre, framing.rule, framing.detached) == (1, "hip16", (0,))
    assert not any(0 in bone for bone in framing.bones)
    # Two static references, one above the other (zero length between them): both detached.
    twice = _under_reference(walk, np.zeros((T, 3)), walk.root_translation, extra_references=1)
    framing = _framing(twice)
    assert (framing.centre, framing.detached) == (2, (0, 1))
    assert not any(b[0] in (0, 1) for b in framing.bones)


def test_a_root_far_from_a_body_that_stays_put_is_detached():
    squat = generate_clip("squat", 1, n_frames=120)
    T = squat.n_frames
    far = _under_reference(squat, np.zeros((T, 3)), squat.root_translation + [500.0, 0.0, 0.0])
    framing = _framing(far)
    assert (framing.centre, framing.detached) == (1, (0,))


def test_a_root_that_only_turns_while_the_body_circles_it_is_detached():
    wave = generate_clip("wave", 2, n_frames=200)
    T = wave.n_frames
    turning = _under_reference(
        wave,
        np.zeros((T, 3)),
        wave.root_translation + [300.0, 0.0, 0.0],
        reference_turn=np.linspace(0.0, np.pi, T),
    )
    framing = _framing(turning)
    assert (framing.centre, framing.detached) == (1, (0,))


def test_a_root_that_moves_with_the_body_is_kept(walk):
    # A reference joint on the pelvis, carried with it: a zero-length bone, not a detached root.
    T = walk.n_frames
    carried = _under_reference(walk, walk.root_translation, np.zeros((T, 3)))
    framing = _framing(carried)
    assert (framing.centre, framing.detached, framing.hidden) == (1, (), ())  # the pelvis
    assert (_framing(_anonymous(carried)).detached, _framing(_anonymous(carried)).hidden) == (
        (),
        (),
    )
    assert len(framing.bones) == carried.n_joints - 1 + carried.skeleton.n_sites


def test_a_static_root_with_no_main_child_follows_the_travelling_joint_nearest_it(walk):
    # A root at the origin holding the walking body and a static prop with more points: the
    # chain stops at the root, which stays behind; the camera follows the body's own root.
    T, sk = walk.n_frames, walk.skeleton
    n_prop = sk.n_joints + sk.n_sites + 2
    J = 1 + sk.n_joints + n_prop
    skeleton = Skeleton(
        joint_names=tuple(f"j{k}" for k in range(J)),
        parents=np.concatenate(
            (
                [-1],
                np.where(sk.parents < 0, 0, sk.parents + 1),
                [0],
                np.arange(sk.n_joints + 1, J - 1),
            )
        ),
        offsets=np.concatenate(
            (np.zeros((1, 3)), sk.offsets, np.tile([[0.0, 0.0, 2.0]], (n_prop, 1)))
        ),
        channels=(("tx", "ty", "tz", "rz", "rx", "ry"), *sk.channels, *((),) * n_prop),
        euler=sk.euler,
        axes=np.concatenate((quat.identity((1,)), sk.axes, quat.identity((n_prop,)))),
        site_names=tuple(f"s{k}" for k in range(sk.n_sites)),
        site_parents=sk.site_parents + 1,
        site_offsets=sk.site_offsets,
    )
    rotations = np.concatenate(
        (quat.identity((T, 1)), walk.rotations, quat.identity((T, n_prop))), axis=1
    )
    translations = np.broadcast_to(skeleton.offsets, (T, J, 3)).copy()
    translations[:, 1] = walk.root_translation
    motion = Motion(skeleton, walk.fps, np.zeros((T, 3)), rotations, translations)
    framing = _framing(motion)
    assert (framing.centre, framing.rule, framing.detached) == (1, "travelling", ())


def test_payloads_of_a_comparison_show_the_same_points():
    clip = generate_clip("walk", 1, n_frames=90)
    T = clip.n_frames
    wrapped = _under_reference(clip, np.zeros((T, 3)), clip.root_translation)
    shifted = dataclasses.replace(
        wrapped, joint_translations=wrapped.joint_translations + [0.0, 0.5, 0.0]
    )
    a, b, _ = frame_data.encode_comparison(wrapped, shifted)
    for payload in (a, b):
        assert (payload["follow"], payload["hidden"]) == (1, [0])
        assert payload["bones"] == a["bones"]
