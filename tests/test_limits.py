"""quatmotion.limits: one place for what a file may declare, checked before allocating."""

from __future__ import annotations

import json
import threading

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from quatmotion import limits
from quatmotion.errors import FormatError


def test_defaults_are_far_beyond_real_clips_and_below_exhaustion() -> None:
    d = limits.Limits()
    # CMU's longest clip: ~20,000 frames, 31 joints, 120 frames/s.
    assert d.frames >= 100 * 20_000 // 2 and d.joints >= 1_000 and d.fps >= 1_000
    # A clip at the limit fits in memory: rotations and translations in float64.
    assert d.joint_frames * 7 * 8 < 2 * (1 << 30)


def test_check_names_file_field_and_limit() -> None:
    with pytest.raises(FormatError) as caught:
        limits.check("frames", 10**9, "clip.bvh", "Frames:", line=12)
    text = str(caught.value)
    assert text.startswith("clip.bvh:12: Frames: is 1,000,000,000 frames, over the limit")
    assert "QUATMOTION_LIMITS=frames=" in text
    limits.check("frames", limits.current().frames, "clip.bvh", "Frames:")  # the limit itself


@pytest.mark.parametrize("value", [-1, float("nan"), float("inf"), None, True, "12"])
def test_check_refuses_invalid_counts_whatever_the_limit(value) -> None:
    with pytest.raises(FormatError, match="a.amc: frame count is"):
        limits.check("frames", value, "a.amc", "frame count")


@pytest.mark.parametrize("fps", [0.0, -30.0, float("nan"), 1e9])
def test_check_refuses_bad_frame_rates(fps: float) -> None:
    with pytest.raises(FormatError, match="Frame Time"):
        limits.check("fps", fps, "a.bvh", "Frame Time")


def test_raised_is_scoped_and_nests() -> None:
    default = limits.current().frames
    with limits.raised(frames=default * 10) as outer:
        assert limits.current() is outer
        limits.check("frames", default * 5, None, "frames")
        with limits.raised(joints=7):
            assert limits.current().frames == default * 10 and limits.current().joints == 7
        assert limits.current().joints == limits.Limits().joints
    assert limits.current().frames == default
    with pytest.raises(FormatError):
        limits.check("frames", default * 5, None, "frames")


def test_raised_in_one_thread_leaves_others_alone() -> None:
    seen = []
    with limits.raised(frames=5):
        thread = threading.Thread(target=lambda: seen.append(limits.current().frames))
        thread.start()
        thread.join()
    assert seen == [limits.Limits().frames]


def test_environment_variable(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(limits.ENV_VAR, "frames=5e6, joints=20_000")
    assert limits.current().frames == 5_000_000 and limits.current().joints == 20_000
    assert isinstance(limits.current().frames, int)
    monkeypatch.setenv(limits.ENV_VAR, "frame=5")
    with pytest.raises(ValueError, match="no limit 'frame'"):
        limits.current()
    monkeypatch.setenv(limits.ENV_VAR, "frames=-5")
    with pytest.raises(ValueError, match="positive"):
        limits.current()
    monkeypatch.setenv(limits.ENV_VAR, "frames=1.5")
    with pytest.raises(ValueError, match="whole"):
        limits.current()


def test_json_depth_ignores_brackets_in_strings() -> None:
    assert limits.json_depth(b"1") == 0
    text = json.dumps({"a": [[1], {"b": '[[[["}' + "\\"}]})  # a quote and a backslash inside
    assert limits.json_depth(text) == 3 and json.loads(text)["a"][1]["b"].endswith("\\")


def test_load_json_refuses_deep_nesting_before_recursing() -> None:
    deep = b"[" * 100_000 + b"]" * 100_000
    with pytest.raises(FormatError, match=r"settings nesting depth is 100,000 levels"):
        limits.load_json(deep, "x.qidx", "settings")
    with pytest.raises(FormatError, match="x.gltf: document is not valid JSON"):
        limits.load_json(b"{", "x.gltf")
    assert limits.load_json('{"a": [1, 2]}', None) == {"a": [1, 2]}


def test_json_depth_is_quick_over_a_long_string() -> None:
    """A .gltf upload's data URI: 40 MB of one string (a regex alternation per character took
    17 s)."""
    import time

    text = json.dumps({"uri": "QUJD" * 10_000_000, "a": [["x\\"]]})
    started = time.process_time()
    assert limits.json_depth(text) == 3
    assert time.process_time() - started < 4


def _depth(value) -> int:
    if isinstance(value, dict):
        return 1 + max(map(_depth, value.values()), default=0)
    if isinstance(value, list):
        return 1 + max(map(_depth, value), default=0)
    return 0


_TEXT = st.text(alphabet='[]{}"\\ax', max_size=8)
_JSON = st.recursive(
    st.none() | st.integers() | _TEXT,
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(_TEXT, inner, max_size=3),
    max_leaves=20,
)


@settings(max_examples=300, deadline=None, database=None, derandomize=True)
@given(value=_JSON)
def test_json_depth_is_the_documents_depth(value) -> None:
    """Strings full of brackets, quotes and runs of backslashes: only the structure counts."""
    for text in (json.dumps(value), json.dumps(value, indent=1, ensure_ascii=False)):
        assert limits.json_depth(text) == _depth(value)
