"""MAVLink 2 signing timestamps against pymavlink's receiving rules: a stream a receiver meets anew
is refused more than a minute behind the receiver's own timestamp, a known stream below its last.

The station's clock is a stand-in function; each receiver's own timestamp is set as its clock
would have set it at that moment.
"""

import dataclasses
import os
import socket
import threading
import time
import types
from datetime import datetime, timezone

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav2
from test_gcs_landing import CONFIG
from test_gcs_link import free_port

from uav_landing_vision.gcs.mavlink import MavlinkSender, open_link
from uav_landing_vision.gcs import signing
from uav_landing_vision.gcs.signing import (
    LAST_TIMESTAMP, RENEW_S, RESERVE_S, RETRY_S, UNITS_PER_S, SigningTimestamps, clock_timestamp,
)

KEY = bytes(range(32))
RESERVE = int(RESERVE_S * UNITS_PER_S)  # in stamp units
UNIX_2015 = datetime(2015, 1, 1, tzinfo=timezone.utc).timestamp()


class Clock:
    def __init__(self):
        self.now = time.time()

    def __call__(self):
        return self.now


@pytest.fixture
def monotonic(monkeypatch):
    """``signing``'s monotonic time, a ``Clock`` that stands still until the test moves it."""
    clock = Clock()
    monkeypatch.setattr(signing, "time", types.SimpleNamespace(monotonic=clock))
    return clock


@pytest.fixture
def key_file(tmp_path):
    path = tmp_path / "signing.key"
    path.write_text(KEY.hex() + "\n")
    return path


@pytest.fixture
def gcs():
    """A signing GCS on loopback whose own timestamp is that of its clock at ``now``."""
    conns = []

    def start(now, port=0):
        conn = open_link(f"udpin:127.0.0.1:{port}", 255, 190, KEY)
        conn.mav.signing.timestamp = clock_timestamp(now)
        conns.append(conn)
        return conn

    yield start
    for c in conns:
        c.close()


def station(conn, key_file, clock, timestamp_file=""):
    mav = dataclasses.replace(
        CONFIG.mavlink, connection=f"udpout:127.0.0.1:{conn.port.getsockname()[1]}",
        signing_key_file=str(key_file), signing_timestamp_file=str(timestamp_file),
    )
    return MavlinkSender(mav, clock=clock)


def heartbeats_taken(conn, sender, count=3, timeout=3.0):
    """Heartbeats the GCS accepted of ``count`` sent; the refused ones come out as BAD_DATA."""
    for _ in range(count):
        sender.send_heartbeat()
    taken = seen = 0
    deadline = time.monotonic() + timeout
    while seen < count and time.monotonic() < deadline:
        m = conn.recv_match(blocking=True, timeout=0.1)
        if m is not None and m.get_type() in ("HEARTBEAT", "BAD_DATA"):
            seen += 1
            taken += m.get_type() == "HEARTBEAT"
    assert seen == count, "the GCS did not receive every frame"
    return taken


def test_a_gcs_restarted_after_the_station_ran_an_hour_accepts_it(gcs, key_file):
    clock = Clock()
    first = gcs(clock.now)
    sender = station(first, key_file, clock)
    assert heartbeats_taken(first, sender) == 3
    clock.now += 3600.0
    port = first.port.getsockname()[1]
    first.close()
    restarted = gcs(clock.now, port)  # the station's stream is new to it
    assert heartbeats_taken(restarted, sender) == 3
    sender.close()


def test_a_station_restarted_after_its_clock_stepped_back_is_accepted(gcs, key_file, tmp_path):
    clock = Clock()
    conn = gcs(clock.now)
    state = tmp_path / "state" / "signing.timestamp"
    state.parent.mkdir()
    sender = station(conn, key_file, clock, state)
    assert heartbeats_taken(conn, sender) == 3
    sender.close()
    clock.now -= 3600.0
    sender = station(conn, key_file, clock, state)
    assert heartbeats_taken(conn, sender) == 3
    sender.close()


def test_without_the_stored_timestamp_that_restart_is_refused(gcs, key_file, tmp_path):
    """What the stored timestamp prevents (the receiving rule the test above relies on)."""
    clock = Clock()
    conn = gcs(clock.now)
    sender = station(conn, key_file, clock, tmp_path / "a")
    assert heartbeats_taken(conn, sender) == 3
    sender.close()
    clock.now -= 3600.0
    sender = station(conn, key_file, clock, tmp_path / "b")
    assert heartbeats_taken(conn, sender) == 0
    sender.close()


def test_the_default_state_file_is_beside_the_key(gcs, key_file):
    conn = gcs(time.time())
    sender = station(conn, key_file, Clock())
    sender.close()
    stored = int((key_file.parent / "signing.key.timestamp").read_text())
    assert stored == sender._stamps.start + RESERVE


def test_signing_timestamps_count_10_microsecond_units_from_2015_utc(monkeypatch):
    """As ``datetime`` counts them, and as pymavlink's own ``setup_signing`` stamps at the same time."""
    assert clock_timestamp(UNIX_2015) == 0 and clock_timestamp(UNIX_2015 + 1.0) == 100_000
    t = datetime(2025, 3, 4, 5, 6, 7, 890000, tzinfo=timezone.utc).timestamp()
    assert clock_timestamp(t) == round((t - UNIX_2015) * 100_000)
    monkeypatch.setattr(mavutil, "time", types.SimpleNamespace(time=lambda: t))
    gcs = types.SimpleNamespace(mav=mav2.MAVLink(None))
    mavutil.mavfile.setup_signing(gcs, KEY, link_id=0)
    assert clock_timestamp(t) == gcs.mav.signing.timestamp


def test_stamps_follow_the_clock_and_never_go_back(tmp_path):
    clock = Clock()
    stamps = SigningTimestamps(tmp_path / "t", clock)
    t0 = clock_timestamp(clock.now)
    assert stamps.start == t0 and stamps.advance(t0 + 5) == t0 + 5  # frames ahead of the clock keep their rise
    clock.now += 10.0
    assert stamps.advance(t0 + 5) == t0 + 10 * UNITS_PER_S
    clock.now -= 3600.0
    assert stamps.advance(t0 + 10 * UNITS_PER_S + 3) == t0 + 10 * UNITS_PER_S + 3


def test_the_reservation_is_renewed_ahead_by_a_thread_of_its_own(tmp_path, monkeypatch):
    """Written, flushed, renamed and the rename flushed (the folder's fsync), by the writer thread
    once the stamps are RENEW_S from the stored reservation: a disk slow to flush (seconds, with
    a bag being recorded on it) must not hold up the bridge's tick."""
    flushed = []

    def fsync(fd):
        flushed.append((os.readlink(f"/proc/self/fd/{fd}"), threading.current_thread() is threading.main_thread()))
        real_fsync(fd)

    real_fsync = os.fsync
    monkeypatch.setattr(signing.os, "fsync", fsync)
    path = tmp_path / "t"
    clock = Clock()
    stamps = SigningTimestamps(path, clock)
    first = int(path.read_text())
    assert first == stamps.start + RESERVE
    assert [name for name, _ in flushed] == [str(path) + ".tmp", str(tmp_path)]  # the file, then its rename
    flushed.clear()
    clock.now += RESERVE_S - RENEW_S - 1.0
    stamps.advance(0)
    assert stamps._pending is None and not flushed  # still far ahead: not written again
    clock.now += 2.0
    now = stamps.advance(0)
    stamps.close()
    assert int(path.read_text()) == now + RESERVE
    assert flushed and not any(main for _, main in flushed)  # by the writer, not in the tick
    assert SigningTimestamps(path, lambda: clock.now - 7200.0).start == now + RESERVE  # a restart starts above it
    assert SigningTimestamps(path, lambda: clock.now + 7200.0).start == clock_timestamp(clock.now + 7200.0)


def count_writes(stamps):
    """The values ``stamps`` tries to write from now on, in order."""
    calls, real = [], stamps._write

    def write(value):
        calls.append(value)
        return real(value)

    stamps._write = write
    return calls


def test_a_reservation_written_in_the_tick_runs_a_full_reserve_ahead_and_then_lasts(tmp_path):
    """Stamps that reach the stored reservation (the clock jumped ahead past it) make the tick write
    the next one RESERVE_S ahead of them, so the frames after it need no write for a while."""
    path = tmp_path / "t"
    clock = Clock()
    stamps = SigningTimestamps(path, clock)
    clock.now += RESERVE_S + 5.0
    stamp = stamps.advance(0)
    assert int(path.read_text()) == stamp + RESERVE
    writes = count_writes(stamps)
    for k in range(1, 2000):  # frames signed at the rising stamps, the clock standing still
        assert stamps.advance(stamp + k) == stamp + k
    assert writes == []
    stamps.close()


def test_no_frame_is_signed_at_the_stored_reservation_before_a_new_one_is_on_disk(tmp_path, monkeypatch):
    """A writer that has not finished by then (a disk stalled for RENEW_S) is waited for."""
    release = threading.Event()
    real_fsync = os.fsync

    def stalled_fsync(fd):
        if threading.current_thread() is not threading.main_thread():
            release.wait(10.0)
        real_fsync(fd)

    monkeypatch.setattr(signing.os, "fsync", stalled_fsync)
    path = tmp_path / "t"
    clock = Clock()
    stamps = SigningTimestamps(path, clock)
    stored = int(path.read_text())
    clock.now += RESERVE_S - RENEW_S + 1.0
    stamps.advance(0)  # the writer starts, and stalls
    clock.now += RENEW_S  # now past the stored reservation
    threading.Timer(0.2, release.set).start()
    stamp = stamps.advance(0)
    assert release.is_set() and stamp > stored and int(path.read_text()) > stamp
    stamps.close()


def test_a_clock_before_2015_starts_from_the_stored_timestamp(tmp_path):
    path = tmp_path / "t"
    path.write_text("123456789\n")
    assert SigningTimestamps(path, lambda: 0.0).start == 123456789
    assert clock_timestamp(0.0) == 0


@pytest.mark.parametrize("text", ["", "12ab", "-5", str(1 << 48)])
def test_a_bad_state_file_is_named(tmp_path, text):
    path = tmp_path / "t"
    path.write_text(text)
    with pytest.raises(ValueError, match="not a 48-bit timestamp; remove it"):
        SigningTimestamps(path)


@pytest.mark.parametrize("where, why", [("file/t", "cannot read it"), ("missing/t", "cannot write it")])
def test_a_state_file_out_of_reach_stops_the_start(tmp_path, where, why):
    (tmp_path / "file").write_text("")
    with pytest.raises(OSError, match=f"signing timestamp file .*/{where}: {why}"):
        SigningTimestamps(tmp_path / where)


def test_a_failed_store_later_is_reported_and_tried_again_at_most_once_every_retry_period(tmp_path, monotonic):
    """Signing goes on meanwhile, its stamps rising frame by frame."""
    path = tmp_path / "state" / "t"
    path.parent.mkdir()
    clock = Clock()
    stamps = SigningTimestamps(path, clock)
    path.unlink()
    path.parent.rmdir()  # the directory is gone: the next write fails
    writes = count_writes(stamps)
    clock.now += RESERVE_S + 1.0  # past the reservation: the tick must write
    current = stamps.advance(0)
    assert len(writes) == 1 and "cannot write it" in stamps.store_error
    for _ in range(50):  # frames within RETRY_S of the failure: no new try
        current = stamps.advance(current + 1)
        monotonic.now += RETRY_S / 100
    assert len(writes) == 1 and current == clock_timestamp(clock.now) + 50
    monotonic.now += RETRY_S
    stamps.advance(current + 1)
    assert len(writes) == 2
    path.parent.mkdir()
    monotonic.now += RETRY_S + 0.01
    stamps.advance(current + 2)
    assert len(writes) == 3 and stamps.store_error == "" and int(path.read_text()) >= current + 2 + RESERVE
    stamps.close()


def gcs_heartbeat_heard(conn, sender, timeout=3.0):
    """The GCS sends its own signed heartbeat to the station; True once the station has parsed it."""
    before = sender.mav.signing.timestamp
    conn.mav.heartbeat_send(6, 8, 0, 0, 4)  # a GCS's heartbeat, to the address the station sends from
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        sender.poll()
        if sender.mav.signing.timestamp != before:
            return True
        time.sleep(0.01)
    return False


def test_a_station_whose_clock_is_behind_the_gcs_is_accepted_once_it_hears_the_gcs(gcs, key_file):
    clock = Clock()
    conn = gcs(clock.now + 600.0)  # the GCS's clock is 10 minutes ahead
    sender = station(conn, key_file, clock)
    assert heartbeats_taken(conn, sender) == 0  # a new stream 10 minutes behind the GCS: refused
    assert gcs_heartbeat_heard(conn, sender)
    assert clock_timestamp(clock.now + 600.0) <= sender.mav.signing.timestamp < clock_timestamp(clock.now + 601.0)
    assert heartbeats_taken(conn, sender) == 3
    sender.close()


def test_a_forged_frame_neither_blocks_the_gcs_stamps_nor_piles_up(key_file):
    """pymavlink records a stream's stamp before it checks the signature. With the sender's own
    signing state, a forged frame stamped far ahead on the GCS's stream made the GCS's real frames
    look old, and each forged (link, system, component) stayed in its table for good. A udpin
    station hears anyone who sends to its port."""
    clock = Clock()
    port = free_port(socket.SOCK_DGRAM)
    mav = dataclasses.replace(CONFIG.mavlink, connection=f"udpin:127.0.0.1:{port}", signing_key_file=str(key_file))
    sender = MavlinkSender(mav, clock=clock)
    gcs = open_link(f"udpout:127.0.0.1:{port}", 255, 190, KEY)
    gcs.mav.signing.timestamp = clock_timestamp(clock.now + 600.0)
    forger = open_link(f"udpout:127.0.0.1:{port}", 255, 190, bytes(32))  # the GCS's ids, another key
    forger.mav.signing.timestamp = clock_timestamp(clock.now + 86400.0)
    for system in (255, *range(1, 50)):
        forger.mav.srcSystem = system
        forger.mav.heartbeat_send(6, 8, 0, 0, 4)
    deadline = time.monotonic() + 3.0
    while sender._inbound.signing.badsig_count < 50 and time.monotonic() < deadline:
        sender.poll()
        time.sleep(0.01)
    assert sender._inbound.signing.badsig_count == 50
    assert sender.mav.signing.timestamp < clock_timestamp(clock.now + 1.0)  # no forged stamp taken
    assert gcs_heartbeat_heard(gcs, sender)  # the GCS's real frame still raises it
    assert clock_timestamp(clock.now + 600.0) <= sender.mav.signing.timestamp < clock_timestamp(clock.now + 601.0)
    assert len(sender._inbound.signing.stream_timestamps) <= 1
    for link in (gcs, forger, sender):
        link.close()


def test_a_gcs_stamp_beyond_what_48_bits_can_reserve_is_not_taken(gcs, key_file):
    clock = Clock()
    conn = gcs(clock.now)
    sender = station(conn, key_file, clock)
    heartbeats_taken(conn, sender)
    conn.mav.signing.timestamp = LAST_TIMESTAMP + 1
    assert not gcs_heartbeat_heard(conn, sender, timeout=0.5)
    conn.mav.signing.timestamp = LAST_TIMESTAMP - 5
    assert gcs_heartbeat_heard(conn, sender)
    sender.close()


def test_a_frame_signed_with_another_key_moves_nothing(gcs, key_file):
    clock = Clock()
    conn = gcs(clock.now + 600.0)
    conn.mav.signing.secret_key = bytes(32)  # someone without the station's key
    sender = station(conn, key_file, clock)
    assert heartbeats_taken(conn, sender) == 0
    assert not gcs_heartbeat_heard(conn, sender, timeout=0.5)
    assert sender.mav.signing.timestamp < clock_timestamp(clock.now + 1.0)
    sender.close()


def test_a_gcs_stamp_at_the_last_reservable_timestamp_is_taken(gcs, key_file):
    clock = Clock()
    conn = gcs(clock.now)
    sender = station(conn, key_file, clock)
    heartbeats_taken(conn, sender)
    conn.mav.signing.timestamp = LAST_TIMESTAMP
    assert gcs_heartbeat_heard(conn, sender)
    assert sender.mav.signing.timestamp == LAST_TIMESTAMP
    sender.close()


def test_a_gcs_whose_clock_is_behind_does_not_set_the_station_back(gcs, key_file):
    """The station's stamps never go back: after hearing a GCS 10 minutes behind, the GCS still
    takes its frames (a lower stamp on the station's stream would be refused as a replay)."""
    clock = Clock()
    conn = gcs(clock.now - 600.0)
    sender = station(conn, key_file, clock)
    assert heartbeats_taken(conn, sender) == 3
    before = sender.mav.signing.timestamp
    conn.mav.heartbeat_send(6, 8, 0, 0, 4)
    deadline = time.monotonic() + 3.0
    while sender._inbound.signing.goodsig_count == 0 and time.monotonic() < deadline:
        sender.poll()
        time.sleep(0.01)
    assert sender._inbound.signing.goodsig_count == 1  # the GCS's frame was heard
    assert sender.mav.signing.timestamp >= before
    assert heartbeats_taken(conn, sender) == 3
    sender.close()
