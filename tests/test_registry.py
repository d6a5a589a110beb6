"""The plug-in registry: lookup, errors, name clashes and a real third-party distribution."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import warnings

import pytest

from wholehand import registry
from wholehand.errors import PluginError

BUILTINS = {
    "contact_estimators": {"mesh_sdf", "coal_distance"},
    "allocators": {"qp", "qp_no_consistency", "fingertip_only"},
}


@pytest.fixture(autouse=True)
def _fresh_registry():
    registry.refresh()
    yield
    registry.refresh()


@pytest.mark.parametrize("group", sorted(BUILTINS))
def test_builtins_are_registered_through_entry_points(group):
    specs = registry.available(group)
    assert BUILTINS[group] <= set(specs)
    for name in BUILTINS[group]:
        assert specs[name].distribution == "wholehand"
        assert specs[name].value.startswith("wholehand_plugins.")


def test_unknown_name_lists_installed_names():
    with pytest.raises(PluginError) as info:
        registry.get_class("allocators", "no_such_allocator")
    message = str(info.value)
    assert "no_such_allocator" in message and "wholehand.allocators" in message
    for name in BUILTINS["allocators"]:
        assert name in message


def test_unknown_group_is_rejected():
    with pytest.raises(PluginError, match="unknown plug-in group"):
        registry.available("grippers")


def test_full_group_names_are_accepted():
    assert registry.available("wholehand.allocators") == registry.available("allocators")


def test_a_class_is_accepted_in_place_of_a_name():
    class Dummy:
        pass

    assert registry.get_class("allocators", Dummy) is Dummy


def _make_distribution(root, dist, module, group, name, body):
    """Build and install a tiny distribution with pip into ``root/site``; return that folder."""
    src = root / f"{dist}-src"
    (src / module).mkdir(parents=True)
    (src / module / "__init__.py").write_text(textwrap.dedent(body))
    (src / "pyproject.toml").write_text(
        textwrap.dedent(
            f"""
            [build-system]
            requires = ["setuptools"]
            build-backend = "setuptools.build_meta"
            [project]
            name = "{dist}"
            version = "0.1"
            [tool.setuptools]
            packages = ["{module}"]
            [project.entry-points."{group}"]
            {name} = "{module}:Plugin"
            """
        )
    )
    site = root / "site"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--quiet",
            "--no-deps",
            "--no-index",
            "--no-build-isolation",
            "--target",
            str(site),
            str(src),
        ],
        check=True,
        capture_output=True,
    )
    return site


ESTIMATOR_BODY = '''
    """A third-party estimator that finds no contacts."""
    from wholehand.contacts.base import ContactEstimator, ContactSet

    class Plugin(ContactEstimator):
        """Finds nothing, for testing."""

        def __init__(self, hand=None, obj=None, scale=1.0):
            self.hand, self.scale = hand, scale

        def estimate(self, kinematics, wMo, stamp=0.0):
            h = kinematics.hand
            return ContactSet.empty(h.link_actuated, h.link_fingertip, stamp)
'''


def test_third_party_estimator_loads_by_name_without_touching_core(tmp_path, monkeypatch, allegro):
    site = _make_distribution(
        tmp_path,
        "acme-estimator",
        "acme_estimator",
        "wholehand.contact_estimators",
        "acme_nothing",
        ESTIMATOR_BODY,
    )
    monkeypatch.syspath_prepend(str(site))
    registry.refresh()
    spec = registry.available("contact_estimators")["acme_nothing"]
    assert spec.distribution == "acme-estimator" and not spec.builtin
    estimator = registry.load("contact_estimators", "acme_nothing", hand=allegro, scale=2.0)
    assert estimator.scale == 2.0

    import numpy as np

    from wholehand.models.kinematics import HandKinematics

    contacts = estimator.estimate(HandKinematics(allegro), np.eye(4), stamp=1.5)
    assert len(contacts) == 0 and contacts.stamp == 1.5


def test_bad_parameters_name_the_plugin(tmp_path, monkeypatch):
    site = _make_distribution(
        tmp_path,
        "acme-estimator",
        "acme_estimator",
        "wholehand.contact_estimators",
        "acme_nothing",
        ESTIMATOR_BODY,
    )
    monkeypatch.syspath_prepend(str(site))
    registry.refresh()
    with pytest.raises(PluginError, match="acme_nothing.*rejected its parameters"):
        registry.load("contact_estimators", "acme_nothing", colour="red")


def test_failed_import_names_entry_point_and_distribution(tmp_path, monkeypatch):
    site = _make_distribution(
        tmp_path,
        "broken-plugin",
        "broken_plugin",
        "wholehand.allocators",
        "broken",
        "import module_that_does_not_exist\n",
    )
    monkeypatch.syspath_prepend(str(site))
    registry.refresh()
    with pytest.raises(PluginError) as info:
        registry.get_class("allocators", "broken")
    message = str(info.value)
    assert "broken-plugin" in message and "broken_plugin:Plugin" in message
    assert "module_that_does_not_exist" in message


def test_name_clash_warns_and_builtin_wins(tmp_path, monkeypatch):
    site = _make_distribution(
        tmp_path,
        "acme-estimator",
        "acme_estimator",
        "wholehand.contact_estimators",
        "mesh_sdf",
        ESTIMATOR_BODY,
    )
    monkeypatch.syspath_prepend(str(site))
    registry.refresh()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        specs = registry.available("contact_estimators")
    assert any("mesh_sdf" in str(w.message) and "acme-estimator" in str(w.message) for w in caught)
    assert specs["mesh_sdf"].distribution == "wholehand"
    other = registry.get_class("contact_estimators", "acme-estimator:mesh_sdf")
    assert other.__module__ == "acme_estimator"


def test_a_plugin_whose_constructor_raises_is_named():
    class Exploding:
        """Raises on construction."""

        def __init__(self, gain: float = 1.0) -> None:
            raise RuntimeError("no calibration file")

    with pytest.raises(
        PluginError,
        match="Exploding.*raised while it was constructed.*RuntimeError: no calibration file",
    ):
        registry.load("allocators", Exploding, gain=2.0)
