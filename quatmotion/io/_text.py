"""Shared helpers for the motion-file readers and writers: text, numbers, channel angles.

Conventions
-----------
* Files are read as bytes and decoded as UTF-8 (joint names in Japanese, German, French...),
  a byte that is not part of a UTF-8 sequence as the Latin-1 character it is (comments in
  legacy encodings: HDM05 ASF headers carry Latin-1 umlauts), so decoding never fails and a
  UTF-8 name never comes out garbled. A UTF-8 byte-order mark is skipped. Control bytes other
  than white space (NUL, escape, ...) mean the file is not text: a
  :class:`~quatmotion.FormatError` naming the line is raised.
* Tokens are separated by ASCII white space only (:func:`fields`): ``str.split()`` would also
  split at U+0085, U+00A0 or U+3000 inside a name. Writers write UTF-8.
* Line numbers are 1-based, as an editor shows them.
* Numbers are parsed in bulk by a Numba-compiled scanner (:func:`scan_tokens`); the readers check
  the layout of the whole table with vectorised comparisons and only fall back to a careful
  line-by-line parse (which names the offending line) when that check fails.
* Channel angles: :func:`compose_channels` turns per-frame angles about named axes (``"x"``,
  ``"y"``, ``"z"``) into unit quaternions (w first), :func:`decompose_channels` inverts it. With
  ``intrinsic=False`` (ASF/AMC) the first listed axis is applied first
  (``R = R_c2 @ R_c1 @ R_c0``); with ``intrinsic=True`` (BVH) ``R = R_c0 @ R_c1 @ R_c2``. One and
  two axes are extracted in closed form (not through a 3-axis Euler), so a file's angles come
  back as written when they lie in ``(-pi, pi]``.
* Writers go through :func:`atomic_write`: the text goes to a temporary file in the target's
  folder, which is renamed over the target, so no reader ever sees a half-written file.
"""

from __future__ import annotations

import codecs
import itertools
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numba
import numpy as np
from numpy.typing import NDArray

from quatmotion import limits, quat
from quatmotion._atomic import atomic_write_bytes
from quatmotion.errors import FormatError
from quatmotion.quat.jit import about_axis, multiply

# Bytes that never occur in a text file: C0 controls except tab, LF, VT, FF, CR; and DEL.
_BINARY = re.compile(rb"[\x00-\x08\x0e-\x1f\x7f]")
_TEXT_BYTES = bytes(b for b in range(256) if not _BINARY.match(bytes([b])))


_UTF8_BOM = b"\xef\xbb\xbf"
_LATIN1_FALLBACK = "quatmotion-latin1"


def _as_latin1(error: UnicodeError) -> tuple[str, int]:
    """Codec error handler: a byte that is not UTF-8 is the Latin-1 character it encodes."""
    if not isinstance(error, UnicodeDecodeError):
        raise error
    return error.object[error.start : error.end].decode("latin-1"), error.end


codecs.register_error(_LATIN1_FALLBACK, _as_latin1)
_ASCII_SPACE = re.compile(r"[ \t\n\r\x0b\x0c]+")


def fields(line: str) -> list[str]:
    """The tokens of ``line``, split at ASCII white space only (``str.split()`` without
    arguments also splits at U+0085, U+00A0, U+3000..., which occur inside UTF-8 names)."""
    if line.isascii():
        return line.split()
    return [token for token in _ASCII_SPACE.split(line) if token]


def read_text(path: str | Path) -> str:
    """The whole file as a string (UTF-8, Latin-1 for bytes that are not), refusing binary
    content.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    str
        The text with line endings normalised to ``\\n``.

    Raises
    ------
    FormatError
        If the file contains control bytes that no text file has (naming the line).
    OSError
        If the file cannot be read.
    """
    return decode_text(read_bytes(path), path)


def read_bytes(path: str | Path) -> bytes:
    """The whole file, its size checked against the limits first (``file_bytes``); a file that
    is no regular file (a pipe, a device) is read up to the limit and refused beyond it.

    Raises
    ------
    FormatError
        A file larger than :func:`quatmotion.limits.current` allows.
    OSError
        If the file cannot be read.
    """
    ceiling = limits.current().file_bytes
    with open(path, "rb") as file:
        size = os.fstat(file.fileno()).st_size
        limits.check("file_bytes", size, path, "the file's size")
        data = file.read(ceiling + 1)
    limits.check("file_bytes", len(data), path, "the file's size")
    return data


def check_count(
    text: str, pattern: re.Pattern[str], limit: str, allowed: int, path: str | Path, what: str
) -> None:
    """Refuse a text in which ``pattern`` occurs more than ``allowed`` times, naming the line
    of the first occurrence too many: a count in C over the raw text, before a parser builds
    anything per occurrence. ``limit`` names the :class:`quatmotion.limits.Limits` field."""
    beyond = next(itertools.islice(pattern.finditer(text), allowed, None), None)
    if beyond is not None:
        line = text.count("\n", 0, beyond.start()) + 1
        limits.check(limit, allowed + 1, path, f"{what} (at least)", line)


def decode_text(data: bytes, path: str | Path) -> str:
    """The bytes of a text file as a string: :func:`read_text` without reading a file.

    Parameters
    ----------
    data : bytes
        The whole file.
    path : str or Path
        The name messages give (it is not opened).

    Returns
    -------
    str
        The text (UTF-8; a byte outside a UTF-8 sequence as its Latin-1 character) with line
        endings normalised to ``\\n``.

    Raises
    ------
    FormatError
        If ``data`` holds control bytes that no text file has (naming the line).
    """
    if data.startswith(_UTF8_BOM):  # Windows editors start text files with one
        data = data[len(_UTF8_BOM) :]
    # bytes.translate deleting every allowed byte is a fast C scan; the regex only locates.
    bad = _BINARY.search(data) if data.translate(None, _TEXT_BYTES) else None
    if bad is not None:
        line = data.count(b"\n", 0, bad.start()) + 1
        raise FormatError(f"not a text file (byte 0x{data[bad.start()]:02x})", path, line)
    text = data.decode("utf-8", errors=_LATIN1_FALLBACK)
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    return text


def parse_float(token: str, path: str | Path, line: int, what: str = "number") -> float:
    """One finite float, or a FormatError naming ``path:line`` and ``what`` was expected."""
    try:
        value = float(token)
    except ValueError:
        raise FormatError(f"expected a number ({what}), got {token!r}", path, line) from None
    if not np.isfinite(value):
        raise FormatError(f"{what} is not finite: {token!r}", path, line)
    return value


def parse_floats(
    tokens: Sequence[str], path: str | Path, line: int, what: str = "number"
) -> list[float]:
    """Several finite floats (see :func:`parse_float`)."""
    return [parse_float(t, path, line, what) for t in tokens]


def parse_int(token: str, path: str | Path, line: int, what: str = "integer") -> int:
    """One integer, or a FormatError naming ``path:line``."""
    try:
        return int(token)
    except ValueError:
        raise FormatError(f"expected an integer ({what}), got {token!r}", path, line) from None


def atomic_write(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically, encoded as UTF-8 (ASCII for ASCII names)."""
    atomic_write_bytes(path, text.encode("utf-8"))


_AXIS_INDEX = {"x": 1, "y": 2, "z": 3}


def compose_channels(
    angles: NDArray[np.float64], axes: str, intrinsic: bool
) -> NDArray[np.float64]:
    """Unit quaternions of rotations about ``axes`` in turn.

    Parameters
    ----------
    angles : ndarray, shape (..., k)
        Radians, ``angles[..., i]`` about axis ``axes[i]``.
    axes : str
        ``k`` letters of ``xyz`` (0 to 3, no repeats), lower case.
    intrinsic : bool
        ``True``: ``R = R_a0 @ R_a1 @ R_a2`` (BVH); ``False``: ``R = R_a2 @ R_a1 @ R_a0`` (ASF).

    Returns
    -------
    ndarray, shape (..., 4)
    """
    angles = np.asarray(angles, dtype=np.float64)
    if len(axes) == 3:
        return quat.from_euler(angles, axes.upper() if intrinsic else axes.lower())
    out = quat.identity(angles.shape[:-1])
    for i, axis in enumerate(axes):
        e = quat.about_axis(angles[..., i], axis)
        out = e if i == 0 else (quat.multiply(out, e) if intrinsic else quat.multiply(e, out))
    return out


def _sign_of_product(later: str, first: str) -> tuple[int, float]:
    """Index and sign of ``e_later * e_first = sign * e_third`` for unit quaternion axes."""
    product = quat.multiply(quat.about_axis(np.pi, later), quat.about_axis(np.pi, first))
    third = int(np.argmax(np.abs(product[1:]))) + 1
    return third, float(np.sign(product[third]))


def decompose_channels(q: NDArray[np.float64], axes: str, intrinsic: bool) -> NDArray[np.float64]:
    """Angles about ``axes`` of unit quaternions: the inverse of :func:`compose_channels`.

    Parameters
    ----------
    q : ndarray, shape (..., 4)
    axes : str
        0 to 3 distinct lower-case letters of ``xyz``.
    intrinsic : bool
        See :func:`compose_channels`.

    Returns
    -------
    ndarray, shape (..., k)
        Radians in ``(-pi, pi]`` (the middle of three in ``[-pi/2, pi/2]``). For one or two axes
        the closed form below is exact for rotations about those axes; a rotation with a
        component about another axis gets the angles of its parts about the named axes.
    """
    q = np.asarray(q, dtype=np.float64)
    k = len(axes)
    if k == 0:
        return np.zeros((*q.shape[:-1], 0))
    if k == 3:
        return quat.to_euler(q, axes.upper() if intrinsic else axes.lower())
    w = q[..., 0]
    if k == 1:
        qi = q[..., _AXIS_INDEX[axes]]
        # Sign-invariant: atan2(sin a, cos a) from the double-angle forms, exact for q and -q.
        return np.arctan2(2 * w * qi, w * w - qi * qi)[..., None]
    # Two axes: write the rotation extrinsically as R_second(b) @ R_first(a).
    first, second = (axes[1], axes[0]) if intrinsic else (axes[0], axes[1])
    third, s = _sign_of_product(second, first)
    qi, qk, qj = q[..., _AXIS_INDEX[first]], q[..., _AXIS_INDEX[second]], q[..., third]
    # q = (cb + sb e_k)(ca + sa e_i) = cb ca + cb sa e_i + sb ca e_k + s sb sa e_j (half angles).
    a = np.arctan2(2 * (qi * w + s * qj * qk), (w * w + qk * qk) - (qi * qi + qj * qj))
    b = np.arctan2(2 * (w * qk + s * qi * qj), (w * w + qi * qi) - (qk * qk + qj * qj))
    return np.stack((b, a) if intrinsic else (a, b), axis=-1)


# --------------------------------------------------------------------------------------------
# Bulk number scanning
# --------------------------------------------------------------------------------------------

_POW10 = np.array([10.0**k for k in range(23)])


@numba.njit(cache=True, nogil=True)
def _scan_tokens(buf, pow10):  # pragma: no cover - compiled
    n = buf.shape[0]
    cap = n // 2 + 1
    values = np.empty(cap, dtype=np.float64)
    numeric = np.empty(cap, dtype=np.bool_)
    hashes = np.empty(cap, dtype=np.uint64)
    lines = np.empty(cap, dtype=np.int64)
    count = 0
    line = 0
    i = 0
    while i < n:
        c = buf[i]
        if c == 10:
            line += 1
            i += 1
            continue
        if c == 32 or c == 9 or c == 11 or c == 12 or c == 13:
            i += 1
            continue
        start = i
        while i < n:
            c = buf[i]
            if c == 32 or c == 9 or c == 10 or c == 11 or c == 12 or c == 13:
                break
            i += 1
        end = i
        # Number grammar: [+-]? digits [. digits] [(e|E) [+-]? digits], at least one digit.
        k = start
        negative = False
        if buf[k] == 43 or buf[k] == 45:
            negative = buf[k] == 45
            k += 1
        mantissa = np.int64(0)
        digits = 0
        kept = 0
        exponent = 0
        while k < end and 48 <= buf[k] <= 57:
            if kept < 18:
                mantissa = mantissa * 10 + (buf[k] - 48)
                if mantissa > 0:
                    kept += 1
            else:
                exponent += 1
            digits += 1
            k += 1
        if k < end and buf[k] == 46:
            k += 1
            while k < end and 48 <= buf[k] <= 57:
                if kept < 18:
                    mantissa = mantissa * 10 + (buf[k] - 48)
                    exponent -= 1
                    if mantissa > 0:
                        kept += 1
                digits += 1
                k += 1
        ok = digits > 0
        if ok and k < end and (buf[k] == 101 or buf[k] == 69):
            k += 1
            exp_negative = False
            if k < end and (buf[k] == 43 or buf[k] == 45):
                exp_negative = buf[k] == 45
                k += 1
            exp_digits = 0
            e = 0
            while k < end and 48 <= buf[k] <= 57:
                if e < 100000:
                    e = e * 10 + (buf[k] - 48)
                exp_digits += 1
                k += 1
            ok = exp_digits > 0
            exponent += -e if exp_negative else e
        ok = ok and k == end
        value = 0.0
        if ok:
            # Exact when both mantissa and 10^|exponent| are exact doubles (Clinger's fast path),
            # within an ulp or two otherwise.
            m = float(mantissa)
            if exponent == 0:
                value = m
            elif 0 < exponent <= 22:
                value = m * pow10[exponent]
            elif -22 <= exponent < 0:
                value = m / pow10[-exponent]
            elif exponent < -300:
                value = m * 10.0 ** (exponent + 300) * 1e-300
            else:
                value = m * 10.0**exponent
            if negative:
                value = -value
        # FNV-1a of names (numbers get 0), to compare them without making Python strings.
        h = np.uint64(0)
        if not ok:
            h = np.uint64(14695981039346656037)
            for k in range(start, end):
                h = (h ^ np.uint64(buf[k])) * np.uint64(1099511628211)
        values[count] = value
        numeric[count] = ok
        hashes[count] = h
        lines[count] = line
        count += 1
    return values[:count], numeric[:count], hashes[:count], lines[:count]


def token_hash(token: str) -> int:
    """The hash :func:`scan_tokens` gives a token (FNV-1a 64 of its UTF-8 bytes)."""
    h = 14695981039346656037
    for byte in token.encode("utf-8"):
        h = ((h ^ byte) * 1099511628211) & 0xFFFFFFFFFFFFFFFF
    return h


def scan_tokens(
    text: str,
) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.uint64], NDArray[np.int64]]:
    """Split ``text`` at ASCII white space and parse every token that is a decimal number, in
    one pass.

    Compiled with Numba: this is the bulk path of the readers (hundreds of MB/s).

    Parameters
    ----------
    text : str
        Text as :func:`read_text` returns it (scanned as its UTF-8 bytes).

    Returns
    -------
    values : ndarray of float, shape (N,)
        The value of each token (0 where it is not a number).
    numeric : ndarray of bool, shape (N,)
        Whether each token is a plain decimal number (``[+-]digits[.digits][e[+-]digits]``;
        ``nan``, ``inf`` and anything else are not).
    hashes : ndarray of uint64, shape (N,)
        :func:`token_hash` of each token that is not a number (0 for numbers), to compare
        names in bulk.
    lines : ndarray of int, shape (N,)
        0-based line of each token within ``text``.
    """
    buf = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    if buf.size == 0:
        return (
            np.zeros(0),
            np.zeros(0, dtype=bool),
            np.zeros(0, dtype=np.uint64),
            np.zeros(0, dtype=np.int64),
        )
    return _scan_tokens(buf, _POW10)


@numba.njit(cache=True, nogil=True)
def _compose_axis_angles(angles, axis_vectors, n_axes, intrinsic):  # pragma: no cover - compiled
    T, J = angles.shape[0], angles.shape[1]
    out = np.empty((T, J, 4))
    for t in range(T):
        for j in range(J):
            w, x, y, z = 1.0, 0.0, 0.0, 0.0
            for i in range(n_axes[j]):
                u = axis_vectors[j, i]
                ew, ex, ey, ez = about_axis(angles[t, j, i], u[0], u[1], u[2])
                if intrinsic:  # q <- q e
                    w, x, y, z = multiply(w, x, y, z, ew, ex, ey, ez)
                else:  # q <- e q
                    w, x, y, z = multiply(ew, ex, ey, ez, w, x, y, z)
            out[t, j, 0] = w
            out[t, j, 1] = x
            out[t, j, 2] = y
            out[t, j, 3] = z
    return out


def compose_joint_channels(
    values: NDArray[np.float64],
    columns: NDArray[np.int64],
    letters: Sequence[str],
    intrinsic: bool,
    pre_rotations: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Local rotations of all joints from a table of channel angles, in one compiled pass.

    Parameters
    ----------
    values : ndarray, shape (T, V)
        Angles in radians (other columns ignored).
    columns : ndarray of int, shape (J, 3)
        ``columns[j, i]`` is the column of joint ``j``'s ``i``-th rotation channel (``-1`` when
        it has fewer).
    letters : sequence of str, length J
        Each joint's rotation axes in channel order (``""`` to ``"xyz"``).
    intrinsic : bool
        See :func:`compose_channels`.
    pre_rotations : ndarray, shape (J, 4), optional
        ``C`` of each joint: the result is ``C M C^-1`` (computed as rotations about the axes
        ``C e_i``, which is the same rotation).

    Returns
    -------
    ndarray, shape (T, J, 4)
        Unit quaternions, w first.
    """
    J = len(letters)
    T = values.shape[0]
    axis_vectors = np.zeros((J, 3, 3))
    n_axes = np.array([len(a) for a in letters], dtype=np.int64)
    for j, axes in enumerate(letters):
        for i, axis in enumerate(axes):
            axis_vectors[j, i, _AXIS_INDEX[axis] - 1] = 1.0
    if pre_rotations is not None:
        axis_vectors = quat.rotate(np.asarray(pre_rotations)[:, None, :], axis_vectors)
    padded = np.concatenate((values, np.zeros((T, 1))), axis=1)
    angles = padded[:, np.where(columns < 0, values.shape[1], columns)]
    return _compose_axis_angles(np.ascontiguousarray(angles), axis_vectors, n_axes, intrinsic)
