import os
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from controller.errors import BadInput
from controller.surveys.frames import directory_items, read_pair, split_rg, still_source
from controller.surveys.video_frames import video_source


def grey(h=48, w=64, level=0):
    img = np.full((h, w), level, np.uint8)
    # some texture so codecs keep a picture; each level its own, so that two levels are two pictures
    # and not one twice (frames.check_two_views)
    img[np.random.default_rng(level).random((h, w)) < 0.1] = 200
    return img


def write(path: Path, img) -> str:
    assert cv2.imwrite(str(path), img)
    return str(path)


def test_stills_keep_argument_order_and_every_n_keeps_frame_numbers(tmp_path):
    items = [(write(tmp_path / f"{i}_L.png", grey(level=i)), write(tmp_path / f"{i}_R.png", grey(level=i + 1)))
             for i in range(7)]
    src = still_source(items, every=3)
    jobs = list(src.jobs)
    assert src.total == 3 and [j.frame for j in jobs] == [0, 3, 6]
    left, right, warn = read_pair(jobs[1])
    assert left[1, 1] == 3 and warn is None and left.shape == (48, 64)
    assert [j.frame for j in still_source(items, every=2, max_frames=2).jobs] == [0, 2]


def test_a_still_copied_under_another_name_or_given_twice_is_surveyed_once(tmp_path):
    """Five copies of one pair would count its fish five times: copies (the same bytes in both
    views) are left out and named with the pair they copy; same-sized pairs that differ, or share
    one view only, are all kept."""
    import shutil
    pairs = [(write(tmp_path / f"{i}_L.png", grey(level=i)), write(tmp_path / f"{i}_R.png", grey(level=i + 1)))
             for i in range(3)]
    for k in range(2):                                            # pair 0 copied twice, pair 2 once
        for side in "LR":
            shutil.copy(tmp_path / f"0_{side}.png", tmp_path / f"copy{k}_{side}.png")
    for side in "LR":
        shutil.copy(tmp_path / f"2_{side}.png", tmp_path / f"z_{side}.png")
    shutil.copy(tmp_path / "0_L.png", tmp_path / "half_L.png")   # the same left, another right: a pair of its own
    write(tmp_path / "half_R.png", grey(level=9))
    items = directory_items(str(tmp_path))
    src = still_source(items + [items[0]])                        # and the first pair given again
    names = [j.where for j in src.jobs]
    assert names == [" + ".join(items[i]) for i in range(len(items)) if Path(items[i][0]).stem[:-2] in
                     {"0", "1", "2", "half"}], names
    assert src.total == 4 and len(src.warnings) == 4
    copied = {w.split(":")[0]: w.split("the same images as ")[1] for w in src.warnings}
    first = " + ".join(items[[Path(a).stem for a, _ in items].index("0_L")])
    assert copied[" + ".join((str(tmp_path / "copy0_L.png"), str(tmp_path / "copy0_R.png")))].startswith(first)
    assert copied[" + ".join((str(tmp_path / "z_L.png"), str(tmp_path / "z_R.png")))].startswith(
        f"{tmp_path / '2_L.png'} + {tmp_path / '2_R.png'}")
    assert [j.frame for j in still_source(items, every=3).jobs] == [0, 5]   # every N counts the distinct pairs
    assert still_source(pairs).warnings == []


def test_a_missing_file_fails_before_anything_is_read(tmp_path):
    a, b = write(tmp_path / "a.png", grey()), write(tmp_path / "b.png", grey(level=1))
    with pytest.raises(BadInput, match=r"nope.png: no such file"):
        still_source([(a, b), (a, str(tmp_path / "nope.png"))])


@pytest.mark.parametrize("content, fault", [(b"", "empty file"), (b"not an image", "not a readable image")])
def test_unreadable_or_empty_images_are_named(tmp_path, content, fault):
    a = write(tmp_path / "a.png", grey())
    bad = tmp_path / "b.png"
    bad.write_bytes(content)
    job = next(still_source([(a, str(bad))]).jobs)
    with pytest.raises(BadInput, match=rf"b.png: {fault}"):
        read_pair(job)


def _encoded(ext: str, **params) -> bytes:
    flags = [v for kv in params.items() for v in (getattr(cv2, kv[0]), kv[1])]
    ok, data = cv2.imencode(ext, grey(96, 128), flags)
    assert ok
    return data.tobytes()


@pytest.mark.parametrize("ext, params, fault", [
    (".jpg", {}, "truncated JPEG"),
    (".jpg", {"IMWRITE_JPEG_PROGRESSIVE": 1}, "truncated JPEG"),     # several scans: cut in the last
    (".png", {}, "truncated PNG"),
])
@pytest.mark.parametrize("keep", [0.3, 0.6, 0.99])
def test_an_image_cut_short_is_named_not_measured_half_grey(tmp_path, ext, params, fault, keep):
    whole = _encoded(ext, **params)
    a = write(tmp_path / "a.png", grey(96, 128))
    cut = tmp_path / f"cut{ext}"
    cut.write_bytes(whole[:max(16, int(len(whole) * keep))])
    with pytest.raises(BadInput, match=rf"cut{ext}: {fault}"):
        read_pair(next(still_source([(a, str(cut))]).jobs))


def test_whole_images_with_a_thumbnail_or_a_trailer_are_read(tmp_path):
    """An EXIF-like thumbnail (a whole JPEG, end marker and all, before the main scan) and bytes
    after the end (camera trailers) are no truncation; the image reads as written."""
    main = _encoded(".jpg")
    thumb = _encoded(".jpg")
    app1 = b"Exif\x00\x00" + thumb
    with_thumb = main[:2] + b"\xff\xe1" + (len(app1) + 2).to_bytes(2, "big") + app1 + main[2:]
    other = write(tmp_path / "other.png", grey(96, 128, level=1))
    for name, data in (("thumb.jpg", with_thumb), ("trailer.jpg", main + b"\x00" * 64 + b"TRAILER"),
                       ("trailer.png", _encoded(".png") + b"\x00" * 16)):
        (tmp_path / name).write_bytes(data)
        left, right, _ = read_pair(next(still_source([(str(tmp_path / name), other)]).jobs))
        assert left.shape == (96, 128) == right.shape
        assert np.abs(left.astype(int) - grey(96, 128)).max() <= (0 if name.endswith(".png") else 60)


def test_left_and_right_of_different_sizes(tmp_path):
    a, b = write(tmp_path / "a.png", grey()), write(tmp_path / "b.png", grey(50, 64))
    with pytest.raises(BadInput, match=r"b.png: 64x50 pixels, but the left image .*a.png is 64x48"):
        read_pair(next(still_source([(a, b)]).jobs))


def test_colour_and_grey_pairs_are_read_as_they_are(tmp_path):
    c = write(tmp_path / "c.png", cv2.cvtColor(grey(), cv2.COLOR_GRAY2BGR))
    c2 = write(tmp_path / "c2.png", cv2.cvtColor(grey(level=5), cv2.COLOR_GRAY2BGR))
    left, right, _ = read_pair(next(still_source([(c, c2)]).jobs))
    assert left.shape == (48, 64, 3) and left.dtype == np.uint8


def test_rg_frame_left_is_red_right_is_green_and_blue_is_checked(tmp_path):
    img = np.zeros((48, 64, 3), np.uint8)
    img[..., 2], img[..., 1] = grey(level=10), grey(level=90)        # BGR: red = 2, green = 1
    left, right, warn = read_pair(next(still_source([(write(tmp_path / "rg.png", img),)]).jobs))
    assert left[1, 1] == 10 and right[1, 1] == 90 and warn is None
    img[..., 0] = 120
    _, _, warn = split_rg(img, "x.png")
    assert warn.startswith("x.png: blue channel not empty (mean level 120)")
    with pytest.raises(BadInput, match="grey image"):
        split_rg(grey(), "g.png")
    with pytest.raises(BadInput, match="not an RG frame"):
        split_rg(cv2.cvtColor(grey(), cv2.COLOR_GRAY2BGR), "g.png")


def test_directory_pairs_in_sorted_order_else_png_rg_frames(tmp_path):
    for stem in ("b", "a", "c10", "c09"):
        write(tmp_path / f"{stem}_R.png", grey())
        write(tmp_path / f"{stem}_L.jpg", grey())
    items = directory_items(str(tmp_path))
    assert [Path(left).name for left, _ in items] == ["a_L.jpg", "b_L.jpg", "c09_L.jpg", "c10_L.jpg"]
    assert all(Path(r).name == Path(left).name.replace("_L.jpg", "_R.png") for left, r in items)
    write(tmp_path / "d_L.png", grey())
    with pytest.raises(BadInput, match=r"d_L.png: no right image \(d_R.\*\) beside it"):
        directory_items(str(tmp_path))
    rg = tmp_path / "rg"
    rg.mkdir()
    (rg / "notes.txt").write_text("x")
    with pytest.raises(BadInput, match=r"rg: no pairs .* and no \*.png RG frames"):
        directory_items(str(rg))
    for i in (2, 1):
        write(rg / f"f{i}.png", np.zeros((8, 8, 3), np.uint8))
    assert [Path(p).name for (p,) in directory_items(str(rg))] == ["f1.png", "f2.png"]
    with pytest.raises(BadInput, match="no such directory"):
        directory_items(str(tmp_path / "none"))


def test_directory_pairs_named_l_r_in_lower_case_and_two_images_for_one_side_refused(tmp_path):
    for left, right in (("a_l.PNG", "a_r.PNG"), ("b_L.jpg", "b_r.jpg")):
        write(tmp_path / left, grey())
        write(tmp_path / right, grey())
    assert [tuple(Path(p).name for p in item) for item in directory_items(str(tmp_path))] == \
        [("a_l.PNG", "a_r.PNG"), ("b_L.jpg", "b_r.jpg")]
    write(tmp_path / "b_R.png", grey())       # a second right image for b: which is meant?
    with pytest.raises(BadInput, match=r"b_r\.jpg: a second right image for 'b', beside b_R\.png$"):
        directory_items(str(tmp_path))


@pytest.mark.parametrize("strays", [["rg1.png"], ["rg1.png", "chart.jpg", "zz.tif"]])
def test_an_image_that_is_no_one_of_a_pair_beside_pairs_is_refused_not_left_out(tmp_path, strays):
    """An RG frame among pairs was left out without a word: the survey's count rested on less."""
    for stem in ("a", "b"):
        write(tmp_path / f"{stem}_L.png", grey())
        write(tmp_path / f"{stem}_R.png", grey())
    for name in strays:
        write(tmp_path / name, grey())
    first = sorted(strays)[0]
    more = f", nor are {len(strays) - 1} more" if len(strays) > 1 else ""
    with pytest.raises(BadInput, match=rf"{first}: not one of a pair \(\*_L\.\* with \*_R\.\*\) beside 2 pairs"
                                       rf"{more}: move it out"):
        directory_items(str(tmp_path))
    (tmp_path / "notes.txt").write_text("not an image")
    for name in strays:
        (tmp_path / name).unlink()
    assert len(directory_items(str(tmp_path))) == 2          # what is no image is no stray


@pytest.mark.parametrize("layout", ["pairs", "rg", "folders"])
def test_hidden_files_a_mac_leaves_beside_each_image_are_not_surveyed(tmp_path, layout):
    """A folder copied from a Mac holds ``._a_L.png`` (AppleDouble, no image) beside each image:
    the survey stopped on it as unreadable."""
    names = {"pairs": ["a_L.png", "a_R.png"], "rg": ["f1.png"], "folders": ["H7_L/1.png", "H7_R/1.png"]}[layout]
    for name in names:
        path = tmp_path / name
        path.parent.mkdir(exist_ok=True)
        write(path, grey())
        (path.parent / f"._{path.name}").write_bytes(b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X")
    (tmp_path / ".thumbs_L.png").write_bytes(b"not an image")
    (tmp_path / ".Trashes").mkdir()
    (tmp_path / ".Trashes" / "x_L.png").write_bytes(b"not an image")
    items = directory_items(str(tmp_path))
    assert [tuple(Path(p).relative_to(tmp_path).as_posix() for p in item) for item in items] == \
        [tuple(names)]


@pytest.mark.parametrize("left, right", [("H7_L", "H7_R"), ("left", "right"), ("L", "R"), ("cam 1-l", "cam 1-r")])
def test_a_directory_of_two_view_folders_pairs_their_images_by_name(tmp_path, left, right):
    # StereoMorph's layout: Images/H7_L/008428.jpeg beside Images/H7_R/008428.jpeg
    for folder in (left, right):
        for name in ("008430.jpeg", "008428.jpeg", "008610.png"):
            (tmp_path / folder).mkdir(exist_ok=True)
            write(tmp_path / folder / name, grey())
    (tmp_path / left / "notes.txt").write_text("digitized by A.B.")
    (tmp_path / "H7_Shapes_2D").mkdir()                         # another folder of the project: not a view
    items = directory_items(str(tmp_path))
    assert [tuple(Path(p).relative_to(tmp_path).as_posix() for p in item) for item in items] == [
        (f"{left}/{n}", f"{right}/{n}") for n in ("008428.jpeg", "008430.jpeg", "008610.png")]


def test_images_beside_view_folders_are_what_is_surveyed(tmp_path):
    (tmp_path / "H7_L").mkdir()
    write(tmp_path / "H7_L" / "1.png", grey())
    write(tmp_path / "a_L.png", grey())
    write(tmp_path / "a_R.png", grey())
    assert [tuple(Path(p).name for p in item) for item in directory_items(str(tmp_path))] == [("a_L.png", "a_R.png")]


@pytest.mark.parametrize("layout, fault", [
    ({"H7_L": ["1.jpg", "2.jpg"], "H7_R": ["1.jpg"]}, r"H7_L/2\.jpg: no image named 2\.\* in .*H7_R to pair it with$"),
    ({"H7_L": ["1.jpg"], "H7_R": ["1.jpg", "3.jpg", "4.jpg"]},
     r"H7_R/3\.jpg: no image named 3\.\* in .*H7_L to pair it with \(1 more alone\)$"),
    ({"H7_L": ["1.jpg"]}, r"H7_L: no right view's folder beside it$"),
    ({"H7_L": ["1.jpg"], "left": ["1.jpg"], "H7_R": ["1.jpg"]}, r"left: a second left view's folder, beside H7_L$"),
    ({"H7_L": ["1.jpg", "1.png"], "H7_R": ["1.jpg"]}, r"H7_L/1\.png: a second image for '1', beside 1\.jpg$"),
    ({"H7_L": [], "H7_R": []}, r"H7_L: no images$"),
])
def test_view_folders_that_do_not_pair_are_named(tmp_path, layout, fault):
    for folder, names in layout.items():
        (tmp_path / folder).mkdir()
        for name in names:
            write(tmp_path / folder / name, grey())
    with pytest.raises(BadInput, match=fault):
        directory_items(str(tmp_path))


def make_video(path: Path, frames: int, size=(64, 48), rg=False, fps=25.0, started=0, blue=0) -> str:
    """A video whose frame i shows the moment i + ``started`` (its level, 8 a moment: a camera started
    ``started`` frames late shows the moment 0 at its frame -started)."""
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, size)
    assert out.isOpened()
    for i in range(frames):
        img = np.zeros((size[1], size[0], 3), np.uint8)
        img[:, :, 2 if rg else 1] = 8 * (i + started)       # the moment, readable back from the picture
        img[:, :, 1 if rg else 2] = 100
        img[:, :, 0] = blue
        out.write(img)
    out.release()
    return str(path)


def level(img) -> int:
    return int(round(float(np.median(img))))


def test_two_videos_read_in_order_every_n_max_m(tmp_path):
    a, b = make_video(tmp_path / "l.avi", 20), make_video(tmp_path / "r.avi", 20)
    src = video_source((a, b), every=3, max_frames=5)
    assert src.fps == pytest.approx(25.0) and src.total == 5
    jobs = list(src.jobs)
    assert [j.frame for j in jobs] == [0, 3, 6, 9, 12]
    assert [level(j.left[..., 1]) for j in jobs] == pytest.approx([0, 24, 48, 72, 96], abs=3)
    assert all(j.right.shape == (48, 64, 3) for j in jobs)
    assert [j.frame for j in video_source((a, b), every=7).jobs] == [0, 7, 14]


def test_rg_video_is_split_into_left_red_and_right_green(tmp_path):
    jobs = list(video_source((make_video(tmp_path / "rg.avi", 4, rg=True),)).jobs)
    assert len(jobs) == 4 and jobs[2].left.ndim == 2
    assert level(jobs[2].left) == pytest.approx(16, abs=3) and level(jobs[2].right) == pytest.approx(100, abs=3)


def test_an_rg_video_s_blue_channel_is_checked_as_an_rg_still_s(tmp_path):
    """Each frame's warning travels with its job, read where the pair is (as a still's does)."""
    clean = list(video_source((make_video(tmp_path / "rg.avi", 3, rg=True),)).jobs)
    assert [read_pair(j)[2] for j in clean] == [None] * 3
    bled = list(video_source((make_video(tmp_path / "blue.avi", 3, rg=True, blue=60),)).jobs)
    warnings = [read_pair(j)[2] for j in bled]
    assert all(w is not None and re.search(r"blue channel not empty \(mean level (5[5-9]|6[0-5])\)", w)
               for w in warnings), warnings                # MJPG's 60, give or take its rounding
    assert [w.split(":")[0] for w in warnings] == [f"{tmp_path}/blue.avi frame {i}" for i in range(3)]


def test_a_video_that_ends_early_is_named(tmp_path):
    a, b = make_video(tmp_path / "long.avi", 12), make_video(tmp_path / "short.avi", 8)
    with pytest.raises(BadInput, match=r"short.avi: ends at frame 8, but .*long.avi goes on"):
        list(video_source((a, b)).jobs)
    rg = make_video(tmp_path / "rg.avi", 12, rg=True)
    with pytest.raises(BadInput, match=r"rg.avi: --max-frames: the video ends after 12 frames \(6 pairs\), "
                                       r"before --max-frames 7"):
        list(video_source((rg,), every=2, max_frames=7).jobs)


@pytest.mark.parametrize("offset", [3, -4])
def test_sync_offset_pairs_the_same_moments_numbered_as_the_left_video(tmp_path, offset):
    # the right camera started `offset` frames before the left (its frame k + offset = the left's k);
    # negative: the left one started first
    left = make_video(tmp_path / "l.avi", 24, started=4)
    right = make_video(tmp_path / "r.avi", 24 + offset, started=4 - offset)
    src = video_source((left, right), every=2, sync_offset=offset)
    jobs = list(src.jobs)
    first = max(0, -offset)
    assert [j.frame for j in jobs] == list(range(first, 24, 2)) and src.total == len(jobs)
    moments = [level(j.left[..., 1]) / 8 - 4 for j in jobs]
    assert moments == pytest.approx([j.frame for j in jobs], abs=0.4)                  # the left's own frames
    assert [level(j.right[..., 1]) for j in jobs] == pytest.approx([level(j.left[..., 1]) for j in jobs], abs=3)
    # without it the pairs are two moments apart, and the lengths differ: named, the remedy with it
    with pytest.raises(BadInput, match=r"ends at frame \d+, but .* goes on: .*--sync-offset N .*--max-frames \d+"):
        list(video_source((left, right)).jobs)


def test_a_sync_offset_beyond_a_video_or_for_stills_is_refused(tmp_path):
    left, right = make_video(tmp_path / "l.avi", 6), make_video(tmp_path / "r.avi", 6)
    with pytest.raises(BadInput, match=r"r.avi: --sync-offset: skips 9 frames, but the video has 6"):
        video_source((left, right), sync_offset=9)
    with pytest.raises(BadInput, match=r"l.avi: no frames after --sync-offset"):
        list(video_source((left, right), sync_offset=-6).jobs)
    with pytest.raises(BadInput, match=r"--sync-offset: is for two videos"):
        video_source((make_video(tmp_path / "rg.avi", 4, rg=True),), sync_offset=1)


@pytest.mark.parametrize("fps_right, refused", [(10.0, True), (24.0, True), (26.0, True), (25.0, False),
                                                (25.2, False), (24.8, False)])
def test_two_videos_at_different_frame_rates_are_refused_before_any_frame(tmp_path, fps_right, refused):
    a, b = make_video(tmp_path / "l.avi", 6), make_video(tmp_path / "r.avi", 6, fps=fps_right)
    if refused:
        with pytest.raises(BadInput, match=rf"r.avi: {fps_right:g} frames/s, but .*l.avi is 25: not synchronised"):
            video_source((a, b))
    else:       # within 1 %: a container's rounding (29.97 written as 30), not another camera rate
        assert len(list(video_source((a, b)).jobs)) == 6


def test_missing_or_unopenable_video(tmp_path):
    with pytest.raises(BadInput, match=r"none.avi: no such file"):
        video_source((str(tmp_path / "none.avi"),))
    junk = tmp_path / "junk.avi"
    junk.write_bytes(b"\0" * 100)
    with pytest.raises(BadInput, match=r"junk.avi: (cannot open as a video|no frames)"):
        list(video_source((str(junk),)).jobs)


@pytest.mark.parametrize("ext", [".png", ".jpg", ".bmp", ".tif"])
def test_a_still_image_given_as_a_video_is_refused_as_one(tmp_path, ext):
    """FFmpeg reads a still as a one-frame video: surveyed so, its fish were single sightings, left
    out, and the survey counted 0 where --pair counted them."""
    rng = np.random.default_rng(0)
    stills = []
    for side in "lr":
        path = tmp_path / f"{side}{ext}"
        assert cv2.imwrite(str(path), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
        stills.append(str(path))
    with pytest.raises(BadInput, match=rf"l{ext}: a still image \(\w+\), not a video: survey stills with --pair"):
        list(video_source(tuple(stills)).jobs)
    with pytest.raises(BadInput, match=rf"l{ext}: a still image"):       # beside a real video
        list(video_source((stills[0], make_video(tmp_path / "r.avi", 5))).jobs)
    with pytest.raises(BadInput, match=rf"l{ext}: a still image"):       # as an RG video
        list(video_source((stills[0],)).jobs)


def test_a_video_of_one_frame_is_surveyed_as_one_pair(tmp_path):
    a, b = make_video(tmp_path / "l.avi", 1), make_video(tmp_path / "r.avi", 1)
    assert [j.frame for j in video_source((a, b)).jobs] == [0]


def test_one_file_or_one_picture_given_for_both_views_is_refused(tmp_path):
    """Its 'fish' were triangulated from no disparity into lengths that were never there."""
    a = write(tmp_path / "a.png", grey())
    copy = write(tmp_path / "copy.png", grey())
    with pytest.raises(BadInput, match=r"a.png: is the same file as the left view .*a.png"):
        still_source([(a, a)])
    with pytest.raises(BadInput, match=r"copy.png: is the same picture as the left view .*a.png"):
        read_pair(next(still_source([(a, copy)]).jobs))
    v = make_video(tmp_path / "v.avi", 4, size=(64, 48))
    with pytest.raises(BadInput, match=r"v.avi: is the same file as the left view"):
        video_source((v, v))
    textured = []
    for name in ("l.avi", "r.avi"):
        out = cv2.VideoWriter(str(tmp_path / name), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (64, 48))
        for _ in range(3):
            out.write(cv2.cvtColor(grey(), cv2.COLOR_GRAY2BGR))
        out.release()
        textured.append(str(tmp_path / name))
    with pytest.raises(BadInput, match=r"r.avi frame 0: is the same picture as the left view .*l.avi frame 0"):
        list(video_source(tuple(textured)).jobs)
    # two dark frames alike (lights off, a capped lens): a pair with nothing in it
    dark = [write(tmp_path / f"dark_{s}.png", np.zeros((48, 64), np.uint8)) for s in "LR"]
    left, right, _ = read_pair(next(still_source([tuple(dark)]).jobs))
    assert not left.any() and not right.any()


@pytest.mark.parametrize("rg", [False, True])
def test_a_video_cut_short_of_its_header_is_refused_not_surveyed_to_its_damaged_end(tmp_path, rg):
    """A copy interrupted halfway: its header still declares every frame; the frames decoded stop
    halfway, the last of them perhaps half decoded. Surveyed without a word before."""
    whole = [make_video(tmp_path / f"{s}.avi", 30, rg=rg, size=(320, 240)) for s in ("lr" if not rg else "l")]
    cut = []
    for path in whole:
        data = Path(path).read_bytes()
        Path(path + ".cut.avi").write_bytes(data[:len(data) // 2])
        cut.append(path + ".cut.avi")
    jobs = video_source(tuple(cut)).jobs
    with pytest.raises(BadInput, match=r"\.cut\.avi: ends at frame \d+, but its header declares 30 frames: cut short "
                                       r"or damaged; --max-frames \d+ surveys the pairs before its end"):
        list(jobs)
    assert len(list(video_source(tuple(whole)).jobs)) == 30          # whole, it is read to its end


@pytest.mark.parametrize("cut_side", [0, 1])
def test_one_of_two_videos_cut_short_is_named_cut_not_unsynchronised(tmp_path, cut_side):
    """Only one file cut short: it was blamed on synchronisation and its --max-frames advice took in
    the cut file's last, perhaps half-decoded frame. It is named as cut short, the advice stopping
    before its last frame."""
    whole = [make_video(tmp_path / f"{s}.avi", 30, size=(320, 240)) for s in "lr"]
    data = Path(whole[cut_side]).read_bytes()
    cut = whole[cut_side] + ".cut.avi"
    Path(cut).write_bytes(data[:len(data) // 2])
    pair = list(whole)
    pair[cut_side] = cut
    with pytest.raises(BadInput) as caught:
        list(video_source(tuple(pair)).jobs)
    msg = str(caught.value)
    m = re.search(r"\.cut\.avi: ends at frame (\d+), but its header declares 30 frames: cut short or damaged; "
                  r"--max-frames (\d+) surveys the pairs before its end", msg)
    assert m and int(m[2]) == int(m[1]) - 1 and "synchronised" not in msg, msg


def _rendered_view(seed: int):
    from devices.sim.fish_scene import underwater_rig, underwater_scene
    scene = underwater_scene(np.random.default_rng(seed), underwater_rig(image_size=(640, 480), focal_px=700.0))
    return scene.left, scene.right


def _jpeg(img, quality: int):
    return cv2.imdecode(cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])[1], cv2.IMREAD_UNCHANGED)


@pytest.mark.parametrize("quality", [50, 75, 95, 100])
def test_one_picture_recompressed_for_the_other_view_is_refused(tmp_path, quality):
    """One picture as both views, not equal but as good as (a JPEG copy; red = green in an RG frame):
    its 'fish' were invented from a zero disparity (an outside tester: two fish of 22 and 24 cm, exit 0)."""
    left, right = _rendered_view(quality)
    a = write(tmp_path / "a_L.png", left)
    copy = write(tmp_path / "a_R.jpg", _jpeg(left, quality))
    with pytest.raises(BadInput, match=r"a_R.jpg: is the left view .*a_L.png again \(correlation (0\.9\d|1\.00)"):
        read_pair(next(still_source([(a, copy)]).jobs))
    g = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
    rg = write(tmp_path / "rg.png", np.dstack([np.zeros_like(g), _jpeg(g, quality), g]))
    with pytest.raises(BadInput, match=r"rg.png: red and green are one picture"):
        read_pair(next(still_source([(rg,)]).jobs))
    # the two cameras' own views of the same moment are a pair, as a pair and as an RG frame
    b = write(tmp_path / "b_R.png", right)
    assert read_pair(next(still_source([(a, b)]).jobs))[0].shape == left.shape
    gr = cv2.cvtColor(right, cv2.COLOR_BGR2GRAY)
    rg2 = write(tmp_path / "rg2.png", np.dstack([np.zeros_like(g), gr, g]))
    assert read_pair(next(still_source([(rg2,)]).jobs))[0].shape == g.shape


@pytest.mark.parametrize("seed", range(4))
def test_one_camera_s_colour_picture_given_as_an_rg_frame_is_refused(tmp_path, seed):
    """A colour view (one camera: blue green water) read as an RG frame: its red against its green
    may stay under the same-picture bound (0.80 here), but its blue holds the picture too; measured
    so, a colour video gave a fish of 401 g at exit 0 (an outside tester). An RG frame of the two
    views, JPEG'd (its blue mere bleed), is still a pair, with no warning."""
    left, right = _rendered_view(seed)
    deep = left.copy()           # deep water: red nearly gone, its sensor noise left (red ~ green < 0.8)
    noise = np.random.default_rng(seed).normal(0, 4, left.shape[:2])
    deep[..., 2] = np.clip(0.1 * left[..., 2] + 20 + noise, 0, 255).astype(np.uint8)
    for name, img in (("colour.png", left), ("colour.jpg", _jpeg(left, 90)), ("deep.png", deep),
                      ("deep.jpg", _jpeg(deep, 90))):
        path = write(tmp_path / name, img)
        with pytest.raises(BadInput) as refused:
            read_pair(next(still_source([(path,)]).jobs))
        said = str(refused.value)
        assert re.search(rf"{name}: a colour picture, not an RG frame: its blue channel \(mean level \d+\) is "
                         r"the picture its (green|red) is" if name.startswith("deep") else
                         rf"{name}: (a colour picture|red and green are one picture)", said), said
    rg = np.dstack([np.zeros(left.shape[:2], np.uint8), cv2.cvtColor(right, cv2.COLOR_BGR2GRAY),
                    cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)])
    for quality in (75, 95):
        _, _, warn = read_pair(next(still_source([(write(tmp_path / f"rg{quality}.png", _jpeg(rg, quality)),)]).jobs))
        assert warn is None


def test_two_cameras_views_are_far_from_one_picture_twice():
    """The bound's margin, both sides: rendered pairs and (where the shared folder is) the real
    chessboard set from two cameras, against copies of one view through JPEG and a 1 px shift."""
    from controller.surveys.frame_pixels import SAME_PICTURE, likeness
    from tests.vision.shared_data import SHARED_DATA
    pairs = [_rendered_view(seed) for seed in range(6)]
    real = sorted((SHARED_DATA / "stereo-chessboard").glob("left*.jpg"))
    pairs += [(cv2.imread(str(p)), cv2.imread(str(p).replace("left", "right"))) for p in real]
    assert max(likeness(a, b) for a, b in pairs) < SAME_PICTURE / 4
    copies = [_jpeg(a, 50) for a, _ in pairs] + [np.roll(a, 1, axis=1) for a, _ in pairs]
    assert min(likeness(a, c) for (a, _), c in zip(pairs + pairs, copies, strict=True)) > SAME_PICTURE


def test_a_still_that_is_a_pipe_is_refused_before_any_is_read(tmp_path):
    """A FIFO held the survey until something wrote to it (then read empty); ``<(...)`` was 'no such
    file' to the worker processes that read stills. Both refused at once, by name."""
    import os
    right = write(tmp_path / "a_R.png", grey(level=3))
    fifo = tmp_path / "a_L.png"
    os.mkfifo(fifo)
    with pytest.raises(BadInput, match=r"a_L.png: not a regular file \(a pipe"):
        still_source([(str(fifo), right)])
    r, w = os.pipe()
    try:
        with pytest.raises(BadInput, match=rf"/dev/fd/{r}: not a regular file"):
            still_source([(f"/dev/fd/{r}", right)])
    finally:
        os.close(r)
        os.close(w)


def test_a_worker_s_job_of_too_many_pixels_is_refused_from_its_header_not_decoded():
    """A 20000x20000 job took a worker 1.37 GB to refuse (an outside tester): its header says so."""
    from controller.surveys.runner import check_header_size
    from devices.sim.stereo_rig import convergent_rig
    from tests.controller.huge_images import huge_png
    from vision.calib_file import StereoCalibration
    rig = convergent_rig()
    p_only = StereoCalibration(P1=rig.P1, P2=rig.P2)          # no image size to refuse it by
    big = huge_png(20000, 20000)
    with pytest.raises(BadInput, match=r"left.png: 20000x20000 pixels: more than any survey camera's 50 megapixels"):
        check_header_size(p_only, (big, big), ("left.png", "right.png"))
    fine = huge_png(7000, 7000)                              # 49 megapixels: left to the rest of the checks
    check_header_size(p_only, (fine, fine), ("left.png", "right.png"))


@pytest.mark.parametrize("kind", ["directory", "dangling", "loop", "fifo"])
def test_a_view_named_as_an_image_but_no_file_is_named_for_what_it_is(tmp_path, kind):
    write(tmp_path / "a_L.png", grey())
    other = tmp_path / "a_R.png"
    if kind == "directory":
        other.mkdir()
    elif kind == "dangling":
        other.symlink_to(tmp_path / "gone.png")
    elif kind == "loop":
        other.symlink_to(tmp_path / "b_R.png")
        (tmp_path / "b_R.png").symlink_to(other)
    else:
        os.mkfifo(other)
    said = {"directory": "a directory", "dangling": "a link to nothing", "loop": "a link that loops",
            "fifo": "not a regular file"}[kind]
    with pytest.raises(BadInput) as err:
        directory_items(str(tmp_path))
    assert f"a_R.png: {said}, not an image file" in str(err.value)
