"""Every command in README.md and docs/ runs as written.

The fenced blocks marked runnable (an info string of ```bash runnable, ```sh runnable or ```python
runnable; docs/README.md, "Runnable blocks") are run, document by document, against a live
``evcbench serve`` on the emulated default bench, from a directory laid out as the repository root
(every top-level entry linked, ``var`` the service's data dir), with $EVCBENCH_URL and
$EVCBENCH_TOKEN set as a reader's shell has them after the README's first block. A document's blocks
run in order in one shell (``set -eo pipefail``), so a block may use the variables an earlier one
set, as a reader's terminal would; every block must exit 0.

The blocks not marked runnable (``make run``, a lab's several services, real hardware) are checked
without running them: every ``evcbench`` command parses with the CLI's own parser, every ``make``
target exists and every ``python -m`` module is importable; and every ``METHOD /api/…`` the
documents name is a route of the service.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import resource
import shlex
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

from service.frontends.cli import build_parser
from tests.support.live_server import Server

ROOT = Path(__file__).resolve().parents[2]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
FENCE = re.compile(r"^```([A-Za-z]*)([^\n`]*)\n(.*?)^```[ \t]*$", re.M | re.S)
SHELLS = ("bash", "sh")
#: the info-string word that marks a block runnable
MARKER = "runnable"
#: a document's blocks at most (s): the tutorial's discover and tracking jobs take tens of seconds
DOCUMENT_TIMEOUT_S = 300
DONE = "@@evcbench-doc-block-done@@"


@dataclass(frozen=True)
class Block:
    path: Path
    line: int
    lang: str
    text: str
    runnable: bool

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def fenced_blocks(path: Path) -> list[Block]:
    text = path.read_text(encoding="utf-8")
    return [
        Block(path, text.count("\n", 0, m.start()) + 1, m.group(1), m.group(3), MARKER in m.group(2).split())
        for m in FENCE.finditer(text)
    ]


def all_blocks() -> list[Block]:
    return [block for path in DOCUMENTS for block in fenced_blocks(path)]


def script_of(blocks: list[Block]) -> str:
    """One shell script of a document's runnable blocks, in order; a python block runs as
    ``.venv/bin/python -`` (as the document says to run it)."""
    parts = ["set -eo pipefail"]
    for i, block in enumerate(blocks):
        body = block.text
        if block.lang == "python":
            body = f".venv/bin/python - <<'EVCBENCH_DOC_EOF'\n{body}EVCBENCH_DOC_EOF\n"
        parts += [f"# {block.where}", body, f"printf '\\n%s\\n' \"{DONE} {i} $SECONDS\""]
    return "\n".join(parts) + "\n"


def children_cpu_s() -> float:
    """CPU seconds of this process's ended and reaped children (and theirs)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def repository_view(tmp: Path, data_dir: Path) -> Path:
    """A directory that looks like the repository root to a reader's commands: every top-level entry
    linked, ``var`` the live service's data dir. What the commands write lands here, not in the tree."""
    view = tmp / "repo"
    view.mkdir()
    for entry in ROOT.iterdir():
        if entry.name not in ("var", ".git"):
            (view / entry.name).symlink_to(entry)
    (view / "var").symlink_to(data_dir.resolve())
    return view


def test_runnable_blocks_are_found_and_marked_as_documented():
    blocks = [b for b in all_blocks() if b.runnable]
    assert {b.lang for b in blocks} <= {*SHELLS, "python"}, [b.where for b in blocks if b.lang not in SHELLS]
    documents = {b.path.relative_to(ROOT).as_posix() for b in blocks}
    assert {"README.md", "docs/tutorial.md"} <= documents, documents
    guide = (ROOT / "docs" / "README.md").read_text()
    assert "```bash runnable" in guide and "tests/system/test_docs_commands.py" in guide


# ---------------------------------------------------------------------- commands checked, not run
#: the CLI called as a command: ``evcbench`` or a path to it, then a sub-command (not a database named so)
EVCBENCH = re.compile(r"(?:^|[\s(])(?:\S*/)?evcbench([ \t]+[a-z][^|;&)<>\n]*)")


def shell_lines(block: Block) -> list[str]:
    """The block's logical lines (continuations joined), a heredoc's body left out, and each command
    substitution ``$(…)`` as a line of its own (``x`` in its place)."""
    lines, heredoc = [], None
    for line in block.text.replace("\\\n", " ").splitlines():
        if heredoc is not None:
            heredoc = None if line.strip() == heredoc else heredoc
            continue
        found = re.search(r"<<-?\s*'?\"?(\w+)", line)
        heredoc = found.group(1) if found else None
        while inner := re.search(r"\$\(([^()]*)\)", line):
            lines.append(inner.group(1))
            line = line[: inner.start()] + "x" + line[inner.end() :]
        lines.append(line)
    return lines


def evcbench_commands() -> list[tuple[str, list[str]]]:
    out = []
    for block in all_blocks():
        if block.lang not in SHELLS:
            continue
        for line in shell_lines(block):
            for m in EVCBENCH.finditer(line):
                out.append((block.where, shlex.split(m.group(1), comments=True)))
    return out


def test_every_evcbench_command_in_the_documents_parses():
    commands = evcbench_commands()
    assert len(commands) > 20
    parser = build_parser()
    refused = []
    for where, args in commands:
        try:
            parser.parse_args(args)
        except SystemExit:
            refused.append(f"{where}: evcbench {shlex.join(args)}")
    assert refused == [], "\n".join(refused)


def test_every_make_target_and_python_module_in_the_documents_exists():
    targets = set(re.findall(r"^([a-z][a-z-]*):", (ROOT / "Makefile").read_text(), re.M))
    missing = []
    for block in all_blocks():
        if block.lang not in SHELLS:
            continue
        for line in shell_lines(block):
            missing += [
                f"{block.where}: make {t}" for t in re.findall(r"\bmake ([a-z][a-z-]*)", line) if t not in targets
            ]
            for module in re.findall(r"python -m ([\w.]+)", line):
                if module != "pytest" and importlib.util.find_spec(module) is None:
                    missing.append(f"{block.where}: python -m {module}")
    assert missing == [], "\n".join(missing)


ROUTE = re.compile(r"\b(GET|POST|PUT|PATCH|DELETE) (/api/[A-Za-z0-9_/{}.-]*)")


def documented_routes() -> dict[tuple[str, str], str]:
    """(method, path with every {parameter} as {}) → where it is first named."""
    found: dict[tuple[str, str], str] = {}
    for path in DOCUMENTS:
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for method, route in ROUTE.findall(line):
                key = (method, re.sub(r"\{[^}]*\}", "{}", route.rstrip("/.")))
                if key[1] == "/api":  # "/api/…": any route
                    continue
                found.setdefault(key, f"{path.relative_to(ROOT)}:{number}")
    return found


LINK = re.compile(r"\]\(([^)\s]+)\)")


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation but ``-`` and ``_`` dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = FENCE.sub("", path.read_text(encoding="utf-8"))
    return {slug(m.group(1)) for m in re.finditer(r"^#+ (.+)$", text, re.M)}


def test_every_relative_link_in_the_documents_resolves():
    broken = []
    for path in DOCUMENTS:
        text = FENCE.sub("", path.read_text(encoding="utf-8"))
        for target in LINK.findall(text):
            if re.match(r"[a-z]+:", target):
                continue
            file, _, anchor = target.partition("#")
            resolved = (path.parent / file).resolve() if file else path
            if not resolved.exists():
                broken.append(f"{path.relative_to(ROOT)}: {target} (no such file)")
            elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
                broken.append(f"{path.relative_to(ROOT)}: {target} (no such heading)")
    assert broken == [], "\n".join(broken)


# ---------------------------------------------------------------------- the runnable blocks, run
@pytest.mark.realtime
def test_runnable_blocks_run_against_a_live_service(tmp_path):
    by_document: dict[Path, list[Block]] = {}
    for block in all_blocks():
        if block.runnable:
            by_document.setdefault(block.path, []).append(block)
    started, cpu_before = time.monotonic(), children_cpu_s()
    server = Server(tmp_path / "data", tmp_path / "service.log", bench="default")
    failures, ran = [], []
    try:
        view = repository_view(tmp_path, server.data_dir)
        env = {k: v for k, v in os.environ.items() if not k.startswith("EVCBENCH_")}
        env.update(EVCBENCH_URL=server.url, EVCBENCH_TOKEN=server.token, OPENBLAS_NUM_THREADS="1")
        for path, blocks in by_document.items():
            clock, cpu = time.monotonic(), children_cpu_s()
            try:
                done = subprocess.run(
                    ["bash", "-c", script_of(blocks)],
                    cwd=view,
                    env=env,
                    capture_output=True,
                    text=True,
                    timeout=DOCUMENT_TIMEOUT_S,
                )
                code, stdout, stderr = done.returncode, done.stdout, done.stderr
            except subprocess.TimeoutExpired as exc:
                code, stdout, stderr = "timeout", str(exc.stdout or ""), str(exc.stderr or "")
            marks = [int(s) for s in re.findall(rf"^{DONE} \d+ (\d+)$", stdout, re.M)]
            finished = len(marks)
            ran.append(
                f"{path.relative_to(ROOT)}: {finished}/{len(blocks)} blocks, {time.monotonic() - clock:.1f} s, "
                f"{children_cpu_s() - cpu:.1f} s of CPU in its commands (blocks ended at {marks} s)"
            )
            if code != 0:
                failures.append(
                    f"{blocks[min(finished, len(blocks) - 1)].where} exited {code}\n"
                    f"--- stdout\n{stdout[-3000:]}\n--- stderr\n{stderr[-3000:]}"
                )
        openapi = httpx.get(f"{server.url}/openapi.json", timeout=30).json()
    finally:
        stopped = server.stop()
    cpu = children_cpu_s() - cpu_before
    head = f"{len(ran)} documents in {time.monotonic() - started:.1f} s, {cpu:.1f} s of CPU with the service's"
    print(f"\n{head}:\n  " + "\n  ".join(ran))
    assert failures == [], "\n\n".join(failures)
    assert stopped, (tmp_path / "service.log").read_text()[-3000:]

    served = {
        (method.upper(), re.sub(r"\{[^}]*\}", "{}", route))
        for route, methods in openapi["paths"].items()
        for method in methods
    }
    unknown = {key: where for key, where in documented_routes().items() if key not in served}
    assert unknown == {}, json.dumps({f"{m} {p}": w for (m, p), w in unknown.items()}, indent=1)
