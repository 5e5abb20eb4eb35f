"""Write ``quatmotion/codec/rans_tables.bin``: the frequency tables of ``.qmz`` format 3's
static rANS coder (``quatmotion/codec/rans.py``; ``docs/format.md``, *Coefficient rows,
format 3*).

The tables are part of the format: a reader uses the file's frequencies, never recomputes
them (the floating-point Laplace below may round differently on another machine). Run once
when the format was made; a new table set would be a new format version::

    .venv/bin/python tools/make_rans_tables.py

Table ``t`` for ``t < 80`` is the *direct* table of scale code ``q = t - 48`` (Laplace scale
``b = 2 ** (q / 8)`` symbol units): ``P(v) = F(v + 1/2) - F(v - 1/2)``. Table ``t >= 80`` is the
*shifted* table of code ``q = t - 80 + 24``: the distribution of ``floor(v / 2 ** k)`` when the
scale is ``2 ** k`` times larger, ``P(y) = F(y + 1) - F(y)``. ``F`` is the Laplace CDF of scale
``b``. A table codes ``v`` in ``-M..M`` directly; ``M`` is the largest ``|v|`` whose frequency
``P(v) 4096`` is at least 1.5 (at most 127); everything beyond is the escape symbol, whose
frequency is the tail's (at least 1). Frequencies are ``max(1, round(4096 P))`` with the
rounding's difference taken up by the largest.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

OUT = Path(__file__).resolve().parents[1] / "quatmotion" / "codec" / "rans_tables.bin"
PROB_BITS = 12
TOTAL = 1 << PROB_BITS
DIRECT = range(-48, 32)  # scale codes of the direct tables
SHIFTED = range(24, 32)  # scale codes of the shifted tables
MAX_M = 127


def laplace_cdf(x: float, b: float) -> float:
    return 0.5 * math.exp(x / b) if x <= 0 else 1.0 - 0.5 * math.exp(-x / b)


def table(q: int, shifted: bool) -> list[int]:
    b = 2.0 ** (q / 8.0)
    if shifted:
        p = lambda v: laplace_cdf(v + 1.0, b) - laplace_cdf(v, b)  # noqa: E731
    else:
        p = lambda v: laplace_cdf(v + 0.5, b) - laplace_cdf(v - 0.5, b)  # noqa: E731
    M = 0
    while M < MAX_M and min(p(M + 1), p(-M - 1)) * TOTAL >= 1.5:
        M += 1
    probs = [p(v) for v in range(-M, M + 1)]
    probs.append(max(0.0, 1.0 - sum(probs)))
    freqs = [max(1, round(x * TOTAL)) for x in probs]
    top = max(range(len(freqs) - 1), key=lambda i: freqs[i])
    freqs[top] += TOTAL - sum(freqs)
    assert freqs[top] >= 1 and sum(freqs) == TOTAL
    return freqs


def main() -> None:
    out = bytearray(b"QMZRANS1")
    tables = [table(q, False) for q in DIRECT] + [table(q, True) for q in SHIFTED]
    out += struct.pack("<H", len(tables))
    for freqs in tables:
        M = (len(freqs) - 2) // 2
        out += struct.pack("<B", M)
        out += struct.pack(f"<{len(freqs)}H", *freqs)
    OUT.write_bytes(bytes(out))
    print(f"{OUT}: {len(tables)} tables, {len(out)} bytes")


if __name__ == "__main__":
    main()
