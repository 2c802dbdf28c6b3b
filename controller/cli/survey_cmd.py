"""``fishfarm survey``: fish lengths and weights from stereo pairs, and the survey's statistics.

    fishfarm survey --calib CALIB.json --species sparus_aurata --setup underwater|surface
                    (--pair L R ... | --rg FRAME ... | --dir DIR | --video L R | --rg-video F)
                    --json OUT.json [--plot HIST.png] [--csv FISH.csv] [--config farm.toml --stock NAME]
                    [--up x,y,z] [--every N] [--max-frames M] [--workers N|tcp/HOST:PORT [--site S]]
                    [--seed S]

Pairs are measured by vision.survey.measure_pair in one worker process per core, or, with
``--workers tcp/HOST:PORT``, by the ``fishfarm worker`` processes reached there over Zenoh
(controller/surveys/remote.py: if nothing listens there, the survey listens itself for workers to
join; with no worker up it measures here). OUT.json is
the contract of DESIGN.md plus optional fields (README, "Weight surveys"). Bad input exits 2
with one line naming the file and the fault; an empty survey (no fish) is a result, count 0.
"""
from __future__ import annotations

import math
import os
import sys

import click

from controller.cli.params import Finite
from controller.errors import BadInput


def _up(text: str | None) -> tuple[float, float, float] | None:
    if text is None:
        return None
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        raise BadInput("--up", None, f"expected three numbers x,y,z, got {text!r}") from None
    norm = math.sqrt(sum(x * x for x in v)) if len(v) == 3 and all(map(math.isfinite, v)) else 0.0
    if len(v) != 3 or norm == 0:
        raise BadInput("--up", None, f"expected a non-zero finite vector x,y,z, got {text!r}")
    return (v[0] / norm, v[1] / norm, v[2] / norm)


def _source(pairs, rgs, directory, video, rg_video, every, max_frames, sync_offset=0):
    """The survey's frames, and every file they are read from (a directory listed once)."""
    from controller.surveys import frames
    given = [name for name, v in (("--pair", pairs), ("--rg", rgs), ("--dir", directory), ("--video", video),
                                  ("--rg-video", rg_video)) if v]
    if len(given) != 1:
        got = f" (got {', '.join(given)})" if given else ""
        raise click.UsageError("give exactly one input: --pair L R (repeatable), --rg FRAME (repeatable), "
                               f"--dir DIR, --video L R or --rg-video F{got}")
    if sync_offset and not video:
        raise BadInput("--sync-offset", None, "is for two videos (--video LEFT RIGHT)")
    if video or rg_video:
        paths = tuple(video) if video else (rg_video,)
        from controller.surveys.video_frames import video_source
        return video_source(paths, every, max_frames, sync_offset), list(paths)
    items = [tuple(p) for p in pairs] or [(p,) for p in rgs] or frames.directory_items(directory)
    return frames.still_source(items, every, max_frames), [f for item in items for f in item]


class _Progress:
    """A rich progress bar on a terminal; silence in a pipe or a log. The first warning is printed,
    the others counted (an RG video with a faint blue channel would say it on every frame)."""

    def __init__(self, total: int | None):
        self.bar = None
        self.warnings = 0
        if sys.stderr.isatty():
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
            self.bar = Progress(TextColumn("survey"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                                console=Console(stderr=True), transient=True)
            self.task = self.bar.add_task("pairs", total=total)
            self.bar.start()

    def say(self, text: str) -> None:
        if self.bar:
            self.bar.console.print(text, markup=False, highlight=False, soft_wrap=True)  # names may hold [ ]
        else:
            click.echo(text, err=True)

    def __call__(self, result) -> None:
        if result.warning:
            self.warnings += 1
            if self.warnings == 1:
                self.say(f"fishfarm survey: warning: {result.warning}")
        if self.bar:
            self.bar.advance(self.task)

    def stop(self) -> None:
        if self.warnings > 1:
            self.say(f"fishfarm survey: warning: the same for {self.warnings - 1} more pairs")
        if self.bar:
            self.bar.stop()


def _recorder(config_path: str, tank_id: str, species: str, json_path: str):
    """Checked before any pair is measured: the tank exists and holds ``species`` (and fish), the
    ledger opens."""
    from controller.config import load_config
    from controller.store import Store
    cfg = load_config(config_path)
    tank = next((t for t in cfg.tanks if t.id == tank_id), None)
    if tank is None:
        raise BadInput(config_path, "--tank", f"no tank {tank_id!r} (tanks: {', '.join(t.id for t in cfg.tanks)})")
    if tank.species != species:
        raise BadInput(config_path, "--tank", f"{tank_id} holds {tank.species}, not {species}")
    store = Store(cfg.store.path, cfg.surveys.min_weighed_fish)
    try:           # the stock as the controller counts it (Rations.stock): start-survey refuses it too
        if tank.stock + store.stock_change(tank_id) <= 0:
            raise BadInput(config_path, "--tank", f"{tank_id} holds no fish (its stock events took them all)")
    finally:
        store.close()

    def record(lengths, weights, scores) -> None:
        store = Store(cfg.store.path, cfg.surveys.min_weighed_fish)
        try:
            again = store.same_fish_survey(tank_id, lengths)
            if again is not None:     # the same pairs surveyed twice: the growth fit would count it twice
                raise BadInput(config_path, "--tank", f"{tank_id}: these {len(lengths)} fish are already recorded "
                                                      f"(its survey {again.id}, from {again.source})")
            # OUT.json as the controller will open it, from whatever folder it runs in
            store.add_survey(tank_id, _farm_now(cfg.store.path), species, os.path.abspath(json_path), lengths,
                             weights, scores)
        finally:
            store.close()
    record.ledger = cfg.store.path
    return record


def _farm_now(ledger) -> float:
    """The farm's time now: the wall clock's, or the ledger's latest entry where a controller on a
    sped-up clock has written ahead of it (a survey stamped with the wall's time landed 18 farm hours
    in the past at --speed 600, before the stock events it follows)."""
    import time

    from controller.store import ledger_time
    return max(time.time(), ledger_time(ledger) or 0.0)


class _WorkersType(click.ParamType):
    """A number of local processes, or a Zenoh endpoint (``tcp/HOST:PORT``) where vision workers are."""

    name = "workers"

    def convert(self, value, param, ctx):
        if isinstance(value, int) or "/" not in str(value):
            try:
                n = int(value)
            except ValueError:
                self.fail(f"{value!r} is neither a number of processes nor an endpoint like tcp/HOST:PORT", param, ctx)
            if n < 1:
                self.fail(f"{n} processes: at least 1", param, ctx)
            return n
        return str(value)


_WORKERS = _WorkersType()
# workers waiting for a listener retry every second (zenoh_config.CLIENT_RETRY_S): a survey that has just
# started listening gives them this long to join before it measures here
HUB_DISCOVER_S = 5.0


def _remote(endpoint: str, site: str, user: str | None, password: str | None):
    """(options for measure_remote, session): whatever listens at ``endpoint``, or this survey
    listening there itself for workers to join (then it waits a little longer for them)."""
    from controller.surveys.remote import DISCOVER_S, connect
    from controller.surveys.worker import SITE
    if not SITE.match(site):
        raise BadInput("--site", None, f"{site!r}: letters, digits, _ and - only")
    session, listening = connect(endpoint, user=user, password=password)
    return {"session": session, "site": site, "discover_s": HUB_DISCOVER_S if listening else DISCOVER_S}, session


@click.command()
@click.option("--calib", "calib_path", required=True, metavar="CALIB.json", help="the stereo rig's calibration")
@click.option("--species", required=True, help="a species of config/species.toml, e.g. sparus_aurata")
@click.option("--setup", required=True, type=click.Choice(["underwater", "surface"]))
@click.option("--pair", "pairs", nargs=2, multiple=True, metavar="LEFT RIGHT", help="a stereo pair (repeatable)")
@click.option("--rg", "rgs", multiple=True, metavar="FRAME", help="an RG frame: left in red, right in green")
@click.option("--dir", "directory", metavar="DIR",
              help="*_L.*/*_R.* pairs, *.png RG frames, or folders *_L/*_R of images paired by name")
@click.option("--video", nargs=2, metavar="LEFT RIGHT", default=None, help="two synchronised video files")
@click.option("--rg-video", metavar="FILE", help="one RG video")
@click.option("--sync-offset", type=int, default=0, metavar="N",
              help="--video: the right video's frame k + N shows the left's frame k (N < 0: the left started later)")
@click.option("--every", type=click.IntRange(min=1), default=1, show_default=True, help="survey every N-th frame")
@click.option("--max-frames", type=click.IntRange(min=1), default=None, help="survey at most M pairs")
@click.option("--json", "json_path", required=True, metavar="OUT.json")
@click.option("--plot", "plot_path", metavar="HIST.png", help="weight and length histograms (PNG)")
@click.option("--csv", "csv_path", metavar="FISH.csv", help="every fish, units in the headers")
@click.option("--config", "config_path", metavar="farm.toml", help="farm config: [stocks.NAME], the ledger for --tank")
@click.option("--tank", "tank_id", help="record the survey in the ledger for this tank: its rations follow it")
@click.option("--stock", help="use this stock's a, b (farm.toml [stocks.NAME]) instead of the species'")
@click.option("--up", "up", metavar="x,y,z", help="water-surface normal in the calibration's frame")
@click.option("--floor-mm", "floor_mm", type=Finite(min=0.001, max=100_000), default=None, metavar="MM",
              help="surface setup: the tank floor's distance below the left camera (along --up); what lies "
                   "on it (fish shadows, debris) is not counted")
@click.option("--workers", type=_WORKERS, default=None, metavar="N|tcp/HOST:PORT",
              help="N local processes (default: cores), or the vision workers reached at this Zenoh endpoint")
@click.option("--site", default="demo", show_default=True, help="farm site of the vision workers (--workers ENDPOINT)")
@click.option("--user", default=None, help="Zenoh user name at --workers ENDPOINT (a deployment's router)")
@click.option("--password", default=None, help="its Zenoh password")
@click.option("--seed", type=click.IntRange(min=0), default=1, show_default=True, help="seed of the bootstrap interval")
@click.option("--measure", default=None, hidden=True, help="module:function measuring a pair (tests)")
def survey(calib_path, species, setup, pairs, rgs, directory, video, rg_video, sync_offset, every, max_frames,
           json_path, plot_path, csv_path, config_path, stock, tank_id, up, floor_mm, workers, site, user, password,
           seed, measure):
    """Fish lengths and weights from stereo pairs, with the survey's statistics."""
    from controller.cli.calib_io import load_calibration
    from controller.cli.output_paths import check_outputs
    from controller.feeding.rations import species_file
    from controller.surveys.runner import MEASURE
    from controller.surveys.species import survey_species, with_stock
    from controller.surveys.survey import SurveyOptions, run_survey
    sp = survey_species(species, species_file(config_path))
    if stock:
        sp = with_stock(sp, config_path or "config/farm.toml", stock)
    elif config_path and not tank_id:
        raise click.UsageError("--config is read for --stock NAME or --tank T only: give one of them too")
    config_path = config_path or ("config/farm.toml" if (stock or tank_id) else None)
    record = _recorder(config_path, tank_id, species, json_path) if tank_id else None
    calib = load_calibration(calib_path)
    up_world = _up(up)
    source, files = _source(pairs, rgs, directory, video, rg_video, every, max_frames, sync_offset)
    # (the page is written by renaming a new file into place: its directory is what must be writable)
    check_outputs({"--json": json_path, "--csv": csv_path, "--plot": plot_path},
                  [calib_path, config_path, getattr(record, "ledger", None), *files])
    if plot_path:
        from controller.plotting import check_figure_name
        check_figure_name(plot_path, "--plot")
    if (user is not None or password is not None) and not isinstance(workers, str):
        raise BadInput("--user", None, "a login is for --workers tcp/HOST:PORT (a deployment's router)")
    remote, session = _remote(workers, site, user, password) if isinstance(workers, str) else (None, None)
    progress = _Progress(source.total)
    _warn_sparse(source, progress)
    _warn_copies(source, progress)
    if floor_mm is not None and setup != "surface":
        raise BadInput("--floor-mm", None, "the tank floor is the surface setup's (--setup surface)")
    opts = SurveyOptions(sp.setup(setup, up_world, floor_mm), sp, workers=None if remote else workers, seed=seed,
                         measure=measure or MEASURE, on_pair=progress, record=record, remote=remote,
                         before_commit=_plotter(plot_path))
    try:
        summary = run_survey(source, calib, opts, json_path, csv_path)
    finally:
        progress.stop()
        if session is not None:
            session.close()
    if measured_none(summary):
        _why_no_fish(calib, lambda: _source(pairs, rgs, directory, video, rg_video, every, max_frames,
                                            sync_offset)[0])
    w = summary["weight_g"]
    mean = "n/a" if w["mean"] is None else f"{w['mean']:.1f} g"
    ci = "" if not w["ci"] else f" (95 % CI {w['ci'][0]:.1f}-{w['ci'][1]:.1f})"
    rejected = summary["rejected_lengths_cm"]
    shown = ", ".join(f"{x:.1f}" for x in rejected[:5]) + (" ..." if len(rejected) > 5 else "")
    left_out = f"; {len(rejected)} left out as measuring errors ({shown} cm)" if rejected else ""
    click.echo(f"{summary['count']} fish in {summary['frames']} pairs{_tracked(summary)}: mean weight {mean}{ci}"
               f"{left_out}", err=True)


FIT_PAIRS = 5


def measured_none(summary: dict) -> bool:
    """Pairs surveyed and no fish measured in any (not: measured, and no track long enough to count:
    "no fish in any pair" was said of a clip with 5 measurements)."""
    return summary["frames"] > 0 and summary.get("fish_entries", summary["count"]) == 0


def _why_no_fish(calib, source) -> None:
    """No fish in any pair: the first pairs' own texture against the calibration (vision.pair_fit),
    a warning when the views look swapped or the calibration is another rig's. Best effort: a pair
    that cannot be read again says nothing here (the survey has said what it had to)."""
    import itertools

    from controller.surveys.frames import read_pair
    from vision.pair_fit import pair_fit, verdict
    try:
        views = [read_pair(job)[:2] for job in itertools.islice(source().jobs, FIT_PAIRS)]
        said = verdict(pair_fit(views, calib))
    except Exception:  # noqa: BLE001 - a hint, never a survey's failure
        return
    if said is not None:
        click.echo(f"fishfarm survey: warning: no fish in any pair, and {said}", err=True)


def _warn_copies(source, progress, shown: int = 3) -> None:
    """Stills whose images are an earlier pair's (frames._distinct): left out, said first."""
    copies = source.warnings or []
    for text in copies[:shown]:
        progress.say(f"fishfarm survey: warning: {text}")
    if len(copies) > shown:
        progress.say(f"fishfarm survey: warning: and {len(copies) - shown} more copies, each surveyed once")


def _warn_sparse(source, progress) -> None:
    """Video surveyed at fewer than CONFIRMING_RATE pairs a second: a fish swims far between pairs,
    so the tracker may lose it (counted twice) or join two fish into one track; said once, first."""
    from controller.surveys.survey import CONFIRMING_RATE
    if source.fps is None or source.fps / source.every >= CONFIRMING_RATE:
        return
    most = max(1, int(source.fps // CONFIRMING_RATE))
    progress.say(f"fishfarm survey: warning: pairs {source.every / source.fps:.2f} s apart (--every {source.every} at "
                  f"{source.fps:g} frames/s): a fish may swim out of its track's reach between pairs and be "
                  f"counted twice, or two fish be joined; --every {most} or less surveys "
                  f"{CONFIRMING_RATE:g} pairs a second or more")


def _plotter(plot_path: str | None):
    """The page written before OUT.json is put in place and the survey recorded (a page that
    cannot be written fails the survey as a whole), or None."""
    if not plot_path:
        return None

    def plot(summary: dict) -> None:
        from controller.surveys.plot import plot_survey
        plot_survey(summary, plot_path)
    return plot


def _tracked(summary: dict) -> str:
    """In video, why the count is not the entries': each fish counts once, and only a track of
    enough sightings counts (the JSON's ``fish`` lists every measurement of every frame)."""
    tracks = summary.get("tracks") or {}
    if summary.get("statistics_per") != "track":
        return ""
    most = tracks.get("min_sightings", 1)
    kept = f", those seen in at least {most} pairs counted" if most > 1 else ""
    return f" ({summary.get('fish_entries', 0)} measurements of {tracks.get('seen', 0)} tracked fish{kept})"
