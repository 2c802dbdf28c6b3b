"""Feeding tables as the operator loads them, and the rations a survey's fish call for.

Expected figures are worked out here from the module's words (each fish fed by its own class;
rates linear in temperature between columns, the nearest column beyond; the pellet of the
smallest quarter), not from the code."""
from __future__ import annotations

import math

import numpy as np
import pytest
import tomli_w
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.feeding.feeding_table import (
    FeedingTable,
    load_feeding_table,
    project_weight,
    ration_from_weights,
    table_from_species,
)
from controller.feeding.rations import load_species
from devices.errors import BadInput

TABLE = {
    "species": "sparus_aurata",
    "source": "test chart",
    "temperatures_c": [14.0, 18.0, 22.0],
    "classes": [
        {"up_to_g": 5.0, "pellet_mm": 0.8, "rate_pct": [2.0, 4.0, 6.0], "sgr_pct": [1.0, 2.0, 3.0]},
        {"up_to_g": 50.0, "pellet_mm": 2.0, "rate_pct": [1.0, 2.0, 3.0], "sgr_pct": [0.5, 1.0, 1.5]},
        {"up_to_g": 500.0, "pellet_mm": 4.5, "rate_pct": [0.5, 1.0, 1.5]},
    ],
}


def write(tmp_path, data) -> str:
    path = tmp_path / "table.toml"
    path.write_text(tomli_w.dumps(data))
    return str(path)


def table(**changes) -> FeedingTable:
    return FeedingTable.model_validate({**TABLE, **changes})


def test_a_table_file_loads_and_its_lookups_follow_the_chart(tmp_path):
    t = load_feeding_table(write(tmp_path, TABLE))
    assert t.rate_pct(3.0, 18.0) == 4.0 and t.rate_pct(20.0, 22.0) == 3.0
    assert t.rate_pct(3.0, 16.0) == pytest.approx(3.0) and t.rate_pct(3.0, 21.0) == pytest.approx(5.5)
    assert t.rate_pct(3.0, 8.0) == 2.0 and t.rate_pct(3.0, 30.0) == 6.0       # beyond: nearest column
    assert t.rate_pct(5.0, 18.0) == 2.0                                       # up_to_g is exclusive
    assert t.rate_pct(9000.0, 18.0) == 1.0                                    # past the last class: the last
    assert list(t.pellet_mm([1, 4.99, 5, 49, 50, 1e6])) == [0.8, 0.8, 2.0, 2.0, 4.5, 4.5]
    assert t.sgr_pct(3.0, 20.0) == pytest.approx(2.5) and t.sgr_pct(100.0, 20.0) is None


@pytest.mark.parametrize(("change", "key", "fault"), [
    ({"source": None}, "source", ""),
    ({"source": "  "}, "source", "must name"),
    ({"colour": "red"}, "colour", "unknown key"),
    ({"temperatures_c": [18.0, 14.0, 22.0]}, "temperatures_c", "increase strictly"),
    ({"temperatures_c": [14.0, 18.0, 60.0]}, "temperatures_c", "-5..40"),
    ({"classes": [TABLE["classes"][1], TABLE["classes"][0]]}, "(top level)", "up_to_g must increase"),
    ({"classes": [{**TABLE["classes"][0], "rate_pct": [1.0, 2.0]}]}, "classes.0.rate_pct", "has 2 values"),
    ({"classes": [{**TABLE["classes"][0], "sgr_pct": [1.0]}]}, "classes.0.sgr_pct", "has 1 values"),
    ({"classes": [{**TABLE["classes"][0], "rate_pct": [1.0, -2.0, 1.0]}]}, "classes.0", "rate_pct must lie"),
    ({"classes": [{**TABLE["classes"][0], "pellet_mm": 0}]}, "classes.0.pellet_mm", "greater than 0"),
    ({"classes": []}, "classes", "at least 1"),
])
def test_a_bad_table_is_refused_naming_file_and_key(tmp_path, change, key, fault):
    data = {k: v for k, v in {**TABLE, **change}.items() if v is not None}
    path = write(tmp_path, data)
    with pytest.raises(BadInput) as err:
        load_feeding_table(path)
    text = str(err.value)
    assert text.startswith(path) and f": {key}" in text and fault in text and "\n" not in text


def test_each_fish_is_fed_by_its_own_class():
    # 100 fish measured, half 4 g (class 1: 4 %) and half 10 g (class 2: 2 %) at 18 degC, in a tank of 3000
    w = np.r_[np.full(50, 4.0), np.full(50, 10.0)]
    plan = ration_from_weights(w, 3000, 18.0, table())
    assert plan.grams == pytest.approx(3000 * (4.0 * 0.04 + 10.0 * 0.02) / 2)
    assert plan.biomass_g == pytest.approx(3000 * 7.0) and plan.mean_weight_g == pytest.approx(7.0)
    assert plan.rate_pct == pytest.approx(100 * plan.grams / plan.biomass_g)
    # the mean weight alone (7 g: class 2 at 2 %) would have fed 3000 x 7 x 2 % = 420 g, not 540
    assert plan.grams == pytest.approx(540.0)
    assert plan.pellet_mm == 0.8 and plan.pellet_share == 0.5          # the small half sets the pellet


def test_the_pellet_suits_the_smallest_quarter():
    w = np.r_[np.full(20, 4.0), np.full(80, 30.0)]                       # 20 % small: the quarter is big
    assert ration_from_weights(w, 100, 18.0, table()).pellet_mm == 2.0
    w = np.r_[np.full(30, 4.0), np.full(70, 30.0)]
    plan = ration_from_weights(w, 100, 18.0, table())
    assert plan.pellet_mm == 0.8 and plan.pellet_share == pytest.approx(0.3)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(0.1, 2000.0), min_size=1, max_size=200), st.integers(0, 100_000), st.floats(-5.0, 40.0))
def test_a_ration_lies_between_the_lowest_and_highest_rate_of_its_fish(weights, stock, temp):
    t = table()
    plan = ration_from_weights(weights, stock, temp, t)
    w = np.array(weights)
    rates = t.rate_pct(w, temp)
    biomass = stock * w.mean()
    assert biomass * rates.min() / 100 * (1 - 1e-9) <= plan.grams <= biomass * rates.max() / 100 * (1 + 1e-9)
    assert plan.pellet_mm in {c.pellet_mm for c in t.classes} and 0 < plan.pellet_share <= 1


@pytest.mark.parametrize("weights", [[], [1.0, 0.0], [1.0, -3.0], [1.0, math.nan], [math.inf]])
def test_a_ration_refuses_a_survey_with_no_fish_or_a_weight_that_is_no_weight(weights):
    with pytest.raises(ValueError, match="at least one measured fish"):
        ration_from_weights(weights, 100, 18.0, table())


def test_projection_grows_day_by_day_at_the_class_s_rate_and_crosses_into_the_next():
    t = table()
    assert project_weight(10.0, 10, 18.0, t) == pytest.approx(10.0 * math.exp(0.01 * 10))
    assert project_weight(10.0, 0, 18.0, t) == 10.0
    assert project_weight(10.0, 10, 18.0, t, sgr_pct=3.0) == pytest.approx(10.0 * math.exp(0.3))
    # 4.5 g grows 2 %/day in class 1 until it passes 5 g, then 1 %/day
    w, day = 4.5, 0
    while w < 5.0:
        w *= math.exp(0.02)
        day += 1
    expected = w * math.exp(0.01 * (20 - day))
    assert project_weight(4.5, 20, 18.0, t) == pytest.approx(expected)
    assert project_weight(60.0, 5, 18.0, t) is None                     # the chart gives no SGR there
    with pytest.raises(ValueError):
        project_weight(10.0, -1, 18.0, t)


def test_a_species_with_no_chart_is_fed_by_its_species_rows_at_any_temperature():
    species = load_species()
    t = table_from_species("sparus_aurata", species["sparus_aurata"])
    row = species["sparus_aurata"].row(18.0)
    assert t.rate_pct(18.0, 10.0) == row.rate_pct == t.rate_pct(18.0, 30.0)
    assert t.pellet_mm(18.0) == row.pellet_mm and t.source
