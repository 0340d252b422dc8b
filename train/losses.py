"""Training losses (paper Sec. "Training"): L = 100 * L_consistency + 1 * L_pixel + 0.5 * L_perceptual.

LPIPS needs ImageNet-pretrained VGG/AlexNet weights that no registry package ships, so the default perceptual term
is a documented substitute: (1 - SSIM) + image-gradient L1, both over the person. A user who has LPIPS weights passes
a TorchScript module (`--lpips FILE`, see train/README.md) that maps two [B,3,H,W] images in [-1,1] to distances.
"""
import torch
import torch.nn.functional as F

from .geometry import visibility, warp

LAMBDA_CONSISTENCY = 100.0
LAMBDA_PIXEL = 1.0
LAMBDA_PERCEPTUAL = 0.5


def masked_l1(pred, target, mask):
    """Mean |pred - target| over the pixels in mask (all channels); 0 for an empty mask."""
    m = mask.expand_as(pred)
    return (torch.abs(pred - target) * m).sum() / m.sum().clamp_min(1.0)


def _gauss(size=11, sigma=1.5, device=None):
    x = torch.arange(size, dtype=torch.float32, device=device) - size // 2
    g = torch.exp(-x * x / (2 * sigma * sigma))
    return g / g.sum()


def ssim_map(x, y, c1=0.01 ** 2, c2=0.03 ** 2):
    """SSIM (Wang et al. 2004, 11x11 Gaussian, sigma 1.5) per pixel for images in [0,1]: [B,C,H,W]."""
    c = x.shape[1]
    g = _gauss(device=x.device)
    kx = g.view(1, 1, 1, -1).repeat(c, 1, 1, 1)
    ky = g.view(1, 1, -1, 1).repeat(c, 1, 1, 1)

    def blur(t):
        t = F.conv2d(F.pad(t, (5, 5, 0, 0), mode="reflect"), kx, groups=c)
        return F.conv2d(F.pad(t, (0, 0, 5, 5), mode="reflect"), ky, groups=c)

    mx, my = blur(x), blur(y)
    sxx = blur(x * x) - mx * mx
    syy = blur(y * y) - my * my
    sxy = blur(x * y) - mx * my
    return ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))


def gradient_l1(pred, target, mask):
    """L1 between horizontal and vertical finite differences, over pixel pairs inside the mask."""
    loss = 0.0
    for dim in (2, 3):
        dp = torch.diff(pred, dim=dim)
        dt = torch.diff(target, dim=dim)
        m = torch.minimum(mask.narrow(dim, 0, mask.shape[dim] - 1), mask.narrow(dim, 1, mask.shape[dim] - 1))
        loss = loss + masked_l1(dp, dt, m)
    return loss


def perceptual(pred, target, mask, lpips=None):
    """The perceptual term on images in [-1,1]: the prediction is put over the ground-truth background first, so
    only the person counts. With `lpips` (a TorchScript module) it is LPIPS; otherwise (1 - SSIM) + gradient L1."""
    comp = pred * mask + target * (1 - mask)
    if lpips is not None:
        return lpips(comp, target).mean()
    s = ssim_map((comp + 1) / 2, (target + 1) / 2)
    m = mask.expand_as(s)
    ssim_term = ((1 - s) * m).sum() / m.sum().clamp_min(1.0)
    return ssim_term + gradient_l1(comp, target, mask)


def consistency(pred_ref, pred_mv, b):
    """Paper's L_consistency: the ref rendering warped into the mv view vs. the mv rendering, L1 over the points
    visible in both (Eq. 9). Returns (loss, visible fraction of the mv mask)."""
    grid, vis = visibility(b["mv_depth"], b["mv_view_from_world"], b["mv_half"],
                           b["ref_depth"], b["ref_view_from_world"], b["ref_half"])
    warped = warp(pred_ref, grid, vis)
    frac = vis.sum() / b["mv_mask"].sum().clamp_min(1.0)
    return masked_l1(warped, pred_mv, vis), frac


def total_loss(pred_ref, pred_mv, b, lpips=None):
    """The weighted sum and its parts (floats) for logging."""
    l_cons, frac = consistency(pred_ref, pred_mv, b)
    l_pix = masked_l1(pred_ref, b["ref_rgb"], b["ref_mask"]) + masked_l1(pred_mv, b["mv_rgb"], b["mv_mask"])
    l_per = perceptual(pred_ref, b["ref_rgb"], b["ref_mask"], lpips) + perceptual(pred_mv, b["mv_rgb"], b["mv_mask"],
                                                                                  lpips)
    total = LAMBDA_CONSISTENCY * l_cons + LAMBDA_PIXEL * l_pix + LAMBDA_PERCEPTUAL * l_per
    parts = {"consistency": l_cons, "pixel": l_pix, "perceptual": l_per, "visible": frac, "total": total}
    return total, {k: float(v.detach()) for k, v in parts.items()}
