"""ESPNetv2 (Mehta et al., CVPR 2019) semantic segmentation, scale 2.0, Cityscapes classes, in PyTorch.

The network is written here from the paper and from the tensor names and
shapes of the released Cityscapes checkpoint (sacmehta/EdgeNets), so that the
checkpoint loads with ``strict=True``. In the paper's terms:

* Encoder (the ImageNet ESPNetv2 without its last level and classifier): a
  strided 3x3 convolution (level 1, 1/2), then three strided EESP units with
  input reinforcement (levels 2, 3 and 4: 1/4, 1/8, 1/16), levels 3 and 4
  followed by 3 and 7 EESP units. Widths at scale 2.0: 32, 128, 256, 512.
* EESP unit: reduce (grouped 1x1), split and transform (K = 4 depth-wise
  dilated 3x3 convolutions on the same reduced map), hierarchical feature
  fusion (each branch adds the previous one's output), merge (BN + PReLU over
  the concatenation, grouped 1x1 expansion), residual and PReLU.
* Decoder (the head this checkpoint holds, from the EdgeNets release):
  bottom-up, from 1/16 to 1/2, four efficient pyramid pooling blocks joined
  by gated skip connections from encoder levels 3, 2 and 1.

LoST-X reads the last encoder level (512 channels at 1/16: the "conv5" of
this net) and the decoder's 20 class scores (19 Cityscapes train ids and
background) at 1/2, turned into probabilities and area-pooled to the 1/16 grid.
"""

from __future__ import annotations

import math
import re
import zipfile
from collections.abc import Mapping
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..config import BackboneConfig
from ..errors import InputError, ModelError
from ..images import check_frame
from .base import BackboneInfo, SemanticFrame, file_md5

CITYSCAPES_CLASSES = (
    "road", "sidewalk", "building", "wall", "fence", "pole", "traffic light", "traffic sign", "vegetation",
    "terrain", "sky", "person", "rider", "car", "truck", "bus", "train", "motorcycle", "bicycle", "background",
)
DEFAULT_CLASSES = {"road": ("road",), "building": ("building",), "vegetation": ("vegetation",)}

WIDTHS = (32, 128, 256, 512)
"""Encoder widths of levels 1-4 at scale 2.0."""
REPEATS = (3, 7)
"""EESP units after the strided units of levels 3 and 4."""
BRANCHES = 4
"""K: parallel dilated branches of every EESP unit."""
RECEPTIVE_LIMITS = (13, 11, 9, 7)
"""Largest effective kernel of an EESP branch: in the strided units of levels 2 and 3, in level 3's units
and level 4's strided unit, in level 4's units."""
DECODER_WIDTHS = (64, 48, 32)
PYRAMID_WIDTH = 10
PYRAMID_SCALES = (2.0, 1.5, 1.0, 0.5, 0.1)
REINFORCEMENT_WIDTH = 3

INPUT_SIZE = (768, 384)
"""(width, height) every frame is resized to. Three quarters of the 1024 x 512 training resolution: the same
day labels on RobotCar, far better night labels, less than half the time (docs/backbones.md)."""
HINT = "pass the ESPNetv2 Cityscapes weights with --model PATH"
FEATURE_TENSOR = "base_net.level4"
"""The module whose output LoST-X reads: the last encoder level."""
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class ConvBNAct(nn.Module):
    """Convolution (same padding, no bias), batch norm, PReLU."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int = 1, groups: int = 1) -> None:
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, kernel, stride, padding=kernel // 2, groups=groups, bias=False)
        self.bn = nn.BatchNorm2d(cout)
        self.act = nn.PReLU(cout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.bn(self.conv(x)))


class ConvBN(nn.Module):
    """Convolution (same padding, no bias) and batch norm, no activation."""

    def __init__(self, cin: int, cout: int, kernel: int, groups: int = 1) -> None:
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, kernel, padding=kernel // 2, groups=groups, bias=False)
        self.bn = nn.BatchNorm2d(cout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.bn(self.conv(x))


class BNAct(nn.Module):
    """Batch norm and PReLU."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.bn = nn.BatchNorm2d(channels)
        self.act = nn.PReLU(channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.bn(x))


class DilatedDepthwise(nn.Module):
    """One EESP branch: a depth-wise 3x3 convolution with dilation ``rate`` (padding keeps the size)."""

    def __init__(self, channels: int, rate: int, stride: int) -> None:
        super().__init__()
        self.conv = nn.Conv2d(channels, channels, 3, stride, padding=rate, dilation=rate, groups=channels, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(x)


def branch_rates(branches: int, receptive_limit: int) -> tuple[int, ...]:
    """Dilation rates of an EESP unit's branches, in fusion order.

    Branch k (0-based) would use rate k + 1 (an effective 3x3 kernel of
    2k + 3 pixels); where that exceeds the level's receptive limit it falls
    back to rate 1. Ascending order puts the undilated branches first, so
    hierarchical fusion only adds growing receptive fields.
    """
    return tuple(sorted(k + 1 if 2 * k + 3 <= receptive_limit else 1 for k in range(branches)))


class EESP(nn.Module):
    """Extremely Efficient Spatial Pyramid unit of depth-wise dilated convolutions (paper Sec. 3.2, Fig. 1c).

    With ``stride=2`` it is the strided unit inside :class:`StridedEESP`, which
    returns the merged maps before the residual and activation. That unit's
    ``module_act`` is in the checkpoint but unused: :class:`StridedEESP`
    activates only after fusing its branches.
    """

    def __init__(self, cin: int, cout: int, receptive_limit: int, stride: int = 1) -> None:
        super().__init__()
        if cout % BRANCHES:
            raise ValueError(f"EESP width {cout} is not a multiple of {BRANCHES} branches")
        reduced = cout // BRANCHES
        self.stride = stride
        self.proj_1x1 = ConvBNAct(cin, reduced, 1, groups=BRANCHES)
        self.spp_dw = nn.ModuleList(
            DilatedDepthwise(reduced, rate, stride) for rate in branch_rates(BRANCHES, receptive_limit)
        )
        self.br_after_cat = BNAct(cout)
        self.conv_1x1_exp = ConvBN(cout, cout, 1, groups=BRANCHES)
        self.module_act = nn.PReLU(cout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        reduced = self.proj_1x1(x)
        fused = [self.spp_dw[0](reduced)]
        for branch in self.spp_dw[1:]:
            # Hierarchical feature fusion: summing the smaller receptive fields in removes gridding artefacts.
            fused.append(branch(reduced) + fused[-1])
        merged = self.conv_1x1_exp(self.br_after_cat(torch.cat(fused, dim=1)))
        if self.stride > 1:
            return merged
        if merged.shape == x.shape:
            merged = merged + x
        return self.module_act(merged)


class StridedEESP(nn.Module):
    """Down-sampling by 2 (paper Fig. 1d): a strided EESP unit beside a 3x3 average pool, concatenated
    (pool first), plus input reinforcement: the input image, average-pooled to this resolution,
    through a 3x3 and a 1x1 convolution, added before the PReLU."""

    def __init__(self, cin: int, cout: int, receptive_limit: int) -> None:
        super().__init__()
        self.eesp = EESP(cin, cout - cin, receptive_limit, stride=2)
        self.inp_reinf = nn.Sequential(
            ConvBNAct(3, REINFORCEMENT_WIDTH, 3),
            ConvBN(REINFORCEMENT_WIDTH, cout, 1),
        )
        self.act = nn.PReLU(cout)

    def forward(self, x: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
        pooled = halve(x)
        out = torch.cat([pooled, self.eesp(x)], dim=1)
        return self.act(out + self.inp_reinf(image))


def halve(x: torch.Tensor) -> torch.Tensor:
    """3x3 average pool with stride 2 (zero padding counts): the network's down-sampling of maps and image."""
    return F.avg_pool2d(x, kernel_size=3, stride=2, padding=1)


class Encoder(nn.Module):
    """ESPNetv2 encoder, levels 1-4; returns each level's output (1/2, 1/4, 1/8, 1/16)."""

    def __init__(self) -> None:
        super().__init__()
        w1, w2, w3, w4 = WIDTHS
        limit2, limit3_0, limit3, limit4 = RECEPTIVE_LIMITS
        self.level1 = ConvBNAct(3, w1, 3, stride=2)
        self.level2_0 = StridedEESP(w1, w2, limit2)
        self.level3_0 = StridedEESP(w2, w3, limit3_0)
        self.level3 = nn.ModuleList(EESP(w3, w3, limit3) for _ in range(REPEATS[0]))
        # The strided unit of level 4 shares level 3's receptive limit.
        self.level4_0 = StridedEESP(w3, w4, limit3)
        self.level4 = nn.ModuleList(EESP(w4, w4, limit4) for _ in range(REPEATS[1]))

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, ...]:
        l1 = self.level1(image)
        image_4 = halve(halve(image))
        l2 = self.level2_0(l1, image_4)
        image_8 = halve(image_4)
        l3 = self.level3_0(l2, image_8)
        for unit in self.level3:
            l3 = unit(l3)
        l4 = self.level4_0(l3, halve(image_8))
        for unit in self.level4:
            l4 = unit(l4)
        return l1, l2, l3, l4


class SequentialConvBNAct(nn.Module):
    """:class:`ConvBNAct` as the decoder's checkpoint stores it (a Sequential named ``cbr``)."""

    def __init__(self, cin: int, cout: int, kernel: int, groups: int = 1) -> None:
        super().__init__()
        self.cbr = nn.Sequential(
            nn.Conv2d(cin, cout, kernel, padding=kernel // 2, groups=groups, bias=False),
            nn.BatchNorm2d(cout),
            nn.PReLU(cout),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.cbr(x)


class SequentialBNAct(nn.Module):
    """:class:`BNAct` as the decoder's checkpoint stores it (a Sequential named ``br``)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.br = nn.Sequential(nn.BatchNorm2d(channels), nn.PReLU(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.br(x)


class ChannelShuffle(nn.Module):
    """Interleave ``groups`` equal channel groups: channel c of group g moves to position c * groups + g."""

    def __init__(self, groups: int) -> None:
        super().__init__()
        self.groups = groups

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, c, h, w = x.shape
        return x.view(n, self.groups, c // self.groups, h, w).transpose(1, 2).reshape(n, c, h, w)


class PyramidPool(nn.Module):
    """Efficient pyramid pooling: project to a few channels, filter them depth-wise at five scales
    (2, 1.5, 1, 0.5 and 0.1 times the map, at least 5 x 5), and merge the scales of each channel with a
    grouped 3x3 convolution (after a shuffle puts a channel's five scales side by side), then a 1x1.

    The last block (``final``) ends in that 1x1 convolution with a bias: the class logits.
    """

    def __init__(self, cin: int, cout: int, final: bool = False) -> None:
        super().__init__()
        width, n = PYRAMID_WIDTH, len(PYRAMID_SCALES)
        self.projection_layer = SequentialConvBNAct(cin, width, 1)
        self.stages = nn.ModuleList(
            nn.Conv2d(width, width, 3, padding=1, groups=width, bias=False) for _ in PYRAMID_SCALES
        )
        self.merge_layer = nn.Sequential(
            SequentialBNAct(width * n),
            ChannelShuffle(n),
            SequentialConvBNAct(width * n, width, 3, groups=width),
            nn.Conv2d(width, cout, 1, bias=final),
        )
        self.br = None if final else SequentialBNAct(cout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.projection_layer(x)
        h, w = x.shape[2:]
        scaled = []
        for scale, stage in zip(PYRAMID_SCALES, self.stages):
            size = (max(math.ceil(h * scale), 5), max(math.ceil(w * scale), 5))
            if scale > 1.0:
                y = F.adaptive_avg_pool2d(stage(_resize(x, size)), (h, w))
            elif scale < 1.0:
                y = _resize(stage(F.adaptive_avg_pool2d(x, size)), (h, w))
            else:
                y = stage(x)
            scaled.append(y)
        out = self.merge_layer(torch.cat(scaled, dim=1))
        return out if self.br is None else self.br(out)


def _resize(x: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    return F.interpolate(x, size=size, mode="bilinear", align_corners=True)


class GatedSkip(nn.Module):
    """Skip connection from an encoder level into the decoder: a grouped 3x3 convolution to the decoder's
    width, scaled channel by channel by a sigmoid gate computed from the globally pooled encoder map."""

    def __init__(self, cin: int, cout: int) -> None:
        super().__init__()
        self.wt_layer = nn.Sequential(nn.AdaptiveAvgPool2d(1), nn.Conv2d(cin, cout, 1, bias=False), nn.Sigmoid())
        self.expansion_layer = SequentialConvBNAct(cin, cout, 3, groups=math.gcd(cin, cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.expansion_layer(x) * self.wt_layer(x)


class ESPNetv2Segmentation(nn.Module):
    """The whole network. ``forward`` returns (features, logits): the last encoder level
    (512 x H/16 x W/16) and the class logits at half the input resolution (20 x H/2 x W/2)."""

    def __init__(self, n_classes: int = len(CITYSCAPES_CLASSES)) -> None:
        super().__init__()
        _, w2, w3, w4 = WIDTHS
        d1, d2, d3 = DECODER_WIDTHS
        self.base_net = Encoder()
        self.bu_dec_l1 = PyramidPool(w4, d1)
        self.bu_dec_l2 = PyramidPool(d1, d2)
        self.bu_dec_l3 = PyramidPool(d2, d3)
        self.bu_dec_l4 = PyramidPool(d3, n_classes, final=True)
        self.merge_enc_dec_l2 = GatedSkip(w3, d1)
        self.merge_enc_dec_l3 = GatedSkip(w2, d2)
        self.merge_enc_dec_l4 = GatedSkip(WIDTHS[0], d3)
        self.bu_br_l2 = nn.Sequential(nn.BatchNorm2d(d1), nn.PReLU(d1))
        self.bu_br_l3 = nn.Sequential(nn.BatchNorm2d(d2), nn.PReLU(d2))
        self.bu_br_l4 = nn.Sequential(nn.BatchNorm2d(d3), nn.PReLU(d3))

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        l1, l2, l3, l4 = self.base_net(image)
        out = self.bu_dec_l1(l4)
        steps = (
            (l3, self.merge_enc_dec_l2, self.bu_br_l2, self.bu_dec_l2),
            (l2, self.merge_enc_dec_l3, self.bu_br_l3, self.bu_dec_l3),
            (l1, self.merge_enc_dec_l4, self.bu_br_l4, self.bu_dec_l4),
        )
        for skip, merge, norm, decode in steps:
            # Upsampling to the skip's size is 2x wherever the input divides by 16.
            out = _resize(out, tuple(skip.shape[2:])) + merge(skip)
            out = decode(norm(out))
        return l4, out


def torch_device(name: str) -> torch.device:
    """``auto`` (a CUDA GPU where PyTorch sees one, else the CPU), ``cpu``, ``cuda`` or ``cuda:N`` as a torch
    device; an error if that GPU is not here."""
    if name == "auto":
        return torch.device("cuda", 0) if torch.cuda.is_available() else torch.device("cpu")
    if name == "cpu":
        return torch.device("cpu")
    match = re.fullmatch(r"cuda(?::(\d+))?", name)
    if match is None:
        raise InputError(f"device {name!r} is not one of auto, cpu, cuda, cuda:N")
    if not torch.cuda.is_available():
        raise ModelError(f"device {name!r} was asked for, but PyTorch {torch.__version__} sees no CUDA GPU here; "
                         "use --device cpu")
    index = int(match.group(1) or 0)
    if index >= torch.cuda.device_count():
        raise ModelError(f"device {name!r} was asked for, but only {torch.cuda.device_count()} CUDA GPU(s) are here")
    return torch.device("cuda", index)


def read_state_dict(path: Path) -> dict[str, torch.Tensor]:
    """The tensors of a checkpoint file, read without running any of its code (``weights_only``)."""
    if not path.is_file():
        raise ModelError(f"model file not found: {path}; {HINT}")
    try:
        loaded = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # torch.load reports bad files as EOFError, KeyError, RuntimeError, UnpicklingError...
        # ... whose words (a pickle opcode, an errno, advice about torch.load's arguments) mean nothing to a user.
        size = path.stat().st_size
        kind = "a damaged PyTorch archive" if zipfile.is_zipfile(path) else "not a PyTorch checkpoint"
        raise ModelError(f"{path} is {kind} ({size} bytes: truncated, or another kind of file); {HINT}") from None
    if isinstance(loaded, Mapping) and isinstance(loaded.get("state_dict"), Mapping):
        loaded = loaded["state_dict"]  # a training checkpoint wraps the weights
    if not isinstance(loaded, Mapping) or not all(isinstance(v, torch.Tensor) for v in loaded.values()):
        raise ModelError(f"{path} holds a {type(loaded).__name__}, not a state dict of tensors; {HINT}")
    # Weights saved from a DataParallel wrapper carry a "module." prefix.
    return {str(k).removeprefix("module."): v for k, v in loaded.items()}


def load_network(path: Path) -> ESPNetv2Segmentation:
    """The network with the checkpoint at ``path`` loaded strictly, in eval mode, on the CPU."""
    weights = read_state_dict(path)
    net = ESPNetv2Segmentation()
    expected = net.state_dict()
    missing = [k for k in expected if k not in weights]
    unexpected = [k for k in weights if k not in expected]
    if missing or unexpected:
        detail = []
        if missing:
            detail.append(f"{len(missing)} of its {len(expected)} tensors are missing (e.g. {missing[0]!r})")
        if unexpected:
            detail.append(f"{len(unexpected)} are unknown to it (e.g. {unexpected[0]!r})")
        raise ModelError(f"{path} is not the scale-2.0 Cityscapes ESPNetv2: {', '.join(detail)}; {HINT}")
    for key, tensor in expected.items():
        if weights[key].shape != tensor.shape:
            raise ModelError(f"{path} is not the scale-2.0 Cityscapes ESPNetv2: tensor {key!r} has shape "
                             f"{tuple(weights[key].shape)}, not {tuple(tensor.shape)}; {HINT}")
    net.load_state_dict(weights, strict=True)
    return net.eval()


class ESPNetv2Backbone:
    """ESPNetv2 (scale 2.0) trained on Cityscapes, run with PyTorch on the CPU or a CUDA GPU.

    Every frame is resized to 768 x 384 (:data:`INPUT_SIZE`); the features are
    the last encoder level, 512 channels on a 24 x 48 grid.
    """

    def __init__(self, config: BackboneConfig, path: Path) -> None:
        path = Path(path)
        self.device = torch_device(config.device)
        if config.threads < 1:
            raise InputError(f"threads must be at least 1, got {config.threads}")
        torch.set_num_threads(config.threads)
        # Channels-last runs the depth-wise convolutions about a third faster on the CPU, same results.
        self.net = load_network(path).to(self.device, memory_format=torch.channels_last)
        self._mean = torch.tensor(IMAGENET_MEAN, device=self.device).view(1, 3, 1, 1) * 255.0
        self._std = torch.tensor(IMAGENET_STD, device=self.device).view(1, 3, 1, 1) * 255.0
        width, height = INPUT_SIZE
        self.info = BackboneInfo(
            name="espnetv2-cityscapes",
            model_file=path.name,
            model_md5=file_md5(path),
            feature_dim=WIDTHS[-1],
            grid=(height // 16, width // 16),
            class_names=CITYSCAPES_CLASSES,
            default_classes=DEFAULT_CLASSES,
            feature_tensor=FEATURE_TENSOR,
            input_size=INPUT_SIZE,
        )

    def _run(self, image: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        image = check_frame(image)
        h, w = image.shape[:2]
        shrink = INPUT_SIZE[0] <= w and INPUT_SIZE[1] <= h
        resized = cv2.resize(image, INPUT_SIZE, interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
        x = torch.from_numpy(resized).to(self.device).permute(2, 0, 1)[None].float()
        x = ((x - self._mean) / self._std).contiguous(memory_format=torch.channels_last)
        with torch.inference_mode():
            return self.net(x)

    def __call__(self, image: np.ndarray) -> SemanticFrame:
        features, logits = self._run(image)
        with torch.inference_mode():
            # Averaging the half-resolution probabilities over each feature cell is an exact area resize.
            probs = F.adaptive_avg_pool2d(torch.softmax(logits, dim=1), tuple(features.shape[2:]))
            probs = probs / probs.sum(dim=1, keepdim=True)
            labels = logits[0].argmax(dim=0).to(torch.uint8)
        return SemanticFrame(
            features=features[0].contiguous().cpu().numpy(),
            probs=probs[0].contiguous().cpu().numpy(),
            label_map=labels.cpu().numpy(),
        )

    def segment(self, image: np.ndarray) -> np.ndarray:
        """Full-resolution label map (H x W, uint8 class ids) of a frame, for checking the segmentation."""
        _, logits = self._run(image)
        with torch.inference_mode():
            logits = F.interpolate(logits, size=image.shape[:2], mode="bilinear", align_corners=True)
            return logits[0].argmax(dim=0).to(torch.uint8).cpu().numpy()
