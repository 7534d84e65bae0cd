"""A toy policy behind starVLA's websocket policy server protocol, both payload generations, for
the Rust client's end-to-end test (tests/starvla_policy.rs). Test time only; runs in the venv of
scripts/setup/remote_policy_venv.sh (PyPI `websockets` and `openpi-client`, whose `msgpack_numpy`
is byte for byte starVLA's `deployment/model_server/tools/msgpack_numpy.py`).

The wire is starVLA's `WebsocketPolicyServer` (starVLA/starVLA 0ed0aad2; ginwind/VLA-JEPA ec8c70f6
for the older generation), rewritten here since starVLA is not on PyPI: a websockets asyncio server
with compression off and no size limit; per connection the metadata map first; each request is
routed as `_route_message` routes it (`request_id` default "default", `type` default "infer",
`payload` default the whole message; "ping"; "infer"/"predict_action" call the policy's
`predict_action(**payload)`), the reply an envelope `{"status", "ok", "type": "inference_result",
"request_id", "data" | "error": {"message"}}`; a policy exception is an error envelope and the
connection stays open; a handler crash sends the traceback as text and closes with 1011.

Generations (--generation):
  head    metadata as `PolicyServerWrapper.metadata` (action_chunk_size = --chunk, ...);
          predict_action(examples, unnorm_key=None, **kwargs) -> {"actions": (1, T, 7)} (already
          "unnormalised": the client executes them as they are)
  legacy  metadata {"env": "simpler_env"}; predict_action(batch_images, instructions,
          unnorm_key=None, state=None, do_sample, use_ddim, num_ddim_steps) ->
          {"normalized_actions": (1, T, 7), "embodied_action_tokens": (1, 32, 8)}

The actions are a deterministic function of the request number n (1-based over all connections)
and the row t, logged with everything received, so the test can check what was sent and what was
executed against the stored steps:
  head:   a[t, j] = (-1)^t * 0.01 * (j + 1) + 0.001 * n (j < 6);  a[t, 6] = 1.0 if t is even else 0.0
  legacy: a[t, j] = ((7t + 3j + n) % 11 - 5) / 4 (j < 6, outside [-1, 1] at times, to be clipped);
          a[t, 6] = 0.9 if t is odd else 0.2

Faults, by request number n: --error-at N (the policy raises: an error envelope), --drop-at N
(abort the TCP connection instead of answering). --tag T goes into the metadata (another server);
--swap-after K: from the (K+1)-th connection on, the metadata says it is another model.
Prints `listening on <port>` (port 0 picks a free one) once it accepts connections.
"""

import argparse
import asyncio
import itertools
import json
import traceback

import numpy as np
from openpi_client import msgpack_numpy
import websockets.asyncio.server as _server
import websockets.frames


def describe_image(im):
    if not isinstance(im, np.ndarray):
        return {"type": str(type(im))}
    d = {"dtype": im.dtype.str, "shape": list(im.shape)}
    if im.dtype == np.uint8 and im.ndim == 3:
        h = im.shape[0] // 2
        d["sum"] = int(im.astype(np.int64).sum())
        d["top_mean"] = float(im[:h].mean())
        d["bottom_mean"] = float(im[h:].mean())
    return d


def describe_state(s):
    if s is None:
        return None
    if not isinstance(s, np.ndarray):
        return {"type": str(type(s))}
    return {"dtype": s.dtype.str, "shape": list(s.shape), "values": s.reshape(-1).tolist()}


class ToyPolicy:
    def __init__(self, args, log):
        self.args = args
        self.log = log
        self.n = 0
        self.session = None

    def _check_images(self, images):
        if not (isinstance(images, list) and len(images) == 2):
            raise TypeError(f"expected [agentview, wrist], got {type(images)} of {len(images) if isinstance(images, list) else '?'}")
        for im in images:
            if not (isinstance(im, np.ndarray) and im.dtype == np.uint8 and im.ndim == 3 and im.shape[2] == 3):
                raise TypeError(f"an image must be uint8 (H, W, 3), got {describe_image(im)}")

    def _rows(self):
        t = np.arange(self.args.predict, dtype=np.float64)[:, None]
        j = np.arange(6, dtype=np.float64)[None, :]
        if self.args.generation == "head":
            xyz = np.where(t % 2 == 0, 1.0, -1.0) * 0.01 * (j + 1) + 0.001 * self.n
            grip = np.where(t % 2 == 0, 1.0, 0.0)
        else:
            xyz = (np.mod(7 * t + 3 * j + self.n, 11) - 5) / 4
            grip = np.where(t % 2 == 1, 0.9, 0.2)
        return np.concatenate([xyz, grip], axis=1).astype(np.float32)[None]

    def _record(self, received, actions):
        self.log({"event": "infer", "n": self.n, "session": self.session, **received,
                  "actions": actions[0].astype(np.float64).tolist()})

    def predict_action(self, **payload):
        self.n += 1
        if self.n == self.args.error_at:
            raise RuntimeError(f"toy policy failure at request {self.n}")
        if self.args.generation == "head":
            return self.head(**payload)
        return self.legacy(**payload)

    def head(self, examples, unnorm_key=None, do_sample=None, use_ddim=None, num_ddim_steps=None):
        if not (isinstance(examples, list) and len(examples) == 1 and isinstance(examples[0], dict)):
            raise TypeError(f"examples must be a list of one dict, got {examples!r:.200}")
        ex = examples[0]
        unknown = set(ex) - {"image", "lang", "state"}
        if unknown:
            raise TypeError(f"unknown example keys {sorted(unknown)}")
        self._check_images(ex["image"])
        if not isinstance(ex["lang"], str):
            raise TypeError(f"lang must be str, got {type(ex['lang'])}")
        actions = self._rows()
        self._record({
            "images": [describe_image(im) for im in ex["image"]], "lang": ex["lang"],
            "state": describe_state(ex.get("state")), "unnorm_key": unnorm_key,
            "options": {"do_sample": do_sample, "use_ddim": use_ddim, "num_ddim_steps": num_ddim_steps},
        }, actions)
        return {"actions": actions}

    def legacy(self, batch_images, instructions, unnorm_key=None, state=None, do_sample=None, use_ddim=None, num_ddim_steps=None):
        if not (isinstance(batch_images, list) and len(batch_images) == 1):
            raise TypeError("batch_images must be a list of one example's images")
        self._check_images(batch_images[0])
        if not (isinstance(instructions, list) and len(instructions) == 1 and isinstance(instructions[0], str)):
            raise TypeError(f"instructions must be [str], got {instructions!r:.200}")
        if state is not None and not (isinstance(state, list) and len(state) == 1):
            raise TypeError("state must be a list of one example's state")
        actions = self._rows()
        self._record({
            "images": [describe_image(im) for im in batch_images[0]], "lang": instructions[0],
            "state": describe_state(state[0] if state is not None else None), "unnorm_key": unnorm_key,
            "options": {"do_sample": do_sample, "use_ddim": use_ddim, "num_ddim_steps": num_ddim_steps},
        }, actions)
        return {"normalized_actions": actions, "embodied_action_tokens": np.zeros((1, 32, 8), np.float32)}


class ToyServer:
    def __init__(self, args):
        self.args = args
        self.sessions = itertools.count()
        self.log_file = open(args.log, "a") if args.log else None
        self.policy = ToyPolicy(args, self.log)
        if args.generation == "head":
            self.metadata = {
                "env": "starvla_policy_server", "ckpt_path": f"/toy/{args.tag}/checkpoints/steps_1_pytorch_model.pt",
                "action_chunk_size": args.chunk, "available_unnorm_keys": ["franka"], "default_unnorm_key": "franka",
                "training_data_mix": "libero_all", "training_obs_image_size": [224, 224],
                "eval_image_contract": "toy", "action_keys": ["action"], "state_keys": ["state"],
            }
        else:
            self.metadata = {"env": "simpler_env"} if args.tag == "toy" else {"env": "simpler_env", "tag": args.tag}

    def log(self, event):
        if self.log_file:
            self.log_file.write(json.dumps(event) + "\n")
            self.log_file.flush()

    def route(self, msg):
        """`_route_message` of starVLA's `WebsocketPolicyServer`."""
        req_id = msg.get("request_id", "default")
        mtype = msg.get("type", "infer")
        payload = msg.get("payload", msg)
        if mtype == "ping":
            return {"status": "ok", "ok": True, "type": "ping", "request_id": req_id}
        if mtype in ("infer", "predict_action"):
            if not isinstance(payload, dict):
                return {"status": "error", "ok": False, "type": "inference_result", "request_id": req_id,
                        "error": {"message": "Payload must be a dict", "payload_type": str(type(payload))}}
            try:
                data = self.policy.predict_action(**payload)
            except Exception as e:
                return {"status": "error", "ok": False, "type": "inference_result", "request_id": req_id,
                        "error": {"message": str(e)}}
            return {"status": "ok", "ok": True, "type": "inference_result", "request_id": req_id, "data": data}
        return {"status": "error", "ok": False, "type": "unknown", "request_id": req_id,
                "error": {"message": f"Unsupported message type '{mtype}'"}}

    async def handler(self, websocket):
        packer = msgpack_numpy.Packer()
        session = next(self.sessions)
        self.log({"event": "connect", "session": session})
        metadata = self.metadata
        if self.args.swap_after and session >= self.args.swap_after:
            metadata = {**metadata, "tag": "swapped"}
        await websocket.send(packer.pack(metadata))
        while True:
            try:
                msg = msgpack_numpy.unpackb(await websocket.recv())
                self.policy.session = session
                if self.policy.n + 1 == self.args.drop_at:
                    self.policy.n += 1
                    self.log({"event": "drop", "n": self.policy.n, "session": session})
                    websocket.transport.abort()
                    return
                await websocket.send(packer.pack(self.route(msg)))
            except websockets.ConnectionClosed:
                break
            except Exception:
                await websocket.send(traceback.format_exc())
                await websocket.close(
                    code=websockets.frames.CloseCode.INTERNAL_ERROR,
                    reason="Internal server error. Traceback included in previous frame.",
                )
                return

    async def run(self):
        async with _server.serve(self.handler, "127.0.0.1", self.args.port, compression=None, max_size=None) as server:
            port = server.sockets[0].getsockname()[1]
            print(f"listening on {port}", flush=True)
            await server.serve_forever()


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--port", type=int, default=0)
    p.add_argument("--generation", choices=["head", "legacy"], default="head")
    p.add_argument("--chunk", type=int, default=5, help="head: action_chunk_size in the metadata")
    p.add_argument("--predict", type=int, default=7, help="rows T of each reply")
    p.add_argument("--error-at", type=int, default=0)
    p.add_argument("--drop-at", type=int, default=0)
    p.add_argument("--tag", default="toy")
    p.add_argument("--swap-after", type=int, default=0)
    p.add_argument("--log", default="")
    asyncio.run(ToyServer(p.parse_args()).run())


if __name__ == "__main__":
    main()
