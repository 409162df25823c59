"""Settings of the simulated navigation instruments (``config/sim-device.toml``,
sections ``[dvl]`` and ``[gps]``).

Schema only, declared with :func:`svss_daq.config.spec` (doc with units, range); the
values live in the TOML file, none in code. :class:`DvlSimConfig` and
:class:`GpsSimConfig` are meant to be composed into the simulated device's whole
configuration; :func:`load_instruments` reads just these two sections of a file that
may hold others.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from svss_daq.config import from_dict, read_toml, spec

__all__ = ["DvlSimConfig", "GpsSimConfig", "NavInstrumentsConfig", "load_instruments"]


@dataclass(frozen=True)
class DvlSimConfig:
    """A Teledyne RDI Workhorse-family DVL sending PD0 ensembles with bottom track."""
    rate_hz: float = spec("ensemble rate, Hz", lo=0.1, hi=20)
    latency_s: float = spec("delay from the measurement (the ensemble's time stamp) to the "
                            "ensemble on the wire, s", lo=0.0, hi=5.0)
    coordinate_system: str = spec("bottom-track velocity coordinates (PD0 EX): ship "
                                  "(X stbd, Y fwd, Z up) or earth (E, N, U)",
                                  choices=("ship", "earth"))
    beam_angle_deg: float = spec("Janus beam angle from the vertical, deg (written to the "
                                 "fixed leader, which the navigation reads)",
                                 choices=(20.0, 30.0))
    frequency_khz: float = spec("system frequency written to the fixed leader, kHz",
                                choices=(75.0, 150.0, 300.0, 600.0, 1200.0, 2400.0))
    max_range_m: float = spec("slant range beyond which a beam finds no bottom, m",
                              lo=0.5, hi=1000)
    velocity_sigma_m_s: float = spec("white noise on each bottom-track velocity "
                                     "component, m/s (1 sigma)", lo=0.0, hi=1.0)
    range_sigma_m: float = spec("white noise on each beam's slant range, m (1 sigma)",
                                lo=0.0, hi=10.0)
    heading_sigma_deg: float = spec("white noise on the compass heading, deg (1 sigma)",
                                    lo=0.0, hi=20.0)
    tilt_sigma_deg: float = spec("white noise on pitch and roll, deg (1 sigma)",
                                 lo=0.0, hi=10.0)
    sound_speed_m_s: float = spec("sound speed the instrument reports (EC), m/s",
                                  lo=1400, hi=1600)
    salinity_ppt: float = spec("salinity the instrument reports (ES), ppt", lo=0, hi=40)
    temperature_c: float = spec("water temperature the instrument reports, deg C",
                                lo=-5, hi=40)
    transducer_depth_m: float = spec("transducer depth the instrument reports (ED), m",
                                     lo=0.0, hi=1000)
    serial_number: int = spec("instrument serial number in the fixed leader",
                              lo=0, hi=2**32 - 1)
    seed: int = spec("seed of the noise generator", lo=0, hi=2**63 - 1)
    # error cases (docs/sim_device.md, "DVL error cases")
    velocity_scale_error: float = spec(
        "velocity scale error: the measured bottom-track velocity is (1 + this) times the "
        "true one (0.005: 0.5 %)", lo=-0.5, hi=0.5)
    misalignment_deg: float = spec(
        "mounting misalignment about the vertical not in the heading alignment EA: the "
        "head's forward axis turned this far to starboard (clockwise seen from above), so "
        "the velocity it measures is the body's turned the other way, deg",
        lo=-180.0, hi=180.0)
    dropout_start_s: float = spec(
        "start of a bottom-lock dropout, simulated seconds after the track's start",
        lo=-1e6, hi=1e6)
    dropout_s: float = spec(
        "length of that dropout (bad velocities -32768, ranges 0), s; 0: none",
        lo=0.0, hi=1e6)


@dataclass(frozen=True)
class GpsSimConfig:
    """A dual-antenna GNSS receiver (heading along body x) sending NMEA 0183."""
    rate_hz: float = spec("GGA, RMC, VTG and HDT rate, Hz", lo=0.1, hi=50)
    zda_rate_hz: float = spec("ZDA rate, Hz", lo=0.01, hi=50)
    latency_s: float = spec("delay from the fix time (the sentences' time field) to the "
                            "sentences on the wire, s", lo=0.0, hi=5.0)
    origin_latitude_deg: float = spec("survey origin (north of the NED frame the track is "
                                      "given in): latitude, deg", lo=-89.0, hi=89.0)
    origin_longitude_deg: float = spec("survey origin longitude, deg", lo=-180.0, hi=180.0)
    origin_height_m: float = spec("survey origin ellipsoidal height, m (NED down = 0 "
                                  "there)", lo=-1000.0, hi=10000.0)
    geoid_separation_m: float = spec("geoid height above the ellipsoid reported in GGA "
                                     "(altitude = ellipsoidal height - this), m",
                                     lo=-120.0, hi=120.0)
    position_sigma_m: float = spec("white noise on the antenna's north and east, m "
                                   "(1 sigma each)", lo=0.0, hi=100.0)
    height_sigma_m: float = spec("white noise on the antenna height, m (1 sigma)",
                                 lo=0.0, hi=100.0)
    heading_sigma_deg: float = spec("white noise on the HDT heading, deg (1 sigma)",
                                    lo=0.0, hi=20.0)
    velocity_sigma_m_s: float = spec("white noise on the velocity over ground (RMC, VTG) "
                                     "per horizontal component, m/s (1 sigma)",
                                     lo=0.0, hi=10.0)
    fix_quality: int = spec("GGA fix quality while the fix is good (1 GPS, 2 DGPS, "
                            "4 RTK fixed, 5 RTK float)", choices=(1, 2, 4, 5))
    satellites: int = spec("satellites in use reported in GGA", lo=0, hi=99)
    hdop: float = spec("horizontal dilution of precision reported in GGA", lo=0.1, hi=99)
    talker: str = spec("talker ID of GGA, RMC, VTG and ZDA", choices=("GP", "GN", "GL", "GA"))
    heading_talker: str = spec("talker ID of HDT", choices=("GP", "GN", "HE", "HC"))
    seed: int = spec("seed of the noise generator", lo=0, hi=2**63 - 1)


@dataclass(frozen=True)
class NavInstrumentsConfig:
    dvl: DvlSimConfig = spec("simulated DVL")
    gps: GpsSimConfig = spec("simulated GPS")


def load_instruments(path: str | os.PathLike) -> NavInstrumentsConfig:
    """The ``[dvl]`` and ``[gps]`` sections of ``path`` (other sections are left to
    their own schemas); errors name the file and the dotted key."""
    data = read_toml(path)
    return from_dict(NavInstrumentsConfig, {k: data[k] for k in ("dvl", "gps") if k in data},
                     str(path))
