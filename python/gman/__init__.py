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

from . import _gman

__all__ = [
    "ACTIONS",
    "ATTR_DIM",
    "FEATURE_DIM",
    "NUM_ACTIONS",
    "Navigator",
    "ObjectNavEnv",
    "VecEnv",
    "evaluate",
    "make_vec_env",
]

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


def _limits(max_steps: MaxSteps) -> Tuple[int, int]:
    """(living room, other rooms) step limits; None: the reference 200 / 100."""
    if max_steps is None:
        return 200, 100
    if isinstance(max_steps, (bool, np.bool_)):
        raise TypeError("max_steps must be an int or a (living_room, other) pair, got a bool")
    if isinstance(max_steps, (int, np.integer)):
        m = int(max_steps)
        pair = (m, m)
    else:
        try:
            a, b = max_steps  # type: ignore[misc]
        except (TypeError, ValueError):
            raise TypeError(
                f"max_steps must be an int or a (living_room, other) pair, got {max_steps!r}"
            ) from None
        pair = (int(a), int(b))
    if min(pair) < 1:
        raise ValueError(f"max_steps must be at least 1, got {max_steps!r}")
    return pair


def _map_grid(map: Optional[Tuple[int, int]]) -> Tuple[int, int]:
    if map is None:
        return 0, 0
    try:
        r, c = map
        r, c = int(r), int(c)
    except (TypeError, ValueError):
        raise TypeError(f"map must be None or a (rows, cols) pair, got {map!r}") from None
    if r < 1 or c < 1:
        raise ValueError(f"map must have at least one row and one column, got {map!r}")
    return r, c


def _data_arg(data: Union[None, str, "os.PathLike[str]"]) -> Optional[str]:
    return None if data is None else os.fspath(data)


def _seed_arg(seed: Optional[int]) -> Optional[int]:
    if seed is None:
        return None
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, (bool, np.bool_)):
        raise TypeError(f"seed must be an int or None, got {seed!r}")
    if seed < 0:
        raise ValueError(f"seed must be non-negative, got {seed}")
    return int(seed)


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

    ``split="train"`` samples training tasks (slot i's sampler is seeded with ``seed + i``);
    ``split="val"`` / ``"test"`` hands out the official episodes in file order (slot by slot,
    wrapping around after the last).
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int = 1,
        *,
        data: Union[None, str, "os.PathLike[str]"] = None,
        split: str = "train",
        seed: Optional[int] = None,
        world_seed: int = 2022,
        map: Optional[Tuple[int, int]] = None,
        max_steps: MaxSteps = None,
        reward: str = "mixed",
        episodes: Optional[int] = None,
        oracle: bool = False,
        copy: bool = False,
    ) -> None:
        if not isinstance(num_envs, (int, np.integer)) or isinstance(num_envs, bool):
            raise TypeError(f"num_envs must be an int, got {num_envs!r}")
        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        living, other = _limits(max_steps)
        rows, cols = _map_grid(map)
        self._core = _gman.VecCore(
            _data_arg(data),
            int(world_seed),
            str(split),
            int(num_envs),
            str(reward),
            living,
            other,
            rows,
            cols,
            bool(oracle),
            episodes,
        )
        self._seed = _seed_arg(seed)
        self._copy = bool(copy)
        self._oracle = bool(oracle)
        self._has_map = rows > 0
        self.num_envs = int(num_envs)
        self.single_observation_space = _observation_space(rows, cols)
        self.single_action_space = spaces.Discrete(NUM_ACTIONS)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.split = str(split)
        self.render_mode = None
        a = self._core.arrays()
        self._arrays = a
        self._obs = {"features": a["features"], "target": a["target"], "ps_target": a["ps_target"]}
        if self._has_map:
            self._obs["map"] = a["map"]
        self._info_keys = _INFO_KEYS + (("oracle_action",) if self._oracle else ())
        self._started = False

    # -- gymnasium API -------------------------------------------------------------------

    def reset(
        self, *, seed: Optional[int] = None, options: Optional[Dict[str, Any]] = None
    ) -> Tuple[Dict[str, np.ndarray], Dict[str, np.ndarray]]:
        """Starts a new episode in every environment (the official list from its start)."""
        seed = _seed_arg(seed)
        if seed is None and not self._started:
            seed = self._seed
        self._core.reset(seed, True)
        self._started = True
        return self._observation(), self._info()

    def step(
        self, actions: Any
    ) -> Tuple[Dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray, Dict[str, np.ndarray]]:
        """Steps every environment with ``actions`` (integers in 0..6, one per environment)."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        self._core.step(_actions(actions, self.num_envs))
        a = self._arrays
        rew, term, trunc = a["reward"], a["terminated"], a["truncated"]
        if self._copy:
            rew, term, trunc = rew.copy(), term.copy(), trunc.copy()
        return self._observation(), rew, term, trunc, self._info()

    def close_extras(self, **kwargs: Any) -> None:
        self._core = None  # type: ignore[assignment]

    # -- extras --------------------------------------------------------------------------

    def scene_names(self) -> Sequence[str]:
        """Scene names by the ids of ``info["scene"]``."""
        return self._core.scene_names()

    def category_names(self) -> Sequence[str]:
        """Category names by the ids of ``info["target_category"]``."""
        return self._core.category_names()

    @property
    def num_episodes(self) -> int:
        """Official episodes of the split (0 for train)."""
        return self._core.num_episodes

    @property
    def completed_episodes(self) -> int:
        """Official episodes finished at least once since the last reset."""
        return self._core.completed

    def report(self, agent: str = "python") -> Dict[str, Any]:
        """``gman eval --json``'s report of the official episodes once all have finished."""
        r, _ = self._core.report(agent)
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
        raise TypeError(f"actions must be integers (0..{NUM_ACTIONS - 1}), got dtype {a.dtype}")
    if a.shape != (n,):
        raise ValueError(f"actions must have shape ({n},), got {a.shape}")
    return np.ascontiguousarray(a, dtype=np.int64)


class ObjectNavEnv(gymnasium.Env):
    """One GMAN episode at a time (``gman/ObjectNav-v0``): a :class:`VecEnv` of one.

    The same observations, rewards and info as :class:`VecEnv` (without the batch axis).
    ``reset(seed=s)`` seeds the training sampler with ``s`` (slot 0 of a VecEnv seeded with
    ``s``); on an evaluation split each ``reset()`` takes the next official episode.
    """

    metadata = {"render_modes": []}

    def __init__(self, **kwargs: Any) -> None:
        kwargs.pop("num_envs", None)
        kwargs["copy"] = True
        self._vec = VecEnv(1, **kwargs)
        self.observation_space = self._vec.single_observation_space
        self.action_space = self._vec.single_action_space
        self._done = True
        self._fresh = True

    def reset(
        self, *, seed: Optional[int] = None, options: Optional[Dict[str, Any]] = None
    ) -> Tuple[Dict[str, np.ndarray], Dict[str, Any]]:
        super().reset(seed=seed)
        seed = _seed_arg(seed)
        if seed is None and self._fresh:
            seed = self._vec._seed
        self._vec._core.reset(seed, self._fresh or seed is not None)
        self._vec._started = True
        self._fresh = False
        self._done = False
        return _unbatch(self._vec._observation()), _unbatch(self._vec._info())

    def step(self, action: Any):
        if self._done:
            raise RuntimeError("the episode is over: call reset()")
        a = np.asarray(action)
        if a.dtype.kind not in "iu" or a.shape != ():
            raise TypeError(f"action must be one integer in 0..{NUM_ACTIONS - 1}, got {action!r}")
        obs, rew, term, trunc, info = self._vec.step(a.reshape(1))
        self._done = bool(term[0] or trunc[0])
        return _unbatch(obs), float(rew[0]), bool(term[0]), bool(trunc[0]), _unbatch(info)


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
    episodes: Optional[int] = None,
    oracle: bool = False,
    copy: bool = False,
) -> VecEnv:
    """A :class:`VecEnv` of ``num_envs`` environments.

    Args:
        data: GMAN data directory (``attributes.json``, ``scenes/``, ``episodes/``); None for
            the built-in synthetic world.
        split: ``"train"`` (sampled tasks), ``"val"`` or ``"test"`` (official episodes in order).
        num_envs: batch size B.
        seed: seed of the training sampler used by the first ``reset()`` (slot i: seed + i).
        map: ``(rows, cols)`` adds the spatial map observation ``obs["map"]``.
        max_steps: step limit, one int or ``(living_room, other)``; default 200 / 100.
        reward: ``"mixed"`` (the paper's), ``"navigation"``, ``"distance"`` or ``"similarity"``.
        world_seed: world seed (``gman --world-seed``).
        episodes: at most this many episodes per episode file (``gman eval --episodes``).
        oracle: add ``info["oracle_action"]`` (a shortest-path action, for scripted agents).
        copy: return copies instead of the arrays refilled in place.
    """
    return VecEnv(
        num_envs,
        data=data,
        split=split,
        seed=seed,
        world_seed=world_seed,
        map=map,
        max_steps=max_steps,
        reward=reward,
        episodes=episodes,
        oracle=oracle,
        copy=copy,
    )


def evaluate(
    policy: Union[str, "os.PathLike[str]", bytes, Policy],
    data: Union[None, str, "os.PathLike[str]"] = None,
    split: str = "val",
    *,
    num_envs: int = 16,
    episodes: Optional[int] = None,
    map: Optional[Tuple[int, int]] = None,
    max_steps: MaxSteps = None,
    reward: str = "mixed",
    world_seed: int = 2022,
    seed: int = 0,
    agent_name: Optional[str] = None,
    return_episodes: bool = False,
) -> Any:
    """The paper's metrics on the official episodes of ``split``, as ``gman eval --json``.

    ``policy`` is one of:

    * ``"random"`` or ``"oracle"``: the built-in agents (``seed`` seeds the random one);
    * a path to a model file (training checkpoint or ``*.gman`` blob), or a blob's ``bytes``:
      evaluated by ``gman eval``'s evaluator (gman-core's navigator, the device's bits);
    * a callable ``policy(obs, info) -> actions`` over batches of a :class:`VecEnv` of
      ``num_envs`` environments: ``info["episode_start"]`` marks each new episode,
      ``info["ended"]`` the environments whose episode ended at the last step (they reset at
      this step and their action is ignored), ``info["oracle_action"]`` is a shortest-path
      action.

    Returns the report dict (``results.seen`` / ``results.unseen`` with ``sr``, ``spl``,
    ``epa`` in percent and ``dts`` in metres, ``by_room``, ``episodes``), the same numbers
    ``gman eval`` writes; with ``return_episodes=True`` also the list of per-episode results.
    """
    living, other = _limits(max_steps)
    if isinstance(policy, (bytes, bytearray, memoryview)):
        r, e = _gman.host_evaluate(
            _data_arg(data), int(world_seed), str(split), agent_name or "blob", bytes(policy),
            int(seed), episodes, str(reward), living, other,
        )
    elif isinstance(policy, (str, os.PathLike)):
        name = os.fspath(policy)
        r, e = _gman.host_evaluate(
            _data_arg(data), int(world_seed), str(split), name, None, int(seed), episodes,
            str(reward), living, other,
        )
        if agent_name:
            r = json.dumps({**json.loads(r), "agent": agent_name})
    elif callable(policy):
        if split == "train":
            raise ValueError("split train has no official episodes; use split=\"val\" or \"test\"")
        env = VecEnv(
            num_envs, data=data, split=split, world_seed=world_seed, map=map,
            max_steps=(living, other), reward=reward, episodes=episodes, oracle=True,
        )
        obs, info = env.reset()
        info["ended"] = np.zeros(num_envs, bool)
        core = env._core
        total = core.num_episodes
        while core.completed < total:
            obs, _, term, trunc, info = env.step(policy(obs, info))
            info["ended"] = term | trunc
        r, e = core.report(agent_name or getattr(policy, "__name__", "python"))
        env.close()
    else:
        raise TypeError(
            "policy must be \"random\", \"oracle\", a model path, blob bytes or a callable "
            f"policy(obs, info) -> actions; got {type(policy).__name__}"
        )
    report = json.loads(r)
    return (report, json.loads(e)) if return_episodes else report


def _float_vector(x: Any, name: str, length: Optional[int]) -> np.ndarray:
    a = np.asarray(x)
    if a.dtype.kind != "f":
        raise TypeError(f"{name} must be a float array, got dtype {a.dtype}")
    a = np.ascontiguousarray(a, dtype=np.float32).reshape(-1)
    if length is not None and a.size != length:
        raise ValueError(f"{name} must have {length} floats, got shape {np.shape(x)}")
    return a


class Navigator:
    """gman-core's navigator over a weight blob, as ``gman eval --agent BLOB`` runs it.

    ``reset(attr, seed)`` starts an episode; ``step(obs, map=None, ps=None)`` returns
    ``(action, probs, value, adapted)`` and buffers the step; every ``k`` steps (the blob's
    schedule) the inner update (Algorithm 1, lines 15-20) runs inside ``step``; ``adapt()``
    runs it now. Same bits as the CLI and the firmware.
    """

    def __init__(self, core: "_gman.NavigatorCore") -> None:
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
        with open(path, "rb") as f:
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
    def buffered(self) -> int:
        """Steps buffered for the next inner update."""
        return self._core.buffered

    def reset(self, attr: Any, seed: int) -> None:
        """Starts an episode with target attribute vector ``attr`` (45 floats) and ``seed``."""
        s = _seed_arg(seed)
        if s is None:
            raise TypeError("seed must be an int")
        self._core.reset(_float_vector(attr, "attr", self._core.attr_dim), s)

    def step(
        self, obs: Any, map: Any = None, ps: Any = None
    ) -> Tuple[int, np.ndarray, float, bool]:
        """One control step: ``(action, probs, value, adapted)``."""
        o = _float_vector(obs, "obs", FEATURE_DIM)
        n = self._core.map_len
        m = None if map is None else _float_vector(map, "map", n)
        if n and m is None:
            raise ValueError(f"this model takes a spatial map {self.map_shape}: pass map=")
        p = None if ps is None else _float_vector(ps, "ps", None)
        return self._core.step(o, m, p)

    def adapt(self) -> bool:
        """Runs the inner update on the buffered steps now; True if it ran."""
        return self._core.adapt()


gymnasium.register(
    id="gman/ObjectNav-v0",
    entry_point="gman:ObjectNavEnv",
    vector_entry_point="gman:VecEnv",
)
