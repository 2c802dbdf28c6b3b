"""A survey another process writes into the ledger is taken up by the running controller: the
ration planned again and published, the survey published, the grading alarm raised or cleared."""
from __future__ import annotations

import json
import math

import pytest

from controller.alarms import Alarms
from controller.config import load_config
from controller.feeding.rations import Rations, load_species
from controller.store import Store
from controller.surveys.watch import SurveyWatch
from devices.clock import ManualClock

T = 1_780_000_000.0


class Published(list):
    def __call__(self, suffix, payload, reliable=False):
        self.append((suffix, payload))

    def on(self, suffix):
        return [p for s, p in self if s == suffix]


@pytest.fixture
def farm(tmp_path):
    cfg = load_config("config/farm.toml")
    store = Store(tmp_path / "ledger.db")
    published = Published()
    clock = ManualClock(T)
    alarms = Alarms(store, published, clock)
    rations = Rations(cfg, load_species(), store)
    return cfg, store, rations, alarms, published, SurveyWatch(cfg, store, rations, alarms, published)


def test_a_new_survey_sets_the_ration_is_published_once_and_a_spread_stock_raises_grading(farm, tmp_path):
    cfg, store, rations, alarms, published, watch = farm
    before = rations.today("T1", T)
    assert watch.check(T) == []
    out = tmp_path / "out.json"
    out.write_text(json.dumps({"species": "sparus_aurata", "count": 4, "fish": [], "weight_g": {"mean": 42.5}}))
    other = Store(tmp_path / "ledger.db")                # another process: fishfarm survey --tank T1
    other.add_survey("T1", T + 10, "sparus_aurata", str(out), [10.0, 11.0, 13.0, 15.0], [20.0, 30.0, 40.0, 80.0])
    other.close()
    assert watch.check(T + 20) == ["T1"] and watch.check(T + 25) == []         # taken up once
    [ration] = published.on("tank/T1/ration")
    assert ration["basis"] == "survey" and ration["grams"] != pytest.approx(before.grams)
    assert ration["grams"] == pytest.approx(rations.today("T1", T + 20).grams, abs=0.05)
    [survey] = published.on("tank/T1/survey")
    assert survey["count"] == 4 and survey["weight_g"] == {"mean": 42.5} and survey["t"].startswith("2026-")
    cv = 100 * (sum((w - 42.5) ** 2 for w in (20, 30, 40, 80)) / 3) ** 0.5 / 42.5     # 61 %: above 30 %
    # the weight it rests on (10 s grown) and its 95 % half-width: 1.96 · CV / √n on the log scale
    assert ration["mean_weight_g"] == pytest.approx(42.5, rel=1e-4)
    assert ration["weight_ci_pct"] == pytest.approx(100 * math.expm1(1.96 * cv / 100 / 2), abs=0.01)
    [alarm] = [a for a in alarms.active.of("grading/T1")]
    assert f"weight CV {cv:.1f} %" in alarm.text and "grade the stock" in alarm.text
    # a later, even survey clears it; its OUT.json is gone: the ledger's summary is published
    store.add_survey("T1", T + 100, "sparus_aurata", str(tmp_path / "gone.json"), [12.0, 12.0], [30.0, 31.0])
    assert watch.check(T + 200) == ["T1"] and list(alarms.active.of("grading/T1")) == []
    latest = published.on("tank/T1/survey")[-1]
    assert latest["count"] == 2 and latest["weight_g"]["mean"] == pytest.approx(30.5) and "fish" not in latest


def test_an_operator_s_ration_stands_and_a_survey_not_yet_taken_is_not_seen_early(farm):
    cfg, store, rations, alarms, published, watch = farm
    rations.set("T2", T, 777.0, "operator")
    store.add_survey("T2", T + 50, "sparus_aurata", "x", [10.0], [25.0])
    assert watch.check(T + 10) == []                      # stamped later than now
    assert watch.check(T + 60) == ["T2"]
    assert published.on("tank/T2/ration")[-1]["grams"] == 777.0
    assert published.on("tank/T2/ration")[-1]["basis"] == "operator"


def test_the_figures_between_the_last_two_surveys_are_published_and_shown_in_status(farm):
    import math
    from types import SimpleNamespace

    from controller.status import _weights
    cfg, store, rations, alarms, published, watch = farm
    day = 86_400.0
    store.add_survey("T1", T, "sparus_aurata", "a", [10.0] * 3, [20.0] * 3)
    f = store.add_intent(tank="T1", date="d", t=T + day, target_g=900, run_s=60, cycles_before=0, source="demand")
    store.close_feed(f.id, "done", 900.0, T + day + 60)
    store.add_survey("T1", T + 10 * day, "sparus_aurata", "b", [11.0] * 3, [25.0] * 3)
    assert watch.check(T + 10 * day + 5) == ["T1"]
    [fig] = published.on("tank/T1/figures")
    stock = cfg.tank("T1").stock
    assert fig["sgr_pct_day"] == pytest.approx(100 * math.log(25 / 20) / 10)
    assert fig["feed_g"] == 900 and fig["fcr"] == pytest.approx(900 / (stock * 25 - stock * 20))
    assert fig["mean_weight_g"] == 25 and fig["weight_cv_pct"] == 0 and fig["grading"] is False
    c = SimpleNamespace(rations=rations, surveys=watch)
    shown = _weights(c, "T1", T + 10 * day + 5)
    assert shown["mean_weight_g"] == 25 and shown["ration_basis"] == "survey"
    assert shown["sgr_pct_day"] == fig["sgr_pct_day"] and shown["fcr"] == fig["fcr"]
    # two surveys: the fitted growth is the interval's, and so are its FCR's feed and gain
    assert fig["fit"]["sgr_pct_day"] == pytest.approx(fig["sgr_pct_day"]) and fig["fit"]["surveys"] == 2
    assert fig["fit"]["fcr"] == pytest.approx(fig["fcr"]) and fig["fit"]["fcr_ci"][0] < fig["fcr"]
    assert shown["sgr_fit_pct_day"] == fig["fit"]["sgr_pct_day"] and shown["fcr_fit"] == fig["fit"]["fcr"]
    # no fish died: the net FCR is the biological one, published and shown beside it
    assert fig["fcr_net"] == fig["fcr"] and shown["fcr_net_fit"] == pytest.approx(fig["fit"]["fcr"])
    assert shown["weight_ci_pct"] > 0
    never = _weights(c, "T4", T)
    assert never["ration_basis"] == "config" and never["mean_weight_g"] == cfg.tank("T4").mean_weight_g
    # an operator's ration: status says so, as the ration's topic does
    rations.set("T1", T + 10 * day + 6, 500.0, "operator")
    set_by_hand = _weights(c, "T1", T + 10 * day + 7)
    assert set_by_hand["ration_basis"] == "operator" == rations.payload("T1", T + 10 * day + 7)["basis"]
    assert set_by_hand["mean_weight_g"] == 25
    assert never["last_survey_t"] is None and never["fcr"] is None


def test_a_survey_that_counts_no_fish_is_published_warns_and_plans_nothing_until_one_counts_again(farm, tmp_path):
    """Cameras blocked or fouled, the lights off, turbid water: the survey is a result (count 0), the
    operator is told, and the ration keeps resting on the last survey that counted fish."""
    cfg, store, rations, alarms, published, watch = farm
    store.add_survey("T1", T, "sparus_aurata", "a", [10.0, 11.0], [20.0, 24.0])
    assert watch.check(T + 1) == ["T1"]
    ration, figures = published.on("tank/T1/ration")[-1], published.on("tank/T1/figures")[-1]
    out = tmp_path / "empty.json"
    out.write_text(json.dumps({"species": "sparus_aurata", "count": 0, "fish": [], "frames": 100}))
    store.add_survey("T1", T + 100, "sparus_aurata", str(out), [], [])
    before = len(published)
    assert watch.check(T + 200) == [] and watch.check(T + 300) == []
    new = published[before:]
    assert [s for s, _ in new] == ["tank/T1/survey", "alarm/survey/T1"]     # once; no ration, no figures
    assert new[0][1]["count"] == 0 and new[0][1]["frames"] == 100 and new[0][1]["t"].startswith("2026-")
    [alarm] = alarms.active.of("survey/T1")
    assert alarm.kind == "no_fish" and alarm.severity == "warning"
    assert "counted no fish" in alarm.text
    assert "rests on the surveys that counted fish (newest 2026-05-28T" in alarm.text
    assert rations.today("T1", T + 300).grams == pytest.approx(ration["grams"], abs=0.05)
    assert watch.figures["T1"] == figures
    # a second empty one is published too; one that counts fish clears the warning and is planned from
    store.add_survey("T1", T + 400, "sparus_aurata", "gone.json", [], [])
    assert watch.check(T + 500) == [] and published.on("tank/T1/survey")[-1]["t"] > new[0][1]["t"]
    store.add_survey("T1", T + 600, "sparus_aurata", "b", [12.0], [30.0])
    assert watch.check(T + 700) == ["T1"] and list(alarms.active.of("survey/T1")) == []
    assert published.on("tank/T1/ration")[-1]["grams"] != pytest.approx(ration["grams"])


def test_a_tank_whose_every_survey_counted_no_fish_warns_from_start_and_rests_on_the_config(farm):
    cfg, store, rations, alarms, published, watch = farm
    store.add_survey("T3", T, "sparus_aurata", "x", [], [])
    assert watch.check(T + 10) == []
    [alarm] = alarms.active.of("survey/T3")
    assert "rests on the configured weight" in alarm.text
    assert published.on("tank/T3/ration") == [] and len(published.on("tank/T3/survey")) == 1
    # a restarted controller: the warning still stands, the survey is published again, nothing else
    again = SurveyWatch(cfg, store, rations, alarms, published)
    assert again.check(T + 20) == [] and len(published.on("tank/T3/survey")) == 2
    assert len(list(alarms.active.of("survey/T3"))) == 1


def test_a_survey_off_the_growth_so_far_warns_in_the_figures_and_an_alarm_until_one_follows_it(farm):
    """Weekly surveys on 20·e^(0.02·day), then one 40 % heavier (a camera knocked out of its
    calibration reads every fish long): flagged, its ration follows it; the next on the curve clears."""
    cfg, store, rations, alarms, published, watch = farm
    day = 86_400.0

    def survey(d, factor=1.0):
        mean = 20.0 * math.exp(0.02 * d) * factor
        store.add_survey("T2", T + d * day, "sparus_aurata", "x", [10.0] * 40,
                         [mean * (1 + 0.15 * (1 if i % 2 else -1)) for i in range(40)])
        return watch.check(T + d * day + 1)
    for d in (0, 7, 14):
        assert survey(d) == ["T2"]
    assert published.on("tank/T2/figures")[-1]["against_growth"]["off"] is False
    assert list(alarms.active.of("survey/T2")) == []
    assert survey(21, 1.4) == ["T2"]
    fig = published.on("tank/T2/figures")[-1]
    assert fig["against_growth"]["off"] is True and fig["against_growth"]["off_pct"] == pytest.approx(40.0)
    [alarm] = alarms.active.of("survey/T2")
    assert alarm.kind == "off_growth"
    assert "reads 40.0 % heavier than the growth of the 3 surveys before it" in alarm.text
    assert published.on("tank/T2/ration")[-1]["mean_weight_g"] > 20.0 * math.exp(0.02 * 21)   # followed
    survey(28)
    assert list(alarms.active.of("survey/T2")) == []


@pytest.fixture
def weighing(tmp_path):
    """The farm's ``[surveys] min_weighed_fish`` (10) in force, as the controller opens its ledger."""
    cfg = load_config("config/farm.toml")
    assert cfg.surveys.min_weighed_fish == 10
    store = Store(tmp_path / "ledger.db", cfg.surveys.min_weighed_fish)
    published = Published()
    alarms = Alarms(store, published, ManualClock(T))
    rations = Rations(cfg, load_species(), store)
    return cfg, store, rations, alarms, published, SurveyWatch(cfg, store, rations, alarms, published)


def even(n: int, mean: float) -> tuple[list[float], list[float]]:
    return [10.0] * n, [mean * (1 + 0.2 * (1 if i % 2 else -1)) for i in range(n)]


@pytest.mark.parametrize("few", [1, 3, 9])
def test_a_survey_of_too_few_fish_warns_and_plans_nothing_until_one_weighs_the_tank_again(weighing, few):
    """Three fish of two thousand (a reef behind them hid the rest) read a tank 25 % light: the survey
    is a result, published and warned of (``few_fish``), but the ration keeps resting on the last
    survey that weighs the tank; a survey of no fish after it turns the warning into ``no_fish``; one
    of ``min_weighed_fish`` fish weighs the tank again, clears both and is planned from."""
    cfg, store, rations, alarms, published, watch = weighing
    store.add_survey("T1", T, "sparus_aurata", "a", *even(40, 20.0))
    assert watch.check(T + 1) == ["T1"]
    ration, figures = published.on("tank/T1/ration")[-1], published.on("tank/T1/figures")[-1]
    store.add_survey("T1", T + 100, "sparus_aurata", "few.json", *even(few, 15.0))
    before = len(published)
    assert watch.check(T + 200) == [] and watch.check(T + 300) == []
    new = published[before:]
    assert [s for s, _ in new] == ["tank/T1/survey", "alarm/survey/T1"]       # once; no ration, no figures
    assert new[0][1]["count"] == few
    [alarm] = alarms.active.of("survey/T1")
    assert alarm.kind == "few_fish" and alarm.severity == "warning"
    assert f"counted {few} fish, fewer than the 10 that weigh the tank" in alarm.text
    assert "rests on the surveys that counted fish (newest 2026-05-28T" in alarm.text
    assert rations.today("T1", T + 300).grams == pytest.approx(ration["grams"], abs=0.05)
    assert rations.payload("T1", T + 300)["mean_weight_g"] == pytest.approx(20.0, rel=1e-3)
    assert watch.figures["T1"] == figures
    store.add_survey("T1", T + 400, "sparus_aurata", "none.json", [], [])
    assert watch.check(T + 500) == []
    assert [a.kind for a in alarms.active.of("survey/T1")] == ["no_fish"]
    store.add_survey("T1", T + 600, "sparus_aurata", "b", *even(10, 24.0))
    assert watch.check(T + 700) == ["T1"] and list(alarms.active.of("survey/T1")) == []
    assert published.on("tank/T1/ration")[-1]["mean_weight_g"] == pytest.approx(24.0, rel=0.01)


def test_a_tank_whose_only_survey_counted_a_handful_rests_on_the_configured_weight(weighing):
    cfg, store, rations, alarms, published, watch = weighing
    store.add_survey("T3", T, "sparus_aurata", "x", *even(4, 200.0))
    assert watch.check(T + 10) == []
    [alarm] = alarms.active.of("survey/T3")
    assert alarm.kind == "few_fish" and "rests on the configured weight" in alarm.text
    payload = rations.payload("T3", T + 10)
    assert payload["basis"] == "config" and payload["mean_weight_g"] == cfg.tank("T3").mean_weight_g
