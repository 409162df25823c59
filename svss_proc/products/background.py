"""Background estimation: a 3-D sliding median of the image magnitude.

The seed paper estimates the background of SVSS volumes with a median filter whose kernel
is 0.2 m cross-track x 1.2 m along-track x 0.1 m depth. :func:`kernel_voxels` turns such
a kernel (m) into odd voxel counts; :func:`median_background` computes the median over
that window at every voxel with one of two methods:

``"exact"``
    The exact windowed median. For finite data without missing voxels it equals
    ``scipy.ndimage.median_filter(x, size=kernel, mode=boundary)`` element for element.
``"histogram"``
    The same sliding median run on the magnitudes quantised to bins of ``bin_db`` dB
    (bin centres at the volume's smallest positive value plus multiples of ``bin_db``).
    Quantisation is monotone, so the median of the quantised values is the quantised
    exact median: the result is the exact median rounded to its bin's centre, and
    ``|20 log10(approx / exact)| <= bin_db / 2`` at every voxel whose exact median is
    positive (zeros stay exactly zero, missing stays missing). That is the documented
    error bound; it holds for any data, not only on average.

Both run a numba kernel over integer *levels*: every voxel value becomes its rank in the
volume (``exact``) or its dB bin (``histogram``); a window slides along-track (the
kernel's longest axis, so each step adds and removes only one cross x depth slab of
levels) over tables of level counts whose median is found by walking a pointer that
moves only a few steps per voxel. The cost does not depend on the kernel's along-track
length; lines (cross, depth) run in parallel. Two kernels, one result:

- **Grouped** (up to 4096 levels, a kernel at least 3 voxels across: the default
  histogram of a tile): three cross-track neighbour lines slide together. Their windows
  share ``kernel_cross - 2`` of their ``kernel_cross`` columns, counted once in a shared
  table; each line adds a table of its own two other columns, and its median is walked
  on the sum of the two. Each table's count below one common reference level (the
  middle line's last median) is kept, so an update costs one comparison whatever the
  number of lines. Per voxel: ``2 x kernel_depth x (kernel_cross - 2 + 6) / 3`` count
  updates (50 for the seed's 61 x 11 x 5, against 110 one line at a time), over levels
  stored along-track-contiguous (int16), and missing voxels counted in a table slot of
  their own (no branch). Its medians equal the per-line kernel's level for level
  (``tests/products/test_background.py``).
- **Per line** (many sparse levels, such as the ranks of a large volume, in three tiers of
  counts: levels, blocks of 64, blocks of 4096; or a kernel one voxel across): one
  line's window at a time, ``2 x kernel_cross x kernel_depth`` count updates per voxel.

Missing data: NaN and infinities (and, with ``ignore_zeros``, exact zeros: voxels no
ping reached) are left out of every window; the median is then taken over the voxels
present (the lower median, element ``(n - 1) // 2`` of the n sorted values, when n is
even) and is NaN where a window holds none.

Boundaries (``boundary``), as in ``scipy.ndimage``: ``"reflect"`` (d c b a | a b c d |
d c b a, scipy's default), ``"mirror"`` (d c b | a b c d | c b a), ``"nearest"``
(a a a | a b c d | d d d), or ``"truncate"`` (the window shrinks to the voxels inside
the volume: padding counts as missing).
"""

from __future__ import annotations

import logging
import math
import time

import numba
import numpy as np

from ..imaging.grid import kernel_voxels  # noqa: F401  (the kernel's voxels: defined with the grid)

log = logging.getLogger(__name__)

METHODS = ("exact", "histogram")
BOUNDARIES = ("reflect", "mirror", "nearest", "truncate")
_NP_PAD = {"reflect": "symmetric", "mirror": "reflect", "nearest": "edge"}
_MID_SHIFT, _TOP_SHIFT = 6, 12   # count-table blocks: 64 and 4096 levels
_MAX_HIST_LEVELS = 1 << 20


@numba.njit(cache=True, inline="always")
def _slab(levels, ia, j, m, wc, wd, s, fine, mid, top, three, ptr, below):
    """Add (s = +1) or remove (s = -1) the cross x depth slab ``ia`` of the window of line
    (j, m). ``below`` counts the levels under the pointer ``ptr`` (a level, or a block of
    4096 levels when ``three``). Returns the updated ``below`` and the levels moved."""
    shift = 12 if three else 0
    n = 0
    for jj in range(j, j + wc):
        for mm in range(m, m + wd):
            lev = levels[ia, jj, mm]
            if lev >= 0:
                n += 1
                fine[lev] += s
                if three:
                    mid[lev >> 6] += s
                    top[lev >> 12] += s
                below += s * ((lev >> shift) < ptr)   # branch-free: this is unpredictable
    return below, n


@numba.njit(cache=True, inline="always")
def _walk(counts, ptr, below, k):
    """The pointer moved over ``counts`` (a count per level, or per block of levels) to
    the entry that holds the ``k``-th counted level (0-based), ``below`` the count under
    it before and after: returns (ptr, below)."""
    while below + counts[ptr] <= k:
        below += counts[ptr]
        ptr += 1
    while below > k:
        ptr -= 1
        below -= counts[ptr]
    return ptr, below


@numba.njit(cache=True, parallel=True)
def _sliding_median_levels(levels, wa, wc, wd, n_levels, three, counts_dtype_probe,
                           n_threads, out):
    """Median level of every ``wa x wc x wd`` window of the padded level volume.

    ``levels``: int32 (A + wa - 1, C + wc - 1, D + wd - 1), -1 for missing; ``out``:
    int32 (A, C, D), receives the level of the lower median, -1 where a window holds no
    level. ``three``: count levels in three tiers (levels, 64-blocks, 4096-blocks; for
    many sparse levels such as ranks) rather than one (few dense levels such as dB bins).
    ``counts_dtype_probe``: a 1-element array whose dtype the level counts take. Lines
    (cross, depth) are dealt round-robin to ``n_threads`` workers.
    """
    na, nc, nd = out.shape
    n_lines = nc * nd
    for t in numba.prange(n_threads):
        fine = np.zeros(n_levels, dtype=counts_dtype_probe.dtype)
        mid = np.zeros((n_levels >> 6) + 1 if three else 1, dtype=np.int32)
        top = np.zeros((n_levels >> 12) + 1 if three else 1, dtype=np.int32)
        ptr = 0
        below = 0
        for line in range(t, n_lines, n_threads):
            j = line // nd
            m = line % nd
            count = 0
            for ia in range(wa - 1):
                below, n = _slab(levels, ia, j, m, wc, wd, 1, fine, mid, top, three, ptr,
                                 below)
                count += n
            for i in range(na):
                below, n = _slab(levels, i + wa - 1, j, m, wc, wd, 1, fine, mid, top, three,
                                 ptr, below)
                count += n
                if count == 0:
                    out[i, j, m] = -1
                else:
                    k = (count - 1) // 2
                    if three:
                        ptr, below = _walk(top, ptr, below, k)
                        r = k - below
                        b = ptr << 6
                        while mid[b] <= r:
                            r -= mid[b]
                            b += 1
                        lev = b << 6
                        while fine[lev] <= r:
                            r -= fine[lev]
                            lev += 1
                        out[i, j, m] = lev
                    else:
                        ptr, below = _walk(fine, ptr, below, k)
                        out[i, j, m] = ptr
                below, n = _slab(levels, i, j, m, wc, wd, -1, fine, mid, top, three, ptr,
                                 below)
                count -= n
            for ia in range(na, na + wa - 1):
                below, n = _slab(levels, ia, j, m, wc, wd, -1, fine, mid, top, three, ptr,
                                 below)
    return out



@numba.njit(cache=True, parallel=True)
def _gather_along_last(levels, src_a, src_c, src_d, missing, out):
    """``out[jj, mm, ia] = levels[src_a[ia], src_c[jj], src_d[mm]]``: the padded levels
    with the along-track axis last (``src_*``: the volume's index for each padded
    position, -1 outside it); ``missing`` where an index is -1 or the level negative.
    Blocks of 32 along-track positions keep both sides' cache lines in use."""
    ncp, ndp, nap = out.shape
    nblk = (nap + 31) // 32
    for task in numba.prange(ncp * nblk):
        jj = task // nblk
        a0 = (task % nblk) * 32
        a1 = min(a0 + 32, nap)
        c = src_c[jj]
        for mm in range(ndp):
            d = src_d[mm]
            for ia in range(a0, a1):
                a = src_a[ia]
                if c < 0 or d < 0 or a < 0:
                    out[jj, mm, ia] = missing
                else:
                    v = levels[a, c, d]
                    out[jj, mm, ia] = missing if v < 0 else v
    return out


@numba.njit(cache=True, inline="always")
def _median_from(shared, own, q, below, k):
    """Level of element ``k`` of the counts ``shared + own``, walked from level ``q``
    (``below``: the count under ``q``)."""
    p = q
    while below + shared[p] + own[p] <= k:
        below += shared[p] + own[p]
        p += 1
    while below > k:
        p -= 1
        below -= shared[p] + own[p]
    return p


@numba.njit(cache=True, parallel=True)
def _grouped_median_levels(lev, wa, wc, wd, n_levels, counts_dtype_probe, n_threads, out):
    """Median level of every ``wa x wc x wd`` window, three cross-track lines at a time.

    ``lev``: padded levels, along-track last: (cross, depth, along) = (at least 3 x
    ceil(C / 3) + wc - 1, D + wd - 1, A + wa - 1), ``n_levels`` for missing (also in the
    cross-track columns past the padded volume); ``out``: int32 (A, C, D), the level of
    the lower median, -1 where a window holds no level. ``wc >= 3``.

    Lines j0, j0 + 1, j0 + 2 (one depth) share the columns j0 + 2 .. j0 + wc - 1 (table
    ``S``); line 0 adds columns j0, j0 + 1 (``U0``), line 1 j0 + 1, j0 + wc (``U1``),
    line 2 j0 + wc, j0 + wc + 1 (``U2``). ``bS`` .. ``b2``: each table's count under the
    reference level ``q``; a window's present count is its size less the slot
    ``n_levels`` of its tables. Tasks (a group of lines at one depth) are dealt to
    ``n_threads`` workers in contiguous runs, depth fastest, so that consecutive tasks
    reuse each other's columns in cache.
    """
    na, nc, nd = out.shape
    M = n_levels
    W = wa * wc * wd
    n_tasks = ((nc + 2) // 3) * nd
    for t in numba.prange(n_threads):
        S = np.zeros(M + 1, dtype=counts_dtype_probe.dtype)
        U0 = np.zeros(M + 1, dtype=counts_dtype_probe.dtype)
        U1 = np.zeros(M + 1, dtype=counts_dtype_probe.dtype)
        U2 = np.zeros(M + 1, dtype=counts_dtype_probe.dtype)
        for task in range(t * n_tasks // n_threads, (t + 1) * n_tasks // n_threads):
            j0 = 3 * (task // nd)
            m = task % nd
            S[:] = 0
            U0[:] = 0
            U1[:] = 0
            U2[:] = 0
            q = 0
            bS = 0
            b0 = 0
            b1 = 0
            b2 = 0
            for i in range(na):
                # the first window fills planes 0 .. wa - 1; each later one adds plane
                # i + wa - 1 and removes plane i - 1
                lo, hi = (0, wa) if i == 0 else (i + wa - 1, i + wa)
                rm = i > 0
                ir = i - 1
                for ia in range(lo, hi):
                    for jj in range(j0 + 2, j0 + wc):
                        for mm in range(m, m + wd):
                            a = lev[jj, mm, ia]
                            S[a] += 1
                            bS += a < q
                            if rm:
                                r = lev[jj, mm, ir]
                                S[r] -= 1
                                bS -= r < q
                    for mm in range(m, m + wd):
                        a = lev[j0, mm, ia]
                        U0[a] += 1
                        b0 += a < q
                        a = lev[j0 + 1, mm, ia]
                        x = a < q
                        U0[a] += 1
                        U1[a] += 1
                        b0 += x
                        b1 += x
                        a = lev[j0 + wc, mm, ia]
                        x = a < q
                        U1[a] += 1
                        U2[a] += 1
                        b1 += x
                        b2 += x
                        a = lev[j0 + wc + 1, mm, ia]
                        U2[a] += 1
                        b2 += a < q
                        if rm:
                            r = lev[j0, mm, ir]
                            U0[r] -= 1
                            b0 -= r < q
                            r = lev[j0 + 1, mm, ir]
                            x = r < q
                            U0[r] -= 1
                            U1[r] -= 1
                            b0 -= x
                            b1 -= x
                            r = lev[j0 + wc, mm, ir]
                            x = r < q
                            U1[r] -= 1
                            U2[r] -= 1
                            b1 -= x
                            b2 -= x
                            r = lev[j0 + wc + 1, mm, ir]
                            U2[r] -= 1
                            b2 -= r < q
                n = W - S[M] - U0[M]
                p = -1 if n == 0 else _median_from(S, U0, q, bS + b0, (n - 1) // 2)
                out[i, j0, m] = p
                qn = p
                if j0 + 1 < nc:
                    n = W - S[M] - U1[M]
                    p = -1 if n == 0 else _median_from(S, U1, q, bS + b1, (n - 1) // 2)
                    out[i, j0 + 1, m] = p
                    if p >= 0:
                        qn = p
                if j0 + 2 < nc:
                    n = W - S[M] - U2[M]
                    p = -1 if n == 0 else _median_from(S, U2, q, bS + b2, (n - 1) // 2)
                    out[i, j0 + 2, m] = p
                if qn >= 0:         # the reference follows the middle line's median
                    while q < qn:
                        bS += S[q]
                        b0 += U0[q]
                        b1 += U1[q]
                        b2 += U2[q]
                        q += 1
                    while q > qn:
                        q -= 1
                        bS -= S[q]
                        b0 -= U0[q]
                        b1 -= U1[q]
                        b2 -= U2[q]
    return out


def _source_indices(n: int, half: int, boundary: str) -> np.ndarray:
    """The volume's index (0 .. n - 1) at each of the ``n + 2 half`` padded positions
    of one axis, as :func:`_pad` pads (-1: outside the volume, 'truncate')."""
    idx = np.arange(n, dtype=np.int64)
    if boundary not in BOUNDARIES:
        raise ValueError(f"boundary {boundary!r}; expected one of {BOUNDARIES}")
    if boundary == "truncate":
        return np.pad(idx, half, mode="constant", constant_values=-1)
    return np.pad(idx, half, mode=_NP_PAD[boundary])


def _run_grouped(levels: np.ndarray, n_levels: int, kernel: tuple[int, int, int],
                 boundary: str, probe: np.ndarray) -> np.ndarray:
    na, nc, nd = levels.shape
    wa, wc, wd = kernel
    src = [_source_indices(n, k // 2, boundary) for n, k in zip(levels.shape, kernel)]
    # cross-track columns past the padded volume (the last group's lines beyond C)
    width = 3 * ((nc + 2) // 3) + wc - 1
    src[1] = np.concatenate([src[1], np.full(width - src[1].size, -1, dtype=np.int64)])
    lev = np.empty((src[1].size, src[2].size, src[0].size), dtype=np.int16)
    _gather_along_last(np.ascontiguousarray(levels, dtype=np.int32), src[0], src[1],
                       src[2], n_levels, lev)
    out = np.empty(levels.shape, dtype=np.int32)
    _grouped_median_levels(lev, wa, wc, wd, n_levels, probe, numba.get_num_threads(), out)
    return out

def _pad(levels: np.ndarray, kernel: tuple[int, int, int], boundary: str) -> np.ndarray:
    width = [(k // 2, k // 2) for k in kernel]
    if boundary == "truncate":
        return np.pad(levels, width, mode="constant", constant_values=-1)
    if boundary not in _NP_PAD:
        raise ValueError(f"boundary {boundary!r}; expected one of {BOUNDARIES}")
    return np.pad(levels, width, mode=_NP_PAD[boundary])


def _run(levels: np.ndarray, n_levels: int, kernel: tuple[int, int, int],
         boundary: str, unique: bool) -> np.ndarray:
    """Median level of every window (-1: none); ``levels`` int32, -1 missing."""
    # level counts: one byte suffices for unique levels (exact ranks) when the kernel
    # fits the volume and padding mirrors (a voxel then appears at most 2 x 2 x 2 times
    # in a window; 'nearest' repeats edge voxels up to the kernel's size); two bytes
    # when a window holds fewer than 65536 voxels
    small = (unique and boundary != "nearest"
             and all(k <= n for k, n in zip(kernel, levels.shape)))
    window = kernel[0] * kernel[1] * kernel[2]
    probe = np.zeros(1, dtype=np.uint8 if small else np.uint16 if window < 65536
                     else np.int32)
    three = n_levels > 4096
    if not three and kernel[1] >= 3:
        # missing voxels take the table slot n_levels, so the grouped tables' counts
        # reach the window's size: bytes only when it fits
        probe = np.zeros(1, dtype=np.uint8 if window < 256 else np.uint16
                         if window < 65536 else np.int32)
        return _run_grouped(levels, max(int(n_levels), 1), kernel, boundary, probe)
    padded = np.ascontiguousarray(_pad(levels, kernel, boundary), dtype=np.int32)
    out = np.empty(levels.shape, dtype=np.int32)
    _sliding_median_levels(padded, *kernel, max(int(n_levels), 1), three, probe,
                           numba.get_num_threads(), out)
    return out


def _present(mag: np.ndarray, ignore_zeros: bool) -> np.ndarray:
    ok = np.isfinite(mag)
    if ignore_zeros:
        ok &= mag != 0
    return ok


def median_exact(mag: np.ndarray, kernel: tuple[int, int, int], boundary: str = "reflect",
                 ignore_zeros: bool = False) -> np.ndarray:
    """Exact 3-D sliding median of ``mag`` (any real dtype; result float32 or float64
    as the input) over an odd ``kernel`` (voxels along each axis). See the module
    docstring for missing voxels and boundaries."""
    mag = np.asarray(mag)
    _check(mag, kernel)
    ok = _present(mag, ignore_zeros)
    values = mag[ok]
    order = np.argsort(values, kind="stable")
    ranks = np.empty(values.size, dtype=np.int32)
    ranks[order] = np.arange(values.size, dtype=np.int32)
    levels = np.full(mag.shape, -1, dtype=np.int32)
    levels[ok] = ranks
    med = _run(levels, values.size, kernel, boundary, unique=True)
    table = np.append(values[order], np.nan).astype(_float(mag))
    return table[med]  # level -1 picks the trailing NaN


@numba.njit(cache=True, parallel=True)
def _positive_range(flat):
    """(min, max) of the finite positive values of ``flat`` (inf, -inf when there are
    none)."""
    lo, hi = np.inf, -np.inf
    for i in numba.prange(flat.size):
        v = np.float64(flat[i])
        if v > 0 and v < np.inf:
            lo = min(lo, v)
            hi = max(hi, v)
    return lo, hi


def _positive_db_range(flat: np.ndarray) -> tuple[float, float]:
    """(min, max) of 20 log10 over the finite positive values of ``flat`` (inf, -inf
    when there are none): the logarithm of the extremes (it is monotone), not of every
    value."""
    lo, hi = _positive_range(flat)
    if lo > hi:
        return math.inf, -math.inf
    return 20.0 * math.log10(lo), 20.0 * math.log10(hi)


@numba.njit(cache=True, parallel=True)
def _quantise_db(flat, ignore_zeros, lo_db, bin_db, n_bins, out):
    """Level of each value: -1 missing (NaN, inf, zeros if ``ignore_zeros``), 0 for
    zero, 1 + round((20 log10 v - lo_db) / bin_db) (clipped to n_bins) otherwise."""
    for i in numba.prange(flat.size):
        v = flat[i]
        if not (v >= 0 and v < np.inf) or (ignore_zeros and v == 0):
            out[i] = -1
        elif v == 0:
            out[i] = 0
        else:
            b = int(np.floor((20.0 * np.log10(np.float64(v)) - lo_db) / bin_db + 0.5))
            out[i] = 1 + min(max(b, 0), n_bins - 1)
    return out


def median_histogram(mag: np.ndarray, kernel: tuple[int, int, int], bin_db: float,
                     boundary: str = "reflect", ignore_zeros: bool = False) -> np.ndarray:
    """Approximate 3-D sliding median: the exact median of ``mag`` quantised to
    ``bin_db`` dB bins, returned as the bin centre. ``|error| <= bin_db / 2`` dB where
    the exact median is positive; zeros and missing voxels as :func:`median_exact`.
    Requires ``mag >= 0``."""
    mag = np.ascontiguousarray(mag)
    _check(mag, kernel)
    if not bin_db > 0:
        raise ValueError(f"histogram bin must be positive, got {bin_db} dB")
    if np.any(mag < 0):
        raise ValueError("the histogram median needs non-negative magnitudes")
    flat = mag.reshape(-1)
    lo, hi = _positive_db_range(flat)
    n_bins = 0 if lo > hi else int(math.floor((hi - lo) / bin_db + 0.5)) + 1
    if n_bins > _MAX_HIST_LEVELS - 1:
        raise ValueError(f"dynamic range {hi - lo:.0f} dB needs {n_bins} bins of "
                         f"{bin_db} dB; at most {_MAX_HIST_LEVELS - 1}")
    lo = lo if n_bins else 0.0
    levels = _quantise_db(flat, bool(ignore_zeros), lo, float(bin_db), max(n_bins, 1),
                          np.empty(flat.size, dtype=np.int32)).reshape(mag.shape)
    med = _run(levels, n_bins + 1, kernel, boundary, unique=False)
    centres_db = lo + np.arange(n_bins) * bin_db
    table = np.concatenate([[0.0], 10.0 ** (centres_db / 20.0), [np.nan]])
    return table.astype(_float(mag))[med]


def median_background(mag: np.ndarray, kernel: tuple[int, int, int], method: str,
                      bin_db: float, boundary: str = "reflect",
                      ignore_zeros: bool = False) -> np.ndarray:
    """Background of ``mag`` by ``method`` (``"exact"`` or ``"histogram"`` with
    ``bin_db`` dB bins)."""
    if method not in METHODS:
        raise ValueError(f"background method {method!r}; expected one of {METHODS}")
    t0 = time.perf_counter()
    out = (median_exact(mag, kernel, boundary, ignore_zeros) if method == "exact" else
           median_histogram(mag, kernel, bin_db, boundary, ignore_zeros))
    log.debug("%s median of %s voxels, kernel %s, %s boundary: %.2f s", method,
              "x".join(map(str, np.shape(mag))), "x".join(map(str, kernel)), boundary,
              time.perf_counter() - t0)
    return out


def _check(mag: np.ndarray, kernel) -> None:
    if mag.ndim != 3:
        raise ValueError(f"expected a 3-D volume, got shape {mag.shape}")
    if len(kernel) != 3 or any(int(k) != k or k < 1 or k % 2 == 0 for k in kernel):
        raise ValueError(f"kernel must be three odd positive voxel counts, got {kernel}")
    if np.iscomplexobj(mag):
        raise ValueError("pass the magnitude, not the complex image")


def _float(mag: np.ndarray) -> type:
    return np.float64 if mag.dtype == np.float64 else np.float32


def greater_of_below(bg: np.ndarray, depth: np.ndarray, kernel_depth: int,
                     from_m: float | None) -> np.ndarray:
    """``bg`` (along x cross x depth) where each voxel at ``depth`` >= ``from_m`` takes
    the greater of its own value and that of the window just beneath it: the median
    window (``kernel_depth`` voxels deep) shifted down by ``kernel_depth // 2 + 1``
    planes, so that it holds only voxels deeper than this one (the last plane's beyond
    the tile's bottom). A greatest-of estimate against the upper edges of brighter
    layers: where a layer brightens within the window's depth, the centred median lags
    it and the voxels on its edge stand out; the window beneath sees the layer. A
    compact object fills neither window, so its level is unchanged. ``from_m`` None:
    ``bg`` as it is."""
    if from_m is None or bg.shape[-1] < 2:
        return bg
    sel = np.asarray(depth) >= from_m
    if not sel.any():
        return bg
    shift = int(kernel_depth) // 2 + 1
    idx = np.minimum(np.arange(bg.shape[-1]) + shift, bg.shape[-1] - 1)[sel]
    out = bg.copy()
    out[..., sel] = np.maximum(bg[..., sel], bg[..., idx])
    return out

