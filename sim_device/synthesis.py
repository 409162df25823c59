"""Element-level synthesis of point-scatterer echoes (numba kernels): the physics, and
the entry points of the two passes.

For every scatterer k, transmit leg image a and receive leg image b of channel ch, the
received pressure is (PHYSICS.md section 5)

    p_ch(t) = Re{ sum A_t(k, a) A_r(k, b, ch) s_a(t - tau_t(k, a) - tau_r(k, b, ch)) },

with s_a the analytic transmit pulse and A_t, A_r the complex leg factors: source level
and scatterer strength (on the transmit leg), beam gain, spreading, interface
transmission (1 + R down, 1 - R up), sediment and water attenuation, and the multipath
factors R_s^n_s R_b^n_b of image legs. Interface scatterers take sigma(theta)^(1/4) on
each leg, i.e. the bistatic strength sqrt(sigma(theta_t) sigma(theta_r)) (equal to the
monostatic sigma for backscatter). Levels are evaluated at the carrier frequency.

Rather than evaluating the pulse per echo, the kernels add each echo's complex baseband
impulse A exp(-j 2 pi f_c tau) (the convention of :mod:`svss_daq.conventions`) at its
fractional delay into a baseband buffer with 4-tap Lagrange weights, and
:meth:`~sim_device.pulse.PulseSynthesiser.to_passband` convolves the buffer once with the
sampled baseband pulse and remodulates (:mod:`sim_device.pulse`). Geometry is in the
tile frame (z down from the interface), float64.

The rooms:

* :mod:`sim_device.synthesis_args`: what the kernels take, as named bundles (scatterers,
  transmit legs, paths, medium, beam, window; :class:`Pass2`: pass 2's together);
* :mod:`sim_device.synthesis_legs`: the scalar functions of a leg, written once for the
  CPU and the GPU (:func:`build`);
* :mod:`sim_device.echo_loop`: the scalar transmit leg and pass 2's echo loop, written
  once over a leg function for the reference, curved and GPU kernels;
* :mod:`sim_device.synthesis_reference`: the reference kernels (pass 1 by the scalar
  leg, pass 2 parallel over channels: :func:`accumulate`);
* :mod:`sim_device.synthesis_fast` (with :mod:`sim_device.synthesis_fast_legs`, the legs
  in vectorisable loops): the default kernels (pass 1 vectorised across scatterers,
  pass 2 scatterer-parallel into per-thread float32 buffers: :func:`accumulate_fast`,
  :func:`accumulate_fast_serial`);
* :mod:`sim_device.synthesis_gpu`: pass 2 on a GPU; :mod:`sim_device.synthesis_curved`:
  the reference kernels over an undulating interface;
* :mod:`sim_device.pulse`: the digitised pulse and the buffers' passband.

Pass 1 (:func:`transmit_legs`, here: it picks the reference or the fast kernel) takes
the bundles (``pts, samp, img, medium, beam, out``); pass 2's entry points take one
:class:`~sim_device.synthesis_args.Pass2`. This module re-exports the names the rest of
the simulator and its tests use.
"""

from __future__ import annotations

from .pulse import AA_PAD, AA_PASS, AA_STOP, PulseSynthesiser, digitised_pulse  # noqa: F401
from .synthesis_args import (  # noqa: F401 (re-exported)
    IMG_DIR,
    IMG_H,
    IMG_NB,
    IMG_RS,
    IMG_X,
    IMG_Y,
    MED_INTERFACE,
    Beam,
    Medium,
    Pass2,
    Paths,
    Points,
    TransmitLegs,
    Window,
    beam_of,
    window,
)
from .synthesis_fast import (  # noqa: F401 (re-exported)
    SERIAL_BELOW,
    accumulate_fast,
    accumulate_fast_kernel,
    accumulate_fast_serial,
    accumulate_fast_serial_kernel,
    transmit_fast_kernel,
)
from .synthesis_legs import (  # noqa: F401 (re-exported)
    build,
    cis_cycles,
    cis_cycles32,
    float_floor,
    gain,
    lagrange4,
    leg,
    leg_amplitude,
    leg_body,
    ray_amplitude_terms,
    two_medium_terms,
)
from .synthesis_reference import (  # noqa: F401 (re-exported)
    accumulate,
    accumulate_kernel,
    path_kept,
    receive_needed,
    receive_plan,
    transmit_kernel,
)


def transmit_legs(pts: Points, samp, img, medium: Medium, beam: Beam, out: TransmitLegs,
                  fast: bool = False) -> None:
    """Pass 1: every scatterer's transmit legs (``pts``, strengths ``samp``), one per
    projector image (rows of ``img``), through ``medium`` and the projector's ``beam``,
    into ``out``: by :func:`transmit_kernel` (the scalar leg per scatterer and image) or,
    ``fast``, :func:`transmit_fast_kernel` (the same legs, those of first-sediment
    scatterers vectorised across scatterers)."""
    (transmit_fast_kernel if fast else transmit_kernel)(pts, samp, img, medium, beam, out)
