"""Flow, Z-map and visibility between orthographic views, batched in PyTorch (paper Eq. 4 and Eq. 9).

Conventions (reference-facts.md): view space x right, y up, +z towards the camera; depth = view z (larger nearer),
-1 in the background; pixel centre x = ((col+0.5)/(W/2) - 1) * half_width, y = (1 - (row+0.5)/(H/2)) * half_height.
A point at view coordinates (x, y) of a view with half extents (hw, hh) is at grid_sample coordinates
(x/hw, -y/hh) with align_corners=False, which puts -1/+1 on the outer pixel edges exactly like the pixel centres above.
"""
import math

import torch
import torch.nn.functional as F

VISIBILITY_LAMBDA = 0.02  # paper Eq. 9


def pixel_view_xy(h, w, half, device=None):
    """View-space x, y of every pixel centre: [B,H,W] each, for half extents `half` [B,2]."""
    cols = (torch.arange(w, device=device, dtype=torch.float32) + 0.5) / (w / 2) - 1
    rows = 1 - (torch.arange(h, device=device, dtype=torch.float32) + 0.5) / (h / 2)
    y, x = torch.meshgrid(rows, cols, indexing="ij")
    return x[None] * half[:, 0, None, None], y[None] * half[:, 1, None, None]


def transfer(depth_t, vfw_t, half_t, vfw_s, half_s):
    """For every pixel of target view t with depth, its position in view s (paper Eq. 4).

    Returns grid [B,H,W,2] (grid_sample coordinates into view s), z_s [B,1,H,W] (the Z-map: view-s z) and the
    target mask [B,1,H,W] (depth_t > -1); grid and z are zero outside the mask, as the reference masks them.
    """
    b, _, h, w = depth_t.shape
    x, y = pixel_view_xy(h, w, half_t, depth_t.device)
    p = torch.stack([x, y, depth_t[:, 0], torch.ones_like(x)], -1)  # [B,H,W,4] in view t
    world_from_t = torch.linalg.inv(vfw_t)
    m = vfw_s @ world_from_t  # view s from view t
    q = torch.einsum("bij,bhwj->bhwi", m, p)
    mask = (depth_t > -1).float()
    grid = torch.stack([q[..., 0] / half_s[:, 0, None, None], -q[..., 1] / half_s[:, 1, None, None]], -1)
    grid = grid * mask[:, 0, ..., None]
    z = q[..., 2][:, None] * mask
    return grid, z, mask


def warp(x, grid, mask, mode="bilinear"):
    """Samples x [B,C,h,w] at grid [B,H,W,2] (zeros outside) and zeroes pixels outside mask [B,1,H,W]."""
    return F.grid_sample(x, grid, mode=mode, padding_mode="zeros", align_corners=False) * mask


def visibility(depth_mv, vfw_mv, half_mv, depth_ref, vfw_ref, half_ref, lam=VISIBILITY_LAMBDA):
    """Paper Eq. 9 for every pixel v of the mv view: the point (v, D_mv) projected into the ref view has ref depth
    D_ref^mv; it is visible in both when |D_ref^mv - D_ref(v')| < lam * min(...), with depths shifted by +1 so they
    are positive distances behind the cube's far plane (the paper's depths are positive camera distances).

    Returns (grid into ref [B,H,W,2], visible mask [B,1,H,W])."""
    grid, z_ref, mask = transfer(depth_mv, vfw_mv, half_mv, vfw_ref, half_ref)
    d_ref = F.grid_sample(depth_ref, grid, mode="nearest", padding_mode="border", align_corners=False)
    inside = (grid.abs() <= 1).all(-1)[:, None]
    a, b = z_ref + 1, d_ref + 1
    vis = (torch.abs(a - b) < lam * torch.minimum(a, b)) & (d_ref > -1) & inside & (mask > 0)
    return grid, vis.float()


# --- The geometric colour lookup the residual decoder starts from (must match src/neural and src/pipeline/warp.rs) ---

# Smallest bilinear mask weight accepted as "the source sees colour here" (src/pipeline/warp.rs MIN_MASK_WEIGHT).
MIN_MASK_WEIGHT = 0.05


def srgb_to_linear(v):
    """sRGB-encoded [0,1] -> linear light (src/buffer.rs srgb_to_linear; clamps to [0,1])."""
    v = v.clamp(0, 1)
    return torch.where(v <= 0.04045, v / 12.92, ((v.clamp_min(0.04045) + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(v):
    """Linear light -> sRGB-encoded [0,1] (src/buffer.rs linear_to_srgb; clamps to [0,1])."""
    v = v.clamp(0, 1)
    return torch.where(v <= 0.0031308, v * 12.92, 1.055 * v.clamp_min(0.0031308) ** (1 / 2.4) - 0.055)


# How far a surface's unit normal must turn away from the source camera (the source-view z of the normal, negated)
# before it takes the back image alone (src/pipeline/warp.rs BACK_FACING_RAMP).
BACK_FACING_RAMP = 0.3


def source_axis(vfw_t, vfw_s):
    """The source camera's view +z axis (toward the source camera) in target view space [B,3]
    (src/pipeline/warp.rs `source_axis`)."""
    m = vfw_t @ torch.linalg.inv(vfw_s)  # view t from view s
    axis = m[:, :3, 2]
    return axis / axis.norm(dim=1, keepdim=True).clamp_min(1e-12)


def back_weight(normals, axis):
    """How much each target pixel takes the back image [B,1,H,W]: smoothstep(0, BACK_FACING_RAMP, -n . axis) of its
    target-view unit normal `normals` [B,3,H,W] (src/pipeline/warp.rs `back_weight`; 0 for non-finite normals)."""
    t = (-(normals * axis[:, :, None, None]).sum(1, keepdim=True) / BACK_FACING_RAMP).clamp(0, 1)
    t = torch.nan_to_num(t, nan=0.0)
    return t * t * (3 - 2 * t)


# Up to which |source-view z| of a surface's unit normal the side images blend in, and their blur as a fraction of
# the source image's width (src/pipeline/warp.rs SIDE_RAMP, SIDE_BLUR).
SIDE_RAMP = 0.5
SIDE_BLUR = 4.0 / 512.0


def side_weight(normals, axis):
    """How much each target pixel takes the side images [B,1,H,W]: 1 - smoothstep(0, SIDE_RAMP, |n . axis| / |n_z|)
    of its target-view unit normal `normals` [B,3,H,W]: how much the photo shrinks the surface against this view
    (src/pipeline/warp.rs `side_weight`; 0 for non-finite normals and surfaces seen edge-on here)."""
    ratio = (normals * axis[:, :, None, None]).sum(1, keepdim=True).abs() / (SIDE_RAMP * normals[:, 2:3].abs())
    t = ratio.clamp(0, 1)
    weight = 1 - t * t * (3 - 2 * t)
    return torch.where(torch.isfinite(weight), weight, torch.zeros_like(weight))


def box_radii(sigma, passes=3):
    """The box radii of the `image` crate's `fast_blur` for standard deviation `sigma` (Kovesi's boxes for a
    Gaussian, with the crate's rounding: src/pipeline/warp.rs blurs the side images with it)."""
    w_ideal = math.sqrt(12.0 * sigma * sigma / passes + 1.0)
    w_l = math.floor(w_ideal)
    if w_l % 2 == 0:
        w_l -= 1
    w_u = w_l + 2
    m = math.floor(0.25 * passes * (w_l + 3.0) - 3.0 * sigma * sigma / (w_l + 1.0) + 0.5)  # Rust's f32::round
    radii = []
    for i in range(passes):
        r = (max((w_l if i < m else w_u) - 1, 0)) // 2
        radii.append(r + 1 if r % 2 == 0 else r)
    return radii


@torch.no_grad()
def side_image(linear, mask):
    """The side image of `linear` [B,3,H,W] (premultiplied by `mask` [B,1,H,W]) as `warp::SideImages::of` makes it:
    blur(c m) / blur(m) by the `image` crate's `fast_blur` (box passes along rows, then columns, each with the edge
    pixel repeated, values kept in [0, 1]) of standard deviation SIDE_BLUR of the width, premultiplied again by the
    mask; 0 where the blurred mask is below 1e-6."""
    m = mask.clamp(0, 1)
    x = torch.cat([linear, m], 1)
    for r in box_radii(SIDE_BLUR * linear.shape[-1]):
        k = 2 * r + 1
        x = F.avg_pool2d(F.pad(x, (r, r, 0, 0), mode="replicate"), (1, k), stride=1).clamp(0, 1)
        x = F.avg_pool2d(F.pad(x, (0, 0, r, r), mode="replicate"), (k, 1), stride=1).clamp(0, 1)
    cover = x[:, 3:]
    ok = (cover > 1e-6) & (m > 0)
    return torch.where(ok, x[:, :3] / cover.clamp_min(1e-6) * m, torch.zeros_like(linear))


@torch.no_grad()
def warp_rgb(src_linear, src_mask, grid, mask, back_linear=None, back=None, side=None):
    """The decoder's `warped_rgb` input: the source photo looked up at the flow, exactly as the geometric renderer's
    `MirroredFront` lookup without the visibility test (src/pipeline/warp.rs `sample_masked`); with `back_linear`
    (the back image, like `src_linear`) and `back` ([B,1,h,w], `back_weight`) the photo and the back image looked up
    at the same point and blended by `back`, as `SourceColours::sample` does for `--fill back` (the neural
    renderer's lookup at run time, `pipeline::neural_back_lookup`). With `side` = (side_linear, side_back_linear,
    weight) (`side_image` of the photo and of the back image or None, and [B,1,h,w] `side_weight`) the same lookup
    in the side images is blended in by `weight`, as `SourceColours::sample` does with the input's side images.

    src_linear [B,3,H,W]: linear RGB premultiplied by src_mask [B,1,H,W]; grid [B,h,w,2] from `transfer`; mask
    [B,1,h,w] the target pixels with a flow. Per target pixel the four bilinear taps give sum(w*c) / sum(w*m) (taps
    outside the image count zero, like grid_sample's zero padding and the Rust loop's skipped taps), clamped to
    [0,1], sRGB-encoded and mapped to [-1,1]. Pixels whose mask weight sum(w*m) is below MIN_MASK_WEIGHT (the flow
    lands outside the source silhouette) and pixels outside `mask` are 0.
    Returns (rgb [B,3,h,w], known [B,1,h,w])."""
    den = F.grid_sample(src_mask.clamp(0, 1), grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    known = ((den >= MIN_MASK_WEIGHT) & (mask > 0)).float()

    def looked_up(photo, behind):
        linear = F.grid_sample(photo, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
        linear = linear / den.clamp_min(MIN_MASK_WEIGHT)
        if behind is not None and back is not None:
            far = F.grid_sample(behind, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
            linear = linear * (1 - back) + far / den.clamp_min(MIN_MASK_WEIGHT) * back
        return linear

    linear = looked_up(src_linear, back_linear)
    if side is not None:
        side_linear, side_back_linear, weight = side
        blurred = looked_up(side_linear, side_back_linear if back_linear is not None else None)
        linear = linear * (1 - weight) + blurred * weight
    colour = linear_to_srgb(linear.clamp(0, 1)) * 2 - 1
    return colour * known, known
