import json
import math

import numpy as np
import pytest

from controller.config import load_config
from controller.errors import BadInput
from controller.feeding.rations import load_species
from controller.surveys.species import survey_species, with_stock

SPECIES = ["sparus_aurata", "dicentrarchus_labrax", "salmo_salar", "oncorhynchus_mykiss", "oreochromis_niloticus"]


@pytest.mark.parametrize("key", SPECIES)
def test_every_species_has_coefficients_with_a_source_and_a_body_shape(key):
    sp = survey_species(key)
    assert sp.source and sp.name
    # Froese (2006): 2.5 < b < 3.5; a 10 cm fish weighs "in the order of 10 g"
    assert 2.5 < sp.weight.b < 3.5
    assert 5 < sp.weight.weight_g(10.0) < 30
    g = sp.setup("underwater", None).geometry
    assert 0 < g.min_length_cm < g.max_length_cm and 0 < g.max_tilt_deg <= 90 and 0 < g.depth_to_length < 1


def test_sea_bream_is_the_papers_relation():
    sp = survey_species("sparus_aurata")
    assert (sp.weight.a, sp.weight.b) == (0.02263, 3.032) and "4.3" in sp.source


def test_feeding_controller_still_reads_the_file():
    species = load_species()
    assert set(SPECIES) <= set(species)
    assert all(sp.feeding for sp in species.values())
    load_config("config/farm.toml")       # the stocks section is part of the farm's config


def test_unknown_species_lists_the_known_ones():
    with pytest.raises(BadInput) as exc:
        survey_species("thunnus_thynnus")
    msg = str(exc.value)
    assert msg.startswith("--species: unknown species 'thunnus_thynnus'") and all(k in msg for k in SPECIES)


def test_bad_survey_section_names_file_and_key(tmp_path):
    p = tmp_path / "species.toml"
    p.write_text('[x]\nname = "x"\na = 0.01\nb = 3\nfeeding = [{ up_to_g = 1, rate_pct = 1, pellet_mm = 1 }]\n'
                 '[x.survey]\nmin_length_cm = 50\nmax_length_cm = 10\n')
    with pytest.raises(BadInput, match=r"species.toml: x.survey: min_length_cm \(50\) must be below"):
        survey_species("x", p)
    p.write_text(p.read_text().replace("min_length_cm = 50\n", "fins = 3\n"))
    with pytest.raises(BadInput, match=r"x.survey.fins: unknown key"):
        survey_species("x", p)


def test_table_one_implies_a_near_0_012_for_the_papers_nursery_stock():
    """Mean W = a E[L^b]; for L lognormal with mean m and CV c, E[L^b] = m^b (1 + c^2)^(b(b-1)/2)."""
    m, sd, w, b = 11.14, 1.58, 19.06, 3.032
    a = w / (m ** b * (1 + (sd / m) ** 2) ** (b * (b - 1) / 2))
    assert a == pytest.approx(0.0120, abs=0.0002)
    # the same by simulation: lengths drawn from that law give the table's mean weight with a
    s2 = math.log(1 + (sd / m) ** 2)
    L = np.random.default_rng(1).lognormal(math.log(m) - s2 / 2, math.sqrt(s2), 400_000)
    assert a * np.mean(L ** b) == pytest.approx(w, rel=0.005)
    sp = with_stock(survey_species("sparus_aurata"), "config/farm.toml", "nursery")
    assert sp.weight.a == pytest.approx(a, abs=0.0002) and sp.weight.b == b
    assert sp.source.startswith("farm.toml stocks.nursery")


STOCK = '[stocks.s1]\nspecies = "sparus_aurata"\na = 0.015\nb = 3.0\nsource = "hand sample, May"\n'


def test_stock_override_and_its_faults(tmp_path):
    p = tmp_path / "farm.toml"
    p.write_text(STOCK)
    sp = with_stock(survey_species("sparus_aurata"), p, "s1")
    assert (sp.weight.a, sp.weight.b) == (0.015, 3.0) and "hand sample" in sp.source
    assert sp.coefficients() == {"a": 0.015, "b": 3.0, "source": "farm.toml stocks.s1: hand sample, May"}
    with pytest.raises(BadInput, match=r"farm.toml: stocks.s2: no such stock \(stocks: s1\)"):
        with_stock(survey_species("sparus_aurata"), p, "s2")
    with pytest.raises(BadInput, match=r"stocks.s1.species: 'sparus_aurata', but the survey is of 'salmo_salar'"):
        with_stock(survey_species("salmo_salar"), p, "s1")
    for bad, key in (("a = 0.015", "a = -1"), ("b = 3.0", "b = 7"), ('source', 'colour = "red"\nsource')):
        p.write_text(STOCK.replace(bad, key))
        with pytest.raises(BadInput, match=r"farm.toml: stocks.s1.(a|b|colour): "):
            with_stock(survey_species("sparus_aurata"), p, "s1")


@pytest.mark.parametrize("a, b, weighs", [
    ("1e-30", "3.0", False),       # every fish 0.0 g, each figure within its own bounds
    ("0.0000226", "3.032", False),  # the species' a in kg per cm^b: 1000 x light
    ("0.9", "3.5", False),
    ("0.012", "3.032", True),      # the paper's nursery stock (Table I): 0.53 x the species' law
    ("0.045", "2.9", True),
    ("0.02263", "3.032", True),
])
def test_a_stock_whose_a_and_b_weigh_no_fish_of_its_species_is_refused(tmp_path, a, b, weighs):
    p = tmp_path / "farm.toml"
    p.write_text(STOCK.replace("a = 0.015", f"a = {a}").replace("b = 3.0", f"b = {b}"))
    if weighs:
        assert with_stock(survey_species("sparus_aurata"), p, "s1").weight.a == float(a)
        return
    with pytest.raises(BadInput, match=r"farm.toml: stocks.s1.a: a = .* x the .* g of sparus_aurata's own law") as e:
        with_stock(survey_species("sparus_aurata"), p, "s1")
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("floor_mm", [None, 1400.0])
def test_the_floor_travels_with_the_setup_to_a_worker(floor_mm):
    """A worker measures with the setup it is sent: the floor's distance must survive the wire, or a
    survey on workers reports the shadows its own process would drop."""
    from controller.surveys import wire
    sp = survey_species("sparus_aurata")
    setup = sp.setup("surface", (0.0, 0.0, 1.0), floor_mm)
    again = wire.setup_from_json(json.loads(json.dumps(wire.setup_to_json(setup))))
    assert again == setup and again.floor_mm == floor_mm
