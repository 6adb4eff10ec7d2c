"""Fixtures from the original SWAT code for the parity tests, and the weights both sides fill in.

Run as a script in a virtual environment that runs the original code (PyTorch, gym 0.13.1, MuJoCo
2.3.3 and the small mujoco_py shim of the original-code tools; see docs/fidelity.md, "Regenerating the
fixtures") to rewrite ``tests/data/original/*.npz``:

    ORIGINAL_TOOLS=/path/to/tools/original /tmp/orig-venv/bin/python tests/original_parity_data.py

``networks.npz``: for bodies of every family, the original's structure inputs (parents, traversals,
relations) and the outputs of its actor and twin critic for SWAT, AMORPHEUS and SMP (both message
passes) on random observations and actions, in two weight states: ``init`` (the original's own
initialisation, stored for the transformers: every LayerNorm the identity) and ``filled`` (every
weight drawn by :func:`filled_state_dict`, LayerNorms far from the identity; SMP has only this one).
``environments.npz``: for every body of the original, steps of its environment class from known
states and actions: the observation it returns, reward and done, and the observation of the state's
own kinematics. ``models.npz`` and ``models/``: run folders of SWAT and AMORPHEUS saved by the
original's ``checkpoint.save_model``, their state dicts and the actions of their actors. ``updates.npz``: two consecutive ``TD3.train_single`` updates of SWAT and SMP from filled weights,
the batches and the target-policy noise the original drew, and the parameters after each update at
sampled positions. Only :func:`filled_state_dict`, :func:`flat_ids`, :func:`stored_shapes` and
:func:`assert_structure_inputs_equal` are imported by the tests; the first three need nothing but NumPy.
"""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path

import numpy as np

OUTPUT = Path(__file__).resolve().parent / "data" / "original"
NETWORK_BODIES = ("hopper_5", "walker_7_main", "cheetah_4_front", "humanoid_2d_9_full", "nervenet_ostrich")
UPDATE_BODY = "walker_7_main"
FEATURES = 6
BATCH = 4
UPDATE_BATCH = 8
TRANSFORMER = {
    "attention_embedding_size": 16,
    "attention_heads": 2,
    "attention_hidden_size": 32,
    "attention_layers": 2,
}
MESSAGE_WIDTH = 8
PROBES_PER_NETWORK = 3000


def filled_state_dict(shapes: dict[str, tuple[int, ...]], seed: int) -> dict[str, np.ndarray]:
    """Deterministic float32 weights for a state dict of these shapes, keys in sorted order: uniform in
    +-1/sqrt(fan in) (the last axis; an embedding's width), LayerNorm weights in 1 +- 0.5 and biases in
    +-0.5, so no LayerNorm is near the identity."""
    rng = np.random.default_rng(seed)
    filled = {}
    for key in sorted(shapes):
        shape = tuple(shapes[key])
        if ".norm" in key:
            values = rng.uniform(-0.5, 0.5, shape) + (1.0 if key.endswith("weight") else 0.0)
        else:
            bound = 1.0 / np.sqrt(shape[-1] if len(shape) > 1 else shape[0])
            values = rng.uniform(-bound, bound, shape)
        filled[key] = values.astype(np.float32)
    return filled


def flat_ids(shapes: dict[str, tuple[int, ...]]) -> dict[str, np.ndarray]:
    """A state dict of these shapes whose entries number every weight: keys in sorted order, entries in
    row-major order, 0, 1, 2, ... (float64, exact). Mapped like weights, it tells where each of our
    parameters comes from."""
    ids, offset = {}, 0
    for key in sorted(shapes):
        size = int(np.prod(shapes[key]))
        ids[key] = np.arange(offset, offset + size, dtype=np.float64).reshape(shapes[key])
        offset += size
    return ids


def stored_shapes(data, prefix: str) -> dict[str, tuple[int, ...]]:
    """The state-dict shapes the generator saved under ``prefix`` (``<prefix>/keys``, ``<prefix>/shapes``)."""
    return {
        str(key): tuple(int(size) for size in str(shape).split(","))
        for key, shape in zip(data[f"{prefix}/keys"], data[f"{prefix}/shapes"], strict=True)
    }


def assert_structure_inputs_equal(structure, row: int, data, body: str, tolerance: dict) -> None:
    """Row ``row`` of a padded StructureBatch has the parents (any negative one the root's -1), traversal
    positions and relations (swat_jax's channel order) that ``data`` holds for ``body`` under
    ``structure/{body}/``, written by the reference code."""
    from swat_jax.morphology import RELATION_NAMES
    from swat_jax.networks.original_weights import ORIGINAL_RELATION_ORDER

    limbs = int(structure.num_limbs[row])
    parents = data[f"structure/{body}/parents"]
    np.testing.assert_array_equal(structure.parents[row, :limbs], np.where(parents < 0, -1, parents))
    np.testing.assert_array_equal(
        structure.traversal_positions[row, :limbs], data[f"structure/{body}/traversals"]
    )
    channels = [ORIGINAL_RELATION_ORDER.index(name) for name in RELATION_NAMES]
    np.testing.assert_allclose(
        structure.relations[row, :limbs, :limbs],
        data[f"structure/{body}/relations"][..., channels],
        **tolerance,
    )


def _original_args(**overrides):
    from arguments import get_args

    argv, sys.argv = sys.argv, ["main.py"]
    try:
        args = get_args()
    finally:
        sys.argv = argv
    args.traversal_types = ["pre", "inlcrs", "postlcrs"]
    args.rel_size = 3
    args.disable_fold = True
    args.td = args.bu = True
    args.msg_dim = MESSAGE_WIDTH
    args.limb_obs_size = FEATURES
    args.max_action = 1.0
    for key, value in {**TRANSFORMER, **overrides}.items():
        setattr(args, key, value)
    return args


NETWORK_CLASSES = {
    "swat": ("StructureActor.StructurePolicy", "StructureCritic.CriticStructurePolicy"),
    "amorpheus": ("TransformerActor.TransformerPolicy", "TransformerCritic.CriticTransformerPolicy"),
    "smp": ("ModularActor.ActorGraphPolicy", "ModularCritic.CriticGraphPolicy"),
}


def _networks(architecture: str, args):
    import importlib

    built = []
    for path in NETWORK_CLASSES[architecture]:
        module, name = path.split(".")
        cls = getattr(importlib.import_module(module), name)
        common = (args.limb_obs_size, 1, args.msg_dim, args.batch_size)
        if "Critic" in name:
            built.append(cls(*common, args.max_children, True, True, True, args))
        else:
            built.append(cls(*common, args.max_action, args.max_children, True, True, True, args))
    return built


def _numpy_state(module) -> dict[str, np.ndarray]:
    return {
        key: value.detach().cpu().numpy().astype(np.float32) for key, value in module.state_dict().items()
    }


def _load(module, weights: dict[str, np.ndarray]) -> None:
    import torch

    module.load_state_dict({key: torch.from_numpy(value) for key, value in weights.items()})


def _shapes(module) -> dict[str, tuple[int, ...]]:
    return {key: tuple(value.shape) for key, value in module.state_dict().items()}


def _graph(body: str, architecture: str):
    import utils
    from common import xml_path

    parents = utils.getGraphStructure(xml_path(body))
    if architecture == "swat":
        return parents, utils.getGraphDict(parents, ["pre", "inlcrs", "postlcrs"])
    return parents, {"parents": parents}


def _save_shapes(out: dict, prefix: str, shapes: dict) -> None:
    keys = sorted(shapes)
    out[f"{prefix}/keys"] = np.array(keys)
    out[f"{prefix}/shapes"] = np.array([",".join(map(str, shapes[key])) for key in keys])


def generate_networks() -> dict[str, np.ndarray]:
    import torch
    import utils

    out: dict[str, np.ndarray] = {"features": np.int32(FEATURES), "message_width": np.int32(MESSAGE_WIDTH)}
    for key, value in TRANSFORMER.items():
        out[key] = np.int32(value)
    graphs = {body: _graph(body, "smp")[0] for body in NETWORK_BODIES}
    max_children = utils.findMaxChildren(list(NETWORK_BODIES), graphs)
    out["max_children"] = np.int32(max_children)
    rng = np.random.default_rng(0)
    for body in NETWORK_BODIES:
        parents, graph = _graph(body, "swat")
        out[f"structure/{body}/parents"] = np.array(parents, np.int32)
        out[f"structure/{body}/traversals"] = np.stack(
            [t.cpu().numpy() for t in graph["traversals"]], -1
        ).astype(np.int32)
        out[f"structure/{body}/relations"] = graph["relation"].cpu().numpy().astype(np.float32)
        limbs = len(parents)
        out[f"inputs/{body}/observation"] = rng.uniform(-1, 1, (BATCH, limbs * FEATURES)).astype(np.float32)
        out[f"inputs/{body}/action"] = rng.uniform(-1, 1, (BATCH, limbs)).astype(np.float32)
    for architecture in NETWORK_CLASSES:
        torch.manual_seed(0)
        args = _original_args(batch_size=BATCH, max_children=max_children)
        actor, critic = _networks(architecture, args)
        states = ("filled",) if architecture == "smp" else ("init", "filled")
        for state in states:
            for name, network, seed in (("actor", actor, 1), ("critic", critic, 2)):
                _save_shapes(out, f"{architecture}/{name}", _shapes(network))
                if state == "filled":
                    _load(network, filled_state_dict(_shapes(network), seed))
                elif architecture != "smp":
                    for key, value in _numpy_state(network).items():
                        out[f"{architecture}/{state}/{name}/{key}"] = value
            for body in NETWORK_BODIES:
                _, graph = _graph(body, architecture)
                for network in (actor, critic):
                    network.change_morphology(graph)
                observation = torch.from_numpy(out[f"inputs/{body}/observation"])
                action = torch.from_numpy(out[f"inputs/{body}/action"])
                with torch.no_grad():
                    q1, q2 = critic(observation, action)
                    out[f"{architecture}/{state}/{body}/actor"] = actor(observation).numpy()
                out[f"{architecture}/{state}/{body}/q1"] = q1.numpy().reshape(BATCH, -1)
                out[f"{architecture}/{state}/{body}/q2"] = q2.numpy().reshape(BATCH, -1)
    return out


class _FixedBatches:
    """A stand-in replay buffer: ``sample`` returns the given batches in turn and calls ``before`` first."""

    def __init__(self, batches, before):
        self.batches, self.before, self.calls = batches, before, 0

    def sample(self, batch_size):
        assert batch_size == len(self.batches[self.calls][0])
        self.before(self.calls)
        self.calls += 1
        return self.batches[self.calls - 1]


def generate_updates() -> dict[str, np.ndarray]:
    import TD3
    import torch

    out: dict[str, np.ndarray] = {"body": np.array(UPDATE_BODY), "features": np.int32(FEATURES)}
    for key, value in TRANSFORMER.items():
        out[key] = np.int32(value)
    out["message_width"] = np.int32(MESSAGE_WIDTH)
    parents, _ = _graph(UPDATE_BODY, "smp")
    limbs = len(parents)
    rng = np.random.default_rng(1)
    batches = []
    for update in range(2):
        batch = (
            rng.uniform(-1, 1, (UPDATE_BATCH, limbs * FEATURES)),
            rng.uniform(-1, 1, (UPDATE_BATCH, limbs * FEATURES)),
            rng.uniform(-1, 1, (UPDATE_BATCH, limbs)),
            rng.uniform(-1, 1, (UPDATE_BATCH, 1)),
            (rng.uniform(size=(UPDATE_BATCH, 1)) < 0.3).astype(np.float64),
        )
        for name, value in zip(
            ("observation", "next_observation", "action", "reward", "done"), batch, strict=True
        ):
            out[f"batch/{update}/{name}"] = value.astype(np.float32)
        # float64, as the original's replay buffer returns them: torch.FloatTensor copies those, but it
        # would share a float32 array's memory, and the in-place noise draw on the action array would
        # then overwrite the batch's actions.
        batches.append(tuple(value.astype(np.float32).astype(np.float64) for value in batch))
    for architecture in ("swat", "smp"):
        args = _original_args(
            batch_size=UPDATE_BATCH,
            max_children=max(parents.count(p) for p in set(parents)),
            actor_type=architecture,
            critic_type=architecture,
        )
        out[f"{architecture}/max_children"] = np.int32(args.max_children)
        torch.manual_seed(0)
        policy = TD3.TD3(args)
        networks = {
            "actor": policy.actor,
            "critic": policy.critic,
            "target_actor": policy.actor_target,
            "target_critic": policy.critic_target,
        }
        for name, seed in (("actor", 1), ("critic", 2)):
            shapes = _shapes(networks[name])
            _save_shapes(out, f"{architecture}/{name}", shapes)
            weights = filled_state_dict(shapes, seed)
            _load(networks[name], weights)
            _load(networks["target_" + name], weights)
            total = sum(int(np.prod(s)) for s in shapes.values())
            out[f"{architecture}/{name}/probe_ids"] = np.sort(
                rng.choice(total, min(total, PROBES_PER_NETWORK), replace=False)
            )
        policy.change_morphology(_graph(UPDATE_BODY, architecture)[1])

        def snapshot(update, architecture=architecture, networks=networks):
            if update == 0:
                return
            _record(out, f"{architecture}/after/{update - 1}", networks)

        with _recorded_normal_draws() as noise:
            policy.train_single(
                _FixedBatches(batches, snapshot),
                2,
                batch_size=UPDATE_BATCH,
                discount=args.discount,
                tau=args.tau,
                policy_noise=args.policy_noise,
                noise_clip=args.noise_clip,
                policy_freq=args.policy_freq,
            )
        _record(out, f"{architecture}/after/1", networks)
        assert len(noise) == 2, f"expected one noise draw per update, got {len(noise)}"
        for update, draw in enumerate(noise):
            out[f"{architecture}/noise/{update}"] = draw.astype(np.float32)
    return out


@contextlib.contextmanager
def _recorded_normal_draws():
    """Every ``Tensor.normal_`` result while inside (the original's target-policy noise), as NumPy arrays."""
    import torch

    draws, normal = [], torch.Tensor.normal_

    def recording(tensor, *args, **kwargs):
        result = normal(tensor, *args, **kwargs)
        draws.append(result.detach().clone().numpy())
        return result

    torch.Tensor.normal_ = recording
    try:
        yield draws
    finally:
        torch.Tensor.normal_ = normal


def _record(out: dict, prefix: str, networks: dict) -> None:
    for name, network in networks.items():
        architecture, base = prefix.split("/")[0], name.removeprefix("target_")
        state = _numpy_state(network)
        flat = np.concatenate([state[key].ravel() for key in out[f"{architecture}/{base}/keys"]])
        out[f"{prefix}/{name}"] = flat[out[f"{architecture}/{base}/probe_ids"]]


ENVIRONMENT_STEPS = 30
"""Random-action steps per body (with resets at termination); RECORDED_STEPS of them are kept."""
RECORDED_STEPS = (0, 1, 14, 29)


def generate_environments() -> dict[str, np.ndarray]:
    """For every body with an environment class in the original, a few steps of that class: the state
    before (qpos, qvel), the action (motor order), the state after, what ``step`` gives (observation,
    reward, done), and the observation recomputed after an extra ``sim.forward()`` (the state's own
    kinematics)."""
    import importlib

    from common import SRC, xml_path

    out: dict[str, np.ndarray] = {}
    names = sorted(name[:-3] for name in os.listdir(Path(SRC) / "environments") if name.endswith(".py"))
    for body in (name for name in names if name != "ModularEnv"):
        env = importlib.import_module(f"environments.{body}").ModularEnv(xml_path(body))
        env.seed(0)
        rng = np.random.RandomState(0)
        fields = ("qpos", "qvel", "action", "qpos_after", "qvel_after", "obs", "obs_fresh", "reward", "done")
        records: dict[str, list] = {key: [] for key in fields}
        env.reset()
        for step in range(ENVIRONMENT_STEPS):
            qpos, qvel = env.sim.data.qpos.copy(), env.sim.data.qvel.copy()
            action = rng.uniform(env.action_space.low, env.action_space.high)
            observation, reward, done, _ = env.step(action)
            observation = np.array(observation, copy=True)
            env.sim.forward()
            if step in RECORDED_STEPS:
                after = (env.sim.data.qpos.copy(), env.sim.data.qvel.copy())
                values = (qpos, qvel, action, *after, observation, env._get_obs().copy(), reward, done)
                for key, value in zip(fields, values, strict=True):
                    records[key].append(value)
            if done:
                env.reset()
        for key, values in records.items():
            out[f"{body}/{key}"] = np.array(values)
    return out


MODEL_BODY = "hopper_3"
MODEL_ARCHITECTURES = ("swat", "transformer")
"""Checkpoints written by the original's own ``checkpoint.save_model`` for the converter's tests (SMP's
400-300 layers would make a file of megabytes; its weights are checked by the network tests)."""


def generate_models() -> dict[str, np.ndarray]:
    """For SWAT and AMORPHEUS (the original's ``transformer``): a run folder as the original ``main.py``
    writes it (``args.txt``, ``model_1.pyth`` from ``checkpoint.save_model``) under
    ``tests/data/original/models/<type>/``, and, in the returned arrays, its state dicts and the
    actor's actions for random observations of MODEL_BODY. For SMP (whose files would be megabytes):
    its args, state-dict shapes and actions with filled weights."""
    import json

    import checkpoint
    import TD3
    import torch

    out: dict[str, np.ndarray] = {"body": np.array(MODEL_BODY)}
    parents, graph = _graph(MODEL_BODY, "swat")
    rng = np.random.default_rng(2)
    observation = rng.uniform(-1, 1, (BATCH, len(parents) * 19)).astype(np.float32)
    out["observation"] = observation
    for architecture in MODEL_ARCHITECTURES:
        args = _original_args(
            batch_size=BATCH, actor_type=architecture, critic_type=architecture, max_children=2
        )
        args.limb_obs_size = 19
        args.custom_xml = "environments/hoppers"
        args.seed = 3
        folder = OUTPUT / "models" / architecture
        folder.mkdir(parents=True, exist_ok=True)
        saved = {
            key: value
            for key, value in vars(args).items()
            if isinstance(value, int | float | str | list | type(None))
        }
        (folder / "args.txt").write_text(json.dumps(saved, indent=2))
        torch.manual_seed(0)
        policy = TD3.TD3(args)
        for network, seed in ((policy.actor, 3), (policy.critic, 4)):
            _load(network, filled_state_dict(_shapes(network), seed))
        for name, network in (
            ("actor", policy.actor),
            ("critic", policy.critic),
            ("target_actor", policy.actor_target),
            ("target_critic", policy.critic_target),
        ):
            for key, value in _numpy_state(network).items():
                out[f"{architecture}/{name}/{key}"] = value
        checkpoint.save_model(
            str(folder), policy, 1234, 5, 1234, {}, [MODEL_BODY], args, model_name="model_1.pyth"
        )
        policy.change_morphology(graph if architecture == "swat" else {"parents": parents})
        with torch.no_grad():
            out[f"{architecture}/actions"] = policy.actor(torch.from_numpy(observation)).numpy()
    # SMP at the original's default sizes (msg_dim 32, the 400-300 layers), Hopper++'s one child slot:
    # its args, state-dict shapes and actions, the weights filled as filled_state_dict fills them.
    args = _original_args(batch_size=BATCH, actor_type="smp", critic_type="smp", max_children=1)
    args.limb_obs_size, args.msg_dim, args.custom_xml, args.seed = 19, 32, "environments/hoppers", 3
    saved = {key: value for key, value in vars(args).items() if isinstance(value, int | float | str | list)}
    out["smp/args"] = np.array(json.dumps({**saved, "max_children": None}))
    torch.manual_seed(0)
    actor, critic = _networks("smp", args)
    for name, network, seed in (("actor", actor, 3), ("critic", critic, 4)):
        _save_shapes(out, f"smp/{name}", _shapes(network))
        _load(network, filled_state_dict(_shapes(network), seed))
    actor.change_morphology({"parents": parents})
    with torch.no_grad():
        out["smp/actions"] = actor(torch.from_numpy(observation)).numpy()
    return out


def main() -> None:
    tools = os.environ.get("ORIGINAL_TOOLS")
    if not tools:
        sys.exit("set ORIGINAL_TOOLS to the folder of the original-code tools (its common.py and shim/)")
    sys.path.insert(0, tools)
    import common

    common.setup_paths()
    OUTPUT.mkdir(parents=True, exist_ok=True)
    for name, generate in (
        ("networks", generate_networks),
        ("updates", generate_updates),
        ("environments", generate_environments),
        ("models", generate_models),
    ):
        path = OUTPUT / f"{name}.npz"
        np.savez_compressed(path, **generate())
        print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    main()
