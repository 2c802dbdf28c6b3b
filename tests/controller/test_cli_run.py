"""``fishfarm run`` and ``fishfarm sim`` refuse bad input with one line and exit 2."""
import socket
import subprocess
import sys

import pytest

TANK = '[[tanks]]\nid = "A"\nstock = 10\nmean_weight_g = 5\nposition_m = 1\nsensors = ["A1"]\n'


def fishfarm(*args, timeout=60):
    return subprocess.run([sys.executable, "-m", "controller.cli", *args], capture_output=True, text=True,
                          timeout=timeout)


def test_missing_config(tmp_path):
    r = fishfarm("run", "--config", str(tmp_path / "nope.toml"), "--no-console")
    assert r.returncode == 2 and r.stderr.strip() == f"fishfarm: {tmp_path / 'nope.toml'}: no such file"


def test_speed_needs_simulated_devices(tmp_path):
    cfg = tmp_path / "farm.toml"
    cfg.write_text(TANK + '[devices.d]\nkind = "dispenser"\ndriver = "modbus"\nport = 1502\n')
    r = fishfarm("run", "--config", str(cfg), "--speed", "10", "--no-console")
    assert r.returncode == 2 and "devices: --speed needs every device simulated" in r.stderr


def test_busy_port_names_the_key(tmp_path):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        cfg = tmp_path / "farm.toml"
        cfg.write_text(TANK + f'[devices.d]\nkind = "dispenser"\ndriver = "sim"\nport = {port}\n')
        r = fishfarm("sim", "--config", str(cfg), "--endpoints", str(tmp_path / "e.json"))
    assert r.returncode == 2
    assert f"fishfarm: {cfg}: devices.d.port: " in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("args", [["--speed", "0"], ["--duration", "-1"], ["--log-level", "loud"]])
def test_bad_options(args):
    r = fishfarm("run", *args)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1


def test_a_farm_without_a_contact_hub(tmp_path):
    cfg = tmp_path / "farm.toml"
    cfg.write_text(TANK)
    r = fishfarm("run", "--config", str(cfg), "--no-console")
    assert r.returncode == 2
    assert r.stderr.strip() == f"fishfarm: {cfg}: devices: the feeding robot needs exactly one contacts device, found 0"


def test_unknown_species(tmp_path):
    cfg = tmp_path / "farm.toml"
    cfg.write_text(TANK.replace('id = "A"', 'id = "A"\nspecies = "tuna"'))
    r = fishfarm("run", "--config", str(cfg), "--no-console")
    assert r.returncode == 2
    assert r.stderr.strip().startswith(f"fishfarm: {cfg}: tanks.0.species: unknown species 'tuna'")


def BUS() -> str:  # noqa: N802 - a section, like TANK
    """A [bus] of its own: a run that opens its bus must not meet another test's on 7447."""
    from hil_tests.ports import free_port
    return f'[bus]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n'


DEVICES = "".join(f'[devices.{k}]\nkind = "{k}"\ndriver = "sim"\n' for k in ("contacts", "rail", "dispenser"))


@pytest.mark.parametrize("store_path", ["{blocker}/fishfarm.db", "{blocker}/var/fishfarm.db", "{directory}"])
def test_unusable_store_path_exits_2_naming_store_path(tmp_path, store_path):
    """A ledger that cannot be created is the operator's to fix: one line naming store.path, before
    any simulated device is started."""
    (tmp_path / "blocker").write_text("a regular file, not a directory\n")
    (tmp_path / "dir").mkdir()
    path = store_path.format(blocker=tmp_path / "blocker", directory=tmp_path / "dir")
    cfg = tmp_path / "farm.toml"
    cfg.write_text(f'[store]\npath = "{path}"\n' + TANK + DEVICES)
    r = fishfarm("run", "--config", str(cfg), "--no-console", "--duration", "1", timeout=30)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"fishfarm: store.path: {path}: cannot open the ledger")
    assert "internal error" not in r.stderr


@pytest.mark.parametrize("section, key", [("[demand]\nwindow = 60\n", "demand.window"),
                                          ("[sim]\nsed = 1\n", "sim.sed"),
                                          ('[bus]\nlisten = ["nonsense"]\n', "bus.listen"),
                                          # Zenoh took these and failed as its session opened: after
                                          # the simulator had started and the ledger was made
                                          ('[bus]\nlisten = ["tcp/127.0.0.1:99999"]\n', "bus.listen"),
                                          ('[bus]\nlisten = ["tcp/127.0.0.1:abc"]\n', "bus.listen"),
                                          ('[bus]\nconnect = ["tcp/127.0.0.1:0"]\n', "bus.connect"),
                                          ('[bus]\nmode = "client"\nconnect = []\n', "bus"),
                                          ("[sim.pond]\nconditions = {glare = -3}\n", "sim.pond.conditions"),
                                          ("[sim.pond]\nconditions = {sunshine = 1}\n", "sim.pond.conditions"),
                                          # each [sim.*] sub-section too: they were the simulator's
                                          # exit after the controller had started it
                                          ("[sim.fish]\nrate = 1\n", "sim.fish.rate"),
                                          ("[sim.fish]\nrate_hz = [-1.0, 2.0]\n", "sim.fish.rate_hz"),
                                          ("[sim.pond]\nrobot = {speed = 1}\n", "sim.pond.robot.speed"),
                                          ("[sim.stereo_camera]\nfish_in_view = [18, 10]\n",
                                           "sim.stereo_camera.fish_in_view"),
                                          ("[sim.tower_camera]\njpeg_quality = 150\n",
                                           "sim.tower_camera.jpeg_quality")])
def test_a_bad_key_in_any_section_is_one_line_before_the_simulator_starts(tmp_path, section, key):
    cfg = tmp_path / "farm.toml"
    cfg.write_text(TANK + DEVICES + f'[store]\npath = "{tmp_path / "ledger.db"}"\n' + section)
    r = fishfarm("run", "--config", str(cfg), "--no-console", "--duration", "1", timeout=30)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and f"{key}:" in lines[0] and "farm.toml" in lines[0], lines
    assert list(tmp_path.iterdir()) == [cfg]              # no ledger made, nothing started


def test_duration_ends_a_run_whose_devices_never_open(tmp_path):
    """A device that never opens kept the start retrying: --duration 2 ran until killed at 60 s."""
    cfg = tmp_path / "farm.toml"
    cfg.write_text(f'[store]\npath = "{tmp_path / "ledger.db"}"\n' + BUS() + TANK
                   + '[devices.contacts]\nkind = "contacts"\ndriver = "serial"\nport = "/dev/no-such-hub"\n'
                   + '[devices.rail]\nkind = "rail"\ndriver = "can"\ninterface = "virtual"\nchannel = "nobody"\n'
                   + '[devices.dispenser]\nkind = "dispenser"\ndriver = "modbus"\nhost = "127.0.0.1"\nport = 9\n')
    r = fishfarm("run", "--config", str(cfg), "--no-console", "--duration", "2", timeout=60)
    assert r.returncode == 0, r.stderr
    assert "--duration passed while the controller was still starting" in r.stderr


def test_a_duration_shorter_than_a_slow_start_still_runs_the_controller(tmp_path):
    """The start is waited for when no device has failed to open: a duration shorter than the
    simulator's start ended runs that never came up (exit 0, nothing done)."""
    cfg = tmp_path / "farm.toml"
    cfg.write_text(f'[store]\npath = "{tmp_path / "ledger.db"}"\n' + BUS() + TANK + DEVICES)
    r = fishfarm("run", "--config", str(cfg), "--no-console", "--duration", "0.01", timeout=60)
    assert r.returncode == 0, r.stderr
    assert "controller for site demo up" in r.stderr and "still starting" not in r.stderr
    # the stop's farm time is the ledger's last: a restart carries on from it, not from before the stop
    import sqlite3

    from controller.store import ledger_time
    db = sqlite3.connect(tmp_path / "ledger.db")
    [(stopped,)] = db.execute("SELECT t FROM farm_clock").fetchall()
    db.close()
    assert ledger_time(tmp_path / "ledger.db") == stopped


@pytest.mark.parametrize("args, said", [
    (["--speed", "600"], "fishfarm: --clock: the clock file sets farm time: not with --speed"),
    (["--epoch-wall", "1780000000", "--epoch-farm", "1780000001"],
     "fishfarm: --clock: the clock file sets farm time: not with --epoch-wall or --epoch-farm"),
])
def test_a_clock_file_with_speed_or_epochs_is_refused_not_ignored(tmp_path, args, said):
    clock = tmp_path / "clock"
    clock.write_text("x")
    r = fishfarm("run", "--clock", str(clock), *args, "--config", str(tmp_path / "none.toml"))
    assert r.returncode == 2 and r.stderr.strip() == said


def _ledger_at(path, t: float) -> None:
    from controller.store import Store
    store = Store(path)
    store.add_demand("A", t, 0.5)
    store.close()


@pytest.mark.parametrize("ahead_s, follows, carried", [(2 * 86400.0, True, True), (-600.0, True, False),
                                                        (100.0, False, False)])
def test_a_simulated_farm_s_clock_carries_on_from_a_ledger_ahead_of_it(tmp_path, ahead_s, follows, carried):
    """A --speed 600 run restarted on its ledger started at the wall clock again: farm time ran
    back days, and demands of 'the future' were served at once."""
    from types import SimpleNamespace

    from controller.cli.run_cmd import _after_the_ledger
    from devices.clock import ScaledClock
    clock = ScaledClock.starting(600.0, 1.8e9)
    _ledger_at(tmp_path / "l.db", 1.8e9 + ahead_s)
    cfg = SimpleNamespace(store=SimpleNamespace(path=str(tmp_path / "l.db")))
    got, at = _after_the_ledger(cfg, clock, follows)
    if carried:
        assert at == 1.8e9 + ahead_s and got.speed == 600.0
        assert 1.8e9 + ahead_s <= got.now() < 1.8e9 + ahead_s + 600.0 * 60
    else:
        assert got is clock and at is None


@pytest.mark.parametrize("ahead_s", [400.0, 3 * 86400.0])
def test_a_farm_clock_the_ledger_is_ahead_of_is_refused(tmp_path, ahead_s):
    from types import SimpleNamespace

    from controller.cli.run_cmd import _after_the_ledger
    from controller.errors import BadInput
    from devices.clock import ScaledClock
    clock = ScaledClock(1.0, 1.8e9, 1.8e9)           # a farm's own (explicit) timeline
    _ledger_at(tmp_path / "l.db", clock.now() + ahead_s)
    cfg = SimpleNamespace(store=SimpleNamespace(path=str(tmp_path / "l.db")))
    with pytest.raises(BadInput) as exc:
        _after_the_ledger(cfg, clock, follows=False)
    msg = str(exc.value)
    assert msg.startswith(f"store.path: {tmp_path / 'l.db'}: the ledger's last entry (")
    assert "the clock went back" in msg
    assert f"is {ahead_s / 3600:.1f} h after this clock's farm time" in msg


@pytest.mark.parametrize("clock_file, advice", [(False, "give --epoch-wall/--epoch-farm that carry on"),
                                                 (True, "give a clock file whose farm time starts after it")])
def test_the_clock_went_back_advice_fits_the_clock_given(tmp_path, clock_file, advice):
    """With --clock, the advice named --epoch-wall/--epoch-farm, which --clock refuses."""
    from types import SimpleNamespace

    from controller.cli.run_cmd import _after_the_ledger
    from controller.errors import BadInput
    from devices.clock import ScaledClock
    clock = ScaledClock(1.0, 1.8e9, 1.8e9)
    _ledger_at(tmp_path / "l.db", clock.now() + 3600.0)
    cfg = SimpleNamespace(store=SimpleNamespace(path=str(tmp_path / "l.db")))
    with pytest.raises(BadInput, match=advice):
        _after_the_ledger(cfg, clock, False, clock_file)


def test_a_ledger_at_the_end_of_the_farm_s_years_is_named_not_a_flag_never_given(tmp_path):
    """A run given --epoch-farm late in 2199 wrote its ledger there; a plain restart then failed on
    the simulator's --epoch-farm, a flag the user never gave, and wrote a later entry each time."""
    from types import SimpleNamespace

    from controller.cli.run_cmd import _after_the_ledger
    from controller.errors import BadInput
    from devices.clock import ScaledClock
    from devices.clock_file import FARM_MAX
    _ledger_at(tmp_path / "l.db", FARM_MAX - 600.0)
    cfg = SimpleNamespace(store=SimpleNamespace(path=str(tmp_path / "l.db")))
    with pytest.raises(BadInput) as exc:
        _after_the_ledger(cfg, ScaledClock.starting(60.0), True)
    msg = str(exc.value)
    assert msg.startswith(f"store.path: {tmp_path / 'l.db'}: the ledger's last entry (") and "2000-2199" in msg
    assert "--epoch" not in msg and "\n" not in msg


def test_no_ledger_yet_changes_nothing(tmp_path):
    from types import SimpleNamespace

    from controller.cli.run_cmd import _after_the_ledger
    from devices.clock import ScaledClock
    clock = ScaledClock.starting(60.0)
    cfg = SimpleNamespace(store=SimpleNamespace(path=str(tmp_path / "none.db")))
    assert _after_the_ledger(cfg, clock, follows=True) == (clock, None)


def test_every_farm_time_the_ledger_keeps_counts_for_where_a_clock_carries_on(tmp_path):
    """A night of surveys and cleaning writes no demand, feed or alarm: the restarted farm's clock
    carried on from before the survey rows it had written. Every time column of every table counts
    (named t, t_*, *_t in the schema), and a survey row alone sets the time."""
    from controller.store import LEDGER_TIMES, Store, ledger_time
    store = Store(tmp_path / "l.db")
    try:
        schema = {(table, col) for (table,) in store.db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")
                  for (_, col, *_rest) in store.db.execute(f"PRAGMA table_info({table})")
                  if col == "t" or col.startswith("t_") or col.endswith("_t")}
        assert schema and schema == set(LEDGER_TIMES)
        _ledger_at(tmp_path / "l.db", 1.8e9)
        store.add_survey("A", 1.8e9 + 3600.0, "sparus_aurata", "night.json", [20.0], [100.0], [0.9])
    finally:
        store.close()
    assert ledger_time(tmp_path / "l.db") == 1.8e9 + 3600.0


WARMED = """
import sys
from controller.cli.run_cmd import _warm
from controller.config import load_config
from controller.demand_stats import beat_threshold
cfg = load_config("config/farm.toml")
assert "vision.float_track" not in sys.modules and beat_threshold.cache_info().currsize == 0
_warm(cfg)
warm = beat_threshold.cache_info()
from controller.config import validate_section
from controller.demand import DemandFilter, DemandParams
DemandFilter(validate_section(DemandParams, cfg.demand, cfg.path, "demand"), {t.id: list(t.sensors) for t in cfg.tanks})
after = beat_threshold.cache_info()
print("vision.float_track" in sys.modules, "scipy.stats" in sys.modules, warm.currsize > 0, after.misses == warm.misses)
"""


def test_the_start_s_slow_work_is_done_before_the_loop_and_its_signal_handlers():
    """A start spent ~1.5 s (5 s at a load of 8) on its event loop importing the float tracker's
    filterpy and scipy and working out the demand filter's thresholds: a SIGINT or SIGTERM then
    waited for the loop, and twice in twelve the stop's watchdog ended the process (exit 70). That
    work is done before: the controller's own filter then finds every threshold worked out."""
    r = subprocess.run([sys.executable, "-c", WARMED], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.split() == ["True", "True", "True", "True"], (r.stdout, r.stderr)


def test_a_surface_survey_on_simulated_cameras_is_refused_naming_the_key(tmp_path):
    """The simulated stereo camera renders underwater scenes only: its surface surveys counted a
    fish or two, warned the water hid the rest, and fell back to the configured weights for good."""
    import tomllib

    import tomli_w
    raw = tomllib.loads(open("config/farm.toml").read())
    raw["surveys"]["setup"] = "surface"
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    cfg = tmp_path / "farm.toml"
    cfg.write_text(tomli_w.dumps(raw))
    r = fishfarm("run", "--config", str(cfg), "--no-console", "--duration", "1")
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert f"{cfg}: surveys.setup: \"surface\", but devices.stereo is simulated" in r.stderr
