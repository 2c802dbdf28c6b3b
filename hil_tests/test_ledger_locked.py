"""Another process holds the ledger's write lock (a sqlite3 shell left inside a transaction, a
backup tool): the controller must go on answering. Each of its writes waited SQLite's busy timeout
(5 s) on the event loop, so `status` took 10 s and an operator's e-stop was answered "Timeout"
(its latches set on the Zenoh thread, its reply stuck behind the loop). Now a write locked out
past a short wait is the ledger unwritable — the alarm, nothing fed, retried — and the e-stop,
`status` and the refusals of what cannot be recorded are answered within the operator tools'
own 2 s timeout. A reset, which needs no ledger, is done and answered "ok" (it was done and
answered "cannot be written; try again")."""
import sqlite3
import time

import pytest

from hil_tests.farm import HilFarm


@pytest.mark.hil
def test_a_ledger_locked_by_another_process_leaves_e_stop_and_status_answered(tmp_path):
    farm = HilFarm(tmp_path, speed=20.0)
    try:
        farm.start_farm()
        hold = sqlite3.connect(str(farm.db_path), isolation_level=None, timeout=30)
        hold.execute("BEGIN IMMEDIATE")                 # the write lock, held by another process's connection
        try:
            for _ in range(3):
                code, reply = farm.tool("status", "--json")
                assert code == 0 and "tanks" in reply, reply
                code, reply = farm.tool("override", "estop", "--operator", "ana", "--reason", "drill")
                assert code == 0 and reply == {"ok": True, "confirmed": True}, reply
                # a reset needs no ledger: done, and said so, its request id not remembered (it
                # was answered "cannot be written; try again" of a reset carried out)
                code, reply = farm.tool("override", "reset", "--operator", "ana")
                assert code == 0 and reply["ok"] is True and "not remembered" in reply["note"], reply
                code, reply = farm.tool("status", "--json")
                assert reply["feeder"]["state"] != "estop", reply["feeder"]
                # a stock event is the ledger's: refused, and said so, not left to time out
                code, reply = farm.tool("override", "mortality", "--operator", "ana", "tank=T1", "count=1")
                assert code == 1 and reply["error"].startswith("ledger: cannot be written"), reply
            farm.check_alive()
        finally:
            hold.execute("ROLLBACK")
            hold.close()
        deadline = time.time() + 60
        while True:                                      # written again: the stock event is taken
            code, reply = farm.tool("override", "mortality", "--operator", "ana", "tank=T1", "count=1")
            if code == 0:
                break
            assert time.time() < deadline and reply["error"].startswith("ledger: cannot be written"), reply
            time.sleep(0.5)
        assert "ledger: written again" in farm.log("controller.log", tail=10_000)
    finally:
        farm.stop()
