"""The detector network (PyTorch; training and export only): a narrow single-class YOLO-style net.

Backbone of strided 3×3 convolutions and depthwise-separable residual blocks, a top-down
feature pyramid, and one head per stride (8, 16, 32). Each head cell predicts five raw
values ``[objectness logit, tx, ty, tw, th]`` decoded by :func:`decode_torch` (the same
formula as the numpy runtime, :func:`..detector.decode`). Fully convolutional: any input
whose sides are multiples of 32.
"""

import torch
from torch import nn
from torch.nn import functional as F

STRIDES = (8, 16, 32)
OUTPUTS = 5  # objectness logit, tx, ty, tw, th
PRIOR = 0.01  # initial objectness probability (focal-loss prior)
MAX_LOG_SIZE = 6.0  # |tw|, |th| are clamped to this when decoding


def conv_bn(cin: int, cout: int, k: int = 3, stride: int = 1, groups: int = 1, act: bool = True) -> nn.Sequential:
    layers = [nn.Conv2d(cin, cout, k, stride, k // 2, groups=groups, bias=False), nn.BatchNorm2d(cout)]
    if act:
        layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


class SeparableBlock(nn.Module):
    """Residual depthwise 3×3 → pointwise 1×1 block."""

    def __init__(self, ch: int):
        super().__init__()
        self.dw = conv_bn(ch, ch, 3, groups=ch, act=False)
        self.pw = conv_bn(ch, ch, 1)

    def forward(self, x):
        return x + self.pw(self.dw(x))


def stage(cin: int, cout: int, blocks: int) -> nn.Sequential:
    return nn.Sequential(conv_bn(cin, cout, 3, 2), *[SeparableBlock(cout) for _ in range(blocks)])


class Head(nn.Module):
    """Depthwise 3×3 + pointwise, then a 1×1 prediction layer."""

    def __init__(self, ch: int):
        super().__init__()
        self.body = nn.Sequential(conv_bn(ch, ch, 3, groups=ch, act=False), conv_bn(ch, ch, 1))
        self.pred = nn.Conv2d(ch, OUTPUTS, 1)
        nn.init.normal_(self.pred.weight, std=0.01)
        nn.init.zeros_(self.pred.bias)
        with torch.no_grad():
            self.pred.bias[0] = -torch.log(torch.tensor((1 - PRIOR) / PRIOR))

    def forward(self, x):
        return self.pred(self.body(x))


class UavDetectorNet(nn.Module):
    """Backbone (strides 2…32), FPN top-down path, heads at strides 8/16/32.

    ``width`` = channels of the stride-8 level; the stride-16/32 levels use 4/3 and 2× that.
    """

    def __init__(self, width: int = 48, blocks: tuple[int, int, int] = (2, 2, 2)):
        super().__init__()
        c3, c4, c5 = width, width * 4 // 3, width * 2
        self.stem = nn.Sequential(conv_bn(3, 16, 3, 2), conv_bn(16, 32, 3, 2), SeparableBlock(32))
        self.s3, self.s4, self.s5 = stage(32, c3, blocks[0]), stage(c3, c4, blocks[1]), stage(c4, c5, blocks[2])
        self.lat4, self.lat3 = conv_bn(c5, c4, 1), conv_bn(c4, c3, 1)
        self.fuse4, self.fuse3 = SeparableBlock(c4), SeparableBlock(c3)
        self.heads = nn.ModuleList([Head(c3), Head(c4), Head(c5)])

    def forward(self, x):
        """``x`` (N,3,H,W) float in [0,1] → raw head maps at strides 8, 16, 32, each (N,5,H/s,W/s)."""
        p3 = self.s3(self.stem(x))
        p4 = self.s4(p3)
        p5 = self.s5(p4)
        f4 = self.fuse4(p4 + F.interpolate(self.lat4(p5), scale_factor=2.0, mode="nearest"))
        f3 = self.fuse3(p3 + F.interpolate(self.lat3(f4), scale_factor=2.0, mode="nearest"))
        return self.heads[0](f3), self.heads[1](f4), self.heads[2](p5)


def decode_torch(raw: torch.Tensor, stride: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Objectness logits (N,H,W) and boxes (N,H,W,4) ``[x0,y0,x1,y1]`` in input pixels of one head.

    Cell (i, j) spans ``[j·s, (j+1)·s) × [i·s, (i+1)·s)``; centre ``((j+½+tx)·s, (i+½+ty)·s)``,
    size ``(s·e^tw, s·e^th)`` with ``tw, th`` clamped to ±:data:`MAX_LOG_SIZE`.
    """
    _, _, h, w = raw.shape
    gy, gx = torch.meshgrid(torch.arange(h, dtype=raw.dtype), torch.arange(w, dtype=raw.dtype), indexing="ij")
    cx = (gx + 0.5 + raw[:, 1]) * stride
    cy = (gy + 0.5 + raw[:, 2]) * stride
    bw = stride * torch.exp(raw[:, 3].clamp(-MAX_LOG_SIZE, MAX_LOG_SIZE))
    bh = stride * torch.exp(raw[:, 4].clamp(-MAX_LOG_SIZE, MAX_LOG_SIZE))
    boxes = torch.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], dim=-1)
    return raw[:, 0], boxes


class BoxVerifierNet(nn.Module):
    """The box verifier: crops (N,3,S,S) in [0,1] → one logit each (the box holds the UAV).

    Four stride-2 stages of 3×3 convolutions (``width``, 2×, 4×, 6× channels), global average
    pooling and a linear layer."""

    def __init__(self, width: int = 16):
        super().__init__()
        c = (width, 2 * width, 4 * width, 6 * width)
        self.features = nn.Sequential(
            conv_bn(3, c[0], 3, 2), conv_bn(c[0], c[0]),
            conv_bn(c[0], c[1], 3, 2), conv_bn(c[1], c[1]),
            conv_bn(c[1], c[2], 3, 2), conv_bn(c[2], c[2]),
            conv_bn(c[2], c[3], 3, 2), nn.AdaptiveAvgPool2d(1), nn.Flatten())
        self.logit = nn.Linear(c[3], 1)

    def forward(self, x):
        return self.logit(self.features(x))
