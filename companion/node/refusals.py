"""Refused input made visible: counts per kind and sender, and a rate-limited warning for each.

A refusal (a forged bundle, a MAVLink frame with a bad signature, a vehicle link frame from the
wrong system...) is counted under its kind and sender. The first refusal of a (kind, sender) pair
is logged at once; later ones are summed and logged at most once per `interval` seconds with the
count since the last line, so that a flood of bad input costs a counter increment per item and
one log line per interval, whatever its rate. At most `max_senders` senders are told apart per
kind (bounded memory whatever the senders claim to be); the rest are counted as "others".
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from collections.abc import Callable

WARN_INTERVAL_S = 60.0
MAX_SENDERS = 64
OTHERS = "others"


class Refusals:
    """Counts refusals by kind (and by kind and sender) and warns about them, rate-limited.

    `where` prefixes every line ("uav 0: mesh", "uav 0: MAVLink"); `clock` is monotonic seconds.
    Thread-safe: the mesh counts from Zenoh's callback threads.
    """

    def __init__(
        self,
        log: logging.Logger,
        where: str,
        interval: float = WARN_INTERVAL_S,
        max_senders: int = MAX_SENDERS,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._log, self._where, self._interval, self._max = log, where, interval, max_senders
        self._clock = clock
        self._lock = threading.Lock()
        self.kinds: Counter[str] = Counter()
        self.by_sender: dict[str, Counter[str]] = {}
        self._unlogged: dict[tuple[str, str], int] = {}
        self._next: dict[tuple[str, str], float] = {}
        self.lines = 0  # warnings logged

    def refuse(self, kind: str, sender: object, detail: str = "") -> None:
        """Count one refusal of `kind` from `sender`; log it now or sum it for the next line."""
        with self._lock:
            self.kinds[kind] += 1
            senders = self.by_sender.setdefault(kind, Counter())
            who = str(sender)
            if who not in senders and len(senders) >= self._max:
                who = OTHERS
            senders[who] += 1
            key = (kind, who)
            self._unlogged[key] = self._unlogged.get(key, 0) + 1
            now = self._clock()
            if now < self._next.get(key, -float("inf")):
                return
            count, total = self._unlogged.pop(key), senders[who]
            self._next[key] = now + self._interval
            self.lines += 1
        since = "" if count == total else f" ({count} since the last warning)"
        self._log.warning(
            "%s: refused %s from %s%s: %d so far%s; further ones from it are summed every %.0f s",
            self._where, kind, who, f" ({detail})" if detail else "", total, since, self._interval,
        )  # fmt: skip

    def flush(self) -> None:
        """Log what was summed and not yet logged (at the end of a run)."""
        with self._lock:
            pending = [(k, n, self.by_sender[k[0]][k[1]]) for k, n in self._unlogged.items() if n]
            self._unlogged.clear()
            self.lines += len(pending)
        for (kind, who), count, total in pending:
            line = "%s: refused %s from %s: %d so far (%d since the last warning)"
            self._log.warning(line, self._where, kind, who, total, count)

    def summary(self) -> dict[str, dict[str, int]]:
        """kind -> sender -> count (for the report)."""
        with self._lock:
            return {kind: dict(senders) for kind, senders in self.by_sender.items()}
