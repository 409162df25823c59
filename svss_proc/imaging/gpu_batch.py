"""Several pings per GPU launch (issue 33): the pings a tile receives are queued on the
host and imaged by one launch per ``pings_per_launch`` pings, each thread summing its
voxel over the queued pings and channels and adding the sum to the tile once.

Why: on an H100 the one-ping launch (:mod:`~svss_proc.imaging.gpu_kernel`) spent more
host time per ping preparing the launch's ~50 array arguments (0.56 s per 250 pings)
and making three uploads (0.43 s) than the GPU spent in the kernel (0.35 s). A batch
packs each ping's geometry into one row of one array in the kernel precision and one
in float64 (the cone decisions at an edge), and their along- and cross-track ranges and
ring slot into a third: three uploads and one launch per batch, and the image read and
written once per batch instead of once per ping. Each ping's tap planes sit in one slot
of a device ring (:class:`PlaneRing`), uploaded once however many tiles the ping
reaches, or made there from its codes (:mod:`~.gpu_conditioning`, issue 52); the
kernel reads them through the slot number.

Row layout, both precisions (``n_a``, ``n_c``, ``n_d`` voxels along, across, in
depth; ``n_ch`` channels), offsets from the projector as in
:class:`~svss_proc.imaging.kernel_args.VoxelGeometry`:

    ax[n_a] cy[n_c] dz[n_d] rx_dx[n_ch] rx_dy[n_ch] rx_h[n_ch] apod[n_ch] bore[3]
    h_tx cos_tx cos_rx t0 inv_dt theta

(the float64 row leaves the apodisation's place unused and ends at ``cos_rx``). The
kernel rebuilds the one-ping bundle (:class:`~svss_proc.imaging.kernel_args.KernelArgs`)
from row views and calls the same voxel sum as the one-ping kernel
(:mod:`~svss_proc.imaging.kernel_math`), so a batch adds exactly the per-ping sums,
in a different order of float additions.

A queue is flushed when it is full, when the next ping needs another kernel
specialisation, travel-time model or sample count, and before anything reads the tile
(:meth:`PingBatcher.flush`, which :meth:`~.imager.PingAccumulator.settle` calls).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import cuda

from .gpu_kernel import _BUFFERS, _math, _delays_to_device, cross_range, run_ping_gpu
from .gpu_shared import THREADS, block_count_for
from .gpu_staging import StagedRows, on_device
from .kernel_args import (ConeGate, DelayModel, ImageSlice, KernelArgs, KernelData,
                          PingArray, TapPlanes, VoxelGeometry, check_call, kernel_args)
from .kernel_math import kernel_one

_voxel_sum = _math.voxel_sum
block_count = block_count_for(globals())     # the block sum (gpu_shared)

#: scalars at the end of a row: h_tx cos_tx cos_rx t0 inv_dt theta
N_SCALARS = 6


def row_length(na: int, nc: int, nd: int, nch: int) -> int:
    """Length of a ping's geometry row (module docstring)."""
    return na + nc + nd + 4 * nch + 3 + N_SCALARS


def pack_row(row: np.ndarray, g, planes: TapPlanes | None) -> None:
    """Write one ping's geometry ``g`` (:class:`VoxelGeometry` or :class:`ConeGate`) and
    ``planes``' sample axis (None: the float64 row, which has none) into ``row``."""
    o = 0
    for a in (g.ax, g.cy, g.dz, g.rx_dx, g.rx_dy, g.rx_h,
              getattr(g, "apod", None), g.bore):
        n = len(g.rx_dx) if a is None else a.size
        if a is not None:
            row[o:o + n] = a
        o += n
    row[o:o + 3] = (g.h_tx, g.cos_tx, g.cos_rx)
    if planes is not None:
        row[o + 3:o + 6] = (planes.t0, planes.inv_dt, planes.theta)


_KERNELS: dict = {}


def _make_kernel(interp: int, mode: int, gating: bool, halvings: int):
    @cuda.jit
    def kernel(img_re, img_im, ring, rows, rows64, ranges, nk, tt, surf, surf64, na,
               nc, nch, ia0, ia1, ic0, ic1, count):
        i = cuda.grid(1)
        ncb = ic1 - ic0
        nd = img_re.shape[2]
        part = cuda.shared.array(THREADS, dtype=np.int64)
        n = 0
        if i < (ia1 - ia0) * ncb * nd:
            ia = ia0 + i // (ncb * nd)
            rem = i % (ncb * nd)
            ic = ic0 + rem // nd
            iz = rem % nd
            one = kernel_one(ring[0, 0])            # the kernel precision
            acc_re = one - one
            acc_im = one - one
            o_c = na
            o_d = o_c + nc
            o_x = o_d + nd
            o_y = o_x + nch
            o_h = o_y + nch
            o_w = o_h + nch
            o_b = o_w + nch
            o_s = o_b + 3
            for k in range(nk):
                if ia < ranges[k, 0] or ia >= ranges[k, 1] or ic < ranges[k, 2] \
                        or ic >= ranges[k, 3]:
                    continue
                g = rows[k]
                f = rows64[k]
                p = ranges[k, 4]                     # the ping's slot in the ring
                args = KernelArgs(
                    TapPlanes(ring[p, 0], ring[p, 1], g[o_s + 3], g[o_s + 4], g[o_s + 5]),
                    VoxelGeometry(g[0:o_c], g[o_c:o_d], g[o_d:o_x], g[o_s], g[o_x:o_y],
                                  g[o_y:o_h], g[o_h:o_w], g[o_w:o_b], g[o_b:o_s],
                                  g[o_s + 1], g[o_s + 2], surf),
                    tt,
                    ConeGate(f[0:o_c], f[o_c:o_d], f[o_d:o_x], f[o_s], f[o_x:o_y],
                             f[o_y:o_h], f[o_h:o_w], f[o_b:o_s], f[o_s + 1], f[o_s + 2],
                             surf64))
                sr, si, m = _voxel_sum(ia, ic, iz, interp, mode, gating, halvings, args,
                                       one)
                acc_re += sr
                acc_im += si
                n += m
            img_re[ia, ic, iz] += acc_re             # each thread owns its voxel
            img_im[ia, ic, iz] += acc_im
        block_count(part, n, count)                  # the block's updates, one atomic add

    return kernel


def kernel_for(interp: int, mode: int, gating: bool, halvings: int):
    key = (interp, mode, bool(gating), int(halvings))
    if key not in _KERNELS:
        _KERNELS[key] = _make_kernel(*key)
    return _KERNELS[key]


@dataclass
class _Queue:
    """The pings queued for one tile: their kernel arguments, voxel ranges and ring
    slots."""
    out: ImageSlice
    count: object
    key: tuple
    delays: DelayModel
    args: list = field(default_factory=list)
    ranges: list = field(default_factory=list)


class PlaneRing:
    """The device tap planes of the pings queued (module docstring): ``capacity`` slots
    of one plane shape and dtype, each held by reference counts: the queues it is in
    (until their launch is enqueued) and whoever made it (the imager, until the ping is
    imaged). Planes made on the host go up through page-locked staging
    (:class:`~.gpu_staging.StagedRows`); planes made on the device
    (:mod:`~.gpu_conditioning`) are written into their slot there."""

    def __init__(self, capacity: int, plane_shape: tuple, dtype, stream):
        self.capacity = int(capacity)
        self.staged = StagedRows(capacity, (2,) + tuple(plane_shape), dtype, stream)
        self.refs = np.zeros(self.capacity, dtype=np.int64)
        self.of: dict[int, tuple] = {}        # id(kernel data): (kernel data, slot)

    @property
    def device(self):
        """The ring, (capacity, 2, taps, channels, samples) on the device."""
        return self.staged.device

    def fits(self, plane_shape: tuple, dtype) -> bool:
        return self.staged.fits((2,) + tuple(plane_shape), dtype)

    def free_slot(self) -> int | None:
        free = np.flatnonzero(self.refs == 0)
        return None if free.size == 0 else int(free[0])

    def drop(self, slot: int) -> None:
        """One reference of ``slot`` less; the slot is free at none."""
        self.refs[slot] -= 1
        if self.refs[slot] <= 0:
            self.refs[slot] = 0
            self.forget(slot)

    def forget(self, slot: int) -> None:
        """No kernel data names ``slot`` any more."""
        for key, (_, s) in list(self.of.items()):
            if s == slot:
                del self.of[key]


class PingBatcher:
    """The GPU kernel's front door with pings batched per tile: :meth:`run_ping` has the
    signature of :func:`~svss_proc.imaging.gpu_kernel.run_ping_gpu`; with a device
    counter (``count=``) it queues the ping and launches when ``pings_per_launch`` are
    queued for the tile; without one it runs the ping alone and waits, as
    ``run_ping_gpu`` does. :meth:`flush` launches what is queued. Uploads and launches
    go on :attr:`stream`, without waiting (:mod:`~.gpu_staging`); a ping's planes go up
    once however many tiles it reaches, or are made on the device
    (:meth:`device_planes`)."""

    def __init__(self, pings_per_launch: int):
        if pings_per_launch < 1:
            raise ValueError(f"pings_per_launch {pings_per_launch}, expected 1 or more")
        self.pings_per_launch = int(pings_per_launch)
        self._queues: dict[int, _Queue] = {}     # id(image plane re): queue
        #: the CUDA stream everything of the batches is enqueued on
        self.stream = cuda.stream()
        self._ring: PlaneRing | None = None
        self._rows: dict[str, StagedRows] = {}
        #: launches made and pings they imaged, ping planes made on the device (for
        #: benchmarks and tests)
        self.launches = 0
        self.pings = 0
        self.planes_made = 0

    def run_ping(self, out: ImageSlice, kd: KernelData, array: PingArray,
                 delays: DelayModel, *, gating: bool = True, count=None) -> int | None:
        if count is None:
            return run_ping_gpu(out, kd, array, delays, gating=gating)
        if kd.dtype != out.re.dtype:
            raise ValueError(f"kernel data is {kd.dtype}, the image planes are "
                             f"{out.re.dtype}")
        check_call(out)
        args = kernel_args(kd, array, out.axes, delays)
        ic0, ic1 = cross_range(args, gating)
        if out.ia1 <= out.ia0 or ic1 <= ic0 or len(out.axes.depth) == 0:
            return None
        key = (kd.interp, delays.code, bool(gating), kd.halvings, kd.planes.re.shape,
               id(count), id(delays.table), id(args.gate.surf))
        slot = self._slot_for(kd)            # (may launch every queue for room)
        q = self._queues.get(id(out.re))
        if q is not None and (q.key != key or q.delays.table is not delays.table):
            self._launch(q)
            q = None
        if q is None:
            q = self._queues[id(out.re)] = _Queue(out, count, key, delays)
        self._ring.refs[slot] += 1
        q.args.append(args)
        q.ranges.append((out.ia0, out.ia1, ic0, ic1, slot))
        if len(q.args) >= self.pings_per_launch:
            self._launch(q)
        return None

    # the ring of planes
    def _ring_for(self, plane_shape: tuple, dtype) -> PlaneRing:
        """The ring, made (again, after launching every queue) for these planes."""
        r = self._ring
        if r is None or not r.fits(plane_shape, dtype):
            self.flush()
            if r is not None and r.refs.any():
                raise RuntimeError("GPU planes of another shape are still held")
            # every tile a ping reaches may hold a full queue, and a ping is held while
            # it is imaged: room for three tiles' queues before a forced launch
            r = self._ring = PlaneRing(3 * self.pings_per_launch + 2, plane_shape, dtype,
                                       self.stream)
        return r

    def _claim(self, plane_shape: tuple, dtype) -> int:
        """A free slot (launching every queue when none is), held once."""
        ring = self._ring_for(plane_shape, dtype)
        slot = ring.free_slot()
        if slot is None:
            self.flush()
            slot = ring.free_slot()
            if slot is None:
                raise RuntimeError(f"all {ring.capacity} GPU plane slots are held")
        ring.forget(slot)
        ring.refs[slot] += 1
        return slot

    def _slot_for(self, kd: KernelData) -> int:
        """The ring slot of ``kd``'s planes: its own (made on the device, or uploaded
        for an earlier tile) or a new one they are uploaded into."""
        ring = self._ring
        if ring is not None and id(kd) in ring.of:
            return ring.of[id(kd)][1]
        p = kd.planes
        if on_device(p.re):
            raise ValueError("device tap planes not made by this batcher")
        slot = self._claim(p.re.shape, p.re.dtype)
        try:
            host = self._ring.staged.host_row(slot)
            host[0] = p.re
            host[1] = p.im
            self._ring.staged.send(slot)
        except BaseException:
            self._ring.drop(slot)
            raise
        self._ring.of[id(kd)] = (kd, slot)
        self._ring.refs[slot] -= 1           # held by the queues it goes into only
        return slot

    def device_planes(self, conditioner, codes: np.ndarray, axis) -> KernelData:
        """A ping's tap planes made on the device by ``conditioner``
        (:class:`~.gpu_conditioning.DeviceConditioner`) from its ADC codes (channels x
        samples) taken on ``axis``, in a ring slot held until :meth:`release`."""
        codes = np.asarray(codes)
        if not conditioner.accepts(codes):
            raise ValueError(f"codes of shape {codes.shape}: the device conditions at most "
                             f"{conditioner.n_in} samples a channel")
        axis = conditioner.conditioner.checked_axis(axis)   # before a slot is held
        shape = conditioner.plane_shape(codes.shape[0])
        slot = self._claim(shape, conditioner.dtype)
        ring = self._ring
        try:
            st = self._rows.get("codes")
            wide = (codes.shape[0], conditioner.n_in)
            if st is None or not st.fits(wide, np.int32) or st.capacity != ring.capacity:
                st = self._rows["codes"] = StagedRows(ring.capacity, wide, np.int32,
                                                      self.stream)
            row = st.host_row(slot)
            row[:, :codes.shape[1]] = codes
            d_codes = st.send(slot)
            kd = conditioner(d_codes, codes.shape[1], axis, ring.device, slot,
                             self.stream)
        except BaseException:
            ring.drop(slot)                  # nothing holds it: free again
            raise
        ring.of[id(kd)] = (kd, slot)
        self.planes_made += 1
        return kd

    def release(self, kd: KernelData) -> None:
        """Let go of planes made by :meth:`device_planes` (their slot is free once the
        launches that read them are enqueued)."""
        ring = self._ring
        if ring is not None and id(kd) in ring.of:
            ring.drop(ring.of[id(kd)][1])

    def flush(self, image_re=None) -> None:
        """Launch the pings queued for the tile whose real image plane is ``image_re``
        (None: for every tile)."""
        keys = list(self._queues) if image_re is None else [id(image_re)]
        for k in keys:
            q = self._queues.get(k)
            if q is not None:
                self._launch(q)

    def _staged(self, role: str, shape: tuple, dtype) -> StagedRows:
        """Page-locked staging of one launch's ``role`` rows (two launches' worth, so
        that packing a launch does not wait for the last one's copy)."""
        st = self._rows.get(role)
        if st is None or not st.fits(shape, dtype):
            st = self._rows[role] = StagedRows(2, shape, dtype, self.stream)
        st.turn ^= 1
        st.host_row(st.turn)
        return st

    def _launch(self, q: _Queue) -> None:
        self._queues.pop(id(q.out.re), None)
        nk = len(q.args)
        if nk == 0:
            return
        try:
            a0 = q.args[0]
            g0 = a0.geometry
            na, nc, nd, nch = g0.ax.size, g0.cy.size, g0.dz.size, g0.rx_dx.size
            dtype = a0.planes.re.dtype
            k = self.pings_per_launch
            row = row_length(na, nc, nd, nch)
            s_rows = self._staged("rows", (k, row), dtype)
            s_rows64 = self._staged("rows64", (k, row), np.float64)
            s_ranges = self._staged("ranges", (k, 5), np.int64)
            rows, rows64, ranges = (s.host[s.turn] for s in (s_rows, s_rows64, s_ranges))
            for j, a in enumerate(q.args):
                pack_row(rows[j], a.geometry, a.planes)
                pack_row(rows64[j], a.gate, None)
                ranges[j] = q.ranges[j]
            ranges[nk:] = 0
            r = np.asarray(q.ranges)
            ia0, ia1 = int(r[:, 0].min()), int(r[:, 1].max())
            ic0, ic1 = int(r[:, 2].min()), int(r[:, 3].max())
            interp, mode, gating, halvings = q.key[:4]
            d_rows, d_rows64, d_ranges = (s.send(s.turn)
                                          for s in (s_rows, s_rows64, s_ranges))
            n = (ia1 - ia0) * (ic1 - ic0) * nd
            kernel = kernel_for(interp, mode, gating, halvings)
            kernel[math.ceil(n / THREADS), THREADS, self.stream](
                q.out.re, q.out.im, self._ring.device, d_rows, d_rows64, d_ranges, nk,
                _delays_to_device(a0.delays), _BUFFERS.table(g0.surf),
                _BUFFERS.table(a0.gate.surf), na, nc, nch, ia0, ia1, ic0, ic1, q.count)
            self.launches += 1
            self.pings += nk
        finally:                             # enqueued (or failed): its slots let go
            for rr in q.ranges:
                self._ring.drop(rr[4])
