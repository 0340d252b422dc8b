"""Export checkpoints to the ONNX files the Rust runtime loads (src/neural), with r2human metadata, and check that
ONNX Runtime and PyTorch agree on random inputs (max abs diff, written to export_report.json)."""
import json
import os

import numpy as np
import onnx
import torch

from .fit import R2HumanNet
from .nets import TIERS, ZMAP_FREQUENCIES, FofNet, fof_net_from_checkpoint

FORMAT_VERSION = 1
# The decoder's inputs, in order. `warped_rgb` (the residual decoder's photo lookup) cannot be called `rgb` like the
# brief's wording because ONNX value names are unique and `rgb` is the output.
DECODER_INPUTS = ("features", "zmap", "normals", "warped_rgb")


def _metadata(path, entries):
    model = onnx.load(path)
    del model.metadata_props[:]
    for k, v in entries.items():
        model.metadata_props.append(onnx.StringStringEntryProto(key=k, value=str(v)))
    onnx.checker.check_model(model)
    onnx.save(model, path)


def _export(module, args, path, inputs, outputs, dynamic_axes=None):
    module.eval()
    torch.onnx.export(module, args, path, input_names=inputs, output_names=outputs, opset_version=17,
                      dynamo=False, dynamic_axes=dynamic_axes, do_constant_folding=True)


def _compare(path, module, feeds):
    """Max |ONNX Runtime - PyTorch| over the outputs for one set of inputs."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 2
    sess = ort.InferenceSession(path, opts, providers=["CPUExecutionProvider"])
    got = sess.run(None, {k: v.numpy() for k, v in feeds.items()})[0]
    with torch.no_grad():
        want = module(*feeds.values()).numpy()
    if got.shape != want.shape:
        raise RuntimeError(f"{path}: ONNX output shape {got.shape} != PyTorch {want.shape}")
    return float(np.max(np.abs(got - want)))


def export_renderer(ckpt_path, out_dir, seed=0):
    ck = torch.load(ckpt_path, map_location="cpu")
    tier, fof_n, res = ck["tier"], ck["fof_n"], ck["resolution"]
    model = R2HumanNet(tier, fof_n)
    model.load_state_dict(ck["model"])
    model.eval()
    c = TIERS[tier]["features"]
    stride = model.decoder.stride
    os.makedirs(out_dir, exist_ok=True)
    g = torch.Generator().manual_seed(seed)
    common = {"r2human.format": FORMAT_VERSION, "r2human.tier": tier, "r2human.resolution": res,
              "r2human.fof_n": fof_n, "r2human.feature_channels": c,
              "r2human.recipe": json.dumps(ck["recipe"], sort_keys=True)}
    report = {}

    enc_path = os.path.join(out_dir, "encoder.onnx")
    enc_in = {"image": torch.rand(1, 3, res, res, generator=g) * 2 - 1,
              "fof": torch.randn(1, fof_n, res, res, generator=g) * 0.3,
              "normals": torch.nn.functional.normalize(torch.randn(1, 3, res, res, generator=g), dim=1)}
    _export(model.encoder, tuple(enc_in.values()), enc_path, list(enc_in), ["features"])
    _metadata(enc_path, {**common, "r2human.kind": "encoder"})
    report["encoder"] = {"max_abs_diff": _compare(enc_path, model.encoder, enc_in)}

    dec_path = os.path.join(out_dir, "decoder.onnx")

    def dec_inputs(h, w):
        return {"features": torch.randn(1, c, h, w, generator=g),
                "zmap": torch.rand(1, 1, h, w, generator=g) * 2 - 1,
                "normals": torch.nn.functional.normalize(torch.randn(1, 3, h, w, generator=g), dim=1),
                "warped_rgb": torch.rand(1, 3, h, w, generator=g) * 2 - 1}

    axes = {k: {2: "h", 3: "w"} for k in [*DECODER_INPUTS, "rgb"]}
    _export(model.decoder, tuple(dec_inputs(res // 2, res // 2).values()), dec_path, list(DECODER_INPUTS),
            ["rgb"], axes)
    _metadata(dec_path, {**common, "r2human.kind": "decoder", "r2human.stride": stride,
                         "r2human.zmap_frequencies": ZMAP_FREQUENCIES, "r2human.color_space": "srgb",
                         "r2human.residual": "warped_rgb"})
    report["decoder"] = {f"{h}x{w}": {"max_abs_diff": _compare(dec_path, model.decoder, dec_inputs(h, w))}
                         for h, w in [(res, res), (stride * 9, stride * 5)]}
    return report


def export_fof(ckpt_path, out_dir, seed=0):
    ck = torch.load(ckpt_path, map_location="cpu")
    tier, fof_n, res = ck["tier"], ck["fof_n"], ck["resolution"]
    model = fof_net_from_checkpoint(ck)
    model.load_state_dict(ck["model"])
    model.eval()
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, "fof.onnx")
    g = torch.Generator().manual_seed(seed)
    feeds = {"image": torch.rand(1, 3, res, res, generator=g) * 2 - 1} if "image" in model.inputs else {}
    for name in FofNet.fofs(model.inputs):
        # Coefficients of plausible occupied columns: c0 (the occupied fraction of the ray, times 2) in [0, 1].
        feeds[name] = torch.randn(1, fof_n, res, res, generator=g) * 0.2
        feeds[name][:, :1] = torch.rand(1, 1, res, res, generator=g)
    _export(model, tuple(feeds.values()), path, list(feeds), ["fof"])
    meta = {"r2human.format": FORMAT_VERSION, "r2human.kind": "fof", "r2human.tier": tier, "r2human.resolution": res,
            "r2human.fof_n": fof_n, "r2human.stride": model.stride, "r2human.fof_inputs": ",".join(model.inputs),
            "r2human.recipe": json.dumps(ck["recipe"], sort_keys=True)}
    if model.residual:
        meta["r2human.residual"] = model.residual
    _metadata(path, meta)
    return {"fof": {"max_abs_diff": _compare(path, model, feeds)}}


def export_placement(ckpt_path, out_dir, seed=0):
    """`placement.onnx` (train/placement.py): inputs `body`, `prior` [1,N,R,R] -> `shift` [1,1,R,R]."""
    from .placement import placement_from_checkpoint

    ck = torch.load(ckpt_path, map_location="cpu")
    fof_n, res = ck["fof_n"], ck["resolution"]
    model = placement_from_checkpoint(ck)
    model.eval()
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, "placement.onnx")
    g = torch.Generator().manual_seed(seed)
    feeds = {}
    for name in ("body", "prior"):
        feeds[name] = torch.randn(1, fof_n, res, res, generator=g) * 0.05
        feeds[name][:, :1] = torch.rand(1, 1, res, res, generator=g)
    _export(model, tuple(feeds.values()), path, list(feeds), ["shift"])
    _metadata(path, {"r2human.format": FORMAT_VERSION, "r2human.kind": "placement", "r2human.tier": ck["tier"],
                     "r2human.resolution": res, "r2human.fof_n": fof_n, "r2human.stride": model.stride,
                     "r2human.placement_weight": model.weight,
                     "r2human.recipe": json.dumps(ck["recipe"], sort_keys=True)})
    return {"placement": {"max_abs_diff": _compare(path, model, feeds)}}


def export(args):
    if not args.renderer and not args.fof and not getattr(args, "placement", None):
        raise SystemExit("nothing to export: give --renderer RUN/renderer.pt, --fof RUN/fof.pt and/or "
                         "--placement RUN/placement.pt")
    # Exporting one model keeps the other entries of an existing report (e.g. fof.onnx added to a shipped folder).
    report_path = os.path.join(args.out, "export_report.json")
    report = {}
    if os.path.exists(report_path):
        with open(report_path) as f:
            report = json.load(f)
    if args.renderer:
        report.update(export_renderer(args.renderer, args.out))
    if args.fof:
        report.update(export_fof(args.fof, args.out))
    if getattr(args, "placement", None):
        report.update(export_placement(args.placement, args.out))
    sizes = {f: os.path.getsize(os.path.join(args.out, f)) for f in os.listdir(args.out) if f.endswith(".onnx")}
    report["bytes"] = sizes
    with open(report_path, "w") as f:
        json.dump(report, f, indent=1, sort_keys=True)
    print(json.dumps(report, indent=1, sort_keys=True))
    worst = max(v["max_abs_diff"] for k, v in _flatten(report))
    if worst > args.tolerance:
        raise SystemExit(f"ONNX Runtime and PyTorch disagree by {worst:.3g} > {args.tolerance}")


def _flatten(report):
    for k, v in report.items():
        if isinstance(v, dict) and "max_abs_diff" in v:
            yield k, v
        elif isinstance(v, dict):
            yield from _flatten(v)
