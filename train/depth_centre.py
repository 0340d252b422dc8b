"""The body cube's depth convention in PyTorch, batched: the occupied volume's centroid at z = 0.

Mirrors `src/geometry/depth_centre.rs` (the one definition; see its module docs): `pipeline::compute_geometry`
places whatever geometry it chose by `centre_fof` — closed-form centroid of the FOF's occupancy, the depth range it
occupies (decoded at the 0.5 level, 256 depths), the cube-limited shift `centring_shift`, and the exact
coefficient-space shift `shift_matrix`. The FOF net's output is centred like that at inference, so the held-out
evaluation centres every prediction the same way before comparing it with the (centred) ground truth, and the
training loss may compare the centred output (`fit-fof` default) — what inference renders.

FOFs here are `[B, N, H, W]`; a column counts only where `mask` (`[B, 1, H, W]`, > 0.5) holds the person and its
occupancy can reach 0.5 (`Fof::is_empty_column`'s bound).
"""
import math

import torch

# Shifts smaller than this (z units) are not applied (depth_centre.rs MIN_SHIFT).
MIN_SHIFT = 1e-3
# Depths at which the occupied range is decoded (centre_fof: fof_depth_range(fof, 4, 256)).
RANGE_SAMPLES = 256
ISO_LEVEL = 0.5


def occupied_columns(fof, mask=None):
    """[B,1,H,W] bool: columns whose occupancy can reach 0.5 (bound 0.5 c_0 + sum |c_k| >= 0.5), inside `mask`."""
    bound = 0.5 * fof[:, :1] + fof[:, 1:].abs().sum(1, keepdim=True)
    cols = bound >= ISO_LEVEL
    if mask is not None:
        cols = cols & (mask > 0.5)
    return cols


def fof_centroid_z(fof, mask=None):
    """Centroid z of each item's occupied volume in closed form ([B]; NaN where it is empty): with s = (z+1)/2, a
    column's volume is c_0/2 and its first moment c_0/4 + sum_k c_k ((-1)^k - 1)/(k pi)^2."""
    n = fof.shape[1]
    k = torch.arange(n, dtype=fof.dtype, device=fof.device)
    w = torch.where(k % 2 == 1, -2.0 / (k * math.pi).clamp_min(1e-12) ** 2, torch.zeros_like(k))
    w[0] = 0.25
    cols = occupied_columns(fof, mask).to(fof.dtype)
    volume = (0.5 * fof[:, 0:1] * cols).sum((1, 2, 3))
    moment = (torch.einsum("bnhw,n->bhw", fof, w)[:, None] * cols).sum((1, 2, 3))
    s = moment / volume.clamp_min(1e-9)
    return torch.where(volume > 1e-9, 2.0 * s - 1.0, torch.full_like(s, float("nan")))


@torch.no_grad()
def fof_depth_range(fof, mask=None, samples=RANGE_SAMPLES):
    """[B] lo, [B] hi: the z range each item occupies at the 0.5 level (sample centres; NaN where nothing is)."""
    n = fof.shape[1]
    s = (torch.arange(samples, dtype=fof.dtype, device=fof.device) + 0.5) / samples
    k = torch.arange(1, n, dtype=fof.dtype, device=fof.device)
    basis = torch.cos(k[None, :] * math.pi * s[:, None])
    cols = occupied_columns(fof, mask)
    b = fof.shape[0]
    lo = torch.full((b,), float("nan"), dtype=fof.dtype, device=fof.device)
    hi = lo.clone()
    for i in range(b):
        c = fof[i].reshape(n, -1)[:, cols[i].reshape(-1)]  # [N, columns]
        if c.shape[1] == 0:
            continue
        occ = 0.5 * c[:1] + basis @ c[1:]  # [samples, columns]
        hit = (occ >= ISO_LEVEL).any(1).nonzero()
        if hit.numel():
            z = 2.0 * (hit[:, 0].to(fof.dtype) + 0.5) / samples - 1.0
            lo[i], hi[i] = z.min(), z.max()
    return lo, hi


def centring_shift(centroid, z_min, z_max):
    """The z shift putting `centroid` at 0, limited so that [z_min, z_max] stays inside [-1, 1]; a range wider than
    the cube is centred on its middle; 0 where any input is NaN (element-wise on [B] tensors)."""
    lowest, highest = -1.0 - z_min, 1.0 - z_max
    limited = torch.maximum(torch.minimum(-centroid, highest), lowest)
    dz = torch.where(lowest > highest, -0.5 * (z_min + z_max), limited)
    ok = torch.isfinite(centroid) & torch.isfinite(z_min) & torch.isfinite(z_max) & (z_min <= z_max)
    return torch.where(ok, dz, torch.zeros_like(dz))


def shift_generator(n, dtype=torch.float32, device=None):
    """[N,N]: the S of [`shift_matrix`], S_k = sum_{j, j+k odd} w_j c_j 4k / (pi (k^2 - j^2)) (w_0 = 1/2, else 1),
    row 0 zero. It does not depend on the shift, so a shift per column ([`shift_columns`]) needs it once."""
    k = torch.arange(n, dtype=dtype, device=device)
    kk, jj = k[:, None], k[None, :]
    odd = ((kk + jj) % 2 == 1) & (kk > 0)
    wj = torch.where(jj == 0, torch.full_like(jj, 0.5), torch.ones_like(jj))
    return torch.where(odd, wj * 4.0 * kk / (math.pi * (kk * kk - jj * jj)).masked_fill(~odd, 1.0),
                       torch.zeros_like(kk * jj))


def shift_matrix(n, dz):
    """[B,N,N]: the linear map of FOF coefficients under a depth shift dz ([B], z units), exact while nothing
    occupied would leave the cube (`centring_shift` never asks for that): c'_k = cos(k pi d) c_k - sin(k pi d) S_k, d = dz/2,
    S = [`shift_generator`] c; c'_0 = c_0."""
    k = torch.arange(n, dtype=dz.dtype, device=dz.device)
    s = shift_generator(n, dz.dtype, dz.device)  # [N,N]
    angle = k[None, :] * math.pi * (0.5 * dz[:, None])  # [B,N]
    m = torch.diag_embed(torch.cos(angle)) - torch.sin(angle)[:, :, None] * s[None]
    m[:, 0, :] = 0.0
    m[:, 0, 0] = 1.0
    return m


def shift_fof(fof, dz):
    """`fof` [B,N,H,W] moved by dz ([B]) along z (see [`shift_matrix`])."""
    return torch.einsum("bkj,bjhw->bkhw", shift_matrix(fof.shape[1], dz), fof)


def shift_columns(fof, dz):
    """`fof` [B,N,H,W] with every column moved by its own dz ([B,1,H,W], z units): [`shift_matrix`] per column,
    exact while the column's occupancy stays inside the cube."""
    n = fof.shape[1]
    k = torch.arange(n, dtype=fof.dtype, device=fof.device).view(1, -1, 1, 1)
    s = torch.einsum("kj,bjhw->bkhw", shift_generator(n, fof.dtype, fof.device), fof)
    angle = k * math.pi * (0.5 * dz)
    return torch.cos(angle) * fof - torch.sin(angle) * s


def centre_fof(fof, mask=None):
    """`fof` placed by the depth convention (as `depth_centre::centre_fof`) and the shift applied ([B]). The shift
    is differentiable through the centroid (the range limit is not)."""
    centroid = fof_centroid_z(fof, mask)
    lo, hi = fof_depth_range(fof.detach(), mask)
    dz = centring_shift(centroid, lo, hi)
    dz = torch.where(dz.abs() < MIN_SHIFT, torch.zeros_like(dz), dz)
    return shift_fof(fof, dz), dz
