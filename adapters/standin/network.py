"""A small cost-volume stereo network, the stand-in backbone of demos and tests.

Cheap per pixel, with the parts most CPU-friendly stereo networks share (GwcNet's
group-wise correlation, DispNet-style 2-D aggregation, RAFT's lookups and convex
upsampling), all at 1/4 resolution:

1. a shared feature CNN to 1/4 resolution;
2. a group-wise correlation cost volume at 1/4 resolution, ``max_disparity_px / 4``
   levels, with one more group: the correlation of a soft census transform (Zabih and
   Woodfill) of the 1/4-resolution grey image, a hand-made matching cost computed with
   fixed convolutions that depends only on the order of neighbouring intensities and so
   matches photographs as well as the procedural training pairs;
3. a 2-D hourglass (1/4 -> 1/16 -> 1/4) that reads the volume's levels as channels,
   next to the left features, and returns one matching cost per level, added to a
   direct weighted sum of the correlation groups; soft-argmin of it is the initial
   disparity;
4. a few refinement steps (shared weights, a plain recurrent state): each looks up the
   correlation and the aggregated cost around the current estimate and adds a residual;
5. a learned convex upsampling by 4 (RAFT) to full resolution, whose weights come from
   the refinement state, so edges follow the left image;
6. one full-resolution residual step (StereoNet-like): the soft census of the full-resolution
   images is compared at the upsampled disparity and a few pixels either side, and a
   small dilated CNN turns these costs, the left image and the disparity into a
   sub-pixel correction.

The bundled weights (``weights/standin.onnx``, described by ``weights/standin.json``)
are this architecture trained with the recipe in
:mod:`srde_fusion.adapters.standin.training` (3000 steps, seed 0, then 700 steps on
larger crops, seed 1, then 1300 steps on 256x512 crops, seed 2).

It follows IGEV's interface: ``(B, 3, H, W)`` float RGB in 0..255, normalised inside,
``H`` and ``W`` multiples of 32 (the ``"igev"`` preset pads to that), output
``(B, 1, H, W)`` positive disparity in pixels. Like the real networks it matches
texture; on textureless or mirror-like surfaces it has nothing to match and fails.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

from srde_fusion.errors import BackboneError

__all__ = ["StandinConfig", "StandinStereo", "StandinOutputs", "STANDIN_SIZES", "build_standin",
           "SoftCensus", "row_correlations"]

FEATURE_STRIDE = 4  # features, volume and refinement run at 1/4 resolution
INPUT_MULTIPLE = 32  # the hourglass halves 1/4-resolution maps twice more (with margin)
_DIRECT_INIT_GAIN = 5.0  # initial softmax sharpness of the direct correlation path
# Soft census: tanh(difference / softness) of grey values in -1..1; 0.04 is about five
# 8-bit grey levels, above sensor noise, so flat regions give weak, not random, bits.
_CENSUS_SOFTNESS = 0.04


@dataclass(frozen=True)
class StandinConfig:
    """Architecture of the stand-in network, grouped by part.

    Attributes
    ----------
    feature_channels : int
        Feature extractor: channels of the 1/4-resolution matching features.
    max_disparity_px : int
        Cost volume: largest disparity at full resolution (a multiple of 8); the volume
        has ``max_disparity_px / 4`` levels.
    correlation_groups : int
        Cost volume: groups of the group-wise correlation (divides ``feature_channels``).
    volume_channels : int
        Aggregation: channels of the 2-D hourglass at 1/4 resolution (twice as many
        at 1/8 and 1/16).
    hidden_channels : int
        Refinement: channels of the recurrent state (and of the context).
    lookup_radius : int
        Refinement: volume levels looked up on each side of the current estimate.
    iterations : int
        Refinement: residual updates per forward pass.
    census_radius : int
        Census: half-size of the census window, at 1/4 and at full resolution
        (``(2 r + 1)^2 - 1`` comparisons).
    refine_channels : int
        Full-resolution step: channels of its CNN.
    refine_radius : int
        Full-resolution step: census costs at ``-r .. r`` pixels around the estimate.
    """

    feature_channels: int = 32
    max_disparity_px: int = 192
    correlation_groups: int = 2
    volume_channels: int = 48
    hidden_channels: int = 32
    lookup_radius: int = 3
    iterations: int = 3
    census_radius: int = 2
    refine_channels: int = 16
    refine_radius: int = 2

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not (isinstance(value, int) and value >= 1):
                raise BackboneError(
                    f"StandinConfig.{name}: expected an integer >= 1, got {value!r}"
                )
        if self.max_disparity_px % (2 * FEATURE_STRIDE):
            raise BackboneError(
                f"StandinConfig.max_disparity_px: expected a multiple of {2 * FEATURE_STRIDE}, "
                f"got {self.max_disparity_px}"
            )
        if self.feature_channels % self.correlation_groups:
            raise BackboneError(
                f"StandinConfig.correlation_groups: expected a divisor of feature_channels "
                f"({self.feature_channels}), got {self.correlation_groups}"
            )


#: Named sizes: ``"default"`` is the bundled model, ``"tiny"`` trains in seconds (tests).
STANDIN_SIZES: dict[str, StandinConfig] = {
    "default": StandinConfig(),
    "tiny": StandinConfig(feature_channels=16, max_disparity_px=64, correlation_groups=2,
                          volume_channels=16, hidden_channels=16, lookup_radius=2, iterations=2,
                          census_radius=1, refine_channels=8, refine_radius=1),
}


@dataclass(frozen=True)
class StandinOutputs:
    """Every disparity estimate of one forward pass (for training losses).

    Attributes
    ----------
    initial : torch.Tensor, (B, 1, H, W), float32, pixels
        Soft-argmin of the aggregated cost, upsampled bilinearly to full resolution.
    refined : tuple of torch.Tensor, each (B, 1, H, W), float32, pixels
        Convex-upsampled estimate after each refinement step, then the full-resolution
        step's estimate; the last one is the output.
    """

    initial: torch.Tensor
    refined: tuple[torch.Tensor, ...]


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1), nn.InstanceNorm2d(cout),
                         nn.ReLU(inplace=True))


class _ResBlock(nn.Module):
    def __init__(self, channels: int, dilation: int = 1, norm: bool = True) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(channels, channels, 3, 1, dilation, dilation=dilation)
        self.conv2 = nn.Conv2d(channels, channels, 3, 1, 1)
        # Instance norm in the feature CNN evens out exposure; the refinement's
        # inputs carry absolute scales (disparity, costs) that it must keep.
        self.norm1 = nn.InstanceNorm2d(channels) if norm else nn.Identity()
        self.norm2 = nn.InstanceNorm2d(channels) if norm else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.norm1(self.conv1(x)))
        return F.relu(x + self.norm2(self.conv2(y)))


class FeatureExtractor(nn.Module):
    """(B, 3, H, W) normalised image -> (B, C, H/4, W/4) features."""

    def __init__(self, *, out_channels: int) -> None:
        super().__init__()
        mid = max(out_channels // 2, 8)
        self.layers = nn.Sequential(
            _conv(3, mid, stride=2), _ResBlock(mid),
            _conv(mid, out_channels, stride=2), _ResBlock(out_channels),
            _ResBlock(out_channels, dilation=2),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layers(x)


def groupwise_correlation(left: torch.Tensor, right: torch.Tensor, levels: int,
                          groups: int) -> torch.Tensor:
    """Group-wise correlation volume (Guo et al., GwcNet).

    Parameters
    ----------
    left, right : torch.Tensor, (B, C, h, w)
        Feature maps.
    levels : int
        Disparity levels ``D`` (in feature pixels).
    groups : int
        Channel groups ``G``.

    Returns
    -------
    torch.Tensor, (B, G, D, h, w)
        Mean product of left features at x and right features at x - d; zero where
        x - d falls outside the image.
    """
    b, c, h, w = left.shape
    # Pad on the left so that every shift is a slice with constant bounds; negative
    # slice ends keep the exported ONNX graph valid for any width.
    right_pad = F.pad(right, (levels - 1, 0))
    left_groups = left.view(b, groups, c // groups, h, w)
    # One level at a time: the (B, C, D, h, w) products never exist at once.
    volume = [
        (left_groups * right_pad[..., levels - 1 - d:(-d or None)].view(b, groups, -1, h, w)
         ).mean(dim=2)
        for d in range(levels)
    ]
    return torch.stack(volume, dim=2)


class SoftCensus(nn.Module):
    """Soft census transform with a fixed convolution: one channel per neighbour.

    Channel ``k`` is ``tanh((I(p + o_k) - I(p)) / softness)`` over the ``(2 r + 1)^2 - 1``
    offsets ``o_k`` of the window (edge pixels replicated): about +-1 where a neighbour is
    clearly brighter or darker, near 0 in flat regions. The mean product of two such
    descriptors is one minus a soft, normalised Hamming distance.
    """

    def __init__(self, radius: int, softness: float = _CENSUS_SOFTNESS) -> None:
        super().__init__()
        k = 2 * radius + 1
        offsets = [(dy, dx) for dy in range(k) for dx in range(k) if (dy, dx) != (radius, radius)]
        weight = torch.zeros(len(offsets), 1, k, k)
        for i, (dy, dx) in enumerate(offsets):
            weight[i, 0, dy, dx] = 1.0
            weight[i, 0, radius, radius] = -1.0
        # fixed, not learned: a buffer outside the state dict (a constant in ONNX)
        self.register_buffer("weight", weight, persistent=False)
        self.radius = radius
        self.softness = softness

    @property
    def channels(self) -> int:
        """Number of comparisons, ``(2 r + 1)^2 - 1``."""
        return self.weight.shape[0]

    def forward(self, grey: torch.Tensor) -> torch.Tensor:
        """(B, 1, H, W) grey in -1..1 -> (B, K, H, W) soft census bits in -1..1."""
        r = self.radius
        diff = F.conv2d(F.pad(grey, (r, r, r, r), mode="replicate"), self.weight)
        return torch.tanh(diff * (1.0 / self.softness))


def row_correlations(left: torch.Tensor, right: torch.Tensor, x_px: torch.Tensor,
                     radius: int) -> torch.Tensor:
    """Mean product of left descriptors with right ones sampled along the row.

    For each offset ``o`` in ``-radius .. radius``: the channel mean of ``left`` times
    ``right`` interpolated linearly along the row at ``x_px - o``. The product is linear
    in the interpolated sample, so the products at the ``2 radius + 2`` whole columns
    around ``x_px`` are computed and interpolated instead of resampling the descriptors;
    each column is one gather of channel-last descriptor rows (one index per pixel, not
    one per channel: on a CPU about 3x faster, and far less memory, than resampling
    them with grid sampling or per-channel gathers).

    Parameters
    ----------
    left, right : torch.Tensor, (B, C, H, W)
    x_px : torch.Tensor, (B, 1, H, W), float32, column positions in pixels in ``right``
    radius : int

    Returns
    -------
    torch.Tensor, (B, 2 radius + 1, H, W)
        Channel ``k`` is the offset ``o = k - radius``; a column outside the row
        contributes zero.
    """
    b, c, h, w = left.shape
    left_last = left.permute(0, 2, 3, 1)  # (B, H, W, C)
    right_rows = right.permute(0, 2, 3, 1).reshape(-1, c)  # one row per pixel
    x = x_px[:, 0]  # (B, H, W)
    below = torch.floor(x)
    frac = x - below
    ones = torch.ones_like(x, dtype=torch.long)
    width = ones.sum(dim=2, keepdim=True)
    # flat index of each pixel's row start, (batch * H + row) * W, from cumulative sums
    row_start = ((torch.cumsum(ones, dim=0) - 1) * ones.sum(dim=1, keepdim=True)
                 + torch.cumsum(ones, dim=1) - 1) * width
    below_index = below.long()
    products = []  # whole columns floor(x) - radius .. floor(x) + radius + 1
    for k in range(-radius, radius + 2):
        column = below_index + k
        inside = ((column >= 0) & (column < width)).to(left.dtype)
        index = row_start + torch.minimum(column.clamp(min=0), width - 1)
        sampled = torch.index_select(right_rows, 0, index.reshape(-1)).view(b, h, w, c)
        products.append((left_last * sampled).mean(dim=3) * inside)
    # offset o samples x - o, between the whole columns floor(x) - o and floor(x) - o + 1
    costs = [(1.0 - frac) * products[radius - o] + frac * products[radius - o + 1]
             for o in range(-radius, radius + 1)]
    return torch.stack(costs, dim=1)


class FullResolutionStep(nn.Module):
    """Census costs around the upsampled disparity + left image -> refined disparity."""

    def __init__(self, *, channels: int, radius: int, max_disparity_px: int) -> None:
        super().__init__()
        c = channels
        self.radius = radius
        self.scale = 1.0 / max_disparity_px
        self.net = nn.Sequential(
            nn.Conv2d(2 * radius + 1 + 3 + 1, c, 3, padding=1), nn.LeakyReLU(0.1, inplace=True),
            nn.Conv2d(c, c, 3, padding=1), nn.LeakyReLU(0.1, inplace=True),
            nn.Conv2d(c, c, 3, padding=2, dilation=2), nn.LeakyReLU(0.1, inplace=True),
            nn.Conv2d(c, c, 3, padding=4, dilation=4), nn.LeakyReLU(0.1, inplace=True),
            nn.Conv2d(c, c, 3, padding=1), nn.LeakyReLU(0.1, inplace=True),
            nn.Conv2d(c, 1, 3, padding=1),
        )
        with torch.no_grad():  # start as the identity: the upsampled estimate
            self.net[-1].weight.mul_(0.01)
            self.net[-1].bias.zero_()

    def forward(self, image_left: torch.Tensor, census_left: torch.Tensor,
                census_right: torch.Tensor, disparity: torch.Tensor) -> torch.Tensor:
        """Refined (B, 1, H, W) disparity in pixels from the same-sized estimate."""
        # column index without shape arithmetic, so the export stays dynamic in width
        columns = torch.cumsum(torch.ones_like(disparity), dim=3) - 1.0
        costs = row_correlations(census_left, census_right, columns - disparity, self.radius)
        x = torch.cat([costs, image_left, disparity * self.scale], dim=1)
        return disparity + self.net(x)


class Hourglass2d(nn.Module):
    """Volume levels as channels + left features -> (B, V, h, w) state and (B, D, h, w) cost."""

    def __init__(self, *, in_channels: int, channels: int, levels: int) -> None:
        super().__init__()
        v = channels
        self.stem = nn.Sequential(nn.Conv2d(in_channels, v, 1), nn.ReLU(inplace=True),
                                  nn.Conv2d(v, v, 3, 1, 1), nn.ReLU(inplace=True))
        self.down1 = nn.Sequential(nn.Conv2d(v, 2 * v, 3, 2, 1), nn.ReLU(inplace=True),
                                   nn.Conv2d(2 * v, 2 * v, 3, 1, 1), nn.ReLU(inplace=True))
        self.down2 = nn.Sequential(nn.Conv2d(2 * v, 2 * v, 3, 2, 1), nn.ReLU(inplace=True),
                                   nn.Conv2d(2 * v, 2 * v, 3, 1, 2, dilation=2),
                                   nn.ReLU(inplace=True))
        self.up2 = nn.ConvTranspose2d(2 * v, 2 * v, 4, 2, 1)
        self.up1 = nn.ConvTranspose2d(2 * v, v, 4, 2, 1)
        self.out = nn.Sequential(nn.Conv2d(v, v, 3, 1, 1), nn.ReLU(inplace=True))
        self.cost = nn.Conv2d(v, levels, 3, 1, 1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x0 = self.stem(x)
        x1 = self.down1(x0)
        x2 = self.down2(x1)
        x1 = F.relu(x1 + self.up2(x2))
        x0 = self.out(F.relu(x0 + self.up1(x1)))
        return x0, self.cost(x0)


def volume_lookup(volume: torch.Tensor, disparity: torch.Tensor, radius: int) -> torch.Tensor:
    """Linear interpolation of a volume along disparity around the current estimate.

    Parameters
    ----------
    volume : torch.Tensor, (B, V, D, h, w)
    disparity : torch.Tensor, (B, 1, h, w), float32, feature pixels
    radius : int
        Offsets ``-radius .. radius`` around ``disparity``.

    Returns
    -------
    torch.Tensor, (B, V * (2 radius + 1), h, w)
        Zero where the sample falls outside ``[0, D - 1]``.
    """
    b, v, levels, h, w = volume.shape
    offsets = torch.arange(-radius, radius + 1, dtype=volume.dtype, device=volume.device)
    pos = disparity + offsets.view(1, -1, 1, 1)  # (B, O, h, w)
    below = torch.floor(pos)
    frac = pos - below
    samples = 0
    # Two gathers (the levels either side) instead of dense hat weights over all levels:
    # far cheaper per pixel; weights of levels outside [0, D - 1] are zeroed.
    for index, weight in ((below, 1.0 - frac), (below + 1.0, frac)):
        inside = ((index >= 0) & (index <= levels - 1)).to(volume.dtype)
        index = index.clamp(0, levels - 1).long().unsqueeze(1).expand(b, v, -1, h, w)
        samples = samples + torch.gather(volume, 2, index) * (weight * inside).unsqueeze(1)
    return samples.reshape(b, -1, h, w)


def softmax_channels(logits: torch.Tensor, dim: int = 1) -> torch.Tensor:
    """Softmax along a non-last axis, written out (onnxruntime's Softmax transposes then)."""
    e = torch.exp(logits - logits.amax(dim=dim, keepdim=True))
    return e / e.sum(dim=dim, keepdim=True)


class UpdateBlock(nn.Module):
    """Lookups + disparity + context + state -> new state, disparity update, upsampling mask."""

    def __init__(self, *, hidden_channels: int, lookup_channels: int) -> None:
        super().__init__()
        m = hidden_channels
        self.encode = nn.Sequential(nn.Conv2d(lookup_channels + 1, m, 1), nn.ReLU(inplace=True),
                                    nn.Conv2d(m, m, 3, padding=1), nn.ReLU(inplace=True))
        self.state = nn.Sequential(nn.Conv2d(3 * m, m, 3, padding=1), nn.ReLU(inplace=True),
                                   _ResBlock(m, dilation=2, norm=False),
                                   nn.Conv2d(m, m, 3, padding=1))
        self.delta = nn.Conv2d(m, 1, 3, padding=1)
        self.mask = nn.Sequential(nn.Conv2d(m, m, 3, padding=1), nn.ReLU(inplace=True),
                                  nn.Conv2d(m, 9 * FEATURE_STRIDE**2, 1))

    def forward(self, hidden: torch.Tensor, context: torch.Tensor, lookups: torch.Tensor,
                disparity_scaled: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        motion = self.encode(torch.cat([lookups, disparity_scaled], dim=1))
        hidden = torch.tanh(self.state(torch.cat([hidden, context, motion], dim=1)))
        return hidden, self.delta(hidden)

    def upsampling_mask(self, hidden: torch.Tensor) -> torch.Tensor:
        # RAFT scales the mask logits by 0.25 to balance the gradients.
        return 0.25 * self.mask(hidden)


def convex_upsample(disparity: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """RAFT's convex upsampling by 4: each fine pixel is a convex combination of 3x3 coarse.

    Parameters
    ----------
    disparity : torch.Tensor, (B, 1, h, w), float32, feature pixels
    mask : torch.Tensor, (B, 9 * 16, h, w)
        Logits of the combination weights.

    Returns
    -------
    torch.Tensor, (B, 1, 4 h, 4 w), float32, full-resolution pixels
    """
    b, _, h, w = disparity.shape
    r = FEATURE_STRIDE
    padded = F.pad(disparity * r, (1, 1, 1, 1), mode="replicate")
    # 9 shifted copies, sliced with constant (negative) ends so the export stays dynamic.
    neighbours = [padded[:, :, dy:(dy - 2) or None, dx:(dx - 2) or None]
                  for dy in range(3) for dx in range(3)]
    neighbours = torch.cat(neighbours, dim=1).unsqueeze(2)  # (B, 9, 1, h, w)
    weights = softmax_channels(mask.view(b, 9, r * r, h, w))  # (B, 9, 16, h, w)
    fine = (weights * neighbours).sum(dim=1)  # (B, 16, h, w)
    return F.pixel_shuffle(fine, r)  # (B, 1, 4h, 4w)


class StandinStereo(nn.Module):
    """The stand-in stereo network.

    Parameters
    ----------
    feature_channels, max_disparity_px, correlation_groups, volume_channels,
    hidden_channels, lookup_radius, iterations, census_radius, refine_channels,
    refine_radius : int
        Keyword-only, grouped by part as in :class:`StandinConfig`.

    Examples
    --------
    >>> import torch
    >>> net = StandinStereo(**asdict(STANDIN_SIZES["tiny"])).eval()
    >>> x = torch.zeros(1, 3, 64, 96)
    >>> net(x, x).shape
    torch.Size([1, 1, 64, 96])
    """

    def __init__(self, *,
                 # feature extractor
                 feature_channels: int = 32,
                 # cost volume
                 max_disparity_px: int = 192, correlation_groups: int = 2,
                 # aggregation
                 volume_channels: int = 48,
                 # refinement
                 hidden_channels: int = 32, lookup_radius: int = 3, iterations: int = 3,
                 # hand-made census costs and the full-resolution step
                 census_radius: int = 2, refine_channels: int = 16, refine_radius: int = 2
                 ) -> None:
        super().__init__()
        self.config = StandinConfig(
            feature_channels=feature_channels, max_disparity_px=max_disparity_px,
            correlation_groups=correlation_groups, volume_channels=volume_channels,
            hidden_channels=hidden_channels, lookup_radius=lookup_radius, iterations=iterations,
            census_radius=census_radius, refine_channels=refine_channels,
            refine_radius=refine_radius,
        )
        self.census = SoftCensus(census_radius)
        groups = correlation_groups + 1  # the learned groups and the census
        self.levels = max_disparity_px // FEATURE_STRIDE
        self.features = FeatureExtractor(out_channels=feature_channels)
        # a compressed copy of the left features guides the aggregation (edges, texture)
        self.guide = nn.Sequential(nn.Conv2d(feature_channels, hidden_channels, 1),
                                   nn.ReLU(inplace=True))
        self.context = nn.Sequential(_conv(feature_channels, hidden_channels),
                                     nn.Conv2d(hidden_channels, 2 * hidden_channels, 3, padding=1))
        self.hourglass = Hourglass2d(
            in_channels=groups * self.levels + hidden_channels,
            channels=volume_channels, levels=self.levels)
        # The hourglass mixes levels freely, so it must learn which input channel belongs
        # to which output level; a direct path, the same at every level (a weighted sum of
        # the groups), gives the cost a matching signal from the first step. Without it
        # training settled on a constant disparity.
        self.direct = nn.Conv3d(groups, 1, 1)
        with torch.no_grad():
            self.direct.weight.fill_(_DIRECT_INIT_GAIN / groups)
            self.direct.bias.zero_()
            self.hourglass.cost.weight.mul_(0.1)
        # lookups in the correlation (G + 1 channels) and the aggregated cost (1 channel)
        lookup_channels = (groups + 1) * (2 * lookup_radius + 1)
        self.update = UpdateBlock(hidden_channels=hidden_channels, lookup_channels=lookup_channels)
        self.full_resolution = FullResolutionStep(
            channels=refine_channels, radius=refine_radius, max_disparity_px=max_disparity_px)
        self.register_buffer("levels_px", torch.arange(self.levels, dtype=torch.float32),
                             persistent=False)

    def forward(self, left: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
        """Disparity of the left image.

        Parameters
        ----------
        left, right : torch.Tensor, (B, 3, H, W), float32, RGB in 0..255
            ``H`` and ``W`` multiples of 32.

        Returns
        -------
        torch.Tensor, (B, 1, H, W), float32, pixels
        """
        return self._run(left, right, every_step=False).refined[-1]

    def forward_all(self, left: torch.Tensor, right: torch.Tensor) -> StandinOutputs:
        """Every intermediate estimate, for training (same inputs as ``forward``)."""
        return self._run(left, right, every_step=True)

    def _run(self, left: torch.Tensor, right: torch.Tensor, *, every_step: bool
             ) -> StandinOutputs:
        cfg = self.config
        b = left.shape[0]
        # IGEV/RAFT normalisation: 0..255 -> -1..1
        both = torch.cat([left, right], dim=0) * (2.0 / 255.0) - 1.0
        feats = self.features(both)
        feat_left, feat_right = feats[:b], feats[b:]
        corr = groupwise_correlation(feat_left, feat_right, self.levels, cfg.correlation_groups)
        grey = both.mean(dim=1, keepdim=True)
        census_quarter = self.census(F.avg_pool2d(grey, FEATURE_STRIDE))
        corr = torch.cat([corr, groupwise_correlation(
            census_quarter[:b], census_quarter[b:], self.levels, 1)], dim=1)
        _, _, levels, h, w = corr.shape
        state, cost = self.hourglass(torch.cat(
            [corr.reshape(b, -1, h, w), self.guide(feat_left)], dim=1))
        cost = cost + self.direct(corr).squeeze(1)  # (B, D, h, w)

        prob = softmax_channels(cost)  # (B, D, h, w)
        disparity = (prob * self.levels_px.view(1, -1, 1, 1)).sum(dim=1, keepdim=True)
        initial = F.interpolate(disparity * FEATURE_STRIDE, scale_factor=FEATURE_STRIDE,
                                mode="bilinear", align_corners=False)

        volume = torch.cat([corr, cost.unsqueeze(1)], dim=1)  # (B, G + 1, D, h, w)
        hidden, context = torch.tanh(self.context(feat_left)).chunk(2, dim=1)
        context = F.relu(context)
        refined = []
        for step in range(cfg.iterations):
            disparity = disparity.detach()  # RAFT/IGEV: no gradient through the iterate
            lookups = volume_lookup(volume, disparity, cfg.lookup_radius)
            hidden, delta = self.update(hidden, context, lookups, disparity / self.levels)
            disparity = disparity + delta
            if every_step or step == cfg.iterations - 1:
                refined.append(convex_upsample(disparity, self.update.upsampling_mask(hidden)))
        census_full = self.census(grey)
        refined.append(self.full_resolution(
            both[:b], census_full[:b], census_full[b:], refined[-1].detach()))
        return StandinOutputs(initial=initial, refined=tuple(refined))


def build_standin(config: StandinConfig | str = "default") -> StandinStereo:
    """Build a freshly initialised stand-in network of a named size or a config.

    Parameters
    ----------
    config : StandinConfig or {"default", "tiny"}

    Returns
    -------
    StandinStereo
    """
    if isinstance(config, str):
        if config not in STANDIN_SIZES:
            raise BackboneError(
                f"size: expected one of {', '.join(STANDIN_SIZES)}, got {config!r}"
            )
        config = STANDIN_SIZES[config]
    return StandinStereo(**asdict(config))
