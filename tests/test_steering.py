"""The steering policy on its own (lsmta.pantilt.steering): lead prediction that brakes,
head choice with coasting on the body, damped aim of several heads."""

import numpy as np
import pytest

from lsmta.pantilt import (
    HeadChooser,
    LeadPredictor,
    Pointer,
    Steering,
    SteeringParams,
    body_offsets,
    coast_head,
    lead_displacement,
)
from lsmta.synth.pantilt import pantilt_head
from lsmta.widearea import TargetEstimate

# a head LED and two shoulder LEDs, mm
HEAD = np.array([0.0, 0.0, 1700.0])
LEFT, RIGHT = np.array([-190.0, 0.0, 1300.0]), np.array([190.0, 0.0, 1300.0])


def estimate(time, targets):
    """A TargetEstimate of ``{id: (position, velocity)}``."""
    ids = np.array(sorted(targets), int)
    states = np.array([np.r_[targets[i][0], targets[i][1]] for i in ids]).reshape(-1, 6)
    return TargetEstimate(time=time, ids=ids, states=states,
                          covariances=np.zeros((len(ids), 6, 6)))


def heads():
    return [pantilt_head(rng=1, position=(-800.0, -3000.0, 1500.0)),
            pantilt_head(rng=2, position=(800.0, -3000.0, 1500.0))]


def test_the_lead_prediction_brakes_with_a_stopping_head_and_never_turns_back():
    # a head walking at 1200 mm/s along X brakes to a stop at 4000 mm/s² (0.3 s ramp)
    dt = 1 / 240
    t = np.arange(0, 1.5, dt)
    v = np.clip(1200.0 - 4000.0 * np.clip(t - 0.5, 0, None), 0, None)
    x = np.cumsum(v) * dt
    stop = x[-1]
    w = int(round(0.2 / dt))                    # velocity change over 0.2 s, as the loop does
    vel = np.c_[v, np.zeros((len(t), 2))][w:]
    acc = (vel - np.c_[v, np.zeros((len(t), 2))][:-w]) / 0.2
    lead = 0.33
    braked = x[w:] + lead_displacement(vel, acc, lead)[:, 0]
    constant = x[w:] + lead_displacement(vel, np.zeros_like(acc), lead)[:, 0]
    # constant velocity leads to where the head would have been had it not stopped; from
    # 0.1 s into the stop (when the velocity estimate has begun to fall) braking takes at
    # least half of that overshoot away, and it never predicts behind the head
    late = t[w:] >= 0.6
    assert constant.max() - stop > 150.0
    assert braked[late].max() - stop < 0.5 * (constant[late].max() - stop)
    assert np.all(braked >= x[w:] - 1e-9) and np.all(braked <= constant + 1e-9)
    # exact on a constant deceleration: 600 mm/s at -4000 mm/s² stops after 45 mm
    d = lead_displacement([[600.0, 0.0, 0.0]], [[-4000.0, 0.0, 0.0]], 0.3)
    assert np.allclose(d, [[45.0, 0.0, 0.0]])
    # speeding up keeps constant velocity unless asked
    up = lead_displacement([[600.0, 0.0, 0.0]], [[4000.0, 0.0, 0.0]], 0.3)
    assert np.allclose(up, [[180.0, 0.0, 0.0]])
    assert np.allclose(lead_displacement([[600.0, 0.0, 0.0]], [[4000.0, 0.0, 0.0]], 0.3,
                                         speed_up=True), [[360.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="acceleration"):
        lead_displacement([[1.0, 0.0, 0.0]], [[1.0, 0.0]], 0.3)
    with pytest.raises(ValueError, match="dt"):
        lead_displacement([[1.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]], -0.1)


def test_the_predictor_brakes_from_the_velocity_history_and_holds_the_height():
    # steady: constant velocity over the lead (from the estimate to the tick plus the lead),
    # the height the newest estimate's although the head rises
    predictor = LeadPredictor(params=SteeringParams(lead=0.3, accel_window=0.2))
    v = np.array([1200.0, 0.0, 100.0])
    for k in range(9):
        s = 0.05 * k
        e = estimate(s, {3: (HEAD + s * v, v)})
        p = predictor.predict(e, s + 0.02)                # the tick, 20 ms after the estimate
    assert p.time == pytest.approx(0.4 + 0.02 + 0.3)
    assert np.allclose(p.states[0, :3], e.states[0, :3] + [1200.0 * 0.32, 0.0, 0.0])
    assert p.states[0, 2] == e.states[0, 2]
    # braking: forwards at 600 mm/s, 800 mm/s slower than 0.2 s ago: stops after 45 mm
    predictor = LeadPredictor(params=SteeringParams(lead=0.3, accel_window=0.2))
    for k in range(5):
        s = 0.05 * k
        e = estimate(s, {3: (HEAD, [1400.0 - 4000.0 * s, 0.0, 0.0])})
        p = predictor.predict(e, s)
    assert np.allclose(p.states[0, :3] - HEAD, [45.0, 0.0, 0.0])
    # no window: constant velocity, overshooting the stop
    flat = LeadPredictor(params=SteeringParams(lead=0.3, accel_window=0.0))
    assert flat.predict(e, 0.2).states[0, 0] - HEAD[0] == pytest.approx(180.0)
    # lead 0: the newest estimate itself
    still = LeadPredictor(params=SteeringParams(lead=0.0))
    assert still.predict(e, 1.0) is e


def test_a_dead_head_coasts_on_the_body_with_its_last_offsets():
    ids = np.array([3, 5, 7])
    X = np.array([HEAD, LEFT, RIGHT])
    off = body_offsets(ids, X, 0, 600.0)
    assert set(off) == {5, 7} and np.allclose(off[5], [190.0, 0.0, 400.0])
    assert body_offsets(ids, X, 0, 100.0) == {}
    # the head LED is gone; one shoulder moved on by (100, 50, 0), the other is gone too
    moved = X[1:2] + [100.0, 50.0, 0.0]
    assert np.allclose(coast_head([5], moved, off, [0.0, 0.0, 0.0]), [100.0, 50.0, 1700.0])
    both = X[1:] + [100.0, 50.0, 0.0]
    assert np.allclose(coast_head([5, 7], both, off, [0.0, 0.0, 0.0]), [100.0, 50.0, 1700.0])
    # no body target alive: the head is held where it was last aimed
    assert np.allclose(coast_head([9], moved, off, [1.0, 2.0, 3.0]), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="head"):
        body_offsets(ids, X, 3, 600.0)
    with pytest.raises(ValueError, match="positions"):
        coast_head(ids, X[:, :2], off, [0.0, 0.0, 0.0])


def test_the_chooser_coasts_while_the_head_track_is_dead_then_takes_the_highest():
    chooser = HeadChooser(params=SteeringParams(coast=0.5, head_margin=200.0))
    zero = np.zeros(3)
    body = {5: (LEFT, zero), 7: (RIGHT, zero)}
    assert chooser.choose(estimate(0.0, {3: (HEAD, zero), **body}), 0.0)[::2] == (3, False)
    # the head LED's track dies; the shoulders walk on by 100 mm along x
    shift = np.array([100.0, 0.0, 0.0])
    walked = {5: (LEFT + shift, zero), 7: (RIGHT + shift, zero)}
    hid, X, coasted = chooser.choose(estimate(0.1, walked), 0.1)
    assert (hid, coasted) == (3, True) and np.allclose(X, HEAD + shift)
    # still coasting 0.5 s after the death, not after
    assert chooser.choose(estimate(0.6, walked), 0.6)[2]
    hid, X, coasted = chooser.choose(estimate(0.7, walked), 0.7)
    assert hid in (5, 7) and not coasted and X[2] == 1300.0
    # the head LED is born again (a new id): higher by more than the margin, it is the head
    hid, X, coasted = chooser.choose(estimate(0.8, {11: (HEAD + shift, zero), **walked}), 0.8)
    assert (hid, coasted) == (11, False) and np.allclose(X, HEAD + shift)
    # a target about as high as the coasted head ends the coasting at once
    chooser.choose(estimate(0.9, walked), 0.9)
    hid, _, coasted = chooser.choose(estimate(1.0, {12: (HEAD + [0, 0, -50.0], zero),
                                                    **walked}), 1.0)
    assert (hid, coasted) == (12, False)
    # nothing alive: the head held where it was, until the coasting ends; then no head
    hid, X, coasted = chooser.choose(estimate(1.1, {}), 1.1)
    assert (hid, coasted) == (12, True) and np.allclose(X, HEAD + [0, 0, -50.0])
    assert chooser.choose(estimate(1.7, {}), 1.7) == (-1, None, False)


def test_the_pointer_damps_the_aim_point_and_aims_every_head_at_it():
    models = heads()
    pointer = Pointer(models, [(0.0, 0.0), (0.0, 0.0)], damping=0.5, tol_px=0.2)
    first, second = np.array([0.0, 0.0, 1200.0]), np.array([300.0, 100.0, 1200.0])
    pointer.point(first)
    assert np.array_equal(pointer.smoothed, first)
    aims = pointer.point(second)
    assert np.allclose(pointer.smoothed, 0.5 * (first + second))
    for model, a, current in zip(models, aims, pointer.current):
        assert a.reachable[0] and np.array_equal(a.settings[0], current)
        xy = model.project(pointer.smoothed[None], *current)[0]
        assert np.hypot(*(xy - [model.camera.cx, model.camera.cy])) <= 0.2
    with pytest.raises(ValueError, match="start"):
        Pointer(models, [(0.0, 0.0)])
    with pytest.raises(ValueError, match="damping"):
        Pointer(models, [(0.0, 0.0)] * 2, damping=0.0)
    with pytest.raises(TypeError, match="heads"):
        Pointer([m.camera for m in models], [(0.0, 0.0)] * 2)


def test_steering_chains_prediction_head_choice_and_damped_aim():
    p = SteeringParams(lead=0.3, coast=0.5)
    steering = Steering(heads(), [(0.0, 0.0), (0.0, 0.0)], params=p)
    assert steering.step(estimate(0.0, {}), 0.0).settings is None        # nothing alive
    v = np.array([500.0, 0.0, 0.0])
    step = steering.step(estimate(0.1, {3: (HEAD, v), 5: (LEFT, v)}), 0.1)
    assert step.head_id == 3 and step.since == 0.1 and not step.coasted
    # predicted 0.3 s ahead at constant velocity (no history yet), moved to the face
    assert np.allclose(step.aim_point, HEAD + 0.3 * v + p.aim_offset)
    assert step.settings.shape == (2, 2) and not step.settings.flags.writeable
    # the head dies: coasted on the shoulder, the same head and since
    step = steering.step(estimate(0.2, {5: (LEFT + 0.1 * v, v)}), 0.2)
    assert step.head_id == 3 and step.coasted and step.since == 0.1
    with pytest.raises(ValueError, match="damping"):
        SteeringParams(damping=1.5)
    with pytest.raises(TypeError, match="lead_height"):
        SteeringParams(lead_height=1)
    with pytest.raises(ValueError, match="aim_offset"):
        SteeringParams(aim_offset=(0.0, 1.0))
    with pytest.raises(TypeError, match="params"):
        Steering(heads(), [(0.0, 0.0)] * 2, params={"lead": 0.3})
