"""The register map: one table in code, written out as config/modbus_map.csv and README's table."""
import math
import struct
import subprocess
import sys
import tomllib

import pytest
import tomli_w
from hypothesis import given
from hypothesis import strategies as st

from controller.config import load_config
from controller.errors import BadInput
from controller.scada import register_map as rm
from controller.scada import words as wire

from .conftest import MAP_CSV, ROOT, map_rows

WIDTH = {"bool": 1, "u16": 1, "i16": 1, "u32": 2, "i32": 2, "f32": 2}


def test_the_csv_is_the_table():
    """Regenerate with: python -m controller.scada.register_map > config/modbus_map.csv"""
    made = subprocess.run([sys.executable, "-m", "controller.scada.register_map", "--config", "config/farm.toml"],
                          capture_output=True, text=True, cwd=ROOT, check=True).stdout
    assert made == MAP_CSV.read_text(), "config/modbus_map.csv differs from the table: regenerate it"
    assert made == rm.csv_text(rm.layout(load_config(ROOT / "config" / "farm.toml")))


def test_readme_shows_the_table():
    """Regenerate with: python -m controller.scada.register_map --markdown"""
    assert rm.markdown() in (ROOT / "README.md").read_text(), "README's register map differs from the table"


def test_every_value_has_its_own_words_and_a_documented_form():
    rows = map_rows()
    assert list(rows[0]) == ["name", "type", "address", "data_type", "scale", "units", "access", "description"]
    taken = {}
    for r in rows:
        assert r["type"] in ("coil", "discrete input", "input register", "holding register")
        assert r["data_type"] in WIDTH and r["access"] in ("R", "R/W", "W") and r["description"]
        assert (r["data_type"] == "bool") == (r["type"] in ("coil", "discrete input"))
        if "W" in r["access"]:
            assert r["type"] in ("coil", "holding register"), r["name"]
        for w in range(WIDTH[r["data_type"]]):
            key = (r["type"], int(r["address"]) + w)
            assert key not in taken, f"{r['name']} overlaps {taken[key]}"
            taken[key] = r["name"]
    assert len({(r["type"], r["name"]) for r in rows}) == len(rows)
    # the commands the issue names are all there, per tank where they are per tank
    cfg = load_config(ROOT / "config" / "farm.toml")
    names = {r["name"] for r in rows if "W" in r["access"]}
    assert {"estop", "reset", "ack_all"} <= names
    for t in cfg.tanks:
        assert {f"tank.{t.id}.pause", f"tank.{t.id}.feed_now_g", f"tank.{t.id}.set_ration_g"} <= names


def test_tank_blocks_follow_the_documented_stride():
    cfg = load_config(ROOT / "config" / "farm.toml")
    rows = {(r["type"], r["name"]): int(r["address"]) for r in map_rows()}
    for block in ("tank", "survey", "water", "growth"):    # survey coils, water, growth: per-tank blocks of their own
        names = {r.name for r in rm.TABLE if r.block == block}
        for kind, (base, stride) in rm.BLOCKS[block].items():
            for i, t in enumerate(cfg.tanks):
                mine = [a for (k, n), a in rows.items()
                        if k == kind and n.startswith(f"tank.{t.id}.") and n.split(".")[-1] in names]
                assert mine and all(base + i * stride <= a < base + (i + 1) * stride for a in mine)


def words(dtype, raw, order):
    if WIDTH[dtype] == 1:
        return [raw & 0xFFFF]
    hi, lo = (raw >> 16) & 0xFFFF, raw & 0xFFFF
    return [hi, lo] if order == "big" else [lo, hi]


@pytest.mark.parametrize("order", ["big", "little"])
@given(x=st.floats(width=32, allow_nan=False), u32=st.integers(0, 0xFFFF_FFFE),
       i32=st.integers(-0x7FFF_FFFF, 0x7FFF_FFFF), u16=st.integers(0, 0xFFFE), i16=st.integers(-0x7FFF, 0x7FFF))
def test_words_both_orders(order, x, u32, i32, u16, i16):
    f = struct.unpack(">I", struct.pack(">f", x))[0]
    assert wire.encode("f32", x, 1, order) == words("f32", f, order)
    assert wire.decode("f32", words("f32", f, order), 1, order) == x
    for dtype, v in (("u32", u32), ("i32", i32), ("u16", u16), ("i16", i16)):
        assert wire.encode(dtype, v, 1, order) == words(dtype, v & 0xFFFF_FFFF, order)
        assert wire.decode(dtype, words(dtype, v & 0xFFFF_FFFF, order), 1, order) == v


@pytest.mark.parametrize("order", ["big", "little"])
def test_no_value_markers(order):
    assert wire.encode("u16", None) == [0xFFFF] and wire.encode("i16", None) == [0x8000]
    assert wire.encode("u32", None, 1, order) == [0xFFFF, 0xFFFF]
    assert wire.encode("i32", None, 1, order) == words("i32", 0x8000_0000, order)
    assert math.isnan(struct.unpack(">f", struct.pack(">HH", *words("f32", 0, "big")[:0],
                                                       *(wire.encode("f32", None, 1, "big"))))[0])
    assert wire.decode("f32", wire.encode("f32", None, 1, order), 1, order) is None
    assert wire.encode("u16", math.nan) == [0xFFFF]


@pytest.mark.parametrize("order", ["big", "little"])
def test_a_known_number_beyond_its_register_reads_as_the_register_s_end(order):
    """An FCR of 700 (a tiny gain between surveys a day apart) read "no value", which the map keeps
    for what the controller does not know: it saturates, as a PLC's analogue input does."""
    assert wire.encode("u16", 700, 0.01) == [0xFFFE] and wire.encode("u16", -0.5, 0.01) == [0]
    assert wire.encode("i16", -400, 0.01) == [(-0x7FFF) & 0xFFFF] and wire.encode("i16", 400, 0.01) == [0x7FFF]
    assert wire.encode("u32", 5e9, 1, order) == words("u32", 0xFFFF_FFFE, order)
    assert wire.encode("i32", -1e12, 1, order) == words("i32", -0x7FFF_FFFF & 0xFFFF_FFFF, order)
    assert wire.encode("u16", math.inf) == [0xFFFE] and wire.encode("i16", -math.inf) == [(-0x7FFF) & 0xFFFF]
    assert wire.decode("u16", wire.encode("u16", 70000)) == 0xFFFE       # never wrapped, never the marker
    big = wire.decode("f32", wire.encode("f32", 1e39, 1, order), 1, order)
    assert big == pytest.approx(wire.FLT_MAX) and wire.decode("f32", wire.encode("f32", -math.inf, 1, order), 1,
                                                           order) == -math.inf


@pytest.mark.parametrize("key,value", [("colour", 1), ("word_order", "middle"), ("unit", 0), ("max_connections", 0),
                                       ("idle_timeout_s", -1), ("refresh_s", 0)])
def test_scada_section_is_checked(tmp_path, key, value):
    raw = tomllib.loads((ROOT / "config" / "farm.toml").read_text())
    raw["scada"][key] = value
    p = tmp_path / "farm.toml"
    p.write_text(tomli_w.dumps(raw))
    with pytest.raises(BadInput) as err:
        load_config(p)
    assert f"scada.{key}" in str(err.value), str(err.value)
