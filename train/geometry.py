"""Flow, Z-map and visibility between orthographic views, batched in PyTorch (paper Eq. 4 and Eq. 9).

Conventions (reference-facts.md): view space x right, y up, +z towards the camera; depth = view z (larger nearer),
-1 in the background; pixel centre x = ((col+0.5)/(W/2) - 1) * half_width, y = (1 - (row+0.5)/(H/2)) * half_height.
A point at view coordinates (x, y) of a view with half extents (hw, hh) is at grid_sample coordinates
(x/hw, -y/hh) with align_corners=False, which puts -1/+1 on the outer pixel edges exactly like the pixel centres above.
"""
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
