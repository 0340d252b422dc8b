"""Convert a small float TFLite CNN (MediaPipe's face landmark model and selfie segmenter) to ONNX, NCHW inside.

Usage: python tflite_to_onnx.py MODEL.tflite OUT.onnx

Why not `tflite2onnx`: version 0.4.1 (the converter `live.sh` uses for the pose model) fails on the face landmark
model in its layout propagation (PReLU slopes of rank 3), and `tf2onnx` needs TensorFlow (a 1.5 GB venv). This
script handles exactly the operators those models have (float16 weights behind DEQUANTIZE, CONV_2D,
DEPTHWISE_CONV_2D, PRELU, ADD, MAX_POOL_2D, PAD; the selfie segmenter's RELU, HARD_SWISH, LOGISTIC, MUL, global
AVERAGE_POOL_2D, RESIZE_BILINEAR and MediaPipe's custom Convolution2DTransposeBias) and refuses any other, so a
changed model fails loudly instead of converting wrongly. The graph keeps the TFLite interface: input NHWC float,
outputs NHWC as TFLite has them. Checked once against tf2onnx's conversion of the face model (max |difference| of
the 1404 landmark outputs on photos: see docs/geometry.md) and against LiteRT (PyPI `ai-edge-litert`) running the
selfie segmenter on the bundled photos (max |difference| 7e-5).

Needs `tflite`, `onnx` and `numpy` (the live-venv of scripts/setup.d/live.sh has them).
"""
import sys

import numpy as np
import onnx
import tflite
from onnx import TensorProto, helper, numpy_helper

OPS = {v: k for k, v in tflite.BuiltinOperator.__dict__.items() if not k.startswith("_")}
DTYPES = {tflite.TensorType.FLOAT32: np.float32, tflite.TensorType.FLOAT16: np.float16,
          tflite.TensorType.INT32: np.int32}


def main(src, dst):
    buf = open(src, "rb").read()
    model = tflite.Model.GetRootAsModel(buf, 0)
    if model.SubgraphsLength() != 1:
        raise SystemExit(f"{src}: {model.SubgraphsLength()} subgraphs, expected 1")
    g = model.Subgraphs(0)

    def tensor(i):
        return g.Tensors(i)

    def name(i):
        return tensor(i).Name().decode()

    def constant(i):
        t = tensor(i)
        data = model.Buffers(t.Buffer()).DataAsNumpy()
        if isinstance(data, int) or data is None or len(data) == 0:
            return None
        dtype = DTYPES.get(t.Type())
        if dtype is None:
            raise SystemExit(f"{src}: tensor {name(i)} has unsupported type {t.Type()}")
        return np.frombuffer(data.tobytes(), dtype=dtype).reshape(t.ShapeAsNumpy())

    consts = {}  # tensor index -> float32 numpy array (NHWC / TFLite layout)
    for i in range(g.TensorsLength()):
        c = constant(i)
        if c is not None:
            consts[i] = c.astype(np.float32) if c.dtype == np.float16 else c

    nodes, inits = [], []
    inputs = [g.Inputs(k) for k in range(g.InputsLength())]
    outputs = [g.Outputs(k) for k in range(g.OutputsLength())]
    if len(inputs) != 1:
        raise SystemExit(f"{src}: {len(inputs)} inputs, expected 1")
    nchw = {}  # tensor index -> ONNX name of its NCHW value

    def init(arr, label):
        n = f"const_{len(inits)}_{label}"
        inits.append(numpy_helper.from_array(np.ascontiguousarray(arr), n))
        return n

    src_name = name(inputs[0])
    nodes.append(helper.make_node("Transpose", [src_name], [src_name + "_nchw"], perm=[0, 3, 1, 2]))
    nchw[inputs[0]] = src_name + "_nchw"

    def activation(out, fused, label):
        if fused == tflite.ActivationFunctionType.NONE:
            return out
        if fused == tflite.ActivationFunctionType.RELU:
            nodes.append(helper.make_node("Relu", [out], [out + "_relu"]))
            return out + "_relu"
        raise SystemExit(f"{src}: fused activation {fused} on {label} not supported")

    def pads_for(opts):
        if opts.Padding() == tflite.Padding.SAME:
            return {"auto_pad": "SAME_UPPER"}
        if opts.Padding() == tflite.Padding.VALID:
            return {"auto_pad": "VALID"}
        raise SystemExit(f"{src}: padding {opts.Padding()} not supported")

    for k in range(g.OperatorsLength()):
        op = g.Operators(k)
        code = model.OperatorCodes(op.OpcodeIndex())
        kind = OPS.get(max(code.BuiltinCode(), code.DeprecatedBuiltinCode()))
        ins = [op.Inputs(j) for j in range(op.InputsLength())]
        out = op.Outputs(0)
        oname = f"t{out}_{name(out)}"
        opts_table = op.BuiltinOptions()
        if kind == "DEQUANTIZE":
            if ins[0] not in consts:
                raise SystemExit(f"{src}: DEQUANTIZE of a non-constant tensor {name(ins[0])}")
            consts[out] = consts[ins[0]].astype(np.float32)
        elif kind in ("CONV_2D", "DEPTHWISE_CONV_2D"):
            if kind == "CONV_2D":
                opts = tflite.Conv2DOptions()
            else:
                opts = tflite.DepthwiseConv2DOptions()
            opts.Init(opts_table.Bytes, opts_table.Pos)
            w = consts[ins[1]]
            b = consts[ins[2]] if len(ins) > 2 and ins[2] >= 0 else None
            attrs = dict(strides=[opts.StrideH(), opts.StrideW()],
                         dilations=[opts.DilationHFactor(), opts.DilationWFactor()], **pads_for(opts))
            if kind == "CONV_2D":
                weight = w.transpose(0, 3, 1, 2)  # OHWI -> OIHW
            else:
                if opts.DepthMultiplier() != 1:
                    raise SystemExit(f"{src}: depth multiplier {opts.DepthMultiplier()} not supported")
                weight = w.transpose(3, 0, 1, 2)  # 1HWC -> C1HW
                attrs["group"] = int(w.shape[3])
            args = [nchw[ins[0]], init(weight, "w")] + ([init(b, "b")] if b is not None else [])
            nodes.append(helper.make_node("Conv", args, [oname], **attrs))
            nchw[out] = activation(oname, opts.FusedActivationFunction(), oname)
        elif kind == "PRELU":
            slope = consts[ins[1]].reshape(-1, 1, 1)  # per channel, broadcast over H, W
            nodes.append(helper.make_node("PRelu", [nchw[ins[0]], init(slope, "slope")], [oname]))
            nchw[out] = oname
        elif kind in ("ADD", "MUL"):
            opts = tflite.AddOptions() if kind == "ADD" else tflite.MulOptions()
            opts.Init(opts_table.Bytes, opts_table.Pos)
            if any(i in consts for i in ins):
                raise SystemExit(f"{src}: {kind} with a constant operand not supported")
            # NCHW on both sides: a [1, 1, 1, C] gate becomes [1, C, 1, 1] and broadcasts over H, W.
            nodes.append(helper.make_node(kind.capitalize(), [nchw[ins[0]], nchw[ins[1]]], [oname]))
            nchw[out] = activation(oname, opts.FusedActivationFunction(), oname)
        elif kind == "MAX_POOL_2D":
            opts = tflite.Pool2DOptions()
            opts.Init(opts_table.Bytes, opts_table.Pos)
            nodes.append(helper.make_node("MaxPool", [nchw[ins[0]]], [oname],
                                          kernel_shape=[opts.FilterHeight(), opts.FilterWidth()],
                                          strides=[opts.StrideH(), opts.StrideW()], **pads_for(opts)))
            nchw[out] = activation(oname, opts.FusedActivationFunction(), oname)
        elif kind == "PAD":
            p = consts[ins[1]].astype(np.int64)  # [4, 2] in NHWC order: (before, after) per axis
            order = [0, 3, 1, 2]
            pads = np.array([p[a, 0] for a in order] + [p[a, 1] for a in order], dtype=np.int64)
            nodes.append(helper.make_node("Pad", [nchw[ins[0]], init(pads, "pads")], [oname], mode="constant"))
            nchw[out] = oname
        elif kind == "RELU":
            nodes.append(helper.make_node("Relu", [nchw[ins[0]]], [oname]))
            nchw[out] = oname
        elif kind == "LOGISTIC":
            nodes.append(helper.make_node("Sigmoid", [nchw[ins[0]]], [oname]))
            nchw[out] = oname
        elif kind == "HARD_SWISH":
            # x * relu6(x + 3) / 6 = x * HardSigmoid(x; alpha 1/6, beta 1/2).
            gate = oname + "_gate"
            nodes.append(helper.make_node("HardSigmoid", [nchw[ins[0]]], [gate], alpha=1.0 / 6.0, beta=0.5))
            nodes.append(helper.make_node("Mul", [nchw[ins[0]], gate], [oname]))
            nchw[out] = oname
        elif kind == "AVERAGE_POOL_2D":
            opts = tflite.Pool2DOptions()
            opts.Init(opts_table.Bytes, opts_table.Pos)
            in_shape = tensor(ins[0]).ShapeAsNumpy()
            whole = (opts.FilterHeight(), opts.FilterWidth()) == (in_shape[1], in_shape[2])
            if not whole or tuple(tensor(out).ShapeAsNumpy()[1:3]) != (1, 1):
                raise SystemExit(f"{src}: only a global AVERAGE_POOL_2D (filter = input size) is supported")
            nodes.append(helper.make_node("GlobalAveragePool", [nchw[ins[0]]], [oname]))
            nchw[out] = activation(oname, opts.FusedActivationFunction(), oname)
        elif kind == "RESIZE_BILINEAR":
            opts = tflite.ResizeBilinearOptions()
            opts.Init(opts_table.Bytes, opts_table.Pos)
            if opts.AlignCorners():
                mode = "align_corners"
            elif opts.HalfPixelCenters():
                mode = "half_pixel"
            else:
                mode = "asymmetric"
            hw = consts[ins[1]].astype(np.int64)
            channels = int(tensor(ins[0]).ShapeAsNumpy()[3])
            sizes = np.array([1, channels, hw[0], hw[1]], dtype=np.int64)
            nodes.append(helper.make_node("Resize", [nchw[ins[0]], "", "", init(sizes, "sizes")], [oname],
                                          mode="linear", coordinate_transformation_mode=mode))
            nchw[out] = oname
        elif kind == "CUSTOM" and code.CustomCode().decode() == "Convolution2DTransposeBias":
            # MediaPipe's transposed convolution with bias; its custom options are TfLiteTransposeConvParams
            # (padding as the C enum TfLitePadding, where 1 is SAME; stride_width, stride_height; int32 each). Only
            # the non-overlapping case (kernel = stride, SAME padding: output = input x stride, no crop) is
            # supported.
            padding, stride_w, stride_h = np.frombuffer(op.CustomOptionsAsNumpy().tobytes(), dtype=np.int32)[:3]
            w = consts[ins[1]]  # OHWI
            b = consts[ins[2]]
            if padding != 1 or (w.shape[1], w.shape[2]) != (stride_h, stride_w):
                raise SystemExit(f"{src}: Convolution2DTransposeBias only with kernel = stride and SAME padding")
            weight = w.transpose(3, 0, 1, 2)  # OHWI -> (in, out, kH, kW)
            nodes.append(helper.make_node("ConvTranspose", [nchw[ins[0]], init(weight, "w"), init(b, "b")], [oname],
                                          strides=[int(stride_h), int(stride_w)],
                                          kernel_shape=[int(w.shape[1]), int(w.shape[2])]))
            nchw[out] = oname
        else:
            raise SystemExit(f"{src}: operator {kind} not supported by this converter")

    graph_outputs = []
    for o in outputs:
        n = name(o)
        nodes.append(helper.make_node("Transpose", [nchw[o]], [n + "_nhwc"], perm=[0, 2, 3, 1]))
        nodes.append(helper.make_node("Identity", [n + "_nhwc"], [n]))
        graph_outputs.append(helper.make_tensor_value_info(n, TensorProto.FLOAT, [int(d) for d in tensor(o).ShapeAsNumpy()]))
    graph = helper.make_graph(
        nodes, "tflite_converted",
        [helper.make_tensor_value_info(src_name, TensorProto.FLOAT, [int(d) for d in tensor(inputs[0]).ShapeAsNumpy()])],
        graph_outputs, initializer=inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], producer_name="r2human tflite_to_onnx")
    m.ir_version = 8
    onnx.checker.check_model(m)
    onnx.save(m, dst)
    print(f"wrote {dst}: {len(nodes)} nodes, {len(inits)} constants")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    main(sys.argv[1], sys.argv[2])
