"""The elastic clock (devices/elastic_clock.py) against a writer that dies mid-write and files that
are spoilt: readers never loop without end, a dead writer's segment is re-drawn, a live writer's
half-write reads slow, and a file that is not sound is refused naming the field."""
from __future__ import annotations

import math
import os
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from devices.clock_file import BUSY, GEN_AT, HEAD, IDLE, LEASE_S, NSLOTS, SEG, SEG_AT, SLOT, pace_of
from devices.elastic_clock import ElasticClock, create
from devices.errors import BadInput

SLOW, FAST, START = 100.0, 10_000.0, 1_780_000_000.0
ROOT = Path(__file__).resolve().parents[2]

# A writer that stops inside its re-draw, between the counter's two steps (the wall is read there)
WRITER = """
import struct, sys, time
from devices.elastic_clock import ElasticClock, GEN_AT
c = ElasticClock(sys.argv[1])
c.claim("controller")
real = c._time
def wall():
    if struct.unpack_from("<Q", c._map, GEN_AT)[0] & 1:
        print("odd", flush=True)
        time.sleep(600)
    return real()
c._time = wall
c.idle_until(c.now() + 1e5)
"""


def gen(path) -> int:
    return struct.unpack_from("<Q", Path(path).read_bytes(), GEN_AT)[0]


@pytest.fixture
def stopped_writer(tmp_path):
    """(clock path, the writer process, a reader opened before it) once the writer is stopped with
    the counter odd, holding the lock."""
    path = tmp_path / "clock"
    create(path, slow=SLOW, fast=FAST, farm_start=START)
    reader = ElasticClock(path)
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline() == "odd\n"
        assert gen(path) & 1
        yield path, proc, reader
    finally:
        proc.kill()
        proc.wait()
        reader.close()


def test_a_writer_killed_mid_write_is_mended_by_the_next_reader(stopped_writer):
    path, proc, reader = stopped_writer
    proc.kill()
    proc.wait()
    assert gen(path) & 1                       # the dead writer's counter, odd for good
    t0 = time.monotonic()
    f = reader.now()                           # returned at all: the old code looped here for ever
    assert time.monotonic() - t0 < 1.0
    assert not gen(path) & 1                   # re-drawn under the lock nobody held
    assert f >= START and reader.speed == SLOW  # the dead controller's slot holds the clock slow


def test_a_clock_left_odd_by_a_dead_writer_opens_and_shows(stopped_writer, tmp_path):
    path, proc, _reader = stopped_writer
    proc.kill()
    proc.wait()
    show = subprocess.run([sys.executable, "-m", "controller.cli", "clock", "--show", str(path)], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert show.returncode == 0, show.stderr
    assert "a writer died mid-write" in show.stderr
    assert not gen(path) & 1


def test_a_live_writer_mid_write_is_read_slow_not_waited_for(stopped_writer):
    path, _proc, reader = stopped_writer       # alive, holding the lock, its counter odd
    wall = [time.time()]
    reader._time = lambda: wall[0]             # (the wall, moved by hand from here on)
    t0 = time.monotonic()
    first = reader.now()
    wall[0] += 2.0
    later = reader.now()
    assert time.monotonic() - t0 < 1.0         # not waited for
    assert later - first == pytest.approx(2.0 * SLOW)   # slow on from the last sound segment
    assert gen(path) & 1                       # nobody wrote over the live writer's half


def test_a_clock_held_mid_write_by_a_stopped_writer_still_opens(stopped_writer):
    path, _proc, _reader = stopped_writer
    late = ElasticClock(path)                  # after a second's wait: the file's segment, sound
    assert late.now() >= START
    late.close()


def _spoil(path, **fields) -> None:
    """Write the fields named (segment or head) into the clock file at ``path``."""
    buf = bytearray(Path(path).read_bytes())
    magic, version, g, *seg, slow, fast, n, lease = HEAD.unpack_from(buf, 0)
    names = ["wall0", "farm0", "speed", "limit", "after"]
    seg = [fields.get(k, v) for k, v in zip(names, seg, strict=True)]
    HEAD.pack_into(buf, 0, magic, version, fields.get("gen", g), *seg, fields.get("slow", slow),
                   fields.get("fast", fast), fields.get("n", n), fields.get("lease", lease))
    for i, raw in fields.get("slots", {}).items():
        SLOT.pack_into(buf, HEAD.size + i * SLOT.size, *raw)
    Path(path).write_bytes(buf)


@pytest.mark.parametrize("fields, named", [
    ({"speed": 0.0}, "segment"),
    ({"speed": math.nan}, "segment"),
    ({"farm0": math.nan}, "segment"),
    ({"farm0": 1e300}, "segment"),
    ({"limit": math.nan}, "segment"),
    ({"wall0": time.time() + 1e6}, "segment"),
    ({"speed": -SLOW, "after": -SLOW, "slow": -SLOW}, "slow"),
    ({"slow": 9000.0, "fast": 10.0}, "slow"),
    ({"fast": 1e300}, "fast"),
    ({"n": 3}, "slots"),
    ({"lease": math.nan}, "lease"),
    ({"lease": -0.5}, "lease"),
    ({"lease": 1e9}, "lease"),
    ({"slots": {0: (b"sim", 1, 9, 0.0, b"x", 1.0)}}, "slot 0"),
    ({"slots": {2: (b"\xff\xfe", 1, BUSY, SLOW, b"x", 1.0)}}, "slot 2"),
    ({"slots": {0: (b"sim", os.getpid(), IDLE, math.nan, b"x", 1.0)}}, "slot 0"),
    ({"slots": {0: (b"sim", os.getpid(), IDLE, 1e300, b"x", 1.0)}}, "slot 0"),
    ({"slots": {1: (b"sim", 1, BUSY, math.nan, b"x", 1.0)}}, "slot 1"),
    ({"slots": {1: (b"sim", 1, BUSY, SLOW, b"x", math.nan)}}, "slot 1"),
    ({"slots": {3: (b"sim", 1, IDLE, START, b"x", -1.0)}}, "slot 3"),
    ({"slots": {0: (b"sim", 1, IDLE, START, b"x", time.time() + 1e6)}}, "slot 0"),    # its lease never lapsed
])
def test_a_spoilt_file_is_refused_naming_the_field(tmp_path, fields, named):
    path = tmp_path / "clock"
    create(path, slow=SLOW, fast=FAST, farm_start=START)
    _spoil(path, **fields)
    with pytest.raises(BadInput) as err:
        ElasticClock(path)
    assert str(err.value).startswith(f"{path}: {named}: ")
    assert "\n" not in str(err.value)


def test_a_segment_spoilt_after_opening_is_re_drawn_from_the_slots(tmp_path):
    path = tmp_path / "clock"
    create(path, slow=SLOW, fast=FAST, farm_start=START, wall_time=lambda: 5_000.0)
    c = ElasticClock(path, wall_time=lambda: 5_000.0)
    c.claim("sim")
    c.idle_until(START + 1e6)
    assert c.speed == FAST
    before = c.now()
    _spoil(path, speed=0.0)                    # (the file, not the map: one page, shared)
    assert c.now() == pytest.approx(before)    # no ZeroDivisionError, no jump
    assert c.speed == FAST                     # re-drawn from the slots: all idle
    assert SEG.unpack_from(path.read_bytes(), SEG_AT)[2] == FAST
    c.close()


def test_all_slots_taken_is_bad_input_not_an_internal_error(tmp_path):
    path = tmp_path / "clock"
    create(path, slow=SLOW, fast=FAST, farm_start=START, awaited=tuple(f"s{i}" for i in range(NSLOTS)))
    c = ElasticClock(path)
    with pytest.raises(BadInput, match="all 16 are taken"):
        c.claim("sim")
    c.close()


# A process on the clock file (as `fishfarm run`/`sim` take it), reading on a line from the test
ON_THE_CLOCK = """
import signal, sys
from controller.cli.sim_cmd import elastic
signal.signal(signal.SIGTERM, lambda *a: print("stop path", flush=True))
c = elastic(sys.argv[1], "controller")
print("ready", flush=True)
sys.stdin.readline()
a = c.now(); c.busy(why="moving"); c.idle_until(a + 10); b = c.now()
print("read", b >= a, c.slots() == [], flush=True)
"""


@pytest.mark.parametrize("size", [0, 100])
def test_a_clock_file_cut_short_stops_the_process_not_sigbus(tmp_path, size):
    path = tmp_path / "clock"
    create(path, slow=SLOW, fast=FAST, farm_start=START)
    proc = subprocess.Popen([sys.executable, "-c", ON_THE_CLOCK, str(path)], cwd=ROOT, text=True,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout.readline() == "ready\n"
    os.truncate(path, size)
    out, err = proc.communicate("go\n", timeout=60)
    assert proc.returncode == 0, err           # the old reader died of SIGBUS (-7) reading past the end
    assert out.splitlines() == ["stop path", "read True True"]
    said = [line for line in err.splitlines() if "shrank" in line]
    assert len(said) == 1 and f"shrank to {size} bytes" in said[0] and str(path) in said[0]


HOLDER = """
import sys
from devices.elastic_clock import ElasticClock
c = ElasticClock(sys.argv[1])
c.claim("sim")
c.idle_until(c.now() + 1e6)
print("holding", flush=True)
sys.stdin.readline()
"""


def test_a_second_farm_on_one_clock_file_is_refused_naming_the_holder(tmp_path):
    path = tmp_path / "clock"
    create(path, slow=SLOW, fast=FAST, farm_start=START, awaited=("sim", "controller"))
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(path)], cwd=ROOT, text=True,
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    other = ElasticClock(path)
    try:
        assert holder.stdout.readline() == "holding\n"
        with pytest.raises(BadInput) as err:
            other.claim("sim", wait_s=0.0)     # the old code took it over and wrote its own word
        assert str(err.value).startswith(f"{path}: slot 'sim': held by pid {holder.pid}, which is running")
        assert [(s.name, s.pid) for s in other.slots()[:1]] == [("sim", holder.pid)]   # untouched
        other.claim("controller")              # reserved by the harness: still claimed
        holder.stdin.close()                   # the holder ends while a claim waits for it
        threading.Thread(target=holder.wait, daemon=True).start()   # (reaped: no zombie)
        assert other.claim("sim", wait_s=60.0) == 0   # a dead process's slot is taken over
    finally:
        holder.kill()
        holder.wait()
        other.close()


def test_a_segment_overwritten_with_an_earlier_anchor_does_not_take_log_times_back(tmp_path):
    """Another program writes a sound but earlier segment (a day back): now() is held monotonic and
    so is at(), which stamps the log lines (they read a day behind the ledger and the status)."""
    path = tmp_path / "clock"
    create(path, slow=SLOW, fast=FAST, farm_start=START)
    clock = ElasticClock(path)
    try:
        before = clock.now()
        seg = clock.segment()
        with open(path, "r+b") as fh:
            raw = bytearray(fh.read())
            SEG.pack_into(raw, SEG_AT, seg.wall0, seg.farm0 - 86_400.0, seg.speed, seg.limit, seg.after)
            fh.seek(0)
            fh.write(raw)
        assert clock.segment().farm0 < before - 80_000            # the file reads a day back
        now = time.time()
        assert clock.now() >= before and clock.at(now) >= before
    finally:
        clock.close()



def test_a_word_given_in_the_wall_s_future_holds_the_farm_slow():
    """Opened, such a slot is refused (above); spoilt later, its word is none: slow, as a spoilt
    slot's. Taken as given, its lease never lapsed and the farm ran fast without its holder."""
    w = 5_000.0
    given = (b"sim", 1, IDLE, START + 1e6, b"x", w)
    future = (b"controller", 2, IDLE, START + 1e6, b"x", w + 1e6)
    assert pace_of([given, given], START, w, SLOW, FAST, lambda pid: True, LEASE_S)[0] == FAST
    assert pace_of([given, future], START, w, SLOW, FAST, lambda pid: True, LEASE_S)[0] == SLOW
