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
from pathlib import Path
from typing import Callable

SIGNING_EPOCH_S = 1420070400  # 2015-01-01 00:00 UTC
UNITS_PER_S = 100_000
RESERVE_S = 60.0  # the stored timestamp runs this far ahead of the ones in use
HEADROOM = 10_000  # frames that may still be signed below the stored timestamp


def clock_timestamp(now_s: float) -> int:
    """A Unix time as a signing timestamp (a clock before 2015 gives 0)."""
    return int((max(now_s, SIGNING_EPOCH_S) - SIGNING_EPOCH_S) * UNITS_PER_S)


class SigningTimestamps:
    """The outgoing timestamps of one signed link: never below the clock, never going back, and,
    with a state file, never reused across restarts, whatever the clock did meanwhile.

    The file holds a reservation: a timestamp ``RESERVE_S`` ahead of the ones in use, written
    (atomically, flushed to disk) before any frame is signed at or above it. A station starts
    from the greater of its clock and the reservation, so a crash loses nothing. A reservation
    that cannot be written later (a full disk) leaves the signing going, and ``store_error``
    says why, until a write succeeds.
    """

    def __init__(self, state_file: str | Path | None, clock: Callable[[], float] = time.time):
        self._path = Path(state_file) if state_file else None
        self._clock = clock
        self.store_error = ""
        self.start = clock_timestamp(clock())
        self._reserved = 0
        if self._path is not None:
            self.start = max(self.start, self._read())
            self._reserve(self.start)
            if self.store_error:
                raise OSError(f"mavlink signing timestamp file {self.store_error}")

    def advance(self, current: int) -> int:
        """The timestamp to sign the next frames from, given the link's ``current`` one."""
        stamp = max(current, clock_timestamp(self._clock()))
        if self._path is not None and stamp + HEADROOM >= self._reserved:
            self._reserve(stamp)
        return stamp

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

    def _reserve(self, stamp: int) -> None:
        reserved = stamp + int(RESERVE_S * UNITS_PER_S)
        tmp = self._path.with_name(self._path.name + ".tmp")
        try:
            with open(tmp, "w", encoding="ascii") as f:
                f.write(f"{reserved}\n")
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self._path)
        except OSError as exc:
            self.store_error = f"{self._path}: cannot write it ({exc})"
            return
        self._reserved, self.store_error = reserved, ""
