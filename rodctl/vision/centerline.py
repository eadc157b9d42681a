"""Image -> the rod's centerline: N points, ordered from the clamped end to the gripper.

Why tracking instead of skeleton + graph: the clamp is fixed and calibrated, so its pixel and the
rod's direction there are known. Starting there and walking along the rod gives the order clamp ->
gripper by construction (no flip is possible), follows a self-crossing loop instead of short-cutting
it (at a crossing the walker keeps its curvature and goes straight over), and touches only the
pixels near the rod, so the cost does not grow with the image size. A skeleton has none of these
properties for free: it must be pruned of spurs, it shortens at the ends by half the rod width, it
merges at crossings, and ordering its pixels needs a graph walk in Python.

How one step works: predict the next point a step ``h`` ahead on the circle through the last two
chords (constant curvature), sample the image along the normal there (a cross-section), find the
run of "rod" samples nearest to the prediction and its two 50 % edges by linear interpolation, and
move the point to their midpoint. Where the run touches the window's border or is much wider than
the rod, another stretch of rod crosses: the prediction is kept unchanged.

Why colour coverage: the renderer knows the colours, so each pixel's rod coverage a (the fraction
of the pixel the rod covers) is recovered by one affine map of its RGB value: a = w . rgb + b,
with (w, b) solved so that the rod colour maps to 1 and every other scene colour to 0. Anti-aliased
pixels are convex blends a * rod + (1 - a) * other, and the map is affine, so it returns the exact
coverage a (exactly for up to three non-rod colours in general position, or for any number of
greys, the default). Bilinear interpolation is linear too, so sampling RGB and then mapping equals
mapping the whole image first: only the few hundred samples per frame are ever converted.

Sub-pixel accuracy comes from the 50 % edges of the anti-aliased band; after the walk, every output
point is refined again by a cross-section along the normal of the resampled curve (all points in
one vectorised call). The rod's end: from the last point, sample along the predicted direction until
the coverage falls below 50 %: that is the tip of the rod's round cap, half the band width beyond
the centreline's end.

Occlusion: when the walk stops early (far from the gripper's pixel, when it is given as a hint),
the extractor searches ahead along the predicted path for the rod to reappear and bridges the gap
with a straight segment, or, when the hidden stretch reaches the gripper, with a cubic Hermite
curve that ends on the gripper's pose. Either way ``ok`` is False and ``bridged`` is True, so the
loop can decide; with ``extract.on_gap = "fail"``, or when nothing can be bridged, the points are
NaN. Without the hint (and without ``rod_length``), an occluder that hides the rod's last part is
indistinguishable from the rod's end.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable
from dataclasses import dataclass
from itertools import chain

import cv2
import numpy as np

from rodctl import fixedla as fla
from rodctl.config.camera import CameraConfig
from rodctl.errors import UserError
from rodctl.geometry import linspace_from_zero, polyline_length, resample_polyline
from rodctl.vision.camera import Camera

#: One point of a traced path, pixels: an array, or a walk step's (x, y).
_Pixel = np.ndarray | tuple[float, float]

# Cross-section sample spacing (px) and the status codes of `_cross_sections`.
_DT = 0.5
# Walk: steps predicted per vectorised call, the largest correction (px) after which points
# further ahead are not trusted, and the largest turn (rad) per step.
_LOOKAHEAD = 6
_TRUST_PX = 3.0
_MAX_TURN = 0.8
#: Per predicted step i (1-based) of a walk batch: i and the slots of its x, y and normal's x,
#: y in the batch's list of positions (all x first, then all y, ...).
_WALK_SLOTS = tuple(
    (i + 1, i, i + _LOOKAHEAD, i + 2 * _LOOKAHEAD, i + 3 * _LOOKAHEAD) for i in range(_LOOKAHEAD)
)
# A cross-section narrower than this fraction of the rod's band is the rod's tip.
_NARROW = 0.75
# A run wider than this fraction of the band is another stretch of rod touching it: ambiguous.
_WIDE = 1.3
# Runs wider than the band by more than this (px) are treated as merged with another stretch.
_MERGE_PX = 1.5
# Up to this many cross-sections are analysed in plain Python (numpy's per-call overhead
# dominates for a handful of short rows); more go through the vectorised path. Both give the
# same numbers (tests/vision/test_centerline.py checks it).
_SCALAR_ROWS = 8
_OK, _AMBIGUOUS, _LOST = 0, 1, 2  # `_analyse_rows` relies on _OK 0 and _AMBIGUOUS 1
#: The left and right edges' signs in `_analyse_rows`.
_SIGNS = np.array([[1.0], [-1.0]], np.float32)
_SIGNS.flags.writeable = False
# `_find_end` samples this many points of its arc first, the rest only if needed.
_END_FIRST = 32


@dataclass(frozen=True)
class Extraction:
    """The result of extracting one image.

    Attributes:
        points: (N, 2) float64 pixels (u, v), clamp end first; all NaN when the step failed.
        ok: True when the whole rod was seen and traced; False otherwise (see `note`).
        note: why `ok` is False ("" when ok).
        bridged: True when part of the rod was hidden and the points bridge the gap; the points
            are finite but only approximate there.
    """

    points: np.ndarray
    ok: bool
    note: str = ""
    bridged: bool = False


def _cos_sin(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of a short array through the C library's scalar functions.

    numpy may dispatch its vectorised cos/sin to other code on other CPUs (AVX-512); the C
    library's scalar functions give the same bits on every x86-64 machine with FMA
    (docs/reproducibility.md). The arrays here hold a few dozen angles.
    """
    values = angles.tolist()
    n = len(values)
    return (
        np.fromiter(map(math.cos, values), np.float64, n),
        np.fromiter(map(math.sin, values), np.float64, n),
    )


def _min_norm_lstsq(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The least-squares solution of a x = b (minimum norm when under-determined), in fixed-order
    arithmetic (replaces `numpy.linalg.lstsq`, whose LAPACK result depends on the BLAS kernel).

    For a (k, 4) with k <= 4 rows: x = a^T (a a^T + eps I)^-1 b; otherwise the normal equations
    (a^T a + eps I) x = a^T b. The tiny ridge eps (1e-12 of the trace, colours scaled to [0, 1])
    keeps repeated or coplanar colours (several greys) solvable; it moves the solution by about
    1e-12, far below the 0.1 the caller checks.
    """
    scale = 255.0
    a_s = np.asarray(a, dtype=np.float64) / np.array([scale, scale, scale, 1.0])
    k, n = a_s.shape
    if k <= n:
        gram = fla.matmul(a_s, a_s.T)
        gram += (1e-12 * max(float(np.trace(gram)), 1.0)) * np.eye(k)
        y = fla.spd_solve(gram, b)
        x = None if y is None else fla.matvec(np.ascontiguousarray(a_s.T), y)
    else:
        gram = fla.matmul(a_s.T, a_s)
        gram += (1e-12 * max(float(np.trace(gram)), 1.0)) * np.eye(n)
        x = fla.spd_solve(gram, fla.matvec(np.ascontiguousarray(a_s.T), b))
    if x is None:  # pragma: no cover - a ridge-regularised Gram matrix is positive definite
        return np.zeros(n)
    return x / np.array([scale, scale, scale, 1.0])


def _median(values: list[float]) -> float:
    """`np.median` of a short list, bit for bit, without numpy's per-call overhead."""
    v = sorted(values)
    k = len(v) // 2
    return v[k] if len(v) % 2 else (v[k - 1] + v[k]) / 2.0


def _length(points: np.ndarray) -> float:
    """`polyline_length` of (M, 2) points, bit for bit, without its wrappers' overhead."""
    return float(np.add.reduce(np.hypot(*(points[1:] - points[:-1]).T)))


#: np.arange(-m, m + 1) * _DT per half-width m (cross-section sample offsets); read-only.
_OFFSETS: dict[int, np.ndarray] = {}


def _read_only(
    cache: dict[int, np.ndarray], key: int, limit: int, make: Callable[[], np.ndarray]
) -> np.ndarray:
    """`cache[key]`, made by `make()` (read-only) the first time; the cache is emptied when it
    holds `limit` entries."""
    value = cache.get(key)
    if value is None:
        if len(cache) >= limit:
            cache.clear()
        value = cache[key] = make()
        value.flags.writeable = False
    return value


def _offsets(m: int) -> np.ndarray:
    return _read_only(_OFFSETS, m, 16, lambda: np.arange(-m, m + 1) * _DT)


def _resample_planes(p: np.ndarray, n: int, seg: np.ndarray | None = None) -> np.ndarray:
    """``resample_polyline(p.T, n).T`` bit for bit, for (2, M) planes of x and y (M >= 2):
    the (2, n) points equally spaced in arc length; `seg`, the segments' lengths, if known."""
    if seg is None:
        seg = np.hypot(*(p[:, 1:] - p[:, :-1]))
    s = np.empty(len(seg) + 1)
    s[0] = 0.0
    seg.cumsum(out=s[1:])
    total = float(s[-1])
    if total <= 0.0:
        return np.repeat(p[:, :1], n, axis=1)
    q = linspace_from_zero(total, n)
    out = np.empty((2, n))
    out[0] = np.interp(q, s, p[0])
    out[1] = np.interp(q, s, p[1])
    return out


def _section_maps(centres: np.ndarray, normals: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(2, T, K) float32 sample positions centre + t * normal for (2, K) planes of centres and
    normals: the x and the y plane (the two maps `cv2.remap` takes), sample offset by sample
    offset (a row holds one offset of every cross-section, so numpy's inner loops run over the
    K cross-sections, not over the few offsets). Computed in float64 and rounded once: the bits
    of ``(centres.T[:, None] + t[None, :, None] * normals.T[:, None]).astype(np.float32)``
    moved to (2, T, K)."""
    prod = np.multiply(normals[:, None, :], t[:, None])
    out = np.empty(prod.shape, np.float32)
    np.add(prod, centres[:, None, :], out=out)
    return out


def _hermite(p0: np.ndarray, d0: np.ndarray, p1: np.ndarray, d1: np.ndarray, n: int) -> np.ndarray:
    """(n, 2) cubic Hermite curve from p0 (unit direction d0) to p1 (unit direction d1)."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    scale = float(np.hypot(*(p1 - p0)))
    h00, h10 = 2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t
    h01, h11 = -2 * t**3 + 3 * t**2, t**3 - t**2
    return h00 * p0 + h10 * scale * d0 + h01 * p1 + h11 * scale * d1


def _locate_row(
    s: list[float] | array, m: int, band: float | None, max_width: float, rod=None, b: int = 0
) -> tuple[float, float, int]:
    """Scalar twin of the vectorised analysis in `CenterlineExtractor._cross_sections`.

    Args:
        s: 2m + 1 coverage samples across the rod, spaced `_DT`, the prediction at index m
            (the row is s[b:b + 2m + 1] when s holds several).
        m: half the number of samples.
        band: the rod's band width (px) if known.
        max_width: the width above which the section is ambiguous.
        rod: bytes of s >= 0.5 when the caller has them (one numpy comparison for many rows;
            runs are found by `bytes.find`), else made here; b: the row's start in s and rod.

    Returns:
        (offset px, width px, status).
    """
    f = bytes(v >= 0.5 for v in s) if rod is None else rod
    last = 2 * m
    c = b + m  # indices below are into s and f: the row's sample i is at b + i
    end = b + last + 1
    j = c
    if not f[c]:  # the rod sample nearest c, the left one on a tie
        jl, jr = f.rfind(1, b, c), f.find(1, c + 1, end)
        if jl < 0 and jr < 0:
            return 0.0, 0.0, _LOST
        j = jl if jl >= 0 and (jr < 0 or c - jl <= jr - c) else jr
    # the nearest non-rod samples on either side of j (none: the run leaves the window)
    left = f.rfind(0, b, j)
    right = f.find(0, j + 1, end)
    left_off, right_off = left < 0, right < 0
    # the 50 % crossings between lc, lc + 1 and rc - 1, rc (clipped to the window)
    lc = b if left_off else left
    rc = b + last if right_off else right
    s0, s1 = s[lc], s[lc + 1]
    t_left = (lc - c) * _DT + (0.5 - s0) / (s1 - s0 if s1 - s0 > 1e-6 else 1.0) * _DT
    r0, r1 = s[rc - 1], s[rc]
    t_right = (rc - 1 - c) * _DT + (r0 - 0.5) / (r0 - r1 if r0 - r1 > 1e-6 else 1.0) * _DT
    width = t_right - t_left
    offset = 0.5 * (t_left + t_right)
    touches = left_off or right_off
    if band is not None:
        if width > band + _MERGE_PX and not (left_off and right_off):
            from_left = t_left + 0.5 * band
            from_right = t_right - 0.5 * band
            if left_off:
                offset = from_right
            elif right_off:
                offset = from_left
            else:
                offset = from_left if abs(from_left) < abs(from_right) else from_right
            width = band
        touches = left_off and right_off
    if touches or width > max_width:
        return offset, width, (_AMBIGUOUS if f[c] else _LOST)
    return offset, width, _OK


#: Per half-width m, `_analyse_rows`'s tables as (T, 1) int16 columns (int64 for very long
#: sections): nearness to the prediction (index m; larger is nearer, >= 1), i + 1, T - i, and
#: i + 1 above m, T - i below it (0 at m); and (2, 1) [1, 2m], for the crossings' rows.
_ROW_TABLES: dict[int, tuple[np.ndarray, ...]] = {}


def _row_tables(m: int) -> tuple[np.ndarray, ...]:
    tables = _ROW_TABLES.get(m)
    if tables is None:
        n = 2 * m + 1
        idx = np.arange(n)
        kind = np.int16 if n < 16_000 else np.int64
        up, down = idx + 1, n - idx
        tables = (
            (n - np.abs(idx - m)).astype(kind)[:, None],
            up.astype(kind)[:, None],
            down.astype(kind)[:, None],
            np.where(idx < m, up, np.where(idx > m, down, 0)).astype(kind)[:, None],
            np.array([[1], [2 * m]], kind),
        )
        for table in tables:
            table.flags.writeable = False
        if len(_ROW_TABLES) >= 16:
            _ROW_TABLES.clear()
        _ROW_TABLES[m] = tables
    return tables


#: np.arange(k), the cross-sections' columns, for the last few k.
_COLUMNS: dict[int, np.ndarray] = {}


def _columns(k: int) -> np.ndarray:
    return _read_only(_COLUMNS, k, 64, lambda: np.arange(k))


def _analyse_rows(
    s: np.ndarray, m: int, t: np.ndarray, max_width: float, band: float | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The vectorised analysis of `CenterlineExtractor._cross_sections`: (2m + 1, K) float32
    coverage samples (column k is cross-section k, row i its offset t[i]) -> offsets, widths,
    status (see there), the numbers of `_locate_row` cross-section by cross-section up to
    float32 rounding.

    For each cross-section: j, the "rod" sample nearest the prediction (the first of a tie); a
    section without one is lost. left/right: the nearest non-rod samples on either side of j
    (-1 and 2m + 1 when the run reaches the window's end), kept as the codes L = left + 1 and
    R = 2m + 1 - right (0: the run leaves the window on that side). Every numpy pass runs
    along rows, i.e. over all K sections at once.
    """
    n, k = s.shape
    notab = np.less(s, 0.5)
    near, up, down, up_down, ends = _row_tables(m)
    codes = np.empty((2, k), up.dtype)  # L, R
    lost = None
    if m > 0 and not np.count_nonzero(notab[m]):
        # every prediction lies on the rod (the rule in the refinement): j = m, and the run's
        # ends are the nearest non-rod samples either side of m: L is the largest i + 1 over
        # non-rod i < m and R the largest n - i over non-rod i > m (0 when there is none)
        coded = np.multiply(notab, up_down)
        np.maximum.reduce(coded[:m], axis=0, out=codes[0])
        np.maximum.reduce(coded[m + 1 :], axis=0, out=codes[1])
    else:
        cols = _columns(k)
        at_j = np.multiply(~notab, near).argmax(axis=0)  # the first of a tie: the left one
        lost = notab[at_j, cols]
        # running maxima of the non-rod samples' i + 1 from the top, and of their n - i from
        # the bottom (accumulated on the reversed rows: row j is row n - 1 - j there)
        codes[0] = np.maximum.accumulate(np.multiply(notab, up), axis=0)[at_j, cols]
        from_end = np.maximum.accumulate(np.multiply(notab, down)[::-1], axis=0)
        codes[1] = from_end[n - 1 - at_j, cols]
        if np.count_nonzero(lost):  # no rod sample at all: j = 0, whose left is -1 and right 1
            codes[0, lost] = 0
            codes[1, lost] = n - 1
    left_off, right_off = codes == 0
    # e: where the left crossing (row 0: between samples lc and lc + 1) and the right one
    # (row 1: between rc - 1 and rc) start: lc = max(L, 1) - 1 and rc - 1 = 2m - max(R, 1)
    # (the window's clipping, which is all a code of 0 needs)
    e = np.abs(np.subtract(np.maximum(codes, 1), ends, dtype=np.intp))
    # Both 50 % crossings at once, between a = s[e] and b = s[e + 1]: the right edge's
    # (r0 - 0.5) and (r0 - r1) are the left formula's (0.5 - a) and (b - a) negated, exactly.
    idx = e * k
    idx += _columns(k)
    flat = s.ravel()
    a = flat.take(idx)
    num = (0.5 - a) * _SIGNS
    den = (flat[k:].take(idx) - a) * _SIGNS
    t_left, t_right = t.take(e) + num / np.where(den > 1e-6, den, 1.0) * _DT
    width = t_right - t_left
    offset = 0.5 * (t_left + t_right)
    both_off = left_off & right_off
    if band is not None:
        # Wider than the rod but bounded on both sides: another stretch of rod touches ours
        # on one side. The other edge is still ours: put the centre half a band inside the
        # edge whose implied centre is nearer the prediction. A run that runs off one end of
        # the window is located from its free edge alike.
        broad = width > band + _MERGE_PX
        if np.count_nonzero(broad):
            merged = broad & ~both_off
            from_left = t_left + 0.5 * band
            from_right = t_right - 0.5 * band
            nearer = np.where(np.abs(from_left) < np.abs(from_right), from_left, from_right)
            one_sided = np.where(left_off, from_right, np.where(right_off, from_left, nearer))
            offset = np.where(merged, one_sided, offset)
            width = np.where(merged, band, width)
        touches = both_off
    else:
        touches = left_off | right_off
    wide = touches | (width > max_width)
    status = wide.astype(np.int64)  # _OK (0), or _AMBIGUOUS (1) where wide
    if lost is not None:
        # Too wide and not even under the prediction: something beside the rod, not a crossing.
        status[wide & notab[m]] = _LOST
        status[lost] = _LOST
    return offset, width, status


#: `cv2.transform` matrix of the coverage's channel sum: (p0 + p1) + p2 (+ -0.0, which leaves
#: every float32, -0.0 included, unchanged). OpenCV computes 1 * p0 + 1 * p1 + 1 * p2 + m3 in
#: float32 from left to right; the products by 1 are exact, so even a fused multiply-add gives
#: the bits of numpy's two additions, in one pass instead of two.
_SUM3 = np.array([[1.0, 1.0, 1.0, -0.0]], np.float32)
_SUM3.flags.writeable = False

#: cv2.remap refuses maps of SHRT_MAX (32767) columns or more; longer samplings go in rows.
_REMAP_MAX = 32767
_REMAP_ROW = 4096


class CenterlineExtractor:
    """Finds the rod in a camera image and returns its centerline as N ordered pixel points.

    One extractor per thread: the walk samples into scratch arrays the extractor keeps.

    Args:
        cfg: the camera config (`points`, `render` colours and width, `extract` options).
        camera: the calibrated camera that took the images (used for the clamp's pixel and, with
            ``extract.arc_length = "plane"``, to space the points equally on the rod's plane).
        clamp_pose: (3,) world pose of the clamped end [x, y, theta].
        rod_length: the rod's length (m), optional: when given, a traced rod whose length on the
            plane differs from it by more than `length_tolerance` is reported as not ok.
        length_tolerance: relative tolerance of that length check.

    Raises:
        UserError: the configured colours do not let the rod be told apart from the rest.
    """

    def __init__(
        self,
        cfg: CameraConfig,
        camera: Camera,
        clamp_pose: np.ndarray,
        rod_length: float | None = None,
        length_tolerance: float = 0.05,
    ) -> None:
        self.cfg = cfg
        self.camera = camera
        self.points = int(cfg.points)
        self.rod_length = rod_length
        self.length_tolerance = float(length_tolerance)
        r, e = cfg.render, cfg.extract
        self._start, self._start_dir = camera.project_pose_direction(np.asarray(clamp_pose))
        self._line_px = float(r.rod_width_px)
        # The visible band is wider than OpenCV's thickness (anti-aliasing, round-off); this is
        # only a prior, replaced by the widths measured along the rod in each image.
        self._band_prior = self._line_px + 2.0
        self._step = float(e.step_px) if e.step_px is not None else self._line_px
        self._half_track = 0.5 * self._band_prior + 4.0
        self._m_track = int(round(self._half_track / _DT))  # the walk's m (`_cross_sections`)
        self._half_refine = 0.5 * self._band_prior + 2.5
        self._coverage_w, self._coverage_b = self._coverage_map()
        self._cov_b32 = np.float32(self._coverage_b)
        # The affine map as three per-channel tables of the same float32 products (w_c * value,
        # the bias folded into the last), so that sampling is one cv2.LUT and two additions
        # with the bits of `_affine`.
        v = np.arange(256, dtype=np.float32)
        w = self._coverage_w
        self._coverage_lut = np.stack(
            [v * w[0], v * w[1], v * w[2] + self._cov_b32], axis=-1
        ).reshape(1, 256, 3)
        self._bg_value = tuple(float(c) for c in r.background_color)
        self._walk_samplers: dict[tuple[int, int], Callable] = {}
        self._section_buffers: dict[int, tuple[np.ndarray, ...]] = {}
        self._max_steps = int(4 * (camera.width + camera.height) / self._step) + 10
        # `_find_end`'s arc lengths: all, and the second part (after t[0])
        self._end_t = np.arange(0.0, self._step * _LOOKAHEAD + self._band_prior + 2.0, 0.25)
        self._end_t_rest = np.concatenate([self._end_t[:1], self._end_t[_END_FIRST:]])
        self._end_t_first = self._end_t[:_END_FIRST]
        self._arc_samplers: dict[tuple[int, int], tuple] = {}

    # ------------------------------------------------------------------ colour -> coverage
    def _coverage_map(self) -> tuple[np.ndarray, float]:
        """Solve (w, b) with w . rod + b = 1 and w . c + b = 0 for every other scene colour."""
        r = self.cfg.render
        others = [r.background_color]
        if r.background == "checker":
            others.append(r.checker_color)
        if r.draw_gripper or r.draw_clamp:
            others.append(r.fixture_color)
        if r.occlusions or r.random_occlusions:
            others.append(r.occluder_color)
        colours = np.array([r.rod_color, *others], dtype=np.float64)
        a = np.column_stack([colours, np.ones(len(colours))])
        target = np.zeros(len(colours))
        target[0] = 1.0
        sol = _min_norm_lstsq(a, target)
        got = fla.matvec(a, sol)
        if abs(got[0] - 1.0) > 0.1 or np.abs(got[1:]).max() > 0.1:
            raise UserError(
                "camera.render: the rod colour cannot be told apart from the other scene colours "
                f"(rod {r.rod_color}, others {others}); make the rod the only chromatic colour "
                "or use at most three other colours"
            )
        return sol[:3].astype(np.float32), float(sol[3])

    def coverage(self, image: np.ndarray) -> np.ndarray:
        """(H, W) float32 rod coverage in [0, 1] of a whole image (for plots and debugging).

        Args:
            image: (H, W, 3) uint8 RGB.
        """
        return np.clip(self._affine(image.astype(np.float32)), 0.0, 1.0)

    def _affine(self, rgb: np.ndarray) -> np.ndarray:
        """w . rgb + b over the last axis of float32 (..., 3), in a fixed order of operations.

        Written out instead of `rgb @ w`: float32 matmul goes to BLAS sgemv, whose kernel (and so
        the last bit of every coverage value) differs between CPUs (docs/reproducibility.md).
        """
        w = self._coverage_w
        return (rgb[..., 0] * w[0] + rgb[..., 1] * w[1]) + (rgb[..., 2] * w[2] + self._cov_b32)

    def _sample(self, image: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """Rod coverage at (..., 2) pixel positions, bilinear; 0 outside the image (unclipped)."""
        return self._sample_maps(image, np.moveaxis(pts, -1, 0).astype(np.float32))

    def _sample_maps(self, image: np.ndarray, maps: np.ndarray) -> np.ndarray:
        """`_sample` at float32 pixel positions given as (2, ...) x and y planes."""
        shape = maps.shape[1:]
        flat = maps.reshape(2, 1, -1)
        n = flat.shape[2]
        if n >= _REMAP_MAX:
            # cv2.remap takes maps narrower than SHRT_MAX: a long trace (a rod looping across
            # the image) is sampled in rows (each point's value does not depend on the layout)
            rows = np.zeros((2, -(-n // _REMAP_ROW), _REMAP_ROW), dtype=np.float32)
            rows.reshape(2, -1)[:, :n] = flat[:, 0]
            flat = rows
        # two one-channel maps: the samples of one two-channel map, bit for bit
        rgb = cv2.remap(
            image,
            flat[0],
            flat[1],
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=self._bg_value,
        )
        # not clipped to [0, 1]: only 50 % crossings are used, and clipping costs time
        part = cv2.LUT(rgb, self._coverage_lut)
        return cv2.transform(part, _SUM3).reshape(-1)[:n].reshape(shape)

    def _sample_sections(
        self, image: np.ndarray, centres: np.ndarray, normals: np.ndarray, t: np.ndarray
    ) -> np.ndarray:
        """(T, K) coverage of the cross-sections through (2, K) planes of centres and normals at
        offsets t: `_sample_maps` of `_section_maps`, bit for bit, in scratch arrays kept per T
        and grown to the largest K seen (the result is one of them: use it before the next
        call)."""
        n, k = len(t), centres.shape[1]
        size = n * k
        if size >= _REMAP_MAX:
            return self._sample_maps(image, _section_maps(centres, normals, t))
        buffers = self._section_buffers.get(n)
        if buffers is None or buffers[0].shape[1] < size:
            cap = size + size // 4  # room for a slightly longer rod in the next frames
            buffers = self._section_buffers[n] = (
                np.empty((2, cap)),
                np.empty((2, 1, cap), np.float32),
                np.empty((1, cap, 3), np.uint8),
                np.empty((1, cap, 3), np.float32),
                np.empty((1, cap), np.float32),
            )
        prod_buf, maps_buf, rgb_buf, part_buf, cov_buf = buffers
        prod = prod_buf[:, :size].reshape(2, n, k)
        maps = maps_buf[:, :, :size]
        # centre + normal * t in float64, rounded once into the float32 maps (`_section_maps`)
        np.multiply(normals[:, None, :], t[:, None], out=prod)
        np.add(prod, centres[:, None, :], out=maps.reshape(2, n, k))
        rgb = cv2.remap(
            image,
            maps[0],
            maps[1],
            cv2.INTER_LINEAR,
            rgb_buf[:, :size],
            cv2.BORDER_CONSTANT,
            self._bg_value,
        )
        part = cv2.LUT(rgb, self._coverage_lut, part_buf[:, :size])
        return cv2.transform(part, _SUM3, cov_buf[:, :size]).reshape(n, k)

    def _walk_rows(self, image: np.ndarray, qn: list[float], t: np.ndarray) -> tuple[array, bytes]:
        """The walk's `_LOOKAHEAD` cross-sections in one call: ``qn`` holds the predicted
        points' x, then their y, then the normals' x, then their y; returns the coverage samples
        (row after row) as an `array.array` (indexing gives Python floats, as `tolist` would)
        and ``bytes`` of sample >= 0.5. The numbers of `_sample_maps` of `_section_maps`."""
        return self._walk_sampler(len(qn) // 4, t)(image, qn)

    def _walk_sampler(self, k: int, t: np.ndarray) -> Callable[[np.ndarray, list[float]], tuple]:
        """`_walk_rows` for k cross-sections of offsets t, as a function of (image, qn) that
        works in scratch arrays made once per (k, len(t)) (the results are copied out), with
        every view and constant it needs bound beforehand."""
        n = len(t)
        sampler = self._walk_samplers.get((k, n))
        if sampler is not None:
            return sampler
        qn_buf = np.empty(4 * k)
        a = qn_buf.reshape(4, k, 1)
        centres, normals = a[:2], a[2:]
        prod = np.empty((2, k, n))
        maps = np.empty((2, 1, k * n), np.float32)
        maps_kn = maps.reshape(2, k, n)
        map_x, map_y = maps[0], maps[1]
        rgb = np.empty((1, k * n, 3), np.uint8)
        part = np.empty((1, k * n, 3), np.float32)
        cov = np.empty((1, k * n), np.float32)
        lut, bg = self._coverage_lut, self._bg_value
        remap, linear, constant = cv2.remap, cv2.INTER_LINEAR, cv2.BORDER_CONSTANT
        to_coverage, channel_sum, multiply, add = cv2.LUT, cv2.transform, np.multiply, np.add

        def sample(image: np.ndarray, qn: list[float]) -> tuple[array, bytes]:
            qn_buf[:] = qn
            # centre + normal * t in float64, rounded once into the float32 maps
            add(centres, multiply(normals, t, out=prod), out=maps_kn)
            remap(image, map_x, map_y, linear, rgb, constant, bg)
            channel_sum(to_coverage(rgb, lut, part), _SUM3, cov)
            return array("f", cov.tobytes()), (cov >= 0.5).tobytes()

        if len(self._walk_samplers) >= 16:
            self._walk_samplers.clear()
        self._walk_samplers[k, n] = sample
        return sample

    # ------------------------------------------------------------------ cross-sections
    def _cross_sections(
        self,
        image: np.ndarray,
        centres: np.ndarray,
        normals: np.ndarray,
        half: float,
        max_width: float,
        band: float | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Locate the rod across K cross-sections.

        Args:
            image: (H, W, 3) uint8 RGB.
            centres: (K, 2) predicted centre points (px).
            normals: (K, 2) unit normals along which to sample.
            half: half-length of each cross-section (px).
            max_width: a run wider than this is another stretch of rod crossing: ambiguous.
            band: the rod's band width, when known: a run wider than it (but below the
                ambiguity limit) is located from its one edge that fits the prediction best.

        Returns:
            offsets (K,) along the normal from centre to the band's midpoint, widths (K,) of the
            band between its 50 % edges, status (K,) one of _OK, _AMBIGUOUS, _LOST.
        """
        return self._sections_planes(image, centres.T, normals.T, half, max_width, band)

    def _sections_planes(
        self,
        image: np.ndarray,
        centres: np.ndarray,
        normals: np.ndarray,
        half: float,
        max_width: float,
        band: float | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`_cross_sections` of (2, K) planes of centres and normals (x row, y row)."""
        m = int(round(half / _DT))
        t = _offsets(m)
        k = centres.shape[1]
        s = self._sample_sections(image, centres, normals, t)
        if k <= _SCALAR_ROWS:
            n = 2 * m + 1
            s = np.ascontiguousarray(s.T)  # one cross-section per row
            flat, rod = s.ravel().tolist(), (s >= 0.5).tobytes()
            rows_out = [_locate_row(flat, m, band, max_width, rod, i * n) for i in range(k)]
            off_w_st = np.array(rows_out, dtype=np.float64).reshape(k, 3)
            return off_w_st[:, 0], off_w_st[:, 1], off_w_st[:, 2].astype(np.int64)
        return _analyse_rows(s, m, t, max_width, band)

    # ------------------------------------------------------------------ the walk
    def _inside(self, p: np.ndarray) -> bool:
        return 0.0 <= p[0] <= self.camera.width - 1 and 0.0 <= p[1] <= self.camera.height - 1

    def _walk(
        self, image: np.ndarray, p: np.ndarray, d: np.ndarray, turn: float
    ) -> tuple[list[tuple[float, float]], np.ndarray, float, list[float], str]:
        """Track the rod from p (last chord direction d, turn per step) until it ends.

        Each iteration predicts `_LOOKAHEAD` steps along the constant-curvature arc and samples
        all their cross-sections in one `cv2.remap` call; it keeps the points up to the first
        that needed a large correction or was ambiguous (a prediction that far ahead is no longer
        trusted). Scalar Python on purpose: the arrays are tiny and numpy's per-call overhead
        would dominate.

        Returns:
            (points visited after p, last chord direction, last turn per step, measured band
            widths, "" or the reason the walk failed).
        """
        h = self._step
        m = self._m_track
        n = 2 * m + 1
        t = _offsets(m)
        sample = self._walk_sampler(_LOOKAHEAD, t)
        # per row: its index, its samples [b, e) with the prediction at c, its normal's slots
        rows = [
            (i, i * n, i * n + m, (i + 1) * n, i + 2 * _LOOKAHEAD, i + 3 * _LOOKAHEAD)
            for i in range(_LOOKAHEAD)
        ]
        px, py = float(p[0]), float(p[1])
        heading = math.atan2(float(d[1]), float(d[0]))
        out: list[tuple[float, float]] = []
        widths: list[float] = []
        w_max, h_max = self.camera.width - 1, self.camera.height - 1
        cos, sin, hypot, atan2, remainder = (
            math.cos,
            math.sin,
            math.hypot,
            math.atan2,
            math.remainder,
        )
        two_pi = 2 * math.pi
        for _ in range(self._max_steps):
            recent = widths[-8:]
            band = sorted(recent)[len(recent) // 2] if recent else self._band_prior
            wide, narrow, merge_w, half_band = (
                _WIDE * band,
                _NARROW * band,
                band + _MERGE_PX,
                0.5 * band,
            )
            # qn: the predicted points' x, their y, the normals' x, their y (`_walk_rows`)
            qn = [0.0] * (4 * _LOOKAHEAD)
            qx, qy = px, py
            half_turn = 0.5 * turn
            for i, ix, iy, inx, iny in _WALK_SLOTS:
                a = heading + turn * i
                qx += h * cos(a)
                qy += h * sin(a)
                qn[ix] = qx
                qn[iy] = qy
                a += half_turn
                qn[inx] = -sin(a)
                qn[iny] = cos(a)
            vals, rod = sample(image, qn)
            accepted: list[tuple[float, float]] = []
            any_ok = False
            for i, b, c, e, inx, iny in rows:
                if (
                    rod[c]
                    and (left := rod.rfind(0, b, c)) >= 0
                    and (right := rod.find(0, c + 1, e)) >= 0
                ):
                    # The usual row, a run under the prediction bounded on both sides:
                    # `_locate_row`'s arithmetic for it, inline (the same operations).
                    s0 = vals[left]
                    ds = vals[left + 1] - s0
                    t_left = (left - c) * _DT + (0.5 - s0) / (ds if ds > 1e-6 else 1.0) * _DT
                    r0 = vals[right - 1]
                    dr = r0 - vals[right]
                    t_right = (right - 1 - c) * _DT + (r0 - 0.5) / (dr if dr > 1e-6 else 1.0) * _DT
                    wid = t_right - t_left
                    off = 0.5 * (t_left + t_right)
                    if wid > merge_w:
                        from_left, from_right = t_left + half_band, t_right - half_band
                        off = from_left if abs(from_left) < abs(from_right) else from_right
                        wid = band
                    st = _AMBIGUOUS if wid > wide else _OK
                else:
                    off, wid, st = _locate_row(vals, m, band, wide, rod, b)
                # A band much narrower than the rod is its rounded tip seen off-centre (or a
                # graze of another stretch): the walk has reached the end.
                if st == _OK and wid < narrow:
                    st = _LOST
                if st == _LOST or (i > 0 and (st == _AMBIGUOUS or abs(off) > _TRUST_PX)):
                    break  # beyond here the prediction is not trusted: re-predict
                qx, qy = qn[i], qn[i + _LOOKAHEAD]
                if not (0.0 <= qx <= w_max and 0.0 <= qy <= h_max):
                    return (
                        out,
                        np.array([math.cos(heading), math.sin(heading)]),
                        turn,
                        widths,
                        ("the rod leaves the image"),
                    )
                if st == _OK:
                    qx += off * qn[inx]
                    qy += off * qn[iny]
                    widths.append(wid)
                    any_ok = True
                accepted.append((qx, qy))
                if st == _OK and abs(off) > _TRUST_PX:
                    break  # the first point was far off: re-predict from it
            if not accepted:
                break
            if len(accepted) > 1:
                ax, ay = accepted[-2]
            else:
                ax, ay = px, py
            lx, ly = accepted[-1]
            if hypot(lx - ax, ly - ay) < 1e-6:
                break
            new_heading = atan2(ly - ay, lx - ax)
            if any_ok:
                # turn per step = mean change of chord heading over the batch (it telescopes);
                # where the rod was ambiguous (a crossing), the predicted turn is kept.
                change = remainder(new_heading - heading, two_pi)
                turn = min(max(change / len(accepted), -_MAX_TURN), _MAX_TURN)
            heading = new_heading
            out.extend(accepted)
            px, py = lx, ly
        else:
            return (
                out,
                np.array([math.cos(heading), math.sin(heading)]),
                turn,
                widths,
                ("the walk along the rod did not end"),
            )
        return out, np.array([math.cos(heading), math.sin(heading)]), turn, widths, ""

    def _arc_sampler(self, n: int, slot: int) -> tuple[Callable[[np.ndarray], np.ndarray], tuple]:
        """A sampler of n points whose positions are written into its float32 maps (x, y):
        returns (sample(image) -> the (n,) float32 coverage in a scratch array, (map x, map y));
        the numbers of `_sample_maps`. One per (n, slot): the two parts of `_find_end` keep
        their samples apart."""
        found = self._arc_samplers.get((n, slot))
        if found is not None:
            return found
        maps = np.empty((2, 1, n), np.float32)
        map_x, map_y = maps[0], maps[1]
        rgb = np.empty((1, n, 3), np.uint8)
        part = np.empty((1, n, 3), np.float32)
        cov = np.empty((1, n), np.float32)
        lut, bg = self._coverage_lut, self._bg_value

        def sample(image: np.ndarray) -> np.ndarray:
            cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, rgb, cv2.BORDER_CONSTANT, bg)
            return cv2.transform(cv2.LUT(rgb, lut, part), _SUM3, cov)[0]

        if len(self._arc_samplers) >= 16:
            self._arc_samplers.clear()
        found = self._arc_samplers[n, slot] = (sample, (maps[0, 0], maps[1, 0]))
        return found

    def _sample_arc(
        self, image: np.ndarray, p: np.ndarray, h_base: float, k: float, t: np.ndarray, skip: int
    ) -> tuple[np.ndarray, float, float]:
        """Coverage along the predicted constant-curvature arc from p (tangent at p: heading
        `h_base`; curvature k) at arc lengths t[skip:], and the arc's direction at t[0]. The
        positions are computed in float64 and rounded once into the sampler's maps."""
        heading = np.multiply(t, k)
        heading += h_base
        cos_h, sin_h = _cos_sin(heading)
        sample, (map_x, map_y) = self._arc_sampler(len(t) - skip, skip)
        px, py = p[0], p[1]
        if abs(k) < 1e-9:
            np.add(np.multiply(t[skip:], cos_h[0]), px, out=map_x)  # px + t cos(h0)
            np.add(np.multiply(t[skip:], sin_h[0]), py, out=map_y)
        else:
            h0 = heading[0] - k * t[0]
            # px + (sin h - sin h0) / k, py + (cos h0 - cos h) / k
            np.add(np.divide(np.subtract(sin_h[skip:], math.sin(h0)), k), px, out=map_x)
            np.add(np.divide(np.subtract(math.cos(h0), cos_h[skip:]), k), py, out=map_y)
        return sample(image), float(cos_h[0]), float(sin_h[0])

    def _find_end(
        self, image: np.ndarray, p: np.ndarray, d: np.ndarray, turn: float, cap: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """The centreline's end and direction there: follow the predicted arc from p to the 50 %
        crossing of coverage (the tip of the round cap), then step back by the cap radius.

        The arc's tangent at p is the last chord d turned by half a step's turn; its curvature
        is the turn per step over the step."""
        t = self._end_t
        k = turn / self._step
        h_base = math.atan2(d[1], d[0]) + 0.5 * turn
        # Sampled in two parts, the second only when the first has no crossing (the crossing
        # is usually within a band or two of p): every point's position and sample depend on
        # its own t and on t[0] only, so the first crossing is the same as in one call.
        s, c0, s0 = self._sample_arc(image, p, h_base, k, self._end_t_first, 0)
        i = np.less(s, 0.5).tobytes().find(1)  # the first sample below 50 %, -1 if none
        if i < 0 and len(t) > _END_FIRST:
            rest = self._sample_arc(image, p, h_base, k, self._end_t_rest, 1)[0]
            s = np.concatenate([s, rest])
            i = np.less(s, 0.5).tobytes().find(1)
        if i <= 0:
            return p.copy(), np.array([c0, s0])
        t_cross = t[i - 1] + (s[i - 1] - 0.5) / max(s[i - 1] - s[i], 1e-6) * 0.25
        # the point of the same arc at t_cross - cap, in scalar arithmetic (the same operations)
        t_end = t_cross - cap
        heading = h_base + k * t_end
        c, sn = math.cos(heading), math.sin(heading)
        if abs(k) < 1e-9:
            end = np.array([p[0] + t_end * c, p[1] + t_end * sn])
        else:
            h0 = heading - k * t_end
            end = np.array([p[0] + (sn - math.sin(h0)) / k, p[1] + (math.cos(h0) - c) / k])
        return end, np.array([c, sn])

    def _reappear(
        self, image: np.ndarray, p: np.ndarray, d: np.ndarray, turn: float, band: float
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Search ahead of p (along the predicted arc) for the rod to reappear after a gap."""
        max_gap = self.cfg.extract.max_gap_px
        if max_gap <= 0:
            return None
        h = self._step
        dist = np.arange(h, max_gap + h, 0.5 * h)
        ang = turn / h * dist  # heading change along the predicted constant-curvature arc
        heading = math.atan2(d[1], d[0]) + ang
        # positions by integrating the heading along the arc (cumulative sum of small steps)
        dirs = np.column_stack(_cos_sin(heading))
        steps = np.diff(np.concatenate([[0.0], dist]))
        pos = p[None, :] + np.cumsum(dirs * steps[:, None], axis=0)
        normals = np.column_stack([-dirs[:, 1], dirs[:, 0]])
        half = 0.5 * band + 4.0 + 0.25 * max_gap
        off, wid, st = self._cross_sections(image, pos, normals, half, 1.6 * band)
        good = np.nonzero((st == _OK) & (wid > 0.6 * band) & (wid < 1.6 * band))[0]
        inside = np.array([self._inside(q) for q in pos])
        good = good[inside[good]]
        if len(good) == 0:
            return None
        i = good[0]
        return pos[i] + off[i] * normals[i], dirs[i]

    # ------------------------------------------------------------------ public
    def extract(self, image: np.ndarray, gripper_pose: np.ndarray | None = None) -> Extraction:
        """Extract the rod's centerline from one image.

        Args:
            image: (H, W, 3) uint8 RGB, as `Camera.render` makes it.
            gripper_pose: (3,) gripper pose [x, y, theta] (world), optional. When given, the walk
                must end near its pixel (otherwise the rod is occluded or lost) and a hidden last
                stretch can be bridged onto it.

        Returns:
            The `Extraction`: N points clamp -> gripper, ok, note, bridged.
        """
        img = np.ascontiguousarray(image)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise ValueError(f"image must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
        if img.shape[:2] != (self.camera.height, self.camera.width):
            raise ValueError(
                f"image is {img.shape[1]}x{img.shape[0]}, camera is "
                f"{self.camera.width}x{self.camera.height}"
            )
        grip_px = grip_dir = None
        if gripper_pose is not None:
            grip_px, grip_dir = self.camera.project_pose_direction(np.asarray(gripper_pose))
        line, widths, gaps, why = self._trace(img, grip_px, grip_dir)
        if line is None:
            return Extraction(self._failed(), False, why)
        # Refine every point across the band, on a resampled curve (one vectorised call).
        return self._finish(img, line, widths, gaps)

    def _trace(
        self, img: np.ndarray, grip_px: np.ndarray | None, grip_dir: np.ndarray | None
    ) -> tuple[np.ndarray | None, list[float], list[float], str]:
        """Walk from the clamp, bridging gaps while the rod keeps reappearing.

        Returns:
            (the traced polyline or None, cross-section widths, gap lengths, why it failed).
        """
        # --- walk from the clamp, bridging gaps while the rod keeps reappearing
        p, d, turn = self._start.copy(), self._start_dir.copy(), 0.0
        path: list[_Pixel] = [p]
        widths: list[float] = []
        gaps: list[float] = []
        # Is the rod visible right at the clamp? If not, the start itself is hidden. (One
        # cross-section half a step ahead, through the walk's sampler: the numbers of
        # `_cross_sections` of it.)
        step_ahead = 0.5 * self._step
        centre_normal = [p[0] + step_ahead * d[0], p[1] + step_ahead * d[1], -d[1], d[0]]
        vals, rod = self._walk_rows(img, centre_normal, _offsets(self._m_track))
        first = _locate_row(vals, self._m_track, None, _WIDE * self._band_prior, rod)[2]
        end_dir = d
        closed = False  # True once the path has been bridged onto the gripper's pixel
        for _ in range(20):
            if first == _LOST:
                first = _OK
                found = self._reappear(img, p, d, turn, self._band_prior)
                if found is None:
                    return None, widths, gaps, "the rod is not visible at the clamp"
                gaps.append(float(np.hypot(*(found[0] - p))))
                p, d = found
                path.append(p)
            pts, d, turn, w, why = self._walk(img, p, d, turn)
            path.extend(pts)
            widths.extend(w)
            if why:
                return None, widths, gaps, why
            p = np.array(path[-1], dtype=np.float64)
            band = _median(widths) if widths else self._band_prior
            end, end_dir = self._find_end(img, p, d, turn, 0.5 * band)
            if grip_px is not None:
                complete = np.hypot(*(end - grip_px)) <= max(2.0 * band, 6.0)
            elif self.rod_length is not None:
                # no hint: a trace clearly shorter than the rod may continue after a gap
                seen = polyline_length(self.camera.unproject(np.array([*path, end])))
                complete = seen >= self.rod_length * (1.0 - self.length_tolerance)
            else:
                complete = True
            if complete:
                break
            found = self._reappear(img, p, d, turn, band)
            if found is None and grip_px is None:
                break  # nothing more to see; the length check below reports it
            if found is None:
                # the hidden stretch runs to the gripper: bridge onto its pose, if short enough
                assert grip_px is not None and grip_dir is not None  # projected together
                gap = float(np.hypot(*(grip_px - end)))
                if gap > self.cfg.extract.max_gap_px:
                    return None, widths, gaps, f"the rod is lost {gap:.0f} px before the gripper"
                path = self._trim_after(path, end, end_dir)
                path.append(end)
                path.extend(_hermite(end, end_dir, grip_px, grip_dir, 12)[1:])
                gaps.append(gap)
                closed = True
                break
            gaps.append(float(np.hypot(*(found[0] - p))))
            p, d = found
            path.append(p)
        else:
            return None, widths, gaps, "too many gaps along the rod"
        if not closed:
            path = self._trim_after(path, end, end_dir)
            path.append(end)
        # np.array(path) (arrays and tuples of two floats), in a third of its time
        line = np.fromiter(chain.from_iterable(path), np.float64, 2 * len(path)).reshape(-1, 2)
        if len(line) < 3 or _length(line) < 2 * self._step:
            return None, widths, gaps, "no rod found next to the clamp"

        return line, widths, gaps, ""

    def _finish(
        self,
        img: np.ndarray,
        line: np.ndarray,
        widths: list[float],
        gaps: list[float],
    ) -> Extraction:
        """Refine and resample the traced line to N points, then judge it: bridged gaps and a
        traced length unlike the rod's make the frame not ok."""
        line = self._refine(img, line, _median(widths) if widths else self._band_prior)
        out = self._resample_out(line, self.points)
        if not np.isfinite(out).all():
            return Extraction(
                self._failed(), False, "the traced rod leaves the plane's visible side"
            )
        if gaps:
            note = f"occluded: bridged {len(gaps)} gap(s), {sum(gaps):.0f} px in all"
            if self.cfg.extract.on_gap == "fail":
                return Extraction(self._failed(), False, note)
            return Extraction(out, False, note, bridged=True)
        if self.rod_length is not None:
            length = _length(self.camera.unproject(out))
            rel = length / self.rod_length - 1.0
            if abs(rel) > self.length_tolerance:
                return Extraction(
                    out,
                    False,
                    f"traced length {length:.3f} m differs from the rod's {self.rod_length:.3f} m "
                    f"by {100 * rel:+.0f} %: occluded or confused",
                )
        return Extraction(out, True)

    def _failed(self) -> np.ndarray:
        """The points of a failed extraction: (N, 2) NaN, a new array each time."""
        return np.full((self.points, 2), np.nan)

    @staticmethod
    def _trim_after(path: list[_Pixel], end: np.ndarray, d: np.ndarray) -> list[_Pixel]:
        """Drop the walk's last points that lie beyond `end` (they sat inside the rod's cap)."""
        dx, dy = float(d[0]), float(d[1])
        while len(path) > 1 and (
            float(path[-1][0] - end[0]) * dx + float(path[-1][1] - end[1]) * dy >= -1e-9
        ):
            path.pop()
        return path

    def _refine(self, image: np.ndarray, line: np.ndarray, band: float) -> np.ndarray:
        """Move each point of a resampled copy of `line` to the band's midpoint (ends kept).

        Computed on (2, n) planes of x and y (contiguous rows): the numbers of
        `resample_polyline` and of central-difference unit normals (left of the direction of
        travel) of the (n, 2) points, operation for operation."""
        passes = self.cfg.extract.refine_passes
        if passes <= 0:
            return line
        p = line.T
        seg = np.hypot(*(p[:, 1:] - p[:, :-1]))
        n = max(self.points, int(float(np.add.reduce(seg)) / 2.0) + 2)  # `polyline_length`
        sign = np.array([[-1.0], [1.0]])
        for _ in range(passes):
            p = _resample_planes(p, n, seg)
            seg = None
            # np.gradient's central differences inside, as unit vectors; the normal (-dy, dx)
            d = (p[:, 2:] - p[:, :-2]) / 2.0
            d /= np.maximum(np.hypot(d[0], d[1]), 1e-12)
            normals = d[::-1] * sign
            inner = p[:, 1:-1]
            off, _, st = self._sections_planes(
                image, inner, normals, self._half_refine, _WIDE * band, band
            )
            ok = (st == _OK) & (np.abs(off) < 2.0)
            # inner[ok] += off[ok] * normals[ok], without the copies
            np.add(inner, off * normals, out=inner, where=ok)
        return p.T

    def _resample_out(self, line: np.ndarray, n: int) -> np.ndarray:
        """Resample to n points at equal arc length in the image or on the plane (config)."""
        if self.cfg.extract.arc_length == "image":
            return resample_polyline(line, n)
        world = self.camera.unproject(line)
        if not np.isfinite(world).all():
            return np.full((n, 2), np.nan)
        return self.camera.project(_resample_planes(world.T, n).T)
