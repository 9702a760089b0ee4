"""A tiny IGEV-style stereo network, the stand-in backbone of demos and tests.

It has the parts of IGEV-Stereo (Xu et al., CVPR 2023) at toy scale: a shared feature
CNN at 1/4 resolution, a group-wise correlation cost volume, a small 3-D hourglass that
regularises it into a geometry encoding volume, soft-argmin for an initial disparity, a
convolutional GRU that refines the disparity from lookups into that volume around the
current estimate, and RAFT's convex upsampling to full resolution.

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

__all__ = ["StandinConfig", "StandinStereo", "StandinOutputs", "STANDIN_SIZES", "build_standin"]

FEATURE_STRIDE = 4  # features, volume and refinement run at 1/4 resolution
INPUT_MULTIPLE = 32  # the hourglass halves 1/4-resolution maps twice more (with margin)


@dataclass(frozen=True)
class StandinConfig:
    """Architecture of the stand-in network, grouped by part.

    Attributes
    ----------
    feature_channels : int
        Feature extractor: channels of the 1/4-resolution matching features.
    max_disparity_px : int
        Cost volume: largest disparity at full resolution (a multiple of 4); the volume
        has ``max_disparity_px / 4`` levels.
    correlation_groups : int
        Cost volume: groups of the group-wise correlation (divides ``feature_channels``).
    volume_channels : int
        Aggregation: channels of the 3-D hourglass.
    hidden_channels : int
        Refinement: channels of the convolutional GRU state (and of the context).
    lookup_radius : int
        Refinement: volume levels looked up on each side of the current estimate.
    iterations : int
        Refinement: GRU updates per forward pass.
    """

    feature_channels: int = 32
    max_disparity_px: int = 192
    correlation_groups: int = 8
    volume_channels: int = 8
    hidden_channels: int = 32
    lookup_radius: int = 3
    iterations: int = 4

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
    "tiny": StandinConfig(feature_channels=16, max_disparity_px=64, correlation_groups=4,
                          volume_channels=4, hidden_channels=16, lookup_radius=2, iterations=2),
}


@dataclass(frozen=True)
class StandinOutputs:
    """Every disparity estimate of one forward pass (for training losses).

    Attributes
    ----------
    initial : torch.Tensor, (B, 1, H, W), float32, pixels
        Soft-argmin of the aggregated volume, upsampled bilinearly to full resolution.
    refined : tuple of torch.Tensor, each (B, 1, H, W), float32, pixels
        Convex-upsampled estimate after each GRU update; the last one is the output.
    """

    initial: torch.Tensor
    refined: tuple[torch.Tensor, ...]


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1), nn.InstanceNorm2d(cout),
                         nn.ReLU(inplace=True))


class _ResBlock(nn.Module):
    def __init__(self, channels: int, dilation: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(channels, channels, 3, 1, dilation, dilation=dilation)
        self.conv2 = nn.Conv2d(channels, channels, 3, 1, 1)
        self.norm1 = nn.InstanceNorm2d(channels)
        self.norm2 = nn.InstanceNorm2d(channels)

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
    shifted = torch.stack(
        [right_pad[..., levels - 1 - d:(-d or None)] for d in range(levels)], dim=2
    )  # (B, C, D, h, w)
    products = (left.unsqueeze(2) * shifted).view(b, groups, c // groups, levels, h, w)
    return products.sum(dim=2) * (groups / c)


class Hourglass3d(nn.Module):
    """(B, G, D, h, w) correlation -> (B, V, D, h, w) geometry volume and (B, D, h, w) cost."""

    def __init__(self, *, in_channels: int, channels: int) -> None:
        super().__init__()
        v = channels
        self.stem = nn.Sequential(nn.Conv3d(in_channels, v, 3, 1, 1), nn.ReLU(inplace=True))
        self.down = nn.Sequential(nn.Conv3d(v, 2 * v, 3, 2, 1), nn.ReLU(inplace=True),
                                  nn.Conv3d(2 * v, 2 * v, 3, 1, 1), nn.ReLU(inplace=True))
        self.up = nn.ConvTranspose3d(2 * v, v, 4, 2, 1)
        self.cost = nn.Conv3d(v, 1, 3, 1, 1)

    def forward(self, corr: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = self.stem(corr)
        x = F.relu(x + self.up(self.down(x)))
        return x, self.cost(x).squeeze(1)


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
    grid = torch.arange(levels, dtype=volume.dtype, device=volume.device)
    # (B, O, 1, h, w) sample positions against (1, 1, D, 1, 1) levels -> hat weights.
    # Dense weights instead of grid_sample keep the graph to elementwise ops and einsum.
    pos = disparity.unsqueeze(1) + offsets.view(1, -1, 1, 1, 1)
    weights = F.relu(1.0 - (pos - grid.view(1, 1, -1, 1, 1)).abs())
    samples = torch.einsum("bodhw,bvdhw->bvohw", weights, volume)
    return samples.reshape(b, -1, h, w)


class ConvGRU(nn.Module):
    """Convolutional GRU cell (as in RAFT)."""

    def __init__(self, *, hidden_channels: int, input_channels: int) -> None:
        super().__init__()
        total = hidden_channels + input_channels
        self.convz = nn.Conv2d(total, hidden_channels, 3, padding=1)
        self.convr = nn.Conv2d(total, hidden_channels, 3, padding=1)
        self.convq = nn.Conv2d(total, hidden_channels, 3, padding=1)

    def forward(self, h: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        hx = torch.cat([h, x], dim=1)
        z = torch.sigmoid(self.convz(hx))
        r = torch.sigmoid(self.convr(hx))
        q = torch.tanh(self.convq(torch.cat([r * h, x], dim=1)))
        return (1 - z) * h + z * q


class UpdateBlock(nn.Module):
    """Lookups + disparity + context -> GRU -> disparity update and upsampling mask."""

    def __init__(self, *, hidden_channels: int, lookup_channels: int) -> None:
        super().__init__()
        m = hidden_channels
        self.encode_lookup = nn.Sequential(nn.Conv2d(lookup_channels, m, 1), nn.ReLU(inplace=True))
        self.encode_disp = nn.Sequential(nn.Conv2d(1, m // 2, 7, padding=3), nn.ReLU(inplace=True))
        self.encode = nn.Sequential(nn.Conv2d(m + m // 2, m - 1, 3, padding=1),
                                    nn.ReLU(inplace=True))
        self.gru = ConvGRU(hidden_channels=m, input_channels=m + m)
        self.delta = nn.Sequential(nn.Conv2d(m, m, 3, padding=1), nn.ReLU(inplace=True),
                                   nn.Conv2d(m, 1, 3, padding=1))
        self.mask = nn.Sequential(nn.Conv2d(m, m, 3, padding=1), nn.ReLU(inplace=True),
                                  nn.Conv2d(m, 9 * FEATURE_STRIDE**2, 1))

    def forward(self, hidden: torch.Tensor, context: torch.Tensor, lookups: torch.Tensor,
                disparity: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        motion = self.encode(torch.cat([self.encode_lookup(lookups),
                                        self.encode_disp(disparity)], dim=1))
        motion = torch.cat([motion, disparity], dim=1)
        hidden = self.gru(hidden, torch.cat([motion, context], dim=1))
        # RAFT scales the mask logits by 0.25 to balance the gradients.
        return hidden, self.delta(hidden), 0.25 * self.mask(hidden)


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
    weights = torch.softmax(mask.view(b, 9, r * r, h, w), dim=1)  # (B, 9, 16, h, w)
    fine = (weights * neighbours).sum(dim=1)  # (B, 16, h, w)
    return F.pixel_shuffle(fine, r)  # (B, 1, 4h, 4w)


class StandinStereo(nn.Module):
    """The stand-in stereo network.

    Parameters
    ----------
    feature_channels, max_disparity_px, correlation_groups, volume_channels,
    hidden_channels, lookup_radius, iterations : int
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
                 max_disparity_px: int = 192, correlation_groups: int = 8,
                 # aggregation
                 volume_channels: int = 8,
                 # refinement
                 hidden_channels: int = 32, lookup_radius: int = 3, iterations: int = 4) -> None:
        super().__init__()
        self.config = StandinConfig(
            feature_channels=feature_channels, max_disparity_px=max_disparity_px,
            correlation_groups=correlation_groups, volume_channels=volume_channels,
            hidden_channels=hidden_channels, lookup_radius=lookup_radius, iterations=iterations,
        )
        self.levels = max_disparity_px // FEATURE_STRIDE
        self.features = FeatureExtractor(out_channels=feature_channels)
        self.context = nn.Sequential(_conv(feature_channels, hidden_channels),
                                     nn.Conv2d(hidden_channels, 2 * hidden_channels, 3, padding=1))
        self.hourglass = Hourglass3d(in_channels=correlation_groups, channels=volume_channels)
        # lookups from the geometry volume, its correlation, and a 2x coarser copy of both
        lookup_channels = 2 * (volume_channels + correlation_groups) * (2 * lookup_radius + 1)
        self.update = UpdateBlock(hidden_channels=hidden_channels, lookup_channels=lookup_channels)
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
        return self.forward_all(left, right).refined[-1]

    def forward_all(self, left: torch.Tensor, right: torch.Tensor) -> StandinOutputs:
        """Every intermediate estimate, for training (same inputs as ``forward``)."""
        cfg = self.config
        # IGEV/RAFT normalisation: 0..255 -> -1..1
        both = torch.cat([left, right], dim=0) * (2.0 / 255.0) - 1.0
        feats = self.features(both)
        feat_left, feat_right = feats.chunk(2, dim=0)
        corr = groupwise_correlation(feat_left, feat_right, self.levels, cfg.correlation_groups)
        geometry, cost = self.hourglass(corr)

        prob = torch.softmax(cost, dim=1)  # (B, D, h, w)
        disparity = (prob * self.levels_px.view(1, -1, 1, 1)).sum(dim=1, keepdim=True)
        initial = F.interpolate(disparity * FEATURE_STRIDE, scale_factor=FEATURE_STRIDE,
                                mode="bilinear", align_corners=False)

        volume = torch.cat([geometry, corr], dim=1)  # (B, V + G, D, h, w)
        coarse = F.avg_pool3d(volume, (2, 1, 1), (2, 1, 1))  # halve the disparity axis
        hidden, context = torch.tanh(self.context(feat_left)).chunk(2, dim=1)
        context = F.relu(context)
        refined = []
        for _ in range(cfg.iterations):
            disparity = disparity.detach()  # RAFT/IGEV: no gradient through the iterate
            lookups = torch.cat([volume_lookup(volume, disparity, cfg.lookup_radius),
                                 volume_lookup(coarse, disparity * 0.5, cfg.lookup_radius)], dim=1)
            hidden, delta, mask = self.update(hidden, context, lookups, disparity)
            disparity = disparity + delta
            refined.append(convex_upsample(disparity, mask))
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
