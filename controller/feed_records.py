"""The feed rows of the ledger (``controller.store``'s schema): intents, their outcomes, suspects, the
dispenser's counters last seen, and the sums the rations and production figures read. A mixin of
``controller.store.Store`` (its connection, lock, ``_write`` and ``transaction``), kept apart so
the store's own module stays the schema and the connection.
"""
from __future__ import annotations

import uuid

from controller.feed_outcome import Feed, next_tag


class FeedRecords:
    # -- feeds ----------------------------------------------------------------
    def next_tag(self, device_tags=()) -> tuple[int, int]:
        """(seq, tag): seq counts every feed ever; the tag follows the ledger's last one, skipping
        what the device shows (``device_tags``: its LAST_TAG and RUN_TAG)."""
        row = self.db.execute("SELECT seq, tag FROM feed ORDER BY seq DESC LIMIT 1").fetchone()
        seq, last = (row["seq"], row["tag"]) if row is not None else (0, None)
        return seq + 1, next_tag(last, device_tags)

    def add_intent(self, *, tank: str, date: str, t: float, target_g: float, run_s: float,
                   cycles_before: int, source: str, demand_id: int | None = None,
                   hopper_before: float | None = None, device_tags=()) -> Feed:
        with self._lock:
            seq, tag = self.next_tag(device_tags)
            feed_id = uuid.uuid4().hex[:16]
            self._write(
                "INSERT INTO feed (id, seq, tank, date, t_intent, target_g, run_s, tag, cycles_before, "
                "phase, source, demand_id, hopper_before) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, 'intent', ?, ?, ?)",
                (feed_id, seq, tank, date, t, target_g, run_s, tag, cycles_before, source, demand_id,
                 hopper_before))
            return self.feed(feed_id)

    def mark_suspect(self, feed_id: str, note: str) -> Feed:
        """An open intent whose outcome nobody can tell: kept against the ration, awaiting an
        operator. Its demand is served by it, in the same commit: food may have gone in for that ask,
        and fish still hungry ask again (serving the old ask again could feed it twice)."""
        with self.transaction() as db:
            cur = db.execute("UPDATE feed SET phase = 'suspect', note = ? WHERE id = ? AND phase = 'intent'",
                             (note, feed_id))
            if cur.rowcount != 1:
                raise RuntimeError(f"feed {feed_id} is not an open intent")
            db.execute("UPDATE demand SET outcome = 'served', feed_id = ? WHERE id = "
                       "(SELECT demand_id FROM feed WHERE id = ?) AND outcome = 'open'", (feed_id, feed_id))
        return self.feed(feed_id)

    def settle_suspect(self, feed_id: str, grams: float, t: float, operator: str, reason: str) -> Feed:
        """An operator's word on a suspect feed: ``grams`` > 0 went in (done), 0 none (aborted)."""
        phase = "done" if grams > 0 else "aborted"
        with self._lock:
            row = self.db.execute("SELECT note FROM feed WHERE id = ?", (feed_id,)).fetchone()
            cur = self._write(
                "UPDATE feed SET phase = ?, grams = ?, t_closed = ?, settled_by = ?, note = ? "
                "WHERE id = ? AND phase = 'suspect'",
                (phase, grams if grams > 0 else None, t, operator,
                 f"settled by {operator}: {reason}" + (f" (was: {row['note']})" if row and row["note"] else ""),
                 feed_id))
            if cur.rowcount != 1:
                raise LookupError(f"feed {feed_id} is not suspect")
            return self.feed(feed_id)

    def suspects(self) -> list[Feed]:
        return [Feed(**dict(r)) for r in
                self.db.execute("SELECT * FROM feed WHERE phase = 'suspect' ORDER BY seq")]

    # -- dispenser counters last seen ---------------------------------------------
    def counters_seen(self, device: str) -> tuple[int, float] | None:
        row = self.db.execute("SELECT cycles, total_g FROM counters WHERE device = ?", (device,)).fetchone()
        return None if row is None else (row["cycles"], row["total_g"])

    def forget_counters(self, device: str) -> None:
        """A device known to be new (a simulator this process started): nothing to compare with."""
        self._write("DELETE FROM counters WHERE device = ?", (device,))

    def see_counters(self, device: str, cycles: int, total_g: float, t: float) -> None:
        self._write("INSERT INTO counters (device, cycles, total_g, t) VALUES (?, ?, ?, ?) "
                    "ON CONFLICT (device) DO UPDATE SET cycles = excluded.cycles, total_g = excluded.total_g, "
                    "t = excluded.t", (device, cycles, total_g, t))

    def close_feed(self, feed_id: str, phase: str, grams: float | None, t: float, note: str = "",
                   served_demand: int | None = None) -> Feed:
        """Close an intent; with ``served_demand``, mark that demand served in the same commit."""
        if phase not in ("done", "aborted"):
            raise ValueError(phase)
        with self.transaction() as db:
            cur = db.execute("UPDATE feed SET phase = ?, grams = ?, t_closed = ?, note = ? "
                             "WHERE id = ? AND phase = 'intent'", (phase, grams, t, note, feed_id))
            if cur.rowcount != 1:
                raise RuntimeError(f"feed {feed_id} is not an open intent")
            if served_demand is not None:
                db.execute("UPDATE demand SET outcome = 'served', feed_id = ? WHERE id = ?", (feed_id, served_demand))
        return self.feed(feed_id)

    def feed(self, feed_id: str) -> Feed:
        row = self.db.execute("SELECT * FROM feed WHERE id = ?", (feed_id,)).fetchone()
        return Feed(**dict(row))

    def rebook_late(self, tag: int, grams: float, t: float, note: str) -> Feed | None:
        """The newest feed of ``tag``, closed ``aborted`` (its START given up as never landed), booked
        done with the grams the device counted for that tag's run after all; None when it was not."""
        with self.transaction() as db:
            row = db.execute("SELECT id, phase FROM feed WHERE tag = ? ORDER BY seq DESC LIMIT 1", (tag,)).fetchone()
            if row is None or row["phase"] != "aborted":
                return None
            db.execute("UPDATE feed SET phase = 'done', grams = ?, t_closed = ?, note = ? WHERE id = ?",
                       (grams, t, note, row["id"]))
        return self.feed(row["id"])

    def open_intents(self) -> list[Feed]:
        return [Feed(**dict(r)) for r in
                self.db.execute("SELECT * FROM feed WHERE phase = 'intent' ORDER BY seq")]

    def fed_g(self, tank: str, date: str) -> float:
        """Grams measured into ``tank`` on farm day ``date`` (done feeds only)."""
        return self.db.execute("SELECT COALESCE(SUM(grams), 0) FROM feed WHERE tank = ? AND date = ? "
                               "AND phase = 'done'", (tank, date)).fetchone()[0]

    def feed_per_day(self, tank: str, since: float | None = None) -> list[tuple[str, float, float]]:
        """(farm day, first intent's farm time, grams measured) per day with feeds done, in order."""
        rows = self.db.execute("SELECT date, MIN(t_intent), SUM(grams) FROM feed WHERE tank = ? AND phase = 'done' "
                               "AND t_intent >= ? GROUP BY date ORDER BY date", (tank, since or -1e18))
        return [(r[0], r[1], r[2]) for r in rows]

    def fed_between(self, tank: str, t1: float, t2: float) -> float:
        """Grams measured into ``tank`` by feeds begun in (t1, t2] (farm time)."""
        return self.db.execute("SELECT COALESCE(SUM(grams), 0) FROM feed WHERE tank = ? AND phase = 'done' "
                               "AND t_intent > ? AND t_intent <= ?", (tank, t1, t2)).fetchone()[0]

    def committed_g(self, tank: str, date: str) -> float:
        """Fed plus the targets of open and suspect intents: what the ration must still cover."""
        return self.db.execute(
            "SELECT COALESCE(SUM(CASE phase WHEN 'done' THEN grams ELSE target_g END), 0) FROM feed "
            "WHERE tank = ? AND date = ? AND phase IN ('done', 'intent', 'suspect')", (tank, date)).fetchone()[0]

    def learned_rate(self, note: str, last: int = 10) -> tuple[float | None, int]:
        """(grams per run second, runs) over the last runs closed with ``note`` (runs that ended as
        timed; partial or jammed runs would teach a wrong rate)."""
        rows = self.db.execute("SELECT grams, run_s FROM feed WHERE phase = 'done' AND note = ? AND run_s > 1 "
                               "ORDER BY seq DESC LIMIT ?", (note, last)).fetchall()
        run_s = sum(r["run_s"] for r in rows)
        return (sum(r["grams"] for r in rows) / run_s if run_s > 0 else None), len(rows)

    def delivery_ratios(self, note: str, last: int) -> list[float]:
        """Grams delivered / grams aimed for the last runs closed with ``note``, newest first."""
        rows = self.db.execute("SELECT grams, target_g FROM feed WHERE phase = 'done' AND note = ? AND run_s > 1 "
                               "AND target_g > 0 ORDER BY seq DESC LIMIT ?", (note, last)).fetchall()
        return [r["grams"] / r["target_g"] for r in rows]

    def feeds(self) -> list[Feed]:
        return [Feed(**dict(r)) for r in self.db.execute("SELECT * FROM feed ORDER BY seq")]
