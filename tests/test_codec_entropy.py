"""The compiled range decoder reads constriction's streams to the bit: random residual tables
of every scale (escapes included), decoded by it and by constriction's own decoder."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion.codec import entropy


def _words(data: bytes) -> np.ndarray:
    return np.frombuffer(data + b"\0" * (-len(data) % 4), dtype="<u4").astype(np.uint32)


@pytest.mark.parametrize("seed", range(6))
def test_compiled_decoder_matches_constriction(seed):
    rng = np.random.default_rng(seed)
    for trial in range(10):
        n, C = int(rng.integers(1, 40)), int(rng.integers(1, 70))
        scale = np.exp(rng.uniform(-4.0, 6.0, C))
        R = np.round(rng.laplace(0.0, scale * rng.uniform(0.2, 3.0), (n, C))).astype(np.int64)
        if trial % 3 == 0:  # an escape: |r| past the coder's range
            R[rng.integers(0, n), rng.integers(0, C)] = int(rng.choice([-1, 1]) * 10**6)
        starts = rng.random(n) < 0.1
        starts[0] = True
        initial = np.exp(rng.uniform(-4.0, 5.0, C))
        start_scale = np.exp(rng.uniform(-2.0, 6.0, C))
        data = entropy.encode_rows(R, initial, start_scale, starts)
        np.testing.assert_array_equal(entropy.decode_rows(data, n, initial, start_scale, starts), R)
        reference = entropy._decode_rows_constriction(_words(data), n, initial, start_scale, starts)
        np.testing.assert_array_equal(reference, R)


def test_a_corrupt_stream_is_refused_or_decodes_to_something():
    R = np.arange(40, dtype=np.int64).reshape(10, 4) % 5 - 2
    starts = np.zeros(10, dtype=bool)
    starts[0] = True
    data = bytearray(entropy.encode_rows(R, np.ones(4), np.ones(4), starts))
    data[0] ^= 0xFF
    try:
        out = entropy.decode_rows(bytes(data), 10, np.ones(4), np.ones(4), starts)
    except ValueError as error:
        assert "corrupt" in str(error)
    else:
        assert out.shape == (10, 4)
