"""hil_tests.farm: a HIL farm's config is one the controller loads, whatever tanks the run asks for
(bench_feeding's one-tank farm stopped at `devices.thermometer.probes.T5: not a tank id` once probes
were checked against the tanks)."""
from __future__ import annotations

import tomli_w

from controller.config import load_config
from hil_tests.farm import HilFarm


def _loaded(tmp_path, overrides):
    farm = HilFarm(tmp_path, speed=1.0, overrides=overrides)
    try:
        (tmp_path / "c.toml").write_text(tomli_w.dumps(farm.config))
        return farm.config, load_config(tmp_path / "c.toml")
    finally:
        farm.witness.stop()


def test_a_farm_of_one_tank_drops_the_demo_s_probes_of_tanks_it_has_not(tmp_path):
    one = [{"id": "T1", "stock": 100, "mean_weight_g": 50.0, "position_m": 2.0, "sensors": ["a", "b"]}]
    raw, cfg = _loaded(tmp_path, {"tanks": one})
    assert [t.id for t in cfg.tanks] == ["T1"]
    assert raw["devices"]["thermometer"]["probes"] == {"supply": 0, "T1": 1}


def test_the_demo_s_own_tanks_keep_every_probe(tmp_path):
    import tomllib
    demo = tomllib.loads(open("config/farm.toml").read())["devices"]["thermometer"]["probes"]
    raw, _ = _loaded(tmp_path, None)
    assert raw["devices"]["thermometer"]["probes"] == demo
