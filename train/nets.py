"""The three networks at three size tiers: `paper` (the reference sizes), `small`, and `tiny` (CPU real time).

Contracts (identical for every tier; the Rust side checks names, shapes and metadata, see src/neural/mod.rs):
  encoder  image [B,3,R,R] (sRGB*mask*2-1), fof [B,N,R,R], normals [B,3,R,R] -> features [B,C,R/4,R/4]
  decoder  features [B,C,h,w] (warped, zero outside the target mask), zmap [B,1,h,w] (source z, 0 outside),
           normals [B,3,h,w] (target view space), warped_rgb [B,3,h,w] (the geometric colour lookup at the flow,
           sRGB in [-1,1], 0 where unknown; train/geometry.py warp_rgb)
                                                                 -> rgb [B,3,h,w] (sRGB in [-1,1], no activation)
           The Z-map is expanded inside the graph into cos(n*pi*z), sin(n*pi*z), n = 1..16 (32 channels). The
           network predicts a RESIDUAL: rgb = warped_rgb + UNet(features, zmap encoding, normals, warped_rgb), with
           the last convolution zero-initialised, so an untrained decoder reproduces the geometric renderer's colour
           lookup and training only adds what the Z-map, normals and features say (occlusion, the back, shading).
           This is a deliberate deviation from the paper (whose decoder sees C + 32 + 3 = 291 channels and no
           photo): the tiny tier sees encoder features at 1/4 resolution only, and the skip keeps the photo's
           full-resolution texture. The paper tier's first convolution sees 256 + 32 + 3 + 3 = 294 channels.
  fof      image [B,3,R,R] plus, as chosen at training (`FofNet(inputs=...)`, exported as `r2human.fof_inputs`),
           body [B,N,R,R] (the fitted body's FOF, `body_fof.npy`: the reference's 35-channel input) and/or
           prior [B,N,R,R] (the silhouette-inflation prior, `prior_fof.npy`) -> fof [B,N,R,R] = base + UNet(all
           inputs), residual on one base input (`r2human.residual`: `body` or `prior`; no activation; last
           convolution zero-initialised, so the untrained net is its base). Without a base (`residual=None`) the
           UNet's output is the FOF (the paper's plain regression).
"""
import math

import torch
import torch.nn as nn
import torch.nn.functional as F

ZMAP_FREQUENCIES = 16

# Per tier: source resolution R, feature channels C, encoder kind/widths, decoder widths, FOF-net widths.
TIERS = {
    "tiny": dict(resolution=256, features=16, encoder="plain", encoder_widths=[16, 32], encoder_blocks=2,
                 decoder_widths=[16, 24, 32], fof_widths=[16, 24, 32, 48]),
    "small": dict(resolution=512, features=64, encoder="hrnet", encoder_widths=[16, 32, 64, 128], encoder_blocks=2,
                  decoder_widths=[32, 64, 128, 256], fof_widths=[32, 48, 64, 96, 128]),
    "paper": dict(resolution=512, features=256, encoder="hrnet", encoder_widths=[32, 64, 128, 256], encoder_blocks=4,
                  decoder_widths=[64, 128, 256, 512, 1024], fof_widths=[48, 96, 192, 384, 384]),
}


def conv(cin, cout, k=3, s=1):
    return nn.Conv2d(cin, cout, k, s, k // 2)


class ConvAct(nn.Sequential):
    def __init__(self, cin, cout, k=3, s=1):
        super().__init__(conv(cin, cout, k, s), nn.ReLU(inplace=True))


class BasicBlock(nn.Module):
    """Residual block of two 3x3 convolutions (HRNet's BasicBlock without batch norm, which exports cleanly and
    trains at batch size 1-4)."""

    def __init__(self, c):
        super().__init__()
        self.a = conv(c, c)
        self.b = conv(c, c)

    def forward(self, x):
        return F.relu(x + self.b(F.relu(self.a(x))))


class PlainEncoder(nn.Module):
    """tiny: two stride-2 convolutions to 1/4 resolution, residual blocks, 1x1 projection to C features."""

    def __init__(self, cin, widths, blocks, features):
        super().__init__()
        self.stem = nn.Sequential(ConvAct(cin, widths[0], 3, 2), ConvAct(widths[0], widths[1], 3, 2))
        self.blocks = nn.Sequential(*[BasicBlock(widths[1]) for _ in range(blocks)])
        self.head = conv(widths[1], features, 1)

    def forward(self, x):
        return self.head(self.blocks(self.stem(x)))


class HRNetEncoder(nn.Module):
    """HRNetV2-like: a stride-4 stem, then stages that add one lower-resolution branch each (widths w, 2w, 4w, 8w)
    with residual blocks and all-to-all exchange between branches; the HRNetV2 head upsamples every branch to 1/4,
    concatenates and projects with 1x1 convolutions to C features. `paper` uses widths 32/64/128/256 (W32)."""

    def __init__(self, cin, widths, blocks, features):
        super().__init__()
        self.stem = nn.Sequential(ConvAct(cin, 64, 3, 2), ConvAct(64, 64, 3, 2), ConvAct(64, widths[0], 3, 1))
        self.widths = widths
        self.stages = nn.ModuleList()
        self.transitions = nn.ModuleList()
        self.fuse = nn.ModuleList()
        for stage in range(1, len(widths) + 1):
            ws = widths[:stage]
            if stage > 1:  # new branch from the lowest one
                self.transitions.append(ConvAct(widths[stage - 2], widths[stage - 1], 3, 2))
            self.stages.append(nn.ModuleList([nn.Sequential(*[BasicBlock(w) for _ in range(blocks)]) for w in ws]))
            self.fuse.append(nn.ModuleList([nn.ModuleList([self._exchange(ws[j], ws[i], j - i) for j in range(stage)])
                                            for i in range(stage)]))
        total = sum(widths)
        self.head = nn.Sequential(ConvAct(total, total, 1), conv(total, features, 1))

    @staticmethod
    def _exchange(cin, cout, levels):
        if levels == 0:
            return nn.Identity()
        if levels > 0:  # from lower resolution: 1x1 then upsample (done in forward)
            return conv(cin, cout, 1)
        layers = []  # from higher resolution: stride-2 convolutions
        for k in range(-levels):
            last = k == -levels - 1
            layers.append(conv(cin, cout if last else cin, 3, 2))
            if not last:
                layers.append(nn.ReLU(inplace=True))
        return nn.Sequential(*layers)

    def forward(self, x):
        xs = [self.stem(x)]
        for s, (blocks, fuse) in enumerate(zip(self.stages, self.fuse)):
            if s > 0:
                xs.append(self.transitions[s - 1](xs[-1]))
            xs = [b(v) for b, v in zip(blocks, xs)]
            out = []
            for i in range(len(xs)):
                acc = 0
                for j in range(len(xs)):
                    y = fuse[i][j](xs[j])
                    if j > i:
                        y = F.interpolate(y, size=xs[i].shape[-2:], mode="bilinear", align_corners=False)
                    acc = acc + y
                out.append(F.relu(acc))
            xs = out
        size = xs[0].shape[-2:]
        cat = torch.cat([xs[0]] + [F.interpolate(v, size=size, mode="bilinear", align_corners=False) for v in xs[1:]], 1)
        return self.head(cat)


class UNet(nn.Module):
    """U-Net: level 0 at full resolution, each further level halves it (stride-2 max pool) and uses `widths[i]`
    channels; the up path uses transposed convolutions and skip concatenation like the reference decoder. `light`
    (tiny) uses one convolution per level, a 1x1 input projection and additive skips to save multiply-adds."""

    def __init__(self, cin, cout, widths, light=False):
        super().__init__()
        self.light = light
        self.stride = 2 ** (len(widths) - 1)
        if light:
            self.inc = ConvAct(cin, widths[0], 1)
            self.downs = nn.ModuleList([ConvAct(widths[i], widths[i + 1], 3, 2) for i in range(len(widths) - 1)])
            self.mid = ConvAct(widths[-1], widths[-1])
            self.ups = nn.ModuleList([nn.ConvTranspose2d(widths[i + 1], widths[i], 2, 2) for i in range(len(widths) - 1)])
            # Full resolution gets a pointwise merge only: the 3x3 context comes from the levels below.
            self.merge = nn.ModuleList([ConvAct(widths[i], widths[i], 1 if i == 0 else 3) for i in range(len(widths) - 1)])
        else:
            self.inc = nn.Sequential(ConvAct(cin, widths[0]), ConvAct(widths[0], widths[0]))
            self.downs = nn.ModuleList([nn.Sequential(nn.MaxPool2d(2), ConvAct(widths[i], widths[i + 1]),
                                                      ConvAct(widths[i + 1], widths[i + 1]))
                                        for i in range(len(widths) - 1)])
            self.mid = nn.Identity()
            self.ups = nn.ModuleList([nn.ConvTranspose2d(widths[i + 1], widths[i], 2, 2) for i in range(len(widths) - 1)])
            self.merge = nn.ModuleList([nn.Sequential(ConvAct(2 * widths[i], widths[i]), ConvAct(widths[i], widths[i]))
                                        for i in range(len(widths) - 1)])
        self.out = conv(widths[0], cout, 1)

    def forward(self, x):
        skips = [self.inc(x)]
        for d in self.downs:
            skips.append(d(skips[-1]))
        y = self.mid(skips.pop())
        for i in reversed(range(len(self.ups))):
            up = self.ups[i](y)
            skip = skips.pop()
            y = self.merge[i](up + skip if self.light else torch.cat([up, skip], 1))
        return self.out(y)


def zmap_encoding(z):
    """cos(n*pi*z), sin(n*pi*z) for n = 1..16: [B,1,H,W] -> [B,32,H,W]."""
    n = torch.arange(1, ZMAP_FREQUENCIES + 1, dtype=z.dtype, device=z.device).view(1, -1, 1, 1)
    a = z * n * math.pi
    return torch.cat([torch.cos(a), torch.sin(a)], 1)


class Encoder(nn.Module):
    def __init__(self, tier, fof_n):
        super().__init__()
        cfg = TIERS[tier]
        cin = 3 + fof_n + 3
        if cfg["encoder"] == "plain":
            self.net = PlainEncoder(cin, cfg["encoder_widths"], cfg["encoder_blocks"], cfg["features"])
        else:
            self.net = HRNetEncoder(cin, cfg["encoder_widths"], cfg["encoder_blocks"], cfg["features"])

    def forward(self, image, fof, normals):
        return self.net(torch.cat([image, fof, normals], 1))


class Decoder(nn.Module):
    """Residual Z-map decoder: `warped_rgb + UNet(...)` (see the module docs for why)."""

    def __init__(self, tier):
        super().__init__()
        cfg = TIERS[tier]
        self.net = UNet(cfg["features"] + 2 * ZMAP_FREQUENCIES + 3 + 3, 3, cfg["decoder_widths"],
                        light=tier == "tiny")
        # Zero residual at initialisation: the untrained decoder is the geometric lookup.
        nn.init.zeros_(self.net.out.weight)
        nn.init.zeros_(self.net.out.bias)
        self.stride = self.net.stride

    def forward(self, features, zmap, normals, warped_rgb):
        return warped_rgb + self.net(torch.cat([features, zmap_encoding(zmap), normals, warped_rgb], 1))


# The FOF net's FOF inputs (the photo is `image`), by ONNX input name.
FOF_INPUTS = ("body", "prior")


def parse_fof_inputs(text):
    """`[image,]body[,prior]` -> the tuple of input names, checked: `image` (the masked photo) first when present,
    then any of the FOF inputs once each; at least one input. Without `image` the net sees geometry only (the
    body FOF and/or the inflation prior, whose empty columns carry the silhouette): what it learns then does not
    depend on how synthetic textures look."""
    names = tuple(t.strip() for t in text.split(",") if t.strip())
    fofs = names[1:] if names[:1] == ("image",) else names
    if not names or len(set(names)) != len(names) or any(n not in FOF_INPUTS for n in fofs):
        raise ValueError(f"FOF net inputs {text!r}: give `image` first (optional), then any of "
                         f"{', '.join(FOF_INPUTS)} once each (e.g. image,body,prior or body,prior)")
    return names


class FofNet(nn.Module):
    """Photo and/or FOF priors -> N FOF-X coefficients.

    `inputs` names the inputs in order: `image` (optional) then any of `body` (the fitted body's FOF, the reference's input) and
    `prior` (the silhouette-inflation prior). With `residual` set to one of the FOF inputs the net is RESIDUAL on it,
    like the decoder on the colour lookup: fof = base + UNet(all inputs) with the last convolution zero-initialised,
    so an untrained net returns its base exactly and training only adds what the photo says. `residual=None` is the
    paper's plain regression. The legacy form `prior=True/False` is `inputs=("image", "prior"), residual="prior"` /
    `inputs=("image",), residual=None` (checkpoints of earlier versions)."""

    def __init__(self, tier, fof_n, prior=None, inputs=None, residual="unset"):
        super().__init__()
        if inputs is None:
            inputs = ("image", "prior") if prior in (None, True) else ("image",)
        inputs = parse_fof_inputs(",".join(inputs))
        if residual == "unset":
            residual = "prior" if "prior" in inputs else ("body" if "body" in inputs else None)
        if residual is not None and (residual == "image" or residual not in inputs):
            raise ValueError(f"the residual base {residual!r} must be one of the FOF inputs {self.fofs(inputs)}")
        self.inputs, self.residual = inputs, residual
        # Kept for old callers: whether the net takes the inflation prior.
        self.prior = "prior" in inputs
        channels = 3 * ("image" in inputs) + fof_n * len(self.fofs(inputs))
        self.net = UNet(channels, fof_n, TIERS[tier]["fof_widths"], light=False)
        if residual is not None:
            nn.init.zeros_(self.net.out.weight)
            nn.init.zeros_(self.net.out.bias)
        self.stride = self.net.stride

    @staticmethod
    def fofs(inputs):
        """The FOF inputs among `inputs` (all but `image`)."""
        return tuple(n for n in inputs if n != "image")

    def forward(self, *tensors):
        if len(tensors) != len(self.inputs):
            raise ValueError(f"FofNet takes {self.inputs}, got {len(tensors)} tensors")
        out = self.net(torch.cat(tensors, 1))
        if self.residual is None:
            return out
        return tensors[self.inputs.index(self.residual)] + out


def fof_net_from_checkpoint(ck):
    """The FofNet a `fof.pt` describes (new checkpoints name `inputs` and `residual`; older ones only `prior`)."""
    if "inputs" in ck:
        return FofNet(ck["tier"], ck["fof_n"], inputs=tuple(ck["inputs"]), residual=ck.get("residual"))
    return FofNet(ck["tier"], ck["fof_n"], prior=ck.get("prior", False))


def count_parameters(m):
    return sum(p.numel() for p in m.parameters())
