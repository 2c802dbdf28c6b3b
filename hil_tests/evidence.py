"""What a hardware-in-loop run proved: the controller's ledger judged against the simulator's truth.

The ledger is compared with the auger's physical runs run by run (``ledger_against_runs``): every
physical run has exactly one ledger row (same tag, intent committed before the run started), and
that row says what happened: ``done`` with the load cell's grams (within its resolution of what
physically left), or ``suspect`` (the outcome was unknowable: held against the ration, alarmed);
never ``aborted``, and never left open unless it is the ledger's latest row (a controller stopped
during that run settles it when it starts again). Every ``done`` row has its physical run. Every problem is counted.
"""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

from hil_tests.stalls import stalled_s

SERVE_WITHIN_S = 60.0
QUEUED_BY = 2            # other feeds under way or started while one waited: the robot was busy, not idle
RESOLUTION_G = 0.1
# A fish that stops asking leaves no mark: a turbulence contact seconds after the last fish contact
# looks like one more from the fish. Demands raised this soon after an episode's end are counted
# apart (``late_demands``) rather than called feed on turbulence.
AFTERGLOW_S = 10.0
# A run starts after its intent is committed: how long after depends on the machine's load (at
# 1440x, 0.1 s of wall is 144 farm s), so a run is matched to the LATEST row with its tag whose
# intent came before it started. Tags repeat only after 65535 runs; the time tells those apart.
CLOCK_SLACK_S = 1.0       # the two processes' clocks agree to far better than this (shared epoch)


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
    queued: list[str] = field(default_factory=list)   # served late behind a queue of other tanks
    stalled: list[str] = field(default_factory=list)  # late only by the time the machine stood still
    runs_compared: int = 0         # physical runs matched against the ledger, one by one
    suspect: int = 0               # ledger rows whose outcome was unknowable (held, alarmed)
    power_cut_runs: int = 0        # physical runs a dispenser power cut ended uncounted
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
                f"max {service[-1]:.1f} s, {len(self.queued)} late behind a queue, {len(self.stalled)} late "
                f"across a stall of the machine; "
                f"ledger {self.ledger_g:.1f} g, physical {self.physical_g:.1f} g; "
                f"{self.runs_compared} runs compared with the ledger one by one ({self.power_cut_runs} cut by "
                f"power), {self.suspect} suspect rows; {len(self.problems)} problems")

    def fail(self, text: str) -> None:
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


def _running_at(g: dict, t: float) -> bool:
    """The robot was already serving feed ``g`` at ``t`` (its intent before, its close after; a feed
    never closed proves nothing and does not count)."""
    closed = g["t_closed"] if "t_closed" in g.keys() else None     # a ledger row or a dict
    return closed is not None and g["t_intent"] < t < closed


def service_against_demands(v: Verdict, feeds, demand_t: dict, since: float | None = None,
                            stalls: list[tuple[float, float]] = ()) -> None:
    """Every raise served within 60 s (ledger rows as dicts; ``demand_t`` maps demand id to its raise).
    ``stalls``: farm spans in which the machine stood still (hil_tests/stalls.py) — a wait that is
    within 60 s once they are taken out is counted in ``stalled``, not failed."""
    for f in feeds:
        # (an operator's feed has a demand row of its own, not the fish's: not held to their 60 s)
        if f["demand_id"] in demand_t and f["phase"] != "aborted":
            if since is not None and demand_t[f["demand_id"]] < since:
                continue
            raised = demand_t[f["demand_id"]]
            wait = f["t_intent"] - raised
            v.service_s.append(wait)
            if wait <= SERVE_WITHIN_S:
                continue
            stood = stalled_s(stalls, raised, f["t_intent"])
            if wait - stood <= SERVE_WITHIN_S:
                v.stalled.append(f"feed {f['id']} for {f['tank']}: {wait:.1f} s, {stood:.1f} s of it with "
                                 f"the machine stalled")
                continue
            # One robot serves one tank at a time: demands that come together from tanks across the
            # rail can exceed what it can do in 60 s. Late with the robot serving other tanks all the
            # while is a queue (counted, bounded by the caller); late otherwise is the controller's.
            others = sum(g["id"] != f["id"] and (raised <= g["t_intent"] < f["t_intent"] or _running_at(g, raised))
                         for g in feeds)
            if others >= QUEUED_BY and wait <= 2 * SERVE_WITHIN_S:
                v.queued.append(f"feed {f['id']} for {f['tank']}: {wait:.1f} s behind {others} other feeds")
            else:
                v.fail(f"feed {f['id']} for {f['tank']} started {wait:.1f} s after its demand "
                       f"({others} other feeds between)")


def judge(db, truth: list[dict], end_t: float, since: float | None = None,
          stalls: list[tuple[float, float]] = ()) -> Verdict:
    """``since``: the end of the warm-up. A demand raised before it, on contacts heard while the
    controller was still coming up, waits for the rail's homing and is not held to the 60 s
    service; every demand after it is. Episodes that started before it are not judged (how soon
    their demand came), but a demand raised in one is no false demand: ``truth`` is the whole run's
    (a tank asking since before the controller was up was fed on its backlog, and called false)."""
    v = Verdict()
    episodes = episodes_by_tank(truth, end_t)
    judged = {tank: [e for e in spans if since is None or e[0] >= since] for tank, spans in episodes.items()}
    v.episodes = sum(map(len, judged.values()))
    demands = db.execute("SELECT id, tank, t, outcome FROM demand WHERE source = 'demand' ORDER BY t").fetchall()
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
    for tank, spans in judged.items():
        raised = sorted(d["t"] for d in demands if d["tank"] == tank)
        for start, end in spans:
            first = next((t for t in raised if start <= t <= end), None)
            if first is None and (end_t - start < SERVE_WITHIN_S
                                  or any(start <= t <= end for t in fed_at[tank])):
                continue    # too late in the run to judge, or fed (by a neighbour's raise) unasked
            v.detection_s.append(float("inf") if first is None else first - start)
    # every raise served within 60 s, unless the ration was reached
    service_against_demands(v, feeds, demand_t, since, stalls)
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


def match_runs(feeds, runs: list[dict]) -> tuple[dict[int, dict], list[dict]]:
    """Each physical run's ledger row: the latest with its tag whose intent came before the run
    started. Returns ({run index: row}, runs with no row)."""
    by_tag: dict[int, list[dict]] = defaultdict(list)
    for f in feeds:
        by_tag[f["tag"]].append(f)
    matched, unmatched = {}, []
    for i, run in enumerate(runs):
        rows = [f for f in by_tag.get(run["tag"], [])
                if f["t_intent"] <= run["t_start"] + CLOCK_SLACK_S]
        if rows:
            matched[i] = max(rows, key=lambda f: f["t_intent"])
        else:
            unmatched.append(run)
    return matched, unmatched


def ledger_against_runs(v: Verdict, feeds, runs: list[dict]) -> None:
    """Judge the ledger run by run (see the module's doc). Adds one problem per fault found."""
    feeds = sorted((dict(f) for f in feeds), key=lambda f: f["seq"])
    v.runs = v.runs_compared = len(runs)
    v.power_cut_runs = sum(bool(r.get("power_cut")) for r in runs)
    v.suspect = sum(f["phase"] == "suspect" for f in feeds)
    matched, unmatched = match_runs(feeds, runs)
    for run in unmatched:
        v.fail(f"auger run {run['tag']} at {run['t_start']:.1f} ({run['physical_g']:.1f} g) has no ledger row: "
               "food the ledger does not know")
    runs_of: dict[str, list[dict]] = defaultdict(list)
    for i, f in matched.items():
        runs_of[f["id"]].append(runs[i])
    for f in feeds:
        mine = runs_of.get(f["id"], [])
        what = f"feed {f['id']} (tag {f['tag']}, {f['tank']}, {f['phase']})"
        if len(mine) > 1:
            v.fail(f"{what} matches {len(mine)} auger runs: dispensed more than once")
        if f["phase"] == "done" and not mine:
            v.fail(f"{what} has no physical auger run: {f['grams']} g the auger never gave")
        for run in mine:
            physical, measured = run["physical_g"], run.get("measured_g")
            if measured is not None and abs(measured - physical) > RESOLUTION_G + 1e-9:
                v.fail(f"run {run['tag']}: load cell {measured} g, physical {physical:.3f} g")
            if f["phase"] == "done":
                if f.get("settled_by") is None and (measured is None or abs(f["grams"] - measured) > 1e-6):
                    v.fail(f"{what}: ledger {f['grams']} g, load cell {measured} g")
                if abs(f["grams"] - physical) > RESOLUTION_G + 1e-9:
                    v.fail(f"{what}: ledger {f['grams']} g, physical {physical:.3f} g")
            elif f["phase"] == "aborted":
                v.fail(f"{what}: booked without grams but the auger ran {physical:.3f} g: "
                       "food the ledger does not know")
            elif f["phase"] == "intent" and f is not feeds[-1]:
                # only the latest intent may be open: the controller stopped during its run and
                # settles it when it starts again; an older open intent was never settled
                v.fail(f"{what}: left open though the auger ran {physical:.3f} g")
    done = [f for f in feeds if f["phase"] == "done"]
    v.ledger_g = sum(f["grams"] for f in done)
    v.physical_g = sum(r["physical_g"] for r in runs)


def _ledger_equals_physics(v: Verdict, feeds, truth: list[dict]) -> None:
    ledger_against_runs(v, feeds, [r for r in truth if r["kind"] == "auger_run"])
