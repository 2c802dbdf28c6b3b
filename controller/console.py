"""What the operator at the terminal sees: one status line per tank, refreshed live.

On a terminal a rich table is redrawn in place; otherwise (a service log) one compact
line per tank is logged every ``every_wall_s``.
"""
from __future__ import annotations

import asyncio
import logging
import sys

log = logging.getLogger("fishfarm.status")


def tank_lines(status: dict) -> list[str]:
    feeder = status["feeder"]
    lines = [f"{status['t']}  feeder {feeder['state']:<10} at {feeder['position_m']} m, "
             f"hopper {feeder['hopper_g']} g"]
    for tank_id, tank in status["tanks"].items():
        demand = "DEMAND" if tank["demand"] else "quiet "
        pct = 100.0 * tank["fed_g"] / tank["ration_g"] if tank["ration_g"] else 0.0
        lines.append(f"  {tank_id:<6} {demand}  fed {tank['fed_g']:>8.1f} / {tank['ration_g']:>8.1f} g "
                     f"({pct:5.1f} %)  pellet {tank['pellet_mm']} mm")
    for alarm in status["alarms"]:
        lines.append(f"  ALARM {alarm['severity']} {alarm['source']}: {alarm['text']}")
    return lines


def _table(status: dict):
    from rich.table import Table
    feeder = status["feeder"]
    table = Table(title=f"fishfarm {status['site']}  {status['t']}  feeder: {feeder['state']} "
                        f"at {feeder['position_m']} m, hopper {feeder['hopper_g']} g")
    for col in ("tank", "demand", "fed today (g)", "ration (g)", "%", "pellet"):
        table.add_column(col, justify="right" if col != "tank" else "left")
    for tank_id, tank in status["tanks"].items():
        pct = 100.0 * tank["fed_g"] / tank["ration_g"] if tank["ration_g"] else 0.0
        table.add_row(tank_id, "[bold yellow]DEMAND[/]" if tank["demand"] else "-", f"{tank['fed_g']:.1f}",
                      f"{tank['ration_g']:.1f}", f"{pct:.0f}", f"{tank['pellet_mm']} mm")
    for alarm in status["alarms"]:
        table.caption = (table.caption or "") + f"\nALARM {alarm['source']}: {alarm['text']}"
    return table


async def show(get_status, every_wall_s: float = 1.0, log_every_wall_s: float = 60.0) -> None:
    if sys.stdout.isatty():
        from rich.live import Live
        with Live(_table(get_status()), refresh_per_second=2, transient=False) as live:
            while True:
                await asyncio.sleep(every_wall_s)
                live.update(_table(get_status()))
    else:
        while True:
            await asyncio.sleep(log_every_wall_s)
            for line in tank_lines(get_status()):
                log.info("%s", line)
