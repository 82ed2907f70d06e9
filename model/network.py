"""IT-Net (Yuan et al., ICCV 2019): one PointNet step that predicts a rigid update, iterated.

Shapes: B = batch, N = points. Poses are (B, 4, 4) homogeneous matrices in the normalised frame
of ``itnet.preprocess``; quaternions are WXYZ.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import torch
from torch import Tensor, nn

IDENTITY_OUTPUT = (1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # quaternion WXYZ, translation xyz
# the rotation's first two columns (Zhou et al., CVPR 2019), translation xyz
IDENTITY_OUTPUT_6D = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0)
Rotation = Literal["quaternion", "6d"]
ROTATIONS: tuple[str, ...] = get_args(Rotation)


@dataclass(frozen=True)
class NetworkConfig:
    """Architecture switches. The defaults are the paper's; the flags rerun its ablations.

    ``rotation``: what the regressor's output parameterises, ``quaternion`` (the paper's: 4
    numbers, normalised) or ``6d`` (the rotation's first two columns, made orthonormal by
    Gram-Schmidt: continuous over all rotations, where a quaternion is not, Zhou et al. 2019)."""

    point_channels: tuple[int, ...] = (64, 128, 1024)
    head_channels: tuple[int, ...] = (512, 256)
    identity_init: bool = True
    rotation: str = "quaternion"

    def __post_init__(self) -> None:
        if self.rotation not in ROTATIONS:
            raise ValueError(f"unknown rotation {self.rotation!r}; one of {', '.join(ROTATIONS)}")

    @property
    def outputs(self) -> int:
        return 7 if self.rotation == "quaternion" else 9


def quat_wxyz_translation_to_pose(output: Tensor) -> Tensor:
    """(B, 7) = quaternion WXYZ (normalised here) + translation -> rigid pose (B, 4, 4)."""
    q = output[:, :4] / output[:, :4].norm(dim=-1, keepdim=True).clamp_min(1e-8)
    w, x, y, z = q.unbind(-1)
    rotation = torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(-1, 3, 3)
    top = torch.cat([rotation, output[:, 4:7, None]], dim=-1)
    bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=output.dtype, device=output.device)
    return torch.cat([top, bottom.expand(output.shape[0], 1, 4)], dim=1)


def six_d_translation_to_pose(output: Tensor) -> Tensor:
    """(B, 9) = two 3-vectors a1, a2 + translation -> rigid pose (B, 4, 4). The rotation's
    columns: b1 = a1/|a1|, b2 = the part of a2 orthogonal to b1, normalised, b3 = b1 × b2.
    Written with elementwise products only, so that the ONNX export needs no cross product."""
    a1, a2, t = output[:, 0:3], output[:, 3:6], output[:, 6:9]
    b1 = a1 / a1.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    a2 = a2 - (b1 * a2).sum(-1, keepdim=True) * b1
    b2 = a2 / a2.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    x1, y1, z1 = b1.unbind(-1)
    x2, y2, z2 = b2.unbind(-1)
    b3 = torch.stack([y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2], dim=-1)
    rotation = torch.stack([b1, b2, b3], dim=-1)  # columns
    top = torch.cat([rotation, t[:, :, None]], dim=-1)
    bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=output.dtype, device=output.device)
    return torch.cat([top, bottom.expand(output.shape[0], 1, 4)], dim=1)


def output_to_pose(output: Tensor, rotation: str) -> Tensor:
    """The regressor's output (B, 7 | 9) -> rigid pose (B, 4, 4), as ``rotation`` reads it."""
    if rotation == "6d":
        return six_d_translation_to_pose(output)
    return quat_wxyz_translation_to_pose(output)


def apply_pose(pose: Tensor, points: Tensor) -> Tensor:
    """Pose (B, 4, 4) applied to points (B, N, 3) -> (B, N, 3)."""
    return points @ pose[:, :3, :3].transpose(1, 2) + pose[:, None, :3, 3]


def _mlp(channels: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for c_in, c_out in zip(channels[:-1], channels[1:]):
        layers += [nn.Linear(c_in, c_out, bias=False), nn.BatchNorm1d(c_out), nn.ReLU()]
    return nn.Sequential(*layers)


class PoseRegressor(nn.Module):
    """PointNet: shared MLP 3->64->128->1024, max-pool, MLP 1024->512->256, linear 256->7 (9)."""

    def __init__(self, config: NetworkConfig) -> None:
        super().__init__()
        self.point_mlp = _mlp([3, *config.point_channels])
        self.head = _mlp([config.point_channels[-1], *config.head_channels])
        self.out = nn.Linear(config.head_channels[-1], config.outputs)
        if config.identity_init:
            nn.init.zeros_(self.out.weight)
            identity = IDENTITY_OUTPUT if config.rotation == "quaternion" else IDENTITY_OUTPUT_6D
            with torch.no_grad():
                self.out.bias.copy_(torch.tensor(identity))

    def forward(self, points: Tensor) -> Tensor:
        """Points (B, N, 3) -> (B, 7): quaternion WXYZ (unnormalised) + translation; with the
        6D rotation (B, 9): two unnormalised columns + translation."""
        b, n, _ = points.shape
        features = self.point_mlp(points.reshape(b * n, 3)).reshape(b, n, -1)
        hidden = self.head(features.amax(dim=1))
        with torch.autocast(points.device.type, enabled=False):  # full precision for the pose
            return self.out(hidden.float())


class ITNet(nn.Module):
    """The iterative transformer: one regressor, shared by every iteration."""

    def __init__(self, config: NetworkConfig | None = None) -> None:
        super().__init__()
        self.config = config or NetworkConfig()
        self.regressor = PoseRegressor(self.config)

    def step(
        self, points: Tensor, pose: Tensor, stop_gradient: bool = True
    ) -> tuple[Tensor, Tensor]:
        """One iteration: points (B, N, 3), pose so far (B, 4, 4) -> (next pose, update), each B x4x4.

        The input is moved by the pose so far, the regressor predicts the update dT, and
        ``next = dT @ pose``. With ``stop_gradient`` the moved input is detached, so the gradient
        flows only through the composition (the paper's choice).
        """
        moving = pose.detach() if stop_gradient else pose
        output = self.regressor(apply_pose(moving, points))
        delta = output_to_pose(output, self.config.rotation)
        return delta @ pose, delta

    def forward(self, points: Tensor, iterations: int, stop_gradient: bool = True) -> list[Tensor]:
        """Points (B, N, 3) -> the poses after iterations 1..K, each (B, 4, 4)."""
        pose = torch.eye(4, dtype=points.dtype, device=points.device).expand(len(points), 4, 4)
        poses = []
        for _ in range(iterations):
            pose, _ = self.step(points, pose, stop_gradient)
            poses.append(pose)
        return poses


def _bn_scale(norm: nn.BatchNorm1d) -> Tensor:
    """(C,): what BatchNorm in eval mode multiplies each channel by."""
    return norm.weight.detach() / torch.sqrt(norm.running_var + norm.eps)


def _folded(linear: nn.Linear, norm: nn.BatchNorm1d | None) -> tuple[Tensor, Tensor]:
    """Weight (C_out, C_in) and bias (C_out,) of ``linear`` followed by ``norm`` in eval mode."""
    weight = linear.weight.detach().float()
    bias = (
        linear.bias.detach().float()
        if linear.bias is not None
        else torch.zeros(len(weight), device=weight.device)
    )
    if norm is None:
        return weight, bias
    scale = _bn_scale(norm)
    return weight * scale[:, None], (bias - norm.running_mean) * scale + norm.bias.detach()


def _folded_mlp(mlp: nn.Sequential) -> list[tuple[Tensor, Tensor]]:
    layers = list(mlp)
    return [_folded(layers[i], layers[i + 1]) for i in range(0, len(layers), 3)]


class ExportableStep(nn.Module):
    """The graph exported to ONNX: (points B x N x 3, pose B x4x4) -> (next pose, update).

    The same function as ``ITNet.step`` in eval mode, written for inference engines: BatchNorm is
    folded into the weights, and the per-point MLP runs channels-first, (B, C, N), so the max-pool
    reduces the innermost axis. onnxruntime's ReduceMax over the point axis of (B, N, 1024) took
    1.7 ms at N = 1,024 on 2 cores, half of the whole step; over the innermost axis, 0.07 ms.
    The update is built by two small matrix products (:func:`pose_update_matrices`) instead of
    ``quat_wxyz_translation_to_pose``'s nine formulas: the same pose in about a tenth of the
    graph's nodes, which on 2 cores cost more than their arithmetic.
    """

    def __init__(self, net: ITNet) -> None:
        super().__init__()
        regressor = net.regressor
        point = _folded_mlp(regressor.point_mlp)
        head = [*_folded_mlp(regressor.head), _folded(regressor.out, None)]
        for i, (w, b) in enumerate(point):
            self.register_buffer(f"point_w{i}", w.contiguous())
            self.register_buffer(f"point_b{i}", b[:, None].contiguous())
        for i, (w, b) in enumerate(head):
            self.register_buffer(f"head_w{i}", w.t().contiguous())
            self.register_buffer(f"head_b{i}", b.contiguous())
        self.point_layers, self.head_layers = len(point), len(head)
        self.rotation = net.config.rotation
        from_quaternion, from_translation, bottom = pose_update_matrices()
        self.register_buffer("update_from_quaternion", from_quaternion)
        self.register_buffer("update_from_translation", from_translation)
        self.register_buffer("update_bottom", bottom)

    def regress(self, moved: Tensor) -> Tensor:
        """Moved points (B, N, 3) -> (B, 7) as ``PoseRegressor.forward``."""
        h = moved.transpose(1, 2)  # (B, 3, N)
        last = self.point_layers - 1
        for i in range(last):
            h = torch.relu(getattr(self, f"point_w{i}") @ h + getattr(self, f"point_b{i}"))
        # max over points commutes with the per-channel bias and ReLU (both monotone): pool the
        # (B, 1024, N) product first, then add and clip 1,024 numbers instead of 1,024 x N
        g = (getattr(self, f"point_w{last}") @ h).amax(dim=-1)
        g = torch.relu(g + getattr(self, f"point_b{last}")[:, 0])  # (B, 1024)
        for i in range(self.head_layers):
            g = g @ getattr(self, f"head_w{i}") + getattr(self, f"head_b{i}")
            if i < self.head_layers - 1:
                g = torch.relu(g)
        return g

    def update(self, output: Tensor) -> Tensor:
        """(B, 7) quaternion WXYZ (any length) + translation -> (B, 4, 4), as
        ``quat_wxyz_translation_to_pose``: R = C · vec(q qᵀ) / |q|². (B, 9) with the 6D
        rotation: ``six_d_translation_to_pose``."""
        if self.rotation == "6d":
            return six_d_translation_to_pose(output)
        q, t = output[:, :4], output[:, 4:7]
        outer = (q[:, :, None] * q[:, None, :]).reshape(-1, 16)
        norm = (q * q).sum(-1, keepdim=True).clamp_min(1e-16)
        flat = (
            (outer / norm) @ self.update_from_quaternion
            + t @ self.update_from_translation
            + self.update_bottom
        )
        return flat.reshape(-1, 4, 4)

    def forward(self, points: Tensor, pose: Tensor) -> tuple[Tensor, Tensor]:
        delta = self.update(self.regress(apply_pose(pose, points)))
        return delta @ pose, delta


def pose_update_matrices() -> tuple[Tensor, Tensor, Tensor]:
    """Constants that turn a quaternion's outer product and a translation into a rigid pose,
    row-major: (16, 16) from vec(q qᵀ) of a unit WXYZ quaternion (R = w² + x² − y² − z², ... the
    rotation's entries are quadratic forms), (3, 16) from the translation, (16,) the bottom row."""
    w, x, y, z = range(4)
    rotation = [  # (row, column) -> [(coefficient, i, j)], terms of q_i q_j
        [[(1, w, w), (1, x, x), (-1, y, y), (-1, z, z)], [(2, x, y), (-2, w, z)], [(2, x, z), (2, w, y)]],
        [[(2, x, y), (2, w, z)], [(1, w, w), (-1, x, x), (1, y, y), (-1, z, z)], [(2, y, z), (-2, w, x)]],
        [[(2, x, z), (-2, w, y)], [(2, y, z), (2, w, x)], [(1, w, w), (-1, x, x), (-1, y, y), (1, z, z)]],
    ]  # fmt: skip
    from_quaternion = torch.zeros(16, 16)
    for row, entries in enumerate(rotation):
        for column, terms in enumerate(entries):
            for coefficient, i, j in terms:
                # vec(q qᵀ) holds q_i q_j at 4i + j and 4j + i: split a cross term between both
                half = coefficient / (1 if i == j else 2)
                from_quaternion[4 * i + j, 4 * row + column] += half
                if i != j:
                    from_quaternion[4 * j + i, 4 * row + column] += half
    from_translation = torch.zeros(3, 16)
    for row in range(3):
        from_translation[row, 4 * row + 3] = 1.0
    bottom = torch.zeros(16)
    bottom[15] = 1.0
    return from_quaternion, from_translation, bottom


PointLoss = Literal["squared", "distance"]
POINT_LOSSES: tuple[str, ...] = get_args(PointLoss)


def _per_point(diff: Tensor, kind: str) -> Tensor:
    """(..., 3) differences -> (...) per-point loss: ``squared`` ||d||², ``distance`` ||d||."""
    squared = diff.square().sum(-1)
    if kind == "squared":
        return squared
    if kind == "distance":
        return (squared + 1e-12).sqrt()  # the epsilon keeps the gradient finite at 0
    raise ValueError(f"unknown point loss {kind!r}; one of {', '.join(POINT_LOSSES)}")


def point_loss(
    pose_estimate: Tensor,
    pose_target: Tensor,
    points: Tensor,
    symmetries: Tensor | None = None,
    kind: str = "squared",
) -> Tensor:
    """PLoss: mean over batch and points of ||T_est x - T_gt x||^2. Poses (B,4,4), points (B,N,3).

    With ``symmetries`` (B, G, 4, 4): each example's equivalent targets are ``S_g @ T_gt`` (turns
    about the canonical origin, ``itnet.symmetry``), and its loss is the smallest over g (an
    example with fewer turns repeats one of them). ``kind="distance"`` takes ||·|| instead of
    ||·||² (the paper's): its gradient does not fade as the estimate nears the target, which
    weighs small errors (precision) more against large ones."""
    if symmetries is None:
        diff = apply_pose(pose_estimate, points) - apply_pose(pose_target, points)
        return _per_point(diff, kind).mean()
    b, g = symmetries.shape[:2]
    targets = (symmetries @ pose_target[:, None]).reshape(b * g, 4, 4)
    repeated = points[:, None].expand(b, g, *points.shape[1:]).reshape(b * g, *points.shape[1:])
    estimate = apply_pose(pose_estimate, points)[:, None]  # (B, 1, N, 3)
    diff = estimate - apply_pose(targets, repeated).reshape(b, g, *points.shape[1:])
    return _per_point(diff, kind).mean(-1).amin(1).mean()
