"""Train the whole-report check (``vision.fish_check``) on crops from tools/fish_check_data.py and
export it to ONNX (run by ONNX Runtime).

Not part of the project's dependencies or its suite: torch lives in a separate venv (see
tools/train_fork_net.py's docstring for it).
    .venv/bin/python tools/fish_check_data.py --seed0 310000 --scenes 400 --out /tmp/fc_a.npz
    .venv/bin/python tools/fish_check_data.py --seed0 310400 --scenes 400 --out /tmp/fc_b.npz
    .venv-train/bin/python tools/train_fish_check.py --data /tmp/fc_a.npz /tmp/fc_b.npz \
        --out vision/models/fish_check.onnx --epochs 8 --minutes 20 --threads 2
Seed-fixed (torch, numpy); the last ``--val-scenes`` scenes are held out and their figures printed
(JSON lines) after every epoch. Augmented as the crop nets are (flips across the axis, gains,
channel swaps and grey, contrast, blur, noise).
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
from tools.train_fork_net import BLURS, normalise  # noqa: E402
from vision import fish_check  # noqa: E402

H, W = fish_check.GRID_H, fish_check.GRID_W


class FishCheck(nn.Module):
    def __init__(self):
        super().__init__()
        self.c1 = nn.Sequential(nn.Conv2d(3, 16, 3, 2, 1, bias=False), nn.BatchNorm2d(16), nn.ReLU())
        self.c2 = _sep(16, 24)
        self.c3 = _sep(24, 32, stride=2)
        self.c4 = _sep(32, 48, stride=2)
        self.c5 = _sep(48, 64, dil=2)
        self.head = nn.Sequential(nn.Linear(128, 32), nn.ReLU(), nn.Linear(32, 1))

    def forward(self, x):
        b = self.c5(self.c4(self.c3(self.c2(self.c1(x)))))
        return self.head(torch.cat([b.mean(dim=(2, 3)), b.amax(dim=(2, 3))], dim=1))


def augment(x, g):
    """x uint8 (N, H, W, 3) -> float (N, 3, H, W) normalised."""
    x = torch.from_numpy(x).float().permute(0, 3, 1, 2)
    N = len(x)
    flip = torch.rand(N, generator=g) < 0.5
    x[flip] = x[flip].flip(2)
    x = x * torch.exp(0.25 * torch.randn(N, 3, 1, 1, generator=g))
    perm = torch.rand(N, generator=g) < 0.15
    if perm.any():
        x[perm] = x[perm][:, torch.randperm(3, generator=g)]
    grey = torch.rand(N, generator=g) < 0.15
    x[grey] = x[grey].mean(1, keepdim=True).expand(-1, 3, -1, -1)
    contrast = torch.exp(0.4 * torch.randn(N, 1, 1, 1, generator=g))
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    x = (x - mean) * contrast + mean
    which = torch.randint(0, len(BLURS) + 2, (N,), generator=g)
    for k, kern in enumerate(BLURS):
        m = which == k
        if m.any():
            x[m] = F.conv2d(F.pad(x[m], (2, 2, 2, 2), mode="replicate"), kern.expand(3, 1, 5, 5), groups=3)
    x = x + torch.randn(x.shape, generator=g) * (6 * torch.rand(N, 1, 1, 1, generator=g))
    return normalise(x.clamp(0, 255).round())


def evaluate(model, x, y, src):
    model.eval()
    with torch.no_grad():
        z = np.concatenate([model(normalise(torch.from_numpy(x[k:k + 2048]).float().permute(0, 3, 1, 2)))[:, 0].numpy()
                            for k in range(0, len(x), 2048)])
    model.train()
    p = 1 / (1 + np.exp(-z))
    out = {}
    for name, m in (("synthetic", src == 0), ("pipeline", src == 1)):
        if not m.any():
            continue
        pos, neg = (y == 1) & m, (y == 0) & m
        acc = round(float(((p[m] > 0.5) == (y[m] == 1)).mean()), 3)
        out[name] = {"n": int(m.sum()), "right": int(pos.sum()), "acc": acc,
                     "right_over_0.5": round(float((p[pos] > 0.5).mean()), 3) if pos.any() else None,
                     "wrong_over_0.5": round(float((p[neg] > 0.5).mean()), 3) if neg.any() else None,
                     "auc": auc(p[m], y[m] == 1)}
    return out


def auc(p, pos):
    if pos.all() or not pos.any():
        return None
    r = np.argsort(np.argsort(p)) + 1
    return round(float((r[pos].sum() - pos.sum() * (pos.sum() + 1) / 2) / (pos.sum() * (~pos).sum())), 4)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", nargs="+", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--epochs", type=int, default=8)
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--per-epoch", type=int, default=40000)
    ap.add_argument("--val-scenes", type=int, default=80)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--minutes", type=float, default=20.0)
    ap.add_argument("--pipeline-weight", type=float, default=3.0, help="the pipeline's own segments count this much")
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
    xt, yt, wt = x[~val], y[~val], np.where(meta[~val, 2] == 1, args.pipeline_weight, 1.0).astype(np.float32)
    xv, yv, sv = x[val], y[val], meta[val, 2]
    model = FishCheck()
    print(json.dumps({"train": int(len(xt)), "val": int(len(xv)), "train_right": int(yt.sum()),
                      "params": sum(p.numel() for p in model.parameters())}), flush=True)
    per = min(args.per_epoch, len(xt))
    steps = args.epochs * (per // args.batch)
    opt = torch.optim.AdamW(model.parameters(), lr=3e-3, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=3e-3, total_steps=steps, pct_start=0.15)
    rng = np.random.default_rng(0)
    t0 = time.time()
    for epoch in range(args.epochs):
        order = rng.permutation(len(xt))[:per]
        run = []
        for k in range(0, len(order) - args.batch + 1, args.batch):
            idx = np.sort(order[k:k + args.batch])
            z = model(augment(xt[idx], g))[:, 0]
            loss = F.binary_cross_entropy_with_logits(z, torch.from_numpy(yt[idx]), weight=torch.from_numpy(wt[idx]))
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            run.append(float(loss.detach()))
            if time.time() - t0 > 60 * args.minutes:
                break
        print(json.dumps({"epoch": epoch, "s": round(time.time() - t0), "loss": round(float(np.mean(run)), 4),
                          "val": evaluate(model, xv, yv, sv)}), flush=True)
        export(model, args.out)
        if time.time() - t0 > 60 * args.minutes:
            break


def export(model, out):
    model.eval()
    torch.onnx.export(model, torch.zeros(1, 3, H, W), out, input_names=["crops"], output_names=["logit"],
                      dynamic_axes={"crops": {0: "n"}, "logit": {0: "n"}}, opset_version=13, dynamo=False)
    model.train()


if __name__ == "__main__":
    main()
