"""Train the learned fork locator (``vision.fork_net``) on crops from tools/fork_net_data.py and
export it to ONNX (run by ONNX Runtime).

Not part of the project's dependencies or its suite: torch lives in a separate venv,
    /root/.pyenv/versions/3.11.7/bin/python -m venv .venv-train
    .venv-train/bin/pip install torch==2.13.0 numpy opencv-python-headless onnx onnxruntime
    .venv/bin/python tools/fork_net_data.py --seed0 100000 --scenes 750 --out /tmp/a.npz   (~4 min each
    .venv/bin/python tools/fork_net_data.py --seed0 100750 --scenes 750 --out /tmp/b.npz    on a free core)
    .venv-train/bin/python tools/train_fork_net.py --data /tmp/a.npz /tmp/b.npz --out vision/models/fork_net.onnx \
        --epochs 10 --per-epoch 60000 --minutes 32 --threads 1
(the model of 2026-12-02: those commands, 20 min of training on a loaded machine). The packaged model
(2026-12-07): ``tools/fork_net_data.py --seed0 S --scenes 750`` for S = 110000, 110750, 111500,
112250 (four at once, ~12 min), then ``--data`` those four ``--epochs 36 --per-epoch 100000
--minutes 40 --threads 2 --val-scenes 100`` (27 min, the machine to itself). Forks of
every notch shape, with crops at a finer last pass (tools/models/fork_net_fine_candidate.onnx,
2026-12-06, 656 s; ``vision.fork_net`` has its figures): ``--seed0 107000`` and ``107750``, each
``--fine --conditions '{"notch_power": [0.6, 1.6]}'``, then ``--minutes 40 --val-scenes 100``.
Small fish:
``tools/fork_net_data.py --size 640x480 --jpeg 95`` renders smaller images through a camera's JPEG
(tools/models/fork_net_candidate.onnx, 2026-12-04: that data besides the above, ``--epochs 20
--per-epoch 100000``; vision/fork_net.py has its figures).
The snout locator (``vision.snout_net``) is the same net trained on tools/snout_net_data.py's crops,
of snouts of every shape (``snout_taper``) and at the last pass's finer span:
    .venv/bin/python tools/snout_net_data.py --seed0 106000 --scenes 450 --out /tmp/sn_a.npz \
        --conditions '{"snout_taper": [-0.35, 0.8]}'
    .venv/bin/python tools/snout_net_data.py --seed0 106450 --scenes 300 --out /tmp/sn_b.npz \
        --conditions '{"snout_taper": [-0.35, 0.8]}'
    .venv-train/bin/python tools/train_fork_net.py --data /tmp/sn_a.npz /tmp/sn_b.npz \
        --out vision/models/snout_net.onnx --epochs 8 --per-epoch 80000 --minutes 30 --threads 2 --val-scenes 60
(2026-12-06: 373 s on the machine to itself; run alone: beside another busy process two torch
threads ran ~8x slower).
The surface setup's end locators (``vision.surface_nets``) are the same net trained on
tools/surface_net_data.py's crops of rendered nursery tanks (2026-12-07):
    .venv/bin/python tools/surface_net_data.py --seed0 120000 --scenes 400 --fins 0 --out /tmp/sn0
    .venv/bin/python tools/surface_net_data.py --seed0 120400 --scenes 400 --fins 0 --out /tmp/sn1
    .venv/bin/python tools/surface_net_data.py --seed0 130000 --scenes 400 --fins 0.6 --out /tmp/fn0
    .venv/bin/python tools/surface_net_data.py --seed0 130400 --scenes 400 --fins 0.6 --out /tmp/fn1
    .venv-train/bin/python tools/train_fork_net.py --data /tmp/sn0_snout.npz /tmp/sn1_snout.npz \
        --out vision/models/surface_snout_net.onnx --epochs 8 --per-epoch 80000 --minutes 14 --threads 1 --val-scenes 40
    .venv-train/bin/python tools/train_fork_net.py --data /tmp/sn0_base.npz /tmp/sn1_base.npz /tmp/fn0_base.npz \
        /tmp/fn1_base.npz --out vision/models/surface_base_net.onnx --epochs 8 --per-epoch 80000 --minutes 14 \
        --threads 2 --val-scenes 40
The packaged body-end net (2026-12-07, forty-first session) is trained longer on more tanks:
``tools/surface_net_data.py --scenes 400`` at seeds 150000 and 150400 (``--fins 0``), 150800, 151200
and 151600 (``--fins 0.6``) and 152000 (``--fins 1.0``), two at a time (~11 min), then ``--data``
their six ``_base.npz`` ``--epochs 30 --per-epoch 100000 --minutes 30 --threads 2 --val-scenes 40``
(23 min, the machine to itself).
Seed-fixed (torch, numpy); the last ``--val-scenes`` scenes of the data are held out and their
figures printed (JSON lines) after every epoch. Two threads (the machine is shared).

Augmented for footage nobody here rendered: flips across the axis, per-channel gains, channel
swaps and grey, blur, noise, and brightness/contrast (the crop's own normalisation takes most).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from tools.torch_parts import sep_conv as _sep  # noqa: E402
from vision import fork_net  # noqa: E402

H, W = fork_net.GRID_H, fork_net.GRID_W
HH, HW = H // 2, W // 2
ANGLE_WEIGHT = 5.0      # at 0.5 the axis' turn stayed near 0 (8 degrees off stayed ~7 off after 4 epochs)


class ForkNet(nn.Module):
    def __init__(self):
        super().__init__()
        self.c1 = nn.Sequential(nn.Conv2d(3, 16, 3, 2, 1, bias=False), nn.BatchNorm2d(16), nn.ReLU())
        self.c2 = _sep(16, 24)
        self.c3 = _sep(24, 32, stride=2)
        self.c4 = _sep(32, 48, dil=2)
        self.c5 = _sep(48, 48, dil=4)
        self.heat_lo = nn.Conv2d(48, 1, 1)
        self.heat_hi = nn.Conv2d(24, 1, 1)
        self.head = nn.Sequential(nn.Linear(96, 32), nn.ReLU(), nn.Linear(32, 3))

    def forward(self, x):
        a = self.c2(self.c1(x))                     # (N, 24, H/2, W/2)
        b = self.c5(self.c4(self.c3(a)))            # (N, 48, H/4, W/4)
        heat = F.interpolate(self.heat_lo(b), scale_factor=2.0, mode="bilinear", align_corners=False) + self.heat_hi(a)
        pooled = torch.cat([b.mean(dim=(2, 3)), b.amax(dim=(2, 3))], dim=1)
        return heat, self.head(pooled)


US = torch.tensor(fork_net.U0 + (np.arange(HW) + 0.5) * (fork_net.U1 - fork_net.U0) / HW, dtype=torch.float32)
VS = torch.tensor(-fork_net.V1 + (np.arange(HH) + 0.5) * (2 * fork_net.V1) / HH, dtype=torch.float32)


def soft_argmax(heat):
    p = torch.softmax(heat.flatten(1), dim=1).view(-1, HH, HW)
    return torch.stack([(p.sum(1) * US).sum(1), (p.sum(2) * VS).sum(1)], dim=1), p


BLURS = [torch.tensor(np.outer(k, k), dtype=torch.float32) for k in
         [np.exp(-0.5 * (np.arange(-2, 3) / s) ** 2) / np.exp(-0.5 * (np.arange(-2, 3) / s) ** 2).sum()
          for s in (0.6, 0.9, 1.3)]]


def augment(x, y, g, flips: bool = True):
    """x uint8 (N, H, W, 3) -> float (N, 3, H, W) normalised; y (N, 5) with v and the turn flipped
    where the crop is (half of them; none without ``flips``: crops of one handedness)."""
    x = torch.from_numpy(x).float().permute(0, 3, 1, 2)
    y = torch.from_numpy(y).clone()
    N = len(x)
    flip = (torch.rand(N, generator=g) < 0.5) & flips
    x[flip] = x[flip].flip(2)
    y[flip, 2] = -y[flip, 2]
    y[flip, 3] = -y[flip, 3]
    gains = torch.exp(0.25 * torch.randn(N, 3, 1, 1, generator=g))
    x = x * gains
    perm = torch.rand(N, generator=g) < 0.15
    if perm.any():
        x[perm] = x[perm][:, torch.randperm(3, generator=g)]
    grey = torch.rand(N, generator=g) < 0.15
    x[grey] = x[grey].mean(1, keepdim=True).expand(-1, 3, -1, -1)
    contrast = torch.exp(0.4 * torch.randn(N, 1, 1, 1, generator=g))
    x = (x - x.mean(dim=(1, 2, 3), keepdim=True)) * contrast + x.mean(dim=(1, 2, 3), keepdim=True)
    which = torch.randint(0, len(BLURS) + 2, (N,), generator=g)
    for k, kern in enumerate(BLURS):
        m = which == k
        if m.any():
            x[m] = F.conv2d(F.pad(x[m], (2, 2, 2, 2), mode="replicate"), kern.expand(3, 1, 5, 5), groups=3)
    x = x + torch.randn(x.shape, generator=g) * (6 * torch.rand(N, 1, 1, 1, generator=g))
    x = x.clamp(0, 255).round()
    return normalise(x), y


def normalise(x):
    x = x - x.mean(dim=(2, 3), keepdim=True)
    return x / (x.std(dim=(1, 2, 3), keepdim=True, unbiased=False) + 4.0)


def losses(model, x, y):
    heat, head = model(x)
    heat = heat[:, 0]
    pos = y[:, 0] > 0.5
    cls = F.binary_cross_entropy_with_logits(head[:, 0], y[:, 0])
    if not pos.any():
        return cls, cls
    uv, p = soft_argmax(heat[pos])
    # positions in lengths, not spans: every fish's error counts alike
    rel = y[pos, 4:5]
    coord = (torch.abs(uv - y[pos, 1:3]) / rel).sum(1).mean()
    gu = torch.exp(-0.5 * ((US[None] - y[pos, 1:2]) / 0.06) ** 2)
    gv = torch.exp(-0.5 * ((VS[None] - y[pos, 2:3]) / 0.06) ** 2)
    target = gv[:, :, None] * gu[:, None, :]
    target = target / target.sum(dim=(1, 2), keepdim=True).clamp_min(1e-9)
    ce = -(target * torch.log(p.clamp_min(1e-9))).sum(dim=(1, 2)).mean()
    ang = ((head[pos, 1] - torch.sin(y[pos, 3])) ** 2 + (head[pos, 2] - torch.cos(y[pos, 3])) ** 2).mean()
    total = cls + 20.0 * coord + 0.1 * ce + ANGLE_WEIGHT * ang
    return total, coord


def evaluate(model, x, y, src):
    model.eval()
    out_uv, out_logit = [], []
    with torch.no_grad():
        for k in range(0, len(x), 2048):
            xb = normalise(torch.from_numpy(x[k:k + 2048]).float().permute(0, 3, 1, 2))
            heat, head = model(xb)
            uv, _ = soft_argmax(heat[:, 0])
            out_uv.append(uv.numpy())
            out_logit.append(head[:, 0].numpy())
    model.train()
    uv, logit = np.concatenate(out_uv), np.concatenate(out_logit)
    pos = y[:, 0] > 0.5
    err = np.hypot(uv[:, 0] - y[:, 1], uv[:, 1] - y[:, 2]) / np.maximum(y[:, 4], 1e-6)
    res = {}
    for name, m in (("proposals", src == 0), ("jittered", src == 1)):
        e = err[pos & m]
        res[name] = {"n": int(len(e)), "within_3pct": round(float((e <= 0.03).mean()), 3) if len(e) else None,
                     "within_1_5pct": round(float((e <= 0.015).mean()), 3) if len(e) else None,
                     "median_pct": round(100 * float(np.median(e)), 2) if len(e) else None}
    p = 1 / (1 + np.exp(-logit))
    res["class_acc"] = round(float(((p > 0.5) == pos).mean()), 3)
    res["pos_conf_median"] = round(float(np.median(p[pos])), 3)
    res["neg_over_0.5"] = round(float((p[~pos] > 0.5).mean()), 3)
    return res


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", nargs="+", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--epochs", type=int, default=8)
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--per-epoch", type=int, default=60000, help="crops drawn for each epoch")
    ap.add_argument("--val-scenes", type=int, default=100)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--minutes", type=float, default=25.0, help="stop training after this long")
    ap.add_argument("--no-flip", action="store_true",
                    help="no flips across the axis: crops of one handedness (snout_net_data.py --upright)")
    args = ap.parse_args()
    torch.manual_seed(0)
    torch.set_num_threads(args.threads)
    g = torch.Generator().manual_seed(0)
    parts = [np.load(p) for p in args.data]
    x = np.concatenate([p["x"] for p in parts])
    y = np.concatenate([p["y"] for p in parts]).astype(np.float32)
    meta = np.concatenate([p["meta"] for p in parts])
    seeds = np.unique(meta[:, 0])
    val = np.isin(meta[:, 0], seeds[-args.val_scenes:])
    xt, yt = x[~val], y[~val]
    xv, yv, sv = x[val], y[val], meta[val, 2]
    print(json.dumps({"train": int(len(xt)), "val": int(len(xv)), "train_pos": int(yt[:, 0].sum())}), flush=True)
    model = ForkNet()
    print(json.dumps({"params": sum(p.numel() for p in model.parameters())}), flush=True)
    per = min(args.per_epoch, len(xt))
    steps = args.epochs * (per // args.batch)
    opt = torch.optim.AdamW(model.parameters(), lr=3e-3, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=3e-3, total_steps=steps, pct_start=0.15)
    rng = np.random.default_rng(0)
    t0 = time.time()
    step = 0
    for epoch in range(args.epochs):
        order = rng.permutation(len(xt))[:per]
        run = []
        for k in range(0, len(order) - args.batch + 1, args.batch):
            idx = np.sort(order[k:k + args.batch])
            xb, yb = augment(xt[idx], yt[idx], g, not args.no_flip)
            loss, coord = losses(model, xb, yb)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            step += 1
            run.append(float(coord.detach()))
            if time.time() - t0 > 60 * args.minutes:
                break
        print(json.dumps({"epoch": epoch, "s": round(time.time() - t0), "coord_l1": round(float(np.mean(run)), 4),
                          "val": evaluate(model, xv, yv, sv)}), flush=True)
        export(model, args.out)
        if time.time() - t0 > 60 * args.minutes:
            break


def export(model, out):
    model.eval()
    dummy = torch.zeros(1, 3, H, W)
    torch.onnx.export(model, dummy, out, input_names=["crops"], output_names=["heat", "head"],
                      dynamic_axes={"crops": {0: "n"}, "heat": {0: "n"}, "head": {0: "n"}}, opset_version=13,
                      dynamo=False)
    model.train()


if __name__ == "__main__":
    main()
