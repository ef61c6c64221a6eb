"""The MAVLink link failing during a landing, on real sockets and pseudo-terminals.

The bridge must never raise, block or print from a tick because of its link, must keep its
stage machine, count what it could not send, and, once the link is back, send again, starting
with a heartbeat and the current stage (the STATUSTEXT of a stage change made during the
outage never reached the GCS).
"""

import dataclasses
import errno
import os
import select
import socket
import struct
import termios
import threading
import time
import tty
import types
from unittest import mock

import pytest
from pymavlink.dialects.v20 import common as mav2
from test_gcs_landing import CONFIG, feed, on_axis

from uav_landing_vision.gcs import GcsBridge, Stage
from uav_landing_vision.gcs import link as link_module
from uav_landing_vision.gcs.mavlink import MavlinkSender, open_link

TICK_S = 0.1  # mavlink.rate_hz 10


def make_bridge(connection):
    return GcsBridge(dataclasses.replace(CONFIG, mavlink=dataclasses.replace(CONFIG.mavlink, connection=connection)))


def make_sender(connection):
    return MavlinkSender(dataclasses.replace(CONFIG.mavlink, connection=connection))


class WaitWatch:
    """Whether a call could have waited on its link, told from the link's state, not a clock: every
    handle it holds must be non-blocking (so no send, read or connect waits) and its one poll for
    writability must not wait (the TCP link's constructor alone may, ``START_WAIT_S``)."""

    def __init__(self, link):
        self.link, self.waits, self.blocking_handles = link, [], 0

    def __call__(self, fn):
        real = link_module._writable

        def writable(handle, wait_s):
            self.waits.append(wait_s)
            return real(handle, wait_s)

        with mock.patch.object(link_module, "_writable", writable):
            value = fn()
        handle = getattr(self.link, "_handle", None) or getattr(self.link, "_sock", None)
        self.blocking_handles += handle is not None and os.get_blocking(handle.fileno())
        return value

    def assert_never_waited(self):
        assert self.blocking_handles == 0, "a call left a blocking handle on the link"
        assert not any(self.waits), f"a call polled its link with a wait: {max(self.waits)} s"


def finishes_within(seconds, fn):
    """``fn()``, failing the test (not hanging it) if it has not returned within ``seconds``."""
    out, done = {}, threading.Event()

    def target():
        try:
            out["value"] = fn()
        except BaseException as exc:  # noqa: BLE001 (re-raised in the test's thread)
            out["error"] = exc
        finally:
            done.set()

    threading.Thread(target=target, daemon=True).start()
    assert done.wait(seconds), f"still blocked after {seconds} s"
    if "error" in out:
        raise out["error"]
    return out.get("value")


def parse(data: bytes) -> list:
    parser = mav2.MAVLink(None)
    parser.robust_parsing = True
    return parser.parse_buffer(data) or []


def assert_announced_once(messages):
    """The GCS heard of the stage (LAND, entered while it was cut off) exactly once."""
    texts = [m.text for m in messages if m.get_type() == "STATUSTEXT"]
    assert len(texts) == 1 and texts[0].startswith("VISION LAND r=25.0m"), texts


class Flight:
    """A landing held 25 m out on the approach axis, in wall-clock time: a tracked pose before
    every tick, at 10 Hz; ``pump`` runs the GCS's side between ticks."""

    def __init__(self, bridge, pump=lambda: None):
        self.bridge, self.pump = bridge, pump
        self.t0 = time.monotonic()
        self.watch = WaitWatch(bridge._sender.link)
        self.stages = []

    def run(self, seconds, until=lambda: False):
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not until():
            t = 1000.0 + time.monotonic() - self.t0
            feed(self.bridge, t - 0.02, on_axis(25.0))
            self.stages.append(self.watch(lambda: self.bridge.tick(t)).guidance.stage)
            self.pump()
            time.sleep(TICK_S)

    def assert_landing_went_on(self):
        assert self.stages[0] is Stage.APPROACH and set(self.stages[1:]) == {Stage.LAND}
        self.watch.assert_never_waited()


def free_port(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def monotonic(monkeypatch):
    """The links' monotonic clock, a fake that stands still until the test moves ``monotonic.now``."""
    clock = types.SimpleNamespace(now=1000.0)
    monkeypatch.setattr(link_module, "time", types.SimpleNamespace(monotonic=lambda: clock.now))
    return clock


class TcpGcs:
    """A GCS listening on TCP that reads everything it gets; it can go away and come back."""

    def __init__(self, port=0, backlog=1):
        self.listener = socket.socket()
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", port))
        self.listener.listen(backlog)
        self.listener.setblocking(False)
        self.port = self.listener.getsockname()[1]
        self.conn, self.data, self.reading, self.gone = None, b"", True, False

    def pump(self):
        if self.gone:
            return
        if self.conn is None:
            try:
                self.conn, _ = self.listener.accept()
                self.conn.setblocking(False)
            except BlockingIOError:
                return
        while self.reading:
            try:
                chunk = self.conn.recv(1 << 16)
            except BlockingIOError:
                return
            if not chunk:
                return
            self.data += chunk

    def pump_until_quiet(self, quiet_s=0.3):
        while True:
            size = len(self.data)
            time.sleep(quiet_s)
            self.pump()
            if len(self.data) == size:
                return

    def messages(self):
        return parse(self.data)

    def go_away(self, reset=False):
        if self.conn is not None:
            if reset:  # RST instead of FIN
                self.conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            self.conn.close()
        self.listener.close()
        self.gone = True


class UdpGcs:
    """A GCS sending datagrams to the bridge's udpin port and collecting what comes back."""

    def __init__(self, port):
        self.link = open_link(f"udpout:127.0.0.1:{port}", 255, 190)
        self.got = []

    def heartbeat(self):
        self.link.mav.heartbeat_send(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, mav2.MAV_STATE_ACTIVE)

    def pump(self):
        while (m := self.link.recv_match(blocking=False)) is not None:
            self.got.append(m)

    def types(self) -> set:
        return {m.get_type() for m in self.got}

    def close(self):
        self.link.close()


def heard_then_closed(flight, bridge, gcs):
    """The GCS heartbeats; the landing goes on until it has the heartbeat, the stage (once) and a pose."""
    gcs.heartbeat()
    flight.run(3.0, until=lambda: {"HEARTBEAT", "STATUSTEXT", "ODOMETRY"} <= gcs.types())
    bridge.close()
    gcs.close()
    flight.assert_landing_went_on()
    assert_announced_once(gcs.got)


def udpin_bridge_and_gcs():
    port = free_port(socket.SOCK_DGRAM)
    return make_bridge(f"udpin:127.0.0.1:{port}"), UdpGcs(port)


def test_udpin_answers_the_gcs_once_it_has_sent_a_packet():
    """``udpin`` can only answer addresses it heard from: the bridge must read its socket. It
    never did, so it never sent anything, whatever the GCS sent it."""
    bridge, gcs = udpin_bridge_and_gcs()
    flight = Flight(bridge, gcs.pump)
    flight.run(0.5)
    assert not gcs.got
    heard_then_closed(flight, bridge, gcs)  # the stage, announced once the GCS is heard
    stats = bridge.link_stats
    assert stats.dropped > 0 and "no GCS" in stats.last_error and stats.restored == 1 and stats.up


def test_udpin_stops_answering_a_gcs_that_has_gone_silent(monkeypatch):
    """It answered every address it ever heard from, for ever: a GCS gone, or restarted on another
    port, went on receiving guidance, and the link reported itself up. A GCS heartbeats every second."""
    monkeypatch.setattr(link_module, "PEER_SILENCE_S", 0.5)
    bridge, gcs = udpin_bridge_and_gcs()
    flight = Flight(bridge, gcs.pump)
    gcs.heartbeat()
    flight.run(3.0, until=lambda: "ODOMETRY" in gcs.types())
    assert bridge.link_stats.up
    flight.run(1.0)  # silent for twice PEER_SILENCE_S
    assert not bridge.link_stats.up and "no GCS heard within 0.5 s" in bridge.link_stats.last_error
    gcs.got.clear()
    flight.run(0.5)
    assert not gcs.got
    heard_then_closed(flight, bridge, gcs)  # heard again: the heartbeat and the stage first
    assert bridge.link_stats.restored == 1


def test_udpout_tells_whether_anybody_listens_and_sends_all_the_same():
    """``udpout`` could not tell whether anyone listened: its link said up with the GCS's port
    closed. From a socket connected to the GCS, the kernel's "port unreachable" says so (the link
    is down, with why); frames still go out, so a GCS that comes up gets them at once, starting
    with the heartbeat and the stage."""
    port = free_port(socket.SOCK_DGRAM)
    bridge = make_bridge(f"udpout:127.0.0.1:{port}")
    flight = Flight(bridge)
    flight.run(0.5)
    stats = bridge.link_stats
    assert not stats.up and stats.last_error == f"nobody listens at 127.0.0.1:{port} (port unreachable)"
    assert stats.written > 0 and stats.dropped == 0  # nothing held back
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", port))
    gcs.setblocking(False)
    got = []

    def pump():
        while True:
            try:
                got.append(gcs.recv(65536))
            except BlockingIOError:
                return

    flight.pump = pump
    flight.run(link_module.REFUSAL_QUIET_S + 0.5)  # frames out without a refusal for that long: somebody listens
    # Up again: the heartbeat and the stage first, as after an outage (the stage changed unheard).
    heard = [m for data in got for m in parse(data)]
    assert bridge.link_stats.up and {m.get_type() for m in heard} >= {"HEARTBEAT", "ODOMETRY"}
    assert_announced_once(heard)
    flight.pump = lambda: None
    gcs.close()
    flight.run(0.5)
    assert not bridge.link_stats.up and "nobody listens" in bridge.link_stats.last_error
    bridge.close()
    assert bridge.link_stats.dropped == 0
    flight.assert_landing_went_on()


def test_udpout_sends_the_frame_that_meets_an_earlier_frames_port_unreachable():
    """The first frame finds nobody (loopback answers "port unreachable" at once); the GCS then
    starts on that port. The next frame's send raises the pending refusal, and it must still go out."""
    port = free_port(socket.SOCK_DGRAM)
    link = link_module.open_transport(f"udpout:127.0.0.1:{port}")
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        link.write(b"first")
        poller = select.poll()
        poller.register(link._sock.fileno(), select.POLLERR)
        assert poller.poll(2000), "no port unreachable came back"
        gcs.bind(("127.0.0.1", port))
        gcs.settimeout(2.0)
        link.write(b"second")
        assert gcs.recv(64) == b"second"
        assert (link.stats.written, link.stats.dropped) == (2, 0)
    finally:
        gcs.close()
        link.close()


@pytest.mark.parametrize("reset", [False, True], ids=["closed", "reset"])
def test_a_tcp_gcs_that_goes_away_and_comes_back(capfd, reset):
    """pymavlink printed a line per frame once the GCS had gone (stdout, not the node's log) and
    never connected again."""
    gcs = TcpGcs()
    bridge = make_bridge(f"tcp:127.0.0.1:{gcs.port}")
    flight = Flight(bridge, lambda: gcs.pump())
    flight.run(0.5)
    before = len(gcs.messages())
    assert before >= 6
    gcs.go_away(reset)
    flight.run(1.5)
    gcs = TcpGcs(gcs.port)
    flight.run(4.0, until=lambda: {"HEARTBEAT", "STATUSTEXT", "ODOMETRY"} <= {m.get_type() for m in gcs.messages()})
    bridge.close()
    flight.assert_landing_went_on()
    assert_announced_once(gcs.messages())
    assert capfd.readouterr() == ("", "")
    stats = bridge.link_stats
    assert stats.failures >= 1 and stats.dropped > 0 and stats.restored == 1 and stats.up


def test_a_tcp_gcs_not_up_at_start_up():
    """The bridge would not start (ConnectionRefusedError after 2 s of retries) without its GCS."""
    port = free_port()
    bridge = finishes_within(1.5, lambda: make_bridge(f"tcp:127.0.0.1:{port}"))
    flight = Flight(bridge)
    flight.run(0.5)
    assert "refused" in bridge.link_stats.last_error and bridge.link_stats.dropped > 0
    gcs = TcpGcs(port)
    flight.pump = gcs.pump
    flight.run(4.0, until=lambda: {"HEARTBEAT", "STATUSTEXT", "ODOMETRY"} <= {m.get_type() for m in gcs.messages()})
    bridge.close()
    flight.assert_landing_went_on()
    assert_announced_once(gcs.messages())


def test_a_tcp_gcs_that_does_not_answer_never_blocks_the_tick():
    """A GCS whose host is gone does not answer the connection (its SYNs are dropped, as here by a
    full accept queue): a blocking connect waits minutes."""
    gcs = TcpGcs(backlog=0)
    filler = socket.create_connection(("127.0.0.1", gcs.port))  # fills the accept queue
    bridge = finishes_within(3.0, lambda: make_bridge(f"tcp:127.0.0.1:{gcs.port}"))
    flight = Flight(bridge)
    finishes_within(10.0, lambda: flight.run(3.5))  # past the connection timeout and a new attempt
    bridge.close()
    filler.close()
    gcs.go_away()
    flight.assert_landing_went_on()
    error = bridge.link_stats.last_error  # our connect timeout, or the kernel's (TCP_USER_TIMEOUT_MS), first
    assert bridge.link_stats.failures >= 1 and ("no answer" in error or "timed out" in error)


def test_a_tcp_connection_left_unanswered_is_given_up_after_the_connect_timeout(monkeypatch, monotonic):
    """And tried again at once: the reopen was due REOPEN_PERIOD_S after the first try."""
    attempts = []

    def connect(self):
        attempts.append(monotonic.now)
        return socket.socket(socket.AF_INET, socket.SOCK_STREAM), True  # still connecting

    monkeypatch.setattr(link_module.TcpLink, "_connect", connect)
    monkeypatch.setattr(link_module, "_writable", lambda handle, wait_s: False)  # nothing ever answers
    first_try = monotonic.now
    link = link_module.open_transport(f"tcp:127.0.0.1:{free_port()}")
    assert attempts == [first_try] and not link.stats.up
    monotonic.now += link_module.CONNECT_TIMEOUT_S - 0.01
    link.poll()
    assert link.stats.failures == 0
    monotonic.now += 0.02
    link.poll()
    assert link.stats.failures == 1 and "no answer" in link.stats.last_error
    link.poll()
    assert attempts == [first_try, monotonic.now]
    link.close()


def flood(sender, seconds=10.0):
    """STATUSTEXTs as fast as the link takes them until it reports one dropped; whether any call
    could have waited on the link is checked on return."""
    watch, deadline = WaitWatch(sender.link), time.monotonic() + seconds
    while sender.stats.dropped == 0 and time.monotonic() < deadline:
        watch(lambda: sender.send_statustext("VISION LAND r=25.0m gs=+0.0 lat=+0.0deg", mav2.MAV_SEVERITY_NOTICE))
    watch.assert_never_waited()


def test_a_tcp_gcs_that_stops_reading():
    """A full send buffer: frames are dropped whole and counted, never cut (a partial send used to
    leave half a frame on the stream, which the GCS's parser then discards with the next one)."""
    gcs = TcpGcs()
    gcs.reading = False
    sender = make_sender(f"tcp:127.0.0.1:{gcs.port}")
    gcs.pump()
    finishes_within(30.0, lambda: flood(sender))
    assert sender.stats.dropped == 1 and sender.stats.up and "not reading" in sender.stats.last_error
    gcs.reading = True
    gcs.pump_until_quiet()
    sender.send_heartbeat()  # after what was left of a cut frame, if one was
    gcs.pump_until_quiet()
    sender.close()
    got = gcs.messages()
    assert not [m for m in got if m.get_type() == "BAD_DATA"]
    assert len(got) == sender.stats.written


class Radio:
    """A telemetry radio on a pseudo-terminal behind a fixed path (as udev's /dev/serial/by-id
    links): unplugged, its tty hangs up; plugged back, it is a new tty behind the same path."""

    def __init__(self, path):
        self.path, self.master, self.data = path, None, b""
        self.plug()

    def plug(self):
        self.master, slave = os.openpty()
        tty.setraw(self.master)
        os.set_blocking(self.master, False)
        tmp = f"{self.path}.new"
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.path)
        os.close(slave)

    def unplug(self):
        os.close(self.master)
        self.master = None

    def pump(self):
        while self.master is not None:
            try:
                chunk = os.read(self.master, 1 << 16)
            except (BlockingIOError, OSError):  # EIO while no one has the tty open
                return
            if not chunk:
                return
            self.data += chunk

    def messages(self):
        return parse(self.data)


def test_a_serial_radio_unplugged_and_plugged_back(tmp_path):
    radio = Radio(tmp_path / "radio")
    bridge = make_bridge(f"{radio.path},57600")
    flight = Flight(bridge, radio.pump)
    flight.run(0.5)
    assert len(radio.messages()) >= 6
    radio.unplug()
    flight.run(1.5)
    radio = Radio(radio.path)
    flight.pump = radio.pump
    flight.run(4.0, until=lambda: {"HEARTBEAT", "STATUSTEXT", "ODOMETRY"} <= {m.get_type() for m in radio.messages()})
    bridge.close()
    flight.assert_landing_went_on()
    assert_announced_once(radio.messages())
    stats = bridge.link_stats
    assert stats.failures >= 1 and stats.dropped > 0 and stats.restored == 1 and stats.up


def test_a_missing_serial_device_is_tried_again_once_per_reopen_period(tmp_path, monotonic):
    first_try = monotonic.now
    link = link_module.open_transport(str(tmp_path / "ttyUSB_absent"))
    assert link.stats.failures == 1 and not link.stats.up
    for _ in range(10):  # ticks within the period: no new try
        link.poll()
        link.write(b"frame")
        monotonic.now += link_module.REOPEN_PERIOD_S / 20
    assert link.stats.failures == 1 and link.stats.dropped == 10
    monotonic.now = first_try + link_module.REOPEN_PERIOD_S
    link.poll()
    assert link.stats.failures == 2
    link.poll()
    assert link.stats.failures == 2
    link.close()


def test_a_serial_radio_that_stops_draining_never_blocks_the_tick(tmp_path):
    """The tty's output buffer full (a radio that stopped taking data): the write blocked until
    someone read the other end, and the node's executor with it."""
    radio = Radio(tmp_path / "radio")
    sender = make_sender(f"{radio.path},57600")
    finishes_within(30.0, lambda: flood(sender))
    assert sender.stats.dropped == 1 and sender.stats.up and "not reading" in sender.stats.last_error
    radio.pump()
    sender.send_heartbeat()
    radio.pump()
    sender.close()
    got = radio.messages()
    assert not [m for m in got if m.get_type() == "BAD_DATA"] and len(got) == sender.stats.written


@pytest.mark.parametrize("connection, message", [
    ("tcp:127.0.0.1", "HOST:PORT"),
    ("udpin:127.0.0.1:port", "HOST:PORT"),
    ("udpbcast:127.0.0.1:14550", "udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT or a serial device"),
    ("/dev/ttyUSB0,fast", "baud rate"),
    ("/dev/ttyUSB0,12345", "baud rate"),
    ("/dev/ttyUSB0,0", "baud rate"),  # B0 hangs the line up
])
def test_malformed_connections_are_refused_at_start_up(connection, message):
    with pytest.raises(ValueError, match=message):
        make_bridge(connection)


def received_within(link, seconds=2.0) -> bytes:
    data = b""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not data.endswith(b"end"):
        link.poll()
        data += link.received()
        time.sleep(0.01)
    return data


@pytest.mark.parametrize("kind", ["udpin", "udpout", "tcp", "serial"])
def test_every_link_keeps_what_the_gcs_sent_until_taken(kind, tmp_path):
    """The station parses the GCS's signed frames for their timestamps (gcs.signing): every link
    hands over what came in, in order, once."""
    closers = []
    if kind == "udpin":
        port = free_port(socket.SOCK_DGRAM)
        link = link_module.open_transport(f"udpin:127.0.0.1:{port}")
        gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        closers.append(gcs.close)
        send = lambda data: gcs.sendto(data, ("127.0.0.1", port))  # noqa: E731
    elif kind == "udpout":
        gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        gcs.bind(("127.0.0.1", 0))
        closers.append(gcs.close)
        link = link_module.open_transport(f"udpout:127.0.0.1:{gcs.getsockname()[1]}")
        link.write(b"hello")  # the GCS answers the address it heard from
        peer = gcs.recvfrom(64)[1]
        send = lambda data: gcs.sendto(data, peer)  # noqa: E731
    elif kind == "tcp":
        gcs = TcpGcs()
        link = link_module.open_transport(f"tcp:127.0.0.1:{gcs.port}")
        deadline = time.monotonic() + 2.0
        while gcs.conn is None and time.monotonic() < deadline:
            gcs.pump()
        closers.append(lambda: gcs.go_away())
        send = gcs.conn.sendall
    else:
        radio = Radio(tmp_path / "radio")
        link = link_module.open_transport(str(radio.path))
        closers.append(radio.unplug)
        send = lambda data: os.write(radio.master, data)  # noqa: E731
    try:
        send(b"first ")
        send(b"then the end")
        assert received_within(link) == b"first then the end"
        link.poll()
        assert link.received() == b""
    finally:
        link.close()
        for close in closers:
            close()


def test_a_udpin_peer_that_cannot_be_reached_costs_the_others_nothing():
    """The first peer whose sendto failed (here a broadcast address, refused without
    SO_BROADCAST; live, a peer whose route went) ended the loop: the other peers, the local GCS
    among them, got nothing, and the frame counted as dropped."""
    port = free_port(socket.SOCK_DGRAM)
    link = link_module.open_transport(f"udpin:127.0.0.1:{port}")
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(2.0)
    try:
        link._peers = {("255.255.255.255", 14550): time.monotonic(), gcs.getsockname(): time.monotonic()}
        link.write(b"frame")
        assert gcs.recv(64) == b"frame"
        stats = link.stats
        assert (stats.written, stats.dropped) == (1, 0) and "255.255.255.255:14550" in stats.last_error
    finally:
        link.close()
        gcs.close()


def test_a_serial_link_takes_every_byte_as_sent_whatever_the_tty_was_set_to(tmp_path):
    """Python 3.11's tty.setraw leaves input translations an earlier user of the device set (here
    INLCR and IGNCR, as a terminal program might leave them): 0a 0d came in as 0d, the 0d lost."""
    radio = Radio(tmp_path / "radio")
    fd = os.open(radio.path, os.O_RDWR | os.O_NOCTTY)
    attrs = termios.tcgetattr(fd)
    attrs[0] |= termios.INLCR | termios.IGNCR | termios.PARMRK
    termios.tcsetattr(fd, termios.TCSANOW, attrs)
    link = link_module.open_transport(str(radio.path))
    os.close(fd)
    try:
        frame = bytes([0xFD, 0x0A, 0x0D, 0x41, 0xFF]) + b"the end"
        os.write(radio.master, frame)
        assert received_within(link) == frame
    finally:
        link.close()
        radio.unplug()


def test_a_tcp_link_gives_up_on_a_gcs_that_stops_acknowledging():
    """Without a user timeout the kernel kept a silent GCS's frames for the ~15 min of its
    retransmissions, took more, and, when the network came back, sent them all late (20 s
    late, measured across a network namespace)."""
    gcs = TcpGcs()
    link = link_module.open_transport(f"tcp:127.0.0.1:{gcs.port}")
    try:
        sock = link._handle
        assert sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_USER_TIMEOUT) == link_module.TCP_USER_TIMEOUT_MS
    finally:
        link.close()
        gcs.go_away()


def test_udpout_does_not_flap_when_the_host_rate_limits_its_port_unreachable(monotonic):
    """Linux answers at most about one "port unreachable" a second to a remote sender (not on
    loopback). At 10 ticks a second most polls saw none, so the link went up and down every
    second, logging each change and re-sending the heartbeat and the stage each time."""
    port = free_port(socket.SOCK_DGRAM)
    link = link_module.open_transport(f"udpout:127.0.0.1:{port}")
    real_recv, tick = link._sock.recv, [0]

    class RateLimited:  # the kernel's answer kept to one a second, as from a remote host
        def __getattr__(self, name):
            return getattr(sock, name)

        def recv(self, size):
            try:
                return real_recv(size)
            except ConnectionRefusedError:
                if tick[0] % 10:
                    raise BlockingIOError from None
                raise

    link.write(b"frame")  # connects the socket
    sock = link._sock
    link._sock = RateLimited()
    states = []
    for tick[0] in range(60):  # 6 s at 10 Hz: a frame then a poll
        link.write(b"frame")
        time.sleep(0.005)  # the loopback's answer
        link.poll()
        states.append(link.stats.up)
        monotonic.now += 0.1
    link.close()
    assert not any(states[10:]) and "nobody listens" in link.stats.last_error


def test_udpout_replaces_a_socket_that_fails_otherwise():
    """A connected UDP socket keeps the source address it was connected from: after the
    station's address changed (DHCP, a radio modem reconnecting) every send failed with
    ENETUNREACH until the node was restarted, where a new socket works at once."""
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(2.0)
    link = link_module.open_transport(f"udpout:127.0.0.1:{gcs.getsockname()[1]}")

    class AddressGone:
        def send(self, data, *flags):
            raise OSError(errno.ENETUNREACH, os.strerror(errno.ENETUNREACH))

        def close(self):
            pass

    try:
        link.write(b"one")
        assert gcs.recv(64) == b"one"
        old, link._sock = link._sock, AddressGone()
        link.write(b"lost")
        old.close()
        link.write(b"two")
        assert gcs.recv(64) == b"two"
        assert (link.stats.written, link.stats.dropped) == (2, 1) and "unreachable" in link.stats.last_error
    finally:
        link.close()
        gcs.close()
