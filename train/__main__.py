"""python -m train {fit,fit-fof,fit-placement,export,eval,synth} ... (see train/README.md)."""
import argparse
import json
import sys

from .nets import TIERS


def _train_args(p):
    p.add_argument("--data", required=True, help="an `r2human dataset` folder (dataset.json inside)")
    p.add_argument("--tier", choices=sorted(TIERS), default="tiny")
    p.add_argument("--out", required=True, help="run folder: checkpoints, train.log, log.jsonl")
    p.add_argument("--resolution", type=int, default=None, help="training resolution (default: the tier's)")
    p.add_argument("--steps", type=int, default=10_000, help="stop after this many optimiser steps")
    p.add_argument("--minutes", type=float, default=0, help="also stop after this wall time (0: no limit)")
    p.add_argument("--batch", type=int, default=4, help="batch per process (the paper: 4)")
    p.add_argument("--lr", type=float, default=2e-4, help="Adam learning rate (the paper: 2e-4)")
    p.add_argument("--workers", type=int, default=0, help="DataLoader worker processes")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--log-every", type=int, default=20)
    p.add_argument("--threads", type=int, default=0,
                   help="PyTorch CPU threads (0: PyTorch's default); 1 is fastest on a busy shared CPU")
    p.add_argument("--no-eval", action="store_true", help="skip the held-out evaluation at the end")


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m train", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)

    p = sub.add_parser("fit", help="train encoder + decoder (single process, or under torchrun)")
    _train_args(p)
    p.add_argument("--ckpt-every", type=int, default=200)
    p.add_argument("--resume", default=None, help="continue from a renderer.pt")
    p.add_argument("--init-from", default=None,
                   help="start from the weights of a model folder's encoder.onnx and decoder.onnx (e.g. models/tiny: "
                        "fine-tune the shipped renderer; a fresh optimiser)")
    p.add_argument("--lambda-consistency", type=float, default=100.0, help="the paper: 100")
    p.add_argument("--permute-colours", action="store_true",
                   help="permute each item's RGB channels at random (the same way in the photo, its back image and "
                        "the targets): the decoder cannot learn the synthetic people's colours of hidden surfaces")
    p.add_argument("--invert-colours", action="store_true",
                   help="invert the colours of half the items in linear light (alike in the photo, its back image and "
                        "the targets): the decoder cannot learn whether hidden surfaces are usually bright or dark")
    p.add_argument("--gain-colours", action="store_true",
                   help="scale each item's colours by a random gain per channel in linear light, log-uniform in "
                        "[0.2, 1] (alike in the photo, its back image and the targets; after --invert-colours): the "
                        "decoder cannot tell an inverted item from another")
    p.add_argument("--fof-dropout", type=float, default=0.3,
                   help="probability of feeding zeros instead of the FOF (the released test script feeds zeros)")
    p.add_argument("--lpips", default=None,
                   help="TorchScript LPIPS module (x, y in [-1,1] -> distance); default: SSIM + gradient substitute")

    p = sub.add_parser("fit-fof", help="train the FOF network (photo + body FOF and/or inflation prior -> FOF-X)")
    _train_args(p)
    p.add_argument("--ckpt-every", type=int, default=200, help="checkpoint (and held-out evaluation) interval")
    p.add_argument("--resume", default=None, help="continue from a fof.pt")
    p.add_argument("--lambda-occupancy", type=float, default=2.0,
                   help="weight of the decoded-occupancy L1 next to the coefficient L1 (weight 1)")
    p.add_argument("--lambda-silhouette", type=float, default=4.0,
                   help="weight of the silhouette term (every column of the person must hold some body)")
    p.add_argument("--inputs", default="image,prior",
                   help="the net's inputs: image (optional: without it the net sees geometry only), then any of body "
                        "(the fitted body's FOF, body_fof.npy; the reference's input) and prior (the inflation "
                        "prior, prior_fof.npy), e.g. image,body,prior or body,prior (exported as "
                        "r2human.fof_inputs)")
    p.add_argument("--residual", default=None, choices=["body", "prior", "none"],
                   help="the FOF input the net is residual on (default: body when among --inputs, else prior)")
    p.add_argument("--no-prior", action="store_true",
                   help="train the plain image -> FOF net (same as --inputs image --residual none)")
    p.add_argument("--body-depth-flip", type=float, default=0.0,
                   help="share of training items whose body FOF input is mirrored front to back (the pose "
                        "network's facing-away failure), so the net learns when not to trust it (default 0)")
    p.add_argument("--no-centre-output", action="store_true",
                   help="compare the raw output with the ground truth (the default places the output by the "
                        "depth convention first, as the pipeline does)")

    p = sub.add_parser("fit-placement", help="train the placement net (body FOF + inflation prior -> a depth shift "
                                             "per column of the prior; train/placement.py)")
    _train_args(p)
    p.add_argument("--ckpt-every", type=int, default=200, help="checkpoint (and held-out evaluation) interval")
    p.add_argument("--resume", default=None, help="continue from a placement.pt")
    p.add_argument("--with-coefficients", action="store_true",
                   help="the UNet also reads both FOFs' coefficients, not only their column moments")
    p.add_argument("--lambda-occupancy", type=float, default=2.0,
                   help="weight of the decoded-occupancy L1 next to the coefficient L1 (weight 1)")

    p = sub.add_parser("export", help="write encoder.onnx, decoder.onnx and/or fof.onnx with metadata and check them")
    p.add_argument("--renderer", default=None, help="renderer.pt from `fit` (writes encoder.onnx, decoder.onnx)")
    p.add_argument("--fof", default=None, help="fof.pt from `fit-fof`")
    p.add_argument("--placement", default=None, help="placement.pt from `fit-placement`")
    p.add_argument("--out", required=True, help="model folder, e.g. models/tiny")
    p.add_argument("--tolerance", type=float, default=1e-3, help="max allowed |ONNX Runtime - PyTorch|")

    p = sub.add_parser("export-untrained", help="export randomly initialised models of a tier (speed tests only)")
    p.add_argument("--tier", choices=sorted(TIERS), required=True)
    p.add_argument("--fof-n", type=int, default=32)
    p.add_argument("--resolution", type=int, default=None, help="default: the tier's")
    p.add_argument("--out", required=True)

    p = sub.add_parser("eval", help="held-out evaluation of a checkpoint")
    p.add_argument("--data", required=True)
    p.add_argument("--renderer", default=None)
    p.add_argument("--fof", default=None)
    p.add_argument("--fof-onnx", action="append", default=[], metavar="NAME=PATH",
                   help="also evaluate an exported fof.onnx under row NAME (repeatable; e.g. "
                        "fof_body=models/tiny/fof_body.onnx); with only these, the priors and the files are compared")
    p.add_argument("--placement", default=None, help="a placement.pt from `fit-placement`")
    p.add_argument("--placement-onnx", action="append", default=[], metavar="NAME=PATH",
                   help="also evaluate an exported placement.onnx under row NAME (repeatable)")
    p.add_argument("--split", default="test", choices=["test", "train", "all"],
                   help="subjects to evaluate the FOF rows on (all: an unseen dataset)")

    p = sub.add_parser("synth", help="write a tiny synthetic dataset (for tests and smoke runs only)")
    p.add_argument("--out", required=True)
    p.add_argument("--subjects", type=int, default=6)
    p.add_argument("--views", type=int, default=4)
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument("--fof-n", type=int, default=8)
    p.add_argument("--seed", type=int, default=0)

    args = ap.parse_args(argv)
    if getattr(args, "threads", 0):
        import torch
        torch.set_num_threads(args.threads)
    if args.cmd == "fit":
        from .fit import fit
        fit(args)
    elif args.cmd == "fit-fof":
        from .fit import fit_fof
        fit_fof(args)
    elif args.cmd == "fit-placement":
        from .placement import fit_placement
        fit_placement(args)
    elif args.cmd == "export":
        from .export import export
        export(args)
    elif args.cmd == "export-untrained":
        import os
        import tempfile

        import torch

        from .export import export_fof, export_renderer
        from .fit import R2HumanNet
        from .nets import FofNet
        res = args.resolution or TIERS[args.tier]["resolution"]
        rec = {"untrained": True, "purpose": "speed measurements only: random weights", "tier": args.tier}
        with tempfile.TemporaryDirectory() as tmp:
            common = {"tier": args.tier, "fof_n": args.fof_n, "resolution": res, "recipe": rec}
            torch.save({**common, "model": R2HumanNet(args.tier, args.fof_n).state_dict()}, f"{tmp}/r.pt")
            torch.save({**common, "prior": True, "model": FofNet(args.tier, args.fof_n).state_dict()}, f"{tmp}/f.pt")
            os.makedirs(args.out, exist_ok=True)
            report = export_renderer(f"{tmp}/r.pt", args.out)
            report.update(export_fof(f"{tmp}/f.pt", args.out))
        print(json.dumps(report, indent=1, sort_keys=True))
    elif args.cmd == "eval":
        import os

        import torch

        from .fit import R2HumanNet, evaluate_fof, evaluate_renderer
        from .nets import fof_net_from_checkpoint
        out = {}
        if args.renderer:
            ck = torch.load(args.renderer, map_location="cpu")
            m = R2HumanNet(ck["tier"], ck["fof_n"])
            m.load_state_dict(ck["model"])
            out["renderer"] = evaluate_renderer(m, args.data, ck["resolution"], torch.device("cpu"))
            out["renderer_zero_fof"] = evaluate_renderer(m, args.data, ck["resolution"], torch.device("cpu"), "zero")
        onnx = {}
        for item in args.fof_onnx:
            name, sep, path = item.partition("=")
            if not sep or not name or not path:
                raise SystemExit(f"--fof-onnx {item!r}: expected NAME=PATH")
            if not os.path.isfile(path):
                raise SystemExit(f"--fof-onnx {item!r}: no such file {path}")
            onnx[name] = path
        if args.fof or onnx:
            m, res = None, None
            if args.fof:
                ck = torch.load(args.fof, map_location="cpu")
                m = fof_net_from_checkpoint(ck)
                m.load_state_dict(ck["model"])
                res = ck["resolution"]
            out["fof"] = evaluate_fof(m, args.data, res, torch.device("cpu"), per_subject=True, onnx=onnx,
                                      split=args.split)
        if args.placement or args.placement_onnx:
            from .placement import evaluate_placement, placement_from_checkpoint
            m, res = None, None
            if args.placement:
                ck = torch.load(args.placement, map_location="cpu")
                m, res = placement_from_checkpoint(ck), ck["resolution"]
            files = dict(item.partition("=")[::2] for item in args.placement_onnx)
            out["placement"] = evaluate_placement(m, args.data, res, split=args.split, per_subject=True, onnx=files)
        print(json.dumps(out, indent=1))
    elif args.cmd == "synth":
        from .synth import write_dataset
        meta = write_dataset(args.out, args.subjects, args.views, args.resolution, args.fof_n, args.seed)
        print(f"wrote {len(meta['subjects'])} subjects to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
