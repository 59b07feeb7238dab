"""The feed-forward feature network: points -> triplanes -> per-point features and SDF.

Pipeline (PartField-style, see ``METHOD.md``, Architecture):

1. PVCNN point encoder: a shared MLP on (xyz, normal), then point-voxel blocks that scatter-mean
   point features into an R^3 grid, run 3D convolutions and read the grid back trilinearly.
2. Scatter-mean of point features onto the xy, xz and yz planes (P x P each).
3. 3D-aware plane convolutions (each plane sees line averages of the other two; a simplified
   stand-in for the release's plane U-Net), a 2D CNN (shared by the three planes) with
   max-pooling down to (P / 2**s)^2 tokens per plane, a transformer over all 3 (P / 2**s)^2
   tokens with learned position and plane embeddings, and a transposed convolution back to
   P x P, plus a per-pixel MLP residual from the (3D-aware) scattered planes.
4. Query: bilinear sampling of the three output planes, summed; the first ``sdf_channels``
   channels feed a small SDF MLP, the rest form the unit feature.

All coordinates live in the normalised frame [-1, 1]^3; points outside are clamped to the border
cells. Pure torch, device-agnostic: tensors follow the device of the inputs and the module.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .config import CONTEXT_LINES, PLANE_AXES, ModelConfig


# -------------------------------------------------------------------------- functional pieces
def grid_index(xyz: torch.Tensor, res: int) -> torch.Tensor:
    """Integer cell of each coordinate in a ``res``-cell split of [-1, 1].

    Parameters
    ----------
    xyz : (..., d) float
    res : int

    Returns
    -------
    (..., d) long, in [0, res).
    """
    return ((xyz + 1.0) * (0.5 * res)).floor().long().clamp_(0, res - 1)


def scatter_mean(values: torch.Tensor, index: torch.Tensor, size: int) -> torch.Tensor:
    """Batched scatter-mean.

    Parameters
    ----------
    values : (b, n, c) float
    index : (b, n) long, in [0, size)
    size : int, number of bins per batch item.

    Returns
    -------
    (b, size, c) float: the mean of the values in each bin (0 for empty bins).
    """
    b, n, c = values.shape
    flat = (index + size * torch.arange(b, device=index.device)[:, None]).reshape(-1)
    total = values.new_zeros(b * size, c).index_add_(0, flat, values.reshape(-1, c))
    count = values.new_zeros(b * size).index_add_(0, flat, values.new_ones(b * n))
    return (total / count.clamp_min(1.0)[:, None]).reshape(b, size, c)


def voxelize(feats: torch.Tensor, xyz: torch.Tensor, res: int) -> torch.Tensor:
    """Scatter-mean point features into a voxel grid.

    Parameters
    ----------
    feats : (b, n, c) float
    xyz : (b, n, 3) float in [-1, 1]
    res : int

    Returns
    -------
    (b, c, res, res, res) float, laid out (z, y, x) as :func:`torch.nn.functional.grid_sample`
    expects for grid coordinates (x, y, z).
    """
    ijk = grid_index(xyz, res)
    index = (ijk[..., 2] * res + ijk[..., 1]) * res + ijk[..., 0]
    grid = scatter_mean(feats, index, res**3)  # (b, r^3, c)
    return grid.transpose(1, 2).reshape(feats.shape[0], feats.shape[2], res, res, res)


def devoxelize(grid: torch.Tensor, xyz: torch.Tensor) -> torch.Tensor:
    """Trilinear interpolation of a voxel grid at points.

    Parameters
    ----------
    grid : (b, c, r, r, r) float, laid out (z, y, x)
    xyz : (b, n, 3) float in [-1, 1]

    Returns
    -------
    (b, n, c) float
    """
    g = xyz[:, :, None, None, :]  # (b, n, 1, 1, 3)
    out = F.grid_sample(grid, g, mode="bilinear", padding_mode="border", align_corners=False)
    return out[:, :, :, 0, 0].transpose(1, 2)


def scatter_planes(feats: torch.Tensor, xyz: torch.Tensor, res: int) -> torch.Tensor:
    """Scatter-mean point features onto the xy, xz and yz planes.

    Parameters
    ----------
    feats : (b, n, c) float
    xyz : (b, n, 3) float in [-1, 1]
    res : int, plane side P.

    Returns
    -------
    (b, 3, c, P, P) float; image rows follow the plane's second axis, columns its first.
    """
    b, n, c = feats.shape
    ij = grid_index(xyz, res)
    index = torch.stack([ij[..., v] * res + ij[..., u] + k * res * res
                         for k, (u, v) in enumerate(PLANE_AXES)], dim=1)  # (b, 3, n)
    planes = scatter_mean(feats.repeat(1, 3, 1), index.reshape(b, 3 * n), 3 * res * res)
    return planes.reshape(b, 3, res, res, c).permute(0, 1, 4, 2, 3)


def sample_planes(planes: torch.Tensor, xyz: torch.Tensor) -> torch.Tensor:
    """Bilinear sampling of three planes at points, summed.

    Parameters
    ----------
    planes : (b, 3, c, P, P) float
    xyz : (b, n, 3) float in [-1, 1]

    Returns
    -------
    (b, n, c) float
    """
    b, _, c, h, w = planes.shape
    grid = torch.stack([xyz[..., list(axes)] for axes in PLANE_AXES], dim=1)  # (b, 3, n, 2)
    out = F.grid_sample(planes.reshape(b * 3, c, h, w), grid.reshape(b * 3, -1, 1, 2),
                        mode="bilinear", padding_mode="border", align_corners=False)
    return out.reshape(b, 3, c, -1).sum(1).transpose(1, 2)


def cross_plane_context(planes: torch.Tensor) -> torch.Tensor:
    """What the other two planes know about each plane's rows and columns (3D-aware context).

    Each plane shares one axis with each other plane. The other plane is averaged over its
    remaining axis, and the resulting line of features is broadcast along the target plane's
    remaining axis (as in Rodin's 3D-aware convolution).

    Parameters
    ----------
    planes : (b, 3, c, P, P) float

    Returns
    -------
    (b, 3, 2c, P, P) float
    """
    out = []
    for lines in CONTEXT_LINES:
        parts = []
        for j, axis, along_w in lines:
            line = planes[:, j].mean(dim=axis)  # (b, c, P)
            parts.append(line[:, :, None, :] if along_w else line[:, :, :, None])
        p = planes.shape[-1]
        out.append(torch.cat([x.expand(-1, -1, p, p) for x in parts], dim=1))
    return torch.stack(out, dim=1)


# -------------------------------------------------------------------------- modules
class AwarePlaneBlock(nn.Module):
    """Residual 3x3 conv of each plane together with its cross-plane context (shared weights).

    (b, 3, c, P, P) -> (b, 3, c, P, P).
    """

    def __init__(self, c: int):
        super().__init__()
        self.conv = nn.Conv2d(3 * c, c, 3, padding=1)
        self.norm = nn.GroupNorm(_groups(c), c)

    def forward(self, planes: torch.Tensor) -> torch.Tensor:
        b, three, c, p, _ = planes.shape
        x = torch.cat([planes, cross_plane_context(planes)], dim=2).reshape(b * three, 3 * c, p, p)
        return planes + F.gelu(self.norm(self.conv(x))).reshape(b, three, c, p, p)



class PointVoxelBlock(nn.Module):
    """One PVConv block: (voxel branch + point branch), then ReLU. (b, n, c_in) -> (b, n, c_out)."""

    def __init__(self, c_in: int, c_out: int, res: int):
        super().__init__()
        self.res = res
        groups = _groups(c_out)
        self.voxel = nn.Sequential(
            nn.Conv3d(c_in, c_out, 3, padding=1), nn.GroupNorm(groups, c_out), nn.LeakyReLU(0.1),
            nn.Conv3d(c_out, c_out, 3, padding=1), nn.GroupNorm(groups, c_out), nn.LeakyReLU(0.1),
        )
        self.point = nn.Linear(c_in, c_out)

    def forward(self, feats: torch.Tensor, xyz: torch.Tensor) -> torch.Tensor:
        grid = self.voxel(voxelize(feats, xyz, self.res))
        return F.relu(devoxelize(grid, xyz) + self.point(feats))


class PointEncoder(nn.Module):
    """PVCNN-style encoder: (b, n, 3) points + (b, n, 3) normals -> (b, n, c_out) features."""

    def __init__(self, point_channels: int, resolutions, channels, c_out: int):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(6, point_channels), nn.ReLU(),
                                 nn.Linear(point_channels, point_channels), nn.ReLU())
        blocks, c = [], point_channels
        for res, ch in zip(resolutions, channels, strict=True):
            blocks.append(PointVoxelBlock(c, ch, res))
            c = ch
        self.blocks = nn.ModuleList(blocks)
        self.out = nn.Linear(c + point_channels, c_out)

    def forward(self, xyz: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        base = self.mlp(torch.cat([xyz, normals], dim=-1))
        h = base
        for block in self.blocks:
            h = block(h, xyz)
        return self.out(torch.cat([h, base], dim=-1))


class PlaneTransformer(nn.Module):
    """(b, 3, c, P, P) planes -> (b, 3, c_out, P, P): 3D-aware plane convolutions, CNN down, ViT,
    transposed conv up, plus a per-pixel MLP residual."""

    def __init__(self, c_in: int, res: int, down_channels, width: int, layers: int, heads: int,
                 mlp_ratio: float, dropout: float, c_out: int, residual_hidden: int, aware_layers: int = 0):
        super().__init__()
        self.aware = nn.Sequential(*[AwarePlaneBlock(c_in) for _ in range(aware_layers)])
        stages, c = [], c_in
        for ch in down_channels:
            stages += [nn.Conv2d(c, ch, 3, padding=1), nn.GELU(), nn.MaxPool2d(2)]
            c = ch
        self.down = nn.Sequential(*stages)
        scale = 2 ** len(down_channels)
        if res % scale:
            raise ValueError(f"plane resolution {res} is not divisible by {scale}")
        self.tokens_side = res // scale
        self.proj = nn.Linear(c, width) if c != width else nn.Identity()
        self.pos = nn.Parameter(torch.zeros(1, 1, self.tokens_side**2, width))
        self.plane = nn.Parameter(torch.zeros(1, 3, 1, width))
        nn.init.trunc_normal_(self.pos, std=0.02)
        nn.init.trunc_normal_(self.plane, std=0.02)
        layer = nn.TransformerEncoderLayer(width, heads, int(width * mlp_ratio), dropout,
                                           activation="gelu", batch_first=True, norm_first=True)
        self.vit = nn.TransformerEncoder(layer, layers, norm=nn.LayerNorm(width),
                                         enable_nested_tensor=False)
        self.up = nn.ConvTranspose2d(width, c_out, kernel_size=scale, stride=scale)
        self.residual = nn.Sequential(nn.Conv2d(c_in, residual_hidden, 1), nn.GELU(),
                                      nn.Conv2d(residual_hidden, c_out, 1))

    def forward(self, planes: torch.Tensor) -> torch.Tensor:
        planes = self.aware(planes)
        b, three, c, p, _ = planes.shape
        x = planes.reshape(b * three, c, p, p)
        t = self.down(x)  # (3b, c', s, s)
        s = t.shape[-1]
        t = self.proj(t.flatten(2).transpose(1, 2)).reshape(b, three, s * s, -1)
        t = (t + self.pos + self.plane).reshape(b, three * s * s, -1)
        t = self.vit(t)  # (b, 3 s^2, width)
        t = t.reshape(b * three, s, s, -1).permute(0, 3, 1, 2)
        out = self.up(t) + self.residual(x)
        return out.reshape(b, three, -1, p, p)


class FeatureNet(nn.Module):
    """Points + normals -> triplanes; triplanes + query points -> unit features and SDF.

    Attributes
    ----------
    config : ModelConfig
    dim : int, feature dimension.
    """

    def __init__(self, config: ModelConfig):
        super().__init__()
        self.config = config
        e, p, t, h = config.encoder, config.planes, config.transformer, config.head
        self.dim = h.feature_dim
        self.sdf_channels = h.sdf_channels
        self.encoder = PointEncoder(e.point_channels, e.voxel_resolutions, e.voxel_channels, p.channels)
        self.backbone = PlaneTransformer(p.channels, p.resolution, p.down_channels, t.width, t.layers,
                                         t.heads, t.mlp_ratio, t.dropout,
                                         h.sdf_channels + h.feature_dim, h.residual_hidden,
                                         p.aware_layers)
        self.sdf_head = nn.Sequential(nn.Linear(h.sdf_channels, h.sdf_hidden), nn.ReLU(),
                                      nn.Linear(h.sdf_hidden, 1))

    def forward(self, points: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        """Encode clouds.

        Parameters
        ----------
        points, normals : (b, n, 3) float, normalised frame.

        Returns
        -------
        (b, 3, sdf_channels + dim, P, P) float planes.
        """
        feats = self.encoder(points, normals)
        planes = scatter_planes(feats, points, self.config.planes.resolution)
        return self.backbone(planes)

    def query_raw(self, planes: torch.Tensor, xyz: torch.Tensor) -> torch.Tensor:
        """(b, 3, C, P, P) planes, (b, n, 3) points -> (b, n, C) summed plane samples."""
        return sample_planes(planes, xyz)

    def query(self, planes: torch.Tensor, xyz: torch.Tensor) -> torch.Tensor:
        """(b, 3, C, P, P) planes, (b, n, 3) points -> (b, n, dim) unit features."""
        return F.normalize(self.query_raw(planes, xyz)[..., self.sdf_channels :], dim=-1)

    def query_all(self, planes: torch.Tensor, xyz: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(b, 3, C, P, P) planes, (b, n, 3) points -> ((b, n, dim) unit features, (b, n) SDF)."""
        raw = self.query_raw(planes, xyz)
        feats = F.normalize(raw[..., self.sdf_channels :], dim=-1)
        sdf = self.sdf_head(raw[..., : self.sdf_channels])[..., 0]
        return feats, sdf

    def encode_and_query(self, points: torch.Tensor, normals: torch.Tensor,
                         query_xyz: torch.Tensor) -> torch.Tensor:
        """(b, n, 3) points and normals, (b, q, 3) queries -> (b, q, dim) unit features."""
        return self.query(self(points, normals), query_xyz)


def _groups(c: int) -> int:
    for g in (8, 4, 2):
        if c % g == 0:
            return g
    return 1


def build_model(config: ModelConfig, device: str | torch.device = "cpu") -> FeatureNet:
    """Instantiate a :class:`FeatureNet` on ``device`` (``"meta"`` allocates nothing)."""
    with torch.device(device):
        return FeatureNet(config)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
