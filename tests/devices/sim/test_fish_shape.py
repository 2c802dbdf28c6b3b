"""The simulated fish's snout and fork shapes (``snout_taper``, ``notch_power``): the head or the fork
alone reshaped, drawn per fish only when asked for."""
import numpy as np
import pytest

from devices.sim.fish_body import HEAD, N_ALONG, N_AROUND, build_mesh
from devices.sim.fish_conditions import underwater_conditions
from devices.sim.fish_placement import populate
from devices.sim.fish_scene import underwater_rig, underwater_scene
from devices.sim.fish_species import SPECIES

TINY = dict(image_size=(320, 240), focal_px=350.0)


def _rings(mesh):
    """(u along the body, depth above the axis, half width) of each body ring, snout first."""
    ring = mesh.verts[1:1 + N_ALONG * N_AROUND].reshape(N_ALONG, N_AROUND, 3)
    x_end = ring[-1, 0, 0]
    return ring[:, 0, 0] / x_end, ring[:, :, 2].max(axis=1), ring[:, :, 1].max(axis=1)


def _tip_power(mesh):
    """The snout outline's power: the log-log slope of depth over the first rings."""
    u, depth, _ = _rings(mesh)
    head = np.flatnonzero(u < 0.05)[:4]
    return np.polyfit(np.log(u[head]), np.log(depth[head]), 1)[0]


@pytest.mark.parametrize("name", sorted(SPECIES))
@pytest.mark.parametrize("taper", [-0.5, -0.3, 0.25, 0.8, 1.5])
def test_taper_sets_the_snouts_power_and_leaves_the_body_behind_the_head(name, taper):
    sp = SPECIES[name]
    plain = build_mesh(sp, 300.0)
    u, depth0, width0 = _rings(plain)
    mesh = build_mesh(sp, 300.0, snout_taper=taper)
    u1, depth, width = _rings(mesh)
    np.testing.assert_allclose(u1, u)
    behind = u >= HEAD
    np.testing.assert_allclose(depth[behind], depth0[behind], rtol=1e-12)
    np.testing.assert_allclose(width[behind], width0[behind], rtol=1e-12)
    np.testing.assert_allclose(mesh.verts[0], 0.0)                      # the snout tip stays at the origin
    np.testing.assert_allclose(mesh.verts[mesh.fork_vertex], [300.0, 0, 0])
    slope0 = _tip_power(plain)
    assert _tip_power(mesh) - slope0 == pytest.approx(taper, abs=0.01)
    assert 0.55 < slope0 < 0.75                                          # the species' own rounded head
    inside = (u > 0) & (u < HEAD)
    assert np.all(np.sign(depth0[inside] - depth[inside]) == np.sign(taper))   # pointed: thinner head


def _trailing_edge(mesh):
    """(x, z) of the caudal fin's upper trailing edge, lobe tip first, the notch last."""
    base = 1 + N_ALONG * N_AROUND
    outline = mesh.verts[base + 1:base + 1 + 15][:, [0, 2]]    # the caudal's upper half: 8 leading, 7 trailing
    return outline[7:]


def _notch_power(mesh):
    """The trailing edge's height goes as (1 - t)^power on its even steps t to the notch (fin wear
    bites x, not the height)."""
    z = _trailing_edge(mesh)[:-1, 1]
    return np.polyfit(np.log(np.arange(len(z), 0, -1) / (len(z) + 1)), np.log(z), 1)[0]


@pytest.mark.parametrize("name", sorted(SPECIES))
@pytest.mark.parametrize("power", [0.5, 0.7, 1.0, 1.3, 1.8, 2.5])
def test_notch_power_shapes_the_fork_and_keeps_the_notch_innermost(name, power):
    L = 300.0
    mesh = build_mesh(SPECIES[name], L, notch_power=power)
    edge = _trailing_edge(mesh)
    np.testing.assert_allclose(edge[-1], [L, 0.0], atol=1e-9)               # ends at the notch
    np.testing.assert_allclose(mesh.verts[mesh.fork_vertex], [L, 0, 0])
    back = edge[:-1]
    assert np.all(back[:, 0] > L) and np.all(back[:, 1] > 0)
    # behind the notch x - L ~ z^(1 / power): a V at 1, a slit over it, a U under it
    slope = np.polyfit(np.log(back[:, 1]), np.log(back[:, 0] - L), 1)[0]
    assert slope == pytest.approx(1 / power, rel=1e-6)
    assert _notch_power(mesh) == pytest.approx(power, rel=1e-6)
    body = _rings(mesh)
    np.testing.assert_allclose(body[1], _rings(build_mesh(SPECIES[name], L))[1])   # the body as it was


def test_snout_and_notch_are_drawn_per_fish_only_when_given_and_checked():
    rig = underwater_rig(**TINY)
    for seed in range(3):
        plain = underwater_scene(np.random.default_rng(seed), rig=rig)
        one = underwater_scene(np.random.default_rng(seed), rig=rig, snout_taper=[0.4, 0.4], notch_power=[1.0, 1.0])
        # one value draws nothing: the same fish, where they were, each with the pointed head and a V fork
        assert [f.length_cm for f in one.fish] == [f.length_cm for f in plain.fish]
        assert [f.snout_px.tolist() for f in one.fish] == [f.snout_px.tolist() for f in plain.fish]
        assert not np.array_equal(one.left, plain.left) or not plain.fish
    cond, _ = underwater_conditions(np.random.default_rng(5), rig, 12, {"snout_taper": [-0.3, 0.8],
                                                                        "notch_power": [0.7, 1.6]})
    fishes, _ = populate(np.random.default_rng(6), rig, cond)
    assert len(fishes) >= 6
    # each fish's snout power over its species' own (the individual's depth and width scales keep it)
    own = np.array([_tip_power(f.mesh) - _tip_power(build_mesh(f.species, f.length_mm)) for f in fishes])
    assert np.all((own > -0.31) & (own < 0.81)) and np.ptp(own) > 0.4      # each fish its own snout
    notch = np.array([_notch_power(f.mesh) for f in fishes])
    assert np.all((notch > 0.7 - 1e-9) & (notch < 1.6 + 1e-9)) and np.ptp(notch) > 0.3      # and its own fork
    for name, bad, why in (("snout_taper", [0.5, 0.2], "lo <= hi"), ("snout_taper", [-0.8, 0.0], "lo <= hi"),
                           ("snout_taper", [0.0, 2.0], "lo <= hi"), ("snout_taper", "x", r"\[lo, hi\]"),
                           ("notch_power", [0.1], r"\[lo, hi\]"), ("notch_power", [0.3, 1.0], "lo <= hi"),
                           ("notch_power", [1.0, 3.0], "lo <= hi"), ("notch_power", [1.2, 1.1], "lo <= hi")):
        with pytest.raises(ValueError, match=f"{name}.*{why}"):
            underwater_scene(np.random.default_rng(0), rig=rig, **{name: bad})
