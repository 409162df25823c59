"""Digitiser scaling between pressure and ADC codes, against numbers worked out by hand
from the hardware configuration (config/hardware.toml, [digitiser]):

    sensitivity -195 dB re 1 V/uPa, gain 0 dB  ->  10^(-195/20) = 1.7782794e-10 V/uPa
    1 Pa = 1e6 uPa                               ->  1.7782794e-4 V at the ADC
    24 bits: largest code 2^23 - 1 = 8 388 607 at full scale 2.5 V
                                                 ->  3 355 442.8 counts/V
    1 Pa                                         ->  1.7782794e-4 * 3 355 442.8
                                                     = 596.691484 counts
(to 1e-8, so that 2^23 codes instead of 2^23 - 1, 1.2e-7 off, fails)
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from svss_daq.scaling import counts_per_upa, full_scale_counts, quantise

COUNTS_PER_PA = 596.691484    # worked out above


@pytest.fixture
def dig(hardware):
    d = hardware.value.digitiser
    # the numbers the hand calculation above started from
    assert (d.bits, d.full_scale_v, d.sensitivity_db_re_v_per_upa, d.gain_db) == (
        24, 2.5, -195.0, 0.0)
    return d


def test_counts_per_upa_worked_out_by_hand(dig):
    assert full_scale_counts(dig) == 8_388_607
    assert counts_per_upa(dig) * 1e6 == pytest.approx(COUNTS_PER_PA, rel=1e-8)


def test_gain_and_bits_scale_as_the_hardware_does(dig):
    # +20 dB of analogue gain is ten times the voltage at the ADC; 6 dB less sensitive
    # hydrophone about half; a 16-bit ADC has 32 767 codes over the same 2.5 V
    assert counts_per_upa(dataclasses.replace(dig, gain_db=20.0)) * 1e6 == pytest.approx(
        10 * COUNTS_PER_PA, rel=1e-6)
    assert counts_per_upa(dataclasses.replace(dig, sensitivity_db_re_v_per_upa=-201.0)) \
        * 1e6 == pytest.approx(COUNTS_PER_PA * 10 ** (-6 / 20), rel=1e-6)
    d16 = dataclasses.replace(dig, bits=16)
    assert full_scale_counts(d16) == 32_767
    assert counts_per_upa(d16) * 1e6 == pytest.approx(
        1.7782794e-4 * 32_767 / 2.5, rel=1e-6)
    assert counts_per_upa(dataclasses.replace(dig, full_scale_v=5.0)) * 1e6 == pytest.approx(
        COUNTS_PER_PA / 2, rel=1e-6)


def test_quantise_rounds_and_clips_at_full_scale(dig):
    pa = 1e6                                            # 1 Pa in uPa
    fs_upa = 2.5 / 1.7782794e-10                        # the pressure at 2.5 V, uPa
    p = np.array([0.0, pa, -pa, 10 * pa, 0.25 * fs_upa, 2 * fs_upa, -2 * fs_upa])
    codes, clipped = quantise(p, dig)
    assert codes.dtype == np.int32
    np.testing.assert_array_equal(
        codes, [0, 597, -597, 5967, 2_097_152, 8_388_607, -8_388_608])
    assert clipped == 2
