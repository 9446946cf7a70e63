"""Rotation algebra: identities between quaternions, matrices, 6D, Euler and axis-angle."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from motionaug.augment.motion import rotations as R

torch.set_num_threads(1)
ORDERS = ["xyz", "xzy", "yxz", "yzx", "zxy", "zyx"]


def random_quats(n: int, seed: int = 0) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return R.qnormalize(torch.randn(n, 4, generator=gen, dtype=torch.float64))


def axis_matrix(axis: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return {
        "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


def test_qrot_and_qmul_agree_with_matrices() -> None:
    q, r = random_quats(64, 1), random_quats(64, 2)
    v = torch.randn(64, 3, dtype=torch.float64)
    mq, mr = R.quat_to_matrix(q), R.quat_to_matrix(r)
    torch.testing.assert_close(R.quat_to_matrix(R.qmul(q, r)), mq @ mr)
    torch.testing.assert_close(R.qrot(q, v), (mq @ v[..., None])[..., 0])
    torch.testing.assert_close(R.qrot(R.qinv(q), R.qrot(q, v)), v)
    # rotation matrices are orthonormal with determinant +1
    torch.testing.assert_close(mq @ mq.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(64, 3, 3))
    torch.testing.assert_close(torch.linalg.det(mq), torch.ones(64, dtype=torch.float64))


def test_qrot_broadcasts_leading_dims() -> None:
    q = random_quats(5).reshape(5, 1, 4)
    v = torch.randn(5, 7, 3, dtype=torch.float64)
    out = R.qrot(q, v)
    assert out.shape == (5, 7, 3)
    torch.testing.assert_close(out[:, 3], R.qrot(q[:, 0], v[:, 3]))


def test_qrot_rejects_wrong_width() -> None:
    with pytest.raises(ValueError, match="last dim 4"):
        R.qrot(torch.zeros(3, 3), torch.zeros(3, 3))


def test_matrix_to_quat_round_trip_including_half_turns() -> None:
    q = random_quats(200, 3)
    half_turns = torch.tensor([[0.0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [0, 0.6, 0.8, 0]], dtype=torch.float64)
    q = torch.cat([q, half_turns, torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64)])
    back = R.matrix_to_quat(R.quat_to_matrix(q))
    same_sign = torch.where(q[..., :1] < 0, -q, q)
    # half turns have w == 0, so the sign is only defined up to +-; compare as rotations too
    torch.testing.assert_close(R.quat_to_matrix(back), R.quat_to_matrix(q))
    regular = q[:, 0].abs() > 1e-6
    torch.testing.assert_close(back[regular], same_sign[regular])
    assert (back[:, 0] >= 0).all()


def test_cont6d_round_trip_and_layout() -> None:
    q = random_quats(100, 4)
    d6 = R.quat_to_cont6d(q)
    m = R.quat_to_matrix(q)
    torch.testing.assert_close(d6[..., :3], m[..., :, 0])
    torch.testing.assert_close(d6[..., 3:], m[..., :, 1])
    torch.testing.assert_close(R.cont6d_to_matrix(d6), m)
    q_back = R.cont6d_to_quat(d6)
    torch.testing.assert_close(torch.abs((q_back * q).sum(-1)), torch.ones(100, dtype=torch.float64))
    # a non-orthonormal 6D vector still yields a proper rotation
    noisy = R.cont6d_to_matrix(d6 * 1.7 + 0.05)
    torch.testing.assert_close(torch.linalg.det(noisy), torch.ones(100, dtype=torch.float64))


def test_qbetween_takes_v0_to_v1_and_handles_opposites() -> None:
    gen = torch.Generator().manual_seed(5)
    v0 = torch.randn(50, 3, generator=gen, dtype=torch.float64)
    v1 = torch.randn(50, 3, generator=gen, dtype=torch.float64) * 3.0
    q = R.qbetween(v0, v1)
    torch.testing.assert_close(R.qrot(q, v0 / v0.norm(dim=-1, keepdim=True)), v1 / v1.norm(dim=-1, keepdim=True))
    opposite = torch.tensor([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    q_opp = R.qbetween(opposite, -opposite)
    assert torch.isfinite(q_opp).all()
    torch.testing.assert_close(R.qrot(q_opp, opposite), -opposite)


def test_qfix_makes_sequences_continuous_without_changing_rotations() -> None:
    gen = torch.Generator().manual_seed(6)
    base = R.qnormalize(torch.cumsum(0.05 * torch.randn(30, 2, 4, generator=gen, dtype=torch.float64), dim=0) + 1.0)
    signs = torch.where(torch.rand(30, 2, 1, generator=gen) < 0.5, -1.0, 1.0).to(torch.float64)
    flipped = base * signs
    fixed = R.qfix(flipped)
    assert ((fixed[1:] * fixed[:-1]).sum(-1) >= 0).all()
    torch.testing.assert_close(R.quat_to_matrix(fixed), R.quat_to_matrix(base))
    torch.testing.assert_close(fixed[0], flipped[0])
    # time along another axis
    torch.testing.assert_close(R.qfix(flipped.transpose(0, 1), time_dim=-2), fixed.transpose(0, 1))
    np.testing.assert_allclose(R.qfix_np(flipped.numpy()), fixed.numpy())


@pytest.mark.parametrize("order", ORDERS)
def test_euler_is_intrinsic_and_round_trips(order: str) -> None:
    angles = np.array([0.3, -0.7, 1.1])
    expected = axis_matrix(order[0], angles[0]) @ axis_matrix(order[1], angles[1]) @ axis_matrix(order[2], angles[2])
    q = R.euler_to_quat(torch.as_tensor(angles), order)
    np.testing.assert_allclose(R.quat_to_matrix(q).numpy(), expected, atol=1e-12)
    gen = torch.Generator().manual_seed(7)
    many = (torch.rand(100, 3, generator=gen, dtype=torch.float64) - 0.5) * torch.tensor(
        [6.0, 3.0, 6.0], dtype=torch.float64
    )
    back = R.quat_to_euler(R.euler_to_quat(many, order), order)
    torch.testing.assert_close(back, many)
    degrees = R.euler_to_quat(torch.rad2deg(many), order.upper(), degrees=True)
    torch.testing.assert_close(degrees, R.euler_to_quat(many, order))


def test_euler_matches_scipy_intrinsic() -> None:
    rotation = pytest.importorskip("scipy.spatial.transform").Rotation
    angles = np.array([[10.0, -35.0, 80.0], [170.0, 20.0, -100.0]])
    for order in ORDERS:
        ours = R.quat_to_matrix(R.euler_to_quat(torch.as_tensor(angles), order, degrees=True)).numpy()
        np.testing.assert_allclose(
            ours, rotation.from_euler(order.upper(), angles, degrees=True).as_matrix(), atol=1e-12
        )


def test_euler_rejects_bad_order() -> None:
    with pytest.raises(ValueError, match="euler order"):
        R.euler_to_quat(torch.zeros(3), "xy")
    with pytest.raises(ValueError, match="distinct"):
        R.matrix_to_euler(torch.eye(3), "zxz")


def test_axis_angle_round_trip_and_small_angles() -> None:
    gen = torch.Generator().manual_seed(8)
    aa = torch.randn(100, 3, generator=gen, dtype=torch.float64)
    aa = aa / aa.norm(dim=-1, keepdim=True) * torch.rand(100, 1, generator=gen, dtype=torch.float64) * 3.0
    q = R.axis_angle_to_quat(aa)
    torch.testing.assert_close(q.norm(dim=-1), torch.ones(100, dtype=torch.float64))
    torch.testing.assert_close(R.quat_to_axis_angle(q), aa)
    axis = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    torch.testing.assert_close(
        R.qrot(R.axis_angle_to_quat(axis * math.pi / 2), torch.tensor([1.0, 0, 0], dtype=torch.float64)),
        torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64),
    )
    tiny = torch.tensor([[1e-9, 0.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    assert torch.isfinite(R.axis_angle_to_quat(tiny)).all()
    assert torch.isfinite(R.quat_to_axis_angle(R.axis_angle_to_quat(tiny))).all()


def test_numpy_wrappers_are_float64() -> None:
    q = random_quats(4, 9).numpy()
    v = np.ones((4, 3), dtype=np.float32)
    out = R.qrot_np(q, v)
    assert out.dtype == np.float64
    np.testing.assert_allclose(out, R.qrot(torch.as_tensor(q), torch.as_tensor(v, dtype=torch.float64)).numpy())
    np.testing.assert_allclose(R.qmul_np(q, R.qinv_np(q)), np.tile([1.0, 0, 0, 0], (4, 1)), atol=1e-12)
    assert R.quat_to_cont6d_np(q).shape == (4, 6)
    assert R.cont6d_to_matrix_np(R.quat_to_cont6d_np(q)).shape == (4, 3, 3)
    assert R.euler_to_quat_np(np.zeros(3), "zxy").tolist() == [1.0, 0.0, 0.0, 0.0]
