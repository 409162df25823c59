"""The simulated DVL and GPS on real pseudo-terminals, read by the project's own drivers
(SerialLink + PD0/NMEA stream parsers) and svss_daq.navigation.Navigator, as on the boat.

Simulated time runs TIME_SCALE times faster than the host; tolerances follow the injected
noise (config/sim-device.toml) plus the encodings' resolution.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time

import numpy as np
import pytest

from sim_device.devices.clock import SimClock
from sim_device.devices.dvl import DvlEmulator
from sim_device.devices.gps import GpsEmulator, antenna_ned
from sim_device.devices.instruments_config import load_instruments
from sim_device.scene import MotionConfig, load_scene
from sim_device.track import parse_utc_ns, pose_at
from svss_daq.config import DevicesConfig, HardwareConfig, config_path, load
from svss_daq.protocols import nmea
from svss_daq.protocols.nmea import NmeaStreamParser
from svss_daq.protocols.pd0 import Pd0StreamParser
from svss_daq.drivers.serial_link import SerialLink
from svss_daq.frames import body_to_ned
from svss_daq.navigation import (Navigator, dvl_sample_from_pd0, geodetic_to_ned,
                                 head_height_m, janus_beam_vectors)
from svss_daq.ping import (NAV_BOTTOM_LOCK, NAV_DEAD_RECKONED, NAV_GPS_FIX,
                           NAV_HEADING_FROM_COMPASS, NAV_NO_HEADING)

TIME_SCALE = 5.0
DEG = math.pi / 180
WAIT_S = 5.0


@pytest.fixture(scope="module")
def setup():
    inst = load_instruments(config_path("sim-device.toml"))
    hw = load(HardwareConfig, config_path("hardware.toml"))
    nav = load(DevicesConfig, config_path("devices.toml")).navigation
    g = inst.gps
    nav = dataclasses.replace(nav, origin_latitude_deg=g.origin_latitude_deg,
                              origin_longitude_deg=g.origin_longitude_deg,
                              origin_height_m=g.origin_height_m,
                              dvl_beam_angle_deg=inst.dvl.beam_angle_deg)
    scene = load_scene(config_path("scenes/demo.toml"))
    track = dataclasses.replace(scene.track, motion=MotionConfig(
        heave_m=0.1, heave_period_s=7.0, sway_m=0.2, sway_period_s=11.0, roll_deg=3.0,
        roll_period_s=5.0, pitch_deg=1.5, pitch_period_s=6.0, yaw_deg=4.0, yaw_period_s=13.0))
    start_ns = parse_utc_ns(track.start_time_utc)
    seed = scene.scene.seed

    def truth(t_ns: int):
        return pose_at(track, (t_ns - start_ns) * 1e-9, seed)

    return dict(inst=inst, hw=hw, nav=nav, truth=truth, start_ns=start_ns)


class Rig:
    """Emulators and the project's readers, records stamped with the simulated clock on
    arrival (HDT carries no time: it is stamped with its epoch's GGA time, the receiver
    sending an epoch's sentences together)."""

    def __init__(self, s, tmp_path, gps_cfg=None, dvl_cfg=None) -> None:
        self.clock = SimClock(s["start_ns"], TIME_SCALE)
        lev = s["hw"].lever_arms
        self.gps = GpsEmulator(gps_cfg or s["inst"].gps, lev, self.clock, s["truth"], tmp_path)
        self.dvl = DvlEmulator(dvl_cfg or s["inst"].dvl, lev, self.clock, s["truth"], tmp_path)
        self.nmea: list = []   # (arrival sim ns, record)
        self.pd0: list = []
        self._epoch_ns = None
        self.links = []

    def _on_nmea(self, rec) -> None:
        self.nmea.append((self.clock.now_ns(), rec))

    def _on_pd0(self, rec) -> None:
        self.pd0.append((self.clock.now_ns(), rec))

    def __enter__(self) -> "Rig":
        self.clock.start()
        self.gps.start()
        self.dvl.start()
        for dev, parser, cb in ((self.gps, NmeaStreamParser(), self._on_nmea),
                                (self.dvl, Pd0StreamParser(), self._on_pd0)):
            link = SerialLink(dev.port, parser, on_record=cb, reconnect_initial_s=0.02,
                              reconnect_max_s=0.1)
            link.start(wait_connected_s=WAIT_S)
            self.links.append(link)
        return self

    def __exit__(self, *exc) -> None:
        for link in self.links:
            link.stop()
        self.gps.close()
        self.dvl.close()

    def run_for(self, sim_s: float) -> None:
        time.sleep(sim_s / TIME_SCALE)

    def stamped_nmea(self) -> list:
        out, epoch = [], None
        for _, rec in self.nmea:
            if isinstance(rec, nmea.GgaFix):
                epoch = rec.time_ns
            if isinstance(rec, nmea.HdtHeading):
                if epoch is not None:
                    out.append((epoch, rec))
            else:
                out.append(rec)
        return out

    def of(self, cls) -> list:
        return [r for _, r in self.nmea if isinstance(r, cls)]

    def ensembles(self) -> list:
        return [e for _, e in self.pd0]


def test_instruments_match_the_true_track_and_navigation_poses_pings(setup, tmp_path):
    s = setup
    g, d = s["inst"].gps, s["inst"].dvl
    with Rig(s, tmp_path) as rig:
        rig.run_for(14.0)
    truth, lev = s["truth"], s["hw"].lever_arms
    origin = (g.origin_latitude_deg, g.origin_longitude_deg, g.origin_height_m)

    # GPS: time stamps, antenna position, heading, velocity, latency
    ggas = [r for r in rig.of(nmea.GgaFix) if r.time_ns is not None]
    assert len(ggas) >= 0.8 * 14.0 * g.rate_hz
    assert all(r.fix_quality == g.fix_quality and r.satellites == g.satellites for r in ggas)
    period = int(1e9 / g.rate_hz)
    assert all(r.time_ns % period == 0 for r in ggas)  # stamped with the fix time
    for r in ggas:
        ant = antenna_ned(truth(r.time_ns), lev.gps_antenna_m)
        got = geodetic_to_ned(r.latitude_deg, r.longitude_deg,
                              r.altitude_msl_m + r.geoid_separation_m, origin)
        assert np.all(np.abs(got[:2] - ant[:2]) < 4 * g.position_sigma_m + 1e-3), (got, ant)
        assert abs(got[2] - ant[2]) < 4 * g.height_sigma_m + 1e-3
    rmcs = rig.of(nmea.RmcFix)
    assert rmcs and all(r.valid and r.mode == "D" for r in rmcs)
    for r in rmcs:
        p = truth(r.time_ns)
        assert abs(r.speed_mps - math.hypot(p.vel_north_m_s, p.vel_east_m_s)) < 0.3
    heads = [x for x in rig.stamped_nmea() if isinstance(x, tuple)]
    assert len(heads) >= len(ggas) - 1
    for t, h in heads:
        err = math.remainder(h.heading_rad - truth(t).heading_rad, 2 * math.pi)
        assert abs(err) < 4 * g.heading_sigma_deg * DEG + 0.005 * DEG
    zdas = rig.of(nmea.ZdaTime)
    assert 0.8 * 14.0 * g.zda_rate_hz <= len(zdas) <= 14.0 * g.zda_rate_hz + 1
    lag = [(t_rx - r.time_ns) * 1e-9 for t_rx, r in rig.nmea
           if isinstance(r, nmea.GgaFix) and r.time_ns is not None]
    assert min(lag) >= g.latency_s - 0.005 and np.median(lag) < g.latency_s + 0.1

    # DVL: time, attitude, body velocity of the head, ranges, latency
    ens = rig.ensembles()
    assert len(ens) >= 0.8 * 14.0 * d.rate_hz
    assert [e.ensemble_number for e in ens] == list(range(ens[0].ensemble_number,
                                                          ens[0].ensemble_number + len(ens)))
    beam = d.beam_angle_deg * DEG
    for e in ens:
        p = truth(e.time_ns)
        assert abs(e.pitch_rad - p.pitch_rad) < 4 * d.tilt_sigma_deg * DEG + 0.005 * DEG
        assert abs(e.roll_rad - p.roll_rad) < 4 * d.tilt_sigma_deg * DEG + 0.005 * DEG
        assert abs(math.remainder(e.heading_rad - p.heading_rad, 2 * math.pi)) \
            < 4 * d.heading_sigma_deg * DEG + 0.005 * DEG
        smp = dvl_sample_from_pd0(e)
        dt = 1e-3
        v_ned = (antenna_ned(truth(e.time_ns + 10**6), lev.dvl_m)
                 - antenna_ned(truth(e.time_ns - 10**6), lev.dvl_m)) / (2 * dt)
        v_body = body_to_ned(p.roll_rad, p.pitch_rad, p.heading_rad).T @ v_ned
        assert np.all(np.abs(np.array(smp.velocity_body_m_s) - v_body)
                      < 4 * d.velocity_sigma_m_s + 0.002), (smp.velocity_body_m_s, v_body)
        head_h = p.down_m + p.altitude_m - antenna_ned(p, lev.dvl_m)[2]
        rot = body_to_ned(p.roll_rad, p.pitch_rad, p.heading_rad)
        want = head_h / (janus_beam_vectors(beam) @ rot.T)[:, 2]   # along the beams
        # on the wire, RDI's vertical ranges: along the beam x cos(beam angle), untilted
        assert e.fixed.beam_angle_rad == pytest.approx(beam)
        assert np.all(np.abs(e.bottom_track.range_m - want * math.cos(beam))
                      < 4 * d.range_sigma_m + 0.006)
        assert np.all(np.abs(np.array(smp.ranges_m) - want) < 4 * d.range_sigma_m + 0.006)
        assert abs(head_height_m(smp) - head_h) < 4 * d.range_sigma_m + 0.006
    lag = [(t_rx - e.time_ns) * 1e-9 for t_rx, e in rig.pd0]
    assert min(lag) >= d.latency_s - 0.005 and np.median(lag) < d.latency_s + 0.1

    # Navigator: each ping time's pose within the expected error
    nav = Navigator(s["nav"], lev)
    nav.add_nmea(rig.stamped_nmea())
    for e in ens:
        nav.add_pd0(e)
    t0 = max(ggas[0].time_ns, ens[0].time_ns) + 10**9
    t1 = min(ggas[-1].time_ns, ens[-1].time_ns) - 10**9
    pings = np.arange(t0, t1, 10**8)  # 10 pings/s
    poses = nav.poses(pings)
    err_h = [math.hypot(q.north_m - truth(t).north_m, q.east_m - truth(t).east_m)
             for t, q in zip(pings, poses)]
    logging.getLogger(__name__).info("navigation on the emulators: horizontal RMS %.3f m, "
                                     "max %.3f m over %d pings", np.sqrt(np.mean(np.square(err_h))),
                                     max(err_h), len(pings))
    assert max(err_h) < 3 * g.position_sigma_m  # smoothed GPS on the DVL's track shape
    for t, q in zip(pings, poses):
        p = truth(t)
        assert q.quality & NAV_GPS_FIX and q.quality & NAV_BOTTOM_LOCK
        assert abs(math.remainder(q.heading_rad - p.heading_rad, 2 * math.pi)) < 0.5 * DEG
        assert abs(q.roll_rad - p.roll_rad) < 0.3 * DEG and abs(q.pitch_rad - p.pitch_rad) < 0.3 * DEG
        assert abs(q.altitude_m - p.altitude_m) < 0.05
        assert abs(q.down_m - p.down_m) < 4 * g.height_sigma_m
        assert math.hypot(q.vel_north_m_s - p.vel_north_m_s, q.vel_east_m_s - p.vel_east_m_s) < 0.1


def test_vanish_and_garbage_resynchronise_without_losing_valid_data(setup, tmp_path, caplog):
    s = setup
    caplog.set_level(logging.WARNING)
    with Rig(s, tmp_path) as rig:
        rig.run_for(2.0)
        dvl_link, gps_link = rig.links[1], rig.links[0]
        # garbage between messages, a false PD0 header among it
        n_before = rig.dvl.ensemble_number
        junk = b"\x13\x7f\x7f\x30\x01\x00\x02\x99garbage\x7f"
        rig.dvl.inject_garbage(junk)
        rig.gps.inject_garbage(b"\x00\xffnoise$GPGGA,12*00\r\n\x01\x02")
        rig.run_for(2.0)
        # the DVL vanishes for 3 s of simulated time and returns under the same path
        port = rig.dvl.port
        dev_before = dvl_link.device
        rig.dvl.vanish(3.0)
        assert rig.dvl.port == port
        t_end = time.monotonic() + WAIT_S
        while time.monotonic() < t_end and not (dvl_link.stats.connects >= 2 and dvl_link.connected):
            time.sleep(0.01)
        assert dvl_link.connected and dvl_link.device is not None  # back under the same path
        rig.run_for(2.5)
    nums = [e.ensemble_number for e in rig.ensembles()]
    assert n_before in nums and n_before + 1 in nums  # nothing lost around the garbage
    p = dvl_link.parser.stats
    assert p.bytes_discarded >= len(junk) and p.discard_runs >= 1
    assert dvl_link.stats.disconnects >= 1 and dvl_link.stats.connects >= 2
    assert dev_before is not None
    gaps = [(a, b) for a, b in zip(nums, nums[1:]) if b != a + 1]
    assert len(gaps) == 1, gaps  # one gap: the vanish; data resumed after it
    missing = gaps[0][1] - gaps[0][0] - 1
    rate = s["inst"].dvl.rate_hz
    assert 3.0 * rate - 2 <= missing <= 3.0 * rate + 10
    assert rig.dvl.stats.writes_dropped >= 3.0 * rate - 2 and rig.dvl.stats.vanishes == 1
    assert nums[-1] - gaps[0][1] >= 2.0 * rate - 2
    kinds = [f.kind for f in rig.dvl.stats.faults]
    assert kinds == ["garbage", "vanish", "return"]
    assert all("simulated time" in m for m in caplog.messages if "fault" in m)
    assert any("vanish" in m for m in caplog.messages)
    # GPS: the junk is rejected and counted, every epoch's GGA arrives
    assert gps_link.parser.stats.rejected >= 1
    times = [r.time_ns for r in rig.of(nmea.GgaFix) if r.time_ns is not None]
    assert np.all(np.diff(times) == int(1e9 / s["inst"].gps.rate_hz))


def test_gps_outage_and_lost_bottom_lock_as_the_instruments_show_them(setup, tmp_path):
    s = setup
    g, d = s["inst"].gps, s["inst"].dvl
    with Rig(s, tmp_path) as rig:
        rig.run_for(4.0)
        rig.gps.outage(6.0)  # longer than twice heading_max_age_s
        rig.run_for(7.0)
        rig.dvl.lose_bottom_lock(3.0)   # mid-loss 1.5 s from a sample with lock: beyond
        rig.run_for(5.0)                # navigation.dvl_max_gap_s (1 s)
    ggas = rig.of(nmea.GgaFix)
    nofix = [r for r in ggas if r.fix_quality == 0]
    assert abs(len(nofix) - 6.0 * g.rate_hz) <= 2 and all(r.latitude_deg is None for r in nofix)
    assert nofix[0].time_ns is not None  # the receiver's clock goes on
    assert len([r for r in rig.of(nmea.RmcFix) if not r.valid]) == len(nofix)
    assert len([h for h in rig.of(nmea.HdtHeading) if h.heading_rad is None]) == len(nofix)
    assert len(rig.of(nmea.ZdaTime)) >= 12  # ZDA through the outage
    ens = rig.ensembles()
    lost = [e for e in ens if np.all(np.isnan(e.bottom_track.velocity_mps))]
    assert abs(len(lost) - 3.0 * d.rate_hz) <= 2
    assert all(np.all(np.isnan(e.bottom_track.range_m)) and
               np.all(e.bottom_track.velocity_raw == -32768) for e in lost)
    assert all(np.all(np.isnan(dvl_sample_from_pd0(e).velocity_body_m_s)) for e in lost)
    # navigation: dead reckoning through the outage, no altitude without bottom lock
    nav = Navigator(s["nav"], s["hw"].lever_arms)
    nav.add_nmea(rig.stamped_nmea())
    for e in ens:
        nav.add_pd0(e)
    t_out = nofix[len(nofix) // 2].time_ns
    t_lost = lost[len(lost) // 2].time_ns
    t_dr = nofix[0].time_ns + int(1.6e9)  # past gps_fix_max_age_s, within heading_max_age_s
    q_out, q_lost, q_dr = nav.poses([t_out, t_lost, t_dr])
    assert q_out.quality & NAV_DEAD_RECKONED and not q_out.quality & NAV_GPS_FIX
    # a GNSS compass loses heading with the fix: the DVL's compass carries it
    assert q_out.quality & NAV_HEADING_FROM_COMPASS and not q_out.quality & NAV_NO_HEADING
    assert math.isnan(q_lost.altitude_m) and not q_lost.quality & NAV_BOTTOM_LOCK
    assert q_lost.quality & NAV_GPS_FIX
    assert q_dr.quality & NAV_DEAD_RECKONED and not q_dr.quality & NAV_NO_HEADING
    p = s["truth"](t_dr)
    assert math.hypot(q_dr.north_m - p.north_m, q_dr.east_m - p.east_m) < 3 * g.position_sigma_m


def test_outputs_are_stamped_with_their_measurement_time_however_late_the_thread(setup,
                                                                              tmp_path):
    """An emulator stamps each output with its measurement time plus the clock's steps,
    read at once: it read the host clock twice, and a thread held up between the two
    reads (a loaded machine) stamped its output early by the hold-up times the time
    scale (DVL roll 0.0054 rad from the truth, 0.2 s at time scale 5). At a time scale
    of 1e5 every microsecond between two reads is 0.1 s: every GGA and every ensemble
    must still sit on its instrument's period grid (NMEA and PD0 carry hundredths of a
    second)."""
    s = setup
    g, d = s["inst"].gps, s["inst"].dvl
    clock = SimClock(s["start_ns"], 1e5)
    lev = s["hw"].lever_arms
    gps = GpsEmulator(g, lev, clock, s["truth"], tmp_path)
    dvl = DvlEmulator(d, lev, clock, s["truth"], tmp_path)
    got_nmea, got_pd0 = [], []
    links = []
    try:
        clock.start()
        gps.start()
        dvl.start()
        for dev, parser, out in ((gps, NmeaStreamParser(), got_nmea),
                                 (dvl, Pd0StreamParser(), got_pd0)):
            link = SerialLink(dev.port, parser, on_record=out.append,
                              reconnect_initial_s=0.02, reconnect_max_s=0.1)
            link.start(wait_connected_s=WAIT_S)
            links.append(link)
        # waits for what is asserted below: GGAs with a time (the first ones may come
        # before the stream's first date and have none)
        deadline = time.monotonic() + 60.0
        while (len([r for r in got_nmea if isinstance(r, nmea.GgaFix)
                    and r.time_ns is not None]) < 50
               or len(got_pd0) < 50) and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        for link in links:
            link.stop()
        gps.close()
        dvl.close()
    ggas = [r for r in got_nmea if isinstance(r, nmea.GgaFix) and r.time_ns is not None]
    assert len(ggas) >= 50 and len(got_pd0) >= 50
    for period_ns, stamps in ((int(round(1e9 / g.rate_hz)), [r.time_ns for r in ggas]),
                              (int(round(1e9 / d.rate_hz)), [e.time_ns for e in got_pd0])):
        off = [t % period_ns for t in stamps]
        assert all(o == 0 for o in off), sorted(set(off))[:10]
