"""Issue 10's grow-out on the real processes: the demo farm's eight tanks, each surveyed weekly at its
own hour of the night by the rail robot, the pairs measured by vision workers in processes of their
own, fish that grow on the food they eat and die at a known rate (devices/sim/stock.py), on an
elastic clock (devices/elastic_clock.py). Shared by ``bench/bench_growout.py`` (60 farm days) and
``hil_tests/test_growout.py`` (14).

What makes it cheap enough, each a setting of this farm (``overrides``), not of the code:
- **meals**: the fish eat ``MEALS_PER_DAY`` large meals (``[sim.fish] meals_per_day``: a meal is
  that share of a day's appetite, growing with the fish), each one portion (``portion_g`` up to
  2.5 kg through a 40 g/s auger, as a farm's feeder blows them): the clock is slow for a few dozen
  meals a day instead of ~200 60-g portions;
- **surveys**: up to ``PAIRS`` pairs a survey, the simulated cameras at ``SIZE`` and ``FPS``
  (a survey's wall is the camera's rate: README "More fish a survey"), 10 farm s for the water to
  settle (the survey stop runs at a tenth of the slow speed: 60 s of settling were a wall second a
  visit), two vision workers measuring while the simulator renders.

The judge (``judge``) compares the controller's figures with the simulator's truth: per survey its
biomass (stock x the survey's mean), per pair of a tank's consecutive surveys FCR and SGR, per
planned ration the biomass it rests on (``rations``: stock x the mean weight of the tank's growth fit
that day, what ``Rations.plan`` gives from the ledger as it stood), per tank the SGR and FCR fitted
to its surveys (``fits``, over the fit's window), and every served demand's wait, those
overlapping a survey visit apart.
"""
from __future__ import annotations

import bisect
import contextlib
import io
import json
import math
import os
import re
import time
from collections import defaultdict
from datetime import datetime
from pathlib import Path

from controller.cli import main as fishfarm
from controller.config import load_config
from controller.feeding.rations import Rations, load_species
from controller.production import stock_at, tank_figures
from controller.store import Store
from hil_tests.evidence import judge as judge_feeding
from hil_tests.farm import HilFarm, merge

ROOT = Path(__file__).resolve().parents[1]
START = 1_780_056_000.0          # 2026-05-29 12:00 UTC, 13:00 local: by day, the first night surveys all
SLOW, FAST = 600.0, 60000.0      # the elastic clock's speeds (README "The elastic clock"; 60000x since the
                                 # contact driver holds stream_t behind waiting contacts: at 30000x before)
MEALS_PER_DAY = 4.0
PAIRS = 32                       # the stop ends sooner once its CI is within ±ci_pct (5 %: ~62 fish)
FPS = 12.0
SIZE = (960, 720)                # not 640x480: its small fish read heavy (README "The grow-out's cameras")
AUGER_G_S = 100.0
PORTION_G = 500.0
APPETITE_PCT = 1.6
WORKERS = 2
WARMUP_S = 120.0
STATE_LINE = re.compile(r"^(\S+Z) INFO\s+fishfarm\.feeder: feeder: (\w+)")
HEARD_LINE = re.compile(r"^(\S+Z) INFO\s+fishfarm: demand from (\w+) at [\d.]+ contacts/s, heard ([\d.]+) s after")
LATE_FEED = re.compile(r"^feed (\w+) for (\w+) started ([\d.]+) s after its demand \((\d+) other feeds between\)$")
# a feed ahead in the queue holds the robot at most this long besides its portion's auger run: the
# rail's length at 1 m/s there and back, the gate and the load cell settling
PER_FEED_S = 45.0
EXPIRED = re.compile(r"^demand (\d+) for (\w+) at ([\d.]+) never served \(expired\)$")
OPEN = re.compile(r"^demand (\d+) for (\w+) at ([\d.]+) never served \(open\)$")
OPEN_AT_END_S = 120.0       # a demand heard this close to the run's end may still be waiting (the judge's own margin)
OVER_RATION = re.compile(r"^(\w+) fed [\d.]+ g on ([\d-]+), ration [\d.]+ g$")


def overrides(pairs: int = PAIRS, meals_per_day: float = MEALS_PER_DAY, fish_in_view=(10, 18), fps: float = FPS,
              auger_g_s: float = AUGER_G_S, size=SIZE) -> dict:
    base = load_config(ROOT / "config" / "farm.toml")
    tanks = []
    for t in base.tanks:
        row = t.model_dump(exclude_none=True)
        row["survey"] = {**row["survey"], "pairs": pairs}
        tanks.append(row)
    return {"tanks": tanks,
            "feeding": {"portion_g": PORTION_G, "auger_rate_g_s": auger_g_s},
            "surveys": {"settle_s": 10.0},
            "sim": {"stock": {"record_s": 3600.0},
                    "fish": {"meals_per_day": meals_per_day, "ration_pct_day": APPETITE_PCT},
                    "dispenser": {"rate_g_s": auger_g_s},
                    "stereo_camera": {"fps": fps, "fish_in_view": list(fish_in_view),
                                      "width": size[0], "height": size[1]}}}


def enter_deaths(farm: HilFarm, entered: dict) -> None:
    """The simulator's deaths since the last look, entered as mortality events (a farm worker's
    ``fishfarm override mortality``). Run in this process: a ``fishfarm`` process per tank-day with
    deaths cost 0.4 s of CPU starting Python and its imports, ~300 of them (~120 CPU s) over 60
    days on the farm's 2 cores."""
    dead = defaultdict(int)
    for r in farm.truth():
        if r["kind"] == "mortality":
            dead[r["tank"]] += r["count"]
    for tank, count in dead.items():
        new = count - entered.get(tank, 0)
        if new > 0:
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                fishfarm(["override", "mortality", f"tank={tank}", f"count={new}", "--connect",
                          f"tcp/127.0.0.1:{farm.zenoh_port}", "--reason", "dead fish counted", "--timeout", "10"])
            entered[tank] = count


def run(workdir: Path, days: float, *, slow: float = SLOW, fast: float = FAST, workers: int = WORKERS,
        **settings) -> tuple[HilFarm, dict]:
    """The grow-out: (the farm, stopped; its figures)."""
    config = merge(overrides(**settings), {"surveys": {"out_dir": str(Path(workdir) / "surveys")}})
    farm = HilFarm(workdir, speed=slow, overrides=config, farm_start=START, surveys=True, elastic=(slow, fast))
    started = time.monotonic()
    entered: dict = {}
    day_walls = []
    try:
        farm.start_workers(workers)
        farm.start_sim()
        farm.start_controller()
        up = farm.wait_controller_up()
        end = up + days * 86400.0
        day, mark = up, time.monotonic()
        while day < end:
            day = min(end, day + 86400.0)
            farm.sleep_until_farm(day)
            enter_deaths(farm, entered)
            day_walls.append(round(time.monotonic() - mark, 1))
            mark = time.monotonic()
        end = farm.farm_now()
        farm.check_alive()
        cpu = cpu_seconds(farm)
    finally:
        farm.stop()
    out = {"days": days, "speed": {"slow": slow, "fast": fast}, "workers": workers, "cpu_s": cpu,
           "settings": {"pairs": config["tanks"][0]["survey"]["pairs"], "feeding": config["feeding"],
                        "surveys": config["surveys"],
                        **{k: config["sim"][k] for k in ("fish", "dispenser", "stereo_camera")}},
           "wall_s": round(time.monotonic() - started, 1), "wall_per_day_s": day_walls,
           "deaths_entered": entered, **judge(farm, up, end)}
    out["wall_by_reason"] = farm.watch.summary()
    out["pairs"] = pairs_spent(farm, Path(workdir) / "surveys")
    return farm, out


def pairs_spent(farm: HilFarm, out_dir: Path) -> dict:
    """Pairs the simulated cameras rendered against those the recorded surveys measured: frames a
    survey's stop did not take cost the simulator as much as the ones it did."""
    rendered = sum(r.get("rendered", 0) for r in farm.truth() if r["kind"] == "stereo_camera")
    measured = 0
    for path in sorted(out_dir.glob("*.json")):
        with contextlib.suppress(OSError, ValueError):
            measured += int(json.loads(path.read_text()).get("frames", 0))
    return {"rendered": rendered, "measured": measured}


def cpu_seconds(farm: HilFarm) -> dict:
    """CPU seconds (user + system) each process of the farm has used so far: what the run costs,
    whatever share of the machine other work took."""
    tick = os.sysconf("SC_CLK_TCK")
    procs = {"sim": farm.sim_proc, "controller": farm.ctl_proc,
             **{f"worker-{i}": w for i, w in enumerate(farm.workers)}}
    out = {}
    for name, proc in procs.items():
        try:
            fields = Path(f"/proc/{proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, AttributeError):
            continue
        out[name] = round((int(fields[11]) + int(fields[12])) / tick, 1)
    return out


def truth_at(stock: dict, tank: str, t: float) -> dict:
    """The simulator's stock record of ``tank`` nearest before ``t`` (they come every farm hour)."""
    rows = stock[tank]
    i = bisect.bisect_right([r["t"] for r in rows], t) - 1
    return rows[max(i, 0)]


def pct(a: float, b: float) -> float | None:
    return round(100.0 * (a - b) / b, 2) if b else None


def visits(log: str) -> list[tuple[float, float]]:
    """Farm spans the robot spent ``surveying`` (from its state lines)."""
    spans, start = [], None
    for line in log.splitlines():
        m = STATE_LINE.match(line)
        if not m:
            continue
        t = datetime.fromisoformat(m[1].replace("Z", "+00:00")).timestamp()
        if m[2] == "surveying" and start is None:
            start = t
        elif m[2] != "surveying" and start is not None:
            spans.append((start, t))
            start = None
    return spans


def judge(farm: HilFarm, up: float, end: float) -> dict:
    truth = farm.truth()
    stock = defaultdict(list)
    for r in truth:
        if r["kind"] == "stock":
            stock[r["tank"]].append(r)
    cfg = load_config(farm.dir / "controller.toml")
    store = Store(farm.db_path, cfg.surveys.min_weighed_fish)
    surveys, intervals = [], []
    for tank in (t.id for t in cfg.tanks):
        figures = tank_figures(cfg, store, tank)
        for s in figures["surveys"]:
            true = truth_at(stock, tank, s["t"])
            surveys.append({"tank": tank, "date": s["date"], "t": round(s["t"]), "fish": s["fish"],
                            "mean_g": round(s["mean_weight_g"], 2),
                            "true_mean_g": true["mean_g"], "mean_err_pct": pct(s["mean_weight_g"], true["mean_g"]),
                            "stock": s["stock"], "true_count": true["count"],
                            "biomass_err_pct": pct(s["stock"] * s["mean_weight_g"], true["biomass_g"])})
        for iv, (a, b) in zip(figures["intervals"], zip(figures["surveys"], figures["surveys"][1:], strict=False),
                              strict=False):
            intervals.append(_interval(tank, iv, truth_at(stock, tank, a["t"]), truth_at(stock, tank, b["t"]),
                                       (b["t"] - a["t"]) / 86400.0))
    rations, fits = ration_bases(cfg, store, stock), []
    for tank in (t.id for t in cfg.tanks):
        fit = tank_figures(cfg, store, tank).get("fit")
        if fit is not None:
            fits.append({**_interval(tank, {"fcr": fit.get("fcr"), "fcr_net": fit.get("fcr_net"),
                                            "sgr_pct": fit["sgr_pct_day"]},
                                     truth_at(stock, tank, fit["t_first"]), truth_at(stock, tank, fit["t_last"]),
                                     (fit["t_last"] - fit["t_first"]) / 86400.0), "surveys": fit["surveys"]})
    spans = visits((farm.dir / "controller.log").read_text())
    waits, during, surveyed = [], [], []
    db = store.db
    raised = {r["id"]: r["t"] for r in db.execute("SELECT id, t FROM demand WHERE source = 'demand'")}
    heard = heard_late(farm)
    served = "SELECT demand_id, t_intent, tank FROM feed WHERE demand_id IS NOT NULL AND phase != 'aborted'"
    for f in db.execute(served):
        if f["demand_id"] not in raised:             # an operator's feed: no fish waited for it
            continue
        t0, t1 = raised[f["demand_id"]], f["t_intent"]
        waits.append(t1 - t0)
        if any(a < t1 and t0 < b for a, b in spans):   # less the time it took to be heard (raised)
            late = max((h for tank, t, h in heard if tank == f["tank"] and abs(t - t0) < 5.0), default=0.0)
            during.append(t1 - t0 - late)
            surveyed.append(sum(max(0.0, min(b, t1) - max(a, t0 + late)) for a, b in spans))
    store.close()
    waits.sort()
    with farm.ledger() as ledger:
        verdict = judge_feeding(ledger, truth, end, since=up + WARMUP_S, stalls=farm.stalls())
    with farm.ledger() as ledger:
        feeding = sort_problems(ledger, verdict.problems, heard, PER_FEED_S + PORTION_G / AUGER_G_S)
        # the surveys' warnings the controller raised (each raise that is news is a history row): honest cameras
        # over a whole grow-out should raise next to none
        survey_alarms = [f"{r['source']} {r['kind']}: {r['text']}" for r in ledger.execute(
            "SELECT source, kind, text FROM alarm WHERE source LIKE 'survey/%' AND active = 1 ORDER BY id")]
        # surveys that counted too few fish to weigh their tank, none or a handful (the figures' survey
        # lists leave them out): "T2 at 1780086984 3"
        empty_surveys = [f"{r['tank']} at {r['t']:.0f} {r['count']}" for r in ledger.execute(
            "SELECT tank, t, count FROM survey WHERE count < ? ORDER BY t", (cfg.surveys.min_weighed_fish,))]
    # the simulator's lookahead: every episode found the clock slow when it started
    fast = [f"{r['tank']} at {r['t']:.0f}" for r in truth if r["kind"] == "episode_start" and r["t"] < end - 60
            and farm.watch.ran_fast_at(r["t"])]
    return {"surveys": surveys, "intervals": intervals, "rations": rations, "fits": fits,
            "episodes_started_fast": fast, "survey_alarms": survey_alarms, "empty_surveys": empty_surveys,
            "demands": {"served": len(waits), "p50_s": round(waits[len(waits) // 2], 1) if waits else None,
                        "max_s": round(waits[-1], 1) if waits else None,
                        "during_survey_visits": len(during), "max_during_visits_s": round(max(during), 1)
                        if during else None, "over_60_during_visits": sum(w > 60 for w in during),
                        # the farm seconds the robot spent surveying once the demand was raised: what a
                        # survey cost it (the filter dates a slow fish's demand back to its contacts)
                        "max_surveying_while_waiting_s": round(max(surveyed), 1) if surveyed else None,
                        "over_60_because_of_survey": sum(s > 60 for s in surveyed)},
            "survey_visits": len(spans), "feeding": {"summary": verdict.summary(), **feeding,
                                                     "false_demands": len(verdict.false_demands),
                                                     "detected_within_180": verdict.detected_within(180),
                                                     "feeds": verdict.feeds, "runs_compared": verdict.runs_compared}}


def ration_bases(cfg, store: Store, stock: dict) -> list[dict]:
    """Every ration planned from a survey: the biomass it rests on (the stock then x the mean weight
    ``Rations.plan`` gives from the ledger as it stood at the planning) against the true biomass."""
    plans, events, out = Rations(cfg, load_species(), store), [dict(e) for e in store.stock_events()], []
    rows = store.db.execute("SELECT tank, date, t FROM ration WHERE source IN ('survey', 'projected') ORDER BY t")
    for tank, date, t in rows.fetchall():
        mean_g = plans.plan(tank, t).mean_weight_g
        biomass = stock_at(cfg.tank(tank).stock, events, tank, t) * mean_g
        true = truth_at(stock, tank, t)
        out.append({"tank": tank, "date": date, "mean_g": round(mean_g, 2), "true_mean_g": true["mean_g"],
                    "biomass_err_pct": pct(biomass, true["biomass_g"])})
    return out


def heard_late(farm: HilFarm) -> list[tuple[str, float, float]]:
    """(tank, farm time raised, farm s heard after) of every demand the controller heard late: the
    clock ran fast while contacts no one foresaw (turbulence, a night's false demand) came in."""
    out = []
    for line in (farm.dir / "controller.log").read_text().splitlines():
        if (m := HEARD_LINE.match(line)) and float(m[3]) > 0:
            t = datetime.fromisoformat(m[1].replace("Z", "+00:00")).timestamp()
            out.append((m[2], t - float(m[3]), float(m[3])))
    return out


def sort_problems(ledger, problems: list[str], heard: list[tuple[str, float, float]], per_feed_s: float,
                  expiry_s: float = 600.0) -> dict:
    """The farm-day judge's problems sorted: ``queued`` (a late feed no later than the feeds ahead
    of it take, or a demand that expired while the robot served that many: the meal times, when
    all eight tanks ask together), ``heard_late`` (late, or expired,
    only by the time its demand's contacts took to be heard: a fast clock meanwhile, contacts
    nobody foresaw — turbulence, a night's false demand), ``ration_lowered`` (a day's ration planned
    again lower after that day's feeds: a survey, a stock event or the water's temperature),
    ``problems`` (the rest)."""
    out = {"queued": 0, "heard_late": 0, "ration_lowered": 0, "problems": []}
    for text in problems:
        kind = _kind(ledger, text, heard, per_feed_s, expiry_s)
        if kind is None:
            out["problems"].append(text)
        else:
            out[kind] += 1
    return out


def _kind(ledger, text: str, heard, per_feed_s: float, expiry_s: float) -> str | None:
    def late(tank: str, t: float) -> float:
        return max((h for who, raised, h in heard if who == tank and abs(raised - t) < 5.0), default=0.0)
    if m := LATE_FEED.match(text):
        row = ledger.execute("SELECT d.t FROM feed f JOIN demand d ON d.id = f.demand_id WHERE f.id = ?",
                             (m[1],)).fetchone()
        wait, ahead = float(m[3]), int(m[4])
        wait -= late(m[2], row[0]) if row is not None else 0.0
        if wait <= 60.0:
            return "heard_late"
        return "queued" if ahead > 0 and wait <= per_feed_s * (ahead + 1) else None
    if m := OPEN.match(text):
        # dated back to its first contact (a slow fish's, an hour before), heard just before the stop:
        # still waiting when the run ended, not left unserved
        t = float(m[3])
        end = ledger.execute("SELECT MAX(t) FROM farm_clock").fetchone()[0]
        if end is not None and t + late(m[2], t) >= end - OPEN_AT_END_S:
            return "heard_late"
        return None
    if m := EXPIRED.match(text):
        t = float(m[3])
        if late(m[2], t) >= expiry_s - 60.0:
            return "heard_late"
        ahead = ledger.execute("SELECT count(*) FROM feed WHERE tank != ? AND t_intent BETWEEN ? AND ?",
                               (m[2], t, t + expiry_s)).fetchone()[0]
        return "queued" if ahead * per_feed_s >= expiry_s else None     # the robot served others all along
    if m := OVER_RATION.match(text):
        planned = ledger.execute("SELECT t FROM ration WHERE tank = ? AND date = ?", (m[1], m[2])).fetchone()
        last = ledger.execute("SELECT max(t_intent) FROM feed WHERE tank = ? AND date = ?", (m[1], m[2])).fetchone()
        return "ration_lowered" if planned is not None and last[0] is not None and planned[0] > last[0] else None
    return None


def _interval(tank: str, iv: dict, ta: dict, tb: dict, days: float) -> dict:
    """The controller's FCR and SGR between two times against the simulator's. Its FCR is the
    biological one (controller/production.py: the feed over the growth it made, the fish that died
    meanwhile weighed when they died), and so is ``true_fcr``: the food eaten over the biomass's
    gain plus the dead fish's weight (devices/sim/stock.py); ``true_fcr_net``, over the gain alone,
    beside it (~3 % higher over 7 weeks at 0.05 % deaths a day)."""
    gain = tb["biomass_g"] - ta["biomass_g"]
    eaten = tb["eaten_g"] - ta["eaten_g"]
    grown = gain + tb["died_g"] - ta["died_g"]
    true_fcr = eaten / grown if grown > 0 else None
    true_sgr = 100.0 * math.log(tb["mean_g"] / ta["mean_g"]) / days
    return {"tank": tank, "days": round(days, 2), "fcr": iv.get("fcr"),
            "true_fcr": None if true_fcr is None else round(true_fcr, 3),
            "fcr_net": iv.get("fcr_net"), "true_fcr_net": round(eaten / gain, 3) if gain > 0 else None,
            "fcr_net_err_pct": None if iv.get("fcr_net") is None or gain <= 0 else pct(iv["fcr_net"], eaten / gain),
            "fcr_err_pct": None if iv.get("fcr") is None or true_fcr is None else pct(iv["fcr"], true_fcr),
            "sgr_pct": iv.get("sgr_pct"), "true_sgr_pct": round(true_sgr, 3),
            "sgr_err_pct": None if iv.get("sgr_pct") is None else pct(iv["sgr_pct"], true_sgr)}
