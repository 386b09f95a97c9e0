"""Site adaptation of the appearance cue: fitted in numpy/scipy on a site's own unlabelled videos.

The appearance network (``appearance.onnx``) was fine-tuned on renders; at a real site each
camera adds its own colour cast, blur and noise, and the appearance cost ``|a - b| / 2`` of two
views' descriptors loses its meaning. :class:`SiteAdaptation` is a small map on ``(K, D)`` unit
vectors of the network (the pooled activations of its trunk's stages, or of its last stage,
when it gives them: they keep more of what a camera change leaves of a person than the head's
descriptors; else the descriptors; ``vector`` says which), learned from pairs mined on the
site's own videos (:mod:`xvmatch.inference.adaptation.adaptation_pairs`), with no identities:

1. **per-view standardisation** ``x = (d - mean_v) / scale_v`` (``v`` = top or horizontal): a
   camera's colour cast moves all of its descriptors the same way, and this removes it;
2. **a low-rank linear metric** ``z = P^T x`` (``P``: ``(D, r)``), normalised to unit length:
   ``P`` holds the leading generalised eigenvectors of the difference scatter of negative pairs
   against that of positive pairs (``S_neg v = lambda S_pos v``, a whitened LDA / KISSME-style
   metric: directions where the same person differs little and different people differ much),
   the rank ``r`` chosen on held-out pairs; ``r = 0`` denotes the standardisation alone (``P``
   the identity);
3. **the cost** ``|z_a - z_b| / 2``, recalibrated by a logit-affine map
   ``logit(c') = a logit(c) + b`` so that each cost carries the likelihood ratio it carries on
   the renders the network was trained on (a class-balanced logistic fit of "same person" on
   ``logit(c)``, on the site's held-out pairs and on reference renders): the fusion of
   ``matcher.onnx`` sees costs on the scale it was trained with, and a weak cue is pulled towards
   the neutral cost instead of passing for a strong one.

:func:`fit_site_adaptation` fits it (float64, deterministic eigen-solver, no randomness), chooses
the rank by the verification AUC of held-out cross-view pairs (the last part of the video: a
split by time), and refuses (``accepted`` False) when no rank beats the unadapted descriptors
there by more than twice the AUC's standard error. :func:`adaptation_bytes` /
:func:`load_adaptation` store it as ``adaptation.npz`` in a
bundle (read without numpy's loader: each zip member's declared size is bounded by the largest
array its vector allows before it is inflated, each ``.npy`` header checked before any
allocation, no pickle, every array and scalar checked). Numpy and scipy only.
"""

from __future__ import annotations

import io
import math
import os
import zipfile
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from xvmatch.cues.matcher_inputs import appearance_cost

__all__ = [
    "ADAPTATION_FILE",
    "ADAPTATION_FORMAT_VERSION",
    "ADAPTATION_FORMAT_VERSIONS",
    "CALIBRATIONS",
    "DEFAULT_RANKS",
    "MAX_NUMBER_BYTES",
    "NEUTRAL_SLOPE",
    "NPY_HEADER_BYTES",
    "RIDGE",
    "SCALE_FLOOR",
    "VECTORS",
    "VIEWS",
    "ZIP_ENTRY_BYTES",
    "AdaptationFit",
    "PairSet",
    "SiteAdaptation",
    "adaptation_array_bytes",
    "adaptation_bytes",
    "auc_standard_error",
    "better_than_chance",
    "choose_fit",
    "fit_site_adaptation",
    "load_adaptation",
    "pair_auc",
]

ADAPTATION_FILE = "adaptation.npz"
"""The adaptation's file name in a site bundle."""
ADAPTATION_FORMAT_VERSION = 2
"""Version of the arrays stored in ``adaptation.npz`` (2 added ``vector``)."""
ADAPTATION_FORMAT_VERSIONS: tuple[int, ...] = (1, 2)
"""Versions read (a version 1 file maps the descriptors)."""
VECTORS: tuple[str, ...] = ("descriptors", "features", "stages")
"""What an adaptation maps: the network's unit descriptors, its pooled trunk activations (the
head's input), or the pooled activations of each stage of the trunk (more of what a camera
change leaves of a person at each step, docs/adaptation.md)."""
RIDGE: dict[str, float] = {"descriptors": 0.01, "features": 0.3, "stages": 0.3}
"""Default ridge of the positive scatter per vector: the 1,280 features (1,976 stages) need more
than the 128 descriptors with a few hundred pairs (measured on the adaptation benchmark's
renders)."""
VIEWS: tuple[str, ...] = ("top", "hor")
"""The two views, each with its own standardisation."""
DEFAULT_RANKS: tuple[int, ...] = (0, 2, 4, 8, 16, 32, 64)
"""Ranks tried (0: the standardisation alone); those above the descriptor size are skipped."""
CALIBRATIONS: tuple[str, ...] = ("odds", "median", "site", "none")
"""Ways to recalibrate the adapted cost (:func:`fit_site_adaptation`)."""
_EPS = 1e-6


def _logit(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, _EPS, 1.0 - _EPS)
    return np.log(c) - np.log1p(-c)


@dataclass(frozen=True, eq=False)
class SiteAdaptation:
    """The fitted map of one site (see the module docstring).

    Attributes:
        top_mean, top_scale: ``(D,)`` standardisation of the top view's descriptors.
        hor_mean, hor_scale: ``(D,)`` the same for the horizontal view.
        projection: ``(D, r)`` metric projection (``r = D`` and the identity for rank 0).
        calibration: ``(2,)`` ``a, b`` of the logit-affine cost map (``1, 0``: none).
        rank: the rank chosen (0: the standardisation alone).
        vector: what it maps, one of :data:`VECTORS`.
    """

    top_mean: np.ndarray
    top_scale: np.ndarray
    hor_mean: np.ndarray
    hor_scale: np.ndarray
    projection: np.ndarray
    calibration: np.ndarray
    rank: int
    vector: str = "descriptors"

    @property
    def dim(self) -> int:
        """The descriptor size ``D`` it takes."""
        return int(self.top_mean.shape[0])

    @classmethod
    def identity(cls, dim: int, vector: str = "descriptors") -> SiteAdaptation:
        """The map that changes nothing: descriptors and costs as the network gives them."""
        zeros, ones = np.zeros(dim), np.ones(dim)
        return cls(zeros, ones, zeros.copy(), ones.copy(), np.eye(dim), np.array([1.0, 0.0]), 0,
                   vector)

    def transform(self, descriptors: np.ndarray, view: str) -> np.ndarray:
        """``(K, r)`` float64 unit adapted descriptors of ``(K, D)`` descriptors of ``view``.

        Raises:
            ValueError: an unknown view or a descriptor size other than :attr:`dim`.
        """
        if view not in VIEWS:
            raise ValueError(f"view must be one of {VIEWS}, got {view!r}")
        d = np.asarray(descriptors, dtype=np.float64)
        if d.ndim != 2 or d.shape[1] != self.dim:
            raise ValueError(f"descriptors must be (K, {self.dim}), got {d.shape}")
        mean, scale = ((self.top_mean, self.top_scale) if view == "top"
                       else (self.hor_mean, self.hor_scale))
        z = ((d - mean) / scale) @ self.projection
        norm = np.linalg.norm(z, axis=1, keepdims=True)
        return z / np.maximum(norm, 1e-12)

    def calibrate(self, cost: np.ndarray) -> np.ndarray:
        """The logit-affine map of a raw adapted cost ``|z_a - z_b| / 2`` (in [0, 1])."""
        cost = np.asarray(cost, dtype=np.float64)
        a, b = (float(v) for v in self.calibration)
        if a == 1.0 and b == 0.0:
            return cost
        return 1.0 / (1.0 + np.exp(-(a * _logit(cost) + b)))

    def cost(self, top: np.ndarray, hor: np.ndarray) -> np.ndarray:
        """``(M, N)`` adapted appearance cost in [0, 1] of raw top ``(M, D)`` and horizontal
        ``(N, D)`` descriptors: the cue ``matcher.onnx`` receives."""
        return self.calibrate(appearance_cost(self.transform(top, "top"),
                                              self.transform(hor, "hor")))

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays stored in ``adaptation.npz``."""
        return {"format_version": np.array(ADAPTATION_FORMAT_VERSION),
                "top_mean": self.top_mean, "top_scale": self.top_scale,
                "hor_mean": self.hor_mean, "hor_scale": self.hor_scale,
                "projection": self.projection, "calibration": self.calibration,
                "rank": np.array(self.rank), "vector": np.array(self.vector)}


def adaptation_bytes(adaptation: SiteAdaptation) -> bytes:
    """``adaptation.npz``'s bytes (uncompressed, float64; the same fit gives the same bytes)."""
    buf = io.BytesIO()
    np.savez(buf, **adaptation.arrays())
    return buf.getvalue()


MAX_NUMBER_BYTES = 8
"""Widest number an array of ``adaptation.npz`` may hold, in bytes: :func:`adaptation_bytes`
writes float64 and int64; wider ones (``longdouble``, complex) are refused."""
NPY_HEADER_BYTES = 10_000
"""Largest ``.npy`` header of an array, in bytes (numpy's own ``max_header_size``; the headers
:func:`adaptation_bytes` writes are 128 bytes)."""
ZIP_ENTRY_BYTES = 1_024
"""Room for each array's zip headers (local and central, with zip64 extras: about 200 bytes)."""
SCALE_FLOOR = 1e-6
"""Smallest standardisation scale a fit gives (:func:`fit_site_adaptation` floors each
descriptor's spread there); a stored smaller one is refused."""
_ARRAYS = ("format_version", "vector", "rank", "top_mean", "top_scale", "hor_mean", "hor_scale",
           "calibration", "projection")
"""The arrays of ``adaptation.npz``, in the order they are read."""
_READ_ERRORS = (OSError, EOFError, ValueError, RuntimeError, NotImplementedError,
                zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error)
"""What reading a corrupt, truncated or crafted zip may raise (CRC, inflate, header errors)."""


def adaptation_array_bytes(dim: int) -> dict[str, int]:
    """The most bytes each array of ``adaptation.npz`` may declare for a vector of size
    ``dim`` (``.npy`` header included): its largest shape (the projection ``(D, D)`` at rank 0,
    each standardisation ``(D,)``, the calibration ``(2,)``, scalars, the longest name of
    :data:`VECTORS`) at :data:`MAX_NUMBER_BYTES` a number (4 bytes a character), plus
    :data:`NPY_HEADER_BYTES`. A zip member declaring more is refused before it is inflated."""
    numbers = {"format_version": 1, "rank": 1, "calibration": 2, "projection": dim * dim,
               **{k: dim for k in ("top_mean", "top_scale", "hor_mean", "hor_scale")}}
    out = {k: n * MAX_NUMBER_BYTES + NPY_HEADER_BYTES for k, n in numbers.items()}
    out["vector"] = 4 * max(map(len, VECTORS)) + NPY_HEADER_BYTES
    return out


def _file_bytes(dims: Callable[[str], int | None]) -> int:
    """The most bytes ``adaptation.npz`` may hold for the network of ``dims``: every array of
    its largest vector at its bound (:func:`adaptation_array_bytes`), with its zip headers."""
    largest = max((d for d in map(dims, VECTORS) if d is not None), default=0)
    return sum(adaptation_array_bytes(largest).values()) + ZIP_ENTRY_BYTES * (len(_ARRAYS) + 1)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return (text.splitlines()[0] if text else type(exc).__name__)[:120]


def _npy_array(data: bytes, key: str) -> np.ndarray:
    """The array of one member's ``.npy`` bytes, its header checked before any allocation: a
    plain numeric or text dtype of at most :data:`MAX_NUMBER_BYTES` a number, and exactly as
    many bytes as its shape needs (no pickle is ever read)."""
    from numpy.lib import format as npy

    fp = io.BytesIO(data)
    version = npy.read_magic(fp)
    if version not in ((1, 0), (2, 0)):
        raise ValueError(f"array {key!r}: .npy format version {version} is not read")
    read = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
    shape, fortran, dtype = read(fp, max_header_size=NPY_HEADER_BYTES)
    wide = dtype.kind != "U" and dtype.itemsize > MAX_NUMBER_BYTES
    if dtype.hasobject or dtype.kind not in "biufU" or dtype.fields is not None or wide:
        raise ValueError(f"array {key!r} must hold plain numbers of at most "
                         f"{MAX_NUMBER_BYTES} bytes, got {dtype}")
    count = math.prod(shape)
    if count * dtype.itemsize != len(data) - fp.tell():
        raise ValueError(f"array {key!r}: its header says {shape} {dtype} "
                         f"({count * dtype.itemsize:,} bytes), the file holds "
                         f"{len(data) - fp.tell():,}; truncated or corrupt")
    flat = np.frombuffer(data, dtype=dtype, count=count, offset=fp.tell())
    return flat.reshape(shape, order="F" if fortran else "C").copy()


def _read_array(archive: zipfile.ZipFile, key: str, bound: int) -> np.ndarray:
    """Array ``key`` of the archive, its declared size checked against ``bound`` before it is
    inflated (a zip bomb is refused unread)."""
    info = next((i for i in archive.infolist() if i.filename == f"{key}.npy"), None)
    if info is None:
        raise ValueError(f"array {key!r} is missing")
    if info.file_size > bound:
        raise ValueError(f"array {key!r} declares {info.file_size:,} bytes, more than the "
                         f"{bound:,} it may hold; not an adaptation file that adapt writes")
    try:
        with archive.open(info) as member:
            data = member.read(bound + 1)  # zipfile stops at the declared size
    except _READ_ERRORS as exc:
        raise ValueError(f"array {key!r} is unreadable ({_first_line(exc)})") from None
    try:
        return _npy_array(data, key)
    except _READ_ERRORS as exc:
        if str(exc).startswith(f"array {key!r}"):  # the header's own checks, one line
            raise
        raise ValueError(f"array {key!r} is unreadable ({_first_line(exc)})") from None


def _integer(value: np.ndarray, key: str, low: int, high: int) -> int:
    """A stored scalar checked to be an integer (not a bool, not a float, even a whole one) in
    ``low..high``."""
    if value.shape != () or value.dtype.kind not in "iu":
        got = (f"{value.item()!r} ({value.dtype})" if value.shape == () else
               f"{value.dtype} of shape {value.shape}")
        raise ValueError(f"array {key!r} must be an integer, got {got}")
    number = int(value)
    if not low <= number <= high:
        raise ValueError(f"array {key!r} must be in {low}..{high}, got {number}")
    return number


def _vector_of(archive: zipfile.ZipFile, version: int, bound: int) -> str:
    """What a file of format ``version`` maps (``descriptors`` before version 2)."""
    if version < 2:
        return "descriptors"
    v = _read_array(archive, "vector", bound)
    if v.shape != () or v.dtype.kind != "U" or str(v) not in VECTORS:
        raise ValueError(f"array 'vector' must be one of {VECTORS}")
    return str(v)


def _checked_maps(arrays: dict[str, np.ndarray], dim: int, rank: int) -> None:
    """The standardisations, calibration and projection checked for shape, type and sense."""
    want = {k: (dim,) for k in ("top_mean", "top_scale", "hor_mean", "hor_scale")}
    want["calibration"] = (2,)
    for key, shape in want.items():
        if arrays[key].shape != shape or arrays[key].dtype.kind not in "fiu":
            raise ValueError(f"array {key!r} must be numbers of shape {shape}, got "
                             f"{arrays[key].dtype} {arrays[key].shape}")
    proj, cols = arrays["projection"], dim if rank == 0 else rank
    if proj.shape != (dim, cols) or proj.dtype.kind != "f":
        raise ValueError(f"array 'projection' must be ({dim}, {cols}) floats for rank {rank}")
    for key in (*want, "projection"):
        if not np.isfinite(arrays[key]).all():
            raise ValueError(f"array {key!r} holds NaN or infinite values")
    for key in ("top_scale", "hor_scale"):
        if (arrays[key] < SCALE_FLOOR).any():
            raise ValueError(f"array {key!r} must be > 0, at least {SCALE_FLOOR:g} (the "
                             "smallest spread a fit gives)")
    if arrays["calibration"][0] <= 0:
        raise ValueError("array 'calibration' must have a slope > 0")


def _read_adaptation(archive: zipfile.ZipFile, dims: Callable[[str], int | None]
                     ) -> SiteAdaptation:
    """:func:`load_adaptation` of an opened archive."""
    small = adaptation_array_bytes(0)
    version = _integer(_read_array(archive, "format_version", small["format_version"]),
                       "format_version", 0, 2**31)
    if version not in ADAPTATION_FORMAT_VERSIONS:
        raise ValueError(f"format version {version}, this xvmatch reads "
                         f"{', '.join(map(str, ADAPTATION_FORMAT_VERSIONS))}; run xvmatch adapt "
                         "again")
    vector = _vector_of(archive, version, small["vector"])
    dim = dims(vector)
    if dim is None:
        raise ValueError(f"it maps the network's {vector}, which this bundle's appearance "
                         "network does not give; run xvmatch adapt again")
    bounds = adaptation_array_bytes(dim)
    rank = _integer(_read_array(archive, "rank", bounds["rank"]), "rank", 0, dim)
    arrays = {k: _read_array(archive, k, bounds[k]) for k in _ARRAYS[3:]}
    _checked_maps(arrays, dim, rank)
    f64 = {k: np.asarray(v, dtype=np.float64) for k, v in arrays.items()}
    return SiteAdaptation(f64["top_mean"], f64["top_scale"], f64["hor_mean"], f64["hor_scale"],
                          f64["projection"], f64["calibration"], rank, vector)


def load_adaptation(path: str | os.PathLike,
                    dims: Callable[[str], int | None]) -> SiteAdaptation:
    """Read ``adaptation.npz``, every array checked against the vector it maps.

    The file is opened without blocking (a FIFO or a device is refused at once) and read whole
    only when no larger than a complete adaptation of the network's largest vector can be;
    each zip member's declared size is checked against the most its array may hold
    (:func:`adaptation_array_bytes`) before it is inflated, and each ``.npy`` header before any
    allocation; no pickle is ever read.

    Args:
        path: the file.
        dims: the size of each vector the network gives (``vector -> size or None``, e.g.
            :meth:`xvmatch.inference.matching.bundle.AppearanceSpec.dim`).

    Raises:
        ValueError: one line naming the array: unreadable (truncated, not a zip, a bad CRC), a
            pickled object, larger than its shape allows, missing, of the wrong shape or type
            (``format_version`` and ``rank`` must be integers, ``rank`` in ``0..D``), not
            finite, a scale under :data:`SCALE_FLOOR`, a calibration slope <= 0, a vector the
            network does not give.
    """
    from xvmatch.core.input_files import InputFileError, read_input_bytes

    try:
        data = read_input_bytes(path, max_bytes=_file_bytes(dims))
    except InputFileError as exc:
        reason = str(exc).removeprefix(f"{os.fspath(path)}: ")
        raise ValueError(f"not a readable adaptation file ({reason})") from None
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except _READ_ERRORS as exc:
        raise ValueError(f"not a readable adaptation file ({_first_line(exc)})") from None
    with archive:
        return _read_adaptation(archive, dims)


@dataclass(frozen=True, eq=False)
class PairSet:
    """Descriptors of a site's boxes and the pairs mined among them (no identities).

    Attributes:
        top, hor: ``(K_v, D)`` raw descriptors of the boxes of each view.
        within_pos, within_neg: ``{view: (P, 2)}`` index pairs into that view's descriptors:
            the same tracklet in two frames / two boxes of one frame.
        cross_pos, cross_neg: ``(P, 2)`` index pairs ``(top, hor)``: confident pseudo-matches
            of the box-only matcher / a pseudo-matched box against another box of its frame.
        within_group, cross_pos_group, cross_neg_group: the time group (burst) of each pair,
            ``{view: (P,)}`` for the within-view positives and negatives stacked in that order,
            for the held-out split by time.
        vector: what ``top`` and ``hor`` hold, one of :data:`VECTORS`.
    """

    top: np.ndarray
    hor: np.ndarray
    within_pos: dict[str, np.ndarray]
    within_neg: dict[str, np.ndarray]
    cross_pos: np.ndarray
    cross_neg: np.ndarray
    within_pos_group: dict[str, np.ndarray] = field(default_factory=dict)
    within_neg_group: dict[str, np.ndarray] = field(default_factory=dict)
    cross_pos_group: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    cross_neg_group: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    vector: str = "descriptors"

    def counts(self) -> dict[str, int]:
        """How many pairs of each kind (for the manifest's record)."""
        out = {"cross_pos": len(self.cross_pos), "cross_neg": len(self.cross_neg)}
        for v in VIEWS:
            out[f"{v}_pos"] = len(self.within_pos[v])
            out[f"{v}_neg"] = len(self.within_neg[v])
        return out


@dataclass(frozen=True, eq=False)
class AdaptationFit:
    """The outcome of :func:`fit_site_adaptation`.

    Attributes:
        adaptation: the map (fitted on all pairs with the rank chosen); the identity when
            refused.
        accepted: whether it beat the unadapted descriptors on the held-out pairs.
        reason: why it was refused ('' when accepted).
        auc_before: held-out cross-view verification AUC of the unadapted cost.
        auc_after: that of the chosen rank (fitted without the held-out pairs).
        auc_by_rank: ``{rank: held-out AUC}`` of every rank tried.
        heldout_pairs: ``(positives, negatives)`` held out.
    """

    adaptation: SiteAdaptation
    accepted: bool
    reason: str
    auc_before: float
    auc_after: float
    auc_by_rank: dict[int, float]
    heldout_pairs: tuple[int, int]


def choose_fit(fits: Mapping[str, AdaptationFit]) -> AdaptationFit:
    """The fit to keep of several fitted on the same pairs, one per vector (``{vector: fit}``,
    in order of preference): the accepted one with the highest held-out AUC (both measured on
    the same held-out pairs), the earlier on a tie; none accepted, the first one's refusal.

    Each vector can fail where the other helps: on a rendered scene the features' fit was
    refused where the descriptors' gained 9 CVIDF1 points (docs/adaptation.md).
    """
    if not fits:
        raise ValueError("no fit to choose from")
    accepted = [f for f in fits.values() if f.accepted]
    if not accepted:
        return next(iter(fits.values()))
    return max(accepted, key=lambda f: f.auc_after)  # max keeps the first of equals


def pair_auc(pos: np.ndarray, neg: np.ndarray) -> float:
    """Verification AUC of costs: the probability that a positive pair costs less than a
    negative one (ties count half; Mann-Whitney U over ranks). NaN without both kinds."""
    pos, neg = np.asarray(pos, np.float64).ravel(), np.asarray(neg, np.float64).ravel()
    if pos.size == 0 or neg.size == 0:
        return float("nan")
    # average ranks (ties share the mean of their places), in numpy: scipy.stats alone takes
    # half a second to import, and associate's appearance check calls this once per run
    x = np.concatenate([pos, neg])
    order = np.argsort(x, kind="stable")
    starts = np.r_[0, np.flatnonzero(np.diff(x[order])) + 1]
    ends = np.r_[starts[1:], x.size]
    ranks = np.empty(x.size)
    ranks[order] = np.repeat((starts + ends + 1) / 2.0, ends - starts)
    u = ranks[: pos.size].sum() - pos.size * (pos.size + 1) / 2.0
    return float(1.0 - u / (pos.size * neg.size))


def auc_standard_error(auc: float, n_pos: int, n_neg: int) -> float:
    """Standard error of an AUC measured on ``n_pos`` positives and ``n_neg`` negatives (Hanley
    and McNeil, Radiology 1982, Eq. 2)."""
    a = float(auc)
    q1, q2 = a / (2.0 - a), 2.0 * a * a / (1.0 + a)
    var = (a * (1 - a) + (n_pos - 1) * (q1 - a * a) + (n_neg - 1) * (q2 - a * a)) / max(
        n_pos * n_neg, 1)
    return float(np.sqrt(max(var, 0.0)))


def better_than_chance(auc: float, pairs: tuple[int, int], min_gain: float = 0.005) -> bool:
    """Whether a held-out verification AUC measured on ``pairs`` ``(positives, negatives)`` is
    above chance (0.5) by more than ``min_gain`` and twice its standard error: the same bar
    :func:`fit_site_adaptation` sets an adaptation against the unadapted cost."""
    if not np.isfinite(auc) or min(pairs) < 1:
        return False
    return auc >= 0.5 + max(min_gain, 2.0 * auc_standard_error(auc, *pairs))


def _scatter(diff: list[np.ndarray], weights: list[float], dim: int) -> np.ndarray:
    """Weighted mean over groups of each group's mean outer product of differences."""
    out = np.zeros((dim, dim))
    total = 0.0
    for d, w in zip(diff, weights, strict=True):
        if len(d) and w > 0:
            out += w * (d.T @ d) / len(d)
            total += w
    return out / max(total, 1e-12)


def _standardisation(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = x.mean(axis=0)
    std = x.std(axis=0)
    floor = max(float(np.median(std)) * 1e-2, SCALE_FLOOR)
    return mean, np.maximum(std, floor)


def _fit(pairs: PairSet, masks: dict[str, np.ndarray], ranks: Sequence[int],
         reg: float, within: float) -> dict[int, SiteAdaptation]:
    """Uncalibrated maps of each rank fitted on the pairs selected by ``masks``."""
    dim = pairs.top.shape[1]
    used = {v: np.zeros(len(getattr(pairs, v)), bool) for v in VIEWS}
    for key, idx in (("cross_pos", pairs.cross_pos), ("cross_neg", pairs.cross_neg)):
        sel = idx[masks[key]]
        used["top"][sel[:, 0]] = True
        used["hor"][sel[:, 1]] = True
    for v in VIEWS:
        for key in ("within_pos", "within_neg"):
            used[v][getattr(pairs, key)[v][masks[f"{v}_{key}"]].ravel()] = True
    stats = {}
    for v in VIEWS:
        d = getattr(pairs, v)
        stats[v] = _standardisation(d[used[v]] if used[v].any() else d)
    x = {v: (getattr(pairs, v) - stats[v][0]) / stats[v][1] for v in VIEWS}

    def diffs(a: str, b: str, idx: np.ndarray) -> np.ndarray:
        return x[a][idx[:, 0]] - x[b][idx[:, 1]]

    pos = [diffs("top", "hor", pairs.cross_pos[masks["cross_pos"]])]
    neg = [diffs("top", "hor", pairs.cross_neg[masks["cross_neg"]])]
    for v in VIEWS:
        pos.append(diffs(v, v, pairs.within_pos[v][masks[f"{v}_within_pos"]]))
        neg.append(diffs(v, v, pairs.within_neg[v][masks[f"{v}_within_neg"]]))
    weights = [1.0, within, within]
    s_pos, s_neg = _scatter(pos, weights, dim), _scatter(neg, weights, dim)
    s_pos += reg * (np.trace(s_pos) / dim + 1e-12) * np.eye(dim)
    s_neg += 1e-9 * (np.trace(s_neg) / dim + 1e-12) * np.eye(dim)
    from scipy.linalg import eigh

    # only the leading eigenvectors are used: computing those alone is 10x faster for the
    # 1,976 stages, with the same vectors to rounding
    lead = max(max(ranks), 1)
    values, vectors = eigh(s_neg, s_pos, driver="gvx", subset_by_index=[dim - lead, dim - 1])
    order = np.argsort(-values, kind="stable")
    vectors = vectors[:, order]
    signs = np.sign(vectors[np.argmax(np.abs(vectors), axis=0), np.arange(lead)])
    vectors = vectors * np.where(signs == 0, 1.0, signs)
    out = {}
    for r in ranks:
        proj = np.eye(dim) if r == 0 else vectors[:, :r].copy()
        out[r] = SiteAdaptation(stats["top"][0], stats["top"][1], stats["hor"][0],
                                stats["hor"][1], proj, np.array([1.0, 0.0]), int(r),
                                pairs.vector)
    return out


def _pair_costs(adaptation: SiteAdaptation | None, pairs: PairSet, idx: np.ndarray
                ) -> np.ndarray:
    """Costs of ``(top, hor)`` index pairs: raw ``|a - b| / 2``, or ``adaptation``'s uncalibrated
    cost."""
    a, b = pairs.top[idx[:, 0]], pairs.hor[idx[:, 1]]
    if adaptation is not None:
        a, b = adaptation.transform(a, "top"), adaptation.transform(b, "hor")
    return 0.5 * np.linalg.norm(np.asarray(a, np.float64) - np.asarray(b, np.float64), axis=1)


def _log_odds(pos: np.ndarray, neg: np.ndarray, ridge: float = 1e-3) -> tuple[float, float]:
    """``alpha, beta`` of a class-balanced logistic regression of "same person" on
    ``logit(cost)`` (``log-odds = alpha logit(c) + beta``), by Newton's method (deterministic)."""
    x = np.concatenate([_logit(pos), _logit(neg)])
    y = np.concatenate([np.ones(len(pos)), np.zeros(len(neg))])
    w = np.concatenate([np.full(len(pos), 0.5 / len(pos)), np.full(len(neg), 0.5 / len(neg))])
    X = np.stack([x, np.ones_like(x)], axis=1)
    theta = np.zeros(2)
    for _ in range(50):
        p = 1.0 / (1.0 + np.exp(-(X @ theta)))
        grad = X.T @ (w * (p - y)) + ridge * theta
        hess = (X * (w * p * (1.0 - p))[:, None]).T @ X + ridge * np.eye(2)
        step = np.linalg.solve(hess, grad)
        theta = theta - step
        if np.abs(step).max() < 1e-10:
            break
    return float(theta[0]), float(theta[1])


def _calibration(raw_pos, raw_neg, new_pos, new_neg) -> np.ndarray:
    """``a, b`` mapping the medians of the adapted positive and negative costs (logits) onto
    those of the unadapted ones; ``1, 0`` when either set is empty or degenerate."""
    if min(len(raw_pos), len(raw_neg), len(new_pos), len(new_neg)) == 0:
        return np.array([1.0, 0.0])
    rp, rn = (float(np.median(_logit(c))) for c in (raw_pos, raw_neg))
    np_, nn = (float(np.median(_logit(c))) for c in (new_pos, new_neg))
    if not (nn - np_ > 1e-6 and rn - rp > 1e-6):
        return np.array([1.0, 0.0])
    a = (rn - rp) / (nn - np_)
    return np.array([a, rp - a * np_])


NEUTRAL_SLOPE = 1e-3
"""Slope of the odds calibration of a site cue whose lower costs are no likelier the same
person (a fitted log-odds slope >= 0): every cost goes to about the reference's neutral cost
(likelihood ratio 1) instead of passing for the cue the network has on renders."""


def _odds_calibration(ref_pos, ref_neg, new_pos, new_neg) -> np.ndarray:
    """``a, b`` giving each adapted cost the reference cost of the same likelihood ratio: with
    ``log-odds = alpha logit(c) + beta`` fitted on the site's pairs (``new``) and on the
    reference (``ref``, the network on the renders it was trained on),
    ``logit(c') = (alpha logit(c) + beta - beta_ref) / alpha_ref``. A site ``alpha`` of about 0
    or above (the cue says nothing there, or the opposite) is taken as :data:`NEUTRAL_SLOPE` times
    ``alpha_ref`` with ``beta`` 0 (class-balanced pairs: a likelihood ratio of 1): the costs go
    to the neutral one instead of through unchanged."""
    if min(len(ref_pos), len(ref_neg), len(new_pos), len(new_neg)) == 0:
        return np.array([1.0, 0.0])
    alpha, beta = _log_odds(new_pos, new_neg)
    alpha_ref, beta_ref = _log_odds(ref_pos, ref_neg)
    if not alpha_ref < 0:  # on its own renders a lower cost must mean the same person
        return np.array([1.0, 0.0])
    if alpha > NEUTRAL_SLOPE * alpha_ref:  # no evidence either way: likelihood ratio 1
        alpha, beta = NEUTRAL_SLOPE * alpha_ref, 0.0
    return np.array([alpha / alpha_ref, (beta - beta_ref) / alpha_ref])


def _checked_calibration(calibration: str | None,
                         reference: tuple[np.ndarray, np.ndarray] | None) -> str:
    """The calibration of :func:`fit_site_adaptation` (None: ``"odds"`` with a reference, else
    ``"none"``), checked against :data:`CALIBRATIONS` and the reference it needs."""
    if calibration is None:
        calibration = "odds" if reference is not None else "none"
    if calibration not in CALIBRATIONS:
        raise ValueError(f"calibration must be one of {CALIBRATIONS}, got {calibration!r}")
    if calibration in ("odds", "median") and reference is None:
        raise ValueError(f"calibration {calibration!r} needs the reference costs")
    return calibration


def _checked_ranks(pairs: PairSet, ranks: Sequence[int], heldout: float) -> tuple[int, list[int]]:
    """The descriptor size D and the ranks to try (sorted, those in 0..D), the pairs' vector,
    sizes and the held-out fraction checked."""
    if pairs.vector not in VECTORS:
        raise ValueError(f"pairs.vector must be one of {VECTORS}, got {pairs.vector!r}")
    dim = int(pairs.top.shape[1])
    if pairs.hor.shape[1] != dim:
        raise ValueError(f"top and horizontal descriptors differ in size ({dim}, "
                         f"{pairs.hor.shape[1]})")
    if not 0.0 < heldout < 1.0:
        raise ValueError(f"heldout must be in (0, 1), got {heldout}")
    ranks = sorted({int(r) for r in ranks if 0 <= int(r) <= dim})
    if not ranks:
        raise ValueError(f"no rank in 0..{dim} to try")
    return dim, ranks


def _heldout_cut(pairs: PairSet, heldout: float) -> int | None:
    """The first held-out time group: the last ``heldout`` fraction of the pairs' groups are
    held out (None: a single group, nothing to hold out)."""
    groups = np.concatenate([pairs.cross_pos_group, pairs.cross_neg_group,
                             *(pairs.within_pos_group.get(v, np.zeros(0, np.int64))
                               for v in VIEWS)]).astype(np.int64)
    unique = np.unique(groups)
    return unique[int(np.floor(len(unique) * (1.0 - heldout)))] if len(unique) > 1 else None


def _split_masks(pairs: PairSet, cut: int | None, train: bool) -> dict[str, np.ndarray]:
    """Masks of the training pairs (groups before ``cut``; all without a cut) or of the
    held-out ones (none without a cut), per kind of pair, as :func:`_fit` takes them."""
    def pick(g: np.ndarray) -> np.ndarray:
        g = np.asarray(g, np.int64)
        if cut is None:
            return np.full(len(g), train)
        return g < cut if train else g >= cut

    out = {"cross_pos": pick(pairs.cross_pos_group), "cross_neg": pick(pairs.cross_neg_group)}
    for v in VIEWS:
        for key, grp in (("within_pos", pairs.within_pos_group),
                         ("within_neg", pairs.within_neg_group)):
            n = len(getattr(pairs, key)[v])
            out[f"{v}_{key}"] = pick(grp.get(v, np.zeros(n, np.int64)))
    return out


def _calibrated(final: SiteAdaptation, heldout_fit: SiteAdaptation, pairs: PairSet,
                hp: np.ndarray, hn: np.ndarray, calibration: str,
                reference: tuple[np.ndarray, np.ndarray] | None) -> SiteAdaptation:
    """``final`` with the calibration measured on the held-out pairs ``hp``, ``hn`` by the
    map fitted without them (``heldout_fit``): the reliability of the cue on pairs it was not
    fitted to (the fit's own pairs would make it look surer than it is)."""
    new = (_pair_costs(heldout_fit, pairs, hp), _pair_costs(heldout_fit, pairs, hn))
    if calibration == "site":
        cal = _calibration(_pair_costs(None, pairs, hp), _pair_costs(None, pairs, hn), *new)
    elif calibration == "median":
        cal = _calibration(*reference, *new)
    else:
        cal = _odds_calibration(*reference, *new)
    return SiteAdaptation(final.top_mean, final.top_scale, final.hor_mean, final.hor_scale,
                          final.projection, cal, final.rank, final.vector)


def fit_site_adaptation(
    pairs: PairSet,
    ranks: Sequence[int] = DEFAULT_RANKS,
    heldout: float = 0.25,
    min_gain: float = 0.005,
    min_heldout: int = 10,
    reg: float | None = None,
    within: float = 0.5,
    calibration: str | None = None,
    reference: tuple[np.ndarray, np.ndarray] | None = None,
) -> AdaptationFit:
    """Fit, choose and check a :class:`SiteAdaptation` (see the module docstring).

    Args:
        pairs: the mined descriptors and pairs.
        ranks: the ranks tried (0: the standardisation alone); those above ``D`` are skipped.
        heldout: the fraction of the time groups (the last ones) held out to choose the rank.
        min_gain: the held-out AUC must beat the unadapted one by this much, and by twice its
            standard error (:func:`auc_standard_error`), else the fit is refused.
        min_heldout: fewest held-out cross-view positives (and negatives) to judge at all.
        reg: ridge on the positive scatter, a fraction of its mean eigenvalue (None:
            :data:`RIDGE` of the pairs' vector).
        within: weight of each view's within-view pairs in the scatters against the cross-view
            pairs' 1.
        calibration: how the adapted cost is put on the scale the fusion expects
            (:data:`CALIBRATIONS`): ``"odds"``, each cost gets the reference cost of the same
            likelihood ratio; ``"median"``, the medians of positives and negatives go to the
            reference's; ``"site"``, to the unadapted cost's on the same pairs; ``"none"``.
            None: ``"odds"`` with a ``reference``, else ``"none"``. The likelihood ratios and
            medians of the adapted cost are measured on the held-out pairs.
        reference: ``(positive, negative)`` raw costs of the network on its training domain
            (:func:`xvmatch.inference.adaptation.adaptation_pairs.reference_costs`), for ``"odds"``
            and ``"median"``.

    Returns:
        The :class:`AdaptationFit`; when refused, :attr:`AdaptationFit.adaptation` is the
        identity and ``reason`` says why.
    """
    calibration = _checked_calibration(calibration, reference)
    dim, ranks = _checked_ranks(pairs, ranks, heldout)
    if reg is None:
        reg = RIDGE[pairs.vector]
    cut = _heldout_cut(pairs, heldout)
    identity = SiteAdaptation.identity(dim, pairs.vector)
    test = _split_masks(pairs, cut, False)
    hp, hn = pairs.cross_pos[test["cross_pos"]], pairs.cross_neg[test["cross_neg"]]
    nan = float("nan")
    if cut is None or min(len(hp), len(hn)) < min_heldout:
        return AdaptationFit(identity, False, f"too few confident cross-view pairs to judge the "
                             f"adaptation ({len(hp)} positives and {len(hn)} negatives held out, "
                             f"{min_heldout} of each needed): give more frames or video",
                             nan, nan, {}, (len(hp), len(hn)))
    before = pair_auc(_pair_costs(None, pairs, hp), _pair_costs(None, pairs, hn))
    candidates = _fit(pairs, _split_masks(pairs, cut, True), ranks, reg, within)
    by_rank = {r: pair_auc(_pair_costs(m, pairs, hp), _pair_costs(m, pairs, hn))
               for r, m in candidates.items()}
    best = max(ranks, key=lambda r: (round(by_rank[r], 6), -r))
    needed = max(min_gain, 2.0 * auc_standard_error(by_rank[best], len(hp), len(hn)))
    if not by_rank[best] >= before + needed:
        return AdaptationFit(identity, False, f"adaptation does not help on the held-out pairs "
                             f"(AUC {by_rank[best]:.4f} at rank {best} against {before:.4f} "
                             f"unadapted; it must gain {needed:.4f}, twice its standard error)",
                             before, by_rank[best], by_rank, (len(hp), len(hn)))
    every = {k: np.ones_like(v) for k, v in test.items()}
    final = _fit(pairs, every, [best], reg, within)[best]
    if calibration != "none":
        final = _calibrated(final, candidates[best], pairs, hp, hn, calibration, reference)
    return AdaptationFit(final, True, "", before, by_rank[best], by_rank, (len(hp), len(hn)))
