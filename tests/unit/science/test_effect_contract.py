"""The effect contract (service.science.effects.base), its conformance checks and the registry that
loads plug-ins (issue 38 §2): every built-in conforms; a plug-in from a directory or an entry point
takes its place by stage; a bad one is refused by the check that fails, by name, and loading goes
on; ``evcbench effects check`` names each failure and exits 1. Fresh registries, never the
process's own (which other tests' diagnoses read)."""

from __future__ import annotations

import sys
import textwrap

import numpy as np
import pytest

from service.frontends.cli import main
from service.science.effects import BUILTINS, EFFECTS
from service.science.effects.conformance import check_effect, synthetic_context, synthetic_record
from service.science.effects.delay import Delay
from service.science.effects.registry import BUILTIN, Registry

HEADER = (
    "import numpy as np\nfrom service.science.effects import Effect\nfrom service.science.fitting.lsq import Block\n"
)
GOOD = HEADER + textwrap.dedent(
    """
    class Sag(Effect):
        name = "sag"
        signature = "the output sags in proportion to the drive squared"
        units = {"sag_um": "µm"}

        def blocks(self, ctx):
            return [Block.make("sag_um", (ctx.u_v / ctx.u_scale_v) ** 2)]
    """
)


class LeadNotLag(Delay):
    """A delay whose declared response has the wrong sign of phase: its inverse would double it."""

    name = "lead_not_lag"

    def response(self, frequency_hz, fs_hz, theta):
        return np.exp(2j * np.pi * np.asarray(frequency_hz) * theta["delay_s"])


def fresh() -> Registry:
    registry = Registry()
    for cls in BUILTINS:
        registry.register(cls(), BUILTIN)
    return registry


def test_every_builtin_conforms_and_says_its_rule_units_and_inverse():
    for name, effect in EFFECTS.items():
        assert check_effect(effect, builtin=True) == [], name
        assert effect.rule and effect.units, name
        assert effect.inverse in ("iterate", "response", "invert") or effect.no_inverse, name  # "none" says why
    # the rules live on the effects: a one-rate record cannot test a delay, whatever module asks
    record = synthetic_record()
    assert EFFECTS["delay"].untestable([record]) is None  # 10 and 50 Hz
    assert EFFECTS["dynamics"].response(np.array([0.0]), 5000.0, {"fn_hz": 800.0, "zeta": 0.05})[0] == pytest.approx(1)


def test_a_bad_effect_is_refused_by_the_check_that_fails():
    class Raises(Delay):
        name = "raises"

        def apply(self, columns, fs_hz, theta):
            raise RuntimeError("boom")

    class Wide(Delay):
        name = "wide"

        def apply(self, columns, fs_hz, theta):
            return columns[:-1]

    checks = {type(e).__name__: {f.check for f in check_effect(e)} for e in (LeadNotLag(), Raises(), Wide(), object())}
    assert checks == {"LeadNotLag": {"inverse"}, "Raises": {"apply"}, "Wide": {"apply"}, "object": {"contract"}}
    (failure,) = check_effect(Raises())
    assert "RuntimeError: boom at test_effect_contract.py:" in failure.message
    lag = LeadNotLag()
    ctx = synthetic_context(synthetic_record())
    assert ctx.n == synthetic_record().n_samples and lag.untestable([synthetic_record()]) is None


def test_a_directory_plugin_takes_its_place_by_stage_and_bad_ones_are_recorded(tmp_path):
    (tmp_path / "sag.py").write_text(GOOD)
    (tmp_path / "nameless.py").write_text(GOOD.replace('name = "sag"', 'name = ""').replace("Sag", "Nameless"))
    (tmp_path / "nan.py").write_text(GOOD.replace('"sag"', '"nan_sag"').replace("** 2", "* np.nan"))
    (tmp_path / "taken.py").write_text(GOOD.replace('"sag"', '"drift"'))
    (tmp_path / "syntax.py").write_text("class (:\n")
    registry = fresh()
    registry.load_directory(tmp_path)
    registry.load_directory(tmp_path)  # once per directory
    names = list(registry.effects)
    assert names.index("line_disturbance") + 1 == names.index("sag") == names.index("delay") - 1
    assert registry.origins["sag"] == str(tmp_path / "sag.py")
    failed = {f["name"]: f["error"] for f in registry.failed}
    assert set(failed) == {"nameless", "nan_sag", "drift", "syntax"}, failed
    assert failed["nan_sag"].startswith("finite: block 'sag_um' has non-finite values")
    assert failed["drift"] == "the name 'drift' is taken by builtin" and failed["syntax"].startswith("SyntaxError")
    assert "sag" not in EFFECTS  # the process's registry is untouched
    listed = registry.catalogue()
    (sag,) = [e for e in listed["effects"] if e["name"] == "sag"]
    assert sag["parameters"] == [{"name": "sag_um", "unit": "µm"}] and sag["inverse"] == "iterate"


def test_an_entry_point_plugin_is_loaded_from_its_distribution(tmp_path, monkeypatch):
    (tmp_path / "labsag.py").write_text(GOOD)
    info = tmp_path / "labsag-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: labsag\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[evcbench.effects]\nsag = labsag:Sag\nmissing = labsag:Nope\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    registry = fresh()
    registry.load_entry_points()
    assert registry.origins["sag"] == "entry point sag (labsag:Sag)"
    assert [f["name"] for f in registry.failed] == ["missing"] and "AttributeError" in registry.failed[0]["error"]
    sys.modules.pop("labsag", None)


def test_effects_check_names_every_failure_and_exits_1(tmp_path, capsys):
    good, bad = tmp_path / "sag.py", tmp_path / "bad.py"
    good.write_text(GOOD)
    bad.write_text(GOOD.replace('units = {"sag_um": "µm"}', "units = {}").replace("** 2", "[:-1]"))
    assert main(["effects", "check", str(good)]) == 0
    assert capsys.readouterr().out.startswith("ok   sag: additive physical effect; parameters sag_um [µm]")
    assert main(["effects", "check", str(bad)]) == 1
    out = capsys.readouterr().out
    assert "FAIL sag: shapes: block 'sag_um' has shape" in out and "FAIL sag: units:" in out
    (tmp_path / "oops.py").write_text("raise ValueError('not today')\n")
    assert main(["effects", "check", str(tmp_path / "oops.py")]) == 1
    assert "FAIL oops: import: ValueError: not today" in capsys.readouterr().out


def test_a_stored_model_with_an_effect_not_loaded_is_refused_naming_the_model_not_a_500():
    from service.science.errors import FieldError
    from service.usecases.identify import load_model

    row = {"id": "md_fade", "effects": ["hysteresis", "gain_fade"], "parameters": {"model": "composite"}}
    with pytest.raises(FieldError) as refused:
        load_model(row)
    assert refused.value.field == "model" and "has not loaded: gain_fade" in refused.value.message
