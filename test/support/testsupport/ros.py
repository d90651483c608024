"""DDS domains for tests: each ROS test gets its own id, all inside 0-101.

Ids above 101 (except 215-232) map to UDP ports that can clash with the kernel's ephemeral range,
and two tests sharing a domain can discover each other's leftover participants.
"""

from __future__ import annotations

import os

_TESTS = ("dds_exchange", "player", "segmentation", "mapper", "contact_graph", "spare1", "spare2", "spare3")


def domain_id(test: str) -> int:
    """A domain id unique to `test` within this run (and varied by pid between runs)."""
    slot = _TESTS.index(test)
    return 20 + (os.getpid() % 10) * 8 + slot  # 20 .. 99
