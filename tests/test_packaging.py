"""The wheel must carry every package of the source tree (an editable install hides a miss)."""
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11

ROOT = Path(__file__).resolve().parent.parent


def test_every_package_directory_is_listed_in_pyproject():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    mapped = {name: ROOT / folder for name, folder in config.get("package-dir", {}).items()}
    found = {
        ".".join(init.parent.relative_to(ROOT).parts)
        for top in ("pipeline", "shading", "clothjit")
        for init in (ROOT / top).rglob("__init__.py")
        if "__pycache__" not in init.parts
    }
    assert found <= listed, f"packages missing from pyproject.toml: {sorted(found - listed)}"
    for name, folder in mapped.items():
        assert (folder / "__init__.py").exists(), f"{name} -> {folder} is not a package"
    assert listed <= found | set(mapped), f"listed but absent: {sorted(listed - found)}"


def test_no_mapped_package_shadows_a_module():
    """`shading.textures` as a mapped data package once hid the module shading/textures.py
    in installed copies (the source tree never shows it)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    for name in config.get("package-dir", {}):
        module_file = ROOT.joinpath(*name.split(".")).with_suffix(".py")
        assert not module_file.exists(), f"package {name} would shadow {module_file}"
