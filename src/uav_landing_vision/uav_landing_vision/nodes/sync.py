"""Exact-time matching of messages by ``header.stamp`` (DESIGN §4; message_filters is not available).

A :class:`StampCache` holds, per stamp, the messages received so far from a fixed set of
inputs, in either order of arrival. A stamp is complete when every input has delivered; the
cache keeps at most ``size`` incomplete stamps and hands back the oldest when it overflows.
With ``restart_behind_ns``, a message stamped that far before a waiting entry starts a new
time-line (a replay started again): the entries of the old one are handed back at once, where
they would otherwise outrank, and evict, every new stamp.
"""

import time
from dataclasses import dataclass, field

# A message stamped this far before the ones waiting belongs to a new time-line (a replay or a
# camera clock started again), not to a late delivery.
RESTART_BEHIND_NS = 2_000_000_000


@dataclass
class Entry:
    """The messages of one stamp, by input name."""

    stamp_ns: int
    items: dict = field(default_factory=dict)
    since: float = field(default_factory=time.monotonic)  # when its first message arrived


class RepeatedStampError(ValueError):
    """An input delivered a second message with a stamp still waiting in the cache."""


class StampCache:
    """Incomplete entries keyed by stamp (integer ns), bounded to ``size`` entries."""

    def __init__(self, inputs, size: int, restart_behind_ns: int | None = None):
        if size < 1:
            raise ValueError(f"cache size must be at least 1, got {size}")
        self.inputs = frozenset(inputs)
        self.size = size
        self.restart_behind_ns = restart_behind_ns
        self._entries: dict[int, Entry] = {}

    def add(self, name: str, stamp_ns: int, item) -> tuple[Entry | None, list[Entry]]:
        """Store ``item`` of input ``name``; returns (the entry it completed, or None, and the
        entries evicted, by a new time-line or because the cache overflowed, oldest first). A
        repeated (name, stamp) raises :class:`RepeatedStampError` and keeps the earlier item:
        which of the two the other input's message belongs to cannot be told."""
        if name not in self.inputs:
            raise KeyError(f"unknown input {name!r}")
        if stamp_ns in self._entries and name in self._entries[stamp_ns].items:
            raise RepeatedStampError(f"a second {name} stamped {stamp_ns} ns while the first waits for its pair")
        evicted = []
        if self.restart_behind_ns is not None:
            ahead = sorted(s for s in self._entries if s - stamp_ns > self.restart_behind_ns)
            evicted = [self._entries.pop(s) for s in ahead]
        entry = self._entries.setdefault(stamp_ns, Entry(stamp_ns))
        entry.items[name] = item
        if self.inputs <= entry.items.keys():
            return self._entries.pop(stamp_ns), evicted
        while len(self._entries) > self.size:
            evicted.append(self._entries.pop(min(self._entries)))
        return None, evicted

    def pop_older(self, stamp_ns: int) -> list[Entry]:
        """Remove and return the entries stamped before ``stamp_ns``, oldest first."""
        old = sorted(s for s in self._entries if s < stamp_ns)
        return [self._entries.pop(s) for s in old]

    def pop_expired(self, max_age_s: float) -> list[Entry]:
        """Remove and return the entries waiting longer than ``max_age_s``, oldest stamp first,
        together with every older entry (so that entries leave in stamp order)."""
        now = time.monotonic()
        expired = [s for s, e in self._entries.items() if now - e.since > max_age_s]
        return self.pop_older(max(expired) + 1) if expired else []

    def pop_newer(self, stamp_ns: int) -> list[Entry]:
        """Remove and return the entries stamped after ``stamp_ns``, oldest first."""
        new = sorted(s for s in self._entries if s > stamp_ns)
        return [self._entries.pop(s) for s in new]

    def has_newer(self, name: str, stamp_ns: int) -> bool:
        """Whether an entry stamped after ``stamp_ns`` holds a message of input ``name``."""
        return any(s > stamp_ns and name in e.items for s, e in self._entries.items())

    def __len__(self) -> int:
        return len(self._entries)
