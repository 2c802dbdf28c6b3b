"""The underwater pipeline's settings (``vision.underwater.Params``): what each stage looks for and
keeps, with the measurements each default rests on."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Params:
    min_fish_frac: float = 0.08     # shortest fish looked for, as a fraction of the image width
    work_width: int = 320           # width of the working image bodies are found on
    mask_k: tuple[float, ...] = (2.0, 5.0)   # fish: water distance above median + k MAD
    end_offsets: tuple[float, ...] = (-0.12, -0.02)   # fork hypotheses at each
                                    # region end, shifted by these shares of its length along its axis
                                    # (five offsets, -0.17..0.03, found as many fish on four bench
                                    # sets with the fork stage ~10-20 % dearer)
    otsu_share: float = 1.0         # ... and above this share of Otsu's threshold
    max_fins: int = 60              # per image
    band_px: float = 3.0            # epipolar band for fork pairing
    max_residual_px: float = 2.5    # snout triangulation
    good_length_px: float = 250.0   # fish this long in the image score 1 on size (x image width / 1280)
    fin_floor: float = 0.2          # the least the fork-template term (eq. 13) gives a located fork
    min_score: float = 0.02         # post-filter: a fish whose measurement rests on little is dropped
    max_epipolar: float = 0.03      # post-filter: each end within this share of the length of the other
                                    # image's best match along its epipolar line ...
    epipolar_either: bool = True    # ... looked for from either view (False: from both; before 2026-12-03,
                                    # seventh session, when it dropped 41 of 155 right reports on the tuning
                                    # seeds, 27 of them right in every direction, and 9 of 12 wrong ones)
    transfer: bool = True           # a fork found in one image only is looked for along its epipolar line
    transfer_snouts: bool = True    # each left snout candidate is looked for along its epipolar line on the
                                    # right (off: ~9 % less CPU, recall -0.005 / -0.015 on the bench sets)
    transfer_snout_min: float = 0.9  # ... where the learned snout locator is at least this sure of it
                                    # (2026-12-03: as many fish on the bench sets, one more on the tuning
                                    # seeds, ~1-2 % less CPU than 0)
    near_mm: float = 300.0          # working range of the rig for that search (from the camera)
    far_mm: float = 4000.0
    bank_per_mpix: float = 8.0      # eq. (13)'s best fork proposals per megapixel (0: off; 10 at 1280x960)
    bank_levels: int = 2            # ... scored on the working image and its first halving
    bank_stride: int = 2            # ... at grid points this many px apart
    bank_keep: float = 0.1          # ... the share of them with the most emboss energy
    bank_right: bool = False        # ... in the right view too (2026-12-08: off, its forks found there along
                                    # their epipolar lines, as any fork seen in one view: the six bench sets
                                    # 745 right, 25 wrong against 746, 25; the outside testers and the drawn
                                    # fish the same; 5-9 ms less a pair of ~95. Without ``transfer``: on)
    row_regions: bool = False       # fork proposals at the ends of regions unlike the row-compensated water
                                    # (on until 2026-12-07, thirty-eighth session: off, the six bench sets found
                                    # 677 fish right against 669, 25 wrong against 23, the outside testers' 39 / 4
                                    # and 28 / 7 against 40 / 4 and 26 / 7, with ~12-15 % less CPU a pair;
                                    # README "Underwater fish measurement")
    outlines: bool = True           # fork proposals from silhouettes against the local background
    outline_k: tuple[float, ...] = (2.0, 4.0)   # ... thresholds, in local background spreads
    outline_ends: tuple[float, ...] = (-0.12, -0.02)   # ... outline ends shifted by these shares of its length
    fork_net: bool = True           # forks located by the learned locator (vision.fork_net), not vision.fork
    net_min_conf: float = 0.9       # ... where its confidence is at least this (2026-12-03, 0.5 -> 0.9: the
                                    # same reports on three bench sets and at 1920x1080, one more fish on seeds
                                    # 1000+, ~15 % less CPU a pair: the score kept no fork pair below 0.9 at
                                    # min_chance 0.75, and its forks were most of what transfers and snouts cost)
    net_weight: float = 1.0         # ... which enters the score raised to this power
    upright: bool = False           # the learned locators' crops and eq. 13's window with v down the image
                                    # (vision.fins.down_side): both swimming directions alike (README, "Both
                                    # swimming directions alike"); off for the fork locator's crops, which
                                    # placed the drawn fish worse (README, "Upright snouts")
    upright_snouts: bool = True     # ... the snout locator's crops alone, and (below) eq. 13's window alone:
    upright_fins: bool = True       # on since 2026-12-07 (forty-second session): the outside testers' fish
                                    # 43 / 5 and 32 / 6 -> 49 / 2 and 39 / 4 right / wrong, the six bench sets
                                    # 708 / 24 -> 707 / 21, the drawn fish as before (the fork locator's upright
                                    # crops placed one in ten of those 1.36 % off: README, "Upright snouts")
    min_fill: float = 0.0           # the least share of the fork-snout segment inside a silhouette (term 0 there)
    max_fork_residual_px: float = np.inf    # post-filter: the forks' triangulation residual
    keypoints: bool = True          # fork hypotheses and snout candidates from the learned keypoint net
                                    # (vision.fish_keypoints) over the whole image
    kp_classical: bool = True       # ... beside the classical proposers (False: the net's only)
    kp_width: int = 320             # ... which sees the image this wide
    kp_mirrored: bool = False       # ... and its mirror image too, the maps averaged (fish_keypoints.maps)
    kp_min_conf: float = 0.05       # ... its peaks at least this sure (tuning seeds 200000+: forks within
                                    # 10 % of the length for 65 % of clear fish at 0.05, 46 % at 0.1)
    kp_offsets: tuple[float, ...] = (0.0,)  # ... a hypothesis at each fork shifted by these shares of its
                                    # length towards its snout
    kp_floor: float = 1.0           # ... its fork confidence enters the score as floor + (1 - floor) x conf
    kp_snout_floor: float = 1.0     # ... and its snout's agreement with the chosen one likewise
    kp_snouts: bool = True          # ... its snout paired with each fork is a snout candidate
    snout_net: bool = True          # snout candidates moved to the learned snout locator's tip (vision.snout_net)
    snout_net_min: float = 0.5      # ... where it is at least this sure, dropped elsewhere (2026-12-03: before,
                                    # kept where they were; as many fish on the bench sets and the tuning seeds
                                    # and one more on seeds 1000+, one wrong report fewer at 1920x1080)
    snout_to_edge: bool = False     # ... and its tip then taken to the image's own edge by the classical tip
                                    # search (vision.snout.refine_tips), as every other candidate is (2026-12-06:
                                    # the net of then placed two outside testers' snouts ~1 % of the length inside
                                    # the fish; on, more fish there, fewer on the project's renderer and the
                                    # 60-day grow-out over its 10 min: README, "Snouts at the image's edge"; the
                                    # net trained since on every snout shape: "Snout and fork shapes")
    learned_score: bool = True      # the score is the fitted chance the report is right (vision.learned_score),
                                    # not the product of terms (kept as quality "hand_score")
    min_chance: float = 0.85        # ... post-filter then: a fish less likely right than this is dropped
                                    # (0.75 until the epipolar check looked from either view; 0.85 since:
                                    # more recall at no less precision on the tuning seeds 200000+, both bench
                                    # sets and 1920x1080, where 0.75 lost 1-2 points of precision; 0.88 with
                                    # the keypoint net of 2026-12-07: the least at which the tuning seeds and
                                    # seeds 0+ hold 0.95, README "The keypoint net retrained on reef"; 0.85
                                    # again with upright snouts (forty-second session): six bench sets 707 / 21
                                    # -> 746 / 25, the outside testers 49 / 2 -> 56 / 5 and 39 / 4 -> 47 / 5;
                                    # at 0.8 769 / 32: README "Upright snouts")

    @property
    def snout_crops_upright(self) -> bool:
        """Whether the snout locator's crops are upright: all of them (``upright``) or these alone."""
        return self.upright or self.upright_snouts

    @property
    def fin_window_upright(self) -> bool:
        """Whether eq. 13's window at located forks is upright: everything or it alone."""
        return self.upright or self.upright_fins
