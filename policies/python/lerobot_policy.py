"""A lerobot 0.6.1 checkpoint as a policy of the Python host (libero_eval_host.py), fed exactly as
``lerobot-eval`` feeds it (``lerobot/scripts/lerobot_eval.py``'s rollout):

    preprocess_observation(raw) -> task -> env preprocessor (LiberoProcessorStep on LIBERO)
    -> the checkpoint's preprocessor -> predict_action_chunk under inference_mode
    -> the checkpoint's postprocessor -> env postprocessor

with the numerics lerobot-eval sets (``cudnn.benchmark``, ``cuda.matmul.allow_tf32``). The raw
observation is lerobot's own LIBERO env format (``envs/libero.py``'s ``_format_raw_obs``: the
cameras as robosuite renders them, ``robot_state`` with ``robot0_eef_quat``, the controller's
``ee_ori_mat``, gripper and joint states) or its ALOHA one (``pixels.top``, ``agent_pos``), built
from the arrays the pipeline sends.

Where this differs from ``select_action`` on purpose: each call predicts a chunk per episode and
returns its first ``n_action_steps`` actions; the pipeline keeps each episode's queue, so episodes
that started at different steps share one forward (lerobot's own queue is the batch's, lockstep).
Flow-matching noise (π0, π0.5, SmolVLA) is drawn per episode from a generator seeded by (episode
seed, policy step), so an episode's actions do not depend on which episodes share its forward.
Policies that keep state between calls (ACT with temporal ensembling, diffusion's observation
history) are refused: their state would be the batch's, not the episode's.
"""

import hashlib
import importlib.metadata
import os

import numpy as np

BENCHMARKS = ("libero", "aloha_sim")


class CheckpointError(ValueError):
    """The checkpoint does not fit the benchmark (features, processors, a stateful policy)."""


def _versions():
    out = {}
    for pkg in ("lerobot", "torch", "transformers", "numpy", "safetensors"):
        try:
            out[pkg] = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            out[pkg] = None
    return out


def _files_sha256(directory):
    out = {}
    for name in sorted(os.listdir(directory)):
        path = os.path.join(directory, name)
        if os.path.isfile(path):
            h = hashlib.sha256()
            with open(path, "rb") as f:
                for block in iter(lambda: f.read(1 << 22), b""):
                    h.update(block)
            out[name] = h.hexdigest()
    return out


class LerobotPolicy:
    def __init__(self, checkpoint, device, options):
        import torch
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.envs.configs import AlohaEnv, LiberoEnv
        from lerobot.envs.factory import make_env_pre_post_processors
        from lerobot.envs.utils import preprocess_observation
        from lerobot.policies import make_policy, make_pre_post_processors

        self.torch = torch
        self.preprocess_observation = preprocess_observation
        self.benchmark = options.pop("benchmark", "libero")
        if self.benchmark not in BENCHMARKS:
            raise CheckpointError(f"benchmark {self.benchmark!r}: expected one of {BENCHMARKS}")
        tokenizer = options.pop("tokenizer", None)
        steps = options.pop("steps", None)
        # The pipeline's ensemble= combines chunks itself: it needs every action of each chunk.
        whole_chunk = options.pop("whole_chunk", None) == "1"
        if options:
            raise CheckpointError(f"unknown options {sorted(options)} for lerobot: (known: steps, tokenizer)")
        self.checkpoint = os.path.abspath(checkpoint)
        if not os.path.isfile(os.path.join(self.checkpoint, "config.json")):
            raise CheckpointError(
                f"{self.checkpoint} has no config.json: a lerobot checkpoint directory holds config.json, "
                "model.safetensors, policy_preprocessor.json and policy_postprocessor.json "
                "(the pretrained_model/ folder of a training run, or a Hugging Face snapshot)"
            )
        # lerobot-eval's numerics (scripts/lerobot_eval.py, eval_main).
        torch.backends.cudnn.benchmark = True
        torch.backends.cuda.matmul.allow_tf32 = True

        cfg = PreTrainedConfig.from_pretrained(self.checkpoint)
        cfg.pretrained_path = self.checkpoint
        cfg.device = device or ("cuda" if torch.cuda.is_available() else "cpu")
        if self.benchmark == "libero":
            self.env_cfg = LiberoEnv(task="libero_spatial")
        else:
            self.env_cfg = AlohaEnv(task="AlohaTransferCube-v0")
        self._check_features(cfg)
        if cfg.type == "act" and getattr(cfg, "temporal_ensemble_coeff", None) is not None:
            raise CheckpointError(
                "this ACT checkpoint uses temporal ensembling (temporal_ensemble_coeff set): its ensembler is one "
                "state for the whole batch, so episodes that share forwards would mix; run it with "
                "temporal_ensemble_coeff = null in config.json"
            )
        if cfg.type in ("diffusion", "tdmpc", "vqbet"):
            raise CheckpointError(
                f"a {cfg.type} policy keeps an observation history between calls, one for the whole batch; "
                "the host serves policies whose chunk depends on the current observation only"
            )
        self.policy = make_policy(cfg, env_cfg=self.env_cfg)
        self.policy.eval()
        self.cfg = self.policy.config
        overrides = {
            "device_processor": {"device": str(self.cfg.device)},
            "rename_observations_processor": {"rename_map": {}},
        }
        if tokenizer:
            overrides["tokenizer_processor"] = {"tokenizer_name": tokenizer}
        self.pre, self.post = make_pre_post_processors(
            self.cfg, pretrained_path=self.checkpoint, preprocessor_overrides=overrides
        )
        self.env_pre, self.env_post = make_env_pre_post_processors(self.env_cfg, self.cfg)
        self.n_action_steps = int(steps) if steps else int(self.cfg.n_action_steps)
        chunk = int(getattr(self.cfg, "chunk_size", self.n_action_steps))
        if whole_chunk:
            self.n_action_steps = chunk
        if not 1 <= self.n_action_steps <= chunk:
            raise CheckpointError(f"steps={self.n_action_steps}: the checkpoint's chunks hold {chunk} actions")
        self.noise_shape = None
        if hasattr(self.cfg, "max_action_dim") and cfg.type in ("pi0", "pi05", "smolvla"):
            self.noise_shape = (chunk, int(self.cfg.max_action_dim))

    def _check_features(self, cfg):
        """Refuse a checkpoint whose inputs or output the benchmark cannot give or take."""
        from lerobot.configs import FeatureType

        if self.benchmark == "libero":
            env_images = {"observation.images.image", "observation.images.image2"}
            state_dim, action_dim = 8, 7
        else:
            env_images = {"observation.images.top"}
            state_dim, action_dim = 14, 14
        problems = []
        for key, feature in (cfg.input_features or {}).items():
            if feature.type == FeatureType.VISUAL and key not in env_images:
                problems.append(f"it reads the camera {key}, and {self.benchmark} gives {sorted(env_images)}")
            if feature.type == FeatureType.STATE and tuple(feature.shape) != (state_dim,):
                problems.append(f"its {key} is {tuple(feature.shape)}, and {self.benchmark}'s state is ({state_dim},)")
        action = (cfg.output_features or {}).get("action")
        if action is not None and tuple(action.shape) != (action_dim,):
            problems.append(f"its action is {tuple(action.shape)}, and {self.benchmark} takes ({action_dim},)")
        if problems:
            raise CheckpointError(f"the checkpoint {self.checkpoint} does not fit {self.benchmark}: " + "; ".join(problems))

    def describe(self):
        images = sorted(k for k, f in self.cfg.input_features.items() if f.type.name == "VISUAL")
        if self.benchmark == "libero":
            observation = {
                "cameras": ["agentview", "wrist"] if "observation.images.image2" in images else ["agentview"],
                "camera_size": int(self.env_cfg.observation_height),
                "raw": "lerobot's LIBERO env observation: pixels.image/image2 as robosuite renders them, robot_state",
            }
        else:
            observation = {"cameras": ["top"], "raw": "gym-aloha pixels_agent_pos: top 480x640, agent_pos (14)"}
        return {
            "kind": "lerobot",
            "policy_type": self.cfg.type,
            "checkpoint": self.checkpoint,
            "checkpoint_sha256": _files_sha256(self.checkpoint),
            "versions": _versions(),
            "device": str(self.cfg.device),
            "benchmark": self.benchmark,
            "observation": observation,
            "action_dim": 7 if self.benchmark == "libero" else 14,
            "chunk_size": int(getattr(self.cfg, "chunk_size", self.n_action_steps)),
            "executed_steps": self.n_action_steps,
            "preprocessor": [type(s).__name__ for s in self.pre.steps],
            "postprocessor": [type(s).__name__ for s in self.post.steps],
            "env_preprocessor": [type(s).__name__ for s in self.env_pre.steps],
            "env_postprocessor": [type(s).__name__ for s in self.env_post.steps],
            "numerics": {
                "cudnn_benchmark": True,
                "cuda_matmul_allow_tf32": True,
                "inference_mode": True,
            },
            "noise": (
                "N(0,1) float32 (chunk, max_action_dim) per episode from torch.Generator().manual_seed("
                "(seed * 1000003 + policy_step) mod 2^63) on the CPU"
                if self.noise_shape
                else None
            ),
        }

    def raw_observation(self, batch):
        """lerobot's env observation dict (envs/libero.py _format_raw_obs; gym-aloha's) from the batch."""
        if self.benchmark == "libero":
            pixels = {"image": batch["agentview"]}
            if "wrist" in batch:
                pixels["image2"] = batch["wrist"]
            return {
                "pixels": pixels,
                "robot_state": {
                    "eef": {"pos": batch["eef_pos"], "quat": batch["eef_quat"], "mat": batch["eef_mat"]},
                    "gripper": {"qpos": batch["gripper_qpos"], "qvel": batch["gripper_qvel"]},
                    "joints": {"pos": batch["joint_pos"], "vel": batch["joint_vel"]},
                },
            }
        return {"pixels": {"top": batch["top"]}, "agent_pos": batch["agent_pos"]}

    def policy_inputs(self, batch):
        """What the policy's forward receives: the observation through the env's and the checkpoint's
        preprocessors, as lerobot-eval's rollout makes it."""
        obs = self.preprocess_observation(self.raw_observation(batch))
        obs["task"] = list(batch["task"])
        obs = self.env_pre(obs)
        return self.pre(obs)

    def noise(self, batch):
        if self.noise_shape is None:
            return None
        torch = self.torch
        rows = []
        for seed, step in zip(batch["seed"].tolist(), batch["policy_step"].tolist()):
            g = torch.Generator().manual_seed((seed * 1000003 + step) % (1 << 63))
            rows.append(torch.normal(0.0, 1.0, size=self.noise_shape, generator=g, dtype=torch.float32))
        return torch.stack(rows).to(self.cfg.device)

    def act(self, batch):
        torch = self.torch
        inputs = self.policy_inputs(batch)
        noise = self.noise(batch)
        with torch.inference_mode():
            if noise is None:
                chunk = self.policy.predict_action_chunk(inputs)
            else:
                chunk = self.policy.predict_action_chunk(inputs, noise=noise)
        chunk = chunk[:, : self.n_action_steps]
        b, t, d = chunk.shape
        # The postprocessors act on (B, D) actions, as after select_action; a chunk goes row by row.
        actions = self.post(chunk.reshape(b * t, d))
        actions = self.env_post({"action": actions})["action"]
        return actions.reshape(b, t, -1).float().cpu().numpy()
