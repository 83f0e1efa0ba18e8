"""The effects registry: the built-ins, then plug-ins from the entry-point group ``evcbench.effects``
(as python-can finds ``can.interface``) and from a directory of ``.py`` files (``evcbench serve
--effects-dir DIR`` or EVCBENCH_EFFECTS_DIR, several joined by the path separator).

An entry point names an Effect subclass (or an instance, or a module whose Effect subclasses it
registers); a directory's file registers every Effect subclass it defines. A plug-in is registered
only if it passes the conformance checks (service.science.effects.conformance) and its name is free;
one that fails to import or to conform is recorded by name with its error, and loading goes on.
Plug-ins take their place after the registered effects of the same stage (the order a composite
applies them: additive regressors, transforms, the gauge, capacity).
"""

from __future__ import annotations

import importlib.util
import inspect
import os
import sys
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from types import ModuleType

from service.science.effects.base import Effect
from service.science.effects.conformance import _error, check_effect

ENTRY_POINT_GROUP = "evcbench.effects"
ENV_DIR = "EVCBENCH_EFFECTS_DIR"
BUILTIN = "builtin"
STAGE_ORDER = ("drive", "additive", "transform", "output", "capacity")


class Refused(ValueError):
    """A plug-in that does not conform, or whose name is taken."""


@dataclass
class Registry:
    """``effects``: name -> effect in application order; ``origins``: name -> "builtin",
    "entry point NAME (module:attr)" or the file's path; ``failed``: the plug-ins refused, each
    ``{"name", "origin", "error"}``."""

    effects: dict[str, Effect] = field(default_factory=dict)
    origins: dict[str, str] = field(default_factory=dict)
    failed: list[dict] = field(default_factory=list)
    loaded_from: set[str] = field(default_factory=set)

    def register(self, effect: Effect, origin: str) -> None:
        """Add ``effect`` after the effects of its stage; Refused (naming every failed check) if it
        does not conform or its name is taken. Built-ins are checked by their tests, not at import."""
        problems = [] if origin == BUILTIN else check_effect(effect)
        if problems:
            raise Refused("; ".join(map(str, problems)))
        if effect.name in self.effects:
            raise Refused(f"the name {effect.name!r} is taken by {self.origins[effect.name]}")
        rank = STAGE_ORDER.index(effect.stage)
        items = list(self.effects.items())
        at = sum(1 for _, e in items if STAGE_ORDER.index(e.stage) <= rank)
        items.insert(at, (effect.name, effect))
        self.effects.clear()
        self.effects.update(items)
        self.origins[effect.name] = origin

    def _try(self, name: str, origin: str, load) -> None:
        """Register what ``load()`` returns (effects); record the error by ``name`` if anything fails."""
        try:
            found = list(load())
            if not found:
                raise Refused("it defines no subclass of service.science.effects.Effect")
        except Exception as exc:
            self.failed.append({"name": name, "origin": origin, "error": _error(exc)})
            return
        for effect in found:
            try:
                self.register(effect, origin)
            except Exception as exc:
                self.failed.append({"name": getattr(effect, "name", "") or name, "origin": origin, "error": str(exc)})

    def catalogue(self) -> dict:
        """Every effect with its origin, parameters with units and rules, and the refused plug-ins
        (``{"effects": [...], "failed": [...]}``, JSON types; GET /api/effects)."""
        return {
            "effects": [
                {
                    "name": name,
                    "origin": self.origins[name],
                    "kind": e.kind,
                    "stage": e.stage,
                    "signature": e.signature,
                    "rule": e.rule,
                    "sweep": dict(e.sweep),
                    "parameters": [{"name": k, "unit": u} for k, u in e.units.items()],
                    "inverse": e.inverse,
                    "no_inverse": e.no_inverse or None,
                    "emulator_bench": e.emulator_bench,
                    "separated_from": sorted(e.separated_from),
                }
                for name, e in self.effects.items()
            ],
            "failed": [dict(f) for f in self.failed],
        }

    def load_entry_points(self, group: str = ENTRY_POINT_GROUP) -> None:
        """Every plug-in of the entry-point ``group`` (once per group)."""
        if f"group:{group}" in self.loaded_from:
            return
        self.loaded_from.add(f"group:{group}")
        for ep in entry_points(group=group):
            self._try(ep.name, f"entry point {ep.name} ({ep.value})", lambda ep=ep: effects_of(ep.load()))

    def load_directory(self, directory: str | Path) -> None:
        """Every ``*.py`` file of ``directory``, by name (once per directory); a missing directory
        is recorded as a failure."""
        path = Path(directory).expanduser().resolve()
        if str(path) in self.loaded_from:
            return
        self.loaded_from.add(str(path))
        if not path.is_dir():
            self.failed.append({"name": path.name, "origin": str(path), "error": "no such directory"})
            return
        for file in sorted(path.glob("*.py")):
            self._try(file.stem, str(file), lambda file=file: effects_of(load_file(file)))

    def load_plugins(self, effects_dir: str | Path | None = None) -> Registry:
        """Entry points, then the directories ``effects_dir`` names (several joined by the path
        separator; None: EVCBENCH_EFFECTS_DIR's); returns self."""
        self.load_entry_points()
        dirs = str(effects_dir) if effects_dir else os.environ.get(ENV_DIR, "")
        for d in dirs.split(os.pathsep):
            if d:
                self.load_directory(d)
        return self


def load_file(path: Path) -> ModuleType:
    """Import the plug-in file ``path`` as module ``evcbench_effects_<stem>``."""
    name = f"evcbench_effects_{path.stem}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot import {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickling look their module up by name
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    return module


def effects_of(obj) -> list[Effect]:
    """The effects ``obj`` provides: an Effect instance, an Effect subclass (instantiated), or a
    module's Effect subclasses defined in it (anything else: a list with the object, which the
    checks refuse by type)."""
    if isinstance(obj, ModuleType):
        return [
            cls()
            for _, cls in inspect.getmembers(obj, inspect.isclass)
            if issubclass(cls, Effect) and cls is not Effect and cls.__module__ == obj.__name__
        ]
    if inspect.isclass(obj) and issubclass(obj, Effect):
        return [obj()]
    return [obj]
