"""The placement net: one depth shift per column for the silhouette-inflation prior, read from the fitted body.

Why a shift and not a FOF: reduce every column of a person to one interval and the ground truth loses little, and
the inflation prior's thickness at the true column depths comes within reach of the issue's target while its own
depth (the centre plane) does not (`cargo run --release --example geometry_oracle`). The Rust geometry
`body-placed` (`src/body/placed.rs`) moves each column by a fixed `PLACEMENT_WEIGHT` times the body's column depth
about the body's centroid. This net keeps that as its base and learns a correction per column, from geometry only
(no photo: the lesson of the FOF net is that what a net learns from synthetic textures does not carry over to
photos), so it has one scalar per column to get wrong instead of a whole FOF:

    shift = PLACEMENT_WEIGHT * (c_body - mean c_body) + UNet(features)      (last convolution zero-initialised)

The untrained net is exactly `body-placed` (at the net's resolution). Features per column, all from the two FOFs
the FOF net reads (`body`, `prior`, box-averaged to R): the prior's occupied length and centroid about its own
volume centroid, the body's length and centroid about its own, whether the body covers the column, and the mask
(the prior's occupied columns). Loss: the prior moved by the shift, placed by the depth convention
(`depth_centre.centre_fof`, as the pipeline places every geometry), against the ground truth: coefficient L1 +
`lambda_occupancy` x decoded-occupancy L1, as `fit-fof`.

Export (`placement.onnx`): inputs `body`, `prior` [1,N,R,R] -> `shift` [1,1,R,R] (z units, 0 outside the prior's
columns); the Rust side upsamples the shift to its FOF grid and moves the prior's surfaces by it.
"""
import json
import math
import os
import time

import numpy as np
import torch
import torch.nn as nn
from torch.utils.data import DataLoader

from . import losses
from .dataset import R2Dataset
from .depth_centre import centre_fof, occupied_columns, shift_columns
from .fit import Logger, RunningMeans, decode_occupancy, flip_batch, occupancy_iou
from .nets import TIERS, UNet, count_parameters

# src/body/placed.rs PLACEMENT_WEIGHT: the fixed share of the body's depth `body-placed` moves each column by.
PLACEMENT_WEIGHT = 0.5
FEATURES = 6
# Columns thinner than this (z units) have no reliable centroid (box-averaged silhouette edges).
MIN_LENGTH = 1e-3


def column_length_and_centroid(fof):
    """Per column ([B,1,H,W] each): the occupied length in z units (c_0; the occupancy integrates to c_0 / 2 over
    s = (z + 1) / 2 in [0, 1]) and the occupied centroid z in closed form (first moment c_0 / 4 + sum_k c_k
    ((-1)^k - 1) / (k pi)^2 over the volume, as `depth_centre.fof_centroid_z` per column); both 0 where the column
    is empty ([`occupied_columns`]) or thinner than MIN_LENGTH. Also the [B,1,H,W] bool of the columns that count."""
    n = fof.shape[1]
    k = torch.arange(n, dtype=fof.dtype, device=fof.device)
    w = torch.where(k % 2 == 1, -2.0 / (k * math.pi).clamp_min(1e-12) ** 2, torch.zeros_like(k))
    w[0] = 0.25
    length = fof[:, :1]
    cols = occupied_columns(fof) & (length > MIN_LENGTH)
    moment = torch.einsum("bnhw,n->bhw", fof, w)[:, None]
    s = moment / (0.5 * length).clamp_min(0.5 * MIN_LENGTH)
    zero = torch.zeros_like(length)
    return torch.where(cols, length, zero), torch.where(cols, 2.0 * s - 1.0, zero), cols


def about_centroid(length, centroid, cols):
    """`centroid` less the volume-weighted mean centroid of `cols` (per item), 0 outside `cols`."""
    wgt = length * cols
    mean = (wgt * centroid).sum((1, 2, 3), keepdim=True) / wgt.sum((1, 2, 3), keepdim=True).clamp_min(1e-6)
    return torch.where(cols, centroid - mean, torch.zeros_like(centroid))


class PlacementNet(nn.Module):
    """(body FOF, inflation prior FOF) -> the depth shift of each of the prior's columns (module docs)."""

    def __init__(self, tier, weight=PLACEMENT_WEIGHT, fofs_in=0):
        super().__init__()
        self.weight = float(weight)
        # With `fofs_in` = N the UNet also reads both FOFs' coefficients (2N more channels), not only the moments.
        self.fofs_in = int(fofs_in)
        self.net = UNet(FEATURES + 2 * self.fofs_in, 1, TIERS[tier]["fof_widths"], light=False)
        nn.init.zeros_(self.net.out.weight)
        nn.init.zeros_(self.net.out.bias)
        self.stride = self.net.stride

    def features(self, body, prior):
        """[`placement_inputs`] at this net's weight (with the coefficients when the net reads them)."""
        feats, base, mask = placement_inputs(body, prior, self.weight)
        if self.fofs_in:
            feats = torch.cat([feats, body * mask, prior * mask], 1)
        return feats, base, mask

    def forward(self, body, prior):
        feats, base, mask = self.features(body, prior)
        return (base + self.net(feats)) * mask

    def place(self, body, prior):
        """The prior with its columns moved by the net's shift (before the depth convention)."""
        return shift_columns(prior, self(body, prior))


def placement_inputs(body, prior, weight=PLACEMENT_WEIGHT):
    """The [B,FEATURES,H,W] input of the UNet, the base shift [B,1,H,W] (`weight` x the body's column depth about
    its centroid: `body-placed`) and the prior's columns (float), module docs."""
    lp, cp, colp = column_length_and_centroid(prior)
    lb, cb, colb = column_length_and_centroid(body)
    colb = colb & colp
    dp = about_centroid(lp, cp, colp)
    db = about_centroid(lb, cb, colb)
    mask = colp.to(prior.dtype)
    covered = colb.to(prior.dtype)
    feats = torch.cat([lp, dp, lb * covered, db, covered, mask], 1)
    return feats, weight * db, mask


def base_placement(body, prior, weight=PLACEMENT_WEIGHT):
    """The untrained net's placement (`body-placed` at this resolution): the prior moved by the base shift."""
    _, base, mask = placement_inputs(body, prior, weight)
    return shift_columns(prior, base * mask)


def placement_loss(model, b, lambda_occupancy, samples=32):
    """Coefficient L1 + `lambda_occupancy` x decoded-occupancy L1 of the placed, depth-centred prior against the
    ground truth, over the mask (module docs)."""
    gt, mask = b["src_fof"], b["src_mask"]
    pred = centre_fof(model.place(b["src_body"], b["src_prior"]) * mask, mask)[0]
    coef = losses.masked_l1(pred, gt, mask)
    occ = losses.masked_l1(decode_occupancy(pred, samples), decode_occupancy(gt, samples), mask)
    return coef + lambda_occupancy * occ, {"coef_l1": coef.item(), "occ_l1": occ.item()}


@torch.no_grad()
def evaluate_placement(model, data, resolution, split="test", per_subject=False, onnx=None):
    """Volumetric IoU (decoded 0.5 level, after the depth convention) of the prior, the body, `body-placed` and the
    net (and any exported `placement.onnx`, rows by name) against the ground truth, overall and per framing."""
    if model is not None:
        model.eval()
    ds = R2Dataset(data, split, resolution=resolution, cache=False, with_views=False)
    framings = ds.meta.get("framings", {})
    rows = {"prior": lambda b: b["src_prior"], "body": lambda b: b["src_body"],
            "body_placed": lambda b: base_placement(b["src_body"], b["src_prior"])}
    if model is not None:
        rows["net"] = lambda b: model.place(b["src_body"], b["src_prior"])
    for name, path in (onnx or {}).items():
        rows[name] = onnx_placement(path)
    each = {}
    for i in range(len(ds)):
        b = {k: t[None] for k, t in ds[i].items()}
        mask, gt = b["src_mask"], b["src_fof"]
        each[ds.subjects[i]] = {k: occupancy_iou(centre_fof(f(b) * mask, mask)[0] * mask, gt, mask)
                                for k, f in rows.items()}
    if model is not None:
        model.train()
    out = {"subjects": len(ds), **{k: round(float(np.mean([e[k] for e in each.values()])), 4) for k in rows}}
    groups = {}
    for name, ious in each.items():
        groups.setdefault(framings.get(name, "unknown"), []).append(ious)
    out["by_framing"] = {f: {"subjects": len(g), **{k: round(float(np.mean([x[k] for x in g])), 4) for k in rows}}
                         for f, g in sorted(groups.items())}
    if per_subject:
        out["per_subject"] = {s: {k: round(v, 4) for k, v in e.items()} for s, e in each.items()}
    return out


def onnx_placement(path):
    """A batch -> placed prior predictor running an exported `placement.onnx` through ONNX Runtime."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    sess = ort.InferenceSession(path, opts, providers=["CPUExecutionProvider"])

    def run(b):
        shift = sess.run(None, {"body": b["src_body"].numpy(), "prior": b["src_prior"].numpy()})[0]
        return shift_columns(b["src_prior"], torch.from_numpy(shift))

    return run


def placement_from_checkpoint(ck):
    m = PlacementNet(ck["tier"], ck.get("weight", PLACEMENT_WEIGHT), ck.get("fofs_in", 0))
    m.load_state_dict(ck["model"])
    return m


def save_placement(args, model, opt, step, ds, elapsed, evaluation=None):
    rec = {"data": os.path.abspath(args.data), "subjects": len(ds), "steps": step, "seconds": round(elapsed, 1),
           "batch": args.batch, "lr": args.lr, "seed": args.seed, "resolution": args.resolution,
           "losses": {"coefficient_l1": 1.0, "occupancy_l1": args.lambda_occupancy, "occupancy_samples": 32},
           "placement": f"shift = {model.weight} * body depth + UNet(features), last convolution zero-initialised",
           "augmentation": "left-right flip (p = 0.5)", "dataset": {k: ds.meta.get(k) for k in ("seed", "framing")}}
    if evaluation is not None:
        rec["held_out"] = evaluation
    path = os.path.join(args.out, "placement.pt")
    torch.save({"kind": "placement", "tier": args.tier, "fof_n": ds.fof_n, "resolution": args.resolution,
                "weight": model.weight, "fofs_in": model.fofs_in, "model": model.state_dict(), "optimizer": opt.state_dict(), "step": step,
                "recipe": rec}, path + ".tmp")
    os.replace(path + ".tmp", path)


def fit_placement(args):
    torch.manual_seed(args.seed)
    args.resolution = args.resolution or TIERS[args.tier]["resolution"]
    log = Logger(args.out, 0)
    ds = R2Dataset(args.data, "train", resolution=args.resolution, seed=args.seed, with_views=False)
    if not (ds.has_body and ds.has_prior):
        raise SystemExit(f"{args.data} lacks body_fof.npy or prior_fof.npy per subject: rewrite it with "
                         "`r2human dataset` (without --no-body-fof)")
    loader = DataLoader(ds, batch_size=args.batch, shuffle=True, num_workers=args.workers,
                        drop_last=len(ds) >= args.batch)
    model = PlacementNet(args.tier, fofs_in=ds.fof_n if args.with_coefficients else 0)
    opt = torch.optim.Adam(model.parameters(), lr=args.lr)
    step = 0
    if args.resume and os.path.exists(args.resume):
        ck = torch.load(args.resume, map_location="cpu")
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        step = ck.get("step", 0)
    log(f"placement net tier {args.tier}: {count_parameters(model) / 1e6:.3f} M params, {len(ds)} train subjects at "
        f"{args.resolution} px, lambda_occupancy {args.lambda_occupancy}, resumed from step {step}, "
        f"threads {torch.get_num_threads()}")
    if step == 0 and not args.no_eval:
        log("held-out evaluation at step 0 (net = body-placed): " +
            json.dumps(evaluate_placement(model, args.data, args.resolution)))
    t0, epoch, stop, running = time.time(), 0, False, RunningMeans()
    gen = torch.Generator().manual_seed(args.seed * 31)
    while not stop:
        for b in loader:
            b = flip_batch(b, gen)
            loss, parts = placement_loss(model, b, args.lambda_occupancy)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            step += 1
            parts["loss"] = loss.item()
            running.add(parts)
            elapsed = time.time() - t0
            if step % args.log_every == 0:
                avg = running.take()
                log(f"placement step {step} epoch {epoch} {elapsed:.0f}s " +
                    " ".join(f"{k} {v:.4f}" for k, v in avg.items()), step=step, seconds=round(elapsed, 1), **avg)
            if step % args.ckpt_every == 0:
                ev = None if args.no_eval else evaluate_placement(model, args.data, args.resolution)
                if ev is not None:
                    log(f"held-out evaluation at step {step}: " + json.dumps(ev), step=step, placement_eval=ev)
                save_placement(args, model, opt, step, ds, elapsed, ev)
            stop = step >= args.steps or bool(args.minutes and elapsed > args.minutes * 60)
            if stop:
                break
        epoch += 1
    elapsed = time.time() - t0
    summary = None if args.no_eval else evaluate_placement(model, args.data, args.resolution)
    save_placement(args, model, opt, step, ds, elapsed, summary)
    log(f"placement net finished: {step} steps in {elapsed:.0f}s")
    if summary is not None:
        log("held-out evaluation: " + json.dumps(summary), placement_eval=summary)
