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


# -- rations from surveys -------------------------------------------------------------------------
DAY = 86_400.0


def species_rate(rations, w: float) -> float:
    """The species file's rate for a fish of ``w`` g, read here from its rows."""
    rows = rations.species["sparus_aurata"].feeding
    return next((r.rate_pct for r in rows if w < r.up_to_g), rows[-1].rate_pct)


def test_a_fresh_survey_feeds_each_fish_by_its_own_class(rations):
    weights = [4.0, 12.0, 12.0, 30.0, 90.0]                     # five classes of the species' table
    rations.store.add_survey("T1", T, "sparus_aurata", "test", [8.0] * 5, weights)    # not grown yet
    r = rations.today("T1", T)
    stock = rations.cfg.tank("T1").stock
    assert r.source == "survey"
    assert r.grams == pytest.approx(stock * sum(w * species_rate(rations, w) for w in weights) / 5 / 100)
    assert r.pellet_mm == 1.2                                   # the smallest quarter: 12 g fish's


def test_a_stale_survey_is_projected_at_the_growth_measured_between_the_last_two(rations):
    first = [10.0, 14.0, 18.0]
    second = [w * 1.25 for w in first]                         # +25 % in 10 days
    rations.store.add_survey("T1", T - 40 * DAY, "sparus_aurata", "a", [8.0] * 3, first)
    rations.store.add_survey("T1", T - 30 * DAY, "sparus_aurata", "b", [9.0] * 3, second)
    plan = rations.plan("T1", T)                                # 30 days > 14: projected
    grown = [w * 1.25 ** 3 for w in second]                    # the same growth for three more periods
    stock = rations.cfg.tank("T1").stock
    assert plan.source == "projected" and "fitted to 2 surveys" in plan.note
    assert plan.mean_weight_g == pytest.approx(sum(grown) / 3)
    assert plan.grams == pytest.approx(stock * sum(w * species_rate(rations, w) for w in grown) / 3 / 100)


def test_a_stale_lone_survey_grows_at_the_chart_s_rate_or_says_it_is_not_projected(rations, tmp_path):
    import math
    import tomllib
    rations.store.add_survey("T1", T - 30 * DAY, "sparus_aurata", "a", [8.0] * 2, [20.0, 30.0])
    plan = rations.plan("T1", T)
    chart = tomllib.loads(open("config/feeding/sparus_aurata.toml").read())   # the demo's, at 22 degC
    col = chart["temperatures_c"].index(rations.cfg.feeding.water_temp_c)
    w = 25.0
    for _ in range(30):                                 # a day at a time, at the class's SGR
        row = next(c for c in chart["classes"] if w < c["up_to_g"])
        w *= math.exp(row["sgr_pct"][col] / 100)
    assert plan.source == "projected" and "the feeding chart's growth" in plan.note
    assert plan.mean_weight_g == pytest.approx(w)
    bare = rations.cfg.model_copy(update={"feeding": rations.cfg.feeding.model_copy(update={"tables": []})})
    plain = Rations(bare, load_species(), rations.store)       # the species rows give no growth
    plan = plain.plan("T1", T)
    assert plan.source == "projected" and "not projected" in plan.note and plan.mean_weight_g == 25.0


def test_a_survey_after_the_time_asked_is_not_used(rations):
    rations.store.add_survey("T1", T + 3600, "sparus_aurata", "later", [8.0], [90.0])
    assert rations.plan("T1", T).source == "config"


def test_a_new_survey_plans_the_day_again_but_an_operator_s_ration_stands(rations):
    before = rations.today("T1", T)
    rations.store.add_survey("T1", T + 60, "sparus_aurata", "new", [8.0] * 2, [30.0, 30.0])
    after = rations.replan("T1", T + 60)
    assert before.source == "config" and after.source == "survey" and after.grams != before.grams
    rations.set("T1", T + 120, 123.0, "operator")
    assert rations.replan("T1", T + 180).grams == 123.0


def test_a_survey_after_the_day_s_feeding_never_sets_its_ration_below_what_was_fed(rations):
    before = rations.today("T1", T)
    fed = 0.8 * before.grams
    f = rations.store.add_intent(tank="T1", date=before.date, t=T + 10, target_g=fed, run_s=9, cycles_before=0,
                                 source="demand")
    rations.store.close_feed(f.id, "done", fed, T + 20)
    rations.store.add_survey("T1", T + 60, "sparus_aurata", "light", [8.0] * 2, [2.0, 2.0])   # fish far lighter
    after = rations.replan("T1", T + 60)
    assert after.source == "survey" and after.grams == pytest.approx(fed) and after.left_g == 0
    tomorrow = rations.today("T1", T + 86_400)
    assert tomorrow.grams < 0.5 * before.grams                     # the next day follows the survey


def test_a_chart_is_read_at_the_tank_s_water_temperature(tmp_path):
    import tomli_w

    from controller.config import load_config
    chart = {"species": "sparus_aurata", "source": "test", "temperatures_c": [10.0, 20.0],
             "classes": [{"up_to_g": 1e9, "pellet_mm": 2.0, "rate_pct": [1.0, 3.0]}]}
    (tmp_path / "chart.toml").write_text(tomli_w.dumps(chart))
    cfg = load_config("config/farm.toml")
    cfg = cfg.model_copy(update={"path": str(tmp_path / "farm.toml"),
                                 "feeding": cfg.feeding.model_copy(update={"tables": ["chart.toml"],
                                                                           "water_temp_c": 15.0})})
    (tmp_path / "farm.toml").write_text("")
    tanks = [t.model_copy(update={"water_temp_c": 12.0}) if t.id == "T2" else t for t in cfg.tanks]
    cfg = cfg.model_copy(update={"tanks": tanks})
    r = Rations(cfg, load_species(), Store(tmp_path / "r.db"))
    t1, t2 = cfg.tank("T1"), cfg.tank("T2")
    assert r.today("T1", T).grams == pytest.approx(t1.stock * t1.mean_weight_g * 2.0 / 100)     # 15 degC
    assert r.today("T2", T).grams == pytest.approx(t2.stock * t2.mean_weight_g * 1.4 / 100)     # 12 degC
    twice = cfg.model_copy(update={"feeding": cfg.feeding.model_copy(update={"tables": ["chart.toml"] * 2})})
    from controller.errors import BadInput
    with pytest.raises(BadInput, match=r"farm.toml: feeding.tables.1: a second table for 'sparus_aurata'"):
        Rations(twice, load_species(), Store(tmp_path / "s.db"))


def test_a_chart_is_found_beside_farm_toml_first_then_among_those_shipped(tmp_path):
    import tomli_w

    from controller.config import load_config
    from controller.errors import BadInput
    cfg = load_config("config/farm.toml")
    moved = cfg.model_copy(update={"path": str(tmp_path / "farm.toml")})
    (tmp_path / "farm.toml").write_text("")
    shipped = Rations(moved, load_species(), Store(tmp_path / "a.db")).tables["sparus_aurata"]
    assert shipped.source.startswith("fishfarm example")
    (tmp_path / "feeding").mkdir()
    own = {"species": "sparus_aurata", "source": "our feed maker", "temperatures_c": [20.0],
           "classes": [{"up_to_g": 1e9, "pellet_mm": 3.0, "rate_pct": [1.0]}]}
    (tmp_path / "feeding" / "sparus_aurata.toml").write_text(tomli_w.dumps(own))
    assert Rations(moved, load_species(), Store(tmp_path / "b.db")).tables["sparus_aurata"].source == "our feed maker"
    missing = moved.model_copy(update={"feeding": moved.feeding.model_copy(update={"tables": ["nowhere.toml"]})})
    with pytest.raises(BadInput, match="nowhere.toml: no such file"):
        Rations(missing, load_species(), Store(tmp_path / "c.db"))


def test_the_ration_rests_on_the_surveys_pooled_not_on_the_newest_alone(rations):
    """Three weekly surveys on a 2 %/day growth, the newest reading 10 % heavy, each of the same
    spread and count: with a constant-SGR fit the ration's mean weight three days on is the least
    squares line through the three ln means (numpy's polyfit here), not the newest mean grown."""
    import numpy as np
    cfg = rations.cfg.model_copy(update={"feeding": rations.cfg.feeding.model_copy(update={"growth_model": "sgr"})})
    pooled = Rations(cfg, load_species(), rations.store)
    spread = np.array([0.8, 0.9, 1.0, 1.1, 1.2])                 # the same CV in every survey
    days = np.array([0.0, 7.0, 14.0])
    means = 20 * np.exp(0.02 * days) * np.array([1.0, 1.0, 1.1])
    for d, m in zip(days, means, strict=True):
        pooled.store.add_survey("T1", T + d * DAY, "sparus_aurata", f"s{d}", [10.0] * 5, list(m * spread))
    slope, icpt = np.polyfit(days, np.log(means), 1)
    plan = pooled.plan("T1", T + 17 * DAY)
    assert plan.source == "survey" and "fitted to 3 surveys" in plan.note
    assert plan.mean_weight_g == pytest.approx(np.exp(icpt + slope * 17))
    assert plan.mean_weight_g < means[-1] * np.exp(slope * 3)    # the heavy reading is not taken whole
    assert plan.growth["model"] == "sgr" and plan.growth["weight_ci_pct"] > 0


def test_a_tank_emptied_and_stocked_again_is_not_fed_as_the_fish_that_left(rations):
    """A full harvest, then 100 fish of 18 g moved in from T1: they were fed as the 752 g fish
    harvested (pellet 4.5 mm). They are fed as T1's survey saw them, grown at the chart's rate; a
    tank emptied with nobody moved in since goes back to the config's weight."""
    store, cfg = rations.store, rations.cfg
    store.add_survey("T4", T, "sparus_aurata", "big", [30.0] * 4, [700.0, 740.0, 760.0, 800.0])
    store.add_survey("T1", T + 3600, "sparus_aurata", "small", [10.0] * 4, [16.0, 17.0, 19.0, 20.0])
    assert rations.plan("T4", T + 7200).mean_weight_g > 700
    store.add_stock_event(t=T + 86400, tank="T4", kind="harvest", count=cfg.tank("T4").stock, to_tank=None, who="t")
    plan = rations.plan("T4", T + 86400 + 60)
    assert plan.source == "config" and plan.mean_weight_g == cfg.tank("T4").mean_weight_g
    assert "are gone" in plan.note
    store.add_stock_event(t=T + 2 * 86400, tank="T1", kind="transfer", count=100, to_tank="T4", who="t")
    plan = rations.plan("T4", T + 2 * 86400 + 60)
    assert plan.source == "projected" and "moved in from T1" in plan.note
    assert 18.0 <= plan.mean_weight_g <= 18.0 * 1.1            # T1's 18 g fish, two days' chart growth
    assert plan.pellet_mm <= 2.0
    store.add_survey("T4", T + 3 * 86400, "sparus_aurata", "new", [10.0] * 4, [18.0, 19.0, 21.0, 22.0])
    plan = rations.plan("T4", T + 3 * 86400 + 60)               # its own survey again, and only it
    assert plan.source == "survey" and plan.mean_weight_g == pytest.approx(20.0, rel=0.05)


@pytest.mark.parametrize("surveyed", [False, True])
def test_fish_moved_into_a_tank_that_still_holds_fish_are_fed_at_their_own_weight(rations, surveyed):
    """200 fish of ~204 g moved from T1 into T2's 24 g fish were fed as 24 g fish: the ration rested
    on the config's weight for every fish. Each group is now fed in its share of the stock at its own
    weight (T2's own: its newest survey or the config); a survey of T2 after the transfer sees them all."""
    from controller.feeding.feeding_table import ration_from_weights
    store, cfg = rations.store, rations.cfg
    big = [190.0, 200.0, 210.0, 216.0]
    store.add_survey("T1", T, "sparus_aurata", "T1", [20.0] * 4, big)
    own = [22.0, 23.0, 25.0, 26.0]
    if surveyed:
        store.add_survey("T2", T + 60, "sparus_aurata", "T2", [11.0] * 4, own)
    store.add_stock_event(t=T + 3600, tank="T1", kind="transfer", count=200, to_tank="T2", who="t")
    t = T + 3600 + 60
    stock, temp = rations.stock("T2"), rations.water_temp_c("T2")
    table = rations.tables["sparus_aurata"]
    mine = own if surveyed else [cfg.tank("T2").mean_weight_g]
    plan = rations.plan("T2", t)
    # each group alone, through the public formula, grown as the plan grows them (an hour: ~0)
    expected = (ration_from_weights(mine, stock - 200, temp, table).grams
                + ration_from_weights(big, 200, temp, table).grams)
    assert plan.grams == pytest.approx(expected, rel=0.01)
    assert plan.mean_weight_g == pytest.approx(((stock - 200) * sum(mine) / len(mine) + 200 * 204.0) / stock,
                                               rel=0.01)
    assert "200 fish moved in from T1" in plan.note
    store.add_survey("T2", T + 7200, "sparus_aurata", "after", [11.0] * 4, own)      # sees them all
    after = rations.plan("T2", T + 7200 + 60)
    assert "moved in" not in after.note and after.mean_weight_g == pytest.approx(24.0, rel=0.01)
