"""A config against the ledger it carries on (controller.ledger_config): what the two cannot both be
is refused naming the key, and what changed since the last start is logged once."""
from __future__ import annotations

import logging

import pytest

from controller.config import load_config
from controller.errors import BadInput
from controller.ledger_config import check_against_ledger
from controller.store import Store

DAY = 86_400.0
T = 1_780_300_000.0           # 2026-06-01T07:46:40Z


@pytest.fixture
def farm(tmp_path):
    cfg = load_config("config/farm.toml")
    store = Store(tmp_path / "ledger.db")
    yield cfg, store
    store.close()


def with_(cfg, **top):
    return cfg.model_copy(update=top)


def tanks_with(cfg, i, **changes):
    tanks = list(cfg.tanks)
    tanks[i] = tanks[i].model_copy(update=changes)
    return cfg.model_copy(update={"tanks": tanks})


@pytest.mark.parametrize("harvest, moved_in, refused", [(600, 0, True), (500, 0, False), (600, 100, False),
                                                        (601, 100, True)])
def test_a_stock_its_events_take_below_zero_is_refused_naming_it(farm, harvest, moved_in, refused):
    """T8 stocked 500 in the config while the ledger harvested 600 of it: the stock read -100 and
    status failed for the whole farm, the SCADA froze and housekeeping crashed each farm minute."""
    cfg, store = farm
    i = next(k for k, t in enumerate(cfg.tanks) if t.id == "T8")
    cfg = tanks_with(cfg, i, stock=500)
    if moved_in:
        store.add_stock_event(t=T - 2 * DAY, tank="T1", kind="transfer", count=moved_in, to_tank="T8", who="op")
    store.add_stock_event(t=T - DAY, tank="T8", kind="harvest", count=harvest, to_tank=None, who="op")
    if not refused:
        check_against_ledger(cfg, store, T)
        return
    with pytest.raises(BadInput) as exc:
        check_against_ledger(cfg, store, T)
    msg = str(exc.value)
    assert msg.startswith(f"{cfg.path}: tanks.{i}.stock: 500 fish, but the ledger's stock events take tank 'T8' "
                          f"to {500 + moved_in - harvest} at its harvest of 2026-05-31")
    assert "not today's" in msg


@pytest.mark.parametrize("offset_h, refused", [(1.0, False), (-7.0, False), (-12.0, True)])
def test_a_zone_that_puts_today_before_the_ledger_s_last_farm_day_is_refused(farm, offset_h, refused):
    """utc_offset_h from +1 to -12 after a morning's feeding (2026-06-01 local): today became
    2026-05-31, the day's rations started again from nothing and the fed fish were fed again."""
    cfg, store = farm
    store.set_ration("T1", "2026-06-01", 500.0, 2.0, "survey", T - 3600)
    f = store.add_intent(tank="T1", date="2026-06-01", t=T - 1800, target_g=60, run_s=5, cycles_before=0,
                         source="demand")
    store.close_feed(f.id, "done", 60.0, T - 1790)
    cfg = with_(cfg, utc_offset_h=offset_h)
    if not refused:
        check_against_ledger(cfg, store, T)
        return
    with pytest.raises(BadInput) as exc:
        check_against_ledger(cfg, store, T)
    assert str(exc.value).startswith(f"{cfg.path}: utc_offset_h: -12 h makes today 2026-05-31, before the "
                                     "ledger's last farm day 2026-06-01")


def test_what_changed_since_the_last_start_is_logged_once(farm, caplog):
    cfg, store = farm
    with caplog.at_level(logging.WARNING, logger="fishfarm.config"):
        check_against_ledger(cfg, store, T)                       # the first start: nothing to compare
        assert not caplog.records
        check_against_ledger(cfg, store, T + 60)                  # the same config again: silent
        assert not caplog.records
        changed = tanks_with(cfg, 2, stock=cfg.tanks[2].stock + 100, species="salmo_salar")
        changed = changed.model_copy(update={"tanks": [changed.tanks[1], changed.tanks[0], *changed.tanks[2:]],
                                             "utc_offset_h": 2.0})
        check_against_ledger(changed, store, T + 120)
        said = [r.getMessage() for r in caplog.records]
        check_against_ledger(changed, store, T + 180)             # said once: remembered since
    ids = [t.id for t in cfg.tanks]
    assert len(said) == 4 and len(caplog.records) == 4, said
    assert said[0].startswith(f"config: tanks {ids} -> {[ids[1], ids[0], *ids[2:]]}: the SCADA's tank blocks")
    assert said[1].startswith(f"config: utc_offset_h {cfg.utc_offset_h:g} -> 2: the farm day's start changed")
    assert said[2].startswith(f"config: tank {ids[2]}: stock {cfg.tanks[2].stock} -> {cfg.tanks[2].stock + 100}")
    assert said[3] == f"config: tank {ids[2]}: species sparus_aurata -> salmo_salar: its surveys so far were of " \
                      "sparus_aurata"


def test_a_ledger_that_cannot_be_written_at_start_is_not_a_crash(farm, caplog):
    """A full disk at start is the ledger alarm's to tell while the controller runs on: remembering
    the config (a write) must not end the start."""
    from tests.controller.test_ledger_unwritable import disk_full
    cfg, store = farm
    with caplog.at_level(logging.WARNING, logger="fishfarm.config"), disk_full(store):
        check_against_ledger(cfg, store, T)
    assert any("not remembered for the next start" in r.getMessage() for r in caplog.records)
    check_against_ledger(cfg, store, T + 60)                    # written once it can be
    assert store.db.execute("SELECT COUNT(*) FROM config_seen").fetchone()[0] > 0


def test_devices_reordered_move_the_alarm_slots_and_are_said(farm, caplog):
    """The SCADA's alarm slots follow the devices in config order: a reorder moves them (sorted, the
    comparison saw no change)."""
    cfg, store = farm
    check_against_ledger(cfg, store, T)
    names = list(cfg.devices)
    swapped = cfg.model_copy(update={"devices": {n: cfg.devices[n] for n in [names[1], names[0], *names[2:]]}})
    with caplog.at_level(logging.WARNING, logger="fishfarm.config"):
        check_against_ledger(swapped, store, T + 60)
    assert [r.getMessage() for r in caplog.records] == [
        f"config: devices {names} -> {[names[1], names[0], *names[2:]]}: the SCADA's alarm slots moved"]
