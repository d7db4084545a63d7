"""A client generated from the live service's ``/openapi.json`` by openapi-python-client, as a user of
the API makes one, downloads a job's model: the zip it hands over unpacks into a bundle that loads.

The generator reads ``application/zip`` as bytes once told to treat it like
``application/octet-stream`` (its ``content_type_overrides``, as the README shows); the document's
part is to declare each download's body as ``type: string, format: binary`` — without that schema
the generated download returns nothing."""

from __future__ import annotations

import importlib
import io
import subprocess
import sys
import zipfile
from pathlib import Path

import torch

from jobspecs import tiny_spec
from live_api import running_server, wait_for
from neuenh.checkpoint import Bundle
from neuenh.models import get_model

TOKEN = "generated-client-token"
BIN = Path(sys.executable).parent
# the generator's own option for media types it does not know: read them as bytes
OVERRIDES = ("content_type_overrides:\n"
             "  application/zip: application/octet-stream\n"
             "  image/png: application/octet-stream\n")


def generate_client(url: str, where: Path, package: str):
    """Generate a client package from the document at ``url`` into ``where`` and import it."""
    config = where / "client.yaml"
    config.write_text(OVERRIDES)
    done = subprocess.run([str(BIN / "openapi-python-client"), "generate", "--url", url, "--config", str(config),
                           "--meta", "none", "--output-path", str(where / package)],
                          capture_output=True, text=True, timeout=120,
                          env={"PATH": f"{BIN}:/usr/bin:/bin"})  # its post-hooks run ruff from this virtualenv
    assert done.returncode == 0, done.stdout + done.stderr
    said = done.stdout + done.stderr
    assert "will be omitted" not in said and "Unsupported" not in said, said  # every response understood
    sys.path.insert(0, str(where))
    try:
        return importlib.import_module(package)
    finally:
        sys.path.remove(str(where))


def unzipped(archive: bytes) -> dict[str, bytes]:
    with zipfile.ZipFile(io.BytesIO(archive)) as z:
        return {name: z.read(name) for name in z.namelist()}


def test_a_client_generated_from_the_live_document_downloads_a_model(tmp_path):
    positions = get_model("ggx").positions  # two candidates: stay, or a module at F
    spec = tiny_spec(max_rounds=1, fixed={p: 0 for p in positions if p != "F"})
    with running_server(tmp_path / "data", api_token=TOKEN) as server:
        with server.client(headers={"Authorization": f"Bearer {TOKEN}"}) as c:
            job_id = c.post("/jobs", json=spec.model_dump(mode="json")).json()["id"]
            job = wait_for(c, job_id)
            winner = c.get(f"/jobs/{job_id}/history").json()["rounds"][-1]["winner_state"]
            served = c.get(f"/jobs/{job_id}/model").content
        assert job["status"] in ("CONVERGED", "STOPPED"), job

        generated = generate_client(server.url + "/openapi.json", tmp_path, "neuenh_api_client")
        download = importlib.import_module("neuenh_api_client.api.jobs.download_model_v1_jobs_job_id_model_get")
        from neuenh_api_client.models import ErrorPublic
        from neuenh_api_client.types import File

        with generated.AuthenticatedClient(base_url=server.url, token=TOKEN) as client:
            answer = download.sync_detailed(job_id, client=client)
            missing = download.sync(job_id="0" * 32, client=client)
    assert answer.status_code == 200 and isinstance(answer.parsed, File), answer
    payload = answer.parsed.payload.read()
    assert unzipped(payload) == unzipped(served)  # the files as the service sends them
    assert isinstance(missing, ErrorPublic) and missing.detail == f"no job {'0' * 32!r}"

    with zipfile.ZipFile(io.BytesIO(payload)) as archive:
        archive.extractall(tmp_path / "model")
    bundle = Bundle.load(tmp_path / "model")
    assert bundle.model.name == spec.model and bundle.model.state == winner
    assert len(bundle.materials) == spec.data[0].materials
    wi = torch.nn.functional.normalize(torch.tensor([[0.3, 0.1, 0.9]]), dim=-1)
    f_r = bundle.model.evaluate(wi, wi * torch.tensor([-1.0, -1.0, 1.0]), bundle.materials.as_params(0))
    assert f_r.shape == (1, 3) and torch.isfinite(f_r).all() and (f_r > 0).all()
