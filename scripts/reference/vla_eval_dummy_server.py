"""A dummy model behind vla-eval's OWN model server, for the Rust client's test
(tests/vla_eval_policy.rs). Test time only; runs in the venv of scripts/setup/vla_eval_venv.sh.

The server, the protocol and the codecs are the PyPI package's (vla-eval 0.8.0):
`vla_eval.model_servers.serve.serve_async` (HELLO reply with our `get_observation_params`,
EPISODE_START/END, one ACTION per OBSERVATION, ERROR frames), `vla_eval.model_servers.predict.
PredictModelServer` (server-side action chunks, `chunk_size`), `vla_eval.protocol.messages` and
`numpy_codec`/`image_codec` (string `"__ndarray__"` keys, `"__image__"` PNG images). This file adds
only a deterministic model and a log of what the server received and sent, so the test can check
the client against the package's own decoding.

The model: per predict() a chunk of `--chunk` actions that depend on the step and the state
(when sent), with the gripper component alternating in sign between chunks (so the client's
gripper binarization is exercised):

    chunk[i] = [0.01 * sin(step + i), 0.002 * i, -0.003, 0.001 * (step % 7), 0, 0.0005 * i, g]
    g = 0.25 if (step // chunk) % 2 == 0 else -0.4

Log (`--log FILE`, one JSON line per event, flushed): `episode_start` (payload, session),
`observation` (session, episode, step, for every image key its decoded shape/dtype and the wire
format the package's decoder saw, `task_description`, `states`/`controller_states` dtype, shape,
values, every key), `action` (the (7,) array sent back), `episode_end`.

Faults, by observation number n (1-based, over all connections):
  --drop-at N    abort the TCP connection instead of answering observation N
  --error-at N   the model raises on observation N (the package sends an ERROR frame and keeps
                 the connection open)
  --swap-after N from the (N+1)-th HELLO on, the observation params carry "swapped": true (another
                 model at the same address)

Prints `listening on <port>` (port 0 picks a free one) once it accepts connections.
"""

import argparse
import contextvars
import json
import math

import anyio
import numpy as np

import vla_eval.model_servers.serve as serve_mod
import vla_eval.protocol.numpy_codec as numpy_codec
from vla_eval.model_servers.predict import PredictModelServer

# What the package's decoder saw: the "format" of every "__image__" dict it decoded (observer only).
_formats: list = []
_decode_image = numpy_codec.decode_image


def _observing_decode_image(obj):
    _formats.append(obj.get("format"))
    return _decode_image(obj)


numpy_codec.decode_image = _observing_decode_image

# The websocket of the connection being handled (for --drop-at): set by a wrapper around the
# package's per-connection handler, read in on_observation (the same task).
_ws = contextvars.ContextVar("ws")
_handle_connection = serve_mod._handle_connection


async def _observing_handle_connection(ws, model_server):
    _ws.set(ws)
    await _handle_connection(ws, model_server)


serve_mod._handle_connection = _observing_handle_connection


def describe(v):
    if isinstance(v, np.ndarray):
        d = {"dtype": v.dtype.str, "shape": list(v.shape)}
        if v.ndim == 1:
            d["values"] = v.astype(np.float64).tolist()
        return d
    return {"type": type(v).__name__, "value": v if isinstance(v, (str, int, float, bool)) else None}


class DummyModelServer(PredictModelServer):
    def __init__(self, args):
        super().__init__(chunk_size=args.chunk)
        self.args = args
        self.params = json.loads(args.params)
        self.observations = 0
        self.hellos = 0
        self.log = open(args.log, "a", buffering=1) if args.log else None

    def record(self, **event):
        if self.log:
            self.log.write(json.dumps(event) + "\n")

    def get_observation_params(self):
        self.hellos += 1
        if self.args.swap_after and self.hellos > self.args.swap_after:
            return {**self.params, "swapped": True}
        return dict(self.params)

    async def on_episode_start(self, config, ctx):
        self.record(event="episode_start", session=ctx.session_id, episode=ctx.episode_id, payload=config)
        send = ctx._send_action_fn

        async def recorded(action):
            self.record(event="action", session=ctx.session_id, episode=ctx.episode_id, actions=np.asarray(action["actions"]).astype(np.float64).tolist(), dtype=np.asarray(action["actions"]).dtype.str)
            await send(action)

        ctx._send_action_fn = recorded
        await super().on_episode_start(config, ctx)

    async def on_episode_end(self, result, ctx):
        self.record(event="episode_end", session=ctx.session_id, episode=ctx.episode_id, payload=result)
        await super().on_episode_end(result, ctx)

    async def on_observation(self, obs, ctx):
        self.observations += 1
        n = self.observations
        images = obs.get("images", {})
        formats = _formats[-len(images):] if images else []
        _formats.clear()
        self.record(
            event="observation",
            n=n,
            session=ctx.session_id,
            episode=ctx.episode_id,
            step=ctx.step,
            keys=sorted(obs),
            images={k: describe(v) for k, v in images.items()},
            image_formats=formats,
            image_sums={k: int(np.asarray(v, dtype=np.int64).sum()) for k, v in images.items()},
            task_description=obs.get("task_description"),
            states=describe(obs["states"]) if "states" in obs else None,
            controller_states=describe(obs["controller_states"]) if "controller_states" in obs else None,
        )
        if n == self.args.drop_at:
            _ws.get().transport.abort()
            return
        if n == self.args.error_at:
            raise RuntimeError(f"dummy model failure at observation {n}")
        await super().on_observation(obs, ctx)

    def predict(self, obs, ctx):
        step = ctx.step
        k = self.args.chunk
        g = 0.25 if (step // k) % 2 == 0 else -0.4
        chunk = [
            [0.01 * math.sin(step + i), 0.002 * i, -0.003, 0.001 * (step % 7), 0.0, 0.0005 * i, g] for i in range(k)
        ]
        return {"actions": np.asarray(chunk, dtype=np.float32)}


async def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--port", type=int, default=0)
    p.add_argument("--chunk", type=int, default=4, help="actions per predict() (PredictModelServer chunk_size)")
    p.add_argument("--params", default="{}", help="get_observation_params() as JSON")
    p.add_argument("--log", default=None)
    p.add_argument("--drop-at", type=int, default=0)
    p.add_argument("--error-at", type=int, default=0)
    p.add_argument("--swap-after", type=int, default=0)
    args = p.parse_args()
    server = DummyModelServer(args)
    async with anyio.create_task_group() as tg:
        port = await tg.start(serve_mod.serve_async, server, "127.0.0.1", args.port)
        print(f"listening on {port}", flush=True)


if __name__ == "__main__":
    anyio.run(main)
