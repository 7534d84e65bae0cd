"""The Python policy host: one process the pipeline starts per model replica, serving a Python
policy over its stdin/stdout (libero_policies::python_host on the Rust side).

Run as ``python libero_eval_host.py --target TARGET [--device DEV] [--option KEY=VALUE ...]``,
TARGET being ``lerobot:<checkpoint dir>`` (lerobot_policy.py, beside this file) or
``python:<module>:<factory>`` (a user's policy; the module is imported from the working
directory or PYTHONPATH). Only NumPy is needed beside the policy's own packages.

**Frames** (both directions): ``u32 LE header length``, ``u64 LE blob length``, the header (UTF-8
JSON), the blob. ``header["arrays"]`` maps a name to ``{"dtype", "shape", "offset"}`` into the
blob (C order, little-endian). The host speaks first:

- host -> pipeline, once the policy is loaded: ``{"op": "ready", "protocol": 1, "describe": {...}}``
  (or ``{"op": "error", "message": ...}`` when it could not be loaded, then exits);
- pipeline -> host: ``{"op": "act", "episodes": [{"task", "seed", "policy_step"}...], "arrays":
  {...}}``; the host answers ``{"op": "actions", "arrays": {"actions": float32 (B, T, D)}}`` or
  ``{"op": "error", "message": <traceback>}`` (the host keeps serving);
- pipeline -> host: ``{"op": "exit"}``, or end of file on stdin: the host exits.

The policy is any object with ``describe() -> dict`` and ``act(batch: dict) -> array (B, T, D)``
(an action chunk per episode: the pipeline keeps each episode's queue and asks again when the
executed part of its chunk is spent). ``batch`` holds ``task`` (list of str), ``seed`` and
``policy_step`` (int64 (B,)), and the observation arrays the policy's ``describe()`` asked for (see
the docs book's "Python policies" page). Output on stdout from the policy or its libraries would
corrupt the frames: the host moves fd 1 to stderr before importing anything else.
"""

import json
import os
import struct
import sys
import traceback

PROTOCOL = 1

# The frames' own stdout, before any library can print on it: fd 1 becomes a copy of stderr.
_frames_out = os.fdopen(os.dup(1), "wb", buffering=0)
os.dup2(2, 1)
sys.stdout = sys.stderr
_frames_in = os.fdopen(os.dup(0), "rb", buffering=0)

import numpy as np  # noqa: E402  (after the fd swap: NumPy's import must not print on the frames)


def _read_exact(n):
    chunks, left = [], n
    while left:
        b = _frames_in.read(left)
        if not b:
            return None
        chunks.append(b)
        left -= len(b)
    return b"".join(chunks)


def read_frame():
    """The next frame as (header, arrays), or None at end of input."""
    lengths = _read_exact(12)
    if lengths is None:
        return None
    header_len, blob_len = struct.unpack("<IQ", lengths)
    header = json.loads(_read_exact(header_len).decode())
    # A bytearray: the arrays over it are writable (torch.from_numpy warns on read-only ones).
    blob = bytearray(_read_exact(blob_len)) if blob_len else bytearray()
    arrays = {}
    for name, a in header.pop("arrays", {}).items():
        dtype = np.dtype(a["dtype"]).newbyteorder("<")
        count = int(np.prod(a["shape"], dtype=np.int64))
        arrays[name] = np.frombuffer(blob, dtype=dtype, count=count, offset=a["offset"]).reshape(a["shape"])
    return header, arrays


def write_frame(header, arrays=None):
    parts, meta, offset = [], {}, 0
    for name, a in (arrays or {}).items():
        a = np.ascontiguousarray(a)
        a = a.astype(a.dtype.newbyteorder("<"), copy=False)
        meta[name] = {"dtype": a.dtype.str.lstrip("<|="), "shape": list(a.shape), "offset": offset}
        parts.append(a.tobytes())
        offset += a.nbytes
    header = dict(header, arrays=meta)
    h = json.dumps(header).encode()
    blob = b"".join(parts)
    _frames_out.write(struct.pack("<IQ", len(h), len(blob)) + h + blob)


def load(target, device, options):
    if target.startswith("lerobot:"):
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        import lerobot_policy

        return lerobot_policy.LerobotPolicy(target[len("lerobot:"):], device, options)
    if target.startswith("python:"):
        module_name, _, factory_name = target[len("python:"):].rpartition(":")
        if not module_name or not factory_name:
            raise ValueError(f"{target!r}: expected python:<module>:<factory>")
        sys.path.insert(0, os.getcwd())
        import importlib

        factory = getattr(importlib.import_module(module_name), factory_name)
        return factory(device=device, **options)
    raise ValueError(f"unknown target {target!r}: expected lerobot:<dir> or python:<module>:<factory>")


def main(argv):
    import argparse

    p = argparse.ArgumentParser()
    p.add_argument("--target", required=True)
    p.add_argument("--device", default=None)
    p.add_argument("--option", action="append", default=[], help="KEY=VALUE given to the policy")
    args = p.parse_args(argv)
    options = dict(o.split("=", 1) for o in args.option)
    try:
        policy = load(args.target, args.device, options)
        describe = policy.describe()
        describe.setdefault("python", sys.version.split()[0])
        describe.setdefault("interpreter", sys.executable)
        write_frame({"op": "ready", "protocol": PROTOCOL, "describe": describe})
    except BaseException:
        write_frame({"op": "error", "message": traceback.format_exc()})
        return 1
    # LIBERO_EVAL_HOST_RECORD=<dir>: every call's observations and actions saved as .npz (what the
    # policy saw, for debugging and for the tests' oracle).
    record, calls = os.environ.get("LIBERO_EVAL_HOST_RECORD"), 0
    if record:
        os.makedirs(record, exist_ok=True)
    while True:
        frame = read_frame()
        if frame is None or frame[0].get("op") == "exit":
            return 0
        header, arrays = frame
        try:
            if header.get("op") != "act":
                raise ValueError(f"unknown op {header.get('op')!r}")
            eps = header["episodes"]
            batch = dict(arrays)
            batch["task"] = [e["task"] for e in eps]
            batch["seed"] = np.array([e["seed"] for e in eps], dtype=np.uint64)
            batch["policy_step"] = np.array([e["policy_step"] for e in eps], dtype=np.int64)
            actions = np.asarray(policy.act(batch), dtype=np.float32)
            if actions.ndim != 3 or actions.shape[0] != len(eps):
                raise ValueError(
                    f"act returned an array of shape {actions.shape}; expected (batch={len(eps)}, steps, action dim)"
                )
            if record:
                calls += 1
                np.savez(os.path.join(record, f"call-{os.getpid()}-{calls:06d}.npz"), actions=actions,
                         task_json=json.dumps(batch["task"]), **{k: v for k, v in batch.items() if k != "task"})
            write_frame({"op": "actions"}, {"actions": actions})
        except Exception:
            write_frame({"op": "error", "message": traceback.format_exc()})


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
