"""The Modbus server answers every address of the map from the snapshot, in both word orders, to a
client that is not pymodbus (tests/controller/scada/mbap.py), and guards its writes."""
import random
import re
import struct

import pytest

from .conftest import StandIn, map_rows
from .mbap import Mbap, words_f32

WIDTH = {"bool": 1, "u16": 1, "i16": 1, "u32": 2, "i32": 2, "f32": 2}
NO_VALUE = {"u16": [0xFFFF], "i16": [0x8000], "u32": [0xFFFF, 0xFFFF]}
SEVERITIES = ["info", "warning", "critical"]      # the descriptions: 1 info, 2 warning, 3 critical


def feeder_states() -> list[str]:
    """The enumeration as the map documents it: '0 starting, 1 idle, ...'."""
    [row] = [r for r in map_rows() if r["name"] == "feeder.state"]
    return [name for _, name in sorted((int(i), n) for i, n in re.findall(r"(\d+) ([a-z]+)", row["description"]))]


def random_status(rng: random.Random, tanks: list[str], slots: list[str]) -> dict:
    def maybe(x):
        return None if rng.random() < 0.2 else x

    def f32(lo, hi):       # a value a float32 holds exactly, so the words are unambiguous
        return struct.unpack(">f", struct.pack(">f", rng.uniform(lo, hi)))[0]

    alarms = []
    for source in rng.sample(slots + ["sensor/T1-a", "demand/T2", "grading/T3", "survey/T1", "survey",
                                         "controller/robot.run", "elsewhere"], 6):
        # status also lists cleared alarms not yet acknowledged: the map's are the standing ones
        alarms.append({"source": source, "kind": "general", "severity": rng.choice(SEVERITIES),
                       "acked": rng.random() < 0.5, "active": rng.random() < 0.7})
    feeder = {"state": rng.choice(feeder_states()), "position_m": maybe(f32(0, 100)), "hopper_g": maybe(f32(0, 8000))}
    if feeder["state"] == "estop" and rng.random() < 0.5:
        feeder["starting"] = True          # e-stopped while starting (status marks it so)
    return {"t": "2026-06-01T12:00:00.000Z", "uptime_s": rng.uniform(0, 1e6),
            "feeder": feeder,
            "alarms": alarms,
            "tanks": {t: {"demand": rng.random() < 0.5, "paused": maybe(rng.random() < 0.5),
                          "ration_g": maybe(f32(0, 5000)), "fed_g": maybe(f32(0, 5000)),
                          "pellet_mm": maybe(f32(0.5, 9)), "mean_weight_g": maybe(f32(1, 3000)),
                          "stock": maybe(rng.randint(0, 10**7)),
                          "last_survey_t": maybe("2026-05-30T08:00:00.000Z"),
                          # survey figures: whole tenths of a % and hundredths, as the map scales them
                          "weight_cv_pct": maybe(rng.randint(0, 2000) / 10),
                          "sgr_pct_day": maybe(rng.randint(-500, 2000) / 100),
                          "fcr": maybe(rng.randint(0, 600) / 100),
                          # the growth fit's: an FCR interval may be unbounded above (None)
                          "sgr_fit_pct_day": maybe(rng.randint(-500, 2000) / 100),
                          "sgr_fit_ci_pct_day": maybe(rng.randint(0, 500) / 100),
                          "fcr_fit": maybe(rng.randint(0, 600) / 100),
                          "fcr_fit_ci": maybe([rng.randint(0, 300) / 100, maybe(rng.randint(300, 900) / 100)]),
                          "fcr_net_fit": maybe(rng.randint(0, 600) / 100),
                          "weight_ci_pct": maybe(rng.randint(0, 500) / 10), "fit_surveys": maybe(rng.randint(2, 9)),
                          # the water: hundredths of a degree, below freezing to a hot summer
                          "water_temp_c": maybe(rng.randint(-500, 4000) / 100),
                          "water_temp_source": maybe(rng.choice(["sensor", "config"]))} for t in tanks}}


def hundredths(x):
    """An i16/u16 register at scale 0.01: the raw word (two's complement when negative)."""
    return None if x is None else round(x * 100) & 0xFFFF


def expected(row: dict, st: dict, tanks: list[str], word_order: str, read_only: bool):
    """What a row must read, from the map's words and the status — independently of the server."""
    name = row["name"]
    if row["access"] == "W":
        return 0                                     # momentary commands read 0

    def sev(alarms):
        return max((SEVERITIES.index(a["severity"]) + 1 for a in alarms), default=0)

    def in_slot(a, slot):
        return a["source"] == slot or a["source"].startswith(slot + "/")

    standing = [x for x in st["alarms"] if x["active"]]

    m = re.fullmatch(r"tank\.([^.]+)\.(.+)", name)
    a = re.fullmatch(r"alarm\.(.+)\.(severity|active|unacked)", name)
    if m:
        tank, field = m.groups()
        t = st["tanks"][tank]
        value = {"demand": int(t["demand"]), "paused": None if t["paused"] is None else int(t["paused"]),
                 "pause": bool(t["paused"]), "ration_g": t["ration_g"], "set_ration_g": t["ration_g"],
                 "fed_g": t["fed_g"], "pellet_mm": t["pellet_mm"], "mean_weight_g": t["mean_weight_g"],
                 "biomass_kg": None if t["stock"] is None or t["mean_weight_g"] is None
                 else t["stock"] * t["mean_weight_g"] / 1000,
                 "stock": t["stock"], "last_survey_t": None if t["last_survey_t"] is None else 1780128000,
                 "alarm_severity": sev([x for x in standing if x["source"] in
                                        (f"sensor/{tank}-a", f"sensor/{tank}-b", f"demand/{tank}",
                                         f"grading/{tank}", f"survey/{tank}")]),
                 # raw words: value / scale, a negative i16 in two's complement
                 "weight_cv_pct": None if t["weight_cv_pct"] is None else round(t["weight_cv_pct"] * 10),
                 "sgr_pct_day": None if t["sgr_pct_day"] is None else round(t["sgr_pct_day"] * 100) & 0xFFFF,
                 "fcr": None if t["fcr"] is None else round(t["fcr"] * 100),
                 "water_temp_c": None if t["water_temp_c"] is None else round(t["water_temp_c"] * 100) & 0xFFFF,
                 "water_temp_source": {None: None, "sensor": 0, "config": 1}[t["water_temp_source"]],
                 "sgr_fit_pct_day": hundredths(t["sgr_fit_pct_day"]), "sgr_fit_ci_pct_day": hundredths(
                     t["sgr_fit_ci_pct_day"]), "fcr_fit": hundredths(t["fcr_fit"]),
                 "fcr_fit_low": hundredths((t["fcr_fit_ci"] or [None, None])[0]),
                 "fcr_fit_high": hundredths((t["fcr_fit_ci"] or [None, None])[1]),
                 "weight_ci_pct": None if t["weight_ci_pct"] is None else round(t["weight_ci_pct"] * 10),
                 "fit_surveys": t["fit_surveys"], "fcr_net_fit": hundredths(t["fcr_net_fit"])}[field]
    elif a:
        slot, field = a.groups()
        mine = [x for x in standing if in_slot(x, slot)]
        value = {"severity": sev(mine), "active": bool(mine), "unacked": any(not x["acked"] for x in mine)}[field]
    else:
        f = st["feeder"]
        value = {"uptime_s": int(round(st["uptime_s"])), "map_version": 1, "tank_count": len(tanks),
                 "word_order": int(word_order == "little"), "farm_time": 1780315200,
                 "estop": f["state"] == "estop", "estop_latched": f["state"] == "estop",
                 "ready": f["state"] != "starting" and not f.get("starting"), "writes_enabled": not read_only,
                 "feeder.state": feeder_states().index(f["state"]), "feeder.position_m": f["position_m"],
                 "feeder.hopper_g": f["hopper_g"], "alarms.active": len(standing),
                 "alarms.unacked": sum(not x["acked"] for x in standing),
                 "alarms.highest": sev(standing), "layout_crc": layout_crc(tanks)}.get(name)   # cleaner.*: reserved
    return value


def layout_crc(tanks: list[str]) -> int:
    """The CRC-32 of the JSON [tank ids, alarm slots], each in the map's order (by address)."""
    import json
    import zlib
    acks = sorted((int(r["address"]), r["name"]) for r in map_rows() if re.fullmatch(r"alarm\.(.+)\.ack", r["name"]))
    slots = [re.fullmatch(r"alarm\.(.+)\.ack", n).group(1) for _, n in acks]
    return zlib.crc32(json.dumps([tanks, slots]).encode())


def check_row(row, got, value, word_order):
    dtype = row["data_type"]
    if dtype == "bool":
        assert got == [int(bool(value))], row["name"]
    elif dtype == "f32":
        x = words_f32(got, word_order)
        if value is None:
            assert x != x, row["name"]            # NaN
        else:
            assert x == pytest.approx(value, rel=1e-6), row["name"]
    elif value is None:
        assert got == NO_VALUE[dtype], row["name"]
    else:
        words = got if word_order == "big" else got[::-1]
        raw = words[0] if WIDTH[dtype] == 1 else (words[0] << 16) | words[1]
        assert raw == value, row["name"]


@pytest.mark.parametrize("word_order", ["big", "little"])
def test_every_address_reads_the_snapshot(serve, word_order):
    rng = random.Random(word_order)
    rows = map_rows()
    tanks = sorted({re.match(r"tank\.([^.]+)\.", r["name"]).group(1) for r in rows if r["name"].startswith("tank.")},
                   key=lambda t: int(t[1:]))
    slots = sorted({re.match(r"alarm\.(.+)\.ack$", r["name"]).group(1) for r in rows if r["name"].endswith(".ack")})
    stand_in = StandIn()
    # the coordinator's own refreshes a minute apart: within this test only the test's refresh()es
    # move the heartbeat (at 0.25 s, reading the whole map twice over loopback saw one slip in)
    srv = serve(stand_in, word_order=word_order, refresh_s=60)
    client = Mbap(srv.port)
    try:
        for _ in range(3):                          # a few snapshots: values change, reads follow
            stand_in.current = random_status(rng, tanks, slots)
            srv.refresh()
            for row in rows:
                if row["name"] == "heartbeat":
                    continue
                got = client.read(row["type"], int(row["address"]), WIDTH[row["data_type"]])
                assert isinstance(got, list), (row["name"], got)
                check_row(row, got, expected(row, stand_in.current, tanks, word_order, False), word_order)
        # the heartbeat moves with every refresh, and only then
        [h0] = client.read("input register", 0)
        assert client.read("input register", 0) == [h0]
        srv.refresh()
        srv.refresh()
        assert client.read("input register", 0) == [(h0 + 2) % 0xFFFF]
    finally:
        client.close()


def test_reads_beyond_the_map_and_other_units_are_refused(serve):
    srv = serve()
    client = Mbap(srv.port)
    try:
        for table in ("coil", "discrete input", "input register", "holding register"):
            rows = [r for r in map_rows() if r["type"] == table]
            end = max(int(r["address"]) + WIDTH[r["data_type"]] for r in rows)
            tank_rows = [r for r in rows if r["name"].startswith("tank.")]
            if tank_rows:    # a tank block reads whole, its reserved words too: 8 tanks of one stride
                first = [min(int(r["address"]) for r in tank_rows if r["name"].startswith(f"tank.T{i}."))
                         for i in (1, 2)]
                end = max(end, first[0] + 8 * (first[1] - first[0]))
            assert client.read(table, end, 1) == ("exception", 2)
            assert client.read(table, end - 1, 2) == ("exception", 2)
            assert isinstance(client.read(table, 0, end), list) or end > 125
        got, data = client.call(4, struct.pack(">HH", 0, 1), unit=7)
        assert got == 0x84 and data[0] == 0x0B          # gateway target failed to respond: not this unit
    finally:
        client.close()


class Failing(StandIn):
    broken = False

    def status(self):
        if self.broken:
            raise RuntimeError("status is broken")
        return super().status()


def test_a_failing_status_reads_no_value_not_the_last_number(serve):
    stand_in = Failing({"t": "2026-06-01T00:00:00.000Z", "feeder": {"state": "idle", "position_m": 4.5},
                        "tanks": {"T1": {"ration_g": 250.0}}, "alarms": []})
    srv = serve(stand_in)
    client = Mbap(srv.port)
    try:
        srv.refresh()
        assert words_f32(client.read("input register", 102, 2), "big") == 250.0
        [beat] = client.read("input register", 0)
        stand_in.broken = True
        srv.refresh()
        x = words_f32(client.read("input register", 102, 2), "big")
        assert x != x and words_f32(client.read("input register", 11, 2), "big") != 4.5    # NaN, not 250 / 4.5
        assert client.read("input register", 0) == [beat]             # the heartbeat holds: SCADA sees it stop
        stand_in.broken = False
        srv.refresh()
        assert words_f32(client.read("input register", 102, 2), "big") == 250.0
        assert client.read("input register", 0) == [(beat + 1) % 0xFFFF]
    finally:
        client.close()
