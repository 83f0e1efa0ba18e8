"""``evcbench effects check FILE``: the effect contract's conformance checks on a plug-in file
(service.science.effects.conformance), each failure named; exit 1 on any; and ``evcbench effects
list``, the effects this installation has (built-ins and entry-point plug-ins, and ``--effects-dir``)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _cmd_check(args: argparse.Namespace) -> int:
    from service.science.effects import EFFECTS
    from service.science.effects.conformance import _error, check_effect
    from service.science.effects.registry import effects_of, load_file

    path = Path(args.file)
    try:
        found = effects_of(load_file(path.resolve()))
    except Exception as exc:  # the plug-in's own error: reported, never a traceback
        print(f"FAIL {path.stem}: import: {_error(exc)}")
        return 1
    if not found:
        print(f"FAIL {path.stem}: contract: it defines no subclass of service.science.effects.Effect")
        return 1
    failed = 0
    for effect in found:
        name = getattr(effect, "name", "") or type(effect).__name__
        problems = check_effect(effect)
        if name in EFFECTS:
            problems = [*problems, f"name: {name!r} is a built-in effect's name"]
        for p in problems:
            print(f"FAIL {name}: {p}")
        if not problems:
            units = ", ".join(f"{k} [{u}]" for k, u in effect.units.items())
            print(f"ok   {name}: {effect.stage} {effect.kind} effect; parameters {units}; inverse {effect.inverse}")
        failed += bool(problems)
    return 1 if failed else 0


def _cmd_list(args: argparse.Namespace) -> int:
    from service.science.effects import REGISTRY

    catalogue = REGISTRY.load_plugins(args.effects_dir).catalogue()
    if args.json:
        print(json.dumps(catalogue, ensure_ascii=False))
        return 0
    for e in catalogue["effects"]:
        units = ", ".join(f"{p['name']} [{p['unit']}]" for p in e["parameters"])
        print(f"{e['name']:<22} {e['kind']:<9} {e['origin']}: {units}")
    for f in catalogue["failed"]:
        print(f"REFUSED {f['name']} ({f['origin']}): {f['error']}", file=sys.stderr)
    return 0


def add_commands(sub) -> None:
    """``effects check FILE`` and ``effects list``."""
    effects = sub.add_parser("effects", help="the effects library and plug-ins (check, list)")
    verbs = effects.add_subparsers(dest="effects_command", required=True)
    check = verbs.add_parser("check", help="run the effect contract's conformance checks on a plug-in file")
    check.add_argument("file", type=Path, help="a plug-in effect's .py file")
    check.set_defaults(func=_cmd_check)
    listing = verbs.add_parser("list", help="every effect with its origin and parameters")
    listing.add_argument(
        "--effects-dir", type=Path, help="also a directory of plug-ins (default: $EVCBENCH_EFFECTS_DIR)"
    )
    listing.add_argument("--json", action="store_true", help="print one JSON object")
    listing.set_defaults(func=_cmd_list)
