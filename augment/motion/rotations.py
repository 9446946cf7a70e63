"""Rotation algebra for motion features: quaternions (w, x, y, z), rotation matrices and 6D.

Everything is batched torch over any leading dims (broadcasting where it makes sense), so the
same code serves feature extraction (float64 on CPU) and differentiable recovery inside models.
Conventions follow HumanML3D's ``common/quaternion.py``: ``qrot(q, v)`` rotates ``v`` actively,
``qmul(q, r)`` applies ``r`` first, and the continuous 6D form is the matrix's first two columns.
The ``*_np`` wrappers compute in float64 and return numpy.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

_AXES = {"x": 0, "y": 1, "z": 2}


def _check_last(t: Tensor, size: int, name: str) -> None:
    if t.shape[-1] != size:
        raise ValueError(f"{name} must have last dim {size}, got shape {tuple(t.shape)}")


def qnormalize(q: Tensor, eps: float = 1e-12) -> Tensor:
    """Unit quaternions; ``eps`` keeps an all-zero input finite instead of NaN."""
    _check_last(q, 4, "q")
    return q / q.norm(dim=-1, keepdim=True).clamp_min(eps)


def qinv(q: Tensor) -> Tensor:
    """Conjugate, i.e. the inverse of a unit quaternion."""
    _check_last(q, 4, "q")
    return torch.cat([q[..., :1], -q[..., 1:]], dim=-1)


def qmul(q: Tensor, r: Tensor) -> Tensor:
    """Hamilton product ``q * r`` (rotation ``r`` then ``q``), broadcasting leading dims."""
    _check_last(q, 4, "q")
    _check_last(r, 4, "r")
    w1, x1, y1, z1 = q.unbind(-1)
    w2, x2, y2, z2 = r.unbind(-1)
    return torch.stack(
        (
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ),
        dim=-1,
    )


def qrot(q: Tensor, v: Tensor) -> Tensor:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4), broadcasting leading dims."""
    _check_last(q, 4, "q")
    _check_last(v, 3, "v")
    qvec = q[..., 1:]
    qvec, v = torch.broadcast_tensors(qvec, v)
    uv = torch.linalg.cross(qvec, v, dim=-1)
    uuv = torch.linalg.cross(qvec, uv, dim=-1)
    return v + 2 * (q[..., :1] * uv + uuv)


def qbetween(v0: Tensor, v1: Tensor) -> Tensor:
    """Shortest-arc unit quaternion taking direction ``v0`` to ``v1``.

    Same formula as the reference (so features match the dataset); for exactly opposite vectors,
    where that formula is 0/0, it returns a half turn about an axis perpendicular to ``v0``.
    """
    _check_last(v0, 3, "v0")
    _check_last(v1, 3, "v1")
    v0, v1 = torch.broadcast_tensors(v0, v1)
    axis = torch.linalg.cross(v0, v1, dim=-1)
    lengths = torch.sqrt((v0**2).sum(-1, keepdim=True) * (v1**2).sum(-1, keepdim=True))
    w = lengths + (v0 * v1).sum(-1, keepdim=True)
    q = torch.cat([w, axis], dim=-1)
    degenerate = q.norm(dim=-1, keepdim=True) <= 1e-9 * lengths.clamp_min(1e-30)
    if bool(degenerate.any()):
        half_turn = torch.cat([torch.zeros_like(w), _perpendicular(v0)], dim=-1)
        q = torch.where(degenerate, half_turn, q)
    return qnormalize(q)


def _perpendicular(v: Tensor) -> Tensor:
    """Some unit vector perpendicular to each ``v`` (cross with the least aligned basis axis)."""
    basis = torch.eye(3, dtype=v.dtype, device=v.device)[v.abs().argmin(dim=-1)]
    return torch.nn.functional.normalize(torch.linalg.cross(v, basis, dim=-1), dim=-1)


def qfix(q: Tensor, time_dim: int = -3) -> Tensor:
    """Flip signs along ``time_dim`` so consecutive quaternions have a non-negative dot product."""
    _check_last(q, 4, "q")
    dim = time_dim % q.dim()
    if dim == q.dim() - 1:
        raise ValueError("time_dim cannot be the quaternion dim")
    n = q.shape[dim]
    if n < 2:
        return q.clone()
    dots = (q.narrow(dim, 1, n - 1) * q.narrow(dim, 0, n - 1)).sum(-1, keepdim=True)
    flips = torch.cumsum((dots < 0).to(torch.int64), dim=dim) % 2
    sign = 1 - 2 * flips.to(q.dtype)
    sign = torch.cat([torch.ones_like(sign.narrow(dim, 0, 1)), sign], dim=dim)
    return q * sign


def quat_to_matrix(q: Tensor) -> Tensor:
    """(..., 4) -> (..., 3, 3); does not require unit norm (divides by |q|^2 as the reference)."""
    _check_last(q, 4, "q")
    w, x, y, z = q.unbind(-1)
    s = 2.0 / (q * q).sum(-1)
    m = torch.stack(
        (
            1 - s * (y * y + z * z),
            s * (x * y - z * w),
            s * (x * z + y * w),
            s * (x * y + z * w),
            1 - s * (x * x + z * z),
            s * (y * z - x * w),
            s * (x * z - y * w),
            s * (y * z + x * w),
            1 - s * (x * x + y * y),
        ),
        dim=-1,
    )
    return m.reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(m: Tensor) -> Tensor:
    """(..., 3, 3) rotation matrices -> unit quaternions with w >= 0.

    Builds the quaternion from whichever of w, x, y, z is largest, so it stays accurate near
    half turns where the trace-only formula loses precision.
    """
    if m.shape[-2:] != (3, 3):
        raise ValueError(f"m must end in (3, 3), got shape {tuple(m.shape)}")
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    four_sq = torch.stack(
        (1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22), dim=-1
    )  # 4w^2, 4x^2, 4y^2, 4z^2
    candidates = torch.stack(
        (
            torch.stack((four_sq[..., 0], m21 - m12, m02 - m20, m10 - m01), dim=-1),
            torch.stack((m21 - m12, four_sq[..., 1], m10 + m01, m02 + m20), dim=-1),
            torch.stack((m02 - m20, m10 + m01, four_sq[..., 2], m21 + m12), dim=-1),
            torch.stack((m10 - m01, m02 + m20, m21 + m12, four_sq[..., 3]), dim=-1),
        ),
        dim=-2,
    )  # (..., 4 candidates, 4)
    best = four_sq.argmax(dim=-1, keepdim=True)
    chosen = torch.gather(candidates, -2, best[..., None].expand(best.shape[:-1] + (1, 4))).squeeze(-2)
    q = qnormalize(chosen)
    return torch.where(q[..., :1] < 0, -q, q)


def matrix_to_cont6d(m: Tensor) -> Tensor:
    """First two columns of the matrix, concatenated: (..., 3, 3) -> (..., 6)."""
    return torch.cat([m[..., :, 0], m[..., :, 1]], dim=-1)


def quat_to_cont6d(q: Tensor) -> Tensor:
    """(..., 4) -> (..., 6), as the reference's ``quaternion_to_cont6d``."""
    return matrix_to_cont6d(quat_to_matrix(q))


def cont6d_to_matrix(d6: Tensor) -> Tensor:
    """Gram-Schmidt the two columns back into a rotation matrix (..., 6) -> (..., 3, 3)."""
    _check_last(d6, 6, "d6")
    x = torch.nn.functional.normalize(d6[..., 0:3], dim=-1)
    z = torch.nn.functional.normalize(torch.linalg.cross(x, d6[..., 3:6], dim=-1), dim=-1)
    y = torch.linalg.cross(z, x, dim=-1)
    return torch.stack([x, y, z], dim=-1)


def cont6d_to_quat(d6: Tensor) -> Tensor:
    return matrix_to_quat(cont6d_to_matrix(d6))


def axis_angle_to_quat(aa: Tensor) -> Tensor:
    """Axis-angle (..., 3), angle = norm in radians -> unit quaternion; stable near zero."""
    _check_last(aa, 3, "aa")
    angle = aa.norm(dim=-1, keepdim=True)
    half = 0.5 * angle
    # sin(a/2)/a, with its Taylor series where a is tiny
    small = angle < 1e-6
    safe = torch.where(small, torch.ones_like(angle), angle)
    scale = torch.where(small, 0.5 - angle**2 / 48.0, torch.sin(half) / safe)
    return torch.cat([torch.cos(half), aa * scale], dim=-1)


def quat_to_axis_angle(q: Tensor) -> Tensor:
    """Unit quaternion -> axis-angle with angle in [0, pi]."""
    q = qnormalize(q)
    q = torch.where(q[..., :1] < 0, -q, q)
    sin_half = q[..., 1:].norm(dim=-1, keepdim=True)
    angle = 2 * torch.atan2(sin_half, q[..., :1])
    small = sin_half < 1e-8
    scale = torch.where(
        small, torch.full_like(angle, 2.0), angle / torch.where(small, torch.ones_like(sin_half), sin_half)
    )
    return q[..., 1:] * scale


def _parse_order(order: str) -> list[int]:
    axes = order.lower()
    if len(axes) != 3 or any(a not in _AXES for a in axes):
        raise ValueError(f"euler order must be 3 letters from 'xyz', got {order!r}")
    return [_AXES[a] for a in axes]


def _axis_quat(angle: Tensor, axis: int) -> Tensor:
    half = 0.5 * angle
    parts = [torch.cos(half)] + [torch.sin(half) if i == axis else torch.zeros_like(half) for i in range(3)]
    return torch.stack(parts, dim=-1)


def euler_to_quat(angles: Tensor, order: str, degrees: bool = False) -> Tensor:
    """Intrinsic Euler angles (BVH convention) -> quaternions.

    ``angles[..., i]`` turns about axis ``order[i]``; the result is ``q_0 * q_1 * q_2``, i.e. the
    rotation matrix ``R_0 @ R_1 @ R_2`` a BVH file with channels in that order describes.
    """
    _check_last(angles, 3, "angles")
    axes = _parse_order(order)
    if degrees:
        angles = angles * (math.pi / 180.0)
    q = _axis_quat(angles[..., 0], axes[0])
    for i in (1, 2):
        q = qmul(q, _axis_quat(angles[..., i], axes[i]))
    return q


def matrix_to_euler(m: Tensor, order: str, degrees: bool = False) -> Tensor:
    """Inverse of ``euler_to_quat`` for Tait-Bryan orders (three distinct axes): (..., 3, 3) -> (..., 3).

    The middle angle lies in [-pi/2, pi/2]; at gimbal lock the split between the outer two is arbitrary.
    """
    i, j, k = _parse_order(order)
    if len({i, j, k}) != 3:
        raise ValueError(f"matrix_to_euler needs three distinct axes, got {order!r}")
    s = 1.0 if (j - i) % 3 == 1 else -1.0  # +1 for cyclic orders (xyz, yzx, zxy)
    middle = torch.asin((s * m[..., i, k]).clamp(-1.0, 1.0))
    first = torch.atan2(-s * m[..., j, k], m[..., k, k])
    last = torch.atan2(-s * m[..., i, j], m[..., i, i])
    out = torch.stack([first, middle, last], dim=-1)
    return out * (180.0 / math.pi) if degrees else out


def quat_to_euler(q: Tensor, order: str, degrees: bool = False) -> Tensor:
    return matrix_to_euler(quat_to_matrix(q), order, degrees)


# ---- numpy wrappers (float64) ---------------------------------------------------------------


def _np_call(fn: Callable[..., Tensor], *arrays: np.ndarray, **kwargs: object) -> np.ndarray:
    tensors = [torch.as_tensor(np.asarray(a, dtype=np.float64)) for a in arrays]
    return fn(*tensors, **kwargs).numpy()


def qmul_np(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    return _np_call(qmul, q, r)


def qrot_np(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    return _np_call(qrot, q, v)


def qinv_np(q: np.ndarray) -> np.ndarray:
    return _np_call(qinv, q)


def qfix_np(q: np.ndarray, time_dim: int = -3) -> np.ndarray:
    return _np_call(qfix, q, time_dim=time_dim)


def quat_to_cont6d_np(q: np.ndarray) -> np.ndarray:
    return _np_call(quat_to_cont6d, q)


def cont6d_to_matrix_np(d6: np.ndarray) -> np.ndarray:
    return _np_call(cont6d_to_matrix, d6)


def euler_to_quat_np(angles: np.ndarray, order: str, degrees: bool = False) -> np.ndarray:
    return _np_call(euler_to_quat, angles, order=order, degrees=degrees)
