"""MAVLink 2 signing timestamps: 10 µs units since 2015-01-01, rising with every frame of a link.

A receiver keeps the last timestamp of each stream (link id, system, component) and refuses one
that is not above it; a stream it meets anew (after its own restart) it refuses if the stamp is
more than a minute behind its own timestamp, which follows its clock (ArduPilot sets it from GPS
time). pymavlink only adds one per frame, so left alone a link's stamps fall behind the clock by
about its uptime, and a restarted GCS or autopilot refuses a station that has run for more than
a minute. And a station restarted after its clock stepped back would stamp below what the
receiver last took from it. MAVLink's rules (mavlink.io, "Message signing", timestamp handling)
are that the stamps follow the clock and that a system starts from the greater of its clock and
a stored timestamp; ``SigningTimestamps`` does both.
"""

import os
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Callable

SIGNING_EPOCH_S = 1420070400  # 2015-01-01 00:00 UTC
UNITS_PER_S = 100_000
RESERVE_S = 60.0  # a new reservation runs this far ahead of the stamps in use
RENEW_S = 30.0  # and is written, in the background, once they come this close to the stored one
HEADROOM = 10_000  # frames that may still be signed below the stored reservation
RETRY_S = 1.0  # a failed write is tried again at most this often
RESERVE, RENEW = int(RESERVE_S * UNITS_PER_S), int(RENEW_S * UNITS_PER_S)  # in stamp units
LAST_TIMESTAMP = (1 << 48) - 1 - 2 * RESERVE  # above it no reservation fits in 48 bits


def clock_timestamp(now_s: float) -> int:
    """A Unix time as a signing timestamp (a clock before 2015 gives 0)."""
    return int((max(now_s, SIGNING_EPOCH_S) - SIGNING_EPOCH_S) * UNITS_PER_S)


class SigningTimestamps:
    """The outgoing timestamps of one signed link: never below the clock, never going back, and,
    with a state file, never reused across restarts, whatever the clock did meanwhile.

    The file holds a reservation, a timestamp ahead of the ones in use; no frame is signed at or
    above the reservation on disk (written to a temporary file, flushed, renamed over the file,
    and the rename flushed). A station starts from the greater of its clock and the reservation,
    so neither a crash nor a power cut loses anything. The next reservation is written by a
    thread of its own once the stamps are ``RENEW_S`` from the stored one, so a slow disk does
    not hold up the bridge's tick; only a stamp about to reach the stored reservation waits for
    it. A reservation that cannot be written (a full disk) leaves the signing going, and
    ``store_error`` says why, until a write succeeds; it is tried again at most every ``RETRY_S``.
    """

    def __init__(self, state_file: str | Path | None, clock: Callable[[], float] = time.time):
        self._path = Path(state_file) if state_file else None
        self._clock = clock
        self.store_error = ""
        self.start = clock_timestamp(clock())
        self._reserved = 0  # the reservation on disk
        self._pending: tuple[Future, int] | None = None  # a reservation being written, and its value
        self._next_try = -float("inf")  # monotonic time before which a failed write is not tried again
        self._writer = None
        if self._path is not None:
            self.start = max(self.start, self._read())
            self._store(self.start + RESERVE)
            if self.store_error:
                raise OSError(f"mavlink signing timestamp file {self.store_error}")
            self._writer = ThreadPoolExecutor(1, thread_name_prefix="signing-timestamp")

    def advance(self, current: int) -> int:
        """The timestamp to sign the next frames from, given the link's ``current`` one."""
        stamp = max(current, clock_timestamp(self._clock()))
        if self._path is None:
            return stamp
        self._collect(wait=stamp + HEADROOM >= self._reserved)
        if time.monotonic() < self._next_try:
            return stamp
        if stamp + HEADROOM >= self._reserved:
            self._store(stamp + RESERVE)  # it must be on disk before frames reach it: here
        elif self._pending is None and stamp + RENEW >= self._reserved:
            self._pending = self._writer.submit(self._write, stamp + RESERVE), stamp + RESERVE
        return stamp

    def close(self) -> None:
        """Finish a reservation being written, and stop the writer."""
        self._collect(wait=True)
        if self._writer is not None:
            self._writer.shutdown()

    def _collect(self, wait: bool) -> None:
        """Take the result of the reservation being written, if done (or, with ``wait``, once done)."""
        if self._pending is None or not (wait or self._pending[0].done()):
            return
        (future, value), self._pending = self._pending, None
        self._settle(future.result(), value)

    def _store(self, value: int) -> None:
        self._settle(self._write(value), value)

    def _settle(self, error: str, value: int) -> None:
        if error:
            self.store_error, self._next_try = error, time.monotonic() + RETRY_S
        else:
            self._reserved, self.store_error = max(self._reserved, value), ""

    def _read(self) -> int:
        try:
            text = self._path.read_text(encoding="ascii").strip()
        except FileNotFoundError:
            return 0
        except (OSError, UnicodeDecodeError) as exc:
            raise OSError(f"mavlink signing timestamp file {self._path}: cannot read it ({exc})") from exc
        if not text.isdigit() or int(text) >= 1 << 48:
            raise ValueError(
                f"mavlink signing timestamp file {self._path} holds {text[:40]!r}, not a 48-bit timestamp; "
                "remove it to start from the clock"
            )
        return int(text)

    def _write(self, value: int) -> str:
        """Put ``value`` on disk for good; "" or why it could not."""
        tmp = self._path.with_name(self._path.name + ".tmp")
        try:
            with open(tmp, "w", encoding="ascii") as f:
                f.write(f"{value}\n")
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self._path)
            folder = os.open(self._path.parent, os.O_RDONLY)
            try:
                os.fsync(folder)  # the rename itself
            finally:
                os.close(folder)
        except OSError as exc:
            return f"{self._path}: cannot write it ({exc})"
        return ""
