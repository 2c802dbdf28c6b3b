"""The stereo camera kind: its section, the ``capture`` driver over the simulated pair on the
carriage (MJPEG over HTTP, side by side), and the simulated fish it shows growing."""
from __future__ import annotations

import asyncio
import json
import threading
import types

import numpy as np
import pytest

from devices.clock import ManualClock
from devices.errors import BadInput
from devices.sections import section_model, validate_section
from devices.sim.fish import SimFishParams, SimTank
from devices.sim.fish_species import SPECIES
from devices.sim.stereo_camera import VISIT_GAP_S, SimStereoCameraParams, TankView, frame_size
from devices.sim.stereo_rig import convergent_rig
from devices.sim.stock import SimStock, SimStockParams
from devices.sim.tower_camera import SimTowerCamera
from devices.stereo import StereoPair
from devices.stereo.capture import CaptureStereo, split_pair

W, H = 320, 240


@pytest.fixture
def calib_file(tmp_path):
    path = tmp_path / "CALIB.json"
    path.write_text(json.dumps(convergent_rig(image_size=(W, H)).calibration().to_json()))
    return str(path)


def section(calib, **kw):
    return {"kind": "stereo_camera", "driver": "capture", "sources": ["rtsp://a", "rtsp://b"], "calib": calib, **kw}


def validate(data):
    return validate_section(section_model("stereo_camera", data["driver"]), data, "farm.toml", "devices.stereo")


def test_the_section_is_the_capture_drivers_and_faults_name_the_key(calib_file, tmp_path):
    assert validate(section(calib_file)).layout == "pair"
    with pytest.raises(BadInput, match=r"^farm.toml: devices.stereo.zoom: unknown key$"):
        validate(section(calib_file, zoom=2))
    with pytest.raises(BadInput, match="layout 'side_by_side' takes 1 source, not 2"):
        validate(section(calib_file, layout="side_by_side"))
    with pytest.raises(BadInput, match=r"devices.stereo.calib: .*nope.json: No such file"):
        validate(section(str(tmp_path / "nope.json")))
    (tmp_path / "bad.json").write_text(json.dumps({"P1": [[1, 0, 0, 0]] * 3, "P2": [[1, 0, 0, 0]] * 3}))
    with pytest.raises(BadInput, match=r"devices.stereo.calib: .*bad.json: "):
        validate(section(str(tmp_path / "bad.json")))
    with pytest.raises(BadInput, match=r"devices.stereo.portt: unknown key"):
        validate({"kind": "stereo_camera", "driver": "sim", "portt": 1})


def test_one_frame_carrying_both_views_is_split():
    frame = np.zeros((4, 6, 3), np.uint8)
    frame[:, :3] = 10
    frame[:, 3:] = 20
    left, right = split_pair(frame, "side_by_side")
    assert left.shape == right.shape == (4, 3, 3) and (left == 10).all() and (right == 20).all()
    frame[..., 2], frame[..., 1] = 7, 9               # BGR: red is left, green is right
    left, right = split_pair(frame, "rg")
    assert (left == 7).all() and (right == 9).all()


def a_tank(count: int, weight_g: float, t0: float = 0.0) -> SimTank:
    """A simulated tank whose fish grow on what they eat (devices/sim/stock.py), none dying."""
    tank_cfg = types.SimpleNamespace(id="T1", sensors=["s"], stock=count, mean_weight_g=weight_g,
                                     species="sparus_aurata")
    tank = SimTank(tank_cfg, SimFishParams(), np.random.default_rng(0), t0=t0)
    tank.stock = SimStock("T1", count, weight_g, SimStockParams(mortality_pct_day=0.0), np.random.default_rng(1), t0)
    return tank


def test_the_cameras_see_the_stock_grow_on_what_it_eats():
    tank = a_tank(1000, 20.0)
    view = TankView(SimStereoCameraParams(width=W, height=H), {"T1": tank}, lambda t: "T1")
    sp = SPECIES["sparus_aurata"]
    before, _, _ = view._sizes(tank, sp, 0.0)
    tank.feed(2800.0, 3600.0)                        # 2,800 g eaten at fcr 1.4: +2,000 g of fish, +2 g each
    after, length, _ = view._sizes(tank, sp, 3600.0)
    assert before == pytest.approx(20.0, rel=0.05) and after == pytest.approx(22.0, rel=0.05)
    assert after - before == pytest.approx(2.0, rel=0.3)
    assert length == pytest.approx((22.0 / sp.a) ** (1 / sp.b), rel=0.05)


def test_pairs_of_the_tank_under_the_carriage_come_through_videocapture(tmp_path):
    async def main():
        clock = ManualClock(t=1000.0)
        params = SimStereoCameraParams(width=W, height=H, fps=20, fish_in_view=(3, 3), focal_px=1400)
        tanks = {"T1": a_tank(100, 200.0)}
        where = {"tank": "T1"}
        view = TankView(params, tanks, lambda t: where["tank"])
        served = SimTowerCamera(view.render, clock, {"fps": params.fps, "jpeg_quality": 95, **frame_size(params)})
        served.start()
        calib = view.write_calibration(tmp_path / "CALIB.json")
        cfg = validate({"kind": "stereo_camera", "driver": "capture", "sources": [served.url],
                        "layout": "side_by_side", "calib": calib, "api": "ffmpeg"})
        cam = CaptureStereo("stereo", cfg, clock)
        await cam.open()
        assert served.rendered == 0                  # nothing streams before a survey starts
        await cam.start()
        pairs = [await cam.read() for _ in range(3)]
        where["tank"] = None                         # the carriage moved off: empty water
        clock.t = 10 * 86400.0
        while view.seen[-1][1] is not None:
            await cam.read()
        await cam.stop()
        await cam.close()
        served.stop()
        return cam, view, pairs
    cam, view, pairs = asyncio.run(main())
    assert np.allclose(cam.calibration.P1, view.rig.calibration().P1)
    for pair in pairs:
        assert isinstance(pair, StereoPair)
        assert pair.left.shape == pair.right.shape == (H, W, 3)
        assert not np.array_equal(pair.left, pair.right)          # two viewpoints
    assert [p.seq for p in pairs] == [1, 2, 3]
    seen = [s for s in view.seen if s[1] == "T1"]
    assert seen and all(w == pytest.approx(200.0, rel=0.1) for _, _, w in seen)     # the stock's fish


def test_the_water_is_drawn_once_a_visit():
    """A visit: frames of one tank at most VISIT_GAP_S apart. Another tank, empty water, a gap (the
    stream closed between surveys) or a clock set back each draw new water."""
    where = {"tank": "T1"}
    tanks = {"T1": a_tank(100, 20.0), "T2": a_tank(100, 40.0)}
    view = TankView(SimStereoCameraParams(width=W, height=H, fish_in_view=(1, 2)), tanks, lambda t: where["tank"])
    visits = []
    for tank, t in [("T1", 0.0), ("T1", 5.0), ("T1", 5.0 + VISIT_GAP_S), ("T2", 130.0), ("T2", 140.0), (None, 150.0),
                    (None, 151.0), ("T2", 152.0), ("T2", 153.0 + VISIT_GAP_S + 0.5), ("T2", 100.0)]:
        where["tank"] = tank
        view.render(t)
        visits.append(view.visits)
    assert visits == [1, 1, 1, 2, 2, 3, 3, 4, 5, 6]


def test_a_tank_that_keeps_its_fish_as_individuals_is_drawn_from_them():
    """A stock of individuals (weights lognormal here): the stills' lengths follow theirs."""
    class Stock:
        def __init__(self):
            self.w = np.random.default_rng(1).lognormal(np.log(150.0), 0.25, 5000)

        def weights(self, n, rng):
            return rng.choice(self.w, n)

    tank = types.SimpleNamespace(species="sparus_aurata", stock=Stock())
    view = TankView(SimStereoCameraParams(width=W, height=H), {"T1": tank}, lambda t: "T1")
    weight, length, cv = view._sizes(tank, SPECIES["sparus_aurata"], 0.0)
    lengths = (tank.stock.w / 0.02263) ** (1 / 3.032)
    assert weight == pytest.approx(tank.stock.w.mean(), rel=0.05)
    assert length == pytest.approx(lengths.mean(), rel=0.02) and cv == pytest.approx(lengths.std() / lengths.mean(),
                                                                                      rel=0.15)


def _readers(name: str) -> int:
    """Streams' reader threads (not the opens' own threads, which end just after handing over their
    capture: counted, one still ending made a flaky 2)."""
    return sum(1 for t in threading.enumerate()
               if t.name.startswith(f"{name}/") and t.name.endswith("-reader") and t.is_alive())


def test_starts_and_stops_asked_at_once_open_one_stream_and_leave_none(tmp_path):
    """A survey visit left while its start was still opening; the next visit's start went on after
    60 s without waiting longer: two starts at once opened the sources twice, and the first
    stream was never closed (a probe's controller held 209 reader threads and 6 GB)."""
    async def main():
        clock = ManualClock(t=1000.0)
        params = SimStereoCameraParams(width=W, height=H, fps=20, fish_in_view=(1, 1), focal_px=1400)
        view = TankView(params, {"T1": a_tank(100, 200.0)}, lambda t: "T1")
        served = SimTowerCamera(view.render, clock, {"fps": params.fps, "jpeg_quality": 95, **frame_size(params)})
        served.start()
        cfg = validate({"kind": "stereo_camera", "driver": "capture", "sources": [served.url],
                        "layout": "side_by_side", "calib": view.write_calibration(tmp_path / "CALIB.json"),
                        "api": "ffmpeg"})
        cam = CaptureStereo("stereo-once", cfg, clock)
        await cam.open()
        seen = []
        try:
            for _ in range(2):
                await asyncio.gather(cam.start(), cam.start(), cam.start())
                seen.append(_readers("stereo-once"))
                await cam.read()
                # a stop asked while a start is opening stops what that start opened
                await asyncio.gather(cam.start(), cam.stop())
                await asyncio.sleep(0)
                seen.append((cam.streaming, _readers("stereo-once")))
                await cam.stop()
                seen.append(_readers("stereo-once"))
        finally:
            await cam.close()
            served.stop()
        return seen
    assert asyncio.run(main()) == [1, (False, 0), 0] * 2


def test_a_video_file_goes_on_at_each_visit_where_the_last_left_it(tmp_path, calib_file):
    """A survey from footage (a side-by-side file): each visit played the file from its start, so
    one survey measured its first frames twice. Frames carry their index here (a grey level)."""
    import cv2
    path = str(tmp_path / "pair.avi")
    out = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (2 * W, H))
    for k in range(60):
        out.write(np.full((H, 2 * W, 3), 2 * k + 10, np.uint8))
    out.release()

    def index(pair) -> int:
        return round((float(pair.left.mean()) - 10) / 2)

    async def main():
        clock = ManualClock(t=0.0)
        cfg = validate({"kind": "stereo_camera", "driver": "capture", "sources": [path], "layout": "side_by_side",
                        "calib": calib_file, "api": "ffmpeg"})
        cam = CaptureStereo("stereo", cfg, clock)
        await cam.open()
        seen = []
        for _visit in range(3):
            await cam.start()
            for _ in range(4):
                seen.append(index(await cam.read()))
            await cam.stop()
        await cam.close()
        return seen
    seen = asyncio.run(main())
    assert seen == sorted(seen) and len(set(seen)) == len(seen), seen         # no frame twice, in order
    assert seen[4] > seen[3] and seen[8] > seen[7]
