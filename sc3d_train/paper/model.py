"""The network of Liao, Yang & Wang (2D-3D self-consistency): encoder E, voxel decoder D_v,
mask decoder D_m and the pose head.

Shapes (B = batch, S = ``image_size``, G = ``voxel_resolution``, C = ``base_channels``):

Encoder E (residual)
    stem conv 3x3 (3 -> C) at S x S, then 5 residual blocks, each halving the resolution
    (S/2 .. S/32) with channels C, 2C, 4C, 8C, 8C; BatchNorm + LeakyReLU(0.2). The final
    ``8C x S/32 x S/32`` features are flattened and mapped by linear layers to the shape code
    (``z_mean``, ``z_logvar`` ``[B, shape_dim]``; a conditional VAE: ``z_s = mean + exp(logvar/2) *
    eps`` in training, ``z_s = mean`` in eval) and to the pose code ``z_p [B, pose_dim]``.
Pose head
    ONE linear layer ``pose_head: z_p -> pose_logits [B, A + E]``: a classifier over the
    candidate azimuths and elevations of the pose grid (:class:`sc3d_train.paper.pose.PoseGrid`; the
    continuous pose is a soft-argmax of the logits, see :mod:`sc3d_train.paper.pose`).
Voxel decoder D_v ("voxel tubes", from z_s)
    ``3tube``: three 2D-deconvolution branches; each maps z_s to a ``G x G x G`` tensor whose
    *channel* axis is one of x (width), y (height) or z (depth) and whose two image axes are the
    other two in increasing order. Each is transposed into ``[x, y, z]`` order and the three
    logit volumes are averaged. ``1tube``: only the depth (z-channel) branch.
    Output ``voxel_logits [B, G, G, G]``, index order ``[x, y, z]`` as in the shards (SPEC).
Mask decoder D_m (U-Net, from z_mean and z_p)
    ``[z_mean, z_p]`` -> linear -> ``8C x S/32 x S/32``, then 5 upsampling blocks (x2 each, back
    to S x S); each block concatenates the encoder feature map of the same resolution (U-Net
    skips from E). Output ``mask_logits [B, S, S]`` at the *input image size* (S_m = image_size);
    the self-consistency module works on masks area-downsampled to ``mask_size``.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from sc3d_train.settings.config import ModelConfig  # the settings (defined with the other configs)
from .pose import PoseGrid, pose_from_logits

NUM_ENCODER_BLOCKS = 5
LEAKY_SLOPE = 0.2


@dataclass
class ModelOutput:
    """Network outputs. ``voxel_logits [B, G, G, G]`` ([x, y, z]); ``mask_logits [B, S, S]``
    (S = image_size); ``azimuth [B]`` degrees in [0, 360); ``elevation [B]`` degrees;
    ``pose_logits [B, A + E]`` pose-head output (azimuth then elevation logits); ``z_mean``, ``z_logvar`` ``[B, shape_dim]``."""

    voxel_logits: Tensor
    mask_logits: Tensor
    azimuth: Tensor
    elevation: Tensor
    pose_logits: Tensor
    z_mean: Tensor
    z_logvar: Tensor


def _act() -> nn.Module:
    return nn.LeakyReLU(LEAKY_SLOPE, inplace=True)


class ResidualBlock(nn.Module):
    """Basic residual block: two 3x3 convs with BN; the shortcut is average pooling + 1x1 conv + BN
    (ResNet-D style) rather than a strided 1x1 conv, whose CPU backward in torch 2.13 corrupts the
    heap for inputs with channels-last strides and few channels (e.g. images permuted from HWC,
    ``base_channels`` 4 or 8); ``[B, cin, H, W] -> [B, cout, H/stride, W/stride]``."""

    def __init__(self, cin: int, cout: int, stride: int = 2):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        pool = nn.AvgPool2d(stride) if stride > 1 else nn.Identity()
        self.shortcut = nn.Sequential(pool, nn.Conv2d(cin, cout, 1, bias=False), nn.BatchNorm2d(cout))
        self.act = _act()

    def forward(self, x: Tensor) -> Tensor:
        h = self.act(self.bn1(self.conv1(x)))
        h = self.bn2(self.conv2(h))
        return self.act(h + self.shortcut(x))


class Encoder(nn.Module):
    """Image ``[B, 3, S, S]`` -> ``(features [B, 8C*(S/32)^2], skips)``, skips = the stem output and
    the outputs of the first four blocks (resolutions S, S/2, S/4, S/8, S/16)."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        c = config.base_channels
        self.channels = [c, 2 * c, 4 * c, 8 * c, 8 * c]
        self.stem = nn.Sequential(nn.Conv2d(3, c, 3, 1, 1, bias=False), nn.BatchNorm2d(c), _act())
        cins = [c] + self.channels[:-1]
        self.blocks = nn.ModuleList(ResidualBlock(i, o) for i, o in zip(cins, self.channels))

    def forward(self, x: Tensor) -> tuple[Tensor, list[Tensor]]:
        h = self.stem(x)
        skips = [h]
        for block in self.blocks:
            h = block(h)
            skips.append(h)
        return h.flatten(1), skips[:-1]


def _up(cin: int, cout: int) -> nn.Sequential:
    """x2 upsampling: transposed conv 4x4 stride 2 + BN + LeakyReLU."""
    return nn.Sequential(nn.ConvTranspose2d(cin, cout, 4, 2, 1, bias=False), nn.BatchNorm2d(cout), _act())


class VoxelTube(nn.Module):
    """z_s ``[B, D]`` -> ``[B, G, G, G]``: a 2D deconvolution decoder whose G output channels are
    one spatial axis of the grid (the "tube" axis) and whose G x G image is the other two."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        c, g = config.base_channels, config.voxel_resolution
        self.start = g // 8 if g % 8 == 0 else g // 4
        n_up = {g // 8: 3, g // 4: 2}[self.start]
        chans = [8 * c, 4 * c, 2 * c, c][: n_up + 1]
        self.c0 = chans[0]
        self.fc = nn.Linear(config.shape_dim, self.c0 * self.start * self.start)
        self.ups = nn.Sequential(*[_up(a, b) for a, b in zip(chans[:-1], chans[1:])])
        self.out = nn.Conv2d(chans[-1], g, 3, 1, 1)

    def forward(self, z: Tensor) -> Tensor:
        h = F.leaky_relu(self.fc(z), LEAKY_SLOPE).view(z.shape[0], self.c0, self.start, self.start)
        return self.out(self.ups(h))


class VoxelDecoder(nn.Module):
    """D_v: z_s ``[B, shape_dim]`` -> ``voxel_logits [B, G, G, G]`` in ``[x, y, z]`` order.

    Branch outputs before transposition: ``x``: [B, x, y, z]; ``y``: [B, y, x, z];
    ``z``: [B, z, x, y]. ``3tube`` averages the three (logits); ``1tube`` uses ``z`` only."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        axes = ("x", "y", "z") if config.voxel_decoder == "3tube" else ("z",)
        self.branches = nn.ModuleDict({a: VoxelTube(config) for a in axes})

    def forward(self, z: Tensor) -> Tensor:
        vols = []
        for axis, branch in self.branches.items():
            v = branch(z)
            if axis == "y":
                v = v.permute(0, 2, 1, 3)  # [B, y, x, z] -> [B, x, y, z]
            elif axis == "z":
                v = v.permute(0, 2, 3, 1)  # [B, z, x, y] -> [B, x, y, z]
            vols.append(v)
        return torch.stack(vols, 0).mean(0)


class MaskDecoder(nn.Module):
    """D_m: ``[z_mean, z_p]`` + encoder skips -> ``mask_logits [B, S, S]`` with 5 upsampling
    blocks (U-Net: each block's output is concatenated with the encoder map of its resolution and
    fused by a 3x3 conv)."""

    def __init__(self, config: ModelConfig, enc_channels: list[int]):
        super().__init__()
        self.start = config.image_size // 32
        self.c0 = enc_channels[-1]
        self.fc = nn.Linear(config.shape_dim + config.pose_dim, self.c0 * self.start * self.start)
        # skips (deepest first): block4 (S/16, 8C), block3 (S/8, 4C), block2 (S/4, 2C),
        # block1 (S/2, C), stem (S, C)
        skip_ch = [enc_channels[3], enc_channels[2], enc_channels[1], enc_channels[0], enc_channels[0]]
        out_ch = skip_ch
        cins = [self.c0] + out_ch[:-1]
        self.ups = nn.ModuleList(_up(i, o) for i, o in zip(cins, out_ch))
        self.fuse = nn.ModuleList(
            nn.Sequential(nn.Conv2d(o + s, o, 3, 1, 1, bias=False), nn.BatchNorm2d(o), _act())
            for o, s in zip(out_ch, skip_ch))
        self.out = nn.Conv2d(out_ch[-1], 1, 1)

    def forward(self, z_mean: Tensor, z_p: Tensor, skips: list[Tensor]) -> Tensor:
        h = F.leaky_relu(self.fc(torch.cat([z_mean, z_p], 1)), LEAKY_SLOPE)
        h = h.view(z_mean.shape[0], self.c0, self.start, self.start)
        for up, fuse, skip in zip(self.ups, self.fuse, reversed(skips)):
            h = fuse(torch.cat([up(h), skip], 1))
        return self.out(h)[:, 0]


class SelfConsistencyNet(nn.Module):
    """The whole network: ``forward(images [B, 3, S, S] float in [0, 1]) -> ModelOutput``.
    The self-consistency module itself has no parameters (:mod:`sc3d_train.paper.self_consistency`)."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        self.config = config
        self.encoder = Encoder(config)
        feat = self.encoder.channels[-1] * (config.image_size // 32) ** 2
        self.fc_mean = nn.Linear(feat, config.shape_dim)
        self.fc_logvar = nn.Linear(feat, config.shape_dim)
        self.fc_pose_code = nn.Linear(feat, config.pose_dim)
        self.pose_grid = PoseGrid.of(config)
        self.pose_head = nn.Linear(config.pose_dim, self.pose_grid.num_logits)
        self.voxel_decoder = VoxelDecoder(config)
        self.mask_decoder = MaskDecoder(config, self.encoder.channels)

    def forward(self, images: Tensor, noise: Tensor | None = None, mask_grad: bool = True) -> ModelOutput:
        """``noise [B, shape_dim]`` float: the reparameterisation's standard normal draw in
        training (drawn here with ``randn_like`` when None). The training step draws it outside
        the network, so the compiled and the eager step consume the same random numbers.
        ``mask_grad=False`` runs the mask decoder outside the autograd graph (same values): the
        unlabelled loss reads the mask detached, and under DDP a mask left in the graph made DDP
        wait for mask-decoder gradients that never come (``phase_step.step_losses``)."""
        s = self.config.image_size
        if images.ndim != 4 or images.shape[1] != 3 or images.shape[2] != s or images.shape[3] != s:
            raise ValueError(f"images must be [B, 3, {s}, {s}] (model image_size {s}), got {tuple(images.shape)}")
        feat, skips = self.encoder(images)
        z_mean, z_logvar = self.fc_mean(feat), self.fc_logvar(feat)
        if self.training:
            eps = torch.randn_like(z_mean) if noise is None else noise
            z_s = z_mean + torch.exp(0.5 * z_logvar) * eps
        else:
            z_s = z_mean
        z_p = self.fc_pose_code(feat)
        pose_logits = self.pose_head(z_p)
        azimuth, elevation = pose_from_logits(pose_logits.float(), self.pose_grid)
        voxel_logits = self.voxel_decoder(z_s)
        if mask_grad:
            mask_logits = self.mask_decoder(z_mean, z_p, skips)
        else:
            with torch.no_grad():
                mask_logits = self.mask_decoder(z_mean, z_p, skips)
        return ModelOutput(
            voxel_logits=voxel_logits, mask_logits=mask_logits,
            azimuth=azimuth, elevation=elevation, pose_logits=pose_logits,
            z_mean=z_mean, z_logvar=z_logvar)
