"""What a wheel and the Docker image are built from, checked against the repository's tree.

pyproject.toml lists the packages explicitly and maps the service's rooms (``api/``, ``cli/``, ...) to
``neuenh_service.*`` and ``models/`` to the package data ``neuenh/shipped_models``: a folder of
Python modules missing from that list would silently be left out of the wheel and the image, and a
model folder left out of the Docker build context would be missing from every compose service.
``.ci/wheel_check.py`` builds the wheel itself and uses it from a fresh virtualenv.
"""

from __future__ import annotations

import re
import subprocess
import tomllib
from pathlib import Path, PurePosixPath

from docker.utils.build import exclude_paths

REPO = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
MODELS_HOME = "neuenh.shipped_models"
# Folders of Python modules that are run from a checkout and never installed.
NOT_INSTALLED = {"tests": "the test suite", "bench": "benchmarks (make bench)", "examples": "scripts of the README",
                 ".ci": "the CI's scripts"}


def tree_files() -> list[PurePosixPath]:
    """The files a build of this checkout sees: tracked, and untracked unless git ignores them."""
    listed = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], cwd=REPO,
                            capture_output=True, check=True).stdout.decode().split("\0")
    return [PurePosixPath(f) for f in listed if f and (REPO / f).is_file()]  # a deleted, unstaged file is gone


def source_folder(package: str) -> PurePosixPath:
    """The folder setuptools builds ``package`` from: the longest mapped prefix of pyproject's package-dir."""
    mapping = PYPROJECT.get("package-dir", {})
    parts = package.split(".")
    for cut in range(len(parts), 0, -1):
        prefix = ".".join(parts[:cut])
        if prefix in mapping:
            return PurePosixPath(mapping[prefix], *parts[cut:])
    return PurePosixPath(*parts)


def test_every_folder_of_python_modules_is_a_listed_package():
    listed = {source_folder(p): p for p in PYPROJECT["packages"]}
    with_modules = {f.parent for f in tree_files() if f.suffix == ".py" and f.parts[0] not in NOT_INSTALLED}
    missing = sorted(str(folder) for folder in with_modules - set(listed))
    assert not missing, f"folders of Python modules missing from pyproject.toml's packages: {missing}"
    for folder, package in listed.items():
        if package != MODELS_HOME:
            assert (REPO / folder / "__init__.py").is_file(), f"{package}: {folder}/__init__.py is missing"


def test_the_installed_names_are_the_projects_own():
    assert {p.split(".")[0] for p in PYPROJECT["packages"]} == {"neuenh", "neuenh_service"}
    assert set(PYPROJECT["package-dir"]) == {MODELS_HOME} | {f"neuenh_service.{room}" for room in
                                                             ("api", "cli", "orchestrator", "storage", "workers")}


def test_every_file_under_models_is_package_data():
    assert source_folder(MODELS_HOME) == PurePosixPath("models")
    # "**/*": every file of every bundle, whatever a later bundle adds (the wheel check compares bytes)
    assert PYPROJECT["package-data"][MODELS_HOME] == ["**/*"]
    assert PYPROJECT.get("include-package-data") is False  # package data is exactly what is listed


def image_paths(dockerfile: str) -> dict[PurePosixPath, PurePosixPath]:
    """Where each ``COPY`` from the build context puts what it names (a file or a folder): relative
    destinations start at the ``WORKDIR`` in force, a folder's contents go into its destination, a
    file goes into a destination ending in ``/`` (or taking several sources) under its own name."""
    placed, workdir = {}, PurePosixPath("/")
    for line in re.sub(r"\\\n", " ", dockerfile).splitlines():
        instruction, *words = line.split() or [""]
        if instruction == "WORKDIR":
            workdir = workdir / words[0]
        if instruction != "COPY" or any(w.startswith("--from") for w in words):
            continue
        *sources, destination = [w for w in words if not w.startswith("--")]
        into = destination.endswith("/") or len(sources) > 1
        for source in map(PurePosixPath, sources):
            target = workdir / destination
            placed[source] = target / source.name if into and (REPO / source).is_file() else target
    return placed


def in_image(path: PurePosixPath, placed: dict[PurePosixPath, PurePosixPath]) -> PurePosixPath | None:
    for source, target in placed.items():
        if path == source:
            return target
        if source in path.parents:
            return target / path.relative_to(source)
    return None


def test_the_docker_build_context_holds_every_source_of_the_wheel():
    """What the image's ``pip install .`` builds from — pyproject.toml, README.md, every file of the
    packages' folders (modules and package data) and every file under models/ — is in the build
    context (after .dockerignore) and copied to the folder the image installs from, where the tree
    has it."""
    dockerfile = (REPO / "Dockerfile").read_text()
    install = re.search(r"^WORKDIR (\S+)\n(?:(?:COPY|#).*\n)*RUN pip install \"\.\[", dockerfile, re.M)
    assert install, "the image copies the sources into one folder, then installs a wheel of it (pip install .)"
    source_dir = PurePosixPath(install.group(1))
    ignored = [line.strip() for line in (REPO / ".dockerignore").read_text().splitlines()
               if line.strip() and not line.startswith("#")]
    context = {PurePosixPath(p) for p in exclude_paths(str(REPO), ignored)}
    placed = image_paths(dockerfile)

    roots = {source_folder(p).parts[0] for p in PYPROJECT["packages"]}  # neuenh, api, ..., models
    needed = [PurePosixPath("pyproject.toml"), PurePosixPath("README.md")]
    needed += [f for f in tree_files() if f.parts[0] in roots]  # modules and package data
    assert any(f.parts[0] == "models" and f.name == "model.json" for f in needed), "no shipped model in this tree"
    for f in needed:
        assert f in context, f"{f}: .dockerignore leaves it out of the build context"
        assert in_image(f, placed) == source_dir / f, f"{f}: no COPY line puts it at {source_dir / f}"
