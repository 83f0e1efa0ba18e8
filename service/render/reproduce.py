"""The commands that reproduce a model: the requests that record its datasets again (a sweep's
stored plan body, an import's options, a trajectory's request) and the identification and refine
steps of its lineage, as curl, ``evcbench`` and Python-client text.

Ids change when the steps are run again, so the text keeps them in variables: ``DS1``, ``DS2``, …
for the datasets and ``M1``, ``M2``, … for the lineage's models (``M1`` the root).
Pure text: no store, no HTTP.
"""

from __future__ import annotations

import json
import shlex

from service.render.text import one_line_text

#: the stored plan's keys that are not part of the request body: the planner's figures, and the
#: diagnosis an experiment was made for (a model the steps run again make anew)
PLAN_NOT_IN_BODY = ("samples", "duration_s", "experiment_of")
#: sweep body keys with their own ``evcbench sweep`` flag or form (the rest map to --key-with-dashes)
_CLI_SPECIAL = {"axes", "frequencies_hz", "levels_v", "together", "name"}

_SHELL_PRELUDE = """\
# needs curl and jq; EVCBENCH_TOKEN an operate-scope token (see the README's "API tokens")
URL=${EVCBENCH_URL:-http://127.0.0.1:8000}; AUTH="Authorization: Bearer $EVCBENCH_TOKEN"
post() { curl -sf -X POST "$URL/api$1" -H "$AUTH" -H 'content-type: application/json' -d "$2" | jq -r .job_id; }
wait_job() {  # wait_job JOB_ID FIELD: the job's result.FIELD once it succeeded
  while :; do J=$(curl -sf -H "$AUTH" "$URL/api/jobs/$1")
    case $(echo "$J" | jq -r .state) in succeeded) echo "$J" | jq -r ".result.$2"; return;;
      failed|cancelled) echo "$J" >&2; return 1;; esac; sleep 1; done; }"""


def dataset_request(row: dict) -> dict:
    """How a stored dataset was made: ``{"kind": "sweep"|"trajectory"|"import", "body"}`` with the
    request body (sweep: the stored plan without the planner's figures, named as the dataset; a
    chirp's ``duration_s`` is its block's length, which the planner rounded to whole cycles)."""
    plan = row.get("plan") if isinstance(row.get("plan"), dict) else {}
    if row.get("source") == "import" or "import" in plan:
        options = {k: v for k, v in (plan.get("import") or {}).items() if v is not None}
        return {"kind": "import", "body": {**options, "name": row.get("name")}}
    if row.get("source") == "trajectory":
        return {"kind": "trajectory", "body": dict(plan)}
    body = {k: v for k, v in plan.items() if k not in PLAN_NOT_IN_BODY}
    chirp = [b for b in row.get("blocks") or [] if b.get("kind") == "chirp"]
    if body.get("waveform") == "chirp" and chirp:  # the stored duration_s is the whole plan's: the chirp's
        body["duration_s"] = round((chirp[0]["stop"] - chirp[0]["start"]) / row["sample_rate_hz"], 6)
    body["name"] = row.get("name")
    return {"kind": "sweep", "body": body}


def refine_body(step: dict, previous: dict) -> dict:
    """The POST /api/models/{parent}/refine body of one lineage step (``history`` entries):
    ``add``/``remove`` for one effect changed, else ``effects``; ``datasets`` it added to the fit."""
    now, before = step["effects"], previous["effects"]
    added, removed = [e for e in now if e not in before], [e for e in before if e not in now]
    if len(added) + len(removed) == 1:
        body = {"add": added[0]} if added else {"remove": removed[0]}
    else:
        body = {"effects": list(now)}
    extra = [d for d in step["datasets"] if d not in previous["datasets"]]
    if extra:
        body["datasets"] = extra
    return body


def _vars(ids: list[str], prefix: str) -> dict[str, str]:
    return {i: f"{prefix}{n}" for n, i in enumerate(ids, 1)}


def _json(value) -> str:
    """``value`` as JSON for a single-quoted shell word (a quote in it closed, escaped, reopened)."""
    return json.dumps(value, separators=(", ", ": ")).replace("'", "'\\''")


def _with_vars(text: str, names: dict[str, str]) -> str:
    """Ids in a JSON text for a single-quoted shell word replaced by their variables ("$DS1")."""
    for old, new in names.items():
        text = text.replace(f'"{old}"', f'"\'"${new}"\'"')
    return text


def _py(value, names: dict[str, str]) -> str:
    """``value`` as Python source, ids replaced by their variables (ds1, m1)."""
    text = repr(value)
    for old, new in names.items():
        text = text.replace(repr(old), new.lower())
    return text


def _cli_sweep(body: dict) -> str:
    args = ["evcbench", "sweep", "--axes", ",".join(body.get("axes", ["y"]))]
    if body.get("frequencies_hz") and body.get("waveform", "sine") in ("sine", "multisine"):
        args += ["--frequencies", ",".join(f"{f:g}" for f in body["frequencies_hz"])]
    if body.get("levels_v"):
        args += ["--levels", ",".join(f"{v:g}" for v in body["levels_v"])]
    if body.get("together") is False:
        args.append("--separate")
    if body.get("name"):
        args += ["--name", body["name"]]
    for key, value in body.items():
        if key not in _CLI_SPECIAL and value is not None and not isinstance(value, (list, dict)):
            args += [f"--{key.replace('_', '-')}", f"{value:g}" if isinstance(value, float) else str(value)]
    return " ".join(shlex.quote(a) for a in args) + " --wait --json | jq -r .result.dataset_id"


def commands(dataset_rows: list[dict], steps: list[dict], root: dict) -> dict[str, str]:
    """``{"curl", "cli", "python"}``: the text of each way to reproduce the model. ``steps`` is its
    lineage (service.usecases.discover.history), ``root`` the stored row of its first model."""
    ds = _vars([r["id"] for r in dataset_rows], "DS")
    md = _vars([s["model_id"] for s in steps], "M")
    names = {**ds, **md}
    curl, cli = [_SHELL_PRELUDE], ["# needs jq; --url/--token or EVCBENCH_URL/EVCBENCH_TOKEN as for every verb"]
    py = [
        "from service.frontends.client import Client",
        "",
        'api = Client("http://127.0.0.1:8000", token="evc_…")   # an operate-scope token',
    ]
    for row in dataset_rows:
        req, var = dataset_request(row), ds[row["id"]]
        note = one_line_text(f"# {var} = {row['id']} ({row.get('name')}, {req['kind']})")
        for out, line in zip((curl, cli, py), _dataset_lines(req, var)):
            out += [note, line]
    for out, lines in zip((curl, cli, py), _identify_lines(root, steps[0], ds, md, names)):
        out += lines
    for prev, step in zip(steps, steps[1:]):
        for out, lines in zip((curl, cli, py), _refine_lines(prev, step, md, names)):
            out += lines
    last = md[steps[-1]["model_id"]]
    curl.append(f'curl -sf -H "$AUTH" "$URL/api/models/${last}/report?download=true" -o "${last}-report.html"')
    cli.append(f"evcbench models ${last} --report ${last}-report.html")
    py.append(f'open(f"{{{last.lower()}}}-report.html", "w").write(api.model_report({last.lower()}))')
    cli.insert(1, _SHELL_PRELUDE.split("\n", 1)[1])  # the refine lines use the same two helpers
    return {"curl": "\n".join(curl), "cli": "\n".join(cli), "python": "\n".join(py)}


def _dataset_lines(req: dict, var: str) -> tuple[str, str, str]:
    """The (curl, cli, python) line that makes dataset ``var`` again from its ``dataset_request``."""
    body = req["body"]
    if req["kind"] == "import":
        form = " ".join(f"-F {shlex.quote(f'{k}={v}')}" for k, v in body.items() if k != "filename")
        fname = body.get("filename") or "FILE.csv"
        return (
            f'{var}=$(curl -sf -X POST "$URL/api/datasets" -H "$AUTH" -F file=@{shlex.quote(fname)} '
            f"{form} | jq -r .id)   " + one_line_text(f"# the original file: {fname}"),
            f"{var}=$(evcbench import {shlex.quote(fname)} --json"
            + "".join(
                f" --{k.replace('_', '-')} {shlex.quote(str(v))}" for k, v in body.items() if k not in ("filename",)
            )
            + " | jq -r .id)",
            f"{var.lower()} = api.import_dataset({fname!r}, "
            + ", ".join(f"{k}={v!r}" for k, v in body.items() if k != "filename")
            + ')["id"]',
        )
    if req["kind"] == "trajectory":
        return (
            f"{var}=$(wait_job $(post /trajectories '{_json(body)}') dataset_id)",
            f"# {var}: a trajectory run; no evcbench verb runs one: use the curl or Python lines",
            f'{var.lower()} = api.wait(api.http.post("/api/trajectories", json={_py(body, {})}).json()'
            f'["job_id"])["result"]["dataset_id"]',
        )
    return (
        f"{var}=$(wait_job $(post /sweeps '{_json(body)}') dataset_id)",
        f"{var}=$({_cli_sweep(body)})",
        f'{var.lower()} = api.sweep(**{_py(body, {})})["result"]["dataset_id"]',
    )


def _identify_lines(root: dict, first: dict, ds: dict, md: dict, names: dict) -> tuple[list, list, list]:
    """The (curl, cli, python) lines that identify the lineage's first model on its datasets."""
    kind, n_ops = root["kind"], int((root.get("options") or {}).get("n_operators", 10))
    effects = list(root["effects"])  # as requested (a dynamic PI's rate dependence is its kind's, not asked)
    body = {
        "axis": root["axis"],
        "datasets": first["datasets"],
        "model": kind,
        "effects": effects,
        "n_operators": n_ops,
    }
    m1 = md[first["model_id"]]
    note = one_line_text(f"# {m1} = {first['model_id']}: {kind}, {' + '.join(effects)}")
    return (
        [note, f"{m1}=$(wait_job $(post /models '{_with_vars(_json(body), names)}') model_id)"],
        [
            note,
            f"{m1}=$(evcbench identify --axis {root['axis']} --datasets "
            + ",".join(f"${ds[d]}" for d in first["datasets"])
            + f" --model {kind} --effects "
            + ",".join(effects)
            + f" --n-operators {n_ops} --json | jq -r .id)",
        ],
        [
            note,
            f"{m1.lower()} = api.identify({root['axis']!r}, ["
            + ", ".join(ds[d].lower() for d in first["datasets"])
            + f'], model={kind!r}, effects={effects!r}, n_operators={n_ops})["id"]',
        ],
    )


def _refine_lines(prev: dict, step: dict, md: dict, names: dict) -> tuple[list, list, list]:
    """The (curl, cli, python) lines that refine the lineage's model ``prev`` into ``step``."""
    var, parent = md[step["model_id"]], md[prev["model_id"]]
    body = refine_body(step, prev)
    note = one_line_text(f"# {var} = {step['model_id']}: {step['change']}")
    refine = f"{var}=$(wait_job $(post /models/${parent}/refine '{_with_vars(_json(body), names)}') model_id)"
    args = ", ".join(f"{k}={_py(v, names)}" for k, v in body.items())
    return (
        [note, refine],
        [note, refine + "   # refine has no evcbench verb: the curl helpers above"],
        [note, f'{var.lower()} = api.refine({parent.lower()}, {args})["id"]'],
    )
