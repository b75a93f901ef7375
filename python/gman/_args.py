"""The one check of every public argument of the package.

Every public function and class of :mod:`gman` converts its arguments here, before anything
reaches Rust: a wrong type raises :class:`TypeError`, a value out of range :class:`ValueError`,
and the message names the parameter, the value and the rule. Integer bounds come from the
Rust type the value lands in (``u64`` seeds, ``u32``/``i32`` step limits, ``usize`` counts) and
from the limits the native module exports (:data:`PARAMS` lists them all; ``docs/python.md``
shows the same table). The map grid's rule is the native module's own (``_gman.check_map``),
not a copy.
"""

from __future__ import annotations

import math
import operator
import os
import reprlib
from typing import Any, Dict, Optional, Tuple

import numpy as np

from . import _gman

U64_MAX = 2**64 - 1
MAX_SEED: int = _gman.MAX_SEED
MAX_ENVS: int = _gman.MAX_ENVS
MAX_STEPS: int = _gman.MAX_STEPS
MAX_MAP_SIDE: int = _gman.MAX_MAP_SIDE
MAX_EPISODES: int = _gman.MAX_EPISODES
MAX_BATCH_FLOATS: int = _gman.MAX_BATCH_FLOATS

SPLITS = ("train", "val", "test")
REWARDS = ("mixed", "navigation", "distance", "similarity")
RENDER_MODES = (None, "rgb_array")

# Every public parameter: (type, range). `docs/python.md` has this table; a test keeps the two
# in step.
PARAMS: Dict[str, Tuple[str, str]] = {
    "data": ("None, str or os.PathLike", "an existing data directory; None: the synthetic world"),
    "split": ("str", '"train", "val" or "test" (evaluate: "val" or "test")'),
    "num_envs": ("int", f"1..={MAX_ENVS}, and num_envs x floats per environment <= 2**28"),
    "seed": ("None or int", f"0..={MAX_SEED} (u64)"),
    "world_seed": ("int", f"0..={MAX_SEED} (u64)"),
    "map": ("None or (int, int)", f"rows, cols in 1..={MAX_MAP_SIDE}; <= 7 on offline data"),
    "max_steps": ("None, int or (int, int)", f"1..={MAX_STEPS} (info['steps'] is int32)"),
    "max_episode_steps": ("None or int", f"1..={MAX_STEPS}: caps both step limits (gymnasium's TimeLimit)"),
    "reward": ("str", '"mixed", "navigation", "distance" or "similarity"'),
    "episodes": ("None or int", f"1..={MAX_EPISODES} per episode file (usize)"),
    "oracle": ("bool", "True or False"),
    "copy": ("bool", "True or False"),
    "render_mode": ("None or str", 'None or "rgb_array"'),
    "policy": ("str, os.PathLike, bytes or callable", '"random", "oracle", a model file, blob bytes, policy(obs, info)'),
    "agent_name": ("None or str", "any name"),
    "return_episodes": ("bool", "True or False"),
    "actions": ("integer array", "shape (num_envs,), each in 0..=5"),
    "action": ("integer scalar", "0..=5"),
    "options": ("None or dict", "None or {} (no reset options)"),
    "blob": ("bytes, bytearray or memoryview", "a valid *.gman blob"),
    "path": ("str or os.PathLike", "an existing *.gman file"),
    "attr": ("float array", "45 finite values"),
    "obs": ("float array", "512 finite values"),
    "ps": ("None or float array", "the model's PS width (0: pass None)"),
    "agent": ("str", "a name for the report"),
}


def _show(value: Any) -> str:
    return reprlib.Repr().repr(value) if not isinstance(value, str) else repr(value[:60])


def integer(name: str, value: Any, lo: int, hi: int, why: str = "") -> int:
    """``value`` as an int in ``lo..=hi``; ``4.0`` is 4, ``3.5``, NaN and bools are refused."""
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be an integer, got the bool {value!r}")
    if isinstance(value, (float, np.floating)):
        f = float(value)
        if not (math.isfinite(f) and f.is_integer()):
            raise ValueError(f"{name} must be an integer, got {_show(value)} (not a whole number)")
        v = int(f)
    else:
        try:
            v = operator.index(value)
        except (TypeError, ValueError):
            raise TypeError(
                f"{name} must be an integer, got {type(value).__name__} {_show(value)}"
            ) from None
    if not lo <= v <= hi:
        rule = f" ({why})" if why else ""
        raise ValueError(f"{name} = {v} is out of range: it must be in {lo}..={hi}{rule}")
    return v


def seed(name: str, value: Any) -> Optional[int]:
    """None or a u64 seed."""
    if value is None:
        return None
    return integer(name, value, 0, MAX_SEED, "a u64 seed")


def boolean(name: str, value: Any) -> bool:
    """A bool (``np.bool_`` too); anything else is refused, not truth-tested."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise TypeError(f"{name} must be True or False, got {type(value).__name__} {_show(value)}")


def choice(name: str, value: Any, options: Tuple[Any, ...]) -> Any:
    """One of ``options`` (strings compared exactly)."""
    if value is not None and not isinstance(value, str):
        raise TypeError(f"{name} must be a str, got {type(value).__name__} {_show(value)}")
    if value not in options:
        shown = ", ".join(repr(o) for o in options)
        raise ValueError(f"{name} must be one of {shown}, got {_show(value)}")
    return value


def text(name: str, value: Any, optional: bool = False) -> Optional[str]:
    """A str (or None when ``optional``)."""
    if value is None and optional:
        return None
    if not isinstance(value, str):
        raise TypeError(f"{name} must be a str, got {type(value).__name__} {_show(value)}")
    return value


def path(name: str, value: Any, optional: bool = False) -> Optional[str]:
    """A str or ``os.PathLike`` path (None when ``optional``); bytes paths are refused."""
    if value is None and optional:
        return None
    if isinstance(value, (str, os.PathLike)):
        p = os.fspath(value)
        if isinstance(p, str) and p and "\0" not in p:
            return p
        raise ValueError(f"{name} must be a non-empty path without NUL characters, got {_show(value)}")
    kind = "None, " if optional else ""
    raise TypeError(f"{name} must be {kind}a str or os.PathLike path, got {type(value).__name__} {_show(value)}")


def map_grid(value: Any) -> Tuple[int, int]:
    """None (no map: ``(0, 0)``) or ``(rows, cols)`` by the native map grid rule."""
    if value is None:
        return 0, 0
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
        raise TypeError(f"map must be None or a (rows, cols) pair, got {_show(value)}")
    r = integer("map", value[0], 0, U64_MAX, "a usize")
    c = integer("map", value[1], 0, U64_MAX, "a usize")
    _gman.check_map(r, c)
    if (r, c) == (0, 0):
        raise ValueError("map = (0, 0): pass map=None for no map")
    return r, c


def max_steps(value: Any) -> Tuple[int, int]:
    """(living room, other rooms) step limits; None: the reference 200 / 100."""
    if value is None:
        return 200, 100
    why = "at most i32::MAX: info['steps'] is int32"
    if isinstance(value, (tuple, list)):
        if len(value) != 2:
            raise TypeError(f"max_steps must be an int or a (living_room, other) pair, got {_show(value)}")
        return (
            integer("max_steps", value[0], 1, MAX_STEPS, why),
            integer("max_steps", value[1], 1, MAX_STEPS, why),
        )
    try:
        m = integer("max_steps", value, 1, MAX_STEPS, why)
    except TypeError:
        raise TypeError(
            f"max_steps must be an int or a (living_room, other) pair, got {type(value).__name__} {_show(value)}"
        ) from None
    return m, m


def episodes(value: Any) -> Optional[int]:
    """None (all) or at most this many episodes per episode file."""
    if value is None:
        return None
    return integer("episodes", value, 1, MAX_EPISODES, "episodes per episode file")


def num_envs(value: Any) -> int:
    """A batch size in ``1..=MAX_ENVS`` (the native module also bounds the batch's floats)."""
    return integer("num_envs", value, 1, MAX_ENVS, "environments per batch")


def float_vector(name: str, value: Any, length: Optional[int]) -> np.ndarray:
    """A contiguous float32 copy of a float array of ``length`` values (any shape)."""
    try:
        a = np.asarray(value)
    except Exception as e:  # e.g. ragged nested lists
        raise TypeError(f"{name} must be a float array, got {_show(value)} ({e})") from None
    if a.dtype.kind != "f":
        raise TypeError(f"{name} must be a float array, got dtype {a.dtype}")
    if length is not None and a.size != length:
        raise ValueError(f"{name} must have {length} floats, got shape {a.shape}")
    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(a, dtype=np.float32).reshape(-1)
    bad = np.flatnonzero(~np.isfinite(out))
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"{name} must be finite float32 values, got {a.reshape(-1)[i]!r} at index {i}"
        )
    return out


def reset_options(value: Any) -> None:
    """gymnasium's ``options`` of ``reset``: this environment takes none."""
    if value is None or (isinstance(value, dict) and not value):
        return
    raise ValueError(f"options: this environment takes no reset options, got {_show(value)}")
