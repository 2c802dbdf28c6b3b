"""What a hardware-in-loop run proved: the controller's ledger judged against the simulator's truth."""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

SERVE_WITHIN_S = 60.0
RESOLUTION_G = 0.1
# A fish that stops asking leaves no mark: a turbulence contact seconds after the last fish contact
# looks like one more from the fish. Demands raised this soon after an episode's end are counted
# apart (``late_demands``) rather than called feed on turbulence.
AFTERGLOW_S = 10.0


@dataclass
class Verdict:
    episodes: int = 0
    demands: int = 0
    feeds: int = 0
    runs: int = 0
    ledger_g: float = 0.0
    physical_g: float = 0.0
    problems: list[str] = field(default_factory=list)
    detection_s: list[float] = field(default_factory=list)
    service_s: list[float] = field(default_factory=list)
    late_demands: int = 0
    false_demands: list[str] = field(default_factory=list)

    def detected_within(self, seconds: float) -> float:
        """Share of episodes whose demand was raised within ``seconds`` of their start."""
        return sum(d <= seconds for d in self.detection_s) / max(1, len(self.detection_s))

    def summary(self) -> str:
        service = sorted(self.service_s) or [float("nan")]
        return (f"{self.episodes} episodes, {self.demands} demands ({self.late_demands} within "
                f"{AFTERGLOW_S:.0f} s after an episode's end), {self.feeds} feeds, {self.runs} auger runs; "
                f"raised within 60 s: {self.detected_within(60):.1%}, within 120 s: "
                f"{self.detected_within(120):.1%}; service p50 {service[len(service) // 2]:.1f} s, "
                f"max {service[-1]:.1f} s; ledger {self.ledger_g:.1f} g, physical {self.physical_g:.1f} g")

    def fail(self, text: str) -> None:
        if len(self.problems) < 40:
            self.problems.append(text)


def episodes_by_tank(truth: list[dict], end_t: float) -> dict[str, list[tuple[float, float]]]:
    """[(start, end)] per tank; an episode still open at the end of the run ends at ``end_t``."""
    open_, out = {}, defaultdict(list)
    marks = [r for r in truth if r["kind"] in ("episode_start", "episode_end")]
    for rec in sorted(marks, key=lambda r: r["t"]):
        if rec["kind"] == "episode_start":
            open_[rec["tank"]] = rec["t"]
        elif rec["tank"] in open_:
            out[rec["tank"]].append((open_.pop(rec["tank"]), rec["t"]))
    for tank, start in open_.items():
        out[tank].append((start, end_t))
    return out


def inside(t: float, spans: list[tuple[float, float]], slack: float = 0.0) -> tuple[float, float] | None:
    for start, end in spans:
        if start <= t <= end + slack:
            return start, end
    return None


def judge(db, truth: list[dict], end_t: float) -> Verdict:
    v = Verdict()
    episodes = episodes_by_tank(truth, end_t)
    v.episodes = sum(map(len, episodes.values()))
    demands = db.execute("SELECT id, tank, t, outcome FROM demand ORDER BY t").fetchall()
    feeds = db.execute("SELECT * FROM feed ORDER BY seq").fetchall()
    v.demands, v.feeds = len(demands), len(feeds)
    demand_t = {d["id"]: d["t"] for d in demands}

    # no demand, hence no feed, outside a fish-demand episode
    for d in demands:
        spans = episodes.get(d["tank"], [])
        if inside(d["t"], spans) is None:
            if inside(d["t"], spans, AFTERGLOW_S) is not None:
                v.late_demands += 1
            else:       # the filter's budget (<= 0.5 a tank-day) is the caller's to judge
                v.false_demands.append(f"demand {d['id']} for {d['tank']} at {d['t']:.1f} lies outside every episode")
    # how long fish asked before the filter raised their demand (the filter's own contract is
    # measured here as a distribution; the unit tests of controller/demand.py pin it down)
    fed_at = defaultdict(list)
    for rec in truth:
        if rec["kind"] == "fed":
            fed_at[rec["tank"]].append(rec["t"])
    for tank, spans in episodes.items():
        raised = sorted(d["t"] for d in demands if d["tank"] == tank)
        for start, end in spans:
            first = next((t for t in raised if start <= t <= end), None)
            if first is None and (end_t - start < SERVE_WITHIN_S
                                  or any(start <= t <= end for t in fed_at[tank])):
                continue    # too late in the run to judge, or fed (by a neighbour's raise) unasked
            v.detection_s.append(float("inf") if first is None else first - start)
    # every raise served within 60 s, unless the ration was reached
    for f in feeds:
        if f["demand_id"] is not None and f["phase"] != "aborted":
            wait = f["t_intent"] - demand_t[f["demand_id"]]
            v.service_s.append(wait)
            if wait > SERVE_WITHIN_S:
                v.fail(f"feed {f['id']} for {f['tank']} started {wait:.1f} s after its demand")
    for d in demands:
        if d["outcome"] in ("open", "expired"):
            if d["t"] < end_t - 2 * SERVE_WITHIN_S:
                v.fail(f"demand {d['id']} for {d['tank']} at {d['t']:.1f} never served ({d['outcome']})")
    # within the ration, by the ledger and physically
    rations = {(r["tank"], r["date"]): r["grams"] for r in db.execute("SELECT * FROM ration")}
    fed = defaultdict(float)
    for f in feeds:
        if f["phase"] == "done":
            fed[(f["tank"], f["date"])] += f["grams"]
    for key, grams in fed.items():
        if grams > rations[key] + 1e-6:
            v.fail(f"{key[0]} fed {grams:.1f} g on {key[1]}, ration {rations[key]:.1f} g")
    _ledger_equals_physics(v, feeds, truth)
    return v


def _ledger_equals_physics(v: Verdict, feeds, truth: list[dict]) -> None:
    runs = [r for r in truth if r["kind"] == "auger_run"]
    v.runs = len(runs)
    done = [f for f in feeds if f["phase"] == "done"]
    by_tag = {}
    for run in runs:
        by_tag.setdefault(run["tag"], []).append(run)
    for f in done:
        matches = by_tag.get(f["tag"], [])
        if len(matches) != 1:
            v.fail(f"feed {f['id']} (tag {f['tag']}) matches {len(matches)} auger runs")
            continue
        run = matches[0]
        if abs(f["grams"] - run["measured_g"]) > 1e-6:
            v.fail(f"feed {f['id']}: ledger {f['grams']} g, load cell {run['measured_g']} g")
        if abs(run["measured_g"] - run["physical_g"]) > RESOLUTION_G + 1e-9:
            v.fail(f"run {run['tag']}: load cell {run['measured_g']} g, physical {run['physical_g']} g")
    if len(done) != len(runs):
        v.fail(f"{len(runs)} auger runs but {len(done)} feeds done in the ledger")
    v.ledger_g = sum(f["grams"] for f in done)
    v.physical_g = sum(r["physical_g"] for r in runs)
    if abs(v.ledger_g - v.physical_g) > RESOLUTION_G * max(1, len(runs)):
        v.fail(f"ledger {v.ledger_g:.2f} g against physical {v.physical_g:.2f} g")
