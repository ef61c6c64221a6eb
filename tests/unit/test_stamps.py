"""``stamps``: header stamps as integer nanoseconds, and the malformed ones refused."""

from types import SimpleNamespace

import pytest
from builtin_interfaces.msg import Time
from rclpy.time import Time as RclpyTime

from uav_landing_vision.stamps import header_stamp_ns, stamp_fields, stamp_ns, within_age


@pytest.mark.parametrize("ns", [0, 1, 999_999_999, 1_000_000_000, 1_700_000_000_123_456_789])
def test_stamps_round_trip_as_rclpy_reads_them(ns):
    sec, nanosec = stamp_fields(ns)
    assert 0 <= nanosec < 1_000_000_000
    assert stamp_ns(Time(sec=sec, nanosec=nanosec)) == ns == RclpyTime.from_msg(Time(sec=sec, nanosec=nanosec)).nanoseconds


def test_a_stamp_with_nanosec_from_one_second_on_is_malformed():
    with pytest.raises(ValueError, match=r"header stamp 3 s \+ 1000000000 ns is malformed"):
        stamp_ns(SimpleNamespace(sec=3, nanosec=1_000_000_000))
    with pytest.raises(ValueError, match="malformed"):
        header_stamp_ns(SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=0, nanosec=-1))))


def test_a_message_without_a_header_has_no_stamp():
    assert header_stamp_ns(SimpleNamespace(data=b"")) is None
    assert header_stamp_ns(SimpleNamespace(header=SimpleNamespace(stamp=Time(sec=2, nanosec=5)))) == 2_000_000_005


@pytest.mark.parametrize("limit_s", [0.1, 0.3, 0.5, 0.7, 2.5])
def test_an_age_is_within_a_limit_up_to_the_nanosecond(limit_s):
    limit_ns = round(limit_s * 1e9)
    assert within_age(0, limit_s) and within_age(limit_ns, limit_s)
    assert not within_age(limit_ns + 1, limit_s) and not within_age(-1, limit_s)


@pytest.mark.parametrize("limit_s, limit_ns", [(1.001, 1_001_000_000), (2.01, 2_010_000_000), (4.27, 4_270_000_000)])
def test_a_limit_whose_float_product_falls_short_of_its_nanoseconds_still_reaches_them(limit_s, limit_ns):
    """1.001 * 1e9 is 1000999999.9999999 in floats: the limit is the nearest nanosecond, not the one below."""
    assert within_age(limit_ns, limit_s) and not within_age(limit_ns + 1, limit_s)
