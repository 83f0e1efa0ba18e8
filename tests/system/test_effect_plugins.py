"""Effects as plug-ins (issue 38 §2), end to end: the example of docs/how-to/add-your-own-effect.md,
taken from the page itself, is installed from a temporary directory into a real ``evcbench serve``
(EVCBENCH_EFFECTS_DIR) beside three bad plug-ins and one that does not import. The service starts,
lists the example with its origin and units, refuses the bad ones by name with their errors, and
serves; on a stage built outside the product (tests/support/foreign_stage.py) whose gain fades
moves 2 nm per kV of the drive's path (self-heating), imported as a CSV, the diagnosis names the example
first and discover ends ≤ 2× the floor. ``python -m tests.system.test_effect_plugins`` prints the same
stage's figures in-process (the page quotes them)."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from service.frontends.client import Client
from tests.support.foreign_stage import SAMPLE_RATE_HZ, bouc_wen_um, drive_v
from tests.support.live_server import ROOT, Server

DOC = ROOT / "docs" / "how-to" / "add-your-own-effect.md"
#: the bad plug-ins: what each does wrong, and the check's name that must refuse it
BAD = {
    "raises": ("def blocks(self, ctx):\n        raise RuntimeError('no columns today')\n", "blocks"),
    "short": ("def blocks(self, ctx):\n        return [Block.make('short_um', np.ones(ctx.n - 1))]\n", "shapes"),
    "unitless": ("def blocks(self, ctx):\n        return [Block.make('unitless_um', ctx.t_s)]\n", "units"),
}
HEATING_UM_PER_V = 2e-6  #: the hidden effect: the output moves 2 nm per kV of the drive's path


def example_source() -> str:
    """The page's ```python block that starts with ``# self_heating.py`` (what a reader copies)."""
    blocks = re.findall(r"^```python\n(.*?)^```", DOC.read_text(encoding="utf-8"), re.M | re.S)
    (source,) = [b for b in blocks if b.startswith("# self_heating.py\n")]
    return source


def bad_plugin(name: str) -> str:
    """A plug-in named ``name`` that does the wrong thing BAD says (units declared unless 'unitless')."""
    body, _ = BAD[name]
    units = "" if name == "unitless" else f"    units = {{'{name}_um': 'µm'}}\n"
    return (
        "import numpy as np\n\nfrom service.science.effects import Effect\nfrom service.science.fitting.lsq import Block\n\n\n"
        f"class Bad(Effect):\n    name = '{name}'\n    signature = 'a bad plug-in'\n{units}\n    "
        + body.replace("\n    ", "\n        ").replace("def blocks", "def blocks", 1)
    )


def write_plugins(directory: Path) -> Path:
    directory.mkdir()
    (directory / "self_heating.py").write_text(example_source(), encoding="utf-8")
    for name in BAD:
        (directory / f"{name}.py").write_text(bad_plugin(name), encoding="utf-8")
    (directory / "broken.py").write_text("import numpy as np\nfrom nowhere import Effect\n", encoding="utf-8")
    return directory


def heated_stage() -> tuple[np.ndarray, np.ndarray]:
    """The foreign stage (Bouc–Wen, 5 kHz, a rest then 100/1/50/10 Hz bursts of 60/3/24/6 cycles, 3 nm of
    noise) whose output moves HEATING_UM_PER_V per volt of the drive's travelled path: (u V, x µm)."""
    u = drive_v(frequencies_hz=(100, 1, 50, 10), cycles=(60, 3, 24, 6), rest_s=2.0, gap_s=0.3)
    path = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(u)))])
    x = bouc_wen_um(u) + HEATING_UM_PER_V * path + np.random.default_rng(0).normal(0.0, 0.003, u.size)
    return u, x


def heated_stage_csv(path: Path) -> Path:
    """``heated_stage`` as a CSV of t, u_y, x_y."""
    u, x = heated_stage()
    t = np.arange(u.size) / SAMPLE_RATE_HZ
    np.savetxt(path, np.column_stack([t, u, x]), delimiter=",", header="t,u_y,x_y", comments="", fmt="%.9g")
    return path


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("plugins")
    plugins = write_plugins(tmp / "effects")
    server = Server(tmp / "var", tmp / "server.log", env={"EVCBENCH_EFFECTS_DIR": str(plugins)})
    api = Client(server.url, timeout_s=600, token=server.token, data_dir=server.data_dir)
    try:
        yield server, api, plugins
    finally:
        api.close()
        assert server.stop(), server.log.read_text()


def test_bad_plugins_are_refused_by_name_at_start_up_and_the_service_serves(service):
    server, api, plugins = service
    catalogue = api.http.get("/api/effects").json()
    by_name = {e["name"]: e for e in catalogue["effects"]}
    example = by_name["self_heating"]
    assert example["origin"] == str(plugins / "self_heating.py")
    assert {"name": "self_heating_um", "unit": "µm"} in example["parameters"] and example["rule"]
    assert (
        by_name["drift"]["origin"] == "builtin"
        and {"name": "drift_nm_per_s", "unit": "nm/s"} in by_name["drift"]["parameters"]
    )
    failed = {f["name"]: f for f in catalogue["failed"]}
    assert set(failed) == {"raises", "short", "unitless", "broken"}, failed
    for name, (_, check) in BAD.items():
        assert failed[name]["error"].startswith(f"{check}:") and not set(failed) & set(by_name), failed[name]
    assert "no columns today" in failed["raises"]["error"] and "ModuleNotFoundError" in failed["broken"]["error"]
    assert "effect plug-in short refused" in server.log.read_text()
    assert api.http.get("/api/health").json()["status"] == "ok"
    r = api.http.post("/api/models", json={"axis": "y", "datasets": ["ds_nope"], "effects": ["hysteresis", "short"]})
    assert r.status_code == 422 and r.json()["field"] == "effects" and "'short'" in r.json()["detail"]


@pytest.mark.slow  # a diagnosis and a discover loop of four steps on a 36 200-sample record
def test_the_docs_example_is_found_first_and_discover_reaches_the_floor(service, tmp_path):
    _, api, _ = service
    warnings.simplefilter("ignore")
    ds = api.import_dataset(heated_stage_csv(tmp_path / "heated.csv"), name="self-heating 2 nm/kV")
    base = api.identify("y", [ds["id"]], model="static_pi")
    diagnosis = api.http.get(f"/api/models/{base['id']}/diagnosis", timeout=600).json()
    top = diagnosis["candidates"][0]
    assert (top["effect"], top["claimed"], diagnosis["verdict"]) == ("self_heating", True, "missing_effect"), diagnosis[
        "verdict_text"
    ]
    assert top["signature"].startswith("the output moves in proportion to the drive's travelled path")
    job = api.discover(base["id"], continue_past_ambiguity=True)
    assert job["state"] == "succeeded", job
    result = job["result"]
    found = result["effects_found"][0]
    assert found["effect"] == "self_heating" and 1.5 < found["parameters"]["heating_nm_per_kv"] < 2.5, found
    final = api.http.get(f"/api/models/{result['final_model_id']}/diagnosis", timeout=600).json()
    assert final["residual_rms_um"] <= 2.0 * final["noise_floor_um"], (
        final["residual_rms_um"],
        final["noise_floor_um"],
    )


def main() -> None:
    """The page's figures: the example loaded into this process, the heated stage diagnosed and discovered."""
    import tempfile

    from service.science.data.segmentation import blocks_without_table
    from service.science.discovery.composite import CompositeModel
    from service.science.discovery.diagnosis import diagnose
    from service.science.discovery.loop import discovery_run
    from service.science.discovery.parameters import physical_parameters
    from service.science.discovery.records import records_from_arrays
    from service.science.effects import REGISTRY

    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "self_heating.py").write_text(example_source(), encoding="utf-8")
        REGISTRY.load_directory(tmp)
        u, x = heated_stage()
        table = blocks_without_table({"y": u}, SAMPLE_RATE_HZ)
        recs = records_from_arrays({"u_y_v": u, "x_y_um": x}, SAMPLE_RATE_HZ, table, ("y",), "heated:")
        d = diagnose(recs)
        for c in d["candidates"][:3]:
            print(f"{c['effect']}: claimed {c['claimed']}, p = {c['p_value']:.2g}, score {c['score']}")
        steps = discovery_run(recs)
        for step in steps:
            dg = step["diagnosis"]
            print(step["effects"], f"{dg['residual_rms_um'] * 1e3:.2f} nm, floor {dg['noise_floor_um'] * 1e3:.2f} nm")
        final = CompositeModel(steps[-1]["effects"][1:]).fit(recs)
        print("fitted:", physical_parameters(final).get("self_heating"))


if __name__ == "__main__":
    main()
