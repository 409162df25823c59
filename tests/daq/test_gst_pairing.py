"""GST pairing when GSTs are lost: a 1 Hz receiver sending GGA, RMC and GST each epoch
(GST after its epoch's fix, or before it), every other GST lost. Each lost GST is
counted once (``gps_gst_missing``), each epoch rejected at most once, no fix given out
with an unknown sigma or with another epoch's sigma and then withdrawn by its own (a
ping posed between could have used it). The sentences are written out here (NMEA 0183
GGA, RMC, GST) and parsed by the project's stream parser."""

from __future__ import annotations

import math

import pytest

from svss_daq.nav.nmea_samples import NmeaSampler
from svss_daq.navigation import samples_from_nmea
from svss_daq.protocols.nmea import NmeaStreamParser

N = 30


def _sentence(body: str) -> str:
    x = 0
    for ch in body.encode("ascii"):
        x ^= ch
    return f"${body}*{x:02X}\r\n"


def _epoch(k: int, sigma: float, gst: bool, gst_first: bool) -> list[str]:
    t = f"12{k // 60:02d}{k % 60:02d}.00"
    pos = "5012.790800,N,00806.879600,W"
    s = sigma / math.sqrt(2)               # per axis: sqrt(lat^2 + lon^2) = sigma
    fix = [_sentence(f"GPGGA,{t},{pos},1,08,0.9,10.0,M,,,,"),
           _sentence(f"GPRMC,{t},A,{pos},0.0,0.0,041226,,,A")]
    g = [_sentence(f"GPGST,{t},1.0,{s:.3f},{s:.3f},0.0,{s:.3f},{s:.3f},1.0")] if gst else []
    return g + fix if gst_first else fix + g


def _records(sigmas, gst_first):
    parser = NmeaStreamParser()
    lines = [ln for k, sg in enumerate(sigmas)
             for ln in _epoch(k, sg, gst=k % 2 == 0, gst_first=gst_first)]
    return [(10**18 + i * 10**8, r) for i, line in enumerate(lines)
            for r in parser.feed(line.encode())]


@pytest.mark.parametrize("gst_first", [False, True], ids=["gst after", "gst first"])
def test_each_lost_gst_is_counted_once(gst_first):
    counts: dict = {}
    fixes, _ = samples_from_nmea(_records([3.0] * N, gst_first), 0.3, math.inf, counts)
    assert len(fixes) == N
    assert counts["gps_gst_missing"] == N // 2 and counts["gps_rejected"] == 0
    # the epochs with their own GST carry it; the others the receiver's latest
    assert all(f.sigma_m == pytest.approx(3.0, abs=0.01) for f in fixes)


@pytest.mark.parametrize("gst_first", [False, True], ids=["gst after", "gst first"])
def test_a_gate_below_the_receivers_sigma_rejects_every_epoch_once(gst_first):
    counts: dict = {}
    fixes, _ = samples_from_nmea(_records([5.0] * N, gst_first), 0.3, 4.2, counts)
    assert fixes == []                     # none with an unknown sigma at the start
    assert counts["gps_rejected"] == counts["gps_rejected_sigma"] == N
    assert counts["gps_gst_missing"] == N // 2


def test_no_fix_is_given_out_and_then_withdrawn():
    """Fed record by record (as the daemon feeds it), sigmas alternating about the gate:
    a fix is decided once, with its own GST when it has one."""
    sigmas = [3.0 if (k // 2) % 2 == 0 else 5.0 for k in range(N)]
    s = NmeaSampler(0.3, 4.2, 1.5, {})
    given, withdrawn = [], []
    for rec in _records(sigmas, gst_first=False):
        f, _, gone = s.feed([rec])
        given += f
        withdrawn += gone
    f, _, gone = s.flush()
    given += f
    withdrawn += gone
    assert withdrawn == []
    own = {k for k in range(0, N, 2)}
    for fx in given:
        k = int(round((fx.time_ns // 10**9) % 60))
        if k in own:
            assert fx.sigma_m < 4.2


def test_every_fix_rejected_by_sigma_says_the_receivers_sigma():
    """Every fix rejected for its GST sigma (4.19 m against a 2 m gate): the navigation
    state and the alarm give the receiver's 4.19 m, not "unknown" (no fix was
    accepted to take a sigma from)."""
    import dataclasses

    from svss_daq import navigation as nav
    from svss_daq.alarms import AlarmLimits, check_navigation
    from svss_daq.config import DevicesConfig, LeverArms, config_path, load
    cfg = dataclasses.replace(load(DevicesConfig, config_path("devices.toml")).navigation,
                              gps_max_sigma_m=2.0, origin_latitude_deg=50.2,
                              origin_longitude_deg=-8.1, origin_height_m=0.0)
    n = nav.Navigator(cfg, LeverArms(array_m=(0, 0, 0), gps_antenna_m=(0, 0, 0),
                                     dvl_m=(0, 0, 0)))
    recs = _records([4.19] * N, gst_first=False)
    n.add_nmea(recs)
    q = n.quality(recs[-1][1].time_ns)
    assert q["gps_gate"] == "sigma" and q["gps_sigma_m"] == pytest.approx(4.19, abs=0.01)
    assert q["gps_fixes"] == 0 and q["gps_rejected_sigma"] >= N - 1
    lim = AlarmLimits(ping_interval_s=0.1, no_ping_intervals=5, min_rate_fraction=0.8,
                      rate_window_s=10, disk_min_free_mib=0, disk_min_time_left_s=0,
                      gps_fix_max_age_s=2.0, gps_max_sigma_m=2.0, dead_reckoning_max_s=60,
                      device_silent_s=3.0, worker_max_backlog_s=20, recent_s=10)
    alarms = {a.name: a for a in check_navigation(
        {"state": "recording", "navigation": {"solution": q},
         "devices": {"gps": {"connected": True}}}, lim)}
    assert "GPS sigma 4.19 m above" in alarms["navigation.sigma_high"].message


def test_no_origin_and_every_fix_rejected_still_gives_the_compass_attitude():
    """No survey origin configured and every fix rejected (no fix to take one from),
    the DVL's compass streaming: live poses have no position, but the attitude and
    heading the instruments give, flagged as the compass's (not NaN and no flag)."""
    import dataclasses

    from svss_daq import navigation as nav
    from svss_daq.config import DevicesConfig, LeverArms, config_path, load
    from svss_daq.nav.records import DvlSample
    from svss_daq.ping import NAV_DEAD_RECKONED, NAV_GPS_FIX, NAV_HEADING_FROM_COMPASS
    cfg = dataclasses.replace(load(DevicesConfig, config_path("devices.toml")).navigation,
                              gps_max_sigma_m=2.0, origin_latitude_deg=None,
                              origin_longitude_deg=None)
    n = nav.Navigator(cfg, LeverArms(array_m=(0, 0, 0), gps_antenna_m=(0, 0, 0),
                                     dvl_m=(0, 0, 0)))
    recs = _records([4.19] * N, gst_first=False)
    n.add_nmea(recs)
    t_end = recs[-1][1].time_ns
    n.dvl = [DvlSample(t_end - 10**9 + k * 250_000_000, (0.5, 0.0, 0.0), (5.0,) * 4,
                       heading_rad=math.radians(40.0), roll_rad=0.02, pitch_rad=-0.01)
             for k in range(8)]
    (p,) = n.poses([t_end])
    assert math.isnan(p.north_m) and math.isnan(p.latitude_deg)
    assert not p.quality & (NAV_GPS_FIX | NAV_DEAD_RECKONED)
    assert p.quality & NAV_HEADING_FROM_COMPASS
    assert math.degrees(p.heading_rad) == pytest.approx(40.0, abs=0.5)
    assert p.roll_rad == pytest.approx(0.02) and p.pitch_rad == pytest.approx(-0.01)
