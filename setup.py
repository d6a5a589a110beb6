"""The distribution's packages: every folder holding an ``__init__.py`` under the four source
roots, installed under its root's import name, so that a new package cannot be left out of a
wheel. Everything else about the distribution is in pyproject.toml."""

from setuptools import find_packages, setup

PACKAGE_ROOTS = {
    "wholehand": "wholehand",
    "wholehand_plugins": "plugins",
    "wholehand_robots": "robots",
    "wholehand_objects": "objects",
}
"""Import name -> folder of each source root; the built-in plug-ins, robots and objects are
installed under names that cannot collide with a user's packages."""


def packages() -> list[str]:
    """Every package under the roots, by its installed name."""
    found = []
    for name, folder in PACKAGE_ROOTS.items():
        found.append(name)
        found += [f"{name}.{sub}" for sub in find_packages(folder)]
    return sorted(found)


if __name__ == "__main__":
    setup(packages=packages(), package_dir=PACKAGE_ROOTS)
