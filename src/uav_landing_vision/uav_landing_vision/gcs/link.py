"""The station's end of the MAVLink link: it never blocks, never raises, and reopens what failed.

``mavlink.connection`` is one of:

- ``udpout:HOST:PORT``: datagrams to the GCS, from a socket connected to it, so that the kernel
  reports an ICMP "port unreachable" (nobody listens there: the link is then down until the GCS
  is heard) and only the GCS's own datagrams are read. Frames go out all the same: a GCS may
  start at any time, and one behind a firewall is never heard;
- ``udpin:HOST:PORT``: listen there and answer every address a datagram came from within the
  last ``PEER_SILENCE_S`` (a GCS sends its heartbeat every second), so nothing can be sent
  before the GCS's first packet, and a GCS gone or moved to another port is no longer answered;
- ``tcp:HOST:PORT``: connect to the GCS;
- ``/PATH[,BAUD]``: a serial device (a telemetry radio), 8N1 without flow control, 115200 baud
  unless given.

What comes in is kept for ``Link.received`` (the station reads the GCS's signed frames for
their timestamps, ``gcs.signing``). Every descriptor is non-blocking. A frame the link cannot
take whole now (closed, connecting, output full because the GCS or the radio stopped taking
data, an error) is dropped and counted.
On a stream, a frame the kernel took only in part is finished before any other, so the GCS never
receives a cut frame. A TCP or serial link that fails (an error, the GCS closing it, the radio
unplugged) is closed and reopened at most once every ``REOPEN_PERIOD_S``; a TCP connection left
unanswered for ``CONNECT_TIMEOUT_S`` is given up and tried again. Host names are resolved once,
at start-up.
"""

import errno
import io
import os
import select
import socket
import termios
import time
import tty
from abc import ABC, abstractmethod
from dataclasses import dataclass

REOPEN_PERIOD_S = 1.0
CONNECT_TIMEOUT_S = 2.0
START_WAIT_S = 1.0  # start-up waits this long for the first TCP connection
TCP_USER_TIMEOUT_MS = 2000  # unacknowledged data older than this fails a TCP link
PEER_SILENCE_S = 5.0  # udpin answers an address no longer once it has been silent this long
# udpout: a host answers at most about one "port unreachable" a second (Linux rate-limits them,
# but not on loopback), so nobody listens until frames have gone out this long without one.
REFUSAL_QUIET_S = 2.5
READS_PER_POLL = 64
READ_SIZE = 65536
DEFAULT_BAUD = "115200"
CONNECTIONS = "udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT or a serial device /PATH[,BAUD]"
OUTPUT_FULL = "output full: the GCS or the radio is not reading"


@dataclass(frozen=True)
class LinkStats:
    up: bool  # it takes frames now, as far as the station can tell (a UDP GCS may be gone unseen)
    written: int  # frames handed to the operating system (on a stream, a frame taken in part counts; its rest goes first)
    dropped: int  # frames not sent
    failures: int  # errors that closed a TCP or serial link or failed its reopening
    restored: int  # times frames went out again after some were dropped
    last_error: str  # why the last frame was dropped


def open_transport(connection: str) -> "Link":
    """The link for a ``mavlink.connection``; ValueError if malformed, OSError if its UDP socket
    cannot be bound or its host name does not resolve."""
    if connection.startswith("/"):
        path, _, baud = connection.partition(",")
        return SerialLink(path, _speed(baud or DEFAULT_BAUD))
    scheme, _, address = connection.partition(":")
    if scheme not in ("udpout", "udpin", "tcp"):
        raise ValueError(f"mavlink.connection '{connection}': expected {CONNECTIONS}")
    host, _, port = address.rpartition(":")
    if not (host and port.isdigit() and 0 < int(port) < 65536):
        raise ValueError(f"mavlink.connection '{connection}': expected {scheme}:HOST:PORT")
    kind = socket.SOCK_STREAM if scheme == "tcp" else socket.SOCK_DGRAM
    resolved = socket.getaddrinfo(host, int(port), socket.AF_INET, kind)[0][4]
    return TcpLink(resolved) if scheme == "tcp" else DatagramLink(resolved, listen=scheme == "udpin")


def _speed(baud: str) -> int:
    speed = getattr(termios, f"B{baud}", None) if baud.isdigit() else None
    if not speed:  # B0 (0) hangs the line up
        raise ValueError(f"serial baud rate '{baud}' is not one a tty takes (e.g. 57600, 115200)")
    return speed


class Link(ABC):
    """Counts what is sent and dropped; subclasses send (``_send``) and keep open (``_poll``)."""

    def __init__(self):
        self._written = self._dropped = self._failures = self._restored = 0
        self._last_error = ""
        self._outage = False  # frames dropped since the last one sent
        self._back = False  # a frame sent after an outage, not yet reported by poll()
        self._received: list[bytes] = []  # what came in since the last received()

    @property
    @abstractmethod
    def up(self) -> bool:
        """Whether it takes frames now, as far as the station can tell."""

    @property
    def stats(self) -> LinkStats:
        return LinkStats(self.up, self._written, self._dropped, self._failures, self._restored, self._last_error)

    def write(self, frame: bytes) -> None:
        """Send one frame or drop it; pymavlink's encoder calls this."""
        try:
            sent = self._send(frame)
        except OSError as exc:
            self._failed(exc)
            sent = False
        if not sent:
            self._dropped += 1
            self._outage = True
        else:
            self._written += 1
            if self._outage:
                self._outage, self._back = False, True
                self._restored += 1

    def poll(self) -> bool:
        """Read what came in and reopen a failed link when due; True once when frames have gone
        out again after an outage."""
        try:
            self._poll()
        except OSError as exc:
            self._failed(exc)
        back, self._back = self._back, False
        return back

    def received(self) -> bytes:
        """What came in, as read by the polls since the last call."""
        data, self._received = b"".join(self._received), []
        return data

    def _failed(self, exc: OSError) -> None:
        self._last_error = str(exc)

    @abstractmethod
    def _send(self, frame: bytes) -> bool:
        """Hand ``frame`` to the operating system whole; False (with ``_last_error``) if it cannot now."""

    @abstractmethod
    def _poll(self) -> None:
        """Read what came in; reopen what failed when due."""

    @abstractmethod
    def close(self) -> None:
        """Close what is open."""


class DatagramLink(Link):
    """``udpout`` (one peer, the GCS) or ``udpin`` (every address heard from lately)."""

    def __init__(self, address, listen: bool):
        super().__init__()
        self._listen = listen
        self._sock = self._socket()
        if listen:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._sock.bind(address)
        self._peers = {} if listen else {address: None}  # address -> monotonic time last heard (udpin)
        self._refused = False  # udpout: the last frames met "port unreachable", and the GCS was not heard since
        self._last_refusal = -float("inf")  # udpout: monotonic time of the last "port unreachable"
        self._unconfirmed = False  # udpout: a frame went out since the last poll
        self._connected = listen
        self._next_renewal = 0.0  # udpout: a failed socket is replaced at most once every REOPEN_PERIOD_S

    @staticmethod
    def _socket() -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setblocking(False)
        return sock

    @property
    def up(self) -> bool:
        return bool(self._peers) and not self._outage and not self._refused

    def _send(self, frame: bytes) -> bool:
        if not self._peers:
            self._last_error = f"no GCS heard within {PEER_SILENCE_S:g} s: nowhere to send"  # udpin only
            return False
        if self._listen:  # one peer that cannot be reached must not cost the others the frame
            errors = []
            for host, port in self._peers:
                try:
                    self._sock.sendto(frame, (host, port))
                except OSError as exc:
                    errors.append(f"{host}:{port}: {exc}")
            if errors:
                self._last_error = "; ".join(errors)
            return len(errors) < len(self._peers)
        if not self._connected:  # at start-up, or while there is no route to the GCS
            self._sock.connect(next(iter(self._peers)))
            self._connected = True
        try:
            self._sock.send(frame)
        except ConnectionRefusedError:  # an earlier frame's port unreachable; this one still goes out
            self._not_listening()
            self._sock.send(frame)
        self._unconfirmed = True
        return True

    def _poll(self) -> None:
        if not self._listen:
            self._poll_gcs()
            return
        now = time.monotonic()
        for _ in range(READS_PER_POLL):
            try:
                data, peer = self._sock.recvfrom(READ_SIZE)
            except BlockingIOError:
                break
            self._peers[peer] = now
            self._received.append(data)
        self._peers = {peer: heard for peer, heard in self._peers.items() if now - heard < PEER_SILENCE_S}

    def _poll_gcs(self) -> None:
        """udpout: read what the GCS sent back. A port unreachable says nobody listens; frames
        sent since the last poll without one (the kernel has it within a tick on a LAN), or a
        datagram from the GCS, say somebody does again."""
        if not self._connected:
            return
        refused = heard = False
        for _ in range(READS_PER_POLL):
            try:
                self._received.append(self._sock.recv(READ_SIZE))
            except BlockingIOError:
                break
            except ConnectionRefusedError:
                refused = True
            else:
                heard = True
        quiet = time.monotonic() - self._last_refusal > REFUSAL_QUIET_S
        if refused and not heard:
            self._not_listening()
        elif self._refused and (heard or self._unconfirmed and quiet):  # what went out in between was lost: as after an outage
            self._refused, self._back = False, True
        self._unconfirmed = False

    def _not_listening(self) -> None:
        host, port = next(iter(self._peers))
        self._refused, self._last_refusal = True, time.monotonic()
        self._last_error = f"nobody listens at {host}:{port} (port unreachable)"

    def _failed(self, exc: OSError) -> None:
        """udpout: a socket that fails otherwise (no route, an address gone: the station's address
        changed, a radio modem reconnected) is replaced, at most once every ``REOPEN_PERIOD_S``: a
        connected UDP socket keeps the source address it was connected from."""
        super()._failed(exc)
        if self._listen or isinstance(exc, ConnectionRefusedError) or time.monotonic() < self._next_renewal:
            return
        self._next_renewal = time.monotonic() + REOPEN_PERIOD_S
        self._sock.close()
        self._sock, self._connected = self._socket(), False

    def close(self) -> None:
        self._sock.close()


class StreamLink(Link):
    """A byte stream (TCP, serial) that is closed when it fails and reopened."""

    def __init__(self):
        super().__init__()
        self._handle = None  # the open socket or tty
        self._connecting_since = None  # monotonic time of a TCP connection not yet answered
        self._tail = b""  # the rest of a frame the kernel took in part
        self._next_open = 0.0
        self._open()

    @property
    def up(self) -> bool:
        return self._handle is not None and self._connecting_since is None

    def _open(self) -> None:
        self._next_open = time.monotonic() + REOPEN_PERIOD_S
        try:
            self._handle, connecting = self._connect()
        except OSError as exc:
            self._failed(exc)
            return
        self._connecting_since = time.monotonic() if connecting else None

    def _poll(self) -> None:
        if self._handle is None:
            if time.monotonic() >= self._next_open:
                self._open()
        elif self._connecting_since is not None:
            self._check_connected()
        else:
            for _ in range(READS_PER_POLL):
                data = self._read()
                if data is None:
                    return
                if not data:
                    raise ConnectionResetError("closed by the other end")
                self._received.append(data)

    def _send(self, frame: bytes) -> bool:
        if not self.up:
            self._last_error = self._last_error or "not connected yet"
            return False
        if self._tail:
            self._tail = self._tail[self._write(self._tail):]
            if self._tail:
                self._last_error = OUTPUT_FULL
                return False
        taken = self._write(frame)
        if not taken:
            self._last_error = OUTPUT_FULL
            return False
        self._tail = frame[taken:]
        return True

    def _failed(self, exc: OSError) -> None:
        super()._failed(exc)
        self._failures += 1
        self.close()
        self._handle, self._connecting_since, self._tail = None, None, b""

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()

    @abstractmethod
    def _connect(self):
        """A new handle and whether it is still connecting; OSError if it cannot be had."""

    @abstractmethod
    def _write(self, data: bytes) -> int:
        """Bytes the kernel took (0 when its buffer is full)."""

    @abstractmethod
    def _read(self) -> bytes | None:
        """What came in (b"" at the end of the stream), or None when nothing has."""


class TcpLink(StreamLink):
    def __init__(self, address):
        self._address = address
        super().__init__()
        if self._connecting_since is not None and _writable(self._handle, START_WAIT_S):
            self.poll()

    def _connect(self):
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        # A GCS that stops acknowledging (its network gone) fails the link within this, instead
        # of the kernel holding frames for the ~15 min of its retransmissions and sending them late.
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_USER_TIMEOUT, TCP_USER_TIMEOUT_MS)
        err = sock.connect_ex(self._address)
        if err not in (0, errno.EINPROGRESS):
            sock.close()
            raise OSError(err, os.strerror(err))
        return sock, err != 0

    def _check_connected(self) -> None:
        if _writable(self._handle, 0.0):
            err = self._handle.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
            if err:
                raise OSError(err, os.strerror(err))
            self._connecting_since = None
        elif time.monotonic() - self._connecting_since > CONNECT_TIMEOUT_S:
            raise TimeoutError(f"no answer within {CONNECT_TIMEOUT_S:g} s")

    def _write(self, data: bytes) -> int:
        try:
            return self._handle.send(data, socket.MSG_NOSIGNAL)
        except BlockingIOError:
            return 0

    def _read(self) -> bytes | None:
        try:
            return self._handle.recv(READ_SIZE)
        except BlockingIOError:
            return None


class SerialLink(StreamLink):
    def __init__(self, path: str, speed: int):
        self._path, self._speed = path, speed
        super().__init__()

    def _connect(self):
        handle = io.FileIO(os.open(self._path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK), "r+")
        try:
            _make_raw(handle.fileno(), self._speed)
        except termios.error as exc:
            handle.close()
            raise OSError(*exc.args) from exc
        return handle, False

    def _write(self, data: bytes) -> int:
        try:
            return os.write(self._handle.fileno(), data)
        except BlockingIOError:
            return 0

    def _read(self) -> bytes | None:
        try:
            return os.read(self._handle.fileno(), READ_SIZE)
        except BlockingIOError:
            return None


def _make_raw(fd: int, speed: int) -> None:
    """8 data bits, no parity, 1 stop bit, no flow control, no line editing, no translation of
    input bytes, at ``speed``. Python 3.11's ``tty.setraw`` leaves INLCR, IGNCR, PARMRK, IGNBRK
    and IUCLC as an earlier user of the device set them (3.12's ``cfmakeraw`` clears them): with
    INLCR a 0x0a byte of a frame came in as 0x0d."""
    tty.setraw(fd, termios.TCSANOW)
    iflag, oflag, cflag, lflag, _, _, cc = termios.tcgetattr(fd)
    cflag = (cflag | termios.CLOCAL | termios.CREAD) & ~(termios.CRTSCTS | termios.CSTOPB)
    iflag &= ~(termios.IXON | termios.IXOFF | termios.INLCR | termios.IGNCR | termios.ICRNL | termios.PARMRK
               | termios.IGNBRK | termios.BRKINT | termios.ISTRIP | termios.IUCLC | termios.INPCK)
    termios.tcsetattr(fd, termios.TCSANOW, [iflag, oflag, cflag, lflag, speed, speed, cc])


def _writable(handle, wait_s: float) -> bool:
    poller = select.poll()
    poller.register(handle, select.POLLOUT)
    return bool(poller.poll(wait_s * 1000.0))
