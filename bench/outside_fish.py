"""Stereo pairs of fish from a renderer the survey was not built on: an outside tester's, written
from scratch on 2026-12-06 (issue 7) with nothing of the project's but the rig's camera matrices
(``devices.sim.stereo_rig.convergent_rig``). A fish is a flat textured plane in 3-D warped into
each view through its exact homography, drawn at 2x and area-downsampled: bodies with a humped
back, a narrow peduncle and a V-forked tail, dorsal, anal and pelvic fins, an eye and a gill line;
uniform, countershaded, striped or spotted, fins translucent in 60 %; blue-green, green or blue
water with haze, red absorbed first and a vertical light gradient; a rock or net backdrop 2.6-3.8 m
away in two scenes of three; blur, noise and a JPEG round trip. ``render_pair(rig, rng, idx)``
returns the left and right BGR images and the truth: per fish the 3-D snout and fork (mm), the
fork length ``L``, ``visible`` (the whole outline 3 px inside both images and no other fish within
2 px in either) and the conditions it was drawn with. bench/bench_survey_outside.py measures the
survey on it: a change that gains on ``devices.sim.fish_scene`` and loses here has learned the
project's renderer (as the 2026-12-06 proposers did, ``vision.fish_keypoints``).
"""
from __future__ import annotations

import cv2
import numpy as np

from devices.sim.stereo_rig import convergent_rig

SS = 2                      # supersampling
W, H = 1280, 960


def make_rig():
    return convergent_rig(baseline_mm=400, crossing_mm=1200, focal_px=1400, image_size=(W, H),
                          target=np.array([0, 1200, -1500.0]), forward=np.array([0, 1.0, 0]),
                          up=np.array([0, 0, 1.0]))


# ----------------------------------------------------------------- fish shape (fish-plane, units of FL)
def fish_shape(rng):
    """Polygons in fish-plane coords (x along body from snout=0 to fork=1, y up), units of FL."""
    depth = rng.uniform(0.22, 0.38)
    up_frac = rng.uniform(0.5, 0.62)
    ped = rng.uniform(0.035, 0.055)          # peduncle half-height
    ped_x = rng.uniform(0.82, 0.86)
    lobe_x = rng.uniform(1.08, 1.18)
    lobe_y = rng.uniform(0.13, 0.2)
    snout_y = 0.0
    u = np.linspace(0, ped_x, 60)
    f = np.sin(np.pi * np.clip(u / (ped_x * 1.08), 0, 1) ** rng.uniform(0.55, 0.75))
    f = np.maximum(f, 0)
    upper = np.maximum(depth * up_frac * f, np.where(u > 0.5, ped, 0))
    lower = np.maximum(depth * (1 - up_frac) * f, np.where(u > 0.5, ped, 0))
    # peduncle to fin base
    base_x = ped_x + 0.04
    body_top = np.c_[u, upper + snout_y]
    body_bot = np.c_[u, -lower + snout_y]
    body = np.vstack([body_top, [[base_x, ped * 1.1]], [[base_x, -ped * 1.1]], body_bot[::-1]])
    # caudal fin: lobes, notch at (1, 0)
    caudal = np.array([[ped_x - 0.01, ped * 0.9], [base_x, ped * 1.4],
                       [lobe_x - 0.03, lobe_y * 0.95], [lobe_x, lobe_y],
                       [lobe_x - 0.02, lobe_y * 0.85], [1.0, 0.0],
                       [lobe_x - 0.02, -lobe_y * 0.85], [lobe_x, -lobe_y],
                       [lobe_x - 0.03, -lobe_y * 0.95], [base_x, -ped * 1.4], [ped_x - 0.01, -ped * 0.9]])
    # dorsal + anal fins
    dx0 = rng.uniform(0.3, 0.4)
    dtop = np.interp(dx0, u, upper)
    dorsal = np.array([[dx0, dtop * 0.9], [dx0 + 0.05, dtop + rng.uniform(0.06, 0.12)],
                       [dx0 + 0.28, np.interp(dx0 + 0.28, u, upper) + 0.015],
                       [dx0 + 0.28, np.interp(dx0 + 0.28, u, upper) * 0.8]])
    ax0 = rng.uniform(0.58, 0.64)
    abot = np.interp(ax0, u, lower)
    anal = np.array([[ax0, -abot * 0.9], [ax0 + 0.04, -abot - rng.uniform(0.05, 0.09)],
                     [ax0 + 0.16, -np.interp(ax0 + 0.16, u, lower) - 0.01],
                     [ax0 + 0.16, -np.interp(ax0 + 0.16, u, lower) * 0.8]])
    pelvic = np.array([[0.38, -np.interp(0.38, u, lower) * 0.9], [0.45, -np.interp(0.42, u, lower) - 0.05],
                       [0.48, -np.interp(0.48, u, lower) * 0.95]])
    return dict(body=body, caudal=caudal, fins=[dorsal, anal, pelvic], u=u, upper=upper, lower=lower,
                depth=depth)


PALETTES = {  # dorsal BGR, belly BGR
    "bream": ((95, 100, 90), (215, 215, 210)),
    "salmon": ((110, 95, 70), (225, 225, 220)),
    "trout": ((70, 95, 85), (200, 210, 215)),
    "dark": ((45, 55, 50), (140, 145, 140)),
}


def fish_texture(shape, rng, pattern, fins_translucent, tex_px):
    """RGB (float 0-255) and alpha texture of the fish; texture px per FL = tex_px.
    Texture coords: col = (x + 0.05) * tex_px, row = (0.3 - y) * tex_px."""
    tw, th = int(1.28 * tex_px), int(0.62 * tex_px)
    X = (np.arange(tw) + 0.5) / tex_px - 0.05
    Y = 0.3 - (np.arange(th) + 0.5) / tex_px
    XX, YY = np.meshgrid(X, Y)

    def topx(poly):
        return np.round(np.c_[(poly[:, 0] + 0.05) * tex_px, (0.3 - poly[:, 1]) * tex_px] * 16).astype(np.int32)

    col = np.zeros((th, tw, 3), np.float32)
    alpha = np.zeros((th, tw), np.float32)
    pal = PALETTES[rng.choice(list(PALETTES))]
    back, belly = np.array(pal[0], float), np.array(pal[1], float)
    jitter = rng.uniform(0.8, 1.15)
    back, belly = back * jitter, np.clip(belly * jitter, 0, 255)
    # body colour
    up_i = np.interp(XX, shape["u"], shape["upper"]) + 1e-3
    lo_i = np.interp(XX, shape["u"], shape["lower"]) + 1e-3
    t = np.clip((YY + lo_i) / (up_i + lo_i), 0, 1)          # 0 belly .. 1 back
    if pattern == "uniform":
        c = np.broadcast_to((back + belly) / 2, col.shape).copy()
    else:
        w = np.clip((t - 0.35) / 0.4, 0, 1)[..., None] ** 1.3
        c = belly * (1 - w) + back * w
        # silvery sheen band along the mid flank
        sheen = np.exp(-((t - 0.42) / 0.08) ** 2)[..., None] * rng.uniform(10, 35)
        c = c + sheen
        if pattern == "stripes":
            nb = rng.integers(5, 9)
            phase = rng.uniform(0, 1)
            bars = 0.5 + 0.5 * np.cos(2 * np.pi * (XX * nb / 0.85 + phase))
            bars = (bars > 0.55) * (XX > 0.15) * (XX < 0.82) * (t > 0.2)
            bars = cv2.GaussianBlur(bars.astype(np.float32), (0, 0), tex_px * 0.006)
            c = c * (1 - rng.uniform(0.3, 0.5) * bars[..., None])
        elif pattern == "spots":
            spots = np.zeros((th, tw), np.float32)
            for _ in range(rng.integers(25, 60)):
                sx = rng.uniform(0.12, 0.95)
                sy = rng.uniform(-0.2, 0.2)
                cv2.circle(spots, (int((sx + 0.05) * tex_px), int((0.3 - sy) * tex_px)),
                           max(1, int(rng.uniform(0.006, 0.014) * tex_px)), 1.0, -1)
            spots *= (t > 0.3)
            c = c * (1 - 0.55 * spots[..., None])
        # lateral line
        ll = np.exp(-((t - 0.62) / 0.015) ** 2) * (XX > 0.2) * (XX < 0.85)
        c = c * (1 - 0.15 * ll[..., None])
    # operculum arc and eye
    body_mask = np.zeros((th, tw), np.uint8)
    cv2.fillPoly(body_mask, [topx(shape["body"])], 255, cv2.LINE_AA, 4)
    opx = rng.uniform(0.2, 0.26)
    oper = np.zeros((th, tw), np.float32)
    cv2.ellipse(oper, (int((opx - 0.09 + 0.05) * tex_px), int(0.3 * tex_px)),
                (int(0.09 * tex_px), int(0.1 * tex_px)), 0, -70, 70, 1.0, max(1, int(0.006 * tex_px)))
    c = c * (1 - 0.3 * oper[..., None])
    col[:] = c
    alpha[:] = body_mask / 255.0
    eye_r = max(1, int(rng.uniform(0.025, 0.035) * tex_px))
    ex, ey = int((0.075 + 0.05) * tex_px), int((0.3 - shape["upper"][6] * 0.35) * tex_px)
    cv2.circle(col, (ex, ey), eye_r, (200, 200, 190), -1, cv2.LINE_AA)
    cv2.circle(col, (ex, ey), int(eye_r * 0.6), (15, 15, 15), -1, cv2.LINE_AA)
    # fins
    fin_col = back * rng.uniform(0.7, 1.2) + rng.uniform(-15, 15, 3)
    fin_a = rng.uniform(0.35, 0.65) if fins_translucent else 1.0
    fin_layer = np.zeros((th, tw), np.uint8)
    for poly in [shape["caudal"]] + shape["fins"]:
        cv2.fillPoly(fin_layer, [topx(poly)], 255, cv2.LINE_AA, 4)
    fin_m = (fin_layer / 255.0) * (1 - alpha)        # fins behind/outside body
    # fin rays texture
    rays = 0.85 + 0.15 * np.cos(2 * np.pi * (YY * 60 + XX * 20))
    fc = fin_col[None, None, :] * rays[..., None]
    col = np.where((alpha > 0)[..., None], col, fc)
    alpha_tot = np.clip(alpha + fin_m * fin_a, 0, 1)
    return np.clip(col, 0, 255).astype(np.float32), alpha_tot.astype(np.float32)


# ----------------------------------------------------------------- background
def value_noise(h, w, rng, scales=(64, 24, 8), weights=(1.0, 0.5, 0.25)):
    out = np.zeros((h, w), np.float32)
    for s, wt in zip(scales, weights, strict=True):
        small = rng.random((h // s + 2, w // s + 2)).astype(np.float32)
        out += wt * cv2.resize(small, (w + s, h + s), interpolation=cv2.INTER_CUBIC)[:h, :w]
    return (out - out.min()) / (out.max() - out.min() + 1e-6)


def background_texture(kind, rng, size=2048):
    """(size, size) grey 0..1 texture of a backdrop plane, 1 px = 2 mm (4 m x 4 m)."""
    if kind == "rock":
        n = value_noise(size, size, rng, scales=(96, 32, 8), weights=(1.0, 0.6, 0.3))
        rocks = (n > 0.5).astype(np.float32)
        edges = cv2.Laplacian(cv2.GaussianBlur(rocks, (0, 0), 2), cv2.CV_32F)
        tex = 0.42 + 0.25 * n + 0.15 * rocks - 2 * edges
        return np.clip(tex, 0, 1)
    if kind == "net":
        tex = np.full((size, size), 0.5, np.float32) + 0.1 * value_noise(size, size, rng)
        mesh = int(rng.uniform(15, 25))          # 30-50 mm mesh
        th = 2
        img = np.zeros((size, size), np.uint8)
        for k in range(-size, 2 * size, mesh):
            cv2.line(img, (k, 0), (k + size, size), 255, th, cv2.LINE_AA)
            cv2.line(img, (k, 0), (k - size, size), 255, th, cv2.LINE_AA)
        return np.clip(tex + 0.45 * img / 255.0 * rng.choice([-1, 1]), 0, 1)
    return None


# ----------------------------------------------------------------- projection helpers
def plane_h(K, R, t, origin, e1, e2):
    """3x3 homography from plane coords (a, b) (mm) -> image px: X = origin + a e1 + b e2."""
    return K @ np.c_[R @ e1, R @ e2, R @ origin + t]


def cam_params(rig):
    return [(rig.K1, rig.R1, rig.t1), (rig.K2, rig.R2, rig.t2)]


def render_pair(rig, rng, idx):
    cond = dict(
        bg=str(rng.choice(["plain", "rock", "net"])),
        water=str(rng.choice(["bluegreen", "green", "blue"])),
        blur=float(rng.choice([0.0, 0.6, 1.2])),
        noise=float(rng.uniform(1.5, 6.0)),
        jpeg=int(rng.choice([0, 60, 80, 92])),
        grad=float(rng.uniform(0.25, 0.6)),           # vertical light gradient strength
        atten_m=float(rng.uniform(3.0, 8.0)),
    )
    water = {"bluegreen": (150, 140, 60), "green": (110, 140, 70), "blue": (170, 120, 50)}[cond["water"]]
    water = np.array(water, float) * rng.uniform(0.8, 1.15)
    Ws, Hs = W * SS, H * SS
    # pixel centre convention: hi-res px (u*SS + (SS-1)/2)
    S = np.array([[SS, 0, (SS - 1) / 2], [0, SS, (SS - 1) / 2], [0, 0, 1.0]])
    c1, c2 = rig.centres
    mid = (c1 + c2) / 2
    fwd = np.array([0, 1.0, 0])
    side = np.array([1.0, 0, 0])
    zup = np.array([0, 0, 1.0])
    imgs = [np.tile(water[None, None, :], (Hs, Ws, 1)).astype(np.float32) for _ in range(2)]
    # backdrop
    bgtex = background_texture(cond["bg"], rng)
    if bgtex is not None:
        bdist = rng.uniform(2600, 3800)
        origin = mid + bdist * fwd - 4000 * side + 4000 * zup
        bcol = water * rng.uniform(0.5, 0.9) + np.array([20, 30, 40])
        haze = np.exp(-bdist / 1000 / cond["atten_m"])
        for img, (K, R, t) in zip(imgs, cam_params(rig), strict=True):
            Hm = S @ plane_h(K, R, t, origin, side * 4.0, -zup * 4.0)
            warped = cv2.warpPerspective(bgtex, Hm, (Ws, Hs), flags=cv2.INTER_LINEAR, borderValue=0.5)
            bg = warped[..., None] * 2 * bcol[None, None, :]
            img[:] = bg * haze + water * (1 - haze)
    # fish
    n_fish = int(rng.integers(2, 6))
    fishes = []
    for _ in range(n_fish):
        L = rng.uniform(150, 450)
        dist = rng.uniform(800, 2000)
        centre = mid + dist * fwd + side * rng.uniform(-0.3, 0.3) * dist + zup * rng.uniform(-0.22, 0.22) * dist
        direction = int(rng.choice([-1, 1]))
        yaw = np.radians(rng.uniform(-30, 30))
        tilt = np.radians(rng.uniform(-14, 14))
        roll = np.radians(rng.uniform(-8, 8))
        h = direction * (np.cos(yaw) * side + np.sin(yaw) * fwd)
        h = np.cos(tilt) * h + np.sin(tilt) * zup
        e2 = zup - (zup @ h) * h
        e2 /= np.linalg.norm(e2)
        n = np.cross(h, e2)
        e2 = np.cos(roll) * e2 + np.sin(roll) * n
        snout = centre + 0.5 * L * h
        fork = centre - 0.5 * L * h
        shape = fish_shape(rng)
        pattern = str(rng.choice(["uniform", "gradient", "stripes", "spots"]))
        fins_tr = bool(rng.random() < 0.6)
        fishes.append(dict(L=L, dist=dist, snout=snout, fork=fork, h=h, e2=e2, shape=shape,
                           pattern=pattern, fins_translucent=fins_tr, direction=direction,
                           tilt_deg=float(np.degrees(tilt)), yaw_deg=float(np.degrees(yaw))))
    fishes.sort(key=lambda f: -f["dist"])
    masks = []       # per fish, per view: bool silhouette masks at full res
    outlines_px = []
    for f in fishes:
        L = f["L"]
        # fish-plane axis: x from snout (0) to fork (1) -> world = snout + x*L*(-h) + y*L*e2
        ex, ey = -f["h"] * L, f["e2"] * L
        allpoly = np.vstack([f["shape"]["body"], f["shape"]["caudal"]] + f["shape"]["fins"])
        world = f["snout"] + allpoly[:, :1] * ex + allpoly[:, 1:2] * ey
        p1, p2 = rig.project(world)
        outlines_px.append((p1, p2))
        proj_len = max(np.ptp(p[:, 0]) + np.ptp(p[:, 1]) for p in (p1, p2)) * SS
        tex_px = int(np.clip(proj_len * 1.5, 200, 4000))
        col, alpha = fish_texture(f["shape"], rng, f["pattern"], f["fins_translucent"], tex_px)
        # texture (col,row) -> plane coords (x,y) in FL units
        T = np.array([[1 / tex_px, 0, -0.05 + 0.5 / tex_px], [0, -1 / tex_px, 0.3 - 0.5 / tex_px], [0, 0, 1]])
        brightness = rng.uniform(0.85, 1.15)
        depth_m = f["dist"] / 1000
        absorb = np.exp(-depth_m * np.array([0.08, 0.06, 0.35]))   # BGR: red dies first
        haze = np.exp(-depth_m / cond["atten_m"])
        fm = []
        for img, (K, R, t) in zip(imgs, cam_params(rig), strict=True):
            Hm = S @ plane_h(K, R, t, f["snout"], ex, ey) @ T
            cp = cv2.warpPerspective(col * alpha[..., None], Hm, (Ws, Hs), flags=cv2.INTER_LINEAR)
            a = cv2.warpPerspective(alpha, Hm, (Ws, Hs), flags=cv2.INTER_LINEAR)[..., None]
            cp = cp * brightness * absorb[None, None, :]
            cp = cp * haze + water * (1 - haze) * a
            img[:] = img * (1 - a) + cp
            fm.append(cv2.resize((a[..., 0] > 0.05).astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST) > 0)
        masks.append(fm)
    # light gradient (brighter near the surface / top), mild vignetting
    out = []
    for img in imgs:
        v = np.linspace(0, 1, Hs)[:, None, None]
        g = (1 + cond["grad"] * (0.5 - v)).astype(np.float32)
        img = img * g
        img = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)
        if cond["blur"] > 0:
            img = cv2.GaussianBlur(img, (0, 0), cond["blur"])
        img = img + rng.normal(0, cond["noise"], img.shape)
        img = np.clip(img, 0, 255).astype(np.uint8)
        if cond["jpeg"]:
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, cond["jpeg"]])
            img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        out.append(img)
    # visibility
    truths = []
    for i, f in enumerate(fishes):
        inside = all(((p[:, 0] >= 3) & (p[:, 0] <= W - 4) & (p[:, 1] >= 3) & (p[:, 1] <= H - 4)).all()
                     for p in outlines_px[i])
        overlap = False
        for v in range(2):
            mi = cv2.dilate(masks[i][v].astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
            for j in range(len(fishes)):
                if j != i and (mi & masks[j][v]).any():
                    overlap = True
        sp = rig.project(np.array([f["snout"], f["fork"]]))
        truths.append(dict(L=f["L"], dist=f["dist"], snout=f["snout"].tolist(), fork=f["fork"].tolist(),
                           pattern=f["pattern"], fins_translucent=f["fins_translucent"],
                           direction=f["direction"], tilt_deg=f["tilt_deg"], yaw_deg=f["yaw_deg"],
                           inside=bool(inside), overlap=bool(overlap), visible=bool(inside and not overlap),
                           snout_px=[sp[0][0].tolist(), sp[1][0].tolist()],
                           fork_px=[sp[0][1].tolist(), sp[1][1].tolist()]))
    return out[0], out[1], dict(idx=idx, cond=cond, fish=truths)
