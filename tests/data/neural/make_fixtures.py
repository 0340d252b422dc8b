"""Writes the tiny ONNX models that tests/neural.rs loads (run: .venv/bin/python tests/data/neural/make_fixtures.py).

Every model has a closed-form output so the Rust tests can check real numbers, not just "it ran":
  good/encoder.onnx  features = Conv1x1(AvgPool4(concat(image, fof, normals)))   with the weights W_ENC below
  good/decoder.onnx  rgb = warped_rgb + features[0:3] + 0.5*zmap + 0.25*normals
                           + Conv3x3(features[3] -> 3 ch, all 0.1)
                           + 0 * Upsample4(AvgPool4(features[0:3]))   (the last term fails unless h, w % 4 == 0)
  decoder_3_inputs.onnx    the same without `warped_rgb` (the pre-residual contract: must be rejected by name)
  good/fof.onnx      fof_k = (k+1) * image[k % 3]
and broken variants (wrong names, shapes, kind, metadata, NaN output, fixed size, prior input).
Needs only `onnx` and `numpy`.
"""
import os

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

HERE = os.path.dirname(os.path.abspath(__file__))
R, N, C = 16, 4, 4
W_ENC = np.zeros((C, 3 + N + 3), np.float32)
W_ENC[0, 0] = 1.0  # feature 0 = image R
W_ENC[1, 3] = 1.0  # feature 1 = fof 0
W_ENC[2, 9] = 1.0  # feature 2 = normal z
W_ENC[3, 1] = 0.5  # feature 3 = 0.5 image G + 0.25 fof 3
W_ENC[3, 6] = 0.25


def meta(kind, **extra):
    m = {"r2human.format": "1", "r2human.kind": kind, "r2human.tier": "test", "r2human.resolution": str(R),
         "r2human.fof_n": str(N), "r2human.recipe": "tests/data/neural/make_fixtures.py"}
    if kind != "fof":
        m["r2human.feature_channels"] = str(C)
    m.update({k.replace("__", "."): v for k, v in extra.items()})
    return {k: v for k, v in m.items() if v is not None}


def save(path, nodes, inputs, outputs, inits, metadata):
    graph = helper.make_graph(nodes, os.path.basename(path), inputs, outputs, inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="r2human-fixtures")
    model.ir_version = 8
    for k, v in metadata.items():
        model.metadata_props.append(onnx.StringStringEntryProto(key=k, value=v))
    onnx.checker.check_model(model)
    full = os.path.join(HERE, path)
    os.makedirs(os.path.dirname(full), exist_ok=True)
    onnx.save(model, full)


def t(name, shape):
    return helper.make_tensor_value_info(name, TensorProto.FLOAT, shape)


def encoder(path, image_ch=3, metadata=None):
    nodes = [
        helper.make_node("Concat", ["image", "fof", "normals"], ["x"], axis=1),
        helper.make_node("AveragePool", ["x"], ["p"], kernel_shape=[4, 4], strides=[4, 4]),
        helper.make_node("Conv", ["p", "w"], ["features"]),
    ]
    w = np.zeros((C, image_ch + N + 3, 1, 1), np.float32)
    w[:, : W_ENC.shape[1], 0, 0] = W_ENC[:, : image_ch + N + 3]
    save(path, nodes, [t("image", [1, image_ch, R, R]), t("fof", [1, N, R, R]), t("normals", [1, 3, R, R])],
         [t("features", [1, C, R // 4, R // 4])], [numpy_helper.from_array(w, "w")],
         metadata if metadata is not None else meta("encoder"))


def decoder(path, feat_name="features", nan=False, fixed=None, metadata=None, channels=C, residual=True):
    h, w = fixed if fixed else ("h", "w")
    starts, ends, axes = (numpy_helper.from_array(np.array(v, np.int64), n)
                          for v, n in (([0], "s0"), ([3], "s3"), ([1], "ax")))
    s4 = numpy_helper.from_array(np.array([3], np.int64), "s4a")
    e4 = numpy_helper.from_array(np.array([4], np.int64), "s4b")
    k3 = numpy_helper.from_array(np.full((3, 1, 3, 3), 0.1, np.float32), "k3")
    half = numpy_helper.from_array(np.array(0.5, np.float32), "half")
    quarter = numpy_helper.from_array(np.array(0.25, np.float32), "quarter")
    zero = numpy_helper.from_array(np.array(0.0, np.float32), "zero")
    scales = numpy_helper.from_array(np.array([1, 1, 4, 4], np.float32), "scales")
    nodes = [
        helper.make_node("Slice", [feat_name, "s0", "s3", "ax"], ["f3"]),
        helper.make_node("Slice", [feat_name, "s4a", "s4b", "ax"], ["f1"]),
        helper.make_node("Mul", ["zmap", "half"], ["zt"]),
        helper.make_node("Mul", ["normals", "quarter"], ["nt"]),
        helper.make_node("Conv", ["f1", "k3"], ["ct"], pads=[1, 1, 1, 1]),
        helper.make_node("AveragePool", ["f3"], ["pooled"], kernel_shape=[4, 4], strides=[4, 4]),
        helper.make_node("Resize", ["pooled", "", "scales"], ["up"], mode="nearest"),
        helper.make_node("Mul", ["up", "zero"], ["upz"]),
        helper.make_node("Add", ["f3", "zt"], ["a1"]),
        helper.make_node("Add", ["a1", "nt"], ["a2"]),
        helper.make_node("Add", ["a2", "ct"], ["a3"]),
        helper.make_node("Add", ["a3", "upz"], ["a3b"]),
    ]
    last = "rgb" if not nan else "a4"
    if residual:
        nodes.append(helper.make_node("Add", ["a3b", "warped_rgb"], [last]))
    else:
        nodes.append(helper.make_node("Identity", ["a3b"], [last]))
    if nan:  # sqrt of a negative number: NaN everywhere
        nodes += [helper.make_node("Abs", ["a4"], ["ab"]),
                  helper.make_node("Neg", ["ab"], ["ng"]),
                  helper.make_node("Sub", ["ng", "half"], ["neg"]),
                  helper.make_node("Sqrt", ["neg"], ["rgb"])]
    inputs = [t(feat_name, [1, channels, h, w]), t("zmap", [1, 1, h, w]), t("normals", [1, 3, h, w])]
    if residual:
        inputs.append(t("warped_rgb", [1, 3, h, w]))
    save(path, nodes, inputs, [t("rgb", [1, 3, h, w])], [starts, ends, axes, s4, e4, k3, half, quarter, zero, scales],
         metadata if metadata is not None else meta("decoder", r2human__stride="4"))


def fof(path, prior=False, metadata=None):
    w = np.zeros((N, 3, 1, 1), np.float32)
    for k in range(N):
        w[k, k % 3, 0, 0] = k + 1
    inits = [numpy_helper.from_array(w, "w")]
    inputs = [t("image", [1, 3, R, R])]
    if prior:
        nodes = [helper.make_node("Conv", ["image", "w"], ["c"]), helper.make_node("Add", ["c", "prior"], ["fof"])]
        inputs.append(t("prior", [1, N, R, R]))
    else:
        nodes = [helper.make_node("Conv", ["image", "w"], ["fof"])]
    save(path, nodes, inputs, [t("fof", [1, N, R, R])], inits, metadata if metadata is not None else meta("fof"))


if __name__ == "__main__":
    encoder("good/encoder.onnx")
    decoder("good/decoder.onnx")
    fof("good/fof.onnx")
    fof("fof_prior.onnx", prior=True)
    decoder("decoder_fixed.onnx", fixed=(8, 8))
    decoder("decoder_nan.onnx", nan=True)
    decoder("decoder_wrong_name.onnx", feat_name="feat")
    decoder("decoder_3_inputs.onnx", residual=False)
    encoder("encoder_wrong_channels.onnx", image_ch=5)
    encoder("encoder_labelled_decoder.onnx", metadata=meta("decoder"))
    encoder("encoder_no_fof_n.onnx", metadata=meta("encoder", r2human__fof_n=None))
    decoder("decoder_5_channels.onnx", channels=5,
            metadata=meta("decoder", r2human__stride="4", r2human__feature_channels="5"))
    print("fixtures written to", HERE)
