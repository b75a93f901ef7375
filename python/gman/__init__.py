"""GMAN object navigation from Python (gman-rs inside).

* :func:`make_vec_env` -- the simulator as a :class:`gymnasium.vector.VectorEnv`: a batch of
  episodes stepped in Rust with the GIL released, observations written in place into numpy
  arrays. Also registered as ``gman/ObjectNav-v0`` (single env :class:`ObjectNavEnv`,
  vector entry point :class:`VecEnv`).
* :func:`evaluate` -- the paper's metrics (SR, SPL, EPA, DTS; seen and unseen targets) on the
  official episodes, computed by the same code as ``gman eval --json``.
* :class:`Navigator` -- gman-core's navigator over a weight blob (``*.gman``): the same bits
  as ``gman eval`` and the firmware.

Actions are ``Discrete(6)`` in the paper's order: 0 MoveAhead, 1 RotateLeft, 2 RotateRight,
3 LookUp, 4 LookDown, 5 Done.

Example::

    import numpy as np, gman
    env = gman.make_vec_env(split="train", num_envs=16, seed=0)
    obs, info = env.reset(seed=0)
    for _ in range(100):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    print(gman.evaluate("oracle")["results"]["unseen"]["sr"])   # 100.0
"""

from __future__ import annotations

import json
import os
from typing import Any, Callable, Dict, Optional, Sequence, Tuple, Union

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv as _GymVectorEnv
from gymnasium.vector.utils import batch_space

from . import _args, _gman

__all__ = [
    "ACTIONS",
    "ATTR_DIM",
    "ClosedEnvironmentError",
    "FEATURE_DIM",
    "NUM_ACTIONS",
    "Navigator",
    "ObjectNavEnv",
    "VecEnv",
    "__version__",
    "evaluate",
    "make_vec_env",
]

__version__: str = _gman.__version__
"""The package's version (the Rust crate's, which is the wheel's)."""

FEATURE_DIM: int = _gman.FEATURE_DIM
"""Length of the pooled observation embedding (512)."""
ATTR_DIM: int = _gman.ATTR_DIM
"""Length of a target's attribute vector SE(y) (45)."""
NUM_ACTIONS: int = _gman.NUM_ACTIONS
"""Number of actions (6)."""
ACTIONS: Tuple[str, ...] = ("MoveAhead", "RotateLeft", "RotateRight", "LookUp", "LookDown", "Done")
"""Action names by index (the paper's order)."""

MaxSteps = Union[None, int, Tuple[int, int]]
Policy = Callable[[Dict[str, np.ndarray], Dict[str, np.ndarray]], Any]

#: Frames per second of a recorded video (``render_mode="rgb_array"`` with gymnasium's
#: ``RecordVideo``): one frame per action.
RENDER_FPS = 4


class ClosedEnvironmentError(gymnasium.error.ClosedEnvironmentError, RuntimeError):
    """A call on a closed environment (both gymnasium's error and a ``RuntimeError``)."""


def _closed() -> ClosedEnvironmentError:
    return ClosedEnvironmentError("the environment is closed")


def _observation_space(map_rows: int, map_cols: int) -> spaces.Dict:
    d = {
        "features": spaces.Box(0.0, 1.0, (FEATURE_DIM,), np.float32),
        "target": spaces.Box(0.0, 1.0, (ATTR_DIM,), np.float32),
        "ps_target": spaces.Box(0.0, 1.0, (ATTR_DIM,), np.float32),
    }
    if map_rows:
        d["map"] = spaces.Box(0.0, 1.0, (map_rows * map_cols, FEATURE_DIM), np.float32)
    return spaces.Dict(d)


_INFO_KEYS = (
    "success",
    "episode_start",
    "shortest_path",
    "target_category",
    "scene",
    "episode_index",
    "episode_seed",
    "steps",
)


class VecEnv(_GymVectorEnv):
    """A batch of ``num_envs`` GMAN episodes stepped together in Rust.

    Observations (a dict of numpy arrays, batch first):

    * ``features`` float32 ``(B, 512)``: the pooled observation embedding s_t;
    * ``target`` float32 ``(B, 45)``: the target's attribute vector SE(y);
    * ``ps_target`` float32 ``(B, 45)``: the PS module's target (mean attribute vector of the
      categories in view);
    * ``map`` float32 ``(B, rows*cols, 512)``: the spatial map, only with ``map=(rows, cols)``.

    Rewards are the chosen reward kind (default the paper's ``"mixed"``); ``terminated`` is set
    when Done is issued, ``truncated`` at the step limit. ``info`` holds arrays ``success``,
    ``shortest_path`` (SPL's shortest path in actions, Done included; -1 if unreachable),
    ``target_category``, ``scene`` (ids: :meth:`category_names`, :meth:`scene_names`),
    ``episode_index`` (official episode, -1 in training), ``episode_seed``, ``steps``,
    ``episode_start`` and, with ``oracle=True``, ``oracle_action`` (a shortest-path action).

    Autoreset is gymnasium's default ``NEXT_STEP`` mode: the step after an episode ended
    resets that environment (its action is ignored, reward 0, not terminated).

    The arrays are allocated once and refilled in place by every ``step``/``reset`` (no
    per-step Python objects per environment); pass ``copy=True`` to receive copies.

    ``max_episode_steps`` (what ``gymnasium.make_vec`` passes from the spec, 200) caps both
    step limits, as gymnasium's ``TimeLimit`` caps a single env.

    ``split="train"`` samples training tasks (slot i's sampler is seeded with ``seed + i``);
    ``split="val"`` / ``"test"`` hands out the official episodes in file order (slot by slot,
    wrapping around after the last).
    """

    metadata = {
        "autoreset_mode": AutoresetMode.NEXT_STEP,
        "render_modes": ["rgb_array"],
        "render_fps": RENDER_FPS,
    }

    def __init__(
        self,
        num_envs: int = 1,
        *,
        data: Union[None, str, "os.PathLike[str]"] = None,
        split: str = "train",
        seed: Optional[int] = None,
        world_seed: int = 2022,
        domain_shift: float = 1.0,
        map: Optional[Tuple[int, int]] = None,
        max_steps: MaxSteps = None,
        reward: str = "mixed",
        episodes: Optional[int] = None,
        oracle: bool = False,
        copy: bool = False,
        render_mode: Optional[str] = None,
        max_episode_steps: Optional[int] = None,
    ) -> None:
        # Every argument checked before anything is built (gman._args: one rule each).
        n = _args.num_envs(num_envs)
        data_dir = _args.path("data", data, optional=True)
        split = _args.choice("split", split, _args.SPLITS)
        seed = _args.seed("seed", seed)
        world_seed = _args.integer("world_seed", world_seed, 0, _args.MAX_SEED, "a u64 seed")
        domain_shift = _args.domain_shift(domain_shift)
        rows, cols = _args.map_grid(map)
        living, other = _args.max_steps(max_steps)
        if max_episode_steps is not None:
            # gymnasium.make_vec passes the spec's max_episode_steps (TimeLimit's cap).
            cap = _args.integer("max_episode_steps", max_episode_steps, 1, _args.MAX_STEPS)
            living, other = min(living, cap), min(other, cap)
        reward = _args.choice("reward", reward, _args.REWARDS)
        episodes = _args.episodes(episodes)
        oracle = _args.boolean("oracle", oracle)
        copy = _args.boolean("copy", copy)
        self.render_mode = _args.choice("render_mode", render_mode, _args.RENDER_MODES)
        self._core = _gman.VecCore(
            data_dir, world_seed, split, n, reward, living, other, rows, cols, oracle, episodes,
            self.render_mode is not None, domain_shift,
        )
        self._seed = seed
        self._copy = copy
        self._oracle = oracle
        self._has_map = rows > 0
        self.num_envs = n
        self.single_observation_space = _observation_space(rows, cols)
        self.single_action_space = spaces.Discrete(NUM_ACTIONS)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.split = split
        a = self._core.arrays()
        self._arrays = a
        self._obs = {"features": a["features"], "target": a["target"], "ps_target": a["ps_target"]}
        if self._has_map:
            self._obs["map"] = a["map"]
        self._info_keys = _INFO_KEYS + (("oracle_action",) if self._oracle else ())
        self._started = False

    def _live(self) -> "_gman.VecCore":
        """The native batch, or :class:`ClosedEnvironmentError` after :meth:`close`."""
        if self._core is None:
            raise _closed()
        return self._core

    # -- gymnasium API -------------------------------------------------------------------

    def reset(
        self, *, seed: Optional[int] = None, options: Optional[Dict[str, Any]] = None
    ) -> Tuple[Dict[str, np.ndarray], Dict[str, np.ndarray]]:
        """Starts a new episode in every environment (the official list from its start).

        ``seed`` (0..2**64-1) reseeds slot i's training sampler with ``seed + i``; this
        environment takes no ``options`` (None or ``{}``).
        """
        core = self._live()
        seed = _args.seed("seed", seed)
        _args.reset_options(options)
        if seed is None and not self._started:
            seed = self._seed
        core.reset(seed, True)
        self._started = True
        return self._observation(), self._info()

    def step(
        self, actions: Any
    ) -> Tuple[Dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray, Dict[str, np.ndarray]]:
        """Steps every environment with ``actions`` (integers in 0..=5, one per environment).

        A refused call (``TypeError`` / ``ValueError``) steps no environment.
        """
        core = self._live()
        if not self._started:
            raise RuntimeError("call reset() before step()")
        core.step(_actions(actions, self.num_envs))
        a = self._arrays
        rew, term, trunc = a["reward"], a["terminated"], a["truncated"]
        if self._copy:
            rew, term, trunc = rew.copy(), term.copy(), trunc.copy()
        return self._observation(), rew, term, trunc, self._info()

    def render(self) -> Optional[Tuple[np.ndarray, ...]]:
        """With ``render_mode="rgb_array"``: one top-down RGB view per environment (``uint8``,
        ``(height, width, 3)``, the size depending on the scene): the floor plan, the objects,
        the target's instances outlined, the episode's path so far and the agent's heading.
        None without a render mode."""
        core = self._live()
        if self.render_mode is None:
            return None
        if not self._started:
            raise RuntimeError("call reset() before render()")
        return tuple(core.render(i) for i in range(self.num_envs))

    def close_extras(self, **kwargs: Any) -> None:
        self._core = None  # type: ignore[assignment]

    # -- extras --------------------------------------------------------------------------

    def scene_names(self) -> Sequence[str]:
        """Scene names by the ids of ``info["scene"]``."""
        return self._live().scene_names()

    def category_names(self) -> Sequence[str]:
        """Category names by the ids of ``info["target_category"]``."""
        return self._live().category_names()

    @property
    def num_episodes(self) -> int:
        """Official episodes of the split (0 for train)."""
        return self._live().num_episodes

    @property
    def completed_episodes(self) -> int:
        """Official episodes finished at least once since the last reset."""
        return self._live().completed

    def report(self, agent: str = "python") -> Dict[str, Any]:
        """``gman eval --json``'s report of the official episodes once all have finished."""
        core = self._live()
        r, _ = core.report(_args.text("agent", agent))
        return json.loads(r)

    def _observation(self) -> Dict[str, np.ndarray]:
        if self._copy:
            return {k: v.copy() for k, v in self._obs.items()}
        return dict(self._obs)

    def _info(self) -> Dict[str, np.ndarray]:
        a = self._arrays
        if self._copy:
            return {k: a[k].copy() for k in self._info_keys}
        return {k: a[k] for k in self._info_keys}


def _actions(actions: Any, n: int) -> np.ndarray:
    a = np.asarray(actions)
    if a.dtype.kind not in "iu":
        raise TypeError(f"actions must be integers (0..={NUM_ACTIONS - 1}), got dtype {a.dtype}")
    if a.shape != (n,):
        raise ValueError(f"actions must have shape ({n},), got {a.shape}")
    # The native step checks the range; uint64 values above int64's range would wrap in the
    # conversion below, so they are refused here with their own value.
    if a.dtype == np.uint64 and a.size and a.max() >= NUM_ACTIONS:
        i = int(np.flatnonzero(a >= NUM_ACTIONS)[0])
        raise ValueError(
            f"actions[{i}] = {a[i]} is not an action (0..={NUM_ACTIONS - 1}: "
            + ", ".join(ACTIONS) + ")"
        )
    return np.ascontiguousarray(a, dtype=np.int64)


class ObjectNavEnv(gymnasium.Env):
    """One GMAN episode at a time (``gman/ObjectNav-v0``): a :class:`VecEnv` of one.

    The same observations, rewards and info as :class:`VecEnv` (without the batch axis) and
    the same arguments except ``num_envs`` and ``copy`` (observations are always copies).
    ``reset(seed=s)`` seeds the training sampler with ``s`` (slot 0 of a VecEnv seeded with
    ``s``); on an evaluation split each ``reset()`` takes the next official episode.
    ``render_mode="rgb_array"``: :meth:`render` returns the top-down view of the episode.

    ``gymnasium.make("gman/ObjectNav-v0")`` wraps it in ``TimeLimit(200)``
    (``spec.max_episode_steps``, the longest default episode); with ``max_steps`` above 200
    also pass ``max_episode_steps=`` (or ``-1`` for no wrapper), or the wrapper truncates first.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": RENDER_FPS}

    def __init__(self, **kwargs: Any) -> None:
        if "num_envs" in kwargs and _args.num_envs(kwargs.pop("num_envs")) != 1:
            raise ValueError("num_envs: ObjectNavEnv is one environment (use VecEnv for more)")
        if "copy" in kwargs and not _args.boolean("copy", kwargs.pop("copy")):
            raise ValueError("copy: ObjectNavEnv always returns copies (copy=True)")
        self._vec = VecEnv(1, copy=True, **kwargs)
        self.render_mode = self._vec.render_mode
        self.observation_space = self._vec.single_observation_space
        self.action_space = self._vec.single_action_space
        self._done = True
        self._fresh = True
        self._closed = False

    def _core(self) -> "_gman.VecCore":
        if self._closed:
            raise _closed()
        return self._vec._live()

    def reset(
        self, *, seed: Optional[int] = None, options: Optional[Dict[str, Any]] = None
    ) -> Tuple[Dict[str, np.ndarray], Dict[str, Any]]:
        core = self._core()
        seed = _args.seed("seed", seed)
        _args.reset_options(options)
        super().reset(seed=seed)
        if seed is None and self._fresh:
            seed = self._vec._seed
        core.reset(seed, self._fresh or seed is not None)
        self._vec._started = True
        self._fresh = False
        self._done = False
        return _unbatch(self._vec._observation()), _unbatch(self._vec._info())

    def step(self, action: Any):
        self._core()
        if self._done:
            raise RuntimeError("the episode is over: call reset()")
        a = np.asarray(action)
        if a.dtype.kind not in "iu" or a.shape != ():
            raise TypeError(f"action must be one integer in 0..={NUM_ACTIONS - 1}, got {action!r}")
        if not 0 <= int(a) < NUM_ACTIONS:
            raise ValueError(f"action = {int(a)} is not an action (0..={NUM_ACTIONS - 1}: " + ", ".join(ACTIONS) + ")")
        obs, rew, term, trunc, info = self._vec.step(a.reshape(1))
        self._done = bool(term[0] or trunc[0])
        return _unbatch(obs), float(rew[0]), bool(term[0]), bool(trunc[0]), _unbatch(info)

    def render(self) -> Optional[np.ndarray]:
        """The top-down RGB view (``uint8``, ``(height, width, 3)``) with
        ``render_mode="rgb_array"``; None without a render mode."""
        self._core()
        frames = self._vec.render()
        return None if frames is None else frames[0]

    def close(self) -> None:
        """Releases the environment; a second call does nothing."""
        if not self._closed:
            self._vec.close()
            self._closed = True


def _unbatch(d: Dict[str, np.ndarray]) -> Dict[str, Any]:
    # Numpy scalars keep their dtype (episode seeds are uint64), also when gymnasium's
    # SyncVectorEnv batches the infos again.
    return {k: v[0] for k, v in d.items()}


def make_vec_env(
    data: Union[None, str, "os.PathLike[str]"] = None,
    split: str = "train",
    num_envs: int = 1,
    seed: Optional[int] = None,
    map: Optional[Tuple[int, int]] = None,
    max_steps: MaxSteps = None,
    *,
    reward: str = "mixed",
    world_seed: int = 2022,
    domain_shift: float = 1.0,
    episodes: Optional[int] = None,
    oracle: bool = False,
    copy: bool = False,
    render_mode: Optional[str] = None,
) -> VecEnv:
    """A :class:`VecEnv` of ``num_envs`` environments.

    Every argument is checked before anything is built: a wrong type raises ``TypeError``, a
    value out of range ``ValueError`` naming the argument and its range (the table in
    ``docs/python.md``).

    Args:
        data: GMAN data directory (``attributes.json``, ``scenes/``, ``episodes/``); None for
            the built-in synthetic world.
        split: ``"train"`` (sampled tasks), ``"val"`` or ``"test"`` (official episodes in order).
        num_envs: batch size B, 1..=65536 (and at most 2**28 observation floats per batch).
        seed: seed of the training sampler used by the first ``reset()`` (slot i: seed + i),
            0..=2**64-1.
        map: ``(rows, cols)``, each 1..=16 (at most 7 on offline data), adds the spatial map
            observation ``obs["map"]``.
        max_steps: step limit, one int or ``(living_room, other)``, each 1..=2**31-1;
            default 200 / 100.
        reward: ``"mixed"`` (the paper's), ``"navigation"``, ``"distance"`` or ``"similarity"``.
        world_seed: world seed (``gman --world-seed``), 0..=2**64-1.
        domain_shift: strength S of every scene's style (``gman --domain-shift``), 0..=3:
            1 is the simulator's default, 0 makes every object look the same in every scene
            (``host-sim/SIMULATOR.md``, "Domain shift").
        episodes: at most this many episodes per episode file (``gman eval --episodes``).
        oracle: add ``info["oracle_action"]`` (a shortest-path action, for scripted agents).
        copy: return copies instead of the arrays refilled in place.
        render_mode: None or ``"rgb_array"`` (``render()`` returns each environment's
            top-down view).
    """
    return VecEnv(
        num_envs,
        data=data,
        split=split,
        seed=seed,
        world_seed=world_seed,
        domain_shift=domain_shift,
        map=map,
        max_steps=max_steps,
        reward=reward,
        episodes=episodes,
        oracle=oracle,
        copy=copy,
        render_mode=render_mode,
    )


def evaluate(
    policy: Union[str, "os.PathLike[str]", bytes, Policy],
    data: Union[None, str, "os.PathLike[str]"] = None,
    split: str = "val",
    *,
    num_envs: Optional[int] = None,
    episodes: Optional[int] = None,
    map: Optional[Tuple[int, int]] = None,
    max_steps: MaxSteps = None,
    reward: str = "mixed",
    world_seed: int = 2022,
    domain_shift: float = 1.0,
    seed: Optional[int] = None,
    agent_name: Optional[str] = None,
    return_episodes: bool = False,
) -> Any:
    """The paper's metrics on the official episodes of ``split``, as ``gman eval --json``.

    ``policy`` is one of:

    * ``"random"`` or ``"oracle"``: the built-in agents (``seed`` seeds the random one,
      default 0);
    * a path to a model file (training checkpoint or ``*.gman`` blob), or a blob's ``bytes``:
      evaluated by ``gman eval``'s evaluator (gman-core's navigator, the device's bits);
    * a callable ``policy(obs, info) -> actions`` over batches of a :class:`VecEnv` of
      ``num_envs`` environments (default 16): ``info["episode_start"]`` marks each new
      episode, ``info["ended"]`` the environments whose episode ended at the last step (they
      reset at this step and their action is ignored), ``info["oracle_action"]`` is a
      shortest-path action.

    Options that do not apply to a kind of policy are refused (``ValueError`` saying why), not
    ignored: ``num_envs`` applies only to a callable; ``seed`` only to ``"random"``; ``map``
    to a callable (the environment's map) and to a model, where it must equal the model's own
    grid (``map=None`` takes the model's); the built-in agents take no map.

    Returns the report dict (``results.seen`` / ``results.unseen`` with ``sr``, ``spl``,
    ``epa`` in percent and ``dts`` in metres, ``by_room``, ``episodes``), the same numbers
    ``gman eval`` writes; with ``return_episodes=True`` also the list of per-episode results.
    """
    data_dir = _args.path("data", data, optional=True)
    split = _args.choice("split", split, _args.SPLITS)
    if split == "train":
        raise ValueError('split = "train" has no official episodes; use split="val" or "test"')
    episodes = _args.episodes(episodes)
    living, other = _args.max_steps(max_steps)
    reward = _args.choice("reward", reward, _args.REWARDS)
    world_seed = _args.integer("world_seed", world_seed, 0, _args.MAX_SEED, "a u64 seed")
    domain_shift = _args.domain_shift(domain_shift)
    seed = _args.seed("seed", seed)
    agent_name = _args.text("agent_name", agent_name, optional=True)
    return_episodes = _args.boolean("return_episodes", return_episodes)
    grid = None if map is None else _args.map_grid(map)
    n = None if num_envs is None else _args.num_envs(num_envs)
    if isinstance(policy, (bytes, bytearray, memoryview, str, os.PathLike)):
        builtin = isinstance(policy, str) and policy in ("random", "oracle")
        kind = f"the built-in {policy!r} agent" if builtin else "a model"
        if n is not None:
            raise ValueError(
                f"num_envs = {n} applies only to a callable policy: {kind} is evaluated by "
                "gman eval's evaluator, which steps every episode itself"
            )
        if seed is not None and policy != "random":
            raise ValueError(
                f"seed = {seed} seeds only the built-in \"random\" agent, not {kind} "
                "(a model's episodes are seeded by the episode list)"
            )
        if grid is not None and builtin:
            raise ValueError(f"map = {map!r}: {kind} takes no map")
    if isinstance(policy, (bytes, bytearray, memoryview)):
        r, e = _gman.host_evaluate(
            data_dir, world_seed, split, agent_name or "blob", bytes(policy), 0, episodes,
            reward, living, other, grid, domain_shift,
        )
    elif isinstance(policy, (str, os.PathLike)):
        name = _args.path("policy", policy)
        r, e = _gman.host_evaluate(
            data_dir, world_seed, split, name, None, seed or 0, episodes, reward, living, other,
            grid, domain_shift,
        )
        if agent_name:
            r = json.dumps({**json.loads(r), "agent": agent_name})
    elif callable(policy):
        if seed is not None:
            raise ValueError(
                f"seed = {seed} seeds only the built-in \"random\" agent; a callable policy "
                "seeds itself (the episodes' seeds are in info[\"episode_seed\"])"
            )
        n = 16 if n is None else n
        env = VecEnv(
            n, data=data_dir, split=split, world_seed=world_seed, domain_shift=domain_shift, map=map,
            max_steps=(living, other), reward=reward, episodes=episodes, oracle=True,
        )
        try:
            obs, info = env.reset()
            info["ended"] = np.zeros(n, bool)
            core = env._core
            total = core.num_episodes
            while core.completed < total:
                obs, _, term, trunc, info = env.step(policy(obs, info))
                info["ended"] = term | trunc
            r, e = core.report(agent_name or getattr(policy, "__name__", "python"))
        finally:
            env.close()
    else:
        raise TypeError(
            "policy must be \"random\", \"oracle\", a model path, blob bytes or a callable "
            f"policy(obs, info) -> actions; got {type(policy).__name__}"
        )
    report = json.loads(r)
    return (report, json.loads(e)) if return_episodes else report


class Navigator:
    """gman-core's navigator over a weight blob, as ``gman eval --agent BLOB`` runs it.

    ``reset(attr, seed)`` starts an episode; ``step(obs, map=None, ps=None)`` returns
    ``(action, probs, value, adapted)`` and buffers the step; every ``k`` steps (the blob's
    schedule) the inner update (Algorithm 1, lines 15-20) runs inside ``step``; ``adapt()``
    runs it now. Same bits as the CLI and the firmware. Arguments are checked before the
    navigator is touched (``TypeError`` / ``ValueError`` naming the argument).
    """

    def __init__(self, core: "_gman.NavigatorCore") -> None:
        if not isinstance(core, _gman.NavigatorCore):
            raise TypeError("use Navigator.from_blob(bytes) or Navigator.from_file(path)")
        self._core = core

    @classmethod
    def from_blob(cls, blob: Union[bytes, bytearray, memoryview]) -> "Navigator":
        """Parses a ``*.gman`` blob (raises ValueError naming the problem if it is invalid)."""
        if not isinstance(blob, (bytes, bytearray, memoryview)):
            raise TypeError(f"blob must be bytes, got {type(blob).__name__}")
        return cls(_gman.NavigatorCore.from_blob(bytes(blob)))

    @classmethod
    def from_file(cls, path: Union[str, "os.PathLike[str]"]) -> "Navigator":
        """Reads and parses a blob file."""
        p = _args.path("path", path)
        if not os.path.isfile(p):
            raise FileNotFoundError(f"path {p!r}: no such blob file")
        with open(p, "rb") as f:
            return cls.from_blob(f.read())

    @property
    def method(self) -> str:
        """The method the blob was trained as."""
        return self._core.method

    @property
    def mode(self) -> str:
        """Adaptation mode: ``"efficient"`` (the microcontroller's) or ``"full"``."""
        return self._core.mode

    @property
    def map_shape(self) -> Tuple[int, int]:
        """(rows, cols) of the spatial map the model takes, (0, 0) without one."""
        return tuple(self._core.map_shape)  # type: ignore[return-value]

    @property
    def settings(self) -> Dict[str, Any]:
        """Every setting of the model by key (``gman inspect``'s words), e.g.
        ``{"adapt": True, "inner_lr": 0.01, "step_rule": "paper", ...}``; ``None`` for a
        setting that follows another (``disc_lr`` when it is ``inner_lr``)."""
        return dict(self._core.settings)

    @property
    def buffered(self) -> int:
        """Steps buffered for the next inner update."""
        return self._core.buffered

    def reset(self, attr: Any, seed: int) -> None:
        """Starts an episode with target attribute vector ``attr`` (45 floats) and ``seed``
        (0..=2**64-1)."""
        if seed is None:
            raise TypeError("seed must be an integer, got None")
        s = _args.seed("seed", seed)
        self._core.reset(_args.float_vector("attr", attr, self._core.attr_dim), s)

    def step(
        self, obs: Any, map: Any = None, ps: Any = None
    ) -> Tuple[int, np.ndarray, float, bool]:
        """One control step: ``(action, probs, value, adapted)``."""
        o = _args.float_vector("obs", obs, FEATURE_DIM)
        n = self._core.map_len
        if n and map is None:
            raise ValueError(f"map: this model takes a spatial map {self.map_shape}: pass map=")
        if not n and map is not None:
            raise ValueError("map: this model takes no spatial map: pass map=None")
        m = None if map is None else _args.float_vector("map", map, n)
        k = self._core.ps_dim
        if k and ps is None:
            raise ValueError(f"ps: this model takes a PS input of {k} floats: pass ps=")
        if not k and ps is not None:
            raise ValueError("ps: this model takes no PS input: pass ps=None")
        p = None if ps is None else _args.float_vector("ps", ps, k)
        return self._core.step(o, m, p)

    def adapt(self) -> bool:
        """Runs the inner update on the buffered steps now; True if it ran."""
        return self._core.adapt()


gymnasium.register(
    id="gman/ObjectNav-v0",
    entry_point="gman:ObjectNavEnv",
    vector_entry_point="gman:VecEnv",
    # The longest default episode (living rooms; 100 elsewhere, ended by the env itself).
    max_episode_steps=200,
)
