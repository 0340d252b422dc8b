"""A tiny synthetic dataset in the exact `r2human dataset` format (SPEC.md), rendered with numpy alone.

For the training code's own tests and smoke runs only: the shipped models are trained on the real `r2human dataset`
output. Each subject is a union of ellipsoids (torso, head, arms, legs) with a procedural 3-D albedo texture, ray
cast exactly (orthographic cameras, depth = view z with larger nearer, -1 background), with FOF-X coefficients from
the exact ray/ellipsoid intervals. `mesh.glb` is not written (the trainer does not read it).
"""
import json
import math
import os

import numpy as np

from .dataset import write_png_rgba


def _rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], np.float64)


def _rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], np.float64)


def orbit_view_from_world(yaw_deg, pitch_deg):
    """Rotation-only orbit camera (orthographic, looking at the origin): view = Rx(pitch) @ Ry(-yaw) @ world."""
    m = np.eye(4)
    m[:3, :3] = _rot_x(math.radians(pitch_deg)) @ _rot_y(-math.radians(yaw_deg))
    return m


def random_subject(rng):
    """Ellipsoids (centre, radii, rotation) forming a rough person inside y in [-0.9, 0.9], plus texture params."""
    parts = []
    torso_w = rng.uniform(0.22, 0.32)
    parts.append(([0, 0.15, 0], [torso_w, 0.36, rng.uniform(0.13, 0.2)], 0.0))
    parts.append(([0, 0.68, 0.02], [0.13, 0.17, 0.14], 0.0))
    arm = rng.uniform(0.2, 0.6)
    for side in (-1, 1):
        parts.append(([side * (torso_w + 0.08), 0.2, 0], [0.07, 0.34, 0.07], side * arm))
        parts.append(([side * 0.11, -0.5, 0], [0.09, 0.4, 0.1], side * rng.uniform(0.0, 0.15)))
    colours = rng.uniform(0.1, 0.9, size=(len(parts), 3))
    stripes = rng.uniform(4, 14)
    return {"parts": [{"centre": c, "radii": r, "roll": a} for c, r, a in parts], "colours": colours.tolist(),
            "stripes": stripes}


def _quadrics(subject):
    out = []
    for p in subject["parts"]:
        c, rr, a = np.array(p["centre"], float), np.array(p["radii"], float), p["roll"]
        ca, sa = math.cos(a), math.sin(a)
        rz = np.array([[ca, -sa, 0], [sa, ca, 0], [0, 0, 1]])
        out.append((c, rz @ np.diag(1.0 / rr ** 2) @ rz.T))
    return out


def render(subject, view_from_world, res):
    """Ray casts the subject in a view: returns rgba (straight, [0,1]), depth (-1 bg), normals (view), and the list
    of per-part (z_in, z_out, hit) arrays for FOF."""
    rot = view_from_world[:3, :3]
    xs = (np.arange(res) + 0.5) / (res / 2) - 1
    x, y = np.meshgrid(xs, -xs)
    best = np.full((res, res), -np.inf)
    normal = np.zeros((res, res, 3))
    part_id = np.full((res, res), -1)
    intervals = []
    for k, (c, a) in enumerate(_quadrics(subject)):
        cv, av = rot @ c, rot @ a @ rot.T
        # (p - cv)^T av (p - cv) = 1 with p = (x, y, z): quadratic in z.
        dx, dy = x - cv[0], y - cv[1]
        qa = av[2, 2]
        qb = 2 * (av[0, 2] * dx + av[1, 2] * dy)
        qc = av[0, 0] * dx * dx + 2 * av[0, 1] * dx * dy + av[1, 1] * dy * dy - 1
        disc = qb * qb - 4 * qa * qc
        hit = disc > 0
        sq = np.sqrt(np.where(hit, disc, 0))
        z_out_rel = (-qb - sq) / (2 * qa)
        z_in_rel = (-qb + sq) / (2 * qa)
        z_near = cv[2] + z_in_rel  # larger z is nearer the camera
        z_far = cv[2] + z_out_rel
        intervals.append((np.where(hit, z_far, 0), np.where(hit, z_near, 0), hit))
        closer = hit & (z_near > best)
        best = np.where(closer, z_near, best)
        part_id = np.where(closer, k, part_id)
        p = np.stack([dx, dy, z_near - cv[2]], -1)
        n = p @ av.T
        n /= np.linalg.norm(n, axis=-1, keepdims=True) + 1e-12
        normal = np.where(closer[..., None], n, normal)
    fg = part_id >= 0
    depth = np.where(fg, best, -1.0)
    # World position of the visible point, for a view-independent 3-D texture.
    pv = np.stack([x, y, np.where(fg, best, 0)], -1)
    pw = pv @ rot  # rot^T p
    colours = np.array(subject["colours"])
    base = colours[np.clip(part_id, 0, None)]
    stripe = 0.5 + 0.5 * np.sin(subject["stripes"] * math.pi * pw[..., 1] + 3 * pw[..., 0])
    check = ((np.floor(pw[..., 0] * 8) + np.floor(pw[..., 2] * 8)) % 2) * 0.15
    rgb = np.clip(base * (0.6 + 0.4 * stripe[..., None]) + check[..., None], 0, 1)
    rgba = np.concatenate([np.where(fg[..., None], rgb, 0), fg[..., None].astype(float)], -1)
    return rgba, depth.astype(np.float32), np.where(fg[..., None], normal, 0).astype(np.float32), intervals


def fof_from_intervals(intervals, n):
    """FOF-X coefficients from per-part [z_in, z_out] intervals (their union per pixel), as reference-facts.md."""
    res = intervals[0][0].shape
    # Sample-free union: sort all interval ends and merge per pixel (few parts, so a simple loop is fine).
    lo = np.stack([i[0] for i in intervals], -1)
    hi = np.stack([i[1] for i in intervals], -1)
    hit = np.stack([i[2] for i in intervals], -1)
    coeffs = np.zeros(res + (n,), np.float64)
    order = np.argsort(np.where(hit, lo, np.inf), -1)
    lo = np.take_along_axis(lo, order, -1)
    hi = np.take_along_axis(hi, order, -1)
    hit = np.take_along_axis(hit, order, -1)
    cur_lo = np.full(res, np.nan)
    cur_hi = np.full(res, np.nan)
    k = np.arange(1, n)

    def flush(mask):
        t_in, t_out = np.clip(cur_lo, -1, 1) + 1, np.clip(cur_hi, -1, 1) + 1
        c = np.zeros(res + (n,))
        c[..., 0] = t_out - t_in
        w = k * math.pi / 2
        c[..., 1:] = (np.sin(w * t_out[..., None]) - np.sin(w * t_in[..., None])) / w
        return np.where(mask[..., None], c, 0)

    for j in range(lo.shape[-1]):
        h = hit[..., j]
        open_ = ~np.isnan(cur_lo)
        disjoint = h & open_ & (lo[..., j] > cur_hi)
        coeffs += flush(disjoint)
        start = h & (~open_ | disjoint)
        cur_lo = np.where(start, lo[..., j], cur_lo)
        cur_hi = np.where(start, hi[..., j], np.where(h & open_ & ~disjoint, np.maximum(cur_hi, hi[..., j]), cur_hi))
    coeffs += flush(~np.isnan(cur_lo))
    return coeffs.astype(np.float32)


def slab_prior(mask, n, half=0.15):
    """A stand-in for the Rust writer's inflation prior (`prior_fof.npy`) in this test dataset: the slab
    z in [-half, half] on every mask pixel (numpy has no Poisson inflation; the trainer only needs a plausible prior)."""
    lo = np.full(mask.shape, -half)
    hi = np.full(mask.shape, half)
    return fof_from_intervals([(lo, hi, mask)], n)


def body_stand_in(mask, n, lo=-0.1, hi=0.3):
    """A stand-in for the Rust writer's body FOF (`body_fof.npy`) in this test dataset: the slab z in [lo, hi]."""
    return fof_from_intervals([(np.full(mask.shape, lo), np.full(mask.shape, hi), mask)], n)


def write_dataset(root, subjects=6, views=4, res=64, fof_n=8, seed=0, test=2):
    """Writes `subjects` synthetic subjects with `views` orbit views each; the last `test` subjects are held out."""
    rng = np.random.default_rng(seed)
    names = [f"subject_{i:04d}" for i in range(subjects)]
    os.makedirs(root, exist_ok=True)
    for name in names:
        sub = random_subject(rng)
        d = os.path.join(root, name)
        os.makedirs(os.path.join(d, "views"), exist_ok=True)
        with open(os.path.join(d, "subject.json"), "w") as f:
            json.dump({"generator": "train.synth", "subject": sub, "normalisation": np.eye(4).tolist()}, f)
        rgba, depth, normal, intervals = render(sub, np.eye(4), res)
        write_png_rgba(os.path.join(d, "source_rgba.png"), rgba)
        np.save(os.path.join(d, "source_depth.npy"), depth)
        np.save(os.path.join(d, "source_normal.npy"), normal)
        np.save(os.path.join(d, "fof.npy"), fof_from_intervals(intervals, fof_n))
        np.save(os.path.join(d, "prior_fof.npy"), slab_prior(rgba[..., 3] > 0.5, fof_n))
        # A stand-in for the fitted body's FOF (`body_fof.npy`): a thicker slab shifted off centre, so it differs
        # from both the prior and the ground truth.
        np.save(os.path.join(d, "body_fof.npy"), body_stand_in(rgba[..., 3] > 0.5, fof_n))
        for v in range(views):
            yaw = 360.0 * v / views + rng.uniform(-20, 20)
            pitch = rng.uniform(-15, 15)
            m = orbit_view_from_world(yaw, pitch)
            vd = os.path.join(d, "views", f"view_{v:02d}")
            os.makedirs(vd, exist_ok=True)
            rgba, depth, normal, _ = render(sub, m, res)
            write_png_rgba(os.path.join(vd, "rgba.png"), rgba)
            np.save(os.path.join(vd, "depth.npy"), depth)
            np.save(os.path.join(vd, "normal.npy"), normal)
            cam = {"kind": "orbit", "yaw_deg": yaw, "pitch_deg": pitch, "view_from_world": m.tolist(),
                   "projection": {"orthographic": {"half_width": 1.0, "half_height": 1.0}}, "width": res,
                   "height": res}
            with open(os.path.join(vd, "camera.json"), "w") as f:
                json.dump(cam, f)
    meta = {"format": "r2human-dataset", "version": 1, "resolution": res, "fof_n": fof_n, "seed": seed,
            "subjects": names, "views_per_subject": views,
            "split": {"train": names[: subjects - test], "test": names[subjects - test:]}}
    with open(os.path.join(root, "dataset.json"), "w") as f:
        json.dump(meta, f, indent=1)
    return meta
