"""Tiny random-weight lerobot 0.6.1 checkpoints, built offline with lerobot's own classes and saved
with their processors, and the oracle that checks the pipeline's `lerobot:` actions against
lerobot's own select_action path (tests/python_policy.rs).

    python lerobot_tiny.py smolvla OUT        # OUT/vlm: a tiny SmolVLM (char tokenizer); OUT/ckpt
    python lerobot_tiny.py act OUT            # ACT for ALOHA-sim (top camera, 14-D state and action)
    python lerobot_tiny.py pi05 OUT           # OUT/tokenizer: a char tokenizer; OUT/ckpt: a tiny π0.5 (run
                                              # with tests/fixtures/python_policies/tiny_pi05 on PYTHONPATH)
    python lerobot_tiny.py oracle CKPT REC    # REC: batches the host recorded (LIBERO_EVAL_HOST_RECORD);
                                              # LIBERO's, or ALOHA-sim's where the batches hold agent_pos
    python lerobot_tiny.py dump REC           # the recorded actions: one line "seed step a0 .. a6" each

The oracle is written from lerobot-eval's rollout (scripts/lerobot_eval.py), not from the host's
adapter: per recorded episode, B = 1, `policy.reset()`, then `select_action` as many times as the
host's chunk has actions (lerobot's own queue), the flow-matching noise drawn by the rule the docs
book gives. It prints one JSON line: the largest difference and how many actions it compared.
"""

import json
import os
import sys

import numpy as np


def save_checkpoint(policy, cfg, stats, out):
    """OUT/ckpt: the policy and its pre/post-processors (with these statistics), as training saves them."""
    from lerobot.policies import make_pre_post_processors

    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
    ckpt = os.path.join(out, "ckpt")
    policy.save_pretrained(ckpt)
    pre.save_pretrained(ckpt)
    post.save_pretrained(ckpt)
    print(json.dumps({"checkpoint": os.path.abspath(ckpt), "parameters": sum(p.numel() for p in policy.parameters())}))


def tiny_smolvla(out):
    import torch
    from tokenizers import Tokenizer, models, pre_tokenizers
    from transformers import PreTrainedTokenizerFast, SmolVLMConfig, SmolVLMProcessor
    from transformers.models.smolvlm.image_processing_smolvlm import SmolVLMImageProcessor
    from transformers.models.smolvlm.video_processing_smolvlm import SmolVLMVideoProcessor
    from lerobot.configs import FeatureType, PolicyFeature
    from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig
    from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy

    vlm = os.path.abspath(os.path.join(out, "vlm"))
    os.makedirs(vlm, exist_ok=True)
    # A character-level tokenizer with SmolVLM's special tokens: offline, no Hub download.
    specials = ["<pad>", "<unk>", "<|im_start|>", "<end_of_utterance>", "<image>", "<fake_token_around_image>",
                "<global-img>", "<video>"]
    chars = list("abcdefghijklmnopqrstuvwxyz0123456789.,;:!?-_'\"() ") + ["\n"]
    tok = Tokenizer(models.WordLevel(vocab={t: i for i, t in enumerate(specials + chars)}, unk_token="<unk>"))
    tok.pre_tokenizer = pre_tokenizers.Split("", "isolated")
    hf_tok = PreTrainedTokenizerFast(
        tokenizer_object=tok, unk_token="<unk>", pad_token="<pad>", bos_token="<|im_start|>",
        eos_token="<end_of_utterance>",
        extra_special_tokens={"fake_image_token": "<fake_token_around_image>", "global_image_token": "<global-img>",
                              "image_token": "<image>", "end_of_utterance_token": "<end_of_utterance>"})
    SmolVLMProcessor(image_processor=SmolVLMImageProcessor(), tokenizer=hf_tok,
                     video_processor=SmolVLMVideoProcessor(), image_seq_len=64).save_pretrained(vlm)
    SmolVLMConfig(
        text_config=dict(model_type="llama", hidden_size=64, intermediate_size=128, num_hidden_layers=2,
                         num_attention_heads=2, num_key_value_heads=1, head_dim=32, vocab_size=len(hf_tok),
                         max_position_embeddings=1024),
        vision_config=dict(hidden_size=32, intermediate_size=64, num_hidden_layers=1, num_attention_heads=2,
                           image_size=512, patch_size=16),
        scale_factor=4, image_token_id=hf_tok.convert_tokens_to_ids("<image>"), vocab_size=len(hf_tok),
    ).save_pretrained(vlm)

    cfg = SmolVLAConfig(
        vlm_model_name=vlm, load_vlm_weights=False, num_vlm_layers=2, device="cpu", push_to_hub=False,
        chunk_size=10, n_action_steps=5,
        input_features={"observation.images.image": PolicyFeature(FeatureType.VISUAL, (3, 256, 256)),
                        "observation.images.image2": PolicyFeature(FeatureType.VISUAL, (3, 256, 256)),
                        "observation.state": PolicyFeature(FeatureType.STATE, (8,))},
        output_features={"action": PolicyFeature(FeatureType.ACTION, (7,))})
    torch.manual_seed(0)
    policy = SmolVLAPolicy(cfg)
    # Statistics that keep random actions in the controller's range: state as is, actions scaled.
    stats = {"observation.state": {"mean": torch.zeros(8), "std": torch.ones(8)},
             "action": {"mean": torch.zeros(7), "std": torch.full((7,), 0.3)}}
    save_checkpoint(policy, cfg, stats, out)


def tiny_pi05(out):
    """π0.5 for LIBERO (both cameras, 8-D state, 7-D actions; chunks of 10, 5 executed) at the size
    the tiny_pi05 sitecustomize gives lerobot's classes (refused without it: a full-size one is 4 B).
    Its tokenizer step names PaliGemma's gated tokenizer, as the published checkpoints do; the run
    passes the local stand-in with `tokenizer=OUT/tokenizer`."""
    import torch
    from tokenizers import Tokenizer, models, pre_tokenizers, processors
    from transformers import PreTrainedTokenizerFast
    import lerobot.policies.pi05.modeling_pi05 as mp
    import lerobot.policies.pi05.processor_pi05 as P
    from lerobot.configs import FeatureType, PolicyFeature
    from lerobot.policies.pi05 import PI05Config, PI05Policy

    if mp.get_gemma_config("gemma_2b").width != 64:
        sys.exit("lerobot_tiny.py pi05 needs tests/fixtures/python_policies/tiny_pi05 on PYTHONPATH (the tiny size)")
    tok_dir = os.path.abspath(os.path.join(out, "tokenizer"))
    # A character-level stand-in for PaliGemma's tokenizer: ids < 257152, a pad and a BOS token.
    chars = list(" abcdefghijklmnopqrstuvwxyz0123456789.,;:!?-_'\"()\n")
    vocab = {"<pad>": 0, "<eos>": 1, "<bos>": 2, "<unk>": 3, **{c: i + 4 for i, c in enumerate(chars)}}
    tok = Tokenizer(models.WordLevel(vocab=vocab, unk_token="<unk>"))
    tok.pre_tokenizer = pre_tokenizers.Split("", "isolated")
    tok.post_processor = processors.TemplateProcessing(single="<bos> $A", special_tokens=[("<bos>", 2)])
    PreTrainedTokenizerFast(tokenizer_object=tok, pad_token="<pad>", bos_token="<bos>", eos_token="<eos>",
                            unk_token="<unk>").save_pretrained(tok_dir)
    cfg = PI05Config(
        dtype="float32", device="cpu", push_to_hub=False, chunk_size=10, n_action_steps=5,
        input_features={"observation.images.image": PolicyFeature(FeatureType.VISUAL, (3, 256, 256)),
                        "observation.images.image2": PolicyFeature(FeatureType.VISUAL, (3, 256, 256)),
                        "observation.state": PolicyFeature(FeatureType.STATE, (8,))},
        output_features={"action": PolicyFeature(FeatureType.ACTION, (7,))})
    torch.manual_seed(0)
    policy = PI05Policy(cfg)
    # QUANTILES statistics: the state as is; actions in a third of the controller's range.
    stats = {"observation.state": {"q01": -torch.ones(8), "q99": torch.ones(8)},
             "action": {"q01": torch.full((7,), -0.3), "q99": torch.full((7,), 0.3)}}
    made = P.TokenizerProcessorStep
    P.TokenizerProcessorStep = lambda **kw: made(**{**kw, "tokenizer_name": tok_dir})
    try:
        save_checkpoint(policy, cfg, stats, out)
    finally:
        P.TokenizerProcessorStep = made
    path = os.path.join(out, "ckpt", "policy_preprocessor.json")
    with open(path) as f:
        pre = json.load(f)
    for step in pre["steps"]:
        if step.get("registry_name") == "tokenizer_processor":
            step["config"]["tokenizer_name"] = "google/paligemma-3b-pt-224"
    with open(path, "w") as f:
        json.dump(pre, f, indent=2)


def tiny_act(out):
    import torch
    from lerobot.configs import FeatureType, PolicyFeature
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy

    cfg = ACTConfig(
        input_features={"observation.images.top": PolicyFeature(FeatureType.VISUAL, (3, 480, 640)),
                        "observation.state": PolicyFeature(FeatureType.STATE, (14,))},
        output_features={"action": PolicyFeature(FeatureType.ACTION, (14,))},
        chunk_size=10, n_action_steps=10, dim_model=64, n_heads=2, dim_feedforward=128, n_encoder_layers=1,
        n_decoder_layers=1, n_vae_encoder_layers=1, latent_dim=8,
        pretrained_backbone_weights=None,  # else torchvision downloads ResNet-18 weights
        device="cpu", push_to_hub=False)
    torch.manual_seed(0)
    policy = ACTPolicy(cfg)
    stats = {"observation.images.top": {"mean": torch.full((3, 1, 1), 0.5), "std": torch.full((3, 1, 1), 0.25)},
             "observation.state": {"mean": torch.zeros(14), "std": torch.ones(14)},
             "action": {"mean": torch.zeros(14), "std": torch.ones(14)}}
    save_checkpoint(policy, cfg, stats, out)


def dump(record_dir):
    for name in sorted(os.listdir(record_dir)):
        rec = np.load(os.path.join(record_dir, name))
        for seed, step, chunk in zip(rec["seed"], rec["policy_step"], rec["actions"]):
            for t, a in enumerate(chunk):
                print(int(seed), int(step) + t, " ".join(repr(float(v)) for v in a))


def oracle(ckpt, record_dir, tokenizer=None):
    import torch
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.envs.configs import AlohaEnv, LiberoEnv
    from lerobot.envs.factory import make_env_pre_post_processors
    from lerobot.envs.utils import preprocess_observation
    from lerobot.policies import make_policy, make_pre_post_processors

    names = sorted(os.listdir(record_dir))
    aloha = "agent_pos" in np.load(os.path.join(record_dir, names[0])).files
    cfg = PreTrainedConfig.from_pretrained(ckpt)
    cfg.pretrained_path = ckpt
    cfg.device = "cpu"
    env_cfg = AlohaEnv(task="AlohaTransferCube-v0") if aloha else LiberoEnv(task="libero_spatial")
    policy = make_policy(cfg, env_cfg=env_cfg)
    policy.eval()
    overrides = {"device_processor": {"device": "cpu"}, "rename_observations_processor": {"rename_map": {}}}
    if tokenizer:
        overrides["tokenizer_processor"] = {"tokenizer_name": tokenizer}
    pre, post = make_pre_post_processors(cfg, pretrained_path=ckpt, preprocessor_overrides=overrides)
    env_pre, env_post = make_env_pre_post_processors(env_cfg, cfg)
    chunk, max_dim = cfg.chunk_size, getattr(cfg, "max_action_dim", None)
    worst, compared, calls = 0.0, 0, 0
    for name in names:
        rec = np.load(os.path.join(record_dir, name))
        calls += 1
        tasks = json.loads(str(rec["task_json"]))
        for i, task in enumerate(tasks):
            if aloha:  # gym-aloha's pixels_agent_pos observation
                raw = {"pixels": {"top": rec["top"][i:i + 1]}, "agent_pos": rec["agent_pos"][i:i + 1]}
            else:  # lerobot's LIBERO env observation (envs/libero.py _format_raw_obs)
                raw = {"pixels": {"image": rec["agentview"][i:i + 1], "image2": rec["wrist"][i:i + 1]},
                       "robot_state": {
                           "eef": {"pos": rec["eef_pos"][i:i + 1], "quat": rec["eef_quat"][i:i + 1],
                                   "mat": rec["eef_mat"][i:i + 1]},
                           "gripper": {"qpos": rec["gripper_qpos"][i:i + 1], "qvel": rec["gripper_qvel"][i:i + 1]},
                           "joints": {"pos": rec["joint_pos"][i:i + 1], "vel": rec["joint_vel"][i:i + 1]}}}
            obs = preprocess_observation(raw)
            obs["task"] = [task]
            obs = pre(env_pre(obs))
            seed, step = int(rec["seed"][i]), int(rec["policy_step"][i])
            kwargs = {}
            if cfg.type in ("pi0", "pi05", "smolvla"):  # flow matching: the noise by the docs' rule
                g = torch.Generator().manual_seed((seed * 1000003 + step) % (1 << 63))
                kwargs["noise"] = torch.normal(0.0, 1.0, size=(1, chunk, max_dim), generator=g, dtype=torch.float32)
            policy.reset()
            host = rec["actions"][i]
            if cfg.type == "pi05":
                # PI05Policy.select_action takes no noise: its body (the queue of
                # predict_action_chunk(batch)[:, :n_action_steps]) with the episode's noise
                with torch.inference_mode():
                    queue = list(policy.predict_action_chunk(obs, **kwargs)[:, :cfg.n_action_steps].transpose(0, 1))
            for t in range(host.shape[0]):
                with torch.inference_mode():
                    a = queue.pop(0) if cfg.type == "pi05" else policy.select_action(obs, **kwargs)
                a = env_post({"action": post(a)})["action"][0].float().numpy()
                worst = max(worst, float(np.abs(a - host[t]).max()))
                compared += 1
    print(json.dumps({"calls": calls, "actions_compared": compared, "max_abs_diff": worst}))


if __name__ == "__main__":
    if sys.argv[1] == "smolvla":
        tiny_smolvla(sys.argv[2])
    elif sys.argv[1] == "act":
        tiny_act(sys.argv[2])
    elif sys.argv[1] == "pi05":
        tiny_pi05(sys.argv[2])
    elif sys.argv[1] == "dump":
        dump(sys.argv[2])
    elif sys.argv[1] == "oracle":
        oracle(sys.argv[2], sys.argv[3], *sys.argv[4:5])
    else:
        sys.exit(f"unknown command {sys.argv[1]!r}")
