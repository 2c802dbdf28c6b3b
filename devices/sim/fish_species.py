"""Species the simulated stereo camera renders: body outline, fins, colours and length-weight law.

Outline numbers are ratios of fork length L (snout tip to the innermost point of the caudal fork),
read off lateral photographs and FishBase drawings to about +-10 %: they make the five species look
different (deep-bodied bream, slender salmon), not a taxonomic key. Length-weight coefficients
(W = a L^b, L cm, W g): gilthead sea bream from the issue (a = 0.02263, b = 3.032); the others are
typical FishBase Bayesian estimates for the species (Froese et al. 2014), to within the spread
between published stocks.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Species:
    name: str
    a: float                       # W = a L^b, L fork length cm, W g
    b: float
    depth: float                   # max body depth / L
    width: float                   # max body width / L (laterally compressed: width << depth)
    depth_at: float                # where the body is deepest, fraction of the body (snout = 0)
    dorsal_share: float            # share of the depth above the snout-fork axis
    peduncle: float                # caudal peduncle depth / max depth
    body_end: float                # x of the caudal peduncle (fin base) / L
    lobe_tip: float                # x of the caudal lobe tips / L (fork notch at 1.0)
    lobe_span: float               # half height of the caudal fin at its tips / L
    dorsal_fin: tuple[float, float, float]   # start, end (fraction of the body), height / L
    anal_fin: tuple[float, float, float]
    back: tuple[float, float, float]         # BGR albedo of the back (0..1)
    belly: tuple[float, float, float]        # BGR albedo of the belly
    fin: tuple[float, float, float]          # BGR albedo of the fins
    markings: str = ""             # "spots", "bars", "band", "gill_spot"
    mean_length_cm: tuple[float, float] = (20.0, 35.0)   # farmed stock means drawn from
    nursery_length_cm: tuple[float, float] = (7.0, 14.0)


SPECIES: dict[str, Species] = {s.name: s for s in (
    Species("sparus_aurata", a=0.02263, b=3.032, depth=0.38, width=0.14, depth_at=0.38,
            dorsal_share=0.56, peduncle=0.26, body_end=0.86, lobe_tip=1.13, lobe_span=0.17,
            dorsal_fin=(0.33, 0.80, 0.09), anal_fin=(0.62, 0.82, 0.07),
            back=(0.36, 0.38, 0.36), belly=(0.95, 0.95, 0.95), fin=(0.45, 0.47, 0.50),
            markings="gill_spot", mean_length_cm=(18.0, 32.0), nursery_length_cm=(7.0, 14.0)),
    Species("dicentrarchus_labrax", a=0.0107, b=3.02, depth=0.26, width=0.12, depth_at=0.40,
            dorsal_share=0.55, peduncle=0.36, body_end=0.88, lobe_tip=1.08, lobe_span=0.13,
            dorsal_fin=(0.30, 0.78, 0.10), anal_fin=(0.64, 0.80, 0.07),
            back=(0.32, 0.32, 0.28), belly=(0.95, 0.95, 0.95), fin=(0.50, 0.50, 0.50),
            mean_length_cm=(22.0, 38.0), nursery_length_cm=(8.0, 15.0)),
    Species("salmo_salar", a=0.0094, b=3.04, depth=0.25, width=0.13, depth_at=0.42,
            dorsal_share=0.52, peduncle=0.34, body_end=0.90, lobe_tip=1.05, lobe_span=0.12,
            dorsal_fin=(0.40, 0.55, 0.09), anal_fin=(0.70, 0.82, 0.07),
            back=(0.35, 0.32, 0.25), belly=(0.96, 0.96, 0.97), fin=(0.40, 0.40, 0.40),
            markings="spots", mean_length_cm=(40.0, 70.0), nursery_length_cm=(8.0, 16.0)),
    Species("oncorhynchus_mykiss", a=0.0112, b=3.03, depth=0.26, width=0.13, depth_at=0.42,
            dorsal_share=0.53, peduncle=0.36, body_end=0.91, lobe_tip=1.04, lobe_span=0.12,
            dorsal_fin=(0.40, 0.55, 0.09), anal_fin=(0.68, 0.80, 0.07),
            back=(0.22, 0.32, 0.28), belly=(0.85, 0.88, 0.92), fin=(0.40, 0.45, 0.50),
            markings="band", mean_length_cm=(25.0, 42.0), nursery_length_cm=(8.0, 15.0)),
    Species("oreochromis_niloticus", a=0.0186, b=2.98, depth=0.36, width=0.15, depth_at=0.40,
            dorsal_share=0.55, peduncle=0.35, body_end=0.86, lobe_tip=1.03, lobe_span=0.15,
            dorsal_fin=(0.28, 0.84, 0.10), anal_fin=(0.62, 0.83, 0.09),
            back=(0.30, 0.33, 0.33), belly=(0.75, 0.80, 0.82), fin=(0.38, 0.40, 0.45),
            markings="bars", mean_length_cm=(16.0, 28.0), nursery_length_cm=(6.0, 12.0)),
)}
