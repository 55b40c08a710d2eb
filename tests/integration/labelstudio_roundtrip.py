"""A real round trip through Label Studio: template -> project -> annotation -> export -> import -> fit.

Not part of the default test run (it starts a Label Studio server, which takes minutes). One command, from the
repository root:

    PYTHONPATH=$PWD python tests/integration/labelstudio_roundtrip.py [--label-studio /work/ls-venv/bin/label-studio]

Label Studio runs from its own virtual environment (``python3 -m venv /work/ls-venv && /work/ls-venv/bin/pip
install label-studio``) on 127.0.0.1 with its own sqlite database in a temporary folder. The script

1. starts it with a fresh user and API token, creates a project whose labelling config is
   ``toosicubix template label-studio``, and imports one task per image of the sample;
2. posts, per task, an annotation of the sample's clicks as Label Studio's editor stores them: one
   ``rectanglelabels`` box per vehicle and its keypoints nested under it (``parentID``), in percent;
3. exports the project as JSON through the API, runs ``toosicubix import label-studio`` on the export,
   ``toosicubix fit`` on the result and on the sample, and checks that the cuboids agree (rotation, position
   and size within 1e-6) and that the imported parts equal the sample's.

Exit code 0 when the round trip holds, 1 when it does not, 2 when Label Studio cannot be started.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tests.formats.tool_fixtures import (  # noqa: E402
    cameras_doc,
    label_studio_results,
    same_clicks,
    sample_doc,
)
from toosicubix.formats.templates import label_studio_config  # noqa: E402
from toosicubix.parts.keypoints import keypoints_from_parts  # noqa: E402

#: Agreement required between the fit of the imported file and the fit of the sample: the clicks pass through
#: percent of the image size (float64), so they come back within 1e-12 px; the parts are reordered, which moves
#: the optimum by floating-point rounding only.
TOLERANCE = 1e-6


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Api:
    def __init__(self, base: str, token: str):
        self.base, self.token = base, token

    def call(self, method: str, path: str, body: Any = None) -> Any:
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(self.base + path, data=data, method=method,
                                         headers={"Authorization": f"Token {self.token}",
                                                  "Content-Type": "application/json"})
        with urllib.request.urlopen(request, timeout=120) as response:
            text = response.read().decode()
        return json.loads(text) if text else None


def start_label_studio(binary: str, data_dir: Path, port: int, token: str, log) -> subprocess.Popen:
    env = {**os.environ, "LATEST_VERSION_CHECK": "false", "LABEL_STUDIO_BASE_DATA_DIR": str(data_dir),
           "LABEL_STUDIO_DISABLE_SIGNUP_WITHOUT_LINK": "true"}
    cmd = [binary, "start", "--no-browser", "--internal-host", "127.0.0.1", "-p", str(port),
           "--data-dir", str(data_dir), "--username", "roundtrip@example.com", "--password", secrets.token_hex(8),
           "--user-token", token, "--enable-legacy-api-token", "--log-level", "WARNING"]
    return subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


def wait_ready(api: Api, process: subprocess.Popen, timeout_s: float) -> None:
    start = time.monotonic()
    while time.monotonic() - start < timeout_s:
        if process.poll() is not None:
            raise RuntimeError(f"Label Studio exited with code {process.returncode}")
        try:
            api.call("GET", "/api/projects")
            return
        except (urllib.error.URLError, ConnectionError, TimeoutError):
            time.sleep(3)
    raise RuntimeError(f"Label Studio did not answer within {timeout_s:.0f} s")


def cli(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-m", "toosicubix", *args], env=env, capture_output=True, text=True)


def max_difference(a: dict, b: dict) -> float:
    worst = 0.0
    for image_a, image_b in zip(a["images"], b["images"], strict=True):
        assert image_a["id"] == image_b["id"], (image_a["id"], image_b["id"])
        for va, vb in zip(image_a["vehicles"], image_b["vehicles"], strict=True):
            assert va["status"] == vb["status"] == "ok", (va["status"], vb["status"])
            for key in ("R_cam_vehicle", "t_cam_vehicle", "dimensions"):
                worst = max(worst, float(np.abs(np.array(va[key]) - np.array(vb[key])).max()))
    return worst


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--label-studio", default=shutil.which("label-studio") or "/work/ls-venv/bin/label-studio")
    parser.add_argument("--timeout", type=float, default=900.0, help="Seconds to wait for Label Studio to start.")
    parser.add_argument("--keep", action="store_true", help="Keep the temporary folder.")
    args = parser.parse_args()

    work = Path(tempfile.mkdtemp(prefix="toosicubix-ls-"))
    port, token = _free_port(), secrets.token_hex(20)
    api = Api(f"http://127.0.0.1:{port}", token)
    log = (work / "label-studio.log").open("w")
    print(f"Label Studio: {args.label_studio}, port {port}, data in {work}")
    process = start_label_studio(args.label_studio, work / "ls-data", port, token, log)
    try:
        t0 = time.monotonic()
        try:
            wait_ready(api, process, args.timeout)
        except RuntimeError as exc:
            print(f"cannot start Label Studio: {exc}; its log: {work / 'label-studio.log'}")
            return 2
        print(f"started in {time.monotonic() - t0:.0f} s")
        version = api.call("GET", "/api/version")
        print(f"Label Studio version {version.get('release') or version.get('label-studio-os-package', {})}")

        doc = sample_doc()
        project = api.call("POST", "/api/projects", {"title": "toosicubix round trip",
                                                      "label_config": label_studio_config(("Car", "Van", "Truck",
                                                                                           "Mid Size Car"))})
        print(f"project {project['id']} created from `toosicubix template label-studio`")
        api.call("POST", f"/api/projects/{project['id']}/import",
                 [{"data": {"image": f"https://example.invalid/frames/{image['id']}.png"}} for image in doc["images"]])
        tasks = api.call("GET", f"/api/tasks?project={project['id']}&page_size=100")
        tasks = tasks["tasks"] if isinstance(tasks, dict) else tasks
        by_name = {task["data"]["image"].rsplit("/", 1)[-1]: task for task in tasks}
        n_regions = 0
        for image in doc["images"]:
            task = by_name[f"{image['id']}.png"]
            result = label_studio_results(image, parent_ids=True)
            n_regions += len(result)
            api.call("POST", f"/api/tasks/{task['id']}/annotations", {"result": result, "was_cancelled": False})
        print(f"posted {len(doc['images'])} annotations, {n_regions} regions")

        export = api.call("GET", f"/api/projects/{project['id']}/export?exportType=JSON")
        export_path = work / "export.json"
        export_path.write_text(json.dumps(export, indent=1))
        print(f"exported {len(export)} tasks to {export_path}")

        cameras_path = work / "cameras.json"
        cameras_path.write_text(json.dumps(cameras_doc(doc)))
        imported_path = work / "imported.json"
        run = cli("import", "label-studio", str(export_path), "--cameras", str(cameras_path), "-o", str(imported_path))
        print(f"toosicubix import label-studio: exit {run.returncode}\n{run.stderr.strip()}")
        if run.returncode != 0:
            return 1
        imported = json.loads(imported_path.read_text())
        same_parts = same_clicks(imported, doc)  # same vehicles, names and prototypes, clicks within 1e-9 px
        worst_click = max(
            abs(a[1][k] - b[1][k])
            for ii, is_ in zip(imported["images"], doc["images"], strict=True)
            for vi, vs in zip(ii["vehicles"], is_["vehicles"], strict=True)
            for a, b in zip(sorted(keypoints_from_parts(vi["parts"])), sorted(keypoints_from_parts(vs["parts"])),
                            strict=True)
            for k in (0, 1))
        print(f"imported clicks equal the sample's: {same_parts} (largest click difference {worst_click:.2e} px)")

        fits = {}
        for name, path in (("sample", REPO / "samples" / "annotations.json"), ("imported", imported_path)):
            run = cli("fit", str(path), "-o", str(work / f"fit-{name}"), "-q")
            if run.returncode != 0:
                print(f"toosicubix fit {name}: exit {run.returncode}\n{run.stderr}")
                return 1
            fits[name] = json.loads((work / f"fit-{name}" / "results.json").read_text())
        worst = max_difference(fits["sample"], fits["imported"])
        n = sum(len(im["vehicles"]) for im in fits["imported"]["images"])
        ok = same_parts and worst <= TOLERANCE
        print(f"fitted {n} vehicles from the Label Studio export; largest difference from the sample's fit in "
              f"R_cam_vehicle, t_cam_vehicle (m), dimensions (m): {worst:.2e} (tolerance {TOLERANCE:g})")
        print("ROUND TRIP OK" if ok else "ROUND TRIP FAILED")
        return 0 if ok else 1
    finally:
        os.killpg(process.pid, 15)
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, 9)
        log.close()
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
