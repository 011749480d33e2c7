"""The one registry mechanism (navlab/registry.py) and its four users."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import pytest

from navlab.errors import NavlabError
from navlab.registry import Registry


@dataclass(frozen=True)
class _Thing:
    key: str
    value: int = 0

    def __call__(self, params):
        return (self.key, params)


def test_register_lookup_make_and_messages():
    reg: Registry[_Thing] = Registry("gadget")
    a = reg.register(_Thing("a-one", 1))
    reg.register(_Thing("b-two", 2))
    assert reg["a-one"] is a and "b-two" in reg and list(reg) == ["a-one", "b-two"] and len(reg) == 2
    assert reg.make("a-one", {"p": 1}) == ("a-one", {"p": 1})
    with pytest.raises(NavlabError, match=r"unknown gadget 'nope'; known: a-one, b-two"):
        reg.lookup("nope")
    with pytest.raises(KeyError):
        reg["nope"]  # the mapping protocol keeps KeyError
    reg.register(a)  # the same object again: a no-op
    with pytest.raises(ValueError, match="registered twice"):
        reg.register(_Thing("a-one", 3))
    for bad in ("", "Upper", "snake_case", "with space", None):
        with pytest.raises(ValueError, match="kebab-case"):
            reg.register(_Thing(bad))


def test_check_refuses_and_mapping_updates():
    def check(obj):
        if obj.value < 0:
            raise TypeError("negative")

    reg: Registry[_Thing] = Registry("gadget", check=check)
    with pytest.raises(TypeError):
        reg.register(_Thing("neg", -1))
    saved = {"x": _Thing("x")}
    reg.update(saved)  # MutableMapping: a test can swap the contents and restore them
    assert list(reg) == ["x"]
    reg.clear()
    assert len(reg) == 0
    with pytest.raises(ValueError, match="has key"):
        reg["y"] = _Thing("x")


def test_package_modules_are_discovered_on_first_read():
    from navlab.filters.base import FILTERS
    from navlab.noise import OUTLIERS, SCHEDULES
    from navlab.scenarios.base import SCENARIOS

    assert {"kf", "irakf", "svd-ukf", "vb-ekf", "wls"} <= set(FILTERS)
    assert {"cv2d", "sins-gps", "gps-ins-rtk"} <= set(SCENARIOS)
    assert next(iter(SCHEDULES)) == "constant" and "hakf-tanh" in SCHEDULES
    assert list(OUTLIERS)[:2] == ["none", "mixture"]
    with pytest.raises(NavlabError, match="unknown noise schedule 'x'"):
        SCHEDULES.make("x")
    with pytest.raises(NavlabError, match="unknown scenario 'x'"):
        SCENARIOS.lookup("x")


def test_a_new_module_registers_without_touching_a_list_even_under_threads(tmp_path, monkeypatch):
    pkg = tmp_path / "navlab_plugins_x"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        "from navlab.registry import Registry\nREG = Registry('thing', package='navlab_plugins_x')\n"
    )
    for name in ("alpha", "beta", "gamma"):
        (pkg / f"{name}.py").write_text(
            "import time\nfrom navlab_plugins_x import REG\ntime.sleep(0.01)\n"
            f"class T:\n    key = '{name}'\nREG.register(T)\n"
        )
    monkeypatch.syspath_prepend(str(tmp_path))
    from navlab_plugins_x import REG

    seen, errors = [], []

    def read():
        try:
            seen.append(sorted(REG))
        except Exception as exc:  # pragma: no cover - the failure being tested for
            errors.append(exc)

    threads = [threading.Thread(target=read) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert seen == [["alpha", "beta", "gamma"]] * 8


# -- plugins: entry points ---------------------------------------------------------------------
PLUGIN_THING = _Thing("from-a-plugin", 7)


def _entry_points(monkeypatch, group: str, *specs: tuple[str, str]) -> None:
    """Make importlib.metadata report entry points ``(name, "module:attr")`` in ``group``."""
    import importlib.metadata as md

    import navlab.registry

    eps = md.EntryPoints([md.EntryPoint(name, value, group) for name, value in specs])
    monkeypatch.setattr(navlab.registry, "installed_entry_points", lambda: eps)


def test_entry_points_register_objects_and_a_broken_one_is_named(monkeypatch, caplog):
    _entry_points(
        monkeypatch,
        "navlab.test_gadgets",
        ("from-a-plugin", f"{__name__}:PLUGIN_THING"),
        ("broken", "no_such_module_anywhere:Thing"),
    )
    reg: Registry[_Thing] = Registry("gadget", plugins="navlab.test_gadgets")
    reg.register(_Thing("built-in"))
    assert list(reg) == ["built-in", "from-a-plugin"] and reg["from-a-plugin"] is PLUGIN_THING
    assert "broken" in reg.plugin_errors and "no_such_module_anywhere" in reg.plugin_errors["broken"]
    assert "gadget plugin 'broken'" in caplog.text  # logged, not raised
    with pytest.raises(
        NavlabError, match=r"the gadget plugin 'broken' failed to load: .*ModuleNotFoundError"
    ):
        reg.lookup("broken")


@pytest.mark.parametrize(
    ("module", "name", "group"),
    [
        ("navlab.filters.base", "FILTERS", "navlab.filters"),
        ("navlab.scenarios.base", "SCENARIOS", "navlab.scenarios"),
        ("navlab.noise.schedules", "SCHEDULES", "navlab.noise_schedules"),
        ("navlab.noise.outliers", "OUTLIERS", "navlab.outlier_models"),
    ],
)
def test_every_component_registry_has_its_plugin_group(module, name, group):
    import importlib

    assert getattr(importlib.import_module(module), name).plugins == group
