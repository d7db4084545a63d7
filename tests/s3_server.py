"""A real S3-compatible server for tests: moto's server mode (``moto_server``, a werkzeug HTTP
server speaking the S3 REST protocol) as a subprocess on a free loopback port. The stores under test
talk HTTP to it exactly as they would to MinIO or AWS; nothing is patched in the test process.
Its state lives in memory and dies with the process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import boto3
import pytest
from botocore.config import Config

from serve_process import follow

MOTO_SERVER = str(Path(sys.executable).parent / "moto_server")
CREDENTIALS = {"aws_access_key_id": "neuenh-test", "aws_secret_access_key": "neuenh-test-secret"}


class MotoServer:
    def __init__(self):
        # port 0: the server picks a free one and announces it
        self.proc = subprocess.Popen([MOTO_SERVER, "-H", "127.0.0.1", "-p", "0"], stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, start_new_session=True)
        self.lines, self.url = follow(self.proc, r"Running on (http://[\d.]+:\d+)")
        if self.url is None:
            self.stop()
            raise AssertionError("moto_server did not start:\n" + "\n".join(self.lines))

    def client(self):
        return boto3.client("s3", endpoint_url=self.url, region_name="us-east-1",
                            config=Config(s3={"addressing_style": "path"}), **CREDENTIALS)

    def create_bucket(self, name: str) -> str:
        self.client().create_bucket(Bucket=name)
        return name

    def stop(self) -> None:
        """SIGKILL: its state is in memory and nothing needs flushing (and moto_server's own
        signal handler does not end its serving thread on SIGTERM)."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()


@pytest.fixture(scope="session")
def s3_server():
    """One S3 server for the session (import this fixture into a conftest); each test makes its
    own bucket."""
    server = MotoServer()
    yield server
    server.stop()
