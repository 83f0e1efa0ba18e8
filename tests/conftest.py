"""Shared test set-up.

In-process apps (``create_app`` under TestClient) keep the bench in the test's own process
(``EVCBENCH_ENGINE=inline``) so that tests can reach into the emulator (fault injection, output
log). Services started as real processes (tests/support/live_server.py, service_load.spawn_service) run
the product's default, the bench engine in its own process; tests/system/test_engine_process.py drives
that path through the API as well.

Shared here, once per session (per xdist worker):

- ``sweeps``: emulator sweeps (``sweep_records``) that several files ask for with the same
  arguments; each test gets its own copy.
- ``postgres_url``: a private PostgreSQL cluster (tests/support/pg_server.py) for the store tests.

Per test: ``store``, a fresh SQLite store in the test's tmp_path (a file that defines its own
``store``, e.g. tests/unit/service/test_service_store.py's SQLite-and-PostgreSQL one, overrides it).

Markers (pyproject.toml): ``slow``, ``realtime``, ``browser``, ``postgres``; ``make test-fast``
leaves out all four. ``make test`` runs everything on every core (pytest-xdist, ``--dist
loadgroup``): tests that share an expensive module fixture carry an ``xdist_group`` so that one
worker builds it, and ``pytest_collection_modifyitems`` below puts the long tests first so that
the workers finish together.
"""

from __future__ import annotations

import copy
import json
import os

import pytest

os.environ.setdefault("EVCBENCH_ENGINE", "inline")

# numba's cache is shared by the workers and the services their tests start: drivers/jit.py locks
# its index, so two processes compiling one kernel at once keep each one's machine code.

#: Run order under xdist: the marks of a test, heaviest first (a test's weight is its heaviest mark's);
#: ``first`` before all (tests/system/test_warmup.py reads the cache `make test` filled before any test ran)
WEIGHTS = {"first": 4, "slow": 3, "browser": 2, "realtime": 2, "postgres": 1}


def _weight(item: pytest.Item) -> int:
    return max((w for mark, w in WEIGHTS.items() if item.get_closest_marker(mark)), default=0)


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook sends the worker's collection
def pytest_collection_finish(session: pytest.Session) -> None:
    """Under ``--dist loadgroup``, a worker's node ids carry their group (``…@name``), which is how
    the controller keeps a group on one worker. pytest-xdist sets ``item._nodeid`` for that, which
    pytest 9 no longer reads (a node's id is ``item._id``): without this every group was split
    test by test, and its module fixtures built on every worker. Here the suffix goes on ``_id``,
    where xdist's own did not land, before the worker reports its collection."""
    if not os.environ.get("PYTEST_XDIST_WORKER") or not session.config.getvalue("loadgroup"):
        return
    from _pytest.nodeid import coerce_node_id

    for item in session.items:
        names = sorted(
            {str(m.args[0] if m.args else m.kwargs.get("name", "default")) for m in item.iter_markers("xdist_group")}
        )
        if names and "@" not in item.nodeid:
            item._id = coerce_node_id(f"{item.nodeid}@{'_'.join(names)}")


@pytest.hookimpl(tryfirst=True)  # before xdist reads the groups (it appends them to the node ids)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The PostgreSQL tests share one worker (one cluster). Under xdist the slow tests go first,
    then the real-time, browser and PostgreSQL ones, then the rest, so that the workers finish together.
    A group (xdist_group) stays together, at the place of its heaviest test, so that its module
    fixtures are built once.

    Every item's id ends in its own name: schemathesis (4.32) names its items by operation
    (``test_…[GET /api/health]``) but leaves each id the function's, which pytest 9 reads, so the
    fuzz test's 32 operations shared one id, and under xdist only the first one ran (10 requests
    instead of some 2000: tests/artifacts/fuzz_summary.json)."""
    from _pytest.nodeid import coerce_node_id

    for item in items:
        if item.nodeid.rsplit("::", 1)[-1] != item.name and item.parent is not None:
            item._id = coerce_node_id(f"{item.parent.nodeid}::{item.name}")
    for item in items:
        if item.get_closest_marker("postgres"):
            item.add_marker(pytest.mark.xdist_group("postgres"))
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return  # one process: the files' own order
    units: dict[str, list[int]] = {}
    for index, item in enumerate(items):
        group = item.get_closest_marker("xdist_group")
        units.setdefault(f"group:{group.args[0]}" if group else item.nodeid, []).append(index)
    order = sorted(units.values(), key=lambda unit: (-max(_weight(items[i]) for i in unit), unit[0]))
    items[:] = [items[i] for unit in order for i in unit]


@pytest.fixture(scope="session")
def sweeps():
    """``sweeps(bench, seed=0, **plan) -> {axis: Record}``: ``sweep_records`` of
    service.science.discovery.records (a standard characterisation of an emulated bench unless
    ``plan`` says otherwise), run once per session for each set of arguments. Every call returns a
    deep copy, so a test that changes its records changes no other test's."""
    from service.lab.emulated import sweep_records

    done: dict[str, dict] = {}

    def sweep(bench: str, seed: int = 0, **plan) -> dict:
        key = json.dumps([bench, seed, plan], sort_keys=True, default=repr)
        if key not in done:
            done[key] = sweep_records(bench, seed, **plan)
        return copy.deepcopy(done[key])

    return sweep


@pytest.fixture
def store(tmp_path):
    """A fresh SQLite store (metadata and arrays) in the test's own tmp_path, closed afterwards."""
    from service.store import Store

    s = Store(f"sqlite:///{tmp_path}/evcbench.db", tmp_path)
    yield s
    s.close()


@pytest.fixture(scope="session")
def postgres_url():
    """A private PostgreSQL cluster for the session (each xdist worker that asks starts its own, in
    its own temp dir on a free port). If it cannot start, the tests error (loudly), unless
    EVCBENCH_SKIP_POSTGRES=1 asks to skip them."""
    from tests.support.pg_server import postgres_server

    if os.environ.get("EVCBENCH_SKIP_POSTGRES") == "1":
        pytest.skip("EVCBENCH_SKIP_POSTGRES=1: PostgreSQL store tests skipped on request")
    with postgres_server() as url:
        yield url
