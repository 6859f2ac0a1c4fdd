"""A running mapper's objects written as JSON and arrays, and rebuilt exactly: no pickle.

:func:`encode` turns an object graph (the pipeline with its front end, filter, graph, map
and milestones) into a JSON-able tree plus a dict of NumPy arrays; :func:`decode` rebuilds
it. Shared objects stay shared and cycles close (each object is written once, then named by
reference). Only classes of this program's packages and of filterpy may be rebuilt, and only
by filling their attributes (no constructor, no code named by the file runs); anything else
in the graph is an error that names where it was found. Attributes a class names in its
``TRANSIENT`` tuple (a factorisation it can redo from what it keeps) are not written and come
back as None. Objects given in ``keep`` (a view, whose recording cannot be saved) are written
by name and replaced by the caller's on decoding.
"""

from __future__ import annotations

import enum
import importlib
from collections import Counter, OrderedDict, deque
from typing import Any

import numpy as np

__all__ = ["StateError", "decode", "encode"]

REBUILDABLE = ("vmp.", "milestones.", "filterpy.")  # module prefixes
_DICTS: dict[str, type] = {"dict": dict, "Counter": Counter, "OrderedDict": OrderedDict}


class StateError(ValueError):
    """An object that cannot be written, or a state that cannot be rebuilt."""


def _name(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


class _Encoder:
    def __init__(self, keep: dict[str, object]) -> None:
        self.arrays: dict[str, np.ndarray] = {}
        self.refs: dict[int, int] = {}  # id(object) -> reference number
        self.alive: list[object] = []  # the objects referenced, so their ids stay unique
        self.keep = {id(v): k for k, v in keep.items()}

    def _ref(self, o: object) -> tuple[int, bool]:
        """(reference number, whether it was new) of a mutable object."""
        known = self.refs.get(id(o))
        if known is not None:
            return known, False
        self.refs[id(o)] = n = len(self.refs)
        self.alive.append(o)
        return n, True

    def enc(self, o: Any, path: str) -> Any:
        if o is None or type(o) in (bool, int, float, str):
            return o
        if id(o) in self.keep:
            return {"$keep": self.keep[id(o)]}
        if isinstance(o, np.generic):
            return {"$np": o.dtype.str, "v": o.item()}
        if isinstance(o, tuple) and type(o) is tuple:
            return [self.enc(v, f"{path}[{i}]") for i, v in enumerate(o)]
        if isinstance(o, enum.Enum):
            return {"$enum": _name(type(o)), "name": o.name}
        n, new = self._ref(o)
        if not new:
            return {"$ref": n}
        if isinstance(o, np.ndarray):
            if o.dtype.hasobject:
                raise StateError(f"{path}: an array of Python objects cannot be written")
            key = f"a{len(self.arrays)}"
            self.arrays[key] = o
            return {"$nd": key, "ref": n}
        if type(o) is list:
            return {"$list": [self.enc(v, f"{path}[{i}]") for i, v in enumerate(o)], "ref": n}
        if type(o) in (set, frozenset):
            return {"$set": [self.enc(v, f"{path}{{}}") for v in sorted(o, key=repr)],
                    "frozen": type(o) is frozenset, "ref": n}
        if type(o) is deque:
            return {"$deque": [self.enc(v, f"{path}[{i}]") for i, v in enumerate(o)],
                    "maxlen": o.maxlen, "ref": n}
        if type(o) in (dict, Counter, OrderedDict):
            return {"$dict": [[self.enc(k, f"{path}.key"), self.enc(v, f"{path}[{k!r}]")]
                              for k, v in o.items()], "type": type(o).__name__, "ref": n}
        if hasattr(o, "__self__") and hasattr(o, "__func__"):  # a bound method
            return {"$method": self.enc(o.__self__, f"{path}.__self__"),
                    "name": o.__func__.__name__, "ref": n}
        cls = type(o)
        if not cls.__module__.startswith(REBUILDABLE) or not hasattr(o, "__dict__"):
            raise StateError(f"{path}: a {cls.__module__}.{cls.__qualname__} cannot be written")
        transient = getattr(cls, "TRANSIENT", ())
        return {"$obj": _name(cls), "ref": n,
                "state": {k: self.enc(v, f"{path}.{k}") for k, v in vars(o).items()
                          if k not in transient}}


def encode(root: object, keep: dict[str, object] | None = None
           ) -> tuple[Any, dict[str, np.ndarray]]:
    """``(tree, arrays)`` of ``root``'s object graph; ``keep`` names objects written by name."""
    e = _Encoder(keep or {})
    return e.enc(root, "state"), e.arrays


def _class(name: str) -> type:
    module, _, qualname = name.partition(":")
    if not module.startswith(REBUILDABLE):
        raise StateError(f"the state names {module}.{qualname}, which may not be rebuilt")
    try:
        obj: Any = importlib.import_module(module)
        for part in qualname.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as exc:
        raise StateError(f"the state names {module}.{qualname}, which this program "
                         "does not have (written by another version?)") from exc
    if not isinstance(obj, type):
        raise StateError(f"the state names {module}.{qualname}, which is not a class")
    return obj


class _Decoder:
    def __init__(self, arrays: dict[str, np.ndarray], keep: dict[str, object]) -> None:
        self.arrays = arrays
        self.keep = keep
        self.refs: dict[int, object] = {}

    def _made(self, node: dict, o: object) -> object:
        self.refs[node["ref"]] = o
        return o

    def dec(self, node: Any) -> Any:
        if node is None or type(node) in (bool, int, float, str):
            return node
        if type(node) is list:
            return tuple(self.dec(v) for v in node)
        if "$ref" in node:
            return self.refs[node["$ref"]]
        if "$keep" in node:
            return self.keep[node["$keep"]]
        if "$np" in node:
            return np.dtype(node["$np"]).type(node["v"])
        if "$enum" in node:
            return _class(node["$enum"])[node["name"]]
        if "$nd" in node:
            return self._made(node, self.arrays[node["$nd"]])
        if "$list" in node:
            out: list = self._made(node, [])  # type: ignore[assignment]
            out.extend(self.dec(v) for v in node["$list"])
            return out
        if "$set" in node:
            items = {self.dec(v) for v in node["$set"]}
            return self._made(node, frozenset(items) if node["frozen"] else items)
        if "$deque" in node:
            d: deque = self._made(node, deque(maxlen=node["maxlen"]))  # type: ignore[assignment]
            d.extend(self.dec(v) for v in node["$deque"])
            return d
        if "$dict" in node:
            m = self._made(node, _DICTS[node["type"]]())
            for k, v in node["$dict"]:
                m[self.dec(k)] = self.dec(v)  # type: ignore[index]
            return m
        if "$method" in node:
            return self._made(node, getattr(self.dec(node["$method"]), node["name"]))
        if "$obj" in node:
            cls = _class(node["$obj"])
            o = self._made(node, cls.__new__(cls))
            o.__dict__.update(dict.fromkeys(getattr(cls, "TRANSIENT", ())))
            o.__dict__.update({k: self.dec(v) for k, v in node["state"].items()})
            return o
        raise StateError(f"the state holds a node of no known kind: {sorted(node)[:3]}")


def decode(tree: Any, arrays: dict[str, np.ndarray], keep: dict[str, object] | None = None
           ) -> Any:
    """The object graph :func:`encode` wrote; ``keep`` gives the objects written by name."""
    try:
        return _Decoder(arrays, keep or {}).dec(tree)
    except (KeyError, TypeError, AttributeError, IndexError) as exc:
        raise StateError(f"a damaged state ({type(exc).__name__}: {exc})") from exc
