"""The compiled kernels of the body model, the skin scorer, the renderer and the camera's
undistortion against the plain numpy code they replaced (issue 35 item 4), on small inputs,
to rounding."""

import dataclasses

import numpy as np
import pytest

from lsmta.body import full_body_model, surface_distance, surface_distance_terms, template_size
from lsmta.body._kernels import ball_field
from lsmta.body.metaballs import field
from lsmta.body.silhouette import point_derivatives, point_terms, silhouette_terms
from lsmta.synth.body import make_body, walk
from lsmta.synth.render import cast_body
from lsmta.synth.rigs import triplet_rig
from lsmta.synth.surface import distance_to_ellipsoid

GOLD = (np.sqrt(5.0) - 1.0) / 2.0


@pytest.fixture(scope="module")
def body():
    m = full_body_model(stature=1750.0)
    rng = np.random.default_rng(3)
    J, L = m.skeleton.n_joints, len(m.skeleton.limbs)
    angles = rng.normal(0.0, 0.3, (2, J))
    scales = 1.0 + rng.normal(0.0, 0.05, L)
    radii = m.simplified_radii(template_size(m), scales)
    base = np.tile(np.eye(4), (2, 1, 1))
    base[:, :3, 3] = [[100.0, 200.0, 950.0], [150.0, 180.0, 960.0]]
    pts = rng.normal(0.0, 400.0, (300, 3)) + base[0, :3, 3]
    return m, angles, scales, radii, base, pts


def _transforms(sk, th, s, B):
    """Skeleton.transforms as it was: a numpy loop over the joints."""
    out = np.empty((len(th), sk.n_joints, 4, 4))
    for j, joint in enumerate(sk.joints):
        A = np.zeros((len(th), 4, 4))
        c, sn = np.cos(th[:, j]), np.sin(th[:, j])
        Rz = np.zeros((len(th), 3, 3))
        Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -sn, sn, c, 1.0
        A[:, :3, :3] = np.asarray(joint.rotation) @ Rz
        A[:, :3, 3] = (s[joint.limb] if joint.limb >= 0 else 1.0) * np.asarray(joint.offset)
        A[:, 3, 3] = 1.0
        out[:, j] = (B if joint.parent < 0 else out[:, joint.parent]) @ A
    return out


def _distance(m, pts, seg, frame, angles, scales, radii, base):
    """MetaballModel.distance as it was: numpy, segment by segment."""
    W = _transforms(m.skeleton, angles, scales, base)
    C = m.centres(scales)
    out = np.empty(len(pts))
    for k, sg in enumerate(m.segments):
        sel = seg == k
        R = np.eye(4)
        R[:3, :3] = sg.rotation
        M = (W[:, sg.joint] @ R)[frame[sel]]
        local = np.einsum("nji,nj->ni", M[:, :3, :3], pts[sel] - M[:, :3, 3])
        out[sel] = surface_distance(local[:, None, :] - C[k][None], radii[k])
    return out


def test_transforms_match_the_numpy_chain(body):
    m, angles, scales, _, base, _ = body
    got = m.skeleton.transforms(angles, scales, base=base)
    np.testing.assert_allclose(got, _transforms(m.skeleton, angles, scales, base), rtol=0,
                               atol=1e-9)


def test_distances_match_numpy(body):
    m, angles, scales, radii, base, pts = body
    rng = np.random.default_rng(4)
    seg = rng.integers(0, m.n_segments, len(pts))
    frame = rng.integers(0, 2, len(pts))
    want = _distance(m, pts, seg, frame, angles, scales, radii, base)
    got = m.distance(pts, seg, angles, scales, radii, base=base, frame=frame)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    every = m.all_distances(pts, angles[:1], scales, radii, base=base[:1])
    for k in (0, 7, m.n_segments - 1):
        np.testing.assert_allclose(every[:, k], _distance(
            m, pts, np.full(len(pts), k), np.zeros(len(pts), int), angles[:1], scales, radii,
            base[:1]), rtol=0, atol=1e-9)


def test_point_derivatives_match_the_skeleton_jacobian(body):
    m, angles, scales, radii, base, pts = body
    a, b = angles[:1], base[:1]
    seg = np.argmin(m.all_distances(pts, a, scales, radii, base=b), axis=1)
    W = m.skeleton.transforms(a, scales, base=b)[0]
    F, C = m.frames(a, scales, base=b)[0], m.centres(scales)
    want = np.zeros((len(pts), m.skeleton.n_joints))
    want_t = np.zeros((len(pts), 3))
    for s in np.unique(seg):                     # the numpy code it replaced
        sel = seg == s
        R, o = F[s, :3, :3], F[s, :3, 3]
        t = surface_distance_terms(((pts[sel] - o) @ R)[:, None, :] - C[s][None], radii[s])
        grad = (t.dr_dpsi[:, None] * t.grad) @ R.T
        j = m.segments[s].joint
        in_joint = (pts[sel] - W[j, :3, 3]) @ W[j, :3, :3]
        d_th, _ = m.skeleton.jacobian(a, scales, np.full(sel.sum(), j), in_joint, base=b)
        want[sel] = -np.einsum("nk,nkj->nj", grad, d_th[0])
        want_t[sel] = -grad
    d_th, d_t = point_derivatives(m, pts, seg, a, scales, radii, base=b)
    assert np.abs(want).max() > 1.0              # derivatives that can fail
    np.testing.assert_allclose(d_th, want, rtol=0, atol=1e-8)
    np.testing.assert_allclose(d_t, want_t, rtol=0, atol=1e-12)


def test_point_terms_check_what_the_kernel_would_read(body):
    """Bad indices, radii or points are refused before the compiled pass reads them."""
    m, angles, scales, radii, base, pts = body
    a, b = angles[:1], base[:1]
    seg = np.zeros(len(pts), int)
    bad = seg.copy()
    bad[0] = m.n_segments
    with pytest.raises(ValueError, match="segment"):
        point_terms(m, pts, bad, a, scales, radii, base=b)
    with pytest.raises(ValueError, match="radii"):
        point_terms(m, pts, seg, a, scales, -radii, base=b)
    with pytest.raises(ValueError, match="x"):
        point_terms(m, pts[:, :2], seg, a, scales, radii, base=b)
    nan = pts.copy()
    nan[0] = np.nan
    r, _, _ = point_terms(m, nan, seg, a, scales, radii, base=b)
    assert np.isnan(r[0]) and np.isfinite(r[1:]).all()


def test_silhouette_search_matches_the_vectorised_golden_section(body):
    m, angles, scales, radii, base, pts = body
    a, b = angles[:1], base[:1]
    origin = np.array([0.0, -4000.0, 1000.0])
    d = pts[:60] - origin
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(origin, d.shape).copy()
    near, far, n_steps, n_refine = 2800.0, 5200.0, 48, 40
    got = silhouette_terms(m, o, d, a, scales, radii, near=near, far=far, base=b,
                           n_steps=n_steps, n_refine=n_refine)
    # the numpy search it replaced: the grid's minimum over every segment, then golden
    # sections on the nearest segment, all lines at once
    depths = np.linspace(near, far, n_steps)
    grid = (o[:, None, :] + depths[None, :, None] * d[:, None, :]).reshape(-1, 3)
    D = m.all_distances(grid, a, scales, radii, base=b).reshape(len(d), n_steps, -1)
    seg = np.argmin(D.min(axis=1), axis=1)
    k = np.argmin(D[np.arange(len(d)), :, seg], axis=1)
    step = depths[1] - depths[0]
    lo, hi = depths[k] - step, depths[k] + step

    def f(x):
        return m.distance(o + x[:, None] * d, seg, a, scales, radii, base=b)

    p, q = hi - GOLD * (hi - lo), lo + GOLD * (hi - lo)
    fp, fq = f(p), f(q)
    for _ in range(n_refine):
        left = fp < fq
        lo, hi = np.where(left, lo, p), np.where(left, q, hi)
        p_new, q_new = hi - GOLD * (hi - lo), lo + GOLD * (hi - lo)
        f_new = f(np.where(left, p_new, q_new))
        fp, fq, p, q = (np.where(left, f_new, fq), np.where(left, fp, f_new),
                        np.where(left, p_new, q), np.where(left, p, q_new))
    closest = o + (0.5 * (lo + hi))[:, None] * d
    assert (got.r > 5).any() and (got.r < -5).any()
    np.testing.assert_array_equal(got.segment, seg)
    np.testing.assert_allclose(got.r, f(0.5 * (lo + hi)), rtol=0, atol=1e-8)
    np.testing.assert_allclose(got.closest, closest, rtol=0, atol=1e-3)   # a flat minimum


def test_ball_field_matches_numpy(body):
    m, angles, scales, radii, base, pts = body
    P = m.ball_poses(angles[:1], scales, base=base[:1])[0, 5]              # (3, 4, 4)
    pts = P[1, :3, 3] + np.random.default_rng(7).normal(0.0, 80.0, (400, 3))
    local = np.einsum("bji,nbj->nbi", P[:, :3, :3], pts[:, None, :] - P[None, :, :3, 3])
    want = field(local, radii[5])
    assert want.max() > 0.1
    np.testing.assert_allclose(ball_field(pts, np.ascontiguousarray(P), radii[5]), want,
                               rtol=1e-12, atol=1e-300)


def test_ellipsoid_distance_matches_numpy_bisection():
    rng = np.random.default_rng(5)
    y = np.abs(rng.normal(0.0, 100.0, (500, 3)))
    e = np.array([40.0, 60.0, 120.0])
    e2 = e * e
    lo = np.full(len(y), -e2.min() * (1 - 1e-12))
    hi = np.maximum(np.linalg.norm(y, axis=1) * e.max(), 1.0)
    for _ in range(80):
        t = 0.5 * (lo + hi)
        pos = np.sum((e * y / (t[:, None] + e2)) ** 2, axis=1) - 1.0 > 0
        lo, hi = np.where(pos, t, lo), np.where(pos, hi, t)
    t = 0.5 * (lo + hi)
    dist = np.linalg.norm(e2 * y / (t[:, None] + e2) - y, axis=1)
    want = np.where(np.sum((y / e) ** 2, axis=1) < 1.0, -dist, dist)
    assert (want < 0).any() and (want > 0).any()
    np.testing.assert_allclose(distance_to_ellipsoid(-y, e), want, rtol=0, atol=1e-9)


def test_cast_body_matches_numpy():
    rng = np.random.default_rng(6)
    b = make_body(rng=rng)
    poses = b.part_poses(walk(n_frames=3), frames=1)[0]
    origin = poses[0, :3, 3] + np.array([0.0, -4500.0, 0.0])
    target = poses[rng.integers(0, len(b.parts), 4000), :3, 3] + rng.normal(0.0, 150.0,
                                                                            (4000, 3))
    dirs = (target - origin) / np.linalg.norm(target - origin, axis=1, keepdims=True)
    t_best = np.full(len(dirs), np.inf)
    part = np.full(len(dirs), -1)
    local = np.full((len(dirs), 3), np.nan)
    for p, spec in enumerate(b.parts):           # the numpy code it replaced (no cone test)
        R, T = poses[p, :3, :3], poses[p, :3, 3]
        c, r = np.asarray(spec.centre, float), np.asarray(spec.radii, float)
        o_s = (R.T @ (origin - T) - c) / r
        d_s = (dirs @ R) / r
        a, bb, cc = np.sum(d_s * d_s, axis=1), d_s @ o_s, o_s @ o_s - 1.0
        disc = bb * bb - a * cc
        with np.errstate(invalid="ignore", divide="ignore"):
            q = -(bb + np.copysign(np.sqrt(disc), bb))
            t1, t2 = q / a, cc / q
        t = np.where(np.minimum(t1, t2) > 0, np.minimum(t1, t2), np.maximum(t1, t2))
        better = (disc >= 0) & (t > 0) & (t < t_best)
        t_best[better], part[better] = t[better], p
        local[better] = (o_s + t[better, None] * d_s[better]) * r + c
    hit = cast_body(b, poses, origin, dirs)
    assert 0.2 < np.isfinite(t_best).mean() < 0.9
    np.testing.assert_array_equal(hit.part, part)
    np.testing.assert_allclose(hit.t, t_best, rtol=1e-12)
    np.testing.assert_allclose(hit.local, local, rtol=0, atol=1e-8)
    on = part >= 0
    np.testing.assert_allclose(np.linalg.norm(hit.normal[on], axis=1), 1.0, rtol=1e-12)
    n = np.empty((on.sum(), 3))
    for k, (p, x) in enumerate(zip(part[on], local[on])):
        spec = b.parts[p]
        g = poses[p, :3, :3] @ ((x - np.asarray(spec.centre)) / np.asarray(spec.radii) ** 2)
        n[k] = g / np.linalg.norm(g)
    np.testing.assert_allclose(hit.normal[on], n, rtol=0, atol=1e-9)


def test_undistort_matches_the_numpy_newton_iterations():
    cam = dataclasses.replace(triplet_rig(rng=np.random.default_rng(8))[0], k1=-0.35, k2=0.12,
                              k3=-0.02, p1=0.002, p2=-0.001)
    xy_d = cam.pixel_to_normalized(cam.pixel_grid(supersample=1)[::9, ::9].reshape(-1, 2))
    xd, yd = xy_d[:, 0], xy_d[:, 1]
    x, y = xd.copy(), yd.copy()
    k1, k2, k3, p1, p2 = cam.k1, cam.k2, cam.k3, cam.p1, cam.p2
    for _ in range(30):                          # the numpy iterations it replaced
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        g = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        ex = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd
        ey = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd
        a = radial + 2 * g * x * x + 2 * p1 * y + 6 * p2 * x
        b = 2 * g * x * y + 2 * p1 * x + 2 * p2 * y
        d = radial + 2 * g * y * y + 6 * p1 * y + 2 * p2 * x
        det = a * d - b * b
        dx, dy = (d * ex - b * ey) / det, (a * ey - b * ex) / det
        x -= dx
        y -= dy
        if np.all(np.abs(dx) + np.abs(dy) < 1e-14):
            break
    got = cam.undistort(xy_d)
    assert np.abs(got - xy_d).max() > 1e-2                  # a strong lens
    np.testing.assert_allclose(got, np.stack([x, y], axis=-1), rtol=0, atol=1e-15)
