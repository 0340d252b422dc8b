#!/usr/bin/env bash
# Opt-in GPU runtime for the neural networks (run by `bash scripts/setup.sh --gpu`, or on its own): ONNX Runtime's
# GPU build and the CUDA 13 / cuDNN 9 / TensorRT 10 runtime libraries it was built for, all from PyPI wheels,
# unpacked into the git-ignored `.tools/onnxruntime-gpu`. Nothing here touches the CPU install
# (`.tools/onnxruntime`, scripts/setup.d/neural.sh) or the system.
#
# Versions are pinned below and checked against each other: every pin must satisfy the onnxruntime-gpu wheel's own
# requirements for its `cuda` and `cudnn` extras and every wheel's declared dependencies, and every shared library
# the CUDA and TensorRT providers need (DT_NEEDED, followed transitively, plus cuDNN's sub-libraries, which it opens
# by name) must resolve inside the installed tree. The one library no wheel ships is the NVIDIA driver's
# libcuda.so.1: it comes with the GPU driver, and without it the providers report "no NVIDIA driver".
# The result is `.tools/onnxruntime-gpu/r2human-gpu-libs.txt`: the libraries in load order, which r2human opens by
# absolute path before ONNX Runtime registers a provider (no LD_LIBRARY_PATH needed), and what each provider needs.
#
# TensorRT's full libraries (libnvinfer.so.10 with its builder and ONNX parser) are on PyPI only as a placeholder
# source package that fetches the real wheel from NVIDIA's own package index; where that index is unreachable the
# TensorRT step fails, this script says so, and CUDA + CPU stay installed (`r2human doctor` names the missing
# libraries). R2HUMAN_TENSORRT_INDEX=URL passes an extra index (a mirror of NVIDIA's) to that one pip call.
# Idempotent: a finished install is only re-checked. Usage: bash scripts/setup-gpu.sh
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
DEST="$ROOT/.tools/onnxruntime-gpu"
MANIFEST="$DEST/r2human-gpu-libs.txt"
STAMP="$DEST/r2human-gpu-pins.txt"

# The pins. ONNX Runtime is the CPU build's version (scripts/setup.d/neural.sh); its GPU wheel is built for
# CUDA 13 (libcudart.so.13, libcublas.so.13), cuDNN 9 and TensorRT 10 (libnvinfer.so.10). The CUDA wheels are one
# toolkit release (13.5); CUDA's minor-version compatibility runs them on any CUDA 13 driver (>= 580).
ORT_GPU="onnxruntime-gpu==1.31.1"
CUDA_PINS=(
    "nvidia-cuda-runtime==13.5.37"
    "nvidia-cublas==13.10.0.20"
    "nvidia-curand==10.4.5.25"
    "nvidia-cufft==12.5.0.14"
    "nvidia-cuda-nvrtc==13.5.37"
    "nvidia-nvjitlink==13.5.37"
    "nvidia-cudnn-cu13==9.28.1.4"
)
TRT_PIN="tensorrt-cu13-libs==10.16.1.11"
ORT_LIB="$DEST/onnxruntime/capi/libonnxruntime.so.1.31.1"

die() { echo "setup-gpu: $*" >&2; exit 1; }
if [ "$(uname -s)-$(uname -m)" != "Linux-x86_64" ]; then
    die "the GPU wheels are installed for Linux x86_64 only (this is $(uname -s) $(uname -m))"
fi
if ! command -v python3 >/dev/null 2>&1 || ! python3 -m pip --version >/dev/null 2>&1; then
    apt-get update
    apt-get install -y --no-install-recommends python3 python3-pip
fi
command -v readelf >/dev/null 2>&1 || { apt-get update; apt-get install -y --no-install-recommends binutils; }

pip_install() {
    python3 -m pip install --no-deps --no-input --disable-pip-version-check --upgrade --quiet \
        --target "$DEST" "$@"
}
pins_text="$(printf '%s\n' "$ORT_GPU" "${CUDA_PINS[@]}" "$TRT_PIN")"
start=$(date +%s)
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$pins_text" ] && [ -f "$ORT_LIB" ]; then
    echo "setup-gpu: the pinned wheels are installed in $DEST; checking them"
else
    mkdir -p "$DEST"
    rm -f "$STAMP" "$MANIFEST"
    echo "setup-gpu: installing $ORT_GPU and ${CUDA_PINS[*]} into $DEST (about 1.5 GB to download)"
    pip_install --only-binary=:all: "$ORT_GPU" "${CUDA_PINS[@]}" \
        || die "pip could not install the pinned ONNX Runtime GPU / CUDA / cuDNN wheels (see its message above)"
    printf '%s\n' "$pins_text" > "$STAMP"
fi
[ -f "$ORT_LIB" ] || die "the $ORT_GPU wheel did not contain $ORT_LIB"
# TensorRT is tried on every run until it is there (its index may be reachable next time).
if [ ! -d "$DEST/tensorrt_libs" ]; then
    echo "setup-gpu: installing $TRT_PIN"
    trt_extra=()
    if [ -n "${R2HUMAN_TENSORRT_INDEX:-}" ]; then trt_extra=(--extra-index-url "$R2HUMAN_TENSORRT_INDEX"); fi
    if ! trt_log="$(pip_install "${trt_extra[@]}" "$TRT_PIN" 2>&1)"; then
        echo "$trt_log" | tail -n 5 >&2
        echo "setup-gpu: WARNING: TensorRT ($TRT_PIN) was not installed: PyPI holds only a placeholder that" \
             "downloads the real wheel from NVIDIA's own package index, which pip could not reach here." \
             "The CUDA and CPU providers are installed; for TensorRT, rerun on a machine that reaches that index" \
             "or set R2HUMAN_TENSORRT_INDEX to a mirror of it." >&2
    fi
fi

# Check the pins against each other and write the manifest (exit 1 with the reason when something does not fit).
python3 - "$DEST" "$MANIFEST" <<'PY'
import os, re, subprocess, sys
from pathlib import Path
try:
    from packaging.requirements import Requirement
    from packaging.version import Version
except ImportError:  # pip always vendors it
    from pip._vendor.packaging.requirements import Requirement
    from pip._vendor.packaging.version import Version

dest, manifest = Path(sys.argv[1]), Path(sys.argv[2])

def fail(msg):
    print(f"setup-gpu: {msg}", file=sys.stderr)
    sys.exit(1)

# 1. Versions against each other: the installed distributions and their declared requirements.
dists = {}
for info in dest.glob("*.dist-info"):
    meta = (info / "METADATA").read_text(errors="replace")
    name = re.search(r"^Name: (.+)$", meta, re.M).group(1).strip()
    version = re.search(r"^Version: (.+)$", meta, re.M).group(1).strip()
    reqs = re.findall(r"^Requires-Dist: (.+)$", meta, re.M)
    dists[re.sub(r"[-_.]+", "-", name).lower()] = (Version(version), reqs)
problems = []
for name, (version, reqs) in sorted(dists.items()):
    for text in reqs:
        req = Requirement(text)
        dep = re.sub(r"[-_.]+", "-", req.name).lower()
        # Only requirements among the runtime wheels matter: ORT's extras `cuda` and `cudnn` are its own table of
        # the CUDA versions it was built for; its Python-only dependencies (numpy, protobuf, ...) are not used.
        if req.marker is not None:
            if name == "onnxruntime-gpu":
                if not any(req.marker.evaluate({"extra": e}) for e in ("cuda", "cudnn")):
                    continue
            elif not req.marker.evaluate({"extra": ""}):
                continue
        if not dep.startswith(("nvidia-", "tensorrt")):
            continue
        if dep not in dists:
            if name == "onnxruntime-gpu":
                problems.append(f"{name} {version} wants {text} (extra), which is not pinned")
            continue
        if not req.specifier.contains(dists[dep][0], prereleases=True):
            problems.append(f"{name} {version} needs {req}, pinned {dep} is {dists[dep][0]}")
if problems:
    fail("the pinned versions do not fit together:\n  " + "\n  ".join(problems)
         + "\nchange the pins at the top of scripts/setup-gpu.sh")

# 2. Shared libraries: every soname the providers need, followed through the tree.
def elf_dynamic(path):
    out = subprocess.run(["readelf", "-d", str(path)], capture_output=True, text=True).stdout
    needed = re.findall(r"\(NEEDED\)\s+Shared library: \[(.+?)\]", out)
    soname = re.findall(r"\(SONAME\)\s+Library soname: \[(.+?)\]", out)
    return needed, (soname[0] if soname else None)

tree = {}  # soname or file name -> path
for d in [dest / "nvidia", dest / "tensorrt_libs", dest / "onnxruntime" / "capi"]:
    if not d.is_dir():
        continue
    for p in sorted(d.rglob("*.so*")):
        if not p.is_file() or p.suffix == ".py" or ".so" not in p.name:
            continue
        needed, soname = elf_dynamic(p)
        tree.setdefault(p.name, p)
        if soname:
            tree.setdefault(soname, p)

def on_system(soname):
    r = subprocess.run(["/sbin/ldconfig", "-p"], capture_output=True, text=True).stdout
    return re.search(r"^\s+" + re.escape(soname) + r" ", r, re.M) is not None

DRIVER = {"libcuda.so.1", "libnvidia-ml.so.1"}
capi = dest / "onnxruntime" / "capi"
cudnn_subs = sorted(n for n in tree if re.fullmatch(r"libcudnn_[a-z_]+\.so\.9", n))
order, seen = [], set()
def visit(path, status):
    """Depth-first: a library's dependencies come before it in `order`."""
    if path in seen:
        return
    seen.add(path)
    needed, _ = elf_dynamic(path)
    for so in needed:
        if so in tree:
            visit(tree[so], status)
            status.setdefault(so, "tree")
        elif so in DRIVER:
            status.setdefault(so, "driver")
        elif on_system(so):
            status.setdefault(so, "system")
        else:
            status.setdefault(so, "missing")
    if path.parent != capi:
        order.append(path)

report, fatal = {}, []
trt_installed = (dest / "tensorrt_libs").is_dir()
for provider in ("cuda", "tensorrt"):
    lib = capi / f"libonnxruntime_providers_{provider}.so"
    if not lib.is_file():
        fail(f"{lib} is missing from the onnxruntime-gpu wheel")
    status = {}
    visit(lib, status)
    # Libraries opened by name at run time rather than linked: cuDNN's sub-libraries (cuDNN opens them itself; the
    # CUDA provider reaches cuDNN through its kernels), and those onnxruntime-gpu's `cuda` extra names (cuFFT,
    # NVRTC and nvJitLink for some kernels) or TensorRT's plugins.
    by_name = ["libcudnn.so.9"] + cudnn_subs
    by_name += ["libcufft.so.12", "libnvrtc.so.13", "libnvJitLink.so.13"] if provider == "cuda" else []
    by_name += ["libnvinfer_plugin.so.10"] if provider == "tensorrt" and trt_installed else []
    for so in by_name:
        if so in tree:
            visit(tree[so], status)
            status.setdefault(so, "tree")
        elif provider == "cuda":
            status.setdefault(so, "missing")
    missing = sorted(s for s, v in status.items() if v == "missing")
    report[provider] = status
    if missing and (provider == "cuda" or trt_installed):
        fatal.append(f"the {provider} provider needs {', '.join(missing)}, found neither in {dest} nor on the system")
if fatal:
    fail("\n  ".join(["library check failed:"] + fatal) + "\nreinstall with `rm -rf " + str(dest)
         + " && bash scripts/setup-gpu.sh`")

lines = ["# Written by scripts/setup-gpu.sh: the GPU runtime libraries of this tree.",
         "# preload<TAB>path (relative to this folder), in load order: dependencies first.",
         "# need<TAB>provider<TAB>soname<TAB>tree|system|driver|missing (as found at install time)."]
lines += [f"preload\t{p.relative_to(dest)}" for p in order]
for provider, status in report.items():
    lines += [f"need\t{provider}\t{so}\t{v}" for so, v in sorted(status.items())]
manifest.write_text("\n".join(lines) + "\n")
for provider, status in report.items():
    counts = {k: sum(1 for v in status.values() if v == k) for k in ("tree", "system", "driver", "missing")}
    missing = sorted(s for s, v in status.items() if v == "missing")
    driver = sorted(s for s, v in status.items() if v == "driver")
    text = f"{provider} provider: {counts['tree']} libraries in the tree, {counts['system']} from the system"
    if driver:
        text += f", from the NVIDIA driver: {' '.join(driver)}"
    if missing:
        text += f", MISSING: {' '.join(missing)}"
    print(f"setup-gpu: {text}")
print(f"setup-gpu: versions consistent ({len(dists)} wheels); {len(order)} libraries to preload; manifest {manifest}")
PY

size=$(du -sh "$DEST" | cut -f1)
if [ -e /dev/nvidia0 ] || command -v nvidia-smi >/dev/null 2>&1; then
    echo "setup-gpu: NVIDIA driver present"
else
    echo "setup-gpu: no NVIDIA driver on this machine (libcuda.so.1 comes with it): the GPU providers will say so"
fi
echo "setup-gpu: done in $(( $(date +%s) - start )) s, $size in $DEST. Check with: r2human doctor"
