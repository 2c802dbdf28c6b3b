"""A feed as the ledger keeps it, and how an open one is decided after a restart.

Exactly-once dispensing rests on the intent committed before the auger starts (controller/store.py);
``reconcile()`` reads the dispenser's own counters (its run counter, the tag and load-cell grams of
its last run) to say whether that intent's run happened, never happened, is still running, or
cannot be told (``suspect``: its target stays counted against the ration until an operator settles
it). ``next_tag()`` picks the 16-bit tag the next intent carries.
"""
from __future__ import annotations

from dataclasses import dataclass

SUSPECT = "suspect"
TAGS = 65535            # the device's tags are 1..65535; 0 means none


@dataclass(frozen=True)
class Feed:
    id: str
    seq: int
    tank: str
    date: str
    t_intent: float
    target_g: float
    run_s: float
    tag: int
    cycles_before: int
    phase: str
    grams: float | None
    t_closed: float | None
    note: str | None
    source: str
    demand_id: int | None
    hopper_before: float | None = None     # load cell just before the intent (None: older rows)
    settled_by: str | None = None          # operator who settled a suspect feed


@dataclass(frozen=True)
class Reconciled:
    feed: Feed
    phase: str          # done | aborted | wait (the auger is still running) | suspect
    grams: float | None
    note: str
    no_run_seen: bool = False   # decided from no sign of the run: a START still on the wire may overturn it


def went_backwards(cycles_before: int, cycles_now: int) -> bool:
    """The 32-bit run counter stepped back (a reset), as opposed to moving on or wrapping."""
    return (cycles_now - cycles_before) % 2**32 >= 2**31


def reconcile(feed: Feed, state, *, accepted: bool = False, hopper_tolerance_g: float | None = None
              ) -> Reconciled:
    """Decide an open intent from the dispenser's counters (``DispenserState``).

    The device counts completed runs and remembers the tag and load-cell grams of the last
    one. Our run happened iff the counter moved past ``cycles_before`` and the last tag is
    ours; it never started iff the counter has not moved from a count above 0, the auger is still
    and the load cell has not dropped since the intent (from 0 a power-on since, which resets the
    counter, cannot be told from no run). ``accepted``: the device acknowledged our START, so "never
    started" cannot be true. Anything else is ``suspect``: food may have left, and nobody can
    say how much from here. An ``aborted`` result for a START that may still be on the wire is
    the caller's to confirm (see ``Dispensing._wait_run_end``).
    """
    if state.running and state.run_tag == feed.tag:
        return Reconciled(feed, "wait", None, "auger still running")
    if went_backwards(feed.cycles_before, state.cycles):
        return Reconciled(feed, SUSPECT, None,
                          f"dispenser counters went backwards (cycles {feed.cycles_before} -> {state.cycles}): "
                          f"power cut or new PLC{_hopper_hint(feed, state)}")
    if state.running:
        return Reconciled(feed, "wait", None, f"auger running another run (tag {state.run_tag})")
    moved = (state.cycles - feed.cycles_before) % 2**32
    if moved == 0:
        tolerance = hopper_tolerance_g if hopper_tolerance_g is not None else 1.5 * state.resolution_g
        if feed.hopper_before is not None and feed.hopper_before - state.hopper_g > tolerance:
            return Reconciled(feed, SUSPECT, None, "no run counted but the load cell dropped"
                              + _hopper_hint(feed, state))
        if accepted:
            return Reconciled(feed, SUSPECT, None, "the dispenser accepted the start but counted no run")
        if feed.cycles_before == 0:
            # 0 -> 0 is also a run then a power-on (a power cut, a new PLC, a simulator started anew
            # with the controller): the counters cannot tell, and a refilled hopper hides the load cell's
            return Reconciled(feed, SUSPECT, None, "the dispenser counts no run, and had counted none before "
                              "the intent: a run then a power-on would read the same", no_run_seen=True)
        return Reconciled(feed, "aborted", None, "auger never started", no_run_seen=True)
    if state.last_tag == feed.tag and moved == 1:
        note = "jammed; load cell grams" if state.jammed else "reconciled from dispenser counters"
        return Reconciled(feed, "done", state.last_grams, note)
    if state.last_tag == feed.tag:
        # other runs happened before ours completed? impossible: ours is the last; count it.
        return Reconciled(feed, "done", state.last_grams, f"reconciled; counter moved by {moved}")
    return Reconciled(feed, SUSPECT, None,
                      f"dispenser counter moved by {moved} but last tag {state.last_tag} is not ours")


def _hopper_hint(feed: Feed, state) -> str:
    if feed.hopper_before is None:
        return ""
    return f"; load cell {feed.hopper_before - state.hopper_g:.1f} g down since the intent"


def next_tag(last_tag: int | None, device_tags=()) -> int:
    """The tag after ``last_tag`` (the ledger's latest) in 1..65535, wrapping 65535 -> 1, and
    never one the device shows (its LAST_TAG or RUN_TAG, read just before): after a lost or
    restored ledger, a tag the device remembers would be refused or, worse, taken as already run."""
    taken = {t for t in device_tags if t}
    tag = (last_tag or 0) % TAGS + 1
    while tag in taken:
        tag = tag % TAGS + 1
    return tag
