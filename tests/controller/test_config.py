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
    assert {s["kind"] for s in cfg.devices.values()} == {"contacts", "rail", "dispenser", "thrusters", "tower_camera",
                                                           "thermometer", "stereo_camera"}
    assert all(t.survey is not None and t.survey.every_days == 7 for t in cfg.tanks)
    assert cfg.cleaning is not None          # the pond and its cleaner (tests/controller/test_demo_farm.py)


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
    (GOOD + '[devices.x]\nkind = "laser"\ndriver = "sim"\n', "devices.x.kind: must be one of"),     # not (top level)
    (GOOD + "[feeding]\nwater_poll_s = 4000\n", "feeding: water_poll_s (4000) must be below water_max_age_s"),
    (GOOD + '[scada]\nlisten = "no such host!"\n', "scada.listen: 'no such host!' is not an IP address"),
    # an address out of range: an alarm retried for good, the SCADA never served (an outside tester)
    (GOOD + '[scada]\nlisten = "999.1.1.1"\n', "scada.listen: '999.1.1.1' is not an IP address"),
    (GOOD.replace('sensors = ["A1"]', 'sensors = ["A1", "A1"]'), "sensor 'A1' is listed twice in tank 'A'"),
    (GOOD + '[bus]\nconfig = ""\n', "bus.config: String should have at least 1 character"),
    (GOOD + '[devices.r]\nkind = "rail"\ndriver = "telepathy"\n', "devices.r.driver: driver must be one of"),
    (GOOD + '[devices.d]\nkind = "dispenser"\ndriver = "sim"\nprot = 5\n', "devices.d.prot: unknown key"),
    (GOOD + '[devices.h]\nkind = "contacts"\ndriver = "serial"\nport = "loop://"\n',
     "devices.h.port: loop:// has no file descriptor to wait on"),
    (GOOD + '[devices.h]\nkind = "contacts"\ndriver = "serial"\nport = "RFC2217://hub:2217"\n',
     "devices.h.port: rfc2217:// has no file descriptor"),
    ("site = 's1'\n[[tanks]\n", "not valid TOML"),
    (GOOD + "[surveys]\nfloor_mm = 1400\n", "surveys.floor_mm: the tank floor is the surface setup's"),
    (GOOD + '[surveys]\nsetup = "surface"\nfloor_mm = 0\n', "surveys.floor_mm: "),
    (GOOD + '[[tanks]]\nid = "B"\nstock = 1\nmean_weight_g = 1\nposition_m = 1.05\nsensors = ["B"]\n',
     "tanks.1.position_m: puts tank 'B' 0.05 m from tank 'A', closer than twice feeding.position_tolerance_m (0.1 m)"),
    (GOOD.replace("position_m = 1", "position_m = 9") + '[feeding]\nposition_tolerance_m = 0.5\n[[tanks]]\nid = "B"\n'
     'stock = 1\nmean_weight_g = 1\nposition_m = 8.2\nsensors = ["B"]\n',
     "tanks.1.position_m: puts tank 'B' 0.8 m from tank 'A'"),
])
def test_bad_config_names_file_key_and_reason(tmp_path, text, where):
    p = write(tmp_path, text)
    with pytest.raises(BadInput) as exc:
        load_config(p)
    msg = str(exc.value)
    assert msg.startswith(str(p)) and where in msg and "\n" not in msg


def test_tanks_twice_the_position_tolerance_apart_load(tmp_path):
    text = GOOD + '[[tanks]]\nid = "B"\nstock = 1\nmean_weight_g = 1\nposition_m = 1.1\nsensors = ["B"]\n'
    assert [t.position_m for t in load_config(write(tmp_path, text)).tanks] == [1.0, 1.1]


def test_a_byte_order_mark_is_no_fault(tmp_path):
    """A Windows editor's BOM read as 'Invalid statement (at line 1, column 1)'."""
    p = tmp_path / "farm.toml"
    p.write_bytes(b"\xef\xbb\xbf" + GOOD.encode())
    assert load_config(p).site == "s1"


def test_missing_file(tmp_path):
    with pytest.raises(BadInput, match="no such file"):
        load_config(tmp_path / "nope.toml")


@pytest.mark.parametrize("text, key", [
    (GOOD.replace("position_m = 1", "position_m = inf"), "tanks.0.position_m"),
    (GOOD.replace("mean_weight_g = 5", "mean_weight_g = nan"), "tanks.0.mean_weight_g"),
    ("utc_offset_h = -inf\n" + GOOD, "utc_offset_h"),
    (GOOD + "[feeding]\nportion_g = inf\n", "feeding.portion_g"),
    (GOOD + "[feeding]\nretry_backoff_s = [5.0, nan]\n", "feeding.retry_backoff_s.1"),
    (GOOD + "[demand]\nwindow_s = inf\n", "demand.window_s"),
    (GOOD + '[devices.d]\nkind = "dispenser"\ndriver = "modbus"\ntimeout_s = nan\n', "devices.d.timeout_s"),
    (GOOD + "[sim]\nspeed = -inf\n", "sim.speed"),
    (GOOD + "[sim.fish]\nx = [[1.0, inf]]\n", "sim.fish.x.0.1"),
])
def test_non_finite_numbers_are_refused_in_every_section(tmp_path, text, key):
    p = write(tmp_path, text)
    with pytest.raises(BadInput) as exc:
        load_config(p)
    assert str(exc.value).startswith(f"{p}: {key}: must be a finite number")


@pytest.mark.parametrize("text, key", [
    (GOOD.replace("position_m = 1", "position_m = 1e9"), "tanks.0.position_m: "),
    (GOOD.replace("position_m = 1", "position_m = -0.5"), "tanks.0.position_m: "),
    (GOOD.replace("stock = 10", "stock = 10_000_000_000"), "tanks.0.stock: "),
    (GOOD.replace('"A1"', '"A/1"'), "tanks.0.sensors.0: "),
    ("utc_offset_h = 15\n" + GOOD, "utc_offset_h: "),
    ("utc_offset_h = -13\n" + GOOD, "utc_offset_h: Input should be greater than or equal to -12"),
    ("utc_offset_h = 5.123\n" + GOOD, "utc_offset_h: 5.123 h is no time zone's offset"),
    (GOOD + "[feeding]\nportion_g = 1e300\n", "feeding.portion_g: "),
    (GOOD + "[feeding]\nmove_timeout_s = 1e7\n", "feeding.move_timeout_s: "),
    (GOOD + "[feeding]\nretry_backoff_s = [5.0, -1.0]\n", "feeding.retry_backoff_s.1: "),
    (GOOD + "[feeding]\nportion_g = 4\nmin_portion_g = 5\n", "feeding: min_portion_g (5) is more than portion_g"),
    (GOOD + "[feeding]\nrefill_below_g = 9000\n", "feeding: refill_below_g (9000) must be below"),
    (GOOD + "[surveys]\nmin_weighed_fish = 0\n", "surveys.min_weighed_fish: Input should be greater than or equal"),
    (GOOD + "[surveys]\nmin_weighed_fish = 2.5\n", "surveys.min_weighed_fish: Input should be a valid integer"),
])
def test_numbers_out_of_range_are_refused_naming_the_key(tmp_path, text, key):
    p = write(tmp_path, text)
    with pytest.raises(BadInput) as exc:
        load_config(p)
    assert str(exc.value).startswith(f"{p}: {key}") and "\n" not in str(exc.value)


def test_species_file_refuses_non_finite_numbers(tmp_path):
    from controller.config import load_toml
    p = tmp_path / "species.toml"
    p.write_text("[sparus_aurata]\na = nan\n")
    with pytest.raises(BadInput, match=r"sparus_aurata\.a: must be a finite number"):
        load_toml(p)


@pytest.mark.parametrize("h", [-12, -9.5, -3.5, 0, 5.5, 5.75, 12.75, 14])
def test_every_zone_s_offset_is_taken(tmp_path, h):
    assert load_config(write(tmp_path, f"utc_offset_h = {h}\n" + GOOD)).utc_offset_h == h


def test_a_floor_is_taken_for_the_surface_setup(tmp_path):
    cfg = load_config(write(tmp_path, GOOD + '[surveys]\nsetup = "surface"\nfloor_mm = 1400\n'))
    assert cfg.surveys.floor_mm == 1400.0 and load_config(write(tmp_path, GOOD)).surveys.floor_mm is None
