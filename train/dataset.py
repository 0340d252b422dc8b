"""Reads `r2human dataset` output (SPEC.md, "Dataset format") into training tensors.

Every image tensor follows the networks' contract (train/nets.py): sRGB values mapped to [-1, 1]. The source image is
premultiplied by its mask (background -1, like the reference); targets keep straight colour and come with their mask.
A dataset at a higher resolution than the tier's is box-downsampled by an integer factor (depth: mean over the
foreground sub-pixels; normals renormalised; FOF coefficients averaged).
"""
import json
import math
import os
import random

import numpy as np
import torch
from PIL import Image

from .geometry import srgb_to_linear

FORMAT = "r2human-dataset"


def read_png_rgba(path):
    """8-bit sRGB PNG -> float32 [H,W,4] in [0,1] (straight alpha)."""
    with Image.open(path) as im:
        return np.asarray(im.convert("RGBA"), dtype=np.float32) / 255.0


def write_png_rgba(path, rgba):
    """float [H,W,4] in [0,1] (sRGB, straight alpha) -> 8-bit PNG."""
    Image.fromarray(np.clip(np.rint(np.asarray(rgba) * 255), 0, 255).astype(np.uint8), "RGBA").save(path)


def load_meta(root):
    with open(os.path.join(root, "dataset.json")) as f:
        meta = json.load(f)
    if meta.get("format") != FORMAT or meta.get("version") != 1:
        raise ValueError(f"{root}/dataset.json is not an {FORMAT} version 1 dataset (got {meta.get('format')!r}, "
                         f"version {meta.get('version')!r})")
    return meta


def _box(a, k):
    """Box-downsamples [H,W,...] by an integer factor k."""
    if k == 1:
        return a
    h, w = a.shape[:2]
    return a.reshape(h // k, k, w // k, k, *a.shape[2:]).mean(axis=(1, 3))


def downsample_rgba(rgba, k):
    """Box-downsamples straight-alpha RGBA [H,W,4] by k (colours averaged premultiplied, then straightened)."""
    if k == 1:
        return rgba
    alpha = _box(rgba[..., 3], k)
    premul = _box(rgba[..., :3] * rgba[..., 3:], k)
    rgb = np.where(alpha[..., None] > 1e-6, premul / np.maximum(alpha[..., None], 1e-6), 0)
    return np.concatenate([rgb, alpha[..., None]], -1)


def downsample_view(rgba, depth, normal, k):
    """Downsamples one rendered view (rgba straight [H,W,4], depth [H,W] with -1 background, normals [H,W,3])."""
    if k == 1:
        return rgba, depth, normal
    fg = (depth > -1).astype(np.float32)
    cnt = _box(fg, k)
    d = np.where(cnt > 0, _box(np.where(fg > 0, depth, 0), k) / np.maximum(cnt, 1e-6), -1.0)
    n = _box(normal, k)
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)
    n = np.where(cnt[..., None] > 0, n, 0)
    return downsample_rgba(rgba, k), d.astype(np.float32), n.astype(np.float32)


def camera_tensors(cam):
    """camera.json -> (view_from_world [4,4], half extents [2]) as float32 tensors. Only orthographic cameras."""
    proj = cam["projection"]
    if "orthographic" not in proj:
        raise ValueError(f"only orthographic views are supported for training, got {list(proj)}")
    o = proj["orthographic"]
    return (torch.tensor(np.array(cam["view_from_world"], np.float32).reshape(4, 4)),
            torch.tensor([o["half_width"], o["half_height"]], dtype=torch.float32))


SOURCE_CAMERA = {"view_from_world": np.eye(4).tolist(),
                 "projection": {"orthographic": {"half_width": 1.0, "half_height": 1.0}}}


def view_angle_deg(view_from_world):
    """Angle between a view's axis and the source view's axis (+z towards the source camera), in degrees."""
    m = np.asarray(view_from_world, np.float64).reshape(4, 4)[:3, :3]
    # The camera looks down -z in view space; its +z axis in world coordinates is the third row of the rotation.
    axis = m[2, :]
    return math.degrees(math.acos(max(-1.0, min(1.0, axis[2] / max(np.linalg.norm(axis), 1e-12)))))


class R2Dataset(torch.utils.data.Dataset):
    """One item = one subject's source frame + two of its views (reference and multi-view camera of the paper).

    Views are drawn at random per item (`set_epoch` reseeds, so DistributedSampler shards stay deterministic);
    `fixed_views=(a, b)` picks fixed ones (evaluation).
    """

    def __init__(self, root, split="train", resolution=None, seed=0, fixed_views=None, cache=True, with_views=True):
        self.root = root
        self.meta = load_meta(root)
        # `all`: every subject (an unseen dataset evaluated as a whole).
        self.subjects = list(self.meta["subjects"] if split == "all" else self.meta["split"][split])
        if not self.subjects:
            raise ValueError(f"{root}: split {split!r} is empty")
        self.data_res = int(self.meta["resolution"])
        self.res = int(resolution or self.data_res)
        if self.data_res % self.res:
            raise ValueError(f"dataset resolution {self.data_res} is not a multiple of the training resolution "
                             f"{self.res}")
        self.k = self.data_res // self.res
        self.fof_n = int(self.meta["fof_n"])
        self.views = int(self.meta["views_per_subject"])
        # The FOF net reads the source only (`with_views=False`): datasets written with `--views 0` serve it.
        self.with_views = with_views
        if with_views and self.views < 2:
            raise ValueError("training the renderer needs at least 2 views per subject")
        # `prior_fof.npy` (the inflation prior the residual FOF net corrects) exists in datasets written by this
        # version of `r2human dataset`.
        self.has_prior = all(os.path.exists(os.path.join(root, s, "prior_fof.npy")) for s in self.subjects)
        # `body_fof.npy` (the fitted body's FOF, the reference FOF net's input) exists in datasets written by
        # `r2human dataset` without `--no-body-fof`.
        self.has_body = all(os.path.exists(os.path.join(root, s, "body_fof.npy")) for s in self.subjects)
        # `source_back.png` (the back image the neural renderer's lookup blends in at run time) is written with the
        # body FOF by this version of `r2human dataset`: `back_image` in dataset.json.
        self.has_back = bool(self.meta.get("back_image"))
        self.seed, self.epoch = seed, 0
        self.fixed_views = fixed_views
        self.cache = {} if cache else None

    def set_epoch(self, epoch):
        self.epoch = epoch

    def __len__(self):
        return len(self.subjects)

    def _view(self, folder, cam):
        rgba = read_png_rgba(os.path.join(folder, "rgba.png"))
        depth = np.load(os.path.join(folder, "depth.npy")).astype(np.float32)
        normal = np.load(os.path.join(folder, "normal.npy")).astype(np.float32)
        rgba, depth, normal = downsample_view(rgba, depth, normal, self.k)
        mask = ((rgba[..., 3] > 0.5) & (depth > -1)).astype(np.float32)
        vfw, half = camera_tensors(cam)
        return {
            "rgb": torch.from_numpy(rgba[..., :3] * 2 - 1).permute(2, 0, 1).float(),
            "mask": torch.from_numpy(mask)[None],
            "depth": torch.from_numpy(depth)[None],
            "normals": torch.from_numpy(normal).permute(2, 0, 1).float(),
            "view_from_world": vfw,
            "half": half,
            "angle": torch.tensor(view_angle_deg(cam["view_from_world"]), dtype=torch.float32),
        }

    def _subject(self, name):
        if self.cache is not None and name in self.cache:
            return self.cache[name]
        d = os.path.join(self.root, name)
        rgba = read_png_rgba(os.path.join(d, "source_rgba.png"))
        depth = np.load(os.path.join(d, "source_depth.npy")).astype(np.float32)
        normal = np.load(os.path.join(d, "source_normal.npy")).astype(np.float32)
        fof = _box(np.load(os.path.join(d, "fof.npy")).astype(np.float32), self.k)
        if fof.shape[-1] != self.fof_n:
            raise ValueError(f"{d}/fof.npy has {fof.shape[-1]} coefficients, dataset.json says {self.fof_n}")
        rgba, depth, normal = downsample_view(rgba, depth, normal, self.k)
        prior = None
        if self.has_prior:
            prior = _box(np.load(os.path.join(d, "prior_fof.npy")).astype(np.float32), self.k)
            if prior.shape != fof.shape:
                raise ValueError(f"{d}/prior_fof.npy has shape {prior.shape}, fof.npy {fof.shape}")
        body = None
        if self.has_body:
            body = _box(np.load(os.path.join(d, "body_fof.npy")).astype(np.float32), self.k)
            if body.shape != fof.shape:
                raise ValueError(f"{d}/body_fof.npy has shape {body.shape}, fof.npy {fof.shape}")
        src_cam = SOURCE_CAMERA
        cam_path = os.path.join(d, "source_camera.json")
        if os.path.exists(cam_path):
            with open(cam_path) as f:
                src_cam = json.load(f)
        vfw, half = camera_tensors(src_cam)
        a = rgba[..., 3:]
        mask = torch.from_numpy(((a[..., 0] > 0.5) & (depth > -1)).astype(np.float32))[None]
        src = {
            # Premultiplied by the mask, then *2-1: background -1 (the reference's img*mask input).
            "image": torch.from_numpy(rgba[..., :3] * a * 2 - 1).permute(2, 0, 1).float(),
            # Linear light premultiplied by the mask, as the Rust pipeline holds the photo: the decoder's
            # `warped_rgb` input is looked up in it (train/geometry.py warp_rgb).
            "linear": srgb_to_linear(torch.from_numpy(rgba[..., :3]).permute(2, 0, 1).float()) * mask,
            "mask": mask,
            "fof": torch.from_numpy(fof).permute(2, 0, 1).float().contiguous(),
            "normals": torch.from_numpy(normal).permute(2, 0, 1).float(),
            "view_from_world": vfw,
            "half": half,
        }
        if self.has_back:
            # The back image (`r2human dataset`, `eval::dataset::back_image`) like `linear`; where a subject has none
            # (no face found) or it does not cover a pixel, the photo's colour, as inference looks it up then.
            src["back_linear"] = src["linear"].clone()
            back_path = os.path.join(d, "source_back.png")
            if os.path.exists(back_path):
                back = downsample_rgba(read_png_rgba(back_path), self.k)
                covered = torch.from_numpy((back[..., 3] > 0).astype(np.float32))[None] * mask
                back_lin = srgb_to_linear(torch.from_numpy(back[..., :3]).permute(2, 0, 1).float())
                src["back_linear"] = back_lin * covered + src["linear"] * (1 - covered)
        if prior is not None:
            src["prior"] = torch.from_numpy(prior).permute(2, 0, 1).float().contiguous()
        if body is not None:
            src["body"] = torch.from_numpy(body).permute(2, 0, 1).float().contiguous()
        views = []
        for v in range(self.views if self.with_views else 0):
            vd = os.path.join(d, "views", f"view_{v:02d}")
            with open(os.path.join(vd, "camera.json")) as f:
                cam = json.load(f)
            views.append(self._view(vd, cam))
        item = (src, views)
        if self.cache is not None:
            self.cache[name] = item
        return item

    def __getitem__(self, i):
        src, views = self._subject(self.subjects[i])
        if not self.with_views:
            return {f"src_{k}": v for k, v in src.items()}
        if self.fixed_views is not None:
            a, b = self.fixed_views
        else:
            rng = random.Random(self.seed * 1_000_003 + self.epoch * 7919 + i)
            a, b = rng.sample(range(len(views)), 2)
        out = {f"src_{k}": v for k, v in src.items()}
        out.update({f"ref_{k}": v for k, v in views[a].items()})
        out.update({f"mv_{k}": v for k, v in views[b].items()})
        return out
