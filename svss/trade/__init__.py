"""``svss trade``: speed against accuracy of every option, measured on this machine.

One run times each option of three areas against the highest-fidelity setting of that
area on the reference workloads (``--quick``: tiny ones) and reports time against error:

* imaging (:mod:`.imaging`): interpolation, precision, delay model, voxel size,
  channel subsets, upsampling, and the GPU where numba finds one;
* simulation (:mod:`.simulation`): scatterers per resolution cell, multipath order,
  the volume's level cut-off, target series truncation and form-table step, measured in
  the image domain (mean level, speckle, target excess);
* normalisation (:mod:`.normalisation`): the exact median background against the
  histogram median at several bin widths.

:mod:`.report` finds each area's Pareto front, checks that the defaults (from
``config/processing.toml`` and the scene file) lie on it, recommends a setting for a
real-time budget per tile, and writes the table (CSV, JSON, markdown) and one Pareto
plot per area (PNG).
"""

from .runner import TradeResult, run_trade

__all__ = ["TradeResult", "run_trade"]
