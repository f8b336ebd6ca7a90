"""The checks CI runs besides the tests: ruff's lint rules and the documentation build in
strict mode (a broken cross-reference, link or anchor fails). Both tools come with the
`test` extra; without them these tests are skipped with the command that installs them.
Also: the public docstrings read well in plain `help()` (no autorefs markup, `simulate`'s
help fits a screen or two)."""

import dataclasses
import importlib
import importlib.util
import inspect
import os
import pydoc
import re
import subprocess
import sys
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
INSTALL = 'pip install -e ".[test]"'


def _run(*command, cwd=ROOT):
    """`python -m <command>` in this environment."""
    return _execute(sys.executable, "-m", *command, cwd=cwd)


def _execute(*command, cwd=ROOT):
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")  # mkdocs-material's banner, not ours
    return subprocess.run(list(command), cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=600)


@pytest.mark.skipif(importlib.util.find_spec("ruff") is None, reason=f"ruff: {INSTALL}")
def test_ruff_check_is_clean():
    result = _run("ruff", "check", "grazejax", "tests", "benchmarks")
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.skipif(
    importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("mkdocstrings") is None,
    reason=f"mkdocs and mkdocstrings (the `docs` extra): {INSTALL}",
)
def test_docs_build_in_strict_mode(tmp_path):
    result = _run("mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site"))
    assert result.returncode == 0, result.stdout + result.stderr
    api = (tmp_path / "site" / "api" / "index.html").read_text(encoding="utf-8")
    # The reference is generated from the docstrings: every public name has an entry.
    import grazejax

    public = [
        name for name, value in vars(grazejax).items()
        if not name.startswith("_") and not isinstance(value, types.ModuleType)
    ]
    missing = [name for name in public if f'id="grazejax.{name}"' not in api]
    assert not missing, f"public names without an API entry: {missing}"
    # The landing page is the README, its links pointing at the site's pages.
    home = (tmp_path / "site" / "index.html").read_text(encoding="utf-8")
    assert "Differentiable simulation of impact systems with grazing points" in home
    assert 'href="tour/"' in home and 'src="img/ex1dof-bifurcation.png"' in home


def test_wheel_ships_the_license_and_the_typed_marker_and_runs(tmp_path):
    """The Apache-2.0 text (pyproject's `license-files`) and `py.typed` (PEP 561: type
    checkers read grazejax's annotations) are in the repository and in the built wheel,
    and the wheel installed elsewhere runs the main job."""
    import zipfile

    license_text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert "Apache License" in license_text and "Version 2.0, January 2004" in license_text
    assert "END OF TERMS AND CONDITIONS" in license_text
    assert (ROOT / "grazejax" / "py.typed").is_file()
    # With hatchling installed (the `test` extra) the build needs no isolated environment
    # (and no package index); without it pip installs hatchling into one.
    isolation = ["--no-build-isolation"] if importlib.util.find_spec("hatchling") else []
    result = _run("pip", "wheel", "--no-deps", "--quiet", *isolation, "-w", str(tmp_path), ".")
    assert result.returncode == 0, result.stdout + result.stderr
    (wheel,) = tmp_path.glob("grazejax-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        info = next(name for name in names if name.endswith(".dist-info/METADATA"))
        metadata = archive.read(info).decode()
        assert "grazejax/py.typed" in names
        (shipped,) = [name for name in names if name.endswith(".dist-info/licenses/LICENSE")]
        assert archive.read(shipped).decode() == license_text
    assert "License-Expression: Apache-2.0" in metadata
    _wheel_runs_the_main_job(wheel, tmp_path)


def _wheel_runs_the_main_job(wheel, tmp_path):
    """The wheel, installed into a fresh environment (its dependencies from this one's
    site-packages, so no package index is needed), imports from there, not from this
    checkout, and runs `grazejax reproduce` (one figure) from another folder."""
    venv = tmp_path / "venv"
    result = _run("venv", "--system-site-packages", str(venv))
    assert result.returncode == 0, result.stdout + result.stderr
    bin_dir = venv / ("Scripts" if os.name == "nt" else "bin")
    result = _execute(str(bin_dir / "python"), "-m", "pip", "install", "--no-deps", "--no-index",
                  "--quiet", str(wheel))
    assert result.returncode == 0, result.stdout + result.stderr
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    result = _execute(str(bin_dir / "python"), "-c", "import grazejax; print(grazejax.__file__)",
                  cwd=elsewhere)
    assert result.returncode == 0, result.stdout + result.stderr
    assert Path(result.stdout.strip()).resolve().is_relative_to(venv.resolve()), result.stdout
    result = _execute(str(bin_dir / "grazejax"), "reproduce", "--only", "orbex2-region", "--out",
                  "out", "--quiet", cwd=elsewhere)
    assert result.returncode == 0, result.stdout + result.stderr
    assert any((elsewhere / "out").rglob("*.png")), sorted((elsewhere / "out").rglob("*"))


# mkdocstrings' cross-reference markup, `[name][]` or `[title][grazejax.name]` (the two halves
# possibly split over lines): in `help()` it shows as brackets. Docstrings name the API as
# plain code, `grazejax.Scene`, which the site links (docs/hooks/code_refs.py).
_AUTOREF = re.compile(r"\]\s*\[(grazejax\.[\w.]*)?\]")


def _public_docstrings():
    """(qualified name, docstring) of every public name of grazejax, of the members its
    classes define, and of the public modules `examples`, `paper` and `plot`."""
    import grazejax

    objects = {
        f"grazejax.{name}": value for name, value in vars(grazejax).items()
        if not name.startswith("_") and not isinstance(value, types.ModuleType)
    }
    for module_name in ("examples", "paper", "plot"):
        module = importlib.import_module(f"grazejax.{module_name}")
        objects[module.__name__] = module
        for name, value in vars(module).items():
            if not name.startswith("_") and getattr(value, "__module__", "").startswith(
                module.__name__
            ):
                objects[f"{module.__name__}.{name}"] = value
    for qualified, value in objects.items():
        yield qualified, qualified, inspect.getdoc(value) or ""
        if isinstance(value, type):
            for klass in value.__mro__:
                if not klass.__module__.startswith("grazejax"):
                    continue
                for name, member in vars(klass).items():
                    if name.startswith("_") and name != "__init__":
                        continue
                    member = getattr(member, "__func__", member)
                    doc = getattr(member, "__doc__", None)
                    if isinstance(member, (property, type)) or inspect.isfunction(member):
                        yield qualified, f"{qualified}.{name}", doc or ""


def test_public_docstrings_have_no_autorefs_markup():
    marked = {}
    for owner, name, doc in _public_docstrings():
        if _AUTOREF.search(doc):
            marked.setdefault(owner, []).append(name)
    assert not marked, f"write `grazejax.X`, not [`grazejax.X`][], in: {marked}"


def test_help_of_simulate_fits_and_lists_the_solution():
    import grazejax as gj

    text = pydoc.render_doc(gj.simulate, renderer=pydoc.plaintext)
    lines = text.splitlines()
    assert len(lines) <= 90, f"help(gj.simulate) is {len(lines)} lines (theory: docs/semantics.md)"
    assert "**Arguments:**" in text and "**Returns:**" in text and "**Example:**" in text
    # Every keyword of the signature is described, and every field of the Solution is named.
    for name in inspect.signature(gj.simulate).parameters:
        assert f"`{name}`" in text, f"simulate's docstring does not describe `{name}`"
    for field in dataclasses.fields(gj.Solution):
        assert f"`{field.name}`" in text, f"simulate's Returns does not name `{field.name}`"
