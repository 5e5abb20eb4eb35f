"""Format 3's static rANS coder (:mod:`quatmotion.codec.rans`): bit-exact round trips at every
scale, the compiled decoder against a plain-Python reference decoder written from
``docs/format.md``, the edge cases (no rows, one symbol, the largest escapes), corruption."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion.codec import rans

TOTAL = 1 << rans.PROB_BITS


def ceil_root8(m: int) -> int:
    """``ceil(2 ** (m / 8))`` by bisection in integers (1 for ``m <= 0``)."""
    if m <= 0:
        return 1
    lo, hi = 1, 2 ** (m // 8 + 1)  # lo**8 < 2**m <= hi**8 unless lo is the answer
    while lo < hi:
        mid = (lo + hi) // 2
        if mid**8 >= 2**m:
            hi = mid
        else:
            lo = mid + 1
    return lo


def reference_decode(data: bytes, starts, main_codes, start_codes) -> np.ndarray:
    """The rows of a stream, decoded as docs/format.md says, with Python integers: the state,
    a cumulative search (no slot table), the contexts, the escape and raw bits."""
    freqs = rans.load_tables().freqs
    words = [int.from_bytes(data[i : i + 2], "little") for i in range(4, len(data), 2)]
    x = int.from_bytes(data[:4], "little")
    pos = 0

    def renorm():
        nonlocal x, pos
        while x < 1 << 16:
            x = (x << 16) | words[pos]
            pos += 1

    def raw(bits):
        nonlocal x
        value, shift = 0, 0
        while bits > 0:
            width = min(16, bits)
            value |= (x & ((1 << width) - 1)) << shift
            x >>= width
            renorm()
            shift += width
            bits -= width
        return value

    def table(q):
        q = max(q, rans.Q_MIN)
        if q < 32:
            return q - rans.Q_MIN, 0
        k = min((q - 24) >> 3, 40)
        return 80 + min(q - 8 * k - 24, 7), k

    C = len(main_codes)
    out = np.zeros((len(starts), C), dtype=np.int64)
    h = [[0, 0] for _ in range(C)]
    for i, start in enumerate(starts):
        for c in range(C):
            if start:
                q = int(start_codes[c])
            else:
                q0 = int(main_codes[c])
                j = sum(sum(h[c]) >= ceil_root8(q0 + 8 * i - 24) for i in range(1, 8))
                q = q0 + rans.DELTAS[j]
            t, k = table(q)
            f = freqs[t]
            M = (len(f) - 2) // 2
            slot = x & (TOTAL - 1)
            s, cum = 0, 0
            while cum + f[s] <= slot:
                cum += f[s]
                s += 1
            fs = f[s]
            x = fs * (x >> rans.PROB_BITS) + slot - cum
            renorm()
            if s <= 2 * M:
                y = s - M
            else:
                sign = raw(1)
                y = raw(raw(rans.ESCAPE_BITS)) + M + 1
                y = -y if sign else y
            v = (y << k) + raw(k)
            out[i, c] = v
            h[c] = [0, 0] if start else [min(abs(v), 2**40), h[c][0]]
    assert pos == len(words) and x == 1 << 16
    return out


def code(R, starts, main, start) -> bytes:
    return rans.encode_rows(R, starts, rans.model_of(main, start))


def decode(data, starts, main, start) -> np.ndarray:
    return rans.decode_rows(data, starts, rans.model_of(main, start), len(main))


def _stream(seed: int, q: int, n: int = 40, C: int = 5, escapes: int = 2):
    rng = np.random.default_rng(seed)
    R = np.round(rng.laplace(0.0, 2.0 ** (q / 8.0), (n, C))).astype(np.int64)
    for _ in range(escapes):
        R[rng.integers(n), rng.integers(C)] = int(rng.integers(-(10**12), 10**12))
    starts = np.zeros(n, dtype=bool)
    starts[:: max(1, n // 3)] = True
    return R, starts


@pytest.mark.parametrize("q", list(range(rans.Q_MIN - 8, 130, 7)) + [31, 32, 39, 40, 400])
def test_round_trip_at_every_scale_against_the_reference(q):
    R, starts = _stream(q + 1000, q)
    main = np.full(R.shape[1], q) + np.arange(R.shape[1])
    start = main + 9
    data = code(R, starts, main, start)
    np.testing.assert_array_equal(decode(data, starts, main, start), R)
    np.testing.assert_array_equal(reference_decode(data, starts, main, start), R)
    assert rans.stream_bytes(R, starts, rans.model_of(main, start)) == len(data)


def test_thresholds_are_exact():
    m = np.arange(-20, 8 * 62)
    assert rans.thresholds(m).tolist() == [ceil_root8(int(v)) for v in m]


def test_a_table_fits_the_laplace_it_models():
    """Coding Laplace samples of scale 2**(q/8) with code q costs within a few per cent of
    their ideal code length; a wrong code costs more."""
    rng = np.random.default_rng(7)
    for q in (-16, 0, 12, 24, 36, 60):
        b = 2.0 ** (q / 8)
        R = np.round(rng.laplace(0.0, b, (4000, 1))).astype(np.int64)
        starts = np.ones(len(R), dtype=bool)  # start rows: the start code alone, no context
        sizes = [code(R, starts, [0], [q + d]).__len__() for d in (-16, 0, 16)]
        assert sizes[1] < sizes[0] and sizes[1] < sizes[2]
        _, counts = np.unique(R, return_counts=True)
        entropy = -np.sum(counts * np.log2(counts / len(R))) / 8
        assert sizes[1] <= 1.06 * entropy + 40, q


def test_contexts_follow_the_activity():
    """A channel quiet then busy codes smaller with the contexts than at one scale."""
    rng = np.random.default_rng(8)
    R = np.concatenate([np.round(rng.laplace(0, b, (500, 1))) for b in (0.3, 30.0, 0.3, 30.0)])
    R = R.astype(np.int64)
    first = np.eye(len(R), 1, dtype=bool)[:, 0]
    with_ctx = min(len(code(R, first, [q], [q])) for q in range(0, 64, 2))
    fixed = min(len(code(R, np.ones(len(R), bool), [0], [q])) for q in range(0, 64, 2))
    assert with_ctx < 0.9 * fixed


def test_edge_cases():
    codes = np.array([3, -50, 70])
    empty = np.zeros((0, 3), dtype=np.int64)
    data = code(empty, np.zeros(0, bool), codes, codes)
    assert data == (1 << 16).to_bytes(4, "little")
    assert decode(data, np.zeros(0, bool), codes, codes).shape == (0, 3)
    one = np.array([[5]])
    for start in (True, False):
        data = code(one, np.array([start]), np.array([0]), np.array([0]))
        np.testing.assert_array_equal(decode(data, [start], [0], [0]), one)
    # the largest values the escape codes, at the smallest and the largest scales
    big = 2**62 - 1
    R = np.array([[big, -big, 0], [-big, big, 1]], dtype=np.int64)
    for q in (rans.Q_MIN, 40, 300):
        qs = np.full(3, q)
        data = code(R, np.zeros(2, bool), qs, qs)
        np.testing.assert_array_equal(decode(data, np.zeros(2, bool), qs, qs), R)
        np.testing.assert_array_equal(reference_decode(data, np.zeros(2, bool), qs, qs), R)
    with pytest.raises(ValueError, match="range"):
        code(np.array([[-(2**62)]]), np.zeros(1, bool), [0], [0])


def test_corrupt_streams_are_refused():
    R, starts = _stream(3, 10, n=60)
    codes = np.full(R.shape[1], 10)
    data = code(R, starts, codes, codes)
    for bad in (data[:-2], data + b"\0\0", data[:3], data[:-1], b""):
        with pytest.raises(ValueError, match="corrupt"):
            decode(bad, starts, codes, codes)
    flipped = bytearray(data)
    refused = 0
    for i in range(0, len(data), 3):
        flipped[i] ^= 0x10
        try:
            got = decode(bytes(flipped), starts, codes, codes)
            assert not np.array_equal(got, R)  # decoded, but not to the rows
        except ValueError:
            refused += 1
        flipped[i] ^= 0x10
    assert refused >= 0.9 * len(range(0, len(data), 3))


def test_tables_are_distributions():
    tables = rans.load_tables()
    assert len(tables.freqs) == 88
    for t, f in enumerate(tables.freqs):
        assert sum(f) == TOTAL and min(f) >= 1, t
        M = (len(f) - 2) // 2
        assert max(f[M], f[M - 1] if t >= 80 else 0) == max(f)  # the mode at 0 (or -1)
