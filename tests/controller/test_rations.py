import pytest

from controller.config import load_config
from controller.feeding.rations import Rations, load_species
from controller.store import Store

T = 1_780_000_000.0  # 2026-05-28 20:26 UTC


@pytest.fixture
def rations(tmp_path):
    cfg = load_config("config/farm.toml")
    return Rations(cfg, load_species(), Store(tmp_path / "r.db"))


def test_ration_is_biomass_times_table_rate(rations):
    tank = rations.cfg.tank("T1")                 # 2400 fish of 18 g: 15-40 g class, 2.6 %/day
    r = rations.today("T1", T)
    assert r.grams == pytest.approx(tank.stock * tank.mean_weight_g * 0.026)
    assert r.pellet_mm == 2.0 and r.fed_g == 0


def test_portion_never_exceeds_what_is_left(rations):
    store = rations.store
    r = rations.today("T1", T)
    f = store.add_intent(tank="T1", date=r.date, t=T, target_g=r.grams - 30, run_s=1, cycles_before=0,
                         source="demand")
    store.close_feed(f.id, "done", r.grams - 30, T)
    portion = rations.portion("T1", T, overshoot=0.15)
    assert portion == pytest.approx(30 / 1.15)
    assert portion * 1.15 <= rations.today("T1", T).left_g + 1e-9


def test_nothing_below_min_portion(rations):
    r = rations.today("T1", T)
    rations.set("T1", T, r.fed_g + 4.0, "operator")
    assert rations.portion("T1", T, 0.15) == 0.0


def test_day_rolls_over_at_local_midnight(rations):
    # utc_offset_h = 1 in the demo farm: 23:30 UTC is already tomorrow
    assert rations.date(1_780_011_000.0) != rations.date(1_780_011_000.0 - 3600)


def test_bad_species_file(tmp_path):
    from controller.errors import BadInput
    p = tmp_path / "s.toml"
    p.write_text('[x]\nname = "x"\na = -1\nb = 3\nfeeding = [{ up_to_g = 1, rate_pct = 1, pellet_mm = 1 }]\n')
    with pytest.raises(BadInput, match=r"s.toml: x.a: "):
        load_species(p)
