"""A load client in its own process, for the safety-under-load benchmark (safety_load.py).

    python -m service.perf.load_client download URL DATASET_ID
    python -m service.perf.load_client upload URL CSV_PATH

It repeats its request until SIGTERM, writes ``flowing`` on stdout once bytes move (so the
benchmark presses its stops under load), and on SIGTERM ends with one JSON line of its counts.
The token comes from $EVCBENCH_TOKEN. A plain subprocess, not a multiprocessing child: nothing is
shared with the benchmark but two pipes (a spawned child rebuilding a shared semaphore failed with
FileNotFoundError on a loaded CI machine, and its counts never came).
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading

import httpx


def _announce_flowing(flag: threading.Event) -> None:
    if not flag.is_set():
        flag.set()
        print("flowing", flush=True)


def download(c: httpx.Client, dataset_id: str, stop: threading.Event, flowing: threading.Event) -> dict:
    """Full-resolution CSV downloads of ``dataset_id`` until ``stop``: counts and bytes."""
    done, received = 0, 0
    while not stop.is_set():
        with c.stream("GET", f"/api/datasets/{dataset_id}/data", params={"format": "csv"}) as r:
            for chunk in r.iter_bytes():
                received += len(chunk)
                _announce_flowing(flowing)
                if stop.is_set():
                    break
        done += 1
    return {"downloads": done, "download_bytes": received}


def upload(c: httpx.Client, csv_path: str, stop: threading.Event, flowing: threading.Event) -> dict:
    """Imports of the CSV at ``csv_path`` until ``stop``: counts and the HTTP statuses seen."""
    done, statuses = 0, set()
    _announce_flowing(flowing)
    while not stop.is_set():
        with open(csv_path, "rb") as f:
            statuses.add(c.post("/api/datasets", files={"file": ("load.csv", f, "text/csv")}).status_code)
        done += 1
    return {"imports": done, "import_status": sorted(statuses)}


def main(argv: list[str]) -> int:
    role, url, target = argv
    stop, flowing = threading.Event(), threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    headers = {"Authorization": f"Bearer {os.environ['EVCBENCH_TOKEN']}"}
    with httpx.Client(base_url=url, headers=headers, timeout=600) as c:
        counts = (download if role == "download" else upload)(c, target, stop, flowing)
    print(json.dumps(counts), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
