"""The QSSD paper's compression pipeline (Fig. 2), with QSSD or with the Euclidean K-SVD.

1. **Preprocessing**: the layout's reference pose; the root's translation and orientation
   (heading and tilt channels) kept apart; every other rotating joint as its angular
   displacement from the reference pose, ``ref^-1 q`` (:mod:`quatmotion.codec.channels`).
2. **Multiscale representation** by a lifting scheme that omits the finest
   :data:`OMITTED_LEVELS` levels of detail: PyWavelets' CDF 5/3 (``bior2.2``, the lifting
   wavelet of JPEG 2000) on the displacement logs and root channels, keeping the
   approximation only (one sample per 8 frames).
3. **Sparse decomposition** of the coarse displacements, one sample per coarse frame and
   ``n`` quaternions (joints) per sample: :class:`~quatmotion.sparse.QSSD` (quaternion
   combination) or :class:`~quatmotion.sparse.KSVD` (linear combination of 4n-vectors), one
   dictionary per layout shared by all its clips. The paper's K = 2000, L = 15, 50 iterations
   give a dictionary larger than our collections' coarse samples; ``K = min(2000, N // 8)``
   (at least 4) is used, ``L = min(15, K)``, 50 iterations.
4. **Quantisation**: atom logs (step ``quality / 512`` rad), weights (step ``quality / 32``),
   root channels (step ``quality / 2`` cm of largest displacement).
5. **Arithmetic coding** with constriction: atom indices uniform over ``K``, weights and
   dictionary and root with the adaptive Laplace coder of :mod:`quatmotion.codec.entropy`.

Decompression inverts each step; QSSD's atoms are combined in descending ``|weight|`` order
(sorted at decode, as the paper does).
"""

from __future__ import annotations

import hashlib
import time
import warnings
from typing import Any

import constriction
import numpy as np
import pywt
import scipy.sparse as sp
from numpy.typing import NDArray

from quatmotion import quat
from quatmotion.codec import entropy
from quatmotion.codec.binary import Reader, Writer
from quatmotion.codec.channels import KIND_ROOT
from quatmotion.codec.library import LayoutInfo, PreparedLibrary
from quatmotion.codec.methods._base import ClipContext, CodingOptions, Method
from quatmotion.errors import FormatError
from quatmotion.sparse import KSVD, QSSD, quaternion_combination

__all__ = ["SparseMethod", "cached_fit_seconds", "clear_fit_cache"]

OMITTED_LEVELS = 3
WAVELET = "bior2.2"
MODE = "smooth"
PAPER_K, PAPER_L, PAPER_ITER = 2000, 15, 50
_GAIN = 2.0 ** (OMITTED_LEVELS / 2)  # DC gain of the approximation after 3 levels
_DICT_UNIT = 512.0
_WEIGHT_UNIT = 32.0
_ROOT_UNIT = 2.0
_FIT_CACHE: dict[str, tuple] = {}
"""Learned dictionaries by samples and options: ``key -> (estimator, K, L, fit seconds)``."""
_FIT_CACHE_SIZE = 32  # every layout of a data set (CMU: one per subject) stays learned


def _sample_joints(info: LayoutInfo) -> NDArray[np.int64]:
    """Rotating joints other than root kinds, whose displacements QSSD models."""
    layout = info.layout
    return np.array(
        [j for j, k in enumerate(layout.kinds) if k != KIND_ROOT and layout.counts[j] > 0],
        dtype=np.int64,
    )


def _root_columns(info: LayoutInfo) -> NDArray[np.int64]:
    """Root translation, root-kind joints' channels and moving joint translations."""
    layout = info.layout
    cols = [0, 1, 2]
    for j, k in enumerate(layout.kinds):
        if k == KIND_ROOT:
            cols += list(range(layout.starts[j], layout.starts[j] + 4))
    for k in range(len(layout.translation_joints)):
        cols += list(range(layout.translation_columns(k).start, layout.translation_columns(k).stop))
    return np.array(cols, dtype=np.int64)


def _coarse(signal: NDArray[np.float64]) -> NDArray[np.float64]:
    """Approximation coefficients after omitting the finest levels: ``(T, c) -> (n, c)``."""
    with warnings.catch_warnings():
        # A clip shorter than the wavelet's support at this level (under about 60 frames) gets
        # coefficients that all feel the boundary; the transform stays exactly invertible and
        # the repair step bounds the error, so pywt's warning says nothing the user can act on.
        warnings.filterwarnings("ignore", message="Level value of", category=UserWarning)
        return pywt.wavedec(signal, WAVELET, mode=MODE, level=OMITTED_LEVELS, axis=0)[0]


def clear_fit_cache() -> None:
    """Forget cached dictionaries (the next encode learns again)."""
    _FIT_CACHE.clear()


def cached_fit_seconds() -> float:
    """Wall time spent learning the dictionaries now cached (since :func:`clear_fit_cache`)."""
    return sum(entry[3] for entry in _FIT_CACHE.values())


def _coarse_length(T: int) -> int:
    """Samples :func:`_coarse` keeps of ``T`` frames."""
    n = T
    for _ in range(OMITTED_LEVELS):
        n = pywt.dwt_coeff_len(n, pywt.Wavelet(WAVELET).dec_len, MODE)
    return n


def _fine(coarse: NDArray[np.float64], T: int) -> NDArray[np.float64]:
    """Inverse of :func:`_coarse` with every omitted detail zero: ``(n, c) -> (T, c)``."""
    sizes = []
    n = T
    for _ in range(OMITTED_LEVELS):
        n = pywt.dwt_coeff_len(n, pywt.Wavelet(WAVELET).dec_len, MODE)
        sizes.append(n)
    details = [np.zeros((s, coarse.shape[1])) for s in reversed(sizes)]
    return pywt.waverec([coarse, *details], WAVELET, mode=MODE, axis=0)[:T]


def _check_samples(name: str, what: str, n: int, T: int) -> None:
    """The clip's frame count (the header's) against the coarse samples its payload holds: a
    count the data contradict is refused (pywt's ValueError, or frames made up, otherwise);
    counts the wavelet's rounding maps to the same samples cannot be told apart."""
    expected = _coarse_length(T)
    if n != expected:
        raise FormatError(
            f"{name} clip: {n:,} {what}, where the header's {T:,} frames make {expected:,} "
            "(a frame count the data contradict)"
        )


def _displacements(X: NDArray[np.float64], info: LayoutInfo, joints) -> NDArray[np.float64]:
    """Rotation-vector displacements ``ref^-1 q`` of ``joints``: ``(T, n, 3)``."""
    from quatmotion.codec.channels import from_channels

    m = from_channels(
        X,
        info.skeleton,
        info.layout,
        info.reference,
        np.ones(len(info.layout.translation_joints), dtype=bool),
        1.0,
    )
    d = quat.multiply(quat.conjugate(info.reference[joints]), m.rotations[:, joints])
    return 2.0 * quat.log(quat.canonicalize(d))


class SparseMethod(Method):
    """The Fig. 2 pipeline with ``learner`` ``"qssd"`` or ``"ksvd"``."""

    default_quality = 1.0

    def __init__(
        self,
        learner: str,
        n_atoms: int = PAPER_K,
        sparsity: int = PAPER_L,
        max_iter: int = PAPER_ITER,
    ):
        if learner not in ("qssd", "ksvd"):
            raise ValueError(f"learner must be 'qssd' or 'ksvd', got {learner!r}")
        self.name = learner
        self.learner = learner
        self.n_atoms = n_atoms
        self.sparsity = sparsity
        self.max_iter = max_iter
        self.fit_seconds = 0.0
        """Wall time of the last dictionary fit (fits are cached on the samples)."""

    # ------------------------------------------------------------------ dictionary
    def _fit(self, samples: NDArray[np.float64], seed: int):
        """Dictionary (K, n, 3 logs for QSSD; K, 4n for K-SVD) and the estimator, cached on
        the samples' bytes (a rate-distortion sweep refits nothing)."""
        N = len(samples)
        K = int(max(4, min(self.n_atoms, N // 8)))
        L = int(min(self.sparsity, K))
        key = hashlib.sha1(
            samples.tobytes() + repr((self.learner, K, L, self.max_iter, seed)).encode()
        ).hexdigest()
        if key not in _FIT_CACHE:
            start = time.perf_counter()
            if self.learner == "qssd":
                est = QSSD(K, sparsity=L, max_iter=self.max_iter, random_state=seed).fit(samples)
            else:
                est = KSVD(K, sparsity=L, max_iter=self.max_iter, random_state=seed).fit(samples)
            if len(_FIT_CACHE) >= _FIT_CACHE_SIZE:
                # Keep several: a library of many skeleton structures learns one per layout,
                # and keeping only the last made every re-encode of it learn them all again.
                del _FIT_CACHE[next(iter(_FIT_CACHE))]
            self.fit_seconds = time.perf_counter() - start
            _FIT_CACHE[key] = (est, K, L, self.fit_seconds)
        est, K, L, _ = _FIT_CACHE[key]
        return est, K, L

    # ------------------------------------------------------------------ encoding
    def _coarse_of(self, library: PreparedLibrary, i: int) -> NDArray[np.float64]:
        """Clip ``i``'s coarse joint rotations (angular displacements, the lifting scheme's
        coarse level), ``(T', 3n)``."""
        clip = library.clips[i]
        info = library.layouts[clip.layout]
        d = _displacements(clip.channels, info, _sample_joints(info))
        return _coarse(d.reshape(clip.channels.shape[0], -1))

    def fit_layout(
        self, library: PreparedLibrary, k: int, members: list[int], options: CodingOptions
    ) -> Any:
        info = library.layouts[k]
        n = len(_sample_joints(info))
        Y = np.concatenate([self._coarse_of(library, i) for i in members])
        samples = quat.canonicalize(quat.exp(Y.reshape(-1, n, 3) / _GAIN / 2.0))
        est, _, _ = self._fit(samples, options.seed)
        model, blob = self._model_bytes(est, info, options.quality)
        model["bytes"] = blob
        return model

    def model_bytes(self, model: Any, layout: LayoutInfo) -> bytes:
        return model.get("bytes", b"")  # a model read from a file is already there

    def encode_clip(
        self, library: PreparedLibrary, i: int, model: Any, options: CodingOptions
    ) -> bytes:
        info = library.layouts[library.clips[i].layout]
        coarse = self._coarse_of(library, i)
        return self._encode_clip(library, i, info, model, coarse, options.quality)

    def _model_bytes(self, est, info: LayoutInfo, quality: float):
        """Quantise the dictionary; returns the decoder's model and its bytes."""
        step = quality / _DICT_UNIT
        if self.learner == "qssd":
            D = est.dictionary_log_.reshape(est.dictionary_log_.shape[0], -1)
        else:
            D = est.dictionary_flat_
        Q = np.round(D / step).astype(np.int64)
        stream = entropy.encode_rows(
            Q, np.full(Q.shape[1], 8.0), np.full(Q.shape[1], 64.0), np.zeros(len(Q), dtype=bool)
        )
        blob = Writer().f32(quality).uvarint(Q.shape[0]).uvarint(Q.shape[1]).blob(stream).bytes()
        model = self.load_model(blob, info)
        model["estimator"] = est
        return model, blob

    def _encode_clip(self, library, i, info, model, coarse, quality) -> bytes:
        clip = library.clips[i]
        joints = _sample_joints(info)
        n = len(joints)
        samples = quat.canonicalize(quat.exp(coarse.reshape(-1, n, 3) / _GAIN / 2.0))
        D = model["dictionary"]
        est = model.get("estimator") or self._coder(D, n)
        W = sp.csr_matrix(self._code(est, D, samples))
        wstep = quality / _WEIGHT_UNIT
        counts = np.diff(W.indptr)
        values = np.round(W.data / wstep).astype(np.int64)
        # root channels: coarse approximation in weighted units
        cols = _root_columns(info)
        scale = info.lever[cols]
        R = np.round(_coarse(clip.channels[:, cols] * scale) / (quality / _ROOT_UNIT)).astype(
            np.int64
        )
        Rd = np.diff(R, axis=0, prepend=0)
        w = Writer().f32(quality).uvarint(len(samples))
        enc = constriction.stream.queue.RangeEncoder()
        K = D.shape[0]
        enc.encode(
            counts.astype(np.int32), constriction.stream.model.Uniform(self._sparsity_for(K) + 1)
        )
        enc.encode(W.indices.astype(np.int32), constriction.stream.model.Uniform(K))
        w.blob(enc.get_compressed().astype("<u4").tobytes())
        w.blob(
            entropy.encode_rows(
                values[:, None], np.array([4.0]), np.array([4.0]), np.zeros(len(values), dtype=bool)
            )
        )
        w.uvarint(len(Rd)).raw(
            entropy.encode_rows(
                Rd, np.full(len(cols), 4.0), np.full(len(cols), 256.0), np.arange(len(Rd)) == 0
            )
        )
        return w.bytes()

    def _coder(self, D: NDArray[np.float64], n: int):
        """An estimator that codes on ``D`` (a dictionary read from a file, when appending):
        the fitted state :meth:`_code` uses, without learning."""
        K = D.shape[0]
        if self.learner == "qssd":
            est = QSSD(K, sparsity=self._sparsity_for(K))
            est.dictionary_log_ = D
            est.dictionary_ = quat.exp(D)
        else:
            est = KSVD(K, sparsity=self._sparsity_for(K))
            est.dictionary_flat_ = D
        est.n_features_in_ = n
        return est

    def _sparsity_for(self, K: int) -> int:
        return int(min(self.sparsity, K))

    def _code(self, est, D, samples):
        """The samples' sparse codes with the quantised dictionary ``D`` the decoder will see
        (set in the estimator for the call: QSSD's in log space, K-SVD's flat)."""
        attribute = "dictionary_log_" if self.learner == "qssd" else "dictionary_flat_"
        saved = getattr(est, attribute)
        setattr(est, attribute, D)
        try:
            return est.transform(samples)
        finally:
            setattr(est, attribute, saved)

    # ------------------------------------------------------------------ decoding
    def load_model(self, data: bytes, layout: LayoutInfo) -> Any:
        r = Reader(data, what=f"{self.name} dictionary")
        quality = r.f32()
        K = r.uvarint(1 << 20)
        width = r.uvarint(1 << 20)
        if not (np.isfinite(quality) and quality > 0) or K < 1:
            raise FormatError(f"{self.name} dictionary: invalid header")
        Q = entropy.decode_rows(
            r.blob(), K, np.full(width, 8.0), np.full(width, 64.0), np.zeros(K, dtype=bool)
        )
        r.end()
        D = Q * (quality / _DICT_UNIT)
        n = len(_sample_joints(layout))
        if self.learner == "qssd":
            if width != 3 * n:
                raise FormatError("qssd dictionary: width does not match the skeleton")
            D = D.reshape(K, n, 3)
        elif width != 4 * n:
            raise FormatError("ksvd dictionary: width does not match the skeleton")
        return {"dictionary": D}

    def decode(self, model: Any, payload: bytes, context: ClipContext) -> NDArray[np.float64]:
        info = context.layout
        joints = _sample_joints(info)
        n = len(joints)
        D = model["dictionary"]
        K = D.shape[0]
        r = Reader(payload, what=f"{self.name} clip")
        quality = r.f32()
        N = r.uvarint(1 << 32)
        _check_samples(self.name, "coarse samples", N, context.n_frames)
        words = r.blob()
        words = np.frombuffer(words + b"\0" * (-len(words) % 4), dtype="<u4").astype(np.uint32)
        dec = constriction.stream.queue.RangeDecoder(words)
        try:
            counts = dec.decode(
                constriction.stream.model.Uniform(self._sparsity_for(K) + 1), N
            ).astype(np.int64)
            indices = dec.decode(constriction.stream.model.Uniform(K), int(counts.sum())).astype(
                np.int64
            )
        except (AssertionError, ValueError) as error:
            raise FormatError(f"{self.name} clip: corrupt atom indices ({error})") from None
        try:
            values = entropy.decode_rows(
                r.blob(),
                len(indices),
                np.array([4.0]),
                np.array([4.0]),
                np.zeros(len(indices), dtype=bool),
            )[:, 0]
            n_root = r.uvarint(1 << 32)
            _check_samples(self.name, "coarse root samples", n_root, context.n_frames)
            cols = _root_columns(info)
            Rd = entropy.decode_rows(
                r.take(r.remaining),
                n_root,
                np.full(len(cols), 4.0),
                np.full(len(cols), 256.0),
                np.arange(n_root) == 0,
            )
        except ValueError as error:
            raise FormatError(f"{self.name} clip: {error}") from None
        W = sp.csr_matrix(
            (values * (quality / _WEIGHT_UNIT), indices, np.r_[0, np.cumsum(counts)]), shape=(N, K)
        )
        if self.learner == "qssd":
            Yq = quaternion_combination(D, W)
        else:
            flat = W @ D
            Yq = flat.reshape(N, n, 4)
            norm = np.linalg.norm(Yq, axis=-1, keepdims=True)
            Yq = np.where(norm > 1e-12, Yq / np.maximum(norm, 1e-12), quat.identity((N, n)))
        coarse = 2.0 * quat.log(quat.canonicalize(Yq)).reshape(N, -1) * _GAIN
        T = context.n_frames
        disp = _fine(coarse, T).reshape(T, n, 3)
        rot = quat.multiply(info.reference[joints], quat.exp(disp / 2.0))
        scale = info.lever[cols]
        root = _fine(np.cumsum(Rd, axis=0) * (quality / _ROOT_UNIT), T) / scale
        return _to_layout_channels(rot, joints, root, cols, context)


def _to_layout_channels(rot, joints, root, cols, context: ClipContext) -> NDArray[np.float64]:
    """Channels of the layout from decoded joint rotations and root channels."""
    from quatmotion.codec.channels import from_channels, to_channels
    from quatmotion.motion import Motion

    info = context.layout
    T = rot.shape[0]
    X = np.zeros((T, info.layout.n_channels))
    X[:, cols] = root
    at_rest = ~np.array(
        [
            context.active[info.layout.translation_columns(k)].any()
            for k in range(len(info.layout.translation_joints))
        ],
        dtype=bool,
    )
    base = from_channels(X, context.skeleton, info.layout, info.reference, at_rest, context.fps)
    rotations = base.rotations.copy()
    rotations[:, joints] = rot
    m = Motion(
        context.skeleton, context.fps, base.root_translation, rotations, base.joint_translations
    )
    out, _ = to_channels(m, info.layout, info.reference)
    out[:, cols] = root
    return out
