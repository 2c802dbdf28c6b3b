"""Independent stereo renderer of underwater fish: a held-out yardstick for the stereo fish-length survey.

Written from scratch by an outside tester, without reading the project's own fish renderers, so that
nobody who built the survey drew these fish. Each pair shows 1-8 fish (fork length 15-60 cm; four body
plans of my own: salmon-, bass-, bream- and tilapia-like) 0.6-2 m in front of a convergent rig. A fish is
a slightly C-bent 3-D mid-surface, yawed up to 35 deg, pitched/rolled up to 15 deg, shaded as a body of
elliptic cross-section: dark back / light belly, silvery mirror sheen and specular highlights, scale
texture, optional bars / spots / stripes / mottle, lateral line, gill cover, eye, fins of varied opacity
(some nearly clear) and a forked tail. The fork truth point is the innermost point of the tail notch, the
snout truth point the tip of the body; both lie on the mid-surface and are projected with P1/P2.
Backdrops (cond["bg"]): open water (tinted gradient, light shafts), a sea-cage net at an angle, reef /
rocks, an oblique sandy bottom; sometimes small hazy fish far behind (not in the truth). Camera effects:
per-channel haze with distance, depth of field, motion blur, marine snow / bubbles, vignetting, exposure
differences between the cameras, sensor noise, JPEG. Fish are drawn at 2x and area-downsampled.
"""

from __future__ import annotations

import cv2
import numpy as np

from devices.sim.stereo_rig import convergent_rig

W, H, F1 = 1280, 960, 1400.0
TINTS = {"blue-green": (0.62, 0.55, 0.22), "green": (0.38, 0.55, 0.30), "blue": (0.72, 0.45, 0.14)}
SIGMA = {"blue-green": (0.8, 0.8, 1.7), "green": (1.1, 0.75, 1.6), "blue": (0.7, 0.9, 1.8)}  # B, G, R
# body plans, all lengths as fractions of the snout-fork distance; colours BGR 0..1
SPECIES = {
    "salmon": dict(
        depth=(0.19, 0.24),
        hu=1.1,
        um=(0.38, 0.45),
        ph=0.65,
        pr=(0.34, 0.40),
        up=0.85,
        D=(0.05, 0.09),
        Sp=(0.10, 0.12),
        gam=1.0,
        wr=0.6,
        dors=[(0.38, 0.52, 0.085)],
        anal=(0.70, 0.80, 0.055),
        adip=True,
        eye=(0.065, 0.022),
        back=[(0.40, 0.33, 0.22), (0.32, 0.34, 0.28), (0.45, 0.40, 0.33)],
        fin=(0.30, 0.32, 0.32),
        pats=["spots", "spots", "plain"],
        silver=0.8,
        margin=False,
    ),
    "bass": dict(
        depth=(0.23, 0.28),
        hu=1.05,
        um=(0.36, 0.42),
        ph=0.6,
        pr=(0.34, 0.40),
        up=0.84,
        D=(0.06, 0.10),
        Sp=(0.10, 0.13),
        gam=1.1,
        wr=0.55,
        dors=[(0.30, 0.46, 0.10), (0.52, 0.70, 0.075)],
        anal=(0.64, 0.76, 0.06),
        adip=False,
        eye=(0.075, 0.025),
        back=[(0.42, 0.40, 0.36), (0.30, 0.36, 0.38), (0.45, 0.45, 0.42)],
        fin=(0.35, 0.36, 0.38),
        pats=["plain", "stripes", "spots"],
        silver=0.85,
        margin=True,
    ),
    "bream": dict(
        depth=(0.36, 0.42),
        hu=1.12,
        um=(0.34, 0.40),
        ph=0.5,
        pr=(0.24, 0.30),
        up=0.83,
        D=(0.12, 0.18),
        Sp=(0.14, 0.17),
        gam=1.2,
        wr=0.35,
        dors=[(0.28, 0.72, 0.065)],
        anal=(0.60, 0.76, 0.05),
        adip=False,
        eye=(0.09, 0.032),
        back=[(0.50, 0.45, 0.40), (0.42, 0.45, 0.45), (0.38, 0.42, 0.48)],
        fin=(0.40, 0.42, 0.48),
        pats=["plain", "bars", "plain"],
        silver=0.95,
        margin=True,
    ),
    "tilapia": dict(
        depth=(0.33, 0.39),
        hu=1.08,
        um=(0.38, 0.44),
        ph=0.55,
        pr=(0.34, 0.40),
        up=0.84,
        D=(0.02, 0.04),
        Sp=(0.12, 0.14),
        gam=2.0,
        wr=0.4,
        dors=[(0.25, 0.80, 0.075)],
        anal=(0.60, 0.78, 0.06),
        adip=False,
        eye=(0.08, 0.028),
        back=[(0.30, 0.36, 0.35), (0.25, 0.30, 0.30), (0.35, 0.38, 0.40)],
        fin=(0.28, 0.30, 0.36),
        pats=["bars", "plain", "mottled"],
        silver=0.35,
        margin=False,
    ),
}


def make_rig():
    return convergent_rig(
        baseline_mm=400,
        crossing_mm=1200,
        focal_px=1400,
        image_size=(1280, 960),
        target=np.array([0, 1200, -1500.0]),
        forward=np.array([0, 1.0, 0]),
        up=np.array([0, 0, 1.0]),
    )


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _proj(P, X):
    x = np.c_[np.atleast_2d(X), np.ones(len(np.atleast_2d(X)))] @ P.T
    return x[:, :2] / x[:, 2:3]


def _rays(P, us, vs):
    """World ray directions (camera-z component 1) through 1x pixel coordinates."""
    M = np.linalg.inv(P[:, :3]).astype(np.float32)
    return us[..., None] * M[:, 0] + vs[..., None] * M[:, 1] + M[:, 2]


def _noise(lat, a, b):
    n = np.float32(lat.shape[0])
    a, b = np.asarray(a, np.float32), np.asarray(b, np.float32)
    return cv2.remap(lat, a - np.floor(a / n) * n, b - np.floor(b / n) * n, cv2.INTER_CUBIC, borderMode=cv2.BORDER_WRAP)


def _fbm(lats, a, b, scale, octaves=4):
    out, tot = 0.0, 0.0
    for k in range(octaves):  # each octave turned by 0.9 rad: no axis-aligned lattice look
        c, s = np.cos(0.9 * k) * 2**k / scale, np.sin(0.9 * k) * 2**k / scale
        out = out + 0.5**k * _noise(lats[k % len(lats)], c * a - s * b + 13 * k, s * a + c * b)
        tot += 0.5**k
    return out / tot


def _sstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0, 1)
    return t * t * (3 - 2 * t)


def _water(sc, d):
    """Veiling water colour seen along unit directions d: brighter upwards, with light shafts."""
    dy = np.maximum(d[..., 1], 0.05)
    x, y = d[..., 0] / dy, d[..., 2] / dy
    g = 0.5 + 0.9 * np.clip(0.45 + 1.6 * y, 0, 1.4) + sc["hgrad"] * x
    p = (x - sc["sun"][0]) / np.maximum(sc["sun"][1] - y, 0.05)
    sh = sum(a * np.cos(f * p + ph) for f, ph, a in sc["shafts"])
    sh = np.clip(sh / 2, 0, None) ** 2 * np.clip(0.4 + 1.5 * y, 0, 1) * sc["shaft_k"]
    return (sc["wcol"] * (g + sh)[..., None] + 0.08 * sh[..., None]).astype(np.float32)


def _haze(sc, col, dist, wat):
    T = np.exp(-np.asarray(sc["sig"], np.float32) * np.asarray(dist, np.float32)[..., None])
    return np.asarray(col, np.float32) * T + wat * (1 - T)


def _plane(C, d, p0, n):
    den = d @ n.astype(np.float32)
    lam = ((p0 - C) @ n) / np.where(np.abs(den) > 1e-6, den, 1e-6)
    X = C.astype(np.float32) + lam[..., None] * d
    return lam, X


def _scene(rng):
    sc = {"bg": str(rng.choice(["open_water"] * 3 + ["net", "reef", "sand"]))}
    tint = str(rng.choice(list(TINTS)))
    sc.update(
        tint=tint,
        vis=float(rng.uniform(2500, 9000)),
        hgrad=float(rng.uniform(-0.15, 0.15)),
        sun=(float(rng.uniform(-0.8, 0.8)), float(rng.uniform(0.45, 1.2))),
        shaft_k=float(rng.uniform(0, 0.4)),
        focus=float(rng.uniform(900, 1800)),
        dof=float(rng.uniform(400, 3000)),
        lats=[rng.random((96, 96)).astype(np.float32) for _ in range(6)],
    )
    sc["wcol"] = (np.array(TINTS[tint]) * rng.uniform(0.5, 1.0) * (1 + rng.normal(0, 0.06, 3))).astype(np.float32)
    sc["sig"] = np.array(SIGMA[tint]) / sc["vis"]
    sc["shafts"] = [(rng.uniform(6, 40), rng.uniform(0, 6.3), rng.uniform(0.3, 1)) for _ in range(4)]
    sc["light"] = _unit([rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.2), 1.0])
    sc["lcol"] = (0.45 + 0.9 * sc["wcol"]).astype(np.float32) * rng.uniform(0.8, 1.2)
    if sc["bg"] == "net":
        al = np.radians(rng.choice([-1, 1]) * rng.uniform(15, 50))
        n = _unit([np.sin(al), -np.cos(al), rng.uniform(-0.2, 0.2)])
        sc["net"] = dict(
            p0=np.array([rng.uniform(-400, 400), rng.uniform(2300, 3600), -1500 + rng.uniform(-300, 300)]),
            n=n,
            ea=_unit(np.cross([0, 0, 1.0], n)),
            mesh=rng.uniform(15, 55),
            tw=rng.uniform(1.5, 5),
            diamond=bool(rng.random() < 0.5),
            foul=rng.uniform(0, 1),
            col=np.float32([(0.08,) * 3, (0.22, 0.32, 0.20), (0.65, 0.68, 0.66)][rng.integers(3)]),
        )
    if sc["bg"] == "reef":
        sc["rocks"] = []
        for k in range(int(rng.integers(1, 3))):
            al, tau = np.radians(rng.uniform(-25, 25)), rng.uniform(0.05, 0.6)
            n = _unit([np.sin(al) * np.cos(tau), -np.cos(al) * np.cos(tau), np.sin(tau)])
            sc["rocks"].append(
                dict(
                    p0=np.array([rng.uniform(-800, 800), rng.uniform(2400, 4000) - 500 * k, -1500.0]),
                    n=n,
                    ea=_unit(np.cross([0, 0, 1.0], n)),
                    top=rng.uniform(-300, 900) - 400 * k,
                    amp=rng.uniform(100, 600),
                    scale=rng.uniform(150, 450),
                    pal=rng.uniform(0.7, 1.3)
                    * np.float32(
                        [
                            (0.35, 0.40, 0.45),
                            (0.20, 0.42, 0.35),
                            (0.45, 0.40, 0.60),
                            (0.85, 0.90, 0.92),
                            (0.25, 0.30, 0.30),
                        ]
                    )[rng.permutation(5)],
                )
            )
    if sc["bg"] == "sand":
        sc["sand"] = dict(
            z=-1500 - rng.uniform(450, 1100),
            om=rng.uniform(0, np.pi),
            lam=rng.uniform(60, 160),
            col=np.float32([0.55, 0.66, 0.72]) * rng.uniform(0.7, 1.2),
        )
    nf = int(rng.integers(3, 25)) if rng.random() < 0.45 else 0
    sc["far"] = [
        (
            np.array([rng.uniform(-0.5, 0.5) * y, y, -1500 + rng.uniform(-0.35, 0.35) * y]),
            rng.uniform(150, 450),
            rng.uniform(-20, 20),
            rng.uniform(0.15, 0.6),
        )
        for y in np.sort(rng.uniform(5000, 10000, nf))[::-1]
    ]
    sc["parts"] = (
        (
            np.c_[rng.uniform(-0.5, 0.5, 300), np.ones(300), rng.uniform(-0.37, 0.37, 300)]
            * rng.uniform(250, 3000, 300)[:, None]
            + [0, 0, -1500]
        )[: int(rng.integers(0, 300))]
        if rng.random() < 0.6
        else np.zeros((0, 3))
    )
    sc["psize"] = rng.uniform(0.3, 1.8, len(sc["parts"]))
    nb = int(rng.integers(8, 40)) if rng.random() < 0.12 else 0
    bx = np.array([rng.uniform(-300, 300), rng.uniform(700, 1800), -1500 + rng.uniform(-500, 0)])
    sc["bubbles"] = bx + np.c_[rng.normal(0, 15, nb), rng.normal(0, 15, nb), np.sort(rng.uniform(0, 900, nb))]
    sc["bsize"] = rng.uniform(1, 6, nb)
    return sc


def _grid(sc, P, step):
    o = (step - 1) / 2
    us, vs = np.meshgrid(
        np.arange(W // step, dtype=np.float32) * step + o, np.arange(H // step, dtype=np.float32) * step + o
    )
    d = _rays(P, us, vs)
    dn = np.linalg.norm(d, axis=2)
    du = d / dn[..., None]
    return d, dn, du, _water(sc, du)


def _background(sc, P, C):
    """Backdrop at 1x: water, sand, rocks and far fish computed at half resolution (they are smooth), the net at 1x."""
    d, dn, du, wat = _grid(sc, P, 2)
    img, dep, L = wat.copy(), np.full(wat.shape[:2], 1e9, np.float32), sc["lats"]

    def put(col, cov, dist):
        m = (cov * (dist < dep))[..., None]
        img[:] = img * (1 - m) + _haze(sc, col, dist, wat) * m
        dep[:] = np.where(m[..., 0] > 0.5, dist, dep)

    if "sand" in sc:
        s = sc["sand"]
        lam, X = _plane(C, d, np.array([0, 0, s["z"]]), np.array([0, 0, 1.0]))
        a, b, dist = X[..., 0], X[..., 1], np.where(lam > 0, lam * dn, 1e7)
        fp = dist / F1 / np.maximum(np.abs(du[..., 2]), 0.05)
        rip = np.sin(2 * np.pi * (a * np.cos(s["om"]) + b * np.sin(s["om"])) / s["lam"] + 6 * _fbm(L, a, b, 400, 2))
        rip *= np.clip(1.5 - 3 * fp / s["lam"], 0, 1)
        caus = np.clip(1 - np.abs(_fbm(L[2:], a, b, 150, 2) - 0.5) * 9, 0, 1) ** 3
        tone = 0.7 + 0.2 * rip + 0.5 * (_fbm(L[1:], a, b, 8, 2) - 0.5) + 0.4 * (_fbm(L, a, b, 700, 3) - 0.5)
        col = s["col"] * sc["lcol"] * tone[..., None] + 0.35 * caus[..., None] * sc["lcol"]
        put(col.astype(np.float32), (lam > 0).astype(np.float32), dist)
    for rk in sorted(sc.get("rocks", []), key=lambda r: -r["p0"][1]):
        lam, X = _plane(C, d, rk["p0"], rk["n"])
        rel, eb = X - rk["p0"].astype(np.float32), np.cross(rk["n"], rk["ea"])
        a, b, dist = rel @ rk["ea"].astype(np.float32), rel @ eb.astype(np.float32), np.where(lam > 0, lam * dn, 1e7)
        fp = dist / F1
        top = rk["top"] + rk["amp"] * 2 * (_fbm(L, a, 0 * a, 900, 3) - 0.5) + 120 * (_fbm(L[3:], a, b, 150, 2) - 0.5)
        cov = np.clip((top - b) / fp + 0.5, 0, 1) * (lam > 0)
        h, h2 = _fbm(L, a, b, rk["scale"], 4), _fbm(L, a, b + 12, rk["scale"], 4)
        m = np.clip((_fbm(L[3:], a + 500, b, 700, 3) - 0.3) / 0.4, 0, 0.999) * (len(rk["pal"]) - 1)
        i, fr = m.astype(int), _sstep(0.35, 0.65, m % 1)[..., None]
        col = rk["pal"][i] * (1 - fr) + rk["pal"][np.minimum(i + 1, len(rk["pal"]) - 1)] * fr
        shade = np.clip(1 + 14 * (h2 - h), 0.3, 1.8) * (0.25 + 0.75 * _sstep(0.3, 0.5, h))
        shade *= (0.75 + 0.5 * _fbm(L[2:], a, b, 25, 2)) * np.clip(0.8 + (X[..., 2] + 1500) / 2000, 0.4, 1.3)
        put((col * shade[..., None] * sc["lcol"]).astype(np.float32), cov.astype(np.float32), dist - 600 * h)
    if sc["far"]:
        col, cov, fd = np.zeros_like(img), np.zeros_like(dep), np.full_like(dep, 1e9)
        for X, size, ang, tone in sc["far"]:
            (x, y), dist = (_proj(P, X)[0] - 0.5) / 2, float(np.linalg.norm(X - C))
            ln = F1 * size / dist / 2
            c16 = (int(x * 16), int(y * 16))
            ca, sa = np.cos(np.radians(ang)), np.sin(np.radians(ang))
            tail = np.array(
                [
                    [x + 0.45 * ln * ca, y + 0.45 * ln * sa],
                    [x + 0.7 * ln * ca - 0.15 * ln * sa, y + 0.7 * ln * sa + 0.15 * ln * ca],
                    [x + 0.7 * ln * ca + 0.15 * ln * sa, y + 0.7 * ln * sa - 0.15 * ln * ca],
                ]
            )
            for im, val, lt in ((col, (tone * 0.9, tone, tone), cv2.LINE_AA), (cov, 1.0, cv2.LINE_AA), (fd, dist, 8)):
                cv2.ellipse(im, c16, (int(ln * 8), int(ln * 2.4)), float(ang), 0, 360, val, -1, lt, 4)
                cv2.fillConvexPoly(im, (tail * 16).astype(np.int32), val, lt, 4)
        put(cv2.GaussianBlur(col, (0, 0), 1.0), cv2.GaussianBlur(cov, (0, 0), 1.0), fd)
    img, dep = cv2.resize(img, (W, H)), cv2.resize(dep, (W, H), interpolation=cv2.INTER_NEAREST)
    d, dn, du, wat = _grid(sc, P, 1)
    if "net" in sc:
        nt = sc["net"]
        lam, X = _plane(C, d, nt["p0"], nt["n"])
        rel, eb = X - nt["p0"].astype(np.float32), np.cross(nt["n"], nt["ea"])
        a, b, dist = rel @ nt["ea"].astype(np.float32), rel @ eb.astype(np.float32), np.where(lam > 0, lam * dn, 1e7)
        if nt["diamond"]:
            a, b = (a + b) / 1.414, (a - b) / 1.414
        fp = dist / F1 / np.maximum(np.abs(du @ nt["n"].astype(np.float32)), 0.25)
        foul = _fbm(L, a, b, 250, 3)
        w, m = nt["tw"] * (1 + 2.5 * nt["foul"] * np.clip(foul - 0.45, 0, 1)), nt["mesh"]
        ca = np.clip((w / 2 - np.abs(np.mod(a / m + 0.5, 1) - 0.5) * m) / fp + 0.5, 0, 1)
        cb = np.clip((w / 2 - np.abs(np.mod(b / m + 0.5, 1) - 0.5) * m) / fp + 0.5, 0, 1)
        k = np.clip(3 * fp / m - 1, 0, 1)
        cov = (1 - (1 - ca) * (1 - cb)) * (1 - k) + k * (1 - (1 - w / m) ** 2)
        cov = np.maximum(cov, nt["foul"] * 0.5 * np.clip((foul - 0.58) * 6, 0, 1)) * (lam > 0)
        fc = nt["foul"] * np.clip(foul * 1.5 - 0.3, 0, 1)[..., None]
        col = (nt["col"] * (1 - fc) + np.array([0.18, 0.36, 0.30]) * fc) * sc["lcol"]
        col = col * np.clip(0.8 + (X[..., 2:] + 1500) / 2500, 0.4, 1.3)
        put(col.astype(np.float32), cov.astype(np.float32), dist)
    sig = np.clip(sc["dof"] * np.abs(1 / dep - 1 / sc["focus"]), 0, 6)
    out, lv = img, [0, 1.0, 2.5, 6.0]
    for i in range(1, 4):
        wgt = np.clip((sig - lv[i - 1]) / (lv[i] - lv[i - 1]), 0, 1)[..., None]
        out = out + wgt * (cv2.GaussianBlur(img, (0, 0), lv[i]) - out)
    return out


def _sample_fish(rng, sc, name, centre, L):
    sp, f = SPECIES[name], {"species": name}
    for k in ("depth", "um", "pr", "D", "Sp"):
        f[k] = float(rng.uniform(*sp[k]))
    for k in ("hu", "ph", "up", "gam", "wr", "dors", "anal", "adip", "margin"):
        f[k] = sp[k]
    f.update(Hh=f["depth"] / 2, uc=f["up"] + 0.05, mid=rng.uniform(-0.01, 0.02), beta=rng.uniform(-0.15, 0.15))
    f["Ls"] = L / np.sqrt(1 + (0.4 * f["beta"]) ** 2)
    sgn, psi, th, ro = rng.choice([-1, 1]), *np.radians(rng.uniform([-35, -15, -15], [35, 15, 15]))
    es = -np.array([sgn * np.cos(psi) * np.cos(th), np.sin(psi) * np.cos(th), np.sin(th)])
    et0 = _unit(np.array([0, 0, 1.0]) - es[2] * es)
    et = np.cos(ro) * et0 + np.sin(ro) * np.cross(es, et0)
    f.update(es=es, et=et, en=np.cross(es, et), O=centre - 0.5 * f["Ls"] * es, yaw=float(np.degrees(psi)))
    f["vmax"], f["vmin"] = f["Hh"] * f["hu"] + 0.11, -f["Hh"] * (2 - f["hu"]) - 0.09
    f["eye"] = (sp["eye"][0] * rng.uniform(0.9, 1.1), sp["eye"][1] * rng.uniform(0.85, 1.15))
    back = np.array(sp["back"][rng.integers(len(sp["back"]))]) * rng.uniform(0.6, 1.2)
    if rng.random() < 0.25:  # camouflaged: back close to the water colour
        back = sc["wcol"] * rng.uniform(0.6, 1.1)
    f.update(
        back=back.astype(np.float32),
        belly=np.float32([0.82, 0.84, 0.82]) * rng.uniform(0.7, 1.05),
        cs=rng.uniform(0.45, 0.7),
        fin=np.float32(sp["fin"]) * rng.uniform(0.6, 1.3),
        pattern=str(rng.choice(sp["pats"])),
        silver=sp["silver"] * rng.uniform(0.5, 1.2),
        ks=rng.uniform(0.3, 1.2),
        shin=rng.uniform(8, 40),
        ac=rng.uniform(0.5, 0.95),
        ad=rng.uniform(0.12, 0.9),
        ap=rng.uniform(0.1, 0.7),
        nb=int(rng.integers(5, 9)),
        sd=rng.uniform(25, 60),
        thr=rng.uniform(0.6, 0.72),
        lat=rng.random((64, 64)).astype(np.float32),
        ll=rng.choice([-0.35, 0.3]),
        opR=rng.uniform(0.08, 0.14),
        mb=float(rng.uniform(2, 14)) if rng.random() < 0.3 else 0.0,
    )
    return f


def _prof(f, u):
    um, pr, up = f["um"], f["pr"], f["up"]
    front = np.clip(1 - ((um - np.clip(u, 0, um)) / um) ** 2, 0, 1) ** f["ph"]
    back = pr + (1 - pr) * 0.5 * (1 + np.cos(np.pi * np.clip((u - um) / (up - um), 0, 1)))
    fu = np.where(u < um, front, back)
    mid = f["mid"] * np.sin(np.pi * np.clip(u, 0, 1))
    return mid + f["Hh"] * f["hu"] * fu, mid - f["Hh"] * (2 - f["hu"]) * fu


def _fin(u, d0, d1, hgt):
    x = (u - d0) / (d1 - d0)
    return hgt * np.clip(x / 0.12, 0, 1) ** 0.5 * (1 - 0.6 * x) * np.clip((1 - x) / 0.1, 0, 1) ** 0.5


def _parts(f, u, v):
    """Body mask, caudal mask, fin / pectoral alpha, tail trailing edge and body profile at (u, v)."""
    upper, lower = _prof(f, u)
    body = (u >= 0) & (u <= f["uc"]) & (v <= upper) & (v >= lower)
    a, D, Sp, u0 = np.abs(v), f["D"], f["Sp"], f["uc"] - 0.03
    hp = f["Hh"] * f["pr"] * min(f["hu"], 2 - f["hu"])
    te = 1 + D * np.clip(a / Sp, 0, 1) ** f["gam"]
    caud = (u >= u0) & (u <= te) & (a <= hp + (Sp - hp) * np.clip((u - u0) / (1 + D - u0), 0, 1) ** 0.8) & ~body
    ray = 0.8 + 0.2 * np.cos(np.arctan2(v, u - u0 + 0.03) * 70)
    fin = np.zeros(u.shape, np.float32)
    for d0, d1, hgt in f["dors"] + ([(0.77, 0.83, 0.02)] if f["adip"] else []):
        fin = np.maximum(
            fin, f["ad"] * ((u >= d0) & (u <= d1) & (v >= upper - 0.003) & (v <= upper + _fin(u, d0, d1, hgt)))
        )
    d0, d1, hgt = f["anal"]
    fin = np.maximum(
        fin, f["ad"] * ((u >= d0) & (u <= d1) & (v <= lower + 0.003) & (v >= lower - _fin(u, d0, d1, hgt)))
    )
    fin = np.maximum(
        fin,
        f["ap"] * ((u >= 0.40) & (u <= 0.50) & (v <= lower + 0.003) & (v >= lower - 0.7 * _fin(u, 0.40, 0.50, 0.07))),
    )
    pu, pv = u - 0.22, v - (lower + 0.35 * (upper - lower))
    al, ac = pu * 0.94 + pv * 0.34, -pu * 0.34 + pv * 0.94  # pectoral fan, pointing back-down
    pec = f["ap"] * ((al >= 0) & (al <= 0.12) & (np.abs(ac) <= 0.035 * np.sqrt(np.clip(al / 0.12, 0, 1)))) * ray
    cdl = caud * (f["ac"] + (1 - f["ac"]) * np.clip((u0 + 0.06 - u) / 0.06, 0, 1)) * ray
    alpha = np.maximum.reduce([body.astype(np.float32), cdl, fin * ray, pec]).astype(np.float32)
    return body, caud, alpha, pec.astype(np.float32), te, upper, lower


def _render_fish(f, sc, P, C, frame):
    """Composite fish f onto the 2x frame; return its outline mask at 1x (H, W) and whether it stays in frame.

    Geometry (ray / bent mid-surface) and colour are computed at 1x; u, v are bilinearly upsampled (they are
    smooth) and the outline / alpha evaluated exactly at 2x, so edges are 2x-supersampled."""
    Ls, es, et, en, O = f["Ls"], f["es"], f["et"], f["en"], f["O"]
    bend = [f["beta"] * Ls * ((x - 0.3) ** 2 - 0.09) for x in (0.3, 0.0, 1.2)]
    pts = np.array(
        [
            O + s * es + t * et + n * en
            for s in (0, (1 + f["D"] + 0.02) * Ls)
            for t in (f["vmin"] * Ls, f["vmax"] * Ls)
            for n in (min(bend), max(bend))
        ]
    )
    px = _proj(P, pts)
    dist_c = float(np.linalg.norm(O + 0.5 * Ls * es - C))
    sig = 2 * sc["dof"] * abs(1 / dist_c - 1 / sc["focus"])
    pad = 4 + (3 * sig + f["mb"]) / 2
    x0, x1 = (int(np.clip(g(px[:, 0] + k * pad), -16, W + 16)) for g, k in ((np.min, -1), (np.max, 1)))
    y0, y1 = (int(np.clip(g(px[:, 1] + k * pad), -16, H + 16)) for g, k in ((np.min, -1), (np.max, 1)))
    full = np.zeros((H, W), bool)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return full, False
    X, Y = np.meshgrid(np.arange(x0, x1, dtype=np.float32), np.arange(y0, y1, dtype=np.float32))
    d = _rays(P, X, Y)
    q = (C - O).astype(np.float32)
    es32, et32, en32 = (e.astype(np.float32) for e in (es, et, en))
    ds, dt, dn = d @ es32, d @ et32, d @ en32
    dn = np.where(np.abs(dn) < 1e-3, np.float32(1e-3), dn)
    bn, beta = 0.0, float(f["beta"] * Ls)
    for _ in range(5):  # ray / C-bent mid-surface intersection (fixed point)
        lam = (bn - float(q @ en32)) / dn
        u = (float(q @ es32) + lam * ds) / float(Ls)
        bn = beta * ((u - 0.3) ** 2 - 0.09)
    v = (float(q @ et32) + lam * dt) / float(Ls)
    body, caud, alpha1, pec, te, upper, lower = _parts(f, u, v)
    alpha1 *= lam > 0
    size2 = (2 * (x1 - x0), 2 * (y1 - y0))
    lab = (body + 2 * caud + 4 * (alpha1 > 0)).astype(np.uint8)  # exact 2x evaluation only near edges
    edge = cv2.resize(
        (cv2.dilate(lab, None) != cv2.erode(lab, None)).astype(np.uint8), size2, interpolation=cv2.INTER_NEAREST
    ).astype(bool)
    alpha = cv2.resize(alpha1, size2, interpolation=cv2.INTER_LINEAR)
    alpha *= cv2.resize((alpha1 > 0).astype(np.float32), size2, interpolation=cv2.INTER_NEAREST)
    ix = np.nonzero(edge)
    u2, v2 = (cv2.resize(z, size2, interpolation=cv2.INTER_LINEAR)[ix] for z in (u, v))
    lam2 = cv2.resize(lam, size2, interpolation=cv2.INTER_LINEAR)[ix]
    alpha[ix] = _parts(f, u2, v2)[2] * (lam2 > 0)
    outline = alpha > 0
    # colour: counter-shading, pattern, lateral line, gill cover, scales
    yn = np.clip((v - lower) / (upper - lower + 1e-6), 0, 1)
    nz = _noise(f["lat"], u * 250, v * 250)
    wb = _sstep(f["cs"] - 0.12, f["cs"] + 0.12, yn + 0.1 * (_noise(f["lat"], u * 15, v * 15) - 0.5))[..., None]
    alb = f["belly"] * (1 - wb) + f["back"] * wb
    dark = np.zeros(u.shape, np.float32)
    if f["pattern"] == "bars":
        dark = 0.5 * np.clip((np.cos(2 * np.pi * (u - 0.2) * f["nb"] / 0.7) - 0.2) * 2, 0, 1) * (u > 0.18) * (0.3 + yn)
    elif f["pattern"] == "spots":
        dark = 0.7 * np.clip((_noise(f["lat"], u * f["sd"] + 7, v * f["sd"]) - f["thr"]) * 10, 0, 1) * (yn > 0.35)
    elif f["pattern"] == "stripes":
        dark = 0.45 * np.clip((np.cos(2 * np.pi * yn * 7) - 0.6) * 4, 0, 1) * (yn > 0.3) * (u > 0.2)
    elif f["pattern"] == "mottled":
        dark = 0.6 * np.clip(_fbm([f["lat"]], u * 12, v * 12, 1, 3) - 0.35, 0, 1)
    yl = lower + (upper - lower) * (0.72 + 0.04 * np.sin(np.pi * u))
    dark = dark + f["ll"] * np.clip(1 - np.abs(v - yl) / 0.003, 0, 1) * (u > 0.22) * (u < 0.88)
    ue, re = f["eye"]
    up_e, lo_e = (float(x) for x in _prof(f, np.array(ue)))
    ve = lo_e + 0.62 * (up_e - lo_e)
    ue2 = ue * 2.6 + f["opR"] - 0.04
    gill = np.clip(1 - np.abs(np.hypot(u - ue2 + f["opR"], v - ve) - f["opR"]) / 0.004, 0, 1)
    dark = dark + 0.45 * gill * (u < ue2) * (u > ue2 - 0.6 * f["opR"])
    alb = alb * np.clip(1 - dark, 0.05, 1.5)[..., None] * (0.95 + 0.1 * nz)[..., None]
    alb = np.where(body[..., None], alb, f["fin"] * (0.8 + 0.2 * wb))
    if f["margin"]:
        alb = alb * (1 - 0.5 * (caud & (te - u < 0.012)))[..., None]
    # shading: elliptic cross-section normal facing this camera, sun from above, silver mirror of the water
    yc = np.clip((v - (upper + lower) / 2) / ((upper - lower) / 2 + 1e-6), -0.995, 0.995) * body
    side = (-np.sign(np.mean(dn)) * en).astype(np.float32)
    nrm = np.sqrt(1 - yc**2)[..., None] * side + (f["wr"] * yc)[..., None] * et32
    nrm = nrm / np.linalg.norm(nrm, axis=2, keepdims=True)
    du = d / np.linalg.norm(d, axis=2, keepdims=True)
    Ld = sc["light"].astype(np.float32)
    diff = np.clip(nrm @ Ld, 0, 1)[..., None]
    hv = Ld - du
    spec = np.clip(np.sum(nrm * hv, 2) / np.linalg.norm(hv, axis=2), 0, 1) ** f["shin"] * f["ks"] * (0.7 + 0.6 * nz)
    rz = du[..., 2] - 2 * np.sum(nrm * du, 2) * nrm[..., 2]
    sheen = f["silver"] * (0.35 + 0.45 * (1 - yn)) * np.where(body, 1.0, 0.2) * (0.9 + 0.2 * nz)
    col = (
        alb * (0.3 + 0.8 * diff) * sc["lcol"]
        + (sheen * (0.4 + 1.1 * np.clip(0.5 + 0.9 * rz, 0, 1.5)))[..., None] * (sc["wcol"] + sc["lcol"]) / 2
        + (spec * np.where(body, 1.0, 0.3))[..., None] * sc["lcol"]
    )
    de = np.hypot(u - ue, v - ve) / re
    col = np.where((de < 1)[..., None], np.float32([0.3, 0.42, 0.5]) * (0.4 + 0.6 * diff), col)
    col = np.where((de < 0.55)[..., None], 0.03, col)
    col = np.where((np.hypot(u - ue + 0.25 * re, v - ve - 0.25 * re) < 0.15 * re)[..., None], 0.9, col)
    col = col * (1 - pec[..., None]) + (f["fin"] * (0.5 + 0.5 * diff) * sc["lcol"]) * pec[..., None]
    col = _haze(sc, col, np.abs(lam) * np.linalg.norm(d, axis=2), _water(sc, du)).astype(np.float32)
    pm = cv2.resize(col, size2, interpolation=cv2.INTER_LINEAR) * alpha[..., None]
    if sig > 0.3:
        pm, alpha = cv2.GaussianBlur(pm, (0, 0), sig), cv2.GaussianBlur(alpha, (0, 0), sig)
    if f["mb"] > 0:  # motion blur along the body axis
        e = _proj(P, np.array([O, O + 0.2 * Ls * es]))
        e = (e[1] - e[0]) / np.linalg.norm(e[1] - e[0]) * f["mb"] / 2
        k = 2 * int(f["mb"] / 2 + 1) + 1
        ker = np.zeros((k, k), np.float32)
        cv2.line(
            ker, (int(k // 2 - e[0]), int(k // 2 - e[1])), (int(k // 2 + e[0]), int(k // 2 + e[1])), 1.0, 1, cv2.LINE_AA
        )
        ker /= ker.sum()
        pm, alpha = cv2.filter2D(pm, -1, ker), cv2.filter2D(alpha, -1, ker)
    X0, Y0, X1, Y1 = 2 * x0, 2 * y0, 2 * x1, 2 * y1
    fx0, fy0, fx1, fy1 = max(X0, 0), max(Y0, 0), min(X1, 2 * W), min(Y1, 2 * H)
    if fx1 > fx0 and fy1 > fy0:
        sl = np.s_[fy0 - Y0 : fy1 - Y0, fx0 - X0 : fx1 - X0]
        frame[fy0:fy1, fx0:fx1] = frame[fy0:fy1, fx0:fx1] * (1 - alpha[sl][..., None]) + pm[sl]
    ys, xs = np.nonzero(outline.reshape(y1 - y0, 2, x1 - x0, 2).any(axis=(1, 3)))
    ys, xs = ys + y0, xs + x0
    inside = len(xs) > 0 and xs.min() >= 3 and ys.min() >= 3 and xs.max() <= W - 4 and ys.max() <= H - 4
    ok = (xs >= 0) & (xs < W) & (ys >= 0) & (ys < H)
    full[ys[ok], xs[ok]] = True
    return full, bool(inside)


def _specks(sc, P, C, frame):
    """Marine snow (soft dots) and bubbles (bright rims), 3-D so both cameras agree; drawn at 1x."""
    for pts, sizes, bub in ((sc["parts"], sc["psize"], False), (sc["bubbles"], sc["bsize"], True)):
        if len(pts) == 0:
            continue
        dist = np.linalg.norm(pts - C, axis=1)
        xy, r = _proj(P, pts), F1 * sizes / dist
        sig = sc["dof"] * np.abs(1 / dist - 1 / sc["focus"])
        for lo, hi in ((0, 0.75), (0.75, 2.5), (2.5, 1e9)):
            sel = (sig >= lo) & (sig < hi)
            if not sel.any():
                continue
            lay = np.zeros(frame.shape[:2], np.float32)
            for (x, y), rr in zip(xy[sel], r[sel], strict=True):
                c, rad = (int(x * 16), int(y * 16)), int(max(rr, 0.5) * 16)
                if bub:
                    cv2.circle(lay, c, rad, 0.15, -1, cv2.LINE_AA, 4)
                    cv2.circle(lay, c, rad, 0.8, max(1, int(rr / 4)), cv2.LINE_AA, 4)
                else:
                    cv2.circle(lay, c, rad, 0.5, -1, cv2.LINE_AA, 4)
            lay = cv2.GaussianBlur(lay, (0, 0), max(0.5, min(np.median(sig[sel]), 10)))[..., None]
            frame[:] = frame * (1 - lay) + (0.7 * sc["lcol"] + 0.2) * lay


def render_pair(rig, rng, idx):
    sc = _scene(rng)
    Ps, Cs = (rig.P1, rig.P2), [np.asarray(c, float) for c in rig.centres]
    mid = (Cs[0] + Cs[1]) / 2
    n = int(rng.integers(1, 9))
    main = str(rng.choice(list(SPECIES)))
    fishes, boxes = [], []
    for _ in range(60):
        if len(fishes) == n:
            break
        name = main if rng.random() < 0.75 else str(rng.choice(list(SPECIES)))
        L, depth = float(rng.uniform(150, 600)), float(rng.uniform(650, 1950))
        ray = _rays(Ps[0], np.float32(rng.uniform(60, W - 60)), np.float32(rng.uniform(60, H - 60))).astype(float)
        centre = Cs[0] + ray * (depth - Cs[0][1]) / ray[1]
        c2 = _proj(Ps[1], centre)[0]
        if not (0 < c2[0] < W and 0 < c2[1] < H) or ("sand" in sc and centre[2] - 0.35 * L < sc["sand"]["z"]):
            continue
        c1, half = _proj(Ps[0], centre)[0], F1 * L / depth * 0.55
        box = np.r_[c1 - [half, half * 0.5], c1 + [half, half * 0.5]]
        over = any(min(box[2], b[2]) > max(box[0], b[0]) and min(box[3], b[3]) > max(box[1], b[1]) for b in boxes)
        if over and rng.random() < 0.85:
            continue
        boxes.append(box)
        fishes.append(_sample_fish(rng, sc, name, centre, L))
    fishes.sort(key=lambda f: -np.linalg.norm(f["O"] + 0.5 * f["Ls"] * f["es"] - mid))
    expo = rng.uniform(0.8, 1.2)
    gains = [expo * (1 + rng.normal(0, 0.012, 3)) * g for g in (1.0, 1 + np.clip(rng.normal(0, 0.03), -0.06, 0.06))]
    vig, noise, q = rng.uniform(0.1, 0.35, 2), rng.uniform(0.004, 0.015), int(rng.integers(55, 93))
    imgs, masks, inside = [], [], []
    for c, (P, C) in enumerate(zip(Ps, Cs, strict=True)):
        bg = _background(sc, P, C)
        frame = cv2.resize(bg, (2 * W, 2 * H), interpolation=cv2.INTER_LINEAR)
        res = [_render_fish(f, sc, P, C, frame) for f in fishes]
        masks.append([r[0] for r in res])
        inside.append([r[1] for r in res])
        img = cv2.resize(frame, (W, H), interpolation=cv2.INTER_AREA)
        _specks(sc, P, C, img)
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        r2 = ((xx - W / 2) ** 2 + (yy - H / 2) ** 2) / (W / 2) ** 2
        img = img * (1 - vig[c] * r2 / 1.5)[..., None] * gains[c]
        shot = np.sqrt(noise**2 + 0.01 * noise * np.clip(img, 0, None))  # read + shot noise
        img = img + rng.standard_normal(img.shape, dtype=np.float32) * shot
        img = np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8)
        imgs.append(cv2.imdecode(cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, q])[1], cv2.IMREAD_COLOR))
    ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    truth = []
    for i, f in enumerate(fishes):
        snout = f["O"] + f["beta"] * f["Ls"] * (0.09 - 0.09) * f["en"]
        fork = f["O"] + f["Ls"] * f["es"] + f["beta"] * f["Ls"] * (0.49 - 0.09) * f["en"]
        vis = inside[0][i] and inside[1][i]
        for c in range(2):
            grown = cv2.dilate(masks[c][i].astype(np.uint8), ker).astype(bool)
            vis = vis and not any((grown & masks[c][j]).any() for j in range(len(fishes)) if j != i)
        sp = [_proj(P, snout)[0].tolist() for P in Ps]
        fp = [_proj(P, fork)[0].tolist() for P in Ps]
        truth.append(
            {
                "snout": snout.tolist(),
                "fork": fork.tolist(),
                "L": float(np.linalg.norm(fork - snout)),
                "snout_px": sp,
                "fork_px": fp,
                "visible": bool(vis),
                "pattern": f["pattern"],
                "direction": "left" if sp[0][0] < fp[0][0] else "right",
                "species": f["species"],
                "yaw_deg": f["yaw"],
                "motion_blur_px": f["mb"] / 2,
            }
        )
    cond = {
        "bg": sc["bg"],
        "tint": sc["tint"],
        "visibility_mm": sc["vis"],
        "focus_mm": sc["focus"],
        "far_fish": len(sc["far"]),
        "particles": len(sc["parts"]),
        "bubbles": len(sc["bubbles"]),
        "jpeg_q": q,
        "gain_ratio": float(gains[1].mean() / gains[0].mean()),
        "idx": idx,
    }
    return imgs[0], imgs[1], {"cond": cond, "fish": truth}
