"""A skeleton of single-degree-of-freedom joints (Plänkers et al. 1999, Section 3.2).

Every joint rotates about its own local z axis. A composite articulation (a shoulder) is
several single-DoF joints at one place that differ only in orientation. The transform from
joint ``j``'s frame to its parent's is

    ``A_j = Tr(s_l * offset_j) @ R_ini_j @ Rz(theta_j)``

the static part ``D_ini = Tr(s t) R`` (eq. 3: a translation by the bone, scaled by the
limb's scale ``s_l``, and a fixed re-orientation) followed by the motion part ``D_rot_z``.
The paper writes the world -> joint direction (``X_j = prod D^i X_w``, eq. 2); we keep the
inverse, joint -> world, ``W_j = base @ A_root @ ... @ A_j``, which is the same chain.

State
    static state: the scales ``s`` ``(L,)`` (1 = the template's bone lengths);
    motion state: the angles ``theta`` ``(T, J)`` in radians, one row per frame.

Jacobians are analytic: for a point ``X`` carried by joint ``k``,
``dX/dtheta_j = z_j x (X - o_j)`` for every joint ``j`` on the chain from the root to ``k``
(``z_j``, ``o_j``: world z axis and origin of joint ``j``) and ``dX/ds_l = sum_j
R_parent(j) offset_j`` over the chain's joints whose offset is scaled by limb ``l``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .._validate import as_array
from ._kernels import chain_transforms


@dataclass(frozen=True)
class Joint:
    """One single-DoF joint.

    Attributes
    ----------
    name : str
    parent : int
        Index of the parent joint (-1: the root, attached to the base frame).
    offset : (3,) tuple
        Translation of this joint in the parent joint's frame at scale 1 (mm).
    rotation : (3, 3) tuple of tuples
        Fixed orientation ``R_ini`` of this joint's frame in the parent's (before the
        joint's own rotation about its z axis).
    limb : int
        Index of the limb scale that multiplies ``offset`` (-1: not scaled).
    """

    name: str
    parent: int
    offset: tuple
    rotation: tuple
    limb: int = -1


@dataclass(frozen=True)
class Skeleton:
    """A tree of :class:`Joint` (parents before children) and its limb names.

    Attributes
    ----------
    joints : tuple of Joint
    limbs : tuple of str
        Names of the limb scales ``s``.
    """

    joints: tuple
    limbs: tuple

    def __post_init__(self):
        for j, joint in enumerate(self.joints):
            if not -1 <= joint.parent < j:
                raise ValueError(f"joints: joint {joint.name!r} must come after its parent")
            if not -1 <= joint.limb < len(self.limbs):
                raise ValueError(f"joints: joint {joint.name!r} names limb {joint.limb}, "
                                 f"there are {len(self.limbs)} limbs")
            R = np.asarray(joint.rotation, float)
            if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-9):
                raise ValueError(f"joints: rotation of {joint.name!r} is not a rotation")

    @property
    def n_joints(self) -> int:
        return len(self.joints)

    @property
    def names(self) -> list[str]:
        return [j.name for j in self.joints]

    @cached_property
    def arrays(self) -> tuple:
        """The joints as arrays for the compiled kernels: ``rotation (J, 3, 3)``,
        ``offset (J, 3)`` (mm), ``limb (J,)``, ``parent (J,)`` and ``chain (J, J)`` bool
        (``chain[k, j]``: joint ``j`` lies on the chain from the root to ``k``)."""
        J = self.n_joints
        chain = np.zeros((J, J), bool)
        for k in range(J):
            chain[k, self.chain(k)] = True
        out = (np.array([j.rotation for j in self.joints], float).reshape(J, 3, 3),
               np.array([j.offset for j in self.joints], float).reshape(J, 3),
               np.array([j.limb for j in self.joints], np.int64),
               np.array([j.parent for j in self.joints], np.int64), chain)
        for a in out:
            a.flags.writeable = False
        return out

    def chain(self, k: int) -> list[int]:
        """Joint indices from the root down to joint ``k`` (inclusive)."""
        out = []
        while k >= 0:
            out.append(k)
            k = self.joints[k].parent
        return out[::-1]

    def _check(self, angles, scales, base):
        th = as_array(angles, "angles")
        if th.ndim == 1:
            th = th[None]
        if th.ndim != 2 or th.shape[1] != self.n_joints:
            raise ValueError(f"angles: expected shape (T, {self.n_joints}) or "
                             f"({self.n_joints},), got {np.shape(angles)}")
        s = as_array(scales, "scales", shape=(len(self.limbs),))
        T = len(th)
        B = np.eye(4) if base is None else as_array(base, "base")
        if B.shape == (4, 4):
            B = np.broadcast_to(B, (T, 4, 4))
        if B.shape != (T, 4, 4):
            raise ValueError(f"base: expected shape (4, 4) or ({T}, 4, 4), got {B.shape}")
        return th, s, B

    def transforms(self, angles, scales, *, base=None) -> np.ndarray:
        """Joint frame -> world transforms ``(T, J, 4, 4)``.

        Parameters
        ----------
        angles : (T, J) or (J,) array
            Joint angles, radians.
        scales : (L,) array
            Limb scales (dimensionless).
        base : (4, 4) or (T, 4, 4) array, optional
            World pose of the root's parent frame (mm); identity by default.
        """
        th, s, B = self._check(angles, scales, base)
        rot, offset, limb, parent, _ = self.arrays
        return chain_transforms(th, s, rot, offset, limb, parent, np.ascontiguousarray(B))

    def forward(self, angles, scales, joint, local, *, base=None) -> np.ndarray:
        """World coordinates ``(T, N, 3)`` of points fixed in joint frames.

        Parameters
        ----------
        angles, scales, base
            As in :meth:`transforms`.
        joint : (N,) int array
            The joint that carries each point.
        local : (N, 3) array
            The points in their joint's frame (mm).
        """
        joint, local = self._points(joint, local)
        W = self.transforms(angles, scales, base=base)[:, joint]      # (T, N, 4, 4)
        return np.einsum("tnij,nj->tni", W[..., :3, :3], local) + W[..., :3, 3]

    def _points(self, joint, local):
        local = as_array(local, "local", shape=(None, 3))
        joint = np.asarray(joint)
        if joint.ndim == 0:
            joint = np.full(len(local), int(joint))
        if joint.shape != (len(local),) or not np.issubdtype(joint.dtype, np.integer):
            raise ValueError(f"joint: expected ({len(local)},) integer joint indices")
        if joint.size and (joint.min() < 0 or joint.max() >= self.n_joints):
            raise ValueError(f"joint: indices must lie in [0, {self.n_joints - 1}]")
        return joint, local

    def jacobian(self, angles, scales, joint, local, *, base=None):
        """Analytic derivatives of :meth:`forward`.

        Returns
        -------
        d_angles : (T, N, 3, J) array
            mm per radian.
        d_scales : (T, N, 3, L) array
            mm per unit scale.
        """
        joint, local = self._points(joint, local)
        W = self.transforms(angles, scales, base=base)
        th, s, B = self._check(angles, scales, base)
        T, N, J, L = len(W), len(local), self.n_joints, len(self.limbs)
        Wp = W[:, joint]
        X = np.einsum("tnij,nj->tni", Wp[..., :3, :3], local) + Wp[..., :3, 3]
        d_th = np.zeros((T, N, 3, J))
        d_s = np.zeros((T, N, 3, L))
        for k in np.unique(joint):
            sel = np.flatnonzero(joint == k)
            for j in self.chain(int(k)):
                z, o = W[:, j, :3, 2], W[:, j, :3, 3]                 # (T, 3)
                d_th[..., j][:, sel] = np.cross(z[:, None], X[:, sel] - o[:, None])
                limb = self.joints[j].limb
                if limb >= 0:
                    parent = self.joints[j].parent
                    Rp = B[:, :3, :3] if parent < 0 else W[:, parent, :3, :3]
                    d_s[..., limb][:, sel] += (Rp @ np.asarray(self.joints[j].offset,
                                                            float))[:, None]
        return d_th, d_s


def rot_x(a: float) -> np.ndarray:
    """Rotation by ``a`` radians about x, ``(3, 3)``."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """Rotation by ``a`` radians about y, ``(3, 3)``."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def rot_z(a: float) -> np.ndarray:
    """Rotation by ``a`` radians about z, ``(3, 3)``."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def as_tuple(R) -> tuple:
    """A ``(3, 3)`` array as a tuple of tuples (for :class:`Joint`)."""
    return tuple(tuple(float(v) for v in row) for row in np.asarray(R))
