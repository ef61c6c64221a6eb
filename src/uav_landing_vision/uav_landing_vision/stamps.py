"""Header stamps (``builtin_interfaces/Time``: ``sec``, ``nanosec``) as integer nanoseconds, the key
by which the nodes and the bag reader match a frame's messages."""

NANOSECONDS_PER_SECOND = 1_000_000_000


def stamp_ns(stamp) -> int:
    """``stamp`` in integer ns. ValueError for a malformed one (``nanosec`` not in 0..1e9 − 1):
    read as a time, (s, 1.5e9 ns) would be (s + 1, 0.5e9 ns) and alias a valid stamp."""
    sec, nanosec = int(stamp.sec), int(stamp.nanosec)
    if not 0 <= nanosec < NANOSECONDS_PER_SECOND:
        raise ValueError(f"header stamp {sec} s + {nanosec} ns is malformed "
                         f"(nanosec must be below {NANOSECONDS_PER_SECOND})")
    return sec * NANOSECONDS_PER_SECOND + nanosec


def stamp_fields(ns: int) -> tuple[int, int]:
    """``(sec, nanosec)`` of a time in integer ns."""
    return divmod(int(ns), NANOSECONDS_PER_SECOND)


def within_age(age_ns: int, max_age_s: float) -> bool:
    """Whether ``age_ns`` (a later stamp minus an earlier one) is in 0..``max_age_s``, compared in
    integer ns: as ``age_ns * 1e-9`` a pose exactly 0.3 s old would be 0.30000000000000004 s."""
    return 0 <= age_ns <= round(max_age_s * NANOSECONDS_PER_SECOND)


def header_stamp_ns(msg) -> int | None:
    """:func:`stamp_ns` of ``msg.header.stamp``; None for a message without a header."""
    stamp = getattr(getattr(msg, "header", None), "stamp", None)
    return None if stamp is None else stamp_ns(stamp)
