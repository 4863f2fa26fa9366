"""How a rig's drives are closed (:class:`excite.information.closure.Closure`) follows the
registered kinds: a closure kept for a rig is made again when the registry changes."""

from __future__ import annotations

from excite.factors import base as registry
from excite.factors.base import Kind
from excite.information.closure import Closure
from excite.rig.config import load_rig


class Beacon(Kind):
    """A kind that measures every rig (no sensor entry, no section) and sees absolute position."""

    name = "test_beacon"
    arity = 1
    rows = 3
    breaks = frozenset({"position"})


def test_a_kept_closure_follows_the_registry():
    rig = load_rig("robotaxi")
    before = Closure.of(rig)
    assert before.local and "position" not in before.gauge  # no kind of the robotaxi sees absolute position
    assert Closure.of(rig) is before  # kept for the rig
    registry.register(Beacon())
    try:
        during = Closure.of(rig)
        assert not during.local and during.origin  # the beacon's absolute positions: world states, an origin
    finally:
        registry.unregister(Beacon.name)
    after = Closure.of(rig)
    assert after.local and after.gauge == before.gauge
