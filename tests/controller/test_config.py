import pytest

from controller.config import load_config
from controller.errors import BadInput

GOOD = """
site = "s1"
[[tanks]]
id = "A"
stock = 10
mean_weight_g = 5
position_m = 1
sensors = ["A1"]
"""


def write(tmp_path, text):
    p = tmp_path / "farm.toml"
    p.write_text(text)
    return p


def test_demo_config_loads():
    cfg = load_config("config/farm.toml")
    assert len(cfg.tanks) == 8 and cfg.site == "demo"
    assert {s["kind"] for s in cfg.devices.values()} == {"contacts", "rail", "dispenser"}


def test_minimal_config_defaults(tmp_path):
    cfg = load_config(write(tmp_path, GOOD))
    assert cfg.bus.listen == ["tcp/127.0.0.1:7447"] and cfg.store.path == "var/fishfarm.db"


@pytest.mark.parametrize("text, where", [
    (GOOD + "\nbogus = 1\n", "bogus: unknown key"),
    (GOOD.replace("stock = 10", "stock = -3"), "tanks.0.stock: "),
    (GOOD.replace("stock = 10", 'stock = "many"'), "tanks.0.stock: "),
    (GOOD + '[feeding]\nportion_gg = 3\n', "feeding.portion_gg: unknown key"),
    (GOOD + '[[tanks]]\nid = "A"\nstock = 1\nmean_weight_g = 1\nposition_m = 2\nsensors = ["B"]\n',
     "tanks: tank id 'A' appears twice"),
    (GOOD + '[devices.x]\nkind = "laser"\ndriver = "sim"\n', "devices.x.kind must be one of"),
    (GOOD + '[devices.r]\nkind = "rail"\ndriver = "telepathy"\n', "devices.r.driver: driver must be one of"),
    (GOOD + '[devices.d]\nkind = "dispenser"\ndriver = "sim"\nprot = 5\n', "devices.d.prot: unknown key"),
    ("site = 's1'\n[[tanks]\n", "not valid TOML"),
])
def test_bad_config_names_file_key_and_reason(tmp_path, text, where):
    p = write(tmp_path, text)
    with pytest.raises(BadInput) as exc:
        load_config(p)
    msg = str(exc.value)
    assert msg.startswith(str(p)) and where in msg and "\n" not in msg


def test_missing_file(tmp_path):
    with pytest.raises(BadInput, match="no such file"):
        load_config(tmp_path / "nope.toml")
