"""One log line when a safety rule starts acting and one when it stops, not one per tick.

Shared by the controller (its target limits) and the control tick (stale data): at 50 Hz a
line per tick would bury the one that matters, and the operator needs to see both when a
rule begins to act and how long it acted.
"""

from __future__ import annotations

import logging

log = logging.getLogger("tacgnn.real")


class SafetyLog:
    """Per rule, the ticks it has acted since it started (`active`) and over the run (`total`)."""

    def __init__(self, logger: logging.Logger = log):
        self.log = logger
        self.active: dict[str, int] = {}
        self.total: dict[str, int] = {}

    def note(self, rule: str, acting: bool, message: str) -> None:
        if acting:
            if rule not in self.active:
                self.log.warning("%s", message)
                self.active[rule] = 0
            self.active[rule] += 1
            self.total[rule] = self.total.get(rule, 0) + 1
        elif rule in self.active:
            self.log.warning("%s: released after %d ticks", rule, self.active.pop(rule))
