"""A toy policy behind openpi's policy-server protocol, for the Rust client's test
(policies/tests/openpi_client.rs). Test time only; runs in the venv of
scripts/setup/remote_policy_venv.sh.

The wire side is openpi's: `openpi_client.msgpack_numpy` (the PyPI `openpi-client` package, the
module openpi's `WebsocketPolicyServer` imports) over a `websockets` asyncio server with
compression off and no size limit. Per connection: the metadata message first; then for each
observation dict one reply `{"actions": float32 (chunk, 7), "server_timing": {...}}`; when the
policy raises, the traceback as a text message and a close with code 1011, as openpi's server
does (src/openpi/serving/websocket_policy_server.py).

The toy policy is a deterministic function of what it receives, so the test can compute the
expected chunk on its side and prove both encoding directions:

    actions[i, j] = state[j] + 0.5 * state[7] + 0.01 * (i + 1) + 0.001 * len(prompt.encode())
                    + (image[0, 0, 0] + wrist_image[-1, -1, 2]) / 1000   (when images are sent)

It checks the request's types first (state float64 (8,), prompt str, images uint8 (H, W, 3)) and
fails like a real policy when they are wrong.

With --aloha it is a policy of openpi's ALOHA-sim example instead (examples/aloha_sim: the dict
`{"state": float64 (14,), "images": {"cam_high": uint8 (3, 224, 224)}}`, no prompt): it requires
exactly those keys, types and shapes, and the padding `resize_with_pad` leaves on a 480x640 frame
(rows 0-27 and 196-223 black in every channel, the picture between them not), and answers
`{"actions": float32 (chunk, 14)}` with

    actions[i, j] = state[j] + 0.01 * (i + 1) + cam_high[:, 112, 112].sum() / 100000

Faults, by request number n (1-based, counted over all connections of the server):
  --delay-at N --delay-s S     sleep S seconds before answering request N
  --drop-at N                  abort the TCP connection instead of answering request N
  --error-at N                 the policy raises on request N (text traceback + close 1011)
  --require-images             fail (like a real pi0) unless both 224x224 images are sent
  --bad-reply-at N --bad-reply {no-actions,garbage,wrong-shape}
                               answer request N with a malformed reply

Prints `listening on <port>` (port 0 picks a free one) once it accepts connections.
"""

import argparse
import asyncio
import time
import traceback

import numpy as np
from openpi_client import msgpack_numpy
import websockets.asyncio.server as _server
import websockets.frames


def toy_actions(obs: dict, chunk: int, require_images: bool = False) -> np.ndarray:
    state = obs["observation/state"]
    if require_images:
        for key in ("observation/image", "observation/wrist_image"):
            im = obs.get(key)
            if not (isinstance(im, np.ndarray) and im.shape == (224, 224, 3)):
                raise TypeError(f"{key} must be a 224x224x3 image, got {getattr(im, 'shape', im)}")
    prompt = obs["prompt"]
    if not (isinstance(state, np.ndarray) and state.dtype == np.float64 and state.shape == (8,)):
        raise TypeError(f"observation/state must be float64 (8,), got {type(state)} {getattr(state, 'dtype', None)} {getattr(state, 'shape', None)}")
    if not isinstance(prompt, str):
        raise TypeError(f"prompt must be str, got {type(prompt)}")
    image_term = 0.0
    if "observation/image" in obs:
        img, wrist = obs["observation/image"], obs["observation/wrist_image"]
        for name, im in (("image", img), ("wrist_image", wrist)):
            if not (isinstance(im, np.ndarray) and im.dtype == np.uint8 and im.ndim == 3 and im.shape[2] == 3):
                raise TypeError(f"observation/{name} must be uint8 (H, W, 3), got {getattr(im, 'dtype', None)} {getattr(im, 'shape', None)}")
        image_term = (int(img[0, 0, 0]) + int(wrist[-1, -1, 2])) / 1000.0
    i = np.arange(chunk, dtype=np.float64)[:, None]
    base = state[:7] + 0.5 * state[7] + 0.001 * len(prompt.encode()) + image_term
    return (base[None, :] + 0.01 * (i + 1)).astype(np.float32)


def toy_aloha_actions(obs: dict, chunk: int) -> np.ndarray:
    if sorted(obs) != ["images", "state"]:
        raise TypeError(f"openpi's aloha_sim example sends exactly state and images, got {sorted(obs)}")
    state, images = obs["state"], obs["images"]
    if not (isinstance(state, np.ndarray) and state.dtype == np.float64 and state.shape == (14,)):
        raise TypeError(f"state must be float64 (14,), got {type(state)} {getattr(state, 'dtype', None)} {getattr(state, 'shape', None)}")
    if not (isinstance(images, dict) and sorted(images) == ["cam_high"]):
        raise TypeError(f"images must be {{'cam_high': ...}}, got {images if not isinstance(images, dict) else sorted(images)}")
    cam = images["cam_high"]
    if not (isinstance(cam, np.ndarray) and cam.dtype == np.uint8 and cam.shape == (3, 224, 224)):
        raise TypeError(f"cam_high must be uint8 (3, 224, 224), got {getattr(cam, 'dtype', None)} {getattr(cam, 'shape', None)}")
    if cam[:, :28].any() or cam[:, 196:].any() or not cam[:, 28:196].any():
        raise ValueError("cam_high is not a 480x640 frame after resize_with_pad(224, 224): rows 0-27 and 196-223 must be black, the rest not")
    i = np.arange(chunk, dtype=np.float64)[:, None]
    base = state + int(cam[:, 112, 112].astype(np.int64).sum()) / 100000.0
    return (base[None, :] + 0.01 * (i + 1)).astype(np.float32)


class ToyServer:
    def __init__(self, args):
        self.args = args
        self.requests = 0
        dim = 14 if args.aloha else 7
        self.metadata = {"name": "toy", "action_horizon": args.chunk, "action_dim": dim, "scale": np.array([0.5, 0.01], dtype=np.float32)}

    async def handler(self, websocket):
        packer = msgpack_numpy.Packer()
        await websocket.send(packer.pack(self.metadata))
        a = self.args
        while True:
            try:
                obs = msgpack_numpy.unpackb(await websocket.recv())
                self.requests += 1
                n = self.requests
                if n == a.drop_at:
                    websocket.transport.abort()
                    return
                if n == a.delay_at:
                    await asyncio.sleep(a.delay_s)
                if n == a.bad_reply_at:
                    if a.bad_reply == "garbage":
                        await websocket.send(b"\x92\x01")  # an array of 2 holding 1: truncated
                    elif a.bad_reply == "no-actions":
                        await websocket.send(packer.pack({"action": np.zeros((a.chunk, 7), np.float32)}))
                    else:
                        await websocket.send(packer.pack({"actions": np.zeros((a.chunk, 6), np.float32)}))
                    continue
                start = time.monotonic()
                if n == a.error_at:
                    raise RuntimeError(f"toy policy failure at request {n}")
                if a.aloha:
                    reply = {"actions": toy_aloha_actions(obs, a.chunk)}
                else:
                    reply = {"actions": toy_actions(obs, a.chunk, a.require_images), "echo": {"prompt": obs["prompt"], "keys": sorted(obs)}}
                reply["server_timing"] = {"infer_ms": (time.monotonic() - start) * 1000}
                await websocket.send(packer.pack(reply))
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
    p.add_argument("--chunk", type=int, default=10, help="predicted chunk length (openpi's action_horizon)")
    p.add_argument("--delay-at", type=int, default=0)
    p.add_argument("--delay-s", type=float, default=0.0)
    p.add_argument("--drop-at", type=int, default=0)
    p.add_argument("--error-at", type=int, default=0)
    p.add_argument("--require-images", action="store_true")
    p.add_argument("--aloha", action="store_true", help="a policy of openpi's ALOHA-sim example (14-D)")
    p.add_argument("--bad-reply-at", type=int, default=0)
    p.add_argument("--bad-reply", choices=["no-actions", "garbage", "wrong-shape"], default="garbage")
    asyncio.run(ToyServer(p.parse_args()).run())


if __name__ == "__main__":
    main()
