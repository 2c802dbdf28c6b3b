"""The history queryable answers on a thread of its own, from a read-only connection of its own:
the controller's loop (Modbus e-stops, ``status``, the ledger's writes) never waits behind a big
query (100,000 rows held a Modbus e-stop 11.9 s)."""
from __future__ import annotations

import asyncio
import sqlite3
import threading
from types import SimpleNamespace

import pytest

import controller.history
from controller.config import load_config
from controller.overrides import Overrides
from controller.store import Store

T = 1_780_000_000.0


def test_a_history_query_runs_beside_the_loop_which_goes_on_writing(tmp_path, monkeypatch):
    ledger = Store(tmp_path / "ledger.db")
    ledger.add_survey("T1", T, "sparus_aurata", "a.json", [10.0, 12.0], [20.0, 30.0])
    real, seen, gate = controller.history.query_reply, {}, threading.Event()

    def held(store, cfg, key, params, now):
        seen.update(thread=threading.current_thread(), store=store)
        assert gate.wait(10), "the loop did not run while the query was answered"
        with pytest.raises(sqlite3.OperationalError, match="readonly"):
            store.db.execute("DELETE FROM survey")
        return real(store, cfg, key, params, now)
    monkeypatch.setattr(controller.history, "query_reply", held)
    c = SimpleNamespace(store=ledger, cfg=load_config("config/farm.toml"), clock=SimpleNamespace(now=lambda: T))
    overrides = Overrides(c)

    async def go():
        asking = asyncio.create_task(overrides.history({}, key="history/surveys/T1", params={}))
        await asyncio.sleep(0.05)
        ledger.add_stock_event(t=T, tank="T1", kind="mortality", count=1, to_tank=None, who="ana")  # meanwhile
        gate.set()
        return await asking
    try:
        reply = asyncio.run(go())
    finally:
        ledger.close()
    assert reply["ok"] is True and len(reply["rows"]) == 1
    assert seen["thread"] is not threading.main_thread() and seen["store"] is not ledger
