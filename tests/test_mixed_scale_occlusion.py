"""Self-occlusion in the mixed-scale walk (issue 39): the pan-tilt heads' face markers hidden
by the head itself (ray casting, ``MixedScaleScene.occlusion``), against the normals rule."""

from dataclasses import replace

import numpy as np
import pytest

from lsmta.evaluation import mixed_scale as ms
from lsmta.pantilt.aiming import aim
from lsmta.synth.mixed_scale import OCCLUSION_RULES, SimulatedHead, mixed_scale_scene

T0 = 0.1     # s: the person stands at the walk's start, facing -Y (no head turn)


def _heads(scene_kw, side_deg=40.0, distance=2600.0):
    """Head positions: one in front of the face at T0, one on each side ``side_deg`` off
    the face's forward direction (-Y)."""
    face = mixed_scale_scene(**scene_kw).t[0]
    a = np.radians(side_deg)
    return [face + distance * np.array([0.0, -1.0, 0.0]),
            face + distance * np.array([np.sin(a), -np.cos(a), 0.0]),
            face + distance * np.array([-np.sin(a), -np.cos(a), 0.0])]


def _scene(occlusion):
    kw = dict(rng=1, travel=500.0, stand=0.5, n_ceiling=2, turn_deg=(0.0, 0.0))
    return replace(mixed_scale_scene(**kw, heads=_heads(kw)), occlusion=occlusion)


def _drawn(scene):
    """Per head: the markers drawn at T0 (aimed at the face), their normals' cosines to the
    head's centre, and the device."""
    world, normals, _ = scene.face_at(T0)
    out = []
    for h in scene.heads:
        dev = SimulatedHead(h, scene, rng=0)
        s = aim(h, world[0].mean(axis=0)[None]).settings[0]
        C = h.camera_at(*s).C
        ray = C - world[0]
        cos = (ray / np.linalg.norm(ray, axis=1, keepdims=True) * normals[0]).sum(axis=1)
        out.append((np.isfinite(dev.true_xy(T0, s)).all(axis=1), cos, dev, C))
    return out


@pytest.fixture(scope="module")
def rules():
    return {rule: _drawn(_scene(rule)) for rule in OCCLUSION_RULES}


def test_the_same_walk_under_every_rule():
    a, b = _scene("normals"), _scene("surface")
    np.testing.assert_array_equal(a.face_at(T0)[0], b.face_at(T0)[0])
    assert a.occlusion == "normals" and b.occlusion == "surface"
    assert mixed_scale_scene(rng=1, travel=500.0, stand=0.2, n_ceiling=2).occlusion == "normals"


def test_the_nose_hides_from_a_side_head_what_faces_it_and_a_frontal_head_sees(rules):
    front, left, right = rules["surface"]
    model = _scene("surface").face
    # from the front the whole face is drawn, as by the normals rule
    assert front[0].all() and rules["normals"][0][0].all()
    # from each side (40 degrees off), a marker under an eye that faces the head (cos > 0.1)
    # is hidden by the face, the nose between them: the far one from each side
    behind = [np.flatnonzero(~d & (cos > 0.1)) for d, cos, _, _ in (left, right)]
    names = [{model.labels[i] for i in b} for b in behind]
    assert names[0] and names[1] and all(n <= {f"under_eye_{i}" for i in range(4)} for n in names)
    x = model.neutral[:, 0]
    # (head x is world X: the head at +X loses a marker at x < 0, beyond the nose)
    assert (x[behind[0]] < -10).all() and (x[behind[1]] > 10).all()
    # the frontal head draws them
    assert front[0][np.concatenate(behind)].all()
    # the side heads lose more of the face than the nose hides
    assert (~left[0]).sum() > len(behind[0]) and (~right[0]).sum() > len(behind[1])


def test_the_rules_hide_what_they_say(rules):
    for k in range(3):
        normals, surface, both = (rules[r][k][0] for r in ("normals", "surface", "both"))
        cos = rules["normals"][k][1]
        np.testing.assert_array_equal(normals, cos > 0.3)     # lsmta.synth.face.visible
        np.testing.assert_array_equal(both, normals & surface)
        # a grazing marker the ray cast clears is drawn with "surface", not with "normals"
        assert k == 0 or (surface & ~normals).any()
        # a marker facing away is hidden by the ray cast too (it lies behind the face)
        assert not (surface & (cos < -0.2)).any()


def test_a_head_far_from_the_cast_centre_is_cast_again(rules):
    _, side, _ = rules["surface"]
    dev, C = side[2], side[3]
    scene = dev.scene
    near = dev.clear_of_head(T0, C)
    np.testing.assert_array_equal(near, scene.unhidden([T0], C[None])[0, 0])
    front_centre = scene.heads[0].camera.C
    np.testing.assert_array_equal(dev.clear_of_head(T0, front_centre),
                                  scene.unhidden([T0], front_centre[None])[0, 0])
    assert dev.clear_of_head(T0, front_centre).sum() > near.sum()


def test_hidden_shares_name_each_rule():
    scene = _scene("surface")
    # a stand-in capture: the grabbed frames' times and the heads' settings there
    devs = [SimulatedHead(h, scene, rng=0) for h in scene.heads]
    world, _, _ = scene.face_at(T0)
    for d in devs:
        d.command(0.0, aim(d.head, world[0].mean(axis=0)[None]).settings[0])
        d.grab(T0)

    class Capture:
        times = np.array([T0])

    shares = ms.hidden_shares(Capture, scene, devs)
    assert 0 < shares["hidden_ray_cast"] < shares["hidden_normals"] < 0.5
    assert 0 <= shares["hidden_ray_cast_only"] <= shares["hidden_ray_cast"]
    plain = ms.hidden_shares(Capture, _scene("normals"), devs)
    assert np.isnan(plain["hidden_ray_cast"])


def test_bad_occlusion():
    with pytest.raises(ValueError, match="occlusion"):
        replace(mixed_scale_scene(rng=1, travel=500.0, stand=0.2, n_ceiling=2), occlusion="rays")
    scene = _scene("surface")
    dev = SimulatedHead(scene.heads[0], scene, rng=0)
    with pytest.raises(ValueError, match="drawn"):
        from lsmta.synth.mixed_scale import render_pantilt_video
        world, normals, anchor = scene.face_at([T0])
        render_pantilt_video(dev.head, [[0.0, 0.0]], world, normals, anchor,
                             drawn=np.ones((1, 3), bool))


def test_the_fill_drops_markers_a_head_of_their_pair_sees_edge_on():
    # the system's rule (MixedScaleParams.min_view_cos): the fitted face's normals, from each
    # marker's neighbours, against the line of sight; judged by the generator's normals
    from lsmta.face import learn
    from lsmta.synth.face import expression_weights, face_model
    from lsmta.systems import fill_face

    fm = face_model()
    shapes = fm.shapes(expression_weights(200, rng=3))
    model = learn(shapes[:150], method="pca")
    pts = shapes[150:160]                                  # head frame: the face looks along +z
    a = np.radians(75.0)
    centres = np.array([[0.0, 0.0, 3000.0], [3000.0 * np.sin(a), 0.0, 3000.0 * np.cos(a)]])
    C = np.broadcast_to(centres[:, None], (2, len(pts), 3))
    pairs = np.zeros(pts.shape[:2] + (2,), int)
    pairs[..., 1] = 1
    kept, _ = fill_face(pts, model, views=(C, pairs))       # no gate: every marker kept
    assert np.isfinite(kept).all()
    kept, fit = fill_face(pts, model, views=(C, pairs), min_view_cos=0.3)
    dropped = ~np.isfinite(kept).all(axis=2)
    ray = centres[1] - fm.neutral
    true_cos = (fm.normals * ray).sum(axis=1) / np.linalg.norm(ray, axis=1)
    assert dropped[:, true_cos < 0.0].all()                # behind the face from head 1
    assert not dropped[:, true_cos > 0.6].any()            # facing head 1
    assert 0.1 < dropped.mean() < 0.7 and fit.fitted.all()
    with pytest.raises(ValueError, match="views"):
        fill_face(pts, model, min_view_cos=0.3)


def test_the_committed_occlusion_result_has_what_notebook_15_reads():
    run = ms.read_motor_fit_result(path=ms.OCCLUSION_RESULT)
    assert run is not None, f"no committed {ms.OCCLUSION_RESULT}"
    assert "--occlusion surface" in run["command"] and "--out" not in run["command"]
    assert run["occlusion"] == "surface" and run["min_view_cos"] > -1 and run["motor_fit"]
    assert {18, 20} <= set(run["seeds"].tolist()) and len(run["seeds"]) >= 10
    for key in ("face_median_mm", "face_measured_mm", "face_filled_mm", "face_fitted",
                "labels_correct", "labels_coverage"):
        assert run[key].shape == run["seeds"].shape and np.isfinite(run[key]).all()
    assert ((run["labels_coverage"] > 0) & (run["labels_coverage"] <= 1)).all()
    # the same walks without the gate: the same rule, no gate, the same seeds
    free = ms.read_motor_fit_result(path=ms.OCCLUSION_NO_GATE_RESULT)
    assert free is not None and free["occlusion"] == "surface" and free["min_view_cos"] == -1
    assert "--min-view-cos" not in free["command"] and np.array_equal(free["seeds"], run["seeds"])
    # the normals rule's committed run records neither: it read as the defaults
    plain = ms.read_motor_fit_result()
    assert plain["occlusion"] == "normals" and plain["min_view_cos"] == -1


def test_the_committed_view_gate_design_has_what_notebook_15_reads():
    design = ms.read_view_gate_design()
    assert design is not None, f"no committed {ms.VIEW_GATE_DESIGN_RESULT}"
    assert design["occlusion"] == "surface" and set(design["seeds"].tolist()) == {18, 20}
    assert design["chosen"] in design["min_view_cos"] and -1 in design["min_view_cos"]
    n = (len(design["seeds"]), len(design["min_view_cos"]))
    for key in ("face_median_mm", "face_measured_mm", "face_filled_mm", "measured"):
        assert design[key].shape == n and np.isfinite(design[key]).all()
    assert "min_view_cos" in design["script"] and len(design["commands"]) >= 2
    assert ms.read_view_gate_design(path=ms.VIEW_GATE_DESIGN_RESULT.with_name("none.json")) is None


def test_markers_tracked_onto_one_dot_are_both_dropped():
    # MixedScaleParams.merge_px: two labels on one dot (seed 22's head 1: 12 markers)
    from lsmta.systems import MixedScaleParams
    from lsmta.systems.mixed_scale import coinciding_markers

    xy = np.array([[[10.0, 10.0], [10.3, 10.0], [30.0, 10.0], [np.nan, np.nan]],
                   [[10.0, 10.0], [15.0, 10.0], [30.0, 10.0], [30.0, 10.0]]])
    before = xy.copy()
    np.testing.assert_array_equal(coinciding_markers(xy, tol_px=1.0),
                                  [[True, True, False, False], [False, False, True, True]])
    assert not coinciding_markers(xy, tol_px=0.1)[0].any()
    np.testing.assert_array_equal(xy, before)
    with pytest.raises(ValueError, match="tol_px"):
        coinciding_markers(xy, tol_px=0.0)
    with pytest.raises(ValueError, match="merge_px"):
        MixedScaleParams(merge_px=-1.0)
