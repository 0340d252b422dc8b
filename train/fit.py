"""Training loops (renderer: encoder + decoder; FOF net), single-process or under torchrun (DistributedDataParallel).

Single process (CPU or one GPU):   python -m train fit --data DIR --tier tiny --out runs/tiny
Several GPUs / nodes:              torchrun --nproc_per_node=G [--nnodes ...] -m train fit --data DIR --tier paper ...
Under torchrun every rank reads its DistributedSampler shard; rank 0 alone logs, evaluates and writes checkpoints.
"""
import json
import math
import os
import time

import numpy as np
import torch
import torch.distributed as dist
import torch.nn as nn
from torch.utils.data import DataLoader, DistributedSampler

from . import losses
from .depth_centre import centre_fof
from .dataset import R2Dataset
from .geometry import (back_weight, linear_to_srgb, side_image, side_weight, source_axis, srgb_to_linear, transfer, warp,
                       warp_rgb)
from .nets import TIERS, Decoder, Encoder, FofNet, count_parameters, fof_net_from_checkpoint, parse_fof_inputs


class R2HumanNet(nn.Module):
    """Encoder + decoder, rendering the batch's ref and mv views from its source frame (paper Fig. 2)."""

    def __init__(self, tier, fof_n):
        super().__init__()
        self.encoder = Encoder(tier, fof_n)
        self.decoder = Decoder(tier)

    def render(self, feats, b, view):
        grid, z, mask = transfer(b[f"{view}_depth"], b[f"{view}_view_from_world"], b[f"{view}_half"],
                                 b["src_view_from_world"], b["src_half"])
        return self.decoder(warp(feats, grid, mask), z, b[f"{view}_normals"] * mask, lookup(b, view, grid, mask))

    def forward(self, b, fof):
        feats = self.encoder(b["src_image"], fof, b["src_normals"])
        return self.render(feats, b, "ref"), self.render(feats, b, "mv")


def lookup(b, view, grid, mask):
    """The residual decoder's `warped_rgb` input for `view`: the photo looked up at the flow, blended with the back
    image where the target surface turns away from the source camera when the batch has one (`src_back_linear`,
    datasets with `source_back.png`), and with the side images (`side_image`) where the source camera sees the
    surface edge-on, as the neural renderer looks it up at run time with `--fill back`."""
    axis = source_axis(b[f"{view}_view_from_world"], b["src_view_from_world"])
    normals = b[f"{view}_normals"]
    behind = b.get("src_back_linear")
    side_back = side_image(behind, b["src_mask"]) if behind is not None else None
    side = (side_image(b["src_linear"], b["src_mask"]), side_back, side_weight(normals, axis))
    weight = back_weight(normals, axis) if behind is not None else None
    return warp_rgb(b["src_linear"], b["src_mask"], grid, mask, behind, weight, side)[0]


def geometric_baseline(b, view):
    """The geometric renderer for comparison: the colour lookup at the flow (mask-aware, no occlusion test; with the
    back image when the data has one), i.e. the residual decoder's `warped_rgb` input and an untrained decoder's
    output."""
    grid, _, mask = transfer(b[f"{view}_depth"], b[f"{view}_view_from_world"], b[f"{view}_half"],
                             b["src_view_from_world"], b["src_half"])
    return lookup(b, view, grid, mask)


def masked_psnr_ssim(pred, target, mask):
    """PSNR and SSIM over the mask on [0,1] images (per sample lists)."""
    p, t = (pred.clamp(-1, 1) + 1) / 2, (target + 1) / 2
    m = mask.expand_as(p)
    out = []
    s = losses.ssim_map(p * m, t * m)
    for i in range(p.shape[0]):
        n = m[i].sum().clamp_min(1.0)
        mse = (((p[i] - t[i]) ** 2) * m[i]).sum() / n
        psnr = 10 * math.log10(1.0 / max(float(mse), 1e-10))
        out.append((psnr, float((s[i] * m[i]).sum() / n)))
    return out


def setup_distributed():
    """(rank, world, device). Initialises the process group when launched by torchrun (WORLD_SIZE > 1)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if torch.cuda.is_available():
        device = torch.device("cuda", local)
        torch.cuda.set_device(device)
    else:
        device = torch.device("cpu")
    if world > 1:
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
    return rank, world, device


class Logger:
    def __init__(self, out, rank):
        self.rank = rank
        self.path = os.path.join(out, "train.log")
        self.jsonl = os.path.join(out, "log.jsonl")
        if rank == 0:
            os.makedirs(out, exist_ok=True)

    def __call__(self, msg, **record):
        if self.rank != 0:
            return
        line = time.strftime("%Y-%m-%dT%H:%M:%SZ ", time.gmtime()) + msg
        print(line, flush=True)
        with open(self.path, "a") as f:
            f.write(line + "\n")
        if record:
            with open(self.jsonl, "a") as f:
                f.write(json.dumps(record) + "\n")


class RunningMeans:
    """Sums of the loss parts since the last log line: `add` one step's parts, `take` their means (and restart)."""

    def __init__(self):
        self.sums, self.n = {}, 0

    def add(self, parts):
        for k, v in parts.items():
            self.sums[k] = self.sums.get(k, 0.0) + v
        self.n += 1

    def take(self):
        means = {k: v / self.n for k, v in self.sums.items()}
        self.sums, self.n = {}, 0
        return means


def to_device(b, device):
    return {k: v.to(device, non_blocking=True) for k, v in b.items()}


def stop_flag(stop, device, world):
    """Every rank stops when any rank wants to (rank 0's time budget)."""
    if world == 1:
        return stop
    t = torch.tensor([1.0 if stop else 0.0], device=device)
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    return bool(t.item() > 0)


@torch.no_grad()
def evaluate_renderer(model, data, resolution, device, fof_mode="gt"):
    """Held-out evaluation: every test subject's source against each of its views; PSNR/SSIM over the person for
    the neural renderer and the geometric warp, grouped by the view's angle from the source (close <= 45 deg,
    divergent >= 90 deg, as the paper's tables)."""
    model.eval()
    ds = R2Dataset(data, "test", resolution=resolution, cache=False)
    groups = {"close": {"neural": [], "geometric": []}, "divergent": {"neural": [], "geometric": []},
              "all": {"neural": [], "geometric": []}}
    for i in range(len(ds)):
        for v in range(ds.views):
            ds.fixed_views = (v, v)
            b = to_device({k: t[None] for k, t in ds[i].items()}, device)
            fof = b["src_fof"] if fof_mode == "gt" else torch.zeros_like(b["src_fof"])
            feats = model.encoder(b["src_image"], fof, b["src_normals"])
            pred = model.render(feats, b, "ref")
            geo = geometric_baseline(b, "ref")
            angle = float(b["ref_angle"][0])
            (pn, sn), = masked_psnr_ssim(pred, b["ref_rgb"], b["ref_mask"])
            (pg, sg), = masked_psnr_ssim(geo, b["ref_rgb"], b["ref_mask"])
            keys = ["all"] + (["close"] if angle <= 45 else []) + (["divergent"] if angle >= 90 else [])
            for k in keys:
                groups[k]["neural"].append((pn, sn))
                groups[k]["geometric"].append((pg, sg))
    model.train()
    summary = {}
    for g, d in groups.items():
        summary[g] = {"views": len(d["neural"])}
        for r, vals in d.items():
            if vals:
                summary[g][r] = {"psnr": float(np.mean([v[0] for v in vals])),
                                 "ssim": float(np.mean([v[1] for v in vals]))}
    return summary


def recipe(args, tier, data_meta, steps, seconds, world):
    return {"tier": tier, "data": os.path.abspath(args.data), "dataset_seed": data_meta.get("seed"),
            "train_subjects": len(data_meta["split"]["train"]), "test_subjects": len(data_meta["split"]["test"]),
            "resolution": args.resolution, "steps": steps, "batch": args.batch, "world_size": world,
            "lr": args.lr, "optimizer": "Adam", "seconds": round(seconds),
            "losses": {"consistency": getattr(args, "lambda_consistency", None), "pixel": losses.LAMBDA_PIXEL,
                       "perceptual": losses.LAMBDA_PERCEPTUAL,
                       "perceptual_kind": "lpips" if getattr(args, "lpips", None) else "ssim+gradient (LPIPS substitute)",
                       "visibility_lambda": 0.02},
            "decoder": "residual: rgb = warped_rgb + UNet(...), last convolution zero-initialised",
            "fof_dropout": getattr(args, "fof_dropout", 0.0),
            "permute_colours": getattr(args, "permute_colours", False),
            "invert_colours": getattr(args, "invert_colours", False),
            "gain_colours": getattr(args, "gain_colours", False), "seed": args.seed, "torch": str(torch.__version__),
            "resumed_from": getattr(args, "resume", None), "initialised_from": getattr(args, "init_from", None)}


def fit(args):
    rank, world, device = setup_distributed()
    torch.manual_seed(args.seed + rank)
    cfg = TIERS[args.tier]
    args.resolution = args.resolution or cfg["resolution"]
    log = Logger(args.out, rank)
    ds = R2Dataset(args.data, "train", resolution=args.resolution, seed=args.seed)
    sampler = DistributedSampler(ds, num_replicas=world, rank=rank, shuffle=True, seed=args.seed) if world > 1 else None
    loader = DataLoader(ds, batch_size=args.batch, shuffle=sampler is None, sampler=sampler,
                        num_workers=args.workers, drop_last=len(ds) >= args.batch * world)
    model = R2HumanNet(args.tier, ds.fof_n).to(device)
    start_step = 0
    if getattr(args, "init_from", None):
        args.previous_recipe = load_onnx_weights(model, args.init_from)
    if args.resume and os.path.exists(args.resume):
        ck = torch.load(args.resume, map_location=device)
        model.load_state_dict(ck["model"])
        start_step = ck.get("step", 0)
        args.previous_recipe = ck.get("recipe")
    net = nn.parallel.DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None) \
        if world > 1 else model
    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    if args.resume and os.path.exists(args.resume) and "optimizer" in ck:
        opt.load_state_dict(ck["optimizer"])
    lpips = torch.jit.load(args.lpips, map_location=device).eval() if args.lpips else None
    if lpips is not None:
        for p in lpips.parameters():
            p.requires_grad_(False)
    losses.LAMBDA_CONSISTENCY = args.lambda_consistency
    log(f"tier {args.tier}: encoder {count_parameters(model.encoder) / 1e6:.3f} M params, decoder "
        f"{count_parameters(model.decoder) / 1e6:.3f} M; {len(ds)} train subjects at {args.resolution} px, "
        f"fof_n {ds.fof_n}, world {world}, device {device}, threads {torch.get_num_threads()}")
    t0 = time.time()
    step, epoch, stop = start_step, 0, False
    gen = torch.Generator().manual_seed(args.seed * 31 + rank)
    running = RunningMeans()
    while not stop:
        if sampler is not None:
            sampler.set_epoch(epoch)
        ds.set_epoch(epoch)
        for b in loader:
            b = to_device(b, device)
            if getattr(args, "permute_colours", False):
                b = permute_colours(b, gen)
            if getattr(args, "invert_colours", False):
                b = invert_colours(b, gen)
            if getattr(args, "gain_colours", False):
                b = gain_colours(b, gen)
            keep = (torch.rand(b["src_fof"].shape[0], 1, 1, 1, generator=gen) >= args.fof_dropout).float().to(device)
            pred_ref, pred_mv = net(b, b["src_fof"] * keep)
            loss, parts = losses.total_loss(pred_ref, pred_mv, b, lpips)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            step += 1
            running.add(parts)
            elapsed = time.time() - t0
            if step % args.log_every == 0:
                avg = running.take()
                log(f"step {step} epoch {epoch} {elapsed:.0f}s " + " ".join(f"{k} {v:.4f}" for k, v in avg.items()),
                    step=step, epoch=epoch, seconds=round(elapsed, 1), **avg)
            if rank == 0 and step % args.ckpt_every == 0:
                save_checkpoint(args, model, opt, step, ds, elapsed, world)
            stop = step >= args.steps or (args.minutes and elapsed > args.minutes * 60)
            stop = stop_flag(stop, device, world)
            if stop:
                break
        epoch += 1
    elapsed = time.time() - t0
    if rank == 0:
        save_checkpoint(args, model, opt, step, ds, elapsed, world)
        log(f"finished: {step} steps in {elapsed:.0f}s")
        if not args.no_eval:
            summary = evaluate_renderer(model, args.data, args.resolution, device)
            log("held-out evaluation (PSNR dB / SSIM over the person): " + json.dumps(summary), eval=summary)
    if world > 1:
        dist.destroy_process_group()


def load_onnx_weights(model, folder):
    """Sets `model`'s encoder and decoder weights from `folder`'s encoder.onnx and decoder.onnx (`train export`
    names each initializer after its parameter); every parameter must be found with its shape. Returns the
    recipe the models were trained with (their `r2human.recipe` metadata)."""
    import onnx
    from onnx import numpy_helper

    recipe = None
    for part in ("encoder", "decoder"):
        path = os.path.join(folder, f"{part}.onnx")
        graph = onnx.load(path)
        weights = {i.name: numpy_helper.to_array(i) for i in graph.graph.initializer}
        module = getattr(model, part)
        state = module.state_dict()
        for name, tensor in state.items():
            if name not in weights or tuple(weights[name].shape) != tuple(tensor.shape):
                found = weights[name].shape if name in weights else "missing"
                raise ValueError(f"{path}: parameter {name} {tuple(tensor.shape)} not found ({found}): a model of "
                                 f"another tier or FOF order?")
            state[name] = torch.from_numpy(weights[name].copy())
        module.load_state_dict(state)
        meta = {p.key: p.value for p in graph.metadata_props}
        recipe = json.loads(meta["r2human.recipe"]) if "r2human.recipe" in meta else recipe
    return recipe


# Every colour image of a renderer batch: the encoder's input, the photo and back image the lookup reads, the targets.
COLOUR_KEYS = ("src_image", "src_linear", "src_back_linear", "ref_rgb", "mv_rgb")


def permute_colours(b, gen):
    """The same random permutation of the RGB channels for every colour image of each item (`COLOUR_KEYS`; one of
    the six per item, the identity included), the other tensors untouched. Exact in sRGB and in linear light alike,
    so the photo, its lookup and the targets stay consistent. A decoder trained on it cannot learn what colour the
    synthetic people's hidden surfaces usually are (the back of a head painted cream on real photos, a grey photo
    included): it has to take the hue from the photo's lookup."""
    orders = torch.tensor([[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]])
    pick = orders[torch.randint(0, 6, (b["src_image"].shape[0],), generator=gen)]
    out = dict(b)
    for k in COLOUR_KEYS:
        if k in b:
            index = pick.to(b[k].device)[:, :, None, None].expand(-1, -1, *b[k].shape[2:])
            out[k] = torch.gather(b[k], 1, index)
    return out


def recoloured(b, f):
    """`b` with every colour image recoloured in linear light by `f(colour, coverage)`, which maps premultiplied
    linear colours over their coverage (the mask for the photo and its back image, 1 for straight colours) and acts
    on each item alone: the photo (`src_linear`) and its back image, the encoder's sRGB input (`src_image`, from the
    recoloured straight photo, -1 outside the mask) and the targets (`ref_rgb`, `mv_rgb`, sRGB in [-1, 1]); the other
    tensors as they are. A recolouring that is linear per item (an inversion, a gain) commutes with the lookup."""
    out = dict(b)
    mask = b["src_mask"]
    for k in ("src_linear", "src_back_linear"):
        if k in b:
            out[k] = f(b[k], mask)
    straight = f(b["src_linear"] / mask.clamp_min(1e-6), torch.ones_like(mask))
    out["src_image"] = torch.where(mask > 0, linear_to_srgb(straight) * 2 - 1, torch.full_like(straight, -1.0))
    for k in ("ref_rgb", "mv_rgb"):
        if k in b:
            linear = srgb_to_linear((b[k] + 1) / 2)
            out[k] = linear_to_srgb(f(linear, torch.ones_like(linear[:, :1]))) * 2 - 1
    return out


def invert_colours(b, gen, p=0.5):
    """Inverts the colours of a random share `p` of the items in linear light (`L -> 1 - L`), alike in the photo
    (`src_image`, `src_linear`), its back image and the targets, the other tensors untouched: consistent through the
    lookup, so a decoder trained on it cannot learn whether the synthetic people's hidden surfaces are usually bright
    or dark (the permuted fine-tune still painted the back of dark heads white on real photos)."""
    flip = (torch.rand(b["src_image"].shape[0], generator=gen) < p).to(b["src_image"].device)[:, None, None, None]
    inverted = recoloured(b, lambda colour, coverage: coverage - colour)
    return {k: torch.where(flip, inverted[k], v) if k in COLOUR_KEYS and k in inverted else v for k, v in b.items()}


def gain_colours(b, gen, lowest=0.2):
    """Scales each item's colours by a random gain per channel in linear light, log-uniform in `[lowest, 1]`, alike
    in the photo (`src_image`, `src_linear`), its back image and the targets, the other tensors untouched. A gain
    commutes with the lookup (bilinear sampling is linear), so the photo, its lookup and the targets stay consistent.
    After `invert_colours` the brightness and hue of an item are continuous unknowns: a decoder cannot tell an
    inverted item from another (the inverted fine-tune painted the back of a dark-haired, dark-uniformed real person's
    head pale grey: it guessed the item was inverted) and must take the colour of hidden surfaces from the lookup."""
    n = b["src_image"].shape[0]
    log_gain = torch.rand(n, 3, generator=gen) * math.log(lowest)
    gain = log_gain.exp().to(b["src_image"].device)[:, :, None, None]
    return recoloured(b, lambda colour, coverage: colour * gain)


def save_checkpoint(args, model, opt, step, ds, elapsed, world):
    path = os.path.join(args.out, "renderer.pt")
    torch.save({"kind": "renderer", "tier": args.tier, "fof_n": ds.fof_n, "resolution": args.resolution,
                "model": model.state_dict(), "optimizer": opt.state_dict(), "step": step,
                "recipe": {**recipe(args, args.tier, ds.meta, step, elapsed, world),
                           "previous_stage": getattr(args, "previous_recipe", None)}}, path + ".tmp")
    os.replace(path + ".tmp", path)


def decode_occupancy(fof, samples=64):
    """FOF-X decode at `samples` depths per pixel: [B,N,H,W] -> [B,samples,H,W] occupancy."""
    n = fof.shape[1]
    s = (torch.arange(samples, dtype=fof.dtype, device=fof.device) + 0.5) / samples
    k = torch.arange(1, n, dtype=fof.dtype, device=fof.device)
    basis = torch.cos(k[None, :] * math.pi * s[:, None])  # [samples, N-1]
    return 0.5 * fof[:, :1] + torch.einsum("sk,bkhw->bshw", basis, fof[:, 1:])


def fof_inputs(model, b):
    """The FOF net's inputs from a batch, in the net's order (`model.inputs`: the photo when it takes it, then
    `body` and/or `prior`)."""
    out = [b["src_image"]] if "image" in model.inputs else []
    for name in FofNet.fofs(model.inputs):
        if f"src_{name}" not in b:
            file = {"prior": "prior_fof.npy", "body": "body_fof.npy"}[name]
            raise ValueError(f"this FOF net takes `{name}`, but the dataset has no {file}: rewrite it with this "
                             "version's `r2human dataset` (without --no-body-fof)")
        out.append(b[f"src_{name}"])
    return tuple(out)


def occupancy_iou(pred, gt, mask, samples=64):
    """Volumetric IoU of the decoded 0.5 iso-surfaces over the mask's columns."""
    m = mask > 0.5
    po, go = (decode_occupancy(pred, samples) > 0.5) & m, (decode_occupancy(gt, samples) > 0.5) & m
    return float((po & go).sum()) / max(float((po | go).sum()), 1.0)


def onnx_fof_predictor(path):
    """A FOF predictor (batch -> [B,N,H,W]) running an exported `fof.onnx` through ONNX Runtime on the batch's
    inputs the file declares (`r2human.fof_inputs`, default image + prior): how the shipped files are compared."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    sess = ort.InferenceSession(path, opts, providers=["CPUExecutionProvider"])
    names = [i.name for i in sess.get_inputs()]

    def run(b):
        feeds = {}
        for name in names:
            if f"src_{name}" not in b:
                raise SystemExit(f"{path} takes `{name}`, which the dataset does not hold")
            feeds[name] = b[f"src_{name}"].cpu().numpy()
        return torch.from_numpy(sess.run(None, feeds)[0])

    return run


@torch.no_grad()
def evaluate_fof(model, data, resolution, device, per_subject=False, onnx=None, split="test"):
    """Held-out FOF accuracy of the FOF net next to the FOF priors the dataset holds (the inflation prior `prior_`,
    the fitted body `body_`) and any exported nets (`onnx`: name -> fof.onnx path, rows `NAME_`): coefficient L1
    over the person, the volumetric IoU of the decoded 0.5 iso-surface against ground truth, and the share of the
    silhouette's columns that hold body; every prediction is first placed by the depth convention
    (`depth_centre.centre_fof`), as inference does. `model` may be None (priors and ONNX files only); `split`:
    `test`, `train` or `all`. With `per_subject`, also each subject's IoU per row (`per_subject`: name -> {row:
    iou}) and the mean IoU per framing (`by_framing`: framing -> {row: iou})."""
    if model is not None:
        model.eval()
    ds = R2Dataset(data, split, resolution=resolution, cache=False, with_views=False)
    framings = ds.meta.get("framings", {})
    out = {"subjects": len(ds)}
    predictors = {}
    if model is not None:
        predictors["net"] = lambda b: model(*fof_inputs(model, b))
    if ds.has_prior:
        predictors["prior"] = lambda b: b["src_prior"]
    if ds.has_body:
        predictors["body"] = lambda b: b["src_body"]
    for name, path in (onnx or {}).items():
        predictors[name] = onnx_fof_predictor(path)
    rows = {k: ([], [], []) for k in predictors}
    each = {}
    for i in range(len(ds)):
        b = to_device({k: t[None] for k, t in ds[i].items()}, device)
        mask, gt = b["src_mask"], b["src_fof"]
        for k, predict in predictors.items():
            # Placed in depth as `pipeline::compute_geometry` places every geometry (the ground truth already is).
            pred = centre_fof(predict(b).to(device) * mask, mask)[0] * mask
            rows[k][0].append(float(losses.masked_l1(pred, gt, mask)))
            rows[k][1].append(occupancy_iou(pred, gt, mask))
            # Silhouette kept: the share of the person's columns that hold some body (0.5 level).
            kept = ((decode_occupancy(pred, 64).max(1, keepdim=True).values > 0.5) & (mask > 0.5)).sum()
            rows[k][2].append(float(kept) / max(float((mask > 0.5).sum()), 1.0))
        each[ds.subjects[i]] = {k: round(rows[k][1][-1], 4) for k in rows}
    if model is not None:
        model.train()
    for k in rows:
        prefix = "" if k == "net" else k + "_"
        out[prefix + "coefficient_l1"] = float(np.mean(rows[k][0]))
        out[prefix + "occupancy_iou"] = float(np.mean(rows[k][1]))
        out[prefix + "silhouette_kept"] = float(np.mean(rows[k][2]))
    if per_subject:
        out["per_subject"] = each
        groups = {}
        for name, ious in each.items():
            groups.setdefault(framings.get(name, "unknown"), []).append(ious)
        out["by_framing"] = {f: {"subjects": len(g), **{k: round(float(np.mean([x[k] for x in g])), 4) for k in rows}}
                             for f, g in sorted(groups.items())}
    return out


# A column inside the silhouette must reach this occupancy somewhere (the mesh is the 0.5 level: the margin keeps
# the silhouette after the Rust side's upsampling).
SILHOUETTE_LEVEL = 0.6


def silhouette_loss(occ, mask):
    """Mean over the person's pixels of relu(SILHOUETTE_LEVEL - max over depth of the occupancy): every column the
    photo shows must hold some body. Without it the L1 terms teach the net to erase thin parts (an arm a few percent
    of the ray long costs less L1 when predicted empty than when predicted at a slightly wrong depth)."""
    peak = occ.max(1, keepdim=True).values
    return (torch.relu(SILHOUETTE_LEVEL - peak) * mask).sum() / mask.sum().clamp_min(1.0)


def fof_loss(net, model, b, lambda_occupancy, lambda_silhouette=0.0, samples=32, centre=False):
    """Masked L1 on the coefficients + `lambda_occupancy` x masked L1 on the decoded occupancy (what the mesh is
    extracted from) + `lambda_silhouette` x [`silhouette_loss`]. `net` runs the model (it may be its DDP wrapper).
    With `centre`, the prediction is first placed by the depth convention (`depth_centre.centre_fof`, as
    `pipeline::compute_geometry` places the net's output), so its depth offset, which one photo cannot show, costs
    nothing."""
    pred = net(*fof_inputs(model, b))
    gt, mask = b["src_fof"], b["src_mask"]
    if centre:
        pred = centre_fof(pred, mask)[0]
    coef = losses.masked_l1(pred, gt, mask)
    occ_pred = decode_occupancy(pred, samples)
    occ = losses.masked_l1(occ_pred, decode_occupancy(gt, samples), mask)
    sil = silhouette_loss(occ_pred, mask)
    loss = coef + lambda_occupancy * occ + lambda_silhouette * sil
    return loss, {"coef_l1": coef.item(), "occ_l1": occ.item(), "silhouette": sil.item()}


def flip_batch(b, gen):
    """Mirrors a random half of the batch left-right (image, mask, FOF, prior, body): a mirrored person is as plausible
    and x does not enter FOF coefficients (they describe occupancy along z only)."""
    keys = [k for k in ("src_image", "src_mask", "src_fof", "src_prior", "src_body") if k in b]
    n = b[keys[0]].shape[0]
    flip = torch.rand(n, generator=gen) < 0.5
    if not bool(flip.any()):
        return b
    out = dict(b)
    for k in keys:
        t = b[k].clone()
        t[flip] = torch.flip(t[flip], dims=[-1])
        out[k] = t
    return out


def flip_body_in_depth(b, gen, p):
    """Mirrors the body FOF (`src_body`) front to back for a random share `p` of the batch, the other inputs and the
    target untouched: the pose network's known failure (a person read as seen from behind, arms and back fitted on
    the wrong side; docs/geometry.md, "The body prior") shown to the net, so it learns to trust the body FOF only
    where the rest agrees. Mirroring z -> -z maps occupancy(s) to occupancy(1 - s), i.e. coefficient k to (-1)^k
    times itself."""
    if p <= 0 or "src_body" not in b:
        return b
    body = b["src_body"]
    pick = torch.rand(body.shape[0], generator=gen) < p
    if not bool(pick.any()):
        return b
    sign = torch.ones(body.shape[1], dtype=body.dtype)
    sign[1::2] = -1
    out = dict(b)
    t = body.clone()
    t[pick] = t[pick] * sign.view(1, -1, 1, 1)
    out["src_body"] = t
    return out


def save_fof(args, model, opt, step, ds, elapsed, world, evaluation=None):
    rec = recipe(args, args.tier, ds.meta, step, elapsed, world)
    rec["losses"] = {"coefficient_l1": 1.0, "occupancy_l1": args.lambda_occupancy, "occupancy_samples": 32,
                     "silhouette": args.lambda_silhouette, "silhouette_level": SILHOUETTE_LEVEL}
    ins = ", ".join(model.inputs)
    rec["fof_net"] = (f"residual on `{model.residual}`: fof = {model.residual} + UNet({ins}), last convolution "
                      "zero-initialised") if model.residual else f"plain: ({ins}) -> fof"
    rec["fof_inputs"] = list(model.inputs)
    rec["augmentation"] = "left-right flip (p = 0.5)" + (
        f", body FOF mirrored in depth (p = {args.body_depth_flip})" if getattr(args, "body_depth_flip", 0) > 0 else "")
    rec["loss_on_centred_output"] = not getattr(args, "no_centre_output", False)
    rec.pop("decoder", None)
    rec.pop("fof_dropout", None)
    if evaluation is not None:
        rec["held_out"] = evaluation
    path = os.path.join(args.out, "fof.pt")
    torch.save({"kind": "fof", "tier": args.tier, "fof_n": ds.fof_n, "resolution": args.resolution,
                "prior": model.prior, "inputs": list(model.inputs), "residual": model.residual,
                "model": model.state_dict(), "optimizer": opt.state_dict(), "step": step,
                "recipe": rec}, path + ".tmp")
    os.replace(path + ".tmp", path)


def fof_net_choice(args, ds):
    """The FOF net's inputs and residual base from `--inputs` / `--residual` (`--no-prior`: the plain image -> FOF
    net), checked against what the dataset holds."""
    if getattr(args, "no_prior", False):
        return ("image",), None
    inputs = parse_fof_inputs(args.inputs)
    files = {"prior": (ds.has_prior, "prior_fof.npy"), "body": (ds.has_body, "body_fof.npy")}
    for name in FofNet.fofs(inputs):
        present, file = files[name]
        if not present:
            raise SystemExit(f"{args.data} has no {file} per subject (needed by --inputs {args.inputs}): rewrite it "
                             "with this version's `r2human dataset`, or choose other --inputs")
    residual = args.residual
    if residual == "none":
        residual = None
    elif residual is None:
        residual = "body" if "body" in inputs else ("prior" if "prior" in inputs else None)
    if residual is not None and residual not in FofNet.fofs(inputs):
        raise SystemExit(f"--residual {residual} is not one of --inputs {args.inputs}")
    return inputs, residual


def fit_fof(args):
    rank, world, device = setup_distributed()
    torch.manual_seed(args.seed + rank)
    args.resolution = args.resolution or TIERS[args.tier]["resolution"]
    log = Logger(args.out, rank)
    ds = R2Dataset(args.data, "train", resolution=args.resolution, seed=args.seed, with_views=False)
    inputs, residual = fof_net_choice(args, ds)
    sampler = DistributedSampler(ds, num_replicas=world, rank=rank, shuffle=True, seed=args.seed) if world > 1 else None
    loader = DataLoader(ds, batch_size=args.batch, shuffle=sampler is None, sampler=sampler, num_workers=args.workers,
                        drop_last=len(ds) >= args.batch * world)
    model = FofNet(args.tier, ds.fof_n, inputs=inputs, residual=residual).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=args.lr)
    start_step = 0
    if args.resume and os.path.exists(args.resume):
        ck = torch.load(args.resume, map_location=device)
        resumed = fof_net_from_checkpoint(ck)
        if (resumed.inputs, resumed.residual) != (model.inputs, model.residual):
            raise SystemExit(f"{args.resume} takes {','.join(resumed.inputs)} (residual {resumed.residual}), not "
                             f"--inputs {','.join(model.inputs)} --residual {model.residual}")
        model.load_state_dict(ck["model"])
        if "optimizer" in ck:
            opt.load_state_dict(ck["optimizer"])
        start_step = ck.get("step", 0)
    net = nn.parallel.DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None) \
        if world > 1 else model
    log(f"FOF net tier {args.tier}: {count_parameters(model) / 1e6:.3f} M params, "
        f"inputs {','.join(inputs)}, residual on {residual or 'nothing'}, {len(ds)} train subjects at "
        f"{args.resolution} px, fof_n {ds.fof_n}, lambda_occupancy {args.lambda_occupancy}, lambda_silhouette "
        f"{args.lambda_silhouette}, resumed from step {start_step}, "
        f"threads {torch.get_num_threads()}")
    if rank == 0 and start_step == 0 and not args.no_eval:
        log(f"held-out FOF evaluation at step 0 (= the {residual or 'untrained net'}): " +
            json.dumps(evaluate_fof(model, args.data, args.resolution, device)))
    t0, step, epoch, stop, running = time.time(), start_step, 0, False, RunningMeans()
    gen = torch.Generator().manual_seed(args.seed * 31 + rank)
    while not stop:
        if sampler is not None:
            sampler.set_epoch(epoch)
        for b in loader:
            b = to_device(flip_body_in_depth(flip_batch(b, gen), gen, getattr(args, "body_depth_flip", 0.0)), device)
            loss, parts = fof_loss(net, model, b, args.lambda_occupancy, args.lambda_silhouette,
                                   centre=not args.no_centre_output)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            step += 1
            parts["loss"] = loss.item()
            running.add(parts)
            elapsed = time.time() - t0
            if step % args.log_every == 0:
                avg = running.take()
                log(f"fof step {step} epoch {epoch} {elapsed:.0f}s " + " ".join(f"{k} {v:.4f}" for k, v in avg.items()),
                    step=step, epoch=epoch, seconds=round(elapsed, 1), **{f"fof_{k}": v for k, v in avg.items()})
            if rank == 0 and step % args.ckpt_every == 0:
                ev = None if args.no_eval else evaluate_fof(model, args.data, args.resolution, device)
                if ev is not None:
                    log(f"held-out FOF evaluation at step {step}: " + json.dumps(ev), step=step, fof_eval=ev)
                save_fof(args, model, opt, step, ds, elapsed, world, ev)
            stop = stop_flag(step >= args.steps or (args.minutes and elapsed > args.minutes * 60), device, world)
            if stop:
                break
        epoch += 1
    if rank == 0:
        elapsed = time.time() - t0
        summary = None if args.no_eval else evaluate_fof(model, args.data, args.resolution, device)
        save_fof(args, model, opt, step, ds, elapsed, world, summary)
        log(f"FOF net finished: {step} steps in {elapsed:.0f}s")
        if summary is not None:
            log("held-out FOF evaluation: " + json.dumps(summary), fof_eval=summary)
    if world > 1:
        dist.destroy_process_group()
