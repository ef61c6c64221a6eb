"""``stamps``: header stamps as integer nanoseconds, and the malformed ones refused."""

from types import SimpleNamespace

import pytest
from builtin_interfaces.msg import Time
from rclpy.time import Time as RclpyTime

from uav_landing_vision.stamps import header_stamp_ns, stamp_fields, stamp_ns


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
