"""Reference outputs for the policy pre/post-processing parity test (test time only).

usage: preprocess_fixtures.py OUT_DIR [FRAME.png ...] [TOP.npy ...]

Run by `policies/tests/preprocess_parity.rs` with the reference venv's python (numpy, Pillow,
robosuite), into a temporary folder. Each step is computed the way the published evaluation code
computes it, on the same deterministic images the Rust test reads back:

images (per input `<name>`; uint8 HxWx3 `.npy`):
  <name>__input.npy          the image as the env returns it (a synthetic 256x256 pattern, a
                             non-square 256x200 one, and each FRAME.png given: real camera frames)
  <name>__rot180.npy         img[::-1, ::-1]                      (OpenVLA, OpenVLA-OFT, openpi)
  <name>__lanczos224.npy     PIL Image.resize((224, 224), LANCZOS) of rot180
  <name>__bilinear224.npy    PIL Image.resize((224, 224), BILINEAR) of rot180
  synthetic256__{lanczos,bilinear}_<W>x<H>.npy  the same to non-square sizes (pass order)
  <name>__resize_with_pad224.npy  openpi_client.image_tools.resize_with_pad(rot180, 224, 224)
                             (PIL BILINEAR, black padding), transcribed below
  <name>__jpeg95.npy         PIL JPEG quality 95 (4:2:0) round trip of rot180 (libjpeg-turbo, as
                             tf.io.encode_jpeg/decode_jpeg of the OpenVLA loop use)
  <name>__crop09.npy         tf.image.crop_and_resize (bilinear, box of area 0.9 centred,
                             224x224) between tf.image.convert_image_dtype uint8 -> float32 and
                             back (saturate), on lanczos224: transcribed to float32 numpy below
                             (TensorFlow is not in the venv; the transcription follows TF's
                             CPU kernel, crop_and_resize_op.cc, and image_ops_impl.py)
  <name>__openvla.npy        the whole OpenVLA chain: rot180 -> jpeg95 -> lanczos224 -> crop09

ALOHA-sim's `cam_high` (openpi's examples/aloha_sim; per input `<name>`, listed in meta.json's
"aloha_images"): a synthetic 480x640 pattern and each TOP.npy given (an upright 480x640x3 `top`
frame of the ALOHA bundle's golden episodes), no rotation:
  <name>__input.npy          the frame as gym-aloha returns obs["pixels"]["top"]
  <name>__pad224.npy         resize_with_pad(frame, 224, 224), HWC (the client then makes it CHW)

proprio.json (floats as IEEE bit patterns): quaternions (x, y, z, w) and robosuite.utils.transform_utils.quat2axisangle of
  each (the function the OpenVLA/OFT/openpi loops copy), plus a LIBERO state
  concat(eef_pos, quat2axisangle(eef_quat), gripper_qpos).
actions.json: dataset statistics in the `norm_stats` layout, normalized actions, and
  prismatic's predict_action un-normalisation (q01/q99 with the mask), then
  experiments/robot/robot_utils.normalize_gripper_action(binarize=True) and
  invert_gripper_action, transcribed below.
"""

import io
import json
import math
import sys
from pathlib import Path

import numpy as np
from PIL import Image

import robosuite.utils.transform_utils as T


def synthetic(h, w):
    """Gradients, a fine checkerboard, a disc and a diagonal line: every resampling path is hit."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    r = (x * 255.0 / (w - 1)).round()
    g = (y * 255.0 / (h - 1)).round()
    b = 127.5 + 127.5 * np.sin(x / 7.0) * np.cos(y / 11.0)
    img = np.stack([r, g, b], axis=-1)
    checker = ((x.astype(int) // 3 + y.astype(int) // 3) % 2 == 0) & (x > w * 0.6) & (y < h * 0.4)
    img[checker] = [250, 250, 250]
    disc = (x - w * 0.3) ** 2 + (y - h * 0.7) ** 2 < (min(h, w) * 0.15) ** 2
    img[disc] = [10, 200, 30]
    line = np.abs(x - y) < 1.0
    img[line] = [0, 0, 0]
    return np.clip(img.round(), 0, 255).astype(np.uint8)


def pil_resize(img, size, method):
    return np.asarray(Image.fromarray(img).resize((size, size), resample=method))


def resize_with_pad(img, height, width, method=Image.BILINEAR):
    """openpi_client.image_tools.resize_with_pad for one HxWx3 uint8 image (its PIL path)."""
    image = Image.fromarray(img)
    cur_width, cur_height = image.size
    if cur_width == width and cur_height == height:
        return img
    ratio = max(cur_width / width, cur_height / height)
    resized_height = int(cur_height / ratio)
    resized_width = int(cur_width / ratio)
    resized = image.resize((resized_width, resized_height), resample=method)
    zero = Image.new(resized.mode, (width, height), 0)
    pad_height = max(0, int((height - resized_height) / 2))
    pad_width = max(0, int((width - resized_width) / 2))
    zero.paste(resized, (pad_width, pad_height))
    return np.asarray(zero)


def jpeg_round_trip(img, quality=95):
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="JPEG", quality=quality)
    buf.seek(0)
    return np.asarray(Image.open(buf).convert("RGB"))


def tf_center_crop(img, area=0.9, size=224):
    """float32 transcription of OpenVLA's crop_and_resize between convert_image_dtype calls.

    convert_image_dtype(uint8 -> float32): cast, times float32(1/255).
    crop_and_resize (bilinear, CPU kernel): box (y1, x1, y2, x2) = ((1-s)/2, (1-s)/2, (1+s)/2 ...)
      with s = sqrt(area) in float32; in_y = y1*(H-1) + y*height_scale, height_scale =
      (y2-y1)*(H-1)/(size-1); top = floor(in_y), bottom = ceil(in_y), lerp in float32.
    clip to [0, 1]; convert_image_dtype(float32 -> uint8, saturate): times 255.5, truncate.
    """
    f32 = np.float32
    h, w, _ = img.shape
    im = img.astype(f32) * f32(1.0 / 255.0)
    s = np.sqrt(f32(area))
    s = np.clip(s, f32(0), f32(1))
    off = (f32(1) - s) / f32(2)
    y1, x1, y2, x2 = off, off, off + s, off + s
    hs = (y2 - y1) * f32(h - 1) / f32(size - 1)
    ws = (x2 - x1) * f32(w - 1) / f32(size - 1)
    out = np.zeros((size, size, 3), f32)
    for yy in range(size):
        in_y = y1 * f32(h - 1) + f32(yy) * hs
        ty, by = int(math.floor(in_y)), int(math.ceil(in_y))
        yl = f32(in_y - f32(ty))
        for xx in range(size):
            in_x = x1 * f32(w - 1) + f32(xx) * ws
            lx, rx = int(math.floor(in_x)), int(math.ceil(in_x))
            xl = f32(in_x - f32(lx))
            tl, tr, bl, br = im[ty, lx], im[ty, rx], im[by, lx], im[by, rx]
            top = tl + (tr - tl) * xl
            bottom = bl + (br - bl) * xl
            out[yy, xx] = top + (bottom - top) * yl
    out = np.clip(out, f32(0), f32(1))
    return np.clip(out * f32(255.5), 0, 255).astype(np.uint8)


RESIZE_SHAPES = [(224, 200), (200, 224), (300, 128), (128, 300), (100, 90), (256, 250), (250, 256)]


def images(out: Path, frames):
    inputs = {"synthetic256": synthetic(256, 256), "synthetic256x200": synthetic(256, 200)}
    for p in frames:
        inputs[Path(p).stem.replace("__", "_")] = np.asarray(Image.open(p).convert("RGB"))
    names = []
    for name, img in inputs.items():
        rot = np.ascontiguousarray(img[::-1, ::-1])
        lanczos = pil_resize(rot, 224, Image.LANCZOS)
        steps = {
            "input": img,
            "rot180": rot,
            "lanczos224": lanczos,
            "bilinear224": pil_resize(rot, 224, Image.BILINEAR),
            "resize_with_pad224": resize_with_pad(rot, 224, 224),
            "jpeg95": jpeg_round_trip(rot),
            "crop09": tf_center_crop(lanczos),
            "openvla": tf_center_crop(pil_resize(jpeg_round_trip(rot), 224, Image.LANCZOS)),
        }
        if name == "synthetic256":
            # Pillow runs the vertical pass first when it shrinks more: both orders covered.
            for w, h in RESIZE_SHAPES:
                steps[f"lanczos_{w}x{h}"] = np.asarray(Image.fromarray(rot).resize((w, h), Image.LANCZOS))
                steps[f"bilinear_{w}x{h}"] = np.asarray(Image.fromarray(rot).resize((w, h), Image.BILINEAR))
        for step, arr in steps.items():
            np.save(out / f"{name}__{step}.npy", np.ascontiguousarray(arr, dtype=np.uint8))
        names.append(name)
    return names


def aloha_images(out: Path, tops):
    inputs = {"aloha_synthetic480x640": synthetic(480, 640)}
    for p in tops:
        inputs[f"aloha_{Path(p).parent.name}_{Path(p).stem}"] = np.load(p)
    for name, img in inputs.items():
        assert img.shape == (480, 640, 3) and img.dtype == np.uint8, (name, img.shape, img.dtype)
        np.save(out / f"{name}__input.npy", np.ascontiguousarray(img))
        np.save(out / f"{name}__pad224.npy", np.ascontiguousarray(resize_with_pad(img, 224, 224), dtype=np.uint8))
    return list(inputs)


def bits(a):
    """float64 values as their IEEE bit patterns (JSON readers need not round-trip floats)."""
    return [int(v) for v in np.asarray(a, dtype=np.float64).view(np.uint64)]


def proprio(out: Path):
    rng = np.random.RandomState(0)
    quats = [
        [0.0, 0.0, 0.0, 1.0],  # identity: den == 0, zeros
        [0.0, 0.0, 0.0, -1.0],  # identity, other sign: zeros too
        [0.0, 0.0, 0.0, 1.0 + 1e-12],  # w > 1 (unnormalised): clipped
        [1.0, 0.0, 0.0, 0.0],  # exactly pi about x
        [-1.0, 0.0, 0.0, 0.0],  # the antipode: -pi about x
        [0.9995, 0.0, 0.0, 0.0316],  # near pi, w > 0: angle just below pi
        [-0.9995, 0.0, 0.0, -0.0316],  # same rotation, w < 0: angle just above pi, axis flipped
        [0.95441879, 0.0826259, -0.2010037, 0.20458553],  # robosuite robot0_eef_quat, LIBERO init
        [0.9925, 0.05, -0.1, -0.05],  # LIBERO-like with w < 0 (the hand turned past pi)
        [0.0, 0.0, 1e-9, 1.0],  # w == 1: den == 0 exactly, zeros
        [2e-8, 0.0, 0.0, 1.0 - 1e-16],  # den ~1.5e-8 is not "close" to 0 (rel_tol only): computed
    ]
    for _ in range(12):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        quats.append(q.tolist())
    rows = []
    for q in quats:
        q = np.array(q, dtype=np.float64)
        aa = T.quat2axisangle(q.copy())
        rows.append({"quat_xyzw": bits(q), "axisangle": bits(aa)})
    pos = np.array([-0.2, 0.05, 1.1])
    grip = np.array([0.039, -0.0391])
    q = np.array(quats[7])
    state = np.concatenate((pos, T.quat2axisangle(q.copy()), grip))
    doc = {
        "quat2axisangle": rows,
        "state": {"eef_pos": bits(pos), "eef_quat_xyzw": bits(q), "gripper_qpos": bits(grip), "state": bits(state)},
    }
    (out / "proprio.json").write_text(json.dumps(doc, indent=1))


def actions(out: Path):
    rng = np.random.RandomState(1)
    q01 = [-0.75, -0.9, -0.93, -0.1, -0.19, -0.25, 0.0]
    q99 = [0.93, 0.87, 0.93, 0.13, 0.18, 0.31, 1.0]
    mask = [True, True, True, True, True, True, False]
    norm_stats = {
        "libero_spatial_no_noops": {
            "action": {"mean": [0.0] * 7, "std": [1.0] * 7, "max": [1.0] * 7, "min": [-1.0] * 7,
                       "q01": q01, "q99": q99, "mask": mask},
            "proprio": {"mean": [0.0] * 8, "std": [1.0] * 8, "q01": [0.0] * 8, "q99": [1.0] * 8},
            "num_transitions": 52970, "num_trajectories": 432,
        },
        "bridge_orig": {
            "action": {"q01": [-0.03] * 6 + [0.0], "q99": [0.03] * 6 + [1.0]},
            "proprio": {},
        },
    }
    normalized = rng.uniform(-1, 1, size=(16, 7))
    normalized[0, -1] = 0.5  # un-normalised 0.5 -> 0 -> np.sign(0) = 0
    normalized[1, :] = [-1, 1, -1, 1, -1, 1, 0.0]
    normalized[2, :] = [0, 0, 0, 0, 0, 0, 1.0]
    normalized[3, -1] = -0.2  # below 0 (not clipped by the reference): -> -1 -> inverted +1
    results = {}
    for key in norm_stats:
        st = norm_stats[key]["action"]
        m = np.array(st.get("mask", np.ones_like(st["q01"], dtype=bool)))
        hi, lo = np.array(st["q99"]), np.array(st["q01"])
        unnorm = np.where(m, 0.5 * (normalized + 1) * (hi - lo) + lo, normalized)
        g = unnorm.copy()
        g[..., -1] = 2 * (g[..., -1] - 0.0) / (1.0 - 0.0) - 1  # normalize_gripper_action
        g[..., -1] = np.sign(g[..., -1])  # binarize=True
        inv = g.copy()
        inv[..., -1] = inv[..., -1] * -1.0  # invert_gripper_action
        results[key] = {"unnormalized": unnorm.tolist(), "gripper_env": g.tolist(), "openvla_env": inv.tolist()}
    doc = {"norm_stats": norm_stats, "normalized": normalized.tolist(), "expected": results}
    (out / "actions.json").write_text(json.dumps(doc, indent=1))


def main():
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    names = images(out, [a for a in sys.argv[2:] if not a.endswith(".npy")])
    aloha = aloha_images(out, [a for a in sys.argv[2:] if a.endswith(".npy")])
    proprio(out)
    actions(out)
    import PIL

    meta = {"images": names, "aloha_images": aloha, "resize_shapes": RESIZE_SHAPES, "numpy": np.__version__, "pillow": PIL.__version__}
    (out / "meta.json").write_text(json.dumps(meta, indent=1))


if __name__ == "__main__":
    main()
