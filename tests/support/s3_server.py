"""A throw-away S3-compatible server for the lab tests: moto's server mode on a free loopback port.

``S3Server`` can be stopped and started again on the same port (``stop()``, ``start()``), to play an
object store that goes away and comes back; moto keeps its buckets and objects in this process
meanwhile, as a real store keeps them on disk. ``env`` is what a service needs to reach it.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager

from tests.support.pg_server import free_port

CREDENTIALS = {
    "AWS_ACCESS_KEY_ID": "evcbench-test",
    "AWS_SECRET_ACCESS_KEY": "evcbench-test-secret",
    "AWS_DEFAULT_REGION": "us-east-1",
}


class S3Server:
    """moto's threaded server on 127.0.0.1:``port``; ``endpoint_url``, ``env``, ``client()``."""

    def __init__(self, port: int | None = None):
        self.port = port or free_port()
        self.endpoint_url = f"http://127.0.0.1:{self.port}"
        self.env = {"EVCBENCH_S3_ENDPOINT_URL": self.endpoint_url, **CREDENTIALS}
        self._server = None

    def start(self) -> None:
        from moto.server import ThreadedMotoServer

        logging.getLogger("werkzeug").setLevel(logging.WARNING)  # one log line per request otherwise
        self._server = ThreadedMotoServer(ip_address="127.0.0.1", port=self.port, verbose=False)
        self._server.start()

    def stop(self) -> None:
        if self._server is not None:
            self._server.stop()
            self._server = None

    def client(self):
        """A boto3 S3 client of this server (for set-up and for tampering with objects)."""
        import boto3

        return boto3.session.Session().client(
            "s3",
            endpoint_url=self.endpoint_url,
            aws_access_key_id=CREDENTIALS["AWS_ACCESS_KEY_ID"],
            aws_secret_access_key=CREDENTIALS["AWS_SECRET_ACCESS_KEY"],
            region_name=CREDENTIALS["AWS_DEFAULT_REGION"],
        )

    def make_bucket(self, name: str) -> str:
        self.client().create_bucket(Bucket=name)
        return name


@contextmanager
def s3_server() -> Iterator[S3Server]:
    """A running server; stopped afterwards."""
    server = S3Server()
    server.start()
    try:
        yield server
    finally:
        server.stop()
