"""Navigation: the pose of the body origin at any time (e.g. every ping's transmit time).

Inputs are GPS fixes (geodetic, of the antenna; only real fixes: GGA quality 0
"invalid" and 6 "estimated", RMC status V or mode E/N are rejected and counted; an
optional GST horizontal sigma), headings (NMEA HDT; else the DVL's compass; else the
RMC course over ground; each fallback flagged), and DVL samples (bottom-track velocity
of the DVL head in the body frame, slant ranges of the four Janus beams and of a
vertical beam, roll, pitch and compass heading, the head's geometry). Output: :class:`svss_daq.ping.NavSnapshot` per
requested time; :meth:`Navigator.quality` summarises the solution's state.

Method (``docs/navigation.md``):

* Geodetic to survey NED: exact WGS-84 (geodetic -> ECEF -> rotation into the local
  north-east-down tangent plane at the survey origin); no flat-earth approximation.
* Lever arms (``config/hardware.toml`` ``lever_arms``): the fusion tracks the DVL head;
  body origin = head - R(roll, pitch, heading) @ r_dvl; a GPS fix measures the head
  plus R @ (r_gps - r_dvl).
* Fusion (:mod:`svss_daq.nav.fusion`): Kalman filters on the DVL's sample times, the
  DVL's velocities (rotated to NED) the process, GPS fixes (weighted by their GST
  sigma; those above ``gps_max_sigma_m`` rejected), GPS heights and the DVL's altitude
  the measurements; an RTS smoother over the records (a recording, or the live history
  up to ``fixed_lag_s`` past the ping). Without DVL, positions are interpolated
  linearly between fixes.
* DVL coordinates: PD0 bottom track in ``beam`` coordinates goes beam -> instrument by
  Teledyne RDI's "ADCP Coordinate Transformation" formulas (:func:`beam_to_instrument`,
  with a 3-beam solution when one beam is bad and ``dvl_min_beams`` is 3), then
  instrument -> ship with the heading alignment EA (and the 180 deg roll of an
  up-looking head); ``instrument`` the same without the first step; ``ship`` and
  ``earth`` as sent.
* Altitude above the bottom: mean over valid beams of range x (vertical component of
  the beam direction rotated by roll and pitch), plus the DVL head's depth below the body
  origin (:func:`head_height_m`). RDI's bottom-track ranges are vertical (along the
  beam x cos(beam angle)): samples hold them divided by that cosine. Janus beams at the
  fixed leader's beam angle (``dvl_beam_angle_deg`` only without one), RDI's layout for a
  down-looking convex head with beam 3 on the bow: 3 forward, 4 aft, 2 starboard, 1
  port (:func:`rdi_beam_vectors`; concave swaps the pairs). With fewer than
  ``dvl_min_beams`` slanted ranges, a vertical (fifth) beam's range is used.

Angles in radians, distances m, times int ns since the Unix epoch UTC.
"""


from svss_daq.ping import NAV_HEADING_FROM_COMPASS, NAV_HEADING_FROM_COURSE, NAV_NO_HEADING

from .nav.dvl_geometry import (altitude_from_ranges, beam_to_instrument, body_beam_vectors,
                               head_height_m, instrument_to_ship, janus_beam_vectors,
                               rdi_beam_vectors, three_beam_fill)
from .nav.fusion import compute_poses
from .nav.geodesy import (WGS84_A, WGS84_E2, WGS84_F, ecef_to_geodetic, geodetic_to_ecef,
                          geodetic_to_ned, ned_rotation, ned_to_geodetic)
from .nav.headings import wrap_angle
from .nav.navigator import Navigator
from .nav.clocks import InstrumentClock, PingClock
from .nav.nmea_samples import (GGA_NOT_A_FIX, RMC_MODE_NOT_A_FIX, NmeaSampler, gst_sigma_m,
                               samples_from_nmea)
from .nav.pd0_samples import dvl_sample_from_pd0
from .nav.records import DvlSample, GpsFix, HeadingSample
from .nav.renavigate import (Renavigation, RenavigationError, records_problem, renavigate,
                             renavigation)

__all__ = [
    "WGS84_A", "WGS84_F", "WGS84_E2", "NAV_HEADING_FROM_COURSE", "NAV_HEADING_FROM_COMPASS",
    "NAV_NO_HEADING", "GpsFix", "HeadingSample", "DvlSample", "geodetic_to_ecef",
    "ecef_to_geodetic", "ned_rotation", "geodetic_to_ned", "ned_to_geodetic",
    "rdi_beam_vectors", "janus_beam_vectors", "beam_to_instrument", "three_beam_fill",
    "instrument_to_ship", "altitude_from_ranges", "body_beam_vectors", "head_height_m",
    "gst_sigma_m", "dvl_sample_from_pd0",
    "samples_from_nmea", "NmeaSampler", "PingClock", "InstrumentClock", "compute_poses",
    "Navigator", "renavigate", "renavigation",
    "Renavigation", "RenavigationError", "records_problem", "GGA_NOT_A_FIX", "RMC_MODE_NOT_A_FIX", "wrap_angle",
]
