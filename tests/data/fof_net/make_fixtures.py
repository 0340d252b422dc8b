"""Writes the tiny residual FOF nets that tests/fof_net.rs loads (run: .venv/bin/python tests/data/fof_net/make_fixtures.py).

Each has the shipped FOF net's contract (inputs `image` [1,3,R,R], `prior` [1,N,R,R]; output `fof` [1,N,R,R];
r2human metadata with kind `fof`, R = 16, N = 4) and a closed-form output:
  fof_identity.onnx  fof = prior + 0 * image            (an untrained residual net: must give the prior back)
  fof_offset.onnx    fof = prior + [0.25, 0, 0, 0]      (thicker everywhere: c0 is twice the occupied ray fraction)
  fof_nan.onnx       fof = prior + NaN                  (a broken model: must be an error or a fallback, never a mesh)
  fof_zero.onnx      fof = 0                            (erases every column: must not erase the silhouette)
  fof_identity32.onnx  the identity with N = 32 (the pipeline's default order: `r2human eval` with it must score the
                     FOF-net geometry exactly like the inflation prior)
  fof_body.onnx      inputs image, body, prior (`r2human.fof_inputs = image,body,prior`, residual `body`):
                     fof = body + 0 * prior + [0.25, 0, 0, 0]  (the reference's inputs; must refine the body FOF)
  fof_geometry.onnx  inputs body, prior only, no image (`r2human.fof_inputs = body,prior`, residual `prior`):
                     fof = prior + 0 * body + [0.25, 0, 0, 0]  (a net that sees geometry only: no photo fed)
  fof_bad_inputs.onnx  `r2human.fof_inputs = image,depth` (an input this build cannot feed: a clear error)
  fof_bad_residual.onnx  inputs image, prior but `r2human.residual = body` (a base it does not take: an error)
  placement_split.onnx, placement_split32.onnx  placement nets (inputs body, prior; output shift [1,1,R,R]):
                     shift 0.1 on the left half, -0.2 on the right (N = 4 and N = 32)
  placement_nan32.onnx  a placement net (N = 32) whose shift is NaN on the left half (a broken model)
Needs only `onnx` and `numpy`.
"""
import os

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

HERE = os.path.dirname(os.path.abspath(__file__))
R, N = 16, 4


def save_body(name, offset, fof_inputs="image,body,prior", residual="body", inputs=("body", "prior"), image=True):
    """A net on `inputs` (after image, when `image`): fof = <residual input> + offset + 0 * (every other input)."""
    zero = numpy_helper.from_array(np.zeros((1, 1, 1, 1), np.float32), "zero")
    off = numpy_helper.from_array(np.asarray(offset, np.float32).reshape(1, N, 1, 1), "offset")
    if image:
        nodes = [helper.make_node("ReduceMean", ["image"], ["m"], keepdims=1),
                 helper.make_node("Mul", ["m", "zero"], ["acc0"])]
    else:
        nodes = [helper.make_node("Identity", ["zero"], ["acc0"])]
    base = residual if residual in inputs else inputs[0]
    for k, other in enumerate(inputs):
        if other != base:
            nodes.append(helper.make_node("Mul", [other, "zero"], [f"z{k}"]))
            nodes.append(helper.make_node("Add", [f"acc{k}", f"z{k}"], [f"acc{k + 1}"]))
        else:
            nodes.append(helper.make_node("Identity", [f"acc{k}"], [f"acc{k + 1}"]))
    nodes.append(helper.make_node("Add", [base, "offset"], ["b1"]))
    nodes.append(helper.make_node("Add", ["b1", f"acc{len(inputs)}"], ["fof"]))
    graph = helper.make_graph(
        nodes, name,
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, R, R])] * image +
        [helper.make_tensor_value_info(i, TensorProto.FLOAT, [1, N, R, R]) for i in inputs],
        [helper.make_tensor_value_info("fof", TensorProto.FLOAT, [1, N, R, R])], [zero, off])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="r2human-fixtures")
    model.ir_version = 8
    meta = {"r2human.format": "1", "r2human.kind": "fof", "r2human.tier": "test", "r2human.resolution": str(R),
            "r2human.fof_n": str(N), "r2human.residual": residual, "r2human.fof_inputs": fof_inputs,
            "r2human.recipe": "tests/data/fof_net/make_fixtures.py"}
    for k, v in meta.items():
        model.metadata_props.append(onnx.StringStringEntryProto(key=k, value=v))
    onnx.checker.check_model(model)
    onnx.save(model, os.path.join(HERE, name))


def save(name, offset, n=N, keep_prior=1.0):
    zero = numpy_helper.from_array(np.zeros((1, 1, 1, 1), np.float32), "zero")
    off = numpy_helper.from_array(np.asarray(offset, np.float32).reshape(1, n, 1, 1), "offset")
    keep = numpy_helper.from_array(np.array(keep_prior, np.float32), "keep")
    nodes = [
        helper.make_node("Mul", ["prior", "keep"], ["p0"]),
        # 0 * mean(image) keeps `image` a used input, as in a real net.
        helper.make_node("ReduceMean", ["image"], ["m"], keepdims=1),
        helper.make_node("Mul", ["m", "zero"], ["m0"]),
        helper.make_node("Add", ["p0", "offset"], ["p1"]),
        helper.make_node("Add", ["p1", "m0"], ["fof"]),
    ]
    graph = helper.make_graph(
        nodes, name,
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, R, R]),
         helper.make_tensor_value_info("prior", TensorProto.FLOAT, [1, n, R, R])],
        [helper.make_tensor_value_info("fof", TensorProto.FLOAT, [1, n, R, R])], [zero, off, keep])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="r2human-fixtures")
    model.ir_version = 8
    meta = {"r2human.format": "1", "r2human.kind": "fof", "r2human.tier": "test", "r2human.resolution": str(R),
            "r2human.fof_n": str(n), "r2human.residual": "prior", "r2human.recipe": "tests/data/fof_net/make_fixtures.py"}
    for k, v in meta.items():
        model.metadata_props.append(onnx.StringStringEntryProto(key=k, value=v))
    onnx.checker.check_model(model)
    onnx.save(model, os.path.join(HERE, name))


save("fof_identity.onnx", [0, 0, 0, 0])
save("fof_offset.onnx", [0.25, 0, 0, 0])
save("fof_nan.onnx", [float("nan"), 0, 0, 0])
save("fof_identity32.onnx", [0] * 32, n=32)
save("fof_zero.onnx", [0, 0, 0, 0], keep_prior=0.0)
save_body("fof_body.onnx", [0.25, 0, 0, 0])
save_body("fof_geometry.onnx", [0.25, 0, 0, 0], fof_inputs="body,prior", residual="prior", image=False)
save_body("fof_bad_inputs.onnx", [0, 0, 0, 0], fof_inputs="image,depth", residual="prior", inputs=("prior",))
save_body("fof_bad_residual.onnx", [0, 0, 0, 0], fof_inputs="image,prior", residual="body", inputs=("prior",))


def save_placement(name, left, right, n=N):
    """A placement net (`r2human.kind = placement`: inputs body, prior [1,n,R,R] -> shift [1,1,R,R]) whose shift is
    `left` on the model's left half and `right` on its right half, plus 0 * mean(body) + 0 * mean(prior)."""
    zero = numpy_helper.from_array(np.zeros((1, 1, 1, 1), np.float32), "zero")
    pattern = np.full((1, 1, R, R), right, np.float32)
    pattern[..., : R // 2] = left
    shift = numpy_helper.from_array(pattern, "pattern")
    nodes = [
        helper.make_node("ReduceMean", ["body"], ["mb"], keepdims=1),
        helper.make_node("ReduceMean", ["prior"], ["mp"], keepdims=1),
        helper.make_node("Add", ["mb", "mp"], ["m"]),
        helper.make_node("Mul", ["m", "zero"], ["m0"]),
        helper.make_node("Add", ["pattern", "m0"], ["shift"]),
    ]
    graph = helper.make_graph(
        nodes, name,
        [helper.make_tensor_value_info(i, TensorProto.FLOAT, [1, n, R, R]) for i in ("body", "prior")],
        [helper.make_tensor_value_info("shift", TensorProto.FLOAT, [1, 1, R, R])], [zero, shift])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="r2human-fixtures")
    model.ir_version = 8
    meta = {"r2human.format": "1", "r2human.kind": "placement", "r2human.tier": "test", "r2human.resolution": str(R),
            "r2human.fof_n": str(n), "r2human.recipe": "tests/data/fof_net/make_fixtures.py"}
    for k, v in meta.items():
        model.metadata_props.append(onnx.StringStringEntryProto(key=k, value=v))
    onnx.checker.check_model(model)
    onnx.save(model, os.path.join(HERE, name))


# Placement nets (tests/fof_net.rs, `PlacementNet`): a closed-form split shift, the same at N = 32 (the pipeline's
# order), and a broken one.
save_placement("placement_split.onnx", 0.1, -0.2)
save_placement("placement_split32.onnx", 0.1, -0.2, n=32)
save_placement("placement_nan32.onnx", float("nan"), 0.0, n=32)
