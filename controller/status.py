"""The whole state snapshot (``farm/{site}/status``, the console, the SCADA coordinator): built
from what the controller's parts already hold, never from a device. Parts still starting read
as absent or "starting"."""
from __future__ import annotations

import time


def farm_status(c) -> dict:
    """``c``: the Controller (controller/app.py)."""
    now = c.clock.now()
    tanks = {}
    pending = c.robot.pending if c.robot is not None else {}
    store = getattr(c, "store", None)
    paused = store.paused_tanks() if store is not None and store.db is not None else {}
    for tank in c.cfg.tanks:
        r = c.rations.today(tank.id, now)
        job = pending.get(tank.id)
        tanks[tank.id] = {"demand": job is not None,
                          "demand_t": None if job is None else c.clock.iso(job.t),
                          "fed_g": round(r.fed_g, 1), "ration_g": round(r.grams, 1),
                          "pellet_mm": r.pellet_mm, "stock": c.rations.stock(tank.id),
                          "paused": tank.id in paused, **_weights(c, tank.id, now, r)}
        demand = getattr(c, "filter", None)     # absent while the controller starts
        note = demand.slow_fish(tank.id) if demand is not None and tank.id in demand.tanks else None
        if note is not None:
            tanks[tank.id]["slow_fish"] = note
    # an e-stop while starting latched the devices, and the robot will start in it: the feeder is in
    # e-stop (SCADA's coil 0 read 0 under a standing e-stop alarm), and still starting (optional field)
    feeder = c.robot.snapshot() if c.robot is not None else {
        "t": c.clock.iso(now), "state": "starting" if getattr(c, "estop_before_start", None) is None else "estop",
        "position_m": None, "hopper_g": None, "starting": True}
    out = {"t": c.clock.iso(now), "site": c.cfg.site, "feeder": feeder,
           "uptime_s": round(time.monotonic() - c.started_monotonic, 3),
           "tanks": tanks,
           "alarms": c.alarms.listing()}
    water = getattr(c, "water", None)
    if water is not None and water.device is not None:
        out["water"] = water.snapshot()
    cleaner = getattr(c, "cleaner", None)
    if cleaner is not None:
        out["cleaner"] = cleaner.snapshot()
    elif c.cfg.cleaning is not None:
        out["cleaner"] = {"t": c.clock.iso(now), "state": "starting", "x_m": None, "y_m": None,
                          "heading_rad": None, "coverage": None}
    if getattr(c, "contacts", None) is not None:
        out["contacts"] = contact_lines(c)
    stops = getattr(c, "survey_stops", None)
    if stops is not None:                 # the survey under way (tank, pairs so far) and those asked for
        out["survey"] = stops.snapshot()
    suspects = store.suspects() if store is not None and store.db is not None else []
    if suspects:      # feeds of unknown outcome, held against the ration until settled
        out["suspect"] = [{"id": f.id, "tank": f.tank, "date": f.date, "t": c.clock.iso(f.t_intent),
                           "target_g": round(f.target_g, 1), "note": f.note} for f in suspects]
    return out


def contact_lines(c) -> dict:
    """The contact hub's line health since the controller started, across reconnections: lines
    rejected (noise, bad checksum) and missing by sequence number, sensors nobody configured. A
    noisy line shows here before fish go unheard."""
    hub, carried = c.contacts, c.contacts_carried
    return {"device": hub.name, "unknown_sensors": sorted(c.unknown_sensors),
            **{count: carried[count] + getattr(hub, count, 0) for count in carried}}


def _weights(c, tank_id: str, now: float, ration=None) -> dict:
    """What the tank's ration rests on, and its last survey's figures (None before any); ``ration``:
    today's (``Rations.today``), where the caller has it already."""
    ration = ration if ration is not None else c.rations.today(tank_id, now)
    basis = c.rations.basis(tank_id, now)
    watch = getattr(c, "surveys", None)
    f = watch.figures.get(tank_id, {}) if watch is not None else {}
    water = getattr(c, "water", None)
    temp = water.temperature(tank_id, now) if water is not None else None
    # today's ration's own basis, as its topic says it ("operator" once an operator set it); the mean
    # weight is the tank's estimate all the same
    return {"mean_weight_g": round(basis.mean_weight_g, 2), "ration_basis": ration.source,
            "water_temp_c": None if temp is None else round(temp.celsius, 2),
            "water_temp_source": None if temp is None else temp.source,
            "last_survey_t": f.get("last_survey_t"), "weight_cv_pct": f.get("weight_cv_pct"),
            "sgr_pct_day": f.get("sgr_pct_day"), "fcr": f.get("fcr"), **_fitted(basis, f.get("fit"))}


def _fitted(basis, fit: dict | None) -> dict:
    """The growth fit's figures (optional fields): the ration weight's 95 % interval today, SGR and
    FCR over the fit's window with theirs."""
    out = {}
    if basis.growth is not None:
        out["weight_ci_pct"] = round(basis.growth["weight_ci_pct"], 2)
    if fit is not None:
        out |= {"sgr_fit_pct_day": fit["sgr_pct_day"], "sgr_fit_ci_pct_day": fit["sgr_ci_pct_day"],
                "fcr_fit": fit["fcr"], "fcr_fit_ci": fit["fcr_ci"], "fcr_net_fit": fit.get("fcr_net"),
                "fit_surveys": fit["surveys"]}
    return out
