"""New weight surveys in the ledger, taken up by the running controller.

A survey lands in the ledger from another process (``fishfarm survey --tank``) or, later, the
survey scheduler. Each housekeeping tick the controller looks for a tank's newest survey; for one
it has not taken up yet (and at start, for the newest of each tank):

- today's ration is planned again from it (an operator's ration stands) and published;
- the survey is published on ``farm/{site}/tank/{tank}/survey``: its OUT.json (the survey's
  ``source``, when that file is still there and is the survey's) plus ``"t"`` (ISO), else the
  ledger's summary of it in OUT.json's shape;
- the tank's grading alarm (``grading/{tank}``) is raised when the weight CV is above
  ``[feeding] grading_cv_pct``, cleared when a later survey is within it;
- a survey that counted no fish (cameras blocked or fouled, the lights, turbid water) is published
  all the same (count 0: an empty survey is a result) and raises the tank's ``survey/{tank}``
  warning (kind ``no_fish``) until a later survey weighs the tank; nothing is planned from it: the
  ration stays on the surveys that weigh the tank, and says "projected" once they are old. One that
  counted fewer than ``[surveys] min_weighed_fish`` (10) is treated alike (kind ``few_fish``): three
  fish of two thousand, a reef hiding the rest, read a tank 25 % light and its ration followed;
- a survey whose mean weight is off the growth fitted to the surveys before it by more than the two
  uncertainties allow (``production.against_growth``, in the figures as ``against_growth``) raises
  ``survey/{tank}`` (kind ``off_growth``) until a later one follows it; the ration follows it all the
  same (a manager may set one by hand);
- its production figures between its last two surveys (controller/production.py) are published on
  ``farm/{site}/tank/{tank}/figures`` and kept for the status snapshot and the SCADA map, with
  (``fit``) SGR and FCR fitted to every survey of the growth window and their 95 % intervals.
"""
from __future__ import annotations

import json
import logging
from datetime import UTC, datetime

log = logging.getLogger(__name__)
GRADING = "grading"
NO_FISH = "no_fish"
FEW_FISH = "few_fish"
OFF_GROWTH = "off_growth"


class SurveyWatch:
    def __init__(self, cfg, store, rations, alarms, publish):
        self.cfg, self.store, self.rations, self.alarms, self.publish = cfg, store, rations, alarms, publish
        self.taken: dict[str, int] = {}        # tank -> id of the survey last taken up
        self.empty: dict[str, int] = {}        # tank -> id of the survey that counted no fish, last seen
        self.figures: dict[str, dict] = {}      # tank -> the latest figures (status, SCADA)

    def check(self, now: float) -> list[str]:
        """Take up each tank's newest survey not yet seen; returns the tanks that had one (that
        counted fish: an empty one only publishes and warns)."""
        fresh = []
        least = self.store.min_weighed
        for tank in self.cfg.tanks:
            [last] = self.store.surveys(tank.id, until=now, limit=1, counted=None) or [None]
            counted = last if last is None or last.count >= least else \
                next(iter(self.store.surveys(tank.id, until=now, limit=1)), None)
            if counted is not None and self.taken.get(tank.id) != counted.id:
                self._take_up(tank.id, counted, now)
                fresh.append(tank.id)
            if last is not None and last.count < least:
                self._empty(tank.id, last, counted)
            elif last is not None:
                for kind in (NO_FISH, FEW_FISH):
                    self.alarms.clear(f"survey/{tank.id}", f"tank {tank.id}: the survey of {_iso(last.t)} "
                                      f"counted {last.count} fish", kind=kind)
        return fresh

    def _take_up(self, tank_id: str, survey, now: float) -> None:
        self.taken[tank_id] = survey.id
        self.rations.replan(tank_id, now)
        self.publish(f"tank/{tank_id}/ration", self.rations.payload(tank_id, now))
        self.publish(f"tank/{tank_id}/survey", survey_payload(survey))
        self._grading(tank_id, survey)
        self.figures[tank_id] = figures = self._figures(tank_id, survey)
        self._against_growth(tank_id, survey, figures)
        self.publish(f"tank/{tank_id}/figures", figures)

    def _against_growth(self, tank_id: str, survey, figures: dict) -> None:
        """The survey against the tank's growth before it (``production.against_growth``): in the
        figures, and the ``survey/{tank}`` warning (kind ``off_growth``) while the newest is off it."""
        from controller.production import against_growth
        got = figures["against_growth"] = against_growth(self.store, tank_id, survey,
                                                         self.cfg.feeding.growth_window_d)
        when = _iso(survey.t)
        if got is None or not got["off"]:
            self.alarms.clear(f"survey/{tank_id}", f"tank {tank_id}: the survey of {when} follows its growth",
                              kind=OFF_GROWTH)
            return
        side = "heavier" if got["off_pct"] > 0 else "lighter"
        text = (f"tank {tank_id}: the survey of {when} reads {abs(got['off_pct']):.1f} % {side} than the growth "
                f"of the {got['surveys']} surveys before it (beyond {abs(got['band_pct']):.1f} %): a camera moved "
                f"or its calibration out of date, another stock? The ration follows it")
        self.alarms.raise_(f"survey/{tank_id}", text, kind=OFF_GROWTH)

    def _empty(self, tank_id: str, last, counted) -> None:
        """``last``, the tank's newest survey, counted too few fish to weigh the tank (none, or fewer
        than ``[surveys] min_weighed_fish``): published once, and the no-fish or few-fish warning
        raised (``counted``: the newest survey that does weigh it, or None)."""
        if self.empty.get(tank_id) == last.id:
            return
        self.empty[tank_id] = last.id
        self.publish(f"tank/{tank_id}/survey", survey_payload(last))
        rests = f"the surveys that counted fish (newest {_iso(counted.t)})" if counted is not None \
            else "the configured weight"
        if last.count == 0:
            what, kind = "counted no fish (cameras blocked or fouled, lights, turbid water?)", NO_FISH
        else:
            what = (f"counted {last.count} fish, fewer than the {self.store.min_weighed} that weigh the tank "
                    f"(a water or a background that hides most fish?): not planned from")
            kind = FEW_FISH
        other = FEW_FISH if kind == NO_FISH else NO_FISH
        self.alarms.clear(f"survey/{tank_id}", f"tank {tank_id}: the survey of {_iso(last.t)} counted "
                          f"{last.count} fish", kind=other)
        self.alarms.raise_(f"survey/{tank_id}", f"tank {tank_id}: the survey of {_iso(last.t)} {what}; "
                           f"the ration rests on {rests}", kind=kind)

    def _figures(self, tank_id: str, survey) -> dict:
        from controller.production import tank_figures
        f = tank_figures(self.cfg, self.store, tank_id, last=2)
        last = f["intervals"][-1] if f["intervals"] else {}
        return {"t": _iso(survey.t), "last_survey_t": _iso(survey.t), "fish": survey.count,
                "mean_weight_g": survey.mean_weight_g, "weight_cv_pct": survey.cv_pct,
                "condition_k": f["surveys"][-1]["k"] if f["surveys"] else None,
                "sgr_pct_day": last.get("sgr_pct"), "fcr": last.get("fcr"), "fcr_net": last.get("fcr_net"),
                "feed_g": last.get("feed_g"),
                "gain_g": last.get("gain_g"), "days": last.get("days"), "grading": f.get("grading"),
                "projection": f.get("projection"), "fit": f.get("fit")}

    def _grading(self, tank_id: str, survey) -> None:
        limit = self.cfg.feeding.grading_cv_pct
        cv = survey.cv_pct or 0.0
        when = _iso(survey.t)
        if cv > limit:
            self.alarms.raise_(f"grading/{tank_id}", f"tank {tank_id}: weight CV {cv:.1f} % above {limit:g} % "
                               f"(survey {when}, {survey.count} fish): grade the stock", kind=GRADING)
        else:
            self.alarms.clear(f"grading/{tank_id}", f"tank {tank_id}: weight CV {cv:.1f} % (survey {when})",
                              kind=GRADING)


def survey_payload(survey) -> dict:
    """OUT.json + {"t": iso} when the survey's OUT.json is at hand, else the ledger's summary."""
    doc = _out_json(survey.source, survey.count)
    if doc is None:
        doc = {"species": survey.species, "count": survey.count, "source": survey.source,
               "length_cm": {"mean": survey.mean_length_cm},
               "weight_g": {"mean": survey.mean_weight_g, "sd": survey.sd_weight_g},
               "cv_pct": survey.cv_pct}
    return {**doc, "t": _iso(survey.t)}


def _out_json(path: str, count: int) -> dict | None:
    try:
        with open(path, encoding="utf-8") as fh:
            doc = json.load(fh)
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and doc.get("count") == count else None


def _iso(t: float) -> str:
    """As the rest of the snapshot stamps time: UTC, milliseconds, ``Z``."""
    return datetime.fromtimestamp(t, UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")
